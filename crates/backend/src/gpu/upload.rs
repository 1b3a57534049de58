//! How a frame's colour goes up: as the f32 samples themselves, or
//! ([`UploadPrecision::F16`]) as IEEE halves, two to a 32-bit word, which a first pass
//! (`unpack.wgsl`, WGSL's `unpack2x16float`) widens into the f32 planes the filters'
//! shaders read. Half the colour's bytes cross the bus; the filters' shaders, and their
//! device buffers, are the same with either.
//!
//! The halves are rounded to nearest, ties to even (the `half` crate: the CPU's F16C
//! instructions where it has them), after clamping to +-[`F16_MAX`]: brighter HDR colour
//! would otherwise become infinite on the device, where no repair follows (the CPU's
//! repair of NaN and infinite input, [`crate::pipeline::prepare`], runs before the
//! conversion). Values below f16's smallest normal (6.1e-5) go as subnormals (a device may
//! flush those to zero when it widens them, as WGSL allows), and f16's signed zeros and
//! NaN are kept.
//!
//! A separate pass rather than `unpack2x16float` in every filter's loads: one path for the
//! four filters, their shaders (which mirror the CPU functions line by line) untouched.
//! Its cost is device-side: it reads 2 bytes and writes 4 per sample, at device memory's
//! bandwidth, tens of times the bus's; the f32 planes still take their room on the device.

use super::buffers::params_buffer;
use super::{bind, pipeline, Gpu, StorageBuffer};
use crate::filters::passes::output_ceiling;
use crate::frame::{Frame, Rgb};
use crate::pipeline::{FrameFacts, Inputs, Scratch, UploadPrecision};
use crate::BackendError;
use half::f16;
use half::slice::HalfFloatSliceExt;
use rayon::prelude::*;
use std::borrow::Cow;

/// f16's largest finite value: colour is clamped to +-this before conversion.
pub(crate) const F16_MAX: f32 = 65504.0;

/// Samples per parallel block of the conversion (as the server's wire conversions, whose
/// f16 replies are not clamped: they send the client what the filter computed, where this
/// conversion feeds shaders that no repair follows).
const BLOCK: usize = 1 << 16;

/// Workgroup size of `unpack.wgsl`.
const UNPACK_GROUP: usize = 64;

/// `src` as f16 into `dst` (exactly as long): each sample clamped to +-[`F16_MAX`] (NaN
/// stays NaN), then rounded to nearest, ties to even.
pub(crate) fn to_f16(src: &[f32], dst: &mut [f16]) {
    debug_assert_eq!(src.len(), dst.len());
    // On the crate's pool, as every filter's parallel work (its size is the one
    // `--threads` / `AFTERIMAGE_THREADS` set).
    crate::pipeline::exec::pool().install(|| {
        dst.par_chunks_mut(BLOCK)
            .zip(src.par_chunks(BLOCK))
            .for_each(|(d, s)| {
                let mut clamped = [0.0f32; 1024];
                for (dc, sc) in d.chunks_mut(1024).zip(s.chunks(1024)) {
                    let c = &mut clamped[..sc.len()];
                    for (o, &v) in c.iter_mut().zip(sc) {
                        *o = v.clamp(-F16_MAX, F16_MAX);
                    }
                    dc.convert_from_f32_slice(c);
                }
            })
    });
}

/// The f16 side: the packed halves on the device and the pass that widens them.
#[derive(Debug)]
struct Packed {
    /// ceil(3n / 2) words of halves.
    buffer: StorageBuffer,
    /// The pass's parameters (its count of halves) and bindings.
    _params: wgpu::Buffer,
    bound: wgpu::BindGroup,
    groups: (u32, u32),
    /// The frame's halves, reused (an even count: the last word's high half is padding).
    halves: Vec<f16>,
}

/// The colour planes' way onto the device for one frame size: into the first `3 n`
/// samples of the filter's f32 buffer `dst`, directly or through [`Packed`].
#[derive(Debug)]
pub(crate) struct ColorUpload {
    n: usize,
    packed: Option<Packed>,
}

impl ColorUpload {
    /// The upload of `n`-pixel colour into `dst` (the filter's, whose first `3 n` samples
    /// are the colour planes) at `precision`.
    pub(crate) fn new(
        gpu: &Gpu,
        precision: UploadPrecision,
        dst: &StorageBuffer,
        n: usize,
    ) -> Result<Self, BackendError> {
        debug_assert!(dst.len >= 3 * n);
        let packed = match precision {
            UploadPrecision::F32 => None,
            UploadPrecision::F16 => {
                let words = (3 * n).div_ceil(2);
                let buffer = StorageBuffer::new(gpu, "colour as f16", words)?;
                let params = params_buffer(gpu, "unpack params", &[(3 * n) as u32, 0, 0, 0]);
                let bound = bind(gpu, gpu.unpack(), &[&params, &buffer.buffer, &dst.buffer]);
                let groups = words.div_ceil(UNPACK_GROUP);
                Some(Packed {
                    buffer,
                    _params: params,
                    bound,
                    groups: (groups.min(65535) as u32, groups.div_ceil(65535) as u32),
                    halves: vec![f16::ZERO; 2 * words],
                })
            }
        };
        Ok(ColorUpload { n, packed })
    }

