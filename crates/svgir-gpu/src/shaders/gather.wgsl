// The one-bounce gather on the GPU (SPEC 5, Eqn 13), as svgir_trace::gather computes it for
// relighting (gather_all, gather_two_sided): for ray (j, k) whose first hit is Gaussian h,
//
//   L1b = 2pi/K sum_e (sum_m w_m(u~, v~) f(-w_k, w_e; a_h^m, r_h^m, n_h^m) max(1e-6, n_h^m . w_e)) L_e
//
// over h's escapes e on the side the ray meets: the directions of h's micro-buffer that hit
// nothing, with the env radiance (SPEC 4's clamp, the lights' texels black), then h's
// directional lights (unclamped, weighted by visibility and solid angle), in the CPU's order.
//
// Work split: one 64-thread workgroup per (side, h) with rays (the host groups the rays by their
// hit, as the CPU does). The threads build h's escapes in shared memory together, then each
// shades every 64th ray of the group; a ray's value is written to its own slot, so no atomics.
// Escape lists longer than ESC are built and summed in chunks. Saves nothing: relighting takes
// no gradient.

struct GatherParams {
    k: u32,            // directions per Gaussian
    m: u32,            // vertices per Gaussian
    n: u32,            // Gaussians
    layered: u32,      // Diffuse::Layered (else added)
    env_w: u32,
    env_h: u32,
    e_at: u32,         // first row of the layered-diffuse table in `tables`
    words: u32,        // u32 words of one Gaussian's escape mask
    env_at0: u32,      // side 0: its env texels, lights, light count, visibility offset
    lights_at0: u32,
    lights0: u32,
    vis_at0: u32,
    env_at1: u32,      // side 1 (two-sided gathers)
    lights_at1: u32,
    lights1: u32,
    vis_at1: u32,
    env_max: f32,
    scale: f32,        // 2 pi / K
    groups: u32,       // groups in this dispatch
    _pad: u32,
}

const ESC: u32 = 512u;
const MU_NODES: u32 = 65u;   // svgir_shading::layering
const R_NODES: u32 = 33u;

@group(0) @binding(0) var<uniform> P: GatherParams;
// Per Gaussian of the rays' micro-buffer: (b1, cos xi), (b2, sin xi), (n, 0), unused.
@group(0) @binding(1) var<storage, read> ray_frames: array<vec4<f32>>;
// The same for each side's micro-buffer, side s at 4 N s.
@group(0) @binding(2) var<storage, read> hit_frames: array<vec4<f32>>;
// K Fibonacci rows; at e_at the layered table E(mu, r) (x of each row); at env_at* a side's
// texels (rgb, 1 where a light's texel); at lights_at* two rows per light: (dir, Omega K / 2pi),
// (texel index as a float, 0, 0, 0).
@group(0) @binding(3) var<storage, read> tables: array<vec4<f32>>;
// Per side and Gaussian, `words` u32: bit s set where sample s escaped (hit nothing).
@group(0) @binding(4) var<storage, read> escaped: array<u32>;
// Per side and vertex (s N + h) M + m: (unit normal out of that side, roughness), (albedo, 0).
@group(0) @binding(5) var<storage, read> verts: array<vec4<f32>>;
// Light visibility, vis_at* + b N + h.
@group(0) @binding(6) var<storage, read> light_vis: array<f32>;
// Per group of this dispatch: (side, h, first pair, pairs).
@group(0) @binding(7) var<storage, read> groups: array<vec4<u32>>;
// Per pair: (j K + k, u~ | v~ << 16 as unorm16).
@group(0) @binding(8) var<storage, read> pairs: array<vec2<u32>>;
// L1b per pair of this dispatch, 3 floats.
@group(0) @binding(9) var<storage, read_write> out: array<f32>;
// Loops cut short (loop_guard.wgsl): bit 32.
@group(0) @binding(10) var<storage, read_write> status: array<atomic<u32>, 2>;

var<workgroup> esc_dir: array<vec4<f32>, ESC>;  // (direction, L.r)
var<workgroup> esc_gb: array<vec2<f32>, ESC>;   // (L.g, L.b)

// svgir_shading::layering::specular_albedo's value: E(n.v, r) by bilinear lookup.
fn specular_albedo(nv: f32, r: f32) -> f32 {
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
    return ex0 + (ex1 - ex0) * fy;
}

