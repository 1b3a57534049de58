//! One output frame of the pixel-tracing filter (Shinya 1993, 002): motion paths through
//! the window, the primary flow gathered along each pixel's path (eq. 11, 14-16), missed
//! objects scattered in from the other frames (eq. 13, 16), front-to-back blend (eq. 17).
//!
//! Positions are continuous pixel coordinates: pixel `(x, y)` covers `[x, x+1) x [y, y+1)`,
//! its centre is `(x + 0.5, y + 0.5)`, its sample in frame `l` lies at centre + jitter_l.
//!
//! The fast path of the scalar reference (`reference.rs`, the implementation it replaced):
//! the same steps and the same floating-point operations in the same order, so the output
//! is the reference's to the bit (`tests.rs` checks it), organised for speed:
//! - each pixel's path is traced through the whole window in one go (its position and
//!   velocity stay in registers), bands of rows in parallel; paths are stored band by band
//!   and frame by frame within a band, so the passes that read them stream them;
//! - the maps to l0 are built frame by frame outwards from l0, in parallel within a frame;
//! - the scatter of missed samples (eq. 13) runs its tests in parallel and keeps only the
//!   samples that fail them, which are then added in the reference's order (frame, then
//!   sample), one pass over a list that is empty where motion is coherent;
//! - pixel coordinates come from loop counters, not divisions; positions are converted to
//!   pixels through `i32`; the kernel is a type parameter, not a branch per sample; the
//!   missed flows live in one pool of list nodes and every buffer is kept in a [`Scratch`]
//!   across frames (no allocation per pixel or, in steady state, per frame).

use super::{Kernel, Params, BLEND, PATHS, SEPARATE};
use crate::frame::{Frame, Rgb};
use crate::pipeline::exec::{par_rows, pool, BAND_ROWS};
use crate::pipeline::{Recorder, Skip};
use rayon::prelude::*;
use std::ops::AddAssign;

/// A position, `NAN` when the path left the image (or behind the camera).
pub(super) type Pos = [f32; 2];
pub(super) const LOST: Pos = [f32::NAN, f32::NAN];

/// Fixed-point iterations that invert a frame's motion-to-previous when the frame before it
/// has no `motion_next`: x + m(x) = p. Rigid motion varies slowly between neighbouring
/// pixels, so two or three steps settle; more only help across discontinuities, where no
/// number of steps gives one answer.
pub(super) const INVERSE_ITERATIONS: usize = 3;

/// Samples tested per parallel pass of the scatter (eq. 13) times the pixels of one
/// sample's footprint: bounds the list of samples kept between the test and the sequential
/// add (12 bytes each, so 48 MiB at most, and about none where motion is coherent).
const SCATTER_BUDGET: usize = 1 << 22;

/// What one output frame's tracing saw.
#[derive(Clone, Copy, Debug, Default)]
pub struct TraceCounts {
    /// Pixels whose output blends more than one flow.
    pub several_flows: u64,
    /// Flows dropped because a pixel's list was full.
    pub dropped: u64,
}

impl AddAssign for TraceCounts {
    fn add_assign(&mut self, o: Self) {
        self.several_flows += o.several_flows;
        self.dropped += o.dropped;
    }
}

/// The frames of one window and the output position in it.
pub struct Window<'a> {
    /// The frames, oldest first.
    pub frames: Vec<&'a Frame>,
    /// Position of the output frame (`l0`) in `frames`.
    pub centre: usize,
}

/// The buffers of [`trace`], kept by the filter from one output to the next.
#[derive(Debug, Default)]
pub struct Scratch {
    /// chi(l; k0, l0) of every pixel k0 (see [`path_index`]).
    paths: Vec<Pos>,
    /// chi(l0; k, l) of every pixel k of every frame l, frame by frame.
    maps: Vec<Pos>,
    /// Samples that failed the two-way test, one list per band of a scatter pass.
    failed: Vec<Vec<Failed>>,
    /// The missed flows of every pixel.
    missed: Missed,
}

