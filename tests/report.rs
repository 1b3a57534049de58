//! `afterimage report --quick`: every filter on every scene, finite figures, plots that
//! decode, and passthrough's PSNR equal to `afterimage eval` on the same frames.

mod common;

use afterimage::filters::list;
use afterimage::scene::CATALOGUE;
use afterimage::tolerance::Tolerance;
use common::{run, run_ok};
use serde_json::Value;
use std::path::Path;

fn finite(v: &Value, what: &str) -> f64 {
    let x = v.as_f64().unwrap_or_else(|| panic!("{what}: not a number: {v}"));
    assert!(x.is_finite(), "{what}: {x}");
    x
}

/// The report's `cell` has the mean PSNR, mean SSIM and tRMSE of `eval --json`'s summary
/// (to 1e-12 relative); `label` names the cell in a failure.
fn assert_cell_is_eval(label: &str, cell: &Value, eval: &Value) {
    for key in ["mean_psnr", "mean_ssim", "trmse"] {
        Tolerance::rel(1e-12)
            .check(
                &format!("{label} {key}"),
                finite(&cell[key], key),
                finite(&eval["summary"][key], key),
            )
            .unwrap();
    }
}

/// Runs the quick report once into `dir` and returns the parsed JSON and stdout.
fn quick_report(dir: &Path) -> (Value, String) {
    // `-j 2`: the pool's size is what the command line asked for, whatever the machine.
    let out = run_ok(&["report", "--quick", "-j", "2", "-o", dir.to_str().unwrap()]);
    let json = std::fs::read_to_string(dir.join("report.json")).unwrap();
    (serde_json::from_str(&json).unwrap(), out)
}

