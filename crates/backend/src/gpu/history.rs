//! What the device filters with a history (`taa`, `traa`, `phlm`, `upsample`) keep: one
//! struct, [`DeviceHistory`], that each filter's module instantiates with its parameters,
//! passes and buffers and gives its frames (`impl GpuTaa { fn start ... }`).
//!
//! A frame is started (checked, prepared on the host, uploaded, its passes submitted) and
//! then completed (read back, its record made). [`DeviceHistory::process`] does both before
//! it returns; [`DeviceHistory::push_overlapped`] completes the previous frame after
//! starting this one, so the host's work on one frame and the device's on the other run at
//! the same time.

use super::frame_io::{FrameBack, FrameIo, IoShape, Submitted};
use super::timing::FrameClock;
use super::{Gpu, UploadPrecision};
use crate::filters::reconstruct::Reconstruction;
use crate::frame::{Frame, Rgb};
use crate::pipeline::{
    check_needs, check_size, DeviceTimes, FilterKind, InputCounts, Inputs, Output, PixelCounts, Recorder,
    Scratch,
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

/// What makes a started frame's output once its results are back: the filter's record and
/// counts, from the results and the frame's clock.
pub(crate) type Finish<T> =
    Box<dyn FnOnce(&mut T, FrameBack, FrameClock) -> Result<Output, BackendError> + Send>;

/// A frame submitted to the device and not yet completed.
pub(crate) struct Started<T> {
    submitted: Submitted,
    clock: FrameClock,
    finish: Finish<T>,
    /// The history's bookkeeping before the frame, for a failed readback to go back to.
    before: (usize, bool, bool),
}

impl<T> std::fmt::Debug for Started<T> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Started")
            .field("submitted", &self.submitted)
            .finish_non_exhaustive()
    }
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
    /// The frame [`DeviceHistory::push_overlapped`] started last, not yet completed.
    in_flight: Option<Started<Self>>,
    /// Outputs completed and not yet handed back (a frame size changed under one).
    ready: Vec<Output>,
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
            in_flight: None,
            ready: Vec::new(),
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

    /// A frame's submission: the history it writes is the one read next (when `stateful`),
    /// in the working space of a frame with HDR colour when `hdr`; its output comes from
    /// `finish` once its results are back.
    pub(crate) fn submitted(
        &mut self,
        submitted: Submitted,
        clock: FrameClock,
        (stateful, hdr): (bool, bool),
        finish: Finish<Self>,
    ) -> Started<Self> {
        let before = (self.read, self.valid, self.tonemapped);
        if stateful {
            self.read = 1 - self.read;
            self.valid = true;
        }
        self.tonemapped = hdr;
        Started {
            submitted,
            clock,
            finish,
            before,
        }
    }

    /// Reads back the `started` frame and makes its output. A failed readback leaves the
    /// history as before the frame when `undo` (no later frame was started).
    fn complete(&mut self, started: Started<Self>, undo: bool) -> Result<Output, BackendError> {
        let Started {
            submitted,
            mut clock,
            finish,
            before,
        } = started;
        let io = self.buffers.as_ref().expect("sized").io();
        match io.read(&self.gpu, submitted, &mut self.words, &mut clock) {
            Ok(back) => finish(self, back, clock),
            Err(e) => {
                if undo {
                    (self.read, self.valid, self.tonemapped) = before;
                }
                Err(e)
            }
        }
    }

    /// The output of a frame of filter `name` with frame index `index`: `color`, and `rec`
    /// finished with its pixel and input counts, the history's size and the `device` times.
    pub(crate) fn output(
        &self,
        name: &'static str,
        index: u64,
        rec: Recorder,
        (pixels, input): (PixelCounts, InputCounts),
        device: DeviceTimes,
        color: Rgb,
    ) -> Output
    where
        Self: crate::pipeline::Filter,
    {
        let counts = (pixels, input, crate::pipeline::Filter::state_bytes(self));
        super::history_output(name, index, rec, counts, color, device)
    }

    /// Whether a frame is started and not yet completed (state cannot be saved then).
    pub(crate) fn in_flight(&self) -> bool {
        self.in_flight.is_some()
    }

    /// Forgets a frame in flight and outputs not handed back (a reset or a loaded state).
    pub(crate) fn drop_in_flight(&mut self) {
        self.in_flight = None;
        self.ready.clear();
    }
}

/// A filter's frames, started by its own `start`.
pub(crate) trait StartFrame: Sized {
    /// Checks, prepares, uploads and submits `frame`.
    fn start(&mut self, frame: &Frame) -> Result<Started<Self>, BackendError>;
}

impl<P, S, B: FrameBuffers<P, S>> DeviceHistory<P, S, B>
where
    Self: StartFrame,
{
    /// Filters `frame`, its output back before this returns.
    pub(crate) fn run(&mut self, frame: &Frame) -> Result<Output, BackendError> {
        let started = self.start(frame)?;
        self.complete(started, true)
    }

    /// Starts `frame` and completes the frame started before it: its output (none for the
    /// first frame or the first after a flush). Where the frame size changes, the frame
    /// before is completed first (new buffers drop its readback). On error the outputs
    /// already complete stay for the next call.
    pub(crate) fn push_overlapped(&mut self, frame: &Frame) -> Result<Vec<Output>, BackendError> {
        let size = (frame.width(), frame.height());
        if self.in_flight.is_some() && self.buffers.as_ref().map(|b| b.io().size()) != Some(size) {
            // New buffers would drop the readback the frame in flight waits on.
            let held = self.in_flight.take().expect("checked");
            let out = self.complete(held, false)?;
            self.ready.push(out);
        }
        let started = self.start(frame)?;
        let mut out = std::mem::take(&mut self.ready);
        if let Some(held) = self.in_flight.replace(started) {
            out.push(self.complete(held, false)?);
        }
        Ok(out)
    }

    /// Completes the frame in flight: the outputs not handed back yet, oldest first.
    pub(crate) fn flush_overlapped(&mut self) -> Result<Vec<Output>, BackendError> {
        let mut out = std::mem::take(&mut self.ready);
        if let Some(held) = self.in_flight.take() {
            out.push(self.complete(held, false)?);
        }
        Ok(out)
    }
}
