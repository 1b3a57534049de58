//! The Sobel operator (Oliveros 2018, sec. 3.8, eq. 3.5 and 3.6).

use super::neighborhood::gather3x3;
use wide::f32x8;

/// Gradient magnitude `sqrt(gx^2 + gy^2)` of nine taps (row-major, centre 4) with the
/// Sobel kernels of Oliveros 2018 eq. 3.5 (x: [-1 0 1; -2 0 2; -1 0 1]) and eq. 3.6
/// (y: [1 2 1; 0 0 0; -1 -2 -1]).
#[inline]
pub fn sobel_magnitude(t: &[f32; 9]) -> f32 {
    let gx = (t[2] + 2.0 * t[5] + t[8]) - (t[0] + 2.0 * t[3] + t[6]);
    let gy = (t[0] + 2.0 * t[1] + t[2]) - (t[6] + 2.0 * t[7] + t[8]);
    (gx * gx + gy * gy).sqrt()
}

/// [`sobel_magnitude`] of eight pixels' taps, lane by lane (the same operations, so the
/// same bits).
#[inline(always)]
pub fn sobel_magnitude_v(t: &[f32x8; 9]) -> f32x8 {
    let two = f32x8::splat(2.0);
    let gx = (t[2] + two * t[5] + t[8]) - (t[0] + two * t[3] + t[6]);
    let gy = (t[0] + two * t[1] + t[2]) - (t[6] + two * t[7] + t[8]);
    (gx * gx + gy * gy).sqrt()
}

/// Sobel magnitude of one row `y` of `src` into `out` (edges clamped).
pub fn sobel_plane(src: &[f32], width: usize, height: usize, y: usize, out: &mut [f32]) {
    for (x, o) in out.iter_mut().enumerate() {
        *o = sobel_magnitude(&gather3x3(src, width, height, x, y));
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::SplitMix64;
    use crate::tolerance::Tolerance;

    /// f64 reference by explicit convolution with the two matrices of eq. 3.5 and 3.6.
    fn sobel_f64(p: &[f64], w: usize, h: usize, x: usize, y: usize) -> f64 {
        let kx = [[-1.0, 0.0, 1.0], [-2.0, 0.0, 2.0], [-1.0, 0.0, 1.0]];
        let ky = [[1.0, 2.0, 1.0], [0.0, 0.0, 0.0], [-1.0, -2.0, -1.0]];
        let (mut gx, mut gy) = (0.0, 0.0);
        for (j, (rx, ry)) in kx.iter().zip(ky.iter()).enumerate() {
            for i in 0..3 {
                let xi = (x as isize + i as isize - 1).clamp(0, w as isize - 1) as usize;
                let yj = (y as isize + j as isize - 1).clamp(0, h as isize - 1) as usize;
                gx += rx[i] * p[yj * w + xi];
                gy += ry[i] * p[yj * w + xi];
            }
        }
        (gx * gx + gy * gy).sqrt()
    }

    #[test]
    fn sobel_matches_explicit_convolution() {
        let mut rng = SplitMix64::new(41);
        let (w, h) = (11, 7);
        for scale in [1.0, 1e3, 1e-4] {
            let p: Vec<f32> = (0..w * h).map(|_| (rng.next_f64() * scale) as f32).collect();
            let p64: Vec<f64> = p.iter().map(|&v| v as f64).collect();
            let mut row = vec![0.0; w];
            for y in 0..h {
                sobel_plane(&p, w, h, y, &mut row);
                for (x, &v) in row.iter().enumerate() {
                    Tolerance::new(1e-6 * scale, 1e-5)
                        .check("sobel", v as f64, sobel_f64(&p64, w, h, x, y))
                        .unwrap();
                }
            }
        }
        // A unit vertical step gives 4 (the 1-2-1 column weights) next to the step.
        let step: Vec<f32> = (0..w * h).map(|i| if i % w >= 5 { 1.0 } else { 0.0 }).collect();
        let mut row = vec![0.0; w];
        sobel_plane(&step, w, h, 3, &mut row);
        assert_eq!((row[3], row[4], row[5], row[6]), (0.0, 4.0, 4.0, 0.0));
    }
}
