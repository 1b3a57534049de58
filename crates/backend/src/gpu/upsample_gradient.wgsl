// `upsample`: the raw gradient pass of `spatiotemporal` (see upsample.wgsl, which
// precedes this file).

// The reference's `gradients`, first loop (Herzog et al. 2010, sec. 3.4): pixel (x, y)
// takes the relative luma gradient of its block's sample against the luma of the same
// surface point's previous shaded sample, with its sign (temporal::signed_gradient); 0
// where that sample's history was at least half kept for a sub-pixel surface, or where a
// repaired sample says nothing; 1 (unknown counts as maximal) without history.
fn gradient_pixel(x: u32, y: u32) {
    let i = y * P.width + x;
    let s = cell_sample(max(cell(x, P.phase_x), 0), max(cell(y, P.phase_y), 0));
    var g = 1.0;
    if has(FLAG_HISTORY) {
        let fi = rp_at(i, P.texel);
        if s.found && rp_at(s.j, P.texel) >= 0.5 && fi >= 0.5 {
            let j = s.j;
            let fj = rp_at(j, P.texel);
            if has(FLAG_SUB_GRADIENT) && rp_at(j, P.texel + 1u) >= 0.5 * fj {
                g = 0.0;
            } else {
                let l = luma_of(color_at(s.k));
                let known = rp_at(j, LK + 1u);
                let known2 = rp_at(j, LK + 3u);
                var before: f32;
                if P.gradient_lag == 2u && known2 >= 0.5 {
                    before = rp_at(j, LK + 2u) / known2;
                } else if known >= 0.5 {
                    before = rp_at(j, LK) / known;
                } else {
                    before = luma_of(vec3<f32>(rp_at(j, R), rp_at(j, R + 1u), rp_at(j, R + 2u)));
                }
                // temporal::signed_gradient.
                g = clamp((l - before) / max(max(l, before), LUMA_FLOOR), -1.0, 1.0);
            }
        } else if !s.found && has(FLAG_INVALID) && fi >= 0.5 {
            g = 0.0;
        }
    }
    now[i] = g;
}

@compute @workgroup_size(WORKGROUP, WORKGROUP)
fn gradient_pass(@builtin(global_invocation_id) gid: vec3<u32>) {
    if inside(gid) {
        gradient_pixel(gid.x, gid.y);
    }
}
