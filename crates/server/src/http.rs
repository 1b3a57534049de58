//! The HTTP layer (axum) over the same [`Service`]: JSON sessions, EXR frames, health,
//! readiness and Prometheus metrics. The router is built by [`router`] so tests can drive
//! it without a socket.
//!
//! A frame request takes its session before its body is read: an unknown, busy or failed
//! session, or a `Content-Length` larger than any EXR of the session's size, is answered
//! at once. The body is then read within the request timeout and a memory reservation,
//! and decoded, filtered and encoded on the rayon pool.

use super::activity::Held;
use super::service::Service;
use crate::filters;
use crate::io::{
    check_exr_header, encode_filtered, frame_and_input, read_raw_exr_bytes_limited, Compression,
    FilteredFrame, Keep, OutputOptions, Precision, ReadOptions,
};
use crate::session::{
    params_from_json, Caller, Checkout, ErrorKind, Filtered, KeptInput, MotionInput, Reservation,
    SessionError, SessionRequest,
};
use axum::body::{Body, Bytes};
use axum::extract::rejection::QueryRejection;
use axum::extract::{DefaultBodyLimit, FromRequestParts, Path, Query, State};
use axum::http::request::Parts;
use axum::http::{header, HeaderMap, HeaderValue, StatusCode};
use axum::response::{IntoResponse, Response};
use axum::routing::{get, post};
use axum::{Json, Router};
use http_body_util::BodyExt;
use serde::Deserialize;
use serde_json::{json, Map, Value};
use std::time::Duration;

/// Header of a frame reply carrying its report as JSON.
pub const RECORD_HEADER: &str = "x-afterimage-record";
/// Response header: outputs still queued for later requests (a windowed filter gives a
/// whole shot at once at a cut, or at a flush).
pub const READY_HEADER: &str = "x-afterimage-ready";
/// Request header: the frame's index (a whole number), over the file's `afterimage.index`.
/// Without either, the session numbers frames in the order it receives them.
pub const INDEX_HEADER: &str = "x-afterimage-index";
/// Request header: `1`/`true` when a new shot starts at this frame (the filter drops its
/// history), `0`/`false` when not; over the file's `afterimage.reset`.
pub const RESET_HEADER: &str = "x-afterimage-reset";
/// Request header: the frame's sub-pixel jitter `x,y` in pixels (each in -1..=1), over the
/// file's `afterimage.jitter`.
pub const JITTER_HEADER: &str = "x-afterimage-jitter";
/// Largest JSON body (session creation).
pub const MAX_JSON_BYTES: usize = 64 << 10;

/// An error as an HTTP response: status from its kind, JSON body naming the problem.
pub struct HttpError(pub SessionError);

impl From<SessionError> for HttpError {
    fn from(e: SessionError) -> Self {
        HttpError(e)
    }
}

impl IntoResponse for HttpError {
    fn into_response(self) -> Response {
        let code = match self.0.kind() {
            ErrorKind::InvalidArgument => StatusCode::BAD_REQUEST,
            ErrorKind::TooLarge => StatusCode::PAYLOAD_TOO_LARGE,
            ErrorKind::NotFound => StatusCode::NOT_FOUND,
            ErrorKind::ResourceExhausted => StatusCode::TOO_MANY_REQUESTS,
            ErrorKind::FailedPrecondition => StatusCode::CONFLICT,
            ErrorKind::Unauthenticated => StatusCode::UNAUTHORIZED,
            ErrorKind::Internal => StatusCode::INTERNAL_SERVER_ERROR,
            ErrorKind::Unavailable => StatusCode::SERVICE_UNAVAILABLE,
        };
        let field = match &self.0 {
            SessionError::Invalid { field, .. } | SessionError::TooLarge { field, .. } => {
                Value::String(field.clone())
            }
            _ => Value::Null,
        };
        let body =
            json!({"error": {"reason": self.0.reason(), "field": field, "message": self.0.client_message()}});
        let mut resp = (code, Json(body)).into_response();
        if code == StatusCode::UNAUTHORIZED {
            resp.headers_mut()
                .insert(header::WWW_AUTHENTICATE, HeaderValue::from_static("Bearer"));
        }
        resp
    }
}

type HttpResult<T> = Result<T, HttpError>;

fn counted<T>(svc: &Service, r: Result<T, SessionError>) -> HttpResult<T> {
    svc.count(r).map_err(HttpError)
}

