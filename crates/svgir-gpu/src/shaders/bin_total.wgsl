// Binning, between the scan and the emission: the number of (tile, Gaussian) entries this
// render bins, from the last Gaussian's scanned offset and count, against the capacity of the
// entry buffers. It sets the entries kept (what the sort, the ranges and the backward read) and
// the overflow flag of this render (what the optimiser and the densification statistics read:
// an overflowed render's step is skipped, never taken on a truncated list), and keeps the most
// entries binned and the overflowed renders since the host last read and cleared them, so the
// host can size the buffers without reading anything back per iteration. One thread.

@group(0) @binding(0) var<uniform> P: Params;
@group(0) @binding(1) var<storage, read> off: array<u32>;
@group(0) @binding(2) var<storage, read> cnt: array<u32>;
@group(0) @binding(3) var<storage, read_write> count: array<u32>;

@compute @workgroup_size(1)
fn main() {
    var total = 0u;
    if P.n > 0u {
        total = off[P.n - 1u] + cnt[P.n - 1u];
    }
    let over = total > P.capacity;
    count[C_KEPT] = min(total, P.capacity);
    count[C_TOTAL] = total;
    count[C_OVERFLOW] = select(0u, 1u, over);
    count[C_MAX] = max(count[C_MAX], total);
    count[C_OVERFLOWS] += select(0u, 1u, over);
}
