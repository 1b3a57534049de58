//! The temporal half of spatio-temporal upsampling (Herzog et al. 2010, sec.
//! 3.2-3.4): history fetched along the motion with a validity test per tap, and the
//! relative temporal gradient of luma that steers how far history is trusted.

use crate::filters::passes::on_screen;
use crate::pipeline::exec::{pool, rows_mut};
use rayon::prelude::*;

/// Luma below which relative gradients are measured against this floor instead: a change
/// of 0.001 on a pixel of luma 0.001 is noise, not a 100% change. 1% of display white.
pub const LUMA_FLOOR: f32 = 0.01;

/// History taps must show the same surface as the pixel: Herzog et al. 2010, sec. 3.2, "compare the
/// warped depth with the depth of the previous frame ... also compare the material (object
/// id), since depth alone misses contact points".
pub struct Validity<'a> {
    /// This frame's linear depth.
    pub depth: Option<&'a [f32]>,
    /// The previous frame's depth (history plane).
    pub prev_depth: &'a [f32],
    /// This frame's object ids.
    pub ids: Option<&'a [u32]>,
    /// The previous frame's ids, stored as f32 (exact below 2^24).
    pub prev_ids: &'a [f32],
    /// Relative depth difference a tap may have.
    pub depth_tolerance: f32,
    /// A tap that fails is still accepted when a pixel of this frame's 3x3 shows its
    /// surface and moves within this many pixels of this pixel ([`surface_nearby`]); 0: off.
    pub neighbour_motion: f32,
    /// Share of its weight a tap that fails keeps when its surface is next to the pixel
    /// this frame (any motion) and the pixel's surface was nowhere near the tap in the
    /// previous frame ([`seen_before`]): a sub-pixel surface that this frame's jittered
    /// G-buffer sample caught; 0: off.
    pub subpixel: f32,
    /// This frame's motion (for `neighbour_motion`; `None`: nothing moves).
    pub motion: Option<[&'a [f32]; 2]>,
    /// Frame size (the rows of the planes above).
    pub width: usize,
    /// Frame height.
    pub height: usize,
}

impl Validity<'_> {
    /// Whether pixel `i` keeps tap `tap`: `Some(false)` when it passes, `Some(true)` when it
    /// fails but shows a surface that a sub-pixel one covers at `i` this frame (kept with the
    /// share `subpixel` of its weight), `None` when it is rejected.
    #[inline(always)]
    fn keeps(&self, i: usize, tap: usize) -> Option<bool> {
        if self.ok(i, tap) {
            Some(false)
        } else if self.subpixel > 0.0 && self.intruder(i, tap) {
            Some(true)
        } else {
            None
        }
    }

    /// Whether a failing tap's surface is next to pixel `i` this frame (any motion) and
    /// `i`'s surface was not within a pixel of the tap in the previous frame.
    #[inline(always)]
    fn intruder(&self, i: usize, tap: usize) -> bool {
        sub_pixel_intruder(
            &self.neighbours(f32::INFINITY),
            i,
            tap,
            &|q| (self.prev_ids[q], self.prev_depth[q]),
            self.ids.map(|d| d[i] as f32),
            self.depth.map(|d| d[i]),
        )
    }

    #[inline(always)]
    fn ok(&self, i: usize, tap: usize) -> bool {
        if let Some(ids) = self.ids {
            if ids[i] as f32 != self.prev_ids[tap] {
                return self.nearby(i, tap);
            }
        }
        if let Some(d) = self.depth {
            let z = d[i];
            if (self.prev_depth[tap] - z).abs() > self.depth_tolerance * z.abs() {
                return self.nearby(i, tap);
            }
        }
        true
    }

    /// The pixel's neighbourhood for [`surface_nearby`], accepting a surface that moves
    /// within `max_motion` pixels of the pixel.
    #[inline(always)]
    fn neighbours(&self, max_motion: f32) -> Nearby<'_> {
        Nearby {
            depth: self.depth,
            ids: self.ids,
            motion: self.motion,
            width: self.width,
            height: self.height,
            depth_tolerance: self.depth_tolerance,
            max_motion,
        }
    }

    /// The fallback of a failed tap: [`surface_nearby`] when `neighbour_motion` is on.
    #[inline(always)]
    fn nearby(&self, i: usize, tap: usize) -> bool {
        self.neighbour_motion > 0.0
            && surface_nearby(
                &self.neighbours(self.neighbour_motion),
                i,
                self.prev_ids[tap],
                self.prev_depth[tap],
            )
    }
}

