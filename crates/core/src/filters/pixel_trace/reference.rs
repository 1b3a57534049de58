//! The scalar reference of the pixel-tracing filter (Shinya 1993): the implementation
//! before the fast path of `trace.rs`, kept as it was, one pixel at a time and one
//! operation at a time, for the tests to check the fast path against (`tests.rs`). Same
//! algorithm and the same floating-point operations in the same order: the two agree to
//! the bit.
//!
//! Motion paths through the window, the primary flow gathered along each pixel's path
//! (eq. 11, 14-16), missed objects scattered in from the other frames (eq. 13, 16),
//! front-to-back blend (eq. 17).
//!
//! Positions are continuous pixel coordinates: pixel `(x, y)` covers `[x, x+1) x [y, y+1)`,
//! its centre is `(x + 0.5, y + 0.5)`, its sample in frame `l` lies at centre + jitter_l.

use super::trace::{blend_sorted, Flow, Pos, TraceCounts, Window, INVERSE_ITERATIONS, LOST};
use super::{Kernel, Params, BLEND, PATHS, SEPARATE};
use crate::frame::{Frame, Plane, Rgb};
use crate::pipeline::exec::{par_rows, pool};
use crate::pipeline::{Recorder, Skip};
use rayon::prelude::*;

struct Geometry {
    w: usize,
    h: usize,
}

impl Geometry {
    /// The pixel holding position `p`, if any.
    #[inline]
    fn pixel(&self, p: Pos) -> Option<usize> {
        // `NAN` fails both tests.
        if p[0] >= 0.0 && p[1] >= 0.0 && p[0] < self.w as f32 && p[1] < self.h as f32 {
            Some(p[1] as usize * self.w + p[0] as usize)
        } else {
            None
        }
    }

    #[inline]
    fn centre(&self, i: usize) -> Pos {
        [(i % self.w) as f32 + 0.5, (i / self.w) as f32 + 0.5]
    }
}

/// A motion field (two planes) read at pixel `i`.
#[inline]
fn at(m: &[Plane<f32>; 2], i: usize) -> Pos {
    [m[0].data()[i], m[1].data()[i]]
}

#[inline]
fn add(a: Pos, b: Pos) -> Pos {
    [a[0] + b[0], a[1] + b[1]]
}

#[inline]
fn sub(a: Pos, b: Pos) -> Pos {
    [a[0] - b[0], a[1] - b[1]]
}

/// The max norm: the box kernel's own, so `d_th` = its support diameter means "inside it".
#[inline]
fn dist(a: Pos, b: Pos) -> f32 {
    (a[0] - b[0]).abs().max((a[1] - b[1]).abs())
}

impl Kernel {
    /// Weight of an offset `d` for support radius `r` (0 outside).
    #[inline]
    fn weight(self, d: Pos, r: f32) -> f32 {
        match self {
            Kernel::Box => {
                if d[0].abs() < r && d[1].abs() < r {
                    1.0
                } else {
                    0.0
                }
            }
            Kernel::Gaussian => {
                let d2 = d[0] * d[0] + d[1] * d[1];
                if d2 < r * r {
                    // sigma = r / 2: the support holds two sigmas each way.
                    (-2.0 * d2 / (r * r)).exp()
                } else {
                    0.0
                }
            }
        }
    }
}

/// Whether pixel `i` of `frame` shows the object `id` (always, without object ids).
#[inline]
fn shows(frame: &Frame, i: usize, id: Option<u32>) -> bool {
    match (frame.object_id(), id) {
        (Some(ids), Some(id)) => ids.data()[i] == id,
        _ => true,
    }
}

/// The pixel of `frame` nearest `p` that shows object `id`: the one holding `p`, else the
/// nearest of its 8 neighbours that does (a thin object that this pixel's sample missed
/// is often in the next one), else none.
fn find(g: &Geometry, frame: &Frame, p: Pos, id: Option<u32>) -> Option<usize> {
    let i = g.pixel(p)?;
    if shows(frame, i, id) {
        return Some(i);
    }
    let (x, y) = ((i % g.w) as isize, (i / g.w) as isize);
    let mut best: Option<(f32, usize)> = None;
    for dy in -1..=1isize {
        for dx in -1..=1isize {
            let (nx, ny) = (x + dx, y + dy);
            if (dx, dy) == (0, 0) || nx < 0 || ny < 0 || nx >= g.w as isize || ny >= g.h as isize {
                continue;
            }
            let j = ny as usize * g.w + nx as usize;
            let d = dist(g.centre(j), p);
            if shows(frame, j, id) && best.is_none_or(|(bd, _)| d < bd) {
                best = Some((d, j));
            }
        }
    }
    best.map(|(_, j)| j)
}

