//! The memory floor of a filter: the bytes it must read and write per frame over the
//! bandwidth of a plain copy measured on the same machine in the same run. A filter at 1x its floor could only go faster by moving fewer
//! bytes.

use crate::frame::{ChannelKind, ChannelSet, Frame};
use crate::metrics::Timing;
use crate::pipeline::exec::pool;
use rayon::prelude::*;
use serde::Serialize;
use std::hint::black_box;
use std::time::{Duration, Instant};

/// Bytes of one sample: every channel is f32 or u32.
const SAMPLE_BYTES: usize = 4;
/// Bytes of the output: linear RGB in f32.
const OUTPUT_BYTES: usize = 3 * SAMPLE_BYTES;
/// Size of each of the two copy buffers: as large as a 1080p frame's planes, so the copy
/// streams as a full-size frame does. (On the 2-core CI VM, which reports a 260 MiB L3,
/// copies of 16 MiB to 1 GiB per buffer all ran at 46-53 GB/s: its caches do not make
/// this floor an L3 figure.)
pub const COPY_BYTES: usize = 64 << 20;
/// Rows of the copy handed to one rayon task (in f32 samples).
const COPY_CHUNK: usize = 1 << 16;

/// The measured bandwidth of a plain copy.
#[derive(Clone, Copy, Debug, Serialize)]
pub struct Bandwidth {
    /// Bytes read plus bytes written per second.
    pub bytes_per_s: f64,
    /// Bytes in each buffer.
    pub copy_bytes: usize,
    /// Times of one whole copy.
    pub copy: Timing,
    /// Threads of the pool that copied (the filters' pool).
    pub threads: usize,
}

impl Bandwidth {
    /// Milliseconds a plain copy needs to move `bytes` (read plus written).
    pub fn floor_ms(&self, bytes: usize) -> f64 {
        bytes as f64 / self.bytes_per_s * 1e3
    }
}

/// Copies `src` into `dst` (same length) on the filters' rayon pool: the plain copy whose
/// bandwidth is the floor.
pub fn parallel_copy(dst: &mut [f32], src: &[f32]) {
    pool().install(|| {
        dst.par_chunks_mut(COPY_CHUNK)
            .zip(src.par_chunks(COPY_CHUNK))
            .for_each(|(d, s)| d.copy_from_slice(s))
    });
}

/// Untimed copying before the timed copies: it faults the pages in and brings the pool's
/// threads and cores up to speed. Measured on the 2-core VM, the first 9 copies of a
/// fresh process ran at 28-33 GB/s where later ones ran at 35-48.
const WARM_UP: Duration = Duration::from_millis(300);

/// Times `reps` copies of [`COPY_BYTES`] on the filters' rayon pool (after [`WARM_UP`] of
/// untimed copies) and returns the median bandwidth.
pub fn measure_copy_bandwidth(reps: usize) -> Bandwidth {
    let n = COPY_BYTES / SAMPLE_BYTES;
    let src: Vec<f32> = (0..n).map(|i| i as f32).collect();
    let mut dst = vec![1.0f32; n];
    let warm = Instant::now();
    while warm.elapsed() < WARM_UP {
        parallel_copy(&mut dst, &src);
        black_box(&mut dst);
    }
    let mut ms = Vec::with_capacity(reps);
    for _ in 0..reps.max(1) {
        let t = Instant::now();
        parallel_copy(&mut dst, &src);
        black_box(&mut dst);
        ms.push(t.elapsed().as_secs_f64() * 1e3);
    }
    let copy = Timing::of(&ms);
    Bandwidth {
        bytes_per_s: 2.0 * COPY_BYTES as f64 / (copy.median_ms / 1e3),
        copy_bytes: COPY_BYTES,
        copy,
        threads: pool().current_num_threads(),
    }
}

/// Bytes a filter must move per pixel: each channel it reads that the frame has (colour
/// always), its history read and written (`state_bytes_per_pixel` counts both buffers),
/// and the RGB output written.
pub fn bytes_per_pixel(uses: ChannelSet, present: ChannelSet, state_bytes_per_pixel: usize) -> usize {
    let input: usize = uses
        .with(ChannelKind::Color)
        .iter()
        .filter(|&k| present.contains(k))
        .map(|k| k.components() * SAMPLE_BYTES)
        .sum();
    input + state_bytes_per_pixel + OUTPUT_BYTES
}

/// Bytes a filter must move for `frame`: [`bytes_per_pixel`] over its pixels, with the
/// colour read at its own size (a quarter for 2x2 sparse shading).
pub fn bytes_per_frame(uses: ChannelSet, frame: &Frame, state_bytes_per_pixel: usize) -> usize {
    let full = bytes_per_pixel(uses, frame.channels(), state_bytes_per_pixel) * frame.pixels();
    let (cw, ch) = frame.color_size();
    let color = ChannelKind::Color.components() * SAMPLE_BYTES;
    full - color * (frame.pixels() - cw * ch)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn phlm_moves_about_500_mb_at_1080p() {
        // PHLM at 1920x1080 with f32 state (54 floats a pixel) moves about 500 MB a frame.
        let uses = ChannelSet::of(&[ChannelKind::Color, ChannelKind::Depth, ChannelKind::Motion]);
        let present = uses.with(ChannelKind::Normal);
        let b = bytes_per_pixel(uses, present, 216);
        assert_eq!(b, 12 + 4 + 8 + 216 + 12);
        let mb = (b * 1920 * 1080) as f64 / 1e6;
        assert!((450.0..550.0).contains(&mb), "{mb} MB");
        // A channel the filter would use but the frame lacks is not counted.
        assert_eq!(
            bytes_per_pixel(uses, ChannelSet::of(&[ChannelKind::Color]), 0),
            24
        );
    }

    #[test]
    fn floor_is_bytes_over_bandwidth() {
        let bw = Bandwidth {
            bytes_per_s: 1e10,
            copy_bytes: 0,
            copy: Timing::of(&[1.0]),
            threads: 1,
        };
        crate::tolerance::Tolerance::rel(1e-12)
            .check("floor", bw.floor_ms(1_000_000_000), 100.0)
            .unwrap();
    }
}
