//! Rectification of history against a colour box: clip toward the centre, or clamp.

/// Absolute part of the [`guard`] by which every box is grown: Pedersen 2016 (INSIDE's
/// `clip_aabb`, `FLT_EPS = 1e-8`), so that a flat black box never divides by zero.
pub const CLIP_EPS: f32 = 1.0e-8;

/// Relative part of the [`guard`]: 1e-4 of the box's largest magnitude. With the
/// absolute part alone, rounding in a flat channel (min = max, e.g. a constant Co) decides
/// the clip of all three channels, and two backends that sum in other orders (a Catmull-Rom
/// fetch, `phlm`'s f32 solve against f64) clip differently. Rounding lies far below 1e-4
/// of a value; a larger guard starts to keep history a clip should remove (docs/gpu.md).
pub const CLIP_REL: f32 = 1.0e-4;

/// How far the box `[min, max]` is grown on each side before a clip:
/// `CLIP_EPS + CLIP_REL * m`, `m` the largest magnitude of its bounds. The lane and WGSL
/// versions compute the same.
#[inline(always)]
pub fn guard(min: [f32; 3], max: [f32; 3]) -> f32 {
    let m = min[0]
        .abs()
        .max(max[0].abs())
        .max(min[1].abs().max(max[1].abs()))
        .max(min[2].abs().max(max[2].abs()));
    CLIP_EPS + CLIP_REL * m
}

/// Clips `q` toward the centre of the box `[min, max]` (grown by its [`guard`] on each
/// side): if `q` lies outside, it is moved
/// along the segment to the centre until it meets the box surface; inside, it is returned
/// unchanged (Pedersen 2016, INSIDE's `clip_aabb`; Karis 2014). Unlike a per-axis clamp this
/// keeps the history's hue instead of snapping it to a corner (Oliveros 2018, fig. 3.9).
/// Returns the point and whether it moved.
#[inline]
pub fn clip_toward_center(q: [f32; 3], min: [f32; 3], max: [f32; 3]) -> ([f32; 3], bool) {
    let g = guard(min, max);
    let mut worst = 0.0f32;
    let mut center = [0.0f32; 3];
    let mut v = [0.0f32; 3];
    for k in 0..3 {
        center[k] = 0.5 * (max[k] + min[k]);
        let extent = 0.5 * (max[k] - min[k]) + g;
        v[k] = q[k] - center[k];
        worst = worst.max((v[k] / extent).abs());
    }
    if worst > 1.0 {
        let s = 1.0 / worst;
        (
            [center[0] + v[0] * s, center[1] + v[1] * s, center[2] + v[2] * s],
            true,
        )
    } else {
        (q, false)
    }
}

/// Clips `q` along the ray toward `target` (a point inside the box, e.g. the current input
/// colour): if `q` lies outside `[min, max]` grown by its [`guard`], returns the first
/// point of the segment from `q` to `target` inside that box, else `q` unchanged
/// (Iglesias-Guitian et al. 2016, Algorithm 1 lines 14-17: `ray_ori = f, ray_dir = y - f`,
/// `f = ray_ori + ray_hit * ray_dir`). A `target` outside `[min, max]` is clamped into it
/// first, so it lies at least the guard inside the grown box and the result moves
/// continuously with `q`. Returns the point and whether it moved.
#[inline]
pub fn clip_toward_point(q: [f32; 3], target: [f32; 3], min: [f32; 3], max: [f32; 3]) -> ([f32; 3], bool) {
    let mut t = 0.0f32;
    let mut outside = false;
    let mut tgt = [0.0f32; 3];
    let g = guard(min, max);
    for k in 0..3 {
        tgt[k] = target[k].max(min[k]).min(max[k]);
        // Entering the slab of axis k: the bound q violates, reached at fraction t_k.
        let (lo, hi) = (min[k] - g, max[k] + g);
        let bound = if q[k] < lo {
            lo
        } else if q[k] > hi {
            hi
        } else {
            continue;
        };
        outside = true;
        let d = tgt[k] - q[k];
        // d is non-zero here (q is outside the slab, tgt inside), and |bound - q| <= |d|.
        t = t.max(((bound - q[k]) / d).min(1.0));
    }
    if !outside {
        return (q, false);
    }
    let p = [0, 1, 2].map(|k| (q[k] + t * (tgt[k] - q[k])).max(min[k] - g).min(max[k] + g));
    (p, true)
}

