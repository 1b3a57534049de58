//! afterimage's core: the frame model ([`frame`]), image I/O ([`io`]), procedural test
//! scenes ([`scene`]), per-pixel kernels ([`kernels`]), the filters ([`filters`]) behind one
//! interface ([`pipeline`]) and quality metrics ([`metrics`]). Nothing here knows of an
//! async runtime, the network or a GPU: the `afterimage-backend`, `afterimage-server` and
//! `afterimage` crates build on it. `docs/ARCHITECTURE.md` maps the layers.

#![forbid(unsafe_code)]
#![warn(missing_docs)]
// Planar kernels index several planes (and rows) with the same `x`; a range loop says that
// more plainly than zipped iterators.
#![allow(clippy::needless_range_loop)]

pub mod echo;
pub mod filters;
pub mod frame;
pub mod io;
pub mod kernels;
pub mod metrics;
pub mod pipeline;
pub mod rng;
pub mod scene;
pub mod tolerance;
