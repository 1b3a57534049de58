//! `phlm`'s stages fused into one pass over bands of rows ([`par_bands_strided`]): a band's
//! working colour and YCoCg (rows and their 3x3 halo) go to band-local buffers; then each
//! row's models are fetched at their previous positions (one texel of [`STATE_PLANES`] floats per tap:
//! beta, R, z, the count of failed box tests, the speed and the depth of a pixel side by side), its 3x3
//! statistics are computed once for both the feature and the model test, and the feature
//! and Algorithm 1 (prediction, box test, clip, the RLS update in f64 with reciprocal
//! pivots) run on blocks of eight pixels in vector lanes. The reference
//! ([`super::reference`]) reads the planes one by one per pixel, computes the statistics twice and
//! solves each pixel alone.
//!
//! Every stage computes what the reference computes, with the same float operations in the
//! same order, so the outputs are the same bits; the tests compare them frame by frame.

use super::feature::accumulate_lanes;
use super::rls::{self, D, P_LEN};
use super::{
    history_depth, Counts, ModelFetch, OnClip, Params, TestBox, BETA, DEPTH, DEPTH_JUMP_SPEED, R, S,
    STATE_PLANES, STRIKE_DECAY, V, Z,
};
use crate::filters::passes::{
    dilate_motion_rows, dilate_skip, on_screen_bits, previous_positions, reproject_skip, FrameContext,
    FrameResult, FrameSlices,
};
use crate::frame::Rgb;
use crate::kernels::lanes::{self, Lanes, LANES};
use crate::kernels::{
    bilinear_texels, fmax, fmin, nearest_texel, rgb_to_ycocg, tonemap, tonemap_inverse, FootprintLanes, SPAN,
};
use crate::pipeline::exec::{par_bands_strided, sized, stage_indices, Halo, StageClock};
use crate::pipeline::FilterError;
use std::ops::Range;
use wide::f32x8;

/// Stages of the fused pass, in order (indices into its [`StageClock`]).
const STAGES: [&str; 6] = ["tonemap", "ycocg", "reproject", "feature", "model", "untonemap"];
stage_indices!(STAGES: TONEMAP, YCOCG, REPROJECT, FEATURE, MODEL, UNTONEMAP);

/// Every lane of a block, as bits.
const ALL: u32 = (1 << LANES) - 1;

/// Floats of one pixel's state texel: beta (12), R (10), z (3), the count of failed box
/// tests (1), the speed (1), the depth (1).
pub(super) const TEXEL: usize = STATE_PLANES;

// The Catmull-Rom fetch writes beta's span and the bilinear R, z and count side by side:
// together they must be the whole texel, or stale floats of the reused block buffer would leak.
const _: () = assert!(BETA == 0 && R - BETA == SPAN);

/// What the pass reads for one frame.
struct Sources<'a> {
    /// The frame, its motion dilated where dilation runs (its depth is kept with the
    /// models, [`super::depth_share`]).
    frame: FrameSlices<'a>,
    /// The previous frame's state texels, when there is history.
    state: Option<&'a [f32]>,
}

/// What runs and the constants of the model.
#[derive(Clone, Copy)]
struct Plan<'a> {
    tonemap: bool,
    reproject: bool,
    has_history: bool,
    /// Largest output: just below 1 in the tonemapped space, unbounded otherwise.
    hi: f32,
    /// The prior `R0 = I / p0` that forgetting relaxes toward.
    prior: f32,
    p: &'a Params,
}

/// One band task's buffers, reused across the bands it runs.
#[derive(Default)]
struct Band {
    /// YCoCg of the band's rows and one row above and below (clamped to the image).
    cur: [Vec<f32>; 3],
    /// The working colour (tonemapped input) of the band's rows.
    work: [Vec<f32>; 3],
    /// Per-column 3-row min, max and sum of each channel, then the sum of squares of each
    /// channel (filled for the variance test box only), with one clamped column on each
    /// side and padding to whole blocks.
    cols: [Vec<f32>; 12],
    /// This row's fetched state, block by block.
    fetched: Vec<Fetched>,
    /// One block's fetched texels, before they are taken into lanes (kept across blocks:
    /// zeroing 864 bytes per block was a `memset` call).
    texels: [[f32; TEXEL]; LANES],
    /// This row's new feature, block by block.
    z: Vec<[Lanes; 3]>,
    /// This row's 3x3 depth range (low, high; [`depth_range_row`]), padded to whole
    /// blocks, and its per-column 3-row range before the columns are taken together.
    depth: [Vec<f32>; 4],
}

