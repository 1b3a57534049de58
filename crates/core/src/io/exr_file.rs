//! OpenEXR through the `exr` crate.

use super::preset::Preset;
use super::raw::{RawChannel, RawData, RawImage};
use super::IoError;
use crate::frame::{ChannelKind, DepthKind, Frame, FrameMeta, NormalSpace, Sampling};
use exr::prelude::{self as x, AttributeValue, ReadChannels, ReadLayers, Text, WritableImage};
use std::path::Path;

/// Attribute names under which the `afterimage` layout stores per-frame values.
mod attr {
    pub const INDEX: &str = "afterimage.index";
    pub const JITTER: &str = "afterimage.jitter";
    pub const RESET: &str = "afterimage.reset";
    pub const DEPTH_KIND: &str = "afterimage.depth_kind";
    pub const NORMAL_SPACE: &str = "afterimage.normal_space";
    /// Sparse shading: (factor, phase x, phase y); absent for full shading.
    pub const SHADING: &str = "afterimage.shading";
}

/// The attribute declaring sparse shading (dropped from outputs, whose colour is dense).
pub(crate) const SHADING_ATTRIBUTE: &str = attr::SHADING;

/// Sample precision of written float channels (object ids are always u32).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Precision {
    /// Half floats: half the bytes, about 3 significant digits, max 65504.
    F16,
    /// Full floats.
    #[default]
    F32,
}

/// Compression of written files: the methods OpenEXR defines that the `exr` crate writes.
/// `Pxr24` (every f32 channel rounded to 24 bits), `B44`/`B44a` (f16 channels in 4x4
/// blocks) and `Dwaa`/`Dwab` (DCT of the channels named as colour: `R`, `G`, `B`, `Y`, ...;
/// the others lossless) lose precision; the others are lossless.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Compression {
    /// None: largest, fastest.
    None,
    /// Run-length: fast, small on flat areas.
    Rle,
    /// ZIP of single scan lines.
    Zips,
    /// ZIP over 16 scan lines: the common default.
    #[default]
    Zip,
    /// PIZ (wavelet): best lossless method on noisy renders.
    Piz,
    /// Lossy: f32 rounded to 24 bits, then ZIP.
    Pxr24,
    /// Lossy: f16 in 4x4 blocks (f32 channels are stored losslessly).
    B44,
    /// B44 with flat blocks stored in 3 bytes.
    B44a,
    /// Lossy DCT over 32 scan lines (DreamWorks).
    Dwaa,
    /// Lossy DCT over 256 scan lines.
    Dwab,
}

impl Compression {
    /// Every method, by the name [`Compression::name`] gives it.
    pub const ALL: [Compression; 10] = [
        Compression::None,
        Compression::Rle,
        Compression::Zips,
        Compression::Zip,
        Compression::Piz,
        Compression::Pxr24,
        Compression::B44,
        Compression::B44a,
        Compression::Dwaa,
        Compression::Dwab,
    ];

    /// The name `--compression` takes (oiiotool's spelling, lower case).
    pub fn name(self) -> &'static str {
        match self {
            Compression::None => "none",
            Compression::Rle => "rle",
            Compression::Zips => "zips",
            Compression::Zip => "zip",
            Compression::Piz => "piz",
            Compression::Pxr24 => "pxr24",
            Compression::B44 => "b44",
            Compression::B44a => "b44a",
            Compression::Dwaa => "dwaa",
            Compression::Dwab => "dwab",
        }
    }

    pub(crate) fn to_exr(self) -> x::Compression {
        match self {
            Compression::None => x::Compression::Uncompressed,
            Compression::Rle => x::Compression::RLE,
            Compression::Zips => x::Compression::ZIP1,
            Compression::Zip => x::Compression::ZIP16,
            Compression::Piz => x::Compression::PIZ,
            Compression::Pxr24 => x::Compression::PXR24,
            Compression::B44 => x::Compression::B44,
            Compression::B44a => x::Compression::B44A,
            Compression::Dwaa => x::Compression::DWAA(None),
            Compression::Dwab => x::Compression::DWAB(None),
        }
    }
}

