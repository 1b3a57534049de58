//! `phlm`: Pixel History Linear Models (Iglesias-Guitian, Moon, Koniaris, Smolikowski and
//! Mitchell 2016), with an RLS that stays bounded forever ([`rls`]).
//!
//! Every pixel keeps a linear model `f = beta^T x` with `x = [1, z_r, z_g, z_b]` (eq. 3-4):
//! `beta` is 3x4 (a row per colour channel) and one 4x4 inverse covariance `P` is shared by
//! the three rows (sec. 6: "the final dimension d ... is 4"). `z` is a temporal feature, a
//! smoothed and temporally accumulated copy of the input (sec. 5.1, [`feature`]).
//!
//! Stages per frame:
//! 1. `repair`: non-finite and negative input replaced and counted (never enters state).
//! 2. `tonemap`: the reversible tonemap `c / (1 + max c)` (HDR input only): one firefly of
//!    1e5 is then a bounded sample instead of a value that dominates the regression.
//! 3. `ycocg`: the input in YCoCg, where the neighbourhood box and the luma range live.
//! 4. `dilate`: velocity dilation (with depth, `dilation` on): each pixel takes the motion
//!    of the nearest pixel of its 3x3, as `taa` does, so the pixels beside a thin moving
//!    edge fetch the edge's models.
//! 5. `reproject`: each pixel's previous position `p + motion`; off screen -> the model is
//!    reset to the input (Algorithm 1 lines 7-9). Left out when nothing moves (the static
//!    case of sec. 5.2: `pi(v)` is the identity and state is read in place).
//! 6. `feature`: the temporal feature (sec. 5.1), fetched at the previous position.
//! 7. `model`: Algorithm 1 lines 11-22: fetch beta and P, predict, test against the 3x3 box,
//!    clip toward the input and reset on a failure that persists ([`strikes`], [`miss`],
//!    [`jump`]), RLS update (eq. 5-7 with regularized forgetting in information form,
//!    bounded forever: see [`rls`]), output `beta^T x`.
//! 8. `untonemap` (HDR input only).
//!
//! State: beta (12), the information matrix R = P^-1 (10, packed symmetric), z (3), the
//! count of failed box tests (1), and the speed and depth of the frame that wrote it (2)
//! = [`STATE_PLANES`] float planes, double-buffered.
//!
//! Choices where the paper is open (each cited where it is made; `variant = paper` puts
//! back the paper's own settings, [`Variant`]):
//! - the model fetch: the paper's is bilinear ("our linear models are stored in GPU texture
//!   memory, and thus we can exploit texture cache and hardware bilinear interpolation",
//!   sec. 6). Our default reads the model's coefficients `beta` with Catmull-Rom (sharper
//!   under sub-pixel motion, as `taa`'s history) and its information `R` and the feature
//!   bilinearly ([`ModelFetch::CatmullRom`]); `model_fetch = nearest` is the cheapest. A
//!   convex blend of positive-definite matrices is positive definite (and of matrices
//!   `>= R0` is `>= R0`), so bilinear R stays valid and the bound `P <= p0 I` holds;
//!   Catmull-Rom's negative lobes would not keep R definite, which is why R stays
//!   bilinear. We blend the information `R = P^-1` (what we store) where the paper's
//!   texture fetch blends P: blending R pools the neighbours' evidence, and both are
//!   convex blends of SPD matrices.
//! - velocity dilation (`dilation`, our addition from `taa`; the paper reprojects with
//!   each pixel's own motion).
//! - the hull test runs in YCoCg ("the convex hull in a given colorspace (e.g. RGB or
//!   YCgCo)", sec. 5.2): the same 3x3 pass then gives the luma range the feature needs; the
//!   clip follows the paper's ray from the prediction toward the input (lines 14-17).
//! - the forgetting factor falls with the pixel's speed (`lambda_moving`, our choice,
//!   measured: [`DEFAULT_LAMBDA_MOVING`]): the paper's `lambda = 0.998` for still pixels,
//!   0.8 from 1 px/frame; `lambda_moving = 0` gives the paper's single `lambda`.
//! - the model after a clip is reset to the clipped colour ("resetting a linear model with a
//!   specific color value", sec. 5.2), its information relaxed halfway toward `I / clip_p`
//!   (`clip_keep = 0.5`, [`DEFAULT_CLIP_KEEP`]; the paper's reset is all the way, with the
//!   init value 1000, we default `clip_p` to 1: [`DEFAULT_CLIP_P`] has the measurements).
//! - `p0 = 100` where the paper initialises with 1000 ([`DEFAULT_P0`]).
//! - a failed box test clips only when it persists: three failures in a row
//!   (`clip_after = 1.75`, [`DEFAULT_CLIP_AFTER`]); before that it only relaxes the model's
//!   information (`fail_keep = 0.25`, [`DEFAULT_FAIL_KEEP`]) and the RLS update pulls it
//!   toward the input. The paper clips at every failure (lines 12-19). With jittered input
//!   one frame's 3x3 box misses what a still pixel has rightly converged to (sub-pixel
//!   detail this frame's samples missed); clipping it there threw away what the model had
//!   averaged (docs/phlm-ablations.md, table 12).
//! - a failure counts, and relaxes, as much as the prediction missed the box by
//!   (`fail_ramp`, [`DEFAULT_FAIL_RAMP`], [`miss`]), so that a miss by a rounding moves
//!   both by a rounding and the GPU follows the CPU; and twice where the pixel's speed
//!   changed since its history was written (`speed_jump`, [`DEFAULT_SPEED_JUMP`],
//!   [`jump`]), so that a surface that left the pixel (a fast thin spoke) is clipped at
//!   once rather than after three frames (docs/phlm-ablations.md, table 13); and twice
//!   where the depth stored with the history lies outside this frame's 3x3 depth range
//!   (`depth_jump`, [`DEFAULT_DEPTH_JUMP`], [`depth_share`]): a disocclusion behind a thin
//!   post, where post and background move alike and the speed does not tell them apart.

pub mod feature;
mod kernel;
// The scalar statement the fused kernel is tested against (a naive oracle, tests only).
#[cfg(test)]
mod reference;
pub mod rls;

use super::passes::{Conversion, FrameResult, TemporalState};
use super::reconstruct::PixelFilter;
use crate::filter_params;
use crate::filters::passes::{history_filter, temporal_stages};
use crate::frame::{ChannelKind, ChannelSet, Plane};
use crate::kernels::tonemap;
#[cfg(test)]
use crate::kernels::{bilinear, catmull_rom};
use crate::pipeline::exec::for_rows;
use crate::pipeline::{FilterKind, ModelHealth, ParamKind, PixelCounts, StateError};
use rls::{D, P_LEN};
use serde::{Deserialize, Serialize};
use std::ops::AddAssign;

/// How the model state is read at a reprojected position.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ModelFetch {
    /// Bilinear blend of the four nearest models (the paper's texture fetch, sec. 6).
    Bilinear,
    /// The nearest model (4x fewer reads; blocky under sub-pixel motion).
    Nearest,
    /// `beta` by Catmull-Rom ([`crate::kernels::catmull_rom`]: 12 taps, sharp under
    /// sub-pixel motion, can overshoot, which the box test then clips), `R` and `z`
    /// bilinear (`R` must stay a convex blend to stay positive definite).
    CatmullRom,
}

/// Which settings `phlm` runs with.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Variant {
    /// The parameters as given (defaults: our measured choices, docs/phlm-ablations.md).
    Tuned,
    /// Iglesias-Guitian et al. 2016's own settings where we depart from them: one
    /// `lambda` for every pixel (`lambda_moving = 0`), no velocity dilation, bilinear model
    /// fetch, `p0 = clip_p = 1000`, and a hard reset on clip (`clip_keep = 0`) at every
    /// failed box test, however far out and whatever the pixel's speed or depth did
    /// (`clip_after = 1`, `fail_ramp = fail_ramp_box = 0`, `speed_jump = depth_jump = 0`)
    /// on each pixel's own sample (`pixel_filter = box`); these twelve parameters are then
    /// overridden ([`Params::effective`]).
    Paper,
}

/// The box a prediction is tested against (Algorithm 1 lines 13-16).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum TestBox {
    /// The 3x3 min/max box (the paper's AABB of the neighbourhood, sec. 5.2).
    Minmax,
    /// The variance box `mean +- test_gamma sigma` within the min/max box (Salvi 2016, as
    /// `taa` builds it): tighter, so more predictions are clipped.
    Variance,
}

/// What a prediction outside the box does to its model (Algorithm 1 line 18).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum OnClip {
    /// Reset the model to the clipped colour: intercept = colour, slopes 0 (the paper,
    /// sec. 5.2 and 6).
    Reset,
    /// Shift the intercept so the model predicts the clipped colour, keeping its slopes
    /// (our ablation: the model's fit to the feature survives the clip).
    Shift,
}

