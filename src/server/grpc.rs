//! The gRPC layer (tonic): a thin adapter from the proto messages to [`Service`].

use super::proto::afterimage_server::{Afterimage, AfterimageServer};
use super::proto::{self as pb, filtered_chunk, frame_chunk};
use super::service::Service;
use super::wire::{self, Assembly};
use crate::pipeline::{self, ParamKind};
use crate::session::{ErrorKind, Filtered, SessionError, SessionInfo, SessionRequest};
use std::pin::Pin;
use tokio::sync::mpsc;
use tokio_stream::{wrappers::ReceiverStream, Stream, StreamExt};
use tonic::{Request, Response, Status, Streaming};

/// The status for a session error.
pub fn status(e: &SessionError) -> Status {
    let msg = e.to_string();
    match e.kind() {
        ErrorKind::InvalidArgument => Status::invalid_argument(msg),
        ErrorKind::NotFound => Status::not_found(msg),
        ErrorKind::ResourceExhausted => Status::resource_exhausted(msg),
        ErrorKind::FailedPrecondition => Status::failed_precondition(msg),
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
    }
}

/// The proto description of every filter.
pub fn filters_pb() -> Vec<pb::FilterInfo> {
    pipeline::list()
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

/// The reply to one filtered frame: a header, then the colour in chunks.
pub fn reply(
    f: &Filtered,
    session_id: &str,
    req: &pb::FrameHeader,
    server_ms: f64,
    max_chunk: usize,
) -> Vec<pb::FilteredChunk> {
    let sample = pb::SampleType::try_from(req.reply_sample).unwrap_or(pb::SampleType::F32);
    let sample = if sample == pb::SampleType::U32 {
        pb::SampleType::F32
    } else {
        sample
    };
    let compression = pb::Compression::try_from(req.reply_compression).unwrap_or(pb::Compression::None);
    let (w, h) = f.color[0].size();
    let bytes = wire::encode_planes(&f.color, sample, compression);
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
            compression: compression as i32,
            byte_length: bytes.len() as u64,
        }),
        report: Some(report),
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
    out
}

/// The gRPC service.
#[derive(Clone)]
pub struct Grpc(pub Service);

impl Grpc {
    /// As a tonic server, with message limits that fit the chunking.
    pub fn server(self) -> AfterimageServer<Grpc> {
        let limit = self.0.config.max_chunk_bytes + (64 << 10);
        AfterimageServer::new(self)
            .max_decoding_message_size(limit.max(4 << 20))
            .max_encoding_message_size(limit.max(4 << 20))
    }
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
            tracing::debug!(error = %e, "frame refused");
            let _ = tx.send(Err(status(&e))).await;
            false
        }
    }
}

