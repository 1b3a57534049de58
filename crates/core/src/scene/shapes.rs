//! Analytic primitives in their own (local) coordinates.

use super::math::{Aabb, Ray};
use glam::{DVec2, DVec3};

/// A primitive, centred at its local origin.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Shape {
    /// The plane y = 0, normal +y (infinite).
    Plane,
    /// A sphere of this radius.
    Sphere {
        /// Radius.
        radius: f64,
    },
    /// A box with these half extents.
    Cuboid {
        /// Half extents along x, y, z.
        half: DVec3,
    },
    /// A capped cylinder along y.
    Cylinder {
        /// Radius.
        radius: f64,
        /// Half of the height.
        half_height: f64,
    },
}

/// Which part of a shape a ray met: enough, with the local hit point, to give the normal
/// (see [`Shape::normal`]). Visibility queries carry this instead of the normal, so that
/// only the nearest hit of a ray pays for one.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Face(u8);

impl Face {
    /// A box's face: the axis of its normal (0, 1, 2 for x, y, z).
    pub(crate) fn axis(self) -> usize {
        self.0 as usize
    }

    /// A cylinder's face: whether it is a (flat) cap.
    pub(crate) fn is_cap(self) -> bool {
        self.0 != CYLINDER_SIDE
    }
}

/// A hit in local coordinates.
#[derive(Clone, Copy, Debug)]
pub struct LocalHit {
    /// Ray parameter.
    pub t: f64,
    /// Local normal (unit, facing outwards).
    pub normal: DVec3,
}

fn solve_quadratic(a: f64, b: f64, c: f64) -> Option<(f64, f64)> {
    let disc = b * b - 4.0 * a * c;
    if disc < 0.0 {
        return None;
    }
    let s = disc.sqrt();
    // Numerically stable roots.
    let q = -0.5 * (b + b.signum() * s);
    let (r0, r1) = if q == 0.0 { (0.0, 0.0) } else { (q / a, c / q) };
    Some((r0.min(r1), r0.max(r1)))
}

impl Shape {
    /// Local bounds (None for the infinite plane).
    pub fn bounds(&self) -> Option<Aabb> {
        let half = match *self {
            Shape::Plane => return None,
            Shape::Sphere { radius } => DVec3::splat(radius),
            Shape::Cuboid { half } => half,
            Shape::Cylinder { radius, half_height } => DVec3::new(radius, half_height, radius),
        };
        Some(Aabb {
            min: -half,
            max: half,
        })
    }

    /// Texture coordinates of the local surface point `p` whose local normal is `n`
    /// (world units along the surface, so patterns keep their scale).
    #[inline]
    pub fn uv(&self, p: DVec3, n: DVec3) -> DVec2 {
        match *self {
            Shape::Plane => DVec2::new(p.x, p.z),
            Shape::Sphere { radius } => {
                let d = p / radius;
                DVec2::new(d.z.atan2(d.x) * radius, d.y.clamp(-1.0, 1.0).asin() * radius)
            }
            Shape::Cuboid { .. } => {
                if n.x != 0.0 {
                    DVec2::new(p.z, p.y)
                } else if n.y != 0.0 {
                    DVec2::new(p.x, p.z)
                } else {
                    DVec2::new(p.x, p.y)
                }
            }
            Shape::Cylinder { radius, .. } => {
                if n.y != 0.0 {
                    DVec2::new(p.x, p.z)
                } else {
                    DVec2::new(p.z.atan2(p.x) * radius, p.y)
                }
            }
        }
    }

    /// The nearest hit with `t_min < t < t_max` of a local ray.
    pub fn intersect(&self, r: &Ray, t_min: f64, t_max: f64) -> Option<LocalHit> {
        self.hit(r, t_min, t_max).map(|(t, face)| LocalHit {
            t,
            normal: self.normal(face, r.at(t)),
        })
    }

    /// The outward unit normal of `face` at the local surface point `p` (a point of
    /// that face, as [`Shape::hit`] found it).
    #[inline]
    pub fn normal(&self, face: Face, p: DVec3) -> DVec3 {
        match *self {
            Shape::Plane => DVec3::Y,
            Shape::Sphere { radius } => p / radius,
            Shape::Cuboid { .. } => {
                let axis = face.0 as usize;
                let mut normal = DVec3::ZERO;
                normal[axis] = p[axis].signum();
                normal
            }
            Shape::Cylinder { radius, .. } => match face.0 {
                CYLINDER_SIDE => DVec3::new(p.x / radius, 0.0, p.z / radius),
                CYLINDER_BOTTOM => DVec3::NEG_Y,
                _ => DVec3::Y,
            },
        }
    }

    /// [`Shape::intersect`] without the normal: the ray parameter and the face.
    #[inline]
    pub fn hit(&self, r: &Ray, t_min: f64, t_max: f64) -> Option<(f64, Face)> {
        match *self {
            Shape::Plane => hit_plane(r, t_min, t_max),
            Shape::Sphere { radius } => hit_sphere(radius, r, t_min, t_max),
            Shape::Cuboid { half } => hit_cuboid(half, r, t_min, t_max),
            Shape::Cylinder { radius, half_height } => hit_cylinder(radius, half_height, r, t_min, t_max),
        }
    }
}

// One function per shape, so that batched queries (the reference's, which test one
// primitive against all the samples of a pixel) run a loop without a dispatch per ray,
// with exactly the arithmetic of [`Shape::hit`].

