//! `upsample` on the GPU: the CPU filter's parameters, stages and state format, with its
//! per-pixel stages in WGSL (`upsample*.wgsl`: reprojection, raw gradient, blend), every
//! method (`spatiotemporal`, `spatial`, `temporal`, `taa`) and shading factor. The history
//! (the CPU's interleaved texels) stays on the device, double-buffered; a frame uploads its
//! colour at the colour's own size and the G-buffer at full resolution, and reads back the
//! colour and the pixel counts. The host runs what the CPU filter runs on whole planes
//! before and after: `repair` and `reconstruct` (full shading) before the upload, the depth
//! range (`geometry`), and `reconstruct` on the output after the readback (sparse
//! shading), so both backends filter the same numbers.

use super::buffers::{download, plane};
use super::frame_io::{FrameBack, FrameIo, IoShape, Submitted};
use super::history::{DeviceHistory, FrameBuffers, StartFrame, Started};
use super::timing::{self, FrameClock};
use super::{history_filter, input_consts, pipeline, Gpu};
use super::{StorageBuffer, FRAME, IN_DEPTH, IN_INVALID, IN_MX};
use crate::filters::passes::TemporalState;
use crate::filters::upsample::{
    decay_for, falloff, geometry, skips, Method, Params, Sparse, Upsample, DEPTH, G1, GRADIENT_WEIGHTS, ID,
    LK, LUMA_FLOOR, R, TAA_KERNEL, TAA_MAX_COUNT, T_DEPTH, T_ID, W, WEIGHT_EPSILON,
};
use crate::frame::{Frame, Plane, Sampling};
use crate::pipeline::{check_channels, FilterKind, Inputs, PixelCounts, Recorder};
use crate::BackendError;

const REPROJECT: &str = include_str!("upsample_reproject.wgsl");
const GRADIENT: &str = include_str!("upsample_gradient.wgsl");
const BLEND: &str = include_str!("upsample_blend.wgsl");
const WORKGROUP: usize = 8;

/// Input planes past the shared ones ([`super::INPUT_PLANES`]): normal x, y, z and the
/// object id (as the f32 the CPU compares, `id as f32`), in units of width x height.
const IN_NX: usize = super::INPUT_PLANES;
const IN_ID: usize = IN_NX + 3;
const INPUT_PLANES: usize = IN_ID + 1;

// Bits of `Params.flags`, declared in upsample.wgsl ([`consts`]).
super::flag_bits! {
    flag_consts: FLAG_HISTORY, FLAG_GEO_DEPTH, FLAG_DEPTH, FLAG_NORMAL, FLAG_IDS, FLAG_MOTION,
    FLAG_INVALID, FLAG_SKY, FLAG_VALIDITY, FLAG_SUB_GRADIENT
}

// The methods as `Params.method`.
const M_SPATIOTEMPORAL: u32 = 0;
const M_SPATIAL: u32 = 1;
const M_TEMPORAL: u32 = 2;
const M_TAA: u32 = 3;

// The counters: holes filled (`temporal`), clipped (`taa`), pixels that lost their history
// in the reprojection.
super::counters! { counter_consts: C_RESET, C_CLIPPED, C_LOST }

super::frame_io::bindings! {
    /// upsample.wgsl's buffers after `P` and `inp`: the history read, the reprojected texels,
    /// the raw gradients, the history written, the colour and the counters.
    BINDINGS: hist: Read, rp: Write, now: Write, next: Write, out: Write, counters: Counters
}

/// Footprint offsets of the largest factor, `(2 x 4 + 1)^2`: the image-space table.
const OFFSETS: usize = 81;
/// Words of `Params` before the table.
const HEADER: usize = 24;
/// Floats of the largest history texel.
const MAX_TEXEL: usize = 13;
const _: () = assert!(MAX_TEXEL >= LK + 4);

/// What upsample's shaders take from Rust: the input planes, the flag bits, methods,
/// history channels and counters above, the workgroup size, and the CPU filter's
/// constants.
fn consts() -> String {
    let [gw0, gw1, gw2, gw3] = GRADIENT_WEIGHTS;
    let flags = flag_consts();
    let methods = super::wgsl_consts![M_SPATIOTEMPORAL, M_SPATIAL, M_TEMPORAL, M_TAA];
    let channels = super::wgsl_consts![R, W, T_DEPTH, T_ID, DEPTH, ID, G1, LK, MAX_TEXEL];
    let counters = counter_consts() + &super::wgsl_consts![WORKGROUP, OFFSETS];
    let cpu = super::wgsl_consts![WEIGHT_EPSILON, LUMA_FLOOR, TAA_MAX_COUNT]
        + &super::wgsl_consts![GW0 = gw0, GW1 = gw1, GW2 = gw2, GW3 = gw3];
    let inputs = input_consts() + &super::wgsl_consts![IN_NX, IN_ID];
    [inputs, flags, methods, channels, counters, cpu].concat()
}

