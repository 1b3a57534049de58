//! Sessions: one filter instance with its history per client stream, behind limits (count,
//! one memory budget over all state and requests, frame size, per-key quotas), with idle
//! eviction and failure isolation. Synchronous and transport-free: the gRPC and HTTP layers
//! in `server` call it, and run the filtering on the rayon pool.
//!
//! Concurrency: a session's filter is never behind a lock while it runs. A request
//! [checks the session out](Sessions::checkout) (a few instructions under a mutex), works
//! on it with no lock held, and the [`Checkout`] puts it back when dropped. A second
//! request meanwhile is refused at once ("session busy"), so nothing waits on a frame: not
//! the pool, not the async workers, not `GET`. A gRPC stream [claims](Sessions::attach) its
//! session for as long as it is open; other streams and HTTP frames are refused.
//!
//! A session outlives the connections that feed it, so a client can reconnect by id until
//! the idle timeout.

pub mod access;
pub mod budget;
mod error;
pub mod region;

pub use access::{ApiKey, Caller, Keyring, Quotas};
pub use budget::{Budget, Reservation};
pub use error::{cap_message, clip, ErrorKind, SessionError, ECHO_CHARS, MAX_MESSAGE_BYTES};
pub use region::Region;

use crate::backend::Created;
use crate::filters;
use crate::frame::{ChannelKind, ChannelSet, Frame, FrameMeta, MotionConvention, Plane, Rgb};
use crate::io::InputImage;
use crate::pipeline::exec::panic_text;
use crate::pipeline::{self, Filter, FilterError, FilterInfo, FilterState, FrameRecord};
use access::SessionSlot;
use afterimage_core::metrics::{luma, mse, psnr_from_mse, ssim, MetricSpace, SpaceChoice};
use error::filter_error;
use rayon::prelude::*;
use serde::Serialize;
use serde_json::{Map, Value};
use std::collections::{HashMap, VecDeque};
use std::panic::{catch_unwind, AssertUnwindSafe};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::{Duration, Instant};

/// Limits every session is held to.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Limits {
    /// Sessions open at once.
    pub max_sessions: usize,
    /// Bytes the server may hold for its clients: session state, frames being received,
    /// decoded and answered.
    pub memory_budget_bytes: u64,
    /// A session unused this long is closed.
    pub idle_timeout: Duration,
    /// Largest frame width.
    pub max_width: u32,
    /// Largest frame height.
    pub max_height: u32,
    /// Largest encoded frame (all channels, on the wire).
    pub max_frame_bytes: u64,
    /// Largest share of non-finite colour samples a frame may have; a frame above it is
    /// refused (a NaN flood is a renderer bug, not something to filter).
    pub max_non_finite_fraction: f64,
    /// This server's name among replicas behind one address, said in "no such session"
    /// answers so a client can tell a lost session from a wrong id.
    pub replica: String,
    /// The backend of sessions that do not name one.
    pub default_backend: crate::backend::BackendChoice,
    /// Signs exported state, and imports must carry its signature (see
    /// [`crate::pipeline::state`]); a secret, never shown.
    #[serde(skip)]
    pub state_key: Option<crate::pipeline::state::StateKey>,
    /// Whether sessions may have shared memory regions.
    pub shared_memory: bool,
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
            replica: "local".into(),
            default_backend: crate::backend::BackendChoice::Cpu,
            state_key: None,
            shared_memory: true,
        }
    }
}

/// The convention of a frame's motion when it reaches [`Checkout::process`].
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
    /// Where the filter runs: `cpu`, `gpu` or `auto` (empty: the server's default,
    /// [`Limits::default_backend`]).
    pub backend: String,
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
    /// Where the filter runs.
    pub backend: crate::backend::Backend,
}

/// The size and channels of a session's frames: what a transport checks a frame against
/// before receiving or decoding it, and sizes its memory reservation by.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct FrameShape {
    /// Width.
    pub width: u32,
    /// Height.
    pub height: u32,
    /// Channels the client declared (a reference may come too).
    pub channels: ChannelSet,
}

impl FrameShape {
    /// Pixels of a frame.
    pub fn pixels(&self) -> u64 {
        self.width as u64 * self.height as u64
    }

    /// Float components per pixel of a decoded frame: every declared channel plus a
    /// reference (object ids count as one 4-byte component).
    pub fn components(&self) -> u64 {
        self.channels
            .with(ChannelKind::Reference)
            .iter()
            .map(|k| k.components() as u64)
            .sum()
    }

    /// Bytes of a decoded frame at most (4 per component).
    pub fn decoded_bytes(&self) -> u64 {
        self.pixels() * self.components() * 4
    }

    /// Bytes of a filtered colour output (three f32 planes).
    pub fn output_bytes(&self) -> u64 {
        self.pixels() * 12
    }
}

/// A filtered frame and its figures.
#[derive(Debug)]
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
    /// The frame's values as they were filtered (index, jitter, reset).
    pub meta: FrameMeta,
    /// The input file it replaces, when the transport kept it (HTTP).
    pub input: Option<KeptInput>,
}

/// A frame's decoded input file, kept until its output is written (windowed filters keep
/// `lookahead` of them), with its share of the memory budget.
#[derive(Debug)]
pub struct KeptInput {
    /// The input.
    pub image: InputImage,
    _hold: Reservation,
}

impl KeptInput {
    /// Keeps `image`, its bytes reserved in `caller`'s budgets.
    pub fn new(sessions: &Sessions, caller: &Caller, image: InputImage) -> Result<KeptInput, SessionError> {
        let hold = sessions.reserve(
            caller,
            image.bytes(),
            "an input kept for its output's pass-through",
        )?;
        Ok(KeptInput { image, _hold: hold })
    }
}

/// What a frame in a filter's window waits with: its reference, values and input.
#[derive(Debug)]
struct Pending {
    reference: Option<Rgb>,
    meta: FrameMeta,
    input: Option<KeptInput>,
}

/// State-file notes a session adds to its filter's state.
const NOTE_NEXT_INDEX: &str = "session.next_index";
const NOTE_JITTER_PREV: &str = "session.jitter_prev";
const NOTE_METRIC_SPACE: &str = "session.metric_space";

