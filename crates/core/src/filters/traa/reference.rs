//! The scalar reference of `traa`: one whole-plane pass per stage, exactly as the filter
//! was first written. The fused band kernel (`kernel.rs`) must give the same output
//! (the tests compare them frame by frame); this stays the readable statement of what the
//! filter computes.

use super::super::passes::{
    from_working, on_screen, output_ceiling, reference_filter, sharpen, slices_mut, tonemap_stage,
    FrameContext, FrameResult, Reprojection, TemporalState,
};
use super::{
    feedback, mix, Params, Traa, Variant, DEPTH01, DEPTH_DISTANCE_MIN, SHARPEN_BASELINE, SHARPEN_IMPROVED,
    SOBEL, SOBEL_LIT_WEIGHT, SOBEL_UNLIT_WEIGHT,
};
use crate::frame::{ChannelKind, Frame, Plane, Rgb};
use crate::kernels::{
    bilinear, clamp_to_box, clip_toward_center, for_each_row_stats, gather3x3, luma, sobel_plane, CROSS,
};
use crate::pipeline::exec::{for_rows, par_rows};
use crate::pipeline::{FilterError, PixelCounts, Skip};
use std::borrow::Cow;

reference_filter!(
    /// `traa` computed stage by stage over whole planes.
    ReferenceTraa, Traa, clone, |p| TemporalState::new(Traa::history_planes(p), false)
);

