//! The one writer of filtered frames, shared by `afterimage filter`, the HTTP reply and
//! `afterimage stream --output`.
//!
//! A filtered frame replaces its input file in a pipeline, so by default the output is the
//! input with only its colour changed: every part, channel and header attribute is kept
//! under its own name and sample type, channels are bit-identical, data and display
//! windows are the input's (negative origins and overscan included), and the filtered
//! colour goes back into the input's colour channels (`ViewLayer.Combined.R`, or `R,G,B`
//! for plain files), in their sample type unless [`OutputOptions::precision`] says
//! otherwise. The colour's part gains the frame values (`afterimage.index`, `.jitter`,
//! `.reset`) and the frame's record as JSON (`afterimage.record`); a sparse-shading
//! declaration (`afterimage.shading`) is dropped, since the output colour is dense.
//!
//! The output's extension picks its format ([`super::OutputFormat`]): OpenEXR as above, or
//! PNG/JPEG holding the filtered colour alone as 8-bit sRGB, clamped to [0, 1].
//!
//! Alpha is passed through unchanged: filters work on colour alone. Where the input's
//! colour is premultiplied by a coverage alpha (Blender's transparent film), the filtered
//! colour of an edge pixel sits over the input's coverage of that pixel, which differs
//! from the history's by the sub-pixel motion of the edge; over an opaque background
//! (alpha 1 everywhere) nothing changes.

use super::exr_file::{float_samples, Compression, ExrHeaders, Precision};
use super::preset::ReadOptions;
use super::raw::{RawData, RawImage};
use super::IoError;
use crate::frame::{FrameMeta, Rgb};
use exr::prelude::{self as x, AttributeValue, Text, WritableImage};
use std::path::Path;

/// Attribute that carries the frame's record (JSON) in written files.
pub const RECORD_ATTRIBUTE: &str = "afterimage.record";

/// Which of the input's channels an output keeps besides the filtered colour.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Keep {
    /// Every part, channel and attribute of the input (a drop-in replacement).
    #[default]
    All,
    /// The colour's part with its colour and alpha channels only.
    Filtered,
    /// Nothing of the input but its windows: the filtered colour as `R,G,B`.
    None,
}

impl Keep {
    /// Every choice, by name.
    pub const ALL: [Keep; 3] = [Keep::All, Keep::Filtered, Keep::None];

    /// The name `--keep` takes.
    pub fn name(self) -> &'static str {
        match self {
            Keep::All => "all",
            Keep::Filtered => "filtered",
            Keep::None => "none",
        }
    }
}

impl Keep {
    /// The one of `self` and `other` that keeps less.
    pub fn narrower(self, other: Keep) -> Keep {
        let rank = |k: Keep| match k {
            Keep::None => 0,
            Keep::Filtered => 1,
            Keep::All => 2,
        };
        if rank(self) <= rank(other) {
            self
        } else {
            other
        }
    }
}

impl std::str::FromStr for Keep {
    type Err = IoError;

    fn from_str(s: &str) -> Result<Self, IoError> {
        Keep::ALL
            .into_iter()
            .find(|k| k.name() == s)
            .ok_or_else(|| IoError::Argument(format!("keep {s:?}: expected one of all, filtered, none")))
    }
}

/// How a filtered frame is written. An input trimmed to keep less (see
/// [`InputImage::trim_to`]) is written with the narrower of the two.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct OutputOptions {
    /// What of the input is kept.
    pub keep: Keep,
    /// Compression of every part (None: each part's own; ZIP when there is no EXR input).
    pub compression: Option<Compression>,
    /// Sample type of the filtered colour (None: the input colour's; f32 without an EXR input).
    pub precision: Option<Precision>,
}

/// The decoded input file a filtered frame replaces: its channels and headers, and which
/// channels hold the colour.
#[derive(Clone, Debug)]
pub struct InputImage {
    raw: RawImage,
    color: [String; 3],
    /// What an output of it can still keep ([`InputImage::trim_to`]).
    holds: Keep,
}

