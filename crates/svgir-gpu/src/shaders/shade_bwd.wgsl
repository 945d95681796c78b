// Backward of the vertex shading (shade.wgsl), as svgir_pbr::shade_backward computes it on the
// CPU: given v_color = dL/dc_j^m, with C = 2pi/K, per sample of light Lin = V clamp(L_env) +
// L_ind and per vertex with cos = n_m . w > 0, f_c = t a_c/pi + S and g = v_color[j, m]:
//
//   dL/da_c = C g_c t E_c / pi (E_c = sum cos Lin_c), dL/dr += C cos dS/dr sum_c g_c Lin_c,
//   dL/dn += C [cos dS/dn sum_c g_c Lin_c + w sum_c g_c f_c Lin_c],
//   dL/dLin_c = C sum_m g_c f_c cos,
//
// and with the layered diffuse weight, q = sum_c g_c a_c E_c / pi times dt/dr and dt/d(n.v) w_o.
//
// Work split: one thread per listed Gaussian (visible on this side, with a non-zero v_color),
// its samples in the CPU's order. A thread owns its material gradients and its share of rho's,
// written to its own slots (`grads`); the negated normal of a back side is undone here (F_BACK).
// The env texels' gradient is shared by every Gaussian, so no thread adds to it: each writes its
// samples' C V dL/dLin (0 for channels outside the clamp) to `v_light`, and the host adds them
// into the texels through the direction cache's taps in a fixed order (no atomics, the same sum
// at every run). Saves nothing: the samples are recomputed as the forward makes them.

@group(0) @binding(0) var<uniform> P: ShadeParams;
// As shade.wgsl.
@group(0) @binding(1) var<storage, read> frames: array<vec4<f32>>;
@group(0) @binding(2) var<storage, read> tables: array<vec4<f32>>;
@group(0) @binding(3) var<storage, read> samples: array<vec4<u32>>;
@group(0) @binding(4) var<storage, read> verts: array<vec4<f32>>;
@group(0) @binding(5) var<storage, read> given: array<f32>;
@group(0) @binding(6) var<storage, read> light_vis: array<f32>;
@group(0) @binding(7) var<storage, read> list: array<u32>;
// dL/dc per vertex, (j * M + m) * 3 + c.
@group(0) @binding(8) var<storage, read> v_color: array<f32>;
// Per Gaussian j, 7 M + 1 floats: v_albedo (M x 3), v_roughness (M), v_normals (M x 3), v_rho.
@group(0) @binding(9) var<storage, read_write> grads: array<f32>;
// Per sample of the bound Gaussians, ((j - base) * (K + lights) + s) * 3 + c: C V dL/dLin_c.
@group(0) @binding(10) var<storage, read_write> v_light: array<f32>;
// Loops cut short (loop_guard.wgsl): bit 128.
@group(0) @binding(11) var<storage, read_write> status: array<atomic<u32>, 2>;

const F_BACK: u32 = 16u;   // the back side: its shading normals are negated

@compute @workgroup_size(64)
fn main(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let t = gid.x + gid.y * nwg.x * 64u;
    if t >= P.count {
        return;
    }
    let j = list[t];
    let m = P.m;
    let b1 = frames[4u * j];
    let b2 = frames[4u * j + 1u];
    let nf = frames[4u * j + 2u].xyz;
    let wo = view_dir(frames[4u * j + 3u].xyz);
    var vn: array<vec3<f32>, MAX_V>;
    var rough: array<f32, MAX_V>;
    var kd: array<vec3<f32>, MAX_V>;
    var gm: array<vec3<f32>, MAX_V>;
    for (var v = 0u; v < m; v++) {
        let nr = verts[(j * m + v) * 3u];
        let a = verts[(j * m + v) * 3u + 1u];
        vn[v] = nr.xyz;
        rough[v] = nr.w;
        kd[v] = a.xyz * INV_PI * a.w;
        let at = (j * m + v) * 3u;
        gm[v] = vec3<f32>(v_color[at], v_color[at + 1u], v_color[at + 2u]);
    }
    var e: array<vec3<f32>, MAX_V>;
    var vr: array<f32, MAX_V>;
    var vnrm: array<vec3<f32>, MAX_V>;
    var v_rho = 0.0;
    let local = j - P.base;
    let per = P.k + P.lights;
    for (var s = 0u; s < per; s++) {
        let smp = fetch_sample(j, local, s, b1, b2, nf);
        if !smp.ok {
            continue;
        }
        let dir = smp.dir;
        let hf = half_fresnel(wo, dir);
        let lin = smp.direct + smp.ind;
        var v_lin = vec3<f32>(0.0);
        for (var v = 0u; v < m; v++) {
            let cos = dot(vn[v], dir);
            if cos <= 0.0 {
                continue;
            }
            let sg = spec_grad(vn[v], rough[v], dot(vn[v], wo), hf.xyz, hf.w, wo, dir, cos);
            let f = kd[v] + vec3<f32>(sg.value);
            let gl = gm[v] * lin;
            e[v] += cos * lin;
            let sum_gl = gl.x + gl.y + gl.z;
            let sum_glf = gl.x * f.x + gl.y * f.y + gl.z * f.z;
            v_lin += gm[v] * f * cos;
            vr[v] += cos * sg.v_r * sum_gl;
            vnrm[v] += cos * sg.v_n * sum_gl + dir * sum_glf;
        }
        // svgir_pbr::shade_backward::light_grads: to the taps through V (channels inside the
        // clamp), to rho through the traced radiance.
        if smp.vis > 0.0 {
            let gv = select(vec3<f32>(0.0), P.scale * smp.vis * v_lin, smp.live);
            let at = (local * per + s) * 3u;
            v_light[at] = gv.x;
            v_light[at + 1u] = gv.y;
            v_light[at + 2u] = gv.z;
        }
        v_rho += P.scale * (v_lin.x * smp.traced.x + v_lin.y * smp.traced.y + v_lin.z * smp.traced.z);
    }
    let stride = 7u * m + 1u;
    let base = j * stride;
    let sign = select(1.0, -1.0, (P.flags & F_BACK) != 0u);
    for (var v = 0u; v < m; v++) {
        let dw = verts[(j * m + v) * 3u + 2u];
        let a = verts[(j * m + v) * 3u + 1u];
        let q = gm[v].x * a.x * INV_PI * e[v].x + gm[v].y * a.y * INV_PI * e[v].y + gm[v].z * a.z * INV_PI * e[v].z;
        let v_alb = P.scale * gm[v] * e[v] * INV_PI * a.w;
        let v_n = P.scale * (vnrm[v] + q * dw.x * wo);
        for (var c = 0u; c < 3u; c++) {
            grads[base + v * 3u + c] = v_alb[c];
            grads[base + 4u * m + v * 3u + c] = sign * v_n[c];
        }
        grads[base + 3u * m + v] = P.scale * (vr[v] + q * dw.y);
    }
    grads[base + 7u * m] = v_rho;
    guard_loops(128u);
}
