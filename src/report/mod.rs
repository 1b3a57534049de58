//! `afterimage report`: every filter on every scene, quality next to run time.
//!
//! [`run`] renders the catalogue scenes in process, runs each filter over each scene and
//! measures, per filter and scene, mean PSNR and SSIM against the supersampled reference,
//! tRMSE, ms/frame (median and p95, total and per stage), state bytes per megapixel and
//! the ratio of ms/frame to the filter's memory floor (`floor.rs`). An optional timing
//! section runs every filter on a synthetic full-size G-buffer ([`synthetic_frame`]),
//! since rendering 1080p scenes would take far longer than filtering them.
//! [`markdown`], [`csv`] and [`write_plots`] turn the result into a table, a CSV and
//! plots; the JSON is the [`Report`] itself.
//!
//! Everything but the times is deterministic: scenes are seeded, filters are pure
//! functions of their input and state.

mod floor;
mod plot;
mod table;

pub use crate::scene::{synthetic_frame, synthetic_sparse_frame};
pub use floor::{
    bytes_per_frame, bytes_per_pixel, measure_copy_bandwidth, parallel_copy, Bandwidth, COPY_BYTES,
};
pub use plot::write_plots;
pub use table::{csv, markdown};

use crate::backend::BackendChoice;
use crate::filters;
use crate::frame::{ChannelKind, ChannelSet, Frame, Rgb, Sampling};
use crate::io::{IoError, ReadOptions, Sequence};
use crate::metrics::{Evaluator, MetricSpace, MetricsError, SpaceChoice, Timing};
use crate::pipeline::{params::parse_assignments, summarize_stages, FilterError, FrameRecord, StageSummary};
use crate::scene::{Jitter, Scene, SceneError, Settings, CATALOGUE};
use serde::Serialize;
use serde_json::{Map, Value};
use std::path::{Path, PathBuf};
use std::time::Instant;
use thiserror::Error;

/// Why a report could not be made.
#[derive(Debug, Error)]
pub enum ReportError {
    /// A filter spec names no filter, or a parameter it does not have or out of bounds.
    #[error("filter spec {spec:?}: {source}")]
    Spec {
        /// The spec as given.
        spec: String,
        /// What is wrong with it.
        #[source]
        source: Box<FilterError>,
    },
    /// A filter spec's backend cannot be had (no GPU backend, adapter or implementation).
    #[error("filter spec {spec:?}: {source}")]
    Backend {
        /// The spec as given.
        spec: String,
        /// Why not.
        #[source]
        source: Box<crate::backend::BackendError>,
    },
    /// A scene name or a scene setting is wrong.
    #[error("scene {scene:?}: {source}")]
    Scene {
        /// The scene.
        scene: String,
        /// What is wrong.
        #[source]
        source: SceneError,
    },
    /// A filter refused a frame (a bug: scene frames are well formed).
    #[error("filter {filter} on scene {scene}, frame {index}: {source}")]
    Run {
        /// The filter's label.
        filter: String,
        /// The scene.
        scene: String,
        /// The frame.
        index: u64,
        /// What the filter said.
        #[source]
        source: Box<FilterError>,
    },
    /// A shot's frames cannot be paired with its reference (lengths or sizes differ), or
    /// a corpus directory holds no shots.
    #[error("shot {shot}: {message}")]
    Shot {
        /// The shot's name.
        shot: String,
        /// What is wrong.
        message: String,
    },
    /// A setting out of range (empty lists, zero frames, a strip frame past the end).
    #[error("{0}")]
    Config(String),
    /// Metrics could not compare output and reference.
    #[error(transparent)]
    Metrics(#[from] MetricsError),
    /// Writing a file failed.
    #[error(transparent)]
    Io(#[from] IoError),
    /// Drawing a plot failed.
    #[error("plot {path}: {message}")]
    Plot {
        /// The file being drawn.
        path: PathBuf,
        /// What the plotting backend said.
        message: String,
    },
}

/// One filter as the report runs it: a registry name, parameter overrides, and the label
/// it goes by in tables and plots.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct FilterSpec {
    /// Shown in tables and plots: the spec as written (`traa:variant=baseline`).
    pub label: String,
    /// Registry name.
    pub name: &'static str,
    /// Overrides of the defaults.
    pub params: Map<String, Value>,
    /// Where it runs (`NAME@gpu`; default the CPU).
    pub backend: BackendChoice,
}

impl FilterSpec {
    /// Parses `NAME[@BACKEND][:key=value...]` (`taa`, `traa:variant=baseline`,
    /// `taa@gpu:alpha=0.2`; BACKEND cpu, gpu, auto, gpu-f16 or auto-f16, default cpu) and checks it against
    /// the registry (unknown filter, unknown parameter and out-of-bound values are refused
    /// here; a backend that cannot be had, when the filter is made).
    pub fn parse(spec: &str) -> Result<FilterSpec, ReportError> {
        let spec = spec.trim();
        let mut parts = spec.split(':');
        let head = parts.next().unwrap_or_default().trim();
        let (name, backend) = match head.split_once('@') {
            Some((name, b)) => (
                name.trim(),
                b.trim()
                    .parse::<BackendChoice>()
                    .map_err(|e| ReportError::Backend {
                        spec: spec.to_string(),
                        source: Box::new(e),
                    })?,
            ),
            None => (head, BackendChoice::Cpu),
        };
        let assignments: Vec<&str> = parts.map(str::trim).filter(|p| !p.is_empty()).collect();
        let err = |source| ReportError::Spec {
            spec: spec.to_string(),
            source: Box::new(source),
        };
        let params = parse_assignments(&assignments).map_err(err)?;
        let filter = filters::create(name, &params).map_err(err)?;
        Ok(FilterSpec {
            label: spec.to_string(),
            name: filter.name(),
            params,
            backend,
        })
    }

