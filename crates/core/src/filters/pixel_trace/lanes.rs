//! The fast path's kernels over [`LANES`] pixels at once for the unit box (Shinya's kernel
//! of one pixel area, the default): the scatter test (eq. 13-15) and the gather of eq. 11,
//! each the scalar code of `trace.rs` (and so of the reference) written as loops over
//! fixed-size arrays that the compiler vectorises: positions, tests and selections lane
//! by lane, the reads at computed pixels (gathers) element by element, and the rare cases
//! (a footprint of more than one sample, a sample that fails the two-way test) handed to
//! the scalar code lane by lane, in the order the reference meets them. Every lane
//! computes exactly the reference's floating-point operations; where the reference skips a
//! sample, a lane adds +0 to a sum of non-negative terms, which leaves it as it is.
//!
//! Pixel coordinates come from positions through [`whole_to_i32`], which is exact below
//! 2^22 pixels a side; larger images take the scalar code ([`LANE_MAX_SIDE`]).

use super::trace::{
    centre, dist, gather_frame, path_index, BoxKernel, Failed, Gathered, Grid, Pos, Scatter, View,
    INVERSE_ITERATIONS, LOST,
};
use super::Params;

/// Pixels handled together: 8 f32, one AVX2 register.
pub(super) const LANES: usize = 8;

/// Below this many pixels a side positions convert to pixels with [`whole_to_i32`].
pub(super) const LANE_MAX_SIDE: usize = 1 << 22;

/// One f32 per lane.
type Fl = [f32; LANES];
/// One pixel index per lane.
type Ix = [usize; LANES];
/// One flag per lane.
type Mask = [bool; LANES];

/// Positions of the lanes, x and y apart.
#[derive(Clone, Copy)]
struct Pts {
    x: Fl,
    y: Fl,
}

impl Pts {
    fn of(p: &[Pos; LANES]) -> Self {
        Pts {
            x: p.map(|p| p[0]),
            y: p.map(|p| p[1]),
        }
    }

    fn at(&self, i: usize) -> Pos {
        [self.x[i], self.y[i]]
    }
}

/// 1.5 x 2^23: a whole f32 `v` with |v| <= 2^22 plus this holds `v` in its low bits.
const MAGIC: f32 = 12_582_912.0;

/// The whole number `v` (|v| <= 2^22) as an i32, in operations that vectorise (`as i32`
/// saturates, which does not).
#[inline(always)]
pub(super) fn whole_to_i32(v: f32) -> i32 {
    ((v + MAGIC).to_bits() as i32).wrapping_sub(MAGIC.to_bits() as i32)
}

/// Whether any lane is set.
#[inline(always)]
pub(super) fn any(m: &Mask) -> bool {
    m.iter().fold(false, |a, &b| a | b)
}

/// The first of the lanes' pixels when they are consecutive (what coherent motion gives):
/// then a read of them is one load instead of one per lane.
#[inline(always)]
fn run(j: &Ix) -> Option<usize> {
    let from: Ix = std::array::from_fn(|i| j[i].wrapping_sub(i));
    (from == [j[0]; LANES]).then_some(j[0])
}

/// `a` at each lane's pixel (a pixel index of the image, or 0); `run` is [`run`]`(j)`.
#[inline(always)]
fn gather_run<T: Copy + Default>(a: &[T], j: &Ix, run: Option<usize>) -> [T; LANES] {
    if let Some(run) = run.and_then(|j0| a.get(j0..j0.wrapping_add(LANES))) {
        return run.try_into().expect("LANES values");
    }
    let Some(last) = a.len().checked_sub(1) else {
        return [T::default(); LANES];
    };
    std::array::from_fn(|i| a[j[i].min(last)])
}

/// `a` at each lane's pixel (a pixel index of the image, or 0).
#[inline(always)]
fn gather<T: Copy + Default>(a: &[T], j: &Ix) -> [T; LANES] {
    gather_run(a, j, run(j))
}

