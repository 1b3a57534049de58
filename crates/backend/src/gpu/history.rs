//! What the device filters with a history (`taa`, `traa`, `phlm`, `upsample`) keep: one
//! struct, [`DeviceHistory`], that each filter's module instantiates with its parameters,
//! passes and buffers and gives its frames (`impl GpuTaa { fn run ... }`).

use super::frame_io::{FrameIo, IoShape};
use super::{Gpu, UploadPrecision};
use crate::filters::reconstruct::Reconstruction;
use crate::frame::{Frame, Rgb};
use crate::pipeline::{
    check_needs, check_size, DeviceTimes, FilterKind, Inputs, Output, PixelCounts, Recorder, Scratch,
};
use crate::BackendError;
use std::sync::Arc;

/// A filter's device buffers for one frame size.
pub(crate) trait FrameBuffers<P, S>: Sized {
    /// What their [`FrameIo`] holds.
    const SHAPE: IoShape;

    /// Their way in and out, which holds the frame size.
    fn io(&self) -> &FrameIo;

    /// The filter's passes, compiled.
    fn compile(gpu: &Gpu) -> S;

    /// New buffers of `filter` around `io`, made for the frame's size.
    fn make(filter: &DeviceHistory<P, S, Self>, io: FrameIo) -> Result<Self, BackendError>;
}

/// A device filter with a history: its device, parameters `P`, compiled passes `S` and
/// buffers `B` for the frame size, and what it keeps from frame to frame.
#[derive(Debug)]
pub struct DeviceHistory<P, S, B> {
    pub(crate) gpu: Arc<Gpu>,
    pub(crate) params: P,
    /// The precision of the colour's upload.
    pub(crate) upload: UploadPrecision,
    pub(crate) passes: S,
    pub(crate) buffers: Option<B>,
    /// Which of the double-buffered histories holds the previous frame.
    pub(crate) read: usize,
    /// Whether it does (not on the first frame or after a reset).
    pub(crate) valid: bool,
    /// Whether its colour is tonemapped.
    pub(crate) tonemapped: bool,
    /// Readback staging, reused.
    pub(crate) words: Vec<f32>,
    /// Planes of the host's `reconstruct` stage, reused from frame to frame.
    pub(crate) scratch: Scratch,
}

impl<P, S, B: FrameBuffers<P, S>> DeviceHistory<P, S, B> {
    /// The filter with parameters `params` on `gpu`, its colour uploaded at `upload`
    /// precision.
    pub fn new(gpu: Arc<Gpu>, params: P, upload: UploadPrecision) -> Self {
        let passes = B::compile(&gpu);
        DeviceHistory {
            gpu,
            params,
            upload,
            passes,
            buffers: None,
            read: 0,
            valid: false,
            tonemapped: false,
            words: Vec::new(),
            scratch: Scratch::default(),
        }
    }

    /// The buffers for a `width` x `height` frame (new ones drop the history).
    pub(crate) fn sized(&mut self, width: usize, height: usize) -> Result<(), BackendError> {
        if self.buffers.as_ref().map(|b| b.io().size()) != Some((width, height)) {
            // Dropped first: the old buffers and the new never take the device's memory
            // together.
            self.buffers = None;
            self.valid = false;
            self.read = 0;
            let io = FrameIo::new(&self.gpu, B::SHAPE, (width, height), self.upload)?;
            self.buffers = Some(B::make(self, io)?);
        }
        Ok(())
    }

    /// The way in and out of the buffers made for this frame ([`DeviceHistory::started`]).
    pub(crate) fn io(&self) -> &FrameIo {
        self.buffers.as_ref().expect("sized").io()
    }

    /// The inputs of a frame of filter `K`: checked, repaired and reconstructed by `recon`
    /// on the CPU before the upload, so the GPU filters the same colour.
    pub(crate) fn prepared<'f, K: FilterKind>(
        &mut self,
        frame: &'f Frame,
        recon: Reconstruction,
        rec: &mut Recorder,
    ) -> Result<Inputs<'f>, BackendError> {
        check_needs(K::NAME, K::needs(), frame)?;
        Ok(recon.prepare(frame, K::uses(), rec, &mut self.scratch)?)
    }

    /// A frame's start: `frame` checked against the history's size, the buffers for its
    /// `inp`; whether the history holds the previous frame.
    pub(crate) fn started(&mut self, frame: &Frame, inp: &Inputs) -> Result<bool, BackendError> {
        check_size(self.buffers.as_ref().map(|b| b.io().size()), self.valid, frame)?;
        self.sized(inp.width, inp.height)?;
        Ok(self.valid && !frame.meta.reset)
    }

    /// A frame's end: the history just written is read next, in the working space of
    /// `inp`; the output is `color` and `rec` finished as filter `name` run on the GPU,
    /// with `pixels`, the history's `state_bytes` and the `device` times.
    #[allow(clippy::too_many_arguments)]
    pub(crate) fn finished(
        &mut self,
        name: &'static str,
        frame: &Frame,
        inp: &Inputs,
        rec: Recorder,
        (pixels, state_bytes): (PixelCounts, usize),
        device: DeviceTimes,
        color: Rgb,
    ) -> Output {
        self.read = 1 - self.read;
        self.valid = true;
        self.tonemapped = inp.facts.hdr;
        let counts = (pixels, inp.counts, state_bytes);
        super::history_output(name, frame, rec, counts, color, device)
    }
}
