//! Bad files give one-line errors that name the problem; nothing panics. Then mutation
//! fuzzing on stable Rust of everything a client can send the server: EXR bodies, gRPC
//! frame headers and chunks, JSON session requests, and sequences of session operations.
//! A bounded number of cases runs in `cargo test`; `cargo test --release --test bad_input
//! -- --ignored --nocapture` runs the long campaign (`AFTERIMAGE_FUZZ_CASES` per target).
//! Every case is checked for panics and for the largest single allocation it made (this
//! crate's global allocator records it per thread), which must not grow with what a
//! header declares.

mod common;

use afterimage::frame::{ChannelKind, Frame, Plane};
use afterimage::io::{read_frame, write_exr, ChannelSpec, IoError, ReadOptions, WriteOptions};

fn one_line(e: &IoError) -> String {
    let s = e.to_string();
    assert!(!s.contains('\n'), "not one line: {s}");
    s
}

#[test]
fn truncated_exr() {
    let dir = tempfile::tempdir().unwrap();
    let src = std::fs::read(common::fixture("blender-motion/frame_0001.exr")).unwrap();
    let path = dir.path().join("cut.exr");
    std::fs::write(&path, &src[..src.len() / 2]).unwrap();
    let e = read_frame(&path, &ReadOptions::default()).unwrap_err();
    let s = one_line(&e);
    assert!(matches!(e, IoError::Format { .. }), "{s}");
    assert!(
        s.contains("cut.exr") && s.contains("not a readable OpenEXR file"),
        "{s}"
    );
    // Not an EXR at all.
    std::fs::write(&path, b"hello").unwrap();
    let s = one_line(&read_frame(&path, &ReadOptions::default()).unwrap_err());
    assert!(s.contains("OpenEXR"), "{s}");
    // Missing file.
    let s = one_line(&read_frame(&dir.path().join("none.exr"), &ReadOptions::default()).unwrap_err());
    assert!(s.contains("none.exr") && s.contains("no such file"), "{s}");
}

#[test]
fn missing_channel_names_what_was_asked_and_what_is_there() {
    let path = common::fixture("blender-motion/frame_0001.exr");
    let opts = ReadOptions {
        mapping: vec![ChannelSpec::parse_mapping("albedo=ViewLayer.Emit").unwrap()],
        ..ReadOptions::default()
    };
    let s = one_line(&read_frame(&path, &opts).unwrap_err());
    assert!(s.contains("channel albedo"), "{s}");
    assert!(s.contains("ViewLayer.Emit.{R,G,B}"), "{s}");
    assert!(s.contains("ViewLayer.DiffCol.R"), "lists present channels: {s}");
    // A preset that does not fit.
    let opts = ReadOptions {
        preset: "afterimage".parse().unwrap(),
        ..ReadOptions::default()
    };
    let s = one_line(&read_frame(&path, &opts).unwrap_err());
    assert!(s.contains("color.R") && s.contains("preset afterimage"), "{s}");
    // Explicit mappings that work.
    let opts = ReadOptions {
        mapping: vec![
            ChannelSpec::parse_mapping("color=ViewLayer.DiffCol").unwrap(),
            ChannelSpec::parse_mapping("depth=ViewLayer.Depth.Z").unwrap(),
        ],
        ..ReadOptions::default()
    };
    let f = read_frame(&path, &opts).unwrap();
    let blender = read_frame(&path, &ReadOptions::default()).unwrap();
    assert_eq!(f.color(), blender.albedo().unwrap());
    // Malformed mappings.
    for bad in ["color", "colour=R,G,B", "motion=X,Y,Z", "depth="] {
        let e = ChannelSpec::parse_mapping(bad).unwrap_err();
        assert!(e.to_string().contains(bad), "{e}");
    }
    assert!("houdini"
        .parse::<afterimage::io::PresetChoice>()
        .unwrap_err()
        .to_string()
        .contains("blender"));
}

#[test]
fn layers_of_different_sizes_are_refused() {
    use exr::prelude::*;
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("two_sizes.exr");
    let layer = |name: &str, w: usize, h: usize| {
        Layer::new(
            (w, h),
            LayerAttributes::named(name),
            Encoding::default(),
            AnyChannels::sort(smallvec::smallvec![
                AnyChannel::new("R", FlatSamples::F32(vec![0.5; w * h])),
                AnyChannel::new("G", FlatSamples::F32(vec![0.5; w * h])),
                AnyChannel::new("B", FlatSamples::F32(vec![0.5; w * h])),
            ]),
        )
    };
    Image::from_layers(
        ImageAttributes::new(IntegerBounds::from_dimensions((8, 6))),
        vec![layer("beauty", 8, 6), layer("extra", 4, 6)],
    )
    .write()
    .to_file(&path)
    .unwrap();
    let e = read_frame(&path, &ReadOptions::default()).unwrap_err();
    let s = one_line(&e);
    assert!(
        s.contains("layer extra has data window 4x6 at (0, 0) but layer beauty has 8x6 at (0, 0)"),
        "{s}"
    );
}

