//! `afterimage serve`: the gRPC and HTTP servers (see `afterimage::server`).

use afterimage::server::{self, Config};
use anyhow::Context;
use clap::Args;
use std::path::PathBuf;

/// Arguments of `serve`.
#[derive(Args, Debug)]
pub struct ServeArgs {
    /// TOML config file (optional; every field has a default, and `AFTERIMAGE_<FIELD>`
    /// environment variables override both, e.g. AFTERIMAGE_HTTP_ADDR=0.0.0.0:8080).
    #[arg(long)]
    config: Option<PathBuf>,
    /// Print the effective config as TOML and exit.
    #[arg(long)]
    print_config: bool,
    /// The gRPC address to listen on (over the config file and AFTERIMAGE_GRPC_ADDR), e.g.
    /// 0.0.0.0:50051.
    #[arg(long, value_name = "ADDR")]
    grpc_addr: Option<String>,
    /// The HTTP address to listen on (over the config file and AFTERIMAGE_HTTP_ADDR), e.g.
    /// 0.0.0.0:8080.
    #[arg(long, value_name = "ADDR")]
    http_addr: Option<String>,
}

pub fn run(args: ServeArgs) -> anyhow::Result<()> {
    let mut config = Config::load(args.config.as_deref(), std::env::vars())?;
    if let Some(addr) = args.grpc_addr {
        config.grpc_addr = addr;
    }
    if let Some(addr) = args.http_addr {
        config.http_addr = addr;
    }
    config.validate().context("serve --grpc-addr/--http-addr")?;
    if args.print_config {
        super::print_stdout(&toml::to_string(&config)?)?;
        return Ok(());
    }
    let rt = tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()
        .context("starting the async runtime")?;
    rt.block_on(server::serve(config, server::shutdown_signal()))?;
    Ok(())
}
