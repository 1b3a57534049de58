//! Filtering one shot: what `afterimage filter` runs, and `afterimage batch` for each shot.
//!
//! - **Streams**: frames are read (and decoded) up to [`READ_AHEAD`] ahead on a thread of
//!   their own, encoded up to [`WRITE_BEHIND`] behind on another, and written (put) on a
//!   third while the next is encoded, so I/O overlaps filtering and encoding; never more
//!   than those few frames are held. Inputs and outputs are
//!   local files or an object store ([`super::store`]), each output whole or not at all.
//! - **Checkpoints** (batch): every N frames, once the outputs before them are written, the
//!   filter's state ([`afterimage::pipeline::state`]), the measurement's last frame pair and
//!   the records so far are saved beside the outputs (`.afterimage-progress/<shot>.*`). A
//!   rerun of the same command continues from the last one and writes what an uninterrupted
//!   run writes, redoing at most N frames. A windowed filter (`pixel_trace`) saves no state:
//!   its state is its window of input frames, so it replays the `lookahead` frames before the
//!   checkpoint and throws their outputs away.

use super::filter::{jitter_table, FilterArgs};
use super::store::storage_for;
use afterimage::frame::{ChannelKind, Frame, FrameMeta, Rgb};
use afterimage::io::{
    encode_filtered_for, refuse_overwrite, write_png, FilteredFrame, InputImage, IoError, OutputNaming,
    OutputOptions, PresetChoice, ReadOptions, Selection, Sequence, Storage,
};
use afterimage::metrics::{Evaluator, FrameMetrics, MetricSpace, SpaceChoice};
use afterimage::pipeline::state::StateKey;
use afterimage::pipeline::{params::parse_assignments, Filter, FilterState, FrameRecord, Output};
use anyhow::Context;
use indicatif::ProgressBar;
use serde::{Deserialize, Serialize};
use serde_json::{json, Value};
use sha2::{Digest, Sha256};
use std::collections::{BTreeMap, HashMap, VecDeque};
use std::path::{Path, PathBuf};
use std::sync::mpsc::{channel, sync_channel, Receiver, Sender, SyncSender};
use std::sync::Arc;

/// Frames read and decoded ahead of the filter.
pub const READ_AHEAD: usize = 2;
/// Filtered frames waiting to be encoded and written.
pub const WRITE_BEHIND: usize = 2;
/// The checkpoint format (the progress file; the state files carry their own version).
const PROGRESS_VERSION: u32 = 1;
/// Largest frame a checkpoint is read for (a 65536 x 32768 frame): any real shot.
const MAX_CHECKPOINT_PIXELS: u64 = 1 << 31;

/// What filtering one sequence gave (`filter` prints it; `batch` summarises it).
pub struct ShotReport {
    /// Where the outputs went (the directory or pattern).
    pub output: String,
    /// The records of the frames this run filtered, in order.
    pub records: Vec<FrameRecord>,
    /// Frames done by an earlier run that this one continued (0 without a checkpoint).
    pub resumed_at: usize,
    /// Quality against the reference, when there was one (over the whole shot).
    pub summary: Option<afterimage::metrics::Summary>,
    /// What the outputs depend on, hashed ([`fingerprint`]).
    pub fingerprint: String,
}

/// The frames `args` selects (`--frames`, `--missing`).
fn selection(args: &FilterArgs) -> Selection {
    Selection {
        range: args.frames,
        missing: args.missing,
    }
}

/// What a shot's outputs depend on, hashed: the build ([`build_id`]), the command's
/// arguments, the filter's parameters (defaults included) and each input file's frame
/// number, name and stamp (size and modification time, see [`Storage::stamps`]). A
/// checkpoint or a done marker of another fingerprint is not continued or trusted.
fn fingerprint_of(
    args: &FilterArgs,
    params: &Value,
    input: &Sequence,
    store: &dyn Storage,
) -> anyhow::Result<String> {
    let mut hash = Sha256::new();
    hash.update(format!("{} {args:?} {params}", build_id()));
    // Each directory's stamps, by file name (a bare pattern's frames are `name`, the
    // listing of the current directory `./name`).
    let mut dirs: HashMap<PathBuf, HashMap<std::ffi::OsString, String>> = HashMap::new();
    for e in &input.entries {
        let file = e.source();
        let dir = file.parent().unwrap_or(Path::new(""));
        if !dirs.contains_key(dir) {
            let stamps = store
                .stamps(dir)?
                .into_iter()
                .filter_map(|(p, stamp)| Some((p.file_name()?.to_os_string(), stamp)))
                .collect();
            dirs.insert(dir.to_path_buf(), stamps);
        }
        let stamp = file
            .file_name()
            .and_then(|n| dirs[dir].get(n))
            .with_context(|| format!("{}: the input frame is gone", file.display()))?;
        hash.update(format!("\n{} {} {stamp}", e.number, file.display()));
    }
    Ok(format!("{:x}", hash.finalize()))
}

