//! Subcommands of the `afterimage` binary. Thin glue over the library: parse, call,
//! print.

mod batch;
mod eval;
mod filter;
mod info;
mod keygen;
mod read_args;
mod report;
mod scene;
mod serve;
mod shot;
mod store;
mod stream;

use clap::{Parser, Subcommand};

/// Temporal anti-aliasing and deflickering of rendered frames.
#[derive(Parser, Debug)]
#[command(name = "afterimage", version, about, long_about = None)]
pub struct Cli {
    #[command(subcommand)]
    command: Command,
    /// Filter threads (default: `AFTERIMAGE_THREADS`, else one per core).
    #[arg(short = 'j', long, global = true, value_name = "N")]
    threads: Option<usize>,
    /// Log lines on stderr: text (coloured only on a terminal, and never with NO_COLOR set)
    /// or json (one object a line, for log collectors). AFTERIMAGE_LOG sets the level.
    #[arg(
        long,
        global = true,
        default_value = "text",
        env = "AFTERIMAGE_LOG_FORMAT",
        value_name = "text|json"
    )]
    pub log_format: LogFormat,
}

/// How log lines are written (`--log-format`).
#[derive(clap::ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
pub enum LogFormat {
    /// One line of text per event.
    Text,
    /// One JSON object per event.
    Json,
}

/// Starts logging to stderr at the levels `AFTERIMAGE_LOG` gives (default: warnings, and
/// `batch`'s progress lines, target `afterimage::progress`), in `format`, with ANSI colour
/// only where stderr is a terminal and `NO_COLOR` is unset.
pub fn init_logging(format: LogFormat) {
    use std::io::IsTerminal;
    let filter = tracing_subscriber::EnvFilter::try_from_env("AFTERIMAGE_LOG")
        .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("warn,afterimage::progress=info"));
    let builder = tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_writer(std::io::stderr);
    match format {
        LogFormat::Json => builder.json().init(),
        LogFormat::Text => {
            let colour = std::io::stderr().is_terminal() && std::env::var_os("NO_COLOR").is_none();
            builder.with_ansi(colour).init()
        }
    }
}

#[derive(Subcommand, Debug)]
enum Command {
    /// Describe an image file: size, channels, detected preset, value ranges and
    /// non-finite counts.
    Info(info::InfoArgs),
    /// Measure a sequence against a reference: PSNR, SSIM, RMSE per frame and tRMSE.
    Eval(eval::EvalArgs),
    /// Run a filter over a sequence: EXR out, per-frame records, metrics with a reference.
    Filter(filter::FilterArgs),
    /// Filter many shots (a manifest, or -i DIR repeated): resumable, sharded over the
    /// processes of a cluster job, with a summary.
    Batch(batch::BatchArgs),
    /// List the filters: parameters with defaults and bounds, channels, stages, state size.
    Filters(filter::FiltersArgs),
    /// Error against run time: every filter on every scene, with tables, JSON, CSV and
    /// plots.
    Report(report::ReportArgs),
    /// Serve filter sessions over gRPC and HTTP (the main job): `afterimage serve`.
    Serve(serve::ServeArgs),
    /// Stream a sequence or a scene to a running server over gRPC (the remote-renderer
    /// side): filtered frames out, round-trip figures.
    Stream(stream::StreamArgs),
    /// Render a procedural test scene (exact G-buffer, supersampled reference) to EXR.
    Scene(scene::SceneArgs),
    /// Make a new API key for `serve`: prints the secret for the client and the entry for
    /// the server's keys file (which stores only its hash).
    Keygen(keygen::KeygenArgs),
}

/// Runs the parsed command.
pub fn run(cli: Cli) -> anyhow::Result<()> {
    if let Some(n) = cli.threads {
        afterimage::pipeline::exec::set_threads(n)
            .map_err(|have| anyhow::anyhow!("--threads {n}: the filter pool already runs {have} threads"))?;
    }
    match cli.command {
        Command::Info(a) => info::run(a),
        Command::Eval(a) => eval::run(a),
        Command::Scene(a) => scene::run(a),
        Command::Serve(a) => serve::run(a),
        Command::Stream(a) => stream::run(a),
        Command::Report(a) => report::run(a),
        Command::Filter(a) => filter::run(a),
        Command::Batch(a) => batch::run(a),
        Command::Filters(a) => filter::list(a),
        Command::Keygen(a) => keygen::run(a),
    }
}

/// `println!` for results: through [`print_stdout`], so `| head` ends the output quietly;
/// returns from the calling function on any other write error.
macro_rules! outln {
    () => {
        $crate::cli::print_stdout("\n")?
    };
    ($($arg:tt)*) => {
        $crate::cli::print_stdout(&format!("{}\n", format_args!($($arg)*)))?
    };
}
pub(crate) use outln;

/// Writes `text` to stdout; a reader that closes the pipe early (`| head`) is not an error.
pub(crate) fn print_stdout(text: &str) -> anyhow::Result<()> {
    use std::io::Write;
    match std::io::stdout().lock().write_all(text.as_bytes()) {
        Err(e) if e.kind() == std::io::ErrorKind::BrokenPipe => Ok(()),
        r => Ok(r?),
    }
}
