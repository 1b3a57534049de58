//! The one service both transports call: sessions, keys, metrics, and running every
//! request's heavy work (decoding, filtering, encoding) on the rayon pool, never on tokio's
//! workers, with any panic kept inside its request.

use super::config::Config;
use super::metrics::Metrics;
use super::schedule::{Scheduler, Share};
use crate::io::ExrLimits;
use crate::pipeline::exec::{panic_text, pool, with_cancel};
use crate::session::{Caller, FrameShape, Keyring, SessionError, Sessions};
use std::panic::{catch_unwind, AssertUnwindSafe};
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::Arc;
use tokio::sync::watch;

/// Shared by the gRPC and HTTP layers.
#[derive(Clone)]
pub struct Service {
    /// The sessions.
    pub sessions: Arc<Sessions>,
    /// Counters for `/metrics`.
    pub metrics: Arc<Metrics>,
    /// The config it runs with.
    pub config: Arc<Config>,
    /// The API keys (empty: no authentication).
    pub keys: Arc<Keyring>,
    /// Requests between taking a session and giving it back (drain waits for these).
    in_flight: Arc<AtomicUsize>,
    /// Turns true when the server starts draining (streams end between frames).
    draining: Arc<watch::Sender<bool>>,
    /// Fair shares of the pool between keys and sessions.
    scheduler: Scheduler,
}

/// Cancels a pool job when dropped (see [`Service::on_pool`]).
struct CancelOnDrop(Option<Arc<AtomicBool>>);

impl Drop for CancelOnDrop {
    fn drop(&mut self) {
        if let Some(flag) = &self.0 {
            flag.store(true, Ordering::SeqCst);
        }
    }
}

/// One request in flight; counted until dropped.
pub struct InFlight(Arc<AtomicUsize>);

impl Drop for InFlight {
    fn drop(&mut self) {
        self.0.fetch_sub(1, Ordering::SeqCst);
    }
}

impl Service {
    /// A service with no sessions.
    pub fn new(config: Config, keys: Keyring) -> Self {
        Service {
            sessions: Arc::new(Sessions::new(config.limits())),
            metrics: Arc::new(Metrics::default()),
            config: Arc::new(config),
            keys: Arc::new(keys),
            in_flight: Arc::default(),
            draining: Arc::new(watch::channel(false).0),
            scheduler: Scheduler::new(pool().current_num_threads(), |job| pool().spawn(job)),
        }
    }

    /// Starts draining: new sessions and frames are refused, `/readyz` answers 503, open
    /// streams end after their current frame.
    pub fn drain(&self) {
        self.sessions.close_all_new_work();
        self.draining.send_replace(true);
    }

    /// Turns true when draining starts.
    pub fn draining(&self) -> watch::Receiver<bool> {
        self.draining.subscribe()
    }

    /// Counts `e` and passes it on.
    pub fn count<T>(&self, r: Result<T, SessionError>) -> Result<T, SessionError> {
        if let Err(e) = &r {
            self.metrics.error(e.reason());
            tracing::debug!(error = %e, "request refused");
        }
        r
    }

    /// The caller presenting `authorization` (an `Authorization` header or `authorization`
    /// metadata value): anonymous on a server without keys; refusals counted.
    pub fn caller(&self, authorization: Option<&str>) -> Result<Caller, SessionError> {
        self.count(self.keys.caller(authorization))
    }

    /// Marks a request in flight until the guard drops.
    pub fn begin(&self) -> InFlight {
        self.in_flight.fetch_add(1, Ordering::SeqCst);
        InFlight(self.in_flight.clone())
    }

    /// Requests in flight now.
    pub fn in_flight(&self) -> usize {
        self.in_flight.load(Ordering::SeqCst)
    }