/// [`Shape::hit`] of [`Shape::Plane`].
#[inline(always)]
pub(crate) fn hit_plane(r: &Ray, t_min: f64, t_max: f64) -> Option<(f64, Face)> {
    if r.dir.y.abs() < 1e-15 {
        return None;
    }
    let t = -r.origin.y / r.dir.y;
    (t > t_min && t < t_max).then_some((t, Face(0)))
}

/// [`Shape::hit`] of [`Shape::Sphere`].
#[inline(always)]
pub(crate) fn hit_sphere(radius: f64, r: &Ray, t_min: f64, t_max: f64) -> Option<(f64, Face)> {
    let ok = |t: f64| t > t_min && t < t_max;
    let b = 2.0 * r.origin.dot(r.dir);
    let c = r.origin.length_squared() - radius * radius;
    let (t0, t1) = solve_quadratic(1.0, b, c)?;
    let t = if ok(t0) {
        t0
    } else if ok(t1) {
        t1
    } else {
        return None;
    };
    Some((t, Face(0)))
}

/// [`Shape::hit`] of [`Shape::Cuboid`].
#[inline(always)]
pub(crate) fn hit_cuboid(half: DVec3, r: &Ray, t_min: f64, t_max: f64) -> Option<(f64, Face)> {
    let ok = |t: f64| t > t_min && t < t_max;
    let inv = r.dir.recip();
    let t0 = (-half - r.origin) * inv;
    let t1 = (half - r.origin) * inv;
    let tn = t0.min(t1);
    let tf = t0.max(t1);
    let near = tn.max_element();
    let far = tf.min_element();
    if near > far {
        return None;
    }
    // The face: the axis whose slab boundary this is.
    let (t, bounds) = if ok(near) {
        (near, tn)
    } else if ok(far) {
        (far, tf)
    } else {
        return None;
    };
    let axis = if bounds.x == t {
        0
    } else if bounds.y == t {
        1
    } else if bounds.z == t {
        2
    } else {
        0
    };
    Some((t, Face(axis)))
}

/// [`Shape::hit`] of [`Shape::Cylinder`].
#[inline(always)]
pub(crate) fn hit_cylinder(
    radius: f64,
    half_height: f64,
    r: &Ray,
    t_min: f64,
    t_max: f64,
) -> Option<(f64, Face)> {
    let ok = |t: f64| t > t_min && t < t_max;
    let mut best: Option<(f64, Face)> = None;
    let mut consider = |t: f64, face: u8| {
        if ok(t) && best.is_none_or(|b| t < b.0) {
            best = Some((t, Face(face)));
        }
    };
    let a = r.dir.x * r.dir.x + r.dir.z * r.dir.z;
    if a > 1e-18 {
        let b = 2.0 * (r.origin.x * r.dir.x + r.origin.z * r.dir.z);
        let c = r.origin.x * r.origin.x + r.origin.z * r.origin.z - radius * radius;
        if let Some((t0, t1)) = solve_quadratic(a, b, c) {
            for t in [t0, t1] {
                if r.at(t).y.abs() <= half_height {
                    consider(t, CYLINDER_SIDE);
                }
            }
        }
    }
    if r.dir.y.abs() > 1e-15 {
        for (s, face) in [(-1.0, CYLINDER_BOTTOM), (1.0, CYLINDER_TOP)] {
            let t = (s * half_height - r.origin.y) / r.dir.y;
            let p = r.at(t);
            if p.x * p.x + p.z * p.z <= radius * radius {
                consider(t, face);
            }
        }
    }
    best
}

/// [`Face`]s of a cylinder.
const CYLINDER_SIDE: u8 = 0;
const CYLINDER_BOTTOM: u8 = 1;
const CYLINDER_TOP: u8 = 2;

#[cfg(test)]
mod tests {
    use super::*;
    use crate::tolerance::Tolerance;

    #[test]
    fn hits_land_on_the_surface() {
        let shapes = [
            Shape::Sphere { radius: 1.3 },
            Shape::Cuboid {
                half: DVec3::new(0.5, 1.0, 2.0),
            },
            Shape::Cylinder {
                radius: 0.7,
                half_height: 1.1,
            },
        ];
        let mut rng = crate::rng::SplitMix64::new(3);
        let t = Tolerance::abs(1e-9);
        for s in shapes {
            let mut hits = 0;
            for _ in 0..500 {
                let o = DVec3::new(rng.range(-5.0, 5.0), rng.range(-5.0, 5.0), rng.range(-5.0, 5.0));
                if o.abs().max_element() < 2.5 {
                    continue; // start outside every shape
                }
                let target = DVec3::new(rng.range(-1.0, 1.0), rng.range(-1.0, 1.0), rng.range(-1.0, 1.0));
                let r = Ray {
                    origin: o,
                    dir: (target - o).normalize(),
                };
                let Some(h) = s.intersect(&r, 1e-9, 1e9) else {
                    continue;
                };
                hits += 1;
                let p = r.at(h.t);
                let b = s.bounds().unwrap();
                assert!(p.cmpge(b.min - 1e-9).all() && p.cmple(b.max + 1e-9).all());
                t.check("unit normal", h.normal.length(), 1.0).unwrap();
                assert!(h.normal.dot(r.dir) < 0.0, "outside rays hit front faces");
                if let Shape::Sphere { radius } = s {
                    t.check("on sphere", p.length(), radius).unwrap();
                }
            }
            assert!(hits > 100, "{s:?}: {hits}");
        }
    }
}