impl InputImage {
    /// Keeps `raw` (as decoded) for writing the result of filtering it; `opts` says which
    /// channels are its colour. The colour's own samples are dropped: the result replaces them.
    pub fn new(mut raw: RawImage, opts: &ReadOptions) -> Result<InputImage, IoError> {
        let mapping = raw.mapping(opts)?;
        let color: [String; 3] = mapping[0]
            .1
            .clone()
            .try_into()
            .map_err(|_| IoError::Argument("colour needs 3 components".into()))?;
        for ch in raw.channels.iter_mut().filter(|c| color.contains(&c.name)) {
            ch.data = RawData::F32(Vec::new());
        }
        Ok(InputImage {
            raw,
            color,
            holds: Keep::All,
        })
    }

    /// Drops the samples an output written with `keep` will not use (a windowed filter
    /// holds its inputs for `lookahead` frames): all but the alpha for
    /// [`Keep::Filtered`], all for [`Keep::None`].
    /// An output asked to keep more than that afterwards keeps only what is left.
    pub fn trim_to(&mut self, keep: Keep) {
        self.holds = keep.narrower(self.holds);
        let keep = self.holds;
        let alpha = self.alpha_name().map(str::to_string);
        for ch in &mut self.raw.channels {
            let used = match keep {
                Keep::All => true,
                Keep::Filtered => Some(&ch.name) == alpha.as_ref(),
                Keep::None => false,
            };
            if !used {
                ch.data = RawData::F32(Vec::new());
            }
        }
    }

    /// The input's colour channel names.
    pub fn color_names(&self) -> &[String; 3] {
        &self.color
    }

    /// The alpha beside the colour: the colour's `R` name with `A` for its last component.
    pub fn alpha_name(&self) -> Option<&str> {
        let r = &self.color[0];
        let stem = r.rsplit_once('.').map_or("", |(s, _)| s);
        let want = if stem.is_empty() {
            "A".to_string()
        } else {
            format!("{stem}.A")
        };
        self.raw.channel(&want).map(|c| c.name.as_str())
    }

    /// Bytes of samples held (what keeping it costs).
    pub fn bytes(&self) -> u64 {
        self.raw
            .channels
            .iter()
            .map(|c| match &c.data {
                RawData::F32(v) => v.len() as u64 * 4,
                RawData::U32(v) => v.len() as u64 * 4,
            })
            .sum()
    }

    /// The decoded input (colour samples dropped).
    pub fn raw(&self) -> &RawImage {
        &self.raw
    }
}

/// One filtered frame to write.
#[derive(Clone, Copy, Debug)]
pub struct FilteredFrame<'a> {
    /// The filtered colour.
    pub color: &'a Rgb,
    /// The frame's values (index, jitter, reset), written as attributes.
    pub meta: &'a FrameMeta,
    /// The frame's record as JSON, written as [`RECORD_ATTRIBUTE`].
    pub record: Option<&'a str>,
    /// The input it replaces (None: a frame without a file, such as a generated scene).
    pub input: Option<&'a InputImage>,
}

type AnyImage = x::Image<x::Layers<x::AnyChannels<x::FlatSamples>>>;

/// Writes a filtered frame to `path` (see the module docs), creating its directory. The
/// file appears whole or not at all: it is written under a hidden temporary name beside
/// `path` (`.NAME.partial`) and renamed into place, so a reader, or a run that was killed
/// and is resumed, never sees half a frame under the real name.
pub fn write_filtered(path: &Path, frame: &FilteredFrame, opts: &OutputOptions) -> Result<(), IoError> {
    let format = super::OutputFormat::of(path)?;
    if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).map_err(|e| IoError::os(dir, e))?;
    }
    let (mut file, partial) = create_partial(path)?;
    if format != super::OutputFormat::Exr {
        let bytes = super::ldr::encode_ldr(frame.color, format, path)?;
        std::io::Write::write_all(&mut file, &bytes).map_err(|e| IoError::os(&partial, e))?;
        drop(file);
        return std::fs::rename(&partial, path).map_err(|e| IoError::os(path, e));
    }
    let image = filtered_image(frame, opts, path)?;
    image
        .write()
        .to_buffered(std::io::BufWriter::new(file))
        .map_err(|e| super::exr_file::exr_error(&partial, e))?;
    std::fs::rename(&partial, path).map_err(|e| IoError::os(path, e))
}

