// `taa` on the GPU: the stages of `crate::filters::taa` (its scalar reference,
// `filters/taa/reference.rs`, is the statement of what is computed; every function here
// names the CPU function it mirrors).
//
// This file holds what the entry points share; each entry point's own bindings and code
// follow it in its own module (`taa_resolve.wgsl`, `taa_sharpen.wgsl`, `taa_convert.wgsl`).
//
// Entry points:
// - `resolve`: per pixel, tonemap + YCoCg of the 3x3 neighbourhood, velocity dilation,
//   reprojection (Catmull-Rom or bilinear), depth rejection, the variance-box clip and the
//   blend; writes the next history texel [Y, Co, Cg, count] (and depth) and the colour
//   (linear, or working space when a sharpen follows).
// - `sharpen`: the cross sharpen of the working colour, then back to linear.
// - `convert`: the history moved between linear and tonemapped working space when a stream
//   switches between LDR and HDR frames (`passes::convert_texel_history`).

struct Params {
    width: u32,
    height: u32,
    // Bits: see the FLAG_ constants.
    flags: u32,
    // Offset of the depth plane within `hist` (4 * width * height).
    depth_at: u32,
    alpha: f32,
    gamma: f32,
    depth_rejection: f32,
    sharpen: f32,
    // The sharpen's upper bound: passes::output_ceiling.
    top: f32,
}

const FLAG_TONEMAP: u32 = 1u;
const FLAG_DILATE: u32 = 2u;
const FLAG_REPROJECT: u32 = 4u;
const FLAG_DEPTH_REJECT: u32 = 8u;
const FLAG_HISTORY: u32 = 16u;
const FLAG_CATMULL_ROM: u32 = 32u;
const FLAG_LUMA_WEIGHT: u32 = 64u;
const FLAG_INVALID: u32 = 128u;
const FLAG_SHARPEN: u32 = 256u;
const FLAG_KEEP_DEPTH: u32 = 512u;
const FLAG_TO_TONEMAPPED: u32 = 1024u;

// Planes of `inp`, in units of width * height.
const IN_R: u32 = 0u;
const IN_MX: u32 = 3u;
const IN_MY: u32 = 4u;
const IN_DEPTH: u32 = 5u;
const IN_INVALID: u32 = 6u;

// Counters: history reset, clipped, rejected by depth.
const C_RESET: u32 = 0u;
const C_CLIPPED: u32 = 1u;
const C_REJECTED: u32 = 2u;

// `MAX_COUNT` of `filters/taa/mod.rs`.
const MAX_COUNT: f32 = 255.0;

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
