//! The scalar reference of `upsample`: one whole-plane pass per stage, exactly as the
//! filter was first written. The fused band kernels (`kernel.rs`) must give the same
//! output (the tests compare them frame by frame); this stays the readable statement of
//! what the filter computes.

use super::super::reconstruct::Reconstruction;
use super::spatial::{self, depth_range, Geometry, Sparse};
use super::temporal::{cancelled, confidence, filter_gradients, reproject, signed_gradient, Validity};
use super::{
    decay_for, Method, Params, Upsample, DEPTH, G1, ID, LK, R, TAA_KERNEL, TAA_MAX_COUNT, T_DEPTH, T_ID, W,
};
use crate::filters::passes::slices_mut;
use crate::frame::{ChannelKind, Frame, Plane, Rgb};
use crate::kernels::luma;
use crate::pipeline::exec::{for_rows, par_rows};
use crate::pipeline::{
    bind_size, check_channels, DoubleBuffer, FilterError, FilterKind, Output, PixelCounts, Recorder, Scratch,
    Skip,
};

/// `upsample` computed stage by stage over whole planes.
#[derive(Debug)]
pub struct ReferenceUpsample {
    params: Params,
    hist: DoubleBuffer,
    scratch: Scratch,
}

impl ReferenceUpsample {
    /// A fresh reference filter.
    pub fn new(params: Params) -> Self {
        ReferenceUpsample {
            hist: DoubleBuffer::new(params.method.planes()),
            scratch: Scratch::default(),
            params,
        }
    }

    /// Filters one frame.
    pub fn process(&mut self, frame: &Frame) -> Result<Output, FilterError> {
        check_channels(Upsample::NAME, Upsample::needs(), frame)?;
        let p = self.params.clone();
        let method = p.method;
        let mut rec = Recorder::new();
        let inp = Reconstruction::new(p.pixel_filter, p.filter_width).prepare(
            frame,
            Upsample::uses(),
            &mut rec,
            &mut self.scratch,
        )?;
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
            sky_depth_only: p.sky_depth_only,
        };

