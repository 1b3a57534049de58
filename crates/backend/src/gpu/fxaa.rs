//! `fxaa` on the GPU (`fxaa.wgsl`): the luma pass and the FXAA pass of
//! [`crate::filters::fxaa::reference`], on the colour repaired on the CPU. No history.

use super::frame_io::{FrameIo, IoShape};
use super::timing::FrameClock;
use super::{bind, pipeline, stateless_filter, stateless_output, Gpu, StorageBuffer};
use crate::filters::fxaa::{Fxaa, Params};
use crate::frame::Frame;
use crate::pipeline::{check_needs, prepare, FilterKind, Output, Recorder, UploadPrecision};
use crate::BackendError;
use std::sync::Arc;

const SOURCE: &str = include_str!("fxaa.wgsl");
const WORKGROUP: usize = 8;

/// What `fxaa` keeps for a frame: the colour, 8 parameter words, no counters, and its two
/// passes.
const SHAPE: IoShape = IoShape::new("fxaa", 3, 8, 0, (2, WORKGROUP));

/// Device buffers for one frame size, and the passes' bind groups.
#[derive(Debug)]
struct Buffers {
    io: FrameIo,
    /// Held for the bind groups: the luma the first pass writes and the output.
    _planes: [StorageBuffer; 2],
    out: wgpu::Buffer,
    /// The luma pass's and the FXAA pass's.
    groups: [wgpu::BindGroup; 2],
}

/// `fxaa` on the device.
#[derive(Debug)]
pub struct GpuFxaa {
    gpu: Arc<Gpu>,
    params: Params,
    upload: UploadPrecision,
    luma: wgpu::ComputePipeline,
    fxaa: wgpu::ComputePipeline,
    buffers: Option<Buffers>,
    words: Vec<f32>,
}

impl GpuFxaa {
    /// The filter with parameters `params` on `gpu`, its colour uploaded at `upload`
    /// precision.
    pub fn new(gpu: Arc<Gpu>, params: Params, upload: UploadPrecision) -> Self {
        let consts = super::wgsl_consts![WORKGROUP];
        GpuFxaa {
            upload,
            luma: pipeline(&gpu, "fxaa luma", &consts, SOURCE, "luma_pass"),
            fxaa: pipeline(&gpu, "fxaa", &consts, SOURCE, "fxaa_pass"),
            gpu,
            params,
            buffers: None,
            words: Vec::new(),
        }
    }

    /// The buffers and bind groups for a `width` x `height` frame.
    fn buffers(&self, (width, height): (usize, usize)) -> Result<Buffers, BackendError> {
        let gpu = &self.gpu;
        let io = FrameIo::new(gpu, SHAPE, (width, height), self.upload)?;
        let n = width * height;
        let luma = StorageBuffer::new(gpu, "fxaa luma", n)?;
        let out = StorageBuffer::new(gpu, "fxaa output", 3 * n)?;
        let (p, c, l) = (&io.params, &io.input.buffer, &luma.buffer);
        let groups = [
            bind(gpu, &self.luma, &[p, c, l]),
            bind(gpu, &self.fxaa, &[p, c, l, &out.buffer]),
        ];
        Ok(Buffers {
            out: out.buffer.clone(),
            _planes: [luma, out],
            io,
            groups,
        })
    }

    fn run(&mut self, frame: &Frame) -> Result<Output, BackendError> {
        check_needs(Fxaa::NAME, Fxaa::needs(), frame)?;
        let mut rec = Recorder::new();
        let inp = prepare(frame, Fxaa::uses(), &mut rec)?;
        let (w, h) = (inp.width, inp.height);
        let mut clock = FrameClock::start();
        if self.buffers.as_ref().map(|b| b.io.size()) != Some((w, h)) {
            self.buffers = None;
            self.buffers = Some(self.buffers((w, h))?);
        }
        let gpu = &self.gpu;
        let b = self.buffers.as_mut().expect("just made");
        let mut bytes = b.io.upload.write(gpu, &b.io.input, &inp.color);
        let p = &self.params;
        let param_words = [
            w as u32,
            h as u32,
            inp.facts.hdr as u32,
            0,
            p.subpix.to_bits(),
            p.edge_threshold.to_bits(),
            p.edge_threshold_min.to_bits(),
            0,
        ];
        bytes += b.io.write_params(gpu, &param_words);
        let mut enc = b.io.encoder(gpu);
        let g = b.io.groups();
        let [luma, fxaa] = &b.groups;
        let used = b.io.encode_passes(
            &mut enc,
            &[(true, &self.luma, luma, g), (true, &self.fxaa, fxaa, g)],
        );
        let back =
            b.io.submit_and_read(gpu, enc, (&b.out, used), &mut self.words, &mut clock)?;
        // One pass per stage: each its own device time where there are timestamps, else
        // the frame's round trip shared evenly.
        let device = clock.times(back.shaders_ms(), self.upload, bytes);
        let each = match &back.pass_ms {
            Some(v) => [v[0], v[1]],
            None => [(device.upload_ms + device.readback_ms) / 2.0; 2],
        };
        rec.ran_for("luma", each[0]);
        rec.ran_for("fxaa", each[1]);
        Ok(stateless_output(
            Fxaa::NAME,
            frame.meta.index,
            rec,
            inp.counts,
            back.color,
            device,
        ))
    }
}

stateless_filter!(GpuFxaa, Fxaa, |f| &f.params);
