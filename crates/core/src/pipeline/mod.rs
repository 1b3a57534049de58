//! The filter interface: requirements, parameters, per-frame records, the stage planner,
//! and execution on the pool. The registry of the filters that implement it is
//! [`crate::filters::registry`]; this module knows none of them.
//!
//! A filter is created by name with validated parameters ([`crate::filters::create`]), then fed frames in
//! order ([`Filter::process`]); each frame gives an output image and a [`FrameRecord`].
//! Filters run on the crate's rayon pool ([`exec::pool`]), split by rows.

pub mod clean;
pub mod exec;
pub mod history;
pub mod input;
pub mod params;
pub mod planner;
pub mod record;
pub mod state;

pub use history::{DoubleBuffer, Scratch};
pub use input::{prepare, Inputs};
pub use params::{FilterParams, ParamKind, ParamSpec};
pub use planner::FrameFacts;
pub use record::{
    missing_channels, summarize_stages, Backend, DeviceTimes, FrameRecord, InputCounts, ModelHealth,
    PixelCounts, Recorder, Skip, StageRecord, StageSummary, UploadPrecision, WindowRecord,
};
pub use state::{FilterState, StateError};

use crate::frame::{ChannelKind, ChannelSet, Frame, FrameError, Rgb};
use serde::Serialize;
use serde_json::{Map, Value};
use thiserror::Error;

