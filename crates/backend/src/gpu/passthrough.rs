//! `passthrough` on the GPU: the repaired colour through the device and back. The
//! round trip's floor: what any GPU filter pays for its upload and readback. With f16
//! upload the colour comes back widened (`upload`): rounded to f16, not bit for bit.

use super::frame_io::{FrameIo, IoShape};
use super::timing::FrameClock;
use super::{stateless_filter, stateless_output, Gpu};
use crate::filters::passthrough::{Params, Passthrough};
use crate::frame::Frame;
use crate::pipeline::{check_needs, prepare, FilterKind, Output, Recorder, UploadPrecision};
use crate::BackendError;
use std::sync::Arc;

/// The colour in and out: no parameters, counters or passes.
const SHAPE: IoShape = IoShape::new("passthrough", 3, 0, 0, (0, 1));

/// `passthrough` through the device.
#[derive(Debug)]
pub struct GpuPassthrough {
    gpu: Arc<Gpu>,
    upload: UploadPrecision,
    /// The colour on the device, its upload and its readback, for the last frame size.
    io: Option<FrameIo>,
    words: Vec<f32>,
}

impl GpuPassthrough {
    /// The filter on `gpu`, its colour uploaded at `upload` precision.
    pub fn new(gpu: Arc<Gpu>, upload: UploadPrecision) -> Self {
        GpuPassthrough {
            gpu,
            upload,
            io: None,
            words: Vec::new(),
        }
    }

    fn run(&mut self, frame: &Frame) -> Result<Output, BackendError> {
        check_needs(Passthrough::NAME, Passthrough::needs(), frame)?;
        let mut rec = Recorder::new();
        let inp = prepare(frame, Passthrough::uses(), &mut rec)?;
        let size = (inp.width, inp.height);
        let mut clock = FrameClock::start();
        if self.io.as_ref().map(FrameIo::size) != Some(size) {
            self.io = None;
            self.io = Some(FrameIo::new(&self.gpu, SHAPE, size, self.upload)?);
        }
        let io = self.io.as_mut().expect("just made");
        let bytes = io.upload.write(&self.gpu, &io.input, &inp.color);
        let enc = io.encoder(&self.gpu);
        let colour = io.input.buffer.clone();
        let back = io.submit_and_read(&self.gpu, enc, (&colour, 0), &mut self.words, &mut clock)?;
        // No shader: the copy is the upload and the readback.
        let device = clock.times(None, self.upload, bytes);
        rec.ran_for("copy", device.upload_ms + device.readback_ms);
        Ok(stateless_output(
            Passthrough::NAME,
            frame.meta.index,
            rec,
            inp.counts,
            back.color,
            device,
        ))
    }
}

stateless_filter!(GpuPassthrough, Passthrough, |_f| &Params {});
