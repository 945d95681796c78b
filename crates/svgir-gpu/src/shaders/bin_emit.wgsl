// Binning, step 2: each Gaussian (in depth order) writes one entry per tile its box touches, at
// its scanned offset: the tile as the sort key, the entry's own index as the value (so that after
// the stable sort by tile each tile's list is in (depth, id) order and each entry still names its
// slot), and the Gaussian of each entry. One thread per Gaussian.

@group(0) @binding(0) var<uniform> P: Params;
@group(0) @binding(1) var<storage, read> order: array<u32>;
@group(0) @binding(2) var<storage, read> off: array<u32>;
@group(0) @binding(3) var<storage, read> cnt: array<u32>;
@group(0) @binding(4) var<storage, read> rect: array<u32>;
@group(0) @binding(5) var<storage, read_write> tkey: array<u32>;
@group(0) @binding(6) var<storage, read_write> tval: array<u32>;
@group(0) @binding(7) var<storage, read_write> egauss: array<u32>;

@compute @workgroup_size(256)
fn main(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let k = gid.x + gid.y * nwg.x * 256u;
    if k >= P.n || cnt[k] == 0u {
        return;
    }
    let g = order[k];
    let tx0 = rect[g * 4u] / TILE;
    let tx1 = (rect[g * 4u + 1u] - 1u) / TILE + 1u;
    let ty0 = rect[g * 4u + 2u] / TILE;
    let ty1 = (rect[g * 4u + 3u] - 1u) / TILE + 1u;
    var o = off[k];
    for (var ty = ty0; ty < ty1; ty++) {
        for (var tx = tx0; tx < tx1; tx++) {
            if o < P.capacity {
                tkey[o] = ty * P.tiles_x + tx;
                tval[o] = o;
                egauss[o] = g;
            }
            o++;
        }
    }
}
