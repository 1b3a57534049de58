//! A frame's channels made safe for a filter, and the facts the planner decides on.
//!
//! Non-finite samples (NaN, +-Inf) in any channel a filter reads are replaced by the mean
//! of the finite samples of their 3x3 neighbourhood (0 when there are none), and negative
//! colour is set to 0, so nothing unusable can reach a filter's history or output. Both are
//! counted in the record. Clean channels are borrowed, not copied.

use super::planner::FrameFacts;
use super::record::{InputCounts, Recorder, Skip};
use super::FilterError;
use crate::frame::{ChannelKind, ChannelSet, DepthKind, Frame, Plane, Rgb};
use std::borrow::Cow;

/// Name of the repair stage in every filter's record.
pub const REPAIR_STAGE: &str = "repair";

/// The channels a filter reads, repaired, with the planner's facts.
#[derive(Debug)]
pub struct Inputs<'a> {
    /// Width in pixels.
    pub width: usize,
    /// Height in pixels.
    pub height: usize,
    /// Colour, finite and non-negative, at its own size (the frame's unless the frame is
    /// shaded sparsely, see [`crate::frame::Sampling`]).
    pub color: Cow<'a, Rgb>,
    /// Linear depth, finite (when the frame has depth and the filter uses it).
    pub depth: Option<Cow<'a, Plane<f32>>>,
    /// Motion to the previous frame in pixels, finite.
    pub motion: Option<Cow<'a, [Plane<f32>; 2]>>,
    /// Albedo, finite and non-negative.
    pub albedo: Option<Cow<'a, Rgb>>,
    /// Normals, finite (when the frame has them and the filter uses them).
    pub normal: Option<Cow<'a, Rgb>>,
    /// Object ids.
    pub object_id: Option<&'a Plane<u32>>,
    /// Samples repaired.
    pub counts: InputCounts,
    /// Pixels whose colour had a non-finite or negative component (`None` when there were
    /// none). Their repaired value is a guess (the neighbours' mean, or 0), so temporal
    /// filters keep the pixel's history instead of blending the guess in.
    pub invalid: Option<Vec<bool>>,
    /// What the planner knows about this frame.
    pub facts: FrameFacts,
}

/// Scan result of one plane.
#[derive(Default)]
struct Scan {
    non_finite: u64,
    negative: u64,
    max: f32,
}

fn scan(p: &Plane<f32>, clamp_negative: bool) -> Scan {
    use rayon::prelude::*;
    // Branch-free, so the loop runs on vector lanes: counts of non-finite and (finite)
    // negative samples, and the largest finite sample (at least 0). The maximum is taken
    // over the bits: for floats >= 0 their order is that of the integers (an integer
    // maximum vectorises where a float one may not, for NaN's sake).
    let chunk = |data: &[f32]| {
        let (mut non_finite, mut negative, mut max) = (0u32, 0u32, 0u32);
        for &v in data {
            let finite = v.abs() < f32::INFINITY;
            non_finite += (!finite) as u32;
            negative += (finite & (v < 0.0)) as u32;
            let x = if finite & (v > 0.0) { v.to_bits() } else { 0 };
            max = max.max(x);
        }
        Scan {
            non_finite: non_finite as u64,
            negative: if clamp_negative { negative as u64 } else { 0 },
            max: f32::from_bits(max),
        }
    };
    super::exec::pool().install(|| {
        p.data()
            .par_chunks(1 << 16)
            .map(chunk)
            .reduce(Scan::default, |a, b| Scan {
                non_finite: a.non_finite + b.non_finite,
                negative: a.negative + b.negative,
                max: a.max.max(b.max),
            })
    })
}

