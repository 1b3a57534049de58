//! `upsample`: spatio-temporal upsampling (Herzog, Eisemann, Myszkowski, Seidel 2010,
//! "Spatio-Temporal Upsampling on the GPU"), and the three baselines its claim is
//! measured against, as `method`s of one filter.
//!
//! Input: a frame whose colour is shaded at one pixel of every 2x2 or 4x4 block in a
//! rotating order ([`crate::frame::Sampling`]), with the G-buffer (depth, normal, motion,
//! object id) at full resolution. Output: full-resolution colour. A fully shaded frame is
//! accepted too (factor 1).
//!
//! Methods:
//! - `spatiotemporal` (the paper): joint-bilateral gather of this frame's samples (eq.
//!   1-2; `spatial.rs`) blended with an exponential history buffer (eq. 6-7) whose weight is
//!   the accumulated sample weight, decayed by `decay` each frame; the binary "shaded this
//!   frame" weight is the image-space kernel at distance 0. The relative temporal gradient
//!   of luma (sec. 3.4), filtered over the current and three previous gradients (4, 3, 2, 1)
//!   and over a box slightly larger than the block, gives a confidence `c` that (a) scales
//!   the history's weight and (b) sets the image-space kernel's width between
//!   `kernel_sharp` (c = 1: only a pixel's own sample counts, history does the rest) and
//!   `kernel_wide` (c = 0: the whole block footprint, the spatial estimate). Disoccluded
//!   pixels and the first frame count as maximal gradient (fig. 6). The gradient is kept
//!   with its sign and filtered twice, as magnitudes (the paper) and as signed values, in
//!   which the random-sign differences of Monte Carlo noise and of jittered samples cancel;
//!   the confidence reads the magnitudes less `gradient_cancel` (0.75) of what cancelled
//!   ([`GRADIENT_CANCEL`], docs/upsample-realistic.md). A history tap that fails the
//!   validity test is still used when one of the pixel's eight neighbours shows its surface
//!   this frame and moves within `neighbour_motion` (0.1 px) of the pixel: a jittered
//!   G-buffer flips ids and depths at edges from frame to frame ([`NEIGHBOUR_MOTION`]).
//!   The gradient compares a new sample with the pixel's shaded sample before the last
//!   (`gradient_lag` 2, [`GRADIENT_LAG`]; the paper's is the last, 1): with 8-phase jitter and
//!   2x2 shading that one had the same sub-pixel offset, so jitter stops reading as change.
//!   A tap that fails because a sub-pixel surface caught by this frame's jittered G-buffer
//!   sample covers the pixel (the tap's surface is next to the pixel, the pixel's was nowhere
//!   near the tap before) is kept too, so that surface's sample blends in as partial coverage
//!   (`subpixel_keep` 1, [`SUBPIXEL_KEEP`]). A pixel with no normal (the sky) weighs samples by
//!   depth alone (`sky_depth_only`, [`SKY_DEPTH_ONLY`]; all methods' gathers).
//! - `spatial`: the joint-bilateral upsampling alone, wide kernel (Yang et al.'s spatial
//!   method as Herzog et al. 2010 compare it).
//! - `temporal`: reverse reprojection with hole filling (Herzog et al. 2010, eq. 3-4; Nehab et al.):
//!   a shaded pixel takes its sample, another pixel its valid reprojected history, a hole
//!   the spatial estimate.
//! - `taa`: TAA-style upsampling with scaling-aware accumulation (Yang, Liu and Salvi 2020,
//!   "A Survey of Temporal Antialiasing Techniques", "Temporal upsampling"; Unreal's temporal upscale): samples splatted with a Gaussian of the
//!   distance, the blend weight scaled by the best sample's kernel value, history clamped
//!   to the samples' min/max box.
//!
//! Stages: `repair`, `geometry` (the depth range that depth differences are measured
//! against), `reproject` (history along motion, taps tested on object id and depth),
//! `gradient` (spatiotemporal only), `blend`.
//!
//! Choices where the paper is vague (its text is stemmed), and why:
//! - Kernel shape: `(1 - x/sigma)^3`, clamped at 1e-5 (sec. 3.1, fig. 4: "finite support,
//!   clamped to a small epsilon"); image-space distance in units of the block diagonal
//!   (eq. 5: "r the diagonal length").
//! - Footprint: the samples within one block of the pixel along both axes: the four around
//!   an unshaded pixel, a shaded pixel's own sample and its eight lattice neighbours (the
//!   paper's "four nearest" is asymmetric at shaded pixels).
//! - `depth_sigma` 0.03 of the depth range (sec. 3.1 reads "3 ... difference of near and far
//!   frustum plane"); the range is `far - near` when the frame gives it, else the range of
//!   the depths of the pixels showing an object, so that a sky at 1e10 does not flatten it.
//! - `normal_sigma` 0.5 on `1 - n_i . n_j` (weight 0.91 at 10 degrees, 0.39 at 30, 0 past 60):
//!   the paper's value did not survive stemming.
//! - `decay` (0 = auto): `1 - 1 / (2 x period)` per frame, 0.875 for 2x2 and 0.969 for 4x4,
//!   so a pixel keeps about two of its own samples (the paper: "a window of 16 frames for
//!   4x4"), but at least `min_decay` 0.93 ([`MIN_DECAY`]: at 2x2 two samples are too few to
//!   average jitter and noise); lower reacts faster, higher averages more.
//! - History is fetched bilinearly over the taps that pass the validity test, renormalised
//!   (fig. 9 weighs nearest against bilinear; bilinear avoids the "precision loss" of
//!   nearest under continuous motion); the history weight is scaled by the passing taps'
//!   share. Gradients live at full resolution: each pixel takes its block's sample's.

