// `upsample` on the GPU: the stages of `crate::filters::upsample` (its scalar reference,
// `filters/upsample/reference.rs`, is the statement of what is computed; every function
// here names the CPU function it mirrors, with the same float operations in the same
// order).
//
// Entry points, one pass each:
// - `reproject_pass`: the history texels fetched bilinearly along the motion over the
//   taps that pass the validity test (temporal::reproject), into `rp` with the tap weight
//   and the weight kept for sub-pixel surfaces.
// - `gradient_pass` (`spatiotemporal`): each pixel's raw relative luma gradient (the
//   reference's `gradients`, first loop), into `now`.
// - `blend_pass`: the method's output and next history texel.
//
// Where a decision can fall differently in f32 on the two backends, both take it on the
// same numbers: the image-space term per footprint offset (distances, `taa`'s Gaussian,
// the falloff at `kernel_wide`) comes from the host's table (`P.table`), so no sqrt or exp
// is evaluated here; ids are compared as the f32 the host made of them (`ids[i] as f32`,
// as the CPU compares them); `max(x, 0)` of a value that may be NaN is written as the
// select that Rust's `f32::max` is (the other operand for NaN).

struct Params {
    width: u32,
    height: u32,
    // Bits: see the FLAG_ constants.
    flags: u32,
    // One of the M_ constants.
    method: u32,
    // The shading pattern (frame::Sampling) and the colour planes' size.
    factor: u32,
    phase_x: u32,
    phase_y: u32,
    color_width: u32,
    color_height: u32,
    // Floats of a history texel (Method::planes).
    texel: u32,
    gradient_lag: u32,
    pad: u32,
    kernel_sharp: f32,
    kernel_wide: f32,
    // 1 / (depth_sigma x depth range).
    inv_depth_scale: f32,
    normal_sigma: f32,
    depth_tolerance: f32,
    // 0 for the methods that do not use them.
    neighbour_motion: f32,
    subpixel: f32,
    gradient_scale: f32,
    gradient_cancel: f32,
    decay: f32,
    taa_alpha: f32,
    pad2: f32,
    // Per footprint offset (dy + f)(2f + 1) + dx + f: the distance in block diagonals
    // (`spatiotemporal`, whose kernel width varies per pixel), the falloff at `kernel_wide`
    // (`spatial`, `temporal`) or `taa`'s Gaussian of the squared distance.
    table: array<f32, OFFSETS>,
}

// Declared before this file from Rust (`gpu::upsample::consts`): the IN_ planes of `inp`
// in units of width * height (colour planes at their own size from 0), the FLAG_ bits,
// the M_ methods, the history channels (R, W, T_DEPTH, T_ID, DEPTH, ID, G1, LK), COUNTERS
// and the C_ counters, WORKGROUP, OFFSETS, and the CPU filter's constants WEIGHT_EPSILON,
// LUMA_FLOOR, GW0..GW3 (GRADIENT_WEIGHTS), TAA_MAX_COUNT.

// Declared from Rust (`gpu::upsample::BINDINGS`), after frame.wgsl's `P` and `inp`: the
// history `hist`; `rp`, the reprojected texels (`texel` floats, then the tap weight and the
// part kept for sub-pixel surfaces); `now`, the raw gradients; the next history `next`,
// `out` and `counters`.

// Whether an invocation's pixel lies in the frame.
fn inside(gid: vec3<u32>) -> bool {
    return gid.x < P.width && gid.y < P.height;
}

fn count(c: u32) {
    atomicAdd(&counters[c], 1u);
}

// Colour sample k (planes of color_width x color_height from the start of `inp`).
fn color_at(k: u32) -> vec3<f32> {
    let m = P.color_width * P.color_height;
    return vec3<f32>(inp[IN_R * m + k], inp[IN_R * m + m + k], inp[IN_R * m + 2u * m + k]);
}

fn depth_at(i: u32) -> f32 {
    return inp[IN_DEPTH * plane_len() + i];
}

fn id_at(i: u32) -> f32 {
    return inp[IN_ID * plane_len() + i];
}

fn normal_at(i: u32) -> vec3<f32> {
    let n = plane_len();
    return vec3<f32>(inp[IN_NX * n + i], inp[(IN_NX + 1u) * n + i], inp[(IN_NX + 2u) * n + i]);
}

fn motion_at(i: u32) -> vec2<f32> {
    if !has(FLAG_MOTION) {
        return vec2<f32>(0.0);
    }
    let n = plane_len();
    return vec2<f32>(inp[IN_MX * n + i], inp[IN_MY * n + i]);
}