    /// Every registered filter of full-resolution colour at its defaults, in registry
    /// order, each followed by its other values of a `variant` parameter (`traa`'s
    /// baseline, `phlm`'s paper settings); the filters of sparse shading have their own
    /// section ([`FilterSpec::sparse`]).
    pub fn every() -> Vec<FilterSpec> {
        filters::list()
            .into_iter()
            .filter(|info| !info.sparse_input)
            .flat_map(|info| {
                let at_defaults = FilterSpec {
                    label: info.name.to_string(),
                    name: info.name,
                    params: Map::new(),
                    backend: BackendChoice::Cpu,
                };
                let variants = info.params.iter().find_map(|p| match (p.name, p.kind) {
                    ("variant", crate::pipeline::ParamKind::Choice { options }) => Some(options),
                    _ => None,
                });
                let default = filters::create(info.name, &Map::new()).ok().and_then(|f| {
                    f.params()
                        .get("variant")
                        .and_then(|v| v.as_str().map(str::to_string))
                });
                let others = variants
                    .into_iter()
                    .flatten()
                    .filter(move |v| default.as_deref() != Some(**v))
                    .map(move |v| FilterSpec {
                        label: format!("{}:variant={v}", info.name),
                        name: info.name,
                        params: [("variant".to_string(), Value::from(*v))].into_iter().collect(),
                        backend: BackendChoice::Cpu,
                    });
                std::iter::once(at_defaults).chain(others)
            })
            .collect()
    }

    /// Every filter of sparse shading, one spec per value of its `method` parameter (the
    /// method and its baselines), or at its defaults when it has none.
    pub fn sparse() -> Vec<FilterSpec> {
        filters::list()
            .into_iter()
            .filter(|info| info.sparse_input)
            .flat_map(|info| {
                let methods = info.params.iter().find_map(|p| match (p.name, p.kind) {
                    ("method", crate::pipeline::ParamKind::Choice { options }) => Some(options),
                    _ => None,
                });
                match methods {
                    Some(options) => options
                        .iter()
                        .map(|m| FilterSpec {
                            label: format!("{}:method={m}", info.name),
                            name: info.name,
                            params: [("method".to_string(), Value::from(*m))].into_iter().collect(),
                            backend: BackendChoice::Cpu,
                        })
                        .collect(),
                    None => vec![FilterSpec {
                        label: info.name.to_string(),
                        name: info.name,
                        params: Map::new(),
                        backend: BackendChoice::Cpu,
                    }],
                }
            })
            .collect()
    }

    /// A new instance on the spec's backend.
    fn create(&self) -> Result<crate::backend::Created, ReportError> {
        crate::backend::create(self.name, &self.params, self.backend).map_err(|e| match e {
            crate::backend::BackendError::Filter(source) => ReportError::Spec {
                spec: self.label.clone(),
                source: Box::new(source),
            },
            other => ReportError::Backend {
                spec: self.label.clone(),
                source: Box::new(other),
            },
        })
    }

    fn uses(&self) -> ChannelSet {
        filters::info(self.name).map_or(ChannelSet::EMPTY, |i| ChannelSet::of(&i.uses))
    }

    fn takes_sparse(&self) -> bool {
        filters::info(self.name).is_some_and(|i| i.sparse_input)
    }
}

/// A shot rendered elsewhere (a user's frames, the Blender corpus): input frames read
/// from disk with every channel their preset maps and the jitter their headers carry,
/// and a reference sequence of the same length and size. The report runs it as it runs a
/// catalogue scene.
#[derive(Clone, Debug, PartialEq, Eq, Serialize)]
pub struct Shot {
    /// Its name in tables and plots.
    pub name: String,
    /// The input frames: a directory, pattern, glob or file (see [`Sequence::open`]).
    pub input: String,
    /// The reference frames, frame for frame (colour only is read).
    pub reference: String,
    /// Run as if the renderer had not said where its samples fell: every frame's jitter
    /// is set to 0 (the filters then weigh the 3x3 samples at the pixel centres).
    pub jitter_unknown: bool,
}

impl Shot {
    /// A shot from `--input [NAME=]DIR` and `--reference DIR`. Without a name, the input's
    /// last path component names it, or its parent's when that component is `input` (the
    /// corpus layout, `SCENE/input`).
    pub fn parse(input: &str, reference: &str) -> Shot {
        let (name, input) = match input.split_once('=') {
            Some((name, dir))
                if !name.is_empty() && !name.contains(['/', '\\']) && !Path::new(input).exists() =>
            {
                (name.to_string(), dir.to_string())
            }
            _ => {
                let path = Path::new(input.trim_end_matches(['/', '\\']));
                let last = |p: &Path| p.file_name().map(|n| n.to_string_lossy().into_owned());
                let name = match last(path) {
                    Some(n) if n == "input" => path.parent().and_then(last).unwrap_or(n),
                    Some(n) => n,
                    None => input.to_string(),
                };
                (name, input.to_string())
            }
        };
        Shot {
            name,
            input,
            reference: reference.to_string(),
            jitter_unknown: false,
        }
    }

