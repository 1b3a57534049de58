//! `upsample`'s stages fused into passes over bands of rows ([`par_bands_strided`]).
//!
//! The joint-bilateral gather (Herzog et al. 2010, eq. 1-2), shared by `spatial`,
//! `temporal` (hole filling) and `spatiotemporal`, and the splat of `taa` read the shaded
//! samples around each pixel. A band first expands every sample row it needs to full
//! resolution ([`SampleRows`]: each sample's colour, validity, depth and normal repeated
//! over the `factor` columns of its cell), so that for a block of [`LANES`] pixels the
//! sample left of, in and right of each pixel's cell are three contiguous loads at fixed
//! offsets (`-factor`, `0`, `+factor`); the image-space distances form a pattern that is the
//! same for every block of a row (a block starts at a multiple of 8, which `factor`
//! divides). The weights and sums then run on 8-pixel lanes without branches: a slot with
//! no sample gets weight 0, which adds `+0` to every sum, so the sums are the reference's.
//!
//! History is one plane of interleaved texels (the reference's planes side by side), one
//! load per bilinear tap; it is reprojected row by row inside the band (`temporal`, `taa`).
//! `spatiotemporal`'s gradient filter is a box over `r + factor - 1` rows around a pixel,
//! reaching into other bands, so its reprojection is one band pass of its own (into a
//! texel plane that holds the tap weight in place of the depth), and the gradient, the box
//! and the blend a second.
//!
//! Every stage computes what the reference ([`super::reference`]) computes, with the same
//! float operations in the same order, so the outputs are the same bits; the tests compare
//! them frame by frame.

use super::spatial::{falloff, Sparse, WEIGHT_EPSILON};
use super::temporal::{filter_gradients, signed_gradient, sub_pixel_intruder, surface_nearby, Nearby};
use super::{Method, Params, DEPTH, G1, ID, LK, R, TAA_KERNEL, TAA_MAX_COUNT, T_DEPTH, T_ID, W};
use crate::filters::passes::{on_screen_bits, previous_positions, FrameContext, FrameResult};
use crate::frame::{ChannelKind, Plane, Rgb, Sampling};
use crate::kernels::lanes::{self, each, Lanes, Mask, LANES};
use crate::kernels::{fmax, fmin, LUMA_REC709};
use crate::pipeline::exec::{par_bands_strided, pool, sized, StageClock};
use crate::pipeline::{FilterError, Inputs, PixelCounts, Recorder, Skip};
use std::ops::Range;
use wide::{f32x8, i32x8};

/// Stages of the fused passes timed by their clock, in record order.
const STAGES: [&str; 3] = ["reproject", "gradient", "blend"];
const REPROJECT: usize = 0;
const GRADIENT: usize = 1;
const BLEND: usize = 2;

/// Texel sizes of the history: `spatiotemporal` [R, G, B, W, depth, id, G1, G2, G3, LK,
/// K, LK2, K2], `temporal` [R, G, B, depth, id], `taa` [R, G, B, count] (the reference's planes).
const ST: usize = 13;
const TM: usize = 5;
const TA: usize = 4;

/// Channels of an expanded sample row.
const E_R: usize = 0;
const E_VALID: usize = 3;
const E_DEPTH: usize = 4;
const E_N: usize = 5;
const E_CH: usize = 8;

/// The depth range of [`super::spatial::depth_range`], as a vectorised parallel reduction
/// (min and max are exact, so any order gives the same range).
pub fn depth_range(depth: &[f32], ids: Option<&[u32]>, near_far: Option<[f32; 2]>) -> f32 {
    use rayon::prelude::*;
    if let Some([n, f]) = near_far {
        if (f - n).is_finite() && f > n {
            return f - n;
        }
    }
    const CHUNK: usize = 1 << 15;
    let fold = |d: &[f32], ids: Option<&[u32]>| {
        let (mut lo, mut hi) = ([f32::INFINITY; LANES], [f32::NEG_INFINITY; LANES]);
        let mut block = |dc: &[f32; LANES], keep: [bool; LANES]| {
            for l in 0..LANES {
                let (v, keep) = (dc[l], keep[l] & (dc[l].abs() < f32::INFINITY));
                lo[l] = fmin(lo[l], if keep { v } else { f32::INFINITY });
                hi[l] = fmax(hi[l], if keep { v } else { f32::NEG_INFINITY });
            }
        };
        let n = d.len() / LANES * LANES;
        let pad = |s: &[f32]| -> [f32; LANES] { each(|l| s.get(n + l).copied().unwrap_or(f32::NAN)) };
        match ids {
            Some(ids) => {
                for (dc, ic) in d.chunks_exact(LANES).zip(ids.chunks_exact(LANES)) {
                    block(dc.try_into().expect("a block"), each(|l| ic[l] != 0));
                }
                block(&pad(d), each(|l| ids.get(n + l).is_some_and(|&i| i != 0)));
            }
            None => {
                for dc in d.chunks_exact(LANES) {
                    block(dc.try_into().expect("a block"), [true; LANES]);
                }
                block(&pad(d), [true; LANES]);
            }
        }
        (
            lo.into_iter().fold(f32::INFINITY, fmin),
            hi.into_iter().fold(f32::NEG_INFINITY, fmax),
        )
    };
    let join = |a: (f32, f32), b: (f32, f32)| (fmin(a.0, b.0), fmax(a.1, b.1));
    let (lo, hi) = pool().install(|| {
        let none = (f32::INFINITY, f32::NEG_INFINITY);
        match ids {
            Some(ids) => depth
                .par_chunks(CHUNK)
                .zip(ids.par_chunks(CHUNK))
                .map(|(d, i)| fold(d, Some(i)))
                .reduce(|| none, join),
            None => depth
                .par_chunks(CHUNK)
                .map(|d| fold(d, None))
                .reduce(|| none, join),
        }
    });
    if hi > lo {
        hi - lo
    } else {
        1.0
    }
}

