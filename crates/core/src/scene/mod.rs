//! Procedural test scenes with exact G-buffers and supersampled references.
//!
//! A small deterministic CPU ray caster (rayon over rows): analytic primitives, procedural
//! textures, one animated sun with hard shadows (or a sampled soft shadow with `noise`),
//! an ambient term and a sky. Per frame it writes the full G-buffer from one sample through
//! the jittered pixel position, **exact** motion (each hit point moved back by its object's
//! previous transform and projected by the previous camera; sky pixels get the camera-only
//! motion), and a reference integrating the same shading over the pixel box with N x N
//! stratified samples. Scene time is the frame number.
//!
//! The reference is most of the cost (256 shaded samples and shadow rays per pixel by
//! default), so it is evaluated in batches (`render/reference.rs`): per pixel, only the
//! primitives its beam can reach in front of a face that hides the whole pixel, each tested
//! against all the pixel's samples in one loop, and one swept-box query for the shadow
//! rays. The batched result is bit-identical to shading each sample with the unculled
//! queries (test `batched_reference_is_exact`).

mod bvh;
mod camera;
mod catalogue;
mod material;
mod math;
mod render;
mod shapes;
mod synthetic;
pub use synthetic::{synthetic_frame, synthetic_sparse_frame};

pub use camera::{Camera, Projected, Projection, RayGen};
pub use catalogue::CATALOGUE;
pub use material::{Material, Pattern};
pub use math::{Aabb, Ray, Rigid};
pub use render::{halton_jitter, Hit, Instant, Sample, BEHIND_CAMERA_MOTION, SKY_DEPTH};
pub use shapes::{LocalHit, Shape};

use crate::frame::Frame;
use glam::DVec3;
use serde::Serialize;
use std::sync::Arc;
use thiserror::Error;

/// A value animated over scene time (frame numbers, fractional allowed).
pub type Anim<T> = Arc<dyn Fn(f64) -> T + Send + Sync>;

/// One object: a primitive with a material, an id and a rigid motion.
#[derive(Clone)]
pub struct Object {
    /// Name, for tests and scene.json.
    pub name: String,
    /// Object id written to the G-buffer (never 0: that is the sky).
    pub id: u32,
    /// The primitive.
    pub shape: Shape,
    /// Its surface.
    pub material: Material,
    /// Local-to-world transform over time.
    pub motion: Anim<Rigid>,
}

/// A scene: objects, camera, light and sky, all as functions of time.
#[derive(Clone)]
pub struct SceneDef {
    /// Catalogue name.
    pub name: &'static str,
    /// What it tests.
    pub description: &'static str,
    /// The objects.
    pub objects: Vec<Object>,
    /// The camera over time.
    pub camera: Anim<Camera>,
    /// Direction towards the sun over time (any length).
    pub sun: Anim<DVec3>,
    /// Irradiance of the sun on a surface facing it.
    pub sun_irradiance: DVec3,
    /// Angular radius of the sun's disc, radians (used by the noisy soft shadow).
    pub sun_angular_radius: f64,
    /// Ambient irradiance (no shadowing).
    pub ambient: DVec3,
    /// Sky colour straight up.
    pub sky_top: DVec3,
    /// Sky colour at the horizon.
    pub sky_horizon: DVec3,
    /// A camera cut at this frame (its `reset` is set).
    pub cut_at: Option<u64>,
    /// Distance fog: colour fades to the horizon colour as `exp(-distance / fog)`. It
    /// keeps the infinite ground planes band-limited towards the horizon, where any
    /// finite sampling would alias, so that the N x N reference converges.
    pub fog_distance: Option<f64>,
}

/// Sub-pixel jitter of the input sample.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Jitter {
    /// Pixel centres.
    None,
    /// Halton(2,3) with this many phases (8 or 16).
    Halton(u32),
}

impl Jitter {
    /// The offset of frame `index`, pixels, x right, y down.
    pub fn offset(self, index: u64) -> [f32; 2] {
        match self {
            Jitter::None => [0.0, 0.0],
            Jitter::Halton(phases) => halton_jitter(index, phases),
        }
    }
}

