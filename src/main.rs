//! The `afterimage` command: parses the command line and dispatches to `cli`.
#![forbid(unsafe_code)]

mod cli;

use clap::Parser;

/// A binary built for x86-64-v3 (see `.cargo/config.toml`) stops with a message on a CPU
/// without AVX2 and FMA, before any vector instruction could fault.
fn check_cpu() {
    #[cfg(all(target_arch = "x86_64", target_feature = "avx2", target_feature = "fma"))]
    if !(std::is_x86_feature_detected!("avx2") && std::is_x86_feature_detected!("fma")) {
        eprintln!(
            "error: this afterimage was built for x86-64-v3 (AVX2 and FMA) and this CPU lacks them; \
             build it with RUSTFLAGS=\"-C target-cpu=x86-64\" cargo build --release"
        );
        std::process::exit(2);
    }
}

fn main() {
    check_cpu();
    let args = cli::Cli::parse();
    cli::init_logging(args.log_format);
    if let Err(e) = cli::run(args) {
        eprintln!("error: {e:#}");
        std::process::exit(1);
    }
}