/// What the passes read for one frame.
struct Setup<'a> {
    w: usize,
    h: usize,
    /// Block size, its log2, and the phase.
    f: isize,
    shift: u32,
    px: isize,
    py: isize,
    sparse: &'a Sparse<'a>,
    /// Depth and normals of the geometric weights (`None`: the term is 1).
    geo_depth: Option<&'a [f32]>,
    normal: Option<[&'a [f32]; 3]>,
    inv_depth_scale: f32,
    normal_sigma: f32,
    sky_depth_only: bool,
    /// This frame's depth, ids and motion (validity, the next history).
    depth: Option<&'a [f32]>,
    ids: Option<&'a [u32]>,
    motion: Option<[&'a [f32]; 2]>,
    /// Per lane of a block, whether the pixel sits on its cell's sample column, as a mask
    /// and as 1 or 0.
    on_column: Mask,
    column: Lanes,
    /// Per row offset `dy + f` and slot (left, own, right cell): the image-space weight of
    /// each lane (`spatial`, `temporal`: the falloff at `kernel_wide`; `taa`: the Gaussian)
    /// or its distance in block diagonals (`spatiotemporal`, whose width varies).
    table: Vec<[Lanes; 3]>,
    /// Floats of an expanded sample row.
    stride: usize,
}

/// [`falloff`] of eight values, lane by lane, with `inv_sigma = 1 / sigma` and `fmax`
/// for `f32::max`: the same value for every input (NaN included: both give the other
/// operand; a -0 or +0 `t` gives the clamp either way).
#[inline(always)]
fn falloff_v(x: f32x8, inv_sigma: f32x8) -> f32x8 {
    let f = f32x8::splat;
    let t = lanes::fmax_v(f(1.0) - x * inv_sigma, f(0.0));
    lanes::fmax_v(t * t * t, f(WEIGHT_EPSILON))
}

/// `[f(0), f(1), f(2)]`.
#[inline(always)]
fn three<T>(f: impl Fn(usize) -> T) -> [T; 3] {
    [f(0), f(1), f(2)]
}

/// `a x b` lane by lane.
#[inline(always)]
fn mul(a: &Lanes, b: &Lanes) -> Lanes {
    each(|l| a[l] * b[l])
}

/// How many lanes are set.
#[inline(always)]
fn set_lanes(m: &Mask) -> u64 {
    let mut n = 0u32;
    for &b in m {
        n += b as u32;
    }
    n as u64
}

/// Lanes `x0..x0 + 8` of a row, zero past its end.
#[inline(always)]
fn ld(s: &[f32], x0: usize) -> Lanes {
    match s.get(x0..x0 + LANES) {
        Some(b) => b.try_into().expect("a block"),
        None => each(|l| s.get(x0 + l).copied().unwrap_or(0.0)),
    }
}

/// Lanes `x0..x0 + 8` of channel `c` of a row of `n`-float texels, zero past its end.
#[inline(always)]
fn ld_texel(s: &[f32], n: usize, c: usize, x0: usize) -> Lanes {
    match s.get(n * x0..n * (x0 + LANES)) {
        Some(b) => each(|l| b[n * l + c]),
        None => each(|l| s.get(n * (x0 + l) + c).copied().unwrap_or(0.0)),
    }
}

/// Stores texels of `N` channels for the lanes of a block that lie in the row.
#[inline(always)]
fn st_texels<const N: usize>(s: &mut [f32], x0: usize, v: &[Lanes; N]) {
    let n = LANES.min(s.len() / N - x0);
    for l in 0..n {
        let t: &mut [f32; N] = (&mut s[N * (x0 + l)..N * (x0 + l + 1)])
            .try_into()
            .expect("a texel");
        for (c, t) in t.iter_mut().enumerate() {
            *t = v[c][l];
        }
    }
}

/// Luma (Rec. 709, [`crate::kernels::luma`]) in lanes.
#[inline(always)]
fn luma_lanes(c: &[Lanes; 3]) -> Lanes {
    each(|l| LUMA_REC709[0] * c[0][l] + LUMA_REC709[1] * c[1][l] + LUMA_REC709[2] * c[2][l])
}

/// The sample rows a band reads, expanded to full resolution: entry `x + f` of row `b`
/// holds the sample of the cell of column `x` (its colour, 1 when it exists and is valid
/// else 0, its depth and normal), zero where there is none.
#[derive(Default)]
struct SampleRows {
    /// The first cell row held, and how many.
    first: isize,
    rows: usize,
    /// Which held rows exist (inside the colour planes and the frame).
    present: Vec<bool>,
    data: [Vec<f32>; E_CH],
}

/// Writes `value(a)` to the `f` entries of each cell `a` of `cells` (`f` of 1, 2 or 4).
#[inline(always)]
fn expand(cells: &mut [f32], f: usize, value: impl Fn(usize) -> f32) {
    fn by<const F: usize>(cells: &mut [f32], value: impl Fn(usize) -> f32) {
        for (a, c) in cells.chunks_exact_mut(F).enumerate() {
            let c: &mut [f32; F] = c.try_into().expect("a cell");
            *c = [value(a); F];
        }
    }
    match f {
        1 => by::<1>(cells, value),
        2 => by::<2>(cells, value),
        _ => by::<4>(cells, value),
    }
}

/// One sample row of a pixel's footprint: its expanded channels and its row offset.
struct Slot<'a> {
    e: [&'a [f32]; E_CH],
    /// `dy + f`.
    dyi: usize,
}

impl SampleRows {
    /// Expands the cell rows that rows `rows` read: one above the first's cell to one below
    /// the last's.
    fn build(&mut self, fr: &Setup, rows: Range<usize>, geometry: bool) {
        let first = ((rows.start as isize - fr.py) >> fr.shift) - 1;
        let last = ((rows.end as isize - 1 - fr.py) >> fr.shift) + 1;
        self.first = first;
        self.rows = (last - first + 1) as usize;
        self.present.clear();
        let s = fr.stride;
        let channels = if geometry { E_CH } else { E_VALID + 1 };
        for d in &mut self.data[..channels] {
            if d.len() < self.rows * s {
                d.resize(self.rows * s, 0.0);
            }
        }
        let sp = fr.sparse;
        let (cw, ch) = (sp.color_width, sp.color_height);
        let f = fr.f as usize;
        for k in 0..self.rows {
            let b = first + k as isize;
            let sy = fr.f * b + fr.py;
            let present = b >= 0 && (b as usize) < ch && (sy as usize) < fr.h;
            self.present.push(present);
            if !present {
                continue;
            }
            let (b, sy) = (b as usize, sy as usize);
            let row = k * s..(k + 1) * s;
            // Entry `x + f` holds the sample of column x's cell: cell a's columns
            // `f a + px .. f a + px + f` are entries `f a + px + f ..`; the entries before
            // cell 0's and after the last cell's stay 0.
            let first_at = f + fr.px as usize;
            let tail = first_at + f * cw;
            // Cells whose sample lies in the frame; the colour, depth and normal of the
            // others (and of invalid samples) are left finite and carry weight 0.
            let inside = fr.w.saturating_sub(fr.px as usize).div_ceil(f).min(cw);
            for (c, d) in self.data[..channels].iter_mut().enumerate() {
                let d = &mut d[row.clone()];
                d[..first_at.min(s)].fill(0.0);
                if tail < s {
                    d[tail..].fill(0.0);
                }
                let cells = &mut d[first_at..tail.min(s)];
                let (cells, outside) = cells.split_at_mut(f * inside);
                outside.fill(0.0);
                match c {
                    E_R..=2 => expand(cells, f, |a| sp.color[c][b * cw + a]),
                    E_VALID => match sp.invalid {
                        Some(v) => expand(cells, f, |a| (!v[b * cw + a]) as u8 as f32),
                        None => cells.fill(1.0),
                    },
                    _ => {
                        let plane = if c == E_DEPTH {
                            fr.geo_depth
                        } else {
                            fr.normal.map(|n| n[c - E_N])
                        };
                        match plane {
                            Some(p) => {
                                let src = &p[sy * fr.w..(sy + 1) * fr.w];
                                expand(cells, f, |a| src[f * a + fr.px as usize])
                            }
                            None => cells.fill(0.0),
                        }
                    }
                }
            }
        }
    }

    /// The sample rows of row `y`'s footprint, in the reference's order (cell rows above,
    /// own, below): the row above only for a pixel on a sample row (at `dy = -f`).
    #[inline(always)]
    fn slots<'s>(&'s self, fr: &Setup, y: usize) -> ([Option<Slot<'s>>; 3], isize) {
        let t = y as isize - fr.py;
        let b0 = t >> fr.shift;
        let my = t - (b0 << fr.shift);
        let s = fr.stride;
        let get = |b: isize, dy: isize| -> Option<Slot<'s>> {
            let k = (b - self.first) as usize;
            self.present[k].then(|| Slot {
                e: std::array::from_fn(|c| self.data[c].get(k * s..(k + 1) * s).unwrap_or(&[])),
                dyi: (dy + fr.f) as usize,
            })
        };
        let up = if my == 0 { get(b0 - 1, -fr.f) } else { None };
        ([up, get(b0, -my), get(b0 + 1, fr.f - my)], my)
    }
}

/// A pixel block's own geometry.
struct PixelGeo {
    depth: Lanes,
    normal: [Lanes; 3],
    /// `1 / normal_sigma`, or 0 for a pixel whose normal term is 1 (`sky_depth_only`).
    inv_normal: f32x8,
}

