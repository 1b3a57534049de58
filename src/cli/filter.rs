//! `afterimage filter` (run a filter over a sequence) and `afterimage filters` (list them).

use super::outln;
use super::read_args::ReadArgs;
use afterimage::filters;
use afterimage::frame::{Frame, FrameMeta, Rgb};
use afterimage::io::{write_exr, write_png, Compression, ExrLayout, Precision, WriteOptions};
use afterimage::metrics::{Evaluator, SpaceChoice, Timing};
use afterimage::pipeline::{
    params::parse_assignments, summarize_stages, Filter, FrameRecord, Output, ParamKind,
};
use anyhow::Context;
use clap::Args;
use indicatif::{ProgressBar, ProgressStyle};
use serde_json::json;
use std::collections::VecDeque;
use std::path::PathBuf;

/// Arguments of `filter`.
#[derive(Args, Debug)]
pub struct FilterArgs {
    /// The filter (see `afterimage filters`).
    #[arg(long)]
    filter: String,
    /// Set a parameter: --set alpha=0.05 --set variant=baseline. Repeatable.
    #[arg(long = "set", value_name = "KEY=VALUE")]
    set: Vec<String>,
    /// Frames to filter: a directory, a pattern (frame_%04d.exr), a glob or a file.
    #[arg(short = 'i', long)]
    input: String,
    /// Output directory: frame_NNNN.exr (afterimage preset, colour only) and records.json.
    #[arg(short = 'o', long)]
    output: PathBuf,
    /// Ground truth, frame for frame: PSNR, SSIM and tRMSE are printed and recorded
    /// (default: the input frames' own reference channel, when they have one).
    #[arg(long)]
    reference: Option<String>,
    /// Channel-name preset of the reference files.
    #[arg(long, default_value = "auto", value_name = "PRESET")]
    reference_preset: String,
    /// Also write PNG previews (tonemapped c/(1+c) when the input is HDR).
    #[arg(long)]
    png: bool,
    /// Write half floats.
    #[arg(long)]
    f16: bool,
    /// Frame numbers where a new shot starts, comma-separated (--cuts 1001,1050): the filter
    /// drops its history there, as it does for a frame whose file says `afterimage.reset`.
    #[arg(long, value_delimiter = ',', value_name = "FRAME")]
    cuts: Vec<u64>,
    #[command(flatten)]
    read: ReadArgs,
}

/// Arguments of `filters`.
#[derive(Args, Debug)]
pub struct FiltersArgs {
    /// Print JSON instead of text.
    #[arg(long)]
    json: bool,
}

pub fn list(args: FiltersArgs) -> anyhow::Result<()> {
    use std::fmt::Write as _;
    let infos = filters::list();
    let mut text = String::new();
    if args.json {
        text = serde_json::to_string_pretty(&infos)? + "\n";
    }
    for info in infos.iter().filter(|_| !args.json) {
        let names =
            |v: &[afterimage::frame::ChannelKind]| v.iter().map(|c| c.name()).collect::<Vec<_>>().join(", ");
        writeln!(text, "{}: {}", info.name, info.summary)?;
        writeln!(text, "  needs: {}", names(&info.needs))?;
        let optional: Vec<_> = info
            .uses
            .iter()
            .copied()
            .filter(|c| !info.needs.contains(c))
            .collect();
        writeln!(
            text,
            "  uses if present: {}",
            if optional.is_empty() {
                "-".into()
            } else {
                names(&optional)
            }
        )?;
        writeln!(text, "  stages: {}", info.stages.join(" -> "))?;
        writeln!(text, "  state: {} bytes/pixel", info.state_bytes_per_pixel)?;
        for p in info.params {
            let bounds = match p.kind {
                ParamKind::Float { min, max } => format!("{min} ..= {max}"),
                ParamKind::Int { min, max } => format!("{min} ..= {max}"),
                ParamKind::Bool => "true | false".into(),
                ParamKind::Choice { options } => options.join(" | "),
            };
            writeln!(text, "  --set {}={}  [{bounds}]", p.name, info.defaults[p.name])?;
            writeln!(text, "      {}", p.doc)?;
        }
        writeln!(text)?;
    }
    super::print_stdout(&text)
}

/// What the output of a pushed frame needs when it comes out.
struct Pending {
    number: u64,
    meta: FrameMeta,
    reference: Option<Rgb>,
    hdr: bool,
}

