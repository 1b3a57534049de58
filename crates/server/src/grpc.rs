//! The gRPC layer (tonic): a thin adapter from the proto messages to [`Service`].
//!
//! A stream claims its session with its first frame header; every header is checked
//! against the session's shape (and its memory reserved) before a byte of data is taken;
//! each complete frame is decoded, filtered and answered on the rayon pool. Every refusal
//! ends the stream with a status naming the problem.

use super::listener::until_true;
use super::proto::afterimage_server::{Afterimage, AfterimageServer};
use super::proto::{self as pb, filtered_chunk, frame_chunk};
use super::service::{InFlight, Service};
use super::wire::{self, Assembly, FramePlan};
use crate::filters;
use crate::frame::Plane;
use crate::pipeline::ParamKind;
use crate::pipeline::Scratch;
use crate::session::{
    clip, Caller, Checkout, ErrorKind, Filtered, MotionInput, Region, Reservation, SessionError, SessionInfo,
    SessionRequest, StreamClaim,
};
use afterimage_client::codec::{in_host_order, put_planes, sample_bytes};
use bytes::Bytes;
use std::future::Future;
use std::pin::Pin;
use std::sync::{mpsc as sync_mpsc, Arc, Mutex, PoisonError};
use std::time::{Duration, Instant};
use tokio::sync::{mpsc, watch};
use tokio_stream::{wrappers::ReceiverStream, Stream, StreamExt};
use tonic::metadata::MetadataMap;
use tonic::{Code, Request, Response, Status, Streaming};
use tonic_health::pb::health_server::{Health, HealthServer};
use tonic_health::ServingStatus;
use tonic_reflection::server::{v1, v1alpha};

/// The status for a session error (its message capped).
pub fn status(e: &SessionError) -> Status {
    let msg = e.client_message();
    match e.kind() {
        ErrorKind::InvalidArgument => Status::invalid_argument(msg),
        ErrorKind::NotFound => Status::not_found(msg),
        ErrorKind::ResourceExhausted | ErrorKind::TooLarge => Status::resource_exhausted(msg),
        ErrorKind::FailedPrecondition => Status::failed_precondition(msg),
        ErrorKind::Unauthenticated => Status::unauthenticated(msg),
        ErrorKind::Internal => Status::internal(msg),
        ErrorKind::Unavailable => Status::unavailable(msg),
    }
}

fn session_pb(s: SessionInfo, max_chunk: usize) -> pb::Session {
    pb::Session {
        id: s.id,
        filter: s.filter,
        params_json: s.params.to_string(),
        width: s.width,
        height: s.height,
        motion: s.motion,
        channels: s.channels,
        needs: s.needs,
        uses: s.uses,
        state_bytes: s.state_bytes,
        frames: s.frames,
        idle_seconds: s.idle_seconds,
        max_chunk_bytes: max_chunk as u64,
        lookahead: s.lookahead,
        backend: s.backend.name().to_string(),
    }
}

/// The proto description of every filter.
pub fn filters_pb() -> Vec<pb::FilterInfo> {
    filters::list()
        .into_iter()
        .map(|i| pb::FilterInfo {
            name: i.name.into(),
            summary: i.summary.into(),
            needs: i.needs.iter().map(|k| k.name().into()).collect(),
            uses: i.uses.iter().map(|k| k.name().into()).collect(),
            stages: i.stages.iter().map(|s| s.to_string()).collect(),
            params: i
                .params
                .iter()
                .map(|p| {
                    let (kind, min, max, choices) = match &p.kind {
                        ParamKind::Float { min, max } => ("number", Some(*min), Some(*max), vec![]),
                        ParamKind::Int { min, max } => {
                            ("integer", Some(*min as f64), Some(*max as f64), vec![])
                        }
                        ParamKind::Bool => ("bool", None, None, vec![]),
                        ParamKind::Choice { options } => (
                            "choice",
                            None,
                            None,
                            options.iter().map(|o| o.to_string()).collect(),
                        ),
                    };
                    pb::ParamSpec {
                        name: p.name.into(),
                        kind: kind.into(),
                        default_json: i.defaults.get(p.name).map_or("null".into(), |v| v.to_string()),
                        min,
                        max,
                        choices,
                        doc: p.doc.into(),
                    }
                })
                .collect(),
            state_bytes_per_pixel: i.state_bytes_per_pixel as u64,
        })
        .collect()
}

/// How a frame asks for its reply's colour: the sample type (f32 unless f16) and the
/// compression.
fn reply_encoding(req: &pb::FrameHeader) -> (pb::SampleType, pb::Compression) {
    let sample = match pb::SampleType::try_from(req.reply_sample) {
        Ok(pb::SampleType::F16) => pb::SampleType::F16,
        _ => pb::SampleType::F32,
    };
    let compression = pb::Compression::try_from(req.reply_compression).unwrap_or(pb::Compression::None);
    (sample, compression)
}

