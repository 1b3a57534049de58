//! The HTTP layer (axum) over the same [`Service`]: JSON sessions, EXR frames, health,
//! readiness and Prometheus metrics. The router is built by [`router`] so tests can drive
//! it without a socket.
//!
//! A frame request takes its session before its body is read: an unknown, busy or failed
//! session, or a `Content-Length` larger than any EXR of the session's size, is answered
//! at once. The body is then read within the request timeout and a memory reservation,
//! and decoded, filtered and encoded on the rayon pool.

use super::service::Service;
use crate::filters;
use crate::frame::Frame;
use crate::io::{
    check_exr_header, read_exr_frame_bytes_limited, write_exr_bytes, Compression, ExrLayout, Precision,
    ReadOptions, WriteOptions,
};
use crate::session::{
    params_from_json, Caller, Checkout, ErrorKind, Filtered, MotionInput, SessionError, SessionRequest,
};
use axum::body::{Body, Bytes};
use axum::extract::{DefaultBodyLimit, FromRequestParts, Path, State};
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
    };
    let info = counted(&svc, svc.sessions.create(&caller, &req))?;
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
            format!("more than the {limit} bytes an EXR for this session can need"),
        )),
        Ok(Err(e)) => Err(SessionError::invalid("body", format!("could not be read: {e}"))),
        Ok(Ok(c)) => Ok(c.to_bytes()),
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

impl IntoResponse for Reply {
    fn into_response(self) -> Response {
        match self {
            Reply::Exr { exr, record, left } => {
                let mut resp = (StatusCode::OK, exr).into_response();
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
) -> Result<Reply, SessionError> {
    let (f, left) = co.queue_and_take(outs)?;
    let Some(f) = f else { return Ok(none) };
    let out = Frame::new(f.color).map_err(|e| SessionError::Internal(e.to_string()))?;
    let opts = WriteOptions {
        precision: Precision::F32,
        compression: Compression::None,
        layout: ExrLayout::Plain,
    };
    let exr = write_exr_bytes(&out, &opts).map_err(|e| SessionError::Internal(e.to_string()))?;
    let record = json!({"index": f.index, "psnr": f.psnr, "ssim": f.ssim, "record": f.record}).to_string();
    svc.metrics.frame(&f.record);
    co.recycle(out.into_color());
    Ok(Reply::Exr { exr, record, left })
}

async fn post_frame(
    State(svc): State<Service>,
    Auth(caller): Auth,
    Path(id): Path<String>,
    headers: HeaderMap,
    body: Body,
) -> HttpResult<Response> {
    let _in_flight = svc.begin();
    // The session first: unknown, busy or failed sessions are answered before the body.
    let co = counted(&svc, svc.sessions.checkout(&caller, &id))?;
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
    let reply = svc
        .on_pool(move |sessions| {
            let mut co = co;
            let label = std::path::Path::new("request body");
            let body_err = |e: crate::io::IoError| SessionError::invalid("body", e.to_string());
            let limits = job.exr_limits(shape);
            let file = check_exr_header(&bytes, label, &limits).map_err(body_err)?;
            // The decoder's image, its planes as read and the frame (4 bytes per sample
            // each), then the output and the encoded reply.
            let decode = 3 * shape.pixels() * file.channels as u64 * 4 + 2 * shape.output_bytes();
            let _decode_hold = sessions.reserve(&caller, decode, "decoding a frame")?;
            let frame = read_exr_frame_bytes_limited(&bytes, label, &ReadOptions::default(), &limits)
                .map_err(body_err)?;
            drop(bytes);
            let index = frame.meta.index;
            let outs = co.process(frame, MotionInput::Internal)?;
            let lookahead = co.lookahead();
            hand_over(&job, &mut co, outs, Reply::Accepted { index, lookahead })
        })
        .await?;
    drop(body_hold);
    Ok(reply.into_response())
}

/// Ends the sequence of a session whose filter looks ahead: each call returns the oldest
/// output not handed over yet (200 with the EXR; `x-afterimage-ready` says how many more
/// are queued), then 204 when none is left.
async fn post_flush(
    State(svc): State<Service>,
    Auth(caller): Auth,
    Path(id): Path<String>,
) -> HttpResult<Response> {
    let co = counted(&svc, svc.sessions.checkout(&caller, &id))?;
    let shape = co.shape();
    let held = shape.output_bytes() * (2 * co.lookahead() as u64 + 2);
    let hold = counted(&svc, svc.sessions.reserve(&caller, held, "a flush"))?;
    let job = svc.clone();
    let reply = svc
        .on_pool(move |_| {
            let mut co = co;
            let outs = co.flush()?;
            hand_over(&job, &mut co, outs, Reply::Empty)
        })
        .await?;
    drop(hold);
    Ok(reply.into_response())
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
    Ok(([(header::CONTENT_TYPE, "text/plain; version=0.0.4")], text).into_response())
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
        .layer(DefaultBodyLimit::max(MAX_JSON_BYTES))
        .with_state(svc)
}
