//! The scalar reference of `phlm`: whole-plane passes over planar state, exactly as the
//! filter was first written (Algorithm 1 of Iglesias-Guitian et al. 2016 pixel by pixel).
//! The fused band kernel (`kernel.rs`) must give the same output (the tests compare
//! them frame by frame); this stays the readable statement of what the filter computes.

use super::super::passes::{
    dilate_motion, dilate_skip, from_working, on_screen, reference_filter, reproject_skip, slices_mut,
    to_ycocg, tonemap_stage, Conversion, FrameContext, FrameResult, TemporalState,
};
use super::rls::{self, D, P_LEN};
use super::{
    convert_state, depth_share, fail_relax, feature, fetch, fetch_model, history_depth, jump, miss, ramp,
    strikes, Counts, From, Model, Params, Phlm, TestBox, BETA, DEPTH, R, S, STATE_PLANES, V, Z,
};
use crate::frame::{Frame, Plane, Rgb};
use crate::kernels::{clip_toward_point, for_each_row_stats, rgb_to_ycocg, variance_box, ycocg_to_rgb};
use crate::pipeline::exec::{for_rows, par_rows};
use crate::pipeline::FilterError;

reference_filter!(
    /// `phlm` computed stage by stage over whole planes.
    ReferencePhlm, Phlm, effective, |_p| TemporalState::with_conversion(STATE_PLANES, Conversion::Custom(convert_state))
);

