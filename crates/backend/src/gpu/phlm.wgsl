// `phlm` on the GPU: one pass per frame, one invocation per pixel, computing what
// `crate::filters::phlm::reference` computes stage by stage (each function names the CPU
// function it mirrors): the working colour's 3x3 statistics in YCoCg, the previous
// position (with velocity dilation, `reproject.wgsl`), the temporal feature (sec. 5.1 of Iglesias-Guitian et al. 2016), and Algorithm 1
// (fetch, predict, box test, clip, the RLS update, output).
//
// The RLS update is `rls::update_information_f32`: the information form with regularized
// forgetting, formed with one rounding per entry (fma) and solved by a Cholesky
// factorisation whose pivots are held at or above the prior (the rls module's docs give
// the bound and the still-pixel measurements).
//
// State: phlm::STATE_PLANES planes (beta 12, R = P^-1 packed 10, z 3, the count of failed
// box tests 1, the speed 1, the depth 1; the CPU filter's texel order, one plane each so
// neighbouring invocations read neighbouring words), in three buffers (beta, R, z with the
// count, the speed and the depth), double-buffered.

struct Params {
    width: u32,
    height: u32,
    // Bits: see the FLAG_ constants.
    flags: u32,
    // phlm::Params::clip_after (phlm::strikes).
    clip_after: f32,
    lambda: f32,
    lambda_moving: f32,
    lambda_speed: f32,
    p0: f32,
    clip_p: f32,
    clip_keep: f32,
    feature_a: f32,
    feature_b: f32,
    feature_alpha_min: f32,
    test_gamma: f32,
    // Largest output: just below 1 in the tonemapped space, else f32::MAX.
    hi: f32,
    // The bound R >= I / max(p0, clip_p) that every model keeps (resets to I / p0, clips
    // blend toward I / clip_p, forgetting toward I / p0): the Cholesky pivots' floor.
    pivot_floor: f32,
    // phlm::Params::fail_keep.
    fail_keep: f32,
    // phlm::Params::fail_ramp (phlm::miss).
    fail_ramp: f32,
    // phlm::Params::speed_jump (phlm::jump).
    speed_jump: f32,
    // phlm::Params::fail_ramp_box (phlm::ramp).
    fail_ramp_box: f32,
    // phlm::Params::depth_jump (phlm::depth_share).
    depth_jump: f32,
}

// Declared from Rust (`gpu::phlm::BINDINGS`), after frame.wgsl's `P` and `inp`: the previous
// models (`beta`, `info`, `feat`) and the next (`next_beta`, `next_info`, `next_feat`), each
// in three parts (beta, R, z with the count of failed box tests and the speed) so that no
// buffer is past the 128 MiB a shader's buffer may have on many devices at 1080p; `out`
// and `counters`.

// Declared before this file from Rust (`gpu::phlm::consts`): the FLAG_ bits of `P.flags`
// (FLAG_DEPTH: the frame has depth, uploaded and kept with the models,
// phlm::history_depth), the IN_ planes of `inp` in units of width * height, COUNTERS and
// the C_ counters (history reset, clipped, reset off screen, repaired, largest trace(P)
// as bits), WORKGROUP, and FEATURE_EPS, STRIKE_DECAY and DEPTH_JUMP_SPEED of the CPU
// filter.

// The parts of the state (phlm::BETA, phlm::R, phlm::Z ranges, a buffer each).
const BETA: u32 = 0u;
const R: u32 = 1u;
const Z: u32 = 2u;

// Where a previous position's state is read (phlm::fetch): the nearest pixel (all four
// taps on it, weights 0), or kernels::bilinear's footprint.
fn taps(px: f32, py: f32) -> Bilinear {
    if has(FLAG_NEAREST) {
        let j = min(u32(max(py, 0.0)), P.height - 1u) * P.width + min(u32(max(px, 0.0)), P.width - 1u);
        return Bilinear(j, j, j, j, 0.0, 0.0);
    }
    return bilinear_taps(px, py, P.width, P.height);
}