filter_params! {
    /// Parameters of `phlm`.
    pub struct Params {
        /// RLS forgetting factor (paper: 0.998, memory ~1/(1-lambda) = 500 frames). Higher: more
        /// supersampling on still content, slower to follow slow shading changes; lower: follows changes,
        /// keeps more flicker
        lambda: f32 = DEFAULT_LAMBDA, ParamKind::Float { min: 0.5, max: 0.99999 };
        /// tuned (the parameters as given; defaults measured on the Blender corpus and the scene catalogue)
        /// or paper (Iglesias-Guitian et al. 2016's settings: overrides lambda_moving = 0, dilation = false,
        /// model_fetch = bilinear, p0 = clip_p = 1000, clip_keep = 0, clip_after = 1, fail_ramp =
        /// fail_ramp_box = 0, speed_jump = depth_jump = 0, pixel_filter = box)
        variant: Variant = Variant::Tuned, ParamKind::Choice { options: &["tuned", "paper"] };
        /// diagonal of P at initialisation and off-screen reset (default 100; paper: 1000). High: a new model
        /// follows the input at once; low: it trusts its initial value
        p0: f32 = DEFAULT_P0, ParamKind::Float { min: 1e-3, max: 1e6 };
        /// diagonal of P after a clip reset (default 1; paper: 1000 like p0, the model restarts from the
        /// input and the pixel shows its raw input). Lower keeps the clipped colour longer: less flicker on
        /// thin features, more lag
        clip_p: f32 = DEFAULT_CLIP_P, ParamKind::Float { min: 1e-3, max: 1e6 };
        /// feature convergence phi = a l^2 + b v l^3 (paper: a = 0.125): how fast the feature catches up when
        /// its luma leaves the neighbourhood range
        feature_a: f32 = feature::DEFAULT_A, ParamKind::Float { min: 0.0, max: 100.0 };
        /// feature convergence, motion term (paper: b = 0.25): faster catch-up for moving pixels
        feature_b: f32 = feature::DEFAULT_B, ParamKind::Float { min: 0.0, max: 100.0 };
        /// smallest weight of the current low-pass sample in the feature (our choice, 0.08 = a 12-frame
        /// memory): lower gives a smoother feature that lags more (a change of shading with no motion shows
        /// later)
        feature_alpha_min: f32 = feature::DEFAULT_ALPHA_MIN, ParamKind::Float { min: 0.001, max: 1.0 };
        /// reprojected model read: catmull_rom (beta by Catmull-Rom, R and the feature bilinear: sharp under
        /// motion, 12 taps), bilinear (paper's texture fetch, smooth, blurs moving detail) or nearest (4x
        /// fewer reads, blocky)
        model_fetch: ModelFetch = ModelFetch::CatmullRom, ParamKind::Choice { options: &["catmull_rom", "bilinear", "nearest"] };
        /// take the motion of the nearest pixel of the 3x3 (needs depth; as taa): pixels beside a thin moving
        /// edge follow the edge's models (off: the paper's own motion per pixel)
        dilation: bool = true, ParamKind::Bool;
        /// forgetting factor of moving pixels (default 0.8; 0 = off: the paper's lambda everywhere): lambda
        /// falls linearly with the pixel's speed from lambda (still) to lambda_moving (at lambda_speed
        /// px/frame and faster). Still content keeps the long memory that supersamples it, moving content
        /// follows its changes (0.8 from the lambda sweep of docs/phlm-ablations.md, table 4)
        lambda_moving: f32 = DEFAULT_LAMBDA_MOVING, ParamKind::Float { min: 0.0, max: 0.99999 };
        /// speed (px/frame) at which the forgetting factor reaches lambda_moving (lambda_moving > 0 only;
        /// default 0.25): lower treats slow motion as moving (follows a slow dolly or a moving object sooner,
        /// keeps a little more flicker), higher keeps the still pixels' long memory for slow motion too
        lambda_speed: f32 = DEFAULT_LAMBDA_SPEED, ParamKind::Float { min: 0.01, max: 100.0 };
        /// box the prediction is tested against: minmax (paper's 3x3 AABB) or variance (mean +- test_gamma
        /// sigma within it, as taa): tighter catches more ghosting and jitter-driven drift, but clips (and
        /// resets) more models, which shows more raw input
        test_box: TestBox = TestBox::Minmax, ParamKind::Choice { options: &["minmax", "variance"] };
        /// half-width in sigmas of the variance test box (test_box = variance only; taa's 1.0): lower clips
        /// more, higher approaches the min/max box
        test_gamma: f32 = DEFAULT_TEST_GAMMA, ParamKind::Float { min: 0.25, max: 4.0 };
        /// what a clipped prediction does to its model: reset (paper: intercept = clipped colour, slopes 0)
        /// or shift (the intercept moves so the model predicts the clipped colour, slopes kept)
        on_clip: OnClip = OnClip::Reset, ParamKind::Choice { options: &["reset", "shift"] };
        /// how persistent a failed box test must be before it clips the model: each pixel counts s = s_prev /
        /// 2 + 1 in a frame whose prediction left the box (s_prev / 2 otherwise; a miss by less than
        /// fail_ramp adds less, one where the speed jumped up to 2: speed_jump), and a failure clips and
        /// resets only when s >= clip_after (default 1.75: three frames in a row; 1.875: four; 1.5: two; 1 or
        /// less: every failure, the paper; 2: only after 24 in a row, where f32 rounds the count to 2).
        /// Higher: detail that one jittered frame's 3x3 box misses keeps its accumulated model (still content
        /// converges); a real change shows its old colour longer (fail_keep makes the model follow it
        /// meanwhile)
        clip_after: f32 = DEFAULT_CLIP_AFTER, ParamKind::Float { min: 0.0, max: 2.0 };
        /// confidence kept by a model whose prediction left the box without clipping yet (clip_after > 1): R
        /// = fail_keep R + (1 - fail_keep) I / clip_p, beta kept (default 0.25; 1 = untouched). Lower: the
        /// RLS update follows a real change at once; higher: still detail keeps more of what it accumulated
        fail_keep: f32 = DEFAULT_FAIL_KEEP, ParamKind::Float { min: 0.0, max: 1.0 };
        /// how far outside its box (the largest YCoCg channel of the working space) a prediction must be to
        /// count as a whole failure: a miss by d adds h = min(1, d / fail_ramp) to the count of clip_after
        /// and relaxes R with 1 - h (1 - fail_keep) (default 0.002; 0: every miss counts whole, the paper).
        /// Higher: misses by a sliver hardly count (still detail keeps its model, and the GPU and CPU agree
        /// at the box's edge); a slow real change (a moving light) is followed later
        fail_ramp: f32 = DEFAULT_FAIL_RAMP, ParamKind::Float { min: 0.0, max: 1.0 };
        /// the ramp of a miss grows with the box: a miss counts whole from max(fail_ramp, fail_ramp_box * the
        /// box's extent) on (the largest YCoCg channel of its max - min). Where the 3x3 is noisy (a path
        /// tracer's 1 spp) or jittered detail spans it, a converged model's misses are small against the box
        /// and hardly count; where it is flat, a small real change (a moving light) counts at once (0: the
        /// fixed fail_ramp alone)
        fail_ramp_box: f32 = DEFAULT_FAIL_RAMP_BOX, ParamKind::Float { min: 0.0, max: 4.0 };
        /// change of a pixel's speed (px/frame) at which a failed box test counts twice, so that it clips at
        /// once: a miss counts 1 + min(1, |v - v_prev| / speed_jump) times, v_prev the speed stored with the
        /// fetched history (default 1; 0: off). Lower: a surface that leaves a pixel (a spoke passing, a
        /// disocclusion) is cut sooner; higher: still content under a moving neighbour keeps its model
        speed_jump: f32 = DEFAULT_SPEED_JUMP, ParamKind::Float { min: 0.0, max: 1000.0 };
        /// how far outside this frame's 3x3 depth range (relative to the depth) the depth stored with the
        /// fetched history must lie for a failed box test to count twice, so that it clips at once: a miss
        /// counts 1 + min(1, d / depth_jump) times, d = (lo - d_prev) / d_prev below the range, (d_prev - hi)
        /// / hi above it (default 0.25; 0: off; needs depth). Lower: a background uncovered behind a thin
        /// post sheds the post's colour sooner; higher: only clear disocclusions count
        depth_jump: f32 = DEFAULT_DEPTH_JUMP, ParamKind::Float { min: 0.0, max: 100.0 };
        /// confidence kept by a clipped model: R = clip_keep R + (1 - clip_keep) I / clip_p (default 0.5; 0 =
        /// the paper's hard reset of P to clip_p I; 1 = keep R). Higher: a clip disturbs less (less flicker),
        /// the model follows the new input more slowly (more lag)
        clip_keep: f32 = DEFAULT_CLIP_KEEP, ParamKind::Float { min: 0.0, max: 1.0 };
        ..reconstruct
    }
}

