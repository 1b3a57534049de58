//! Every filter at 1920x1080 and at the odd size 1919x1079, plus a plain copy of the same
//! bytes as the memory-bandwidth floor. `cargo bench --bench filters`; the medians are the
//! figures quoted in the issue notes and the README.

use afterimage::frame::{ChannelKind, Frame, Plane};
use afterimage::pipeline::{create, list};
use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion, Throughput};
use std::hint::black_box;
use std::time::Duration;

/// A synthetic G-buffer frame: textured colour with some HDR highlights, a depth ramp with
/// object steps, object ids in blocks, albedo, and a uniform sub-pixel pan, so every stage
/// of every filter runs.
fn frame(w: usize, h: usize, index: u64) -> Frame {
    let t = index as f32;
    let pat = |x: usize, y: usize, k: f32| {
        let (fx, fy) = (x as f32 + 1.3 * t, y as f32 - 0.7 * t);
        0.5 + 0.45 * ((fx * 0.21 + k).sin() * (fy * 0.17 - k).cos())
    };
    let color = [0.0, 1.0, 2.0].map(|k| {
        Plane::from_fn(w, h, |x, y| {
            pat(x, y, k) * if (x / 97 + y / 89) % 11 == 0 { 8.0 } else { 1.0 }
        })
    });
    let mut f = Frame::new(color).unwrap();
    let albedo = [0.5, 1.5, 2.5].map(|k| Plane::from_fn(w, h, |x, y| pat(x, y, k)));
    f.set_f32(ChannelKind::Albedo, albedo.to_vec()).unwrap();
    f.set_f32(
        ChannelKind::Depth,
        vec![Plane::from_fn(w, h, |x, y| {
            2.0 + y as f32 * 0.01 + ((x / 64) % 3) as f32
        })],
    )
    .unwrap();
    f.set_f32(
        ChannelKind::Motion,
        vec![Plane::filled(w, h, -1.3f32), Plane::filled(w, h, 0.7f32)],
    )
    .unwrap();
    f.set_object_id(Plane::from_fn(w, h, |x, y| (1 + x / 64 + 30 * (y / 64)) as u32))
        .unwrap();
    f.meta.index = index;
    f
}

fn bench(c: &mut Criterion) {
    for (w, h) in [(1920usize, 1080usize), (1919, 1079)] {
        let frames = [frame(w, h, 0), frame(w, h, 1)];
        let mut group = c.benchmark_group(format!("{w}x{h}"));
        group.sample_size(20).measurement_time(Duration::from_secs(8));
        group.throughput(Throughput::Elements((w * h) as u64));
        // The floor: reading and writing the colour planes once (12 bytes in, 12 out per pixel).
        let src: Vec<f32> = frames[0]
            .color()
            .iter()
            .flat_map(|p| p.data().iter().copied())
            .collect();
        let mut dst = vec![0.0f32; src.len()];
        group.bench_function("copy_rgb", |b| {
            b.iter(|| {
                dst.copy_from_slice(black_box(&src));
                black_box(&dst);
            })
        });
        for info in list() {
            let variants: Vec<(String, serde_json::Map<String, serde_json::Value>)> = if info.name == "traa" {
                ["baseline", "improved"]
                    .iter()
                    .map(|v| {
                        let mut m = serde_json::Map::new();
                        m.insert("variant".into(), (*v).into());
                        (format!("traa_{v}"), m)
                    })
                    .collect()
            } else {
                vec![(info.name.to_string(), Default::default())]
            };
            for (label, params) in variants {
                let mut f = create(info.name, &params).unwrap();
                f.process(&frames[0]).unwrap();
                let mut i = 1;
                group.bench_with_input(
                    BenchmarkId::new(label.clone(), f.state_bytes() / (w * h)),
                    &(),
                    |b, _| {
                        b.iter(|| {
                            let out = f.process(&frames[i % 2]).unwrap();
                            i += 1;
                            black_box(out.color);
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
