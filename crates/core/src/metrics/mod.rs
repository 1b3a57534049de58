//! Quality metrics: MSE, RMSE, PSNR, SSIM (with a map) and the temporal error tRMSE, all
//! computed in a stated space (see [`MetricSpace`]); and the summary of measured times
//! ([`Timing`]).

mod ssim;
mod timing;

pub use ssim::{ssim, SsimResult, SSIM_C1_K, SSIM_C2_K, SSIM_RADIUS, SSIM_SIGMA};
pub use timing::{process_cpu_ms, quantile, Timing};

use crate::frame::{Plane, Rgb};
use serde::{Deserialize, Serialize};
use thiserror::Error;

/// Errors of the metrics: the caller passed images that cannot be compared.
#[derive(Debug, Error, Clone, PartialEq)]
pub enum MetricsError {
    /// Two images differ in size.
    #[error("{what}: {got_w}x{got_h} does not match {w}x{h}")]
    SizeMismatch {
        /// Which images.
        what: &'static str,
        /// Size of the first.
        w: usize,
        /// Height of the first.
        h: usize,
        /// Width of the second.
        got_w: usize,
        /// Height of the second.
        got_h: usize,
    },
}

/// `Ok` when the planes `a` and `b` have the same size.
pub fn check_same_size<T, U>(what: &'static str, a: &Plane<T>, b: &Plane<U>) -> Result<(), MetricsError> {
    let ((w, h), (got_w, got_h)) = (a.size(), b.size());
    if (w, h) == (got_w, got_h) {
        Ok(())
    } else {
        Err(MetricsError::SizeMismatch {
            what,
            w,
            h,
            got_w,
            got_h,
        })
    }
}

/// Rec. ITU-R BT.709 luma weights for linear RGB.
pub const REC709_LUMA: [f64; 3] = [0.2126, 0.7152, 0.0722];

/// The space metrics are computed in.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum MetricSpace {
    /// Linear values clamped to [0, 1]: for LDR content.
    Linear,
    /// Linear values mapped by `c / (1 + c)` (negatives clamped to 0): for HDR content,
    /// so one bright pixel does not dominate.
    Tonemapped,
}

/// The space asked for: a fixed one, or chosen by content.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum SpaceChoice {
    /// Tonemapped when any finite reference sample exceeds 1, else linear.
    #[default]
    Auto,
    /// Always [`MetricSpace::Linear`].
    Linear,
    /// Always [`MetricSpace::Tonemapped`].
    Tonemapped,
}

impl SpaceChoice {
    /// The space for content whose reference is `reference`.
    pub fn resolve(self, reference: &Rgb) -> MetricSpace {
        match self {
            SpaceChoice::Linear => MetricSpace::Linear,
            SpaceChoice::Tonemapped => MetricSpace::Tonemapped,
            SpaceChoice::Auto => {
                let hdr = reference
                    .iter()
                    .any(|p| p.data().iter().any(|&v| v.is_finite() && v > 1.0));
                if hdr {
                    MetricSpace::Tonemapped
                } else {
                    MetricSpace::Linear
                }
            }
        }
    }
}

impl MetricSpace {
    /// Maps one linear sample into this space (NaN stays NaN so that it shows in the
    /// figures instead of being hidden).
    #[inline]
    pub fn apply(self, v: f32) -> f64 {
        let v = v as f64;
        match self {
            MetricSpace::Linear => v.clamp(0.0, 1.0),
            MetricSpace::Tonemapped => {
                let v = v.max(0.0);
                if v.is_infinite() {
                    1.0
                } else {
                    v / (1.0 + v)
                }
            }
        }
    }
}

/// Mean squared error over all three channels, in `space`.
pub fn mse(a: &Rgb, b: &Rgb, space: MetricSpace) -> Result<f64, MetricsError> {
    check_same_size("mse", &a[0], &b[0])?;
    let n = a[0].data().len() * 3;
    let mut sum = 0.0f64;
    for c in 0..3 {
        for (&x, &y) in a[c].data().iter().zip(b[c].data()) {
            let d = space.apply(x) - space.apply(y);
            sum += d * d;
        }
    }
    Ok(sum / n as f64)
}

/// PSNR in dB for a peak of 1 (infinite when `mse` is 0).
pub fn psnr_from_mse(mse: f64) -> f64 {
    10.0 * (1.0 / mse).log10()
}

/// Rec.709 luma of `rgb` after mapping each channel into `space`, in f64.
pub fn luma(rgb: &Rgb, space: MetricSpace) -> Plane<f64> {
    let (w, h) = rgb[0].size();
    let [r, g, b] = rgb;
    let data = r
        .data()
        .iter()
        .zip(g.data())
        .zip(b.data())
        .map(|((&r, &g), &b)| {
            REC709_LUMA[0] * space.apply(r)
                + REC709_LUMA[1] * space.apply(g)
                + REC709_LUMA[2] * space.apply(b)
        })
        .collect();
    Plane::from_vec(w, h, data).expect("same size as the input")
}

