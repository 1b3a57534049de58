// `fxaa` on the GPU: FXAA 3.11, quality preset 12 (Lottes 2011), as
// `crate::filters::fxaa::reference` computes it (each function names the CPU function it
// mirrors). Two entry points: `luma` writes the perceptual luma of every pixel, `fxaa`
// finds each pixel's fetch position from the luma and fetches the colour bilinearly.

struct Params {
    width: u32,
    height: u32,
    // 1: the frame is HDR (luma of the tonemapped colour), else the colour clamped to 1.
    hdr: u32,
    pad: u32,
    subpix: f32,
    edge_threshold: f32,
    edge_threshold_min: f32,
    pad2: f32,
}

// kernels::LUMA_REC709.
const LUMA_REC709: vec3<f32> = vec3<f32>(0.2126, 0.7152, 0.0722);

@group(0) @binding(0) var<storage, read> P: Params;
@group(0) @binding(1) var<storage, read> color: array<f32>;
@group(0) @binding(2) var<storage, read_write> luma: array<f32>;
@group(0) @binding(3) var<storage, read_write> out: array<f32>;

fn plane_len() -> u32 {
    return P.width * P.height;
}

// fxaa::luma_of: sqrt of the Rec. 709 luma of the tonemapped colour (HDR) or of the
// colour clamped to 1.
@compute @workgroup_size(WORKGROUP, WORKGROUP)
fn luma_pass(@builtin(global_invocation_id) gid: vec3<u32>) {
    if gid.x >= P.width || gid.y >= P.height {
        return;
    }
    let n = plane_len();
    let i = gid.y * P.width + gid.x;
    var c = vec3<f32>(color[i], color[n + i], color[2u * n + i]);
    if P.hdr != 0u {
        c = c * (1.0 / (1.0 + max(max(c.x, c.y), c.z)));
    } else {
        c = min(c, vec3<f32>(1.0));
    }
    luma[i] = sqrt(max(dot(LUMA_REC709, c), 0.0));
}

// kernels::fetch_clamped of the luma.
fn luma_at(x: i32, y: i32) -> f32 {
    let cx = u32(clamp(x, 0, i32(P.width) - 1));
    let cy = u32(clamp(y, 0, i32(P.height) - 1));
    return luma[cy * P.width + cx];
}

// kernels::bilinear of plane `k` (0..2 colour from `color`, 3 the luma) at (x, y).
fn bilinear(k: u32, x: f32, y: f32) -> f32 {
    let b = bilinear_taps(x, y, P.width, P.height);
    if k == 3u {
        return blend(vec4<f32>(luma[b.i00], luma[b.i01], luma[b.i10], luma[b.i11]), b);
    }
    let o = k * plane_len();
    return blend(vec4<f32>(color[o + b.i00], color[o + b.i01], color[o + b.i10], color[o + b.i11]), b);
}

