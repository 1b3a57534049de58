//! Summaries of measured times: median and 95th percentile, the figures every report and
//! CLI quotes (medians because these machines are noisy).

use serde::{Deserialize, Serialize};

/// The `q` quantile (0..=1) of `values` by the nearest-rank method on a sorted copy:
/// `sorted[ceil(q * n) - 1]`. NaN when `values` is empty.
pub fn quantile(values: &[f64], q: f64) -> f64 {
    if values.is_empty() {
        return f64::NAN;
    }
    let mut v = values.to_vec();
    v.sort_by(f64::total_cmp);
    let rank = (q.clamp(0.0, 1.0) * v.len() as f64).ceil() as usize;
    v[rank.clamp(1, v.len()) - 1]
}

/// Median and 95th percentile of a set of times, in milliseconds.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Timing {
    /// Median (nearest rank).
    pub median_ms: f64,
    /// 95th percentile (nearest rank).
    pub p95_ms: f64,
    /// How many times were measured.
    pub count: usize,
}

impl Timing {
    /// The summary of `ms` (NaN figures when empty).
    pub fn of(ms: &[f64]) -> Timing {
        Timing {
            median_ms: quantile(ms, 0.5),
            p95_ms: quantile(ms, 0.95),
            count: ms.len(),
        }
    }
}

/// CPU time this process's live threads have spent so far, ms (the sum of each thread's
/// `/proc/self/task/*/schedstat` run time, in nanoseconds); None where `/proc` has no such
/// files (not Linux). Differences of two readings say how many cores a piece of work kept
/// busy, which wall time alone cannot: on a machine whose cores a client and a server
/// share, their CPU times add up.
pub fn process_cpu_ms() -> Option<f64> {
    let mut ns = 0u64;
    for task in std::fs::read_dir("/proc/self/task").ok()?.flatten() {
        // A thread that ended since the listing has no file left: its time is gone anyway.
        let Ok(stat) = std::fs::read_to_string(task.path().join("schedstat")) else {
            continue;
        };
        ns += stat.split_whitespace().next()?.parse::<u64>().ok()?;
    }
    Some(ns as f64 / 1e6)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[cfg(target_os = "linux")]
    #[test]
    fn process_cpu_time_counts_a_busy_thread() {
        let start = process_cpu_ms().expect("Linux has /proc/self/task/*/schedstat");
        let wall = std::time::Instant::now();
        let mut x = 0u64;
        // Busy until 20 ms of CPU have been counted (a loaded machine may give this thread
        // less than its wall time), or fail after 10 s.
        while process_cpu_ms().unwrap() - start < 20.0 {
            x = std::hint::black_box(x.wrapping_mul(6364136223846793005).wrapping_add(1));
            assert!(wall.elapsed().as_secs() < 10, "20 ms of CPU never counted");
        }
    }

    #[test]
    fn nearest_rank_quantiles() {
        let v = [5.0, 1.0, 4.0, 2.0, 3.0];
        assert_eq!(quantile(&v, 0.5), 3.0);
        assert_eq!(quantile(&v, 0.95), 5.0);
        assert_eq!(quantile(&v, 0.0), 1.0);
        let t = Timing::of(&(1..=100).map(f64::from).collect::<Vec<_>>());
        assert_eq!((t.median_ms, t.p95_ms, t.count), (50.0, 95.0, 100));
        assert!(quantile(&[], 0.5).is_nan());
    }
}