// kernels::catmull_rom of beta's plane k over footprint f (phlm::fetch_model), summed in
// the CPU's order: each row's two partial sums, weighted by the row, added last.
fn beta_catmull_rom(k: u32, f: ptr<function, CatmullRom>) -> f32 {
    let o = k * plane_len();
    var lo = 0.0;
    var hi = 0.0;
    for (var j = 0; j < 4; j++) {
        let row = o + (*f).ys[j] * P.width;
        var a: f32;
        var b: f32;
        if j == 1 || j == 2 {
            a = (*f).wx[0] * beta[row + (*f).xs[0]] + (*f).wx[2] * beta[row + (*f).xs[2]];
            b = (*f).wx[1] * beta[row + (*f).xs[1]] + (*f).wx[3] * beta[row + (*f).xs[3]];
        } else {
            a = (*f).wx[1] * beta[row + (*f).xs[1]];
            b = (*f).wx[2] * beta[row + (*f).xs[2]];
        }
        lo += (*f).wy[j] * a;
        hi += (*f).wy[j] * b;
    }
    return lo + hi;
}

// Planes k .. k + 3 of beta by Catmull-Rom.
fn beta_catmull_rom4(k: u32, f: ptr<function, CatmullRom>) -> vec4<f32> {
    return vec4<f32>(
        beta_catmull_rom(k, f),
        beta_catmull_rom(k + 1u, f),
        beta_catmull_rom(k + 2u, f),
        beta_catmull_rom(k + 3u, f),
    );
}

// Planes k .. k + 3 of part `part` (fetch).
fn fetch4(part: u32, k: u32, t: Bilinear) -> vec4<f32> {
    return vec4<f32>(fetch(part, k, t), fetch(part, k + 1u, t), fetch(part, k + 2u, t), fetch(part, k + 3u, t));
}

// Plane k of part `part` of the previous models at taps t.
fn fetch(part: u32, k: u32, t: Bilinear) -> f32 {
    let o = k * plane_len();
    var s: vec4<f32>;
    if part == BETA {
        s = vec4<f32>(beta[o + t.i00], beta[o + t.i01], beta[o + t.i10], beta[o + t.i11]);
    } else if part == R {
        s = vec4<f32>(info[o + t.i00], info[o + t.i01], info[o + t.i10], info[o + t.i11]);
    } else {
        s = vec4<f32>(feat[o + t.i00], feat[o + t.i01], feat[o + t.i10], feat[o + t.i11]);
    }
    if has(FLAG_NEAREST) {
        return s.x;
    }
    return blend(s, t);
}

// phlm::feature::convergence and accumulate (sec. 5.1: phi = a l^2 + b v l^3).
fn accumulate(prev: vec3<f32>, lowpass: vec3<f32>, lo: f32, hi: f32, v: f32) -> vec3<f32> {
    let fl = 0.25 * prev.x + 0.5 * prev.y + 0.25 * prev.z;
    let l = max(max(lo - fl, fl - hi), 0.0);
    let phi = P.feature_a * l * l + P.feature_b * v * l * l * l;
    let a = clamp(phi / (l + (hi - lo) + FEATURE_EPS), P.feature_alpha_min, 1.0);
    return prev + a * (lowpass - prev);
}

// One axis of kernels::clip_toward_point: the fraction of the way from q to tgt at which
// the slab [lo, hi] is entered (0 when q is inside it), and 1 in `.y` when q is outside.
fn slab_entry(q: f32, tgt: f32, lo: f32, hi: f32) -> vec2<f32> {
    if q < lo {
        return vec2<f32>(min((lo - q) / (tgt - q), 1.0), 1.0);
    }
    if q > hi {
        return vec2<f32>(min((hi - q) / (tgt - q), 1.0), 1.0);
    }
    return vec2<f32>(0.0, 0.0);
}

