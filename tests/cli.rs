//! The `afterimage` binary: `info`, `eval`, `--help`.

mod common;

use afterimage::frame::{ChannelKind, Frame, Plane};
use afterimage::io::{read_frame, write_exr, ReadOptions, Sequence, WriteOptions};
use afterimage::metrics::{Evaluator, SpaceChoice};
use afterimage::tolerance::Tolerance;

fn run(args: &[&str]) -> (bool, String, String) {
    let out = common::bin().args(args).output().unwrap();
    (
        out.status.success(),
        String::from_utf8_lossy(&out.stdout).into_owned(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

/// The subcommands, as the top-level help lists them.
fn commands() -> Vec<String> {
    let (ok, out, _) = run(&["--help"]);
    assert!(ok && out.contains("Usage"), "{out}");
    out.lines()
        .skip_while(|l| !l.starts_with("Commands:"))
        .skip(1)
        .take_while(|l| l.starts_with("  "))
        .filter_map(|l| l.split_whitespace().next())
        .filter(|c| *c != "help")
        .map(str::to_string)
        .collect()
}

#[test]
fn help_on_every_command() {
    let commands = commands();
    assert_eq!(
        commands,
        ["info", "eval", "filter", "filters", "report", "serve", "stream", "scene", "keygen"]
    );
    for c in &commands {
        let (ok, out, err) = run(&[c, "--help"]);
        assert!(
            ok && out.contains(&format!("Usage: afterimage {c}")),
            "{c}: {out}{err}"
        );
        // One spelling of the common options everywhere.
        assert!(out.contains("-j, --threads <N>"), "{c} --help has no -j: {out}");
        assert!(!out.contains("--out "), "{c} --help still says --out: {out}");
        let short: &[&str] = match c.as_str() {
            "filter" | "stream" => &["-i, --input", "-o, --output"],
            "eval" => &["-i, --input"],
            "scene" | "report" => &["-o, --output"],
            _ => &[],
        };
        for s in short {
            assert!(out.contains(s), "{c} --help lacks {s}: {out}");
        }
    }
    let (ok, out, _) = run(&["eval", "--help"]);
    assert!(ok && out.contains("--reference") && out.contains("--preset"));
}

#[test]
fn a_closed_pipe_ends_quietly() {
    use std::process::Stdio;
    // The reader goes away before the command writes (`afterimage ... | head -0`).
    for args in [&["filters", "--json"][..], &["filters"], &["scene", "--list"]] {
        let mut child = common::bin()
            .args(args)
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap();
        drop(child.stdout.take());
        let out = child.wait_with_output().unwrap();
        assert!(
            out.status.success(),
            "{args:?} after the reader left: {:?}, stderr {}",
            out.status,
            String::from_utf8_lossy(&out.stderr)
        );
        assert!(
            out.stderr.is_empty(),
            "{args:?}: {}",
            String::from_utf8_lossy(&out.stderr)
        );
    }
}

#[test]
fn threads_flag_is_checked() {
    // tests/report.rs checks that `-j` sizes the pool.
    let (ok, _, err) = run(&["filters", "--threads", "lots"]);
    assert!(!ok && err.contains("--threads"), "{err}");
}

#[test]
fn info_gives_windows_and_compression() {
    use exr::prelude::*;
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("crop.1001.exr");
    // A cropped render: data 140x80 at (10, 5) inside a 160x90 display window, PIZ.
    let (w, h) = (140usize, 80usize);
    let mut attrs = LayerAttributes::named("beauty");
    attrs.layer_position = Vec2(10, 5);
    let layer = Layer::new(
        (w, h),
        attrs,
        Encoding {
            compression: exr::compression::Compression::PIZ,
            ..Encoding::default()
        },
        AnyChannels::sort(smallvec::smallvec![
            AnyChannel::new("R", FlatSamples::F32(vec![0.5; w * h])),
            AnyChannel::new("G", FlatSamples::F32(vec![0.5; w * h])),
            AnyChannel::new("B", FlatSamples::F32(vec![0.5; w * h])),
        ]),
    );
    Image::from_layers(
        ImageAttributes::new(IntegerBounds::from_dimensions((160, 90))),
        vec![layer],
    )
    .write()
    .to_file(&path)
    .unwrap();
    let p = path.to_str().unwrap();
    let (ok, out, err) = run(&["info", p]);
    assert!(ok, "{err}");
    assert!(
        out.contains(
            "part 0 (beauty): data 140x80 at (10, 5), display 160x90 at (0, 0), PIZ compression, 3 channels"
        ),
        "{out}"
    );
    let (ok, out, _) = run(&["info", p, "--json"]);
    let v: serde_json::Value = serde_json::from_str(&out).unwrap();
    assert!(ok);
    let part = &v["parts"][0];
    assert_eq!(
        (
            &part["data_window"]["x"],
            &part["data_window"]["width"],
            &part["display_window"]["height"]
        ),
        (
            &serde_json::json!(10),
            &serde_json::json!(140),
            &serde_json::json!(90)
        )
    );
    assert_eq!(part["compression"], "PIZ");
}

#[test]
fn info_describes_many_files_and_sequences() {
    let dir = common::fixture("blender-motion");
    let d = dir.to_str().unwrap();
    let first = format!("{d}/frame_0001.exr");
    let second = format!("{d}/frame_0002.exr");
    let pattern = format!("{d}/frame_%04d.exr");
    let (ok, out, err) = run(&["info", &first, &second]);
    assert!(ok, "{err}");
    let files: Vec<&str> = out.lines().filter(|l| l.starts_with("file:")).collect();
    assert_eq!(files.len(), 2, "{out}");
    assert!(files[1].ends_with("frame_0002.exr"), "{out}");
    for spec in [d, pattern.as_str()] {
        let (ok, out, err) = run(&["info", spec, "--json"]);
        assert!(ok, "{spec}: {err}");
        let v: serde_json::Value = serde_json::from_str(&out).unwrap();
        let all = v
            .as_array()
            .unwrap_or_else(|| panic!("{spec}: an array for a sequence"));
        assert_eq!(all.len(), 3, "{spec}");
        assert!(all.iter().all(|f| f["width"].as_u64() > Some(0)), "{spec}");
    }
    // One file: one object, as before.
    let (ok, out, _) = run(&["info", &first, "--json"]);
    assert!(
        ok && serde_json::from_str::<serde_json::Value>(&out)
            .unwrap()
            .is_object()
    );
}

#[test]
fn info_describes_a_blender_file() {
    let f = common::fixture("blender-motion/frame_0002.exr");
    let (ok, out, err) = run(&["info", "--json", f.to_str().unwrap()]);
    assert!(ok, "{err}");
    let v: serde_json::Value = serde_json::from_str(&out).unwrap();
    assert_eq!(v["width"], 320);
    assert_eq!(v["preset"], "blender");
    assert_eq!(v["motion_convention"], "blender");
    assert_eq!(v["non_finite_total"], 0);
    let vx = v["channels"]
        .as_array()
        .unwrap()
        .iter()
        .find(|c| c["name"] == "ViewLayer.Vector.X")
        .unwrap();
    Tolerance::abs(1e-4)
        .check("min Vector.X", vx["min"].as_f64().unwrap(), -5.0)
        .unwrap();
    let (ok, text, _) = run(&["info", f.to_str().unwrap()]);
    assert!(ok);
    assert!(text.contains("preset:  blender (detected)"), "{text}");
    assert!(
        text.contains("motion     <- ViewLayer.Vector.X, ViewLayer.Vector.Y"),
        "{text}"
    );
}

#[test]
fn info_reports_non_finite_counts_instead_of_failing() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("nan.exr");
    let mut c = Plane::filled(6, 4, 0.5f32);
    c.set(1, 1, f32::NAN);
    c.set(2, 1, f32::NEG_INFINITY);
    let f = Frame::new([c, Plane::filled(6, 4, f32::NAN), Plane::filled(6, 4, 0.1)]).unwrap();
    write_exr(&path, &f, &WriteOptions::default()).unwrap();
    let (ok, out, err) = run(&["info", "--json", path.to_str().unwrap()]);
    assert!(ok, "{err}");
    let v: serde_json::Value = serde_json::from_str(&out).unwrap();
    assert_eq!(v["non_finite_total"], 26);
    let r = v["channels"]
        .as_array()
        .unwrap()
        .iter()
        .find(|c| c["name"] == "color.R")
        .unwrap();
    assert_eq!((r["nan"].as_u64(), r["inf"].as_u64()), (Some(1), Some(1)));
    let (_, text, _) = run(&["info", path.to_str().unwrap()]);
    assert!(text.contains("warning: 26 non-finite samples"), "{text}");
}

#[test]
fn bad_files_fail_with_one_line() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("broken.exr");
    std::fs::write(&path, b"\x76\x2f\x31\x01garbage").unwrap();
    let (ok, out, err) = run(&["info", path.to_str().unwrap()]);
    assert!(!ok && out.is_empty());
    assert_eq!(err.trim().lines().count(), 1, "{err}");
    assert!(err.starts_with("error: ") && err.contains("broken.exr"), "{err}");
    let (ok, _, err) = run(&["eval", "--input", path.to_str().unwrap()]);
    assert!(!ok && err.contains("broken.exr"), "{err}");
}

#[test]
fn eval_matches_the_library_and_writes_every_format() {
    let input = common::fixture("blender-fence/input");
    let reference = common::fixture("blender-fence/reference");
    let (i, r) = (input.to_str().unwrap(), reference.to_str().unwrap());
    let (ok, out, err) = run(&["eval", "--input", i, "--reference", r, "--json"]);
    assert!(ok, "{err}");
    let v: serde_json::Value = serde_json::from_str(&out).unwrap();
    // The same figures in process.
    let mut e = Evaluator::new(SpaceChoice::Auto);
    let opts = ReadOptions::default();
    let ins: Vec<Frame> = Sequence::open(i)
        .unwrap()
        .frames(&opts)
        .collect::<Result<_, _>>()
        .unwrap();
    let refs: Vec<Frame> = Sequence::open(r)
        .unwrap()
        .frames(&opts)
        .collect::<Result<_, _>>()
        .unwrap();
    for (a, b) in ins.iter().zip(&refs) {
        e.push(a.meta.index, a.color(), b.color(), false).unwrap();
    }
    let s = e.summary().unwrap();
    let t = Tolerance::rel(1e-12);
    t.check(
        "mean psnr",
        v["summary"]["mean_psnr"].as_f64().unwrap(),
        s.mean_psnr,
    )
    .unwrap();
    t.check("trmse", v["summary"]["trmse"].as_f64().unwrap(), s.trmse.unwrap())
        .unwrap();
    assert_eq!(v["frames"].as_array().unwrap().len(), 4);
    assert_eq!(v["summary"]["space"], "tonemapped", "the reference goes above 1");
    // CSV: a header and a row per frame.
    let (ok, csv, _) = run(&[
        "eval",
        "--input",
        i,
        "--reference",
        r,
        "--csv",
        "--space",
        "linear",
    ]);
    assert!(ok);
    assert_eq!(csv.lines().count(), 5);
    assert!(csv.starts_with("frame,mse,rmse,psnr_db,ssim,temporal_mse"));
    // The table, and an SSIM map that decodes as an image of the frame's size.
    let map = tempfile::tempdir().unwrap();
    let png = map.path().join("ssim.png");
    let (ok, table, err) = run(&[
        "eval",
        "--input",
        i,
        "--reference",
        r,
        "--ssim-map",
        "2",
        "--ssim-map-out",
        png.to_str().unwrap(),
    ]);
    assert!(ok, "{err}");
    assert!(
        table.contains("| frame | PSNR dB |") && table.contains("4 frames"),
        "{table}"
    );
    let img = image::open(&png).unwrap();
    assert_eq!((img.width(), img.height()), (160, 90));
    let (ok, _, err) = run(&[
        "eval",
        "--input",
        i,
        "--reference",
        r,
        "--ssim-map",
        "9",
        "--ssim-map-out",
        png.to_str().unwrap(),
    ]);
    assert!(!ok && err.contains("no frame numbered 9"), "{err}");
}

#[test]
fn eval_uses_the_reference_channel_and_checks_sizes() {
    let dir = tempfile::tempdir().unwrap();
    let src = read_frame(
        &common::fixture("blender-motion/frame_0001.exr"),
        &ReadOptions::default(),
    )
    .unwrap();
    // A frame carrying its own reference: the colour, 0.1 brighter.
    let mut f = src.clone();
    let brighter = f.color().clone().map(|p| p.map(|v| v + 0.1));
    f.set_f32(ChannelKind::Reference, brighter.to_vec()).unwrap();
    write_exr(&dir.path().join("f_0001.exr"), &f, &WriteOptions::default()).unwrap();
    let (ok, out, err) = run(&[
        "eval",
        "--input",
        dir.path().to_str().unwrap(),
        "--json",
        "--space",
        "linear",
    ]);
    assert!(ok, "{err}");
    let v: serde_json::Value = serde_json::from_str(&out).unwrap();
    let rmse = v["frames"][0]["rmse"].as_f64().unwrap();
    assert!(rmse > 0.05 && rmse <= 0.1 + 1e-6, "{rmse}");
    // Without a reference anywhere: a clear error.
    let bare = tempfile::tempdir().unwrap();
    write_exr(&bare.path().join("f_0001.exr"), &src, &WriteOptions::default()).unwrap();
    let (ok, _, err) = run(&["eval", "--input", bare.path().to_str().unwrap()]);
    assert!(!ok && err.contains("no reference channel"), "{err}");
    // Size mismatch against the fence reference.
    let r = common::fixture("blender-fence/reference/frame_0001.exr");
    let (ok, _, err) = run(&[
        "eval",
        "--input",
        bare.path().to_str().unwrap(),
        "--reference",
        r.to_str().unwrap(),
    ]);
    assert!(
        !ok && err.contains("is 320x180 but its reference is 160x90"),
        "{err}"
    );
}

#[test]
fn filter_cuts_drop_history_at_the_frames_named() {
    let dir = tempfile::tempdir().unwrap();
    let input = dir.path().join("in");
    let d = input.to_str().unwrap();
    let (ok, _, err) = run(&[
        "scene", "flyover", "--frames", "4", "--size", "40x24", "--spp", "1", "-o", d,
    ]);
    assert!(ok, "{err}");
    // History restarts per frame, with and without a cut at frame 2 (short flags).
    let resets = |cuts: &[&str]| -> Vec<u64> {
        let out = dir.path().join(format!("out{}", cuts.len()));
        let mut args = vec!["filter", "--filter", "taa", "-i", d, "-o", out.to_str().unwrap()];
        args.extend_from_slice(cuts);
        let (ok, _, err) = run(&args);
        assert!(ok, "{err}");
        let v: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(out.join("records.json")).unwrap()).unwrap();
        v["frames"]
            .as_array()
            .unwrap()
            .iter()
            .map(|f| f["pixels"]["history_reset"].as_u64().unwrap())
            .collect()
    };
    let plain = resets(&[]);
    let cut = resets(&["--cuts", "2"]);
    assert_eq!(plain[0], 40 * 24);
    assert!(plain[2] < 40 * 24, "{plain:?}");
    assert_eq!(cut[2], 40 * 24, "{cut:?}");
    assert_eq!(
        (cut[1], cut[3] < 40 * 24),
        (plain[1], true),
        "{cut:?} vs {plain:?}"
    );
    // A cut at a frame the input does not have is refused before anything runs.
    let (ok, _, err) = run(&["filter", "--filter", "taa", "-i", d, "-o", d, "--cuts", "1,9"]);
    assert!(
        !ok && err.contains("--cuts 9: the input has no frame 9 (its frames are 0-3)"),
        "{err}"
    );
}