    /// [`output_ceiling`] of a frame with `facts` as the device sees its colour: the
    /// largest sample rounded as the upload rounds it (clamped to +-[`F16_MAX`], to
    /// nearest), so that the bound is that of the CPU filter given that colour.
    pub(crate) fn output_ceiling(&self, facts: &FrameFacts) -> f32 {
        let mut f = *facts;
        if self.packed.is_some() {
            f.max_color = f16::from_f32(f.max_color.clamp(-F16_MAX, F16_MAX)).to_f32();
        }
        output_ceiling(&f)
    }

    /// Queues `color` (planes of `n` samples) for the device; the bytes queued. With f16,
    /// [`ColorUpload::encode`] must then come before the filter's passes.
    pub(crate) fn write(&mut self, gpu: &Gpu, dst: &StorageBuffer, color: &Rgb) -> u64 {
        let n = self.n;
        match &mut self.packed {
            None => color
                .iter()
                .enumerate()
                .map(|(k, p)| dst.write(gpu, k * n, p.data()))
                .sum(),
            Some(p) => {
                for (k, plane) in color.iter().enumerate() {
                    to_f16(plane.data(), &mut p.halves[k * n..(k + 1) * n]);
                }
                let bytes: &[u8] = bytemuck::cast_slice(p.halves.reinterpret_cast());
                gpu.queue.write_buffer(&p.buffer.buffer, 0, bytes);
                bytes.len() as u64
            }
        }
    }

    /// [`Self::write`] of a frame's colour `inp.color`, after which planes of the host's own
    /// (a reconstruction) go back to `scratch`.
    pub(crate) fn write_frame<'f>(
        &mut self,
        gpu: &Gpu,
        dst: &StorageBuffer,
        frame: &'f Frame,
        inp: &mut Inputs<'f>,
        scratch: &mut Scratch,
    ) -> u64 {
        let bytes = self.write(gpu, dst, &inp.color);
        if let Cow::Owned(rgb) = std::mem::replace(&mut inp.color, Cow::Borrowed(frame.color())) {
            scratch.recycle(rgb);
        }
        bytes
    }

    /// Encodes the pass widening the halves into `dst`'s colour planes (nothing with f32).
    pub(crate) fn encode(&self, gpu: &Gpu, enc: &mut wgpu::CommandEncoder) {
        if let Some(p) = &self.packed {
            let mut pass = enc.begin_compute_pass(&wgpu::ComputePassDescriptor {
                label: Some("unpack colour"),
                timestamp_writes: None,
            });
            pass.set_pipeline(gpu.unpack());
            pass.set_bind_group(0, &p.bound, &[]);
            pass.dispatch_workgroups(p.groups.0, p.groups.1, 1);
        }
    }
}

/// The unpack pass's pipeline (compiled once per device: [`Gpu::unpack`]).
pub(crate) fn unpack_pipeline(gpu: &Gpu) -> wgpu::ComputePipeline {
    let consts = super::wgsl_consts![UNPACK_GROUP];
    pipeline(
        gpu,
        "unpack colour",
        &consts,
        include_str!("unpack.wgsl"),
        "unpack",
    )
}

/// Uploads a history filter's frame into `input` (its `IN_` planes): the colour of `inp`
/// through `upload` (planes of the host's own go back to `scratch`), then as f32 motion
/// when `motion`, depth when `depth` (and the frame has some), and the invalid mask.
/// Returns the bytes written.
#[allow(clippy::too_many_arguments)]
pub(crate) fn upload_inputs<'f>(
    gpu: &Gpu,
    upload: &mut ColorUpload,
    input: &StorageBuffer,
    frame: &'f Frame,
    inp: &mut Inputs<'f>,
    scratch: &mut Scratch,
    motion: bool,
    depth: bool,
) -> u64 {
    use super::{IN_DEPTH, IN_INVALID, IN_MX};
    let n = inp.width * inp.height;
    let mut bytes = upload.write_frame(gpu, input, frame, inp, scratch);
    if motion {
        let m = inp.motion.as_deref().expect("motion to upload");
        for (k, plane) in m.iter().enumerate() {
            bytes += input.write(gpu, (IN_MX + k) * n, plane.data());
        }
    }
    if let (Some(d), true) = (inp.depth.as_deref(), depth) {
        bytes += input.write(gpu, IN_DEPTH * n, d.data());
    }
    if let Some(invalid) = &inp.invalid {
        let mask: Vec<f32> = invalid.iter().map(|&v| v as u8 as f32).collect();
        bytes += input.write(gpu, IN_INVALID * n, &mask);
    }
    bytes
}
