//! `afterimage batch`: many shots, each filtered as `afterimage filter` filters one
//! sequence (the same code and every one of its options), resumable, and split over the
//! processes of a cluster job.
//!
//! - **Shots** come from a manifest (TOML or JSON: defaults, then `[[shot]]` tables with
//!   `name`, `input`, `output` and extra `filter` arguments) or from `-i [NAME=]DIR`
//!   repeated, each directory a shot named NAME (default: after the directory), written
//!   under `-o ROOT/<name>/`.
//! - **Storage**: inputs and outputs are local paths or object store URLs (`s3://`, `gs://`,
//!   `az://`; see [`super::store`]), read ahead and written behind the filter
//!   ([`super::shot`]).
//! - **Resumable**: every output frame appears whole or not at all (a local file is written
//!   under a hidden temporary name, then renamed; an object is one put), and a finished shot
//!   leaves `.afterimage-done/<name>.json` beside its outputs, with the shot's fingerprint
//!   (build, arguments, filter parameters, inputs' names, sizes and modification times); a
//!   rerun skips a finished shot whose fingerprint is unchanged and filters it again otherwise.
//!   An unfinished shot continues from its last checkpoint (`--checkpoint-every N` frames:
//!   the filter's state, saved beside the outputs in `.afterimage-progress/`), redoing at
//!   most N frames, and its outputs are those of an uninterrupted run.
//! - **Sharding**: `--shard INDEX/COUNT` (default: `JOB_COMPLETION_INDEX`, as a Kubernetes
//!   Indexed Job sets it, or `AWS_BATCH_JOB_ARRAY_INDEX`, with the count from
//!   `AFTERIMAGE_SHARD_COUNT`) gives whole shots to shards, longest first to the shard with
//!   the fewest frames so far: deterministic, even by frame count, and no two shards ever
//!   write the same file (each process counts the frames when it starts, so the inputs
//!   must be complete by then). A shot whose input does not open is failed by its shard.
//! - **Results**: a bar per shot and one overall (frames/s, ETA) on a terminal, else plain
//!   progress lines in the log (`--progress-every`); a summary in JSON and
//!   markdown (per shot: frames, ms/frame, PSNR/tRMSE with a reference, failures); a
//!   failed shot is retried `--retries` times; the exit status is non-zero when any failed.

use super::filter::FilterArgs;
use super::outln;
use super::shot::{run_shot, Checkpoints};
use super::store::{set_endpoint, storage_for};
use afterimage::io::{OutputNaming, Sequence};
use anyhow::Context;
use clap::{Args, Parser};
use indicatif::{MultiProgress, ProgressBar, ProgressStyle};
use serde::{Deserialize, Serialize};
use std::io::IsTerminal;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// Arguments of `batch`.
#[derive(Args, Debug)]
pub struct BatchArgs {
    /// The manifest (TOML or JSON; see `afterimage batch --help` and the README).
    manifest: Option<PathBuf>,
    /// A shot directory (repeatable), instead of or besides a manifest, as NAME=DIR or DIR
    /// (named after the directory), written to `-o ROOT/<name>/`.
    #[arg(short = 'i', long = "input", value_name = "[NAME=]DIR")]
    inputs: Vec<String>,
    /// Output root for `-i` shots.
    #[arg(short = 'o', long, value_name = "ROOT")]
    output: Option<PathBuf>,
    /// The filter of `-i` shots, and of manifest shots that name none.
    #[arg(long)]
    filter: Option<String>,
    /// This process's share of the shots, INDEX/COUNT (e.g. 0/3). Default: from
    /// JOB_COMPLETION_INDEX (Kubernetes Indexed Job) or AWS_BATCH_JOB_ARRAY_INDEX, with
    /// AFTERIMAGE_SHARD_COUNT; else all shots.
    #[arg(long, value_name = "INDEX/COUNT")]
    shard: Option<String>,
    /// Times a failed shot is run again (from its last checkpoint). A shot whose input or
    /// output is not found or not allowed (no credentials, access denied), or whose filter
    /// arguments are wrong, is not: another attempt would fail the same way.
    #[arg(long, default_value_t = 1)]
    retries: u32,
    /// Seconds before a failed shot's first retry; each later wait doubles, up to 120 s,
    /// with up to as much again at random (jitter), so shards that failed together do not
    /// retry together. (Each object store request is already retried on its own, with
    /// backoff, for up to 3 minutes before a shot fails.)
    #[arg(long, default_value_t = 5.0, value_name = "SECONDS")]
    retry_delay: f64,
    /// Filter finished shots again instead of skipping them.
    #[arg(long)]
    force: bool,
    /// The summary's path (JSON; a markdown table is written beside it), a file or an
    /// object URL. Default: batch-summary.json, or batch-summary-shard-I-of-N.json, in the
    /// current directory.
    #[arg(long, value_name = "FILE")]
    summary: Option<PathBuf>,
    /// Frames between checkpoints of a shot's filter state (0: none, a killed shot starts
    /// over). A checkpoint holds the filter's history (half its `state` in `afterimage
    /// filters`): 16 bytes a pixel for taa, 108 for phlm, 33 MB and 224 MB at 1920x1080.
    /// Fewer frames between them redo less after a kill and write more.
    #[arg(long, default_value_t = 16, value_name = "N")]
    checkpoint_every: usize,
    /// Let a manifest's shots write outside the manifest's directory (by default a local
    /// output must lie under it, so a manifest cannot overwrite files elsewhere).
    #[arg(long)]
    allow_outside: bool,
    /// S3 endpoint for `s3://` paths (an S3-compatible store: MinIO, Ceph, moto); default:
    /// AWS_ENDPOINT_URL, else AWS's own.
    #[arg(long, value_name = "URL")]
    endpoint: Option<String>,
    /// Seconds between plain progress lines (frames/s, ETA) in the log when stderr is not a
    /// terminal (a Kubernetes Job's log); one is also written as each shot ends.
    #[arg(long, default_value_t = 30.0, value_name = "SECONDS")]
    progress_every: f64,
}

