//! Helpers shared by the integration tests.
#![allow(dead_code)]

use afterimage::frame::{Plane, Rgb};
use afterimage::scene::{Jitter, Settings};
use std::path::{Path, PathBuf};

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

/// Scene settings without jitter or noise: `width` x `height`, `frames`, `spp` reference
/// samples, `seed`, one pixel shaded in every `shading` x `shading` block.
pub fn unjittered(width: usize, height: usize, frames: u64, spp: u32, seed: u64, shading: u32) -> Settings {
    Settings {
        width,
        height,
        frames,
        spp,
        jitter: Jitter::None,
        noise: false,
        seed,
        shading,
    }
}

/// A check skipped for a missing tool: `SKIPPED: {skipped}` on stderr, unless the
/// environment variable `require` is set (CI installs the tool and sets it): then the test
/// fails with `{require} is set but {missing}`.
pub fn skip_missing_tool(require: &str, missing: &str, skipped: &str) {
    assert!(
        std::env::var_os(require).is_none(),
        "{require} is set but {missing}"
    );
    eprintln!("SKIPPED: {skipped}");
}

/// The `afterimage` binary built for this test run.
pub fn bin() -> std::process::Command {
    std::process::Command::new(env!("CARGO_BIN_EXE_afterimage"))
}

/// Runs the `afterimage` binary with `args`: whether it succeeded, its stdout and stderr.
pub fn run(args: &[&str]) -> (bool, String, String) {
    let out = bin().args(args).output().unwrap();
    (
        out.status.success(),
        String::from_utf8_lossy(&out.stdout).into_owned(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

/// Runs the `afterimage` binary with `args`, which must succeed (else the test fails with
/// its stderr): its stdout.
pub fn run_ok(args: &[&str]) -> String {
    let (ok, out, err) = run(args);
    assert!(ok, "{err}");
    out
}

/// EXR images as the `exr` crate reads them: every part, channel and attribute.
pub type ExrImage =
    exr::prelude::Image<exr::prelude::Layers<exr::prelude::AnyChannels<exr::prelude::FlatSamples>>>;

/// Reads every part of an EXR file with the `exr` crate directly (not through our reader).
pub fn read_exr_all(path: &Path) -> ExrImage {
    use exr::prelude::*;
    read()
        .no_deep_data()
        .largest_resolution_level()
        .all_channels()
        .all_layers()
        .all_attributes()
        .from_file(path)
        .unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

/// The pass-through inputs: the three-frame Blender render `blender-motion` as rendered,
/// cropped (data window 320x180 at (10, 5) inside a 350x200 display), in overscan (data at
/// (-16, -8) around a 288x164 display), and Nuke-style multi-part (one part per Blender
/// pass, named `ViewLayer.Combined` and so on, colour in half floats with PIZ). Written
/// under `root/<name>/frame_000N.exr`; returns (name, directory).
pub fn passthrough_inputs(root: &Path) -> Vec<(&'static str, PathBuf)> {
    use exr::prelude::*;
    let mut out = Vec::new();
    for name in ["blender", "cropped", "overscan", "multipart"] {
        let dir = root.join(name);
        std::fs::create_dir_all(&dir).unwrap();
        for n in 1..=3 {
            let src = fixture(&format!("blender-motion/frame_{n:04}.exr"));
            let mut image = read_exr_all(&src);
            match name {
                "cropped" => {
                    image.layer_data[0].attributes.layer_position = Vec2(10, 5);
                    image.attributes.display_window = IntegerBounds::new((0, 0), (350, 200));
                }
                "overscan" => {
                    image.layer_data[0].attributes.layer_position = Vec2(-16, -8);
                    image.attributes.display_window = IntegerBounds::new((0, 0), (288, 164));
                }
                "multipart" => image = split_into_parts(image),
                _ => {}
            }
            image
                .write()
                .to_file(dir.join(format!("frame_{n:04}.exr")))
                .unwrap();
        }
        out.push((name, dir));
    }
    out
}

/// One part per channel prefix (`ViewLayer.Combined.R` goes to part `ViewLayer.Combined`
/// as `R`); the colour part in f16 with PIZ.
fn split_into_parts(image: ExrImage) -> ExrImage {
    use exr::prelude::*;
    let mut image = into_parts(&image, |full| {
        let (prefix, last) = full.rsplit_once('.').unwrap();
        Some((prefix.to_string(), last.to_string()))
    });
    for layer in &mut image.layer_data {
        let name = layer.attributes.layer_name.as_ref().unwrap().to_string();
        if name.ends_with("Combined") {
            layer.encoding.compression = Compression::PIZ;
            for ch in &mut layer.channel_data.list {
                if let FlatSamples::F32(v) = &ch.sample_data {
                    ch.sample_data = FlatSamples::F16(v.iter().map(|&x| f16::from_f32(x)).collect());
                }
            }
        }
    }
    image
}

/// The one-part `image` rewritten as parts: `part_of(full channel name)` gives the part
/// and the name the channel is written under in it, or None to leave the channel out.
/// Parts come in the order their first channel does; each keeps the original part's
/// attributes (named) and encoding.
pub fn into_parts(image: &ExrImage, part_of: impl Fn(&str) -> Option<(String, String)>) -> ExrImage {
    use exr::prelude::*;
    let layer = &image.layer_data[0];
    let mut groups: Vec<(String, Vec<AnyChannel<FlatSamples>>)> = Vec::new();
    for ch in &layer.channel_data.list {
        let Some((part, name)) = part_of(&ch.name.to_string()) else {
            continue;
        };
        let c = AnyChannel::new(name.as_str(), ch.sample_data.clone());
        match groups.iter_mut().find(|(p, _)| *p == part) {
            Some((_, list)) => list.push(c),
            None => groups.push((part, vec![c])),
        }
    }
    let layers: Vec<_> = groups
        .into_iter()
        .map(|(part, list)| {
            let mut attributes = layer.attributes.clone();
            attributes.layer_name = Some(Text::from(part.as_str()));
            Layer::new(
                layer.size,
                attributes,
                layer.encoding,
                AnyChannels::sort(list.into()),
            )
        })
        .collect();
    Image::from_layers(image.attributes.clone(), layers)
}

/// What an output may differ in from its input besides the colour samples.
#[derive(Clone, Copy, Debug, Default)]
pub struct Expect {
    /// Compression of every part (None: each input part's own).
    pub compression: Option<exr::compression::Compression>,
}

/// The one pass-through check for every path (CLI, HTTP, gRPC): `output` replaces `input`.
/// Same display window, parts (names, data windows, compression), channels (names, sample
/// types); every channel but the colour's (`*.R`, `*.G`, `*.B` of the part holding
/// `Combined`, or plain `R,G,B`) bit-identical, alpha included; every header attribute
/// kept except `afterimage.*`; the colour finite; the frame's record in
/// `afterimage.record`.
pub fn assert_replaces(input: &Path, output: &Path, expect: Expect) {
    use exr::prelude::*;
    let (a, b) = (read_exr_all(input), read_exr_all(output));
    let what = format!("{} -> {}", input.display(), output.display());
    assert_eq!(
        a.attributes.display_window, b.attributes.display_window,
        "display window: {what}"
    );
    assert_eq!(a.attributes.pixel_aspect, b.attributes.pixel_aspect, "{what}");
    assert_eq!(a.layer_data.len(), b.layer_data.len(), "parts: {what}");
    let strip = |attrs: &LayerAttributes| {
        let mut attrs = attrs.clone();
        attrs
            .other
            .retain(|k, _| !k.to_string().starts_with("afterimage."));
        attrs
    };
    let mut records = 0;
    for (la, lb) in a.layer_data.iter().zip(&b.layer_data) {
        let part = la
            .attributes
            .layer_name
            .as_ref()
            .map(|t| t.to_string())
            .unwrap_or_default();
        assert_eq!(la.attributes.layer_name, lb.attributes.layer_name, "{what}");
        assert_eq!(
            (la.attributes.layer_position, la.size),
            (lb.attributes.layer_position, lb.size),
            "data window of part {part:?}: {what}"
        );
        let compression = expect.compression.unwrap_or(la.encoding.compression);
        assert_eq!(
            lb.encoding.compression, compression,
            "compression of part {part:?}: {what}"
        );
        assert_eq!(
            strip(&la.attributes),
            strip(&lb.attributes),
            "attributes of part {part:?}: {what}"
        );
        let holds_color = lb.channel_data.list.iter().any(|c| {
            let full = if part.is_empty() {
                c.name.to_string()
            } else {
                format!("{part}.{}", c.name)
            };
            full == "R" || (full.contains("Combined") && full.ends_with(".R"))
        });
        if !holds_color {
            let stale: Vec<String> = lb
                .attributes
                .other
                .keys()
                .map(|k| k.to_string())
                .filter(|k| k.starts_with("afterimage."))
                .collect();
            assert!(
                stale.is_empty(),
                "part {part:?} has frame attributes {stale:?}: {what}"
            );
        }
        if let Some(AttributeValue::Text(t)) = lb.attributes.other.get(&Text::from("afterimage.record")) {
            let v: serde_json::Value = serde_json::from_str(&t.to_string()).expect("record is JSON");
            assert!(v.is_object(), "{v}");
            records += 1;
        }
        let names = |l: &Layer<AnyChannels<FlatSamples>>| -> Vec<String> {
            l.channel_data.list.iter().map(|c| c.name.to_string()).collect()
        };
        assert_eq!(names(la), names(lb), "channels of part {part:?}: {what}");
        for (ca, cb) in la.channel_data.list.iter().zip(&lb.channel_data.list) {
            let full = if part.is_empty() {
                ca.name.to_string()
            } else {
                format!("{part}.{}", ca.name)
            };
            let is_color = ["R", "G", "B"]
                .iter()
                .any(|c| full == *c || (full.contains("Combined") && full.ends_with(&format!(".{c}"))));
            let bits = |s: &FlatSamples| -> (&'static str, Vec<u32>) {
                match s {
                    FlatSamples::F16(v) => ("f16", v.iter().map(|x| x.to_bits() as u32).collect()),
                    FlatSamples::F32(v) => ("f32", v.iter().map(|x| x.to_bits()).collect()),
                    FlatSamples::U32(v) => ("u32", v.clone()),
                }
            };
            let ((ta, va), (tb, vb)) = (bits(&ca.sample_data), bits(&cb.sample_data));
            assert_eq!(ta, tb, "sample type of {full}: {what}");
            if is_color {
                let finite = match &cb.sample_data {
                    FlatSamples::F16(v) => v.iter().all(|x| x.is_finite()),
                    FlatSamples::F32(v) => v.iter().all(|x| x.is_finite()),
                    FlatSamples::U32(_) => true,
                };
                assert!(finite, "{full} has non-finite samples: {what}");
            } else {
                assert!(va == vb, "{full} is not bit-identical: {what}");
            }
        }
    }
    assert_eq!(records, 1, "one part carries afterimage.record: {what}");
}

/// A valid 4x4 EXR, uncompressed, in one 4x4 tile, whose data window, display window and
/// tile size are then rewritten to `w x h` (395 bytes that declare a `w x h` image).
pub fn lying_exr(w: i32, h: i32) -> Vec<u8> {
    use exr::prelude::*;
    let channels = AnyChannels::sort(
        ["B", "G", "R"]
            .iter()
            .map(|n| AnyChannel::new(*n, FlatSamples::F32(vec![0.5; 16])))
            .collect(),
    );
    let encoding = Encoding {
        compression: exr::compression::Compression::Uncompressed,
        blocks: Blocks::Tiles(Vec2(4, 4)),
        line_order: LineOrder::Increasing,
    };
    let layer = Layer::new((4, 4), LayerAttributes::default(), encoding, channels);
    let mut exr = Vec::new();
    Image::from_layer(layer)
        .write()
        .to_buffered(std::io::Cursor::new(&mut exr))
        .unwrap();
    let patch = |exr: &mut Vec<u8>, name: &[u8], values: &[i32]| {
        let at = exr.windows(name.len()).position(|x| x == name).unwrap() + name.len() + 4;
        for (k, v) in values.iter().enumerate() {
            exr[at + 4 * k..at + 4 * k + 4].copy_from_slice(&v.to_le_bytes());
        }
    };
    patch(&mut exr, b"dataWindow\0box2i\0", &[0, 0, w - 1, h - 1]);
    patch(&mut exr, b"displayWindow\0box2i\0", &[0, 0, w - 1, h - 1]);
    patch(&mut exr, b"tiles\0tiledesc\0", &[w, h]);
    exr
}
