//! Writing and reading back: lossless in f32, within f16 rounding in f16, for every
//! compression; PNG within 8-bit quantisation; sequences in every spelling.

mod common;

use afterimage::frame::{ChannelKind, DepthKind, Frame, NormalSpace, Plane};
use afterimage::io::{
    read_frame, write_exr, write_png, Compression, Precision, ReadOptions, Sequence, WriteOptions,
};
use afterimage::tolerance::Tolerance;

/// A frame with every channel, HDR colour (up to 6e4, inside f16's range) and random
/// values everywhere, on an odd size.
fn full_frame(seed: u64) -> Frame {
    let (w, h) = (37, 23);
    let mut f = Frame::new(common::random_rgb(w, h, seed, 0.0, 6.0e4)).unwrap();
    let one = |s: u64, lo: f64, hi: f64| common::random_rgb(w, h, s, lo, hi)[0].clone();
    f.set_f32(ChannelKind::Depth, vec![one(seed + 1, 0.1, 1000.0)])
        .unwrap();
    f.set_f32(
        ChannelKind::Motion,
        vec![one(seed + 2, -40.0, 40.0), one(seed + 3, -40.0, 40.0)],
    )
    .unwrap();
    f.set_f32(
        ChannelKind::Normal,
        common::random_rgb(w, h, seed + 4, -1.0, 1.0).to_vec(),
    )
    .unwrap();
    f.set_f32(
        ChannelKind::Albedo,
        common::random_rgb(w, h, seed + 5, 0.0, 1.0).to_vec(),
    )
    .unwrap();
    f.set_f32(
        ChannelKind::Reference,
        common::random_rgb(w, h, seed + 6, 0.0, 10.0).to_vec(),
    )
    .unwrap();
    f.set_object_id(Plane::from_fn(w, h, |x, y| {
        (x * 1_000_003 + y * 77) as u32 % 70_000
    }))
    .unwrap();
    f.meta.index = 17;
    f.meta.jitter = [0.25, -0.375];
    f.meta.reset = true;
    f.meta.exposure = Some(1.5);
    f.meta.near_far = Some([0.1, 500.0]);
    f.meta.depth_kind = DepthKind::Linear;
    f.meta.normal_space = NormalSpace::View;
    f
}

/// `f` written as EXR at `precision` with each compression and read back.
fn exr_round_trips(f: &Frame, precision: Precision) -> Vec<(Compression, Frame)> {
    let dir = tempfile::tempdir().unwrap();
    [Compression::None, Compression::Zip, Compression::Piz]
        .into_iter()
        .map(|compression| {
            let path = dir.path().join(format!("{compression:?}.exr"));
            write_exr(
                &path,
                f,
                &WriteOptions {
                    precision,
                    compression,
                },
            )
            .unwrap();
            (compression, read_frame(&path, &ReadOptions::default()).unwrap())
        })
        .collect()
}

#[test]
fn f32_round_trip_is_lossless_for_every_compression() {
    let f = full_frame(1);
    for (compression, back) in exr_round_trips(&f, Precision::F32) {
        assert_eq!(back, f, "{compression:?}");
    }
}

#[test]
fn f16_round_trip_is_within_half_rounding() {
    let f = full_frame(2);
    for (compression, back) in exr_round_trips(&f, Precision::F16) {
        assert_eq!(back.channels(), f.channels());
        assert_eq!(back.meta, f.meta);
        assert_eq!(back.object_id(), f.object_id(), "ids stay exact u32");
        for kind in f.channels().iter().filter(|k| *k != ChannelKind::ObjectId) {
            for (a, b) in f.planes(kind).unwrap().iter().zip(back.planes(kind).unwrap()) {
                Tolerance::F16_ROUNDING
                    .check_slices(&format!("{kind} {compression:?}"), b.data(), a.data())
                    .unwrap();
            }
        }
        // And f16 really was written: at least some values changed.
        assert_ne!(back.color(), f.color());
    }
}