/// A manifest: defaults for every shot, then the shots.
#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
struct Manifest {
    /// Default filter.
    filter: Option<String>,
    /// `afterimage filter` arguments for every shot (before each shot's own).
    #[serde(default)]
    args: Vec<String>,
    /// The shots.
    #[serde(default)]
    shot: Vec<ShotSpec>,
}

/// One shot of a manifest.
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
struct ShotSpec {
    /// Unique name (the done marker and the summary use it).
    name: String,
    /// The sequence, as `filter -i` takes it.
    input: String,
    /// Where its outputs go, as `filter -o` takes it.
    output: String,
    /// Its filter (default: the manifest's, or --filter).
    filter: Option<String>,
    /// More `afterimage filter` arguments (`--set`, `--cuts`, `--keep`, `--reference`, ...).
    #[serde(default)]
    args: Vec<String>,
}

/// A shot ready to run: its `filter` arguments and frame count (0 with the error when its
/// input does not open: the shot is then reported failed by its shard, not fatal to all).
struct Shot {
    spec: ShotSpec,
    argv: Vec<String>,
    frames: usize,
    open_error: Option<String>,
}

/// What happened to a shot, as the summary says.
#[derive(Debug, Serialize, Deserialize)]
struct ShotResult {
    name: String,
    input: String,
    output: String,
    frames: usize,
    /// done, skipped (finished earlier) or failed.
    status: String,
    attempts: u32,
    ms_per_frame: Option<f64>,
    mean_psnr: Option<f64>,
    trmse: Option<f64>,
    error: Option<String>,
    /// What the outputs depend on (see `shot::fingerprint`); absent in markers of older
    /// builds, which are therefore filtered again.
    #[serde(default)]
    fingerprint: Option<String>,
}

#[derive(Parser)]
#[command(no_binary_name = true)]
struct ShotArgs {
    #[command(flatten)]
    filter: FilterArgs,
}

/// `INDEX/COUNT` from the flag, else from the job environment.
fn shard(flag: Option<&str>) -> anyhow::Result<(usize, usize)> {
    let parse = |s: &str, what: &str| -> anyhow::Result<(usize, usize)> {
        let bad = || anyhow::anyhow!("{what} {s:?}: expected INDEX/COUNT with INDEX < COUNT, e.g. 0/3");
        let (i, n) = s.split_once('/').ok_or_else(bad)?;
        let (i, n): (usize, usize) = (
            i.trim().parse().map_err(|_| bad())?,
            n.trim().parse().map_err(|_| bad())?,
        );
        if n == 0 || i >= n {
            return Err(bad());
        }
        Ok((i, n))
    };
    if let Some(s) = flag {
        return parse(s, "--shard");
    }
    let index = ["JOB_COMPLETION_INDEX", "AWS_BATCH_JOB_ARRAY_INDEX"]
        .iter()
        .find_map(|v| std::env::var(v).ok().map(|x| (*v, x)));
    match (index, std::env::var("AFTERIMAGE_SHARD_COUNT").ok()) {
        (Some((var, i)), Some(n)) => parse(&format!("{i}/{n}"), &format!("{var}/AFTERIMAGE_SHARD_COUNT")),
        (Some((var, _)), None) => anyhow::bail!(
            "{var} is set but AFTERIMAGE_SHARD_COUNT is not: set it to the job's number of shards"
        ),
        _ => Ok((0, 1)),
    }
}

