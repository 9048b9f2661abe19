// node bench/lightmap_view.mjs URL TOKEN SCENE.lit.glb MODE OUT.png
// A picture of a bake as a person sees it: opens SCENE.lit.glb in the
// running lightfarmd's status page (3D view, the file's own camera and
// exposure) in headless Chromium, switches to MODE ("lit", or "lightmap"
// for the light alone on white surfaces, where blotches and streaks show
// that textures hide) and saves the canvas to OUT.png. bench/lightmap_view.sh
// starts the server; docs/images/ holds what it made.
import { createRequire } from "node:module";
import path from "node:path";
import { fileURLToPath } from "node:url";

const here = path.dirname(fileURLToPath(import.meta.url));
const require = createRequire(path.join(here, "../web/package.json"));
const { chromium } = require("playwright-core");

const [url, token, glb, mode, out] = process.argv.slice(2);
if (!out || !["lit", "lightmap"].includes(mode)) {
  console.error("usage: node bench/lightmap_view.mjs URL TOKEN SCENE.lit.glb lit|lightmap OUT.png");
  process.exit(2);
}
const browser = await chromium.launch({
  executablePath: process.env.LIGHTFARM_CHROMIUM || "/usr/bin/chromium",
  args: ["--no-sandbox", "--disable-gpu", "--use-angle=swiftshader", "--enable-unsafe-swiftshader",
         "--disable-background-networking", "--disable-component-update", "--disable-sync", "--no-first-run"],
});
let failed = null;
try {
  const page = await browser.newPage({ viewport: { width: 1280, height: 1400 } });
  await page.goto(`${url}/?token=${encodeURIComponent(token)}`);  // sets the cookie
  const frames = async () => page.evaluate(() => window.lightfarmView?.state.frames ?? 0);
  // Waits for a frame after `after` of the opened file in `want` mode.
  const drawn = async (want, after) => {
    // Polled with evaluate(): the page's Content-Security-Policy forbids
    // the eval that waitForFunction uses.
    for (const deadline = Date.now() + 120_000; ; await new Promise((r) => setTimeout(r, 200))) {
      const s = await page.evaluate(() => window.lightfarmView && { ...window.lightfarmView.state });
      if (s?.error) throw new Error("3D view: " + s.error);
      if (s && s.mode === want && s.file === path.basename(glb) && s.frames > after) return s.frames;
      if (Date.now() > deadline) throw new Error(`3D view: ${glb} not drawn in mode ${want} within 120 s`);
    }
  };
  // The view's module installs the file input's handler once three.js is in.
  for (const deadline = Date.now() + 30_000; !(await page.evaluate(() => !!window.lightfarmView));) {
    if (Date.now() > deadline) throw new Error("the 3D view did not start within 30 s");
    await new Promise((r) => setTimeout(r, 100));
  }
  await page.setInputFiles("#view3d-file", glb);
  const opened = await drawn("lit", await frames());
  if (mode !== "lit") {
    await page.check(`input[name=view3d-mode][value=${mode}]`);
    await drawn(mode, opened);
  }
  await page.locator("#view3d-canvas canvas").screenshot({ path: out });
} catch (e) {
  failed = e.message;
} finally {
  await browser.close();
}
console.log(JSON.stringify({ glb, mode, out, error: failed }));
process.exit(failed ? 1 : 0);