/// One frame's stages, from `tonemap` to `untonemap`, with the parameters `p`.
fn stages(p: &Params, frame: &Frame, ctx: FrameContext) -> Result<FrameResult, FilterError> {
    let improved = p.variant == Variant::Improved;
    let (inp, rec, has_history, read, next, scratch) = ctx.into_parts();
    let (w, h) = (inp.width, inp.height);
    let working = tonemap_stage(rec, &inp, scratch);
    let variant_skip = (!improved).then_some(Skip::Variant {
        variant: p.variant.name(),
    });
    // Depth normalised by the far plane (or the largest depth), for eq. 4.4-4.6 and 4.9.
    let depth01: Option<Plane<f32>> = inp.depth.as_deref().filter(|_| improved).map(|d| {
        let far = frame
            .meta
            .near_far
            .map(|nf| nf[1])
            .unwrap_or_else(|| d.data().iter().fold(0.0f32, |a, &v| a.max(v)))
            .max(f32::MIN_POSITIVE);
        d.map(|v| v / far)
    });

    let no_history = (!has_history).then_some(Skip::NoHistory);
    let reprojection = Reprojection::plan(rec, &inp, has_history, true, scratch);
    let n_hist = read.len();
    // Reprojected history (bilinear, as INSIDE samples its history buffer) and whether
    // each pixel's previous position was on screen.
    let reprojected: Option<(Vec<Plane<f32>>, Vec<bool>)> =
        rec.stage("reproject", reprojection.skip.clone(), || {
            let m = reprojection.motion(&inp);
            let mut out: Vec<Plane<f32>> = (0..n_hist).map(|_| scratch.plane(w, h)).collect();
            let mut valid = vec![false; w * h];
            // One position per pixel; the colour planes, then (improved) Sobel and depth.
            let src: Vec<&[f32]> = read.iter().map(|p| p.data()).collect();
            let (rgb_out, extra_out) = out.split_at_mut(3);
            let [r, g, b] = rgb_out else {
                unreachable!("three colour planes")
            };
            for_rows([r.data_mut(), g.data_mut(), b.data_mut()], w, |y, [r, g, b]| {
                for x in 0..w {
                    let i = y * w + x;
                    let (px, py) = (x as f32 + 0.5 + m[0][i], y as f32 + 0.5 + m[1][i]);
                    [r[x], g[x], b[x]] = bilinear([src[0], src[1], src[2]], w, h, px, py);
                }
            });
            if let [sob, dep] = extra_out {
                for_rows([sob.data_mut(), dep.data_mut()], w, |y, [s, d]| {
                    for x in 0..w {
                        let i = y * w + x;
                        let (px, py) = (x as f32 + 0.5 + m[0][i], y as f32 + 0.5 + m[1][i]);
                        [s[x], d[x]] = bilinear([src[SOBEL], src[DEPTH01]], w, h, px, py);
                    }
                });
            }
            crate::pipeline::exec::pool().install(|| {
                use rayon::prelude::*;
                valid.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
                    for (x, v) in row.iter_mut().enumerate() {
                        let i = y * w + x;
                        *v = on_screen(x as f32 + 0.5 + m[0][i], y as f32 + 0.5 + m[1][i], w, h);
                    }
                })
            });
            (out, valid)
        });
    let (hist, valid): (Vec<&[f32]>, Option<&[bool]>) = match &reprojected {
        Some((planes, valid)) => (planes.iter().map(|p| p.data()).collect(), Some(valid)),
        None => (read.iter().map(|p| p.data()).collect(), None),
    };
    let history_at = |i: usize| has_history && valid.is_none_or(|v| v[i]);

    let raw_sobel = rec.stage("sobel", variant_skip.clone(), || {
        sobel_edges(&working, inp.albedo.as_deref(), depth01.as_ref())
    });
    // The Sobel image's own TRAA (sec. 4.3.3): clamp into the averaged cross/3x3 range
    // of the raw Sobel, INSIDE's feedback, no sharpen.
    let sobel: Option<Cow<Plane<f32>>> = match raw_sobel {
        None => None,
        Some(raw) => {
            let stable = rec.stage("sobel_history", no_history.clone(), || {
                let mut out = Plane::new(w, h);
                let r = raw.data();
                for_rows([out.data_mut()], w, |y, [row]| {
                    for x in 0..w {
                        let i = y * w + x;
                        if !history_at(i) {
                            row[x] = r[i];
                            continue;
                        }
                        if inp.is_invalid(i) {
                            // No usable colour here this frame: keep the edge history.
                            row[x] = hist[SOBEL][i];
                            continue;
                        }
                        let t = gather3x3(r, w, h, x, y);
                        let (mut lo3, mut hi3) = (f32::INFINITY, f32::NEG_INFINITY);
                        let (mut lo_x, mut hi_x) = (f32::INFINITY, f32::NEG_INFINITY);
                        for (j, &v) in t.iter().enumerate() {
                            lo3 = lo3.min(v);
                            hi3 = hi3.max(v);
                            if CROSS.contains(&j) {
                                lo_x = lo_x.min(v);
                                hi_x = hi_x.max(v);
                            }
                        }
                        let (hv, _) = clamp_to_box(hist[SOBEL][i], 0.5 * (lo3 + lo_x), 0.5 * (hi3 + hi_x));
                        let k = feedback(r[i], hv, p.feedback_min, p.feedback_max);
                        row[x] = mix(r[i], hv, k);
                    }
                });
                out
            });
            Some(stable.map_or(Cow::Owned(raw), Cow::Owned))
        }
    };

    // Eq. 4.1: modelAverage.
    let model_average = rec.stage(
        "model_average",
        variant_skip
            .clone()
            .or_else(|| inp.require(ChannelKind::ObjectId)),
        || model_average(inp.object_id.expect("required")),
    );
    // Eq. 4.4-4.6: depth pseudo-variance plus temporal pseudo-variance.
    let depth_variance = rec.stage(
        "depth_variance",
        variant_skip.clone().or_else(|| inp.require(ChannelKind::Depth)),
        || {
            let d = depth01.as_ref().expect("with depth");
            depth_variance(d, has_history.then(|| hist[DEPTH01]), &history_at)
        },
    );
    // Eq. 4.12-4.14.
    let aliased = rec.stage("aliased", variant_skip.clone(), || {
        aliased(
            w,
            h,
            sobel.as_deref(),
            model_average.as_ref(),
            depth_variance.as_ref(),
        )
    });

    let mut out: Rgb = scratch.planes(w, h);
    let al = aliased.as_ref().map(|p| p.data());
    let counts = rec.run("resolve", || {
        let cur = working.each_ref().map(|p| p.data());
        let [o0, o1, o2] = slices_mut(&mut out);
        let mut it = next.iter_mut();
        let n3: [&mut [f32]; 3] = std::array::from_fn(|_| it.next().expect("3 planes").data_mut());
        let [n0, n1, n2] = n3;
        par_rows([o0, o1, o2, n0, n1, n2], w, |y, [or, og, ob, nr, ng, nb]| {
            let mut c = PixelCounts::default();
            for_each_row_stats(cur, w, h, y, |x, s| {
                let i = y * w + x;
                let current = [cur[0][i], cur[1][i], cur[2][i]];
                let (lo, hi) = if improved && history_at(i) {
                    let a = al.map_or(0.0, |al| al[i]);
                    let mut lo = [0.0; 3];
                    let mut hi = [0.0; 3];
                    for k in 0..3 {
                        // Eq. 4.15 then eq. 4.16.
                        let cmin = mix(s.min_cross[k], s.min[k], a);
                        let cmax = mix(s.max_cross[k], s.max[k], a);
                        lo[k] = mix(current[k], cmin, a);
                        hi[k] = mix(current[k], cmax, a);
                    }
                    (lo, hi)
                } else {
                    (
                        [0, 1, 2].map(|k| 0.5 * (s.min[k] + s.min_cross[k])),
                        [0, 1, 2].map(|k| 0.5 * (s.max[k] + s.max_cross[k])),
                    )
                };
                let value = if history_at(i) && inp.is_invalid(i) {
                    // No usable sample here this frame: keep the history as it is.
                    [hist[0][i], hist[1][i], hist[2][i]]
                } else if history_at(i) {
                    let (hc, moved) = clip_toward_center([hist[0][i], hist[1][i], hist[2][i]], lo, hi);
                    c.history_clipped += moved as u64;
                    let k = feedback(luma(current), luma(hc), p.feedback_min, p.feedback_max);
                    [0, 1, 2].map(|j| mix(current[j], hc[j], k).max(0.0))
                } else {
                    c.history_reset += 1;
                    current
                };
                (nr[x], ng[x], nb[x]) = (value[0], value[1], value[2]);
                (or[x], og[x], ob[x]) = (value[0], value[1], value[2]);
            });
            c
        })
    });
    if improved {
        if let Some(s) = &sobel {
            next[SOBEL].data_mut().copy_from_slice(s.data());
        }
        if let Some(d) = &depth01 {
            next[DEPTH01].data_mut().copy_from_slice(d.data());
        }
    }
    let strength = if improved {
        SHARPEN_IMPROVED
    } else {
        SHARPEN_BASELINE
    };
    if let Some(s) = rec.stage(
        "sharpen",
        (!p.sharpen).then_some(Skip::Disabled { param: "sharpen" }),
        || sharpen(&out, strength, output_ceiling(&inp.facts), scratch),
    ) {
        scratch.recycle(std::mem::replace(&mut out, s));
    }
    rec.stage("untonemap", inp.facts.tonemap(), || from_working(&mut out, true));
    scratch.recycle(reprojection.dilated.into_iter().flatten());
    scratch.recycle(reprojected.into_iter().flat_map(|(planes, _)| planes));
    if let Cow::Owned(w) = working {
        scratch.recycle(w);
    }
    Ok(FrameResult {
        color: out,
        pixels: counts,
        model: None,
    })
}

