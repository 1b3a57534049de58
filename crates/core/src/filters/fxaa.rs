//! `fxaa`: FXAA 3.11 (Lottes 2011, "FXAA 3.11", NVIDIA whitepaper and `Fxaa3_11.h`), the PC
//! quality path with its default preset 12: the spatial baseline of the PHLM paper and of
//! the thesis. No history.
//!
//! Stages: `repair`, `luma` (perceptual luma: `sqrt` of the Rec. 709 luma, of the
//! tonemapped colour for HDR input; FXAA expects gamma-2 luma), `fxaa` (edge detection,
//! edge-end search along the edge, sub-pixel blend; the output is a bilinear fetch of the
//! input at the offset position).
//!
//! The filter runs one fused pass over bands of rows ([`par_bands`]): each band computes the
//! luma of its rows and one row above and below (into rows its task keeps for the next
//! band), tests every row for FXAA's early exit in a vectorised loop, copies the colour
//! rows, and runs the edge search and the bilinear fetch only for the pixels that passed
//! the test (a small share of most frames). [`reference()`](fn@reference) is the plain two-pass version it
//! matches bit for bit (but for the sign of a zero: a -0 input sample comes out -0, where
//! the reference gives +0). The pass also tests every colour sample it reads, so a clean frame
//! (the usual case) is read once, in place: the pass assumes the last frame's LDR or HDR
//! and runs again in the rare frame where that was wrong, and a frame with samples to
//! repair goes through [`prepare`] and the pass again.

use super::passes::{planes, slices_mut};
use crate::filter_params;
use crate::frame::{Frame, Plane, Rgb};
use crate::kernels::{bilinear, fmax, fmin, luma, tonemap};
use crate::pipeline::clean::{color_max, CleanMax};
use crate::pipeline::exec::{for_rows, par_bands, StageClock, BAND_ROWS};
use crate::pipeline::input::REPAIR_STAGE;
use crate::pipeline::{
    check_needs, prepare, Filter, FilterError, FilterKind, FilterState, FrameFacts, InputCounts, Output,
    ParamKind, PixelCounts, Recorder, Scratch, Skip, StateError,
};
use serde_json::Value;

filter_params! {
    /// Parameters of `fxaa` (the three tunables of `FxaaPixelShader`, defaults as in the header).
    pub struct Params {
        /// sub-pixel aliasing removal (Fxaa3_11.h: 1.0 upper limit softer, 0.75 default, 0.5 sharper, 0 off)
        subpix: f32 = 0.75, ParamKind::Float { min: 0.0, max: 1.0 };
        /// minimum local contrast to process (0.333 too little, 0.25 low quality, 0.166 default, 0.125 high,
        /// 0.063 overkill)
        edge_threshold: f32 = 0.166, ParamKind::Float { min: 0.063, max: 0.333 };
        /// darkness threshold below which edges are skipped (0.0833 upper limit/default, 0.0625 high quality,
        /// 0.0312 visible limit)
        edge_threshold_min: f32 = 0.0833, ParamKind::Float { min: 0.0, max: 0.0833 };
    }
}

/// Search steps of FXAA 3.11 quality preset 12 (`FXAA_QUALITY__PS 5`: P0..P4 =
/// 1.0, 1.5, 2.0, 4.0, 12.0), in pixels along the edge.
pub const PRESET_12_STEPS: [f32; 5] = [1.0, 1.5, 2.0, 4.0, 12.0];

/// The FXAA filter (no history; it keeps the planes handed back by [`Filter::recycle`] to
/// write the next output into, and whether the last frame was HDR as a guess for the next,
/// `None` after a frame with samples to repair).
#[derive(Debug)]
pub struct Fxaa {
    params: Params,
    scratch: Scratch,
    last_hdr: Option<bool>,
}

impl FilterKind for Fxaa {
    const NAME: &'static str = "fxaa";
    const SUMMARY: &'static str =
        "FXAA 3.11 quality preset 12 (Lottes 2011): spatial edge anti-aliasing, no history";
    const STAGES: &'static [&'static str] = &["repair", "luma", "fxaa"];
    type Params = Params;
    fn new(params: Params) -> Self {
        Fxaa {
            params,
            scratch: Scratch::default(),
            last_hdr: None,
        }
    }
}

/// Result of the search for both ends of an edge.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct EdgeEnds {
    /// Final position on the negative side.
    pub pos_n: [f32; 2],
    /// Final position on the positive side.
    pub pos_p: [f32; 2],
    /// Luma at the last sample on the negative side, minus the local average.
    pub end_n: f32,
    /// The same on the positive side.
    pub end_p: f32,
}

/// FXAA's edge-end search: from `pos_b` (on the edge, half a pixel across it) step along
/// `off` (a unit pixel step along the edge) by `steps` on both sides, sampling the luma
/// bilinearly, until the luma minus `luma_avg` reaches `gradient_scaled` in magnitude.
/// After the last sample the position advances once more without sampling (as the header
/// does: the last step is a guess).
#[allow(clippy::too_many_arguments)] // the header's own variables, named as there
pub fn edge_search(
    luma: &[f32],
    w: usize,
    h: usize,
    pos_b: [f32; 2],
    off: [f32; 2],
    luma_avg: f32,
    gradient_scaled: f32,
    steps: &[f32],
) -> EdgeEnds {
    let at = |p: [f32; 2]| bilinear([luma], w, h, p[0], p[1])[0] - luma_avg;
    let mut pos_n = [pos_b[0] - off[0] * steps[0], pos_b[1] - off[1] * steps[0]];
    let mut pos_p = [pos_b[0] + off[0] * steps[0], pos_b[1] + off[1] * steps[0]];
    let mut end_n = at(pos_n);
    let mut end_p = at(pos_p);
    let mut done_n = end_n.abs() >= gradient_scaled;
    let mut done_p = end_p.abs() >= gradient_scaled;
    for (k, &step) in steps.iter().enumerate().skip(1) {
        if !done_n {
            pos_n = [pos_n[0] - off[0] * step, pos_n[1] - off[1] * step];
        }
        if !done_p {
            pos_p = [pos_p[0] + off[0] * step, pos_p[1] + off[1] * step];
        }
        if done_n && done_p || k + 1 == steps.len() {
            break;
        }
        if !done_n {
            end_n = at(pos_n);
            done_n = end_n.abs() >= gradient_scaled;
        }
        if !done_p {
            end_p = at(pos_p);
            done_p = end_p.abs() >= gradient_scaled;
        }
    }
    EdgeEnds {
        pos_n,
        pos_p,
        end_n,
        end_p,
    }
}

