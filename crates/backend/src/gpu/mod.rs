//! The wgpu backend (cargo feature `gpu`): filters as WGSL compute shaders, their state
//! kept in device buffers between frames.
//!
//! One device per process ([`shared`]), opened on first use and shared by every GPU filter
//! (a server's sessions included); wgpu's device and queue are thread-safe. Per frame a
//! filter uploads only the channels its plan needs, runs its passes in one submission, and
//! reads back the colour, its counters and its passes' timestamps in one copy (`timing`:
//! the record's device times). Input checks and repair stay on the CPU
//! ([`crate::pipeline::prepare`]), so both backends see the same repaired input and write
//! the same records. Shader sources are `common.wgsl` followed by the filter's own.
//!
//! The colour goes up as f32 or, at the caller's choice ([`UploadPrecision::F16`]), as f16
//! widened on the device (`upload`); motion, depth and the invalid mask always as f32.
//!
//! Filters here: `passthrough`, `fxaa`, `taa`, `traa`, `phlm` (its per-pixel 4x4 solve in
//! f32: [`crate::filters::phlm::rls::update_information_f32`]) and `upsample` (every method
//! and shading factor). Left for later: `pixel_trace`.

mod buffers;
mod frame_io;
mod fxaa;
mod history;
mod passthrough;
mod phlm;
mod submit;
mod taa;
mod timing;
mod traa;
mod upload;
mod upsample;

use super::{AdapterInfo, BackendError};
use crate::frame::Rgb;
use crate::pipeline::params::build;
use crate::pipeline::{
    Backend, DeviceTimes, Filter, InputCounts, Output, PixelCounts, Recorder, UploadPrecision,
};
use serde_json::{Map, Value};
use std::sync::{Arc, OnceLock};

pub(crate) use buffers::{Readback, StorageBuffer};

/// How a device filter is made: on the device, with the parameter values (checked by the
/// registry) and the colour's upload precision.
type Make = fn(Arc<Gpu>, &Map<String, Value>, UploadPrecision) -> Result<Box<dyn Filter>, BackendError>;

/// Every device filter, by name: [`create`] makes them, [`FILTERS`] lists them.
const DEVICE_FILTERS: [(&str, Make); 6] = [
    ("passthrough", |gpu, _, upload| {
        Ok(Box::new(passthrough::GpuPassthrough::new(gpu, upload)))
    }),
    ("fxaa", |gpu, values, upload| {
        Ok(Box::new(fxaa::GpuFxaa::new(gpu, build("fxaa", values)?, upload)))
    }),
    ("taa", |gpu, values, upload| {
        Ok(Box::new(taa::GpuTaa::new(gpu, build("taa", values)?, upload)))
    }),
    ("traa", |gpu, values, upload| {
        Ok(Box::new(traa::GpuTraa::new(gpu, build("traa", values)?, upload)))
    }),
    ("phlm", |gpu, values, upload| {
        Ok(Box::new(phlm::GpuPhlm::new(gpu, build("phlm", values)?, upload)))
    }),
    ("upsample", |gpu, values, upload| {
        Ok(Box::new(upsample::GpuUpsample::new(
            gpu,
            build("upsample", values)?,
            upload,
        )))
    }),
];

