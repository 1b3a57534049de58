//! Ray casting one instant of a scene: visibility, shading, exact motion, and the frame
//! assembly (G-buffer from one jittered sample, reference from N x N samples).

use super::bvh::Bvh;
use super::camera::{Camera, Projected, RayGen};
use super::material::Pattern;
use super::math::{radical_inverse, Aabb, Ray, Rigid};
use super::shapes::{Face, LocalHit};
use super::{SceneDef, Settings};
use crate::frame::{ChannelKind, Frame, FrameMeta, Plane, Sampling};
use crate::rng::SplitMix64;
use glam::DVec3;
use rayon::prelude::*;

mod reference;

/// Depth written for sky pixels (also the far plane in the frame values): far beyond
/// every scene, finite so that depth arithmetic in filters stays finite.
pub const SKY_DEPTH: f64 = 1000.0;

/// Motion written for a point that was behind the camera in the previous frame: far off
/// screen in both axes, so that every filter treats it as "reprojects off screen".
pub const BEHIND_CAMERA_MOTION: f32 = -1.0e4;

/// Offset of shadow-ray origins along the normal, against self-intersection.
const SHADOW_EPSILON: f64 = 1e-6;

/// Everything about one instant: placed objects, their BVH, the camera, the sun.
pub struct Instant<'a> {
    def: &'a SceneDef,
    xf: Vec<Rigid>,
    /// World bounds of each object (None: an infinite plane).
    bounds: Vec<Option<Aabb>>,
    bvh: Bvh,
    planes: Vec<usize>,
    /// The camera.
    pub camera: Camera,
    sun: DVec3,
}

/// A surface hit in world terms.
#[derive(Clone, Copy, Debug)]
pub struct Hit {
    /// Index of the object.
    pub object: usize,
    /// Hit in the object's local frame.
    pub local: LocalHit,
    /// The hit point in the object's local coordinates.
    pub local_point: DVec3,
    /// Texture coordinates of the hit (zero on a solid-coloured material, which reads
    /// none).
    pub uv: glam::DVec2,
    /// World normal.
    pub normal: DVec3,
}

/// What one camera sample sees.
#[derive(Clone, Copy, Debug)]
pub struct Sample {
    /// Shaded linear colour.
    pub color: DVec3,
    /// Planar depth ([`SKY_DEPTH`] for sky).
    pub depth: f64,
    /// World normal (zero for sky).
    pub normal: DVec3,
    /// Object id (0 for sky).
    pub object_id: u32,
    /// Albedo (zero for sky).
    pub albedo: DVec3,
    /// Where the seen point was in the previous frame (None: behind the camera then).
    pub prev: Option<Projected>,
    /// Where it will be in the next frame (None: behind the camera then).
    pub next: Option<Projected>,
}