/// The compiled passes.
#[derive(Debug)]
pub(crate) struct Passes {
    reproject: wgpu::ComputePipeline,
    gradient: wgpu::ComputePipeline,
    blend: wgpu::ComputePipeline,
}

/// Device buffers for one frame size, and the bind groups that use them (made once: the
/// history alternates between two).
#[derive(Debug)]
pub(crate) struct Buffers {
    io: FrameIo,
    /// The history: `hist[read]` is the previous frame's, the other is written.
    hist: [StorageBuffer; 2],
    /// `reproject[k]` reads `hist[k]`; `blend[k]` writes `hist[1 - k]`.
    reproject: [wgpu::BindGroup; 2],
    gradient: wgpu::BindGroup,
    blend: [wgpu::BindGroup; 2],
    out: StorageBuffer,
    /// Held for the bind groups: the reprojected texels (with their tap weights) and the
    /// raw gradients, which the passes hand on within a frame.
    _between: [StorageBuffer; 2],
}

/// `upsample` with its history on the device.
pub(crate) type GpuUpsample = DeviceHistory<Params, Passes, Buffers>;

impl FrameBuffers<Params, Passes> for Buffers {
    /// What `upsample` keeps for a frame: its inputs (the shared planes, normals and ids), the
    /// parameters and the image-space table, the counters, and passes reproject, gradient and
    /// blend.
    const SHAPE: IoShape = IoShape::new(
        "upsample",
        INPUT_PLANES,
        HEADER + OFFSETS,
        COUNTERS,
        (3, WORKGROUP),
    );

    fn io(&self) -> &FrameIo {
        &self.io
    }

    fn compile(gpu: &Gpu) -> Passes {
        let consts = consts();
        let make = |label: &str, body: &str, entry: &str| {
            let source = format!(
                "{}{}\n{FRAME}\n{body}",
                BINDINGS.wgsl(),
                include_str!("upsample.wgsl")
            );
            pipeline(gpu, label, &consts, &source, entry)
        };
        Passes {
            reproject: make("upsample reproject", REPROJECT, "reproject_pass"),
            gradient: make("upsample gradient", GRADIENT, "gradient_pass"),
            blend: make("upsample blend", BLEND, "blend_pass"),
        }
    }

    fn make(f: &GpuUpsample, io: FrameIo) -> Result<Self, BackendError> {
        let (gpu, (width, height)) = (&*f.gpu, io.size());
        let n = width * height;
        let (passes, texel) = (&f.passes, f.texel());
        // `spatial` keeps no history: one-float stand-ins for the bindings.
        let history = || StorageBuffer::new(gpu, "upsample history", texel * n);
        let hist = [history()?, history()?];
        let rp = StorageBuffer::new(gpu, "upsample reprojected", (texel + 2) * n)?;
        let now = StorageBuffer::new(gpu, "upsample gradients", n)?;
        let out = StorageBuffer::new(gpu, "upsample colour", 3 * n)?;
        let (r, g, c) = (
            ("rp", &rp.buffer),
            ("now", &now.buffer),
            ("counters", &io.counters),
        );
        let group = |pass, buffers: &[(&str, &wgpu::Buffer)]| BINDINGS.group(gpu, pass, &io, buffers);
        let reproject = [0, 1].map(|k| group(&passes.reproject, &[("hist", &hist[k].buffer), r, c]));
        let gradient = group(&passes.gradient, &[r, g]);
        let blend = [0, 1].map(|k| {
            group(
                &passes.blend,
                &[r, g, ("next", &hist[1 - k].buffer), ("out", &out.buffer), c],
            )
        });
        Ok(Buffers {
            io,
            hist,
            reproject,
            gradient,
            blend,
            out,
            _between: [rp, now],
        })
    }
}

impl GpuUpsample {
    /// Floats of a history texel.
    fn texel(&self) -> usize {
        self.params.method.planes()
    }

    /// The CPU filter's empty state, the layout the device history is saved and loaded in.
    fn empty_history(&self) -> TemporalState {
        Upsample::history(&self.params)
    }

    /// Bytes of the device history.
    fn history_bytes(&self) -> usize {
        match (&self.buffers, self.texel()) {
            (Some(b), t) if t > 0 => b.hist.iter().map(StorageBuffer::bytes).sum(),
            _ => 0,
        }
    }

