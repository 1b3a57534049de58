// `sharpen` reads the resolved working colour (`src`, the resolve's output) and writes
// `dst`: passes::sharpen (kernels::sharpen_cross, thesis eq. 4.17) clamped to
// [0, S.top] (passes::output_ceiling), then back to linear in the tonemapped space.
// `traa` runs it too, with its variant's strength (eq. 3.1 or 4.17): the module that
// precedes this file declares `Params` (with `width`, `height`, `flags`, `sharpen`,
// `top`), FLAG_TONEMAP and WORKGROUP.
@group(0) @binding(0) var<storage, read> S: Params;
@group(0) @binding(1) var<storage, read> src: array<f32>;
@group(0) @binding(2) var<storage, read_write> dst: array<f32>;

@compute @workgroup_size(WORKGROUP, WORKGROUP)
fn sharpen(@builtin(global_invocation_id) gid: vec3<u32>) {
    let x = gid.x;
    let y = gid.y;
    let w = S.width;
    let h = S.height;
    if x >= w || y >= h {
        return;
    }
    let n = w * h;
    let up = select(y - 1u, 0u, y == 0u) * w;
    let down = min(y + 1u, h - 1u) * w;
    let left = select(x - 1u, 0u, x == 0u);
    let right = min(x + 1u, w - 1u);
    let tonemapped = (S.flags & FLAG_TONEMAP) != 0u;
    let top = S.top;
    var c: vec3<f32>;
    for (var k = 0u; k < 3u; k++) {
        let o = k * n;
        let v = src[o + y * w + x];
        let around = src[o + up + x] + src[o + y * w + left] + src[o + y * w + right] + src[o + down + x];
        c[k] = clamp(v + S.sharpen * (v - 0.25 * around), 0.0, top);
    }
    if tonemapped {
        c = tonemap_inverse(c);
    }
    let i = y * w + x;
    dst[i] = c.x;
    dst[n + i] = c.y;
    dst[2u * n + i] = c.z;
}
