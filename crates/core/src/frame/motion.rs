//! Motion-vector conventions.
//!
//! Internally a motion vector is the **offset in pixels from the current pixel centre to
//! where that surface point was in the previous frame, x right, y down, jitter excluded**:
//! `prev = p + mv`. Every other convention is converted at the edge by a
//! [`MotionConvention`]; getting this wrong is the most common TAA integration bug
//! (FSR2 issues #22, #39, #102), so each preset below states its source.

use super::{Frame, FrameError, Plane};
use serde::{Deserialize, Serialize};
use std::fmt;
use std::str::FromStr;

/// Units of a motion vector.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum MotionUnits {
    /// Pixels of the frame.
    Pixels,
    /// Fractions of the frame size (1.0 = the whole width or height).
    Uv,
    /// Normalised device coordinates: the frame spans [-1, 1], so 2.0 = the whole size.
    Ndc,
}

/// Which way a motion vector points.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum MotionDirection {
    /// From the current position to the previous one: `prev = p + v`.
    ToPrevious,
    /// From the previous position to the current one: `prev = p - v`.
    ToCurrent,
}

/// Direction of the vertical axis of a motion vector.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum YAxis {
    /// Positive y points down the image (rows counted from the top).
    Down,
    /// Positive y points up the image.
    Up,
}

/// How a renderer encodes motion vectors.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct MotionConvention {
    /// Units of the vector.
    pub units: MotionUnits,
    /// Which way it points.
    pub direction: MotionDirection,
    /// Direction of its y axis.
    pub y: YAxis,
    /// Whether the vector was computed between jittered sample positions, i.e. it
    /// contains `jitter_prev - jitter_cur` (in the direction of the vector) on top of the
    /// true motion.
    pub jittered: bool,
}

impl MotionConvention {
    /// Ours: pixels, to previous, y down, jitter excluded.
    pub const INTERNAL: MotionConvention = MotionConvention {
        units: MotionUnits::Pixels,
        direction: MotionDirection::ToPrevious,
        y: YAxis::Down,
        jittered: false,
    };

    /// Blender Cycles' `Vector.XY` pass: pixels, to the previous frame, y up:
    /// `prev = (col + X, row - Y)` with rows from the top (checked on the real renders in
    /// `tests/fixtures/blender-*`, see their README). Cycles renders without jitter.
    pub const BLENDER: MotionConvention = MotionConvention {
        units: MotionUnits::Pixels,
        direction: MotionDirection::ToPrevious,
        y: YAxis::Up,
        jittered: false,
    };

    /// Blender Cycles' `Vector.ZW` pass, motion to the **next** frame: minus that motion,
    /// y up: `next = (col - Z, row + W)` (the fixtures' README, checked on
    /// `tests/fixtures/blender-motion`). Read through this convention, a next-vector comes
    /// out internal: `next = p + v`, y down.
    pub const BLENDER_NEXT: MotionConvention = MotionConvention {
        units: MotionUnits::Pixels,
        direction: MotionDirection::ToCurrent,
        y: YAxis::Up,
        jittered: false,
    };

    /// AMD FidelityFX FSR2 after its `motionVectorScale`: UV units (top-left origin, so
    /// y down), pointing from the current pixel to its previous position (the reproject
    /// pass samples history at `uv + mv`); jitter excluded unless the context is created
    /// with `FFX_FSR2_ENABLE_MOTION_VECTORS_JITTER_CANCELLATION` (then use `jittered`).
    pub const FSR2: MotionConvention = MotionConvention {
        units: MotionUnits::Uv,
        direction: MotionDirection::ToPrevious,
        y: YAxis::Down,
        jittered: false,
    };

    /// Unreal Engine's velocity buffer (decoded): `ScreenPos - PrevScreenPos` in clip
    /// space (NDC, y up), computed with unjittered matrices; the TAA pass reads history
    /// at `ScreenPos - Velocity`.
    pub const UNREAL: MotionConvention = MotionConvention {
        units: MotionUnits::Ndc,
        direction: MotionDirection::ToCurrent,
        y: YAxis::Up,
        jittered: false,
    };

    /// Unity's `_CameraMotionVectorsTexture`: `uv_current - uv_previous` in UV space with
    /// the origin at the bottom left (y up), unjittered matrices.
    pub const UNITY: MotionConvention = MotionConvention {
        units: MotionUnits::Uv,
        direction: MotionDirection::ToCurrent,
        y: YAxis::Up,
        jittered: false,
    };

