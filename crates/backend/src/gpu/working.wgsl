// The working colour of the filters that tonemap HDR input (taa, traa, phlm: their
// `FLAG_TONEMAP`), read from the colour planes of `inp` (`frame.wgsl`). Added to their
// shaders by the host (`gpu::WORKING`).

fn input_color(i: u32) -> vec3<f32> {
    let n = plane_len();
    return vec3<f32>(inp[IN_R * n + i], inp[(IN_R + 1u) * n + i], inp[(IN_R + 2u) * n + i]);
}

// The working colour (tonemapped for HDR input) of pixel i (passes::to_working).
fn working(i: u32) -> vec3<f32> {
    let c = input_color(i);
    if has(FLAG_TONEMAP) {
        return tonemap(c);
    }
    return c;
}

// The working colour in YCoCg at pixel (x, y) clamped to the image (passes::to_ycocg).
fn working_ycocg(x: i32, y: i32) -> vec3<f32> {
    return rgb_to_ycocg(working(clamped(x, y)));
}