/// Mean squared difference of the frame-to-frame changes of output and reference, in
/// `space`: `mean over pixels and channels of ((out_t - out_{t-1}) - (ref_t - ref_{t-1}))^2`.
/// Charges flicker (output changes the reference does not) and lag or ghosting (changes
/// the output misses) alike. tRMSE is the square root of its mean over frames.
pub fn temporal_mse(
    out: &Rgb,
    out_prev: &Rgb,
    reference: &Rgb,
    ref_prev: &Rgb,
    space: MetricSpace,
) -> Result<f64, MetricsError> {
    check_same_size("temporal error, previous output", &out[0], &out_prev[0])?;
    check_same_size("temporal error, reference", &out[0], &reference[0])?;
    check_same_size("temporal error, previous reference", &out[0], &ref_prev[0])?;
    let n = out[0].data().len() * 3;
    let mut sum = 0.0f64;
    for c in 0..3 {
        let it = out[c]
            .data()
            .iter()
            .zip(out_prev[c].data())
            .zip(reference[c].data().iter().zip(ref_prev[c].data()));
        for ((&o, &op), (&r, &rp)) in it {
            let d = (space.apply(o) - space.apply(op)) - (space.apply(r) - space.apply(rp));
            sum += d * d;
        }
    }
    Ok(sum / n as f64)
}

/// Figures of one frame.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct FrameMetrics {
    /// Frame number.
    pub index: u64,
    /// Mean squared error over RGB.
    pub mse: f64,
    /// Root of `mse`.
    pub rmse: f64,
    /// PSNR in dB (peak 1).
    pub psnr: f64,
    /// Mean SSIM on luma.
    pub ssim: f64,
    /// Temporal MSE against the previous frame (None for the first frame of a sequence or
    /// after a reset).
    pub temporal_mse: Option<f64>,
}

/// Summary over a sequence.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Summary {
    /// Frames measured.
    pub frames: usize,
    /// The space used.
    pub space: MetricSpace,
    /// Mean of per-frame PSNR.
    pub mean_psnr: f64,
    /// PSNR of the mean MSE over all frames.
    pub psnr_of_mean_mse: f64,
    /// Mean of per-frame SSIM.
    pub mean_ssim: f64,
    /// Mean of per-frame MSE.
    pub mean_mse: f64,
    /// Root of the mean temporal MSE over the frame pairs that have one (None when no pair).
    pub trmse: Option<f64>,
}

/// Accumulates per-frame metrics over a sequence of (output, reference) pairs.
#[derive(Debug)]
pub struct Evaluator {
    choice: SpaceChoice,
    space: Option<MetricSpace>,
    prev: Option<(Rgb, Rgb)>,
    /// Per-frame figures so far.
    pub frames: Vec<FrameMetrics>,
}

impl Evaluator {
    /// A new evaluator; with [`SpaceChoice::Auto`] the space is fixed by the first frame's
    /// reference, so that every frame of a sequence is measured alike.
    pub fn new(choice: SpaceChoice) -> Self {
        Evaluator {
            choice,
            space: None,
            prev: None,
            frames: Vec::new(),
        }
    }

    /// The space in use (None before the first frame).
    pub fn space(&self) -> Option<MetricSpace> {
        self.space
    }

    /// The last frame's output and reference, which the next frame's temporal error is
    /// measured against (None before the first frame and after a cut's reset).
    pub fn last_pair(&self) -> Option<&(Rgb, Rgb)> {
        self.prev.as_ref()
    }

    /// An evaluator that continues one stopped after `frames`, in `space`, with the last
    /// output and reference `last_pair` ([`Self::space`], [`Self::last_pair`] and
    /// [`Self::frames`] of the stopped one): what it measures next is what the stopped one
    /// would have measured.
    pub fn resumed(
        choice: SpaceChoice,
        space: Option<MetricSpace>,
        last_pair: Option<(Rgb, Rgb)>,
        frames: Vec<FrameMetrics>,
    ) -> Self {
        Evaluator {
            choice,
            space,
            prev: last_pair,
            frames,
        }
    }

    /// Measures one frame. `reset` drops the temporal pair (a camera cut), and so does a
    /// change of size. Images of different sizes are an error that changes nothing.
    pub fn push(
        &mut self,
        index: u64,
        out: &Rgb,
        reference: &Rgb,
        reset: bool,
    ) -> Result<&FrameMetrics, MetricsError> {
        check_same_size("output vs reference", &reference[0], &out[0])?;
        let space = *self.space.get_or_insert_with(|| self.choice.resolve(reference));
        let m = mse(out, reference, space)?;
        let s = ssim(&luma(out, space), &luma(reference, space), false)?.mean;
        let t = match (&self.prev, reset) {
            (Some((op, rp)), false) if op[0].size() == out[0].size() => {
                Some(temporal_mse(out, op, reference, rp, space)?)
            }
            _ => None,
        };
        self.prev = Some((out.clone(), reference.clone()));
        self.frames.push(FrameMetrics {
            index,
            mse: m,
            rmse: m.sqrt(),
            psnr: psnr_from_mse(m),
            ssim: s,
            temporal_mse: t,
        });
        Ok(self.frames.last().expect("just pushed"))
    }

