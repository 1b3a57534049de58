//! `taa` on the GPU: the CPU filter's plan ([`StagePlan`]), parameters and state format,
//! with its per-pixel stages in WGSL (`taa*.wgsl`). The history (texels [Y, Co, Cg, count],
//! and depth with depth rejection) stays on the device, double-buffered; a frame uploads
//! its colour (and the motion and depth its plan needs), and reads back the colour and the
//! pixel counts.

use super::buffers::{params_buffer, write_words, TexelHistory};
use super::frame_io::{FrameBack, FrameIo, IoShape, Submitted};
use super::history::{DeviceHistory, FrameBuffers, StartFrame, Started};
use super::timing::{self, FrameClock};
use super::{bind, history_filter, input_consts, pipeline, Gpu, StorageBuffer, INPUT_PLANES};
use super::{COUNTS, FRAME, REPROJECT, WORKING};
use crate::filters::taa::{HistoryFilter, Params, StagePlan, Taa};
use crate::frame::Frame;
use crate::pipeline::{DeviceTimes, FilterKind, Inputs, PixelCounts, Recorder};
use crate::BackendError;

const SHARED: &str = include_str!("taa.wgsl");
const WORKGROUP: usize = 8;

// Bits of `Params.flags`, declared in the shaders ([`consts`]).
super::flag_bits! {
    flag_consts: FLAG_TONEMAP, FLAG_DILATE, FLAG_REPROJECT, FLAG_DEPTH_REJECT, FLAG_HISTORY,
    FLAG_CATMULL_ROM, FLAG_LUMA_WEIGHT, FLAG_INVALID, FLAG_SHARPEN, FLAG_KEEP_DEPTH,
    FLAG_TO_TONEMAPPED
}

// The counters: pixels whose history was reset, clipped, rejected.
super::counters! { counter_consts: C_RESET, C_CLIPPED, C_REJECTED }

super::frame_io::bindings! {
    /// taa_resolve.wgsl's buffers after `P` and `inp`.
    RESOLVE: hist: Read, next: Write, out: Write, counters: Counters
}

/// Words of the shaders' `Params` (`taa.wgsl`, in [`GpuTaa::param_words`]'s order).
const PARAM_WORDS: usize = 9;

/// Workgroup size of the `convert` pass (one texel an invocation).
const CONVERT_GROUP: usize = 64;

/// What taa's shaders take from Rust: the input planes ([`input_consts`]), the flag bits
/// and counters above, the workgroup sizes, and the CPU filter's sample count bound.
fn consts() -> String {
    use crate::filters::taa::MAX_COUNT;
    input_consts()
        + &flag_consts()
        + &counter_consts()
        + &super::wgsl_consts![WORKGROUP, CONVERT_GROUP, MAX_COUNT, SUMMED = COUNTERS]
}

/// The compiled passes.
#[derive(Debug)]
pub(crate) struct Passes {
    resolve: wgpu::ComputePipeline,
    sharpen: wgpu::ComputePipeline,
    convert: wgpu::ComputePipeline,
}

/// Device buffers for one frame size, and the bind groups that use them (made once: the
/// history alternates between two).
#[derive(Debug)]
pub(crate) struct Buffers {
    io: FrameIo,
    convert_params: wgpu::Buffer,
    /// The history: `hist.buffer(read)` is the previous frame's, the other is written.
    hist: TexelHistory,
    /// `resolve[k]` reads `hist[k]` and writes `hist[1 - k]` and the colour `out[0]`.
    resolve: [wgpu::BindGroup; 2],
    /// Sharpens `out[0]` into `out[1]`.
    sharpen: wgpu::BindGroup,
    /// `convert[k]` converts `hist[k]` in place.
    convert: [wgpu::BindGroup; 2],
    /// The resolved colour (working space when a sharpen follows), then the sharpened one.
    out: [StorageBuffer; 2],
}

/// `taa` with its history on the device.
pub(crate) type GpuTaa = DeviceHistory<Params, Passes, Buffers>;

impl FrameBuffers<Params, Passes> for Buffers {
    /// What `taa` keeps for a frame: its inputs, 9 parameter words, the counters, and passes
    /// convert, resolve and sharpen.
    const SHAPE: IoShape = IoShape::new("taa", INPUT_PLANES, PARAM_WORDS, COUNTERS, (3, WORKGROUP));

    fn io(&self) -> &FrameIo {
        &self.io
    }

