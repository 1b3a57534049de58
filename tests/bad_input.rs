//! Bad files give one-line errors that name the problem; nothing panics.

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
    assert!("nuke"
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
    assert!(s.contains("layer extra is 4x6 but layer beauty is 8x6"), "{s}");
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
