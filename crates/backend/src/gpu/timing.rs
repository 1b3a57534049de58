//! Where a GPU frame's time goes: its passes' device time from timestamp queries (where the
//! adapter has them, `wgpu::Features::TIMESTAMP_QUERY`), the host's upload and readback
//! around them, and the stages' shares in the frame's record.

use super::{Gpu, Readback};
use crate::pipeline::{DeviceTimes, Recorder, Skip, UploadPrecision};
use std::time::Instant;

/// Timestamps at the start and end of up to `passes` compute passes of one frame.
#[derive(Debug)]
pub(crate) struct PassTimer {
    set: wgpu::QuerySet,
    resolved: wgpu::Buffer,
    passes: u32,
    /// Nanoseconds per timestamp tick.
    period_ns: f64,
}

impl PassTimer {
    /// A timer for `passes` passes, or none where the device has no timestamp queries.
    pub(crate) fn new(gpu: &Gpu, passes: u32) -> Option<Self> {
        if !gpu.device.features().contains(wgpu::Features::TIMESTAMP_QUERY) {
            return None;
        }
        let set = gpu.device.create_query_set(&wgpu::QuerySetDescriptor {
            label: Some("pass timestamps"),
            ty: wgpu::QueryType::Timestamp,
            count: 2 * passes,
        });
        let resolved = gpu.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("pass timestamps resolved"),
            size: 16 * passes as u64,
            usage: wgpu::BufferUsages::QUERY_RESOLVE | wgpu::BufferUsages::COPY_SRC,
            mapped_at_creation: false,
        });
        Some(PassTimer {
            set,
            resolved,
            passes,
            period_ns: gpu.queue.get_timestamp_period() as f64,
        })
    }

    /// 32-bit words the timestamps take in a readback.
    pub(crate) fn words(&self) -> usize {
        4 * self.passes as usize
    }

    /// The timestamp writes of pass `k` (counting from 0 in the frame).
    pub(crate) fn writes(&self, k: u32) -> wgpu::ComputePassTimestampWrites<'_> {
        debug_assert!(k < self.passes);
        wgpu::ComputePassTimestampWrites {
            query_set: &self.set,
            beginning_of_pass_write_index: Some(2 * k),
            end_of_pass_write_index: Some(2 * k + 1),
        }
    }

    /// Encodes the copy of the first `used` passes' timestamps into `back` at word `at`.
    pub(crate) fn resolve(&self, enc: &mut wgpu::CommandEncoder, used: u32, back: &Readback, at: usize) {
        enc.resolve_query_set(&self.set, 0..2 * used, &self.resolved, 0);
        enc.copy_buffer_to_buffer(
            &self.resolved,
            0,
            back.buffer(),
            (at * 4) as u64,
            16 * used as u64,
        );
    }

    /// Milliseconds of each of the first `used` passes, from the words read back.
    pub(crate) fn pass_ms(&self, words: &[f32], used: u32) -> Vec<f64> {
        let tick = |q: usize| {
            let (lo, hi) = (words[2 * q].to_bits() as u64, words[2 * q + 1].to_bits() as u64);
            lo | (hi << 32)
        };
        (0..used as usize)
            .map(|k| tick(2 * k + 1).saturating_sub(tick(2 * k)) as f64 * self.period_ns / 1e6)
            .collect()
    }
}

/// A begun compute pass, timed by `timer` as pass `k` where there is one.
pub(crate) fn begin<'e>(
    enc: &'e mut wgpu::CommandEncoder,
    timer: Option<&PassTimer>,
    k: u32,
) -> wgpu::ComputePass<'e> {
    enc.begin_compute_pass(&wgpu::ComputePassDescriptor {
        label: None,
        timestamp_writes: timer.map(|t| t.writes(k)),
    })
}

/// The host's clock around one frame's device work: started before the uploads, marked at
/// the submission and when the colour is back.
#[derive(Debug)]
pub(crate) struct FrameClock {
    start: Instant,
    submitted: Option<Instant>,
    back: Option<Instant>,
}

impl FrameClock {
    /// Starts the clock (before the frame's first upload).
    pub(crate) fn start() -> Self {
        FrameClock {
            start: Instant::now(),
            submitted: None,
            back: None,
        }
    }

    /// Marks the submission.
    pub(crate) fn submitted(&mut self) {
        self.submitted = Some(Instant::now());
    }

    /// Marks the colour back in host memory.
    pub(crate) fn back(&mut self) {
        self.back = Some(Instant::now());
    }

    /// The frame's device times, `shaders_ms` from timestamps where there are some, with
    /// the `bytes` it uploaded and their colour's `upload` precision.
    pub(crate) fn times(&self, shaders_ms: Option<f64>, upload: UploadPrecision, bytes: u64) -> DeviceTimes {
        let ms = |a: Instant, b: Instant| b.saturating_duration_since(a).as_secs_f64() * 1e3;
        let submitted = self.submitted.unwrap_or(self.start);
        let back = self.back.unwrap_or(submitted);
        let round_trip = ms(submitted, back);
        DeviceTimes {
            upload_ms: ms(self.start, submitted),
            shaders_ms,
            readback_ms: (round_trip - shaders_ms.unwrap_or(0.0)).max(0.0),
            upload,
            upload_bytes: bytes,
        }
    }
}

/// Records `stages` (name, and why it was left out) with the stages that ran sharing `ms`
/// evenly: the stages a pass fuses have no times of their own.
pub(crate) fn share(rec: &mut Recorder, stages: Vec<(&'static str, Option<Skip>)>, ms: f64) {
    let ran = stages.iter().filter(|(_, s)| s.is_none()).count().max(1);
    for (name, skip) in stages {
        match skip {
            Some(why) => rec.skip(name, why),
            None => rec.ran_for(name, ms / ran as f64),
        }
    }
}
