//! `taa` on the GPU: the CPU filter's plan ([`StagePlan`]), parameters and state format,
//! with its per-pixel stages in WGSL (`taa*.wgsl`). The history (texels [Y, Co, Cg, count],
//! and depth with depth rejection) stays on the device, double-buffered; a frame uploads
//! its colour (and the motion and depth its plan needs), and reads back the colour and the
//! pixel counts.

use super::buffers::{params_buffer, submit_and_read, write_words, FrameBack, TexelHistory};
use super::history::{DeviceHistory, FrameBuffers};
use super::timing::{self, FrameClock, PassTimer};
use super::upload::{upload_inputs, ColorUpload};
use super::INPUT_PLANES;
use super::{bind, groups, history_filter, input_consts, pipeline, Gpu, Readback, StorageBuffer, REPROJECT};
use crate::filters::taa::{HistoryFilter, Params, StagePlan, Taa};
use crate::frame::Frame;
use crate::pipeline::{
    DeviceTimes, Filter, FilterKind, Inputs, Output, PixelCounts, Recorder, UploadPrecision,
};
use crate::BackendError;
use std::sync::Arc;

const SHARED: &str = include_str!("taa.wgsl");
const WORKGROUP: usize = 8;

// Bits of `Params.flags`, declared in taa.wgsl from these ([`consts`]).
const FLAG_TONEMAP: u32 = 1;
const FLAG_DILATE: u32 = 2;
const FLAG_REPROJECT: u32 = 4;
const FLAG_DEPTH_REJECT: u32 = 8;
const FLAG_HISTORY: u32 = 16;
const FLAG_CATMULL_ROM: u32 = 32;
const FLAG_LUMA_WEIGHT: u32 = 64;
const FLAG_INVALID: u32 = 128;
const FLAG_SHARPEN: u32 = 256;
const FLAG_KEEP_DEPTH: u32 = 512;
const FLAG_TO_TONEMAPPED: u32 = 1024;

/// Words of the counters: reset, clipped, rejected (the `C_` indices); padded.
const COUNTERS: usize = 4;
const C_RESET: usize = 0;
const C_CLIPPED: usize = 1;
const C_REJECTED: usize = 2;
/// Workgroup size of the `convert` pass (one texel an invocation).
const CONVERT_GROUP: usize = 64;

/// What taa's shaders take from Rust: the input planes ([`input_consts`]), the flag bits
/// and counters above, the workgroup sizes, and the CPU filter's sample count bound.
fn consts() -> String {
    use crate::filters::taa::MAX_COUNT;
    input_consts()
        + &super::wgsl_consts![
            FLAG_TONEMAP,
            FLAG_DILATE,
            FLAG_REPROJECT,
            FLAG_DEPTH_REJECT,
            FLAG_HISTORY,
            FLAG_CATMULL_ROM,
            FLAG_LUMA_WEIGHT,
            FLAG_INVALID,
            FLAG_SHARPEN,
            FLAG_KEEP_DEPTH,
            FLAG_TO_TONEMAPPED,
            COUNTERS,
            C_RESET,
            C_CLIPPED,
            C_REJECTED,
            WORKGROUP,
            CONVERT_GROUP,
            MAX_COUNT,
        ]
}

/// The compiled passes.
#[derive(Debug)]
pub(crate) struct Passes {
    resolve: wgpu::ComputePipeline,
    sharpen: wgpu::ComputePipeline,
    convert: wgpu::ComputePipeline,
}

impl Passes {
    fn new(gpu: &Gpu) -> Self {
        let consts = consts();
        let with = |body: &str| format!("{SHARED}\n{body}");
        Passes {
            resolve: pipeline(
                gpu,
                "taa resolve",
                &consts,
                &with(&format!("{}\n{REPROJECT}", include_str!("taa_resolve.wgsl"))),
                "resolve",
            ),
            sharpen: pipeline(
                gpu,
                "taa sharpen",
                &consts,
                &with(include_str!("taa_sharpen.wgsl")),
                "sharpen",
            ),
            convert: pipeline(
                gpu,
                "taa convert",
                &consts,
                &with(include_str!("taa_convert.wgsl")),
                "convert",
            ),
        }
    }
}