// kernels::clip_toward_point (Algorithm 1 lines 14-17): q moved along the ray toward
// `toward` (clamped into the box) to the box; w = 1 when it moved. Written per axis, with
// no loop over components: a dynamically indexed vector becomes memory on some drivers.
fn clip_toward_point(q: vec3<f32>, toward: vec3<f32>, lo: vec3<f32>, hi: vec3<f32>) -> vec4<f32> {
    let tgt = min(max(toward, lo), hi);
    // The box grown by its guard (kernels::clip).
    let g = vec3<f32>(clip_guard(lo, hi));
    let glo = lo - g;
    let ghi = hi + g;
    let ex = slab_entry(q.x, tgt.x, glo.x, ghi.x);
    let ey = slab_entry(q.y, tgt.y, glo.y, ghi.y);
    let ez = slab_entry(q.z, tgt.z, glo.z, ghi.z);
    if ex.y + ey.y + ez.y == 0.0 {
        return vec4<f32>(q, 0.0);
    }
    let t = max(max(ex.x, ey.x), ez.x);
    return vec4<f32>(min(max(q + t * (tgt - q), glo), ghi), 1.0);
}

// One pixel's model (phlm::Model): beta's rows, and R = P^-1 packed (rls::SYM order:
// (0,0) (0,1) (0,2) (0,3) in ra, (1,1) (1,2) (1,3) (2,2) in rb, (2,3) (3,3) in rc). Named
// vectors rather than arrays: an array indexed in a loop becomes memory on some drivers.
struct Model {
    b0: vec4<f32>,
    b1: vec4<f32>,
    b2: vec4<f32>,
    ra: vec4<f32>,
    rb: vec4<f32>,
    rc: vec2<f32>,
}

// rls::init_information: R = I / p.
fn set_information(m: ptr<function, Model>, p: f32) {
    let d = 1.0 / p;
    (*m).ra = vec4<f32>(d, 0.0, 0.0, 0.0);
    (*m).rb = vec4<f32>(d, 0.0, 0.0, d);
    (*m).rc = vec2<f32>(0.0, d);
}

// phlm::Model::reset: intercept = colour, slopes 0, R = I / p.
fn model_reset(c: vec3<f32>, p: f32) -> Model {
    var m: Model;
    m.b0 = vec4<f32>(c.x, 0.0, 0.0, 0.0);
    m.b1 = vec4<f32>(c.y, 0.0, 0.0, 0.0);
    m.b2 = vec4<f32>(c.z, 0.0, 0.0, 0.0);
    set_information(&m, p);
    return m;
}

// rls::predict: beta^T x per channel, summed in the CPU's order.
fn row_dot(b: vec4<f32>, x: vec4<f32>) -> f32 {
    return b.x * x.x + b.y * x.y + b.z * x.z + b.w * x.w;
}

fn predict(m: Model, x: vec4<f32>) -> vec3<f32> {
    return vec3<f32>(row_dot(m.b0, x), row_dot(m.b1, x), row_dot(m.b2, x));
}

// phlm::Model::clip (Algorithm 1 line 18): reset to `c` or shifted to predict it, R
// relaxed toward I / clip_p.
fn model_clip(m: ptr<function, Model>, pred: vec3<f32>, c: vec3<f32>) {
    if has(FLAG_SHIFT) {
        let d = c - pred;
        (*m).b0.x += d.x;
        (*m).b1.x += d.y;
        (*m).b2.x += d.z;
    } else {
        (*m).b0 = vec4<f32>(c.x, 0.0, 0.0, 0.0);
        (*m).b1 = vec4<f32>(c.y, 0.0, 0.0, 0.0);
        (*m).b2 = vec4<f32>(c.z, 0.0, 0.0, 0.0);
    }
    relax(m, P.clip_keep);
}

// phlm::Model::relax: R relaxed toward I / clip_p, keeping `k` of it.
fn relax(m: ptr<function, Model>, k: f32) {
    var init: Model;
    set_information(&init, P.clip_p);
    if k == 0.0 {
        (*m).ra = init.ra;
        (*m).rb = init.rb;
        (*m).rc = init.rc;
    } else {
        (*m).ra = k * (*m).ra + (1.0 - k) * init.ra;
        (*m).rb = k * (*m).rb + (1.0 - k) * init.rb;
        (*m).rc = k * (*m).rc + (1.0 - k) * init.rc;
    }
}


// phlm::strikes: the count of failed box tests after this frame (halved, + the miss).
fn strikes(prev: f32, hit: f32) -> f32 {
    return STRIKE_DECAY * prev + hit;
}

