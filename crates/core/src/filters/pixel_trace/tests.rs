//! The fast path (`trace.rs`) against the scalar reference (`reference.rs`): both run the
//! same sequences through the filter's window, every output compared to the bit, with the
//! window records (flows blended, flows dropped).

use super::{Params, PixelTrace};
use crate::filters::pixel_trace::Kernel;
use crate::frame::{ChannelKind, Frame, Plane, Rgb};
use crate::pipeline::{Filter, FilterKind, Output};
use crate::rng::SplitMix64;
use crate::scene::{Jitter, Scene, Settings};
use crate::tolerance::Tolerance;

/// Which implementation a run uses.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Path {
    /// The fast path.
    Fast,
    /// The fast path without first steps kept across outputs (as for huge images).
    FastUncached,
    /// The scalar reference.
    Reference,
}

fn run(params: &Params, frames: &[Frame], path: Path) -> Vec<Output> {
    let mut f = PixelTrace::new(params.clone());
    f.reference = path == Path::Reference;
    f.first_steps = path != Path::FastUncached;
    let mut out = Vec::new();
    for frame in frames {
        for o in f.push(frame).unwrap() {
            out.push(o);
        }
        // Outputs handed back, as the bench does: the fast path reuses their planes.
        if let Some(o) = out.last() {
            f.recycle(o.color.clone());
        }
    }
    out.extend(f.finish().unwrap());
    out
}

/// Runs both and compares every output; returns the flows the reference blended and
/// dropped over the run (so a case can check that it reached the missed-flow code).
fn same(what: &str, params: &Params, frames: &[Frame]) -> (u64, u64) {
    let slow = run(params, frames, Path::Reference);
    let (mut several, mut dropped) = (0, 0);
    for path in [Path::Fast, Path::FastUncached] {
        let fast = run(params, frames, path);
        let what = format!("{what} ({path:?})");
        let (s, d) = compare(&what, &fast, &slow);
        several += s;
        dropped += d;
    }
    (several, dropped)
}

/// Compares two runs output by output; returns the second's flows blended and dropped.
fn compare(what: &str, fast: &[Output], slow: &[Output]) -> (u64, u64) {
    assert_eq!(fast.len(), slow.len(), "{what}: outputs");
    let (mut several, mut dropped) = (0, 0);
    for (a, b) in fast.iter().zip(slow) {
        let i = b.record.index;
        for c in 0..3 {
            Tolerance::EXACT
                .check_slices(
                    &format!("{what}: frame {i} channel {c}"),
                    a.color[c].data(),
                    b.color[c].data(),
                )
                .unwrap();
        }
        let (wa, wb) = (
            a.record.window.as_ref().unwrap(),
            b.record.window.as_ref().unwrap(),
        );
        assert_eq!(wa, wb, "{what}: frame {i} window record");
        let names = |o: &Output| {
            o.record
                .stages
                .iter()
                .map(|s| (s.name, s.skipped.clone()))
                .collect::<Vec<_>>()
        };
        assert_eq!(names(a), names(b), "{what}: frame {i} stages");
        several += wb.pixels_with_several_flows;
        dropped += wb.flows_dropped;
    }
    (several, dropped)
}

/// How a random sequence moves.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Motion {
    /// A few objects (blocks of ids), each its own uniform sub-pixel motion, some fast.
    Objects,
    /// Independent random vectors per pixel: every path incoherent.
    Noise,
    /// Tens of pixels a frame: paths leave the image within a step or two.
    Leaving,
}

/// Which channels and defects a random sequence has.
#[derive(Clone, Copy, Debug)]
struct Case {
    w: usize,
    h: usize,
    frames: u64,
    motion: Motion,
    depth: bool,
    ids: bool,
    motion_next: bool,
    /// NaN and Inf sprinkled over colour, depth, motion and motion_next.
    non_finite: bool,
    /// Frames that are cuts.
    resets: &'static [u64],
    jitter: bool,
}

impl Case {
    const BASE: Case = Case {
        w: 37,
        h: 21,
        frames: 12,
        motion: Motion::Objects,
        depth: true,
        ids: true,
        motion_next: true,
        non_finite: false,
        resets: &[],
        jitter: true,
    };
}