pub fn run(args: FilterArgs) -> anyhow::Result<()> {
    let values = parse_assignments(&args.set)?;
    let mut filter = filters::create(&args.filter, &values)?;
    let in_opts = args.read.options()?;
    let (input, reference, ref_opts) = super::read_args::open_with_reference(
        &args.input,
        args.reference.as_deref(),
        &args.reference_preset,
    )?;
    if let Some(missing) = args
        .cuts
        .iter()
        .find(|&&c| !input.entries.iter().any(|e| e.number == c))
    {
        let (first, last) = (input.entries[0].number, input.entries[input.len() - 1].number);
        anyhow::bail!("--cuts {missing}: the input has no frame {missing} (its frames are {first}-{last})");
    }
    std::fs::create_dir_all(&args.output).with_context(|| format!("creating {}", args.output.display()))?;
    let write = WriteOptions {
        precision: if args.f16 { Precision::F16 } else { Precision::F32 },
        compression: Compression::Zip,
        layout: ExrLayout::Afterimage,
    };
    let bar = ProgressBar::new(input.len() as u64).with_style(
        ProgressStyle::with_template("{msg:>10} [{bar:30}] {pos}/{len} frames, {eta} left")?
            .progress_chars("=> "),
    );
    bar.set_message(args.filter.clone());
    let mut eval = Evaluator::new(SpaceChoice::Auto);
    let mut records: Vec<FrameRecord> = Vec::new();
    let mut ref_frames = reference.as_ref().map(|r| r.frames(&ref_opts));
    // A windowed filter returns frame t after frame t + lookahead arrives: what the output
    // of each pushed frame needs waits here until it comes out.
    let mut pending: VecDeque<Pending> = VecDeque::new();
    let mut emit =
        |out: Output, pending: &mut VecDeque<Pending>, filter: &mut dyn Filter| -> anyhow::Result<()> {
            let p = pending.pop_front().expect("one output per frame pushed");
            if let Some(r) = &p.reference {
                eval.push(p.number, &out.color, r, p.meta.reset)
                    .with_context(|| format!("measuring frame {} against its reference", p.number))?;
            }
            let mut result = Frame::new(out.color)?;
            result.meta = p.meta;
            write_exr(
                &args.output.join(format!("frame_{:04}.exr", p.number)),
                &result,
                &write,
            )?;
            if args.png {
                write_png(
                    &args.output.join(format!("frame_{:04}.png", p.number)),
                    result.color(),
                    p.hdr,
                )?;
            }
            records.push(out.record);
            filter.recycle(result.into_color());
            bar.inc(1);
            Ok(())
        };
    for (i, frame) in input.frames(&in_opts).enumerate() {
        let entry = &input.entries[i];
        let mut frame = frame?;
        if args.cuts.contains(&entry.number) {
            frame.meta.reset = true;
        }
        let reference: Option<Rgb> = match ref_frames.as_mut() {
            Some(it) => Some(it.next().expect("same length")?.color().clone()),
            None => frame.reference().cloned(),
        };
        pending.push_back(Pending {
            number: entry.number,
            meta: frame.meta.clone(),
            reference,
            hdr: frame_is_hdr(&frame),
        });
        let outs = filter
            .push(&frame)
            .with_context(|| format!("filtering {}", entry.path.display()))?;
        for out in outs {
            emit(out, &mut pending, filter.as_mut())?;
        }
    }
    for out in filter.finish().context("flushing the filter's window")? {
        emit(out, &mut pending, filter.as_mut())?;
    }
    bar.finish_and_clear();

    let summary = eval.summary();
    let doc = json!({
        "filter": args.filter,
        "params": filter.params(),
        "input": args.input,
        "frames": records,
        "metrics": eval.frames,
        "summary": summary,
    });
    let path = args.output.join("records.json");
    std::fs::write(&path, serde_json::to_string_pretty(&doc)?)
        .with_context(|| format!("writing {}", path.display()))?;

    // Per-stage medians, then quality.
    let totals: Vec<f64> = records.iter().map(|r| r.total_ms).collect();
    outln!(
        "{}: {} frames -> {} (median {:.2} ms/frame)",
        args.filter,
        records.len(),
        args.output.display(),
        Timing::of(&totals).median_ms
    );
    for s in summarize_stages(&records) {
        match s.timing {
            Some(t) => outln!("  {:<16} ran {:>3}x, median {:.3} ms", s.name, s.ran, t.median_ms),
            None => outln!(
                "  {:<16} left out: {}",
                s.name,
                s.first_skip.as_deref().unwrap_or("-")
            ),
        }
    }
    let reset: u64 = records.iter().map(|r| r.pixels.history_reset).sum();
    let clipped: u64 = records.iter().map(|r| r.pixels.history_clipped).sum();
    let non_finite: u64 = records.iter().map(|r| r.input.non_finite).sum();
    outln!("  history: {reset} pixel restarts, {clipped} clipped; non-finite input samples: {non_finite}");
    if let Some(s) = summary {
        outln!(
            "  vs reference ({:?} space): mean PSNR {:.3} dB, mean SSIM {:.4}, tRMSE {}",
            s.space,
            s.mean_psnr,
            s.mean_ssim,
            s.trmse.map_or("- (one frame)".into(), |t| format!("{t:.6}"))
        );
    }
    Ok(())
}

fn frame_is_hdr(f: &Frame) -> bool {
    f.color().iter().any(|p| p.data().iter().any(|&v| v > 1.0))
}
