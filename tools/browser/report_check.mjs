// Checks an svgir HTML report in headless Chromium at a desktop and a phone width, and saves a
// screenshot of the top of the page at each.
//
//   node tools/browser/report_check.mjs RUN/report.html OUT_DIR
//
// Fails (exit 1) if the page reports an error, an image does not decode, the page scrolls
// sideways, or the first section is not the results. Prints one JSON line per width.
import { launch } from './screenshot.mjs';
import path from 'node:path';
import fs from 'node:fs';

const WIDTHS = [
  { name: 'desktop', width: 1280, height: 900 },
  { name: 'phone', width: 390, height: 844, isMobile: true, deviceScaleFactor: 2 },
];

async function main() {
  const [page_arg, out_dir] = process.argv.slice(2);
  if (!page_arg || !out_dir) {
    console.error('usage: node report_check.mjs REPORT.html OUT_DIR');
    process.exit(2);
  }
  const page_path = path.resolve(page_arg);
  if (!fs.existsSync(page_path)) throw new Error(`${page_path}: no such report`);
  fs.mkdirSync(out_dir, { recursive: true });
  const browser = await launch();
  const problems = [];
  try {
    for (const w of WIDTHS) {
      const page = await browser.newPage({
        viewport: { width: w.width, height: w.height },
        isMobile: !!w.isMobile,
        deviceScaleFactor: w.deviceScaleFactor || 1,
      });
      const errors = [];
      page.on('console', (m) => { if (m.type() === 'error') errors.push(m.text()); });
      page.on('pageerror', (e) => errors.push(String(e)));
      await page.goto('file://' + page_path, { waitUntil: 'load' });
      const facts = await page.evaluate(() => {
        const imgs = [...document.images];
        return {
          images: imgs.length,
          broken: imgs.filter((i) => !i.complete || i.naturalWidth === 0).length,
          scroll_width: document.documentElement.scrollWidth,
          inner_width: window.innerWidth,
          first_section: document.querySelector('h2')?.textContent || '',
          sections: [...document.querySelectorAll('h2')].map((h) => h.textContent),
          plots: document.querySelectorAll('svg.plot').length,
        };
      });
      const shot = path.join(out_dir, `report_${w.name}.png`);
      await page.screenshot({ path: shot });
      const summary = { width: w.name, ...facts, errors, screenshot: shot };
      console.log(JSON.stringify(summary));
      if (errors.length) problems.push(`${w.name}: page errors: ${errors.join('; ')}`);
      if (facts.broken) problems.push(`${w.name}: ${facts.broken} of ${facts.images} images did not decode`);
      if (facts.scroll_width > facts.inner_width + 1) {
        problems.push(`${w.name}: the page scrolls sideways (${facts.scroll_width} px wide in a ${facts.inner_width} px window)`);
      }
      await page.close();
    }
  } finally {
    await browser.close();
  }
  if (problems.length) {
    console.error(`${page_arg}:\n  ` + problems.join('\n  '));
    process.exit(1);
  }
}

main().catch((e) => { console.error(`error: ${e.message}`); process.exit(1); });