// phlm::ramp: the ramp of a miss for the test box lo..hi, max(fail_ramp, fail_ramp_box *
// the largest channel of hi - lo).
fn ramp(lo: vec3<f32>, hi: vec3<f32>) -> f32 {
    let e = hi - lo;
    return max(P.fail_ramp, P.fail_ramp_box * max(max(e.x, e.y), e.z));
}

// phlm::miss: how much of a failure a box test is, from the prediction q and where the
// clip took it (w = 1 when it moved): min(1, d / r), d the largest channel of |q - c|;
// 1 with no ramp, 0 inside the box.
fn miss(q: vec3<f32>, c: vec4<f32>, r: f32) -> f32 {
    if c.w == 0.0 {
        return 0.0;
    }
    if r == 0.0 {
        return 1.0;
    }
    let d = abs(q - c.xyz);
    return min(max(max(d.x, d.y), d.z) / r, 1.0);
}

// phlm::jump: how many times a failure counts where the speed changed (1 to 2).
fn jump(v: f32, v_prev: f32) -> f32 {
    if P.speed_jump == 0.0 {
        return 1.0;
    }
    return 1.0 + min(abs(v - v_prev) / P.speed_jump, 1.0);
}

// phlm::history_depth: a positive depth (infinity as f32::MAX), else 0 (unknown).
fn history_depth(d: f32) -> f32 {
    if d > 0.0 {
        return min(d, F32_MAX);
    }
    return 0.0;
}

// The 3x3 range of history depths around (x, y), edges clamped (kernel::depth_range_row).
fn depth_range(x: u32, y: u32) -> vec2<f32> {
    let n = plane_len();
    var lo = F32_MAX;
    var hi = 0.0;
    for (var dy = -1; dy <= 1; dy++) {
        let yy = u32(clamp(i32(y) + dy, 0, i32(P.height) - 1));
        for (var dx = -1; dx <= 1; dx++) {
            let xx = u32(clamp(i32(x) + dx, 0, i32(P.width) - 1));
            let d = history_depth(inp[IN_DEPTH * n + yy * P.width + xx]);
            lo = min(lo, d);
            hi = max(hi, d);
        }
    }
    return vec2<f32>(lo, hi);
}


// phlm::depth_share: how far (0 to 1) the history's depth lies outside the 3x3 range,
// weighed by the speed v.
fn depth_share(range: vec2<f32>, d_prev: f32, v: f32) -> f32 {
    if P.depth_jump == 0.0 || d_prev <= 0.0 || range.y <= 0.0 {
        return 0.0;
    }
    let below = (range.x - d_prev) / d_prev;
    let above = (d_prev - range.y) / range.y;
    return min(max(max(below, above), 0.0) / P.depth_jump, 1.0) * min(v / DEPTH_JUMP_SPEED, 1.0);
}

// phlm::forgetting: lambda, falling with the speed v toward lambda_moving.
fn forgetting(v: f32) -> f32 {
    if P.lambda_moving == 0.0 {
        return P.lambda;
    }
    return P.lambda + (P.lambda_moving - P.lambda) * min(v / P.lambda_speed, 1.0);
}

// A Cholesky pivot held at or above `floor` (rls::cholesky with a floor); its square
// root, or -1 for a non-finite one.
fn pivot_root(s: f32, floor: f32) -> f32 {
    if !finite(s) {
        return -1.0;
    }
    return sqrt(select(floor, s, s > floor));
}