/// The fingerprint (see [`fingerprint_of`]) of the shot `args` describes, without filtering
/// it: what `batch` compares with a finished shot's done marker.
pub fn fingerprint(args: &FilterArgs) -> anyhow::Result<String> {
    let params = afterimage::filters::create(&args.filter, &parse_assignments(&args.set)?)?.params();
    let store = storage_for(&args.input)?;
    let input = Sequence::open_in_selected(&args.input, &*store, &selection(args))?;
    fingerprint_of(args, &params, &input, &*store)
}

/// Where and how often a shot is checkpointed (see the module).
pub struct Checkpoints {
    /// Every checkpoint file's name starts with this (`<dir>/.afterimage-progress/<shot>`).
    pub base: PathBuf,
    /// Frames between checkpoints; 0 saves none.
    pub every: usize,
}

impl Checkpoints {
    fn file(&self, suffix: &str) -> PathBuf {
        let mut name = self.base.file_name().unwrap_or_default().to_os_string();
        name.push(suffix);
        self.base.with_file_name(name)
    }

    fn progress_path(&self) -> PathBuf {
        self.file(".progress.json")
    }

    fn state_path(&self, next: usize, what: &str) -> PathBuf {
        self.file(&format!(".{next}.{what}.state"))
    }

    /// Whether `name` is one of this shot's state files (`<shot>.<N>.<what>.state`): what a
    /// progress file names is checked against it before it is read or deleted.
    fn is_state_file(&self, name: &str) -> bool {
        let shot = self.base.file_name().unwrap_or_default().to_string_lossy();
        name.strip_prefix(&*shot)
            .and_then(|rest| rest.strip_prefix('.'))
            .is_some_and(|rest| rest.ends_with(".state") && !rest.contains(['/', '\\']))
    }

    /// Removes the shot's checkpoint files (once its outputs and records are all written, or
    /// when a checkpoint is not continued): its state files, then its progress file.
    pub fn clear(&self, storage: &dyn Storage) -> anyhow::Result<()> {
        let dir = self.base.parent().unwrap_or(Path::new(""));
        let listed = match storage.list(dir) {
            Ok(files) => files,
            Err(_) if storage.is_local() && !dir.exists() => Vec::new(),
            Err(e) => return Err(e.into()),
        };
        for path in listed {
            if path
                .file_name()
                .is_some_and(|n| self.is_state_file(&n.to_string_lossy()))
            {
                storage.delete(&path)?;
            }
        }
        storage.delete(&self.progress_path())?;
        Ok(())
    }
}

/// The progress file: where a shot stopped, and what it needs to continue.
#[derive(Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct Progress {
    version: u32,
    /// Hash of the build ([`build_id`]), the command's arguments and the filter's
    /// parameters: a checkpoint of anything else is not continued.
    fingerprint: String,
    /// Position in the sequence of the first frame whose output is not written yet.
    next: usize,
    /// Its frame number (for people reading the file).
    frame: u64,
    /// The filter's state file (none for a windowed filter).
    state: Option<String>,
    /// The measurement's last output and reference, as a state file.
    metrics_state: Option<String>,
    space: Option<MetricSpace>,
    records: Vec<Value>,
    /// The figures so far, as the bits of their values (JSON has no infinite PSNR).
    metrics: Vec<MetricBits>,
}

/// A frame's figures, losslessly: the index, then mse, rmse, psnr, ssim and temporal mse
/// (absent: `None`) as `f64::to_bits`.
#[derive(Serialize, Deserialize)]
struct MetricBits(u64, [u64; 4], Option<u64>);