    /// Bevy's motion-vector prepass: `(clip_current - clip_previous) * (0.5, -0.5)`, i.e.
    /// `uv_current - uv_previous` with the UV origin at the top left (y down); its TAA
    /// reads history at `uv - motion_vector`. Unjittered.
    pub const BEVY: MotionConvention = MotionConvention {
        units: MotionUnits::Uv,
        direction: MotionDirection::ToCurrent,
        y: YAxis::Down,
        jittered: false,
    };

    /// The named presets.
    pub const PRESETS: [(&'static str, MotionConvention); 6] = [
        ("internal", Self::INTERNAL),
        ("blender", Self::BLENDER),
        ("fsr2", Self::FSR2),
        ("unreal", Self::UNREAL),
        ("unity", Self::UNITY),
        ("bevy", Self::BEVY),
    ];

    /// The preset called `name`.
    pub fn preset(name: &str) -> Option<MotionConvention> {
        Self::PRESETS.iter().find(|(n, _)| *n == name).map(|(_, c)| *c)
    }

    fn scale(&self, width: usize, height: usize) -> [f32; 2] {
        match self.units {
            MotionUnits::Pixels => [1.0, 1.0],
            MotionUnits::Uv => [width as f32, height as f32],
            MotionUnits::Ndc => [width as f32 * 0.5, height as f32 * 0.5],
        }
    }

    /// Converts one vector `v` of this convention into the internal one, for a frame of
    /// `width x height` pixels whose jitter is `jitter_cur` (this frame) and
    /// `jitter_prev` (the previous frame), both in pixels, x right, y down.
    pub fn to_internal(
        &self,
        v: [f32; 2],
        width: usize,
        height: usize,
        jitter_cur: [f32; 2],
        jitter_prev: [f32; 2],
    ) -> [f32; 2] {
        let s = self.scale(width, height);
        let mut m = [v[0] * s[0], v[1] * s[1]];
        if self.y == YAxis::Up {
            m[1] = -m[1];
        }
        if self.direction == MotionDirection::ToCurrent {
            m = [-m[0], -m[1]];
        }
        if self.jittered {
            m[0] -= jitter_prev[0] - jitter_cur[0];
            m[1] -= jitter_prev[1] - jitter_cur[1];
        }
        m
    }

    /// The inverse of [`MotionConvention::to_internal`].
    pub fn from_internal(
        &self,
        m: [f32; 2],
        width: usize,
        height: usize,
        jitter_cur: [f32; 2],
        jitter_prev: [f32; 2],
    ) -> [f32; 2] {
        let mut m = m;
        if self.jittered {
            m[0] += jitter_prev[0] - jitter_cur[0];
            m[1] += jitter_prev[1] - jitter_cur[1];
        }
        if self.direction == MotionDirection::ToCurrent {
            m = [-m[0], -m[1]];
        }
        if self.y == YAxis::Up {
            m[1] = -m[1];
        }
        let s = self.scale(width, height);
        [m[0] / s[0], m[1] / s[1]]
    }

    /// Converts two motion planes of this convention in place into the internal one.
    pub fn planes_to_internal(
        &self,
        planes: &mut [Plane<f32>; 2],
        jitter_cur: [f32; 2],
        jitter_prev: [f32; 2],
    ) {
        if *self == Self::INTERNAL {
            return;
        }
        let (w, h) = planes[0].size();
        let [px, py] = planes;
        for (x, y) in px.data_mut().iter_mut().zip(py.data_mut().iter_mut()) {
            let m = self.to_internal([*x, *y], w, h, jitter_cur, jitter_prev);
            *x = m[0];
            *y = m[1];
        }
    }

    /// Converts a frame's motion (read in this convention) to the internal one, using the
    /// frame's jitter and `jitter_prev`. Does nothing when the frame has no motion.
    pub fn frame_to_internal(&self, frame: &mut Frame, jitter_prev: [f32; 2]) {
        let jitter = frame.meta.jitter;
        if let Some(m) = frame.motion_mut() {
            self.planes_to_internal(m, jitter, jitter_prev);
        }
    }
}

impl fmt::Display for MotionConvention {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        if let Some((name, _)) = Self::PRESETS.iter().find(|(_, c)| c == self) {
            return f.write_str(name);
        }
        write!(
            f,
            "{:?}, {:?}, y {:?}{}",
            self.units,
            self.direction,
            self.y,
            if self.jittered { ", jittered" } else { "" }
        )
    }
}

