//! Test support shared by the filters' fast-versus-reference tests: adversarial frame
//! sequences at odd sizes, and a comparison of two outputs (colour through the tolerance
//! helper, and the record's stages and counts).

/// What a filter's tests name besides its own module's items (the `Filter` impl that
/// `history_filter!` writes names these in full).
pub mod prelude {
    pub use crate::filters::reconstruct::Reconstruction;
    pub use crate::frame::{Frame, Rgb};
    pub use crate::pipeline::{Filter, FilterError, FilterState, Output, StateError};
    pub use serde_json::Value;
}

use crate::frame::{ChannelKind, Frame, Plane};
use crate::pipeline::params::{build, parse_assignments};
use crate::pipeline::{Filter, FilterKind, Output};
use crate::rng::SplitMix64;
use crate::tolerance::Tolerance;

/// Sizes every fast path is checked at: single pixels, single rows and columns, a size
/// with one full band of rows and a partial one, odd widths.
pub const ODD_SIZES: [(usize, usize); 8] =
    [(1, 1), (1, 7), (7, 1), (2, 2), (3, 3), (5, 9), (17, 11), (33, 19)];

/// A frame of `w x h` with colour, depth and motion built from `rng`: colour in `[0,
/// scale)` with a few fireflies when `scale > 1`, depth in steps with noise, motion of up
/// to `motion` pixels (some of it leaving the image).
pub fn random_frame(rng: &mut SplitMix64, w: usize, h: usize, scale: f64, motion: f64, index: u64) -> Frame {
    let mut plane =
        |f: &mut dyn FnMut(&mut SplitMix64, usize, usize) -> f32| Plane::from_fn(w, h, |x, y| f(rng, x, y));
    let color = [0, 1, 2].map(|_| {
        plane(&mut |r, _, _| {
            let v = r.next_f64() * scale.min(1.0);
            (if scale > 1.0 && r.next_f64() < 0.02 {
                v * scale
            } else {
                v
            }) as f32
        })
    });
    let mut f = Frame::new(color).expect("same size");
    let depth = plane(&mut |r, x, y| (1.0 + ((x / 3 + y / 2) % 4) as f64 + 0.01 * r.next_f64()) as f32);
    f.set_f32(ChannelKind::Depth, vec![depth]).expect("same size");
    let m = [0, 1].map(|_| plane(&mut |r, _, _| ((r.next_f64() * 2.0 - 1.0) * motion) as f32));
    f.set_f32(ChannelKind::Motion, m.to_vec()).expect("same size");
    f.meta.index = index;
    f
}

/// Named sequences of `n` frames of `w x h` that reach every branch of a temporal filter:
/// LDR and HDR frames in turn, smooth pan, random motion (off-screen included), HDR with
/// fireflies, a cut, NaN and negative input, no depth, no motion channel, a still scene.
pub fn sequences(w: usize, h: usize, n: u64, seed: u64) -> Vec<(&'static str, Vec<Frame>)> {
    let mut rng = SplitMix64::new(seed);
    let mut seq = |scale: f64, motion: f64| -> Vec<Frame> {
        (0..n)
            .map(|i| random_frame(&mut rng, w, h, scale, motion, i))
            .collect()
    };
    let pan: Vec<Frame> = (0..n).map(|i| crate::scene::synthetic_frame(w, h, i)).collect();
    let random_motion = seq(1.0, 3.0);
    let hdr = seq(1e4, 0.7);
    let mut cut = seq(1.0, 0.5);
    if let Some(f) = cut.get_mut(n as usize / 2) {
        f.meta.reset = true;
    }
    let mut dirty = seq(2.0, 1.5);
    for (i, f) in dirty.iter_mut().enumerate() {
        let [r, g, b] = f.color_mut();
        let at = (i * 7) % r.len();
        r[at] = f32::NAN;
        g[(at + 1) % g.len()] = -2.0;
        b[(at + 3) % b.len()] = f32::INFINITY;
    }
    let mut no_depth = seq(1.0, 1.0);
    no_depth.iter_mut().for_each(|f| f.remove(ChannelKind::Depth));
    let mut no_motion = seq(1.0, 1.0);
    no_motion.iter_mut().for_each(|f| f.remove(ChannelKind::Motion));
    let still = seq(1.0, 0.0);
    // LDR and HDR frames in turn: the history moves between working spaces every frame.
    let switching: Vec<Frame> = (0..n)
        .map(|i| random_frame(&mut rng, w, h, if i % 2 == 0 { 1.0 } else { 50.0 }, 0.8, i))
        .collect();
    vec![
        ("ldr and hdr in turn", switching),
        ("pan", pan),
        ("random motion", random_motion),
        ("hdr", hdr),
        ("cut", cut),
        ("nan and negative", dirty),
        ("no depth", no_depth),
        ("no motion", no_motion),
        ("still", still),
    ]
}

