//! The `reconstruct` stage of the temporal filters: the current frame's colour replaced by
//! its reconstruction with the pixel filter the output is meant to converge to, at the
//! samples' true (jittered) positions ([`crate::kernels::reconstruct`]).
//!
//! With the jitter known (the file's `afterimage.jitter`, `--jitter-from`, or the
//! session's per-frame field) the 3x3 samples are weighted where they fell; with it
//! unknown (0 on both axes) they are weighted at the pixel centres, a fixed blur at least
//! as wide ([`Reconstruction::blind`]).
//! `box` leaves the colour as it is: each pixel's own sample, which converges to the box
//! integral over the pixel (what our procedural references are).
//!
//! Sparse shading (`upsample`) has no 3x3 of samples to weigh: there the stage runs on the
//! filter's full-resolution output instead, at the pixel centres ([`Reconstruction::sparse_output`]),
//! and the history keeps the unfiltered values, so a still image still converges.

use crate::frame::{ChannelSet, Frame, Rgb};
use crate::kernels::reconstruct::{blackman_harris, edge_taps, gaussian, reconstruct_row, taps};
use crate::pipeline::exec::par_rows;
use crate::pipeline::{prepare, FilterError, Inputs, Recorder, Scratch, Skip};
use serde::{Deserialize, Serialize};
use std::borrow::Cow;

/// The stage's name in every filter's records.
pub const STAGE: &str = "reconstruct";

/// The pixel filter of the image a temporal filter converges to.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum PixelFilter {
    /// Each pixel's own sample: the box integral over the pixel (no reconstruction).
    Box,
    /// Cycles' default, Blackman-Harris over `+-filter_width` pixels.
    BlackmanHarris,
    /// Cycles' Gaussian, standard deviation `filter_width / 4`.
    Gaussian,
}

/// The options a `pixel_filter` parameter offers, in [`PixelFilter`]'s order.
pub const PIXEL_FILTERS: &[&str] = &["box", "blackman_harris", "gaussian"];

/// Cycles' default pixel filter width, 1.5 px (Blender's Film panel; Blackman-Harris then
/// reaches 1.5 px from the sample).
pub const DEFAULT_FILTER_WIDTH: f32 = 1.5;

/// How a frame is reconstructed: a filter and its width.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Reconstruction {
    /// The pixel filter.
    pub filter: PixelFilter,
    /// Its width in pixels (Cycles' convention).
    pub width: f32,
}

impl Reconstruction {
    /// No reconstruction (each pixel's own sample).
    pub const NONE: Reconstruction = Reconstruction {
        filter: PixelFilter::Box,
        width: DEFAULT_FILTER_WIDTH,
    };

    /// A filter and its width (a filter's `pixel_filter` and `filter_width` parameters).
    pub const fn new(filter: PixelFilter, width: f32) -> Reconstruction {
        Reconstruction { filter, width }
    }

    /// The weight of a sample `v` pixels from the pixel centre along one axis.
    fn weight(&self, v: f32) -> f32 {
        match self.filter {
            PixelFilter::Box => (v.abs() < 0.5) as u8 as f32,
            PixelFilter::BlackmanHarris => blackman_harris(v, self.width),
            PixelFilter::Gaussian => gaussian(v, self.width),
        }
    }

