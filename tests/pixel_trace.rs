//! `pixel_trace` (Shinya 1993): the paper's two experiments on our scenes, flow
//! separation at silhouettes, and the windowed interface (latency, flush, cuts).

mod common;

use afterimage::filters::create;
use afterimage::frame::{ChannelKind, Frame, Rgb};
use afterimage::metrics::{mse, psnr_from_mse, MetricSpace};
use afterimage::pipeline::{params::parse_assignments, run_sequence, FilterError, Output};
use afterimage::scene::{Jitter, Scene, Settings};

fn settings(width: usize, height: usize, frames: u64, spp: u32) -> Settings {
    common::unjittered(width, height, frames, spp, 7, 1)
}

fn pixel_trace(set: &[&str]) -> Box<dyn afterimage::pipeline::Filter> {
    create("pixel_trace", &parse_assignments(set).unwrap()).unwrap()
}

/// The output for frame `index` of a run over `frames`.
fn output_for(set: &[&str], frames: &[Frame], index: u64) -> Output {
    let mut f = pixel_trace(set);
    run_sequence(f.as_mut(), frames)
        .unwrap()
        .into_iter()
        .find(|o| o.record.index == index)
        .unwrap()
}

fn rms(a: &Rgb, b: &Rgb) -> f64 {
    mse(a, b, MetricSpace::Linear).unwrap().sqrt()
}

/// Shinya's experiment 1 (sec. 5, fig. 4): the 1/8-px bar 1 degree off horizontal moving
/// 0.22 px/frame, box kernel of one pixel area. The RMS error of frame t0 against the
/// converged box-filtered reference (64x64 samples per pixel) falls as the window grows.
#[test]
fn thin_line_error_falls_as_the_window_grows() {
    let t0 = 64u64;
    // 64 rows: the bar stays in the image over all 129 frames.
    let seq = Scene::new("thin-line", settings(64, 64, 2 * t0 + 1, 1)).unwrap();
    let frames: Vec<Frame> = (0..=2 * t0).map(|t| seq.frame(t)).collect();
    let fine = Scene::new("thin-line", settings(64, 64, 2 * t0 + 1, 4096)).unwrap();
    let reference = fine.frame(t0).reference().unwrap().clone();
    let mut curve = Vec::new();
    for t in [1u64, 4, 16, 64, 128] {
        let window = &frames[(t0 - t / 2) as usize..=(t0 + t / 2) as usize];
        let out = output_for(&[&format!("window={t}")], window, t0);
        let w = out.record.window.as_ref().unwrap();
        assert_eq!((w.first, w.last), (t0 - t / 2, t0 + t / 2), "the whole window");
        curve.push((t, rms(&out.color, &reference)));
    }
    let input = rms(frames[t0 as usize].color(), &reference);
    println!("thin-line RMS error vs T (input {input:.5}):");
    for (t, e) in &curve {
        println!("  T = {t:>3}: {e:.5}");
    }
    // T = 1 is the input itself.
    afterimage::tolerance::Tolerance::abs(1e-9)
        .check("T=1 is the input", curve[0].1, input)
        .unwrap();
    for pair in curve[..4].windows(2) {
        assert!(
            pair[1].1 < pair[0].1,
            "error must fall from T={} to T={}: {curve:?}",
            pair[0].0,
            pair[1].0
        );
    }
    assert!(
        curve[3].1 < 0.2 * curve[0].1,
        "T=64 removes most of the aliasing: {curve:?}"
    );
}

/// Shinya's experiment 2 (fig. 5): rotating thin spokes, accelerating (non-uniform)
/// motion, T = 32: aliasing mostly removed, measured as PSNR gain over the input.
#[test]
fn spokes_aliasing_is_mostly_removed_with_32_frames() {
    let t0 = 24u64;
    let scene = Scene::new("spokes", settings(64, 64, 2 * t0 + 1, 256)).unwrap();
    let frames: Vec<Frame> = (0..=2 * t0).map(|t| scene.frame(t)).collect();
    let out = output_for(
        &["window=32"],
        &frames[(t0 - 16) as usize..=(t0 + 16) as usize],
        t0,
    );
    let reference = frames[t0 as usize].reference().unwrap();
    let before = psnr_from_mse(mse(frames[t0 as usize].color(), reference, MetricSpace::Linear).unwrap());
    let after = psnr_from_mse(mse(&out.color, reference, MetricSpace::Linear).unwrap());
    println!(
        "spokes T=32: input {before:.2} dB, pixel_trace {after:.2} dB (+{:.2})",
        after - before
    );
    assert!(
        after > before + 4.0,
        "input {before:.2} dB, filtered {after:.2} dB"
    );
}

