//! `phlm`: Pixel History Linear Models (Iglesias-Guitian, Moon, Koniaris, Smolikowski and
//! Mitchell 2016; seed 000), with an RLS that stays bounded forever ([`rls`]).
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
//! 4. `reproject`: each pixel's previous position `p + motion`; off screen -> the model is
//!    reset to the input (Algorithm 1 lines 7-9). Left out when nothing moves (the static
//!    case of sec. 5.2: `pi(v)` is the identity and state is read in place).
//! 5. `feature`: the temporal feature (sec. 5.1), fetched at the previous position.
//! 6. `model`: Algorithm 1 lines 11-22: fetch beta and P, predict, test against the 3x3 box,
//!    clip toward the input and reset on failure, RLS update (eq. 5-7 with regularized
//!    forgetting in information form, bounded forever: see [`rls`]), output `beta^T x`.
//! 7. `untonemap` (HDR input only).
//!
//! State: beta (12), the information matrix R = P^-1 (10, packed symmetric), z (3) = 25
//! float planes, double-buffered (200 bytes per pixel).
//!
//! Choices where the paper is open (each cited where it is made):
//! - the model fetch is bilinear by default ("our linear models are stored in GPU texture
//!   memory, and thus we can exploit texture cache and hardware bilinear interpolation",
//!   sec. 6); `model_fetch = nearest` is the cheaper alternative. A convex blend of
//!   positive-definite matrices is positive definite (and of matrices `>= R0` is `>= R0`),
//!   so bilinear R stays valid and the bound `P <= p0 I` holds. We blend the information
//!   `R = P^-1` (what we store) where the paper's texture fetch blends P: blending R pools
//!   the neighbours' evidence, and both are convex blends of SPD matrices.
//! - the hull test runs in YCoCg ("the convex hull in a given colorspace (e.g. RGB or
//!   YCgCo)", sec. 5.2): the same 3x3 pass then gives the luma range the feature needs; the
//!   clip follows the paper's ray from the prediction toward the input (lines 14-17).
//! - the model after a clip is reset to the clipped colour ("resetting a linear model with a
//!   specific color value", sec. 5.2) with `P = clip_p I`; the paper's reset uses the init
//!   value 1000, we default to 1 ([`DEFAULT_CLIP_P`] has the measurements).

pub mod feature;
pub mod rls;

use super::passes::{from_working, on_screen, slices_mut, to_working, to_ycocg, Conversion, TemporalState};
use crate::filter_params;
use crate::frame::{ChannelKind, ChannelSet, Frame, Plane, Rgb};
use crate::kernels::{bilinear, clip_toward_point, for_each_row_stats, rgb_to_ycocg, tonemap, ycocg_to_rgb};
use crate::pipeline::exec::{for_rows, par_rows};
use crate::pipeline::{
    check_needs, prepare, Filter, FilterError, FilterKind, ModelHealth, Output, ParamKind, PixelCounts,
    Recorder, Skip,
};
use rls::{D, P_LEN};
use serde::{Deserialize, Serialize};
use serde_json::Value;
use std::ops::AddAssign;

/// How the model state is read at a reprojected position.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ModelFetch {
    /// Bilinear blend of the four nearest models (the paper's texture fetch, sec. 6).
    Bilinear,
    /// The nearest model (4x fewer reads; blocky under sub-pixel motion).
    Nearest,
}

