//! The scene catalogue: exact motion, Shinya's parameters, converged references,
//! determinism, and a lossless trip through the EXR writer and reader.

mod common;

use afterimage::frame::{ChannelKind, Frame};
use afterimage::io::{read_frame, ReadOptions, Sequence};
use afterimage::metrics::{mse, MetricSpace};
use afterimage::scene::{Jitter, Projection, Scene, Settings, BEHIND_CAMERA_MOTION, CATALOGUE, SKY_DEPTH};
use afterimage::tolerance::Tolerance;
use glam::DVec3;

fn small(frames: u64) -> Settings {
    Settings {
        width: 64,
        height: 36,
        frames,
        spp: 4,
        jitter: Jitter::Halton(8),
        noise: false,
        seed: 7,
        shading: 1,
    }
}

/// For every scene and frame: follow each pixel's motion from its sample position into
/// the previous frame and cast a ray there at the previous instant. Where the point was
/// visible then (nothing nearer in front of it), that ray must hit the same object at
/// the point's previous depth; sky must land on sky. Occluded points are counted, not
/// checked; a point that lands on something farther, or on another object at its depth,
/// is a motion error.
#[test]
fn motion_is_exact_in_every_scene() {
    motion_lands_on_the_same_point(ChannelKind::Motion, -1);
}

/// The same for `motion_next` into the next frame.
#[test]
fn motion_next_is_exact_in_every_scene() {
    motion_lands_on_the_same_point(ChannelKind::MotionNext, 1);
}