/// The caller, from the `Authorization: Bearer KEY` header (anonymous on a server without
/// keys); 401 otherwise.
pub struct Auth(pub Caller);

impl FromRequestParts<Service> for Auth {
    type Rejection = HttpError;

    async fn from_request_parts(parts: &mut Parts, svc: &Service) -> Result<Self, HttpError> {
        let value = parts
            .headers
            .get(header::AUTHORIZATION)
            .map(|v| v.to_str().unwrap_or("(not text)"));
        svc.caller(value).map(Auth).map_err(HttpError)
    }
}

/// Body of `POST /v1/sessions`.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CreateBody {
    /// Filter name.
    pub filter: String,
    /// Parameter overrides.
    #[serde(default)]
    pub params: Map<String, Value>,
    /// Frame width.
    pub width: u32,
    /// Frame height.
    pub height: u32,
    /// Motion convention preset of the gRPC frames (HTTP frames carry their own in the
    /// EXR preset).
    #[serde(default)]
    pub motion: String,
    /// Channels that will be sent.
    #[serde(default)]
    pub channels: Vec<String>,
    /// Where the filter runs: cpu, gpu, auto, gpu-f16 or auto-f16 (default: the server's).
    #[serde(default)]
    pub backend: String,
}

async fn create(
    State(svc): State<Service>,
    Auth(caller): Auth,
    body: Result<Json<CreateBody>, axum::extract::rejection::JsonRejection>,
) -> HttpResult<Response> {
    let Json(b) = counted(
        &svc,
        body.map_err(|e| {
            let field = "body";
            if e.status() == StatusCode::PAYLOAD_TOO_LARGE {
                SessionError::too_large(field, format!("a JSON body is at most {MAX_JSON_BYTES} bytes"))
            } else {
                SessionError::invalid(field, e.body_text())
            }
        }),
    )?;
    let req = SessionRequest {
        filter: b.filter,
        params: params_from_json(&b.params),
        width: b.width,
        height: b.height,
        motion: b.motion,
        channels: b.channels,
        backend: b.backend,
    };
    // On the pool: a GPU session opens the device and compiles its shaders (up to seconds
    // the first time), which must not hold a tokio worker.
    let info = svc.on_pool(move |s| s.create(&caller, &req)).await?;
    Ok((StatusCode::CREATED, Json(info)).into_response())
}

async fn get_session(
    State(svc): State<Service>,
    Auth(caller): Auth,
    Path(id): Path<String>,
) -> HttpResult<Response> {
    Ok(Json(counted(&svc, svc.sessions.get(&caller, &id))?).into_response())
}

async fn delete_session(
    State(svc): State<Service>,
    Auth(caller): Auth,
    Path(id): Path<String>,
) -> HttpResult<Response> {
    let frames = counted(&svc, svc.sessions.close(&caller, &id))?;
    Ok(Json(json!({"id": id, "frames": frames})).into_response())
}

/// The media type of a session state file ([`crate::pipeline::state`]).
pub const STATE_MEDIA_TYPE: &str = "application/vnd.afterimage.state";

/// `GET /v1/sessions/{id}/state`: the session's filter state as a state file.
async fn get_state(
    State(svc): State<Service>,
    Auth(caller): Auth,
    Path(id): Path<String>,
) -> HttpResult<Response> {
    let info = counted(&svc, svc.sessions.get(&caller, &id))?;
    let co = counted(&svc, svc.sessions.checkout(&caller, &id))?;
    // The copy of the history and the file made from it.
    let hold = counted(
        &svc,
        svc.sessions.reserve(&caller, info.state_bytes, "a state export"),
    )?;
    let bytes = svc
        .on_pool(move |_| {
            let mut co = co;
            co.export_state()
        })
        .await?;
    Ok(([(header::CONTENT_TYPE, STATE_MEDIA_TYPE)], held_body(bytes, hold)).into_response())
}

