//! Where a filter runs: the CPU filters of [`crate::filters`] (rayon; the reference) or,
//! with the `gpu` cargo feature, the wgpu backend ([`gpu`]).
//!
//! The seam is the [`Filter`] interface itself: a GPU filter is one more implementation of
//! it, so records, metrics, sessions, the CLI and the server work the same with either and
//! only say which one ran ([`FrameRecord::backend`](crate::pipeline::FrameRecord)). What
//! both backends share is everything before and after the filter's own arithmetic: input
//! checks and repair ([`crate::pipeline::prepare`]), the stage plan (e.g.
//! [`crate::filters::taa::StagePlan`]: which stages run and why the others are left out),
//! parameters, and the saved-state format. The CPU filter is the reference the GPU one is
//! tested against.
//!
//! Choosing: [`BackendChoice::Cpu`] always works; [`BackendChoice::Gpu`] fails with a
//! precise [`BackendError`] when the build has no GPU backend, the machine no adapter, or
//! the filter (or one of its parameter values) no GPU implementation; [`BackendChoice::Auto`]
//! takes the GPU when all three are there, else the CPU, and says which it took.
//! [`BackendChoice::GpuF16`] and [`BackendChoice::AutoF16`] are the same with the colour
//! uploaded as f16 ([`UploadPrecision::F16`]: half its bytes, rounded to 11 significant
//! bits). The precision rides on the backend's name (`gpu-f16`) rather than a separate
//! option because the choice already flows everywhere a filter is made (the CLI's
//! `--backend`, a report's `NAME@BACKEND`, a session's `backend`, the server's
//! `default_backend`), and the precision means nothing without the GPU.

#![forbid(unsafe_code)]
#![warn(missing_docs)]

#[cfg(feature = "gpu")]
pub mod gpu;

// The core's modules, under the names the modules here use.
#[allow(unused_imports)]
use afterimage_core::{filters, frame, io, kernels, pipeline, rng, scene, tolerance};

use crate::pipeline::{Filter, FilterError};
use serde::{Deserialize, Serialize};
use serde_json::{Map, Value};
use thiserror::Error;

pub use crate::pipeline::{Backend, UploadPrecision};

/// The backend a caller asks for.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum BackendChoice {
    /// The CPU filters.
    #[default]
    Cpu,
    /// The GPU backend; an error where there is none.
    Gpu,
    /// The GPU where the build, the machine and the filter allow it, else the CPU.
    Auto,
    /// [`BackendChoice::Gpu`] with the colour uploaded as f16.
    #[serde(rename = "gpu-f16")]
    GpuF16,
    /// [`BackendChoice::Auto`] with the colour uploaded as f16 where it takes the GPU.
    #[serde(rename = "auto-f16")]
    AutoF16,
}

impl BackendChoice {
    /// Every choice (the tests go through them all; the CLI's help texts list the same
    /// names, written out).
    pub const ALL: [BackendChoice; 5] = [
        BackendChoice::Cpu,
        BackendChoice::Gpu,
        BackendChoice::Auto,
        BackendChoice::GpuF16,
        BackendChoice::AutoF16,
    ];

    /// The precision of the colour upload where the choice takes the GPU.
    pub fn upload(self) -> UploadPrecision {
        match self {
            BackendChoice::GpuF16 | BackendChoice::AutoF16 => UploadPrecision::F16,
            _ => UploadPrecision::F32,
        }
    }

    /// Whether the choice insists on the GPU (an error where there is none).
    pub fn requires_gpu(self) -> bool {
        matches!(self, BackendChoice::Gpu | BackendChoice::GpuF16)
    }
}

impl std::str::FromStr for BackendChoice {
    type Err = BackendError;
    /// The choice whose name (as `Display` writes it) is `s`.
    fn from_str(s: &str) -> Result<Self, BackendError> {
        let unknown = || BackendError::UnknownChoice { got: s.to_string() };
        Self::ALL
            .into_iter()
            .find(|c| c.to_string() == s)
            .ok_or_else(unknown)
    }
}

impl std::fmt::Display for BackendChoice {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            BackendChoice::Cpu => "cpu",
            BackendChoice::Gpu => "gpu",
            BackendChoice::Auto => "auto",
            BackendChoice::GpuF16 => "gpu-f16",
            BackendChoice::AutoF16 => "auto-f16",
        })
    }
}

