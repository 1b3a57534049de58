//! The stiff and extreme-case suite (issue 5): long still scenes, HDR extremes, fireflies,
//! non-finite and negative input, black, constant, Nyquist flicker, abrupt steps and the
//! forgetting factor's extremes. Every case runs for `phlm`, `taa` and `traa`; PHLM's inverse
//! covariances are also checked for symmetric positive definiteness with a Cholesky
//! factorisation. Long variants are `#[ignore]`d (`cargo test --release --test stiff --
//! --ignored`).

use afterimage::filters::create;
use afterimage::filters::phlm::{rls, Params as PhlmParams, Phlm};
use afterimage::frame::{ChannelKind, Frame, Plane, Rgb};
use afterimage::pipeline::{params::parse_assignments, Filter, FilterKind, FrameRecord};
use afterimage::rng::SplitMix64;
use afterimage::tolerance::Tolerance;

/// The filters every case runs on.
const FILTERS: [&str; 3] = ["phlm", "taa", "traa"];

/// A frame of `w` x `h` with colour from `f(x, y, channel)`, zero motion and a flat depth
/// (so every stage that can run does).
fn frame(w: usize, h: usize, index: u64, f: impl Fn(usize, usize, usize) -> f32) -> Frame {
    let color: Rgb = [0, 1, 2].map(|c| Plane::from_fn(w, h, |x, y| f(x, y, c)));
    let mut fr = Frame::new(color).unwrap();
    fr.set_f32(
        ChannelKind::Motion,
        vec![Plane::filled(w, h, 0.0), Plane::filled(w, h, 0.0)],
    )
    .unwrap();
    fr.set_f32(ChannelKind::Depth, vec![Plane::filled(w, h, 5.0)])
        .unwrap();
    fr.meta.index = index;
    fr
}

/// `name` with `set`, on each pixel's own sample (`pixel_filter=box`) unless `set` says
/// otherwise: the cases state the values a pixel must reach, and the reconstruction (a
/// convex blend of the 3x3) would mix its neighbours in; it has its case of its own
/// ([`the_reconstruction_keeps_extremes_finite`]).
fn filter(name: &str, set: &[&str]) -> Box<dyn Filter> {
    let mut set = set.to_vec();
    if !set.iter().any(|s| s.starts_with("pixel_filter=")) {
        set.push("pixel_filter=box");
    }
    create(name, &parse_assignments(&set).unwrap()).unwrap()
}

/// PHLM's defaults on each pixel's own sample (see [`filter`]).
fn phlm_params() -> PhlmParams {
    PhlmParams {
        pixel_filter: afterimage::filters::reconstruct::PixelFilter::Box,
        ..PhlmParams::default()
    }
}

/// Largest absolute value of an image, NaN if any sample is not finite.
fn max_abs(rgb: &Rgb) -> f32 {
    let mut m = 0.0f32;
    for p in rgb {
        for &v in p.data() {
            if !v.is_finite() {
                return f32::NAN;
            }
            m = m.max(v.abs());
        }
    }
    m
}

fn mean(rgb: &Rgb) -> f64 {
    let n = rgb[0].data().len() * 3;
    rgb.iter().flat_map(|p| p.data()).map(|&v| v as f64).sum::<f64>() / n as f64
}

/// Every P of a PHLM filter is symmetric (packed storage) positive definite (checked on
/// its stored inverse R, which is SPD exactly when P is) with trace at most `bound`;
/// returns the largest trace.
fn check_p(f: &Phlm, bound: f64) -> f64 {
    let rs = f.information_matrices();
    assert!(!rs.is_empty());
    let mut max_trace = 0.0f64;
    for (i, r) in rs.iter().enumerate() {
        let (pd, pivot) = rls::positive_definite(r);
        assert!(
            pd,
            "R of pixel {i} is not positive definite (pivot {pivot}): {r:?}"
        );
        let t = rls::trace_of_inverse_packed(r).unwrap() as f64;
        assert!(t <= bound, "trace(P) of pixel {i} = {t} > {bound}");
        max_trace = max_trace.max(t);
    }
    max_trace
}