/// The column numbers `x..x + LANES` as f32 (exact below [`LANE_MAX_SIDE`]), in
/// operations that vectorise (`usize as f32` does not).
#[inline(always)]
fn columns(x: usize) -> Fl {
    let x = x as f32;
    std::array::from_fn(|i| x + i as f32)
}

/// The scatter test (see `scatter_band`) for the [`UnitBox`](super::trace) kernel of
/// samples `x..x + LANES` of row `y` of frame `l` (their maps to l0 at `map`): the samples
/// that fail the two-way test with the pixel they fall in, in order, into `list`. A lane
/// whose footprint holds more than one pixel takes the scalar code.
#[inline(always)]
pub(super) fn scatter_lanes(
    sc: &Scatter,
    map: &[Pos; LANES],
    x: usize,
    y: usize,
    list: &mut Vec<Failed>,
    scalar: impl Fn(usize, Pos, &mut Vec<Failed>),
) {
    let Scatter {
        g,
        f,
        l,
        n,
        params,
        paths,
    } = *sc;
    let d_th = params.threshold();
    let [j0, j1] = f.jitter;
    let (w, h) = (g.w as i32, g.h as i32);
    let q = Pts {
        x: map.map(|m| m[0] + j0),
        y: map.map(|m| m[1] + j1),
    };
    let mut several = [false; LANES];
    let mut wgt = [0.0f32; LANES];
    let mut ck = [[0.0f32; LANES]; 2];
    let mut at = [0usize; LANES];
    let mut k0 = [0usize; LANES];
    for i in 0..LANES {
        let (fx, fy) = (q.x[i].floor(), q.y[i].floor());
        several[i] = (fx == q.x[i]) | (fy == q.y[i]);
        let kx = whole_to_i32(fx.max(-1.0).min(g.wf));
        let ky = whole_to_i32(fy.max(-1.0).min(g.hf));
        let inside = (kx >= 0) & (kx < w) & (ky >= 0) & (ky < h) & !several[i];
        ck[0][i] = fx + 0.5;
        ck[1][i] = fy + 0.5;
        let d = [ck[0][i] - q.x[i], ck[1][i] - q.y[i]];
        wgt[i] = if inside & (d[0].abs() < 0.5) & (d[1].abs() < 0.5) {
            1.0
        } else {
            0.0
        };
        let (kx, ky) = (kx.max(0) as usize, ky.max(0) as usize);
        at[i] = if inside { path_index(n, g.w, l, kx, ky) } else { 0 };
        k0[i] = if inside { ky * g.w + kx } else { 0 };
    }
    let chi = gather(paths, &at);
    let hy = y as f32 + 0.5;
    let xs = columns(x);
    let mut fail = [false; LANES];
    for i in 0..LANES {
        let s = [xs[i] + 0.5 + j0, hy + j1];
        let c = [ck[0][i], ck[1][i]];
        // In k0's own flow when both eq. 14 and eq. 15 hold: counted there.
        let own = (dist(c, q.at(i)) < d_th) & (dist(s, chi[i]) < d_th);
        fail[i] = (wgt[i] != 0.0) & !own;
    }
    if !(any(&fail) | any(&several)) {
        return;
    }
    for i in 0..LANES {
        if several[i] {
            scalar(x + i, map[i], list);
        } else if fail[i] {
            list.push(Failed {
                k0: k0[i] as u32,
                k: (y * g.w + x + i) as u32,
                w: wgt[i],
            });
        }
    }
}

