//! The service's figures for Prometheus (`/metrics`): frames and errors by reason,
//! stage-time histograms per filter and stage; gauges of sessions and state bytes are read
//! from the sessions when scraped. Kept in a `prometheus-client` registry and written in
//! its Prometheus text format (version 0.0.4), so escaping, the `_total` suffix of counters
//! and the histogram series follow the format without code of our own.

use crate::pipeline::FrameRecord;
use crate::session::Totals;
use prometheus_client::encoding::{prometheus_text, EncodeLabelSet};
use prometheus_client::metrics::counter::Counter;
use prometheus_client::metrics::family::Family;
use prometheus_client::metrics::gauge::Gauge;
use prometheus_client::metrics::histogram::Histogram;
use prometheus_client::registry::Registry;
use std::sync::atomic::AtomicU64;

/// The `Content-Type` of [`Metrics::render`]'s text.
pub const CONTENT_TYPE: &str = prometheus_text::CONTENT_TYPE;

/// Upper bounds of the stage-time histogram buckets, in seconds.
const BUCKETS_S: [f64; 12] = [
    0.0001, 0.0005, 0.001, 0.0025, 0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1.0,
];

#[derive(Clone, Debug, Hash, PartialEq, Eq, EncodeLabelSet)]
struct FilterLabel {
    filter: String,
}

#[derive(Clone, Debug, Hash, PartialEq, Eq, EncodeLabelSet)]
struct ReasonLabel {
    reason: &'static str,
}

#[derive(Clone, Debug, Hash, PartialEq, Eq, EncodeLabelSet)]
struct StageLabels {
    filter: String,
    stage: String,
}

type StageFamily = Family<StageLabels, Histogram, fn() -> Histogram>;

fn stage_histogram() -> Histogram {
    Histogram::new(BUCKETS_S)
}

/// The service's counters.
pub struct Metrics {
    registry: Registry,
    sessions: Gauge,
    state_bytes: Gauge<u64, AtomicU64>,
    frames: Family<FilterLabel, Counter>,
    errors: Family<ReasonLabel, Counter>,
    stages: StageFamily,
}

impl Default for Metrics {
    fn default() -> Self {
        let sessions = Gauge::default();
        let state_bytes = Gauge::<u64, AtomicU64>::default();
        let frames = Family::<FilterLabel, Counter>::default();
        let errors = Family::<ReasonLabel, Counter>::default();
        let stages = StageFamily::new_with_constructor(stage_histogram);
        let mut registry = Registry::default();
        // Counters are registered without `_total`: the encoder appends it.
        registry.register("afterimage_sessions", "Open sessions", sessions.clone());
        registry.register(
            "afterimage_state_bytes",
            "Bytes of filter state reserved by open sessions",
            state_bytes.clone(),
        );
        registry.register("afterimage_frames", "Frames filtered", frames.clone());
        registry.register(
            "afterimage_errors",
            "Requests refused or failed, by reason",
            errors.clone(),
        );
        registry.register(
            "afterimage_stage_seconds",
            "Time per stage (and total) per frame",
            stages.clone(),
        );
        Metrics {
            registry,
            sessions,
            state_bytes,
            frames,
            errors,
            stages,
        }
    }
}

impl Metrics {
    /// Counts a filtered frame and its stage times.
    pub fn frame(&self, record: &FrameRecord) {
        let filter = record.filter.to_string();
        self.frames
            .get_or_create(&FilterLabel {
                filter: filter.clone(),
            })
            .inc();
        let stage = |stage: &str| StageLabels {
            filter: filter.clone(),
            stage: stage.to_string(),
        };
        for s in &record.stages {
            if let Some(ms) = s.ms {
                self.stages.get_or_create(&stage(s.name)).observe(ms / 1e3);
            }
        }
        self.stages
            .get_or_create(&stage("total"))
            .observe(record.total_ms / 1e3);
    }

    /// Counts an error by reason.
    pub fn error(&self, reason: &'static str) {
        self.errors.get_or_create(&ReasonLabel { reason }).inc();
    }

