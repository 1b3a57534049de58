//! `taa`: the industry TAA baseline (Karis 2014, "High quality temporal supersampling";
//! Salvi 2016, "An excursion in temporal supersampling"; survey 003; the outline Bevy's TAA
//! and FSR2's accumulate pass follow).
//!
//! Stages per frame:
//! 1. `repair`: non-finite and negative input replaced and counted.
//! 2. `tonemap`: the reversible tonemap `c / (1 + max c)` (HDR input only).
//! 3. `ycocg`: the working colour in YCoCg, where the clip box is built.
//! 4. `dilate`: velocity dilation (motion of the nearest pixel of the 3x3; needs depth).
//! 5. `reproject`: history fetched at `p + motion` with Catmull-Rom (or bilinear); a pixel
//!    whose previous position is off screen restarts. Left out when nothing moves.
//! 6. `depth_reject` (optional): history whose depth disagrees with the current depth by
//!    more than `depth_rejection` (relative) restarts.
//! 7. `resolve`: 3x3 min/max and variance box (mean +- gamma sigma) in YCoCg; history
//!    clipped toward the box centre; blend with `alpha` (raised to 1/(n+1) for young
//!    history, so a restarted pixel converges as a running mean) and Karis's luminance
//!    weights.
//! 8. `sharpen` (optional), 9. `untonemap` (HDR input only).
//!
//! State: history Y, Co, Cg and sample count (+ depth with depth rejection), double-buffered.

use super::passes::{
    from_working, on_screen, sharpen, slices_mut, to_working, to_ycocg, Reprojection, TemporalState,
};
use crate::filter_params;
use crate::frame::{ChannelKind, ChannelSet, Frame, Plane, Rgb};
use crate::kernels::{
    bilinear, catmull_rom, clip_toward_center, for_each_row_stats, variance_box, ycocg_to_rgb,
};
use crate::pipeline::exec::{for_rows, par_rows};
use crate::pipeline::{
    check_needs, prepare, Filter, FilterError, FilterKind, Output, ParamKind, PixelCounts, Recorder, Skip,
};
use serde::{Deserialize, Serialize};
use serde_json::Value;

/// How history is resampled at its reprojected position.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum HistoryFilter {
    /// 5-tap Catmull-Rom (sharp; Karis 2014).
    CatmullRom,
    /// Bilinear (cheaper, blurs history a little every frame that moves).
    Bilinear,
}

filter_params! {
    /// Parameters of `taa`.
    pub struct Params {
        alpha: f32 = DEFAULT_ALPHA,
            ParamKind::Float { min: 0.01, max: 1.0 },
            "weight of the current frame (Karis 2014: 0.1). Lower: smoother, more supersampling, more ghosting and lag; higher: sharper response, more jitter shimmer";
        gamma: f32 = DEFAULT_GAMMA,
            ParamKind::Float { min: 0.25, max: 4.0 },
            "variance-box half-width in sigmas (Salvi 2016; survey: 0.75-1.25). Lower: less ghosting, more flicker; higher: stabler, more ghosting";
        history_filter: HistoryFilter = HistoryFilter::CatmullRom,
            ParamKind::Choice { options: &["catmull_rom", "bilinear"], },
            "history resampling: catmull_rom keeps moving history sharp; bilinear is cheaper and blurs it";
        dilation: bool = true,
            ParamKind::Bool,
            "take the motion of the nearest pixel of the 3x3 (needs depth): moving edges carry their history";
        luminance_weighting: bool = true,
            ParamKind::Bool,
            "weight samples by 1/(1 + luma) (Karis 2014): fewer bright flickering pixels, a slightly darker bias";
        depth_rejection: f32 = 0.0,
            ParamKind::Float { min: 0.0, max: 10.0 },
            "restart history whose reprojected depth differs from the current by more than this fraction (0 = off); catches disocclusion the colour box misses, can reject on thin geometry";
        sharpen: f32 = 0.0,
            ParamKind::Float { min: 0.0, max: 4.0 },
            "strength of the output cross sharpen (0 = off; 1 = thesis eq. 4.17); counters the blur of resampling, amplifies noise";
    }
}

/// Blend weight of the current frame: 0.1 (Karis 2014; DESIGN.md "alpha 0.1 default").
pub const DEFAULT_ALPHA: f32 = 0.1;
/// Variance-box width: 1.0 sigma (Salvi 2016; the survey 003 gives 0.75-1.25).
pub const DEFAULT_GAMMA: f32 = 1.0;
/// Sample counts are held at this many frames: past 1/alpha the blend weight is `alpha`
/// anyway, and a bounded count keeps the state bounded on endless still scenes.
const MAX_COUNT: f32 = 255.0;

