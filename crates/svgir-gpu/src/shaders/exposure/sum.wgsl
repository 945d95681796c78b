// The correction's parameter gradients: each of the 12 summed over the workgroups' partials in
// group order (backward.wgsl), into `grad`, which the Adam step (adam.wgsl) reads. One
// workgroup, a thread per parameter.

@group(0) @binding(0) var<uniform> E: ExposureParams;
@group(0) @binding(1) var<storage, read> partials: array<f32>;
@group(0) @binding(2) var<storage, read_write> grad: array<f32>;

@compute @workgroup_size(16)
fn main(@builtin(local_invocation_index) q: u32) {
    if q >= PARAMS {
        return;
    }
    var s = 0.0;
    for (var g = 0u; g < E.groups; g++) {
        s += partials[g * PARAMS + q];
    }
    grad[q] = s;
}