mod kernel;
// The scalar statement the fused kernel is tested against (a naive oracle, tests only).
#[cfg(test)]
mod reference;
mod spatial;
mod temporal;

use crate::filters::passes::{history_filter, temporal_stages};
#[cfg(test)]
use kernel::depth_range as depth_range_fast;
pub use kernel::{geometry, skips};
pub use spatial::{depth_range, falloff, Gathered, Geometry, Sparse, WEIGHT_EPSILON};
pub use temporal::{
    confidence, filter_gradients, relative_gradient, reproject, seen_before, signed_gradient, surface_nearby,
    Nearby, Validity, GRADIENT_WEIGHTS, LUMA_FLOOR,
};

use super::passes::{Conversion, TemporalState};
use crate::filter_params;
use crate::frame::{ChannelKind, ChannelSet, Plane, Sampling};
use crate::pipeline::{FilterKind, ParamKind, StateError};
use serde::{Deserialize, Serialize};

/// Which reconstruction.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Method {
    /// Herzog et al. 2010: joint bilateral + exponential history steered by the gradient.
    Spatiotemporal,
    /// Joint-bilateral upsampling of this frame's samples only.
    Spatial,
    /// Reprojection cache with hole filling.
    Temporal,
    /// TAA-style upsampling (scaling-aware accumulation, clamped history).
    Taa,
}

impl Method {
    /// The method's parameter value.
    pub fn name(self) -> &'static str {
        match self {
            Method::Spatiotemporal => "spatiotemporal",
            Method::Spatial => "spatial",
            Method::Temporal => "temporal",
            Method::Taa => "taa",
        }
    }

    /// History planes the method keeps.
    pub fn planes(self) -> usize {
        match self {
            Method::Spatiotemporal => 13,
            Method::Temporal => 5,
            Method::Taa => 4,
            Method::Spatial => 0,
        }
    }
}

/// History planes of the reference (the filter keeps them as the channels of one plane of
/// interleaved texels, in this order): colour, weight (spatiotemporal) or sample count
/// (taa), then the previous frame's depth and ids for the validity test, then three past
/// gradients. Public for the GPU backend, whose shaders read the same texels.
pub const R: usize = 0;
/// The accumulated weight (`spatiotemporal`) or sample count (`taa`).
pub const W: usize = 3;
/// Depth of `temporal` (which has no weight plane).
pub const T_DEPTH: usize = 3;
/// Object id of `temporal`.
pub const T_ID: usize = 4;
/// Depth of `spatiotemporal`.
pub const DEPTH: usize = 4;
/// Object id of `spatiotemporal`.
pub const ID: usize = 5;
/// The newest of the three past gradients of `spatiotemporal`.
pub const G1: usize = 6;
/// Luma of the pixel's last shaded sample times `K`, and `K`: 1 where that sample is known
/// (both carried along the motion; their ratio survives bilinear fetches across unknowns);
/// then the same two for the shaded sample before it (`gradient_lag` 2).
pub const LK: usize = 9;

