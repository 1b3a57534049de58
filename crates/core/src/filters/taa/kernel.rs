//! `taa`'s stages fused into one pass over bands of rows ([`par_bands`]): a band's working
//! colour and YCoCg (rows and their 3x3 halo) are computed into band-local buffers, then
//! each row is dilated, reprojected, tested for depth, resolved and brought back to linear
//! colour while its data is in cache. The full-plane temporaries of the reference (working
//! colour, YCoCg, dilated motion, reprojected history: 12 planes written and read again)
//! are gone, and the arithmetic of each stage runs in row loops the compiler vectorises.
//! The history fetch is a gather at each pixel's own position: its Catmull-Rom footprints
//! (tap positions and weights) are computed for eight pixels at once, and each pixel's
//! twelve taps are read and weighted two texels to an 8-float vector
//! ([`crate::kernels::catmull_rom_texel`], [`FootprintLanes::texels`]).
//!
//! Every stage computes what the reference ([`super::reference`]) computes, with the same
//! float operations in the same order, so the outputs are the same bits; the tests compare
//! them frame by frame.

use super::{HistoryFilter, Params, StagePlan, Taa, MAX_COUNT};
use crate::filters::passes::{
    dilate_row, from_working, on_screen_bits, output_ceiling, previous_positions, sharpen, tonemap_row,
    untonemap_row, FrameContext, FrameResult, FrameSlices,
};
use crate::frame::Rgb;
use crate::kernels::lanes::{self, block, Lanes, Mask, LANES};
use crate::kernels::{
    bilinear, bilinear_texels, box_from_columns, clip_toward_center, column_stats, rgb_to_ycocg,
    variance_box, ycocg_to_rgb, FootprintLanes, NeighborhoodStats, TEXEL,
};
use crate::pipeline::exec::{par_bands_strided, sized, stage_indices, Halo, StageClock};
use crate::pipeline::{FilterError, FilterKind, PixelCounts};
use std::ops::Range;
use wide::f32x8;

/// Stages of the fused pass, in order (indices into its [`StageClock`]): the filter's
/// stages less `repair` and `reconstruct` (run before it) and `sharpen` (a pass of its own).
const STAGES: [&str; 7] = {
    let s = <Taa as FilterKind>::STAGES;
    [s[2], s[3], s[4], s[5], s[6], s[7], s[9]]
};
stage_indices!(STAGES: TONEMAP, YCOCG, DILATE, REPROJECT, DEPTH_REJECT, RESOLVE, UNTONEMAP);

/// What the pass reads for one frame.
struct Sources<'a> {
    frame: FrameSlices<'a>,
    /// The history, when there is one.
    hist: Option<History<'a>>,
}

/// The previous frame's state: texels `[Y, Co, Cg, count]`, and depth with depth rejection.
#[derive(Clone, Copy)]
struct History<'a> {
    texels: &'a [f32],
    depth: Option<&'a [f32]>,
}

/// Which stages run, and the knobs of the resolve.
#[derive(Clone, Copy)]
struct Plan {
    tonemap: bool,
    dilate: bool,
    reproject: bool,
    depth_reject: bool,
    untonemap: bool,
    filter: HistoryFilter,
    knobs: Knobs,
}

/// Parameters of the per-pixel resolve.
#[derive(Clone, Copy)]
struct Knobs {
    alpha: f32,
    gamma: f32,
    luminance_weighting: bool,
    depth_rejection: f32,
}

/// One band task's buffers, reused across the bands it runs and across frames' tasks.
#[derive(Default)]
struct Band {
    /// YCoCg of the band's rows and one row above and below (clamped to the image).
    cur: [Vec<f32>; 3],
    /// The working colour of one row (tonemapped input).
    work: [Vec<f32>; 3],
    /// This row's motion (dilated).
    motion: [Vec<f32>; 2],
    /// This row's reprojected history: Y, Co, Cg, count.
    hist: [Vec<f32>; 4],
    /// This row's reprojected history depth, then 1 where depth rejects the history.
    reject: Vec<f32>,
    /// Per-column 3-row statistics of this row: min, max, sum, sum of squares, per channel.
    cols: [Vec<f32>; 12],
}

