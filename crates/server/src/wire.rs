//! Frames on the wire: a header naming the channels, then chunks whose bytes are the
//! channels' planar little-endian samples (f32, f16, or u32 for object ids), each
//! optionally zstd-compressed. Decoding checks everything against the session (size,
//! channels, lengths) and says precisely what is wrong.

use super::proto::{ChannelHeader, Compression, DataChunk, FrameHeader, SampleType};
use crate::frame::{count_non_finite, ChannelKind, ChannelSet, Frame, FrameMeta, Plane, Rgb, Sampling};
use crate::pipeline::Scratch;
use crate::session::{clip, FrameShape, Region, SessionError};
pub use afterimage_client::codec::chunks;
use afterimage_client::codec::{joined, sample_bytes, Samples};
use afterimage_client::frame::{encode, Channel, Encoding, FrameData};
pub use afterimage_client::frame::{encode_ids, encode_planes};
use bytes::Bytes;
use std::borrow::Cow;
use std::ops::Range;

/// Default largest chunk: 1 MiB.
pub const DEFAULT_MAX_CHUNK_BYTES: usize = 1 << 20;

pub use afterimage_client::connect::{CONNECTION_WINDOW_BYTES, MAX_FRAME_BYTES, STREAM_WINDOW_BYTES};

fn invalid(field: impl Into<String>, message: impl Into<String>) -> SessionError {
    SessionError::invalid(field, message)
}

/// What a frame header announces, checked against the session before a byte of data is
/// accepted: every channel known, declared, of a sample type and compression that fit it,
/// and exactly as long as the session's size makes it (uncompressed) or at most zstd's
/// worst case for that size (compressed). All arithmetic is checked: a client's lengths
/// can be any u64.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct FramePlan {
    /// Bytes of data that must follow the header.
    pub wire_bytes: u64,
    /// Bytes of the decoded frame (every sent channel as 4-byte samples).
    pub decoded_bytes: u64,
    /// Decoded bytes of each channel, in header order.
    raw_bytes: Vec<u64>,
    /// Each channel's planes: how many, and their size.
    planes: Vec<(usize, (usize, usize))>,
    /// Where the colour's planes are among every channel's, in header order.
    color_planes: Range<usize>,
}

/// Largest zstd frame for `raw` input bytes (zstd's `ZSTD_COMPRESSBOUND`).
pub fn zstd_bound(raw: u64) -> u64 {
    let small = if raw < (128 << 10) {
        ((128 << 10) - raw) >> 11
    } else {
        0
    };
    raw + (raw >> 8) + small
}

impl FramePlan {
    /// Checks `h` against a session's `shape` and the server's `max_frame_bytes`.
    pub fn check(
        h: &FrameHeader,
        shape: FrameShape,
        max_frame_bytes: u64,
    ) -> Result<FramePlan, SessionError> {
        let sampling = Sampling {
            factor: h.shading_factor.max(1),
            phase: [h.shading_phase_x, h.shading_phase_y],
        };
        sampling.validate().map_err(|e| invalid("shading_factor", e))?;
        let (w, hh) = (shape.width as usize, shape.height as usize);
        let (cw, chh) = sampling.color_size(w, hh);
        if h.channels.len() > ChannelKind::ALL.len() {
            return Err(invalid(
                "channels",
                format!(
                    "{} channel headers, there are only {} channels",
                    h.channels.len(),
                    ChannelKind::ALL.len()
                ),
            ));
        }
        let mut seen = ChannelSet::EMPTY;
        let mut wire = 0u64;
        let mut decoded = 0u64;
        let mut raw_bytes = Vec::with_capacity(h.channels.len());
        let mut planes = Vec::with_capacity(h.channels.len());
        let mut color_planes = 0..0;
        let mut plane_count = 0;
        for ch in &h.channels {
            let kind = channel_kind(ch, seen, shape.channels)?;
            seen = seen.with(kind);
            let name = kind.name();
            let sample = SampleType::try_from(ch.sample).map_err(|_| {
                invalid(
                    format!("channels[{name}].sample"),
                    format!("unknown sample type {}", ch.sample),
                )
            })?;
            match (kind == ChannelKind::ObjectId, sample == SampleType::U32) {
                (true, false) => return Err(invalid("channels[object_id].sample", "expected u32")),
                (false, true) => {
                    return Err(invalid(
                        format!("channels[{name}].sample"),
                        "u32 is for object_id only; expected f32 or f16",
                    ))
                }
                _ => {}
            }
            let (pw, ph) = if kind == ChannelKind::Color {
                (cw, chh)
            } else {
                (w, hh)
            };
            let samples = (pw * ph * kind.components()) as u64;
            let raw = samples * sample_bytes(sample) as u64;
            let got = ch.byte_length;
            match Compression::try_from(ch.compression) {
                Ok(Compression::None) if got != raw => {
                    return Err(invalid(
                        format!("channels[{name}]"),
                        format!(
                            "expected {raw} bytes ({} x {pw}x{ph} {sample:?} samples), got {got}",
                            kind.components()
                        ),
                    ))
                }
                Ok(Compression::Zstd) if got > zstd_bound(raw) => {
                    return Err(invalid(
                        format!("channels[{name}]"),
                        format!(
                            "{got} bytes of zstd data for {raw} bytes of samples, at most {} can be needed",
                            zstd_bound(raw)
                        ),
                    ))
                }
                Ok(_) => {}
                Err(_) => {
                    return Err(invalid(
                        format!("channels[{name}].compression"),
                        format!("unknown compression {}", ch.compression),
                    ))
                }
            }
            wire = wire
                .checked_add(got)
                .ok_or_else(|| invalid("channels.byte_length", "the lengths overflow"))?;
            decoded += samples * 4;
            raw_bytes.push(raw);
            planes.push((kind.components(), (pw, ph)));
            if kind == ChannelKind::Color {
                color_planes = plane_count..plane_count + kind.components();
            }
            plane_count += kind.components();
        }
        if !seen.contains(ChannelKind::Color) {
            return Err(invalid("channels", "no color channel; every frame needs one"));
        }
        if wire > max_frame_bytes {
            return Err(SessionError::too_large(
                "channels.byte_length",
                format!(
                    "frame {} would be {wire} bytes on the wire, the limit is {max_frame_bytes}",
                    h.index
                ),
            ));
        }
        Ok(FramePlan {
            wire_bytes: wire,
            decoded_bytes: decoded,
            raw_bytes,
            planes,
            color_planes,
        })
    }
}

