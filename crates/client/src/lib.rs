//! The afterimage protocol for a program that talks to an afterimage server: the messages
//! and the gRPC client generated from `crates/client/proto/afterimage/v1/afterimage.proto`, and nothing of
//! the filters. `docs/server.md` describes the calls; the server's side of the protocol
//! comes with the `server` feature.
#![forbid(unsafe_code)]

/// Code generated from `crates/client/proto/afterimage/v1/afterimage.proto` by `build.rs`.
#[allow(missing_docs, clippy::all, clippy::pedantic)]
pub mod proto {
    tonic::include_proto!("afterimage.v1");

    /// The encoded `FileDescriptorSet` of the protocol (with its comments), for the
    /// server's reflection service.
    #[cfg(feature = "server")]
    pub const FILE_DESCRIPTOR_SET: &[u8] = tonic::include_file_descriptor_set!("afterimage_descriptor");
}
