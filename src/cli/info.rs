//! `afterimage info FILE`.

use super::read_args::ReadArgs;
use afterimage::io::{read_raw, ChannelStats};
use clap::Args;
use serde::Serialize;
use std::path::PathBuf;

/// Arguments of `info`.
#[derive(Args, Debug)]
pub struct InfoArgs {
    /// The image file (.exr, .png, .jpg).
    file: PathBuf,
    /// Print JSON instead of text.
    #[arg(long)]
    json: bool,
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
}

fn fmt_opt(v: Option<f64>) -> String {
    v.map_or("-".into(), |v| format!("{v:.6}"))
}

pub fn run(args: InfoArgs) -> anyhow::Result<()> {
    let opts = args.read.options()?;
    let raw = read_raw(&args.file)?;
    let preset = raw.preset(&opts).ok();
    let (mapping, mapping_error) = match raw.mapping(&opts) {
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
    let info = Info {
        file: args.file.display().to_string(),
        width: raw.width,
        height: raw.height,
        preset: preset.as_ref().map(|p| p.to_string()),
        motion_convention: raw.motion_convention(&opts).ok().map(|c| c.to_string()),
        mapping,
        mapping_error,
        non_finite_total: channels.iter().map(|c| c.stats.nan + c.stats.inf).sum(),
        channels,
        meta: raw.meta.clone(),
        shading: raw.shading,
    };
    if args.json {
        println!("{}", serde_json::to_string_pretty(&info)?);
        return Ok(());
    }
    println!("file:    {}", info.file);
    println!("size:    {}x{}", info.width, info.height);
    let how = if args.read.preset == "auto" {
        " (detected)"
    } else {
        ""
    };
    println!("preset:  {}{how}", info.preset.as_deref().unwrap_or("none fits"));
    if let Some(m) = &info.motion_convention {
        println!("motion convention: {m}");
    }
    let meta = &info.meta;
    println!(
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
        println!(
            "shading: one pixel per {f}x{f} block, at ({}, {}) of each: colour stored at those pixels, 0 elsewhere",
            s.phase[0],
            s.phase[1],
            f = s.factor
        );
    }
    println!();
    println!(
        "{:<28} {:<5} {:>14} {:>14} {:>14} {:>8} {:>8}",
        "channel", "type", "min", "max", "mean", "NaN", "Inf"
    );
    for c in &info.channels {
        println!(
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
    println!();
    if let Some(e) = &info.mapping_error {
        println!("frame channels: none ({e})");
    } else {
        println!("frame channels:");
        for (k, names) in &info.mapping {
            println!("  {k:<10} <- {}", names.join(", "));
        }
    }
    if info.non_finite_total > 0 {
        println!(
            "warning: {} non-finite samples (see the NaN and Inf columns)",
            info.non_finite_total
        );
    }
    Ok(())
}
