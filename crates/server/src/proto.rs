//! The protocol's code, generated in `afterimage-client` (with its `server` feature).

pub use ::afterimage_client::proto::*;