#[test]
fn multipart_layers_are_read_with_their_names() {
    use exr::prelude::*;
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("parts.exr");
    let layer = |name: &str, v: f32| {
        Layer::new(
            (5, 4),
            LayerAttributes::named(name),
            Encoding::default(),
            AnyChannels::sort(smallvec::smallvec![
                AnyChannel::new("R", FlatSamples::F32(vec![v; 20])),
                AnyChannel::new("G", FlatSamples::F32(vec![v; 20])),
                AnyChannel::new("B", FlatSamples::F32(vec![v; 20])),
            ]),
        )
    };
    Image::from_layers(
        ImageAttributes::new(IntegerBounds::from_dimensions((5, 4))),
        vec![layer("color", 0.25), layer("albedo", 0.75)],
    )
    .write()
    .to_file(&path)
    .unwrap();
    let f = read_frame(&path, &ReadOptions::default()).unwrap();
    assert_eq!(f.color()[1].get(2, 2), 0.25);
    assert_eq!(f.albedo().unwrap()[0].get(4, 3), 0.75);
}

#[test]
fn nan_filled_colour_is_read_and_counted() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("nan.exr");
    let (w, h) = (9, 7);
    let mut f = Frame::new([
        Plane::filled(w, h, f32::NAN),
        Plane::filled(w, h, 0.5),
        Plane::filled(w, h, f32::INFINITY),
    ])
    .unwrap();
    f.set_f32(ChannelKind::Depth, vec![Plane::filled(w, h, 1.0)])
        .unwrap();
    write_exr(&path, &f, &WriteOptions::default()).unwrap();
    let back = read_frame(&path, &ReadOptions::default()).unwrap();
    let n = back.non_finite();
    assert_eq!(n.of(ChannelKind::Color), 2 * 63);
    assert_eq!(n.of(ChannelKind::Depth), 0);
    assert_eq!(
        back.check_finite().unwrap_err().to_string(),
        "non-finite samples (color: 126)"
    );
}

// ---------------------------------------------------------------------------------------
// Mutation fuzzing.

mod fuzz {
    use afterimage::frame::{ChannelKind, ChannelSet, Frame};
    use afterimage::io::{
        encode_filtered, frame_and_input, read_raw_exr_bytes_limited, write_exr_bytes, Compression,
        ExrLimits, FilteredFrame, OutputOptions, Precision, ReadOptions, WriteOptions,
    };
    use afterimage::report::synthetic_frame;
    use afterimage::rng::SplitMix64;
    use afterimage::server::proto as pb;
    use afterimage::server::wire::{self, Assembly, FramePlan};
    use afterimage::session::FrameShape;
    use std::alloc::{GlobalAlloc, Layout, System};
    use std::cell::Cell;
    use std::panic::{catch_unwind, AssertUnwindSafe};
    use std::time::Instant;

    /// The system allocator, recording the largest single allocation of each thread.
    struct Tracking;

    thread_local! {
        static PEAK: Cell<usize> = const { Cell::new(0) };
    }

    fn note(size: usize) {
        let _ = PEAK.try_with(|p| {
            if size > p.get() {
                p.set(size)
            }
        });
    }

    // SAFETY: every call is passed to the system allocator unchanged; `note` only reads and
    // writes a const-initialised thread-local cell, which allocates nothing.
    unsafe impl GlobalAlloc for Tracking {
        unsafe fn alloc(&self, l: Layout) -> *mut u8 {
            note(l.size());
            unsafe { System.alloc(l) }
        }
        unsafe fn alloc_zeroed(&self, l: Layout) -> *mut u8 {
            note(l.size());
            unsafe { System.alloc_zeroed(l) }
        }
        unsafe fn realloc(&self, p: *mut u8, l: Layout, new: usize) -> *mut u8 {
            note(new);
            unsafe { System.realloc(p, l, new) }
        }
        unsafe fn dealloc(&self, p: *mut u8, l: Layout) {
            unsafe { System.dealloc(p, l) }
        }
    }

    #[global_allocator]
    static ALLOCATOR: Tracking = Tracking;

    /// Runs `f` and returns its result (None when it panicked) with the largest single
    /// allocation it made on this thread.
    fn measured<T>(f: impl FnOnce() -> T) -> (Option<T>, usize) {
        PEAK.with(|p| p.set(0));
        let r = catch_unwind(AssertUnwindSafe(f)).ok();
        (r, PEAK.with(|p| p.get()))
    }

    /// Cases per target: `AFTERIMAGE_FUZZ_CASES`, else `default`.
    fn cases(default: u64) -> u64 {
        std::env::var("AFTERIMAGE_FUZZ_CASES")
            .ok()
            .and_then(|v| v.parse().ok())
            .unwrap_or(default)
    }

    fn below(rng: &mut SplitMix64, n: usize) -> usize {
        (rng.next_u64() % n.max(1) as u64) as usize
    }

    const INTERESTING_32: [u32; 10] = [
        0,
        1,
        2,
        0x7f,
        0x80,
        0xffff,
        0x1_0000,
        100_000,
        0x7fff_ffff,
        0xffff_ffff,
    ];