/// Runs `taa`'s stages from `tonemap` to `untonemap` for one frame.
pub(super) fn frame(p: &Params, ctx: FrameContext<'_, '_>) -> Result<FrameResult, FilterError> {
    let FrameContext {
        inp,
        rec,
        has_history,
        read,
        next,
        scratch,
    } = ctx;
    let (w, h) = (inp.width, inp.height);
    let facts = inp.facts;
    let StagePlan {
        tonemap: tonemap_skip,
        dilate: dilate_skip,
        reproject: reproject_skip,
        depth_reject: reject_skip,
        sharpen: sharpen_skip,
    } = StagePlan::new(p, &inp, has_history);
    let plan = Plan {
        tonemap: tonemap_skip.is_none(),
        dilate: dilate_skip.is_none(),
        reproject: reproject_skip.is_none(),
        depth_reject: reject_skip.is_none(),
        // With a sharpen, colour goes back to linear after it, over the whole frame.
        untonemap: tonemap_skip.is_none() && sharpen_skip.is_some(),
        filter: p.history_filter,
        knobs: Knobs {
            alpha: p.alpha,
            gamma: p.gamma,
            luminance_weighting: p.luminance_weighting,
            depth_rejection: p.depth_rejection,
        },
    };
    let src = Sources {
        frame: FrameSlices::of(&inp, None),
        hist: has_history.then(|| History {
            texels: read[0].data(),
            depth: read.get(1).map(|p| p.data()),
        }),
    };
    let mut out: Rgb = scratch.planes(w, h);
    let clock = StageClock::<7>::default();
    let t = std::time::Instant::now();
    let pixels = {
        let [o0, o1, o2] = out.each_mut().map(|p| p.data_mut());
        par_bands_strided(
            [o0, o1, o2, next[0].data_mut()],
            [w, w, w, 4 * w],
            h,
            |band: &mut Band, rows, planes| run_band(&src, &plan, &clock, band, rows, planes),
        )
    };
    let ms = t.elapsed().as_secs_f64() * 1e3;
    if let (Some(d), Some(nd)) = (src.frame.depth, next.get_mut(1)) {
        nd.data_mut().copy_from_slice(d);
    }
    let shares = clock.shares();
    let skips = [
        tonemap_skip.clone(),
        None,
        dilate_skip,
        reproject_skip,
        reject_skip,
        None,
        if plan.untonemap {
            None
        } else {
            tonemap_skip.clone()
        },
    ];
    for (k, skip) in skips.into_iter().enumerate().take(RESOLVE + 1) {
        rec.ran_unless(STAGES[k], skip, ms * shares[k]);
    }
    if let Some(s) = rec.stage("sharpen", sharpen_skip, || {
        sharpen(&out, p.sharpen, output_ceiling(&facts), scratch)
    }) {
        scratch.recycle(std::mem::replace(&mut out, s));
        rec.stage("untonemap", tonemap_skip, || from_working(&mut out, true));
    } else {
        rec.ran_unless("untonemap", tonemap_skip, ms * shares[UNTONEMAP]);
    }
    Ok(FrameResult {
        color: out,
        pixels,
        model: None,
    })
}