/// Errors of filter creation and processing. All but [`FilterError::Device`] are the
/// caller's: a bad name, parameter or frame. The filter's state is untouched by a frame that fails.
#[derive(Debug, Error, Clone, PartialEq)]
pub enum FilterError {
    /// No filter of that name.
    #[error("unknown filter {got:?}; known: {known}")]
    UnknownFilter {
        /// The name given.
        got: String,
        /// The filters there are.
        known: String,
    },
    /// A parameter the filter does not have.
    #[error("filter {filter} has no parameter {param:?}; its parameters: {known}")]
    UnknownParam {
        /// The filter.
        filter: &'static str,
        /// The name given.
        param: String,
        /// Its parameters.
        known: String,
    },
    /// A parameter of the wrong type or out of bounds.
    #[error("filter {filter}, parameter {param}: {message}")]
    BadParam {
        /// The filter.
        filter: &'static str,
        /// The parameter.
        param: String,
        /// What was expected and what was given.
        message: String,
    },
    /// `--set` text without `=`.
    #[error("expected key=value, got {got:?}")]
    Assignment {
        /// The text given.
        got: String,
    },
    /// The frame lacks a channel the filter needs.
    #[error("filter {filter} needs the {channel} channel, which frame {index} does not have")]
    MissingChannel {
        /// The filter.
        filter: &'static str,
        /// The channel.
        channel: ChannelKind,
        /// The frame's index.
        index: u64,
    },
    /// The frame size differs from the history's without a reset.
    #[error("frame {index} is {got_w}x{got_h} but the filter's history is {width}x{height}; send a reset frame (or reset the filter) to change size")]
    SizeChanged {
        /// The frame's index.
        index: u64,
        /// History width.
        width: usize,
        /// History height.
        height: usize,
        /// Frame width.
        got_w: usize,
        /// Frame height.
        got_h: usize,
    },
    /// Device depth whose near/far planes are unknown cannot be linearised.
    #[error("the depth channel is device depth but the frame gives no near/far planes to linearise it")]
    DeviceDepthWithoutPlanes,
    /// A windowed filter was fed one frame at a time through [`Filter::process`].
    #[error("filter {filter} looks {lookahead} frames ahead: feed it with push and finish (the `filter` and `report` commands and the server do), not process")]
    NeedsWindow {
        /// The filter.
        filter: &'static str,
        /// Frames it looks ahead.
        lookahead: usize,
    },
    /// A sparsely shaded frame given to a filter that needs full-resolution colour.
    #[error("filter {filter} needs colour shaded at every pixel, but frame {index} shades one pixel per {factor}x{factor} block (colour {color_w}x{color_h} for a {width}x{height} frame); use the upsample filter")]
    SparseColor {
        /// The filter.
        filter: &'static str,
        /// The frame's index.
        index: u64,
        /// Its shading factor.
        factor: u32,
        /// Colour width.
        color_w: usize,
        /// Colour height.
        color_h: usize,
        /// Frame width.
        width: usize,
        /// Frame height.
        height: usize,
    },
    /// An invalid frame.
    #[error(transparent)]
    Frame(#[from] FrameError),
    /// Not the caller's: the device a GPU filter runs on failed (lost, out of memory). The
    /// filter's state is as it was before the frame.
    #[error("the {backend} backend failed: {message}")]
    Device {
        /// The backend.
        backend: Backend,
        /// What the device said.
        message: String,
    },
}

/// A filtered frame.
#[derive(Clone, Debug)]
pub struct Output {
    /// The filtered colour, linear RGB, the input's size.
    pub color: Rgb,
    /// What happened.
    pub record: FrameRecord,
}

/// A filter instance with its state. Frames go in in order; `reset` forgets the history.
pub trait Filter: Send {
    /// The registry name.
    fn name(&self) -> &'static str;
    /// The parameters in effect, as JSON.
    fn params(&self) -> Value;
    /// Filters one frame. On error the state is left as it was. A windowed filter
    /// (`lookahead() > 0`) refuses this with [`FilterError::NeedsWindow`].
    fn process(&mut self, frame: &Frame) -> Result<Output, FilterError>;
    /// Frames after frame t that must have arrived before t's output is ready: 0 for a
    /// causal filter, T/2 for a window of frames t - T/2 ..= t + T/2.
    fn lookahead(&self) -> usize {
        0
    }
    /// Feeds the next frame; returns the outputs that became ready, oldest first: a causal
    /// filter's is this frame's own, a windowed filter's the frame `lookahead` back (none
    /// while its window fills). On error the state is left as it was.
    fn push(&mut self, frame: &Frame) -> Result<Vec<Output>, FilterError> {
        Ok(vec![self.process(frame)?])
    }
    /// Like [`Filter::push`], but this frame's output may come from the next call: a GPU
    /// filter starts this frame on the device and then reads back the one before, so the
    /// host's work on one frame and the device's on the other overlap. Outputs come in
    /// order, at most one call late; [`Filter::flush_overlapped`] returns those held. A
    /// caller with the next frame at hand uses it (the shot runner does); the default is
    /// `push`. On error the state is left as it was.
    fn push_overlapped(&mut self, frame: &Frame) -> Result<Vec<Output>, FilterError> {
        self.push(frame)
    }
    /// The outputs [`Filter::push_overlapped`] holds back, oldest first; afterwards the
    /// filter is as after `push` (its history kept). Call it before saving state.
    fn flush_overlapped(&mut self) -> Result<Vec<Output>, FilterError> {
        Ok(Vec::new())
    }
    /// The outputs still held back at the end of a sequence, oldest first; afterwards the
    /// filter is empty, as after `reset`.
    fn finish(&mut self) -> Result<Vec<Output>, FilterError> {
        Ok(Vec::new())
    }
    /// Forgets the history: the next frame starts afresh.
    fn reset(&mut self);
    /// Bytes of state held now.
    fn state_bytes(&self) -> usize;
    /// Hands an output's planes back for reuse by the next frame (optional: callers that
    /// keep their outputs simply do not call it).
    fn recycle(&mut self, _planes: Rgb) {}
    /// Everything this filter carries to the next frame ([`state`]): loaded into a filter
    /// of the same name and parameters, the frames that follow give bit-identical outputs.
    /// A windowed filter cannot: its state is its window of input frames, which a caller
    /// replays instead (push the `lookahead` frames before the first output wanted).
    fn save_state(&self) -> Result<FilterState, StateError> {
        Err(StateError::Unsupported {
            filter: self.name(),
            why: "it holds a window of input frames; replay them instead",
        })
    }
    /// Continues from a state [`Filter::save_state`] gave; refused (and the filter left as
    /// it was) unless the state is this filter's, with the same parameters.
    fn load_state(&mut self, _state: &FilterState) -> Result<(), StateError> {
        Err(StateError::Unsupported {
            filter: self.name(),
            why: "it holds a window of input frames; replay them instead",
        })
    }
    /// Where this instance runs (its records say the same).
    fn backend(&self) -> Backend {
        Backend::Cpu
    }
}

/// Static description of a filter kind, implemented by each filter module.
pub trait FilterKind: Filter + Sized + 'static {
    /// Registry name.
    const NAME: &'static str;
    /// One line on what it is.
    const SUMMARY: &'static str;
    /// Stage names in execution order.
    const STAGES: &'static [&'static str];
    /// Its parameters.
    type Params: FilterParams;
    /// Channels it cannot work without (by default the colour alone, as for every filter
    /// but `pixel_trace`).
    fn needs() -> ChannelSet {
        ChannelSet::of(&[ChannelKind::Color])
    }
    /// Channels it reads when present (a superset of `needs`; by default `needs` alone).
    fn uses() -> ChannelSet {
        Self::needs()
    }
    /// Bytes of state per pixel with these parameters (both history buffers; by default
    /// none, as for a filter without history).
    fn state_bytes_per_pixel(_params: &Self::Params) -> usize {
        0
    }
    /// Whether it reconstructs sparsely shaded colour (see [`crate::frame::Sampling`]);
    /// the others refuse such frames with [`FilterError::SparseColor`].
    const SPARSE_INPUT: bool = false;
    /// A fresh instance.
    fn new(params: Self::Params) -> Self;
}

