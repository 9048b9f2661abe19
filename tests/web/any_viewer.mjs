// node tests/web/any_viewer.mjs SCENE.unlit.glb SCENE.lit.glb EXPOSURE OUT_DIR
// Renders one bake twice in a real headless Chromium (Debian's
// /usr/bin/chromium, or $LIGHTFARM_CHROMIUM, driven by playwright-core), from
// the same camera (the box of the scene, seen from -z). Each file is shown
// by what it is: one with MOZ_lightmap as lightfarm's view shows
// scene.lit.glb, any other as a stock viewer would (so two bakes of one
// scene can be compared as either):
//  * scene.unlit.glb as any viewer would: a stock three.js GLTFLoader and a
//    WebGLRenderer with its defaults (no tone mapping, sRGB output), no
//    lights, nothing of lightfarm's;
//  * scene.lit.glb as lightfarm's own 3D view does: MOZ_lightmap read as
//    RGBM (intensity x rgbm_range x rgb x a) into three.js's lightMap on
//    TEXCOORD_1, the file's own materials, ACES filmic tone mapping at
//    EXPOSURE (the lightmap's automatic exposure, protocol/display_tone.h).
// Prints one JSON line: per-pixel absolute differences (0-255, all channels)
// over the pixels either render covers (mean, 99th percentile, max), the
// share of the frame they cover, and the two renders' mean colours; saves
// both renders to OUT_DIR as PNG. Exits 1 on any failure, 2 on bad use.
import http from "node:http";
import { createRequire } from "node:module";
import fs from "node:fs";
import path from "node:path";
import { fileURLToPath } from "node:url";

const here = path.dirname(fileURLToPath(import.meta.url));
const web = path.join(here, "../../web");
const require = createRequire(path.join(web, "package.json"));
const { chromium } = require("playwright-core");

const [unlitGlb, litGlb, exposureText, outDir] = process.argv.slice(2);
if (!outDir || !(Number(exposureText) > 0)) {
  console.error("usage: node tests/web/any_viewer.mjs SCENE.unlit.glb SCENE.lit.glb EXPOSURE OUT_DIR");
  process.exit(2);
}

// Whether a glb carries MOZ_lightmap (its JSON chunk lists the extension).
function isLit(file) {
  const glb = fs.readFileSync(file);
  const json = JSON.parse(glb.subarray(20, 20 + glb.readUInt32LE(12)).toString("utf8"));
  return (json.extensionsUsed || []).includes("MOZ_lightmap");
}

