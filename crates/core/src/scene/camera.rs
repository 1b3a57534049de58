//! Pinhole perspective and orthographic cameras.

use super::math::Ray;
use glam::DVec3;
use serde::Serialize;

/// How a camera projects.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Projection {
    /// Pinhole with a vertical field of view in radians.
    Perspective {
        /// Vertical field of view, radians.
        fov_y: f64,
    },
    /// Parallel projection showing `height` world units vertically.
    Orthographic {
        /// World units across the image height.
        height: f64,
    },
}

/// A camera pose and projection. Looks along `forward`; `right` and `up` span the image
/// plane (x right, y up in world terms; image rows grow downwards).
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Camera {
    /// Centre of projection (or of the image plane, for orthographic).
    pub position: [f64; 3],
    /// Unit right vector.
    pub right: [f64; 3],
    /// Unit up vector.
    pub up: [f64; 3],
    /// Unit viewing direction.
    pub forward: [f64; 3],
    /// Projection.
    pub projection: Projection,
}

/// Where a world point lands in an image.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Projected {
    /// Column, pixel units from the left edge (pixel centres at +0.5).
    pub x: f64,
    /// Row, pixel units from the top edge.
    pub y: f64,
    /// Planar depth along the viewing direction.
    pub depth: f64,
}

/// Rays of one camera for one image size.
#[derive(Clone, Copy, Debug)]
pub struct RayGen {
    pos: DVec3,
    forward: DVec3,
    /// World step per pixel to the right.
    right: DVec3,
    /// World step per pixel up.
    up: DVec3,
    /// Offset of the top-left image corner from the centre.
    corner: DVec3,
    perspective: bool,
}

impl RayGen {
    /// Whether every ray starts at the camera position (perspective) rather than on the
    /// image plane (orthographic).
    pub fn perspective(&self) -> bool {
        self.perspective
    }

    /// The ray through image position `(x, y)`.
    #[inline]
    pub fn ray(&self, x: f64, y: f64) -> Ray {
        let offset = self.corner + self.right * x - self.up * y;
        if self.perspective {
            Ray {
                origin: self.pos,
                dir: (self.forward + offset).normalize(),
            }
        } else {
            Ray {
                origin: self.pos + offset,
                dir: self.forward,
            }
        }
    }
}

impl Camera {
    /// A camera at `position` looking at `target`, with `up_hint` roughly up.
    pub fn look_at(position: DVec3, target: DVec3, up_hint: DVec3, projection: Projection) -> Camera {
        let forward = (target - position).normalize();
        let right = forward.cross(up_hint).normalize();
        let up = right.cross(forward);
        Camera {
            position: position.to_array(),
            right: right.to_array(),
            up: up.to_array(),
            forward: forward.to_array(),
            projection,
        }
    }

    fn basis(&self) -> (DVec3, DVec3, DVec3, DVec3) {
        (
            DVec3::from_array(self.position),
            DVec3::from_array(self.right),
            DVec3::from_array(self.up),
            DVec3::from_array(self.forward),
        )
    }

    /// Half extents of the image plane at distance 1 (perspective) or in world units
    /// (orthographic).
    fn half_extent(&self, w: usize, h: usize) -> (f64, f64) {
        let aspect = w as f64 / h as f64;
        let hy = match self.projection {
            Projection::Perspective { fov_y } => (fov_y * 0.5).tan(),
            Projection::Orthographic { height } => height * 0.5,
        };
        (hy * aspect, hy)
    }

    /// The ray through image position `(x, y)` (pixel units from the top-left corner) of
    /// a `w x h` image.
    pub fn ray(&self, x: f64, y: f64, w: usize, h: usize) -> Ray {
        self.rays(w, h).ray(x, y)
    }

    /// A ray generator for a `w x h` image (the per-image constants computed once).
    pub fn rays(&self, w: usize, h: usize) -> RayGen {
        let (pos, right, up, forward) = self.basis();
        let (hx, hy) = self.half_extent(w, h);
        RayGen {
            pos,
            forward,
            right: right * (2.0 * hx / w as f64),
            up: up * (2.0 * hy / h as f64),
            corner: -right * hx + up * hy,
            perspective: matches!(self.projection, Projection::Perspective { .. }),
        }
    }

    /// Projects a world point; None when it is behind a perspective camera.
    pub fn project(&self, p: DVec3, w: usize, h: usize) -> Option<Projected> {
        let (pos, right, up, forward) = self.basis();
        let (hx, hy) = self.half_extent(w, h);
        let c = p - pos;
        let depth = c.dot(forward);
        let (sx, sy) = match self.projection {
            Projection::Perspective { .. } => {
                if depth <= 1e-9 {
                    return None;
                }
                (c.dot(right) / depth, c.dot(up) / depth)
            }
            Projection::Orthographic { .. } => (c.dot(right), c.dot(up)),
        };
        Some(Projected {
            x: (sx / hx + 1.0) * 0.5 * w as f64,
            y: (1.0 - sy / hy) * 0.5 * h as f64,
            depth,
        })
    }

    /// Where a direction at infinity lands (perspective), or the point `far` along the
    /// ray (orthographic): the camera-only motion of the sky.
    pub fn project_sky(&self, ray: &Ray, far: f64, w: usize, h: usize) -> Option<Projected> {
        match self.projection {
            Projection::Perspective { .. } => {
                let pos = DVec3::from_array(self.position);
                self.project(pos + ray.dir, w, h)
                    .map(|p| Projected { depth: far, ..p })
            }
            Projection::Orthographic { .. } => self.project(ray.at(far), w, h),
        }
    }

    /// World units per pixel vertically (orthographic only).
    pub fn world_per_pixel(&self, h: usize) -> Option<f64> {
        match self.projection {
            Projection::Orthographic { height } => Some(height / h as f64),
            Projection::Perspective { .. } => None,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::tolerance::Tolerance;

    #[test]
    fn rays_and_projection_are_inverse() {
        let t = Tolerance::abs(1e-9);
        for projection in [
            Projection::Perspective { fov_y: 0.9 },
            Projection::Orthographic { height: 4.0 },
        ] {
            let cam = Camera::look_at(
                DVec3::new(1.0, 2.0, 3.0),
                DVec3::new(0.0, 0.5, -2.0),
                DVec3::Y,
                projection,
            );
            for (x, y) in [(0.5, 0.5), (100.25, 31.75), (63.9, 0.1)] {
                let r = cam.ray(x, y, 128, 72);
                let p = cam.project(r.at(5.0), 128, 72).unwrap();
                t.check("x", p.x, x).unwrap();
                t.check("y", p.y, y).unwrap();
            }
        }
    }
}
