//! `traa`: temporal reprojection anti-aliasing after Oliveros 2018 (*Improved sampling for
//! temporal anti-aliasing*, the thesis below).
//!
//! `variant = baseline` is the thesis's starting point, the INSIDE / Uncharted 4 TRAA
//! (Pedersen 2016 = thesis ref. \[6\]; Xu 2016 = ref. \[19\]), sec. 3.6:
//! velocity of the nearest pixel of the 3x3 (3.6.3); history fetched bilinearly; min/max of
//! the 3x3 and of the cross (+) averaged into the colour box (3.6.3); history clipped toward
//! the box centre (3.6.4); feedback from the luminance difference of clipped history and
//! current, biased toward history (3.6.3); the sharpen of eq. 3.1 on the output (3.6.5).
//!
//! `variant = improved` adds chapter 4.3 (each term is left out when its channel is):
//! - `sobel`: Sobel magnitudes of the lit luma l, the albedo luma u and the linear depth d,
//!   `g = 0.3 u + 0.7 l + d` (eq. 4.9), clamped to [0, 1], `sobel = sqrt(g^2 (3 - 2 g))`
//!   (eq. 4.10);
//! - `sobel_history`: the Sobel image's own one-channel TRAA (clamp instead of clip, no
//!   sharpen; sec. 4.3.3) kept in the state, so the edge mask is stable over time;
//! - `model_average`: share of the 3x3 with another object id (eq. 4.1);
//! - `depth_variance`: depth pseudo-variance and temporal pseudo-variance (eq. 4.4-4.6), zero when the
//!   normalising distance is below 0.002;
//! - `aliased`: aliasedValue = clamp01(sobelAvg + depthPV + depthTPV + modelAverage) (eq. 4.12-4.14)
//!   mixes the cross and 3x3 boxes (eq. 4.15) and shrinks the box toward the current colour
//!   (eq. 4.16);
//! - the normalised sharpen of eq. 4.17.
//!
//! Choices where the thesis is silent, and why:
//! - The feedback formula and its bounds 0.88 / 0.97 are INSIDE's (`_FeedbackMin`,
//!   `_FeedbackMax` of Playdead's TemporalReprojection shader, which sec. 3.6.3 describes
//!   in words): `k = lerp(0.88, 0.97, (1 - |l0 - l1| / max(l0, l1, 0.2))^2)`.
//! - Linear depth is used as `depth / far` (Unity's Linear01Depth, the depth the thesis's
//!   0.002 threshold of sec. 4.3.2 is stated in): `far` from the frame's near/far planes,
//!   else the largest depth in the frame.
//! - Without albedo, `g = l + d` (the lit and unlit weights of eq. 4.9 summed).
//! - The box is clipped toward its centre, as INSIDE's `clip_aabb` does; the thesis's
//!   figure draws the current colour at the centre, which eq. 4.16 makes true when the box
//!   shrinks.
//! - Sharpening is applied to the displayed output only, never fed back into history.
//! - In HDR the filter works on tonemapped colour `c / (1 + max c)` (as `taa`), so eq.
//!   3.1's "colour peak" cannot reach extreme values.
//!
//! The filter runs as one fused pass over bands of rows (`kernel.rs`), plus a second band
//! pass for the sharpen, which reads its neighbours in the finished output; the stage by
//! stage statement of the same function is kept as `reference::ReferenceTraa` (tests only), and the
//! tests check the two give the same bits.
//!
//! State: history RGB (working space) as interleaved texels `[r, g, b]` (baseline) or
//! `[r, g, b, sobel]` (improved, with a second plane of depth / far), double-buffered.

mod kernel;
// The scalar statement the fused kernel is tested against (a naive oracle, tests only).
#[cfg(test)]
mod reference;

use super::passes::{Conversion, TemporalState};
use crate::filter_params;
use crate::filters::passes::{history_filter, reproject_skip, temporal_stages};
use crate::frame::{ChannelKind, ChannelSet, Plane};
use crate::kernels::{lanes, tonemap, tonemap_inverse};
use crate::pipeline::exec::for_rows;
use crate::pipeline::{FilterKind, Inputs, ParamKind, Skip};
use serde::{Deserialize, Serialize};
use wide::f32x8;

/// Which TRAA of the thesis.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Variant {
    /// INSIDE / Uncharted 4 (thesis sec. 3.6).
    Baseline,
    /// The thesis's improvements (sec. 4.3).
    Improved,
}

