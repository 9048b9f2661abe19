// node tests/web/status_page_3d.mjs URL TOKEN JOB_ID SCREENSHOT.png [SCENE.lit.glb [PROBES.json]]
// Opens lightfarmd's status page in a real headless Chromium (Debian's
// /usr/bin/chromium, or $LIGHTFARM_CHROMIUM) driven by playwright-core, selects
// the job, waits for the 3D view to draw its latest lightmap, switches through
// the three modes, and checks what a person would see: the canvas drew the
// scene (its pixels are not one colour), and no error reached the console.
// With SCENE.lit.glb, also opens that file in the view, as a person would, and
// checks that it draws by its own embedded lightmap (MOZ_lightmap, RGBM); the
// result's file_against_job is the mean difference between that view and the
// job's own lit view (0-255, over the scene's pixels).
// With PROBES.json (the job's), checks that the job's view shows every one of
// its probes, and opens that file in the view alone: its probes, drawn; then
// the lit glb, whose exposure must be its own lightmap's (the job's, within
// RGBM's rounding), not the probes' before it.
// Saves the lit view to SCREENSHOT.png. Prints one JSON line; exits 1 on any
// failure, 2 on bad use.
import { createRequire } from "node:module";
import path from "node:path";
import { fileURLToPath } from "node:url";

const here = path.dirname(fileURLToPath(import.meta.url));
const require = createRequire(path.join(here, "../../web/package.json"));
const { chromium } = require("playwright-core");

const [url, token, job, screenshot, litGlb, probesJson] = process.argv.slice(2);
const fs = await import("node:fs");
const probeCount = probesJson ? JSON.parse(fs.readFileSync(probesJson, "utf8")).probes.length : 0;
if (!screenshot) {
  console.error("usage: node tests/web/status_page_3d.mjs URL TOKEN JOB_ID SCREENSHOT.png");
  process.exit(2);
}

