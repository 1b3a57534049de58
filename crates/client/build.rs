//! Generates the gRPC code from `proto/` with pure-Rust tools (protox parses the .proto
//! files, tonic-prost-build writes the code): no system `protoc` needed. The server's side
//! (the service trait) only with the `server` feature, so a client builds without it.
//! The encoded descriptor set goes to `OUT_DIR/afterimage_descriptor.bin` as well: the
//! server's reflection service (`grpc.reflection.v1`) answers from it.

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let proto = "proto/afterimage/v1/afterimage.proto";
    println!("cargo:rerun-if-changed={proto}");
    let mut compiler = protox::Compiler::new(["proto"])?;
    compiler
        .include_source_info(true)
        .include_imports(true)
        .open_files([proto])?;
    let out = std::path::PathBuf::from(std::env::var_os("OUT_DIR").ok_or("OUT_DIR not set")?);
    std::fs::write(
        out.join("afterimage_descriptor.bin"),
        compiler.encode_file_descriptor_set(),
    )?;
    // `bytes` fields as `bytes::Bytes`: a chunk is a view into the buffer it arrived in, and
    // chunking a frame for sending slices one buffer instead of copying it.
    tonic_prost_build::configure()
        .bytes(".afterimage.v1")
        .codec_path("crate::connect::WireCodec")
        .build_server(std::env::var_os("CARGO_FEATURE_SERVER").is_some())
        .compile_fds(compiler.file_descriptor_set())?;
    Ok(())
}
