// Our glTF export drawn by an engine that implements KHR_gaussian_splatting: the
// PlayCanvas engine (npm `playcanvas`, pinned in package.json), in headless Chromium.
//
// Given our .glb of a scene, the scene's cameras.json and transsplat's own render of
// the first camera (PNG), it:
//  1. serves a page, the engine module and the file from a local HTTP server;
//  2. loads the .glb as a container asset, instantiates it, places the engine's camera
//     at the first camera (INRIA cameras.json, moved into glTF's axes: a half turn
//     about z) with the same vertical field of view and canvas size, and waits until
//     the splats are drawn;
//  3. checks that the drawn pixels (not the black background) lie where transsplat's
//     render has the scene: the two foreground masks overlap (IoU at least MIN_IOU), the
//     two images agree (PSNR at least MIN_PSNR; the engine's splat rasteriser is not
//     ours), and far better than with the render mirrored left to right (what a wrong
//     axis convention would give);
//  4. loads the same file with the extension's name misspelt (the primitive is then an
//     ordinary point cloud) and checks the engine draws no splats from it (at most a
//     point a Gaussian, far under the splat page's foreground).
// Saves both screenshots; prints one JSON line; exits 1 on any failed check.
//
// Usage: node gltf_test.mjs SCENE.glb CAMERAS.json RENDER_VIEW0.png SHOT_DIR

import { chromium } from 'playwright-core';
import fs from 'node:fs';
import http from 'node:http';
import path from 'node:path';
import { pngPixels } from './png.mjs';
import { fileURLToPath } from 'node:url';

const MIN_IOU = 0.6;
const MIN_PSNR = 25.0;
const [glbPath, camerasPath, renderPath, shots] = process.argv.slice(2, 6);
fs.mkdirSync(shots, { recursive: true });
const here = path.dirname(fileURLToPath(import.meta.url));
const engine = path.join(here, 'node_modules/playcanvas/build/playcanvas.mjs');

const glb = fs.readFileSync(glbPath);
// The extension's name misspelt everywhere it is a whole JSON string (same length, so
// the container stays valid): what a GLB without the extension looks like.
const plain = Buffer.from(glb);
const from = Buffer.from('"KHR_gaussian_splatting"');
for (let at = plain.indexOf(from); at >= 0; at = plain.indexOf(from, at + 1)) {
  plain.write('"KHR_gaussian_splattinX"', at);
}
const cam = JSON.parse(fs.readFileSync(camerasPath, 'utf8'))[0];

const page = `<!doctype html><html><body style="margin:0;background:#000">
<canvas id="c" width="${cam.width}" height="${cam.height}"></canvas>
<script type="module">
import * as pc from '/playcanvas.mjs';
window.drawGlb = async (url, cam) => {
  const canvas = document.getElementById('c');
  const device = await pc.createGraphicsDevice(canvas, {
    deviceTypes: ['webgl2'], antialias: false, preserveDrawingBuffer: true,
  });
  const app = new pc.AppBase(canvas);
  const opts = new pc.AppOptions();
  opts.graphicsDevice = device;
  opts.componentSystems = [pc.RenderComponentSystem, pc.CameraComponentSystem, pc.GSplatComponentSystem];
  opts.resourceHandlers = [pc.ContainerHandler, pc.TextureHandler, pc.GSplatHandler];
  app.init(opts);
  app.setCanvasResolution(pc.RESOLUTION_FIXED, cam.width, cam.height);
  app.start();
  // The camera in glTF's axes: the PLY's (x, y, z) is glTF's (-x, -y, z). INRIA's
  // rotation holds the camera's right, down and forward axes as columns.
  const g = (v) => [-v[0], -v[1], v[2]];
  const R = cam.rotation;
  const col = (k) => [R[0][k], R[1][k], R[2][k]];
  const p = g(cam.position), f = g(col(2)), d = g(col(1));
  const camera = new pc.Entity('camera');
  camera.addComponent('camera', {
    clearColor: new pc.Color(0, 0, 0, 1),
    fov: 2 * Math.atan(cam.height / 2 / cam.fy) * 180 / Math.PI,
    nearClip: 0.01, farClip: 1000,
  });
  camera.setPosition(p[0], p[1], p[2]);
  camera.lookAt(p[0] + f[0], p[1] + f[1], p[2] + f[2], -d[0], -d[1], -d[2]);
  app.root.addChild(camera);
  const asset = await new Promise((resolve, reject) => {
    app.assets.loadFromUrl(url, 'container', (err, a) => (err ? reject(new Error(String(err))) : resolve(a)));
  });
  app.root.addChild(asset.resource.instantiateRenderEntity());
  const splats = asset.resource.gsplats ? asset.resource.gsplats.length : 0;
  // Frames until the sorted splats show (the sort runs in a worker).
  for (let i = 0; i < 120; i++) {
    await new Promise((r) => requestAnimationFrame(r));
  }
  const oc = new OffscreenCanvas(cam.width, cam.height);
  const ctx = oc.getContext('2d');
  ctx.drawImage(canvas, 0, 0);
  const px = ctx.getImageData(0, 0, cam.width, cam.height).data;
  return { splats, pixels: Array.from(px) };
};
window.pageReady = true;
</script></body></html>`;

