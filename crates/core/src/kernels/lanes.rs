//! Eight pixels at a time: per-pixel kernels in lane form. A value is an array of
//! [`LANES`] pixels' values and each operation a loop over them, which the compiler turns
//! into single vector instructions (8 f32 lanes of AVX2). A fused pass loads a block of
//! pixels into lanes, runs these, and stores the block.
//!
//! Each function computes, lane by lane, exactly what its scalar original computes for one
//! pixel: the same operations in the same order, so the same bits (the tests compare them
//! on random and adversarial inputs).

use super::clip::{CLIP_EPS, CLIP_REL};
use super::neighborhood::{fmax, fmin};
use wide::{f32x4, f32x8, i32x8};

/// Pixels per block.
pub const LANES: usize = 8;

/// One value for each pixel of a block.
pub type Lanes = [f32; LANES];

/// Each lane's index: `[0, 1, ..., 7]`.
pub const IOTA: Lanes = [0.0, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0];

/// One flag for each pixel of a block.
pub type Mask = [bool; LANES];

/// An array of `f(i)` for each index `i`: what [`std::array::from_fn`] builds, as a plain
/// loop, which the compiler inlines and vectorises where `from_fn`'s machinery can keep a
/// large closure out of line (and then every lane is a call).
#[inline(always)]
pub fn each<T: Copy + Default, const N: usize>(mut f: impl FnMut(usize) -> T) -> [T; N] {
    let mut out = [T::default(); N];
    for (i, o) in out.iter_mut().enumerate() {
        *o = f(i);
    }
    out
}

/// `s[at..at + N]` as an array (one bounds check for the block, none inside it).
#[inline(always)]
pub fn block<T, const N: usize>(s: &[T], at: usize) -> &[T; N] {
    s[at..at + N].try_into().expect("N elements")
}

/// Stores the lanes of a block from column `x0` that lie in the row `s` (all eight by one
/// fixed-size store when the block is whole: a slice copy of variable length is a call).
#[inline(always)]
pub fn store(s: &mut [f32], x0: usize, v: &Lanes) {
    match s.get_mut(x0..x0 + LANES) {
        Some(dst) => *<&mut [f32; LANES]>::try_from(dst).expect("eight lanes") = *v,
        None => {
            let n = s.len() - x0;
            s[x0..].copy_from_slice(&v[..n]);
        }
    }
}

/// `acc[c] += w * t[c]` for every channel `c` (the same operations, so the same bits as
/// that loop), eight and then four channels to a vector instruction: the loop alone was
/// left scalar for texels of 11 and 5 channels.
#[inline(always)]
pub fn add_scaled<const N: usize>(acc: &mut [f32; N], w: f32, t: &[f32; N]) {
    let mut c = 0;
    while c + 8 <= N {
        let a = f32x8::from(*block::<f32, 8>(acc, c)) + f32x8::splat(w) * f32x8::from(*block::<f32, 8>(t, c));
        acc[c..c + 8].copy_from_slice(&a.to_array());
        c += 8;
    }
    while c + 4 <= N {
        let a = f32x4::from(*block::<f32, 4>(acc, c)) + f32x4::splat(w) * f32x4::from(*block::<f32, 4>(t, c));
        acc[c..c + 4].copy_from_slice(&a.to_array());
        c += 4;
    }
    for c in c..N {
        acc[c] += w * t[c];
    }
}

/// The same value in every lane.
#[inline(always)]
pub fn splat(v: f32) -> Lanes {
    [v; LANES]
}

/// `f` applied lane by lane.
#[inline(always)]
pub fn map(a: &Lanes, f: impl Fn(f32) -> f32) -> Lanes {
    each(|l| f(a[l]))
}

/// `f` applied lane by lane to two values.
#[inline(always)]
pub fn map2(a: &Lanes, b: &Lanes, f: impl Fn(f32, f32) -> f32) -> Lanes {
    each(|l| f(a[l], b[l]))
}