impl Variant {
    fn name(self) -> &'static str {
        match self {
            Variant::Baseline => "baseline",
            Variant::Improved => "improved",
        }
    }
}

filter_params! {
    /// Parameters of `traa`.
    pub struct Params {
        /// baseline: INSIDE / Uncharted 4 TRAA (thesis sec. 3.6); improved: with Sobel history, object ids,
        /// depth pseudo-variance and the adaptive box (sec. 4.3)
        variant: Variant = Variant::Improved, ParamKind::Choice { options: &["baseline", "improved"] };
        /// history weight where current and history luma differ most (INSIDE 0.88). Higher: smoother, more
        /// ghosting
        feedback_min: f32 = FEEDBACK_MIN, ParamKind::Float { min: 0.0, max: 0.999 };
        /// history weight where they agree (INSIDE 0.97). Higher: more supersampling on still content, slower
        /// response
        feedback_max: f32 = FEEDBACK_MAX, ParamKind::Float { min: 0.0, max: 0.999 };
        /// sharpen the output: eq. 3.1 (strength 4) for baseline, the normalised eq. 4.17 for improved
        sharpen: bool = true, ParamKind::Bool;
        ..reconstruct
    }
}

/// INSIDE's `_FeedbackMin` (Pedersen 2016; the feedback of thesis sec. 3.6.3).
pub const FEEDBACK_MIN: f32 = 0.88;
/// INSIDE's `_FeedbackMax` (Pedersen 2016).
pub const FEEDBACK_MAX: f32 = 0.97;
/// Floor of the luma normaliser in the feedback (INSIDE: `max(lum0, max(lum1, 0.2))`).
pub const FEEDBACK_LUMA_FLOOR: f32 = 0.2;
/// Sharpen strength of eq. 3.1, `[0 -1 0; -1 5 -1; 0 -1 0]` (Oliveros 2018, after Xu 2016).
pub const SHARPEN_BASELINE: f32 = 4.0;
/// Sharpen strength of eq. 4.17, `[0 -0.25 0; -0.25 2 -0.25; 0 -0.25 0]` (Oliveros 2018).
pub const SHARPEN_IMPROVED: f32 = 1.0;
/// Eq. 4.9: weight of the albedo ("unlit") luma Sobel.
pub const SOBEL_UNLIT_WEIGHT: f32 = 0.3;
/// Eq. 4.9: weight of the lit luma Sobel.
pub const SOBEL_LIT_WEIGHT: f32 = 0.7;
/// Sec. 4.3.2: below this normalising depth distance the pseudo-variances are zero.
pub const DEPTH_DISTANCE_MIN: f32 = 0.002;

/// History planes of the reference: working RGB, then (improved) the Sobel history and
/// depth / far. (The filter itself keeps the same values as texels, see [`Traa`].)
#[cfg(test)]
const SOBEL: usize = 3;
#[cfg(test)]
const DEPTH01: usize = 4;

/// Which of `traa`'s optional stages run on a frame, and why each of the others is left
/// out (`None`: it runs), as the reference plans them. The CPU kernel and the GPU backend
/// follow the same plan, so their records agree.
#[derive(Clone, Debug, PartialEq)]
pub struct StagePlan {
    /// `tonemap` (and `untonemap`): HDR input only.
    pub tonemap: Option<Skip>,
    /// `reproject`: needs history, motion and some motion in the frame.
    pub reproject: Option<Skip>,
    /// `dilate`: needs reprojection and depth.
    pub dilate: Option<Skip>,
    /// The improved variant's own stages (`sobel`, `aliased`).
    pub variant: Option<Skip>,
    /// `sobel_history`: needs history.
    pub sobel_history: Option<Skip>,
    /// `model_average`: improved, with object ids.
    pub model: Option<Skip>,
    /// `depth_variance` (and depth / far in the Sobel): improved, with depth.
    pub depth: Option<Skip>,
    /// `sharpen`: needs `sharpen` on.
    pub sharpen: Option<Skip>,
}

