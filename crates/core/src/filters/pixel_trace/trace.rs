//! One output frame of the pixel-tracing filter (Shinya 1993): motion paths through
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

use super::lanes::{self, At, Lanes, PathLanes, LANES, LANE_MAX_SIDE};
use super::{Kernel, Params, BLEND, PATHS, SEPARATE};
use crate::frame::{Frame, Rgb};
use crate::pipeline::exec::{par_rows, pool, BAND_ROWS};
use crate::pipeline::{Recorder, Skip};
use rayon::prelude::*;

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

add_assign_fields!(TraceCounts {
    several_flows,
    dropped
});

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
    /// Each pixel's velocity while its path is traced.
    vel: Vec<Pos>,
    /// Back step codes of frames that no longer need them, for frames to come.
    codes: Vec<Vec<u32>>,
}

/// [`FirstSteps`] code of a pixel whose first step leaves the image.
const OUTSIDE: u32 = u32::MAX;
/// Set in a [`FirstSteps`] code when the pixel reached does not show the stepping object.
const HIDDEN: u32 = 1 << 31;
/// Set in a forward [`FirstSteps`] code when the step's velocity is not the pixel's first
/// forward velocity (the inverted motion was taken): it is then position minus centre.
const INVERTED: u32 = 1 << 30;
/// The pixel in a [`FirstSteps`] code.
const PIXEL: u32 = INVERTED - 1;
/// Images of at most this many pixels keep [`FirstSteps`] (their codes hold the pixel).
const FIRST_STEPS_MAX_PIXELS: usize = PIXEL as usize;

/// Every pixel's first step from its frame towards l0 and the pixel it lands on, which
/// depend on the frame and its neighbour only, not on l0: kept while the frame is in the
/// window, so that each output's maps (see [`map_to_centre`]) and paths (see
/// [`paths_band`]) start from them instead of stepping again. Forward for a frame before
/// l0 and for l0 (a step to the next frame, the motion inverted where there is no
/// `motion_next`: the dearest step), back for a frame after l0 and for l0 (its own
/// motion: recomputed, only the pixel reached is kept).
#[derive(Debug, Default)]
pub struct FirstSteps {
    /// Where each pixel's forward step lands.
    fwd_pos: Vec<Pos>,
    /// The pixel there, with [`HIDDEN`] when it does not show the pixel's object and
    /// [`INVERTED`] as said there, or [`OUTSIDE`].
    fwd_code: Vec<u32>,
    /// The pixel the back step lands on, with [`HIDDEN`], or [`OUTSIDE`].
    back_code: Vec<u32>,
    fwd: bool,
    back: bool,
}

impl FirstSteps {
    /// Ready for another frame (buffers kept).
    pub fn clear(&mut self) {
        self.fwd = false;
        self.back = false;
    }
}

