// The tile backwards' reduction (raster_bwd.wgsl, feat_bwd.wgsl): `stage_partials` puts each
// subgroup's sums into `partial`; `write_partials`, the last step, makes an entry's
// 24-float chunk from the subgroups' partial sums `partial[s][i]` (s < n_sg, i < 6 groups of
// four), into `grads[base ..]`, its first `count` floats. Subgroup s adds group s (with fewer
// than six subgroups, each takes every n_sg-th), each lane a strided share of the subgroups, then
// `subgroupAdd`; lane 0 writes. So every lane loops n_sg / sg_size times (once on 32-wide
// hardware, four times on lavapipe's eight) where one thread per group adding all n_sg
// partials looped n_sg times: the tile lists lavapipe's loop cap (loop_guard.wgsl) lets through
// grow about fivefold. The order of the additions is fixed: the same sums at every run. The
// kernel declares `partial` and `grads`, and calls this from uniform control flow after a
// barrier that follows the partials' writes.

// The first step: each subgroup's sums of its lanes' six groups into `partial[sg]`.
fn stage_partials(c0: vec4<f32>, c1: vec4<f32>, c2: vec4<f32>, c3: vec4<f32>, c4: vec4<f32>, c5: vec4<f32>, sg: u32, sg_lane: u32) {
    let s0 = subgroupAdd(c0);
    let s1 = subgroupAdd(c1);
    let s2 = subgroupAdd(c2);
    let s3 = subgroupAdd(c3);
    let s4 = subgroupAdd(c4);
    let s5 = subgroupAdd(c5);
    if sg_lane == 0u {
        partial[sg][0] = s0;
        partial[sg][1] = s1;
        partial[sg][2] = s2;
        partial[sg][3] = s3;
        partial[sg][4] = s4;
        partial[sg][5] = s5;
    }
}

fn write_partials(base: u32, count: u32, sg: u32, sg_lane: u32, sg_size: u32, n_sg: u32) {
    for (var i = sg; i < 6u; i += n_sg) {
        var v = vec4<f32>(0.0);
        for (var s = sg_lane; s < n_sg; s += sg_size) {
            v += partial[s][i];
        }
        let t = subgroupAdd(v);
        let q = 4u * i;
        if sg_lane == 0u {
            if q < count {
                grads[base + q] = t.x;
            }
            if q + 1u < count {
                grads[base + q + 1u] = t.y;
            }
            if q + 2u < count {
                grads[base + q + 2u] = t.z;
            }
            if q + 3u < count {
                grads[base + q + 3u] = t.w;
            }
        }
    }
}
