//! `passthrough` on the GPU: the repaired colour through the device and back. The
//! round trip's floor: what any GPU filter pays for its upload and readback. With f16
//! upload the colour comes back widened (`upload`): rounded to f16, not bit for bit.

use super::upload::ColorUpload;
use super::{stateless_filter, stateless_output, Gpu, Readback, StorageBuffer};
use crate::filters::passthrough::{Params, Passthrough};
use crate::frame::Frame;
use crate::pipeline::{check_needs, prepare, FilterKind, Output, Recorder, UploadPrecision};
use crate::BackendError;
use std::sync::Arc;

/// `passthrough` through the device.
#[derive(Debug)]
pub struct GpuPassthrough {
    gpu: Arc<Gpu>,
    upload: UploadPrecision,
    /// The colour on the device, its readback and its upload, for the last frame size.
    buffers: Option<(usize, StorageBuffer, Readback, ColorUpload)>,
    words: Vec<f32>,
}

impl GpuPassthrough {
    /// The filter on `gpu`, its colour uploaded at `upload` precision.
    pub fn new(gpu: Arc<Gpu>, upload: UploadPrecision) -> Self {
        GpuPassthrough {
            gpu,
            upload,
            buffers: None,
            words: Vec::new(),
        }
    }

    fn run(&mut self, frame: &Frame) -> Result<Output, BackendError> {
        check_needs(Passthrough::NAME, Passthrough::needs(), frame)?;
        let mut rec = Recorder::new();
        let inp = prepare(frame, Passthrough::uses(), &mut rec)?;
        let (w, h) = (inp.width, inp.height);
        let n = w * h;
        let mut clock = super::timing::FrameClock::start();
        if self.buffers.as_ref().map(|b| b.0) != Some(n) {
            let dev = StorageBuffer::new(&self.gpu, "passthrough colour", 3 * n)?;
            let upload = ColorUpload::new(&self.gpu, self.upload, &dev, n)?;
            self.buffers = Some((
                n,
                dev,
                Readback::new(&self.gpu, "passthrough readback", 3 * n),
                upload,
            ));
        }
        let (_, dev, back, upload) = self.buffers.as_mut().expect("just made");
        let bytes = upload.write(&self.gpu, dev, &inp.color);
        let mut enc = self.gpu.device.create_command_encoder(&Default::default());
        upload.encode(&self.gpu, &mut enc);
        back.copy_from(&mut enc, &dev.buffer, 0, 3 * n);
        self.gpu.queue.submit([enc.finish()]);
        clock.submitted();
        back.read(&self.gpu, 3 * n, &mut self.words)?;
        clock.back();
        let color = super::buffers::planes_from(&self.words, w, h)?;
        // No shader: the copy is the upload and the readback.
        let device = clock.times(None, self.upload, bytes);
        rec.ran_for("copy", device.upload_ms + device.readback_ms);
        Ok(stateless_output(
            Passthrough::NAME,
            frame,
            rec,
            inp.counts,
            color,
            device,
        ))
    }
}

stateless_filter!(GpuPassthrough, Passthrough, |_f| &Params {});
