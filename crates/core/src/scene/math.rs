//! Rays, rigid transforms and bounding boxes (f64: motion must be exact).

use glam::{DMat3, DVec3};

/// A ray `origin + t * dir`, `dir` of unit length.
#[derive(Clone, Copy, Debug)]
pub struct Ray {
    /// Start.
    pub origin: DVec3,
    /// Unit direction.
    pub dir: DVec3,
}

impl Ray {
    /// The point at parameter `t`.
    pub fn at(&self, t: f64) -> DVec3 {
        self.origin + self.dir * t
    }
}

/// A rotation followed by a translation: `world = rotation * local + translation`.
/// Built by [`Rigid::new`], which also keeps the inverse rotation for ray transforms.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Rigid {
    /// Orthonormal rotation.
    pub rotation: DMat3,
    /// Translation.
    pub translation: DVec3,
    /// The inverse (transpose) of `rotation`.
    inverse: DMat3,
}

impl Rigid {
    /// No motion.
    pub const IDENTITY: Rigid = Rigid {
        rotation: DMat3::IDENTITY,
        translation: DVec3::ZERO,
        inverse: DMat3::IDENTITY,
    };

    /// A pure translation.
    pub fn translate(t: DVec3) -> Rigid {
        Rigid::new(DMat3::IDENTITY, t)
    }

    /// Rotation `r`, then translation `t`.
    pub fn new(r: DMat3, t: DVec3) -> Rigid {
        Rigid {
            rotation: r,
            translation: t,
            inverse: r.transpose(),
        }
    }

    /// Local point to world.
    pub fn point(&self, p: DVec3) -> DVec3 {
        self.rotation * p + self.translation
    }

    /// Local direction to world.
    pub fn vector(&self, v: DVec3) -> DVec3 {
        self.rotation * v
    }

    /// World direction to local.
    #[inline]
    pub fn vector_to_local(&self, v: DVec3) -> DVec3 {
        self.inverse * v
    }

    /// World ray to local (the parameter `t` is preserved: rotations keep lengths).
    #[inline]
    pub fn ray_to_local(&self, r: &Ray) -> Ray {
        Ray {
            origin: self.point_to_local(r.origin),
            dir: self.inverse * r.dir,
        }
    }

    /// World point to local.
    #[inline]
    pub fn point_to_local(&self, p: DVec3) -> DVec3 {
        self.inverse * (p - self.translation)
    }

    /// World ray to local when its origin's local position is known already (rays that
    /// share an origin: a perspective camera's). Equal to [`Rigid::ray_to_local`].
    #[inline]
    pub fn ray_to_local_from(&self, local_origin: DVec3, r: &Ray) -> Ray {
        Ray {
            origin: local_origin,
            dir: self.inverse * r.dir,
        }
    }
}

/// An axis-aligned box.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Aabb {
    /// Minimum corner.
    pub min: DVec3,
    /// Maximum corner.
    pub max: DVec3,
}

impl Aabb {
    /// The empty box.
    pub const EMPTY: Aabb = Aabb {
        min: DVec3::splat(f64::INFINITY),
        max: DVec3::splat(f64::NEG_INFINITY),
    };

    /// The smallest box holding both.
    pub fn union(&self, o: &Aabb) -> Aabb {
        Aabb {
            min: self.min.min(o.min),
            max: self.max.max(o.max),
        }
    }

    /// Centre.
    pub fn centre(&self) -> DVec3 {
        (self.min + self.max) * 0.5
    }

    /// The world box of a local box under `xf` (its 8 corners transformed).
    pub fn transformed(&self, xf: &Rigid) -> Aabb {
        let mut out = Aabb::EMPTY;
        for i in 0..8 {
            let c = DVec3::new(
                if i & 1 == 0 { self.min.x } else { self.max.x },
                if i & 2 == 0 { self.min.y } else { self.max.y },
                if i & 4 == 0 { self.min.z } else { self.max.z },
            );
            let w = xf.point(c);
            out.min = out.min.min(w);
            out.max = out.max.max(w);
        }
        out
    }

    /// Entry and exit parameters of `ray` (with precomputed `inv_dir`) within
    /// `[0, t_max]`, if it hits.
    #[inline]
    pub fn hit(&self, ray: &Ray, inv_dir: DVec3, t_max: f64) -> Option<f64> {
        let t0 = (self.min - ray.origin) * inv_dir;
        let t1 = (self.max - ray.origin) * inv_dir;
        let near = t0.min(t1).max_element().max(0.0);
        let far = t0.max(t1).min_element().min(t_max);
        (near <= far).then_some(near)
    }
}

/// Rotation by `angle` radians about the unit `axis`.
pub fn rotation(axis: DVec3, angle: f64) -> DMat3 {
    DMat3::from_axis_angle(axis.normalize(), angle)
}

/// The radical inverse of `i` in `base` (Halton sequence element).
pub fn radical_inverse(mut i: u64, base: u64) -> f64 {
    let mut f = 1.0;
    let mut r = 0.0;
    while i > 0 {
        f /= base as f64;
        r += f * (i % base) as f64;
        i /= base;
    }
    r
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::tolerance::Tolerance;

    #[test]
    fn rigid_round_trip_and_box_hits() {
        let xf = Rigid::new(
            rotation(DVec3::new(1.0, 2.0, 3.0), 0.7),
            DVec3::new(4.0, -1.0, 2.0),
        );
        let ray = Ray {
            origin: DVec3::new(0.3, 0.1, -5.0),
            dir: DVec3::new(0.1, 0.2, 1.0).normalize(),
        };
        let local = xf.ray_to_local(&ray);
        let t = Tolerance::abs(1e-12);
        for k in [0.0, 1.0, 7.5] {
            let a = xf.point(local.at(k));
            let b = ray.at(k);
            t.check("x", a.x, b.x).unwrap();
            t.check("z", a.z, b.z).unwrap();
        }
        let b = Aabb {
            min: DVec3::splat(-1.0),
            max: DVec3::splat(1.0),
        };
        let r = Ray {
            origin: DVec3::new(0.0, 0.0, -3.0),
            dir: DVec3::Z,
        };
        t.check("entry", b.hit(&r, r.dir.recip(), 10.0).unwrap(), 2.0)
            .unwrap();
        assert!(b.hit(&r, r.dir.recip(), 1.5).is_none());
    }

    #[test]
    fn halton_values() {
        assert_eq!(radical_inverse(1, 2), 0.5);
        assert_eq!(radical_inverse(3, 2), 0.75);
        Tolerance::abs(1e-15)
            .check("h3(2)", radical_inverse(2, 3), 2.0 / 3.0)
            .unwrap();
        Tolerance::abs(1e-15)
            .check("h3(4)", radical_inverse(4, 3), 4.0 / 9.0)
            .unwrap();
    }
}
