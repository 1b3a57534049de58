//! Channel-name presets: which file channels make which frame channel.

use super::raw::RawImage;
use super::IoError;
use crate::frame::{ChannelKind, MotionConvention};
use std::fmt;
use std::str::FromStr;

/// A channel-name layout.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Preset {
    /// Ours, written by every writer of this project: `color.{R,G,B}`, `depth.Z`,
    /// `motion.{X,Y}` and `motion_next.{X,Y}` (internal convention), `normal.{X,Y,Z}`,
    /// `object_id.id` (u32),
    /// `albedo.{R,G,B}`, `reference.{R,G,B}`.
    Afterimage,
    /// Blender Cycles multilayer: `<layer>.Combined.{R,G,B}`, `<layer>.Depth.Z`,
    /// `<layer>.Vector.{X,Y}` (Blender motion convention; `.{Z,W}` motion to the next
    /// frame, see [`MotionConvention::BLENDER_NEXT`]), `<layer>.Normal.{X,Y,Z}` (world
    /// space), `<layer>.IndexOB.X`, `<layer>.DiffCol.{R,G,B}`. `layer` is the view layer's
    /// name, `ViewLayer` by default.
    Blender {
        /// The view layer name.
        layer: String,
    },
    /// Nuke-style parts: colour in part `rgba` (`rgba.{R,G,B}`), every other channel under
    /// the [`Preset::Afterimage`] names (parts `depth` with `Z`, `motion` with `X,Y`, ...),
    /// motion in the internal convention unless `--motion-convention` says otherwise.
    Nuke,
    /// A plain single-layer image: `R,G,B` is colour (and `Z` depth when present).
    Plain,
}

impl Preset {
    /// File channel names for a frame channel, or None when the preset has none.
    pub fn names(&self, kind: ChannelKind) -> Option<Vec<String>> {
        let join = |prefix: &str, comps: &[&str]| -> Vec<String> {
            comps.iter().map(|c| format!("{prefix}{c}")).collect()
        };
        match self {
            Preset::Afterimage => {
                let p = format!("{}.", kind.name());
                Some(match kind {
                    ChannelKind::Color | ChannelKind::Albedo | ChannelKind::Reference => {
                        join(&p, &["R", "G", "B"])
                    }
                    ChannelKind::Normal => join(&p, &["X", "Y", "Z"]),
                    ChannelKind::Motion | ChannelKind::MotionNext => join(&p, &["X", "Y"]),
                    ChannelKind::Depth => join(&p, &["Z"]),
                    ChannelKind::ObjectId => join(&p, &["id"]),
                })
            }
            Preset::Blender { layer } => {
                let l = |pass: &str| format!("{layer}.{pass}.");
                match kind {
                    ChannelKind::Color => Some(join(&l("Combined"), &["R", "G", "B"])),
                    ChannelKind::Depth => Some(join(&l("Depth"), &["Z"])),
                    ChannelKind::Motion => Some(join(&l("Vector"), &["X", "Y"])),
                    ChannelKind::MotionNext => Some(join(&l("Vector"), &["Z", "W"])),
                    ChannelKind::Normal => Some(join(&l("Normal"), &["X", "Y", "Z"])),
                    ChannelKind::ObjectId => Some(join(&l("IndexOB"), &["X"])),
                    ChannelKind::Albedo => Some(join(&l("DiffCol"), &["R", "G", "B"])),
                    ChannelKind::Reference => None,
                }
            }
            Preset::Nuke => match kind {
                ChannelKind::Color => Some(join("rgba.", &["R", "G", "B"])),
                _ => Preset::Afterimage.names(kind),
            },
            Preset::Plain => match kind {
                ChannelKind::Color => Some(join("", &["R", "G", "B"])),
                ChannelKind::Depth => Some(join("", &["Z"])),
                _ => None,
            },
        }
    }

    /// The motion convention the preset's motion channel is written in.
    pub fn motion_convention(&self) -> MotionConvention {
        match self {
            Preset::Blender { .. } => MotionConvention::BLENDER,
            Preset::Afterimage | Preset::Nuke | Preset::Plain => MotionConvention::INTERNAL,
        }
    }

    /// The convention the preset's motion-to-next channel is written in (its vectors,
    /// converted, give `next = p + v`).
    pub fn motion_next_convention(&self) -> MotionConvention {
        match self {
            Preset::Blender { .. } => MotionConvention::BLENDER_NEXT,
            Preset::Afterimage | Preset::Nuke | Preset::Plain => MotionConvention::INTERNAL,
        }
    }

    /// Detects the preset from a file's channel names.
    pub fn detect(raw: &RawImage) -> Option<Preset> {
        if raw.channel("color.R").is_some() {
            return Some(Preset::Afterimage);
        }
        if let Some(c) = raw.channels.iter().find(|c| c.name.ends_with(".Combined.R")) {
            let layer = c.name.trim_end_matches(".Combined.R").to_string();
            return Some(Preset::Blender { layer });
        }
        if raw.channel("rgba.R").is_some() {
            return Some(Preset::Nuke);
        }
        if raw.channel("R").is_some() {
            return Some(Preset::Plain);
        }
        None
    }
}

impl fmt::Display for Preset {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Preset::Afterimage => f.write_str("afterimage"),
            Preset::Blender { layer } if layer == "ViewLayer" => f.write_str("blender"),
            Preset::Blender { layer } => write!(f, "blender (layer {layer})"),
            Preset::Nuke => f.write_str("nuke"),
            Preset::Plain => f.write_str("plain"),
        }
    }
}