/// History planes.
const Y: usize = 0;
const CO: usize = 1;
const CG: usize = 2;
const COUNT: usize = 3;
const DEPTH: usize = 4;

/// The TAA filter with its history.
#[derive(Debug)]
pub struct Taa {
    params: Params,
    hist: TemporalState,
}

impl FilterKind for Taa {
    const NAME: &'static str = "taa";
    const SUMMARY: &'static str =
        "industry TAA: velocity dilation, Catmull-Rom history, YCoCg variance clipping, luminance-weighted blend";
    const STAGES: &'static [&'static str] = &[
        "repair",
        "tonemap",
        "ycocg",
        "dilate",
        "reproject",
        "depth_reject",
        "resolve",
        "sharpen",
        "untonemap",
    ];
    type Params = Params;
    fn needs() -> ChannelSet {
        ChannelSet::of(&[ChannelKind::Color])
    }
    fn uses() -> ChannelSet {
        ChannelSet::of(&[ChannelKind::Color, ChannelKind::Motion, ChannelKind::Depth])
    }
    fn state_bytes_per_pixel(p: &Params) -> usize {
        2 * 4 * Self::history_planes(p)
    }
    fn new(params: Params) -> Self {
        Taa {
            hist: TemporalState::new(Self::history_planes(&params), true),
            params,
        }
    }
}

impl Taa {
    fn history_planes(p: &Params) -> usize {
        if p.depth_rejection > 0.0 {
            5
        } else {
            4
        }
    }
}