/// Device buffers for one frame size, and the bind groups that use them (made once: the
/// history alternates between two).
#[derive(Debug)]
pub(crate) struct Buffers {
    width: usize,
    height: usize,
    params: wgpu::Buffer,
    convert_params: wgpu::Buffer,
    input: StorageBuffer,
    /// The colour's way into `input`.
    upload: ColorUpload,
    /// The history: `hist.buffer(read)` is the previous frame's, the other is written.
    hist: TexelHistory,
    counters: wgpu::Buffer,
    /// `resolve[k]` reads `hist[k]` and writes `hist[1 - k]` and the colour `out[0]`.
    resolve: [wgpu::BindGroup; 2],
    /// Sharpens `out[0]` into `out[1]`.
    sharpen: wgpu::BindGroup,
    /// `convert[k]` converts `hist[k]` in place.
    convert: [wgpu::BindGroup; 2],
    /// The resolved colour (working space when a sharpen follows), then the sharpened one.
    out: [StorageBuffer; 2],
    /// Timestamps of the frame's passes (convert, resolve, sharpen), where the device has
    /// them.
    timer: Option<PassTimer>,
    /// The colour (3 planes), the counters, then the timestamps.
    back: Readback,
}

impl Buffers {
    fn new(
        gpu: &Gpu,
        passes: &Passes,
        width: usize,
        height: usize,
        depth: bool,
        upload: UploadPrecision,
    ) -> Result<Self, BackendError> {
        let n = width * height;
        let params = params_buffer(gpu, "taa params", &[0; 9]);
        let convert_params = params_buffer(gpu, "taa convert params", &[0; 9]);
        let input = StorageBuffer::new(gpu, "taa input", INPUT_PLANES * n)?;
        let upload = ColorUpload::new(gpu, upload, &input, n)?;
        let hist = TexelHistory::new(gpu, "taa history", (width, height), 4, depth)?;
        let out = [
            StorageBuffer::new(gpu, "taa colour", 3 * n)?,
            StorageBuffer::new(gpu, "taa colour", 3 * n)?,
        ];
        let counters = StorageBuffer::new(gpu, "taa counters", COUNTERS)?.buffer;
        let resolve = [0, 1].map(|k| {
            bind(
                gpu,
                &passes.resolve,
                &[
                    &params,
                    &input.buffer,
                    hist.buffer(k),
                    hist.buffer(1 - k),
                    &out[0].buffer,
                    &counters,
                ],
            )
        });
        let sharpen = bind(gpu, &passes.sharpen, &[&params, &out[0].buffer, &out[1].buffer]);
        let convert = [0, 1].map(|k| bind(gpu, &passes.convert, &[&convert_params, hist.buffer(k)]));
        let timer = PassTimer::new(gpu, 3);
        let timer_words = timer.as_ref().map_or(0, PassTimer::words);
        Ok(Buffers {
            width,
            height,
            params,
            convert_params,
            input,
            upload,
            hist,
            counters,
            resolve,
            sharpen,
            convert,
            out,
            back: Readback::new(gpu, "taa readback", 3 * n + COUNTERS + timer_words),
            timer,
        })
    }
}

/// `taa` with its history on the device.
pub(crate) type GpuTaa = DeviceHistory<Params, Passes, Buffers>;

impl FrameBuffers<Params, Passes> for Buffers {
    fn size(&self) -> (usize, usize) {
        (self.width, self.height)
    }

    fn make(f: &GpuTaa, (width, height): (usize, usize)) -> Result<Self, BackendError> {
        Buffers::new(&f.gpu, &f.passes, width, height, f.keeps_depth(), f.upload)
    }
}

impl GpuTaa {
    /// The filter with parameters `params` on `gpu`, its colour uploaded at `upload`
    /// precision.
    pub fn new(gpu: Arc<Gpu>, params: Params, upload: UploadPrecision) -> Self {
        let passes = Passes::new(&gpu);
        DeviceHistory::with(gpu, params, upload, passes)
    }

    fn keeps_depth(&self) -> bool {
        self.params.depth_rejection > 0.0
    }

    fn param_words(&self, width: usize, height: usize, flags: u32, top: f32) -> [u32; 9] {
        let p = &self.params;
        [
            width as u32,
            height as u32,
            flags,
            (4 * width * height) as u32,
            p.alpha.to_bits(),
            p.gamma.to_bits(),
            p.depth_rejection.to_bits(),
            p.sharpen.to_bits(),
            top.to_bits(),
        ]
    }
}

