// Shared by stage 1's loss kernels (SPEC 2): the per-view uniform, the layouts of the buffers
// they pass along, the SSIM window and a workgroup sum.

struct LossParams {
    // Camera-to-world rotation rows (w unused): the ray of pixel (x, y) is R^T (u, v, 1).
    rt0: vec4<f32>,
    rt1: vec4<f32>,
    rt2: vec4<f32>,
    // Camera centre (w unused).
    center: vec4<f32>,
    // fx, fy, cx, cy.
    k: vec4<f32>,
    // Background colour the photo is composited over (w unused).
    bg: vec4<f32>,
    // The SSIM window's 11 taps (svgir_metrics::gaussian_window), 12th unused.
    taps0: vec4<f32>,
    taps1: vec4<f32>,
    taps2: vec4<f32>,
    width: u32,
    height: u32,
    // 1: the mask and entropy losses are on.
    use_mask: u32,
    // Slot of the loss ring this iteration writes.
    slot: u32,
    w_l1: f32,
    w_ssim: f32,
    w_mask: f32,
    w_entropy: f32,
    // The depth-normal weight at this iteration (0: the term is off) and the distortion weight.
    w_dn: f32,
    w_dist: f32,
    // Workgroups of the per-pixel kernels (rows of `partials`).
    groups: u32,
    _pad: u32,
}

// The forward's per-pixel record (raster_fwd.wgsl): colour 0..3, alpha 3, depth 4, normal 6..9,
// distortion 9.
const PIX: u32 = 13u;
// The output gradients (raster_bwd.wgsl): colour 0..3, alpha 3, depth 4, normal 5..8, distortion 8.
const VPIX: u32 = 9u;
// The photo: RGB, alpha, dilated mask (0 or 1).
const TGT: u32 = 5u;
// Per-workgroup partial sums, and the loss ring's record: |d| sum, SSIM-map sum, mask sum,
// entropy sum, depth-normal sum, distortion sum, squared-error sum; the ring's 8th is the total.
const PARTS: u32 = 8u;
const HALF: i32 = 5;
// Opacity below which the expected depth is not formed (losses/depth_normal.rs).
const MIN_OPACITY: f32 = 1e-4;

var<workgroup> red: array<f32, 256>;

fn tap(L: LossParams, k: i32) -> f32 {
    let i = u32(k + HALF);
    if i < 4u {
        return L.taps0[i];
    }
    if i < 8u {
        return L.taps1[i - 4u];
    }
    return L.taps2[i - 8u];
}

fn ray_of(L: LossParams, x: u32, y: u32) -> vec3<f32> {
    let d = vec3<f32>((f32(x) + 0.5 - L.k.z) / L.k.x, (f32(y) + 0.5 - L.k.w) / L.k.y, 1.0);
    return vec3<f32>(dot(L.rt0.xyz, d), dot(L.rt1.xyz, d), dot(L.rt2.xyz, d));
}

// Sum of `v` over the workgroup's 256 threads, in a fixed tree order (the same at every run).
// Every thread must call it.
fn wg_sum(v: f32, tid: u32) -> f32 {
    red[tid] = v;
    workgroupBarrier();
    for (var s = 128u; s > 0u; s >>= 1u) {
        if tid < s {
            red[tid] += red[tid + s];
        }
        workgroupBarrier();
    }
    let r = red[0];
    workgroupBarrier();
    return r;
}