    /// The reconstruction of a frame whose jitter is unknown: at the pixel centres, with the
    /// width at which the centred taps average as much of the samples' noise (the same sum
    /// of squared weights, per axis) as this filter's taps do on average over uniformly
    /// jittered positions, never narrower. Blackman-Harris 1.5 px gives 1.73 px; from about
    /// 2.3 px (2.7 for the Gaussian) the centred taps already average as much and the width
    /// stays; a narrow filter widens most (Blackman-Harris 0.6 px to 1.23: its jittered taps
    /// split a sample between two pixels, its centred ones keep it whole). At 1.5 px the
    /// centred taps are nearly the pixel's own sample (Blackman-Harris weighs a neighbour
    /// a pixel away at 0.06 of the centre), so a blind frame would average less than a
    /// jittered one, and its aliasing and noise pass through. On the Blender corpus with
    /// the jitter unknown (docs/corpus.md, "The width when the jitter is unknown") this
    /// width gains `taa` +0.23 dB, `phlm` +0.51, `traa` +0.87 and `upsample` +1.04 on
    /// the mean over the same width as the jittered taps.
    pub fn blind(&self) -> Reconstruction {
        if self.filter == PixelFilter::Box {
            return *self;
        }
        let at = |width: f32| Reconstruction { width, ..*self };
        let gain = |t: [f32; 3]| t.iter().map(|w| w * w).sum::<f32>();
        const PHASES: usize = 64;
        let target = (0..PHASES)
            .map(|k| gain(taps((k as f32 + 0.5) / PHASES as f32 - 0.5, |v| self.weight(v))))
            .sum::<f32>()
            / PHASES as f32;
        // The centred taps' gain falls as the width grows (their neighbours weigh more).
        let (mut lo, mut hi) = (self.width, 4.0 * self.width);
        for _ in 0..40 {
            let mid = 0.5 * (lo + hi);
            if gain(taps(0.0, |v| at(mid).weight(v))) > target {
                lo = mid;
            } else {
                hi = mid;
            }
        }
        at(0.5 * (lo + hi))
    }

    /// Why the stage is left out, if it is.
    fn skip(&self) -> Option<Skip> {
        (self.filter == PixelFilter::Box).then_some(Skip::Disabled {
            param: "pixel_filter",
        })
    }

    /// `rgb`, jittered by `jitter` (pixels, x right, y down), reconstructed with this
    /// filter into planes from `scratch`, and the reconstruction's largest sample (at least
    /// 0), taken while each row is in cache.
    pub fn apply(&self, rgb: &Rgb, jitter: [f32; 2], scratch: &mut Scratch) -> (Rgb, f32) {
        let (w, h) = rgb[0].size();
        let wx = taps(jitter[0], |v| self.weight(v));
        let wy = taps(jitter[1], |v| self.weight(v));
        let mut out: Rgb = scratch.planes(w, h);
        let src = rgb.each_ref().map(|p| p.data());
        // One pass over the three planes, a row of each per task.
        let largest: Largest = par_rows(out.each_mut().map(|p| p.data_mut()), w, |y, rows| {
            let (up, down) = (y.saturating_sub(1), (y + 1).min(h - 1));
            let wy = edge_taps(wy, y, h);
            let mut tmp = vec![0.0; w];
            let mut m = Largest::default();
            for (src, row) in src.iter().zip(rows) {
                let line = |k: usize| &src[k * w..(k + 1) * w];
                reconstruct_row([line(up), line(y), line(down)], wy, wx, &mut tmp, row);
                m.0 = row.iter().fold(m.0, |m, &v| m.max(v));
            }
            m
        });
        (out, largest.0)
    }

    /// The frame's inputs as every temporal filter starts from them: the channels it `uses`
    /// repaired and planned (stage `repair`), then this stage.
    pub fn prepare<'a>(
        &self,
        frame: &'a Frame,
        uses: ChannelSet,
        rec: &mut Recorder,
        scratch: &mut Scratch,
    ) -> Result<Inputs<'a>, FilterError> {
        let mut inp = prepare(frame, uses, rec)?;
        self.stage(rec, &mut inp, frame.meta.jitter, scratch);
        Ok(inp)
    }

    /// The `reconstruct` stage: replaces `inp.color` by its reconstruction (or records why
    /// it is left out). Every temporal filter runs it right after `repair`, the CPU's
    /// reference and fused kernels and the GPU backend alike, so they see the same colour.
    /// A jitter of 0 on both axes is a renderer that did not say where it sampled: the
    /// frame is reconstructed [`Self::blind`].
    pub fn stage(&self, rec: &mut Recorder, inp: &mut Inputs, jitter: [f32; 2], scratch: &mut Scratch) {
        if inp.color[0].size() != (inp.width, inp.height) {
            // Sparse shading: the stage runs on the output ([`Self::sparse_output`]).
            return;
        }
        let recon = if jitter == [0.0, 0.0] { self.blind() } else { *self };
        if let Some((rgb, largest)) =
            rec.stage(STAGE, self.skip(), || recon.apply(&inp.color, jitter, scratch))
        {
            // The filter's input is now the reconstruction: its largest sample bounds the
            // output (`passes::output_ceiling`), as for a frame given reconstructed.
            inp.facts.max_color = largest;
            if let Cow::Owned(old) = std::mem::replace(&mut inp.color, Cow::Owned(rgb)) {
                scratch.recycle(old);
            }
        }
    }
}

