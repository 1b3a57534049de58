//! Sessions: one filter instance with its history per client stream, behind limits (count,
//! a memory budget over all state, frame size), with idle eviction and failure isolation.
//! Synchronous and transport-free: the gRPC and HTTP layers in `server` call it from the
//! rayon pool. A session outlives the connections that feed it, so a client can reconnect
//! by id until the idle timeout.

use crate::frame::{ChannelKind, ChannelSet, Frame, MotionConvention, Rgb};
use crate::metrics::{luma, mse, psnr_from_mse, ssim, MetricSpace, SpaceChoice};
use crate::pipeline::{self, Filter, FilterError, FrameRecord};
use serde::Serialize;
use serde_json::{Map, Value};
use std::collections::{HashMap, VecDeque};
use std::panic::{catch_unwind, AssertUnwindSafe};
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::{Duration, Instant};
use thiserror::Error;

/// Limits every session is held to.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Limits {
    /// Sessions open at once.
    pub max_sessions: usize,
    /// Bytes of filter state over all sessions.
    pub memory_budget_bytes: u64,
    /// A session unused this long is closed.
    pub idle_timeout: Duration,
    /// Largest frame width and height.
    pub max_width: u32,
    /// Largest frame height.
    pub max_height: u32,
    /// Largest encoded frame (all channels, on the wire).
    pub max_frame_bytes: u64,
    /// Largest share of non-finite colour samples a frame may have; a frame above it is
    /// refused (a NaN flood is a renderer bug, not something to filter).
    pub max_non_finite_fraction: f64,
}

impl Default for Limits {
    fn default() -> Self {
        Limits {
            max_sessions: 64,
            memory_budget_bytes: 8 << 30,
            idle_timeout: Duration::from_secs(300),
            max_width: 8192,
            max_height: 8192,
            max_frame_bytes: 1 << 30,
            max_non_finite_fraction: 0.5,
        }
    }
}

/// What went wrong, sorted by whose fault it is; the server maps [`SessionError::kind`] to
/// a gRPC code and an HTTP status.
#[derive(Debug, Error, Clone, PartialEq)]
pub enum SessionError {
    /// The request is wrong: the message names the field, what was expected and what came.
    #[error("{field}: {message}")]
    Invalid {
        /// The field or value at fault.
        field: String,
        /// Expected vs got.
        message: String,
    },
    /// No session of that id (never existed, closed, or evicted after being idle).
    #[error("no session {id:?} (closed, evicted after {idle_s} s idle, or never created)")]
    NotFound {
        /// The id asked for.
        id: String,
        /// The idle timeout.
        idle_s: u64,
    },
    /// A limit would be exceeded.
    #[error("{0}")]
    Exhausted(String),
    /// The session failed earlier (a filter panicked) and must be closed.
    #[error("session {id} failed: {message}; close it and open a new one")]
    Failed {
        /// The session.
        id: String,
        /// What happened.
        message: String,
    },
    /// A bug on our side (a filter panicked on this frame).
    #[error("internal error: {0}")]
    Internal(String),
    /// The server is shutting down.
    #[error("the server is shutting down")]
    ShuttingDown,
}

/// The class of a [`SessionError`], for status codes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ErrorKind {
    /// 400 / INVALID_ARGUMENT.
    InvalidArgument,
    /// 404 / NOT_FOUND.
    NotFound,
    /// 429 / RESOURCE_EXHAUSTED.
    ResourceExhausted,
    /// 409 / FAILED_PRECONDITION.
    FailedPrecondition,
    /// 500 / INTERNAL.
    Internal,
    /// 503 / UNAVAILABLE.
    Unavailable,
}

