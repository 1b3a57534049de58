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

use super::trace::{centre, dist, gather_frame, path_index, BoxKernel, Failed, Gathered, Grid, Pos, View};
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

#[inline(always)]
fn any(m: &Mask) -> bool {
    m.iter().fold(false, |a, &b| a | b)
}

/// `a` at each lane's pixel (a pixel index of the image, or 0).
#[inline(always)]
fn gather<T: Copy + Default>(a: &[T], j: &Ix) -> [T; LANES] {
    let Some(last) = a.len().checked_sub(1) else {
        return [T::default(); LANES];
    };
    std::array::from_fn(|i| a[j[i].min(last)])
}

/// The scatter test (see `scatter_band`) for the [`UnitBox`](super::trace) kernel of
/// samples `x..x + LANES` of row `y` of frame `l` (their maps to l0 at `map`): the samples
/// that fail the two-way test with the pixel they fall in, in order, into `list`. A lane
/// whose footprint holds more than one pixel takes the scalar code.
#[allow(clippy::too_many_arguments)]
#[inline(always)]
pub(super) fn scatter_lanes(
    g: &Grid,
    f: &View,
    l: usize,
    n: usize,
    params: &Params,
    paths: &[Pos],
    map: &[Pos; LANES],
    x: usize,
    y: usize,
    list: &mut Vec<Failed>,
    scalar: impl Fn(usize, Pos, &mut Vec<Failed>),
) {
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
    let mut fail = [false; LANES];
    for i in 0..LANES {
        let s = [(x + i) as f32 + 0.5 + j0, hy + j1];
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
    let m = gather(map, &k);
    let col = f.rgb.map(|ch| gather(ch, &k));
    let hy = y as f32 + 0.5;
    for i in 0..LANES {
        let hx = (x + i) as f32 + 0.5;
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
