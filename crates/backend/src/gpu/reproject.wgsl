// What `taa` and `phlm` share to reproject: velocity dilation and the Catmull-Rom
// footprint. Appended to a filter's shader, which declares `P` (with `width`, `height`),
// `inp` and its planes `IN_MX`, `IN_MY`, `IN_DEPTH`, and `plane_len()`.

// passes::nearest_motion: the motion of the nearest (smallest depth) pixel of the 3x3,
// in-image neighbours only, rows then columns, the first of equal depths winning, the
// centre starting as the best.
fn dilated_motion(x: u32, y: u32) -> vec2<f32> {
    let n = plane_len();
    let w = P.width;
    var best = y * w + x;
    var best_d = inp[IN_DEPTH * n + best];
    let y0 = select(y - 1u, 0u, y == 0u);
    let y1 = min(y + 2u, P.height);
    let x0 = select(x - 1u, 0u, x == 0u);
    let x1 = min(x + 2u, w);
    for (var yy = y0; yy < y1; yy++) {
        for (var xx = x0; xx < x1; xx++) {
            let i = yy * w + xx;
            let d = inp[IN_DEPTH * n + i];
            if d < best_d {
                best_d = d;
                best = i;
            }
        }
    }
    return vec2<f32>(inp[IN_MX * n + best], inp[IN_MY * n + best]);
}

// kernels::sample's catmull_rom_weights.
fn catmull_rom_weights(t: f32) -> vec4<f32> {
    let t2 = t * t;
    let t3 = t2 * t;
    return vec4<f32>(
        -0.5 * t + t2 - 0.5 * t3,
        1.0 - 2.5 * t2 + 1.5 * t3,
        0.5 * t + 2.0 * t2 - 1.5 * t3,
        -0.5 * t2 + 0.5 * t3,
    );
}

// kernels::sample's Footprint: the Catmull-Rom footprint at (px, py), taps clamped to the
// image, the row weights divided by the sum of the twelve weights used (the 4x4 without
// its corners).
struct CatmullRom {
    xs: array<u32, 4>,
    ys: array<u32, 4>,
    wx: vec4<f32>,
    wy: vec4<f32>,
}

fn catmull_rom_footprint(px: f32, py: f32, width: u32, height: u32) -> CatmullRom {
    let fx = px - 0.5;
    let fy = py - 0.5;
    let x1 = floor(fx);
    let y1 = floor(fy);
    var f: CatmullRom;
    f.wx = catmull_rom_weights(fx - x1);
    let wy = catmull_rom_weights(fy - y1);
    let middle = f.wx.y + f.wx.z;
    let all = (f.wx.x + f.wx.y) + (f.wx.z + f.wx.w);
    let wsum = middle * (wy.x + wy.w) + all * (wy.y + wy.z);
    f.wy = wy / wsum;
    for (var k = 0; k < 4; k++) {
        f.xs[k] = clamp_index(x1 + f32(k - 1), width);
        f.ys[k] = clamp_index(y1 + f32(k - 1), height);
    }
    return f;
}
