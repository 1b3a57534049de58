//! `phlm` (f32, planar, parallel) against a float64 scalar reference of the same algorithm,
//! written independently from the paper's Algorithm 1 (full 4x4 matrices, Gauss-Jordan
//! inverse, per-pixel loops), over 10,000 frames of a moving, noisy scene.

#![allow(clippy::needless_range_loop)] // index loops mirror the equations

use afterimage::filters::phlm::{Params, Phlm};
use afterimage::frame::{ChannelKind, Frame, Plane, Rgb};
use afterimage::kernels::clip::{CLIP_EPS, CLIP_REL};
use afterimage::pipeline::{Filter, FilterKind};
use afterimage::rng::SplitMix64;

const W: usize = 24;
const H: usize = 16;
/// Content velocity in pixels per frame (motion points back: -V).
const V: [f64; 2] = [0.37, -0.21];

fn scene(t: u64, rng: &mut SplitMix64) -> Frame {
    let tt = t as f64;
    let color: Rgb = [0, 1, 2].map(|c| {
        Plane::from_fn(W, H, |x, y| {
            let (u, v) = (x as f64 + 0.5 - V[0] * tt, y as f64 + 0.5 - V[1] * tt);
            let s = 0.5 + 0.3 * (0.4 * u + c as f64).sin() * (0.3 * v).cos() + 0.05 * (rng.next_f64() - 0.5);
            s as f32
        })
    });
    let mut f = Frame::new(color).unwrap();
    f.set_f32(
        ChannelKind::Motion,
        vec![
            Plane::filled(W, H, -V[0] as f32),
            Plane::filled(W, H, -V[1] as f32),
        ],
    )
    .unwrap();
    f.meta.index = t;
    f
}

/// The reference state of one pixel.
#[derive(Clone, Copy)]
struct Px {
    beta: [[f64; 4]; 3],
    p: [[f64; 4]; 4],
    z: [f64; 3],
}

fn ycocg(c: [f64; 3]) -> [f64; 3] {
    [
        0.25 * c[0] + 0.5 * c[1] + 0.25 * c[2],
        0.5 * c[0] - 0.5 * c[2],
        -0.25 * c[0] + 0.5 * c[1] - 0.25 * c[2],
    ]
}

fn rgb(c: [f64; 3]) -> [f64; 3] {
    let t = c[0] - c[2];
    [t + c[1], c[0] + c[2], t - c[1]]
}

fn invert(m: &[[f64; 4]; 4]) -> [[f64; 4]; 4] {
    let mut a = *m;
    let mut inv = [[0.0; 4]; 4];
    for (i, row) in inv.iter_mut().enumerate() {
        row[i] = 1.0;
    }
    for c in 0..4 {
        let piv = (c..4)
            .max_by(|&i, &j| a[i][c].abs().total_cmp(&a[j][c].abs()))
            .unwrap();
        a.swap(c, piv);
        inv.swap(c, piv);
        let d = a[c][c];
        for j in 0..4 {
            a[c][j] /= d;
            inv[c][j] /= d;
        }
        for i in 0..4 {
            if i != c {
                let f = a[i][c];
                for j in 0..4 {
                    a[i][j] -= f * a[c][j];
                    inv[i][j] -= f * inv[c][j];
                }
            }
        }
    }
    inv
}

fn reset(c: [f64; 3], z: [f64; 3], p0: f64) -> Px {
    let mut p = [[0.0; 4]; 4];
    for (i, row) in p.iter_mut().enumerate() {
        row[i] = p0;
    }
    Px {
        beta: c.map(|v| [v, 0.0, 0.0, 0.0]),
        p,
        z,
    }
}

fn predict(m: &Px, x: &[f64; 4]) -> [f64; 3] {
    m.beta.map(|b| (0..4).map(|j| b[j] * x[j]).sum())
}

/// Bilinear blend of pixel states at `(px, py)` (centres at +0.5, edges clamped). The
/// filter stores and blends the information matrix R = P^-1, so the blend is of P^-1.
fn blend(state: &[Px], px: f64, py: f64) -> Px {
    let (fx, fy) = (px - 0.5, py - 0.5);
    let (x0, y0) = (fx.floor(), fy.floor());
    let (tx, ty) = (fx - x0, fy - y0);
    let cl = |v: f64, n: usize| (v.max(0.0) as usize).min(n - 1);
    let taps = [
        (cl(x0, W), cl(y0, H), (1.0 - tx) * (1.0 - ty)),
        (cl(x0 + 1.0, W), cl(y0, H), tx * (1.0 - ty)),
        (cl(x0, W), cl(y0 + 1.0, H), (1.0 - tx) * ty),
        (cl(x0 + 1.0, W), cl(y0 + 1.0, H), tx * ty),
    ];
    let mut out = Px {
        beta: [[0.0; 4]; 3],
        p: [[0.0; 4]; 4],
        z: [0.0; 3],
    };
    for (x, y, w) in taps {
        let s = &state[y * W + x];
        let r = invert(&s.p);
        for c in 0..3 {
            for j in 0..4 {
                out.beta[c][j] += w * s.beta[c][j];
            }
            out.z[c] += w * s.z[c];
        }
        for i in 0..4 {
            for j in 0..4 {
                out.p[i][j] += w * r[i][j];
            }
        }
    }
    out.p = invert(&out.p);
    out
}

