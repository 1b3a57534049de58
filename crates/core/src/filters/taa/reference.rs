//! The scalar reference of `taa`: one whole-plane pass per stage, exactly as the filter
//! was first written. The fused band kernel (`kernel.rs`) must give the same output
//! (the tests compare them frame by frame); this stays the readable statement of what the
//! filter computes.

use super::super::passes::{
    from_working, on_screen, output_ceiling, reference_filter, sharpen, slices_mut, to_ycocg, tonemap_stage,
    FrameContext, FrameResult, Reprojection, TemporalState,
};
use super::{HistoryFilter, Params, Taa, MAX_COUNT};
use crate::frame::{ChannelKind, Frame, Plane, Rgb};
use crate::kernels::{
    bilinear, catmull_rom, clip_toward_center, for_each_row_stats, variance_box, ycocg_to_rgb,
};
use crate::pipeline::exec::{for_rows, par_rows};
use crate::pipeline::{FilterError, PixelCounts, Skip};

/// History planes of the reference (the filter itself keeps Y, Co, Cg and the count
/// interleaved in one plane, and depth in a second).
const Y: usize = 0;
const CO: usize = 1;
const CG: usize = 2;
const COUNT: usize = 3;
const DEPTH: usize = 4;

reference_filter!(
    /// `taa` computed stage by stage over whole planes.
    ReferenceTaa, Taa, clone, |p| TemporalState::new(Taa::history_planes(p), true)
);