impl PixelGeo {
    #[inline(always)]
    fn load<const D: bool, const N: bool>(fr: &Setup, y: usize, x0: usize) -> Self {
        let row = y * fr.w..(y + 1) * fr.w;
        let normal = if N {
            // `three`, not `map`: `map`'s closure stayed out of line (a call per
            // channel and block, its result passed through memory).
            let n = fr.normal.expect("N");
            three(|c| ld(&n[c][row.clone()], x0))
        } else {
            [[0.0; LANES]; 3]
        };
        let inv = 1.0 / fr.normal_sigma;
        let inv_normal = if N && fr.sky_depth_only {
            f32x8::from(each(|l| {
                if normal[0][l] == 0.0 && normal[1][l] == 0.0 && normal[2][l] == 0.0 {
                    0.0
                } else {
                    inv
                }
            }))
        } else {
            f32x8::splat(inv)
        };
        PixelGeo {
            depth: if D {
                ld(&fr.geo_depth.expect("D")[row.clone()], x0)
            } else {
                [0.0; LANES]
            },
            normal,
            inv_normal,
        }
    }
}

/// The joint-bilateral gather of a block ([`Sparse::gather`] in lanes): over the slots in
/// order, weight = `image(slot)` times the geometric weight (normal term times depth term,
/// [`super::spatial::Geometry::weight`]), 0 where the slot has no sample. Returns the sum of
/// weight x colour and the sum of weights.
#[inline(always)]
fn gather_lanes<const D: bool, const N: bool>(
    fr: &Setup,
    slots: &[Option<Slot>; 3],
    x0: usize,
    g: &PixelGeo,
    image: &[[Lanes; 3]; 3],
) -> ([Lanes; 3], Lanes) {
    // In f32x8 vectors, lane by lane the operations of the scalar gather.
    let f = f32x8::splat;
    let v = |a: &Lanes| f32x8::from(*a);
    let falloff = |x: f32x8, sigma: f32| falloff_v(x, f(1.0 / sigma));
    let mut sum = [f(0.0); 3];
    let mut wsum = f(0.0);
    for (slot, image) in slots.iter().zip(image) {
        let Some(slot) = slot else { continue };
        for s in 0..3 {
            let at = x0 + s * fr.f as usize;
            let e = |c: usize| -> &[f32; LANES] { slot.e[c][at..at + LANES].try_into().expect("a block") };
            let valid = e(E_VALID);
            let mut geo = f(1.0);
            if D {
                let sd = v(e(E_DEPTH));
                geo *= falloff((v(&g.depth) - sd).abs() * f(fr.inv_depth_scale), 1.0);
            }
            if N {
                let (nx, ny, nz) = (v(e(E_N)), v(e(E_N + 1)), v(e(E_N + 2)));
                let dot = v(&g.normal[0]) * nx + v(&g.normal[1]) * ny + v(&g.normal[2]) * nz;
                geo *= falloff_v(lanes::fmax_v(f(1.0) - dot, f(0.0)), g.inv_normal);
            }
            // 1 where the slot has a sample, else 0: the weight is exact or +0.
            let mask = if s == 0 { mul(valid, &fr.column) } else { *valid };
            let wt = v(&image[s]) * geo * v(&mask);
            for (c, sum) in sum.iter_mut().enumerate() {
                *sum += wt * v(e(E_R + c));
            }
            wsum += wt;
        }
    }
    (lanes::arrays3(&sum), wsum.to_array())
}

/// [`super::spatial::Gathered::mean`] in lanes, 0 where no sample had weight.
#[inline(always)]
fn mean(sum: &[Lanes; 3], wsum: &Lanes) -> [Lanes; 3] {
    three(|c| each(|l| if wsum[l] > 0.0 { sum[c][l] / wsum[l] } else { 0.0 }))
}

/// The colour of each lane's own sample, and which lanes have one (shaded this frame:
/// on a sample row and column, with a valid sample).
#[inline(always)]
fn own_lanes(fr: &Setup, slots: &[Option<Slot>; 3], my: isize, x0: usize) -> ([Lanes; 3], Mask) {
    match (&slots[1], my == 0) {
        (Some(slot), true) => {
            let at = x0 + fr.f as usize;
            let e = |c: usize| -> Lanes { slot.e[c][at..at + LANES].try_into().expect("a block") };
            let valid = e(E_VALID);
            let own: Mask = each(|l| fr.on_column[l] & (valid[l] != 0.0));
            ([e(0), e(1), e(2)], own)
        }
        _ => ([[0.0; LANES]; 3], [false; LANES]),
    }
}

/// The bilinear reprojection of [`super::temporal::reproject`] for row `y`, from a plane of
/// `N`-float texels: each pixel's taps at `p + motion` that pass the validity test (this
/// pixel's id against the tap's channel `id`, its depth against channel `depth`; all taps
/// when `valid` is off; a failing tap's surface next to the pixel and the pixel's nowhere
/// near the tap before keeps the share `valid.4` of its weight, `subpixel_keep`),
/// renormalised; calls `emit(x, texel, tap weight, weight kept for sub-pixel surfaces)`.
/// Returns the pixels with less than half of the weight.
#[inline(always)]
fn reproject_row<const N: usize>(
    fr: &Setup,
    hist: &[f32],
    y: usize,
    valid: Option<(usize, usize, f32, f32, f32)>,
    mut emit: impl FnMut(usize, [f32; N], f32, f32),
) -> u64 {
    let (w, h) = (fr.w, fr.h);
    let near_motion = valid.map_or(0.0, |v| v.3);
    let subpixel = valid.map_or(0.0, |v| v.4);
    // Whether a tap that fails may still be kept.
    let fallback = near_motion > 0.0 || subpixel > 0.0;
    let nearby = Nearby {
        depth: fr.depth,
        ids: fr.ids,
        motion: fr.motion,
        width: w,
        height: h,
        depth_tolerance: valid.map_or(0.0, |v| v.2),
        max_motion: near_motion,
    };
    let row = y * w..(y + 1) * w;
    let motion = fr.motion.map(|m| m.map(|m| &m[row.clone()]));
    let depth = valid.and(fr.depth).map(|d| &d[row.clone()]);
    let ids = valid.and(fr.ids).map(|d| &d[row.clone()]);
    let (dc, ic, tol, _, _) = valid.unwrap_or((0, 0, 0.0, 0.0, 0.0));
    let mut lost = 0u64;
    let f = f32x8::splat;
    for x0 in (0..w).step_by(LANES) {
        // Eight pixels' positions, on-screen test, taps and weights in vectors (the same
        // operations as one pixel's, so the same bits), then each pixel's taps.
        let [px, py] = match motion {
            Some([mx, my]) => previous_positions(mx, my, x0, y),
            None => {
                // `x + 0.5 + 0.0`: the same numbers without a motion row.
                let x = f(x0 as f32) + f32x8::from(lanes::IOTA) + f(0.5);
                [x.to_array(), [y as f32 + 0.5; LANES]]
            }
        };
        let on = on_screen_bits(&px, &py, w, h);
        let (fx, fy) = (f32x8::from(px) - f(0.5), f32x8::from(py) - f(0.5));
        let (x0f, y0f) = (fx.floor(), fy.floor());
        let (tx, ty) = (fx - x0f, fy - y0f);
        let one = f(1.0);
        let wts = [
            ((one - tx) * (one - ty)).to_array(),
            (tx * (one - ty)).to_array(),
            ((one - tx) * ty).to_array(),
            (tx * ty).to_array(),
        ];
        // On screen, `x0f` lies in -1 ..= w - 1 (and `y0f` likewise): the clamps of the
        // reference's `(v.max(0) as usize).min(n - 1)` on whole numbers.
        let (xi, yi) = (x0f.trunc_int(), y0f.trunc_int());
        let (zero, wm, hm) = (
            i32x8::splat(0),
            i32x8::splat(w as i32 - 1),
            i32x8::splat(h as i32 - 1),
        );
        let (xa, xb) = (xi.max(zero).to_array(), (xi + i32x8::splat(1)).min(wm).to_array());
        let (ya, yb) = (yi.max(zero).to_array(), (yi + i32x8::splat(1)).min(hm).to_array());
        for l in 0..LANES.min(w - x0) {
            let x = x0 + l;
            let mut acc = [0.0f32; N];
            let mut total = 0.0f32;
            let mut kept = 0.0f32;
            if on >> l & 1 != 0 {
                let (ya, yb) = (ya[l] as usize * w, yb[l] as usize * w);
                let (xa, xb) = (xa[l] as usize, xb[l] as usize);
                let taps = [
                    (xa + ya, wts[0][l]),
                    (xb + ya, wts[1][l]),
                    (xa + yb, wts[2][l]),
                    (xb + yb, wts[3][l]),
                ];
                let id = ids.map(|ids| ids[x] as f32);
                let z = depth.map(|d| d[x]);
                // Branch-free: a tap that fails adds weight +0 (and +0 or -0 to each sum,
                // which leaves sums that start at +0 and only grow as they were), so the
                // sums are the reference's, which skips it.
                for (t, wt) in taps {
                    let tex: &[f32; N] = hist[N * t..N * t + N].try_into().expect("a texel");
                    let mut same = true;
                    if let Some(id) = id {
                        same &= id == tex[ic];
                    }
                    if let Some(z) = z {
                        let far = (tex[dc] - z).abs() > tol * z.abs();
                        same &= !far;
                    }
                    let mut ok = wt > 0.0 && same;
                    // The weight kept for a sub-pixel surface (`subpixel`) when `ok` is not.
                    let mut sub = 0.0;
                    if !same && wt > 0.0 && fallback {
                        ok = near_motion > 0.0 && surface_nearby(&nearby, y * w + x, tex[ic], tex[dc]);
                        if !ok
                            && subpixel > 0.0
                            && sub_pixel_tap::<N>(&nearby, hist, y * w + x, t, (ic, dc), (id, z))
                        {
                            sub = wt * subpixel;
                        }
                    }
                    kept += sub;
                    let wt = if ok { wt } else { sub };
                    total += wt;
                    lanes::add_scaled(&mut acc, wt, tex);
                }
            }
            let inv = if total > 0.0 { 1.0 / total } else { 0.0 };
            emit(x, acc.map(|a| a * inv), total, kept);
            lost += (total < 0.5) as u64;
        }
    }
    lost
}

