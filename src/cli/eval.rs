//! `afterimage eval --input SEQ --reference SEQ`.

use super::outln;
use super::read_args::ReadArgs;
use afterimage::io::{inferno, write_png_rgb8};
use afterimage::metrics::{luma, ssim, Evaluator, FrameMetrics, SpaceChoice, Summary};
use anyhow::{bail, Context};
use clap::{Args, ValueEnum};
use indicatif::{ProgressBar, ProgressStyle};
use serde::Serialize;
use std::path::PathBuf;

#[derive(Clone, Copy, Debug, ValueEnum)]
enum Space {
    /// Tonemapped when the first reference frame has values above 1, else linear.
    Auto,
    /// Linear, clamped to [0, 1].
    Linear,
    /// c / (1 + c).
    Tonemapped,
}

/// Arguments of `eval`.
#[derive(Args, Debug)]
pub struct EvalArgs {
    /// Frames to measure: a directory, a pattern (frame_%04d.exr), a glob or a file.
    #[arg(short = 'i', long)]
    input: String,
    /// Ground truth, frame for frame (default: the input frames' own `reference` channel).
    #[arg(long)]
    reference: Option<String>,
    /// Space the metrics are computed in.
    #[arg(long, value_enum, default_value = "auto")]
    space: Space,
    /// Print JSON (per-frame figures and summary) instead of a table.
    #[arg(long, conflicts_with = "csv")]
    json: bool,
    /// Print CSV (one row per frame) instead of a table.
    #[arg(long)]
    csv: bool,
    /// Write the SSIM map of this frame (its frame number) as a PNG (bright = similar).
    #[arg(long, value_name = "FRAME", requires = "ssim_map_out")]
    ssim_map: Option<u64>,
    /// Where to write the SSIM map.
    #[arg(long, value_name = "PNG")]
    ssim_map_out: Option<PathBuf>,
    /// Channel-name preset of the reference files (default: detect).
    #[arg(long, default_value = "auto", value_name = "PRESET")]
    reference_preset: String,
    #[command(flatten)]
    read: ReadArgs,
}

#[derive(Serialize)]
struct Report<'a> {
    input: &'a str,
    reference: Option<&'a str>,
    frames: &'a [FrameMetrics],
    summary: Summary,
}

pub fn run(args: EvalArgs) -> anyhow::Result<()> {
    let in_opts = args.read.options()?;
    let (input, reference, ref_opts) = super::read_args::open_with_reference(
        &args.input,
        args.reference.as_deref(),
        &args.reference_preset,
    )?;
    let choice = match args.space {
        Space::Auto => SpaceChoice::Auto,
        Space::Linear => SpaceChoice::Linear,
        Space::Tonemapped => SpaceChoice::Tonemapped,
    };
    let mut eval = Evaluator::new(choice);
    let bar = ProgressBar::new(input.len() as u64).with_style(
        ProgressStyle::with_template("{msg:>10} [{bar:30}] {pos}/{len} frames, {eta} left")?
            .progress_chars("=> "),
    );
    bar.set_message("eval");
    let mut ref_frames = reference.as_ref().map(|r| r.frames(&ref_opts));
    let mut map_written = false;
    for (i, frame) in input.frames(&in_opts).enumerate() {
        let frame = frame?;
        let entry = &input.entries[i];
        let ref_rgb = match ref_frames.as_mut() {
            Some(it) => it.next().expect("same length")?.color().clone(),
            None => frame.reference().cloned().with_context(|| {
                format!(
                    "{}: no --reference given and the frame has no reference channel",
                    entry.path.display()
                )
            })?,
        };
        if ref_rgb[0].size() != (frame.width(), frame.height()) {
            bail!(
                "frame {} ({}) is {}x{} but its reference is {}x{}",
                entry.number,
                entry.path.display(),
                frame.width(),
                frame.height(),
                ref_rgb[0].width(),
                ref_rgb[0].height()
            );
        }
        // A sparsely shaded input is measured as a viewer sees it: each pixel shows the
        // sample of its block.
        let color = frame.color_full();
        eval.push(entry.number, &color, &ref_rgb, frame.meta.reset)?;
        if args.ssim_map == Some(entry.number) {
            let out = args.ssim_map_out.as_ref().expect("clap requires it");
            let space = eval.space().expect("set by push");
            let map = ssim(&luma(&color, space), &luma(&ref_rgb, space), true)?
                .map
                .expect("asked for");
            let bytes = map.data().iter().flat_map(|&v| inferno(v)).collect();
            write_png_rgb8(out, map.width(), map.height(), bytes)?;
            map_written = true;
        }
        bar.inc(1);
    }
    bar.finish_and_clear();
    if let (Some(n), false) = (args.ssim_map, map_written) {
        bail!("--ssim-map {n}: the input has no frame numbered {n}");
    }
    let summary = eval.summary().expect("at least one frame");
    if args.json {
        let report = Report {
            input: &args.input,
            reference: args.reference.as_deref(),
            frames: &eval.frames,
            summary,
        };
        outln!("{}", serde_json::to_string_pretty(&report)?);
    } else if args.csv {
        outln!("frame,mse,rmse,psnr_db,ssim,temporal_mse");
        for f in &eval.frames {
            outln!(
                "{},{},{},{},{},{}",
                f.index,
                f.mse,
                f.rmse,
                f.psnr,
                f.ssim,
                f.temporal_mse.map_or(String::new(), |t| t.to_string())
            );
        }
    } else {
        outln!("| frame | PSNR dB | SSIM   | RMSE     | temporal RMSE |");
        outln!("|------:|--------:|-------:|---------:|--------------:|");
        for f in &eval.frames {
            outln!(
                "| {:>5} | {:>7.3} | {:.4} | {:.6} | {:>13} |",
                f.index,
                f.psnr,
                f.ssim,
                f.rmse,
                f.temporal_mse.map_or("-".into(), |t| format!("{:.6}", t.sqrt()))
            );
        }
        outln!();
        outln!(
            "{} frames, {:?} space: mean PSNR {:.3} dB, mean SSIM {:.4}, tRMSE {}",
            summary.frames,
            summary.space,
            summary.mean_psnr,
            summary.mean_ssim,
            summary
                .trmse
                .map_or("- (one frame)".into(), |t| format!("{t:.6}"))
        );
    }
    Ok(())
}