    /// Every shot of a corpus directory: each subdirectory with an `input` and a
    /// `reference` directory (the layout `corpus/render.sh` writes), sorted by name.
    pub fn corpus(dir: &Path) -> Result<Vec<Shot>, ReportError> {
        let mut shots: Vec<Shot> = std::fs::read_dir(dir)
            .map_err(|e| IoError::os(dir, e))?
            .filter_map(|e| e.ok().map(|e| e.path()))
            .filter(|p| p.join("input").is_dir() && p.join("reference").is_dir())
            .map(|p| Shot {
                name: p
                    .file_name()
                    .map_or_else(String::new, |n| n.to_string_lossy().into_owned()),
                input: p.join("input").to_string_lossy().into_owned(),
                reference: p.join("reference").to_string_lossy().into_owned(),
                jitter_unknown: false,
            })
            .collect();
        if shots.is_empty() {
            return Err(ReportError::Shot {
                shot: dir.display().to_string(),
                message: "no SCENE/input and SCENE/reference directories in it".into(),
            });
        }
        shots.sort_by(|a, b| a.name.cmp(&b.name));
        Ok(shots)
    }

    /// Frames in the input (0 when it cannot be opened; running it says why).
    fn len(&self) -> usize {
        Sequence::open(&self.input).map_or(0, |s| s.len())
    }

    /// Reads the input frames (channels by the detected preset, jitter from the headers)
    /// with their reference attached; `tick` after each frame.
    fn load(&self, tick: &mut dyn FnMut(&str)) -> Result<(Vec<Frame>, Vec<f64>), ReportError> {
        let err = |message: String| ReportError::Shot {
            shot: self.name.clone(),
            message,
        };
        let input = Sequence::open(&self.input)?;
        let reference = Sequence::open(&self.reference)?;
        if input.len() != reference.len() {
            return Err(err(format!(
                "{} has {} frames but the reference {} has {}",
                self.input,
                input.len(),
                self.reference,
                reference.len()
            )));
        }
        let opts = ReadOptions::default();
        let mut frames = Vec::with_capacity(input.len());
        let mut read_ms = Vec::with_capacity(input.len());
        // Each frame's time runs from the end of the previous one's, so it includes the
        // reading the iterators do.
        let mut t = Instant::now();
        for (frame, r) in input.frames(&opts).zip(reference.frames(&opts)) {
            let (mut frame, r) = (frame?, r?);
            if r.width() != frame.width() || r.height() != frame.height() {
                return Err(err(format!(
                    "frame {} is {}x{} but its reference is {}x{}",
                    frames.len(),
                    frame.width(),
                    frame.height(),
                    r.width(),
                    r.height()
                )));
            }
            if self.jitter_unknown {
                frame.meta.jitter = [0.0, 0.0];
            }
            frame
                .set_f32(ChannelKind::Reference, r.into_color().into())
                .map_err(|e| err(e.to_string()))?;
            read_ms.push(t.elapsed().as_secs_f64() * 1e3);
            frames.push(frame);
            tick(&format!("{}: read", self.name));
            t = Instant::now();
        }
        Ok((frames, read_ms))
    }
}

/// Size and length of the timing section's synthetic sequence.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct TimingSize {
    /// Width in pixels.
    pub width: usize,
    /// Height in pixels.
    pub height: usize,
    /// Timed frames per filter (after one untimed frame that allocates the state).
    pub frames: usize,
}

/// What to run.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Config {
    /// Catalogue scenes, in order.
    pub scenes: Vec<String>,
    /// Shots read from disk, run after the catalogue scenes in the same tables.
    pub shots: Vec<Shot>,
    /// Filters, in order.
    pub filters: Vec<FilterSpec>,
    /// How every scene is rendered (size, frames, reference samples, jitter, seed).
    pub render: Settings,
    /// Frame shown in the image strips (default: the last).
    pub strip_frame: Option<u64>,
    /// The full-size timing section (None: left out).
    pub timing: Option<TimingSize>,
    /// Timed copies for the bandwidth floor.
    pub copy_reps: usize,
    /// The sparse-shading comparison (None: left out).
    pub upsampling: Option<UpsamplingConfig>,
}

/// The upsampling section: scenes rendered with sparse shading (one pixel per `factor x
/// factor` block, no jitter, as Herzog et al. 2010 sample) and the reconstructions run on
/// them, at the main section's size, frames and reference samples.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct UpsamplingConfig {
    /// Catalogue scenes.
    pub scenes: Vec<String>,
    /// Reconstructions (filters that take sparse colour).
    pub filters: Vec<FilterSpec>,
    /// Block size (2 or 4).
    pub factor: u32,
    /// Also run the main section's shots (`--input`, `--corpus`), each frame shaded
    /// sparsely in the rotating order from its dense render ([`Frame::shaded_sparsely`]).
    pub shots: bool,
}