/// One frame of Algorithm 1 in f64 for the default parameters with a bilinear model fetch
/// and a hard reset on a clip (with the forgetting factor of the scene's speed,
/// `Params::lambda_moving`).
fn reference_frame(
    state: &mut Option<Vec<Px>>,
    y: &[[f64; 3]],
    motion: [f64; 2],
    p: &Params,
) -> Vec<[f64; 3]> {
    let (p0, clip_p) = (p.p0 as f64, p.clip_p as f64);
    // Motion-dependent forgetting: every frame's motion channel is -V (also frame 0's).
    let speed = (V[0] * V[0] + V[1] * V[1]).sqrt();
    let lambda = if p.lambda_moving == 0.0 {
        p.lambda as f64
    } else {
        let (still, moving) = (p.lambda as f64, p.lambda_moving as f64);
        still + (moving - still) * (speed / p.lambda_speed as f64).min(1.0)
    };
    let at = |x: isize, yy: isize| {
        y[(yy.clamp(0, H as isize - 1) as usize) * W + x.clamp(0, W as isize - 1) as usize]
    };
    let mut next = Vec::with_capacity(W * H);
    let mut out = Vec::with_capacity(W * H);
    for py in 0..H {
        for px in 0..W {
            let i = py * W + px;
            // 3x3 box in YCoCg: min, max, mean.
            let mut lo = [f64::INFINITY; 3];
            let mut hi = [f64::NEG_INFINITY; 3];
            let mut mean = [0.0; 3];
            for dy in -1..=1 {
                for dx in -1..=1 {
                    let c = ycocg(at(px as isize + dx, py as isize + dy));
                    for k in 0..3 {
                        lo[k] = lo[k].min(c[k]);
                        hi[k] = hi[k].max(c[k]);
                        mean[k] += c[k] / 9.0;
                    }
                }
            }
            let (qx, qy) = (px as f64 + 0.5 + motion[0], py as f64 + 0.5 + motion[1]);
            let on = qx >= 0.0 && qx <= W as f64 && qy >= 0.0 && qy <= H as f64;
            let mut m = match state {
                Some(s) if on => {
                    let mut m = blend(s, qx, qy);
                    // Feature (sec. 5.1, our reading): alpha = clamp(phi / (l + range)).
                    let yz = 0.25 * m.z[0] + 0.5 * m.z[1] + 0.25 * m.z[2];
                    let l = (lo[0] - yz).max(yz - hi[0]).max(0.0);
                    let v = motion[0].hypot(motion[1]);
                    let phi = p.feature_a as f64 * l * l + p.feature_b as f64 * v * l * l * l;
                    let a = (phi / (l + hi[0] - lo[0] + 1e-6)).clamp(p.feature_alpha_min as f64, 1.0);
                    let low = rgb(mean);
                    for k in 0..3 {
                        m.z[k] += a * (low[k] - m.z[k]);
                    }
                    m
                }
                _ => reset(y[i], y[i], p0),
            };
            let x = [1.0, m.z[0], m.z[1], m.z[2]];
            // Predict; outside the box -> first point of the ray toward y inside it; reset.
            let f = ycocg(predict(&m, &x));
            let target = ycocg(y[i]);
            // The box grown by the clip's guard on each side (part of its definition).
            let mag = (0..3).map(|k| lo[k].abs().max(hi[k].abs())).fold(0.0, f64::max);
            let g = CLIP_EPS as f64 + CLIP_REL as f64 * mag;
            let (lo, hi) = (lo.map(|v| v - g), hi.map(|v| v + g));
            let inside = (0..3).all(|k| f[k] >= lo[k] && f[k] <= hi[k]);
            if !inside {
                let mut s: f64 = 0.0;
                for k in 0..3 {
                    let bound = if f[k] < lo[k] {
                        lo[k]
                    } else if f[k] > hi[k] {
                        hi[k]
                    } else {
                        continue;
                    };
                    s = s.max((bound - f[k]) / (target[k] - f[k]));
                }
                let clipped = [0, 1, 2].map(|k| f[k] + s * (target[k] - f[k]));
                m = reset(rgb(clipped), m.z, clip_p);
            }
            // RLS in information form with the prior I / p0.
            let r = invert(&m.p);
            let mut a = [[0.0; 4]; 4];
            for ii in 0..4 {
                for jj in 0..4 {
                    a[ii][jj] =
                        lambda * r[ii][jj] + x[ii] * x[jj] + if ii == jj { (1.0 - lambda) / p0 } else { 0.0 };
                }
            }
            let e: Vec<f64> = {
                let f = predict(&m, &x);
                (0..3).map(|k| y[i][k] - f[k]).collect()
            };
            m.p = invert(&a);
            for c in 0..3 {
                for j in 0..4 {
                    let g: f64 = (0..4).map(|k| m.p[j][k] * x[k]).sum();
                    m.beta[c][j] += g * e[c];
                }
            }
            out.push(predict(&m, &x).map(|v| v.max(0.0)));
            next.push(m);
        }
    }
    *state = Some(next);
    out
}

