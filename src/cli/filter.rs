//! `afterimage filter` (run a filter over a sequence) and `afterimage filters` (list them).

use super::outln;
use super::read_args::{ReadArgs, WriteArgs};
use super::shot::run_shot;
use afterimage::filters;
use afterimage::io::Sequence;
use afterimage::metrics::Timing;
use afterimage::pipeline::{missing_channels, summarize_stages, ParamKind};
use afterimage::scene::halton_jitter;
use anyhow::Context;
use clap::Args;
use indicatif::{ProgressBar, ProgressStyle};
use std::collections::BTreeMap;
use std::path::PathBuf;

/// Arguments of `filter`.
#[derive(Args, Debug)]
pub struct FilterArgs {
    /// The filter (see `afterimage filters`).
    #[arg(long)]
    pub(super) filter: String,
    /// Set a parameter: --set alpha=0.05 --set variant=baseline. Repeatable.
    #[arg(long = "set", value_name = "KEY=VALUE")]
    pub(super) set: Vec<String>,
    /// Where the filter runs: cpu, gpu (an error where the build, the machine or the filter
    /// has none; see `afterimage info --backends`), or auto (the GPU where it can, else the CPU);
    /// gpu-f16 and auto-f16 upload the colour to the GPU as f16 (half the bytes, 11
    /// significant bits, clamped to +-65504; see the README's GPU backend section).
    #[arg(long, default_value = "cpu", value_name = "cpu|gpu|auto|gpu-f16|auto-f16")]
    pub(super) backend: afterimage::backend::BackendChoice,
    /// Frames to filter: a directory, a pattern (frame_%04d.exr), a glob or a file.
    #[arg(short = 'i', long)]
    pub(super) input: String,
    /// Frame numbers to filter: FIRST-LAST or FIRST-LAST:STEP (--frames 1001-1100:2), or
    /// one frame (default: every frame of the input).
    #[arg(long, value_name = "A-B[:STEP]")]
    pub(super) frames: Option<afterimage::io::FrameRange>,
    /// A frame number missing from the input (or the --frames range): error (refuse the
    /// sequence), skip (leave it out; history restarts after the gap), hold (filter the
    /// nearest earlier frame again, motion zero, written under the missing number).
    #[arg(long, default_value = "error", value_name = "skip|error|hold")]
    pub(super) missing: afterimage::io::Missing,
    /// Where to write: a directory (each output keeps its input's file name) or a pattern
    /// with the frame number as `####`, `%04d`, `$F4` or `@@@@` (out/shot_aa.####.exr).
    /// records.json goes into the directory.
    #[arg(short = 'o', long, value_name = "DIR|PATTERN")]
    pub(super) output: String,
    /// Where to write the per-frame records (default: records.json in the output directory).
    #[arg(long, value_name = "FILE")]
    pub(super) records: Option<PathBuf>,
    /// Ground truth, frame for frame: PSNR, SSIM and tRMSE are printed and recorded
    /// (default: the input frames' own reference channel, when they have one).
    #[arg(long)]
    pub(super) reference: Option<String>,
    /// Channel-name preset of the reference files.
    #[arg(long, default_value = "auto", value_name = "PRESET")]
    pub(super) reference_preset: String,
    /// Also write PNG previews (tonemapped c/(1+c) when the input is HDR).
    #[arg(long)]
    pub(super) png: bool,
    /// Frame numbers where a new shot starts, comma-separated (--cuts 1001,1050): the filter
    /// drops its history there, as it does for a frame whose file says `afterimage.reset`.
    #[arg(long, value_delimiter = ',', value_name = "FRAME")]
    pub(super) cuts: Vec<u64>,
    /// Each frame's sub-pixel jitter, over what the files say (pixels, x right, y down):
    /// `halton:8` (Halton 2,3 with 8 phases, indexed by frame number modulo 8, as
    /// `afterimage scene` renders), or a file: JSON (`[[x, y], ...]` in frame order, or
    /// `{"1001": [x, y], ...}` by frame number) or CSV lines `frame,x,y`.
    #[arg(long, value_name = "halton:N|FILE")]
    pub(super) jitter_from: Option<String>,
    /// Channels every frame must have, comma-separated (--require motion,depth): a frame
    /// without one is an error, where otherwise the stages that read it are left out (and
    /// the summary and records say so).
    #[arg(long, value_delimiter = ',', value_name = "CHANNEL")]
    pub(super) require: Vec<String>,
    #[command(flatten)]
    pub(super) read: ReadArgs,
    #[command(flatten)]
    pub(super) write: WriteArgs,
    /// Old name of --half.
    #[arg(long, hide = true)]
    pub(super) f16: bool,
    /// S3 endpoint for `s3://` inputs and outputs (an S3-compatible store such as MinIO);
    /// default: AWS_ENDPOINT_URL, else AWS's own.
    #[arg(long, value_name = "URL")]
    pub(super) endpoint: Option<String>,
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

pub fn run(args: FilterArgs) -> anyhow::Result<()> {
    let bar = ProgressBar::new(0).with_style(
        ProgressStyle::with_template("{msg:>10} [{bar:30}] {pos}/{len} frames, {eta} left")?
            .progress_chars("=> "),
    );
    bar.set_message(args.filter.clone());
    super::store::set_endpoint(args.endpoint.clone())?;
    let report = run_shot(&args, &bar, None)?;
    bar.finish_and_clear();
    let records = &report.records;
    // Per-stage medians, then quality.
    let totals: Vec<f64> = records.iter().map(|r| r.total_ms).collect();
    outln!(
        "{}: {} frames -> {} (median {:.2} ms/frame)",
        args.filter,
        records.len(),
        report.output,
        Timing::of(&totals).median_ms
    );
    for s in summarize_stages(records) {
        let why: Vec<String> = s.skips.iter().map(|(w, n)| format!("{w} ({n}x)")).collect();
        match s.timing {
            Some(t) if why.is_empty() => {
                outln!("  {:<16} ran {:>3}x, median {:.3} ms", s.name, s.ran, t.median_ms)
            }
            Some(t) => outln!(
                "  {:<16} ran {:>3}x, median {:.3} ms; left out: {}",
                s.name,
                s.ran,
                t.median_ms,
                why.join(", ")
            ),
            None => outln!("  {:<16} left out: {}", s.name, why.join(", ")),
        }
    }
    let missing = missing_channels(records);
    if !missing.is_empty() {
        let what: Vec<String> = missing
            .iter()
            .map(|(c, n)| format!("{c} on {n} of {} frames", records.len()))
            .collect();
        outln!(
            "  missing channels: {} (--require makes that an error)",
            what.join(", ")
        );
    }
    let reset: u64 = records.iter().map(|r| r.pixels.history_reset).sum();
    let clipped: u64 = records.iter().map(|r| r.pixels.history_clipped).sum();
    let non_finite: u64 = records.iter().map(|r| r.input.non_finite).sum();
    outln!("  history: {reset} pixel restarts, {clipped} clipped; non-finite input samples: {non_finite}");
    if let Some(s) = &report.summary {
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

/// A jitter CSV: records `frame,x,y`, the first of which may be a header, read by the
/// `csv` crate (quoted fields, spaces around fields, a byte-order mark, CRLF line ends and
/// blank lines all read as a spreadsheet writes them). The error names the line.
fn jitter_csv(text: &str) -> Result<BTreeMap<u64, [f32; 2]>, String> {
    let mut reader = csv::ReaderBuilder::new()
        .has_headers(false)
        .flexible(true)
        .trim(csv::Trim::All)
        .from_reader(text.as_bytes());
    let mut table = BTreeMap::new();
    for (n, record) in reader.records().enumerate() {
        let record = record.map_err(|e| e.to_string())?;
        let parsed = match (record.get(0), record.get(1), record.get(2), record.len()) {
            (Some(k), Some(x), Some(y), 3) => k
                .parse::<u64>()
                .ok()
                .zip(x.parse::<f32>().ok().zip(y.parse::<f32>().ok())),
            _ => None,
        };
        match parsed {
            Some((k, (x, y))) => {
                table.insert(k, [x, y]);
            }
            None if n == 0 => {} // a header
            None => {
                // The reader's position is where it began to look for the record, before
                // the blank lines it skipped: count the lines up to the record's first byte.
                let from = record.position().map_or(0, |p| p.byte() as usize).min(text.len());
                let bytes = text.as_bytes();
                let skipped = bytes[from..]
                    .iter()
                    .take_while(|&&b| b == b'\r' || b == b'\n')
                    .count();
                let line = 1 + bytes[..from + skipped].iter().filter(|&&b| b == b'\n').count();
                let fields: Vec<&str> = record.iter().collect();
                return Err(format!("line {line}: expected frame,x,y, got {fields:?}"));
            }
        }
    }
    Ok(table)
}

/// The jitter of every frame of `input` from `--jitter-from` (see [`FilterArgs`]), by
/// frame number; every frame must get one.
pub(super) fn jitter_table(spec: &str, input: &Sequence) -> anyhow::Result<BTreeMap<u64, [f32; 2]>> {
    let numbers: Vec<u64> = input.entries.iter().map(|e| e.number).collect();
    let table: BTreeMap<u64, [f32; 2]> = if let Some(n) = spec.strip_prefix("halton:") {
        let phases: u32 = n
            .parse()
            .ok()
            .filter(|&p| p > 0)
            .with_context(|| format!("--jitter-from {spec}: expected halton:N with N phases > 0"))?;
        numbers.iter().map(|&k| (k, halton_jitter(k, phases))).collect()
    } else {
        let text = std::fs::read_to_string(spec).with_context(|| format!("--jitter-from {spec}"))?;
        let at = |what: String| format!("--jitter-from {spec}: {what}");
        if spec.to_ascii_lowercase().ends_with(".csv") {
            jitter_csv(&text).map_err(|e| anyhow::anyhow!(at(e)))?
        } else {
            match serde_json::from_str::<serde_json::Value>(&text).with_context(|| at("not JSON".into()))? {
                serde_json::Value::Array(v) => {
                    if v.len() != numbers.len() {
                        anyhow::bail!(at(format!("{} jitters for {} frames", v.len(), numbers.len())));
                    }
                    let pairs: Vec<[f32; 2]> = serde_json::from_value(serde_json::Value::Array(v))
                        .with_context(|| at("expected [[x, y], ...]".into()))?;
                    numbers.iter().copied().zip(pairs).collect()
                }
                serde_json::Value::Object(m) => m
                    .into_iter()
                    .map(|(k, v)| {
                        let n = k
                            .parse::<u64>()
                            .with_context(|| at(format!("key {k:?} is not a frame number")))?;
                        let j: [f32; 2] = serde_json::from_value(v)
                            .with_context(|| at(format!("frame {k}: expected [x, y]")))?;
                        Ok((n, j))
                    })
                    .collect::<anyhow::Result<_>>()?,
                _ => anyhow::bail!(at("expected a JSON array or object".into())),
            }
        }
    };
    if let Some(missing) = numbers.iter().find(|n| !table.contains_key(n)) {
        anyhow::bail!("--jitter-from {spec}: no jitter for frame {missing}");
    }
    if let Some((k, j)) = table
        .iter()
        .find(|(_, j)| !afterimage::frame::FrameMeta::jitter_in_range(**j))
    {
        anyhow::bail!("--jitter-from {spec}: frame {k}: jitter {j:?} is not within -1..=1 pixels");
    }
    Ok(table)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// What a spreadsheet writes: a byte-order mark, a header with spaces, quoted fields,
    /// CRLF line ends and a blank line. Splitting lines at ',' took the first frame (behind
    /// the mark) for a header and refused the quoted one.
    #[test]
    fn a_jitter_csv_reads_as_a_spreadsheet_writes_it() {
        let text = "\u{feff}1001, 0.25, -0.125\r\n\r\n\"1002\",\" 0.5\",\"-0.5\"\r\n 1003 ,0,1\r\n";
        let t = jitter_csv(text).unwrap();
        assert_eq!(
            t.into_iter().collect::<Vec<_>>(),
            [(1001, [0.25, -0.125]), (1002, [0.5, -0.5]), (1003, [0.0, 1.0])]
        );
        let t = jitter_csv("frame, x, y\n1001,0.25,0.75\n").unwrap();
        assert_eq!(t.into_iter().collect::<Vec<_>>(), [(1001, [0.25, 0.75])]);
        // Only the first record may be a header; a bad one later is named by its line.
        let e = jitter_csv("frame,x,y\n1001,0.25,0.75\n\n1002,0.25\n").unwrap_err();
        assert!(
            e.starts_with("line 4: expected frame,x,y") && e.contains("\"0.25\""),
            "{e}"
        );
        let e = jitter_csv("1001,0.25,0.75\n1002,\"0.5,0.5\",0\n").unwrap_err();
        assert!(e.starts_with("line 2:") && e.contains("\"0.5,0.5\""), "{e}");
    }
}
