//! Reaching a server: the address, TLS, the API key and the routing key on every call, and
//! HTTP/2 windows sized for frames.

use crate::proto::afterimage_client::AfterimageClient;
use std::marker::PhantomData;
use tonic::codec::{BufferSettings, Codec};
use tonic::metadata::{Ascii, MetadataValue};
use tonic::service::interceptor::InterceptedService;
use tonic::service::Interceptor;
use tonic::transport::{Certificate, Channel, ClientTlsConfig, Endpoint};
use tonic::Status;
use tonic_prost::{ProstDecoder, ProstEncoder};

/// The routing key of a session: an HTTP header and gRPC metadata entry a client sends,
/// with the same value, on every request of a session (create, frames, get, close). With
/// several replicas behind one address, a proxy hashes on it (nginx `hash
/// $http_x_afterimage_route consistent`, Envoy Gateway's consistent hash on a header) so a
/// session's requests all reach the replica that holds its state. The server itself does
/// not read it; a request that reaches another replica gets "no session" naming that
/// replica (see `deploy/README.md`).
pub const ROUTE_HEADER: &str = "x-afterimage-route";

/// HTTP/2 flow-control window per stream. h2's default (64 KiB) makes a 1 MiB chunk wait
/// for 16 window updates; a few chunks' worth keeps the pipe full on any link.
pub const STREAM_WINDOW_BYTES: u32 = 4 << 20;
/// HTTP/2 flow-control window per connection (several streams share it). On the server it
/// is also the most a gRPC client can make it buffer outside the memory budget (data sent
/// but not read yet while a frame is filtered); 8 MiB keeps loopback at 1.4 GB/s.
pub const CONNECTION_WINDOW_BYTES: u32 = 8 << 20;
/// Largest HTTP/2 frame each side accepts. h2's default (16 KiB) cuts a 1 MiB chunk into 64
/// frames, each a wakeup and a buffer of its own on the receiving side.
pub const MAX_FRAME_BYTES: u32 = 1 << 20;

/// Starting size of the buffer a gRPC message stream is received into (tonic's default
/// is 8 KiB). tonic copies each HTTP/2 frame into it and, when a message does not fit
/// after what it has read, moves the unread bytes to its start; with room for several
/// 1 MiB chunks that move comes once every few chunks instead of with every one.
pub const RECEIVE_BUFFER_BYTES: usize = 8 << 20;

/// The protocol's gRPC codec: prost's, receiving into a buffer of
/// [`RECEIVE_BUFFER_BYTES`] (`build.rs` makes the generated client and server use it).
#[derive(Debug, Clone, Copy)]
pub struct WireCodec<T, U>(PhantomData<(T, U)>);

impl<T, U> Default for WireCodec<T, U> {
    fn default() -> Self {
        WireCodec(PhantomData)
    }
}

impl<T, U> Codec for WireCodec<T, U>
where
    T: prost::Message + Send + 'static,
    U: prost::Message + Default + Send + 'static,
{
    type Encode = T;
    type Decode = U;
    type Encoder = ProstEncoder<T>;
    type Decoder = ProstDecoder<U>;

    fn encoder(&mut self) -> Self::Encoder {
        ProstEncoder::default()
    }

    fn decoder(&mut self) -> Self::Decoder {
        // The second figure is tonic's default yield threshold, which only encoders use.
        ProstDecoder::new(BufferSettings::new(RECEIVE_BUFFER_BYTES, 32 << 10))
    }
}

/// Largest message the client takes or sends (a reply chunk and its framing).
const MAX_MESSAGE_BYTES: usize = 64 << 20;

/// How to reach a server: its API key and, for `https://` addresses, the CA that signed
/// its certificate.
#[derive(Clone, Debug, Default)]
pub struct ConnectOptions {
    /// Sent as `authorization: Bearer KEY` on every call.
    pub api_key: Option<String>,
    /// PEM of the CA (or the self-signed certificate) to trust, for `https://`.
    pub tls_ca: Option<Vec<u8>>,
    /// The name the certificate is for, when it is not the address's host.
    pub tls_domain: Option<String>,
    /// Sent as [`ROUTE_HEADER`] on every call: the key a proxy in front of several
    /// replicas routes the client's session by (printable ASCII).
    pub route: Option<String>,
}