/// One band: its rows' YCoCg (and halo) into the band buffers, then row by row the other
/// stages.
#[allow(clippy::too_many_arguments)]
fn run_band(
    src: &Sources,
    plan: &Plan,
    clock: &StageClock<7>,
    band: &mut Band,
    rows: Range<usize>,
    [or, og, ob, next]: [&mut [f32]; 4],
) -> PixelCounts {
    let (w, h) = (src.frame.w, src.frame.h);
    let halo = Halo::new(&rows, w, h);
    let Band {
        cur,
        work,
        motion,
        hist,
        reject,
        cols,
    } = band;
    let mut cur = cur.each_mut().map(|v| sized(v, halo.samples()));
    for r in halo.start..halo.end {
        let at = r * w..(r + 1) * w;
        let input = [0, 1, 2].map(|k| &src.frame.color[k][at.clone()]);
        let dst = halo.row(r);
        let [c0, c1, c2] = cur.each_mut().map(|c| &mut c[dst.clone()]);
        if plan.tonemap {
            let [t0, t1, t2] = work.each_mut().map(|v| sized(v, w));
            clock.time(TONEMAP, || tonemap_row(input, [&mut *t0, &mut *t1, &mut *t2]));
            clock.time(YCOCG, || ycocg_row([t0, t1, t2], [c0, c1, c2]));
        } else {
            clock.time(YCOCG, || ycocg_row(input, [c0, c1, c2]));
        }
    }
    let mut counts = PixelCounts::default();
    for y in rows.clone() {
        let k = y - rows.start;
        let at = y * w..(y + 1) * w;
        // This row's motion: dilated, or as given.
        let m: Option<[&[f32]; 2]> = if !plan.reproject {
            None
        } else if plan.dilate {
            let [mx, my] = motion.each_mut().map(|v| sized(v, w));
            let (d, mv) = (
                src.frame.depth.expect("planned"),
                src.frame.motion.expect("planned"),
            );
            clock.time(DILATE, || dilate_row(d, mv, w, h, y, mx, my));
            Some([&*mx, &*my])
        } else {
            src.frame
                .motion
                .map(|mv| [&mv[0][at.clone()], &mv[1][at.clone()]])
        };
        // This row's history: reprojected, or in place when nothing moves.
        let hrow: Option<[&[f32]; 4]> = match src.hist {
            None => None,
            Some(hs) => {
                let [hy, hco, hcg, hn] = hist.each_mut().map(|v| sized(v, w));
                let dst = [&mut *hy, &mut *hco, &mut *hcg, &mut *hn];
                match m {
                    Some(m) => clock.time(REPROJECT, || {
                        reproject_row(hs.texels, plan.filter, w, h, y, m, dst)
                    }),
                    // Nothing moves: this pixel's own texels, taken apart.
                    None => clock.time(RESOLVE, || {
                        deinterleave_row(&hs.texels[4 * at.start..4 * at.end], dst)
                    }),
                }
                Some([&*hy, &*hco, &*hcg, &*hn])
            }
        };
        let rej: Option<&[f32]> = if plan.depth_reject {
            let prev = src.hist.and_then(|hs| hs.depth).expect("planned");
            let rj = sized(reject, w);
            let d = &src.frame.depth.expect("planned")[at.clone()];
            counts.history_rejected += clock.time(DEPTH_REJECT, || {
                depth_reject_row(prev, d, m, w, h, y, plan.knobs.depth_rejection, rj)
            });
            Some(&*rj)
        } else {
            None
        };
        let [cy, ca, cb] = [0, 1, 2].map(|c| halo.stencil(y).map(|r| &cur[c][r]));
        let cl = cols.each_mut().map(|v| sized(v, w));
        let o = k * w..(k + 1) * w;
        let c = clock.time(RESOLVE, || {
            resolve_row(
                [cy, ca, cb],
                hrow,
                rej,
                src.frame.invalid.map(|v| &v[at.clone()]),
                &plan.knobs,
                cl,
                [&mut or[o.clone()], &mut og[o.clone()], &mut ob[o.clone()]],
                &mut next[4 * o.start..4 * o.end],
            )
        });
        counts += c;
        if plan.untonemap {
            clock.time(UNTONEMAP, || {
                untonemap_row([&mut or[o.clone()], &mut og[o.clone()], &mut ob[o.clone()]])
            });
        }
    }
    counts
}

/// Stage `ycocg` of one row ([`rgb_to_ycocg`]).
fn ycocg_row(src: [&[f32]; 3], dst: [&mut [f32]; 3]) {
    let [r, g, b] = src;
    let [a, c, d] = dst;
    let n = a.len();
    let (r, g, b, c, d) = (&r[..n], &g[..n], &b[..n], &mut c[..n], &mut d[..n]);
    for x in 0..n {
        [a[x], c[x], d[x]] = rgb_to_ycocg([r[x], g[x], b[x]]);
    }
}

