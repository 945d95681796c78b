// The correction's forward: each pixel's rendered colour becomes its object's corrected colour
// over the background in place, the loss's input; the render's own colour is saved in `raw` for the backward, which puts it back before
// the raster backward reads the forward's record. One thread per pixel.

@group(0) @binding(0) var<uniform> E: ExposureParams;
@group(0) @binding(1) var<storage, read> params: array<f32>;
@group(0) @binding(2) var<storage, read_write> img: array<f32>;
@group(0) @binding(3) var<storage, read_write> raw: array<f32>;

fn corrected(row: u32, c: vec3<f32>, a: f32) -> vec3<f32> {
    let under = E.bg.xyz * (1.0 - a);
    let f = c - under;
    var out: vec3<f32>;
    for (var k = 0u; k < 3u; k++) {
        let r = row + 3u * k;
        out[k] = params[r] * f.x + params[r + 1u] * f.y + params[r + 2u] * f.z + params[row + 9u + k] * a;
    }
    return out + under;
}

@compute @workgroup_size(256)
fn main(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = gid.x + gid.y * nwg.x * 256u;
    if i >= E.npx {
        return;
    }
    let c = vec3<f32>(img[i * PIX], img[i * PIX + 1u], img[i * PIX + 2u]);
    let o = corrected(E.row, c, img[i * PIX + 3u]);
    for (var k = 0u; k < 3u; k++) {
        raw[i * 3u + k] = c[k];
        img[i * PIX + k] = o[k];
    }
}