#[test]
fn quick_report_covers_every_filter_on_every_scene_with_plots() {
    let dir = tempfile::tempdir().unwrap();
    let (r, stdout) = quick_report(dir.path());
    // The main section runs every filter of full-resolution colour, each followed by its
    // other variants; the upsampling section every method of the filters of sparse shading.
    let mut filters: Vec<String> = Vec::new();
    for i in list().iter().filter(|i| !i.sparse_input) {
        filters.push(i.name.to_string());
        match i.name {
            "traa" => filters.push("traa:variant=baseline".into()),
            "phlm" => filters.push("phlm:variant=paper".into()),
            _ => {}
        }
    }
    let scenes = r["scenes"].as_array().unwrap();
    assert_eq!(scenes.len(), CATALOGUE.len());
    for (sc, entry) in scenes.iter().zip(CATALOGUE) {
        assert_eq!(sc["scene"], entry.name);
        let cells = sc["cells"].as_array().unwrap();
        let names: Vec<&str> = cells.iter().map(|c| c["filter"].as_str().unwrap()).collect();
        assert_eq!(names, filters, "scene {}", entry.name);
        for c in cells {
            let what = format!("{} / {}", entry.name, c["filter"]);
            let psnr = finite(&c["mean_psnr"], &what);
            assert!((5.0..80.0).contains(&psnr), "{what}: PSNR {psnr}");
            let ssim = finite(&c["mean_ssim"], &what);
            assert!((0.0..=1.0).contains(&ssim), "{what}: SSIM {ssim}");
            assert!(finite(&c["trmse"], &what) >= 0.0);
            let cost = &c["cost"];
            assert!(finite(&cost["time"]["median_ms"], &what) > 0.0);
            assert!(finite(&cost["time"]["p95_ms"], &what) >= finite(&cost["time"]["median_ms"], &what));
            assert!(finite(&cost["floor_ms"], &what) > 0.0);
            assert!(finite(&cost["floor_ratio"], &what) > 0.0);
            assert!(finite(&cost["state_bytes_per_megapixel"], &what) >= 0.0);
            assert!(!cost["stages"].as_array().unwrap().is_empty(), "{what}");
            assert_eq!(c["psnr_per_frame"].as_array().unwrap().len(), 8, "{what}");
        }
    }
    // The summary and the timing section have every filter too.
    for key in ["summary", "timing"] {
        let rows: Vec<&str> = r[key]
            .as_array()
            .unwrap()
            .iter()
            .map(|s| s["filter"].as_str().unwrap())
            .collect();
        assert_eq!(rows, filters, "{key}");
    }
    // State per megapixel matches each filter's declared bytes per pixel; a windowed
    // filter's is the frames it holds, at most its declared full window of every channel.
    for row in r["timing"].as_array().unwrap() {
        let label = row["filter"].as_str().unwrap();
        let name = label.split(':').next().unwrap();
        let info = list().into_iter().find(|i| i.name == name).unwrap();
        let got = finite(&row["cost"]["state_bytes_per_megapixel"], info.name);
        let declared = info.state_bytes_per_pixel as f64 * 1e6;
        if label != name {
            // A variant (traa's baseline keeps less state than its default).
            assert!(got > 0.0 && got <= declared, "{label}: {got} of {declared}");
        } else if info.name == "pixel_trace" {
            assert!(got > 0.0 && got <= declared, "{}: {got} of {declared}", info.name);
        } else {
            Tolerance::rel(1e-9).check(info.name, got, declared).unwrap();
        }
    }
    assert!(finite(&r["bandwidth"]["bytes_per_s"], "bandwidth") > 1e8);

    // The upsampling section: upsample's four methods on its three scenes with 2x2 shading.
    let u = &r["upsampling"];
    assert_eq!(u["factor"], 2);
    let methods = ["spatiotemporal", "spatial", "temporal", "taa"].map(|m| format!("upsample:method={m}"));
    let u_scenes = u["scenes"].as_array().unwrap();
    assert_eq!(u_scenes.len(), 3);
    for (sc, name) in u_scenes.iter().zip(["flyover", "moving-sphere", "dynamic-light"]) {
        assert_eq!(sc["scene"], format!("{name}-shading-2x2"));
        let cells = sc["cells"].as_array().unwrap();
        let names: Vec<&str> = cells.iter().map(|c| c["filter"].as_str().unwrap()).collect();
        assert_eq!(names, methods, "{name}");
        for c in cells {
            let psnr = finite(&c["mean_psnr"], name);
            assert!((5.0..80.0).contains(&psnr), "{name}: PSNR {psnr}");
            assert!(finite(&c["cost"]["floor_ratio"], name) > 0.0);
        }
        assert!(dir.path().join(format!("strip_{name}-shading-2x2.png")).exists());
    }
    for key in ["summary", "timing"] {
        assert_eq!(u[key].as_array().unwrap().len(), 4, "upsampling {key}");
    }
    assert!(stdout.contains("# Upsampling: one pixel of every 2x2 block shaded"));

    // The CSV: a header, one row per filter and scene, per filter summary, per filter
    // timing, then the same for the upsampling section.
    let csv = std::fs::read_to_string(dir.path().join("report.csv")).unwrap();
    let n = filters.len();
    assert_eq!(
        csv.lines().count(),
        1 + n * CATALOGUE.len() + 2 * n + 4 * 3 + 2 * 4
    );
    assert!(csv.starts_with("section,scene,filter,"));
    // The markdown on stdout is the one written to report.md.
    assert_eq!(
        std::fs::read_to_string(dir.path().join("report.md")).unwrap(),
        stdout
    );
    assert!(stdout.contains("## All scenes") && stdout.contains("## Timing at 320x180"));
    assert!(stdout.contains("(2 threads,"), "{stdout}");
    // Each timing row quotes frames/s as 1000 over its median ms/frame (as printed).
    let timing = stdout.split("## Timing at 320x180").nth(1).unwrap();
    let rows: Vec<Vec<&str>> = timing
        .lines()
        .skip_while(|l| !l.starts_with("|---"))
        .skip(1)
        .take_while(|l| l.starts_with('|'))
        .map(|l| l.split('|').map(str::trim).collect())
        .collect();
    assert_eq!(rows.len(), n, "timing rows");
    for r in &rows {
        assert_eq!(r[2], "cpu", "the backend column: {r:?}");
        let (ms, fps): (f64, f64) = (r[3].parse().unwrap(), r[9].parse().unwrap());
        // ms is printed to 3 decimals and frames/s to 1.
        Tolerance::new(0.05, 0.0006 / ms)
            .check(&format!("{} frames/s", r[1]), fps, 1e3 / ms)
            .unwrap();
    }

    // Plots exist and decode.
    for name in ["error_vs_time.png", "psnr_per_frame.png"] {
        let img = image::open(dir.path().join(name)).unwrap_or_else(|e| panic!("{name}: {e}"));
        assert!(img.width() >= 640 && img.height() >= 400, "{name}");
    }
    for name in ["error_vs_time.svg", "psnr_per_frame.svg"] {
        let svg = std::fs::read_to_string(dir.path().join(name)).unwrap();
        assert!(
            svg.trim_start().starts_with("<svg") && svg.trim_end().ends_with("</svg>"),
            "{name}"
        );
        for f in &filters {
            assert!(
                svg.contains(&format!("\n{f}\n</text>")),
                "{name} has no label {f}"
            );
        }
    }
    for entry in CATALOGUE {
        let path = dir.path().join(format!("strip_{}.png", entry.name));
        let img = image::open(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
        // Input, each filter, reference; a row of pictures and a row of error maps.
        assert_eq!(img.width() as usize % (filters.len() + 2), 0);
        assert!(img.height() > 2 * 36);
    }

    // Passthrough's PSNR is `afterimage eval` of the same frames rendered by `scene`.
    let pass = filters.iter().position(|f| f == "passthrough").unwrap();
    for scene in ["thin-line", "hdr"] {
        let seq = dir.path().join(scene);
        run_ok(&[
            "scene",
            scene,
            "--size",
            "64x36",
            "--frames",
            "8",
            "--spp",
            "16",
            "--out",
            seq.to_str().unwrap(),
        ]);
        let out = run_ok(&["eval", "--input", seq.to_str().unwrap(), "--json"]);
        let eval: Value = serde_json::from_str(&out).unwrap();
        let cell = &scenes.iter().find(|s| s["scene"] == scene).unwrap()["cells"][pass];
        assert_cell_is_eval(scene, cell, &eval);
    }
}

#[test]
fn report_refuses_bad_specs_with_the_reason() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().to_str().unwrap();
    let (ok, _, err) = run(&["report", "--quick", "--filters", "taa,nope", "--out", out]);
    assert!(!ok && err.contains("\"nope\"") && err.contains("phlm"), "{err}");
    let (ok, _, err) = run(&["report", "--quick", "--filters", "taa:alpha=7", "--out", out]);
    assert!(!ok && err.contains("alpha"), "{err}");
    let (ok, _, err) = run(&[
        "report",
        "--quick",
        "--scenes",
        "thin-line",
        "--strip-frame",
        "9",
        "--out",
        out,
    ]);
    assert!(!ok && err.contains("strip frame 9"), "{err}");
    // A variant label and a subset run.
    let md = run_ok(&[
        "report",
        "--quick",
        "--scenes",
        "thin-line",
        "--filters",
        "traa:variant=baseline,taa",
        "--timing-size",
        "none",
        "--out",
        out,
    ]);
    assert!(
        md.contains("| traa:variant=baseline |") && !md.contains("## Timing"),
        "{md}"
    );
}