impl UpsamplingConfig {
    /// Herzog et al. 2010's comparison: `upsample` and its three baselines on the three dynamic
    /// scenes of issue 8 (camera motion, object motion with disocclusion, moving light),
    /// 2x2 shading.
    pub fn standard() -> UpsamplingConfig {
        UpsamplingConfig {
            scenes: ["flyover", "moving-sphere", "dynamic-light"]
                .map(String::from)
                .to_vec(),
            filters: FilterSpec::sparse(),
            factor: 2,
            shots: false,
        }
    }

    /// The main section's settings with this section's sparse shading, without jitter and
    /// noise (as Herzog et al. 2010 sample).
    fn render(&self, main: Settings) -> Settings {
        Settings {
            jitter: Jitter::None,
            noise: false,
            shading: self.factor,
            ..main
        }
    }
}

impl Config {
    /// The run we quote: every scene and filter at 256x144, 32 frames, 16x16 reference
    /// samples (the `scene` command's defaults), plus timing at 1920x1080 over 10 frames.
    pub fn standard() -> Config {
        Config {
            scenes: CATALOGUE.iter().map(|e| e.name.to_string()).collect(),
            shots: Vec::new(),
            filters: FilterSpec::every(),
            render: Settings::default(),
            strip_frame: None,
            timing: Some(TimingSize {
                width: 1920,
                height: 1080,
                frames: 10,
            }),
            copy_reps: 9,
            upsampling: Some(UpsamplingConfig::standard()),
        }
    }

    /// A run of well under a minute on 2 cores, for tests and a first look: 64x36, 8
    /// frames, 4x4 reference samples, timing at 320x180 over 3 frames.
    pub fn quick() -> Config {
        Config {
            render: Settings {
                width: 64,
                height: 36,
                frames: 8,
                spp: 16,
                jitter: Jitter::Halton(8),
                noise: false,
                seed: 1,
                shading: 1,
            },
            timing: Some(TimingSize {
                width: 320,
                height: 180,
                frames: 3,
            }),
            copy_reps: 5,
            ..Config::standard()
        }
    }

    fn validate(&self) -> Result<(), ReportError> {
        if self.scenes.is_empty() && self.shots.is_empty() {
            return Err(ReportError::Config("no scenes or shots to run".into()));
        }
        if self.filters.is_empty() {
            return Err(ReportError::Config("no filters to run".into()));
        }
        if let Some(f) = self
            .strip_frame
            .filter(|&f| f >= self.render.frames && !self.scenes.is_empty())
        {
            return Err(ReportError::Config(format!(
                "strip frame {f} is past the end: the scenes have {} frames (0..={})",
                self.render.frames,
                self.render.frames.saturating_sub(1)
            )));
        }
        if let Some(t) = self.timing {
            if t.width == 0 || t.height == 0 || t.frames == 0 {
                return Err(ReportError::Config(format!(
                    "timing size {}x{} over {} frames: all three must be at least 1",
                    t.width, t.height, t.frames
                )));
            }
        }
        for s in &self.scenes {
            Scene::new(s, self.render).map_err(|source| ReportError::Scene {
                scene: s.clone(),
                source,
            })?;
        }
        if let Some(u) = &self.upsampling {
            for s in &u.scenes {
                Scene::new(s, u.render(self.render)).map_err(|source| ReportError::Scene {
                    scene: s.clone(),
                    source,
                })?;
            }
            if let Some(f) = u.filters.iter().find(|f| !f.takes_sparse()) {
                return Err(ReportError::Config(format!(
                    "the upsampling section runs filters of sparse shading; {} needs full-resolution colour",
                    f.label
                )));
            }
        }
        Ok(())
    }

    /// Progress steps of a run: one per rendered frame and one per filtered frame.
    pub fn steps(&self) -> u64 {
        let n = self.render.frames;
        let filters = self.filters.len() as u64;
        let scenes = self.scenes.len() as u64 * (n + filters * n)
            + self
                .shots
                .iter()
                .map(|s| s.len() as u64 * (1 + filters))
                .sum::<u64>();
        let timing = self.timing.map_or(0, |t| filters * (t.frames as u64 + 1));
        let upsampling = self.upsampling.as_ref().map_or(0, |u| {
            let filters = u.filters.len() as u64;
            let shots = if u.shots {
                self.shots
                    .iter()
                    .map(|s| s.len() as u64 * (1 + filters))
                    .sum::<u64>()
            } else {
                0
            };
            u.scenes.len() as u64 * (n + filters * n)
                + shots
                + self.timing.map_or(0, |t| filters * (t.frames as u64 + 1))
        });
        scenes + timing + upsampling
    }
}

/// Where a run is, for a progress bar.
#[derive(Clone, Debug)]
pub struct Progress {
    /// Steps done (see [`Config::steps`]).
    pub done: u64,
    /// What is running: `scene: filter`.
    pub what: String,
}