impl Params {
    /// The settings a frame runs with: these parameters, or with `variant = paper` the
    /// paper's values of the twelve it overrides ([`Variant::Paper`]).
    pub fn effective(&self) -> Params {
        match self.variant {
            Variant::Tuned => self.clone(),
            Variant::Paper => Params {
                lambda_moving: 0.0,
                dilation: false,
                model_fetch: ModelFetch::Bilinear,
                p0: PAPER_P0,
                clip_p: PAPER_P0,
                clip_keep: 0.0,
                clip_after: PAPER_CLIP_AFTER,
                fail_ramp: 0.0,
                fail_ramp_box: 0.0,
                // Algorithm 1 regresses on each pixel's own sample.
                pixel_filter: PixelFilter::Box,
                // No effect on the output once every whole failure clips; set so that the
                // count in the state is the paper's too.
                speed_jump: 0.0,
                depth_jump: 0.0,
                ..self.clone()
            },
        }
    }
}

/// RLS forgetting factor `lambda = 0.998` (Iglesias-Guitian et al. 2016, sec. 4 after eq. 6: "we used lambda = 0.998
/// as widely used in real-time tracking systems").
pub const DEFAULT_LAMBDA: f32 = 0.998;
/// Initial diagonal of P in the paper (Iglesias-Guitian et al. 2016, sec. 6: "initialized with a relatively high value, e.g. 1000"),
/// also its P after a clip; `variant = paper` uses it for both.
pub const PAPER_P0: f32 = 1000.0;

/// Initial diagonal of P: 100 (our choice, measured). A new model still fits the input at
/// once (P >> 1), and the prior `R0 = I / p0` that forgetting relaxes toward is 10x
/// stronger than the paper's, which steadies models on still, jittered content. On the
/// 10-scene catalogue (128x72, 32 frames, with dilation, Catmull-Rom fetch and
/// `clip_keep = 0.5`): p0 = 10 / 100 / 1000 give 30.34 / 30.34 / 30.24 dB mean PSNR and
/// tRMSE 0.0332 / 0.0335 / 0.0344 (docs/phlm-ablations.md, table 10).
pub const DEFAULT_P0: f32 = 100.0;

/// Confidence a clipped model keeps, 0.5 (our choice, measured; the paper resets P, 0).
/// With the defaults of table 10 of docs/phlm-ablations.md (catalogue means, 128x72):
/// 0.25 / 0.5 / 0.75 give 30.40 / 30.34 / 30.21 dB and tRMSE 0.0344 / 0.0335 / 0.0331;
/// 0 gives 30.25 dB / 0.0366 (dilation and Catmull-Rom alone). A hard reset shows the
/// clipped pixel's raw input for a frame, which is most of phlm's flicker.
pub const DEFAULT_CLIP_KEEP: f32 = 0.5;

/// Diagonal of P after a clip reset: 1 (our choice, measured). The paper resets a clipped
/// model like a new one (P = 1000 I, sec. 5.2 and 6), so the next update fits the input
/// almost exactly and a clipped pixel shows its raw, aliased input; with P = I the update
/// moves about half way to the input. On our 10-scene catalogue (128x72, 32 frames) this
/// raises mean PSNR from 27.72 to 29.34 dB and lowers tRMSE from 0.0596 to 0.0450 (with
/// `feature_alpha_min = 0.03`); `clip_p = 1000` gives the paper's behaviour.
pub const DEFAULT_CLIP_P: f32 = 1.0;

/// Half-width of the variance test box in sigmas: 1.0, `taa`'s (Salvi 2016; Yang, Liu and
/// Salvi 2020 give 0.75-1.25).
pub const DEFAULT_TEST_GAMMA: f32 = 1.0;

/// The count a failed box test must reach to clip the model: 1.75, three failures in a row
/// (our choice, measured; see [`strikes`]). The paper clips at every failure
/// ([`PAPER_CLIP_AFTER`], Algorithm 1 lines 12-19). With jittered input the 3x3 box of one
/// frame can miss a value the pixel's model has rightly converged to (a sub-pixel pole or
/// texture detail that this frame's samples missed); a clip then resets what the model had
/// accumulated. Chosen with [`DEFAULT_FAIL_KEEP`] on the mean over the 10-scene catalogue
/// (128x72, 32 frames), among the pairs that keep the GPU backend within its bounds of the
/// CPU: `clip_after` 1 / 1.5 / 1.75 / 1.875 with `fail_keep = 0.25` give 30.34 (the
/// paper's clip) / 30.68 / 30.74 / 30.76 dB, tRMSE 0.0335 / 0.0338 / 0.0331 / 0.0328, the
/// worst scene against `taa` -0.09 / +0.18 / +0.18 / +0.16 dB; 1.875 is within what
/// another catalogue would move and waits a frame longer on a real change. In the report's
/// run (256x144) this pair alone left spokes 0.62 dB below `taa` (docs/phlm-ablations.md,
/// table 12); a failure where the pixel's speed changed now clips at once
/// ([`DEFAULT_SPEED_JUMP`]), and spokes is 2.10 dB above it (table 13).
pub const DEFAULT_CLIP_AFTER: f32 = 1.75;
/// Confidence a failed box test leaves a model that it does not clip yet: 0.25 (our
/// choice, measured). The relax of a clip ([`DEFAULT_CLIP_KEEP`]) without the reset of
/// beta: the next RLS update moves the model most of the way to the input, so a real
/// change (a moving light, a spoke passing) is followed while the clip waits, and a still
/// pixel keeps its converged colour as the starting point. At 128x72 with `clip_after =
/// 1.75`: 0 / 0.1 / 0.15 / 0.25 / 0.35 / 0.5 / 1 give 30.64 / 30.72 / 30.73 / 30.74 /
/// 30.72 / 30.67 / 30.42 dB. Lower values follow a passing spoke better (in the report's
/// run spokes was -0.62 dB against `taa` at 0.25, -0.20 at 0.15, before
/// [`DEFAULT_SPEED_JUMP`]), but at 0.15 and 0.1 the GPU's f32 solve left its bounds of the
/// CPU's f64 one (docs/phlm-ablations.md, table 12, before the ramp of [`miss`]).
pub const DEFAULT_FAIL_KEEP: f32 = 0.25;
/// `clip_after` of the paper: every failed box test clips (Algorithm 1 lines 12-19).
pub const PAPER_CLIP_AFTER: f32 = 1.0;
/// How far outside its box a prediction must be to count as a whole failure ([`miss`]):
/// 0.002 of the working space's range, about half an 8-bit code value (our
/// choice, measured; 0 is the paper's all-or-nothing test). Chosen for the GPU, not for
/// the image: with whole misses a prediction on the box's edge fails on one backend only
/// (f32 against f64, or f16 colour), and the count and relax it starts moved one pixel of
/// `camera-cut` 0.058 apart on lavapipe. The catalogue's means hardly move with it (128x72:
/// 0 / 0.001 / 0.002 / 0.005 give 30.85 / 30.86 / 30.86 / 30.87 dB; 256x144: 33.23 /
/// 33.24 / 33.23 / 33.21), but larger ramps let a smooth change lag (`dynamic-light` at
/// 256x144: -0.04 / -0.07 / -0.10 / -0.20 dB against `taa`), and 0.0005 left a GPU
/// variant's HDR pixel 0.02 from the CPU's (docs/phlm-ablations.md, table 13).
pub const DEFAULT_FAIL_RAMP: f32 = 0.002;
/// The share of the test box's extent from which a miss counts whole ([`ramp`]): 0.2
/// (our choice, measured on the Blender corpus). A real render's jittered 1-spp samples
/// make a converged prediction miss one frame's 3x3 box by a share of that box (a path
/// tracer's noise, sub-pixel detail the frame's samples missed); counted whole, three
/// such misses in a row clipped models that were right, most of what `phlm` lost to
/// `taa` on the corpus' path-traced `gi` (-0.69 dB, jitter known). A fixed ramp large
/// enough for that (0.03 to 0.05) let the catalogue's `dynamic-light`, a sun moving over a
/// flat, noiseless box, lag (-0.21 to -0.61 dB against `taa`); a ramp that grows with the
/// box counts such a change at once. On the corpus (jitter known / unknown, against
/// `taa`; docs/corpus.md, "phlm's defaults") 0 / 0.1 / 0.15 / 0.2 give the mean +0.97 /
/// +0.98 / +0.99 / +0.99 and +0.51 / +0.54 / +0.55 / +0.55 dB, the worst scene -0.69 /
/// -0.44 / -0.34 / -0.25 (`gi`) and -0.38 / -0.19 / -0.12 / -0.12; on the catalogue
/// (128x72, box references) +1.18 / +1.18 / +1.17 / +1.16 dB, no scene below `taa`, and
/// its noisy variants +1.04 / +1.01 / +0.98 / +0.96.
pub const DEFAULT_FAIL_RAMP_BOX: f32 = 0.2;
/// The change of speed at which a failed box test clips at once ([`jump`]): 1 px/frame
/// (our choice, measured on the catalogue's mean: `speed_jump` 0 (off) / 0.5 / 1 / 2
/// give 30.72 / 30.85 / 30.86 / 30.82 dB at 128x72 and 32.92 / 33.23 / 33.23 / 33.18 at
/// 256x144, where off leaves `spokes` 0.66 dB below `taa` and 1 puts it 2.10 above;
/// docs/phlm-ablations.md, table 13). A jittered still pixel's speed is 0 frame after
/// frame, so the count of [`strikes`] still waits there.
pub const DEFAULT_SPEED_JUMP: f32 = 1.0;
/// How far outside the 3x3 depth range a history's depth makes a failed box test clip at
/// once ([`depth_share`]): a quarter of the depth (our choice, measured on the Blender
/// corpus). Behind a thin post that the camera passes, the uncovered background fetches
/// the post's models; post and background move alike on screen, so [`jump`] does not cut
/// them, and the post's colour trailed one to three pixels behind it for the three frames
/// the count waits. The history's depth against the whole 3x3 range, not the pixel's own
/// depth, so that the depth a jittered sample hits at a silhouette or on a grazing floor
/// (which changes by more than half from frame to frame at the corpus' horizons) does not
/// count; and only at a moving pixel ([`DEPTH_JUMP_SPEED`]). On the corpus (docs/corpus.md,
/// "What each change gained") 0.25 and 0.5 score the same to 0.01 dB: `fence` +0.23 /
/// +0.25 dB (jitter known / unknown, 16 frames), `foliage` +0.19 / +0.19, no scene below
/// by more than 0.01; the catalogue's mean moves by -0.01.
pub const DEFAULT_DEPTH_JUMP: f32 = 0.25;
/// How a pixel's count of failed box tests decays per frame: it halves ([`strikes`]), so
/// `clip_after` 1.5 needs two failures in a row, 1.75 three and 1.875 four (our choice: a
/// failure three frames back still counts an eighth).
pub const STRIKE_DECAY: f32 = 0.5;

