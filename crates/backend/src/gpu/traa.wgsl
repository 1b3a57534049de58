// `traa` on the GPU: the stages of `crate::filters::traa` (its scalar reference,
// `filters/traa/reference.rs`, is the statement of what is computed; every function here
// names the CPU function it mirrors).
//
// This file holds the parameters every entry point reads; `traa_resolve.wgsl` (the
// stages up to the resolve) and `taa_sharpen.wgsl` (taa's sharpen, the same cross sharpen
// of eq. 3.1 / 4.17) follow it in their own modules.
//
// Entry points:
// - `sobel` (improved): the raw Sobel of eq. 4.9-4.10 per pixel.
// - `sobel_history` (improved): the Sobel image's own TRAA (sec. 4.3.3), or the raw Sobel
//   where there is no history.
// - `resolve`: reprojection, eq. 4.1, eq. 4.4-4.6, eq. 4.12-4.16 (improved) or the
//   averaged boxes (baseline), the clip and INSIDE's feedback; writes the next history
//   and the colour (linear, or working space when a sharpen follows).
// - `sharpen`: the cross sharpen of the working colour, then back to linear.

struct Params {
    width: u32,
    height: u32,
    // Bits: see the FLAG_ constants.
    flags: u32,
    // Channels of a history texel: 3 (baseline: r, g, b) or 4 (improved: and the Sobel
    // history); the depth / far plane follows the texels.
    texel: u32,
    feedback_min: f32,
    feedback_max: f32,
    // The sharpen strength of the variant (eq. 3.1 or 4.17).
    sharpen: f32,
    // The sharpen's upper bound: passes::output_ceiling.
    top: f32,
    // What depth is divided by (Traa::depth_far).
    far: f32,
}

// Declared before the shaders from Rust (`gpu::traa::consts`): the FLAG_ bits of
// `Params.flags`, the IN_ planes of `inp`, COUNTERS and the C_ counters (history reset,
// clipped), WORKGROUP, SOBEL_TEXEL (the Sobel history's channel of a texel), and the CPU
// filter's constants FEEDBACK_LUMA_FLOOR, SOBEL_UNLIT_WEIGHT, SOBEL_LIT_WEIGHT and
// DEPTH_DISTANCE_MIN.