/// The names of a table of device filters.
const fn names<const N: usize>(table: &[(&'static str, Make); N]) -> [&'static str; N] {
    let mut out = [""; N];
    let mut i = 0;
    while i < N {
        out[i] = table[i].0;
        i += 1;
    }
    out
}

/// The filters this backend implements (those [`create`] can make).
pub const FILTERS: &[&str] = &names(&DEVICE_FILTERS);

/// An open device: what every GPU filter runs on.
#[derive(Debug)]
pub struct Gpu {
    /// The device.
    pub device: wgpu::Device,
    /// Its queue.
    pub queue: wgpu::Queue,
    /// The adapter it was opened on.
    pub adapter: AdapterInfo,
    /// The pass widening f16 colour to f32 (`upload`), compiled on first use.
    unpack: OnceLock<wgpu::ComputePipeline>,
    /// The filters' frames, submitted together where several are ready at once.
    batcher: submit::Batcher,
}

impl Gpu {
    /// The pass widening f16 colour to f32, compiled on its first use.
    pub(crate) fn unpack(&self) -> &wgpu::ComputePipeline {
        self.unpack.get_or_init(|| upload::unpack_pipeline(self))
    }

    /// Submits a frame's `commands`, in one submission with other filters' frames ready at
    /// the same time ([`submit::Batcher`]).
    pub(crate) fn submit(&self, commands: wgpu::CommandBuffer) -> wgpu::SubmissionIndex {
        self.batcher.submit(&self.queue, commands)
    }
}

fn instance() -> wgpu::Instance {
    wgpu::Instance::new(wgpu::InstanceDescriptor::new_without_display_handle_from_env())
}

fn describe(info: wgpu::AdapterInfo) -> AdapterInfo {
    AdapterInfo {
        name: info.name,
        device_type: format!("{:?}", info.device_type).to_lowercase(),
        api: info.backend.to_str().to_string(),
        driver: format!("{} {}", info.driver, info.driver_info).trim().to_string(),
    }
}

/// Every adapter wgpu finds (the environment's `WGPU_BACKEND` and `WGPU_ADAPTER_NAME`
/// narrow the search, as wgpu documents).
pub fn adapters() -> Vec<AdapterInfo> {
    pollster::block_on(instance().enumerate_adapters(wgpu::Backends::all()))
        .into_iter()
        .map(|a| describe(a.get_info()))
        .collect()
}

fn open() -> Result<Gpu, String> {
    let instance = instance();
    let adapter = pollster::block_on(instance.request_adapter(&wgpu::RequestAdapterOptions {
        power_preference: wgpu::PowerPreference::HighPerformance,
        ..Default::default()
    }))
    .map_err(|e| e.to_string())?;
    // The adapter's own limits: a 4K frame's history (16 B/px) is past the default
    // 128 MiB storage binding.
    // Timestamp queries where the adapter has them: the records' per-pass device times.
    let timestamps = adapter.features() & wgpu::Features::TIMESTAMP_QUERY;
    let (device, queue) = pollster::block_on(adapter.request_device(&wgpu::DeviceDescriptor {
        label: Some("afterimage"),
        required_features: timestamps,
        required_limits: adapter.limits(),
        experimental_features: wgpu::ExperimentalFeatures::disabled(),
        memory_hints: wgpu::MemoryHints::Performance,
        trace: wgpu::Trace::Off,
    }))
    .map_err(|e| e.to_string())?;
    let adapter = describe(adapter.get_info());
    tracing::info!(adapter = %adapter.name, api = %adapter.api, "GPU backend: opened a device");
    Ok(Gpu {
        device,
        queue,
        adapter,
        unpack: OnceLock::new(),
        batcher: submit::Batcher::default(),
    })
}

/// The process's device, opened on first use; every later call gets the same one (or the
/// same error).
pub fn shared() -> Result<Arc<Gpu>, BackendError> {
    static GPU: OnceLock<Result<Arc<Gpu>, String>> = OnceLock::new();
    GPU.get_or_init(|| open().map(Arc::new))
        .clone()
        .map_err(|why| BackendError::NoAdapter { why })
}

/// Filter `name` on the GPU, `values` overriding its defaults (already checked by the
/// registry), its colour uploaded at `upload` precision.
pub fn create(
    name: &'static str,
    values: &Map<String, Value>,
    upload: UploadPrecision,
) -> Result<Box<dyn Filter>, BackendError> {
    let make = DEVICE_FILTERS
        .iter()
        .find(|(n, _)| *n == name)
        .map(|&(_, make)| make)
        .ok_or_else(|| BackendError::FilterNotOnGpu {
            filter: name.to_string(),
            have: FILTERS.join(", "),
        })?;
    make(shared()?, values, upload)
}

/// Waits for the device to finish `submission` and those before it (`None`: all that was
/// submitted); a device error becomes a [`BackendError::Device`].
pub(crate) fn wait(gpu: &Gpu, submission: Option<wgpu::SubmissionIndex>) -> Result<(), BackendError> {
    let until = wgpu::PollType::Wait {
        submission_index: submission,
        timeout: None,
    };
    gpu.device
        .poll(until)
        .map(|_| ())
        .map_err(|e| BackendError::Device(e.to_string()))
}

/// The WGSL every filter's shaders share (colour transforms, numeric helpers).
const COMMON: &str = include_str!("common.wgsl");

/// A value a shader shares with Rust, declared in WGSL from its Rust definition when the
/// module is built ([`wgsl_consts!`]): each flag bit, buffer index and constant of the
/// filters is written once, in Rust.
pub(crate) trait WgslConst {
    /// `const NAME: TYPE = VALUE;` and a newline.
    fn declare(&self, name: &str) -> String;
}

impl WgslConst for u32 {
    fn declare(&self, name: &str) -> String {
        format!("const {name}: u32 = {self}u;\n")
    }
}

impl WgslConst for usize {
    fn declare(&self, name: &str) -> String {
        u32::try_from(*self)
            .expect("a shader constant fits u32")
            .declare(name)
    }
}

impl WgslConst for f32 {
    fn declare(&self, name: &str) -> String {
        // `{:?}` is the shortest decimal that reads back as the same f32 ("1e-8", "255.0");
        // WGSL has no literal for NaN or infinity.
        assert!(self.is_finite(), "the shader constant {name} is {self}");
        format!("const {name}: f32 = {self:?};\n")
    }
}

/// The WGSL declarations of Rust values: `wgsl_consts![A, B = expr]` declares `A` with the
/// value of the Rust item `A` in scope and `B` with that of `expr`.
macro_rules! wgsl_consts {
    ($($name:ident $(= $value:expr)?),* $(,)?) => {
        [$($crate::gpu::wgsl_consts!(@one $name $(= $value)?)),*].concat()
    };
    (@one $name:ident) => {
        $crate::gpu::WgslConst::declare(&$name, stringify!($name))
    };
    (@one $name:ident = $value:expr) => {
        $crate::gpu::WgslConst::declare(&$value, stringify!($name))
    };
}
pub(crate) use wgsl_consts;

/// Declares the bits of a shader's `Params.flags`: each name a `u32` constant of its own
/// bit, in order from 1, and `$consts()` their WGSL declarations ([`wgsl_consts!`]).
macro_rules! flag_bits {
    ($consts:ident: $($name:ident),* $(,)?) => {
        $crate::gpu::flag_bits!(@at 0; $($name),*);

        /// The flag bits as WGSL constants.
        fn $consts() -> String {
            $crate::gpu::wgsl_consts![$($name),*]
        }
    };
    (@at $n:expr; $name:ident $(, $rest:ident)*) => {
        const $name: u32 = 1 << ($n);
        $crate::gpu::flag_bits!(@at $n + 1; $($rest),*);
    };
    (@at $n:expr;) => {};
}
pub(crate) use flag_bits;

/// Declares a shader's counters: each name a `usize` index into its counter words, in
/// order from 0, `COUNTERS` the words (padded to whole 16 bytes), and `$consts()` the WGSL
/// declarations of all of them ([`wgsl_consts!`]).
macro_rules! counters {
    ($consts:ident: $($name:ident),* $(,)?) => {
        $crate::gpu::counters!(@at 0; $($name),*);

        /// Words of the counters, padded to whole 16 bytes.
        const COUNTERS: usize = (0usize $(+ $crate::gpu::counters!(@one $name))*).next_multiple_of(4);

        /// `COUNTERS` and the counters' indices as WGSL constants.
        fn $consts() -> String {
            $crate::gpu::wgsl_consts![COUNTERS $(, $name)*]
        }
    };
    (@one $name:ident) => {
        1
    };
    (@at $n:expr; $name:ident $(, $rest:ident)*) => {
        const $name: usize = $n;
        $crate::gpu::counters!(@at $n + 1; $($rest),*);
    };
    (@at $n:expr;) => {};
}
pub(crate) use counters;

/// The flags whose condition holds, or'ed together.
pub(crate) fn flags_of(set: &[(bool, u32)]) -> u32 {
    set.iter()
        .filter(|(on, _)| *on)
        .fold(0, |flags, (_, bit)| flags | bit)
}

/// Planes of the history filters' (`taa`, `phlm`) input buffer, in units of width x
/// height: r, g, b, motion x and y, depth, the invalid mask.
pub(crate) const INPUT_PLANES: usize = 7;
pub(crate) const IN_R: usize = 0;
pub(crate) const IN_MX: usize = 3;
pub(crate) const IN_MY: usize = 4;
pub(crate) const IN_DEPTH: usize = 5;
pub(crate) const IN_INVALID: usize = 6;
// The host writes the colour from plane 0 and motion y right after motion x.
const _: () = assert!(IN_R == 0 && IN_MY == IN_MX + 1);

/// The input planes as the shaders' `IN_` constants.
pub(crate) fn input_consts() -> String {
    wgsl_consts![IN_R, IN_MX, IN_MY, IN_DEPTH, IN_INVALID]
}

/// What [`COMMON`] takes from Rust: `kernels::color`'s and `kernels::clip`'s constants.
fn common_consts() -> String {
    use crate::kernels::clip::{CLIP_EPS, CLIP_REL};
    use crate::kernels::{LUMA_REC709, TONEMAP_MAX};
    wgsl_consts![
        TONEMAP_MAX,
        F32_MAX = f32::MAX,
        CLIP_EPS,
        CLIP_REL,
        LUMA_R = LUMA_REC709[0],
        LUMA_G = LUMA_REC709[1],
        LUMA_B = LUMA_REC709[2],
    ]
}

/// The history filters' parameters and input planes at bindings 0 and 1, with their
/// pixel indexing (`frame.wgsl`), appended to those filters' shaders that read the frame.
const FRAME: &str = include_str!("frame.wgsl");
/// The working colour of the filters that tonemap HDR input (`working.wgsl`, after
/// [`FRAME`]).
const WORKING: &str = include_str!("working.wgsl");
/// Pixel counts kept per workgroup (`counts.wgsl`), appended to the shaders that count
/// most of their pixels.
const COUNTS: &str = include_str!("counts.wgsl");
/// Velocity dilation and the Catmull-Rom footprint (`reproject.wgsl`), appended by the
/// filters that reproject a history (`taa`'s resolve, `phlm`).
const REPROJECT: &str = include_str!("reproject.wgsl");

/// A compute pipeline from WGSL `source` (after the Rust constants it shares,
/// [`common_consts`] and the filter's `consts` from [`wgsl_consts!`], then [`COMMON`]),
/// entry point `entry`, its bind group layout taken from the shader.
pub(crate) fn pipeline(
    gpu: &Gpu,
    label: &str,
    consts: &str,
    source: &str,
    entry: &str,
) -> wgpu::ComputePipeline {
    let common = common_consts();
    let module = gpu.device.create_shader_module(wgpu::ShaderModuleDescriptor {
        label: Some(label),
        source: wgpu::ShaderSource::Wgsl(format!("{common}{consts}{COMMON}\n{source}").into()),
    });
    gpu.device
        .create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
            label: Some(label),
            layout: None,
            module: &module,
            entry_point: Some(entry),
            compilation_options: Default::default(),
            cache: None,
        })
}

