//! The frame (G-buffer) model: planar channels, per-frame values, validation, and the
//! motion-vector conventions.

mod channels;
mod motion;
mod plane;
mod sampling;

pub use channels::{ChannelKind, ChannelSet, SampleKind};
pub use motion::{MotionConvention, MotionDirection, MotionUnits, YAxis};
pub use plane::{count_non_finite, Plane};
pub use sampling::{Sampling, FACTORS};

use serde::{Deserialize, Serialize};
use thiserror::Error;

/// Three planes of f32: RGB colour, a normal, an albedo.
pub type Rgb = [Plane<f32>; 3];

/// Errors in building or validating a frame: the caller's data is inconsistent.
#[derive(Debug, Error, Clone, PartialEq)]
pub enum FrameError {
    /// A plane's sample count is not width x height.
    #[error("plane of {width}x{height} needs {expected} samples, got {got}")]
    PlaneLength {
        /// Width asked for.
        width: usize,
        /// Height asked for.
        height: usize,
        /// width x height.
        expected: usize,
        /// Samples given.
        got: usize,
    },
    /// width x height overflows.
    #[error("frame of {width}x{height} is too large")]
    TooLarge {
        /// Width asked for.
        width: usize,
        /// Height asked for.
        height: usize,
    },
    /// A frame of no pixels.
    #[error("frame has no pixels ({width}x{height})")]
    Empty {
        /// Width.
        width: usize,
        /// Height.
        height: usize,
    },
    /// A channel's plane has another size than the frame.
    #[error("channel {channel} component {component} is {got_w}x{got_h}, but the frame is {width}x{height}")]
    SizeMismatch {
        /// The channel.
        channel: ChannelKind,
        /// Index of the component (plane) within the channel.
        component: usize,
        /// Frame width.
        width: usize,
        /// Frame height.
        height: usize,
        /// The plane's width.
        got_w: usize,
        /// The plane's height.
        got_h: usize,
    },
    /// A channel was given the wrong number of planes.
    #[error("channel {channel} needs {expected} components, got {got}")]
    ComponentCount {
        /// The channel.
        channel: ChannelKind,
        /// Components it has.
        expected: usize,
        /// Components given.
        got: usize,
    },
    /// f32 planes given for an integer channel or the reverse.
    #[error("channel {channel} holds {expected} samples, got {got}")]
    SampleType {
        /// The channel.
        channel: ChannelKind,
        /// Its sample type.
        expected: &'static str,
        /// The type given.
        got: &'static str,
    },
    /// Samples that are NaN or infinite where the caller asked for finite ones.
    #[error("{0}")]
    NonFinite(NonFiniteCounts),
    /// A shading pattern that is not one (see [`Sampling::validate`]).
    #[error("{0}")]
    Sampling(String),
    /// A motion-convention name that is not a preset.
    #[error("unknown motion convention {got:?}; known: {known}")]
    UnknownMotionConvention {
        /// The name given.
        got: String,
        /// The presets.
        known: String,
    },
}

/// How the depth channel is encoded.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum DepthKind {
    /// Linear view-space depth, larger = farther (internal).
    #[default]
    Linear,
    /// Device depth in [0, 1], 0 at the near plane (D3D/Vulkan projection).
    Device,
    /// Reversed device depth, 1 at the near plane.
    ReversedDevice,
}

/// Space the normals are given in.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum NormalSpace {
    /// World space (Blender's Normal pass).
    #[default]
    World,
    /// View (camera) space.
    View,
}

/// Per-frame values that are not images.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct FrameMeta {
    /// Frame number within its sequence.
    pub index: u64,
    /// Sub-pixel offset of this frame's samples from the pixel centres, in pixels, x right,
    /// y down, each in [-0.5, 0.5].
    pub jitter: [f32; 2],
    /// A camera cut: no history may survive into this frame.
    pub reset: bool,
    /// Exposure multiplier the renderer applied, if it says.
    pub exposure: Option<f32>,
    /// Camera near and far planes, if known (needed to linearise device depth).
    pub near_far: Option<[f32; 2]>,
    /// How the depth channel is encoded.
    pub depth_kind: DepthKind,
    /// Space of the normal channel.
    pub normal_space: NormalSpace,
}