impl std::str::FromStr for Compression {
    type Err = IoError;

    fn from_str(s: &str) -> Result<Self, IoError> {
        let lower = s.to_ascii_lowercase();
        Compression::ALL
            .into_iter()
            .find(|c| c.name() == lower)
            .ok_or_else(|| {
                let names: Vec<&str> = Compression::ALL.iter().map(|c| c.name()).collect();
                IoError::Argument(format!("compression {s:?}: expected one of {}", names.join(", ")))
            })
    }
}

display_name!(Compression);

/// How [`write_exr`] writes a frame.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct WriteOptions {
    /// Float precision.
    pub precision: Precision,
    /// Compression.
    pub compression: Compression,
}

pub(crate) fn exr_error(path: &Path, e: exr::error::Error) -> IoError {
    match e {
        exr::error::Error::Io(source) if source.kind() != std::io::ErrorKind::UnexpectedEof => {
            IoError::os(path, source)
        }
        other => IoError::Format {
            path: path.to_path_buf(),
            format: "OpenEXR",
            reason: other.to_string(),
        },
    }
}

/// Reads every channel of every layer (part) of an EXR file; all layers must have the same
/// size. Channel names are as [`full_channel_name`] gives them.
pub fn read_raw_exr(path: &Path) -> Result<RawImage, IoError> {
    if !path.exists() {
        return Err(IoError::os(
            path,
            std::io::Error::new(std::io::ErrorKind::NotFound, "no such file"),
        ));
    }
    let bytes = std::fs::read(path).map_err(|e| IoError::os(path, e))?;
    read_raw_exr_bytes(&bytes, path)
}

/// Reads an EXR held in memory within [`ExrLimits::FILES`]; `label` names it in errors.
pub fn read_raw_exr_bytes(bytes: &[u8], label: &Path) -> Result<RawImage, IoError> {
    check_exr_header(bytes, label, &ExrLimits::FILES)?;
    decode_exr(bytes, label, true)
}

/// Decodes every channel of every part's largest level; `parallel` lets the decoder
/// decompress on a thread pool of its own.
fn decode_exr(bytes: &[u8], label: &Path, parallel: bool) -> Result<RawImage, IoError> {
    let reader = x::read()
        .no_deep_data()
        .largest_resolution_level()
        .all_channels()
        .all_layers()
        .all_attributes();
    let reader = if parallel { reader } else { reader.non_parallel() };
    let image = reader
        .from_buffered(std::io::Cursor::new(bytes))
        .map_err(|e| exr_error(label, e))?;
    raw_from_exr(image, label)
}

/// What an EXR may declare. Every EXR the product reads (an HTTP body, a file of `filter`,
/// `batch` or `report`) has its header checked against these before a single pixel is
/// decoded, so what decoding allocates is bounded whatever the header claims.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ExrLimits {
    /// The data window every part must have (width, height); `None`: any, within
    /// `max_pixels`.
    pub size: Option<(usize, usize)>,
    /// Pixels one part may have.
    pub max_pixels: u64,
    /// Channels over all parts.
    pub max_channels: usize,
    /// Parts (layers).
    pub max_parts: usize,
    /// The header must be one the EXR writer accepts (its strict validation), because the
    /// file is written back (the server's reply is the input with its colour replaced): a
    /// file read but not writable would be filtered, then fail.
    pub rewritable: bool,
}

/// The most an EXR's samples may outgrow its file: DEFLATE (ZIP, ZIPS, PXR24) cannot
/// exceed about 1032:1, RLE 64:1 and PIZ's Huffman code with runs a few thousand to one;
/// past this a header declares more than its bytes can hold (a decompression bomb).
pub const MAX_EXR_EXPANSION: u64 = 4096;

/// Declared samples under this many bytes are never refused for their expansion.
const SMALL_DECODE_BYTES: u64 = 64 << 20;

