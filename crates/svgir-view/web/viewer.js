// svgir relighting viewer: WebGL2 splatting of Gaussian surfels relit by precomputed radiance
// transfer. The maths mirror crates/svgir-view/src (light.rs, shade.rs, oracle.rs) line for
// line; a change here needs the same change there (the screenshot test compares the two).
'use strict';
(function () {
  const { LEVELS, LEVEL_R0, LEVEL_STEP, projectSH: projectLight, prefilter } = SvgirLight;
  const { parseHdr, fromEquirect } = SvgirHdr;
  const NEAR = 0.2, TEXW = 2048;
  const MODES = ['rgb', 'albedo', 'roughness', 'normal', 'visibility'];
  const $ = (id) => document.getElementById(id);
  const msgEl = $('msg');
  window.READY = false;
  window.VIEWER_ERROR = null;

  function showError(text) {
    msgEl.textContent = text;
    msgEl.className = 'error';
    window.VIEWER_ERROR = text;
  }
  let infoTimer = null;
  function showInfo(text) {
    if (location.hash.includes('ui=0')) return;
    msgEl.textContent = text;
    msgEl.className = 'info';
    clearTimeout(infoTimer);
    infoTimer = setTimeout(() => { if (msgEl.className === 'info') msgEl.className = 'hidden'; }, 4000);
  }

  // ---- data -----------------------------------------------------------------------------------
  let meta, buf;
  // IEEE half -> float (page.rs writes materials and transfer as f16).
  const HALF = new Float32Array(65536);
  for (let h = 0; h < 65536; h++) {
    const e = (h >> 10) & 31, m = h & 1023, s = (h & 0x8000) ? -1 : 1;
    HALF[h] = e === 0 ? s * m * Math.pow(2, -24) : e === 31 ? (m ? NaN : s * Infinity) : s * (1 + m / 1024) * Math.pow(2, e - 15);
  }
  const halves = (byteOffset, count) => {
    const u = new Uint16Array(buf, byteOffset, count), out = new Float32Array(count);
    for (let k = 0; k < count; k++) out[k] = HALF[u[k]];
    return out;
  };
  try {
    meta = JSON.parse($('svgir-meta').textContent);
    const bin = atob($('svgir-data').textContent.trim());
    const bytes = new Uint8Array(bin.length);
    for (let i = 0; i < bin.length; i++) bytes[i] = bin.charCodeAt(i);
    buf = bytes.buffer;
  } catch (e) {
    showError('This viewer page is damaged (its embedded model cannot be read): ' + e.message);
    return;
  }
  if (!meta.n || !meta.lights || !meta.lights.length) {
    showError('This viewer page holds no model (0 surfels or no light).');
    return;
  }
  $('title').textContent = meta.title || 'svgir viewer';
  const N = meta.n, C = meta.coeffs, DEG = meta.degree, M = meta.vertices, CH = meta.channels || 1;
  const SIDES = meta.twoSided ? 2 : 1;
  const geom = new Float32Array(buf, meta.offsets.geom, N * 16);

  // ---- state (URL hash overrides: yaw, pitch, dist in degrees/units; light, rot, strength,
  // mode, w, h, ui=0, bg) -------------------------------------------------------------------------
  const hp = new URLSearchParams(location.hash.slice(1));
  const num = (k, d) => (hp.has(k) && isFinite(Number(hp.get(k))) ? Number(hp.get(k)) : d);
  const cam0 = meta.camera;
  const state = {
    target: cam0.target.slice(),
    yaw: num('yaw', cam0.yaw * 180 / Math.PI) * Math.PI / 180,
    pitch: num('pitch', cam0.pitch * 180 / Math.PI) * Math.PI / 180,
    dist: num('dist', cam0.dist),
    fovY: cam0.fovY,
    light: 0,
    rot: num('rot', 0),
    strengthScale: 1,
    strengthOverride: hp.has('strength') ? num('strength', 1) : null,
    mode: MODES.indexOf(hp.get('mode') || 'rgb'),
    bg: num('bg', 0),
  };
  if (state.mode < 0) state.mode = 0;
  if (hp.has('light')) {
    const i = meta.lights.findIndex((l) => l.name === hp.get('light'));
    if (i < 0) showError('Unknown light "' + hp.get('light') + '" in the page address.');
    else state.light = i;
  }
  const fixedSize = hp.has('w') && hp.has('h') ? [num('w', 512) | 0, num('h', 512) | 0] : null;
  if (hp.get('ui') === '0') $('panel').className = 'hidden';

  // ---- lights ---------------------------------------------------------------------------------
  // Each light: {name, strength, width, height, data: Float32Array(w*h*3), chain (lazy)}.
  const lights = meta.lights.map((l) => ({
    name: l.name, strength: l.strength, width: l.width, height: l.height,
    data: new Float32Array(buf, l.offset, l.width * l.height * 3), chain: null,
  }));
  const LIGHT_H = lights[0].height, LIGHT_W = lights[0].width;

  // ---- WebGL2 ---------------------------------------------------------------------------------
  const canvas = $('c');
  const gl = canvas.getContext('webgl2', { antialias: false, alpha: false, depth: false, preserveDrawingBuffer: true });
  if (!gl) {
    showError('This browser cannot run the viewer: WebGL2 is not available (enable hardware acceleration, or use a current Chrome, Firefox or Safari).');
    return;
  }
  const extFloat = gl.getExtension('EXT_color_buffer_float');
  const extBlend = gl.getExtension('EXT_float_blend');
  const accumFormat = extFloat && extBlend ? 'RGBA32F' : extFloat ? 'RGBA16F' : 'RGBA8';

  const VS = `#version 300 es
precision highp float; precision highp int; precision highp sampler2D;
uniform sampler2D uGeom, uMat, uTr, uEnv; uniform highp usampler2D uOrder;
uniform mat3 uR; uniform vec3 uT; uniform vec4 uK; uniform vec2 uSize; uniform vec3 uEye;
uniform vec3 uSH[16]; uniform int uCP4; uniform int uChannels; uniform int uN; uniform int uTwoSided; uniform int uLayered; uniform int uMode; uniform float uAngle, uStrength; uniform ivec2 uEnvSize;
flat out vec3 vPc, vTu, vTv, vNc, vC0, vC1, vC2, vC3; flat out vec3 vS; flat out vec2 vCentre;
const float PI = 3.14159265358979;
vec4 fetch(sampler2D t, int i) { return texelFetch(t, ivec2(i % ${TEXW}, i / ${TEXW}), 0); }
vec3 envLevel(int level, vec3 d) {
  d = normalize(d);
  float phi = acos(clamp(d.z, -1.0, 1.0)); float theta = atan(d.y, d.x);
  float gx = -theta / PI, gy = 2.0 * phi / PI - 1.0;
  float W1 = float(uEnvSize.x - 1), H1 = float(uEnvSize.y - 1);
  float fx = clamp((gx + 1.0) * 0.5 * W1, 0.0, W1), fy = clamp((gy + 1.0) * 0.5 * H1, 0.0, H1);
  int x0 = int(fx), y0 = int(fy);
  int x1 = min(x0 + 1, uEnvSize.x - 1), y1 = min(y0 + 1, uEnvSize.y - 1);
  float tx = fx - float(x0), ty = fy - float(y0);
  int base = level * uEnvSize.y;
  vec3 a = texelFetch(uEnv, ivec2(x0, base + y0), 0).rgb, b = texelFetch(uEnv, ivec2(x1, base + y0), 0).rgb;
  vec3 c = texelFetch(uEnv, ivec2(x0, base + y1), 0).rgb, e = texelFetch(uEnv, ivec2(x1, base + y1), 0).rgb;
  return (1.0 - tx) * (1.0 - ty) * a + tx * (1.0 - ty) * b + (1.0 - tx) * ty * c + tx * ty * e;
}
vec3 prefiltered(vec3 r, float rough) {
  float s = sin(-uAngle), c = cos(-uAngle);
  vec3 d = vec3(c * r.x - s * r.y, s * r.x + c * r.y, r.z);
  float lv = clamp((rough - ${LEVEL_R0}) / ${LEVEL_STEP}, 0.0, ${LEVELS - 1}.0);
  int l0 = int(floor(lv)); int l1 = min(l0 + 1, ${LEVELS - 1});
  float t = lv - float(l0);
  vec3 a = envLevel(l0, d), b = envLevel(l1, d);
  return a + (b - a) * t;
}
vec2 envBrdf(float rough, float nv) {
  vec4 r = rough * vec4(-1.0, -0.0275, -0.572, 0.022) + vec4(1.0, 0.0425, 1.04, -0.04);
  float a004 = min(r.x * r.x, exp2(-9.28 * nv)) * r.x + r.y;
  return vec2(-1.04 * a004 + r.z, 1.04 * a004 + r.w);
}
vec3 shadeVertex(int q, vec3 v, bool back) {
  vec4 m0 = fetch(uMat, 3 * q), m1 = fetch(uMat, 3 * q + 1), m2 = fetch(uMat, 3 * q + 2);
  vec3 albedo = m0.rgb; float rough = m0.a;
  vec3 n = back ? -m1.xyz : m1.xyz; float vis = back ? m2.x : m1.w;
  int tq = back ? uN * 4 + q : q;
  if (uMode == 1) return albedo;
  if (uMode == 2) return vec3(rough);
  if (uMode == 3) return 0.5 + 0.5 * n;
  if (uMode == 4) return vec3(vis);
  vec3 irr = vec3(0.0);
  if (uChannels == 1) {
    for (int k = 0; k < 4; k++) {
      if (k >= uCP4) break;
      vec4 t = fetch(uTr, tq * uCP4 + k);
      irr += uSH[4 * k] * t.x + uSH[4 * k + 1] * t.y + uSH[4 * k + 2] * t.z + uSH[4 * k + 3] * t.w;
    }
  } else {
    // One transfer vector per colour channel (the one-bounce term is coloured).
    for (int k = 0; k < 4; k++) {
      if (k >= uCP4) break;
      vec4 tr = fetch(uTr, (3 * tq) * uCP4 + k), tg = fetch(uTr, (3 * tq + 1) * uCP4 + k), tb = fetch(uTr, (3 * tq + 2) * uCP4 + k);
      vec3 a = uSH[4 * k], b = uSH[4 * k + 1], c = uSH[4 * k + 2], d = uSH[4 * k + 3];
      irr += vec3(a.r * tr.x + b.r * tr.y + c.r * tr.z + d.r * tr.w,
                  a.g * tg.x + b.g * tg.y + c.g * tg.z + d.g * tg.w,
                  a.b * tb.x + b.b * tb.y + c.b * tb.z + d.b * tb.w);
    }
  }
  float nvRaw = dot(n, v);
  float nv = clamp(nvRaw, 1e-6, 1.0);
  vec3 r = 2.0 * nvRaw * n - v;
  vec3 pre = prefiltered(r, rough);
  vec2 ab = envBrdf(rough, nv);
  float e = 0.04 * ab.x + ab.y;
  float kd = uLayered == 1 ? 1.0 - e : 1.0;
  float spec = e * vis * uStrength;
  return kd * albedo / PI * max(irr, vec3(0.0)) + pre * spec;
}
void main() {
  // Vertex 4 s + c is corner c of the splat in sorted slot s; the order texture maps slots to
  // surfel ids (back to front).
  int slot = gl_VertexID >> 2, cornerId = gl_VertexID & 3;
  int i = int(texelFetch(uOrder, ivec2(slot % ${TEXW}, slot / ${TEXW}), 0).r);
  vec4 g0 = fetch(uGeom, 4 * i), g1 = fetch(uGeom, 4 * i + 1), g2 = fetch(uGeom, 4 * i + 2), g3 = fetch(uGeom, 4 * i + 3);
  vec3 pc = uR * g0.xyz + uT;
  vec3 tu = uR * g1.xyz, tv = uR * g2.xyz, nc = uR * g3.xyz;
  float su = g1.w, sv = g2.w;
  gl_Position = vec4(2.0, 2.0, 2.0, 1.0);
  if (pc.z <= ${NEAR}) return;
  vec2 centre = vec2(uK.x * pc.x / pc.z + uK.z, uK.y * pc.y / pc.z + uK.w);
  vec2 pk[4];
  for (int k = 0; k < 4; k++) {
    float a = (k & 1) == 0 ? -3.0 : 3.0, b = (k & 2) == 0 ? -3.0 : 3.0;
    vec3 q = pc + (a * su) * tu + (b * sv) * tv;
    if (q.z <= ${NEAR}) return;
    pk[k] = vec2(uK.x * q.x / q.z + uK.z, uK.y * q.y / q.z + uK.w) - centre;
  }
  // The footprint: a rectangle along the projected square's longer side holding its four
  // corners (so the whole 3-sigma square, where rho3 <= 9) and the 3-pixel disk of the
  // low-pass filter (rho2 <= 9), plus a pixel. Every pixel left out has rho > 9, so this draws
  // the same pixels as the oracle's axis-aligned box, with up to several times fewer
  // fragments for thin or tilted splats.
  vec2 ea = pk[1] - pk[0], eb = pk[2] - pk[0];
  vec2 e1 = dot(ea, ea) >= dot(eb, eb) ? ea : eb;
  e1 = dot(e1, e1) > 1e-12 ? normalize(e1) : vec2(1.0, 0.0);
  vec2 e2 = vec2(-e1.y, e1.x);
  vec2 lo = vec2(-3.0), hi = vec2(3.0);
  for (int k = 0; k < 4; k++) {
    vec2 st = vec2(dot(pk[k], e1), dot(pk[k], e2));
    lo = min(lo, st); hi = max(hi, st);
  }
  lo -= 1.0; hi += 1.0;
  vec2 st = vec2((cornerId & 1) == 0 ? lo.x : hi.x, (cornerId & 2) == 0 ? lo.y : hi.y);
  vec2 corner = centre + st.x * e1 + st.y * e2;
  gl_Position = vec4(2.0 * corner.x / uSize.x - 1.0, 1.0 - 2.0 * corner.y / uSize.y, 0.0, 1.0);
  vPc = pc; vTu = tu; vTv = tv; vNc = nc; vS = vec3(su, sv, g0.w); vCentre = centre;
  // Flat outputs come from each triangle's provoking (last) vertex: both triangles of a splat
  // end with corner 3, so only it shades.
  if (cornerId != 3) { vC0 = vC1 = vC2 = vC3 = vec3(0.0); return; }
  bool back = uTwoSided == 1 && dot(g3.xyz, uEye - g0.xyz) < 0.0;
  vec3 view = normalize(uEye - g0.xyz);
  vC0 = shadeVertex(4 * i, view, back); vC1 = shadeVertex(4 * i + 1, view, back);
  vC2 = shadeVertex(4 * i + 2, view, back); vC3 = shadeVertex(4 * i + 3, view, back);
}`;
  const FS = `#version 300 es
precision highp float;
uniform vec4 uK; uniform vec2 uSize;
flat in vec3 vPc, vTu, vTv, vNc, vC0, vC1, vC2, vC3; flat in vec3 vS; flat in vec2 vCentre;
out vec4 outColor;
void main() {
  float x = gl_FragCoord.x, y = uSize.y - gl_FragCoord.y;
  vec3 d = vec3((x - uK.z) / uK.x, (y - uK.w) / uK.y, 1.0);
  float denom = dot(vNc, d);
  if (abs(denom) < 1e-10) discard;
  float t = dot(vNc, vPc) / denom;
  if (t < ${NEAR}) discard;
  vec3 dv = d * t - vPc;
  float u = dot(vTu, dv) / vS.x, v = dot(vTv, dv) / vS.y;
  float rho3 = u * u + v * v;
  vec2 dd = vCentre - vec2(x, y);
  float rho2 = 2.0 * (dd.x * dd.x + dd.y * dd.y);
  float rho = min(rho3, rho2);
  if (rho > 9.0) discard;
  float alpha = min(0.99, vS.z * exp(-0.5 * rho));
  if (alpha < 1.0 / 255.0) discard;
  float uu = clamp(0.5 + 0.5 * u, 0.001, 0.999), vv = clamp(0.5 + 0.5 * v, 0.001, 0.999);
  vec3 c = (1.0 - uu) * (1.0 - vv) * vC0 + uu * (1.0 - vv) * vC1 + (1.0 - uu) * vv * vC2 + uu * vv * vC3;
  outColor = vec4(c * alpha, alpha);
}`;
  const VS_FULL = `#version 300 es
void main() { vec2 p = vec2((gl_VertexID & 1) == 0 ? -1.0 : 3.0, (gl_VertexID & 2) == 0 ? -1.0 : 3.0); gl_Position = vec4(p, 0.0, 1.0); }`;
  const FS_FULL = `#version 300 es
precision highp float;
uniform sampler2D uAccum; uniform int uSrgb; uniform vec3 uBg;
out vec4 outColor;
float srgb(float c) { c = max(c, 0.0); return c <= 0.0031308 ? 12.92 * c : 1.055 * pow(c, 1.0 / 2.4) - 0.055; }
void main() {
  vec4 a = texelFetch(uAccum, ivec2(gl_FragCoord.xy), 0);
  float cover = a.a;
  vec3 lin = a.rgb / max(cover, 1e-5);
  vec3 enc = uSrgb == 1 ? vec3(srgb(lin.r), srgb(lin.g), srgb(lin.b)) : lin;
  outColor = vec4(clamp(enc * cover + uBg * (1.0 - cover), 0.0, 1.0), 1.0);
}`;

  function program(vs, fs) {
    const p = gl.createProgram();
    for (const [type, src] of [[gl.VERTEX_SHADER, vs], [gl.FRAGMENT_SHADER, fs]]) {
      const s = gl.createShader(type);
      gl.shaderSource(s, src);
      gl.compileShader(s);
      if (!gl.getShaderParameter(s, gl.COMPILE_STATUS)) throw new Error('shader: ' + gl.getShaderInfoLog(s));
      gl.attachShader(p, s);
    }
    gl.linkProgram(p);
    if (!gl.getProgramParameter(p, gl.LINK_STATUS)) throw new Error('link: ' + gl.getProgramInfoLog(p));
    const u = {};
    const count = gl.getProgramParameter(p, gl.ACTIVE_UNIFORMS);
    for (let k = 0; k < count; k++) {
      const name = gl.getActiveUniform(p, k).name.replace(/\[0\]$/, '');
      u[name] = gl.getUniformLocation(p, name);
    }
    return { p, u };
  }
  function floatTexture(data, texels, width) {
    width = width || Math.min(TEXW, texels);
    const height = Math.ceil(texels / width);
    const max = gl.getParameter(gl.MAX_TEXTURE_SIZE);
    if (height > max) throw new Error('the model needs a ' + width + 'x' + height + ' texture and this GPU allows ' + max + ' (write the page with fewer surfels, a lower --degree or without --bounce)');
    const padded = new Float32Array(width * height * 4);
    padded.set(data.subarray(0, Math.min(data.length, padded.length)));
    const t = gl.createTexture();
    gl.bindTexture(gl.TEXTURE_2D, t);
    gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MIN_FILTER, gl.NEAREST);
    gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MAG_FILTER, gl.NEAREST);
    gl.texImage2D(gl.TEXTURE_2D, 0, gl.RGBA32F, width, height, 0, gl.RGBA, gl.FLOAT, padded);
    return t;
  }

  let splat, full, texGeom, texMat, texTr, texEnv = null, vao, indexBuf, orderTex, orderPad;
  const CP4 = Math.ceil(C / 4);
  try {
    splat = program(VS, FS);
    full = program(VS_FULL, FS_FULL);
    texGeom = floatTexture(geom, N * 4, TEXW);
    texMat = floatTexture(halves(meta.offsets.mats, N * M * 12), N * M * 3, TEXW);
    // Transfer: C coefficients per vertex, padded to a multiple of 4 (one texel per 4).
    // With the one-bounce term, CH = 3 such vectors per vertex, channel-major.
    // A two-sided model's back-side vectors follow the front's.
    const t16 = halves(meta.offsets.transfer, SIDES * N * M * CH * C);
    const tr = new Float32Array(SIDES * N * M * CH * CP4 * 4);
    for (let q = 0; q < SIDES * N * M * CH; q++) for (let j = 0; j < C; j++) tr[q * CP4 * 4 + j] = t16[q * C + j];
    texTr = floatTexture(tr, SIDES * N * M * CH * CP4, TEXW);
    // Two triangles per splat, (0, 1, 3) and (0, 2, 3): corner 3 provokes both.
    vao = gl.createVertexArray();
    gl.bindVertexArray(vao);
    const idx = new Uint32Array(6 * N);
    for (let s = 0; s < N; s++) idx.set([4 * s, 4 * s + 1, 4 * s + 3, 4 * s, 4 * s + 2, 4 * s + 3], 6 * s);
    indexBuf = gl.createBuffer();
    gl.bindBuffer(gl.ELEMENT_ARRAY_BUFFER, indexBuf);
    gl.bufferData(gl.ELEMENT_ARRAY_BUFFER, idx, gl.STATIC_DRAW);
    orderTex = gl.createTexture();
    gl.bindTexture(gl.TEXTURE_2D, orderTex);
    gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MIN_FILTER, gl.NEAREST);
    gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MAG_FILTER, gl.NEAREST);
    gl.texStorage2D(gl.TEXTURE_2D, 1, gl.R32UI, TEXW, Math.ceil(N / TEXW));
    orderPad = new Uint32Array(TEXW * Math.ceil(N / TEXW));
  } catch (e) {
    showError('The viewer cannot start WebGL2 rendering: ' + e.message);
    return;
  }

  // Accumulation target (premultiplied colour + coverage, float).
  let fbo = null, accumTex = null, fbW = 0, fbH = 0;
  function ensureTarget(w, h) {
    if (w === fbW && h === fbH) return;
    if (accumTex) gl.deleteTexture(accumTex);
    if (fbo) gl.deleteFramebuffer(fbo);
    accumTex = gl.createTexture();
    gl.bindTexture(gl.TEXTURE_2D, accumTex);
    gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MIN_FILTER, gl.NEAREST);
    gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MAG_FILTER, gl.NEAREST);
    const fmt = { RGBA32F: [gl.RGBA32F, gl.FLOAT], RGBA16F: [gl.RGBA16F, gl.HALF_FLOAT], RGBA8: [gl.RGBA8, gl.UNSIGNED_BYTE] }[accumFormat];
    gl.texImage2D(gl.TEXTURE_2D, 0, fmt[0], w, h, 0, gl.RGBA, fmt[1], null);
    fbo = gl.createFramebuffer();
    gl.bindFramebuffer(gl.FRAMEBUFFER, fbo);
    gl.framebufferTexture2D(gl.FRAMEBUFFER, gl.COLOR_ATTACHMENT0, gl.TEXTURE_2D, accumTex, 0);
    if (gl.checkFramebufferStatus(gl.FRAMEBUFFER) !== gl.FRAMEBUFFER_COMPLETE) throw new Error('the ' + accumFormat + ' render target is not supported');
    gl.bindFramebuffer(gl.FRAMEBUFFER, null);
    fbW = w; fbH = h;
  }

  // ---- camera and sort (oracle.rs Orbit::view, sort_back_to_front) -----------------------------
  function orbitView(w, h) {
    const cp = Math.cos(state.pitch), sp = Math.sin(state.pitch), cy = Math.cos(state.yaw), sy = Math.sin(state.yaw);
    const t = state.target;
    const eye = [t[0] + state.dist * cp * cy, t[1] + state.dist * cp * sy, t[2] + state.dist * sp];
    const nrm = (a) => { const l = Math.sqrt(a[0] * a[0] + a[1] * a[1] + a[2] * a[2]); return [a[0] / l, a[1] / l, a[2] / l]; };
    const cross = (a, b) => [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]];
    const f = nrm([t[0] - eye[0], t[1] - eye[1], t[2] - eye[2]]);
    const right = nrm(cross(f, [0, 0, 1]));
    const down = cross(f, right);
    const rot = [right, down, f];
    const trans = [0, 1, 2].map((r) => -(rot[r][0] * eye[0] + rot[r][1] * eye[1] + rot[r][2] * eye[2]));
    const fy = 0.5 * h / Math.tan(0.5 * state.fovY);
    return { rot, trans, eye, fx: fy, fy, cx: 0.5 * w, cy: 0.5 * h, w, h };
  }
  const posF = new Float64Array(N * 3);
  for (let i = 0; i < N; i++) for (let k = 0; k < 3; k++) posF[3 * i + k] = geom[16 * i + k];
  const keys = new Uint32Array(N), keys2 = new Uint32Array(N), order = new Uint32Array(N), order2 = new Uint32Array(N);
  const f32 = new Float32Array(1), u32 = new Uint32Array(f32.buffer);
  const hist = new Uint32Array(256);
  // Back to front: view depth (f64, rounded to f32) descending, ties by id ascending, by a
  // stable LSD radix sort over keys that order as the reversed depth.
  function sortBackToFront(view) {
    const r = view.rot[2], tz = view.trans[2];
    for (let i = 0; i < N; i++) {
      f32[0] = r[0] * posF[3 * i] + r[1] * posF[3 * i + 1] + r[2] * posF[3 * i + 2] + tz;
      const b = u32[0];
      const asc = (b & 0x80000000) ? (~b >>> 0) : ((b | 0x80000000) >>> 0);
      keys[i] = (~asc) >>> 0;
      order[i] = i;
    }
    let src = order, dst = order2, ks = keys, kd = keys2;
    for (let shift = 0; shift < 32; shift += 8) {
      hist.fill(0);
      for (let i = 0; i < N; i++) hist[(ks[i] >>> shift) & 255]++;
      let sum = 0;
      for (let b = 0; b < 256; b++) { const c = hist[b]; hist[b] = sum; sum += c; }
      for (let i = 0; i < N; i++) {
        const d = hist[(ks[i] >>> shift) & 255]++;
        dst[d] = src[i]; kd[d] = ks[i];
      }
      [src, dst] = [dst, src]; [ks, kd] = [kd, ks];
    }
    return src;
  }

  // ---- light state ----------------------------------------------------------------------------
  let envLight = null; // the light the env texture holds
  function useLight() {
    const l = lights[state.light];
    if (!l.chain) l.chain = prefilter(l);
    if (envLight !== l) {
      if (texEnv) gl.deleteTexture(texEnv);
      texEnv = floatTexture(l.chain, l.width * l.height * LEVELS, l.width);
      envLight = l;
    }
    return l;
  }
  function strength() {
    const l = lights[state.light];
    return state.strengthOverride !== null ? state.strengthOverride : l.strength * state.strengthScale;
  }
  let shCache = { key: null, sh: null };
  function lightSH() {
    const l = lights[state.light], angle = state.rot * Math.PI / 180, s = strength();
    const key = state.light + ':' + angle + ':' + s;
    if (shCache.key !== key) shCache = { key, sh: projectLight(l, DEG, angle, s) };
    return shCache.sh;
  }

  // ---- frame ----------------------------------------------------------------------------------
  let lastSortMs = 0;
  function draw() {
    const w = fixedSize ? fixedSize[0] : Math.max(1, Math.floor(window.innerWidth));
    const h = fixedSize ? fixedSize[1] : Math.max(1, Math.floor(window.innerHeight));
    if (canvas.width !== w || canvas.height !== h) { canvas.width = w; canvas.height = h; }
    canvas.style.width = w + 'px'; canvas.style.height = h + 'px';
    ensureTarget(w, h);
    const l = useLight();
    const view = orbitView(w, h);
    const t0 = performance.now();
    const sorted = sortBackToFront(view);
    orderPad.set(sorted);
    gl.bindTexture(gl.TEXTURE_2D, orderTex);
    gl.texSubImage2D(gl.TEXTURE_2D, 0, 0, 0, TEXW, orderPad.length / TEXW, gl.RED_INTEGER, gl.UNSIGNED_INT, orderPad);
    lastSortMs = performance.now() - t0;

    gl.bindFramebuffer(gl.FRAMEBUFFER, fbo);
    gl.viewport(0, 0, w, h);
    gl.clearColor(0, 0, 0, 0);
    gl.clear(gl.COLOR_BUFFER_BIT);
    gl.enable(gl.BLEND);
    gl.blendFunc(gl.ONE, gl.ONE_MINUS_SRC_ALPHA);
    gl.useProgram(splat.p);
    const u = splat.u;
    const R = view.rot;
    // uR is column-major: column c holds R[.][c].
    gl.uniformMatrix3fv(u.uR, false, [R[0][0], R[1][0], R[2][0], R[0][1], R[1][1], R[2][1], R[0][2], R[1][2], R[2][2]]);
    gl.uniform3fv(u.uT, view.trans);
    gl.uniform4f(u.uK, view.fx, view.fy, view.cx, view.cy);
    gl.uniform2f(u.uSize, w, h);
    gl.uniform3fv(u.uEye, view.eye);
    gl.uniform3fv(u.uSH, lightSH());
    gl.uniform1i(u.uCP4, CP4);
    gl.uniform1i(u.uChannels, CH);
    gl.uniform1i(u.uN, N);
    gl.uniform1i(u.uTwoSided, SIDES === 2 ? 1 : 0);
    gl.uniform1i(u.uLayered, meta.layered ? 1 : 0);
    gl.uniform1i(u.uMode, state.mode);
    gl.uniform1f(u.uAngle, state.rot * Math.PI / 180);
    gl.uniform1f(u.uStrength, strength());
    gl.uniform2i(u.uEnvSize, l.width, l.height);
    [[texGeom, 'uGeom'], [texMat, 'uMat'], [texTr, 'uTr'], [texEnv, 'uEnv'], [orderTex, 'uOrder']].forEach(([t, name], k) => {
      gl.activeTexture(gl.TEXTURE0 + k);
      gl.bindTexture(gl.TEXTURE_2D, t);
      gl.uniform1i(u[name], k);
    });
    gl.bindVertexArray(vao);
    gl.drawElements(gl.TRIANGLES, 6 * N, gl.UNSIGNED_INT, 0);
    gl.disable(gl.BLEND);

    gl.bindFramebuffer(gl.FRAMEBUFFER, null);
    gl.viewport(0, 0, w, h);
    gl.useProgram(full.p);
    gl.activeTexture(gl.TEXTURE0);
    gl.bindTexture(gl.TEXTURE_2D, accumTex);
    gl.uniform1i(full.u.uAccum, 0);
    gl.uniform1i(full.u.uSrgb, state.mode <= 1 ? 1 : 0);
    gl.uniform3f(full.u.uBg, state.bg, state.bg, state.bg);
    gl.drawArrays(gl.TRIANGLES, 0, 3);
  }

  let pending = false;
  function requestDraw() {
    if (pending) return;
    pending = true;
    requestAnimationFrame(() => {
      pending = false;
      try { draw(); } catch (e) { showError('Rendering failed: ' + e.message); }
    });
  }

  // ---- controls -------------------------------------------------------------------------------
  const sel = $('light');
  function fillLights() {
    sel.innerHTML = '';
    lights.forEach((l, i) => { const o = document.createElement('option'); o.value = i; o.textContent = l.name; sel.appendChild(o); });
    sel.value = state.light;
  }
  fillLights();
  sel.onchange = () => { state.light = Number(sel.value); state.strengthOverride = null; updateLabels(); requestDraw(); };
  $('rot').value = state.rot;
  $('rot').oninput = () => { state.rot = Number($('rot').value); updateLabels(); requestDraw(); };
  $('str').oninput = () => { state.strengthScale = Math.pow(2, Number($('str').value)); state.strengthOverride = null; updateLabels(); requestDraw(); };
  const modesEl = $('modes');
  MODES.forEach((m, i) => {
    const lab = document.createElement('label');
    lab.innerHTML = '<input type="radio" name="mode" value="' + i + '"> ' + m;
    lab.querySelector('input').checked = i === state.mode;
    lab.querySelector('input').onchange = () => { state.mode = i; requestDraw(); };
    modesEl.appendChild(lab);
  });
  // The light as a small lat-long picture (Reinhard tone map, sRGB), shifted by the rotation.
  const pv = $('preview'), pctx = pv.getContext('2d');
  function drawPreview() {
    const l = lights[state.light], s = strength();
    const img = pctx.createImageData(pv.width, pv.height);
    const shift = state.rot / 360;
    for (let y = 0; y < pv.height; y++) {
      const r = Math.min(l.height - 1, Math.round(y / (pv.height - 1) * (l.height - 1)));
      for (let x = 0; x < pv.width; x++) {
        // Column u of the file layout shows direction theta = pi (1 - 2u); rotating the light by
        // +a moves what was at theta - a to theta.
        let u = x / (pv.width - 1) + shift;
        u -= Math.floor(u);
        const c = Math.min(l.width - 1, Math.round(u * (l.width - 1)));
        for (let ch = 0; ch < 3; ch++) {
          const v = s * l.data[3 * (r * l.width + c) + ch];
          img.data[4 * (y * pv.width + x) + ch] = 255 * Math.pow(v / (1 + v), 1 / 2.2);
        }
        img.data[4 * (y * pv.width + x) + 3] = 255;
      }
    }
    pctx.putImageData(img, 0, 0);
  }
  function updateLabels() {
    $('rotv').textContent = String(state.rot);
    $('strv').textContent = strength().toPrecision(3);
    drawPreview();
  }
  updateLabels();
  const pageMB = (document.documentElement.outerHTML.length / 1e6).toFixed(1);
  function stats(extra) {
    $('stats').textContent = N + ' surfels, SH degree ' + DEG + ' (' + C + ' coefficients per vertex' + (CH === 3 ? ' and channel, with one bounce' : '') + '), ' +
      meta.bytesPerSurfel + ' bytes per surfel on the GPU (' + meta.fileBytesPerSurfel + ' in the file), page ' + pageMB + ' MB, blending in ' + accumFormat + '. ' + (extra || '');
  }
  stats();

  let drag = null;
  canvas.addEventListener('contextmenu', (e) => e.preventDefault());
  canvas.addEventListener('pointerdown', (e) => {
    drag = { x: e.clientX, y: e.clientY, pan: e.button === 2 || e.shiftKey };
    canvas.setPointerCapture(e.pointerId);
  });
  canvas.addEventListener('pointerup', () => { drag = null; });
  canvas.addEventListener('pointermove', (e) => {
    if (!drag) return;
    const dx = e.clientX - drag.x, dy = e.clientY - drag.y;
    drag.x = e.clientX; drag.y = e.clientY;
    if (drag.pan) {
      const v = orbitView(canvas.width, canvas.height);
      const s = state.dist / v.fy;
      for (let k = 0; k < 3; k++) state.target[k] -= s * (dx * v.rot[0][k] + dy * v.rot[1][k]);
    } else {
      state.yaw -= dx * 0.008;
      state.pitch = Math.max(-1.55, Math.min(1.55, state.pitch + dy * 0.008));
    }
    requestDraw();
  });
  canvas.addEventListener('wheel', (e) => {
    e.preventDefault();
    state.dist = Math.max(0.3, state.dist * Math.exp(e.deltaY * 0.001));
    requestDraw();
  }, { passive: false });
  window.addEventListener('resize', requestDraw);
  window.addEventListener('keydown', (e) => {
    if ((e.key === 'h' || e.key === 'H') && e.target.tagName !== 'INPUT' && e.target.tagName !== 'SELECT') {
      $('panel').classList.toggle('hidden');
    }
  });

  async function loadHdrFile(file) {
    try {
      const img = parseHdr(await file.arrayBuffer(), file.name);
      const data = fromEquirect(img, LIGHT_H);
      lights.push({ name: file.name, strength: 1, width: LIGHT_W, height: LIGHT_H, data, chain: null });
      state.light = lights.length - 1;
      state.strengthOverride = null;
      fillLights();
      updateLabels();
      msgEl.className = 'hidden';
      showInfo('Loaded ' + file.name + ' (' + img.width + 'x' + img.height + ').');
      requestDraw();
    } catch (e) {
      showError(file.name + ': cannot use this file as a light: ' + e.message + '. The viewer reads Radiance .hdr (RGBE) lat-long maps.');
    }
  }
  window.loadHdrBytes = (name, bytes) => loadHdrFile({ name, arrayBuffer: async () => bytes.buffer });
  $('file').onchange = (e) => { if (e.target.files[0]) loadHdrFile(e.target.files[0]); };
  const dropEl = $('drop');
  window.addEventListener('dragover', (e) => { e.preventDefault(); dropEl.style.display = 'block'; });
  window.addEventListener('dragleave', () => { dropEl.style.display = 'none'; });
  window.addEventListener('drop', (e) => {
    e.preventDefault();
    dropEl.style.display = 'none';
    if (e.dataTransfer.files[0]) loadHdrFile(e.dataTransfer.files[0]);
  });

  // Frame time: N frames, each with a new camera (so the sort runs), drawn and finished.
  window.measureFrames = (frames) => {
    const n = frames || 30;
    const yaw0 = state.yaw;
    let sortMs = 0;
    const t0 = performance.now();
    for (let k = 0; k < n; k++) {
      state.yaw = yaw0 + 0.01 * (k + 1);
      draw();
      sortMs += lastSortMs;
      const px = new Uint8Array(4);
      gl.readPixels(0, 0, 1, 1, gl.RGBA, gl.UNSIGNED_BYTE, px);
    }
    const ms = (performance.now() - t0) / n;
    state.yaw = yaw0;
    draw();
    stats('Frame ' + ms.toFixed(1) + ' ms (sort ' + (sortMs / n).toFixed(1) + ' ms).');
    return { frameMs: ms, sortMs: sortMs / n, surfels: N, width: canvas.width, height: canvas.height, accum: accumFormat };
  };

  // The same through requestAnimationFrame (as a user sees it; capped by the display's rate).
  window.measureRaf = (frames) => new Promise((resolve) => {
    const n = frames || 30, yaw0 = state.yaw;
    let k = 0, t0 = 0;
    const step = (t) => {
      if (k === 0) t0 = t;
      if (k === n) {
        state.yaw = yaw0;
        draw();
        resolve({ rafMs: (t - t0) / n });
        return;
      }
      k++;
      state.yaw = yaw0 + 0.01 * k;
      draw();
      requestAnimationFrame(step);
    };
    requestAnimationFrame(step);
  });
  $('reset').onclick = () => {
    Object.assign(state, { target: cam0.target.slice(), yaw: cam0.yaw, pitch: cam0.pitch, dist: cam0.dist });
    requestDraw();
  };

  try {
    draw();
    if (accumFormat !== 'RGBA32F') showInfo('This GPU blends in ' + accumFormat + ': colours may differ slightly from the reference renderer.');
    window.READY = true;
  } catch (e) {
    showError('Rendering failed: ' + e.message);
  }
})();
