//! The per-frame record: what ran, what was left out and why, how long each stage took,
//! and what happened to the history.

use serde::Serialize;
use std::fmt;
use std::time::Instant;

use crate::frame::ChannelKind;
use crate::metrics::Timing;

/// Why a stage was left out for this frame.
#[derive(Clone, Debug, PartialEq, Serialize)]
#[serde(rename_all = "snake_case", tag = "why")]
pub enum Skip {
    /// The stage's input channel is absent from the frame.
    MissingChannel {
        /// The channel.
        channel: ChannelKind,
    },
    /// Motion is zero everywhere and the frame is no reset: history already lines up.
    NoMotion,
    /// Colour never exceeds 1: the reversible tonemap would not change the weighting.
    LdrInput,
    /// No non-finite or negative sample in the input: nothing to repair.
    CleanInput,
    /// First frame, reset or reset history: there is nothing to reproject.
    NoHistory,
    /// Turned off by a parameter.
    Disabled {
        /// The parameter.
        param: &'static str,
    },
    /// The stage belongs to another variant of the filter.
    Variant {
        /// The variant that is running.
        variant: &'static str,
    },
}

impl fmt::Display for Skip {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Skip::MissingChannel { channel } => write!(f, "no {channel} channel"),
            Skip::NoMotion => write!(f, "no motion anywhere and no reset"),
            Skip::LdrInput => write!(f, "LDR input (max <= 1)"),
            Skip::CleanInput => write!(f, "no non-finite or negative input"),
            Skip::NoHistory => write!(f, "no history (first frame or reset)"),
            Skip::Disabled { param } => write!(f, "disabled by {param}"),
            Skip::Variant { variant } => write!(f, "not part of variant {variant}"),
        }
    }
}

/// One stage of one frame.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct StageRecord {
    /// Stage name (stable, listed by `afterimage filters`).
    pub name: &'static str,
    /// Wall time in milliseconds; `None` when left out.
    pub ms: Option<f64>,
    /// Why it was left out; `None` when it ran.
    pub skipped: Option<Skip>,
}

/// What happened to the history, counted in pixels.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize)]
pub struct PixelCounts {
    /// History restarted from the input: first frame, reset, off screen, disocclusion.
    pub history_reset: u64,
    /// History rejected by a test (depth) and restarted from the input.
    pub history_rejected: u64,
    /// History moved by rectification (clipped or clamped into the neighbourhood box).
    pub history_clipped: u64,
}

add_assign_fields!(PixelCounts {
    history_reset,
    history_rejected,
    history_clipped
});

/// Input samples that could not be used as they came.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize)]
pub struct InputCounts {
    /// NaN or infinite samples over all channels the filter reads (repaired, never stored).
    pub non_finite: u64,
    /// Negative colour samples (set to 0).
    pub negative: u64,
}

/// Health of per-pixel linear models (filters that keep them, e.g. `phlm`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct ModelHealth {
    /// Share of pixels whose model was reset because its prediction left the neighbourhood
    /// box (clipped and reset, PHLM Algorithm 1 line 18).
    pub reset_by_clip: f64,
    /// Share of pixels whose model was reset because their previous position was off screen
    /// (disocclusion at the border, Algorithm 1 line 9).
    pub reset_by_disocclusion: f64,
    /// Largest trace of an inverse covariance P over the frame.
    pub max_trace_p: f64,
    /// Matrices that failed the health check (non-finite, non-positive diagonal, trace over
    /// the bound) and were re-initialised.
    pub p_repaired: u64,
}

/// The record of one filtered frame.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct FrameRecord {
    /// Frame index (from the frame's values).
    pub index: u64,
    /// The filter.
    pub filter: &'static str,
    /// Every stage of the filter in order, run or left out.
    pub stages: Vec<StageRecord>,
    /// Wall time of the whole frame, milliseconds.
    pub total_ms: f64,
    /// History events.
    pub pixels: PixelCounts,
    /// Unusable input samples.
    pub input: InputCounts,
    /// Bytes of filter state after this frame.
    pub state_bytes: usize,
    /// Health of per-pixel models, for filters that keep them.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub model: Option<ModelHealth>,
    /// The window of frames a windowed filter read for this output.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub window: Option<WindowRecord>,
    /// Where the filter ran.
    pub backend: Backend,
    /// Where a GPU frame's time went (GPU backend only).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub device: Option<DeviceTimes>,
}

