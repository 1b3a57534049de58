// `upsample`: the reprojection pass (see upsample.wgsl, which precedes this file).

// temporal::reproject at pixel (x, y): the history texel at p + motion, bilinear over the
// taps that pass the validity test (all on-screen taps without FLAG_VALIDITY),
// renormalised; then the taps' weight and the part of it kept for sub-pixel surfaces.
// A pixel with less than half of the weight counts as lost (C_LOST).
fn reproject_pixel(x: u32, y: u32) {
    let i = y * P.width + x;
    var ic = ID;
    var dc = DEPTH;
    if P.method == M_TEMPORAL {
        ic = T_ID;
        dc = T_DEPTH;
    }
    let m = motion_at(i);
    let px = f32(x) + 0.5 + m.x;
    let py = f32(y) + 0.5 + m.y;
    var acc: array<f32, MAX_TEXEL>;
    var total = 0.0;
    var kept = 0.0;
    // passes::on_screen (false for NaN).
    if px >= 0.0 && px <= f32(P.width) && py >= 0.0 && py <= f32(P.height) {
        let fx = px - 0.5;
        let fy = py - 0.5;
        let x0 = floor(fx);
        let y0 = floor(fy);
        let tx = fx - x0;
        let ty = fy - y0;
        let xa = clamp_index(x0, P.width);
        let xb = clamp_index(x0 + 1.0, P.width);
        let ya = clamp_index(y0, P.height) * P.width;
        let yb = clamp_index(y0 + 1.0, P.height) * P.width;
        let taps = array<u32, 4>(ya + xa, ya + xb, yb + xa, yb + xb);
        let weights = array<f32, 4>(
            (1.0 - tx) * (1.0 - ty),
            tx * (1.0 - ty),
            (1.0 - tx) * ty,
            tx * ty,
        );
        for (var k = 0; k < 4; k++) {
            let t = taps[k];
            var wt = weights[k];
            if !(wt > 0.0) {
                continue;
            }
            var kind = TAP_PASSES;
            if has(FLAG_VALIDITY) {
                kind = tap_kind(i, t, ic, dc);
            }
            if kind == TAP_REJECTED {
                continue;
            }
            if kind == TAP_SUB_PIXEL {
                wt = wt * P.subpixel;
                kept += wt;
            }
            total += wt;
            for (var c = 0u; c < P.texel; c++) {
                acc[c] += wt * hist_at(t, c);
            }
        }
    }
    var inv = 0.0;
    if total > 0.0 {
        inv = 1.0 / total;
    }
    let at = (P.texel + 2u) * i;
    for (var c = 0u; c < P.texel; c++) {
        rp[at + c] = acc[c] * inv;
    }
    rp[at + P.texel] = total;
    rp[at + P.texel + 1u] = kept;
    if total < 0.5 {
        count(C_LOST);
    }
}

@compute @workgroup_size(WORKGROUP, WORKGROUP)
fn reproject_pass(@builtin(global_invocation_id) gid: vec3<u32>) {
    if inside(gid) {
        reproject_pixel(gid.x, gid.y);
    }
}
