//! `passthrough`: the input colour, repaired (non-finite and negative samples replaced).
//! The no-anti-aliasing baseline every other filter is measured against.
//!
//! The fast path is one pass: each band of rows is copied into reused output planes and
//! tested on the way ([`CleanMax::copy`]), one read and one write of the colour. A frame
//! with something to repair (rare) is then done again by [`reference()`](fn@reference), the plain path:
//! [`prepare`] counts and repairs, the repaired colour is the output.

use super::passes::slices_mut;
use crate::filter_params;
use crate::frame::{Frame, Rgb};
use crate::pipeline::clean::CleanMax;
use crate::pipeline::exec::par_bands;
use crate::pipeline::input::REPAIR_STAGE;
use crate::pipeline::{
    check_needs, prepare, Filter, FilterError, FilterKind, FilterState, InputCounts, Output, PixelCounts,
    Recorder, Scratch, Skip, StateError,
};
use serde_json::Value;

filter_params! {
    /// `passthrough` has no parameters.
    pub struct Params {}
}

/// The passthrough filter (no history; it keeps the planes handed back by
/// [`Filter::recycle`] to write the next output into).
#[derive(Debug, Default)]
pub struct Passthrough {
    scratch: Scratch,
}

impl FilterKind for Passthrough {
    const NAME: &'static str = "passthrough";
    const SUMMARY: &'static str = "the input colour, repaired: the no-AA baseline";
    const STAGES: &'static [&'static str] = &["repair", "copy"];
    type Params = Params;
    fn new(_: Params) -> Self {
        Passthrough::default()
    }
}

/// The scalar reference of the filter (the plain path, and the fast path's fallback for
/// frames with something to repair): [`prepare`] scans the colour, repairs it when needed
/// (recording `repair`), and the `copy` stage makes the output from it.
pub fn reference(frame: &Frame) -> Result<Output, FilterError> {
    check_needs(Passthrough::NAME, Passthrough::needs(), frame)?;
    let mut rec = Recorder::new();
    let inp = prepare(frame, Passthrough::uses(), &mut rec)?;
    let color = rec.run("copy", || inp.color.into_owned());
    Ok(Output {
        color,
        record: rec.finish(
            Passthrough::NAME,
            frame.meta.index,
            PixelCounts::default(),
            inp.counts,
            0,
        ),
    })
}

