// Exclusive prefix sum of u32s, in place, in blocks of 1024 (256 threads, 4 values each): each
// block scans its values and writes its total to `sums`; the driver scans `sums` the same way
// (recursively) and `add` then adds each block's offset. Work split: one workgroup per block.

struct ScanParams {
    n: u32,
    _p0: u32,
    _p1: u32,
    _p2: u32,
}

@group(0) @binding(0) var<uniform> S: ScanParams;
@group(0) @binding(1) var<storage, read_write> data: array<u32>;
@group(0) @binding(2) var<storage, read_write> sums: array<u32>;

var<workgroup> part: array<u32, 256>;

fn block_of(wid: vec3<u32>, nwg: vec3<u32>) -> u32 {
    return wid.x + wid.y * nwg.x;
}

@compute @workgroup_size(256)
fn scan_block(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>, @builtin(local_invocation_index) tid: u32) {
    let block = block_of(wid, nwg);
    let base = block * 1024u + tid * 4u;
    var v: array<u32, 4>;
    var tot = 0u;
    for (var k = 0u; k < 4u; k++) {
        let i = base + k;
        v[k] = select(0u, data[min(i, S.n - 1u)], i < S.n);
        tot += v[k];
    }
    part[tid] = tot;
    workgroupBarrier();
    // Hillis-Steele inclusive scan of the per-thread totals.
    for (var off = 1u; off < 256u; off *= 2u) {
        let mine = part[tid];
        let add = select(0u, part[max(tid, off) - off], tid >= off);
        workgroupBarrier();
        part[tid] = mine + add;
        workgroupBarrier();
    }
    var run = part[tid] - tot;
    for (var k = 0u; k < 4u; k++) {
        let i = base + k;
        if i < S.n {
            data[i] = run;
        }
        run += v[k];
    }
    if tid == 255u {
        sums[block] = part[255];
    }
}

@compute @workgroup_size(256)
fn add(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>, @builtin(local_invocation_index) tid: u32) {
    let block = block_of(wid, nwg);
    let off = sums[block];
    for (var k = 0u; k < 4u; k++) {
        let i = block * 1024u + tid * 4u + k;
        if i < S.n {
            data[i] += off;
        }
    }
}