/// Stage `reproject` of row `y`: each pixel's history at its previous position `p +
/// motion` from the texels: Catmull-Rom (or bilinear) colour and bilinear count; count 0
/// (a restart) off screen, where the colour is left as it was (the resolve does not read
/// it).
fn reproject_row(
    texels: &[f32],
    filter: HistoryFilter,
    w: usize,
    h: usize,
    y: usize,
    m: [&[f32]; 2],
    dst: [&mut [f32]; 4],
) {
    let [hy, hco, hcg, hn] = dst;
    let (mx, my) = (&m[0][..w], &m[1][..w]);
    let (hy, hco, hcg, hn) = (&mut hy[..w], &mut hco[..w], &mut hcg[..w], &mut hn[..w]);
    for x0 in (0..w).step_by(LANES) {
        let [px, py] = previous_positions(mx, my, x0, y);
        let on = on_screen_bits(&px, &py, w, h);
        // Off-screen lanes keep zero texels: count 0, a restart.
        let [a, b, c, d] = match filter {
            HistoryFilter::CatmullRom => FootprintLanes::at(&px, &py).texels(texels, w, h, on),
            HistoryFilter::Bilinear => {
                let mut t = [[0.0; TEXEL]; LANES];
                for (l, t) in t.iter_mut().enumerate() {
                    if on >> l & 1 != 0 {
                        *t = bilinear_texels::<TEXEL>(texels, w, h, px[l], py[l]);
                    }
                }
                lanes::load_texels(&t)
            }
        };
        lanes::store(hy, x0, &a);
        lanes::store(hco, x0, &b);
        lanes::store(hcg, x0, &c);
        lanes::store(hn, x0, &d);
    }
}

/// One row of texels `[Y, Co, Cg, count]` as four rows.
fn deinterleave_row(texels: &[f32], dst: [&mut [f32]; 4]) {
    let [a, b, c, d] = dst;
    for (((t, a), (b, c)), d) in texels
        .chunks_exact(4)
        .zip(a.iter_mut())
        .zip(b.iter_mut().zip(c.iter_mut()))
        .zip(d.iter_mut())
    {
        (*a, *b, *c, *d) = (t[0], t[1], t[2], t[3]);
    }
}

/// Stage `depth_reject` of row `y`: 1 where the history's depth (reprojected bilinearly, or
/// in place when nothing moves) differs from the current depth by more than `threshold`
/// relative, else 0; returns how many pixels it rejects.
#[allow(clippy::too_many_arguments)]
fn depth_reject_row(
    prev: &[f32],
    d: &[f32],
    m: Option<[&[f32]; 2]>,
    w: usize,
    h: usize,
    y: usize,
    threshold: f32,
    out: &mut [f32],
) -> u64 {
    let mut rejected = 0;
    for x in 0..w {
        let dp = match m {
            Some([mx, my]) => bilinear([prev], w, h, x as f32 + 0.5 + mx[x], y as f32 + 0.5 + my[x])[0],
            None => prev[y * w + x],
        };
        let reject = (dp - d[x]).abs() > threshold * d[x].abs().max(1e-6);
        rejected += reject as u64;
        out[x] = reject as u8 as f32;
    }
    rejected
}

/// The resolve of one pixel: returns the new history value and count, and whether the
/// history restarted and whether it was clipped. `n` = the history's sample count (0: no
/// history), `hist` its colour, `invalid` = the input sample was repaired (keep the
/// history). Branch-free, so the row loop vectorises; the same arithmetic as the
/// reference's resolve.
#[inline(always)]
fn resolve_pixel(
    current: [f32; 3],
    stats: &NeighborhoodStats,
    hist: [f32; 3],
    n: f32,
    invalid: bool,
    k: &Knobs,
) -> ([f32; 3], f32, bool, bool) {
    let (lo, hi) = variance_box(stats, k.gamma);
    let (hc, moved) = clip_toward_center(hist, lo, hi);
    let a = k.alpha.max(1.0 / (n + 1.0));
    let (wc, wh) = if k.luminance_weighting {
        (
            a / (1.0 + current[0].max(0.0)),
            (1.0 - a) / (1.0 + hc[0].max(0.0)),
        )
    } else {
        (a, 1.0 - a)
    };
    let kk = 1.0 / (wc + wh);
    let blend = [0, 1, 2].map(|j| (wc * current[j] + wh * hc[j]) * kk);
    let reset = n < 0.5;
    let keep = !reset && invalid;
    let value = [0, 1, 2].map(|j| {
        if reset {
            current[j]
        } else if keep {
            hist[j]
        } else {
            blend[j]
        }
    });
    let count = if reset {
        1.0
    } else if keep {
        n
    } else {
        (n + 1.0).min(MAX_COUNT)
    };
    (value, count, reset, moved && !reset && !keep)
}

