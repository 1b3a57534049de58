//! `fxaa`: FXAA 3.11 (Lottes 2011, "FXAA 3.11", NVIDIA whitepaper and `Fxaa3_11.h`), the PC
//! quality path with its default preset 12: the spatial baseline of the PHLM paper and of
//! the thesis. No history.
//!
//! Stages: `repair`, `luma` (perceptual luma: `sqrt` of the Rec. 709 luma, of the
//! tonemapped colour for HDR input; FXAA expects gamma-2 luma), `fxaa` (edge detection,
//! edge-end search along the edge, sub-pixel blend; the output is a bilinear fetch of the
//! input at the offset position).

use super::passes::{planes, slices_mut};
use crate::filter_params;
use crate::frame::{ChannelKind, ChannelSet, Frame, Plane, Rgb};
use crate::kernels::{bilinear, luma, tonemap};
use crate::pipeline::exec::for_rows;
use crate::pipeline::{
    check_needs, prepare, Filter, FilterError, FilterKind, Output, ParamKind, PixelCounts, Recorder,
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

/// The FXAA filter (stateless).
#[derive(Debug)]
pub struct Fxaa {
    params: Params,
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
        Fxaa { params }
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
        let inp = prepare(frame, Self::uses(), &mut rec)?;
        let (w, h) = (inp.width, inp.height);
        let hdr = inp.facts.hdr;
        let src = inp.color_slices();
        let luma_plane = rec.run("luma", || {
            let mut l = Plane::new(w, h);
            for_rows([l.data_mut()], w, |y, [row]| {
                for x in 0..w {
                    let i = y * w + x;
                    let c = [src[0][i], src[1][i], src[2][i]];
                    let c = if hdr { tonemap(c) } else { c.map(|v| v.min(1.0)) };
                    row[x] = luma(c).max(0.0).sqrt();
                }
            });
            l
        });
        let p = self.params.clone();
        let mut out: Rgb = planes(w, h);
        rec.run("fxaa", || {
            let l = luma_plane.data();
            for_rows(slices_mut(&mut out), w, |y, [r, g, b]| {
                for x in 0..w {
                    let pos = fxaa_position(l, w, h, x, y, &p);
                    let c = bilinear(src, w, h, pos[0], pos[1]);
                    (r[x], g[x], b[x]) = (c[0], c[1], c[2]);
                }
            });
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

    fn reset(&mut self) {}

    fn state_bytes(&self) -> usize {
        0
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::filters::create;
    use crate::pipeline::params::parse_assignments;
    use crate::rng::SplitMix64;

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