    /// Mutates `data` in place with 1-4 edits: bit flips, interesting bytes and words,
    /// deletions, duplications, truncation, and tokens from `dict`.
    fn mutate(rng: &mut SplitMix64, data: &mut Vec<u8>, dict: &[&[u8]]) {
        for _ in 0..1 + below(rng, 4) {
            let len = data.len();
            let at = below(rng, len);
            match below(rng, 8) {
                0 if len > 0 => data[at] ^= 1 << below(rng, 8),
                1 if len > 0 => data[at] = [0u8, 1, 0x7f, 0x80, 0xff][below(rng, 5)],
                2 if len >= 4 => {
                    let at = below(rng, len - 3);
                    let v = if rng.next_u64().is_multiple_of(3) {
                        rng.next_u64() as u32
                    } else {
                        INTERESTING_32[below(rng, INTERESTING_32.len())]
                    };
                    data[at..at + 4].copy_from_slice(&v.to_le_bytes());
                }
                3 if len >= 8 => {
                    let at = below(rng, len - 7);
                    let v = [0u64, u64::MAX, 1 << 63, (1 << 32) + 1, rng.next_u64()][below(rng, 5)];
                    data[at..at + 8].copy_from_slice(&v.to_le_bytes());
                }
                4 if len > 1 => {
                    let end = (at + 1 + below(rng, 64)).min(len);
                    data.drain(at..end);
                }
                5 if len > 1 => {
                    let end = (at + 1 + below(rng, 64)).min(len);
                    let piece = data[at..end].to_vec();
                    let to = below(rng, len);
                    data.splice(to..to, piece);
                }
                6 if len > 1 => data.truncate(at.max(1)),
                _ if !dict.is_empty() => {
                    let token = dict[below(rng, dict.len())];
                    data.splice(at..at, token.iter().copied());
                }
                _ => data.push(rng.next_u64() as u8),
            }
        }
    }

    /// EXR files of `w x h` to start from: every writer layout, precision and
    /// compression, a tiled file, a multi-part file.
    fn exr_seeds(w: usize, h: usize) -> Vec<Vec<u8>> {
        let frame = synthetic_frame(w, h, 3);
        let mut seeds = Vec::new();
        for precision in [Precision::F16, Precision::F32] {
            for compression in [Compression::None, Compression::Zip, Compression::Piz] {
                let opts = WriteOptions {
                    precision,
                    compression,
                };
                seeds.push(write_exr_bytes(&frame, &opts).unwrap());
                // Colour alone as R,G,B, as a filtered frame without an input is written.
                let plain = afterimage::io::FilteredFrame {
                    color: frame.color(),
                    meta: &frame.meta,
                    record: None,
                    input: None,
                };
                let out = afterimage::io::OutputOptions {
                    keep: afterimage::io::Keep::None,
                    compression: Some(compression),
                    precision: Some(precision),
                };
                seeds.push(afterimage::io::encode_filtered(&plain, &out).unwrap());
            }
        }
        seeds.extend(exr_layout_seeds(w, h));
        seeds
    }

    /// A tiled RLE file and a two-part file, written with the exr crate directly.
    fn exr_layout_seeds(w: usize, h: usize) -> Vec<Vec<u8>> {
        use exr::prelude::*;
        let mut seeds = Vec::new();
        let channels = |v: f32| {
            AnyChannels::sort(
                ["B", "G", "R"]
                    .iter()
                    .map(|n| AnyChannel::new(*n, FlatSamples::F32(vec![v; w * h])))
                    .collect(),
            )
        };
        let tiled = Encoding {
            compression: exr::compression::Compression::RLE,
            blocks: Blocks::Tiles(Vec2(8, 8)),
            line_order: LineOrder::Increasing,
        };
        let mut out = Vec::new();
        Image::from_layer(Layer::new(
            (w, h),
            LayerAttributes::default(),
            tiled,
            channels(0.25),
        ))
        .write()
        .to_buffered(std::io::Cursor::new(&mut out))
        .unwrap();
        seeds.push(out);
        let mut out = Vec::new();
        Image::from_layers(
            ImageAttributes::new(IntegerBounds::from_dimensions((w, h))),
            vec![
                Layer::new(
                    (w, h),
                    LayerAttributes::named("beauty"),
                    Encoding::FAST_LOSSLESS,
                    channels(0.5),
                ),
                Layer::new(
                    (w, h),
                    LayerAttributes::named("extra"),
                    Encoding::SMALL_LOSSLESS,
                    channels(2.0),
                ),
            ],
        )
        .write()
        .to_buffered(std::io::Cursor::new(&mut out))
        .unwrap();
        seeds.push(out);
        seeds
    }

    /// Header attributes whose values set sizes: name and type as they stand in a file.
    const SIZE_ATTRIBUTES: &[&[u8]] = &[
        b"dataWindow\0box2i\0",
        b"displayWindow\0box2i\0",
        b"tiles\0tiledesc\0",
        b"chunkCount\0int\0",
    ];