#[inline]
fn id_of(frame: &Frame, i: usize) -> Option<u32> {
    frame.object_id().map(|ids| ids.data()[i])
}

/// One step of a point of object `id` at position `p` of frame `l` to frame `l + 1`, whose
/// last forward step was `v`: `motion_next` of frame `l` where it shows the object (see
/// [`find`]), else
/// the inverse of frame `l + 1`'s motion where that lands on the object, else `v` again
/// (the object is hidden or missed by the sample there: it keeps its velocity). Returns
/// the new position and velocity.
fn step_forward(g: &Geometry, frames: &[&Frame], l: usize, p: Pos, v: Pos, id: Option<u32>) -> (Pos, Pos) {
    let Some(i) = g.pixel(p) else { return (LOST, v) };
    if let Some(mn) = frames[l].motion_next() {
        let v = find(g, frames[l], p, id).map_or(v, |j| at(mn, j));
        return (add(p, v), v);
    }
    let next = frames[l + 1];
    let m = next.motion().expect("the filter needs motion");
    // Solve x + m(x) = p for x, starting from x = p - m(p).
    let mut x = sub(p, at(m, i));
    let mut landed = None;
    for _ in 0..INVERSE_ITERATIONS {
        let Some(j) = g.pixel(x) else { break };
        x = sub(p, at(m, j));
        landed = Some(j);
    }
    match landed.and_then(|_| g.pixel(x)) {
        Some(j) if shows(next, j, id) => (x, sub(x, p)),
        _ => (add(p, v), v),
    }
}

/// One step of a point of object `id` at position `p` of frame `l` to frame `l - 1`, whose
/// last backward step was `v`: frame `l`'s motion where it shows the object (see
/// [`find`]), else `v`.
fn step_back(g: &Geometry, frames: &[&Frame], l: usize, p: Pos, v: Pos, id: Option<u32>) -> (Pos, Pos) {
    if g.pixel(p).is_none() {
        return (LOST, v);
    }
    let m = frames[l].motion().expect("the filter needs motion");
    let v = find(g, frames[l], p, id).map_or(v, |j| at(m, j));
    (add(p, v), v)
}

/// The first forward velocity of pixel `i` of frame `l`: its `motion_next`, else minus its
/// motion (constant velocity).
fn first_forward(frame: &Frame, i: usize) -> Pos {
    match frame.motion_next() {
        Some(mn) => at(mn, i),
        None => {
            let m = at(frame.motion().expect("the filter needs motion"), i);
            [-m[0], -m[1]]
        }
    }
}