/// FXAA 3.11 for pixel `(x, y)`: the position to fetch the colour at (pixel units).
pub fn fxaa_position(l: &[f32], w: usize, h: usize, x: usize, y: usize, p: &Params) -> [f32; 2] {
    let at = |dx: isize, dy: isize| crate::kernels::fetch_clamped(l, w, h, x as isize + dx, y as isize + dy);
    let pos_m = [x as f32 + 0.5, y as f32 + 0.5];
    let luma_m = at(0, 0);
    let luma_s = at(0, 1);
    let luma_e = at(1, 0);
    let luma_n = at(0, -1);
    let luma_w = at(-1, 0);
    let range_max = luma_s.max(luma_m).max(luma_e).max(luma_n).max(luma_w);
    let range_min = luma_s.min(luma_m).min(luma_e).min(luma_n).min(luma_w);
    let range = range_max - range_min;
    if range < p.edge_threshold_min.max(range_max * p.edge_threshold) {
        return pos_m;
    }
    let lumas = Lumas {
        nw: at(-1, -1),
        se: at(1, 1),
        ne: at(1, -1),
        sw: at(-1, 1),
        m: luma_m,
        n: luma_n,
        s: luma_s,
        e: luma_e,
        w: luma_w,
    };
    let edge = Edge::new(pos_m, lumas, range);
    let off = if edge.horz_span { [1.0, 0.0] } else { [0.0, 1.0] };
    let ends = edge_search(
        l,
        w,
        h,
        edge.pos_b,
        off,
        edge.luma_nn * 0.5,
        edge.gradient_scaled,
        &PRESET_12_STEPS,
    );
    edge.position(pos_m, &ends, p.subpix)
}

/// A pixel's luma and its eight neighbours' (Fxaa3_11.h's names: `m` the pixel, `n` the
/// one above, `s` the one below).
struct Lumas {
    m: f32,
    n: f32,
    s: f32,
    e: f32,
    w: f32,
    nw: f32,
    ne: f32,
    sw: f32,
    se: f32,
}

/// The edge through a pixel that passed the contrast test: Fxaa3_11.h's quantities from
/// that test to the edge-end search, shared by [`fxaa_position`] and the fused pass.
#[derive(Clone, Copy)]
struct Edge {
    /// Whether the edge runs horizontally (the search steps along x).
    horz_span: bool,
    /// Toward the steeper neighbour: -1 (n or w) or 1.
    length_sign: f32,
    subpix_c: f32,
    luma_nn: f32,
    gradient_scaled: f32,
    luma_mm: f32,
    /// Across the edge by half a pixel from the pixel's centre: where the search starts.
    pos_b: [f32; 2],
}

impl Edge {
    /// The edge at the pixel centred on `pos_m`, whose cross has luma range `range`.
    #[inline(always)]
    fn new(pos_m: [f32; 2], l: Lumas, range: f32) -> Edge {
        let Lumas {
            m: luma_m,
            n: mut luma_n,
            s: mut luma_s,
            e: luma_e,
            w: luma_w,
            nw: luma_nw,
            ne: luma_ne,
            sw: luma_sw,
            se: luma_se,
        } = l;
        let luma_ns = luma_n + luma_s;
        let luma_we = luma_w + luma_e;
        let subpix_nswe = luma_ns + luma_we;
        let edge_horz1 = -2.0 * luma_m + luma_ns;
        let edge_vert1 = -2.0 * luma_m + luma_we;
        let luma_nese = luma_ne + luma_se;
        let luma_nwne = luma_nw + luma_ne;
        let edge_horz2 = -2.0 * luma_e + luma_nese;
        let edge_vert2 = -2.0 * luma_n + luma_nwne;
        let luma_nwsw = luma_nw + luma_sw;
        let luma_swse = luma_sw + luma_se;
        let edge_horz4 = edge_horz1.abs() * 2.0 + edge_horz2.abs();
        let edge_vert4 = edge_vert1.abs() * 2.0 + edge_vert2.abs();
        let edge_horz3 = -2.0 * luma_w + luma_nwsw;
        let edge_vert3 = -2.0 * luma_s + luma_swse;
        let edge_horz = edge_horz3.abs() + edge_horz4;
        let edge_vert = edge_vert3.abs() + edge_vert4;
        let subpix_nwswnese = luma_nwsw + luma_nese;
        let horz_span = edge_horz >= edge_vert;
        let subpix_a = subpix_nswe * 2.0 + subpix_nwswnese;
        if !horz_span {
            luma_n = luma_w;
            luma_s = luma_e;
        }
        let subpix_b = subpix_a * (1.0 / 12.0) - luma_m;
        let gradient_n = luma_n - luma_m;
        let gradient_s = luma_s - luma_m;
        let pair_n = gradient_n.abs() >= gradient_s.abs();
        let gradient = gradient_n.abs().max(gradient_s.abs());
        let length_sign = if pair_n { -1.0 } else { 1.0 };
        let subpix_c = (subpix_b.abs() / range).clamp(0.0, 1.0);
        // Across the edge by half a pixel toward the steeper neighbour; search along it.
        let pos_b = if horz_span {
            [pos_m[0], pos_m[1] + length_sign * 0.5]
        } else {
            [pos_m[0] + length_sign * 0.5, pos_m[1]]
        };
        let luma_nn = if pair_n { luma_n + luma_m } else { luma_s + luma_m };
        let gradient_scaled = gradient * 0.25;
        let luma_mm = luma_m - luma_nn * 0.5;
        Edge {
            horz_span,
            length_sign,
            subpix_c,
            luma_nn,
            gradient_scaled,
            luma_mm,
            pos_b,
        }
    }

    /// The position to fetch the colour at, given the ends the search found.
    #[inline(always)]
    fn position(&self, pos_m: [f32; 2], ends: &EdgeEnds, subpix: f32) -> [f32; 2] {
        let Edge {
            horz_span,
            length_sign,
            subpix_c,
            luma_mm,
            ..
        } = *self;
        let (dst_n, dst_p) = if horz_span {
            (pos_m[0] - ends.pos_n[0], ends.pos_p[0] - pos_m[0])
        } else {
            (pos_m[1] - ends.pos_n[1], ends.pos_p[1] - pos_m[1])
        };
        let luma_m_lt_zero = luma_mm < 0.0;
        let good_span_n = (ends.end_n < 0.0) != luma_m_lt_zero;
        let good_span_p = (ends.end_p < 0.0) != luma_m_lt_zero;
        let span_length = dst_p + dst_n;
        let direction_n = dst_n < dst_p;
        let dst = dst_n.min(dst_p);
        let good_span = if direction_n { good_span_n } else { good_span_p };
        let subpix_d = -2.0 * subpix_c + 3.0;
        let subpix_f = subpix_d * subpix_c * subpix_c;
        let subpix_h = subpix_f * subpix_f * subpix;
        let pixel_offset = -dst / span_length + 0.5;
        let pixel_offset_good = if good_span { pixel_offset } else { 0.0 };
        let offset = pixel_offset_good.max(subpix_h) * length_sign;
        if horz_span {
            [pos_m[0], pos_m[1] + offset]
        } else {
            [pos_m[0] + offset, pos_m[1]]
        }
    }
}