/// `f` applied lane by lane to three values.
#[inline(always)]
pub fn map3(a: &Lanes, b: &Lanes, c: &Lanes, f: impl Fn(f32, f32, f32) -> f32) -> Lanes {
    each(|l| f(a[l], b[l], c[l]))
}

/// `a` where `m` is set, else `b`.
#[inline(always)]
pub fn select(m: &Mask, a: &Lanes, b: &Lanes) -> Lanes {
    each(|l| if m[l] { a[l] } else { b[l] })
}

/// A block's lanes as one vector.
#[inline(always)]
pub fn v(a: &Lanes) -> f32x8 {
    f32x8::from(*a)
}

/// Three channels' lanes as vectors (written out: `map`'s closure can stay out of line).
#[inline(always)]
pub fn v3(a: &[Lanes; 3]) -> [f32x8; 3] {
    [v(&a[0]), v(&a[1]), v(&a[2])]
}

/// Three vectors as lanes.
#[inline(always)]
pub fn arrays3(a: &[f32x8; 3]) -> [Lanes; 3] {
    [a[0].to_array(), a[1].to_array(), a[2].to_array()]
}

/// The flags of a vector mask (all bits set where true).
#[inline(always)]
pub fn mask_of(m: f32x8) -> Mask {
    let bits = m.to_bitmask();
    each(|l| (bits >> l) & 1 == 1)
}

/// The flags as bits (lane `l` is bit `l`): the flags' bytes (0 or 1) gathered into the
/// top byte by one multiply (no two partial products meet, so nothing carries).
#[inline(always)]
pub fn bits_of(m: &Mask) -> u32 {
    let bytes = u64::from_le_bytes(each(|l| m[l] as u8));
    (bytes.wrapping_mul(0x0102_0408_1020_4080) >> 56) as u32
}

/// A vector mask of bits (all bits set in lane `l` where bit `l` of `bits` is).
#[inline(always)]
pub fn mask_of_bits(bits: u32) -> f32x8 {
    let lane_bit = i32x8::from([1, 2, 4, 8, 16, 32, 64, 128]);
    let set = (i32x8::splat(bits as i32) & lane_bit).simd_eq(lane_bit);
    wide::bytemuck::cast(set)
}

/// A vector mask of flags (all bits set where true).
#[inline(always)]
pub fn mask_from(m: &Mask) -> f32x8 {
    f32x8::from(each(|l| if m[l] { f32::from_bits(u32::MAX) } else { 0.0 }))
}

/// The 3x3 statistics of a block from per-column statistics of three rows: `cols[4c..4c+4]`
/// are channel `c`'s column min, max, sum and sum of squares from one column left of the
/// block to one right of it. Returns min, max, mean and mean of squares per channel, as
/// [`super::for_each_row_stats`] combines the columns.
#[inline(always)]
pub fn box_stats(cols: &[&[f32; LANES + 2]; 12]) -> [[Lanes; 3]; 4] {
    let mut out = [[[0.0; LANES]; 3]; 4];
    for c in 0..3 {
        let [vmin, vmax, vsum, vsq] = [cols[4 * c], cols[4 * c + 1], cols[4 * c + 2], cols[4 * c + 3]];
        out[0][c] = each(|l| fmin(fmin(vmin[l], vmin[l + 1]), vmin[l + 2]));
        out[1][c] = each(|l| fmax(fmax(vmax[l], vmax[l + 1]), vmax[l + 2]));
        out[2][c] = each(|l| (vsum[l] + vsum[l + 1] + vsum[l + 2]) * (1.0 / 9.0));
        out[3][c] = each(|l| (vsq[l] + vsq[l + 1] + vsq[l + 2]) * (1.0 / 9.0));
    }
    out
}