/// `PUT /v1/sessions/{id}/state`: continue the session from a state file (a body of at
/// most the session's reserved state plus a header).
async fn put_state(
    State(svc): State<Service>,
    Auth(caller): Auth,
    Path(id): Path<String>,
    headers: HeaderMap,
    body: Body,
) -> HttpResult<Response> {
    let _in_flight = svc.begin();
    let early = svc.sessions.get(&caller, &id).and_then(|info| {
        let co = svc.sessions.checkout(&caller, &id)?;
        let declared = content_length(&headers)?;
        Ok((info, co, declared))
    });
    let (info, co, declared) = match early {
        Ok(v) => v,
        Err(e) => return refuse_early(&svc, &headers, body, e),
    };
    let max = info
        .state_bytes
        .saturating_add(crate::pipeline::state::MAX_HEADER_BYTES as u64 + 64);
    if let Some(n) = declared.filter(|&n| n > max) {
        return counted(
            &svc,
            Err(SessionError::too_large(
                "body",
                format!("{n} bytes, a state file for this session is at most {max} bytes"),
            )),
        );
    }
    // The body, and the planes decoded from it.
    let hold = counted(
        &svc,
        svc.sessions.reserve(
            &caller,
            declared.unwrap_or(max).saturating_mul(2),
            "a state import",
        ),
    )?;
    let bytes = counted(
        &svc,
        read_body(body, max, Duration::from_secs(svc.config.request_timeout_s)).await,
    )?;
    svc.on_pool(move |_| {
        let mut co = co;
        co.import_state(&bytes)
    })
    .await?;
    drop(hold);
    Ok(Json(counted(&svc, svc.sessions.get(&caller, &id))?).into_response())
}

/// The `Content-Length` a client declared, if any.
fn content_length(headers: &HeaderMap) -> Result<Option<u64>, SessionError> {
    headers
        .get(header::CONTENT_LENGTH)
        .map(|v| {
            v.to_str()
                .ok()
                .and_then(|s| s.trim().parse::<u64>().ok())
                .ok_or_else(|| SessionError::invalid("content-length", "not a whole number"))
        })
        .transpose()
}

/// Reads a body of at most `limit` bytes within `timeout`.
async fn read_body(body: Body, limit: u64, timeout: Duration) -> Result<Bytes, SessionError> {
    let limited = http_body_util::Limited::new(body, usize::try_from(limit).unwrap_or(usize::MAX));
    match tokio::time::timeout(timeout, limited.collect()).await {
        Err(_) => Err(SessionError::invalid(
            "body",
            format!(
                "not received within the request timeout of {} s",
                timeout.as_secs()
            ),
        )),
        Ok(Err(e)) if e.is::<http_body_util::LengthLimitError>() => Err(SessionError::too_large(
            "body",
            format!("more than the {limit} bytes this request can need for this session"),
        )),
        Ok(Err(e)) => Err(SessionError::invalid("body", format!("could not be read: {e}"))),
        Ok(Ok(c)) => Ok(c.to_bytes()),
    }
}

/// Answers a request refused before its body was read. A proxy in front (nginx) sends the
/// whole body before it reads the answer and turns a connection closed under it into 502,
/// so a body of at most `max_frame_mib` is read and dropped after the answer, in the
/// background, within the request timeout; a larger one is not read.
fn refuse_early(svc: &Service, headers: &HeaderMap, body: Body, e: SessionError) -> HttpResult<Response> {
    let cap = svc.config.max_frame_mib << 20;
    if content_length(headers).ok().flatten().is_some_and(|n| n <= cap) {
        let timeout = Duration::from_secs(svc.config.request_timeout_s);
        tokio::spawn(tokio::time::timeout(timeout, discard(body)));
    }
    counted(svc, Err(e))
}

/// Reads a body to its end, keeping nothing.
async fn discard(mut body: Body) {
    while let Some(Ok(_)) = body.frame().await {}
}

/// Bytes a reply body hands to the connection at a time: a client that stops reading holds
/// at most a window of them in the server's buffers, and the rest stays counted.
pub const REPLY_CHUNK_BYTES: usize = 256 << 10;

/// A reply body that keeps its memory reservation until the client has taken it: sent in
/// chunks of [`REPLY_CHUNK_BYTES`], so the last chunk is handed over (and the reservation
/// given back) only once the client has read the rest. A client that never reads is closed
/// by the connection's idle timeout, which frees it.
fn held_body(bytes: Vec<u8>, hold: Reservation) -> Body {
    Body::new(Held::new(
        Chunked {
            bytes: Bytes::from(bytes),
        },
        hold,
    ))
}

/// A body of `bytes` in chunks of [`REPLY_CHUNK_BYTES`].
struct Chunked {
    bytes: Bytes,
}

impl http_body::Body for Chunked {
    type Data = Bytes;
    type Error = std::convert::Infallible;

