//! Every filter against bad input: non-finite and negative samples, wrong parameters,
//! size changes, missing channels. Nothing panics, nothing unusable reaches history or
//! output, and the errors say what and where.

mod common;

use afterimage::filters::{create, list};
use afterimage::frame::{ChannelKind, Frame, Plane};
use afterimage::pipeline::{params::parse_assignments, run_sequence, Filter, FilterError, Skip};
use afterimage::scene::{Jitter, Scene, Settings};

/// Two fresh instances of filter `name` with its defaults, to run side by side.
fn twins(name: &str) -> (Box<dyn Filter>, Box<dyn Filter>) {
    let fresh = || create(name, &Default::default()).unwrap();
    (fresh(), fresh())
}

fn small_scene(name: &str, frames: u64) -> Vec<Frame> {
    let s = Settings {
        width: 48,
        height: 32,
        frames,
        spp: 4,
        jitter: Jitter::Halton(8),
        noise: false,
        seed: 3,
        shading: 1,
    };
    let scene = Scene::new(name, s).unwrap();
    (0..frames).map(|i| scene.frame(i)).collect()
}

fn all_finite(rgb: &afterimage::frame::Rgb) -> bool {
    rgb.iter()
        .all(|p| p.count_non_finite() == 0 && p.data().iter().all(|&v| v >= 0.0))
}

#[test]
fn non_finite_input_never_reaches_history_or_output_and_is_counted() {
    let clean = small_scene("moving-sphere", 8);
    for info in list() {
        let mut f = create(info.name, &Default::default()).unwrap();
        let mut dirty = Vec::new();
        for (t, frame) in clean.iter().enumerate() {
            let mut frame = frame.clone();
            let mut injected = 0;
            if t == 3 || t == 4 {
                // A NaN, both infinities and a negative value in colour, and NaN motion and
                // depth where the filter reads them.
                let [r, g, b] = frame.color_mut();
                r[10] = f32::NAN;
                g[200] = f32::INFINITY;
                b[201] = f32::NEG_INFINITY;
                r[300] = -5.0;
                injected += 3;
                if info.uses.contains(&ChannelKind::Motion) {
                    frame.motion_mut().unwrap()[0].data_mut()[400] = f32::NAN;
                    injected += 1;
                }
                if info.uses.contains(&ChannelKind::Depth) {
                    let mut d = frame.depth().unwrap().clone();
                    d.data_mut()[500] = f32::INFINITY;
                    frame.set_f32(ChannelKind::Depth, vec![d]).unwrap();
                    injected += 1;
                }
            }
            dirty.push((frame, injected));
        }
        // Windowed filters give frame t later: every output, then each with its frame.
        let outs = run_sequence(f.as_mut(), dirty.iter().map(|(frame, _)| frame)).unwrap();
        assert_eq!(outs.len(), dirty.len(), "{}", info.name);
        for (t, (out, &(_, injected))) in outs.iter().zip(&dirty).enumerate() {
            assert_eq!(
                out.record.index, clean[t].meta.index,
                "{}: outputs in order",
                info.name
            );
            assert!(
                all_finite(&out.color),
                "{} frame {t}: non-finite or negative output",
                info.name
            );
            assert_eq!(out.record.input.non_finite, injected, "{} frame {t}", info.name);
            assert_eq!(
                out.record.input.negative,
                if injected > 0 { 1 } else { 0 },
                "{}",
                info.name
            );
            assert_eq!(out.record.ran("repair"), injected > 0, "{}", info.name);
        }
    }
}

#[test]
fn a_flood_of_nan_leaves_history_usable() {
    let clean = small_scene("static", 6);
    for name in ["taa", "traa"] {
        let (mut f, mut g) = twins(name);
        for frame in &clean[..3] {
            f.process(frame).unwrap();
            g.process(frame).unwrap();
        }
        let mut flood = clean[3].clone();
        for p in flood.color_mut() {
            p.fill(f32::NAN);
        }
        let out = f.process(&flood).unwrap();
        assert!(all_finite(&out.color), "{name}");
        assert_eq!(out.record.input.non_finite, 3 * 48 * 32);
        // The flooded frame shows the history; the frame after it is what a run that simply
        // skipped the flooded frame gives (the history was neither lost nor darkened by a
        // made-up sample).
        let a = f.process(&clean[4]).unwrap().color;
        let b = g.process(&clean[4]).unwrap().color;
        assert!(all_finite(&a), "{name}");
        let mse = afterimage::metrics::mse(&a, &b, afterimage::metrics::MetricSpace::Linear).unwrap();
        // traa improved also keeps the flooded frame's depth (valid samples) for its temporal
        // pseudo-variance, so it may differ a little; taa must match.
        let limit = if name == "taa" { 1e-12 } else { 1e-5 };
        assert!(mse < limit, "{name}: MSE {mse} against the run without the flood");
    }
}

