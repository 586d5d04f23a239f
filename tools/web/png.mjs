// A PNG file's pixels, decoded by the browser (no extra npm package): { w, h, data } with
// data RGBA bytes. Shared by the viewer and glTF checks.
import fs from 'node:fs';

export async function pngPixels(page, file) {
  const b64 = fs.readFileSync(file).toString('base64');
  return page.evaluate(async (b64) => {
    const bytes = Uint8Array.from(atob(b64), (c) => c.charCodeAt(0));
    const img = await createImageBitmap(new Blob([bytes], { type: 'image/png' }));
    const oc = new OffscreenCanvas(img.width, img.height);
    const ctx = oc.getContext('2d');
    ctx.drawImage(img, 0, 0);
    return { w: img.width, h: img.height, data: Array.from(ctx.getImageData(0, 0, img.width, img.height).data) };
  }, b64);
}
