//! Device buffers of f32 samples: storage the shaders read and write, and the mappable
//! buffers results come back through.

use super::timing::{FrameClock, PassTimer};
use super::{wait, Gpu};
use crate::BackendError;

/// Bytes of `n` f32 samples (at least 4: wgpu refuses empty bindings).
fn bytes_of(n: usize) -> u64 {
    (n.max(1) * 4) as u64
}

/// A storage buffer of `len` f32 samples.
#[derive(Debug)]
pub(crate) struct StorageBuffer {
    pub(crate) buffer: wgpu::Buffer,
    pub(crate) len: usize,
}

impl StorageBuffer {
    /// A zeroed buffer of `len` samples; a [`BackendError::TooLarge`] (naming it by `label`)
    /// where the device cannot bind that many, instead of wgpu's validation panic.
    pub(crate) fn new(gpu: &Gpu, label: &str, len: usize) -> Result<Self, BackendError> {
        let size = (len.max(1) as u64).saturating_mul(4);
        let limits = gpu.device.limits();
        let limit = limits.max_storage_buffer_binding_size.min(limits.max_buffer_size);
        if size > limit {
            return Err(BackendError::TooLarge {
                what: label.to_string(),
                bytes: size,
                limit,
            });
        }
        let buffer = gpu.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some(label),
            size: bytes_of(len),
            usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST | wgpu::BufferUsages::COPY_SRC,
            mapped_at_creation: false,
        });
        Ok(StorageBuffer { buffer, len })
    }

    /// Queues `data` to be written at sample `at` (it reaches the device with the next
    /// submission); the bytes queued.
    pub(crate) fn write(&self, gpu: &Gpu, at: usize, data: &[f32]) -> u64 {
        debug_assert!(at + data.len() <= self.len);
        if !data.is_empty() {
            gpu.queue
                .write_buffer(&self.buffer, (at * 4) as u64, bytemuck::cast_slice(data));
        }
        (data.len() * 4) as u64
    }

    /// Bytes held on the device.
    pub(crate) fn bytes(&self) -> usize {
        self.len * 4
    }
}

/// A shader's parameters (`words`, 32 bits each): a small read-only storage buffer, which
/// the shaders declare `var<storage, read> P: Params`.
///
/// Not a uniform buffer: Mesa's software Vulkan (lavapipe, what CI runs the shaders on)
/// specialises a shader on the values in its uniform buffer, and with `phlm`'s and `taa`'s
/// parameters it recompiled the shader at every dispatch (6 ms a frame at 8x8, against
/// 0.34 ms) and kept each compiled copy (0.9 MB a frame: a 100,000-frame run went out of
/// memory). Desktop GPUs read a small storage buffer as fast.
pub(crate) fn params_buffer(gpu: &Gpu, label: &str, words: &[u32]) -> wgpu::Buffer {
    let buffer = gpu.device.create_buffer(&wgpu::BufferDescriptor {
        label: Some(label),
        size: (words.len() * 4).next_multiple_of(16) as u64,
        usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST,
        mapped_at_creation: false,
    });
    write_words(gpu, &buffer, words);
    buffer
}

/// Queues `words` to be written at the start of `buffer`; the bytes queued.
pub(crate) fn write_words(gpu: &Gpu, buffer: &wgpu::Buffer, words: &[u32]) -> u64 {
    gpu.queue.write_buffer(buffer, 0, bytemuck::cast_slice(words));
    (words.len() * 4) as u64
}

/// Planes of a `width` x `height` image from `words` read back, plane after plane.
pub(crate) fn planes_from(
    words: &[f32],
    width: usize,
    height: usize,
) -> Result<crate::frame::Rgb, BackendError> {
    let n = width * height;
    let plane = |k: usize| {
        crate::frame::Plane::from_vec(width, height, words[k * n..(k + 1) * n].to_vec())
            .map_err(|e| BackendError::Device(e.to_string()))
    };
    Ok([plane(0)?, plane(1)?, plane(2)?])
}

/// The samples of `parts`, one after another, copied back to the host (a state download:
/// saving, or moving it between working spaces).
pub(crate) fn download(gpu: &Gpu, label: &str, parts: &[&StorageBuffer]) -> Result<Vec<f32>, BackendError> {
    let len: usize = parts.iter().map(|p| p.len).sum();
    let back = Readback::new(gpu, label, len);
    let mut enc = gpu.device.create_command_encoder(&Default::default());
    let mut at = 0;
    for p in parts {
        enc.copy_buffer_to_buffer(&p.buffer, 0, &back.buffer, (at * 4) as u64, (p.len * 4) as u64);
        at += p.len;
    }
    gpu.queue.submit([enc.finish()]);
    let mut words = Vec::new();
    back.read(gpu, len, &mut words)?;
    Ok(words)
}

/// A mappable buffer that results are copied into and read back from.
#[derive(Debug)]
pub(crate) struct Readback {
    buffer: wgpu::Buffer,
    len: usize,
}

