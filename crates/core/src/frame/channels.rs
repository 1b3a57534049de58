//! The channels a G-buffer frame can carry, and sets of them.

use serde::{Deserialize, Serialize};
use std::fmt;

/// One channel of the G-buffer (conventions in `docs/ARCHITECTURE.md`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ChannelKind {
    /// Linear scene-referred RGB (mandatory).
    Color,
    /// Linear view-space depth, larger = farther.
    Depth,
    /// Motion to the previous frame in pixels (internal convention, see `motion`).
    Motion,
    /// Motion to the next frame in pixels: `next = p + v`, x right, y down, jitter
    /// excluded (Blender's `Vector.ZW`; offline renders have it, real-time ones rarely).
    MotionNext,
    /// Unit surface normal (world or view space, see `NormalSpace`).
    Normal,
    /// Object / material index, 0 = background.
    ObjectId,
    /// Unlit surface colour.
    Albedo,
    /// Ground truth for metrics, never read by filters.
    Reference,
}

/// The type of a channel's samples.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SampleKind {
    /// 32-bit float (stored as f16 or f32 on disk).
    F32,
    /// 32-bit unsigned integer (object ids).
    U32,
}

impl ChannelKind {
    /// Every channel, in a fixed order.
    pub const ALL: [ChannelKind; 8] = [
        ChannelKind::Color,
        ChannelKind::Depth,
        ChannelKind::Motion,
        ChannelKind::MotionNext,
        ChannelKind::Normal,
        ChannelKind::ObjectId,
        ChannelKind::Albedo,
        ChannelKind::Reference,
    ];

    /// Number of components (planes).
    pub fn components(self) -> usize {
        match self {
            ChannelKind::Color | ChannelKind::Normal | ChannelKind::Albedo => 3,
            ChannelKind::Reference => 3,
            ChannelKind::Motion | ChannelKind::MotionNext => 2,
            ChannelKind::Depth | ChannelKind::ObjectId => 1,
        }
    }

    /// Sample type.
    pub fn sample_kind(self) -> SampleKind {
        match self {
            ChannelKind::ObjectId => SampleKind::U32,
            _ => SampleKind::F32,
        }
    }

    /// The name used on the command line, in JSON and in the `afterimage` EXR preset.
    pub fn name(self) -> &'static str {
        match self {
            ChannelKind::Color => "color",
            ChannelKind::Depth => "depth",
            ChannelKind::Motion => "motion",
            ChannelKind::MotionNext => "motion_next",
            ChannelKind::Normal => "normal",
            ChannelKind::ObjectId => "object_id",
            ChannelKind::Albedo => "albedo",
            ChannelKind::Reference => "reference",
        }
    }

    /// Parses a name as written by [`ChannelKind::name`].
    pub fn from_name(name: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|k| k.name() == name)
    }

    fn bit(self) -> u8 {
        1 << (self as u8)
    }
}

display_name!(ChannelKind);

/// A set of channels (what a frame carries, what a filter needs or can use).
#[derive(Clone, Copy, Default, PartialEq, Eq, Hash)]
pub struct ChannelSet(u8);

impl ChannelSet {
    /// The empty set.
    pub const EMPTY: ChannelSet = ChannelSet(0);

    /// The set of the given channels.
    pub fn of(kinds: &[ChannelKind]) -> Self {
        kinds.iter().fold(Self::EMPTY, |s, &k| s.with(k))
    }

    /// This set plus `kind`.
    pub fn with(self, kind: ChannelKind) -> Self {
        ChannelSet(self.0 | kind.bit())
    }

    /// Whether `kind` is in the set.
    pub fn contains(self, kind: ChannelKind) -> bool {
        self.0 & kind.bit() != 0
    }

    /// Whether every channel of `other` is in this set.
    pub fn is_superset(self, other: ChannelSet) -> bool {
        self.0 & other.0 == other.0
    }

    /// Channels of `self` that are not in `other`.
    pub fn minus(self, other: ChannelSet) -> ChannelSet {
        ChannelSet(self.0 & !other.0)
    }

    /// The channels, in [`ChannelKind::ALL`] order.
    pub fn iter(self) -> impl Iterator<Item = ChannelKind> {
        ChannelKind::ALL.into_iter().filter(move |k| self.contains(*k))
    }

    /// Whether the set is empty.
    pub fn is_empty(self) -> bool {
        self.0 == 0
    }
}

impl fmt::Display for ChannelSet {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let names: Vec<_> = self.iter().map(ChannelKind::name).collect();
        write!(f, "{{{}}}", names.join(", "))
    }
}

impl fmt::Debug for ChannelSet {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        fmt::Display::fmt(self, f)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_round_trip_and_sets_behave() {
        for k in ChannelKind::ALL {
            assert_eq!(ChannelKind::from_name(k.name()), Some(k));
        }
        let s = ChannelSet::of(&[ChannelKind::Color, ChannelKind::Motion]);
        assert!(s.contains(ChannelKind::Motion));
        assert!(!s.contains(ChannelKind::Depth));
        assert!(s.is_superset(ChannelSet::of(&[ChannelKind::Color])));
        assert_eq!(
            s.minus(ChannelSet::of(&[ChannelKind::Color])),
            ChannelSet::of(&[ChannelKind::Motion])
        );
        assert_eq!(s.to_string(), "{color, motion}");
    }
}
