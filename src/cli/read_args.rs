//! Flags shared by every command that reads frames, and by every command that writes
//! filtered frames.

use afterimage::frame::MotionConvention;
use afterimage::io::{
    ChannelSpec, Compression, Keep, OutputOptions, Precision, PresetChoice, ReadOptions, Sequence,
};
use clap::Args;

/// How to map file channels onto frame channels.
#[derive(Args, Debug, Clone)]
pub struct ReadArgs {
    /// Channel-name preset of the files: auto (detect), afterimage, blender, nuke, plain.
    #[arg(long, default_value = "auto", value_name = "PRESET")]
    pub preset: String,
    /// Map a frame channel to file channels, overriding the preset: KIND=PREFIX
    /// (e.g. color=ViewLayer.Combined) or KIND=NAME,NAME,... (e.g. motion=Vec.X,Vec.Y).
    /// KIND is color, depth, motion, normal, object_id, albedo or reference. Repeatable.
    #[arg(long = "channel", value_name = "KIND=NAMES")]
    pub channel: Vec<String>,
    /// Motion-vector convention of the files (default: the preset's): internal,
    /// blender, fsr2, unreal, unity, bevy.
    #[arg(long, value_name = "NAME")]
    pub motion_convention: Option<String>,
}

impl ReadArgs {
    /// The library's read options.
    pub fn options(&self) -> anyhow::Result<ReadOptions> {
        Ok(ReadOptions {
            preset: self.preset.parse::<PresetChoice>()?,
            mapping: self
                .channel
                .iter()
                .map(|s| ChannelSpec::parse_mapping(s))
                .collect::<Result<_, _>>()?,
            motion_convention: self
                .motion_convention
                .as_deref()
                .map(str::parse::<MotionConvention>)
                .transpose()?,
        })
    }
}

/// How filtered frames are written (the same for `filter` and `stream --output`).
#[derive(Args, Debug, Clone)]
pub struct WriteArgs {
    /// What of each input file the output keeps: all (every part, channel and attribute,
    /// colour replaced in place: a drop-in replacement), filtered (the colour and its alpha),
    /// none (the filtered colour alone as R,G,B).
    #[arg(long, default_value = "all", value_name = "WHAT")]
    pub keep: String,
    /// EXR compression of the outputs (default: each input part's own; zip without an EXR
    /// input): none, rle, zips, zip, piz (lossless); pxr24 (rounds every f32 channel to 24
    /// bits, passed-through depth and motion included), b44, b44a (f16 channels), dwaa,
    /// dwab (colour-named channels) are lossy.
    #[arg(long, value_name = "METHOD")]
    pub compression: Option<String>,
    /// Write the filtered colour as half floats (default: the input colour's type).
    #[arg(long, conflicts_with = "float")]
    pub half: bool,
    /// Write the filtered colour as 32-bit floats.
    #[arg(long)]
    pub float: bool,
}

impl WriteArgs {
    /// The library's output options.
    pub fn options(&self) -> anyhow::Result<OutputOptions> {
        Ok(OutputOptions {
            keep: self.keep.parse::<Keep>()?,
            compression: self
                .compression
                .as_deref()
                .map(str::parse::<Compression>)
                .transpose()?,
            precision: match (self.half, self.float) {
                (true, _) => Some(Precision::F16),
                (_, true) => Some(Precision::F32),
                _ => None,
            },
        })
    }
}

/// Opens an input sequence and, when given, a reference sequence of the same length, with
/// the read options of the reference's preset.
pub fn open_with_reference(
    input: &str,
    reference: Option<&str>,
    reference_preset: &str,
) -> anyhow::Result<(Sequence, Option<Sequence>, ReadOptions)> {
    let input = Sequence::open(input)?;
    let reference = reference.map(Sequence::open).transpose()?;
    if let Some(r) = &reference {
        if r.len() != input.len() {
            anyhow::bail!(
                "{} has {} frames but the reference {} has {}",
                input.spec,
                input.len(),
                r.spec,
                r.len()
            );
        }
    }
    let opts = ReadOptions {
        preset: reference_preset.parse::<PresetChoice>()?,
        ..ReadOptions::default()
    };
    Ok((input, reference, opts))
}
