//! A decoded image as named channels, before any preset maps them onto a frame.

use super::exr_file::ExrHeaders;
use super::preset::{Preset, ReadOptions};
use super::IoError;
use crate::frame::{ChannelKind, Frame, FrameMeta, MotionConvention, Plane, SampleKind, Sampling};
use std::path::PathBuf;

/// Samples of one file channel, widened to 32 bits.
#[derive(Clone, Debug, PartialEq)]
pub enum RawData {
    /// Float samples (f16 in the file is widened exactly).
    F32(Vec<f32>),
    /// Unsigned integer samples.
    U32(Vec<u32>),
}

/// One named channel of a file.
#[derive(Clone, Debug, PartialEq)]
pub struct RawChannel {
    /// Full name, with the layer prefix of multi-part files (`ViewLayer.Combined.R`).
    pub name: String,
    /// Sample type in the file: "f16", "f32" or "u32".
    pub file_type: &'static str,
    /// The samples, row-major.
    pub data: RawData,
}

/// Value range of one channel.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct ChannelStats {
    /// Smallest finite sample (None when there is none).
    pub min: Option<f64>,
    /// Largest finite sample.
    pub max: Option<f64>,
    /// Mean of the finite samples.
    pub mean: Option<f64>,
    /// NaN samples.
    pub nan: u64,
    /// Infinite samples.
    pub inf: u64,
}

impl RawChannel {
    /// Range, mean and non-finite counts of the samples.
    pub fn stats(&self) -> ChannelStats {
        let (mut min, mut max, mut sum, mut n, mut nan, mut inf) =
            (f64::INFINITY, f64::NEG_INFINITY, 0.0f64, 0u64, 0u64, 0u64);
        let mut add = |v: f64| {
            if v.is_nan() {
                nan += 1;
            } else if v.is_infinite() {
                inf += 1;
            } else {
                min = min.min(v);
                max = max.max(v);
                sum += v;
                n += 1;
            }
        };
        match &self.data {
            RawData::F32(v) => v.iter().for_each(|&x| add(x as f64)),
            RawData::U32(v) => v.iter().for_each(|&x| add(x as f64)),
        }
        ChannelStats {
            min: (n > 0).then_some(min),
            max: (n > 0).then_some(max),
            mean: (n > 0).then(|| sum / n as f64),
            nan,
            inf,
        }
    }
}

/// A decoded image: its size, its channels by name, and the frame values stored with it.
#[derive(Clone, Debug, PartialEq)]
pub struct RawImage {
    /// Where it came from.
    pub path: PathBuf,
    /// Width in pixels.
    pub width: usize,
    /// Height in pixels.
    pub height: usize,
    /// Channels, sorted by name.
    pub channels: Vec<RawChannel>,
    /// Per-frame values found in the file's attributes (defaults where absent).
    pub meta: FrameMeta,
    /// Sparse shading the file declares (`afterimage.shading`): its colour holds shaded
    /// samples at their pixels and is gathered into the frame's smaller colour planes.
    pub shading: Sampling,
    /// The file's headers when it is an EXR: what a filtered result keeps of it.
    pub exr: Option<ExrHeaders>,
}

impl RawImage {
    /// The channel called `name`.
    pub fn channel(&self, name: &str) -> Option<&RawChannel> {
        self.channels.iter().find(|c| c.name == name)
    }

    /// All channel names, comma-separated (for error messages).
    pub fn names(&self) -> String {
        self.channels
            .iter()
            .map(|c| c.name.as_str())
            .collect::<Vec<_>>()
            .join(", ")
    }

    /// The preset to use for this file under `opts` (detected when `auto`).
    pub fn preset(&self, opts: &ReadOptions) -> Result<Preset, IoError> {
        let color_mapped = opts.mapping.iter().any(|(k, _)| *k == ChannelKind::Color);
        opts.preset.resolve(self, color_mapped)
    }

    /// The motion convention for this file under `opts`.
    pub fn motion_convention(&self, opts: &ReadOptions) -> Result<MotionConvention, IoError> {
        match opts.motion_convention {
            Some(c) => Ok(c),
            None => Ok(self.preset(opts)?.motion_convention()),
        }
    }

