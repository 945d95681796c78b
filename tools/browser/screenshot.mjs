// Screenshot a page in headless Chromium (Debian's /usr/bin/chromium, driven by playwright-core).
//
//   node tools/browser/screenshot.mjs PAGE.html OUT.png [--width 1280] [--height 800]
//        [--wait "window.READY === true"] [--timeout 60000] [--full-page]
//
// The page is opened from the file system. WebGL runs on SwiftShader (software), so pages that
// render with WebGL work without a GPU. With --wait the screenshot waits until the expression is
// true in the page; the page's console errors are printed and make the command fail.
import { chromium } from 'playwright-core';
import path from 'node:path';
import fs from 'node:fs';
import os from 'node:os';

function parseArgs(argv) {
  const args = { width: 1280, height: 800, wait: null, timeout: 60000, fullPage: false, pos: [] };
  for (let i = 0; i < argv.length; i++) {
    const a = argv[i];
    if (a === '--width') args.width = Number(argv[++i]);
    else if (a === '--height') args.height = Number(argv[++i]);
    else if (a === '--wait') args.wait = argv[++i];
    else if (a === '--timeout') args.timeout = Number(argv[++i]);
    else if (a === '--full-page') args.fullPage = true;
    else args.pos.push(a);
  }
  if (args.pos.length !== 2) {
    console.error('usage: node screenshot.mjs PAGE.html OUT.png [--width W] [--height H] [--wait EXPR] [--timeout MS] [--full-page]');
    process.exit(2);
  }
  return args;
}

export const CHROMIUM_ARGS = [
  '--no-sandbox', '--disable-gpu', '--use-angle=swiftshader', '--enable-unsafe-swiftshader',
  '--disable-quic', '--no-first-run', '--disable-background-networking', '--disable-component-update',
  '--disable-sync', '--allow-file-access-from-files',
];

export async function launch() {
  const executablePath = process.env.CHROMIUM || '/usr/bin/chromium';
  if (!fs.existsSync(executablePath)) {
    throw new Error(`${executablePath}: Chromium not found (Debian: apt-get install chromium; or set CHROMIUM)`);
  }
  return chromium.launch({ executablePath, args: CHROMIUM_ARGS, headless: true });
}

async function main() {
  const args = parseArgs(process.argv.slice(2));
  const page_path = path.resolve(args.pos[0]);
  if (!fs.existsSync(page_path)) throw new Error(`${page_path}: no such page`);
  const browser = await launch();
  const errors = [];
  try {
    const page = await browser.newPage({ viewport: { width: args.width, height: args.height } });
    page.on('console', (m) => { if (m.type() === 'error') errors.push(m.text()); });
    page.on('pageerror', (e) => errors.push(String(e)));
    await page.goto('file://' + page_path, { waitUntil: 'load', timeout: args.timeout });
    if (args.wait) await page.waitForFunction(args.wait, null, { timeout: args.timeout });
    await page.screenshot({ path: args.pos[1], fullPage: args.fullPage });
  } finally {
    await browser.close();
  }
  if (errors.length) {
    console.error(`${args.pos[0]}: the page reported errors:\n  ` + errors.join('\n  '));
    process.exit(1);
  }
}

if (process.argv[1]?.endsWith('screenshot.mjs')) {
  main().catch((e) => { console.error(`error: ${e.message}`); process.exit(1); });
}