fn sequence(case: &Case, seed: u64) -> Vec<Frame> {
    let Case { w, h, .. } = *case;
    let mut rng = SplitMix64::new(seed);
    // Objects: vertical stripes of random width, each with a velocity and a depth.
    let objects = 4;
    let bounds: Vec<usize> = (0..objects).map(|o| o * w / objects).collect();
    let velocity: Vec<[f32; 2]> = (0..objects)
        .map(|_| [rng.range(-2.5, 2.5) as f32, rng.range(-1.5, 1.5) as f32])
        .collect();
    let depth_of: Vec<f32> = (0..objects).map(|_| rng.range(1.0, 10.0) as f32).collect();
    (0..case.frames)
        .map(|t| {
            // The object of pixel (x, y) shifts with its row, so objects overlap and cross.
            let object = |x: usize, y: usize| {
                let x = (x + y / 3 + t as usize) % w;
                bounds.iter().rposition(|&b| x >= b).unwrap_or(0)
            };
            let rgb: Rgb = [0, 1, 2].map(|_| Plane::from_fn(w, h, |_, _| rng.range(0.0, 2.0) as f32));
            let mut f = Frame::new(rgb).unwrap();
            f.meta.index = t;
            f.meta.reset = case.resets.contains(&t);
            if case.jitter {
                f.meta.jitter = [rng.range(-0.5, 0.5) as f32, rng.range(-0.5, 0.5) as f32];
            }
            let mut field = |sign: f32| -> [Plane<f32>; 2] {
                let mut m = [Plane::new(w, h), Plane::new(w, h)];
                for y in 0..h {
                    for x in 0..w {
                        let v = match case.motion {
                            Motion::Objects => velocity[object(x, y)],
                            Motion::Noise => [rng.range(-3.0, 3.0) as f32, rng.range(-3.0, 3.0) as f32],
                            Motion::Leaving => [rng.range(-40.0, 40.0) as f32, rng.range(-40.0, 40.0) as f32],
                        };
                        m[0].set(x, y, sign * v[0]);
                        m[1].set(x, y, sign * v[1]);
                    }
                }
                m
            };
            let motion = field(-1.0);
            let next = field(1.0);
            f.set_f32(ChannelKind::Motion, motion.to_vec()).unwrap();
            if case.motion_next {
                f.set_f32(ChannelKind::MotionNext, next.to_vec()).unwrap();
            }
            if case.depth {
                let d = Plane::from_fn(w, h, |x, y| depth_of[object(x, y)] + 0.01 * x as f32);
                f.set_f32(ChannelKind::Depth, vec![d]).unwrap();
            }
            if case.ids {
                f.set_object_id(Plane::from_fn(w, h, |x, y| object(x, y) as u32 + 1))
                    .unwrap();
            }
            if case.non_finite {
                let bad = [f32::NAN, f32::INFINITY, f32::NEG_INFINITY];
                let kinds = [
                    ChannelKind::Color,
                    ChannelKind::Depth,
                    ChannelKind::Motion,
                    ChannelKind::MotionNext,
                ];
                for kind in kinds {
                    let Some(planes) = f.planes(kind).map(|p| p.to_vec()) else {
                        continue;
                    };
                    let planes: Vec<Plane<f32>> = planes
                        .into_iter()
                        .map(|mut p| {
                            for v in p.data_mut() {
                                if rng.next_f64() < 0.05 {
                                    *v = bad[(rng.next_u64() % 3) as usize];
                                }
                            }
                            p
                        })
                        .collect();
                    match kind {
                        ChannelKind::Color => {
                            for (dst, src) in f.color_mut().into_iter().zip(&planes) {
                                dst.copy_from_slice(src.data());
                            }
                        }
                        kind => f.set_f32(kind, planes).unwrap(),
                    }
                }
            }
            f
        })
        .collect()
}

fn params(window: u32) -> Params {
    Params {
        window,
        ..Params::default()
    }
}

