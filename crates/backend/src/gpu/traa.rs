//! `traa` on the GPU: the CPU filter's plan ([`StagePlan`]), parameters, constants and
//! state format, with its per-pixel stages in WGSL (`traa.wgsl`, `traa_resolve.wgsl`, and
//! `taa`'s sharpen). The history (texels [r, g, b] or [r, g, b, sobel], and depth / far
//! when improved) stays on the device, double-buffered; a frame uploads its colour and
//! what its plan reads of motion, depth, albedo and object ids, and reads back the colour
//! and the pixel counts.
//!
//! Passes: `sobel` and `sobel_history` (improved only: the resolve's aliased value reads
//! the Sobel history's 3x3, which reads the raw Sobel's 3x3), `resolve`, and `sharpen`.

use super::buffers::{download, params_buffer, planes_from, write_words};
use super::timing::{self, FrameClock, PassTimer};
use super::upload::ColorUpload;
use super::{bind, bind_at, groups, history_filter, input_consts, pipeline, Gpu, Readback, StorageBuffer};
use super::{INPUT_PLANES, IN_DEPTH, IN_INVALID, IN_MX, REPROJECT};
use crate::filters::passes::TemporalState;
use crate::filters::traa::{
    Params, StagePlan, Traa, Variant, DEPTH_DISTANCE_MIN, FEEDBACK_LUMA_FLOOR, SOBEL_LIT_WEIGHT,
    SOBEL_UNLIT_WEIGHT,
};
use crate::frame::{Frame, Plane, Rgb};
use crate::pipeline::{
    check_needs, check_size, Backend, Filter, FilterKind, Inputs, Output, PixelCounts, Recorder, Scratch,
    UploadPrecision,
};
use crate::BackendError;
use std::borrow::Cow;
use std::sync::Arc;

const SHARED: &str = include_str!("traa.wgsl");
const WORKGROUP: usize = 8;

// Bits of `Params.flags`, declared in the shaders from these ([`consts`]).
const FLAG_TONEMAP: u32 = 1;
const FLAG_HISTORY: u32 = 2;
const FLAG_REPROJECT: u32 = 4;
const FLAG_DILATE: u32 = 8;
const FLAG_IMPROVED: u32 = 16;
const FLAG_ALBEDO: u32 = 32;
const FLAG_DEPTH: u32 = 64;
const FLAG_MODEL: u32 = 128;
const FLAG_INVALID: u32 = 256;
const FLAG_SHARPEN: u32 = 512;

/// Words of the counters: reset, clipped (the `C_` indices); padded.
const COUNTERS: usize = 4;
const C_RESET: usize = 0;
const C_CLIPPED: usize = 1;
/// The Sobel history's channel of an improved texel [r, g, b, sobel].
const SOBEL_TEXEL: usize = 3;
/// Words of the shaders' `Params` (`traa.wgsl`, in [`GpuTraa::param_words`]'s order).
const PARAM_WORDS: usize = 9;
/// Passes of a frame at most: sobel, sobel_history, resolve, sharpen.
const PASSES: u32 = 4;

/// What traa's shaders take from Rust: the input planes ([`input_consts`]), the flag bits
/// and counters above, the workgroup size, and the CPU filter's constants.
fn consts() -> String {
    input_consts()
        + &super::wgsl_consts![
            FLAG_TONEMAP,
            FLAG_HISTORY,
            FLAG_REPROJECT,
            FLAG_DILATE,
            FLAG_IMPROVED,
            FLAG_ALBEDO,
            FLAG_DEPTH,
            FLAG_MODEL,
            FLAG_INVALID,
            FLAG_SHARPEN,
            COUNTERS,
            C_RESET,
            C_CLIPPED,
            SOBEL_TEXEL,
            WORKGROUP,
            FEEDBACK_LUMA_FLOOR,
            SOBEL_UNLIT_WEIGHT,
            SOBEL_LIT_WEIGHT,
            DEPTH_DISTANCE_MIN,
        ]
}

/// The compiled passes.
#[derive(Debug)]
struct Passes {
    sobel: wgpu::ComputePipeline,
    sobel_history: wgpu::ComputePipeline,
    resolve: wgpu::ComputePipeline,
    sharpen: wgpu::ComputePipeline,
}

