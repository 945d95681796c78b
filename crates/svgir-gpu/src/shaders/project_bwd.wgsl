// Backward of project.wgsl, one thread per Gaussian (svgir_raster::preprocess_backward): the
// Gaussian's entry slots (raster_bwd.wgsl) are summed in entry order, the H gradient is formed
// from the sums of dL/dp (splat.rs, SplatGrad::h_grad), and the chain goes through the projected
// centre, H = K [R s_u t_u | R s_v t_v | R p + t], the quaternion, the sigmoid and the SH colour
// to the raw parameters. Also the densification statistics: |dL/d mean2d| and the weight sum.

@group(0) @binding(0) var<uniform> P: Params;
@group(0) @binding(1) var<storage, read> pos: array<f32>;
@group(0) @binding(2) var<storage, read> rot: array<f32>;
@group(0) @binding(3) var<storage, read> sh: array<f32>;
@group(0) @binding(4) var<storage, read> splat: array<f32>;
@group(0) @binding(5) var<storage, read> rank: array<u32>;
@group(0) @binding(6) var<storage, read> off: array<u32>;
@group(0) @binding(7) var<storage, read> cnt: array<u32>;
@group(0) @binding(8) var<storage, read> grads: array<f32>;
// Per Gaussian: position (3), rotation (4), log-scale (2), opacity logit, mean2d norm, weight (12).
@group(0) @binding(9) var<storage, read_write> vparam: array<f32>;
// Per Gaussian: SH (48).
@group(0) @binding(10) var<storage, read_write> vsh: array<f32>;

const DIM: u32 = 24u;

// d(loss)/d(raw quaternion) from d(loss)/dR (vr[i] = row i), for R = R(q / |q|).
fn quat_backward(q: vec4<f32>, vr: mat3x3<f32>) -> vec4<f32> {
    let len = sqrt(dot(q.xyz, q.xyz) + q.w * q.w);
    let x = q.x / len;
    let y = q.y / len;
    let z = q.z / len;
    let w = q.w / len;
    let g00 = vr[0][0]; let g01 = vr[0][1]; let g02 = vr[0][2];
    let g10 = vr[1][0]; let g11 = vr[1][1]; let g12 = vr[1][2];
    let g20 = vr[2][0]; let g21 = vr[2][1]; let g22 = vr[2][2];
    let vw = 2.0 * (-z * g01 + y * g02 + z * g10 - x * g12 - y * g20 + x * g21);
    let vx = 2.0 * (y * g01 + z * g02 + y * g10 - 2.0 * x * g11 - w * g12 + z * g20 + w * g21 - 2.0 * x * g22);
    let vy = 2.0 * (-2.0 * y * g00 + x * g01 + w * g02 + x * g10 + z * g12 - w * g20 + z * g21 - 2.0 * y * g22);
    let vz = 2.0 * (-2.0 * z * g00 - w * g01 + x * g02 + w * g10 - 2.0 * z * g11 + y * g12 + x * g20 + y * g21);
    let gq = vec4<f32>(vx, vy, vz, vw);
    let qh = vec4<f32>(x, y, z, w);
    return (gq - qh * dot(gq, qh)) / len;
}