impl From<&FrameMetrics> for MetricBits {
    fn from(m: &FrameMetrics) -> Self {
        MetricBits(
            m.index,
            [m.mse, m.rmse, m.psnr, m.ssim].map(f64::to_bits),
            m.temporal_mse.map(f64::to_bits),
        )
    }
}

impl From<&MetricBits> for FrameMetrics {
    fn from(b: &MetricBits) -> Self {
        let [mse, rmse, psnr, ssim] = b.1.map(f64::from_bits);
        FrameMetrics {
            index: b.0,
            mse,
            rmse,
            psnr,
            ssim,
            temporal_mse: b.2.map(f64::from_bits),
        }
    }
}

/// What the output of a pushed frame needs when it comes out.
struct Pending {
    position: usize,
    number: u64,
    path: PathBuf,
    meta: FrameMeta,
    reference: Option<Rgb>,
    hdr: bool,
    input: InputImage,
}

/// Work for the writer thread, in order.
enum Job {
    Frame(Box<FrameJob>),
    Checkpoint {
        files: Vec<(PathBuf, Vec<u8>)>,
        progress: PathBuf,
        text: Vec<u8>,
        stale: Vec<PathBuf>,
    },
}

/// Work for the uploader thread, in order: a file or object to put (a frame's counts on
/// the progress bar), or one to delete.
enum Put {
    File {
        path: PathBuf,
        bytes: Vec<u8>,
        frame: bool,
    },
    Delete(PathBuf),
}

/// A filtered frame for the writer.
struct FrameJob {
    path: PathBuf,
    color: Rgb,
    meta: FrameMeta,
    record: String,
    input: InputImage,
    png: Option<(PathBuf, bool)>,
}

/// Where a run starts: the first position to write, and what was measured before it.
struct Start {
    next: usize,
    records: Vec<Value>,
    eval: Evaluator,
    files: Vec<PathBuf>,
}

/// The metric evaluator's last output and reference as a state file's planes.
fn pair_state(pair: &(Rgb, Rgb)) -> FilterState {
    let mut st = FilterState::empty("metrics", Value::Null);
    st.size = Some(pair.0[0].size());
    st.components = vec![1; 6];
    st.planes = pair.0.iter().chain(&pair.1).cloned().collect();
    st
}

fn state_pair(st: FilterState) -> anyhow::Result<(Rgb, Rgb)> {
    anyhow::ensure!(
        st.filter == "metrics" && st.planes.len() == 6,
        "not a metrics state"
    );
    let mut p = st.planes.into_iter();
    let mut three = || -> Rgb { std::array::from_fn(|_| p.next().expect("six planes")) };
    let out = three();
    Ok((out, three()))
}

/// The checkpoint to continue from, with the filter loaded; `None` (start from the first
/// frame) when there is none, or when it is another run's or damaged (said in a warning).
fn resume(
    c: &Checkpoints,
    storage: &dyn Storage,
    fingerprint: &str,
    filter: &mut dyn Filter,
    frames: usize,
) -> anyhow::Result<Option<Start>> {
    let path = c.progress_path();
    let Some(bytes) = storage.get(&path)? else {
        return Ok(None);
    };
    let mut load = || -> anyhow::Result<Start> {
        let p: Progress = serde_json::from_slice(&bytes).context("not a progress file")?;
        anyhow::ensure!(p.version == PROGRESS_VERSION, "progress format {}", p.version);
        anyhow::ensure!(
            p.fingerprint == fingerprint,
            "it was written by another command or build"
        );
        anyhow::ensure!(p.next <= frames, "frame {} of {frames}", p.next);
        let mut files = Vec::new();
        let mut read_state = |name: &str| -> anyhow::Result<FilterState> {
            anyhow::ensure!(
                c.is_state_file(name),
                "{name:?} is not one of the shot's state files"
            );
            let path = c.base.with_file_name(name);
            let bytes = storage
                .get(&path)?
                .with_context(|| format!("{} is missing", path.display()))?;
            files.push(path);
            // Checkpoints may sit on shared storage: signed and checked when a key is set.
            let key = StateKey::from_env();
            Ok(FilterState::decode_with(
                &bytes,
                MAX_CHECKPOINT_PIXELS,
                key.as_ref(),
            )?)
        };
        match &p.state {
            Some(name) => filter.load_state(&read_state(name)?)?,
            None => anyhow::ensure!(filter.lookahead() > 0 || p.next == 0, "it has no filter state"),
        }
        let pair = p.metrics_state.as_deref().map(&mut read_state).transpose()?;
        let pair = pair.map(state_pair).transpose()?;
        Ok(Start {
            next: p.next,
            eval: Evaluator::resumed(
                SpaceChoice::Auto,
                p.space,
                pair,
                p.metrics.iter().map(Into::into).collect(),
            ),
            records: p.records,
            files,
        })
    };
    match load() {
        Ok(s) => Ok(Some(s)),
        Err(e) => {
            filter.reset();
            tracing::warn!(
                "{}: not continuing from this checkpoint ({e:#}); filtering the shot from its first frame",
                path.display()
            );
            Ok(None)
        }
    }
}