    /// Structure-aware mutation: one 4-byte word of a size attribute's value set to an
    /// interesting value (what a hostile header does on purpose).
    fn mutate_size_attribute(rng: &mut SplitMix64, data: &mut [u8]) {
        let found: Vec<usize> = SIZE_ATTRIBUTES
            .iter()
            .flat_map(|name| {
                data.windows(name.len())
                    .enumerate()
                    .filter(move |(_, w)| w == name)
                    .map(move |(i, _)| i + name.len() + 4)
            })
            .collect();
        if found.is_empty() {
            return;
        }
        let at = found[below(rng, found.len())] + 4 * below(rng, 4);
        if at + 4 <= data.len() {
            let v = INTERESTING_32[below(rng, INTERESTING_32.len())];
            data[at..at + 4].copy_from_slice(&v.to_le_bytes());
        }
    }

    const EXR_TOKENS: &[&[u8]] = &[
        b"dataWindow\0box2i\0",
        b"displayWindow\0box2i\0",
        b"tiles\0tiledesc\0",
        b"compression\0compression\0",
        b"channels\0chlist\0",
        b"chunkCount\0int\0",
        b"type\0string\0",
        b"deepscanline",
        b"\xff\xff\xff\x7f",
    ];

    /// Mutated EXR files through `read` (which returns the image's width): never a panic,
    /// no single allocation over `bound`; prints `what` with the counts.
    fn fuzz_exr_with(
        n: u64,
        seed: u64,
        what: &str,
        bound: usize,
        read: impl Fn(&[u8], u64) -> Result<usize, afterimage::io::IoError>,
    ) {
        let mut seeds = exr_seeds(24, 16);
        seeds.push(super::common::lying_exr(4, 4));
        let fixture = std::fs::read(super::common::fixture("blender-motion/frame_0001.exr")).unwrap();
        let mut rng = SplitMix64::new(seed);
        let (mut ok, mut peak) = (0u64, 0usize);
        let t = Instant::now();
        for case in 0..n {
            let mut data = if case % 16 == 15 {
                fixture.clone()
            } else {
                seeds[below(&mut rng, seeds.len())].clone()
            };
            if rng.next_u64().is_multiple_of(2) {
                mutate_size_attribute(&mut rng, &mut data);
            }
            if rng.next_u64().is_multiple_of(2) {
                mutate(&mut rng, &mut data, EXR_TOKENS);
            }
            let (r, alloc) = measured(|| read(&data, case));
            let r = r.unwrap_or_else(|| {
                panic!(
                    "case {case} (seed {seed}) panicked; input: {}",
                    data.iter().map(|b| format!("{b:02x}")).collect::<String>()
                )
            });
            assert!(
                alloc <= bound,
                "case {case} (seed {seed}) allocated {alloc} bytes at once from a {}-byte file, bound {bound}",
                data.len()
            );
            peak = peak.max(alloc);
            if r.is_ok() {
                ok += 1;
                // A mutated file that still reads becomes a seed (the fuzzer walks on).
                if seeds.len() < 64 {
                    seeds.push(data);
                }
            }
        }
        let s = t.elapsed().as_secs_f64();
        eprintln!(
            "{what}: {n} cases in {s:.1} s ({:.0} cases/s), {ok} still readable, largest allocation {peak} bytes (bound {bound})",
            n as f64 / s
        );
    }

    /// The EXR reader the server uses, on mutated files: never a panic, no allocation
    /// beyond what the session's frame size allows, and every file it takes can be written
    /// back as the reply.
    fn fuzz_exr(n: u64, seed: u64) {
        let (w, h) = (24, 16);
        let limits = ExrLimits {
            size: Some((w, h)),
            max_pixels: (w * h) as u64,
            max_channels: 64,
            max_parts: 16,
            rewritable: true,
        };
        // The decoded planes of the largest allowed file, and the decoders' own buffers.
        let bound = 4 * w * h * limits.max_channels * 4 + (4 << 20);
        fuzz_exr_with(n, seed, "EXR reader", bound, |data, case| {
            let label = std::path::Path::new("fuzz");
            let raw = read_raw_exr_bytes_limited(data, label, &limits)?;
            // What the server does next: the frame, then its reply (the input file with
            // its colour replaced). A file the reader takes must be writable back, or the
            // server would filter it and then fail.
            let (frame, input) = frame_and_input(raw, &ReadOptions::default(), None)?;
            let reply = FilteredFrame {
                color: frame.color(),
                meta: &frame.meta,
                record: None,
                input: Some(&input),
            };
            encode_filtered(&reply, &OutputOptions::default()).unwrap_or_else(|e| {
                panic!(
                    "case {case} (seed {seed}) was read but its reply could not be written: {e}; input: {}",
                    data.iter().map(|b| format!("{b:02x}")).collect::<String>()
                )
            });
            Ok(frame.width())
        });
    }

    /// The CLI's EXR reader (`filter`, `batch`, `report` read files with it) on mutated
    /// files: never a panic, and no allocation past what the shared header check allows
    /// a small file (`ExrLimits::FILES`: at most 4096 times its bytes, or 64 MiB).
    fn fuzz_exr_files(n: u64, seed: u64) {
        let bound = (64 << 20) + (4 << 20);
        fuzz_exr_with(n, seed, "EXR file reader", bound, |data, _| {
            afterimage::io::read_raw_exr_bytes(data, std::path::Path::new("fuzz")).map(|r| r.width)
        });
    }