/// A copy of `p` with non-finite samples replaced by their finite neighbours' mean (0 if
/// none) and, when `clamp_negative`, negative samples set to 0.
fn repaired(p: &Plane<f32>, clamp_negative: bool) -> Plane<f32> {
    let (w, h) = p.size();
    let floor = if clamp_negative { 0.0 } else { f32::NEG_INFINITY };
    Plane::from_fn(w, h, |x, y| {
        let v = p.get(x, y);
        if v.is_finite() {
            return v.max(floor);
        }
        let (mut sum, mut n) = (0.0f64, 0u32);
        for dy in -1..=1isize {
            for dx in -1..=1isize {
                let (xx, yy) = (x as isize + dx, y as isize + dy);
                if xx < 0 || yy < 0 || xx >= w as isize || yy >= h as isize {
                    continue;
                }
                let u = p.get(xx as usize, yy as usize);
                if u.is_finite() {
                    sum += u as f64;
                    n += 1;
                }
            }
        }
        let mean = if n == 0 { 0.0 } else { (sum / n as f64) as f32 };
        // The mean of finite f32 samples can overflow f32 only if they are near f32::MAX.
        if mean.is_finite() {
            mean.max(floor)
        } else {
            0.0
        }
    })
}

/// Repairs a multi-plane channel; borrowed when it is clean.
fn repair_channel<'a, const N: usize>(
    planes: &'a [Plane<f32>; N],
    clamp_negative: bool,
    counts: &mut InputCounts,
    max: &mut f32,
) -> Cow<'a, [Plane<f32>; N]> {
    let scans = planes.each_ref().map(|p| scan(p, clamp_negative));
    let mut dirty = false;
    for s in &scans {
        counts.non_finite += s.non_finite;
        counts.negative += s.negative;
        *max = max.max(s.max);
        dirty |= s.non_finite > 0 || s.negative > 0;
    }
    if dirty {
        Cow::Owned(planes.each_ref().map(|p| repaired(p, clamp_negative)))
    } else {
        Cow::Borrowed(planes)
    }
}

/// Prepares the channels of `frame` that a filter `uses`, recording the repair stage.
pub fn prepare<'a>(
    frame: &'a Frame,
    uses: ChannelSet,
    rec: &mut Recorder,
) -> Result<Inputs<'a>, FilterError> {
    let t = std::time::Instant::now();
    let mut counts = InputCounts::default();
    let mut max_color = 0.0f32;
    let mut unused = 0.0f32;
    let color = repair_channel(frame.color(), true, &mut counts, &mut max_color);
    let invalid = (counts.non_finite + counts.negative > 0).then(|| {
        let [r, g, b] = frame.color().each_ref().map(|p| p.data());
        let ok = |v: f32| v.is_finite() && v >= 0.0;
        (0..r.len())
            .map(|i| !(ok(r[i]) && ok(g[i]) && ok(b[i])))
            .collect::<Vec<bool>>()
    });
    let depth = match frame.depth().filter(|_| uses.contains(ChannelKind::Depth)) {
        None => None,
        Some(d) => {
            let lin: Cow<'a, Plane<f32>> = match frame.meta.depth_kind {
                DepthKind::Linear => Cow::Borrowed(d),
                kind => {
                    let [n, f] = frame.meta.near_far.ok_or(FilterError::DeviceDepthWithoutPlanes)?;
                    Cow::Owned(d.map(|v| kind.to_linear(v, n, f)))
                }
            };
            let one: &[Plane<f32>; 1] = std::slice::from_ref(lin.as_ref()).try_into().expect("one plane");
            match repair_channel(one, false, &mut counts, &mut unused) {
                Cow::Owned([p]) => Some(Cow::Owned(p)),
                Cow::Borrowed(_) => Some(lin),
            }
        }
    };
    let motion = frame
        .motion()
        .filter(|_| uses.contains(ChannelKind::Motion))
        .map(|m| repair_channel(m, false, &mut counts, &mut unused));
    let albedo = frame
        .albedo()
        .filter(|_| uses.contains(ChannelKind::Albedo))
        .map(|a| repair_channel(a, true, &mut counts, &mut unused));
    let normal = frame
        .normal()
        .filter(|_| uses.contains(ChannelKind::Normal))
        .map(|n| repair_channel(n, false, &mut counts, &mut unused));
    let object_id = frame.object_id().filter(|_| uses.contains(ChannelKind::ObjectId));
    let facts = FrameFacts::new(frame, motion.as_deref(), max_color);
    let elapsed = t.elapsed().as_secs_f64() * 1e3;
    if counts.non_finite + counts.negative == 0 {
        rec.skip(REPAIR_STAGE, Skip::CleanInput);
    } else {
        rec.ran_for(REPAIR_STAGE, elapsed);
    }
    Ok(Inputs {
        width: frame.width(),
        height: frame.height(),
        color,
        depth,
        motion,
        albedo,
        normal,
        object_id,
        counts,
        invalid,
        facts,
    })
}

