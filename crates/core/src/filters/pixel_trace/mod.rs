//! `pixel_trace`: Shinya 1993, the pixel-tracing filter. Offline: output frame
//! t0 is a weighted sum over the frames t0 - T/2 ..= t0 + T/2 of the samples along each
//! pixel's motion path, explicitly normalised (eq. 11), with differently moving objects
//! separated by the two-way flow test (eq. 14-15) and blended front to back by depth with
//! coverage alpha (eq. 16-17), and objects the pixel's own sample missed found in the other
//! frames (eq. 13). It reads future frames, so it runs with `lookahead` = T/2 frames of
//! latency: [`Filter::push`] returns frame t once frame t + T/2 has arrived, and
//! [`Filter::finish`] flushes the rest with the window cut at the sequence's end.
//!
//! Choices where the paper leaves room (each stated where it is used):
//! - Paths chain the per-frame motion vectors (`motion` backwards, `motion_next` forwards,
//!   or the inverse of the next frame's `motion` when a frame has no `motion_next`) instead
//!   of object transforms (eq. 12): the G-buffer is what a pipeline has. Each step reads the
//!   vector of the pixel holding the position and keeps the sub-pixel offset (the local
//!   uniformity of eq. 10), so no motion is blended across a silhouette. A path keeps to
//!   its object (by id): where that pixel shows another object, the nearest pixel of the
//!   3x3 that shows its own gives the vector, else it carries on at its last velocity (the
//!   object is hidden there, or too thin for the sample: Shinya's 1/8-px bar).
//! - The norm of eq. 14-15 is the max norm, the box kernel's own; `d_th` defaults to the
//!   support's diameter, as the paper suggests.
//! - Missed flows (eq. 13) are gathered by scattering every sample of the other frames to
//!   its position at t0; samples that fail the two-way test with the pixel's own flow are
//!   grouped by object id (eq. 12 identifies motion by object), one flow when ids are absent.
//! - Eq. 17's farthest flow takes the coverage left over (see `trace::blend`).
//! - A reset frame (a cut) ends the window: paths do not cross it.
//! - D_chi (eq. 9) is taken as 1, as the paper does for eq. 10.

mod lanes;
#[cfg(test)]
mod reference;
#[cfg(test)]
mod tests;
mod trace;

use crate::filter_params;
use crate::frame::{ChannelKind, ChannelSet, Frame, Plane, Rgb};
use crate::pipeline::input::REPAIR_STAGE;
use crate::pipeline::{
    check_needs, prepare, Filter, FilterError, FilterKind, InputCounts, Output, ParamKind, PixelCounts,
    Recorder, Skip, WindowRecord,
};
use serde::{Deserialize, Serialize};
use serde_json::Value;
use std::collections::VecDeque;

/// The filter kernel w of eq. 7-11.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Kernel {
    /// 1 inside the square of half-width `support` (Shinya's experiments: one pixel area,
    /// `support` 0.5).
    Box,
    /// exp(-d^2 / 2 sigma^2) with sigma = support / 2, cut at `support`.
    Gaussian,
}

filter_params! {
    /// Parameters of `pixel_trace`.
    pub struct Params {
        /// frames T in the window t-T/2..=t+T/2 (Shinya: 16 for a walk-through, 32 for non-uniform motion,
        /// 128 for his thin line). Larger: more sub-pixel detail recovered, cost and memory grow as T,
        /// latency T/2 frames
        window: u32 = DEFAULT_WINDOW, ParamKind::Int { min: 1, max: 256 };
        /// filter kernel w: box (Shinya's, sharpest; support 0.5 = one pixel area) or gaussian (smoother,
        /// less aliasing left at small T, softer)
        kernel: Kernel = Kernel::Box, ParamKind::Choice { options: &["box", "gaussian"] };
        /// kernel support radius in pixels. Larger: softer and more samples per frame (cost grows as its
        /// square)
        support: f32 = DEFAULT_SUPPORT, ParamKind::Float { min: 0.25, max: 4.0 };
        /// two-way flow test threshold in pixels (eq. 14-15); 0 = the support's diameter. Smaller: objects
        /// separate sooner but paths with motion error lose samples; larger: different motions merge
        d_th: f32 = 0.0, ParamKind::Float { min: 0.0, max: 16.0 };
        /// separate differently moving objects (eq. 13-17). Off: one flow per pixel, cheaper, smears objects
        /// into what moves behind them
        flow_separation: bool = true, ParamKind::Bool;
        /// most missed flows (other objects) kept per pixel, the A-buffer list; more cost memory only where
        /// objects overlap
        max_flows: u32 = 3, ParamKind::Int { min: 1, max: 8 };
    }
}