// fxaa::fxaa_position: the position (pixel units) pixel (x, y) fetches its colour at.
fn fxaa_position(x: u32, y: u32) -> vec2<f32> {
    let xi = i32(x);
    let yi = i32(y);
    let pos_m = vec2<f32>(f32(x) + 0.5, f32(y) + 0.5);
    let luma_m = luma_at(xi, yi);
    var luma_s = luma_at(xi, yi + 1);
    let luma_e = luma_at(xi + 1, yi);
    var luma_n = luma_at(xi, yi - 1);
    let luma_w = luma_at(xi - 1, yi);
    let range_max = max(max(max(max(luma_s, luma_m), luma_e), luma_n), luma_w);
    let range_min = min(min(min(min(luma_s, luma_m), luma_e), luma_n), luma_w);
    let range = range_max - range_min;
    if range < max(P.edge_threshold_min, range_max * P.edge_threshold) {
        return pos_m;
    }
    let luma_nw = luma_at(xi - 1, yi - 1);
    let luma_se = luma_at(xi + 1, yi + 1);
    let luma_ne = luma_at(xi + 1, yi - 1);
    let luma_sw = luma_at(xi - 1, yi + 1);
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
    let edge_horz4 = abs(edge_horz1) * 2.0 + abs(edge_horz2);
    let edge_vert4 = abs(edge_vert1) * 2.0 + abs(edge_vert2);
    let edge_horz3 = -2.0 * luma_w + luma_nwsw;
    let edge_vert3 = -2.0 * luma_s + luma_swse;
    let edge_horz = abs(edge_horz3) + edge_horz4;
    let edge_vert = abs(edge_vert3) + edge_vert4;
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
    let pair_n = abs(gradient_n) >= abs(gradient_s);
    let gradient = max(abs(gradient_n), abs(gradient_s));
    let length_sign = select(1.0, -1.0, pair_n);
    let subpix_c = clamp(abs(subpix_b) / range, 0.0, 1.0);
    var pos_b = pos_m;
    var off = vec2<f32>(0.0, 1.0);
    if horz_span {
        pos_b.y += length_sign * 0.5;
        off = vec2<f32>(1.0, 0.0);
    } else {
        pos_b.x += length_sign * 0.5;
    }
    let luma_nn = select(luma_s + luma_m, luma_n + luma_m, pair_n);
    let gradient_scaled = gradient * 0.25;
    let luma_mm = luma_m - luma_nn * 0.5;
    let luma_avg = luma_nn * 0.5;

    // fxaa::edge_search: step along the edge on both sides until the luma minus the
    // average reaches gradient_scaled; after the last sample the position advances once
    // more without sampling.
    // fxaa::PRESET_12_STEPS (FXAA_QUALITY__PS 5: P0..P4).
    var steps = array<f32, 5>(1.0, 1.5, 2.0, 4.0, 12.0);
    var pos_n = pos_b - off * steps[0];
    var pos_p = pos_b + off * steps[0];
    var end_n = bilinear(3u, pos_n.x, pos_n.y) - luma_avg;
    var end_p = bilinear(3u, pos_p.x, pos_p.y) - luma_avg;
    var done_n = abs(end_n) >= gradient_scaled;
    var done_p = abs(end_p) >= gradient_scaled;
    for (var k = 1u; k < 5u; k++) {
        let step = steps[k];
        if !done_n {
            pos_n -= off * step;
        }
        if !done_p {
            pos_p += off * step;
        }
        if (done_n && done_p) || k + 1u == 5u {
            break;
        }
        if !done_n {
            end_n = bilinear(3u, pos_n.x, pos_n.y) - luma_avg;
            done_n = abs(end_n) >= gradient_scaled;
        }
        if !done_p {
            end_p = bilinear(3u, pos_p.x, pos_p.y) - luma_avg;
            done_p = abs(end_p) >= gradient_scaled;
        }
    }

    var dst_n: f32;
    var dst_p: f32;
    if horz_span {
        dst_n = pos_m.x - pos_n.x;
        dst_p = pos_p.x - pos_m.x;
    } else {
        dst_n = pos_m.y - pos_n.y;
        dst_p = pos_p.y - pos_m.y;
    }
    let luma_m_lt_zero = luma_mm < 0.0;
    let good_span_n = (end_n < 0.0) != luma_m_lt_zero;
    let good_span_p = (end_p < 0.0) != luma_m_lt_zero;
    let span_length = dst_p + dst_n;
    let direction_n = dst_n < dst_p;
    let dst = min(dst_n, dst_p);
    let good_span = select(good_span_p, good_span_n, direction_n);
    let subpix_d = -2.0 * subpix_c + 3.0;
    let subpix_f = subpix_d * subpix_c * subpix_c;
    let subpix_h = subpix_f * subpix_f * P.subpix;
    let pixel_offset = -dst / span_length + 0.5;
    let pixel_offset_good = select(0.0, pixel_offset, good_span);
    let offset = max(pixel_offset_good, subpix_h) * length_sign;
    if horz_span {
        return vec2<f32>(pos_m.x, pos_m.y + offset);
    }
    return vec2<f32>(pos_m.x + offset, pos_m.y);
}

@compute @workgroup_size(WORKGROUP, WORKGROUP)
fn fxaa_pass(@builtin(global_invocation_id) gid: vec3<u32>) {
    if gid.x >= P.width || gid.y >= P.height {
        return;
    }
    let n = plane_len();
    let i = gid.y * P.width + gid.x;
    let pos = fxaa_position(gid.x, gid.y);
    for (var k = 0u; k < 3u; k++) {
        out[k * n + i] = bilinear(k, pos.x, pos.y);
    }
}