    /// The summary so far (None before the first frame).
    pub fn summary(&self) -> Option<Summary> {
        let space = self.space?;
        let n = self.frames.len() as f64;
        let mean = |f: fn(&FrameMetrics) -> f64| self.frames.iter().map(f).sum::<f64>() / n;
        let temporal: Vec<f64> = self.frames.iter().filter_map(|f| f.temporal_mse).collect();
        let mean_mse = mean(|f| f.mse);
        Some(Summary {
            frames: self.frames.len(),
            space,
            mean_psnr: mean(|f| f.psnr),
            psnr_of_mean_mse: psnr_from_mse(mean_mse),
            mean_ssim: mean(|f| f.ssim),
            mean_mse,
            trmse: (!temporal.is_empty())
                .then(|| (temporal.iter().sum::<f64>() / temporal.len() as f64).sqrt()),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::tolerance::Tolerance;

    fn rgb(w: usize, h: usize, f: impl Fn(usize, usize, usize) -> f32) -> Rgb {
        [0, 1, 2].map(|c| Plane::from_fn(w, h, |x, y| f(x, y, c)))
    }

    #[test]
    fn mse_and_psnr_of_a_known_offset() {
        let a = rgb(8, 4, |_, _, _| 0.5);
        let b = rgb(8, 4, |_, _, _| 0.6);
        let m = mse(&a, &b, MetricSpace::Linear).unwrap();
        Tolerance::rel(1e-6).check("mse", m, 0.01).unwrap();
        Tolerance::rel(1e-6)
            .check("psnr", psnr_from_mse(m), 20.0)
            .unwrap();
        assert!(psnr_from_mse(0.0).is_infinite());
    }

    #[test]
    fn auto_space_follows_the_reference() {
        let ldr = rgb(4, 4, |_, _, _| 0.9);
        let hdr = rgb(4, 4, |x, _, _| if x == 0 { 40.0 } else { 0.1 });
        assert_eq!(SpaceChoice::Auto.resolve(&ldr), MetricSpace::Linear);
        assert_eq!(SpaceChoice::Auto.resolve(&hdr), MetricSpace::Tonemapped);
        Tolerance::EXACT
            .check("tonemap", MetricSpace::Tonemapped.apply(3.0), 0.75)
            .unwrap();
        assert_eq!(MetricSpace::Linear.apply(7.0), 1.0);
        assert_eq!(MetricSpace::Tonemapped.apply(f32::INFINITY), 1.0);
        assert!(MetricSpace::Linear.apply(f32::NAN).is_nan());
    }

    #[test]
    fn temporal_error_charges_flicker_and_lag_but_not_shared_change() {
        let a = rgb(4, 4, |_, _, _| 0.2);
        let b = rgb(4, 4, |_, _, _| 0.4);
        let s = MetricSpace::Linear;
        // Output follows the reference exactly: no temporal error, even with an offset.
        let a_off = rgb(4, 4, |_, _, _| 0.25);
        let b_off = rgb(4, 4, |_, _, _| 0.45);
        assert!(Tolerance::abs(1e-12).eq(temporal_mse(&b_off, &a_off, &b, &a, s).unwrap(), 0.0));
        // Output lags (does not change): charged the whole change (0.2 in f32).
        Tolerance::rel(1e-6)
            .check("lag", temporal_mse(&a, &a, &b, &a, s).unwrap(), 0.04)
            .unwrap();
        // Output flickers on a still reference: charged too.
        Tolerance::rel(1e-6)
            .check("flicker", temporal_mse(&b, &a, &a, &a, s).unwrap(), 0.04)
            .unwrap();
    }

    #[test]
    fn evaluator_summarises_and_resets() {
        let r = rgb(12, 12, |x, y, c| ((x * 3 + y * 5 + c) % 7) as f32 / 7.0);
        let o = rgb(12, 12, |x, y, c| ((x * 3 + y * 5 + c) % 7) as f32 / 7.0 + 0.05);
        let mut e = Evaluator::new(SpaceChoice::Auto);
        e.push(1, &o, &r, false).unwrap();
        e.push(2, &o, &r, false).unwrap();
        e.push(3, &o, &r, true).unwrap();
        // A wrong size is refused and changes nothing.
        let small = rgb(4, 4, |_, _, _| 0.5);
        let err = e.push(4, &small, &r, false).unwrap_err();
        assert_eq!(err.to_string(), "output vs reference: 4x4 does not match 12x12");
        assert_eq!(e.frames.len(), 3);
        assert_eq!(e.frames[0].temporal_mse, None);
        assert!(e.frames[1].temporal_mse.is_some());
        assert_eq!(e.frames[2].temporal_mse, None);
        let s = e.summary().unwrap();
        assert_eq!(s.frames, 3);
        assert_eq!(s.space, MetricSpace::Linear);
        Tolerance::abs(1e-9)
            .check("trmse", s.trmse.unwrap(), 0.0)
            .unwrap();
        assert!(s.mean_ssim < 1.0 && s.mean_ssim > 0.5);
    }
}