/// Filters the centre frame of `win` (stages timed into `rec`); returns its colour and
/// what happened. The reference: see the module's documentation.
pub(super) fn trace(win: &Window, params: &Params, rec: &mut Recorder) -> (Rgb, TraceCounts) {
    let frames = &win.frames;
    let c = win.centre;
    let g = Geometry {
        w: frames[c].width(),
        h: frames[c].height(),
    };
    let n = frames.len();
    let px = g.w * g.h;
    let r = params.support;
    let d_th = params.threshold();
    let jitter: Vec<Pos> = frames.iter().map(|f| f.meta.jitter).collect();

    // Paths chi(l; k0, l0) of every pixel centre of l0 (eq. 12 with motion vectors in place
    // of the transforms, local uniformity as in eq. 10), and maps chi(l0; k, l) of every
    // pixel of every frame to l0, each built from its neighbour towards l0: O(n x pixels).
    // A path keeps to its own object: where a frame's pixel shows another one (the object
    // is hidden there, or too thin for that pixel's sample) it carries on at its velocity.
    let mut paths: Vec<Vec<Pos>> = vec![Vec::new(); n];
    let mut to_centre: Vec<Vec<Pos>> = vec![Vec::new(); n];
    let home = frames[c];
    let motion_c = home.motion().expect("the filter needs motion");
    rec.run(PATHS, || {
        pool().install(|| {
            paths[c] = (0..px).map(|i| g.centre(i)).collect();
            to_centre[c] = paths[c].clone();
            // Backwards from l0.
            let mut state: Vec<(Pos, Pos)> = (0..px).map(|i| (g.centre(i), at(motion_c, i))).collect();
            for l in (0..c).rev() {
                state = state
                    .par_iter()
                    .enumerate()
                    .map(|(i, &(p, v))| step_back(&g, frames, l + 1, p, v, id_of(home, i)))
                    .collect();
                paths[l] = state.iter().map(|s| s.0).collect();
            }
            // Forwards from l0.
            let mut state: Vec<(Pos, Pos)> = (0..px).map(|i| (g.centre(i), first_forward(home, i))).collect();
            for l in c + 1..n {
                state = state
                    .par_iter()
                    .enumerate()
                    .map(|(i, &(p, v))| step_forward(&g, frames, l - 1, p, v, id_of(home, i)))
                    .collect();
                paths[l] = state.iter().map(|s| s.0).collect();
            }
            // Every pixel of frame l to l0: steps towards l0 until a frame shows the object at
            // the position reached, then that frame's map (already built); where no frame does,
            // the steps reach l0 themselves.
            for l in (0..c).rev() {
                let f = frames[l];
                let (_, rest) = to_centre.split_at_mut(l + 1);
                let maps = &*rest;
                to_centre[l] = (0..px)
                    .into_par_iter()
                    .map(|i| {
                        let id = id_of(f, i);
                        let (mut y, mut v) =
                            step_forward(&g, frames, l, g.centre(i), first_forward(f, i), id);
                        for m in l + 1..=c {
                            match g.pixel(y) {
                                None => return LOST,
                                Some(j) if m == c || shows(frames[m], j, id) => {
                                    return through(&g, &maps[m - l - 1], y)
                                }
                                Some(_) => (y, v) = step_forward(&g, frames, m, y, v, id),
                            }
                        }
                        LOST
                    })
                    .collect();
            }
            for l in c + 1..n {
                let f = frames[l];
                let m0 = f.motion().expect("the filter needs motion");
                let (maps, _) = to_centre.split_at_mut(l);
                let maps = &*maps;
                let mapped: Vec<Pos> = (0..px)
                    .into_par_iter()
                    .map(|i| {
                        let id = id_of(f, i);
                        let (mut y, mut v) = step_back(&g, frames, l, g.centre(i), at(m0, i), id);
                        for m in (c..l).rev() {
                            match g.pixel(y) {
                                None => return LOST,
                                Some(j) if m == c || shows(frames[m], j, id) => {
                                    return through(&g, &maps[m], y)
                                }
                                Some(_) => (y, v) = step_back(&g, frames, m, y, v, id),
                            }
                        }
                        LOST
                    })
                    .collect();
                to_centre[l] = mapped;
            }
        })
    });

    // Missed objects (eq. 13): samples of other frames that land in a pixel's
    // reconstruction area at l0 but fail the two-way test with its own flow.
    let mut missed: Vec<Flows> = vec![Flows::default(); if params.flow_separation { px } else { 0 }];
    let mut dropped = 0u64;
    let skip = (!params.flow_separation).then_some(Skip::Disabled {
        param: "flow_separation",
    });
    rec.stage(SEPARATE, skip, || {
        for l in (0..n).filter(|&l| l != c) {
            let f = frames[l];
            let [cr, cg, cb] = f.color().each_ref().map(|p| p.data());
            for k in 0..px {
                // The sample's own position at l0 (its jitter carried along the flow).
                let q = add(to_centre[l][k], jitter[l]);
                if q[0].is_nan() {
                    continue;
                }
                let s = add(g.centre(k), jitter[l]);
                let key = f.object_id().map_or(0, |ids| ids.data()[k]);
                // Without depth, missed objects (thin, fast: what a pixel's own sample misses) go in front.
                let z = f.depth().map_or(f32::MAX, |d| d.data()[k]);
                let rgb = [cr[k], cg[k], cb[k]];
                for_footprint(&g, q, r, |k0| {
                    let wgt = params.kernel.weight(sub(g.centre(k0), q), r);
                    // In k0's own flow when both eq. 14 and eq. 15 hold: counted there.
                    let own = dist(g.centre(k0), q) < d_th && dist(s, paths[l][k0]) < d_th;
                    if wgt == 0.0 || own {
                        return;
                    }
                    if !missed[k0].add(key, wgt, rgb, z, params.max_flows as usize) {
                        dropped += 1;
                    }
                });
            }
        }
    });

    // Primary flow of every pixel (eq. 11 normalised, eq. 14-16), then the blend (eq. 17).
    let mut out: Rgb = std::array::from_fn(|_| Plane::new(g.w, g.h));
    let [or, og, ob] = out.each_mut().map(|p| p.data_mut());
    let centre_depth = frames[c].depth();
    let mut counts = rec.run(BLEND, || {
        par_rows([or, og, ob], g.w, |y, [rr, rg, rb]| {
            let mut counts = TraceCounts::default();
            for x in 0..g.w {
                let k0 = y * g.w + x;
                let home = g.centre(k0);
                let (mut sum, mut sum_w, mut total) = ([0.0f32; 3], 0.0f32, 0.0f32);
                for l in 0..n {
                    let p = paths[l][k0];
                    if p[0].is_nan() {
                        continue;
                    }
                    let f = frames[l];
                    let col = f.color();
                    // Samples k with w(chi(l; k0, l0) - s_k) != 0.
                    for_footprint(&g, sub(p, jitter[l]), r, |k| {
                        let s = add(g.centre(k), jitter[l]);
                        let wgt = params.kernel.weight(sub(p, s), r);
                        if wgt == 0.0 {
                            return;
                        }
                        total += wgt;
                        // Eq. 14: the sample's own path reaches l0 near k0; eq. 15: it lies
                        // near k0's path. Without separation every sample counts.
                        let same = !params.flow_separation
                            || (dist(home, add(to_centre[l][k], jitter[l])) < d_th && dist(s, p) < d_th);
                        if same {
                            for (a, ch) in sum.iter_mut().zip(col.iter()) {
                                *a += wgt * ch.data()[k];
                            }
                            sum_w += wgt;
                        }
                    });
                }
                let own = Flow {
                    key: u32::MAX,
                    w: sum_w,
                    rgb: sum,
                    z: centre_depth.map_or(f32::INFINITY, |d| d.data()[k0]),
                };
                let others = missed.get(k0).map_or(&[][..], |f| f.as_slice());
                let rgb = blend(own, others, total, &mut counts);
                rr[x] = rgb[0];
                rg[x] = rgb[1];
                rb[x] = rgb[2];
            }
            counts
        })
    });
    counts.dropped = dropped;
    (out, counts)
}