impl Reconstruction {
    /// The stage for a frame shaded sparsely (`sparse`): the filter's full-resolution
    /// output `color` filtered at the pixel centres, in place (or the record of why not).
    /// Every temporal filter's frame ends with it ([`super::passes::TemporalState::run`],
    /// and `upsample`'s reference); a fully shaded frame was reconstructed on its input.
    pub fn sparse_output(&self, rec: &mut Recorder, color: &mut Rgb, sparse: bool, scratch: &mut Scratch) {
        if !sparse {
            return;
        }
        if let Some((rgb, _)) = rec.stage(STAGE, self.skip(), || self.apply(color, [0.0, 0.0], scratch)) {
            let old = std::mem::replace(color, rgb);
            scratch.recycle(old);
        }
    }
}

/// The largest of the samples added into it (`+=` keeps the maximum): a row's largest
/// sample, reduced over the rows by [`par_rows`].
#[derive(Clone, Copy, Default)]
struct Largest(f32);

impl std::ops::AddAssign for Largest {
    fn add_assign(&mut self, other: Largest) {
        self.0 = self.0.max(other.0);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::frame::{ChannelKind, ChannelSet};
    use crate::frame::{Frame, Plane};
    use crate::pipeline::prepare;
    use crate::tolerance::Tolerance;

    fn frame(w: usize, h: usize) -> Frame {
        let rgb: Rgb = std::array::from_fn(|c| {
            Plane::from_vec(
                w,
                h,
                (0..w * h).map(|i| ((i * 7 + c * 3) % 11) as f32 / 10.0).collect(),
            )
            .unwrap()
        });
        Frame::new(rgb).unwrap()
    }

    #[test]
    fn box_leaves_the_colour_alone_and_says_so() {
        let f = frame(9, 5);
        let mut rec = Recorder::new();
        let mut inp = prepare(&f, ChannelSet::of(&[ChannelKind::Color]), &mut rec).unwrap();
        Reconstruction::NONE.stage(&mut rec, &mut inp, [0.3, 0.1], &mut Scratch::default());
        assert!(matches!(inp.color, Cow::Borrowed(_)));
        let r = rec.finish("test", 0, Default::default(), Default::default(), 0);
        assert_eq!(
            r.stage(STAGE).unwrap().skipped,
            Some(Skip::Disabled {
                param: "pixel_filter"
            })
        );
    }

    #[test]
    fn blackman_harris_moves_each_pixel_toward_its_neighbours_by_the_jitter() {
        let f = frame(9, 5);
        let bh = Reconstruction {
            filter: PixelFilter::BlackmanHarris,
            width: DEFAULT_FILTER_WIDTH,
        };
        let mut rec = Recorder::new();
        let mut inp = prepare(&f, ChannelSet::of(&[ChannelKind::Color]), &mut rec).unwrap();
        bh.stage(&mut rec, &mut inp, [0.5, 0.0], &mut Scratch::default());
        assert!(matches!(inp.color, Cow::Owned(_)));
        // Jitter +0.5 in x: the left neighbour's sample sits as far away as the pixel's own
        // (0.5 px each way), so with a uniform column the two weigh the same.
        let (l, c, r) = (
            f.color()[0].data()[9 + 3],
            f.color()[0].data()[9 + 4],
            f.color()[0].data()[9 + 5],
        );
        let wx = taps(0.5, |v| blackman_harris(v, 1.5));
        assert!(Tolerance::abs(1e-6).eq(wx[0] as f64, wx[1] as f64));
        let wy = taps(0.0, |v| blackman_harris(v, 1.5));
        let col = |x: usize| {
            let d = f.color()[0].data();
            (wy[0] * d[x] + wy[1] * d[9 + x] + wy[2] * d[18 + x]) as f64
        };
        let want = wx[0] as f64 * col(3) + wx[1] as f64 * col(4) + wx[2] as f64 * col(5);
        assert!(
            Tolerance::abs(1e-6).eq(inp.color[0].data()[9 + 4] as f64, want),
            "{l} {c} {r}"
        );
    }

    /// The sum of squared weights of 3x3 taps, per axis, for jitter `j`.
    fn gain(r: Reconstruction, j: f32) -> f64 {
        taps(j, |v| r.weight(v)).iter().map(|&w| (w as f64).powi(2)).sum()
    }

    #[test]
    fn the_blind_width_averages_as_much_as_the_jittered_taps() {
        // Widths solved independently (numpy, bisection on the same filters).
        for (filter, want) in [
            (PixelFilter::BlackmanHarris, 1.7303),
            (PixelFilter::Gaussian, 1.8369),
        ] {
            let r = Reconstruction::new(filter, DEFAULT_FILTER_WIDTH);
            let b = r.blind();
            assert_eq!(b.filter, filter);
            Tolerance::abs(2e-3)
                .check(&format!("{filter:?} blind width"), b.width as f64, want)
                .unwrap();
            // The jittered taps' mean gain over a fine grid of phases.
            let n = 10_000;
            let mean = (0..n)
                .map(|k| gain(r, (k as f32 + 0.5) / n as f32 - 0.5))
                .sum::<f64>()
                / n as f64;
            Tolerance::abs(1e-4)
                .check(&format!("{filter:?} gain"), gain(b, 0.0), mean)
                .unwrap();
            assert!(
                gain(r, 0.0) > mean + 0.1,
                "{filter:?}: centred taps at the set width average less"
            );
        }
        assert_eq!(Reconstruction::NONE.blind(), Reconstruction::NONE);
        // Never narrower; the parameter's bounds and a narrow filter (numpy as above).
        for (width, want) in [(0.6, 1.2277), (1.0, 1.4417), (2.5, 2.5), (4.0, 4.0)] {
            let b = Reconstruction::new(PixelFilter::BlackmanHarris, width).blind();
            Tolerance::abs(2e-3)
                .check(&format!("blind width of {width}"), b.width as f64, want)
                .unwrap();
            assert!(b.width >= width, "{width}: {}", b.width);
        }
    }

    #[test]
    fn a_frame_without_jitter_is_reconstructed_blind() {
        let f = frame(9, 5);
        let bh = Reconstruction::new(PixelFilter::BlackmanHarris, DEFAULT_FILTER_WIDTH);
        let staged = |jitter: [f32; 2]| {
            let mut rec = Recorder::new();
            let mut inp = prepare(&f, ChannelSet::of(&[ChannelKind::Color]), &mut rec).unwrap();
            bh.stage(&mut rec, &mut inp, jitter, &mut Scratch::default());
            inp.color.into_owned()
        };
        let mut scratch = Scratch::default();
        for (jitter, want) in [
            (
                [0.0, 0.0],
                bh.blind().apply(f.color(), [0.0, 0.0], &mut scratch).0,
            ),
            // One axis at 0 is a jitter like any other (Halton's first x, say).
            ([0.0, 0.25], bh.apply(f.color(), [0.0, 0.25], &mut scratch).0),
        ] {
            let got = staged(jitter);
            for c in 0..3 {
                assert_eq!(got[c].data(), want[c].data(), "jitter {jitter:?} channel {c}");
            }
        }
        let sharp = bh.apply(f.color(), [0.0, 0.0], &mut scratch).0;
        assert_ne!(staged([0.0, 0.0])[0].data(), sharp[0].data());
    }
}