/// Shots for each shard: longest first, each to the shard with the fewest frames so far
/// (ties: the lower index); shots of equal length in name order.
fn assign(frames: &[(String, usize)], count: usize) -> Vec<usize> {
    let mut order: Vec<usize> = (0..frames.len()).collect();
    order.sort_by(|&a, &b| frames[b].1.cmp(&frames[a].1).then(frames[a].0.cmp(&frames[b].0)));
    let mut load = vec![0usize; count];
    let mut owner = vec![0usize; frames.len()];
    for k in order {
        let s = (0..count).min_by_key(|&s| (load[s], s)).expect("count > 0");
        load[s] += frames[k].1;
        owner[k] = s;
    }
    owner
}

/// `path` made absolute against the working directory, with `.` and `..` resolved by
/// name (symbolic links are not followed: the check is on what the manifest says).
fn lexical_absolute(path: &Path) -> anyhow::Result<PathBuf> {
    use std::path::Component;
    let joined = std::env::current_dir()
        .context("the working directory")?
        .join(path);
    let mut out = PathBuf::new();
    for c in joined.components() {
        match c {
            Component::CurDir => {}
            Component::ParentDir => {
                out.pop();
            }
            other => out.push(other),
        }
    }
    Ok(out)
}

/// Refuses a manifest shot whose local output lies outside `root`, the manifest's
/// directory (object-store outputs are bounded by their credentials instead).
fn confine(spec: &ShotSpec, root: &Path) -> anyhow::Result<()> {
    if spec.output.contains("://") {
        return Ok(());
    }
    let out = lexical_absolute(Path::new(&spec.output))?;
    anyhow::ensure!(
        out.starts_with(root),
        "shot {}: output {} is outside the manifest's directory {}; pass --allow-outside to write there",
        spec.name,
        spec.output,
        root.display()
    );
    Ok(())
}

fn read_manifest(path: &Path) -> anyhow::Result<Manifest> {
    let text = std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
    let json = path.extension().is_some_and(|e| e.eq_ignore_ascii_case("json"));
    let m: Manifest = if json {
        serde_json::from_str(&text).with_context(|| format!("{}: not a batch manifest", path.display()))?
    } else {
        toml::from_str(&text).with_context(|| format!("{}: not a batch manifest", path.display()))?
    };
    Ok(m)
}

/// The shots of the manifest and of `-i`, checked: names unique, filters named, inputs open.
fn shots(args: &BatchArgs) -> anyhow::Result<Vec<Shot>> {
    let manifest = match &args.manifest {
        Some(p) => read_manifest(p)?,
        None => Manifest::default(),
    };
    let mut specs = manifest.shot.clone();
    if let (Some(path), false) = (&args.manifest, args.allow_outside) {
        let root = lexical_absolute(path.parent().unwrap_or(Path::new("")))?;
        for spec in &specs {
            confine(spec, &root)?;
        }
    }
    if !args.inputs.is_empty() {
        let root = args
            .output
            .as_ref()
            .context("-i shots need -o ROOT: each is written to ROOT/<name>/")?;
        for spec in &args.inputs {
            let (name, dir) = named_input(spec)?;
            specs.push(ShotSpec {
                output: root.join(&name).display().to_string(),
                name,
                input: dir.display().to_string(),
                filter: None,
                args: Vec::new(),
            });
        }
    }
    if specs.is_empty() {
        anyhow::bail!("no shots: give a manifest with [[shot]] tables, or -i DIR (repeatable) with -o ROOT");
    }
    let mut out = Vec::new();
    for spec in specs {
        if let Some(other) = out.iter().find(|s: &&Shot| s.spec.name == spec.name) {
            anyhow::bail!(
                "two shots are named {:?} ({} and {}): shot names must be unique; name -i shots with -i NAME=DIR",
                spec.name,
                other.spec.input,
                spec.input
            );
        }
        if spec.name.is_empty() || spec.name.contains(['/', '\\']) || spec.name.starts_with('.') {
            anyhow::bail!(
                "shot name {:?}: expected a file name (no slashes, not starting with a dot)",
                spec.name
            );
        }
        let filter = spec
            .filter
            .clone()
            .or_else(|| manifest.filter.clone())
            .or_else(|| args.filter.clone())
            .with_context(|| {
                format!(
                    "shot {}: no filter (give --filter, or `filter` in the manifest)",
                    spec.name
                )
            })?;
        let opened = storage_for(&spec.input).and_then(|st| Ok(Sequence::open_in(&spec.input, &*st)?));
        let (frames, open_error) = match opened {
            Ok(seq) => (seq.len(), None),
            Err(e) => (0, Some(format!("{e:#}"))),
        };
        let naming = OutputNaming::parse(&spec.output).with_context(|| format!("shot {}", spec.name))?;
        let records = naming.dir().join(format!("{}.records.json", spec.name));
        let mut argv: Vec<String> = vec![
            "--filter".into(),
            filter,
            "-i".into(),
            spec.input.clone(),
            "-o".into(),
            spec.output.clone(),
            "--records".into(),
            records.display().to_string(),
        ];
        argv.extend(manifest.args.iter().cloned());
        argv.extend(spec.args.iter().cloned());
        out.push(Shot {
            spec,
            argv,
            frames,
            open_error,
        });
    }
    Ok(out)
}