/// Figures of one filter over one sequence, shared by the scene cells and the timing rows.
#[derive(Clone, Debug, Serialize)]
pub struct Cost {
    /// Wall time of `process` per frame.
    pub time: Timing,
    /// Per-stage times and skips.
    pub stages: Vec<StageSummary>,
    /// Bytes of filter state per megapixel (both history buffers).
    pub state_bytes_per_megapixel: f64,
    /// Bytes the filter must move per frame (see [`bytes_per_pixel`]).
    pub bytes_per_frame: usize,
    /// Time a plain copy needs to move those bytes.
    pub floor_ms: f64,
    /// `time.median_ms / floor_ms`.
    pub floor_ratio: f64,
}

impl Cost {
    fn of(
        spec: &FilterSpec,
        frame: &Frame,
        wall_ms: &[f64],
        records: &[FrameRecord],
        bw: &Bandwidth,
    ) -> Cost {
        let pixels = frame.width() * frame.height();
        let state = records.iter().map(|r| r.state_bytes).max().unwrap_or(0);
        let state_per_pixel = state.div_ceil(pixels.max(1));
        let bytes_per_frame = bytes_per_frame(spec.uses(), frame, state_per_pixel);
        let time = Timing::of(wall_ms);
        let floor_ms = bw.floor_ms(bytes_per_frame);
        Cost {
            time,
            stages: summarize_stages(records),
            state_bytes_per_megapixel: state as f64 / pixels.max(1) as f64 * 1e6,
            bytes_per_frame,
            floor_ms,
            floor_ratio: time.median_ms / floor_ms,
        }
    }
}

/// One filter on one scene.
#[derive(Clone, Debug, Serialize)]
pub struct Cell {
    /// The filter's label.
    pub filter: String,
    /// Mean of per-frame PSNR, dB.
    pub mean_psnr: f64,
    /// Mean of per-frame SSIM on luma.
    pub mean_ssim: f64,
    /// Temporal RMSE (None with a single frame).
    pub trmse: Option<f64>,
    /// Run time and memory.
    pub cost: Cost,
    /// PSNR of every frame, in order.
    pub psnr_per_frame: Vec<f64>,
}

/// One scene.
#[derive(Clone, Debug, Serialize)]
pub struct SceneReport {
    /// Catalogue name.
    pub scene: String,
    /// What it tests.
    pub description: String,
    /// Space the metrics were computed in (tonemapped for HDR references).
    pub space: MetricSpace,
    /// Time to render one frame (input, G-buffer and reference).
    pub render: Timing,
    /// One cell per filter, in the config's order.
    pub cells: Vec<Cell>,
}

/// One filter over all scenes.
#[derive(Clone, Debug, Serialize)]
pub struct FilterSummary {
    /// The filter's label.
    pub filter: String,
    /// Mean over scenes of the mean PSNR.
    pub mean_psnr: f64,
    /// Mean over scenes of the mean SSIM.
    pub mean_ssim: f64,
    /// Mean over scenes of tRMSE (over the scenes that have one).
    pub mean_trmse: Option<f64>,
    /// Wall time per frame over every frame of every scene.
    pub time: Timing,
    /// Median over scenes of the ratio to the floor.
    pub floor_ratio: f64,
    /// Bytes of state per megapixel.
    pub state_bytes_per_megapixel: f64,
}

/// One filter on the synthetic full-size sequence.
#[derive(Clone, Debug, Serialize)]
pub struct TimingRow {
    /// The filter's label.
    pub filter: String,
    /// Where it ran.
    pub backend: crate::backend::Backend,
    /// The precision its colour went up to the GPU in (GPU rows only).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub upload: Option<crate::backend::UploadPrecision>,
    /// Run time and memory.
    pub cost: Cost,
}

/// The frame shown side by side for one scene.
#[derive(Clone, Debug)]
pub struct Strip {
    /// The scene.
    pub scene: String,
    /// The frame's index.
    pub frame: u64,
    /// Metric space (HDR scenes are shown tonemapped).
    pub space: MetricSpace,
    /// The unfiltered input.
    pub input: Rgb,
    /// Each filter's output, labelled.
    pub outputs: Vec<(String, Rgb)>,
    /// The supersampled reference.
    pub reference: Rgb,
}

/// The upsampling section's results, laid out as the main section's.
#[derive(Clone, Debug, Serialize)]
pub struct UpsamplingReport {
    /// Block size of the sparse shading.
    pub factor: u32,
    /// Per scene, per reconstruction.
    pub scenes: Vec<SceneReport>,
    /// Per reconstruction over the scenes.
    pub summary: Vec<FilterSummary>,
    /// Per reconstruction on the full-size synthetic sequence, sparsely shaded.
    pub timing: Vec<TimingRow>,
}

/// The whole report. Serialises to `report.json` (the strips are written as images).
#[derive(Clone, Debug, Serialize)]
pub struct Report {
    /// What was run.
    pub config: Config,
    /// Copy bandwidth of this machine in this run.
    pub bandwidth: Bandwidth,
    /// Per scene, per filter.
    pub scenes: Vec<SceneReport>,
    /// Per filter over all scenes.
    pub summary: Vec<FilterSummary>,
    /// Per filter on the full-size synthetic sequence (empty when left out).
    pub timing: Vec<TimingRow>,
    /// The sparse-shading comparison (None when left out).
    pub upsampling: Option<UpsamplingReport>,
    /// Image strips, one per scene (then one per scene of the upsampling section).
    #[serde(skip)]
    pub strips: Vec<Strip>,
}