/// The min and max of the 3x3 box and of its cross (+) of a block, per channel: `rows[c]`
/// are channel `c`'s rows above, here and below, from one column left of the block to one
/// right. Returns min, max, cross min and cross max, combined as
/// [`super::for_each_row_stats`] does (per column first, then across).
#[inline(always)]
pub fn box_and_cross_bounds(rows: &[[&[f32; LANES + 2]; 3]; 3]) -> [[Lanes; 3]; 4] {
    // In vectors: each column's three-row min and max is computed once per offset (the
    // same operations on the same values, so the same bits).
    let mut out = [[[0.0; LANES]; 3]; 4];
    for (c, [a, b, d]) in rows.iter().enumerate() {
        let at = |r: &[f32; LANES + 2], o: usize| f32x8::from(*block::<f32, LANES>(r, o));
        let vmin = |o: usize| fmin_v(fmin_v(at(a, o), at(b, o)), at(d, o));
        let vmax = |o: usize| fmax_v(fmax_v(at(a, o), at(b, o)), at(d, o));
        out[0][c] = fmin_v(fmin_v(vmin(0), vmin(1)), vmin(2)).to_array();
        out[1][c] = fmax_v(fmax_v(vmax(0), vmax(1)), vmax(2)).to_array();
        let (b0, b1, b2, a1, d1) = (at(b, 0), at(b, 1), at(b, 2), at(a, 1), at(d, 1));
        out[2][c] = fmin_v(fmin_v(fmin_v(b0, b1), b2), fmin_v(a1, d1)).to_array();
        out[3][c] = fmax_v(fmax_v(fmax_v(b0, b1), b2), fmax_v(a1, d1)).to_array();
    }
    out
}

/// [`super::variance_box`] in lanes: `mean +- gamma sigma` within `[min, max]`.
#[inline(always)]
pub fn variance_box(
    min: &[Lanes; 3],
    max: &[Lanes; 3],
    mean: &[Lanes; 3],
    mean_sq: &[Lanes; 3],
    gamma: f32,
) -> ([Lanes; 3], [Lanes; 3]) {
    let mut lo = [[0.0; LANES]; 3];
    let mut hi = [[0.0; LANES]; 3];
    for k in 0..3 {
        let sigma = map2(&mean_sq[k], &mean[k], |q, m| (q - m * m).max(0.0).sqrt());
        lo[k] = map3(&mean[k], &sigma, &min[k], |m, s, mn| (m - gamma * s).max(mn));
        hi[k] = map3(&mean[k], &sigma, &max[k], |m, s, mx| (m + gamma * s).min(mx));
    }
    (lo, hi)
}

/// [`super::clip_toward_center`] in lanes: each `q` moved toward the centre of its box until
/// it is inside; returns the points and which moved.
#[inline(always)]
pub fn clip_toward_center(q: &[Lanes; 3], min: &[Lanes; 3], max: &[Lanes; 3]) -> ([Lanes; 3], Mask) {
    let (p, moved) = clip_toward_center_v(&v3(q), &v3(min), &v3(max));
    (arrays3(&p), mask_of(moved))
}

/// [`clip_toward_center`] on vectors, with the moved lanes as a vector mask. In `f32x8`
/// with float masks: as plain lane loops, the flag and the select compiled to a compare,
/// a branch and a division per lane.
#[inline(always)]
pub fn clip_toward_center_v(q: &[f32x8; 3], min: &[f32x8; 3], max: &[f32x8; 3]) -> ([f32x8; 3], f32x8) {
    let half = f32x8::splat(0.5);
    let g = guard(min, max);
    let mut worst = f32x8::splat(0.0);
    let mut center = [f32x8::splat(0.0); 3];
    let mut d = [f32x8::splat(0.0); 3];
    for k in 0..3 {
        center[k] = half * (max[k] + min[k]);
        let extent = half * (max[k] - min[k]) + g;
        d[k] = q[k] - center[k];
        worst = max_of(worst, (d[k] / extent).abs());
    }
    let moved = worst.simd_gt(f32x8::splat(1.0));
    let s = f32x8::splat(1.0) / worst;
    (each(|k| moved.select(center[k] + d[k] * s, q[k])), moved)
}