impl StagePlan {
    /// The plan for a frame with inputs `inp`, `has_history` saying whether the history
    /// holds a previous frame.
    pub fn new(p: &Params, inp: &Inputs, has_history: bool) -> Self {
        let improved = p.variant == Variant::Improved;
        let reproject = reproject_skip(inp, has_history);
        let variant = (!improved).then_some(Skip::Variant {
            variant: p.variant.name(),
        });
        StagePlan {
            tonemap: inp.facts.tonemap(),
            dilate: reproject.clone().or_else(|| inp.require(ChannelKind::Depth)),
            reproject,
            sobel_history: (!has_history).then_some(Skip::NoHistory),
            model: variant.clone().or_else(|| inp.require(ChannelKind::ObjectId)),
            depth: variant.clone().or_else(|| inp.require(ChannelKind::Depth)),
            variant,
            sharpen: (!p.sharpen).then_some(Skip::Disabled { param: "sharpen" }),
        }
    }

    /// The stages from `tonemap` to `untonemap` in the order the filter records them, each
    /// with why it is left out (`sobel_history` only in the improved variant).
    pub fn stages(&self, improved: bool) -> Vec<(&'static str, Option<Skip>)> {
        let mut stages = vec![
            ("tonemap", self.tonemap.clone()),
            ("dilate", self.dilate.clone()),
            ("reproject", self.reproject.clone()),
            ("sobel", self.variant.clone()),
        ];
        if improved {
            stages.push(("sobel_history", self.sobel_history.clone()));
        }
        stages.extend([
            ("model_average", self.model.clone()),
            ("depth_variance", self.depth.clone()),
            ("aliased", self.variant.clone()),
            ("resolve", None),
            ("sharpen", self.sharpen.clone()),
            ("untonemap", self.tonemap.clone()),
        ]);
        stages
    }
}

/// The TRAA filter with its history.
#[derive(Debug)]
pub struct Traa {
    params: Params,
    hist: TemporalState,
}

impl Traa {
    /// History planes (of one value per pixel each): RGB, and Sobel and depth when improved.
    fn history_planes(p: &Params) -> usize {
        match p.variant {
            Variant::Baseline => 3,
            Variant::Improved => 5,
        }
    }

    /// The empty history of a filter with parameters `p`: texels [r, g, b] or [r, g, b,
    /// sobel] (one fetch per tap of the history), and depth / far in a plane of its own (it
    /// is only written on frames with depth). The GPU filter saves and loads its device
    /// state through the same layout, so states move between backends.
    pub fn history(p: &Params) -> TemporalState {
        let (layout, conversion): (&[usize], Conversion) = match p.variant {
            Variant::Baseline => (&[3], Conversion::Custom(convert_rgb_texels::<3>)),
            Variant::Improved => (&[4, 1], Conversion::Custom(convert_rgb_texels::<4>)),
        };
        TemporalState::with_components(layout, conversion)
    }

    /// Moves the history `planes` (of [`Traa::history`]'s layout for `p`) between linear
    /// and tonemapped working space, as the filter does when a stream switches between LDR
    /// and HDR frames.
    pub fn convert_history(p: &Params, planes: &mut [Plane<f32>], to_tonemapped: bool) {
        match p.variant {
            Variant::Baseline => convert_rgb_texels::<3>(planes, to_tonemapped),
            Variant::Improved => convert_rgb_texels::<4>(planes, to_tonemapped),
        }
    }

    /// What depth is divided by for the linear depth of eq. 4.4-4.6 and 4.9: the far plane
    /// of the frame's `near_far`, else the largest of its `depth`.
    pub fn depth_far(near_far: Option<[f32; 2]>, depth: &[f32]) -> f32 {
        kernel::far(near_far, depth)
    }

    /// Sharpen strength of the variant: eq. 3.1 or eq. 4.17.
    pub fn sharpen_strength(p: &Params) -> f32 {
        match p.variant {
            Variant::Baseline => SHARPEN_BASELINE,
            Variant::Improved => SHARPEN_IMPROVED,
        }
    }
}

impl FilterKind for Traa {
    const NAME: &'static str = "traa";
    const SUMMARY: &'static str =
        "the thesis's TRAA: INSIDE / Uncharted 4 baseline, or improved with Sobel history, object ids and depth pseudo-variance";
    temporal_stages! {
        "tonemap", "dilate", "reproject", "sobel", "sobel_history", "model_average", "depth_variance",
        "aliased", "resolve", "sharpen", "untonemap"
    }
    type Params = Params;
    fn uses() -> ChannelSet {
        ChannelSet::of(&[
            ChannelKind::Color,
            ChannelKind::Motion,
            ChannelKind::Depth,
            ChannelKind::Albedo,
            ChannelKind::ObjectId,
        ])
    }
    fn state_bytes_per_pixel(p: &Params) -> usize {
        2 * 4 * Self::history_planes(p)
    }
    fn new(params: Params) -> Self {
        Traa {
            hist: Traa::history(&params),
            params,
        }
    }
}