impl ExrLimits {
    /// Limits for frames read from files (`filter`, `batch`, `report`, `info`): any size up
    /// to 16384x16384 pixels a part (16K), 16 parts and 256 channels.
    pub const FILES: ExrLimits = ExrLimits {
        size: None,
        max_pixels: 16384 * 16384,
        max_channels: 256,
        max_parts: 16,
        rewritable: false,
    };
}

/// What [`check_exr_header`] read from a header: enough to size the decode.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ExrShape {
    /// Channels over all parts.
    pub channels: usize,
    /// Parts.
    pub parts: usize,
}

/// Reads only the header of the EXR in `bytes` and checks it against `limits`: each part's
/// data window size, the number of parts and channels, no deep data, no subsampling.
pub fn check_exr_header(bytes: &[u8], label: &Path, limits: &ExrLimits) -> Result<ExrShape, IoError> {
    let refuse = |reason: String| IoError::Format {
        path: label.to_path_buf(),
        format: "OpenEXR",
        reason: format!("{reason}; refused before decoding"),
    };
    let meta = exr::meta::MetaData::read_from_buffered(std::io::Cursor::new(bytes), false)
        .map_err(|e| exr_error(label, e))?;
    if meta.headers.len() > limits.max_parts {
        return Err(refuse(format!(
            "{} parts, at most {}",
            meta.headers.len(),
            limits.max_parts
        )));
    }
    let mut channels = 0usize;
    let mut declared = 0u64;
    for (i, h) in meta.headers.iter().enumerate() {
        let part = h
            .own_attributes
            .layer_name
            .as_ref()
            .map_or(format!("part {i}"), |n| {
                format!("part {:?}", crate::echo::clip(&n.to_string()))
            });
        if h.deep {
            return Err(refuse(format!("{part} holds deep data, which is not supported")));
        }
        let (w, hh) = (h.layer_size.0, h.layer_size.1);
        match limits.size {
            Some((lw, lh)) if (w, hh) != (lw, lh) => {
                return Err(refuse(format!(
                    "{part} declares a {w}x{hh} data window, frames here are {lw}x{lh}"
                )));
            }
            None if (w as u64).saturating_mul(hh as u64) > limits.max_pixels => {
                return Err(refuse(format!(
                    "{part} declares a {w}x{hh} data window, more than the {} pixels a part may have",
                    limits.max_pixels
                )));
            }
            _ => {}
        }
        if let Some(ch) = h.channels.list.iter().find(|c| c.sampling != x::Vec2(1, 1)) {
            return Err(refuse(format!(
                "{part}: channel {} is subsampled, which is not supported",
                crate::echo::clip(&ch.name.to_string())
            )));
        }
        channels += h.channels.list.len();
        let pixels = (w as u64).saturating_mul(hh as u64);
        let bytes_per_pixel: u64 = h
            .channels
            .list
            .iter()
            .map(|c| {
                if c.sample_type == exr::meta::attribute::SampleType::F16 {
                    2
                } else {
                    4
                }
            })
            .sum();
        declared = declared.saturating_add(pixels.saturating_mul(bytes_per_pixel));
    }
    if channels > limits.max_channels {
        return Err(refuse(format!(
            "{channels} channels, at most {}",
            limits.max_channels
        )));
    }
    if limits.rewritable {
        exr::meta::MetaData::validate(&meta.headers, true).map_err(|e| {
            refuse(format!(
                "its header is one the EXR writer refuses ({e}), so no reply could be written"
            ))
        })?;
    }
    let holds = (bytes.len() as u64).saturating_mul(MAX_EXR_EXPANSION);
    if declared > SMALL_DECODE_BYTES.max(holds) {
        return Err(refuse(format!(
            "its header declares {declared} bytes of samples in a file of {} bytes, more than {MAX_EXR_EXPANSION} times its size (a decompression bomb)",
            bytes.len()
        )));
    }
    Ok(ExrShape {
        channels,
        parts: meta.headers.len(),
    })
}

