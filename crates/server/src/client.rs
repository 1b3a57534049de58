//! A gRPC client for the service: what `afterimage stream` and the end-to-end tests use.

use super::proto::afterimage_client::AfterimageClient;
use super::proto::{self as pb, filtered_chunk, frame_chunk};
use super::wire;
use crate::frame::{ChannelSet, Frame, Rgb};
use std::collections::VecDeque;
use std::sync::Mutex;
use std::time::Instant;
use tokio::sync::{mpsc, Semaphore};
use tokio_stream::wrappers::ReceiverStream;
use tokio_stream::StreamExt;
use tonic::metadata::{Ascii, MetadataValue};
use tonic::service::interceptor::InterceptedService;
use tonic::service::Interceptor;
use tonic::transport::{Certificate, Channel, ClientTlsConfig, Endpoint};
use tonic::Status;

/// How to reach a server: its API key and, for `https://` addresses, the CA that signed
/// its certificate.
#[derive(Clone, Debug, Default)]
pub struct ConnectOptions {
    /// Sent as `authorization: Bearer KEY` on every call.
    pub api_key: Option<String>,
    /// PEM of the CA (or the self-signed certificate) to trust, for `https://`.
    pub tls_ca: Option<Vec<u8>>,
    /// The name the certificate is for, when it is not the address's host.
    pub tls_domain: Option<String>,
    /// Sent as [`super::ROUTE_HEADER`] on every call: the key a proxy in front of several
    /// replicas routes the client's session by (printable ASCII).
    pub route: Option<String>,
}

/// Why a client could not connect.
#[derive(Debug, thiserror::Error)]
pub enum ConnectError {
    /// The connection failed.
    #[error(transparent)]
    Transport(#[from] tonic::transport::Error),
    /// The options do not fit the address.
    #[error("{0}")]
    Options(String),
}

/// Adds the API key and the routing key to every call.
#[derive(Clone, Debug, Default)]
pub struct Auth {
    key: Option<MetadataValue<Ascii>>,
    route: Option<MetadataValue<Ascii>>,
}

impl Interceptor for Auth {
    fn call(&mut self, mut req: tonic::Request<()>) -> Result<tonic::Request<()>, Status> {
        if let Some(v) = &self.key {
            req.metadata_mut().insert("authorization", v.clone());
        }
        if let Some(v) = &self.route {
            req.metadata_mut().insert(super::ROUTE_HEADER, v.clone());
        }
        Ok(req)
    }
}

/// The generated client, with the API key added to every call.
pub type Inner = AfterimageClient<InterceptedService<Channel, Auth>>;

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

/// A connected client.
#[derive(Clone)]
pub struct Client {
    /// The generated client, for calls not wrapped here.
    pub inner: Inner,
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
        let tls = url.starts_with("https://");
        let mut endpoint = Endpoint::from_shared(url)?
            .initial_stream_window_size(super::wire::STREAM_WINDOW_BYTES)
            .initial_connection_window_size(super::wire::CONNECTION_WINDOW_BYTES)
            .tcp_nodelay(true);
        match (&opts.tls_ca, tls) {
            (Some(ca), true) => {
                let mut config = ClientTlsConfig::new().ca_certificate(Certificate::from_pem(ca));
                if let Some(d) = &opts.tls_domain {
                    config = config.domain_name(d.clone());
                }
                endpoint = endpoint.tls_config(config)?;
            }
            (None, true) => {
                return Err(ConnectError::Options(
                    "an https:// server needs the CA certificate that signed its certificate (--tls-ca)"
                        .into(),
                ))
            }
            (Some(_), false) => {
                return Err(ConnectError::Options(
                    "a CA certificate was given for an http:// address; use https://".into(),
                ))
            }
            (None, false) => {}
        }
        let key = opts
            .api_key
            .as_ref()
            .map(|k| {
                MetadataValue::try_from(format!("Bearer {k}"))
                    .map_err(|_| ConnectError::Options("the API key is not printable ASCII".into()))
            })
            .transpose()?;
        let route = opts
            .route
            .as_ref()
            .map(|r| {
                MetadataValue::try_from(r.as_str())
                    .map_err(|_| ConnectError::Options("the routing key is not printable ASCII".into()))
            })
            .transpose()?;
        let channel = endpoint.connect().await?;
        let inner = AfterimageClient::with_interceptor(channel, Auth { key, route })
            .max_decoding_message_size(64 << 20)
            .max_encoding_message_size(64 << 20);
        Ok(Client { inner })
    }

