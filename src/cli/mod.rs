//! Subcommands of the `afterimage` binary. Thin glue over the library: parse, call,
//! print.

mod eval;
mod info;
mod read_args;
mod scene;

use clap::{Parser, Subcommand};

/// Temporal anti-aliasing and deflickering of rendered frames.
#[derive(Parser, Debug)]
#[command(name = "afterimage", version, about, long_about = None)]
pub struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand, Debug)]
enum Command {
    /// Describe an image file: size, channels, detected preset, value ranges and
    /// non-finite counts.
    Info(info::InfoArgs),
    /// Measure a sequence against a reference: PSNR, SSIM, RMSE per frame and tRMSE.
    Eval(eval::EvalArgs),
    /// Render a procedural test scene (exact G-buffer, supersampled reference) to EXR.
    Scene(scene::SceneArgs),
}

/// Runs the parsed command.
pub fn run(cli: Cli) -> anyhow::Result<()> {
    match cli.command {
        Command::Info(a) => info::run(a),
        Command::Eval(a) => eval::run(a),
        Command::Scene(a) => scene::run(a),
    }
}