impl Passes {
    fn new(gpu: &Gpu) -> Self {
        let consts = consts();
        let stages = format!("{SHARED}\n{}\n{REPROJECT}", include_str!("traa_resolve.wgsl"));
        let sharpen = format!("{SHARED}\n{}", include_str!("taa_sharpen.wgsl"));
        let make = |label: &str, source: &str, entry: &str| pipeline(gpu, label, &consts, source, entry);
        Passes {
            sobel: make("traa sobel", &stages, "sobel"),
            sobel_history: make("traa sobel history", &stages, "sobel_history"),
            resolve: make("traa resolve", &stages, "resolve"),
            sharpen: make("traa sharpen", &sharpen, "sharpen"),
        }
    }
}

/// Device buffers for one frame size, and the bind groups that use them (made once: the
/// history alternates between two).
#[derive(Debug)]
struct Buffers {
    width: usize,
    height: usize,
    params: wgpu::Buffer,
    input: StorageBuffer,
    /// The colour's way into `input`.
    upload: ColorUpload,
    /// Albedo (3 planes) and object ids (improved; a word each in baseline).
    albedo: StorageBuffer,
    ids: StorageBuffer,
    /// The history: `hist[read]` is the previous frame's, the other is written.
    hist: [StorageBuffer; 2],
    counters: wgpu::Buffer,
    /// Writes the raw Sobel.
    sobel: wgpu::BindGroup,
    /// `sobel_history[k]` reads `hist[k]`.
    sobel_history: [wgpu::BindGroup; 2],
    /// `resolve[k]` reads `hist[k]` and writes `hist[1 - k]` and the colour `out[0]`.
    resolve: [wgpu::BindGroup; 2],
    /// Sharpens `out[0]` into `out[1]`.
    sharpen: wgpu::BindGroup,
    /// The resolved colour (working space when a sharpen follows), then the sharpened one.
    out: [StorageBuffer; 2],
    /// Timestamps of the frame's passes, where the device has them.
    timer: Option<PassTimer>,
    /// The colour (3 planes), the counters, then the timestamps.
    back: Readback,
}