    /// Streams `frames` to session `session`, [`SendOptions::in_flight`] at a time (with 1,
    /// the next frame is sent when the previous reply is in, so `round_trip_ms` is a
    /// per-frame latency; with 2 it also counts the wait behind the frame before), and calls
    /// `on_reply` with each reply in order. With a windowed filter (`session.lookahead` = L > 0) the
    /// reply to frame t comes after frame t + L is sent: the client keeps L frames in
    /// flight, closes its side after the last frame and reads the rest (`round_trip_ms`
    /// then counts from the frame's own sending, so it includes the L frames' wait).
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
        let lookahead = session.lookahead as usize;
        let (tx, rx) = mpsc::channel::<pb::FrameChunk>(4);
        let mut replies = self.inner.stream(ReceiverStream::new(rx)).await?.into_inner();
        // Frames sent whose reply has not come: when, and how many bytes.
        let in_flight: Mutex<VecDeque<(Instant, u64)>> = Mutex::new(VecDeque::new());
        // A permit per frame that may be in flight; each reply gives one back.
        let permits = Semaphore::new(lookahead + opts.in_flight.max(1));
        // Frames go out while replies come in: a server that answers frame t while it
        // receives frame t + 1 never waits on a client busy sending.
        let send = async {
            for frame in frames {
                match permits.acquire().await {
                    Ok(p) => p.forget(),
                    Err(_) => return,
                }
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
                let sent: u64 = chunks.iter().map(|c| c.data.len() as u64).sum();
                lock(&in_flight).push_back((Instant::now(), sent));
                let parts = std::iter::once(frame_chunk::Part::Header(header))
                    .chain(chunks.into_iter().map(frame_chunk::Part::Data));
                for part in parts {
                    if tx.send(pb::FrameChunk { part: Some(part) }).await.is_err() {
                        // The server ended the stream: the replies' status says why.
                        return;
                    }
                }
            }
            // Closing our side makes a windowed filter give its last frames.
            drop(tx);
        };
        let receive = async {
            while let Some(reply) = read_reply(&mut replies, &in_flight).await? {
                permits.add_permits(1);
                on_reply(reply);
            }
            let unanswered = lock(&in_flight).len();
            if unanswered > 0 {
                return Err(Status::unavailable(format!(
                    "the server ended the stream with {unanswered} frames unanswered"
                )));
            }
            Ok(())
        };
        tokio::pin!(send, receive);
        let mut sending = true;
        loop {
            tokio::select! {
                () = &mut send, if sending => sending = false,
                r = &mut receive => return r,
            }
        }
    }
}

/// The queue of frames in flight (never held across an await).
fn lock<T>(m: &Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|p| p.into_inner())
}

/// Reads one reply (header, then the colour's chunks), matched to the oldest frame in
/// flight; None when the stream ended cleanly.
async fn read_reply(
    replies: &mut tonic::Streaming<pb::FilteredChunk>,
    in_flight: &Mutex<VecDeque<(Instant, u64)>>,
) -> Result<Option<Reply>, Status> {
    let head = match replies.next().await {
        Some(Ok(pb::FilteredChunk {
            part: Some(filtered_chunk::Part::Header(h)),
        })) => h,
        Some(Ok(_)) => return Err(Status::internal("reply data before its header")),
        Some(Err(s)) => return Err(s),
        None => return Ok(None),
    };
    let color_h = head
        .color
        .clone()
        .ok_or_else(|| Status::internal("reply without colour"))?;
    let mut bytes = Vec::with_capacity(color_h.byte_length as usize);
    while (bytes.len() as u64) < color_h.byte_length {
        match replies.next().await {
            Some(Ok(pb::FilteredChunk {
                part: Some(filtered_chunk::Part::Data(d)),
            })) => bytes.extend_from_slice(&d.data),
            Some(Err(s)) => return Err(s),
            _ => return Err(Status::internal("reply ended before its colour")),
        }
    }
    let color = wire::decode_color(&color_h, &bytes, head.width, head.height)
        .map_err(|e| Status::internal(e.to_string()))?;
    let (t, sent) = lock(in_flight)
        .pop_front()
        .ok_or_else(|| Status::internal("a reply to no frame sent"))?;
    Ok(Some(Reply {
        index: head.index,
        color,
        report: head.report.unwrap_or_default(),
        round_trip_ms: t.elapsed().as_secs_f64() * 1e3,
        payload_bytes: sent + bytes.len() as u64,
    }))
}
