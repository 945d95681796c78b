// Stage 1's loss, the sum: the per-workgroup partial sums of the per-pixel kernels, added in a
// fixed order, into this iteration's slot of the loss ring (means, and the weighted total as
// losses/objective.rs forms it: w_l1 L1 + w_ssim (1 - SSIM) + mask + entropy + depth-normal +
// distortion). The host reads the ring every few iterations, never per iteration. One workgroup.

@group(0) @binding(0) var<uniform> L: LossParams;
@group(0) @binding(1) var<storage, read> partials: array<f32>;
@group(0) @binding(2) var<storage, read_write> ring: array<f32>;

var<workgroup> sums: array<f32, 8>;

@compute @workgroup_size(256)
fn main(@builtin(local_invocation_index) tid: u32) {
    for (var k = 0u; k < 7u; k++) {
        var acc = 0.0;
        for (var g = tid; g < L.groups; g += 256u) {
            acc += partials[g * PARTS + k];
        }
        let t = wg_sum(acc, tid);
        if tid == 0u {
            sums[k] = t;
        }
    }
    workgroupBarrier();
    if tid == 0u {
        let np = f32(L.width * L.height);
        let nf = 3.0 * np;
        let o = L.slot * PARTS;
        let l1 = sums[0] / nf;
        let ssim = sums[1] / nf;
        ring[o] = l1;
        ring[o + 1u] = ssim;
        ring[o + 2u] = sums[2] / np;
        ring[o + 3u] = sums[3] / np;
        ring[o + 4u] = sums[4] / np;
        ring[o + 5u] = sums[5] / np;
        ring[o + 6u] = sums[6] / nf;
        var total = L.w_l1 * l1 + L.w_ssim * (1.0 - ssim);
        if L.use_mask != 0u {
            total += L.w_mask * ring[o + 2u] + L.w_entropy * ring[o + 3u];
        }
        total += L.w_dn * ring[o + 4u];
        if L.w_dist > 0.0 {
            total += L.w_dist * ring[o + 5u];
        }
        ring[o + 7u] = total;
    }
}
