//! `fxaa` on the GPU (`fxaa.wgsl`): the luma pass and the FXAA pass of
//! [`crate::filters::fxaa::reference`], on the colour repaired on the CPU. No history.

use super::buffers::params_buffer;
use super::timing::{begin, FrameClock, PassTimer};
use super::upload::ColorUpload;
use super::{bind, groups, pipeline, stateless_filter, stateless_output, Gpu, Readback, StorageBuffer};
use crate::filters::fxaa::{Fxaa, Params};
use crate::frame::Frame;
use crate::pipeline::{check_needs, prepare, FilterKind, Output, Recorder, UploadPrecision};
use crate::BackendError;
use std::sync::Arc;

const SOURCE: &str = include_str!("fxaa.wgsl");
const WORKGROUP: usize = 8;

/// Device buffers for one frame size.
#[derive(Debug)]
struct Buffers {
    n: usize,
    color: StorageBuffer,
    /// The colour's way into `color`.
    upload: ColorUpload,
    luma: StorageBuffer,
    out: StorageBuffer,
    /// The two passes' timestamps, where the device has them.
    timer: Option<PassTimer>,
    /// The colour (3 planes), then the timestamps.
    back: Readback,
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

    fn run(&mut self, frame: &Frame) -> Result<Output, BackendError> {
        check_needs(Fxaa::NAME, Fxaa::needs(), frame)?;
        let mut rec = Recorder::new();
        let inp = prepare(frame, Fxaa::uses(), &mut rec)?;
        let (w, h) = (inp.width, inp.height);
        let n = w * h;
        let mut clock = FrameClock::start();
        if self.buffers.as_ref().map(|b| b.n) != Some(n) {
            let gpu = &self.gpu;
            let timer = PassTimer::new(gpu, 2);
            let timer_words = timer.as_ref().map_or(0, PassTimer::words);
            let color = StorageBuffer::new(gpu, "fxaa colour", 3 * n)?;
            self.buffers = Some(Buffers {
                n,
                upload: ColorUpload::new(gpu, self.upload, &color, n)?,
                color,
                luma: StorageBuffer::new(gpu, "fxaa luma", n)?,
                out: StorageBuffer::new(gpu, "fxaa output", 3 * n)?,
                back: Readback::new(gpu, "fxaa readback", 3 * n + timer_words),
                timer,
            });
        }
        let gpu = &self.gpu;
        let b = self.buffers.as_mut().expect("just made");
        let mut bytes = b.upload.write(gpu, &b.color, &inp.color);
        let b = &*b;
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
        let params = params_buffer(gpu, "fxaa params", &param_words);
        bytes += (param_words.len() * 4) as u64;
        let (gx, gy) = groups(w, h, WORKGROUP);
        let mut enc = gpu.device.create_command_encoder(&Default::default());
        b.upload.encode(gpu, &mut enc);
        let timer = b.timer.as_ref();
        for (k, (pipe, buffers)) in [
            (&self.luma, vec![&params, &b.color.buffer, &b.luma.buffer]),
            (
                &self.fxaa,
                vec![&params, &b.color.buffer, &b.luma.buffer, &b.out.buffer],
            ),
        ]
        .into_iter()
        .enumerate()
        {
            let bg = bind(gpu, pipe, &buffers);
            let mut pass = begin(&mut enc, timer, k as u32);
            pass.set_pipeline(pipe);
            pass.set_bind_group(0, &bg, &[]);
            pass.dispatch_workgroups(gx, gy, 1);
        }
        b.back.copy_from(&mut enc, &b.out.buffer, 0, 3 * n);
        if let Some(t) = timer {
            t.resolve(&mut enc, 2, &b.back, 3 * n);
        }
        gpu.queue.submit([enc.finish()]);
        clock.submitted();
        let words = 3 * n + timer.map_or(0, PassTimer::words);
        b.back.read(gpu, words, &mut self.words)?;
        clock.back();
        let color = super::buffers::planes_from(&self.words, w, h)?;
        // One pass per stage: each its own device time where there are timestamps, else
        // the frame's round trip shared evenly.
        let pass_ms = timer.map(|t| t.pass_ms(&self.words[3 * n..], 2));
        let device = clock.times(pass_ms.as_ref().map(|v| v.iter().sum()), self.upload, bytes);
        let each = match &pass_ms {
            Some(v) => [v[0], v[1]],
            None => [(device.upload_ms + device.readback_ms) / 2.0; 2],
        };
        rec.ran_for("luma", each[0]);
        rec.ran_for("fxaa", each[1]);
        Ok(stateless_output(
            Fxaa::NAME,
            frame,
            rec,
            inp.counts,
            color,
            device,
        ))
    }
}

stateless_filter!(GpuFxaa, Fxaa, |f| &f.params);
