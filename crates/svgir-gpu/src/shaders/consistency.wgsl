// The radiance-consistency gather on the GPU (SPEC 6, Eqn 14/16), forward and backward, as
// svgir_pbr::radiance_consistency_with_grad computes it on the CPU: for each selected pair
// (j, k_j) whose ray hits Gaussian h, Eqn 13's one-bounce radiance off h,
//
//   L1b = 2pi/K sum_e (sum_m w_m(u~, v~) f(v, w_e; a_h^m, r_h^m, n_h^m) max(1e-6, n_h^m . w_e)) L_e,
//
// over h's escapes e (its micro-buffer directions that hit nothing, with the clamped env light,
// then its directional lights, in the CPU's order), then the upstream gradient of L_rc,
// g = sign(L1b - rho L) / (3 count) v_loss, and the gradients of g . L1b: with C = 2pi/K,
// f_c = t a_c/pi + S, cos = max(1e-6, n.l), gl_c = g_c C w_m L_c,
//
//   dL/da_mc += gl_c cos t/pi, dL/dr_m += sum_c gl_c cos dS/dr + q dt/dr,
//   dL/dn_m += sum_c gl_c cos dS/dn + [n.l > 1e-6] (sum_c gl_c f_c) l + q dt/d(n.v) v,
//   dL/dL_e,c = sum_m g_c C w_m f_c cos,     q = sum_c gl_c cos a_c/pi,
//
// (svgir_trace::gather_backward's note). v is the unit direction from h back to j.
//
// Work split: one 64-thread workgroup per group of at most 64 pairs with the same hit h (the
// host groups them). The threads build h's escapes in shared memory, then take the group's
// pairs one at a time: each thread shades its share of the escapes (every 64th), the partial
// sums are added in thread order into L1b, thread 0 forms g, and each thread adds its escapes'
// share of the gradients: into private material sums (h's M vertices) and into its escapes'
// light gradients, which it owns. At the end the material sums are added over the threads in
// thread order. Each group writes its own slots (L1b per pair; per group h's material gradients
// and each escape's dL/dL); the host adds the groups of one h in order and routes the light
// gradients through the env taps, so no atomics and the same sums at every run. Saves nothing.

struct ConsParams {
    k: u32,        // directions per Gaussian
    m: u32,        // vertices per Gaussian
    n: u32,        // hit Gaussians uploaded (the host renumbers the Gaussians the pairs touch)
    layered: u32,  // Diffuse::Layered (else added)
    env_w: u32,
    env_h: u32,
    e_at: u32,     // first row of the layered-diffuse table in `tables`
    words: u32,    // u32 words of one Gaussian's escape mask
    env_at: u32,   // the env texels in `tables`
    lights_at: u32,
    lights: u32,
    vis_at: u32,
    env_max: f32,
    scale: f32,    // 2 pi / K
    groups: u32,   // groups in this dispatch
    stride: u32,   // floats per group in `grads`: 7 M + 3 (K + lights)
    rho: f32,      // the indirect scale of the traced radiance
    up: f32,       // v_loss / (3 count)
    _pad0: u32,
    _pad1: u32,
}

const ESC: u32 = 512u;      // most escapes (directions + lights) of a Gaussian; the host checks
const OWN: u32 = 8u;        // escapes a thread owns: ESC / 64
const MU_NODES: u32 = 65u;  // svgir_shading::layering
const R_NODES: u32 = 33u;

@group(0) @binding(0) var<uniform> P: ConsParams;
// Per Gaussian the pairs touch, hits first: (b1, cos xi), (b2, sin xi), (n, 0), unused.
@group(0) @binding(1) var<storage, read> frames: array<vec4<f32>>;
// K Fibonacci rows; at e_at the layered table E(mu, r) (x of each row); at env_at the texels
// (rgb, 1 where a light's texel); at lights_at two rows per light: (dir, Omega K / 2pi),
// (texel index as a float, 0, 0, 0).
@group(0) @binding(2) var<storage, read> tables: array<vec4<f32>>;
// Per hit Gaussian, `words` u32: bit s set where sample s escaped.
@group(0) @binding(3) var<storage, read> escaped: array<u32>;
// Per vertex h M + m of the hits: (unit normal, roughness), (albedo, 0).
@group(0) @binding(4) var<storage, read> verts: array<vec4<f32>>;
// Light visibility, vis_at + b N + h.
@group(0) @binding(5) var<storage, read> light_vis: array<f32>;
// Per group of this dispatch: (h, first pair, pairs, 0).
@group(0) @binding(6) var<storage, read> groups: array<vec4<u32>>;
// Per pair of this dispatch, 5 words: j K + k (j renumbered), u~ | v~ << 16 (unorm16), the traced L (3 f32 bits).
@group(0) @binding(7) var<storage, read> pairs: array<u32>;
// L1b per pair of this dispatch, 3 floats.
@group(0) @binding(8) var<storage, read_write> l1b: array<f32>;
// Per group: v_albedo (M x 3), v_roughness (M), v_normals (M x 3), then dL/dL per escape (3).
@group(0) @binding(9) var<storage, read_write> grads: array<f32>;
// Loops cut short (loop_guard.wgsl): bit 256.
@group(0) @binding(10) var<storage, read_write> status: array<atomic<u32>, 2>;

