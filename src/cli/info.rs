//! `afterimage info FILE...`.

use super::outln;
use super::read_args::ReadArgs;
use afterimage::frame::FrameMeta;
use afterimage::io::{
    frame_number, read_exr_parts, read_raw, ChannelStats, ExrPart, PixelWindow, ReadOptions, Sequence,
};
use clap::Args;
use serde::Serialize;
use std::path::{Path, PathBuf};

/// Arguments of `info`.
#[derive(Args, Debug)]
pub struct InfoArgs {
    /// Image files (.exr, .png, .jpg), or sequences: a directory, a printf pattern
    /// (frame_%04d.exr) or a glob. Files are described in order, sequences frame by frame.
    #[arg(required_unless_present = "backends", num_args = 1..)]
    files: Vec<String>,
    /// Print JSON instead of text: an object for a single file, else an array of them.
    #[arg(long)]
    json: bool,
    /// List the backends filters can run on instead: the CPU, and the GPU adapters this
    /// build can use (with the filters the GPU backend implements).
    #[arg(long)]
    backends: bool,
    #[command(flatten)]
    read: ReadArgs,
}

#[derive(Serialize)]
struct ChannelInfo {
    name: String,
    file_type: &'static str,
    #[serde(flatten)]
    stats: ChannelStats,
}

#[derive(Serialize)]
struct Info {
    file: String,
    width: usize,
    height: usize,
    preset: Option<String>,
    motion_convention: Option<String>,
    /// Frame channel -> file channels, when the file maps onto a frame.
    mapping: Vec<(String, Vec<String>)>,
    /// Why the file does not map onto a frame, if it does not.
    mapping_error: Option<String>,
    channels: Vec<ChannelInfo>,
    non_finite_total: u64,
    meta: afterimage::frame::FrameMeta,
    /// Sparse shading the file declares (factor 1: every pixel).
    shading: afterimage::frame::Sampling,
    /// An EXR's parts: windows and compression (empty for other formats).
    parts: Vec<ExrPart>,
}

fn fmt_opt(v: Option<f64>) -> String {
    v.map_or("-".into(), |v| format!("{v:.6}"))
}

/// `info --backends`: the CPU, and each GPU adapter with what the GPU backend can run.
fn backends(json: bool) -> anyhow::Result<()> {
    use afterimage::backend::{adapters, gpu_filters, GPU_BUILT};
    let found = adapters();
    if json {
        let doc = serde_json::json!({
            "cpu": { "threads": afterimage::pipeline::exec::pool().current_num_threads() },
            "gpu_built": GPU_BUILT,
            "gpu_filters": gpu_filters(),
            "gpu_uploads": if GPU_BUILT { &["f32", "f16"][..] } else { &[][..] },
            "adapters": found,
        });
        outln!("{}", serde_json::to_string_pretty(&doc)?);
        return Ok(());
    }
    outln!(
        "cpu: every filter, {} threads",
        afterimage::pipeline::exec::pool().current_num_threads()
    );
    if !GPU_BUILT {
        outln!("gpu: not in this build (rebuild with --features gpu)");
        return Ok(());
    }
    if found.is_empty() {
        outln!("gpu: no adapter found (Mesa's software Vulkan, Debian's mesa-vulkan-drivers, provides one)");
    }
    for a in &found {
        outln!(
            "gpu: {} ({}, {}; driver {})",
            a.name,
            a.device_type,
            a.api,
            a.driver
        );
    }
    outln!("gpu filters: {}", gpu_filters().join(", "));
    outln!(
        "gpu colour upload: f32 (--backend gpu or auto), or f16 (--backend gpu-f16 or auto-f16: half the colour's bytes, rounded to 11 significant bits, clamped to +-65504)"
    );
    Ok(())
}

pub fn run(args: InfoArgs) -> anyhow::Result<()> {
    if args.backends {
        return backends(args.json);
    }
    let opts = args.read.options()?;
    let mut files: Vec<PathBuf> = Vec::new();
    for spec in &args.files {
        let path = Path::new(spec);
        if path.is_file() {
            files.push(path.to_path_buf());
        } else {
            files.extend(Sequence::open(spec)?.entries.into_iter().map(|e| e.path));
        }
    }
    let infos = files
        .iter()
        .map(|f| describe(f, &opts))
        .collect::<Result<Vec<_>, _>>()?;
    if args.json {
        let text = match infos.as_slice() {
            [one] => serde_json::to_string_pretty(one)?,
            many => serde_json::to_string_pretty(many)?,
        };
        outln!("{text}");
        return Ok(());
    }
    for (i, info) in infos.iter().enumerate() {
        if i > 0 {
            outln!();
        }
        print_text(info, args.read.preset == "auto")?;
    }
    Ok(())
}