/// `gather_frame` for the [`UnitBox`](super::trace) kernel and pixels `x..x + LANES` of
/// row `y` (their paths at `paths`) into `acc`. A lane whose footprint holds more than one
/// sample (a path at a whole pixel coordinate) takes the scalar code.
#[allow(clippy::too_many_arguments)]
#[inline(always)]
pub(super) fn gather_lanes(
    g: &Grid,
    f: &View,
    map: &[Pos],
    paths: &[Pos; LANES],
    x: usize,
    y: usize,
    params: &Params,
    acc: &mut Lanes,
) {
    let d_th = params.threshold();
    let separate = params.flow_separation;
    let [j0, j1] = f.jitter;
    let (w, h) = (g.w as i32, g.h as i32);
    let mut k = [0usize; LANES];
    let mut wgt = [0.0f32; LANES];
    let mut s = [[0.0f32; LANES]; 2];
    let mut several = [false; LANES];
    let p = Pts::of(paths);
    for i in 0..LANES {
        let q = [p.x[i] - j0, p.y[i] - j1];
        let (fx, fy) = (q[0].floor(), q[1].floor());
        several[i] = (fx == q[0]) | (fy == q[1]);
        let kx = whole_to_i32(fx.max(-1.0).min(g.wf));
        let ky = whole_to_i32(fy.max(-1.0).min(g.hf));
        let inside = (kx >= 0) & (kx < w) & (ky >= 0) & (ky < h) & !several[i];
        s[0][i] = fx + 0.5 + j0;
        s[1][i] = fy + 0.5 + j1;
        let d = [p.x[i] - s[0][i], p.y[i] - s[1][i]];
        wgt[i] = if inside & (d[0].abs() < 0.5) & (d[1].abs() < 0.5) {
            1.0
        } else {
            0.0
        };
        k[i] = if inside { (ky * w + kx) as usize } else { 0 };
    }
    let kr = run(&k);
    let m = gather_run(map, &k, kr);
    let col = f.rgb.map(|ch| gather_run(ch, &k, kr));
    let hy = y as f32 + 0.5;
    let xs = columns(x);
    for i in 0..LANES {
        let hx = xs[i] + 0.5;
        let near_home = dist([hx, hy], [m[i][0] + j0, m[i][1] + j1]) < d_th;
        let near_path = dist([s[0][i], s[1][i]], p.at(i)) < d_th;
        let take = (wgt[i] != 0.0) & (!separate | (near_home & near_path));
        acc.total[i] += wgt[i];
        acc.sum_w[i] += if take { wgt[i] } else { 0.0 };
        for c in 0..3 {
            acc.sum[c][i] += if take { wgt[i] * col[c][i] } else { 0.0 };
        }
    }
    if any(&several) {
        for i in 0..LANES {
            if several[i] {
                let mut one = acc.get(i);
                let home = centre(x + i, y);
                gather_frame::<BoxKernel>(g, f, map, paths[i], home, params, &mut one);
                acc.set(i, one);
            }
        }
    }
}

/// The pixel index holding each lane's position and whether it lies in the image, as
/// `Grid::pixel` (0 where it does not). Positions in the image convert exactly below
/// [`LANE_MAX_SIDE`]; the index needs the image under 2^31 pixels ([`Grid::lane_steps`]).
#[inline(always)]
fn pixel_lanes(g: &Grid, p: &Pts) -> (Ix, Mask) {
    let (w, wf, hf) = (g.w as i32, g.wf, g.hf);
    let mut j = [0usize; LANES];
    let mut inside = [false; LANES];
    for i in 0..LANES {
        let (x, y) = (p.x[i], p.y[i]);
        inside[i] = (x >= 0.0) & (y >= 0.0) & (x < wf) & (y < hf);
        let kx = whole_to_i32(x.max(0.0).min(wf).floor());
        let ky = whole_to_i32(y.max(0.0).min(hf).floor());
        j[i] = if inside[i] {
            (ky * w + kx) as u32 as usize
        } else {
            0
        };
    }
    (j, inside)
}

/// Whether frame `f` shows each lane's object (`id`) at its pixel `j` (`run` as for
/// [`gather_run`]), as `View::shows`.
#[inline(always)]
fn shows_lanes(f: &View, j: &Ix, run: Option<usize>, id: Option<&[u32; LANES]>) -> Mask {
    match (f.ids, id) {
        (Some(ids), Some(id)) => {
            let at = gather_run(ids, j, run);
            std::array::from_fn(|i| at[i] == id[i])
        }
        _ => [true; LANES],
    }
}