/// A still scene with a fixed texture and small per-frame noise (as jitter gives).
fn still_frame(rng: &mut SplitMix64, index: u64) -> Frame {
    let noise: Vec<f32> = (0..8 * 8 * 3).map(|_| rng.next_f64() as f32 * 0.02).collect();
    frame(8, 8, index, |x, y, c| {
        0.2 + 0.6 * (((x * 3 + y * 5 + c) % 7) as f32 / 7.0) + noise[(y * 8 + x) * 3 + c]
    })
}

/// PHLM on a still scene for `frames` frames: P stays SPD under trace(P0) = 4 p0 (1% margin),
/// no matrix needs repair, the output stays finite and close to the noise-free mean.
fn phlm_still(frames: u64) -> f64 {
    let mut f = Phlm::new(phlm_params());
    phlm_still_on(&mut f, frames, check_p)
}

/// [`phlm_still`] on filter `f` (either backend): every frame's record says no matrix was
/// repaired and trace(P) stayed under the bound; every 10,000 frames `check` looks at the
/// models themselves.
fn phlm_still_on<F: Filter + ?Sized>(f: &mut F, frames: u64, check: impl Fn(&F, f64) -> f64) -> f64 {
    let params = phlm_params();
    let bound = 4.0 * params.p0.max(params.clip_p) as f64 * 1.01;
    let mut rng = SplitMix64::new(5);
    let mut max_trace = 0.0f64;
    let mut last = None;
    for t in 0..frames {
        let fr = still_frame(&mut rng, t);
        let out = f.process(&fr).unwrap();
        let m = out.record.model.expect("phlm reports model health");
        assert_eq!(m.p_repaired, 0, "frame {t}");
        max_trace = max_trace.max(m.max_trace_p);
        assert!(max_trace <= bound, "frame {t}: trace {max_trace}");
        if t % 10_000 == 0 || t + 1 == frames {
            check(f, bound);
            assert!(max_abs(&out.color).is_finite());
        }
        if t + 1 == frames {
            last = Some(out.color);
        }
    }
    // Stable: the output is the scene (noise mean 0.01) to within the noise.
    let out = last.unwrap();
    for (c, p) in out.iter().enumerate() {
        for y in 0..8 {
            for x in 0..8 {
                let expect = 0.2 + 0.6 * (((x * 3 + y * 5 + c) % 7) as f32 / 7.0) + 0.01;
                Tolerance::abs(0.01)
                    .check("still output", p.get(x, y) as f64, expect as f64)
                    .unwrap();
            }
        }
    }
    max_trace
}

#[test]
fn phlm_still_scene_100k_frames_keeps_p_bounded() {
    let t = phlm_still(100_000);
    println!("phlm still 100k: max trace(P) {t:.3}");
}

#[test]
#[ignore = "1,000,000 frames: run in release"]
fn phlm_still_scene_1m_frames_keeps_p_bounded() {
    let t = phlm_still(1_000_000);
    println!("phlm still 1M: max trace(P) {t:.3}");
}

/// taa and traa on the same long still scene: output finite and stable (frame 20,000 equals
/// frame 2,000 to within the noise). Their converged value is not the scene at local
/// extrema of this pixel-frequency texture: variance clipping pulls history toward the box
/// (up to ~0.1 here, printed), the known TAA bias the PHLM paper's sharpness claim is about.
#[test]
fn taa_and_traa_survive_a_long_still_scene() {
    for name in ["taa", "traa"] {
        still_scene(filter(name, &[]).as_mut(), 20_000);
    }
}

/// `taa` on the GPU backend (feature `gpu`, an adapter needed) through the still scene of
/// [`taa_and_traa_survive_a_long_still_scene`], 100,000 frames (or
/// `AFTERIMAGE_GPU_STILL_FRAMES`), with the same bounds.
#[cfg(feature = "gpu")]
#[test]
#[ignore = "100,000 frames on the GPU backend: CI runs it on lavapipe"]
fn taa_on_the_gpu_survives_a_long_still_scene() {
    still_scene(gpu_filter("taa").as_mut(), gpu_still_frames());
}

/// `phlm` on the GPU backend (its RLS solved in f32) through [`phlm_still`]'s scene and
/// bounds, 100,000 frames (or `AFTERIMAGE_GPU_STILL_FRAMES`): no model repaired, trace(P)
/// under its bound every frame (from the record: the GPU's models stay on the device), the
/// output the scene.
#[cfg(feature = "gpu")]
#[test]
#[ignore = "100,000 frames on the GPU backend: CI runs it on lavapipe"]
fn phlm_on_the_gpu_keeps_p_bounded_on_a_long_still_scene() {
    let mut f = gpu_filter("phlm");
    let t = phlm_still_on(f.as_mut(), gpu_still_frames(), |_, _| 0.0);
    println!("phlm on the GPU, still scene: max trace(P) {t:.3}");
}