impl SessionError {
    /// Its class.
    pub fn kind(&self) -> ErrorKind {
        match self {
            SessionError::Invalid { .. } => ErrorKind::InvalidArgument,
            SessionError::NotFound { .. } => ErrorKind::NotFound,
            SessionError::Exhausted(_) => ErrorKind::ResourceExhausted,
            SessionError::Failed { .. } => ErrorKind::FailedPrecondition,
            SessionError::Internal(_) => ErrorKind::Internal,
            SessionError::ShuttingDown => ErrorKind::Unavailable,
        }
    }

    /// A short stable label for metrics (`errors_total{reason=...}`).
    pub fn reason(&self) -> &'static str {
        match self {
            SessionError::Invalid { .. } => "invalid_argument",
            SessionError::NotFound { .. } => "not_found",
            SessionError::Exhausted(_) => "resource_exhausted",
            SessionError::Failed { .. } => "session_failed",
            SessionError::Internal(_) => "internal",
            SessionError::ShuttingDown => "shutting_down",
        }
    }

    /// An invalid-argument error.
    pub fn invalid(field: impl Into<String>, message: impl Into<String>) -> Self {
        SessionError::Invalid {
            field: field.into(),
            message: message.into(),
        }
    }
}

fn filter_error(e: FilterError) -> SessionError {
    let field = match &e {
        FilterError::UnknownFilter { .. } => "filter",
        FilterError::UnknownParam { .. } | FilterError::BadParam { .. } | FilterError::Assignment { .. } => {
            "params"
        }
        FilterError::MissingChannel { .. } => "channels",
        FilterError::SizeChanged { .. } => "size",
        _ => "frame",
    };
    SessionError::invalid(field, e.to_string())
}

/// The convention of a frame's motion when it reaches [`Sessions::process`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum MotionInput {
    /// The session's convention (the gRPC stream): converted here.
    Session,
    /// Already internal (an EXR whose preset named its convention).
    Internal,
}

/// What a client asks for when it opens a session.
#[derive(Clone, Debug, Default)]
pub struct SessionRequest {
    /// Registry name.
    pub filter: String,
    /// Parameter overrides as text, as `--set key=value` takes them.
    pub params: Vec<(String, String)>,
    /// Frame width.
    pub width: u32,
    /// Frame height.
    pub height: u32,
    /// Motion convention preset name (empty: internal).
    pub motion: String,
    /// Channel names the client will send (empty: the filter's `uses`).
    pub channels: Vec<String>,
}

/// What a client is told about a session.
#[derive(Clone, Debug, Serialize, PartialEq)]
pub struct SessionInfo {
    /// Unguessable id.
    pub id: String,
    /// Filter name.
    pub filter: String,
    /// Parameters in effect.
    pub params: Value,
    /// Frame width.
    pub width: u32,
    /// Frame height.
    pub height: u32,
    /// Motion convention preset.
    pub motion: String,
    /// Channels the client said it sends.
    pub channels: Vec<String>,
    /// Channels the filter needs.
    pub needs: Vec<String>,
    /// Channels the filter reads when present.
    pub uses: Vec<String>,
    /// Bytes of state reserved against the budget.
    pub state_bytes: u64,
    /// Frames filtered so far.
    pub frames: u64,
    /// Seconds since the last use.
    pub idle_seconds: f64,
    /// Frames of latency: frame t comes out after frame t + lookahead went in (windowed
    /// filters; 0 for causal ones).
    pub lookahead: u32,
}

/// A filtered frame and its figures.
#[derive(Clone, Debug)]
pub struct Filtered {
    /// The frame's index.
    pub index: u64,
    /// Filtered colour.
    pub color: Rgb,
    /// The filter's record.
    pub record: FrameRecord,
    /// PSNR against the frame's reference channel, when it had one.
    pub psnr: Option<f64>,
    /// SSIM against the reference, when it had one.
    pub ssim: Option<f64>,
}

