//! `phlm` on the GPU: the CPU filter's parameters, stage plan and saved-state format, with
//! its per-pixel work in one WGSL pass (`phlm.wgsl`). The models (beta, R, z, the count
//! of failed box tests, the speed and the depth: [`STATE_PLANES`] planes) stay on the
//! device, double-buffered; a frame uploads its
//! colour (and motion and the invalid mask when it has them) and reads back the colour and
//! the model counters in one buffer.
//!
//! The RLS update is solved in f32 ([`rls::update_information_f32`], which the shader
//! mirrors): the information matrix formed with one rounding per entry and Cholesky pivots
//! held at or above the prior. The CPU solves in f64.

use super::buffers::download;
use super::frame_io::{FrameBack, FrameIo, IoShape, Submitted};
use super::history::{DeviceHistory, FrameBuffers, StartFrame, Started};
use super::timing::{self, FrameClock};
use super::{history_filter, input_consts, pipeline, Gpu, StorageBuffer, INPUT_PLANES};
use super::{COUNTS, FRAME, REPROJECT, WORKING};
use crate::filters::passes::{dilate_skip, reproject_skip, TemporalState};
use crate::filters::phlm::{
    convert_state, from_texels, to_texels, ModelFetch, OnClip, Params, Phlm, TestBox, STATE_PLANES,
};
use crate::frame::{Frame, Plane};
use crate::pipeline::{FilterKind, Inputs, ModelHealth, PixelCounts, Recorder, Skip};
use crate::BackendError;

const SOURCE: &str = include_str!("phlm.wgsl");
const WORKGROUP: usize = 8;

// Bits of `Params.flags`, declared in phlm.wgsl ([`consts`]).
super::flag_bits! {
    flag_consts: FLAG_TONEMAP, FLAG_REPROJECT, FLAG_HISTORY, FLAG_MOTION, FLAG_INVALID, FLAG_NEAREST,
    FLAG_VARIANCE_BOX, FLAG_SHIFT, FLAG_DILATE, FLAG_CATMULL_ROM, FLAG_DEPTH
}

// The counters: models reset, clipped, reset off screen, P repaired, the largest trace(P)
// (as bits).
super::counters! { counter_consts: C_RESET, C_CLIPPED, C_OFFSCREEN, C_REPAIRED, C_TRACE }

/// What phlm.wgsl takes from Rust: the input planes ([`input_consts`]), the flag bits and
/// counters above, the workgroup's side, and the CPU filter's constants it mirrors.
fn consts() -> String {
    use crate::filters::phlm::{feature, DEPTH_JUMP_SPEED, STRIKE_DECAY};
    input_consts()
        + &flag_consts()
        + &counter_consts()
        // The largest trace(P) keeps its bits' maximum (non-negative floats order as their
        // bits): the counts from C_TRACE on are not summed.
        + &super::wgsl_consts![
            WORKGROUP,
            SUMMED = C_TRACE,
            FEATURE_EPS = feature::EPS,
            STRIKE_DECAY,
            DEPTH_JUMP_SPEED
        ]
}

/// Planes of each part of the models (phlm's BETA, R and Z ranges): beta, the information
/// matrix R, the feature z with the count of failed box tests, the speed and the depth; a
/// buffer each, so a 1080p frame's parts fit the 128 MiB a shader's buffer may have on many
/// devices (all 28 planes at 1080p are 232 MB).
const PARTS: [(&str, usize); 3] = [
    ("phlm models (beta)", 12),
    ("phlm models (R)", 10),
    (
        "phlm models (z, the count of failed box tests, the speed, the depth)",
        6,
    ),
];

// The parts are the whole state, in its order.
const _: () = assert!(PARTS[0].1 + PARTS[1].1 + PARTS[2].1 == STATE_PLANES);

super::frame_io::bindings! {
    /// phlm.wgsl's buffers after `P` and `inp`: the previous models' parts ([`PARTS`]), the
    /// next models' parts, the colour and the counters.
    BINDINGS: beta: Read, info: Read, feat: Read, next_beta: Write, next_info: Write, next_feat: Write,
        out: Write, counters: Counters
}

