//! Statistics of a pixel's 3x3 neighbourhood: min/max and mean of the full box and of the
//! cross (+), and the variance box.

use super::fetch_clamped;
use std::cell::RefCell;

/// Indices of the cross (+) taps within a row-major 3x3 gather (centre = 4).
pub const CROSS: [usize; 5] = [1, 3, 4, 5, 7];

/// The 3x3 neighbourhood of `(x, y)` in row-major order (centre at index 4), edges clamped.
#[inline]
pub fn gather3x3(plane: &[f32], width: usize, height: usize, x: usize, y: usize) -> [f32; 9] {
    let (x, y) = (x as isize, y as isize);
    let mut out = [0.0; 9];
    for (i, o) in out.iter_mut().enumerate() {
        let (dx, dy) = ((i % 3) as isize - 1, (i / 3) as isize - 1);
        *o = fetch_clamped(plane, width, height, x + dx, y + dy);
    }
    out
}

/// Per-component statistics of nine colour taps.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct NeighborhoodStats {
    /// Minimum over the 3x3 box.
    pub min: [f32; 3],
    /// Maximum over the 3x3 box.
    pub max: [f32; 3],
    /// Mean over the 3x3 box.
    pub mean: [f32; 3],
    /// Mean of the squares over the 3x3 box (for the variance box).
    pub mean_sq: [f32; 3],
    /// Minimum over the cross (+).
    pub min_cross: [f32; 3],
    /// Maximum over the cross (+).
    pub max_cross: [f32; 3],
    /// Mean over the cross (+).
    pub mean_cross: [f32; 3],
}

/// Statistics of the 3x3 box and of its cross from nine taps (row-major, centre 4).
#[inline]
pub fn cross_and_box_stats(taps: &[[f32; 3]; 9]) -> NeighborhoodStats {
    let mut s = NeighborhoodStats {
        min: [f32::INFINITY; 3],
        max: [f32::NEG_INFINITY; 3],
        mean: [0.0; 3],
        mean_sq: [0.0; 3],
        min_cross: [f32::INFINITY; 3],
        max_cross: [f32::NEG_INFINITY; 3],
        mean_cross: [0.0; 3],
    };
    for (i, t) in taps.iter().enumerate() {
        let in_cross = i % 2 == 1 || i == 4;
        for k in 0..3 {
            s.min[k] = s.min[k].min(t[k]);
            s.max[k] = s.max[k].max(t[k]);
            s.mean[k] += t[k];
            s.mean_sq[k] += t[k] * t[k];
            if in_cross {
                s.min_cross[k] = s.min_cross[k].min(t[k]);
                s.max_cross[k] = s.max_cross[k].max(t[k]);
                s.mean_cross[k] += t[k];
            }
        }
    }
    for k in 0..3 {
        s.mean[k] /= 9.0;
        s.mean_sq[k] /= 9.0;
        s.mean_cross[k] /= 5.0;
    }
    s
}

/// The variance box `mean +- gamma * sigma` per component (Salvi 2016), intersected with the
/// min/max box so it never reaches outside the values actually seen.
#[inline]
pub fn variance_box(s: &NeighborhoodStats, gamma: f32) -> ([f32; 3], [f32; 3]) {
    let mut lo = [0.0; 3];
    let mut hi = [0.0; 3];
    for k in 0..3 {
        let sigma = (s.mean_sq[k] - s.mean[k] * s.mean[k]).max(0.0).sqrt();
        lo[k] = (s.mean[k] - gamma * sigma).max(s.min[k]);
        hi[k] = (s.mean[k] + gamma * sigma).min(s.max[k]);
    }
    (lo, hi)
}

/// `min` for finite values: a single instruction, without `f32::min`'s NaN handling (inputs
/// to the filters are repaired to be finite).
#[inline(always)]
pub fn fmin(a: f32, b: f32) -> f32 {
    if a < b {
        a
    } else {
        b
    }
}

/// `max` for finite values (see [`fmin`]).
#[inline(always)]
pub fn fmax(a: f32, b: f32) -> f32 {
    if a > b {
        a
    } else {
        b
    }
}

thread_local! {
    /// Per-thread column sums of one row (12 x width floats), reused across rows and frames.
    static COLUMNS: RefCell<Vec<f32>> = const { RefCell::new(Vec::new()) };
}