/// A bind group of `pipeline`'s group 0 with `buffers` at bindings 0, 1, ...
pub(crate) fn bind(
    gpu: &Gpu,
    pipeline: &wgpu::ComputePipeline,
    buffers: &[&wgpu::Buffer],
) -> wgpu::BindGroup {
    let at: Vec<(u32, &wgpu::Buffer)> = buffers.iter().enumerate().map(|(i, b)| (i as u32, *b)).collect();
    bind_at(gpu, pipeline, &at)
}

/// A bind group of `pipeline`'s group 0 with each buffer at its binding: the bindings its
/// entry point uses, where a module's entry points share some of their bindings.
pub(crate) fn bind_at(
    gpu: &Gpu,
    pipeline: &wgpu::ComputePipeline,
    buffers: &[(u32, &wgpu::Buffer)],
) -> wgpu::BindGroup {
    let entries: Vec<wgpu::BindGroupEntry> = buffers
        .iter()
        .map(|&(binding, b)| wgpu::BindGroupEntry {
            binding,
            resource: b.as_entire_binding(),
        })
        .collect();
    gpu.device.create_bind_group(&wgpu::BindGroupDescriptor {
        label: None,
        layout: &pipeline.get_bind_group_layout(0),
        entries: &entries,
    })
}

/// The output of a stateless filter's frame on the device: `color`, and `rec` finished
/// (no history to count) as run on the GPU with the `device` times.
pub(crate) fn stateless_output(
    filter: &'static str,
    index: u64,
    rec: Recorder,
    input: InputCounts,
    color: Rgb,
    device: DeviceTimes,
) -> Output {
    let counts = (PixelCounts::default(), input, 0);
    history_output(filter, index, rec, counts, color, device)
}