filter_params! {
    /// Parameters of `phlm`.
    pub struct Params {
        lambda: f32 = DEFAULT_LAMBDA,
            ParamKind::Float { min: 0.5, max: 0.99999 },
            "RLS forgetting factor (paper: 0.998, memory ~1/(1-lambda) = 500 frames). Higher: more supersampling on still content, slower to follow slow shading changes; lower: follows changes, keeps more flicker";
        p0: f32 = DEFAULT_P0,
            ParamKind::Float { min: 1e-3, max: 1e6 },
            "diagonal of P at initialisation and off-screen reset (paper: 1000). High: a new model follows the input at once; low: it trusts its initial value";
        clip_p: f32 = DEFAULT_CLIP_P,
            ParamKind::Float { min: 1e-3, max: 1e6 },
            "diagonal of P after a clip reset (default 1; paper: 1000 like p0, the model restarts from the input and the pixel shows its raw input). Lower keeps the clipped colour longer: less flicker on thin features, more lag";
        feature_a: f32 = feature::DEFAULT_A,
            ParamKind::Float { min: 0.0, max: 100.0 },
            "feature convergence phi = a l^2 + b v l^3 (paper: a = 0.125): how fast the feature catches up when its luma leaves the neighbourhood range";
        feature_b: f32 = feature::DEFAULT_B,
            ParamKind::Float { min: 0.0, max: 100.0 },
            "feature convergence, motion term (paper: b = 0.25): faster catch-up for moving pixels";
        feature_alpha_min: f32 = feature::DEFAULT_ALPHA_MIN,
            ParamKind::Float { min: 0.001, max: 1.0 },
            "smallest weight of the current low-pass sample in the feature (our choice, 0.03 = a 33-frame memory): lower gives a smoother feature that lags more";
        model_fetch: ModelFetch = ModelFetch::Bilinear,
            ParamKind::Choice { options: &["bilinear", "nearest"], },
            "reprojected model read: bilinear (paper's texture fetch, smooth) or nearest (4x fewer reads)";
    }
}

/// RLS forgetting factor `lambda = 0.998` (000, sec. 4 after eq. 6: "we used lambda = 0.998
/// as widely used in real-time tracking systems").
pub const DEFAULT_LAMBDA: f32 = 0.998;
/// Initial diagonal of P (000, sec. 6: "initialized with a relatively high value, e.g. 1000").
pub const DEFAULT_P0: f32 = 1000.0;

/// Diagonal of P after a clip reset: 1 (our choice, measured). The paper resets a clipped
/// model like a new one (P = 1000 I, sec. 5.2 and 6), so the next update fits the input
/// almost exactly and a clipped pixel shows its raw, aliased input; with P = I the update
/// moves about half way to the input. On our 10-scene catalogue (128x72, 32 frames) this
/// raises mean PSNR from 27.72 to 29.34 dB and lowers tRMSE from 0.0596 to 0.0450 (with
/// `feature_alpha_min = 0.03`); `clip_p = 1000` gives the paper's behaviour.
pub const DEFAULT_CLIP_P: f32 = 1.0;

/// Number of state planes: beta (12), R = P^-1 (10), z (3).
pub const STATE_PLANES: usize = 3 * D + P_LEN + 3;
/// First plane of beta (row-major: channel c, feature j at `BETA + c * D + j`).
const BETA: usize = 0;
/// First plane of the information matrix R = P^-1 (packed upper triangle).
const R: usize = 3 * D;
/// First plane of z.
const Z: usize = R + P_LEN;

/// One pixel's model state.
#[derive(Clone, Copy, Debug)]
struct Model {
    beta: [[f32; D]; 3],
    /// The information matrix `R = P^-1` (packed), see [`rls::update_information`].
    r: [f32; P_LEN],
    z: [f32; 3],
}

impl Model {
    /// Reset to colour `c` with `P = p0 I` (000, sec. 6: intercept = colour, slopes 0).
    #[inline(always)]
    fn reset(c: [f32; 3], z: [f32; 3], p0: f32) -> Model {
        Model {
            beta: c.map(|v| [v, 0.0, 0.0, 0.0]),
            r: rls::init_information(p0),
            z,
        }
    }

    /// The model held in state values `s` (beta and R at their plane offsets) with
    /// feature `z`.
    #[inline(always)]
    fn from_state(s: &[f32], z: [f32; 3]) -> Model {
        Model {
            beta: std::array::from_fn(|c| std::array::from_fn(|j| s[BETA + c * D + j])),
            r: std::array::from_fn(|k| s[R + k]),
            z,
        }
    }

    #[inline(always)]
    fn x(&self) -> [f32; D] {
        [1.0, self.z[0], self.z[1], self.z[2]]
    }
}