/// A rectangle of pixels in an EXR's coordinates: origin (may be negative) and size.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
pub struct PixelWindow {
    /// Left column.
    pub x: i64,
    /// Top row.
    pub y: i64,
    /// Width in pixels.
    pub width: u64,
    /// Height in pixels.
    pub height: u64,
}

/// How one part of an EXR file is laid out, from its header alone.
#[derive(Clone, Debug, PartialEq, Eq, serde::Serialize)]
pub struct ExrPart {
    /// The part's layer name, if it has one.
    pub name: Option<String>,
    /// Where its pixels are (the data window).
    pub data_window: PixelWindow,
    /// The frame it belongs to (the display window, shared by all parts).
    pub display_window: PixelWindow,
    /// Compression, as OpenEXR names it (`ZIP`, `PIZ`, `NONE`, ...).
    pub compression: String,
    /// Channels in the part.
    pub channels: usize,
}

/// Reads only the headers of an EXR file: each part's windows and compression.
pub fn read_exr_parts(path: &Path) -> Result<Vec<ExrPart>, IoError> {
    let meta = exr::meta::MetaData::read_from_file(path, false).map_err(|e| exr_error(path, e))?;
    Ok(meta
        .headers
        .iter()
        .map(|h| {
            let display = h.shared_attributes.display_window;
            ExrPart {
                name: h.own_attributes.layer_name.as_ref().map(|n| n.to_string()),
                data_window: PixelWindow {
                    x: h.own_attributes.layer_position.0 as i64,
                    y: h.own_attributes.layer_position.1 as i64,
                    width: h.layer_size.0 as u64,
                    height: h.layer_size.1 as u64,
                },
                display_window: PixelWindow {
                    x: display.position.0 as i64,
                    y: display.position.1 as i64,
                    width: display.size.0 as u64,
                    height: display.size.1 as u64,
                },
                compression: compression_name(h.compression).to_string(),
                channels: h.channels.list.len(),
            }
        })
        .collect())
}

/// OpenEXR's name for a compression method (as `exrheader` and `oiiotool` print it).
fn compression_name(c: exr::compression::Compression) -> &'static str {
    use exr::compression::Compression as C;
    match c {
        C::Uncompressed => "NONE",
        C::RLE => "RLE",
        C::ZIP1 => "ZIPS",
        C::ZIP16 => "ZIP",
        C::PIZ => "PIZ",
        C::PXR24 => "PXR24",
        C::B44 => "B44",
        C::B44A => "B44A",
        C::DWAA(_) => "DWAA",
        C::DWAB(_) => "DWAB",
        _ => "other",
    }
}

/// Reads an EXR from an untrusted source: the header is checked against `limits` first
/// ([`check_exr_header`]), then the pixels are decoded on the calling thread (no thread
/// pool of the decoder's own).
pub fn read_raw_exr_bytes_limited(
    bytes: &[u8],
    label: &Path,
    limits: &ExrLimits,
) -> Result<RawImage, IoError> {
    check_exr_header(bytes, label, limits)?;
    decode_exr(bytes, label, false)
}

type AnyImage = x::Image<x::Layers<x::AnyChannels<x::FlatSamples>>>;

/// Everything in an EXR file but its samples: the shared header, and each part's attributes,
/// windows, encoding and channel types. With the samples of a [`RawImage`] it rebuilds the
/// file (see `io::output`).
#[derive(Clone, Debug, PartialEq)]
pub struct ExrHeaders {
    pub(crate) image: x::ImageAttributes,
    pub(crate) parts: Vec<PartHeader>,
}

/// One part (layer) of an [`ExrHeaders`].
#[derive(Clone, Debug, PartialEq)]
pub(crate) struct PartHeader {
    pub(crate) attributes: x::LayerAttributes,
    pub(crate) size: (usize, usize),
    pub(crate) encoding: x::Encoding,
    pub(crate) channels: Vec<ChannelHeader>,
}