/// [`sub_pixel_intruder`] for tap `t` of pixel `i` read from texels of `N` floats in `hist`
/// (channels `ic`, `dc` hold the previous id and depth; `id`, `z` are the pixel's; the
/// reference's `Validity::intruder`).
#[inline(always)]
fn sub_pixel_tap<const N: usize>(
    nearby: &Nearby,
    hist: &[f32],
    i: usize,
    t: usize,
    (ic, dc): (usize, usize),
    (id, z): (Option<f32>, Option<f32>),
) -> bool {
    sub_pixel_intruder(
        nearby,
        i,
        t,
        &|q: usize| (hist[N * q + ic], hist[N * q + dc]),
        id,
        z,
    )
}

/// One band task's buffers, reused across the bands it runs.
#[derive(Default)]
struct Band {
    samples: SampleRows,
    /// This row's reprojected history texels and tap weights.
    hist: Vec<f32>,
    frac: Vec<f32>,
    /// `spatiotemporal`: per cell of a sample row, the gradient its pixels take; this
    /// band's raw gradients and temporally filtered gradients (with `r` zero columns each
    /// side), rows `ylo..yhi`; the confidence of one row.
    cells: Vec<f32>,
    now: Vec<f32>,
    filtered: Vec<f32>,
    /// The temporally filtered gradients with their sign (laid out as `filtered`).
    signed: Vec<f32>,
    conf: Vec<f32>,
}

/// Dispatches on which geometric terms exist.
macro_rules! with_geometry {
    ($fr:expr, $f:ident($($arg:expr),*)) => {
        match ($fr.geo_depth.is_some(), $fr.normal.is_some()) {
            (true, true) => $f::<true, true>($($arg),*),
            (true, false) => $f::<true, false>($($arg),*),
            (false, true) => $f::<false, true>($($arg),*),
            (false, false) => $f::<false, false>($($arg),*),
        }
    };
}

/// Runs `upsample`'s stages from `geometry` to `blend` for one frame.
pub(super) fn frame(
    p: &Params,
    decay: f32,
    sampling: Sampling,
    near_far: Option<[f32; 2]>,
    ctx: FrameContext<'_, '_>,
) -> Result<FrameResult, FilterError> {
    let (inp, rec, has_history, read, next, scratch) = ctx.into_parts();
    let method = p.method;
    let (w, h) = (inp.width, inp.height);
    let stateful = method != Method::Spatial;
    let has_history = stateful && has_history;
    let (cw, ch) = inp.color[0].size();
    let sparse = Sparse::new(inp.color_slices(), cw, ch, sampling, inp.invalid.as_deref());
    let range = geometry(method, &inp, near_far, rec);
    let fr = setup(p, &inp, &sparse, sampling, range);

    let mut pixels = PixelCounts::default();
    let mut out: Rgb = scratch.planes(w, h);
    let hist = has_history.then(|| read[0].data());
    let [reproject_skip, gradient_skip] = skips(method, has_history);
    if stateful && !has_history {
        pixels.history_reset += (w * h) as u64;
    }
    let clock = StageClock::<3>::default();
    let mut timed = 0.0;
    // `spatiotemporal`: the reprojection as a pass of its own (the box of gradients reads
    // other bands' rows).
    let mut reprojected = None;
    if let (Method::Spatiotemporal, Some(hist)) = (method, hist) {
        let mut rp = scratch.plane(ST * w, h);
        let t = std::time::Instant::now();
        pixels.history_rejected += st_reproject_pass(&fr, p, hist, &clock, rp.data_mut());
        timed += t.elapsed().as_secs_f64() * 1e3;
        reprojected = Some(rp);
    }
    let t = std::time::Instant::now();
    let pass = BlendPass {
        fr: &fr,
        p,
        decay,
        hist,
        rp: reprojected.as_ref().map(|p| p.data()),
        clock: &clock,
        texels: match method {
            Method::Spatiotemporal => ST,
            Method::Temporal => TM,
            Method::Taa => TA,
            Method::Spatial => 0,
        },
    };
    pixels += pass.run(&mut out, next);
    let ms = timed + t.elapsed().as_secs_f64() * 1e3;
    let shares = clock.shares();
    for (k, skip) in [reproject_skip, gradient_skip, None].into_iter().enumerate() {
        match skip {
            Some(why) => rec.skip(STAGES[k], why),
            None => rec.ran_for(STAGES[k], ms * shares[k]),
        }
    }
    scratch.recycle(reprojected);
    Ok(FrameResult {
        color: out,
        pixels,
        model: None,
    })
}

