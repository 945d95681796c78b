// Stage 1's loss, kernel 2 of 4: the vertical pass of the moments' blur, the SSIM map and its
// partials (ssim_backward.rs: dS/dmu1, dS/de11, dS/de12, each over N = 3 pixels), and the first
// pass of the depth-normal term (losses/depth_normal.rs, pass 1): per interior pixel the normal
// of the depth's back-projected points, the pixel's loss, dL/dN (written to `vout`, already
// weighted) and the gradients of its two difference vectors (`dbuf`, 6 floats a pixel). One
// thread per pixel; each workgroup writes its SSIM-map and depth-normal sums to `partials`.

@group(0) @binding(0) var<uniform> L: LossParams;
@group(0) @binding(1) var<storage, read> hbuf: array<f32>;
@group(0) @binding(2) var<storage, read> img: array<f32>;
@group(0) @binding(3) var<storage, read_write> pbuf: array<f32>;
@group(0) @binding(4) var<storage, read_write> dbuf: array<f32>;
@group(0) @binding(5) var<storage, read_write> vout: array<f32>;
@group(0) @binding(6) var<storage, read_write> partials: array<f32>;

const C1: f32 = 0.0001;
const C2: f32 = 0.0009;

fn point_of(q: u32, x: u32, y: u32) -> vec3<f32> {
    let s = img[q * PIX + 4u];
    let o = img[q * PIX + 3u];
    return L.center.xyz + s / max(o, MIN_OPACITY) * ray_of(L, x, y);
}

@compute @workgroup_size(256)
fn main(
    @builtin(global_invocation_id) gid: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(local_invocation_index) tid: u32,
) {
    let p = gid.x + gid.y * nwg.x * 256u;
    let w = L.width;
    let h = L.height;
    let npx = w * h;
    let inside = p < npx;
    let inv_count = 1.0 / f32(npx * 3u);
    var s_sum = 0.0;
    var dn_sum = 0.0;
    if inside {
        let x = p % w;
        let y = p / w;
        for (var c = 0u; c < 3u; c++) {
            var m = array<f32, 5>(0.0, 0.0, 0.0, 0.0, 0.0);
            for (var k = -HALF; k <= HALF; k++) {
                let yy = i32(y) + k;
                if yy < 0 || yy >= i32(h) {
                    continue;
                }
                let q = u32(yy) * w + x;
                let t = tap(L, k);
                for (var j = 0u; j < 5u; j++) {
                    m[j] += t * hbuf[q * 15u + c * 5u + j];
                }
            }
            let mu1 = m[0];
            let mu2 = m[1];
            let a1 = 2.0 * mu1 * mu2 + C1;
            let a2 = 2.0 * (m[4] - mu1 * mu2) + C2;
            let b1 = mu1 * mu1 + mu2 * mu2 + C1;
            let b2 = (m[2] - mu1 * mu1) + (m[3] - mu2 * mu2) + C2;
            let sm = (a1 * a2) / (b1 * b2);
            s_sum += sm;
            let s = sm * inv_count;
            pbuf[p * 9u + c * 3u] = s * (2.0 * mu2 / a1 - 2.0 * mu2 / a2 - 2.0 * mu1 / b1 + 2.0 * mu1 / b2);
            pbuf[p * 9u + c * 3u + 1u] = -s / b2;
            pbuf[p * 9u + c * 3u + 2u] = 2.0 * s / a2;
        }
        var v_dx = vec3<f32>(0.0);
        var v_dy = vec3<f32>(0.0);
        var v_n = vec3<f32>(0.0);
        if L.w_dn != 0.0 {
            var pix_loss = 1.0;
            if x > 0u && y > 0u && x + 1u < w && y + 1u < h {
                let dx = point_of(p + 1u, x + 1u, y) - point_of(p - 1u, x - 1u, y);
                let dy = point_of(p + w, x, y + 1u) - point_of(p - w, x, y - 1u);
                let cr = cross(dy, dx);
                let len = length(cr);
                if len >= 1e-20 {
                    let nd = cr / len;
                    let o = img[p * PIX + 3u];
                    let ni = vec3<f32>(img[p * PIX + 6u], img[p * PIX + 7u], img[p * PIX + 8u]);
                    let np = f32(npx);
                    pix_loss = 1.0 - dot(ni, nd * o);
                    v_n = -nd * o / np;
                    let v_nd = -ni * o / np;
                    let v_cr = (v_nd - nd * dot(nd, v_nd)) / len;
                    // cr = dy x dx: d/d dy = dx x v_cr, d/d dx = v_cr x dy.
                    v_dy = cross(dx, v_cr);
                    v_dx = cross(v_cr, dy);
                }
            }
            dn_sum = pix_loss;
        }
        dbuf[p * 6u] = v_dx.x;
        dbuf[p * 6u + 1u] = v_dx.y;
        dbuf[p * 6u + 2u] = v_dx.z;
        dbuf[p * 6u + 3u] = v_dy.x;
        dbuf[p * 6u + 4u] = v_dy.y;
        dbuf[p * 6u + 5u] = v_dy.z;
        vout[p * VPIX + 5u] = L.w_dn * v_n.x;
        vout[p * VPIX + 6u] = L.w_dn * v_n.y;
        vout[p * VPIX + 7u] = L.w_dn * v_n.z;
    }
    let wg = wid.x + wid.y * nwg.x;
    let s_tot = wg_sum(s_sum, tid);
    let dn_tot = wg_sum(dn_sum, tid);
    if tid == 0u {
        partials[wg * PARTS + 1u] = s_tot;
        partials[wg * PARTS + 4u] = dn_tot;
    }
}