/// Where [`PathLanes`] steps: the pixel holding each lane's position and whether there is
/// one (else the path is lost), and whether the stepping frame shows the lane's object
/// there, if known.
pub(super) struct At {
    pub(super) pixel: Ix,
    pub(super) valid: Mask,
    pub(super) shows: Option<Mask>,
}

impl At {
    /// From the positions.
    #[inline(always)]
    pub(super) fn of(g: &Grid, p: &[Pos; LANES]) -> Self {
        let (pixel, valid) = pixel_lanes(g, &Pts::of(p));
        At {
            pixel,
            valid,
            shows: None,
        }
    }

    /// From first-step codes (`trace.rs`): `outside` for none, the pixel in `pixel_bits`,
    /// `hidden` set where the frame does not show the object.
    #[inline(always)]
    pub(super) fn of_codes(code: &[u32; LANES], outside: u32, pixel_bits: u32, hidden: u32) -> Self {
        let valid = code.map(|k| k != outside);
        At {
            pixel: std::array::from_fn(|i| {
                if valid[i] {
                    (code[i] & pixel_bits) as usize
                } else {
                    0
                }
            }),
            valid,
            shows: Some(code.map(|k| k & hidden == 0)),
        }
    }
}

/// One step of `LANES` paths (positions `p`, velocities `v`, objects `id`) into `out` and
/// `v`: `trace.rs`'s `step_back_at` and `step_forward_at` lane by lane, the same
/// operations. A lane whose frame does not show its object where it is (a search of the
/// neighbours), or whose motion inversion runs past its second iterate, takes `scalar`
/// (lane, position, velocity before the step).
pub(super) struct PathLanes<'a> {
    pub(super) p: &'a [Pos; LANES],
    pub(super) v: &'a mut [Pos; LANES],
    pub(super) out: &'a mut [Pos; LANES],
    pub(super) id: Option<&'a [u32; LANES]>,
}