impl Inputs<'_> {
    /// The colour planes as slices.
    pub fn color_slices(&self) -> [&[f32]; 3] {
        self.color.each_ref().map(|p| p.data())
    }

    /// Whether the frame carries `kind` for this filter.
    pub fn has(&self, kind: ChannelKind) -> bool {
        match kind {
            ChannelKind::Color => true,
            ChannelKind::Depth => self.depth.is_some(),
            ChannelKind::Motion => self.motion.is_some(),
            ChannelKind::Albedo => self.albedo.is_some(),
            ChannelKind::ObjectId => self.object_id.is_some(),
            ChannelKind::Normal => self.normal.is_some(),
            ChannelKind::Reference | ChannelKind::MotionNext => false,
        }
    }

    /// Whether colour sample `i` was non-finite or negative (see [`Inputs::invalid`]).
    pub fn is_invalid(&self, i: usize) -> bool {
        self.invalid.as_ref().is_some_and(|v| v[i])
    }

    /// `None` when `kind` is present, else the reason a stage that needs it is left out.
    pub fn require(&self, kind: ChannelKind) -> Option<Skip> {
        (!self.has(kind)).then_some(Skip::MissingChannel { channel: kind })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn non_finite_and_negative_colour_is_repaired_and_counted() {
        let mut r = Plane::filled(4, 3, 0.5f32);
        r.set(1, 1, f32::NAN);
        r.set(2, 2, -3.0);
        let mut g = Plane::filled(4, 3, 0.25f32);
        g.set(0, 0, f32::INFINITY);
        let b = Plane::filled(4, 3, 2.0f32);
        let frame = Frame::new([r, g, b]).unwrap();
        let mut rec = Recorder::new();
        let inp = prepare(&frame, ChannelSet::of(&[ChannelKind::Color]), &mut rec).unwrap();
        assert_eq!(
            inp.counts,
            InputCounts {
                non_finite: 2,
                negative: 1
            }
        );
        // NaN at (1,1): mean of its 8 neighbours, one of which (-3) counts as itself (-3
        // is finite) but the result is floored at 0; here 7 x 0.5 and -3 -> (3.5-3)/8.
        assert_eq!(inp.color[0].get(1, 1), (3.5f32 - 3.0) / 8.0);
        assert_eq!(inp.color[0].get(2, 2), 0.0);
        assert_eq!(inp.color[1].get(0, 0), 0.25);
        assert!(matches!(inp.color, Cow::Owned(_)));
        assert!(rec
            .finish("t", 0, Default::default(), inp.counts, 0)
            .ran(REPAIR_STAGE));
        assert_eq!(inp.facts.max_color, 2.0);
        assert!(inp.facts.hdr);
    }

    #[test]
    fn clean_input_is_borrowed_and_the_stage_left_out() {
        let frame = Frame::new(std::array::from_fn(|_| Plane::filled(3, 2, 0.5f32))).unwrap();
        let mut rec = Recorder::new();
        let inp = prepare(&frame, ChannelSet::of(&[ChannelKind::Color]), &mut rec).unwrap();
        assert!(matches!(inp.color, Cow::Borrowed(_)));
        assert!(!inp.facts.hdr);
        let r = rec.finish("t", 0, Default::default(), inp.counts, 0);
        assert_eq!(r.stage(REPAIR_STAGE).unwrap().skipped, Some(Skip::CleanInput));
    }
}
