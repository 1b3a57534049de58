//! PHLM's temporal feature `z` (Iglesias-Guitian et al. 2016, sec. 5.1): an exponential accumulation (eq. 1) of a
//! low-pass of the input, with a per-pixel convergence factor from luma contrast.
//!
//! The paper gives `alpha = phi(v, l) / (l + Delta(Y))`, `phi = a l^2 + b v l^3`, with
//! `v` the screen-space velocity, `Delta(Y)` the luma range of the neighbourhood and `l` "the
//! minimum distance between the luminance value for the pixel in the accumulated feature
//! image and the range of luminance described by Delta(Y)". It leaves open which side of
//! the blend alpha weights and its limits. Our reading, and why:
//! - `alpha` weighs the *current* low-pass sample: it grows with `l` (the accumulated feature
//!   has left what the neighbourhood now shows: catch up) and with `v l^3` (moving content
//!   catches up faster), which is the direction every contrast-driven TAA blend takes
//!   (Karis 2014, Lottes' TXAA). Read the other way, a feature inside the range (`l = 0`)
//!   would take no history at all and the feature would not be "free of noise".
//! - `l = 0` inside the range, so `phi = 0` there: we keep a floor `alpha_min` (default
//!   [`DEFAULT_ALPHA_MIN`]) so a consistent feature still averages new samples instead of
//!   freezing at its first value; and `alpha <= 1`.
//! - luma is YCgCo's Y (sec. 5.1: "using the YCgCo colorspace"), in the filter's working
//!   space (the tonemapped one for HDR input, where Y lies in [0, 1)); the low-pass is the
//!   3x3 box mean.

use super::Params;
use crate::kernels::lanes::{self, Lanes};
use wide::f32x8;

/// `a = 0.125` (Iglesias-Guitian et al. 2016, sec. 5.1: "we have used a = 0.125 and b = 0.25").
pub const DEFAULT_A: f32 = 0.125;
/// `b = 0.25` (Iglesias-Guitian et al. 2016, sec. 5.1).
pub const DEFAULT_B: f32 = 0.25;
/// Floor of the convergence factor (our choice; see the module docs): 0.08, a memory of
/// about 12 frames. Measured on the scene catalogue's mean with the persistent box test
/// and the speed jump (`clip_after`, `fail_ramp`, `speed_jump`; docs/phlm-ablations.md,
/// table 13): 0.03 / 0.06 / 0.075 / 0.08 give 30.88 / 30.89 / 30.87 / 30.86 dB at 128x72
/// and 33.23 / 33.25 / 33.24 / 33.23 at 256x144, flat; the floor decides how fast the
/// feature follows a change of shading with no motion, so the worst scene against `taa`
/// (`dynamic-light` at 256x144) goes -0.55 / -0.23 / -0.12 / -0.10 dB, and still detail
/// gives a little back (`static` at 256x144: +2.97 / +2.77 / +2.75 dB at 0.03 / 0.075 /
/// 0.08). Before that test (every failure clipped, `clip_p = 1`): 0.125 gave 29.04 dB,
/// 0.06 29.15, 0.03 29.34 (thin-line 31.5 -> 35.5 dB).
pub const DEFAULT_ALPHA_MIN: f32 = 0.08;
/// Guard of the denominator `l + Delta(Y)` on flat neighbourhoods.
pub const EPS: f32 = 1e-6;

/// YCgCo luma of an RGB colour (the Y of [`crate::kernels::rgb_to_ycocg`]).
#[inline(always)]
fn y_of(c: [f32; 3]) -> f32 {
    0.25 * c[0] + 0.5 * c[1] + 0.25 * c[2]
}

/// The convergence factor: weight of the current low-pass sample, in `[alpha_min, 1]`.
/// `l` = distance of the feature's luma to `[lo, hi]`, `v` = motion length in pixels.
#[inline(always)]
pub fn convergence(feature_luma: f32, lo: f32, hi: f32, v: f32, p: &Params) -> f32 {
    let l = (lo - feature_luma).max(feature_luma - hi).max(0.0);
    let phi = p.feature_a * l * l + p.feature_b * v * l * l * l;
    (phi / (l + (hi - lo) + EPS)).clamp(p.feature_alpha_min, 1.0)
}

/// One step of the feature: `z = z_prev + alpha (lowpass - z_prev)` (eq. 1 with `alpha`
/// from [`convergence`]); `lo`, `hi` = the neighbourhood's luma range.
#[inline(always)]
pub fn accumulate(prev: [f32; 3], lowpass: [f32; 3], lo: f32, hi: f32, v: f32, p: &Params) -> [f32; 3] {
    let a = convergence(y_of(prev), lo, hi, v, p);
    [0, 1, 2].map(|k| prev[k] + a * (lowpass[k] - prev[k]))
}