filter_params! {
    /// Parameters of `upsample`.
    pub struct Params {
        /// spatiotemporal (Herzog et al. 2010), or a baseline: spatial (joint bilateral only), temporal
        /// (reprojection with hole filling), taa (scaling-aware accumulation)
        method: Method = Method::Spatiotemporal, ParamKind::Choice { options: &["spatiotemporal", "spatial", "temporal", "taa"] };
        /// history weight kept per frame (0 = auto: 1 - 1/(2 x pattern period), 0.875 for 2x2 and 0.969 for
        /// 4x4, at least min_decay). Higher: smoother, more lag on changes the gradient misses; lower:
        /// faster, noisier
        decay: f32 = 0.0, ParamKind::Float { min: 0.0, max: 0.999 };
        /// the least decay the automatic one (decay = 0) takes with sparse shading: 0.93 lengthens 2x2's
        /// history (0.875) and leaves 4x4's (0.969); 0: the automatic rule alone. Higher: jitter and noise
        /// average over more frames, slower convergence, more lag on changes the gradient misses
        min_decay: f32 = MIN_DECAY, ParamKind::Float { min: 0.0, max: 0.999 };
        /// relative luma gradient at which history is no longer trusted (Herzog et al. 2010, eq. 8: 1).
        /// Lower: reacts to smaller changes, blurrier; higher: sharper, more lag
        gradient_scale: f32 = 1.0, ParamKind::Float { min: 0.01, max: 100.0 };
        /// which of the pixel's past shaded samples the temporal gradient compares its new sample with: 1,
        /// the last (Herzog et al. 2010, sec. 3.4), or 2, the one before it (1 where that is unknown). With
        /// 8-phase jitter and 2x2 shading (period 4) that sample had the same jitter offset, so the sub-pixel
        /// offset stops reading as change; a change of the shading is measured over twice the time
        gradient_lag: u32 = GRADIENT_LAG, ParamKind::Int { min: 1, max: 2 };
        /// share of the gradient that changes of random sign may cancel: the confidence reads the filtered
        /// magnitudes (Herzog et al. 2010, sec. 3.4; 0) less this share of what the same filters cancel on
        /// the signed gradients (1). Higher: Monte Carlo noise and jittered samples of sub-pixel detail stop
        /// reading as change and history is kept; lower: history resampled under motion, blurred, is caught
        /// and replaced sooner
        gradient_cancel: f32 = GRADIENT_CANCEL, ParamKind::Float { min: 0.0, max: 1.0 };
        /// image-space kernel width at full confidence, in block diagonals: below 1/(factor x 1.41) (0.18 for
        /// 4x4) no other sample reaches it, so a still image converges to its own samples; higher blurs
        /// converged detail
        kernel_sharp: f32 = 0.1, ParamKind::Float { min: 0.01, max: 4.0 };
        /// image-space kernel width at no confidence and for the spatial method, in block diagonals (1: the
        /// block footprint). Higher: smoother fill, blurrier
        kernel_wide: f32 = 1.0, ParamKind::Float { min: 0.01, max: 4.0 };
        /// depth difference (fraction of the frame's depth range) at which a sample stops counting (Herzog et
        /// al. 2010: 3%). Lower: sharper silhouettes, grazing surfaces fill worse
        depth_sigma: f32 = 0.03, ParamKind::Float { min: 1e-4, max: 10.0 };
        /// normal difference (1 - cos) at which a sample stops counting. Lower: sharper creases, curved
        /// surfaces fill worse
        normal_sigma: f32 = 0.5, ParamKind::Float { min: 1e-3, max: 2.0 };
        /// relative depth difference a history tap may have and still count as the same surface. Lower:
        /// catches more disocclusion, also rejects valid history under fast motion in depth
        depth_tolerance: f32 = 0.1, ParamKind::Float { min: 1e-3, max: 10.0 };
        /// spatiotemporal: a history tap that fails the validity test (Herzog et al. 2010, sec. 3.2: same
        /// object id, same depth) is still accepted when one of the pixel's eight neighbours this frame shows
        /// its surface (id and depth) and moves within this many pixels of the pixel (0: off, the paper's
        /// test). Higher: a jittered G-buffer's edges and sub-pixel objects keep their history; too high:
        /// history of an object that moved away survives next to it (ghosting at disocclusions)
        neighbour_motion: f32 = NEIGHBOUR_MOTION, ParamKind::Float { min: 0.0, max: 100.0 };
        /// a pixel whose normal is zero (the sky: the ray hit nothing) weighs samples by depth alone. false:
        /// the normal term as for a surface, 1 - n.n' = 1 against every sample, so the sky's samples and
        /// history weigh the clamp 1e-5 and any surface's sample or history outweighs them (a jittered edge
        /// against the sky takes the object's full colour, a sub-pixel object over the sky its full colour).
        /// true leaves two sky directions, which have no geometry, to the image-space kernel
        sky_depth_only: bool = SKY_DEPTH_ONLY, ParamKind::Bool;
        /// spatiotemporal: share of its weight a history tap keeps when it fails the validity test because a
        /// sub-pixel surface, caught by this frame's jittered G-buffer sample, covers the pixel: the tap's
        /// surface is next to the pixel this frame (any motion) and the pixel's surface was nowhere within a
        /// pixel of the tap in the previous frame. The new surface's sample then blends into the history as
        /// one sample of partial coverage, and its gradient is 0 (nothing of that surface to compare with).
        /// 0: off (Herzog et al. 2010, sec. 3.2: rejected, the pixel takes the sub-pixel surface's full
        /// colour). Higher: thin objects converge toward their coverage; an object uncovered faster than a
        /// pixel per frame from behind another blends in over a few frames
        subpixel_keep: f32 = SUBPIXEL_KEEP, ParamKind::Float { min: 0.0, max: 1.0 };
        /// taa method: blend weight of a sample at its own pixel (Karis 2014: 0.1)
        taa_alpha: f32 = crate::filters::taa::DEFAULT_ALPHA, ParamKind::Float { min: 0.01, max: 1.0 };
        ..reconstruct
    }
}