impl Buffers {
    fn new(
        gpu: &Gpu,
        passes: &Passes,
        (width, height): (usize, usize),
        improved: bool,
        upload: UploadPrecision,
    ) -> Result<Self, BackendError> {
        let n = width * height;
        // The improved variant's own planes; baseline binds a word for each.
        let g = if improved { n } else { 1 };
        let hist_len = n * (texel(improved) + improved as usize);
        let params = params_buffer(gpu, "traa params", &[0; PARAM_WORDS]);
        let input = StorageBuffer::new(gpu, "traa input", INPUT_PLANES * n)?;
        let upload = ColorUpload::new(gpu, upload, &input, n)?;
        let albedo = StorageBuffer::new(gpu, "traa albedo", 3 * g)?;
        let ids = StorageBuffer::new(gpu, "traa object ids", g)?;
        let raw = StorageBuffer::new(gpu, "traa sobel", g)?;
        let stable = StorageBuffer::new(gpu, "traa sobel history", g)?;
        let hist = [
            StorageBuffer::new(gpu, "traa history", hist_len)?,
            StorageBuffer::new(gpu, "traa history", hist_len)?,
        ];
        let out = [
            StorageBuffer::new(gpu, "traa colour", 3 * n)?,
            StorageBuffer::new(gpu, "traa colour", 3 * n)?,
        ];
        let counters = StorageBuffer::new(gpu, "traa counters", COUNTERS)?.buffer;
        // The bindings of traa_resolve.wgsl.
        let (p, i) = ((0, &params), (1, &input.buffer));
        let sobel = bind_at(gpu, &passes.sobel, &[p, i, (2, &albedo.buffer), (6, &raw.buffer)]);
        let sobel_history = [0, 1].map(|k| {
            let h = (4, &hist[k].buffer);
            bind_at(
                gpu,
                &passes.sobel_history,
                &[p, i, h, (6, &raw.buffer), (7, &stable.buffer)],
            )
        });
        let resolve = [0, 1].map(|k| {
            bind_at(
                gpu,
                &passes.resolve,
                &[
                    p,
                    i,
                    (3, &ids.buffer),
                    (4, &hist[k].buffer),
                    (5, &hist[1 - k].buffer),
                    (7, &stable.buffer),
                    (8, &out[0].buffer),
                    (9, &counters),
                ],
            )
        });
        let sharpen = bind(gpu, &passes.sharpen, &[&params, &out[0].buffer, &out[1].buffer]);
        let timer = PassTimer::new(gpu, PASSES);
        let timer_words = timer.as_ref().map_or(0, PassTimer::words);
        Ok(Buffers {
            width,
            height,
            params,
            input,
            upload,
            albedo,
            ids,
            hist,
            counters,
            sobel,
            sobel_history,
            resolve,
            sharpen,
            out,
            back: Readback::new(gpu, "traa readback", 3 * n + COUNTERS + timer_words),
            timer,
        })
    }
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
#[derive(Debug)]
pub struct GpuTraa {
    gpu: Arc<Gpu>,
    params: Params,
    /// The precision of the colour's upload.
    upload: UploadPrecision,
    passes: Passes,
    buffers: Option<Buffers>,
    /// Which of `buffers.hist` holds the previous frame.
    read: usize,
    /// Whether it does (not on the first frame or after a reset).
    valid: bool,
    /// Whether its colour is tonemapped.
    tonemapped: bool,
    /// Readback staging, reused.
    words: Vec<f32>,
    /// Planes of the host's `reconstruct` stage, reused from frame to frame.
    scratch: Scratch,
}

impl GpuTraa {
    /// The filter with parameters `params` on `gpu`, its colour uploaded at `upload`
    /// precision.
    pub fn new(gpu: Arc<Gpu>, params: Params, upload: UploadPrecision) -> Self {
        GpuTraa {
            upload,
            passes: Passes::new(&gpu),
            gpu,
            params,
            buffers: None,
            read: 0,
            valid: false,
            tonemapped: false,
            words: Vec::new(),
            scratch: Scratch::default(),
        }
    }

    fn improved(&self) -> bool {
        self.params.variant == Variant::Improved
    }

    /// The buffers for a `width` x `height` frame (new ones drop the history).
    fn sized(&mut self, width: usize, height: usize) -> Result<(), BackendError> {
        if self.buffers.as_ref().map(|b| (b.width, b.height)) != Some((width, height)) {
            // Dropped first: the old buffers and the new never take the device's memory
            // together.
            self.buffers = None;
            self.valid = false;
            self.read = 0;
            let improved = self.improved();
            self.buffers = Some(Buffers::new(
                &self.gpu,
                &self.passes,
                (width, height),
                improved,
                self.upload,
            )?);
        }
        Ok(())
    }

