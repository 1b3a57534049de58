//! The one float-comparison helper of the crate.
//!
//! Every comparison of floating-point results (in tests, in checks against scalar
//! references, in validation) goes through [`Tolerance`], so that "how close is close
//! enough" is stated once per call site and means the same thing everywhere.

/// An absolute and a relative tolerance: `a` and `b` agree when
/// `|a - b| <= abs + rel * max(|a|, |b|)`.
///
/// Two NaNs never agree; two infinities of the same sign do.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Tolerance {
    /// Absolute part, for values near zero.
    pub abs: f64,
    /// Relative part, for large values.
    pub rel: f64,
}

impl Tolerance {
    /// Exact equality (infinities of the same sign included).
    pub const EXACT: Tolerance = Tolerance { abs: 0.0, rel: 0.0 };

    /// Purely absolute tolerance.
    pub const fn abs(abs: f64) -> Self {
        Tolerance { abs, rel: 0.0 }
    }

    /// Purely relative tolerance.
    pub const fn rel(rel: f64) -> Self {
        Tolerance { abs: 0.0, rel }
    }

    /// Both an absolute and a relative part.
    pub const fn new(abs: f64, rel: f64) -> Self {
        Tolerance { abs, rel }
    }

    /// Rounding of one f16 conversion (half a unit in the last place, 2^-11 relative),
    /// plus the smallest subnormal step for values near zero.
    pub const F16_ROUNDING: Tolerance = Tolerance {
        abs: 6.0e-8,
        rel: 1.0 / 2048.0,
    };

    /// Whether `a` and `b` agree within this tolerance.
    pub fn eq(&self, a: f64, b: f64) -> bool {
        if a.is_nan() || b.is_nan() {
            return false;
        }
        if a == b {
            return true;
        }
        if a.is_infinite() || b.is_infinite() {
            return false;
        }
        (a - b).abs() <= self.abs + self.rel * a.abs().max(b.abs())
    }

    /// Whether two f32 are the same bits, or both NaN: what a fast kernel that repeats its
    /// reference's operations must give. (Rust leaves the sign and payload of a NaN made by
    /// arithmetic unspecified, and the compiler may swap the operands of `+` and `*`.)
    pub fn same_bits(a: f32, b: f32) -> bool {
        a.to_bits() == b.to_bits() || (a.is_nan() && b.is_nan())
    }

    /// `Ok` when `a` and `b` agree, otherwise a message naming `what`, both values and
    /// the tolerance: handy in tests (`.unwrap()` prints it).
    pub fn check(&self, what: &str, a: f64, b: f64) -> Result<(), String> {
        if self.eq(a, b) {
            Ok(())
        } else {
            Err(format!(
                "{what}: {a} vs {b} differ by {} (tolerance abs {} rel {})",
                (a - b).abs(),
                self.abs,
                self.rel
            ))
        }
    }

    /// Compares two slices element by element; the error names the first index that
    /// disagrees and how many do.
    pub fn check_slices(&self, what: &str, a: &[f32], b: &[f32]) -> Result<(), String> {
        if a.len() != b.len() {
            return Err(format!("{what}: lengths differ, {} vs {}", a.len(), b.len()));
        }
        let mut first = None;
        let mut count = 0usize;
        for (i, (&x, &y)) in a.iter().zip(b).enumerate() {
            if !self.eq(x as f64, y as f64) {
                count += 1;
                first.get_or_insert((i, x, y));
            }
        }
        match first {
            None => Ok(()),
            Some((i, x, y)) => Err(format!(
                "{what}: {count} of {} values differ; first at index {i}: {x} vs {y} \
                 (tolerance abs {} rel {})",
                a.len(),
                self.abs,
                self.rel
            )),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn absolute_and_relative_parts() {
        let t = Tolerance::new(1e-3, 1e-2);
        assert!(t.eq(0.0, 0.0009));
        assert!(!t.eq(0.0, 0.0011));
        assert!(t.eq(1000.0, 1009.0));
        assert!(!t.eq(1000.0, 1012.0));
    }

    #[test]
    fn special_values() {
        let t = Tolerance::abs(1.0);
        assert!(!t.eq(f64::NAN, f64::NAN));
        assert!(t.eq(f64::INFINITY, f64::INFINITY));
        assert!(!t.eq(f64::INFINITY, f64::NEG_INFINITY));
        assert!(!t.eq(f64::INFINITY, 1e300));
        assert!(Tolerance::EXACT.eq(0.25, 0.25));
        assert!(!Tolerance::EXACT.eq(0.25, 0.2500001));
    }

    #[test]
    fn slice_check_names_the_first_difference() {
        let err = Tolerance::abs(0.1)
            .check_slices("x", &[1.0, 2.0, 3.0], &[1.0, 2.5, 3.5])
            .unwrap_err();
        assert!(err.contains("2 of 3"), "{err}");
        assert!(err.contains("index 1"), "{err}");
    }
}