/// Stage `geometry` of a frame with inputs `inp` (left out for `taa`, whose splat weighs
/// no geometry, and without depth): the depth range of [`super::spatial::depth_range`].
pub fn geometry(method: Method, inp: &Inputs, near_far: Option<[f32; 2]>, rec: &mut Recorder) -> Option<f32> {
    let variant = Skip::Variant {
        variant: method.name(),
    };
    rec.stage(
        "geometry",
        (method == Method::Taa)
            .then_some(variant)
            .or_else(|| inp.require(ChannelKind::Depth)),
        || {
            let ids = inp.object_id.map(Plane::data);
            depth_range(
                inp.depth.as_deref().map(Plane::data).expect("required"),
                ids,
                near_far,
            )
        },
    )
}

/// Why stages `reproject` and `gradient` are left out of a frame of `method` (`None`:
/// they run): `spatial` keeps no history, only `spatiotemporal` has gradients, and
/// without history (`has_history`) there is nothing to reproject.
pub fn skips(method: Method, has_history: bool) -> [Option<Skip>; 2] {
    let variant = Skip::Variant {
        variant: method.name(),
    };
    [
        (method == Method::Spatial)
            .then_some(variant.clone())
            .or_else(|| (!has_history).then_some(Skip::NoHistory)),
        (method != Method::Spatiotemporal).then_some(variant),
    ]
}

/// What the passes read for a frame with inputs `inp`, its sparse colour `sparse` and the
/// depth range `range` (`None`: stage `geometry` was left out).
fn setup<'a>(
    p: &Params,
    inp: &'a Inputs,
    sparse: &'a Sparse<'a>,
    sampling: Sampling,
    range: Option<f32>,
) -> Setup<'a> {
    let method = p.method;
    let (w, h) = (inp.width, inp.height);
    let f = sampling.factor as isize;
    let depth = inp.depth.as_deref().map(Plane::data);
    let on_column: Mask = each(|l| (l as isize - sampling.phase[0] as isize).rem_euclid(f) == 0);
    Setup {
        w,
        h,
        f,
        shift: sampling.factor.trailing_zeros(),
        px: sampling.phase[0] as isize,
        py: sampling.phase[1] as isize,
        sparse,
        geo_depth: depth.filter(|_| range.is_some() && method != Method::Taa),
        normal: (method != Method::Taa)
            .then(|| inp.normal.as_deref().map(|n| n.each_ref().map(Plane::data)))
            .flatten(),
        inv_depth_scale: 1.0 / (p.depth_sigma * range.unwrap_or(1.0)),
        normal_sigma: p.normal_sigma,
        sky_depth_only: p.sky_depth_only,
        depth,
        ids: inp.object_id.map(Plane::data),
        motion: inp.motion.as_deref().map(|m| m.each_ref().map(Plane::data)),
        on_column,
        column: on_column.map(|b| b as u8 as f32),
        table: weight_table(p, sparse, sampling),
        stride: w.next_multiple_of(LANES) + 2 * f as usize,
    }
}

/// [`Setup::table`]: per row offset `dy + f` and slot (left, own, right cell), each lane's
/// image-space weight (`spatial`, `temporal`: the falloff at `kernel_wide`; `taa`: the
/// Gaussian) or its distance in block diagonals (`spatiotemporal`).
fn weight_table(p: &Params, sparse: &Sparse, sampling: Sampling) -> Vec<[Lanes; 3]> {
    let f = sampling.factor as isize;
    let side = 2 * f as usize + 1;
    // Per row offset and slot, each lane's offset index (`Sparse::dist` order) or none.
    let offset = |dyi: usize, s: usize, l: usize| -> usize {
        let m = (l as isize - sampling.phase[0] as isize).rem_euclid(f);
        let dx = [-f, -m, f - m][s];
        if s == 0 && m != 0 {
            // Masked: any offset will do.
            dyi * side
        } else {
            dyi * side + (dx + f) as usize
        }
    };
    (0..side)
        .map(|dyi| {
            std::array::from_fn(|s| {
                each(|l| {
                    let o = offset(dyi, s, l);
                    match p.method {
                        Method::Spatiotemporal => sparse.dist(o),
                        Method::Taa => (-TAA_KERNEL * sparse.dist2(o)).exp(),
                        _ => falloff(sparse.dist(o), p.kernel_wide),
                    }
                })
            })
        })
        .collect()
}

/// `spatiotemporal`'s reprojection of the history `hist` as a band pass of its own, into
/// `rp` (texels of [`ST`] floats, the tap weight in the depth's place and the weight kept
/// for a sub-pixel surface in the id's). Returns the pixels with less than half of the
/// weight.
fn st_reproject_pass(fr: &Setup, p: &Params, hist: &[f32], clock: &StageClock<3>, rp: &mut [f32]) -> u64 {
    let (w, h) = (fr.w, fr.h);
    par_bands_strided([rp], [ST * w], h, |_: &mut (), rows, [band]| {
        let mut lost = 0;
        for y in rows.clone() {
            let o = &mut band[ST * w * (y - rows.start)..ST * w * (y - rows.start + 1)];
            let valid = Some((DEPTH, ID, p.depth_tolerance, p.neighbour_motion, p.subpixel_keep));
            lost += clock.time(REPROJECT, || {
                reproject_row::<ST>(fr, hist, y, valid, |x, t, total, kept| {
                    let dst: &mut [f32; ST] = (&mut o[ST * x..ST * x + ST]).try_into().expect("a texel");
                    *dst = t;
                    // The tap weight takes the depth's place, the weight kept for a
                    // sub-pixel surface the id's.
                    dst[DEPTH] = total;
                    dst[ID] = kept;
                })
            });
        }
        lost
    })
}

/// The blend pass (with `temporal`'s and `taa`'s reprojection, and `spatiotemporal`'s
/// gradients): what its bands read besides their own buffers.
struct BlendPass<'a> {
    fr: &'a Setup<'a>,
    p: &'a Params,
    decay: f32,
    /// The history's texels, when there is one.
    hist: Option<&'a [f32]>,
    /// `spatiotemporal`'s reprojected history ([`st_reproject_pass`]).
    rp: Option<&'a [f32]>,
    clock: &'a StageClock<3>,
    /// Floats of a texel of the next history (0: `spatial` keeps none).
    texels: usize,
}

