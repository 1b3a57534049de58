//! Prometheus text exposition of the service's figures: frames and errors by reason,
//! stage-time histograms per filter and stage; gauges of sessions and state bytes are read
//! from the sessions when scraped.

use crate::pipeline::FrameRecord;
use crate::session::Totals;
use std::collections::BTreeMap;
use std::fmt::Write;
use std::sync::Mutex;

/// Upper bounds of the stage-time histogram buckets, in seconds.
const BUCKETS_S: [f64; 12] = [
    0.0001, 0.0005, 0.001, 0.0025, 0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1.0,
];

#[derive(Default)]
struct Histogram {
    counts: [u64; BUCKETS_S.len()],
    count: u64,
    sum: f64,
}

impl Histogram {
    fn observe(&mut self, s: f64) {
        for (c, &b) in self.counts.iter_mut().zip(&BUCKETS_S) {
            if s <= b {
                *c += 1;
            }
        }
        self.count += 1;
        self.sum += s;
    }
}

#[derive(Default)]
struct Inner {
    frames: BTreeMap<String, u64>,
    errors: BTreeMap<&'static str, u64>,
    stages: BTreeMap<(String, String), Histogram>,
}

/// The service's counters.
#[derive(Default)]
pub struct Metrics {
    inner: Mutex<Inner>,
}

impl Metrics {
    /// Counts a filtered frame and its stage times.
    pub fn frame(&self, record: &FrameRecord) {
        let mut m = self.inner.lock().unwrap_or_else(|p| p.into_inner());
        *m.frames.entry(record.filter.to_string()).or_default() += 1;
        for s in &record.stages {
            if let Some(ms) = s.ms {
                m.stages
                    .entry((record.filter.to_string(), s.name.to_string()))
                    .or_default()
                    .observe(ms / 1e3);
            }
        }
        m.stages
            .entry((record.filter.to_string(), "total".into()))
            .or_default()
            .observe(record.total_ms / 1e3);
    }

    /// Counts an error by reason.
    pub fn error(&self, reason: &'static str) {
        let mut m = self.inner.lock().unwrap_or_else(|p| p.into_inner());
        *m.errors.entry(reason).or_default() += 1;
    }

    /// The text exposition.
    pub fn render(&self, totals: Totals) -> String {
        let m = self.inner.lock().unwrap_or_else(|p| p.into_inner());
        let mut o = String::new();
        let _ = writeln!(
            o,
            "# HELP afterimage_sessions Open sessions.\n# TYPE afterimage_sessions gauge"
        );
        let _ = writeln!(o, "afterimage_sessions {}", totals.sessions);
        let _ = writeln!(
            o,
            "# HELP afterimage_state_bytes Bytes of filter state reserved by open sessions.\n# TYPE afterimage_state_bytes gauge"
        );
        let _ = writeln!(o, "afterimage_state_bytes {}", totals.state_bytes);
        let _ = writeln!(
            o,
            "# HELP afterimage_frames_total Frames filtered.\n# TYPE afterimage_frames_total counter"
        );
        for (f, n) in &m.frames {
            let _ = writeln!(o, "afterimage_frames_total{{filter=\"{f}\"}} {n}");
        }
        let _ = writeln!(o, "# HELP afterimage_errors_total Requests refused or failed, by reason.\n# TYPE afterimage_errors_total counter");
        for (r, n) in &m.errors {
            let _ = writeln!(o, "afterimage_errors_total{{reason=\"{r}\"}} {n}");
        }
        let _ = writeln!(
            o,
            "# HELP afterimage_stage_seconds Time per stage (and total) per frame.\n# TYPE afterimage_stage_seconds histogram"
        );
        for ((f, s), h) in &m.stages {
            for (c, b) in h.counts.iter().zip(&BUCKETS_S) {
                let _ = writeln!(
                    o,
                    "afterimage_stage_seconds_bucket{{filter=\"{f}\",stage=\"{s}\",le=\"{b}\"}} {c}"
                );
            }
            let _ = writeln!(
                o,
                "afterimage_stage_seconds_bucket{{filter=\"{f}\",stage=\"{s}\",le=\"+Inf\"}} {}",
                h.count
            );
            let _ = writeln!(
                o,
                "afterimage_stage_seconds_sum{{filter=\"{f}\",stage=\"{s}\"}} {}",
                h.sum
            );
            let _ = writeln!(
                o,
                "afterimage_stage_seconds_count{{filter=\"{f}\",stage=\"{s}\"}} {}",
                h.count
            );
        }
        o
    }
}