/// What stage `reproject` hands the feature and the model for one block of pixels.
#[derive(Clone, Copy, Default)]
struct Fetched {
    /// The previous state (beta, R, z, the count, the speed; [`TEXEL`] floats), one lane
    /// per pixel; zero where there is none.
    state: [Lanes; TEXEL],
    /// Pixels without history (first frame, reset, off screen, padding), as bits (lane `l`
    /// is bit `l`).
    none: u32,
    /// Motion length (of the dilated motion where dilation runs): this frame's speed,
    /// stored in the state's plane `V` for [`super::jump`].
    speed: Lanes,
}

/// Runs `phlm`'s stages from `tonemap` to `untonemap` for one frame.
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
    let reproject_skip = reproject_skip(&inp, has_history);
    let dilate_skip = dilate_skip(&inp, &reproject_skip, p.dilation);
    let tonemap_skip = facts.tonemap();
    // Velocity dilation, a whole-plane pass before the fused one (its 3x3 depth search
    // would otherwise run again for each of a band's halo rows).
    let t = std::time::Instant::now();
    let dilated = dilate_skip.is_none().then(|| {
        dilate_motion_rows(
            inp.motion.as_deref().expect("required"),
            inp.depth.as_deref().expect("required"),
            scratch,
        )
    });
    let dilate_ms = t.elapsed().as_secs_f64() * 1e3;
    let plan = Plan {
        tonemap: tonemap_skip.is_none(),
        reproject: reproject_skip.is_none(),
        has_history,
        hi: crate::filters::passes::output_ceiling(&facts),
        prior: 1.0 / p.p0,
        p,
    };
    let src = Sources {
        frame: FrameSlices::of(&inp, dilated.as_ref()),
        state: has_history.then(|| read[0].data()),
    };
    let mut out: Rgb = scratch.planes(w, h);
    let clock = StageClock::<6>::default();
    let t = std::time::Instant::now();
    let counts = {
        let [o0, o1, o2] = out.each_mut().map(|p| p.data_mut());
        par_bands_strided(
            [o0, o1, o2, next[0].data_mut()],
            [w, w, w, TEXEL * w],
            h,
            |band: &mut Band, rows, planes| run_band(&src, &plan, &clock, band, rows, planes),
        )
    };
    let ms = t.elapsed().as_secs_f64() * 1e3;
    let shares = clock.shares();
    let skips = [
        tonemap_skip.clone(),
        None,
        reproject_skip,
        None,
        None,
        tonemap_skip,
    ];
    for (k, skip) in skips.into_iter().enumerate() {
        if k == REPROJECT {
            // `dilate` runs before the fused pass and is recorded in its place.
            rec.ran_unless("dilate", dilate_skip.clone(), dilate_ms);
        }
        rec.ran_unless(STAGES[k], skip, ms * shares[k]);
    }
    scratch.recycle(dilated.into_iter().flatten());
    Ok(counts.result(out))
}

