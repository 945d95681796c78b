// svgir viewer: the light's maths (crates/svgir-view/src/light.rs in JavaScript): texel
// directions and solid angles of SPEC 4's grid, the SH basis of svgir-core, the SH projection of a
// rotated map and the GGX-prefiltered chain. A change here needs the same change there.
'use strict';
const SvgirLight = (function () {
  const LEVELS = 6, LEVEL_R0 = 0.09, LEVEL_STEP = 0.18;
  const SH_C0 = 0.2820948, SH_C1 = 0.48860252;
  const SH_C2 = [1.0925485, -1.0925485, 0.31539157, -1.0925485, 0.54627424];
  const SH_C3 = [-0.5900436, 2.8906114, -0.4570458, 0.37317634, -0.4570458, 1.4453057, -0.5900436];
  function texelDir(w, h, row, col) {
    const gx = -1 + 2 * col / Math.max(w - 1, 1), gy = -1 + 2 * row / Math.max(h - 1, 1);
    const theta = -gx * Math.PI, phi = 0.5 * Math.PI * (gy + 1);
    return [Math.sin(phi) * Math.cos(theta), Math.sin(phi) * Math.sin(theta), Math.cos(phi)];
  }
  function texelSolidAngle(w, h, row, col) {
    w = Math.max(w, 2); const hh = Math.max(h, 2);
    const dphi = Math.PI / (hh - 1);
    const rows = (row === 0 || row + 1 >= h) ? 1 - Math.sin(dphi) / dphi : Math.sin(row * dphi) * 2 * (1 - Math.cos(dphi)) / dphi;
    const dtheta = 2 * Math.PI / (w - 1);
    const cols = (col === 0 || col + 1 >= w) ? 0.5 * dtheta : dtheta;
    return rows * cols;
  }
  function shBasis(DEG, d, out) {
    const x = d[0], y = d[1], z = d[2];
    out[0] = SH_C0;
    if (DEG < 1) return;
    out[1] = -SH_C1 * y; out[2] = SH_C1 * z; out[3] = -SH_C1 * x;
    if (DEG < 2) return;
    const xx = x * x, yy = y * y, zz = z * z, xy = x * y, yz = y * z, xz = x * z;
    out[4] = SH_C2[0] * xy; out[5] = SH_C2[1] * yz; out[6] = SH_C2[2] * (2 * zz - xx - yy);
    out[7] = SH_C2[3] * xz; out[8] = SH_C2[4] * (xx - yy);
    if (DEG < 3) return;
    out[9] = SH_C3[0] * y * (3 * xx - yy); out[10] = SH_C3[1] * xy * z;
    out[11] = SH_C3[2] * y * (4 * zz - xx - yy); out[12] = SH_C3[3] * z * (2 * zz - 3 * xx - 3 * yy);
    out[13] = SH_C3[4] * x * (4 * zz - xx - yy); out[14] = SH_C3[5] * z * (xx - yy);
    out[15] = SH_C3[6] * x * (xx - 3 * yy);
  }
  // light.rs project_sh: the map rotated by `angle` about +Z, scaled by `strength`.
  function projectSH(l, DEG, angle, strength) {
    const C = (DEG + 1) * (DEG + 1);
    const acc = new Float64Array(16 * 3), b = new Float64Array(16);
    const s = Math.sin(angle), c = Math.cos(angle);
    for (let r = 0; r < l.height; r++) {
      for (let col = 0; col < l.width; col++) {
        const d = texelDir(l.width, l.height, r, col);
        shBasis(DEG, [c * d[0] - s * d[1], s * d[0] + c * d[1], d[2]], b);
        const w = texelSolidAngle(l.width, l.height, r, col);
        const t = 3 * (r * l.width + col);
        for (let j = 0; j < C; j++) for (let ch = 0; ch < 3; ch++) acc[3 * j + ch] += w * b[j] * l.data[t + ch];
      }
    }
    const out = new Float32Array(16 * 3);
    for (let k = 0; k < 3 * C; k++) out[k] = acc[k] * strength;
    return out;
  }
  function ggxD(nh, r) {
    const a2 = (r * r) * (r * r), t = nh * nh * (a2 - 1) + 1;
    return a2 / (Math.PI * t * t);
  }
  // light.rs prefilter: level 0 the map, levels 1..5 GGX-convolved with n = v = R.
  function prefilter(l) {
    const w = l.width, h = l.height, T = w * h;
    const dirs = [], omega = new Float64Array(T);
    for (let r = 0; r < h; r++) for (let c = 0; c < w; c++) { dirs.push(texelDir(w, h, r, c)); omega[r * w + c] = texelSolidAngle(w, h, r, c); }
    const out = new Float32Array(LEVELS * T * 4);
    for (let t = 0; t < T; t++) for (let ch = 0; ch < 3; ch++) out[4 * t + ch] = l.data[3 * t + ch];
    for (let level = 1; level < LEVELS; level++) {
      const rough = LEVEL_R0 + level * LEVEL_STEP;
      for (let o = 0; o < T; o++) {
        const R = dirs[o];
        let a0 = 0, a1 = 0, a2 = 0, ws = 0;
        for (let t = 0; t < T; t++) {
          const d = dirs[t];
          const nl = R[0] * d[0] + R[1] * d[1] + R[2] * d[2];
          if (nl <= 0) continue;
          const hx = R[0] + d[0], hy = R[1] + d[1], hz = R[2] + d[2];
          const hl = Math.hypot(hx, hy, hz);
          const nh = (R[0] * hx + R[1] * hy + R[2] * hz) / hl;
          const wt = ggxD(nh, rough) * nl * omega[t];
          a0 += wt * l.data[3 * t]; a1 += wt * l.data[3 * t + 1]; a2 += wt * l.data[3 * t + 2]; ws += wt;
        }
        const q = 4 * (level * T + o);
        if (ws > 0) { out[q] = a0 / ws; out[q + 1] = a1 / ws; out[q + 2] = a2 / ws; }
      }
    }
    return out;
  }

  return { LEVELS, LEVEL_R0, LEVEL_STEP, projectSH, prefilter };
})();
