//! afterimage: temporal anti-aliasing and deflickering of rendered frames.
//!
//! The library holds the frame model ([`frame`]), image I/O ([`io`]), procedural test
//! scenes ([`scene`]), per-pixel kernels ([`kernels`]), the filters ([`filters`]) behind one
//! interface ([`pipeline`]), quality metrics ([`metrics`]), and where filters run ([`backend`]: the CPU, or wgpu with
//! the `gpu` feature); the binary (`src/main.rs` and its `cli` module) is a thin layer
//! over them.
//! `docs/ARCHITECTURE.md` in the repository maps the layers and the path of a frame.

#![forbid(unsafe_code)]
#![warn(missing_docs)]
// Planar kernels index several planes (and rows) with the same `x`; a range loop says that
// more plainly than zipped iterators.
#![allow(clippy::needless_range_loop)]

pub mod backend;
pub mod echo;
pub mod filters;
pub mod frame;
pub mod io;
pub mod kernels;
pub mod metrics;
pub mod pipeline;
pub mod report;
pub mod rng;
pub mod scene;
pub mod server;
pub mod session;
pub mod tolerance;