/// Words of the shader's `Params` (`phlm.wgsl`: 21 four-byte fields, in
/// [`GpuPhlm::param_words`]'s order).
const PARAM_WORDS: usize = 21;

/// Device buffers for one frame size, and the two bind groups that alternate the state.
#[derive(Debug)]
pub(crate) struct Buffers {
    io: FrameIo,
    /// The models, in [`PARTS`]: `state[read]` is the previous frame's, the other is
    /// written.
    state: [[StorageBuffer; 3]; 2],
    out: StorageBuffer,
    /// `bound[k]` reads `state[k]` and writes `state[1 - k]`.
    bound: [wgpu::BindGroup; 2],
}

/// `phlm` with its models on the device (its passes: the one compiled pass).
pub(crate) type GpuPhlm = DeviceHistory<Params, wgpu::ComputePipeline, Buffers>;

impl FrameBuffers<Params, wgpu::ComputePipeline> for Buffers {
    /// What `phlm` keeps for a frame: its inputs, parameters, counters and its one pass.
    const SHAPE: IoShape = IoShape::new("phlm", INPUT_PLANES, PARAM_WORDS, COUNTERS, (1, WORKGROUP));

    fn io(&self) -> &FrameIo {
        &self.io
    }

    fn compile(gpu: &Gpu) -> wgpu::ComputePipeline {
        pipeline(
            gpu,
            "phlm",
            &consts(),
            &format!(
                "{}{SOURCE}\n{FRAME}\n{WORKING}\n{COUNTS}\n{REPROJECT}",
                BINDINGS.wgsl()
            ),
            "resolve",
        )
    }

    fn make(f: &GpuPhlm, io: FrameIo) -> Result<Self, BackendError> {
        let (gpu, (width, height)) = (&*f.gpu, io.size());
        let n = width * height;
        let pass = &f.passes;
        let models = || -> Result<[StorageBuffer; 3], BackendError> {
            let [a, b, c] = PARTS.map(|(label, planes)| StorageBuffer::new(gpu, label, planes * n));
            Ok([a?, b?, c?])
        };
        let state = [models()?, models()?];
        let out = StorageBuffer::new(gpu, "phlm colour", 3 * n)?;
        let bound = [0, 1].map(|k| {
            let names = [["beta", "info", "feat"], ["next_beta", "next_info", "next_feat"]];
            let models = [&state[k], &state[1 - k]].into_iter().zip(names);
            let buffers: Vec<_> = models
                .flat_map(|(parts, names)| names.into_iter().zip(parts.iter().map(|b| &b.buffer)))
                .collect();
            let ends = [("out", &out.buffer), ("counters", &io.counters)];
            BINDINGS.group(gpu, pass, &io, &[&buffers[..], &ends].concat())
        });
        Ok(Buffers {
            io,
            state,
            out,
            bound,
        })
    }
}

impl GpuPhlm {
    /// The shader's `Params` words for settings `p` (the effective ones).
    fn param_words(p: &Params, width: usize, height: usize, flags: u32, hi: f32) -> [u32; PARAM_WORDS] {
        [
            width as u32,
            height as u32,
            flags,
            p.clip_after.to_bits(),
            p.lambda.to_bits(),
            p.lambda_moving.to_bits(),
            p.lambda_speed.to_bits(),
            p.p0.to_bits(),
            p.clip_p.to_bits(),
            p.clip_keep.to_bits(),
            p.feature_a.to_bits(),
            p.feature_b.to_bits(),
            p.feature_alpha_min.to_bits(),
            p.test_gamma.to_bits(),
            hi.to_bits(),
            (1.0 / p.p0.max(p.clip_p)).to_bits(),
            p.fail_keep.to_bits(),
            p.fail_ramp.to_bits(),
            p.speed_jump.to_bits(),
            p.fail_ramp_box.to_bits(),
            p.depth_jump.to_bits(),
        ]
    }

