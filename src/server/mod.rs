//! The service: gRPC (tonic) and HTTP (axum) as thin layers over [`crate::session`], plus
//! the wire format, config, metrics and the client used by `afterimage stream`.

pub mod client;
pub mod config;
pub mod grpc;
pub mod http;
pub mod listener;
pub mod metrics;
pub mod proto;
pub mod run;
pub mod service;
pub mod wire;

pub use config::Config;
pub use run::{serve, shutdown_signal, start, Running, ServeError};
pub use service::Service;