/// `chi(l0; p)` for a position `p` of a frame whose pixel map to l0 is `mapped`: the map
/// at the pixel holding `p`, plus `p`'s offset from that pixel's centre (local uniformity).
#[inline]
fn through(g: &Geometry, mapped: &[Pos], p: Pos) -> Pos {
    match g.pixel(p) {
        Some(i) => add(mapped[i], sub(p, g.centre(i))),
        None => LOST,
    }
}

/// Calls `f(k)` for every pixel `k` whose centre lies within `r` (max norm) of `p`.
#[inline]
fn for_footprint(g: &Geometry, p: Pos, r: f32, mut f: impl FnMut(usize)) {
    let x0 = (p[0] - 0.5 - r).ceil().max(0.0) as usize;
    let y0 = (p[1] - 0.5 - r).ceil().max(0.0) as usize;
    let x1 = ((p[0] - 0.5 + r).floor() as isize).min(g.w as isize - 1);
    let y1 = ((p[1] - 0.5 + r).floor() as isize).min(g.h as isize - 1);
    if x1 < 0 || y1 < 0 {
        return;
    }
    for y in y0..=y1 as usize {
        for x in x0..=x1 as usize {
            f(y * g.w + x);
        }
    }
}

/// A pixel's bounded list of missed flows.
#[derive(Clone, Debug, Default)]
struct Flows {
    list: Vec<Flow>,
}

impl Flows {
    /// Adds a sample to the flow of its object (a new flow when there is room); false when
    /// the list is full and it had to be dropped.
    fn add(&mut self, key: u32, w: f32, rgb: [f32; 3], z: f32, max: usize) -> bool {
        let flow = match self.list.iter_mut().position(|f| f.key == key) {
            Some(i) => &mut self.list[i],
            None if self.list.len() < max => {
                self.list.push(Flow {
                    key,
                    z: f32::INFINITY,
                    ..Flow::default()
                });
                self.list.last_mut().expect("just pushed")
            }
            None => return false,
        };
        flow.w += w;
        for (a, v) in flow.rgb.iter_mut().zip(rgb) {
            *a += w * v;
        }
        flow.z = flow.z.min(z);
        true
    }

    fn as_slice(&self) -> &[Flow] {
        &self.list
    }
}

/// Eq. 17: the pixel's flows sorted near to far, each with coverage alpha = its weight over
/// the pixel's total (eq. 16), blended front to back. The farthest flow is what lies
/// behind everything else in the pixel, so it takes the coverage left over (Shinya's sum
/// leaves `prod(1 - alpha)` of the pixel empty, which darkens it: the alphas of a pixel
/// need not sum to one over a finite window).
fn blend(own: Flow, others: &[Flow], total: f32, counts: &mut TraceCounts) -> [f32; 3] {
    let mut flows: Vec<Flow> = Vec::with_capacity(1 + others.len());
    flows.push(own);
    flows.extend(others.iter().copied());
    flows.retain(|f| f.w > 0.0);
    if flows.is_empty() {
        return [0.0; 3];
    }
    if flows.len() > 1 {
        counts.several_flows += 1;
    }
    flows.sort_by(|a, b| a.z.total_cmp(&b.z));
    blend_sorted(&flows, total)
}