        let mut pixels = PixelCounts::default();
        let decay = decay_for(&p, sampling);
        let scratch = &mut self.scratch;
        let (read, next) = self.hist.split();
        let motion = inp.motion.as_deref().map(|m| m.each_ref().map(Plane::data));
        // Reprojected history: colour (+ weight or count, + the three past gradients) and
        // the share of valid taps.
        let mut frac = scratch.plane(w, h);
        // The part of `frac` kept for sub-pixel surfaces.
        let mut kept = scratch.plane(w, h);
        let reprojected: Option<Vec<Plane<f32>>> = rec.stage(
            "reproject",
            (!stateful)
                .then_some(variant.clone())
                .or_else(|| (!has_history).then_some(Skip::NoHistory)),
            || {
                let src = |k: usize| read[k].data();
                let fr = frac.data_mut();
                let kp = kept.data_mut();
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
                    neighbour_motion: if method == Method::Spatiotemporal {
                        p.neighbour_motion
                    } else {
                        0.0
                    },
                    subpixel: if method == Method::Spatiotemporal {
                        p.subpixel_keep
                    } else {
                        0.0
                    },
                    motion,
                    width: w,
                    height: h,
                };
                // The methods keep different numbers of history planes (the array length
                // differs), hence a macro rather than a closure.
                macro_rules! reproject_planes {
                    ($validity:expr, $($k:expr),+) => {{
                        let mut o = scratch.planes(w, h);
                        let lost = reproject([$(src($k)),+], motion, $validity, w, h, slices_mut(&mut o), fr, kp);
                        (Vec::from(o), lost)
                    }};
                }
                match method {
                    Method::Spatiotemporal => {
                        let (o, lost) = reproject_planes!(
                            Some(&validity),
                            R, R + 1, R + 2, W, G1, G1 + 1, G1 + 2, LK, LK + 1, LK + 2, LK + 3
                        );
                        pixels.history_rejected += lost;
                        o
                    }
                    Method::Temporal => {
                        let (o, lost) = reproject_planes!(Some(&validity), R, R + 1, R + 2);
                        pixels.history_rejected += lost;
                        o
                    }
                    Method::Taa | Method::Spatial => {
                        let (o, lost) = reproject_planes!(None, R, R + 1, R + 2, W);
                        pixels.history_reset += lost;
                        o
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
                    kept.data(),
                    p.subpixel_keep > 0.0,
                    w,
                    h,
                    p.gradient_scale,
                    p.gradient_cancel,
                    p.gradient_lag,
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
                    let n: [&mut [f32]; 13] =
                        std::array::from_fn(|_| it.next().expect("13 planes").data_mut());
                    let [n0, n1, n2, nw, nd, ni, ng1, ng2, ng3, nlk, nk, nlk2, nk2] = n;
                    for_rows(
                        [
                            o0, o1, o2, n0, n1, n2, nw, nd, ni, ng1, ng2, ng3, nlk, nk, nlk2, nk2,
                        ],
                        w,
                        |y, [or, og, ob, hr, hg, hb, hw, hd, hi, g1, g2, g3, lk, kn, lk2, kn2]| {
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
                                // The last shaded sample's luma and the one before it.
                                (lk[x], kn[x], lk2[x], kn2[x]) = match (sparse.own(x, y, w, h), hist) {
                                    (Some(k), Some(hp)) => (
                                        luma(sparse.color.map(|p| p[k])),
                                        1.0,
                                        hp[7].data()[i],
                                        hp[8].data()[i],
                                    ),
                                    (Some(k), None) => (luma(sparse.color.map(|p| p[k])), 1.0, 0.0, 0.0),
                                    (None, Some(hp)) => (
                                        hp[7].data()[i],
                                        hp[8].data()[i],
                                        hp[9].data()[i],
                                        hp[10].data()[i],
                                    ),
                                    (None, None) => (0.0, 0.0, 0.0, 0.0),
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

        scratch.recycle([frac, kept, conf, grad_now]);
        scratch.recycle(reprojected.into_iter().flatten());
        let bytes = if stateful {
            self.hist.swap();
            self.hist.bytes()
        } else {
            0
        };
        Reconstruction::new(self.params.pixel_filter, self.params.filter_width).sparse_output(
            &mut rec,
            &mut out,
            !sampling.is_full(),
            &mut self.scratch,
        );
        Ok(Output {
            color: out,
            record: rec.finish(Upsample::NAME, frame.meta.index, pixels, inp.counts, bytes),
        })
    }
}

/// Herzog et al. 2010, sec. 3.4: this frame's relative luma gradient at every shaded sample, against
/// the luma of the same surface point's previous shaded sample (1 where there is none since
/// a disocclusion or reset: unknown counts as maximal), spread to the pixels
/// of its block (and 1 at any pixel whose own history is invalid), filtered over time with
/// the three previous gradients (weights 4, 3, 2, 1; 1 where unknown) and over a box of
/// `2r + 1` pixels, `r = max(1, factor / 2)`, slightly larger than the block; `conf` gets
/// the confidence, `now` the unfiltered gradient to store (with its sign,
/// [`signed_gradient`]). Both filters run on the magnitudes (the paper's) and on the signed
/// values, where changes of random sign cancel; the confidence reads
/// [`cancelled`]`(magnitudes, signed, cancel)`. With `sub_grad` a sample whose history was
/// at least half kept for a sub-pixel surface (`kept`, `subpixel_keep`) has gradient 0:
/// nothing of its surface was there to compare with.
#[allow(clippy::too_many_arguments)]
fn gradients(
    sparse: &Sparse,
    hist: Option<&[Plane<f32>]>,
    frac: &[f32],
    kept: &[f32],
    sub_grad: bool,
    w: usize,
    h: usize,
    scale: f32,
    cancel: f32,
    lag: u32,
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
                // A sample whose history was kept for a sub-pixel surface: nothing to compare.
                (Some(_), Some((_, j)))
                    if frac[j] >= 0.5 && frac[i] >= 0.5 && sub_grad && kept[j] >= 0.5 * frac[j] =>
                {
                    0.0
                }
                (Some(hp), Some((k, j))) if frac[j] >= 0.5 && frac[i] >= 0.5 => {
                    let l = luma(sparse.color.map(|p| p[k]));
                    // The same point's last shaded luma when known, else the paper's
                    // reconstruction of the previous frame.
                    let (known, known2) = (hp[8].data()[j], hp[10].data()[j]);
                    let before = if lag == 2 && known2 >= 0.5 {
                        hp[9].data()[j] / known2
                    } else if known >= 0.5 {
                        hp[7].data()[j] / known
                    } else {
                        luma([hp[0].data()[j], hp[1].data()[j], hp[2].data()[j]])
                    };
                    signed_gradient(l, before)
                }
                // A repaired (invalid) sample says nothing: keep trusting history.
                (Some(_), None) if sparse.invalid.is_some() && frac[i] >= 0.5 => 0.0,
                _ => 1.0,
            };
        }
    });
    // Temporal filter, weights 4, 3, 2, 1 over now and the three previous gradients: of
    // their magnitudes (the paper's) and of the signed values.
    let mut filtered = scratch.plane(w, h);
    let mut signed = scratch.plane(w, h);
    let now_ro: &[f32] = now;
    for_rows([filtered.data_mut(), signed.data_mut()], w, |y, [row, srow]| {
        for x in 0..w {
            let i = y * w + x;
            // Unknown past gradients (no history) count as maximal.
            let past = hist.map_or([1.0; 3], |hp| [hp[4].data()[i], hp[5].data()[i], hp[6].data()[i]]);
            let g = [now_ro[i], past[0], past[1], past[2]];
            // The magnitudes' filter (the paper's) and the signed values' filter.
            row[x] = filter_gradients(g.map(f32::abs));
            srow[x] = filter_gradients(g);
        }
    });
    // Spatial box of both, then the confidence.
    let r = (f / 2).max(1) as isize;
    let (src, ssrc) = (filtered.data(), signed.data());
    for_rows([conf], w, |y, [row]| {
        for x in 0..w {
            let (mut sum, mut ssum, mut n) = (0.0f32, 0.0f32, 0u32);
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
                    ssum += ssrc[yy as usize * w + xx as usize];
                    n += 1;
                }
            }
            let n = n as f32;
            row[x] = confidence(cancelled(sum / n, ssum / n, cancel), scale);
        }
    });
    scratch.recycle([filtered, signed]);
}
