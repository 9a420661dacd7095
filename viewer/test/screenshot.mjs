// Drive headless Chromium (Debian's /usr/bin/chromium, no browser download) with
// playwright-core: open each URL, wait until the viewer reports the requested frame as
// rendered (window.viewerState.ready), and save a screenshot of the page (OUT.png) and
// the viewer's state then (OUT.png.json).
// Usage: node test/screenshot.mjs [--viewport=WxH] CHROMIUM PROFILE_DIR URL OUT.png [URL OUT.png ...]
// (default viewport 640x480; with ?ui=0 in the URL the screenshot is the canvas alone).
import { writeFileSync } from "node:fs";
import { chromium } from "playwright-core";

let args = process.argv.slice(2);
let viewport = { width: 640, height: 480 };
const size = args.length && /^--viewport=(\d+)x(\d+)$/.exec(args[0]);
if (size) {
  viewport = { width: Number(size[1]), height: Number(size[2]) };
  args = args.slice(1);
}
const [executablePath, profile, ...pairs] = args;
if (!executablePath || !profile || pairs.length < 2 || pairs.length % 2) {
  console.error("usage: screenshot.mjs [--viewport=WxH] CHROMIUM PROFILE_DIR URL OUT.png [URL OUT.png ...]");
  process.exit(2);
}
const context = await chromium.launchPersistentContext(profile, {
  executablePath,
  headless: true,
  viewport,
  args: [
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--enable-unsafe-swiftshader",
    "--use-angle=swiftshader",
  ],
});
let failed = false;
try {
  const page = context.pages()[0] ?? (await context.newPage());
  page.on("console", (m) => console.log(`[page ${m.type()}] ${m.text()}`));
  page.on("pageerror", (e) => console.log(`[page error] ${e.stack || e.message}`));
  const renderer = await page.evaluate(() => {
    const gl = document.createElement("canvas").getContext("webgl2");
    if (!gl) return "no WebGL2";
    const ext = gl.getExtension("WEBGL_debug_renderer_info");
    return ext ? gl.getParameter(ext.UNMASKED_RENDERER_WEBGL) : gl.getParameter(gl.RENDERER);
  });
  console.log(`WebGL renderer: ${renderer}`);
  for (let i = 0; i < pairs.length; i += 2) {
    const [url, out] = [pairs[i], pairs[i + 1]];
    await page.goto(url);
    await page.waitForFunction(
      () => window.viewerState && (window.viewerState.ready || window.viewerState.error),
      null,
      { timeout: 120000, polling: 200 },
    );
    const error = await page.evaluate(() => window.viewerState.error);
    if (error) throw new Error(`the viewer reports: ${error}`);
    await page.screenshot({ path: out });
    const state = await page.evaluate(() => JSON.stringify(window.viewerState));
    writeFileSync(`${out}.json`, state);
    console.log(`${url} -> ${out} ${state}`);
  }
} catch (e) {
  console.error(`screenshot failed: ${e.message}`);
  failed = true;
} finally {
  await context.close();
}
process.exit(failed ? 1 : 0);