/// Where a GPU frame's time went: the host queuing its inputs, the device running its
/// shaders, and the colour coming back. The stages' own times share the shader time (or,
/// without timestamp queries, the frame's device round trip).
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct DeviceTimes {
    /// Host time writing the frame's channels and parameters to the device queue and
    /// submitting, milliseconds.
    pub upload_ms: f64,
    /// Device time of the frame's shader passes, first start to last end, from timestamp
    /// queries, milliseconds; absent where the adapter has no timestamp queries.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub shaders_ms: Option<f64>,
    /// Host time from the submission to the colour in host memory, less `shaders_ms` where
    /// known (the queue, the copy back and the map; with f16 colour, also the untimed pass
    /// that widens it to f32 on the device), milliseconds.
    pub readback_ms: f64,
    /// The precision the frame's colour went up in.
    pub upload: UploadPrecision,
    /// Bytes the frame queued for the device: its channels and its parameters.
    pub upload_bytes: u64,
}

/// The precision a GPU filter's colour planes go up to the device in. Motion, depth and
/// the invalid mask always go as f32: f16's 11 significant bits leave a motion of 1024 to
/// 2048 pixels a whole pixel's resolution, and depth three decimal digits.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum UploadPrecision {
    /// 32-bit floats: the samples as the CPU filter sees them.
    #[default]
    F32,
    /// IEEE half floats, two to a 32-bit word, widened to f32 on the device: half the
    /// colour's bytes, each sample rounded to nearest (relative error at most 2^-11) and
    /// held within +-65504 (f16's largest finite value; brighter HDR colour is clamped).
    F16,
}

impl UploadPrecision {
    /// Its name in records and options: `f32` or `f16`.
    pub fn name(self) -> &'static str {
        match self {
            UploadPrecision::F32 => "f32",
            UploadPrecision::F16 => "f16",
        }
    }
}

/// Where a filter runs: the CPU (on the crate's rayon pool; the reference) or a GPU (the
/// `gpu` cargo feature's wgpu backend, `crate::backend`). Which one a caller gets is chosen
/// there; the filter interface and its records only say which one ran.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Backend {
    /// The CPU filters of [`crate::filters`].
    #[default]
    Cpu,
    /// A wgpu device.
    Gpu,
}

impl Backend {
    /// The name used in records, options and the report: `cpu` or `gpu`.
    pub fn name(self) -> &'static str {
        match self {
            Backend::Cpu => "cpu",
            Backend::Gpu => "gpu",
        }
    }
}

display_name!(UploadPrecision, Backend);

/// The window of frames behind one output of a windowed filter, and its flows.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct WindowRecord {
    /// Index of the first frame read.
    pub first: u64,
    /// Index of the last frame read.
    pub last: u64,
    /// Frames that arrived after this one before it came out (its latency).
    pub latency_frames: u64,
    /// Pixels whose output blends more than one flow.
    pub pixels_with_several_flows: u64,
    /// Flows dropped because a pixel's list was full (their weight is lost).
    pub flows_dropped: u64,
}

impl FrameRecord {
    /// The stage called `name`, if the filter has one.
    pub fn stage(&self, name: &str) -> Option<&StageRecord> {
        self.stages.iter().find(|s| s.name == name)
    }

    /// Whether stage `name` ran this frame.
    pub fn ran(&self, name: &str) -> bool {
        self.stage(name).is_some_and(|s| s.skipped.is_none())
    }

    /// The record with every time set to 0: what goes into an output file, so that the
    /// same input gives the same bytes on every run (the times are in the records file).
    pub fn without_timings(&self) -> FrameRecord {
        let mut r = self.clone();
        r.total_ms = 0.0;
        for s in &mut r.stages {
            s.ms = s.ms.map(|_| 0.0);
        }
        if let Some(d) = &mut r.device {
            d.upload_ms = 0.0;
            d.readback_ms = 0.0;
            d.shaders_ms = d.shaders_ms.map(|_| 0.0);
        }
        r
    }
}

/// Builds a [`FrameRecord`] while a filter runs: times stages and notes those left out.
#[derive(Debug)]
pub struct Recorder {
    start: Instant,
    stages: Vec<StageRecord>,
}