/// A `-i` shot: `NAME=DIR` (when no file `NAME=DIR` exists), else `DIR` named after its
/// last component.
fn named_input(spec: &str) -> anyhow::Result<(String, PathBuf)> {
    if let Some((name, dir)) = spec.split_once('=') {
        if !Path::new(spec).exists() && !name.contains(['/', '\\']) {
            return Ok((name.to_string(), PathBuf::from(dir)));
        }
    }
    let dir = PathBuf::from(spec);
    let name = dir
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .with_context(|| format!("{spec}: a shot directory needs a name (or give -i NAME={spec})"))?;
    Ok((name, dir))
}

/// The fingerprint of a shot as it would run now (see `shot::fingerprint`).
fn shot_fingerprint(shot: &Shot) -> anyhow::Result<String> {
    if let Some(e) = &shot.open_error {
        anyhow::bail!("{e}");
    }
    super::shot::fingerprint(&shot_args(shot)?.filter)
}

/// The shot's `filter` arguments, parsed.
fn shot_args(shot: &Shot) -> anyhow::Result<ShotArgs> {
    ShotArgs::try_parse_from(&shot.argv)
        .map_err(|e| anyhow::anyhow!("shot {}: its filter arguments: {}", shot.spec.name, e.render()))
}

/// Where a finished shot leaves its marker: `.afterimage-done/<name>.json` in its output
/// directory.
fn done_marker(spec: &ShotSpec) -> anyhow::Result<PathBuf> {
    let naming = OutputNaming::parse(&spec.output)?;
    Ok(naming
        .dir()
        .join(".afterimage-done")
        .join(format!("{}.json", spec.name)))
}

/// Where a shot's checkpoints go: `.afterimage-progress/<name>.*` in its output directory.
fn checkpoints(spec: &ShotSpec, every: usize) -> anyhow::Result<Checkpoints> {
    let naming = OutputNaming::parse(&spec.output)?;
    Ok(Checkpoints {
        base: naming.dir().join(".afterimage-progress").join(&spec.name),
        every,
    })
}

/// Writes `text` to `path` (a file or an object) whole or not at all, as frames are written.
fn write_atomic(path: &Path, text: &str) -> anyhow::Result<()> {
    let spec = path.to_string_lossy();
    storage_for(&spec)?
        .put(path, text.as_bytes())
        .with_context(|| format!("writing {}", path.display()))
}

/// A shot whose input did not open when the shard counted the frames: it stays failed for
/// this run (the shards' split was made without its frames).
#[derive(Debug, thiserror::Error)]
#[error("{0}")]
struct NotOpened(String);

/// Why another attempt at a shot that failed with `e` would fail the same way, or `None`
/// when it might not: a file or object not found, not allowed (access denied, no
/// credentials: the object store's refusals carry these kinds, see `store::refused`), or
/// a wrong argument, anywhere in the error's chain.
fn permanent(e: &anyhow::Error) -> Option<&'static str> {
    use afterimage::backend::BackendError;
    use std::io::ErrorKind;
    e.chain().find_map(|cause| {
        if cause.is::<NotOpened>() {
            return Some("its input did not open when the shard started");
        }
        if let Some(io) = cause.downcast_ref::<std::io::Error>() {
            return match io.kind() {
                ErrorKind::NotFound => Some("not found"),
                ErrorKind::PermissionDenied => Some("not allowed"),
                ErrorKind::InvalidInput => Some("a wrong argument"),
                _ => None,
            };
        }
        match cause.downcast_ref::<BackendError>() {
            Some(BackendError::NoAdapter { .. } | BackendError::Device(_)) | None => None,
            Some(_) => Some("the filter, its parameters or backend are wrong"),
        }
    })
}