    /// The shaders' `Params` words.
    fn param_words(&self, width: usize, height: usize, flags: u32, top: f32, far: f32) -> [u32; PARAM_WORDS] {
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

history_filter!(GpuTraa, Traa);

impl GpuTraa {
    /// The CPU filter's empty state, the layout the device history is saved and loaded in.
    fn empty_history(&self) -> TemporalState {
        Traa::history(&self.params)
    }

    /// Bytes of the device history.
    fn history_bytes(&self) -> usize {
        self.buffers
            .as_ref()
            .map_or(0, |b| b.hist.iter().map(StorageBuffer::bytes).sum())
    }

    /// The history planes as the CPU filter lays them out: the texels, then (improved)
    /// depth / far.
    fn download_history(&self) -> Result<Vec<Plane<f32>>, BackendError> {
        let b = self.buffers.as_ref().expect("sized");
        let (w, n, t) = (b.width, b.width * b.height, texel(self.improved()));
        let words = download(&self.gpu, "traa history readback", &[&b.hist[self.read]])?;
        let mut planes = vec![plane(t * w, b.height, words[..t * n].to_vec())?];
        if self.improved() {
            planes.push(plane(w, b.height, words[t * n..(t + 1) * n].to_vec())?);
        }
        Ok(planes)
    }

    /// Writes `planes` (the CPU filter's layout) into the history read next.
    fn upload_history(&self, planes: &[Plane<f32>]) {
        let b = self.buffers.as_ref().expect("sized");
        let mut at = 0;
        for p in planes {
            b.hist[self.read].write(&self.gpu, at, p.data());
            at += p.data().len();
        }
    }

    fn run(&mut self, frame: &Frame) -> Result<Output, BackendError> {
        let mut rec = Recorder::new();
        check_needs(Traa::NAME, Traa::needs(), frame)?;
        let recon = self.params.reconstruction();
        let mut inp = recon.prepare(frame, Traa::uses(), &mut rec, &mut self.scratch)?;
        let (w, h) = (inp.width, inp.height);
        let hdr = inp.facts.hdr;
        check_size(
            self.buffers.as_ref().map(|b| (b.width, b.height)),
            self.valid,
            frame,
        )?;
        self.sized(w, h)?;
        let has_history = self.valid && !frame.meta.reset;
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
        let top = self
            .buffers
            .as_ref()
            .expect("sized")
            .upload
            .output_ceiling(&inp.facts);
        let words = self.param_words(w, h, flags, top, far);
        let bytes = self.upload_frame(frame, &mut inp, flags, &words);
        let back = self.dispatch(w, h, flags, &mut clock)?;
        let shaders_ms = back.pass_ms.as_ref().map(|v| v.iter().sum());
        let device = clock.times(shaders_ms, self.upload, bytes);
        // One pass fuses most stages: those that ran share the passes' device time (or,
        // without timestamps, the frame's round trip).
        timing::share(
            &mut rec,
            plan.stages(self.improved()),
            shaders_ms.unwrap_or(device.upload_ms + device.readback_ms),
        );

        self.read = 1 - self.read;
        self.valid = true;
        self.tonemapped = hdr;
        let c = &back.counters;
        let pixels = PixelCounts {
            history_reset: c[C_RESET] as u64,
            history_clipped: c[C_CLIPPED] as u64,
            history_rejected: 0,
        };
        let mut record = rec.finish(
            Traa::NAME,
            frame.meta.index,
            pixels,
            inp.counts,
            self.state_bytes(),
        );
        record.backend = Backend::Gpu;
        record.device = Some(device);
        Ok(Output {
            color: back.color,
            record,
        })
    }

    /// The shaders' flags for a frame with inputs `inp` under `plan`.
    fn flags(&self, plan: &StagePlan, inp: &Inputs, has_history: bool) -> u32 {
        let improved = self.improved();
        let mut flags = 0;
        let mut set = |on: bool, bit: u32| {
            if on {
                flags |= bit;
            }
        };
        set(plan.tonemap.is_none(), FLAG_TONEMAP);
        set(has_history, FLAG_HISTORY);
        set(plan.reproject.is_none(), FLAG_REPROJECT);
        set(plan.dilate.is_none(), FLAG_DILATE);
        set(improved, FLAG_IMPROVED);
        set(improved && inp.albedo.is_some(), FLAG_ALBEDO);
        set(plan.depth.is_none(), FLAG_DEPTH);
        set(plan.model.is_none(), FLAG_MODEL);
        set(inp.invalid.is_some(), FLAG_INVALID);
        set(plan.sharpen.is_none(), FLAG_SHARPEN);
        flags
    }

    /// Uploads what the `flags` say the shaders read: the colour (as f32 or f16; planes of
    /// the host's own go back to the scratch), then motion, depth, the invalid mask, albedo
    /// as f32 and the object ids; then the shaders' parameter `words`, and clears the
    /// counters. Returns the bytes written.
    fn upload_frame<'f>(&mut self, frame: &'f Frame, inp: &mut Inputs<'f>, flags: u32, words: &[u32]) -> u64 {
        let n = inp.width * inp.height;
        let gpu = &self.gpu;
        let b = self.buffers.as_mut().expect("sized");
        let mut bytes = b.upload.write(gpu, &b.input, &inp.color);
        if let Cow::Owned(rgb) = std::mem::replace(&mut inp.color, Cow::Borrowed(frame.color())) {
            self.scratch.recycle(rgb);
        }
        let b = &*b;
        if flags & FLAG_REPROJECT != 0 {
            let m = inp.motion.as_deref().expect("reprojection needs motion");
            for (k, plane) in m.iter().enumerate() {
                bytes += b.input.write(gpu, (IN_MX + k) * n, plane.data());
            }
        }
        if let Some(d) = inp.depth.as_deref() {
            if flags & (FLAG_DILATE | FLAG_DEPTH) != 0 {
                bytes += b.input.write(gpu, IN_DEPTH * n, d.data());
            }
        }
        if let Some(invalid) = &inp.invalid {
            let mask: Vec<f32> = invalid.iter().map(|&v| v as u8 as f32).collect();
            bytes += b.input.write(gpu, IN_INVALID * n, &mask);
        }
        if let (Some(albedo), true) = (inp.albedo.as_deref(), flags & FLAG_ALBEDO != 0) {
            for (k, plane) in albedo.iter().enumerate() {
                bytes += b.albedo.write(gpu, k * n, plane.data());
            }
        }
        if let (Some(ids), true) = (inp.object_id, flags & FLAG_MODEL != 0) {
            bytes += write_words(gpu, &b.ids.buffer, ids.data());
        }
        bytes += write_words(gpu, &b.params, words);
        bytes + write_words(gpu, &b.counters, &[0; COUNTERS])
    }

    /// Runs the frame's passes (after the colour's unpacking) and reads back the colour,
    /// the counters and the timestamps, marking `clock` at the submission and the readback.
    fn dispatch(
        &mut self,
        w: usize,
        h: usize,
        flags: u32,
        clock: &mut FrameClock,
    ) -> Result<FrameBack, BackendError> {
        let n = w * h;
        let gpu = &self.gpu;
        let b = self.buffers.as_ref().expect("sized");
        let mut enc = gpu.device.create_command_encoder(&Default::default());
        b.upload.encode(gpu, &mut enc);
        let timer = b.timer.as_ref();
        let (gx, gy) = groups(w, h, WORKGROUP);
        let improved = flags & FLAG_IMPROVED != 0;
        let sharpen = flags & FLAG_SHARPEN != 0;
        let passes = [
            (improved, &self.passes.sobel, &b.sobel),
            (improved, &self.passes.sobel_history, &b.sobel_history[self.read]),
            (true, &self.passes.resolve, &b.resolve[self.read]),
            (sharpen, &self.passes.sharpen, &b.sharpen),
        ];
        let mut used = 0;
        for (_, pipeline, group) in passes.into_iter().filter(|(on, _, _)| *on) {
            let mut pass = timing::begin(&mut enc, timer, used);
            used += 1;
            pass.set_pipeline(pipeline);
            pass.set_bind_group(0, group, &[]);
            pass.dispatch_workgroups(gx, gy, 1);
        }
        b.back
            .copy_from(&mut enc, &b.out[sharpen as usize].buffer, 0, 3 * n);
        enc.copy_buffer_to_buffer(
            &b.counters,
            0,
            b.back.buffer(),
            (3 * n * 4) as u64,
            (COUNTERS * 4) as u64,
        );
        let timer_at = 3 * n + COUNTERS;
        if let Some(t) = timer {
            t.resolve(&mut enc, used, &b.back, timer_at);
        }
        gpu.queue.submit([enc.finish()]);
        clock.submitted();
        let words = timer_at + timer.map_or(0, PassTimer::words);
        b.back.read(gpu, words, &mut self.words)?;
        clock.back();
        Ok(FrameBack {
            color: planes_from(&self.words, w, h)?,
            counters: self.words[3 * n..timer_at].iter().map(|v| v.to_bits()).collect(),
            pass_ms: timer.map(|t| t.pass_ms(&self.words[timer_at..], used)),
        })
    }
}

/// What the device gives back for a frame.
struct FrameBack {
    color: Rgb,
    /// The counters (at the `C_` indices).
    counters: Vec<u32>,
    /// Each pass's time from its timestamps, where the device has them.
    pass_ms: Option<Vec<f64>>,
}

/// A plane of samples read back (their count is the plane's by construction).
fn plane(width: usize, height: usize, data: Vec<f32>) -> Result<Plane<f32>, BackendError> {
    Plane::from_vec(width, height, data).map_err(|e| BackendError::Device(e.to_string()))
}
