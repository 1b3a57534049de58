//! `traa`'s stages fused into one pass over bands of rows ([`par_bands_strided`]), and the
//! sharpen in a second band pass (it reads the finished output of the rows around it).
//!
//! A band task computes each stage for its rows, plus the halo of rows that the next
//! stage's 3x3 reads, into band-local buffers: the working colour, the lumas and depth /
//! far three rows beyond the band (the Sobel of a row reads the rows next to it, the Sobel
//! history the raw Sobel around it, and the aliased value the Sobel history around it), the
//! raw Sobel two rows beyond, the dilated motion, the history fetch and the Sobel history
//! one row beyond. The reference's 25-odd full-plane temporaries are gone. Buffers that a
//! 3x3 reads hold each row with one column of edge padding on each side, so the clamped
//! 3x3 of every pixel, border included, is one block of [`LANES`] pixels read at fixed
//! offsets: every stage but the dilation and the history fetch (a gather at each pixel's
//! own position) runs in lanes.
//!
//! Every stage computes what the reference ([`super::reference`]) computes, with the same
//! float operations in the same order, so the outputs are the same bits; the tests compare
//! them frame by frame. Minima and maxima use [`fmin`] / [`fmax`], which agree with the
//! reference's `f32::min` / `max` on the repaired, finite input (the values they see are
//! never NaN, and a sign of zero cannot change what follows them).

use super::{
    feedback_v, mix_v, Params, StagePlan, Traa, Variant, DEPTH_DISTANCE_MIN, SOBEL_LIT_WEIGHT,
    SOBEL_UNLIT_WEIGHT,
};
use crate::filters::passes::{
    dilate_row, on_screen_bits, output_ceiling, previous_positions, tonemap_row, untonemap_row, FrameContext,
    FrameResult,
};
use crate::frame::{Plane, Rgb};
use crate::kernels::lanes::{self, block, mask_of_bits, Lanes, Mask, LANES};
use crate::kernels::{fmax, luma, luma_v, sharpen_cross, sobel_magnitude_v, BilinearLanes};
use crate::pipeline::exec::{par_bands, par_bands_strided, sized, StageClock};
use crate::pipeline::{FilterError, FilterKind, FrameFacts, Inputs, PixelCounts, Recorder, Skip};
use std::ops::Range;
use wide::f32x8;

/// Stages of the fused pass, in order (indices into its [`StageClock`]): the filter's
/// stages less `repair` and `reconstruct` (run before it) and `sharpen` (a pass of its own).
const STAGES: [&str; 10] = {
    let s = <Traa as FilterKind>::STAGES;
    [s[2], s[3], s[4], s[5], s[6], s[7], s[8], s[9], s[10], s[12]]
};
const TONEMAP: usize = 0;
const DILATE: usize = 1;
const REPROJECT: usize = 2;
const SOBEL: usize = 3;
const SOBEL_HISTORY: usize = 4;
const MODEL_AVERAGE: usize = 5;
const DEPTH_VARIANCE: usize = 6;
const ALIASED: usize = 7;
const RESOLVE: usize = 8;
const UNTONEMAP: usize = 9;

/// What the pass reads for one frame.
struct Sources<'a> {
    w: usize,
    h: usize,
    color: [&'a [f32]; 3],
    /// Albedo (improved only).
    albedo: Option<[&'a [f32]; 3]>,
    /// Object ids (improved only).
    ids: Option<&'a [u32]>,
    /// Linear depth (for the dilation, and depth / far when improved).
    depth: Option<&'a [f32]>,
    /// The far distance that depth is divided by (improved with depth).
    far: f32,
    motion: Option<[&'a [f32]; 2]>,
    invalid: Option<&'a [bool]>,
    /// The history's texels, when there is one.
    texels: Option<&'a [f32]>,
    /// The history's depth / far (improved with depth and history).
    prev_depth: Option<&'a [f32]>,
}

/// Which stages run, and the knobs.
#[derive(Clone, Copy)]
struct Plan {
    improved: bool,
    tonemap: bool,
    dilate: bool,
    reproject: bool,
    /// The Sobel history's own TRAA (improved, with history).
    sobel_history: bool,
    /// Depth / far, its Sobel and the depth pseudo-variances (improved, with depth).
    depth: bool,
    /// Eq. 4.1 (improved, with object ids).
    model_average: bool,
    /// Colour goes back to linear in this pass (without a sharpen).
    untonemap: bool,
    feedback_min: f32,
    feedback_max: f32,
}

/// Rows `first..` of an image, `stride` samples each, in a buffer reused across bands.
#[derive(Default)]
struct Rows<T> {
    v: Vec<T>,
    first: usize,
    stride: usize,
}

impl<T: Copy + Default> Rows<T> {
    /// Holds rows `rows` from now on (contents unspecified).
    fn hold(&mut self, rows: &Range<usize>, stride: usize) {
        self.first = rows.start;
        self.stride = stride;
        let n = rows.len() * stride;
        if self.v.len() < n {
            self.v.resize(n, T::default());
        }
    }

    fn row(&self, r: usize) -> &[T] {
        let at = (r - self.first) * self.stride;
        &self.v[at..at + self.stride]
    }

    fn row_mut(&mut self, r: usize) -> &mut [T] {
        let at = (r - self.first) * self.stride;
        &mut self.v[at..at + self.stride]
    }

    /// Rows `r - 1`, `r`, `r + 1`, clamped into the image of height `h`.
    fn rows3(&self, r: usize, h: usize) -> [&[T]; 3] {
        [
            self.row(r.saturating_sub(1)),
            self.row(r),
            self.row((r + 1).min(h - 1)),
        ]
    }
}

/// One band task's buffers, reused across the bands it runs and across frames' tasks.
/// Padded rows (pixel `x` at `x + 1`, edges repeated) for what a 3x3 reads; the others hold
/// pixel `x` at `x`.
#[derive(Default)]
struct Band {
    /// The working colour (padded).
    work: [Rows<f32>; 3],
    /// Luma of the working colour, of the albedo, and depth / far (padded).
    lit: Rows<f32>,
    unlit: Rows<f32>,
    depth01: Rows<f32>,
    /// Raw and stabilised Sobel (padded).
    raw: Rows<f32>,
    stable: Rows<f32>,
    /// Dilated motion.
    motion: [Rows<f32>; 2],
    /// Reprojected history: r, g, b and (improved) the Sobel history.
    hist: [Rows<f32>; 4],
    /// Reprojected depth / far of the history (the band's rows).
    prev_depth: Rows<f32>,
    /// Whether the history is used here (there is one, and the previous position is on
    /// screen), and whether the input was repaired here.
    valid: Rows<bool>,
    invalid: Rows<bool>,
    /// One row each: eq. 4.1, eq. 4.4-4.6, eq. 4.12-4.14.
    model_average: Vec<f32>,
    depth_variance: Vec<f32>,
    aliased: Vec<f32>,
}

/// Samples per band row: the width in whole blocks, and a column of padding each side.
fn stride(w: usize) -> usize {
    w.next_multiple_of(LANES) + 2
}

/// The columns a block of [`LANES`] pixels reads in a padded row: one more on each side.
const SPAN: usize = LANES + 2;

/// The blocks of [`LANES`] pixels covering a row of `w`: the first pixel and how many of
/// the block's lanes are pixels.
fn blocks(w: usize) -> impl Iterator<Item = (usize, usize)> {
    (0..w).step_by(LANES).map(move |x0| (x0, (w - x0).min(LANES)))
}

/// Repeats the edge pixels of a padded row of `w` pixels into its padding.
fn pad(row: &mut [f32], w: usize) {
    row[0] = row[1];
    row[w + 1] = row[w];
}

/// The nine taps of the 3x3s of a block's eight lanes from three padded spans, row-major:
/// tap `k` of every lane as one vector.
#[inline(always)]
fn taps_v(t: &[&[f32; SPAN]; 3]) -> [f32x8; 9] {
    let at = |r: usize, c: usize| f32x8::from(*block::<f32, LANES>(t[r], c));
    [
        at(0, 0),
        at(0, 1),
        at(0, 2),
        at(1, 0),
        at(1, 1),
        at(1, 2),
        at(2, 0),
        at(2, 1),
        at(2, 2),
    ]
}

/// The spans of a block in three padded rows.
#[inline(always)]
fn spans<'a>(rows: &[&'a [f32]; 3], x0: usize) -> [&'a [f32; SPAN]; 3] {
    [block(rows[0], x0), block(rows[1], x0), block(rows[2], x0)]
}

