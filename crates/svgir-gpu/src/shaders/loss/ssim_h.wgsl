// Stage 1's loss, kernel 1 of 4: the horizontal pass of SSIM's 11-tap Gaussian blur (SPEC 2's
// D-SSIM; svgir_metrics' 3DGS variant, zero padding) of the five moments x, y, x^2, y^2, xy of
// render x and photo y, per channel. One thread per pixel; `hbuf` holds 15 floats a pixel
// (channel-major: x, y, xx, yy, xy).

@group(0) @binding(0) var<uniform> L: LossParams;
@group(0) @binding(1) var<storage, read> img: array<f32>;
@group(0) @binding(2) var<storage, read> tgt: array<f32>;
@group(0) @binding(3) var<storage, read_write> hbuf: array<f32>;

// The photo composited over the background (stage1::target_rgb), channel c.
fn gt_at(q: u32, c: u32) -> f32 {
    let a = tgt[q * TGT + 3u];
    return tgt[q * TGT + c] * a + L.bg[c] * (1.0 - a);
}

@compute @workgroup_size(256)
fn main(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let p = gid.x + gid.y * nwg.x * 256u;
    if p >= L.width * L.height {
        return;
    }
    let x = i32(p % L.width);
    let row = p - u32(x);
    for (var c = 0u; c < 3u; c++) {
        var m = array<f32, 5>(0.0, 0.0, 0.0, 0.0, 0.0);
        for (var k = -HALF; k <= HALF; k++) {
            let xx = x + k;
            if xx < 0 || xx >= i32(L.width) {
                continue;
            }
            let q = row + u32(xx);
            let a = img[q * PIX + c];
            let b = gt_at(q, c);
            let w = tap(L, k);
            m[0] += w * a;
            m[1] += w * b;
            m[2] += w * a * a;
            m[3] += w * b * b;
            m[4] += w * a * b;
        }
        for (var j = 0u; j < 5u; j++) {
            hbuf[p * 15u + c * 5u + j] = m[j];
        }
    }
}