/// `--noise` renders the scenes' noisy input (the catalogue's `--noise`): the header says
/// so, and the unfiltered input of a scene with soft shadows scores other figures.
#[test]
fn report_noise_renders_noisy_input() {
    let dir = tempfile::tempdir().unwrap();
    let psnr = |noise: bool| {
        let out = dir.path().join(if noise { "noisy" } else { "clean" });
        let mut args = vec![
            "report",
            "--quick",
            "--scenes",
            "static",
            "--filters",
            "passthrough",
        ];
        args.extend(["--timing-size", "none", "--upsampling-scenes", "none", "-o"]);
        args.push(out.to_str().unwrap());
        if noise {
            args.push("--noise");
        }
        run_ok(&args);
        let md = std::fs::read_to_string(out.join("report.md")).unwrap();
        assert_eq!(md.contains("noisy input"), noise, "{md}");
        let r: Value =
            serde_json::from_str(&std::fs::read_to_string(out.join("report.json")).unwrap()).unwrap();
        finite(&r["scenes"][0]["cells"][0]["mean_psnr"], "passthrough on static")
    };
    // One-sample soft shadows: the unfiltered input is further from the reference.
    let (clean, noisy) = (psnr(false), psnr(true));
    assert!(noisy < clean - 0.01, "clean {clean} dB, noisy {noisy} dB");
}