#[test]
fn filter_runs_over_a_rendered_sequence_and_matches_the_library() {
    let dir = tempfile::tempdir().unwrap();
    let input = dir.path().join("in");
    let output = dir.path().join("out");
    let (ok, _, err) = run(&[
        "scene",
        "moving-sphere",
        "--frames",
        "4",
        "--size",
        "40x24",
        "--spp",
        "4",
        "--out",
        input.to_str().unwrap(),
    ]);
    assert!(ok, "{err}");
    let (ok, out, err) = run(&[
        "filter",
        "--filter",
        "traa",
        "--set",
        "variant=baseline",
        "--set",
        "sharpen=false",
        "--input",
        input.to_str().unwrap(),
        "--output",
        output.to_str().unwrap(),
        "--png",
    ]);
    assert!(ok, "{err}");
    assert!(
        out.contains("vs reference") && out.contains("resolve") && out.contains("left out"),
        "{out}"
    );
    for i in 0..4 {
        assert!(output.join(format!("frame_{i:04}.exr")).exists());
        assert!(output.join(format!("frame_{i:04}.png")).exists());
    }
    let records: serde_json::Value =
        serde_json::from_slice(&std::fs::read(output.join("records.json")).unwrap()).unwrap();
    assert_eq!(records["frames"].as_array().unwrap().len(), 4);
    assert_eq!(records["params"]["variant"], "baseline");
    assert_eq!(records["params"]["sharpen"], false);
    assert_eq!(records["frames"][0]["stages"][3]["name"], "reproject");
    // The written frames are what the library computes, and the printed PSNR is theirs.
    let mut f = afterimage::filters::create(
        "traa",
        &afterimage::pipeline::params::parse_assignments(&["variant=baseline", "sharpen=false"]).unwrap(),
    )
    .unwrap();
    let seq = Sequence::open(input.to_str().unwrap()).unwrap();
    let mut eval = Evaluator::new(SpaceChoice::Auto);
    for (i, frame) in seq.frames(&ReadOptions::default()).enumerate() {
        let frame = frame.unwrap();
        let expect = f.process(&frame).unwrap().color;
        let written = read_frame(&output.join(format!("frame_{i:04}.exr")), &ReadOptions::default()).unwrap();
        assert_eq!(written.color(), &expect);
        eval.push(i as u64, &expect, frame.reference().unwrap(), false)
            .unwrap();
    }
    let psnr = eval.summary().unwrap().mean_psnr;
    assert!(
        out.contains(&format!("mean PSNR {psnr:.3} dB")),
        "{out} vs {psnr}"
    );
}

