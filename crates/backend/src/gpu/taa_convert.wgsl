// `convert`: passes::convert_texel_history, in place on the history texels.
@group(0) @binding(0) var<storage, read> C: Params;
@group(0) @binding(1) var<storage, read_write> texels: array<f32>;

@compute @workgroup_size(CONVERT_GROUP)
fn convert(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) groups: vec3<u32>) {
    let i = gid.x + gid.y * groups.x * CONVERT_GROUP;
    if i >= C.width * C.height {
        return;
    }
    let rgb = max(ycocg_to_rgb(vec3<f32>(texels[4u * i], texels[4u * i + 1u], texels[4u * i + 2u])), vec3<f32>(0.0));
    var c: vec3<f32>;
    if (C.flags & FLAG_TO_TONEMAPPED) != 0u {
        c = tonemap(rgb);
    } else {
        c = tonemap_inverse(rgb);
    }
    let t = rgb_to_ycocg(c);
    texels[4u * i] = t.x;
    texels[4u * i + 1u] = t.y;
    texels[4u * i + 2u] = t.z;
}
