//! One frame of each catalogue scene at the `scene` command's defaults (256x144, a 16x16
//! stratified reference = 256 samples per pixel, Halton jitter), on the crate's rayon pool:
//! the "a 256x144 frame with a 256-spp reference renders in well under a second" figure.
//! `cargo bench --bench scenes`.

use afterimage::scene::{Scene, Settings, CATALOGUE};
use criterion::{criterion_group, criterion_main, Criterion};
use std::hint::black_box;
use std::time::Duration;

fn bench(c: &mut Criterion) {
    let mut group = c.benchmark_group("scene_256x144_256spp");
    group.sample_size(10).measurement_time(Duration::from_secs(6));
    for entry in CATALOGUE {
        let scene = Scene::new(entry.name, Settings::default()).expect("catalogue scene");
        // Frame 5: past the first frames, where some scenes are still setting up.
        group.bench_function(entry.name, |b| b.iter(|| black_box(scene.frame(5))));
    }
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
