//! The HTTP layer (axum) over the same [`Service`]: JSON sessions, EXR frames, health,
//! readiness and Prometheus metrics. The router is built by [`router`] so tests can drive
//! it without a socket.

use super::service::Service;
use crate::frame::Frame;
use crate::io::{
    read_exr_frame_bytes, write_exr_bytes, Compression, ExrLayout, Precision, ReadOptions, WriteOptions,
};
use crate::pipeline;
use crate::session::{params_from_json, ErrorKind, Filtered, SessionError, SessionRequest};
use axum::body::Bytes;
use axum::extract::{DefaultBodyLimit, Path, State};
use axum::http::{header, HeaderValue, StatusCode};
use axum::response::{IntoResponse, Response};
use axum::routing::{get, post};
use axum::{Json, Router};
use serde::Deserialize;
use serde_json::{json, Map, Value};

/// Header of a frame reply carrying its report as JSON.
pub const RECORD_HEADER: &str = "x-afterimage-record";
/// Response header: outputs still queued for later requests (a windowed filter gives a
/// whole shot at once at a cut, or at a flush).
pub const READY_HEADER: &str = "x-afterimage-ready";

/// An error as an HTTP response: status from its kind, JSON body naming the problem.
pub struct HttpError(pub SessionError);

impl IntoResponse for HttpError {
    fn into_response(self) -> Response {
        let code = match self.0.kind() {
            ErrorKind::InvalidArgument => StatusCode::BAD_REQUEST,
            ErrorKind::NotFound => StatusCode::NOT_FOUND,
            ErrorKind::ResourceExhausted => StatusCode::TOO_MANY_REQUESTS,
            ErrorKind::FailedPrecondition => StatusCode::CONFLICT,
            ErrorKind::Internal => StatusCode::INTERNAL_SERVER_ERROR,
            ErrorKind::Unavailable => StatusCode::SERVICE_UNAVAILABLE,
        };
        let field = match &self.0 {
            SessionError::Invalid { field, .. } => Value::String(field.clone()),
            _ => Value::Null,
        };
        let body =
            json!({"error": {"reason": self.0.reason(), "field": field, "message": self.0.to_string()}});
        (code, Json(body)).into_response()
    }
}

type HttpResult<T> = Result<T, HttpError>;

fn counted<T>(svc: &Service, r: Result<T, SessionError>) -> HttpResult<T> {
    svc.count(r).map_err(HttpError)
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
    body: Result<Json<CreateBody>, axum::extract::rejection::JsonRejection>,
) -> HttpResult<Response> {
    let Json(b) = body.map_err(|e| HttpError(SessionError::invalid("body", e.body_text())))?;
    let req = SessionRequest {
        filter: b.filter,
        params: params_from_json(&b.params),
        width: b.width,
        height: b.height,
        motion: b.motion,
        channels: b.channels,
    };
    let info = counted(&svc, svc.sessions.create(&req))?;
    Ok((StatusCode::CREATED, Json(info)).into_response())
}

async fn get_session(State(svc): State<Service>, Path(id): Path<String>) -> HttpResult<Response> {
    Ok(Json(counted(&svc, svc.sessions.get(&id))?).into_response())
}

async fn delete_session(State(svc): State<Service>, Path(id): Path<String>) -> HttpResult<Response> {
    let frames = counted(&svc, svc.sessions.close(&id))?;
    Ok(Json(json!({"id": id, "frames": frames})).into_response())
}

fn frame_from_exr(body: &[u8]) -> Result<Frame, SessionError> {
    read_exr_frame_bytes(
        body,
        std::path::Path::new("request body"),
        &ReadOptions::default(),
    )
    .map_err(|e| SessionError::invalid("body", e.to_string()))
}

async fn post_frame(State(svc): State<Service>, Path(id): Path<String>, body: Bytes) -> HttpResult<Response> {
    // Unknown sessions are refused before decoding the body.
    counted(&svc, svc.sessions.frame_shape(&id))?;
    let frame = counted(&svc, frame_from_exr(&body))?;
    let index = frame.meta.index;
    let outs = svc.frame(id.clone(), frame).await.map_err(HttpError)?;
    let (f, left) = counted(&svc, svc.sessions.queue_and_take(&id, outs))?;
    match f {
        Some(f) => exr_response(f, left),
        None => {
            let lookahead = counted(&svc, svc.sessions.get(&id))?.lookahead;
            Ok((
                StatusCode::ACCEPTED,
                Json(json!({
                    "accepted": index,
                    "lookahead": lookahead,
                    "message": format!("frame {index} is in the filter's window: its output comes after frame {index} + {lookahead}; POST /v1/sessions/{id}/flush at the end of the sequence for the rest"),
                })),
            )
                .into_response())
        }
    }
}

/// Ends the sequence of a session whose filter looks ahead: each call returns the oldest
/// output not handed over yet (200 with the EXR; `x-afterimage-ready` says how many more
/// are queued), then 204 when none is left.
async fn post_flush(State(svc): State<Service>, Path(id): Path<String>) -> HttpResult<Response> {
    let outs = svc.flush(id.clone()).await.map_err(HttpError)?;
    let (f, left) = counted(&svc, svc.sessions.queue_and_take(&id, outs))?;
    match f {
        Some(f) => exr_response(f, left),
        None => Ok(StatusCode::NO_CONTENT.into_response()),
    }
}

/// A filtered frame as an EXR body, its figures in the record header, and how many more
/// outputs are queued for later requests.
fn exr_response(f: Filtered, left: usize) -> HttpResult<Response> {
    let out = Frame::new(f.color).map_err(|e| HttpError(SessionError::Internal(e.to_string())))?;
    let opts = WriteOptions {
        precision: Precision::F32,
        compression: Compression::None,
        layout: ExrLayout::Plain,
    };
    let exr = write_exr_bytes(&out, &opts).map_err(|e| HttpError(SessionError::Internal(e.to_string())))?;
    let record = json!({"index": f.index, "psnr": f.psnr, "ssim": f.ssim, "record": f.record}).to_string();
    let mut resp = (StatusCode::OK, exr).into_response();
    let h = resp.headers_mut();
    h.insert(header::CONTENT_TYPE, HeaderValue::from_static("image/x-exr"));
    if let Ok(v) = HeaderValue::from_str(&record) {
        h.insert(RECORD_HEADER, v);
    }
    h.insert(READY_HEADER, HeaderValue::from(left));
    Ok(resp)
}

async fn filters() -> Response {
    Json(json!({"filters": pipeline::list()})).into_response()
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

async fn metrics(State(svc): State<Service>) -> Response {
    let text = svc.metrics.render(svc.sessions.totals());
    ([(header::CONTENT_TYPE, "text/plain; version=0.0.4")], text).into_response()
}

/// The HTTP API.
pub fn router(svc: Service) -> Router {
    let limit = (svc.config.max_frame_mib << 20) as usize;
    Router::new()
        .route("/healthz", get(healthz))
        .route("/readyz", get(readyz))
        .route("/metrics", get(metrics))
        .route("/v1/filters", get(filters))
        .route("/v1/sessions", post(create))
        .route("/v1/sessions/{id}", get(get_session).delete(delete_session))
        .route("/v1/sessions/{id}/frames", post(post_frame))
        .route("/v1/sessions/{id}/flush", post(post_flush))
        .layer(DefaultBodyLimit::max(limit))
        .with_state(svc)
}