/// The 3x3 statistics of pixel `x` from its columns `xl`, `x`, `xr`: per channel, the
/// column min, max, sum and sum of squares at `cols[4c..4c+4]` (as
/// [`crate::kernels::for_each_row_stats`] combines them).
#[inline(always)]
fn stats_at(cols: &[&[f32]; 12], xl: usize, x: usize, xr: usize) -> NeighborhoodStats {
    let mut s = NeighborhoodStats::default();
    box_from_columns(cols, xl, x, xr, &mut s);
    s
}

/// The rows one resolve writes: output colour (working space) and the new history's
/// texels.
struct Outs<'a> {
    rgb: [&'a mut [f32]; 3],
    next: &'a mut [f32],
}

impl Outs<'_> {
    #[inline(always)]
    fn put(&mut self, x: usize, value: [f32; 3], count: f32) {
        self.next[4 * x..4 * x + 4].copy_from_slice(&[value[0], value[1], value[2], count]);
        let rgb = ycocg_to_rgb(value);
        self.rgb[0][x] = rgb[0].max(0.0);
        self.rgb[1][x] = rgb[1].max(0.0);
        self.rgb[2][x] = rgb[2].max(0.0);
    }
}

/// The columns a block of [`LANES`] pixels reads: one more on each side.
const SPAN: usize = LANES + 2;

/// [`resolve_pixel`] for a block of pixels in lanes: statistics from the block's columns
/// `c`, the input `cur`, the history colour and count `n`, the repaired-input flags.
/// Returns the new colour and count, and the masks of reset and clipped pixels. After the
/// statistics it runs in `f32x8` vectors with float masks: written as lane loops, its
/// flags and selects compiled to a branch per lane.
#[inline(always)]
fn resolve_lanes(
    c: &[&[f32; SPAN]; 12],
    cur: &[Lanes; 3],
    hist: &[Lanes; 3],
    n: &Lanes,
    invalid: &Mask,
    k: &Knobs,
) -> ([f32x8; 3], f32x8, f32x8, f32x8) {
    let [min, max, mean, mean_sq] = lanes::box_stats(c);
    let (lo, hi) = lanes::variance_box(&min, &max, &mean, &mean_sq, k.gamma);
    let (cur, hist) = (lanes::v3(cur), lanes::v3(hist));
    let (hc, moved) = lanes::clip_toward_center_v(&hist, &lanes::v3(&lo), &lanes::v3(&hi));
    let (zero, one, n) = (f32x8::splat(0.0), f32x8::splat(1.0), lanes::v(n));
    let a = lanes::max_of(f32x8::splat(k.alpha), one / (n + one));
    let (wc, wh) = if k.luminance_weighting {
        (
            a / (one + lanes::max_of(cur[0], zero)),
            (one - a) / (one + lanes::max_of(hc[0], zero)),
        )
    } else {
        (a, one - a)
    };
    let kk = one / (wc + wh);
    let reset = n.simd_lt(f32x8::splat(0.5));
    let keep = reset.select(zero, lanes::mask_from(invalid));
    let value = lanes::each(|j| reset.select(cur[j], keep.select(hist[j], (wc * cur[j] + wh * hc[j]) * kk)));
    let grown = lanes::min_of(n + one, f32x8::splat(MAX_COUNT));
    let count = reset.select(one, keep.select(n, grown));
    let clipped = (reset | keep).select(zero, moved);
    (value, count, reset, clipped)
}