    /// The previous frame's models as [`STATE_PLANES`] planes (the CPU reference's planar
    /// layout).
    fn download(&self) -> Result<Vec<Plane<f32>>, BackendError> {
        let b = self.buffers.as_ref().expect("sized");
        let (w, h) = b.io.size();
        let n = w * h;
        let parts: Vec<&StorageBuffer> = b.state[self.read].iter().collect();
        let words = download(&self.gpu, "phlm model readback", &parts)?;
        (0..STATE_PLANES)
            .map(|k| {
                Plane::from_vec(w, h, words[k * n..(k + 1) * n].to_vec())
                    .map_err(|e| BackendError::Device(e.to_string()))
            })
            .collect()
    }

    /// Writes [`STATE_PLANES`] model planes as the previous frame's.
    fn upload(&self, planes: &[Plane<f32>]) {
        let b = self.buffers.as_ref().expect("sized");
        let n = b.io.size().0 * b.io.size().1;
        let mut k = 0;
        for (part, (_, count)) in b.state[self.read].iter().zip(PARTS) {
            for j in 0..count {
                part.write(&self.gpu, j * n, planes[k].data());
                k += 1;
            }
        }
    }
}

history_filter!(GpuPhlm, Phlm);

impl GpuPhlm {
    /// The CPU filter's empty state, the layout the device models are saved and loaded in.
    fn empty_history(&self) -> TemporalState {
        Phlm::history()
    }

    /// Bytes of the device models.
    fn history_bytes(&self) -> usize {
        self.buffers
            .as_ref()
            .map_or(0, |b| b.state.iter().flatten().map(StorageBuffer::bytes).sum())
    }

    /// The models read next as the CPU filter lays them out (one plane of texels).
    fn download_history(&self) -> Result<Vec<Plane<f32>>, BackendError> {
        Ok(vec![to_texels(&self.download()?)])
    }

    /// Writes `planes` (the CPU filter's layout) into the models read next.
    fn upload_history(&self, planes: &[Plane<f32>]) {
        self.upload(&from_texels(&planes[0]));
    }
}

/// Which of the CPU filter's optional stages a frame runs (`None`: it runs, else why it is
/// left out), and the shader's flags that say the same.
struct FramePlan {
    tonemap: Option<Skip>,
    reproject: Option<Skip>,
    dilate: Option<Skip>,
    flags: u32,
}

impl FramePlan {
    /// The plan for inputs `inp` under the effective settings `p`, `has_history` saying
    /// whether the models hold a previous frame.
    fn new(p: &Params, inp: &Inputs, has_history: bool) -> Self {
        let tonemap = inp.facts.tonemap();
        let reproject = reproject_skip(inp, has_history);
        let dilate = dilate_skip(inp, &reproject, p.dilation);
        let mut flags = 0;
        let mut set = |on: bool, bit: u32| {
            if on {
                flags |= bit;
            }
        };
        set(tonemap.is_none(), FLAG_TONEMAP);
        set(reproject.is_none(), FLAG_REPROJECT);
        set(has_history, FLAG_HISTORY);
        set(inp.motion.is_some(), FLAG_MOTION);
        set(inp.invalid.is_some(), FLAG_INVALID);
        set(p.model_fetch == ModelFetch::Nearest, FLAG_NEAREST);
        set(p.test_box == TestBox::Variance, FLAG_VARIANCE_BOX);
        set(p.on_clip == OnClip::Shift, FLAG_SHIFT);
        set(dilate.is_none(), FLAG_DILATE);
        set(p.model_fetch == ModelFetch::CatmullRom, FLAG_CATMULL_ROM);
        set(inp.depth.is_some(), FLAG_DEPTH);
        FramePlan {
            tonemap,
            reproject,
            dilate,
            flags,
        }
    }

    /// Records the CPU filter's stages, run or left out for the same reasons; one pass runs
    /// them all, so those that ran share its device time `ms`.
    fn record(self, rec: &mut Recorder, ms: f64) {
        timing::share(
            rec,
            vec![
                ("tonemap", self.tonemap.clone()),
                ("ycocg", None),
                ("dilate", self.dilate),
                ("reproject", self.reproject),
                ("feature", None),
                ("model", None),
                ("untonemap", self.tonemap),
            ],
            ms,
        );
    }
}

