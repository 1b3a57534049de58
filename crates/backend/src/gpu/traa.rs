//! `traa` on the GPU: the CPU filter's plan ([`StagePlan`]), parameters, constants and
//! state format, with its per-pixel stages in WGSL (`traa.wgsl`, `traa_resolve.wgsl`, and
//! `taa`'s sharpen). The history (texels [r, g, b] or [r, g, b, sobel], and depth / far
//! when improved) stays on the device, double-buffered; a frame uploads its colour and
//! what its plan reads of motion, depth, albedo and object ids, and reads back the colour
//! and the pixel counts.
//!
//! Passes: `sobel` and `sobel_history` (improved only: the resolve's aliased value reads
//! the Sobel history's 3x3, which reads the raw Sobel's 3x3), `resolve`, and `sharpen`.

use super::buffers::{write_words, TexelHistory};
use super::frame_io::{FrameBack, FrameIo, IoShape, Submitted};
use super::history::{DeviceHistory, FrameBuffers, StartFrame, Started};
use super::timing::{self, FrameClock};
use super::{bind, history_filter, input_consts, pipeline, Gpu, StorageBuffer};
use super::{COUNTS, FRAME, INPUT_PLANES, REPROJECT, WORKING};
use crate::filters::traa::{
    Params, StagePlan, Traa, Variant, DEPTH_DISTANCE_MIN, FEEDBACK_LUMA_FLOOR, SOBEL_LIT_WEIGHT,
    SOBEL_UNLIT_WEIGHT,
};
use crate::frame::Frame;
use crate::pipeline::{FilterKind, Inputs, PixelCounts, Recorder};
use crate::BackendError;

const SHARED: &str = include_str!("traa.wgsl");
const WORKGROUP: usize = 8;

// Bits of `Params.flags`, declared in the shaders ([`consts`]).
super::flag_bits! {
    flag_consts: FLAG_TONEMAP, FLAG_HISTORY, FLAG_REPROJECT, FLAG_DILATE, FLAG_IMPROVED, FLAG_ALBEDO,
    FLAG_DEPTH, FLAG_MODEL, FLAG_INVALID, FLAG_SHARPEN
}

// The counters: pixels whose history was reset, clipped.
super::counters! { counter_consts: C_RESET, C_CLIPPED }

/// The Sobel history's channel of an improved texel [r, g, b, sobel].
const SOBEL_TEXEL: usize = 3;
super::frame_io::bindings! {
    /// The buffers of traa_resolve.wgsl's passes after `P` and `inp`.
    STAGES: albedo: Read, ids: Ids, hist: Read, next: Write, raw: Write, stable: Write,
        out: Write, counters: Counters
}

/// Words of the shaders' `Params` (`traa.wgsl`, in [`GpuTraa::param_words`]'s order).
const PARAM_WORDS: usize = 9;

/// What traa's shaders take from Rust: the input planes ([`input_consts`]), the flag bits
/// and counters above, the workgroup size, and the CPU filter's constants.
fn consts() -> String {
    let ours = super::wgsl_consts! {
        SOBEL_TEXEL, WORKGROUP, SUMMED = COUNTERS, FEEDBACK_LUMA_FLOOR, SOBEL_UNLIT_WEIGHT, SOBEL_LIT_WEIGHT, DEPTH_DISTANCE_MIN
    };
    input_consts() + &flag_consts() + &counter_consts() + &ours
}

/// The compiled passes.
#[derive(Debug)]
pub(crate) struct Passes {
    sobel: wgpu::ComputePipeline,
    sobel_history: wgpu::ComputePipeline,
    resolve: wgpu::ComputePipeline,
    sharpen: wgpu::ComputePipeline,
}

/// What `traa` keeps on the device for one frame size.
#[derive(Debug)]
pub(crate) struct Buffers {
    io: FrameIo,
    /// Albedo (3 planes) and object ids (improved; a word each in baseline).
    albedo: StorageBuffer,
    ids: StorageBuffer,
    /// The history: `hist.buffer(read)` is the previous frame's, the other is written.
    hist: TexelHistory,
    /// The resolved colour (working space when a sharpen follows), then the sharpened one.
    out: [StorageBuffer; 2],
    groups: Groups,
}

/// The passes' bind groups (made once: the history alternates between two).
#[derive(Debug)]
struct Groups {
    /// Writes the raw Sobel.
    sobel: wgpu::BindGroup,
    /// `sobel_history[k]` reads history `k`.
    sobel_history: [wgpu::BindGroup; 2],
    /// `resolve[k]` reads history `k` and writes history `1 - k` and the colour `out[0]`.
    resolve: [wgpu::BindGroup; 2],
    /// Sharpens `out[0]` into `out[1]`.
    sharpen: wgpu::BindGroup,
}

/// Channels of a history texel: r, g, b, and the Sobel history when improved.
fn texel(improved: bool) -> usize {
    if improved {
        4
    } else {
        3
    }
}