/// Runs `traa`'s stages from `tonemap` to `untonemap` for one frame.
pub(super) fn frame(
    p: &Params,
    near_far: Option<[f32; 2]>,
    ctx: FrameContext<'_, '_>,
) -> Result<FrameResult, FilterError> {
    let (inp, rec, has_history, read, next, scratch) = ctx.into_parts();
    let (w, h) = (inp.width, inp.height);
    let skips = StagePlan::new(p, &inp, has_history);
    let plan = plan(&skips, p, has_history);
    let src = sources(&inp, &plan, near_far, has_history, read);
    let mut out: Rgb = scratch.planes(w, h);
    let clock = StageClock::<10>::default();
    let t = std::time::Instant::now();
    let pixels = fused_pass(&src, &plan, &clock, &mut out, next);
    let ms = t.elapsed().as_secs_f64() * 1e3;
    let shares = clock.shares();
    skips.record_fused(rec, plan.improved, ms, &shares);
    match skips.sharpen {
        Some(why) => {
            rec.skip("sharpen", why);
            record_untonemap(rec, skips.tonemap, ms * shares[UNTONEMAP]);
        }
        None => {
            let mut sharp: Rgb = scratch.planes(w, h);
            let (ms, shares) = sharpen_pass(p, &out, &mut sharp, &inp.facts, plan.tonemap);
            rec.ran_for("sharpen", ms * shares[0]);
            record_untonemap(rec, skips.tonemap, ms * shares[1]);
            scratch.recycle(std::mem::replace(&mut out, sharp));
        }
    }
    Ok(FrameResult {
        color: out,
        pixels,
        model: None,
    })
}

impl StagePlan {
    /// Records the fused pass's stages from `tonemap` to `resolve` (`sobel_history` only
    /// in the improved variant): their `shares` of its time `ms`, or why they were left out.
    fn record_fused(&self, rec: &mut Recorder, improved: bool, ms: f64, shares: &[f64; 10]) {
        // `sharpen` and `untonemap` follow, recorded by the caller.
        for (name, skip) in self
            .stages(improved)
            .into_iter()
            .filter(|(n, _)| *n != "sharpen" && *n != "untonemap")
        {
            let k = STAGES.iter().position(|s| *s == name).expect("a fused stage");
            match skip {
                Some(why) => rec.skip(name, why),
                None => rec.ran_for(name, ms * shares[k]),
            }
        }
    }
}

/// Which stages the fused pass runs (as `skips` plans them), and its knobs.
fn plan(skips: &StagePlan, p: &Params, has_history: bool) -> Plan {
    let improved = p.variant == Variant::Improved;
    Plan {
        improved,
        tonemap: skips.tonemap.is_none(),
        dilate: skips.dilate.is_none(),
        reproject: skips.reproject.is_none(),
        sobel_history: improved && has_history,
        depth: skips.depth.is_none(),
        model_average: skips.model.is_none(),
        untonemap: skips.tonemap.is_none() && skips.sharpen.is_some(),
        feedback_min: p.feedback_min,
        feedback_max: p.feedback_max,
    }
}

/// Records `untonemap`: `ms`, or why it was left out (`tonemap`'s reason).
fn record_untonemap(rec: &mut Recorder, tonemap: Option<Skip>, ms: f64) {
    match tonemap {
        Some(why) => rec.skip("untonemap", why),
        None => rec.ran_for("untonemap", ms),
    }
}