/// [`super::clip::guard`] lane by lane.
#[inline(always)]
pub fn guard(min: &[f32x8; 3], max: &[f32x8; 3]) -> f32x8 {
    // Magnitudes are neither NaN nor -0, so any maximum gives the scalar code's bits.
    let m = min[0]
        .abs()
        .max(max[0].abs())
        .max(min[1].abs().max(max[1].abs()))
        .max(min[2].abs().max(max[2].abs()));
    f32x8::splat(CLIP_EPS) + f32x8::splat(CLIP_REL) * m
}

/// [`fmin`] lane by lane: `a` where `a < b`, else `b` (the same bits).
#[inline(always)]
pub fn fmin_v(a: f32x8, b: f32x8) -> f32x8 {
    a.simd_lt(b).select(a, b)
}

/// [`fmax`] lane by lane: `a` where `a > b`, else `b` (the same bits).
#[inline(always)]
pub fn fmax_v(a: f32x8, b: f32x8) -> f32x8 {
    a.simd_gt(b).select(a, b)
}

/// `f32::clamp(x, 0, 1)` lane by lane (NaN stays NaN, `-0` stays `-0`).
#[inline(always)]
pub fn clamp01(x: f32x8) -> f32x8 {
    let (zero, one) = (f32x8::splat(0.0), f32x8::splat(1.0));
    let x = x.simd_lt(zero).select(zero, x);
    x.simd_gt(one).select(one, x)
}

/// `a.max(b)` lane by lane, with the scalar code's bits: a NaN operand gives the other,
/// and of two equal values (`+0` and `-0`) it gives `a`, as the compiled `f32::max` does
/// here (test `vector_clips_give_the_scalar_bits_on_special_values`; wide's `max` gives
/// `b`).
#[inline(always)]
pub fn max_of(a: f32x8, b: f32x8) -> f32x8 {
    a.is_nan().select(b, b.simd_gt(a).select(b, a))
}

/// `a.min(b)` lane by lane, with the scalar code's bits (see [`max_of`]).
#[inline(always)]
pub fn min_of(a: f32x8, b: f32x8) -> f32x8 {
    a.is_nan().select(b, b.simd_lt(a).select(b, a))
}

/// [`super::clip_toward_point`] in lanes: each `q` outside its box moved along the ray
/// toward `target` (clamped into the box) until it enters; returns the points and which
/// moved, as bits (lane `l` is bit `l`).
#[inline(always)]
pub fn clip_toward_point(
    q: &[Lanes; 3],
    target: &[Lanes; 3],
    min: &[Lanes; 3],
    max: &[Lanes; 3],
) -> ([Lanes; 3], u32) {
    // In `f32x8` vectors with float masks, as [`clip_toward_center_v`].
    let [q, target, min, max] = [v3(q), v3(target), v3(min), v3(max)];
    let one = f32x8::splat(1.0);
    let mut t = f32x8::splat(0.0);
    let mut outside = f32x8::splat(0.0);
    let mut tgt = [f32x8::splat(0.0); 3];
    let g = guard(&min, &max);
    let lo: [f32x8; 3] = each(|k| min[k] - g);
    let hi: [f32x8; 3] = each(|k| max[k] + g);
    for k in 0..3 {
        tgt[k] = min_of(max_of(target[k], min[k]), max[k]);
        let below = q[k].simd_lt(lo[k]);
        let out = below | q[k].simd_gt(hi[k]);
        let bound = below.select(lo[k], hi[k]);
        let step = min_of((bound - q[k]) / (tgt[k] - q[k]), one);
        t = out.select(max_of(t, step), t);
        outside |= out;
    }
    let p = each(|k| {
        let moved = min_of(max_of(q[k] + t * (tgt[k] - q[k]), lo[k]), hi[k]);
        outside.select(moved, q[k]).to_array()
    });
    (p, outside.to_bitmask())
}