impl BlendPass<'_> {
    /// The pass over the frame's bands into `out` and the next history's plane (`spatial`
    /// keeps no history).
    fn run(&self, out: &mut Rgb, next: &mut [Plane<f32>]) -> PixelCounts {
        let (w, h) = (self.fr.w, self.fr.h);
        let [o0, o1, o2] = out.each_mut().map(|p| p.data_mut());
        match next.first_mut() {
            Some(np) => par_bands_strided(
                [o0, o1, o2, np.data_mut()],
                [w, w, w, self.texels * w],
                h,
                |band: &mut Band, rows, planes| self.band(band, rows, planes),
            ),
            None => par_bands_strided([o0, o1, o2], [w; 3], h, |band: &mut Band, rows, [or, og, ob]| {
                self.band(band, rows, [or, og, ob, &mut []])
            }),
        }
    }

    /// One band: its sample rows expanded, `spatiotemporal`'s gradients, then row by row
    /// the method's blend into the output rows and the next history's.
    #[inline]
    fn band(&self, band: &mut Band, rows: Range<usize>, [or, og, ob, nx]: [&mut [f32]; 4]) -> PixelCounts {
        let (fr, p, clock) = (self.fr, self.p, self.clock);
        let (method, w, texels) = (p.method, fr.w, self.texels);
        let geometry = method != Method::Taa;
        band.samples.build(fr, rows.clone(), geometry);
        let mut counts = PixelCounts::default();
        match method {
            Method::Spatiotemporal => {
                clock.time(GRADIENT, || {
                    gradient_band(
                        fr,
                        self.rp,
                        p.gradient_lag == 2,
                        p.subpixel_keep > 0.0,
                        band,
                        rows.clone(),
                    )
                });
            }
            Method::Spatial | Method::Temporal | Method::Taa => {}
        }
        for y in rows.clone() {
            let k = y - rows.start;
            let o = k * w..(k + 1) * w;
            let out = [&mut or[o.clone()], &mut og[o.clone()], &mut ob[o.clone()]];
            let nx = &mut nx[texels * o.start..texels * o.end];
            counts += match method {
                Method::Spatial => clock.time(BLEND, || with_geometry!(fr, spatial_row(fr, band, y, out))),
                Method::Temporal => self.temporal(band, y, out, nx),
                Method::Taa => self.taa(band, y, out, nx),
                Method::Spatiotemporal => clock.time(BLEND, || {
                    with_geometry!(
                        fr,
                        st_row(fr, p, self.decay, band, self.rp, rows.start, y, out, nx)
                    )
                }),
            };
        }
        counts
    }

    /// `temporal` for row `y`: the history reprojected into the band's row (the pixels
    /// with less than half of the valid weight counted as rejected), then the blend.
    #[inline(always)]
    fn temporal(&self, band: &mut Band, y: usize, out: [&mut [f32]; 3], nx: &mut [f32]) -> PixelCounts {
        let (fr, clock) = (self.fr, self.clock);
        let valid = Some((T_DEPTH, T_ID, self.p.depth_tolerance, 0.0, 0.0));
        let mut c = PixelCounts {
            history_rejected: self.reproject_band::<TM>(band, y, valid),
            ..PixelCounts::default()
        };
        let hrow = self.hist.map(|_| (&band.hist[..TM * fr.w], &band.frac[..fr.w]));
        c += clock.time(BLEND, || {
            with_geometry!(fr, temporal_row(fr, &band.samples, hrow, y, out, nx))
        });
        c
    }

    /// `taa` for row `y`: the history reprojected into the band's row (the pixels with
    /// less than half of the weight counted as reset), then the splat and blend.
    #[inline(always)]
    fn taa(&self, band: &mut Band, y: usize, out: [&mut [f32]; 3], nx: &mut [f32]) -> PixelCounts {
        let (fr, p, clock) = (self.fr, self.p, self.clock);
        let mut c = PixelCounts {
            history_reset: self.reproject_band::<TA>(band, y, None),
            ..PixelCounts::default()
        };
        let hrow = self.hist.map(|_| (&band.hist[..TA * fr.w], &band.frac[..fr.w]));
        c += clock.time(BLEND, || taa_row(fr, p, &band.samples, hrow, y, out, nx));
        c
    }

    /// Row `y` of the history reprojected into the band (`N` values a pixel, then the
    /// valid share); the pixels with less than half of the weight (0 without history).
    #[inline(always)]
    fn reproject_band<const N: usize>(
        &self,
        band: &mut Band,
        y: usize,
        valid: Option<(usize, usize, f32, f32, f32)>,
    ) -> u64 {
        let (fr, w) = (self.fr, self.fr.w);
        let hrow = sized(&mut band.hist, N * w);
        let frow = sized(&mut band.frac, w);
        let Some(hist) = self.hist else { return 0 };
        self.clock.time(REPROJECT, || {
            reproject_row::<N>(fr, hist, y, valid, |x, t, total, _| {
                hrow[N * x..N * x + N].copy_from_slice(&t);
                frow[x] = total;
            })
        })
    }
}

/// The table entries of a row's slots (zeros for a missing slot).
fn row_table(fr: &Setup, slots: &[Option<Slot>; 3]) -> [[Lanes; 3]; 3] {
    three(|k| slots[k].as_ref().map_or([[0.0; LANES]; 3], |s| fr.table[s.dyi]))
}

/// `spatial` for row `y`: the gather at `kernel_wide`, its mean.
fn spatial_row<const D: bool, const N: bool>(
    fr: &Setup,
    band: &Band,
    y: usize,
    out: [&mut [f32]; 3],
) -> PixelCounts {
    let (slots, _) = band.samples.slots(fr, y);
    let image = row_table(fr, &slots);
    let [or, og, ob] = out;
    for x0 in (0..fr.w).step_by(LANES) {
        let g = PixelGeo::load::<D, N>(fr, y, x0);
        let (sum, wsum) = gather_lanes::<D, N>(fr, &slots, x0, &g, &image);
        let v = mean(&sum, &wsum);
        lanes::store(or, x0, &v[0]);
        lanes::store(og, x0, &v[1]);
        lanes::store(ob, x0, &v[2]);
    }
    PixelCounts::default()
}

/// The next history's depth and id lanes of row `y` (0 where the frame has none).
#[inline(always)]
fn depth_ids(fr: &Setup, y: usize, x0: usize) -> (Lanes, Lanes) {
    let row = y * fr.w..(y + 1) * fr.w;
    let d = fr.depth.map_or([0.0; LANES], |d| ld(&d[row.clone()], x0));
    let i = fr.ids.map_or([0.0; LANES], |ids| {
        let r = &ids[row];
        each(|l| r.get(x0 + l).map_or(0.0, |&v| v as f32))
    });
    (d, i)
}

/// `temporal` for row `y`: a shaded pixel takes its sample, another its valid reprojected
/// history (`frac >= 0.5`), a hole the spatial estimate (counted as a reset).
#[allow(clippy::too_many_arguments)]
fn temporal_row<const D: bool, const N: bool>(
    fr: &Setup,
    samples: &SampleRows,
    hist: Option<(&[f32], &[f32])>,
    y: usize,
    out: [&mut [f32]; 3],
    next: &mut [f32],
) -> PixelCounts {
    let (slots, my) = samples.slots(fr, y);
    let image = row_table(fr, &slots);
    let [or, og, ob] = out;
    let mut holes = 0u64;
    for x0 in (0..fr.w).step_by(LANES) {
        let (own_c, own) = own_lanes(fr, &slots, my, x0);
        let (hc, ok): ([Lanes; 3], Mask) = match hist {
            Some((t, fr_)) => {
                let frac = ld(fr_, x0);
                (three(|c| ld_texel(t, TM, c, x0)), each(|l| frac[l] >= 0.5))
            }
            None => ([[0.0; LANES]; 3], [false; LANES]),
        };
        let hole: Mask = each(|l| !own[l] & !ok[l]);
        let fill = if set_lanes(&hole) > 0 {
            let g = PixelGeo::load::<D, N>(fr, y, x0);
            let (sum, wsum) = gather_lanes::<D, N>(fr, &slots, x0, &g, &image);
            mean(&sum, &wsum)
        } else {
            [[0.0; LANES]; 3]
        };
        holes += if x0 + LANES <= fr.w {
            set_lanes(&hole)
        } else {
            set_lanes(&each(|l| hole[l] & (x0 + l < fr.w)))
        };
        let v: [Lanes; 3] = three(|c| lanes::select(&own, &own_c[c], &lanes::select(&ok, &hc[c], &fill[c])));
        lanes::store(or, x0, &v[0]);
        lanes::store(og, x0, &v[1]);
        lanes::store(ob, x0, &v[2]);
        let (d, i) = depth_ids(fr, y, x0);
        st_texels::<TM>(next, x0, &[v[0], v[1], v[2], d, i]);
    }
    PixelCounts {
        history_reset: holes,
        ..Default::default()
    }
}