/// What the fused pass reads for a frame with inputs `inp` and the history `read`.
fn sources<'a>(
    inp: &'a Inputs,
    plan: &Plan,
    near_far: Option<[f32; 2]>,
    has_history: bool,
    read: &'a [Plane<f32>],
) -> Sources<'a> {
    let improved = plan.improved;
    let depth = inp.depth.as_deref().map(|d| d.data());
    // Depth / far (improved): far from the frame's planes, else its largest depth.
    let far = match (plan.depth, depth) {
        (true, Some(d)) => far(near_far, d),
        _ => 1.0,
    };
    Sources {
        w: inp.width,
        h: inp.height,
        color: inp.color_slices(),
        albedo: inp
            .albedo
            .as_deref()
            .filter(|_| improved)
            .map(|a| a.each_ref().map(|p| p.data())),
        ids: inp.object_id.filter(|_| improved).map(|p| p.data()),
        depth,
        far,
        motion: inp.motion.as_deref().map(|m| m.each_ref().map(|p| p.data())),
        invalid: inp.invalid.as_deref(),
        texels: has_history.then(|| read[0].data()),
        prev_depth: read
            .get(1)
            .filter(|_| has_history && plan.depth)
            .map(|p| p.data()),
    }
}

/// The fused pass over the frame's bands ([`run_band`]) into `out` and the next history's
/// planes `next` (the texels, and depth / far when the history keeps it).
fn fused_pass(
    src: &Sources,
    plan: &Plan,
    clock: &StageClock<10>,
    out: &mut Rgb,
    next: &mut [Plane<f32>],
) -> PixelCounts {
    let (w, h) = (src.w, src.h);
    let [o0, o1, o2] = out.each_mut().map(|p| p.data_mut());
    match next {
        [texels, depth01] => par_bands_strided(
            [o0, o1, o2, texels.data_mut(), depth01.data_mut()],
            [w, w, w, 4 * w, w],
            h,
            |band: &mut Band, rows, [or, og, ob, texels, depth01]| {
                run_band::<4>(src, plan, clock, band, rows, [or, og, ob], texels, Some(depth01))
            },
        ),
        [texels] => par_bands_strided(
            [o0, o1, o2, texels.data_mut()],
            [w, w, w, 3 * w],
            h,
            |band: &mut Band, rows, [or, og, ob, texels]| {
                run_band::<3>(src, plan, clock, band, rows, [or, og, ob], texels, None)
            },
        ),
        _ => unreachable!("traa keeps one or two history planes"),
    }
}

/// The sharpen pass over bands of `out` into `sharp` (and `untonemap` in the same pass when
/// the colour is tonemapped): its time in ms and the shares of its two stages.
fn sharpen_pass(
    p: &Params,
    out: &Rgb,
    sharp: &mut Rgb,
    facts: &FrameFacts,
    untonemap: bool,
) -> (f64, [f64; 2]) {
    let (w, h) = out[0].size();
    let strength = Traa::sharpen_strength(p);
    let clock = StageClock::<2>::default();
    let t = std::time::Instant::now();
    {
        let src = out.each_ref().map(|p| p.data());
        let [s0, s1, s2] = sharp.each_mut().map(|p| p.data_mut());
        par_bands([s0, s1, s2], w, h, |_: &mut (), rows, band| {
            sharpen_band(
                src,
                w,
                h,
                strength,
                output_ceiling(facts),
                untonemap,
                &clock,
                rows.clone(),
                band,
            );
            rows.len()
        });
    }
    (t.elapsed().as_secs_f64() * 1e3, clock.shares())
}

/// The far distance depth is divided by (improved): the frame's far plane `near_far`,
/// else the largest of `depth`; at least the smallest normal f32.
pub(super) fn far(near_far: Option<[f32; 2]>, depth: &[f32]) -> f32 {
    near_far
        .map(|nf| nf[1])
        .unwrap_or_else(|| largest(depth))
        .max(f32::MIN_POSITIVE)
}

/// The largest sample of a plane, at least 0 (the reference's fold of `f32::max` from 0,
/// in lanes: the same value for finite samples).
fn largest(d: &[f32]) -> f32 {
    use rayon::prelude::*;
    crate::pipeline::exec::pool().install(|| {
        d.par_chunks(1 << 16)
            .map(|c| {
                let mut m = [0.0f32; LANES];
                let mut it = c.chunks_exact(LANES);
                for b in &mut it {
                    m = lanes::each(|l| fmax(m[l], b[l]));
                }
                it.remainder()
                    .iter()
                    .fold(m.into_iter().fold(0.0, f32::max), |a, &v| a.max(v))
            })
            .reduce(|| 0.0, f32::max)
    })
}

/// One band: the stages over the band's rows and their halos, into the band buffers, then
/// row by row the model average, depth variance, aliased value and resolve. `N`: channels
/// of the history texels (3: baseline, 4: improved, the Sobel history fourth).
#[allow(clippy::too_many_arguments)]
fn run_band<const N: usize>(
    src: &Sources,
    plan: &Plan,
    clock: &StageClock<10>,
    band: &mut Band,
    rows: Range<usize>,
    out: [&mut [f32]; 3],
    next: &mut [f32],
    next_depth: Option<&mut [f32]>,
) -> PixelCounts {
    let h = src.h;
    let grow = |k: usize| rows.start.saturating_sub(k)..(rows.end + k).min(h);
    // Rows with a halo of 1 (what the resolve's and the aliased value's 3x3 read), 2 (the
    // raw Sobel the Sobel history's 3x3 reads) and 3 (what the raw Sobel reads).
    let (r1, r2, r3) = (grow(1), grow(2), grow(3));
    // The working colour (and its luma, the albedo's and depth / far for the Sobel).
    let prep = if plan.improved { r3 } else { r1.clone() };
    band.tonemap(src, plan, clock, &prep);
    if plan.improved {
        clock.time(SOBEL, || band.sobel(src, plan, &prep, &r2));
    }
    band.history::<N>(src, plan, clock, &rows, &r1);
    if plan.sobel_history {
        band.sobel_history(src, plan, clock, &r1);
    }
    band.resolve_rows::<N>(src, plan, clock, rows, out, next, next_depth)
}

