// Stage 1's loss, kernel 4 of 4 (losses/objective.rs): the vertical pass of the partials' blur,
// giving D-SSIM's colour gradient `G*(dS/dmu1) + 2 x G*(dS/de11) + y G*(dS/de12)`; L1's; the mask
// and entropy terms on the rendered opacity; the depth-normal term's second pass (each pixel
// gathers its neighbours' difference gradients onto its depth and opacity); the distortion's
// constant gradient. Writes the output gradients the raster backward reads (`vout`, all but the
// normal, which ssim_map.wgsl wrote) and each workgroup's sums to `partials`. One thread per pixel.

@group(0) @binding(0) var<uniform> L: LossParams;
@group(0) @binding(1) var<storage, read> img: array<f32>;
@group(0) @binding(2) var<storage, read> tgt: array<f32>;
@group(0) @binding(3) var<storage, read> qbuf: array<f32>;
@group(0) @binding(4) var<storage, read> dbuf: array<f32>;
@group(0) @binding(5) var<storage, read_write> vout: array<f32>;
@group(0) @binding(6) var<storage, read_write> partials: array<f32>;

fn dvec(q: u32, at: u32) -> vec3<f32> {
    return vec3<f32>(dbuf[q * 6u + at], dbuf[q * 6u + at + 1u], dbuf[q * 6u + at + 2u]);
}

// The photo composited over the background (stage1::target_rgb), channel c.
fn gt_at(q: u32, c: u32) -> f32 {
    let a = tgt[q * TGT + 3u];
    return tgt[q * TGT + c] * a + L.bg[c] * (1.0 - a);
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
    let nf = f32(npx * 3u);
    let np = f32(npx);
    var l1_sum = 0.0;
    var se_sum = 0.0;
    var mask_sum = 0.0;
    var ent_sum = 0.0;
    var dist_sum = 0.0;
    if inside {
        let x = p % w;
        let y = p / w;
        var q = array<f32, 9>(0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0);
        for (var k = -HALF; k <= HALF; k++) {
            let yy = i32(y) + k;
            if yy < 0 || yy >= i32(h) {
                continue;
            }
            let r = u32(yy) * w + x;
            let t = tap(L, k);
            for (var j = 0u; j < 9u; j++) {
                q[j] += t * qbuf[r * 9u + j];
            }
        }
        for (var c = 0u; c < 3u; c++) {
            let a = img[p * PIX + c];
            let b = gt_at(p, c);
            let d = a - b;
            l1_sum += abs(d);
            se_sum += d * d;
            let v_l1 = select(0.0, L.w_l1 * sign(d) / nf, d != 0.0);
            let v_ssim = q[c * 3u] + 2.0 * a * q[c * 3u + 1u] + b * q[c * 3u + 2u];
            vout[p * VPIX + c] = v_l1 - L.w_ssim * v_ssim;
        }
        let o = img[p * PIX + 3u];
        var v_a = 0.0;
        if L.use_mask != 0u {
            if tgt[p * TGT + 4u] == 0.0 {
                v_a += L.w_mask / np;
                mask_sum = o;
            }
            let oc = clamp(o, 1e-6, 1.0 - 1e-6);
            let m = tgt[p * TGT + 3u];
            v_a += L.w_entropy * ((oc - m) / (oc * (1.0 - oc)) / np);
            ent_sum = -(m * log(oc) + (1.0 - m) * log(1.0 - oc));
        }
        var v_depth = 0.0;
        if L.w_dn != 0.0 {
            var v_p = vec3<f32>(0.0);
            if x > 0u {
                v_p += dvec(p - 1u, 0u);
            }
            if x + 1u < w {
                v_p -= dvec(p + 1u, 0u);
            }
            if y > 0u {
                v_p += dvec(p - w, 3u);
            }
            if y + 1u < h {
                v_p -= dvec(p + w, 3u);
            }
            let v_d = dot(v_p, ray_of(L, x, y));
            let s = img[p * PIX + 4u];
            if o > MIN_OPACITY {
                v_depth = L.w_dn * (v_d / o);
                v_a += L.w_dn * (-v_d * s / (o * o));
            } else {
                v_depth = L.w_dn * (v_d / MIN_OPACITY);
            }
        }
        vout[p * VPIX + 3u] = v_a;
        vout[p * VPIX + 4u] = v_depth;
        var v_dist = 0.0;
        if L.w_dist > 0.0 {
            v_dist = L.w_dist / np;
            dist_sum = img[p * PIX + 9u];
        }
        vout[p * VPIX + 8u] = v_dist;
    }
    let wg = wid.x + wid.y * nwg.x;
    let l1_tot = wg_sum(l1_sum, tid);
    let mask_tot = wg_sum(mask_sum, tid);
    let ent_tot = wg_sum(ent_sum, tid);
    let dist_tot = wg_sum(dist_sum, tid);
    let se_tot = wg_sum(se_sum, tid);
    if tid == 0u {
        partials[wg * PARTS] = l1_tot;
        partials[wg * PARTS + 2u] = mask_tot;
        partials[wg * PARTS + 3u] = ent_tot;
        partials[wg * PARTS + 5u] = dist_tot;
        partials[wg * PARTS + 6u] = se_tot;
    }
}
