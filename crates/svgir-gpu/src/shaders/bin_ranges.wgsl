// Binning, step 3: each tile's range [start, end) of the sorted entries (ranges zeroed first, so
// an empty tile has start == end == 0). One thread per entry of
// the capacity; those past the entries kept return.

@group(0) @binding(0) var<uniform> P: Params;
@group(0) @binding(1) var<storage, read> tkey: array<u32>;
@group(0) @binding(2) var<storage, read_write> ranges: array<u32>;
@group(0) @binding(3) var<storage, read> count: array<u32>;

@compute @workgroup_size(256)
fn main(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let s = gid.x + gid.y * nwg.x * 256u;
    let entries = min(count[C_KEPT], P.capacity);
    if s >= entries {
        return;
    }
    let t = tkey[s];
    if s == 0u || tkey[s - 1u] != t {
        ranges[t * 2u] = s;
    }
    if s + 1u == entries || tkey[s + 1u] != t {
        ranges[t * 2u + 1u] = s + 1u;
    }
}