/// One channel of a [`PartHeader`].
#[derive(Clone, Debug, PartialEq)]
pub(crate) struct ChannelHeader {
    /// The name inside its part.
    pub(crate) name: Text,
    /// The name in the [`RawImage`] (`part.channel` for named parts).
    pub(crate) full_name: String,
    pub(crate) sample_type: x::SampleType,
    pub(crate) quantize_linearly: bool,
}

impl ExrHeaders {
    /// The data window's origin (the same for every part).
    pub fn data_origin(&self) -> (i64, i64) {
        let p = self.parts[0].attributes.layer_position;
        (p.0 as i64, p.1 as i64)
    }

    /// The frame index the file declares (`afterimage.index`; the last part that has one,
    /// as the frame's values are read), if it does.
    pub fn frame_index(&self) -> Option<u64> {
        self.parts
            .iter()
            .rev()
            .find_map(|p| match p.attributes.other.get(&Text::from(attr::INDEX)) {
                Some(AttributeValue::Text(t)) => t.to_string().parse().ok(),
                _ => None,
            })
    }

    /// The display window: origin and size.
    pub fn display_window(&self) -> PixelWindow {
        let d = self.image.display_window;
        PixelWindow {
            x: d.position.0 as i64,
            y: d.position.1 as i64,
            width: d.size.0 as u64,
            height: d.size.1 as u64,
        }
    }
}

/// The name a channel of part `part` gets in a [`RawImage`]. A name that already carries
/// its layer (it has a `.`, as compositors and Blender write full names such as
/// `ViewLayer.Vector.X` into any part) is used as written; a bare one (`R`) gets the part's
/// name as prefix (`rgba.R`), as in single-part multilayer files. Unnamed parts add nothing.
pub fn full_channel_name(part: Option<&str>, channel: &str) -> String {
    match part {
        Some(p) if !p.is_empty() && !channel.contains('.') => format!("{p}.{channel}"),
        _ => channel.to_string(),
    }
}

fn raw_from_exr(image: AnyImage, path: &Path) -> Result<RawImage, IoError> {
    let mut first: Option<(x::Vec2<usize>, x::Vec2<i32>, Option<String>)> = None;
    let mut channels = Vec::new();
    let mut parts = Vec::new();
    let mut meta = FrameMeta::default();
    let mut shading = Sampling::FULL;
    // Full channel name -> the part it came from, to refuse a name given twice.
    let mut seen = std::collections::HashMap::new();
    for layer in image.layer_data {
        let lname = layer.attributes.layer_name.as_ref().map(|t| t.to_string());
        let position = layer.attributes.layer_position;
        match &first {
            None => first = Some((layer.size, position, lname.clone())),
            Some((size, pos, first_name)) if *size != layer.size || *pos != position => {
                return Err(IoError::Inconsistent {
                    path: path.to_path_buf(),
                    reason: format!(
                        "layer {} has data window {}x{} at ({}, {}) but layer {} has {}x{} at ({}, {})",
                        lname.as_deref().unwrap_or("(unnamed)"),
                        layer.size.0,
                        layer.size.1,
                        position.0,
                        position.1,
                        first_name.as_deref().unwrap_or("(unnamed)"),
                        size.0,
                        size.1,
                        pos.0,
                        pos.1,
                    ),
                })
            }
            _ => {}
        }
        read_meta(&layer.attributes, &mut meta);
        if let Some(AttributeValue::IntVec3((f, px, py))) =
            layer.attributes.other.get(&Text::from(attr::SHADING))
        {
            let s = [f, px, py].map(|&v| u32::try_from(v).unwrap_or(u32::MAX));
            shading = Sampling {
                factor: s[0],
                phase: [s[1], s[2]],
            };
            shading.validate().map_err(|reason| IoError::Format {
                path: path.to_path_buf(),
                format: "OpenEXR",
                reason: format!("attribute {}: {reason}", attr::SHADING),
            })?;
        }
        let mut headers = Vec::new();
        for ch in layer.channel_data.list {
            if ch.sampling != x::Vec2(1, 1) {
                return Err(IoError::Format {
                    path: path.to_path_buf(),
                    format: "OpenEXR",
                    reason: format!("channel {} is subsampled, which is not supported", ch.name),
                });
            }
            let name = full_channel_name(lname.as_deref(), &ch.name.to_string());
            let part = lname.as_deref().unwrap_or("(unnamed)");
            if let Some(earlier) = seen.insert(name.clone(), part.to_string()) {
                return Err(IoError::Inconsistent {
                    path: path.to_path_buf(),
                    reason: format!(
                        "channel {name} is in part {earlier} and again in part {part}; each channel once expected"
                    ),
                });
            }
            let (file_type, sample_type, data) = match ch.sample_data {
                x::FlatSamples::F16(v) => (
                    "f16",
                    x::SampleType::F16,
                    RawData::F32(v.iter().map(|h| h.to_f32()).collect()),
                ),
                x::FlatSamples::F32(v) => ("f32", x::SampleType::F32, RawData::F32(v)),
                x::FlatSamples::U32(v) => ("u32", x::SampleType::U32, RawData::U32(v)),
            };
            headers.push(ChannelHeader {
                name: ch.name,
                full_name: name.clone(),
                sample_type,
                quantize_linearly: ch.quantize_linearly,
            });
            channels.push(RawChannel {
                name,
                file_type,
                data,
            });
        }
        parts.push(PartHeader {
            attributes: layer.attributes,
            size: (layer.size.0, layer.size.1),
            encoding: layer.encoding,
            channels: headers,
        });
    }
    let Some((size, _, _)) = first else {
        return Err(IoError::Format {
            path: path.to_path_buf(),
            format: "OpenEXR",
            reason: "the file has no layers".into(),
        });
    };
    channels.sort_by(|a, b| a.name.cmp(&b.name));
    Ok(RawImage {
        path: path.to_path_buf(),
        width: size.0,
        height: size.1,
        channels,
        meta,
        shading,
        exr: Some(ExrHeaders {
            image: image.attributes,
            parts,
        }),
    })
}

