//! A gRPC client for the service over this crate's frames: what `afterimage stream` and the
//! end-to-end tests use. The protocol's side of it (connecting, encoding, pipelined
//! streaming) is `afterimage-client`'s; this adds [`Frame`]s in and [`Rgb`] out.

use super::proto as pb;
use super::wire;
use crate::frame::{ChannelSet, Frame, Plane, Rgb};
pub use afterimage_client::connect::{Auth, ConnectError, ConnectOptions, Inner};
use afterimage_client::frame::{encode, Encoded, Encoding};
use afterimage_client::shm::SharedRegion;
use std::borrow::Borrow;
use tonic::Status;

/// A client connected to a server.
#[derive(Clone, Debug)]
pub struct Client {
    /// The generated client, for calls not wrapped here.
    pub inner: Inner,
}

/// A filtered frame as the client receives it.
#[derive(Clone, Debug)]
pub struct Reply {
    /// Frame index.
    pub index: u64,
    /// Filtered colour.
    pub color: Rgb,
    /// The server's report.
    pub report: pb::FrameReport,
    /// From sending the frame's header to holding its whole reply, ms.
    pub round_trip_ms: f64,
    /// Bytes sent for the frame plus bytes received for its reply.
    pub payload_bytes: u64,
}

/// How frames are sent.
#[derive(Clone, Copy, Debug)]
pub struct SendOptions {
    /// Sample type of colour and other float channels, and of the reply.
    pub sample: pb::SampleType,
    /// Compression of every channel and of the reply.
    pub compression: pb::Compression,
    /// Send the frame's reference channel when it has one (the reply then has PSNR/SSIM).
    pub reference: bool,
    /// Frames sent ahead of their replies (beyond a windowed filter's lookahead): 1 sends
    /// the next frame when the last reply is in (`round_trip_ms` is then a latency); 2 sends
    /// it while the server filters the last, which is what the server overlaps (it
    /// receives one frame while it filters another). At least 1.
    pub in_flight: usize,
    /// Send the frames' bytes and take the replies' colour through a shared memory region
    /// the server makes for the session (a client on the server's machine; uncompressed,
    /// causal filters, at most 2 frames in flight): only headers cross the socket.
    pub shared_memory: bool,
}

/// A frame as [`Client::stream`] sends it: encoded as it is sent, so that through a shared
/// memory region an f32 frame is written into its slot straight from its planes.
struct Pending<'s, F> {
    frame: F,
    session_id: &'s str,
    /// The channels sent, those the frame has.
    channels: ChannelSet,
    how: Encoding,
}

impl<F: Borrow<Frame>> afterimage_client::stream::Outgoing for Pending<'_, F> {
    fn encode(self) -> Encoded {
        wire::with_frame_data(self.frame.borrow(), self.channels, |data| {
            encode(data, self.session_id, self.how)
        })
    }

    fn in_place(&self) -> bool {
        self.how.in_place()
    }

    fn place(self, region: &SharedRegion, n: u64) -> std::io::Result<Encoded> {
        wire::with_frame_data(self.frame.borrow(), self.channels, |data| {
            region.write(n, data, self.session_id, self.how)
        })
    }
}

impl Client {
    /// Connects to `url` (`http://host:port`) without a key.
    pub async fn connect(url: String) -> Result<Client, ConnectError> {
        Self::connect_with(url, &ConnectOptions::default()).await
    }

    /// Connects to `url` (`http://host:port`, or `https://` with `opts.tls_ca`) and sends
    /// `opts.api_key` with every call.
    pub async fn connect_with(url: String, opts: &ConnectOptions) -> Result<Client, ConnectError> {
        Ok(Client {
            inner: afterimage_client::connect::connect(url, opts).await?,
        })
    }