history_filter!(GpuTaa, Taa, texels);

impl GpuTaa {
    fn run(&mut self, frame: &Frame) -> Result<Output, BackendError> {
        let mut rec = Recorder::new();
        let recon = self.params.reconstruction();
        let mut inp = self.prepared::<Taa>(frame, recon, &mut rec)?;
        let (w, h) = (inp.width, inp.height);
        let hdr = inp.facts.hdr;
        let has_history = self.started(frame, &inp)?;
        let plan = StagePlan::new(&self.params, &inp, has_history);
        let flags = self.flags(&plan, &inp, has_history);

        let mut clock = FrameClock::start();
        let top = self
            .buffers
            .as_ref()
            .expect("sized")
            .upload
            .output_ceiling(&inp.facts);
        let words = self.param_words(w, h, flags, top);
        // The history goes to the working space of this frame's colour first.
        let convert = (has_history && self.tonemapped != hdr)
            .then(|| self.param_words(w, h, if hdr { FLAG_TO_TONEMAPPED } else { 0 }, top));
        let bytes = self.upload_frame(frame, &mut inp, &plan, flags, &words, convert.as_ref());
        let back = self.dispatch(w, h, convert.is_some(), plan.sharpen.is_none(), &mut clock)?;
        let device = clock.times(back.pass_ms.as_ref().map(|v| v.iter().sum()), self.upload, bytes);
        record_stages(&mut rec, &plan, &device, back.pass_ms.as_deref());
        let c = &back.counters;
        let pixels = PixelCounts {
            history_reset: c[C_RESET] as u64,
            history_clipped: c[C_CLIPPED] as u64,
            history_rejected: c[C_REJECTED] as u64,
        };
        let counts = (pixels, self.state_bytes());
        Ok(self.finished(Taa::NAME, frame, &inp, rec, counts, device, back.color))
    }

    /// The shader's flags for a frame with inputs `inp` under `plan`.
    fn flags(&self, plan: &StagePlan, inp: &Inputs, has_history: bool) -> u32 {
        let p = &self.params;
        let mut flags = 0;
        let mut set = |on: bool, bit: u32| {
            if on {
                flags |= bit;
            }
        };
        set(plan.tonemap.is_none(), FLAG_TONEMAP);
        set(plan.dilate.is_none(), FLAG_DILATE);
        set(plan.reproject.is_none(), FLAG_REPROJECT);
        set(plan.depth_reject.is_none(), FLAG_DEPTH_REJECT);
        set(has_history, FLAG_HISTORY);
        set(p.history_filter == HistoryFilter::CatmullRom, FLAG_CATMULL_ROM);
        set(p.luminance_weighting, FLAG_LUMA_WEIGHT);
        set(inp.invalid.is_some(), FLAG_INVALID);
        set(plan.sharpen.is_none(), FLAG_SHARPEN);
        set(self.keeps_depth() && inp.depth.is_some(), FLAG_KEEP_DEPTH);
        flags
    }