/// The preset asked for on the command line.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum PresetChoice {
    /// Detect from the channel names.
    #[default]
    Auto,
    /// Force [`Preset::Afterimage`].
    Afterimage,
    /// Force [`Preset::Blender`] (the layer name is still detected, `ViewLayer` if none).
    Blender,
    /// Force [`Preset::Nuke`].
    Nuke,
    /// Force [`Preset::Plain`].
    Plain,
}

impl PresetChoice {
    /// The names accepted by `FromStr`.
    pub const NAMES: &'static str = "auto, afterimage, blender, nuke, plain";

    /// The preset for `raw`. `color_mapped` (an explicit `--channel color=...`) lets
    /// detection fail: the other channels are then looked for under the
    /// [`Preset::Afterimage`] names, so `--channel` alone reads any layout.
    pub fn resolve(self, raw: &RawImage, color_mapped: bool) -> Result<Preset, IoError> {
        match self {
            PresetChoice::Auto => match Preset::detect(raw) {
                Some(p) => Ok(p),
                None if color_mapped => Ok(Preset::Afterimage),
                None => Err(IoError::UnknownLayout {
                    path: raw.path.clone(),
                    present: raw.names(),
                }),
            },
            PresetChoice::Afterimage => Ok(Preset::Afterimage),
            PresetChoice::Nuke => Ok(Preset::Nuke),
            PresetChoice::Plain => Ok(Preset::Plain),
            PresetChoice::Blender => Ok(match Preset::detect(raw) {
                Some(p @ Preset::Blender { .. }) => p,
                _ => Preset::Blender {
                    layer: "ViewLayer".into(),
                },
            }),
        }
    }
}

impl FromStr for PresetChoice {
    type Err = IoError;
    fn from_str(s: &str) -> Result<Self, IoError> {
        match s {
            "auto" => Ok(PresetChoice::Auto),
            "afterimage" => Ok(PresetChoice::Afterimage),
            "blender" => Ok(PresetChoice::Blender),
            "nuke" => Ok(PresetChoice::Nuke),
            "plain" => Ok(PresetChoice::Plain),
            _ => Err(IoError::Argument(format!(
                "unknown preset {s:?}; expected one of {}",
                Self::NAMES
            ))),
        }
    }
}

/// An explicit mapping of one frame channel to file channels (`--channel KIND=SPEC`).
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum ChannelSpec {
    /// Exact file channel names, one per component (`motion=Vec.X,Vec.Y`).
    Names(Vec<String>),
    /// A layer prefix (`color=ViewLayer.Combined`): the components are the file channels
    /// `PREFIX.R,G,B` or `PREFIX.X,Y,Z` (as many as the frame channel has), or the channel
    /// `PREFIX` itself for a one-component channel.
    Prefix(String),
}

impl ChannelSpec {
    /// Parses `KIND=SPEC`.
    pub fn parse_mapping(s: &str) -> Result<(ChannelKind, ChannelSpec), IoError> {
        let (kind, spec) = s.split_once('=').ok_or_else(|| {
            IoError::Argument(format!(
                "channel mapping {s:?} is not KIND=NAMES (e.g. color=ViewLayer.Combined or motion=Vec.X,Vec.Y)"
            ))
        })?;
        let kind = ChannelKind::from_name(kind.trim()).ok_or_else(|| {
            let known: Vec<_> = ChannelKind::ALL.iter().map(|k| k.name()).collect();
            IoError::Argument(format!(
                "channel mapping {s:?}: unknown channel {kind:?}; expected one of {}",
                known.join(", ")
            ))
        })?;
        let spec = spec.trim();
        if spec.is_empty() {
            return Err(IoError::Argument(format!(
                "channel mapping {s:?} names no file channel"
            )));
        }
        let spec = if spec.contains(',') {
            let names: Vec<String> = spec.split(',').map(|n| n.trim().to_string()).collect();
            if names.len() != kind.components() {
                return Err(IoError::Argument(format!(
                    "channel mapping {s:?}: {kind} needs {} names, got {}",
                    kind.components(),
                    names.len()
                )));
            }
            ChannelSpec::Names(names)
        } else {
            ChannelSpec::Prefix(spec.to_string())
        };
        Ok((kind, spec))
    }

    /// The file channel names this spec means for `kind` in `raw`; on failure, a
    /// description of what was looked for.
    pub fn resolve(&self, kind: ChannelKind, raw: &RawImage) -> Result<Vec<String>, String> {
        match self {
            ChannelSpec::Names(n) => {
                if n.iter().all(|n| raw.channel(n).is_some()) {
                    Ok(n.clone())
                } else {
                    Err(n.join(", "))
                }
            }
            ChannelSpec::Prefix(p) => {
                let sets: &[&[&str]] = match kind.components() {
                    3 => &[&["R", "G", "B"], &["X", "Y", "Z"]],
                    2 => &[&["X", "Y"], &["R", "G"], &["U", "V"], &["u", "v"]],
                    _ => &[&["Z"], &["X"], &["R"], &["Y"], &["V"], &["id"]],
                };
                if kind.components() == 1 && raw.channel(p).is_some() {
                    return Ok(vec![p.clone()]);
                }
                let mut tried = Vec::new();
                for set in sets {
                    let names: Vec<String> = set.iter().map(|c| format!("{p}.{c}")).collect();
                    if names.iter().all(|n| raw.channel(n).is_some()) {
                        return Ok(names);
                    }
                    tried.push(format!("{p}.{{{}}}", set.join(",")));
                }
                Err(tried.join(" or "))
            }
        }
    }
}

/// How to read a frame from a file.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ReadOptions {
    /// Channel-name preset.
    pub preset: PresetChoice,
    /// Explicit mappings that override the preset, per channel.
    pub mapping: Vec<(ChannelKind, ChannelSpec)>,
    /// Motion convention of the file (None: the preset's).
    pub motion_convention: Option<MotionConvention>,
}