/// Default `gradient_cancel`: the share of the gradient that changes of random sign may
/// cancel (not in Herzog et al. 2010, whose sec. 3.4 filters magnitudes, i.e. 0). Chosen on
/// the mean over the ten catalogue scenes with 2x2 shading at 128x72, 32 frames
/// (docs/upsample-realistic.md): noise-free, 0 / 0.5 / 0.75 / 1 give 25.60 / 25.63 / 25.64 /
/// 25.64 dB and tRMSE 0.0511 / 0.0500 / 0.0495 / 0.0491; with `--jitter 8 --noise` 24.87 /
/// 24.91 / 24.95 / 25.02 dB. The tradeoff is history resampled under camera motion, which
/// blurs textures in ways of random sign: at 1 the noise-free flyover falls below temporal
/// reprojection (25.23 against 25.27 dB), at 0.75 it stays above (25.32).
pub const GRADIENT_CANCEL: f32 = 0.75;

/// Default `gradient_lag`: see the parameter (Herzog et al. 2010, sec. 3.4 compare with the
/// last shaded sample, 1). Chosen on the mean over the ten catalogue scenes with 2x2
/// shading at 128x72, 32 frames (docs/upsample-realistic.md), never on one scene, measured
/// with `min_decay = 0` (before that default): with `--jitter 8 --noise` 1 / 2 give 25.262 / 25.429 dB (tRMSE 0.0630 / 0.0614), noise-free
/// 25.627 / 25.633 dB; with 4x4 shading (where the last sample already had the same jitter
/// offset) 24.201 / 24.203 and 24.909 / 24.908 dB.
pub const GRADIENT_LAG: u32 = 2;