impl Band {
    /// Stage `tonemap` for rows `prep`: the working colour (the input tonemapped, or as it
    /// is), padded.
    fn tonemap(&mut self, src: &Sources, plan: &Plan, clock: &StageClock<10>, prep: &Range<usize>) {
        let w = src.w;
        let work = &mut self.work;
        work.iter_mut().for_each(|b| b.hold(prep, stride(w)));
        clock.time(TONEMAP, || {
            for r in prep.clone() {
                let at = r * w..(r + 1) * w;
                let input = src.color.map(|c| &c[at.clone()]);
                let [a, b, c] = work.each_mut().map(|b| &mut b.row_mut(r)[1..w + 1]);
                if plan.tonemap {
                    tonemap_row(input, [a, b, c]);
                } else {
                    a.copy_from_slice(input[0]);
                    b.copy_from_slice(input[1]);
                    c.copy_from_slice(input[2]);
                }
                work.iter_mut().for_each(|b| pad(b.row_mut(r), w));
            }
        });
    }

    /// Stage `sobel` (improved): the luma of the working colour, the albedo's and depth /
    /// far for rows `prep` (padded), then the raw Sobel of rows `r2` from them.
    fn sobel(&mut self, src: &Sources, plan: &Plan, prep: &Range<usize>, r2: &Range<usize>) {
        let (w, h) = (src.w, src.h);
        let s = stride(w);
        let Band {
            work,
            lit,
            unlit,
            depth01,
            raw,
            ..
        } = self;
        lit.hold(prep, s);
        for r in prep.clone() {
            let [a, b, c] = work.each_ref().map(|b| &b.row(r)[1..w + 1]);
            let l = &mut lit.row_mut(r)[1..w + 1];
            for x in 0..w {
                l[x] = luma([a[x], b[x], c[x]]);
            }
            pad(lit.row_mut(r), w);
        }
        if let Some(alb) = src.albedo {
            unlit.hold(prep, s);
            for r in prep.clone() {
                let at = r * w..(r + 1) * w;
                let [a, b, c] = alb.map(|c| &c[at.clone()]);
                let u = &mut unlit.row_mut(r)[1..w + 1];
                for x in 0..w {
                    u[x] = luma([a[x], b[x], c[x]]);
                }
                pad(unlit.row_mut(r), w);
            }
        }
        if plan.depth {
            let d = src.depth.expect("planned");
            depth01.hold(prep, s);
            for r in prep.clone() {
                let dr = &d[r * w..(r + 1) * w];
                let o = &mut depth01.row_mut(r)[1..w + 1];
                for x in 0..w {
                    o[x] = dr[x] / src.far;
                }
                pad(depth01.row_mut(r), w);
            }
        }
        raw.hold(r2, s);
        for r in r2.clone() {
            let l = lit.rows3(r, h);
            let u = src.albedo.map(|_| unlit.rows3(r, h));
            let d = plan.depth.then(|| depth01.rows3(r, h));
            sobel_row(l, u, d, w, raw.row_mut(r));
        }
    }

    /// The history at each pixel's previous position (or in place when nothing moves) for
    /// the band's rows `rows` (and the halo `r1` when the Sobel history reads it), with
    /// whether it is used there (`valid`), whether the input was repaired there (`invalid`,
    /// rows `r1`) and the previous depth / far.
    fn history<const N: usize>(
        &mut self,
        src: &Sources,
        plan: &Plan,
        clock: &StageClock<10>,
        rows: &Range<usize>,
        r1: &Range<usize>,
    ) {
        let w = src.w;
        let s = stride(w);
        let Band {
            motion,
            hist,
            prev_depth,
            valid,
            invalid,
            ..
        } = self;
        valid.hold(r1, s);
        invalid.hold(r1, s);
        prev_depth.hold(rows, s);
        for r in r1.clone() {
            let iv = &mut invalid.row_mut(r)[..w];
            match src.invalid {
                Some(v) => iv.copy_from_slice(&v[r * w..(r + 1) * w]),
                None => iv.fill(false),
            }
        }
        hist.iter_mut().for_each(|b| b.hold(r1, s));
        // The Sobel history reads the history one row beyond the band; the resolve only the
        // band's rows.
        let fetch = if plan.sobel_history {
            r1.clone()
        } else {
            rows.clone()
        };
        match src.texels {
            None => r1.clone().for_each(|r| valid.row_mut(r).fill(false)),
            Some(texels) if plan.reproject => {
                motion.iter_mut().for_each(|b| b.hold(r1, s));
                for r in fetch {
                    let m: [&[f32]; 2] = if plan.dilate {
                        let (d, mv) = (src.depth.expect("planned"), src.motion.expect("planned"));
                        let [mx, my] = motion.each_mut().map(|b| &mut b.row_mut(r)[..w]);
                        clock.time(DILATE, || dilate_row(d, mv, w, src.h, r, mx, my));
                        motion.each_ref().map(|b| &b.row(r)[..w])
                    } else {
                        src.motion.expect("planned").map(|m| &m[r * w..(r + 1) * w])
                    };
                    let prev = src.prev_depth.filter(|_| rows.contains(&r));
                    let pd = &mut prev_depth.row_mut(r.clamp(rows.start, rows.end - 1))[..w];
                    let ok = &mut valid.row_mut(r)[..w];
                    let hr = hist.each_mut().map(|b| &mut b.row_mut(r)[..w]);
                    clock.time(REPROJECT, || {
                        reproject_row::<N>(texels, prev, w, src.h, r, m, ok, hr, pd)
                    });
                }
            }
            Some(texels) => clock.time(RESOLVE, || {
                for r in fetch {
                    valid.row_mut(r)[..w].fill(true);
                    let row = &texels[N * r * w..N * (r + 1) * w];
                    let hr = hist.each_mut().map(|b| &mut b.row_mut(r)[..w]);
                    for (x, t) in row.chunks_exact(N).enumerate() {
                        for c in 0..N {
                            hr[c][x] = t[c];
                        }
                    }
                    if let (Some(prev), true) = (src.prev_depth, rows.contains(&r)) {
                        prev_depth.row_mut(r)[..w].copy_from_slice(&prev[r * w..(r + 1) * w]);
                    }
                }
            }),
        }
    }