impl Filter for Taa {
    fn name(&self) -> &'static str {
        Self::NAME
    }

    fn params(&self) -> Value {
        Value::Object(crate::pipeline::params::to_json(&self.params))
    }

    fn process(&mut self, frame: &Frame) -> Result<Output, FilterError> {
        check_needs(Self::NAME, Self::needs(), frame)?;
        let p = self.params.clone();
        let mut rec = Recorder::new();
        let inp = prepare(frame, Self::uses(), &mut rec)?;
        let (w, h) = (inp.width, inp.height);
        let facts = inp.facts;
        let hdr = facts.hdr;
        let has_history = self.hist.begin(frame, hdr)?;
        let scratch = &mut self.hist.scratch;

        let working = rec
            .stage("tonemap", facts.tonemap(), || {
                to_working(&inp.color, true, scratch)
            })
            .unwrap_or(std::borrow::Cow::Borrowed(&*inp.color));

        let ycocg: Rgb = rec.run("ycocg", || to_ycocg(&working, scratch));

        let no_history = (!has_history).then_some(Skip::NoHistory);
        let reprojection = Reprojection::plan(&mut rec, &inp, has_history, p.dilation, scratch);
        let n_hist = self.hist.buffer.read().len();
        let (read, next) = self.hist.buffer.split();
        let reprojected: Option<Vec<Plane<f32>>> = rec.stage("reproject", reprojection.skip.clone(), || {
            let m = reprojection.motion(&inp);
            let src: Vec<&[f32]> = read.iter().map(|p| p.data()).collect();
            let mut out: Vec<Plane<f32>> = (0..n_hist).map(|_| scratch.plane(w, h)).collect();
            let filter = p.history_filter;
            let rows = {
                let mut it = out.iter_mut();
                let a: [&mut [f32]; 4] = std::array::from_fn(|_| it.next().expect("4 planes").data_mut());
                (a, it.next().map(|p| p.data_mut()))
            };
            let (four, depth_out) = rows;
            // Depth (when kept) is resampled bilinearly in a second, cheap loop below.
            for_rows(four, w, |y, [hy, hco, hcg, hn]| {
                for x in 0..w {
                    let i = y * w + x;
                    let px = x as f32 + 0.5 + m[0][i];
                    let py = y as f32 + 0.5 + m[1][i];
                    if !on_screen(px, py, w, h) {
                        hn[x] = 0.0;
                        continue;
                    }
                    let c = match filter {
                        HistoryFilter::CatmullRom => catmull_rom([src[Y], src[CO], src[CG]], w, h, px, py),
                        HistoryFilter::Bilinear => bilinear([src[Y], src[CO], src[CG]], w, h, px, py),
                    };
                    [hy[x], hco[x], hcg[x]] = c;
                    hn[x] = bilinear([src[COUNT]], w, h, px, py)[0];
                }
            });
            if let Some(d) = depth_out {
                for_rows([d], w, |y, [row]| {
                    for x in 0..w {
                        let i = y * w + x;
                        row[x] = bilinear(
                            [src[DEPTH]],
                            w,
                            h,
                            x as f32 + 0.5 + m[0][i],
                            y as f32 + 0.5 + m[1][i],
                        )[0];
                    }
                });
            }
            out
        });
        let hist: Vec<&[f32]> = match &reprojected {
            Some(r) => r.iter().map(|p| p.data()).collect(),
            None => read.iter().map(|p| p.data()).collect(),
        };

        let mut pixels = PixelCounts::default();
        let reject: Option<Vec<bool>> = rec.stage(
            "depth_reject",
            (p.depth_rejection <= 0.0)
                .then_some(Skip::Disabled {
                    param: "depth_rejection",
                })
                .or_else(|| no_history.clone())
                .or_else(|| inp.require(ChannelKind::Depth)),
            || {
                let d = inp.depth.as_deref().expect("required").data();
                let prev = hist[DEPTH];
                d.iter()
                    .zip(prev)
                    .map(|(&d, &dp)| (dp - d).abs() > p.depth_rejection * d.abs().max(1e-6))
                    .collect()
            },
        );
        if let Some(r) = &reject {
            pixels.history_rejected = r.iter().filter(|&&b| b).count() as u64;
        }

        let mut out: Rgb = scratch.planes(w, h);
        let counts = rec.run("resolve", || {
            let cur = ycocg.each_ref().map(|p| p.data());
            let [o0, o1, o2] = slices_mut(&mut out);
            let mut it = next.iter_mut();
            let n4: [&mut [f32]; 4] = std::array::from_fn(|_| it.next().expect("4 planes").data_mut());
            let [n0, n1, n2, n3] = n4;
            let counts = par_rows(
                [o0, o1, o2, n0, n1, n2, n3],
                w,
                |y, [or, og, ob, ny, nco, ncg, nn]| {
                    let mut c = PixelCounts::default();
                    for_each_row_stats(cur, w, h, y, |x, stats| {
                        let i = y * w + x;
                        let current = [cur[0][i], cur[1][i], cur[2][i]];
                        let n = if has_history && !reject.as_ref().is_some_and(|r| r[i]) {
                            hist[COUNT][i]
                        } else {
                            0.0
                        };
                        let (value, count) = if n < 0.5 {
                            c.history_reset += 1;
                            (current, 1.0)
                        } else if inp.is_invalid(i) {
                            // No usable sample here this frame: keep the history as it is.
                            ([hist[Y][i], hist[CO][i], hist[CG][i]], n)
                        } else {
                            let (lo, hi) = variance_box(stats, p.gamma);
                            let (h, moved) =
                                clip_toward_center([hist[Y][i], hist[CO][i], hist[CG][i]], lo, hi);
                            c.history_clipped += moved as u64;
                            let a = p.alpha.max(1.0 / (n + 1.0));
                            let (wc, wh) = if p.luminance_weighting {
                                (a / (1.0 + current[0].max(0.0)), (1.0 - a) / (1.0 + h[0].max(0.0)))
                            } else {
                                (a, 1.0 - a)
                            };
                            let k = 1.0 / (wc + wh);
                            let v = [0, 1, 2].map(|j| (wc * current[j] + wh * h[j]) * k);
                            (v, (n + 1.0).min(MAX_COUNT))
                        };
                        [ny[x], nco[x], ncg[x]] = value;
                        nn[x] = count;
                        let rgb = ycocg_to_rgb(value);
                        (or[x], og[x], ob[x]) = (rgb[0].max(0.0), rgb[1].max(0.0), rgb[2].max(0.0));
                    });
                    c
                },
            );
            if let (Some(d), Some(nd)) = (inp.depth.as_deref(), next.get_mut(DEPTH)) {
                nd.data_mut().copy_from_slice(d.data());
            }
            counts
        });
        pixels.history_reset += counts.history_reset;
        pixels.history_clipped += counts.history_clipped;

        if let Some(s) = rec.stage(
            "sharpen",
            (p.sharpen <= 0.0).then_some(Skip::Disabled { param: "sharpen" }),
            || sharpen(&out, p.sharpen, hdr, scratch),
        ) {
            scratch.recycle(std::mem::replace(&mut out, s));
        }
        rec.stage("untonemap", facts.tonemap(), || from_working(&mut out, true));

        scratch.recycle(ycocg);
        scratch.recycle(reprojection.dilated.into_iter().flatten());
        scratch.recycle(reprojected.into_iter().flatten());
        if let std::borrow::Cow::Owned(w) = working {
            scratch.recycle(w);
        }
        let bytes = self.hist.finish(hdr);
        Ok(Output {
            color: out,
            record: rec.finish(Self::NAME, frame.meta.index, pixels, inp.counts, bytes),
        })
    }

    fn reset(&mut self) {
        self.hist.buffer.reset();
    }

    fn recycle(&mut self, planes: Rgb) {
        self.hist.scratch.recycle(planes);
    }

    fn state_bytes(&self) -> usize {
        self.hist.buffer.bytes()
    }
}