/// Raw Sobel edge value per pixel (eq. 4.9-4.10) from the working colour, the albedo and
/// depth / far, each optional but the colour.
fn sobel_edges(working: &Rgb, albedo: Option<&Rgb>, depth01: Option<&Plane<f32>>) -> Plane<f32> {
    let (w, h) = working[0].size();
    let luma_of = |rgb: &Rgb| {
        let [r, g, b] = rgb.each_ref().map(|p| p.data());
        Plane::from_vec(w, h, (0..w * h).map(|i| luma([r[i], g[i], b[i]])).collect()).expect("sized")
    };
    let lit = luma_of(working);
    let unlit = albedo.map(luma_of);
    let mut out = Plane::new(w, h);
    for_rows([out.data_mut()], w, |y, [row]| {
        let mut l = vec![0.0; w];
        sobel_plane(lit.data(), w, h, y, &mut l);
        let u = unlit.as_ref().map(|p| {
            let mut u = vec![0.0; w];
            sobel_plane(p.data(), w, h, y, &mut u);
            u
        });
        let d = depth01.map(|p| {
            let mut d = vec![0.0; w];
            sobel_plane(p.data(), w, h, y, &mut d);
            d
        });
        for x in 0..w {
            let surface = match &u {
                Some(u) => SOBEL_UNLIT_WEIGHT * u[x] + SOBEL_LIT_WEIGHT * l[x],
                None => l[x],
            };
            let g = (surface + d.as_ref().map_or(0.0, |d| d[x])).clamp(0.0, 1.0);
            row[x] = (g * g * (3.0 - 2.0 * g)).sqrt();
        }
    });
    out
}