/// [`super::rgb_to_ycocg`] in lanes.
#[inline(always)]
pub fn rgb_to_ycocg(c: &[Lanes; 3]) -> [Lanes; 3] {
    [
        map3(&c[0], &c[1], &c[2], |r, g, b| 0.25 * r + 0.5 * g + 0.25 * b),
        map2(&c[0], &c[2], |r, b| 0.5 * r - 0.5 * b),
        map3(&c[0], &c[1], &c[2], |r, g, b| -0.25 * r + 0.5 * g - 0.25 * b),
    ]
}

/// [`super::ycocg_to_rgb`] in lanes.
#[inline(always)]
pub fn ycocg_to_rgb(c: &[Lanes; 3]) -> [Lanes; 3] {
    let t = map2(&c[0], &c[2], |y, cg| y - cg);
    [
        map2(&t, &c[1], |t, co| t + co),
        map2(&c[0], &c[2], |y, cg| y + cg),
        map2(&t, &c[1], |t, co| t - co),
    ]
}

/// A block's `N` values per pixel written as interleaved texels: pixel `l`'s values to
/// `out[l * N..(l + 1) * N]`, for the `out.len() / N` (at most [`LANES`]) first pixels.
/// Each eight values go by one 8x8 transpose in vectors, the `N % 8` left lane by lane.
#[inline(always)]
pub fn store_texels<const N: usize>(cols: &[Lanes; N], out: &mut [f32]) {
    let whole = N / LANES * LANES;
    for g in (0..whole).step_by(LANES) {
        let rows = f32x8::transpose(each(|k| f32x8::from(cols[g + k])));
        for (t, row) in out.chunks_exact_mut(N).zip(rows) {
            t[g..g + LANES].copy_from_slice(&row.to_array());
        }
    }
    for (l, t) in out.chunks_exact_mut(N).enumerate().take(LANES) {
        for c in whole..N {
            t[c] = cols[c][l];
        }
    }
}

/// [`store_texels`] of four values per pixel, from vectors: pixel `l`'s to
/// `out[4 l..4 l + 4]`, by one 4x8 transpose (the 8x8 one with zero rows, whose halves the
/// compiler drops) where the lane-by-lane copy was 32 scalar stores.
#[inline(always)]
pub fn store_texels4(cols: &[f32x8; 4], out: &mut [f32; 4 * LANES]) {
    store_texels_v::<4>(cols, out);
}

/// [`store_texels`] of a whole block of `N` values per pixel (`N` at most 4: the first
/// `N` of `cols`) into `out`, which holds `N * LANES` values: one 4x8 transpose, and each
/// pixel's values by one 4-float store (in order, so for `N` < 4 each store's last
/// value is overwritten by the next pixel's; the last pixel's `N` values alone).
#[inline(always)]
pub fn store_texels_v<const N: usize>(cols: &[f32x8; 4], out: &mut [f32]) {
    const { assert!(N >= 1 && N <= 4) };
    let out = &mut out[..N * LANES];
    let z = f32x8::splat(0.0);
    let rows = f32x8::transpose([cols[0], cols[1], cols[2], cols[3], z, z, z, z]);
    for (l, row) in rows.iter().enumerate().take(LANES - 1) {
        out[N * l..N * l + 4].copy_from_slice(&row.to_array()[..4]);
    }
    out[N * (LANES - 1)..].copy_from_slice(&rows[LANES - 1].to_array()[..N]);
}

/// The inverse of [`store_texels`]: eight texels of `N` values as `N` lanes.
#[inline(always)]
pub fn load_texels<const N: usize>(texels: &[[f32; N]; LANES]) -> [Lanes; N] {
    let mut cols = [[0.0; LANES]; N];
    let whole = N / LANES * LANES;
    for g in (0..whole).step_by(LANES) {
        let rows = each(|l| f32x8::from(*block::<f32, LANES>(&texels[l], g)));
        for (k, v) in f32x8::transpose(rows).into_iter().enumerate() {
            cols[g + k] = v.to_array();
        }
    }
    let tail = N - whole;
    if tail >= TAIL_BY_TRANSPOSE {
        // The last values padded to eight with zeros, and transposed like the others.
        let rows = each(|l| {
            let mut r = [0.0; LANES];
            r[..tail].copy_from_slice(&texels[l][whole..]);
            f32x8::from(r)
        });
        for (k, v) in f32x8::transpose(rows).into_iter().take(tail).enumerate() {
            cols[whole + k] = v.to_array();
        }
    } else {
        for (c, col) in cols.iter_mut().enumerate().skip(whole) {
            *col = each(|l| texels[l][c]);
        }
    }
    cols
}

