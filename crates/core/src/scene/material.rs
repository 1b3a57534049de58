//! Procedural textures and materials.

use glam::{DVec2, DVec3};

/// `floor(x)` as an integer without a libm call (baseline x86-64 has no rounding
/// instruction for it) and without the saturating float-to-integer cast on the common
/// path: adding 1.5 x 2^52 rounds `x` to the nearest integer, which then sits in the low
/// mantissa bits. Values beyond 2^51 take the saturating cast, which only changes the
/// pattern parity at distances no scene reaches.
#[inline]
fn floor_i64(x: f64) -> i64 {
    const MAGIC: f64 = 6_755_399_441_055_744.0; // 1.5 x 2^52
    if x.abs() < 2_251_799_813_685_248.0 {
        // |x| < 2^51: y's ulp is 1, so y - MAGIC is x rounded to the nearest integer.
        let y = x + MAGIC;
        let nearest = (y.to_bits() as i64).wrapping_sub(MAGIC.to_bits() as i64);
        nearest - ((y - MAGIC) > x) as i64
    } else {
        let i = x as i64;
        if (i as f64) > x {
            i.saturating_sub(1)
        } else {
            i
        }
    }
}

/// A procedural pattern mixing two colours over local texture coordinates.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Pattern {
    /// Colour `a` everywhere.
    Solid,
    /// Squares of side `size`.
    Checker {
        /// Side of a square, world units.
        size: f64,
    },
    /// Stripes across u with this period (half `a`, half `b`).
    Stripes {
        /// Period, world units.
        period: f64,
    },
    /// A zone plate `0.5 + 0.5 cos(k |uv|^2)`: frequency rising without bound, the
    /// hardest case for any anti-aliasing filter.
    ZonePlate {
        /// Chirp rate.
        k: f64,
    },
}

/// A surface: albedo pattern, emission, optional Blinn-Phong specular.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Material {
    /// The albedo pattern.
    pub pattern: Pattern,
    /// First colour.
    pub a: DVec3,
    /// Second colour.
    pub b: DVec3,
    /// Emitted radiance (added regardless of light).
    pub emission: DVec3,
    /// Specular strength (0: none).
    pub specular: f64,
    /// Blinn-Phong exponent.
    pub shininess: f64,
}

impl Material {
    /// A matte solid colour.
    pub fn matte(c: DVec3) -> Material {
        Material {
            pattern: Pattern::Solid,
            a: c,
            b: c,
            emission: DVec3::ZERO,
            specular: 0.0,
            shininess: 1.0,
        }
    }

    /// A matte pattern of two colours.
    pub fn patterned(pattern: Pattern, a: DVec3, b: DVec3) -> Material {
        Material {
            pattern,
            a,
            b,
            ..Material::matte(a)
        }
    }

    /// A pure emitter (black albedo).
    pub fn emitter(e: DVec3) -> Material {
        Material {
            emission: e,
            ..Material::matte(DVec3::ZERO)
        }
    }

    /// With Blinn-Phong specular.
    pub fn with_specular(self, strength: f64, shininess: f64) -> Material {
        Material {
            specular: strength,
            shininess,
            ..self
        }
    }

    /// Albedo at texture coordinates `uv`.
    #[inline(always)]
    pub fn albedo(&self, uv: DVec2) -> DVec3 {
        let m = match self.pattern {
            Pattern::Solid => 0.0,
            Pattern::Checker { size } => ((floor_i64(uv.x / size) + floor_i64(uv.y / size)) & 1) as f64,
            Pattern::Stripes { period } => (floor_i64(2.0 * uv.x / period) & 1) as f64,
            Pattern::ZonePlate { k } => 0.5 - 0.5 * (k * uv.length_squared()).cos(),
        };
        self.a + (self.b - self.a) * m
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn floor_matches_std() {
        for x in [
            -2.5,
            -2.0,
            -0.5,
            -0.0,
            0.0,
            0.3,
            1.0,
            7.9,
            -1e-12,
            1e15 + 0.5,
            0.5,
            1.5,
            2.5,
            -1.5,
            -3.5,
            4503599627370495.5,
            -2251799813685247.5,
            2251799813685248.0,
            -1e300,
        ] {
            assert_eq!(floor_i64(x), x.floor() as i64, "{x}");
        }
        // Random values at every scale a texture coordinate over a pattern size can take,
        // and the integers and half-integers around them.
        let mut rng = crate::rng::SplitMix64::new(7);
        for _ in 0..100_000 {
            let x = rng.range(-1.0, 1.0) * 10f64.powf(rng.range(-6.0, 16.0));
            for x in [x, x.round(), x.round() + 0.5, x.round() - 0.5] {
                assert_eq!(floor_i64(x), x.floor() as i64, "{x}");
            }
        }
    }
}