    fn poll_frame(
        mut self: std::pin::Pin<&mut Self>,
        _: &mut std::task::Context<'_>,
    ) -> std::task::Poll<Option<Result<http_body::Frame<Bytes>, Self::Error>>> {
        if self.bytes.is_empty() {
            return std::task::Poll::Ready(None);
        }
        let n = self.bytes.len().min(REPLY_CHUNK_BYTES);
        let chunk = self.bytes.split_to(n);
        std::task::Poll::Ready(Some(Ok(http_body::Frame::data(chunk))))
    }

    fn is_end_stream(&self) -> bool {
        self.bytes.is_empty()
    }

    fn size_hint(&self) -> http_body::SizeHint {
        http_body::SizeHint::with_exact(self.bytes.len() as u64)
    }
}

/// What a frame or flush request answers.
enum Reply {
    /// A filtered frame: EXR bytes, its record as JSON, outputs still queued.
    Exr {
        exr: Vec<u8>,
        record: String,
        left: usize,
    },
    /// Nothing came out yet (a windowed filter's window is filling).
    Accepted { index: u64, lookahead: u32 },
    /// Nothing is left (flush).
    Empty,
}

impl Reply {
    /// The response, keeping `hold` (grown to the reply's size when it is larger) until an
    /// EXR reply has been read.
    fn holding(self, mut hold: Reservation) -> Response {
        match self {
            Reply::Exr { exr, record, left } => {
                let more = (exr.len() as u64).saturating_sub(hold.bytes());
                // The reply exists already: counted whether it fits or not.
                hold.force_grow(more);
                let mut resp = (StatusCode::OK, held_body(exr, hold)).into_response();
                let h = resp.headers_mut();
                h.insert(header::CONTENT_TYPE, HeaderValue::from_static("image/x-exr"));
                if let Ok(v) = HeaderValue::from_str(&record) {
                    h.insert(RECORD_HEADER, v);
                }
                h.insert(READY_HEADER, HeaderValue::from(left));
                resp
            }
            Reply::Accepted { index, lookahead } => (
                StatusCode::ACCEPTED,
                Json(json!({
                    "accepted": index,
                    "lookahead": lookahead,
                    "message": format!("frame {index} is in the filter's window: its output comes after frame {index} + {lookahead}; POST /v1/sessions/<id>/flush at the end of the sequence for the rest"),
                })),
            )
                .into_response(),
            Reply::Empty => StatusCode::NO_CONTENT.into_response(),
        }
    }
}

/// Hands the oldest output over as an EXR reply (queueing the rest in the session), or
/// `none` when there is none; counts and recycles it. Runs on the pool.
fn hand_over(
    svc: &Service,
    co: &mut Checkout,
    outs: Vec<Filtered>,
    none: Reply,
    output: &OutputOptions,
) -> Result<Reply, SessionError> {
    let (f, left) = co.queue_and_take(outs)?;
    let Some(f) = f else { return Ok(none) };
    let record = json!({"index": f.index, "psnr": f.psnr, "ssim": f.ssim, "record": f.record}).to_string();
    let frame_record = serde_json::to_string(&f.record).map_err(|e| SessionError::Internal(e.to_string()))?;
    let frame = FilteredFrame {
        color: &f.color,
        meta: &f.meta,
        record: Some(&frame_record),
        input: f.input.as_ref().map(|k| &k.image),
    };
    let exr = encode_filtered(&frame, output).map_err(|e| SessionError::Internal(e.to_string()))?;
    svc.metrics.frame(&f.record);
    co.recycle(f.color);
    Ok(Reply::Exr { exr, record, left })
}

/// How a frame's reply is written: query parameters `keep` (all, filtered, none),
/// `compression` (none, zip, piz, ...) and `precision` (half, float); by default the input
/// file with its colour replaced, as `afterimage filter` writes it.
#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
struct OutputQuery {
    keep: Option<String>,
    compression: Option<String>,
    precision: Option<String>,
}

impl OutputQuery {
    fn options(&self) -> Result<OutputOptions, SessionError> {
        let invalid = |field: &str, e: crate::io::IoError| SessionError::invalid(field, e.to_string());
        Ok(OutputOptions {
            keep: match &self.keep {
                Some(k) => k.parse::<Keep>().map_err(|e| invalid("keep", e))?,
                None => Keep::All,
            },
            compression: match &self.compression {
                Some(c) => Some(c.parse::<Compression>().map_err(|e| invalid("compression", e))?),
                None => None,
            },
            precision: match self.precision.as_deref() {
                None => None,
                Some("half") => Some(Precision::F16),
                Some("float") => Some(Precision::F32),
                Some(other) => {
                    return Err(SessionError::invalid(
                        "precision",
                        format!("{:?}: expected half or float", crate::session::clip(other)),
                    ))
                }
            },
        })
    }
}