struct Inner {
    filter: Box<dyn Filter>,
    /// Jitter of the previous frame, for jittered motion conventions.
    jitter_prev: Option<[f32; 2]>,
    /// Metric space fixed by the first reference seen.
    space: Option<MetricSpace>,
    frames: u64,
    failed: Option<String>,
    /// References of the frames filtered whose output has not come out yet (windowed
    /// filters hold `lookahead` of them), oldest first.
    pending: VecDeque<Option<Rgb>>,
    /// Outputs that came out but were not handed over yet (the HTTP API returns one per
    /// request), oldest first.
    ready: VecDeque<Filtered>,
}

impl Inner {
    /// Refuses work on a session whose filter panicked earlier, with that message.
    fn usable(&self, id: &str) -> Result<(), SessionError> {
        match &self.failed {
            Some(message) => Err(SessionError::Failed {
                id: id.to_string(),
                message: message.clone(),
            }),
            None => Ok(()),
        }
    }
}

struct Session {
    info: SessionInfo,
    channels: ChannelSet,
    needs: ChannelSet,
    motion: MotionConvention,
    last_used: Mutex<Instant>,
    inner: Mutex<Inner>,
}

fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    // A panic inside a filter is caught before it can poison; recover anyway.
    m.lock().unwrap_or_else(|p| p.into_inner())
}

/// Every open session.
pub struct Sessions {
    limits: Limits,
    map: Mutex<HashMap<String, Arc<Session>>>,
    closing: std::sync::atomic::AtomicBool,
}

/// Figures over every session, for `/metrics`.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Totals {
    /// Open sessions.
    pub sessions: usize,
    /// Bytes of state reserved.
    pub state_bytes: u64,
}

fn new_id() -> Result<String, SessionError> {
    let mut b = [0u8; 16];
    getrandom::fill(&mut b)
        .map_err(|e| SessionError::Internal(format!("no OS randomness for a session id: {e}")))?;
    Ok(b.iter().map(|x| format!("{x:02x}")).collect())
}

fn channel_names(set: ChannelSet) -> Vec<String> {
    set.iter().map(|k| k.name().to_string()).collect()
}

impl Sessions {
    /// No sessions yet, under `limits`.
    pub fn new(limits: Limits) -> Self {
        Sessions {
            limits,
            map: Mutex::new(HashMap::new()),
            closing: Default::default(),
        }
    }

    /// The limits.
    pub fn limits(&self) -> &Limits {
        &self.limits
    }

    /// Refuses new sessions and frames from now on (graceful shutdown).
    pub fn close_all_new_work(&self) {
        self.closing.store(true, std::sync::atomic::Ordering::SeqCst);
    }

    /// Whether [`Sessions::close_all_new_work`] was called.
    pub fn is_closing(&self) -> bool {
        self.closing.load(std::sync::atomic::Ordering::SeqCst)
    }

    fn check_open(&self) -> Result<(), SessionError> {
        if self.closing.load(std::sync::atomic::Ordering::SeqCst) {
            Err(SessionError::ShuttingDown)
        } else {
            Ok(())
        }
    }

