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

/// Samples per parallel block of the sample conversions: large enough that rayon's
/// overhead is nil, small enough that a 720p plane splits over every core.
pub const BLOCK: usize = 1 << 16;

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
                let mut h = vec![half::f16::ZERO; s.len()];
                h.convert_from_f32_slice(s);
                for (o, v) in d.chunks_exact_mut(2).zip(&h) {
                    o.copy_from_slice(&v.to_le_bytes());
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
                let h: Vec<half::f16> = s
                    .chunks_exact(2)
                    .map(|b| half::f16::from_le_bytes([b[0], b[1]]))
                    .collect();
                h.convert_to_f32_slice(d);
            }
            _ => {
                for (o, b) in d.iter_mut().zip(s.chunks_exact(4)) {
                    *o = f32::from_le_bytes([b[0], b[1], b[2], b[3]]);
                }
            }
        });
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
pub fn chunks(bytes: Vec<u8>, max_chunk: usize) -> Vec<DataChunk> {
    let bytes = bytes::Bytes::from(bytes);
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