/// Creates the hidden file `path` is written under ([`partial_path`]), new: whatever was
/// at that name is removed first (a symbolic link itself, never its target), and the file
/// is created exclusively, so a link planted in between fails the write instead of
/// redirecting it.
pub fn create_partial(path: &Path) -> Result<(std::fs::File, std::path::PathBuf), IoError> {
    let partial = partial_path(path);
    match std::fs::remove_file(&partial) {
        Err(e) if e.kind() != std::io::ErrorKind::NotFound => return Err(IoError::os(&partial, e)),
        _ => {}
    }
    let file = std::fs::OpenOptions::new()
        .write(true)
        .create_new(true)
        .open(&partial)
        .map_err(|e| IoError::os(&partial, e))?;
    Ok((file, partial))
}

/// The hidden name a file is written under before it is renamed to `path` (`.NAME.partial`
/// beside it), so that it appears whole or not at all.
pub fn partial_path(path: &Path) -> std::path::PathBuf {
    let name = path
        .file_name()
        .map_or("file".into(), |n| n.to_string_lossy().into_owned());
    path.with_file_name(format!(".{name}.partial"))
}

/// Encodes a filtered frame as EXR bytes (an HTTP reply), as [`write_filtered`] writes it,
/// compressing on the calling thread.
pub fn encode_filtered(frame: &FilteredFrame, opts: &OutputOptions) -> Result<Vec<u8>, IoError> {
    encode(frame, opts, Path::new("(reply)"), false)
}

/// Encodes a filtered frame bound for `path` (an object store, or a file written by a
/// [`super::Storage`]) exactly as [`write_filtered`] writes it, in the format its extension
/// names, EXR blocks compressed on the pool.
pub fn encode_filtered_for(
    path: &Path,
    frame: &FilteredFrame,
    opts: &OutputOptions,
) -> Result<Vec<u8>, IoError> {
    match super::OutputFormat::of(path)? {
        super::OutputFormat::Exr => encode(frame, opts, path, true),
        format => super::ldr::encode_ldr(frame.color, format, path),
    }
}

fn encode(
    frame: &FilteredFrame,
    opts: &OutputOptions,
    label: &Path,
    parallel: bool,
) -> Result<Vec<u8>, IoError> {
    let image = filtered_image(frame, opts, label)?;
    let mut out = std::io::Cursor::new(Vec::new());
    let written = if parallel {
        image.write().to_buffered(&mut out)
    } else {
        image.write().non_parallel().to_buffered(&mut out)
    };
    written.map_err(|e| super::exr_file::exr_error(label, e))?;
    Ok(out.into_inner())
}

/// Puts the frame values, the record, and no sparse-shading declaration into `a`.
fn set_frame_attributes(frame: &FilteredFrame, a: &mut x::LayerAttributes) {
    super::exr_file::write_meta(frame.meta, a);
    a.other.remove(&Text::from(super::exr_file::SHADING_ATTRIBUTE));
    match frame.record.and_then(Text::new_or_none) {
        Some(t) => a
            .other
            .insert(Text::from(RECORD_ATTRIBUTE), AttributeValue::Text(t)),
        None => a.other.remove(&Text::from(RECORD_ATTRIBUTE)),
    };
}