/// The channel a header names: known, not sent twice, declared for the session (a
/// reference may always come).
fn channel_kind(
    ch: &ChannelHeader,
    seen: ChannelSet,
    declared: ChannelSet,
) -> Result<ChannelKind, SessionError> {
    let name = ch.name.as_str();
    let kind = ChannelKind::from_name(name).ok_or_else(|| {
        invalid(
            "channels.name",
            format!(
                "unknown channel {:?}; expected any of {}",
                clip(name),
                ChannelKind::ALL.map(|k| k.name()).join(", ")
            ),
        )
    })?;
    if seen.contains(kind) {
        return Err(invalid("channels.name", format!("channel {name} is sent twice")));
    }
    if kind != ChannelKind::Reference && !declared.contains(kind) {
        return Err(invalid(
            "channels.name",
            format!("channel {name} was not declared when the session was created"),
        ));
    }
    Ok(kind)
}

/// Chunks at least this long are kept as they came; shorter ones are copied together.
pub(crate) const KEEP_CHUNK_BYTES: usize = 64 << 10;

/// Collects one frame's chunks after its header: copied into its planes as they arrive
/// when it lands ([`Assembly::land`]); else kept as they came (views of the transport's
/// receive buffers), not copied into one buffer, and decoding reads across them.
#[derive(Debug)]
pub struct Assembly {
    /// The header.
    pub header: FrameHeader,
    /// What it announced.
    pub plan: FramePlan,
    /// The data so far, in order: large chunks as they came, runs of small ones copied
    /// together (kept as views, a 1-byte chunk would pin its message's framing and cost a
    /// piece per byte).
    chunks: Vec<Bytes>,
    /// Small chunks copied together since the last large one.
    tail: Vec<u8>,
    /// Bytes received so far.
    received: u64,
    /// Where the frame's bytes lie in the session's shared memory region, when they do.
    region: Option<u64>,
    /// The planes an f32 frame's chunks are copied into as they arrive.
    landing: Option<Landing>,
}

/// The planes of a frame whose samples need no conversion (every channel f32,
/// uncompressed, in host order), filled as its chunks arrive: each chunk is copied once,
/// to where the filter reads it, and dropped, so the transport reuses its receive buffer
/// (a chunk kept until the frame is whole makes it take fresh memory for every message,
/// which costs a page fault per 4 KiB).
#[derive(Debug)]
struct Landing {
    /// Every channel's planes, in header order.
    planes: Vec<Plane<f32>>,
    /// The byte of the frame's data where each plane ends.
    ends: Vec<usize>,
    /// Which of them are the colour's.
    color: Range<usize>,
    /// The colour's NaN and infinite samples among those filled, counted as each chunk is
    /// copied in (still in cache) rather than in a pass of its own.
    non_finite: u64,
}