/// An output's stages as compared: name, whether it ran, why it was left out.
pub fn stages(o: &Output) -> Vec<(&'static str, bool, Option<String>)> {
    o.record
        .stages
        .iter()
        .map(|s| (s.name, s.ms.is_some(), s.skipped.as_ref().map(|k| k.to_string())))
        .collect()
}

/// The ways [`with_gbuffer`] gives a frame its g-buffer: all of it, without albedo,
/// without object ids, and all of it with the far plane set.
pub const GBUFFER_KINDS: [&str; 4] = ["all", "no albedo", "no object id", "near_far"];

/// `f` with the channels `traa`'s improved variant reads beyond the shared sequences':
/// albedo in [0, 1) and object ids in small blocks with some single-pixel objects; then
/// left out again as `kind` (one of [`GBUFFER_KINDS`]) says, or (`near_far`) kept with the
/// far plane set.
pub fn with_gbuffer(f: &Frame, rng: &mut SplitMix64, kind: &str) -> Frame {
    let mut f = f.clone();
    let (w, h) = (f.width(), f.height());
    let albedo = [0, 1, 2].map(|_| Plane::from_fn(w, h, |_, _| rng.next_f64() as f32));
    f.set_f32(ChannelKind::Albedo, albedo.to_vec()).unwrap();
    let ids = Plane::from_fn(w, h, |x, y| {
        ((x / 3 + y / 2) % 3) as u32 + (rng.next_f64() < 0.1) as u32
    });
    f.set_object_id(ids).unwrap();
    match kind {
        "no albedo" => f.remove(ChannelKind::Albedo),
        "no object id" => f.remove(ChannelKind::ObjectId),
        "near_far" => f.meta.near_far = Some([0.5, 3.0]),
        _ => {}
    }
    f
}

/// Panics unless `fast` and `reference` agree: colour within `tol`, the same stages run
/// and left out (with the same reasons), the same pixel and input counts.
pub fn assert_same_output(fast: &Output, reference: &Output, tol: Tolerance, what: &str) {
    for c in 0..3 {
        tol.check_slices(
            &format!("{what}: colour {c}"),
            fast.color[c].data(),
            reference.color[c].data(),
        )
        .unwrap();
    }
    assert_eq!(stages(fast), stages(reference), "{what}: stages");
    assert_eq!(
        fast.record.pixels, reference.record.pixels,
        "{what}: pixel counts"
    );
    assert_eq!(fast.record.input, reference.record.input, "{what}: input counts");
    assert_eq!(
        fast.record.state_bytes, reference.record.state_bytes,
        "{what}: state bytes"
    );
}