/// Errors in scene settings.
#[derive(Debug, Error, PartialEq)]
pub enum SceneError {
    /// No scene of that name.
    #[error("unknown scene {got:?}; the catalogue has: {known}")]
    Unknown {
        /// The name asked for.
        got: String,
        /// The names there are.
        known: String,
    },
    /// A setting out of range.
    #[error("{0}")]
    Setting(String),
}

/// How to render: size, reference samples, jitter, noise, seed.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Settings {
    /// Width in pixels.
    pub width: usize,
    /// Height in pixels.
    pub height: usize,
    /// Frames in the sequence (scenes time their events, e.g. the cut, by it).
    pub frames: u64,
    /// Reference samples per pixel, a square number N x N.
    pub spp: u32,
    /// Jitter of the input sample.
    pub jitter: Jitter,
    /// Turn the sun's soft shadow into a one-sample Monte-Carlo estimate in the input.
    pub noise: bool,
    /// Seed of every random choice.
    pub seed: u64,
    /// Sparse shading: 1 shades every pixel; 2 or 4 shade one pixel of every 2x2 or 4x4
    /// block, in the rotating order of [`crate::frame::Sampling::rotating`] (Herzog et al.
    /// 2010), while the G-buffer and the reference stay at full resolution.
    pub shading: u32,
}

impl Default for Settings {
    /// 256x144, 32 frames, 16x16 reference samples, 8-phase Halton jitter, no noise.
    fn default() -> Self {
        Settings {
            width: 256,
            height: 144,
            frames: 32,
            spp: 256,
            jitter: Jitter::Halton(8),
            noise: false,
            seed: 1,
            shading: 1,
        }
    }
}

impl Settings {
    /// Checks the settings; the error says which bound was broken.
    pub fn validate(&self) -> Result<(), SceneError> {
        let n = self.reference_grid();
        if n * n != self.spp || self.spp == 0 {
            return Err(SceneError::Setting(format!(
                "spp must be a square number N x N (stratified grid), got {}; nearest: {} or {}",
                self.spp,
                n.max(1) * n.max(1),
                (n + 1) * (n + 1)
            )));
        }
        if self.width == 0 || self.height == 0 || self.width > 16384 || self.height > 16384 {
            return Err(SceneError::Setting(format!(
                "size must be between 1x1 and 16384x16384, got {}x{}",
                self.width, self.height
            )));
        }
        if self.frames == 0 {
            return Err(SceneError::Setting("frames must be at least 1".into()));
        }
        crate::frame::Sampling {
            factor: self.shading,
            phase: [0, 0],
        }
        .validate()
        .map_err(SceneError::Setting)?;
        if let Jitter::Halton(p) = self.jitter {
            if p == 0 {
                return Err(SceneError::Setting("jitter phases must be at least 1".into()));
            }
        }
        Ok(())
    }

    /// N of the N x N reference grid.
    pub fn reference_grid(&self) -> u32 {
        (self.spp as f64).sqrt().round() as u32
    }
}

/// A catalogue scene with its settings: renders frames on demand.
#[derive(Clone)]
pub struct Scene {
    /// The definition.
    pub def: SceneDef,
    /// The settings.
    pub settings: Settings,
}

impl Scene {
    /// The catalogue scene `name` under `settings`.
    pub fn new(name: &str, settings: Settings) -> Result<Scene, SceneError> {
        settings.validate()?;
        let entry = CATALOGUE
            .iter()
            .find(|e| e.name == name)
            .ok_or_else(|| SceneError::Unknown {
                got: name.to_string(),
                known: CATALOGUE.iter().map(|e| e.name).collect::<Vec<_>>().join(", "),
            })?;
        Ok(Scene {
            def: (entry.build)(&settings),
            settings,
        })
    }

    /// Frame `index` (0-based): G-buffer, reference and frame values.
    pub fn frame(&self, index: u64) -> Frame {
        render::render(&self.def, &self.settings, index)
    }

    /// The scene at time `t` (for tests and tools that trace their own rays).
    pub fn instant(&self, t: f64) -> Instant<'_> {
        Instant::new(&self.def, t)
    }

    /// The object called `name`.
    pub fn object(&self, name: &str) -> Option<&Object> {
        self.def.objects.iter().find(|o| o.name == name)
    }
}