/// The scalar reference of the filter, as it was first written: the `luma` pass writes the
/// whole luma plane, then the `fxaa` pass runs [`fxaa_position`] and a bilinear fetch of the
/// colour for every pixel. `src` is the repaired colour (finite, non-negative), `hdr`
/// whether it exceeds 1 anywhere. The filter's fused band pass gives the same bits; its
/// tests compare the two.
pub fn reference(src: [&[f32]; 3], w: usize, h: usize, hdr: bool, p: &Params) -> Rgb {
    let mut l = Plane::new(w, h);
    for_rows([l.data_mut()], w, |y, [row]| {
        for x in 0..w {
            let i = y * w + x;
            let c = [src[0][i], src[1][i], src[2][i]];
            let c = if hdr { tonemap(c) } else { c.map(|v| v.min(1.0)) };
            row[x] = luma(c).max(0.0).sqrt();
        }
    });
    let mut out: Rgb = planes(w, h);
    let l = l.data();
    for_rows(slices_mut(&mut out), w, |y, [r, g, b]| {
        for x in 0..w {
            let pos = fxaa_position(l, w, h, x, y, p);
            let c = bilinear(src, w, h, pos[0], pos[1]);
            (r[x], g[x], b[x]) = (c[0], c[1], c[2]);
        }
    });
    out
}

/// FXAA's luma of one colour, as [`reference`] computes it: `sqrt` of the Rec. 709 luma of
/// the tonemapped colour when `HDR`, else of the colour clamped to 1.
#[inline(always)]
fn luma_of<const HDR: bool>(c: [f32; 3]) -> f32 {
    let c = if HDR { tonemap(c) } else { c.map(|v| v.min(1.0)) };
    luma(c).max(0.0).sqrt()
}

/// [`luma_of`] over a row: `out[x]` from `c[k][x]` (all of one length; vectorised). Tests
/// the colour on the way: returns its largest
/// [`clean_key`](crate::pipeline::clean::clean_key).
fn luma_row<const HDR: bool>(c: [&[f32]; 3], out: &mut [f32]) -> CleanMax {
    let n = out.len();
    let (r, g, b) = (&c[0][..n], &c[1][..n], &c[2][..n]);
    for x in 0..n {
        out[x] = luma_of::<HDR>([r[x], g[x], b[x]]);
    }
    // A loop of its own, over samples still in L1: one loop mixing the two does not
    // vectorise.
    let mut m = CleanMax::of(r);
    m += CleanMax::of(g);
    m += CleanMax::of(b);
    m
}

/// FXAA's early exit over a row (Fxaa3_11.h: `range < max(fxaaQualityEdgeThresholdMin,
/// rangeMax * fxaaQualityEdgeThreshold)` leaves the pixel as it is), vectorised: `edge[x]`
/// is 1 where pixel `x` must be processed. `up`, `mid`, `down` are luma rows padded by one
/// sample on each side (the row's edge repeated); `edge` has the row's width. Returns
/// whether any pixel must be processed.
fn contrast_row(up: &[f32], mid: &[f32], down: &[f32], edge: &mut [u8], p: &Params) -> bool {
    let w = edge.len();
    let (n, s) = (&up[1..w + 1], &down[1..w + 1]);
    let (west, m, east) = (&mid[..w], &mid[1..w + 1], &mid[2..w + 2]);
    let mut any = 0;
    for x in 0..w {
        // Luma is finite (repaired colour), so the NaN-blind min and max are exact.
        let range_max = fmax(fmax(fmax(fmax(s[x], m[x]), east[x]), n[x]), west[x]);
        let range_min = fmin(fmin(fmin(fmin(s[x], m[x]), east[x]), n[x]), west[x]);
        let range = range_max - range_min;
        // `!(range < t)` in the header; the same for finite values.
        edge[x] = (range >= fmax(p.edge_threshold_min, range_max * p.edge_threshold)) as u8;
        any |= edge[x];
    }
    any != 0
}

/// Calls `f(x)` for every `x` with `flags[x] != 0`, eight flags at a time.
#[inline(always)]
fn for_each_set(flags: &[u8], mut f: impl FnMut(usize)) {
    let mut chunks = flags.chunks_exact(8);
    for (c, chunk) in (&mut chunks).enumerate() {
        if u64::from_le_bytes(chunk.try_into().expect("8 flags")) != 0 {
            for (i, &e) in chunk.iter().enumerate() {
                if e != 0 {
                    f(c * 8 + i);
                }
            }
        }
    }
    let base = flags.len() - chunks.remainder().len();
    for (i, &e) in chunks.remainder().iter().enumerate() {
        if e != 0 {
            f(base + i);
        }
    }
}

/// Rows of luma a band task has computed, kept while it moves on to the next band (rayon
/// runs a task's bands in order, so one band's rows below are the next one's own): slot
/// `y % LUMA_SLOTS` holds row `y`, `w + 2` samples padded with the row's edge samples.
/// A band uses its rows and one above and below; where a row has pixels to process it also
/// uses [`SEARCH_REACH`] rows above and below, for vertical edge searches.
#[derive(Default)]
struct LumaRows {
    luma: Vec<f32>,
    /// `y + 1` for the row `y` in each slot, 0 for none.
    tag: Vec<usize>,
    w: usize,
    h: usize,
}

/// Rows an edge search along a column reads above and below its pixel: preset 12 samples
/// at 1, 2.5, 4.5 and 8.5 pixels from the pixel's centre (the last step of
/// [`PRESET_12_STEPS`] is not sampled), so the last bilinear sample spans rows `y + 8` and
/// `y + 9` (and `y - 9`, `y - 8`).
const SEARCH_REACH: usize = 9;

/// Slots of [`LumaRows`]: a band's rows and the search's reach on both sides fit, so
/// nothing a band reads is evicted while it runs.
const LUMA_SLOTS: usize = 32;
const _: () = assert!(LUMA_SLOTS >= BAND_ROWS + 2 * SEARCH_REACH);