/// A pixel's count of failed box tests after this frame, and whether this frame's failure
/// clips: `s = STRIKE_DECAY s_prev + hit`, clipping when it failed (`hit > 0`) and
/// `s >= clip_after` (`s_prev` is fetched with the model's information, 0 without
/// history; `hit` is [`miss`]). With `clip_after <= 1` and `fail_ramp = 0` every failure
/// clips, as the paper. The fused kernel computes it in `f32x8` with the same operations.
#[cfg(test)]
#[inline(always)]
pub(crate) fn strikes(prev: f32, hit: f32, clip_after: f32) -> (f32, bool) {
    let s = STRIKE_DECAY * prev + hit;
    (s, hit > 0.0 && s >= clip_after)
}

/// How much of a failure a prediction's box test is, in [0, 1]: 0 inside the box, else
/// `min(1, d / ramp)` where `d` is how far the clip moves it (the largest YCoCg channel
/// of `pred - clipped`), and 1 with `ramp = 0`. A miss by a sliver counts a sliver toward
/// [`strikes`], so the count is continuous in the prediction: at the box's edge a rounding
/// moves it by a rounding (the GPU's f32 and the CPU's f64 solves, or f16 colour, then
/// agree), where a whole strike would start a clip on one backend alone frames later.
/// The fused kernel computes it in `f32x8` with the same operations.
#[cfg(test)]
#[inline(always)]
pub(crate) fn miss(pred: [f32; 3], clipped: [f32; 3], moved: bool, ramp: f32) -> f32 {
    if !moved {
        return 0.0;
    }
    if ramp == 0.0 {
        return 1.0;
    }
    let d = (pred[0] - clipped[0])
        .abs()
        .max((pred[1] - clipped[1]).abs())
        .max((pred[2] - clipped[2]).abs());
    (d / ramp).min(1.0)
}

/// The ramp of [`miss`] for a test box `lo..hi` (YCoCg):
/// `max(fail_ramp, fail_ramp_box * extent)`, the extent the largest channel of `hi - lo`. A converged model under a
/// noisy or jittered 3x3 misses by a share of the box; under a flat one a real change of
/// a few codes is all there is. The fused kernel and the GPU compute it with the same
/// operations.
#[cfg(test)]
#[inline(always)]
pub(crate) fn ramp(lo: [f32; 3], hi: [f32; 3], p: &Params) -> f32 {
    let extent = (hi[0] - lo[0]).max(hi[1] - lo[1]).max(hi[2] - lo[2]);
    p.fail_ramp.max(p.fail_ramp_box * extent)
}

/// How many times a failed box test counts where the pixel's speed changed: `1 +
/// min(1, |v - v_prev| / speed_jump)`, `v` this frame's speed (px/frame, of the dilated
/// motion) and `v_prev` the speed stored with the history it fetched; 1 with
/// `speed_jump = 0`. Where the speed jumps, the history is of another surface (a thin
/// spoke that moved on leaves a still background whose history is the spoke), and a miss
/// there clips at once (it counts 2 >= `clip_after`); where it does not (still content a
/// jitter phase missed), it waits. Continuous in both speeds, as [`miss`]. SMAA's
/// temporal resolve weighs its history down by the same difference of speeds (Jimenez et
/// al. 2012, `SMAAResolvePS`, which keeps each pixel's speed in the colour's alpha). The
/// fused kernel computes it in `f32x8` with the same operations.
#[cfg(test)]
#[inline(always)]
pub(crate) fn jump(v: f32, v_prev: f32, speed_jump: f32) -> f32 {
    if speed_jump == 0.0 {
        return 1.0;
    }
    1.0 + ((v - v_prev).abs() / speed_jump).min(1.0)
}

/// The depth a pixel's history keeps of depth `d`: `d` where it is a positive depth
/// (infinity as `f32::MAX`), else 0, which [`depth_share`] reads as unknown.
#[inline(always)]
pub(crate) fn history_depth(d: f32) -> f32 {
    if d > 0.0 {
        d.min(f32::MAX)
    } else {
        0.0
    }
}

/// How far, as a share in [0, 1], the depth `d_prev` stored with the fetched history lies
/// outside this frame's 3x3 depth range `lo..=hi` (each a [`history_depth`]): the
/// relative distance `(lo - d_prev) / d_prev` below it or `(d_prev - hi) / hi` above it,
/// over `depth_jump`, at most 1; 0 inside the range, with `depth_jump = 0`, and where
/// either depth is unknown (0); times `min(1, v / DEPTH_JUMP_SPEED)`, `v` this frame's
/// speed. A failed box test counts `1 + share` times where that is more than [`jump`].
/// The fused kernel computes it in `f32x8` with the same operations.
#[cfg(test)]
#[inline(always)]
pub(crate) fn depth_share(lo: f32, hi: f32, d_prev: f32, v: f32, depth_jump: f32) -> f32 {
    if depth_jump == 0.0 || d_prev <= 0.0 || hi <= 0.0 {
        return 0.0;
    }
    let below = (lo - d_prev) / d_prev;
    let above = (d_prev - hi) / hi;
    (below.max(above).max(0.0) / depth_jump).min(1.0) * (v / DEPTH_JUMP_SPEED).min(1.0)
}

/// The speed (px/frame) from which [`depth_share`] counts whole: 1, linear below. A
/// surface uncovers another only where something moves; at a still pixel the depth a
/// jittered sample hits changes with the jitter's phase (a sub-pixel wire that some phases
/// hit), which the count of [`strikes`] is there to wait out (on the catalogue's still
/// scenes an unweighted share cost `static` 0.37 dB and `thin-line` 0.31).
pub const DEPTH_JUMP_SPEED: f32 = 1.0;

/// The confidence a failure that does not clip leaves a model: `fail_keep` for a whole
/// miss or more (`hit >= 1`, [`miss`] times [`jump`]), 1 for none, linear in between
/// (`1 - min(hit, 1) (1 - fail_keep)`), so that the relax too is continuous at the box's
/// edge.
#[cfg(test)]
#[inline(always)]
pub(crate) fn fail_relax(hit: f32, fail_keep: f32) -> f32 {
    1.0 - hit.min(1.0) * (1.0 - fail_keep)
}

/// Forgetting factor of pixels moving [`Params::lambda_speed`] (1 px/frame) or faster: 0.8
/// (our choice, measured; 0 turns motion-dependent forgetting off, the paper's single
/// `lambda`). The paper's 500-frame memory supersamples still content but makes moving
/// models lag; a global `lambda = 0.8` helps the moving scenes and costs the still one
/// 1.4 dB (docs/phlm-ablations.md, table 4). From the speed, on the 10-scene catalogue
/// (128x72, 32 frames): mean PSNR 29.41 -> 29.71 dB, tRMSE 0.0415 -> 0.0405 (flyover
/// +1.66, fence +0.55, foliage +0.26, spokes +0.12 dB; static and dynamic-light unchanged;
/// no scene below today's by more than 0.02 dB); noisy variants 32.05 -> 32.16 dB.
pub const DEFAULT_LAMBDA_MOVING: f32 = 0.8;

/// The speed at which the forgetting factor reaches [`DEFAULT_LAMBDA_MOVING`]: 0.25 px/frame
/// (our choice, measured on the Blender corpus; 1 before). A slow dolly or an object
/// moving a quarter pixel a frame then forgets at the moving rate. Against `taa` at its
/// corpus blend weight (0.2), on the 48-frame corpus' mean with [`DEFAULT_DEPTH_JUMP`]: 1 /
/// 0.5 / 0.25 / 0.125 lead it by +0.58 / +0.73 / +0.86 / +0.89 dB with the jitter known
/// and +0.39 / +0.49 / +0.56 / +0.57 unknown; `foliage` trails it by 1.12 / 0.46 / 0.12 /
/// -0.05 dB (known); tRMSE 0.0347 / 0.0349 / 0.0350 / 0.0351 (measured before
/// [`DEPTH_JUMP_SPEED`], which moves 0.25's leads to +0.88 / +0.58; docs/corpus.md, "What
/// each change gained"). Below 0.25 the gain is within another corpus' noise and flicker
/// grows.
pub const DEFAULT_LAMBDA_SPEED: f32 = 0.25;