impl Default for Recorder {
    fn default() -> Self {
        Recorder::new()
    }
}

impl Recorder {
    /// Starts the clock of a frame.
    pub fn new() -> Self {
        Recorder {
            start: Instant::now(),
            stages: Vec::new(),
        }
    }

    /// Runs stage `name` and times it.
    pub fn run<T>(&mut self, name: &'static str, f: impl FnOnce() -> T) -> T {
        let t = Instant::now();
        let out = f();
        self.stages.push(StageRecord {
            name,
            ms: Some(t.elapsed().as_secs_f64() * 1e3),
            skipped: None,
        });
        out
    }

    /// Runs stage `name` unless `skip` says why not; returns `None` when left out.
    pub fn stage<T>(&mut self, name: &'static str, skip: Option<Skip>, f: impl FnOnce() -> T) -> Option<T> {
        match skip {
            Some(why) => {
                self.skip(name, why);
                None
            }
            None => Some(self.run(name, f)),
        }
    }

    /// Notes that stage `name` was left out.
    pub fn skip(&mut self, name: &'static str, why: Skip) {
        self.stages.push(StageRecord {
            name,
            ms: None,
            skipped: Some(why),
        });
    }

    /// Notes that stage `name` ran for `ms` milliseconds, timed by the caller.
    pub fn ran_for(&mut self, name: &'static str, ms: f64) {
        self.stages.push(StageRecord {
            name,
            ms: Some(ms),
            skipped: None,
        });
    }

    /// Notes stage `name`, timed by the caller: left out where `skip` says why, else run for
    /// `ms` milliseconds (a fused pass's stages, each with its own reason to be left out).
    pub fn ran_unless(&mut self, name: &'static str, skip: Option<Skip>, ms: f64) {
        match skip {
            Some(why) => self.skip(name, why),
            None => self.ran_for(name, ms),
        }
    }