const server = http.createServer((req, res) => {
  const files = {
    '/': ['text/html', Buffer.from(page)],
    '/playcanvas.mjs': ['text/javascript', fs.readFileSync(engine)],
    '/scene.glb': ['model/gltf-binary', glb],
    '/plain.glb': ['model/gltf-binary', plain],
  };
  const f = files[req.url];
  res.writeHead(f ? 200 : 404, { 'Content-Type': f ? f[0] : 'text/plain' });
  res.end(f ? f[1] : 'not found');
});
await new Promise((r) => server.listen(0, '127.0.0.1', r));
const base = `http://127.0.0.1:${server.address().port}`;

const browser = await chromium.launch({
  executablePath: process.env.CHROMIUM || '/usr/bin/chromium',
  args: ['--no-sandbox', '--disable-gpu-sandbox', '--use-angle=swiftshader', '--enable-unsafe-swiftshader',
    '--ignore-gpu-blocklist', '--disable-background-networking', '--no-first-run'],
});
const failures = [];
const check = (ok, what) => { if (!ok) failures.push(what); };

async function draw(url) {
  const p = await browser.newPage({ viewport: { width: cam.width, height: cam.height } });
  const errors = [];
  p.on('pageerror', (e) => errors.push(String(e)));
  await p.goto(base + '/');
  await p.waitForFunction(() => window.pageReady === true);
  const out = await p.evaluate(([u, c]) => window.drawGlb(u, c), [url, cam]);
  await p.screenshot({ path: path.join(shots, `gltf_${path.basename(url, '.glb')}.png`) });
  await p.close();
  return { ...out, errors };
}

// transsplat's render, decoded by the browser.
async function renderPixels(file) {
  const p = await browser.newPage();
  const out = await pngPixels(p, file);
  await p.close();
  return out;
}

const fg = (px, i) => px[i] + px[i + 1] + px[i + 2] > 3 * 8;
const results = {};
try {
  const ours = await draw('/scene.glb');
  const ref = await renderPixels(renderPath);
  check(ref.w === cam.width && ref.h === cam.height, `render is ${ref.w}x${ref.h}, camera ${cam.width}x${cam.height}`);
  check(ours.errors.length === 0, `page errors: ${ours.errors.join('; ')}`);
  check(ours.splats === 1, `the engine made ${ours.splats} splat assets from our file (expected 1)`);
  let both = 0, either = 0, drawn = 0, mse = 0, mseMirrored = 0;
  for (let i = 0; i < ref.data.length; i += 4) {
    const a = fg(ours.pixels, i), b = fg(ref.data, i);
    both += a && b; either += a || b; drawn += a;
    const x = (i / 4) % cam.width;
    const m = i + 4 * (cam.width - 1 - 2 * x);
    for (let c = 0; c < 3; c++) {
      mse += ((ours.pixels[i + c] - ref.data[i + c]) / 255) ** 2;
      mseMirrored += ((ours.pixels[i + c] - ref.data[m + c]) / 255) ** 2;
    }
  }
  const n = ref.data.length / 4;
  const psnr = (e) => +(10 * Math.log10(1 / Math.max(e / (3 * n), 1e-12))).toFixed(2);
  results.drawn_fraction = +(drawn / n).toFixed(4);
  results.iou = +(both / Math.max(either, 1)).toFixed(4);
  results.psnr_vs_transsplat = psnr(mse);
  results.psnr_vs_mirrored = psnr(mseMirrored);
  check(drawn > 0.01 * n, `the engine drew ${drawn} non-background pixels of ${n}`);
  check(results.iou >= MIN_IOU, `foreground IoU with transsplat's render ${results.iou} < ${MIN_IOU}`);
  check(results.psnr_vs_transsplat >= MIN_PSNR, `PSNR against transsplat's render ${results.psnr_vs_transsplat} < ${MIN_PSNR}`);
  check(results.psnr_vs_transsplat > results.psnr_vs_mirrored + 6, 'the drawing is no closer to the render than to its mirror image');

  const bare = await draw('/plain.glb');
  check(bare.splats === 0, `the engine made ${bare.splats} splat assets from the file without the extension`);
  let bareDrawn = 0;
  for (let i = 0; i < bare.pixels.length; i += 4) bareDrawn += fg(bare.pixels, i);
  results.drawn_fraction_without_extension = +(bareDrawn / n).toFixed(4);
  check(bareDrawn < 0.25 * drawn, `without the extension ${bareDrawn} pixels drawn, with it ${drawn}`);
} catch (e) {
  failures.push(String(e && e.stack ? e.stack : e));
} finally {
  await browser.close();
  server.close();
}
console.log(JSON.stringify(results));
if (failures.length) {
  console.error('gltf_test: ' + failures.join('\n'));
  process.exit(1);
}
console.log('gltf_test passed');
