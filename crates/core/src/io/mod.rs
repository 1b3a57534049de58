//! Reading and writing frames: OpenEXR (single-layer and multilayer, f16/f32, with
//! channel-name presets), PNG/JPEG for LDR input and previews, and frame sequences.
//!
//! Interleaved pixels exist only in here: everything that leaves this module is planar.

mod colormap;
mod exr_file;
mod ldr;
mod naming;
mod output;
mod preset;
mod raw;
mod sequence;
mod storage;

pub use colormap::inferno;
pub use exr_file::{
    check_exr_header, full_channel_name, read_exr_parts, read_raw_exr, read_raw_exr_bytes,
    read_raw_exr_bytes_limited, write_exr, write_exr_bytes, Compression, ExrHeaders, ExrLimits, ExrPart,
    ExrShape, PixelWindow, Precision, WriteOptions,
};
pub use ldr::{linear_to_srgb, read_ldr, rgb_to_srgb8, srgb_to_linear, write_png, write_png_rgb8};
pub use naming::{refuse_overwrite, FramePattern, OutputFormat, OutputNaming};
pub use output::{
    encode_filtered, encode_filtered_for, partial_path, write_filtered, FilteredFrame, InputImage, Keep,
    OutputOptions, RECORD_ATTRIBUTE,
};
pub use preset::{ChannelSpec, Preset, PresetChoice, ReadOptions};
pub use raw::{ChannelStats, RawChannel, RawData, RawImage};
pub use sequence::{frame_number, FrameRange, Missing, Selection, Sequence, SequenceEntry};
pub use storage::{read_raw_in, LocalFiles, Storage};

use crate::frame::{ChannelKind, Frame, FrameError};
use std::path::{Path, PathBuf};
use thiserror::Error;

/// Errors of reading and writing frames, sorted by whose fault they are: the file
/// system's, the file's, or the request's (a channel or preset that does not fit).
#[derive(Debug, Error)]
pub enum IoError {
    /// The operating system refused (missing file, permissions, disk full).
    #[error("{path}: {source}")]
    Os {
        /// The file.
        path: PathBuf,
        /// The OS error.
        #[source]
        source: std::io::Error,
    },
    /// The file is not a valid image of its format (truncated, corrupt, unsupported).
    #[error("{path}: not a readable {format} file: {reason}")]
    Format {
        /// The file.
        path: PathBuf,
        /// "OpenEXR", "PNG", ...
        format: &'static str,
        /// What the decoder said.
        reason: String,
    },
    /// Layers or channels of one file disagree in size.
    #[error("{path}: {reason}")]
    Inconsistent {
        /// The file.
        path: PathBuf,
        /// What disagrees.
        reason: String,
    },
    /// A channel that was asked for is not in the file.
    #[error("{path}: no {wanted} for channel {channel} (preset {preset}); the file has: {present}")]
    MissingChannel {
        /// The file.
        path: PathBuf,
        /// The frame channel.
        channel: ChannelKind,
        /// The file channel names looked for.
        wanted: String,
        /// The preset in use.
        preset: String,
        /// The channel names the file has.
        present: String,
    },
    /// No preset fits the file's channel names.
    #[error("{path}: cannot tell the channel layout (no colour as `color.R`, `<layer>.Combined.R`, `rgba.R` or `R`); pass --preset or --channel color=...; the file has: {present}")]
    UnknownLayout {
        /// The file.
        path: PathBuf,
        /// The channel names the file has.
        present: String,
    },
    /// The file's channels do not make a valid frame.
    #[error("{path}: {source}")]
    Frame {
        /// The file.
        path: PathBuf,
        /// The frame error.
        #[source]
        source: FrameError,
    },
    /// A file type this crate does not read or write.
    #[error("{path}: unsupported file type (expected .exr, .png, .jpg or .jpeg)")]
    UnsupportedType {
        /// The file.
        path: PathBuf,
    },
    /// A sequence specification that matches nothing, or has a gap.
    #[error("{0}")]
    Sequence(String),
    /// A bad argument: unknown preset, malformed channel mapping.
    #[error("{0}")]
    Argument(String),
}

impl IoError {
    /// The OS (or a storage service, as an OS-like error) refused `path`.
    pub fn os(path: &Path, source: std::io::Error) -> Self {
        IoError::Os {
            path: path.to_path_buf(),
            source,
        }
    }
}

