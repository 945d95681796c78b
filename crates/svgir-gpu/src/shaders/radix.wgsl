// One pass of a stable LSD radix sort of (key, value) u32 pairs on 4 bits at `shift`.
// Work split: blocks of 1024 pairs, one workgroup of 256 threads each.
// - `histogram`: per block, how many keys have each digit, into counts[digit * blocks + block]
//   (digit-major, so that the exclusive scan of `counts` gives each (digit, block) its first
//   output slot);
// - `scatter`: each block writes its pairs to those slots, in order within a digit. Ranks inside
//   the block come from a workgroup scan of one-hot digit counters packed 8 bits to a digit (four
//   digits a word): a chunk of 256 keys has exclusive counts below 256, which the bytes hold.
// Stability (equal keys keep their order) is what makes (tile, depth, id) order out of passes on
// the depth and then the tile.

struct SortParams {
    // Pairs the buffers hold (the dispatch covers them).
    n: u32,
    shift: u32,
    blocks: u32,
    // 1: sort only the first `nbuf[0]` pairs (the entries a render kept, counted on the GPU).
    counted: u32,
}

@group(0) @binding(0) var<uniform> R: SortParams;
@group(0) @binding(1) var<storage, read> keys_in: array<u32>;
@group(0) @binding(2) var<storage, read> vals_in: array<u32>;
@group(0) @binding(3) var<storage, read_write> counts: array<u32>;
@group(0) @binding(4) var<storage, read_write> keys_out: array<u32>;
@group(0) @binding(5) var<storage, read_write> vals_out: array<u32>;
@group(0) @binding(6) var<storage, read> nbuf: array<u32>;

fn pairs() -> u32 {
    return select(R.n, min(R.n, nbuf[0]), R.counted != 0u);
}

var<workgroup> hist: array<atomic<u32>, 16>;
var<workgroup> packed: array<vec4<u32>, 256>;
var<workgroup> running: array<u32, 16>;
var<workgroup> last_excl: vec4<u32>;
var<workgroup> last_digit: u32;

fn block_of(wid: vec3<u32>, nwg: vec3<u32>) -> u32 {
    return wid.x + wid.y * nwg.x;
}

@compute @workgroup_size(256)
fn histogram(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>, @builtin(local_invocation_index) tid: u32) {
    let block = block_of(wid, nwg);
    let n = pairs();
    if tid < 16u {
        atomicStore(&hist[tid], 0u);
    }
    workgroupBarrier();
    for (var c = 0u; c < 4u; c++) {
        let i = block * 1024u + c * 256u + tid;
        if i < n {
            atomicAdd(&hist[(keys_in[i] >> R.shift) & 15u], 1u);
        }
    }
    workgroupBarrier();
    if tid < 16u && block < R.blocks {
        counts[tid * R.blocks + block] = atomicLoad(&hist[tid]);
    }
    // Keep the bindings of `scatter` alive in this entry point's layout.
    if R.n == 0xffffffffu {
        keys_out[0] = vals_in[0];
        vals_out[0] = 0u;
    }
}

fn onehot(d: u32) -> vec4<u32> {
    if d >= 16u {
        return vec4<u32>(0u);
    }
    let bit = 1u << ((d & 3u) * 8u);
    let w = d >> 2u;
    return vec4<u32>(select(0u, bit, w == 0u), select(0u, bit, w == 1u), select(0u, bit, w == 2u), select(0u, bit, w == 3u));
}

fn byte_of(v: vec4<u32>, d: u32) -> u32 {
    return (v[d >> 2u] >> ((d & 3u) * 8u)) & 255u;
}

@compute @workgroup_size(256)
fn scatter(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>, @builtin(local_invocation_index) tid: u32) {
    let block = block_of(wid, nwg);
    let n = pairs();
    if tid < 16u && block < R.blocks {
        running[tid] = counts[tid * R.blocks + block];
    }
    for (var c = 0u; c < 4u; c++) {
        let i = block * 1024u + c * 256u + tid;
        let valid = i < n;
        var k = 0u;
        var v = 0u;
        if valid {
            k = keys_in[i];
            v = vals_in[i];
        }
        let d = select(16u, (k >> R.shift) & 15u, valid);
        let own = onehot(d);
        packed[tid] = own;
        workgroupBarrier();
        for (var off = 1u; off < 256u; off *= 2u) {
            let mine = packed[tid];
            let add = select(vec4<u32>(0u), packed[max(tid, off) - off], tid >= off);
            workgroupBarrier();
            packed[tid] = mine + add;
            workgroupBarrier();
        }
        // Exclusive counts: wrapping arithmetic undoes the carry of a byte that reached 256.
        let excl = packed[tid] - own;
        if valid {
            let dst = running[d] + byte_of(excl, d);
            keys_out[dst] = k;
            vals_out[dst] = v;
        }
        if tid == 255u {
            last_excl = excl;
            last_digit = d;
        }
        workgroupBarrier();
        if tid < 16u {
            running[tid] += byte_of(last_excl, tid) + select(0u, 1u, last_digit == tid);
        }
        workgroupBarrier();
    }
}