/// A session's filter and everything that changes frame by frame: owned by whoever has the
/// session checked out.
struct Inner {
    filter: Box<dyn Filter>,
    /// Jitter of the previous frame, for jittered motion conventions.
    jitter_prev: Option<[f32; 2]>,
    /// Metric space fixed by the first reference seen.
    space: Option<MetricSpace>,
    /// What the frames filtered whose output has not come out yet wait with (windowed
    /// filters hold `lookahead` of them), oldest first.
    pending: VecDeque<Pending>,
    /// The index given to the next frame that comes without one.
    next_index: u64,
    /// Outputs that came out but were not handed over yet (the HTTP API returns one per
    /// request), oldest first.
    ready: VecDeque<Filtered>,
    /// The last frame's input planes, which decode the next one: fresh multi-MiB planes
    /// cost a page fault per 4 KiB, the largest share of a streamed frame's server time.
    inputs: pipeline::Scratch,
}

/// Where a session's [`Inner`] is.
enum Slot {
    /// Free to check out.
    Idle(Box<Inner>),
    /// Checked out by a request, filtering the frame of this index (None: still receiving
    /// it).
    Busy(Option<u64>),
    /// A filter panicked; the state is dropped and every later request gets this message.
    Failed(String),
}

struct Session {
    info: SessionInfo,
    /// The key that created it (None: a server without keys).
    owner: Option<String>,
    channels: ChannelSet,
    needs: ChannelSet,
    motion: MotionConvention,
    /// Largest share of non-finite colour samples in a frame.
    non_finite_limit: f64,
    /// Signs its exports and checks its imports.
    state_key: Option<crate::pipeline::state::StateKey>,
    last_used: Mutex<Instant>,
    frames: AtomicU64,
    slot: Mutex<Slot>,
    /// A gRPC stream has claimed it.
    streamed: AtomicBool,
    /// Its state's share of the budgets (grown when the filter holds more than reserved).
    state: Mutex<Reservation>,
    /// Its place in its key's session quota.
    _quota: SessionSlot,
    /// Its shared memory region, once a client opened one (removed with the session).
    region: Mutex<Option<Arc<Region>>>,
}

impl Session {
    fn shape(&self) -> FrameShape {
        FrameShape {
            width: self.info.width,
            height: self.info.height,
            channels: self.channels,
        }
    }

    fn touch(&self) {
        *lock(&self.last_used) = Instant::now();
    }
}

fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    // Nothing panics while these short locks are held; recover anyway.
    m.lock().unwrap_or_else(|p| p.into_inner())
}

/// Every open session.
pub struct Sessions {
    limits: Limits,
    budget: Arc<Budget>,
    map: Mutex<HashMap<String, Arc<Session>>>,
    closing: AtomicBool,
}

/// Figures over every session, for `/metrics`.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Totals {
    /// Open sessions.
    pub sessions: usize,
    /// Bytes of state reserved.
    pub state_bytes: u64,
    /// Bytes of the memory budget in use (state and requests in flight).
    pub budget_used: u64,
    /// The memory budget.
    pub budget_limit: u64,
}

fn new_id() -> Result<String, SessionError> {
    random_hex(16).map_err(|e| SessionError::Internal(format!("no OS randomness for a session id: {e}")))
}

/// `bytes` random bytes from the OS, as lower-case hex (session ids, routing keys).
pub fn random_hex(bytes: usize) -> Result<String, getrandom::Error> {
    let mut b = vec![0u8; bytes];
    getrandom::fill(&mut b)?;
    Ok(b.iter().map(|x| format!("{x:02x}")).collect())
}

/// The motion convention a request names (`internal` when it names none), with its name.
fn requested_motion(req: &SessionRequest) -> Result<(String, MotionConvention), SessionError> {
    let name = if req.motion.is_empty() {
        "internal"
    } else {
        req.motion.as_str()
    };
    let motion = MotionConvention::preset(name).ok_or_else(|| {
        let known: Vec<&str> = MotionConvention::PRESETS.iter().map(|(n, _)| *n).collect();
        SessionError::invalid(
            "motion",
            format!(
                "unknown convention {:?}; expected one of {}",
                clip(name),
                known.join(", ")
            ),
        )
    })?;
    Ok((name.to_string(), motion))
}

/// The channels a request will send (the filter's `uses` and colour when it lists none),
/// and the filter's `needs` and `uses`; refused when the list lacks a needed one.
fn requested_channels(
    req: &SessionRequest,
    info: &FilterInfo,
) -> Result<(ChannelSet, ChannelSet, ChannelSet), SessionError> {
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
                        "unknown channel {:?}; expected any of {}",
                        clip(name),
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
    Ok((channels, needs, uses))
}

fn channel_names(set: ChannelSet) -> Vec<String> {
    set.iter().map(|k| k.name().to_string()).collect()
}

/// Bytes per pixel a session holds beyond its filter's state: a windowed filter's
/// references waiting for their outputs and the outputs queued for HTTP (up to
/// `lookahead + 1` of each, three f32 planes).
fn queued_bytes_per_pixel(lookahead: usize) -> usize {
    if lookahead == 0 {
        0
    } else {
        2 * (lookahead + 1) * 12
    }
}

impl Sessions {
    /// No sessions yet, under `limits`.
    pub fn new(limits: Limits) -> Self {
        Sessions {
            budget: Budget::new("the memory budget", limits.memory_budget_bytes),
            limits,
            map: Mutex::new(HashMap::new()),
            closing: Default::default(),
        }
    }

    /// The limits.
    pub fn limits(&self) -> &Limits {
        &self.limits
    }

    /// The server's memory budget (state and requests of every session).
    pub fn budget(&self) -> &Arc<Budget> {
        &self.budget
    }

    /// Refuses new sessions and frames from now on (graceful shutdown).
    pub fn close_all_new_work(&self) {
        self.closing.store(true, Ordering::SeqCst);
    }

    /// Whether [`Sessions::close_all_new_work`] was called.
    pub fn is_closing(&self) -> bool {
        self.closing.load(Ordering::SeqCst)
    }

    fn check_open(&self) -> Result<(), SessionError> {
        if self.is_closing() {
            Err(SessionError::ShuttingDown)
        } else {
            Ok(())
        }
    }

