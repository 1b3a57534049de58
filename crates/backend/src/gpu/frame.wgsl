// What the shaders of the history filters (taa's resolve, traa's stages, phlm, upsample)
// share about their frame: the filter's parameters `P` (its own `Params`, with `flags`,
// `width` and `height`) and its input planes `inp` at bindings 0 and 1, and how pixels
// are indexed. Added to each of those shaders by the host (`gpu::FRAME`).

@group(0) @binding(0) var<storage, read> P: Params;
@group(0) @binding(1) var<storage, read> inp: array<f32>;

fn has(f: u32) -> bool {
    return (P.flags & f) != 0u;
}

fn plane_len() -> u32 {
    return P.width * P.height;
}

// The index of pixel (x, y) clamped to the image (kernels::fetch_clamped).
fn clamped(x: i32, y: i32) -> u32 {
    let cx = u32(clamp(x, 0, i32(P.width) - 1));
    let cy = u32(clamp(y, 0, i32(P.height) - 1));
    return cy * P.width + cx;
}