fn motion_lands_on_the_same_point(channel: ChannelKind, step: i64) {
    for entry in CATALOGUE {
        let settings = small(6);
        let scene = Scene::new(entry.name, settings).unwrap();
        let (w, h) = (settings.width, settings.height);
        let (mut checked, mut occluded, mut offscreen, mut total) = (0usize, 0usize, 0usize, 0usize);
        let mut max_depth_err = 0.0f64;
        let mut max_px_err = 0.0f64;
        let frames = if step < 0 {
            1..settings.frames
        } else {
            0..settings.frames - 1
        };
        for t in frames {
            let frame = scene.frame(t);
            // "prev" is the other instant: the previous or the next one.
            let prev = scene.instant((t as i64 + step) as f64);
            let rays = prev.camera.rays(w, h);
            let [mx, my] = frame.planes(channel).unwrap() else {
                panic!("two motion planes")
            };
            let ids = frame.object_id().unwrap();
            let depth = frame.depth().unwrap();
            let j = frame.meta.jitter;
            let now = scene.instant(t as f64);
            for y in 0..h {
                for x in 0..w {
                    total += 1;
                    let (sx, sy) = (x as f64 + 0.5 + j[0] as f64, y as f64 + 0.5 + j[1] as f64);
                    let (vx, vy) = (mx.get(x, y) as f64, my.get(x, y) as f64);
                    if vx == BEHIND_CAMERA_MOTION as f64 {
                        offscreen += 1;
                        continue;
                    }
                    let (px, py) = (sx + vx, sy + vy);
                    if !(0.0..w as f64).contains(&px) || !(0.0..h as f64).contains(&py) {
                        offscreen += 1;
                        continue;
                    }
                    let id = ids.get(x, y);
                    let hit = prev.intersect(&rays.ray(px, py), f64::INFINITY);
                    if id == 0 {
                        // Sky: camera-only motion. Perspective: the previous camera's ray
                        // through the motion's end has the same direction (a point at
                        // infinity); orthographic: it passes through the far point.
                        let cur = now.camera.rays(w, h).ray(sx, sy);
                        let was = rays.ray(px, py);
                        let err = match now.camera.projection {
                            Projection::Perspective { .. } => (was.dir - cur.dir).length(),
                            Projection::Orthographic { .. } => {
                                let q = cur.at(SKY_DEPTH) - was.origin;
                                (q - was.dir * q.dot(was.dir)).length() / SKY_DEPTH
                            }
                        };
                        assert!(
                            err < 1e-9,
                            "{} frame {t} ({x},{y}): sky motion off by {err}",
                            entry.name
                        );
                        assert_eq!(depth.get(x, y) as f64, SKY_DEPTH, "sky depth");
                        if hit.is_none() {
                            checked += 1;
                        } else {
                            occluded += 1; // an object has moved in front of that sky since
                        }
                        continue;
                    }
                    // Where the surface point was, at the previous instant, and its depth.
                    let ray = now.camera.rays(w, h).ray(sx, sy);
                    let cur = now.intersect(&ray, f64::INFINITY).expect("not sky");
                    let was = prev.transform(cur.object).point(cur.local_point);
                    let expected = prev.camera.project(was, w, h).unwrap();
                    max_px_err = max_px_err
                        .max((expected.x - px).abs())
                        .max((expected.y - py).abs());
                    let Some(hit) = hit else {
                        panic!("{} frame {t} ({x},{y}): motion lands on sky", entry.name);
                    };
                    let fwd = DVec3::from_array(prev.camera.forward);
                    let origin = rays.ray(px, py).origin;
                    let hit_depth =
                        (rays.ray(px, py).at(hit.local.t) - DVec3::from_array(prev.camera.position)).dot(fwd);
                    let _ = origin;
                    let tol = 1e-6 * expected.depth.max(1.0);
                    if hit_depth < expected.depth - tol.max(1e-4 * expected.depth) {
                        occluded += 1;
                        continue;
                    }
                    let err = (hit_depth - expected.depth).abs() / expected.depth;
                    assert_eq!(
                        scene.def.objects[hit.object].id, id,
                        "{} frame {t} ({x},{y}): lands on another object (depth error {err})",
                        entry.name
                    );
                    max_depth_err = max_depth_err.max(err);
                    checked += 1;
                }
            }
        }
        println!(
            "{channel}: {:<14} checked {:5.1}% of pixels (occluded before {:4.1}%, off screen {:4.1}%): \
             max position error {max_px_err:.1e} px, max depth error {max_depth_err:.1e} (relative)",
            entry.name,
            100.0 * checked as f64 / total as f64,
            100.0 * occluded as f64 / total as f64,
            100.0 * offscreen as f64 / total as f64,
        );
        assert!(
            checked as f64 > 0.5 * total as f64,
            "{}: checked only {checked}/{total}",
            entry.name
        );
        assert!(max_px_err < 1e-3, "{}: {max_px_err}", entry.name);
        assert!(max_depth_err < 1e-4, "{}: {max_depth_err}", entry.name);
    }
}