    /// Opens a session: validates the filter, parameters, size, motion convention and
    /// channels, and reserves its state against the memory budget.
    pub fn create(&self, req: &SessionRequest) -> Result<SessionInfo, SessionError> {
        self.check_open()?;
        self.evict_idle();
        let info = pipeline::info(&req.filter).ok_or_else(|| {
            let known: Vec<&str> = pipeline::list().iter().map(|i| i.name).collect();
            SessionError::invalid(
                "filter",
                format!(
                    "unknown filter {:?}; expected one of {}",
                    req.filter,
                    known.join(", ")
                ),
            )
        })?;
        let pairs: Vec<String> = req.params.iter().map(|(k, v)| format!("{k}={v}")).collect();
        let values = pipeline::params::parse_assignments(&pairs).map_err(filter_error)?;
        let filter = pipeline::create(&req.filter, &values).map_err(filter_error)?;
        let l = &self.limits;
        for (field, got, max) in [
            ("width", req.width, l.max_width),
            ("height", req.height, l.max_height),
        ] {
            if got == 0 || got > max {
                return Err(SessionError::invalid(
                    field,
                    format!("expected 1..={max}, got {got}"),
                ));
            }
        }
        let motion_name = if req.motion.is_empty() {
            "internal"
        } else {
            req.motion.as_str()
        };
        let motion = MotionConvention::preset(motion_name).ok_or_else(|| {
            let known: Vec<&str> = MotionConvention::PRESETS.iter().map(|(n, _)| *n).collect();
            SessionError::invalid(
                "motion",
                format!(
                    "unknown convention {motion_name:?}; expected one of {}",
                    known.join(", ")
                ),
            )
        })?;
        let needs = ChannelSet::of(&info.needs);
        let uses = ChannelSet::of(&info.uses).with(ChannelKind::Color);
        let channels = if req.channels.is_empty() {
            uses
        } else {
            let mut set = ChannelSet::EMPTY;
            for name in &req.channels {
                let k = ChannelKind::from_name(name).ok_or_else(|| {
                    SessionError::invalid(
                        "channels",
                        format!(
                            "unknown channel {name:?}; expected any of {}",
                            ChannelKind::ALL.map(|k| k.name()).join(", ")
                        ),
                    )
                })?;
                set = set.with(k);
            }
            set
        };
        if let Some(missing) = needs.minus(channels).iter().next() {
            return Err(SessionError::invalid(
                "channels",
                format!(
                    "filter {} needs {missing}, which the channel list does not have",
                    info.name
                ),
            ));
        }
        let pixels = req.width as u64 * req.height as u64;
        let state_bytes = info.state_bytes_per_pixel as u64 * pixels;
        let id = new_id()?;
        let session = Arc::new(Session {
            info: SessionInfo {
                id: id.clone(),
                filter: info.name.to_string(),
                params: filter.params(),
                width: req.width,
                height: req.height,
                motion: motion_name.to_string(),
                channels: channel_names(channels),
                needs: channel_names(needs),
                uses: channel_names(uses),
                state_bytes,
                frames: 0,
                idle_seconds: 0.0,
                lookahead: filter.lookahead() as u32,
            },
            channels,
            needs,
            motion,
            last_used: Mutex::new(Instant::now()),
            inner: Mutex::new(Inner {
                filter,
                jitter_prev: None,
                space: None,
                frames: 0,
                failed: None,
                pending: VecDeque::new(),
                ready: VecDeque::new(),
            }),
        });
        let mut map = lock(&self.map);
        if map.len() >= l.max_sessions {
            return Err(SessionError::Exhausted(format!(
                "{} sessions open, the limit is {}; close one or wait for idle ones to be evicted ({} s)",
                map.len(),
                l.max_sessions,
                l.idle_timeout.as_secs()
            )));
        }
        let used: u64 = map.values().map(|s| s.info.state_bytes).sum();
        let free = l.memory_budget_bytes.saturating_sub(used);
        if state_bytes > free {
            return Err(SessionError::Exhausted(format!(
                "a {}x{} {} session needs {state_bytes} bytes of state, {free} of the {} byte budget are free",
                req.width, req.height, info.name, l.memory_budget_bytes
            )));
        }
        map.insert(id, session.clone());
        tracing::info!(id = %session.info.id, filter = info.name, width = req.width, height = req.height, "session opened");
        Ok(session.info.clone())
    }

    fn get_arc(&self, id: &str) -> Result<Arc<Session>, SessionError> {
        self.evict_idle();
        lock(&self.map)
            .get(id)
            .cloned()
            .ok_or_else(|| SessionError::NotFound {
                id: id.to_string(),
                idle_s: self.limits.idle_timeout.as_secs(),
            })
    }

    /// A session's figures.
    pub fn get(&self, id: &str) -> Result<SessionInfo, SessionError> {
        let s = self.get_arc(id)?;
        let mut info = s.info.clone();
        info.frames = lock(&s.inner).frames;
        info.idle_seconds = lock(&s.last_used).elapsed().as_secs_f64();
        Ok(info)
    }

