// `traa`: the passes up to the resolve (see traa.wgsl, which precedes this file, and
// reproject.wgsl, which follows it).
//
// Where the two backends could decide differently: every decision here is taken on values
// computed by the same f32 operations in the same order as the CPU's, and none of them
// follows a multiply-add a compiler may fuse. The nearest-depth dilation compares input
// depths (ties: the first in the CPU's order wins, reproject.wgsl); the on-screen test and
// the depth variance's threshold (eq. 4.4-4.6's 0.002) compare sums, quotients and
// absolute differences of inputs; object ids are compared as integers. What a fused
// multiply-add may round differently (lumas, the Sobel, the mixes, the feedback) moves
// the output continuously: the clip and the clamps are continuous at their box's surface.
//
// The buffers (`albedo`, `ids`, `hist`, `next`, `raw`, `stable`, `out`, `counters`) are
// declared from Rust (`gpu::traa::STAGES`), after frame.wgsl's `P` and `inp`.

// Linear depth of pixel i: depth / far.
fn depth01(i: u32) -> f32 {
    return inp[IN_DEPTH * plane_len() + i] / P.far;
}

fn repaired(i: u32) -> bool {
    return has(FLAG_INVALID) && inp[IN_INVALID * plane_len() + i] != 0.0;
}

// What the Sobel of eq. 4.9 reads at pixel i: the lit luma, the albedo luma, depth / far.
const LIT: u32 = 0u;
const UNLIT: u32 = 1u;
const DEPTH: u32 = 2u;

fn sobel_source(k: u32, i: u32) -> f32 {
    switch k {
        case 0u: {
            return luma_of(working(i));
        }
        case 1u: {
            let n = plane_len();
            return luma_of(vec3<f32>(albedo[i], albedo[n + i], albedo[2u * n + i]));
        }
        default: {
            return depth01(i);
        }
    }
}

// kernels::sobel_magnitude of source k's 3x3 at (x, y), edges clamped (eq. 3.5, 3.6).
fn sobel_of(k: u32, x: i32, y: i32) -> f32 {
    var t: array<f32, 9>;
    for (var j = 0; j < 9; j++) {
        t[j] = sobel_source(k, clamped(x + j % 3 - 1, y + j / 3 - 1));
    }
    let gx = (t[2] + 2.0 * t[5] + t[8]) - (t[0] + 2.0 * t[3] + t[6]);
    let gy = (t[0] + 2.0 * t[1] + t[2]) - (t[6] + 2.0 * t[7] + t[8]);
    return sqrt(gx * gx + gy * gy);
}

// reference::sobel_edges at (x, y): eq. 4.9, clamped to [0, 1], and eq. 4.10.
fn raw_sobel(x: i32, y: i32) -> f32 {
    let l = sobel_of(LIT, x, y);
    var surface = l;
    if has(FLAG_ALBEDO) {
        surface = SOBEL_UNLIT_WEIGHT * sobel_of(UNLIT, x, y) + SOBEL_LIT_WEIGHT * l;
    }
    var d = 0.0;
    if has(FLAG_DEPTH) {
        d = sobel_of(DEPTH, x, y);
    }
    let g = clamp(surface + d, 0.0, 1.0);
    return sqrt(g * g * (3.0 - 2.0 * g));
}

@compute @workgroup_size(WORKGROUP, WORKGROUP)
fn sobel(@builtin(global_invocation_id) gid: vec3<u32>) {
    if gid.x < P.width && gid.y < P.height {
        raw[gid.y * P.width + gid.x] = raw_sobel(i32(gid.x), i32(gid.y));
    }
}

// Where pixel i's history comes from: whether it is used (there is one, and the previous
// position is on screen), and that position when the history is reprojected.
struct Previous {
    used: bool,
    px: f32,
    py: f32,
}

fn previous(x: u32, y: u32) -> Previous {
    var p = Previous(has(FLAG_HISTORY), 0.0, 0.0);
    if has(FLAG_HISTORY) && has(FLAG_REPROJECT) {
        let n = plane_len();
        let i = y * P.width + x;
        var m = vec2<f32>(inp[IN_MX * n + i], inp[IN_MY * n + i]);
        if has(FLAG_DILATE) {
            m = dilated_motion(x, y);
        }
        p.px = f32(x) + 0.5 + m.x;
        p.py = f32(y) + 0.5 + m.y;
        // passes::on_screen (false for NaN).
        p.used = p.px >= 0.0 && p.px <= f32(P.width) && p.py >= 0.0 && p.py <= f32(P.height);
    }
    return p;
}