    /// Session state import on mutated state files, half of them with a recomputed
    /// SHA-256 (as a forger writes them): never a panic, no allocation past the session's
    /// size, and a state a filter accepts never makes it emit a non-finite sample.
    fn fuzz_state(n: u64, seed: u64) {
        use afterimage::pipeline::FilterState;
        use sha2::Digest;
        let (w, h) = (12, 8);
        let filters = ["taa", "traa", "phlm", "upsample", "fxaa", "passthrough"];
        let input = |i: u64| {
            let mut f = synthetic_frame(w, h, i);
            f.meta.index = i;
            f
        };
        let seeds: Vec<(&str, Vec<u8>)> = filters
            .iter()
            .map(|&name| {
                let mut f = afterimage::filters::create(name, &Default::default()).unwrap();
                for i in 0..3 {
                    f.push(&input(i)).unwrap();
                }
                (name, f.save_state().unwrap().encode())
            })
            .collect();
        let state_tokens: &[&[u8]] = &[
            b"AFTSTATE",
            br#""size":"#,
            br#""components":"#,
            br#""tonemapped":"#,
            b"null",
            b"true",
            b"false",
            b"[99999,99999]",
            b"\x00\x00\xc0\x7f",
            b"\x00\x00\x80\x7f",
            b"\x00\x00\x80\xbf",
            b"\xff\xff\x7f\x7f",
        ];
        // The planes of a 12x8 state and a 1 MiB header.
        let bound = w * h * 64 * 4 * 2 + (2 << 20);
        let mut rng = SplitMix64::new(seed);
        let (mut loaded, mut peak) = (0u64, 0usize);
        let t = Instant::now();
        for case in 0..n {
            let (name, seed_bytes) = &seeds[below(&mut rng, seeds.len())];
            let mut data = seed_bytes.clone();
            mutate(&mut rng, &mut data, state_tokens);
            if rng.next_u64().is_multiple_of(2) && data.len() > 32 {
                let body = data.len() - 32;
                let sum = sha2::Sha256::digest(&data[..body]);
                data[body..].copy_from_slice(&sum);
            }
            let (r, alloc) = measured(|| {
                let st = FilterState::decode(&data, (w * h) as u64).ok()?;
                let mut f = afterimage::filters::create(name, &Default::default()).unwrap();
                f.load_state(&st).ok()?;
                f.push(&input(3)).ok()
            });
            let r = r.unwrap_or_else(|| {
                panic!(
                    "case {case} (seed {seed}, {name}) panicked; input: {}",
                    data.iter().map(|b| format!("{b:02x}")).collect::<String>()
                )
            });
            assert!(
                alloc <= bound,
                "case {case} ({name}) allocated {alloc} bytes at once"
            );
            peak = peak.max(alloc);
            if let Some(outs) = r {
                loaded += 1;
                for o in outs {
                    for p in &o.color {
                        assert!(
                            p.data().iter().all(|v| v.is_finite()),
                            "case {case} ({name}): an accepted state made the filter emit a non-finite sample; input: {}",
                            data.iter().map(|b| format!("{b:02x}")).collect::<String>()
                        );
                    }
                }
            }
        }
        let s = t.elapsed().as_secs_f64();
        eprintln!(
            "state import: {n} cases in {s:.1} s ({:.0} cases/s), {loaded} loaded and filtered, largest allocation {peak} bytes (bound {bound})",
            n as f64 / s
        );
    }

    /// A frame's header and bytes as the client encodes them, for a session of `shape`.
    fn wire_seed(
        frame: &Frame,
        channels: ChannelSet,
        sample: pb::SampleType,
        compression: pb::Compression,
    ) -> (pb::FrameHeader, Vec<u8>) {
        let (h, chunks) = wire::encode_frame(frame, "s", channels, sample, compression, 1 << 20);
        let bytes = chunks.iter().flat_map(|c| c.data.iter().copied()).collect();
        (h, bytes)
    }