    /// Runs `job` on the rayon pool and waits for it without blocking the async worker. A
    /// panic in the job fails this request only (INTERNAL, logged and counted); a session
    /// the job had checked out is put back as it was, or failed when its filter panicked.
    pub async fn on_pool<T: Send + 'static>(
        &self,
        job: impl FnOnce(&Sessions) -> Result<T, SessionError> + Send + 'static,
    ) -> Result<T, SessionError> {
        self.on_pool_as(Share::default(), job).await
    }

    /// [`Self::on_pool`] for `share`: the job waits for its turn among the keys' and
    /// sessions' fair shares ([`Scheduler`]).
    pub async fn on_pool_as<T: Send + 'static>(
        &self,
        share: Share,
        job: impl FnOnce(&Sessions) -> Result<T, SessionError> + Send + 'static,
    ) -> Result<T, SessionError> {
        let sessions = self.sessions.clone();
        let guard = self.begin();
        let (tx, rx) = tokio::sync::oneshot::channel();
        // Set when this future is dropped before the job ends (the client went away): the
        // session's steps ask `exec::cancelled` (a queued frame is then dropped, a flush stops
        // between frames and drops its window), so the job always runs to tidy up.
        let flag = Arc::new(AtomicBool::new(false));
        let mut cancel = CancelOnDrop(Some(flag.clone()));
        self.scheduler.submit(share, move || {
            let r = with_cancel(flag, || catch_unwind(AssertUnwindSafe(|| job(&sessions)))).unwrap_or_else(
                |panic| {
                    let cause = panic_text(panic.as_ref());
                    tracing::error!(%cause, "a request panicked; it fails, the server goes on");
                    Err(SessionError::Internal(format!("the request failed: {cause}")))
                },
            );
            drop(guard);
            let _ = tx.send(r);
        });
        let r = rx
            .await
            .unwrap_or_else(|_| Err(SessionError::Internal("the worker dropped the request".into())));
        cancel.0 = None; // finished: nothing to cancel
        self.count(r)
    }

    /// The share a frame of `shape` for session `id` of `caller` takes of the pool.
    pub fn share(&self, caller: &Caller, id: &str, shape: FrameShape) -> Share {
        Share {
            key: caller.name().unwrap_or_default().to_string(),
            session: id.to_string(),
            pixels: shape.pixels(),
        }
    }

    /// What an EXR body for a session of `shape` may declare (checked from its header).
    pub fn exr_limits(&self, shape: FrameShape) -> ExrLimits {
        ExrLimits {
            size: Some((shape.width as usize, shape.height as usize)),
            max_pixels: shape.pixels(),
            max_channels: self.config.max_exr_channels,
            max_parts: self.config.max_exr_parts,
            rewritable: true,
        }
    }

    /// The largest EXR body a frame of `shape` can need: every allowed channel as
    /// uncompressed f32, plus headers and offset tables (1 MiB), capped by `max_frame_mib`.
    /// OpenEXR stores a chunk uncompressed when compression would grow it, so no valid
    /// file is larger.
    pub fn max_exr_body(&self, shape: FrameShape) -> u64 {
        let samples = shape.pixels() * self.config.max_exr_channels as u64;
        let offsets = shape.height as u64 * 8 * self.config.max_exr_parts as u64;
        (samples * 4 + offsets + (1 << 20)).min(self.config.max_frame_mib << 20)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::session::{MotionInput, SessionRequest};

    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn a_panic_in_a_pool_job_fails_only_that_request() {
        let svc = Service::new(Config::default(), Keyring::default());
        let a = Caller::ANONYMOUS;
        let req = SessionRequest {
            filter: "taa".into(),
            width: 24,
            height: 16,
            ..Default::default()
        };
        let id = svc.sessions.create(&a, &req).unwrap().id;
        // A panic while "decoding", with the session checked out: the request fails with
        // the cause, the session is put back untouched, the pool and the server go on.
        let job_id = id.clone();
        let e = svc
            .on_pool(move |s| -> Result<(), SessionError> {
                let _co = s.checkout(&Caller::ANONYMOUS, &job_id)?;
                let bytes: &[u8] = &[];
                let _ = bytes[usize::MAX / 2];
                Ok(())
            })
            .await
            .unwrap_err();
        assert!(
            matches!(e, SessionError::Internal(ref m) if m.contains("out of bounds")),
            "{e}"
        );
        assert_eq!(svc.in_flight(), 0);
        let text = svc.metrics.render(svc.sessions.totals());
        assert!(
            text.contains("afterimage_errors_total{reason=\"internal\"} 1"),
            "{text}"
        );
        let job_id = id.clone();
        let outs = svc
            .on_pool(move |s| {
                let mut co = s.checkout(&Caller::ANONYMOUS, &job_id)?;
                co.process(crate::scene::synthetic_frame(24, 16, 0), MotionInput::Internal)
            })
            .await
            .unwrap();
        assert_eq!(outs.len(), 1);
        assert_eq!(svc.sessions.get(&a, &id).unwrap().frames, 1);
    }
}