/// This frame's G-buffer as [`surface_nearby`] reads it.
pub struct Nearby<'a> {
    /// Linear depth.
    pub depth: Option<&'a [f32]>,
    /// Object ids.
    pub ids: Option<&'a [u32]>,
    /// Motion.
    pub motion: Option<[&'a [f32]; 2]>,
    /// Frame size.
    pub width: usize,
    /// Frame height.
    pub height: usize,
    /// Relative depth difference that still counts as the same surface.
    pub depth_tolerance: f32,
    /// Largest difference of motion (either axis, pixels) from pixel `i`'s.
    pub max_motion: f32,
}

/// Whether a history tap of object `id` at depth `z` that failed pixel `i`'s validity test
/// shows a surface that is within a pixel of `i` this frame and moves with it: one of the
/// eight neighbours of `i` has that id, a depth within the tolerance of `z`, and a motion
/// within `max_motion` of `i`'s on both axes.
///
/// A jittered G-buffer samples a random point of each pixel (docs/upsample-realistic.md):
/// at an edge or a sub-pixel object a pixel's id and depth flip between the surfaces its
/// footprint covers from frame to frame, and the test of Herzog et al. 2010, sec. 3.2
/// (same id, same depth) rejects history that is still the pixel's. A surface that has
/// moved away (a disocclusion) is either not next to the pixel any more or moves
/// differently from the surface that uncovered it, and stays rejected.
#[inline(never)]
pub fn surface_nearby(g: &Nearby, i: usize, id: f32, z: f32) -> bool {
    let (w, h) = (g.width, g.height);
    let (x, y) = (i % w, i / w);
    let (mx, my) = g.motion.map_or((0.0, 0.0), |m| (m[0][i], m[1][i]));
    for yy in y.saturating_sub(1)..(y + 2).min(h) {
        for xx in x.saturating_sub(1)..(x + 2).min(w) {
            let q = yy * w + xx;
            if q == i {
                continue;
            }
            if g.ids.is_some_and(|ids| ids[q] as f32 != id) {
                continue;
            }
            if g.depth
                .is_some_and(|d| (z - d[q]).abs() > g.depth_tolerance * d[q].abs())
            {
                continue;
            }
            if let Some(m) = g.motion {
                if !((m[0][q] - mx).abs() <= g.max_motion && (m[1][q] - my).abs() <= g.max_motion) {
                    continue;
                }
            }
            return true;
        }
    }
    false
}

/// Whether tap `t` of pixel `i`, which failed the validity test, is kept for a sub-pixel
/// surface (`subpixel_keep`): the tap's surface (`prev(t)`, the previous frame's id and
/// depth) is next to the pixel this frame (`nearby`, whatever its motion: its
/// `max_motion` is not read), and the pixel's own surface (`id`, `z`) was not within a
/// pixel of the tap in the previous frame ([`seen_before`]).
#[inline(never)]
pub fn sub_pixel_intruder(
    nearby: &Nearby,
    i: usize,
    t: usize,
    prev: &impl Fn(usize) -> (f32, f32),
    id: Option<f32>,
    z: Option<f32>,
) -> bool {
    let anywhere = Nearby {
        max_motion: f32::INFINITY,
        ..*nearby
    };
    let (tid, tz) = prev(t);
    surface_nearby(&anywhere, i, tid, tz)
        && !seen_before(
            prev,
            nearby.width,
            nearby.height,
            t,
            id,
            z,
            nearby.depth_tolerance,
        )
}

/// Whether the previous frame showed the surface of object `id` at depth `z` at pixel `t`
/// or one of its eight neighbours: `prev(q)` gives pixel `q`'s previous id and depth; an
/// absent channel (`id` or `z` `None`) matches anything. Relative depth differences are
/// measured against `z`, as [`Validity`] measures a tap's.
#[inline(never)]
pub fn seen_before(
    prev: &impl Fn(usize) -> (f32, f32),
    width: usize,
    height: usize,
    t: usize,
    id: Option<f32>,
    z: Option<f32>,
    depth_tolerance: f32,
) -> bool {
    let (w, h) = (width, height);
    let (x, y) = (t % w, t / w);
    for yy in y.saturating_sub(1)..(y + 2).min(h) {
        for xx in x.saturating_sub(1)..(x + 2).min(w) {
            let (pid, pz) = prev(yy * w + xx);
            if id.is_some_and(|id| id != pid) {
                continue;
            }
            if z.is_some_and(|z| (pz - z).abs() > depth_tolerance * z.abs()) {
                continue;
            }
            return true;
        }
    }
    false
}