    /// The history planes as the CPU filter lays them out: one plane of texels.
    fn download_history(&self) -> Result<Vec<Plane<f32>>, BackendError> {
        let b = self.buffers.as_ref().expect("sized");
        let t = self.texel();
        if t == 0 {
            return Ok(Vec::new());
        }
        let words = download(&self.gpu, "upsample history readback", &[&b.hist[self.read]])?;
        let (w, h) = b.io.size();
        Ok(vec![plane(t * w, h, words)?])
    }

    /// Writes `planes` (the CPU filter's layout) into the history read next.
    fn upload_history(&self, planes: &[Plane<f32>]) {
        let b = self.buffers.as_ref().expect("sized");
        if let Some(p) = planes.first() {
            b.hist[self.read].write(&self.gpu, 0, p.data());
        }
    }

    /// The counts of a frame of `pixels` pixels from its `counters`, `has_history` saying
    /// whether the history held the previous frame.
    fn pixel_counts(&self, c: &[u32], has_history: bool, pixels: usize) -> PixelCounts {
        let lost = c[C_LOST] as u64;
        let mut counts = PixelCounts {
            history_reset: c[C_RESET] as u64,
            history_clipped: c[C_CLIPPED] as u64,
            history_rejected: 0,
        };
        match self.params.method {
            Method::Taa => counts.history_reset += lost,
            _ => counts.history_rejected += lost,
        }
        if self.params.method != Method::Spatial && !has_history {
            counts.history_reset += pixels as u64;
        }
        counts
    }

    /// The shader's parameters for a frame with inputs `inp` shaded with `sampling`,
    /// its depth range `range` (`None`: stage `geometry` was left out).
    fn param_words(
        &self,
        inp: &Inputs,
        sampling: Sampling,
        range: Option<f32>,
        has_history: bool,
    ) -> Vec<u32> {
        let p = &self.params;
        let method = p.method;
        let st = method == Method::Spatiotemporal;
        let flags = [
            (has_history, FLAG_HISTORY),
            (range.is_some() && inp.depth.is_some(), FLAG_GEO_DEPTH),
            (inp.depth.is_some(), FLAG_DEPTH),
            (inp.normal.is_some() && method != Method::Taa, FLAG_NORMAL),
            (inp.object_id.is_some(), FLAG_IDS),
            (inp.motion.is_some(), FLAG_MOTION),
            (inp.invalid.is_some(), FLAG_INVALID),
            (p.sky_depth_only, FLAG_SKY),
            (
                matches!(method, Method::Spatiotemporal | Method::Temporal),
                FLAG_VALIDITY,
            ),
            (p.subpixel_keep > 0.0, FLAG_SUB_GRADIENT),
        ]
        .iter()
        .filter(|(on, _)| *on)
        .fold(0, |flags, (_, bit)| flags | bit);
        let (cw, ch) = inp.color[0].size();
        let m = match method {
            Method::Spatiotemporal => M_SPATIOTEMPORAL,
            Method::Spatial => M_SPATIAL,
            Method::Temporal => M_TEMPORAL,
            Method::Taa => M_TAA,
        };
        let only_st = |v: f32| if st { v } else { 0.0 };
        let mut words = vec![
            inp.width as u32,
            inp.height as u32,
            flags,
            m,
            sampling.factor,
            sampling.phase[0],
            sampling.phase[1],
            cw as u32,
            ch as u32,
            self.texel() as u32,
            p.gradient_lag,
            0,
        ];
        words.extend(
            [
                p.kernel_sharp,
                p.kernel_wide,
                1.0 / (p.depth_sigma * range.unwrap_or(1.0)),
                p.normal_sigma,
                p.depth_tolerance,
                only_st(p.neighbour_motion),
                only_st(p.subpixel_keep),
                p.gradient_scale,
                p.gradient_cancel,
                decay_for(p, sampling),
                p.taa_alpha,
                0.0,
            ]
            .map(f32::to_bits),
        );
        debug_assert_eq!(words.len(), HEADER);
        words.extend(image_table(p, sampling).map(f32::to_bits));
        words
    }