#[test]
fn report_is_deterministic_apart_from_timings() {
    use afterimage::report::{run, Config};
    let mut c = Config::quick();
    c.scenes = vec!["foliage".into(), "hdr".into()];
    c.timing = None;
    let a = run(&c, &mut |_| {}).unwrap();
    let b = run(&c, &mut |_| {}).unwrap();
    for (sa, sb) in a.scenes.iter().zip(&b.scenes) {
        for (ca, cb) in sa.cells.iter().zip(&sb.cells) {
            assert_eq!(ca.psnr_per_frame, cb.psnr_per_frame, "{} {}", sa.scene, ca.filter);
            assert_eq!(
                (ca.mean_ssim, ca.trmse, ca.cost.bytes_per_frame),
                (cb.mean_ssim, cb.trmse, cb.cost.bytes_per_frame)
            );
        }
    }
    for (sa, sb) in a.strips.iter().zip(&b.strips) {
        for ((la, oa), (_, ob)) in sa.outputs.iter().zip(&sb.outputs) {
            for c in 0..3 {
                assert_eq!(oa[c].data(), ob[c].data(), "{} {la}", sa.scene);
            }
        }
    }
}

/// `tests/fixtures/corpus/<scene>/<part>` as a string.
fn corpus(scene: &str, part: &str) -> String {
    common::fixture(&format!("corpus/{scene}/{part}"))
        .to_str()
        .unwrap()
        .to_string()
}