impl Landing {
    /// Copies `bytes`, which start at byte `at` of the frame's data, into the planes.
    fn put(&mut self, mut at: usize, mut bytes: &[u8]) {
        let mut k = self.ends.partition_point(|&end| end <= at);
        while !bytes.is_empty() && k < self.planes.len() {
            let start = self.ends[k] - self.planes[k].data().len() * 4;
            let dst = &mut bytemuck::cast_slice_mut::<f32, u8>(self.planes[k].data_mut())[at - start..];
            let n = dst.len().min(bytes.len());
            dst[..n].copy_from_slice(&bytes[..n]);
            if self.color.contains(&k) {
                // The samples this chunk completes: a chunk may end inside a sample.
                let from = at - start;
                let done = &self.planes[k].data()[from / 4..(from + n) / 4];
                self.non_finite += count_non_finite(done);
            }
            (at, bytes, k) = (at + n, &bytes[n..], k + 1);
        }
    }
}

impl Assembly {
    /// Starts a frame whose header passed [`FramePlan::check`].
    pub fn start(header: FrameHeader, plan: FramePlan) -> Assembly {
        Assembly {
            header,
            plan,
            chunks: Vec::new(),
            tail: Vec::new(),
            received: 0,
            region: None,
            landing: None,
        }
    }

    /// Has the frame's chunks copied into planes from `spare` as they arrive, when its
    /// samples need no conversion ([`lands`]) and it is streamed; call it before the first
    /// chunk.
    pub fn land(&mut self, spare: &mut Scratch) {
        if !lands(&self.header) || self.region.is_some() || self.received > 0 {
            return;
        }
        let mut planes = Vec::new();
        let mut ends = Vec::new();
        let mut end = 0;
        for &(count, (w, h)) in &self.plan.planes {
            for _ in 0..count {
                end += w * h * 4;
                planes.push(spare.plane(w, h));
                ends.push(end);
            }
        }
        self.landing = Some(Landing {
            planes,
            ends,
            color: self.plan.color_planes.clone(),
            non_finite: 0,
        });
    }

    /// Whether the chunks are copied into planes as they arrive ([`Assembly::land`]).
    pub fn is_landed(&self) -> bool {
        self.landing.is_some()
    }

    /// A frame whose bytes lie in the session's shared memory region from `offset` (its
    /// header passed [`FramePlan::check`] and the region's check): complete at once, and
    /// [`Assembly::fill`] gives it its bytes when they are read.
    pub fn in_region(header: FrameHeader, plan: FramePlan, offset: u64) -> Assembly {
        Assembly {
            received: plan.wire_bytes,
            region: Some(offset),
            ..Assembly::start(header, plan)
        }
    }

    /// Where the frame's bytes lie in the region, when they do.
    pub fn region_offset(&self) -> Option<u64> {
        self.region
    }

    /// Gives a frame in the region the bytes read from it.
    pub fn fill(&mut self, bytes: Vec<u8>) {
        self.chunks = vec![Bytes::from(bytes)];
    }

    /// Takes back the buffer [`Assembly::fill`] gave (empty if it is shared still).
    pub fn take_buffer(&mut self) -> Vec<u8> {
        self.chunks
            .pop()
            .and_then(|b| b.try_into_mut().ok())
            .map(Vec::from)
            .unwrap_or_default()
    }

    /// Adds a chunk; refuses one over `max_chunk` bytes or past the announced length.
    pub fn push(&mut self, chunk: impl Into<Bytes>, max_chunk: usize) -> Result<(), SessionError> {
        let chunk = chunk.into();
        if self.region.is_some() {
            return Err(invalid(
                "data",
                format!(
                    "chunk out of order: frame {}'s bytes are in the shared memory region; no DataChunk follows its header",
                    self.header.index
                ),
            ));
        }
        if chunk.len() > max_chunk {
            return Err(SessionError::too_large(
                "data",
                format!("chunk of {} bytes, the limit is {max_chunk}", chunk.len()),
            ));
        }
        if self.received + chunk.len() as u64 > self.plan.wire_bytes {
            return Err(invalid(
                "data",
                format!(
                    "frame {}: chunks add up to more than the {} bytes the header announced",
                    self.header.index, self.plan.wire_bytes
                ),
            ));
        }
        let at = self.received as usize;
        self.received += chunk.len() as u64;
        if let Some(l) = &mut self.landing {
            l.put(at, &chunk);
            return Ok(());
        }
        if chunk.len() < KEEP_CHUNK_BYTES {
            if self.tail.capacity() == 0 {
                // Once, for what is still to come: no regrowth, whatever the chunking.
                self.tail
                    .reserve_exact((self.missing() + chunk.len() as u64) as usize);
            }
            self.tail.extend_from_slice(&chunk);
        } else {
            self.close_tail();
            self.chunks.push(chunk);
        }
        if self.complete() {
            self.close_tail();
            self.tail = Vec::new();
        }
        Ok(())
    }