/// From how many values past the last eight [`load_texels`] transposes them too (below
/// that, lane-by-lane loads are fewer instructions).
const TAIL_BY_TRANSPOSE: usize = 4;

#[cfg(test)]
mod tests {
    use super::*;
    use crate::kernels::{clip, color, for_each_row_stats, neighborhood, NeighborhoodStats};
    use crate::rng::SplitMix64;
    use crate::tolerance::Tolerance;

    /// Random blocks of values at several scales, with exact ties, zeros and flat boxes.
    fn block(rng: &mut SplitMix64, scale: f64) -> Lanes {
        std::array::from_fn(|l| match l % 4 {
            0 => 0.0,
            1 => 0.25,
            _ => (rng.next_f64() * 2.0 - 0.5) as f32 * scale as f32,
        })
    }

    /// The vector transposes put every value where the plain loops put it, for texels of
    /// fewer, exactly and more than eight values and for partial blocks.
    #[test]
    fn texels_and_lanes_transpose_like_the_plain_loops() {
        fn case<const N: usize>(rng: &mut SplitMix64) {
            let cols: [Lanes; N] = std::array::from_fn(|_| block(rng, 3.0));
            for n in 0..=LANES {
                let mut out = vec![f32::NAN; n * N + 3];
                store_texels(&cols, &mut out[..n * N]);
                for l in 0..n {
                    for c in 0..N {
                        assert_eq!(out[l * N + c].to_bits(), cols[c][l].to_bits(), "N {N} n {n}");
                    }
                }
                assert!(
                    out[n * N..].iter().all(|v| v.is_nan()),
                    "N {N} n {n}: wrote past the end"
                );
            }
            let texels: [[f32; N]; LANES] =
                std::array::from_fn(|_| std::array::from_fn(|_| rng.next_f64() as f32));
            let back = load_texels(&texels);
            for l in 0..LANES {
                for c in 0..N {
                    assert_eq!(back[c][l].to_bits(), texels[l][c].to_bits(), "N {N}");
                }
            }
        }
        let mut rng = SplitMix64::new(5);
        for _ in 0..100 {
            let cols: [Lanes; 4] = std::array::from_fn(|_| block(&mut rng, 3.0));
            let mut out = [f32::NAN; 4 * LANES];
            store_texels4(&cols.map(f32x8::from), &mut out);
            let mut want = [0.0; 4 * LANES];
            store_texels(&cols, &mut want);
            assert_eq!(out.map(f32::to_bits), want.map(f32::to_bits));
            let three: [Lanes; 3] = [cols[0], cols[1], cols[2]];
            let mut out = [f32::NAN; 3 * LANES + 1];
            store_texels_v::<3>(&cols.map(f32x8::from), &mut out);
            let mut want = [0.0; 3 * LANES];
            store_texels(&three, &mut want);
            assert_eq!(
                out[..3 * LANES].iter().map(|v| v.to_bits()).collect::<Vec<_>>(),
                want.map(f32::to_bits)
            );
            assert!(out[3 * LANES].is_nan(), "wrote past the block");
        }
        case::<1>(&mut rng);
        case::<3>(&mut rng);
        case::<8>(&mut rng);
        case::<9>(&mut rng);
        case::<25>(&mut rng);
        case::<26>(&mut rng);
        case::<27>(&mut rng);
    }