/// The slices of one frame that the tracing reads.
#[derive(Clone, Copy)]
pub(super) struct View<'a> {
    pub(super) mx: &'a [f32],
    pub(super) my: &'a [f32],
    pub(super) next: Option<[&'a [f32]; 2]>,
    pub(super) ids: Option<&'a [u32]>,
    pub(super) depth: Option<&'a [f32]>,
    pub(super) rgb: [&'a [f32]; 3],
    pub(super) jitter: Pos,
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
    pub(super) fn motion(&self, i: usize) -> Pos {
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
    pub(super) fn first_forward(&self, i: usize) -> Pos {
        match self.next {
            Some([nx, ny]) => [nx[i], ny[i]],
            None => [-self.mx[i], -self.my[i]],
        }
    }
}

#[derive(Clone, Copy)]
pub(super) struct Grid {
    pub(super) w: usize,
    pub(super) h: usize,
    pub(super) wf: f32,
    pub(super) hf: f32,
    /// Whether the lane kernels apply (sides below [`LANE_MAX_SIDE`]).
    pub(super) lanes: bool,
}

impl Grid {
    /// The pixel `(x, y)` holding position `p`, if any. `NAN` fails the tests; in the
    /// image a position is >= 0, so its floor is its truncation, and below 2^31, so
    /// `as i32` truncates as `as usize` does; below 2^22 [`lanes::whole_to_i32`] does it
    /// without the saturation of `as`.
    #[inline(always)]
    fn cell(&self, p: Pos) -> Option<(usize, usize)> {
        if !((p[0] >= 0.0) & (p[1] >= 0.0) & (p[0] < self.wf) & (p[1] < self.hf)) {
            return None;
        }
        Some(if self.lanes {
            (
                lanes::whole_to_i32(p[0].floor()) as usize,
                lanes::whole_to_i32(p[1].floor()) as usize,
            )
        } else {
            (p[0] as i32 as usize, p[1] as i32 as usize)
        })
    }

    /// Whether paths step [`LANES`] at a time: sides below [`LANE_MAX_SIDE`] and pixel
    /// indices in an `i32`.
    pub(super) fn lane_steps(&self) -> bool {
        self.lanes && self.w * self.h <= i32::MAX as usize
    }

    /// The index of the pixel holding `p`, if any.
    #[inline(always)]
    fn pixel(&self, p: Pos) -> Option<usize> {
        self.cell(p).map(|(x, y)| y * self.w + x)
    }
}

#[inline(always)]
pub(super) fn centre(x: usize, y: usize) -> Pos {
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
pub(super) fn dist(a: Pos, b: Pos) -> f32 {
    (a[0] - b[0]).abs().max((a[1] - b[1]).abs())
}

/// The filter kernel w of eq. 7-11 as a type, so that the loops over samples are compiled
/// once per kernel with no branch on it.
pub(super) trait Weight: Copy + Send + Sync {
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
pub(super) struct BoxKernel;

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

// Below LANE_MAX_SIDE pixels a side, `p - 0.5 - 0.5` and `p - 0.5 + 0.5` are exact for
// every `p` whose footprint can meet the image (the spacing of f32 there is 1/4 at most).

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

/// [`find`] where pixel `p` shows another object than `id`: its nearest neighbour that
/// shows it, if any.
#[inline(never)]
pub(super) fn find_search(g: &Grid, ids: &[u32], p: Pos, id: u32) -> Option<usize> {
    let (x, y) = g.cell(p)?;
    search(g, ids, p, id, x, y)
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
    step_forward_at(g, views, l, p, v, id, i, None)
}

/// [`step_forward`] from `p` in pixel `i`; `shows` whether frame `l` shows `id` there, if
/// known.
#[allow(clippy::too_many_arguments)]
#[inline(always)]
fn step_forward_at(
    g: &Grid,
    views: &[View],
    l: usize,
    p: Pos,
    v: Pos,
    id: Option<u32>,
    i: usize,
    shows: Option<bool>,
) -> (Pos, Pos) {
    let here = &views[l];
    if let Some([nx, ny]) = here.next {
        let v = find_at(g, here, p, id, i, shows).map_or(v, |j| [nx[j], ny[j]]);
        return (add(p, v), v);
    }
    let next = &views[l + 1];
    let (x, at, landed) = invert(g, next, p, i);
    match at {
        Some(j) if landed && next.shows(j, id) => (x, sub(x, p)),
        _ => (add(p, v), v),
    }
}

/// Solves x + m(x) = p for x, `m` frame `next`'s motion, by [`INVERSE_ITERATIONS`]
/// fixed-point steps from x = p - m(i), `i` the pixel of `p`: returns x, its pixel and
/// whether a step ran. An iterate in the previous one's pixel, or equal to the previous
/// one, repeats itself: the steps left would change nothing, so they stop there (the
/// reference runs them all, to the same x).
#[inline(always)]
fn invert(g: &Grid, next: &View, p: Pos, i: usize) -> (Pos, Option<usize>, bool) {
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
        let nx = sub(p, next.motion(j));
        from = j;
        if nx[0].to_bits() == x[0].to_bits() && nx[1].to_bits() == x[1].to_bits() {
            // Still in pixel j: the next step would stop.
            break;
        }
        x = nx;
        at = g.pixel(x);
    }
    (x, at, landed)
}

/// [`find`] for `p` in pixel `i`; `shows` whether `f` shows `id` there, if known.
#[inline(always)]
fn find_at(g: &Grid, f: &View, p: Pos, id: Option<u32>, i: usize, shows: Option<bool>) -> Option<usize> {
    if shows.unwrap_or_else(|| f.shows(i, id)) {
        return Some(i);
    }
    match (f.ids, id) {
        (Some(ids), Some(id)) => find_search(g, ids, p, id),
        _ => Some(i),
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

/// [`step_back`] from `p` in pixel `i`; `shows` whether `f` shows `id` there.
#[inline(always)]
fn step_back_at(g: &Grid, f: &View, p: Pos, v: Pos, id: Option<u32>, i: usize, shows: bool) -> (Pos, Pos) {
    let v = find_at(g, f, p, id, i, Some(shows)).map_or(v, |j| f.motion(j));
    (add(p, v), v)
}

/// Where path `l` of pixel `(x, y)` lives in [`Scratch::paths`]: bands of [`BAND_ROWS`]
/// rows, in a band frame after frame, in a frame row after row. A band's pixels are traced
/// together and their paths written there; the scatter and the blend read frame `l` of a
/// band as one run.
#[inline(always)]
pub(super) fn path_index(n: usize, w: usize, l: usize, x: usize, y: usize) -> usize {
    ((y / BAND_ROWS) * n + l) * (BAND_ROWS * w) + (y % BAND_ROWS) * w + x
}

/// A sample `k` of one frame that failed the two-way test with pixel `k0` (eq. 13) and
/// weighs `w` there.
#[derive(Clone, Copy, Debug)]
pub(super) struct Failed {
    pub(super) k0: u32,
    pub(super) k: u32,
    pub(super) w: f32,
}

/// One flow of a pixel: weighted colour sum, weight, nearest depth (eq. 16).
#[derive(Clone, Copy, Debug, Default)]
pub(super) struct Flow {
    /// The object id of its samples (`u32::MAX`: the pixel's own flow).
    pub(super) key: u32,
    pub(super) w: f32,
    pub(super) rgb: [f32; 3],
    pub(super) z: f32,
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
/// `scratch`, `steps` the first steps of `win`'s frames, kept from earlier outputs);
/// returns it and what happened.
pub fn trace(
    win: &Window,
    params: &Params,
    rec: &mut Recorder,
    scratch: &mut Scratch,
    steps: &mut [FirstSteps],
    out: Rgb,
) -> (Rgb, TraceCounts) {
    let (w, h) = (win.frames[win.centre].width(), win.frames[win.centre].height());
    match params.kernel {
        Kernel::Box if params.support == 0.5 && w.max(h) < LANE_MAX_SIDE => {
            trace_with::<UnitBox>(win, params, rec, scratch, steps, out)
        }
        Kernel::Box => trace_with::<BoxKernel>(win, params, rec, scratch, steps, out),
        Kernel::Gaussian => trace_with::<GaussianKernel>(win, params, rec, scratch, steps, out),
    }
}

fn trace_with<K: Weight>(
    win: &Window,
    params: &Params,
    rec: &mut Recorder,
    scratch: &mut Scratch,
    steps: &mut [FirstSteps],
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
        lanes: w.max(h) < LANE_MAX_SIDE,
    };
    let n = views.len();
    let px = w * h;
    let stride = BAND_ROWS * w;
    let Scratch {
        paths,
        maps,
        failed,
        missed,
        vel,
        codes,
    } = scratch;
    grow(paths, h.div_ceil(BAND_ROWS) * n * stride);
    grow(maps, n * px);
    grow(vel, h.div_ceil(BAND_ROWS) * stride);
    let mut steps = (px <= FIRST_STEPS_MAX_PIXELS && steps.len() == n).then_some(steps);

    // Paths chi(l; k0, l0) of every pixel centre of l0 (eq. 12 with motion vectors in place
    // of the transforms, local uniformity as in eq. 10), and maps chi(l0; k, l) of every
    // pixel of every frame to l0, each built from its neighbour towards l0: O(n x pixels).
    // A path keeps to its own object: where a frame's pixel shows another one (the object
    // is hidden there, or too thin for that pixel's sample) it carries on at its velocity.
    rec.run(PATHS, || {
        pool().install(|| {
            if let Some(steps) = steps.as_deref_mut() {
                first_steps(&g, views, c, steps, codes);
            }
            let steps = steps.as_deref();
            let paths = &mut paths[..h.div_ceil(BAND_ROWS) * n * stride];
            trace_paths(&g, views, c, steps.map(|s| &s[c]), paths, vel);
            map_to_centre(&g, views, c, steps, &mut maps[..n * px]);
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

/// Every pixel's path through the window: backwards from l0, then forwards, band by band
/// (`vel` holds the velocities of a band's pixels); `steps` l0's first steps, if kept.
fn trace_paths(
    g: &Grid,
    views: &[View],
    c: usize,
    steps: Option<&FirstSteps>,
    paths: &mut [Pos],
    vel: &mut [Pos],
) {
    let n = views.len();
    let stride = BAND_ROWS * g.w;
    paths
        .par_chunks_mut(n * stride)
        .zip(vel.par_chunks_mut(stride))
        .enumerate()
        .for_each(|(b, (band, vel))| {
            let rows = b * BAND_ROWS..((b + 1) * BAND_ROWS).min(g.h);
            paths_band(g, views, c, steps, rows, band, vel)
        });
}

/// The paths of the pixels of `rows` (one band) into `band`, frame after frame: each
/// frame's step of every pixel of the band in one loop, the frame's planes at hand and the
/// band's positions and velocities (`vel`) in cache. The first step each way and the pixel
/// it lands on come from l0's first steps (`steps`) where kept.
#[inline(never)]
fn paths_band(
    g: &Grid,
    views: &[View],
    c: usize,
    steps: Option<&FirstSteps>,
    rows: std::ops::Range<usize>,
    band: &mut [Pos],
    vel: &mut [Pos],
) {
    let (w, n) = (g.w, views.len());
    let stride = BAND_ROWS * w;
    let start = rows.start * w;
    let bpx = rows.len() * w;
    let home = &views[c];
    let ids = home.ids.map(|ids| &ids[start..start + bpx]);
    let id = |k: usize| ids.map(|ids| ids[k]);
    let vel = &mut vel[..bpx];
    for (r, row) in band[c * stride..][..bpx].chunks_mut(w).enumerate() {
        for (x, p) in row.iter_mut().enumerate() {
            *p = centre(x, rows.start + r);
        }
    }
    // Backwards from l0: first its own motion (its pixel shows its object).
    if c > 0 {
        let (lo, hi) = band.split_at_mut(c * stride);
        let (home_pos, dst) = (&hi[..bpx], &mut lo[(c - 1) * stride..][..bpx]);
        for (k, ((d, v), &p)) in dst.iter_mut().zip(vel.iter_mut()).zip(home_pos).enumerate() {
            *v = home.motion(start + k);
            *d = add(p, *v);
        }
    }
    let lanes = g.lane_steps();
    for l in (0..c.saturating_sub(1)).rev() {
        let f = &views[l + 1];
        let (lo, hi) = band.split_at_mut((l + 1) * stride);
        let (src, dst) = (&hi[..bpx], &mut lo[l * stride..][..bpx]);
        match steps.filter(|s| s.back && l + 2 == c) {
            // From frame l0 - 1, where l0's back steps say which pixel holds each path.
            Some(st) => {
                let code = &st.back_code[start..start + bpx];
                let one = |k: usize, p: Pos, v: Pos| match code[k] {
                    OUTSIDE => (LOST, v),
                    code => step_back_at(g, f, p, v, id(k), (code & PIXEL) as usize, code & HIDDEN == 0),
                };
                band_steps(lanes, ids, src, dst, vel, one, |k, step| {
                    let code = code[k..k + LANES].try_into().expect("LANES codes");
                    let at = At::of_codes(code, OUTSIDE, PIXEL, HIDDEN);
                    let pixel = at.pixel;
                    step.back(f, &at, |i, p, v| {
                        step_back_at(g, f, p, v, id(k + i), pixel[i], false)
                    });
                });
            }
            None => {
                let one = |k: usize, p: Pos, v: Pos| step_back(g, f, p, v, id(k));
                band_steps(lanes, ids, src, dst, vel, one, |k, step| {
                    let at = At::of(g, step.p);
                    step.back(f, &at, |i, p, v| one(k + i, p, v));
                });
            }
        }
    }
    // Forwards from l0.
    if c + 1 < n {
        let (lo, hi) = band.split_at_mut((c + 1) * stride);
        let (home_pos, dst) = (&lo[c * stride..][..bpx], &mut hi[..bpx]);
        match steps.filter(|s| s.fwd) {
            Some(st) => {
                let (pos, code) = (&st.fwd_pos[start..start + bpx], &st.fwd_code[start..start + bpx]);
                for (k, ((d, v), ((&ctr, &p), &code))) in dst
                    .iter_mut()
                    .zip(vel.iter_mut())
                    .zip(home_pos.iter().zip(pos).zip(code))
                    .enumerate()
                {
                    *d = p;
                    *v = if code != OUTSIDE && code & INVERTED != 0 {
                        sub(p, ctr)
                    } else {
                        home.first_forward(start + k)
                    };
                }
            }
            None => {
                for (k, ((d, v), &p)) in dst.iter_mut().zip(vel.iter_mut()).zip(home_pos).enumerate() {
                    (*d, *v) = step_forward(g, views, c, p, home.first_forward(start + k), id(k));
                }
            }
        }
    }
    for l in c + 2..n {
        let (lo, hi) = band.split_at_mut(l * stride);
        let (src, dst) = (&lo[(l - 1) * stride..][..bpx], &mut hi[..bpx]);
        let (here, next) = (&views[l - 1], &views[l]);
        match steps.filter(|s| s.fwd && l == c + 2) {
            // From frame l0 + 1, where l0's forward steps say which pixel holds each path.
            Some(st) => {
                let code = &st.fwd_code[start..start + bpx];
                let one = |k: usize, p: Pos, v: Pos| match code[k] {
                    OUTSIDE => (LOST, v),
                    code => step_forward_at(
                        g,
                        views,
                        l - 1,
                        p,
                        v,
                        id(k),
                        (code & PIXEL) as usize,
                        Some(code & HIDDEN == 0),
                    ),
                };
                band_steps(lanes, ids, src, dst, vel, one, |k, step| {
                    let code = code[k..k + LANES].try_into().expect("LANES codes");
                    let at = At::of_codes(code, OUTSIDE, PIXEL, HIDDEN);
                    step.forward(g, here, next, &at, |i, p, v| one(k + i, p, v));
                });
            }
            None => {
                let one = |k: usize, p: Pos, v: Pos| step_forward(g, views, l - 1, p, v, id(k));
                band_steps(lanes, ids, src, dst, vel, one, |k, step| {
                    let at = At::of(g, step.p);
                    step.forward(g, here, next, &at, |i, p, v| one(k + i, p, v));
                });
            }
        }
    }
}

/// One step of every path of a band, from `src` into `dst` with velocities `vel`: `lane`
/// on [`LANES`] paths at a time (from pixel `k` of the band) where `lanes`, `one` on each
/// of the rest (pixel, position, velocity; returns the new position and velocity); `ids`
/// the objects of the band's pixels.
#[inline(always)]
fn band_steps(
    lanes: bool,
    ids: Option<&[u32]>,
    src: &[Pos],
    dst: &mut [Pos],
    vel: &mut [Pos],
    one: impl Fn(usize, Pos, Pos) -> (Pos, Pos),
    lane: impl Fn(usize, PathLanes<'_>),
) {
    let mut k0 = 0;
    if lanes {
        for (((k, p), out), v) in src
            .chunks_exact(LANES)
            .enumerate()
            .zip(dst.chunks_exact_mut(LANES))
            .zip(vel.chunks_exact_mut(LANES))
        {
            let k = k * LANES;
            let p = p.try_into().expect("LANES positions");
            let out = out.try_into().expect("LANES positions");
            let v = v.try_into().expect("LANES velocities");
            let id = ids.map(|ids| ids[k..k + LANES].try_into().expect("LANES ids"));
            lane(k, PathLanes { p, v, out, id });
            k0 = k + LANES;
        }
    }
    for (k, ((d, v), &p)) in dst.iter_mut().zip(vel.iter_mut()).zip(src).enumerate().skip(k0) {
        (*d, *v) = one(k, p, *v);
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
/// reach l0 themselves. Frame by frame outwards from l0, from the frames' first steps
/// (`steps`) where kept.
fn map_to_centre(g: &Grid, views: &[View], c: usize, steps: Option<&[FirstSteps]>, maps: &mut [Pos]) {
    let (w, n) = (g.w, views.len());
    let px = w * g.h;
    for (i, p) in maps[c * px..(c + 1) * px].iter_mut().enumerate() {
        *p = centre(i % w, i / w);
    }
    for l in (0..c).rev() {
        let (done, rest) = maps.split_at_mut((l + 1) * px);
        let rest = &*rest;
        let chunks = done[l * px..].par_chunks_mut(BAND_ROWS * w).enumerate();
        match steps.map(|s| &s[l]).filter(|s| s.fwd) {
            Some(st) => chunks.for_each(|(b, chunk)| {
                map_band_forward_cached(g, views, c, l, rest, st, b * BAND_ROWS, chunk)
            }),
            None => {
                chunks.for_each(|(b, chunk)| map_band_forward(g, views, c, l, rest, b * BAND_ROWS, chunk))
            }
        }
    }
    for l in c + 1..n {
        let (done, rest) = maps.split_at_mut(l * px);
        let done = &*done;
        let chunks = rest[..px].par_chunks_mut(BAND_ROWS * w).enumerate();
        match steps.map(|s| &s[l]).filter(|s| s.back) {
            Some(st) => chunks
                .for_each(|(b, chunk)| map_band_back_cached(g, views, c, l, done, st, b * BAND_ROWS, chunk)),
            None => chunks.for_each(|(b, chunk)| map_band_back(g, views, c, l, done, b * BAND_ROWS, chunk)),
        }
    }
}

/// The first steps this output uses that its frames do not have yet: forward for l0 and
/// the frames before it, back for l0 and the frames after it. The frames before l0 no
/// longer need their back steps: their buffers go to `codes`, for frames to come.
fn first_steps(g: &Grid, views: &[View], c: usize, steps: &mut [FirstSteps], codes: &mut Vec<Vec<u32>>) {
    let n = views.len();
    for (l, st) in steps.iter_mut().enumerate() {
        if l < c && st.back {
            st.back = false;
            codes.push(std::mem::take(&mut st.back_code));
        }
        if l <= c && l + 1 < n && !st.fwd {
            first_steps_forward(g, views, l, st);
        }
        if l >= c && l > 0 && !st.back {
            if st.back_code.capacity() == 0 {
                st.back_code = codes.pop().unwrap_or_default();
            }
            first_steps_back(g, views, l, st);
        }
    }
}

/// The [`FirstSteps`] code of a first step that reached `p`, for an object `id` whose
/// frame there is `next`.
#[inline(always)]
fn step_code(g: &Grid, next: &View, p: Pos, id: Option<u32>) -> u32 {
    match g.pixel(p) {
        None => OUTSIDE,
        Some(j) => j as u32 | if next.shows(j, id) { 0 } else { HIDDEN },
    }
}

/// Frame `l`'s forward first steps (to frame `l + 1`).
fn first_steps_forward(g: &Grid, views: &[View], l: usize, st: &mut FirstSteps) {
    let (w, px) = (g.w, g.w * g.h);
    st.fwd_pos.resize(px, LOST);
    st.fwd_code.resize(px, OUTSIDE);
    let chunk = BAND_ROWS * w;
    st.fwd_pos
        .par_chunks_mut(chunk)
        .zip(st.fwd_code.par_chunks_mut(chunk))
        .enumerate()
        .for_each(|(b, (pos, code))| {
            for (r, (pos, code)) in pos.chunks_mut(w).zip(code.chunks_mut(w)).enumerate() {
                let y = b * BAND_ROWS + r;
                let mut x0 = 0;
                if g.lane_steps() {
                    let (f, next) = (&views[l], &views[l + 1]);
                    for (x, (p, k)) in pos
                        .chunks_exact_mut(LANES)
                        .zip(code.chunks_exact_mut(LANES))
                        .enumerate()
                    {
                        let x = x * LANES;
                        let (p, k): (&mut [Pos; LANES], &mut [u32; LANES]) =
                            (p.try_into().expect("LANES"), k.try_into().expect("LANES"));
                        let odd = lanes::first_steps_forward(
                            g,
                            f,
                            next,
                            x,
                            y,
                            [OUTSIDE, HIDDEN, INVERTED],
                            &mut *p,
                            &mut *k,
                        );
                        if lanes::any(&odd) {
                            for i in (0..LANES).filter(|&i| odd[i]) {
                                (p[i], k[i]) = first_step_forward(g, views, l, x + i, y);
                            }
                        }
                        x0 = x + LANES;
                    }
                }
                for (x, (p, k)) in pos.iter_mut().zip(code.iter_mut()).enumerate().skip(x0) {
                    (*p, *k) = first_step_forward(g, views, l, x, y);
                }
            }
        });
    st.fwd = true;
}

/// The forward first step of pixel `(x, y)` of frame `l` (see [`step_forward`], whose
/// operations it repeats): the position reached and its [`FirstSteps`] code. Its own pixel
/// shows its object, so with `motion_next` the step is that; where the inverted motion
/// lands on the object, that pixel is the one the code needs.
#[inline(always)]
fn first_step_forward(g: &Grid, views: &[View], l: usize, x: usize, y: usize) -> (Pos, u32) {
    let i = y * g.w + x;
    let (f, next) = (&views[l], &views[l + 1]);
    let id = f.id(i);
    let p = centre(x, y);
    let v = f.first_forward(i);
    if f.next.is_none() {
        let (x, at, landed) = invert(g, next, p, i);
        if let Some(j) = at {
            if landed && next.shows(j, id) {
                return (x, j as u32 | INVERTED);
            }
        }
    }
    let p = add(p, v);
    (p, step_code(g, next, p, id))
}

/// Frame `l`'s back first steps (to frame `l - 1`).
fn first_steps_back(g: &Grid, views: &[View], l: usize, st: &mut FirstSteps) {
    let (w, px) = (g.w, g.w * g.h);
    let f = &views[l];
    st.back_code.resize(px, OUTSIDE);
    let chunk = BAND_ROWS * w;
    st.back_code
        .par_chunks_mut(chunk)
        .enumerate()
        .for_each(|(b, code)| {
            for (r, code) in code.chunks_mut(w).enumerate() {
                let y = b * BAND_ROWS + r;
                let mut x0 = 0;
                if g.lane_steps() {
                    for (x, k) in code.chunks_exact_mut(LANES).enumerate() {
                        let x = x * LANES;
                        k.copy_from_slice(&lanes::first_steps_back(
                            g,
                            f,
                            &views[l - 1],
                            x,
                            y,
                            [OUTSIDE, HIDDEN],
                        ));
                        x0 = x + LANES;
                    }
                }
                for (x, k) in code.iter_mut().enumerate().skip(x0) {
                    let i = y * w + x;
                    let id = f.id(i);
                    // Its own pixel shows its object: the step is its motion.
                    let p = add(centre(x, y), f.motion(i));
                    *k = step_code(g, &views[l - 1], p, id);
                }
            }
        });
    st.back = true;
}

/// [`map_band_forward`] from frame `l`'s forward first steps `st`: where the first step
/// lands on the object (or on l0) the map is that frame's there, else the scalar steps.
#[allow(clippy::too_many_arguments)]
#[inline(never)]
fn map_band_forward_cached(
    g: &Grid,
    views: &[View],
    c: usize,
    l: usize,
    nearer: &[Pos],
    st: &FirstSteps,
    y0: usize,
    chunk: &mut [Pos],
) {
    let w = g.w;
    let px = w * g.h;
    let next = (l + 1 != c).then(|| &nearer[..px]);
    let start = y0 * w;
    let (pos, code) = (
        &st.fwd_pos[start..start + chunk.len()],
        &st.fwd_code[start..start + chunk.len()],
    );
    let f = &views[l];
    let one = |o: usize, p: Pos, k: u32| {
        if k == OUTSIDE {
            LOST
        } else if next.is_none() || k & HIDDEN == 0 {
            through_cached(next, p, (k & PIXEL) as usize)
        } else {
            // Frame l + 1 (not l0) does not show the object there: steps on.
            let i = start + o;
            let v = if k & INVERTED != 0 {
                sub(p, centre(i % w, i / w))
            } else {
                f.first_forward(i)
            };
            let id = f.id(i);
            let (p, v) = step_forward_at(g, views, l + 1, p, v, id, (k & PIXEL) as usize, Some(false));
            map_forward_on(g, views, c, l, l + 2, nearer, p, v, id)
        }
    };
    let mut o0 = 0;
    if g.lanes {
        for (o, ((out, p), k)) in chunk
            .chunks_exact_mut(LANES)
            .zip(pos.chunks_exact(LANES))
            .zip(code.chunks_exact(LANES))
            .enumerate()
        {
            let o = o * LANES;
            let out: &mut [Pos; LANES] = out.try_into().expect("LANES maps");
            let (p, k) = (
                p.try_into().expect("LANES positions"),
                k.try_into().expect("LANES codes"),
            );
            if lanes::through_lanes(next, p, k, [OUTSIDE, PIXEL, HIDDEN], out).is_none() {
                for i in 0..LANES {
                    out[i] = one(o + i, p[i], k[i]);
                }
            }
            o0 = o + LANES;
        }
    }
    for (o, ((out, &p), &k)) in chunk.iter_mut().zip(pos).zip(code).enumerate().skip(o0) {
        *out = one(o, p, k);
    }
}

/// [`map_band_back`] from frame `l`'s back first steps `st` (see
/// [`map_band_forward_cached`]).
#[allow(clippy::too_many_arguments)]
#[inline(never)]
fn map_band_back_cached(
    g: &Grid,
    views: &[View],
    c: usize,
    l: usize,
    nearer: &[Pos],
    st: &FirstSteps,
    y0: usize,
    chunk: &mut [Pos],
) {
    let w = g.w;
    let px = w * g.h;
    let f = &views[l];
    let next = (l - 1 != c).then(|| &nearer[(l - 1) * px..l * px]);
    for (r, row) in chunk.chunks_mut(w).enumerate() {
        let y = y0 + r;
        let code = &st.back_code[y * w..(y + 1) * w];
        let (mx, my) = (&f.mx[y * w..(y + 1) * w], &f.my[y * w..(y + 1) * w]);
        let one = |x: usize, k: u32, v: Pos| {
            let p = add(centre(x, y), v);
            if k == OUTSIDE {
                LOST
            } else if next.is_none() || k & HIDDEN == 0 {
                through_cached(next, p, (k & PIXEL) as usize)
            } else {
                // Frame l - 1 (not l0) does not show the object there: steps on.
                let id = f.id(y * w + x);
                let (p, v) = step_back_at(g, &views[l - 1], p, v, id, (k & PIXEL) as usize, false);
                map_back_on(g, views, c, l - 1, nearer, p, v, id)
            }
        };
        let mut x0 = 0;
        if g.lanes {
            for (x, (((out, k), vx), vy)) in row
                .chunks_exact_mut(LANES)
                .zip(code.chunks_exact(LANES))
                .zip(mx.chunks_exact(LANES))
                .zip(my.chunks_exact(LANES))
                .enumerate()
            {
                let x = x * LANES;
                let out: &mut [Pos; LANES] = out.try_into().expect("LANES maps");
                let k: &[u32; LANES] = k.try_into().expect("LANES codes");
                let (vx, vy) = (vx.try_into().expect("LANES"), vy.try_into().expect("LANES"));
                let p = lanes::centres_plus(x, y, vx, vy);
                if lanes::through_lanes(next, &p, k, [OUTSIDE, PIXEL, HIDDEN], out).is_none() {
                    for i in 0..LANES {
                        out[i] = one(x + i, k[i], [vx[i], vy[i]]);
                    }
                }
                x0 = x + LANES;
            }
        }
        for (x, (((out, &k), &vx), &vy)) in row.iter_mut().zip(code).zip(mx).zip(my).enumerate().skip(x0) {
            *out = one(x, k, [vx, vy]);
        }
    }
}

/// [`through`] at pixel `j`, which holds `p` (in the image, so its centre is its floor
/// plus a half); `mapped` `None` for l0's own map.
#[inline(always)]
fn through_cached(mapped: Option<&[Pos]>, p: Pos, j: usize) -> Pos {
    let ctr = [p[0].floor() + 0.5, p[1].floor() + 0.5];
    let base = mapped.map_or(ctr, |m| m[j]);
    add(base, sub(p, ctr))
}

/// The map to l0 of pixel `(x, y)` of frame `l` < l0; `nearer` holds the maps of frames
/// l + 1 ..= l0.
fn map_pixel_forward(
    g: &Grid,
    views: &[View],
    c: usize,
    l: usize,
    nearer: &[Pos],
    x: usize,
    y: usize,
) -> Pos {
    let f = &views[l];
    let i = y * g.w + x;
    let id = f.id(i);
    let (p, v) = step_forward(g, views, l, centre(x, y), f.first_forward(i), id);
    map_forward_on(g, views, c, l, l + 1, nearer, p, v, id)
}

/// The map to l0 of a point of object `id` from frame `l` < l0 that reached `p` in frame
/// `m0` with velocity `v`: on through frames `m0 ..= l0` (see [`map_pixel_forward`]).
#[allow(clippy::too_many_arguments)]
fn map_forward_on(
    g: &Grid,
    views: &[View],
    c: usize,
    l: usize,
    m0: usize,
    nearer: &[Pos],
    mut p: Pos,
    mut v: Pos,
    id: Option<u32>,
) -> Pos {
    let (w, px) = (g.w, g.w * g.h);
    for m in m0..=c {
        let Some((qx, qy)) = g.cell(p) else { return LOST };
        if m == c || views[m].shows(qy * w + qx, id) {
            let mapped = (m != c).then(|| &nearer[(m - l - 1) * px..(m - l) * px]);
            return through(g, mapped, p, qx, qy);
        }
        (p, v) = step_forward(g, views, m, p, v, id);
    }
    LOST
}

/// The map to l0 of pixel `(x, y)` of frame `l` > l0; `nearer` holds the maps of frames
/// 0 .. l.
fn map_pixel_back(g: &Grid, views: &[View], c: usize, l: usize, nearer: &[Pos], x: usize, y: usize) -> Pos {
    let f = &views[l];
    let i = y * g.w + x;
    let id = f.id(i);
    let (p, v) = step_back(g, f, centre(x, y), f.motion(i), id);
    map_back_on(g, views, c, l, nearer, p, v, id)
}

/// The map to l0 of a point of object `id` from a frame after l0 that reached `p` in frame
/// `m0 - 1` with velocity `v`: on through frames `m0 - 1` down to l0 (see
/// [`map_pixel_back`]).
#[allow(clippy::too_many_arguments)]
fn map_back_on(
    g: &Grid,
    views: &[View],
    c: usize,
    m0: usize,
    nearer: &[Pos],
    mut p: Pos,
    mut v: Pos,
    id: Option<u32>,
) -> Pos {
    let (w, px) = (g.w, g.w * g.h);
    for m in (c..m0).rev() {
        let Some((qx, qy)) = g.cell(p) else { return LOST };
        if m == c || views[m].shows(qy * w + qx, id) {
            let mapped = (m != c).then(|| &nearer[m * px..(m + 1) * px]);
            return through(g, mapped, p, qx, qy);
        }
        (p, v) = step_back(g, &views[m], p, v, id);
    }
    LOST
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
    for (r, row) in chunk.chunks_mut(w).enumerate() {
        let y = y0 + r;
        for (x, out) in row.iter_mut().enumerate() {
            *out = map_pixel_forward(g, views, c, l, nearer, x, y);
        }
    }
}

/// The maps to l0 of the rows from `y0` of frame `l` > l0 into `chunk`; `nearer` holds the
/// maps of frames 0 .. l.
#[inline(never)]
fn map_band_back(g: &Grid, views: &[View], c: usize, l: usize, nearer: &[Pos], y0: usize, chunk: &mut [Pos]) {
    let w = g.w;
    for (r, row) in chunk.chunks_mut(w).enumerate() {
        let y = y0 + r;
        for (x, out) in row.iter_mut().enumerate() {
            *out = map_pixel_back(g, views, c, l, nearer, x, y);
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
        let sc = Scatter {
            g,
            f,
            l,
            n,
            params,
            paths,
        };
        let map = &maps[l * px..(l + 1) * px];
        for first in (0..h.div_ceil(BAND_ROWS)).step_by(bands_per_pass) {
            let bands = bands_per_pass.min(h.div_ceil(BAND_ROWS) - first);
            failed[..bands].par_iter_mut().enumerate().for_each(|(b, list)| {
                let y0 = (first + b) * BAND_ROWS;
                scatter_band::<K>(&sc, map, y0..(y0 + BAND_ROWS).min(h), list);
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

/// What the scatter test of frame `l`'s samples reads (eq. 13-15): the grid, the frame's
/// view, `l` and the number of frames `n`, the parameters and the paths of every frame.
#[derive(Clone, Copy)]
pub(super) struct Scatter<'a> {
    pub(super) g: &'a Grid,
    pub(super) f: &'a View<'a>,
    pub(super) l: usize,
    pub(super) n: usize,
    pub(super) params: &'a Params,
    pub(super) paths: &'a [Pos],
}

/// The samples of rows `rows` of frame `sc.l` (map to l0 `map`) that fail the two-way test
/// with a pixel whose reconstruction area they fall in (eq. 13-15), into `list`.
#[inline(never)]
fn scatter_band<K: Weight>(sc: &Scatter, map: &[Pos], rows: std::ops::Range<usize>, list: &mut Vec<Failed>) {
    let g = sc.g;
    let w = g.w;
    list.clear();
    let scalar = |x: usize, y: usize, m: Pos, list: &mut Vec<Failed>| scatter_sample::<K>(sc, x, y, m, list);
    for y in rows {
        let row = &map[y * w..(y + 1) * w];
        let mut x0 = 0;
        if K::UNIT && g.lanes {
            for (x, m) in row.chunks_exact(LANES).enumerate() {
                let m = m.try_into().expect("LANES maps");
                let one = |x: usize, m: Pos, list: &mut Vec<Failed>| scalar(x, y, m, list);
                lanes::scatter_lanes(sc, m, x * LANES, y, list, one);
                x0 = (x + 1) * LANES;
            }
        }
        for (x, &m) in row.iter().enumerate().skip(x0) {
            scalar(x, y, m, list);
        }
    }
}

/// The scatter test of sample `(x, y)` of frame `l`, whose map to l0 is `m` (see
/// [`scatter_band`]).
#[inline(always)]
fn scatter_sample<K: Weight>(sc: &Scatter, x: usize, y: usize, m: Pos, list: &mut Vec<Failed>) {
    let Scatter {
        g,
        f,
        l,
        n,
        params,
        paths,
    } = *sc;
    let (r, d_th) = (params.support, params.threshold());
    // The sample's own position at l0 (its jitter carried along the flow).
    let q = add(m, f.jitter);
    if q[0].is_nan() {
        return;
    }
    let s = add(centre(x, y), f.jitter);
    let Some([x0, x1, y0, y1]) = K::footprint(g, q, r) else {
        return;
    };
    for ky in y0..=y1 {
        for kx in x0..=x1 {
            let ck = centre(kx, ky);
            let wgt = K::weight(sub(ck, q), r);
            // In k0's own flow when both eq. 14 and eq. 15 hold: counted there.
            let own = dist(ck, q) < d_th && dist(s, paths[path_index(n, g.w, l, kx, ky)]) < d_th;
            if wgt == 0.0 || own {
                continue;
            }
            list.push(Failed {
                k0: (ky * g.w + kx) as u32,
                k: (y * g.w + x) as u32,
                w: wgt,
            });
        }
    }
}

/// What a pixel's primary flow has gathered (eq. 11, 16): the weighted colour and weight
/// of the samples in its flow, and the weight of all samples in its reconstruction area.
#[derive(Clone, Copy, Default)]
pub(super) struct Gathered {
    pub(super) sum: [f32; 3],
    pub(super) sum_w: f32,
    pub(super) total: f32,
}

/// The samples of frame `f` (map to l0 `map`) around the path position `p` of the pixel
/// whose centre is `home`, gathered into `acc` (eq. 11, 14-15).
#[allow(clippy::too_many_arguments)]
#[inline(always)]
pub(super) fn gather_frame<K: Weight>(
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
        let lanes = if K::UNIT && g.lanes && x + LANES <= w {
            LANES
        } else {
            1
        };
        let mut acc = Lanes::default();
        let mut one = Gathered::default();
        for (l, f) in views.iter().enumerate() {
            let map = &maps[l * px..(l + 1) * px];
            let at = path_index(n, w, l, x, y);
            if lanes == LANES {
                let p = paths[at..at + LANES].try_into().expect("LANES paths");
                lanes::gather_lanes(g, f, map, p, x, y, params, &mut acc);
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
    blend_sorted(&flows[..len], total)
}

/// [`blend`]'s front-to-back sum over `flows` (at least one, of weight above 0, sorted
/// near to far), the last taking the coverage left over.
#[inline(always)]
pub(super) fn blend_sorted(flows: &[Flow], total: f32) -> [f32; 3] {
    let mut out = [0.0f32; 3];
    let mut left = 1.0f32;
    let last = flows.len() - 1;
    for (i, f) in flows.iter().enumerate() {
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