/// Eq. 4.1: per pixel, the share of its 3x3 (centre included, so at most 8/9) whose
/// object id differs from its own.
fn model_average(ids: &Plane<u32>) -> Plane<f32> {
    let (w, h) = ids.size();
    let id = ids.data();
    let mut out = Plane::new(w, h);
    for_rows([out.data_mut()], w, |y, [row]| {
        for x in 0..w {
            let me = id[y * w + x];
            let mut diff = 0u32;
            for yy in y.saturating_sub(1)..=(y + 1).min(h - 1) {
                for xx in x.saturating_sub(1)..=(x + 1).min(w - 1) {
                    diff += (id[yy * w + xx] != me) as u32;
                }
            }
            // Edge pixels count their clamped neighbours as the same object, as a clamped
            // texture fetch would.
            row[x] = diff as f32 / 9.0;
        }
    });
    out
}

/// Eq. 4.4-4.6 summed: depth pseudo-variance `(|z - avg| / maxDist)^2` plus temporal
/// pseudo-variance `(|z_prev - avg| / maxDist)^4`, both zero where `maxDist =
/// min(|min - avg|, |max - avg|)` is below 0.002. `prev` is the reprojected depth / far of
/// the previous frame (used where `has_prev(i)`).
fn depth_variance(
    d: &Plane<f32>,
    prev: Option<&[f32]>,
    has_prev: &(dyn Fn(usize) -> bool + Sync),
) -> Plane<f32> {
    let (w, h) = d.size();
    let dd = d.data();
    let mut out = Plane::new(w, h);
    for_rows([out.data_mut()], w, |y, [row]| {
        for x in 0..w {
            let i = y * w + x;
            let t = gather3x3(dd, w, h, x, y);
            let (mut lo, mut hi, mut sum) = (f32::INFINITY, f32::NEG_INFINITY, 0.0);
            for &v in &t {
                lo = lo.min(v);
                hi = hi.max(v);
                sum += v;
            }
            let avg = sum / 9.0;
            let max_dist = (lo - avg).abs().min((hi - avg).abs());
            row[x] = if max_dist < DEPTH_DISTANCE_MIN {
                0.0
            } else {
                let pv = ((dd[i] - avg).abs() / max_dist).powi(2);
                let tpv = match prev {
                    Some(p) if has_prev(i) => ((p[i] - avg).abs() / max_dist).powi(4),
                    _ => 0.0,
                };
                // Outliers can make these huge; eq. 4.14 clamps the sum to 1 anyway.
                (pv + tpv).min(1.0)
            };
        }
    });
    out
}

/// Eq. 4.12-4.14: `aliasedValue = clamp01(sobelAvg + depth terms + modelAverage)` with
/// `sobelAvg = mix(sobelAvgCross, sobelAvg3x3, clamp01(modelAverage + sobel))` on the
/// stabilised Sobel image. Absent terms are 0.
fn aliased(
    w: usize,
    h: usize,
    sobel: Option<&Plane<f32>>,
    model_average: Option<&Plane<f32>>,
    depth_variance: Option<&Plane<f32>>,
) -> Plane<f32> {
    let mut out = Plane::new(w, h);
    for_rows([out.data_mut()], w, |y, [row]| {
        for x in 0..w {
            let i = y * w + x;
            let ma = model_average.map_or(0.0, |p| p.data()[i]);
            let sobel_avg = sobel.map_or(0.0, |s| {
                let t = gather3x3(s.data(), w, h, x, y);
                let avg3 = t.iter().sum::<f32>() / 9.0;
                let avg_cross = CROSS.iter().map(|&j| t[j]).sum::<f32>() / 5.0;
                mix(avg_cross, avg3, (ma + t[4]).clamp(0.0, 1.0))
            });
            let dv = depth_variance.map_or(0.0, |p| p.data()[i]);
            row[x] = (sobel_avg + dv + ma).clamp(0.0, 1.0);
        }
    });
    out
}