    #[test]
    fn box_and_cross_bounds_give_the_row_stats_bits() {
        let mut rng = SplitMix64::new(72);
        let (w, h) = (LANES + 2, 3);
        for case in 0..500 {
            let scale = [1.0, 1e-5, 1e4, 3.0][case % 4];
            let planes: Vec<Vec<f32>> = (0..3)
                .map(|_| {
                    (0..h)
                        .flat_map(|_| block(&mut rng, scale).into_iter().chain([0.5, -0.0]))
                        .collect()
                })
                .collect();
            let p = [&planes[0][..], &planes[1][..], &planes[2][..]];
            let rows: [[&[f32; LANES + 2]; 3]; 3] = std::array::from_fn(|c| {
                std::array::from_fn(|r| p[c][r * w..(r + 1) * w].try_into().unwrap())
            });
            let [min, max, min_cross, max_cross] = box_and_cross_bounds(&rows);
            for_each_row_stats(p, w, h, 1, |x, s| {
                if x == 0 || x == w - 1 {
                    return;
                }
                let l = x - 1;
                for c in 0..3 {
                    assert_eq!(s.min[c].to_bits(), min[c][l].to_bits(), "case {case}: min");
                    assert_eq!(s.max[c].to_bits(), max[c][l].to_bits(), "case {case}: max");
                    assert_eq!(
                        s.min_cross[c].to_bits(),
                        min_cross[c][l].to_bits(),
                        "case {case}: min+"
                    );
                    assert_eq!(
                        s.max_cross[c].to_bits(),
                        max_cross[c][l].to_bits(),
                        "case {case}: max+"
                    );
                }
            });
        }
    }

    /// The vector clips against the scalar ones on special values: NaN, infinities, signed
    /// zeros, points on the box's faces, empty boxes.
    #[test]
    fn vector_clips_give_the_scalar_bits_on_special_values() {
        const SPECIAL: [f32; 10] = [
            f32::NAN,
            f32::INFINITY,
            f32::NEG_INFINITY,
            0.0,
            -0.0,
            1.0,
            -1.0,
            0.5,
            1e-30,
            3e38,
        ];
        let mut rng = SplitMix64::new(73);
        let pick = |rng: &mut SplitMix64| -> f32 {
            if rng.next_f64() < 0.5 {
                SPECIAL[(rng.next_f64() * SPECIAL.len() as f64) as usize % SPECIAL.len()]
            } else {
                (rng.next_f64() * 4.0 - 2.0) as f32
            }
        };
        for case in 0..20_000 {
            let mut gen =
                || -> [Lanes; 3] { std::array::from_fn(|_| std::array::from_fn(|_| pick(&mut rng))) };
            let (q, target, a, b) = (gen(), gen(), gen(), gen());
            // Boxes as the filters build them, `min <= max` (a NaN bound stays NaN).
            let min: [Lanes; 3] = each(|c| each(|l| fmin(a[c][l], b[c][l])));
            let max: [Lanes; 3] = each(|c| each(|l| fmax(a[c][l], b[c][l])));
            let (pc, mc) = clip_toward_center(&q, &min, &max);
            let (pp, mp) = clip_toward_point(&q, &target, &min, &max);
            for l in 0..LANES {
                let at = |v: &[Lanes; 3]| [0, 1, 2].map(|c| v[c][l]);
                let same = |a: [f32; 3], b: [f32; 3]| (0..3).all(|c| Tolerance::same_bits(a[c], b[c]));
                let (sc, smc) = clip::clip_toward_center(at(&q), at(&min), at(&max));
                assert_eq!(smc, mc[l], "case {case} lane {l}: centre, moved");
                assert!(
                    same(sc, at(&pc)),
                    "case {case} lane {l}: centre {:?} scalar {:?} lanes {:?}",
                    (at(&q), at(&min), at(&max)),
                    sc,
                    at(&pc)
                );
                let (sp, smp) = clip::clip_toward_point(at(&q), at(&target), at(&min), at(&max));
                assert_eq!(smp, mp >> l & 1 == 1, "case {case} lane {l}: point, moved");
                assert!(
                    same(sp, at(&pp)),
                    "case {case} lane {l}: point {:?} scalar {:?} lanes {:?}",
                    (at(&q), at(&target), at(&min), at(&max)),
                    sp,
                    at(&pp)
                );
            }
        }
    }