/// Window of 16 frames: Shinya's walk-through experiment (sec. 5); his thin line needs 128
/// to settle, his spokes 32.
pub const DEFAULT_WINDOW: u32 = 16;
/// Box of one pixel area (Shinya sec. 5: "the box function with one pixel area").
pub const DEFAULT_SUPPORT: f32 = 0.5;

impl Params {
    /// The two-way test's threshold: `d_th`, or the support's diameter (Shinya: "according
    /// to the diameter of the support of the filter kernel").
    pub fn threshold(&self) -> f32 {
        if self.d_th > 0.0 {
            self.d_th
        } else {
            2.0 * self.support
        }
    }

    fn half(&self) -> usize {
        self.window as usize / 2
    }
}

/// Stage names: the paths and maps to t0, the missed flows scattered in, the primary flow
/// gathered and every flow blended.
const PATHS: &str = "paths";
const SEPARATE: &str = "separate_flows";
const BLEND: &str = "blend";

/// The pixel-tracing filter: a window of frames and the next one to output.
#[derive(Debug)]
pub struct PixelTrace {
    params: Params,
    /// The frames still needed, oldest first (repaired colour and what the paths read),
    /// with the input samples repaired in each.
    frames: VecDeque<Frame>,
    repaired: VecDeque<InputCounts>,
    /// Time each frame's repair took (None: nothing to repair).
    repair_ms: VecDeque<Option<f64>>,
    /// Position in the shot of `frames[0]`.
    base: usize,
    /// Position in the shot of the next frame to output.
    emitted: usize,
    /// The first steps of each frame's pixels towards the output frame, computed when
    /// first needed and kept with the frame.
    steps: VecDeque<trace::FirstSteps>,
    /// First steps of frames gone, for the frames to come (their buffers reused).
    spare_steps: Vec<trace::FirstSteps>,
    /// The tracing's buffers, kept from one output to the next.
    scratch: trace::Scratch,
    /// Output planes handed back by [`Filter::recycle`], for the next outputs.
    spare: Vec<Rgb>,
    /// Outputs from the scalar reference (`reference.rs`) instead of the fast path: the
    /// tests compare the two.
    #[cfg(test)]
    reference: bool,
    /// Whether the fast path keeps first steps (the tests run it without too).
    #[cfg(test)]
    first_steps: bool,
}

impl FilterKind for PixelTrace {
    const NAME: &'static str = "pixel_trace";
    const SUMMARY: &'static str =
        "Shinya's pixel-tracing filter (1993): a window of past and future frames along motion paths, flows separated; offline, T/2 frames of latency";
    const STAGES: &'static [&'static str] = &[REPAIR_STAGE, PATHS, SEPARATE, BLEND];
    type Params = Params;
    fn needs() -> ChannelSet {
        ChannelSet::of(&[ChannelKind::Color, ChannelKind::Motion])
    }
    fn uses() -> ChannelSet {
        Self::needs()
            .with(ChannelKind::MotionNext)
            .with(ChannelKind::Depth)
            .with(ChannelKind::ObjectId)
    }
    fn state_bytes_per_pixel(params: &Params) -> usize {
        // The window's frames: colour 3, motion 2, motion_next 2, depth 1, id 1 (4 bytes
        // each), T + 1 of them at most.
        (params.window as usize + 1) * 9 * 4
    }
    fn new(params: Params) -> Self {
        PixelTrace {
            params,
            frames: VecDeque::new(),
            repaired: VecDeque::new(),
            repair_ms: VecDeque::new(),
            base: 0,
            emitted: 0,
            steps: VecDeque::new(),
            spare_steps: Vec::new(),
            scratch: trace::Scratch::default(),
            spare: Vec::new(),
            #[cfg(test)]
            reference: false,
            #[cfg(test)]
            first_steps: true,
        }
    }
}

