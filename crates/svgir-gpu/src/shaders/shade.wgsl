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
// the Gaussians `base .. base + span` whose samples (and given indirect light) are bound.
//
// Env lookups are made here from the direction (svgir_core::envmap::grid_coords, Taps::at) rather
// than read from the CPU's direction cache: 32 bytes a sample saved, at the price of acos/atan2's
// rounding, which moves a tap only where a direction sits on a texel boundary (the bilinear
// weights are continuous there). Saves nothing for a backward.

struct ShadeParams {
    camera: vec3<f32>,
    env_max: f32,     // SPEC 4's clamp of L_env (the light texels are not clamped)
    k: u32,           // directions per Gaussian
    m: u32,           // vertices per Gaussian
    flags: u32,
    count: u32,       // Gaussians in `list`
    env_w: u32,
    env_h: u32,
    lights: u32,      // directional lights
    n: u32,           // Gaussians in all (the output stride of one part)
    rho: f32,         // F_TRACED: L_ind = rho L
    scale: f32,       // 2 pi / K
    env_at: u32,      // first env texel in `tables`
    lights_at: u32,   // first light in `tables`
    base: u32,        // first Gaussian whose samples are bound
    span: u32,        // Gaussians whose samples are bound
}

const F_VIS: u32 = 1u;     // ShadeParams::visibility (else V = 1)
const F_TRACED: u32 = 2u;  // Indirect::Traced
const F_GIVEN: u32 = 4u;   // Indirect::Given
const F_SPLIT: u32 = 8u;   // write the direct and indirect parts too
const MAX_V: u32 = 6u;     // svgir_shading::MAX_VERTICES
const PI: f32 = 3.14159265358979;
const INV_PI: f32 = 0.3183098861837907;   // f32 of f64 1/pi, as the CPU's FRAC_1_PI
const FOUR_PI: f32 = 12.566370614359172; // f32 of f64 4 pi
const DOT_EPS: f32 = 1e-6; // svgir_shading::DOT_EPS
const F0: f32 = 0.04;      // svgir_shading::F0

@group(0) @binding(0) var<uniform> P: ShadeParams;
// Per Gaussian: (b1, cos xi), (b2, sin xi), (n, 0), (position, 0): its hemisphere frame
// (svgir_shading::HemiFrame over the micro-buffer's normal) and centre.
@group(0) @binding(1) var<storage, read> frames: array<vec4<f32>>;
// K Fibonacci rows (cos g, sin g, r, z) of the micro-buffer's table (interleaved subsets
// included); at env_at the texels (rgb, 1 where a light texel is black to the K samples); at
// lights_at two per light: (dir, Omega K / 2pi), (texel index as a float, 0, 0, 0).
@group(0) @binding(2) var<storage, read> tables: array<vec4<f32>>;
// Packed micro-buffer samples of Gaussians base .. base + span, (j - base) * K + k:
// (V unorm16 | L.r f16 << 16, L.g | L.b << 16, first hit, u~ | v~ << 16), as trace.wgsl writes.
@group(0) @binding(3) var<storage, read> samples: array<vec4<u32>>;
// Per vertex j * M + m: (unit shading normal, roughness), (albedo, diffuse weight t).
@group(0) @binding(4) var<storage, read> verts: array<vec4<f32>>;
// F_GIVEN: L_ind per sample, 3 floats, same order as `samples`.
@group(0) @binding(5) var<storage, read> given: array<f32>;
// Light visibility, b * N + j.
@group(0) @binding(6) var<storage, read> light_vis: array<f32>;
// The Gaussians to shade (ascending, within base .. base + span).
@group(0) @binding(7) var<storage, read> list: array<u32>;
// Colour, then (F_SPLIT) direct and indirect parts: (j * M + m) * 3 + c, N * M * 3 each.
@group(0) @binding(8) var<storage, read_write> out: array<f32>;

// svgir_shading::split's clamped dot: [DOT_EPS, 1].
fn cdot(x: f32) -> f32 {
    return clamp(x, DOT_EPS, 1.0);
}

// atan(x) for x >= 0 to about 2 ulp: Cephes' atanf reduction to |x| <= tan(pi/8) and its
// degree-9 odd polynomial. The drivers' own atan may be far coarser (Vulkan allows 4096 ulp;
// lavapipe's moved the colours by 1e-4), and the lookup should not depend on the driver.
fn atan_pos(x: f32) -> f32 {
    var base = 0.0;
    var t = x;
    if x > 2.414213562373095 {
        base = 0.5 * PI;
        t = -1.0 / x;
    } else if x > 0.4142135623730950 {
        base = 0.25 * PI;
        t = (x - 1.0) / (x + 1.0);
    }
    let z = t * t;
    return base + ((((8.05374449538e-2 * z - 1.38776856032e-1) * z + 1.99777106478e-1) * z - 3.33329491539e-1) * z * t + t);
}

// atan2(y, x) in [-pi, pi] from atan_pos, with the signs of libm's (atan2(+-0, -x) = +-pi).
fn atan2_accurate(y: f32, x: f32) -> f32 {
    let ax = abs(x);
    let ay = abs(y);
    var a = 0.0;
    if ax >= ay {
        if ax > 0.0 {
            a = atan_pos(ay / ax);
        }
    } else {
        a = 0.5 * PI - atan_pos(ax / ay);
    }
    if x < 0.0 {
        a = PI - a;
    }
    return select(a, -a, y < 0.0 || (y == 0.0 && (bitcast<u32>(y) >> 31u) == 1u));
}

