//! `taa`: the industry TAA baseline (Karis 2014, "High quality temporal supersampling";
//! Salvi 2016, "An excursion in temporal supersampling"; Yang, Liu and Salvi 2020; the outline Bevy's TAA
//! and FSR2's accumulate pass follow).
//!
//! Stages per frame:
//! 1. `repair`: non-finite and negative input replaced and counted.
//! 2. `tonemap`: the reversible tonemap `c / (1 + max c)` (HDR input only).
//! 3. `ycocg`: the working colour in YCoCg, where the clip box is built.
//! 4. `dilate`: velocity dilation (motion of the nearest pixel of the 3x3; needs depth).
//! 5. `reproject`: history fetched at `p + motion` with Catmull-Rom (or bilinear); a pixel
//!    whose previous position is off screen restarts. Left out when nothing moves.
//! 6. `depth_reject` (optional): history whose depth disagrees with the current depth by
//!    more than `depth_rejection` (relative) restarts.
//! 7. `resolve`: 3x3 min/max and variance box (mean +- gamma sigma) in YCoCg; history
//!    clipped toward the box centre; blend with `alpha` (raised to 1/(n+1) for young
//!    history, so a restarted pixel converges as a running mean) and Karis's luminance
//!    weights.
//! 8. `sharpen` (optional), 9. `untonemap` (HDR input only).
//!
//! State: history Y, Co, Cg and sample count (+ depth with depth rejection), double-buffered.

mod kernel;
// The scalar statement the fused kernel is tested against (a naive oracle, tests only).
#[cfg(test)]
mod reference;

use super::passes::{convert_texel_history, dilate_skip, reproject_skip, Conversion, TemporalState};
use crate::filter_params;
use crate::filters::passes::{history_filter, temporal_stages};
use crate::frame::{ChannelKind, ChannelSet};
use crate::pipeline::{FilterKind, Inputs, ParamKind, Skip};
use serde::{Deserialize, Serialize};

/// How history is resampled at its reprojected position.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum HistoryFilter {
    /// 5-tap Catmull-Rom (sharp; Karis 2014).
    CatmullRom,
    /// Bilinear (cheaper, blurs history a little every frame that moves).
    Bilinear,
}

filter_params! {
    /// Parameters of `taa`.
    pub struct Params {
        /// weight of the current frame (default 0.2, chosen on the Blender corpus; Karis 2014 and Bevy: 0.1,
        /// Unreal: 0.04). Lower: smoother, more supersampling, more ghosting and lag; higher: sharper
        /// response, more jitter shimmer
        alpha: f32 = DEFAULT_ALPHA, ParamKind::Float { min: 0.01, max: 1.0 };
        /// variance-box half-width in sigmas (Salvi 2016; survey: 0.75-1.25). Lower: less ghosting, more
        /// flicker; higher: stabler, more ghosting
        gamma: f32 = DEFAULT_GAMMA, ParamKind::Float { min: 0.25, max: 4.0 };
        /// history resampling: catmull_rom keeps moving history sharp; bilinear is cheaper and blurs it
        history_filter: HistoryFilter = HistoryFilter::CatmullRom, ParamKind::Choice { options: &["catmull_rom", "bilinear"] };
        /// take the motion of the nearest pixel of the 3x3 (needs depth): moving edges carry their history
        dilation: bool = true, ParamKind::Bool;
        /// weight samples by 1/(1 + luma) (Karis 2014): fewer bright flickering pixels, a slightly darker
        /// bias
        luminance_weighting: bool = true, ParamKind::Bool;
        /// restart history whose reprojected depth differs from the current by more than this fraction (0 =
        /// off); catches disocclusion the colour box misses, can reject on thin geometry
        depth_rejection: f32 = 0.0, ParamKind::Float { min: 0.0, max: 10.0 };
        /// strength of the output cross sharpen (0 = off; 1 = thesis eq. 4.17); counters the blur of
        /// resampling, amplifies noise
        sharpen: f32 = 0.0, ParamKind::Float { min: 0.0, max: 4.0 };
        ..reconstruct
    }
}

/// Blend weight of the current frame: 0.2 (our choice, measured on the Blender corpus;
/// Karis 2014, "High quality temporal supersampling", and Bevy's TAA blend 0.1, Unreal's
/// 0.04). On the corpus' mean, 0.1 / 0.15
/// / 0.2 / 0.25 give 29.87 / 30.02 / 30.23 / 30.30 dB over 16 frames and 0.1 / 0.15 / 0.2
/// give 30.18 / 30.51 / 30.73 over 48, where SSIM and tRMSE improve too (0.0365 ->
/// 0.0361); the moving scenes gain most (`foliage` +1.54, `movers` +1.49), the
/// path-traced `gi` loses 0.60 (docs/corpus.md, "taa's blend weight").
pub const DEFAULT_ALPHA: f32 = 0.2;
/// Variance-box width: 1.0 sigma (Salvi 2016; the survey of Yang, Liu and Salvi 2020 gives 0.75-1.25).
pub const DEFAULT_GAMMA: f32 = 1.0;
/// Sample counts are held at this many frames: past 1/alpha the blend weight is `alpha`
/// anyway, and a bounded count keeps the state bounded on endless still scenes.
pub const MAX_COUNT: f32 = 255.0;