impl PathLanes<'_> {
    /// The step by velocities `m` where `take`, else by `v` (kept); lost where not
    /// `valid`. Lanes in `odd` take `scalar`.
    #[inline(always)]
    fn finish(
        &mut self,
        valid: &Mask,
        take: &Mask,
        m: [Fl; 2],
        odd: &Mask,
        scalar: impl Fn(usize, Pos, Pos) -> (Pos, Pos),
    ) {
        let v0 = *self.v;
        for i in 0..LANES {
            let v = if take[i] { [m[0][i], m[1][i]] } else { v0[i] };
            let p = self.p[i];
            self.out[i] = if valid[i] {
                [p[0] + v[0], p[1] + v[1]]
            } else {
                LOST
            };
            self.v[i] = v;
        }
        if any(odd) {
            for i in 0..LANES {
                if odd[i] {
                    (self.out[i], self.v[i]) = scalar(i, self.p[i], v0[i]);
                }
            }
        }
    }

    /// `step_back_at`: frame `f`'s motion where it shows the object.
    #[inline(always)]
    pub(super) fn back(mut self, f: &View, at: &At, scalar: impl Fn(usize, Pos, Pos) -> (Pos, Pos)) {
        let r = run(&at.pixel);
        let shows = at.shows.unwrap_or_else(|| shows_lanes(f, &at.pixel, r, self.id));
        let m = [gather_run(f.mx, &at.pixel, r), gather_run(f.my, &at.pixel, r)];
        let take: Mask = std::array::from_fn(|i| at.valid[i] & shows[i]);
        let odd: Mask = std::array::from_fn(|i| at.valid[i] & !shows[i]);
        self.finish(&at.valid, &take, m, &odd, scalar);
    }

    /// `step_forward_at` from frame `here` to frame `next`: `here`'s `motion_next` where
    /// it shows the object, or without it `next`'s motion inverted where that lands on the
    /// object.
    #[inline(always)]
    pub(super) fn forward(
        mut self,
        g: &Grid,
        here: &View,
        next: &View,
        at: &At,
        scalar: impl Fn(usize, Pos, Pos) -> (Pos, Pos),
    ) {
        if let Some([nx, ny]) = here.next {
            let r = run(&at.pixel);
            let shows = at
                .shows
                .unwrap_or_else(|| shows_lanes(here, &at.pixel, r, self.id));
            let m = [gather_run(nx, &at.pixel, r), gather_run(ny, &at.pixel, r)];
            let take: Mask = std::array::from_fn(|i| at.valid[i] & shows[i]);
            let odd: Mask = std::array::from_fn(|i| at.valid[i] & !shows[i]);
            self.finish(&at.valid, &take, m, &odd, scalar);
            return;
        }
        // `invert` (trace.rs): x0 = p - m(i), x1 = p - m(pixel of x0); it stops at x0
        // when x0 is in pixel i or x1 equals x0, at x1 when x1 is in x0's pixel; past
        // the image it has no pixel and the step keeps its velocity.
        let p = Pts::of(self.p);
        let Inverted {
            x,
            at: a0,
            run: r0,
            landed,
            odd,
        } = Inverted::of(g, next, &p, &at.pixel);
        let odd: Mask = std::array::from_fn(|i| at.valid[i] & odd[i]);
        let shows = shows_lanes(next, &a0, r0, self.id);
        let take: Mask = std::array::from_fn(|i| landed[i] & shows[i]);
        // Where the inversion lands on the object the velocity is x - p.
        let m: [Fl; 2] = [
            std::array::from_fn(|i| x[0][i] - p.x[i]),
            std::array::from_fn(|i| x[1][i] - p.y[i]),
        ];
        let v0 = *self.v;
        for i in 0..LANES {
            let v = if take[i] { [m[0][i], m[1][i]] } else { v0[i] };
            let q = self.p[i];
            self.out[i] = match (at.valid[i], take[i]) {
                (false, _) => LOST,
                (true, true) => [x[0][i], x[1][i]],
                (true, false) => [q[0] + v[0], q[1] + v[1]],
            };
            self.v[i] = v;
        }
        if any(&odd) {
            for i in 0..LANES {
                if odd[i] {
                    (self.out[i], self.v[i]) = scalar(i, self.p[i], v0[i]);
                }
            }
        }
    }
}

/// `through_cached` (trace.rs) of `LANES` positions `p` in the pixels of first-step codes
/// `code` (the pixel in `pixel_bits`): `mapped` there (the pixel centre for l0's own
/// map) plus each position's offset from its pixel's centre, into `out`. None when a
/// lane's code is `outside`, or `hidden` for a frame other than l0 (the caller's scalar
/// code steps on there).
#[inline(always)]
pub(super) fn through_lanes(
    mapped: Option<&[Pos]>,
    p: &[Pos; LANES],
    code: &[u32; LANES],
    [outside, pixel_bits, hidden]: [u32; 3],
    out: &mut [Pos; LANES],
) -> Option<()> {
    let stop = if mapped.is_some() { hidden } else { 0 };
    let simple = code
        .iter()
        .fold(true, |a, &k| a & (k != outside) & (k & stop == 0));
    if !simple {
        return None;
    }
    let p = Pts::of(p);
    let ctr = Pts {
        x: p.x.map(|v| v.floor() + 0.5),
        y: p.y.map(|v| v.floor() + 0.5),
    };
    let base = match mapped {
        Some(m) => {
            let j: Ix = code.map(|k| (k & pixel_bits) as usize);
            Pts::of(&gather(m, &j))
        }
        None => ctr,
    };
    for i in 0..LANES {
        out[i] = [base.x[i] + (p.x[i] - ctr.x[i]), base.y[i] + (p.y[i] - ctr.y[i])];
    }
    Some(())
}