// svgir_core::envmap::grid_coords then Taps::at: the bilinear taps of direction d.
fn env_lookup(d_in: vec3<f32>) -> vec3<f32> {
    var d = vec3<f32>(0.0, 0.0, 1.0);
    let len = length(d_in);
    if len > 0.0 {
        d = d_in / len;
    }
    // acos(z) as atan2(sqrt((1 - z)(1 + z)), z): exact near the poles, where 1 - z^2 is not.
    let z = clamp(d.z, -1.0, 1.0);
    let phi = atan2_accurate(sqrt((1.0 - z) * (1.0 + z)), z);
    let theta = atan2_accurate(d.y, d.x);
    let gx = -theta / PI;
    let gy = 2.0 * phi / PI - 1.0;
    let wm = f32(P.env_w - 1u);
    let hm = f32(P.env_h - 1u);
    let fx = clamp((gx + 1.0) * 0.5 * wm, 0.0, wm);
    let fy = clamp((gy + 1.0) * 0.5 * hm, 0.0, hm);
    let x0 = u32(fx);
    let y0 = u32(fy);
    let x1 = min(x0 + 1u, P.env_w - 1u);
    let y1 = min(y0 + 1u, P.env_h - 1u);
    let tx = fx - f32(x0);
    let ty = fy - f32(y0);
    let idx = vec4<u32>(y0 * P.env_w + x0, y0 * P.env_w + x1, y1 * P.env_w + x0, y1 * P.env_w + x1);
    let w = vec4<f32>((1.0 - tx) * (1.0 - ty), tx * (1.0 - ty), (1.0 - tx) * ty, tx * ty);
    var raw = vec3<f32>(0.0);
    for (var t = 0u; t < 4u; t++) {
        let texel = tables[P.env_at + idx[t]];
        // BrightLights::mask_taps: a light texel is black to the K samples.
        if texel.w == 0.0 {
            raw += w[t] * texel.xyz;
        }
    }
    return raw;
}

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
    // SPEC 3: one view direction per Gaussian (normalize_or(Z)).
    var wo = vec3<f32>(0.0, 0.0, 1.0);
    let to_cam = P.camera - pos;
    let dist = length(to_cam);
    if dist > 0.0 {
        wo = to_cam / dist;
    }
    // The per-vertex lobes (svgir_shading::split::lobe).
    var vn: array<vec3<f32>, MAX_V>;
    var c0: array<f32, MAX_V>;
    var a2m1: array<f32, MAX_V>;
    var kk: array<f32, MAX_V>;
    var omk: array<f32, MAX_V>;
    for (var v = 0u; v < m; v++) {
        let nr = verts[(j * m + v) * 2u];
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
    let vis_on = (P.flags & F_VIS) != 0u;
    let local = j - P.base;
    let n_samples = P.k + P.lights;
    for (var s = 0u; s < n_samples; s++) {
        var dir: vec3<f32>;
        var direct = vec3<f32>(0.0);
        var ind = vec3<f32>(0.0);
        if s < P.k {
            // Micro-buffer sample (svgir_pbr::shade::sample).
            let w = samples[local * P.k + s];
            var vis = 1.0;
            if vis_on {
                vis = unpack2x16unorm(w.x).x;
            }
            var traced = vec3<f32>(0.0);
            if (P.flags & F_TRACED) != 0u {
                traced = vec3<f32>(unpack2x16float(w.x).y, unpack2x16float(w.y));
                ind = traced * P.rho;
            } else if (P.flags & F_GIVEN) != 0u {
                let g = (local * P.k + s) * 3u;
                ind = vec3<f32>(given[g], given[g + 1u], given[g + 2u]);
            }
            if vis <= 0.0 && all(traced == vec3<f32>(0.0)) && all(ind == vec3<f32>(0.0)) {
                continue;
            }
            // HemiFrame::dir.
            let f = tables[s];
            let c = f.x * b1.w - f.y * b2.w;
            let sn = f.y * b1.w + f.x * b2.w;
            dir = b1.xyz * (f.z * c) + b2.xyz * (f.z * sn) + nf * f.w;
            if vis > 0.0 {
                direct = vis * clamp(env_lookup(dir), vec3<f32>(0.0), vec3<f32>(P.env_max));
            }
        } else {
            // Directional light b (svgir_pbr::shade::light_sample): its one tap, unclamped.
            let b = s - P.k;
            let l0 = tables[P.lights_at + 2u * b];
            let texel_index = u32(tables[P.lights_at + 2u * b + 1u].x);
            dir = l0.xyz;
            var vis = 0.0;
            if vis_on {
                vis = light_vis[b * P.n + j];
            } else if dot(nf, dir) > 0.0 {
                vis = 1.0;
            }
            if vis <= 0.0 {
                continue;
            }
            direct = vis * l0.w * tables[P.env_at + texel_index].xyz;
        }
        // svgir_shading::split::half: the half vector and Schlick-Fresnel (UE4's exp2 form).
        let hsum = wo + dir;
        let h = hsum / max(length(hsum), 1e-12);
        let vh = cdot(dot(wo, h));
        let fr = F0 + (1.0 - F0) * exp2((-5.55473 * vh - 6.98316) * vh);
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
        let a = verts[(j * m + v) * 2u + 1u];
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
}