const page = `<!doctype html><html><body style="margin:0;background:#000">
<script type="importmap">{"imports": {"three": "/three/build/three.module.js",
                                      "three/addons/": "/three/examples/jsm/"}}</script>
<script type="module">
import * as THREE from "three";
import { GLTFLoader } from "three/addons/loaders/GLTFLoader.js";
const size = 320;

// The camera both renders share: the scene's box from -z (the Cornell box's
// open side), filling the frame.
function cameraFor(object) {
  const box = new THREE.Box3().setFromObject(object);
  const centre = box.getCenter(new THREE.Vector3()), extent = box.getSize(new THREE.Vector3());
  const camera = new THREE.PerspectiveCamera(40, 1, 0.01, 100);
  const distance = 0.5 * Math.max(extent.x, extent.y) / Math.tan(THREE.MathUtils.degToRad(20)) + 0.5 * extent.z;
  camera.position.set(centre.x, centre.y, centre.z - 1.05 * distance);
  camera.lookAt(centre);
  return camera;
}

function pixels(renderer) {
  const gl = renderer.getContext();
  const data = new Uint8Array(size * size * 4);
  gl.readPixels(0, 0, size, size, gl.RGBA, gl.UNSIGNED_BYTE, data);
  return data;
}

async function render(url, prepare) {
  const canvas = document.createElement("canvas");
  document.body.appendChild(canvas);
  const renderer = new THREE.WebGLRenderer({ canvas, preserveDrawingBuffer: true });
  renderer.setSize(size, size);
  const loader = new GLTFLoader();
  let lightmaps = null;
  if (prepare) loader.register((parser) => (lightmaps = new MozLightmap(parser)));
  const gltf = await loader.loadAsync(url);
  const scene = new THREE.Scene();
  scene.add(gltf.scene);
  if (prepare) await prepare(renderer, gltf, lightmaps);
  renderer.render(scene, cameraFor(gltf.scene));
  return { data: pixels(renderer), png: canvas.toDataURL("image/png") };
}

// MOZ_lightmap as lightfarm's view reads it (README, "Looking at a bake").
class MozLightmap {
  constructor(parser) { this.parser = parser; this.name = "MOZ_lightmap"; this.found = []; }
  async extendMaterialParams(index, params) {
    const ext = (this.parser.json.materials[index].extensions || {}).MOZ_lightmap;
    if (!ext) return;
    const texture = await this.parser.getDependency("texture", ext.index);
    texture.colorSpace = THREE.NoColorSpace;  // RGBM is linear data
    texture.channel = ext.texCoord;
    params.lightMap = texture;
    params.lightMapIntensity = ext.intensity * ext.extras.rgbm_range;
    this.found.push(ext);
  }
}

// lightfarm's view of a scene.lit.glb: its lightmaps read as RGBM, tone-mapped.
const asLightfarmsView = async (renderer, gltf, lightmaps) => {
    if (!lightmaps.found.length) throw new Error("lit.glb: no MOZ_lightmap");
    renderer.toneMapping = THREE.ACESFilmicToneMapping;
    renderer.toneMappingExposure = ${Number(exposureText)};
    // RGBM: the lightmap chunk multiplied by the alpha, as the view does.
    const fromChunk = "lightMapTexel.rgb * lightMapIntensity";
    if (!THREE.ShaderChunk.lights_fragment_maps.includes(fromChunk)) throw new Error("three.js's lightmap chunk changed");
    const rgbmChunk = THREE.ShaderChunk.lights_fragment_maps.replace(
      fromChunk, "lightMapTexel.rgb * lightMapTexel.a * lightMapIntensity");
    gltf.scene.traverse((node) => {
      if (!node.isMesh || !node.material.lightMap) return;
      node.material.metalness = 0;  // the bake is Lambertian
      node.material.onBeforeCompile = (shader) => {
        shader.fragmentShader = shader.fragmentShader.replace("#include <lights_fragment_maps>", rgbmChunk);
      };
      node.material.customProgramCacheKey = () => "rgbm";
      node.material.needsUpdate = true;
    });
};

window.result = (async () => {
  const unlit = await render("/unlit.glb", ${isLit(unlitGlb)} ? asLightfarmsView : null);
  const lit = await render("/lit.glb", ${isLit(litGlb)} ? asLightfarmsView : null);
  const diffs = [];
  let covered = 0;
  const mean = { unlit: [0, 0, 0], lit: [0, 0, 0] };
  for (let i = 0; i < unlit.data.length; i += 4) {
    const seen = [0, 1, 2].some((c) => unlit.data[i + c] > 0 || lit.data[i + c] > 0);
    if (!seen) continue;
    covered++;
    for (let c = 0; c < 3; c++) {
      diffs.push(Math.abs(unlit.data[i + c] - lit.data[i + c]));
      mean.unlit[c] += unlit.data[i + c];
      mean.lit[c] += lit.data[i + c];
    }
  }
  diffs.sort((a, b) => a - b);
  for (const k of ["unlit", "lit"]) mean[k] = mean[k].map((v) => v / Math.max(covered, 1));
  return {
    covered_fraction: covered / (size * size),
    mean_difference: diffs.reduce((s, d) => s + d, 0) / Math.max(diffs.length, 1),
    p99_difference: diffs.length ? diffs[Math.floor(0.99 * (diffs.length - 1))] : 0,
    max_difference: diffs.length ? diffs[diffs.length - 1] : 0,
    mean_colour: mean,
    pngs: { unlit: unlit.png, lit: lit.png },
  };
})();
</script></body></html>`;

// Serves the page, three.js from the npm install, and the two files.
const files = { "/unlit.glb": unlitGlb, "/lit.glb": litGlb };
const server = http.createServer((req, res) => {
  const url = decodeURIComponent(req.url.split("?")[0]);
  let file = files[url];
  if (!file && url.startsWith("/three/") && !url.includes("..")) file = path.join(web, "node_modules", url.slice(1));
  if (url === "/favicon.ico") {
    res.writeHead(204);
    res.end();
  } else if (url === "/") {
    res.writeHead(200, { "Content-Type": "text/html" });
    res.end(page);
  } else if (file && fs.existsSync(file)) {
    const type = file.endsWith(".js") ? "text/javascript" : "model/gltf-binary";
    res.writeHead(200, { "Content-Type": type });
    fs.createReadStream(file).pipe(res);
  } else {
    res.writeHead(404);
    res.end();
  }
});
await new Promise((r) => server.listen(0, "127.0.0.1", r));

const problems = [];
const browser = await chromium.launch({
  executablePath: process.env.LIGHTFARM_CHROMIUM || "/usr/bin/chromium",
  args: ["--no-sandbox", "--disable-gpu", "--use-angle=swiftshader", "--enable-unsafe-swiftshader",
         "--disable-background-networking", "--disable-component-update", "--disable-sync", "--no-first-run"],
});
let status = 0;
try {
  const tab = await browser.newPage();
  tab.on("console", (m) => { if (m.type() === "error") problems.push(`console: ${m.text()}`); });
  tab.on("pageerror", (e) => problems.push("page error: " + e.message));
  await tab.goto(`http://127.0.0.1:${server.address().port}/`);
  const result = await tab.evaluate(() => window.result);
  fs.mkdirSync(outDir, { recursive: true });
  for (const [name, url] of Object.entries(result.pngs))
    fs.writeFileSync(path.join(outDir, `${name}.png`), Buffer.from(url.split(",")[1], "base64"));
  delete result.pngs;
  if (problems.length) throw new Error(problems.join("; "));
  console.log(JSON.stringify(result));
} catch (e) {
  console.log(JSON.stringify({ error: String(e.message || e), problems }));
  status = 1;
} finally {
  await browser.close();
  server.close();
}
process.exit(status);