/// The kinds of [`sequences`] shaded sparsely with `factor` (one pixel of every `factor x
/// factor` block, in the rotating order of [`Sampling::rotating`]) for filters of sparse
/// input, each with full-resolution normals and object ids (some of them 0, the sky) added,
/// and besides: the synthetic scene's sparse G-buffer, a sequence without normals and ids,
/// one whose frames give their near and far planes, and NaN and negative samples in the
/// sparse colour itself.
pub fn sparse_sequences(
    w: usize,
    h: usize,
    n: u64,
    seed: u64,
    factor: u32,
) -> Vec<(&'static str, Vec<Frame>)> {
    let mut rng = SplitMix64::new(seed ^ 0x5eed);
    let mut seqs: Vec<(&'static str, Vec<Frame>)> = sequences(w, h, n, seed)
        .into_iter()
        .filter(|(name, _)| *name != "pan" && *name != "nan and negative")
        .map(|(name, frames)| {
            let frames = frames
                .into_iter()
                .enumerate()
                .map(|(i, f)| sparse_from(&mut rng, &f, factor, i as u64, true))
                .collect();
            (name, frames)
        })
        .collect();
    let pan = (0..n)
        .map(|i| crate::scene::synthetic_sparse_frame(w, h, i, factor))
        .collect();
    let mut bare: Vec<Frame> = Vec::new();
    let mut planes: Vec<Frame> = Vec::new();
    let mut dirty: Vec<Frame> = Vec::new();
    for i in 0..n {
        let f = random_frame(&mut rng, w, h, 1.0, 1.2, i);
        bare.push(sparse_from(&mut rng, &f, factor, i, false));
        let mut p = sparse_from(&mut rng, &f, factor, i, true);
        p.meta.near_far = Some([0.5, 6.0]);
        planes.push(p);
        let mut d = sparse_from(&mut rng, &f, factor, i, true);
        let [r, g, b] = d.color_mut();
        let at = (i as usize * 5) % r.len();
        r[at] = f32::NAN;
        g[(at + 1) % g.len()] = -2.0;
        b[(at + 2) % b.len()] = f32::INFINITY;
        dirty.push(d);
    }
    seqs.extend([
        ("sparse pan", pan),
        ("no normals or ids", bare),
        ("near and far planes", planes),
        ("nan and negative samples", dirty),
    ]);
    seqs
}

/// `f` shaded sparsely at frame `index`'s pattern of `factor`, with its depth and motion,
/// and random normals and ids in patches when `extra`.
fn sparse_from(rng: &mut SplitMix64, f: &Frame, factor: u32, index: u64, extra: bool) -> Frame {
    let (w, h) = (f.width(), f.height());
    let s = crate::frame::Sampling::rotating(factor, index);
    let color = Frame::gather(f.color(), s).expect("a valid factor");
    let mut out = Frame::subsampled(color, w, h, s).expect("gathered at the pattern's size");
    for k in [ChannelKind::Depth, ChannelKind::Motion] {
        if let Some(p) = f.planes(k) {
            out.set_f32(k, p.to_vec()).expect("same size");
        }
    }
    if extra {
        let tilt: Vec<[f32; 2]> = (0..w * h)
            .map(|_| [rng.next_f64() as f32 - 0.5, rng.next_f64() as f32 - 0.5])
            .collect();
        let normal = [0, 1, 2].map(|c| {
            Plane::from_fn(w, h, |x, y| {
                let patch = ((x / 3 + y / 2) % 3) as f32 * 0.4;
                let t = tilt[y * w + x];
                let v = [patch + 0.2 * t[0], 0.3 * t[1], 1.0];
                let l = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
                v[c] / l
            })
        });
        out.set_f32(ChannelKind::Normal, normal.to_vec())
            .expect("same size");
        out.set_object_id(Plane::from_fn(w, h, |x, y| {
            ((x / 4 + y / 3 + index as usize / 3) % 3) as u32
        }))
        .expect("same size");
    }
    out.meta = f.meta.clone();
    out
}

/// Runs `frames` through a fast filter and its reference (`reference` filters one frame)
/// side by side and panics at the first frame whose outputs differ at all
/// ([`assert_same_output`] with [`Tolerance::EXACT`], and the same model health); `what`
/// names the case.
pub fn assert_filter_matches(
    fast: &mut dyn Filter,
    mut reference: impl FnMut(&Frame) -> Output,
    frames: &[Frame],
    what: &str,
) {
    for (i, f) in frames.iter().enumerate() {
        let a = fast.process(f).unwrap();
        let b = reference(f);
        let what = format!("{what} frame {i}");
        assert_same_output(&a, &b, Tolerance::EXACT, &what);
        assert_eq!(a.record.model, b.record.model, "{what}: model health");
        fast.recycle(a.color);
    }
}

/// The reference of a fused filter `F`: the scalar statement of the same function that the
/// fast one is tested against, one frame at a time.
pub trait Reference<F: FilterKind> {
    /// A fresh reference with the parameters `params`.
    fn with_params(params: F::Params) -> Self;
    /// Filters one frame (panics on an error: tests only).
    fn filter(&mut self, frame: &Frame) -> Output;
}

/// Runs `frames` through the fused filter `F` and its reference `R` with each parameter set
/// of `variants` (`key=value` strings) in turn, as [`assert_filter_matches`] does; `what`
/// names the sequence (the parameter set is added).
pub fn assert_variants_match<F: FilterKind + Filter, R: Reference<F>>(
    variants: &[&[&str]],
    frames: &[Frame],
    what: &str,
) {
    for set in variants {
        let params: F::Params = build(F::NAME, &parse_assignments(set).unwrap()).unwrap();
        let mut slow = R::with_params(params.clone());
        assert_filter_matches(
            &mut F::new(params),
            |f| slow.filter(f),
            frames,
            &format!("{what} {set:?}"),
        );
    }
}