/// One band: its rows' working colour and YCoCg (and halo) into the band buffers, then row
/// by row the other stages.
fn run_band(
    src: &Sources,
    plan: &Plan,
    clock: &StageClock<6>,
    band: &mut Band,
    rows: Range<usize>,
    [or, og, ob, next]: [&mut [f32]; 4],
) -> Counts {
    let (w, h) = (src.frame.w, src.frame.h);
    let halo = Halo::new(&rows, w, h);
    let Band {
        cur,
        work,
        cols,
        fetched,
        texels,
        z,
        depth,
    } = band;
    let mut cur = cur.each_mut().map(|v| sized(v, halo.samples()));
    let mut work = work.each_mut().map(|v| sized(v, halo.samples()));
    for r in halo.start..halo.end {
        let at = r * w..(r + 1) * w;
        let dst = halo.row(r);
        let input = [0, 1, 2].map(|k| &src.frame.color[k][at.clone()]);
        let [w0, w1, w2] = work.each_mut().map(|c| &mut c[dst.clone()]);
        if plan.tonemap {
            clock.time(TONEMAP, || {
                for x in 0..w {
                    let t = tonemap([input[0][x], input[1][x], input[2][x]]);
                    (w0[x], w1[x], w2[x]) = (t[0], t[1], t[2]);
                }
            });
        } else {
            w0.copy_from_slice(input[0]);
            w1.copy_from_slice(input[1]);
            w2.copy_from_slice(input[2]);
        }
        let [c0, c1, c2] = cur.each_mut().map(|c| &mut c[dst.clone()]);
        let (w0, w1, w2) = (&*w0, &*w1, &*w2);
        clock.time(YCOCG, || {
            for x in 0..w {
                [c0[x], c1[x], c2[x]] = rgb_to_ycocg([w0[x], w1[x], w2[x]]);
            }
        });
    }
    // Row buffers hold whole blocks: `wp` pixels, the last ones padding.
    let wp = w.div_ceil(LANES) * LANES;
    let mut counts = Counts::default();
    for y in rows.clone() {
        let at = y * w..(y + 1) * w;
        let fetch_stage = if plan.reproject { REPROJECT } else { MODEL };
        let fetched = sized(fetched, wp / LANES);
        clock.time(fetch_stage, || fetch_row(src, plan, y, fetched, texels));
        let cols = cols.each_mut().map(|v| sized(v, wp + 2));
        let rows3 = halo.stencil(y);
        let centre = halo.row(y);
        let squares = plan.p.test_box == TestBox::Variance;
        let stats = clock.time(FEATURE, || column_stats(&cur, &rows3, w, squares, cols));
        let z = sized(z, wp / LANES);
        let working = work.each_ref().map(|c| &c[centre.clone()]);
        let ycocg = cur.each_ref().map(|c| &c[centre.clone()]);
        let invalid = src.frame.invalid.map(|v| &v[at.clone()]);
        clock.time(FEATURE, || {
            feature_row(&stats, working, fetched, invalid, plan.p, w, z)
        });
        let k = y - rows.start;
        let o = k * w..(k + 1) * w;
        let row_out = [&mut or[o.clone()], &mut og[o.clone()], &mut ob[o.clone()]];
        let texels = &mut next[TEXEL * o.start..TEXEL * o.end];
        counts += clock.time(MODEL, || {
            let depths = src.frame.depth.map(|d| {
                let range = (plan.p.depth_jump > 0.0).then(|| depth_range_row(d, w, h, y, wp, depth));
                (&d[at.clone()], range)
            });
            model_row(
                &stats, working, ycocg, fetched, z, depths, invalid, plan, w, row_out, texels,
            )
        });
        if plan.tonemap {
            let [r, g, b] = [&mut or[o.clone()], &mut og[o.clone()], &mut ob[o.clone()]];
            clock.time(UNTONEMAP, || {
                for x in 0..w {
                    let c = tonemap_inverse([r[x], g[x], b[x]]);
                    (r[x], g[x], b[x]) = (c[0], c[1], c[2]);
                }
            });
        }
    }
    counts
}

/// Stage `reproject` of row `y` (or the in-place read when nothing moves): each pixel's
/// previous state (bilinear or nearest at `p + motion`, or its own) into its block's
/// lanes, with the motion length for the feature; `none` (and a zero state) where there
/// is no state (no history, off screen, padding).
fn fetch_row(
    src: &Sources,
    plan: &Plan,
    y: usize,
    blocks: &mut [Fetched],
    texels: &mut [[f32; TEXEL]; LANES],
) {
    let (w, h) = (src.frame.w, src.frame.h);
    let row = y * w..(y + 1) * w;
    let moving = match (plan.reproject, src.frame.motion) {
        (true, Some(m)) => Some(m),
        _ => None,
    };
    for (b, blk) in blocks.iter_mut().enumerate() {
        let x0 = b * LANES;
        blk.none = ALL;
        blk.speed = [0.0; LANES];
        if let Some([mx, my]) = src.frame.motion {
            let (mx, my) = (
                lanes_of(&mx[row.clone()], x0, w, 0.0),
                lanes_of(&my[row.clone()], x0, w, 0.0),
            );
            blk.speed = lanes::each(|l| (mx[l] * mx[l] + my[l] * my[l]).sqrt());
        }
        let Some(state) = src.state else {
            blk.state = [[0.0; LANES]; TEXEL];
            continue;
        };
        let n = LANES.min(w - x0);
        // Lanes with a texel (bit `l`): the real pixels, on screen where they move.
        let mut have = (1u32 << n) - 1;
        if let Some([mx, my]) = moving {
            // Positions and the on-screen test for the block in vectors (what
            // [`crate::filters::passes::on_screen`] computes per pixel), then each lane's fetch in place.
            let [px, py] = previous_positions(&mx[row.clone()], &my[row.clone()], x0, y);
            have &= on_screen_bits(&px, &py, w, h);
            match plan.p.model_fetch {
                // beta by Catmull-Rom, R and z bilinear (as `fetch_model`), the eight
                // footprints in vectors (the same bits as one at a time); zeros where there
                // is no texel, padding included.
                ModelFetch::CatmullRom => FootprintLanes::at(&px, &py)
                    .span_and_bilinear::<TEXEL, { TEXEL - R }>(state, w, h, have, BETA, R, texels),
                fetch => {
                    for (l, texel) in texels.iter_mut().enumerate() {
                        *texel = if have >> l & 1 == 0 {
                            [0.0; TEXEL]
                        } else if fetch == ModelFetch::Bilinear {
                            bilinear_texels(state, w, h, px[l], py[l])
                        } else {
                            nearest_texel(state, w, h, px[l], py[l])
                        };
                    }
                }
            }
        } else {
            for (l, texel) in texels.iter_mut().enumerate().take(n) {
                *texel = *lanes::block(state, (y * w + x0 + l) * TEXEL);
            }
            // Padding lanes have zero texels.
            for texel in texels.iter_mut().skip(n) {
                *texel = [0.0; TEXEL];
            }
        }
        blk.none = !have & ALL;
        blk.state = lanes::load_texels(texels);
    }
}