/// The forgetting factor of a pixel moving `v` pixels per frame: [`Params::lambda`], or
/// with motion-dependent forgetting (`lambda_moving > 0`) the blend
/// `lambda + (lambda_moving - lambda) min(v / lambda_speed, 1)` (our ablation: a global
/// `lambda` trades the still scenes against the moving ones, docs/phlm-ablations.md).
#[inline(always)]
pub(crate) fn forgetting(v: f32, p: &Params) -> f32 {
    if p.lambda_moving == 0.0 {
        p.lambda
    } else {
        p.lambda + (p.lambda_moving - p.lambda) * (v / p.lambda_speed).min(1.0)
    }
}

/// Number of state planes: beta (12), R = P^-1 (10), z (3), the count of failed box
/// tests (1, [`strikes`]), and the pixel's speed and depth when it was last updated (2,
/// [`jump`] and [`depth_share`]).
pub const STATE_PLANES: usize = 3 * D + P_LEN + 3 + 3;
/// First plane of beta (row-major: channel c, feature j at `BETA + c * D + j`).
pub(crate) const BETA: usize = 0;
/// First plane of the information matrix R = P^-1 (packed upper triangle).
pub(crate) const R: usize = 3 * D;
/// First plane of z.
pub(crate) const Z: usize = R + P_LEN;
/// The plane of the count of failed box tests ([`strikes`]).
pub(crate) const S: usize = Z + 3;
/// The plane of the pixel's speed (px/frame) in the frame that last updated it ([`jump`]).
pub(crate) const V: usize = S + 1;
/// The plane of the pixel's depth in the frame that last updated it ([`history_depth`]).
pub(crate) const DEPTH: usize = V + 1;

/// One pixel's model state.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Model {
    pub(crate) beta: [[f32; D]; 3],
    /// The information matrix `R = P^-1` (packed), see [`rls::update_information`]; read
    /// by the reference's update (the fused kernel updates the state planes in place).
    #[cfg_attr(not(test), allow(dead_code))]
    pub(crate) r: [f32; P_LEN],
    pub(crate) z: [f32; 3],
}

impl Model {
    /// Reset to colour `c` with `P = p0 I` (Iglesias-Guitian et al. 2016, sec. 6: intercept = colour, slopes 0).
    #[cfg(test)]
    #[inline(always)]
    pub(crate) fn reset(c: [f32; 3], z: [f32; 3], p0: f32) -> Model {
        Model {
            beta: c.map(|v| [v, 0.0, 0.0, 0.0]),
            r: rls::init_information(p0),
            z,
        }
    }

    /// The model held in state values `s` (beta and R at their plane offsets) with
    /// feature `z`.
    #[inline(always)]
    pub(crate) fn from_state(s: &[f32], z: [f32; 3]) -> Model {
        Model {
            beta: std::array::from_fn(|c| std::array::from_fn(|j| s[BETA + c * D + j])),
            r: std::array::from_fn(|k| s[R + k]),
            z,
        }
    }

    /// Algorithm 1 line 18 as `p` chooses: the model whose prediction `pred` left the box,
    /// after its prediction was clipped to `c` (RGB): reset to `c` or shifted to predict
    /// it ([`OnClip`]), its information `R` relaxed to `I / clip_p` ([`Params::clip_keep`]).
    #[cfg(test)]
    #[inline(always)]
    pub(crate) fn clip(&mut self, pred: [f32; 3], c: [f32; 3], p: &Params) {
        for ch in 0..3 {
            match p.on_clip {
                OnClip::Reset => self.beta[ch] = [c[ch], 0.0, 0.0, 0.0],
                OnClip::Shift => self.beta[ch][0] += c[ch] - pred[ch],
            }
        }
        self.relax(p.clip_keep, p.clip_p);
    }

    /// The information `R` relaxed toward `I / clip_p`, keeping `keep` of it (a clip keeps
    /// [`Params::clip_keep`], a failed box test that does not clip yet
    /// [`Params::fail_keep`]).
    #[cfg(test)]
    #[inline(always)]
    pub(crate) fn relax(&mut self, keep: f32, clip_p: f32) {
        let init = rls::init_information(clip_p);
        self.r = if keep == 0.0 {
            init
        } else {
            std::array::from_fn(|k| keep * self.r[k] + (1.0 - keep) * init[k])
        };
    }

    #[inline(always)]
    pub(crate) fn x(&self) -> [f32; D] {
        [1.0, self.z[0], self.z[1], self.z[2]]
    }
}

/// Where a pixel's history is.
#[cfg(test)]
#[derive(Clone, Copy, Debug)]
pub(crate) enum From {
    /// No history (first frame, reset) or off screen.
    Nothing,
    /// In place (nothing moves).
    Here(usize),
    /// At this previous position (pixel units).
    At(f32, f32),
}

/// Reads `N` state planes of a `w` x `h` image at `at` (zeros for [`From::Nothing`]).
#[cfg(test)]
#[inline(always)]
pub(crate) fn fetch<const N: usize>(
    planes: [&[f32]; N],
    w: usize,
    h: usize,
    at: From,
    how: ModelFetch,
) -> [f32; N] {
    match at {
        From::Nothing => [0.0; N],
        From::Here(i) => planes.map(|p| p[i]),
        From::At(x, y) => match how {
            // Catmull-Rom reads beta only ([`fetch_model`]); the rest is bilinear.
            ModelFetch::Bilinear | ModelFetch::CatmullRom => bilinear(planes, w, h, x, y),
            ModelFetch::Nearest => {
                let j = (y.max(0.0) as usize).min(h - 1) * w + (x.max(0.0) as usize).min(w - 1);
                planes.map(|p| p[j])
            }
        },
    }
}

/// [`fetch`] of the model planes (beta, then R): with [`ModelFetch::CatmullRom`] beta's
/// twelve planes are read by Catmull-Rom, R bilinearly.
#[cfg(test)]
#[inline(always)]
pub(crate) fn fetch_model(planes: [&[f32]; Z], w: usize, h: usize, at: From, how: ModelFetch) -> [f32; Z] {
    let mut s = fetch(planes, w, h, at, how);
    if let (ModelFetch::CatmullRom, From::At(x, y)) = (how, at) {
        let beta: [f32; 3 * D] = catmull_rom(std::array::from_fn(|c| planes[BETA + c]), w, h, x, y);
        s[BETA..BETA + 3 * D].copy_from_slice(&beta);
    }
    s
}

/// Per-row counters of the model pass (the kernel's and the reference's).
#[derive(Clone, Copy, Debug, Default)]
pub(crate) struct Counts {
    pub(crate) pixels: PixelCounts,
    pub(crate) offscreen: u64,
    pub(crate) repaired: u64,
    pub(crate) max_trace: f32,
}

impl AddAssign for Counts {
    fn add_assign(&mut self, o: Counts) {
        self.pixels += o.pixels;
        self.offscreen += o.offscreen;
        self.repaired += o.repaired;
        self.max_trace = self.max_trace.max(o.max_trace);
    }
}

impl Counts {
    /// The frame's result: the output `color` (one value per pixel of it counted here) and
    /// the models' health over the frame.
    pub(crate) fn result(self, color: crate::frame::Rgb) -> FrameResult {
        let (w, h) = color[0].size();
        let n = (w * h) as f64;
        FrameResult {
            color,
            pixels: self.pixels,
            model: Some(ModelHealth {
                reset_by_clip: self.pixels.history_clipped as f64 / n,
                reset_by_disocclusion: self.offscreen as f64 / n,
                max_trace_p: self.max_trace as f64,
                p_repaired: self.repaired,
            }),
        }
    }
}

/// The PHLM filter with its models.
#[derive(Debug)]
pub struct Phlm {
    params: Params,
    hist: TemporalState,
}

impl FilterKind for Phlm {
    const NAME: &'static str = "phlm";
    const SUMMARY: &'static str =
        "Pixel History Linear Models (Iglesias-Guitian et al. 2016): per-pixel RLS linear models over a temporal feature, box-clipped, with bounded (regularized) forgetting";
    temporal_stages! { "tonemap", "ycocg", "dilate", "reproject", "feature", "model", "untonemap" }
    type Params = Params;
    fn uses() -> ChannelSet {
        ChannelSet::of(&[ChannelKind::Color, ChannelKind::Motion, ChannelKind::Depth])
    }
    fn state_bytes_per_pixel(_: &Params) -> usize {
        2 * 4 * STATE_PLANES
    }
    fn new(params: Params) -> Self {
        Phlm {
            params,
            hist: Phlm::history(),
        }
    }
}