#[test]
fn parameters_are_validated_with_the_bound_in_the_message() {
    let err = |filter: &str, set: &[&str]| {
        create(filter, &parse_assignments(set).unwrap())
            .err()
            .unwrap()
            .to_string()
    };
    let refused = [
        ("taa", "alpha=2"),
        ("traa", "variant=fancy"),
        ("taa", "alhpa=0.2"),
        ("taa", "dilation=3"),
    ]
    .map(|(filter, set)| err(filter, &[set]));
    assert_eq!(
        refused,
        [
            "filter taa, parameter alpha: 2 is out of bounds: expected 0.01 <= value <= 1",
            "filter traa, parameter variant: expected one of baseline, improved, got \"fancy\"",
            "filter taa has no parameter \"alhpa\"; its parameters: alpha, gamma, history_filter, dilation, luminance_weighting, depth_rejection, sharpen, pixel_filter, filter_width",
            "filter taa, parameter dilation: expected true or false, got 3",
        ]
    );
    assert!(err("nope", &[]).starts_with("unknown filter \"nope\"; known: passthrough, fxaa, taa, traa"));
    assert_eq!(
        parse_assignments(&["alpha"]).unwrap_err(),
        FilterError::Assignment { got: "alpha".into() }
    );
    // Every filter's defaults are within its own bounds, and each spec names a field.
    for info in list() {
        assert_eq!(info.params.len(), info.defaults.len(), "{}", info.name);
        for spec in info.params {
            assert!(
                info.defaults.contains_key(spec.name),
                "{}: {}",
                info.name,
                spec.name
            );
        }
        create(info.name, &Default::default()).unwrap();
    }
}

#[test]
fn a_size_change_needs_a_reset_and_device_depth_needs_its_planes() {
    let a = small_scene("static", 2);
    let b = Frame::new(std::array::from_fn(|_| Plane::filled(20, 10, 0.5f32))).unwrap();
    let mut f = create("taa", &Default::default()).unwrap();
    f.process(&a[0]).unwrap();
    let err = f.process(&b).unwrap_err();
    assert_eq!(
        err.to_string(),
        "frame 0 is 20x10 but the filter's history is 48x32; send a reset frame (or reset the filter) to change size"
    );
    // The failed frame did not disturb the session: the next frame of the right size works,
    // and after a reset the new size is accepted.
    f.process(&a[1]).unwrap();
    f.reset();
    assert_eq!(f.process(&b).unwrap().color[0].size(), (20, 10));
    // Device depth without near/far planes cannot be used, and the error says why.
    let mut dev = a[0].clone();
    dev.meta.depth_kind = afterimage::frame::DepthKind::Device;
    assert_eq!(
        create("taa", &Default::default())
            .unwrap()
            .process(&dev)
            .unwrap_err(),
        FilterError::DeviceDepthWithoutPlanes
    );
}

#[test]
fn the_planner_leaves_out_what_a_frame_does_not_need() {
    // LDR static scene: no tonemap, no reprojection (nothing moves).
    let frames = small_scene("static", 3);
    let mut taa = create("taa", &Default::default()).unwrap();
    let first = taa.process(&frames[0]).unwrap().record;
    assert_eq!(first.stage("reproject").unwrap().skipped, Some(Skip::NoHistory));
    let second = taa.process(&frames[1]).unwrap().record;
    assert_eq!(second.stage("reproject").unwrap().skipped, Some(Skip::NoMotion));
    assert_eq!(second.stage("tonemap").unwrap().skipped, Some(Skip::LdrInput));
    assert_eq!(second.stage("untonemap").unwrap().skipped, Some(Skip::LdrInput));
    assert_eq!(
        second.stage("sharpen").unwrap().skipped,
        Some(Skip::Disabled { param: "sharpen" })
    );
    assert!(second.ran("resolve"));
    // HDR moving scene: both run.
    let hdr = small_scene("hdr", 3);
    let mut taa = create("taa", &Default::default()).unwrap();
    taa.process(&hdr[0]).unwrap();
    let r = taa.process(&hdr[1]).unwrap().record;
    assert!(r.ran("tonemap") && r.ran("untonemap"), "{r:?}");
    // No motion channel: reprojection left out for that reason.
    let mut no_motion = frames[1].clone();
    no_motion.remove(ChannelKind::Motion);
    let mut taa = create("taa", &Default::default()).unwrap();
    taa.process(&frames[0]).unwrap();
    let r = taa.process(&no_motion).unwrap().record;
    assert_eq!(
        r.stage("reproject").unwrap().skipped,
        Some(Skip::MissingChannel {
            channel: ChannelKind::Motion
        })
    );
    // On a first frame too: what the input lacks is named before the history it has not.
    for name in ["taa", "traa", "phlm"] {
        let mut f = create(name, &Default::default()).unwrap();
        let r = f.process(&no_motion).unwrap().record;
        assert_eq!(
            r.stage("reproject").unwrap().skipped,
            Some(Skip::MissingChannel {
                channel: ChannelKind::Motion
            }),
            "{name}"
        );
    }
    let set = parse_assignments(&["depth_rejection=0.05"]).unwrap();
    let mut no_depth = frames[0].clone();
    no_depth.remove(ChannelKind::Depth);
    let r = create("taa", &set).unwrap().process(&no_depth).unwrap().record;
    assert_eq!(
        r.stage("depth_reject").unwrap().skipped,
        Some(Skip::MissingChannel {
            channel: ChannelKind::Depth
        })
    );
    // Every stage a filter lists appears in its record, in order.
    for info in list() {
        let mut f = create(info.name, &Default::default()).unwrap();
        let r = run_sequence(f.as_mut(), &frames[..1]).unwrap().remove(0).record;
        let names: Vec<&str> = r.stages.iter().map(|s| s.name).collect();
        assert_eq!(names, info.stages, "{}", info.name);
    }
}