/// The waits between a failed shot's attempts: exponential from `first` (doubling, at most
/// 120 s), each with up to as much again at random, `retries` of them at most.
fn shot_backoff(first: std::time::Duration, retries: u32) -> backon::ExponentialBuilder {
    backon::ExponentialBuilder::default()
        .with_min_delay(first)
        .with_factor(2.0)
        .with_max_delay(std::time::Duration::from_secs(120).max(first))
        .with_jitter()
        .with_max_times(retries as usize)
}

/// Runs `attempt` (told its number, from 1) until it succeeds, fails [`permanent`]ly, or
/// the waits of `backoff` run out; between attempts `wait` sleeps and `retrying` is told
/// the error, the attempt that failed and the wait. The last result, and the attempts made.
fn with_retries<T>(
    backoff: backon::ExponentialBuilder,
    wait: impl backon::BlockingSleeper,
    mut attempt: impl FnMut(u32) -> anyhow::Result<T>,
    mut retrying: impl FnMut(&anyhow::Error, u32, std::time::Duration),
) -> (anyhow::Result<T>, u32) {
    use backon::BlockingRetryable;
    let made = std::cell::Cell::new(0u32);
    let result = (|| {
        made.set(made.get() + 1);
        attempt(made.get())
    })
    .retry(backoff)
    .sleep(wait)
    .when(|e| permanent(e).is_none())
    .notify(|e, d| retrying(e, made.get(), d))
    .call();
    (result, made.get())
}

fn run_one(shot: &Shot, bar: &ProgressBar, checkpoint_every: usize) -> anyhow::Result<ShotResult> {
    if let Some(e) = &shot.open_error {
        return Err(NotOpened(e.clone()).into());
    }
    let args = shot_args(shot)?;
    let report = run_shot(
        &args.filter,
        bar,
        Some(&checkpoints(&shot.spec, checkpoint_every)?),
    )?;
    if report.resumed_at > 0 {
        tracing::info!(
            "shot {}: continued from its checkpoint at frame {} of {}",
            shot.spec.name,
            report.resumed_at + 1,
            shot.frames
        );
    }
    let totals: Vec<f64> = report.records.iter().map(|r| r.total_ms).collect();
    Ok(ShotResult {
        name: shot.spec.name.clone(),
        input: shot.spec.input.clone(),
        output: report.output,
        frames: report.resumed_at + report.records.len(),
        status: "done".into(),
        attempts: 1,
        ms_per_frame: Some(afterimage::metrics::Timing::of(&totals).median_ms),
        mean_psnr: report.summary.as_ref().map(|s| s.mean_psnr),
        trmse: report.summary.as_ref().and_then(|s| s.trmse),
        error: None,
        fingerprint: Some(report.fingerprint),
    })
}

/// Progress as plain log lines (target `afterimage::progress`) where stderr is no terminal
/// and the bars are hidden: a line every `every`, and one as each shot ends.
struct PlainProgress {
    /// The shard's frames: done or skipped before the current shot, and in all.
    overall: ProgressBar,
    /// The shot being filtered, by name.
    current: std::sync::Mutex<Option<(String, ProgressBar)>>,
    /// Frames filtered by this process (skipped shots not counted), for the rate.
    filtered: std::sync::atomic::AtomicU64,
    started: Instant,
}

impl PlainProgress {
    /// Logs where the shard stands: the current shot's frames, the shard's, the rate of
    /// this run's filtering and the time the rest takes at that rate.
    fn line(&self) {
        use std::sync::atomic::Ordering;
        let current = self.current.lock().unwrap_or_else(|p| p.into_inner());
        let (shot, in_shot) = match &*current {
            Some((name, bar)) => (
                format!(
                    "shot {name} {}/{} frames; ",
                    bar.position(),
                    bar.length().unwrap_or(0)
                ),
                bar.position(),
            ),
            None => (String::new(), 0),
        };
        let filtered = self.filtered.load(Ordering::Relaxed) + in_shot;
        let done = self.overall.position() + in_shot;
        let total = self.overall.length().unwrap_or(0);
        let secs = self.started.elapsed().as_secs_f64();
        let rate = if secs > 0.0 { filtered as f64 / secs } else { 0.0 };
        let eta = if rate > 0.0 {
            format!("{:.0} s", total.saturating_sub(done) as f64 / rate)
        } else {
            "-".into()
        };
        tracing::info!(
            target: "afterimage::progress",
            "{shot}shard {done}/{total} frames, {rate:.2} frames/s, ETA {eta}"
        );
    }
}