/// A filter on the GPU backend (an adapter needed; lavapipe will do), on each pixel's own
/// sample as [`filter`].
#[cfg(feature = "gpu")]
fn gpu_filter(name: &str) -> Box<dyn Filter> {
    let set = parse_assignments(&["pixel_filter=box"]).unwrap();
    afterimage::backend::create(name, &set, afterimage::backend::BackendChoice::Gpu)
        .expect("a GPU adapter (lavapipe will do)")
        .filter
}

/// Frames of the GPU still scenes: 100,000, or `AFTERIMAGE_GPU_STILL_FRAMES`.
#[cfg(feature = "gpu")]
fn gpu_still_frames() -> u64 {
    std::env::var("AFTERIMAGE_GPU_STILL_FRAMES")
        .ok()
        .map(|v| v.parse().expect("AFTERIMAGE_GPU_STILL_FRAMES: a whole number"))
        .unwrap_or(100_000)
}

/// Runs `f` over `frames` frames of the still scene: every output finite, the last within
/// 0.02 of frame 2,000's at every pixel; prints the largest distance from the noise-free
/// scene.
fn still_scene(f: &mut dyn Filter, frames: u64) {
    let name = format!("{} on the {}", f.name(), f.backend());
    {
        let mut rng = SplitMix64::new(5);
        let mut early = None;
        let mut out = None;
        for t in 0..frames {
            let o = f.process(&still_frame(&mut rng, t)).unwrap();
            assert!(max_abs(&o.color).is_finite(), "{name} frame {t}");
            if t == 2_000 {
                early = Some(o.color);
            } else {
                out = Some(o.color);
            }
        }
        let (early, out) = (early.unwrap(), out.unwrap());
        let mut bias = 0.0f32;
        for (c, (p, q)) in out.iter().zip(&early).enumerate() {
            for y in 0..8 {
                for x in 0..8 {
                    Tolerance::abs(0.02)
                        .check(&name, p.get(x, y) as f64, q.get(x, y) as f64)
                        .unwrap();
                    let scene = 0.2 + 0.6 * (((x * 3 + y * 5 + c) % 7) as f32 / 7.0) + 0.01;
                    bias = bias.max((p.get(x, y) - scene).abs());
                }
            }
        }
        println!("{name}: still {frames} frames, largest |output - scene| {bias:.4}");
    }
}

/// HDR from 1e-6 to 1e6 across the image and a one-frame firefly of 1e5: never a non-finite
/// value, and the firefly's pixel is back within 1% of its value before within the stated
/// number of frames.
#[test]
fn hdr_extremes_and_a_firefly_decay() {
    // Frames until the firefly pixel is back within 1% (stated per filter).
    // Measured: phlm 1,161, taa 63, traa 58. taa/traa clip the firefly into the box the
    // next frame, then forget the clipped excess at their feedback rate. phlm's model fits
    // the firefly (its box holds it), misses the box the frames after, and is clipped
    // onto the box's surface, which lies on the 10x brighter row below in this
    // gradient; from there its still-pixel memory (lambda 0.998, ~500 frames) brings it
    // back, passing 68% below its value at frame 80. The time is chaotic in the clip's
    // details: before the clip boxes were grown by their guard (kernels::clip::guard) it
    // was 7 frames, because misses by under 1e-8 clipped and relaxed the model again.
    for (name, within) in [("phlm", 1300), ("taa", 70), ("traa", 64)] {
        let n = firefly_decay(filter(name, &[]).as_mut(), name, within + 50, |_, _| {});
        println!("{name}: firefly gone after {n} frames");
        assert!(n <= within, "{name}: firefly took {n} frames (> {within})");
    }
}

