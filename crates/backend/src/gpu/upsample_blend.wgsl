// `upsample`: the blend pass (see upsample.wgsl, which precedes this file).

// temporal::filter_gradients: the current and three previous gradients weighted
// GRADIENT_WEIGHTS (Herzog et al. 2010, sec. 3.4).
fn filter_gradients(g: vec4<f32>) -> f32 {
    return (GW0 * g.x + GW1 * g.y + GW2 * g.z + GW3 * g.w) / (GW0 + GW1 + GW2 + GW3);
}

// The reference's `gradients`, last loops: the temporal filter of pixel q's gradients,
// of their magnitudes and of the signed values (unknown past gradients count as 1).
fn filtered(q: u32) -> vec2<f32> {
    var past = vec3<f32>(1.0);
    if has(FLAG_HISTORY) {
        past = vec3<f32>(rp_at(q, G1), rp_at(q, G1 + 1u), rp_at(q, G1 + 2u));
    }
    let g = vec4<f32>(now[q], past);
    return vec2<f32>(filter_gradients(abs(g)), filter_gradients(g));
}

// The confidence at (x, y): both filtered gradients averaged over the box of 2r + 1
// pixels, r = max(1, factor / 2), in the reference's order; temporal::cancelled and
// temporal::confidence (Herzog et al. 2010, eq. 8).
fn confidence_at(x: u32, y: u32) -> f32 {
    let r = i32(max(1u, P.factor / 2u));
    var sum = 0.0;
    var ssum = 0.0;
    var n = 0u;
    for (var dy = -r; dy <= r; dy++) {
        let yy = i32(y) + dy;
        if yy < 0 || yy >= i32(P.height) {
            continue;
        }
        for (var dx = -r; dx <= r; dx++) {
            let xx = i32(x) + dx;
            if xx < 0 || xx >= i32(P.width) {
                continue;
            }
            let f = filtered(u32(yy) * P.width + u32(xx));
            sum += f.x;
            ssum += f.y;
            n += 1u;
        }
    }
    let m = sum / f32(n);
    let s = ssum / f32(n);
    let g = m - P.gradient_cancel * (m - abs(s));
    let t = 1.0 - min(g / P.gradient_scale, 1.0);
    if t > 0.0 {
        return t * t;
    }
    return 0.0;
}

fn write_out(i: u32, v: vec3<f32>) {
    let n = plane_len();
    out[i] = v.x;
    out[n + i] = v.y;
    out[2u * n + i] = v.z;
}

fn write_colour_texel(i: u32, v: vec3<f32>) {
    let at = P.texel * i;
    next[at + R] = v.x;
    next[at + R + 1u] = v.y;
    next[at + R + 2u] = v.z;
}

fn depth_or_zero(i: u32) -> f32 {
    if has(FLAG_DEPTH) {
        return depth_at(i);
    }
    return 0.0;
}

fn id_or_zero(i: u32) -> f32 {
    if has(FLAG_IDS) {
        return id_at(i);
    }
    return 0.0;
}

// `spatiotemporal` (Herzog et al. 2010): the gather at the kernel width the confidence
// sets, blended with the history weighted by its accumulated weight, the confidence and
// the share of valid taps (eq. 6-7); the next texel holds the blend, the decayed weight,
// depth and id, the gradients and the lumas of the last two shaded samples.
fn spatiotemporal(x: u32, y: u32) {
    let i = y * P.width + x;
    let c = confidence_at(x, y);
    let sigma = P.kernel_sharp + (1.0 - c) * (P.kernel_wide - P.kernel_sharp);
    let s = gather(x, y, sigma);
    let history = has(FLAG_HISTORY);
    var prev = vec3<f32>(0.0);
    var wh = 0.0;
    var pg = vec2<f32>(1.0);
    if history {
        prev = vec3<f32>(rp_at(i, R), rp_at(i, R + 1u), rp_at(i, R + 2u));
        wh = c * rp_at(i, W) * rp_at(i, P.texel);
        pg = vec2<f32>(rp_at(i, G1), rp_at(i, G1 + 1u));
    }
    let total = s.weight + wh;
    var v = vec3<f32>(0.0);
    if total > 0.0 {
        v = vec3<f32>(
            (s.sum.x + wh * prev.x) / total,
            (s.sum.y + wh * prev.y) / total,
            (s.sum.z + wh * prev.z) / total,
        );
    }
    write_out(i, v);
    write_colour_texel(i, v);
    let at = P.texel * i;
    next[at + W] = P.decay * total;
    next[at + DEPTH] = depth_or_zero(i);
    next[at + ID] = id_or_zero(i);
    next[at + G1] = now[i];
    next[at + G1 + 1u] = pg.x;
    next[at + G1 + 2u] = pg.y;
    // The last shaded sample's luma and the one before it.
    let own = own_sample(x, y);
    var lk = vec4<f32>(0.0);
    if own.found && history {
        lk = vec4<f32>(luma_of(color_at(own.k)), 1.0, rp_at(i, LK), rp_at(i, LK + 1u));
    } else if own.found {
        lk = vec4<f32>(luma_of(color_at(own.k)), 1.0, 0.0, 0.0);
    } else if history {
        lk = vec4<f32>(rp_at(i, LK), rp_at(i, LK + 1u), rp_at(i, LK + 2u), rp_at(i, LK + 3u));
    }
    next[at + LK] = lk.x;
    next[at + LK + 1u] = lk.y;
    next[at + LK + 2u] = lk.z;
    next[at + LK + 3u] = lk.w;
}