/// Frame values a request's headers give (see [`INDEX_HEADER`], [`RESET_HEADER`],
/// [`JITTER_HEADER`]).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
struct FrameHeaders {
    index: Option<u64>,
    reset: Option<bool>,
    jitter: Option<[f32; 2]>,
}

impl FrameHeaders {
    fn parse(headers: &HeaderMap) -> Result<FrameHeaders, SessionError> {
        let text = |name: &'static str| -> Result<Option<&str>, SessionError> {
            headers
                .get(name)
                .map(|v| {
                    v.to_str()
                        .map_err(|_| SessionError::invalid(name, "not ASCII text"))
                })
                .transpose()
        };
        let index = text(INDEX_HEADER)?
            .map(|v| {
                v.trim().parse::<u64>().map_err(|_| {
                    SessionError::invalid(
                        INDEX_HEADER,
                        format!(
                            "{:?}: expected a whole number 0..={}",
                            crate::session::clip(v),
                            u64::MAX
                        ),
                    )
                })
            })
            .transpose()?;
        let reset = text(RESET_HEADER)?
            .map(|v| match v.trim() {
                "1" | "true" => Ok(true),
                "0" | "false" => Ok(false),
                other => Err(SessionError::invalid(
                    RESET_HEADER,
                    format!("{:?}: expected 1, 0, true or false", crate::session::clip(other)),
                )),
            })
            .transpose()?;
        let jitter = text(JITTER_HEADER)?
            .map(|v| {
                let bad = || {
                    SessionError::invalid(
                        JITTER_HEADER,
                        format!(
                            "{:?}: expected two numbers x,y in pixels, each in -1..=1",
                            crate::session::clip(v)
                        ),
                    )
                };
                let (x, y) = v.split_once(',').ok_or_else(bad)?;
                let parse = |t: &str| t.trim().parse::<f32>().ok();
                let j = [parse(x).ok_or_else(bad)?, parse(y).ok_or_else(bad)?];
                crate::frame::FrameMeta::jitter_in_range(j)
                    .then_some(j)
                    .ok_or_else(bad)
            })
            .transpose()?;
        Ok(FrameHeaders { index, reset, jitter })
    }
}

async fn post_frame(
    State(svc): State<Service>,
    Auth(caller): Auth,
    Path(id): Path<String>,
    query: Result<Query<OutputQuery>, QueryRejection>,
    headers: HeaderMap,
    body: Body,
) -> HttpResult<Response> {
    let _in_flight = svc.begin();
    // The session first: unknown, busy or failed sessions are answered at once, before the
    // body is read (and bad options or headers too; see `refuse_early`).
    let early = output_options(query).and_then(|output| {
        let given = FrameHeaders::parse(&headers)?;
        Ok((output, given, svc.sessions.checkout(&caller, &id)?))
    });
    let (output, given, co) = match early {
        Ok(v) => v,
        Err(e) => return refuse_early(&svc, &headers, body, e),
    };
    let shape = co.shape();
    let max = svc.max_exr_body(shape);
    let declared = counted(&svc, content_length(&headers))?;
    if let Some(n) = declared.filter(|&n| n > max) {
        return counted(
            &svc,
            Err(SessionError::too_large(
                "body",
                format!(
                    "{n} bytes, an EXR frame for this {}x{} session is at most {max} bytes ({} channels of f32 and headers)",
                    shape.width, shape.height, svc.config.max_exr_channels
                ),
            )),
        );
    }
    let body_hold = counted(
        &svc,
        svc.sessions
            .reserve(&caller, declared.unwrap_or(max), "a frame's request body"),
    )?;
    let bytes = counted(
        &svc,
        read_body(body, max, Duration::from_secs(svc.config.request_timeout_s)).await,
    )?;
    let job = svc.clone();
    let share = svc.share(&caller, &id, shape);
    let reply = svc
        .on_pool_as(share, move |sessions| {
            let mut co = co;
            let label = std::path::Path::new("request body");
            let body_err = |e: crate::io::IoError| SessionError::invalid("body", e.to_string());
            let limits = job.exr_limits(shape);
            let file = check_exr_header(&bytes, label, &limits).map_err(body_err)?;
            // The decoder's image, its planes as read and the frame (4 bytes per sample
            // each), then the output and the encoded reply.
            let decode = 3 * shape.pixels() * file.channels as u64 * 4 + 2 * shape.output_bytes();
            let _decode_hold = sessions.reserve(&caller, decode, "decoding a frame")?;
            let mut raw = read_raw_exr_bytes_limited(&bytes, label, &limits).map_err(body_err)?;
            drop(bytes);
            let declared = raw.exr.as_ref().and_then(|h| h.frame_index());
            raw.meta.index = match given.index.or(declared) {
                Some(i) => i,
                None => co.next_index()?,
            };
            if let Some(r) = given.reset {
                raw.meta.reset = r;
            }
            if let Some(j) = given.jitter {
                raw.meta.jitter = j;
            }
            let (frame, mut input) = frame_and_input(raw, &ReadOptions::default(), None).map_err(body_err)?;
            input.trim_to(output.keep);
            let input = KeptInput::new(sessions, &caller, input)?;
            let index = frame.meta.index;
            let outs = co.process_kept(frame, MotionInput::Internal, Some(input))?;
            let lookahead = co.lookahead();
            hand_over(&job, &mut co, outs, Reply::Accepted { index, lookahead }, &output)
        })
        .await?;
    Ok(reply.holding(body_hold))
}