var<workgroup> esc_dir: array<vec4<f32>, ESC>;  // (direction, L.r)
var<workgroup> esc_gb: array<vec2<f32>, ESC>;   // (L.g, L.b)
var<workgroup> partial: array<vec3<f32>, 64>;
var<workgroup> upstream: vec3<f32>;
var<workgroup> vertex_sums: array<f32, 448>;    // 64 threads x 7 floats of one vertex

// svgir_shading::layering::specular_albedo: (E, dE/d(n.v), dE/dr) by bilinear lookup.
fn specular_albedo_d(nv: f32, r: f32) -> vec3<f32> {
    let mu_live = nv > DOT_EPS && nv < 1.0;
    let r_live = r > 0.0 && r < 1.0;
    let x = clamp(nv, DOT_EPS, 1.0) * f32(MU_NODES - 1u);
    let y = clamp(r, 0.0, 1.0) * f32(R_NODES - 1u);
    let i = min(u32(x), MU_NODES - 2u);
    let j = min(u32(y), R_NODES - 2u);
    let fx = x - f32(i);
    let fy = y - f32(j);
    let e00 = tables[P.e_at + i * R_NODES + j].x;
    let e01 = tables[P.e_at + i * R_NODES + j + 1u].x;
    let e10 = tables[P.e_at + (i + 1u) * R_NODES + j].x;
    let e11 = tables[P.e_at + (i + 1u) * R_NODES + j + 1u].x;
    let ex0 = e00 + (e10 - e00) * fx;
    let ex1 = e01 + (e11 - e01) * fx;
    let dx = (e10 - e00) + ((e11 - e01) - (e10 - e00)) * fy;
    let dy = ex1 - ex0;
    return vec3<f32>(ex0 + (ex1 - ex0) * fy, select(0.0, dx * f32(MU_NODES - 1u), mu_live),
        select(0.0, dy * f32(R_NODES - 1u), r_live));
}