/// The 3x3 box part of [`NeighborhoodStats`] (min, max, mean, mean of squares) for pixel
/// `x` from per-column 3-row statistics of its row: `cols[4c..4c + 4]` hold channel `c`'s
/// column min, max, sum and sum of squares; `xl` and `xr` are the (clamped) neighbours.
#[inline(always)]
pub fn box_from_columns(cols: &[&[f32]; 12], xl: usize, x: usize, xr: usize, s: &mut NeighborhoodStats) {
    for c in 0..3 {
        let [vmin, vmax, vsum, vsq] = [cols[4 * c], cols[4 * c + 1], cols[4 * c + 2], cols[4 * c + 3]];
        s.min[c] = fmin(fmin(vmin[xl], vmin[x]), vmin[xr]);
        s.max[c] = fmax(fmax(vmax[xl], vmax[x]), vmax[xr]);
        s.mean[c] = (vsum[xl] + vsum[x] + vsum[xr]) * (1.0 / 9.0);
        s.mean_sq[c] = (vsq[xl] + vsq[x] + vsq[xr]) * (1.0 / 9.0);
    }
}

/// The vertical pass of the separable 3x3 box: per column, the min, max, sum and sum of
/// squares of the rows `a`, `b` and `c` of one channel (as many columns as `vmin` has).
#[inline(always)]
pub fn column_stats([a, b, c]: [&[f32]; 3], [vmin, vmax, vsum, vsq]: [&mut [f32]; 4]) {
    for x in 0..vmin.len() {
        let (u, v, t) = (a[x], b[x], c[x]);
        vmin[x] = fmin(fmin(u, v), t);
        vmax[x] = fmax(fmax(u, v), t);
        vsum[x] = u + v + t;
        vsq[x] = u * u + v * v + t * t;
    }
}

