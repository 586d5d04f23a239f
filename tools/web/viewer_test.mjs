// The 3D viewer in a real browser (headless Chromium through playwright-core).
//
// Given an edit output folder (report.html and renders/{before,after}_<test view>.png,
// both rendered by transsplat's CPU rasterizer), it:
//  1. opens report.html from disk and waits for the viewer's first sorted frame;
//  2. jumps to the first test camera through the camera menu and compares the canvas
//     with transsplat's render of that camera ("after"): PSNR at least MIN_PSNR;
//  3. clicks "before", compares with the "before" render, and checks that what changed
//     between the two canvases lies where the edit is (where the two renders differ);
//  4. drags the split slider to the middle and checks the left half shows "before" and
//     the right half "after";
//  5. saves screenshots, and times frames (sort + draw) on this page and, when given,
//     on a large `transsplat view` page (--fps-page), at 1280x720;
//  6. opens the page with WebGL disabled and checks the viewer says so instead of
//     showing a blank canvas.
// Prints one JSON line of measurements; exits 1 on any failed check.
//
// Usage: node viewer_test.mjs EDIT_OUT_DIR SHOT_DIR [--fps-page PAGE.html]

import { chromium } from 'playwright-core';
import fs from 'node:fs';
import path from 'node:path';
import { pngPixels } from './png.mjs';

const MIN_PSNR = 25.0;
const [dir, shots] = process.argv.slice(2, 4);
const fpsIdx = process.argv.indexOf('--fps-page');
const fpsPage = fpsIdx > 0 ? process.argv[fpsIdx + 1] : null;
fs.mkdirSync(shots, { recursive: true });

const executablePath = process.env.CHROMIUM || '/usr/bin/chromium';
const baseArgs = [
  '--no-sandbox', '--disable-gpu-sandbox', '--disable-quic', '--no-first-run',
  '--disable-background-networking', '--disable-component-update', '--disable-sync',
  '--use-angle=swiftshader', '--enable-unsafe-swiftshader', '--ignore-gpu-blocklist',
];

const failures = [];
const check = (ok, what) => { if (!ok) failures.push(what); };
const results = {};