#[test]
fn filters_lists_every_filter_with_bounds_and_bad_params_are_refused() {
    let (ok, out, _) = run(&["filters", "--json"]);
    assert!(ok);
    let v: serde_json::Value = serde_json::from_str(&out).unwrap();
    let names: Vec<&str> = v
        .as_array()
        .unwrap()
        .iter()
        .map(|f| f["name"].as_str().unwrap())
        .collect();
    assert_eq!(
        names,
        [
            "passthrough",
            "fxaa",
            "taa",
            "traa",
            "phlm",
            "pixel_trace",
            "upsample"
        ]
    );
    let taa = &v[2];
    assert_eq!(taa["defaults"]["alpha"], 0.1);
    assert_eq!(taa["params"][0]["kind"]["max"], 1.0);
    assert_eq!(taa["uses"], serde_json::json!(["color", "depth", "motion"]));
    assert_eq!(taa["needs"], serde_json::json!(["color"]));
    let (ok, text, _) = run(&["filters"]);
    assert!(
        ok && text.contains("--set variant=\"improved\"  [baseline | improved]"),
        "{text}"
    );
    let dir = tempfile::tempdir().unwrap();
    let (ok, _, err) = run(&[
        "filter",
        "--filter",
        "taa",
        "--set",
        "gamma=9",
        "--input",
        "nowhere",
        "--output",
        dir.path().to_str().unwrap(),
    ]);
    assert!(!ok);
    assert!(
        err.contains("filter taa, parameter gamma: 9 is out of bounds: expected 0.25 <= value <= 4"),
        "{err}"
    );
}