    /// The wire decoder on mutated headers and data: the plan refuses what does not fit
    /// the session before data is accepted, and decoding never panics or over-allocates.
    fn fuzz_wire(n: u64, seed: u64) {
        let (w, h) = (24, 16);
        let channels = ChannelSet::of(&[
            ChannelKind::Color,
            ChannelKind::Depth,
            ChannelKind::Motion,
            ChannelKind::ObjectId,
        ]);
        let shape = FrameShape {
            width: w as u32,
            height: h as u32,
            channels,
        };
        let frame = synthetic_frame(w, h, 1);
        let seeds: Vec<_> = [
            (pb::SampleType::F32, pb::Compression::None),
            (pb::SampleType::F16, pb::Compression::None),
            (pb::SampleType::F32, pb::Compression::Zstd),
            (pb::SampleType::F16, pb::Compression::Zstd),
        ]
        .into_iter()
        .map(|(s, c)| wire_seed(&frame, channels, s, c))
        .collect();
        let bound = 4 * (w * h * 16 * 4) + (1 << 20);
        let mut rng = SplitMix64::new(seed);
        let (mut planned, mut decoded, mut peak) = (0u64, 0u64, 0usize);
        let t = Instant::now();
        for case in 0..n {
            let (mut head, mut data) = seeds[below(&mut rng, seeds.len())].clone();
            // Mutate the header's fields (as a client can set any of them) or the data.
            match below(&mut rng, 3) {
                0 => {
                    if !head.channels.is_empty() {
                        let i = below(&mut rng, head.channels.len());
                        let c = &mut head.channels[i];
                        match below(&mut rng, 5) {
                            0 => {
                                c.byte_length = [
                                    0,
                                    1,
                                    u64::MAX,
                                    1 << 63,
                                    c.byte_length + 1,
                                    c.byte_length.saturating_sub(1),
                                    rng.next_u64(),
                                ][below(&mut rng, 7)]
                            }
                            1 => c.sample = below(&mut rng, 4) as i32 - (below(&mut rng, 2) as i32) * 100,
                            2 => c.compression = below(&mut rng, 3) as i32,
                            3 => {
                                c.name = ["color", "depth", "reference", "albedo", "colour", ""]
                                    [below(&mut rng, 6)]
                                .into()
                            }
                            _ => {
                                let dup = c.clone();
                                head.channels.push(dup);
                            }
                        }
                    }
                }
                1 => {
                    head.shading_factor = [0, 1, 2, 3, 4, 8, u32::MAX][below(&mut rng, 7)];
                    head.shading_phase_x = below(&mut rng, 5) as u32;
                    head.shading_phase_y = [0, 1, u32::MAX][below(&mut rng, 3)];
                }
                _ => mutate(&mut rng, &mut data, &[]),
            }
            let (r, alloc) = measured(|| {
                let plan = FramePlan::check(&head, shape, 1 << 30)?;
                let mut a = Assembly::start(head.clone(), plan);
                if case % 2 == 1 {
                    // Copied into planes as the chunks arrive, where the header allows.
                    a.land(&mut Default::default());
                }
                for chunk in data.chunks(4096) {
                    a.push(chunk.to_vec(), 1 << 20)?;
                }
                if !a.complete() {
                    return Ok(false);
                }
                wire::decode(&mut a, shape, &mut Default::default(), None).map(|_| true)
            });
            let r = r.unwrap_or_else(|| panic!("case {case} (seed {seed}) panicked; header {head:?}"));
            assert!(
                alloc <= bound,
                "case {case} (seed {seed}) allocated {alloc} bytes at once, bound {bound}"
            );
            peak = peak.max(alloc);
            match r {
                Ok(true) => decoded += 1,
                Ok(false) => planned += 1,
                Err(_) => {}
            }
        }
        let s = t.elapsed().as_secs_f64();
        eprintln!(
            "wire decoder: {n} cases in {s:.1} s ({:.0} cases/s), {decoded} decoded, {planned} planned but short, largest allocation {peak} bytes",
            n as f64 / s
        );
    }

    /// A random JSON value: any type, extreme numbers, long strings, nesting.
    fn json_value(rng: &mut SplitMix64, depth: usize) -> serde_json::Value {
        use serde_json::{json, Value};
        match below(rng, if depth > 2 { 6 } else { 8 }) {
            0 => Value::Null,
            1 => Value::Bool(rng.next_u64().is_multiple_of(2)),
            2 => [
                json!(0),
                json!(1),
                json!(-1),
                json!(7),
                json!(1e300),
                json!(-1e-300),
                json!(u64::MAX),
                json!(i64::MIN),
                json!(0.5),
            ][below(rng, 9)]
            .clone(),
            3 => json!(rng.range(-1e6, 1e6)),
            4 => Value::String(
                ["", "baseline", "improved", "paper", "bilinear", "x"][below(rng, 6)]
                    .repeat(1 + below(rng, 3)),
            ),
            5 => Value::String("\u{1F600}\u{0}\\\"".repeat(below(rng, 300))),
            6 => Value::Array((0..below(rng, 4)).map(|_| json_value(rng, depth + 1)).collect()),
            _ => {
                let mut m = serde_json::Map::new();
                for _ in 0..below(rng, 4) {
                    m.insert(format!("k{}", below(rng, 5)), json_value(rng, depth + 1));
                }
                Value::Object(m)
            }
        }
    }