/// The pixel centres `x..x + LANES` of row `y` plus the velocities `vx`, `vy`, as
/// `centre(x, y) + v` (trace.rs).
#[inline(always)]
pub(super) fn centres_plus(x: usize, y: usize, vx: &[f32; LANES], vy: &[f32; LANES]) -> [Pos; LANES] {
    let xs = columns(x);
    let cy = y as f32 + 0.5;
    std::array::from_fn(|i| [xs[i] + 0.5 + vx[i], cy + vy[i]])
}

/// `invert` (trace.rs) of `LANES` positions `p` in pixels `i`, `next`'s motion: x0 = p -
/// m(i), x1 = p - m(pixel of x0); it stops at x0 when x0 is in pixel i or x1 equals x0,
/// at x1 when x1 is in x0's pixel; past the image it has no pixel. Lanes that go on
/// further are `odd` (for the scalar code).
struct Inverted {
    /// Where it stopped.
    x: [Fl; 2],
    /// The pixel there (that of x0), and [`run`] of them.
    at: Ix,
    run: Option<usize>,
    /// Whether it stopped in the image.
    landed: Mask,
    odd: Mask,
}

impl Inverted {
    #[inline(always)]
    fn of(g: &Grid, next: &View, p: &Pts, i: &Ix) -> Self {
        const _: () = assert!(INVERSE_ITERATIONS >= 2);
        let r = run(i);
        let (mx, my) = (gather_run(next.mx, i, r), gather_run(next.my, i, r));
        let x0 = Pts {
            x: std::array::from_fn(|k| p.x[k] - mx[k]),
            y: std::array::from_fn(|k| p.y[k] - my[k]),
        };
        let (a0, in0) = pixel_lanes(g, &x0);
        let r0 = run(&a0);
        let (mx, my) = (gather_run(next.mx, &a0, r0), gather_run(next.my, &a0, r0));
        let x1 = Pts {
            x: std::array::from_fn(|k| p.x[k] - mx[k]),
            y: std::array::from_fn(|k| p.y[k] - my[k]),
        };
        let (a1, in1) = pixel_lanes(g, &x1);
        let mut x = [[0.0f32; LANES]; 2];
        let mut landed = [false; LANES];
        let mut odd = [false; LANES];
        for k in 0..LANES {
            let stop0 = (a0[k] == i[k])
                | ((x1.x[k].to_bits() == x0.x[k].to_bits()) & (x1.y[k].to_bits() == x0.y[k].to_bits()));
            let stop1 = !stop0 & in1[k] & (a1[k] == a0[k]);
            landed[k] = in0[k] & (stop0 | stop1);
            x[0][k] = if stop0 { x0.x[k] } else { x1.x[k] };
            x[1][k] = if stop0 { x0.y[k] } else { x1.y[k] };
            odd[k] = in0[k] & !stop0 & in1[k] & !stop1;
        }
        Inverted {
            x,
            at: a0,
            run: r0,
            landed,
            odd,
        }
    }
}

/// `step_code` (trace.rs) of `LANES` first steps that reached `p`, for objects `id` whose
/// frame there is `next`: the pixel, with `hidden` where `next` does not show the object,
/// or `outside`.
#[inline(always)]
fn step_codes(
    g: &Grid,
    next: &View,
    p: &[Pos; LANES],
    id: Option<&[u32; LANES]>,
    [outside, hidden]: [u32; 2],
) -> [u32; LANES] {
    let (j, inside) = pixel_lanes(g, &Pts::of(p));
    let shows = shows_lanes(next, &j, run(&j), id);
    std::array::from_fn(|k| {
        if inside[k] {
            j[k] as u32 | if shows[k] { 0 } else { hidden }
        } else {
            outside
        }
    })
}