// Colour sample k left out (repaired from NaN or negative input).
fn invalid_sample(k: u32) -> bool {
    return has(FLAG_INVALID) && inp[IN_INVALID * plane_len() + k] != 0.0;
}

// Rust's `v.max(0.0)`: 0 for NaN.
fn max0(v: f32) -> f32 {
    return select(0.0, v, v > 0.0);
}

// spatial::falloff: (1 - x / sigma)^3, clamped below at WEIGHT_EPSILON.
fn falloff(x: f32, sigma: f32) -> f32 {
    let t = max0(1.0 - x * (1.0 / sigma));
    return max(t * t * t, WEIGHT_EPSILON);
}

// spatial::Geometry::weight: normal term times depth term between pixels i and j.
fn geo_weight(i: u32, j: u32) -> f32 {
    var w = 1.0;
    if has(FLAG_GEO_DEPTH) {
        w *= falloff(abs(depth_at(i) - depth_at(j)) * P.inv_depth_scale, 1.0);
    }
    if has(FLAG_NORMAL) {
        let ni = normal_at(i);
        if !(has(FLAG_SKY) && ni.x == 0.0 && ni.y == 0.0 && ni.z == 0.0) {
            let nj = normal_at(j);
            let dot = ni.x * nj.x + ni.y * nj.y + ni.z * nj.z;
            w *= falloff(max0(1.0 - dot), P.normal_sigma);
        }
    }
    return w;
}

// Sparse::cell: the lattice cell at or before pixel coordinate x along an axis with
// phase p (x - p + factor > 0, so the division floors).
fn cell(x: u32, p: u32) -> i32 {
    let f = i32(P.factor);
    return (i32(x) - i32(p) + f) / f - 1;
}

// A shaded sample: its colour index, full-resolution pixel and footprint offset.
struct Sample {
    found: bool,
    k: u32,
    j: u32,
    o: u32,
}

// One cell (a, b) of Sparse::near's footprint of pixel (x, y): its sample when it lies
// in the colours and the frame, within one block of the pixel, and is valid.
fn near_sample(x: u32, y: u32, a: i32, b: i32) -> Sample {
    let f = i32(P.factor);
    var s = Sample(false, 0u, 0u, 0u);
    let sy = f * b + i32(P.phase_y);
    let dy = sy - i32(y);
    let sx = f * a + i32(P.phase_x);
    let dx = sx - i32(x);
    if b < 0 || b >= i32(P.color_height) || sy >= i32(P.height) || abs(dy) > f {
        return s;
    }
    if a < 0 || a >= i32(P.color_width) || sx >= i32(P.width) || abs(dx) > f {
        return s;
    }
    let k = u32(b) * P.color_width + u32(a);
    if invalid_sample(k) {
        return s;
    }
    s.found = true;
    s.k = k;
    s.j = u32(sy) * P.width + u32(sx);
    s.o = u32((dy + f) * (2 * f + 1) + dx + f);
    return s;
}

// Sparse::sample: cell (a, b)'s sample when it exists, is valid and lies in the frame.
fn cell_sample(a: i32, b: i32) -> Sample {
    var s = Sample(false, 0u, 0u, 0u);
    if a < 0 || b < 0 || a >= i32(P.color_width) || b >= i32(P.color_height) {
        return s;
    }
    let k = u32(b) * P.color_width + u32(a);
    let sx = P.factor * u32(a) + P.phase_x;
    let sy = P.factor * u32(b) + P.phase_y;
    if invalid_sample(k) || sx >= P.width || sy >= P.height {
        return s;
    }
    s.found = true;
    s.k = k;
    s.j = sy * P.width + sx;
    return s;
}

// Sparse::own: pixel (x, y)'s own sample when it was shaded this frame.
fn own_sample(x: u32, y: u32) -> Sample {
    let f = P.factor;
    if x % f != P.phase_x || y % f != P.phase_y {
        return Sample(false, 0u, 0u, 0u);
    }
    return cell_sample(i32(x / f), i32(y / f));
}

struct Gathered {
    sum: vec3<f32>,
    weight: f32,
}

// Sparse::gather (Herzog et al. 2010, eq. 1-2): over the footprint's samples in order,
// weight = image-space term (the falloff of the distance at width `sigma` for
// `spatiotemporal`, else the table's) times the geometric weight.
fn gather(x: u32, y: u32, sigma: f32) -> Gathered {
    let i = y * P.width + x;
    let a0 = cell(x, P.phase_x);
    let b0 = cell(y, P.phase_y);
    var g = Gathered(vec3<f32>(0.0), 0.0);
    for (var b = b0 - 1; b <= b0 + 1; b++) {
        for (var a = a0 - 1; a <= a0 + 1; a++) {
            let s = near_sample(x, y, a, b);
            if s.found {
                var image = P.table[s.o];
                if P.method == M_SPATIOTEMPORAL {
                    image = falloff(image, sigma);
                }
                let wt = image * geo_weight(i, s.j);
                let v = color_at(s.k);
                g.sum = vec3<f32>(g.sum.x + wt * v.x, g.sum.y + wt * v.y, g.sum.z + wt * v.z);
                g.weight += wt;
            }
        }
    }
    return g;
}