    /// Stage `sobel_history`: the Sobel image's own TRAA (sec. 4.3.3) for rows `r1`, from
    /// the raw Sobel and the history's fourth channel, into `stable`.
    fn sobel_history(&mut self, src: &Sources, plan: &Plan, clock: &StageClock<10>, r1: &Range<usize>) {
        let (w, h) = (src.w, src.h);
        let Band {
            raw,
            stable,
            hist,
            valid,
            invalid,
            ..
        } = self;
        stable.hold(r1, stride(w));
        clock.time(SOBEL_HISTORY, || {
            for r in r1.clone() {
                sobel_history_row(
                    raw.rows3(r, h),
                    hist[3].row(r),
                    valid.row(r),
                    invalid.row(r),
                    plan,
                    w,
                    stable.row_mut(r),
                );
            }
        });
    }

    /// Row by row: (improved) the model average, depth variance and aliased value, and
    /// depth / far into the next history's `next_depth`; the resolve into `out` and the next
    /// history's texels `next`; `untonemap` when it runs here. The Sobel read is the Sobel
    /// history's where it ran, else the raw Sobel.
    #[allow(clippy::too_many_arguments)]
    fn resolve_rows<const N: usize>(
        &mut self,
        src: &Sources,
        plan: &Plan,
        clock: &StageClock<10>,
        rows: Range<usize>,
        out: [&mut [f32]; 3],
        next: &mut [f32],
        next_depth: Option<&mut [f32]>,
    ) -> PixelCounts {
        let (w, h) = (src.w, src.h);
        let s = stride(w);
        let Band {
            work,
            depth01,
            raw,
            stable,
            hist,
            prev_depth,
            valid,
            invalid,
            model_average,
            depth_variance,
            aliased,
            ..
        } = self;
        let sobel: &Rows<f32> = if plan.sobel_history { stable } else { raw };
        let [or, og, ob] = out;
        let mut next_depth = next_depth;
        let mut counts = PixelCounts::default();
        for y in rows.clone() {
            let k = y - rows.start;
            if plan.improved {
                let ma: Option<&[f32]> = if plan.model_average {
                    let ma = sized(model_average, s);
                    clock.time(MODEL_AVERAGE, || {
                        model_average_row(src.ids.expect("planned"), w, h, y, ma)
                    });
                    Some(ma)
                } else {
                    None
                };
                let dv: Option<&[f32]> = if plan.depth {
                    let dv = sized(depth_variance, s);
                    clock.time(DEPTH_VARIANCE, || {
                        depth_variance_row(depth01.rows3(y, h), prev_depth.row(y), valid.row(y), w, dv)
                    });
                    Some(dv)
                } else {
                    None
                };
                let al = sized(aliased, s);
                clock.time(ALIASED, || aliased_row(sobel.rows3(y, h), ma, dv, w, al));
                if let (true, Some(nd)) = (plan.depth, next_depth.as_deref_mut()) {
                    nd[k * w..(k + 1) * w].copy_from_slice(&depth01.row(y)[1..w + 1]);
                }
            }
            let o = k * w..(k + 1) * w;
            let mut dst = [&mut or[o.clone()], &mut og[o.clone()], &mut ob[o.clone()]];
            let c = clock.time(RESOLVE, || {
                resolve_row::<N>(
                    work.each_ref().map(|b| b.rows3(y, h)),
                    hist.each_ref().map(|b| b.row(y)),
                    valid.row(y),
                    invalid.row(y),
                    plan.improved.then_some(&aliased[..]),
                    plan.improved.then(|| sobel.row(y)),
                    plan,
                    w,
                    &mut dst,
                    &mut next[N * o.start..N * o.end],
                )
            });
            counts += c;
            if plan.untonemap {
                clock.time(UNTONEMAP, || untonemap_row(dst));
            }
        }
        counts
    }
}

/// Stage `reproject` of row `y`: each pixel's previous position `p + motion`, whether it is
/// on screen (`ok`), and there the history's texels (bilinear, taken apart into `hist`) and
/// the previous depth / far (`prev` into `pd`, when given); eight pixels at a time, their
/// positions and bilinear footprints in vectors.
#[inline(never)]
#[allow(clippy::too_many_arguments)]
fn reproject_row<const N: usize>(
    texels: &[f32],
    prev: Option<&[f32]>,
    w: usize,
    h: usize,
    y: usize,
    m: [&[f32]; 2],
    ok: &mut [bool],
    hist: [&mut [f32]; 4],
    pd: &mut [f32],
) {
    let (mx, my, ok, pd) = (&m[0][..w], &m[1][..w], &mut ok[..w], &mut pd[..w]);
    let mut hist = hist.map(|r| &mut r[..w]);
    for x0 in (0..w).step_by(LANES) {
        let [px, py] = previous_positions(mx, my, x0, y);
        let on = on_screen_bits(&px, &py, w, h);
        let taps = BilinearLanes::at(&px, &py, w, h);
        if N < 4 && prev.is_none() {
            // Three channels (baseline): each lane's four taps as 4-float vectors (one
            // vector op per tap where it was one scalar op per channel), stored by one
            // transpose. With four channels (already one vector per tap) and the depth,
            // this block form measured slower: its transposes and gathers cost more than
            // they saved.
            let n = LANES.min(w - x0);
            for (l, ok) in ok[x0..x0 + n].iter_mut().enumerate() {
                *ok = on >> l & 1 != 0;
            }
            let t = lanes::load_texels(&taps.texels4::<N>(texels, w, h, on));
            for (row, t) in hist.iter_mut().zip(&t).take(N) {
                store_on(row, x0, on, t);
            }
            continue;
        }
        for l in 0..LANES.min(w - x0) {
            let x = x0 + l;
            ok[x] = on >> l & 1 != 0;
            if !ok[x] {
                continue;
            }
            let t = taps.texel::<N>(texels, w, h, l);
            for c in 0..N {
                hist[c][x] = t[c];
            }
            if let Some(prev) = prev {
                // One plane is a plane of one-channel texels: `bilinear`'s bits.
                pd[x] = taps.texel::<1>(prev, w, h, l)[0];
            }
        }
    }
}