impl PixelTrace {
    /// The output of the frame at shot position `pos` from the frames held.
    fn output(&mut self, pos: usize, latency: usize) -> Output {
        let half = self.params.half();
        let first = pos.saturating_sub(half).max(self.base);
        let last = (pos + half).min(self.base + self.frames.len() - 1);
        let frames: Vec<&Frame> = (first..=last).map(|p| &self.frames[p - self.base]).collect();
        let centre_frame = frames[pos - first];
        let mut rec = Recorder::new();
        let win = trace::Window {
            frames,
            centre: pos - first,
        };
        // The output frame's own repair, timed when it arrived.
        match self.repair_ms[pos - self.base] {
            Some(ms) => rec.ran_for(REPAIR_STAGE, ms),
            None => rec.skip(REPAIR_STAGE, Skip::CleanInput),
        }
        let (w, h) = (centre_frame.width(), centre_frame.height());
        let out = match self.spare.pop() {
            Some(rgb) if rgb[0].size() == (w, h) => rgb,
            _ => std::array::from_fn(|_| Plane::new(w, h)),
        };
        #[cfg(test)]
        if self.reference {
            let _ = out;
            let (color, counts) = reference::trace(&win, &self.params, &mut rec);
            return self.finish_output(rec, &win, pos, latency, color, counts);
        }
        let steps = &mut self.steps.make_contiguous()[first - self.base..=last - self.base];
        #[cfg(test)]
        let steps = if self.first_steps { steps } else { &mut [] };
        let (color, counts) = trace::trace(&win, &self.params, &mut rec, &mut self.scratch, steps, out);
        self.finish_output(rec, &win, pos, latency, color, counts)
    }

    /// The output's record, with its window.
    fn finish_output(
        &self,
        rec: Recorder,
        win: &trace::Window,
        pos: usize,
        latency: usize,
        color: Rgb,
        counts: trace::TraceCounts,
    ) -> Output {
        let centre_frame = win.frames[win.centre];
        let mut record = rec.finish(
            Self::NAME,
            centre_frame.meta.index,
            PixelCounts::default(),
            self.repaired[pos - self.base],
            self.state_bytes(),
        );
        record.window = Some(WindowRecord {
            first: win.frames[0].meta.index,
            last: win.frames[win.frames.len() - 1].meta.index,
            latency_frames: latency as u64,
            pixels_with_several_flows: counts.several_flows,
            flows_dropped: counts.dropped,
        });
        Output { color, record }
    }

    /// Every output that is ready: frames with `half` frames after them (or all, at the end
    /// of a shot); then drops the frames no later output needs.
    fn drain(&mut self, end_of_shot: bool) -> Vec<Output> {
        let half = self.params.half();
        let mut out = Vec::new();
        let held_until = self.base + self.frames.len();
        while self.emitted < held_until && (end_of_shot || self.emitted + half < held_until) {
            // Nobody waits for the rest (a cancelled stream's flush): stop between frames.
            if crate::pipeline::exec::cancelled() {
                break;
            }
            out.push(self.output(self.emitted, held_until - 1 - self.emitted));
            self.emitted += 1;
        }
        while self.base + half < self.emitted && !self.frames.is_empty() {
            self.frames.pop_front();
            if let Some(steps) = self.steps.pop_front() {
                self.spare_steps.push(steps);
            }
            self.repaired.pop_front();
            self.repair_ms.pop_front();
            self.base += 1;
        }
        if end_of_shot {
            self.reset();
        }
        out
    }