const problems = [];
const browser = await chromium.launch({
  executablePath: process.env.LIGHTFARM_CHROMIUM || "/usr/bin/chromium",
  // No GPU here: WebGL on SwiftShader. No background traffic to the outside.
  args: ["--no-sandbox", "--disable-gpu", "--use-angle=swiftshader", "--enable-unsafe-swiftshader",
         "--disable-background-networking", "--disable-component-update", "--disable-sync", "--no-first-run"],
});
const result = { job };
try {
  const page = await browser.newPage({ viewport: { width: 1280, height: 1400 } });
  page.on("console", (m) => { if (m.type() === "error") problems.push(`console: ${m.text()} (${m.location().url})`); });
  page.on("pageerror", (e) => problems.push("page error: " + e.message));
  page.on("response", (r) => { if (r.status() >= 400) problems.push(`HTTP ${r.status()}: ${r.url()}`); });
  page.on("requestfailed", (r) => problems.push("request failed: " + r.url() + " " + r.failure()?.errorText));

  await page.goto(`${url}/?token=${encodeURIComponent(token)}`);  // sets the cookie, redirects to /
  // The 12-character id the page shows selects the job (it needed all 24).
  await page.goto(`${url}/#job=${job.slice(0, 12)}`);
  await page.reload();  // the hash alone does not reload the page

  const drawn = async (mode, file = null, after = 0) => {
    // Polled with evaluate(), not waitForFunction(): the page's
    // Content-Security-Policy forbids eval, which waitForFunction's poller uses.
    for (const deadline = Date.now() + 90_000; ; await new Promise((r) => setTimeout(r, 100))) {
      const done = await page.evaluate(([m, f, n]) => {
        const v = window.lightfarmView;
        return !!v && !!(v.state.error || (v.state.ready && v.state.mode === m && v.state.file === f && v.state.frames > n));
      }, [mode, file, after]);
      if (done) break;
      if (Date.now() > deadline) throw new Error(`3D view: not drawn in mode ${mode} within 90 s`);
    }
    const state = await page.evaluate(() => ({ ...window.lightfarmView.state }));
    if (state.error) throw new Error("3D view: " + state.error);
    if (!file && state.job !== job) throw new Error(`3D view: shows job ${state.job}, not ${job}`);
    // The canvas's pixels (preserveDrawingBuffer): how many distinct colours.
    const name = file ? (file.endsWith(".json") ? "probes_file" : "file") : mode;
    const pixels = await page.evaluate((name) => {
      const gl = document.querySelector("#view3d-canvas canvas");
      const c = document.createElement("canvas");
      c.width = gl.width;
      c.height = gl.height;
      const ctx = c.getContext("2d");
      ctx.drawImage(gl, 0, 0);
      const data = ctx.getImageData(0, 0, c.width, c.height).data;
      const colours = new Set();
      let background = 0;
      for (let i = 0; i < data.length; i += 4) {
        colours.add((data[i] >> 2) << 12 | (data[i + 1] >> 2) << 6 | data[i + 2] >> 2);
        if (data[i] === 0x30 && data[i + 1] === 0x30 && data[i + 2] === 0x30) background++;
      }
      (window.canvases = window.canvases || {})[name] = data;  // kept for file_against_job
      return { distinct: colours.size, scene_fraction: 1 - background / (data.length / 4) };
    }, name);
    result[name] = { pass: state.pass, frames: state.frames, probes: state.probes, exposure: state.exposure, ...pixels };
    if (probeCount && name !== "file" && state.probes !== probeCount)
      problems.push(`${name}: ${state.probes} probes shown, not ${probeCount}`);
    if (pixels.distinct < 16) problems.push(`${name}: the canvas has ${pixels.distinct} colours`);
    // A few probes alone are small spheres in a large frame.
    const least = name === "probes_file" ? 0.01 : 0.05;
    if (pixels.scene_fraction < least) problems.push(`${name}: the scene covers ${pixels.scene_fraction} of the canvas`);
  };

  await drawn("lit");
  for (const mode of ["lightmap", "error", "lit"]) {
    await page.check(`input[name=view3d-mode][value=${mode}]`);
    await drawn(mode);
  }
  await page.locator("#view3d-canvas canvas").screenshot({ path: screenshot });
  // Probes first, then the lit glb: each sets its own exposure, the glb's
  // from its embedded lightmap, the same bake's as the job's (the view kept
  // the previous one's, issue #36).
  const open = async (file) => {
    const before = await page.evaluate(() => window.lightfarmView.state.frames);
    await page.setInputFiles("#view3d-file", file);
    await drawn("lit", path.basename(file), before);
  };
  if (probesJson) await open(probesJson);
  if (litGlb) {
    await open(litGlb);
    const own = result.file.exposure / result.lit.exposure;
    if (!(Math.abs(own - 1) < 0.05))
      problems.push(`file: exposure ${result.file.exposure}, the job's own ${result.lit.exposure}`);
    // The job's lit view (its lightmap from the service) against the same
    // bake's scene.lit.glb opened from disk, from the same camera: the mean
    // absolute difference of the pixels either shows as the scene (0-255).
    result.file_against_job = await page.evaluate(() => {
      const a = window.canvases.lit, b = window.canvases.file;
      let sum = 0, count = 0;
      for (let i = 0; i < a.length; i += 4) {
        const bg = (d) => d[i] === 0x30 && d[i + 1] === 0x30 && d[i + 2] === 0x30;
        if (bg(a) && bg(b)) continue;
        for (let c = 0; c < 3; c++) sum += Math.abs(a[i + c] - b[i + c]);
        count += 3;
      }
      return count ? sum / count : 0;
    });
  }
} catch (e) {
  problems.push(e.message);
} finally {
  await browser.close();
}
result.problems = problems;
console.log(JSON.stringify(result));
process.exit(problems.length ? 1 : 0);
