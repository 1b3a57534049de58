// `taa`: the resolve pass (see taa.wgsl, which precedes this file). Its buffers (`hist`,
// `next`, `out`, `counters`) are declared from Rust (`gpu::taa::RESOLVE`), after frame.wgsl's
// `P` and `inp`.

fn texel_at(i: u32) -> vec4<f32> {
    let k = 4u * i;
    return vec4<f32>(hist[k], hist[k + 1u], hist[k + 2u], hist[k + 3u]);
}

fn hist_texel(x: u32, y: u32) -> vec4<f32> {
    return texel_at(y * P.width + x);
}

// kernels::bilinear of the four texel channels at (px, py), taps clamped to the image.
fn bilinear_texel(px: f32, py: f32) -> vec4<f32> {
    let b = bilinear_taps(px, py, P.width, P.height);
    let top = lerp4(texel_at(b.i00), texel_at(b.i01), b.tx);
    let bottom = lerp4(texel_at(b.i10), texel_at(b.i11), b.tx);
    return lerp4(top, bottom, b.ty);
}

// kernels::bilinear of the history depth plane.
fn bilinear_depth(px: f32, py: f32) -> f32 {
    let b = bilinear_taps(px, py, P.width, P.height);
    let d = P.depth_at;
    return blend(vec4<f32>(hist[d + b.i00], hist[d + b.i01], hist[d + b.i10], hist[d + b.i11]), b);
}

// kernels::catmull_rom_texel: Catmull-Rom of Y, Co, Cg over the 4x4 footprint without its
// corners, renormalised (Karis 2014; Jimenez 2016), and bilinear of the count.
fn catmull_rom_texel(px: f32, py: f32) -> vec4<f32> {
    var f = catmull_rom_footprint(px, py, P.width, P.height);
    var acc = vec3<f32>(0.0);
    for (var j = 0; j < 4; j++) {
        let inner = j == 1 || j == 2;
        var row = vec3<f32>(0.0);
        for (var k = 0; k < 4; k++) {
            if inner || k == 1 || k == 2 {
                row += f.wx[k] * hist_texel(f.xs[k], f.ys[j]).xyz;
            }
        }
        acc += f.wy[j] * row;
    }
    return vec4<f32>(acc, bilinear_texel(px, py).w);
}

fn resolve_pixel(x: u32, y: u32) {
    let n = plane_len();
    let i = y * P.width + x;

    // The 3x3 statistics of the working colour in YCoCg (kernels::for_each_row_stats,
    // edges clamped): min, max, mean and mean of squares. Summed as the CPU sums them,
    // each column's three rows first, then the three columns: the variance box's sigma,
    // sqrt(mean_sq - mean^2), turns a last-bit difference of a flat neighbourhood's sums
    // into one of about 1e-4.
    var lo = vec3<f32>(F32_MAX);
    var hi = vec3<f32>(-F32_MAX);
    var col_sum: array<vec3<f32>, 3>;
    var col_sq: array<vec3<f32>, 3>;
    var current = vec3<f32>(0.0);
    for (var dx = -1; dx <= 1; dx++) {
        let u = working_ycocg(i32(x) + dx, i32(y) - 1);
        let v = working_ycocg(i32(x) + dx, i32(y));
        let t = working_ycocg(i32(x) + dx, i32(y) + 1);
        lo = min(lo, min(min(u, v), t));
        hi = max(hi, max(max(u, v), t));
        col_sum[dx + 1] = u + v + t;
        col_sq[dx + 1] = u * u + v * v + t * t;
        if dx == 0 {
            current = v;
        }
    }
    let mean = (col_sum[0] + col_sum[1] + col_sum[2]) * (1.0 / 9.0);
    let mean_sq = (col_sq[0] + col_sq[1] + col_sq[2]) * (1.0 / 9.0);

    // The history at this pixel's previous position.
    var h = vec4<f32>(0.0);
    var hist_depth = 0.0;
    if has(FLAG_HISTORY) {
        if has(FLAG_REPROJECT) {
            var m = vec2<f32>(inp[IN_MX * n + i], inp[IN_MY * n + i]);
            if has(FLAG_DILATE) {
                m = dilated_motion(x, y);
            }
            let px = f32(x) + 0.5 + m.x;
            let py = f32(y) + 0.5 + m.y;
            // passes::on_screen (false for NaN).
            let on = px >= 0.0 && px <= f32(P.width) && py >= 0.0 && py <= f32(P.height);
            if on {
                if has(FLAG_CATMULL_ROM) {
                    h = catmull_rom_texel(px, py);
                } else {
                    h = bilinear_texel(px, py);
                }
            }
            if has(FLAG_DEPTH_REJECT) {
                hist_depth = bilinear_depth(px, py);
            }
        } else {
            h = hist_texel(x, y);
            if has(FLAG_DEPTH_REJECT) {
                hist_depth = hist[P.depth_at + i];
            }
        }
    }
    var count = 0.0;
    if has(FLAG_HISTORY) {
        count = h.w;
    }
    if has(FLAG_DEPTH_REJECT) {
        let d = inp[IN_DEPTH * n + i];
        if abs(hist_depth - d) > P.depth_rejection * max(abs(d), 1e-6) {
            atomicAdd(&wg_counts[C_REJECTED], 1u);
            count = 0.0;
        }
    }

    var value: vec3<f32>;
    var next_count: f32;
    if count < 0.5 {
        atomicAdd(&wg_counts[C_RESET], 1u);
        value = current;
        next_count = 1.0;
    } else if has(FLAG_INVALID) && inp[IN_INVALID * n + i] != 0.0 {
        // No usable sample here this frame: keep the history as it is.
        value = h.xyz;
        next_count = count;
    } else {
        // The variance box (kernels::variance_box, Salvi 2016) within the min/max box.
        let sigma = sqrt(max(mean_sq - mean * mean, vec3<f32>(0.0)));
        let blo = max(mean - P.gamma * sigma, lo);
        let bhi = min(mean + P.gamma * sigma, hi);
        let clipped = clip_toward_center(h.xyz, blo, bhi);
        if clipped.w != 0.0 {
            atomicAdd(&wg_counts[C_CLIPPED], 1u);
        }
        let a = max(P.alpha, 1.0 / (count + 1.0));
        var wc = a;
        var wh = 1.0 - a;
        if has(FLAG_LUMA_WEIGHT) {
            // Karis 2014's luminance weights.
            wc = a / (1.0 + max(current.x, 0.0));
            wh = (1.0 - a) / (1.0 + max(clipped.x, 0.0));
        }
        let k = 1.0 / (wc + wh);
        value = (wc * current + wh * clipped.xyz) * k;
        next_count = min(count + 1.0, MAX_COUNT);
    }
    next[4u * i] = value.x;
    next[4u * i + 1u] = value.y;
    next[4u * i + 2u] = value.z;
    next[4u * i + 3u] = next_count;
    if has(FLAG_KEEP_DEPTH) {
        next[P.depth_at + i] = inp[IN_DEPTH * n + i];
    }
    var rgb = max(ycocg_to_rgb(value), vec3<f32>(0.0));
    if has(FLAG_TONEMAP) && !has(FLAG_SHARPEN) {
        rgb = tonemap_inverse(rgb);
    }
    out[i] = rgb.x;
    out[n + i] = rgb.y;
    out[2u * n + i] = rgb.z;
}
