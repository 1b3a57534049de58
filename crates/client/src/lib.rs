//! The afterimage protocol for a program that talks to an afterimage server, such as a
//! renderer, without the filters: the messages and gRPC client generated from
//! `proto/afterimage/v1/afterimage.proto`, connecting with TLS, an API key and a routing
//! key ([`connect`]), frames as named planes encoded for the wire ([`frame`]), and
//! pipelined streaming with replies in order ([`stream`]), over the socket or a shared
//! memory region on the server's machine ([`shm`]). `docs/server.md` describes the
//! calls; the server's side of the protocol comes with the `server` feature.
//!
//! ```no_run
//! # async fn run() -> Result<(), Box<dyn std::error::Error>> {
//! use afterimage_client::frame::{encode, Channel, Encoding, FrameData};
//! use afterimage_client::proto::{CreateSessionRequest, SampleType, Compression};
//! let mut client = afterimage_client::connect::connect("http://127.0.0.1:50051".into(), &Default::default()).await?;
//! let session = client
//!     .create_session(CreateSessionRequest { filter: "taa".into(), width: 4, height: 2, ..Default::default() })
//!     .await?
//!     .into_inner();
//! let (r, g, b) = (vec![0.5f32; 8], vec![0.5f32; 8], vec![0.5f32; 8]);
//! let planes = [&r[..], &g[..], &b[..]];
//! let frame = FrameData { channels: vec![Channel { name: "color", planes: &planes }], ..Default::default() };
//! let how = Encoding { sample: SampleType::F32, compression: Compression::None, max_chunk: session.max_chunk_bytes as usize };
//! let encoded = encode(&frame, &session.id, how);
//! afterimage_client::stream::stream(&mut client, &session, [encoded], 2, |reply| {
//!     println!("frame {}: {} red samples", reply.index, reply.color[0].len());
//! })
//! .await?;
//! # Ok(()) }
//! ```
#![forbid(unsafe_code)]
#![warn(missing_docs)]

pub mod codec;
pub mod connect;
pub mod frame;
pub mod shm;
pub mod stream;

/// Code generated from `proto/afterimage/v1/afterimage.proto` by `build.rs`.
#[allow(missing_docs, clippy::all, clippy::pedantic)]
pub mod proto {
    tonic::include_proto!("afterimage.v1");

    /// The encoded `FileDescriptorSet` of the protocol (with its comments), for the
    /// server's reflection service.
    #[cfg(feature = "server")]
    pub const FILE_DESCRIPTOR_SET: &[u8] = tonic::include_file_descriptor_set!("afterimage_descriptor");
}
