//! Helpers shared by the integration tests.
#![allow(dead_code)]

use afterimage::frame::{Plane, Rgb};
use std::path::PathBuf;

/// `tests/fixtures/<rel>`.
pub fn fixture(rel: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("tests/fixtures")
        .join(rel)
}

/// A deterministic RGB image with values in `[lo, hi)`.
pub fn random_rgb(w: usize, h: usize, seed: u64, lo: f64, hi: f64) -> Rgb {
    let mut rng = afterimage::rng::SplitMix64::new(seed);
    [0, 1, 2].map(|_| Plane::from_fn(w, h, |_, _| rng.range(lo, hi) as f32))
}

/// The `afterimage` binary built for this test run.
pub fn bin() -> std::process::Command {
    std::process::Command::new(env!("CARGO_BIN_EXE_afterimage"))
}