fn mean(values: impl Iterator<Item = f64>) -> Option<f64> {
    let (sum, n) = values.fold((0.0, 0usize), |(s, n), v| (s + v, n + 1));
    (n > 0).then(|| sum / n as f64)
}

/// Runs the report. `progress` is called after every rendered and every filtered frame.
pub fn run(config: &Config, progress: &mut dyn FnMut(&Progress)) -> Result<Report, ReportError> {
    config.validate()?;
    let mut done = 0u64;
    let mut tick = |what: &str| {
        done += 1;
        progress(&Progress {
            done,
            what: what.to_string(),
        });
    };
    let bandwidth = measure_copy_bandwidth(config.copy_reps);
    let strip_frame = config.strip_frame.map(|f| f as usize);
    let sources: Vec<Source> = config
        .scenes
        .iter()
        .map(|s| Source::Catalogue(s))
        .chain(config.shots.iter().map(Source::Shot))
        .collect();
    let (scenes, summary, mut strips) = run_scenes(
        &sources,
        config.render,
        &config.filters,
        strip_frame,
        &bandwidth,
        &mut tick,
    )?;
    let timing = match config.timing {
        Some(size) => {
            let frames = [0, 1].map(|i| synthetic_frame(size.width, size.height, i));
            time_filters(&config.filters, &frames, size, &bandwidth, &mut tick)?
        }
        None => Vec::new(),
    };
    let upsampling = match &config.upsampling {
        None => None,
        Some(u) => {
            let mut sources: Vec<Source> = u.scenes.iter().map(|s| Source::Catalogue(s)).collect();
            if u.shots {
                sources.extend(config.shots.iter().map(|s| Source::SparseShot(s, u.factor)));
            }
            let (scenes, summary, more) = run_scenes(
                &sources,
                u.render(config.render),
                &u.filters,
                strip_frame,
                &bandwidth,
                &mut tick,
            )?;
            strips.extend(more);
            let timing = match config.timing {
                Some(size) => {
                    let frames = [0, 1].map(|i| synthetic_sparse_frame(size.width, size.height, i, u.factor));
                    time_filters(&u.filters, &frames, size, &bandwidth, &mut tick)?
                }
                None => Vec::new(),
            };
            Some(UpsamplingReport {
                factor: u.factor,
                scenes,
                summary,
                timing,
            })
        }
    };
    Ok(Report {
        config: config.clone(),
        bandwidth,
        scenes,
        summary,
        timing,
        upsampling,
        strips,
    })
}

type ScenesRun = (Vec<SceneReport>, Vec<FilterSummary>, Vec<Strip>);