fn read_meta(a: &x::LayerAttributes, meta: &mut FrameMeta) {
    if let Some(e) = a.exposure {
        meta.exposure = Some(e);
    }
    if let (Some(n), Some(f)) = (a.near_clip_plane, a.far_clip_plane) {
        meta.near_far = Some([n, f]);
    }
    let get = |k: &str| a.other.get(&Text::from(k));
    if let Some(AttributeValue::Text(t)) = get(attr::INDEX) {
        if let Ok(i) = t.to_string().parse() {
            meta.index = i;
        }
    }
    if let Some(AttributeValue::FloatVec2(v)) = get(attr::JITTER) {
        // The reconstruct stage weighs samples by it: a value that is no jitter is
        // taken as unknown (0), as a missing one is.
        let j = [v.0, v.1];
        if FrameMeta::jitter_in_range(j) {
            meta.jitter = j;
        } else {
            tracing::warn!(jitter = ?j, "{}: not finite and within -1..=1 pixels, taken as unknown", attr::JITTER);
        }
    }
    if let Some(AttributeValue::I32(r)) = get(attr::RESET) {
        meta.reset = *r != 0;
    }
    if let Some(AttributeValue::Text(t)) = get(attr::DEPTH_KIND) {
        if let Ok(k) = serde_json::from_value::<DepthKind>(t.to_string().into()) {
            meta.depth_kind = k;
        }
    }
    if let Some(AttributeValue::Text(t)) = get(attr::NORMAL_SPACE) {
        if let Ok(k) = serde_json::from_value::<NormalSpace>(t.to_string().into()) {
            meta.normal_space = k;
        }
    }
}