// rls::update_information_f32: R = lambda R + (1 - lambda) prior I + x x^T (one rounding per
// entry), beta += R^-1 x e, the pivots held at or above `P.pivot_floor` (the prior, or
// 1 / clip_p where clips can take R below the prior). Returns trace(R^-1), or -1 when R
// is not finite (m unchanged).
fn update(m: ptr<function, Model>, x: vec4<f32>, e: vec3<f32>, lambda: f32, prior: f32) -> f32 {
    let q = (1.0 - lambda) * prior;
    let ra = (*m).ra;
    let rb = (*m).rb;
    let rc = (*m).rc;
    let a00 = fma(lambda, ra.x, x.x * x.x + q);
    let a01 = fma(lambda, ra.y, x.x * x.y);
    let a02 = fma(lambda, ra.z, x.x * x.z);
    let a03 = fma(lambda, ra.w, x.x * x.w);
    let a11 = fma(lambda, rb.x, x.y * x.y + q);
    let a12 = fma(lambda, rb.y, x.y * x.z);
    let a13 = fma(lambda, rb.z, x.y * x.w);
    let a22 = fma(lambda, rb.w, x.z * x.z + q);
    let a23 = fma(lambda, rc.x, x.z * x.w);
    let a33 = fma(lambda, rc.y, x.w * x.w + q);
    // Cholesky with reciprocal pivots (rls::cholesky).
    let l00 = pivot_root(a00, P.pivot_floor);
    let i0 = 1.0 / l00;
    let l10 = a01 * i0;
    let l11 = pivot_root(a11 - l10 * l10, P.pivot_floor);
    let i1 = 1.0 / l11;
    let l20 = a02 * i0;
    let l21 = (a12 - l20 * l10) * i1;
    let l22 = pivot_root(a22 - l20 * l20 - l21 * l21, P.pivot_floor);
    let i2 = 1.0 / l22;
    let l30 = a03 * i0;
    let l31 = (a13 - l30 * l10) * i1;
    let l32 = (a23 - l30 * l20 - l31 * l21) * i2;
    let l33 = pivot_root(a33 - l30 * l30 - l31 * l31 - l32 * l32, P.pivot_floor);
    let i3 = 1.0 / l33;
    if l00 < 0.0 || l11 < 0.0 || l22 < 0.0 || l33 < 0.0 {
        return -1.0;
    }
    // Forward and back substitution (rls::solve).
    let w0 = x.x * i0;
    let w1 = (x.y - l10 * w0) * i1;
    let w2 = (x.z - l20 * w0 - l21 * w1) * i2;
    let w3 = (x.w - l30 * w0 - l31 * w1 - l32 * w2) * i3;
    let g3 = w3 * i3;
    let g2 = (w2 - l32 * g3) * i2;
    let g1 = (w1 - l21 * g2 - l31 * g3) * i1;
    let g0 = (w0 - l10 * g1 - l20 * g2 - l30 * g3) * i0;
    let g = vec4<f32>(g0, g1, g2, g3);
    (*m).b0 += g * e.x;
    (*m).b1 += g * e.y;
    (*m).b2 += g * e.z;
    (*m).ra = vec4<f32>(a00, a01, a02, a03);
    (*m).rb = vec4<f32>(a11, a12, a13, a22);
    (*m).rc = vec2<f32>(a23, a33);
    // trace(R^-1) = ||L^-1||_F^2, column by column (rls::trace_of_inverse).
    let m10 = (-l10 * i0) * i1;
    let m20 = (-l20 * i0 - l21 * m10) * i2;
    let m30 = (-l30 * i0 - l31 * m10 - l32 * m20) * i3;
    let m21 = (-l21 * i1) * i2;
    let m31 = (-l31 * i1 - l32 * m21) * i3;
    let m32 = (-l32 * i2) * i3;
    return i0 * i0 + m10 * m10 + m20 * m20 + m30 * m30 + i1 * i1 + m21 * m21 + m31 * m31 + i2 * i2
        + m32 * m32 + i3 * i3;
}

fn finite4(b: vec4<f32>) -> bool {
    return finite(b.x) && finite(b.y) && finite(b.z) && finite(b.w);
}

fn beta_finite(m: Model) -> bool {
    return finite4(m.b0) && finite4(m.b1) && finite4(m.b2);
}

// One column of a 3x3 neighbourhood: min, max, sum and sum of squares of its three rows
// (kernels::for_each_row_stats's vertical pass), and its middle tap.
struct Column {
    lo: vec3<f32>,
    hi: vec3<f32>,
    sum: vec3<f32>,
    sq: vec3<f32>,
    centre: vec3<f32>,
}