@compute @workgroup_size(64)
fn main(@builtin(workgroup_id) wg: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
        @builtin(local_invocation_index) t: u32) {
    let gi = wg.x + wg.y * nwg.x;
    if gi >= P.groups {
        return; // the whole workgroup: uniform
    }
    let g = groups[gi];
    let side = g.x;
    let h = g.y;
    let k_all = P.k;
    var env_at = P.env_at0;
    var lights_at = P.lights_at0;
    var lights = P.lights0;
    var vis_at = P.vis_at0;
    if side == 1u {
        env_at = P.env_at1;
        lights_at = P.lights_at1;
        lights = P.lights1;
        vis_at = P.vis_at1;
    }
    let hf = (side * P.n + h) * 4u;
    let hb1 = hit_frames[hf];
    let hb2 = hit_frames[hf + 1u];
    let hn = hit_frames[hf + 2u].xyz;
    let m = P.m;
    let total = k_all + lights;
    let chunks = (total + ESC - 1u) / ESC;
    let rounds = (g.w + 63u) / 64u;
    for (var round = 0u; round < rounds; round++) {
        let p = round * 64u + t;
        let valid = p < g.w;
        // The ray's set-up (svgir_trace::gather::RaySetup): the view towards j, the vertex
        // weights at the hit's (u~, v~), per vertex of h its lobe and diffuse part.
        var v = vec3<f32>(0.0, 0.0, 1.0);
        var wts: array<f32, MAX_V>;
        var vn: array<vec3<f32>, MAX_V>;
        var c0: array<f32, MAX_V>;
        var a2m1: array<f32, MAX_V>;
        var kk: array<f32, MAX_V>;
        var omk: array<f32, MAX_V>;
        var dpart: array<vec3<f32>, MAX_V>;
        var at = 0u;
        if valid {
            let pair = pairs[g.z + p];
            at = pair.x;
            let j = pair.x / k_all;
            let kr = pair.x % k_all;
            let rf = j * 4u;
            v = -frame_dir(ray_frames[rf], ray_frames[rf + 1u], ray_frames[rf + 2u].xyz, tables[kr]);
            let uv = unpack2x16unorm(pair.y);
            wts = vertex_weights(m, uv.x, uv.y);
            for (var q = 0u; q < m; q++) {
                let b = ((side * P.n + h) * m + q) * 2u;
                let nr = verts[b];
                let alb = verts[b + 1u].xyz;
                let r = nr.w;
                let nv_raw = dot(nr.xyz, v);
                let nv = cdot(nv_raw);
                let a = r * r;
                let a2 = a * a;
                let kq = (r + 1.0) * (r + 1.0) / 8.0;
                let gv = 1.0 / (nv * (1.0 - kq) + kq);
                vn[q] = nr.xyz;
                c0[q] = a2 * gv / FOUR_PI;
                a2m1[q] = a2 - 1.0;
                kk[q] = kq;
                omk[q] = 1.0 - kq;
                var tw = 1.0;
                if P.layered != 0u {
                    tw = 1.0 - specular_albedo(nv_raw, r);
                }
                dpart[q] = alb * (INV_PI * tw);
            }
        }
        var acc = vec3<f32>(0.0);
        for (var c = 0u; c < chunks; c++) {
            // h's escapes c ESC .. (c + 1) ESC, built together (zero light: not an escape).
            for (var e = c * ESC + t; e < min((c + 1u) * ESC, total); e += 64u) {
                var dir = vec3<f32>(0.0);
                var l = vec3<f32>(0.0);
                if e < k_all {
                    let word = escaped[(side * P.n + h) * P.words + e / 32u];
                    if ((word >> (e % 32u)) & 1u) != 0u {
                        dir = frame_dir(hb1, hb2, hn, tables[e]);
                        l = clamp(env_lookup_at(dir, env_at), vec3<f32>(0.0), vec3<f32>(P.env_max));
                    }
                } else {
                    let b = e - k_all;
                    let vis = light_vis[vis_at + b * P.n + h];
                    if vis > 0.0 {
                        let l0 = tables[lights_at + 2u * b];
                        let texel = u32(tables[lights_at + 2u * b + 1u].x);
                        dir = l0.xyz;
                        l = (vis * l0.w) * tables[env_at + texel].xyz;
                    }
                }
                esc_dir[e - c * ESC] = vec4<f32>(dir, l.x);
                esc_gb[e - c * ESC] = l.yz;
            }
            workgroupBarrier();
            if valid {
                for (var e = 0u; e < min(ESC, total - c * ESC); e++) {
                    let ed = esc_dir[e];
                    let l = vec3<f32>(ed.w, esc_gb[e]);
                    if all(l == vec3<f32>(0.0)) {
                        continue;
                    }
                    let dir = ed.xyz;
                    let hf = half_fresnel(v, dir);
                    let hv = hf.xyz;
                    let fr = hf.w;
                    var f_cos = vec3<f32>(0.0);
                    for (var q = 0u; q < m; q++) {
                        let nl = dot(vn[q], dir);
                        let nh = cdot(dot(vn[q], hv));
                        let qq = nh * nh * a2m1[q] + 1.0;
                        let s = fr * c0[q] / (qq * qq * (cdot(nl) * omk[q] + kk[q]));
                        f_cos += (dpart[q] + vec3<f32>(s)) * (max(nl, DOT_EPS) * wts[q]);
                    }
                    acc += f_cos * l;
                }
            }
            workgroupBarrier();
        }
        if valid {
            let o = (g.z + p) * 3u;
            out[o] = acc.x * P.scale;
            out[o + 1u] = acc.y * P.scale;
            out[o + 2u] = acc.z * P.scale;
        }
    }
    guard_loops(32u);
}