    /// The budgets a request of `caller` counts against: the server's and the key's.
    fn budgets_of(&self, caller: &Caller) -> Vec<Arc<Budget>> {
        let mut b = vec![self.budget.clone()];
        if let Some(k) = caller.api_key() {
            b.push(k.memory.clone());
        }
        b
    }

    /// Takes `bytes` of the memory budget (and the caller's quota) for a request, named
    /// `what` in the error when they are not free.
    pub fn reserve(&self, caller: &Caller, bytes: u64, what: &str) -> Result<Reservation, SessionError> {
        let budgets = self.budgets_of(caller);
        Reservation::take(&budgets.iter().collect::<Vec<_>>(), bytes, what)
    }

    /// Opens a session for `caller`: validates the filter, parameters, size, motion
    /// convention and channels, and reserves the state its parameters build against the
    /// memory budget and the caller's quotas.
    pub fn create(&self, caller: &Caller, req: &SessionRequest) -> Result<SessionInfo, SessionError> {
        self.check_open()?;
        self.evict_idle();
        let (info, made) = self.requested_filter(req)?;
        let (filter, state_bpp, backend) = (made.filter, made.state_bytes_per_pixel, made.backend);
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
        let (motion_name, motion) = requested_motion(req)?;
        let (channels, needs, uses) = requested_channels(req, &info)?;
        let pixels = req.width as u64 * req.height as u64;
        let lookahead = filter.lookahead();
        // The filter's state, the frames a window holds, and the planes of the last
        // frame's input that decode the next ([`Checkout::input_planes`]).
        let inputs = FrameShape {
            width: req.width,
            height: req.height,
            channels,
        }
        .decoded_bytes();
        let state_bytes = (state_bpp + queued_bytes_per_pixel(lookahead)) as u64 * pixels + inputs;
        let quota = caller.session_slot()?;
        let budgets = self.budgets_of(caller);
        let reservation = Reservation::take(
            &budgets.iter().collect::<Vec<_>>(),
            state_bytes,
            &format!(
                "a {}x{} {} session with {}",
                req.width,
                req.height,
                info.name,
                filter.params()
            ),
        )?;
        let id = new_id()?;
        let session = Arc::new(Session {
            info: SessionInfo {
                id: id.clone(),
                filter: info.name.to_string(),
                params: filter.params(),
                width: req.width,
                height: req.height,
                motion: motion_name,
                channels: channel_names(channels),
                needs: channel_names(needs),
                uses: channel_names(uses),
                state_bytes,
                frames: 0,
                idle_seconds: 0.0,
                lookahead: lookahead as u32,
                backend,
            },
            owner: caller.name().map(str::to_string),
            channels,
            needs,
            motion,
            non_finite_limit: l.max_non_finite_fraction,
            state_key: l.state_key.clone(),
            last_used: Mutex::new(Instant::now()),
            frames: AtomicU64::new(0),
            slot: Mutex::new(Slot::Idle(Box::new(Inner {
                filter,
                jitter_prev: None,
                space: None,
                pending: VecDeque::new(),
                next_index: 0,
                ready: VecDeque::new(),
                inputs: pipeline::Scratch::default(),
            }))),
            streamed: AtomicBool::new(false),
            state: Mutex::new(reservation),
            _quota: quota,
            region: Mutex::new(None),
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
        map.insert(id, session.clone());
        drop(map);
        tracing::info!(id = %session.info.id, key = caller.name().unwrap_or("-"), filter = info.name, width = req.width, height = req.height, state_bytes, "session opened");
        Ok(session.info.clone())
    }

    /// The filter a request names, made on the backend it (or the server's default) asks
    /// for, with its parameters checked.
    fn requested_filter(&self, req: &SessionRequest) -> Result<(FilterInfo, Created), SessionError> {
        let info = filters::info(&req.filter).ok_or_else(|| {
            let known: Vec<&str> = filters::list().iter().map(|i| i.name).collect();
            SessionError::invalid(
                "filter",
                format!(
                    "unknown filter {:?}; expected one of {}",
                    clip(&req.filter),
                    known.join(", ")
                ),
            )
        })?;
        if req.params.len() > 64 {
            return Err(SessionError::invalid(
                "params",
                format!("{} parameters, at most 64", req.params.len()),
            ));
        }
        let pairs: Vec<String> = req.params.iter().map(|(k, v)| format!("{k}={v}")).collect();
        let values = pipeline::params::parse_assignments(&pairs).map_err(filter_error)?;
        let choice = if req.backend.is_empty() {
            self.limits.default_backend
        } else {
            req.backend
                .parse::<crate::backend::BackendChoice>()
                .map_err(|e| SessionError::invalid("backend", e.to_string()))?
        };
        let made = crate::backend::create(&req.filter, &values, choice).map_err(|e| match e {
            crate::backend::BackendError::Filter(e) => filter_error(e),
            other => SessionError::invalid("backend", other.to_string()),
        })?;
        Ok((info, made))
    }

    fn not_found(&self, id: &str) -> SessionError {
        SessionError::NotFound {
            id: clip(id).into_owned(),
            idle_s: self.limits.idle_timeout.as_secs(),
            replica: self.limits.replica.clone(),
        }
    }

    /// Session `id` if `caller` owns it: another key's session is "not found", the same
    /// reply as for an id that never existed.
    fn get_arc(&self, caller: &Caller, id: &str) -> Result<Arc<Session>, SessionError> {
        self.evict_idle();
        lock(&self.map)
            .get(id)
            .filter(|s| s.owner.as_deref() == caller.name())
            .cloned()
            .ok_or_else(|| self.not_found(id))
    }

    /// A session's figures; never waits for a frame being filtered.
    pub fn get(&self, caller: &Caller, id: &str) -> Result<SessionInfo, SessionError> {
        let s = self.get_arc(caller, id)?;
        let mut info = s.info.clone();
        info.frames = s.frames.load(Ordering::SeqCst);
        info.idle_seconds = lock(&s.last_used).elapsed().as_secs_f64();
        info.state_bytes = lock(&s.state).bytes();
        Ok(info)
    }

    /// Closes a session; returns the frames it filtered. A frame being filtered finishes,
    /// and the session's memory is given back when it does.
    pub fn close(&self, caller: &Caller, id: &str) -> Result<u64, SessionError> {
        let mut map = lock(&self.map);
        let owned = map.get(id).is_some_and(|s| s.owner.as_deref() == caller.name());
        let s = owned
            .then(|| map.remove(id))
            .flatten()
            .ok_or_else(|| self.not_found(id))?;
        drop(map);
        tracing::info!(id, "session closed");
        Ok(s.frames.load(Ordering::SeqCst))
    }

    /// Closes every session idle for longer than the timeout (but not one that is
    /// filtering a frame); returns how many.
    pub fn evict_idle(&self) -> usize {
        let timeout = self.limits.idle_timeout;
        let mut map = lock(&self.map);
        let before = map.len();
        map.retain(|id, s| {
            let busy = matches!(*lock(&s.slot), Slot::Busy(_));
            let keep = busy || lock(&s.last_used).elapsed() <= timeout;
            if !keep {
                tracing::info!(id = %id, "session evicted after being idle");
            }
            keep
        });
        before - map.len()
    }

    /// Open sessions, reserved state and the budget.
    pub fn totals(&self) -> Totals {
        let map = lock(&self.map);
        Totals {
            sessions: map.len(),
            state_bytes: map.values().map(|s| lock(&s.state).bytes()).sum(),
            budget_used: self.budget.used(),
            budget_limit: self.budget.limit(),
        }
    }

    /// The frame shape of session `id`.
    pub fn frame_shape(&self, caller: &Caller, id: &str) -> Result<FrameShape, SessionError> {
        Ok(self.get_arc(caller, id)?.shape())
    }

    /// Takes session `id` for one request (a frame over HTTP, a flush): refused at once
    /// when it is busy with another frame, fed by a gRPC stream, or failed. The session is
    /// put back when the [`Checkout`] is dropped.
    pub fn checkout(&self, caller: &Caller, id: &str) -> Result<Checkout, SessionError> {
        self.check_open()?;
        let s = self.get_arc(caller, id)?;
        if s.streamed.load(Ordering::SeqCst) {
            return Err(SessionError::Busy(format!(
                "session busy: session {} is fed by a gRPC stream; send its frames there",
                s.info.id
            )));
        }
        Checkout::take(s)
    }

    /// Session `id`'s shared memory region, made on the first call (`bytes` long, at most
    /// what two frames in flight and their f32 replies can take) and the same one after
    /// with the same size. Refused when the server's config turns regions off. Its memory
    /// (the file, and the buffers a frame and a reply are staged in) is reserved against
    /// the caller's budgets until the session closes.
    pub fn open_region(&self, caller: &Caller, id: &str, bytes: u64) -> Result<Arc<Region>, SessionError> {
        self.check_open()?;
        let s = self.get_arc(caller, id)?;
        if !self.limits.shared_memory {
            return Err(SessionError::invalid(
                "shared_memory",
                "this server serves no shared memory regions (shared_memory = false); stream the frames' bytes instead",
            ));
        }
        if s.info.lookahead > 0 {
            return Err(SessionError::invalid(
                "session_id",
                format!(
                    "session {id} runs a windowed filter ({}, {} frames of lookahead): its outputs come after later frames and have no place of their own in a region; stream its frames' bytes instead",
                    s.info.filter, s.info.lookahead
                ),
            ));
        }
        let shape = s.shape();
        let max = 2 * (shape.decoded_bytes() + shape.output_bytes());
        if bytes == 0 || bytes > max {
            return Err(SessionError::invalid(
                "bytes",
                format!(
                    "a region of {bytes} bytes for a {}x{} session: expected 1 to {max} (two frames of its channels as f32 and their replies)",
                    shape.width, shape.height
                ),
            ));
        }
        let mut slot = lock(&s.region);
        // Again under the lock: a region made after `close_regions` swept would outlive
        // the server.
        self.check_open()?;
        if let Some(r) = slot.as_ref() {
            return if r.bytes() == bytes {
                Ok(r.clone())
            } else {
                Err(SessionError::invalid(
                    "bytes",
                    format!(
                        "session {id} has a region of {} bytes; a session has one region (close the session for another size)",
                        r.bytes()
                    ),
                ))
            };
        }
        let hold = self.reserve(
            caller,
            2 * bytes,
            &format!("a shared memory region of {bytes} bytes"),
        )?;
        let region = Arc::new(Region::create(bytes, hold)?);
        tracing::info!(id, bytes, path = %region.path().display(), "shared memory region opened");
        *slot = Some(region.clone());
        Ok(region)
    }

    /// Drops every session's shared memory region (their files are removed once no frame
    /// in flight holds them): for a server that stops.
    pub fn close_regions(&self) {
        for s in lock(&self.map).values() {
            lock(&s.region).take();
        }
    }

    /// Claims session `id` for a gRPC stream until the [`StreamClaim`] is dropped: refused
    /// when another stream has it.
    pub fn attach(&self, caller: &Caller, id: &str) -> Result<StreamClaim, SessionError> {
        self.check_open()?;
        let s = self.get_arc(caller, id)?;
        if s.streamed
            .compare_exchange(false, true, Ordering::SeqCst, Ordering::SeqCst)
            .is_err()
        {
            return Err(SessionError::Busy(format!(
                "session busy: session {} is fed by another stream; one stream per session",
                s.info.id
            )));
        }
        Ok(StreamClaim { session: s })
    }
}

/// A session claimed by one gRPC stream.
pub struct StreamClaim {
    session: Arc<Session>,
}

impl StreamClaim {
    /// The session's id.
    pub fn id(&self) -> &str {
        &self.session.info.id
    }

    /// The session's frame shape.
    pub fn shape(&self) -> FrameShape {
        self.session.shape()
    }

    /// The session's shared memory region, if a client opened one.
    pub fn region(&self) -> Option<Arc<Region>> {
        lock(&self.session.region).clone()
    }

    /// Takes the session for the stream's next frame (refused when it failed). A frame
    /// whose header came before a shutdown is still filtered.
    pub fn checkout(&self) -> Result<Checkout, SessionError> {
        Checkout::take(self.session.clone())
    }
}

impl Drop for StreamClaim {
    fn drop(&mut self) {
        self.session.streamed.store(false, Ordering::SeqCst);
    }
}

/// A session taken by one request: its filter, with no lock held. Dropping it puts the
/// session back (or leaves it failed, when its filter panicked).
pub struct Checkout {
    session: Arc<Session>,
    inner: Option<Box<Inner>>,
    /// Set when the filter panicked: the state may be torn.
    failed: Option<String>,
}

impl Checkout {
    fn take(session: Arc<Session>) -> Result<Checkout, SessionError> {
        let inner = {
            let mut slot = lock(&session.slot);
            match std::mem::replace(&mut *slot, Slot::Busy(None)) {
                Slot::Idle(inner) => inner,
                Slot::Busy(index) => {
                    *slot = Slot::Busy(index);
                    return Err(SessionError::Busy(match index {
                        Some(i) => format!("session busy: frame {i} is being filtered"),
                        None => "session busy: a frame is being received".into(),
                    }));
                }
                Slot::Failed(message) => {
                    *slot = Slot::Failed(message.clone());
                    return Err(SessionError::Failed {
                        id: session.info.id.clone(),
                        message,
                    });
                }
            }
        };
        session.touch();
        Ok(Checkout {
            session,
            inner: Some(inner),
            failed: None,
        })
    }

    /// The session's id.
    pub fn id(&self) -> &str {
        &self.session.info.id
    }

    /// The session's frame shape.
    pub fn shape(&self) -> FrameShape {
        self.session.shape()
    }

    /// The session's frames of latency (windowed filters).
    pub fn lookahead(&self) -> u32 {
        self.session.info.lookahead
    }

    fn inner(&mut self) -> Result<&mut Inner, SessionError> {
        if let Some(message) = &self.failed {
            return Err(SessionError::Failed {
                id: self.session.info.id.clone(),
                message: message.clone(),
            });
        }
        Ok(self.inner.as_mut().expect("present until dropped or failed"))
    }

    /// Filters one frame and returns the outputs that came out, oldest first: this frame's
    /// own for a causal filter; for a windowed one the frame `lookahead` back (none while
    /// its window fills; a whole shot at a cut). The frame must have the session's size
    /// and the channels the filter needs; its motion is in the session's convention (or
    /// already internal with [`MotionInput::Internal`]). On any error but a filter panic
    /// the session's state is as it was; after a panic the session is failed.
    pub fn process(&mut self, frame: Frame, motion: MotionInput) -> Result<Vec<Filtered>, SessionError> {
        self.process_kept(frame, motion, None)
    }

    /// [`Checkout::process`] for a frame decoded from the wire, whose colour's NaN and
    /// infinite samples were counted as it was copied in (see [`crate::wire::Decoded`]).
    pub fn process_decoded(
        &mut self,
        d: crate::wire::Decoded,
        motion: MotionInput,
    ) -> Result<Vec<Filtered>, SessionError> {
        self.filter_frame(d.frame, motion, None, d.color_non_finite)
    }

    /// The index the session gives its next frame when the frame has none: one past the
    /// last frame's (0 first).
    pub fn next_index(&mut self) -> Result<u64, SessionError> {
        Ok(self.inner()?.next_index)
    }

    /// [`Checkout::process`], keeping the frame's input file until its output comes out
    /// (it is in that output's [`Filtered::input`]).
    pub fn process_kept(
        &mut self,
        frame: Frame,
        motion: MotionInput,
        input: Option<KeptInput>,
    ) -> Result<Vec<Filtered>, SessionError> {
        self.filter_frame(frame, motion, input, None)
    }

    /// Checks and filters a frame; `color_non_finite` is its colour's NaN and infinite
    /// samples when already counted.
    fn filter_frame(
        &mut self,
        mut frame: Frame,
        motion: MotionInput,
        input: Option<KeptInput>,
        color_non_finite: Option<u64>,
    ) -> Result<Vec<Filtered>, SessionError> {
        if crate::pipeline::exec::cancelled() {
            // Queued for a client that has gone: dropped, the session as it was.
            return Err(SessionError::Cancelled);
        }
        let s = self.session.clone();
        *lock(&s.slot) = Slot::Busy(Some(frame.meta.index));
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
        let (cw, ch) = frame.color_size();
        let samples = 3 * cw * ch;
        // The colour alone (the other channels are the filter's to repair), a plane a thread.
        let bad =
            color_non_finite.unwrap_or_else(|| frame.color().par_iter().map(Plane::count_non_finite).sum());
        let fraction = bad as f64 / samples as f64;
        let max = s.non_finite_limit;
        if fraction > max {
            return Err(SessionError::invalid(
                "color",
                format!(
                    "frame {}: {bad} of {samples} colour samples are NaN or infinite ({:.1}%), at most {:.1}% allowed",
                    frame.meta.index,
                    fraction * 100.0,
                    max * 100.0
                ),
            ));
        }
        let inner = self.inner()?;
        if motion == MotionInput::Session {
            let prev = inner.jitter_prev.unwrap_or(frame.meta.jitter);
            s.motion.frame_to_internal(&mut frame, prev);
        }
        let jitter = frame.meta.jitter;
        let index = frame.meta.index;
        inner.pending.push_back(Pending {
            reference: frame.reference().cloned(),
            meta: frame.meta.clone(),
            input,
        });
        let outs = self.guarded(&format!("frame {index}"), |f| f.push(&frame));
        let Some(inner) = self.inner.as_mut() else {
            return outs.map(|_| Vec::new()); // the filter panicked: `outs` is the error
        };
        // Only this frame's planes: a bound of one decoded frame, whatever sizes came before.
        inner.inputs = pipeline::Scratch::default();
        inner.inputs.recycle(frame.into_planes());
        if outs.is_err() {
            inner.pending.pop_back();
        }
        let outs = outs?;
        inner.jitter_prev = Some(jitter);
        inner.next_index = index.saturating_add(1);
        s.frames.fetch_add(1, Ordering::SeqCst);
        let outs = outs.into_iter().map(|o| measured(inner, o)).collect();
        self.account_state();
        outs
    }

    /// Ends the session's sequence: the outputs a windowed filter still holds, oldest
    /// first (none for a causal filter). The next frame starts a new sequence.
    pub fn flush(&mut self) -> Result<Vec<Filtered>, SessionError> {
        self.inner()?;
        let outs = self.guarded("the flush", |f| f.finish())?;
        if crate::pipeline::exec::cancelled() {
            // The flush stopped early for a client that left: what it held goes too.
            self.abandon()?;
            return Err(SessionError::Cancelled);
        }
        let inner = self
            .inner
            .as_mut()
            .expect("present after a flush that did not panic");
        let outs: Result<Vec<Filtered>, SessionError> =
            outs.into_iter().map(|o| measured(inner, o)).collect();
        inner.pending.clear();
        outs
    }

    /// Drops what the filter holds for the sequence in progress (a windowed filter's frames,
    /// a causal filter's history) and every output not handed over: for a client that went
    /// away mid-sequence, whose outputs nobody will take. The session stays open; its next
    /// frame starts a new sequence.
    pub fn abandon(&mut self) -> Result<(), SessionError> {
        let inner = self.inner()?;
        inner.filter.reset();
        inner.pending.clear();
        inner.ready.clear();
        inner.jitter_prev = None;
        Ok(())
    }

    /// The session's state as a state file ([`crate::pipeline::state`]): the filter's
    /// history, with the session's next frame index and last jitter in its notes. Imported
    /// into a session of the same filter, parameters and size, the frames that follow give
    /// what this session would have given. Refused while outputs wait to be handed over
    /// (flush first) and for a windowed filter (its state is its window of frames).
    pub fn export_state(&mut self) -> Result<Vec<u8>, SessionError> {
        let inner = self.inner()?;
        if !inner.pending.is_empty() || !inner.ready.is_empty() {
            return Err(SessionError::invalid(
                "state",
                format!(
                    "{} frames are in the filter's window and {} outputs wait to be handed over; flush the session first",
                    inner.pending.len(),
                    inner.ready.len()
                ),
            ));
        }
        let mut st = inner
            .filter
            .save_state()
            .map_err(|e| SessionError::invalid("state", e.to_string()))?;
        st.notes.insert(NOTE_NEXT_INDEX.into(), inner.next_index.into());
        st.notes.insert(
            NOTE_JITTER_PREV.into(),
            serde_json::to_value(inner.jitter_prev).unwrap_or_default(),
        );
        st.notes.insert(
            NOTE_METRIC_SPACE.into(),
            serde_json::to_value(inner.space).unwrap_or_default(),
        );
        Ok(st.encode_with(self.session.state_key.as_ref()))
    }

    /// Continues from a state file [`Checkout::export_state`] gave (untrusted bytes: checked
    /// against the session's size before anything is allocated, then against its filter and
    /// parameters). On error the session is as it was.
    pub fn import_state(&mut self, bytes: &[u8]) -> Result<(), SessionError> {
        let (w, h) = (
            self.session.info.width as usize,
            self.session.info.height as usize,
        );
        let bad = |message: String| SessionError::invalid("state", message);
        let key = self.session.state_key.as_ref();
        let st = FilterState::decode_with(bytes, (w * h) as u64, key).map_err(|e| bad(e.to_string()))?;
        if let Some((sw, sh)) = st.size.filter(|&s| s != (w, h)) {
            return Err(bad(format!("the state is {sw}x{sh}, the session {w}x{h}")));
        }
        let next_index = match st.notes.get(NOTE_NEXT_INDEX) {
            Some(v) => v
                .as_u64()
                .ok_or_else(|| bad(format!("note {NOTE_NEXT_INDEX}: expected a frame index, got {v}")))?,
            None => 0,
        };
        let jitter_prev: Option<[f32; 2]> = match st.notes.get(NOTE_JITTER_PREV) {
            Some(v) => serde_json::from_value(v.clone()).map_err(|_| {
                bad(format!(
                    "note {NOTE_JITTER_PREV}: expected null or [x, y], got {v}"
                ))
            })?,
            None => None,
        };
        let space: Option<MetricSpace> = match st.notes.get(NOTE_METRIC_SPACE) {
            Some(v) => serde_json::from_value(v.clone()).map_err(|_| {
                bad(format!(
                    "note {NOTE_METRIC_SPACE}: expected null or a metric space"
                ))
            })?,
            None => None,
        };
        let inner = self.inner()?;
        if !inner.pending.is_empty() || !inner.ready.is_empty() {
            return Err(bad(format!(
                "{} frames are in the filter's window; flush the session first",
                inner.pending.len() + inner.ready.len()
            )));
        }
        inner.filter.load_state(&st).map_err(|e| bad(e.to_string()))?;
        inner.next_index = next_index;
        inner.jitter_prev = jitter_prev;
        inner.space = space;
        self.account_state();
        Ok(())
    }

    /// Planes the last frame's input left (their samples stale), for decoding the next one.
    pub fn input_planes(&mut self) -> Result<&mut pipeline::Scratch, SessionError> {
        Ok(&mut self.inner()?.inputs)
    }

    /// Hands an output's planes back to the filter for reuse (see [`Filter::recycle`]).
    pub fn recycle(&mut self, planes: Rgb) {
        if let Ok(inner) = self.inner() {
            inner.filter.recycle(planes);
        }
    }

    /// Queues outputs to be handed over one per request (HTTP), then takes the oldest;
    /// also returns how many are left after it.
    pub fn queue_and_take(&mut self, outs: Vec<Filtered>) -> Result<(Option<Filtered>, usize), SessionError> {
        let inner = self.inner()?;
        inner.ready.extend(outs);
        let first = inner.ready.pop_front();
        Ok((first, inner.ready.len()))
    }

    /// Runs `call` on the filter with a panic kept inside the session: the session is
    /// marked failed (its state is dropped, later requests are refused with the message)
    /// and the server goes on.
    fn guarded(
        &mut self,
        what: &str,
        call: impl FnOnce(&mut dyn Filter) -> Result<Vec<pipeline::Output>, FilterError>,
    ) -> Result<Vec<pipeline::Output>, SessionError> {
        let inner = self.inner.as_mut().expect("checked by the caller");
        match catch_unwind(AssertUnwindSafe(|| call(inner.filter.as_mut()))) {
            Ok(Ok(outs)) => Ok(outs),
            Ok(Err(e)) => Err(filter_error(e)),
            Err(panic) => {
                let message = format!(
                    "filter {} panicked on {what}: {}",
                    self.session.info.filter,
                    panic_text(panic.as_ref())
                );
                tracing::error!(id = %self.session.info.id, %message, "session failed");
                self.failed = Some(message.clone());
                self.inner = None;
                Err(SessionError::Internal(message))
            }
        }
    }

    /// Counts what the filter holds now against the session's reservation: state that
    /// outgrew its estimate is held in the budget anyway (it exists) and logged, since the
    /// estimate is a bug to fix.
    fn account_state(&mut self) {
        let s = &self.session;
        let Some(inner) = &self.inner else { return };
        let px = s.info.width as u64 * s.info.height as u64;
        let queued = (inner.pending.len() + inner.ready.len()) as u64 * px * 12;
        let held = inner.filter.state_bytes() as u64 + queued + inner.inputs.bytes() as u64;
        let mut r = lock(&s.state);
        if held > r.bytes() {
            tracing::warn!(id = %s.info.id, filter = %s.info.filter, reserved = r.bytes(), held, "session state outgrew its reservation");
            let more = held - r.bytes();
            r.force_grow(more);
        }
    }
}

impl Drop for Checkout {
    fn drop(&mut self) {
        let s = &self.session;
        let back = match (self.failed.take(), self.inner.take()) {
            (Some(message), _) => Slot::Failed(message),
            (None, Some(inner)) => Slot::Idle(inner),
            (None, None) => Slot::Failed("the session's state was lost".into()),
        };
        *lock(&s.slot) = back;
        s.touch();
    }
}

/// An output with its figures against the reference its frame came with.
fn measured(inner: &mut Inner, out: pipeline::Output) -> Result<Filtered, SessionError> {
    let Pending {
        reference,
        meta,
        input,
    } = inner.pending.pop_front().ok_or_else(|| {
        SessionError::Internal(format!(
            "output {} came out of no pending frame",
            out.record.index
        ))
    })?;
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
        meta,
        input,
    })
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
    use crate::scene::synthetic_frame;

