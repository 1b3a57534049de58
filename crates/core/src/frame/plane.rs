//! A planar image channel: one `Vec<T>` of `width * height` samples, row-major.

use super::FrameError;

/// One channel of an image: `width * height` samples of `T`, row-major (row 0 at the top).
///
/// Planar storage maps 1:1 onto GPU storage buffers and lets rayon split work by rows.
#[derive(Clone, Debug, PartialEq)]
pub struct Plane<T> {
    width: usize,
    height: usize,
    data: Vec<T>,
}

impl<T> Plane<T> {
    /// Width in pixels.
    pub fn width(&self) -> usize {
        self.width
    }

    /// Height in pixels.
    pub fn height(&self) -> usize {
        self.height
    }

    /// `(width, height)`.
    pub fn size(&self) -> (usize, usize) {
        (self.width, self.height)
    }
}

impl<T: Copy + Default> Plane<T> {
    /// A plane filled with `T::default()` (zero).
    pub fn new(width: usize, height: usize) -> Self {
        Self::filled(width, height, T::default())
    }
}

impl<T: Copy> Plane<T> {
    /// A plane filled with `value`.
    pub fn filled(width: usize, height: usize, value: T) -> Self {
        Plane {
            width,
            height,
            data: vec![value; width * height],
        }
    }

    /// A plane whose sample at `(x, y)` is `f(x, y)`.
    pub fn from_fn(width: usize, height: usize, mut f: impl FnMut(usize, usize) -> T) -> Self {
        let mut data = Vec::with_capacity(width * height);
        for y in 0..height {
            for x in 0..width {
                data.push(f(x, y));
            }
        }
        Plane { width, height, data }
    }

    /// Wraps `data`; its length must be `width * height`.
    pub fn from_vec(width: usize, height: usize, data: Vec<T>) -> Result<Self, FrameError> {
        let expected = width
            .checked_mul(height)
            .ok_or(FrameError::TooLarge { width, height })?;
        if data.len() != expected {
            return Err(FrameError::PlaneLength {
                width,
                height,
                expected,
                got: data.len(),
            });
        }
        Ok(Plane { width, height, data })
    }

    /// All samples, row-major.
    pub fn data(&self) -> &[T] {
        &self.data
    }

    /// All samples, row-major, mutable. The length cannot change through this.
    pub fn data_mut(&mut self) -> &mut [T] {
        &mut self.data
    }

    /// The samples, giving up the plane.
    pub fn into_vec(self) -> Vec<T> {
        self.data
    }

    /// The sample at column `x`, row `y` (panics when out of bounds, like slice indexing).
    #[inline]
    pub fn get(&self, x: usize, y: usize) -> T {
        self.data[y * self.width + x]
    }

    /// The sample at `(x, y)` with coordinates clamped into the plane (edge extension).
    #[inline]
    pub fn get_clamped(&self, x: isize, y: isize) -> T {
        let x = x.clamp(0, self.width as isize - 1) as usize;
        let y = y.clamp(0, self.height as isize - 1) as usize;
        self.data[y * self.width + x]
    }

    /// Sets the sample at `(x, y)`.
    #[inline]
    pub fn set(&mut self, x: usize, y: usize, value: T) {
        self.data[y * self.width + x] = value;
    }

    /// Row `y`.
    pub fn row(&self, y: usize) -> &[T] {
        &self.data[y * self.width..(y + 1) * self.width]
    }

    /// A new plane of the same size with `f` applied to every sample.
    pub fn map<U: Copy>(&self, f: impl Fn(T) -> U) -> Plane<U> {
        Plane {
            width: self.width,
            height: self.height,
            data: self.data.iter().map(|&v| f(v)).collect(),
        }
    }
}

impl Plane<f32> {
    /// Number of samples that are NaN or infinite.
    pub fn count_non_finite(&self) -> u64 {
        count_non_finite(&self.data)
    }
}

/// Number of samples in `samples` that are NaN or infinite.
pub fn count_non_finite(samples: &[f32]) -> u64 {
    samples.iter().filter(|v| !v.is_finite()).count() as u64
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn from_vec_checks_length() {
        assert!(Plane::from_vec(3, 2, vec![0.0f32; 6]).is_ok());
        let err = Plane::from_vec(3, 2, vec![0.0f32; 5]).unwrap_err();
        assert_eq!(err.to_string(), "plane of 3x2 needs 6 samples, got 5");
    }

    #[test]
    fn indexing_is_row_major() {
        let p = Plane::from_fn(4, 3, |x, y| (10 * y + x) as u32);
        assert_eq!(p.get(3, 2), 23);
        assert_eq!(p.row(1), &[10, 11, 12, 13]);
        assert_eq!(p.get_clamped(-5, 7), 20);
    }
}
