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
//! luma of its rows and one row above and below into a buffer of its own, tests every row
//! for FXAA's early exit in a vectorised loop, copies the colour rows, and runs the edge
//! search and the bilinear fetch only for the pixels that passed the test (a small share
//! of most frames). [`reference`] is the plain two-pass version it must match bit for bit.
//! A frame with samples to repair goes through [`prepare`] first; a clean one (told by one
//! vectorised read, [`color_max`]) is read in place.

use super::passes::{planes, slices_mut};
use crate::filter_params;
use crate::frame::{ChannelKind, ChannelSet, Frame, Plane, Rgb};
use crate::kernels::{bilinear, fmax, fmin, luma, tonemap};
use crate::pipeline::clean::color_max;
use crate::pipeline::exec::{for_rows, par_bands, StageClock};
use crate::pipeline::input::REPAIR_STAGE;
use crate::pipeline::{
    check_needs, prepare, Filter, FilterError, FilterKind, FrameFacts, InputCounts, Output, ParamKind,
    PixelCounts, Recorder, Scratch, Skip,
};
use serde_json::Value;

filter_params! {
    /// Parameters of `fxaa` (the three tunables of `FxaaPixelShader`, defaults as in the header).
    pub struct Params {
        subpix: f32 = 0.75,
            ParamKind::Float { min: 0.0, max: 1.0 },
            "sub-pixel aliasing removal (Fxaa3_11.h: 1.0 upper limit softer, 0.75 default, 0.5 sharper, 0 off)";
        edge_threshold: f32 = 0.166,
            ParamKind::Float { min: 0.063, max: 0.333 },
            "minimum local contrast to process (0.333 too little, 0.25 low quality, 0.166 default, 0.125 high, 0.063 overkill)";
        edge_threshold_min: f32 = 0.0833,
            ParamKind::Float { min: 0.0, max: 0.0833 },
            "darkness threshold below which edges are skipped (0.0833 upper limit/default, 0.0625 high quality, 0.0312 visible limit)";
    }
}

/// Search steps of FXAA 3.11 quality preset 12 (`FXAA_QUALITY__PS 5`: P0..P4 =
/// 1.0, 1.5, 2.0, 4.0, 12.0), in pixels along the edge.
pub const PRESET_12_STEPS: [f32; 5] = [1.0, 1.5, 2.0, 4.0, 12.0];

/// The FXAA filter (no history; it keeps the planes handed back by [`Filter::recycle`] to
/// write the next output into).
#[derive(Debug)]
pub struct Fxaa {
    params: Params,
    scratch: Scratch,
}