/// The buffer a stream's uncompressed replies are encoded into, lent to the transport
/// and back when the last chunk of a reply is sent: a fresh buffer a frame (11 MB at 720p
/// in f32) costs a page fault per 4 KiB.
#[derive(Clone, Default)]
pub struct ReplyBuffer(Arc<Mutex<Vec<u8>>>);

impl ReplyBuffer {
    /// `len` bytes written by `fill`, as bytes that come back here when dropped.
    fn lend(&self, len: usize, fill: impl FnOnce(&mut [u8])) -> Bytes {
        let mut buf = std::mem::take(&mut *self.0.lock().unwrap_or_else(PoisonError::into_inner));
        buf.resize(len, 0);
        fill(&mut buf);
        Bytes::from_owner(Lent {
            buf,
            home: self.clone(),
        })
    }
}

/// A reply's bytes on loan from a [`ReplyBuffer`].
struct Lent {
    buf: Vec<u8>,
    home: ReplyBuffer,
}

impl AsRef<[u8]> for Lent {
    fn as_ref(&self) -> &[u8] {
        &self.buf
    }
}

impl Drop for Lent {
    fn drop(&mut self) {
        *self.home.0.lock().unwrap_or_else(PoisonError::into_inner) = std::mem::take(&mut self.buf);
    }
}

/// The reply to one filtered frame: a header, then the colour in chunks (uncompressed
/// ones encoded in `buffer` when given); or, with `region` (the session's shared memory,
/// for a frame that came through it), the colour written at the frame's `reply_offset`
/// and the header alone.
pub fn reply(
    f: &Filtered,
    session_id: &str,
    req: &pb::FrameHeader,
    server_ms: f64,
    max_chunk: usize,
    region: Option<&Region>,
    buffer: Option<&ReplyBuffer>,
) -> Result<Vec<pb::FilteredChunk>, SessionError> {
    let (sample, compression) = reply_encoding(req);
    let (w, h) = f.color[0].size();
    let planes = f.color.each_ref().map(|p| p.data());
    let place = region.zip(req.shared_memory.as_ref());
    let (bytes, byte_length) = match place {
        Some((r, at)) if in_host_order(sample as i32, pb::Compression::None as i32) => {
            // The planes' bytes are the wire's samples: written without a staging copy.
            let plane_bytes = (w * h * 4) as u64;
            for (k, p) in (0..).zip(planes) {
                r.write_from(
                    f.index,
                    at.reply_offset + k * plane_bytes,
                    bytemuck::cast_slice(p),
                )?;
            }
            (Bytes::new(), 3 * plane_bytes as usize)
        }
        Some((r, at)) => {
            let len = 3 * w * h * sample_bytes(sample);
            r.write(f.index, at.reply_offset, len, |buf| {
                put_planes(&planes, sample, buf)
            })?;
            (Bytes::new(), len)
        }
        None => match buffer.filter(|_| compression == pb::Compression::None) {
            Some(b) => {
                let bytes = b.lend(3 * w * h * sample_bytes(sample), |buf| {
                    put_planes(&planes, sample, buf)
                });
                let len = bytes.len();
                (bytes, len)
            }
            None => {
                let bytes = wire::encode_planes(&planes, sample, compression);
                let len = bytes.len();
                (Bytes::from(bytes), len)
            }
        },
    };
    let r = &f.record;
    let report = pb::FrameReport {
        index: f.index,
        total_ms: r.total_ms,
        stages: r
            .stages
            .iter()
            .map(|s| pb::StageTime {
                name: s.name.into(),
                ms: s.ms,
                skipped: s.skipped.as_ref().map_or(String::new(), |w| w.to_string()),
            })
            .collect(),
        history_reset: r.pixels.history_reset,
        history_rejected: r.pixels.history_rejected,
        history_clipped: r.pixels.history_clipped,
        non_finite_input: r.input.non_finite,
        negative_input: r.input.negative,
        state_bytes: r.state_bytes as u64,
        psnr: f.psnr,
        ssim: f.ssim,
        record_json: serde_json::to_string(r).unwrap_or_default(),
        server_ms,
    };
    let header = pb::FilteredHeader {
        session_id: session_id.into(),
        index: f.index,
        width: w as u32,
        height: h as u32,
        color: Some(pb::ChannelHeader {
            name: "color".into(),
            sample: sample as i32,
            compression: if place.is_some() {
                pb::Compression::None
            } else {
                compression
            } as i32,
            byte_length: byte_length as u64,
        }),
        report: Some(report),
        shared_memory: place.map(|(_, at)| *at),
    };
    let mut out = vec![pb::FilteredChunk {
        part: Some(filtered_chunk::Part::Header(header)),
    }];
    out.extend(
        wire::chunks(bytes, max_chunk)
            .into_iter()
            .map(|d| pb::FilteredChunk {
                part: Some(filtered_chunk::Part::Data(d)),
            }),
    );
    Ok(out)
}

