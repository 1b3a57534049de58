//! The stage planner: what a frame does not need.
//!
//! A stage is left out when its input is absent or its effect would be nil, and the record
//! says which and why. The rules shared by filters live here:
//! - no motion anywhere and no reset: reprojection is the identity, skip it;
//! - LDR input (colour never above 1): no reversible tonemap;
//! - a channel absent: every stage that reads it (e.g. no object ids, no modelAverage).

use super::record::Skip;
use crate::frame::{Frame, Plane};

/// Motion below this many pixels everywhere counts as none: reprojecting by it would move
/// history by less than 1e-4 of a pixel, below f32 resolution of the colours it blends.
pub const MOTION_EPS_PX: f32 = 1.0e-4;

/// What the planner knows about a frame.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FrameFacts {
    /// The frame is a reset (camera cut).
    pub reset: bool,
    /// Some pixel moves by more than [`MOTION_EPS_PX`].
    pub any_motion: bool,
    /// Largest finite colour sample.
    pub max_color: f32,
    /// Colour exceeds 1 somewhere.
    pub hdr: bool,
}

impl FrameFacts {
    /// Facts of `frame` with its (repaired) motion and largest colour sample.
    pub fn new(frame: &Frame, motion: Option<&[Plane<f32>; 2]>, max_color: f32) -> Self {
        let any_motion =
            motion.is_some_and(|m| m.iter().any(|p| p.data().iter().any(|v| v.abs() > MOTION_EPS_PX)));
        FrameFacts {
            reset: frame.meta.reset,
            any_motion,
            max_color,
            hdr: max_color > 1.0,
        }
    }

    /// Whether reprojection is needed: `None` to run it, else why not.
    pub fn reprojection(&self) -> Option<Skip> {
        (!self.any_motion && !self.reset).then_some(Skip::NoMotion)
    }

    /// Whether the reversible tonemap is needed: `None` to run it, else why not.
    pub fn tonemap(&self) -> Option<Skip> {
        (!self.hdr).then_some(Skip::LdrInput)
    }
}
