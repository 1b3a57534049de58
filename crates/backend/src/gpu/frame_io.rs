//! What every device filter keeps for one frame size to take a frame in and give its
//! colour back ([`FrameIo`]): the shader's parameter words, the input planes and the
//! colour's way into them, the counters, the passes' timer, and the readback. A filter's
//! own buffers (history, intermediate planes, bind groups) sit beside it.

use super::buffers::{params_buffer, planes_from, write_words, Readback, StorageBuffer};
use super::timing::{self, FrameClock, PassTimer};
use super::upload::{upload_inputs, ColorUpload};
use super::{groups, Gpu};
use crate::frame::{Frame, Rgb};
use crate::pipeline::{Inputs, Scratch, UploadPrecision};
use crate::BackendError;

/// The sizes a filter's [`FrameIo`] is made with.
#[derive(Clone, Copy, Debug)]
pub(crate) struct IoShape {
    /// The filter's name, for the buffers' labels and size errors.
    label: &'static str,
    /// Planes of the input buffer (the colour's three first).
    input_planes: usize,
    /// Words of the shaders' `Params`.
    param_words: usize,
    /// Words of the counters the shaders add to (cleared before each frame).
    counters: usize,
    /// Passes a frame runs at most (each timed where the device has timestamps).
    passes: u32,
    /// The side of the passes' square workgroups.
    workgroup: usize,
}

impl IoShape {
    /// The shape of filter `label`: `input_planes` planes in, `param_words` words of
    /// parameters, `counters` counter words, at most `passes` passes of square workgroups
    /// of side `workgroup`.
    pub(crate) const fn new(
        label: &'static str,
        input_planes: usize,
        param_words: usize,
        counters: usize,
        (passes, workgroup): (u32, usize),
    ) -> Self {
        IoShape {
            label,
            input_planes,
            param_words,
            counters,
            passes,
            workgroup,
        }
    }
}

/// A compute pass of a frame: whether it runs, its pipeline, its bind group and its
/// workgroups in x and y.
pub(crate) type Pass<'a> = (bool, &'a wgpu::ComputePipeline, &'a wgpu::BindGroup, (u32, u32));

/// What the device gives back for a frame.
pub(crate) struct FrameBack {
    pub(crate) color: Rgb,
    /// The filter's counters.
    pub(crate) counters: Vec<u32>,
    /// Each pass's time from its timestamps, where the device has them.
    pub(crate) pass_ms: Option<Vec<f64>>,
}

impl FrameBack {
    /// The passes' device time in all, where the device has timestamps.
    pub(crate) fn shaders_ms(&self) -> Option<f64> {
        self.pass_ms.as_ref().map(|v| v.iter().sum())
    }
}

/// A filter's way in and out of the device for one frame size.
#[derive(Debug)]
pub(crate) struct FrameIo {
    shape: IoShape,
    width: usize,
    height: usize,
    /// The shaders' `Params`.
    pub(crate) params: wgpu::Buffer,
    /// The input planes, the colour's first.
    pub(crate) input: StorageBuffer,
    /// The colour's way into `input`, for colour planes of `color_len` samples.
    pub(crate) upload: ColorUpload,
    color_len: usize,
    precision: UploadPrecision,
    /// The shaders' counters (at least a word: wgpu refuses empty bindings).
    pub(crate) counters: wgpu::Buffer,
    timer: Option<PassTimer>,
    /// The colour (3 planes), the counters, then the passes' timestamps.
    back: Readback,
}

impl FrameIo {
    /// The buffers of a `width` x `height` frame of shape `shape`, its colour uploaded at
    /// `precision`.
    pub(crate) fn new(
        gpu: &Gpu,
        shape: IoShape,
        (width, height): (usize, usize),
        precision: UploadPrecision,
    ) -> Result<Self, BackendError> {
        let n = width * height;
        let label = shape.label;
        let params = params_buffer(
            gpu,
            &format!("{label} params"),
            &vec![0; shape.param_words.max(1)],
        );
        let input = StorageBuffer::new(gpu, &format!("{label} input"), shape.input_planes * n)?;
        let counters = StorageBuffer::new(gpu, &format!("{label} counters"), shape.counters)?.buffer;
        let timer = (shape.passes > 0)
            .then(|| PassTimer::new(gpu, shape.passes))
            .flatten();
        let words = 3 * n + shape.counters + timer.as_ref().map_or(0, PassTimer::words);
        Ok(FrameIo {
            upload: ColorUpload::new(gpu, precision, &input, n)?,
            back: Readback::new(gpu, &format!("{label} readback"), words),
            shape,
            width,
            height,
            params,
            input,
            color_len: n,
            precision,
            counters,
            timer,
        })
    }

