// The correction's backward (exposure::apply_backward): per pixel the colour gradient becomes
// `A^T v` in place, `v . (A bg + b - bg)` is added to the opacity's, and the render's colour goes
// back into the forward's record; the 12 parameter gradients `v_c f_k` and `v_c a` (object
// colour f, opacity a) are summed over each workgroup's pixels into its row of `partials` (a
// tree in shared memory, fixed order), which sum.wgsl adds in group order. No atomics. One
// thread per pixel.

@group(0) @binding(0) var<uniform> E: ExposureParams;
@group(0) @binding(1) var<storage, read> params: array<f32>;
@group(0) @binding(2) var<storage, read> raw: array<f32>;
@group(0) @binding(3) var<storage, read_write> vout: array<f32>;
@group(0) @binding(4) var<storage, read_write> img: array<f32>;
@group(0) @binding(5) var<storage, read_write> partials: array<f32>;

var<workgroup> red: array<f32, 256>;

@compute @workgroup_size(256)
fn main(
    @builtin(global_invocation_id) gid: vec3<u32>,
    @builtin(local_invocation_index) lid: u32,
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
) {
    let i = gid.x + gid.y * nwg.x * 256u;
    let group = wid.x + wid.y * nwg.x;
    var g = vec3<f32>(0.0);
    var f = vec3<f32>(0.0);
    var a = 0.0;
    if i < E.npx {
        g = vec3<f32>(vout[i * VPIX], vout[i * VPIX + 1u], vout[i * VPIX + 2u]);
        let c = vec3<f32>(raw[i * 3u], raw[i * 3u + 1u], raw[i * 3u + 2u]);
        a = img[i * PIX + 3u];
        let bg = E.bg.xyz;
        f = c - bg * (1.0 - a);
        let r = E.row;
        var da = 0.0;
        for (var k = 0u; k < 3u; k++) {
            vout[i * VPIX + k] = params[r + k] * g.x + params[r + 3u + k] * g.y + params[r + 6u + k] * g.z;
            img[i * PIX + k] = c[k];
            let ab = params[r + 3u * k] * bg.x + params[r + 3u * k + 1u] * bg.y + params[r + 3u * k + 2u] * bg.z;
            da += g[k] * (ab + params[r + 9u + k] - bg[k]);
        }
        vout[i * VPIX + 3u] += da;
    }
    for (var q = 0u; q < PARAMS; q++) {
        // q < 9: A[q / 3][q % 3], gradient v_{q/3} f_{q%3}; then b_{q-9}, gradient v_{q-9} a.
        var x: f32;
        if q < 9u {
            x = g[q / 3u] * f[q % 3u];
        } else {
            x = g[q - 9u] * a;
        }
        red[lid] = x;
        workgroupBarrier();
        for (var s = 128u; s > 0u; s = s >> 1u) {
            if lid < s {
                red[lid] = red[lid] + red[lid + s];
            }
            workgroupBarrier();
        }
        if lid == 0u {
            partials[group * PARAMS + q] = red[0];
        }
        workgroupBarrier();
    }
}
