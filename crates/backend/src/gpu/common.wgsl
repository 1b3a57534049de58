// What every filter's shaders share: the colour transforms of `crate::kernels`, each
// naming the CPU function it mirrors, and small numeric helpers. A filter's module source
// is this file followed by the filter's own (`gpu::pipeline` joins them).

// Declared before this file from Rust (`gpu::common_consts`): TONEMAP_MAX, F32_MAX,
// CLIP_EPS, CLIP_REL, and LUMA_R, LUMA_G, LUMA_B.

// kernels::tonemap: c / (1 + max c).
fn tonemap(c: vec3<f32>) -> vec3<f32> {
    return c * (1.0 / (1.0 + max(max(c.x, c.y), c.z)));
}

// kernels::tonemap_inverse: t / (1 - max t), max held below 1.
fn tonemap_inverse(t: vec3<f32>) -> vec3<f32> {
    let m = min(max(max(t.x, t.y), t.z), TONEMAP_MAX);
    return t * (1.0 / (1.0 - m));
}

// kernels::luma: Rec. 709 luma of linear RGB (`luma_of`: fxaa binds a buffer `luma`).
fn luma_of(c: vec3<f32>) -> f32 {
    return LUMA_R * c.x + LUMA_G * c.y + LUMA_B * c.z;
}

// kernels::rgb_to_ycocg (Malvar and Sullivan 2003).
fn rgb_to_ycocg(c: vec3<f32>) -> vec3<f32> {
    return vec3<f32>(
        0.25 * c.x + 0.5 * c.y + 0.25 * c.z,
        0.5 * c.x - 0.5 * c.z,
        -0.25 * c.x + 0.5 * c.y - 0.25 * c.z,
    );
}

// kernels::ycocg_to_rgb.
fn ycocg_to_rgb(c: vec3<f32>) -> vec3<f32> {
    let t = c.x - c.z;
    return vec3<f32>(t + c.y, c.x + c.z, t - c.y);
}

// kernels::sample's clamp_index: a whole number as f32 clamped into 0..n.
fn clamp_index(i: f32, n: u32) -> u32 {
    return u32(clamp(i, 0.0, f32(n - 1u)));
}

// kernels::bilinear's footprint at (px, py) (pixel units, centres at +0.5) on a
// width x height image: the four taps' pixel indices, clamped to the image, and the
// weights toward the second column and row.
struct Bilinear {
    i00: u32,
    i01: u32,
    i10: u32,
    i11: u32,
    tx: f32,
    ty: f32,
}

fn bilinear_taps(px: f32, py: f32, width: u32, height: u32) -> Bilinear {
    let fx = px - 0.5;
    let fy = py - 0.5;
    let x0 = floor(fx);
    let y0 = floor(fy);
    let xa = clamp_index(x0, width);
    let xb = clamp_index(x0 + 1.0, width);
    let ya = clamp_index(y0, height) * width;
    let yb = clamp_index(y0 + 1.0, height) * width;
    return Bilinear(ya + xa, ya + xb, yb + xa, yb + xb, fx - x0, fy - y0);
}

// a + (b - a) t, as kernels::bilinear interpolates (WGSL's mix may round otherwise).
fn lerp(a: f32, b: f32, t: f32) -> f32 {
    return a + (b - a) * t;
}

fn lerp4(a: vec4<f32>, b: vec4<f32>, t: f32) -> vec4<f32> {
    return a + (b - a) * t;
}

// The bilinear blend of four taps s = (s00, s01, s10, s11).
fn blend(s: vec4<f32>, b: Bilinear) -> f32 {
    return lerp(lerp(s.x, s.y, b.tx), lerp(s.z, s.w, b.tx), b.ty);
}

// Whether v is finite, from its bits (WGSL lets a compiler assume NaN and infinity away
// in comparisons, so `v != v` is no test).
fn finite(v: f32) -> bool {
    return (bitcast<u32>(v) & 0x7f800000u) != 0x7f800000u;
}

// kernels::clip::guard: how far a clip box [lo, hi] is grown on each side.
fn clip_guard(lo: vec3<f32>, hi: vec3<f32>) -> f32 {
    let m = max(abs(lo), abs(hi));
    return CLIP_EPS + CLIP_REL * max(max(m.x, m.y), m.z);
}

// kernels::clip_toward_center: q moved toward the centre of [lo, hi] until inside.
fn clip_toward_center(q: vec3<f32>, lo: vec3<f32>, hi: vec3<f32>) -> vec4<f32> {
    let center = 0.5 * (hi + lo);
    let extent = 0.5 * (hi - lo) + vec3<f32>(clip_guard(lo, hi));
    let v = q - center;
    let r = abs(v / extent);
    let worst = max(max(r.x, r.y), r.z);
    if worst > 1.0 {
        return vec4<f32>(center + v * (1.0 / worst), 1.0);
    }
    return vec4<f32>(q, 0.0);
}