/// The largest sub-pixel jitter a frame may say it has, in pixels per axis: a sample
/// jittered further belongs to the neighbouring pixel.
pub const MAX_JITTER: f32 = 1.0;

impl FrameMeta {
    /// Whether `jitter` is a frame's jitter: finite and within [`MAX_JITTER`] per axis
    /// (every interface checks what it is given with this).
    pub fn jitter_in_range(jitter: [f32; 2]) -> bool {
        jitter.iter().all(|v| v.is_finite() && v.abs() <= MAX_JITTER)
    }
}

impl Default for FrameMeta {
    fn default() -> Self {
        FrameMeta {
            index: 0,
            jitter: [0.0, 0.0],
            reset: false,
            exposure: None,
            near_far: None,
            depth_kind: DepthKind::Linear,
            normal_space: NormalSpace::World,
        }
    }
}

/// Non-finite (NaN or infinite) sample counts per channel.
#[derive(Clone, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct NonFiniteCounts {
    /// `(channel, count)` for each float channel the frame has, in channel order.
    pub per_channel: Vec<(ChannelKind, u64)>,
}

impl NonFiniteCounts {
    /// Total over all channels.
    pub fn total(&self) -> u64 {
        self.per_channel.iter().map(|(_, n)| n).sum()
    }

    /// Count for one channel (0 when absent).
    pub fn of(&self, kind: ChannelKind) -> u64 {
        self.per_channel
            .iter()
            .find(|(k, _)| *k == kind)
            .map_or(0, |(_, n)| *n)
    }
}

impl std::fmt::Display for NonFiniteCounts {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let parts: Vec<String> = self
            .per_channel
            .iter()
            .filter(|(_, n)| *n > 0)
            .map(|(k, n)| format!("{k}: {n}"))
            .collect();
        if parts.is_empty() {
            write!(f, "no non-finite samples")
        } else {
            write!(f, "non-finite samples ({})", parts.join(", "))
        }
    }
}

/// One G-buffer frame: `color` is mandatory, every other channel optional, all of the
/// same size. Built with [`Frame::new`] and the `set_*` methods, which check sizes and
/// component counts, so a `Frame` is always consistent.
#[derive(Clone, Debug, PartialEq)]
pub struct Frame {
    width: usize,
    height: usize,
    color: Rgb,
    depth: Option<Plane<f32>>,
    motion: Option<[Plane<f32>; 2]>,
    motion_next: Option<[Plane<f32>; 2]>,
    normal: Option<Rgb>,
    object_id: Option<Plane<u32>>,
    albedo: Option<Rgb>,
    reference: Option<Rgb>,
    /// Where the colour samples lie (full resolution unless shaded sparsely).
    sampling: Sampling,
    /// Per-frame values.
    pub meta: FrameMeta,
}

fn check_planes<T>(
    channel: ChannelKind,
    planes: &[Plane<T>],
    width: usize,
    height: usize,
) -> Result<(), FrameError> {
    if planes.len() != channel.components() {
        return Err(FrameError::ComponentCount {
            channel,
            expected: channel.components(),
            got: planes.len(),
        });
    }
    for (component, p) in planes.iter().enumerate() {
        if p.size() != (width, height) {
            return Err(FrameError::SizeMismatch {
                channel,
                component,
                width,
                height,
                got_w: p.width(),
                got_h: p.height(),
            });
        }
    }
    Ok(())
}

fn into_array<const N: usize>(
    channel: ChannelKind,
    planes: Vec<Plane<f32>>,
) -> Result<[Plane<f32>; N], FrameError> {
    let got = planes.len();
    planes.try_into().map_err(|_| FrameError::ComponentCount {
        channel,
        expected: N,
        got,
    })
}