#[test]
fn skipping_reprojection_when_nothing_moves_changes_nothing() {
    // The same still frames with and without an all-zero motion channel give the same
    // output: the left-out stage had no effect to lose.
    let frames = small_scene("static", 4);
    for name in ["taa", "traa"] {
        let (mut a, mut b) = twins(name);
        for f in &frames {
            let mut moved = f.clone();
            // Force the stage to run with a 1e-3 px motion on pixel 0 (compared away from
            // it): reprojection by zero motion then gives what skipping it gave.
            moved.motion_mut().unwrap()[0].data_mut()[0] = 1e-3;
            let oa = a.process(f).unwrap();
            let ob = b.process(&moved).unwrap();
            if f.meta.index > 0 {
                assert!(!oa.record.ran("reproject") && ob.record.ran("reproject"));
            }
            for k in 0..3 {
                for (i, (x, y)) in oa.color[k].data().iter().zip(ob.color[k].data()).enumerate() {
                    if i > 50 {
                        afterimage::tolerance::Tolerance::new(1e-5, 1e-4)
                            .check(name, *x as f64, *y as f64)
                            .unwrap();
                    }
                }
            }
        }
    }
}

#[test]
fn recycled_buffers_never_leak_into_results() {
    // Outputs handed back are poisoned with NaN first: a stage that read a reused plane
    // before writing all of it would show it.
    let frames = small_scene("moving-sphere", 6);
    for info in list() {
        let (mut a, mut b) = twins(info.name);
        for (i, f) in frames.iter().enumerate() {
            let last = i + 1 == frames.len();
            let (mut oa, mut ob) = (a.push(f).unwrap(), b.push(f).unwrap());
            if last {
                oa.extend(a.finish().unwrap());
                ob.extend(b.finish().unwrap());
            }
            assert_eq!(oa.len(), ob.len());
            for (out, other) in oa.into_iter().zip(ob) {
                let mut poisoned = out.color.clone();
                for p in &mut poisoned {
                    p.data_mut().fill(f32::NAN);
                }
                a.recycle(poisoned);
                assert_eq!(out.color, other.color, "{}", info.name);
            }
        }
    }
}

#[test]
fn history_follows_a_stream_between_ldr_and_hdr_frames() {
    // A still scene whose frame 4 has one HDR pixel: the working space of the whole frame
    // becomes tonemapped, so the history is converted; without that, the history would be
    // read in the wrong space and the image would jump in brightness.
    let frames = small_scene("static", 7);
    // traa's output sharpen works in the working space too, which legitimately changes the
    // output when that space changes: compare without it.
    for (name, set) in [("taa", &[][..]), ("traa", &["sharpen=false"][..])] {
        let mut f = create(name, &parse_assignments(set).unwrap()).unwrap();
        let mut means = Vec::new();
        for (t, frame) in frames.iter().enumerate() {
            let mut frame = frame.clone();
            if t == 4 {
                for p in frame.color_mut() {
                    p[0] = 50.0;
                }
            }
            let out = f.process(&frame).unwrap();
            assert_eq!(out.record.ran("tonemap"), t == 4, "{name} frame {t}");
            // Mean away from the corner pixel.
            let mean: f64 = out.color[1].data()[48 * 4..]
                .iter()
                .map(|&v| v as f64)
                .sum::<f64>()
                / (48 * 28) as f64;
            means.push(mean);
        }
        for t in 4..7 {
            let change = (means[t] / means[3] - 1.0).abs();
            assert!(
                change < 0.02,
                "{name}: frame {t} mean {} vs {} before the HDR frame",
                means[t],
                means[3]
            );
        }
    }
}