/// The output of a history filter's frame on the device: `color`, and `rec` finished with
/// the frame's `(pixel counts, input counts, state bytes)` as run on the GPU with the
/// `device` times.
pub(crate) fn history_output(
    filter: &'static str,
    index: u64,
    rec: Recorder,
    (pixels, input, state_bytes): (PixelCounts, InputCounts, usize),
    color: Rgb,
    device: DeviceTimes,
) -> Output {
    let mut record = rec.finish(filter, index, pixels, input, state_bytes);
    record.backend = Backend::Gpu;
    record.device = Some(device);
    Output { color, record }
}

/// The [`Filter`] methods every device filter `$ty` shares: named as the
/// [`FilterKind`](crate::pipeline::FilterKind) `$kind`, its parameters `$params` (with
/// `self` as `$s`), run on the GPU, its frames through its own `run`.
macro_rules! device_filter_methods {
    ($kind:ty, |$s:ident| $params:expr) => {
        fn name(&self) -> &'static str {
            <$kind as $crate::pipeline::FilterKind>::NAME
        }

        fn params(&self) -> serde_json::Value {
            let $s = self;
            serde_json::Value::Object($crate::pipeline::params::to_json($params))
        }

        fn backend(&self) -> $crate::pipeline::Backend {
            $crate::pipeline::Backend::Gpu
        }

        fn process(
            &mut self,
            frame: &$crate::frame::Frame,
        ) -> Result<$crate::pipeline::Output, $crate::pipeline::FilterError> {
            self.run(frame)
                .map_err(|e| e.into_filter_error(<$kind as $crate::pipeline::FilterKind>::NAME))
        }
    };
}
pub(crate) use device_filter_methods;

