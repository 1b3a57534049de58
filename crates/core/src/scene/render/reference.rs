//! The reference of one pixel: N x N jittered-stratified samples over the pixel box, each
//! shaded exactly as [`Instant::shade`] shades it (same arithmetic, same bits; tested), but
//! batched. Each primitive is tested against all the samples of the pixel in one loop, with
//! no dispatch per ray and the shared part of the ray transformed once: a perspective
//! camera's rays share their origin, an orthographic camera's their direction, and the
//! shadow rays of a pixel without noise all leave towards the sun's centre.

use super::{pixel_beam, Instant, Nearest, Surface};
use crate::rng::SplitMix64;
use crate::scene::camera::RayGen;
use crate::scene::math::{radical_inverse, Ray, Rigid};
use crate::scene::shapes::{hit_cuboid, hit_cylinder, hit_plane, hit_sphere, Face, Shape};
use glam::DVec3;

/// `Scratch::object` of a sample that hit nothing.
const MISS: u32 = u32::MAX;

/// Buffers of one pixel's samples, reused from pixel to pixel.
#[derive(Default)]
pub(super) struct Scratch {
    candidates: Vec<usize>,
    shadow_candidates: Vec<usize>,
    rays: Vec<Ray>,
    t: Vec<f64>,
    object: Vec<u32>,
    face: Vec<Face>,
    /// Per sample: the hit's surface (a default one for the sky).
    surface: Vec<Surface>,
    blocked: Vec<bool>,
    /// The samples with a shadow ray, and those rays.
    lit: Vec<usize>,
    shadow_rays: Vec<Ray>,
}

/// Which part of a batch of rays is shared (see [`for_each_local`]).
#[derive(Clone, Copy)]
enum Shared {
    /// Every ray starts at the first one's origin.
    Origin,
    /// Every ray has the first one's direction.
    Dir,
}

/// Calls `f(k, local ray k)` for every ray of `rays` taken into the frame of `xf`,
/// transforming the shared part once. The local rays are bit-identical to
/// [`Rigid::ray_to_local`]'s.
#[inline(always)]
fn for_each_local(xf: &Rigid, rays: &[Ray], shared: Shared, mut f: impl FnMut(usize, &Ray)) {
    let Some(first) = rays.first() else { return };
    match shared {
        Shared::Origin => {
            let origin = xf.point_to_local(first.origin);
            for (k, r) in rays.iter().enumerate() {
                f(k, &xf.ray_to_local_from(origin, r));
            }
        }
        Shared::Dir => {
            let dir = xf.vector_to_local(first.dir);
            for (k, r) in rays.iter().enumerate() {
                f(
                    k,
                    &Ray {
                        origin: xf.point_to_local(r.origin),
                        dir,
                    },
                );
            }
        }
    }
}

/// Runs `$body` for every ray of `$rays` in the frame of `$xf`, with `$k` the ray's index
/// and `$hit(t_max)` the shape's [`Shape::hit`] of it: one monomorphised loop per kind of
/// shape (a macro, because the body calls a closure generic over the shape).
macro_rules! batch {
    ($shape:expr, $xf:expr, $rays:expr, $shared:expr, |$k:ident, $hit:ident| $body:expr) => {
        match $shape {
            Shape::Plane => for_each_local($xf, $rays, $shared, |$k, r| {
                let $hit = |t_max: f64| hit_plane(r, 0.0, t_max);
                $body
            }),
            Shape::Sphere { radius } => for_each_local($xf, $rays, $shared, |$k, r| {
                let $hit = |t_max: f64| hit_sphere(radius, r, 0.0, t_max);
                $body
            }),
            Shape::Cuboid { half } => for_each_local($xf, $rays, $shared, |$k, r| {
                let $hit = |t_max: f64| hit_cuboid(half, r, 0.0, t_max);
                $body
            }),
            Shape::Cylinder { radius, half_height } => for_each_local($xf, $rays, $shared, |$k, r| {
                let $hit = |t_max: f64| hit_cylinder(radius, half_height, r, 0.0, t_max);
                $body
            }),
        }
    };
}