/// The 3x3 statistics the feature and the model need, per pixel of a row.
struct RowStats<'a> {
    cols: [&'a [f32]; 12],
}

/// Per column of the row: min, max and sum (and with `squares` the sum of squares) of the
/// three rows `rows3` of each channel, at index `x + 1`, with the edge columns repeated at
/// indices `0` and `w + 1` (so pixel `x` reads indices `x .. x + 2` whatever its place)
/// and the padding filled.
fn column_stats<'a>(
    cur: &[&mut [f32]; 3],
    rows3: &[Range<usize>; 3],
    w: usize,
    squares: bool,
    cols: [&'a mut [f32]; 12],
) -> RowStats<'a> {
    let mut cols = cols;
    if squares {
        for c in 0..3 {
            let [a, b, t] = rows3.clone().map(|r| &cur[c][r]);
            let sq = &mut *cols[9 + c];
            for x in 0..w {
                let (u, v, s) = (a[x], b[x], t[x]);
                // As [`crate::kernels::for_each_row_stats`] sums them.
                sq[x + 1] = u * u + v * v + s * s;
            }
            sq[0] = sq[1];
            let last = sq[w];
            sq[w + 1..].fill(last);
        }
    }
    for c in 0..3 {
        let [a, b, t] = rows3.clone().map(|r| &cur[c][r]);
        let (mn, rest) = cols[3 * c..3 * c + 3].split_at_mut(1);
        let (mx, sm) = rest.split_at_mut(1);
        let (mn, mx, sm) = (&mut *mn[0], &mut *mx[0], &mut *sm[0]);
        for x in 0..w {
            let (u, v, s) = (a[x], b[x], t[x]);
            mn[x + 1] = fmin(fmin(u, v), s);
            mx[x + 1] = fmax(fmax(u, v), s);
            sm[x + 1] = u + v + s;
        }
        for col in [&mut *mn, &mut *mx, &mut *sm] {
            col[0] = col[1];
            let last = col[w];
            col[w + 1..].fill(last);
        }
    }
    RowStats {
        cols: cols.map(|c| &*c),
    }
}

impl RowStats<'_> {
    /// Min, max and mean of each channel for the block of pixels starting at `x0`
    /// (as [`crate::kernels::for_each_row_stats`] combines its columns).
    #[inline(always)]
    fn block(&self, x0: usize) -> [[Lanes; 3]; 3] {
        let mut out = [[[0.0; LANES]; 3]; 3];
        for c in 0..3 {
            let col = |k: usize| -> &[f32; LANES + 2] {
                self.cols[3 * c + k][x0..x0 + LANES + 2]
                    .try_into()
                    .expect("a block")
            };
            let (mn, mx, sm) = (col(0), col(1), col(2));
            out[0][c] = lanes::each(|l| fmin(fmin(mn[l], mn[l + 1]), mn[l + 2]));
            out[1][c] = lanes::each(|l| fmax(fmax(mx[l], mx[l + 1]), mx[l + 2]));
            out[2][c] = lanes::each(|l| (sm[l] + sm[l + 1] + sm[l + 2]) * (1.0 / 9.0));
        }
        out
    }

    /// Mean of the squares of each channel for the block at `x0` (filled by
    /// [`column_stats`] with `squares` only).
    #[inline(always)]
    fn mean_sq(&self, x0: usize) -> [Lanes; 3] {
        lanes::each(|c| {
            let sq: &[f32; LANES + 2] = self.cols[9 + c][x0..x0 + LANES + 2].try_into().expect("a block");
            lanes::each(|l| (sq[l] + sq[l + 1] + sq[l + 2]) * (1.0 / 9.0))
        })
    }
}