/// Moves the model state between linear and tonemapped working space (a stream that
/// switches between LDR and HDR frames): each model restarts from its own prediction
/// converted to the new space (slopes 0, P kept), the feature is converted, so the output
/// does not jump.
pub fn convert_state(planes: &mut [Plane<f32>], to_tonemapped: bool) {
    let w = planes[0].width();
    let rows: [&mut [f32]; STATE_PLANES] = {
        let mut it = planes.iter_mut();
        std::array::from_fn(|_| it.next().expect("state planes").data_mut())
    };
    for_rows(rows, w, |_, r| {
        for x in 0..w {
            let s: [f32; STATE_PLANES] = std::array::from_fn(|k| r[k][x]);
            let m = Model::from_state(&s, [s[Z], s[Z + 1], s[Z + 2]]);
            let f = rls::predict(&m.beta, &m.x()).map(|v| v.max(0.0));
            let conv = |c: [f32; 3]| {
                if to_tonemapped {
                    tonemap(c)
                } else {
                    crate::kernels::tonemap_inverse(c)
                }
            };
            let (f, z) = (conv(f), conv(m.z.map(|v| v.max(0.0))));
            for c in 0..3 {
                r[BETA + c * D][x] = f[c];
                for j in 1..D {
                    r[BETA + c * D + j][x] = 0.0;
                }
                r[Z + c][x] = z[c];
            }
        }
    });
}

/// Checks loaded state texels: what the filter writes is a non-negative colour z (below
/// 1 when tonemapped), an information matrix with a positive diagonal (it is positive
/// definite), and a non-negative strike count, speed and depth.
fn check_state_texels(planes: &[Plane<f32>], _: &[usize], tonemapped: bool) -> Result<(), StateError> {
    let Some(texels) = planes.first() else {
        return Ok(());
    };
    let w = texels.width() / STATE_PLANES;
    for (i, t) in texels.data().chunks_exact(STATE_PLANES).enumerate() {
        let bad = |what: &str, v: f32| {
            Err(StateError::Plane {
                plane: 0,
                message: format!(
                    "pixel ({}, {}): {what} is {v}, which the filter never writes",
                    i % w.max(1),
                    i / w.max(1)
                ),
            })
        };
        let top = if tonemapped { 1.0 } else { f32::MAX };
        if let Some(&z) = t[Z..Z + 3].iter().find(|&&z| !(0.0..=top).contains(&z)) {
            return bad("a history colour (z)", z);
        }
        for k in rls::DIAG {
            let d = t[R + k];
            if d <= 0.0 {
                return bad("a diagonal entry of the information matrix", d);
            }
        }
        if t[S] < 0.0 {
            return bad("the count of failed box tests", t[S]);
        }
        if t[V] < 0.0 {
            return bad("the speed", t[V]);
        }
        if t[DEPTH].is_nan() || t[DEPTH] < 0.0 {
            return bad("the depth", t[DEPTH]);
        }
    }
    Ok(())
}

/// [`convert_state`] for state kept as texels of [`STATE_PLANES`] floats.
fn convert_state_texels(planes: &mut [Plane<f32>], to_tonemapped: bool) {
    let mut rows = from_texels(&planes[0]);
    convert_state(&mut rows, to_tonemapped);
    planes[0] = to_texels(&rows);
}

/// The state's [`STATE_PLANES`] planes from its texel plane (a texel of them per pixel).
pub fn from_texels(texels: &Plane<f32>) -> Vec<Plane<f32>> {
    let w = texels.width() / STATE_PLANES;
    (0..STATE_PLANES)
        .map(|k| Plane::from_fn(w, texels.height(), |x, y| texels.get(x * STATE_PLANES + k, y)))
        .collect()
}

/// The state's texel plane from its [`STATE_PLANES`] planes ([`from_texels`] undone).
pub fn to_texels(planes: &[Plane<f32>]) -> Plane<f32> {
    let (w, h) = planes[0].size();
    Plane::from_fn(w * STATE_PLANES, h, |x, y| {
        planes[x % STATE_PLANES].get(x / STATE_PLANES, y)
    })
}

impl Phlm {
    /// The filter's state, empty: one texel of the [`STATE_PLANES`] state floats per pixel (a fetch reads
    /// a pixel's model at once), converted between linear and tonemapped working space by
    /// [`convert_state`]. The GPU backend saves and loads this same format.
    pub fn history() -> TemporalState {
        TemporalState::with_components(&[STATE_PLANES], Conversion::Custom(convert_state_texels))
            .checked_by(check_state_texels)
    }

    /// Every pixel's information matrix `R = P^-1` (packed upper triangle, see
    /// [`rls::SYM`]) after the last frame; empty before the first frame or after a reset.
    /// For health checks ([`rls::positive_definite`], [`rls::trace_of_inverse_packed`]).
    pub fn information_matrices(&self) -> Vec<[f32; P_LEN]> {
        let b = &self.hist.buffer;
        if !b.valid() {
            return Vec::new();
        }
        b.read()[0]
            .data()
            .chunks_exact(STATE_PLANES)
            .map(|t| std::array::from_fn(|k| t[R + k]))
            .collect()
    }
}

history_filter!(Phlm, effective, |p, frame, ctx| kernel::frame(p, ctx));

#[cfg(test)]
mod tests {
    use super::reference::ReferencePhlm;
    use super::*;
    use crate::filters::check::prelude::*;
    use crate::filters::check::{assert_filter_matches, assert_variants_match, sequences, ODD_SIZES};
    use crate::kernels::clip::guard;
    use crate::pipeline::params::{build, parse_assignments};
    use crate::tolerance::Tolerance;

    /// The fused kernel gives the reference's output and model health, bit for bit, with
    /// every option, on every kind of sequence, at odd sizes.
    #[test]
    fn fused_kernel_matches_the_reference() {
        let variants: &[&[&str]] = &[
            &[],
            &["model_fetch=nearest"],
            &["model_fetch=bilinear", "dilation=false"],
            &["variant=paper"],
            &[
                "lambda=0.9",
                "clip_p=1000",
                "feature_alpha_min=0.5",
                "clip_keep=0",
            ],
            &["p0=0.01"],
            &["test_box=variance"],
            &[
                "test_box=variance",
                "test_gamma=0.5",
                "on_clip=shift",
                "clip_keep=0.5",
            ],
            &["on_clip=shift", "clip_keep=1", "clip_p=1000"],
            &["lambda_moving=0.6", "lambda_speed=0.5"],
            &["lambda_moving=0"],
            &["clip_after=1"],
            &["clip_after=1", "fail_ramp=0", "fail_ramp_box=0"],
            &["clip_after=1.5", "fail_keep=0", "fail_ramp=0.3"],
            &["fail_ramp_box=1", "fail_ramp=0"],
            &["fail_ramp=1", "fail_keep=0.6"],
            &["speed_jump=0"],
            &["speed_jump=0.2", "fail_ramp=0.05", "model_fetch=nearest"],
            &["clip_after=2", "fail_keep=1", "model_fetch=nearest"],
            &["clip_after=1.25", "fail_keep=0.7", "model_fetch=bilinear"],
            &["depth_jump=0"],
            &["depth_jump=0.01", "speed_jump=0"],
            &["depth_jump=100", "model_fetch=nearest"],
        ];
        let sizes = ODD_SIZES.iter().copied().chain([(64, 36)]);
        for (w, h) in sizes {
            for (name, frames) in sequences(w, h, 6, (w * 37 + h) as u64) {
                assert_variants_match::<Phlm, ReferencePhlm>(variants, &frames, &format!("{w}x{h} {name}"));
            }
        }
    }

    fn run(set: &[&str], frames: &[Frame]) -> Vec<Output> {
        let params: Params = build("phlm", &parse_assignments(set).unwrap()).unwrap();
        let mut f = Phlm::new(params);
        frames.iter().map(|fr| f.process(fr).unwrap()).collect()
    }

    /// [`run`] on each pixel's own sample (`pixel_filter=box`): the flat frames' colour
    /// comes out exactly, where the reconstruction's normalised weights round it by an ulp.
    fn run_own_samples(set: &[&str], frames: &[Frame]) -> Vec<Output> {
        let set: Vec<&str> = set.iter().copied().chain(["pixel_filter=box"]).collect();
        run(&set, frames)
    }

    /// The variance box lies inside the min/max box: from the same models (frame 1 follows
    /// the same first frame) it clips more predictions.
    #[test]
    fn the_variance_test_box_clips_more() {
        for (name, frames) in sequences(33, 19, 3, 21) {
            if !matches!(name, "still" | "random motion") {
                continue;
            }
            // Every failure clips (`clip_after = 1`, whole misses), so frame 1 counts them.
            let clipped = |set: &[&str]| {
                let set: Vec<&str> = set
                    .iter()
                    .copied()
                    .chain(["clip_after=1", "fail_ramp=0", "fail_ramp_box=0"])
                    .collect();
                run(&set, &frames)[1].record.model.as_ref().unwrap().reset_by_clip
            };
            let (minmax, variance) = (clipped(&[]), clipped(&["test_box=variance"]));
            let tighter = clipped(&["test_box=variance", "test_gamma=0.5"]);
            assert!(
                minmax < variance && variance < tighter,
                "{name}: {minmax} {variance} {tighter}"
            );
        }
    }

