//! Sparse shading: a frame whose colour is shaded at one pixel of every `factor x factor`
//! block of the full-resolution grid (Herzog et al. 2010, sec. 3.2 and fig. 2:
//! "regularly sampled shading", one sample set per frame in a rotating order).
//!
//! The colour plane then has its own size, `ceil(width / factor) x ceil(height / factor)`;
//! its sample `(a, b)` was shaded at the centre of full-resolution pixel
//! `(factor * a + phase[0], factor * b + phase[1])`. Samples whose position falls outside
//! the frame (the last column or row of a size that `factor` does not divide) carry no
//! shading; filters ignore them ([`Sampling::position`] returns `None`).

use serde::{Deserialize, Serialize};

/// Factors a frame's colour may be shaded at: every pixel, one of 2x2, one of 4x4 (the
/// block sizes of Herzog et al. 2010, sec. 4).
pub const FACTORS: [u32; 3] = [1, 2, 4];

/// Where this frame's colour samples lie on the full-resolution grid.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub struct Sampling {
    /// Block size: one shaded pixel per `factor x factor` block (1, 2 or 4).
    pub factor: u32,
    /// The shaded pixel within each block, x right and y down, each below `factor`.
    pub phase: [u32; 2],
}

impl Sampling {
    /// Every pixel shaded (an ordinary frame).
    pub const FULL: Sampling = Sampling {
        factor: 1,
        phase: [0, 0],
    };

    /// The pattern of frame `index` for block size `factor`: the pixel of rank
    /// `index mod factor^2` in the Bayer ordered-dither matrix, so that consecutive frames
    /// are spread over the block and every pixel is shaded once per `factor^2` frames
    /// (the "regular rotating order" of Herzog et al. 2010, fig. 2). For 2x2 the order is (0,0),
    /// (1,1), (1,0), (0,1). `factor` must be a power of two.
    pub fn rotating(factor: u32, index: u64) -> Sampling {
        let rank = (index % (factor as u64 * factor as u64)) as u32;
        let phase = (0..factor)
            .flat_map(|y| (0..factor).map(move |x| [x, y]))
            .find(|&[x, y]| bayer_rank(factor, x, y) == rank)
            .unwrap_or([0, 0]);
        Sampling { factor, phase }
    }

    /// Whether this is full-resolution shading.
    pub fn is_full(self) -> bool {
        self.factor == 1
    }

    /// Frames until every pixel has been shaded once: `factor^2`.
    pub fn period(self) -> u64 {
        self.factor as u64 * self.factor as u64
    }

    /// Size of the colour planes for a `width x height` frame.
    pub fn color_size(self, width: usize, height: usize) -> (usize, usize) {
        let f = self.factor.max(1) as usize;
        (width.div_ceil(f), height.div_ceil(f))
    }

    /// The full-resolution pixel that colour sample `(a, b)` was shaded at, or `None` when
    /// it falls outside a `width x height` frame.
    #[inline(always)]
    pub fn position(self, a: usize, b: usize, width: usize, height: usize) -> Option<(usize, usize)> {
        let f = self.factor as usize;
        let (x, y) = (f * a + self.phase[0] as usize, f * b + self.phase[1] as usize);
        (x < width && y < height).then_some((x, y))
    }

    /// Whether full-resolution pixel `(x, y)` was shaded this frame.
    #[inline(always)]
    pub fn is_shaded(self, x: usize, y: usize) -> bool {
        let f = self.factor as usize;
        x % f == self.phase[0] as usize && y % f == self.phase[1] as usize
    }

    /// Checks the factor and phase; the error says what is wrong.
    pub fn validate(self) -> Result<(), String> {
        if !FACTORS.contains(&self.factor) {
            return Err(format!(
                "shading factor must be one of {FACTORS:?} (one shaded pixel per factor x factor block), got {}",
                self.factor
            ));
        }
        if self.phase.iter().any(|&p| p >= self.factor) {
            return Err(format!(
                "shading phase must lie in the {f}x{f} block (each below {f}), got {:?}",
                self.phase,
                f = self.factor
            ));
        }
        Ok(())
    }
}

impl Default for Sampling {
    fn default() -> Self {
        Sampling::FULL
    }
}

/// Rank of `(x, y)` in the `n x n` Bayer matrix (n a power of two): M(2n) = 4 M(n) tiled
/// plus M(2) scaled, with M(2) = [[0, 2], [3, 1]].
fn bayer_rank(n: u32, x: u32, y: u32) -> u32 {
    let mut rank = 0;
    let mut size = n;
    let (mut x, mut y) = (x, y);
    let mut scale = 1;
    while size > 1 {
        let (bx, by) = (x & 1, y & 1);
        let m2 = match (bx, by) {
            (0, 0) => 0,
            (1, 1) => 1,
            (1, 0) => 2,
            _ => 3,
        };
        rank += m2 * scale;
        // The finest bit decides the coarse order: Bayer ranks the 2x2 offsets first.
        scale *= 4;
        x >>= 1;
        y >>= 1;
        size >>= 1;
    }
    // Reverse the digit order: the lowest bit of the position is the most significant
    // digit of the rank, so consecutive ranks jump across the block.
    reverse_base4(rank, n)
}

fn reverse_base4(mut v: u32, n: u32) -> u32 {
    let digits = n.trailing_zeros();
    let mut out = 0;
    for _ in 0..digits {
        out = out * 4 + v % 4;
        v /= 4;
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rotating_pattern_covers_every_pixel_once_per_period() {
        for f in [1u32, 2, 4] {
            let period = (f * f) as u64;
            let mut seen = std::collections::HashSet::new();
            for i in 0..period {
                let s = Sampling::rotating(f, i);
                s.validate().unwrap();
                assert!(seen.insert(s.phase), "factor {f}: {:?} twice", s.phase);
                assert_eq!(Sampling::rotating(f, i + period), s, "periodic");
            }
            assert_eq!(seen.len() as u64, period);
        }
        let order: Vec<[u32; 2]> = (0..4).map(|i| Sampling::rotating(2, i).phase).collect();
        assert_eq!(order, vec![[0, 0], [1, 1], [1, 0], [0, 1]]);
        // 4x4: consecutive frames jump across the block (the first four ranks are the
        // corners of a 2-pixel lattice), as in an ordered-dither matrix.
        let first: Vec<[u32; 2]> = (0..4).map(|i| Sampling::rotating(4, i).phase).collect();
        assert_eq!(first, vec![[0, 0], [2, 2], [2, 0], [0, 2]]);
    }

    #[test]
    fn positions_and_sizes() {
        let s = Sampling {
            factor: 2,
            phase: [1, 0],
        };
        assert_eq!(s.color_size(5, 3), (3, 2));
        assert_eq!(s.position(0, 0, 5, 3), Some((1, 0)));
        assert_eq!(s.position(2, 1, 5, 3), None, "x = 5 is outside a 5-wide frame");
        assert!(s.is_shaded(3, 2) && !s.is_shaded(2, 2));
        assert!(Sampling {
            factor: 3,
            phase: [0, 0]
        }
        .validate()
        .unwrap_err()
        .contains("[1, 2, 4]"));
        assert!(Sampling {
            factor: 2,
            phase: [2, 0]
        }
        .validate()
        .unwrap_err()
        .contains("below 2"));
    }
}
