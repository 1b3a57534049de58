//! The wire's sample codecs (`afterimage_client::codec::{put_samples, get_samples}`) on one
//! frame's colour at 1920x1080 and at the odd size 1919x1079, next to a plain parallel copy
//! of the same f32 bytes (`copy_rgb`, the floor of the f32 codecs: on a little-endian host
//! they are that copy). Every gRPC frame and reply goes through them, on both ends.
//! Then the shared memory transport's read of the same bytes on one thread: from a region
//! (`region_read_f32`), between two slices with the same loop (`copy_f32`), and as a
//! `memcpy` followed by a count of the NaNs (`copy_then_count`, the read it replaced).
//! `cargo bench --bench wire`.

use afterimage::report::{parallel_copy, synthetic_frame};
use afterimage_client::codec::{get_samples, put_samples, sample_bytes};
use afterimage_client::proto::SampleType;
use afterimage_shm::{copy_f32, Mapping};
use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion, Throughput};
use std::hint::black_box;
use std::time::Duration;

const SIZES: [(usize, usize); 2] = [(1920, 1080), (1919, 1079)];

fn bench(c: &mut Criterion) {
    for (w, h) in SIZES {
        let frame = synthetic_frame(w, h, 0);
        let src: Vec<f32> = frame
            .color()
            .iter()
            .flat_map(|p| p.data().iter().copied())
            .collect();
        let mut group = c.benchmark_group(format!("wire_{w}x{h}"));
        group.sample_size(30).measurement_time(Duration::from_secs(4));
        group.throughput(Throughput::Bytes(4 * src.len() as u64));
        let mut copy = vec![0.0f32; src.len()];
        group.bench_function("copy_rgb", |b| {
            b.iter(|| {
                parallel_copy(&mut copy, black_box(&src));
                black_box(&copy);
            })
        });
        for sample in [SampleType::F32, SampleType::F16] {
            let mut bytes = vec![0u8; src.len() * sample_bytes(sample)];
            let name = format!("{sample:?}").to_lowercase();
            group.bench_with_input(BenchmarkId::new("put", &name), &(), |b, _| {
                b.iter(|| {
                    put_samples(black_box(&src), sample, &mut bytes);
                    black_box(&bytes);
                })
            });
            let mut back = vec![0.0f32; src.len()];
            group.bench_with_input(BenchmarkId::new("get", &name), &(), |b, _| {
                b.iter(|| {
                    get_samples(black_box(&bytes), sample, &mut back);
                    black_box(&back);
                })
            });
        }
        let mut into = vec![0.0f32; src.len()];
        group.bench_function("copy_then_count", |b| {
            b.iter(|| {
                into.copy_from_slice(black_box(&src));
                black_box(afterimage::frame::count_non_finite(&into))
            })
        });
        group.bench_function("copy_f32", |b| {
            b.iter(|| black_box(copy_f32(black_box(&src), &mut into)))
        });
        let region = Mapping::create("bench", 4 * src.len() as u64).expect("a shared memory region");
        let bytes: Vec<u8> = src.iter().flat_map(|v| v.to_ne_bytes()).collect();
        region.write(0, &bytes).expect("within the region");
        group.bench_function("region_read_f32", |b| {
            b.iter(|| black_box(region.read_f32(0, &mut into).expect("within the region")))
        });
        group.finish();
    }
}

criterion_group!(benches, bench);
criterion_main!(benches);
