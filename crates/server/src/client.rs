//! A gRPC client for the service over this crate's frames: what `afterimage stream` and the
//! end-to-end tests use. The protocol's side of it (connecting, encoding, pipelined
//! streaming) is `afterimage-client`'s; this adds [`Frame`]s in and [`Rgb`] out.

use super::proto as pb;
use super::wire;
use crate::frame::{ChannelSet, Frame, Plane, Rgb};
pub use afterimage_client::connect::{Auth, ConnectError, ConnectOptions, Inner};
use afterimage_client::frame::Encoded;
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
        frames: impl IntoIterator<Item = Frame>,
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
        let max_chunk = session.max_chunk_bytes.max(1) as usize;
        let encoded = frames.into_iter().map(|frame| {
            // The reference travels too when the frame has one (the reply then has PSNR/SSIM).
            let send = if opts.reference && frame.reference().is_some() {
                channels.with(crate::frame::ChannelKind::Reference)
            } else {
                channels
            };
            let (header, chunks) = wire::encode_frame(
                &frame,
                &session.id,
                send,
                opts.sample,
                opts.compression,
                max_chunk,
            );
            Encoded { header, chunks }
        });
        let mut bad: Option<Status> = None;
        afterimage_client::stream::stream(&mut self.inner, session, encoded, opts.in_flight, |r| {
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
        })
        .await?;
        bad.map_or(Ok(()), Err)
    }
}