/// HDR from 1e-6 to 1e6 across a 12x12 image and a one-frame firefly of 1e5 at frame 20,
/// each frame passed through `edit` (frame, index) before `f` filters it: asserts every
/// output finite and non-negative; returns the frames until the firefly's pixel is back
/// within 1% of its value before (looking up to `limit` frames after it).
fn firefly_decay(f: &mut dyn Filter, name: &str, limit: u64, edit: impl Fn(&mut Frame, u64)) -> u64 {
    let (w, h) = (12, 12);
    let base = |x: usize, y: usize, c: usize| {
        10f32.powf(-6.0 + 12.0 * ((y * w + x) as f32 / (w * h - 1) as f32)) * (1.0 + 0.1 * c as f32)
    };
    let (mut before, mut back_at) = (0.0f32, None);
    for t in 0..=20 + limit {
        let mut fr = frame(w, h, t, |x, y, c| {
            if t == 20 && (x, y) == (6, 3) {
                1e5
            } else {
                base(x, y, c)
            }
        });
        edit(&mut fr, t);
        let out = f.process(&fr).unwrap();
        assert!(
            max_abs(&out.color).is_finite() && out.color.iter().all(|p| p.data().iter().all(|&v| v >= 0.0)),
            "{name} frame {t}"
        );
        let v = out.color[1].get(6, 3);
        if t == 19 {
            before = v;
        }
        if t > 20 && back_at.is_none() && Tolerance::rel(0.01).eq(v as f64, before as f64) {
            back_at = Some(t - 20);
            break;
        }
    }
    back_at.unwrap_or_else(|| panic!("{name}: the firefly never decayed"))
}

/// NaN, +-Inf and negative colour: never in state (the output afterwards matches a run that
/// never saw them, once the repaired frame's neighbourhood has passed), counted in the record.
#[test]
fn non_finite_and_negative_input_never_enter_state() {
    let (w, h) = (16, 12);
    let scene = |t: u64| frame(w, h, t, |x, y, c| 0.3 + 0.4 * ((x + 2 * y + c) % 3) as f32 / 3.0);
    for name in FILTERS {
        let mut clean = filter(name, &[]);
        let mut dirty = filter(name, &[]);
        for t in 0..40u64 {
            let fr = scene(t);
            let a = clean.process(&fr).unwrap();
            let mut bad = fr.clone();
            let mut expect = 0;
            if t % 5 == 2 {
                let [r, g, b] = bad.color_mut();
                r[17] = f32::NAN;
                g[40] = f32::INFINITY;
                b[41] = f32::NEG_INFINITY;
                r[100] = -3.0;
                expect = 3;
            }
            let b = dirty.process(&bad).unwrap();
            assert_eq!(b.record.input.non_finite, expect, "{name} frame {t}");
            assert_eq!(b.record.input.negative, (expect > 0) as u64, "{name} frame {t}");
            assert!(
                max_abs(&b.color).is_finite() && b.color.iter().all(|p| p.data().iter().all(|&v| v >= 0.0))
            );
            if t % 5 == 4 {
                // Two clean frames later, nothing of the bad samples is left anywhere.
                for (pa, pb) in a.color.iter().zip(&b.color) {
                    for (&va, &vb) in pa.data().iter().zip(pb.data()) {
                        Tolerance::abs(0.02).check(name, vb as f64, va as f64).unwrap();
                    }
                }
            }
        }
    }
}

/// The `reconstruct` stage at the defaults (Blackman-Harris at the frame's jitter) on the
/// cases above: HDR from 1e-6 to 1e6 with a firefly of 1e5, and NaN, +-Inf and negative
/// samples, under a jitter that changes every frame. It is a convex blend of repaired
/// samples, so the outputs stay finite and non-negative, and the firefly, spread over its
/// 3x3, is gone from the pixel within the stated number of frames.
#[test]
fn the_reconstruction_keeps_extremes_finite() {
    // Measured: phlm 14, taa 55, traa 1 frames.
    for (name, within) in [("phlm", 40), ("taa", 80), ("traa", 80)] {
        let mut f = filter(name, &["pixel_filter=blackman_harris"]);
        let n = firefly_decay(f.as_mut(), name, 300, |fr, t| {
            fr.meta.jitter = afterimage::scene::halton_jitter(t, 8);
            if t % 7 == 3 {
                let [r, g, b] = fr.color_mut();
                r[17] = f32::NAN;
                g[40] = f32::INFINITY;
                b[41] = -3.0;
            }
        });
        println!("{name} with the reconstruction: firefly gone after {n} frames");
        assert!(n <= within, "{name}: firefly took {n} frames (> {within})");
    }
}

