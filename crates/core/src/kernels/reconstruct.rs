//! Reconstruction of one jittered frame with a pixel filter: each pixel's value is the
//! filter-weighted mean of the 3x3 samples around it, weighted at the positions where
//! the renderer really took them (pixel centre + the frame's jitter).
//!
//! A renderer's converged image is the scene convolved with its pixel filter (Cycles
//! defaults to Blackman-Harris 1.5 px), not the box integral over each pixel. A temporal
//! filter that blends each frame's own sample converges to the box; one that blends this
//! reconstruction converges to the renderer's filter (Karis 2014, "High quality temporal
//! supersampling", weighs the 3x3 by a Blackman-Harris fit at the jittered offsets; FSR2's
//! accumulate pass does the same with a Lanczos). The jitter is the same for every pixel
//! of a frame, so the weights are one separable 3-tap kernel per axis: a vertical then a
//! horizontal pass per row, renormalised over the taps inside the image at its edges.

use std::f32::consts::TAU;

/// Cycles' Blackman-Harris pixel filter at offset `v` pixels for a filter `width` (Blender
/// `intern/cycles/scene/film.cpp`: `filter_func_blackman_harris`, whose `filter_table`
/// doubles the width, so the support is `+-width`); 0 outside it.
pub fn blackman_harris(v: f32, width: f32) -> f32 {
    if v.abs() >= width {
        return 0.0;
    }
    let t = TAU * (v / (2.0 * width) + 0.5);
    0.35875 - 0.48829 * t.cos() + 0.14128 * (2.0 * t).cos() - 0.01168 * (3.0 * t).cos()
}

/// Cycles' Gaussian pixel filter at offset `v` pixels for a filter `width` (same file:
/// `filter_func_gaussian` with the width tripled, `exp(-2 (2 v / width)^2)`, standard
/// deviation `width / 4`, support `+-1.5 width`); 0 outside it.
pub fn gaussian(v: f32, width: f32) -> f32 {
    if v.abs() >= 1.5 * width {
        return 0.0;
    }
    let u = 2.0 * v / width;
    (-2.0 * u * u).exp()
}

/// The weights of the samples of the pixels at offsets -1, 0, +1 along one axis, whose
/// samples sit at `offset + jitter`, normalised to sum to 1. Where the filter misses all
/// three (a jitter past the filter's support), the pixel keeps its own sample.
pub fn taps(jitter: f32, filter: impl Fn(f32) -> f32) -> [f32; 3] {
    let w = [-1.0f32, 0.0, 1.0].map(|k| filter(k + jitter).max(0.0));
    let sum = w[0] + w[1] + w[2];
    if sum.is_finite() && sum > 1e-6 {
        w.map(|v| v / sum)
    } else {
        [0.0, 1.0, 0.0]
    }
}

/// The taps for a pixel `i` of a line of `n` pixels: `t` with the taps that fall outside
/// the line dropped and the rest renormalised (`t` sums to 1 and its centre is positive
/// unless a neighbour carries all the weight, so at least one kept tap is).
#[inline(always)]
pub fn edge_taps(t: [f32; 3], i: usize, n: usize) -> [f32; 3] {
    let lo = if i == 0 { 0.0 } else { t[0] };
    let hi = if i + 1 >= n { 0.0 } else { t[2] };
    let sum = lo + t[1] + hi;
    if sum > 0.0 {
        [lo / sum, t[1] / sum, hi / sum]
    } else {
        [0.0, 1.0, 0.0]
    }
}