/// Fetches `N` history planes at each pixel's previous position `p + motion` (no motion:
/// in place) bilinearly, over the taps that pass `validity` (all on-screen taps when
/// `None`), renormalised by their weight; `frac` gets the weight of the taps that passed
/// (1: all of the history is usable, 0: none, off screen or disoccluded), `kept` the part
/// of it that taps kept for a sub-pixel surface ([`Validity::subpixel`]). Returns the
/// pixels with `frac < 0.5`.
#[allow(clippy::too_many_arguments)]
pub fn reproject<const N: usize>(
    src: [&[f32]; N],
    motion: Option<[&[f32]; 2]>,
    validity: Option<&Validity>,
    width: usize,
    height: usize,
    out: [&mut [f32]; N],
    frac: &mut [f32],
    kept: &mut [f32],
) -> u64 {
    let (w, h) = (width, height);
    let rows = rows_mut(out, w);
    pool().install(|| {
        rows.into_par_iter()
            .zip(frac.par_chunks_mut(w))
            .zip(kept.par_chunks_mut(w))
            .enumerate()
            .map(|(y, ((row, fr), kp))| {
                let mut lost = 0u64;
                for x in 0..w {
                    let i = y * w + x;
                    let (mx, my) = motion.map_or((0.0, 0.0), |m| (m[0][i], m[1][i]));
                    let (px, py) = (x as f32 + 0.5 + mx, y as f32 + 0.5 + my);
                    let mut acc = [0.0f32; N];
                    let mut total = 0.0f32;
                    let mut sub = 0.0f32;
                    if on_screen(px, py, w, h) {
                        let (fx, fy) = (px - 0.5, py - 0.5);
                        let (x0, y0) = (fx.floor(), fy.floor());
                        let (tx, ty) = (fx - x0, fy - y0);
                        let clamp = |v: f32, n: usize| (v.max(0.0) as usize).min(n - 1);
                        let taps = [
                            (clamp(x0, w), clamp(y0, h), (1.0 - tx) * (1.0 - ty)),
                            (clamp(x0 + 1.0, w), clamp(y0, h), tx * (1.0 - ty)),
                            (clamp(x0, w), clamp(y0 + 1.0, h), (1.0 - tx) * ty),
                            (clamp(x0 + 1.0, w), clamp(y0 + 1.0, h), tx * ty),
                        ];
                        for (tx, ty, wt) in taps {
                            let t = ty * w + tx;
                            let keeps = validity.map_or(Some(false), |v| v.keeps(i, t));
                            if let (true, Some(sub_pixel)) = (wt > 0.0, keeps) {
                                let wt = if sub_pixel {
                                    let wt = wt * validity.expect("kept as sub-pixel").subpixel;
                                    sub += wt;
                                    wt
                                } else {
                                    wt
                                };
                                total += wt;
                                for c in 0..N {
                                    acc[c] += wt * src[c][t];
                                }
                            }
                        }
                    }
                    let inv = if total > 0.0 { 1.0 / total } else { 0.0 };
                    for c in 0..N {
                        row[c][x] = acc[c] * inv;
                    }
                    fr[x] = total;
                    kp[x] = sub;
                    lost += (total < 0.5) as u64;
                }
                lost
            })
            .sum()
    })
}

/// Relative temporal gradient of luma between a new sample and the history at its pixel
/// (Herzog et al. 2010, sec. 3.4: `|L_t - L_t-1| / max(L_t, L_t-1)`, which measures contrast).
#[inline(always)]
pub fn relative_gradient(now: f32, before: f32) -> f32 {
    ((now - before).abs() / now.max(before).max(LUMA_FLOOR)).min(1.0)
}

/// The relative gradient with its sign, `(L_t - L_t-1) / max(L_t, L_t-1)` clamped to
/// [-1, 1]: [`relative_gradient`] (Herzog et al. 2010, sec. 3.4) is its magnitude. Its
/// temporal and spatial filters average it before the magnitude is taken, so differences
/// of random sign between neighbouring samples and frames (Monte Carlo noise, jittered
/// samples of sub-pixel detail) cancel, while a change of the shading moves them all one
/// way (the paper's fig. 7 plots the gradient with its sign).
#[inline(always)]
pub fn signed_gradient(now: f32, before: f32) -> f32 {
    ((now - before) / now.max(before).max(LUMA_FLOOR)).clamp(-1.0, 1.0)
}

/// The gradient the confidence reads: the filtered magnitudes `magnitude` (Herzog et al.
/// 2010, sec. 3.4) less `cancel` times what the signed filter `signed` cancelled,
/// `magnitude - cancel (magnitude - |signed|)`. 0 gives the paper's value, 1 the magnitude
/// of the filtered signed gradient.
#[cfg(test)]
#[inline(always)]
pub fn cancelled(magnitude: f32, signed: f32, cancel: f32) -> f32 {
    magnitude - cancel * (magnitude - signed.abs())
}

