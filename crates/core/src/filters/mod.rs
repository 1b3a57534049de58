//! The filters, one module each; every module holds its filter's whole logic: parameters
//! (with their sources and tradeoffs), state, stages, and tests.
//!
//! | name | what |
//! |---|---|
//! | `passthrough` | the input, repaired (the no-AA baseline) |
//! | `fxaa` | FXAA 3.11, quality preset 12 (Lottes 2011): spatial only |
//! | `taa` | industry TAA (Karis 2014, Salvi 2016): dilation, Catmull-Rom, YCoCg variance clip |
//! | `traa` | the thesis's TRAA (Oliveros 2018): INSIDE/Uncharted 4 baseline or the improved variant |
//! | `phlm` | Pixel History Linear Models (Iglesias-Guitian et al. 2016): per-pixel RLS models, bounded forgetting |
//! | `pixel_trace` | Shinya's pixel-tracing filter (Shinya 1993): a window of frames along motion paths, offline |
//! | `upsample` | Herzog et al.'s spatio-temporal upsampling (Herzog et al. 2010) of sparse shading, and its baselines |

/// Test support (the `check` feature, which the other crates' tests turn on).
#[cfg(any(test, feature = "check"))]
#[allow(missing_docs)]
pub mod check;
pub mod fxaa;
pub mod passes;
pub mod passthrough;
pub mod phlm;
pub mod pixel_trace;
pub mod reconstruct;
mod registry;
pub mod taa;
pub mod traa;
pub mod upsample;

pub use registry::{create, create_sized, info, list, registry};
