//! `upsample`: spatio-temporal upsampling (Herzog, Eisemann, Myszkowski, Seidel 2010,
//! "Spatio-Temporal Upsampling on the GPU", seed 001), and the three baselines its claim is
//! measured against, as `method`s of one filter.
//!
//! Input: a frame whose colour is shaded at one pixel of every 2x2 or 4x4 block in a
//! rotating order ([`crate::frame::Sampling`]), with the G-buffer (depth, normal, motion,
//! object id) at full resolution. Output: full-resolution colour. A fully shaded frame is
//! accepted too (factor 1).
//!
//! Methods:
//! - `spatiotemporal` (the paper): joint-bilateral gather of this frame's samples (eq.
//!   1-2; [`spatial`]) blended with an exponential history buffer (eq. 6-7) whose weight is
//!   the accumulated sample weight, decayed by `decay` each frame; the binary "shaded this
//!   frame" weight is the image-space kernel at distance 0. The relative temporal gradient
//!   of luma (sec. 3.4), filtered over the current and three previous gradients (4, 3, 2, 1)
//!   and over a box slightly larger than the block, gives a confidence `c` that (a) scales
//!   the history's weight and (b) sets the image-space kernel's width between
//!   `kernel_sharp` (c = 1: only a pixel's own sample counts, history does the rest) and
//!   `kernel_wide` (c = 0: the whole block footprint, the spatial estimate). Disoccluded
//!   pixels and the first frame count as maximal gradient (fig. 6).
//! - `spatial`: the joint-bilateral upsampling alone, wide kernel (Yang et al.'s spatial
//!   method as seed 001 compares it).
//! - `temporal`: reverse reprojection with hole filling (seed 001, eq. 3-4; Nehab et al.):
//!   a shaded pixel takes its sample, another pixel its valid reprojected history, a hole
//!   the spatial estimate.
//! - `taa`: TAA-style upsampling with scaling-aware accumulation (survey 003, "Temporal
//!   upsampling"; Unreal's temporal upscale): samples splatted with a Gaussian of the
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
//!   4x4"); lower reacts faster, higher averages more.
//! - History is fetched bilinearly over the taps that pass the validity test, renormalised
//!   (fig. 9 weighs nearest against bilinear; bilinear avoids the "precision loss" of
//!   nearest under continuous motion); the history weight is scaled by the passing taps'
//!   share. Gradients live at full resolution: each pixel takes its block's sample's.

mod spatial;
mod temporal;

pub use spatial::{depth_range, falloff, Gathered, Geometry, Sparse, WEIGHT_EPSILON};
pub use temporal::{confidence, relative_gradient, reproject, Validity, GRADIENT_WEIGHTS, LUMA_FLOOR};

use super::passes::slices_mut;
use crate::filter_params;
use crate::frame::{ChannelKind, ChannelSet, Frame, Plane, Rgb, Sampling};
use crate::kernels::luma;
use crate::pipeline::exec::{for_rows, par_rows};
use crate::pipeline::{
    bind_size, check_channels, prepare, DoubleBuffer, Filter, FilterError, FilterKind, Output, ParamKind,
    PixelCounts, Recorder, Scratch, Skip,
};
use serde::{Deserialize, Serialize};
use serde_json::Value;

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
    fn name(self) -> &'static str {
        match self {
            Method::Spatiotemporal => "spatiotemporal",
            Method::Spatial => "spatial",
            Method::Temporal => "temporal",
            Method::Taa => "taa",
        }
    }

    /// History planes the method keeps.
    fn planes(self) -> usize {
        match self {
            Method::Spatiotemporal => 11,
            Method::Temporal => 5,
            Method::Taa => 4,
            Method::Spatial => 0,
        }
    }
}

/// History planes: colour, weight (spatiotemporal) or sample count (taa), then the
/// previous frame's depth and ids for the validity test, then three past gradients.
const R: usize = 0;
const W: usize = 3;
/// Depth and ids of `temporal` (which has no weight plane).
const T_DEPTH: usize = 3;
const T_ID: usize = 4;
const DEPTH: usize = 4;
const ID: usize = 5;
const G1: usize = 6;
/// Luma of the pixel's last shaded sample times `K`, and `K`: 1 where that sample is known
/// (both carried along the motion; their ratio survives bilinear fetches across unknowns).
const LK: usize = 9;