@compute @workgroup_size(64)
fn main(@builtin(workgroup_id) wg: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
        @builtin(local_invocation_index) t: u32) {
    let gi = wg.x + wg.y * nwg.x;
    if gi >= P.groups {
        return; // the whole workgroup: uniform
    }
    let g = groups[gi];
    let h = g.x;
    let m = P.m;
    let total = P.k + P.lights;
    // h's escapes (zero light: not an escape), as svgir_trace::gather::Escapes::fill.
    let hb1 = frames[h * 4u];
    let hb2 = frames[h * 4u + 1u];
    let hn = frames[h * 4u + 2u].xyz;
    for (var e = t; e < total; e += 64u) {
        var dir = vec3<f32>(0.0);
        var l = vec3<f32>(0.0);
        if e < P.k {
            let word = escaped[h * P.words + e / 32u];
            if ((word >> (e % 32u)) & 1u) != 0u {
                dir = frame_dir(hb1, hb2, hn, tables[e]);
                l = clamp(env_lookup_at(dir, P.env_at), vec3<f32>(0.0), vec3<f32>(P.env_max));
            }
        } else {
            let b = e - P.k;
            let vis = light_vis[P.vis_at + b * P.n + h];
            if vis > 0.0 {
                let l0 = tables[P.lights_at + 2u * b];
                let texel = u32(tables[P.lights_at + 2u * b + 1u].x);
                dir = l0.xyz;
                l = (vis * l0.w) * tables[P.env_at + texel].xyz;
            }
        }
        esc_dir[e] = vec4<f32>(dir, l.x);
        esc_gb[e] = l.yz;
    }
    workgroupBarrier();

    var v_alb: array<vec3<f32>, MAX_V>;
    var v_rough: array<f32, MAX_V>;
    var v_nrm: array<vec3<f32>, MAX_V>;
    var v_light: array<vec3<f32>, OWN>;
    for (var r = 0u; r < g.z; r++) {
        // The ray's set-up (svgir_trace::gather::RaySetup): the view towards j, the vertex
        // weights at the hit's (u~, v~), per vertex of h its normal, albedo and diffuse weight.
        let pb = (g.y + r) * 5u;
        let flat = pairs[pb];
        let j = flat / P.k;
        let kr = flat % P.k;
        let v = -frame_dir(frames[j * 4u], frames[j * 4u + 1u], frames[j * 4u + 2u].xyz, tables[kr]);
        let uv = unpack2x16unorm(pairs[pb + 1u]);
        let wts = vertex_weights(m, uv.x, uv.y);
        var vn: array<vec3<f32>, MAX_V>;
        var rough: array<f32, MAX_V>;
        var alb: array<vec3<f32>, MAX_V>;
        var tw: array<f32, MAX_V>;
        var dw_mu: array<f32, MAX_V>;
        var dw_r: array<f32, MAX_V>;
        for (var q = 0u; q < m; q++) {
            let nr = verts[(h * m + q) * 2u];
            vn[q] = nr.xyz;
            rough[q] = nr.w;
            alb[q] = verts[(h * m + q) * 2u + 1u].xyz;
            tw[q] = 1.0;
            if P.layered != 0u {
                let e = specular_albedo_d(dot(nr.xyz, v), nr.w);
                tw[q] = 1.0 - e.x;
                dw_mu[q] = -e.y;
                dw_r[q] = -e.z;
            }
        }
        // Forward: this thread's escapes, then the threads' sums in order.
        var part = vec3<f32>(0.0);
        for (var e = t; e < total; e += 64u) {
            let ed = esc_dir[e];
            let l = vec3<f32>(ed.w, esc_gb[e]);
            if all(l == vec3<f32>(0.0)) {
                continue;
            }
            let hf = half_fresnel(v, ed.xyz);
            var f_cos = vec3<f32>(0.0);
            for (var q = 0u; q < m; q++) {
                let nl = dot(vn[q], ed.xyz);
                let sg = spec_grad(vn[q], rough[q], dot(vn[q], v), hf.xyz, hf.w, v, ed.xyz, nl);
                f_cos += (alb[q] * (INV_PI * tw[q]) + vec3<f32>(sg.value)) * (max(nl, DOT_EPS) * wts[q]);
            }
            part += f_cos * l;
        }
        partial[t] = part;
        workgroupBarrier();
        if t == 0u {
            var sum = vec3<f32>(0.0);
            for (var i = 0u; i < 64u; i++) {
                sum += partial[i];
            }
            let value = sum * P.scale;
            let o = (g.y + r) * 3u;
            l1b[o] = value.x;
            l1b[o + 1u] = value.y;
            l1b[o + 2u] = value.z;
            let traced = vec3<f32>(bitcast<f32>(pairs[pb + 2u]), bitcast<f32>(pairs[pb + 3u]),
                bitcast<f32>(pairs[pb + 4u]));
            // svgir_pbr::consistency's l1_loss: sign(d) (0 at 0) over 3 count, times v_loss.
            upstream = sign(value - P.rho * traced) * P.up;
        }
        workgroupBarrier();
        let gg = upstream;
        // Backward: this thread's escapes (svgir_trace::gather_backward::backward_pair).
        var own = 0u;
        for (var e = t; e < total; e += 64u) {
            let ed = esc_dir[e];
            let l = vec3<f32>(ed.w, esc_gb[e]);
            let dir = ed.xyz;
            // Not an escape (a hit, a light h does not see); a black escape still passes its
            // gradient to the texels.
            if all(dir == vec3<f32>(0.0)) {
                own++;
                continue;
            }
            let hf = half_fresnel(v, dir);
            var vl = vec3<f32>(0.0);
            for (var q = 0u; q < m; q++) {
                let nl = dot(vn[q], dir);
                let sg = spec_grad(vn[q], rough[q], dot(vn[q], v), hf.xyz, hf.w, v, dir, nl);
                let cos = max(nl, DOT_EPS);
                let gw = P.scale * wts[q];
                let kd = INV_PI * tw[q];
                let f = alb[q] * kd + vec3<f32>(sg.value);
                let gl = gg * gw * l;
                v_alb[q] += gl * (cos * kd);
                let qs = dot(gl, alb[q]) * cos * INV_PI;
                let sum_gl = gl.x + gl.y + gl.z;
                vl += gg * gw * f * cos;
                v_rough[q] += sum_gl * cos * sg.v_r + qs * dw_r[q];
                var dn = sum_gl * cos * sg.v_n + (qs * dw_mu[q]) * v;
                if nl > DOT_EPS {
                    dn += dot(gl, f) * dir;
                }
                v_nrm[q] += dn;
            }
            v_light[own] += vl;
            own++;
        }
        // `partial` and `upstream` are read before the next pair writes them.
        workgroupBarrier();
    }

    let base = gi * P.stride;
    var own = 0u;
    for (var e = t; e < total; e += 64u) {
        let o = base + 7u * m + e * 3u;
        grads[o] = v_light[own].x;
        grads[o + 1u] = v_light[own].y;
        grads[o + 2u] = v_light[own].z;
        own++;
    }
    // h's material gradients, vertex by vertex, added over the threads in order.
    for (var q = 0u; q < m; q++) {
        vertex_sums[t * 7u] = v_alb[q].x;
        vertex_sums[t * 7u + 1u] = v_alb[q].y;
        vertex_sums[t * 7u + 2u] = v_alb[q].z;
        vertex_sums[t * 7u + 3u] = v_rough[q];
        vertex_sums[t * 7u + 4u] = v_nrm[q].x;
        vertex_sums[t * 7u + 5u] = v_nrm[q].y;
        vertex_sums[t * 7u + 6u] = v_nrm[q].z;
        workgroupBarrier();
        if t < 7u {
            var sum = 0.0;
            for (var i = 0u; i < 64u; i++) {
                sum += vertex_sums[i * 7u + t];
            }
            if t < 3u {
                grads[base + q * 3u + t] = sum;
            } else if t == 3u {
                grads[base + 3u * m + q] = sum;
            } else {
                grads[base + 4u * m + q * 3u + t - 4u] = sum;
            }
        }
        workgroupBarrier();
    }
    guard_loops(256u);
}