impl Filter for Passthrough {
    fn name(&self) -> &'static str {
        Self::NAME
    }

    fn params(&self) -> Value {
        Value::Object(crate::pipeline::params::to_json(&Params {}))
    }

    fn save_state(&self) -> Result<FilterState, StateError> {
        Ok(FilterState::empty(Self::NAME, self.params()))
    }

    fn load_state(&mut self, state: &FilterState) -> Result<(), StateError> {
        state.check_stateless(Self::NAME, &self.params())
    }

    fn process(&mut self, frame: &Frame) -> Result<Output, FilterError> {
        check_needs(Self::NAME, Self::needs(), frame)?;
        let mut rec = Recorder::new();
        let (w, h) = (frame.width(), frame.height());
        let src = frame.color().each_ref().map(|p| p.data());
        let mut color: Rgb = self.scratch.planes(w, h);
        let t = std::time::Instant::now();
        let seen: CleanMax = par_bands(slices_mut(&mut color), w, h, |_: &mut (), rows, band| {
            let span = rows.start * w..rows.end * w;
            let mut m = CleanMax::default();
            for (dst, src) in band.into_iter().zip(src) {
                m += CleanMax::copy(dst, &src[span.clone()]);
            }
            m
        });
        if seen.max().is_none() {
            // Something to repair: the plain path counts and repairs exactly (the copy
            // made here is thrown away).
            self.scratch.recycle(color);
            return reference(frame);
        }
        rec.skip(REPAIR_STAGE, Skip::CleanInput);
        rec.ran_for("copy", t.elapsed().as_secs_f64() * 1e3);
        Ok(Output {
            color,
            record: rec.finish(
                Self::NAME,
                frame.meta.index,
                PixelCounts::default(),
                InputCounts::default(),
                0,
            ),
        })
    }
    fn reset(&mut self) {}
    fn state_bytes(&self) -> usize {
        0
    }
    fn recycle(&mut self, planes: Rgb) {
        self.scratch.recycle(planes);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::frame::Plane;
    use crate::rng::SplitMix64;
    use crate::tolerance::Tolerance;

    /// Colour of `w` x `h` with samples from `sample(rng)`.
    fn frame(w: usize, h: usize, rng: &mut SplitMix64, sample: &dyn Fn(&mut SplitMix64) -> f32) -> Frame {
        Frame::new(std::array::from_fn(|_| Plane::from_fn(w, h, |_, _| sample(rng)))).unwrap()
    }

    /// Runs the filter and the reference on `frame` and compares colour and record.
    fn check(f: &mut Passthrough, frame: &Frame, what: &str) {
        let got = f.process(frame).unwrap();
        let want = reference(frame).unwrap();
        for (k, (g, r)) in got.color.iter().zip(&want.color).enumerate() {
            Tolerance::EXACT
                .check_slices(&format!("{what}, plane {k}"), g.data(), r.data())
                .unwrap();
        }
        assert_eq!(got.record.input, want.record.input, "{what}");
        let stages = |o: &Output| {
            o.record
                .stages
                .iter()
                .map(|s| (s.name, s.skipped.clone(), s.ms.is_some()))
                .collect::<Vec<_>>()
        };
        assert_eq!(stages(&got), stages(&want), "{what}");
        f.recycle(got.color);
    }

    #[test]
    fn fast_path_matches_the_reference_on_clean_and_dirty_frames() {
        let mut rng = SplitMix64::new(17);
        let sizes = [(1, 1), (1, 9), (9, 1), (7, 5), (1919, 3), (3, 40), (64, 33)];
        let specials = [f32::NAN, f32::INFINITY, f32::NEG_INFINITY, -1.0, -1e-30, -0.0];
        type Sample = Box<dyn Fn(&mut SplitMix64) -> f32>;
        let kinds: Vec<(&str, Sample)> = vec![
            ("ldr", Box::new(|r| r.next_f64() as f32)),
            (
                "hdr",
                Box::new(|r| (10f64.powf(r.next_f64() * 12.0 - 6.0)) as f32),
            ),
            ("zeros", Box::new(|_| 0.0)),
            (
                "negative zeros",
                Box::new(|r| if r.next_f64() < 0.5 { -0.0 } else { 0.25 }),
            ),
            (
                "max",
                Box::new(|r| if r.next_f64() < 0.5 { f32::MAX } else { 0.0 }),
            ),
            (
                "dirty",
                Box::new(move |r| {
                    if r.next_f64() < 0.1 {
                        specials[(r.next_f64() * 6.0) as usize % 6]
                    } else {
                        r.next_f64() as f32 * 3.0
                    }
                }),
            ),
        ];
        let mut f = Passthrough::default();
        for (w, h) in sizes {
            for (name, sample) in &kinds {
                let fr = frame(w, h, &mut rng, sample.as_ref());
                // Twice: the second time into planes handed back by `recycle`.
                check(&mut f, &fr, &format!("{name} {w}x{h}"));
                check(&mut f, &fr, &format!("{name} {w}x{h}, recycled planes"));
            }
        }
    }

    #[test]
    fn dirty_frames_are_repaired_and_counted_exactly() {
        let mut r = Plane::filled(5, 4, 0.5f32);
        r.set(1, 1, f32::NAN);
        r.set(4, 3, -2.0);
        let mut g = Plane::filled(5, 4, 0.5f32);
        g.set(0, 0, f32::INFINITY);
        g.set(2, 2, -0.0); // not negative: neither counted nor changed
        let frame = Frame::new([r, g, Plane::filled(5, 4, 0.5f32)]).unwrap();
        let out = Passthrough::default().process(&frame).unwrap();
        assert_eq!(
            out.record.input,
            InputCounts {
                non_finite: 2,
                negative: 1
            }
        );
        assert!(out.record.ran(REPAIR_STAGE) && out.record.ran("copy"));
        // NaN: the mean of its finite neighbours; negative: 0; infinite: the mean again.
        let exact =
            |what: &str, got: f32, want: f32| Tolerance::EXACT.check(what, got as f64, want as f64).unwrap();
        exact("NaN repaired", out.color[0].get(1, 1), 0.5);
        exact("negative repaired", out.color[0].get(4, 3), 0.0);
        exact("infinity repaired", out.color[1].get(0, 0), 0.5);
        assert_eq!(out.color[1].get(2, 2).to_bits(), (-0.0f32).to_bits());
        // A clean frame: `repair` left out and why, the colour copied bit for bit.
        let clean = Frame::new(std::array::from_fn(|k| Plane::filled(3, 2, k as f32 * 1e6))).unwrap();
        let out = Passthrough::default().process(&clean).unwrap();
        assert_eq!(
            out.record.stage(REPAIR_STAGE).unwrap().skipped,
            Some(Skip::CleanInput)
        );
        assert!(out.record.ran("copy"));
        exact("clean copy", out.color[2].get(2, 1), 2e6);
    }
}