/// A partial block's texels: pixel `l`'s colour and (with `sobel`, from its `l`th value)
/// Sobel history, for the `out.len() / N` first pixels.
#[inline(always)]
fn partial_texels<const N: usize>(value: &[Lanes; 3], sobel: Option<&[f32]>, out: &mut [f32]) {
    let texels = out.chunks_exact_mut(N);
    match sobel {
        Some(s) => {
            for (l, t) in texels.enumerate() {
                t.copy_from_slice(&[value[0][l], value[1][l], value[2][l], s[l]][..N]);
            }
        }
        None => {
            for (l, t) in texels.enumerate() {
                t.copy_from_slice(&[value[0][l], value[1][l], value[2][l]][..N]);
            }
        }
    }
}

/// Stores the lanes set in `on` (lane `l` is bit `l`) of a block from column `x0` that
/// lie in the row; the others keep what the row held.
#[inline(always)]
fn store_on(row: &mut [f32], x0: usize, on: u32, new: &Lanes) {
    match row.get_mut(x0..x0 + LANES) {
        Some(dst) => {
            let dst = <&mut [f32; LANES]>::try_from(dst).expect("eight lanes");
            *dst = mask_of_bits(on)
                .select(f32x8::from(*new), f32x8::from(*dst))
                .to_array();
        }
        None => {
            for (l, v) in row[x0..].iter_mut().enumerate() {
                if on >> l & 1 != 0 {
                    *v = new[l];
                }
            }
        }
    }
}

/// [`crate::kernels::sobel_magnitude`] of each lane's 3x3 in three padded spans.
#[inline(always)]
fn sobel_lanes(t: &[&[f32; SPAN]; 3]) -> f32x8 {
    sobel_magnitude_v(&taps_v(t))
}

/// Stage `sobel` of one row (eq. 4.9-4.10): the Sobel magnitudes of the lit luma, the
/// albedo luma and depth / far (padded rows above, here and below), combined and shaped;
/// into a padded row.
#[inline(never)]
fn sobel_row(
    lit: [&[f32]; 3],
    unlit: Option<[&[f32]; 3]>,
    depth01: Option<[&[f32]; 3]>,
    w: usize,
    out: &mut [f32],
) {
    for (x0, _) in blocks(w) {
        let l = sobel_lanes(&spans(&lit, x0));
        let surface = match unlit {
            Some(u) => {
                let u = sobel_lanes(&spans(&u, x0));
                f32x8::splat(SOBEL_UNLIT_WEIGHT) * u + f32x8::splat(SOBEL_LIT_WEIGHT) * l
            }
            None => l,
        };
        let d = match depth01 {
            Some(d) => sobel_lanes(&spans(&d, x0)),
            None => f32x8::splat(0.0),
        };
        let g = lanes::clamp01(surface + d);
        let v = (g * g * (f32x8::splat(3.0) - f32x8::splat(2.0) * g)).sqrt();
        *<&mut [f32; LANES]>::try_from(&mut out[x0 + 1..x0 + 1 + LANES]).expect("a block") = v.to_array();
    }
    pad(out, w);
}

/// Stage `sobel_history` of one row (sec. 4.3.3): the reprojected Sobel history `hist`
/// clamped into the averaged 3x3 and cross range of the raw Sobel (padded rows `raw`),
/// blended with INSIDE's feedback; the raw Sobel where the history is not used, the history
/// where the input was repaired. Into a padded row.
#[inline(never)]
fn sobel_history_row(
    raw: [&[f32]; 3],
    hist: &[f32],
    valid: &[bool],
    invalid: &[bool],
    plan: &Plan,
    w: usize,
    out: &mut [f32],
) {
    let (fmin_k, fmax_k) = (plan.feedback_min, plan.feedback_max);
    for (x0, _) in blocks(w) {
        let sp = spans(&raw, x0);
        let hs = f32x8::from(*block::<f32, LANES>(hist, x0));
        let ok = lanes::mask_from(block(valid, x0));
        let iv = lanes::mask_from(block(invalid, x0));
        let t = taps_v(&sp);
        // The reference's order: all nine taps, and the cross among them.
        let (mut lo3, mut hi3) = (t[0], t[0]);
        for &v in &t[1..] {
            lo3 = lanes::fmin_v(lo3, v);
            hi3 = lanes::fmax_v(hi3, v);
        }
        let (fmin_v, fmax_v) = (lanes::fmin_v, lanes::fmax_v);
        let lo_x = fmin_v(fmin_v(fmin_v(fmin_v(t[1], t[3]), t[4]), t[5]), t[7]);
        let hi_x = fmax_v(fmax_v(fmax_v(fmax_v(t[1], t[3]), t[4]), t[5]), t[7]);
        let r = t[4];
        let half = f32x8::splat(0.5);
        // `clamp_to_box`: `q.max(min).min(max)`.
        let hv = lanes::min_of(lanes::max_of(hs, half * (lo3 + lo_x)), half * (hi3 + hi_x));
        let k = feedback_v(r, hv, fmin_k, fmax_k);
        let blend = mix_v(r, hv, k);
        let v = ok.select(iv.select(hs, blend), r).to_array();
        *<&mut [f32; LANES]>::try_from(&mut out[x0 + 1..x0 + 1 + LANES]).expect("a block") = v;
    }
    pad(out, w);
}