/// Sparse shading end to end on the command line: `scene --shading 2` writes it, `info`
/// shows the pattern, `upsample` filters it to full resolution, `taa` refuses it precisely.
#[test]
fn sparse_shading_from_scene_to_upsample() {
    let dir = tempfile::tempdir().unwrap();
    let scene = dir.path().join("ms2");
    let s = scene.to_str().unwrap();
    let (ok, _, err) = run(&[
        "scene",
        "moving-sphere",
        "--size",
        "34x20",
        "--frames",
        "4",
        "--spp",
        "1",
        "--shading",
        "2",
        "--jitter",
        "none",
        "--out",
        s,
    ]);
    assert!(ok, "{err}");
    let (ok, text, _) = run(&["info", &format!("{s}/frame_0001.exr")]);
    assert!(
        ok && text.contains("shading: one pixel per 2x2 block, at (1, 1) of each"),
        "{text}"
    );
    let out = dir.path().join("up");
    let (ok, _, err) = run(&[
        "filter",
        "--filter",
        "upsample",
        "--input",
        s,
        "--output",
        out.to_str().unwrap(),
    ]);
    assert!(ok, "{err}");
    let f = read_frame(&out.join("frame_0003.exr"), &ReadOptions::default()).unwrap();
    assert_eq!((f.width(), f.height(), f.color_size()), (34, 20, (34, 20)));
    let (ok, _, err) = run(&[
        "filter",
        "--filter",
        "taa",
        "--input",
        s,
        "--output",
        dir.path().join("taa").to_str().unwrap(),
    ]);
    assert!(
        !ok && err.contains("filter taa needs colour shaded at every pixel"),
        "{err}"
    );
}