    /// The count of failed box tests: halves each frame, + the miss per failure; a failure
    /// clips once the count reaches `clip_after`.
    #[test]
    fn strikes_count_failures_in_a_row() {
        let mut s = 0.0;
        let mut clips = Vec::new();
        for failed in [true, true, true, false, true, true, true] {
            let (next, clip) = strikes(s, if failed { 1.0 } else { 0.0 }, 1.75);
            s = next;
            clips.push(clip);
        }
        // Three in a row clip (1, 1.5, 1.75); one pass halves the count (0.875), and the
        // next run clips on its third failure again (1.44, 1.72, 1.86).
        let want = [false, false, true, false, false, false, true];
        assert_eq!(clips, want);
        assert!((0..4).all(|k| strikes(k as f32 * 0.5, 1.0, PAPER_CLIP_AFTER).1));
        // The default waits for the third failure in a row.
        let counts = [0.0, 1.0, 1.5].map(|s| strikes(s, 1.0, DEFAULT_CLIP_AFTER).1);
        assert_eq!(counts, [false, false, true]);
        assert!(!strikes(1.99, 1.0, 2.0).1 && !strikes(5.0, 0.0, 0.0).1);
        // Misses by half a ramp add half a strike: six of them do not reach 1.75 (they
        // tend to 1), and a count built by whole misses does not clip on a miss of none.
        let mut s = 0.0;
        for _ in 0..6 {
            let (next, clip) = strikes(s, 0.5, DEFAULT_CLIP_AFTER);
            assert!(!clip);
            s = next;
        }
        assert!(!strikes(4.0, 0.0, 1.0).1 && strikes(4.0, 1e-6, 1.0).1);
        // The relax a miss leaves: fail_keep for a whole one or more, nothing for none.
        assert_eq!(
            [0.0, 0.5, 1.0, 1.5].map(|h| fail_relax(h, 0.25)),
            [1.0, 0.625, 0.25, 0.25]
        );
    }

    /// A miss counts the distance the clip moves the prediction (its largest channel) over
    /// the ramp, at most 1; nothing inside the box; 1 with no ramp.
    #[test]
    fn a_miss_counts_its_distance_over_the_ramp() {
        let pred = [0.5, 0.2, -0.1];
        let tol = Tolerance::abs(1e-6);
        let cases = [
            ([0.5, 0.2, -0.1], true, 0.02, 0.0),
            ([0.495, 0.2, -0.1], true, 0.02, 0.25),
            ([0.5, 0.19, -0.09], true, 0.02, 0.5),
            ([0.4, 0.2, -0.1], true, 0.02, 1.0),
            ([0.4, 0.2, -0.1], false, 0.02, 0.0),
            ([0.4999, 0.2, -0.1], true, 0.0, 1.0),
        ];
        for (clipped, moved, ramp, want) in cases {
            let got = miss(pred, clipped, moved, ramp);
            tol.check(&format!("miss to {clipped:?} ramp {ramp}"), got as f64, want)
                .unwrap();
        }
    }

    /// How many times a failure counts where the speed changed: 1 where it did not, 2 from
    /// a change of `speed_jump` on, linear between; 1 with `speed_jump = 0`.
    #[test]
    fn a_failure_counts_twice_where_the_speed_jumps() {
        let tol = Tolerance::abs(1e-6);
        for (v, v_prev, jump_at, want) in [
            (0.0, 0.0, 1.0, 1.0),
            (2.0, 1.5, 1.0, 1.5),
            (0.0, 3.0, 1.0, 2.0),
            (0.2, 0.0, 0.5, 1.4),
            (5.0, 0.0, 0.0, 1.0),
        ] {
            let got = jump(v, v_prev, jump_at) as f64;
            tol.check(&format!("jump {v} from {v_prev} at {jump_at}"), got, want)
                .unwrap();
        }
    }

    /// How far outside the 3x3 depth range a history's depth is, as a share of
    /// `depth_jump`: 0 inside the range, where a depth is unknown (0) and with
    /// `depth_jump = 0`; linear up to 1 below and above it.
    #[test]
    fn a_failure_counts_twice_where_the_depth_left_the_range() {
        let tol = Tolerance::abs(1e-6);
        for (lo, hi, d_prev, at, want) in [
            (2.0, 10.0, 5.0, 0.25, 0.0),
            (2.0, 10.0, 2.0, 0.25, 0.0),
            (4.0, 10.0, 3.2, 0.25, 1.0),
            (4.0, 10.0, 3.8, 0.25, 4.0 * (0.2 / 3.8)),
            (2.0, 10.0, 11.0, 0.25, 0.4),
            (2.0, 10.0, 11.0, 0.0, 0.0),
            (0.0, 0.0, 5.0, 0.25, 0.0),
            (2.0, 10.0, 0.0, 0.25, 0.0),
            (0.0, 10.0, 30.0, 0.25, 1.0),
        ] {
            let got = depth_share(lo, hi, d_prev, 1.0, at) as f64;
            tol.check(&format!("depth {d_prev} against {lo}..{hi} at {at}"), got, want)
                .unwrap();
        }
        // Weighed by the speed up to DEPTH_JUMP_SPEED: nothing at a still pixel.
        for (v, want) in [(0.0, 0.0), (0.5, 0.5), (1.0, 1.0), (3.0, 1.0)] {
            let got = depth_share(2.0, 10.0, 1.0, v, 0.25) as f64;
            tol.check(&format!("depth share at speed {v}"), got, want)
                .unwrap();
        }
        // What the history keeps of a depth: unknown (0) for none, NaN or a negative one.
        assert_eq!(
            [5.0, 0.0, -1.0, f32::NAN, f32::INFINITY].map(history_depth),
            [5.0, 0.0, 0.0, 0.0, f32::MAX]
        );
    }

    /// An image at depth 10 panning 2 px/frame that a nearer surface (depth 2, another
    /// colour) panning at the same speed covers at once: the speed does not jump, but the
    /// history's depth leaves the new 3x3 range, so the first failed box test clips and the
    /// new colour shows from that frame; with `depth_jump = 0` the clip waits for the third
    /// failure. The state keeps the depth.
    #[test]
    fn a_change_of_depth_clips_at_once() {
        let frame = |v: f32, depth: f32| {
            let mut f = Frame::new(std::array::from_fn(|_| Plane::from_fn(9, 7, |_, _| v))).unwrap();
            f.set_f32(ChannelKind::Depth, vec![Plane::filled(9, 7, depth)])
                .unwrap();
            f.set_f32(
                ChannelKind::Motion,
                vec![Plane::filled(9, 7, -2.0), Plane::filled(9, 7, 0.0)],
            )
            .unwrap();
            f
        };
        let frames: Vec<Frame> = (0..12)
            .map(|t| if t < 8 { frame(0.2, 10.0) } else { frame(0.8, 2.0) })
            .collect();
        assert_the_change_clips_at_once(&frames, "depth_jump=0", DEPTH, [10.0, 2.0]);
    }

    /// Depths a renderer or a client may send (NaN, infinite, zero, negative, denormal,
    /// the largest float) leave the fused kernel on the reference's bits, and the state it
    /// saves loads again (no depth it keeps is refused).
    #[test]
    fn hostile_depths_keep_the_kernel_on_the_reference() {
        let mut frames = random_motion(13, 9);
        let bad = [
            f32::NAN,
            f32::INFINITY,
            0.0,
            -1.0,
            1e-40,
            f32::MAX,
            f32::NEG_INFINITY,
        ];
        for (t, f) in frames.iter_mut().enumerate() {
            let mut d = f.depth().expect("depth").clone();
            for (k, v) in bad.iter().enumerate() {
                let at = (t * 5 + k * 17) % d.data().len();
                d.data_mut()[at] = *v;
            }
            f.set_f32(ChannelKind::Depth, vec![d]).unwrap();
        }
        for set in [&[][..], &["depth_jump=0.01"]] {
            let params: Params = build("phlm", &parse_assignments(set).unwrap()).unwrap();
            let mut slow = ReferencePhlm::new(params.clone());
            let mut fast = Phlm::new(params);
            assert_filter_matches(&mut fast, |f| slow.process(f).unwrap(), &frames, "hostile depths");
            let st = fast.save_state().unwrap();
            fast.load_state(&st).unwrap();
        }
    }

    /// A still image that changes at once to one moving 2 px/frame (a surface that was
    /// not there): the speed jumps, so the first failed box test clips (its miss counts
    /// twice) and the new colour shows from that frame; with `speed_jump = 0` the clip
    /// waits for the third failure as on a still change.
    #[test]
    fn a_change_of_speed_clips_at_once() {
        let frame = |v: f32, mx: f32| {
            let mut f = Frame::new(std::array::from_fn(|_| Plane::from_fn(9, 7, |_, _| v))).unwrap();
            f.set_f32(
                ChannelKind::Motion,
                vec![Plane::filled(9, 7, mx), Plane::filled(9, 7, 0.0)],
            )
            .unwrap();
            f
        };
        let frames: Vec<Frame> = (0..12)
            .map(|t| if t < 8 { frame(0.2, 0.0) } else { frame(0.8, -2.0) })
            .collect();
        assert_the_change_clips_at_once(&frames, "speed_jump=0", V, [0.0, 2.0]);
    }