filter_params! {
    /// Parameters of `upsample`.
    pub struct Params {
        method: Method = Method::Spatiotemporal,
            ParamKind::Choice { options: &["spatiotemporal", "spatial", "temporal", "taa"], },
            "spatiotemporal (Herzog et al. 2010), or a baseline: spatial (joint bilateral only), temporal (reprojection with hole filling), taa (scaling-aware accumulation)";
        decay: f32 = 0.0,
            ParamKind::Float { min: 0.0, max: 0.999 },
            "history weight kept per frame (0 = auto: 1 - 1/(2 x pattern period), 0.875 for 2x2). Higher: smoother, more lag on changes the gradient misses; lower: faster, noisier";
        gradient_scale: f32 = 1.0,
            ParamKind::Float { min: 0.01, max: 100.0 },
            "relative luma gradient at which history is no longer trusted (seed 001 eq. 8, 1). Lower: reacts to smaller changes, blurrier; higher: sharper, more lag";
        kernel_sharp: f32 = 0.1,
            ParamKind::Float { min: 0.01, max: 4.0 },
            "image-space kernel width at full confidence, in block diagonals: below 1/(factor x 1.41) (0.18 for 4x4) no other sample reaches it, so a still image converges to its own samples; higher blurs converged detail";
        kernel_wide: f32 = 1.0,
            ParamKind::Float { min: 0.01, max: 4.0 },
            "image-space kernel width at no confidence and for the spatial method, in block diagonals (1: the block footprint). Higher: smoother fill, blurrier";
        depth_sigma: f32 = 0.03,
            ParamKind::Float { min: 1e-4, max: 10.0 },
            "depth difference (fraction of the frame's depth range) at which a sample stops counting (seed 001: 3%). Lower: sharper silhouettes, grazing surfaces fill worse";
        normal_sigma: f32 = 0.5,
            ParamKind::Float { min: 1e-3, max: 2.0 },
            "normal difference (1 - cos) at which a sample stops counting. Lower: sharper creases, curved surfaces fill worse";
        depth_tolerance: f32 = 0.1,
            ParamKind::Float { min: 1e-3, max: 10.0 },
            "relative depth difference a history tap may have and still count as the same surface. Lower: catches more disocclusion, also rejects valid history under fast motion in depth";
        taa_alpha: f32 = crate::filters::taa::DEFAULT_ALPHA,
            ParamKind::Float { min: 0.01, max: 1.0 },
            "taa method: blend weight of a sample at its own pixel (Karis 2014: 0.1)";
    }
}

/// Fit of the Blackman-Harris reconstruction kernel, `exp(-2.29 d^2)` with `d` in output
/// pixels (Karis 2014, "High quality temporal supersampling", used by Unreal's temporal
/// upscale that survey 003 cites for scaling-aware accumulation).
const TAA_KERNEL: f32 = 2.29;
/// Sample counts of the `taa` method are held here (as in `taa`): past 1/alpha the blend is
/// alpha anyway.
const TAA_MAX_COUNT: f32 = 255.0;

/// The upsampling filter with its history.
#[derive(Debug)]
pub struct Upsample {
    params: Params,
    hist: DoubleBuffer,
    scratch: Scratch,
}

impl FilterKind for Upsample {
    const NAME: &'static str = "upsample";
    const SUMMARY: &'static str =
        "spatio-temporal upsampling of sparse shading (Herzog et al. 2010), with spatial, temporal and TAA-style baselines";
    const STAGES: &'static [&'static str] = &["repair", "geometry", "reproject", "gradient", "blend"];
    type Params = Params;
    const SPARSE_INPUT: bool = true;
    fn needs() -> ChannelSet {
        ChannelSet::of(&[ChannelKind::Color])
    }
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
            hist: DoubleBuffer::new(params.method.planes()),
            scratch: Scratch::default(),
            params,
        }
    }
}

impl Upsample {
    /// The decay in effect for a pattern.
    pub fn decay(&self, sampling: Sampling) -> f32 {
        if self.params.decay > 0.0 {
            self.params.decay
        } else {
            1.0 - 1.0 / (2.0 * sampling.period() as f32)
        }
    }
}