    /// The Prometheus text exposition (version 0.0.4, [`CONTENT_TYPE`]), with the gauges
    /// set from `totals`.
    pub fn render(&self, totals: Totals) -> String {
        self.sessions
            .set(i64::try_from(totals.sessions).unwrap_or(i64::MAX));
        self.state_bytes.set(totals.state_bytes);
        let mut o = String::new();
        prometheus_text::encode(&mut o, &self.registry).expect("writing to a String cannot fail");
        o
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::pipeline::record::{InputCounts, PixelCounts, StageRecord};
    use std::collections::HashMap;

    fn record(resolve_ms: Option<f64>, total_ms: f64) -> FrameRecord {
        FrameRecord {
            index: 1,
            filter: "taa",
            stages: vec![StageRecord {
                name: "resolve",
                ms: resolve_ms,
                skipped: None,
            }],
            total_ms,
            pixels: PixelCounts::default(),
            input: InputCounts::default(),
            state_bytes: 0,
            model: None,
            window: None,
            backend: crate::backend::Backend::Cpu,
            device: None,
        }
    }

    /// The samples of a Prometheus text exposition, `name{labels}` to value; every line
    /// that is not a comment must be a sample.
    fn samples(text: &str) -> HashMap<String, f64> {
        text.lines()
            .filter(|l| !l.starts_with('#') && !l.is_empty())
            .map(|l| {
                let (series, value) = l
                    .rsplit_once(' ')
                    .unwrap_or_else(|| panic!("not a sample: {l:?}"));
                let value = match value {
                    "+Inf" => f64::INFINITY,
                    v => v.parse().unwrap_or_else(|_| panic!("not a value: {l:?}")),
                };
                (series.to_string(), value)
            })
            .collect()
    }

    /// The exposition keeps the names, labels, HELP and TYPE lines the dashboards and
    /// docs/server.md know, and counts what it was told.
    #[test]
    fn the_exposition_names_and_counts_every_figure() {
        let m = Metrics::default();
        m.frame(&record(Some(2.0), 3.0));
        m.frame(&record(Some(0.5), 30.0));
        m.frame(&record(None, 700.0));
        m.error("too_large");
        m.error("too_large");
        m.error("internal");
        let text = m.render(Totals {
            sessions: 3,
            state_bytes: 1234,
            ..Totals::default()
        });
        for line in [
            "# HELP afterimage_sessions Open sessions.",
            "# TYPE afterimage_sessions gauge",
            "# HELP afterimage_state_bytes Bytes of filter state reserved by open sessions.",
            "# TYPE afterimage_state_bytes gauge",
            "# HELP afterimage_frames_total Frames filtered.",
            "# TYPE afterimage_frames_total counter",
            "# HELP afterimage_errors_total Requests refused or failed, by reason.",
            "# TYPE afterimage_errors_total counter",
            "# HELP afterimage_stage_seconds Time per stage (and total) per frame.",
            "# TYPE afterimage_stage_seconds histogram",
        ] {
            assert!(text.lines().any(|l| l == line), "no {line:?} in\n{text}");
        }
        let s = samples(&text);
        let at = |series: &str| *s.get(series).unwrap_or_else(|| panic!("no {series} in\n{text}"));
        assert_eq!(at("afterimage_sessions"), 3.0);
        assert_eq!(at("afterimage_state_bytes"), 1234.0);
        assert_eq!(at("afterimage_frames_total{filter=\"taa\"}"), 3.0);
        assert_eq!(at("afterimage_errors_total{reason=\"too_large\"}"), 2.0);
        assert_eq!(at("afterimage_errors_total{reason=\"internal\"}"), 1.0);
        let resolve = |suffix: &str, le: Option<&str>| {
            let le = le.map_or(String::new(), |b| format!(",le=\"{b}\""));
            at(&format!(
                "afterimage_stage_seconds_{suffix}{{filter=\"taa\",stage=\"resolve\"{le}}}"
            ))
        };
        // 2 ms and 0.5 ms: one in (0.0001, 0.0005], both by 0.0025; the frame that left
        // the stage out is not counted.
        assert_eq!(resolve("bucket", Some("0.0001")), 0.0);
        assert_eq!(resolve("bucket", Some("0.0005")), 1.0);
        assert_eq!(resolve("bucket", Some("0.0025")), 2.0);
        assert_eq!(resolve("bucket", Some("+Inf")), 2.0);
        assert_eq!(resolve("count", None), 2.0);
        assert!((resolve("sum", None) - 0.0025).abs() < 1e-12);
        let total = |le: &str| {
            at(&format!(
                "afterimage_stage_seconds_bucket{{filter=\"taa\",stage=\"total\",le=\"{le}\"}}"
            ))
        };
        assert_eq!((total("0.005"), total("0.05"), total("1")), (1.0, 2.0, 3.0));
        // Twelve finite buckets and +Inf per series, each cumulative.
        let buckets = s
            .keys()
            .filter(|k| k.starts_with("afterimage_stage_seconds_bucket{filter=\"taa\",stage=\"total\""))
            .count();
        assert_eq!(buckets, BUCKETS_S.len() + 1);
    }

    /// A label value that needs escaping is escaped, so one odd name cannot break a scrape.
    #[test]
    fn label_values_are_escaped() {
        let m = Metrics::default();
        m.error("quote\"back\\slash");
        let text = m.render(Totals::default());
        assert!(
            text.contains(r#"afterimage_errors_total{reason="quote\"back\\slash"} 1"#),
            "{text}"
        );
    }
}