impl LumaRows {
    /// Sizes the buffers for `w` x `h` (forgetting every row when the size changes).
    fn reset(&mut self, w: usize, h: usize) {
        if (self.w, self.h) != (w, h) || self.tag.len() != LUMA_SLOTS {
            self.luma.resize(LUMA_SLOTS * (w + 2), 0.0);
            self.tag.clear();
            self.tag.resize(LUMA_SLOTS, 0);
            (self.w, self.h) = (w, h);
        }
    }

    /// Computes rows `ys` (clamped to the image) where not held yet; returns the largest
    /// [`clean_key`](crate::pipeline::clean::clean_key) of the colour read.
    fn ensure(&mut self, ys: std::ops::RangeInclusive<isize>, src: [&[f32]; 3], hdr: bool) -> CleanMax {
        let (w, h) = (self.w, self.h);
        let stride = w + 2;
        let mut seen = CleanMax::default();
        for y in (*ys.start()).max(0)..=(*ys.end()).min(h as isize - 1) {
            let y = y as usize;
            let slot = y % LUMA_SLOTS;
            if self.tag[slot] == y + 1 {
                continue;
            }
            let row = &mut self.luma[slot * stride..(slot + 1) * stride];
            let c = src.map(|p| &p[y * w..(y + 1) * w]);
            seen += if hdr {
                luma_row::<true>(c, &mut row[1..w + 1])
            } else {
                luma_row::<false>(c, &mut row[1..w + 1])
            };
            (row[0], row[w + 1]) = (row[1], row[w]);
            self.tag[slot] = y + 1;
        }
        seen
    }

    /// Where pixel `(0, y)` of held row `y` (inside the image) is in `luma`.
    #[inline(always)]
    fn start(&self, y: usize) -> usize {
        let slot = y % LUMA_SLOTS;
        debug_assert_eq!(self.tag[slot], y + 1, "luma row {y} not computed");
        slot * (self.w + 2) + 1
    }

    /// Row `y` (clamped to the image), padded; it must be held.
    #[inline(always)]
    fn row(&self, y: isize) -> &[f32] {
        let y = y.clamp(0, self.h as isize - 1) as usize;
        let slot = y % LUMA_SLOTS;
        debug_assert_eq!(self.tag[slot], y + 1, "luma row {y} not computed");
        let stride = self.w + 2;
        &self.luma[slot * stride..(slot + 1) * stride]
    }
}

/// A band task's buffers: its luma rows and the edge flags of a band's rows.
#[derive(Default)]
struct BandScratch {
    luma: LumaRows,
    /// `BAND_ROWS` rows of `w` flags.
    edge: Vec<u8>,
}

/// What an edge search reads: the rows a task holds (those the search can reach are
/// computed before it runs).
struct LumaView<'a> {
    rows: &'a LumaRows,
}

impl LumaView<'_> {
    /// [`edge_search`] with the preset's steps along a row (`horizontal`, the span FXAA
    /// calls horizontal) or a column, from `pos_b`. The coordinate across the edge stays
    /// fixed (the reference's `off` is 0 there), so its half of each bilinear sample, rows
    /// or columns and weight, is found once; each sample is then computed as [`bilinear`]
    /// computes it, and the search takes the reference's steps.
    fn edge_search(
        &self,
        pos_b: [f32; 2],
        horizontal: bool,
        luma_avg: f32,
        gradient_scaled: f32,
    ) -> EdgeEnds {
        let (w, h) = (self.rows.w, self.rows.h);
        // `bilinear`'s index clamp; the same for the finite whole numbers it gets here.
        let clamp_index = |i: f32, n: usize| (i as isize).max(0).min(n as isize - 1) as usize;
        let (along, across) = if horizontal { (0, 1) } else { (1, 0) };
        let (n_along, n_across) = if horizontal { (w, h) } else { (h, w) };
        let f = pos_b[across] - 0.5;
        let f0 = f.floor();
        let t_across = f - f0;
        let (ia, ib) = (clamp_index(f0, n_across), clamp_index(f0 + 1.0, n_across));
        // Both sides' positions after each step, by the reference's additions.
        let steps = &PRESET_12_STEPS;
        let b = pos_b[along];
        let (mut q_n, mut q_p) = ([b; 5], [b; 5]);
        let (mut pos_n, mut pos_p) = (b, b);
        for k in 0..5 {
            pos_n -= steps[k];
            pos_p += steps[k];
            (q_n[k], q_p[k]) = (pos_n, pos_p);
        }
        // The luma at the four positions of each side that may be sampled: all eight, in
        // straight loops (no branch on the data: which side stops where is a select below,
        // not a jump the CPU could mispredict), each computed as `bilinear` computes it.
        let q: [f32; 8] = std::array::from_fn(|k| if k < 4 { q_n[k] } else { q_p[k - 4] });
        let mut t = [0.0f32; 8];
        let mut qa = [0usize; 8];
        let mut qb = [0usize; 8];
        for k in 0..8 {
            let f = q[k] - 0.5;
            let f0 = f.floor();
            t[k] = f - f0;
            (qa[k], qb[k]) = (clamp_index(f0, n_along), clamp_index(f0 + 1.0, n_along));
        }
        let mut s = [0.0f32; 8];
        let luma = &self.rows.luma;
        if horizontal {
            // x = q: rows `ia`, `ib` at weight `t_across`, columns `qa`, `qb` at `t`.
            let (ra, rb) = (self.rows.start(ia), self.rows.start(ib));
            for k in 0..8 {
                let (a, b) = (qa[k], qb[k]);
                let top = luma[ra + a] + (luma[ra + b] - luma[ra + a]) * t[k];
                let bottom = luma[rb + a] + (luma[rb + b] - luma[rb + a]) * t[k];
                s[k] = top + (bottom - top) * t_across - luma_avg;
            }
        } else {
            // y = q: columns `ia`, `ib` at weight `t_across`, rows `qa`, `qb` at `t`.
            for k in 0..8 {
                let (ra, rb) = (self.rows.start(qa[k]), self.rows.start(qb[k]));
                let top = luma[ra + ia] + (luma[ra + ib] - luma[ra + ia]) * t_across;
                let bottom = luma[rb + ia] + (luma[rb + ib] - luma[rb + ia]) * t_across;
                s[k] = top + (bottom - top) * t[k] - luma_avg;
            }
        }
        // A side stops at its first sample at least `gradient_scaled` from the average;
        // one that never does takes the last step unsampled, ending on the last sample.
        let stop = |q: [f32; 5], s: &[f32]| {
            let (mut pos, mut end) = (q[4], s[3]);
            for k in (0..4).rev() {
                if s[k].abs() >= gradient_scaled {
                    (pos, end) = (q[k], s[k]);
                }
            }
            (pos, end)
        };
        let ((pos_n, end_n), (pos_p, end_p)) = (stop(q_n, &s[..4]), stop(q_p, &s[4..]));
        let fixed = pos_b[across];
        let full = |q: f32| if horizontal { [q, fixed] } else { [fixed, q] };
        EdgeEnds {
            pos_n: full(pos_n),
            pos_p: full(pos_p),
            end_n,
            end_p,
        }
    }

    /// [`fxaa_position`] of pixel `(x, y)` of row `y` (whose luma row and the rows above
    /// and below it are `rows`, padded), for a pixel that passed [`contrast_row`]. The
    /// same operations in the same order as the reference; the constants are Fxaa3_11.h's
    /// (`FxaaPixelShader`, quality path).
    fn position(&self, rows: [&[f32]; 3], x: usize, y: usize, p: &Params) -> [f32; 2] {
        let [up, mid, down] = rows;
        let pos_m = [x as f32 + 0.5, y as f32 + 0.5];
        let luma_m = mid[x + 1];
        let luma_s = down[x + 1];
        let luma_e = mid[x + 2];
        let luma_n = up[x + 1];
        let luma_w = mid[x];
        let range_max = luma_s.max(luma_m).max(luma_e).max(luma_n).max(luma_w);
        let range_min = luma_s.min(luma_m).min(luma_e).min(luma_n).min(luma_w);
        let range = range_max - range_min;
        let lumas = Lumas {
            m: luma_m,
            n: luma_n,
            s: luma_s,
            e: luma_e,
            w: luma_w,
            nw: up[x],
            ne: up[x + 2],
            sw: down[x],
            se: down[x + 2],
        };
        let edge = Edge::new(pos_m, lumas, range);
        let ends = self.edge_search(
            edge.pos_b,
            edge.horz_span,
            edge.luma_nn * 0.5,
            edge.gradient_scaled,
        );
        edge.position(pos_m, &ends, p.subpix)
    }
}

