// Render a glTF binary with three.js (headless Chromium, WebGL2 on SwiftShader) from a camera
// given in svgir's OpenCV convention, lit by an equirectangular .hdr (gltf_view.html).
//
//   node tools/browser/gltf_render.mjs MODEL.glb LIGHT.hdr CAMERA.json OUT.png
//
// CAMERA.json: {"fx", "fy", "cx", "cy", "width", "height", "rotation": [9, world-to-camera,
// row-major], "translation": [3]}. The canvas (width x height) is saved as OUT.png.
import { launch } from './screenshot.mjs';
import path from 'node:path';
import fs from 'node:fs';
import { fileURLToPath, pathToFileURL } from 'node:url';

const [glb, hdr, camPath, out] = process.argv.slice(2);
if (!out) {
  console.error('usage: node gltf_render.mjs MODEL.glb LIGHT.hdr CAMERA.json OUT.png');
  process.exit(2);
}
for (const f of [glb, hdr, camPath]) if (!fs.existsSync(f)) throw new Error(`${f}: no such file`);
const cam = JSON.parse(fs.readFileSync(camPath, 'utf8'));
const here = path.dirname(fileURLToPath(import.meta.url));
const page = pathToFileURL(path.join(here, 'gltf_view.html'));
page.searchParams.set('glb', pathToFileURL(path.resolve(glb)).href);
page.searchParams.set('hdr', pathToFileURL(path.resolve(hdr)).href);
page.searchParams.set('cam', JSON.stringify(cam));
const browser = await launch();
const errors = [];
try {
  const p = await browser.newPage({ viewport: { width: cam.width, height: cam.height } });
  p.on('console', (m) => { if (m.type() === 'error') errors.push(m.text()); });
  p.on('pageerror', (e) => errors.push(String(e)));
  await p.goto(page.href, { waitUntil: 'load', timeout: 120000 });
  await p.waitForFunction('window.READY === true || window.ERROR !== undefined', null, { timeout: 120000 });
  const err = await p.evaluate('window.ERROR');
  if (err) throw new Error(err);
  await p.locator('canvas').screenshot({ path: out });
} finally {
  await browser.close();
}
if (errors.length) {
  console.error(errors.join('\n'));
  process.exit(1);
}
console.log(`rendered ${glb} under ${hdr}: ${out}`);