/// A shot's inputs, outputs and settings, checked before any frame is read.
struct ShotPlan {
    in_store: Arc<dyn Storage>,
    out_store: Arc<dyn Storage>,
    in_opts: ReadOptions,
    input: Sequence,
    /// The reference sequence, with its store, and how to read it.
    reference: Option<(Sequence, Arc<dyn Storage>)>,
    ref_opts: ReadOptions,
    jitter: Option<BTreeMap<u64, [f32; 2]>>,
    required: Vec<ChannelKind>,
    naming: OutputNaming,
    write: OutputOptions,
}

/// Opens the input (and reference) sequences and checks every argument against them:
/// `--cuts` frames exist, outputs overwrite no input, `--png` goes to local files. Creates
/// the output directory.
fn plan_shot(args: &FilterArgs) -> anyhow::Result<ShotPlan> {
    let in_opts = args.read.options()?;
    let in_store = storage_for(&args.input)?;
    let out_store = storage_for(&args.output)?;
    let selection = selection(args);
    let input = Sequence::open_in_selected(&args.input, &*in_store, &selection)?;
    let reference = match &args.reference {
        Some(spec) => {
            let store = storage_for(spec)?;
            let seq = Sequence::open_in_selected(spec, &*store, &selection)?;
            if seq.len() != input.len() {
                anyhow::bail!(
                    "{} has {} frames but the reference {} has {}",
                    input.spec,
                    input.len(),
                    seq.spec,
                    seq.len()
                );
            }
            Some((seq, store))
        }
        None => None,
    };
    let ref_opts = ReadOptions {
        preset: args.reference_preset.parse::<PresetChoice>()?,
        ..ReadOptions::default()
    };
    if let Some(missing) = args
        .cuts
        .iter()
        .find(|&&c| !input.entries.iter().any(|e| e.number == c))
    {
        let (first, last) = (input.entries[0].number, input.entries[input.len() - 1].number);
        anyhow::bail!("--cuts {missing}: the input has no frame {missing} (its frames are {first}-{last})");
    }
    let jitter = match &args.jitter_from {
        Some(spec) => Some(jitter_table(spec, &input)?),
        None => None,
    };
    let required = required_channels(&args.require)?;
    let naming = OutputNaming::parse_for(&args.output, input.len())?;
    let mut write = args.write.options()?;
    if args.f16 {
        write.precision = Some(afterimage::io::Precision::F16);
    }
    let first = &input.entries[0];
    let format = afterimage::io::OutputFormat::of(&naming.path(&first.path, first.number))?;
    if format != afterimage::io::OutputFormat::Exr {
        let exr_only = [
            (write.compression.is_some(), "--compression"),
            (write.precision.is_some(), "--half/--float"),
            (write.keep != afterimage::io::Keep::default(), "--keep"),
        ];
        for (_, flag) in exr_only.iter().filter(|(given, _)| *given) {
            tracing::warn!("{flag} applies to EXR outputs only; {naming} is {format:?}: ignored");
        }
    }
    if args.png && !out_store.is_local() {
        anyhow::bail!(
            "--png writes previews to local files only; the output {} is in an object store",
            args.output
        );
    }
    let mut outputs: Vec<PathBuf> = input
        .entries
        .iter()
        .map(|e| naming.path(&e.path, e.number))
        .collect();
    if args.png {
        outputs.extend(
            input
                .entries
                .iter()
                .map(|e| naming.preview_path(&e.path, e.number)),
        );
    }
    let inputs: Vec<PathBuf> = input.entries.iter().map(|e| e.source().to_path_buf()).collect();
    refuse_overwrite(&outputs, &inputs)?;
    if out_store.is_local() {
        let dir = naming.dir();
        std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    }
    Ok(ShotPlan {
        in_store,
        out_store,
        in_opts,
        input,
        reference,
        ref_opts,
        jitter,
        required,
        naming,
        write,
    })
}

