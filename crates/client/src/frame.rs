//! A frame as a renderer holds it (named channels of planar samples), encoded for the
//! wire, and a reply's colour decoded.

use crate::codec::{
    chunks, compress, decompress, in_host_order, joined, put_planes, put_samples, sample_bytes, Samples,
};
use crate::proto::{ChannelHeader, Compression, DataChunk, FrameHeader, SampleType};

/// One channel of a frame: its protocol name (`color`, `depth`, `motion`, `normal`,
/// `albedo`, `motion_next`, `reference`, ...; `docs/server.md` lists them) and its
/// components as planes of `width x height` samples, row-major (colour: r, g, b).
#[derive(Clone, Copy, Debug)]
pub struct Channel<'a> {
    /// The protocol's channel name.
    pub name: &'a str,
    /// One plane per component.
    pub planes: &'a [&'a [f32]],
}

/// A frame to send: its channels (colour first or anywhere; at least colour), object ids
/// when the filter uses them, and what the renderer knows of it.
#[derive(Clone, Debug, Default)]
pub struct FrameData<'a> {
    /// The frame's number.
    pub index: u64,
    /// A camera cut: no history survives into this frame.
    pub reset: bool,
    /// The sub-pixel offset of this frame's samples from the pixel centres, in pixels.
    pub jitter: [f32; 2],
    /// The float channels.
    pub channels: Vec<Channel<'a>>,
    /// Object ids, one per pixel.
    pub object_id: Option<&'a [u32]>,
    /// Sparse shading: the colour is one sample per `factor x factor` block, taken at
    /// `phase` (0 or 1: every pixel).
    pub shading: Option<(u32, [u32; 2])>,
}

/// How a frame's samples travel, and the reply's.
#[derive(Clone, Copy, Debug)]
pub struct Encoding {
    /// f32, or f16 (half the bytes, 11 significant bits).
    pub sample: SampleType,
    /// None, or zstd (for links slower than about 60 MB/s).
    pub compression: Compression,
    /// Largest data chunk (the session's `max_chunk_bytes`).
    pub max_chunk: usize,
}

impl Encoding {
    /// Whether frames sent so are written into a shared memory region straight from their
    /// planes (their headers are [`in_place`]): f32 samples, uncompressed (object ids, u32
    /// with the same compression, then too), on a little-endian host.
    pub fn in_place(&self) -> bool {
        in_host_order(self.sample as i32, self.compression as i32)
    }
}

/// A frame encoded for the wire: the header, then its data in chunks.
#[derive(Clone, Debug)]
pub struct Encoded {
    /// What the server checks before it takes a byte of data.
    pub header: FrameHeader,
    /// The channels' bytes, in header order, in chunks.
    pub chunks: Vec<DataChunk>,
}

impl Encoded {
    /// Bytes of data (the header not counted).
    pub fn data_bytes(&self) -> u64 {
        self.chunks.iter().map(|c| c.data.len() as u64).sum()
    }
}

/// Encodes one channel's planes as its wire bytes.
pub fn encode_planes(planes: &[&[f32]], sample: SampleType, compression: Compression) -> Vec<u8> {
    let n: usize = planes.iter().map(|p| p.len()).sum();
    let mut raw = vec![0u8; n * sample_bytes(sample)];
    put_planes(planes, sample, &mut raw);
    compress(raw, compression)
}

/// Encodes object ids as wire bytes.
pub fn encode_ids(ids: &[u32], compression: Compression) -> Vec<u8> {
    let raw: Vec<u8> = ids.iter().flat_map(|v| v.to_le_bytes()).collect();
    compress(raw, compression)
}

/// Bytes each channel of `frame` takes uncompressed as `sample` samples, in header order
/// (object ids last, 4 bytes each).
pub fn raw_bytes<'f>(frame: &'f FrameData<'_>, sample: SampleType) -> impl Iterator<Item = usize> + 'f {
    let floats = frame
        .channels
        .iter()
        .map(move |c| c.planes.iter().map(|p| p.len()).sum::<usize>() * sample_bytes(sample));
    floats.chain(
        frame
            .object_id
            .map(|ids| ids.len() * sample_bytes(SampleType::U32)),
    )
}