    /// Which file channels make which frame channel under `opts`: colour must resolve;
    /// any other channel is taken when all its components are present, and is an error
    /// when only some are, or when an explicit mapping names missing channels.
    pub fn mapping(&self, opts: &ReadOptions) -> Result<Vec<(ChannelKind, Vec<String>)>, IoError> {
        let preset = self.preset(opts)?;
        let mut out = Vec::new();
        for kind in ChannelKind::ALL {
            let explicit = opts.mapping.iter().find(|(k, _)| *k == kind).map(|(_, s)| s);
            let names = match explicit {
                Some(spec) => Some(
                    spec.resolve(kind, self)
                        .map_err(|wanted| IoError::MissingChannel {
                            path: self.path.clone(),
                            channel: kind,
                            wanted,
                            preset: "explicit --channel".into(),
                            present: self.names(),
                        })?,
                ),
                None => preset.names(kind),
            };
            let Some(names) = names else { continue };
            let missing: Vec<&str> = names
                .iter()
                .filter(|n| self.channel(n).is_none())
                .map(String::as_str)
                .collect();
            if missing.len() == names.len() && kind != ChannelKind::Color {
                continue;
            }
            if !missing.is_empty() {
                return Err(IoError::MissingChannel {
                    path: self.path.clone(),
                    channel: kind,
                    wanted: missing.join(", "),
                    preset: preset.to_string(),
                    present: self.names(),
                });
            }
            out.push((kind, names));
        }
        Ok(out)
    }

    /// Maps the channels onto a frame (see [`RawImage::mapping`]). Motion is left in the
    /// file's convention (see [`RawImage::motion_convention`]).
    pub fn to_frame(&self, opts: &ReadOptions) -> Result<Frame, IoError> {
        let mapping = self.mapping(opts)?;
        let chan = |n: &String| self.channel(n).expect("mapping checked every name");
        let to_f32 = |c: &RawChannel| -> Result<Plane<f32>, IoError> {
            let v = match &c.data {
                RawData::F32(v) => v.clone(),
                RawData::U32(v) => v.iter().map(|&x| x as f32).collect(),
            };
            Plane::from_vec(self.width, self.height, v).map_err(|e| self.frame_err(e))
        };
        let float_planes = |names: &[String]| -> Result<Vec<Plane<f32>>, IoError> {
            names.iter().map(|n| to_f32(chan(n))).collect()
        };
        let (_, color_names) = &mapping[0];
        let color: [Plane<f32>; 3] = float_planes(color_names)?
            .try_into()
            .map_err(|_| IoError::Argument("colour needs 3 components".into()))?;
        let mut frame = if self.shading.is_full() {
            Frame::new(color)
        } else {
            Frame::gather(&color, self.shading)
                .and_then(|c| Frame::subsampled(c, self.width, self.height, self.shading))
        }
        .map_err(|e| self.frame_err(e))?;
        for (kind, names) in &mapping[1..] {
            match kind.sample_kind() {
                SampleKind::U32 => {
                    let ids: Vec<u32> = match &chan(&names[0]).data {
                        RawData::U32(v) => v.clone(),
                        // Float ids (Blender's IndexOB): rounded; negative or non-finite
                        // values count as background.
                        RawData::F32(v) => v
                            .iter()
                            .map(|&x| {
                                if x.is_finite() && x > 0.0 {
                                    x.round() as u32
                                } else {
                                    0
                                }
                            })
                            .collect(),
                    };
                    let p = Plane::from_vec(self.width, self.height, ids).map_err(|e| self.frame_err(e))?;
                    frame.set_object_id(p).map_err(|e| self.frame_err(e))?;
                }
                SampleKind::F32 => frame
                    .set_f32(*kind, float_planes(names)?)
                    .map_err(|e| self.frame_err(e))?,
            }
        }
        frame.meta = self.meta.clone();
        Ok(frame)
    }

    fn frame_err(&self, source: crate::frame::FrameError) -> IoError {
        IoError::Frame {
            path: self.path.clone(),
            source,
        }
    }
}
