//! Device buffers of f32 samples: storage the shaders read and write, and the mappable
//! buffers results come back through.

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
    back.read(gpu, None, len, &mut words)?;
    Ok(words)
}

/// The history of `taa` and `traa` on the device, double-buffered: texels of `texel`
/// channels, then (with `extra`) one plane more (`taa`'s depth, `traa`'s depth / far), as
/// the CPU filter lays them out in its planes.
#[derive(Debug)]
pub(crate) struct TexelHistory {
    planes: [StorageBuffer; 2],
    width: usize,
    height: usize,
    texel: usize,
    extra: bool,
}

impl TexelHistory {
    /// Two zeroed histories of a `width` x `height` frame.
    pub(crate) fn new(
        gpu: &Gpu,
        label: &str,
        (width, height): (usize, usize),
        texel: usize,
        extra: bool,
    ) -> Result<Self, BackendError> {
        let len = width * height * (texel + extra as usize);
        Ok(TexelHistory {
            planes: [
                StorageBuffer::new(gpu, label, len)?,
                StorageBuffer::new(gpu, label, len)?,
            ],
            width,
            height,
            texel,
            extra,
        })
    }

    /// History `k`'s buffer.
    pub(crate) fn buffer(&self, k: usize) -> &wgpu::Buffer {
        &self.planes[k].buffer
    }

    /// Bytes of both on the device.
    pub(crate) fn bytes(&self) -> usize {
        self.planes.iter().map(StorageBuffer::bytes).sum()
    }

    /// History `k` in the CPU filter's planes.
    pub(crate) fn download(
        &self,
        gpu: &Gpu,
        k: usize,
    ) -> Result<Vec<crate::frame::Plane<f32>>, BackendError> {
        let (w, h, t) = (self.width, self.height, self.texel);
        let n = w * h;
        let words = download(gpu, "history readback", &[&self.planes[k]])?;
        let mut planes = vec![plane(t * w, h, words[..t * n].to_vec())?];
        if self.extra {
            planes.push(plane(w, h, words[t * n..(t + 1) * n].to_vec())?);
        }
        Ok(planes)
    }

    /// Writes `planes` (the CPU filter's layout) into history `k`.
    pub(crate) fn upload(&self, gpu: &Gpu, k: usize, planes: &[crate::frame::Plane<f32>]) {
        let mut at = 0;
        for p in planes {
            self.planes[k].write(gpu, at, p.data());
            at += p.data().len();
        }
    }
}

/// A plane of samples read back (their count is the plane's by construction).
pub(crate) fn plane(
    width: usize,
    height: usize,
    data: Vec<f32>,
) -> Result<crate::frame::Plane<f32>, BackendError> {
    crate::frame::Plane::from_vec(width, height, data).map_err(|e| BackendError::Device(e.to_string()))
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

    /// Waits for the device (for `submission` and those before it, or for all) and reads
    /// the first `len` words into `out`.
    pub(crate) fn read<T: bytemuck::Pod>(
        &self,
        gpu: &Gpu,
        submission: Option<wgpu::SubmissionIndex>,
        len: usize,
        out: &mut Vec<T>,
    ) -> Result<(), BackendError> {
        let slice = self.buffer.slice(..(len.max(1) * 4) as u64);
        let (tx, rx) = std::sync::mpsc::channel();
        slice.map_async(wgpu::MapMode::Read, move |r| {
            let _ = tx.send(r);
        });
        wait(gpu, submission)?;
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