/// The header of `frame` for session `session_id` sent as `how` says, whose channels (in
/// [`raw_bytes`]'s order) take `lengths` bytes on the wire.
pub fn header(
    frame: &FrameData<'_>,
    session_id: &str,
    how: Encoding,
    lengths: impl IntoIterator<Item = usize>,
) -> FrameHeader {
    let names = frame
        .channels
        .iter()
        .map(|c| (c.name, how.sample))
        .chain(frame.object_id.map(|_| ("object_id", SampleType::U32)));
    let channels = names
        .zip(lengths)
        .map(|((name, sample), bytes)| ChannelHeader {
            name: name.to_string(),
            sample: sample as i32,
            compression: how.compression as i32,
            byte_length: bytes as u64,
        })
        .collect();
    let (factor, phase) = frame.shading.unwrap_or((1, [0, 0]));
    FrameHeader {
        session_id: session_id.to_string(),
        index: frame.index,
        reset: frame.reset,
        jitter_x: frame.jitter[0],
        jitter_y: frame.jitter[1],
        channels,
        reply_sample: how.sample as i32,
        reply_compression: how.compression as i32,
        shading_factor: factor,
        shading_phase_x: phase[0],
        shading_phase_y: phase[1],
        shared_memory: None,
    }
}

/// Whether every channel of a frame with header `h` is, byte for byte, its planes' memory
/// ([`in_host_order`]): such a frame is written into a shared memory region straight from
/// its planes by the client and read from it straight into planes by the server.
pub fn in_place(h: &FrameHeader) -> bool {
    h.channels.iter().all(|c| in_host_order(c.sample, c.compression))
}

/// `frame` for session `session_id`: a header, and its channels in that order (object ids
/// last) in chunks of at most `how.max_chunk` bytes. The reply comes in the same sample
/// type and compression.
pub fn encode(frame: &FrameData<'_>, session_id: &str, how: Encoding) -> Encoded {
    let mut lengths = Vec::new();
    let mut bytes = Vec::with_capacity(raw_bytes(frame, how.sample).sum());
    for ch in &frame.channels {
        let start = bytes.len();
        if how.compression == Compression::None {
            // Straight into the frame's buffer: no buffer per channel to copy from.
            for p in ch.planes {
                let at = bytes.len();
                bytes.resize(at + p.len() * sample_bytes(how.sample), 0);
                put_samples(p, how.sample, &mut bytes[at..]);
            }
        } else {
            bytes.extend_from_slice(&encode_planes(ch.planes, how.sample, how.compression));
        }
        lengths.push(bytes.len() - start);
    }
    if let Some(ids) = frame.object_id {
        let data = encode_ids(ids, how.compression);
        bytes.extend_from_slice(&data);
        lengths.push(data.len());
    }
    Encoded {
        header: header(frame, session_id, how, lengths),
        chunks: chunks(bytes, how.max_chunk),
    }
}

/// Why a reply's colour could not be read.
#[derive(Debug, thiserror::Error)]
pub enum ReplyError {
    /// The reply's header says nothing the client can read.
    #[error("reply colour: {0}")]
    Header(String),
    /// The bytes do not decode to the announced size.
    #[error("reply colour: {0}")]
    Data(#[from] std::io::Error),
}

/// A reply's colour (`ch` its channel header, `pieces` its data chunks in order) as three
/// planes of `width x height` samples.
pub fn decode_color(
    ch: &ChannelHeader,
    pieces: &[&[u8]],
    width: u32,
    height: u32,
) -> Result<[Vec<f32>; 3], ReplyError> {
    let n = width as usize * height as usize;
    let sample = SampleType::try_from(ch.sample)
        .ok()
        .filter(|s| *s != SampleType::U32)
        .ok_or_else(|| ReplyError::Header(format!("sample type {} is not f32 or f16", ch.sample)))?;
    let compression = Compression::try_from(ch.compression)
        .map_err(|_| ReplyError::Header(format!("unknown compression {}", ch.compression)))?;
    // Uncompressed samples are read across the chunks as they came.
    let inflated = match compression {
        Compression::None => None,
        _ => Some(decompress(&joined(pieces), compression, 3 * n * 4)?.into_owned()),
    };
    let pieces = match &inflated {
        Some(raw) => vec![raw.as_slice()],
        None => pieces.to_vec(),
    };
    let got: usize = pieces.iter().map(|p| p.len()).sum();
    let want = 3 * n * sample_bytes(sample);
    if got != want {
        return Err(ReplyError::Header(format!(
            "expected {want} bytes ({} {sample:?} samples of {width}x{height}), got {got}",
            3 * n,
        )));
    }
    let mut samples = Samples::new(pieces, sample);
    let mut plane = || {
        let mut out = vec![0f32; n];
        let read = samples.read(&mut out);
        debug_assert!(read, "the length was checked");
        out
    };
    Ok([plane(), plane(), plane()])
}