/// `traa` with its history on the device.
pub(crate) type GpuTraa = DeviceHistory<Params, Passes, Buffers>;

impl FrameBuffers<Params, Passes> for Buffers {
    /// What `traa` keeps for a frame: its inputs, parameters, counters, and passes sobel,
    /// sobel_history, resolve and sharpen.
    const SHAPE: IoShape = IoShape::new("traa", INPUT_PLANES, PARAM_WORDS, COUNTERS, (4, WORKGROUP));

    fn io(&self) -> &FrameIo {
        &self.io
    }

    fn compile(gpu: &Gpu) -> Passes {
        let consts = consts();
        let resolve = include_str!("traa_resolve.wgsl");
        let stages = format!(
            "{SHARED}\n{}{resolve}\n{FRAME}\n{WORKING}\n{COUNTS}\n{REPROJECT}",
            STAGES.wgsl()
        );
        let sharpen = format!("{SHARED}\n{}", include_str!("taa_sharpen.wgsl"));
        let make = |label: &str, source: &str, entry: &str| pipeline(gpu, label, &consts, source, entry);
        Passes {
            sobel: make("traa sobel", &stages, "sobel"),
            sobel_history: make("traa sobel history", &stages, "sobel_history"),
            resolve: make("traa resolve", &stages, "resolve"),
            sharpen: make("traa sharpen", &sharpen, "sharpen"),
        }
    }

    fn make(f: &GpuTraa, io: FrameIo) -> Result<Self, BackendError> {
        let (gpu, (width, height)) = (&*f.gpu, io.size());
        let n = width * height;
        let (passes, improved) = (&f.passes, f.params.variant == Variant::Improved);
        // The improved variant's own planes; baseline binds a word for each.
        let g = if improved { n } else { 1 };
        let albedo = StorageBuffer::new(gpu, "traa albedo", 3 * g)?;
        let ids = StorageBuffer::new(gpu, "traa object ids", g)?;
        let raw = StorageBuffer::new(gpu, "traa sobel", g)?;
        let stable = StorageBuffer::new(gpu, "traa sobel history", g)?;
        let hist = TexelHistory::new(gpu, "traa history", (width, height), texel(improved), improved)?;
        let colour = || StorageBuffer::new(gpu, "traa colour", 3 * n);
        let out = [colour()?, colour()?];
        let (raw, stable) = (("raw", &raw.buffer), ("stable", &stable.buffer));
        let group = |pass, buffers: &[(&str, &wgpu::Buffer)]| STAGES.group(gpu, pass, &io, buffers);
        let resolve = |k: usize| {
            let ends = [("out", &out[0].buffer), ("counters", &io.counters)];
            let buffers = [
                ("hist", hist.buffer(k)),
                ("next", hist.buffer(1 - k)),
                stable,
                ("ids", &ids.buffer),
            ];
            group(&passes.resolve, &[&buffers[..], &ends].concat())
        };
        let groups = Groups {
            sobel: group(&passes.sobel, &[("albedo", &albedo.buffer), raw]),
            sobel_history: [0, 1]
                .map(|k| group(&passes.sobel_history, &[("hist", hist.buffer(k)), raw, stable])),
            resolve: [0, 1].map(resolve),
            sharpen: bind(
                gpu,
                &passes.sharpen,
                &[&io.params, &out[0].buffer, &out[1].buffer],
            ),
        };
        Ok(Buffers {
            io,
            albedo,
            ids,
            hist,
            out,
            groups,
        })
    }
}

impl GpuTraa {
    fn improved(&self) -> bool {
        self.params.variant == Variant::Improved
    }

    /// The shaders' `Params` words.
    fn param_words(
        &self,
        (width, height): (usize, usize),
        flags: u32,
        top: f32,
        far: f32,
    ) -> [u32; PARAM_WORDS] {
        let p = &self.params;
        [
            width as u32,
            height as u32,
            flags,
            texel(self.improved()) as u32,
            p.feedback_min.to_bits(),
            p.feedback_max.to_bits(),
            Traa::sharpen_strength(p).to_bits(),
            top.to_bits(),
            far.to_bits(),
        ]
    }
}

history_filter!(GpuTraa, Traa, texels);