    /// The frame with its colour, depth and motion repaired (non-finite and negative
    /// samples replaced, as every filter's input is) and only the channels the paths read.
    fn keep(frame: &Frame) -> Result<(Frame, InputCounts, Option<f64>), FilterError> {
        let mut rec = Recorder::new();
        let inp = prepare(frame, Self::uses(), &mut rec)?;
        let repair_ms = rec
            .finish(Self::NAME, 0, PixelCounts::default(), InputCounts::default(), 0)
            .stage(REPAIR_STAGE)
            .and_then(|s| s.ms);
        let mut f = Frame::new(inp.color.into_owned())?;
        f.meta = frame.meta.clone();
        if let Some(d) = inp.depth {
            f.set_f32(ChannelKind::Depth, vec![d.into_owned()])?;
        }
        if let Some(m) = inp.motion {
            f.set_f32(ChannelKind::Motion, m.into_owned().into())?;
        }
        if let Some(m) = frame.motion_next() {
            // Non-finite vectors end a path: the tracer loses them at the image's edge.
            let m = m
                .clone()
                .map(|p| p.map(|v| if v.is_finite() { v } else { f32::NAN }));
            f.set_f32(ChannelKind::MotionNext, m.into())?;
        }
        if let Some(ids) = inp.object_id {
            f.set_object_id(ids.clone())?;
        }
        Ok((f, inp.counts, repair_ms))
    }
}

impl Filter for PixelTrace {
    fn name(&self) -> &'static str {
        Self::NAME
    }
    fn params(&self) -> Value {
        Value::Object(crate::pipeline::params::to_json(&self.params))
    }
    fn process(&mut self, _frame: &Frame) -> Result<Output, FilterError> {
        Err(FilterError::NeedsWindow {
            filter: Self::NAME,
            lookahead: self.lookahead(),
        })
    }
    fn lookahead(&self) -> usize {
        self.params.half()
    }
    fn push(&mut self, frame: &Frame) -> Result<Vec<Output>, FilterError> {
        check_needs(Self::NAME, Self::needs(), frame)?;
        let (kept, repaired, repair_ms) = Self::keep(frame)?;
        let mut out = Vec::new();
        if let Some(held) = self.frames.back() {
            if frame.meta.reset {
                // A cut: the shot before it is finished with its window cut short.
                out = self.drain(true);
            } else if (held.width(), held.height()) != (frame.width(), frame.height()) {
                return Err(FilterError::SizeChanged {
                    index: frame.meta.index,
                    width: held.width(),
                    height: held.height(),
                    got_w: frame.width(),
                    got_h: frame.height(),
                });
            }
        }
        self.frames.push_back(kept);
        let mut steps = self.spare_steps.pop().unwrap_or_default();
        steps.clear();
        self.steps.push_back(steps);
        self.repaired.push_back(repaired);
        self.repair_ms.push_back(repair_ms);
        out.extend(self.drain(false));
        Ok(out)
    }
    fn finish(&mut self) -> Result<Vec<Output>, FilterError> {
        Ok(if self.frames.is_empty() {
            Vec::new()
        } else {
            self.drain(true)
        })
    }
    fn reset(&mut self) {
        self.frames.clear();
        self.spare_steps.extend(self.steps.drain(..));
        self.repaired.clear();
        self.repair_ms.clear();
        self.base = 0;
        self.emitted = 0;
    }
    fn recycle(&mut self, planes: Rgb) {
        // Two sets cover a caller that hands each output back before the next.
        if self.spare.len() < 2 {
            self.spare.push(planes);
        }
    }
    fn state_bytes(&self) -> usize {
        self.frames
            .iter()
            .map(|f| f.pixels() * 4 * f.channels().iter().map(|k| k.components()).sum::<usize>())
            .sum()
    }
}