impl Filter for Upsample {
    fn name(&self) -> &'static str {
        Self::NAME
    }

    fn params(&self) -> Value {
        Value::Object(crate::pipeline::params::to_json(&self.params))
    }

    fn process(&mut self, frame: &Frame) -> Result<Output, FilterError> {
        check_channels(Self::NAME, Self::needs(), frame)?;
        let p = self.params.clone();
        let method = p.method;
        let mut rec = Recorder::new();
        let inp = prepare(frame, Self::uses(), &mut rec)?;
        let (w, h) = (inp.width, inp.height);
        let sampling = frame.sampling();
        let stateful = method != Method::Spatial;
        let has_history = if stateful {
            bind_size(&mut self.hist, frame)?;
            self.hist.valid() && !frame.meta.reset
        } else {
            false
        };
        let variant = Skip::Variant {
            variant: method.name(),
        };
        let (cw, ch) = inp.color[0].size();
        let sparse = Sparse::new(inp.color_slices(), cw, ch, sampling, inp.invalid.as_deref());
        let depth = inp.depth.as_deref().map(Plane::data);
        let ids = inp.object_id.map(Plane::data);

        let range = rec.stage(
            "geometry",
            (method == Method::Taa)
                .then_some(variant.clone())
                .or_else(|| inp.require(ChannelKind::Depth)),
            || depth_range(depth.expect("required"), ids, frame.meta.near_far),
        );
        let geo = Geometry {
            width: w,
            height: h,
            depth: depth.filter(|_| range.is_some()),
            normal: inp.normal.as_deref().map(|n| n.each_ref().map(Plane::data)),
            inv_depth_scale: 1.0 / (p.depth_sigma * range.unwrap_or(1.0)),
            normal_sigma: p.normal_sigma,
        };

        let mut pixels = PixelCounts::default();
        let decay = self.decay(sampling);
        let scratch = &mut self.scratch;
        let (read, next) = self.hist.split();
        let motion = inp.motion.as_deref().map(|m| m.each_ref().map(Plane::data));
        // Reprojected history: colour (+ weight or count, + the three past gradients) and
        // the share of valid taps.
        let mut frac = scratch.plane(w, h);
        let reprojected: Option<Vec<Plane<f32>>> = rec.stage(
            "reproject",
            (!stateful)
                .then_some(variant.clone())
                .or_else(|| (!has_history).then_some(Skip::NoHistory)),
            || {
                let src = |k: usize| read[k].data();
                let fr = frac.data_mut();
                let (prev_depth, prev_ids) = match method {
                    Method::Temporal => (src(T_DEPTH), src(T_ID)),
                    _ if method.planes() > ID => (src(DEPTH), src(ID)),
                    _ => (&[][..], &[][..]),
                };
                let validity = Validity {
                    depth,
                    prev_depth,
                    ids,
                    prev_ids,
                    depth_tolerance: p.depth_tolerance,
                };
                match method {
                    Method::Spatiotemporal => {
                        let mut o: [Plane<f32>; 9] = scratch.planes(w, h);
                        let lost = reproject(
                            [
                                src(R),
                                src(R + 1),
                                src(R + 2),
                                src(W),
                                src(G1),
                                src(G1 + 1),
                                src(G1 + 2),
                                src(LK),
                                src(LK + 1),
                            ],
                            motion,
                            Some(&validity),
                            w,
                            h,
                            slices_mut(&mut o),
                            fr,
                        );
                        pixels.history_rejected += lost;
                        o.into()
                    }
                    Method::Temporal => {
                        let mut o: [Plane<f32>; 3] = scratch.planes(w, h);
                        let lost = reproject(
                            [src(R), src(R + 1), src(R + 2)],
                            motion,
                            Some(&validity),
                            w,
                            h,
                            slices_mut(&mut o),
                            fr,
                        );
                        pixels.history_rejected += lost;
                        o.into()
                    }
                    Method::Taa | Method::Spatial => {
                        let mut o: [Plane<f32>; 4] = scratch.planes(w, h);
                        let lost = reproject(
                            [src(R), src(R + 1), src(R + 2), src(W)],
                            motion,
                            None,
                            w,
                            h,
                            slices_mut(&mut o),
                            fr,
                        );
                        pixels.history_reset += lost;
                        o.into()
                    }
                }
            },
        );
        if reprojected.is_none() && stateful {
            pixels.history_reset += (w * h) as u64;
        }

        // Spatiotemporal: per-pixel confidence from the filtered gradient, and this frame's
        // raw gradient (stored as the newest past gradient).
        let mut conf = scratch.plane(w, h);
        let mut grad_now = scratch.plane(w, h);
        rec.stage(
            "gradient",
            (method != Method::Spatiotemporal).then_some(variant.clone()),
            || {
                gradients(
                    &sparse,
                    reprojected.as_deref(),
                    frac.data(),
                    w,
                    h,
                    p.gradient_scale,
                    grad_now.data_mut(),
                    conf.data_mut(),
                    scratch,
                )
            },
        );

        let mut out: Rgb = scratch.planes(w, h);
        rec.run("blend", || {
            let hist = reprojected.as_deref();
            let fr = frac.data();
            match method {
                Method::Spatial => spatial::upsample(&sparse, &geo, p.kernel_wide, &mut out),
                Method::Spatiotemporal => {
                    let (c, g0) = (conf.data(), grad_now.data());
                    let [o0, o1, o2] = slices_mut(&mut out);
                    let mut it = next.iter_mut();
                    let n: [&mut [f32]; 11] =
                        std::array::from_fn(|_| it.next().expect("11 planes").data_mut());
                    let [n0, n1, n2, nw, nd, ni, ng1, ng2, ng3, nlk, nk] = n;
                    for_rows(
                        [o0, o1, o2, n0, n1, n2, nw, nd, ni, ng1, ng2, ng3, nlk, nk],
                        w,
                        |y, [or, og, ob, hr, hg, hb, hw, hd, hi, g1, g2, g3, lk, kn]| {
                            for x in 0..w {
                                let i = y * w + x;
                                let sigma = p.kernel_sharp + (1.0 - c[i]) * (p.kernel_wide - p.kernel_sharp);
                                let s = sparse.gather(&geo, x, y, sigma);
                                let (prev, wh, pg) = match hist {
                                    Some(hp) => (
                                        [hp[0].data()[i], hp[1].data()[i], hp[2].data()[i]],
                                        c[i] * hp[3].data()[i] * fr[i],
                                        [hp[4].data()[i], hp[5].data()[i]],
                                    ),
                                    None => ([0.0; 3], 0.0, [1.0, 1.0]),
                                };
                                let total = s.weight + wh;
                                let v = [0, 1, 2].map(|k| {
                                    if total > 0.0 {
                                        (s.sum[k] + wh * prev[k]) / total
                                    } else {
                                        0.0
                                    }
                                });
                                (or[x], og[x], ob[x]) = (v[0], v[1], v[2]);
                                (hr[x], hg[x], hb[x]) = (v[0], v[1], v[2]);
                                hw[x] = decay * total;
                                hd[x] = depth.map_or(0.0, |d| d[i]);
                                hi[x] = ids.map_or(0.0, |d| d[i] as f32);
                                (g1[x], g2[x], g3[x]) = (g0[i], pg[0], pg[1]);
                                (lk[x], kn[x]) = match (sparse.own(x, y, w, h), hist) {
                                    (Some(k), _) => (luma(sparse.color.map(|p| p[k])), 1.0),
                                    (None, Some(hp)) => (hp[7].data()[i], hp[8].data()[i]),
                                    (None, None) => (0.0, 0.0),
                                };
                            }
                        },
                    );
                }
                Method::Temporal => {
                    let [o0, o1, o2] = slices_mut(&mut out);
                    let mut it = next.iter_mut();
                    let n: [&mut [f32]; 5] = std::array::from_fn(|_| it.next().expect("5 planes").data_mut());
                    let [n0, n1, n2, nd, ni] = n;
                    let holes: PixelCounts = par_rows(
                        [o0, o1, o2, n0, n1, n2, nd, ni],
                        w,
                        |y, [or, og, ob, hr, hg, hb, hd, hi]| {
                            let mut c = PixelCounts::default();
                            for x in 0..w {
                                let i = y * w + x;
                                let v = match (sparse.own(x, y, w, h), hist) {
                                    (Some(k), _) => sparse.color.map(|p| p[k]),
                                    (None, Some(hp)) if fr[i] >= 0.5 => {
                                        [hp[0].data()[i], hp[1].data()[i], hp[2].data()[i]]
                                    }
                                    _ => {
                                        c.history_reset += 1;
                                        sparse
                                            .gather(&geo, x, y, p.kernel_wide)
                                            .mean()
                                            .unwrap_or([0.0; 3])
                                    }
                                };
                                (or[x], og[x], ob[x]) = (v[0], v[1], v[2]);
                                (hr[x], hg[x], hb[x]) = (v[0], v[1], v[2]);
                                hd[x] = depth.map_or(0.0, |d| d[i]);
                                hi[x] = ids.map_or(0.0, |d| d[i] as f32);
                            }
                            c
                        },
                    );
                    pixels.history_reset += holes.history_reset;
                }
                Method::Taa => {
                    let taa_kernel: Vec<f32> =
                        (0..81).map(|o| (-TAA_KERNEL * sparse.dist2(o)).exp()).collect();
                    let taa_kernel = &taa_kernel;
                    let [o0, o1, o2] = slices_mut(&mut out);
                    let mut it = next.iter_mut();
                    let n: [&mut [f32]; 4] = std::array::from_fn(|_| it.next().expect("4 planes").data_mut());
                    let [n0, n1, n2, nn] = n;
                    let clipped: PixelCounts = par_rows(
                        [o0, o1, o2, n0, n1, n2, nn],
                        w,
                        |y, [or, og, ob, hr, hg, hb, hn]| {
                            let mut counts = PixelCounts::default();
                            for x in 0..w {
                                let i = y * w + x;
                                let (mut sum, mut wsum, mut beta) = ([0.0f32; 3], 0.0f32, 0.0f32);
                                let (mut lo, mut hi) = ([f32::INFINITY; 3], [f32::NEG_INFINITY; 3]);
                                sparse.for_each_near(x, y, w, h, |k, _, o| {
                                    let wt = taa_kernel[o];
                                    beta = beta.max(wt);
                                    wsum += wt;
                                    for c in 0..3 {
                                        let v = sparse.color[c][k];
                                        sum[c] += wt * v;
                                        lo[c] = lo[c].min(v);
                                        hi[c] = hi[c].max(v);
                                    }
                                });
                                let up = if wsum > 0.0 {
                                    sum.map(|s| s / wsum)
                                } else {
                                    [0.0; 3]
                                };
                                let n = match hist {
                                    Some(hp) if fr[i] > 0.0 && wsum > 0.0 => hp[3].data()[i],
                                    _ => 0.0,
                                };
                                let (v, count) = if n <= 0.0 {
                                    (up, beta)
                                } else {
                                    let hp = hist.expect("n > 0 needs history");
                                    let mut moved = false;
                                    let hv = [0, 1, 2].map(|c| {
                                        let v = hp[c].data()[i];
                                        let cl = v.clamp(lo[c], hi[c]);
                                        moved |= cl != v;
                                        cl
                                    });
                                    counts.history_clipped += moved as u64;
                                    let a = beta * p.taa_alpha.max(1.0 / (n + 1.0));
                                    (
                                        [0, 1, 2].map(|c| a * up[c] + (1.0 - a) * hv[c]),
                                        (n + beta).min(TAA_MAX_COUNT),
                                    )
                                };
                                (or[x], og[x], ob[x]) = (v[0], v[1], v[2]);
                                (hr[x], hg[x], hb[x]) = (v[0], v[1], v[2]);
                                hn[x] = count;
                            }
                            counts
                        },
                    );
                    pixels.history_clipped += clipped.history_clipped;
                }
            }
        });

        scratch.recycle([frac, conf, grad_now]);
        scratch.recycle(reprojected.into_iter().flatten());
        let bytes = if stateful {
            self.hist.swap();
            self.hist.bytes()
        } else {
            0
        };
        Ok(Output {
            color: out,
            record: rec.finish(Self::NAME, frame.meta.index, pixels, inp.counts, bytes),
        })
    }

    fn reset(&mut self) {
        self.hist.reset();
    }

    fn recycle(&mut self, planes: Rgb) {
        self.scratch.recycle(planes);
    }

    fn state_bytes(&self) -> usize {
        self.hist.bytes()
    }
}