    /// Closes a session; returns the frames it filtered.
    pub fn close(&self, id: &str) -> Result<u64, SessionError> {
        let s = lock(&self.map).remove(id).ok_or_else(|| SessionError::NotFound {
            id: id.to_string(),
            idle_s: self.limits.idle_timeout.as_secs(),
        })?;
        tracing::info!(id, "session closed");
        let frames = lock(&s.inner).frames;
        Ok(frames)
    }

    /// Closes every session idle for longer than the timeout; returns how many.
    pub fn evict_idle(&self) -> usize {
        let timeout = self.limits.idle_timeout;
        let mut map = lock(&self.map);
        let before = map.len();
        map.retain(|id, s| {
            let keep = lock(&s.last_used).elapsed() <= timeout;
            if !keep {
                tracing::info!(id = %id, "session evicted after being idle");
            }
            keep
        });
        before - map.len()
    }

    /// Open sessions and reserved state.
    pub fn totals(&self) -> Totals {
        let map = lock(&self.map);
        Totals {
            sessions: map.len(),
            state_bytes: map.values().map(|s| s.info.state_bytes).sum(),
        }
    }

    /// Hands an output's planes back to session `id`'s filter for reuse (see
    /// [`Filter::recycle`]); nothing happens when the session is gone.
    pub fn recycle(&self, id: &str, planes: Rgb) {
        if let Ok(s) = self.get_arc(id) {
            lock(&s.inner).filter.recycle(planes);
        }
    }

    /// The size and channels a frame for session `id` must have (for decoding).
    pub fn frame_shape(&self, id: &str) -> Result<(u32, u32, ChannelSet), SessionError> {
        let s = self.get_arc(id)?;
        Ok((s.info.width, s.info.height, s.channels))
    }

    /// Filters one frame of session `id` (blocking: call it on the rayon pool) and returns
    /// the outputs that came out, oldest first: this frame's own for a causal filter; for
    /// a windowed one the frame `lookahead` back (none while its window fills; a whole shot
    /// at a cut). The frame must have the session's size and the channels the filter
    /// needs; its motion is in the session's convention (or already internal with
    /// [`MotionInput::Internal`]). On any error the session's state is as it was.
    pub fn process(
        &self,
        id: &str,
        mut frame: Frame,
        motion: MotionInput,
    ) -> Result<Vec<Filtered>, SessionError> {
        self.check_open()?;
        let s = self.get_arc(id)?;
        *lock(&s.last_used) = Instant::now();
        let (w, h) = (s.info.width as usize, s.info.height as usize);
        if (frame.width(), frame.height()) != (w, h) {
            return Err(SessionError::invalid(
                "size",
                format!(
                    "frame {} is {}x{}, the session is {w}x{h}",
                    frame.meta.index,
                    frame.width(),
                    frame.height()
                ),
            ));
        }
        if let Some(missing) = s.needs.minus(frame.channels()).iter().next() {
            return Err(SessionError::invalid(
                "channels",
                format!(
                    "frame {} has no {missing} channel, which filter {} needs",
                    frame.meta.index, s.info.filter
                ),
            ));
        }
        let nf = frame.non_finite();
        let bad = nf.of(ChannelKind::Color);
        let fraction = bad as f64 / (3 * w * h) as f64;
        if fraction > self.limits.max_non_finite_fraction {
            return Err(SessionError::invalid(
                "color",
                format!(
                    "frame {}: {bad} of {} colour samples are NaN or infinite ({:.1}%), at most {:.1}% allowed",
                    frame.meta.index,
                    3 * w * h,
                    fraction * 100.0,
                    self.limits.max_non_finite_fraction * 100.0
                ),
            ));
        }
        let mut inner = lock(&s.inner);
        inner.usable(id)?;
        if motion == MotionInput::Session {
            let prev = inner.jitter_prev.unwrap_or(frame.meta.jitter);
            s.motion.frame_to_internal(&mut frame, prev);
        }
        let jitter = frame.meta.jitter;
        let index = frame.meta.index;
        inner.pending.push_back(frame.reference().cloned());
        let outs = Self::guarded(&s.info.filter, id, &mut inner, &format!("frame {index}"), |f| {
            f.push(&frame)
        });
        if outs.is_err() {
            inner.pending.pop_back();
        }
        let outs = outs?;
        inner.jitter_prev = Some(jitter);
        inner.frames += 1;
        outs.into_iter().map(|o| Self::measured(&mut inner, o)).collect()
    }