/// What the fused pass found, added up over its bands.
#[derive(Clone, Copy, Debug, Default)]
struct PassStats {
    /// Pixels that passed the early-exit test (and took the edge search).
    passed: u64,
    /// The largest [`clean_key`](crate::pipeline::clean::clean_key) of the colour read:
    /// whether it was clean, and its largest sample.
    seen: CleanMax,
}

add_assign_fields!(PassStats { passed, seen });

/// The filter's fused pass into `out`: per band of rows, `luma` of the band's rows and
/// one row above and below (those not held from the task's previous band), the
/// vectorised early-exit test of every row, a straight copy of the colour, and FXAA
/// proper for the pixels that passed the test (after the luma rows their searches can
/// reach). `src` need not be clean: the pass tests every sample it reads (see
/// [`PassStats::seen`]), and its output is meaningless (but the pass does not fail) when
/// the test fails.
fn fused(
    src: [&[f32]; 3],
    w: usize,
    h: usize,
    hdr: bool,
    p: &Params,
    out: &mut Rgb,
    clock: &StageClock<2>,
) -> PassStats {
    par_bands(slices_mut(out), w, h, |s: &mut BandScratch, rows, [r, g, b]| {
        let BandScratch { luma, edge } = s;
        luma.reset(w, h);
        edge.resize(BAND_ROWS * w, 0);
        let (y0, y1) = (rows.start as isize, rows.end as isize);
        let mut seen = clock.time(0, || luma.ensure(y0 - 1..=y1, src, hdr));
        // The test for every row, and the first and last rows with pixels to process.
        let edge_rows = clock.time(1, || {
            let mut edge_rows: Option<(isize, isize)> = None;
            for (y, flags) in (y0..y1).zip(edge.chunks_exact_mut(w)) {
                if contrast_row(luma.row(y - 1), luma.row(y), luma.row(y + 1), flags, p) {
                    edge_rows = Some(edge_rows.map_or((y, y), |(a, _)| (a, y)));
                }
            }
            for (dst, src) in [&mut *r, &mut *g, &mut *b].into_iter().zip(src) {
                dst.copy_from_slice(&src[rows.start * w..rows.end * w]);
            }
            edge_rows
        });
        let Some((first, last)) = edge_rows else {
            return PassStats { passed: 0, seen };
        };
        let reach = SEARCH_REACH as isize;
        seen += clock.time(0, || luma.ensure(first - reach..=last + reach, src, hdr));
        let passed = clock.time(1, || {
            let view = LumaView { rows: luma };
            let mut passed = 0u64;
            for (k, flags) in edge.chunks_exact(w).take(rows.len()).enumerate() {
                let y = y0 + k as isize;
                let lrows = [luma.row(y - 1), luma.row(y), luma.row(y + 1)];
                let row = k * w;
                for_each_set(flags, |x| {
                    passed += 1;
                    let pos = view.position(lrows, x, y as usize, p);
                    let c = bilinear(src, w, h, pos[0], pos[1]);
                    (r[row + x], g[row + x], b[row + x]) = (c[0], c[1], c[2]);
                });
            }
            passed
        });
        PassStats { passed, seen }
    })
}