/// The gRPC service.
#[derive(Clone)]
pub struct Grpc(pub Service);

impl Grpc {
    /// As a tonic server, with message limits that fit the chunking.
    pub fn server(self) -> AfterimageServer<Grpc> {
        let limit = self.message_limit();
        AfterimageServer::new(self)
            .max_decoding_message_size(limit)
            .max_encoding_message_size(limit)
    }

    /// Largest message either way: a chunk and its framing, at least 4 MiB (gRPC's
    /// default, so session requests with many parameters still fit).
    pub(crate) fn message_limit(&self) -> usize {
        (self.0.config.max_chunk_bytes + (64 << 10)).max(4 << 20)
    }

    /// The caller named by a request's `authorization` metadata.
    fn caller(&self, md: &MetadataMap) -> Result<Caller, Status> {
        let value = md
            .get("authorization")
            .map(|v| v.to_str().unwrap_or("(not text)"));
        self.0.caller(value).map_err(|e| status(&e))
    }

    /// `r` counted as [`Service::count`] does, an error as its status.
    fn counted<T>(&self, r: Result<T, SessionError>) -> Result<T, Status> {
        self.0.count(r).map_err(|e| status(&e))
    }
}

/// `grpc.health.v1.Health` for the server (`""`) and `afterimage.v1.Afterimage`: SERVING
/// until the service starts draining, NOT_SERVING from then on (as `/readyz` turns 503).
/// Open to every caller, with or without a key (the checks of Kubernetes' gRPC probes and
/// of `grpc_health_probe` send none): only [`Grpc`]'s own calls are authenticated. When
/// `closed` turns true the statuses are cleared, which ends open `Watch` streams so they
/// do not hold the shutdown up.
pub async fn health(service: &Service, mut closed: watch::Receiver<bool>) -> HealthServer<impl Health> {
    let (mut reporter, server) = tonic_health::server::health_reporter();
    reporter.set_serving::<AfterimageServer<Grpc>>().await;
    let mut draining = service.draining();
    tokio::spawn(async move {
        let _ = draining.wait_for(|d| *d).await;
        for name in HEALTH_NAMES {
            reporter.set_service_status(name, ServingStatus::NotServing).await;
        }
        let _ = closed.wait_for(|c| *c).await;
        for name in HEALTH_NAMES {
            reporter.clear_service_status(name).await;
        }
    });
    server
}

/// The names health answers for: the whole server and the service.
const HEALTH_NAMES: [&str; 2] = ["", <AfterimageServer<Grpc> as tonic::server::NamedService>::NAME];

/// The v1 and v1alpha reflection services, describing `afterimage.v1` and
/// `grpc.health.v1` (and themselves), for `grpcurl` and other tools that list and call a
/// server's methods without the .proto files.
#[allow(clippy::type_complexity)]
pub fn reflection() -> Result<
    (
        v1::ServerReflectionServer<impl v1::ServerReflection>,
        v1alpha::ServerReflectionServer<impl v1alpha::ServerReflection>,
    ),
    tonic_reflection::server::Error,
> {
    let builder = || {
        tonic_reflection::server::Builder::configure()
            .register_encoded_file_descriptor_set(pb::FILE_DESCRIPTOR_SET)
            .register_encoded_file_descriptor_set(tonic_health::pb::FILE_DESCRIPTOR_SET)
    };
    Ok((builder().build_v1()?, builder().build_v1alpha()?))
}

type ReplyStream = Pin<Box<dyn Stream<Item = Result<pb::FilteredChunk, Status>> + Send>>;

/// Sends the replies of one frame (or of a flush) in order, or its error; false when the
/// stream is over (the error sent, or the client gone).
async fn send_replies(
    tx: &mpsc::Sender<Result<pb::FilteredChunk, Status>>,
    replies: Result<Vec<Vec<pb::FilteredChunk>>, SessionError>,
) -> bool {
    match replies {
        Ok(replies) => {
            for c in replies.into_iter().flatten() {
                // A full queue waits here: a client that does not read its replies stops
                // us reading its frames (flow control, bounded memory).
                if tx.send(Ok(c)).await.is_err() {
                    return false;
                }
            }
            true
        }
        Err(e) => {
            let _ = tx.send(Err(status(&e))).await;
            false
        }
    }
}