/// `report --input NAME=DIR --reference DIR` on Blender frames: one scene per shot, named
/// as asked (or after the `SCENE/input` directory), and each cell's figures are `afterimage
/// eval` of what `afterimage filter` writes for the same frames.
#[test]
fn report_on_blender_frames_matches_filter_then_eval() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("report");
    run_ok(&[
        "report",
        "--input",
        &format!("first={}", corpus("fence", "input")),
        "--reference",
        &corpus("fence", "reference"),
        "--input",
        &corpus("movers", "input"),
        "--reference",
        &corpus("movers", "reference"),
        "--filters",
        "taa,phlm",
        "--timing-size",
        "none",
        "--upsampling-scenes",
        "none",
        "-j",
        "2",
        "-o",
        out.to_str().unwrap(),
    ]);
    let r: Value = serde_json::from_str(&std::fs::read_to_string(out.join("report.json")).unwrap()).unwrap();
    let scenes = r["scenes"].as_array().unwrap();
    let names: Vec<&str> = scenes.iter().map(|s| s["scene"].as_str().unwrap()).collect();
    assert_eq!(
        names,
        ["first", "movers"],
        "no catalogue scene when shots are given"
    );
    assert!(out.join("strip_first.png").is_file());
    for (scene, name) in [("fence", "first"), ("movers", "movers")] {
        let sc = scenes.iter().find(|s| s["scene"] == name).unwrap();
        for (k, filter) in ["taa", "phlm"].iter().enumerate() {
            let cell = &sc["cells"][k];
            assert_eq!(cell["filter"], *filter);
            assert_eq!(cell["psnr_per_frame"].as_array().unwrap().len(), 16);
            let filtered = dir.path().join(format!("{scene}-{filter}"));
            run_ok(&[
                "filter",
                "--filter",
                filter,
                "-i",
                &corpus(scene, "input"),
                "-o",
                filtered.to_str().unwrap(),
                "--float",
            ]);
            let text = run_ok(&[
                "eval",
                "--input",
                filtered.to_str().unwrap(),
                "--reference",
                &corpus(scene, "reference"),
                "--json",
            ]);
            let eval: Value = serde_json::from_str(&text).unwrap();
            assert_cell_is_eval(&format!("{scene} {filter}"), cell, &eval);
        }
    }
    // A reference per input, in order.
    let (ok, _, err) = run(&[
        "report",
        "--input",
        &corpus("fence", "input"),
        "--reference",
        &corpus("fence", "reference"),
        "--input",
        &corpus("gi", "input"),
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(!ok && err.contains("2 --input but 1 --reference"), "{err}");
    // A reference of another length is refused with both lengths.
    let (ok, _, err) = run(&[
        "report",
        "--input",
        &corpus("fence", "input"),
        "--reference",
        &format!("{}/frame_000[1-4].exr", corpus("fence", "reference")),
        "--filters",
        "taa",
        "--timing-size",
        "none",
        "--upsampling-scenes",
        "none",
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(!ok && err.contains("16 frames") && err.contains("has 4"), "{err}");
}

/// `report --input ... --jitter-unknown`: the shot runs with every frame's jitter taken as
/// 0 (the description says so, and the reconstructing filters give other figures than with
/// the header's jitter), and with shots and no `--upsampling-scenes` the upsampling section
/// runs the shot itself, shaded one pixel in 2x2 from its dense frames.
#[test]
fn report_takes_the_jitter_as_unknown_and_upsamples_the_shots() {
    let dir = tempfile::tempdir().unwrap();
    let report = |extra: &[&str], out: &str| -> Value {
        let out = dir.path().join(out);
        let (input, reference) = (corpus("movers", "input"), corpus("movers", "reference"));
        let mut args = vec![
            "report",
            "--input",
            &input,
            "--reference",
            &reference,
            "--filters",
            "taa",
            "--timing-size",
            "none",
            "-o",
            out.to_str().unwrap(),
        ];
        args.extend_from_slice(extra);
        run_ok(&args);
        serde_json::from_str(&std::fs::read_to_string(out.join("report.json")).unwrap()).unwrap()
    };
    let known = report(&[], "known");
    let unknown = report(&["--jitter-unknown", "--upsampling-scenes", "none"], "unknown");
    let desc = |r: &Value| r["scenes"][0]["description"].as_str().unwrap().to_string();
    assert!(
        desc(&unknown).ends_with("jitter taken as unknown"),
        "{}",
        desc(&unknown)
    );
    assert!(!desc(&known).contains("unknown"));
    let psnr = |r: &Value| r["scenes"][0]["cells"][0]["mean_psnr"].as_f64().unwrap();
    assert!(
        psnr(&known) > psnr(&unknown),
        "{} {}",
        psnr(&known),
        psnr(&unknown)
    );
    assert!(unknown["upsampling"].is_null());
    let u = &known["upsampling"];
    assert_eq!(u["factor"], 2);
    let sc = &u["scenes"].as_array().unwrap()[..];
    assert_eq!(sc.len(), 1);
    assert_eq!(sc[0]["scene"], "movers-shading-2x2");
    let cells = sc[0]["cells"].as_array().unwrap();
    assert_eq!(cells.len(), 4);
    for c in cells {
        assert_eq!(c["psnr_per_frame"].as_array().unwrap().len(), 16);
        assert!(c["mean_psnr"].as_f64().unwrap() > 15.0, "{c}");
    }
}