/// One output row: `rows` are the rows above, at and below it (the caller passes the row
/// itself for a missing one, with `wy` from [`edge_taps`]), `tmp` a buffer of the row's
/// width for the vertical pass, `wx` the horizontal taps (renormalised here at both ends).
pub fn reconstruct_row(rows: [&[f32]; 3], wy: [f32; 3], wx: [f32; 3], tmp: &mut [f32], out: &mut [f32]) {
    let n = out.len();
    let tmp = &mut tmp[..n];
    // Zipped slices, so that the loops carry no bounds checks and vectorise.
    for (((t, a), b), c) in tmp.iter_mut().zip(rows[0]).zip(rows[1]).zip(rows[2]) {
        *t = wy[0] * a + wy[1] * b + wy[2] * c;
    }
    if n == 1 {
        out[0] = tmp[0];
        return;
    }
    let [a, b, c] = edge_taps(wx, 0, n);
    out[0] = a * tmp[0] + b * tmp[0] + c * tmp[1];
    for (o, t) in out[1..n - 1].iter_mut().zip(tmp.windows(3)) {
        *o = wx[0] * t[0] + wx[1] * t[1] + wx[2] * t[2];
    }
    let [a, b, c] = edge_taps(wx, n - 1, n);
    out[n - 1] = a * tmp[n - 2] + b * tmp[n - 1] + c * tmp[n - 1];
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::SplitMix64;
    use crate::tolerance::Tolerance;

    /// The direct statement: each pixel the normalised 2D sum of `f(dx) f(dy) c` over the
    /// 3x3 samples inside the image, in f64.
    fn reference(src: &[f32], w: usize, h: usize, j: [f32; 2], f: impl Fn(f32) -> f32) -> Vec<f64> {
        let mut out = vec![0.0; w * h];
        for y in 0..h {
            for x in 0..w {
                let (mut s, mut ws) = (0.0f64, 0.0f64);
                for dy in -1i64..=1 {
                    for dx in -1i64..=1 {
                        let (qx, qy) = (x as i64 + dx, y as i64 + dy);
                        if qx < 0 || qy < 0 || qx >= w as i64 || qy >= h as i64 {
                            continue;
                        }
                        let wt = f(dx as f32 + j[0]).max(0.0) as f64 * f(dy as f32 + j[1]).max(0.0) as f64;
                        s += wt * src[qy as usize * w + qx as usize] as f64;
                        ws += wt;
                    }
                }
                out[y * w + x] = s / ws;
            }
        }
        out
    }

    fn fast(src: &[f32], w: usize, h: usize, j: [f32; 2], f: impl Fn(f32) -> f32 + Copy) -> Vec<f32> {
        let (wx, wy) = (taps(j[0], f), taps(j[1], f));
        let mut out = vec![0.0; w * h];
        let mut tmp = vec![0.0; w];
        for y in 0..h {
            let row = |k: usize| &src[k * w..(k + 1) * w];
            let rows = [row(y.saturating_sub(1)), row(y), row((y + 1).min(h - 1))];
            reconstruct_row(
                rows,
                edge_taps(wy, y, h),
                wx,
                &mut tmp,
                &mut out[y * w..(y + 1) * w],
            );
        }
        out
    }

    #[test]
    fn blackman_harris_is_cycles_window_over_twice_the_width() {
        let t = Tolerance::abs(1e-6);
        // Peak 1 at the centre (the four coefficients sum to 1), 6e-5 (their alternating
        // sum) at the support's edge, 0 past it.
        assert!(t.eq(blackman_harris(0.0, 1.5) as f64, 1.0));
        assert!(Tolerance::abs(1e-5).eq(blackman_harris(1.4999, 1.5) as f64, 6e-5));
        assert_eq!(blackman_harris(1.5, 1.5), 0.0);
        assert!(blackman_harris(0.75, 1.5) < blackman_harris(0.5, 1.5));
        assert!(t.eq(
            blackman_harris(-0.3, 1.5) as f64,
            blackman_harris(0.3, 1.5) as f64
        ));
        // Cycles' Gaussian: standard deviation width / 4.
        assert!(t.eq(gaussian(0.375, 1.5) as f64, (-0.5f64).exp()));
    }

    #[test]
    fn taps_fall_back_to_the_own_sample_when_the_filter_misses_them() {
        assert_eq!(taps(0.9, |v| blackman_harris(v, 0.05)), [0.0, 1.0, 0.0]);
        let t = taps(0.25, |v| blackman_harris(v, 1.5));
        assert!(Tolerance::abs(1e-6).eq((t[0] + t[1] + t[2]) as f64, 1.0));
        // The sample to the left sits 0.75 px away, the one to the right 1.25.
        assert!(t[0] > t[2]);
    }

    #[test]
    fn the_separable_rows_match_the_direct_sum_at_odd_sizes_and_edges() {
        let tol = Tolerance::new(1e-6, 1e-5);
        let mut rng = SplitMix64::new(7);
        type Named = (&'static str, fn(f32) -> f32);
        let filters: [Named; 2] = [
            ("blackman_harris", |v| blackman_harris(v, 1.5)),
            ("gaussian", |v| gaussian(v, 1.0)),
        ];
        for (w, h) in [(1, 1), (1, 5), (7, 1), (2, 2), (13, 9), (31, 17)] {
            for j in [[0.0, 0.0], [-0.5, 0.5], [0.3, -0.1], [0.999, -0.999]] {
                let src: Vec<f32> = (0..w * h)
                    .map(|i| match i % 5 {
                        0 => 0.0,
                        1 => 6.0e4,
                        _ => rng.range(0.0, 4.0) as f32,
                    })
                    .collect();
                for (name, f) in filters {
                    let a = fast(&src, w, h, j, f);
                    let b = reference(&src, w, h, j, f);
                    for (i, (a, b)) in a.iter().zip(&b).enumerate() {
                        assert!(
                            tol.eq(*a as f64, *b),
                            "{name} {w}x{h} jitter {j:?} pixel {i}: {a} vs {b}"
                        );
                    }
                }
            }
        }
    }

    #[test]
    fn a_constant_image_stays_constant_and_an_impulse_spreads_by_the_weights() {
        let (w, h) = (5, 4);
        let f = |v| blackman_harris(v, 1.5);
        let out = fast(&[2.5; 20], w, h, [0.2, -0.4], f);
        assert!(out.iter().all(|v| Tolerance::abs(1e-6).eq(*v as f64, 2.5)));
        let mut imp = vec![0.0; w * h];
        imp[2 * w + 2] = 1.0;
        let j = [0.25, 0.0];
        let out = fast(&imp, w, h, j, f);
        let (wx, wy) = (taps(j[0], f), taps(j[1], f));
        // Pixel (1, 2) sees the impulse as its right neighbour, (3, 2) as its left one.
        assert!(Tolerance::abs(1e-7).eq(out[2 * w + 1] as f64, (wx[2] * wy[1]) as f64));
        assert!(Tolerance::abs(1e-7).eq(out[2 * w + 3] as f64, (wx[0] * wy[1]) as f64));
        assert!(out[2 * w + 3] > out[2 * w + 1]);
    }
}
