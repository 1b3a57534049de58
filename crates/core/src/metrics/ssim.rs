//! SSIM (Wang, Bovik, Sheikh, Simoncelli 2004, "Image quality assessment: from error
//! visibility to structural similarity"), with a Gaussian window.
//!
//! Matches scikit-image's `structural_similarity(gaussian_weights=True, sigma=1.5,
//! use_sample_covariance=False, data_range=1)`: separable Gaussian filtering with
//! half-sample symmetric ("reflect") borders, and a mean over the map without a border
//! of the window radius.

use super::{check_same_size, MetricsError};
use crate::frame::Plane;

/// Gaussian window sigma (Wang et al. 2004, sec. III-C: 11x11, sigma 1.5).
pub const SSIM_SIGMA: f64 = 1.5;
/// Window radius: 11x11 taps (Wang et al. 2004, sec. III-C).
pub const SSIM_RADIUS: usize = 5;
/// K1 of the stabilising constant C1 = (K1 L)^2 (Wang et al. 2004, eq. 7).
pub const SSIM_C1_K: f64 = 0.01;
/// K2 of the stabilising constant C2 = (K2 L)^2 (Wang et al. 2004, eq. 7).
pub const SSIM_C2_K: f64 = 0.03;

/// Mean SSIM and, when asked for, the per-pixel map.
#[derive(Clone, Debug)]
pub struct SsimResult {
    /// Mean over the map without a border of [`SSIM_RADIUS`] pixels (the whole map when
    /// the image is too small for a border).
    pub mean: f64,
    /// The SSIM of every pixel, when asked for.
    pub map: Option<Plane<f32>>,
}

fn gaussian_taps() -> [f64; 2 * SSIM_RADIUS + 1] {
    let mut k = [0.0; 2 * SSIM_RADIUS + 1];
    for (i, t) in k.iter_mut().enumerate() {
        let x = i as f64 - SSIM_RADIUS as f64;
        *t = (-0.5 * x * x / (SSIM_SIGMA * SSIM_SIGMA)).exp();
    }
    let s: f64 = k.iter().sum();
    k.map(|v| v / s)
}

/// Half-sample symmetric reflection of index `i` into `0..n` (d c b a | a b c d | d c b a).
fn reflect(i: isize, n: usize) -> usize {
    let n = n as isize;
    let period = 2 * n;
    let mut m = i.rem_euclid(period);
    if m >= n {
        m = period - 1 - m;
    }
    m as usize
}

/// Separable Gaussian blur of a w x h f64 image.
fn blur(src: &[f64], w: usize, h: usize, k: &[f64]) -> Vec<f64> {
    let r = SSIM_RADIUS as isize;
    let mut tmp = vec![0.0; w * h];
    for y in 0..h {
        let row = &src[y * w..(y + 1) * w];
        for x in 0..w {
            let mut s = 0.0;
            for (j, kv) in k.iter().enumerate() {
                s += kv * row[reflect(x as isize + j as isize - r, w)];
            }
            tmp[y * w + x] = s;
        }
    }
    let mut out = vec![0.0; w * h];
    for y in 0..h {
        for x in 0..w {
            let mut s = 0.0;
            for (j, kv) in k.iter().enumerate() {
                s += kv * tmp[reflect(y as isize + j as isize - r, h) * w + x];
            }
            out[y * w + x] = s;
        }
    }
    out
}

/// SSIM of two single-channel images in [0, 1] (data range 1).
pub fn ssim(a: &Plane<f64>, b: &Plane<f64>, with_map: bool) -> Result<SsimResult, MetricsError> {
    check_same_size("ssim", a, b)?;
    let (w, h) = a.size();
    let k = gaussian_taps();
    let (x, y) = (a.data(), b.data());
    let prod = |f: fn(f64, f64) -> f64| -> Vec<f64> { x.iter().zip(y).map(|(&p, &q)| f(p, q)).collect() };
    let ux = blur(x, w, h, &k);
    let uy = blur(y, w, h, &k);
    let uxx = blur(&prod(|p, _| p * p), w, h, &k);
    let uyy = blur(&prod(|_, q| q * q), w, h, &k);
    let uxy = blur(&prod(|p, q| p * q), w, h, &k);
    let c1 = SSIM_C1_K * SSIM_C1_K;
    let c2 = SSIM_C2_K * SSIM_C2_K;
    let map: Vec<f64> = (0..w * h)
        .map(|i| {
            let (mx, my) = (ux[i], uy[i]);
            let vx = uxx[i] - mx * mx;
            let vy = uyy[i] - my * my;
            let vxy = uxy[i] - mx * my;
            ((2.0 * mx * my + c1) * (2.0 * vxy + c2)) / ((mx * mx + my * my + c1) * (vx + vy + c2))
        })
        .collect();
    let r = SSIM_RADIUS;
    let (x0, x1, y0, y1) = if w > 2 * r && h > 2 * r {
        (r, w - r, r, h - r)
    } else {
        (0, w, 0, h)
    };
    let mut sum = 0.0;
    for yy in y0..y1 {
        for xx in x0..x1 {
            sum += map[yy * w + xx];
        }
    }
    let mean = sum / ((x1 - x0) * (y1 - y0)) as f64;
    Ok(SsimResult {
        mean,
        map: with_map.then(|| Plane::from_vec(w, h, map.iter().map(|&v| v as f32).collect()).expect("size")),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::tolerance::Tolerance;

    #[test]
    fn identical_images_score_one_and_reflection_is_symmetric() {
        let a = Plane::from_fn(20, 16, |x, y| ((x * 7 + y * 3) % 11) as f64 / 11.0);
        let r = ssim(&a, &a, true).unwrap();
        Tolerance::abs(1e-12).check("ssim", r.mean, 1.0).unwrap();
        assert_eq!(reflect(-1, 5), 0);
        assert_eq!(reflect(-2, 5), 1);
        assert_eq!(reflect(5, 5), 4);
        assert_eq!(reflect(6, 5), 3);
        let k = gaussian_taps();
        Tolerance::abs(1e-12)
            .check("taps sum", k.iter().sum(), 1.0)
            .unwrap();
    }

    #[test]
    fn structure_loss_lowers_ssim() {
        let a = Plane::from_fn(32, 32, |x, y| if (x / 2 + y / 2) % 2 == 0 { 0.9 } else { 0.1 });
        let flat = Plane::filled(32, 32, 0.5);
        let r = ssim(&a, &flat, false).unwrap();
        assert!(ssim(&a, &Plane::filled(31, 32, 0.5), false).is_err());
        assert!(r.mean < 0.1, "{}", r.mean);
    }
}