/// [`accumulate`] for a block of pixels in lanes (the same bits per lane).
#[inline(always)]
pub fn accumulate_lanes(
    prev: &[Lanes; 3],
    lowpass: &[Lanes; 3],
    lo: &Lanes,
    hi: &Lanes,
    v_speed: &Lanes,
    p: &Params,
) -> [Lanes; 3] {
    // In `f32x8` with the scalar operations in their order (`max` and `clamp` as
    // [`lanes::max_of`] and comparisons, NaN as there): as a lane loop it compiled to
    // 4-float halves with a NaN blend per `max`.
    let v = |a: &Lanes| f32x8::from(*a);
    let splat = f32x8::splat;
    let [r, g, b] = [v(&prev[0]), v(&prev[1]), v(&prev[2])];
    let fl = splat(0.25) * r + splat(0.5) * g + splat(0.25) * b;
    let (lo, hi, speed) = (v(lo), v(hi), v(v_speed));
    let l = lanes::max_of(lanes::max_of(lo - fl, fl - hi), splat(0.0));
    let phi = splat(p.feature_a) * l * l + splat(p.feature_b) * speed * l * l * l;
    let a = phi / (l + (hi - lo) + splat(EPS));
    // `f32::clamp`: below the floor -> the floor, above 1 -> 1 (NaN stays).
    let a = a
        .simd_lt(splat(p.feature_alpha_min))
        .select(splat(p.feature_alpha_min), a);
    let a = a.simd_gt(splat(1.0)).select(splat(1.0), a);
    let out = |c: f32x8, lp: &Lanes| (c + a * (v(lp) - c)).to_array();
    [out(r, &lowpass[0]), out(g, &lowpass[1]), out(b, &lowpass[2])]
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::kernels::rgb_to_ycocg;
    use crate::tolerance::Tolerance;

    #[test]
    fn luma_is_ycgco_y() {
        let c = [0.3, 0.7, 0.1];
        Tolerance::abs(1e-7)
            .check("Y", y_of(c) as f64, rgb_to_ycocg(c)[0] as f64)
            .unwrap();
    }

    #[test]
    fn convergence_follows_phi_over_l_plus_range() {
        let p = Params::default();
        // Inside the range: the floor.
        assert_eq!(convergence(0.5, 0.4, 0.6, 3.0, &p), p.feature_alpha_min);
        let floor = p.feature_alpha_min as f64;
        // Far outside, still: a l^2 / (l + Delta), f64 reference.
        for (y, lo, hi, v) in [
            (2.0f32, 0.1f32, 0.2f32, 0.0f32),
            (-3.0, 0.0, 0.5, 2.0),
            (9.0, 0.0, 0.0, 0.5),
        ] {
            let l = ((lo - y).max(y - hi)) as f64;
            let phi = 0.125 * l * l + 0.25 * v as f64 * l * l * l;
            let expect = (phi / (l + (hi - lo) as f64 + EPS as f64)).clamp(floor, 1.0);
            Tolerance::new(1e-6, 1e-5)
                .check("alpha", convergence(y, lo, hi, v, &p) as f64, expect)
                .unwrap();
        }
        // Monotone in the distance and in motion.
        let a1 = convergence(1.0, 0.0, 0.1, 0.0, &p);
        let a2 = convergence(2.0, 0.0, 0.1, 0.0, &p);
        let a3 = convergence(2.0, 0.0, 0.1, 1.0, &p);
        assert!(a1 <= a2 && a2 < a3, "{a1} {a2} {a3}");
    }

    #[test]
    fn a_flat_neighbourhood_never_divides_by_zero() {
        let p = Params::default();
        let a = convergence(0.5, 0.5, 0.5, 0.0, &p);
        assert!(a.is_finite() && a == p.feature_alpha_min);
        let z = accumulate([1.0; 3], [0.0; 3], 0.0, 0.0, 100.0, &p);
        assert!(z.iter().all(|v| v.is_finite() && *v >= 0.0 && *v <= 1.0));
    }

    #[test]
    fn lanes_give_the_scalar_bits() {
        use crate::kernels::lanes::LANES;
        let mut rng = crate::rng::SplitMix64::new(17);
        let p = Params::default();
        // Special values (NaN, infinities, signed zeros, negatives) in some lanes, and
        // ties: the vector `max` and `clamp` must give the scalar ones' bits there too.
        const SPECIAL: [f32; 8] = [
            f32::NAN,
            f32::INFINITY,
            f32::NEG_INFINITY,
            0.0,
            -0.0,
            -1.5,
            1e30,
            1e-30,
        ];
        for case in 0..4000 {
            let mut r = |s: f64| -> Lanes {
                std::array::from_fn(|_| {
                    let u = rng.next_f64();
                    if case % 2 == 1 && u < 0.15 {
                        SPECIAL[(u * 1e6) as usize % SPECIAL.len()]
                    } else {
                        (rng.next_f64() * s) as f32
                    }
                })
            };
            let (prev, lowpass) = ([r(2.0), r(2.0), r(2.0)], [r(2.0), r(2.0), r(2.0)]);
            let (mut lo, spread, v) = (r(1.0), r(0.5), r(8.0));
            if case % 3 == 0 {
                // The feature's luma on a bound of the box.
                lo[case % LANES] =
                    0.25 * prev[0][case % LANES] + 0.5 * prev[1][case % LANES] + 0.25 * prev[2][case % LANES];
            }
            let hi: Lanes = std::array::from_fn(|k| lo[k] + spread[k]);
            let z = accumulate_lanes(&prev, &lowpass, &lo, &hi, &v, &p);
            for k in 0..LANES {
                let pick = |a: &[Lanes; 3]| [a[0][k], a[1][k], a[2][k]];
                let want = accumulate(pick(&prev), pick(&lowpass), lo[k], hi[k], v[k], &p);
                let got = pick(&z);
                assert!(
                    (0..3).all(|c| Tolerance::same_bits(want[c], got[c])),
                    "case {case} lane {k}: scalar {want:?} lanes {got:?} (prev {:?}, lo {}, hi {}, v {})",
                    pick(&prev),
                    lo[k],
                    hi[k],
                    v[k]
                );
            }
        }
    }
}