pub fn run(args: BatchArgs) -> anyhow::Result<()> {
    set_endpoint(args.endpoint.clone())?;
    let (index, count) = shard(args.shard.as_deref())?;
    let all = shots(&args)?;
    let owner = assign(
        &all.iter()
            .map(|s| (s.spec.name.clone(), s.frames))
            .collect::<Vec<_>>(),
        count,
    );
    let mine: Vec<&Shot> = all
        .iter()
        .zip(&owner)
        .filter(|(_, &o)| o == index)
        .map(|(s, _)| s)
        .collect();
    let total_frames: usize = mine.iter().map(|s| s.frames).sum();
    let multi = MultiProgress::new();
    let overall = multi.add(
        ProgressBar::new(total_frames as u64).with_style(
            ProgressStyle::with_template("{msg:>12} [{bar:30}] {pos}/{len} frames, {per_sec}, {eta} left")?
                .progress_chars("=> "),
        ),
    );
    overall.set_message(format!("shard {index}/{count}"));
    let started = Instant::now();
    let plain = (!std::io::stderr().is_terminal()).then(|| PlainProgress {
        overall: overall.clone(),
        current: Default::default(),
        filtered: Default::default(),
        started,
    });
    let every = std::time::Duration::try_from_secs_f64(args.progress_every)
        .ok()
        .filter(|d| !d.is_zero())
        .with_context(|| format!("--progress-every {}: expected seconds > 0", args.progress_every))?;
    let (stop, stopped) = std::sync::mpsc::channel::<()>();
    let results = std::thread::scope(|s| {
        if let Some(p) = &plain {
            s.spawn(move || {
                while let Err(std::sync::mpsc::RecvTimeoutError::Timeout) = stopped.recv_timeout(every) {
                    p.line();
                }
            });
        }
        let results = run_shots(&args, &mine, &multi, &overall, plain.as_ref());
        drop(stop);
        results
    })?;
    overall.finish_and_clear();
    finish(&args, (index, count), total_frames, results, started)
}

/// Filters (or skips) this shard's shots in order; the results, as the summary lists them.
fn run_shots(
    args: &BatchArgs,
    mine: &[&Shot],
    multi: &MultiProgress,
    overall: &ProgressBar,
    plain: Option<&PlainProgress>,
) -> anyhow::Result<Vec<ShotResult>> {
    let first_wait = std::time::Duration::try_from_secs_f64(args.retry_delay)
        .with_context(|| format!("--retry-delay {}: expected seconds >= 0", args.retry_delay))?;
    let mut results = Vec::new();
    for shot in mine {
        let shot: &Shot = shot;
        let marker = done_marker(&shot.spec)?;
        let store = storage_for(&shot.spec.output)?;
        let done = match args.force {
            true => None,
            false => store.get(&marker)?,
        };
        if let Some(done) = done {
            let mut r: ShotResult = serde_json::from_slice(&done).with_context(|| {
                format!(
                    "{}: not a done marker; delete it to filter the shot again",
                    marker.display()
                )
            })?;
            match shot_fingerprint(shot) {
                Ok(now) if r.fingerprint.as_deref() == Some(now.as_str()) => {
                    r.status = "skipped".into();
                    overall.inc(shot.frames as u64);
                    results.push(r);
                    continue;
                }
                Ok(_) => multi.suspend(|| {
                    tracing::warn!(
                        "shot {}: finished before, but its filter, parameters, inputs or build changed since ({}); filtering it again",
                        shot.spec.name,
                        marker.display()
                    )
                }),
                Err(e) => multi.suspend(|| {
                    tracing::warn!(
                        "shot {}: cannot tell whether it changed since it finished ({e:#}); filtering it again",
                        shot.spec.name
                    )
                }),
            }
            store.delete(&marker)?;
        }
        if args.force {
            checkpoints(&shot.spec, args.checkpoint_every)?.clear(&*store)?;
        }
        let bar = multi.insert_before(
            overall,
            ProgressBar::new(shot.frames as u64).with_style(
                ProgressStyle::with_template("{msg:>12} [{bar:30}] {pos}/{len} frames, {eta} left")?
                    .progress_chars("=> "),
            ),
        );
        bar.set_message(shot.spec.name.clone());
        if let Some(p) = plain {
            *p.current.lock().unwrap_or_else(|p| p.into_inner()) =
                Some((shot.spec.name.clone(), bar.clone()));
        }
        let (outcome, attempts) = with_retries(
            shot_backoff(first_wait, args.retries),
            std::thread::sleep,
            |_| {
                bar.reset();
                run_one(shot, &bar, args.checkpoint_every)
            },
            |e, attempt, wait| {
                multi.suspend(|| {
                    tracing::warn!(
                        "shot {} failed (attempt {attempt}): {e:#}; trying again in {:.1} s",
                        shot.spec.name,
                        wait.as_secs_f64()
                    )
                })
            },
        );
        let result = match outcome {
            Ok(mut r) => {
                r.attempts = attempts;
                write_atomic(&marker, &serde_json::to_string_pretty(&r)?)?;
                checkpoints(&shot.spec, args.checkpoint_every)?.clear(&*store)?;
                r
            }
            Err(e) => {
                if let (Some(why), true) = (permanent(&e), attempts <= args.retries) {
                    multi.suspend(|| {
                        tracing::warn!("shot {} failed: {e:#}; not retried: {why}", shot.spec.name)
                    });
                }
                ShotResult {
                    name: shot.spec.name.clone(),
                    input: shot.spec.input.clone(),
                    output: shot.spec.output.clone(),
                    frames: shot.frames,
                    status: "failed".into(),
                    attempts,
                    ms_per_frame: None,
                    mean_psnr: None,
                    trmse: None,
                    error: Some(format!("{e:#}")),
                    fingerprint: None,
                }
            }
        };
        if let Some(p) = plain {
            p.line();
            p.filtered
                .fetch_add(bar.position(), std::sync::atomic::Ordering::Relaxed);
            *p.current.lock().unwrap_or_else(|p| p.into_inner()) = None;
        }
        bar.finish_and_clear();
        multi.remove(&bar);
        overall.inc(shot.frames as u64);
        results.push(result);
    }
    Ok(results)
}

