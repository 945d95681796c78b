// The feature raster's per-Gaussian gradients: one thread per (Gaussian, slot float), adding the
// Gaussian's entry slots (feat_bwd.wgsl) in entry order, so adjacent threads read adjacent
// floats and the sums are the same at every run. Float 0 goes through the opacity's sigmoid
// (dL/d logit = dL/do o (1 - o)); the others are the weight sum and the feature rows'
// gradients, as they are. Entries past the capacity were dropped (an overflowed render).

@group(0) @binding(0) var<uniform> P: Params;
@group(0) @binding(1) var<uniform> F: Feat;
@group(0) @binding(2) var<storage, read> splat: array<f32>;
@group(0) @binding(3) var<storage, read> rank: array<u32>;
@group(0) @binding(4) var<storage, read> off: array<u32>;
@group(0) @binding(5) var<storage, read> cnt: array<u32>;
@group(0) @binding(6) var<storage, read> slots: array<f32>;
// Per Gaussian F.fd floats, the slot layout.
@group(0) @binding(7) var<storage, read_write> vfeat: array<f32>;

@compute @workgroup_size(256)
fn main(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = gid.x + gid.y * nwg.x * 256u;
    if i >= P.n * F.fd {
        return;
    }
    let g = i / F.fd;
    let q = i % F.fd;
    let k = rank[g];
    let e0 = min(off[k], P.capacity);
    let e1 = min(off[k] + cnt[k], P.capacity);
    var s = 0.0;
    for (var e = e0; e < e1; e++) {
        s += slots[e * F.fd + q];
    }
    if q == 0u {
        let o = splat[g * SPLAT + S_OPACITY];
        s = s * o * (1.0 - o);
    }
    vfeat[i] = s;
}