function meta(html) {
  const m = html.match(/class="ts-meta">([\s\S]*?)<\/script>/);
  return JSON.parse(m[1].replace(/<\\\//g, '</'));
}

async function open(browser, file, viewport) {
  const page = await browser.newPage({ viewport });
  const errors = [];
  page.on('pageerror', (e) => errors.push(String(e)));
  await page.goto('file://' + path.resolve(file));
  await page.waitForFunction(() => window.transsplatViewers && window.transsplatViewers.length > 0, null, { timeout: 120000 });
  await page.evaluate(() => window.transsplatViewers[0].ready);
  return { page, errors };
}

// Canvas pixels (RGBA, drawing-buffer size) after the next fully sorted frame.
async function canvasPixels(page) {
  return page.evaluate(async () => {
    const v = window.transsplatViewers[0];
    await v.frame();
    const c = document.querySelector('.ts-viewer .ts-canvas');
    const url = c.toDataURL('image/png');
    const img = await createImageBitmap(await (await fetch(url)).blob());
    const oc = new OffscreenCanvas(img.width, img.height);
    const ctx = oc.getContext('2d');
    ctx.drawImage(img, 0, 0);
    return { w: img.width, h: img.height, data: Array.from(ctx.getImageData(0, 0, img.width, img.height).data) };
  });
}

function psnr(a, b, keep = () => true) {
  let se = 0, n = 0;
  for (let i = 0; i < a.w * a.h; i++) {
    if (!keep(i)) continue;
    for (let c = 0; c < 3; c++) {
      const d = (a.data[4 * i + c] - b.data[4 * i + c]) / 255;
      se += d * d; n++;
    }
  }
  return 10 * Math.log10(1 / Math.max(se / Math.max(n, 1), 1e-12));
}

const diff = (a, b, i) => Math.max(...[0, 1, 2].map((c) => Math.abs(a.data[4 * i + c] - b.data[4 * i + c])));

const browser = await chromium.launch({ executablePath, headless: true, args: baseArgs });
try {
  const report = path.join(dir, 'report.html');
  const m = meta(fs.readFileSync(report, 'utf8'));
  const cam = m.cameras[m.start_camera];
  const stem = cam.name;
  const { page, errors } = await open(browser, report, { width: 1280, height: 900 });
  results.gaussians = m.scenes.map((s) => s.count);

  // 2. The test camera through the UI, against transsplat's render.
  await page.selectOption('.ts-viewer .ts-camera', String(m.start_camera));
  await page.click('.ts-viewer .ts-after');
  const after = await canvasPixels(page);
  const refAfter = await pngPixels(page, path.join(dir, 'renders', `after_${stem}.png`));
  check(after.w === refAfter.w && after.h === refAfter.h, `canvas ${after.w}x${after.h} is not the camera's ${refAfter.w}x${refAfter.h}`);
  let lit = 0;
  for (let i = 0; i < after.w * after.h; i++) if (after.data[4 * i] + after.data[4 * i + 1] + after.data[4 * i + 2] > 30) lit++;
  results.lit_fraction = lit / (after.w * after.h);
  check(results.lit_fraction > 0.05, `canvas is nearly blank (${results.lit_fraction})`);
  results.psnr_after = psnr(after, refAfter);
  check(results.psnr_after >= MIN_PSNR, `after: PSNR ${results.psnr_after.toFixed(2)} < ${MIN_PSNR}`);
  await page.screenshot({ path: path.join(shots, 'viewer_after.png') });

  // 3. Before / after toggle.
  await page.click('.ts-viewer .ts-before');
  const before = await canvasPixels(page);
  const refBefore = await pngPixels(page, path.join(dir, 'renders', `before_${stem}.png`));
  results.psnr_before = psnr(before, refBefore);
  check(results.psnr_before >= MIN_PSNR, `before: PSNR ${results.psnr_before.toFixed(2)} < ${MIN_PSNR}`);
  await page.screenshot({ path: path.join(shots, 'viewer_before.png') });
  // Where the renders differ (the edit) versus where the canvases differ.
  const edited = (i) => diff(refAfter, refBefore, i) > 24;
  let inside = 0, nIn = 0, outside = 0, nOut = 0;
  for (let i = 0; i < after.w * after.h; i++) {
    const d = diff(after, before, i);
    if (edited(i)) { inside += d; nIn++; } else { outside += d; nOut++; }
  }
  results.edit_pixels = nIn;
  results.change_inside = inside / Math.max(nIn, 1);
  results.change_outside = outside / Math.max(nOut, 1);
  check(nIn > 50, `the renders hardly differ (${nIn} pixels): no edit to look for`);
  check(results.change_inside > 5 * results.change_outside + 4,
    `toggling changes the edit region by ${results.change_inside.toFixed(1)}, elsewhere by ${results.change_outside.toFixed(1)}`);

  // 4. The split slider: left half before, right half after.
  await page.evaluate(() => {
    const s = document.querySelector('.ts-viewer .ts-split');
    s.value = String((Number(s.min) + Number(s.max)) / 2);
    s.dispatchEvent(new Event('input', { bubbles: true }));
  });
  const split = await canvasPixels(page);
  const w = split.w;
  const margin = Math.round(w * 0.05);
  results.psnr_split_left = psnr(split, refBefore, (i) => i % w < w / 2 - margin);
  results.psnr_split_right = psnr(split, refAfter, (i) => i % w > w / 2 + margin);
  check(results.psnr_split_left >= MIN_PSNR && results.psnr_split_right >= MIN_PSNR,
    `split: left ${results.psnr_split_left.toFixed(1)} dB vs before, right ${results.psnr_split_right.toFixed(1)} dB vs after`);
  await page.screenshot({ path: path.join(shots, 'viewer_split.png') });

  // Colour modes exist for the maps.
  const modes = await page.$$eval('.ts-viewer .ts-colour option', (os) => os.map((o) => o.textContent));
  results.colour_modes = modes;
  check(modes.some((t) => t.includes('gate')), `no gate colour mode in ${JSON.stringify(modes)}`);
  results.frame_ms_report = await page.evaluate(() => window.transsplatViewers[0].benchmark(30));
  check(errors.length === 0, `page errors: ${errors.join('; ')}`);
  await page.close();

  // 5. Frame time on a large page at 1280x720 (software WebGL here: SwiftShader).
  if (fpsPage) {
    const big = await open(browser, fpsPage, { width: 1280, height: 940 });
    results.large_gaussians = meta(fs.readFileSync(fpsPage, 'utf8')).scenes.map((s) => s.count);
    // Fill the 1280x720 window (not the camera's own size).
    await big.page.evaluate(() => window.transsplatViewers[0].setSizeMode('fill'));
    results.frame_ms_large = await big.page.evaluate(() => window.transsplatViewers[0].benchmark(3));
    results.stats_large = await big.page.evaluate(() => window.transsplatViewers[0].stats());
    await big.page.screenshot({ path: path.join(shots, 'viewer_large.png') });
    check(big.errors.length === 0, `large page errors: ${big.errors.join('; ')}`);
    await big.page.close();
  }
} finally {
  await browser.close();
}

// 6. No WebGL: a message, not a blank canvas.
const noGl = await chromium.launch({ executablePath, headless: true, args: [...baseArgs, '--disable-webgl', '--disable-webgl2'] });
try {
  const page = await noGl.newPage();
  await page.goto('file://' + path.resolve(path.join(dir, 'report.html')));
  await page.waitForSelector('.ts-viewer .ts-message', { timeout: 60000 });
  const text = await page.$eval('.ts-viewer .ts-message', (e) => e.textContent);
  results.no_webgl_message = text;
  check(/WebGL2/.test(text), `without WebGL the viewer says ${JSON.stringify(text)}`);
} finally {
  await noGl.close();
}

console.log(JSON.stringify(results));
if (failures.length) {
  console.error('viewer test failed:\n  ' + failures.join('\n  '));
  process.exit(1);
}
console.log('viewer test passed');
