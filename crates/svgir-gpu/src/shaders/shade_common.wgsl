// What the vertex shading's forward (shade.wgsl) and backward (shade_bwd.wgsl) share beyond
// pbr_common.wgsl: their uniform, flags, the view direction and a sample's light. The helpers
// read the kernels' own `P`, `tables`, `samples`, `given` and `light_vis` (declared alike).

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
    base: u32,        // first Gaussian whose given light and light gradients are bound
    span: u32,        // Gaussians whose given light and light gradients are bound
    sbase: u32,       // first Gaussian whose samples are bound (<= base: a kept chunk's)
}

const F_VIS: u32 = 1u;     // ShadeParams::visibility (else V = 1)
const F_TRACED: u32 = 2u;  // Indirect::Traced
const F_GIVEN: u32 = 4u;   // Indirect::Given
const F_SPLIT: u32 = 8u;   // write the direct and indirect parts too
// The lookup in this kernel's env texels.
fn env_lookup(d: vec3<f32>) -> vec3<f32> {
    return env_lookup_at(d, P.env_at);
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
        let w = samples[(j - P.sbase) * P.k + s];
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