/// Pixels whose 5x5 neighbourhood holds both `object` and something else (any two
/// objects when `object` is None): the band where flows overlap.
fn silhouette_band(frame: &Frame, object: Option<u32>) -> Vec<usize> {
    let ids = frame.object_id().unwrap();
    let (w, h) = (frame.width(), frame.height());
    (0..w * h)
        .filter(|&i| {
            let (x, y) = ((i % w) as isize, (i / w) as isize);
            let around: Vec<u32> = (-2..=2)
                .flat_map(|dy| (-2..=2).map(move |dx| (dx, dy)))
                .map(|(dx, dy)| ids.get_clamped(x + dx, y + dy))
                .collect();
            match object {
                Some(o) => around.contains(&o) && around.iter().any(|&v| v != o),
                None => around.iter().any(|&v| v != around[0]),
            }
        })
        .collect()
}

fn rms_at(a: &Rgb, b: &Rgb, pixels: &[usize]) -> f64 {
    let sum: f64 = pixels
        .iter()
        .map(|&i| {
            (0..3)
                .map(|c| (a[c].data()[i] as f64 - b[c].data()[i] as f64).powi(2))
                .sum::<f64>()
        })
        .sum();
    (sum / (3 * pixels.len()) as f64).sqrt()
}

/// Overlapping flows (jittered input, T = 16): with separation the sphere is not smeared
/// into the alley behind it; one flow per pixel smears it. RMS error in the band around
/// its silhouette, against a 16x16-sample reference; the fence (posts and wires panning
/// over the background at nearly its speed) is reported and must not get worse.
#[test]
fn flow_separation_keeps_objects_off_their_background() {
    let t0 = 8u64;
    for (name, object) in [("moving-sphere", Some(5u32)), ("fence", None)] {
        let jittered = |spp| Settings {
            jitter: Jitter::Halton(8),
            ..settings(160, 90, 2 * t0 + 1, spp)
        };
        let scene = Scene::new(name, jittered(1)).unwrap();
        let frames: Vec<Frame> = (0..=2 * t0).map(|t| scene.frame(t)).collect();
        let fine = Scene::new(name, jittered(256)).unwrap().frame(t0);
        let reference = fine.reference().unwrap();
        let band = silhouette_band(&frames[t0 as usize], object);
        let sep = output_for(&["window=16"], &frames, t0);
        let one = output_for(&["window=16", "flow_separation=false"], &frames, t0);
        let (e_sep, e_one) = (
            rms_at(&sep.color, reference, &band),
            rms_at(&one.color, reference, &band),
        );
        let e_in = rms_at(frames[t0 as usize].color(), reference, &band);
        println!(
            "{name}: RMS near silhouettes ({} px): input {e_in:.4}, separated flows {e_sep:.4}, one flow {e_one:.4}",
            band.len()
        );
        assert!(e_sep < 0.75 * e_in, "{name}: separated {e_sep} vs input {e_in}");
        if object.is_some() {
            assert!(
                e_sep < 0.95 * e_one,
                "{name}: separated {e_sep} vs one flow {e_one}"
            );
        } else {
            assert!(
                e_sep < 1.05 * e_one,
                "{name}: separated {e_sep} vs one flow {e_one}"
            );
        }
        assert!(sep.record.ran("separate_flows") && !one.record.ran("separate_flows"));
    }
}

/// Without `motion_next` the forward steps invert the next frame's motion: on exact
/// motion the result stays close to the one with it.
#[test]
fn forward_paths_without_motion_next_invert_the_next_motion() {
    let scene = Scene::new("moving-sphere", settings(64, 36, 17, 4)).unwrap();
    let frames: Vec<Frame> = (0..17).map(|t| scene.frame(t)).collect();
    let stripped: Vec<Frame> = frames
        .iter()
        .map(|f| {
            let mut f = f.clone();
            f.remove(ChannelKind::MotionNext);
            f
        })
        .collect();
    let reference = frames[8].reference().unwrap();
    let with = output_for(&["window=16"], &frames, 8);
    let without = output_for(&["window=16"], &stripped, 8);
    let (a, b) = (
        psnr_from_mse(mse(&with.color, reference, MetricSpace::Linear).unwrap()),
        psnr_from_mse(mse(&without.color, reference, MetricSpace::Linear).unwrap()),
    );
    println!("moving-sphere T=16: with motion_next {a:.2} dB, inverted motion {b:.2} dB");
    assert!((a - b).abs() < 1.0, "{a} vs {b}");
}