    /// Ends session `id`'s sequence: the outputs a windowed filter still holds, oldest
    /// first (none for a causal filter). The session stays open; the next frame starts a
    /// new sequence.
    pub fn flush(&self, id: &str) -> Result<Vec<Filtered>, SessionError> {
        self.check_open()?;
        let s = self.get_arc(id)?;
        *lock(&s.last_used) = Instant::now();
        let mut inner = lock(&s.inner);
        inner.usable(id)?;
        let outs = Self::guarded(&s.info.filter, id, &mut inner, "the flush", |f| f.finish())?;
        let outs: Result<Vec<Filtered>, SessionError> =
            outs.into_iter().map(|o| Self::measured(&mut inner, o)).collect();
        inner.pending.clear();
        outs
    }

    /// Queues outputs of session `id` to be handed over one at a time, then takes the
    /// oldest queued one; also returns how many are left after it.
    pub fn queue_and_take(
        &self,
        id: &str,
        outs: Vec<Filtered>,
    ) -> Result<(Option<Filtered>, usize), SessionError> {
        let s = self.get_arc(id)?;
        let mut inner = lock(&s.inner);
        inner.ready.extend(outs);
        let first = inner.ready.pop_front();
        Ok((first, inner.ready.len()))
    }

    /// Runs `call` on the session's filter with a panic kept inside the session: the
    /// session is marked failed (later frames are refused with the message) and the
    /// server goes on.
    fn guarded(
        filter: &str,
        id: &str,
        inner: &mut Inner,
        what: &str,
        call: impl FnOnce(&mut dyn Filter) -> Result<Vec<pipeline::Output>, FilterError>,
    ) -> Result<Vec<pipeline::Output>, SessionError> {
        match catch_unwind(AssertUnwindSafe(|| call(inner.filter.as_mut()))) {
            Ok(Ok(outs)) => Ok(outs),
            Ok(Err(e)) => Err(filter_error(e)),
            Err(panic) => {
                let cause = panic
                    .downcast_ref::<&str>()
                    .map(|s| s.to_string())
                    .or_else(|| panic.downcast_ref::<String>().cloned())
                    .unwrap_or_else(|| "a panic".into());
                let message = format!("filter {filter} panicked on {what}: {cause}");
                tracing::error!(id, %message, "session failed");
                inner.failed = Some(message.clone());
                Err(SessionError::Internal(message))
            }
        }
    }

    /// An output with its figures against the reference its frame came with.
    fn measured(inner: &mut Inner, out: pipeline::Output) -> Result<Filtered, SessionError> {
        let reference = inner.pending.pop_front().flatten();
        let (psnr, ssim_v) = match reference {
            Some(r) => {
                let space = *inner.space.get_or_insert_with(|| SpaceChoice::Auto.resolve(&r));
                let m = mse(&out.color, &r, space).map_err(|e| SessionError::Internal(e.to_string()))?;
                let s = ssim(&luma(&out.color, space), &luma(&r, space), false)
                    .map_err(|e| SessionError::Internal(e.to_string()))?
                    .mean;
                (Some(psnr_from_mse(m)), Some(s))
            }
            None => (None, None),
        };
        Ok(Filtered {
            index: out.record.index,
            color: out.color,
            record: out.record,
            psnr,
            ssim: ssim_v,
        })
    }
}

