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

#[cfg(test)]
mod tests {
    use super::*;

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