/// `N` lanes of row `s` from pixel `x0`, padding with `pad` past `n` pixels.
#[inline(always)]
fn lanes_of<T: Copy>(s: &[T], x0: usize, n: usize, pad: T) -> [T; LANES] {
    if x0 + LANES <= n {
        *<&[T; LANES]>::try_from(&s[x0..x0 + LANES]).expect("a block")
    } else {
        std::array::from_fn(|l| if x0 + l < n { s[x0 + l] } else { pad })
    }
}

/// The repaired-input flags of the block at `x0` as bits (lane `l` is bit `l`; none past
/// the row's `n` pixels, none without flags).
#[inline(always)]
fn invalid_bits(invalid: Option<&[bool]>, x0: usize, n: usize) -> u32 {
    invalid.map_or(0, |v| lanes::bits_of(&lanes_of(v, x0, n, false)))
}

/// Stage `feature` of one row (Iglesias-Guitian et al. 2016, sec. 5.1): the temporal feature `z` of each pixel from
/// its previous feature, the 3x3 mean (the low-pass) and luma range, and its speed; the
/// input itself where there is no history, the previous feature where the input was
/// repaired.
#[allow(clippy::too_many_arguments)]
fn feature_row(
    stats: &RowStats,
    working: [&[f32]; 3],
    fetched: &[Fetched],
    invalid: Option<&[bool]>,
    p: &Params,
    w: usize,
    z: &mut [[Lanes; 3]],
) {
    for ((b, f), zb) in fetched.iter().enumerate().zip(z) {
        let x0 = b * LANES;
        let [min, max, mean] = stats.block(x0);
        let input: [Lanes; 3] = lanes::each(|c| lanes_of(working[c], x0, w, 0.0));
        let prev: [Lanes; 3] = lanes::each(|c| f.state[Z + c]);
        let inv = lanes::mask_of_bits(invalid_bits(invalid, x0, w));
        let none = lanes::mask_of_bits(f.none);
        let lowpass = lanes::ycocg_to_rgb(&mean);
        let acc = accumulate_lanes(&prev, &lowpass, &min[0], &max[0], &f.speed, p);
        *zb = lanes::each(|c| {
            let kept = inv.select(lanes::v(&prev[c]), lanes::v(&acc[c]));
            none.select(lanes::v(&input[c]), kept).to_array()
        });
    }
}

/// A model reset to colour `c` with `P = p I` ([`super::Model::reset`]) where `m` is set.
#[inline(always)]
fn reset_where(bits: u32, beta: &mut [[Lanes; D]; 3], r: &mut [Lanes; P_LEN], c: &[Lanes; 3], p: f32) {
    // Most blocks reset nothing (a reset follows a cut, a disocclusion or a clip).
    if bits == 0 {
        return;
    }
    let m = lanes::mask_of_bits(bits);
    let init = rls::init_information(p);
    let zero = f32x8::splat(0.0);
    for ch in 0..3 {
        beta[ch][0] = m.select(lanes::v(&c[ch]), lanes::v(&beta[ch][0])).to_array();
        for j in 1..D {
            beta[ch][j] = m.select(zero, lanes::v(&beta[ch][j])).to_array();
        }
    }
    for k in 0..P_LEN {
        r[k] = m.select(f32x8::splat(init[k]), lanes::v(&r[k])).to_array();
    }
}

/// [`super::Model::clip`] where bit `l` of `bits` is set: the model whose prediction `pred`
/// left the box, after its prediction was clipped to `c` (RGB).
#[inline(always)]
fn clip_where(
    bits: u32,
    beta: &mut [[Lanes; D]; 3],
    r: &mut [Lanes; P_LEN],
    pred: &[Lanes; 3],
    c: &[Lanes; 3],
    p: &Params,
) {
    if bits == 0 {
        return;
    }
    let m = lanes::mask_of_bits(bits);
    let v = lanes::v;
    let pick = |a: f32x8, b: &Lanes| m.select(a, v(b)).to_array();
    match p.on_clip {
        OnClip::Reset => {
            for ch in 0..3 {
                beta[ch][0] = pick(v(&c[ch]), &beta[ch][0]);
                for j in 1..D {
                    beta[ch][j] = pick(f32x8::splat(0.0), &beta[ch][j]);
                }
            }
        }
        OnClip::Shift => {
            for ch in 0..3 {
                let shifted = v(&beta[ch][0]) + (v(&c[ch]) - v(&pred[ch]));
                beta[ch][0] = pick(shifted, &beta[ch][0]);
            }
        }
    }
    relax_lanes(bits, r, f32x8::splat(p.clip_keep), p.clip_p);
}