/// The kind of file, from its extension.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FileType {
    /// OpenEXR.
    Exr,
    /// PNG or JPEG (8/16-bit, sRGB-encoded).
    Ldr,
}

impl FileType {
    /// The type of `path`, from its extension (case-insensitive).
    pub fn of(path: &Path) -> Option<FileType> {
        let ext = path.extension()?.to_str()?.to_ascii_lowercase();
        match ext.as_str() {
            "exr" => Some(FileType::Exr),
            "png" | "jpg" | "jpeg" => Some(FileType::Ldr),
            _ => None,
        }
    }
}

/// Decodes any supported file into named channels: EXR as stored, PNG/JPEG as linear
/// `R,G,B` (sRGB decoded).
pub fn read_raw(path: &Path) -> Result<RawImage, IoError> {
    match FileType::of(path) {
        Some(FileType::Exr) => read_raw_exr(path),
        Some(FileType::Ldr) => {
            let frame = read_ldr(path)?;
            let channels = frame
                .color()
                .iter()
                .zip(["R", "G", "B"])
                .map(|(p, n)| RawChannel {
                    name: n.to_string(),
                    file_type: "srgb",
                    data: RawData::F32(p.data().to_vec()),
                })
                .collect();
            Ok(RawImage {
                path: path.to_path_buf(),
                width: frame.width(),
                height: frame.height(),
                channels,
                meta: frame.meta,
                shading: crate::frame::Sampling::FULL,
                exr: None,
            })
        }
        None => Err(IoError::UnsupportedType {
            path: path.to_path_buf(),
        }),
    }
}

/// Reads one frame from an EXR, PNG or JPEG file, with motion converted to the internal
/// convention assuming the previous frame had the same jitter (a sequence reader passes
/// the real one through [`read_frame_after`]).
pub fn read_frame(path: &Path, opts: &ReadOptions) -> Result<Frame, IoError> {
    read_frame_after(path, opts, None)
}

/// Reads one frame, converting jittered motion with the previous frame's jitter
/// `jitter_prev` (None: the same as this frame's).
pub fn read_frame_after(
    path: &Path,
    opts: &ReadOptions,
    jitter_prev: Option<[f32; 2]>,
) -> Result<Frame, IoError> {
    frame_of(&read_raw(path)?, opts, jitter_prev)
}

/// Reads one frame from an EXR held in memory (an HTTP body), motion converted as by
/// [`read_frame`]; `label` names it in errors.
pub fn read_exr_frame_bytes(bytes: &[u8], label: &Path, opts: &ReadOptions) -> Result<Frame, IoError> {
    frame_of(&read_raw_exr_bytes(bytes, label)?, opts, None)
}

/// Reads one frame from an EXR from an untrusted source, its header checked against
/// `limits` before anything is decoded (see [`check_exr_header`]); motion as
/// [`read_exr_frame_bytes`].
pub fn read_exr_frame_bytes_limited(
    bytes: &[u8],
    label: &Path,
    opts: &ReadOptions,
    limits: &ExrLimits,
) -> Result<Frame, IoError> {
    frame_of(&read_raw_exr_bytes_limited(bytes, label, limits)?, opts, None)
}

/// The frame in `raw` (motion converted as by [`read_frame_after`]) and `raw` itself, kept as
/// the input a filtered result replaces (see [`write_filtered`]).
pub fn frame_and_input(
    raw: RawImage,
    opts: &ReadOptions,
    jitter_prev: Option<[f32; 2]>,
) -> Result<(Frame, InputImage), IoError> {
    let frame = frame_of(&raw, opts, jitter_prev)?;
    Ok((frame, InputImage::new(raw, opts)?))
}

/// The frame in `raw`, with its motion converted from the file's convention to the
/// internal one using `jitter_prev` (None: this frame's jitter).
fn frame_of(raw: &RawImage, opts: &ReadOptions, jitter_prev: Option<[f32; 2]>) -> Result<Frame, IoError> {
    let mut frame = raw.to_frame(opts)?;
    let conv = raw.motion_convention(opts)?;
    let prev = jitter_prev.unwrap_or(frame.meta.jitter);
    conv.frame_to_internal(&mut frame, prev);
    let next = raw.preset(opts)?.motion_next_convention();
    let jitter = frame.meta.jitter;
    if let Some(m) = frame.motion_next_mut() {
        next.planes_to_internal(m, jitter, jitter);
    }
    Ok(frame)
}
