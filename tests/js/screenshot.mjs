// A headless chromium (puppeteer-core) on Rerun's web viewer: loads the page, takes a screenshot
// every 2 s and counts, in the mechanism view (the blueprint's left column, a quarter of the
// width), the pixels of the crank's, the rod's and the rocker's colours
// (mps_ros/wire/drawing.py's COLORS); done when each is there, or at the deadline.
//
//   node screenshot.mjs '{"url": "http://127.0.0.1:PORT/?url=...", "chromium": "/usr/bin/chromium", "out": "FILE.png"}'
//
// Prints one JSON line: {"drawn": bool, "counts": {...}, "seconds": s}; the last screenshot in out.
import { writeFileSync } from "node:fs";

import puppeteer from "puppeteer-core";

const opts = JSON.parse(process.argv[2]);
const LINKS = { crank: [31, 119, 180], rod: [255, 127, 14], rocker: [44, 160, 44] };
const ENOUGH = 20; // pixels of each colour
const deadline = Date.now() + (opts.timeoutS ?? 300) * 1000;

const browser = await puppeteer.launch({
  executablePath: opts.chromium,
  headless: true,
  args: [
    "--no-sandbox",
    "--use-angle=swiftshader",
    "--enable-unsafe-swiftshader",
    "--ignore-gpu-blocklist",
    "--window-size=1600,1000",
  ],
});
const started = Date.now();
let result = { drawn: false, counts: {}, seconds: 0 };
try {
  const page = await browser.newPage();
  await page.setViewport({ width: 1600, height: 1000 });
  await page.goto(opts.url, { waitUntil: "load", timeout: 120000 });
  let shot = null;
  while (Date.now() < deadline) {
    shot = await page.screenshot({ type: "png", encoding: "base64" });
    const counts = await page.evaluate(
      async (b64, links) => {
        const img = new Image();
        img.src = `data:image/png;base64,${b64}`;
        await img.decode();
        const c = document.createElement("canvas");
        c.width = img.width;
        c.height = img.height;
        const g = c.getContext("2d");
        g.drawImage(img, 0, 0);
        const w = Math.floor(img.width * 0.27); // the mechanism view's column
        const px = g.getImageData(0, 0, w, img.height).data;
        const out = Object.fromEntries(Object.keys(links).map((k) => [k, 0]));
        for (let i = 0; i < px.length; i += 4) {
          for (const [k, [r, gg, b]] of Object.entries(links)) {
            if (Math.abs(px[i] - r) < 24 && Math.abs(px[i + 1] - gg) < 24 && Math.abs(px[i + 2] - b) < 24) out[k] += 1;
          }
        }
        return out;
      },
      shot,
      LINKS,
    );
    result = { drawn: Object.values(counts).every((n) => n >= ENOUGH), counts, seconds: (Date.now() - started) / 1000 };
    if (result.drawn) break;
    await new Promise((r) => setTimeout(r, 2000));
  }
  if (shot) writeFileSync(opts.out, Buffer.from(shot, "base64"));
} finally {
  await browser.close();
}
console.log(JSON.stringify(result));