/// `first_steps_back` (trace.rs) of pixels `x..x + LANES` of row `y` of frame `f` to
/// frame `prev`: the step is the pixel's motion (its own pixel shows its object).
#[inline(always)]
pub(super) fn first_steps_back(
    g: &Grid,
    f: &View,
    prev: &View,
    x: usize,
    y: usize,
    codes: [u32; 2],
) -> [u32; LANES] {
    let i = y * g.w + x;
    let id = f.ids.map(|ids| ids[i..i + LANES].try_into().expect("LANES ids"));
    let (mx, my) = (&f.mx[i..i + LANES], &f.my[i..i + LANES]);
    let p = centres_plus(x, y, mx.try_into().expect("LANES"), my.try_into().expect("LANES"));
    step_codes(g, prev, &p, id, codes)
}

/// `first_step_forward` (trace.rs) of pixels `x..x + LANES` of row `y` of frame `f` to
/// frame `next`: positions and codes (`[outside, hidden, inverted]`), and the lanes left
/// to the scalar code (an inversion that goes on past its second iterate).
#[allow(clippy::too_many_arguments)]
#[inline(always)]
pub(super) fn first_steps_forward(
    g: &Grid,
    f: &View,
    next: &View,
    x: usize,
    y: usize,
    [outside, hidden, inverted]: [u32; 3],
    pos: &mut [Pos; LANES],
    code: &mut [u32; LANES],
) -> Mask {
    let i = y * g.w + x;
    let id = f.ids.map(|ids| ids[i..i + LANES].try_into().expect("LANES ids"));
    let (mx, my): (&[f32; LANES], &[f32; LANES]) = (
        f.mx[i..i + LANES].try_into().expect("LANES"),
        f.my[i..i + LANES].try_into().expect("LANES"),
    );
    let Some([nx, ny]) = f.next else {
        let zero = [0.0f32; LANES];
        let p = Pts::of(&centres_plus(x, y, &zero, &zero));
        let here: Ix = std::array::from_fn(|k| i + k);
        let inv = Inverted::of(g, next, &p, &here);
        let shows = shows_lanes(next, &inv.at, inv.run, id);
        // Elsewhere constant velocity: minus the motion.
        let on: [Pos; LANES] = std::array::from_fn(|k| [p.x[k] + -mx[k], p.y[k] + -my[k]]);
        let on_code = step_codes(g, next, &on, id, [outside, hidden]);
        for k in 0..LANES {
            let take = inv.landed[k] & shows[k];
            pos[k] = if take { [inv.x[0][k], inv.x[1][k]] } else { on[k] };
            code[k] = if take {
                inv.at[k] as u32 | inverted
            } else {
                on_code[k]
            };
        }
        return inv.odd;
    };
    let v: (&[f32; LANES], &[f32; LANES]) = (
        nx[i..i + LANES].try_into().expect("LANES"),
        ny[i..i + LANES].try_into().expect("LANES"),
    );
    *pos = centres_plus(x, y, v.0, v.1);
    *code = step_codes(g, next, pos, id, [outside, hidden]);
    [false; LANES]
}

/// [`Gathered`] of `LANES` pixels, one array per field.
#[derive(Clone, Copy, Default)]
pub(super) struct Lanes {
    sum: [[f32; LANES]; 3],
    sum_w: [f32; LANES],
    total: [f32; LANES],
}

impl Lanes {
    /// Lane `i`.
    pub(super) fn get(&self, i: usize) -> Gathered {
        Gathered {
            sum: [self.sum[0][i], self.sum[1][i], self.sum[2][i]],
            sum_w: self.sum_w[i],
            total: self.total[i],
        }
    }

    /// Sets lane `i`.
    pub(super) fn set(&mut self, i: usize, g: Gathered) {
        for c in 0..3 {
            self.sum[c][i] = g.sum[c];
        }
        self.sum_w[i] = g.sum_w;
        self.total[i] = g.total;
    }
}