    /// Streams `frames` to session `session` (see [`afterimage_client::stream::stream`]:
    /// [`SendOptions::in_flight`] frames ahead, replies in order) and calls `on_reply` with
    /// each reply.
    pub async fn stream(
        &mut self,
        session: &pb::Session,
        frames: impl IntoIterator<Item = impl Borrow<Frame>>,
        opts: SendOptions,
        mut on_reply: impl FnMut(Reply),
    ) -> Result<(), Status> {
        let channels = ChannelSet::of(
            &session
                .channels
                .iter()
                .filter_map(|c| crate::frame::ChannelKind::from_name(c))
                .collect::<Vec<_>>(),
        );
        let how = Encoding {
            sample: opts.sample,
            compression: opts.compression,
            max_chunk: session.max_chunk_bytes.max(1) as usize,
        };
        let outgoing = frames.into_iter().map(|frame| {
            // The reference travels too when the frame has one (the reply then has PSNR/SSIM).
            let send = if opts.reference && frame.borrow().reference().is_some() {
                channels.with(crate::frame::ChannelKind::Reference)
            } else {
                channels
            };
            Pending {
                frame,
                session_id: &session.id,
                channels: send,
                how,
            }
        });
        let region = match opts.shared_memory {
            true => Some(self.open_region(session, channels, opts).await?),
            false => None,
        };
        let mut bad: Option<Status> = None;
        let through = region.as_ref();
        afterimage_client::stream::stream_through(
            &mut self.inner,
            session,
            outgoing,
            opts.in_flight,
            through,
            |r| {
                let (w, h) = (r.width as usize, r.height as usize);
                let [red, green, blue] = r.color;
                match [red, green, blue].map(|d| Plane::from_vec(w, h, d)) {
                    [Ok(red), Ok(green), Ok(blue)] => on_reply(Reply {
                        index: r.index,
                        color: [red, green, blue],
                        report: r.report,
                        round_trip_ms: r.round_trip_ms,
                        payload_bytes: r.payload_bytes,
                    }),
                    _ => {
                        bad.get_or_insert_with(|| {
                            Status::internal(format!("reply {} of a {w}x{h} frame", r.index))
                        });
                    }
                }
            },
        )
        .await?;
        bad.map_or(Ok(()), Err)
    }

    /// Opens `session`'s shared memory region, a slot per frame in flight, each as large
    /// as a frame of `channels` (and a reference, when sent) and its reply.
    async fn open_region(
        &mut self,
        session: &pb::Session,
        channels: ChannelSet,
        opts: SendOptions,
    ) -> Result<SharedRegion, Status> {
        if opts.compression != pb::Compression::None {
            return Err(Status::invalid_argument(
                "shared memory takes uncompressed frames: nothing crosses a socket to compress for",
            ));
        }
        if !(1..=2).contains(&opts.in_flight) {
            return Err(Status::invalid_argument(format!(
                "shared memory takes 1 or 2 frames in flight (a slot each in the region), not {}",
                opts.in_flight
            )));
        }
        let send = if opts.reference {
            channels.with(crate::frame::ChannelKind::Reference)
        } else {
            channels
        };
        let px = session.width as u64 * session.height as u64;
        let width = afterimage_client::codec::sample_bytes(opts.sample) as u64;
        let frame_bytes: u64 = send
            .with(crate::frame::ChannelKind::Color)
            .iter()
            .map(|k| match k {
                crate::frame::ChannelKind::ObjectId => 4 * px,
                k => k.components() as u64 * width * px,
            })
            .sum();
        let slots = opts.in_flight as u64;
        let bytes = SharedRegion::size_for(frame_bytes, 3 * width * px, slots);
        let region = self
            .inner
            .open_region(pb::OpenRegionRequest {
                session_id: session.id.clone(),
                bytes,
            })
            .await?
            .into_inner();
        SharedRegion::open(&region, frame_bytes, 3 * width * px, slots).map_err(|e| {
            Status::failed_precondition(format!("opening the shared memory region {}: {e}", region.path))
        })
    }
}