/// Filters the sequence `args` names and writes its outputs and records (see the module);
/// `bar` counts the frames written (its length is set here). With `checkpoints`, continues
/// from the last checkpoint of the same command and saves new ones.
pub fn run_shot(
    args: &FilterArgs,
    bar: &ProgressBar,
    checkpoints: Option<&Checkpoints>,
) -> anyhow::Result<ShotReport> {
    let values = parse_assignments(&args.set)?;
    let made = afterimage::backend::create(&args.filter, &values, args.backend)?;
    if made.backend != afterimage::backend::Backend::Cpu || args.backend != Default::default() {
        tracing::info!(filter = %args.filter, backend = %made.backend, "filter backend");
    }
    let mut filter = made.filter;
    let plan = plan_shot(args)?;
    let (input, naming) = (&plan.input, &plan.naming);
    let fingerprint = fingerprint_of(args, &filter.params(), input, &*plan.in_store)?;
    let start = match checkpoints {
        Some(c) => resume(c, &*plan.out_store, &fingerprint, filter.as_mut(), input.len())?,
        None => None,
    };
    let start = start.unwrap_or_else(|| Start {
        next: 0,
        records: Vec::new(),
        eval: Evaluator::new(SpaceChoice::Auto),
        files: Vec::new(),
    });
    let resumed_at = start.next;
    // A windowed filter's outputs from `next` on need the `lookahead` frames before it.
    let feed = start.next.saturating_sub(filter.lookahead());
    bar.set_length(input.len() as u64);
    bar.set_position(start.next as u64);
    let mut shot = Emitter {
        naming,
        png: args.png,
        eval: start.eval,
        earlier: start.records,
        records: Vec::new(),
        pending: VecDeque::new(),
        next: start.next,
        frames: input,
        checkpoints,
        fingerprint: &fingerprint,
        last_files: start.files,
    };
    std::thread::scope(|s| -> anyhow::Result<()> {
        let (read_tx, read_rx) = sync_channel(READ_AHEAD);
        let (jobs, job_rx) = sync_channel::<Job>(WRITE_BEHIND);
        let (back_tx, back_rx) = channel::<Rgb>();
        let (puts, put_rx) = sync_channel::<Put>(1);
        let plan = &plan;
        s.spawn(move || read_frames(plan, feed, read_tx));
        // Writes and deletes, in order, on a thread of their own: an object store's put
        // waits on the network, and the encoder goes on meanwhile.
        let uploader = s.spawn(move || upload(&*plan.out_store, put_rx, bar));
        let writer = s.spawn(move || encode(&plan.write, job_rx, back_tx, puts));
        let filtered = filter_frames(
            args,
            plan,
            feed,
            filter.as_mut(),
            &mut shot,
            read_rx,
            back_rx,
            &jobs,
        );
        drop(jobs);
        let written = writer
            .join()
            .map_err(|_| anyhow::anyhow!("the writer thread panicked"))?;
        let uploaded = uploader
            .join()
            .map_err(|_| anyhow::anyhow!("the uploader thread panicked"))?;
        // A later stage's error explains a failed hand-over to it; otherwise the filter's
        // stands.
        uploaded.and(written).and(filtered)
    })?;
    let summary = shot.eval.summary();
    let frames = shot.all_records()?;
    let doc = json!({
        "filter": args.filter,
        "params": filter.params(),
        "input": args.input,
        "frames": frames,
        "metrics": shot.eval.frames,
        "summary": summary,
    });
    let path = args
        .records
        .clone()
        .unwrap_or_else(|| naming.dir().join("records.json"));
    plan.out_store
        .put(&path, serde_json::to_string_pretty(&doc)?.as_bytes())
        .with_context(|| format!("writing {}", path.display()))?;
    Ok(ShotReport {
        output: naming.to_string(),
        records: shot.records,
        resumed_at,
        summary,
        fingerprint,
    })
}