impl Filter for Fxaa {
    fn name(&self) -> &'static str {
        Self::NAME
    }

    fn save_state(&self) -> Result<FilterState, StateError> {
        Ok(FilterState::empty(Self::NAME, self.params()))
    }

    fn load_state(&mut self, state: &FilterState) -> Result<(), StateError> {
        state.check_stateless(Self::NAME, &self.params())?;
        self.last_hdr = None;
        Ok(())
    }

    fn params(&self) -> Value {
        Value::Object(crate::pipeline::params::to_json(&self.params))
    }

    fn process(&mut self, frame: &Frame) -> Result<Output, FilterError> {
        check_needs(Self::NAME, Self::needs(), frame)?;
        let mut rec = Recorder::new();
        let (w, h) = (frame.width(), frame.height());
        let Fxaa {
            params: p,
            scratch,
            last_hdr,
        } = self;
        let mut out: Rgb = scratch.planes(w, h);
        let color = frame.color().each_ref().map(|p| p.data());
        // Whether `repair` has anything to do and whether the frame is HDR are told by the
        // pass itself, which tests every sample it reads; it starts from the last frame's
        // HDR (else one read of the colour, `color_max`, tells) and runs again in the rare
        // frame where that was wrong.
        let hdr = match *last_hdr {
            Some(hdr) => Some(hdr),
            None => color_max(frame.color())
                .max()
                .map(|max| FrameFacts::new(frame, None, max).hdr),
        };
        if let Some(guess) = hdr {
            let clock = StageClock::default();
            let t = std::time::Instant::now();
            let mut stats = fused(color, w, h, guess, p, &mut out, &clock);
            if let Some(max) = stats.seen.max() {
                let hdr = FrameFacts::new(frame, None, max).hdr;
                if hdr != guess {
                    stats = fused(color, w, h, hdr, p, &mut out, &clock);
                }
                debug_assert_eq!(stats.seen.max(), Some(max));
                *last_hdr = Some(hdr);
                rec.skip(REPAIR_STAGE, Skip::CleanInput);
                rec.fused(["luma", "fxaa"], &clock, t.elapsed().as_secs_f64() * 1e3);
                return Ok(Output {
                    color: out,
                    record: rec.finish(
                        Self::NAME,
                        frame.meta.index,
                        PixelCounts::default(),
                        InputCounts::default(),
                        0,
                    ),
                });
            }
        }
        // Something to repair (rare): `prepare` counts and repairs exactly, and the pass
        // runs on the repaired colour (a pass made before this was found is thrown away;
        // after a frame like this one the next is read once first, not passed over).
        let inp = prepare(frame, Self::uses(), &mut rec)?;
        *last_hdr = None;
        rec.run_fused(["luma", "fxaa"], |clock| {
            fused(inp.color_slices(), w, h, inp.facts.hdr, p, &mut out, clock)
        });
        Ok(Output {
            color: out,
            record: rec.finish(
                Self::NAME,
                frame.meta.index,
                PixelCounts::default(),
                inp.counts,
                0,
            ),
        })
    }

    fn reset(&mut self) {
        self.last_hdr = None;
    }

    fn state_bytes(&self) -> usize {
        0
    }

    fn recycle(&mut self, planes: Rgb) {
        self.scratch.recycle(planes);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::filters::create;
    use crate::pipeline::params::parse_assignments;
    use crate::rng::SplitMix64;
    use crate::tolerance::Tolerance;

    #[test]
    fn edge_search_matches_the_f64_reference() {
        let mut rng = SplitMix64::new(61);
        let (w, h) = (40, 30);
        // Luma quantised to 1/64 so bilinear samples at half-pixel offsets are exact in f32
        // and f64 alike: the two searches must then take the same decisions.
        let l: Vec<f32> = (0..w * h)
            .map(|_| (rng.next_f64() * 64.0).floor() as f32 / 64.0)
            .collect();
        let l64: Vec<f64> = l.iter().map(|&v| v as f64).collect();
        let steps64 = PRESET_12_STEPS.map(|s| s as f64);
        // The f64 reference of the search: each side walks on its own, sampling after every
        // step but the last.
        let search_f64 = |b: [f64; 2], off: [f64; 2], avg: f64, g: f64| {
            let bil = |x: f64, y: f64| crate::kernels::sample::tests::bilinear_f64(&l64, w, h, x, y);
            let side = |sign: f64| {
                let mut pos = [
                    b[0] + sign * off[0] * steps64[0],
                    b[1] + sign * off[1] * steps64[0],
                ];
                let mut end = bil(pos[0], pos[1]) - avg;
                for (k, &s) in steps64.iter().enumerate().skip(1) {
                    if end.abs() >= g {
                        break;
                    }
                    pos = [pos[0] + sign * off[0] * s, pos[1] + sign * off[1] * s];
                    if k + 1 < steps64.len() {
                        end = bil(pos[0], pos[1]) - avg;
                    }
                }
                (pos, end)
            };
            let (pn, en) = side(-1.0);
            let (pp, ep) = side(1.0);
            (pn, pp, en, ep)
        };
        for _ in 0..5000 {
            let x = (rng.next_f64() * w as f64).floor() + 0.5;
            let y = (rng.next_f64() * h as f64).floor();
            let horizontal = rng.next_f64() < 0.5;
            let (b, off) = if horizontal {
                ([x, y], [1.0, 0.0])
            } else {
                ([y, x.min(h as f64 - 0.5)], [0.0, 1.0])
            };
            let avg = (rng.next_f64() * 64.0).floor() / 64.0;
            let g = (rng.next_f64() * 16.0).floor() / 64.0;
            let got = edge_search(
                &l,
                w,
                h,
                b.map(|v| v as f32),
                off.map(|v| v as f32),
                avg as f32,
                g as f32,
                &PRESET_12_STEPS,
            );
            let (pn, pp, en, ep) = search_f64(b, off, avg, g);
            assert_eq!(got.pos_n.map(|v| v as f64), pn);
            assert_eq!(got.pos_p.map(|v| v as f64), pp);
            assert_eq!(got.end_n as f64, en);
            assert_eq!(got.end_p as f64, ep);
        }
    }

    /// Runs the fused pass and [`reference`] on `color` (already repaired) with `p` and
    /// compares them bit for bit (but for the sign of zero); returns how many pixels took
    /// the edge search.
    fn compare(color: &Rgb, p: &Params, what: &str) -> u64 {
        let (w, h) = color[0].size();
        let src = color.each_ref().map(|p| p.data());
        // As `prepare` decides it.
        let hdr = src.iter().any(|p| p.iter().any(|&v| v > 1.0));
        let want = reference(src, w, h, hdr, p);
        // NaN where nothing was written yet.
        let mut got: Rgb = std::array::from_fn(|_| Plane::filled(w, h, f32::NAN));
        let stats = fused(src, w, h, hdr, p, &mut got, &StageClock::default());
        for (k, (g, r)) in got.iter().zip(&want).enumerate() {
            Tolerance::EXACT
                .check_slices(&format!("{what}, plane {k}"), g.data(), r.data())
                .unwrap();
        }
        // Bit for bit but for the sign of zero: a -0 sample the pass copies stays -0, where
        // the reference's bilinear fetch at the pixel centre adds +0 to it.
        for (k, (g, r)) in got.iter().zip(&want).enumerate() {
            for (i, (a, b)) in g.data().iter().zip(r.data()).enumerate() {
                let zeros = (a.to_bits() | b.to_bits()) & 0x7fff_ffff == 0;
                assert!(
                    zeros || a.to_bits() == b.to_bits(),
                    "{what}, plane {k}, sample {i}: {a:e} vs {b:e}"
                );
            }
        }
        // The pass read and tested every sample.
        assert_eq!(stats.seen, color_max(color), "{what}");
        stats.passed
    }

    /// The test images: name and colour of `w` x `h`.
    fn images(w: usize, h: usize, rng: &mut SplitMix64) -> Vec<(&'static str, Rgb)> {
        let (a, b, c) = (rng.range(-1.0, 1.0), rng.range(-1.0, 1.0), rng.range(-0.5, 0.5));
        let mut rgb = |f: &mut dyn FnMut(usize, usize, usize, &mut SplitMix64) -> f32| -> Rgb {
            std::array::from_fn(|k| Plane::from_fn(w, h, |x, y| f(k, x, y, rng)))
        };
        let edge = move |x: usize, y: usize| {
            let (u, v) = (
                (x as f64 + 0.5) / w as f64 - 0.5,
                (y as f64 + 0.5) / h as f64 - 0.5,
            );
            a * u + b * v > c * (a.abs() + b.abs())
        };
        vec![
            ("random LDR", rgb(&mut |_, _, _, r| r.next_f64() as f32)),
            (
                "random HDR up to 1e6",
                rgb(&mut |_, _, _, r| 10f64.powf(r.range(-6.0, 6.0)) as f32),
            ),
            ("zeros", rgb(&mut |_, _, _, _| 0.0)),
            (
                "negative zeros and zeros",
                rgb(&mut |_, x, y, _| if (x + y) % 3 == 0 { -0.0 } else { 0.0 }),
            ),
            ("flat", rgb(&mut |k, _, _, _| 0.3 + 0.1 * k as f32)),
            ("flat HDR", rgb(&mut |_, _, _, _| 5.0)),
            ("hard edge", rgb(&mut |_, x, y, _| edge(x, y) as u8 as f32)),
            (
                "hard HDR edge",
                rgb(&mut |k, x, y, _| if edge(x, y) { 1e6 } else { 0.01 * k as f32 }),
            ),
            (
                "horizontal thin line",
                rgb(&mut |_, _, y, _| (y == h / 2) as u8 as f32),
            ),
            (
                "vertical thin line",
                rgb(&mut |_, x, _, _| (x == w / 2) as u8 as f32),
            ),
            ("diagonal thin line", rgb(&mut |_, x, y, _| (x == y) as u8 as f32)),
            ("checkerboard", rgb(&mut |_, x, y, _| ((x + y) % 2) as f32)),
            (
                "sparse spikes",
                rgb(&mut |_, _, _, r| if r.next_f64() < 0.05 { 50.0 } else { 0.1 }),
            ),
            (
                "smooth with HDR blocks",
                rgb(&mut |k, x, y, _| {
                    let v = 0.5 + 0.45 * ((x as f32 * 0.21 + k as f32).sin() * (y as f32 * 0.17).cos());
                    v * if (x / 13 + y / 11) % 5 == 0 { 8.0 } else { 1.0 }
                }),
            ),
        ]
    }

    /// The parameter sets tested: the defaults, every pixel processed (no early exit on
    /// flat regions), and the bounds of each.
    fn param_sets() -> Vec<Params> {
        let d = Params::default();
        vec![
            d.clone(),
            Params {
                edge_threshold_min: 0.0,
                ..d.clone()
            },
            Params {
                subpix: 0.0,
                edge_threshold: 0.333,
                ..d.clone()
            },
            Params {
                subpix: 1.0,
                edge_threshold: 0.063,
                edge_threshold_min: 0.0312,
            },
        ]
    }

    #[test]
    fn fused_pass_matches_the_reference_bit_for_bit() {
        let mut rng = SplitMix64::new(3);
        let sizes = [
            (1, 1),
            (1, 2),
            (2, 1),
            (1, 9),
            (9, 1),
            (7, 5),
            (8, 8),
            (1919, 3),
            (3, 50),
            (37, 41),
            (64, 64),
        ];
        let mut searched = std::collections::BTreeMap::new();
        for (w, h) in sizes {
            for (name, color) in images(w, h, &mut rng) {
                for (i, p) in param_sets().iter().enumerate() {
                    let n = compare(&color, p, &format!("{name} {w}x{h}, parameters {i}"));
                    *searched.entry(name).or_insert(0) += n;
                }
            }
        }
        // The edge search ran on every kind of image with edges or zeros (those take it when
        // the darkness threshold is 0), so the comparison covers it; flat regions of non-zero
        // luma never take it.
        for (name, n) in &searched {
            assert_eq!(
                *n > 0,
                !name.starts_with("flat"),
                "{name}: {n} pixels took the edge search"
            );
        }
        let flat = Params::default();
        for (w, h) in [(7, 5), (40, 30)] {
            for (name, color) in images(w, h, &mut rng) {
                if name.starts_with("flat") || name.contains("zeros") {
                    assert_eq!(compare(&color, &flat, name), 0, "{name}");
                }
            }
        }
    }

    #[test]
    fn long_vertical_edges_search_beyond_the_band() {
        // Edge-end searches along a vertical edge reach 9 rows up and down, past the band's
        // own luma rows: those rows come from the colour. Edges ending at various rows.
        let mut rng = SplitMix64::new(8);
        for (w, h) in [(6, 60), (33, 47), (5, 17)] {
            for _ in 0..20 {
                let (x0, y0, y1) = (
                    (rng.next_f64() * w as f64) as usize,
                    (rng.next_f64() * h as f64) as usize,
                    (rng.next_f64() * h as f64) as usize,
                );
                let level = rng.range(0.2, 30.0) as f32;
                let color: Rgb = std::array::from_fn(|k| {
                    Plane::from_fn(w, h, |x, y| {
                        let inside = x >= x0 && (y0.min(y1)..=y0.max(y1)).contains(&y);
                        if inside {
                            level * (1.0 + 0.1 * k as f32)
                        } else {
                            0.05
                        }
                    })
                });
                for p in param_sets() {
                    compare(&color, &p, &format!("{w}x{h} edge x >= {x0}, rows {y0}..{y1}"));
                }
            }
        }
    }

    #[test]
    fn process_matches_the_reference_on_dirty_clean_and_recycled_frames() {
        let mut rng = SplitMix64::new(12);
        let mut f = Fxaa::new(Params::default());
        for (w, h) in [(1, 1), (7, 5), (1919, 3), (23, 29)] {
            for dirty in [false, true] {
                let mut color: Rgb = std::array::from_fn(|_| {
                    Plane::from_fn(w, h, |x, y| {
                        ((x / 3 + y / 2) % 2) as f32 * rng.range(0.5, 3.0) as f32
                    })
                });
                if dirty {
                    let bad = [f32::NAN, f32::INFINITY, f32::NEG_INFINITY, -2.0];
                    for (i, v) in bad.into_iter().enumerate() {
                        let n = color[i % 3].data().len();
                        color[i % 3].data_mut()[(i * 7) % n] = v;
                    }
                }
                let frame = Frame::new(color).unwrap();
                // What the plain path sees: the repaired colour and its facts.
                let mut rec = Recorder::new();
                let inp = prepare(&frame, Fxaa::uses(), &mut rec).unwrap();
                let want = reference(inp.color_slices(), w, h, inp.facts.hdr, &Params::default());
                let what = format!("{w}x{h}, dirty {dirty}");
                // Twice: the second time into the planes handed back.
                for _ in 0..2 {
                    let out = f.process(&frame).unwrap();
                    for (k, (g, r)) in out.color.iter().zip(&want).enumerate() {
                        Tolerance::EXACT
                            .check_slices(&format!("{what}, plane {k}"), g.data(), r.data())
                            .unwrap();
                    }
                    assert_eq!(out.record.input, inp.counts, "{what}");
                    assert_eq!(out.record.ran(REPAIR_STAGE), dirty, "{what}");
                    // A clean frame's HDR is the next one's guess; after a dirty frame the
                    // next is read first.
                    assert_eq!(f.last_hdr, (!dirty).then_some(inp.facts.hdr), "{what}");
                    if !dirty {
                        assert_eq!(
                            out.record.stage(REPAIR_STAGE).unwrap().skipped,
                            Some(Skip::CleanInput)
                        );
                    }
                    assert!(out.record.ran("luma") && out.record.ran("fxaa"), "{what}");
                    let names: Vec<_> = out.record.stages.iter().map(|s| s.name).collect();
                    assert_eq!(names, Fxaa::STAGES, "{what}");
                    f.recycle(out.color);
                }
            }
        }
    }

    #[test]
    fn a_stream_switching_between_ldr_and_hdr_gets_the_luma_of_each_frame() {
        // The pass starts from the last frame's HDR; where that is wrong it runs again.
        let mut rng = SplitMix64::new(21);
        let mut f = Fxaa::new(Params::default());
        let (w, h) = (19, 23);
        let kinds = [false, true, true, false, false, true, false, true];
        for (i, hdr) in kinds.into_iter().enumerate() {
            let scale = if hdr { 4.0 } else { 1.0 };
            let color: Rgb = std::array::from_fn(|_| {
                Plane::from_fn(w, h, |x, y| {
                    (((x + i) / 2 + y / 3) % 2) as f32 * scale * rng.range(0.3, 1.0) as f32
                })
            });
            let src = color.each_ref().map(|p| p.data());
            let max = color_max(&color).max().unwrap();
            assert_eq!(max > 1.0, hdr, "frame {i}");
            let want = reference(src, w, h, hdr, &Params::default());
            let out = f.process(&Frame::new(color.clone()).unwrap()).unwrap();
            for (k, (g, r)) in out.color.iter().zip(&want).enumerate() {
                Tolerance::EXACT
                    .check_slices(&format!("frame {i} (HDR {hdr}), plane {k}"), g.data(), r.data())
                    .unwrap();
            }
            // Each stage once, however many passes ran.
            let names: Vec<_> = out.record.stages.iter().map(|s| s.name).collect();
            assert_eq!(names, Fxaa::STAGES, "frame {i}");
            assert_eq!(f.last_hdr, Some(hdr), "frame {i}");
            f.recycle(out.color);
        }
    }

    #[test]
    fn the_pass_tests_what_it_reads_and_survives_unrepaired_colour() {
        // Non-finite and negative samples give a meaningless output, but no panic, and the
        // pass reports them.
        let mut rng = SplitMix64::new(4);
        let bad = [f32::NAN, f32::INFINITY, f32::NEG_INFINITY, -1.0, -f32::MAX];
        for (w, h) in [(1, 1), (9, 7), (40, 33)] {
            for v in bad {
                let mut color: Rgb = std::array::from_fn(|_| {
                    Plane::from_fn(w, h, |x, y| ((x + y) % 3) as f32 * rng.range(0.1, 5.0) as f32)
                });
                let i = (rng.next_f64() * (w * h) as f64) as usize % (w * h);
                color[i % 3].data_mut()[i] = v;
                let src = color.each_ref().map(|p| p.data());
                let mut out: Rgb = std::array::from_fn(|_| Plane::new(w, h));
                for hdr in [false, true] {
                    let p = Params {
                        edge_threshold_min: 0.0,
                        ..Params::default()
                    };
                    let stats = fused(src, w, h, hdr, &p, &mut out, &StageClock::default());
                    assert_eq!(stats.seen.max(), None, "{v} at {i} of {w}x{h}");
                }
            }
        }
    }

    #[test]
    fn search_reach_is_where_the_last_sample_of_preset_12_lands() {
        // Samples after every step but the last, from the pixel centre; the last sample's
        // bilinear footprint reaches one row past its position's floor.
        let far: f32 = PRESET_12_STEPS[..PRESET_12_STEPS.len() - 1].iter().sum();
        let reach = (far + 0.5 - 0.5).floor() as usize + 1;
        assert_eq!(SEARCH_REACH, reach, "steps {PRESET_12_STEPS:?}");
    }

    #[test]
    fn fxaa_smooths_a_stair_stepped_edge_toward_its_coverage() {
        // A half-plane y > 8 + x / 8, sampled once per pixel centre (aliased) and by exact
        // coverage (the reference).
        let (w, h) = (64, 16);
        let edge = |x: f64| 8.0 + x / 8.0;
        let aliased = Plane::from_fn(w, h, |x, y| {
            if (y as f64 + 0.5) > edge(x as f64 + 0.5) {
                1.0f32
            } else {
                0.0
            }
        });
        let coverage = Plane::from_fn(w, h, |x, y| {
            let n = 64;
            let mut c = 0;
            for j in 0..n {
                for i in 0..n {
                    let (px, py) = (
                        x as f64 + (i as f64 + 0.5) / n as f64,
                        y as f64 + (j as f64 + 0.5) / n as f64,
                    );
                    c += (py > edge(px)) as u32;
                }
            }
            c as f32 / (n * n) as f32
        });
        let frame = Frame::new([aliased.clone(), aliased.clone(), aliased.clone()]).unwrap();
        let out = create("fxaa", &parse_assignments::<&str>(&[]).unwrap())
            .unwrap()
            .process(&frame)
            .unwrap();
        let mse = |a: &Plane<f32>| {
            a.data()
                .iter()
                .zip(coverage.data())
                .map(|(x, y)| ((x - y) as f64).powi(2))
                .sum::<f64>()
                / (w * h) as f64
        };
        let (before, after) = (mse(&aliased), mse(&out.color[0]));
        assert!(
            after < 0.6 * before,
            "MSE against coverage: input {before:.5}, fxaa {after:.5}"
        );
        // Flat regions are untouched.
        assert_eq!(out.color[0].get(2, 1), 0.0);
        assert_eq!(out.color[0].get(5, 15), 1.0);
    }
}