/// [`Filter`] for a stateless device filter `$ty`: named and checked as the
/// [`FilterKind`](crate::pipeline::FilterKind) `$kind`, its frames through its own `run`,
/// its parameters `$params` (with `self` as `$s`).
macro_rules! stateless_filter {
    ($ty:ty, $kind:ty, |$s:ident| $params:expr) => {
        impl $crate::pipeline::Filter for $ty {
            $crate::gpu::device_filter_methods!($kind, |$s| $params);

            fn reset(&mut self) {}

            fn state_bytes(&self) -> usize {
                0
            }

            fn save_state(&self) -> Result<$crate::pipeline::FilterState, $crate::pipeline::StateError> {
                Ok($crate::pipeline::FilterState::empty(
                    self.name(),
                    self.params(),
                ))
            }

            fn load_state(
                &mut self,
                state: &$crate::pipeline::FilterState,
            ) -> Result<(), $crate::pipeline::StateError> {
                state.check_stateless(self.name(), &self.params())
            }
        }
    };
}
pub(crate) use stateless_filter;

/// [`Filter`] for a device filter `$ty` with history, named and checked as the
/// [`FilterKind`](crate::pipeline::FilterKind) `$kind`: its state is saved and loaded in
/// the CPU filter's layout, so states move between backends. `$ty` has the fields
/// is a [`history::DeviceHistory`] (its `params`, `buffers`, `read`, `valid`, `tonemapped`
/// and `sized`) with the methods `run`, `empty_history` (the CPU filter's empty state),
/// `history_bytes`, `download_history` (the history read next, in the CPU's planes) and
/// `upload_history` (those planes into the history read next). With `texels` the macro
/// writes those four for a history `buffers.hist` ([`buffers::TexelHistory`]) and a
/// `$kind::history(&params)`.
macro_rules! history_filter {
    ($ty:ty, $kind:ty, texels) => {
        impl $ty {
            /// The CPU filter's empty state, the layout the device history is saved and
            /// loaded in.
            fn empty_history(&self) -> $crate::filters::passes::TemporalState {
                <$kind>::history(&self.params)
            }

            /// Bytes of the device history.
            fn history_bytes(&self) -> usize {
                self.buffers.as_ref().map_or(0, |b| b.hist.bytes())
            }

            /// The history read next, in the CPU filter's planes.
            fn download_history(&self) -> Result<Vec<$crate::frame::Plane<f32>>, $crate::BackendError> {
                let b = self.buffers.as_ref().expect("sized");
                b.hist.download(&self.gpu, self.read)
            }

            /// Writes `planes` (the CPU filter's layout) into the history read next.
            fn upload_history(&self, planes: &[$crate::frame::Plane<f32>]) {
                let b = self.buffers.as_ref().expect("sized");
                b.hist.upload(&self.gpu, self.read, planes)
            }
        }
        $crate::gpu::history_filter!($ty, $kind);
    };
    ($ty:ty, $kind:ty) => {
        impl $crate::pipeline::Filter for $ty {
            $crate::gpu::device_filter_methods!($kind, |f| &f.params);

            fn push_overlapped(
                &mut self,
                frame: &$crate::frame::Frame,
            ) -> Result<Vec<$crate::pipeline::Output>, $crate::pipeline::FilterError> {
                let name = <$kind as $crate::pipeline::FilterKind>::NAME;
                self.push_overlapped(frame)
                    .map_err(|e| e.into_filter_error(name))
            }

            fn flush_overlapped(
                &mut self,
            ) -> Result<Vec<$crate::pipeline::Output>, $crate::pipeline::FilterError> {
                let name = <$kind as $crate::pipeline::FilterKind>::NAME;
                self.flush_overlapped()
                    .map_err(|e| e.into_filter_error(name))
            }

            fn reset(&mut self) {
                self.drop_in_flight();
                self.valid = false;
            }

            fn state_bytes(&self) -> usize {
                self.history_bytes()
            }

            fn save_state(&self) -> Result<$crate::pipeline::FilterState, $crate::pipeline::StateError> {
                use $crate::pipeline::StateError;
                if self.in_flight() {
                    return Err(StateError::Unsupported {
                        filter: self.name(),
                        why: "a frame is in flight (push_overlapped); flush_overlapped first",
                    });
                }
                let mut st = self.empty_history();
                if let (Some(b), true) = (&self.buffers, self.valid) {
                    let planes = self
                        .download_history()
                        .map_err(|e| StateError::Device(e.to_string()))?;
                    st.buffer
                        .restore($crate::gpu::history::FrameBuffers::io(b).size(), planes)
                        .map_err(StateError::Device)?;
                }
                st.set_tonemapped(self.tonemapped);
                Ok(st.save(self.name(), self.params()))
            }

            fn load_state(
                &mut self,
                state: &$crate::pipeline::FilterState,
            ) -> Result<(), $crate::pipeline::StateError> {
                let mut st = self.empty_history();
                st.load(state, self.name(), &self.params())?;
                self.drop_in_flight();
                match st.buffer.history_size() {
                    Some((w, h)) => {
                        self.sized(w, h)
                            .map_err(|e| $crate::pipeline::StateError::Device(e.to_string()))?;
                        self.read = 0;
                        self.upload_history(st.buffer.read());
                        self.gpu.queue.submit([]);
                        self.valid = true;
                    }
                    None => self.valid = false,
                }
                self.tonemapped = st.tonemapped();
                Ok(())
            }
        }
    };
}
pub(crate) use history_filter;

/// Workgroups of `size` x `size` covering a `width` x `height` image.
pub(crate) fn groups(width: usize, height: usize, size: usize) -> (u32, u32) {
    (width.div_ceil(size) as u32, height.div_ceil(size) as u32)
}

#[cfg(test)]
mod tests;