// Gathered::mean, 0 where no sample had weight.
fn mean(g: Gathered) -> vec3<f32> {
    if g.weight > 0.0 {
        return vec3<f32>(g.sum.x / g.weight, g.sum.y / g.weight, g.sum.z / g.weight);
    }
    return vec3<f32>(0.0);
}

// Channel c of history texel t.
fn hist_at(t: u32, c: u32) -> f32 {
    return hist[P.texel * t + c];
}

// Channel c of pixel i's reprojected texel; `P.texel` is its tap weight, the next its
// weight kept for sub-pixel surfaces.
fn rp_at(i: u32, c: u32) -> f32 {
    return rp[(P.texel + 2u) * i + c];
}

// Floor and ceiling of the 3x3 around pixel coordinate v along an axis of n.
fn around(v: u32, n: u32) -> vec2<u32> {
    return vec2<u32>(select(v - 1u, 0u, v == 0u), min(v + 2u, n));
}

// temporal::surface_nearby: one of pixel i's eight neighbours shows object `id` at
// depth `z` and moves within `max_motion` of i on both axes.
fn surface_nearby(i: u32, id: f32, z: f32, max_motion: f32) -> bool {
    let w = P.width;
    let x = i % w;
    let y = i / w;
    let m = motion_at(i);
    let ys = around(y, P.height);
    let xs = around(x, w);
    for (var yy = ys.x; yy < ys.y; yy++) {
        for (var xx = xs.x; xx < xs.y; xx++) {
            let q = yy * w + xx;
            if q == i {
                continue;
            }
            if has(FLAG_IDS) && id_at(q) != id {
                continue;
            }
            if has(FLAG_DEPTH) {
                let dq = depth_at(q);
                if abs(z - dq) > P.depth_tolerance * abs(dq) {
                    continue;
                }
            }
            if has(FLAG_MOTION) {
                let mq = motion_at(q);
                if !(abs(mq.x - m.x) <= max_motion && abs(mq.y - m.y) <= max_motion) {
                    continue;
                }
            }
            return true;
        }
    }
    return false;
}

// temporal::seen_before: the previous frame showed pixel i's surface (its id and depth)
// at tap t or one of its eight neighbours (history channels ic, dc).
fn seen_before(i: u32, t: u32, ic: u32, dc: u32) -> bool {
    let w = P.width;
    let ys = around(t / w, P.height);
    let xs = around(t % w, w);
    for (var yy = ys.x; yy < ys.y; yy++) {
        for (var xx = xs.x; xx < xs.y; xx++) {
            let q = yy * w + xx;
            if has(FLAG_IDS) && id_at(i) != hist_at(q, ic) {
                continue;
            }
            if has(FLAG_DEPTH) {
                let z = depth_at(i);
                if abs(hist_at(q, dc) - z) > P.depth_tolerance * abs(z) {
                    continue;
                }
            }
            return true;
        }
    }
    return false;
}

// What Validity::keeps makes of a tap.
const TAP_REJECTED: u32 = 0u;
const TAP_PASSES: u32 = 1u;
// Failed, but shows a surface that a sub-pixel one covers at the pixel this frame: kept
// with the share P.subpixel of its weight.
const TAP_SUB_PIXEL: u32 = 2u;

// Validity::keeps for pixel i and tap t (history channels ic, dc hold the previous id and
// depth).
fn tap_kind(i: u32, t: u32, ic: u32, dc: u32) -> u32 {
    let tid = hist_at(t, ic);
    let tz = hist_at(t, dc);
    var failed = false;
    if has(FLAG_IDS) && id_at(i) != tid {
        failed = true;
    } else if has(FLAG_DEPTH) {
        let z = depth_at(i);
        failed = abs(tz - z) > P.depth_tolerance * abs(z);
    }
    if !failed || (P.neighbour_motion > 0.0 && surface_nearby(i, tid, tz, P.neighbour_motion)) {
        return TAP_PASSES;
    }
    // Any motion: F32_MAX holds every finite difference (the CPU's infinity).
    if P.subpixel > 0.0 && surface_nearby(i, tid, tz, F32_MAX) && !seen_before(i, t, ic, dc) {
        return TAP_SUB_PIXEL;
    }
    return TAP_REJECTED;
}