/// Eq. 4.1 at one pixel: the share of its 3x3 (centre included, neighbours outside the
/// image count as the same object) whose object id differs from its own.
fn model_average_at(id: &[u32], w: usize, h: usize, x: usize, y: usize) -> f32 {
    let me = id[y * w + x];
    let mut diff = 0u32;
    for yy in y.saturating_sub(1)..=(y + 1).min(h - 1) {
        for xx in x.saturating_sub(1)..=(x + 1).min(w - 1) {
            diff += (id[yy * w + xx] != me) as u32;
        }
    }
    diff as f32 / 9.0
}

/// Stage `model_average` of row `y` (eq. 4.1): pixels with all eight neighbours in blocks
/// of lanes, the others one by one ([`model_average_at`]).
#[inline(never)]
fn model_average_row(id: &[u32], w: usize, h: usize, y: usize, out: &mut [f32]) {
    let mut x = 0;
    if y >= 1 && y + 1 < h {
        let up = &id[(y - 1) * w..y * w];
        let mid = &id[y * w..(y + 1) * w];
        let down = &id[(y + 1) * w..(y + 2) * w];
        // Pixel 0 first, then blocks of pixels 1.. whose right neighbours are inside.
        out[0] = model_average_at(id, w, h, 0, y);
        x = 1;
        while x + LANES < w {
            let t: [&[u32; SPAN]; 3] = [block(up, x - 1), block(mid, x - 1), block(down, x - 1)];
            let v: Lanes = lanes::each(|l| {
                let me = t[1][l + 1];
                let mut diff = 0u32;
                for row in &t {
                    for c in 0..3 {
                        diff += (row[l + c] != me) as u32;
                    }
                }
                diff as f32 / 9.0
            });
            out[x..x + LANES].copy_from_slice(&v);
            x += LANES;
        }
    }
    for x in x..w {
        out[x] = model_average_at(id, w, h, x, y);
    }
}

/// Stage `depth_variance` of one row (eq. 4.4-4.6): from the padded depth / far rows
/// around it and the reprojected previous depth / far `prev` where the history is used.
#[inline(never)]
fn depth_variance_row(d: [&[f32]; 3], prev: &[f32], valid: &[bool], w: usize, out: &mut [f32]) {
    for (x0, _) in blocks(w) {
        let sp = spans(&d, x0);
        let pv = f32x8::from(*block::<f32, LANES>(prev, x0));
        let ok = lanes::mask_from(block(valid, x0));
        let t = taps_v(&sp);
        let f = f32x8::splat;
        let (mut lo, mut hi, mut sum) = (t[0], t[0], f(0.0));
        for &v in &t {
            lo = lanes::fmin_v(lo, v);
            hi = lanes::fmax_v(hi, v);
            sum += v;
        }
        let avg = sum / f(9.0);
        let max_dist = lanes::min_of((lo - avg).abs(), (hi - avg).abs());
        // `powi(2)` and `powi(4)` as the compiler expands them: x x, and (x x)(x x).
        let q = (t[4] - avg).abs() / max_dist;
        let pv_ = q * q;
        let u = (pv - avg).abs() / max_dist;
        let tpv = ok.select((u * u) * (u * u), f(0.0));
        let v = max_dist
            .simd_lt(f(DEPTH_DISTANCE_MIN))
            .select(f(0.0), lanes::min_of(pv_ + tpv, f(1.0)))
            .to_array();
        out[x0..x0 + LANES].copy_from_slice(&v);
    }
}

/// Stage `aliased` of one row (eq. 4.12-4.14): `clamp01(sobelAvg + depth terms +
/// modelAverage)`, `sobelAvg` mixing the cross and 3x3 means of the (padded) Sobel rows by
/// `clamp01(modelAverage + sobel)`; absent terms are 0.
#[inline(never)]
fn aliased_row(sobel: [&[f32]; 3], ma: Option<&[f32]>, dv: Option<&[f32]>, w: usize, out: &mut [f32]) {
    let zero = [0.0f32; LANES];
    for (x0, _) in blocks(w) {
        let sp = spans(&sobel, x0);
        let m = f32x8::from(*ma.map_or(&zero, |m| block(m, x0)));
        let d = f32x8::from(*dv.map_or(&zero, |d| block(d, x0)));
        let t = taps_v(&sp);
        let f = f32x8::splat;
        let avg3 = (t[0] + t[1] + t[2] + t[3] + t[4] + t[5] + t[6] + t[7] + t[8]) / f(9.0);
        let avg_cross = (t[1] + t[3] + t[4] + t[5] + t[7]) / f(5.0);
        let sobel_avg = mix_v(avg_cross, avg3, lanes::clamp01(m + t[4]));
        let v = lanes::clamp01(sobel_avg + d + m).to_array();
        out[x0..x0 + LANES].copy_from_slice(&v);
    }
}