/// Writes the summary (JSON and markdown) of `results` and prints its totals; an error when
/// a shot failed.
fn finish(
    args: &BatchArgs,
    (index, count): (usize, usize),
    total_frames: usize,
    results: Vec<ShotResult>,
    started: Instant,
) -> anyhow::Result<()> {
    let failed = results.iter().filter(|r| r.status == "failed").count();
    let summary_path = args.summary.clone().unwrap_or_else(|| {
        PathBuf::from(if count == 1 {
            "batch-summary.json".to_string()
        } else {
            format!("batch-summary-shard-{index}-of-{count}.json")
        })
    });
    let doc = serde_json::json!({
        "shard": {"index": index, "count": count},
        "shots": results,
        "frames": total_frames,
        "wall_s": started.elapsed().as_secs_f64(),
        "failed": failed,
    });
    write_atomic(&summary_path, &serde_json::to_string_pretty(&doc)?)?;
    let mut md = format!(
        "# afterimage batch, shard {index}/{count}\n\n| shot | status | frames | ms/frame | PSNR dB | tRMSE | error |\n|---|---|---:|---:|---:|---:|---|\n"
    );
    let opt = |v: Option<f64>, p: usize| v.map_or("-".to_string(), |x| format!("{x:.p$}"));
    for r in &results {
        md += &format!(
            "| {} | {} | {} | {} | {} | {} | {} |\n",
            r.name,
            r.status,
            r.frames,
            opt(r.ms_per_frame, 2),
            opt(r.mean_psnr, 3),
            opt(r.trmse, 6),
            r.error
                .as_deref()
                .unwrap_or("")
                .replace('|', "\\|")
                .replace('\n', " ")
        );
    }
    write_atomic(&summary_path.with_extension("md"), &md)?;
    outln!(
        "shard {index}/{count}: {} shots ({} done, {} skipped, {failed} failed), {total_frames} frames in {:.1} s -> {}",
        results.len(),
        results.iter().filter(|r| r.status == "done").count(),
        results.iter().filter(|r| r.status == "skipped").count(),
        started.elapsed().as_secs_f64(),
        summary_path.display()
    );
    for r in results.iter().filter(|r| r.status == "failed") {
        outln!("  {} failed: {}", r.name, r.error.as_deref().unwrap_or("-"));
    }
    if failed > 0 {
        anyhow::bail!(
            "{failed} of {} shots failed (see {})",
            results.len(),
            summary_path.display()
        );
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::{Arc, Mutex};
    use std::time::Duration;

    /// A fake shot that fails `fails` times with `error` and then succeeds: the attempts
    /// it was given, and the waits slept between them (recorded, not slept).
    fn retried(
        retries: u32,
        fails: u32,
        error: fn() -> anyhow::Error,
    ) -> (anyhow::Result<u32>, u32, Vec<u32>, Vec<Duration>) {
        let slept = Arc::new(Mutex::new(Vec::new()));
        let record = slept.clone();
        let mut told = Vec::new();
        let (result, attempts) = with_retries(
            shot_backoff(Duration::from_millis(100), retries),
            move |d| record.lock().unwrap().push(d),
            |n| match n <= fails {
                true => Err(error()),
                false => Ok(n),
            },
            |_, n, _| told.push(n),
        );
        let slept = slept.lock().unwrap().clone();
        (result, attempts, told, slept)
    }

    /// A transient failure is retried after waits that grow (jitter adds at most as much
    /// again, doubling still outgrows it), until it succeeds or the retries run out.
    #[test]
    fn failed_shots_are_retried_after_growing_waits() {
        let transient = || anyhow::anyhow!("s3://b/x: connection reset");
        let (r, attempts, told, slept) = retried(4, 3, transient);
        assert_eq!((r.unwrap(), attempts, told), (4, 4, vec![1, 2, 3]));
        assert_eq!(slept.len(), 3);
        assert!(
            slept[0] >= Duration::from_millis(100) && slept[0] < Duration::from_millis(200),
            "{slept:?}"
        );
        assert!(slept.windows(2).all(|w| w[1] > w[0]), "the waits grow: {slept:?}");
        let (r, attempts, _, slept) = retried(2, 5, transient);
        assert!(r.unwrap_err().to_string().contains("connection reset"));
        assert_eq!((attempts, slept.len()), (3, 2));
        let (r, attempts, _, slept) = retried(0, 1, transient);
        assert_eq!((r.is_err(), attempts, slept.len()), (true, 1, 0));
    }

    /// Not found, not allowed (as the object store's refusals say no credentials or access
    /// denied), a wrong filter parameter and an input that never opened fail at once.
    #[test]
    fn permanent_failures_are_not_retried() {
        use std::io::{Error, ErrorKind};
        fn os(kind: ErrorKind) -> anyhow::Error {
            let io = afterimage::io::IoError::os(Path::new("s3://b/x.exr"), Error::new(kind, "refused"));
            anyhow::Error::new(io).context("reading shot sh010")
        }
        let cases: [fn() -> anyhow::Error; 5] = [
            || os(ErrorKind::NotFound),
            || os(ErrorKind::PermissionDenied),
            || {
                let e = afterimage::backend::create(
                    "taa",
                    &[("alpha".to_string(), 9.0.into())].into_iter().collect(),
                    Default::default(),
                );
                match e {
                    Err(e) => anyhow::Error::new(e),
                    Ok(_) => panic!("alpha = 9 was taken"),
                }
            },
            || NotOpened("in/sh010: no frames".into()).into(),
            || anyhow::Error::new(Error::new(ErrorKind::InvalidInput, "bad")),
        ];
        for case in cases {
            assert!(permanent(&case()).is_some(), "{:#}", case());
            let (r, attempts, told, slept) = retried(3, 10, case);
            assert_eq!((r.is_err(), attempts, told.len(), slept.len()), (true, 1, 0, 0));
        }
        assert_eq!(permanent(&os(ErrorKind::ConnectionReset)), None);
        assert_eq!(permanent(&anyhow::anyhow!("GPU device error")), None);
    }

    #[test]
    fn shots_go_longest_first_to_the_least_loaded_shard() {
        let f = |v: &[(&str, usize)]| v.iter().map(|(n, k)| (n.to_string(), *k)).collect::<Vec<_>>();
        let shots = f(&[("a", 10), ("b", 40), ("c", 30), ("d", 20), ("e", 10)]);
        let owner = assign(&shots, 3);
        // b -> 0, c -> 1, d -> 2, then a and e (10 each, by name) to 2 and 1... by load.
        assert_eq!(owner, vec![2, 0, 1, 2, 1]);
        let load = |s| {
            shots
                .iter()
                .zip(&owner)
                .filter(|(_, &o)| o == s)
                .map(|(x, _)| x.1)
                .sum::<usize>()
        };
        assert_eq!([load(0), load(1), load(2)], [40, 40, 30]);
        assert_eq!(assign(&shots, 1), vec![0; 5]);
    }

    #[test]
    fn shard_flags_are_checked() {
        assert_eq!(shard(Some("1/3")).unwrap(), (1, 3));
        for bad in ["3/3", "x/2", "1", "0/0"] {
            let e = shard(Some(bad)).unwrap_err().to_string();
            assert!(e.contains("INDEX/COUNT"), "{bad}: {e}");
        }
    }
}