/// Ends the sequence of a session whose filter looks ahead: each call returns the oldest
/// output not handed over yet (200 with the EXR; `x-afterimage-ready` says how many more
/// are queued), then 204 when none is left.
async fn post_flush(
    State(svc): State<Service>,
    Auth(caller): Auth,
    Path(id): Path<String>,
    query: Result<Query<OutputQuery>, QueryRejection>,
) -> HttpResult<Response> {
    let output = counted(&svc, output_options(query))?;
    let co = counted(&svc, svc.sessions.checkout(&caller, &id))?;
    let shape = co.shape();
    let held = shape.output_bytes() * (2 * co.lookahead() as u64 + 2);
    let hold = counted(&svc, svc.sessions.reserve(&caller, held, "a flush"))?;
    let job = svc.clone();
    let share = svc.share(&caller, &id, shape);
    let reply = svc
        .on_pool_as(share, move |_| {
            let mut co = co;
            let outs = co.flush()?;
            hand_over(&job, &mut co, outs, Reply::Empty, &output)
        })
        .await?;
    Ok(reply.holding(hold))
}

/// The output options of a frame or flush request's query string.
fn output_options(query: Result<Query<OutputQuery>, QueryRejection>) -> Result<OutputOptions, SessionError> {
    match query {
        Ok(Query(q)) => q.options(),
        Err(e) => Err(SessionError::invalid("query", e.body_text())),
    }
}

async fn filters(Auth(_): Auth) -> Response {
    Json(json!({"filters": filters::list()})).into_response()
}

async fn healthz() -> &'static str {
    "ok"
}

async fn readyz(State(svc): State<Service>) -> Response {
    if svc.sessions.is_closing() {
        (StatusCode::SERVICE_UNAVAILABLE, "shutting down").into_response()
    } else {
        "ready".into_response()
    }
}

async fn metrics(State(svc): State<Service>, headers: HeaderMap) -> HttpResult<Response> {
    if svc.config.metrics_require_key {
        let value = headers
            .get(header::AUTHORIZATION)
            .map(|v| v.to_str().unwrap_or("(not text)"));
        svc.caller(value).map_err(HttpError)?;
    }
    let text = svc.metrics.render(svc.sessions.totals());
    Ok(([(header::CONTENT_TYPE, super::metrics::CONTENT_TYPE)], text).into_response())
}

/// The HTTP API.
pub fn router(svc: Service) -> Router {
    Router::new()
        .route("/healthz", get(healthz))
        .route("/readyz", get(readyz))
        .route("/metrics", get(metrics))
        .route("/v1/filters", get(filters))
        .route("/v1/sessions", post(create))
        .route("/v1/sessions/{id}", get(get_session).delete(delete_session))
        .route("/v1/sessions/{id}/frames", post(post_frame))
        .route("/v1/sessions/{id}/flush", post(post_flush))
        .route("/v1/sessions/{id}/state", get(get_state).put(put_state))
        .layer(DefaultBodyLimit::max(MAX_JSON_BYTES))
        .with_state(svc)
}