/// All-black input stays black; constant input (no excitation) stays exactly that constant.
#[test]
fn black_and_constant_input_stay_put() {
    for name in FILTERS {
        for value in [0.0f32, 0.37, 250.0] {
            let mut f = filter(name, &[]);
            for t in 0..3_000u64 {
                let out = f.process(&frame(8, 8, t, |_, _, _| value)).unwrap();
                for p in &out.color {
                    for &v in p.data() {
                        // (HDR values pass the tonemap round trip: relative f32 rounding.)
                        Tolerance::new(1e-6, 1e-4)
                            .check(name, v as f64, value as f64)
                            .unwrap_or_else(|e| panic!("frame {t}: {e}"));
                    }
                }
            }
            if name == "phlm" {
                // (Re-run as the concrete type to read P.)
                let mut f = Phlm::new(phlm_params());
                for t in 0..3_000u64 {
                    f.process(&frame(8, 8, t, |_, _, _| value)).unwrap();
                }
                check_p(&f, 4.0 * 1000.0 * 1.01);
            }
        }
    }
}

/// PHLM with the forgetting factor at its extremes (0.95: 20-frame memory; 0.9999: 10,000)
/// over 20,000 still frames and a step: bounded and still converging to the new value.
#[test]
fn phlm_lambda_extremes_stay_bounded() {
    for lambda in [0.95f32, 0.9999] {
        let params = PhlmParams {
            lambda,
            ..phlm_params()
        };
        let mut f = Phlm::new(params);
        let mut rng = SplitMix64::new(8);
        for t in 0..20_000u64 {
            f.process(&still_frame(&mut rng, t)).unwrap();
        }
        check_p(&f, 4.0 * 1000.0 * 1.01);
        let mut last = 0.0;
        for t in 20_000..20_100u64 {
            let out = f.process(&frame(8, 8, t, |_, _, _| 0.9)).unwrap();
            last = mean(&out.color);
        }
        Tolerance::abs(0.01).check("after the step", last, 0.9).unwrap();
        check_p(&f, 4.0 * 1000.0 * 1.01);
    }
}

/// Black/white alternation at Nyquist in space and time (a checkerboard that inverts every
/// frame): bounded (by 1; traa's sharpens have gain 5 (eq. 3.1) and 2 (eq. 4.17) on a
/// checkerboard), and the flicker amplitude (mean |out_t - out_{t-1}|, printed; measured
/// phlm 0.0025, taa 0.047, traa baseline 0.47) below the input's 1. The improved traa
/// (1.76) amplifies it by design: its Sobel term calls every pixel aliased and shrinks the
/// clip box onto the current colour (thesis eq. 4.15-4.16), then sharpens.
#[test]
fn nyquist_flicker_is_bounded() {
    for (name, set, bound, most) in [
        ("phlm", "", 1.0, 0.1),
        ("taa", "", 1.0, 0.1),
        ("traa", "variant=baseline", 5.0, 1.0),
        ("traa", "", 2.0, f64::INFINITY),
    ] {
        let mut f = filter(
            name,
            &[set].into_iter().filter(|s| !s.is_empty()).collect::<Vec<_>>(),
        );
        let mut prev: Option<Rgb> = None;
        let mut flicker = 0.0;
        let frames = 400u64;
        for t in 0..frames {
            let out = f
                .process(&frame(8, 8, t, |x, y, _| ((x + y + t as usize) % 2) as f32))
                .unwrap();
            let m = max_abs(&out.color);
            assert!(m.is_finite() && m <= bound + 1e-5, "{name} frame {t}: {m}");
            if let Some(p) = &prev {
                if t >= frames - 100 {
                    let d: f64 = p
                        .iter()
                        .zip(&out.color)
                        .flat_map(|(a, b)| a.data().iter().zip(b.data()).map(|(a, b)| (a - b).abs() as f64))
                        .sum::<f64>()
                        / (8.0 * 8.0 * 3.0);
                    flicker += d / 100.0;
                }
            }
            prev = Some(out.color);
        }
        println!("{name} {set}: Nyquist flicker amplitude {flicker:.4} (input 1)");
        assert!(flicker < most, "{name}: {flicker}");
    }
}