/// Stage `resolve` of one row: min/max of the 3x3 and the cross of the working colour
/// (padded rows `cur[c]` of each channel), the box (averaged, or eq. 4.15-4.16 with the
/// aliased value when improved), the history clipped toward its centre, INSIDE's
/// feedback; writes the output (working space) and the new history's texels (`N = 4`: the
/// Sobel history from `sobel`, padded, fourth).
#[allow(clippy::too_many_arguments)]
#[inline(never)]
fn resolve_row<const N: usize>(
    cur: [[&[f32]; 3]; 3],
    hist: [&[f32]; 4],
    valid: &[bool],
    invalid: &[bool],
    aliased: Option<&[f32]>,
    sobel: Option<&[f32]>,
    plan: &Plan,
    w: usize,
    out: &mut [&mut [f32]; 3],
    next: &mut [f32],
) -> PixelCounts {
    let (fb_min, fb_max) = (plan.feedback_min, plan.feedback_max);
    let (mut resets, mut clips) = (0u32, 0u32);
    for (x0, n) in blocks(w) {
        let rows: [[&[f32; SPAN]; 3]; 3] = cur.map(|c| spans(&c, x0));
        let [min, max, min_cross, max_cross] = lanes::box_and_cross_bounds(&rows);
        let current: [Lanes; 3] = lanes::each(|c| lanes::each(|l| rows[c][1][l + 1]));
        let hs: [Lanes; 3] = lanes::each(|c| *block(hist[c], x0));
        let ok: &Mask = block(valid, x0);
        let iv: &Mask = block(invalid, x0);
        let mut lo = [[0.0; LANES]; 3];
        let mut hi = [[0.0; LANES]; 3];
        match aliased {
            // Eq. 4.15 then eq. 4.16 (where the history is not used the box is not either).
            Some(al) => {
                let a = f32x8::from(*block::<f32, LANES>(al, x0));
                let v = lanes::v;
                for k in 0..3 {
                    let cur = v(&current[k]);
                    lo[k] = mix_v(cur, mix_v(v(&min_cross[k]), v(&min[k]), a), a).to_array();
                    hi[k] = mix_v(cur, mix_v(v(&max_cross[k]), v(&max[k]), a), a).to_array();
                }
            }
            None => {
                for k in 0..3 {
                    lo[k] = lanes::map2(&min[k], &min_cross[k], |a, b| 0.5 * (a + b));
                    hi[k] = lanes::map2(&max[k], &max_cross[k], |a, b| 0.5 * (a + b));
                }
            }
        }
        // From the clip on in `f32x8` vectors with float masks (as lane loops over flags,
        // the clip and the selects compiled to a branch per lane).
        let (hc, moved) = lanes::clip_toward_center_v(&lanes::v3(&hs), &lanes::v3(&lo), &lanes::v3(&hi));
        let hcv = hc;
        let kv = feedback_v(luma_v(&lanes::v3(&current)), luma_v(&hcv), fb_min, fb_max);
        let (zero, one) = (f32x8::splat(0.0), f32x8::splat(1.0));
        let (okv, ivv) = (lanes::mask_from(ok), lanes::mask_from(iv));
        let keep = okv & ivv;
        let blend = ivv.select(zero, okv);
        let value: [Lanes; 3] = lanes::each(|c| {
            let cur = lanes::v(&current[c]);
            // `mix(current, hc, k).max(0.0)`.
            let b = lanes::max_of(cur * (one - kv) + hcv[c] * kv, zero);
            keep.select(lanes::v(&hs[c]), blend.select(b, cur)).to_array()
        });
        for c in 0..3 {
            lanes::store(&mut out[c][..w], x0, &value[c]);
        }
        if n == LANES {
            // A whole block by one transpose (the lane-by-lane copy was a scalar store per
            // value).
            let s = sobel.map_or(f32x8::splat(0.0), |s| {
                f32x8::from(*block::<f32, LANES>(s, x0 + 1))
            });
            let v = lanes::v3(&value);
            lanes::store_texels_v::<N>(&[v[0], v[1], v[2], s], &mut next[N * x0..N * (x0 + LANES)]);
        } else {
            partial_texels::<N>(
                &value,
                sobel.map(|s| &s[x0 + 1..]),
                &mut next[N * x0..N * (x0 + n)],
            );
        }
        // The flags as bytes of a word: counted with one popcount per block.
        let bits = |m: &Mask| u64::from_le_bytes(m.map(u8::from));
        let pixels = if n == LANES {
            u64::MAX
        } else {
            (1u64 << (8 * n)) - 1
        };
        resets += n as u32 - (bits(ok) & pixels).count_ones();
        let lanes_in = (1u32 << n) - 1;
        clips += ((blend & moved).to_bitmask() & lanes_in).count_ones();
    }
    PixelCounts {
        history_reset: resets as u64,
        history_clipped: clips as u64,
        ..Default::default()
    }
}

/// Stages `sharpen` and `untonemap` of one band: each channel sharpened against its cross
/// neighbours in `src` (the resolved output, edges clamped) with [`sharpen_cross`], held in
/// `[0, hi]` (the frame's [`output_ceiling`]); then back to linear colour when `untonemap`.
#[allow(clippy::too_many_arguments)]
fn sharpen_band(
    src: [&[f32]; 3],
    w: usize,
    h: usize,
    strength: f32,
    hi: f32,
    untonemap: bool,
    clock: &StageClock<2>,
    rows: Range<usize>,
    band: [&mut [f32]; 3],
) {
    let [b0, b1, b2] = band;
    let mut band = [b0, b1, b2];
    clock.time(0, || {
        for (p, dst) in src.iter().zip(band.iter_mut()) {
            for y in rows.clone() {
                let row = |r: usize| &p[r * w..(r + 1) * w];
                let (up, mid, down) = (row(y.saturating_sub(1)), row(y), row((y + 1).min(h - 1)));
                let o = &mut dst[(y - rows.start) * w..(y - rows.start + 1) * w];
                let at = |x: usize| {
                    let n = [up[x], mid[x.saturating_sub(1)], mid[(x + 1).min(w - 1)], down[x]];
                    sharpen_cross(mid[x], n, strength).clamp(0.0, hi)
                };
                o[0] = at(0);
                if w > 2 {
                    for (i, o) in o[1..w - 1].iter_mut().enumerate() {
                        let n = [up[i + 1], mid[i], mid[i + 2], down[i + 1]];
                        *o = sharpen_cross(mid[i + 1], n, strength).clamp(0.0, hi);
                    }
                }
                o[w - 1] = at(w - 1);
            }
        }
    });
    if untonemap {
        clock.time(1, || {
            for k in 0..rows.len() {
                let at = k * w..(k + 1) * w;
                let [a, b, c] = &mut band;
                untonemap_row([&mut a[at.clone()], &mut b[at.clone()], &mut c[at.clone()]]);
            }
        });
    }
}