/// The slices of one frame that the tracing reads.
#[derive(Clone, Copy)]
struct View<'a> {
    mx: &'a [f32],
    my: &'a [f32],
    next: Option<[&'a [f32]; 2]>,
    ids: Option<&'a [u32]>,
    depth: Option<&'a [f32]>,
    rgb: [&'a [f32]; 3],
    jitter: Pos,
}

impl<'a> View<'a> {
    fn of(f: &'a Frame) -> Self {
        let m = f.motion().expect("the filter needs motion");
        View {
            mx: m[0].data(),
            my: m[1].data(),
            next: f.motion_next().map(|m| [m[0].data(), m[1].data()]),
            ids: f.object_id().map(|p| p.data()),
            depth: f.depth().map(|p| p.data()),
            rgb: f.color().each_ref().map(|p| p.data()),
            jitter: f.meta.jitter,
        }
    }

    #[inline(always)]
    fn motion(&self, i: usize) -> Pos {
        [self.mx[i], self.my[i]]
    }

    #[inline(always)]
    fn id(&self, i: usize) -> Option<u32> {
        self.ids.map(|ids| ids[i])
    }

    /// Whether pixel `i` shows the object `id` (always, without object ids).
    #[inline(always)]
    fn shows(&self, i: usize, id: Option<u32>) -> bool {
        match (self.ids, id) {
            (Some(ids), Some(id)) => ids[i] == id,
            _ => true,
        }
    }

    /// The first forward velocity of pixel `i`: its `motion_next`, else minus its motion
    /// (constant velocity).
    #[inline(always)]
    fn first_forward(&self, i: usize) -> Pos {
        match self.next {
            Some([nx, ny]) => [nx[i], ny[i]],
            None => [-self.mx[i], -self.my[i]],
        }
    }
}

#[derive(Clone, Copy)]
struct Grid {
    w: usize,
    h: usize,
    wf: f32,
    hf: f32,
}

impl Grid {
    /// The pixel `(x, y)` holding position `p`, if any. `NAN` fails the tests; in the
    /// image a position is below 2^31, so `as i32` truncates as `as usize` does.
    #[inline(always)]
    fn cell(&self, p: Pos) -> Option<(usize, usize)> {
        if p[0] >= 0.0 && p[1] >= 0.0 && p[0] < self.wf && p[1] < self.hf {
            Some((p[0] as i32 as usize, p[1] as i32 as usize))
        } else {
            None
        }
    }

    /// The index of the pixel holding `p`, if any.
    #[inline(always)]
    fn pixel(&self, p: Pos) -> Option<usize> {
        self.cell(p).map(|(x, y)| y * self.w + x)
    }
}

#[inline(always)]
fn centre(x: usize, y: usize) -> Pos {
    [x as f32 + 0.5, y as f32 + 0.5]
}

#[inline(always)]
fn add(a: Pos, b: Pos) -> Pos {
    [a[0] + b[0], a[1] + b[1]]
}

#[inline(always)]
fn sub(a: Pos, b: Pos) -> Pos {
    [a[0] - b[0], a[1] - b[1]]
}

/// The max norm: the box kernel's own, so `d_th` = its support diameter means "inside it".
#[inline(always)]
fn dist(a: Pos, b: Pos) -> f32 {
    (a[0] - b[0]).abs().max((a[1] - b[1]).abs())
}

/// The filter kernel w of eq. 7-11 as a type, so that the loops over samples are compiled
/// once per kernel with no branch on it.
trait Weight: Copy + Send + Sync {
    /// Weight of an offset `d` for support radius `r` (0 outside).
    fn weight(d: Pos, r: f32) -> f32;

    /// Whether this is [`UnitBox`], which the lane loops handle.
    const UNIT: bool = false;

    /// The pixels whose centres lie within `r` of `p` (see [`footprint`]).
    #[inline(always)]
    fn footprint(g: &Grid, p: Pos, r: f32) -> Option<[usize; 4]> {
        footprint(g, p, r)
    }
}

/// [`Kernel::Box`].
#[derive(Clone, Copy)]
struct BoxKernel;

impl Weight for BoxKernel {
    #[inline(always)]
    fn weight(d: Pos, r: f32) -> f32 {
        if d[0].abs() < r && d[1].abs() < r {
            1.0
        } else {
            0.0
        }
    }
}

/// [`Kernel::Box`] of support 0.5 (one pixel area, Shinya's and the default), in an image
/// under 2^22 pixels a side: its footprint in two conversions instead of four.
#[derive(Clone, Copy)]
struct UnitBox;

/// Below this many pixels a side, `p - 0.5 - 0.5` and `p - 0.5 + 0.5` are exact for every
/// `p` whose footprint can meet the image (the spacing of f32 there is 1/4 at most).
const UNIT_BOX_MAX_SIDE: usize = 1 << 22;

impl Weight for UnitBox {
    const UNIT: bool = true;

    #[inline(always)]
    fn weight(d: Pos, r: f32) -> f32 {
        BoxKernel::weight(d, r)
    }

    /// [`footprint`] for `r` = 0.5: columns `ceil(p - 1)..=floor(p)`, one column unless `p`
    /// is a whole number (the same for rows), clipped to the image. Positions far outside
    /// the image saturate, as there.
    #[inline(always)]
    fn footprint(g: &Grid, p: Pos, _r: f32) -> Option<[usize; 4]> {
        let (fx, fy) = (p[0].floor(), p[1].floor());
        let (x1, y1) = (fx as i32, fy as i32);
        let x0 = x1.saturating_sub((fx == p[0]) as i32).max(0);
        let y0 = y1.saturating_sub((fy == p[1]) as i32).max(0);
        let x1 = x1.min(g.w as i32 - 1);
        let y1 = y1.min(g.h as i32 - 1);
        if x1 < 0 || y1 < 0 || x0 > x1 || y0 > y1 {
            return None;
        }
        Some([x0 as usize, x1 as usize, y0 as usize, y1 as usize])
    }
}

/// [`Kernel::Gaussian`].
#[derive(Clone, Copy)]
struct GaussianKernel;

impl Weight for GaussianKernel {
    #[inline(always)]
    fn weight(d: Pos, r: f32) -> f32 {
        let d2 = d[0] * d[0] + d[1] * d[1];
        if d2 < r * r {
            // sigma = r / 2: the support holds two sigmas each way.
            (-2.0 * d2 / (r * r)).exp()
        } else {
            0.0
        }
    }
}

/// The pixels `x0..=x1, y0..=y1` whose centres lie within `r` (max norm) of `p`, if any.
/// `NAN` gives pixel 0 (where every kernel weighs it 0), as the reference does; positions
/// past 2^31 saturate, which leaves the ranges as empty as `usize` would.
#[inline(always)]
fn footprint(g: &Grid, p: Pos, r: f32) -> Option<[usize; 4]> {
    let x0 = (p[0] - 0.5 - r).ceil().max(0.0) as i32;
    let y0 = (p[1] - 0.5 - r).ceil().max(0.0) as i32;
    let x1 = ((p[0] - 0.5 + r).floor() as i32).min(g.w as i32 - 1);
    let y1 = ((p[1] - 0.5 + r).floor() as i32).min(g.h as i32 - 1);
    if x1 < 0 || y1 < 0 || x0 > x1 || y0 > y1 {
        return None;
    }
    Some([x0 as usize, x1 as usize, y0 as usize, y1 as usize])
}

/// The pixel of a frame nearest `p` that shows object `id`: the one holding `p`, else the
/// nearest of its 8 neighbours that does (a thin object that this pixel's sample missed
/// is often in the next one), else none.
#[inline(always)]
fn find(g: &Grid, f: &View, p: Pos, id: Option<u32>) -> Option<usize> {
    let (x, y) = g.cell(p)?;
    let i = y * g.w + x;
    match (f.ids, id) {
        (Some(ids), Some(id)) if ids[i] != id => search(g, ids, p, id, x, y),
        _ => Some(i),
    }
}

/// The 8 neighbours of `(x, y)` in [`find`]: the nearest that shows `id`, the first of
/// equals in row order.
#[inline(never)]
fn search(g: &Grid, ids: &[u32], p: Pos, id: u32, x: usize, y: usize) -> Option<usize> {
    let mut best: Option<(f32, usize)> = None;
    for ny in y.saturating_sub(1)..=(y + 1).min(g.h - 1) {
        let row = &ids[ny * g.w..(ny + 1) * g.w];
        for nx in x.saturating_sub(1)..=(x + 1).min(g.w - 1) {
            if (nx, ny) == (x, y) || row[nx] != id {
                continue;
            }
            let d = dist(centre(nx, ny), p);
            if best.is_none_or(|(bd, _)| d < bd) {
                best = Some((d, ny * g.w + nx));
            }
        }
    }
    best.map(|(_, j)| j)
}

/// One step of a point of object `id` at position `p` of frame `l` to frame `l + 1`, whose
/// last forward step was `v`: `motion_next` of frame `l` where it shows the object (see
/// [`find`]), else the inverse of frame `l + 1`'s motion where that lands on the object,
/// else `v` again (the object is hidden or missed by the sample there: it keeps its
/// velocity). Returns the new position and velocity.
#[inline(always)]
fn step_forward(g: &Grid, views: &[View], l: usize, p: Pos, v: Pos, id: Option<u32>) -> (Pos, Pos) {
    let Some(i) = g.pixel(p) else { return (LOST, v) };
    let here = &views[l];
    if let Some([nx, ny]) = here.next {
        let v = find(g, here, p, id).map_or(v, |j| [nx[j], ny[j]]);
        return (add(p, v), v);
    }
    let next = &views[l + 1];
    // Solve x + m(x) = p for x, starting from x = p - m(p). An iterate whose pixel is the
    // previous one's repeats itself: the iterations left would change nothing, so they
    // stop there (the reference runs them all, to the same x).
    let mut x = sub(p, next.motion(i));
    let mut from = i;
    let mut at = g.pixel(x);
    let mut landed = false;
    for _ in 0..INVERSE_ITERATIONS {
        let Some(j) = at else { break };
        landed = true;
        if j == from {
            break;
        }
        x = sub(p, next.motion(j));
        from = j;
        at = g.pixel(x);
    }
    match at {
        Some(j) if landed && next.shows(j, id) => (x, sub(x, p)),
        _ => (add(p, v), v),
    }
}

/// One step of a point of object `id` at position `p` of frame `f` to the frame before,
/// whose last backward step was `v`: `f`'s motion where it shows the object (see
/// [`find`]), else `v`.
#[inline(always)]
fn step_back(g: &Grid, f: &View, p: Pos, v: Pos, id: Option<u32>) -> (Pos, Pos) {
    if g.cell(p).is_none() {
        return (LOST, v);
    }
    let v = find(g, f, p, id).map_or(v, |j| f.motion(j));
    (add(p, v), v)
}

/// Where path `l` of pixel `(x, y)` lives in [`Scratch::paths`]: bands of [`BAND_ROWS`]
/// rows, in a band frame after frame, in a frame row after row. A band's pixels are traced
/// together and their paths written there; the scatter and the blend read frame `l` of a
/// band as one run.
#[inline(always)]
fn path_index(n: usize, w: usize, l: usize, x: usize, y: usize) -> usize {
    ((y / BAND_ROWS) * n + l) * (BAND_ROWS * w) + (y % BAND_ROWS) * w + x
}

/// A sample `k` of one frame that failed the two-way test with pixel `k0` (eq. 13) and
/// weighs `w` there.
#[derive(Clone, Copy, Debug)]
struct Failed {
    k0: u32,
    k: u32,
    w: f32,
}

/// One flow of a pixel: weighted colour sum, weight, nearest depth (eq. 16).
#[derive(Clone, Copy, Debug, Default)]
struct Flow {
    /// The object id of its samples (`u32::MAX`: the pixel's own flow).
    key: u32,
    w: f32,
    rgb: [f32; 3],
    z: f32,
}

const NONE: u32 = u32::MAX;

/// The most missed flows a pixel keeps: `max_flows`' own bound.
const MAX_FLOWS: usize = 8;

/// Every pixel's bounded list of missed flows: a linked list per pixel in one pool of
/// nodes, in the order the flows were opened.
#[derive(Debug, Default)]
struct Missed {
    /// First node of each pixel's list, [`NONE`] when empty.
    head: Vec<u32>,
    nodes: Vec<(Flow, u32)>,
}

impl Missed {
    /// Empty lists for `px` pixels.
    fn clear(&mut self, px: usize) {
        self.head.clear();
        self.head.resize(px, NONE);
        self.nodes.clear();
    }

    /// Adds a sample to pixel `k0`'s flow of its object (a new flow when there is room);
    /// false when the list is full and it had to be dropped.
    fn add(&mut self, k0: usize, key: u32, w: f32, rgb: [f32; 3], z: f32, max: usize) -> bool {
        let mut at = self.head[k0];
        let mut last = NONE;
        let mut len = 0;
        while at != NONE {
            if self.nodes[at as usize].0.key == key {
                break;
            }
            last = at;
            at = self.nodes[at as usize].1;
            len += 1;
        }
        if at == NONE {
            if len >= max {
                return false;
            }
            at = self.nodes.len() as u32;
            self.nodes.push((
                Flow {
                    key,
                    z: f32::INFINITY,
                    ..Flow::default()
                },
                NONE,
            ));
            match last {
                NONE => self.head[k0] = at,
                last => self.nodes[last as usize].1 = at,
            }
        }
        let flow = &mut self.nodes[at as usize].0;
        flow.w += w;
        for (a, v) in flow.rgb.iter_mut().zip(rgb) {
            *a += w * v;
        }
        flow.z = flow.z.min(z);
        true
    }
}

/// Filters the centre frame of `win` into `out` (stages timed into `rec`, buffers from
/// `scratch`); returns it and what happened.
pub fn trace(
    win: &Window,
    params: &Params,
    rec: &mut Recorder,
    scratch: &mut Scratch,
    out: Rgb,
) -> (Rgb, TraceCounts) {
    let (w, h) = (win.frames[win.centre].width(), win.frames[win.centre].height());
    match params.kernel {
        Kernel::Box if params.support == 0.5 && w.max(h) < UNIT_BOX_MAX_SIDE => {
            trace_with::<UnitBox>(win, params, rec, scratch, out)
        }
        Kernel::Box => trace_with::<BoxKernel>(win, params, rec, scratch, out),
        Kernel::Gaussian => trace_with::<GaussianKernel>(win, params, rec, scratch, out),
    }
}

fn trace_with<K: Weight>(
    win: &Window,
    params: &Params,
    rec: &mut Recorder,
    scratch: &mut Scratch,
    mut out: Rgb,
) -> (Rgb, TraceCounts) {
    let views: Vec<View> = win.frames.iter().map(|f| View::of(f)).collect();
    let views = &views[..];
    let c = win.centre;
    let (w, h) = (win.frames[c].width(), win.frames[c].height());
    let g = Grid {
        w,
        h,
        wf: w as f32,
        hf: h as f32,
    };
    let n = views.len();
    let px = w * h;
    let stride = BAND_ROWS * w;
    let Scratch {
        paths,
        maps,
        failed,
        missed,
    } = scratch;
    grow(paths, h.div_ceil(BAND_ROWS) * n * stride);
    grow(maps, n * px);

    // Paths chi(l; k0, l0) of every pixel centre of l0 (eq. 12 with motion vectors in place
    // of the transforms, local uniformity as in eq. 10), and maps chi(l0; k, l) of every
    // pixel of every frame to l0, each built from its neighbour towards l0: O(n x pixels).
    // A path keeps to its own object: where a frame's pixel shows another one (the object
    // is hidden there, or too thin for that pixel's sample) it carries on at its velocity.
    rec.run(PATHS, || {
        pool().install(|| {
            trace_paths(&g, views, c, &mut paths[..h.div_ceil(BAND_ROWS) * n * stride]);
            map_to_centre(&g, views, c, &mut maps[..n * px]);
        })
    });
    let paths = &paths[..];
    let maps = &maps[..];

    // Missed objects (eq. 13): samples of other frames that land in a pixel's
    // reconstruction area at l0 but fail the two-way test with its own flow.
    let mut dropped = 0u64;
    let skip = (!params.flow_separation).then_some(Skip::Disabled {
        param: "flow_separation",
    });
    let separate = rec.stage(SEPARATE, skip, || {
        missed.clear(px);
        pool().install(|| scatter_missed::<K>(&g, views, c, params, paths, maps, failed, missed))
    });
    if let Some(d) = separate {
        dropped = d;
    }
    let missed = &*missed;

    // Primary flow of every pixel (eq. 11 normalised, eq. 14-16), then the blend (eq. 17).
    let [or, og, ob] = out.each_mut().map(|p| p.data_mut());
    let mut counts = rec.run(BLEND, || {
        par_rows([or, og, ob], w, |y, [rr, rg, rb]| {
            blend_row::<K>(&g, views, c, params, paths, maps, missed, y, [rr, rg, rb])
        })
    });
    counts.dropped = dropped;
    (out, counts)
}

/// Grows `v` to hold `len` positions at least (never shrinks: the buffer is reused).
fn grow(v: &mut Vec<Pos>, len: usize) {
    if v.len() < len {
        v.resize(len, LOST);
    }
}

/// Every pixel's path through the window: backwards from l0, then forwards, band by band.
fn trace_paths(g: &Grid, views: &[View], c: usize, paths: &mut [Pos]) {
    let n = views.len();
    paths
        .par_chunks_mut(n * BAND_ROWS * g.w)
        .enumerate()
        .for_each(|(b, band)| paths_band(g, views, c, b * BAND_ROWS..((b + 1) * BAND_ROWS).min(g.h), band));
}

/// The paths of the pixels of `rows` (one band) into `band`, frame after frame.
#[inline(never)]
fn paths_band(g: &Grid, views: &[View], c: usize, rows: std::ops::Range<usize>, band: &mut [Pos]) {
    let (w, n) = (g.w, views.len());
    let stride = BAND_ROWS * w;
    let home = &views[c];
    for y in rows {
        let local = (y % BAND_ROWS) * w;
        for x in 0..w {
            let k0 = y * w + x;
            let at = local + x;
            let id = home.id(k0);
            let start = centre(x, y);
            band[c * stride + at] = start;
            let (mut p, mut v) = (start, home.motion(k0));
            for l in (0..c).rev() {
                (p, v) = step_back(g, &views[l + 1], p, v, id);
                band[l * stride + at] = p;
            }
            let (mut p, mut v) = (start, home.first_forward(k0));
            for l in c + 1..n {
                (p, v) = step_forward(g, views, l - 1, p, v, id);
                band[l * stride + at] = p;
            }
        }
    }
}

/// chi(l0; p) through the map of frame m (`mapped`, `None` for l0's own, the identity) at
/// the pixel `(x, y)` holding `p`, plus `p`'s offset from that pixel's centre (local
/// uniformity).
#[inline(always)]
fn through(g: &Grid, mapped: Option<&[Pos]>, p: Pos, x: usize, y: usize) -> Pos {
    let ctr = centre(x, y);
    let base = mapped.map_or(ctr, |m| m[y * g.w + x]);
    add(base, sub(p, ctr))
}

/// Every pixel of frame l to l0: steps towards l0 until a frame shows the object at the
/// position reached, then that frame's map (already built); where no frame does, the steps
/// reach l0 themselves. Frame by frame outwards from l0.
fn map_to_centre(g: &Grid, views: &[View], c: usize, maps: &mut [Pos]) {
    let (w, n) = (g.w, views.len());
    let px = w * g.h;
    for (i, p) in maps[c * px..(c + 1) * px].iter_mut().enumerate() {
        *p = centre(i % w, i / w);
    }
    for l in (0..c).rev() {
        let (done, rest) = maps.split_at_mut((l + 1) * px);
        let rest = &*rest;
        done[l * px..]
            .par_chunks_mut(BAND_ROWS * w)
            .enumerate()
            .for_each(|(b, chunk)| map_band_forward(g, views, c, l, rest, b * BAND_ROWS, chunk));
    }
    for l in c + 1..n {
        let (done, rest) = maps.split_at_mut(l * px);
        let done = &*done;
        rest[..px]
            .par_chunks_mut(BAND_ROWS * w)
            .enumerate()
            .for_each(|(b, chunk)| map_band_back(g, views, c, l, done, b * BAND_ROWS, chunk));
    }
}

/// The maps to l0 of the rows from `y0` of frame `l` < l0 into `chunk`; `nearer` holds the
/// maps of frames l + 1 ..= l0.
#[inline(never)]
fn map_band_forward(
    g: &Grid,
    views: &[View],
    c: usize,
    l: usize,
    nearer: &[Pos],
    y0: usize,
    chunk: &mut [Pos],
) {
    let w = g.w;
    let px = w * g.h;
    let f = &views[l];
    for (r, row) in chunk.chunks_mut(w).enumerate() {
        let y = y0 + r;
        for (x, out) in row.iter_mut().enumerate() {
            let i = y * w + x;
            let id = f.id(i);
            let (mut p, mut v) = step_forward(g, views, l, centre(x, y), f.first_forward(i), id);
            *out = LOST;
            for m in l + 1..=c {
                let Some((qx, qy)) = g.cell(p) else { break };
                if m == c || views[m].shows(qy * w + qx, id) {
                    let mapped = (m != c).then(|| &nearer[(m - l - 1) * px..(m - l) * px]);
                    *out = through(g, mapped, p, qx, qy);
                    break;
                }
                (p, v) = step_forward(g, views, m, p, v, id);
            }
        }
    }
}

/// The maps to l0 of the rows from `y0` of frame `l` > l0 into `chunk`; `nearer` holds the
/// maps of frames 0 .. l.
#[inline(never)]
fn map_band_back(g: &Grid, views: &[View], c: usize, l: usize, nearer: &[Pos], y0: usize, chunk: &mut [Pos]) {
    let w = g.w;
    let px = w * g.h;
    let f = &views[l];
    for (r, row) in chunk.chunks_mut(w).enumerate() {
        let y = y0 + r;
        for (x, out) in row.iter_mut().enumerate() {
            let i = y * w + x;
            let id = f.id(i);
            let (mut p, mut v) = step_back(g, f, centre(x, y), f.motion(i), id);
            *out = LOST;
            for m in (c..l).rev() {
                let Some((qx, qy)) = g.cell(p) else { break };
                if m == c || views[m].shows(qy * w + qx, id) {
                    let mapped = (m != c).then(|| &nearer[m * px..(m + 1) * px]);
                    *out = through(g, mapped, p, qx, qy);
                    break;
                }
                (p, v) = step_back(g, &views[m], p, v, id);
            }
        }
    }
}

/// Eq. 13: every sample of every frame but l0 whose position at l0 falls in a pixel's
/// reconstruction area without passing the two-way test with that pixel's flow (eq. 14-15)
/// is added to the pixel's missed flow of its object. The tests run in parallel, a pass
/// over bands of rows of one frame at a time; the samples that fail are then added in the
/// reference's order, frame by frame and sample by sample. Returns the flows dropped.
#[allow(clippy::too_many_arguments)]
fn scatter_missed<K: Weight>(
    g: &Grid,
    views: &[View],
    c: usize,
    params: &Params,
    paths: &[Pos],
    maps: &[Pos],
    failed: &mut Vec<Vec<Failed>>,
    missed: &mut Missed,
) -> u64 {
    let (w, h, n) = (g.w, g.h, views.len());
    let px = w * h;
    let r = params.support;
    let max = (params.max_flows as usize).min(MAX_FLOWS);
    // Pixels of one footprint at most: the passes stay within the budget even where every
    // sample fails.
    let side = (2.0 * r).ceil() as usize + 1;
    let bands_per_pass = (SCATTER_BUDGET / (side * side * BAND_ROWS * w)).clamp(1, h.div_ceil(BAND_ROWS));
    if failed.len() < bands_per_pass {
        failed.resize_with(bands_per_pass, Vec::new);
    }
    let mut dropped = 0u64;
    for l in (0..n).filter(|&l| l != c) {
        let f = &views[l];
        let map = &maps[l * px..(l + 1) * px];
        for first in (0..h.div_ceil(BAND_ROWS)).step_by(bands_per_pass) {
            let bands = bands_per_pass.min(h.div_ceil(BAND_ROWS) - first);
            failed[..bands].par_iter_mut().enumerate().for_each(|(b, list)| {
                let y0 = (first + b) * BAND_ROWS;
                scatter_band::<K>(g, f, l, n, params, paths, map, y0..(y0 + BAND_ROWS).min(h), list);
            });
            for e in failed[..bands].iter().flatten() {
                let k = e.k as usize;
                let key = f.ids.map_or(0, |ids| ids[k]);
                // Without depth, missed objects (thin, fast: what a pixel's own sample
                // misses) go in front.
                let z = f.depth.map_or(f32::MAX, |d| d[k]);
                let rgb = f.rgb.map(|ch| ch[k]);
                if !missed.add(e.k0 as usize, key, e.w, rgb, z, max) {
                    dropped += 1;
                }
            }
        }
    }
    dropped
}

/// The samples of rows `rows` of frame `l` (map to l0 `map`) that fail the two-way test
/// with a pixel whose reconstruction area they fall in (eq. 13-15), into `list`.
#[allow(clippy::too_many_arguments)]
#[inline(never)]
fn scatter_band<K: Weight>(
    g: &Grid,
    f: &View,
    l: usize,
    n: usize,
    params: &Params,
    paths: &[Pos],
    map: &[Pos],
    rows: std::ops::Range<usize>,
    list: &mut Vec<Failed>,
) {
    let w = g.w;
    let (r, d_th) = (params.support, params.threshold());
    let j = f.jitter;
    list.clear();
    for y in rows {
        let row = &map[y * w..(y + 1) * w];
        for (x, &m) in row.iter().enumerate() {
            // The sample's own position at l0 (its jitter carried along the flow).
            let q = add(m, j);
            if q[0].is_nan() {
                continue;
            }
            let s = add(centre(x, y), j);
            let Some([x0, x1, fy0, fy1]) = K::footprint(g, q, r) else {
                continue;
            };
            for ky in fy0..=fy1 {
                for kx in x0..=x1 {
                    let ck = centre(kx, ky);
                    let wgt = K::weight(sub(ck, q), r);
                    // In k0's own flow when both eq. 14 and eq. 15 hold: counted there.
                    let own = dist(ck, q) < d_th && dist(s, paths[path_index(n, w, l, kx, ky)]) < d_th;
                    if wgt == 0.0 || own {
                        continue;
                    }
                    list.push(Failed {
                        k0: (ky * w + kx) as u32,
                        k: (y * w + x) as u32,
                        w: wgt,
                    });
                }
            }
        }
    }
}

/// What a pixel's primary flow has gathered (eq. 11, 16): the weighted colour and weight
/// of the samples in its flow, and the weight of all samples in its reconstruction area.
#[derive(Clone, Copy, Default)]
struct Gathered {
    sum: [f32; 3],
    sum_w: f32,
    total: f32,
}

/// The samples of frame `f` (map to l0 `map`) around the path position `p` of the pixel
/// whose centre is `home`, gathered into `acc` (eq. 11, 14-15).
#[allow(clippy::too_many_arguments)]
#[inline(always)]
fn gather_frame<K: Weight>(
    g: &Grid,
    f: &View,
    map: &[Pos],
    p: Pos,
    home: Pos,
    params: &Params,
    acc: &mut Gathered,
) {
    let (r, d_th) = (params.support, params.threshold());
    if p[0].is_nan() {
        return;
    }
    // Samples k with w(chi(l; k0, l0) - s_k) != 0.
    let Some([x0, x1, y0, y1]) = K::footprint(g, sub(p, f.jitter), r) else {
        return;
    };
    for ky in y0..=y1 {
        for kx in x0..=x1 {
            let k = ky * g.w + kx;
            let s = add(centre(kx, ky), f.jitter);
            let wgt = K::weight(sub(p, s), r);
            if wgt == 0.0 {
                continue;
            }
            acc.total += wgt;
            // Eq. 14: the sample's own path reaches l0 near k0; eq. 15: it lies near k0's
            // path. Without separation every sample counts.
            let same =
                !params.flow_separation || (dist(home, add(map[k], f.jitter)) < d_th && dist(s, p) < d_th);
            if same {
                for (a, ch) in acc.sum.iter_mut().zip(f.rgb) {
                    *a += wgt * ch[k];
                }
                acc.sum_w += wgt;
            }
        }
    }
}

/// Row `y` of the output: the primary flow gathered along each pixel's path (eq. 11,
/// 14-16) and blended with its missed flows (eq. 17).
#[allow(clippy::too_many_arguments)]
#[inline(never)]
fn blend_row<K: Weight>(
    g: &Grid,
    views: &[View],
    c: usize,
    params: &Params,
    paths: &[Pos],
    maps: &[Pos],
    missed: &Missed,
    y: usize,
    [rr, rg, rb]: [&mut [f32]; 3],
) -> TraceCounts {
    let (w, n) = (g.w, views.len());
    let px = w * g.h;
    let depth_c = views[c].depth;
    let mut counts = TraceCounts::default();
    let mut x = 0;
    while x < w {
        let lanes = if K::UNIT && x + LANES <= w { LANES } else { 1 };
        let mut acc = Lanes::default();
        let mut one = Gathered::default();
        for (l, f) in views.iter().enumerate() {
            let map = &maps[l * px..(l + 1) * px];
            let at = path_index(n, w, l, x, y);
            if lanes == LANES {
                gather_lanes(g, f, map, &paths[at..at + LANES], x, y, params, &mut acc);
            } else {
                gather_frame::<K>(g, f, map, paths[at], centre(x, y), params, &mut one);
            }
        }
        if lanes == 1 {
            acc.set(0, one);
        }
        for i in 0..lanes {
            let a = acc.get(i);
            let k0 = y * w + x + i;
            let own = Flow {
                key: u32::MAX,
                w: a.sum_w,
                rgb: a.sum,
                z: depth_c.map_or(f32::INFINITY, |d| d[k0]),
            };
            let rgb = blend(own, missed, k0, a.total, &mut counts);
            (rr[x + i], rg[x + i], rb[x + i]) = (rgb[0], rgb[1], rgb[2]);
        }
        x += lanes;
    }
    counts
}

/// Pixels handled together by the lane loops: 8 f32, one AVX2 register.
const LANES: usize = 8;

/// 1.5 x 2^23: a whole f32 `v` with |v| <= 2^22 plus this holds `v` in its low bits.
const MAGIC: f32 = 12_582_912.0;

/// The whole number `v` (|v| <= 2^22) as an i32, in operations that vectorise (`as i32`
/// saturates, which does not).
#[inline(always)]
fn whole_to_i32(v: f32) -> i32 {
    ((v + MAGIC).to_bits() as i32).wrapping_sub(MAGIC.to_bits() as i32)
}

/// [`gather_frame`] for the [`UnitBox`] kernel and `LANES` pixels `x..x + LANES` of row `y`
/// at once (their paths at `paths`), in loops the compiler vectorises: the same operations,
/// with a sample outside the image or of weight 0 adding +0 (which leaves sums of
/// non-negative terms as they are) instead of being skipped. A lane whose footprint holds
/// more than one sample (a path at a whole pixel coordinate) takes the scalar code.
#[allow(clippy::too_many_arguments)]
#[inline(always)]
fn gather_lanes(
    g: &Grid,
    f: &View,
    map: &[Pos],
    paths: &[Pos],
    x: usize,
    y: usize,
    params: &Params,
    acc: &mut Lanes,
) {
    let d_th = params.threshold();
    let separate = params.flow_separation;
    let [j0, j1] = f.jitter;
    let (w, h) = (g.w as i32, g.h as i32);
    let (Some(last), Ok(paths)) = (map.len().checked_sub(1), <&[Pos; LANES]>::try_from(paths)) else {
        return;
    };
    let map = &map[..=last];
    let [cr, cg, cb] = f.rgb.map(|ch| &ch[..=last]);
    let mut k = [0usize; LANES];
    let mut wgt = [0.0f32; LANES];
    let mut s = [[0.0f32; LANES]; 2];
    let mut several = [false; LANES];
    let (py, px) = (paths.map(|p| p[1]), paths.map(|p| p[0]));
    for i in 0..LANES {
        let q = [px[i] - j0, py[i] - j1];
        let (fx, fy) = (q[0].floor(), q[1].floor());
        several[i] = (fx == q[0]) | (fy == q[1]);
        let kx = whole_to_i32(fx.max(-1.0).min(g.wf));
        let ky = whole_to_i32(fy.max(-1.0).min(g.hf));
        let inside = (kx >= 0) & (kx < w) & (ky >= 0) & (ky < h) & !several[i];
        s[0][i] = fx + 0.5 + j0;
        s[1][i] = fy + 0.5 + j1;
        let d = [px[i] - s[0][i], py[i] - s[1][i]];
        wgt[i] = if inside & (d[0].abs() < 0.5) & (d[1].abs() < 0.5) {
            1.0
        } else {
            0.0
        };
        k[i] = if inside { (ky * w + kx) as usize } else { 0 };
    }
    let mut m = [[0.0f32; LANES]; 2];
    let mut col = [[0.0f32; LANES]; 3];
    for i in 0..LANES {
        let ki = k[i].min(last);
        [m[0][i], m[1][i]] = map[ki];
        col[0][i] = cr[ki];
        col[1][i] = cg[ki];
        col[2][i] = cb[ki];
    }
    let hy = y as f32 + 0.5;
    for i in 0..LANES {
        let hx = (x + i) as f32 + 0.5;
        let near_home = dist([hx, hy], [m[0][i] + j0, m[1][i] + j1]) < d_th;
        let near_path = dist([s[0][i], s[1][i]], [px[i], py[i]]) < d_th;
        let take = (wgt[i] != 0.0) & (!separate | (near_home & near_path));
        acc.total[i] += wgt[i];
        acc.sum_w[i] += if take { wgt[i] } else { 0.0 };
        for c in 0..3 {
            acc.sum[c][i] += if take { wgt[i] * col[c][i] } else { 0.0 };
        }
    }
    for i in 0..LANES {
        if several[i] {
            let mut one = acc.get(i);
            let home = [(x + i) as f32 + 0.5, y as f32 + 0.5];
            gather_frame::<BoxKernel>(g, f, map, paths[i], home, params, &mut one);
            acc.set(i, one);
        }
    }
}

/// [`Gathered`] of `LANES` pixels, one array per field.
#[derive(Clone, Copy, Default)]
struct Lanes {
    sum: [[f32; LANES]; 3],
    sum_w: [f32; LANES],
    total: [f32; LANES],
}

impl Lanes {
    fn get(&self, i: usize) -> Gathered {
        Gathered {
            sum: [self.sum[0][i], self.sum[1][i], self.sum[2][i]],
            sum_w: self.sum_w[i],
            total: self.total[i],
        }
    }

    fn set(&mut self, i: usize, g: Gathered) {
        for c in 0..3 {
            self.sum[c][i] = g.sum[c];
        }
        self.sum_w[i] = g.sum_w;
        self.total[i] = g.total;
    }
}

/// Eq. 17: the pixel's flows sorted near to far, each with coverage alpha = its weight over
/// the pixel's total (eq. 16), blended front to back. The farthest flow is what lies
/// behind everything else in the pixel, so it takes the coverage left over (Shinya's sum
/// leaves `prod(1 - alpha)` of the pixel empty, which darkens it: the alphas of a pixel
/// need not sum to one over a finite window).
#[inline(always)]
fn blend(own: Flow, missed: &Missed, k0: usize, total: f32, counts: &mut TraceCounts) -> [f32; 3] {
    let mut at = missed.head.get(k0).copied().unwrap_or(NONE);
    if at == NONE {
        // The own flow alone: the loop below with one flow, alpha 1.
        if own.w > 0.0 {
            let a = 1.0f32;
            return own.rgb.map(|v| 0.0 + a * v / own.w);
        }
        return [0.0; 3];
    }
    // The own flow and `max_flows` missed ones, those of weight 0 left out.
    let mut flows = [Flow::default(); 1 + MAX_FLOWS];
    let mut len = 0;
    if own.w > 0.0 {
        flows[0] = own;
        len = 1;
    }
    while at != NONE {
        let (f, next) = missed.nodes[at as usize];
        if f.w > 0.0 {
            flows[len] = f;
            len += 1;
        }
        at = next;
    }
    if len == 0 {
        return [0.0; 3];
    }
    if len > 1 {
        counts.several_flows += 1;
        // Stable insertion sort by depth, as the reference's stable `sort_by`.
        for i in 1..len {
            let mut j = i;
            while j > 0 && flows[j - 1].z.total_cmp(&flows[j].z).is_gt() {
                flows.swap(j - 1, j);
                j -= 1;
            }
        }
    }
    let mut out = [0.0f32; 3];
    let mut left = 1.0f32;
    let last = len - 1;
    for (i, f) in flows[..len].iter().enumerate() {
        let alpha = if i == last {
            1.0
        } else {
            (f.w / total.max(f32::MIN_POSITIVE)).min(1.0)
        };
        let a = left * alpha;
        for (o, v) in out.iter_mut().zip(f.rgb) {
            *o += a * v / f.w;
        }
        left -= a;
        if left <= 0.0 {
            break;
        }
    }
    out
}