/// A frame as read: the decoded frame and its file, and the reference colour when a
/// reference sequence is given.
type ReadItem = (Result<(Frame, InputImage), IoError>, Option<Result<Rgb, IoError>>);

/// The reader thread: decodes the input (and reference) frames from position `feed` on.
fn read_frames(plan: &ShotPlan, feed: usize, out: SyncSender<ReadItem>) {
    let given = |n: u64| plan.jitter.as_ref().and_then(|t| t.get(&n).copied());
    let mut refs = plan
        .reference
        .as_ref()
        .map(|(seq, store)| seq.inputs_in(&**store, &plan.ref_opts, |_| None, feed));
    for item in plan.input.inputs_in(&*plan.in_store, &plan.in_opts, given, feed) {
        let r = refs
            .as_mut()
            .map(|it| it.next().expect("same length").map(|(f, _)| f.color().clone()));
        if out.send((item, r)).is_err() {
            break;
        }
    }
}

/// The uploader thread: puts and deletes files in order; a frame's put counts on `bar`.
fn upload(store: &dyn Storage, puts: Receiver<Put>, bar: &ProgressBar) -> anyhow::Result<()> {
    for put in puts {
        match put {
            Put::File { path, bytes, frame } => {
                store.put(&path, &bytes)?;
                if frame {
                    bar.inc(1);
                }
            }
            Put::Delete(path) => store.delete(&path)?,
        }
    }
    Ok(())
}

/// The writer thread: encodes each filtered frame (and its PNG preview), hands its colour
/// planes back for reuse, and passes frames and checkpoints to the uploader in order.
fn encode(
    write: &OutputOptions,
    jobs: Receiver<Job>,
    back: Sender<Rgb>,
    puts: SyncSender<Put>,
) -> anyhow::Result<()> {
    let put = |p: Put| puts.send(p).map_err(|_| anyhow::anyhow!("the uploader stopped"));
    for job in jobs {
        match job {
            Job::Frame(job) => {
                let FrameJob {
                    path,
                    color,
                    meta,
                    record,
                    input,
                    png,
                } = *job;
                let frame = FilteredFrame {
                    color: &color,
                    meta: &meta,
                    record: Some(&record),
                    input: Some(&input),
                };
                let bytes = encode_filtered_for(&path, &frame, write)
                    .with_context(|| format!("writing {}", path.display()))?;
                if let Some((png, hdr)) = png {
                    write_png(&png, &color, hdr)?;
                }
                back.send(color).ok();
                put(Put::File {
                    path,
                    bytes,
                    frame: true,
                })?;
            }
            Job::Checkpoint {
                files,
                progress,
                text,
                stale,
            } => {
                for (path, bytes) in files {
                    put(Put::File {
                        path,
                        bytes,
                        frame: false,
                    })?;
                }
                put(Put::File {
                    path: progress,
                    bytes: text,
                    frame: false,
                })?;
                for path in stale {
                    put(Put::Delete(path))?;
                }
            }
        }
    }
    Ok(())
}