    /// For 12 flat 9x7 frames whose colour changes from 0.2 to 0.8 at frame 8: the centre
    /// pixel (its history 2 px to the left is on screen where it moves) shows the new
    /// colour from frame 8 with the defaults, from frame 10 (the third failure) with `off`;
    /// a clip lands on the box grown by the clip's guard. The state's `plane` keeps
    /// `kept[0]` before the change and `kept[1]` from it.
    fn assert_the_change_clips_at_once(frames: &[Frame], off: &str, plane: usize, kept: [f32; 2]) {
        for (set, first) in [(&[][..], 8), (&[off][..], 10)] {
            let out = run_own_samples(set, frames);
            for t in 8..12 {
                let err = (out[t].color[0].get(4, 3) - 0.8).abs();
                assert_eq!(
                    err <= guard([0.8; 3], [0.8; 3]),
                    t >= first,
                    "{set:?} frame {t}: {err}"
                );
            }
        }
        let mut f = Phlm::new(Params::default());
        for (t, fr) in frames[..9].iter().enumerate() {
            f.process(fr).unwrap();
            let st = f.save_state().unwrap();
            let at = (3 * 9 + 4) * STATE_PLANES + plane;
            assert_eq!(st.planes[0].data()[at], kept[usize::from(t >= 8)], "frame {t}");
        }
    }

    /// A state of the earlier 26-float texel (before the speed was stored) is refused, naming
    /// both layouts, and the filter keeps its own state.
    #[test]
    fn a_state_of_the_earlier_texel_is_refused() {
        let frames = random_motion(3, 5);
        let mut f = Phlm::new(Params::default());
        for fr in &frames[..2] {
            f.process(fr).unwrap();
        }
        let mut old = f.save_state().unwrap();
        let (w, h) = old.size.unwrap();
        old.components = vec![STATE_PLANES - 1];
        old.planes = vec![Plane::from_fn((STATE_PLANES - 1) * w, h, |_, _| 0.5)];
        let e = f.load_state(&old).unwrap_err().to_string();
        let (old, now) = (format!("[{}]", STATE_PLANES - 1), format!("[{STATE_PLANES}]"));
        assert!(e.contains(&old) && e.contains(&now), "{e}");
        let untouched = run(&[], &frames);
        let next = f.process(&frames[2]).unwrap();
        assert!((0..3).all(|c| next.color[c].data() == untouched[2].color[c].data()));
    }

    /// A still image that changes at once (a flat 0.2 to a flat 0.8, so the box is the
    /// new colour alone): the models clip on the change's third frame (the default
    /// `clip_after = 1.75`) or fourth (1.875), with `fail_keep` or without, and from then on
    /// show the new colour (within the clip's guard); the paper's clip at its first frame.
    #[test]
    fn a_persistent_change_clips_once_it_persists() {
        let flat = |v: f32| Frame::new(std::array::from_fn(|_| Plane::from_fn(9, 7, |_, _| v))).unwrap();
        let frames: Vec<Frame> = (0..13).map(|t| flat(if t < 8 { 0.2 } else { 0.8 })).collect();
        let clipped = |out: &[Output], t: usize| out[t].record.model.as_ref().unwrap().reset_by_clip;
        let err = |out: &[Output], t: usize| (out[t].color[0].get(4, 3) - 0.8).abs();
        for (set, first) in [
            (&[][..], 10),
            (&["fail_keep=1"], 10),
            (&["clip_after=1.875"], 11),
            (&["clip_after=1"], 8),
        ] {
            let out = run_own_samples(set, &frames);
            for t in 8..13 {
                assert_eq!(
                    clipped(&out, t),
                    if t == first { 1.0 } else { 0.0 },
                    "{set:?} frame {t}"
                );
                assert_eq!(
                    err(&out, t) <= guard([0.8; 3], [0.8; 3]),
                    t >= first,
                    "{set:?} frame {t}: {}",
                    err(&out, t)
                );
            }
        }
    }

    /// `on_clip = shift` keeps the slopes and moves the prediction to the clipped colour;
    /// `reset` clears the slopes; `clip_keep` blends R toward `I / clip_p`.
    #[test]
    fn a_clip_resets_or_shifts_the_model() {
        let beta = [[0.2, 0.5, -0.1, 0.0], [0.1, 0.0, 0.3, 0.2], [-0.3, 0.1, 0.1, 0.7]];
        let r = [4.0, 0.5, 0.1, 0.2, 3.0, 0.3, 0.1, 2.0, 0.4, 5.0];
        let m0 = Model {
            beta,
            r,
            z: [0.4, 0.6, 0.2],
        };
        let pred = rls::predict(&m0.beta, &m0.x());
        let c = [0.3, 0.45, 0.25];
        let tol = Tolerance::abs(1e-5);
        for (on_clip, keep) in [("reset", "0"), ("shift", "0"), ("shift", "0.25"), ("reset", "1")] {
            let p: Params = build(
                "phlm",
                &parse_assignments(&[
                    &format!("on_clip={on_clip}"),
                    &format!("clip_keep={keep}"),
                    "clip_p=2",
                ])
                .unwrap(),
            )
            .unwrap();
            let mut m = m0;
            m.clip(pred, c, &p);
            let got = rls::predict(&m.beta, &m.x());
            for ch in 0..3 {
                tol.check("prediction after the clip", got[ch] as f64, c[ch] as f64)
                    .unwrap();
                let slopes = if on_clip == "shift" { beta[ch] } else { [0.0; D] };
                assert_eq!(m.beta[ch][1..], slopes[1..], "{on_clip}");
            }
            let init = rls::init_information(2.0);
            for k in 0..P_LEN {
                let want = p.clip_keep as f64 * r[k] as f64 + (1.0 - p.clip_keep as f64) * init[k] as f64;
                tol.check("R after the clip", m.r[k] as f64, want).unwrap();
            }
        }
    }

    /// `n` frames of the "random motion" sequence at 33x19 from `seed`.
    fn random_motion(n: u64, seed: u64) -> Vec<Frame> {
        sequences(33, 19, n, seed)
            .into_iter()
            .find(|(name, _)| *name == "random motion")
            .expect("a random motion sequence")
            .1
    }

    /// `variant = paper` runs exactly the twelve settings it names, whatever they were set to.
    #[test]
    fn the_paper_variant_is_the_papers_settings() {
        let frames = random_motion(5, 9);
        let paper = run(
            &[
                "variant=paper",
                "p0=3",
                "clip_keep=0.9",
                "clip_after=2",
                "fail_ramp=0.5",
                "fail_ramp_box=1",
                "speed_jump=3",
                "depth_jump=0.01",
                "pixel_filter=gaussian",
            ],
            &frames,
        );
        let explicit = run(
            &[
                "lambda_moving=0",
                "dilation=false",
                "model_fetch=bilinear",
                "p0=1000",
                "clip_p=1000",
                "clip_keep=0",
                "clip_after=1",
                "fail_ramp=0",
                "fail_ramp_box=0",
                "speed_jump=0",
                "depth_jump=0",
                "pixel_filter=box",
            ],
            &frames,
        );
        for (a, b) in paper.iter().zip(&explicit) {
            assert!((0..3).all(|c| a.color[c].data() == b.color[c].data()));
        }
        assert!((0..3).any(|c| paper[4].color[c].data() != run(&[], &frames)[4].color[c].data()));
    }

    /// Every ablation knob reaches the output.
    #[test]
    fn each_ablation_knob_changes_the_output() {
        let frames = random_motion(6, 8);
        // The knobs of what a clip does, against a filter that clips at every failure
        // (six frames hold few failures three in a row).
        let paper_clip = ["clip_after=1", "fail_ramp=0", "fail_ramp_box=0"];
        for (set, on) in [
            (&["test_box=variance"][..], &[][..]),
            (&["test_box=variance", "test_gamma=2"], &[]),
            (&["on_clip=shift"], &paper_clip),
            (&["clip_keep=0"], &paper_clip),
            (&["lambda_moving=0"], &[]),
            (&["lambda_speed=3"], &[]),
            (&["dilation=false"], &[]),
            (&["model_fetch=bilinear"], &[]),
            (&["p0=1000"], &[]),
            (&["clip_after=1"], &[]),
            (&["fail_keep=1"], &[]),
            (&["fail_ramp=0", "fail_ramp_box=0"], &[]),
            (&["fail_ramp=0.5"], &[]),
            (&["fail_ramp_box=0"], &[]),
            (&["speed_jump=0"], &[]),
            (&["feature_alpha_min=0.03"], &[]),
            (&["variant=paper"], &[]),
        ] {
            let base = run(on, &frames);
            let with: Vec<&str> = on.iter().chain(set).copied().collect();
            let other = run(&with, &frames);
            let differs = base
                .iter()
                .zip(&other)
                .any(|(a, b)| (0..3).any(|c| a.color[c].data() != b.color[c].data()));
            assert!(differs, "{set:?} changed nothing");
        }
    }
}