    #[test]
    fn bits_of_gives_each_flag_as_its_bit() {
        for bits in 0u32..256 {
            let m: Mask = std::array::from_fn(|l| bits >> l & 1 == 1);
            assert_eq!(bits_of(&m), bits);
            assert_eq!(mask_of_bits(bits).to_bitmask(), bits);
        }
    }

    #[test]
    fn lane_kernels_give_the_scalar_bits() {
        let mut rng = SplitMix64::new(71);
        for case in 0..4000 {
            let scale = [1.0, 1e-5, 1e4, 3.0][case % 4];
            let q: [Lanes; 3] = std::array::from_fn(|_| block(&mut rng, scale));
            // Per-column statistics of three rows, one column each side of the block.
            let mut cols = [[0.0f32; LANES + 2]; 12];
            for c in 0..3 {
                for x in 0..LANES + 2 {
                    let [a, b, t] = [0; 3].map(|_| block(&mut rng, scale)[x % LANES]);
                    cols[4 * c][x] = fmin(fmin(a, b), t);
                    cols[4 * c + 1][x] = fmax(fmax(a, b), t);
                    cols[4 * c + 2][x] = a + b + t;
                    cols[4 * c + 3][x] = a * a + b * b + t * t;
                }
            }
            let gamma = rng.range(0.25, 2.0) as f32;
            let [min, max, mean, mean_sq] = box_stats(&cols.each_ref());
            let (lo, hi) = variance_box(&min, &max, &mean, &mean_sq, gamma);
            let (p, moved) = clip_toward_center(&q, &lo, &hi);
            let rgb = ycocg_to_rgb(&p);
            for l in 0..LANES {
                let col = |c: usize, k: usize, x: usize| cols[4 * c + k][x];
                let s = NeighborhoodStats {
                    min: [0, 1, 2].map(|c| fmin(fmin(col(c, 0, l), col(c, 0, l + 1)), col(c, 0, l + 2))),
                    max: [0, 1, 2].map(|c| fmax(fmax(col(c, 1, l), col(c, 1, l + 1)), col(c, 1, l + 2))),
                    mean: [0, 1, 2]
                        .map(|c| (col(c, 2, l) + col(c, 2, l + 1) + col(c, 2, l + 2)) * (1.0 / 9.0)),
                    mean_sq: [0, 1, 2]
                        .map(|c| (col(c, 3, l) + col(c, 3, l + 1) + col(c, 3, l + 2)) * (1.0 / 9.0)),
                    min_cross: [0.0; 3],
                    max_cross: [0.0; 3],
                    mean_cross: [0.0; 3],
                };
                let bits = |v: [f32; 3]| v.map(f32::to_bits);
                let lane = |v: &[Lanes; 3]| [0, 1, 2].map(|c| v[c][l].to_bits());
                assert_eq!(bits(s.min), lane(&min), "case {case} lane {l}: min");
                assert_eq!(bits(s.max), lane(&max), "case {case} lane {l}: max");
                assert_eq!(bits(s.mean), lane(&mean), "case {case} lane {l}: mean");
                assert_eq!(bits(s.mean_sq), lane(&mean_sq), "case {case} lane {l}: mean_sq");
                let (slo, shi) = neighborhood::variance_box(&s, gamma);
                assert_eq!(bits(slo), lane(&lo), "case {case} lane {l}: lo");
                assert_eq!(bits(shi), lane(&hi), "case {case} lane {l}: hi");
                let (sp, smoved) = clip::clip_toward_center([0, 1, 2].map(|c| q[c][l]), slo, shi);
                assert_eq!(smoved, moved[l], "case {case} lane {l}: moved");
                assert_eq!(bits(sp), lane(&p), "case {case} lane {l}: clipped");
                assert_eq!(
                    bits(color::ycocg_to_rgb(sp)),
                    lane(&rgb),
                    "case {case} lane {l}: rgb"
                );
            }
        }
    }
}