fn filtered_image(frame: &FilteredFrame, opts: &OutputOptions, label: &Path) -> Result<AnyImage, IoError> {
    let (w, h) = (frame.color[0].width(), frame.color[0].height());
    let input = frame.input.filter(|i| i.raw.exr.is_some());
    if let Some(i) = input {
        if (i.raw.width, i.raw.height) != (w, h) {
            return Err(IoError::Inconsistent {
                path: label.to_path_buf(),
                reason: format!(
                    "the filtered colour is {w}x{h} but the input's data window is {}x{}",
                    i.raw.width, i.raw.height
                ),
            });
        }
    }
    let keep = input.map_or(Keep::None, |i| opts.keep.narrower(i.holds));
    match input {
        Some(i) if keep != Keep::None => {
            let headers = i.raw.exr.as_ref().expect("filtered on exr");
            kept_image(frame, i, headers, &OutputOptions { keep, ..*opts })
        }
        _ => Ok(color_only_image(frame, input, opts)),
    }
}

/// The filtered colour alone as `R,G,B`: in the input's windows, the input colour's sample
/// type and its part's compression when there is an EXR input (f32 and ZIP otherwise).
fn color_only_image(frame: &FilteredFrame, input: Option<&InputImage>, opts: &OutputOptions) -> AnyImage {
    let headers = input.and_then(|i| i.raw.exr.as_ref());
    // The part and channel header of the input's red.
    let red = input.zip(headers).and_then(|(i, h)| {
        h.parts.iter().find_map(|p| {
            p.channels
                .iter()
                .find(|c| c.full_name == i.color[0])
                .map(|c| (p, c))
        })
    });
    let precision = opts.precision.unwrap_or(match red {
        Some((_, c)) if c.sample_type == x::SampleType::F16 => Precision::F16,
        _ => Precision::F32,
    });
    let list: Vec<_> = frame
        .color
        .iter()
        .zip(["R", "G", "B"])
        .map(|(p, n)| x::AnyChannel::new(n, float_samples(p.data(), precision)))
        .collect();
    let mut attributes = x::LayerAttributes::default();
    set_frame_attributes(frame, &mut attributes);
    let size = (frame.color[0].width(), frame.color[0].height());
    let image_attributes = match headers {
        Some(h) => {
            attributes.layer_position = h.parts[0].attributes.layer_position;
            let mut a = x::ImageAttributes::new(h.image.display_window);
            a.pixel_aspect = h.image.pixel_aspect;
            a
        }
        None => x::ImageAttributes::new(x::IntegerBounds::from_dimensions(size)),
    };
    let encoding = x::Encoding {
        compression: match (opts.compression, red) {
            (Some(c), _) => c.to_exr(),
            (None, Some((p, _))) => p.encoding.compression,
            (None, None) => Compression::Zip.to_exr(),
        },
        blocks: x::Blocks::ScanLines,
        line_order: x::LineOrder::Increasing,
    };
    let layer = x::Layer::new(size, attributes, encoding, x::AnyChannels::sort(list.into()));
    x::Image::from_layers(image_attributes, vec![layer])
}

/// The input's parts with the colour replaced, as [`OutputOptions::keep`] says.
fn kept_image(
    frame: &FilteredFrame,
    input: &InputImage,
    headers: &ExrHeaders,
    opts: &OutputOptions,
) -> Result<AnyImage, IoError> {
    let alpha = input.alpha_name();
    let mut layers = Vec::new();
    for part in &headers.parts {
        let holds_color = part.channels.iter().any(|c| input.color.contains(&c.full_name));
        let mut list = Vec::new();
        for ch in &part.channels {
            let color_index = input.color.iter().position(|n| *n == ch.full_name);
            let kept = match opts.keep {
                Keep::All => true,
                Keep::Filtered => color_index.is_some() || Some(ch.full_name.as_str()) == alpha,
                Keep::None => unreachable!("colour-only output is written elsewhere"),
            };
            if !kept {
                continue;
            }
            let samples = match color_index {
                Some(k) => {
                    let precision = opts.precision.unwrap_or(match ch.sample_type {
                        x::SampleType::F16 => Precision::F16,
                        _ => Precision::F32,
                    });
                    float_samples(frame.color[k].data(), precision)
                }
                None => passed_through(input, ch)?,
            };
            let mut c = x::AnyChannel::new(ch.name.clone(), samples);
            c.quantize_linearly = ch.quantize_linearly;
            list.push(c);
        }
        if list.is_empty() {
            continue;
        }
        let mut attributes = part.attributes.clone();
        if holds_color {
            set_frame_attributes(frame, &mut attributes);
        } else {
            // The frame's values live on the colour's part alone; stale copies elsewhere
            // would be read back over them.
            attributes
                .other
                .retain(|k, _| !k.to_string().starts_with("afterimage."));
        }
        let mut encoding = part.encoding;
        if let Some(c) = opts.compression {
            encoding.compression = c.to_exr();
        }
        layers.push(x::Layer::new(
            part.size,
            attributes,
            encoding,
            x::AnyChannels::sort(list.into()),
        ));
    }
    Ok(x::Image::from_layers(headers.image.clone(), layers))
}