/// Default `min_decay`: the least decay the automatic rule `1 - 1 / (2 x period)` (0.875 for
/// 2x2, 0.969 for 4x4, after Herzog et al. 2010's "window of 16 frames for 4x4") takes; at 2x2
/// a pixel otherwise keeps about two of its own samples, too few to average jitter and noise.
/// Chosen on the mean over the ten catalogue scenes with 2x2 shading at 128x72, 32 frames,
/// with `gradient_lag` 2 (docs/upsample-realistic.md), never on one scene: 0 (0.875) / 0.9 /
/// 0.93 / 0.95 / 0.97 / 0.985 give 25.429 / 25.468 / 25.509 / 25.531 / 25.550 / 25.562 dB with
/// `--jitter 8 --noise` and 25.633 / 25.642 / 25.651 / 25.656 / 25.660 / 25.662 noise-free.
/// The mean keeps rising past 0.93, but the tests' claims stop holding: at 0.985 the
/// noise-free flyover falls below temporal reprojection (25.22 against 25.27 dB: history
/// resampled under camera motion is kept longer; 0.97 25.27, a 0.005 dB margin; 0.95 25.34;
/// 0.93 25.40) and the still scene is not converged after 32 frames at 2x2 (RMS 0.0014
/// against full-res shading, limit 0.001; 0.0005 at 0.93; 0.95 and 0.97 not run against
/// it), so 0.93 is the largest value checked against both (0.95 would add 0.02 dB with
/// jitter and noise). A floor rather than a fixed decay: 0.93 for 4x4 too
/// lowers its means (24.909 -> 24.879 dB noise-free, 24.201 -> 24.180 with jitter and
/// noise), whose automatic 0.969 it leaves.
pub const MIN_DECAY: f32 = 0.93;

/// Default `sky_depth_only`: true (the paper's normal term, false, treats a pixel without a
/// normal as a surface at right angles to every sample). Chosen on the mean over the ten
/// catalogue scenes with 2x2 shading at 128x72, 32 frames (docs/upsample-realistic.md),
/// never on one scene, with `subpixel_keep` 0: false / true give 25.509 / 25.722 dB (tRMSE
/// 0.0605 / 0.0600) with `--jitter 8 --noise` and 25.651 / 25.808 dB (0.0478 / 0.0476)
/// noise-free; with 4x4 shading 24.203 / 24.316 and 24.908 / 24.984 dB. No scene loses at
/// 2x2; fence gains most (+0.73 / +1.12 dB), through its edges against the sky. The
/// tradeoff: two sky pixels are no longer told apart by anything but the image-space
/// kernel (they have no geometry; the scenes' skies are smooth).
pub const SKY_DEPTH_ONLY: bool = true;

/// Default `subpixel_keep`. Chosen on the mean over the ten catalogue scenes with 2x2
/// shading at 128x72, 32 frames (docs/upsample-realistic.md), never on one scene, with
/// `sky_depth_only`: 0 / 0.25 / 0.5 / 1 give 25.722 / 25.934 / 26.049 / 26.112 dB (tRMSE
/// 0.0600 / 0.0584 / 0.0577 / 0.0573) with `--jitter 8 --noise` and 25.808 / 26.039 /
/// 26.174 / 26.252 dB (0.0476 / 0.0459 / 0.0451 / 0.0446) noise-free; 1 is the largest
/// value. With 4x4 shading 0 / 1 give 24.316 / 24.494 dB with jitter and noise and 24.984 /
/// 25.188 noise-free. Thin-line gains most (30.18 -> 34.00 dB with jitter and noise at 2x2),
/// then spokes (+0.29); foliage loses 0.17 dB with jitter and noise (+0.16 noise-free), hdr
/// 0.05.
pub const SUBPIXEL_KEEP: f32 = 1.0;

