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

// Declared before the shaders from Rust (`gpu::taa::consts`): the FLAG_ bits of
// `Params.flags`, the IN_ planes of `inp` in units of width * height, COUNTERS and the C_
// counters (history reset, clipped, rejected by depth), WORKGROUP and CONVERT_GROUP, and
// MAX_COUNT of the CPU filter.
