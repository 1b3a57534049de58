//! `afterimage scene NAME --out DIR`: render a catalogue scene to EXR.

use super::outln;
use afterimage::io::{write_exr, write_png, Compression, Precision, WriteOptions};
use afterimage::metrics::Timing;
use afterimage::scene::{Jitter, Scene, Settings, BEHIND_CAMERA_MOTION, CATALOGUE, SKY_DEPTH};
use anyhow::Context;
use clap::Args;
use indicatif::{ProgressBar, ProgressStyle};
use serde_json::json;
use std::path::PathBuf;
use std::time::Instant;

/// Arguments of `scene`.
#[derive(Args, Debug)]
pub struct SceneArgs {
    /// Scene name (see --list).
    #[arg(required_unless_present = "list")]
    name: Option<String>,
    /// List the catalogue and exit.
    #[arg(long)]
    list: bool,
    /// Number of frames.
    #[arg(long, default_value_t = 32)]
    frames: u64,
    /// Size, WxH.
    #[arg(long, default_value = "256x144", value_parser = parse_size)]
    size: (usize, usize),
    /// Reference samples per pixel: a square number N x N (stratified grid).
    #[arg(long, default_value_t = 256)]
    spp: u32,
    /// Input jitter: 8 or 16 (Halton 2,3 phases) or none.
    #[arg(long, default_value = "8", value_parser = parse_jitter)]
    jitter: Jitter,
    /// Turn the sun's soft shadow into a 1-sample Monte-Carlo estimate in the input
    /// (the reference integrates it).
    #[arg(long)]
    noise: bool,
    /// Seed of every random choice (same seed, same bits).
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Sparse shading for the upsample filter: shade one pixel of every NxN block (2 or
    /// 4) in a rotating order; G-buffer and reference stay at full resolution. 1 shades
    /// every pixel. Use with --jitter none to sample at pixel centres as Herzog et al. do.
    #[arg(long, default_value_t = 1)]
    shading: u32,
    /// Write half floats (object ids stay u32).
    #[arg(long)]
    f16: bool,
    /// Also write PNG previews of the input and the reference (tonemapped c/(1+c)
    /// when the scene is HDR).
    #[arg(long)]
    png: bool,
    /// Output directory (frame_NNNN.exr in the afterimage preset, plus scene.json).
    #[arg(short = 'o', long, alias = "out", required_unless_present = "list")]
    output: Option<PathBuf>,
}

pub(crate) fn parse_size(s: &str) -> Result<(usize, usize), String> {
    let (w, h) = s
        .split_once(['x', 'X'])
        .ok_or_else(|| format!("size {s:?} is not WxH"))?;
    let p = |v: &str| {
        v.trim()
            .parse::<usize>()
            .map_err(|_| format!("size {s:?} is not WxH"))
    };
    Ok((p(w)?, p(h)?))
}

fn parse_jitter(s: &str) -> Result<Jitter, String> {
    match s {
        "none" => Ok(Jitter::None),
        _ => match s.parse::<u32>() {
            Ok(n) if n > 0 => Ok(Jitter::Halton(n)),
            _ => Err(format!(
                "jitter {s:?}: expected a number of phases (8 or 16) or none"
            )),
        },
    }
}

pub fn run(args: SceneArgs) -> anyhow::Result<()> {
    if args.list {
        for e in CATALOGUE {
            outln!("{:<14} {}", e.name, e.description);
        }
        return Ok(());
    }
    let name = args.name.as_deref().expect("clap requires a name");
    let out = args.output.as_ref().expect("clap requires --output");
    let settings = Settings {
        width: args.size.0,
        height: args.size.1,
        frames: args.frames,
        spp: args.spp,
        jitter: args.jitter,
        noise: args.noise,
        seed: args.seed,
        shading: args.shading,
    };
    let scene = Scene::new(name, settings)?;
    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    let opts = WriteOptions {
        precision: if args.f16 { Precision::F16 } else { Precision::F32 },
        compression: Compression::Zip,
    };
    let bar = ProgressBar::new(args.frames).with_style(
        ProgressStyle::with_template("{msg:>10} [{bar:30}] {pos}/{len} frames, {eta} left")?
            .progress_chars("=> "),
    );
    bar.set_message(name.to_string());
    let mut per_frame = Vec::new();
    let mut ms = Vec::new();
    for i in 0..args.frames {
        let start = Instant::now();
        let frame = scene.frame(i);
        ms.push(start.elapsed().as_secs_f64() * 1e3);
        let file = format!("frame_{i:04}.exr");
        write_exr(&out.join(&file), &frame, &opts)?;
        if args.png {
            let reference = frame.reference().expect("scenes write a reference");
            let hdr = reference.iter().any(|p| p.data().iter().any(|&v| v > 1.0));
            write_png(&out.join(format!("frame_{i:04}.png")), &frame.color_full(), hdr)?;
            write_png(&out.join(format!("reference_{i:04}.png")), reference, hdr)?;
        }
        per_frame.push(json!({
            "index": i,
            "file": file,
            "jitter": frame.meta.jitter,
            "shading": frame.sampling(),
            "reset": frame.meta.reset,
            "camera": (scene.def.camera)(i as f64),
        }));
        bar.inc(1);
    }
    bar.finish_and_clear();
    let median = Timing::of(&ms).median_ms;
    let meta = json!({
        "scene": name,
        "description": scene.def.description,
        "settings": settings,
        "conventions": {
            "channels": "afterimage preset: color.RGB, depth.Z, motion.XY, motion_next.XY, normal.XYZ, object_id.id (u32), albedo.RGB, reference.RGB",
            "motion": "internal: pixels, from the current pixel centre to the point's position in the previous frame, x right, y down, jitter excluded (prev = p + mv)",
            "motion_next": "internal: pixels, from the current pixel centre to the point's position in the next frame, x right, y down, jitter excluded (next = p + mv)",
            "motion_behind_camera": BEHIND_CAMERA_MOTION,
            "depth": "planar view-space depth along the camera's forward axis, larger = farther",
            "sky_depth": SKY_DEPTH,
            "normal": "world space, unit; zero on sky",
            "object_id": "0 = sky",
            "shading": "factor: one shaded colour sample per factor x factor block; phase: the shaded pixel of each block this frame. The EXR stores the samples at their pixels and 0 elsewhere, with afterimage.shading = (factor, phase x, phase y)",
            "jitter": "offset of the input sample from the pixel centre in pixels, x right, y down",
            "reference": format!("{0}x{0} stratified samples over the pixel box, no jitter", settings.reference_grid()),
            "time": "scene time = frame index; frame 0's motion points to time -1",
        },
        "ms_per_frame_median": median,
        "frames": per_frame,
    });
    std::fs::write(out.join("scene.json"), serde_json::to_string_pretty(&meta)?)
        .with_context(|| format!("writing {}", out.join("scene.json").display()))?;
    outln!(
        "{name}: {} frames of {}x{} ({} spp reference) in {}, median {median:.1} ms/frame",
        args.frames,
        settings.width,
        settings.height,
        settings.spp,
        out.display()
    );
    Ok(())
}