/// Shinya 1993, sec. 5, experiment 1, read back from the geometry and the image.
#[test]
fn thin_line_has_shinyas_parameters() {
    let settings = Settings {
        width: 96,
        height: 48,
        spp: 256,
        jitter: Jitter::None,
        ..small(3)
    };
    let scene = Scene::new("thin-line", settings).unwrap();
    let bar = scene.object("bar").unwrap();
    let afterimage::scene::Shape::Cuboid { half } = bar.shape else {
        panic!("bar is a box")
    };
    let cam = (scene.def.camera)(0.0);
    let px = cam.world_per_pixel(settings.height).expect("orthographic");
    let t = Tolerance::abs(1e-12);
    t.check("width 1/8 px", 2.0 * half.y / px, 0.125).unwrap();
    let xf0 = (bar.motion)(0.0);
    let xf1 = (bar.motion)(1.0);
    let axis = xf0.vector(DVec3::X);
    t.check("1 degree", axis.y.atan2(axis.x).to_degrees(), 1.0)
        .unwrap();
    let p0 = cam
        .project(xf0.point(DVec3::ZERO), settings.width, settings.height)
        .unwrap();
    let p1 = cam
        .project(xf1.point(DVec3::ZERO), settings.width, settings.height)
        .unwrap();
    t.check("0.22 px/frame vertically", p1.y - p0.y, 0.22).unwrap();
    t.check("no horizontal motion", p1.x - p0.x, 0.0).unwrap();
    // The reference integrates coverage: each column holds 1/8 of a pixel of white
    // (the bar, white on black, 1 degree off horizontal, covers 0.125 / cos(1 deg)).
    let f = scene.frame(1);
    let r = &f.reference().unwrap()[0];
    let expected = 0.125 / 1f64.to_radians().cos();
    let columns: Vec<f64> = (0..settings.width)
        .map(|x| (0..settings.height).map(|y| r.get(x, y) as f64).sum())
        .collect();
    let mean = columns.iter().sum::<f64>() / columns.len() as f64;
    Tolerance::abs(0.003)
        .check("mean column coverage", mean, expected)
        .unwrap();
    assert!(columns.iter().all(|c| (c - expected).abs() < 0.03), "{columns:?}");
    // And the motion says so: 0.22 px down, none across.
    let [mx, my] = f.motion().unwrap();
    let ids = f.object_id().unwrap();
    let on_bar: Vec<(usize, usize)> = (0..settings.height)
        .flat_map(|y| (0..settings.width).map(move |x| (x, y)))
        .filter(|&(x, y)| ids.get(x, y) == 1)
        .collect();
    assert!(
        !on_bar.is_empty(),
        "the point-sampled bar is visible in some pixels"
    );
    for (x, y) in on_bar {
        Tolerance::abs(1e-4)
            .check("mv y", my.get(x, y) as f64, -0.22)
            .unwrap();
        Tolerance::abs(1e-4)
            .check("mv x", mx.get(x, y) as f64, 0.0)
            .unwrap();
    }
}

/// 16x16 stratified samples are enough: 32x32 changes the flyover reference, at the
/// default size, by under 1e-3 RMSE (linear, clamped).
#[test]
fn reference_has_converged_on_flyover() {
    let base = Settings {
        jitter: Jitter::None,
        ..Settings::default()
    };
    let a = Scene::new("flyover", Settings { spp: 256, ..base })
        .unwrap()
        .frame(0);
    let b = Scene::new("flyover", Settings { spp: 1024, ..base })
        .unwrap()
        .frame(0);
    let rmse = mse(
        a.reference().unwrap(),
        b.reference().unwrap(),
        MetricSpace::Linear,
    )
    .unwrap()
    .sqrt();
    println!("flyover reference 16x16 vs 32x32: RMSE {rmse:.2e}");
    assert!(rmse < 1e-3, "{rmse}");
    // And the reference is far from the 1-sample input (it does integrate something).
    let input_err = mse(a.color(), a.reference().unwrap(), MetricSpace::Linear)
        .unwrap()
        .sqrt();
    assert!(input_err > 10.0 * rmse, "{input_err}");
}

#[test]
fn same_seed_same_bits_and_noise_averages_out() {
    let settings = Settings {
        noise: true,
        jitter: Jitter::Halton(16),
        spp: 16,
        ..small(64)
    };
    let a = Scene::new("static", settings).unwrap();
    let b = Scene::new("static", settings).unwrap();
    assert_eq!(a.frame(1), b.frame(1), "same seed, same bits");
    let c = Scene::new("static", Settings { seed: 8, ..settings }).unwrap();
    assert_ne!(
        a.frame(1).color(),
        c.frame(1).color(),
        "another seed, other noise"
    );
    // A still scene: the reference does not change, the noisy jittered input does, and
    // its mean over 64 frames (16 jitter phases, 64 shadow samples) approaches the
    // reference, which integrates the soft shadow over the pixel box.
    let n = settings.frames;
    let frames: Vec<Frame> = (0..n).map(|t| a.frame(t)).collect();
    assert!(
        frames[0].reference() == frames[1].reference(),
        "a still scene's reference is still"
    );
    assert_ne!(
        frames[0].color(),
        frames[16].color(),
        "same jitter phase, other noise"
    );
    let mut mean = frames[0].color().clone();
    for (c, plane) in mean.iter_mut().enumerate() {
        for (i, v) in plane.data_mut().iter_mut().enumerate() {
            *v = frames.iter().map(|f| f.color()[c].data()[i]).sum::<f32>() / n as f32;
        }
    }
    let r = frames[0].reference().unwrap();
    let one = mse(frames[0].color(), r, MetricSpace::Linear).unwrap();
    let avg = mse(&mean, r, MetricSpace::Linear).unwrap();
    println!("noise: MSE of one frame {one:.2e}, of the mean of {n} {avg:.2e}");
    assert!(avg < one / 4.0, "{one} -> {avg}");
}