/// The temporal filter of gradients, Herzog et al. 2010, sec. 3.4: the current and the three
/// previous gradients weighted 4, 3, 2, 1.
pub const GRADIENT_WEIGHTS: [f32; 4] = [4.0, 3.0, 2.0, 1.0];

/// The temporal filter of gradients (Herzog et al. 2010, sec. 3.4) of the current and the
/// three previous gradients `g`: their mean weighted by [`GRADIENT_WEIGHTS`].
#[inline(always)]
pub fn filter_gradients(g: [f32; 4]) -> f32 {
    let w = GRADIENT_WEIGHTS;
    (w[0] * g[0] + w[1] * g[1] + w[2] * g[2] + w[3] * g[3]) / (w[0] + w[1] + w[2] + w[3])
}

/// Confidence in history from a filtered gradient: `(1 - min(1, g / scale))^2`. Herzog et al. 2010,
/// eq. 8 squares the term so that large gradients cut history fast while small ones
/// barely do; `scale` is its sensitivity ("usually kept at 1").
#[inline(always)]
pub fn confidence(gradient: f32, scale: f32) -> f32 {
    let t = 1.0 - (gradient / scale).min(1.0);
    if t > 0.0 {
        t * t
    } else {
        0.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::tolerance::Tolerance;

    #[test]
    fn reprojection_interpolates_valid_taps_and_reports_the_rest() {
        let (w, h) = (4usize, 3usize);
        let src: Vec<f32> = (0..w * h).map(|i| i as f32).collect();
        let mx = vec![-0.5f32; w * h];
        let my = vec![0.0f32; w * h];
        // Reprojects `src` by (`mx`, 0): the output, the fraction of valid taps, the lost count.
        let run = |mx: &[f32], v: Option<&Validity>| {
            let (mut out, mut frac, mut kept) =
                (vec![0.0f32; w * h], vec![0.0f32; w * h], vec![0.0f32; w * h]);
            let lost = reproject([&src], Some([mx, &my]), v, w, h, [&mut out], &mut frac, &mut kept);
            (out, frac, lost)
        };
        let (out, frac, lost) = run(&mx, None);
        // Half a pixel to the left: the mean of a pixel and its left neighbour.
        Tolerance::abs(1e-6).check("x=2", out[w + 2] as f64, 5.5).unwrap();
        assert_eq!(frac[w + 2], 1.0);
        assert_eq!(lost, 0);
        // A tap on another object is left out and the rest renormalised.
        let ids = vec![1u32; w * h];
        let mut prev_ids = vec![1.0f32; w * h];
        prev_ids[w + 1] = 2.0;
        let depth = vec![1.0f32; w * h];
        let v = Validity {
            depth: Some(&depth),
            prev_depth: &depth,
            ids: Some(&ids),
            prev_ids: &prev_ids,
            depth_tolerance: 0.1,
            neighbour_motion: 0.0,
            subpixel: 0.0,
            motion: None,
            width: w,
            height: h,
        };
        let (out, frac, _) = run(&mx, Some(&v));
        assert_eq!(out[w + 2], 6.0, "only the pixel's own tap is left");
        assert_eq!(frac[w + 2], 0.5);
        // Off screen: nothing.
        let far = vec![-1e9f32; w * h];
        let (out, frac, lost) = run(&far, None);
        assert_eq!(lost, (w * h) as u64);
        assert!(frac.iter().all(|&f| f == 0.0) && out.iter().all(|&v| v == 0.0));
    }

    #[test]
    fn gradient_and_confidence() {
        assert_eq!(relative_gradient(0.5, 0.5), 0.0);
        Tolerance::abs(1e-7)
            .check("halved", relative_gradient(0.5, 1.0) as f64, 0.5)
            .unwrap();
        assert_eq!(relative_gradient(0.0, 1e-4), 0.01, "dark pixels use the floor");
        assert_eq!(relative_gradient(1e30, 0.0), 1.0);
        for (a, b) in [(0.5, 1.0), (1.0, 0.5), (0.0, 1e-4), (1e30, 0.0), (0.3, 0.3)] {
            assert_eq!(signed_gradient(a, b).abs(), relative_gradient(a, b), "{a} {b}");
        }
        assert!(signed_gradient(0.5, 1.0) < 0.0 && signed_gradient(1.0, 0.5) > 0.0);
        assert_eq!(signed_gradient(-1e30, 1.0), -1.0);
        assert_eq!(confidence(0.0, 1.0), 1.0);
        assert_eq!(confidence(0.5, 1.0), 0.25);
        assert_eq!(confidence(2.0, 1.0), 0.0);
    }
}
