//! The protocol's sample encodings: f32 and f16 little-endian samples, zstd, and data
//! chunks. The server decodes with the same functions it checks the sizes for.

use crate::proto::{Compression, DataChunk, SampleType};
use std::borrow::Cow;

/// Bytes of one sample of `s` on the wire.
pub fn sample_bytes(s: SampleType) -> usize {
    match s {
        SampleType::F16 => 2,
        SampleType::F32 | SampleType::U32 => 4,
    }
}

/// Whether samples sent as `sample` with `compression` (the protocol's enum values) are,
/// byte for byte, the host's own f32 or u32 values: 4-byte, uncompressed, and the host
/// little-endian (the wire's order). Such samples are read and written in place of a
/// plane's memory, with no conversion.
pub fn in_host_order(sample: i32, compression: i32) -> bool {
    cfg!(target_endian = "little")
        && compression == Compression::None as i32
        && (sample == SampleType::F32 as i32 || sample == SampleType::U32 as i32)
}

/// Samples per parallel block of the sample conversions: large enough that rayon's
/// overhead is nil, small enough that a 720p plane splits over every core.
pub const BLOCK: usize = 1 << 16;

/// Samples converted at a time through a buffer on the stack (f16 goes through the
/// vector conversions of `half`): a block-sized heap buffer would be 128 KiB, which glibc
/// maps fresh, and faults in, for every block.
const STAGE: usize = 1024;

/// Writes `planes` one after another as little-endian `sample` samples into `dst`
/// (exactly as long as they all are).
pub fn put_planes(planes: &[&[f32]], sample: SampleType, dst: &mut [u8]) {
    let mut at = 0;
    for p in planes {
        let len = p.len() * sample_bytes(sample);
        put_samples(p, sample, &mut dst[at..at + len]);
        at += len;
    }
}

/// Writes `src` as little-endian f32 or f16 samples into `dst` (exactly as long).
pub fn put_samples(src: &[f32], sample: SampleType, dst: &mut [u8]) {
    use half::slice::HalfFloatSliceExt;
    use rayon::prelude::*;
    let width = sample_bytes(sample);
    debug_assert_eq!(dst.len(), src.len() * width);
    dst.par_chunks_mut(BLOCK * width)
        .zip(src.par_chunks(BLOCK))
        .for_each(|(d, s)| match sample {
            SampleType::F16 => {
                let mut h = [half::f16::ZERO; STAGE];
                for (d, s) in d.chunks_mut(2 * STAGE).zip(s.chunks(STAGE)) {
                    let h = &mut h[..s.len()];
                    h.convert_from_f32_slice(s);
                    for (o, v) in d.chunks_exact_mut(2).zip(h.iter()) {
                        o.copy_from_slice(&v.to_le_bytes());
                    }
                }
            }
            _ => {
                for (o, v) in d.chunks_exact_mut(4).zip(s) {
                    o.copy_from_slice(&v.to_le_bytes());
                }
            }
        });
}

/// Reads little-endian f32 or f16 samples from `src` into `dst` (lengths checked by the
/// caller).
pub fn get_samples(src: &[u8], sample: SampleType, dst: &mut [f32]) {
    use half::slice::HalfFloatSliceExt;
    use rayon::prelude::*;
    let width = sample_bytes(sample);
    debug_assert_eq!(src.len(), dst.len() * width);
    dst.par_chunks_mut(BLOCK)
        .zip(src.par_chunks(BLOCK * width))
        .for_each(|(d, s)| match sample {
            SampleType::F16 => {
                let mut h = [half::f16::ZERO; STAGE];
                for (d, s) in d.chunks_mut(STAGE).zip(s.chunks(2 * STAGE)) {
                    let h = &mut h[..d.len()];
                    for (v, b) in h.iter_mut().zip(s.chunks_exact(2)) {
                        *v = half::f16::from_le_bytes([b[0], b[1]]);
                    }
                    h.convert_to_f32_slice(d);
                }
            }
            _ => {
                for (o, b) in d.iter_mut().zip(s.chunks_exact(4)) {
                    *o = f32::from_le_bytes([b[0], b[1], b[2], b[3]]);
                }
            }
        });
}