impl FilterKind for Fxaa {
    const NAME: &'static str = "fxaa";
    const SUMMARY: &'static str =
        "FXAA 3.11 quality preset 12 (Lottes 2011): spatial edge anti-aliasing, no history";
    const STAGES: &'static [&'static str] = &["repair", "luma", "fxaa"];
    type Params = Params;
    fn needs() -> ChannelSet {
        ChannelSet::of(&[ChannelKind::Color])
    }
    fn uses() -> ChannelSet {
        Self::needs()
    }
    fn state_bytes_per_pixel(_: &Params) -> usize {
        0
    }
    fn new(params: Params) -> Self {
        Fxaa {
            params,
            scratch: Scratch::default(),
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
    let mut luma_s = at(0, 1);
    let luma_e = at(1, 0);
    let mut luma_n = at(0, -1);
    let luma_w = at(-1, 0);
    let range_max = luma_s.max(luma_m).max(luma_e).max(luma_n).max(luma_w);
    let range_min = luma_s.min(luma_m).min(luma_e).min(luma_n).min(luma_w);
    let range = range_max - range_min;
    if range < p.edge_threshold_min.max(range_max * p.edge_threshold) {
        return pos_m;
    }
    let luma_nw = at(-1, -1);
    let luma_se = at(1, 1);
    let luma_ne = at(1, -1);
    let luma_sw = at(-1, 1);
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
    let (pos_b, off) = if horz_span {
        ([pos_m[0], pos_m[1] + length_sign * 0.5], [1.0, 0.0])
    } else {
        ([pos_m[0] + length_sign * 0.5, pos_m[1]], [0.0, 1.0])
    };
    let luma_nn = if pair_n { luma_n + luma_m } else { luma_s + luma_m };
    let gradient_scaled = gradient * 0.25;
    let luma_mm = luma_m - luma_nn * 0.5;
    let ends = edge_search(
        l,
        w,
        h,
        pos_b,
        off,
        luma_nn * 0.5,
        gradient_scaled,
        &PRESET_12_STEPS,
    );
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
    let subpix_h = subpix_f * subpix_f * p.subpix;
    let pixel_offset = -dst / span_length + 0.5;
    let pixel_offset_good = if good_span { pixel_offset } else { 0.0 };
    let offset = pixel_offset_good.max(subpix_h) * length_sign;
    if horz_span {
        [pos_m[0], pos_m[1] + offset]
    } else {
        [pos_m[0] + offset, pos_m[1]]
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

/// [`luma_of`] over a row: `out[x]` from `c[k][x]` (all of one length; vectorised).
fn luma_row<const HDR: bool>(c: [&[f32]; 3], out: &mut [f32]) {
    let n = out.len();
    let (r, g, b) = (&c[0][..n], &c[1][..n], &c[2][..n]);
    for x in 0..n {
        out[x] = luma_of::<HDR>([r[x], g[x], b[x]]);
    }
}

/// FXAA's early exit over a row (Fxaa3_11.h: `range < max(fxaaQualityEdgeThresholdMin,
/// rangeMax * fxaaQualityEdgeThreshold)` leaves the pixel as it is), vectorised: `edge[x]`
/// is 1 where pixel `x` must be processed. `up`, `mid`, `down` are luma rows padded by one
/// sample on each side (the row's edge repeated); `edge` has the row's width.
fn contrast_row(up: &[f32], mid: &[f32], down: &[f32], edge: &mut [u8], p: &Params) {
    let w = edge.len();
    let (n, s) = (&up[1..w + 1], &down[1..w + 1]);
    let (west, m, east) = (&mid[..w], &mid[1..w + 1], &mid[2..w + 2]);
    for x in 0..w {
        // Luma is finite (repaired colour), so the NaN-blind min and max are exact.
        let range_max = fmax(fmax(fmax(fmax(s[x], m[x]), east[x]), n[x]), west[x]);
        let range_min = fmin(fmin(fmin(fmin(s[x], m[x]), east[x]), n[x]), west[x]);
        let range = range_max - range_min;
        // `!(range < t)` in the header; the same for finite values.
        edge[x] = (range >= fmax(p.edge_threshold_min, range_max * p.edge_threshold)) as u8;
    }
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

/// The luma a band's edge search reads: rows `lo..hi` from the band's buffer (rows of
/// `w + 2`, padded), the rows beyond computed from the colour when a vertical search
/// reaches them (edge-end samples go up to 9 rows away, the band buffer holds one).
struct LumaView<'a> {
    band: &'a [f32],
    lo: usize,
    hi: usize,
    w: usize,
    h: usize,
    src: [&'a [f32]; 3],
    hdr: bool,
}

impl LumaView<'_> {
    /// Luma of pixel `(x, y)` (inside the image).
    #[inline(always)]
    fn at(&self, x: usize, y: usize) -> f32 {
        if (self.lo..self.hi).contains(&y) {
            self.band[(y - self.lo) * (self.w + 2) + x + 1]
        } else {
            let i = y * self.w + x;
            let c = [self.src[0][i], self.src[1][i], self.src[2][i]];
            if self.hdr {
                luma_of::<true>(c)
            } else {
                luma_of::<false>(c)
            }
        }
    }

    /// Bilinear luma at `(x, y)`, computed as [`bilinear`] does.
    #[inline]
    fn bilinear(&self, x: f32, y: f32) -> f32 {
        let clamp_index = |i: f32, n: usize| (i.max(0.0) as usize).min(n - 1);
        let fx = x - 0.5;
        let fy = y - 0.5;
        let x0 = fx.floor();
        let y0 = fy.floor();
        let tx = fx - x0;
        let ty = fy - y0;
        let xa = clamp_index(x0, self.w);
        let xb = clamp_index(x0 + 1.0, self.w);
        let ya = clamp_index(y0, self.h);
        let yb = clamp_index(y0 + 1.0, self.h);
        let (aa, ab) = (self.at(xa, ya), self.at(xb, ya));
        let (ba, bb) = (self.at(xa, yb), self.at(xb, yb));
        let top = aa + (ab - aa) * tx;
        let bottom = ba + (bb - ba) * tx;
        top + (bottom - top) * ty
    }

    /// [`edge_search`] on this luma with the preset's steps.
    fn edge_search(&self, pos_b: [f32; 2], off: [f32; 2], luma_avg: f32, gradient_scaled: f32) -> EdgeEnds {
        let steps = &PRESET_12_STEPS;
        let at = |p: [f32; 2]| self.bilinear(p[0], p[1]) - luma_avg;
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

    /// [`fxaa_position`] of pixel `(x, y)` of row `y` (whose luma row and the rows above
    /// and below it are `rows`, padded), for a pixel that passed [`contrast_row`]. The
    /// same operations in the same order as the reference; the constants are Fxaa3_11.h's
    /// (`FxaaPixelShader`, quality path).
    fn position(&self, rows: [&[f32]; 3], x: usize, y: usize, p: &Params) -> [f32; 2] {
        let [up, mid, down] = rows;
        let pos_m = [x as f32 + 0.5, y as f32 + 0.5];
        let luma_m = mid[x + 1];
        let mut luma_s = down[x + 1];
        let luma_e = mid[x + 2];
        let mut luma_n = up[x + 1];
        let luma_w = mid[x];
        let range_max = luma_s.max(luma_m).max(luma_e).max(luma_n).max(luma_w);
        let range_min = luma_s.min(luma_m).min(luma_e).min(luma_n).min(luma_w);
        let range = range_max - range_min;
        let luma_nw = up[x];
        let luma_se = down[x + 2];
        let luma_ne = up[x + 2];
        let luma_sw = down[x];
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
        let (pos_b, off) = if horz_span {
            ([pos_m[0], pos_m[1] + length_sign * 0.5], [1.0, 0.0])
        } else {
            ([pos_m[0] + length_sign * 0.5, pos_m[1]], [0.0, 1.0])
        };
        let luma_nn = if pair_n { luma_n + luma_m } else { luma_s + luma_m };
        let gradient_scaled = gradient * 0.25;
        let luma_mm = luma_m - luma_nn * 0.5;
        let ends = self.edge_search(pos_b, off, luma_nn * 0.5, gradient_scaled);
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
        let subpix_h = subpix_f * subpix_f * p.subpix;
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

/// A band task's buffers: the luma of the band's rows and one row above and below (rows
/// of `w + 2`, padded with the row's edge samples), and one row of edge flags.
#[derive(Default)]
struct BandScratch {
    luma: Vec<f32>,
    edge: Vec<u8>,
}

/// The filter's fused pass into `out`: per band of rows, `luma` of the band and its
/// one-row halo into the band's buffer, then per row the vectorised early-exit test, a
/// straight copy of the colour row, and FXAA proper for the pixels that passed the test.
/// Returns how many pixels passed it.
fn fused(
    src: [&[f32]; 3],
    w: usize,
    h: usize,
    hdr: bool,
    p: &Params,
    out: &mut Rgb,
    clock: &StageClock<2>,
) -> u64 {
    let stride = w + 2;
    par_bands(slices_mut(out), w, h, |s: &mut BandScratch, rows, [r, g, b]| {
        let lo = rows.start.saturating_sub(1);
        let hi = (rows.end + 1).min(h);
        let n = (hi - lo) * stride;
        if s.luma.len() < n {
            s.luma.resize(n, 0.0);
        }
        if s.edge.len() < w {
            s.edge.resize(w, 0);
        }
        let BandScratch { luma, edge } = s;
        let (luma, edge) = (&mut luma[..n], &mut edge[..w]);
        clock.time(0, || {
            for (y, row) in (lo..hi).zip(luma.chunks_exact_mut(stride)) {
                let c = src.map(|p| &p[y * w..(y + 1) * w]);
                if hdr {
                    luma_row::<true>(c, &mut row[1..w + 1]);
                } else {
                    luma_row::<false>(c, &mut row[1..w + 1]);
                }
                (row[0], row[w + 1]) = (row[1], row[w]);
            }
        });
        let luma = &*luma;
        let view = LumaView {
            band: luma,
            lo,
            hi,
            w,
            h,
            src,
            hdr,
        };
        let row_of = |y: usize| &luma[(y - lo) * stride..(y - lo + 1) * stride];
        clock.time(1, || {
            let mut passed = 0u64;
            for (k, y) in rows.enumerate() {
                let lrows = [row_of(y.saturating_sub(1)), row_of(y), row_of((y + 1).min(h - 1))];
                contrast_row(lrows[0], lrows[1], lrows[2], edge, p);
                let span = y * w..(y + 1) * w;
                let dst = [
                    &mut r[k * w..(k + 1) * w],
                    &mut g[k * w..(k + 1) * w],
                    &mut b[k * w..(k + 1) * w],
                ];
                for (d, s) in dst.into_iter().zip(src) {
                    d.copy_from_slice(&s[span.clone()]);
                }
                let row = k * w;
                for_each_set(edge, |x| {
                    passed += 1;
                    let pos = view.position(lrows, x, y, p);
                    let c = bilinear(src, w, h, pos[0], pos[1]);
                    (r[row + x], g[row + x], b[row + x]) = (c[0], c[1], c[2]);
                });
            }
            passed
        })
    })
}

impl Filter for Fxaa {
    fn name(&self) -> &'static str {
        Self::NAME
    }

    fn params(&self) -> Value {
        Value::Object(crate::pipeline::params::to_json(&self.params))
    }

    fn process(&mut self, frame: &Frame) -> Result<Output, FilterError> {
        check_needs(Self::NAME, Self::needs(), frame)?;
        let mut rec = Recorder::new();
        let (w, h) = (frame.width(), frame.height());
        // One vectorised read decides whether `repair` has anything to do; when it has,
        // `prepare` counts and repairs exactly.
        let repaired;
        let (src, hdr, counts) = match color_max(frame.color()).max() {
            Some(max) => {
                rec.skip(REPAIR_STAGE, Skip::CleanInput);
                let hdr = FrameFacts::new(frame, None, max).hdr;
                (
                    frame.color().each_ref().map(|p| p.data()),
                    hdr,
                    InputCounts::default(),
                )
            }
            None => {
                repaired = prepare(frame, Self::uses(), &mut rec)?;
                (repaired.color_slices(), repaired.facts.hdr, repaired.counts)
            }
        };
        let mut out: Rgb = self.scratch.planes(w, h);
        let p = &self.params;
        rec.run_fused(["luma", "fxaa"], |clock| {
            fused(src, w, h, hdr, p, &mut out, clock)
        });
        Ok(Output {
            color: out,
            record: rec.finish(Self::NAME, frame.meta.index, PixelCounts::default(), counts, 0),
        })
    }

    fn reset(&mut self) {}

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

    /// f64 reference of the search: each side walks on its own, sampling after every step
    /// but the last.
    #[allow(clippy::too_many_arguments)]
    fn search_f64(
        l: &[f64],
        w: usize,
        h: usize,
        b: [f64; 2],
        off: [f64; 2],
        avg: f64,
        g: f64,
        steps: &[f64],
    ) -> ([f64; 2], [f64; 2], f64, f64) {
        let bil = |x: f64, y: f64| crate::kernels::sample::tests::bilinear_f64(l, w, h, x, y);
        let side = |sign: f64| {
            let mut pos = [b[0] + sign * off[0] * steps[0], b[1] + sign * off[1] * steps[0]];
            let mut end = bil(pos[0], pos[1]) - avg;
            for (k, &s) in steps.iter().enumerate().skip(1) {
                if end.abs() >= g {
                    break;
                }
                pos = [pos[0] + sign * off[0] * s, pos[1] + sign * off[1] * s];
                if k + 1 < steps.len() {
                    end = bil(pos[0], pos[1]) - avg;
                }
            }
            (pos, end)
        };
        let (pn, en) = side(-1.0);
        let (pp, ep) = side(1.0);
        (pn, pp, en, ep)
    }

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
            let (pn, pp, en, ep) = search_f64(&l64, w, h, b, off, avg, g, &steps64);
            assert_eq!(got.pos_n.map(|v| v as f64), pn);
            assert_eq!(got.pos_p.map(|v| v as f64), pp);
            assert_eq!(got.end_n as f64, en);
            assert_eq!(got.end_p as f64, ep);
        }
    }

    /// Runs the fused pass and [`reference`] on `color` (already repaired) with `p` and
    /// compares them bit for bit (as values: -0 and +0 agree); returns how many pixels took
    /// the edge search.
    fn compare(color: &Rgb, p: &Params, what: &str) -> u64 {
        let (w, h) = color[0].size();
        let src = color.each_ref().map(|p| p.data());
        // As `prepare` decides it.
        let hdr = src.iter().any(|p| p.iter().any(|&v| v > 1.0));
        let want = reference(src, w, h, hdr, p);
        // NaN where nothing was written yet.
        let mut got: Rgb = std::array::from_fn(|_| Plane::filled(w, h, f32::NAN));
        let passed = fused(src, w, h, hdr, p, &mut got, &StageClock::default());
        for (k, (g, r)) in got.iter().zip(&want).enumerate() {
            Tolerance::EXACT
                .check_slices(&format!("{what}, plane {k}"), g.data(), r.data())
                .unwrap();
        }
        passed
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