/// Why a filter could not be had on the backend asked for.
#[derive(Debug, Error, Clone, PartialEq)]
pub enum BackendError {
    /// A choice other than cpu, gpu, auto, gpu-f16 or auto-f16.
    #[error("unknown backend {got:?}; expected cpu, gpu or auto (or gpu-f16, auto-f16: the GPU with the colour uploaded as f16)")]
    UnknownChoice {
        /// The text given.
        got: String,
    },
    /// This build has no GPU backend.
    #[error(
        "this build of afterimage has no GPU backend: rebuild with `--features gpu`, or use --backend cpu"
    )]
    NotBuilt,
    /// The GPU backend found no usable adapter.
    #[error("no GPU adapter: {why} (on a machine without a GPU, Mesa's software Vulkan driver, Debian's mesa-vulkan-drivers, provides one)")]
    NoAdapter {
        /// What wgpu said.
        why: String,
    },
    /// The filter has no GPU implementation.
    #[error(
        "filter {filter} has no GPU implementation (the GPU backend has: {have}); use --backend cpu or auto"
    )]
    FilterNotOnGpu {
        /// The filter.
        filter: String,
        /// The filters the GPU backend has.
        have: String,
    },
    /// One of the filter's parameter values has no GPU implementation.
    #[error(
        "filter {filter} on the GPU does not implement {param} = {value} ({why}); use --backend cpu or auto"
    )]
    ParamNotOnGpu {
        /// The filter.
        filter: &'static str,
        /// The parameter.
        param: &'static str,
        /// Its value.
        value: String,
        /// What is missing.
        why: &'static str,
    },
    /// A buffer the filter needs for this frame size is past what the device can bind.
    #[error(
        "{what} needs a {bytes}-byte GPU buffer, past this device's {limit}-byte limit on a shader's buffer: use smaller frames, or --backend cpu"
    )]
    TooLarge {
        /// The buffer (filter and contents).
        what: String,
        /// Its size.
        bytes: u64,
        /// The device's limit (the smaller of the largest buffer and the largest storage
        /// binding).
        limit: u64,
    },
    /// The device failed (lost, out of memory, a shader the driver refused).
    #[error("GPU device error: {0}")]
    Device(String),
    /// The filter or its parameters are wrong whatever the backend.
    #[error(transparent)]
    Filter(#[from] FilterError),
}

impl BackendError {
    /// Whether the caller asked for something wrong (as opposed to the machine lacking it).
    pub fn is_callers(&self) -> bool {
        matches!(self, BackendError::UnknownChoice { .. } | BackendError::Filter(_))
    }

    /// The error as a running filter reports it: the caller's errors as they are, the
    /// device's as [`FilterError::Device`] (and logged).
    pub fn into_filter_error(self, filter: &'static str) -> FilterError {
        match self {
            BackendError::Filter(e) => e,
            other => {
                tracing::error!(filter, error = %other, "GPU filter failed");
                FilterError::Device {
                    backend: Backend::Gpu,
                    message: other.to_string(),
                }
            }
        }
    }
}

/// One GPU adapter the backend can see.
#[derive(Clone, Debug, PartialEq, Eq, Serialize)]
pub struct AdapterInfo {
    /// The adapter's name (e.g. "llvmpipe (LLVM 15.0.6, 256 bits)").
    pub name: String,
    /// Its kind: discrete, integrated, virtual, cpu or other.
    pub device_type: String,
    /// The graphics API it runs on (vulkan, metal, dx12).
    pub api: String,
    /// The driver and its version, as the driver gives them.
    pub driver: String,
}

/// A filter made on a backend.
pub struct Created {
    /// The filter.
    pub filter: Box<dyn Filter>,
    /// Bytes of state per pixel it will hold (what a server reserves for it).
    pub state_bytes_per_pixel: usize,
    /// Where it runs.
    pub backend: Backend,
    /// The precision its colour goes up in (on the GPU; `None` on the CPU).
    pub upload: Option<UploadPrecision>,
}

impl std::fmt::Debug for Created {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Created")
            .field("filter", &self.filter.name())
            .field("state_bytes_per_pixel", &self.state_bytes_per_pixel)
            .field("backend", &self.backend)
            .field("upload", &self.upload)
            .finish()
    }
}

/// Whether this build has the GPU backend.
pub const GPU_BUILT: bool = cfg!(feature = "gpu");

/// The filters the GPU backend implements (empty without the `gpu` feature).
pub fn gpu_filters() -> &'static [&'static str] {
    #[cfg(feature = "gpu")]
    {
        gpu::FILTERS
    }
    #[cfg(not(feature = "gpu"))]
    {
        &[]
    }
}

/// The GPU adapters this build can use (none without the `gpu` feature).
pub fn adapters() -> Vec<AdapterInfo> {
    #[cfg(feature = "gpu")]
    {
        gpu::adapters()
    }
    #[cfg(not(feature = "gpu"))]
    {
        Vec::new()
    }
}