/// An abrupt step of the whole image (0.2 -> 0.8 after 500 still frames): every filter
/// reaches the new value within the stated number of frames and never overshoots.
#[test]
fn abrupt_steps_are_followed() {
    for (name, within) in [("phlm", 3), ("taa", 3), ("traa", 3)] {
        let mut f = filter(name, &[]);
        let mut reached = None;
        for t in 0..560u64 {
            let v = if t < 500 { 0.2 } else { 0.8 };
            let out = f.process(&frame(8, 8, t, |_, _, _| v)).unwrap();
            let m = mean(&out.color);
            assert!(m <= 0.8 + 1e-4, "{name} overshoots: {m}");
            if t >= 500 && reached.is_none() && Tolerance::abs(0.01).eq(m, 0.8) {
                reached = Some(t - 500);
            }
        }
        let n = reached.expect("reaches the new value");
        assert!(n < within, "{name}: {n} frames");
    }
}

/// Every case's record says what happened: PHLM reports max trace(P) and reset shares.
#[test]
fn phlm_record_reports_model_health() {
    let mut f = filter("phlm", &[]);
    let r0: FrameRecord = f.process(&frame(8, 8, 0, |_, _, _| 0.5)).unwrap().record;
    let m = r0.model.unwrap();
    assert_eq!(m.reset_by_disocclusion, 0.0);
    assert!(m.max_trace_p > 0.0 && m.max_trace_p <= 4000.0);
    // A jump outside every box fails every model's test; the third failure in a row
    // (`clip_after = 1.75`) resets every model by clipping.
    let r1 = f.process(&frame(8, 8, 1, |_, _, _| 0.9)).unwrap().record;
    assert_eq!(r1.model.as_ref().unwrap().reset_by_clip, 0.0);
    let clips: Vec<f64> = (2..4)
        .map(|t| {
            let r = f.process(&frame(8, 8, t, |_, _, _| 0.9)).unwrap().record;
            r.model.unwrap().reset_by_clip
        })
        .collect();
    assert_eq!(clips, [0.0, 1.0]);
    // Motion that takes every pixel off screen resets every model by disocclusion.
    let mut fr = frame(8, 8, 4, |_, _, _| 0.9);
    fr.set_f32(
        ChannelKind::Motion,
        vec![Plane::filled(8, 8, 100.0), Plane::filled(8, 8, 0.0)],
    )
    .unwrap();
    let r2 = f.process(&fr).unwrap().record;
    assert_eq!(r2.model.unwrap().reset_by_disocclusion, 1.0);
    assert!(r2.ran("reproject"));
    assert!(
        !r1.ran("reproject"),
        "nothing moves in frame 1: reprojection is left out"
    );
}

/// Bright points (200, a lamp's highlight) moving over a dim, textured background under a
/// panning camera, as in the corpus' `hdr` scene: no filter's output is ever brighter than
/// the brightest sample of its frame. `phlm`'s models, fitted while a point passed, once
/// predicted tonemapped values at the top of the range where it had left, which the
/// untonemap turned into millions.
#[test]
fn moving_highlights_never_outshine_their_frame() {
    let (w, h) = (24, 16);
    for name in FILTERS {
        for set in [&[][..], &["pixel_filter=blackman_harris"]] {
            let mut f = filter(name, set);
            for t in 0..40u64 {
                let mut fr = frame(w, h, t, |x, y, c| {
                    // Stars drift one pixel a frame against the pan; the background pans.
                    let sx = (x + w - (t as usize % w)) % w;
                    if (sx % 7 == 2 && y % 5 == 1) || (sx % 11 == 6 && y % 4 == 3) {
                        [120.0, 160.0, 200.0][c]
                    } else {
                        0.1 + 0.02 * ((x + t as usize + 2 * y) % 5) as f32 + 0.01 * c as f32
                    }
                });
                fr.meta.jitter = afterimage::scene::halton_jitter(t, 8);
                fr.set_f32(
                    ChannelKind::Motion,
                    vec![Plane::filled(w, h, -1.0), Plane::filled(w, h, 0.0)],
                )
                .unwrap();
                let most = max_abs(fr.color());
                let out = f.process(&fr).unwrap();
                let got = max_abs(&out.color);
                assert!(
                    got <= most * (1.0 + 1e-5),
                    "{name} {set:?} frame {t}: output {got} above the frame's brightest sample {most}"
                );
            }
        }
    }
}
