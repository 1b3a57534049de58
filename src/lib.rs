//! afterimage: temporal anti-aliasing and deflickering of rendered frames.
//!
//! This crate is the `afterimage` command (`src/main.rs` and its `cli` module) and its
//! [`report`]; the rest lives in the workspace's crates and is re-exported here under the
//! names the command, the tests and the benches use: the core (`afterimage-core`: [`frame`],
//! [`io`], [`scene`], [`kernels`], [`filters`], [`pipeline`], [`metrics`]), where filters
//! run (`afterimage-backend`: [`backend`], the CPU or wgpu with the `gpu` feature), and the
//! service (`afterimage-server`: [`session`], [`server`]).
//! `docs/ARCHITECTURE.md` in the repository maps the layers and the path of a frame.

#![forbid(unsafe_code)]
#![warn(missing_docs)]

pub use afterimage_backend as backend;
pub use afterimage_core::{echo, filters, frame, io, kernels, metrics, pipeline, rng, scene, tolerance};
pub use afterimage_server as server;
pub use afterimage_server::session;

pub mod report;