impl Frame {
    /// A frame with only colour. Its size is the colour planes' size.
    pub fn new(color: Rgb) -> Result<Frame, FrameError> {
        let (width, height) = color[0].size();
        if width == 0 || height == 0 {
            return Err(FrameError::Empty { width, height });
        }
        check_planes(ChannelKind::Color, &color, width, height)?;
        Ok(Frame {
            width,
            height,
            color,
            depth: None,
            motion: None,
            motion_next: None,
            normal: None,
            object_id: None,
            albedo: None,
            reference: None,
            sampling: Sampling::FULL,
            meta: FrameMeta::default(),
        })
    }

    /// A `width x height` frame whose colour was shaded sparsely with `sampling`: the
    /// colour planes are `sampling.color_size(width, height)` (see [`Sampling`]). Every
    /// other channel is set at full resolution afterwards, as with [`Frame::new`].
    pub fn subsampled(
        color: Rgb,
        width: usize,
        height: usize,
        sampling: Sampling,
    ) -> Result<Frame, FrameError> {
        if width == 0 || height == 0 {
            return Err(FrameError::Empty { width, height });
        }
        sampling.validate().map_err(FrameError::Sampling)?;
        let (cw, ch) = sampling.color_size(width, height);
        check_planes(ChannelKind::Color, &color, cw, ch)?;
        let mut f = Frame::new(color)?;
        f.width = width;
        f.height = height;
        f.sampling = sampling;
        Ok(f)
    }

    /// This fully shaded frame as if only the pixels of `sampling` had been shaded: the
    /// colour gathered at them ([`Frame::gather`]), every other channel and the metadata
    /// kept. How a dense render stands in for a renderer's sparse shading (the report
    /// runs `upsample` on real renders this way). A frame already shaded sparsely, or
    /// an invalid `sampling`, is an error.
    pub fn shaded_sparsely(mut self, sampling: Sampling) -> Result<Frame, FrameError> {
        if !self.sampling.is_full() {
            return Err(FrameError::Sampling(format!(
                "the frame is already shaded one pixel in {0}x{0}",
                self.sampling.factor
            )));
        }
        let sparse = Frame::gather(&self.color, sampling)?;
        self.color = sparse;
        self.sampling = sampling;
        Ok(self)
    }

    /// Where the colour samples lie on the full-resolution grid.
    pub fn sampling(&self) -> Sampling {
        self.sampling
    }

    /// Size of the colour planes: the frame's size unless shaded sparsely.
    pub fn color_size(&self) -> (usize, usize) {
        self.color[0].size()
    }

