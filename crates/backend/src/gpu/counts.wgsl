// The pass of a filter's per-pixel work (its `resolve_pixel`), one invocation a pixel,
// and the pixels it counts: kept per workgroup and added to the filter's `counters` once
// per workgroup, not once per pixel. The counts before `SUMMED` are sums, those from it on
// keep their largest value. Added to the shaders of taa's and traa's resolve and of phlm
// by the host (`gpu::COUNTS`); each declares `counters`, `COUNTERS` and `SUMMED`.

var<workgroup> wg_counts: array<atomic<u32>, COUNTERS>;

@compute @workgroup_size(WORKGROUP, WORKGROUP)
fn resolve(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(local_invocation_index) li: u32) {
    if li < COUNTERS {
        atomicStore(&wg_counts[li], 0u);
    }
    workgroupBarrier();
    if gid.x < P.width && gid.y < P.height {
        resolve_pixel(gid.x, gid.y);
    }
    workgroupBarrier();
    if li < SUMMED {
        let c = atomicLoad(&wg_counts[li]);
        if c != 0u {
            atomicAdd(&counters[li], c);
        }
    } else if li < COUNTERS {
        atomicMax(&counters[li], atomicLoad(&wg_counts[li]));
    }
}