/// Where a pixel's history is.
#[derive(Clone, Copy, Debug)]
enum From {
    /// No history (first frame, reset) or off screen.
    Nothing,
    /// In place (nothing moves).
    Here(usize),
    /// At this previous position (pixel units).
    At(f32, f32),
}

/// Reads `N` state planes of a `w` x `h` image at `at` (zeros for [`From::Nothing`]).
#[inline(always)]
fn fetch<const N: usize>(planes: [&[f32]; N], w: usize, h: usize, at: From, how: ModelFetch) -> [f32; N] {
    match at {
        From::Nothing => [0.0; N],
        From::Here(i) => planes.map(|p| p[i]),
        From::At(x, y) => match how {
            ModelFetch::Bilinear => bilinear(planes, w, h, x, y),
            ModelFetch::Nearest => {
                let j = (y.max(0.0) as usize).min(h - 1) * w + (x.max(0.0) as usize).min(w - 1);
                planes.map(|p| p[j])
            }
        },
    }
}

/// Per-row counters of the model pass.
#[derive(Clone, Copy, Debug, Default)]
struct Counts {
    pixels: PixelCounts,
    offscreen: u64,
    repaired: u64,
    max_trace: f32,
}

impl AddAssign for Counts {
    fn add_assign(&mut self, o: Counts) {
        self.pixels += o.pixels;
        self.offscreen += o.offscreen;
        self.repaired += o.repaired;
        self.max_trace = self.max_trace.max(o.max_trace);
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
        "Pixel History Linear Models (000): per-pixel RLS linear models over a temporal feature, box-clipped, with bounded (regularized) forgetting";
    const STAGES: &'static [&'static str] = &[
        "repair",
        "tonemap",
        "ycocg",
        "reproject",
        "feature",
        "model",
        "untonemap",
    ];
    type Params = Params;
    fn needs() -> ChannelSet {
        ChannelSet::of(&[ChannelKind::Color])
    }
    fn uses() -> ChannelSet {
        ChannelSet::of(&[ChannelKind::Color, ChannelKind::Motion])
    }
    fn state_bytes_per_pixel(_: &Params) -> usize {
        2 * 4 * STATE_PLANES
    }
    fn new(params: Params) -> Self {
        Phlm {
            params,
            hist: TemporalState::with_conversion(STATE_PLANES, Conversion::Custom(convert_state)),
        }
    }
}