    /// The frame size.
    pub(crate) fn size(&self) -> (usize, usize) {
        (self.width, self.height)
    }

    /// Makes the colour's upload take planes of `len` samples (sparse shading: fewer than
    /// the frame's pixels), rebuilding it when that changes.
    pub(crate) fn color_len(&mut self, gpu: &Gpu, len: usize) -> Result<(), BackendError> {
        if self.color_len != len {
            self.upload = ColorUpload::new(gpu, self.precision, &self.input, len)?;
            self.color_len = len;
        }
        Ok(())
    }

    /// Queues the shaders' parameter `words`; the bytes queued.
    pub(crate) fn write_params(&self, gpu: &Gpu, words: &[u32]) -> u64 {
        debug_assert_eq!(words.len(), self.shape.param_words);
        write_words(gpu, &self.params, words)
    }

    /// Queues a history filter's frame ([`upload_inputs`]: the colour, then motion when
    /// `motion`, depth when `depth`, and the invalid mask); the bytes queued.
    pub(crate) fn write_inputs<'f>(
        &mut self,
        gpu: &Gpu,
        frame: &'f Frame,
        inp: &mut Inputs<'f>,
        scratch: &mut Scratch,
        (motion, depth): (bool, bool),
    ) -> u64 {
        upload_inputs(
            gpu,
            &mut self.upload,
            &self.input,
            frame,
            inp,
            scratch,
            motion,
            depth,
        )
    }

    /// A frame's command encoder, the counters cleared and the colour's unpacking (f16)
    /// encoded.
    pub(crate) fn encoder(&self, gpu: &Gpu) -> wgpu::CommandEncoder {
        let mut enc = gpu.device.create_command_encoder(&Default::default());
        if self.shape.counters > 0 {
            enc.clear_buffer(&self.counters, 0, None);
        }
        self.upload.encode(gpu, &mut enc);
        enc
    }

    /// The workgroups of a pass over the frame, one invocation a pixel.
    pub(crate) fn groups(&self) -> (u32, u32) {
        groups(self.width, self.height, self.shape.workgroup)
    }

    /// Encodes those of `passes` that run, each timed where the device has timestamps; how
    /// many ran.
    pub(crate) fn encode_passes(&self, enc: &mut wgpu::CommandEncoder, passes: &[Pass]) -> u32 {
        let mut used = 0;
        for &(_, pipeline, group, (gx, gy)) in passes.iter().filter(|p| p.0) {
            let mut pass = timing::begin(enc, self.timer.as_ref(), used);
            used += 1;
            pass.set_pipeline(pipeline);
            pass.set_bind_group(0, group, &[]);
            pass.dispatch_workgroups(gx, gy, 1);
        }
        used
    }

    /// Ends a frame whose `used` passes `enc` holds: encodes the copies of its colour (3
    /// planes of `color`), its counters and its timestamps into the readback, submits, and
    /// reads them back through `words`, marking `clock` at the submission and the readback.
    pub(crate) fn submit_and_read(
        &self,
        gpu: &Gpu,
        mut enc: wgpu::CommandEncoder,
        color: &wgpu::Buffer,
        used: u32,
        words: &mut Vec<f32>,
        clock: &mut FrameClock,
    ) -> Result<FrameBack, BackendError> {
        let n = self.width * self.height;
        let count = self.shape.counters;
        self.back.copy_from(&mut enc, color, 0, 3 * n);
        if count > 0 {
            let back = self.back.buffer();
            enc.copy_buffer_to_buffer(&self.counters, 0, back, (3 * n * 4) as u64, (count * 4) as u64);
        }
        let timer_at = 3 * n + count;
        let timer = self.timer.as_ref();
        if let Some(t) = timer {
            t.resolve(&mut enc, used, &self.back, timer_at);
        }
        gpu.queue.submit([enc.finish()]);
        clock.submitted();
        self.back
            .read(gpu, timer_at + timer.map_or(0, PassTimer::words), words)?;
        clock.back();
        Ok(FrameBack {
            color: planes_from(words, self.width, self.height)?,
            counters: words[3 * n..timer_at].iter().map(|v| v.to_bits()).collect(),
            pass_ms: timer.map(|t| t.pass_ms(&words[timer_at..], used)),
        })
    }
}
