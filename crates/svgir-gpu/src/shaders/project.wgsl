// Projection (SPEC 1), one thread per Gaussian: culling, the ray-splat matrix H, the projected
// centre, the camera-facing normal, the screen box, the SH colour, and the binning inputs (the
// number of 16-px tiles the box touches, the depth sort key). As
// svgir_raster::preprocess::project_one, except that the box, a culling bound only, is computed
// in f32 with a half-pixel margin instead of in f64 with 0.01 px: it may hold a few more pixels,
// whose exact per-pixel tests then fail, so no image changes.
//
// Saved for the backward: the splat record (common.wgsl's layout) and the box.

@group(0) @binding(0) var<uniform> P: Params;
@group(0) @binding(1) var<storage, read> pos: array<f32>;
@group(0) @binding(2) var<storage, read> rot: array<f32>;
@group(0) @binding(3) var<storage, read> lsc: array<f32>;
@group(0) @binding(4) var<storage, read> opa: array<f32>;
@group(0) @binding(5) var<storage, read> sh: array<f32>;
@group(0) @binding(6) var<storage, read_write> splat: array<f32>;
@group(0) @binding(7) var<storage, read_write> rect: array<u32>;
// Per Gaussian: tiles touched, and the depth key (f32 bits; 0xffffffff when culled) with its id.
@group(0) @binding(8) var<storage, read_write> tiles_n: array<u32>;
@group(0) @binding(9) var<storage, read_write> key: array<u32>;
@group(0) @binding(10) var<storage, read_write> val: array<u32>;

fn cull(i: u32) {
    for (var k = 0u; k < SPLAT; k++) {
        splat[i * SPLAT + k] = 0.0;
    }
    for (var k = 0u; k < 4u; k++) {
        rect[i * 4u + k] = 0u;
    }
    tiles_n[i] = 0u;
    key[i] = 0xffffffffu;
    val[i] = i;
}

// The opacity-aware cut (svgir_raster::splat::rho_limit).
fn rho_limit(o: f32) -> f32 {
    if o >= 0.3496 {
        return 9.0;
    }
    return min(2.0 * log(255.0 * o) + 0.02, 9.0);
}

// Centre and half extents (px, ex, py, ey) of the projected ellipse u^2 + v^2 <= cut2, or a
// negative ex when it crosses the camera plane (2DGS's compute_aabb).
fn conic_extent(tu: vec3<f32>, tv: vec3<f32>, tw: vec3<f32>, cut2: f32) -> vec4<f32> {
    let d = cut2 * (tw.x * tw.x + tw.y * tw.y) - tw.z * tw.z;
    if !(d < 0.0) {
        return vec4<f32>(0.0, -1.0, 0.0, -1.0);
    }
    let qut = cut2 * (tu.x * tw.x + tu.y * tw.y) - tu.z * tw.z;
    let qvt = cut2 * (tv.x * tw.x + tv.y * tw.y) - tv.z * tw.z;
    let quu = cut2 * (tu.x * tu.x + tu.y * tu.y) - tu.z * tu.z;
    let qvv = cut2 * (tv.x * tv.x + tv.y * tv.y) - tv.z * tv.z;
    let px = qut / d;
    let py = qvt / d;
    let ex = sqrt(max(px * px - quu / d, 1e-4));
    let ey = sqrt(max(py * py - qvv / d, 1e-4));
    return vec4<f32>(px, ex, py, ey);
}