fn column(x: i32, y: i32) -> Column {
    let u = working_ycocg(x, y - 1);
    let v = working_ycocg(x, y);
    let t = working_ycocg(x, y + 1);
    return Column(min(min(u, v), t), max(max(u, v), t), u + v + t, u * u + v * v + t * t, v);
}

// Planes k .. k + 3 of beta (part BETA) or R of the next models at pixel i.
fn store4(part: u32, k: u32, i: u32, v: vec4<f32>) {
    let n = plane_len();
    if part == BETA {
        next_beta[k * n + i] = v.x;
        next_beta[(k + 1u) * n + i] = v.y;
        next_beta[(k + 2u) * n + i] = v.z;
        next_beta[(k + 3u) * n + i] = v.w;
    } else {
        next_info[k * n + i] = v.x;
        next_info[(k + 1u) * n + i] = v.y;
        next_info[(k + 2u) * n + i] = v.z;
        next_info[(k + 3u) * n + i] = v.w;
    }
}

fn resolve_pixel(x: u32, y: u32) {
    let n = plane_len();
    let i = y * P.width + x;
    let input = working(i);

    // The 3x3 statistics in YCoCg (kernels::for_each_row_stats, edges clamped), summed as
    // the CPU sums them: each column's three rows, then the three columns.
    let left = column(i32(x) - 1, i32(y));
    let middle = column(i32(x), i32(y));
    let right = column(i32(x) + 1, i32(y));
    let lo = min(min(left.lo, middle.lo), right.lo);
    let hi = max(max(left.hi, middle.hi), right.hi);
    let cur = middle.centre;
    let mean = (left.sum + middle.sum + right.sum) * (1.0 / 9.0);

    // The motion every stage reads: dilated (passes::dilate_motion) when `dilate` runs.
    var mv = vec2<f32>(0.0);
    var speed = 0.0;
    if has(FLAG_MOTION) {
        if has(FLAG_DILATE) {
            mv = dilated_motion(x, y);
        } else {
            mv = vec2<f32>(inp[IN_MX * n + i], inp[IN_MY * n + i]);
        }
        speed = sqrt(mv.x * mv.x + mv.y * mv.y);
    }
    // Where the history is (phlm::From): nowhere, here, or at the previous position.
    var found = has(FLAG_HISTORY);
    var t = Bilinear(i, i, i, i, 0.0, 0.0);
    var cr: CatmullRom;
    var moved = false;
    if found && has(FLAG_REPROJECT) {
        let px = f32(x) + 0.5 + mv.x;
        let py = f32(y) + 0.5 + mv.y;
        // passes::on_screen.
        found = px >= 0.0 && px <= f32(P.width) && py >= 0.0 && py <= f32(P.height);
        if found {
            t = taps(px, py);
            moved = true;
            if has(FLAG_CATMULL_ROM) {
                cr = catmull_rom_footprint(px, py, P.width, P.height);
            }
        }
    }
    let invalid = has(FLAG_INVALID) && inp[IN_INVALID * n + i] != 0.0;

    // The feature (sec. 5.1; sec. 6: initialised with the input).
    var z = input;
    if found {
        let prev = vec3<f32>(fetch(Z, 0u, t), fetch(Z, 1u, t), fetch(Z, 2u, t));
        if invalid {
            z = prev;
        } else {
            z = accumulate(prev, ycocg_to_rgb(mean), lo.x, hi.x, speed);
        }
    }

    // Algorithm 1.
    var m: Model;
    if found && moved && has(FLAG_CATMULL_ROM) {
        // phlm::fetch_model: beta by Catmull-Rom, R bilinear.
        m.b0 = beta_catmull_rom4(0u, &cr);
        m.b1 = beta_catmull_rom4(4u, &cr);
        m.b2 = beta_catmull_rom4(8u, &cr);
    } else if found {
        m.b0 = fetch4(BETA, 0u, t);
        m.b1 = fetch4(BETA, 4u, t);
        m.b2 = fetch4(BETA, 8u, t);
    }
    if found {
        m.ra = fetch4(R, 0u, t);
        m.rb = fetch4(R, 4u, t);
        m.rc = vec2<f32>(fetch(R, 8u, t), fetch(R, 9u, t));
    } else {
        atomicAdd(&wg_counts[C_RESET], 1u);
        if has(FLAG_HISTORY) {
            atomicAdd(&wg_counts[C_OFFSCREEN], 1u);
        }
        m = model_reset(input, P.p0);
    }
    let xf = vec4<f32>(1.0, z);
    // The count of failed box tests, read as R is (0 without history).
    // And the speed stored with it (phlm::jump).
    // And the depth (phlm::depth_share).
    var s_prev = 0.0;
    var v_prev = 0.0;
    var d_prev = 0.0;
    if found {
        s_prev = fetch(Z, 3u, t);
        v_prev = fetch(Z, 4u, t);
        d_prev = fetch(Z, 5u, t);
    }
    var depth = 0.0;
    if has(FLAG_DEPTH) {
        depth = history_depth(inp[IN_DEPTH * n + i]);
    }
    var s = strikes(s_prev, 0.0);
    if !invalid {
        // Lines 12-19: predict; outside the box, clip toward the input and reset.
        var pred = predict(m, xf);
        var blo = lo;
        var bhi = hi;
        if has(FLAG_VARIANCE_BOX) {
            // kernels::variance_box (Salvi 2016) within the min/max box.
            let mean_sq = (left.sq + middle.sq + right.sq) * (1.0 / 9.0);
            let sigma = sqrt(max(mean_sq - mean * mean, vec3<f32>(0.0)));
            blo = max(mean - P.test_gamma * sigma, lo);
            bhi = min(mean + P.test_gamma * sigma, hi);
        }
        let q = rgb_to_ycocg(pred);
        let clipped = clip_toward_point(q, cur, blo, bhi);
        // A failure clips once it persists (clip_after); before, it relaxes R (fail_keep).
        // Each counts, and relaxes, as much as it missed by (fail_ramp).
        // Twice where the speed jumped or the history's depth left the 3x3 range.
        var depth_jump = 1.0;
        if has(FLAG_DEPTH) && P.depth_jump > 0.0 {
            depth_jump = 1.0 + depth_share(depth_range(x, y), d_prev, speed);
        }
        let hit = miss(q, clipped, ramp(blo, bhi)) * max(jump(speed, v_prev), depth_jump);
        s = strikes(s_prev, hit);
        if hit > 0.0 && s >= P.clip_after {
            atomicAdd(&wg_counts[C_CLIPPED], 1u);
            model_clip(&m, pred, ycocg_to_rgb(clipped.xyz));
        } else if hit > 0.0 {
            // phlm::fail_relax: fail_keep for a whole miss or more, in proportion for less.
            let keep = 1.0 - min(hit, 1.0) * (1.0 - P.fail_keep);
            if keep != 1.0 {
                relax(&m, keep);
            }
        }
        // Lines 19-21: the (possibly reset) model's error, the RLS update.
        pred = predict(m, xf);
        let tr = update(&m, xf, input - pred, forgetting(speed), 1.0 / P.p0);
        if tr < 0.0 || !beta_finite(m) {
            atomicAdd(&wg_counts[C_REPAIRED], 1u);
            m = model_reset(input, P.p0);
        } else {
            atomicMax(&wg_counts[C_TRACE], bitcast<u32>(tr));
        }
    }

    // Line 22: the output, and the next state.
    var o = min(max(predict(m, xf), vec3<f32>(0.0)), vec3<f32>(P.hi));
    if has(FLAG_TONEMAP) {
        o = tonemap_inverse(o);
    }
    out[i] = o.x;
    out[n + i] = o.y;
    out[2u * n + i] = o.z;
    store4(BETA, 0u, i, m.b0);
    store4(BETA, 4u, i, m.b1);
    store4(BETA, 8u, i, m.b2);
    store4(R, 0u, i, m.ra);
    store4(R, 4u, i, m.rb);
    next_info[8u * n + i] = m.rc.x;
    next_info[9u * n + i] = m.rc.y;
    next_feat[i] = z.x;
    next_feat[n + i] = z.y;
    next_feat[2u * n + i] = z.z;
    next_feat[3u * n + i] = s;
    next_feat[4u * n + i] = speed;
    next_feat[5u * n + i] = depth;
}