// `temporal` (Herzog et al. 2010, eq. 3-4): a shaded pixel takes its sample, another its
// valid reprojected history, a hole the spatial estimate (counted as reset).
fn temporal(x: u32, y: u32) {
    let i = y * P.width + x;
    let own = own_sample(x, y);
    var v: vec3<f32>;
    if own.found {
        v = color_at(own.k);
    } else if has(FLAG_HISTORY) && rp_at(i, P.texel) >= 0.5 {
        v = vec3<f32>(rp_at(i, R), rp_at(i, R + 1u), rp_at(i, R + 2u));
    } else {
        count(C_RESET);
        v = mean(gather(x, y, P.kernel_wide));
    }
    write_out(i, v);
    write_colour_texel(i, v);
    let at = P.texel * i;
    next[at + T_DEPTH] = depth_or_zero(i);
    next[at + T_ID] = id_or_zero(i);
}

// `taa` (scaling-aware accumulation): the samples splatted with the Gaussian of the
// table, the blend weight scaled by the best sample's, the history clamped to the
// samples' min/max box (counted as clipped where that moved it).
fn taa(x: u32, y: u32) {
    let i = y * P.width + x;
    var sum = vec3<f32>(0.0);
    var wsum = 0.0;
    var beta = 0.0;
    var lo = vec3<f32>(F32_MAX);
    var hi = vec3<f32>(-F32_MAX);
    let a0 = cell(x, P.phase_x);
    let b0 = cell(y, P.phase_y);
    for (var b = b0 - 1; b <= b0 + 1; b++) {
        for (var a = a0 - 1; a <= a0 + 1; a++) {
            let s = near_sample(x, y, a, b);
            if s.found {
                let wt = P.table[s.o];
                beta = max(beta, wt);
                wsum += wt;
                let v = color_at(s.k);
                sum = vec3<f32>(sum.x + wt * v.x, sum.y + wt * v.y, sum.z + wt * v.z);
                lo = min(lo, v);
                hi = max(hi, v);
            }
        }
    }
    var up = vec3<f32>(0.0);
    if wsum > 0.0 {
        up = vec3<f32>(sum.x / wsum, sum.y / wsum, sum.z / wsum);
    }
    var n = 0.0;
    if has(FLAG_HISTORY) && rp_at(i, P.texel) > 0.0 && wsum > 0.0 {
        n = rp_at(i, W);
    }
    var v = up;
    var next_count = beta;
    if n > 0.0 {
        let h = vec3<f32>(rp_at(i, R), rp_at(i, R + 1u), rp_at(i, R + 2u));
        let hv = min(max(h, lo), hi);
        if any(hv != h) {
            count(C_CLIPPED);
        }
        let a = beta * max(P.taa_alpha, 1.0 / (n + 1.0));
        v = a * up + (1.0 - a) * hv;
        next_count = min(n + beta, TAA_MAX_COUNT);
    }
    write_out(i, v);
    write_colour_texel(i, v);
    next[P.texel * i + W] = next_count;
}

// `spatial`: the joint-bilateral gather alone, at `kernel_wide`.
fn spatial(x: u32, y: u32) {
    write_out(y * P.width + x, mean(gather(x, y, P.kernel_wide)));
}

@compute @workgroup_size(WORKGROUP, WORKGROUP)
fn blend_pass(@builtin(global_invocation_id) gid: vec3<u32>) {
    if !inside(gid) {
        return;
    }
    switch P.method {
        case M_SPATIOTEMPORAL: {
            spatiotemporal(gid.x, gid.y);
        }
        case M_TEMPORAL: {
            temporal(gid.x, gid.y);
        }
        case M_TAA: {
            taa(gid.x, gid.y);
        }
        default: {
            spatial(gid.x, gid.y);
        }
    }
}