    /// Ends a run of small chunks: one piece of exactly their bytes.
    fn close_tail(&mut self) {
        if !self.tail.is_empty() {
            self.chunks.push(Bytes::copy_from_slice(&self.tail));
            self.tail.clear();
        }
    }

    /// Whether every announced byte has arrived.
    pub fn complete(&self) -> bool {
        self.received == self.plan.wire_bytes
    }

    /// Bytes still missing.
    pub fn missing(&self) -> u64 {
        self.plan.wire_bytes - self.received
    }

    /// The pieces of the chunks that hold bytes `at..at + len` of the frame's data, in
    /// order; None when the data is shorter.
    fn span(&self, at: usize, len: usize) -> Option<Vec<&[u8]>> {
        let end = at.checked_add(len)?;
        let mut pieces = Vec::new();
        let mut start = 0usize;
        for c in &self.chunks {
            let (lo, hi) = (start.max(at), (start + c.len()).min(end));
            if lo < hi {
                pieces.push(&c[lo - start..hi - start]);
            }
            start += c.len();
            if start >= end {
                break;
            }
        }
        (start >= end).then_some(pieces)
    }
}

/// Decodes `planes` planes of `w x h` float samples of channel `name`, whose bytes are
/// `raw` (pieces in order), into planes taken from `spare`.
fn decode_planes(
    name: &str,
    ch: &ChannelHeader,
    raw: Vec<&[u8]>,
    (w, h): (usize, usize),
    planes: usize,
    spare: &mut Scratch,
) -> Result<Vec<Plane<f32>>, SessionError> {
    let sample = SampleType::try_from(ch.sample).map_err(|_| {
        invalid(
            format!("channels[{name}].sample"),
            format!("unknown sample type {}", ch.sample),
        )
    })?;
    if sample == SampleType::U32 {
        return Err(invalid(
            format!("channels[{name}].sample"),
            "u32 is for object_id only; expected f32 or f16",
        ));
    }
    let n = w * h;
    if n == 0 {
        return Err(invalid(format!("channels[{name}]"), "a frame of zero pixels"));
    }
    let count = n * planes;
    let want = count * sample_bytes(sample);
    let got: usize = raw.iter().map(|p| p.len()).sum();
    if got != want {
        return Err(invalid(
            format!("channels[{name}]"),
            format!("expected {want} bytes ({count} {sample:?} samples), got {got}"),
        ));
    }
    let mut samples = Samples::new(raw, sample);
    (0..planes)
        .map(|_| {
            let mut plane = spare.plane(w, h);
            if samples.read(plane.data_mut()) {
                Ok(plane)
            } else {
                Err(SessionError::Internal(format!(
                    "channels[{name}]: the pieces ran out after a length check"
                )))
            }
        })
        .collect()
}

/// `planes` planes of `w x h` f32 samples read from `region` at `offset`, each straight
/// into its memory, and (when `count`) how many of their samples are NaN or infinite.
fn read_planes(
    region: &Region,
    index: u64,
    offset: u64,
    (w, h): (usize, usize),
    planes: usize,
    spare: &mut Scratch,
    count: bool,
) -> Result<(Vec<Plane<f32>>, u64), SessionError> {
    let mut non_finite = 0;
    let planes = (0..planes)
        .map(|k| {
            let mut plane = spare.plane(w, h);
            let at = offset + (k * w * h * 4) as u64;
            if count {
                non_finite += region.read_counting(index, at, plane.data_mut())?;
            } else {
                region.read_into(index, at, bytemuck::cast_slice_mut(plane.data_mut()))?;
            }
            Ok(plane)
        })
        .collect::<Result<_, SessionError>>()?;
    Ok((planes, non_finite))
}

fn decompress<'a>(
    name: &str,
    ch: &ChannelHeader,
    bytes: &'a [u8],
    limit: usize,
) -> Result<Cow<'a, [u8]>, SessionError> {
    match Compression::try_from(ch.compression) {
        Ok(compression) => afterimage_client::codec::decompress(bytes, compression, limit)
            .map_err(|e| invalid(format!("channels[{name}]"), e.to_string())),
        Err(_) => Err(invalid(
            format!("channels[{name}].compression"),
            format!("unknown compression {}", ch.compression),
        )),
    }
}

/// Whether a streamed frame with header `h` is copied into its planes as its chunks arrive
/// ([`Assembly::land`]): every channel f32 and uncompressed, in host order.
pub fn lands(h: &FrameHeader) -> bool {
    reads_in_place(h) && h.channels.iter().all(|c| c.sample == SampleType::F32 as i32)
}