/// The windowed interface: no output while the window fills, then one per frame with the
/// latency in its record, the rest at `finish`; a cut ends the shot's windows; `process`
/// is refused with the reason; a bad frame leaves the window as it was.
#[test]
fn outputs_come_after_the_window_fills_and_finish_flushes_the_rest() {
    let scene = Scene::new("camera-cut", settings(32, 18, 24, 1)).unwrap();
    let cut = scene.def.cut_at.expect("camera-cut has a cut");
    let frames: Vec<Frame> = (0..24).map(|t| scene.frame(t)).collect();
    let mut f = pixel_trace(&["window=8"]);
    assert_eq!(f.lookahead(), 4);
    assert_eq!(
        f.process(&frames[0]).unwrap_err(),
        FilterError::NeedsWindow {
            filter: "pixel_trace",
            lookahead: 4
        }
    );
    let mut got: Vec<Output> = Vec::new();
    for (t, frame) in frames.iter().enumerate() {
        let t = t as u64;
        if t == 6 {
            // A frame without motion is refused and changes nothing.
            let mut bad = frame.clone();
            bad.remove(ChannelKind::Motion);
            assert!(matches!(f.push(&bad), Err(FilterError::MissingChannel { .. })));
        }
        let outs = f.push(frame).unwrap();
        let expected = if t == cut {
            4 // the shot before the cut: its last 4 frames at once
        } else if t < 4 || (t > cut && t < cut + 4) {
            0 // a window filling
        } else {
            1
        };
        assert_eq!(outs.len(), expected, "frame {t}");
        got.extend(outs);
    }
    let rest = f.finish().unwrap();
    assert_eq!(rest.len(), 4);
    got.extend(rest);
    let indices: Vec<u64> = got.iter().map(|o| o.record.index).collect();
    assert_eq!(indices, (0..24).collect::<Vec<_>>(), "every frame once, in order");
    for o in &got {
        let w = o.record.window.as_ref().unwrap();
        let i = o.record.index;
        // Windows never cross the cut.
        assert!(w.last < cut || w.first >= cut, "frame {i}: {w:?}");
        let shot_start = if i >= cut { cut } else { 0 };
        if i + 4 < cut || (i >= cut && i + 4 < 24) {
            let first = i.saturating_sub(4).max(shot_start);
            assert_eq!(
                (w.first, w.last, w.latency_frames),
                (first, i + 4, 4),
                "frame {i}"
            );
        }
    }
    // After finish the filter is empty: a new sequence starts afresh.
    assert!(f.push(&frames[0]).unwrap().is_empty());
    assert!(f.state_bytes() > 0);
    f.reset();
    assert_eq!(f.state_bytes(), 0);
}

/// Frames of random colour under a uniform translation `v` px/frame with exact motion
/// both ways (no depth, no ids): one flow everywhere.
fn translating(w: usize, h: usize, n: u64, v: [f64; 2], seed: u64) -> Vec<Frame> {
    let mut rng = afterimage::rng::SplitMix64::new(seed);
    (0..n)
        .map(|t| {
            let rgb: Rgb =
                [0, 1, 2].map(|_| afterimage::frame::Plane::from_fn(w, h, |_, _| rng.range(0.0, 1.0) as f32));
            let mut f = Frame::new(rgb).unwrap();
            f.meta.index = t;
            let c = |x: f64| afterimage::frame::Plane::from_fn(w, h, |_, _| x as f32);
            f.set_f32(ChannelKind::Motion, vec![c(-v[0]), c(-v[1])]).unwrap();
            f.set_f32(ChannelKind::MotionNext, vec![c(v[0]), c(v[1])])
                .unwrap();
            f
        })
        .collect()
}

/// Eq. 11 for one flow, box kernel of one pixel area, against a float64 scalar reference:
/// the mean over the window of the sample nearest each point of the pixel's path
/// `centre + (l - t0) v`, frames whose path point is off the image left out.
#[test]
fn one_flow_matches_the_scalar_reference_of_eq_11() {
    let (w, h, v) = (23usize, 17usize, [0.3, -0.45]);
    let frames = translating(w, h, 9, v, 11);
    let out = output_for(&["window=8"], &frames, 4);
    let t = afterimage::tolerance::Tolerance::new(1e-6, 1e-5);
    for y in 0..h {
        for x in 0..w {
            let (mut sum, mut n) = ([0.0f64; 3], 0.0);
            for (l, f) in frames.iter().enumerate() {
                let d = l as f64 - 4.0;
                let (px, py) = (x as f64 + 0.5 + d * v[0], y as f64 + 0.5 + d * v[1]);
                if px < 0.0 || py < 0.0 || px >= w as f64 || py >= h as f64 {
                    continue;
                }
                for (c, s) in sum.iter_mut().enumerate() {
                    *s += f.color()[c].get(px as usize, py as usize) as f64;
                }
                n += 1.0;
            }
            for (c, s) in sum.iter().enumerate() {
                t.check(
                    &format!("({x},{y}) channel {c}"),
                    out.color[c].get(x, y) as f64,
                    s / n,
                )
                .unwrap();
            }
        }
    }
}

