// What the vertex shading's forward (shade.wgsl) and backward (shade_bwd.wgsl) share: their
// uniform, constants, and the env lookup with its driver-independent atan2. The lookup reads the
// kernels' own `P` and `tables` bindings (declared alike in both).

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

// SPEC 3: the view direction of a Gaussian at `pos` (normalize_or(Z)).
fn view_dir(pos: vec3<f32>) -> vec3<f32> {
    let to_cam = P.camera - pos;
    let dist = length(to_cam);
    if dist > 0.0 {
        return to_cam / dist;
    }
    return vec3<f32>(0.0, 0.0, 1.0);
}

// One sample of Gaussian j (`local` = j - base in the bound samples): micro-buffer direction s
// < K (svgir_pbr::shade::sample), else directional light s - K (light_sample). `ok` is false
// where no light can flow through it (V = 0 and no indirect light; a light not seen).
struct Sample {
    ok: bool,
    dir: vec3<f32>,
    vis: f32,
    direct: vec3<f32>,          // V clamp(L_env), or the light's V Omega K / 2pi texel
    live: vec3<bool>,           // channels inside the clamp (their gradient reaches the taps)
    traced: vec3<f32>,          // F_TRACED: L, d L_ind / d rho
    ind: vec3<f32>,             // L_ind
}

fn fetch_sample(j: u32, local: u32, s: u32, b1: vec4<f32>, b2: vec4<f32>, nf: vec3<f32>) -> Sample {
    var r: Sample;
    r.ok = false;
    r.direct = vec3<f32>(0.0);
    r.ind = vec3<f32>(0.0);
    r.traced = vec3<f32>(0.0);
    r.live = vec3<bool>(false);
    let vis_on = (P.flags & F_VIS) != 0u;
    if s < P.k {
        let w = samples[local * P.k + s];
        r.vis = 1.0;
        if vis_on {
            r.vis = unpack2x16unorm(w.x).x;
        }
        if (P.flags & F_TRACED) != 0u {
            r.traced = vec3<f32>(unpack2x16float(w.x).y, unpack2x16float(w.y));
            r.ind = r.traced * P.rho;
        } else if (P.flags & F_GIVEN) != 0u {
            let g = (local * P.k + s) * 3u;
            r.ind = vec3<f32>(given[g], given[g + 1u], given[g + 2u]);
        }
        if r.vis <= 0.0 && all(r.traced == vec3<f32>(0.0)) && all(r.ind == vec3<f32>(0.0)) {
            return r;
        }
        r.dir = frame_dir(b1, b2, nf, tables[s]);
        if r.vis > 0.0 {
            let raw = env_lookup(r.dir);
            r.direct = r.vis * clamp(raw, vec3<f32>(0.0), vec3<f32>(P.env_max));
            r.live = raw >= vec3<f32>(0.0) & raw <= vec3<f32>(P.env_max);
        }
        r.ok = true;
        return r;
    }
    // Directional light b: its one tap, unclamped.
    let b = s - P.k;
    let l0 = tables[P.lights_at + 2u * b];
    let texel_index = u32(tables[P.lights_at + 2u * b + 1u].x);
    r.dir = l0.xyz;
    r.vis = 0.0;
    if vis_on {
        r.vis = light_vis[b * P.n + j];
    } else if dot(nf, r.dir) > 0.0 {
        r.vis = 1.0;
    }
    if r.vis <= 0.0 {
        return r;
    }
    r.direct = r.vis * l0.w * tables[P.env_at + texel_index].xyz;
    r.live = vec3<bool>(true);
    r.ok = true;
    return r;
}