impl Readback {
    /// Room for `len` 32-bit words.
    pub(crate) fn new(gpu: &Gpu, label: &str, len: usize) -> Self {
        let buffer = gpu.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some(label),
            size: bytes_of(len),
            usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        Readback { buffer, len }
    }

    /// The mappable buffer (for copies to an offset other than 0).
    pub(crate) fn buffer(&self) -> &wgpu::Buffer {
        &self.buffer
    }

    /// Encodes a copy of `len` words of `src` from word `at` into this buffer.
    pub(crate) fn copy_from(
        &self,
        enc: &mut wgpu::CommandEncoder,
        src: &wgpu::Buffer,
        at: usize,
        len: usize,
    ) {
        debug_assert!(len <= self.len);
        enc.copy_buffer_to_buffer(src, (at * 4) as u64, &self.buffer, 0, (len * 4) as u64);
    }

    /// Waits for the device and reads the first `len` words into `out`.
    pub(crate) fn read<T: bytemuck::Pod>(
        &self,
        gpu: &Gpu,
        len: usize,
        out: &mut Vec<T>,
    ) -> Result<(), BackendError> {
        let slice = self.buffer.slice(..(len.max(1) * 4) as u64);
        let (tx, rx) = std::sync::mpsc::channel();
        slice.map_async(wgpu::MapMode::Read, move |r| {
            let _ = tx.send(r);
        });
        wait(gpu)?;
        rx.recv()
            .map_err(|e| BackendError::Device(e.to_string()))?
            .map_err(|e| BackendError::Device(e.to_string()))?;
        {
            let data = slice
                .get_mapped_range()
                .map_err(|e| BackendError::Device(e.to_string()))?;
            out.clear();
            // Mapped ranges are aligned for any word type (wgpu maps at 8-byte alignment
            // or more); the fallback copies word by word.
            match bytemuck::try_cast_slice::<u8, T>(&data) {
                Ok(words) => out.extend_from_slice(&words[..len]),
                Err(_) => out.extend(
                    data.chunks_exact(4)
                        .take(len)
                        .map(bytemuck::pod_read_unaligned::<T>),
                ),
            }
        }
        self.buffer.unmap();
        Ok(())
    }
}

/// What a filter's frame gives back from the device.
pub(crate) struct FrameBack {
    /// The colour.
    pub(crate) color: crate::frame::Rgb,
    /// The counters (at the filter's `C_` indices).
    pub(crate) counters: Vec<u32>,
    /// Each pass's time from its timestamps, where the device has them.
    pub(crate) pass_ms: Option<Vec<f64>>,
}

/// Where a frame's results come back: its colour, its `counters` words and the timestamps
/// of its passes.
#[derive(Debug)]
pub(crate) struct FrameReadback {
    /// Timestamps of the frame's passes, where the device has them.
    pub(crate) timer: Option<PassTimer>,
    /// The colour (3 planes), the counters, then the timestamps.
    back: Readback,
    counters: usize,
}

impl FrameReadback {
    /// Room for the colour of `pixels` pixels, `counters` words and the timestamps of up
    /// to `passes` passes.
    pub(crate) fn new(gpu: &Gpu, label: &str, pixels: usize, counters: usize, passes: u32) -> Self {
        let timer = PassTimer::new(gpu, passes);
        let timer_words = timer.as_ref().map_or(0, PassTimer::words);
        FrameReadback {
            back: Readback::new(gpu, label, 3 * pixels + counters + timer_words),
            timer,
            counters,
        }
    }

    /// Ends a `width` x `height` frame whose encoder `enc` holds its first `passes` passes:
    /// encodes the copies of the colour in `out` and of the `counters`, submits, and reads
    /// them back through `words`, marking `clock` at the submission and the readback.
    pub(crate) fn frame(
        &self,
        gpu: &Gpu,
        (mut enc, passes): (wgpu::CommandEncoder, u32),
        (out, counters): (&wgpu::Buffer, &wgpu::Buffer),
        (width, height): (usize, usize),
        clock: &mut FrameClock,
        words: &mut Vec<f32>,
    ) -> Result<FrameBack, BackendError> {
        let n = width * height;
        let back = &self.back;
        back.copy_from(&mut enc, out, 0, 3 * n);
        let at = (3 * n * 4) as u64;
        enc.copy_buffer_to_buffer(counters, 0, &back.buffer, at, (self.counters * 4) as u64);
        let timer_at = 3 * n + self.counters;
        if let Some(t) = &self.timer {
            t.resolve(&mut enc, passes, back, timer_at);
        }
        gpu.queue.submit([enc.finish()]);
        clock.submitted();
        let len = timer_at + self.timer.as_ref().map_or(0, PassTimer::words);
        back.read(gpu, len, words)?;
        clock.back();
        Ok(FrameBack {
            color: planes_from(words, width, height)?,
            counters: words[3 * n..timer_at].iter().map(|v| v.to_bits()).collect(),
            pass_ms: self.timer.as_ref().map(|t| t.pass_ms(&words[timer_at..], passes)),
        })
    }
}
