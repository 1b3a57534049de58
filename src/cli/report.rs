//! `afterimage report`: error against run time for every filter on every scene.

use afterimage::report::{self, Config, FilterSpec, Shot, TimingSize};
use anyhow::Context;
use clap::Args;
use indicatif::{ProgressBar, ProgressStyle};
use std::path::PathBuf;

/// Arguments of `report`.
#[derive(Args, Debug)]
pub struct ReportArgs {
    /// Scenes, comma-separated (default: the whole catalogue, or none when shots are given
    /// with --input or --corpus; see `afterimage scene --list`).
    #[arg(long, value_delimiter = ',')]
    scenes: Vec<String>,
    /// A shot rendered elsewhere, `[NAME=]DIR` (a directory, pattern or glob of frames, every
    /// channel its preset maps, jitter from the headers), run as a scene against the
    /// --reference at the same position. Named after the directory (its parent's name when
    /// it is called `input`) unless NAME is given. Repeatable.
    #[arg(long = "input", value_name = "[NAME=]DIR", requires = "references")]
    inputs: Vec<String>,
    /// The reference frames of the --input at the same position. Repeatable.
    #[arg(long = "reference", value_name = "DIR")]
    references: Vec<String>,
    /// A corpus: every SCENE/input with its SCENE/reference under DIR (the layout
    /// `corpus/render.sh` writes), run as shots.
    #[arg(long, value_name = "DIR")]
    corpus: Option<PathBuf>,
    /// Run the shots (--input, --corpus) as if their jitter were unknown: every frame's
    /// `afterimage.jitter` is taken as 0, so the filters weigh the current samples at the
    /// pixel centres (the case of a renderer that does not say where it sampled).
    #[arg(long)]
    jitter_unknown: bool,
    /// Filters, comma-separated, each NAME or NAME:key=value[:key=value] (default: every
    /// registered filter at its defaults; see `afterimage filters`).
    #[arg(long, value_delimiter = ',')]
    filters: Vec<String>,
    /// Scene size, WxH (default 256x144; 64x36 with --quick).
    #[arg(long, value_parser = super::scene::parse_size)]
    size: Option<(usize, usize)>,
    /// Frames per scene (default 32; 8 with --quick).
    #[arg(long)]
    frames: Option<u64>,
    /// Reference samples per pixel, a square number (default 256; 16 with --quick).
    #[arg(long)]
    spp: Option<u32>,
    /// Seed of the scenes' random choices.
    #[arg(long)]
    seed: Option<u64>,
    /// Render the main section's scenes with `--noise` (the sun's soft shadow as a
    /// one-sample estimate in the input, as `afterimage scene --noise`; references stay
    /// converged).
    #[arg(long)]
    noise: bool,
    /// Size of the timing section's synthetic G-buffer, WxH, or `none` to leave the
    /// section out (default 1920x1080; 320x180 with --quick).
    #[arg(long, value_parser = parse_timing_size)]
    timing_size: Option<TimingArg>,
    /// Timed frames per filter in the timing section (default 10; 3 with --quick).
    #[arg(long)]
    timing_frames: Option<usize>,
    /// Scenes of the upsampling section (sparse shading), comma-separated, `shots` for the
    /// --input/--corpus shots shaded sparsely from their dense frames, or `none` to leave
    /// it out (default: flyover, moving-sphere, dynamic-light; the shots when shots are
    /// given).
    #[arg(long, value_delimiter = ',')]
    upsampling_scenes: Vec<String>,
    /// Filters of the upsampling section, comma-separated, each NAME or
    /// NAME:key=value[:key=value] of a filter that takes sparse shading (default: each
    /// `method` of `upsample`).
    #[arg(long, value_delimiter = ',')]
    upsampling_filters: Vec<String>,
    /// Block size of the upsampling section's sparse shading: 2 or 4.
    #[arg(long)]
    shading: Option<u32>,
    /// Frame shown in the image strips (default: the last).
    #[arg(long)]
    strip_frame: Option<u64>,
    /// A run of well under a minute on 2 cores: small scenes, few frames. Explicit options
    /// still override it.
    #[arg(long)]
    quick: bool,
    /// Output directory: report.md, report.json, report.csv and the plots.
    #[arg(short = 'o', long, alias = "out", default_value = "report")]
    output: PathBuf,
}

/// `--timing-size`: a size, or `none` (a newtype, since clap reads `Option<Option<_>>` as
/// a flag with an optional value).
#[derive(Clone, Copy, Debug)]
struct TimingArg(Option<(usize, usize)>);