/// The main thread: pushes each frame read (from position `feed`) through the filter,
/// after `--require` and `--cuts`, and emits its outputs to the writer through `jobs`.
#[allow(clippy::too_many_arguments)]
fn filter_frames(
    args: &FilterArgs,
    plan: &ShotPlan,
    feed: usize,
    filter: &mut dyn Filter,
    shot: &mut Emitter<'_>,
    read: Receiver<ReadItem>,
    back: Receiver<Rgb>,
    jobs: &SyncSender<Job>,
) -> anyhow::Result<()> {
    let input = &plan.input;
    let mut fed = feed;
    for (position, (item, reference)) in (feed..).zip(read) {
        fed = position + 1;
        while let Ok(planes) = back.try_recv() {
            filter.recycle(planes);
        }
        let entry = &input.entries[position];
        let (mut frame, mut kept) = item?;
        if let Some(k) = plan.required.iter().find(|k| !frame.channels().contains(**k)) {
            anyhow::bail!(
                "{}: no {k} channel, which --require {} asks for (the frame has {})",
                entry.path.display(),
                args.require.join(","),
                frame.channels()
            );
        }
        kept.trim_to(plan.write.keep);
        if args.cuts.contains(&entry.number) {
            frame.meta.reset = true;
        }
        let reference = match reference {
            Some(r) => Some(r?),
            None => frame.reference().cloned(),
        };
        shot.pending.push_back(Pending {
            position,
            number: entry.number,
            path: entry.path.clone(),
            meta: frame.meta.clone(),
            reference,
            hdr: frame_is_hdr(&frame),
            input: kept,
        });
        // A checkpoint after the frame before holds the filter's state then: nothing of
        // this frame may be started yet.
        if shot.checkpoint_at(position) {
            for out in filter
                .flush_overlapped()
                .context("finishing the frames in flight")?
            {
                shot.emit(out, filter, jobs)?;
            }
        }
        // Overlapped: a GPU filter works on this frame while the host reads the next.
        let outs = filter
            .push_overlapped(&frame)
            .with_context(|| format!("filtering {}", entry.path.display()))?;
        for out in outs {
            shot.emit(out, filter, jobs)?;
        }
    }
    // The reader stops early only by panicking: never flush a window cut short.
    anyhow::ensure!(
        fed == input.len(),
        "reading stopped after frame {fed} of {}",
        input.len()
    );
    for out in filter
        .flush_overlapped()
        .context("finishing the frames in flight")?
    {
        shot.emit(out, filter, jobs)?;
    }
    for out in filter.finish().context("flushing the filter's window")? {
        shot.emit(out, filter, jobs)?;
    }
    Ok(())
}

/// The main thread's side of a shot: measures each output, hands it to the writer, and
/// queues checkpoints behind the outputs they cover.
struct Emitter<'a> {
    naming: &'a OutputNaming,
    png: bool,
    eval: Evaluator,
    earlier: Vec<Value>,
    records: Vec<FrameRecord>,
    pending: VecDeque<Pending>,
    /// Outputs before this position were written by an earlier run.
    next: usize,
    frames: &'a Sequence,
    checkpoints: Option<&'a Checkpoints>,
    fingerprint: &'a str,
    /// The files of the last checkpoint, removed once the next is in place.
    last_files: Vec<PathBuf>,
}

impl Emitter<'_> {
    /// Every frame's record so far: an earlier run's, then this run's.
    fn all_records(&self) -> serde_json::Result<Vec<Value>> {
        let mut all = self.earlier.clone();
        for r in &self.records {
            all.push(serde_json::to_value(r)?);
        }
        Ok(all)
    }

    /// Measures `out` and hands it to the writer through `jobs` (owned by the caller, so
    /// that a panic here drops it and the writer ends instead of waiting forever).
    fn emit(&mut self, out: Output, filter: &mut dyn Filter, jobs: &SyncSender<Job>) -> anyhow::Result<()> {
        let send = |job: Job| jobs.send(job).map_err(|_| anyhow::anyhow!("the writer stopped"));
        let p = self.pending.pop_front().expect("one output per frame pushed");
        if p.position < self.next {
            // A frame a windowed filter replays to fill its window: written before.
            filter.recycle(out.color);
            return Ok(());
        }
        if let Some(r) = &p.reference {
            self.eval
                .push(p.number, &out.color, r, p.meta.reset)
                .with_context(|| format!("measuring frame {} against its reference", p.number))?;
        }
        // Timings stay in the records file: the output's bytes depend on its input alone.
        let record = serde_json::to_string(&out.record.without_timings())?;
        self.records.push(out.record);
        send(Job::Frame(Box::new(FrameJob {
            path: self.naming.path(&p.path, p.number),
            color: out.color,
            meta: p.meta,
            record,
            input: p.input,
            png: self
                .png
                .then(|| (self.naming.preview_path(&p.path, p.number), p.hdr)),
        })))?;
        let done = p.position + 1;
        if let (Some(c), true) = (self.checkpoints, self.checkpoint_at(done)) {
            send(self.checkpoint(c, done, filter)?)?;
        }
        Ok(())
    }

    /// Whether a checkpoint is written once the outputs before position `next` are.
    fn checkpoint_at(&self, next: usize) -> bool {
        self.checkpoints
            .is_some_and(|c| c.every > 0 && next.is_multiple_of(c.every) && next < self.frames.len())
    }

    /// The checkpoint at position `next`, for the writer to write once every output before
    /// it (queued already) is written.
    fn checkpoint(&mut self, c: &Checkpoints, next: usize, filter: &dyn Filter) -> anyhow::Result<Job> {
        let mut files = Vec::new();
        let key = StateKey::from_env();
        let name = |p: &Path| p.file_name().map(|n| n.to_string_lossy().into_owned());
        let state = if filter.lookahead() == 0 {
            let path = c.state_path(next, "filter");
            files.push((path.clone(), filter.save_state()?.encode_with(key.as_ref())));
            name(&path)
        } else {
            None
        };
        let metrics_state = match self.eval.last_pair() {
            Some(pair) => {
                let path = c.state_path(next, "metrics");
                files.push((path.clone(), pair_state(pair).encode_with(key.as_ref())));
                name(&path)
            }
            None => None,
        };
        let records = self.all_records()?;
        let progress = Progress {
            version: PROGRESS_VERSION,
            fingerprint: self.fingerprint.to_string(),
            next,
            frame: self.frames.entries[next].number,
            state,
            metrics_state,
            space: self.eval.space(),
            records,
            metrics: self.eval.frames.iter().map(Into::into).collect(),
        };
        let paths: Vec<PathBuf> = files.iter().map(|(p, _)| p.clone()).collect();
        let stale = std::mem::replace(&mut self.last_files, paths);
        Ok(Job::Checkpoint {
            files,
            progress: c.progress_path(),
            text: serde_json::to_vec(&progress)?,
            stale,
        })
    }
}