impl StartFrame for GpuPhlm {
    fn start(&mut self, frame: &Frame) -> Result<Started<Self>, BackendError> {
        let mut rec = Recorder::new();
        let recon = self.params.effective().reconstruction();
        let mut inp = self.prepared::<Phlm>(frame, recon, &mut rec)?;
        let (w, h) = (inp.width, inp.height);
        let hdr = inp.facts.hdr;
        let has_history = self.started(frame, &inp)?;
        let mut clock = FrameClock::start();
        if has_history && self.tonemapped != hdr {
            // A stream moving between LDR and HDR frames: the models move to the new working
            // space on the CPU (rare; `phlm::convert_state`, the CPU filter's conversion).
            let mut planes = self.download()?;
            convert_state(&mut planes, hdr);
            self.upload(&planes);
        }
        let p = &self.params.effective();
        let plan = FramePlan::new(p, &inp, has_history);
        let hi = self.io().upload.output_ceiling(&inp.facts);
        let words = Self::param_words(p, w, h, plan.flags, hi);
        let bytes = self.upload_frame(frame, &mut inp, &words);
        let submitted = self.dispatch(&mut clock);
        let (index, input) = (frame.meta.index, inp.counts);
        let finish = move |f: &mut Self, back: FrameBack, clock: FrameClock| {
            let device = clock.times(back.shaders_ms(), f.upload, bytes);
            // Without timestamps, the stages share the frame's round trip.
            plan.record(
                &mut rec,
                back.shaders_ms().unwrap_or(device.upload_ms + device.readback_ms),
            );
            let c = &back.counters;
            let pixels = PixelCounts {
                history_reset: c[C_RESET] as u64,
                history_clipped: c[C_CLIPPED] as u64,
                history_rejected: 0,
            };
            let n = (w * h) as f64;
            let model = ModelHealth {
                reset_by_clip: c[C_CLIPPED] as f64 / n,
                reset_by_disocclusion: c[C_OFFSCREEN] as f64 / n,
                max_trace_p: f32::from_bits(c[C_TRACE]) as f64,
                p_repaired: c[C_REPAIRED] as u64,
            };
            let mut out = f.output(Phlm::NAME, index, rec, (pixels, input), device, back.color);
            out.record.model = Some(model);
            Ok(out)
        };
        Ok(self.submitted(submitted, clock, (true, hdr), Box::new(finish)))
    }
}

impl GpuPhlm {
    /// Uploads the shader's parameter `words`, the colour (as f32 or f16; planes of the
    /// host's own go back to the scratch), then motion, depth (for the dilation and the
    /// models' depth) and the invalid mask as f32. Returns the bytes written.
    fn upload_frame<'f>(
        &mut self,
        frame: &'f Frame,
        inp: &mut Inputs<'f>,
        words: &[u32; PARAM_WORDS],
    ) -> u64 {
        let gpu = &self.gpu;
        let b = self.buffers.as_mut().expect("sized");
        let motion = inp.motion.is_some();
        let bytes = b.io.write_params(gpu, words);
        bytes
            + b.io
                .write_inputs(gpu, frame, inp, &mut self.scratch, (motion, true))
    }

    /// Runs the pass over the uploaded frame (after the colour's unpacking) and submits it
    /// with the copies of the colour, the counters and the timestamps, marking `clock`.
    fn dispatch(&mut self, clock: &mut FrameClock) -> Submitted {
        let gpu = &self.gpu;
        let b = self.buffers.as_mut().expect("sized");
        let mut enc = b.io.encoder(gpu);
        let pass = (true, &self.passes, &b.bound[self.read], b.io.groups());
        let used = b.io.encode_passes(&mut enc, &[pass]);
        b.io.submit(gpu, enc, &b.out.buffer, used, clock)
    }
}