/// `taa` for row `y`: the samples splatted with the Gaussian of their distance, the blend
/// weight scaled by the best sample's kernel value, history clamped to the samples'
/// min/max box (as the reference).
fn taa_row(
    fr: &Setup,
    p: &Params,
    samples: &SampleRows,
    hist: Option<(&[f32], &[f32])>,
    y: usize,
    out: [&mut [f32]; 3],
    next: &mut [f32],
) -> PixelCounts {
    let (slots, _) = samples.slots(fr, y);
    let [or, og, ob] = out;
    let mut clipped = 0u64;
    for x0 in (0..fr.w).step_by(LANES) {
        let mut sum = [[0.0f32; LANES]; 3];
        let (mut wsum, mut beta) = ([0.0f32; LANES], [0.0f32; LANES]);
        let mut lo = [[f32::INFINITY; LANES]; 3];
        let mut hi = [[f32::NEG_INFINITY; LANES]; 3];
        for slot in slots.iter().flatten() {
            for s in 0..3 {
                let at = x0 + s * fr.f as usize;
                let e =
                    |c: usize| -> &[f32; LANES] { slot.e[c][at..at + LANES].try_into().expect("a block") };
                let valid = e(E_VALID);
                let mask = if s == 0 { mul(valid, &fr.column) } else { *valid };
                let keep: Mask = each(|l| mask[l] != 0.0);
                let k = &fr.table[slot.dyi][s];
                let wt: Lanes = mul(k, &mask);
                // `wt` is 0 where there is no sample and beta >= 0: no select needed. `fmax`
                // and `fmin` give `f32::max` and `min` here (no NaN; a tie of +0 and -0
                // changes neither the clamp's result nor the blend).
                beta = each(|l| fmax(beta[l], wt[l]));
                wsum = each(|l| wsum[l] + wt[l]);
                for c in 0..3 {
                    let v = e(E_R + c);
                    sum[c] = each(|l| sum[c][l] + wt[l] * v[l]);
                    lo[c] = each(|l| if keep[l] { fmin(lo[c][l], v[l]) } else { lo[c][l] });
                    hi[c] = each(|l| if keep[l] { fmax(hi[c][l], v[l]) } else { hi[c][l] });
                }
            }
        }
        let up = mean(&sum, &wsum);
        let n: Lanes = match hist {
            Some((t, frac)) => {
                let (fc, nn) = (ld(frac, x0), ld_texel(t, TA, W, x0));
                each(|l| if fc[l] > 0.0 && wsum[l] > 0.0 { nn[l] } else { 0.0 })
            }
            None => [0.0; LANES],
        };
        let fresh: Mask = each(|l| n[l] <= 0.0);
        let hv: [Lanes; 3] = match hist {
            Some((t, _)) => three(|c| ld_texel(t, TA, c, x0)),
            None => [[0.0; LANES]; 3],
        };
        // `f32::clamp` without its assertion (the reference clamps only where the box exists).
        let hc: [Lanes; 3] = three(|c| {
            each(|l| {
                let v = if hv[c][l] < lo[c][l] { lo[c][l] } else { hv[c][l] };
                if v > hi[c][l] {
                    hi[c][l]
                } else {
                    v
                }
            })
        });
        let moved: Mask = each(|l| (hc[0][l] != hv[0][l]) | (hc[1][l] != hv[1][l]) | (hc[2][l] != hv[2][l]));
        let a: Lanes = each(|l| beta[l] * p.taa_alpha.max(1.0 / (n[l] + 1.0)));
        let v: [Lanes; 3] = three(|c| {
            each(|l| {
                if fresh[l] {
                    up[c][l]
                } else {
                    a[l] * up[c][l] + (1.0 - a[l]) * hc[c][l]
                }
            })
        });
        let count: Lanes = each(|l| {
            if fresh[l] {
                beta[l]
            } else {
                fmin(n[l] + beta[l], TAA_MAX_COUNT)
            }
        });
        let clip = each(|l| !fresh[l] & moved[l]);
        clipped += if x0 + LANES <= fr.w {
            set_lanes(&clip)
        } else {
            set_lanes(&each(|l| clip[l] & (x0 + l < fr.w)))
        };
        lanes::store(or, x0, &v[0]);
        lanes::store(og, x0, &v[1]);
        lanes::store(ob, x0, &v[2]);
        st_texels::<TA>(next, x0, &[v[0], v[1], v[2], count]);
    }
    PixelCounts {
        history_clipped: clipped,
        ..Default::default()
    }
}

/// Half-width of `spatiotemporal`'s box of gradients: `max(1, factor / 2)`.
fn box_radius(f: isize) -> usize {
    (f as usize / 2).max(1)
}

/// `spatiotemporal`'s stage `gradient` for a band: the raw gradient (Herzog et al. 2010,
/// sec. 3.4; see [`super::reference`]) and its temporal filter for the band's rows and
/// `r` rows each side, into the band's buffers.
/// With `lag2` a sample is compared with the shaded sample before the last (`gradient_lag`);
/// with `sub_zero` a sample whose history was mostly kept for a sub-pixel surface
/// (`subpixel_keep`) has gradient 0.
fn gradient_band(
    fr: &Setup,
    rp: Option<&[f32]>,
    lag2: bool,
    sub_zero: bool,
    band: &mut Band,
    rows: Range<usize>,
) {
    let (w, h) = (fr.w, fr.h);
    let r = box_radius(fr.f);
    let (ylo, yhi) = (rows.start.saturating_sub(r), (rows.end + r).min(h));
    let fstride = w + 2 * r;
    let sp = fr.sparse;
    let cw = sp.color_width;
    let now = sized(&mut band.now, (yhi - ylo) * w);
    let filtered = sized(&mut band.filtered, (yhi - ylo) * fstride);
    let signed = sized(&mut band.signed, (yhi - ylo) * fstride);
    let cells = sized(&mut band.cells, cw);
    let mut cells_of = None;
    for y in ylo..yhi {
        let k = y - ylo;
        let nrow = &mut now[k * w..(k + 1) * w];
        let frow = &mut filtered[k * fstride..(k + 1) * fstride];
        let i0 = y * w;
        match rp {
            None => nrow.fill(1.0),
            Some(rp) => {
                // The gradient of each cell of this row's sample row (its pixels' when their
                // own history is valid).
                let b = ((y as isize - fr.py) >> fr.shift).max(0);
                if cells_of != Some(b) {
                    cells_of = Some(b);
                    for (a, c) in cells.iter_mut().enumerate() {
                        *c = match sp.sample(a as isize, b, w, h) {
                            Some((kk, j)) => {
                                let t: &[f32; ST] = rp[ST * j..ST * j + ST].try_into().expect("a texel");
                                // At least half of the kept history kept for a sub-pixel
                                // surface: nothing of this sample's surface to compare with.
                                if t[DEPTH] >= 0.5 && sub_zero && t[ID] >= 0.5 * t[DEPTH] {
                                    0.0
                                } else if t[DEPTH] >= 0.5 {
                                    let l = crate::kernels::luma(sp.color.map(|p| p[kk]));
                                    let (known, known2) = (t[LK + 1], t[LK + 3]);
                                    let before = if lag2 && known2 >= 0.5 {
                                        t[LK + 2] / known2
                                    } else if known >= 0.5 {
                                        t[LK] / known
                                    } else {
                                        crate::kernels::luma([t[R], t[R + 1], t[R + 2]])
                                    };
                                    signed_gradient(l, before)
                                } else {
                                    1.0
                                }
                            }
                            // A repaired (invalid) sample says nothing: keep trusting history.
                            None if sp.invalid.is_some() => 0.0,
                            None => 1.0,
                        };
                    }
                }
                let f = fr.f as usize;
                let row = &rp[ST * i0..ST * (i0 + w)];
                for (a, &c) in cells.iter().enumerate() {
                    // Columns of cell a (cell 0 also takes the columns before the phase).
                    let start = if a == 0 { 0 } else { f * a + fr.px as usize };
                    let end = (f * (a + 1) + fr.px as usize).min(w);
                    for x in start..end {
                        nrow[x] = if row[ST * x + DEPTH] >= 0.5 { c } else { 1.0 };
                    }
                }
            }
        }
        let srow = &mut signed[k * fstride..(k + 1) * fstride];
        frow[..r].fill(0.0);
        frow[r + w..].fill(0.0);
        srow[..r].fill(0.0);
        srow[r + w..].fill(0.0);
        let fw = &mut frow[r..r + w];
        let sw = &mut srow[r..r + w];
        // The magnitudes' filter (the paper's) and the signed values' filter.
        match rp {
            Some(rp) => {
                let row = &rp[ST * i0..ST * (i0 + w)];
                for (x, ((o, so), &n)) in fw.iter_mut().zip(sw.iter_mut()).zip(nrow.iter()).enumerate() {
                    let t: &[f32; ST] = row[ST * x..ST * x + ST].try_into().expect("a texel");
                    let g = [n, t[G1], t[G1 + 1], t[G1 + 2]];
                    *o = filter_gradients(g.map(f32::abs));
                    *so = filter_gradients(g);
                }
            }
            None => {
                for ((o, so), &n) in fw.iter_mut().zip(sw.iter_mut()).zip(nrow.iter()) {
                    let g = [n, 1.0, 1.0, 1.0];
                    *o = filter_gradients(g.map(f32::abs));
                    *so = filter_gradients(g);
                }
            }
        }
    }
}

