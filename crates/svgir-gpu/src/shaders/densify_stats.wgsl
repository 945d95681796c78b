// Densification statistics (svgir_train::densify::DensifyStats::add), resident: per Gaussian
// seen by the view (a non-empty screen box), the screen-space position-gradient norm in NDC
// units is added and the view counted, the largest screen radius kept; the composited weight is
// added for every Gaussian. `stats` holds 4 floats a Gaussian: gradient sum, views (a float,
// exact to 2^24), largest radius, weight sum. An overflowed render (bin_total.wgsl) adds
// nothing. One thread per Gaussian.

struct StatsParams {
    n: u32,
    // 3DGS's threshold is on the NDC gradient: the pixel gradient times sqrt(W H) / 2.
    to_ndc: f32,
    _p0: u32,
    _p1: u32,
}

@group(0) @binding(0) var<uniform> S: StatsParams;
@group(0) @binding(1) var<storage, read> splat: array<f32>;
@group(0) @binding(2) var<storage, read> rect: array<u32>;
@group(0) @binding(3) var<storage, read> vparam: array<f32>;
@group(0) @binding(4) var<storage, read> count: array<u32>;
@group(0) @binding(5) var<storage, read_write> stats: array<f32>;

@compute @workgroup_size(256)
fn main(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = gid.x + gid.y * nwg.x * 256u;
    if i >= S.n || count[C_OVERFLOW] != 0u {
        return;
    }
    let seen = rect[i * 4u] < rect[i * 4u + 1u] && rect[i * 4u + 2u] < rect[i * 4u + 3u];
    let radius = select(0.0, splat[i * SPLAT + S_RADIUS], seen);
    if radius > 0.0 {
        stats[i * 4u] += vparam[i * VP + 10u] * S.to_ndc;
        stats[i * 4u + 1u] += 1.0;
        stats[i * 4u + 2u] = max(stats[i * 4u + 2u], radius);
    }
    stats[i * 4u + 3u] += vparam[i * VP + 11u];
}