/// [`super::Model::relax`] in the lanes of `bits`, each with its own `keep`: `R = keep R +
/// (1 - keep) I / clip_p`, and `I / clip_p` itself where `keep` is 0.
fn relax_lanes(bits: u32, r: &mut [Lanes; P_LEN], keep: f32x8, clip_p: f32) {
    if bits == 0 {
        return;
    }
    let m = lanes::mask_of_bits(bits);
    let v = lanes::v;
    let init = rls::init_information(clip_p);
    let rest = f32x8::splat(1.0) - keep;
    let zero = keep.simd_eq(f32x8::splat(0.0));
    for k in 0..P_LEN {
        let i = f32x8::splat(init[k]);
        // `keep * v + (1 - keep) * init`, as [`super::Model::relax`].
        let relaxed = zero.select(i, keep * v(&r[k]) + rest * i);
        r[k] = m.select(relaxed, v(&r[k])).to_array();
    }
}

/// [`super::jump`] in lanes.
fn jump_lanes(v: &Lanes, v_prev: &Lanes, speed_jump: f32) -> f32x8 {
    let one = f32x8::splat(1.0);
    if speed_jump == 0.0 {
        return one;
    }
    let d = (lanes::v(v) - lanes::v(v_prev)).abs() / f32x8::splat(speed_jump);
    one + lanes::min_of(d, one)
}

/// [`super::ramp`] in lanes.
fn ramp_lanes(lo: &[Lanes; 3], hi: &[Lanes; 3], p: &Params) -> f32x8 {
    let e = |c: usize| lanes::v(&hi[c]) - lanes::v(&lo[c]);
    let extent = lanes::max_of(lanes::max_of(e(0), e(1)), e(2));
    lanes::max_of(f32x8::splat(p.fail_ramp), f32x8::splat(p.fail_ramp_box) * extent)
}

/// [`super::miss`] in lanes: 0 where `moved` is clear, else `min(1, d / ramp)` with `d`
/// the largest channel of `|pred - clipped|` (1 where `ramp` is 0).
fn miss_lanes(pred: &[Lanes; 3], clipped: &[Lanes; 3], moved: u32, ramp: f32x8) -> f32x8 {
    let m = lanes::mask_of_bits(moved);
    let d = |c: usize| (lanes::v(&pred[c]) - lanes::v(&clipped[c])).abs();
    let d = lanes::max_of(lanes::max_of(d(0), d(1)), d(2));
    let one = f32x8::splat(1.0);
    let share = ramp
        .simd_eq(f32x8::splat(0.0))
        .select(one, lanes::min_of(d / ramp, one));
    m.select(share, f32x8::splat(0.0))
}

/// Row `y`'s 3x3 range of [`history_depth`] (edges clamped), low and high, in the first
/// two of `bufs` (`wp` long, the padding 0), the other two the per-column ranges.
fn depth_range_row<'a>(
    depth: &[f32],
    w: usize,
    h: usize,
    y: usize,
    wp: usize,
    bufs: &'a mut [Vec<f32>; 4],
) -> [&'a [f32]; 2] {
    let [lo, hi, col_lo, col_hi] = bufs.each_mut().map(|v| sized(v, wp));
    let rows = [y.saturating_sub(1), y, (y + 1).min(h - 1)].map(|r| &depth[r * w..(r + 1) * w]);
    for x in 0..w {
        let [a, b, c] = rows.map(|r| history_depth(r[x]));
        col_lo[x] = a.min(b).min(c);
        col_hi[x] = a.max(b).max(c);
    }
    for x in 0..w {
        let (l, r) = (x.saturating_sub(1), (x + 1).min(w - 1));
        lo[x] = col_lo[l].min(col_lo[x]).min(col_lo[r]);
        hi[x] = col_hi[l].max(col_hi[x]).max(col_hi[r]);
    }
    lo[w..].fill(0.0);
    hi[w..].fill(0.0);
    [lo, hi]
}