/// Converts a history whose first plane holds texels of `N` channels, RGB first, between
/// linear and tonemapped working space (as the planar conversion of RGB history does; the
/// other channels stay as they are).
fn convert_rgb_texels<const N: usize>(planes: &mut [Plane<f32>], to_tonemapped: bool) {
    let w = planes[0].width();
    for_rows([planes[0].data_mut()], w, |_, [row]| {
        for t in row.chunks_exact_mut(N) {
            let rgb = [t[0], t[1], t[2]];
            let c = if to_tonemapped {
                tonemap(rgb)
            } else {
                tonemap_inverse(rgb)
            };
            t[..3].copy_from_slice(&c);
        }
    });
}

/// INSIDE's feedback: the history weight from the difference of two lumas.
#[cfg(test)]
#[inline(always)]
fn feedback(l0: f32, l1: f32, min: f32, max: f32) -> f32 {
    let diff = (l0 - l1).abs() / l0.max(l1).max(FEEDBACK_LUMA_FLOOR);
    let w = (1.0 - diff).max(0.0);
    min + (max - min) * w * w
}

#[cfg(test)]
#[inline(always)]
fn mix(x: f32, y: f32, t: f32) -> f32 {
    x * (1.0 - t) + y * t
}

/// [`feedback`] of eight pixels, lane by lane (the same operations, so the same bits).
#[inline(always)]
fn feedback_v(l0: f32x8, l1: f32x8, min: f32, max: f32) -> f32x8 {
    let floor = f32x8::splat(FEEDBACK_LUMA_FLOOR);
    let diff = (l0 - l1).abs() / lanes::max_of(lanes::max_of(l0, l1), floor);
    let w = lanes::max_of(f32x8::splat(1.0) - diff, f32x8::splat(0.0));
    f32x8::splat(min) + f32x8::splat(max - min) * w * w
}

/// [`mix`] of eight pixels, lane by lane.
#[inline(always)]
fn mix_v(x: f32x8, y: f32x8, t: f32x8) -> f32x8 {
    x * (f32x8::splat(1.0) - t) + y * t
}

history_filter!(Traa, |p, frame, ctx| kernel::frame(p, frame.meta.near_far, ctx));

#[cfg(test)]
mod tests {
    use super::reference::ReferenceTraa;
    use super::*;
    use crate::filters::check::prelude::*;
    use crate::filters::check::{assert_filter_matches, sequences, with_gbuffer, GBUFFER_KINDS, ODD_SIZES};
    use crate::pipeline::params::{build, parse_assignments};
    use crate::rng::SplitMix64;

    /// The fused kernel gives the reference's output, bit for bit, for both variants and
    /// every option, with each optional channel missing in turn, on every kind of
    /// sequence, at odd sizes.
    #[test]
    fn fused_kernel_matches_the_reference() {
        let params: &[&[&str]] = &[
            &["variant=baseline"],
            &["variant=baseline", "sharpen=false", "feedback_min=0.5"],
            &[],
            &["sharpen=false"],
            &["feedback_min=0.2", "feedback_max=0.99"],
        ];
        let channels = GBUFFER_KINDS;
        let sizes = ODD_SIZES.iter().copied().chain([(64, 36)]);
        for (w, h) in sizes {
            let mut rng = SplitMix64::new((w * 7 + h) as u64);
            for (name, frames) in sequences(w, h, 6, (w * 31 + h) as u64) {
                for set in params {
                    let p: Params = build("traa", &parse_assignments(set).unwrap()).unwrap();
                    // Baseline reads neither albedo nor object ids.
                    let kinds = if p.variant == Variant::Baseline {
                        &channels[..1]
                    } else {
                        &channels[..]
                    };
                    for kind in kinds {
                        let frames: Vec<Frame> =
                            frames.iter().map(|f| with_gbuffer(f, &mut rng, kind)).collect();
                        let mut slow = ReferenceTraa::new(p.clone());
                        assert_filter_matches(
                            &mut Traa::new(p.clone()),
                            |f| slow.process(f).unwrap(),
                            &frames,
                            &format!("{w}x{h} {name} {kind} {set:?}"),
                        );
                    }
                }
            }
        }
    }
}
