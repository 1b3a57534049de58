//! afterimage's service: per-client filter state ([`session`]) and gRPC (tonic) and HTTP
//! (axum) as thin layers over it, plus the wire format, config, metrics and the client used
//! by `afterimage stream`.

#![forbid(unsafe_code)]
#![warn(missing_docs)]

// The layers below, under the names the modules here use.
use afterimage_backend as backend;
use afterimage_core::{echo, filters, frame, io, pipeline};
#[cfg(test)]
use afterimage_core::{rng, scene};

pub mod session;

pub mod activity;
pub mod client;
pub mod config;
pub mod grpc;
pub mod http;
pub mod listener;
pub mod metrics;
pub mod proto;
pub mod run;
pub mod schedule;
pub mod service;
pub mod stream_route;
pub mod wire;

pub use config::Config;

pub use afterimage_client::connect::ROUTE_HEADER;
pub use run::{serve, shutdown_signal, start, Running, ServeError};
pub use service::Service;