    fn compile(gpu: &Gpu) -> Passes {
        let consts = consts();
        let with = |body: &str| format!("{SHARED}\n{body}");
        Passes {
            resolve: pipeline(
                gpu,
                "taa resolve",
                &consts,
                &with(&format!(
                    "{}{}\n{FRAME}\n{WORKING}\n{COUNTS}\n{REPROJECT}",
                    RESOLVE.wgsl(),
                    include_str!("taa_resolve.wgsl")
                )),
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

    fn make(f: &GpuTaa, io: FrameIo) -> Result<Self, BackendError> {
        let (gpu, (width, height)) = (&*f.gpu, io.size());
        let n = width * height;
        let (passes, depth) = (&f.passes, f.keeps_depth());
        let convert_params = params_buffer(gpu, "taa convert params", &[0; PARAM_WORDS]);
        let hist = TexelHistory::new(gpu, "taa history", io.size(), 4, depth)?;
        let colour = || StorageBuffer::new(gpu, "taa colour", 3 * n);
        let out = [colour()?, colour()?];
        let resolve = [0, 1].map(|k| {
            let buffers = [("hist", hist.buffer(k)), ("next", hist.buffer(1 - k))];
            let ends = [("out", &out[0].buffer), ("counters", &io.counters)];
            RESOLVE.group(gpu, &passes.resolve, &io, &[&buffers[..], &ends].concat())
        });
        let sharpen = bind(
            gpu,
            &passes.sharpen,
            &[&io.params, &out[0].buffer, &out[1].buffer],
        );
        let convert = [0, 1].map(|k| bind(gpu, &passes.convert, &[&convert_params, hist.buffer(k)]));
        Ok(Buffers {
            io,
            convert_params,
            hist,
            resolve,
            sharpen,
            convert,
            out,
        })
    }
}

impl GpuTaa {
    fn keeps_depth(&self) -> bool {
        self.params.depth_rejection > 0.0
    }

    fn param_words(&self, width: usize, height: usize, flags: u32, top: f32) -> [u32; PARAM_WORDS] {
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

impl StartFrame for GpuTaa {
    fn start(&mut self, frame: &Frame) -> Result<Started<Self>, BackendError> {
        let mut rec = Recorder::new();
        let recon = self.params.reconstruction();
        let mut inp = self.prepared::<Taa>(frame, recon, &mut rec)?;
        let (w, h) = (inp.width, inp.height);
        let hdr = inp.facts.hdr;
        let has_history = self.started(frame, &inp)?;
        let plan = StagePlan::new(&self.params, &inp, has_history);
        let flags = self.flags(&plan, &inp, has_history);

        let mut clock = FrameClock::start();
        let top = self.io().upload.output_ceiling(&inp.facts);
        let words = self.param_words(w, h, flags, top);
        // The history goes to the working space of this frame's colour first.
        let convert = (has_history && self.tonemapped != hdr)
            .then(|| self.param_words(w, h, if hdr { FLAG_TO_TONEMAPPED } else { 0 }, top));
        let bytes = self.upload_frame(frame, &mut inp, &plan, flags, &words, convert.as_ref());
        let submitted = self.dispatch(convert.is_some(), plan.sharpen.is_none(), &mut clock);
        let (index, input) = (frame.meta.index, inp.counts);
        let finish = move |f: &mut Self, back: FrameBack, clock: FrameClock| {
            let device = clock.times(back.shaders_ms(), f.upload, bytes);
            record_stages(&mut rec, &plan, &device, back.pass_ms.as_deref());
            let c = &back.counters;
            let pixels = PixelCounts {
                history_reset: c[C_RESET] as u64,
                history_clipped: c[C_CLIPPED] as u64,
                history_rejected: c[C_REJECTED] as u64,
            };
            Ok(f.output(Taa::NAME, index, rec, (pixels, input), device, back.color))
        };
        Ok(self.submitted(submitted, clock, (true, hdr), Box::new(finish)))
    }
}

impl GpuTaa {
    /// The shader's flags for a frame with inputs `inp` under `plan`.
    fn flags(&self, plan: &StagePlan, inp: &Inputs, has_history: bool) -> u32 {
        let p = &self.params;
        super::flags_of(&[
            (plan.tonemap.is_none(), FLAG_TONEMAP),
            (plan.dilate.is_none(), FLAG_DILATE),
            (plan.reproject.is_none(), FLAG_REPROJECT),
            (plan.depth_reject.is_none(), FLAG_DEPTH_REJECT),
            (has_history, FLAG_HISTORY),
            (p.history_filter == HistoryFilter::CatmullRom, FLAG_CATMULL_ROM),
            (p.luminance_weighting, FLAG_LUMA_WEIGHT),
            (inp.invalid.is_some(), FLAG_INVALID),
            (plan.sharpen.is_none(), FLAG_SHARPEN),
            (self.keeps_depth() && inp.depth.is_some(), FLAG_KEEP_DEPTH),
        ])
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
        words: &[u32; PARAM_WORDS],
        convert: Option<&[u32; PARAM_WORDS]>,
    ) -> u64 {
        let gpu = &self.gpu;
        let b = self.buffers.as_mut().expect("sized");
        let motion = plan.reproject.is_none();
        let depth = flags & (FLAG_DILATE | FLAG_DEPTH_REJECT | FLAG_KEEP_DEPTH) != 0;
        let mut bytes =
            b.io.write_inputs(gpu, frame, inp, &mut self.scratch, (motion, depth));
        bytes += b.io.write_params(gpu, words);
        if let Some(convert) = convert {
            bytes += write_words(gpu, &b.convert_params, convert);
        }
        bytes
    }

    /// Runs the frame's passes (the colour's unpacking; the history's conversion in place
    /// when `convert`; the resolve into `out[0]`; the sharpen into `out[1]` when `sharpen`)
    /// and submits them with the copies of the colour, the counters and the timestamps,
    /// marking `clock`.
    fn dispatch(&mut self, convert: bool, sharpen: bool, clock: &mut FrameClock) -> Submitted {
        let gpu = &self.gpu;
        let b = self.buffers.as_mut().expect("sized");
        let (w, h) = b.io.size();
        let mut enc = b.io.encoder(gpu);
        // One texel an invocation, in rows of 65535 workgroups at most.
        let texels = (w * h).div_ceil(CONVERT_GROUP);
        let (gx, gy) = (texels.min(65535) as u32, texels.div_ceil(65535) as u32);
        let image = b.io.groups();
        let used = b.io.encode_passes(
            &mut enc,
            &[
                (convert, &self.passes.convert, &b.convert[self.read], (gx, gy)),
                (true, &self.passes.resolve, &b.resolve[self.read], image),
                (sharpen, &self.passes.sharpen, &b.sharpen, image),
            ],
        );
        b.io.submit(gpu, enc, &b.out[sharpen as usize].buffer, used, clock)
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
    let stages = plan.stages();
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