/// Default `neighbour_motion` (px): how closely the surface of a history tap that failed
/// the validity test of Herzog et al. 2010, sec. 3.2 must move with the pixel when one of the
/// pixel's eight neighbours shows it this frame, for the tap to count
/// ([`surface_nearby`]; not in the paper, whose test is the strict one, 0). Chosen on the
/// mean over the ten catalogue scenes with 2x2 shading at 128x72, 32 frames
/// (docs/upsample-realistic.md): with `--jitter 8 --noise` 0 / 0.05 / 0.1 / 0.2 / 0.5 give
/// 24.95 / 25.24 / 25.26 / 25.24 / 24.54 dB (tRMSE 0.0718 / 0.0634 / 0.0630 / 0.0620 /
/// 0.0602); noise-free 25.64 / 25.63 / 25.63 / 25.58 dB (tRMSE 0.0495 / 0.0482 / 0.0480 /
/// 0.0476). Larger values let thin objects that move over a still background (spokes,
/// thin-line) leave trails.
pub const NEIGHBOUR_MOTION: f32 = 0.1;

/// Fit of the Blackman-Harris reconstruction kernel, `exp(-2.29 d^2)` with `d` in output
/// pixels (Karis 2014, "High quality temporal supersampling", used by Unreal's temporal
/// upscale that Yang, Liu and Salvi 2020 cite for scaling-aware accumulation).
pub const TAA_KERNEL: f32 = 2.29;
/// Sample counts of the `taa` method are held here (as in `taa`): past 1/alpha the blend is
/// alpha anyway.
pub const TAA_MAX_COUNT: f32 = 255.0;

/// The upsampling filter with its history.
#[derive(Debug)]
pub struct Upsample {
    params: Params,
    hist: TemporalState,
}

/// Upsample's history is linear colour whatever the frame's range: nothing to convert.
fn keep_history(_: &mut [Plane<f32>], _: bool) {}

/// Largest accumulated sample weight a `spatiotemporal` history holds: each frame adds at
/// most the kernel's weight and keeps `decay` < 1 of the rest, so it stays within a few
/// thousand; far above it, products of weights overflow f32.
const MAX_HISTORY_WEIGHT: f32 = 1e6;

/// Checks loaded history texels: colour non-negative, the `spatiotemporal` weight within
/// [0, [`MAX_HISTORY_WEIGHT`]] and the `taa` count within [0, [`TAA_MAX_COUNT`]].
fn check_history(planes: &[Plane<f32>], components: &[usize], _: bool) -> Result<(), StateError> {
    let (Some(texels), Some(&n)) = (planes.first(), components.first()) else {
        return Ok(());
    };
    let w = (texels.width() / n.max(1)).max(1);
    for (i, t) in texels.data().chunks_exact(n.max(1)).enumerate() {
        let bad = |what: &str, v: f32| {
            Err(StateError::Plane {
                plane: 0,
                message: format!(
                    "pixel ({}, {}): {what} is {v}, which the filter never writes",
                    i % w,
                    i / w
                ),
            })
        };
        if let Some(&c) = t.iter().take(3).find(|&&c| c < 0.0) {
            return bad("a history colour", c);
        }
        if n == Method::Spatiotemporal.planes() && !(0.0..=MAX_HISTORY_WEIGHT).contains(&t[W]) {
            return bad("the accumulated weight", t[W]);
        }
        if n == Method::Taa.planes() && !(0.0..=TAA_MAX_COUNT).contains(&t[3]) {
            return bad("the sample count", t[3]);
        }
    }
    Ok(())
}

impl FilterKind for Upsample {
    const NAME: &'static str = "upsample";
    const SUMMARY: &'static str =
        "spatio-temporal upsampling of sparse shading (Herzog et al. 2010), with spatial, temporal and TAA-style baselines";
    temporal_stages! { "geometry", "reproject", "gradient", "blend" }
    type Params = Params;
    const SPARSE_INPUT: bool = true;
    fn uses() -> ChannelSet {
        ChannelSet::of(&[
            ChannelKind::Color,
            ChannelKind::Depth,
            ChannelKind::Normal,
            ChannelKind::Motion,
            ChannelKind::ObjectId,
        ])
    }
    fn state_bytes_per_pixel(p: &Params) -> usize {
        2 * 4 * p.method.planes()
    }
    fn new(params: Params) -> Self {
        Upsample {
            hist: Upsample::history(&params),
            params,
        }
    }
}