/// A frame being received: its chunks so far, the memory it may take, and its place in
/// the requests in flight.
struct Receiving {
    assembly: Assembly,
    /// When its header came: the whole frame must arrive within the request timeout.
    started: Instant,
    _hold: Reservation,
    _in_flight: InFlight,
}

/// Checks a frame header against the stream's session (claiming the session with the
/// first header) and reserves what the frame will take: its wire bytes, the decoded frame,
/// the output and the reply.
fn start_frame(
    svc: &Service,
    caller: &Caller,
    claim: &mut Option<StreamClaim>,
    h: pb::FrameHeader,
    spare: &mut Scratch,
) -> Result<Receiving, SessionError> {
    if svc.sessions.is_closing() {
        return Err(SessionError::ShuttingDown);
    }
    let claimed = match claim.take() {
        Some(c) if c.id() == h.session_id => c,
        Some(c) => {
            let e = SessionError::invalid(
                "header.session_id",
                format!(
                    "this stream serves session {}, got a frame for {}; open one stream per session",
                    c.id(),
                    clip(&h.session_id)
                ),
            );
            *claim = Some(c);
            return Err(e);
        }
        None => svc.sessions.attach(caller, &h.session_id)?,
    };
    let shape = claimed.shape();
    let region = claimed.region();
    *claim = Some(claimed);
    let plan = FramePlan::check(&h, shape, svc.config.max_frame_mib << 20)?;
    let mut assembly = match h.shared_memory {
        None => Assembly::start(h, plan),
        Some(at) => {
            let r = region.ok_or_else(|| {
                SessionError::invalid(
                    "header.shared_memory",
                    format!(
                        "frame {}: session {} has no shared memory region; open one (OpenRegion) first",
                        h.index, h.session_id
                    ),
                )
            })?;
            let (sample, compression) = reply_encoding(&h);
            if compression != pb::Compression::None {
                return Err(SessionError::invalid(
                    "header.reply_compression",
                    "a reply in shared memory is written uncompressed; expected COMPRESSION_NONE",
                ));
            }
            let reply_len = 3 * shape.pixels() * sample_bytes(sample) as u64;
            r.check(
                h.index,
                (at.offset, plan.wire_bytes),
                (at.reply_offset, reply_len),
            )?;
            Assembly::in_region(h, plan, at.offset)
        }
    };
    let bytes = assembly.plan.wire_bytes + assembly.plan.decoded_bytes + 2 * shape.output_bytes();
    let hold = svc
        .sessions
        .reserve(caller, bytes, &format!("frame {}", assembly.header.index))?;
    assembly.land(spare);
    Ok(Receiving {
        assembly,
        started: Instant::now(),
        _hold: hold,
        _in_flight: svc.begin(),
    })
}

/// Every output as a reply built by `finish` (given it and the server time in ms, shared
/// by the outputs); each output is counted and its planes go back to the filter.
fn replies_of<R>(
    svc: &Service,
    co: &mut Checkout,
    outs: Vec<Filtered>,
    t: Instant,
    finish: impl Fn(&Filtered, f64) -> R,
) -> Vec<R> {
    let ms = t.elapsed().as_secs_f64() * 1e3;
    outs.into_iter()
        .map(|out| {
            let r = finish(&out, ms);
            svc.metrics.frame(&out.record);
            co.recycle(out.color);
            r
        })
        .collect()
}

/// The replies to one frame (or a flush), in order, or why the stream stops.
type Replies = Result<Vec<Vec<pb::FilteredChunk>>, SessionError>;

/// The stream's replies as tonic sends them.
type ReplyTx = mpsc::Sender<Result<pb::FilteredChunk, Status>>;

/// A frame's filtering and the sending of its replies, in progress: true when the stream
/// goes on. Dropping it before it ends cancels the job (see [`Service::on_pool_as`]).
type Filtering = Pin<Box<dyn Future<Output = bool> + Send>>;

/// What a stream's frames hand back for the next ones: the planes a landed frame (see
/// [`Assembly::land`]) was decoded into, once the filter is done with them, and the
/// replies' buffer.
#[derive(Clone)]
struct Recycle {
    planes: sync_mpsc::Sender<Vec<Plane<f32>>>,
    reply: ReplyBuffer,
}