    /// Uploads the colour (as f32 or f16, at its own size; planes of the host's own go
    /// back to the scratch), then the G-buffer and the invalid mask as f32, then the
    /// shader's parameter `words`. Returns the bytes written.
    fn upload_frame<'f>(
        &mut self,
        frame: &'f Frame,
        inp: &mut Inputs<'f>,
        words: &[u32],
    ) -> Result<u64, BackendError> {
        let n = inp.width * inp.height;
        let gpu = &self.gpu;
        let io = &mut self.buffers.as_mut().expect("sized").io;
        io.color_len(gpu, inp.color[0].data().len())?;
        let mut bytes = io
            .upload
            .write_frame(gpu, &io.input, frame, inp, &mut self.scratch);
        let io = &*io;
        let mut put = |at: usize, data: &[f32]| bytes += io.input.write(gpu, at * n, data);
        if let Some(m) = inp.motion.as_deref() {
            put(IN_MX, m[0].data());
            put(IN_MX + 1, m[1].data());
        }
        if let Some(d) = inp.depth.as_deref() {
            put(IN_DEPTH, d.data());
        }
        if let Some(nrm) = inp.normal.as_deref() {
            for (k, plane) in nrm.iter().enumerate() {
                put(IN_NX + k, plane.data());
            }
        }
        if let Some(ids) = inp.object_id {
            // As the CPU compares them.
            let ids: Vec<f32> = ids.data().iter().map(|&v| v as f32).collect();
            put(IN_ID, &ids);
        }
        if let Some(invalid) = &inp.invalid {
            let mask: Vec<f32> = invalid.iter().map(|&v| v as u8 as f32).collect();
            put(IN_INVALID, &mask);
        }
        bytes += io.write_params(gpu, words);
        Ok(bytes)
    }

    /// Runs the frame's passes (the colour's unpacking; the reprojection when `reproject`;
    /// the raw gradient when `gradient`; the blend) and submits them with the copies of the
    /// colour, the counters and the timestamps, marking `clock`.
    fn dispatch(&mut self, reproject: bool, gradient: bool, clock: &mut FrameClock) -> Submitted {
        let gpu = &self.gpu;
        let b = self.buffers.as_mut().expect("sized");
        let mut enc = b.io.encoder(gpu);
        let g = b.io.groups();
        let used = b.io.encode_passes(
            &mut enc,
            &[
                (reproject, &self.passes.reproject, &b.reproject[self.read], g),
                (gradient, &self.passes.gradient, &b.gradient, g),
                (true, &self.passes.blend, &b.blend[self.read], g),
            ],
        );
        b.io.submit(gpu, enc, &b.out.buffer, used, clock)
    }
}

history_filter!(GpuUpsample, Upsample);

impl StartFrame for GpuUpsample {
    fn start(&mut self, frame: &Frame) -> Result<Started<Self>, BackendError> {
        check_channels(Upsample::NAME, Upsample::needs(), frame)?;
        let mut rec = Recorder::new();
        let recon = self.params.reconstruction();
        let mut inp = recon.prepare(frame, Upsample::uses(), &mut rec, &mut self.scratch)?;
        let (w, h) = (inp.width, inp.height);
        let method = self.params.method;
        let stateful = method != Method::Spatial;
        let has_history = self.started(frame, &inp)? && stateful;
        let range = geometry(method, &inp, frame.meta.near_far, &mut rec);
        let sampling = frame.sampling();
        let words = self.param_words(&inp, sampling, range, has_history);

        let mut clock = FrameClock::start();
        let bytes = self.upload_frame(frame, &mut inp, &words)?;
        let gradient = method == Method::Spatiotemporal;
        let submitted = self.dispatch(has_history, gradient, &mut clock);
        let (index, input, hdr) = (frame.meta.index, inp.counts, inp.facts.hdr);
        let finish = move |f: &mut Self, back: FrameBack, clock: FrameClock| {
            let device = clock.times(back.shaders_ms(), f.upload, bytes);
            let [reproject_skip, gradient_skip] = skips(method, has_history);
            let stages = vec![
                ("reproject", reproject_skip),
                ("gradient", gradient_skip),
                ("blend", None),
            ];
            let ms = device.shaders_ms.unwrap_or(device.upload_ms + device.readback_ms);
            timing::share(&mut rec, stages, ms);
            let mut color = back.color;
            recon.sparse_output(&mut rec, &mut color, !sampling.is_full(), &mut f.scratch);
            let pixels = f.pixel_counts(&back.counters, has_history, w * h);
            Ok(f.output(Upsample::NAME, index, rec, (pixels, input), device, color))
        };
        Ok(self.submitted(submitted, clock, (stateful, hdr), Box::new(finish)))
    }
}

/// The image-space term per footprint offset (`Params.table`), as the CPU computes it:
/// the distance in block diagonals for `spatiotemporal` (its kernel width varies per
/// pixel), `taa`'s Gaussian of the squared distance, else the falloff at `kernel_wide`.
fn image_table(p: &Params, sampling: Sampling) -> [f32; OFFSETS] {
    let sparse = Sparse::new([&[]; 3], 0, 0, sampling, None);
    let side = 2 * sampling.factor as usize + 1;
    std::array::from_fn(|o| {
        if o >= side * side {
            return 0.0;
        }
        match p.method {
            Method::Spatiotemporal => sparse.dist(o),
            Method::Taa => (-TAA_KERNEL * sparse.dist2(o)).exp(),
            _ => falloff(sparse.dist(o), p.kernel_wide),
        }
    })
}