/// Parameter overrides from a JSON object (the HTTP API's form), as text pairs.
pub fn params_from_json(map: &Map<String, Value>) -> Vec<(String, String)> {
    map.iter()
        .map(|(k, v)| {
            let text = match v {
                Value::String(s) => s.clone(),
                other => other.to_string(),
            };
            (k.clone(), text)
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::pipeline::Output;
    use crate::report::synthetic_frame;

    /// Delegates to a real filter but panics on one frame index: the only way to exercise
    /// the isolation path, since no shipped filter panics on purpose.
    struct PanicsOn {
        inner: Box<dyn Filter>,
        index: u64,
    }

    impl Filter for PanicsOn {
        fn name(&self) -> &'static str {
            self.inner.name()
        }
        fn params(&self) -> Value {
            self.inner.params()
        }
        fn process(&mut self, frame: &Frame) -> Result<Output, FilterError> {
            if frame.meta.index == self.index {
                panic!("injected fault at frame {}", self.index);
            }
            self.inner.process(frame)
        }
        fn reset(&mut self) {
            self.inner.reset()
        }
        fn state_bytes(&self) -> usize {
            self.inner.state_bytes()
        }
    }

    fn open(sessions: &Sessions, filter: &str) -> String {
        let req = SessionRequest {
            filter: filter.into(),
            width: 24,
            height: 16,
            ..Default::default()
        };
        sessions.create(&req).expect("valid session").id
    }

    fn frame(index: u64) -> Frame {
        let mut f = synthetic_frame(24, 16, index);
        f.meta.index = index;
        f
    }

    #[test]
    fn a_panicking_filter_fails_only_its_session() {
        let sessions = Sessions::new(Limits::default());
        let sick = open(&sessions, "taa");
        let healthy = open(&sessions, "taa");
        {
            let s = sessions.get_arc(&sick).unwrap();
            let mut inner = lock(&s.inner);
            let real = std::mem::replace(
                &mut inner.filter,
                pipeline::create("passthrough", &Map::new()).unwrap(),
            );
            inner.filter = Box::new(PanicsOn {
                inner: real,
                index: 2,
            });
        }
        let mut reference = pipeline::create("taa", &Map::new()).unwrap();
        for i in 0..5 {
            let want = reference.process(&frame(i)).unwrap().color;
            // The healthy session is filtered between the sick one's frames, on the same
            // thread, before and after the panic: it must match in-process filtering exactly.
            let got = sessions
                .process(&healthy, frame(i), MotionInput::Internal)
                .unwrap();
            assert_eq!(got.len(), 1, "a causal filter gives its frame at once");
            assert_eq!(got[0].color, want, "healthy session, frame {i}");
            let sick_result = sessions.process(&sick, frame(i), MotionInput::Internal);
            match (i, sick_result) {
                (0 | 1, Ok(_)) => {}
                (2, Err(SessionError::Internal(m))) => {
                    assert!(m.contains("injected fault at frame 2"), "{m}");
                    assert!(m.contains("filter taa panicked on frame 2"), "{m}");
                }
                (3 | 4, Err(e @ SessionError::Failed { .. })) => {
                    assert_eq!(e.kind(), ErrorKind::FailedPrecondition);
                    assert!(e.to_string().contains("injected fault"), "{e}");
                }
                (i, other) => panic!("sick session, frame {i}: unexpected {other:?}"),
            }
        }
        // The failed session can still be inspected and closed, which frees its budget.
        assert_eq!(sessions.get(&sick).unwrap().frames, 2);
        let before = sessions.totals();
        sessions.close(&sick).unwrap();
        let after = sessions.totals();
        assert_eq!(after.sessions, before.sessions - 1);
        assert!(after.state_bytes < before.state_bytes);
        // And a new session works.
        let fresh = open(&sessions, "phlm");
        sessions.process(&fresh, frame(0), MotionInput::Internal).unwrap();
    }
}