/// Runs both for `frames` frames; returns the max |f32 - f64| over all outputs, the number
/// of pixel-frames where it exceeded 1e-3, and the max over the last frame.
fn compare(frames: u64) -> (f64, u64, f64) {
    // The defaults, with the fetch, the clip and the input this reference states: bilinear models
    // and a hard reset of P at every failed box test, however far out (the Catmull-Rom
    // fetch of beta, `clip_keep`, `clip_after`, `fail_keep`, the ramps and `speed_jump`
    // are checked against the scalar reference bit for bit, `phlm::tests`; this test is
    // about f32 against f64). The scene has no depth, so no dilation.
    let params = Params {
        model_fetch: afterimage::filters::phlm::ModelFetch::Bilinear,
        clip_keep: 0.0,
        clip_after: 1.0,
        fail_ramp: 0.0,
        fail_ramp_box: 0.0,
        speed_jump: 0.0,
        // The reference regresses on each pixel's own sample.
        pixel_filter: afterimage::filters::reconstruct::PixelFilter::Box,
        ..Params::default()
    };
    let mut f = Phlm::new(params.clone());
    let mut state = None;
    let mut rng = SplitMix64::new(77);
    let (mut worst, mut over, mut last) = (0.0f64, 0u64, 0.0f64);
    for t in 0..frames {
        let fr = scene(t, &mut rng);
        let out = f.process(&fr).unwrap();
        let c = fr.color();
        let y: Vec<[f64; 3]> = (0..W * H)
            .map(|i| [0, 1, 2].map(|k| c[k].data()[i] as f64))
            .collect();
        let motion = if t == 0 { [0.0, 0.0] } else { [-V[0], -V[1]] };
        let r = reference_frame(&mut state, &y, motion, &params);
        last = 0.0;
        for i in 0..W * H {
            let d = (0..3)
                .map(|k| (out.color[k].data()[i] as f64 - r[i][k]).abs())
                .fold(0.0, f64::max);
            over += (d > 1e-3) as u64;
            last = last.max(d);
        }
        worst = worst.max(last);
    }
    println!(
        "phlm vs f64 reference over {frames} frames of {W}x{H}: max |f32 - f64| = {worst:.3e}, \
         pixel-frames over 1e-3: {over} of {}, max in the last frame {last:.3e}",
        frames * (W * H) as u64
    );
    (worst, over, last)
}

/// 1,000 frames: the f32 filter never deviates from the f64 reference by more than 1e-3
/// (measured 4.7e-6).
#[test]
fn phlm_matches_the_f64_reference_over_1000_frames() {
    let (worst, _, _) = compare(1_000);
    assert!(worst < 1e-3, "{worst}");
}

/// 10,000 frames: the clip test (Algorithm 1 line 16) is a branch; a prediction that lies
/// within rounding of the box surface can take the other branch in f32 than in f64, and a
/// clip resets the model, so that pixel's output differs by up to the clip distance until
/// the models agree again. Such flips are rare (measured: 122 of 3.84 million pixel-frames
/// over 1e-3, at most 0.049; 12 and 0.032 with `lambda_speed = 1`, whose forgetting at
/// this scene's 0.43 px/frame was 0.91 where the default's is now 0.8, a shorter memory
/// that follows each frame's rounding more) and heal (last frame: 2.9e-7); everywhere else
/// f32 stays within 1e-3.
#[test]
#[ignore = "10,000 frames: run in release"]
fn phlm_matches_the_f64_reference_over_10000_frames() {
    let (_, over, last) = compare(10_000);
    assert!(over <= 400, "{over} pixel-frames over 1e-3 (1e-4 of all)");
    assert!(last < 1e-3, "{last}");
}