/// A row's depth, where the frame has it, and its 3x3 range ([`depth_range_row`]) where
/// `depth_jump` reads it.
type RowDepths<'a> = Option<(&'a [f32], Option<[&'a [f32]; 2]>)>;

/// [`super::depth_share`] in lanes.
fn depth_share_lanes(lo: &Lanes, hi: &Lanes, d_prev: &Lanes, v: &Lanes, depth_jump: f32) -> f32x8 {
    let (lo, hi, b) = (lanes::v(lo), lanes::v(hi), lanes::v(d_prev));
    let (zero, one) = (f32x8::splat(0.0), f32x8::splat(1.0));
    let below = (lo - b) / b;
    let above = (b - hi) / hi;
    let share = lanes::min_of(
        lanes::max_of(lanes::max_of(below, above), zero) / f32x8::splat(depth_jump),
        one,
    ) * lanes::min_of(lanes::v(v) / f32x8::splat(DEPTH_JUMP_SPEED), one);
    (b.simd_gt(zero) & hi.simd_gt(zero)).select(share, zero)
}

/// Stage `model` of one row: Algorithm 1 lines 11-22 (Iglesias-Guitian et al. 2016) on blocks of eight pixels: the
/// fetched model (or a new one), its prediction tested against the 3x3 box and clipped
/// toward the input with a reset, the RLS update, the output; writes the state texels.
#[allow(clippy::too_many_arguments)]
fn model_row(
    stats: &RowStats,
    working: [&[f32]; 3],
    ycocg: [&[f32]; 3],
    fetched: &[Fetched],
    z: &[[Lanes; 3]],
    depths: RowDepths,
    invalid: Option<&[bool]>,
    plan: &Plan,
    w: usize,
    out: [&mut [f32]; 3],
    next: &mut [f32],
) -> Counts {
    let p = plan.p;
    let [or, og, ob] = out;
    let mut counts = Counts::default();
    let mut max_trace = f32x8::splat(0.0);
    for ((b, f), zl) in fetched.iter().enumerate().zip(z) {
        let x0 = b * LANES;
        let n = LANES.min(w - x0);
        let real = ALL >> (LANES - n);
        let [min, max, _] = stats.block(x0);
        let (lo, hi) = match p.test_box {
            TestBox::Minmax => (min, max),
            // The mean only here: the default box leaves it uncomputed.
            TestBox::Variance => {
                let mean = stats.block(x0)[2];
                lanes::variance_box(&min, &max, &mean, &stats.mean_sq(x0), p.test_gamma)
            }
        };
        let input: [Lanes; 3] = lanes::each(|c| lanes_of(working[c], x0, w, 0.0));
        let cur: [Lanes; 3] = lanes::each(|c| lanes_of(ycocg[c], x0, w, 0.0));
        // Flags as bits (lane `l` is bit `l`): `none` from the fetch, `active` the lanes
        // whose input was not repaired.
        let none = f.none;
        let active = !invalid_bits(invalid, x0, w) & ALL;
        let mut beta: [[Lanes; D]; 3] = lanes::each(|c| lanes::each(|j| f.state[BETA + c * D + j]));
        let mut r: [Lanes; P_LEN] = lanes::each(|k| f.state[R + k]);
        reset_where(none, &mut beta, &mut r, &input, p.p0);
        let x: [Lanes; D] = [lanes::splat(1.0), zl[0], zl[1], zl[2]];
        // Lines 12-19: predict; outside the 3x3 box -> clip toward the input and reset.
        let pred = rls::predict_lanes(&beta, &x);
        let pred_ycocg = lanes::rgb_to_ycocg(&pred);
        let (clipped, moved) = lanes::clip_toward_point(&pred_ycocg, &cur, &lo, &hi);
        let moved = moved & active;
        // A failure clips once it persists (`clip_after`): [`miss`](super::miss) and
        // [`strikes`](super::strikes) in `f32x8`, the same operations in the same order.
        // [`super::depth_share`]: a failure counts twice where the history's depth left
        // the 3x3 range, or the speed jumped, whichever is more.
        let (depth, range) = depths.unzip();
        let depth: Lanes = depth.map_or([0.0; LANES], |d| {
            lanes::map(&lanes_of(d, x0, w, 0.0), history_depth)
        });
        let depth_jump = match range.flatten() {
            Some([dlo, dhi]) => {
                let share = depth_share_lanes(
                    lanes::block(dlo, x0),
                    lanes::block(dhi, x0),
                    &f.state[DEPTH],
                    &f.speed,
                    p.depth_jump,
                );
                f32x8::splat(1.0) + share
            }
            None => f32x8::splat(1.0),
        };
        let hit = miss_lanes(&pred_ycocg, &clipped, moved, ramp_lanes(&lo, &hi, p))
            * lanes::max_of(jump_lanes(&f.speed, &f.state[V], p.speed_jump), depth_jump);
        let count_v = f32x8::splat(STRIKE_DECAY) * lanes::v(&f.state[S]) + hit;
        let zero = f32x8::splat(0.0);
        // `hit > 0` only where the prediction moved (`miss` is 0 elsewhere).
        let clip = (hit.simd_gt(zero) & count_v.simd_ge(f32x8::splat(p.clip_after))).to_bitmask();
        let count: Lanes = count_v.to_array();
        clip_where(clip, &mut beta, &mut r, &pred, &lanes::ycocg_to_rgb(&clipped), p);
        // [`super::fail_relax`]: `1 - min(hit, 1) (1 - fail_keep)`; lanes kept whole are
        // left as they are (the reference skips them).
        let one = f32x8::splat(1.0);
        let keep = one - lanes::min_of(hit, one) * f32x8::splat(1.0 - p.fail_keep);
        let relaxing = !clip & keep.simd_ne(f32x8::splat(1.0)).to_bitmask();
        relax_lanes(relaxing, &mut r, keep, p.clip_p);
        // Lines 19-21: error of the (possibly reset) model, RLS update.
        let pred = rls::predict_lanes(&beta, &x);
        let e: [Lanes; 3] = lanes::each(|c| (lanes::v(&input[c]) - lanes::v(&pred[c])).to_array());
        let lambda: Lanes = if p.lambda_moving == 0.0 {
            lanes::splat(p.lambda)
        } else {
            lanes::map(&f.speed, |v| super::forgetting(v, p))
        };
        let (trace, failed) =
            rls::update_information_lanes(&mut beta, &mut r, &x, &e, &lambda, plan.prior, active);
        reset_where(failed, &mut beta, &mut r, &input, p.p0);
        // Every coefficient finite: `b * 0` is zero for a finite `b` and NaN for an
        // infinite or NaN one, so the sum is zero exactly when all are finite (float
        // lanes, which stay in vectors where a flag per coefficient would not).
        let mut probe = f32x8::splat(0.0);
        for b in &beta {
            // Four at a time, so the loop unrolls.
            for c in b {
                probe += lanes::v(c) * f32x8::splat(0.0);
            }
        }
        let broken = probe.simd_ne(f32x8::splat(0.0)).to_bitmask() & active;
        reset_where(broken, &mut beta, &mut r, &input, p.p0);
        // Line 22: the output.
        let o = rls::predict_lanes(&beta, &x);
        let fresh_n = (none & real).count_ones() as u64;
        counts.pixels.history_reset += fresh_n;
        counts.offscreen += if plan.has_history { fresh_n } else { 0 };
        counts.pixels.history_clipped += (clip & real).count_ones() as u64;
        counts.repaired += ((failed & real).count_ones() + (broken & real).count_ones()) as u64;
        // Traces are at least 0 (0 where nothing was updated), as `max_trace` starts; the
        // row's lanes are folded at its end (`f32::max` ignores NaN, as `max_of` with a
        // NaN first operand, and the order of a maximum does not matter).
        let real_trace = lanes::mask_of_bits(real).select(lanes::v(&trace), f32x8::splat(0.0));
        max_trace = lanes::max_of(real_trace, max_trace);
        for (c, row) in [&mut *or, &mut *og, &mut *ob].into_iter().enumerate() {
            // `f32::clamp` written as comparisons (NaN passes, as there), in `f32x8` (as a
            // lane loop it stayed scalar).
            let (v, zero, hi) = (lanes::v(&o[c]), f32x8::splat(0.0), f32x8::splat(plan.hi));
            let v: Lanes = v
                .simd_lt(zero)
                .select(zero, v.simd_gt(hi).select(hi, v))
                .to_array();
            lanes::store(row, x0, &v);
        }
        let mut state = [[0.0; LANES]; TEXEL];
        for c in 0..3 {
            for j in 0..D {
                state[BETA + c * D + j] = beta[c][j];
            }
            state[Z + c] = zl[c];
        }
        state[R..R + P_LEN].copy_from_slice(&r);
        state[S] = count;
        state[V] = f.speed;
        state[DEPTH] = depth;
        lanes::store_texels(&state, &mut next[TEXEL * x0..TEXEL * (x0 + n)]);
    }
    counts.max_trace = max_trace.to_array().into_iter().fold(counts.max_trace, f32::max);
    counts
}
