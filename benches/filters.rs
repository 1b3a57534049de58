//! Every filter at 1920x1080 and at the odd size 1919x1079 on the synthetic G-buffer of
//! `afterimage::report::synthetic_frame`, next to the memory-bandwidth probe the report uses
//! (`copy_64MiB`: `afterimage::report::parallel_copy` of `COPY_BYTES`, larger than the
//! last-level cache, as a frame's planes are) and a copy of one frame's colour (`copy_rgb`,
//! which partly stays in cache and is faster). `cargo bench --bench filters [-- REGEX]`.
//!
//! A filter's floor is the bytes it moves per frame (`afterimage::report::bytes_per_frame`:
//! the channels it reads, its state read and written, the RGB output; in the benchmark id as
//! bytes per pixel) at the probe's bandwidth. After criterion's own output the bench prints
//! one table per size: median ms/frame, frames/s, the floor and the ratio to it, from the
//! estimates of this run. With `--features gpu` the filters the GPU backend has run there
//! too (`taa_gpu`, `passthrough_gpu`: upload, passes and readback per frame). Filters of sparse shading (`upsample` and its baseline methods)
//! run on the same G-buffer with its colour shaded at one pixel per 2x2 block
//! (`afterimage::report::synthetic_sparse_frame`); their colour read is a quarter.

use afterimage::backend::BackendChoice;
use afterimage::filters::list;
use afterimage::frame::ChannelSet;
use afterimage::report::{
    bytes_per_frame, parallel_copy, synthetic_frame, synthetic_sparse_frame, COPY_BYTES,
};
use criterion::{BenchmarkId, Criterion, Throughput};
use std::hint::black_box;
use std::path::Path;
use std::time::Duration;

const SIZES: [(usize, usize); 2] = [(1920, 1080), (1919, 1079)];

/// One benchmark per value of `key`, labelled `label(value)`.
fn sweep(
    key: &str,
    values: &[serde_json::Value],
    label: &dyn Fn(&serde_json::Value) -> String,
) -> Vec<(String, serde_json::Map<String, serde_json::Value>)> {
    values
        .iter()
        .map(|v| {
            let mut m = serde_json::Map::new();
            m.insert(key.into(), v.clone());
            (label(v), m)
        })
        .collect()
}

/// The benchmarks of each filter: its parameter variants worth timing apart.
fn variants(name: &str) -> Vec<(String, serde_json::Map<String, serde_json::Value>)> {
    match name {
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
    }
}

/// [`variants`] on the CPU, and with the `gpu` feature each variant of a filter the GPU
/// backend has again on the GPU (labelled `..._gpu`; on lavapipe a correctness build, not a
/// speed one).
fn backends(name: &str) -> Vec<(String, serde_json::Map<String, serde_json::Value>, BackendChoice)> {
    let mut out: Vec<_> = variants(name)
        .into_iter()
        .map(|(l, p)| (l, p, BackendChoice::Cpu))
        .collect();
    if afterimage::backend::gpu_filters().contains(&name) {
        out.extend(
            variants(name)
                .into_iter()
                .map(|(l, p)| (format!("{l}_gpu"), p, BackendChoice::Gpu)),
        );
    }
    out
}

fn bench(c: &mut Criterion) {
    // The bandwidth probe of the floor, as `afterimage report` measures it.
    let n = COPY_BYTES / 4;
    let big_src: Vec<f32> = (0..n).map(|i| i as f32).collect();
    let mut big_dst = vec![0.0f32; n];
    let mut group = c.benchmark_group("probe");
    group.sample_size(20).measurement_time(Duration::from_secs(4));
    group.throughput(Throughput::Bytes(2 * COPY_BYTES as u64));
    group.bench_function("copy_64MiB", |b| {
        b.iter(|| {
            parallel_copy(&mut big_dst, black_box(&big_src));
            black_box(&big_dst);
        })
    });
    group.finish();
    for (w, h) in SIZES {
        let frames = [synthetic_frame(w, h, 0), synthetic_frame(w, h, 1)];
        let sparse = [0, 1].map(|i| synthetic_sparse_frame(w, h, i, 2));
        let mut group = c.benchmark_group(format!("{w}x{h}"));
        group.sample_size(20).measurement_time(Duration::from_secs(8));
        group.throughput(Throughput::Elements((w * h) as u64));
        // One frame's colour planes read and written (12 bytes in, 12 out per pixel).
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
            let frames = if info.sparse_input { &sparse } else { &frames };
            for (label, params, choice) in backends(info.name) {
                let mut f = afterimage::backend::create(info.name, &params, choice)
                    .unwrap()
                    .filter;
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
                            for o in out {
                                f.recycle(black_box(o).color);
                            }
                        })
                    },
                );
            }
        }
        group.finish();
    }
}

/// The median of a benchmark's latest run, ms (None when it did not run this time).
fn median_ms(dir: &Path) -> Option<f64> {
    let text = std::fs::read_to_string(dir.join("new/estimates.json")).ok()?;
    let v: serde_json::Value = serde_json::from_str(&text).ok()?;
    Some(v["median"]["point_estimate"].as_f64()? / 1e6)
}

/// Prints, per size, every filter benchmarked in this run with its floor and ratio.
fn summary(started: std::time::SystemTime) {
    let root = Path::new(env!("CARGO_TARGET_TMPDIR")).join("../criterion");
    let fresh = |d: &Path| {
        std::fs::metadata(d.join("new/estimates.json"))
            .and_then(|m| m.modified())
            .is_ok_and(|t| t >= started)
    };
    let probe = root.join("probe/copy_64MiB");
    let Some(copy_ms) = fresh(&probe).then(|| median_ms(&probe)).flatten() else {
        println!("(no copy_64MiB probe in this run: no floor table)");
        return;
    };
    let bytes_per_s = 2.0 * COPY_BYTES as f64 / (copy_ms / 1e3);
    println!(
        "\nfloor: copy of {} MiB at {:.1} GB/s (median {copy_ms:.2} ms)",
        COPY_BYTES >> 20,
        bytes_per_s / 1e9
    );
    for (w, h) in SIZES {
        let Ok(entries) = std::fs::read_dir(root.join(format!("{w}x{h}"))) else {
            continue;
        };
        let mut rows = Vec::new();
        for filter in entries.flatten() {
            let Ok(ids) = std::fs::read_dir(filter.path()) else {
                continue;
            };
            for id in ids.flatten() {
                let name = id.file_name().to_string_lossy().to_string();
                let Some(bpp) = name.strip_suffix("B_per_px").and_then(|b| b.parse::<f64>().ok()) else {
                    continue;
                };
                if let Some(ms) = fresh(&id.path()).then(|| median_ms(&id.path())).flatten() {
                    let floor = bpp * (w * h) as f64 / bytes_per_s * 1e3;
                    rows.push((filter.file_name().to_string_lossy().to_string(), bpp, ms, floor));
                }
            }
        }
        if rows.is_empty() {
            continue;
        }
        rows.sort_by(|a, b| a.0.cmp(&b.0));
        println!("\n{w}x{h}: | filter | B/px | ms/frame | frames/s | floor ms | x floor |");
        for (f, bpp, ms, floor) in rows {
            println!(
                "| {f} | {bpp:.0} | {ms:.2} | {:.1} | {floor:.2} | {:.1} |",
                1e3 / ms,
                ms / floor
            );
        }
    }
}

fn main() {
    let started = std::time::SystemTime::now();
    let mut c = Criterion::default().configure_from_args();
    bench(&mut c);
    c.final_summary();
    summary(started);
}