    const A: Caller = Caller::ANONYMOUS;

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

    fn open_as(sessions: &Sessions, caller: &Caller, filter: &str) -> String {
        let req = SessionRequest {
            filter: filter.into(),
            width: 24,
            height: 16,
            ..Default::default()
        };
        sessions.create(caller, &req).expect("valid session").id
    }

    fn open(sessions: &Sessions, filter: &str) -> String {
        open_as(sessions, &A, filter)
    }

    /// The message of a refused request.
    fn refusal<T>(r: Result<T, SessionError>) -> String {
        r.err().unwrap().to_string()
    }

    fn frame(index: u64) -> Frame {
        let mut f = synthetic_frame(24, 16, index);
        f.meta.index = index;
        f
    }

    fn process(sessions: &Sessions, id: &str, f: Frame) -> Result<Vec<Filtered>, SessionError> {
        sessions.checkout(&A, id)?.process(f, MotionInput::Internal)
    }

    #[test]
    fn a_panicking_filter_fails_only_its_session() {
        let sessions = Sessions::new(Limits::default());
        let sick = open(&sessions, "taa");
        let healthy = open(&sessions, "taa");
        {
            let s = sessions.get_arc(&A, &sick).unwrap();
            let mut slot = lock(&s.slot);
            let Slot::Idle(inner) = &mut *slot else {
                panic!("idle")
            };
            let real = std::mem::replace(
                &mut inner.filter,
                filters::create("passthrough", &Map::new()).unwrap(),
            );
            inner.filter = Box::new(PanicsOn {
                inner: real,
                index: 2,
            });
        }
        let mut reference = filters::create("taa", &Map::new()).unwrap();
        for i in 0..5 {
            let want = reference.process(&frame(i)).unwrap().color;
            // The healthy session is filtered between the sick one's frames, on the same
            // thread, before and after the panic: it must match in-process filtering exactly.
            let got = process(&sessions, &healthy, frame(i)).unwrap();
            assert_eq!(got.len(), 1, "a causal filter gives its frame at once");
            assert_eq!(got[0].color, want, "healthy session, frame {i}");
            let sick_result = process(&sessions, &sick, frame(i));
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
        assert_eq!(sessions.get(&A, &sick).unwrap().frames, 2);
        let before = sessions.totals();
        sessions.close(&A, &sick).unwrap();
        let after = sessions.totals();
        assert_eq!(after.sessions, before.sessions - 1);
        assert!(after.state_bytes < before.state_bytes);
        assert_eq!(after.budget_used, after.state_bytes);
        // And a new session works.
        let fresh = open(&sessions, "phlm");
        process(&sessions, &fresh, frame(0)).unwrap();
    }

    /// A frame's input planes stay with the session to decode the next one (fresh
    /// multi-MiB planes fault in page by page): the session holds exactly the last frame's
    /// float planes, and a plane taken from them is that frame's.
    #[test]
    fn a_session_keeps_the_last_input_planes_for_the_next_frame() {
        let sessions = Sessions::new(Limits::default());
        let id = open(&sessions, "taa");
        let f = frame(0);
        let planes: usize = f
            .channels()
            .iter()
            .filter(|k| *k != ChannelKind::ObjectId)
            .map(|k| k.components())
            .sum();
        let red = f.color()[0].data().to_vec();
        let mut co = sessions.checkout(&A, &id).unwrap();
        assert_eq!(co.input_planes().unwrap().bytes(), 0);
        co.process(f, MotionInput::Internal).unwrap();
        let spare = co.input_planes().unwrap();
        assert_eq!(spare.bytes(), planes * 24 * 16 * 4);
        let reused = spare.plane(24, 16);
        // Debug builds poison recycled planes; release builds hand back the samples.
        if !cfg!(debug_assertions) {
            assert_eq!(reused.data(), &red[..]);
        }
        assert_eq!(spare.bytes(), (planes - 1) * 24 * 16 * 4);
    }

    #[test]
    fn a_checked_out_session_refuses_other_requests_without_waiting() {
        let sessions = Sessions::new(Limits::default());
        let id = open(&sessions, "taa");
        let mut held = sessions.checkout(&A, &id).unwrap();
        let e = sessions.checkout(&A, &id).err().unwrap();
        assert_eq!(e.to_string(), "session busy: a frame is being received");
        assert_eq!(e.kind(), ErrorKind::FailedPrecondition);
        // Reads answer while it is out.
        assert_eq!(sessions.get(&A, &id).unwrap().frames, 0);
        held.process(frame(7), MotionInput::Internal).unwrap();
        let e = sessions.checkout(&A, &id).err().unwrap();
        assert_eq!(e.to_string(), "session busy: frame 7 is being filtered");
        // Idle sessions are not evicted while out.
        drop(held);
        assert_eq!(sessions.get(&A, &id).unwrap().frames, 1);
        // A stream's claim keeps HTTP and other streams out until it ends.
        let claim = sessions.attach(&A, &id).unwrap();
        assert!(refusal(sessions.attach(&A, &id)).contains("another stream"));
        assert!(refusal(sessions.checkout(&A, &id)).contains("gRPC stream"));
        claim
            .checkout()
            .unwrap()
            .process(frame(8), MotionInput::Internal)
            .unwrap();
        drop(claim);
        process(&sessions, &id, frame(9)).unwrap();
    }

    #[test]
    fn sessions_belong_to_their_key_and_count_against_its_quotas() {
        let mut ring = Keyring::default();
        let q = Quotas {
            max_sessions: 2,
            memory_bytes: 24 * 16 * 224 * 3 / 2,
        };
        ring.add_plain("a:aaaaaaaaaaaaaaaa,b:bbbbbbbbbbbbbbbb", "test", q)
            .unwrap();
        let a = ring.caller(Some("Bearer aaaaaaaaaaaaaaaa")).unwrap();
        let b = ring.caller(Some("Bearer bbbbbbbbbbbbbbbb")).unwrap();
        let sessions = Sessions::new(Limits::default());
        let id = open_as(&sessions, &a, "phlm");
        for e in [
            sessions.get(&b, &id).err(),
            sessions.checkout(&b, &id).err(),
            sessions.attach(&b, &id).err(),
            sessions.close(&b, &id).err(),
            sessions.get(&A, &id).err(),
        ] {
            assert!(matches!(e, Some(SessionError::NotFound { .. })), "{e:?}");
        }
        // phlm at 24x16 reserves 86,016 bytes; the key's quota holds one and a half.
        let req = SessionRequest {
            filter: "phlm".into(),
            width: 24,
            height: 16,
            ..Default::default()
        };
        let e = sessions.create(&a, &req).unwrap_err().to_string();
        assert!(e.contains("memory quota of key a"), "{e}");
        let _t1 = open_as(&sessions, &a, "taa");
        let e = sessions.create(&a, &req).unwrap_err().to_string();
        assert!(e.contains("key a has 2 sessions open, its quota is 2"), "{e}");
        // The other key is not affected.
        open_as(&sessions, &b, "phlm");
        sessions.close(&a, &id).unwrap();
        open_as(&sessions, &a, "taa");
    }

    /// A session runs on the backend it names, else the server's default; a backend it
    /// cannot have is refused at creation, naming the field and why.
    #[test]
    fn sessions_choose_their_backend() {
        let sessions = Sessions::new(Limits::default());
        let mut req = SessionRequest {
            filter: "taa".into(),
            width: 24,
            height: 16,
            ..Default::default()
        };
        let info = sessions.create(&A, &req).unwrap();
        assert_eq!(info.backend, crate::backend::Backend::Cpu);
        req.backend = "cuda".into();
        let e = sessions.create(&A, &req).unwrap_err();
        assert!(
            matches!(&e, SessionError::Invalid { field, message } if field == "backend" && message.contains("cpu, gpu or auto")),
            "{e}"
        );
        req.backend = "auto".into();
        let info = sessions.create(&A, &req).unwrap();
        assert_eq!(
            info.backend == crate::backend::Backend::Gpu,
            crate::backend::GPU_BUILT
        );
        req.backend = "gpu".into();
        req.filter = "pixel_trace".into();
        let e = sessions.create(&A, &req).unwrap_err();
        assert!(
            matches!(&e, SessionError::Invalid { field, .. } if field == "backend"),
            "{e}"
        );
        // The server's default applies to sessions that do not say.
        let sessions = Sessions::new(Limits {
            default_backend: crate::backend::BackendChoice::Auto,
            ..Limits::default()
        });
        req.backend = String::new();
        let info = sessions.create(&A, &req).unwrap();
        assert_eq!(
            info.backend,
            crate::backend::Backend::Cpu,
            "pixel_trace has no GPU version"
        );
    }

    #[test]
    fn the_reservation_covers_what_every_filter_holds() {
        let cases: &[(&str, &[&str])] = &[
            ("passthrough", &[]),
            ("fxaa", &[]),
            ("taa", &[]),
            ("taa", &["depth_rejection=0.1", "sharpen=0.2"]),
            ("traa", &[]),
            ("traa", &["variant=baseline"]),
            ("phlm", &[]),
            ("upsample", &[]),
            ("pixel_trace", &["window=4"]),
            ("pixel_trace", &["window=32"]),
        ];
        for (filter, set) in cases {
            let sessions = Sessions::new(Limits::default());
            let req = SessionRequest {
                filter: filter.to_string(),
                params: set
                    .iter()
                    .map(|kv| {
                        let (k, v) = kv.split_once('=').unwrap();
                        (k.to_string(), v.to_string())
                    })
                    .collect(),
                width: 24,
                height: 16,
                channels: ChannelKind::ALL
                    .iter()
                    .filter(|k| **k != ChannelKind::Reference)
                    .map(|k| k.name().to_string())
                    .collect(),
                ..Default::default()
            };
            let info = sessions.create(&A, &req).unwrap();
            // Enough frames to fill the largest window.
            for i in 0..40 {
                let mut f = synthetic_frame(24, 16, i);
                f.meta.index = i;
                sessions
                    .checkout(&A, &info.id)
                    .unwrap()
                    .process(f, MotionInput::Internal)
                    .unwrap();
                let now = sessions.get(&A, &info.id).unwrap().state_bytes;
                assert_eq!(
                    now, info.state_bytes,
                    "{filter} {set:?}: the reservation had to grow at frame {i}"
                );
            }
            assert!(info.state_bytes > 0 || ["passthrough", "fxaa"].contains(filter));
        }
    }
}