    /// `POST /v1/sessions` through the router (no socket) with generated and mutated
    /// bodies: every answer is 201 or a 4xx with a JSON error of bounded length, never a
    /// 5xx, never a panic.
    fn fuzz_json(n: u64, seed: u64) {
        use afterimage::server::http::router;
        use afterimage::server::{Config, Service};
        use afterimage::session::Keyring;
        use axum::body::Body;
        use http_body_util::BodyExt;
        use tower::ServiceExt;
        let rt = tokio::runtime::Builder::new_current_thread()
            .enable_all()
            .build()
            .unwrap();
        let filters: Vec<(String, Vec<String>)> = afterimage::filters::list()
            .into_iter()
            .map(|i| {
                (
                    i.name.to_string(),
                    i.params.iter().map(|p| p.name.to_string()).collect(),
                )
            })
            .collect();
        let mut rng = SplitMix64::new(seed);
        let mut counts = std::collections::BTreeMap::<u16, u64>::new();
        let t = Instant::now();
        rt.block_on(async {
            let mut svc = Service::new(Config::default(), Keyring::default());
            for case in 0..n {
                if case % 50 == 0 {
                    svc = Service::new(Config::default(), Keyring::default());
                }
                let (name, params) = &filters[below(&mut rng, filters.len())];
                let mut body = serde_json::json!({"filter": name, "width": 1 + below(&mut rng, 48), "height": 1 + below(&mut rng, 48)});
                let mut p = serde_json::Map::new();
                for _ in 0..below(&mut rng, 3) {
                    let key = if params.is_empty() || rng.next_u64().is_multiple_of(4) { "nope".to_string() } else { params[below(&mut rng, params.len())].clone() };
                    p.insert(key, json_value(&mut rng, 0));
                }
                body["params"] = p.into();
                match below(&mut rng, 6) {
                    0 => body["width"] = json_value(&mut rng, 0),
                    1 => body["channels"] = json_value(&mut rng, 0),
                    2 => body["motion"] = json_value(&mut rng, 0),
                    3 => body["filter"] = json_value(&mut rng, 0),
                    _ => {}
                }
                let mut bytes = serde_json::to_vec(&body).unwrap();
                if rng.next_u64().is_multiple_of(3) {
                    mutate(&mut rng, &mut bytes, &[b"{", b"}", b"\"", b"\\u0000", b"1e999", b"-"]);
                }
                let req = axum::http::Request::post("/v1/sessions")
                    .header("content-type", "application/json")
                    .body(Body::from(bytes.clone()))
                    .unwrap();
                let resp = router(svc.clone()).oneshot(req).await.unwrap();
                let status = resp.status().as_u16();
                let out = resp.into_body().collect().await.unwrap().to_bytes();
                let text = String::from_utf8_lossy(&bytes);
                assert!(
                    status == 201 || (400..500).contains(&status),
                    "case {case} (seed {seed}): {status} for {text}: {}",
                    String::from_utf8_lossy(&out)
                );
                if status != 201 {
                    let v: serde_json::Value = serde_json::from_slice(&out).unwrap_or_else(|e| panic!("case {case}: not JSON ({e}): {}", String::from_utf8_lossy(&out)));
                    let m = v["error"]["message"].as_str().unwrap_or_default();
                    assert!(!m.is_empty() && m.len() <= 1024, "case {case}: message of {} bytes", m.len());
                }
                *counts.entry(status).or_default() += 1;
            }
        });
        let s = t.elapsed().as_secs_f64();
        eprintln!(
            "JSON bodies: {n} cases in {s:.1} s ({:.0} cases/s), statuses {counts:?}",
            n as f64 / s
        );
    }

