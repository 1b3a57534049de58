//! Generates the gRPC code from `proto/` with pure-Rust tools (protox parses the .proto
//! files, tonic-prost-build writes the code): no system `protoc` needed. The server's side
//! (the service trait) only with the `server` feature, so a client builds without it.

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let proto = "proto/afterimage/v1/afterimage.proto";
    println!("cargo:rerun-if-changed={proto}");
    let fds = protox::compile([proto], ["proto"])?;
    // `bytes` fields as `bytes::Bytes`: a chunk is a view into the buffer it arrived in, and
    // chunking a frame for sending slices one buffer instead of copying it.
    tonic_prost_build::configure()
        .bytes(".afterimage.v1")
        .build_server(std::env::var_os("CARGO_FEATURE_SERVER").is_some())
        .compile_fds(fds)?;
    Ok(())
}