impl FromStr for MotionConvention {
    type Err = FrameError;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        Self::preset(s).ok_or_else(|| FrameError::UnknownMotionConvention {
            got: s.to_string(),
            known: Self::PRESETS
                .iter()
                .map(|(n, _)| *n)
                .collect::<Vec<_>>()
                .join(", "),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::tolerance::Tolerance;

    const W: usize = 200;
    const H: usize = 100;

    /// A surface point seen at pixel position `cur` (x right, y down from the top-left
    /// corner, in pixels) that was at `prev` in the previous frame, written the way each
    /// engine writes it, derived from the engine's own definition rather than from our
    /// conversion code.
    fn encode(preset: &str, cur: [f32; 2], prev: [f32; 2]) -> [f32; 2] {
        let (w, h) = (W as f32, H as f32);
        // UV with a top-left origin, UV with a bottom-left origin, NDC (y up).
        let uv_tl = |p: [f32; 2]| [p[0] / w, p[1] / h];
        let uv_bl = |p: [f32; 2]| [p[0] / w, 1.0 - p[1] / h];
        let ndc = |p: [f32; 2]| [2.0 * p[0] / w - 1.0, 1.0 - 2.0 * p[1] / h];
        match preset {
            "internal" => [prev[0] - cur[0], prev[1] - cur[1]],
            // prev = (col + X, row - Y)
            "blender" => [prev[0] - cur[0], cur[1] - prev[1]],
            // history at uv + mv
            "fsr2" => {
                let (a, b) = (uv_tl(cur), uv_tl(prev));
                [b[0] - a[0], b[1] - a[1]]
            }
            // ScreenPos - PrevScreenPos in NDC
            "unreal" => {
                let (a, b) = (ndc(cur), ndc(prev));
                [a[0] - b[0], a[1] - b[1]]
            }
            // uv_cur - uv_prev, bottom-left origin
            "unity" => {
                let (a, b) = (uv_bl(cur), uv_bl(prev));
                [a[0] - b[0], a[1] - b[1]]
            }
            // uv_cur - uv_prev, top-left origin
            "bevy" => {
                let (a, b) = (uv_tl(cur), uv_tl(prev));
                [a[0] - b[0], a[1] - b[1]]
            }
            _ => unreachable!(),
        }
    }

    #[test]
    fn every_preset_recovers_known_motion() {
        // The surface moved 6 px right and 4 px down: it was up-left of where it is now.
        let cur = [120.5, 40.5];
        let prev = [114.5, 36.5];
        for (name, conv) in MotionConvention::PRESETS {
            let v = encode(name, cur, prev);
            let m = conv.to_internal(v, W, H, [0.0; 2], [0.0; 2]);
            let t = Tolerance::abs(1e-4);
            t.check(&format!("{name} x"), m[0] as f64, -6.0).unwrap();
            t.check(&format!("{name} y"), m[1] as f64, -4.0).unwrap();
            let back = conv.from_internal(m, W, H, [0.0; 2], [0.0; 2]);
            t.check(&format!("{name} round trip x"), back[0] as f64, v[0] as f64)
                .unwrap();
            t.check(&format!("{name} round trip y"), back[1] as f64, v[1] as f64)
                .unwrap();
        }
    }

    #[test]
    fn presets_differ_where_engines_differ() {
        // The same displacement encodes to different numbers in each engine: a preset
        // applied to the wrong engine's vectors is caught.
        let v = encode("unity", [120.5, 40.5], [114.5, 36.5]);
        let wrong = MotionConvention::BEVY.to_internal(v, W, H, [0.0; 2], [0.0; 2]);
        assert!(!Tolerance::abs(1e-3).eq(wrong[1] as f64, -4.0));
    }

    #[test]
    fn jittered_vectors_lose_the_jitter_difference() {
        let conv = MotionConvention {
            jittered: true,
            ..MotionConvention::INTERNAL
        };
        // Static surface; the sample moved from jitter_prev to jitter_cur.
        let (jc, jp) = ([0.25, -0.125], [-0.375, 0.3125]);
        // Between jittered sample positions: (p + jp) - (p + jc).
        let v = [jp[0] - jc[0], jp[1] - jc[1]];
        let m = conv.to_internal(v, W, H, jc, jp);
        assert_eq!(m, [0.0, 0.0]);
    }

    #[test]
    fn names_parse_and_print() {
        for (name, conv) in MotionConvention::PRESETS {
            assert_eq!(name.parse::<MotionConvention>().unwrap(), conv);
            assert_eq!(conv.to_string(), name);
        }
        let err = "opengl".parse::<MotionConvention>().unwrap_err();
        assert!(err.to_string().contains("opengl"));
        assert!(err.to_string().contains("blender"));
    }
}