/// Decodes, filters and answers one complete frame on the pool, then sends its replies.
/// The future owns what it needs, so the stream goes on receiving the next frame while it
/// runs, and while the replies go out (a client sends its next frame before it reads them).
fn filter_job(
    svc: &Service,
    caller: &Caller,
    claim: &StreamClaim,
    frame: Receiving,
    tx: &ReplyTx,
    recycle: &Recycle,
) -> Filtering {
    let max_chunk = svc.config.max_chunk_bytes;
    let co = svc.count(claim.checkout());
    let shape = claim.shape();
    let region = claim.region();
    let share = svc.share(caller, claim.id(), shape);
    let (svc, tx, recycle) = (svc.clone(), tx.clone(), recycle.clone());
    Box::pin(async move {
        let replies: Replies = match co {
            Err(e) => Err(e),
            Ok(co) => {
                let req = frame.assembly.header.clone();
                let job = svc.clone();
                svc.on_pool_as(share, move |_| {
                    let t = Instant::now();
                    let (mut co, mut frame) = (co, frame);
                    let region = region
                        .as_deref()
                        .filter(|_| frame.assembly.region_offset().is_some());
                    // f32 straight from the region into the planes; else through a buffer.
                    let in_place = region.filter(|_| wire::reads_in_place(&req));
                    let staged = region.filter(|_| in_place.is_none());
                    if let (Some(r), Some(at)) = (staged, frame.assembly.region_offset()) {
                        let len = frame.assembly.plan.wire_bytes as usize;
                        frame.assembly.fill(r.read(req.index, at, len)?);
                    }
                    let landed = frame.assembly.is_landed();
                    let decoded = wire::decode(&mut frame.assembly, shape, co.input_planes()?, in_place);
                    if let Some(r) = staged {
                        r.recycle(frame.assembly.take_buffer());
                    }
                    drop(frame);
                    let outs = co.process_decoded(decoded?, MotionInput::Session)?;
                    if landed {
                        // The stream lands its next frames in them; gone with the stream.
                        let _ = recycle.planes.send(co.input_planes()?.drain());
                    }
                    let buffer = Some(&recycle.reply);
                    let finish = |f: &Filtered, ms: f64| {
                        reply(f, &req.session_id, &req, ms, max_chunk, region, buffer)
                    };
                    replies_of(&job, &mut co, outs, t, finish).into_iter().collect()
                })
                .await
            }
        };
        send_replies(&tx, replies).await
    })
}

/// Runs `job` to its end unless the client goes away first (then the window's outputs are
/// dropped, see [`abandon`]); true when the stream goes on.
async fn settle(svc: &Service, claim: Option<&StreamClaim>, job: Filtering, tx: &ReplyTx) -> bool {
    tokio::select! {
        ok = job => ok,
        _ = tx.closed() => {
            abandon(svc, claim);
            false
        }
    }
}

/// The outputs a windowed filter still holds when its stream ends, as replies encoded
/// like the last frame's.
async fn flush_stream(
    svc: &Service,
    caller: &Caller,
    claim: &StreamClaim,
    req: pb::FrameHeader,
    max_chunk: usize,
) -> Result<Vec<Vec<pb::FilteredChunk>>, SessionError> {
    let co = svc.count(claim.checkout())?;
    let job = svc.clone();
    svc.on_pool_as(svc.share(caller, claim.id(), claim.shape()), move |_| {
        let t = Instant::now();
        let mut co = co;
        let outs = co.flush()?;
        // A flush's outputs have no frame of their own to take a place in the region.
        let finish = |f: &Filtered, ms: f64| reply(f, &req.session_id, &req, ms, max_chunk, None, None);
        replies_of(&job, &mut co, outs, t, finish).into_iter().collect()
    })
    .await
}

/// Starts a Stream call whose metadata is `md` and whose messages `inbound` gives: the
/// caller checked, then the call served in a task of its own; the replies, ended by an
/// error status when the call fails. tonic's `stream` and [`crate::stream_route`] both
/// come here.
pub(crate) fn open_stream<S>(
    grpc: &Grpc,
    md: &MetadataMap,
    inbound: S,
) -> Result<mpsc::Receiver<Result<pb::FilteredChunk, Status>>, Status>
where
    S: Stream<Item = Result<pb::FrameChunk, Status>> + Unpin + Send + 'static,
{
    let caller = grpc.caller(md)?;
    let (tx, rx) = mpsc::channel(grpc.0.config.queue_depth);
    tokio::spawn(handle_stream(
        grpc.0.clone(),
        caller,
        grpc.message_limit(),
        inbound,
        tx,
    ));
    Ok(rx)
}