async fn handle_stream(
    svc: Service,
    mut inbound: Streaming<pb::FrameChunk>,
    tx: mpsc::Sender<Result<pb::FilteredChunk, Status>>,
) {
    let max_chunk = svc.config.max_chunk_bytes;
    let max_frame = svc.config.max_frame_mib << 20;
    let mut current: Option<Assembly> = None;
    let mut stream_session: Option<String> = None;
    // The last frame's header: how the replies a flush gives are encoded.
    let mut last_header: Option<pb::FrameHeader> = None;
    let fail = |e: SessionError| {
        svc.metrics.error(e.reason());
        tracing::debug!(error = %e, "stream refused");
        Err(status(&e))
    };
    while let Some(msg) = inbound.next().await {
        let chunk = match msg {
            Ok(c) => c,
            Err(s) => {
                tracing::debug!(status = %s, "client stream ended with an error");
                return;
            }
        };
        let step: Result<(), SessionError> = match chunk.part {
            Some(frame_chunk::Part::Header(h)) => {
                if let Some(a) = &current {
                    Err(SessionError::invalid(
                        "header",
                        format!(
                            "chunk out of order: a header for frame {} while frame {} still misses {} bytes",
                            h.index,
                            a.header.index,
                            a.missing()
                        ),
                    ))
                } else if stream_session.as_ref().is_some_and(|s| *s != h.session_id) {
                    Err(SessionError::invalid(
                        "header.session_id",
                        format!(
                            "this stream serves session {}, got a frame for {}; open one stream per session",
                            stream_session.as_deref().unwrap_or_default(),
                            h.session_id
                        ),
                    ))
                } else {
                    // Unknown ids are refused here, before any data is read.
                    match svc.sessions.frame_shape(&h.session_id) {
                        Err(e) => Err(e),
                        Ok(_) => {
                            stream_session = Some(h.session_id.clone());
                            Assembly::start(h, max_frame).map(|a| current = Some(a))
                        }
                    }
                }
            }
            Some(frame_chunk::Part::Data(d)) => match current.as_mut() {
                None => Err(SessionError::invalid(
                    "data",
                    "chunk out of order: data before any frame header",
                )),
                Some(a) => a.push(&d.data, max_chunk),
            },
            None => Err(SessionError::invalid(
                "part",
                "an empty FrameChunk (neither header nor data)",
            )),
        };
        if let Err(e) = step {
            let _ = tx.send(fail(e)).await;
            return;
        }
        if current.as_ref().is_some_and(Assembly::complete) {
            let a = current.take().expect("checked");
            let req = a.header.clone();
            last_header = Some(req.clone());
            let finish = move |f: &Filtered, ms: f64| reply(f, &req.session_id, &req, ms, max_chunk);
            if !send_replies(&tx, svc.wire_frame(a, finish).await).await {
                return;
            }
        }
    }
    // The client closed its side: a windowed filter's last frames come out now.
    if let (None, Some(req)) = (&current, last_header) {
        let id = req.session_id.clone();
        let finish = move |f: &Filtered, ms: f64| reply(f, &req.session_id, &req, ms, max_chunk);
        if !send_replies(&tx, svc.wire_flush(id, finish).await).await {
            return;
        }
    }
    if let Some(a) = current {
        let e = SessionError::invalid(
            "data",
            format!(
                "the stream ended with frame {} missing {} bytes",
                a.header.index,
                a.missing()
            ),
        );
        let _ = tx.send(fail(e)).await;
    }
}

#[tonic::async_trait]
impl Afterimage for Grpc {
    async fn list_filters(
        &self,
        _: Request<pb::ListFiltersRequest>,
    ) -> Result<Response<pb::ListFiltersResponse>, Status> {
        Ok(Response::new(pb::ListFiltersResponse {
            filters: filters_pb(),
        }))
    }

    async fn create_session(
        &self,
        req: Request<pb::CreateSessionRequest>,
    ) -> Result<Response<pb::Session>, Status> {
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
        };
        let info = self
            .0
            .count(self.0.sessions.create(&req))
            .map_err(|e| status(&e))?;
        Ok(Response::new(session_pb(info, self.0.config.max_chunk_bytes)))
    }

    async fn get_session(
        &self,
        req: Request<pb::GetSessionRequest>,
    ) -> Result<Response<pb::Session>, Status> {
        let info = self
            .0
            .count(self.0.sessions.get(&req.into_inner().id))
            .map_err(|e| status(&e))?;
        Ok(Response::new(session_pb(info, self.0.config.max_chunk_bytes)))
    }

    async fn close_session(
        &self,
        req: Request<pb::CloseSessionRequest>,
    ) -> Result<Response<pb::CloseSessionResponse>, Status> {
        let frames = self
            .0
            .count(self.0.sessions.close(&req.into_inner().id))
            .map_err(|e| status(&e))?;
        Ok(Response::new(pb::CloseSessionResponse { frames }))
    }

    type StreamStream = ReplyStream;

    async fn stream(
        &self,
        req: Request<Streaming<pb::FrameChunk>>,
    ) -> Result<Response<Self::StreamStream>, Status> {
        let (tx, rx) = mpsc::channel(self.0.config.queue_depth);
        tokio::spawn(handle_stream(self.0.clone(), req.into_inner(), tx));
        Ok(Response::new(Box::pin(ReceiverStream::new(rx))))
    }
}