    /// The colour at full resolution: the colour itself (borrowed) for a fully shaded
    /// frame, else each pixel takes the sample shaded in its block (nearest-neighbour
    /// expansion, what a viewer of the raw input sees).
    pub fn color_full(&self) -> std::borrow::Cow<'_, Rgb> {
        if self.sampling.is_full() {
            return std::borrow::Cow::Borrowed(&self.color);
        }
        let f = self.sampling.factor as usize;
        let (cw, ch) = self.color_size();
        std::borrow::Cow::Owned(self.color.each_ref().map(|p| {
            Plane::from_fn(self.width, self.height, |x, y| {
                p.get((x / f).min(cw - 1), (y / f).min(ch - 1))
            })
        }))
    }

    /// The colour gathered at `sampling` from a full-resolution `color` (the inverse of a
    /// scatter: how a file that stores sparse shading at full resolution is read back).
    pub fn gather(color: &Rgb, sampling: Sampling) -> Result<Rgb, FrameError> {
        sampling.validate().map_err(FrameError::Sampling)?;
        let (w, h) = color[0].size();
        let (cw, ch) = sampling.color_size(w, h);
        Ok(color.each_ref().map(|p| {
            Plane::from_fn(cw, ch, |a, b| {
                sampling.position(a, b, w, h).map_or(0.0, |(x, y)| p.get(x, y))
            })
        }))
    }

    /// The colour scattered to full resolution: shaded samples at their pixels, 0
    /// elsewhere (how the EXR writer stores sparse shading).
    pub fn color_scattered(&self) -> std::borrow::Cow<'_, Rgb> {
        if self.sampling.is_full() {
            return std::borrow::Cow::Borrowed(&self.color);
        }
        let (cw, ch) = self.color_size();
        let s = self.sampling;
        std::borrow::Cow::Owned(self.color.each_ref().map(|p| {
            let mut out = Plane::new(self.width, self.height);
            for b in 0..ch {
                for a in 0..cw {
                    if let Some((x, y)) = s.position(a, b, self.width, self.height) {
                        out.set(x, y, p.get(a, b));
                    }
                }
            }
            out
        }))
    }

    /// Width in pixels.
    pub fn width(&self) -> usize {
        self.width
    }

    /// Height in pixels.
    pub fn height(&self) -> usize {
        self.height
    }

    /// Number of pixels.
    pub fn pixels(&self) -> usize {
        self.width * self.height
    }

    /// The channels this frame carries.
    pub fn channels(&self) -> ChannelSet {
        let mut s = ChannelSet::of(&[ChannelKind::Color]);
        let present = [
            (ChannelKind::Depth, self.depth.is_some()),
            (ChannelKind::Motion, self.motion.is_some()),
            (ChannelKind::MotionNext, self.motion_next.is_some()),
            (ChannelKind::Normal, self.normal.is_some()),
            (ChannelKind::ObjectId, self.object_id.is_some()),
            (ChannelKind::Albedo, self.albedo.is_some()),
            (ChannelKind::Reference, self.reference.is_some()),
        ];
        for (k, p) in present {
            if p {
                s = s.with(k);
            }
        }
        s
    }

    /// Sets a float channel from its planes (any channel but `object_id`), replacing what
    /// was there; checks the component count and every plane's size.
    pub fn set_f32(&mut self, channel: ChannelKind, planes: Vec<Plane<f32>>) -> Result<(), FrameError> {
        let (w, h) = if channel == ChannelKind::Color {
            self.color_size()
        } else {
            (self.width, self.height)
        };
        check_planes(channel, &planes, w, h)?;
        match channel {
            ChannelKind::Color => self.color = into_array(channel, planes)?,
            ChannelKind::Depth => {
                self.depth = Some(
                    into_array::<1>(channel, planes)?
                        .into_iter()
                        .next()
                        .expect("one plane"),
                )
            }
            ChannelKind::Motion => self.motion = Some(into_array(channel, planes)?),
            ChannelKind::MotionNext => self.motion_next = Some(into_array(channel, planes)?),
            ChannelKind::Normal => self.normal = Some(into_array(channel, planes)?),
            ChannelKind::Albedo => self.albedo = Some(into_array(channel, planes)?),
            ChannelKind::Reference => self.reference = Some(into_array(channel, planes)?),
            ChannelKind::ObjectId => {
                return Err(FrameError::SampleType {
                    channel,
                    expected: "u32",
                    got: "f32",
                })
            }
        }
        Ok(())
    }

    /// Sets the object-id channel.
    pub fn set_object_id(&mut self, ids: Plane<u32>) -> Result<(), FrameError> {
        check_planes(
            ChannelKind::ObjectId,
            std::slice::from_ref(&ids),
            self.width,
            self.height,
        )?;
        self.object_id = Some(ids);
        Ok(())
    }

    /// Removes a channel (colour cannot be removed; asking for it does nothing).
    pub fn remove(&mut self, channel: ChannelKind) {
        match channel {
            ChannelKind::Color => {}
            ChannelKind::Depth => self.depth = None,
            ChannelKind::Motion => self.motion = None,
            ChannelKind::MotionNext => self.motion_next = None,
            ChannelKind::Normal => self.normal = None,
            ChannelKind::ObjectId => self.object_id = None,
            ChannelKind::Albedo => self.albedo = None,
            ChannelKind::Reference => self.reference = None,
        }
    }

    /// Colour planes.
    pub fn color(&self) -> &Rgb {
        &self.color
    }
    /// Depth plane.
    pub fn depth(&self) -> Option<&Plane<f32>> {
        self.depth.as_ref()
    }
    /// Motion planes (internal convention once read through `io`).
    pub fn motion(&self) -> Option<&[Plane<f32>; 2]> {
        self.motion.as_ref()
    }
    /// Motion-to-next planes (internal convention once read through `io`).
    pub fn motion_next(&self) -> Option<&[Plane<f32>; 2]> {
        self.motion_next.as_ref()
    }
    /// Normal planes.
    pub fn normal(&self) -> Option<&Rgb> {
        self.normal.as_ref()
    }
    /// Object ids.
    pub fn object_id(&self) -> Option<&Plane<u32>> {
        self.object_id.as_ref()
    }
    /// Albedo planes.
    pub fn albedo(&self) -> Option<&Rgb> {
        self.albedo.as_ref()
    }
    /// Reference planes.
    pub fn reference(&self) -> Option<&Rgb> {
        self.reference.as_ref()
    }

    /// The float planes of a channel, if present (`object_id` has none).
    pub fn planes(&self, channel: ChannelKind) -> Option<&[Plane<f32>]> {
        match channel {
            ChannelKind::Color => Some(&self.color[..]),
            ChannelKind::Depth => self.depth.as_ref().map(std::slice::from_ref),
            ChannelKind::Motion => self.motion.as_ref().map(|m| &m[..]),
            ChannelKind::MotionNext => self.motion_next.as_ref().map(|m| &m[..]),
            ChannelKind::Normal => self.normal.as_ref().map(|m| &m[..]),
            ChannelKind::Albedo => self.albedo.as_ref().map(|m| &m[..]),
            ChannelKind::Reference => self.reference.as_ref().map(|m| &m[..]),
            ChannelKind::ObjectId => None,
        }
    }

    /// Colour planes, mutable (their size cannot change through this; they are the
    /// colour's own size, see [`Frame::color_size`]).
    pub fn color_mut(&mut self) -> [&mut [f32]; 3] {
        let [r, g, b] = &mut self.color;
        [r.data_mut(), g.data_mut(), b.data_mut()]
    }

    /// The colour planes, taking the frame apart.
    pub fn into_color(self) -> Rgb {
        self.color
    }

    /// Every float plane (colour, then the other channels), taking the frame apart: for a
    /// caller that reuses them for the next frame ([`crate::pipeline::Scratch`]).
    pub fn into_planes(self) -> impl Iterator<Item = Plane<f32>> {
        let rgb = |c: Option<Rgb>| c.into_iter().flatten();
        let pair = |c: Option<[Plane<f32>; 2]>| c.into_iter().flatten();
        self.color
            .into_iter()
            .chain(self.depth)
            .chain(pair(self.motion))
            .chain(pair(self.motion_next))
            .chain(rgb(self.normal))
            .chain(rgb(self.albedo))
            .chain(rgb(self.reference))
    }

    /// Motion planes, mutable.
    pub fn motion_mut(&mut self) -> Option<&mut [Plane<f32>; 2]> {
        self.motion.as_mut()
    }

    /// Motion-to-next planes, mutable.
    pub fn motion_next_mut(&mut self) -> Option<&mut [Plane<f32>; 2]> {
        self.motion_next.as_mut()
    }

    /// Non-finite samples counted per float channel.
    pub fn non_finite(&self) -> NonFiniteCounts {
        let per_channel = ChannelKind::ALL
            .into_iter()
            .filter_map(|k| {
                self.planes(k)
                    .map(|ps| (k, ps.iter().map(Plane::count_non_finite).sum()))
            })
            .collect();
        NonFiniteCounts { per_channel }
    }

    /// `Ok` when no float channel holds a NaN or an infinity, else the counts.
    pub fn check_finite(&self) -> Result<(), FrameError> {
        let counts = self.non_finite();
        if counts.total() == 0 {
            Ok(())
        } else {
            Err(FrameError::NonFinite(counts))
        }
    }

    /// Converts device depth to linear depth in place using `meta.near_far`; afterwards
    /// `meta.depth_kind` is `Linear`. Returns `false` (and changes nothing) when the depth
    /// is device depth but near/far are unknown.
    pub fn linearize_depth(&mut self) -> bool {
        let kind = self.meta.depth_kind;
        let Some(depth) = self.depth.as_mut() else {
            return true;
        };
        if kind == DepthKind::Linear {
            return true;
        }
        let Some([n, f]) = self.meta.near_far else {
            return false;
        };
        for d in depth.data_mut() {
            *d = kind.to_linear(*d, n, f);
        }
        self.meta.depth_kind = DepthKind::Linear;
        true
    }
}

