//! A vectorised test that colour needs no repair, for filters that read only colour: one
//! read of the planes (or a copy that tests on the way) instead of [`super::prepare`]'s
//! scan. It decides only clean or not; when not, the caller runs [`super::prepare`], which
//! counts and repairs exactly.
//!
//! Each sample maps to a key, its bits with -0.0 taken as +0.0: keys of finite
//! non-negative samples are below [`DIRTY_KEY`] and ordered as the samples are; NaN, the
//! infinities and negative samples (what [`super::prepare`] repairs) have keys at or above
//! it. The largest key of a frame then says at once whether it is clean and, if it is, its
//! largest sample (`FrameFacts::max_color`).

use super::exec::pool;
use crate::frame::Rgb;
use rayon::prelude::*;
use std::ops::AddAssign;

/// Keys of samples that need repair are at or above this (the bits of +infinity).
pub const DIRTY_KEY: u32 = 0x7f80_0000;

/// Samples per task of [`color_max`].
const CHUNK: usize = 1 << 16;

/// The key of a sample (see the module documentation).
#[inline(always)]
pub fn clean_key(v: f32) -> u32 {
    let b = v.to_bits();
    if b == 0x8000_0000 {
        0
    } else {
        b
    }
}

/// The largest key seen; `+=` keeps the larger, so results of bands or chunks combine with
/// [`super::exec::par_bands`] and rayon's `reduce`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct CleanMax(pub u32);

impl AddAssign for CleanMax {
    fn add_assign(&mut self, o: CleanMax) {
        self.0 = self.0.max(o.0);
    }
}

impl CleanMax {
    /// The largest key of `src`.
    pub fn of(src: &[f32]) -> CleanMax {
        let mut m = 0;
        for &v in src {
            m = m.max(clean_key(v));
        }
        CleanMax(m)
    }

    /// Copies `src` into `dst` (same length) and returns the largest key of `src`.
    pub fn copy(dst: &mut [f32], src: &[f32]) -> CleanMax {
        assert_eq!(dst.len(), src.len(), "copy between slices of one length");
        let mut m = 0;
        for (d, &s) in dst.iter_mut().zip(src) {
            *d = s;
            m = m.max(clean_key(s));
        }
        CleanMax(m)
    }

    /// The largest sample (0 for none) when every sample was finite and non-negative, else
    /// `None`.
    pub fn max(self) -> Option<f32> {
        (self.0 < DIRTY_KEY).then(|| f32::from_bits(self.0))
    }
}

/// The largest key of the colour planes, read in parallel on the crate's pool.
pub fn color_max(color: &Rgb) -> CleanMax {
    pool().install(|| {
        color
            .par_iter()
            .flat_map(|p| p.data().par_chunks(CHUNK))
            .map(CleanMax::of)
            .reduce(CleanMax::default, |mut a, b| {
                a += b;
                a
            })
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::frame::{ChannelKind, ChannelSet, Frame, Plane};
    use crate::pipeline::{prepare, Recorder};
    use crate::rng::SplitMix64;
    use crate::tolerance::Tolerance;

    /// What `prepare` says of the same colour: clean or not, and its largest sample.
    fn prepared(color: &Rgb) -> (bool, f32) {
        let frame = Frame::new(color.clone()).unwrap();
        let inp = prepare(
            &frame,
            ChannelSet::of(&[ChannelKind::Color]),
            &mut Recorder::new(),
        )
        .unwrap();
        (
            inp.counts.non_finite + inp.counts.negative == 0,
            inp.facts.max_color,
        )
    }

    #[test]
    fn keys_agree_with_prepare_on_every_kind_of_sample() {
        let special = [
            0.0,
            -0.0,
            f32::MIN_POSITIVE,
            1e-45,
            -1e-45,
            1.0,
            1e6,
            f32::MAX,
            -f32::MAX,
            -1.0,
            f32::INFINITY,
            f32::NEG_INFINITY,
            f32::NAN,
            -f32::NAN,
            f32::from_bits(0x7f80_0001),
            f32::from_bits(0xffc0_0000),
        ];
        let mut rng = SplitMix64::new(5);
        for case in 0..400 {
            let (w, h) = (1 + case % 7, 1 + case % 5);
            let color: Rgb = std::array::from_fn(|_| {
                Plane::from_fn(w, h, |_, _| {
                    // Mostly ordinary samples, some special ones.
                    if rng.next_f64() < 0.05 {
                        special[(rng.next_f64() * special.len() as f64) as usize % special.len()]
                    } else {
                        (rng.next_f64() * 4.0) as f32
                    }
                })
            });
            let (clean, max) = prepared(&color);
            let m = color_max(&color);
            assert_eq!(m.max().is_some(), clean, "case {case}: {color:?}");
            if clean {
                Tolerance::EXACT
                    .check(
                        &format!("case {case}: largest sample"),
                        m.max().unwrap() as f64,
                        max as f64,
                    )
                    .unwrap();
            }
            // The copy tests the same and copies every bit.
            let mut dst: Rgb = std::array::from_fn(|_| Plane::filled(w, h, 7.0f32));
            let mut c = CleanMax::default();
            for (d, s) in dst.iter_mut().zip(&color) {
                c += CleanMax::copy(d.data_mut(), s.data());
            }
            assert_eq!(c, m, "case {case}");
            for (d, s) in dst.iter().zip(&color) {
                let bits = |p: &Plane<f32>| p.data().iter().map(|v| v.to_bits()).collect::<Vec<_>>();
                assert_eq!(bits(d), bits(s), "case {case}");
            }
        }
    }

    #[test]
    fn one_bad_sample_anywhere_in_a_large_plane_is_found() {
        let (w, h) = (300, 700); // more than one chunk per plane
        for (k, bad) in [f32::NAN, f32::INFINITY, -1e-30, f32::NEG_INFINITY]
            .into_iter()
            .enumerate()
        {
            let mut color: Rgb = std::array::from_fn(|_| Plane::filled(w, h, 0.5f32));
            let clean = color_max(&color).max().expect("a clean plane");
            Tolerance::EXACT
                .check("largest sample", clean as f64, 0.5)
                .unwrap();
            let i = (k * 7919 + 123_457) % (w * h);
            color[k % 3].data_mut()[i] = bad;
            assert_eq!(color_max(&color).max(), None, "{bad} at {i}");
            let mut dst = vec![0.0f32; w * h];
            assert_eq!(CleanMax::copy(&mut dst, color[k % 3].data()).max(), None);
        }
    }
}
