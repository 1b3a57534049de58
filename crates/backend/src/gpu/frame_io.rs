//! What every device filter keeps for one frame size to take a frame in and give its
//! colour back ([`FrameIo`]): the shader's parameter words, the input planes and the
//! colour's way into them, the counters, the passes' timer, and the readback. A filter's
//! own buffers (history, intermediate planes, bind groups) sit beside it.

use super::buffers::{params_buffer, planes_from, write_words, Readback, StorageBuffer};
use super::timing::{self, FrameClock, PassTimer};
use super::upload::{upload_inputs, ColorUpload};
use super::{bind_at, groups, Gpu};
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

/// What a binding of a history filter's shader holds.
#[derive(Clone, Copy, Debug)]
pub(crate) enum Binding {
    /// f32 samples it reads.
    Read,
    /// f32 samples it writes (and may read).
    Write,
    /// Object ids (u32) it reads.
    Ids,
    /// The counters (`COUNTERS` atomic words).
    Counters,
}

/// Declares `const $name: Bindings` from `buffer: Kind` pairs ([`Binding`]'s variants).
macro_rules! bindings {
    ($(#[$doc:meta])* $name:ident: $($buffer:ident: $kind:ident),* $(,)?) => {
        $(#[$doc])*
        const $name: $crate::gpu::frame_io::Bindings = $crate::gpu::frame_io::Bindings(&[
            $((stringify!($buffer), $crate::gpu::frame_io::Binding::$kind)),*
        ]);
    };
}
pub(crate) use bindings;

/// The storage buffers a history filter's shader binds after frame.wgsl's `P` (binding 0)
/// and `inp` (1), in order from binding 2: their WGSL declarations ([`Bindings::wgsl`])
/// and the numbers the bind groups use ([`Bindings::group`]) both come from this list.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Bindings(pub(crate) &'static [(&'static str, Binding)]);

impl Bindings {
    /// The WGSL declarations, put before the shader's source.
    pub(crate) fn wgsl(&self) -> String {
        let declare = |(k, (name, binding)): (usize, &(&str, Binding))| {
            let (access, ty) = match binding {
                Binding::Read => ("read", "array<f32>"),
                Binding::Write => ("read_write", "array<f32>"),
                Binding::Ids => ("read", "array<u32>"),
                Binding::Counters => ("read_write", "array<atomic<u32>, COUNTERS>"),
            };
            format!(
                "@group(0) @binding({}) var<storage, {access}> {name}: {ty};\n",
                k + 2
            )
        };
        self.0.iter().enumerate().map(declare).collect()
    }

    /// A bind group of `pipeline` (an entry point of a shader with these bindings): the
    /// frame's parameters and inputs from `io`, and each of `buffers` at its name's binding.
    pub(crate) fn group(
        &self,
        gpu: &Gpu,
        pipeline: &wgpu::ComputePipeline,
        io: &FrameIo,
        buffers: &[(&str, &wgpu::Buffer)],
    ) -> wgpu::BindGroup {
        let mut at = vec![(0, &io.params), (1, &io.input.buffer)];
        at.extend(buffers.iter().map(|&(name, buffer)| (self.number(name), buffer)));
        bind_at(gpu, pipeline, &at)
    }

    /// The binding number of `name`.
    fn number(&self, name: &str) -> u32 {
        let k = self.0.iter().position(|(n, _)| *n == name);
        2 + k.unwrap_or_else(|| panic!("{name} is not a binding of this shader")) as u32
    }
}

/// A compute pass of a frame: whether it runs, its pipeline, its bind group and its
/// workgroups in x and y.
pub(crate) type Pass<'a> = (bool, &'a wgpu::ComputePipeline, &'a wgpu::BindGroup, (u32, u32));

/// A frame submitted to the device, its readback still to come ([`FrameIo::read`]).
#[derive(Debug)]
pub(crate) struct Submitted {
    index: wgpu::SubmissionIndex,
    /// Which readback its results are copied to.
    slot: usize,
    /// Passes it ran.
    used: u32,
}

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
    /// Two readbacks, used in turn, so that a frame's results can be copied while the
    /// previous frame's are still mapped or in flight: each holds the colour (3 planes),
    /// the counters, then the passes' timestamps.
    back: [Readback; 2],
    /// The readback the next frame's results go to.
    next_back: usize,
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
            back: [0, 1].map(|_| Readback::new(gpu, &format!("{label} readback"), words)),
            next_back: 0,
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
    /// planes of `color`), its counters and its timestamps into the next of the two
    /// readbacks, and submits, marking `clock`. The frame is read back by
    /// [`FrameIo::read`]; meanwhile the next frame may be uploaded and submitted (its
    /// copies go to the other readback).
    pub(crate) fn submit(
        &mut self,
        gpu: &Gpu,
        mut enc: wgpu::CommandEncoder,
        color: &wgpu::Buffer,
        used: u32,
        clock: &mut FrameClock,
    ) -> Submitted {
        let n = self.width * self.height;
        let count = self.shape.counters;
        let slot = self.next_back;
        self.next_back = 1 - slot;
        let back = &self.back[slot];
        back.copy_from(&mut enc, color, 0, 3 * n);
        if count > 0 {
            let at = (3 * n * 4) as u64;
            enc.copy_buffer_to_buffer(&self.counters, 0, back.buffer(), at, (count * 4) as u64);
        }
        if let Some(t) = &self.timer {
            t.resolve(&mut enc, used, back, 3 * n + count);
        }
        let index = gpu.submit(enc.finish());
        clock.submitted();
        Submitted { index, slot, used }
    }

    /// Waits for the frame `submitted` (not for those submitted after it) and reads back
    /// its colour, counters and timestamps through `words`, marking `clock`.
    pub(crate) fn read(
        &self,
        gpu: &Gpu,
        submitted: Submitted,
        words: &mut Vec<f32>,
        clock: &mut FrameClock,
    ) -> Result<FrameBack, BackendError> {
        let n = self.width * self.height;
        let timer_at = 3 * n + self.shape.counters;
        let timer = self.timer.as_ref();
        let len = timer_at + timer.map_or(0, PassTimer::words);
        self.back[submitted.slot].read(gpu, Some(submitted.index), len, words)?;
        clock.back();
        Ok(FrameBack {
            color: planes_from(words, self.width, self.height)?,
            counters: words[3 * n..timer_at].iter().map(|v| v.to_bits()).collect(),
            pass_ms: timer.map(|t| t.pass_ms(&words[timer_at..], submitted.used)),
        })
    }

    /// [`FrameIo::submit`], then [`FrameIo::read`]: the frame's work done before the call
    /// returns.
    pub(crate) fn submit_and_read(
        &mut self,
        gpu: &Gpu,
        enc: wgpu::CommandEncoder,
        (color, used): (&wgpu::Buffer, u32),
        words: &mut Vec<f32>,
        clock: &mut FrameClock,
    ) -> Result<FrameBack, BackendError> {
        let submitted = self.submit(gpu, enc, color, used, clock);
        self.read(gpu, submitted, words, clock)
    }
}