/// One frame's stages, from `tonemap` to `untonemap`, with the parameters `p`.
fn stages(p: &Params, _frame: &Frame, ctx: FrameContext) -> Result<FrameResult, FilterError> {
    let (inp, rec, has_history, read, next, scratch) = ctx.into_parts();
    let (w, h) = (inp.width, inp.height);
    let working = tonemap_stage(rec, &inp, scratch);

    let ycocg: Rgb = rec.run("ycocg", || to_ycocg(&working, scratch));

    let no_history = (!has_history).then_some(Skip::NoHistory);
    let reprojection = Reprojection::plan(rec, &inp, has_history, p.dilation, scratch);
    let n_hist = read.len();
    let reprojected: Option<Vec<Plane<f32>>> = rec.stage("reproject", reprojection.skip.clone(), || {
        let m = reprojection.motion(&inp);
        let src: Vec<&[f32]> = read.iter().map(|p| p.data()).collect();
        let mut out: Vec<Plane<f32>> = (0..n_hist).map(|_| scratch.plane(w, h)).collect();
        let filter = p.history_filter;
        let rows = {
            let mut it = out.iter_mut();
            let a: [&mut [f32]; 4] = std::array::from_fn(|_| it.next().expect("4 planes").data_mut());
            (a, it.next().map(|p| p.data_mut()))
        };
        let (four, depth_out) = rows;
        // Depth (when kept) is resampled bilinearly in a second, cheap loop below.
        for_rows(four, w, |y, [hy, hco, hcg, hn]| {
            for x in 0..w {
                let i = y * w + x;
                let px = x as f32 + 0.5 + m[0][i];
                let py = y as f32 + 0.5 + m[1][i];
                if !on_screen(px, py, w, h) {
                    hn[x] = 0.0;
                    continue;
                }
                let c = match filter {
                    HistoryFilter::CatmullRom => catmull_rom([src[Y], src[CO], src[CG]], w, h, px, py),
                    HistoryFilter::Bilinear => bilinear([src[Y], src[CO], src[CG]], w, h, px, py),
                };
                [hy[x], hco[x], hcg[x]] = c;
                hn[x] = bilinear([src[COUNT]], w, h, px, py)[0];
            }
        });
        if let Some(d) = depth_out {
            for_rows([d], w, |y, [row]| {
                for x in 0..w {
                    let i = y * w + x;
                    row[x] = bilinear(
                        [src[DEPTH]],
                        w,
                        h,
                        x as f32 + 0.5 + m[0][i],
                        y as f32 + 0.5 + m[1][i],
                    )[0];
                }
            });
        }
        out
    });
    let hist: Vec<&[f32]> = match &reprojected {
        Some(r) => r.iter().map(|p| p.data()).collect(),
        None => read.iter().map(|p| p.data()).collect(),
    };

    let mut pixels = PixelCounts::default();
    let reject: Option<Vec<bool>> = rec.stage(
        "depth_reject",
        (p.depth_rejection <= 0.0)
            .then_some(Skip::Disabled {
                param: "depth_rejection",
            })
            .or_else(|| inp.require(ChannelKind::Depth))
            .or_else(|| no_history.clone()),
        || {
            let d = inp.depth.as_deref().expect("required").data();
            let prev = hist[DEPTH];
            d.iter()
                .zip(prev)
                .map(|(&d, &dp)| (dp - d).abs() > p.depth_rejection * d.abs().max(1e-6))
                .collect()
        },
    );
    if let Some(r) = &reject {
        pixels.history_rejected = r.iter().filter(|&&b| b).count() as u64;
    }

    let mut out: Rgb = scratch.planes(w, h);
    let counts = rec.run("resolve", || {
        let cur = ycocg.each_ref().map(|p| p.data());
        let [o0, o1, o2] = slices_mut(&mut out);
        let mut it = next.iter_mut();
        let n4: [&mut [f32]; 4] = std::array::from_fn(|_| it.next().expect("4 planes").data_mut());
        let [n0, n1, n2, n3] = n4;
        let counts = par_rows(
            [o0, o1, o2, n0, n1, n2, n3],
            w,
            |y, [or, og, ob, ny, nco, ncg, nn]| {
                let mut c = PixelCounts::default();
                for_each_row_stats(cur, w, h, y, |x, stats| {
                    let i = y * w + x;
                    let current = [cur[0][i], cur[1][i], cur[2][i]];
                    let n = if has_history && !reject.as_ref().is_some_and(|r| r[i]) {
                        hist[COUNT][i]
                    } else {
                        0.0
                    };
                    let (value, count) = if n < 0.5 {
                        c.history_reset += 1;
                        (current, 1.0)
                    } else if inp.is_invalid(i) {
                        // No usable sample here this frame: keep the history as it is.
                        ([hist[Y][i], hist[CO][i], hist[CG][i]], n)
                    } else {
                        let (lo, hi) = variance_box(stats, p.gamma);
                        let (h, moved) = clip_toward_center([hist[Y][i], hist[CO][i], hist[CG][i]], lo, hi);
                        c.history_clipped += moved as u64;
                        let a = p.alpha.max(1.0 / (n + 1.0));
                        let (wc, wh) = if p.luminance_weighting {
                            (a / (1.0 + current[0].max(0.0)), (1.0 - a) / (1.0 + h[0].max(0.0)))
                        } else {
                            (a, 1.0 - a)
                        };
                        let k = 1.0 / (wc + wh);
                        let v = [0, 1, 2].map(|j| (wc * current[j] + wh * h[j]) * k);
                        (v, (n + 1.0).min(MAX_COUNT))
                    };
                    [ny[x], nco[x], ncg[x]] = value;
                    nn[x] = count;
                    let rgb = ycocg_to_rgb(value);
                    (or[x], og[x], ob[x]) = (rgb[0].max(0.0), rgb[1].max(0.0), rgb[2].max(0.0));
                });
                c
            },
        );
        if let (Some(d), Some(nd)) = (inp.depth.as_deref(), next.get_mut(DEPTH)) {
            nd.data_mut().copy_from_slice(d.data());
        }
        counts
    });
    pixels.history_reset += counts.history_reset;
    pixels.history_clipped += counts.history_clipped;

    if let Some(s) = rec.stage(
        "sharpen",
        (p.sharpen <= 0.0).then_some(Skip::Disabled { param: "sharpen" }),
        || sharpen(&out, p.sharpen, output_ceiling(&inp.facts), scratch),
    ) {
        scratch.recycle(std::mem::replace(&mut out, s));
    }
    rec.stage("untonemap", inp.facts.tonemap(), || from_working(&mut out, true));

    scratch.recycle(ycocg);
    scratch.recycle(reprojection.dilated.into_iter().flatten());
    scratch.recycle(reprojected.into_iter().flatten());
    if let std::borrow::Cow::Owned(w) = working {
        scratch.recycle(w);
    }
    Ok(FrameResult {
        color: out,
        pixels,
        model: None,
    })
}