/// What `info` says of one file.
fn describe(file: &Path, opts: &ReadOptions) -> anyhow::Result<Info> {
    let raw = read_raw(file)?;
    let preset = raw.preset(opts).ok();
    let (mapping, mapping_error) = match raw.mapping(opts) {
        Ok(m) => (
            m.into_iter().map(|(k, n)| (k.name().to_string(), n)).collect(),
            None,
        ),
        Err(e) => (Vec::new(), Some(e.to_string())),
    };
    let channels: Vec<ChannelInfo> = raw
        .channels
        .iter()
        .map(|c| ChannelInfo {
            name: c.name.clone(),
            file_type: c.file_type,
            stats: c.stats(),
        })
        .collect();
    Ok(Info {
        file: file.display().to_string(),
        width: raw.width,
        height: raw.height,
        preset: preset.as_ref().map(|p| p.to_string()),
        motion_convention: raw.motion_convention(opts).ok().map(|c| c.to_string()),
        mapping,
        mapping_error,
        non_finite_total: channels.iter().map(|c| c.stats.nan + c.stats.inf).sum(),
        channels,
        meta: FrameMeta {
            index: frame_number(file).unwrap_or(raw.meta.index),
            ..raw.meta.clone()
        },
        shading: raw.shading,
        parts: if file.extension().is_some_and(|e| e.eq_ignore_ascii_case("exr")) {
            read_exr_parts(file)?
        } else {
            Vec::new()
        },
    })
}

/// `info` as text for people.
fn print_text(info: &Info, detected: bool) -> anyhow::Result<()> {
    outln!("file:    {}", info.file);
    outln!("size:    {}x{}", info.width, info.height);
    let win = |w: &PixelWindow| format!("{}x{} at ({}, {})", w.width, w.height, w.x, w.y);
    for (i, p) in info.parts.iter().enumerate() {
        outln!(
            "part {i}{}: data {}, display {}, {} compression, {} channels",
            p.name.as_deref().map_or(String::new(), |n| format!(" ({n})")),
            win(&p.data_window),
            win(&p.display_window),
            p.compression,
            p.channels
        );
    }
    let how = if detected { " (detected)" } else { "" };
    outln!("preset:  {}{how}", info.preset.as_deref().unwrap_or("none fits"));
    if let Some(m) = &info.motion_convention {
        outln!("motion convention: {m}");
    }
    let meta = &info.meta;
    outln!(
        "frame:   index {}, jitter ({}, {}), reset {}, exposure {}, near/far {}",
        meta.index,
        meta.jitter[0],
        meta.jitter[1],
        meta.reset,
        meta.exposure.map_or("-".into(), |e| e.to_string()),
        meta.near_far.map_or("-".into(), |[n, f]| format!("{n}/{f}")),
    );
    let s = info.shading;
    if !s.is_full() {
        outln!(
            "shading: one pixel per {f}x{f} block, at ({}, {}) of each: colour stored at those pixels, 0 elsewhere",
            s.phase[0],
            s.phase[1],
            f = s.factor
        );
    }
    outln!();
    outln!(
        "{:<28} {:<5} {:>14} {:>14} {:>14} {:>8} {:>8}",
        "channel",
        "type",
        "min",
        "max",
        "mean",
        "NaN",
        "Inf"
    );
    for c in &info.channels {
        outln!(
            "{:<28} {:<5} {:>14} {:>14} {:>14} {:>8} {:>8}",
            c.name,
            c.file_type,
            fmt_opt(c.stats.min),
            fmt_opt(c.stats.max),
            fmt_opt(c.stats.mean),
            c.stats.nan,
            c.stats.inf
        );
    }
    outln!();
    if let Some(e) = &info.mapping_error {
        outln!("frame channels: none ({e})");
    } else {
        outln!("frame channels:");
        for (k, names) in &info.mapping {
            outln!("  {k:<10} <- {}", names.join(", "));
        }
    }
    if info.non_finite_total > 0 {
        outln!(
            "warning: {} non-finite samples (see the NaN and Inf columns)",
            info.non_finite_total
        );
    }
    Ok(())
}