/// Reads samples from a run of byte pieces (a message's data chunks as they came, not
/// copied together) whose boundaries may fall anywhere, even inside a sample.
pub struct Samples<'a> {
    pieces: std::vec::IntoIter<&'a [u8]>,
    current: &'a [u8],
    sample: SampleType,
}

impl<'a> Samples<'a> {
    /// Samples of type `sample` in `pieces`, in order.
    pub fn new(pieces: Vec<&'a [u8]>, sample: SampleType) -> Samples<'a> {
        Samples {
            pieces: pieces.into_iter(),
            current: &[],
            sample,
        }
    }

    /// Fills `dst`; false when the pieces ran out first.
    pub fn read(&mut self, dst: &mut [f32]) -> bool {
        let width = sample_bytes(self.sample);
        let mut at = 0;
        while at < dst.len() {
            if self.current.is_empty() {
                match self.pieces.next() {
                    Some(p) => self.current = p,
                    None => return false,
                }
                continue;
            }
            if self.current.len() < width {
                // A sample split between pieces: gather its bytes.
                let mut one = [0u8; 4];
                let mut have = self.current.len();
                one[..have].copy_from_slice(self.current);
                while have < width {
                    let Some(p) = self.pieces.next() else {
                        return false;
                    };
                    let take = (width - have).min(p.len());
                    one[have..have + take].copy_from_slice(&p[..take]);
                    have += take;
                    self.current = &p[take..];
                }
                get_samples(&one[..width], self.sample, &mut dst[at..at + 1]);
                at += 1;
                continue;
            }
            let whole = (self.current.len() / width).min(dst.len() - at);
            get_samples(
                &self.current[..whole * width],
                self.sample,
                &mut dst[at..at + whole],
            );
            at += whole;
            self.current = &self.current[whole * width..];
        }
        true
    }
}

/// `pieces` as one slice: borrowed when there is one piece, else copied together.
pub fn joined<'a>(pieces: &[&'a [u8]]) -> Cow<'a, [u8]> {
    match pieces {
        [] => Cow::Borrowed(&[]),
        [one] => Cow::Borrowed(one),
        _ => Cow::Owned(pieces.concat()),
    }
}

/// `raw` as `compression` makes it (zstd at its fastest level).
pub fn compress(raw: Vec<u8>, compression: Compression) -> Vec<u8> {
    match compression {
        Compression::None => raw,
        Compression::Zstd => {
            ruzstd::encoding::compress_to_vec(raw.as_slice(), ruzstd::encoding::CompressionLevel::Fastest)
        }
    }
}

/// Splits bytes into chunks of at most `max_chunk` (views of one buffer, not copies).
pub fn chunks(bytes: impl Into<bytes::Bytes>, max_chunk: usize) -> Vec<DataChunk> {
    let bytes = bytes.into();
    let step = max_chunk.max(1);
    (0..bytes.len())
        .step_by(step)
        .map(|at| DataChunk {
            data: bytes.slice(at..(at + step).min(bytes.len())),
        })
        .collect()
}

/// Decompresses a channel's wire bytes (uncompressed ones as they are, not copied),
/// reading at most `limit` bytes (one past it when there are more, so a caller can refuse
/// a bomb without inflating it).
pub fn decompress(bytes: &[u8], compression: Compression, limit: usize) -> std::io::Result<Cow<'_, [u8]>> {
    match compression {
        Compression::None => Ok(Cow::Borrowed(bytes)),
        Compression::Zstd => {
            use std::io::Read;
            let mut dec = ruzstd::decoding::StreamingDecoder::new(bytes).map_err(|e| {
                std::io::Error::new(std::io::ErrorKind::InvalidData, format!("not a zstd frame: {e}"))
            })?;
            let mut out = Vec::new();
            (&mut dec)
                .take(limit as u64 + 1)
                .read_to_end(&mut out)
                .map_err(|e| std::io::Error::new(e.kind(), format!("corrupt zstd data: {e}")))?;
            Ok(Cow::Owned(out))
        }
    }
}