/// Moves the model state between linear and tonemapped working space (a stream that
/// switches between LDR and HDR frames): each model restarts from its own prediction
/// converted to the new space (slopes 0, P kept), the feature is converted, so the output
/// does not jump.
fn convert_state(planes: &mut [Plane<f32>], to_tonemapped: bool) {
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

impl Phlm {
    /// Every pixel's information matrix `R = P^-1` (packed upper triangle, see
    /// [`rls::SYM`]) after the last frame; empty before the first frame or after a reset.
    /// For health checks ([`rls::positive_definite`], [`rls::trace_of_inverse_packed`]).
    pub fn information_matrices(&self) -> Vec<[f32; P_LEN]> {
        let b = &self.hist.buffer;
        if !b.valid() {
            return Vec::new();
        }
        let planes = &b.read()[R..R + P_LEN];
        (0..planes[0].data().len())
            .map(|i| std::array::from_fn(|k| planes[k].data()[i]))
            .collect()
    }
}

impl Filter for Phlm {
    fn name(&self) -> &'static str {
        Self::NAME
    }

    fn params(&self) -> Value {
        Value::Object(crate::pipeline::params::to_json(&self.params))
    }

    fn process(&mut self, frame: &Frame) -> Result<Output, FilterError> {
        check_needs(Self::NAME, Self::needs(), frame)?;
        let p = self.params.clone();
        let mut rec = Recorder::new();
        let inp = prepare(frame, Self::uses(), &mut rec)?;
        let (w, h) = (inp.width, inp.height);
        let facts = inp.facts;
        let hdr = facts.hdr;
        let has_history = self.hist.begin(frame, hdr)?;
        let scratch = &mut self.hist.scratch;

        let working = rec
            .stage("tonemap", facts.tonemap(), || {
                to_working(&inp.color, true, scratch)
            })
            .unwrap_or(std::borrow::Cow::Borrowed(&*inp.color));
        let rgb = working.each_ref().map(|p| p.data());

        let ycocg: Rgb = rec.run("ycocg", || to_ycocg(&working, scratch));
        let cur = ycocg.each_ref().map(|p| p.data());

        // Previous positions (pixel units); NaN marks off screen.
        let skip = (!has_history)
            .then_some(Skip::NoHistory)
            .or_else(|| inp.require(ChannelKind::Motion))
            .or_else(|| facts.reprojection());
        let positions: Option<[Plane<f32>; 2]> = rec.stage("reproject", skip, || {
            let m = inp
                .motion
                .as_deref()
                .expect("required")
                .each_ref()
                .map(|p| p.data());
            let mut out: [Plane<f32>; 2] = scratch.planes(w, h);
            for_rows(slices_mut(&mut out), w, |y, [px, py]| {
                for x in 0..w {
                    let i = y * w + x;
                    let (qx, qy) = (x as f32 + 0.5 + m[0][i], y as f32 + 0.5 + m[1][i]);
                    (px[x], py[x]) = if on_screen(qx, qy, w, h) {
                        (qx, qy)
                    } else {
                        (f32::NAN, f32::NAN)
                    };
                }
            });
            out
        });
        let pos = positions.as_ref().map(|p| p.each_ref().map(|p| p.data()));
        let motion = inp.motion.as_deref().map(|m| m.each_ref().map(|p| p.data()));

        let (read, next) = self.hist.buffer.split();
        let src: [&[f32]; STATE_PLANES] = std::array::from_fn(|k| read[k].data());
        let from = |i: usize| -> From {
            if !has_history {
                return From::Nothing;
            }
            match pos {
                None => From::Here(i),
                Some([px, _]) if px[i].is_nan() => From::Nothing,
                Some([px, py]) => From::At(px[i], py[i]),
            }
        };
        let src_z: [&[f32]; 3] = std::array::from_fn(|k| src[Z + k]);
        let src_model: [&[f32]; Z] = std::array::from_fn(|k| src[k]);

        // Feature (sec. 5.1): written into next's z planes.
        {
            let (_, z_next) = next.split_at_mut(Z);
            let zrows: [&mut [f32]; 3] = {
                let mut it = z_next.iter_mut();
                std::array::from_fn(|_| it.next().expect("z planes").data_mut())
            };
            rec.run("feature", || {
                for_rows(zrows, w, |y, [zr, zg, zb]| {
                    for_each_row_stats(cur, w, h, y, |x, stats| {
                        let i = y * w + x;
                        let input = [rgb[0][i], rgb[1][i], rgb[2][i]];
                        let f = from(i);
                        let z = if matches!(f, From::Nothing) {
                            // Sec. 6: "Our temporal feature z is initialized with the input image".
                            input
                        } else {
                            let prev = fetch(src_z, w, h, f, p.model_fetch);
                            if inp.is_invalid(i) {
                                prev
                            } else {
                                let v = motion.map_or(0.0, |m| m[0][i].hypot(m[1][i]));
                                feature::accumulate(
                                    prev,
                                    ycocg_to_rgb(stats.mean),
                                    stats.min[0],
                                    stats.max[0],
                                    v,
                                    &p,
                                )
                            }
                        };
                        (zr[x], zg[x], zb[x]) = (z[0], z[1], z[2]);
                    });
                });
            });
        }

        // Algorithm 1.
        let mut out: Rgb = scratch.planes(w, h);
        let hi = if hdr { 1.0 - 1e-7 } else { f32::MAX };
        // The prior R0 = I / p0 that forgetting relaxes toward (rls module docs).
        let prior = 1.0 / p.p0;
        let counts: Counts = rec.run("model", || {
            let (model_next, z_next) = next.split_at_mut(Z);
            let zs: [&[f32]; 3] = std::array::from_fn(|k| z_next[k].data());
            let [o0, o1, o2] = slices_mut(&mut out);
            let mut it = model_next.iter_mut();
            let mrows: [&mut [f32]; Z] = std::array::from_fn(|_| it.next().expect("model planes").data_mut());
            let mut all: Vec<&mut [f32]> = mrows.into_iter().collect();
            all.extend([o0, o1, o2]);
            let rows: [&mut [f32]; Z + 3] = all.try_into().expect("Z + 3 planes");
            par_rows(rows, w, |y, mut r| {
                let mut c = Counts::default();
                for_each_row_stats(cur, w, h, y, |x, stats| {
                    let i = y * w + x;
                    let input = [rgb[0][i], rgb[1][i], rgb[2][i]];
                    let z = [zs[0][i], zs[1][i], zs[2][i]];
                    let f = from(i);
                    let mut m = match f {
                        From::Nothing => {
                            c.pixels.history_reset += 1;
                            if has_history {
                                c.offscreen += 1;
                            }
                            Model::reset(input, z, p.p0)
                        }
                        _ => Model::from_state(&fetch(src_model, w, h, f, p.model_fetch), z),
                    };
                    let x_feat = m.x();
                    if !inp.is_invalid(i) {
                        // Lines 12-19: predict; outside the 3x3 box -> clip toward y and reset.
                        let pred = rls::predict(&m.beta, &x_feat);
                        let (clipped, moved) = clip_toward_point(
                            rgb_to_ycocg(pred),
                            [cur[0][i], cur[1][i], cur[2][i]],
                            stats.min,
                            stats.max,
                        );
                        if moved {
                            c.pixels.history_clipped += 1;
                            m = Model::reset(ycocg_to_rgb(clipped), z, p.clip_p);
                        }
                        // Lines 19-21: error of the (possibly reset) model, RLS update.
                        let pred = rls::predict(&m.beta, &x_feat);
                        let e = [0, 1, 2].map(|k| input[k] - pred[k]);
                        match rls::update_information(&mut m.beta, &mut m.r, &x_feat, e, p.lambda, prior) {
                            Some(trace) => c.max_trace = c.max_trace.max(trace),
                            None => {
                                c.repaired += 1;
                                m = Model::reset(input, z, p.p0);
                            }
                        }
                        if !m.beta.iter().flatten().all(|v| v.is_finite()) {
                            c.repaired += 1;
                            m = Model::reset(input, z, p.p0);
                        }
                    }
                    // Line 22: the output.
                    let o = rls::predict(&m.beta, &x_feat);
                    for ch in 0..3 {
                        for j in 0..D {
                            r[BETA + ch * D + j][x] = m.beta[ch][j];
                        }
                    }
                    for k in 0..P_LEN {
                        r[R + k][x] = m.r[k];
                    }
                    // Rows Z.. of this pass are the output planes.
                    for ch in 0..3 {
                        r[Z + ch][x] = o[ch].clamp(0.0, hi);
                    }
                });
                c
            })
        });

        rec.stage("untonemap", facts.tonemap(), || from_working(&mut out, true));

        let n = (w * h) as f64;
        scratch.recycle(ycocg);
        scratch.recycle(positions.into_iter().flatten());
        if let std::borrow::Cow::Owned(w) = working {
            scratch.recycle(w);
        }
        let bytes = self.hist.finish(hdr);
        let mut record = rec.finish(Self::NAME, frame.meta.index, counts.pixels, inp.counts, bytes);
        record.model = Some(ModelHealth {
            reset_by_clip: counts.pixels.history_clipped as f64 / n,
            reset_by_disocclusion: counts.offscreen as f64 / n,
            max_trace_p: counts.max_trace as f64,
            p_repaired: counts.repaired,
        });
        Ok(Output { color: out, record })
    }

    fn reset(&mut self) {
        self.hist.buffer.reset();
    }

    fn recycle(&mut self, planes: Rgb) {
        self.hist.scratch.recycle(planes);
    }

    fn state_bytes(&self) -> usize {
        self.hist.buffer.bytes()
    }
}