// The history's value at pixel i's previous position p: sample `c` of the
// `stride`-sample texels from `base` (kernels::bilinear where the history is reprojected,
// else pixel i's own).
fn fetch(p: Previous, i: u32, base: u32, stride: u32, c: u32) -> f32 {
    if has(FLAG_REPROJECT) {
        let b = bilinear_taps(p.px, p.py, P.width, P.height);
        let at = base + c;
        return blend(
            vec4<f32>(hist[at + stride * b.i00], hist[at + stride * b.i01], hist[at + stride * b.i10], hist[at + stride * b.i11]),
            b,
        );
    }
    return hist[base + stride * i + c];
}

// INSIDE's feedback (traa::feedback): the history weight from two lumas.
fn feedback(l0: f32, l1: f32) -> f32 {
    let diff = abs(l0 - l1) / max(max(l0, l1), FEEDBACK_LUMA_FLOOR);
    let w = max(1.0 - diff, 0.0);
    return P.feedback_min + (P.feedback_max - P.feedback_min) * w * w;
}

// traa::mix: x (1 - t) + y t (WGSL's mix may round otherwise).
fn mix1(x: f32, y: f32, t: f32) -> f32 {
    return x * (1.0 - t) + y * t;
}

fn mix3(x: vec3<f32>, y: vec3<f32>, t: f32) -> vec3<f32> {
    return x * (1.0 - t) + y * t;
}

// The reference's `sobel_history` stage at (x, y): the reprojected Sobel history clamped
// into the averaged 3x3 and cross range of the raw Sobel, blended by INSIDE's feedback;
// the raw Sobel where the history is not used, the history where the input was repaired.
fn stable_sobel(x: u32, y: u32) -> f32 {
    let i = y * P.width + x;
    let p = previous(x, y);
    if !p.used {
        return raw[i];
    }
    let hs = fetch(p, i, 0u, P.texel, SOBEL_TEXEL);
    if repaired(i) {
        return hs;
    }
    var t: array<f32, 9>;
    for (var j = 0; j < 9; j++) {
        t[j] = raw[clamped(i32(x) + j % 3 - 1, i32(y) + j / 3 - 1)];
    }
    var lo3 = t[0];
    var hi3 = t[0];
    for (var j = 1; j < 9; j++) {
        lo3 = min(lo3, t[j]);
        hi3 = max(hi3, t[j]);
    }
    let lo_x = min(min(min(min(t[1], t[3]), t[4]), t[5]), t[7]);
    let hi_x = max(max(max(max(t[1], t[3]), t[4]), t[5]), t[7]);
    // kernels::clamp_to_box.
    let hv = min(max(hs, 0.5 * (lo3 + lo_x)), 0.5 * (hi3 + hi_x));
    let r = t[4];
    return mix1(r, hv, feedback(r, hv));
}

@compute @workgroup_size(WORKGROUP, WORKGROUP)
fn sobel_history(@builtin(global_invocation_id) gid: vec3<u32>) {
    if gid.x < P.width && gid.y < P.height {
        stable[gid.y * P.width + gid.x] = stable_sobel(gid.x, gid.y);
    }
}

// Eq. 4.1 (reference::model_average): the share of the 3x3 (centre included; neighbours
// outside the image count as the same object) whose object id differs from pixel i's.
fn model_average(x: u32, y: u32) -> f32 {
    let me = ids[y * P.width + x];
    var diff = 0u;
    for (var yy = select(y - 1u, 0u, y == 0u); yy <= min(y + 1u, P.height - 1u); yy++) {
        for (var xx = select(x - 1u, 0u, x == 0u); xx <= min(x + 1u, P.width - 1u); xx++) {
            diff += select(0u, 1u, ids[yy * P.width + xx] != me);
        }
    }
    return f32(diff) / 9.0;
}

// Eq. 4.4-4.6 (reference::depth_variance): depth pseudo-variance plus temporal
// pseudo-variance of the previous depth / far `prev` (where `p.used`), zero where the
// normalising distance is below DEPTH_DISTANCE_MIN. The threshold decides on the sum and
// quotient the CPU computes, in its order (taps row by row from 0).
fn depth_variance(x: u32, y: u32, p: Previous, prev: f32) -> f32 {
    var t: array<f32, 9>;
    for (var j = 0; j < 9; j++) {
        t[j] = depth01(clamped(i32(x) + j % 3 - 1, i32(y) + j / 3 - 1));
    }
    var lo = t[0];
    var hi = t[0];
    var sum = 0.0;
    for (var j = 0; j < 9; j++) {
        lo = min(lo, t[j]);
        hi = max(hi, t[j]);
        sum += t[j];
    }
    let avg = sum / 9.0;
    let max_dist = min(abs(lo - avg), abs(hi - avg));
    if max_dist < DEPTH_DISTANCE_MIN {
        return 0.0;
    }
    let q = abs(t[4] - avg) / max_dist;
    var tpv = 0.0;
    if p.used {
        let u = abs(prev - avg) / max_dist;
        tpv = (u * u) * (u * u);
    }
    return min(q * q + tpv, 1.0);
}