#[test]
fn a_filtered_frame_without_an_input_is_written_as_plain_colour() {
    let dir = tempfile::tempdir().unwrap();
    let f = full_frame(3);
    let path = dir.path().join("plain.exr");
    let frame = afterimage::io::FilteredFrame {
        color: f.color(),
        meta: &f.meta,
        record: Some(r#"{"filter":"taa"}"#),
        input: None,
    };
    afterimage::io::write_filtered(&path, &frame, &Default::default()).unwrap();
    let raw = afterimage::io::read_raw(&path).unwrap();
    let names: Vec<_> = raw.channels.iter().map(|c| c.name.as_str()).collect();
    assert_eq!(names, ["B", "G", "R"]);
    let back = read_frame(&path, &ReadOptions::default()).unwrap();
    assert_eq!(back.color(), f.color());
}

#[test]
fn png_round_trip_within_8_bit_srgb() {
    let dir = tempfile::tempdir().unwrap();
    let rgb = common::random_rgb(19, 11, 9, 0.0, 1.0);
    let path = dir.path().join("p.png");
    write_png(&path, &rgb, false).unwrap();
    let back = read_frame(&path, &ReadOptions::default()).unwrap();
    for (written, read) in rgb.iter().zip(back.color()) {
        for (&a, &b) in written.data().iter().zip(read.data()) {
            // Half a code value in sRGB space.
            let (ea, eb) = (
                afterimage::io::linear_to_srgb(a),
                afterimage::io::linear_to_srgb(b),
            );
            assert!(
                Tolerance::abs(0.5 / 255.0 + 1e-6).eq(ea as f64, eb as f64),
                "{a} vs {b}"
            );
        }
    }
}

fn write_seq(dir: &std::path::Path, numbers: &[u64]) {
    for &n in numbers {
        let mut f = full_frame(n);
        f.meta.index = 0;
        write_exr(
            &dir.join(format!("shot_{n:04}.exr")),
            &f,
            &WriteOptions::default(),
        )
        .unwrap();
    }
}

#[test]
fn sequences_from_directory_pattern_and_glob() {
    let dir = tempfile::tempdir().unwrap();
    write_seq(dir.path(), &[12, 10, 11, 9]);
    std::fs::write(dir.path().join("notes.txt"), "not a frame").unwrap();
    let d = dir.path().display();
    for spec in [
        format!("{d}"),
        format!("{d}/shot_%04d.exr"),
        format!("{d}/shot_*.exr"),
    ] {
        let seq = Sequence::open(&spec).unwrap();
        let numbers: Vec<u64> = seq.entries.iter().map(|e| e.number).collect();
        assert_eq!(numbers, [9, 10, 11, 12], "{spec}");
        let frames: Vec<Frame> = seq
            .frames(&ReadOptions::default())
            .collect::<Result<_, _>>()
            .unwrap();
        assert_eq!(frames[2].meta.index, 11);
    }
}

#[test]
fn a_gap_in_a_sequence_names_the_missing_frame() {
    let dir = tempfile::tempdir().unwrap();
    write_seq(dir.path(), &[1, 2, 4]);
    let spec = format!("{}/shot_%04d.exr", dir.path().display());
    let err = Sequence::open(&spec).unwrap_err().to_string();
    assert!(err.contains("frame 3 is missing"), "{err}");
    assert!(err.contains("shot_0003.exr"), "{err}");
    let err = Sequence::open(&dir.path().display().to_string())
        .unwrap_err()
        .to_string();
    assert!(err.contains("frame 3 is missing"), "{err}");
    let err = Sequence::open(&format!("{}/nothing_%04d.exr", dir.path().display()))
        .unwrap_err()
        .to_string();
    assert!(err.contains("no file matches"), "{err}");
}

#[test]
fn jpeg_and_16_bit_png_are_decoded_from_srgb() {
    let dir = tempfile::tempdir().unwrap();
    // A smooth 8-bit gradient as JPEG (lossy: a few code values of error).
    let (w, h) = (32u32, 16u32);
    let img = image::RgbImage::from_fn(w, h, |x, y| image::Rgb([(x * 8) as u8, (y * 16) as u8, 128]));
    let jpg = dir.path().join("g.jpg");
    img.save(&jpg).unwrap();
    let f = read_frame(&jpg, &ReadOptions::default()).unwrap();
    assert_eq!((f.width(), f.height()), (32, 16));
    let back = afterimage::io::linear_to_srgb(f.color()[2].get(5, 5)) * 255.0;
    // Chroma subsampling moves it a few code values; undecoded sRGB would give 187.
    assert!(Tolerance::abs(8.0).eq(back as f64, 128.0), "{back}");
    // 16-bit PNG: full precision survives.
    let img16 = image::ImageBuffer::<image::Rgb<u16>, _>::from_fn(w, h, |x, _| {
        image::Rgb([x as u16 * 2000, 65535, 0])
    });
    let png = dir.path().join("g16.png");
    img16.save(&png).unwrap();
    let f = read_frame(&png, &ReadOptions::default()).unwrap();
    let v = afterimage::io::linear_to_srgb(f.color()[0].get(7, 3));
    Tolerance::abs(1e-5)
        .check("16-bit", v as f64, 14000.0 / 65535.0)
        .unwrap();
    assert_eq!(f.color()[1].get(0, 0), 1.0);
}