@compute @workgroup_size(256)
fn main(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = gid.x + gid.y * nwg.x * 256u;
    if i >= P.n {
        return;
    }
    let sp = i * SPLAT;
    let k = rank[i];
    let nent = cnt[k];
    for (var c = 0u; c < VP; c++) {
        vparam[i * VP + c] = 0.0;
    }
    for (var c = 0u; c < 48u; c++) {
        vsh[i * 48u + c] = 0.0;
    }
    if nent == 0u {
        return;
    }
    var sum: array<f32, 24>;
    for (var c = 0u; c < DIM; c++) {
        sum[c] = 0.0;
    }
    // Entries past the capacity were dropped (an overflowed render, whose step the optimiser skips).
    let e0 = min(off[k], P.capacity);
    let e1 = min(off[k] + nent, P.capacity);
    for (var e = e0; e < e1; e++) {
        for (var c = 0u; c < DIM; c++) {
            sum[c] += grads[e * DIM + c];
        }
    }
    let v_col = vec3<f32>(sum[0], sum[1], sum[2]);
    let h_depth = vec3<f32>(sum[3], sum[4], sum[5]);
    let v_center = vec2<f32>(sum[6], sum[7]);
    let v_o = sum[8];
    let v_n = vec3<f32>(sum[9], sum[10], sum[11]);
    let gp = vec3<f32>(sum[12], sum[13], sum[14]);
    let gp_x = vec3<f32>(sum[15], sum[16], sum[17]);
    let gp_y = vec3<f32>(sum[18], sum[19], sum[20]);
    let weight = sum[21];

    let tu = vec3<f32>(splat[sp], splat[sp + 1u], splat[sp + 2u]);
    let tv = vec3<f32>(splat[sp + 3u], splat[sp + 4u], splat[sp + 5u]);
    let tw = vec3<f32>(splat[sp + 6u], splat[sp + 7u], splat[sp + 8u]);
    // SplatGrad::h_grad.
    let vtu = cross(tv, gp) - cross(tw, gp_y);
    let vtv = cross(gp, tu) - cross(gp_x, tw);
    let vtw = cross(tu, gp_y) - cross(tv, gp_x) + h_depth;
    var vh0 = vtu;
    var vh1 = vtv;
    var vh2 = vtw;
    // Projected centre c = (H02 / H22, H12 / H22).
    let inv = 1.0 / tw.z;
    vh0.z += v_center.x * inv;
    vh1.z += v_center.y * inv;
    vh2.z -= (v_center.x * tu.z + v_center.y * tv.z) * inv * inv;
    // H = K M with M = [a_u a_v a_0]: v_M = K^T v_H; rows of v_M.
    let fx = P.k.x;
    let fy = P.k.y;
    let cx = P.k.z;
    let cy = P.k.w;
    let vm0 = fx * vh0;
    let vm1 = fy * vh1;
    let vm2 = cx * vh0 + cy * vh1 + vh2;
    // Columns of v_M: (vm0.c, vm1.c, vm2.c).
    let v_au = cam_rot_t(P, vec3<f32>(vm0.x, vm1.x, vm2.x));
    let v_av = cam_rot_t(P, vec3<f32>(vm0.y, vm1.y, vm2.y));
    var v_p = cam_rot_t(P, vec3<f32>(vm0.z, vm1.z, vm2.z));

    let q = vec4<f32>(rot[i * 4u], rot[i * 4u + 1u], rot[i * 4u + 2u], rot[i * 4u + 3u]);
    let rows = quat_rows(q);
    let rtu = rot_col(rows, 0u);
    let rtv = rot_col(rows, 1u);
    let su = splat[sp + S_SCALE];
    let sv = splat[sp + S_SCALE + 1u];
    let flip = splat[sp + S_FLIP];
    let o = splat[sp + S_OPACITY];
    // v_R rows: (su v_au[r], sv v_av[r], flip v_n[r]).
    let vr = mat3x3<f32>(
        vec3<f32>(su * v_au.x, sv * v_av.x, flip * v_n.x),
        vec3<f32>(su * v_au.y, sv * v_av.y, flip * v_n.y),
        vec3<f32>(su * v_au.z, sv * v_av.z, flip * v_n.z),
    );
    let v_q = quat_backward(q, vr);

    // SH colour backward (preprocess_backward.rs, sh_color_backward).
    let p = vec3<f32>(pos[i * 3u], pos[i * 3u + 1u], pos[i * 3u + 2u]);
    let dir = p - P.center.xyz;
    let len = sqrt(dot(dir, dir));
    let d = dir / len;
    let clamped = u32(splat[sp + S_CLAMPED]);
    let gc = vec3<f32>(
        select(v_col.x, 0.0, (clamped & 1u) != 0u),
        select(v_col.y, 0.0, (clamped & 2u) != 0u),
        select(v_col.z, 0.0, (clamped & 4u) != 0u),
    );
    let deg = min(P.sh_degree, 3u);
    var b: array<f32, 16>;
    var bg: array<vec3<f32>, 16>;
    sh_basis(deg, d, &b);
    sh_basis_grad(deg, d, &bg);
    let nc = (deg + 1u) * (deg + 1u);
    var v_d = vec3<f32>(0.0);
    for (var kk = 0u; kk < nc; kk++) {
        let base = i * 48u + kk * 3u;
        vsh[base] = b[kk] * gc.x;
        vsh[base + 1u] = b[kk] * gc.y;
        vsh[base + 2u] = b[kk] * gc.z;
        let s = sh[base] * gc.x + sh[base + 1u] * gc.y + sh[base + 2u] * gc.z;
        v_d += bg[kk] * s;
    }
    v_p += (v_d - d * dot(d, v_d)) / len;

    let o_base = i * VP;
    vparam[o_base] = v_p.x;
    vparam[o_base + 1u] = v_p.y;
    vparam[o_base + 2u] = v_p.z;
    vparam[o_base + 3u] = v_q.x;
    vparam[o_base + 4u] = v_q.y;
    vparam[o_base + 5u] = v_q.z;
    vparam[o_base + 6u] = v_q.w;
    vparam[o_base + 7u] = su * dot(rtu, v_au);
    vparam[o_base + 8u] = sv * dot(rtv, v_av);
    vparam[o_base + 9u] = v_o * o * (1.0 - o);
    // Densification statistic (GradsOf::v_mean2d_norm).
    let gcam = cam_rot(P, v_p);
    let z = splat[sp + S_DEPTH];
    let nx = gcam.x * z / fx;
    let ny = gcam.y * z / fy;
    vparam[o_base + 10u] = sqrt(nx * nx + ny * ny);
    vparam[o_base + 11u] = weight;
}
