//! Generates the gRPC code from `proto/` with pure-Rust tools (protox parses the .proto
//! files, tonic-prost-build writes the code): no system `protoc` needed.

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let proto = "proto/afterimage/v1/afterimage.proto";
    println!("cargo:rerun-if-changed={proto}");
    let fds = protox::compile([proto], ["proto"])?;
    tonic_prost_build::configure().compile_fds(fds)?;
    Ok(())
}