    /// Uploads what the plan reads: the colour (as f32 or f16; planes of the host's own go
    /// back to the scratch), then motion, depth and the invalid mask as f32; then the
    /// shader's parameter `words` and, when the history is converted, the conversion's.
    /// Returns the bytes written.
    fn upload_frame<'f>(
        &mut self,
        frame: &'f Frame,
        inp: &mut Inputs<'f>,
        plan: &StagePlan,
        flags: u32,
        words: &[u32; 9],
        convert: Option<&[u32; 9]>,
    ) -> u64 {
        let gpu = &self.gpu;
        let b = self.buffers.as_mut().expect("sized");
        let motion = plan.reproject.is_none();
        let depth = flags & (FLAG_DILATE | FLAG_DEPTH_REJECT | FLAG_KEEP_DEPTH) != 0;
        let scratch = &mut self.scratch;
        let mut bytes = upload_inputs(gpu, &mut b.upload, &b.input, frame, inp, scratch, motion, depth);
        bytes += write_words(gpu, &b.params, words);
        if let Some(convert) = convert {
            bytes += write_words(gpu, &b.convert_params, convert);
        }
        bytes
    }

    /// Runs the frame's passes (the colour's unpacking; the history's conversion when
    /// `convert`; the resolve; the sharpen when `sharpen`) and reads back the colour, the
    /// counters and the timestamps, marking `clock` at the submission and the readback.
    fn dispatch(
        &mut self,
        w: usize,
        h: usize,
        convert: bool,
        sharpen: bool,
        clock: &mut FrameClock,
    ) -> Result<FrameBack, BackendError> {
        let gpu = &self.gpu;
        let b = self.buffers.as_ref().expect("sized");
        let mut enc = gpu.device.create_command_encoder(&Default::default());
        enc.clear_buffer(&b.counters, 0, None);
        b.upload.encode(gpu, &mut enc);
        let timer = b.timer.as_ref();
        let passes = self.encode_passes(&mut enc, b, w, h, convert, sharpen);
        let outputs = (&b.out[sharpen as usize].buffer, &b.counters, COUNTERS);
        let timed = (timer, passes);
        submit_and_read(gpu, enc, &b.back, outputs, timed, (w, h), &mut self.words, clock)
    }

    /// Encodes the compute passes (each timed where the device has timestamps): the
    /// history's conversion in place when `convert`, the resolve into `out[0]`, and when
    /// `sharpen` the sharpen into `out[1]`. Returns how many passes it encoded.
    fn encode_passes(
        &self,
        enc: &mut wgpu::CommandEncoder,
        b: &Buffers,
        w: usize,
        h: usize,
        convert: bool,
        sharpen: bool,
    ) -> u32 {
        let timer = b.timer.as_ref();
        let mut passes = 0;
        if convert {
            let groups = (w * h).div_ceil(CONVERT_GROUP);
            let (gx, gy) = (groups.min(65535) as u32, groups.div_ceil(65535) as u32);
            let mut pass = timing::begin(enc, timer, passes);
            passes += 1;
            pass.set_pipeline(&self.passes.convert);
            pass.set_bind_group(0, &b.convert[self.read], &[]);
            pass.dispatch_workgroups(gx, gy, 1);
        }
        let (gx, gy) = groups(w, h, WORKGROUP);
        {
            let mut pass = timing::begin(enc, timer, passes);
            passes += 1;
            pass.set_pipeline(&self.passes.resolve);
            pass.set_bind_group(0, &b.resolve[self.read], &[]);
            pass.dispatch_workgroups(gx, gy, 1);
        }
        if sharpen {
            let mut pass = timing::begin(enc, timer, passes);
            passes += 1;
            pass.set_pipeline(&self.passes.sharpen);
            pass.set_bind_group(0, &b.sharpen, &[]);
            pass.dispatch_workgroups(gx, gy, 1);
        }
        passes
    }
}

/// Records the same stages as the CPU filter's record, run or left out for the same
/// reasons. With timestamps `sharpen` gets its pass's time (the last of `pass_ms`) and the
/// others share the rest (one pass fuses them); without, all share the frame's round trip.
fn record_stages(rec: &mut Recorder, plan: &StagePlan, device: &DeviceTimes, pass_ms: Option<&[f64]>) {
    let sharpen_ms = match (pass_ms, plan.sharpen.is_none()) {
        (Some(v), true) => v.last().copied(),
        _ => None,
    };
    let stages = vec![
        ("tonemap", plan.tonemap.clone()),
        ("ycocg", None),
        ("dilate", plan.dilate.clone()),
        ("reproject", plan.reproject.clone()),
        ("depth_reject", plan.depth_reject.clone()),
        ("resolve", None),
        ("sharpen", plan.sharpen.clone()),
        ("untonemap", plan.tonemap.clone()),
    ];
    match (device.shaders_ms, sharpen_ms) {
        (Some(all), Some(sharpen)) => {
            let rest = stages
                .iter()
                .filter(|(n, s)| s.is_none() && *n != "sharpen")
                .count();
            for (name, skip) in stages {
                match (skip, name) {
                    (Some(why), _) => rec.skip(name, why),
                    (None, "sharpen") => rec.ran_for(name, sharpen),
                    (None, _) => rec.ran_for(name, (all - sharpen) / rest as f64),
                }
            }
        }
        (shaders, _) => timing::share(
            rec,
            stages,
            shaders.unwrap_or(device.upload_ms + device.readback_ms),
        ),
    }
}