/// What `afterimage filters` and the server's list show about one filter.
#[derive(Clone, Debug, Serialize)]
pub struct FilterInfo {
    /// Registry name.
    pub name: &'static str,
    /// One line on what it is.
    pub summary: &'static str,
    /// Channels it needs.
    pub needs: Vec<ChannelKind>,
    /// Channels it reads when present.
    pub uses: Vec<ChannelKind>,
    /// Stage names in order.
    pub stages: &'static [&'static str],
    /// Parameters with kinds and bounds.
    pub params: &'static [ParamSpec],
    /// Default parameter values.
    pub defaults: Map<String, Value>,
    /// Bytes of state per pixel with the defaults.
    pub state_bytes_per_pixel: usize,
    /// Whether it takes sparsely shaded colour (the others need every pixel shaded).
    pub sparse_input: bool,
}

/// Builds a filter instance from parameter overrides, with the bytes of state per pixel
/// its parameters make it hold (what a server reserves for it).
pub type CreateFn = fn(&Map<String, Value>) -> Result<(Box<dyn Filter>, usize), FilterError>;

/// One registry entry: the description and a constructor.
pub struct FilterEntry {
    /// The description.
    pub info: fn() -> FilterInfo,
    /// Builds an instance from parameter overrides.
    pub create: CreateFn,
}

fn info_of<F: FilterKind>() -> FilterInfo {
    FilterInfo {
        name: F::NAME,
        summary: F::SUMMARY,
        needs: F::needs().iter().collect(),
        uses: F::uses().iter().collect(),
        stages: F::STAGES,
        params: <F::Params as FilterParams>::SPECS,
        defaults: params::defaults::<F::Params>(),
        state_bytes_per_pixel: F::state_bytes_per_pixel(&F::Params::default()),
        sparse_input: F::SPARSE_INPUT,
    }
}

fn create_of<F: FilterKind>(values: &Map<String, Value>) -> Result<(Box<dyn Filter>, usize), FilterError> {
    let params = params::build::<F::Params>(F::NAME, values)?;
    let bytes = F::state_bytes_per_pixel(&params);
    Ok((Box::new(F::new(params)), bytes))
}

/// The registry entry of filter kind `F`.
pub fn entry<F: FilterKind>() -> FilterEntry {
    FilterEntry {
        info: info_of::<F>,
        create: create_of::<F>,
    }
}

/// Runs `filter` over a whole sequence (push every frame, then finish): one output per
/// frame, in order, for causal and windowed filters alike.
pub fn run_sequence<'a>(
    filter: &mut dyn Filter,
    frames: impl IntoIterator<Item = &'a Frame>,
) -> Result<Vec<Output>, FilterError> {
    let mut out = Vec::new();
    for frame in frames {
        out.extend(filter.push(frame)?);
    }
    out.extend(filter.finish()?);
    Ok(out)
}

/// Checks that `frame` has every channel in `needs` and full-resolution colour.
pub fn check_needs(filter: &'static str, needs: ChannelSet, frame: &Frame) -> Result<(), FilterError> {
    if !frame.sampling().is_full() {
        let (color_w, color_h) = frame.color_size();
        return Err(FilterError::SparseColor {
            filter,
            index: frame.meta.index,
            factor: frame.sampling().factor,
            color_w,
            color_h,
            width: frame.width(),
            height: frame.height(),
        });
    }
    check_channels(filter, needs, frame)
}

/// Checks that `frame` has every channel in `needs`, whatever its colour's sampling (for
/// filters that reconstruct sparse shading).
pub fn check_channels(filter: &'static str, needs: ChannelSet, frame: &Frame) -> Result<(), FilterError> {
    match needs.minus(frame.channels()).iter().next() {
        Some(channel) => Err(FilterError::MissingChannel {
            filter,
            channel,
            index: frame.meta.index,
        }),
        None => Ok(()),
    }
}

/// Sizes `state` for `frame`: a new size is accepted on the first frame, after a reset of
/// the filter, or on a reset frame; otherwise it is an error (and the state is untouched).
pub fn bind_size(state: &mut DoubleBuffer, frame: &Frame) -> Result<(), FilterError> {
    check_size(state.size(), state.valid(), frame)?;
    state.ensure(frame.width(), frame.height());
    Ok(())
}

/// Whether `frame` may go into a state of size `held` (`None`: nothing allocated) that
/// holds a previous frame when `valid`: a new size is accepted on the first frame, after a
/// reset of the filter, or on a reset frame (the rule of [`bind_size`], for state kept
/// elsewhere, e.g. on a GPU).
pub fn check_size(held: Option<(usize, usize)>, valid: bool, frame: &Frame) -> Result<(), FilterError> {
    let (w, h) = (frame.width(), frame.height());
    match held {
        Some((sw, sh)) if (sw, sh) != (w, h) && valid && !frame.meta.reset => Err(FilterError::SizeChanged {
            index: frame.meta.index,
            width: sw,
            height: sh,
            got_w: w,
            got_h: h,
        }),
        _ => Ok(()),
    }
}