impl Upsample {
    /// The filter's empty state: one plane of texels holding the reference's planes side by
    /// side (one load per tap of the history fetch); none for `spatial`. The GPU backend
    /// saves and loads its device state through the same layout.
    pub fn history(p: &Params) -> TemporalState {
        let n = p.method.planes();
        let layout: &[usize] = if n > 0 { &[n] } else { &[] };
        TemporalState::with_components(layout, Conversion::Custom(keep_history)).checked_by(check_history)
    }
}

/// The decay in effect for a pattern: `decay`, or when 0 `1 - 1 / (2 x period)`, for sparse
/// shading at least `min_decay` (fully shaded frames keep 0.5: not measured with the floor).
pub fn decay_for(p: &Params, sampling: Sampling) -> f32 {
    if p.decay > 0.0 {
        p.decay
    } else {
        let auto = 1.0 - 1.0 / (2.0 * sampling.period() as f32);
        if sampling.period() > 1 {
            auto.max(p.min_decay)
        } else {
            auto
        }
    }
}

impl Upsample {
    /// The decay in effect for a pattern.
    pub fn decay(&self, sampling: Sampling) -> f32 {
        decay_for(&self.params, sampling)
    }
}

history_filter!(Upsample, |p, frame, ctx| kernel::frame(
    p,
    decay_for(p, frame.sampling()),
    frame.sampling(),
    frame.meta.near_far,
    ctx
));

#[cfg(test)]
mod tests {
    use super::reference::ReferenceUpsample;
    use super::*;
    use crate::filters::check::prelude::*;
    use crate::filters::check::{assert_variants_match, sparse_sequences, Reference, ODD_SIZES};
    use crate::pipeline::params::{build, parse_assignments};
    use crate::rng::SplitMix64;
    use crate::tolerance::Tolerance;

    impl Reference<Upsample> for ReferenceUpsample {
        fn with_params(params: Params) -> Self {
            Self::new(params)
        }

        fn filter(&mut self, frame: &Frame) -> Output {
            self.process(frame).unwrap()
        }
    }

    #[test]
    fn a_loaded_history_out_of_range_is_refused() {
        let mut f = Upsample::new(Params::default());
        for i in 0..2 {
            let mut frame = crate::scene::synthetic_frame(12, 8, i);
            frame.meta.index = i;
            f.push(&frame).unwrap();
        }
        let good = f.save_state().unwrap();
        f.load_state(&good).unwrap();
        // A weight no frame can accumulate (products of weights overflow f32), then a
        // negative colour: each named, the filter's history as it was.
        for (k, v, what) in [(W, 2.2e38, "accumulated weight"), (R + 1, -1.0, "history colour")] {
            let mut bad = good.clone();
            bad.planes[0].data_mut()[13 * 9 + k] = v;
            let e = f.load_state(&bad).unwrap_err().to_string();
            assert!(e.contains("pixel (9, 0)") && e.contains(what), "{e}");
        }
    }

    /// The fused kernels give the reference's output, bit for bit, for every method and
    /// option, on every kind of sparse sequence (2x2, 4x4 and full shading), at odd sizes.
    #[test]
    fn fused_kernel_matches_the_reference() {
        let variants: &[&[&str]] = &[
            &["method=spatiotemporal"],
            &["method=spatiotemporal", "gradient_cancel=0"],
            &["method=spatiotemporal", "neighbour_motion=0.5"],
            &["method=spatiotemporal", "gradient_lag=2"],
            &["method=spatiotemporal", "gradient_lag=1", "min_decay=0"],
            &["method=spatiotemporal", "sky_depth_only=false", "subpixel_keep=0"],
            &["method=spatiotemporal", "subpixel_keep=0.5", "neighbour_motion=0"],
            &["method=spatial", "sky_depth_only=false"],
            &["method=temporal", "sky_depth_only=false"],
            &[
                "method=spatiotemporal",
                "gradient_lag=2",
                "gradient_cancel=0",
                "decay=0.6",
            ],
            &[
                "method=spatiotemporal",
                "neighbour_motion=50",
                "depth_tolerance=0.01",
            ],
            &[
                "method=spatiotemporal",
                "gradient_cancel=0.3",
                "gradient_scale=0.5",
            ],
            &[
                "method=spatiotemporal",
                "decay=0.5",
                "gradient_scale=0.2",
                "kernel_sharp=0.5",
            ],
            &[
                "method=spatiotemporal",
                "kernel_wide=2.5",
                "depth_sigma=0.5",
                "normal_sigma=0.05",
            ],
            &["method=spatial"],
            &["method=spatial", "kernel_wide=0.3", "depth_sigma=0.001"],
            &["method=temporal"],
            &["method=temporal", "depth_tolerance=0.001", "kernel_wide=3"],
            &["method=taa"],
            &["method=taa", "taa_alpha=0.5"],
        ];
        let sizes = ODD_SIZES.iter().copied().chain([(64, 36)]);
        for (w, h) in sizes {
            for factor in [2, 4, 1] {
                let seed = (w * 31 + h) as u64 + factor as u64;
                let mut seqs = sparse_sequences(w, h, 7, seed, factor);
                let sky = sky_without_normals(&seqs[0].1);
                seqs.push(("sky without normals", sky));
                for (name, frames) in seqs {
                    let what = format!("{w}x{h} {factor}x{factor} {name}");
                    assert_variants_match::<Upsample, ReferenceUpsample>(variants, &frames, &what);
                }
            }
        }
    }