async fn handle_stream<S>(
    svc: Service,
    caller: Caller,
    message_limit: usize,
    mut inbound: S,
    tx: mpsc::Sender<Result<pb::FilteredChunk, Status>>,
) where
    S: Stream<Item = Result<pb::FrameChunk, Status>> + Unpin,
{
    let max_chunk = svc.config.max_chunk_bytes;
    let frame_timeout = Duration::from_secs(svc.config.request_timeout_s);
    let idle = Duration::from_secs(svc.config.idle_connection_timeout_s);
    let mut draining = svc.draining();
    let mut claim: Option<StreamClaim> = None;
    let mut current: Option<Receiving> = None;
    // The last frame's header: how the replies a flush gives are encoded.
    let mut last_header: Option<pb::FrameHeader> = None;
    let fail = |e: SessionError| {
        svc.metrics.error(e.reason());
        tracing::debug!(error = %e, "stream refused");
        Err(status(&e))
    };
    // Two frames in flight at most: one filtering while the next is received (and held,
    // complete, until the filter is free); both hold their memory reservations.
    let mut filtering: Option<Filtering> = None;
    let mut ready: Option<Receiving> = None;
    let (planes_back, landed_planes) = sync_mpsc::channel();
    let recycle = Recycle {
        planes: planes_back,
        reply: ReplyBuffer::default(),
    };
    let mut spare = Scratch::default();
    loop {
        // Only a stream with nothing in flight is idle, or may be ended by a drain.
        let quiet = filtering.is_none() && ready.is_none();
        let wait = tokio::select! {
            ok = async { filtering.as_mut().expect("checked").await }, if filtering.is_some() => {
                filtering = None;
                if !ok {
                    return;
                }
                if let Some(frame) = ready.take() {
                    let claimed = claim.as_ref().expect("claimed with the header");
                    filtering = Some(filter_job(&svc, &caller, claimed, frame, &tx, &recycle));
                }
                continue;
            }
            _ = tx.closed(), if !quiet => {
                abandon(&svc, claim.as_ref());
                return;
            }
            w = next_message(&mut inbound, current.as_ref(), frame_timeout, idle, &mut draining, quiet), if ready.is_none() => w,
        };
        let next = match wait {
            Wait::Message(m) => m,
            Wait::Draining => {
                let _ = tx.send(Err(status(&SessionError::ShuttingDown))).await;
                return;
            }
            Wait::Refuse(e) => {
                let _ = tx.send(fail(e)).await;
                return;
            }
        };
        let chunk = match next {
            None => break,
            Some(Ok(c)) => c,
            Some(Err(s)) if s.code() == Code::OutOfRange => {
                let e = SessionError::too_large(
                    "data",
                    format!(
                        "a message over the server's limit of {message_limit} bytes ({}); send DataChunks of at most max_chunk_bytes = {max_chunk}",
                        s.message()
                    ),
                );
                tracing::warn!(error = %e, "stream refused");
                let _ = tx.send(fail(e)).await;
                return;
            }
            Some(Err(s)) => {
                // Cancelled or reset, or a message that could not be read: nobody takes the
                // window's outputs, so they go now. The status goes to a client that still
                // listens (a reset one has dropped the replies, and the send fails at once).
                tracing::debug!(status = %s, "client stream ended with an error");
                let _ = tx.send(Err(s)).await;
                drop(filtering.take());
                abandon(&svc, claim.as_ref());
                return;
            }
        };
        let header = match (&chunk.part, &filtering) {
            (Some(frame_chunk::Part::Header(_)), Some(_)) => Some(chunk.clone()),
            _ => None,
        };
        spare.recycle(landed_planes.try_iter().flatten());
        let mut step = take_chunk(
            &svc,
            &caller,
            &mut claim,
            &mut current,
            chunk,
            max_chunk,
            &mut spare,
        );
        if let (Err(SessionError::Exhausted(_)), Some(header)) = (&step, header) {
            // No memory for a second frame in flight: the one filtering finishes (and
            // gives its memory back) before this one is received.
            let job = filtering.take().expect("checked");
            if !settle(&svc, claim.as_ref(), job, &tx).await {
                return;
            }
            step = take_chunk(
                &svc,
                &caller,
                &mut claim,
                &mut current,
                header,
                max_chunk,
                &mut spare,
            );
        }
        if let Err(e) = step {
            let _ = tx.send(fail(e)).await;
            return;
        }
        if current.as_ref().is_some_and(|r| r.assembly.complete()) {
            let frame = current.take().expect("checked");
            last_header = Some(frame.assembly.header.clone());
            if filtering.is_some() {
                ready = Some(frame);
            } else {
                let claimed = claim.as_ref().expect("claimed with the header");
                filtering = Some(filter_job(&svc, &caller, claimed, frame, &tx, &recycle));
            }
        }
    }
    if let Some(r) = current {
        let e = SessionError::invalid(
            "data",
            format!(
                "the stream ended with frame {} missing {} bytes",
                r.assembly.header.index,
                r.assembly.missing()
            ),
        );
        let _ = tx.send(fail(e)).await;
        return;
    }
    finish_stream(
        &svc,
        &caller,
        claim.as_ref(),
        (filtering, ready),
        last_header,
        &tx,
        &recycle,
    )
    .await;
}