impl StartFrame for GpuTraa {
    fn start(&mut self, frame: &Frame) -> Result<Started<Self>, BackendError> {
        let mut rec = Recorder::new();
        let recon = self.params.reconstruction();
        let mut inp = self.prepared::<Traa>(frame, recon, &mut rec)?;
        let (size, hdr, improved) = ((inp.width, inp.height), inp.facts.hdr, self.improved());
        let has_history = self.started(frame, &inp)?;
        let mut clock = FrameClock::start();
        if has_history && self.tonemapped != hdr {
            // A stream moving between LDR and HDR frames: the history moves to the new
            // working space on the CPU, by the CPU filter's conversion (rare).
            let mut planes = self.download_history()?;
            Traa::convert_history(&self.params, &mut planes, hdr);
            self.upload_history(&planes);
        }
        let plan = StagePlan::new(&self.params, &inp, has_history);
        let flags = self.flags(&plan, &inp, has_history);
        let far = match (&plan.depth, inp.depth.as_deref()) {
            (None, Some(d)) => Traa::depth_far(frame.meta.near_far, d.data()),
            _ => 1.0,
        };
        let words = self.param_words(size, flags, self.io().upload.output_ceiling(&inp.facts), far);
        let bytes = self.upload_frame(frame, &mut inp, flags, &words);
        let submitted = self.dispatch(flags, &mut clock);
        let (index, input) = (frame.meta.index, inp.counts);
        let finish = move |f: &mut Self, back: FrameBack, clock: FrameClock| {
            let shaders_ms = back.shaders_ms();
            let device = clock.times(shaders_ms, f.upload, bytes);
            // Most stages share a pass: those that ran share the passes' device time (or,
            // without timestamps, the frame's round trip).
            let ms = shaders_ms.unwrap_or(device.upload_ms + device.readback_ms);
            timing::share(&mut rec, plan.stages(improved), ms);
            let c = &back.counters;
            let pixels = PixelCounts {
                history_reset: c[C_RESET] as u64,
                history_clipped: c[C_CLIPPED] as u64,
                history_rejected: 0,
            };
            Ok(f.output(Traa::NAME, index, rec, (pixels, input), device, back.color))
        };
        Ok(self.submitted(submitted, clock, (true, hdr), Box::new(finish)))
    }
}

impl GpuTraa {
    /// The shaders' flags for a frame with inputs `inp` under `plan`.
    fn flags(&self, plan: &StagePlan, inp: &Inputs, has_history: bool) -> u32 {
        let improved = self.improved();
        super::flags_of(&[
            (plan.tonemap.is_none(), FLAG_TONEMAP),
            (has_history, FLAG_HISTORY),
            (plan.reproject.is_none(), FLAG_REPROJECT),
            (plan.dilate.is_none(), FLAG_DILATE),
            (improved, FLAG_IMPROVED),
            (improved && inp.albedo.is_some(), FLAG_ALBEDO),
            (plan.depth.is_none(), FLAG_DEPTH),
            (plan.model.is_none(), FLAG_MODEL),
            (inp.invalid.is_some(), FLAG_INVALID),
            (plan.sharpen.is_none(), FLAG_SHARPEN),
        ])
    }

    /// Uploads what the `flags` say the shaders read: the colour (as f32 or f16; planes of
    /// the host's own go back to the scratch), then motion, depth, the invalid mask, albedo
    /// as f32 and the object ids; then the shaders' parameter `words`. Returns the bytes
    /// written.
    fn upload_frame<'f>(&mut self, frame: &'f Frame, inp: &mut Inputs<'f>, flags: u32, words: &[u32]) -> u64 {
        let n = inp.width * inp.height;
        let gpu = &self.gpu;
        let b = self.buffers.as_mut().expect("sized");
        let motion = flags & FLAG_REPROJECT != 0;
        let depth = flags & (FLAG_DILATE | FLAG_DEPTH) != 0;
        let mut bytes =
            b.io.write_inputs(gpu, frame, inp, &mut self.scratch, (motion, depth));
        if let (Some(albedo), true) = (inp.albedo.as_deref(), flags & FLAG_ALBEDO != 0) {
            for (k, plane) in albedo.iter().enumerate() {
                bytes += b.albedo.write(gpu, k * n, plane.data());
            }
        }
        if let (Some(ids), true) = (inp.object_id, flags & FLAG_MODEL != 0) {
            bytes += write_words(gpu, &b.ids.buffer, ids.data());
        }
        bytes + b.io.write_params(gpu, words)
    }

    /// Runs the frame's passes (after the colour's unpacking) and submits them with the
    /// copies of the colour, the counters and the timestamps, marking `clock`.
    fn dispatch(&mut self, flags: u32, clock: &mut FrameClock) -> Submitted {
        let gpu = &self.gpu;
        let b = self.buffers.as_mut().expect("sized");
        let mut enc = b.io.encoder(gpu);
        let g = b.io.groups();
        let improved = flags & FLAG_IMPROVED != 0;
        let sharpen = flags & FLAG_SHARPEN != 0;
        let (passes, groups) = (&self.passes, &b.groups);
        let used = b.io.encode_passes(
            &mut enc,
            &[
                (improved, &passes.sobel, &groups.sobel, g),
                (
                    improved,
                    &passes.sobel_history,
                    &groups.sobel_history[self.read],
                    g,
                ),
                (true, &passes.resolve, &groups.resolve[self.read], g),
                (sharpen, &passes.sharpen, &groups.sharpen, g),
            ],
        );
        b.io.submit(gpu, enc, &b.out[sharpen as usize].buffer, used, clock)
    }
}