impl DepthKind {
    /// Linear depth of a sample `d` of this kind, for a camera with planes `near`, `far`.
    pub fn to_linear(self, d: f32, near: f32, far: f32) -> f32 {
        // Standard perspective projection to [0, 1]: d = f (z - n) / (z (f - n)).
        match self {
            DepthKind::Device => near * far / (far - d * (far - near)),
            DepthKind::ReversedDevice => near * far / (near + d * (far - near)),
            DepthKind::Linear => d,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::tolerance::Tolerance;

    fn rgb(w: usize, h: usize, v: f32) -> Rgb {
        [
            Plane::filled(w, h, v),
            Plane::filled(w, h, v),
            Plane::filled(w, h, v),
        ]
    }

    /// `into_planes` gives every float plane once, colour first, and no object ids.
    #[test]
    fn into_planes_gives_every_float_plane() {
        let mut f = Frame::new(rgb(3, 2, 1.0)).unwrap();
        f.set_f32(ChannelKind::Depth, vec![Plane::filled(3, 2, 2.0)])
            .unwrap();
        f.set_f32(ChannelKind::Motion, vec![Plane::filled(3, 2, 3.0); 2])
            .unwrap();
        f.set_f32(ChannelKind::Reference, rgb(3, 2, 4.0).into()).unwrap();
        f.set_object_id(Plane::filled(3, 2, 7u32)).unwrap();
        let firsts: Vec<f32> = f.into_planes().map(|p| p.data()[0]).collect();
        assert_eq!(firsts, [1.0, 1.0, 1.0, 2.0, 3.0, 3.0, 4.0, 4.0, 4.0]);
    }

    #[test]
    fn sizes_and_component_counts_are_checked() {
        let mut f = Frame::new(rgb(4, 3, 0.5)).unwrap();
        let err = f.set_f32(ChannelKind::Depth, vec![Plane::new(4, 2)]).unwrap_err();
        assert_eq!(
            err.to_string(),
            "channel depth component 0 is 4x2, but the frame is 4x3"
        );
        let err = f
            .set_f32(ChannelKind::Motion, vec![Plane::new(4, 3)])
            .unwrap_err();
        assert_eq!(err.to_string(), "channel motion needs 2 components, got 1");
        let err = f
            .set_f32(ChannelKind::ObjectId, vec![Plane::new(4, 3)])
            .unwrap_err();
        assert!(err.to_string().contains("u32"));
        assert!(Frame::new(rgb(0, 3, 0.0)).is_err());
        let mut bad = rgb(4, 3, 0.0);
        bad[2] = Plane::new(3, 3);
        assert!(matches!(
            Frame::new(bad),
            Err(FrameError::SizeMismatch { component: 2, .. })
        ));
        f.set_f32(ChannelKind::Motion, vec![Plane::new(4, 3), Plane::new(4, 3)])
            .unwrap();
        assert_eq!(
            f.channels(),
            ChannelSet::of(&[ChannelKind::Color, ChannelKind::Motion])
        );
    }

    #[test]
    fn sparse_colour_has_its_own_size_and_scatters_back() {
        let s = Sampling {
            factor: 2,
            phase: [1, 0],
        };
        let err = Frame::subsampled(rgb(4, 3, 0.5), 5, 3, s).unwrap_err();
        assert_eq!(
            err.to_string(),
            "channel color component 0 is 4x3, but the frame is 3x2"
        );
        let full = [0, 1, 2].map(|c| Plane::from_fn(5, 3, |x, y| (c * 100 + y * 10 + x) as f32));
        let gathered = Frame::gather(&full, s).unwrap();
        let mut f = Frame::subsampled(gathered, 5, 3, s).unwrap();
        assert_eq!((f.width(), f.height(), f.color_size()), (5, 3, (3, 2)));
        // Other channels are full size; colour keeps its own.
        f.set_f32(ChannelKind::Depth, vec![Plane::filled(5, 3, 1.0)])
            .unwrap();
        assert!(f.set_f32(ChannelKind::Color, rgb(5, 3, 0.0).to_vec()).is_err());
        let back = f.color_scattered();
        for (y, x) in [(0, 1), (0, 3), (2, 1), (2, 3)] {
            assert_eq!(back[1].get(x, y), full[1].get(x, y), "shaded ({x},{y})");
        }
        assert_eq!(back[0].get(0, 0), 0.0, "unshaded pixels scatter as 0");
        assert_eq!(Frame::gather(&back, s).unwrap(), *f.color());
        // Nearest expansion: pixel (4, 2) is in block (2, 1), whose sample (x = 5) lies
        // outside the frame and holds 0.
        let near = f.color_full();
        assert_eq!(near[2].get(0, 1), full[2].get(1, 0));
        assert_eq!(near[2].get(4, 2), 0.0);
        assert!(Frame::subsampled(
            rgb(3, 2, 0.0),
            5,
            3,
            Sampling {
                factor: 3,
                phase: [0, 0]
            }
        )
        .is_err());
    }

    #[test]
    fn non_finite_samples_are_counted_per_channel() {
        let mut c = rgb(4, 3, 0.5);
        c[0].set(1, 1, f32::NAN);
        c[2].set(0, 0, f32::INFINITY);
        let mut f = Frame::new(c).unwrap();
        let mut d = Plane::filled(4, 3, 1.0);
        d.set(3, 2, f32::NEG_INFINITY);
        f.set_f32(ChannelKind::Depth, vec![d]).unwrap();
        let n = f.non_finite();
        assert_eq!(n.of(ChannelKind::Color), 2);
        assert_eq!(n.of(ChannelKind::Depth), 1);
        assert_eq!(n.total(), 3);
        let err = f.check_finite().unwrap_err().to_string();
        assert_eq!(err, "non-finite samples (color: 2, depth: 1)");
    }

    #[test]
    fn device_depth_linearises() {
        let (n, far) = (0.1f32, 100.0f32);
        let z = 7.5f32;
        let device = far * (z - n) / (z * (far - n));
        let reversed = n * (far - z) / (z * (far - n));
        for (kind, d) in [(DepthKind::Device, device), (DepthKind::ReversedDevice, reversed)] {
            let mut f = Frame::new(rgb(2, 2, 0.0)).unwrap();
            f.set_f32(ChannelKind::Depth, vec![Plane::filled(2, 2, d)])
                .unwrap();
            f.meta.depth_kind = kind;
            assert!(!f.clone().linearize_depth(), "needs near/far");
            f.meta.near_far = Some([n, far]);
            assert!(f.linearize_depth());
            Tolerance::rel(1e-4)
                .check("linear depth", f.depth().unwrap().get(1, 1) as f64, z as f64)
                .unwrap();
        }
    }
}