/// The end of a stream the client closed cleanly: the frames in flight are answered in
/// order, then a windowed filter's last frames come out.
async fn finish_stream(
    svc: &Service,
    caller: &Caller,
    claim: Option<&StreamClaim>,
    (mut filtering, mut ready): (Option<Filtering>, Option<Receiving>),
    last_header: Option<pb::FrameHeader>,
    tx: &ReplyTx,
    recycle: &Recycle,
) {
    let max_chunk = svc.config.max_chunk_bytes;
    while let Some(job) = filtering.take() {
        if !settle(svc, claim, job, tx).await {
            return;
        }
        if let Some(frame) = ready.take() {
            let claimed = claim.expect("claimed with the header");
            filtering = Some(filter_job(svc, caller, claimed, frame, tx, recycle));
        }
    }
    // A windowed filter's last frames.
    if let (Some(claimed), Some(req)) = (claim, last_header) {
        // A client that resets the call now (it left) stops the flush between frames.
        tokio::select! {
            r = flush_stream(svc, caller, claimed, req, max_chunk) => {
                send_replies(tx, r).await;
            }
            // A reset that arrives as the end of the request stream: what the flush had
            // not given yet waits for nobody either.
            _ = tx.closed() => abandon(svc, claim),
        }
    }
}

/// How waiting for a stream's next message ended.
enum Wait {
    /// A message, the end of the stream (`None`) or the transport's error.
    Message(Option<Result<pb::FrameChunk, Status>>),
    /// The server is draining and no frame is half received.
    Draining,
    /// A frame did not arrive whole within the request timeout, or no frame began within
    /// the idle timeout.
    Refuse(SessionError),
}

/// Waits for the stream's next message: within the request timeout while a frame is half
/// received (however it is chunked); between frames of a `quiet` stream (nothing in
/// flight) within the idle timeout or until the server drains.
async fn next_message<S: Stream<Item = Result<pb::FrameChunk, Status>> + Unpin>(
    inbound: &mut S,
    current: Option<&Receiving>,
    frame_timeout: Duration,
    idle: Duration,
    draining: &mut watch::Receiver<bool>,
    quiet: bool,
) -> Wait {
    match current {
        Some(r) => match tokio::time::timeout_at((r.started + frame_timeout).into(), inbound.next()).await {
            Ok(m) => Wait::Message(m),
            Err(_) => Wait::Refuse(SessionError::invalid(
                "data",
                format!(
                    "frame {}: {} bytes still missing after the request timeout of {} s",
                    r.assembly.header.index,
                    r.assembly.missing(),
                    frame_timeout.as_secs()
                ),
            )),
        },
        None if !quiet => Wait::Message(inbound.next().await),
        None => tokio::select! {
            m = inbound.next() => Wait::Message(m),
            _ = until_true(draining) => Wait::Draining,
            _ = tokio::time::sleep(idle) => Wait::Refuse(SessionError::invalid(
                "stream",
                format!(
                    "no frame for idle_connection_timeout_s = {} s; open a new stream to go on",
                    idle.as_secs()
                ),
            )),
        },
    }
}

/// Takes one chunk of the stream: a header starts a frame (claiming the session with the
/// first), data goes into the frame being received; out of order is refused.
fn take_chunk(
    svc: &Service,
    caller: &Caller,
    claim: &mut Option<StreamClaim>,
    current: &mut Option<Receiving>,
    chunk: pb::FrameChunk,
    max_chunk: usize,
    spare: &mut Scratch,
) -> Result<(), SessionError> {
    match chunk.part {
        Some(frame_chunk::Part::Header(h)) => match current {
            Some(r) => Err(SessionError::invalid(
                "header",
                format!(
                    "chunk out of order: a header for frame {} while frame {} still misses {} bytes",
                    h.index,
                    r.assembly.header.index,
                    r.assembly.missing()
                ),
            )),
            None => start_frame(svc, caller, claim, h, spare).map(|r| *current = Some(r)),
        },
        Some(frame_chunk::Part::Data(d)) => match current.as_mut() {
            None => Err(SessionError::invalid(
                "data",
                "chunk out of order: data before any frame header (or after the header of a frame in the shared memory region, which no DataChunk follows)",
            )),
            Some(r) => r.assembly.push(d.data, max_chunk),
        },
        None => Err(SessionError::invalid(
            "part",
            "an empty FrameChunk (neither header nor data)",
        )),
    }
}