impl<'a> Instant<'a> {
    /// The scene at time `t`.
    pub fn new(def: &'a SceneDef, t: f64) -> Instant<'a> {
        let xf: Vec<Rigid> = def.objects.iter().map(|o| (o.motion)(t)).collect();
        let bounds: Vec<Option<Aabb>> = (def.objects.iter().zip(&xf))
            .map(|(o, xf)| o.shape.bounds().map(|b| b.transformed(xf)))
            .collect();
        let mut finite = Vec::new();
        let mut planes = Vec::new();
        for (i, b) in bounds.iter().enumerate() {
            match b {
                Some(b) => finite.push((i, *b)),
                None => planes.push(i),
            }
        }
        Instant {
            def,
            bounds,
            bvh: Bvh::build(&finite),
            planes,
            xf,
            camera: (def.camera)(t),
            sun: (def.sun)(t).normalize(),
        }
    }

    /// The object transforms at this instant.
    pub fn transform(&self, object: usize) -> &Rigid {
        &self.xf[object]
    }

    /// The finite primitives that a beam bounded by four corner rays (in order around
    /// the beam) may hit, into `out` (cleared first).
    pub fn beam_candidates(&self, corners: &[Ray; 4], out: &mut Vec<usize>) {
        out.clear();
        let centre = corners.iter().fold(DVec3::ZERO, |a, r| a + r.origin + r.dir) / 4.0;
        let planes: [(DVec3, DVec3); 4] = std::array::from_fn(|i| {
            let (a, b) = (&corners[i], &corners[(i + 1) % 4]);
            let n = a.dir.cross(b.origin + b.dir - a.origin);
            let n = if n.dot(centre - a.origin) < 0.0 { -n } else { n };
            (a.origin, n)
        });
        self.bvh.collect_in_beam(&planes, out);
    }

    /// The surface details of the nearest hit `best` of `ray`.
    #[inline(always)]
    fn finish_hit(&self, ray: &Ray, best: Option<Nearest>) -> Option<Hit> {
        best.map(|nearest| self.finish(ray, nearest))
    }

    /// The surface details of `nearest`, the nearest hit of `ray`.
    #[inline(always)]
    fn finish(&self, ray: &Ray, Nearest { object, t, face }: Nearest) -> Hit {
        let object = object as usize;
        let shape = &self.def.objects[object].shape;
        let local_point = self.xf[object].ray_to_local(ray).at(t);
        let normal = shape.normal(face, local_point);
        Hit {
            object,
            local: LocalHit { t, normal },
            local_point,
            // A solid colour reads no texture coordinates (and a sphere's cost two
            // inverse trigonometric calls).
            uv: match self.def.objects[object].material.pattern {
                Pattern::Solid => glam::DVec2::ZERO,
                _ => shape.uv(local_point, normal),
            },
            normal: self.xf[object].vector(normal),
        }
    }

    /// The nearest hit along `ray` before `t_max`.
    pub fn intersect(&self, ray: &Ray, t_max: f64) -> Option<Hit> {
        let mut best: Option<Nearest> = None;
        let mut test = |i: usize, t_max: f64| -> f64 {
            let local = self.xf[i].ray_to_local(ray);
            match self.def.objects[i].shape.hit(&local, 0.0, t_max) {
                Some((t, face)) => {
                    best = Some(Nearest {
                        object: i as u32,
                        t,
                        face,
                    });
                    t
                }
                None => t_max,
            }
        };
        let mut t = t_max;
        for &i in &self.planes {
            t = test(i, t);
        }
        self.bvh.walk(ray, t, &mut test);
        self.finish_hit(ray, best)
    }

    /// The primitives (planes included) that may shadow any point of the box `lo..hi`
    /// from the sun's centre direction, into `out` (cleared first). Empty when nothing
    /// can: the shading of such a pixel casts no shadow rays at all.
    pub fn shadow_candidates(&self, lo: DVec3, hi: DVec3, out: &mut Vec<usize>) {
        out.clear();
        if !lo.cmple(hi).all() {
            return;
        }
        // Shadow rays start up to this far from the hit points (see `Instant::surface`).
        let margin = SHADOW_EPSILON * (1.0 + lo.abs().max(hi.abs()).max_element()) + SHADOW_EPSILON;
        let (lo, hi) = (lo - margin, hi + margin);
        for &i in &self.planes {
            // A ray from p towards the sun meets the plane iff p is on the side facing
            // away from the sun: the signed distance (p - T).N and sun.N differ in sign.
            // It is linear in p, so the box's corners decide. Kept when in doubt.
            let n = self.xf[i].vector(DVec3::Y);
            let towards = n.dot(self.sun);
            let origin = self.xf[i].point(DVec3::ZERO);
            let clear = towards.abs() > 1e-12
                && (0..8).all(|k| {
                    let c = DVec3::new(
                        if k & 1 == 0 { lo.x } else { hi.x },
                        if k & 2 == 0 { lo.y } else { hi.y },
                        if k & 4 == 0 { lo.z } else { hi.z },
                    );
                    (c - origin).dot(n) * towards.signum() > 1e-9
                });
            if !clear {
                out.push(i);
            }
        }
        self.bvh
            .collect_swept((lo + hi) * 0.5, (hi - lo) * 0.5, self.sun, out);
    }

    /// Whether anything but object `skip` blocks `ray` before `t_max`. (A shadow ray
    /// leaving a convex primitive on its lit side cannot hit that primitive again, and
    /// every primitive here is convex.)
    pub fn occluded(&self, ray: &Ray, t_max: f64, skip: usize) -> bool {
        let mut blocked = false;
        let mut test = |i: usize, t_max: f64| -> f64 {
            if i == skip {
                return t_max;
            }
            let local = self.xf[i].ray_to_local(ray);
            if self.def.objects[i].shape.hit(&local, 0.0, t_max).is_some() {
                blocked = true;
                -1.0
            } else {
                t_max
            }
        };
        for &i in &self.planes {
            if test(i, t_max) < 0.0 {
                return true;
            }
        }
        self.bvh.walk(ray, t_max, &mut test);
        blocked
    }

    /// Distance fog towards the horizon colour (none when the scene has no fog).
    #[inline(always)]
    fn fog(&self, c: DVec3, distance: f64) -> DVec3 {
        match self.def.fog_distance {
            Some(f) => {
                let h = self.def.sky_horizon;
                h + (c - h) * (-distance / f).exp()
            }
            None => c,
        }
    }

    #[inline(always)]
    fn sky(&self, dir: DVec3) -> DVec3 {
        let (top, horizon) = (self.def.sky_top, self.def.sky_horizon);
        horizon + (top - horizon) * dir.y.max(0.0)
    }

    /// Direction towards the sun, or a point of the sun's disc for `light` in [0,1)^2
    /// (uniform over the cone of the disc's angular radius).
    #[inline(always)]
    fn sun_direction(&self, light: Option<(f64, f64)>) -> DVec3 {
        let Some((u, v)) = light else { return self.sun };
        let cos_max = self.def.sun_angular_radius.cos();
        let cos_t = 1.0 - u * (1.0 - cos_max);
        let sin_t = (1.0 - cos_t * cos_t).max(0.0).sqrt();
        let phi = 2.0 * std::f64::consts::PI * v;
        let w = self.sun;
        let a = if w.x.abs() > 0.9 { DVec3::Y } else { DVec3::X };
        let t1 = w.cross(a).normalize();
        let t2 = w.cross(t1);
        (w * cos_t + (t1 * phi.cos() + t2 * phi.sin()) * sin_t).normalize()
    }

    /// Colour seen along `ray`; `light` picks a point of the sun's disc (None: its
    /// centre, hard shadows).
    pub fn shade(&self, ray: &Ray, hit: Option<&Hit>, light: Option<(f64, f64)>) -> DVec3 {
        let Some(hit) = hit else { return self.sky(ray.dir) };
        let l = self.sun_direction(light);
        let (surface, shadow) = self.surface(ray, hit, l);
        let blocked = shadow.is_some_and(|r| self.occluded(&r, f64::INFINITY, hit.object));
        self.lit_colour(ray, hit.object, hit.local.t, &surface, blocked)
    }

    /// The first half of [`Instant::shade`] for a hit lit from direction `l`:
    /// everything before the shadow ray, and that ray (None when the sun cannot light the
    /// point, so that no ray is cast).
    #[inline(always)]
    fn surface(&self, ray: &Ray, hit: &Hit, l: DVec3) -> (Surface, Option<Ray>) {
        let m = &self.def.objects[hit.object].material;
        let mut n = hit.normal;
        if n.dot(ray.dir) > 0.0 {
            n = -n; // back faces (inside a box seen through a gap) shade like front faces
        }
        let albedo = m.albedo(hit.uv);
        let unlit = m.emission + albedo * self.def.ambient;
        let ndl = n.dot(l);
        let shadow = (ndl > 0.0 && self.def.sun_irradiance.max_element() > 0.0).then(|| {
            let at = ray.at(hit.local.t);
            let p = at + n * SHADOW_EPSILON * (1.0 + at.abs().max_element());
            Ray { origin: p, dir: l }
        });
        let surface = Surface {
            n,
            albedo,
            unlit,
            ndl,
            l,
            lit: shadow.is_some(),
        };
        (surface, shadow)
    }

    /// The second half of [`Instant::shade`]: the colour of `surface` given whether
    /// its shadow ray was `blocked`, for a hit of `object` at ray parameter `t`.
    #[inline(always)]
    fn lit_colour(&self, ray: &Ray, object: usize, t: f64, surface: &Surface, blocked: bool) -> DVec3 {
        let mut c = surface.unlit;
        if surface.lit && !blocked {
            let m = &self.def.objects[object].material;
            c += surface.albedo * self.def.sun_irradiance * surface.ndl;
            if m.specular > 0.0 {
                let h = (surface.l - ray.dir).normalize();
                c += self.def.sun_irradiance * m.specular * surface.n.dot(h).max(0.0).powf(m.shininess);
            }
        }
        self.fog(c, t)
    }

    /// The full sample through image position `(x, y)` of a `w x h` image, with motion
    /// against the instants `prev` and `next`.
    #[allow(clippy::too_many_arguments)]
    pub fn sample(
        &self,
        prev: &Instant,
        next: &Instant,
        x: f64,
        y: f64,
        w: usize,
        h: usize,
        light: Option<(f64, f64)>,
    ) -> Sample {
        let ray = self.camera.ray(x, y, w, h);
        let hit = self.intersect(&ray, f64::INFINITY);
        let color = self.shade(&ray, hit.as_ref(), light);
        match hit {
            None => Sample {
                color,
                depth: SKY_DEPTH,
                normal: DVec3::ZERO,
                object_id: 0,
                albedo: DVec3::ZERO,
                prev: prev.camera.project_sky(&ray, SKY_DEPTH, w, h),
                next: next.camera.project_sky(&ray, SKY_DEPTH, w, h),
            },
            Some(hit) => {
                let o = &self.def.objects[hit.object];
                let world = ray.at(hit.local.t);
                let fwd = DVec3::from_array(self.camera.forward);
                let was = prev.transform(hit.object).point(hit.local_point);
                let will = next.transform(hit.object).point(hit.local_point);
                Sample {
                    color,
                    depth: (world - DVec3::from_array(self.camera.position)).dot(fwd),
                    normal: hit.normal,
                    object_id: o.id,
                    albedo: o.material.albedo(hit.uv),
                    prev: prev.camera.project(was, w, h),
                    next: next.camera.project(will, w, h),
                }
            }
        }
    }
}

/// Halton(2,3) jitter of frame `index` with `phases` phases, in [-0.5, 0.5)^2.
pub fn halton_jitter(index: u64, phases: u32) -> [f32; 2] {
    let i = index % phases as u64 + 1;
    [
        (radical_inverse(i, 2) - 0.5) as f32,
        (radical_inverse(i, 3) - 0.5) as f32,
    ]
}

fn pixel_seed(seed: u64, frame: u64, x: usize, y: usize) -> u64 {
    let mut r = SplitMix64::new(seed ^ frame.wrapping_mul(0x9E37_79B9_7F4A_7C15));
    let a = r.next_u64();
    SplitMix64::new(a ^ ((y as u64) << 32 | x as u64)).next_u64()
}

#[derive(Clone, Copy, Default)]
struct Pixel {
    color: [f32; 3],
    depth: f32,
    motion: [f32; 2],
    motion_next: [f32; 2],
    normal: [f32; 3],
    id: u32,
    albedo: [f32; 3],
    reference: [f32; 3],
}

/// A hit's shading before its shadow ray (see [`Instant::surface`]).
#[derive(Clone, Copy, Debug, Default)]
struct Surface {
    /// Normal facing the viewer.
    n: DVec3,
    albedo: DVec3,
    /// Emission plus ambient: the colour in shadow, before fog.
    unlit: DVec3,
    /// Cosine between the normal and the light.
    ndl: f64,
    /// Direction towards the light.
    l: DVec3,
    /// Whether the sun may light the point (it casts a shadow ray).
    lit: bool,
}

/// The nearest hit of a ray before its surface details (see [`Instant::finish_hit`]).
#[derive(Clone, Copy, Debug)]
struct Nearest {
    object: u32,
    t: f64,
    face: Face,
}

/// The corner rays of the pixel whose top-left corner is `(x0, y0)`, in order around it
/// (the beam for [`Instant::beam_candidates`]).
fn pixel_beam(rays: &RayGen, x0: f64, y0: f64) -> [Ray; 4] {
    [(x0, y0), (x0 + 1.0, y0), (x0 + 1.0, y0 + 1.0), (x0, y0 + 1.0)].map(|(x, y)| rays.ray(x, y))
}

fn f3(v: DVec3) -> [f32; 3] {
    [v.x as f32, v.y as f32, v.z as f32]
}

/// Renders frame `index` of `def` under `settings`.
pub fn render(def: &SceneDef, settings: &Settings, index: u64) -> Frame {
    let (w, h) = (settings.width, settings.height);
    let t = index as f64;
    let now = Instant::new(def, t);
    let before = Instant::new(def, t - 1.0);
    let after = Instant::new(def, t + 1.0);
    let jitter = settings.jitter.offset(index);
    let n = settings.reference_grid() as usize;
    let rays = now.camera.rays(w, h);
    let rows: Vec<Vec<Pixel>> = (0..h)
        .into_par_iter()
        .map(|py| {
            let mut scratch = reference::Scratch::default();
            (0..w)
                .map(|px| {
                    let mut rng = SplitMix64::new(pixel_seed(settings.seed, index, px, py));
                    let light = settings.noise.then(|| (rng.next_f64(), rng.next_f64()));
                    let (sx, sy) = (
                        px as f64 + 0.5 + jitter[0] as f64,
                        py as f64 + 0.5 + jitter[1] as f64,
                    );
                    let s = now.sample(&before, &after, sx, sy, w, h, light);
                    let offset = |p: Option<Projected>| match p {
                        Some(p) => [(p.x - sx) as f32, (p.y - sy) as f32],
                        None => [BEHIND_CAMERA_MOTION; 2],
                    };
                    let (motion, motion_next) = (offset(s.prev), offset(s.next));
                    // The reference's rotation of the sun-disc samples depends on the pixel
                    // only, so a still scene has the same reference in every frame.
                    let mut still = SplitMix64::new(pixel_seed(settings.seed, u64::MAX, px, py));
                    let (ru, rv) = (still.next_f64(), still.next_f64());
                    let reference = now.reference(
                        &rays,
                        px,
                        py,
                        n,
                        &mut still,
                        settings.noise,
                        (ru, rv),
                        &mut scratch,
                    );
                    Pixel {
                        color: f3(s.color),
                        depth: s.depth as f32,
                        motion,
                        motion_next,
                        normal: f3(s.normal),
                        id: s.object_id,
                        albedo: f3(s.albedo),
                        reference: f3(reference),
                    }
                })
                .collect()
        })
        .collect();
    let pixels: Vec<Pixel> = rows.into_iter().flatten().collect();
    let plane = |f: &dyn Fn(&Pixel) -> f32| -> Plane<f32> {
        Plane::from_vec(w, h, pixels.iter().map(f).collect()).expect("w x h pixels")
    };
    let rgb = |f: &dyn Fn(&Pixel) -> [f32; 3]| -> Vec<Plane<f32>> {
        (0..3).map(|c| plane(&|p: &Pixel| f(p)[c])).collect()
    };
    let color: [Plane<f32>; 3] = rgb(&|p| p.color).try_into().expect("three planes");
    // Sparse shading keeps the samples of this frame's pattern (the others were traced
    // for the G-buffer anyway, which is full resolution).
    let sampling = Sampling::rotating(settings.shading, index);
    let mut frame = if sampling.is_full() {
        Frame::new(color).expect("non-empty")
    } else {
        let sparse = Frame::gather(&color, sampling).expect("validated factor");
        Frame::subsampled(sparse, w, h, sampling).expect("gathered at the pattern's size")
    };
    let set = |frame: &mut Frame, k, planes| frame.set_f32(k, planes).expect("sizes match");
    set(&mut frame, ChannelKind::Depth, vec![plane(&|p| p.depth)]);
    set(
        &mut frame,
        ChannelKind::Motion,
        vec![plane(&|p| p.motion[0]), plane(&|p| p.motion[1])],
    );
    set(
        &mut frame,
        ChannelKind::MotionNext,
        vec![plane(&|p| p.motion_next[0]), plane(&|p| p.motion_next[1])],
    );
    set(&mut frame, ChannelKind::Normal, rgb(&|p| p.normal));
    set(&mut frame, ChannelKind::Albedo, rgb(&|p| p.albedo));
    set(&mut frame, ChannelKind::Reference, rgb(&|p| p.reference));
    frame
        .set_object_id(Plane::from_vec(w, h, pixels.iter().map(|p| p.id).collect()).expect("w x h"))
        .expect("sizes match");
    frame.meta = FrameMeta {
        index,
        jitter,
        reset: def.cut_at == Some(index),
        exposure: None,
        near_far: None,
        depth_kind: crate::frame::DepthKind::Linear,
        normal_space: crate::frame::NormalSpace::World,
    };
    frame
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::{Scene, CATALOGUE};

    /// The batched reference (beam candidates for visibility, swept candidates and the
    /// plane test for shadows, shared local origins and directions, one loop per primitive)
    /// changes nothing: every pixel of every scene, with and without noise, has the same
    /// bits as the mean of [`Instant::shade`] over [`Instant::intersect`] of the same
    /// sample rays, the unbatched queries that test every primitive.
    #[test]
    fn batched_reference_is_exact() {
        let (w, h, n) = (48usize, 27usize, 5usize);
        for entry in CATALOGUE {
            let settings = Settings {
                width: w,
                height: h,
                ..Settings::default()
            };
            let scene = Scene::new(entry.name, settings).unwrap();
            for (t, noise) in [(0.0, false), (7.0, false), (3.0, true)] {
                let now = scene.instant(t);
                let rays = now.camera.rays(w, h);
                let mut scratch = reference::Scratch::default();
                let mut shadowed = 0;
                for py in 0..h {
                    for px in 0..w {
                        let seed = pixel_seed(11, 3, px, py);
                        let rotation = (0.3, 0.8);
                        let batched = now.reference(
                            &rays,
                            px,
                            py,
                            n,
                            &mut SplitMix64::new(seed),
                            noise,
                            rotation,
                            &mut scratch,
                        );
                        let mut rng = SplitMix64::new(seed);
                        let mut sum = DVec3::ZERO;
                        for k in 0..n * n {
                            let (i, j) = (k % n, k / n);
                            let (u, v) = (rng.next_f64(), rng.next_f64());
                            let (x, y) = (
                                px as f64 + (i as f64 + u) / n as f64,
                                py as f64 + (j as f64 + v) / n as f64,
                            );
                            let ray = rays.ray(x, y);
                            let hit = now.intersect(&ray, f64::INFINITY);
                            let q = k as u64 + 1;
                            let light = noise.then(|| {
                                (
                                    (radical_inverse(q, 2) + rotation.0).fract(),
                                    (radical_inverse(q, 3) + rotation.1).fract(),
                                )
                            });
                            sum += now.shade(&ray, hit.as_ref(), light);
                            if let Some(hit) = &hit {
                                let at = ray.at(hit.local.t);
                                let shadow_ray = Ray {
                                    origin: at + hit.normal * 1e-3,
                                    dir: now.sun,
                                };
                                let lit = now.sun.dot(hit.normal) > 0.0;
                                shadowed +=
                                    (lit && now.occluded(&shadow_ray, f64::INFINITY, hit.object)) as usize;
                            }
                        }
                        let scalar = sum / (n * n) as f64;
                        assert_eq!(
                            batched.to_array().map(f64::to_bits),
                            scalar.to_array().map(f64::to_bits),
                            "{} t={t} noise={noise} pixel ({px},{py}): batched {batched} vs scalar {scalar}",
                            entry.name
                        );
                    }
                }
                // Lit scenes have shadows to get right, so the comparison above meant something.
                if now.def.sun_irradiance.max_element() > 0.0 && entry.name != "thin-line" {
                    assert!(shadowed > 0, "{}: no shadowed sample at t={t}", entry.name);
                }
            }
        }
    }
}