/// Filter `name` with `values` overriding its defaults, on the backend `choice` picks.
/// Parameters are checked first, so a bad one is the same error on every backend.
pub fn create(
    name: &str,
    values: &Map<String, Value>,
    choice: BackendChoice,
) -> Result<Created, BackendError> {
    let (cpu, bytes) = filters::create_sized(name, values)?;
    let on_cpu = |filter| Created {
        filter,
        state_bytes_per_pixel: bytes,
        backend: Backend::Cpu,
        upload: None,
    };
    let upload = choice.upload();
    match choice {
        BackendChoice::Cpu => Ok(on_cpu(cpu)),
        BackendChoice::Gpu | BackendChoice::GpuF16 => create_gpu(cpu.name(), values, bytes, upload),
        BackendChoice::Auto | BackendChoice::AutoF16 => match create_gpu(cpu.name(), values, bytes, upload) {
            Ok(made) => {
                tracing::info!(filter = name, "backend auto: took the GPU");
                Ok(made)
            }
            Err(why) => {
                tracing::info!(filter = name, %why, "backend auto: took the CPU");
                Ok(on_cpu(cpu))
            }
        },
    }
}

/// The GPU filter `name` with `values` (`bytes` of state per pixel), its colour uploaded at
/// `upload`; [`BackendError::NotBuilt`] in a build without the `gpu` feature.
fn create_gpu(
    name: &'static str,
    values: &Map<String, Value>,
    bytes: usize,
    upload: UploadPrecision,
) -> Result<Created, BackendError> {
    #[cfg(feature = "gpu")]
    {
        Ok(Created {
            filter: gpu::create(name, values, upload)?,
            state_bytes_per_pixel: bytes,
            backend: Backend::Gpu,
            upload: Some(upload),
        })
    }
    #[cfg(not(feature = "gpu"))]
    {
        let _ = (name, values, bytes, upload);
        Err(BackendError::NotBuilt)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::filters::check::sequences;

    #[test]
    fn choices_parse_and_print() {
        for c in BackendChoice::ALL {
            assert_eq!(c.to_string().parse::<BackendChoice>().unwrap(), c);
            // The config file's spelling (serde) is the command line's.
            let json = serde_json::to_value(c).unwrap();
            assert_eq!(json, Value::from(c.to_string()));
            assert_eq!(serde_json::from_value::<BackendChoice>(json).unwrap(), c);
        }
        assert_eq!(BackendChoice::GpuF16.upload(), UploadPrecision::F16);
        assert_eq!(BackendChoice::AutoF16.upload(), UploadPrecision::F16);
        assert_eq!(BackendChoice::Gpu.upload(), UploadPrecision::F32);
        assert!(BackendChoice::GpuF16.requires_gpu() && !BackendChoice::AutoF16.requires_gpu());
        let e = "cuda".parse::<BackendChoice>().unwrap_err().to_string();
        assert!(e.contains("\"cuda\"") && e.contains("cpu, gpu or auto"), "{e}");
    }

    /// The CPU choice gives the registry's filter, bit for bit, and says so in its records;
    /// a bad parameter is the same error whatever the choice.
    #[test]
    fn cpu_is_the_registry_filter_and_errors_do_not_depend_on_the_backend() {
        let frames = &sequences(11, 7, 3, 5)[1].1;
        let mut a = create("taa", &Map::new(), BackendChoice::Cpu).unwrap();
        assert_eq!(a.backend, Backend::Cpu);
        let mut b = filters::create("taa", &Map::new()).unwrap();
        for f in frames {
            let (x, y) = (a.filter.process(f).unwrap(), b.process(f).unwrap());
            assert_eq!(x.color, y.color);
            assert_eq!(x.record.backend, Backend::Cpu);
        }
        let mut bad = Map::new();
        bad.insert("alpha".into(), Value::from(7.0));
        for c in BackendChoice::ALL {
            let e = create("taa", &bad, c).unwrap_err();
            assert!(
                matches!(e, BackendError::Filter(FilterError::BadParam { .. })),
                "{c}: {e}"
            );
        }
        let e = create("nope", &Map::new(), BackendChoice::Gpu).unwrap_err();
        assert!(
            matches!(e, BackendError::Filter(FilterError::UnknownFilter { .. })),
            "{e}"
        );
    }

    /// Without the GPU backend, `gpu` is a clear error and `auto` falls back to the CPU.
    #[cfg(not(feature = "gpu"))]
    #[test]
    fn without_the_feature_gpu_is_refused_and_auto_takes_the_cpu() {
        for c in [BackendChoice::Gpu, BackendChoice::GpuF16] {
            let e = create("taa", &Map::new(), c).unwrap_err();
            assert_eq!(e, BackendError::NotBuilt);
            assert!(e.to_string().contains("--features gpu"), "{e}");
        }
        for c in [BackendChoice::Auto, BackendChoice::AutoF16] {
            let made = create("taa", &Map::new(), c).unwrap();
            assert_eq!((made.backend, made.upload), (Backend::Cpu, None));
        }
        assert!(adapters().is_empty() && gpu_filters().is_empty());
    }
}