/// The Gaussian kernel and the bounded flow list do what they say: a wider kernel is
/// smoother (spokes: less error than the input, output differs from the box's), and a
/// list of one missed flow drops flows where blades cross, which the record counts.
#[test]
fn gaussian_kernel_and_flow_list_bound() {
    let t0 = 16u64;
    let scene = Scene::new("spokes", settings(48, 48, 2 * t0 + 1, 64)).unwrap();
    let frames: Vec<Frame> = (0..=2 * t0).map(|t| scene.frame(t)).collect();
    let reference = frames[t0 as usize].reference().unwrap();
    let input = rms(frames[t0 as usize].color(), reference);
    let boxed = output_for(&["window=16"], &frames, t0);
    let gauss = output_for(&["window=16", "kernel=gaussian", "support=1"], &frames, t0);
    let e_gauss = rms(&gauss.color, reference);
    println!(
        "spokes T=16: input {input:.4}, box {:.4}, gaussian r=1 {e_gauss:.4}",
        rms(&boxed.color, reference)
    );
    assert!(e_gauss < 0.7 * input, "{e_gauss} vs input {input}");
    assert!(
        rms(&gauss.color, &boxed.color) > 1e-3,
        "the kernel changes the result"
    );
    // Foliage: many thin blades swaying over each other and the ground.
    let scene = Scene::new("foliage", settings(64, 36, 2 * t0 + 1, 1)).unwrap();
    let frames: Vec<Frame> = (0..=2 * t0).map(|t| scene.frame(t)).collect();
    let dropped = |set: &[&str]| output_for(set, &frames, t0).record.window.unwrap().flows_dropped;
    let (one, three) = (dropped(&["window=16", "max_flows=1"]), dropped(&["window=16"]));
    println!("foliage T=16: flows dropped with a list of 1: {one}, of 3: {three}");
    assert!(one > three, "{one} vs {three}");
}

/// Extreme input never panics or leaks non-finite values: HDR from 1e-6 to 1e6 with a
/// 1e30 firefly, motion of 1e9 px (paths leave the image at once), non-finite motion and
/// motion_next, an all-NaN colour frame, and a window longer than the sequence.
#[test]
fn extreme_input_stays_finite() {
    let (w, h) = (19usize, 13usize);
    let mut frames = translating(w, h, 12, [0.7, 0.2], 5);
    let mut rng = afterimage::rng::SplitMix64::new(9);
    for (t, f) in frames.iter_mut().enumerate() {
        for p in f.color_mut() {
            for v in p.iter_mut() {
                *v = 10f64.powf(rng.range(-6.0, 6.0)) as f32;
            }
        }
        match t {
            3 => f.color_mut()[0][40] = 1e30,
            5 => {
                let huge = afterimage::frame::Plane::from_fn(w, h, |_, _| 1e9f32);
                f.set_f32(ChannelKind::Motion, vec![huge.clone(), huge]).unwrap();
            }
            6 => {
                let nan = afterimage::frame::Plane::from_fn(w, h, |x, _| {
                    if x % 2 == 0 {
                        f32::NAN
                    } else {
                        f32::INFINITY
                    }
                });
                f.set_f32(ChannelKind::MotionNext, vec![nan.clone(), nan.clone()])
                    .unwrap();
                f.set_f32(ChannelKind::Motion, vec![nan.clone(), nan]).unwrap();
            }
            8 => {
                for p in f.color_mut() {
                    p.fill(f32::NAN);
                }
            }
            _ => {}
        }
    }
    for set in [
        &["window=8"][..],
        &["window=64", "kernel=gaussian", "support=2", "d_th=0.5"],
    ] {
        let mut f = pixel_trace(set);
        let outs = run_sequence(f.as_mut(), &frames).unwrap();
        assert_eq!(outs.len(), frames.len());
        for o in &outs {
            assert!(
                o.color
                    .iter()
                    .all(|p| p.data().iter().all(|v| v.is_finite() && *v >= 0.0)),
                "{set:?} frame {}",
                o.record.index
            );
        }
        assert!(
            outs[8].record.input.non_finite >= (3 * w * h) as u64,
            "the NaN frame is counted"
        );
    }
}