    /// `frames` with the normals of their pixels of object 0 (the sky) zeroed, as the
    /// renderer writes them.
    fn sky_without_normals(frames: &[Frame]) -> Vec<Frame> {
        frames
            .iter()
            .map(|f| {
                let mut f = f.clone();
                let ids = f.object_id().expect("ids").clone();
                let normal: Vec<Plane<f32>> = f
                    .planes(ChannelKind::Normal)
                    .expect("normals")
                    .iter()
                    .map(|p| {
                        Plane::from_fn(f.width(), f.height(), |x, y| {
                            if ids.get(x, y) == 0 {
                                0.0
                            } else {
                                p.get(x, y)
                            }
                        })
                    })
                    .collect();
                f.set_f32(ChannelKind::Normal, normal).expect("same size");
                f
            })
            .collect()
    }

    /// The sequences of `fused_kernel_matches_the_reference` take the paths of
    /// `subpixel_keep` and `sky_depth_only`: switching either off changes the output.
    #[test]
    fn the_sequences_exercise_sub_pixel_history_and_the_sky() {
        let frames = sky_without_normals(&sparse_sequences(33, 19, 7, 5, 2)[0].1);
        let last = |set: &[&str]| {
            let params: Params = build("upsample", &parse_assignments(set).unwrap()).unwrap();
            let mut f = ReferenceUpsample::new(params);
            let outs: Vec<Output> = frames.iter().map(|fr| f.process(fr).unwrap()).collect();
            outs.into_iter()
                .flat_map(|o| o.color.into_iter().flat_map(|p| p.data().to_vec()))
                .collect::<Vec<f32>>()
        };
        let now = last(&[]);
        for off in ["subpixel_keep=0", "sky_depth_only=false"] {
            assert!(
                Tolerance::EXACT.check_slices(off, &now, &last(&[off])).is_err(),
                "{off} changes nothing on these frames"
            );
        }
    }

    /// The vectorised depth range is the reference's, with and without ids and planes.
    #[test]
    fn depth_range_matches_the_reference() {
        let mut rng = SplitMix64::new(3);
        for n in [1usize, 7, 8, 9, 100, 70_001] {
            let mut depth: Vec<f32> = (0..n).map(|_| (rng.next_f64() * 50.0 - 5.0) as f32).collect();
            depth[n / 2] = f32::NAN;
            depth[n / 3] = f32::INFINITY;
            let ids: Vec<u32> = (0..n).map(|_| (rng.next_f64() * 3.0) as u32).collect();
            for ids in [None, Some(&ids[..])] {
                for nf in [None, Some([0.5, 20.0]), Some([3.0, 3.0])] {
                    assert_eq!(
                        depth_range_fast(&depth, ids, nf).to_bits(),
                        depth_range(&depth, ids, nf).to_bits(),
                        "{n} {nf:?}"
                    );
                }
            }
        }
        assert_eq!(depth_range_fast(&[f32::NAN; 3], None, None), 1.0);
    }
}
