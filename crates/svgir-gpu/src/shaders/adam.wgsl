// Adam (svgir_train::adam, torch.optim.Adam's non-fused order of operations) on one parameter
// group, resident: each thread updates one float of the group from its gradient, which the
// projection backward left interleaved in `grad` (row stride `gstride`, the group's columns
// from `goff`). The host counts the steps and passes the bias-corrected constants. A render
// whose tile entries overflowed the buffers (bin_total.wgsl) has its step skipped: no update
// from a truncated list. One thread per float.
//
// The opacity group may add the binary-opacity term's gradient here (svgir_train::losses::opacity:
// `dL/dx = -x o (1 - o) / N` of the logit x before the step, times the term's weight), as the CPU
// adds it to the gradient before its step; one dispatch fewer than a kernel of its own.

struct AdamParams {
    // Floats in the group (rows x stride).
    count: u32,
    stride: u32,
    gstride: u32,
    goff: u32,
    b1: f32,
    b2: f32,
    eps: f32,
    bc2_sqrt: f32,
    // step_size x lr_scale for the first `first` columns of a row and for the rest (SH: the
    // DC terms at full rate, the others at 1/20; SPEC 2).
    lr_first: f32,
    lr_rest: f32,
    first: u32,
    // The binary-opacity term's weight / N (0: off; the opacity group only, stride 1).
    binary: f32,
}

@group(0) @binding(0) var<uniform> A: AdamParams;
@group(0) @binding(1) var<storage, read_write> param: array<f32>;
@group(0) @binding(2) var<storage, read> grad: array<f32>;
@group(0) @binding(3) var<storage, read_write> m1: array<f32>;
@group(0) @binding(4) var<storage, read_write> m2: array<f32>;
@group(0) @binding(5) var<storage, read> count: array<u32>;

@compute @workgroup_size(256)
fn main(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = gid.x + gid.y * nwg.x * 256u;
    if i >= A.count || count[C_OVERFLOW] != 0u {
        return;
    }
    let row = i / A.stride;
    let c = i - row * A.stride;
    var g = grad[row * A.gstride + A.goff + c];
    if A.binary != 0.0 {
        let x = param[i];
        let o = 1.0 / (1.0 + exp(-x));
        g = g + A.binary * (-x * o * (1.0 - o));
    }
    let m = A.b1 * m1[i] + (1.0 - A.b1) * g;
    let v = A.b2 * m2[i] + (1.0 - A.b2) * g * g;
    m1[i] = m;
    m2[i] = v;
    let denom = sqrt(v) / A.bc2_sqrt + A.eps;
    let lr = select(A.lr_rest, A.lr_first, c < A.first);
    param[i] = param[i] - lr * m / denom;
}
