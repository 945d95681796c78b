// Stage 1's loss, kernel 3 of 4: the horizontal pass of the blur of SSIM's partials (the blur is
// symmetric with zero padding, so it is its own adjoint; ssim_backward.rs). One thread per
// pixel, 9 floats a pixel (channel-major: dS/dmu1, dS/de11, dS/de12).

@group(0) @binding(0) var<uniform> L: LossParams;
@group(0) @binding(1) var<storage, read> pbuf: array<f32>;
@group(0) @binding(2) var<storage, read_write> qbuf: array<f32>;

@compute @workgroup_size(256)
fn main(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let p = gid.x + gid.y * nwg.x * 256u;
    if p >= L.width * L.height {
        return;
    }
    let x = i32(p % L.width);
    let row = p - u32(x);
    var m = array<f32, 9>(0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0);
    for (var k = -HALF; k <= HALF; k++) {
        let xx = x + k;
        if xx < 0 || xx >= i32(L.width) {
            continue;
        }
        let q = row + u32(xx);
        let t = tap(L, k);
        for (var j = 0u; j < 9u; j++) {
            m[j] += t * pbuf[q * 9u + j];
        }
    }
    for (var j = 0u; j < 9u; j++) {
        qbuf[p * 9u + j] = m[j];
    }
}