/// What a row of the report runs on.
enum Source<'a> {
    /// A catalogue scene, rendered with the run's settings.
    Catalogue(&'a str),
    /// Frames read from disk.
    Shot(&'a Shot),
    /// Frames read from disk, shaded sparsely with this block size.
    SparseShot(&'a Shot, u32),
}

/// Renders (or reads) each scene and runs each filter over it; per scene a report and a
/// strip (of frame `strip_frame`, default the last), per filter a summary over the
/// scenes.
fn run_scenes(
    sources: &[Source],
    render: Settings,
    filters: &[FilterSpec],
    strip_frame: Option<usize>,
    bandwidth: &Bandwidth,
    tick: &mut dyn FnMut(&str),
) -> Result<ScenesRun, ReportError> {
    let mut scenes = Vec::new();
    let mut strips = Vec::new();
    let mut wall_by_filter: Vec<Vec<f64>> = vec![Vec::new(); filters.len()];
    for source in sources {
        let (name, description, frames, render_ms) = load_source(source, render, tick)?;
        let name = &name;
        let strip_index = strip_frame.unwrap_or(frames.len().saturating_sub(1));
        if strip_index >= frames.len() {
            return Err(ReportError::Config(format!(
                "strip frame {strip_index} is past the end: {name} has {} frames",
                frames.len()
            )));
        }
        let reference = |f: &Frame| -> Rgb { f.reference().expect("scenes render a reference").clone() };
        let sparse = render.shading > 1;
        let label = if sparse {
            format!("{name}-shading-{0}x{0}", render.shading)
        } else {
            name.clone()
        };
        let mut strip = Strip {
            scene: label.clone(),
            frame: strip_index as u64,
            space: SpaceChoice::Auto.resolve(&reference(&frames[0])),
            input: frames[strip_index].color_full().into_owned(),
            outputs: Vec::new(),
            reference: reference(&frames[strip_index]),
        };
        let mut cells = Vec::new();
        for (k, spec) in filters.iter().enumerate() {
            let scene = SceneRun {
                name,
                label: &label,
                frames: &frames,
                strip_index,
            };
            let (cell, wall) = run_filter(spec, &scene, &mut strip, bandwidth, tick)?;
            wall_by_filter[k].extend_from_slice(&wall);
            cells.push(cell);
        }
        scenes.push(SceneReport {
            scene: label,
            description,
            space: strip.space,
            render: Timing::of(&render_ms),
            cells,
        });
        strips.push(strip);
    }

    let summary = filters
        .iter()
        .enumerate()
        .map(|(k, spec)| {
            let cells: Vec<&Cell> = scenes.iter().map(|s| &s.cells[k]).collect();
            let ratios: Vec<f64> = cells.iter().map(|c| c.cost.floor_ratio).collect();
            FilterSummary {
                filter: spec.label.clone(),
                mean_psnr: mean(cells.iter().map(|c| c.mean_psnr)).unwrap_or(f64::NAN),
                mean_ssim: mean(cells.iter().map(|c| c.mean_ssim)).unwrap_or(f64::NAN),
                mean_trmse: mean(cells.iter().filter_map(|c| c.trmse)),
                time: Timing::of(&wall_by_filter[k]),
                floor_ratio: Timing::of(&ratios).median_ms,
                state_bytes_per_megapixel: cells
                    .iter()
                    .map(|c| c.cost.state_bytes_per_megapixel)
                    .fold(0.0, f64::max),
            }
        })
        .collect();
    Ok((scenes, summary, strips))
}

/// A scene's frames (rendered, or read from a shot and shaded sparsely where asked) with
/// its name, description and the ms each frame took to render or read.
fn load_source(
    source: &Source,
    render: Settings,
    tick: &mut dyn FnMut(&str),
) -> Result<(String, String, Vec<Frame>, Vec<f64>), ReportError> {
    Ok(match source {
        Source::Catalogue(name) => {
            let scene = Scene::new(name, render).map_err(|source| ReportError::Scene {
                scene: name.to_string(),
                source,
            })?;
            let mut render_ms = Vec::with_capacity(render.frames as usize);
            let frames: Vec<Frame> = (0..render.frames)
                .map(|i| {
                    let t = Instant::now();
                    let f = scene.frame(i);
                    render_ms.push(t.elapsed().as_secs_f64() * 1e3);
                    tick(&format!("{name}: render"));
                    f
                })
                .collect();
            (
                name.to_string(),
                scene.def.description.to_string(),
                frames,
                render_ms,
            )
        }
        Source::Shot(shot) | Source::SparseShot(shot, _) => {
            let (mut frames, read_ms) = shot.load(tick)?;
            if let Source::SparseShot(_, factor) = source {
                frames = frames
                    .into_iter()
                    .enumerate()
                    .map(|(i, f)| f.shaded_sparsely(Sampling::rotating(*factor, i as u64)))
                    .collect::<Result<_, _>>()
                    .map_err(|e| ReportError::Shot {
                        shot: shot.name.clone(),
                        message: e.to_string(),
                    })?;
            }
            let unknown = if shot.jitter_unknown {
                ", jitter taken as unknown"
            } else {
                ""
            };
            let description = format!("frames {}, reference {}{unknown}", shot.input, shot.reference);
            (shot.name.clone(), description, frames, read_ms)
        }
    })
}

/// One scene as a filter runs over it.
struct SceneRun<'a> {
    name: &'a String,
    /// The name in tables (with the shading factor where it is sparse).
    label: &'a str,
    frames: &'a [Frame],
    /// The frame whose outputs go into the scene's strip.
    strip_index: usize,
}

/// Runs one filter over a scene: its cell of the table, and the ms each output took (a
/// call's time shared by the outputs it gave). The strip frame's output goes to `strip`.
fn run_filter(
    spec: &FilterSpec,
    scene: &SceneRun<'_>,
    strip: &mut Strip,
    bandwidth: &Bandwidth,
    tick: &mut dyn FnMut(&str),
) -> Result<(Cell, Vec<f64>), ReportError> {
    let frames = scene.frames;
    let mut filter = spec.create()?.filter;
    let mut eval = Evaluator::new(SpaceChoice::Auto);
    let mut records = Vec::with_capacity(frames.len());
    let mut wall = Vec::with_capacity(frames.len());
    // A windowed filter gives frame i after frame i + lookahead: outputs are matched to
    // frames in order.
    let mut done = 0usize;
    for step in 0..=frames.len() {
        let t = Instant::now();
        let outs = match frames.get(step) {
            Some(frame) => filter.push(frame),
            None => filter.finish(),
        }
        .map_err(|source| ReportError::Run {
            filter: spec.label.clone(),
            scene: scene.name.clone(),
            index: frames.get(step).map_or(frames.len() as u64, |f| f.meta.index),
            source: Box::new(source),
        })?;
        let ms = t.elapsed().as_secs_f64() * 1e3 / outs.len().max(1) as f64;
        for out in outs {
            let (i, frame) = (done, &frames[done]);
            done += 1;
            wall.push(ms);
            let r = frame.reference().expect("scenes render a reference");
            eval.push(frame.meta.index, &out.color, r, frame.meta.reset)?;
            records.push(out.record);
            if i == scene.strip_index {
                strip.outputs.push((spec.label.clone(), out.color));
            } else {
                filter.recycle(out.color);
            }
            tick(&format!("{}: {}", scene.label, spec.label));
        }
    }
    let s = eval.summary().expect("at least one frame");
    let cell = Cell {
        filter: spec.label.clone(),
        mean_psnr: s.mean_psnr,
        mean_ssim: s.mean_ssim,
        trmse: s.trmse,
        cost: Cost::of(spec, &frames[0], &wall, &records, bandwidth),
        psnr_per_frame: eval.frames.iter().map(|f| f.psnr).collect(),
    };
    Ok((cell, wall))
}

/// Times each filter on two alternating full-size frames.
fn time_filters(
    filters: &[FilterSpec],
    frames: &[Frame; 2],
    size: TimingSize,
    bandwidth: &Bandwidth,
    tick: &mut dyn FnMut(&str),
) -> Result<Vec<TimingRow>, ReportError> {
    let mut timing = Vec::new();
    for spec in filters {
        let label = format!("{}x{}: {}", size.width, size.height, spec.label);
        let made = spec.create()?;
        let (backend, upload) = (made.backend, made.upload);
        let mut filter = made.filter;
        let run_err = |index: u64, source| ReportError::Run {
            filter: spec.label.clone(),
            scene: format!("synthetic {}x{}", size.width, size.height),
            index,
            source: Box::new(source),
        };
        // Untimed frames allocate the state, fault its pages in and fill a windowed
        // filter's window, so that every timed push gives one output.
        for i in 0..=filter.lookahead() {
            for out in filter.push(&frames[i % 2]).map_err(|e| run_err(i as u64, e))? {
                filter.recycle(out.color);
            }
        }
        tick(&label);
        let mut records = Vec::with_capacity(size.frames);
        let mut wall = Vec::with_capacity(size.frames);
        for i in 1..=size.frames {
            let frame = &frames[i % 2];
            let t = Instant::now();
            let outs = filter.push(frame).map_err(|e| run_err(frame.meta.index, e))?;
            wall.push(t.elapsed().as_secs_f64() * 1e3);
            for out in outs {
                records.push(out.record);
                filter.recycle(out.color);
            }
            tick(&label);
        }
        timing.push(TimingRow {
            filter: spec.label.clone(),
            backend,
            upload,
            cost: Cost::of(spec, &frames[0], &wall, &records, bandwidth),
        });
    }
    Ok(timing)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn filter_specs_parse_and_refuse_precisely() {
        let s = FilterSpec::parse("taa@auto:alpha=0.2").unwrap();
        assert_eq!((s.name, s.backend), ("taa", BackendChoice::Auto));
        assert_eq!(s.label, "taa@auto:alpha=0.2");
        assert_eq!(FilterSpec::parse("taa").unwrap().backend, BackendChoice::Cpu);
        let s = FilterSpec::parse("taa@gpu-f16:alpha=0.2").unwrap();
        assert_eq!((s.name, s.backend), ("taa", BackendChoice::GpuF16));
        let e = FilterSpec::parse("taa@cuda").unwrap_err().to_string();
        assert!(e.contains("\"cuda\"") && e.contains("cpu, gpu or auto"), "{e}");
        let s = FilterSpec::parse("traa:variant=baseline").unwrap();
        assert_eq!((s.name, s.label.as_str()), ("traa", "traa:variant=baseline"));
        assert_eq!(s.params["variant"], "baseline");
        let e = FilterSpec::parse("nope").unwrap_err().to_string();
        assert!(e.contains("\"nope\"") && e.contains("taa"), "{e}");
        let e = FilterSpec::parse("taa:no_such=1").unwrap_err().to_string();
        assert!(e.contains("no_such"), "{e}");
        let sparse = filters::list().iter().filter(|i| i.sparse_input).count();
        let every: Vec<String> = FilterSpec::every().into_iter().map(|s| s.label).collect();
        // Each filter once at its defaults, and the variants other than the default.
        assert_eq!(
            every.iter().filter(|l| !l.contains(':')).count() + sparse,
            filters::list().len(),
            "every registered filter, no hand-kept list"
        );
        for v in ["traa:variant=baseline", "phlm:variant=paper"] {
            assert!(every.iter().any(|l| l == v), "{v} in {every:?}");
        }
        assert!(!every
            .iter()
            .any(|l| l == "traa:variant=improved" || l == "phlm:variant=tuned"));
        let labels: Vec<String> = FilterSpec::sparse().into_iter().map(|s| s.label).collect();
        assert_eq!(
            labels,
            ["spatiotemporal", "spatial", "temporal", "taa"].map(|m| format!("upsample:method={m}"))
        );
    }

    #[test]
    fn config_refuses_empty_lists_and_a_strip_past_the_end() {
        let mut c = Config::quick();
        c.strip_frame = Some(8);
        let e = run(&c, &mut |_| {}).unwrap_err().to_string();
        assert!(e.contains("strip frame 8") && e.contains("8 frames"), "{e}");
        c.strip_frame = None;
        c.scenes.clear();
        assert!(run(&c, &mut |_| {}).is_err());
        let mut c = Config::quick();
        c.scenes = vec!["no-such-scene".into()];
        let e = run(&c, &mut |_| {}).unwrap_err().to_string();
        assert!(e.contains("no-such-scene") && e.contains("thin-line"), "{e}");
    }
}