/// Relative margin of the occluding-face test in [`Instant::pixel_candidates`]: corner hits
/// this close to the face's edge, and primitives this close to the region in front of it,
/// count as "maybe" (far above the rounding of the sample rays, about 1e-16).
const FACE_MARGIN: f64 = 1e-9;

/// When `face` of `shape` (hit at the local point `p`) is planar and `p` lies inside it
/// by [`FACE_MARGIN`], the side of the face's plane (the sign along its normal axis; 0 for
/// a plane); None otherwise (a sphere, a cylinder's side, a hit near an edge).
fn planar_face(shape: Shape, face: Face, p: DVec3) -> Option<f64> {
    match shape {
        Shape::Plane => Some(0.0),
        Shape::Sphere { .. } => None,
        Shape::Cuboid { half } => {
            let axis = face.axis();
            let inside = (0..3)
                .filter(|&a| a != axis)
                .all(|a| p[a].abs() < half[a] * (1.0 - FACE_MARGIN));
            inside.then(|| p[axis].signum())
        }
        Shape::Cylinder { radius, .. } => (face.is_cap()
            && p.x * p.x + p.z * p.z < radius * radius * (1.0 - FACE_MARGIN))
            .then(|| p.y.signum()),
    }
}

impl Instant<'_> {
    /// The finite primitives that may be the nearest hit of a ray through the pixel
    /// whose top-left corner is `(x0, y0)`, into `out` (cleared first): the beam's
    /// candidates, less those that a planar face hiding the whole pixel puts out of reach.
    ///
    /// When the four corner rays all meet the same planar face of a convex primitive
    /// (a plane, a box's face, a cylinder's cap), every ray of the beam meets that face
    /// (the face is convex and holds the four hits), so nothing beyond it matters: the
    /// part of the beam in front of it is the hull of the corners' origins and hits, and a
    /// primitive whose bounds miss that hull's box is dropped. Exact: the batched
    /// reference is checked against unculled queries (`batched_reference_is_exact`).
    fn pixel_candidates(&self, rays: &RayGen, x0: f64, y0: f64, out: &mut Vec<usize>) {
        let corners = pixel_beam(rays, x0, y0);
        self.beam_candidates(&corners, out);
        // Each corner's nearest hit among the candidates: object, parameter, face and
        // local point.
        let mut first: Option<(usize, Face, f64)> = None;
        let (mut lo, mut hi) = (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY));
        for ray in &corners {
            let mut best: Option<(usize, f64, Face)> = None;
            let mut t = f64::INFINITY;
            for &i in self.planes.iter().chain(out.iter()) {
                let local = self.xf[i].ray_to_local(ray);
                if let Some((ht, face)) = self.def.objects[i].shape.hit(&local, 0.0, t) {
                    t = ht;
                    best = Some((i, ht, face));
                }
            }
            let Some((object, t, face)) = best else { return };
            let p = self.xf[object].ray_to_local(ray).at(t);
            let Some(side) = planar_face(self.def.objects[object].shape, face, p) else {
                return;
            };
            match first {
                None => first = Some((object, face, side)),
                Some(f) if f == (object, face, side) => {}
                Some(_) => return,
            }
            for q in [ray.origin, ray.at(t)] {
                lo = lo.min(q);
                hi = hi.max(q);
            }
        }
        let Some((object, _, _)) = first else { return };
        let margin = FACE_MARGIN * (1.0 + lo.abs().max(hi.abs()).max_element());
        let (lo, hi) = (lo - margin, hi + margin);
        out.retain(|&i| {
            i == object || self.bounds[i].is_none_or(|b| b.min.cmple(hi).all() && b.max.cmpge(lo).all())
        });
    }

    /// The reference colour of pixel `(px, py)`: the mean over `n x n` jittered strata
    /// (one uniform point per cell, drawn from `still` row by row) of the shading of each
    /// sample. With `noise`, sample k (from 1) lights from the sun's disc at Halton (2,3)
    /// point k rotated by `rotation`; without, from its centre.
    #[allow(clippy::too_many_arguments)]
    pub(super) fn reference(
        &self,
        rays: &RayGen,
        px: usize,
        py: usize,
        n: usize,
        still: &mut SplitMix64,
        noise: bool,
        rotation: (f64, f64),
        s: &mut Scratch,
    ) -> DVec3 {
        let (x0, y0) = (px as f64, py as f64);
        let shared = if rays.perspective() {
            Shared::Origin
        } else {
            Shared::Dir
        };
        // Pass 1: visibility. Jittered strata leave edge errors of O(N^-1.5), a regular
        // grid O(1/N).
        s.rays.clear();
        for j in 0..n {
            for i in 0..n {
                let (u, v) = (still.next_f64(), still.next_f64());
                s.rays
                    .push(rays.ray(x0 + (i as f64 + u) / n as f64, y0 + (j as f64 + v) / n as f64));
            }
        }
        let m = s.rays.len();
        s.t.clear();
        s.t.resize(m, f64::INFINITY);
        s.object.clear();
        s.object.resize(m, MISS);
        s.face.clear();
        s.face.resize(m, Face::default());
        self.pixel_candidates(rays, x0, y0, &mut s.candidates);
        for &i in self.planes.iter().chain(&s.candidates) {
            let (t, object, face) = (&mut s.t, &mut s.object, &mut s.face);
            batch!(
                self.def.objects[i].shape,
                &self.xf[i],
                &s.rays,
                shared,
                |k, hit| {
                    if let Some((ht, f)) = hit(t[k]) {
                        t[k] = ht;
                        object[k] = i as u32;
                        face[k] = f;
                    }
                }
            );
        }
        let (mut lo, mut hi) = (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY));
        for (r, &t) in s.rays.iter().zip(&s.t) {
            if t < f64::INFINITY {
                let p = r.at(t);
                lo = lo.min(p);
                hi = hi.max(p);
            }
        }
        // Pass 2: surfaces, then shadows. Without noise every shadow ray goes to the sun's
        // centre, so one swept-box query bounds the occluders of the whole pixel and each
        // occluder sees one local direction; with noise each sample has its own point of
        // the sun's disc (Halton 2,3 with a per-pixel rotation), so the reference
        // integrates the soft shadow that the input estimates with one sample.
        s.surface.clear();
        s.lit.clear();
        s.shadow_rays.clear();
        for k in 0..m {
            if s.object[k] == MISS {
                s.surface.push(Surface::default());
                continue;
            }
            let nearest = Nearest {
                object: s.object[k],
                t: s.t[k],
                face: s.face[k],
            };
            let hit = self.finish(&s.rays[k], nearest);
            let q = k as u64 + 1;
            let light = noise.then(|| {
                (
                    (radical_inverse(q, 2) + rotation.0).fract(),
                    (radical_inverse(q, 3) + rotation.1).fract(),
                )
            });
            let (surface, shadow) = self.surface(&s.rays[k], &hit, self.sun_direction(light));
            if let Some(shadow) = shadow {
                s.lit.push(k);
                s.shadow_rays.push(shadow);
            }
            s.surface.push(surface);
        }
        s.blocked.clear();
        s.blocked.resize(m, false);
        if noise {
            for (&k, ray) in s.lit.iter().zip(&s.shadow_rays) {
                s.blocked[k] = self.occluded(ray, f64::INFINITY, s.object[k] as usize);
            }
        } else if !s.lit.is_empty() {
            self.shadow_candidates(lo, hi, &mut s.shadow_candidates);
            for &i in &s.shadow_candidates {
                let (blocked, object, lit) = (&mut s.blocked, &s.object, &s.lit);
                batch!(
                    self.def.objects[i].shape,
                    &self.xf[i],
                    &s.shadow_rays,
                    Shared::Dir,
                    |j, hit| {
                        let k = lit[j];
                        // A shadow ray never tests the primitive it leaves (as in
                        // `Instant::occluded`).
                        if !blocked[k] && object[k] as usize != i {
                            blocked[k] = hit(f64::INFINITY).is_some();
                        }
                    }
                );
            }
        }
        let mut sum = DVec3::ZERO;
        for k in 0..m {
            let r = &s.rays[k];
            sum += match s.object[k] {
                MISS => self.sky(r.dir),
                object => self.lit_colour(r, object as usize, s.t[k], &s.surface[k], s.blocked[k]),
            };
        }
        sum / m as f64
    }
}
