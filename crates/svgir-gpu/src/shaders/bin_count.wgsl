// Binning, step 1: per Gaussian in depth order (the depth sort's values), its tile count and its
// rank. `off` receives the counts, which the driver then scans into each Gaussian's first entry.
// One thread per Gaussian.

@group(0) @binding(0) var<uniform> P: Params;
@group(0) @binding(1) var<storage, read> order: array<u32>;
@group(0) @binding(2) var<storage, read> tiles_n: array<u32>;
@group(0) @binding(3) var<storage, read_write> cnt: array<u32>;
@group(0) @binding(4) var<storage, read_write> off: array<u32>;
@group(0) @binding(5) var<storage, read_write> rank: array<u32>;

@compute @workgroup_size(256)
fn main(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let k = gid.x + gid.y * nwg.x * 256u;
    if k >= P.n {
        return;
    }
    let g = order[k];
    let c = tiles_n[g];
    cnt[k] = c;
    off[k] = c;
    rank[g] = k;
}