// Eq. 4.12-4.14 (reference::aliased): clamp01(sobelAvg + depth terms + modelAverage), the
// Sobel's 3x3 and cross means (of the Sobel history where it ran) mixed by
// clamp01(modelAverage + sobel).
fn aliased(x: u32, y: u32, ma: f32, dv: f32) -> f32 {
    var t: array<f32, 9>;
    for (var j = 0; j < 9; j++) {
        t[j] = stable[clamped(i32(x) + j % 3 - 1, i32(y) + j / 3 - 1)];
    }
    let avg3 = (t[0] + t[1] + t[2] + t[3] + t[4] + t[5] + t[6] + t[7] + t[8]) / 9.0;
    let avg_cross = (t[1] + t[3] + t[4] + t[5] + t[7]) / 5.0;
    let sobel_avg = mix1(avg_cross, avg3, clamp(ma + t[4], 0.0, 1.0));
    return clamp(sobel_avg + dv + ma, 0.0, 1.0);
}

// The colour box of pixel (x, y) (kernels::for_each_row_stats): min and max of the 3x3
// and of the cross of the working colour.
struct Boxes {
    lo: vec3<f32>,
    hi: vec3<f32>,
    lo_cross: vec3<f32>,
    hi_cross: vec3<f32>,
}

fn boxes(x: u32, y: u32) -> Boxes {
    let c = working(y * P.width + x);
    var b = Boxes(c, c, c, c);
    for (var j = 0; j < 9; j++) {
        let v = working(clamped(i32(x) + j % 3 - 1, i32(y) + j / 3 - 1));
        b.lo = min(b.lo, v);
        b.hi = max(b.hi, v);
        if j % 2 == 1 {
            b.lo_cross = min(b.lo_cross, v);
            b.hi_cross = max(b.hi_cross, v);
        }
    }
    return b;
}

// The reference's `resolve` stage at (x, y), with (improved) the per-pixel stages it
// reads: the box (averaged, or eq. 4.15-4.16), the history clipped toward its centre,
// INSIDE's feedback.
fn resolve_pixel(x: u32, y: u32) {
    let n = plane_len();
    let i = y * P.width + x;
    let current = working(i);
    let p = previous(x, y);
    let k = P.texel;
    let depth_at = k * n;
    var value = current;
    if !p.used {
        atomicAdd(&wg_counts[C_RESET], 1u);
    } else {
        let h = vec3<f32>(fetch(p, i, 0u, k, 0u), fetch(p, i, 0u, k, 1u), fetch(p, i, 0u, k, 2u));
        if repaired(i) {
            // No usable sample here this frame: keep the history as it is.
            value = h;
        } else {
            let b = boxes(x, y);
            var lo = 0.5 * (b.lo + b.lo_cross);
            var hi = 0.5 * (b.hi + b.hi_cross);
            if has(FLAG_IMPROVED) {
                var ma = 0.0;
                if has(FLAG_MODEL) {
                    ma = model_average(x, y);
                }
                var dv = 0.0;
                if has(FLAG_DEPTH) {
                    dv = depth_variance(x, y, p, fetch(p, i, depth_at, 1u, 0u));
                }
                let a = aliased(x, y, ma, dv);
                // Eq. 4.15 then eq. 4.16.
                lo = mix3(current, mix3(b.lo_cross, b.lo, a), a);
                hi = mix3(current, mix3(b.hi_cross, b.hi, a), a);
            }
            let hc = clip_toward_center(h, lo, hi);
            if hc.w != 0.0 {
                atomicAdd(&wg_counts[C_CLIPPED], 1u);
            }
            value = max(mix3(current, hc.xyz, feedback(luma_of(current), luma_of(hc.xyz))), vec3<f32>(0.0));
        }
    }
    next[k * i] = value.x;
    next[k * i + 1u] = value.y;
    next[k * i + 2u] = value.z;
    if has(FLAG_IMPROVED) {
        next[k * i + SOBEL_TEXEL] = stable[i];
        if has(FLAG_DEPTH) {
            next[depth_at + i] = depth01(i);
        }
    }
    var rgb = value;
    if has(FLAG_TONEMAP) && !has(FLAG_SHARPEN) {
        rgb = tonemap_inverse(rgb);
    }
    out[i] = rgb.x;
    out[n + i] = rgb.y;
    out[2u * n + i] = rgb.z;
}