/// Whether a frame with header `h` can be read from a shared memory region straight into
/// its planes ([`decode`] with a region): every float channel f32 and every channel
/// uncompressed ([`afterimage_client::frame::in_place`], the test the client writes such a
/// frame straight from its planes by), so the bytes are the samples.
pub fn reads_in_place(h: &FrameHeader) -> bool {
    afterimage_client::frame::in_place(h)
}

/// Decodes an assembled frame for a session of `shape` (its header passed
/// [`FramePlan::check`] against the same shape), into planes taken from `spare` where it
/// has them (the session's last input, [`crate::session::Checkout::input_planes`]). With
/// `region`, the frame's bytes are read from it into the planes, channel by channel (a
/// frame in the region whose header [`reads_in_place`]); without, they are the chunks
/// received (or filled from the region).
pub fn decode(
    a: &mut Assembly,
    shape: FrameShape,
    spare: &mut Scratch,
    region: Option<&Region>,
) -> Result<Decoded, SessionError> {
    let in_place = match (region, a.region_offset()) {
        (Some(r), Some(base)) if reads_in_place(&a.header) => Some((r, base)),
        (None, _) => None,
        _ => {
            return Err(SessionError::Internal(
                "a frame read in place that is not in the region, or not f32".into(),
            ))
        }
    };
    let (w, h) = (shape.width as usize, shape.height as usize);
    let n = w * h;
    let mut at = 0usize;
    let mut seen = ChannelSet::EMPTY;
    let mut color: Option<Rgb> = None;
    let mut rest: Vec<(ChannelKind, Vec<Plane<f32>>)> = Vec::new();
    let mut ids: Option<Plane<u32>> = None;
    let mut color_non_finite = None;
    let mut landed = a.landing.take().map(|l| {
        color_non_finite = Some(l.non_finite);
        l.planes.into_iter()
    });
    let a = &*a;
    let hd = &a.header;
    let sampling = Sampling {
        factor: hd.shading_factor.max(1),
        phase: [hd.shading_phase_x, hd.shading_phase_y],
    };
    sampling.validate().map_err(|e| invalid("shading_factor", e))?;
    let (cw, chh) = sampling.color_size(w, h);
    if a.plan.raw_bytes.len() != hd.channels.len() || !a.complete() {
        return Err(SessionError::Internal(
            "a frame decoded before its plan was complete".into(),
        ));
    }
    for (ch, &raw_len) in hd.channels.iter().zip(&a.plan.raw_bytes) {
        let kind = channel_kind(ch, seen, shape.channels)?;
        seen = seen.with(kind);
        let name = kind.name();
        let len = usize::try_from(ch.byte_length).map_err(|_| invalid("channels.byte_length", "too long"))?;
        if let Some(landed) = &mut landed {
            // The plan made a plane of the right size for every component, filled in order.
            at += len;
            let planes: Vec<Plane<f32>> = landed.by_ref().take(kind.components()).collect();
            if kind == ChannelKind::Color {
                let [r, g, b]: [Plane<f32>; 3] = planes
                    .try_into()
                    .map_err(|_| SessionError::Internal("a landed colour without three planes".into()))?;
                color = Some([r, g, b]);
            } else {
                rest.push((kind, planes));
            }
            continue;
        }
        if let Some((r, base)) = in_place {
            // The plan checked the lengths and the region check the span.
            let offset = base + at as u64;
            at += len;
            if kind == ChannelKind::ObjectId {
                let mut v = vec![0u32; n];
                r.read_into(hd.index, offset, bytemuck::cast_slice_mut(&mut v))?;
                ids = Some(Plane::from_vec(w, h, v).expect("length checked"));
                continue;
            }
            let size = if kind == ChannelKind::Color {
                (cw, chh)
            } else {
                (w, h)
            };
            let is_color = kind == ChannelKind::Color;
            let (planes, non_finite) =
                read_planes(r, hd.index, offset, size, kind.components(), spare, is_color)?;
            if is_color {
                color_non_finite = Some(non_finite);
                let [r, g, b]: [Plane<f32>; 3] = planes.try_into().expect("three components");
                color = Some([r, g, b]);
            } else {
                rest.push((kind, planes));
            }
            continue;
        }
        let pieces = a.span(at, len).ok_or_else(|| {
            invalid(
                format!("channels[{name}]"),
                "the data is shorter than the header says",
            )
        })?;
        at += len;
        let (pw, ph) = if kind == ChannelKind::Color {
            (cw, chh)
        } else {
            (w, h)
        };
        // Uncompressed samples are read across the chunks as they came; compressed ones
        // are joined for the decompressor.
        let inflated = match Compression::try_from(ch.compression) {
            Ok(Compression::None) => None,
            _ => Some(decompress(name, ch, &joined(&pieces), raw_len as usize)?.into_owned()),
        };
        let pieces = match &inflated {
            Some(raw) => vec![raw.as_slice()],
            None => pieces,
        };
        if kind == ChannelKind::ObjectId {
            let raw = joined(&pieces);
            if raw.len() != n * 4 {
                return Err(invalid(
                    "channels[object_id]",
                    format!("expected {} bytes ({n} u32 samples), got {}", n * 4, raw.len()),
                ));
            }
            let v = raw
                .chunks_exact(4)
                .map(|b| u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
                .collect();
            ids = Some(Plane::from_vec(w, h, v).expect("length checked"));
            continue;
        }
        let planes = decode_planes(name, ch, pieces, (pw, ph), kind.components(), spare)?;
        if kind == ChannelKind::Color {
            let [r, g, b]: [Plane<f32>; 3] = planes.try_into().expect("three components");
            color = Some([r, g, b]);
        } else {
            rest.push((kind, planes));
        }
    }
    let color = color.ok_or_else(|| invalid("channels", "no color channel; every frame needs one"))?;
    let mut frame = if sampling.is_full() {
        Frame::new(color)
    } else {
        Frame::subsampled(color, w, h, sampling)
    }
    .map_err(|e| invalid("color", e.to_string()))?;
    for (kind, planes) in rest {
        frame
            .set_f32(kind, planes)
            .map_err(|e| invalid(kind.name(), e.to_string()))?;
    }
    if let Some(ids) = ids {
        frame
            .set_object_id(ids)
            .map_err(|e| invalid("object_id", e.to_string()))?;
    }
    frame.meta.index = a.header.index;
    frame.meta.reset = a.header.reset;
    let jitter = [a.header.jitter_x, a.header.jitter_y];
    if !FrameMeta::jitter_in_range(jitter) {
        return Err(invalid(
            "jitter",
            format!(
                "({}, {}): expected x and y in pixels, each finite and in -1..=1",
                jitter[0], jitter[1]
            ),
        ));
    }
    frame.meta.jitter = jitter;
    Ok(Decoded {
        frame,
        color_non_finite,
    })
}

/// A decoded frame, and its colour's NaN and infinite samples when they were counted as the
/// samples were copied in (landed or read from the region), so the session need not count
/// them again.
#[derive(Debug)]
pub struct Decoded {
    /// The frame.
    pub frame: Frame,
    /// Its colour's NaN and infinite samples, when counted on the way in.
    pub color_non_finite: Option<u64>,
}

/// A frame as a header plus data chunks of at most `max_chunk` bytes, sending the
/// channels in `channels` that the frame has (for clients and tests), through
/// [`afterimage_client::frame::encode`].
pub fn encode_frame(
    frame: &Frame,
    session_id: &str,
    channels: ChannelSet,
    sample: SampleType,
    compression: Compression,
    max_chunk: usize,
) -> (FrameHeader, Vec<DataChunk>) {
    let how = Encoding {
        sample,
        compression,
        max_chunk,
    };
    let e = with_frame_data(frame, channels, |data| encode(data, session_id, how));
    (e.header, e.chunks)
}

/// Calls `f` with `frame` as the client crate's [`FrameData`] (views of its planes),
/// sending the channels in `channels` that the frame has.
pub fn with_frame_data<R>(frame: &Frame, channels: ChannelSet, f: impl FnOnce(&FrameData<'_>) -> R) -> R {
    let kinds: Vec<ChannelKind> = channels
        .with(ChannelKind::Color)
        .iter()
        .filter(|&k| frame.channels().contains(k) && k != ChannelKind::ObjectId)
        .collect();
    let slices: Vec<Vec<&[f32]>> = kinds
        .iter()
        .map(|&k| {
            frame
                .planes(k)
                .expect("listed")
                .iter()
                .map(|p| p.data())
                .collect()
        })
        .collect();
    let data = FrameData {
        index: frame.meta.index,
        reset: frame.meta.reset,
        jitter: frame.meta.jitter,
        channels: kinds
            .iter()
            .zip(&slices)
            .map(|(k, planes)| Channel {
                name: k.name(),
                planes,
            })
            .collect(),
        object_id: channels
            .contains(ChannelKind::ObjectId)
            .then(|| frame.object_id().map(|p| p.data()))
            .flatten(),
        shading: Some((frame.sampling().factor, frame.sampling().phase)),
    };
    f(&data)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::SplitMix64;
    use afterimage_client::codec::{get_samples, put_samples, BLOCK};

    /// Values that stress the conversions: signed zeros, subnormals of both formats, the
    /// f16 overflow edge, infinities and NaN, plus random HDR values.
    fn adversarial(n: usize) -> Vec<f32> {
        let special = [
            0.0,
            -0.0,
            1.0,
            -1.0,
            f32::MIN_POSITIVE,
            1e-40,
            5.96e-8,
            6.1e-5,
            65504.0,
            65520.0,
            1e9,
            -1e30,
            f32::INFINITY,
            f32::NEG_INFINITY,
            f32::NAN,
        ];
        let mut rng = SplitMix64::new(7);
        (0..n)
            .map(|i| {
                if i % 5 == 0 {
                    special[(i / 5) % special.len()]
                } else {
                    (rng.next_f64() as f32 - 0.3) * 10f32.powi((i % 9) as i32 - 3)
                }
            })
            .collect()
    }

    /// A 7x5 frame of adversarial colour (NaN and infinities among it), depth and motion,
    /// and its size.
    fn test_frame() -> (Frame, (usize, usize)) {
        let (w, h) = (7, 5);
        let n = w * h;
        let plane = |k: usize| Plane::from_vec(w, h, adversarial(n + k)[k..].to_vec()).unwrap();
        let mut frame = Frame::new([plane(0), plane(1), plane(2)]).unwrap();
        // Non-finite colour, which the session counts as it lands.
        let [r, g, b] = frame.color_mut();
        (r[0], r[9], g[17], b[n - 1]) = (f32::NAN, f32::INFINITY, f32::NEG_INFINITY, f32::NAN);
        frame.set_f32(ChannelKind::Depth, vec![plane(3)]).unwrap();
        frame
            .set_f32(ChannelKind::Motion, vec![plane(4), plane(5)])
            .unwrap();
        (frame, (w, h))
    }

    /// The bits of `f`'s channel `k`, plane after plane.
    fn bits(f: &Frame, k: ChannelKind) -> Vec<u32> {
        f.planes(k)
            .unwrap()
            .iter()
            .flat_map(|p| p.data().iter().map(|v| v.to_bits()))
            .collect()
    }

    /// A frame decodes to the same bits however its data is cut into chunks: one chunk,
    /// single bytes, cuts inside samples and across channels, random sizes; and f32 gives
    /// back exactly what was sent. Odd sizes, adversarial values, planes reused from a
    /// scratch that already holds other samples.
    #[test]
    fn decoding_reads_across_any_chunking() {
        let (frame, (w, h)) = test_frame();
        let n = w * h;
        let channels = ChannelSet::EMPTY
            .with(ChannelKind::Color)
            .with(ChannelKind::Depth)
            .with(ChannelKind::Motion);
        let shape = FrameShape {
            width: w as u32,
            height: h as u32,
            channels,
        };
        let mut rng = SplitMix64::new(3);
        for sample in [SampleType::F32, SampleType::F16] {
            let (header, chunks) = encode_frame(&frame, "s", channels, sample, Compression::None, 1 << 20);
            let data: Vec<u8> = chunks.iter().flat_map(|c| c.data.to_vec()).collect();
            let random: Vec<usize> = (0..data.len())
                .map(|_| 1 + (rng.next_f64() * 9.0) as usize)
                .collect();
            let cuts: [&dyn Fn(usize) -> usize; 4] = [&|_| data.len(), &|_| 1, &|_| 3, &|i| random[i]];
            let mut first: Option<Frame> = None;
            for (c, cut) in cuts.iter().enumerate() {
                for land in [false, true] {
                    let plan = FramePlan::check(&header, shape, 1 << 30).unwrap();
                    let mut a = Assembly::start(header.clone(), plan);
                    // Stale planes to land in: every byte must be overwritten.
                    let mut landing = Scratch::default();
                    landing.recycle((0..6).map(|_| Plane::from_vec(w, h, vec![f32::NAN; n]).unwrap()));
                    if land {
                        a.land(&mut landing);
                        // Only f32 lands; f16 needs converting, so it is kept as it came.
                        assert_eq!(a.is_landed(), sample == SampleType::F32, "{sample:?}");
                    }
                    let (mut at, mut i) = (0, 0);
                    while at < data.len() {
                        let end = (at + cut(i)).min(data.len());
                        a.push(data[at..end].to_vec(), 1 << 20).unwrap();
                        (at, i) = (end, i + 1);
                    }
                    // Small chunks are copied together: one piece, not one per chunk; a
                    // landed frame keeps none.
                    let pieces = if a.is_landed() { 0 } else { 1 };
                    assert_eq!(a.chunks.len(), pieces, "{sample:?} cut {c}");
                    let mut spare = Scratch::default();
                    spare.recycle((0..6).map(|_| Plane::from_vec(w, h, vec![9.0; n]).unwrap()));
                    let landed = a.is_landed();
                    let d = decode(&mut a, shape, &mut spare, None).unwrap();
                    // A landed colour's NaNs and infinities are counted as it comes, cut
                    // inside samples or not; the rest is left to the session.
                    let counted =
                        landed.then(|| frame.color().iter().map(Plane::count_non_finite).sum::<u64>());
                    assert!(counted != Some(0), "the test frame must hold non-finite colour");
                    assert_eq!(d.color_non_finite, counted, "{sample:?} cut {c} land {land}");
                    let got = d.frame;
                    let want = first.get_or_insert_with(|| got.clone());
                    for k in [ChannelKind::Color, ChannelKind::Depth, ChannelKind::Motion] {
                        assert_eq!(
                            bits(&got, k),
                            bits(want, k),
                            "{sample:?} cut {c} land {land}, {k}"
                        );
                        if sample == SampleType::F32 {
                            assert_eq!(
                                bits(&got, k),
                                bits(&frame, k),
                                "{sample:?} cut {c} land {land}, {k}"
                            );
                        }
                    }
                }
            }
        }
    }

    #[test]
    fn a_region_frame_of_f32_decodes_in_place() {
        use crate::session::{Budget, Reservation};
        use std::os::unix::fs::FileExt;
        let (mut frame, (w, h)) = test_frame();
        let n = w * h;
        let ids: Vec<u32> = (0..n as u32).map(|i| i.wrapping_mul(2654435761)).collect();
        frame.set_object_id(Plane::from_vec(w, h, ids).unwrap()).unwrap();
        let channels = [
            ChannelKind::Color,
            ChannelKind::Depth,
            ChannelKind::Motion,
            ChannelKind::ObjectId,
        ]
        .into_iter()
        .fold(ChannelSet::EMPTY, ChannelSet::with);
        let shape = FrameShape {
            width: w as u32,
            height: h as u32,
            channels,
        };
        for sample in [SampleType::F32, SampleType::F16] {
            let (header, chunks) = encode_frame(&frame, "s", channels, sample, Compression::None, 1 << 20);
            let data: Vec<u8> = chunks.iter().flat_map(|c| c.data.to_vec()).collect();
            let bytes = data.len() as u64 + 13;
            let hold = Reservation::take(&[&Budget::new("test", 1 << 30)], bytes, "region").unwrap();
            let region = Region::create(bytes, hold).unwrap();
            std::fs::File::options()
                .write(true)
                .open(region.path())
                .unwrap()
                .write_all_at(&data, 13)
                .unwrap();
            let plan = FramePlan::check(&header, shape, 1 << 30).unwrap();
            let mut a = Assembly::in_region(header.clone(), plan, 13);
            let got = decode(&mut a, shape, &mut Scratch::default(), Some(&region));
            if sample == SampleType::F16 {
                assert!(matches!(got, Err(SessionError::Internal(_))), "{got:?}");
                assert!(!reads_in_place(&header));
                continue;
            }
            let d = got.unwrap();
            let counted: u64 = frame.color().iter().map(Plane::count_non_finite).sum();
            assert!(counted > 0, "the test frame must hold non-finite colour");
            assert_eq!(d.color_non_finite, Some(counted));
            let got = d.frame;
            for k in [ChannelKind::Color, ChannelKind::Depth, ChannelKind::Motion] {
                assert_eq!(bits(&got, k), bits(&frame, k), "{k}");
            }
            assert_eq!(got.object_id().unwrap().data(), frame.object_id().unwrap().data());
        }
    }

    /// The blocked, parallel conversions equal the one-sample-at-a-time definition
    /// (`to_le_bytes` / `half::f16::from_f32`), bit for bit, across block boundaries.
    #[test]
    fn sample_codecs_match_the_scalar_definition() {
        for n in [1, 7, BLOCK - 1, BLOCK, 2 * BLOCK + 3] {
            let src = adversarial(n);
            for sample in [SampleType::F32, SampleType::F16] {
                let mut bytes = vec![0u8; n * sample_bytes(sample)];
                put_samples(&src, sample, &mut bytes);
                let want: Vec<u8> = match sample {
                    SampleType::F16 => src
                        .iter()
                        .flat_map(|&v| half::f16::from_f32(v).to_le_bytes())
                        .collect(),
                    _ => src.iter().flat_map(|v| v.to_le_bytes()).collect(),
                };
                assert!(bytes == want, "encode {sample:?}, n = {n}");
                let mut back = vec![0f32; n];
                get_samples(&bytes, sample, &mut back);
                for (i, &got) in back.iter().enumerate() {
                    let expect = match sample {
                        SampleType::F16 => half::f16::from_le_bytes([want[2 * i], want[2 * i + 1]]).to_f32(),
                        _ => src[i],
                    };
                    assert!(
                        got.to_bits() == expect.to_bits() || (got.is_nan() && expect.is_nan()),
                        "decode {sample:?}, n = {n}, sample {i}: {got} vs {expect}"
                    );
                }
            }
        }
    }
}