@compute @workgroup_size(256)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let i = gid.x;
    if i >= P.n {
        return;
    }
    let p = vec3<f32>(pos[i * 3u], pos[i * 3u + 1u], pos[i * 3u + 2u]);
    let q = vec4<f32>(rot[i * 4u], rot[i * 4u + 1u], rot[i * 4u + 2u], rot[i * 4u + 3u]);
    let qlen = sqrt(dot(q.xyz, q.xyz) + q.w * q.w);
    if !(qlen > 0.0) {
        cull(i);
        return;
    }
    let rows = quat_rows(q);
    let su = exp(lsc[i * 2u]);
    let sv = exp(lsc[i * 2u + 1u]);
    let a0 = cam_rot(P, p) + P.t.xyz;
    let near = P.clip.x;
    if !(a0.z >= near) {
        cull(i);
        return;
    }
    let tu = rot_col(rows, 0u);
    let tv = rot_col(rows, 1u);
    let nrm = rot_col(rows, 2u);
    let au = cam_rot(P, tu * su);
    let av = cam_rot(P, tv * sv);
    let fx = P.k.x;
    let fy = P.k.y;
    let cx = P.k.z;
    let cy = P.k.w;
    let hu = vec3<f32>(fx * au.x + cx * au.z, fx * av.x + cx * av.z, fx * a0.x + cx * a0.z);
    let hv = vec3<f32>(fy * au.y + cy * au.z, fy * av.y + cy * av.z, fy * a0.y + cy * a0.z);
    let hw = vec3<f32>(au.z, av.z, a0.z);
    let center = vec2<f32>(hu.z / hw.z, hv.z / hw.z);
    let cosv = dot(P.center.xyz - p, nrm);
    if !(abs(cosv) > 0.0) {
        cull(i);
        return;
    }
    let flip = select(-1.0, 1.0, cosv > 0.0);
    let o = 1.0 / (1.0 + exp(-opa[i]));
    let rho_max = rho_limit(o);
    if !(rho_max > 0.0) {
        cull(i);
        return;
    }
    // Screen box: the ellipse's box joined with the filter disk's (preprocess.rs, screen_box).
    let rf = sqrt(0.5 * rho_max) + 1e-4;
    let ext = conic_extent(hu, hv, hw, rho_max);
    let m = 0.5;
    var x0f: f32;
    var x1f: f32;
    var y0f: f32;
    var y1f: f32;
    if ext.y >= 0.0 {
        x0f = min(ext.x - ext.y, center.x - rf) - m;
        x1f = max(ext.x + ext.y, center.x + rf) + m;
        y0f = min(ext.z - ext.w, center.y - rf) - m;
        y1f = max(ext.z + ext.w, center.y + rf) + m;
    } else {
        x0f = -1e30;
        x1f = 1e30;
        y0f = -1e30;
        y1f = 1e30;
    }
    let e3 = conic_extent(hu, hv, hw, 9.0);
    var radius = f32(max(P.width, P.height));
    if e3.y >= 0.0 {
        radius = ceil(max(max(e3.y, e3.w), 3.0 * 0.70710678));
    }
    let fw = f32(P.width);
    let fh = f32(P.height);
    let rx0 = u32(clamp(ceil(x0f - 0.5), 0.0, fw));
    let rx1 = u32(clamp(floor(x1f - 0.5) + 1.0, 0.0, fw));
    let ry0 = u32(clamp(ceil(y0f - 0.5), 0.0, fh));
    let ry1 = u32(clamp(floor(y1f - 0.5) + 1.0, 0.0, fh));
    let finite = abs(center.x) < 1e30 && abs(center.y) < 1e30 && abs(hw.z) < 1e30;
    if !(rx0 < rx1 && ry0 < ry1 && finite) {
        cull(i);
        return;
    }
    // SH colour max(0, 0.5 + SH(normalize(p - cam))) (3DGS).
    let dir = p - P.center.xyz;
    let d = dir / sqrt(dot(dir, dir));
    var b: array<f32, 16>;
    let deg = min(P.sh_degree, 3u);
    sh_basis(deg, d, &b);
    var c = vec3<f32>(0.5);
    let nc = (deg + 1u) * (deg + 1u);
    for (var k = 0u; k < nc; k++) {
        let base = i * 48u + k * 3u;
        c += b[k] * vec3<f32>(sh[base], sh[base + 1u], sh[base + 2u]);
    }
    var clamped = 0u;
    if c.x < 0.0 { clamped |= 1u; c.x = 0.0; }
    if c.y < 0.0 { clamped |= 2u; c.y = 0.0; }
    if c.z < 0.0 { clamped |= 4u; c.z = 0.0; }

    let s = i * SPLAT;
    splat[s + 0u] = hu.x; splat[s + 1u] = hu.y; splat[s + 2u] = hu.z;
    splat[s + 3u] = hv.x; splat[s + 4u] = hv.y; splat[s + 5u] = hv.z;
    splat[s + 6u] = hw.x; splat[s + 7u] = hw.y; splat[s + 8u] = hw.z;
    splat[s + S_CENTER] = center.x;
    splat[s + S_CENTER + 1u] = center.y;
    splat[s + S_OPACITY] = o;
    splat[s + S_DEPTH] = a0.z;
    splat[s + S_NORMAL] = nrm.x * flip;
    splat[s + S_NORMAL + 1u] = nrm.y * flip;
    splat[s + S_NORMAL + 2u] = nrm.z * flip;
    splat[s + S_FLIP] = flip;
    splat[s + S_SCALE] = su;
    splat[s + S_SCALE + 1u] = sv;
    splat[s + S_COLOR] = c.x;
    splat[s + S_COLOR + 1u] = c.y;
    splat[s + S_COLOR + 2u] = c.z;
    splat[s + S_CLAMPED] = f32(clamped);
    splat[s + S_RADIUS] = radius;
    rect[i * 4u] = rx0;
    rect[i * 4u + 1u] = rx1;
    rect[i * 4u + 2u] = ry0;
    rect[i * 4u + 3u] = ry1;
    let tx0 = rx0 / TILE;
    let tx1 = (rx1 - 1u) / TILE + 1u;
    let ty0 = ry0 / TILE;
    let ty1 = (ry1 - 1u) / TILE + 1u;
    tiles_n[i] = (tx1 - tx0) * (ty1 - ty0);
    key[i] = bitcast<u32>(max(a0.z, 0.0));
    val[i] = i;
}
