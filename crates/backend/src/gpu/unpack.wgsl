// The colour uploaded as f16 (`upload.rs`): two IEEE halves to a 32-bit word, the first in
// the low 16 bits, widened to the f32 planes the filters' shaders read. `unpack2x16float`
// is core WGSL: no shader-f16 feature needed.

struct UnpackParams {
    // Halves to widen (3 * width * height).
    count: u32,
    pad0: u32,
    pad1: u32,
    pad2: u32,
}

@group(0) @binding(0) var<storage, read> U: UnpackParams;
@group(0) @binding(1) var<storage, read> packed: array<u32>;
@group(0) @binding(2) var<storage, read_write> dst: array<f32>;

// UNPACK_GROUP is declared before this file from Rust (`gpu::upload`).
@compute @workgroup_size(UNPACK_GROUP)
fn unpack(@builtin(global_invocation_id) id: vec3<u32>, @builtin(num_workgroups) groups: vec3<u32>) {
    let w = id.x + id.y * groups.x * UNPACK_GROUP;
    let at = 2u * w;
    if at >= U.count {
        return;
    }
    let v = unpack2x16float(packed[w]);
    dst[at] = v.x;
    if at + 1u < U.count {
        dst[at + 1u] = v.y;
    }
}