/// Drops the frames a windowed filter holds for a client that left mid-sequence (see
/// [`Checkout::abandon`]): their outputs would wait for nobody. A causal filter's history
/// stays, so a client that reconnects goes on where it was.
fn abandon(svc: &Service, claim: Option<&StreamClaim>) {
    svc.metrics.error(SessionError::Cancelled.reason());
    if let Some(mut co) = claim.and_then(|c| c.checkout().ok()) {
        if co.lookahead() > 0 {
            let _ = co.abandon();
        }
    }
}

#[tonic::async_trait]
impl Afterimage for Grpc {
    async fn list_filters(
        &self,
        req: Request<pb::ListFiltersRequest>,
    ) -> Result<Response<pb::ListFiltersResponse>, Status> {
        self.caller(req.metadata())?;
        Ok(Response::new(pb::ListFiltersResponse {
            filters: filters_pb(),
        }))
    }

    async fn create_session(
        &self,
        req: Request<pb::CreateSessionRequest>,
    ) -> Result<Response<pb::Session>, Status> {
        let caller = self.caller(req.metadata())?;
        let r = req.into_inner();
        let mut params: Vec<(String, String)> = r.params.into_iter().collect();
        params.sort();
        let req = SessionRequest {
            filter: r.filter,
            params,
            width: r.width,
            height: r.height,
            motion: r.motion,
            channels: r.channels,
            backend: r.backend,
        };
        // On the pool: a GPU session opens the device and compiles its shaders (up to
        // seconds the first time), which must not hold a tokio worker.
        let info = self
            .0
            .on_pool(move |s| s.create(&caller, &req))
            .await
            .map_err(|e| status(&e))?;
        Ok(Response::new(session_pb(info, self.0.config.max_chunk_bytes)))
    }

    async fn get_session(
        &self,
        req: Request<pb::GetSessionRequest>,
    ) -> Result<Response<pb::Session>, Status> {
        let caller = self.caller(req.metadata())?;
        let info = self.counted(self.0.sessions.get(&caller, &req.into_inner().id))?;
        Ok(Response::new(session_pb(info, self.0.config.max_chunk_bytes)))
    }

    async fn close_session(
        &self,
        req: Request<pb::CloseSessionRequest>,
    ) -> Result<Response<pb::CloseSessionResponse>, Status> {
        let caller = self.caller(req.metadata())?;
        let frames = self.counted(self.0.sessions.close(&caller, &req.into_inner().id))?;
        Ok(Response::new(pb::CloseSessionResponse { frames }))
    }

    async fn open_region(&self, req: Request<pb::OpenRegionRequest>) -> Result<Response<pb::Region>, Status> {
        let caller = self.caller(req.metadata())?;
        let r = req.into_inner();
        let id = r.session_id.clone();
        // On the pool: it creates and sizes a file.
        let region = self
            .0
            .on_pool(move |s| s.open_region(&caller, &r.session_id, r.bytes))
            .await
            .map_err(|e| status(&e))?;
        Ok(Response::new(pb::Region {
            session_id: id,
            path: region.path().to_string_lossy().into_owned(),
            bytes: region.bytes(),
        }))
    }

    type StreamStream = ReplyStream;

    async fn stream(
        &self,
        req: Request<Streaming<pb::FrameChunk>>,
    ) -> Result<Response<Self::StreamStream>, Status> {
        let md = req.metadata().clone();
        let rx = open_stream(self, &md, req.into_inner())?;
        Ok(Response::new(Box::pin(ReceiverStream::new(rx))))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_reply_buffer_comes_back_when_its_last_chunk_is_dropped() {
        let pool = ReplyBuffer::default();
        let bytes = pool.lend(10, |b| b.copy_from_slice(b"0123456789"));
        let at = bytes.as_ptr();
        let chunks = wire::chunks(bytes, 4);
        assert_eq!(chunks.iter().map(|c| c.data.len()).collect::<Vec<_>>(), [4, 4, 2]);
        assert_eq!(&chunks[2].data[..], b"89");
        let first = chunks[0].clone();
        drop(chunks);
        // One chunk still out: the buffer is lent, so another reply takes memory of its own.
        let other = pool.lend(10, |b| b.fill(7));
        assert_ne!(other.as_ptr(), at);
        assert_eq!((&first.data[..], &other[..]), (&b"0123"[..], &[7u8; 10][..]));
        drop(other);
        drop(first);
        // Every chunk sent: the next reply is written where the first was.
        let again = pool.lend(10, |b| b.fill(1));
        assert_eq!(again.as_ptr(), at);
        assert_eq!(&again[..], &[1; 10]);
    }
}