#[test]
fn fast_path_matches_the_reference_on_random_sequences() {
    let mut several = 0;
    let mut dropped = 0;
    let b = Case::BASE;
    let cases = [
        ("base", b),
        ("1x1", Case { w: 1, h: 1, ..b }),
        ("1x9", Case { w: 1, h: 9, ..b }),
        ("9x1", Case { w: 9, h: 1, ..b }),
        ("7x5", Case { w: 7, h: 5, ..b }),
        (
            "noise",
            Case {
                motion: Motion::Noise,
                ..b
            },
        ),
        (
            "leaving",
            Case {
                motion: Motion::Leaving,
                ..b
            },
        ),
        ("no depth", Case { depth: false, ..b }),
        ("no ids", Case { ids: false, ..b }),
        (
            "no motion_next",
            Case {
                motion_next: false,
                ..b
            },
        ),
        (
            "no motion_next, noise",
            Case {
                motion_next: false,
                motion: Motion::Noise,
                ..b
            },
        ),
        (
            "bare (colour and motion only)",
            Case {
                depth: false,
                ids: false,
                motion_next: false,
                ..b
            },
        ),
        (
            "non-finite",
            Case {
                non_finite: true,
                ..b
            },
        ),
        (
            "non-finite, no motion_next",
            Case {
                non_finite: true,
                motion_next: false,
                ..b
            },
        ),
        (
            "cuts",
            Case {
                resets: &[3, 4, 9],
                ..b
            },
        ),
        ("no jitter", Case { jitter: false, ..b }),
        (
            "taller than a band",
            Case {
                w: 13,
                h: 29,
                frames: 10,
                ..b
            },
        ),
    ];
    for (seed, (name, case)) in cases.iter().enumerate() {
        let frames = sequence(case, 100 + seed as u64);
        for window in [2, 8, 9] {
            let (s, d) = same(&format!("{name} T={window}"), &params(window), &frames);
            several += s;
            dropped += d;
        }
    }
    // The cases reach the missed flows, their blend and a full list.
    assert!(several > 1000 && dropped > 100, "{several} {dropped}");
}

#[test]
fn fast_path_matches_the_reference_for_every_parameter() {
    let frames = sequence(&Case::BASE, 7);
    let variants: Vec<(&str, Params)> = vec![
        (
            "gaussian r=1",
            Params {
                kernel: Kernel::Gaussian,
                support: 1.0,
                ..params(8)
            },
        ),
        (
            "gaussian r=2.7, d_th 0.5",
            Params {
                kernel: Kernel::Gaussian,
                support: 2.7,
                d_th: 0.5,
                ..params(8)
            },
        ),
        (
            "box r=1.3",
            Params {
                support: 1.3,
                ..params(8)
            },
        ),
        (
            "no flow separation",
            Params {
                flow_separation: false,
                ..params(8)
            },
        ),
        (
            "one missed flow",
            Params {
                max_flows: 1,
                ..params(8)
            },
        ),
        (
            "eight missed flows",
            Params {
                max_flows: 8,
                d_th: 0.25,
                ..params(9)
            },
        ),
        ("T=1", params(1)),
        ("T=32, longer than the sequence", params(32)),
    ];
    for (name, p) in &variants {
        same(name, p, &frames);
    }
}

/// The test scenes, as the integration tests render them (jittered, one sample).
#[test]
fn fast_path_matches_the_reference_on_the_scenes() {
    for name in [
        "moving-sphere",
        "fence",
        "spokes",
        "foliage",
        "camera-cut",
        "thin-line",
    ] {
        let settings = Settings {
            width: 48,
            height: 27,
            frames: 14,
            spp: 1,
            jitter: Jitter::Halton(8),
            noise: false,
            seed: 3,
            shading: 1,
        };
        let scene = Scene::new(name, settings).unwrap();
        let frames: Vec<Frame> = (0..14).map(|t| scene.frame(t)).collect();
        same(name, &params(8), &frames);
    }
}

/// The comparison can fail: a change of 1e-4 to one sample of one frame shows.
#[test]
fn the_comparison_sees_a_small_difference() {
    let frames = sequence(&Case::BASE, 5);
    let slow = run(&params(8), &frames, Path::Reference);
    let mut changed = frames.clone();
    changed[4].color_mut()[1][100] += 1e-4;
    let fast = run(&params(8), &changed, Path::Fast);
    let differs = fast.iter().zip(&slow).any(|(a, b)| {
        (0..3).any(|c| {
            Tolerance::EXACT
                .check_slices("", a.color[c].data(), b.color[c].data())
                .is_err()
        })
    });
    assert!(differs);
}