/// Seed 001, sec. 3.4: this frame's relative luma gradient at every shaded sample, against
/// the luma of the same surface point's previous shaded sample (1 where there is none since
/// a disocclusion or reset: unknown counts as maximal), spread to the pixels
/// of its block (and 1 at any pixel whose own history is invalid), filtered over time with
/// the three previous gradients (weights 4, 3, 2, 1; 1 where unknown) and over a box of
/// `2r + 1` pixels, `r = max(1, factor / 2)`, slightly larger than the block; `conf` gets
/// the confidence, `now` the unfiltered gradient to store.
#[allow(clippy::too_many_arguments)]
fn gradients(
    sparse: &Sparse,
    hist: Option<&[Plane<f32>]>,
    frac: &[f32],
    w: usize,
    h: usize,
    scale: f32,
    now: &mut [f32],
    conf: &mut [f32],
    scratch: &mut Scratch,
) {
    let s = sparse.sampling;
    let f = s.factor as usize;
    // Raw gradient of each pixel: its block's sample's, or 1 where its own history is lost.
    for_rows([&mut *now], w, |y, [row]| {
        let b = sparse.cell(y, s.phase[1]).max(0);
        for x in 0..w {
            let i = y * w + x;
            let a = sparse.cell(x, s.phase[0]).max(0);
            row[x] = match (hist, sparse.sample(a, b, w, h)) {
                (Some(hp), Some((k, j))) if frac[j] >= 0.5 && frac[i] >= 0.5 => {
                    let l = luma(sparse.color.map(|p| p[k]));
                    // The same point's last shaded luma when known, else the paper's
                    // reconstruction of the previous frame.
                    let known = hp[8].data()[j];
                    let before = if known >= 0.5 {
                        hp[7].data()[j] / known
                    } else {
                        luma([hp[0].data()[j], hp[1].data()[j], hp[2].data()[j]])
                    };
                    relative_gradient(l, before)
                }
                // A repaired (invalid) sample says nothing: keep trusting history.
                (Some(_), None) if sparse.invalid.is_some() && frac[i] >= 0.5 => 0.0,
                _ => 1.0,
            };
        }
    });
    // Temporal filter, weights 4, 3, 2, 1 over now and the three previous gradients.
    let mut filtered = scratch.plane(w, h);
    let total: f32 = GRADIENT_WEIGHTS.iter().sum();
    let now_ro: &[f32] = now;
    for_rows([filtered.data_mut()], w, |y, [row]| {
        for x in 0..w {
            let i = y * w + x;
            // Unknown past gradients (no history) count as maximal.
            let past = hist.map_or([1.0; 3], |hp| [hp[4].data()[i], hp[5].data()[i], hp[6].data()[i]]);
            row[x] = (GRADIENT_WEIGHTS[0] * now_ro[i]
                + GRADIENT_WEIGHTS[1] * past[0]
                + GRADIENT_WEIGHTS[2] * past[1]
                + GRADIENT_WEIGHTS[3] * past[2])
                / total;
        }
    });
    // Spatial box, then the confidence.
    let r = (f / 2).max(1) as isize;
    let src = filtered.data();
    for_rows([conf], w, |y, [row]| {
        for x in 0..w {
            let (mut sum, mut n) = (0.0f32, 0u32);
            for dy in -r..=r {
                let yy = y as isize + dy;
                if yy < 0 || yy >= h as isize {
                    continue;
                }
                for dx in -r..=r {
                    let xx = x as isize + dx;
                    if xx < 0 || xx >= w as isize {
                        continue;
                    }
                    sum += src[yy as usize * w + xx as usize];
                    n += 1;
                }
            }
            row[x] = confidence(sum / n as f32, scale);
        }
    });
    scratch.recycle([filtered]);
}
