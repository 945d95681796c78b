// svgir viewer: a Radiance .hdr (RGBE) reader and the area-correct resampling of a lat-long map
// to the model's light grid (svgir-core EnvMap::from_equirect in JavaScript), for dropped files.
'use strict';
const SvgirHdr = (function () {
  function parseHdr(buf, name) {
    const bytes = new Uint8Array(buf);
    let pos = 0;
    function line() {
      let s = '';
      while (pos < bytes.length && bytes[pos] !== 10) s += String.fromCharCode(bytes[pos++]);
      if (pos >= bytes.length) throw new Error('the header never ends');
      pos++;
      return s;
    }
    const magic = line();
    if (!magic.startsWith('#?')) throw new Error('not a Radiance .hdr file (no "#?" signature)');
    let fmt = null;
    for (let s = line(); s !== ''; s = line()) if (s.startsWith('FORMAT=')) fmt = s.slice(7).trim();
    if (fmt && fmt !== '32-bit_rle_rgbe') throw new Error('unsupported pixel format ' + fmt + ' (only 32-bit_rle_rgbe)');
    const m = /^-Y (\d+) \+X (\d+)$/.exec(line().trim());
    if (!m) throw new Error('unsupported orientation line (only "-Y H +X W")');
    const H = Number(m[1]), W = Number(m[2]);
    if (!(W > 0 && H > 0 && W * H <= 1 << 26)) throw new Error('bad size ' + W + 'x' + H);
    const rgbe = new Uint8Array(W * H * 4);
    const scan = new Uint8Array(W * 4);
    for (let y = 0; y < H; y++) {
      if (pos + 4 > bytes.length) throw new Error('the file ends at row ' + y + ' of ' + H);
      if (W >= 8 && W < 32768 && bytes[pos] === 2 && bytes[pos + 1] === 2 && (bytes[pos + 2] & 0x80) === 0) {
        if (((bytes[pos + 2] << 8) | bytes[pos + 3]) !== W) throw new Error('row ' + y + ': run-length width mismatch');
        pos += 4;
        for (let ch = 0; ch < 4; ch++) {
          for (let x = 0; x < W;) {
            if (pos >= bytes.length) throw new Error('the file ends inside row ' + y);
            let count = bytes[pos++];
            if (count > 128) {
              count -= 128;
              if (pos >= bytes.length) throw new Error('the file ends inside row ' + y);
              if (x + count > W) throw new Error('row ' + y + ': bad run length');
              const v = bytes[pos++];
              for (let k = 0; k < count; k++) scan[(x++) * 4 + ch] = v;
            } else {
              if (pos + count > bytes.length) throw new Error('the file ends inside row ' + y);
              if (count === 0 || x + count > W) throw new Error('row ' + y + ': bad run length');
              for (let k = 0; k < count; k++) scan[(x++) * 4 + ch] = bytes[pos++];
            }
          }
        }
        rgbe.set(scan, y * W * 4);
      } else {
        // Flat (uncompressed) scanline.
        if (pos + W * 4 > bytes.length) throw new Error('the file ends at row ' + y + ' of ' + H);
        rgbe.set(bytes.subarray(pos, pos + W * 4), y * W * 4);
        pos += W * 4;
      }
    }
    const rgb = new Float32Array(W * H * 3);
    for (let p = 0; p < W * H; p++) {
      const e = rgbe[4 * p + 3];
      const f = e === 0 ? 0 : Math.pow(2, e - 136);
      rgb[3 * p] = rgbe[4 * p] * f; rgb[3 * p + 1] = rgbe[4 * p + 1] * f; rgb[3 * p + 2] = rgbe[4 * p + 2] * f;
    }
    for (let k = 0; k < rgb.length; k++) if (!isFinite(rgb[k])) throw new Error('non-finite pixel values');
    return { width: W, height: H, rgb };
  }
  function overlapCells(a, b, n, wrap) {
    const out = [];
    let x = a;
    while (x < b - 1e-6) {
      const cell = Math.floor(x), end = Math.min(cell + 1, b);
      const idx = wrap ? (((cell % n) + n) % n) : Math.min(Math.max(cell, 0), n - 1);
      out.push([idx, x, end]);
      x = end;
    }
    return out;
  }
  function fromEquirect(img, height) {
    const width = 2 * height, sw = img.width, sh = img.height;
    const dphi = Math.PI / (height - 1), dtheta = 2 * Math.PI / (width - 1);
    const data = new Float32Array(width * height * 3);
    for (let r = 0; r < height; r++) {
      const phiC = r * dphi;
      const phiA = Math.max(phiC - 0.5 * dphi, 0), phiB = Math.min(phiC + 0.5 * dphi, Math.PI);
      const rows = overlapCells(phiA / Math.PI * sh, phiB / Math.PI * sh, sh, false);
      for (let c = 0; c < width; c++) {
        const uc = c / (width - 1), du = 0.5 * dtheta / (2 * Math.PI);
        const cols = overlapCells((uc - du) * sw, (uc + du) * sw, sw, true);
        let a0 = 0, a1 = 0, a2 = 0, ws = 0;
        for (const [j, a, b] of rows) {
          const wr = Math.cos(a / sh * Math.PI) - Math.cos(b / sh * Math.PI);
          for (const [i, ca, cb] of cols) {
            const w = wr * (cb - ca), p = 3 * (j * sw + i);
            a0 += w * img.rgb[p]; a1 += w * img.rgb[p + 1]; a2 += w * img.rgb[p + 2]; ws += w;
          }
        }
        const t = 3 * (r * width + c);
        if (ws > 0) { data[t] = a0 / ws; data[t + 1] = a1 / ws; data[t + 2] = a2 / ws; }
      }
    }
    return data;
  }

  return { parseHdr, fromEquirect };
})();