/// The resolve of pixels `xs` (with columns `x - 1` and `x + 1` inside the row) in blocks
/// of [`LANES`]: every input of a block is a fixed-size array, so the per-pixel code below
/// has no bounds checks or branches left and the compiler vectorises it across the block.
/// Where `xs` is not a whole number of blocks, its last block overlaps the one before
/// (its pixels computed twice, to the same values, and counted once).
/// `REJECT` and `INVALID` say whether those rows exist (the others are not read). Returns
/// where it stopped (the pixels after it are the caller's) and the counts.
#[allow(clippy::too_many_arguments)]
#[inline(always)]
fn resolve_blocks<const REJECT: bool, const INVALID: bool>(
    cols: &[&[f32]; 12],
    centre: [&[f32]; 3],
    hist: [&[f32]; 4],
    reject: &[f32],
    invalid: &[bool],
    k: &Knobs,
    out: &mut Outs,
    xs: Range<usize>,
) -> (usize, u32, u32) {
    let (mut resets, mut clips) = (0u32, 0u32);
    if xs.len() < LANES {
        return (xs.start, 0, 0);
    }
    // Every row cut to the columns the blocks read, so that one bounds check per block
    // covers all of them (the same length for all).
    let n = xs.end + 1;
    let cols: [&[f32]; 12] = lanes::each(|i| &cols[i][..n]);
    let centre: [&[f32]; 3] = lanes::each(|i| &centre[i][..n]);
    let hist: [&[f32]; 4] = lanes::each(|i| &hist[i][..n]);
    let reject = if REJECT { &reject[..n] } else { reject };
    let invalid = if INVALID { &invalid[..n] } else { invalid };
    let rgb_len = out.rgb[0].len().min(n);
    // Blocks from `xs.start`, the last one ending at `xs.end`; `counted`: its lanes not
    // counted before (one loop body: as a closure called twice it was left out of line).
    let all = (1 << LANES) - 1;
    let (mut x0, mut counted) = (xs.start, all);
    loop {
        let c: [&[f32; SPAN]; 12] = std::array::from_fn(|i| block(cols[i], x0 - 1));
        let cen: [&[f32; LANES]; 3] = std::array::from_fn(|i| block(centre[i], x0));
        let hs: [&[f32; LANES]; 4] = std::array::from_fn(|i| block(hist[i], x0));
        let rj: [f32; LANES] = if REJECT { *block(reject, x0) } else { [0.0; LANES] };
        let iv: [bool; LANES] = if INVALID {
            *block(invalid, x0)
        } else {
            [false; LANES]
        };
        let cur: [Lanes; 3] = [*cen[0], *cen[1], *cen[2]];
        let hist3: [Lanes; 3] = [*hs[0], *hs[1], *hs[2]];
        let n: Lanes = if REJECT {
            std::array::from_fn(|l| if rj[l] != 0.0 { 0.0 } else { hs[3][l] })
        } else {
            *hs[3]
        };
        let (value, cnt, reset, clipped) = resolve_lanes(&c, &cur, &hist3, &n, &iv, k);
        let mut rgb = lanes::ycocg_to_rgb(&lanes::arrays3(&value));
        for c in &mut rgb {
            *c = lanes::map(c, |v| v.max(0.0));
        }
        for ch in 0..3 {
            let row = &mut out.rgb[ch][..rgb_len];
            *<&mut [f32; LANES]>::try_from(&mut row[x0..x0 + LANES]).expect("a block") = rgb[ch];
        }
        let texels: &mut [f32; 4 * LANES] = (&mut out.next[4 * x0..4 * (x0 + LANES)])
            .try_into()
            .expect("a block");
        lanes::store_texels4(&[value[0], value[1], value[2], cnt], texels);
        resets += (reset.to_bitmask() & counted).count_ones();
        clips += (clipped.to_bitmask() & counted).count_ones();
        let next = x0 + LANES;
        if next + LANES <= xs.end {
            x0 = next;
        } else if next < xs.end {
            // The last block ends at the end of `xs`; its lanes before `next` were counted.
            x0 = xs.end - LANES;
            counted = all & !((1 << (next - x0)) - 1);
        } else {
            break;
        }
    }
    (xs.end, resets, clips)
}