/// Why a client could not connect.
#[derive(Debug, thiserror::Error)]
pub enum ConnectError {
    /// The connection failed.
    #[error(transparent)]
    Transport(#[from] tonic::transport::Error),
    /// The options do not fit the address.
    #[error("{0}")]
    Options(String),
}

/// Adds the API key and the routing key to every call.
#[derive(Clone, Debug, Default)]
pub struct Auth {
    key: Option<MetadataValue<Ascii>>,
    route: Option<MetadataValue<Ascii>>,
}

impl Interceptor for Auth {
    fn call(&mut self, mut req: tonic::Request<()>) -> Result<tonic::Request<()>, Status> {
        if let Some(v) = &self.key {
            req.metadata_mut().insert("authorization", v.clone());
        }
        if let Some(v) = &self.route {
            req.metadata_mut().insert(ROUTE_HEADER, v.clone());
        }
        Ok(req)
    }
}

/// The generated client, with the API key added to every call.
pub type Inner = AfterimageClient<InterceptedService<Channel, Auth>>;

/// Connects to `url` (`http://host:port`, or `https://` with `opts.tls_ca`) and sends
/// `opts.api_key` and `opts.route` with every call.
pub async fn connect(url: String, opts: &ConnectOptions) -> Result<Inner, ConnectError> {
    let tls = url.starts_with("https://");
    let mut endpoint = Endpoint::from_shared(url)?
        .initial_stream_window_size(STREAM_WINDOW_BYTES)
        .initial_connection_window_size(CONNECTION_WINDOW_BYTES)
        .max_frame_size(MAX_FRAME_BYTES)
        .tcp_nodelay(true);
    match (&opts.tls_ca, tls) {
        (Some(ca), true) => {
            let mut config = ClientTlsConfig::new().ca_certificate(Certificate::from_pem(ca));
            if let Some(d) = &opts.tls_domain {
                config = config.domain_name(d.clone());
            }
            endpoint = endpoint.tls_config(config)?;
        }
        (None, true) => {
            return Err(ConnectError::Options(
                "an https:// server needs the CA certificate that signed its certificate (--tls-ca)".into(),
            ))
        }
        (Some(_), false) => {
            return Err(ConnectError::Options(
                "a CA certificate was given for an http:// address; use https://".into(),
            ))
        }
        (None, false) => {}
    }
    let key = opts
        .api_key
        .as_ref()
        .map(|k| {
            MetadataValue::try_from(format!("Bearer {k}"))
                .map_err(|_| ConnectError::Options("the API key is not printable ASCII".into()))
        })
        .transpose()?;
    let route = opts
        .route
        .as_ref()
        .map(|r| {
            MetadataValue::try_from(r.as_str())
                .map_err(|_| ConnectError::Options("the routing key is not printable ASCII".into()))
        })
        .transpose()?;
    let channel = endpoint.connect().await?;
    let inner = AfterimageClient::with_interceptor(channel, Auth { key, route })
        .max_decoding_message_size(MAX_MESSAGE_BYTES)
        .max_encoding_message_size(MAX_MESSAGE_BYTES);
    Ok(inner)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::proto::{FilteredChunk, FrameChunk};
    use tonic::codec::Decoder;

    /// The generated calls go through [`WireCodec`] (`build.rs` names it), whose decoder
    /// starts with room for several chunks.
    #[test]
    fn the_generated_code_receives_into_a_buffer_for_several_chunks() {
        let generated = include_str!(concat!(env!("OUT_DIR"), "/afterimage.v1.rs"));
        assert!(generated.contains("crate::connect::WireCodec::default()"));
        assert!(!generated.contains("ProstCodec"));
        let settings = WireCodec::<FrameChunk, FilteredChunk>::default()
            .decoder()
            .buffer_settings();
        assert!(
            format!("{settings:?}").contains(&format!("buffer_size: {RECEIVE_BUFFER_BYTES},")),
            "{settings:?}"
        );
    }
}
