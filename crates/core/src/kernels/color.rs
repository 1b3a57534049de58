//! Colour transforms: luma, YCoCg, and the reversible tonemap used for HDR accumulation.

use wide::f32x8;

/// Rec. 709 luma weights (linear RGB), as used by the metrics.
pub const LUMA_REC709: [f32; 3] = [0.2126, 0.7152, 0.0722];

/// Rec. 709 luma of a linear RGB colour.
#[inline(always)]
pub fn luma(c: [f32; 3]) -> f32 {
    LUMA_REC709[0] * c[0] + LUMA_REC709[1] * c[1] + LUMA_REC709[2] * c[2]
}

/// [`luma`] of eight colours, lane by lane (the same operations, so the same bits).
#[inline(always)]
pub fn luma_v(c: &[f32x8; 3]) -> f32x8 {
    let k = LUMA_REC709.map(f32x8::splat);
    k[0] * c[0] + k[1] * c[1] + k[2] * c[2]
}

/// RGB to YCoCg (Malvar and Sullivan 2003): Y = R/4 + G/2 + B/4, Co = (R - B)/2,
/// Cg = -R/4 + G/2 - B/4. The clip box of the TAA is built in this space (Karis 2014),
/// where luma and chroma are separated and the box is tighter.
#[inline(always)]
pub fn rgb_to_ycocg(c: [f32; 3]) -> [f32; 3] {
    let [r, g, b] = c;
    [
        0.25 * r + 0.5 * g + 0.25 * b,
        0.5 * r - 0.5 * b,
        -0.25 * r + 0.5 * g - 0.25 * b,
    ]
}

/// Inverse of [`rgb_to_ycocg`].
#[inline(always)]
pub fn ycocg_to_rgb(c: [f32; 3]) -> [f32; 3] {
    let [y, co, cg] = c;
    let t = y - cg;
    [t + co, y + cg, t - co]
}

/// The largest value [`tonemap`] produces that [`tonemap_inverse`] accepts: inputs up to
/// about 1e7 survive the round trip, larger ones come back as about 1e7.
pub const TONEMAP_MAX: f32 = 1.0 - 1.0e-7;

/// The reversible tonemap `c / (1 + max(r, g, b))` (Karis 2014, "High quality temporal
/// supersampling"): maps HDR colour into [0, 1) so a single firefly cannot dominate the
/// accumulation, and is undone exactly by [`tonemap_inverse`]. Expects `c >= 0`.
#[inline(always)]
pub fn tonemap(c: [f32; 3]) -> [f32; 3] {
    let k = 1.0 / (1.0 + c[0].max(c[1]).max(c[2]));
    [c[0] * k, c[1] * k, c[2] * k]
}

/// Inverse of [`tonemap`]: `t / (1 - max(t))`, with `max(t)` held below 1.
#[inline(always)]
pub fn tonemap_inverse(t: [f32; 3]) -> [f32; 3] {
    let m = t[0].max(t[1]).max(t[2]).min(TONEMAP_MAX);
    let k = 1.0 / (1.0 - m);
    [t[0] * k, t[1] * k, t[2] * k]
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::SplitMix64;
    use crate::tolerance::Tolerance;

    fn ycocg_f64(c: [f64; 3]) -> [f64; 3] {
        // The matrix form, written independently of the kernel.
        let m = [[0.25, 0.5, 0.25], [0.5, 0.0, -0.5], [-0.25, 0.5, -0.25]];
        let mut out = [0.0; 3];
        for (o, row) in out.iter_mut().zip(m) {
            *o = row[0] * c[0] + row[1] * c[1] + row[2] * c[2];
        }
        out
    }

    /// 10 000 random colours from a generator seeded `seed`, each with the scale it was
    /// drawn at (`scales` in turn), components in `[0, scale)`.
    fn random_colours(seed: u64, scales: [f64; 4]) -> impl Iterator<Item = ([f32; 3], f64)> {
        let mut rng = SplitMix64::new(seed);
        (0..10_000).map(move |i| {
            let scale = scales[i % 4];
            ([0, 1, 2].map(|_| (rng.next_f64() * scale) as f32), scale)
        })
    }

    #[test]
    fn ycocg_matches_the_matrix_and_round_trips() {
        // Random LDR, HDR and adversarial (tiny, huge) colours.
        for (c, scale) in random_colours(7, [1.0, 100.0, 1e-6, 1e5]) {
            let y = rgb_to_ycocg(c);
            let r = ycocg_f64(c.map(f64::from));
            // Co and Cg are differences: their error is relative to the inputs' scale.
            let tol = Tolerance::new(1e-7 * scale, 1e-6);
            for k in 0..3 {
                tol.check("ycocg", y[k] as f64, r[k]).unwrap();
            }
            let back = ycocg_to_rgb(y);
            for k in 0..3 {
                Tolerance::new(1e-6 * scale, 1e-6)
                    .check("round trip", back[k] as f64, c[k] as f64)
                    .unwrap();
            }
        }
    }

    #[test]
    fn tonemap_round_trips_and_matches_f64() {
        for (c, _) in random_colours(8, [1.0, 1e3, 1e-6, 1e5]) {
            let t = tonemap(c);
            let m = c.iter().fold(0.0f64, |a, &v| a.max(v as f64));
            for k in 0..3 {
                Tolerance::new(1e-7, 1e-6)
                    .check("tonemap", t[k] as f64, c[k] as f64 / (1.0 + m))
                    .unwrap();
            }
            assert!(t.iter().all(|&v| (0.0..1.0).contains(&v)));
            let back = tonemap_inverse(t);
            // Relative precision of the round trip degrades as 1/(1 - max t) ~ (1 + m).
            let tol = Tolerance::new(1e-7, 2e-6 * (1.0 + m));
            for k in 0..3 {
                tol.check("round trip", back[k] as f64, c[k] as f64).unwrap();
            }
        }
        // Extremes stay finite.
        for v in [0.0f32, 1e-30, 1e6, 1e12, f32::MAX] {
            let back = tonemap_inverse(tonemap([v, 0.0, v * 0.5]));
            assert!(back.iter().all(|x| x.is_finite()), "{v}: {back:?}");
        }
    }

    #[test]
    fn luma_weights_sum_to_one() {
        Tolerance::abs(1e-7)
            .check("sum", luma([1.0, 1.0, 1.0]) as f64, 1.0)
            .unwrap();
    }
}
