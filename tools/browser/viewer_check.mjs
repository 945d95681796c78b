// Drive the relighting viewer page (`svgir view`) in headless Chromium (WebGL2 on SwiftShader).
//
//   node tools/browser/viewer_check.mjs PAGE.html [--hash "yaw=30&pitch=20&dist=4&light=night&ui=0"]
//        [--width 256] [--height 256] [--out SHOT.png] [--frames N] [--drop FILE.hdr] [--timeout MS]
//
// Opens PAGE.html#HASH at the given viewport, waits until the page is ready (window.READY) or
// reports an error (window.VIEWER_ERROR), optionally screenshots the viewport to --out,
// optionally feeds FILE.hdr to the page's drop handler (before the screenshot), and measures
// --frames frames (window.measureFrames: sort + draw + read-back per frame; window.measureRaf:
// the same frames through requestAnimationFrame). Prints one JSON line:
//   {"ready":bool,"error":string|null,"frame":{...}|null,"drop":{"error":...}|null,"console":[...]}
import { launch } from './screenshot.mjs';
import path from 'node:path';
import fs from 'node:fs';

function parseArgs(argv) {
  const a = { hash: '', width: 256, height: 256, out: null, frames: 0, drop: null, timeout: 120000, pos: [] };
  for (let i = 0; i < argv.length; i++) {
    const k = argv[i];
    if (k === '--hash') a.hash = argv[++i];
    else if (k === '--width') a.width = Number(argv[++i]);
    else if (k === '--height') a.height = Number(argv[++i]);
    else if (k === '--out') a.out = argv[++i];
    else if (k === '--frames') a.frames = Number(argv[++i]);
    else if (k === '--drop') a.drop = argv[++i];
    else if (k === '--timeout') a.timeout = Number(argv[++i]);
    else a.pos.push(k);
  }
  if (a.pos.length !== 1) {
    console.error('usage: node viewer_check.mjs PAGE.html [--hash H] [--width W] [--height H] [--out PNG] [--frames N] [--drop FILE.hdr]');
    process.exit(2);
  }
  return a;
}

async function main() {
  const args = parseArgs(process.argv.slice(2));
  const page_path = path.resolve(args.pos[0]);
  if (!fs.existsSync(page_path)) throw new Error(`${page_path}: no such page`);
  const browser = await launch();
  const result = { ready: false, error: null, frame: null, drop: null, console: [] };
  try {
    const page = await browser.newPage({ viewport: { width: args.width, height: args.height }, deviceScaleFactor: 1 });
    page.on('console', (m) => { if (m.type() === 'error' || m.type() === 'warning') result.console.push(m.text()); });
    page.on('pageerror', (e) => result.console.push(String(e)));
    await page.goto('file://' + page_path + (args.hash ? '#' + args.hash : ''), { waitUntil: 'load', timeout: args.timeout });
    await page.waitForFunction('window.READY === true || !!window.VIEWER_ERROR', null, { timeout: args.timeout });
    result.ready = await page.evaluate('window.READY === true');
    result.error = await page.evaluate('window.VIEWER_ERROR');
    if (args.drop) {
      const bytes = [...fs.readFileSync(args.drop)];
      await page.evaluate(`window.VIEWER_ERROR = null`);
      await page.evaluate(async ({ name, bytes }) => { await window.loadHdrBytes(name, new Uint8Array(bytes)); }, { name: path.basename(args.drop), bytes });
      const shown = await page.evaluate(`document.getElementById('msg').textContent`);
      result.drop = { error: await page.evaluate('window.VIEWER_ERROR'), message: shown };
      // Let the page draw the new light.
      await page.evaluate('new Promise((r) => requestAnimationFrame(() => requestAnimationFrame(r)))');
    }
    if (args.out) await page.screenshot({ path: args.out, clip: { x: 0, y: 0, width: args.width, height: args.height } });
    if (args.frames > 0 && result.ready) {
      result.frame = await page.evaluate(`window.measureFrames(${args.frames})`);
      Object.assign(result.frame, await page.evaluate(`window.measureRaf(${args.frames})`));
    }
  } finally {
    await browser.close();
  }
  console.log(JSON.stringify(result));
}

main().catch((e) => { console.error(`error: ${e.message}`); process.exit(1); });