pub(crate) fn write_meta(meta: &FrameMeta, a: &mut x::LayerAttributes) {
    a.exposure = meta.exposure;
    if let Some([n, f]) = meta.near_far {
        a.near_clip_plane = Some(n);
        a.far_clip_plane = Some(f);
    }
    let mut put = |k: &str, v: AttributeValue| {
        a.other.insert(Text::from(k), v);
    };
    put(
        attr::INDEX,
        AttributeValue::Text(Text::from(meta.index.to_string().as_str())),
    );
    put(
        attr::JITTER,
        AttributeValue::FloatVec2(x::Vec2(meta.jitter[0], meta.jitter[1])),
    );
    put(attr::RESET, AttributeValue::I32(meta.reset as i32));
    let name = |v: serde_json::Value| v.as_str().unwrap_or_default().to_string();
    put(
        attr::DEPTH_KIND,
        AttributeValue::Text(Text::from(name(serde_json::json!(meta.depth_kind)).as_str())),
    );
    put(
        attr::NORMAL_SPACE,
        AttributeValue::Text(Text::from(name(serde_json::json!(meta.normal_space)).as_str())),
    );
}

/// Samples at `precision`: f16 rounds to nearest (values widened from f16 come back exactly).
pub(crate) fn float_samples(v: &[f32], precision: Precision) -> x::FlatSamples {
    match precision {
        Precision::F32 => x::FlatSamples::F32(v.to_vec()),
        Precision::F16 => x::FlatSamples::F16(v.iter().map(|&v| half::f16::from_f32(v)).collect()),
    }
}

/// Writes a frame as OpenEXR.
pub fn write_exr(path: &Path, frame: &Frame, opts: &WriteOptions) -> Result<(), IoError> {
    let layer = exr_layer(frame, opts);
    if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).map_err(|e| IoError::os(dir, e))?;
    }
    x::Image::from_layer(layer)
        .write()
        .to_file(path)
        .map_err(|e| exr_error(path, e))
}

/// The whole frame in the `afterimage` layout: every channel under the preset's names, and
/// the frame values as attributes.
fn exr_layer(frame: &Frame, opts: &WriteOptions) -> x::Layer<x::AnyChannels<x::FlatSamples>> {
    let mut list: Vec<x::AnyChannel<x::FlatSamples>> = Vec::new();
    for kind in frame.channels().iter() {
        let names = Preset::Afterimage
            .names(kind)
            .expect("afterimage names every channel");
        if kind == ChannelKind::ObjectId {
            let ids = frame.object_id().expect("listed channel exists");
            list.push(x::AnyChannel::new(
                names[0].as_str(),
                x::FlatSamples::U32(ids.data().to_vec()),
            ));
            continue;
        }
        let scattered;
        let planes = if kind == ChannelKind::Color {
            scattered = frame.color_scattered();
            &scattered[..]
        } else {
            frame.planes(kind).expect("listed channel exists")
        };
        for (p, n) in planes.iter().zip(&names) {
            list.push(x::AnyChannel::new(
                n.as_str(),
                float_samples(p.data(), opts.precision),
            ));
        }
    }
    let mut attributes = x::LayerAttributes::default();
    write_meta(&frame.meta, &mut attributes);
    let s = frame.sampling();
    if !s.is_full() {
        attributes.other.insert(
            Text::from(attr::SHADING),
            AttributeValue::IntVec3((s.factor as i32, s.phase[0] as i32, s.phase[1] as i32)),
        );
    }
    let encoding = x::Encoding {
        compression: opts.compression.to_exr(),
        blocks: x::Blocks::ScanLines,
        line_order: x::LineOrder::Increasing,
    };
    x::Layer::new(
        (frame.width(), frame.height()),
        attributes,
        encoding,
        x::AnyChannels::sort(list.into()),
    )
}

/// Encodes a frame as OpenEXR in memory (an HTTP reply).
pub fn write_exr_bytes(frame: &Frame, opts: &WriteOptions) -> Result<Vec<u8>, IoError> {
    let mut out = std::io::Cursor::new(Vec::new());
    x::Image::from_layer(exr_layer(frame, opts))
        .write()
        .to_buffered(&mut out)
        .map_err(|e| exr_error(Path::new("(reply)"), e))?;
    Ok(out.into_inner())
}