#[test]
fn jitter_and_frame_values() {
    let s = Settings {
        jitter: Jitter::Halton(8),
        ..small(10)
    };
    let scene = Scene::new("static", s).unwrap();
    let j: Vec<[f32; 2]> = (0..10).map(|t| scene.frame(t).meta.jitter).collect();
    let t = Tolerance::abs(1e-7);
    t.check("Halton(2,3) index 1, x", j[0][0] as f64, 0.0).unwrap();
    t.check("Halton(2,3) index 1, y", j[0][1] as f64, 1.0 / 3.0 - 0.5)
        .unwrap();
    t.check("Halton(2,3) index 2, x", j[1][0] as f64, -0.25).unwrap();
    t.check("Halton(2,3) index 2, y", j[1][1] as f64, 2.0 / 3.0 - 0.5)
        .unwrap();
    assert_eq!(j[8], j[0], "8 phases");
    assert!(j.iter().all(|v| v.iter().all(|c| (-0.5..0.5).contains(c))));
    let cut = Scene::new("camera-cut", s).unwrap();
    let resets: Vec<bool> = (0..10).map(|t| cut.frame(t).meta.reset).collect();
    assert_eq!(resets.iter().filter(|r| **r).count(), 1);
    assert!(resets[5], "cut half way through 10 frames");
    // Settings are validated with the bound in the message.
    let e = Scene::new("static", Settings { spp: 200, ..s }).err().unwrap();
    assert!(
        e.to_string().contains("square") && e.to_string().contains("196"),
        "{e}"
    );
    let e = Scene::new("teapot", s).err().unwrap();
    assert!(e.to_string().contains("thin-line"), "{e}");
}

/// `afterimage scene` writes EXR that reads back as exactly the frames rendered in
/// process, plus scene.json; the reader needs no options.
#[test]
fn scenes_load_back_unchanged() {
    let dir = tempfile::tempdir().unwrap();
    for name in ["moving-sphere", "hdr"] {
        let out = dir.path().join(name);
        let status = common::bin()
            .args([
                "scene", name, "--frames", "3", "--size", "40x24", "--spp", "4", "--out",
            ])
            .arg(&out)
            .status()
            .unwrap();
        assert!(status.success());
        let meta: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(out.join("scene.json")).unwrap()).unwrap();
        assert_eq!(meta["frames"].as_array().unwrap().len(), 3);
        let scene = Scene::new(
            name,
            Settings {
                width: 40,
                height: 24,
                frames: 3,
                spp: 4,
                ..Settings::default()
            },
        )
        .unwrap();
        let seq = Sequence::open(out.to_str().unwrap()).unwrap();
        for (t, f) in seq.frames(&ReadOptions::default()).enumerate() {
            assert_eq!(f.unwrap(), scene.frame(t as u64), "{name} frame {t}");
        }
    }
    let f = read_frame(&dir.path().join("hdr/frame_0001.exr"), &ReadOptions::default()).unwrap();
    assert!(f.channels().contains(ChannelKind::Reference));
    let max = f.reference().unwrap()[0]
        .data()
        .iter()
        .cloned()
        .fold(0.0f32, f32::max);
    assert!(max > 1e3, "hdr emitters reach {max}");
}
