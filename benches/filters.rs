//! Every filter at 1920x1080 and at the odd size 1919x1079 on the synthetic G-buffer of
//! `afterimage::report::synthetic_frame`, plus a plain copy of the colour planes as the
//! memory-bandwidth probe (`afterimage::report::parallel_copy`, the one the report times).
//! `cargo bench --bench filters`. A filter's floor is the bytes it moves per frame
//! (`afterimage::report::bytes_per_pixel`, the parameter of its benchmark id, in bytes per
//! pixel) over the copy's bandwidth (24 bytes per pixel moved by copy_rgb: 12 read, 12
//! written): floor time = copy_rgb time * B/24. `afterimage report` computes the same ratio
//! in one run. Filters of sparse shading (`upsample` and its baseline methods) run on the
//! same G-buffer with its colour shaded at one pixel per 2x2 block
//! (`afterimage::report::synthetic_sparse_frame`); their colour read is a quarter.

use afterimage::filters::{create, list};
use afterimage::frame::ChannelSet;
use afterimage::report::{bytes_per_frame, parallel_copy, synthetic_frame, synthetic_sparse_frame};
use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion, Throughput};
use std::hint::black_box;
use std::time::Duration;

fn bench(c: &mut Criterion) {
    for (w, h) in [(1920usize, 1080usize), (1919, 1079)] {
        let frames = [synthetic_frame(w, h, 0), synthetic_frame(w, h, 1)];
        let sparse = [0, 1].map(|i| synthetic_sparse_frame(w, h, i, 2));
        let mut group = c.benchmark_group(format!("{w}x{h}"));
        group.sample_size(20).measurement_time(Duration::from_secs(8));
        group.throughput(Throughput::Elements((w * h) as u64));
        // The bandwidth probe: reading and writing the colour planes once (12 bytes in, 12
        // out per pixel) on the filters' pool.
        let src: Vec<f32> = frames[0]
            .color()
            .iter()
            .flat_map(|p| p.data().iter().copied())
            .collect();
        let mut dst = vec![0.0f32; src.len()];
        group.bench_function("copy_rgb", |b| {
            b.iter(|| {
                parallel_copy(&mut dst, black_box(&src));
                black_box(&dst);
            })
        });
        for info in list() {
            // One benchmark per value of `key`, labelled `label(value)`.
            let sweep =
                |key: &str, values: &[serde_json::Value], label: &dyn Fn(&serde_json::Value) -> String| {
                    values
                        .iter()
                        .map(|v| {
                            let mut m = serde_json::Map::new();
                            m.insert(key.into(), v.clone());
                            (label(v), m)
                        })
                        .collect::<Vec<_>>()
                };
            let variants = match info.name {
                "traa" => sweep("variant", &["baseline".into(), "improved".into()], &|v| {
                    format!("traa_{}", v.as_str().unwrap_or_default())
                }),
                // Shinya's cost grows as width x height x T: the two windows.
                "pixel_trace" => sweep("window", &[8.into(), 32.into()], &|v| format!("pixel_trace_T{v}")),
                // Herzog et al.'s method and the three baselines it is compared with.
                "upsample" => sweep(
                    "method",
                    &[
                        "spatiotemporal".into(),
                        "spatial".into(),
                        "temporal".into(),
                        "taa".into(),
                    ],
                    &|v| format!("upsample_{}", v.as_str().unwrap_or_default()),
                ),
                name => vec![(name.to_string(), Default::default())],
            };
            let frames = if info.sparse_input { &sparse } else { &frames };
            for (label, params) in variants {
                let mut f = create(info.name, &params).unwrap();
                // Fill a windowed filter's window: then every push gives one output.
                for i in 0..=f.lookahead() {
                    f.push(&frames[i % 2]).unwrap();
                }
                let moved = bytes_per_frame(
                    ChannelSet::of(&info.uses),
                    &frames[0],
                    f.state_bytes().div_ceil(w * h),
                )
                .div_ceil(w * h);
                let mut i = 1;
                group.bench_with_input(
                    BenchmarkId::new(label.clone(), format!("{moved}B_per_px")),
                    &(),
                    |b, _| {
                        b.iter(|| {
                            let out = f.push(&frames[i % 2]).unwrap();
                            i += 1;
                            black_box(out);
                        })
                    },
                );
            }
        }
        group.finish();
    }
}

criterion_group!(benches, bench);
criterion_main!(benches);