    /// Notes the stages `names` of one fused pass that took `ms` of wall time: each gets
    /// the share of it that its clock measured (see [`super::exec::StageClock`]).
    pub fn fused<const N: usize>(
        &mut self,
        names: [&'static str; N],
        clock: &super::exec::StageClock<N>,
        ms: f64,
    ) {
        for (name, share) in names.into_iter().zip(clock.shares()) {
            self.ran_for(name, ms * share);
        }
    }

    /// Runs a fused pass `f` and notes its stages `names` as [`Recorder::fused`] does.
    pub fn run_fused<const N: usize, T>(
        &mut self,
        names: [&'static str; N],
        f: impl FnOnce(&super::exec::StageClock<N>) -> T,
    ) -> T {
        let clock = super::exec::StageClock::default();
        let t = Instant::now();
        let out = f(&clock);
        self.fused(names, &clock, t.elapsed().as_secs_f64() * 1e3);
        out
    }

    /// The finished record.
    pub fn finish(
        self,
        filter: &'static str,
        index: u64,
        pixels: PixelCounts,
        input: InputCounts,
        state_bytes: usize,
    ) -> FrameRecord {
        FrameRecord {
            index,
            filter,
            stages: self.stages,
            total_ms: self.start.elapsed().as_secs_f64() * 1e3,
            pixels,
            input,
            state_bytes,
            model: None,
            window: None,
            backend: Backend::Cpu,
            device: None,
        }
    }
}

/// One stage over a run of frames: how often it ran and how long it took, or why it was
/// left out.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct StageSummary {
    /// Stage name.
    pub name: &'static str,
    /// Frames on which it ran.
    pub ran: usize,
    /// Frames on which it was left out.
    pub left_out: usize,
    /// Median and p95 of its time over the frames it ran (None when it never ran).
    pub timing: Option<Timing>,
    /// Why it was left out the first time it was (None when it always ran).
    pub first_skip: Option<String>,
    /// Every reason it was left out, with the frames it was left out for, in the order
    /// each first appeared.
    pub skips: Vec<(String, usize)>,
}

/// Frames on which some stage was left out for lack of each channel, in the order the
/// channels first went missing: what the input lacked, counted per frame.
pub fn missing_channels(records: &[FrameRecord]) -> Vec<(ChannelKind, usize)> {
    let mut out: Vec<(ChannelKind, usize)> = Vec::new();
    for r in records {
        let mut this: Vec<ChannelKind> = Vec::new();
        for s in &r.stages {
            if let Some(Skip::MissingChannel { channel }) = s.skipped {
                if !this.contains(&channel) {
                    this.push(channel);
                }
            }
        }
        for channel in this {
            match out.iter_mut().find(|(c, _)| *c == channel) {
                Some((_, n)) => *n += 1,
                None => out.push((channel, 1)),
            }
        }
    }
    out
}

/// Per-stage summaries of `records`, in the order the filter runs its stages.
pub fn summarize_stages(records: &[FrameRecord]) -> Vec<StageSummary> {
    let mut out: Vec<(StageSummary, Vec<f64>)> = Vec::new();
    for r in records {
        for s in &r.stages {
            let i = match out.iter().position(|(o, _)| o.name == s.name) {
                Some(i) => i,
                None => {
                    out.push((
                        StageSummary {
                            name: s.name,
                            ran: 0,
                            left_out: 0,
                            timing: None,
                            first_skip: None,
                            skips: Vec::new(),
                        },
                        Vec::new(),
                    ));
                    out.len() - 1
                }
            };
            let (o, times) = &mut out[i];
            match (&s.ms, &s.skipped) {
                (Some(ms), _) => {
                    o.ran += 1;
                    times.push(*ms);
                }
                (None, why) => {
                    o.left_out += 1;
                    let why = why.as_ref().map_or("-".into(), |w| w.to_string());
                    if o.first_skip.is_none() {
                        o.first_skip = Some(why.clone());
                    }
                    match o.skips.iter_mut().find(|(w, _)| *w == why) {
                        Some((_, n)) => *n += 1,
                        None => o.skips.push((why, 1)),
                    }
                }
            }
        }
    }
    out.into_iter()
        .map(|(mut o, times)| {
            o.timing = (!times.is_empty()).then(|| Timing::of(&times));
            o
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn stage_summary_counts_runs_and_skips_in_stage_order() {
        let frame = |i: u64, skip_b: bool| {
            let mut r = Recorder::new();
            r.ran_for("a", 1.0 + i as f64);
            if skip_b {
                r.skip("b", Skip::NoHistory);
            } else {
                r.ran_for("b", 10.0);
            }
            r.finish("t", i, PixelCounts::default(), InputCounts::default(), 0)
        };
        let records = [frame(0, true), frame(1, false), frame(2, false)];
        let s = summarize_stages(&records);
        assert_eq!(s.iter().map(|s| s.name).collect::<Vec<_>>(), ["a", "b"]);
        assert_eq!((s[0].ran, s[0].left_out), (3, 0));
        assert_eq!(s[0].timing.unwrap().median_ms, 2.0);
        assert_eq!((s[1].ran, s[1].left_out), (2, 1));
        assert_eq!(
            s[1].first_skip.as_deref(),
            Some("no history (first frame or reset)")
        );
        assert!(s[0].first_skip.is_none());
        assert!(missing_channels(&records).is_empty());
    }

    /// Each reason a stage was left out is counted, and each missing channel once per frame
    /// whatever the number of stages it left out.
    #[test]
    fn missing_channels_are_counted_per_frame() {
        let motion = Skip::MissingChannel {
            channel: ChannelKind::Motion,
        };
        let frame = |i: u64, depth: bool| {
            let mut r = Recorder::new();
            r.skip("reproject", motion.clone());
            r.skip("dilate", motion.clone());
            if depth {
                r.skip(
                    "depth_reject",
                    Skip::MissingChannel {
                        channel: ChannelKind::Depth,
                    },
                );
            } else {
                r.skip("depth_reject", Skip::NoHistory);
            }
            r.finish("t", i, PixelCounts::default(), InputCounts::default(), 0)
        };
        let records = [frame(1, false), frame(2, true), frame(3, true)];
        assert_eq!(
            missing_channels(&records),
            [(ChannelKind::Motion, 3), (ChannelKind::Depth, 2)]
        );
        let s = summarize_stages(&records);
        assert_eq!(s[0].skips, [("no motion channel".to_string(), 3)]);
        assert_eq!(
            s[2].skips,
            [
                ("no history (first frame or reset)".to_string(), 1),
                ("no depth channel".to_string(), 2)
            ]
        );
    }
}