/// Clamps each component of `q` into `[min, max]` (the thesis's one-channel Sobel history
/// uses clamping, Oliveros 2018 sec. 4.3.3). Returns the value and whether it moved.
#[inline]
pub fn clamp_to_box(q: f32, min: f32, max: f32) -> (f32, bool) {
    let c = q.max(min).min(max);
    (c, c != q)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::SplitMix64;
    use crate::tolerance::Tolerance;

    /// The guard in f64.
    fn guard_f64(min: [f64; 3], max: [f64; 3]) -> f64 {
        let m = (0..3).map(|k| min[k].abs().max(max[k].abs())).fold(0.0, f64::max);
        CLIP_EPS as f64 + CLIP_REL as f64 * m
    }

    /// f64 reference: the largest s in [0, 1] with centre + s (q - centre) inside the box
    /// (grown by the guard on each side, part of the clip's definition), found by
    /// intersecting the segment with each slab.
    fn clip_f64(q: [f64; 3], min: [f64; 3], max: [f64; 3]) -> [f64; 3] {
        let c: Vec<f64> = (0..3).map(|k| 0.5 * (min[k] + max[k])).collect();
        let g = guard_f64(min, max);
        let mut s: f64 = 1.0;
        for k in 0..3 {
            let v = q[k] - c[k];
            let half = 0.5 * (max[k] - min[k]) + g;
            if v.abs() > half {
                s = s.min(half / v.abs());
            }
        }
        [0, 1, 2].map(|k| c[k] + s * (q[k] - c[k]))
    }

    /// A random box in `[-scale, scale]^3`.
    fn random_box(rng: &mut SplitMix64, scale: f64) -> ([f32; 3], [f32; 3]) {
        let a = [0, 1, 2].map(|_| rng.range(-1.0, 1.0) * scale);
        let b = [0, 1, 2].map(|_| rng.range(-1.0, 1.0) * scale);
        (
            [0, 1, 2].map(|k| a[k].min(b[k]) as f32),
            [0, 1, 2].map(|k| a[k].max(b[k]) as f32),
        )
    }

    /// `case` on 20 000 random boxes (at scales 1, 1e3 and 1e-3 in turn, from a generator
    /// seeded `seed`, which `case` draws its points from too); `case` says whether the clip
    /// moved its point, which must happen in more than 1000 cases.
    fn for_random_boxes(seed: u64, mut case: impl FnMut(&mut SplitMix64, f64, [f32; 3], [f32; 3]) -> bool) {
        let mut rng = SplitMix64::new(seed);
        let mut moved = 0;
        for i in 0..20_000 {
            let scale = [1.0, 1e3, 1e-3][i % 3];
            let (min, max) = random_box(&mut rng, scale);
            moved += case(&mut rng, scale, min, max) as u32;
        }
        assert!(moved > 1000, "the random cases exercise clipping ({moved})");
    }

    #[test]
    fn clip_matches_the_slab_reference() {
        for_random_boxes(21, |rng, scale, min, max| {
            let q = [0, 1, 2].map(|_| (rng.range(-2.0, 2.0) * scale) as f32);
            let (got, m) = clip_toward_center(q, min, max);
            let expect = clip_f64(q.map(f64::from), min.map(f64::from), max.map(f64::from));
            for k in 0..3 {
                Tolerance::new(1e-6 * scale, 1e-5)
                    .check("clip", got[k] as f64, expect[k])
                    .unwrap();
                // The result is inside the box (up to rounding and the guard).
                let slack = 1e-5 * scale as f32 + 2.0 * guard(min, max);
                assert!(got[k] >= min[k] - slack && got[k] <= max[k] + slack);
            }
            let inside = in_grown(q.map(f64::from), min.map(f64::from), max.map(f64::from));
            assert_eq!(!inside, m, "moved flag for {q:?} in {min:?}..{max:?}");
            m
        });
    }

    /// Whether `p` lies in `[min, max]` grown by the guard (part of the clips' definition).
    fn in_grown(p: [f64; 3], min: [f64; 3], max: [f64; 3]) -> bool {
        let e = guard_f64(min, max);
        (0..3).all(|k| p[k] >= min[k] - e && p[k] <= max[k] + e)
    }

    /// f64 reference of [`clip_toward_point`]: bisection on the segment for the first point
    /// inside the grown box (independent of the slab formula).
    fn clip_point_f64(q: [f64; 3], t: [f64; 3], min: [f64; 3], max: [f64; 3]) -> [f64; 3] {
        let inside = |p: [f64; 3]| in_grown(p, min, max);
        if inside(q) {
            return q;
        }
        let at = |s: f64| [0, 1, 2].map(|k| q[k] + s * (t[k] - q[k]));
        let (mut lo, mut hi) = (0.0f64, 1.0f64);
        for _ in 0..200 {
            let mid = 0.5 * (lo + hi);
            if inside(at(mid)) {
                hi = mid;
            } else {
                lo = mid;
            }
        }
        at(hi)
    }

    #[test]
    fn clip_toward_point_matches_bisection() {
        for_random_boxes(23, |rng, scale, min, max| {
            // The target inside the box (the pixel's own input is part of its 3x3).
            let target = [0, 1, 2].map(|k| min[k] + (max[k] - min[k]) * rng.next_f64() as f32);
            let q = [0, 1, 2].map(|_| (rng.range(-3.0, 3.0) * scale) as f32);
            let (got, m) = clip_toward_point(q, target, min, max);
            let expect = clip_point_f64(
                q.map(f64::from),
                target.map(f64::from),
                min.map(f64::from),
                max.map(f64::from),
            );
            for k in 0..3 {
                Tolerance::new(1e-5 * scale, 1e-4)
                    .check("clip toward point", got[k] as f64, expect[k])
                    .unwrap();
                let g = guard(min, max);
                assert!(got[k] >= min[k] - g && got[k] <= max[k] + g);
            }
            let inside = in_grown(q.map(f64::from), min.map(f64::from), max.map(f64::from));
            assert_eq!(!inside, m);
            m
        });
    }

    #[test]
    fn clip_toward_point_handles_flat_boxes_and_outside_targets() {
        let p = [0.3, 0.2, 0.1];
        let (got, moved) = clip_toward_point([5.0, -2.0, 0.0], p, p, p);
        assert!(moved);
        // On the box grown by the guard.
        for k in 0..3 {
            Tolerance::abs(guard(p, p) as f64 * 1.01)
                .check("flat", got[k] as f64, p[k] as f64)
                .unwrap();
        }
        // A target outside the box is clamped into it: the result is still inside (the
        // box grown by the guard).
        let (got, _) = clip_toward_point([2.0, 2.0, 2.0], [-5.0, 0.5, 9.0], [0.0; 3], [1.0; 3]);
        let g = guard([0.0; 3], [1.0; 3]);
        let grown = -g..=1.0 + g;
        assert!(got.iter().all(|v| grown.contains(v)), "{got:?}");
    }

    /// A flat channel (min = max: a constant Co, say) whose history or prediction is off
    /// by rounding (a sum taken in another order) is inside the box: it neither clips nor
    /// moves the other channels, and past the guard the clip grows from nothing.
    #[test]
    fn rounding_in_a_flat_channel_is_no_clip() {
        let (min, max) = ([0.1f32, 0.105, -0.04], [0.21, 0.105, 0.045]);
        let target = [0.12, 0.105, -0.02];
        let ulp = f32::EPSILON * 0.105;
        for noise in [ulp, -ulp, 4.0 * ulp, -16.0 * ulp] {
            let q = [0.1878, 0.105 + noise, 0.0287];
            assert_eq!(
                clip_toward_center(q, min, max),
                (q, false),
                "centre, noise {noise}"
            );
            assert_eq!(
                clip_toward_point(q, target, min, max),
                (q, false),
                "point, noise {noise}"
            );
        }
        // Past the guard by a thousandth of it, each clip moves the point by about a
        // thousandth of its way to the centre (or the target): the clip grows from nothing.
        let g = guard(min, max);
        let q = [0.1878, 0.105 + g * 1.001, 0.0287];
        let centre = [0, 1, 2].map(|k| 0.5 * (min[k] + max[k]));
        for (got, moved, to) in [
            {
                let (g, m) = clip_toward_center(q, min, max);
                (g, m, centre)
            },
            {
                let (g, m) = clip_toward_point(q, target, min, max);
                (g, m, target)
            },
        ] {
            assert!(moved);
            for k in 0..3 {
                let bound = 2e-3 * (to[k] - q[k]).abs() as f64 + 1e-7;
                Tolerance::abs(bound)
                    .check("continuous", got[k] as f64, q[k] as f64)
                    .unwrap();
            }
        }
    }

    #[test]
    fn clip_into_a_flat_box_lands_on_its_point() {
        let p = [0.3, 0.2, 0.1];
        let (got, moved) = clip_toward_center([5.0, -2.0, 0.0], p, p);
        assert!(moved);
        for k in 0..3 {
            Tolerance::abs(guard(p, p) as f64 * 1.01)
                .check("flat", got[k] as f64, p[k] as f64)
                .unwrap();
        }
    }

    #[test]
    fn clamp_reports_movement() {
        assert_eq!(clamp_to_box(0.5, 0.0, 1.0), (0.5, false));
        assert_eq!(clamp_to_box(2.0, 0.0, 1.0), (1.0, true));
        assert_eq!(clamp_to_box(-1.0, 0.0, 1.0), (0.0, true));
    }
}
