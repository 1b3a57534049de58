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

    /// Decodes an assembled wire frame, filters it and builds a reply with `finish` for
    /// every output that came out (given it and the server time in ms, shared by the
    /// outputs), all on the rayon pool; the outputs' planes then go back to the session's
    /// filter for the next frame. A windowed filter gives no output while its window
    /// fills, so the list may be empty.
    pub async fn wire_frame<R: Send + 'static>(
        &self,
        a: Assembly,
        finish: impl Fn(&Filtered, f64) -> R + Send + 'static,
    ) -> Result<Vec<R>, SessionError> {
        let id = a.header.session_id.clone();
        let metrics = self.metrics.clone();
        self.on_pool(move |s| {
            let t = Instant::now();
            let (w, h, allowed) = s.frame_shape(&id)?;
            let frame = wire::decode(&a, w, h, allowed)?;
            let outs = s.process(&id, frame, MotionInput::Session)?;
            Ok(Self::replies(s, &id, &metrics, outs, t, finish))
        })
        .await
    }

    /// The end of a stream: the outputs session `id`'s windowed filter still holds, each
    /// made a reply by `finish`, as [`Service::wire_frame`].
    pub async fn wire_flush<R: Send + 'static>(
        &self,
        id: String,
        finish: impl Fn(&Filtered, f64) -> R + Send + 'static,
    ) -> Result<Vec<R>, SessionError> {
        let metrics = self.metrics.clone();
        self.on_pool(move |s| {
            let t = Instant::now();
            let outs = s.flush(&id)?;
            Ok(Self::replies(s, &id, &metrics, outs, t, finish))
        })
        .await
    }

    fn replies<R>(
        s: &Sessions,
        id: &str,
        metrics: &Metrics,
        outs: Vec<Filtered>,
        t: Instant,
        finish: impl Fn(&Filtered, f64) -> R,
    ) -> Vec<R> {
        let ms = t.elapsed().as_secs_f64() * 1e3;
        outs.into_iter()
            .map(|out| {
                let reply = finish(&out, ms);
                metrics.frame(&out.record);
                s.recycle(id, out.color);
                reply
            })
            .collect()
    }

    /// Filters a decoded frame whose motion is already internal; the outputs that came out.
    pub async fn frame(&self, id: String, frame: Frame) -> Result<Vec<Filtered>, SessionError> {
        let outs = self
            .on_pool(move |s| s.process(&id, frame, MotionInput::Internal))
            .await?;
        for f in &outs {
            self.metrics.frame(&f.record);
        }
        Ok(outs)
    }

    /// Ends session `id`'s sequence: what its windowed filter still holds.
    pub async fn flush(&self, id: String) -> Result<Vec<Filtered>, SessionError> {
        let outs = self.on_pool(move |s| s.flush(&id)).await?;
        for f in &outs {
            self.metrics.frame(&f.record);
        }
        Ok(outs)
    }
}
