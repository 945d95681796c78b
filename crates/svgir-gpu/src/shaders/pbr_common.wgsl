// What the vertex shading (shade*.wgsl), the one-bounce gather (gather.wgsl) and the
// radiance-consistency gather (consistency.wgsl) share: the constants of svgir_shading, the
// clamped dot, the env lookup with its driver-independent atan2, the hemisphere frame's
// directions, the half vector with Fresnel, the specular lobe's derivatives and the vertex weights. The lookup reads
// the including kernel's `P.env_w`, `P.env_h` and `tables` (declared alike in each).

const MAX_V: u32 = 6u;     // svgir_shading::MAX_VERTICES
const PI: f32 = 3.14159265358979;
const INV_PI: f32 = 0.3183098861837907;   // f32 of f64 1/pi, as the CPU's FRAC_1_PI
const FOUR_PI: f32 = 12.566370614359172; // f32 of f64 4 pi
const DOT_EPS: f32 = 1e-6; // svgir_shading::DOT_EPS
const F0: f32 = 0.04;      // svgir_shading::F0

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

// svgir_core::envmap::grid_coords then Taps::at: the bilinear lookup of direction d in the
// texels at `env_at` of `tables` (the light texels masked).
fn env_lookup_at(d_in: vec3<f32>, env_at: u32) -> vec3<f32> {
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
        let texel = tables[env_at + idx[t]];
        // BrightLights::mask_taps: a light texel is black to the K samples.
        if texel.w == 0.0 {
            raw += w[t] * texel.xyz;
        }
    }
    return raw;
}


// svgir_shading::HemiFrame::dir: Fibonacci row f = (cos g, sin g, r, z) in the frame (b1, cos xi),
// (b2, sin xi), nf.
fn frame_dir(b1: vec4<f32>, b2: vec4<f32>, nf: vec3<f32>, f: vec4<f32>) -> vec3<f32> {
    let c = f.x * b1.w - f.y * b2.w;
    let sn = f.y * b1.w + f.x * b2.w;
    return b1.xyz * (f.z * c) + b2.xyz * (f.z * sn) + nf * f.w;
}

// svgir_shading::split::half: the half vector and Schlick-Fresnel (UE4's exp2 form), (h, F).
fn half_fresnel(wo: vec3<f32>, dir: vec3<f32>) -> vec4<f32> {
    let hsum = wo + dir;
    let h = hsum / max(length(hsum), 1e-12);
    let vh = cdot(dot(wo, h));
    return vec4<f32>(h, F0 + (1.0 - F0) * exp2((-5.55473 * vh - 6.98316) * vh));
}

// svgir_shading::split::spec_grad: S and its derivatives in r and n for one vertex, (S, dS/dr)
// and dS/dn.
struct SpecGrad {
    value: f32,
    v_r: f32,
    v_n: vec3<f32>,
}

fn dot_live(x: f32) -> bool {
    return x > DOT_EPS && x < 1.0;
}

fn spec_grad(n: vec3<f32>, r: f32, nv_raw: f32, h: vec3<f32>, fr: f32, wo: vec3<f32>, l: vec3<f32>, nl_raw: f32) -> SpecGrad {
    // The lobe (svgir_shading::split::lobe).
    let nv = cdot(nv_raw);
    let a = r * r;
    let a2 = a * a;
    let k = (r + 1.0) * (r + 1.0) / 8.0;
    let omk = 1.0 - k;
    let gv = 1.0 / (nv * omk + k);
    let d0 = a2 / PI;
    let cr = 4.0 * r * r * r / PI;
    let cn = -4.0 * a2 * (a2 - 1.0) / PI;
    let nl = cdot(nl_raw);
    let nh_raw = dot(n, h);
    let nh = cdot(nh_raw);
    let q = nh * nh * (a2 - 1.0) + 1.0;
    let den = nl * omk + k;
    let t = 1.0 / (q * den);
    let inv_q = den * t;
    let gl = q * t;
    let d = d0 * inv_q * inv_q;
    let fq = fr * 0.25;
    var g: SpecGrad;
    g.value = fq * d * gv * gl;
    let inv_q3 = inv_q * inv_q * inv_q;
    let dd_dr = (q - 2.0 * a2 * nh * nh) * inv_q3 * cr;
    let dk_dr = (r + 1.0) * 0.25;
    let dgv_dk = -(1.0 - nv) * gv * gv;
    let dgl_dk = -(1.0 - nl) * gl * gl;
    g.v_r = fq * (dd_dr * gv * gl + d * (dgv_dk * gl + gv * dgl_dk) * dk_dr);
    let ds_dnh = select(0.0, fq * gv * gl * (cn * nh * inv_q3), dot_live(nh_raw));
    let ds_dnv = select(0.0, -fq * d * gl * omk * gv * gv, dot_live(nv_raw));
    let ds_dnl = select(0.0, -fq * d * gv * omk * gl * gl, dot_live(nl_raw));
    g.v_n = ds_dnh * h + ds_dnv * wo + ds_dnl * l;
    return g;
}

// svgir_shading::vertex_weights at (u~, v~).
fn vertex_weights(m: u32, u: f32, v: f32) -> array<f32, MAX_V> {
    var w: array<f32, MAX_V>;
    if m == 1u {
        w[0] = 1.0;
    } else if m == 2u {
        w[0] = 1.0 - u;
        w[1] = u;
    } else if m == 4u {
        w[0] = (1.0 - u) * (1.0 - v);
        w[1] = u * (1.0 - v);
        w[2] = (1.0 - u) * v;
        w[3] = u * v;
    } else {
        let l = array<f32, 3>(2.0 * (u - 0.5) * (u - 1.0), -4.0 * u * (u - 1.0), 2.0 * u * (u - 0.5));
        for (var i = 0u; i < 3u; i++) {
            w[i] = l[i] * (1.0 - v);
            w[3u + i] = l[i] * v;
        }
    }
    return w;
}