    /// Random sequences of session operations (create, frames of the right and wrong
    /// size, channels missing, NaN floods, cuts, flushes, streams, concurrent checkouts,
    /// closes) against a model: frame counts, one output per causal frame, the budget
    /// equal to the state reserved, and only the caller's errors.
    fn fuzz_sessions(n: u64, seed: u64) {
        use afterimage::session::{Caller, Limits, MotionInput, SessionError, SessionRequest, Sessions};
        let a = Caller::ANONYMOUS;
        let filters = [
            "passthrough",
            "fxaa",
            "taa",
            "traa",
            "phlm",
            "upsample",
            "pixel_trace",
        ];
        let mut rng = SplitMix64::new(seed);
        let t = Instant::now();
        let (mut ops, mut frames_ok) = (0u64, 0u64);
        for case in 0..n {
            let sessions = Sessions::new(Limits {
                max_sessions: 4,
                memory_budget_bytes: 2 << 20,
                ..Limits::default()
            });
            // Open sessions: id, filter, size, frames filtered.
            let mut open: Vec<(String, &str, (usize, usize), u64)> = Vec::new();
            for _ in 0..8 + below(&mut rng, 24) {
                ops += 1;
                let op = below(&mut rng, 10);
                let r: Result<(), SessionError> = (|| {
                    if open.is_empty() || op == 0 {
                        let filter = filters[below(&mut rng, filters.len())];
                        let (w, h) = (1 + below(&mut rng, 40), 1 + below(&mut rng, 30));
                        let mut params = Vec::new();
                        if filter == "pixel_trace" {
                            params.push(("window".to_string(), (2 * below(&mut rng, 4)).to_string()));
                        }
                        let req = SessionRequest {
                            filter: filter.into(),
                            params,
                            width: w as u32,
                            height: h as u32,
                            ..Default::default()
                        };
                        let info = sessions.create(&a, &req)?;
                        open.push((info.id, filter, (w, h), 0));
                        return Ok(());
                    }
                    let k = below(&mut rng, open.len());
                    let (id, filter, (w, h), _) = open[k].clone();
                    match op {
                        1 => {
                            sessions.close(&a, &id)?;
                            open.remove(k);
                        }
                        2 => {
                            let outs = sessions.checkout(&a, &id)?.flush()?;
                            assert!(
                                filter == "pixel_trace" || outs.is_empty(),
                                "case {case}: a causal filter flushed {}",
                                outs.len()
                            );
                        }
                        3 => {
                            // Two requests at once: the second is refused, not waited for.
                            let held = sessions.checkout(&a, &id)?;
                            let e = sessions.checkout(&a, &id).err().expect("busy");
                            assert!(matches!(e, SessionError::Busy(_)), "case {case}: {e}");
                            drop(held);
                        }
                        _ => {
                            let (fw, fh) = if rng.next_u64().is_multiple_of(8) {
                                (w + 1, h)
                            } else {
                                (w, h)
                            };
                            let mut f = synthetic_frame(fw, fh, open[k].3);
                            f.meta.index = open[k].3;
                            f.meta.reset = rng.next_u64().is_multiple_of(10);
                            if rng.next_u64().is_multiple_of(8) {
                                f.remove(ChannelKind::Motion);
                            }
                            if rng.next_u64().is_multiple_of(8) {
                                let frac = rng.next_f64();
                                for p in f.color_mut() {
                                    for v in p.iter_mut() {
                                        if rng.next_f64() < frac {
                                            *v = [f32::NAN, f32::INFINITY, -1.0][below(&mut rng, 3)];
                                        }
                                    }
                                }
                            }
                            let outs = if op == 9 {
                                let claim = sessions.attach(&a, &id)?;
                                let r = claim.checkout()?.process(f, MotionInput::Internal);
                                r?
                            } else {
                                sessions.checkout(&a, &id)?.process(f, MotionInput::Internal)?
                            };
                            if filter != "pixel_trace" {
                                assert_eq!(
                                    outs.len(),
                                    1,
                                    "case {case}: {filter} gave {} outputs for one frame",
                                    outs.len()
                                );
                            }
                            open[k].3 += 1;
                            frames_ok += 1;
                        }
                    }
                    Ok(())
                })();
                if let Err(e) = r {
                    assert!(
                        matches!(e, SessionError::Invalid { .. } | SessionError::Exhausted(_)),
                        "case {case}: unexpected {e:?}"
                    );
                }
                let totals = sessions.totals();
                assert_eq!(totals.sessions, open.len(), "case {case}");
                assert_eq!(
                    totals.budget_used, totals.state_bytes,
                    "case {case}: budget held by no session"
                );
                for (id, _, _, frames) in &open {
                    assert_eq!(sessions.get(&a, id).unwrap().frames, *frames, "case {case}");
                }
            }
        }
        let s = t.elapsed().as_secs_f64();
        eprintln!(
            "session operations: {n} sequences, {ops} operations ({frames_ok} frames filtered) in {s:.1} s ({:.0} operations/s)",
            ops as f64 / s
        );
    }

    #[test]
    fn exr_reader_survives_mutated_files() {
        fuzz_exr(cases(8000), 1);
    }

    #[test]
    fn exr_file_reader_survives_mutated_files() {
        fuzz_exr_files(cases(2000), 5);
    }

    #[test]
    fn state_import_survives_mutated_and_forged_states() {
        fuzz_state(cases(3000), 6);
    }

    #[test]
    fn wire_decoder_survives_mutated_frames() {
        fuzz_wire(cases(20_000), 2);
    }

    #[test]
    fn session_requests_survive_generated_json() {
        fuzz_json(cases(2000), 3);
    }

    #[test]
    fn session_state_machine_holds_its_invariants() {
        fuzz_sessions(cases(60), 4);
    }

    #[test]
    #[ignore = "the long campaign: cargo test --release --test bad_input -- --ignored --nocapture"]
    fn long_fuzz_campaign() {
        fuzz_exr(cases(500_000), 101);
        fuzz_exr_files(cases(500_000), 105);
        fuzz_state(cases(500_000), 106);
        fuzz_wire(cases(2_000_000), 102);
        fuzz_json(cases(100_000), 103);
        fuzz_sessions(cases(3000), 104);
    }
}

/// A file whose `afterimage.jitter` is no jitter (not finite, or past 1 px) reads as an
/// unknown jitter (0): the reconstruct stage weighs samples by it. A jitter in range is
/// read as written.
#[test]
fn an_out_of_range_jitter_attribute_reads_as_unknown() {
    let dir = tempfile::tempdir().unwrap();
    for (i, (written, read)) in [
        ([5.0, 0.0], [0.0, 0.0]),
        ([f32::NAN, 0.25], [0.0, 0.0]),
        ([-0.375, 0.25], [-0.375, 0.25]),
    ]
    .into_iter()
    .enumerate()
    {
        let path = dir.path().join(format!("j{i}.exr"));
        let mut f = Frame::new(std::array::from_fn(|_| Plane::filled(4, 3, 0.5))).unwrap();
        f.meta.jitter = written;
        write_exr(&path, &f, &WriteOptions::default()).unwrap();
        let back = read_frame(&path, &ReadOptions::default()).unwrap();
        assert_eq!(back.meta.jitter, read, "{written:?}");
    }
}