/// One frame's stages, from `tonemap` to `untonemap`, with the parameters `p`.
fn stages(p: &Params, _frame: &Frame, ctx: FrameContext) -> Result<FrameResult, FilterError> {
    let (inp, rec, has_history, read, next, scratch) = ctx.into_parts();
    let (w, h) = (inp.width, inp.height);
    let working = tonemap_stage(rec, &inp, scratch);
    let rgb = working.each_ref().map(|p| p.data());

    let ycocg: Rgb = rec.run("ycocg", || to_ycocg(&working, scratch));
    let cur = ycocg.each_ref().map(|p| p.data());

    // Previous positions (pixel units); NaN marks off screen.
    let skip = reproject_skip(&inp, has_history);
    // Velocity dilation (with depth): the motion every later stage reads.
    let dilated: Option<[Plane<f32>; 2]> = rec.stage("dilate", dilate_skip(&inp, &skip, p.dilation), || {
        dilate_motion(
            inp.motion.as_deref().expect("required"),
            inp.depth.as_deref().expect("required"),
            scratch,
        )
    });
    let motion = dilated
        .as_ref()
        .or(inp.motion.as_deref())
        .map(|m| m.each_ref().map(|p| p.data()));
    let positions: Option<[Plane<f32>; 2]> = rec.stage("reproject", skip, || {
        let m = motion.expect("required");
        let mut out: [Plane<f32>; 2] = scratch.planes(w, h);
        for_rows(slices_mut(&mut out), w, |y, [px, py]| {
            for x in 0..w {
                let i = y * w + x;
                let (qx, qy) = (x as f32 + 0.5 + m[0][i], y as f32 + 0.5 + m[1][i]);
                (px[x], py[x]) = if on_screen(qx, qy, w, h) {
                    (qx, qy)
                } else {
                    (f32::NAN, f32::NAN)
                };
            }
        });
        out
    });
    let pos = positions.as_ref().map(|p| p.each_ref().map(|p| p.data()));

    let src: [&[f32]; STATE_PLANES] = std::array::from_fn(|k| read[k].data());
    let from = |i: usize| -> From {
        if !has_history {
            return From::Nothing;
        }
        match pos {
            None => From::Here(i),
            Some([px, _]) if px[i].is_nan() => From::Nothing,
            Some([px, py]) => From::At(px[i], py[i]),
        }
    };
    let src_z: [&[f32]; 3] = std::array::from_fn(|k| src[Z + k]);
    let src_model: [&[f32]; Z] = std::array::from_fn(|k| src[k]);
    // The count of failed box tests, the speed and the depth, read as R is (bilinear
    // unless `nearest`).
    let src_strikes: [&[f32]; 3] = [src[S], src[V], src[DEPTH]];
    let depth = inp.depth.as_deref().map(|d| d.data());
    // This frame's 3x3 range of history depths around pixel (x, y), edges clamped.
    let depth_range = |d: &[f32], x: usize, y: usize| {
        let (mut lo, mut hi) = (f32::INFINITY, f32::NEG_INFINITY);
        for yy in [y.saturating_sub(1), y, (y + 1).min(h - 1)] {
            for xx in [x.saturating_sub(1), x, (x + 1).min(w - 1)] {
                let v = history_depth(d[yy * w + xx]);
                (lo, hi) = (lo.min(v), hi.max(v));
            }
        }
        (lo, hi)
    };

    // Feature (sec. 5.1): written into next's z planes.
    {
        let (_, z_next) = next.split_at_mut(Z);
        let zrows: [&mut [f32]; 3] = {
            let mut it = z_next.iter_mut();
            std::array::from_fn(|_| it.next().expect("z planes").data_mut())
        };
        rec.run("feature", || {
            for_rows(zrows, w, |y, [zr, zg, zb]| {
                for_each_row_stats(cur, w, h, y, |x, stats| {
                    let i = y * w + x;
                    let input = [rgb[0][i], rgb[1][i], rgb[2][i]];
                    let f = from(i);
                    let z = if matches!(f, From::Nothing) {
                        // Sec. 6: "Our temporal feature z is initialized with the input image".
                        input
                    } else {
                        let prev = fetch(src_z, w, h, f, p.model_fetch);
                        if inp.is_invalid(i) {
                            prev
                        } else {
                            let v = motion.map_or(0.0, |m| (m[0][i] * m[0][i] + m[1][i] * m[1][i]).sqrt());
                            feature::accumulate(
                                prev,
                                ycocg_to_rgb(stats.mean),
                                stats.min[0],
                                stats.max[0],
                                v,
                                p,
                            )
                        }
                    };
                    (zr[x], zg[x], zb[x]) = (z[0], z[1], z[2]);
                });
            });
        });
    }

    // Algorithm 1.
    let mut out: Rgb = scratch.planes(w, h);
    let hi = super::super::passes::output_ceiling(&inp.facts);
    // The prior R0 = I / p0 that forgetting relaxes toward (rls module docs).
    let prior = 1.0 / p.p0;
    let counts: Counts = rec.run("model", || {
        let (model_next, z_next) = next.split_at_mut(Z);
        let (z_next, sv_next) = z_next.split_at_mut(3);
        let (s_next, vd_next) = sv_next.split_at_mut(1);
        let (v_next, d_next) = vd_next.split_at_mut(1);
        let zs: [&[f32]; 3] = std::array::from_fn(|k| z_next[k].data());
        let [o0, o1, o2] = slices_mut(&mut out);
        let mut it = model_next.iter_mut();
        let mrows: [&mut [f32]; Z] = std::array::from_fn(|_| it.next().expect("model planes").data_mut());
        let mut all: Vec<&mut [f32]> = mrows.into_iter().collect();
        all.extend([
            o0,
            o1,
            o2,
            s_next[0].data_mut(),
            v_next[0].data_mut(),
            d_next[0].data_mut(),
        ]);
        // Rows Z..Z + 3 of this pass are the output planes, rows Z + 3 to Z + 5 the
        // count, the speed and the depth.
        let rows: [&mut [f32]; Z + 6] = all.try_into().expect("Z + 6 planes");
        par_rows(rows, w, |y, mut r| {
            let mut c = Counts::default();
            for_each_row_stats(cur, w, h, y, |x, stats| {
                let i = y * w + x;
                let input = [rgb[0][i], rgb[1][i], rgb[2][i]];
                let z = [zs[0][i], zs[1][i], zs[2][i]];
                let f = from(i);
                let mut m = match f {
                    From::Nothing => {
                        c.pixels.history_reset += 1;
                        if has_history {
                            c.offscreen += 1;
                        }
                        Model::reset(input, z, p.p0)
                    }
                    _ => Model::from_state(&fetch_model(src_model, w, h, f, p.model_fetch), z),
                };
                let x_feat = m.x();
                let [s_prev, v_prev, d_prev] = fetch(src_strikes, w, h, f, p.model_fetch);
                let v = motion.map_or(0.0, |m| (m[0][i] * m[0][i] + m[1][i] * m[1][i]).sqrt());
                let mut s = strikes(s_prev, 0.0, p.clip_after).0;
                if !inp.is_invalid(i) {
                    // Lines 12-19: predict; outside the 3x3 box -> clip toward y and reset.
                    let pred = rls::predict(&m.beta, &x_feat);
                    let (lo, hi) = match p.test_box {
                        TestBox::Minmax => (stats.min, stats.max),
                        TestBox::Variance => variance_box(stats, p.test_gamma),
                    };
                    let pred_ycocg = rgb_to_ycocg(pred);
                    let (clipped, moved) =
                        clip_toward_point(pred_ycocg, [cur[0][i], cur[1][i], cur[2][i]], lo, hi);
                    // A failure clips once it persists (`clip_after`, [`strikes`]); how
                    // much of one it is, [`miss`] and [`jump`].
                    let depth_jump = match depth {
                        Some(d) if p.depth_jump > 0.0 => {
                            let (dlo, dhi) = depth_range(d, x, y);
                            1.0 + depth_share(dlo, dhi, d_prev, v, p.depth_jump)
                        }
                        _ => 1.0,
                    };
                    let hit = miss(pred_ycocg, clipped, moved, ramp(lo, hi, p))
                        * jump(v, v_prev, p.speed_jump).max(depth_jump);
                    let (count, clip) = strikes(s_prev, hit, p.clip_after);
                    s = count;
                    if clip {
                        c.pixels.history_clipped += 1;
                        m.clip(pred, ycocg_to_rgb(clipped), p);
                    } else if hit > 0.0 {
                        let keep = fail_relax(hit, p.fail_keep);
                        if keep != 1.0 {
                            m.relax(keep, p.clip_p);
                        }
                    }
                    // Lines 19-21: error of the (possibly reset) model, RLS update.
                    let pred = rls::predict(&m.beta, &x_feat);
                    let e = [0, 1, 2].map(|k| input[k] - pred[k]);
                    let lambda = super::forgetting(v, p);
                    match rls::update_information(&mut m.beta, &mut m.r, &x_feat, e, lambda, prior) {
                        Some(trace) => c.max_trace = c.max_trace.max(trace),
                        None => {
                            c.repaired += 1;
                            m = Model::reset(input, z, p.p0);
                        }
                    }
                    if !m.beta.iter().flatten().all(|v| v.is_finite()) {
                        c.repaired += 1;
                        m = Model::reset(input, z, p.p0);
                    }
                }
                // Line 22: the output.
                let o = rls::predict(&m.beta, &x_feat);
                for ch in 0..3 {
                    for j in 0..D {
                        r[BETA + ch * D + j][x] = m.beta[ch][j];
                    }
                }
                for k in 0..P_LEN {
                    r[R + k][x] = m.r[k];
                }
                for ch in 0..3 {
                    r[Z + ch][x] = o[ch].clamp(0.0, hi);
                }
                r[Z + 3][x] = s;
                r[Z + 4][x] = v;
                r[Z + 5][x] = depth.map_or(0.0, |d| history_depth(d[i]));
            });
            c
        })
    });

    rec.stage("untonemap", inp.facts.tonemap(), || from_working(&mut out, true));

    scratch.recycle(ycocg);
    scratch.recycle(positions.into_iter().flatten());
    scratch.recycle(dilated.into_iter().flatten());
    if let std::borrow::Cow::Owned(w) = working {
        scratch.recycle(w);
    }
    Ok(counts.result(out))
}