/// Stage `resolve` of one row: 3x3 statistics of the YCoCg rows above, here and below
/// (edges clamped; per column first, then across), the variance box, the clip, the blend;
/// writes the new history and the output in the working space.
#[allow(clippy::too_many_arguments)]
fn resolve_row(
    cur: [[&[f32]; 3]; 3],
    hist: Option<[&[f32]; 4]>,
    reject: Option<&[f32]>,
    invalid: Option<&[bool]>,
    k: &Knobs,
    cols: [&mut [f32]; 12],
    out: [&mut [f32]; 3],
    next: &mut [f32],
) -> PixelCounts {
    let w = out[0].len();
    let mut out = Outs {
        rgb: out.map(|r| &mut r[..w]),
        next: &mut next[..4 * w],
    };
    let centre = cur.map(|p| &p[1][..w]);
    let Some(hist) = hist else {
        // No history: every pixel restarts from its input.
        for x in 0..w {
            out.put(x, [centre[0][x], centre[1][x], centre[2][x]], 1.0);
        }
        return PixelCounts {
            history_reset: w as u64,
            ..Default::default()
        };
    };
    // Per column: min, max, sum and sum of squares of the three rows, per channel.
    let mut cols = cols;
    for (c, planes) in cur.iter().enumerate() {
        let [a, b, t] = planes.map(|p| &p[..w]);
        let [vmin, vmax, vsum, vsq] = {
            let (x, rest) = cols[4 * c..4 * c + 4].split_at_mut(1);
            let (y, rest) = rest.split_at_mut(1);
            let (z, u) = rest.split_at_mut(1);
            [&mut x[0][..w], &mut y[0][..w], &mut z[0][..w], &mut u[0][..w]]
        };
        column_stats([a, b, t], [vmin, vmax, vsum, vsq]);
    }
    let cols = cols.each_ref().map(|c| &c[..w]);
    let hist = hist.map(|h| &h[..w]);
    let none_f: &[f32] = &[];
    let none_b: &[bool] = &[];
    let reject = reject.map_or(none_f, |r| &r[..w]);
    let invalid = invalid.map_or(none_b, |v| &v[..w]);
    // The border pixels (columns clamped) one at a time, the others in the vector loop.
    let one = |x: usize, out: &mut Outs| {
        let s = stats_at(&cols, x.saturating_sub(1), x, (x + 1).min(w - 1));
        let n = if reject.get(x).is_some_and(|&r| r != 0.0) {
            0.0
        } else {
            hist[3][x]
        };
        let inv = invalid.get(x).is_some_and(|&v| v);
        let current = [centre[0][x], centre[1][x], centre[2][x]];
        let hv = [hist[0][x], hist[1][x], hist[2][x]];
        let (value, count, reset, clipped) = resolve_pixel(current, &s, hv, n, inv, k);
        out.put(x, value, count);
        (reset as u32, clipped as u32)
    };
    // The interior in blocks, the border pixels and the rest of the interior one by one.
    let xs = 1..w.saturating_sub(1).max(1);
    let (stop, mut resets, mut clips) = match (reject.is_empty(), invalid.is_empty()) {
        (true, true) => resolve_blocks::<false, false>(&cols, centre, hist, reject, invalid, k, &mut out, xs),
        (false, true) => resolve_blocks::<true, false>(&cols, centre, hist, reject, invalid, k, &mut out, xs),
        (true, false) => resolve_blocks::<false, true>(&cols, centre, hist, reject, invalid, k, &mut out, xs),
        (false, false) => resolve_blocks::<true, true>(&cols, centre, hist, reject, invalid, k, &mut out, xs),
    };
    for x in std::iter::once(0).chain(stop.max(1)..w) {
        let (r, c) = one(x, &mut out);
        resets += r;
        clips += c;
    }
    PixelCounts {
        history_reset: resets as u64,
        history_clipped: clips as u64,
        ..Default::default()
    }
}