/// This build: the version and the executable's size and modification time, so that a
/// rebuilt binary (whose filters may compute otherwise) does not continue another's
/// checkpoint.
fn build_id() -> String {
    let exe = std::env::current_exe().and_then(std::fs::metadata);
    let stamp = exe
        .map(|m| {
            let t = m
                .modified()
                .ok()
                .and_then(|t| t.duration_since(std::time::UNIX_EPOCH).ok());
            format!("{} {:?}", m.len(), t)
        })
        .unwrap_or_default();
    format!("{} {stamp}", env!("CARGO_PKG_VERSION"))
}

/// The channels `--require` names.
fn required_channels(names: &[String]) -> anyhow::Result<Vec<ChannelKind>> {
    names
        .iter()
        .map(|n| {
            ChannelKind::from_name(n.trim()).with_context(|| {
                let known: Vec<&str> = ChannelKind::ALL.iter().map(|k| k.name()).collect();
                format!(
                    "--require {n:?}: not a channel; expected one of {}",
                    known.join(", ")
                )
            })
        })
        .collect()
}

fn frame_is_hdr(f: &Frame) -> bool {
    f.color().iter().any(|p| p.data().iter().any(|&v| v > 1.0))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The figures go through a progress file exactly, an infinite PSNR (a perfect frame)
    /// and an absent temporal error included.
    #[test]
    fn metrics_survive_a_progress_file_bit_for_bit() {
        let m = FrameMetrics {
            index: 7,
            mse: 0.0,
            rmse: 0.0,
            psnr: f64::INFINITY,
            ssim: 0.1 + 0.2,
            temporal_mse: None,
        };
        let n = FrameMetrics {
            temporal_mse: Some(1e-300),
            psnr: 31.000000000000004,
            ..m.clone()
        };
        for x in [m, n] {
            let text = serde_json::to_string(&MetricBits::from(&x)).unwrap();
            let back: MetricBits = serde_json::from_str(&text).unwrap();
            let y = FrameMetrics::from(&back);
            assert_eq!(format!("{x:?}"), format!("{y:?}"));
            assert_eq!(x.psnr.to_bits(), y.psnr.to_bits());
        }
    }

    #[test]
    fn only_the_shots_own_state_files_are_named() {
        let c = Checkpoints {
            base: PathBuf::from("out/.afterimage-progress/sh010"),
            every: 4,
        };
        assert!(c.is_state_file("sh010.16.filter.state"));
        assert_eq!(
            c.state_path(16, "filter"),
            PathBuf::from("out/.afterimage-progress/sh010.16.filter.state")
        );
        for bad in [
            "sh020.16.filter.state",
            "sh010.16.filter.json",
            "sh010/../../x.state",
            "../sh010.1.state",
            "sh0101.state",
        ] {
            assert!(!c.is_state_file(bad), "{bad}");
        }
    }
}