/// Which of `taa`'s optional stages run on a frame, and why each of the others is left out
/// (`None`: it runs). Pure planning from the frame's facts and the parameters: the CPU
/// kernel and the GPU backend (`crate::backend`) follow the same plan, so their records
/// agree.
#[derive(Clone, Debug, PartialEq)]
pub struct StagePlan {
    /// `tonemap` (and `untonemap`): HDR input only.
    pub tonemap: Option<Skip>,
    /// `dilate`: needs reprojection, depth, and `dilation` on.
    pub dilate: Option<Skip>,
    /// `reproject`: needs history, motion and some motion in the frame.
    pub reproject: Option<Skip>,
    /// `depth_reject`: needs `depth_rejection > 0`, depth and history.
    pub depth_reject: Option<Skip>,
    /// `sharpen`: needs `sharpen > 0`.
    pub sharpen: Option<Skip>,
}

impl StagePlan {
    /// The plan for a frame with inputs `inp`, `has_history` saying whether the history
    /// holds a previous frame.
    pub fn new(p: &Params, inp: &Inputs, has_history: bool) -> Self {
        let reproject = reproject_skip(inp, has_history);
        let dilate = dilate_skip(inp, &reproject, p.dilation);
        let depth_reject = (p.depth_rejection <= 0.0)
            .then_some(Skip::Disabled {
                param: "depth_rejection",
            })
            .or_else(|| inp.require(ChannelKind::Depth))
            .or_else(|| (!has_history).then_some(Skip::NoHistory));
        StagePlan {
            tonemap: inp.facts.tonemap(),
            dilate,
            reproject,
            depth_reject,
            sharpen: (p.sharpen <= 0.0).then_some(Skip::Disabled { param: "sharpen" }),
        }
    }

    /// The frame's stages in the record's order, each with why it is left out (`None`: it
    /// runs).
    pub fn stages(&self) -> Vec<(&'static str, Option<Skip>)> {
        vec![
            ("tonemap", self.tonemap.clone()),
            ("ycocg", None),
            ("dilate", self.dilate.clone()),
            ("reproject", self.reproject.clone()),
            ("depth_reject", self.depth_reject.clone()),
            ("resolve", None),
            ("sharpen", self.sharpen.clone()),
            ("untonemap", self.tonemap.clone()),
        ]
    }
}

/// The TAA filter with its history.
#[derive(Debug)]
pub struct Taa {
    params: Params,
    hist: TemporalState,
}

impl FilterKind for Taa {
    const NAME: &'static str = "taa";
    const SUMMARY: &'static str =
        "industry TAA: velocity dilation, Catmull-Rom history, YCoCg variance clipping, luminance-weighted blend";
    temporal_stages! {
        "tonemap", "ycocg", "dilate", "reproject", "depth_reject", "resolve", "sharpen", "untonemap"
    }
    type Params = Params;
    fn uses() -> ChannelSet {
        ChannelSet::of(&[ChannelKind::Color, ChannelKind::Motion, ChannelKind::Depth])
    }
    fn state_bytes_per_pixel(p: &Params) -> usize {
        2 * 4 * Self::history_planes(p)
    }
    fn new(params: Params) -> Self {
        Taa {
            hist: Self::history(&params),
            params,
        }
    }
}

impl Taa {
    /// The filter's empty state: texels [Y, Co, Cg, count] (one vector load per tap of the
    /// history fetch), and a depth plane for depth rejection. The GPU backend saves and
    /// loads its device state through the same layout, so states move between backends.
    pub fn history(p: &Params) -> TemporalState {
        let layout: &[usize] = if p.depth_rejection > 0.0 { &[4, 1] } else { &[4] };
        TemporalState::with_components(layout, Conversion::Custom(convert_texel_history))
    }

    /// History planes: Y, Co, Cg, count, and depth with depth rejection.
    pub(crate) fn history_planes(p: &Params) -> usize {
        if p.depth_rejection > 0.0 {
            5
        } else {
            4
        }
    }
}

history_filter!(Taa, |p, frame, ctx| kernel::frame(p, ctx));

#[cfg(test)]
mod tests {
    use super::reference::ReferenceTaa;
    use super::*;
    use crate::filters::check::{assert_variants_match, sequences, ODD_SIZES};

    /// The fused kernel gives the reference's output, bit for bit, with every option, on
    /// every kind of sequence, at odd sizes.
    #[test]
    fn fused_kernel_matches_the_reference() {
        let variants: &[&[&str]] = &[
            &[],
            &["history_filter=bilinear"],
            &["dilation=false", "luminance_weighting=false"],
            &["depth_rejection=0.05"],
            &["sharpen=0.5"],
            &["alpha=1", "gamma=0.5"],
        ];
        let sizes = ODD_SIZES.iter().copied().chain([(64, 36)]);
        for (w, h) in sizes {
            for (name, frames) in sequences(w, h, 6, (w * 31 + h) as u64) {
                assert_variants_match::<Taa, ReferenceTaa>(variants, &frames, &format!("{w}x{h} {name}"));
            }
        }
    }
}
