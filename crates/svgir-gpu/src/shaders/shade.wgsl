// Vertex shading on the GPU (SPEC 4, with SPEC 5's visibility and indirect light), as
// svgir_pbr::shade computes it on the CPU: for Gaussian j and vertex m,
//
//   c_j^m = 2pi/K sum_s f(w_o, w_s; a_m, r_m, n_m) [V_s L_env(w_s) + L_ind_s] max(0, n_m . w_s)
//
// over the K micro-buffer directions and then the directional lights (svgir_trace::BrightLights),
// with f = t a/pi + S (GGX, split as svgir_shading::split: per vertex the lobe, per sample the
// half vector and Fresnel). The diffuse weight t (1, or 1 - E(n.v, r) when layered) depends on
// the view alone and comes per vertex from the host.
//
// Work split: one thread per listed Gaussian (the side's visible ones, `list`), looping over its
// K samples in order and, per sample, its M vertices; a thread owns its M x 3 outputs, so there
// are no atomics and the sums run in the CPU's order (directions, then lights). The sides of a
// two-sided model are two dispatches with disjoint lists into the same outputs. A dispatch covers
// the Gaussians `base .. base + span` whose given indirect light is bound; their samples lie in a
// buffer from Gaussian `sbase` on (the batch's own upload, sbase = base, or the chunk of kept
// samples that holds the batch, resident.rs).
//
// Env lookups are made here from the direction (svgir_core::envmap::grid_coords, Taps::at) rather
// than read from the CPU's direction cache: 32 bytes a sample saved, at the price of acos/atan2's
// rounding, which moves a tap only where a direction sits on a texel boundary (the bilinear
// weights are continuous there). Saves nothing for a backward.

@group(0) @binding(0) var<uniform> P: ShadeParams;
// Per Gaussian: (b1, cos xi), (b2, sin xi), (n, 0), (position, 0): its hemisphere frame
// (svgir_shading::HemiFrame over the micro-buffer's normal) and centre.
@group(0) @binding(1) var<storage, read> frames: array<vec4<f32>>;
// K Fibonacci rows (cos g, sin g, r, z) of the micro-buffer's table (interleaved subsets
// included); at env_at the texels (rgb, 1 where a light texel is black to the K samples); at
// lights_at two per light: (dir, Omega K / 2pi), (texel index as a float, 0, 0, 0).
@group(0) @binding(2) var<storage, read> tables: array<vec4<f32>>;
// Packed micro-buffer samples of Gaussians from sbase on, (j - sbase) * K + k:
// (V unorm16 | L.r f16 << 16, L.g | L.b << 16, first hit, u~ | v~ << 16), as trace.wgsl writes.
@group(0) @binding(3) var<storage, read> samples: array<vec4<u32>>;
// Per vertex j * M + m: (unit shading normal, roughness), (albedo, diffuse weight t),
// (dt/d(n.v), dt/dr, 0, 0) (the backward's).
@group(0) @binding(4) var<storage, read> verts: array<vec4<f32>>;
// F_GIVEN: L_ind per sample of Gaussians base .. base + span, ((j - base) * K + k) * 3 + c.
@group(0) @binding(5) var<storage, read> given: array<f32>;
// Light visibility, b * N + j.
@group(0) @binding(6) var<storage, read> light_vis: array<f32>;
// The Gaussians to shade (ascending, within base .. base + span).
@group(0) @binding(7) var<storage, read> list: array<u32>;
// Colour, then (F_SPLIT) direct and indirect parts: (j * M + m) * 3 + c, N * M * 3 each.
@group(0) @binding(8) var<storage, read_write> out: array<f32>;
// Loops cut short (loop_guard.wgsl): bit 64.
@group(0) @binding(9) var<storage, read_write> status: array<atomic<u32>, 2>;

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
    let pos = frames[4u * j + 3u].xyz;
    let wo = view_dir(pos);
    // The per-vertex lobes (svgir_shading::split::lobe).
    var vn: array<vec3<f32>, MAX_V>;
    var c0: array<f32, MAX_V>;
    var a2m1: array<f32, MAX_V>;
    var kk: array<f32, MAX_V>;
    var omk: array<f32, MAX_V>;
    for (var v = 0u; v < m; v++) {
        let nr = verts[(j * m + v) * 3u];
        let r = nr.w;
        let nv = cdot(dot(nr.xyz, wo));
        let a = r * r;
        let a2 = a * a;
        let k = (r + 1.0) * (r + 1.0) / 8.0;
        let gv = 1.0 / (nv * (1.0 - k) + k);
        vn[v] = nr.xyz;
        c0[v] = a2 * gv / FOUR_PI;
        a2m1[v] = a2 - 1.0;
        kk[v] = k;
        omk[v] = 1.0 - k;
    }
    // E: sum cos L; P: sum S cos L; direct (d) and indirect (i) light apart.
    var e_d: array<vec3<f32>, MAX_V>;
    var e_i: array<vec3<f32>, MAX_V>;
    var p_d: array<vec3<f32>, MAX_V>;
    var p_i: array<vec3<f32>, MAX_V>;
    let local = j - P.base;
    for (var s = 0u; s < P.k + P.lights; s++) {
        let smp = fetch_sample(j, local, s, b1, b2, nf);
        if !smp.ok {
            continue;
        }
        let dir = smp.dir;
        let direct = smp.direct;
        let ind = smp.ind;
        let hf = half_fresnel(wo, dir);
        let h = hf.xyz;
        let fr = hf.w;
        for (var v = 0u; v < m; v++) {
            let cos = dot(vn[v], dir);
            if cos <= 0.0 {
                continue;
            }
            // svgir_shading::split::spec.
            let nl = cdot(cos);
            let nh = cdot(dot(vn[v], h));
            let q = nh * nh * a2m1[v] + 1.0;
            let sc = fr * c0[v] / (q * q * (nl * omk[v] + kk[v])) * cos;
            e_d[v] += cos * direct;
            e_i[v] += cos * ind;
            p_d[v] += sc * direct;
            p_i[v] += sc * ind;
        }
    }
    let part = P.n * m * 3u;
    for (var v = 0u; v < m; v++) {
        let at = (j * m + v) * 3u;
        let a = verts[(j * m + v) * 3u + 1u];
        let kd = a.xyz * INV_PI * a.w;
        let d = P.scale * (kd * e_d[v] + p_d[v]);
        let i = P.scale * (kd * e_i[v] + p_i[v]);
        for (var c = 0u; c < 3u; c++) {
            out[at + c] = d[c] + i[c];
            if (P.flags & F_SPLIT) != 0u {
                out[part + at + c] = d[c];
                out[2u * part + at + c] = i[c];
            }
        }
    }
    guard_loops(64u);
}