/// The statistics of [`cross_and_box_stats`] for every pixel of row `y` of three planes,
/// computed separably: 3-tap vertical min/max/sum/sum of squares per column (a pass the
/// compiler vectorises), then 3-tap horizontal per pixel. Calls `f(x, &stats)` for each
/// pixel of the row in order. Edges are clamped as in [`gather3x3`]. Expects finite input.
pub fn for_each_row_stats(
    planes: [&[f32]; 3],
    width: usize,
    height: usize,
    y: usize,
    mut f: impl FnMut(usize, &NeighborhoodStats),
) {
    let w = width;
    let (ya, yb, yc) = (y.saturating_sub(1) * w, y * w, (y + 1).min(height - 1) * w);
    COLUMNS.with(|cell| {
        let mut cols = cell.borrow_mut();
        cols.resize(12 * w, 0.0);
        for (k, p) in planes.iter().enumerate() {
            let (a, b, c) = (&p[ya..ya + w], &p[yb..yb + w], &p[yc..yc + w]);
            let chunk = &mut cols[k * 4 * w..(k + 1) * 4 * w];
            let (vmin, rest) = chunk.split_at_mut(w);
            let (vmax, rest) = rest.split_at_mut(w);
            let (vsum, vsq) = rest.split_at_mut(w);
            column_stats([a, b, c], [vmin, vmax, vsum, vsq]);
        }
        let columns: [&[f32]; 12] = std::array::from_fn(|i| &cols[i * w..(i + 1) * w]);
        let mut s = NeighborhoodStats::default();
        for x in 0..w {
            let (xl, xr) = (x.saturating_sub(1), (x + 1).min(w - 1));
            box_from_columns(&columns, xl, x, xr, &mut s);
            for (k, p) in planes.iter().enumerate() {
                let (l, m, r, up, down) = (p[yb + xl], p[yb + x], p[yb + xr], p[ya + x], p[yc + x]);
                s.min_cross[k] = fmin(fmin(fmin(l, m), r), fmin(up, down));
                s.max_cross[k] = fmax(fmax(fmax(l, m), r), fmax(up, down));
                s.mean_cross[k] = (l + m + r + up + down) * 0.2;
            }
            f(x, &s);
        }
    });
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::SplitMix64;
    use crate::tolerance::Tolerance;

    #[test]
    fn stats_and_variance_box_match_f64() {
        let mut rng = SplitMix64::new(31);
        for i in 0..5_000 {
            let scale = [1.0, 1e3, 1e-4][i % 3];
            let taps: [[f32; 3]; 9] =
                std::array::from_fn(|_| [0, 1, 2].map(|_| (rng.next_f64() * scale) as f32));
            let s = cross_and_box_stats(&taps);
            let gamma = rng.range(0.5, 1.5) as f32;
            let (lo, hi) = variance_box(&s, gamma);
            for k in 0..3 {
                let v: Vec<f64> = taps.iter().map(|t| t[k] as f64).collect();
                let cross: Vec<f64> = CROSS.iter().map(|&i| v[i]).collect();
                let mean = v.iter().sum::<f64>() / 9.0;
                let var = v.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / 9.0;
                let fold = |xs: &[f64], f: fn(f64, f64) -> f64| xs.iter().copied().reduce(f).unwrap();
                let t = Tolerance::new(1e-6 * scale, 1e-5);
                t.check("min", s.min[k] as f64, fold(&v, f64::min)).unwrap();
                t.check("max", s.max[k] as f64, fold(&v, f64::max)).unwrap();
                t.check("mean", s.mean[k] as f64, mean).unwrap();
                t.check("min+", s.min_cross[k] as f64, fold(&cross, f64::min))
                    .unwrap();
                t.check("max+", s.max_cross[k] as f64, fold(&cross, f64::max))
                    .unwrap();
                t.check("mean+", s.mean_cross[k] as f64, cross.iter().sum::<f64>() / 5.0)
                    .unwrap();
                let sigma = var.sqrt();
                // sigma from E[x^2] - E[x]^2 in f32 loses digits when the spread is small
                // relative to the mean: allow for that cancellation.
                let tv = Tolerance::new(2e-3 * scale, 1e-3);
                tv.check(
                    "lo",
                    lo[k] as f64,
                    (mean - gamma as f64 * sigma).max(fold(&v, f64::min)),
                )
                .unwrap();
                tv.check(
                    "hi",
                    hi[k] as f64,
                    (mean + gamma as f64 * sigma).min(fold(&v, f64::max)),
                )
                .unwrap();
                assert!(lo[k] <= hi[k] + 1e-6 * scale as f32);
            }
        }
    }

    #[test]
    fn gather_clamps_at_edges() {
        let p: Vec<f32> = (0..12).map(|v| v as f32).collect(); // 4x3
        assert_eq!(
            gather3x3(&p, 4, 3, 0, 0),
            [0.0, 0.0, 1.0, 0.0, 0.0, 1.0, 4.0, 4.0, 5.0]
        );
        assert_eq!(
            gather3x3(&p, 4, 3, 3, 2),
            [6.0, 7.0, 7.0, 10.0, 11.0, 11.0, 10.0, 11.0, 11.0]
        );
    }

    #[test]
    fn row_stats_match_the_per_pixel_gather() {
        let mut rng = SplitMix64::new(33);
        for (w, h) in [(1, 1), (2, 3), (17, 5)] {
            let planes: Vec<Vec<f32>> = (0..3)
                .map(|_| (0..w * h).map(|_| rng.next_f64() as f32 * 10.0).collect())
                .collect();
            let p = [&planes[0][..], &planes[1][..], &planes[2][..]];
            for y in 0..h {
                let mut seen = 0;
                for_each_row_stats(p, w, h, y, |x, s| {
                    let taps: [[f32; 3]; 9] = std::array::from_fn(|i| {
                        let (xx, yy) = (
                            x as isize + (i % 3) as isize - 1,
                            y as isize + (i / 3) as isize - 1,
                        );
                        [0, 1, 2].map(|k| fetch_clamped(p[k], w, h, xx, yy))
                    });
                    let r = cross_and_box_stats(&taps);
                    let t = Tolerance::new(1e-5, 1e-6);
                    for k in 0..3 {
                        for (a, b) in [
                            (s.min[k], r.min[k]),
                            (s.max[k], r.max[k]),
                            (s.mean[k], r.mean[k]),
                            (s.mean_sq[k], r.mean_sq[k]),
                            (s.min_cross[k], r.min_cross[k]),
                            (s.max_cross[k], r.max_cross[k]),
                            (s.mean_cross[k], r.mean_cross[k]),
                        ] {
                            t.check("row stats", a as f64, b as f64).unwrap();
                        }
                    }
                    seen += 1;
                });
                assert_eq!(seen, w);
            }
        }
    }
}