/// `spatiotemporal` for row `y`: the box of filtered gradients and the confidence, the
/// gather at the width the confidence sets, the blend with history, the next history.
#[allow(clippy::too_many_arguments)]
fn st_row<const D: bool, const N: bool>(
    fr: &Setup,
    p: &Params,
    decay: f32,
    band: &mut Band,
    rp: Option<&[f32]>,
    y0: usize,
    y: usize,
    out: [&mut [f32]; 3],
    next: &mut [f32],
) -> PixelCounts {
    let (w, h) = (fr.w, fr.h);
    let r = box_radius(fr.f);
    let ylo = y0.saturating_sub(r);
    let fstride = w + 2 * r;
    // The box: rows y - r ..= y + r inside the image, columns likewise (the zero columns
    // each side add +0 where the reference skips the tap); then the confidence.
    let (ya, yb) = (y.saturating_sub(r), (y + r + 1).min(h));
    let conf = sized(&mut band.conf, w);
    let (filtered, signed) = (&band.filtered, &band.signed);
    let rows_in = (yb - ya) as isize;
    for x0 in (0..w).step_by(LANES) {
        let (mut sum, mut ssum) = ([0.0f32; LANES], [0.0f32; LANES]);
        for yy in ya..yb {
            let at = (yy - ylo) * fstride..(yy - ylo + 1) * fstride;
            let (row, srow) = (&filtered[at.clone()], &signed[at]);
            for d in 0..=2 * r {
                let v = ld(&row[d..], x0);
                for (s, v) in sum.iter_mut().zip(v) {
                    *s += v;
                }
                let v = ld(&srow[d..], x0);
                for (s, v) in ssum.iter_mut().zip(v) {
                    *s += v;
                }
            }
        }
        // In vectors: the box's columns inside the image, `min(x + r, w - 1) - max(x - r, 0)
        // + 1` (at least 1), and the tap count are whole numbers far below 2^24, so exact
        // in f32 and the same as the integer arithmetic of the reference; then the
        // confidence, lane by lane as `super::temporal::confidence(cancelled(..))` computes it.
        let f = f32x8::splat;
        let x = f(x0 as f32) + f32x8::from(lanes::IOTA);
        let (lo, hi) = (
            lanes::max_of(x - f(r as f32), f(0.0)),
            lanes::min_of(x + f(r as f32), f((w - 1) as f32)),
        );
        let cols = lanes::max_of(hi - lo + f(1.0), f(1.0));
        let n = f(rows_in as f32) * cols;
        let (g, sg) = (f32x8::from(sum) / n, f32x8::from(ssum) / n);
        let g = g - f(p.gradient_cancel) * (g - sg.abs());
        let t = f(1.0) - lanes::min_of(g / f(p.gradient_scale), f(1.0));
        let c = t.simd_gt(f(0.0)).select(t * t, f(0.0));
        lanes::store(conf, x0, &c.to_array());
    }
    let conf = &band.conf[..w];
    let now = &band.now[(y - ylo) * w..(y - ylo + 1) * w];
    let (slots, my) = band.samples.slots(fr, y);
    let dist = row_table(fr, &slots);
    let [or, og, ob] = out;
    let row = rp.map(|rp| &rp[ST * y * w..ST * (y + 1) * w]);
    for x0 in (0..w).step_by(LANES) {
        let c = ld(conf, x0);
        // The kernel width and the image-space falloffs in vectors.
        let f = f32x8::splat;
        let sigma = f(p.kernel_sharp) + (f(1.0) - f32x8::from(c)) * f(p.kernel_wide - p.kernel_sharp);
        let inv = f(1.0) / sigma;
        let g = PixelGeo::load::<D, N>(fr, y, x0);
        let image: [[Lanes; 3]; 3] = three(|k| three(|s| falloff_v(f32x8::from(dist[k][s]), inv).to_array()));
        let (sum, wsum) = gather_lanes::<D, N>(fr, &slots, x0, &g, &image);
        let (prev, wh, pg, hk, hk2): ([Lanes; 3], Lanes, [Lanes; 2], [Lanes; 2], [Lanes; 2]) = match row {
            Some(t) => {
                let ch = |k: usize| ld_texel(t, ST, k, x0);
                let (wgt, frac) = (ch(W), ch(DEPTH));
                (
                    [ch(R), ch(R + 1), ch(R + 2)],
                    each(|l| c[l] * wgt[l] * frac[l]),
                    [ch(G1), ch(G1 + 1)],
                    [ch(LK), ch(LK + 1)],
                    [ch(LK + 2), ch(LK + 3)],
                )
            }
            None => (
                [[0.0; LANES]; 3],
                [0.0; LANES],
                [[1.0; LANES]; 2],
                [[0.0; LANES]; 2],
                [[0.0; LANES]; 2],
            ),
        };
        let total: Lanes = each(|l| wsum[l] + wh[l]);
        let (tv, whv) = (f32x8::from(total), f32x8::from(wh));
        let some = tv.simd_gt(f(0.0));
        let v: [Lanes; 3] = three(|k| {
            let blend = (f32x8::from(sum[k]) + whv * f32x8::from(prev[k])) / tv;
            some.select(blend, f(0.0)).to_array()
        });
        let (own_c, own) = own_lanes(fr, &slots, my, x0);
        let lk = lanes::select(&own, &luma_lanes(&own_c), &hk[0]);
        let kn = lanes::select(&own, &[1.0; LANES], &hk[1]);
        // The sample before: the last one where a new one comes.
        let lk2 = lanes::select(&own, &hk[0], &hk2[0]);
        let kn2 = lanes::select(&own, &hk[1], &hk2[1]);
        lanes::store(or, x0, &v[0]);
        lanes::store(og, x0, &v[1]);
        lanes::store(ob, x0, &v[2]);
        let (d, i) = depth_ids(fr, y, x0);
        let n = ld(now, x0);
        let wn = lanes::map(&total, |t| decay * t);
        st_texels::<ST>(
            next,
            x0,
            &[v[0], v[1], v[2], wn, d, i, n, pg[0], pg[1], lk, kn, lk2, kn2],
        );
    }
    PixelCounts::default()
}