/// An input channel's samples in their file type again (f16 samples were widened exactly,
/// so narrowing them gives the same bits back).
fn passed_through(
    input: &InputImage,
    ch: &super::exr_file::ChannelHeader,
) -> Result<x::FlatSamples, IoError> {
    let raw = input
        .raw
        .channel(&ch.full_name)
        .ok_or_else(|| IoError::Inconsistent {
            path: input.raw.path.clone(),
            reason: format!("channel {} is in the header but was not decoded", ch.full_name),
        })?;
    let len = match &raw.data {
        RawData::F32(v) => v.len(),
        RawData::U32(v) => v.len(),
    };
    if len != input.raw.width * input.raw.height {
        return Err(IoError::Inconsistent {
            path: input.raw.path.clone(),
            reason: format!(
                "channel {} holds {len} samples, not the {}x{} of its part",
                ch.full_name, input.raw.width, input.raw.height
            ),
        });
    }
    Ok(match (&raw.data, ch.sample_type) {
        (RawData::F32(v), x::SampleType::F16) => float_samples(v, Precision::F16),
        (RawData::F32(v), _) => x::FlatSamples::F32(v.clone()),
        (RawData::U32(v), _) => x::FlatSamples::U32(v.clone()),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn blender_input() -> InputImage {
        let path =
            Path::new(env!("CARGO_MANIFEST_DIR")).join("../../tests/fixtures/blender-motion/frame_0001.exr");
        let raw = super::super::read_raw_exr(&path).unwrap();
        InputImage::new(raw, &ReadOptions::default()).unwrap()
    }

    #[test]
    fn an_input_holds_only_what_its_output_keeps() {
        let px = 320 * 180 * 4;
        let mut input = blender_input();
        assert_eq!(input.color_names()[0], "ViewLayer.Combined.R");
        assert_eq!(input.alpha_name(), Some("ViewLayer.Combined.A"));
        // 16 channels, the 3 colour ones dropped at once: they are replaced.
        assert_eq!(input.bytes(), 13 * px);
        input.trim_to(Keep::All);
        assert_eq!(input.bytes(), 13 * px);
        input.trim_to(Keep::Filtered);
        assert_eq!(input.bytes(), px, "alpha alone");
        input.trim_to(Keep::None);
        assert_eq!(input.bytes(), 0);
    }

    #[test]
    fn options_parse_by_name_and_refuse_others_naming_the_choices() {
        assert_eq!("filtered".parse::<Keep>().unwrap(), Keep::Filtered);
        for c in Compression::ALL {
            assert_eq!(c.name().parse::<Compression>().unwrap(), c);
        }
        assert_eq!("PIZ".parse::<Compression>().unwrap(), Compression::Piz);
        let e = "lzw".parse::<Compression>().unwrap_err().to_string();
        assert!(e.contains("lzw") && e.contains("dwab"), "{e}");
        let e = "most".parse::<Keep>().unwrap_err().to_string();
        assert!(e.contains("filtered"), "{e}");
    }
}