fn parse_timing_size(s: &str) -> Result<TimingArg, String> {
    match s {
        "none" => Ok(TimingArg(None)),
        _ => super::scene::parse_size(s).map(|size| TimingArg(Some(size))),
    }
}

fn config(args: &ReportArgs) -> anyhow::Result<Config> {
    let mut c = if args.quick {
        Config::quick()
    } else {
        Config::standard()
    };
    if args.inputs.len() != args.references.len() {
        anyhow::bail!(
            "{} --input but {} --reference: give one reference per input, in the same order",
            args.inputs.len(),
            args.references.len()
        );
    }
    if let Some(dir) = &args.corpus {
        c.shots = Shot::corpus(dir)?;
    }
    c.shots.extend(
        args.inputs
            .iter()
            .zip(&args.references)
            .map(|(i, r)| Shot::parse(i, r)),
    );
    for shot in &mut c.shots {
        shot.jitter_unknown = args.jitter_unknown;
    }
    if !args.scenes.is_empty() {
        c.scenes = args.scenes.iter().map(|s| s.trim().to_string()).collect();
    } else if !c.shots.is_empty() {
        c.scenes.clear();
    }
    if !args.filters.is_empty() {
        c.filters = args
            .filters
            .iter()
            .map(|s| FilterSpec::parse(s))
            .collect::<Result<_, _>>()?;
    }
    if let Some((w, h)) = args.size {
        (c.render.width, c.render.height) = (w, h);
    }
    if let Some(n) = args.frames {
        c.render.frames = n;
    }
    if let Some(n) = args.spp {
        c.render.spp = n;
    }
    if let Some(n) = args.seed {
        c.render.seed = n;
    }
    c.render.noise |= args.noise;
    c.strip_frame = args.strip_frame;
    let has_shots = !c.shots.is_empty();
    match args.upsampling_scenes.as_slice() {
        [] => {
            // With shots and no catalogue scenes asked for, the section runs on the shots.
            if let (true, Some(u)) = (has_shots, c.upsampling.as_mut()) {
                u.scenes.clear();
                u.shots = true;
            }
        }
        [none] if none.trim() == "none" => c.upsampling = None,
        scenes => {
            if let Some(u) = c.upsampling.as_mut() {
                u.shots = scenes.iter().any(|s| s.trim() == "shots");
                u.scenes = scenes
                    .iter()
                    .map(|s| s.trim().to_string())
                    .filter(|s| s != "shots")
                    .collect();
            }
        }
    }
    if let (Some(f), Some(u)) = (args.shading, c.upsampling.as_mut()) {
        u.factor = f;
    }
    if let (false, Some(u)) = (args.upsampling_filters.is_empty(), c.upsampling.as_mut()) {
        u.filters = args
            .upsampling_filters
            .iter()
            .map(|s| FilterSpec::parse(s))
            .collect::<Result<_, _>>()?;
    }
    let frames = args.timing_frames.or(c.timing.map(|t| t.frames)).unwrap_or(10);
    match args.timing_size {
        Some(TimingArg(None)) => c.timing = None,
        Some(TimingArg(Some((width, height)))) => {
            c.timing = Some(TimingSize {
                width,
                height,
                frames,
            })
        }
        None => {
            if let Some(t) = c.timing.as_mut() {
                t.frames = frames;
            }
        }
    }
    Ok(c)
}

pub fn run(args: ReportArgs) -> anyhow::Result<()> {
    let config = config(&args)?;
    let bar = ProgressBar::new(config.steps()).with_style(
        ProgressStyle::with_template("{msg:>28} [{bar:30}] {pos}/{len} frames, {eta} left")?
            .progress_chars("=> "),
    );
    let report = report::run(&config, &mut |p| {
        bar.set_position(p.done);
        bar.set_message(p.what.clone());
    })?;
    bar.finish_and_clear();
    let out = &args.output;
    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    let md = report::markdown(&report);
    let mut written = Vec::new();
    for (name, text) in [
        ("report.md", md.clone()),
        ("report.json", serde_json::to_string_pretty(&report)?),
        ("report.csv", report::csv(&report)),
    ] {
        let path = out.join(name);
        std::fs::write(&path, text).with_context(|| format!("writing {}", path.display()))?;
        written.push(path);
    }
    written.extend(report::write_plots(&report, out)?);
    super::print_stdout(&md)?;
    eprintln!(
        "wrote {} files to {}: report.md/json/csv, error_vs_time.png/svg, psnr_per_frame.png/svg, strip_<scene>.png",
        written.len(),
        out.display()
    );
    Ok(())
}
