//! The one service both transports call: sessions, metrics, and running frames on the
//! rayon pool (never on tokio's workers).

use super::config::Config;
use super::metrics::Metrics;
use super::wire::{self, Assembly};
use crate::frame::Frame;
use crate::pipeline::exec::pool;
use crate::session::{Filtered, MotionInput, SessionError, Sessions};
use std::sync::Arc;
use std::time::Instant;

/// Shared by the gRPC and HTTP layers.
#[derive(Clone)]
pub struct Service {
    /// The sessions.
    pub sessions: Arc<Sessions>,
    /// Counters for `/metrics`.
    pub metrics: Arc<Metrics>,
    /// The config it runs with.
    pub config: Arc<Config>,
}

impl Service {
    /// A service with no sessions.
    pub fn new(config: Config) -> Self {
        Service {
            sessions: Arc::new(Sessions::new(config.limits())),
            metrics: Arc::new(Metrics::default()),
            config: Arc::new(config),
        }
    }

    /// Counts `e` and passes it on.
    pub fn count<T>(&self, r: Result<T, SessionError>) -> Result<T, SessionError> {
        if let Err(e) = &r {
            self.metrics.error(e.reason());
        }
        r
    }

    async fn on_pool<T: Send + 'static>(
        &self,
        job: impl FnOnce(&Sessions) -> Result<T, SessionError> + Send + 'static,
    ) -> Result<T, SessionError> {
        let sessions = self.sessions.clone();
        let (tx, rx) = tokio::sync::oneshot::channel();
        pool().spawn(move || {
            let _ = tx.send(job(&sessions));
        });
        let r = rx
            .await
            .unwrap_or_else(|_| Err(SessionError::Internal("the worker dropped the frame".into())));
        self.count(r)
    }

    /// Decodes an assembled wire frame, filters it and builds the reply with `finish`
    /// (given the result and the server time in ms), all on the rayon pool; the output's
    /// planes then go back to the session's filter for the next frame.
    pub async fn wire_frame<R: Send + 'static>(
        &self,
        a: Assembly,
        finish: impl FnOnce(&Filtered, f64) -> R + Send + 'static,
    ) -> Result<R, SessionError> {
        let id = a.header.session_id.clone();
        let metrics = self.metrics.clone();
        self.on_pool(move |s| {
            let t = Instant::now();
            let (w, h, allowed) = s.frame_shape(&id)?;
            let frame = wire::decode(&a, w, h, allowed)?;
            let out = s.process(&id, frame, MotionInput::Session)?;
            let reply = finish(&out, t.elapsed().as_secs_f64() * 1e3);
            metrics.frame(&out.record);
            s.recycle(&id, out.color);
            Ok(reply)
        })
        .await
    }

    /// Filters a decoded frame whose motion is already internal.
    pub async fn frame(&self, id: String, frame: Frame) -> Result<Filtered, SessionError> {
        let f = self
            .on_pool(move |s| s.process(&id, frame, MotionInput::Internal))
            .await?;
        self.metrics.frame(&f.record);
        Ok(f)
    }
}
