// GET /: a read-only page with the token's jobs (scene, times, progress, a
// failure's cause), the selected job's files, its latest preview and a 3D view
// of the scene lit by the latest snapshot (three.js, served by lightfarmd from
// web/node_modules: nothing is fetched from elsewhere). It authenticates with the lightfarm_token cookie that GET
// /?token=T sets, because <img> and fetch from a page cannot be given a bearer header by a person typing a URL.
#pragma once

namespace lf::server {

inline constexpr const char* kStatusPage = R"html(<!doctype html>
<html lang="en">
<head>
<meta charset="utf-8">
<title>lightfarm</title>
<link rel="icon" href="data:,">
<style>
  body { font: 14px/1.4 system-ui, sans-serif; margin: 2em; color: #222; }
  table { border-collapse: collapse; }
  th, td { padding: 4px 10px; border-bottom: 1px solid #ddd; text-align: left; vertical-align: top; }
  tr.job { cursor: pointer; }
  tr.selected { background: #eef; }
  tr.cause td { color: #b00; border-bottom: 1px solid #ddd; padding-top: 0; }
  .bar { width: 120px; height: 8px; background: #ddd; display: inline-block; margin-right: 6px; }
  .bar > div { height: 8px; background: #4a7; }
  #preview img { max-width: 512px; image-rendering: pixelated; border: 1px solid #ccc; }
  .failed { color: #b00; } .succeeded { color: #070; }
  .muted { color: #777; }
  #view3d canvas { border: 1px solid #ccc; display: block; }
  #view3d-legend { display: none; font-size: 12px; }
  #view3d-legend .scale { width: 320px; height: 10px;
    background: linear-gradient(to right, rgb(89,124,240), rgb(0,218,231), rgb(124,231,124), rgb(250,239,89), rgb(240,89,89)); }
  #view3d-legend .ticks { width: 320px; display: flex; justify-content: space-between; }
</style>
<script type="importmap">
{ "imports": { "three": "/ui/three/build/three.module.js", "three/addons/": "/ui/three/examples/jsm/" } }
</script>
</head>
<body>
<h1>lightfarm</h1>
<p id="note"></p>
<table id="jobs">
  <thead><tr><th>job</th><th>scene</th><th>state</th><th>submitted</th><th>started</th><th>finished</th>
  <th>pass</th><th>error estimate</th><th>progress</th><th>ETA</th><th>attempts</th></tr></thead>
  <tbody></tbody>
</table>
<h2>Job <span id="selected-job"></span></h2>
<div id="files"></div>
<div id="view3d">
  <p>
    <label><input type="radio" name="view3d-mode" value="lit" checked> lit</label>
    <label><input type="radio" name="view3d-mode" value="lightmap"> lightmap only</label>
    <label><input type="radio" name="view3d-mode" value="error"> per-texel error</label>
    <label>· or open a <code>scene.lit.glb</code>: <input type="file" id="view3d-file" accept=".glb"></label>
    <span id="view3d-status" class="muted"></span>
  </p>
  <div id="view3d-canvas"></div>
  <div id="view3d-legend"><div class="scale"></div>
    <div class="ticks"><span>0.1%</span><span>1%</span><span>10%</span><span>100% relative standard error</span></div></div>
</div>
<div id="preview"></div>
<script>
"use strict";
// The jobs as the server had them when it sent this page (GET /v1/jobs's
// body), so they show at once; then refreshed every 2 s.
const initial = /*JOBS*/null;
// #job=ID selects a job (a link to one job's view).
let selected = new URLSearchParams(location.hash.slice(1)).get("job"), shownFilesOf = null;

function cell(row, text) {
  const td = document.createElement("td");
  td.textContent = text;
  row.appendChild(td);
  return td;
}

function fmt(x, digits) { return x === null || x === undefined ? "–" : Number(x).toFixed(digits); }
function when(t) { return t ? new Date(t * 1000).toLocaleString() : "–"; }

// How far the job is, preparation included: the server's fraction, from its
// ETA, which takes every stop (passes, time, target error) into account.
function fraction(job) {
  if (job.state === "succeeded") return 1;
  return job.progress.fraction || 0;
}

function scene(job) {
  if (!job.scene_name) return job.scene.slice(0, 12);
  return job.scene_name + (job.scene_triangles ? " (" + job.scene_triangles.toLocaleString() + " triangles)" : "");
}

function render(jobs) {
  document.getElementById("note").textContent = jobs.length ? "" : "No jobs yet.";
  if (jobs.length && !jobs.some(j => j.id === selected)) selected = jobs[0].id;
  const body = document.querySelector("#jobs tbody");
  body.replaceChildren();
  for (const job of jobs) {
    const row = document.createElement("tr");
    row.className = "job" + (job.id === selected ? " selected" : "");
    row.onclick = () => {
      selected = job.id;
      shownFilesOf = null;
      if (window.lightfarmView) window.lightfarmView.state.file = null;  // back from an opened file
      render(jobs);
    };
    cell(row, job.id.slice(0, 12)).title = job.id;
    cell(row, scene(job));
    cell(row, job.state).className = job.state;
    cell(row, when(job.created_at));
    cell(row, when(job.started_at));
    cell(row, when(job.finished_at));
    cell(row, job.progress.pass);
    cell(row, fmt(job.progress.error_estimate, 4));
    const percent = Math.round(100 * fraction(job));
    const bar = document.createElement("div");
    bar.className = "bar";
    const fill = document.createElement("div");
    fill.style.width = percent + "%";
    bar.appendChild(fill);
    const preparing = job.state === "running" && !job.progress.pass;  // load, atlas, BVH: no ETA yet
    const progress = cell(row, preparing ? "preparing" : percent + "%");
    progress.prepend(bar);
    cell(row, job.progress.eta_seconds === null || job.progress.eta_seconds === undefined ? "–"
                                                                                     : fmt(job.progress.eta_seconds, 0) + " s");
    cell(row, job.attempts + " / " + job.max_attempts);
    body.appendChild(row);
    if (job.state === "failed") {  // the cause in plain sight, under its job
      const cause = document.createElement("tr");
      cause.className = "cause";
      const td = cell(cause, job.error + (job.cause ? ": " + job.cause : ""));
      td.colSpan = 11;
      body.appendChild(cause);
    }
  }
  const job = jobs.find(j => j.id === selected);
  if (job) show(job);
}

// The selected job: links to every file it has, and its preview where a
// snapshot exists (no broken image for a job that has none).
async function show(job) {
  document.getElementById("selected-job").textContent = job.id.slice(0, 12) + " · " + scene(job);
  // The 3D view (the module script below) once it has loaded, else when it does.
  if (window.lightfarmView) window.lightfarmView.show(job); else window.lightfarmPendingJob = job;
  const preview = document.getElementById("preview");
  const hasImage = job.latest && job.latest.lightmap;
  if (hasImage) {
    let img = preview.querySelector("img");
    if (!img) { img = document.createElement("img"); img.alt = "preview"; preview.replaceChildren(img); }
    img.src = job.links.preview + "?pass=" + job.latest.lightmap.pass;
  } else {
    preview.replaceChildren();
    const p = document.createElement("p");
    p.className = "muted";
    p.textContent = "No lightmap snapshot yet.";
    preview.appendChild(p);
  }
  const key = job.id + ":" + job.state + ":" + JSON.stringify(job.latest || {});
  if (shownFilesOf === key) return;
  shownFilesOf = key;
  const files = document.getElementById("files");
  try {
    const r = await fetch(job.links.artifacts, { credentials: "same-origin" });
    if (!r.ok) throw new Error(r.statusText);
    const list = (await r.json()).artifacts;
    files.replaceChildren();
    if (!list.length) { files.textContent = "No files yet."; return; }
    const ul = document.createElement("ul");
    for (const a of list) {
      const li = document.createElement("li");
      const link = document.createElement("a");
      link.href = a.url;
      link.textContent = a.name;
      li.appendChild(link);
      if (a.size !== undefined) li.append(" (" + Number(a.size).toLocaleString() + " bytes)");
      ul.appendChild(li);
    }
    files.appendChild(ul);
  } catch (e) {
    files.textContent = "Cannot list the files: " + e.message;
  }
}

async function refresh() {
  try {
    const r = await fetch("/v1/jobs", { credentials: "same-origin" });
    if (!r.ok) throw new Error((await r.json()).error || r.statusText);
    render((await r.json()).jobs);
  } catch (e) {
    document.getElementById("note").textContent = "Cannot read jobs: " + e.message;
  }
}

if (initial) render(initial.jobs);
setInterval(refresh, 2000);
</script>
<script type="module">
// The 3D view: the selected job's scene.lightmapped.glb (written before the
// first pass) lit by its latest lightmap, RGBM-decoded in the shader
// (value = range * rgb * a, README "scene.lit.glb"), or that lightmap on
// white, or the per-texel error. window.lightfarmView.state is what a test
// reads: the job and pass shown, frames drawn, and any error.
const status = document.getElementById("view3d-status");
const state = { job: null, pass: null, mode: "lit", frames: 0, ready: false, error: null, file: null };
let THREE, GLTFLoader, OrbitControls;
try {
  THREE = await import("three");
  ({ GLTFLoader } = await import("three/addons/loaders/GLTFLoader.js"));
  ({ OrbitControls } = await import("three/addons/controls/OrbitControls.js"));
} catch (e) {
  state.error = "three.js is not installed on the server (scripts/run installs it): " + e.message;
  status.textContent = state.error;
}

// three.js's lightMap is irradiance; the texels are E/pi in RGBM, so the
// shader multiplies by the alpha and the intensity carries pi * range. A
// three.js whose lightmap chunk reads otherwise cannot show the bake.
const fromChunk = "lightMapTexel.rgb * lightMapIntensity";
if (THREE && !THREE.ShaderChunk.lights_fragment_maps.includes(fromChunk)) {
  state.error = "this three.js's lightmap shader differs from the one web/package.json pins: cannot decode RGBM";
  status.textContent = state.error;
  THREE = null;
}

const view = { state, show: () => {} };
window.lightfarmView = view;

if (THREE) {
  const width = 720, height = 450;
  const renderer = new THREE.WebGLRenderer({ antialias: true, preserveDrawingBuffer: true });
  renderer.setSize(width, height);
  renderer.toneMapping = THREE.ACESFilmicToneMapping;
  document.getElementById("view3d-canvas").appendChild(renderer.domElement);
  const world = new THREE.Scene();
  world.background = new THREE.Color(0x303030);
  const camera = new THREE.PerspectiveCamera(50, width / height, 0.01, 1000);
  const controls = new OrbitControls(camera, renderer.domElement);
  const draw = () => { renderer.render(world, camera); state.frames++; };
  controls.addEventListener("change", draw);

  let model = null, originals = new Map(), lightmap = null, errorMap = null, range = 1, loading = null;

  const rgbmChunk = THREE.ShaderChunk.lights_fragment_maps.replace(
      fromChunk, "lightMapTexel.rgb * lightMapTexel.a * lightMapIntensity");
  const decodeRgbm = (shader) => {
    shader.fragmentShader = shader.fragmentShader.replace("#include <lights_fragment_maps>", rgbmChunk);
  };
  const lightmapOn = (material) => {
    material.lightMap = lightmap;
    material.lightMapIntensity = Math.PI * range;
    material.metalness = 0;  // the bake is Lambertian
    material.onBeforeCompile = decodeRgbm;
    material.customProgramCacheKey = () => "rgbm";
    material.needsUpdate = true;
    return material;
  };
  const white = new THREE.MeshStandardMaterial({ color: 0xffffff, roughness: 1, metalness: 0 });

  function applyMode() {
    if (!model || !lightmap) return;
    if (state.file && state.mode === "error") status.textContent = "a file has no per-texel error: lit or lightmap only";
    document.getElementById("view3d-legend").style.display = state.mode === "error" ? "block" : "none";
    model.traverse((node) => {
      if (!node.isMesh) return;
      const original = originals.get(node);
      if (node.material !== original) node.material.dispose();  // the last pass's or mode's copy
      if (state.mode === "error" && !errorMap) node.material = original;
      else if (state.mode === "lit") node.material = lightmapOn(original.clone());
      else if (state.mode === "lightmap") node.material = Object.assign(lightmapOn(white.clone()), { side: original.side });
      else node.material = new THREE.MeshBasicMaterial({ map: errorMap, side: original.side });
    });
    draw();
  }
  for (const radio of document.querySelectorAll("input[name=view3d-mode]"))
    radio.onchange = () => { state.mode = radio.value; applyMode(); };

  // Where a person would stand: the file's own camera if it has one (an
  // interior seen from outside is its unlit outer walls), else outside the box.
  function frame(gltf) {
    const box = new THREE.Box3().setFromObject(gltf.scene);
    const size = box.getSize(new THREE.Vector3()).length() || 1;
    camera.near = size / 1000;
    camera.far = size * 10;
    const own = gltf.cameras && gltf.cameras[0];
    if (own) {
      own.updateMatrixWorld(true);
      own.matrixWorld.decompose(camera.position, camera.quaternion, new THREE.Vector3());
      if (own.fov) camera.fov = own.fov;
      const ahead = new THREE.Vector3(0, 0, -1).applyQuaternion(camera.quaternion).multiplyScalar(size * 0.1);
      controls.target.copy(camera.position).add(ahead);
    } else {
      const centre = box.getCenter(new THREE.Vector3());
      camera.position.copy(centre).add(new THREE.Vector3(0.6, 0.4, 0.9).multiplyScalar(size * 0.9));
      controls.target.copy(centre);
    }
    camera.updateProjectionMatrix();
    controls.update();
  }

  async function texture(url) {
    const r = await fetch(url, { credentials: "same-origin", cache: "no-cache" });
    if (!r.ok) throw new Error(url + ": " + r.status + " " + r.statusText);
    // Not premultiplied, no colour conversion: RGBM's alpha is data.
    const bitmap = await createImageBitmap(await r.blob(), { premultiplyAlpha: "none", colorSpaceConversion: "none" });
    const t = new THREE.Texture(bitmap);
    t.flipY = false;  // glTF UVs count rows from the top, as the image does
    t.channel = 1;    // TEXCOORD_1
    t.generateMipmaps = false;
    t.minFilter = THREE.LinearFilter;
    t.needsUpdate = true;
    return { texture: t, headers: r.headers };
  }

  async function load(job) {
    const pass = job.latest.lightmap.pass;
    if (state.job !== job.id) {
      status.textContent = "loading the scene…";
      const gltf = await new GLTFLoader().loadAsync(job.links.artifacts + "/scene.lightmapped.glb");
      if (model) world.remove(model);
      model = gltf.scene;
      originals = new Map();
      model.traverse((node) => { if (node.isMesh) originals.set(node, node.material); });
      world.add(model);
      frame(gltf);
      state.job = job.id;
      state.pass = null;
    }
    if (state.pass !== pass) {
      const [rgbm, error] = await Promise.all([texture(job.links.lightmap_rgbm), texture(job.links.error_map)]);
      rgbm.texture.colorSpace = THREE.NoColorSpace;
      error.texture.colorSpace = THREE.SRGBColorSpace;
      if (lightmap) lightmap.dispose();
      if (errorMap) errorMap.dispose();
      lightmap = rgbm.texture;
      errorMap = error.texture;
      range = Number(rgbm.headers.get("X-Lightfarm-Rgbm-Range")) || 1;
      renderer.toneMappingExposure = Number(rgbm.headers.get("X-Lightfarm-Exposure")) || 1;
      state.pass = Number(rgbm.headers.get("X-Lightfarm-Pass"));
      applyMode();
    }
    status.textContent = "pass " + state.pass + (job.state === "succeeded" ? " (final)" : "") + " · drag to orbit, scroll to zoom";
    state.error = null;  // a failed refresh before this one is behind us
    state.ready = true;
  }

  // A scene.lit.glb opened from disk: its MOZ_lightmap read as the README
  // says (the texture, texCoord, intensity x the RGBM range), shown until a
  // job row is clicked.
  class MozLightmap {
    constructor(parser) { this.parser = parser; this.name = "MOZ_lightmap"; }
    extendMaterialParams(index, params) {
      const ext = (this.parser.json.materials[index].extensions || {}).MOZ_lightmap;
      if (!ext) return Promise.resolve();
      this.found = ext;
      return this.parser.assignTexture(params, "lightMap", { index: ext.index, texCoord: ext.texCoord });
    }
  }
  async function openFile(file) {
    status.textContent = "opening " + file.name + "…";
    let plugin = null;
    const loader = new GLTFLoader().register((parser) => (plugin = new MozLightmap(parser)));
    const gltf = await loader.parseAsync(await file.arrayBuffer(), "");
    if (!plugin || !plugin.found) throw new Error(file.name + " has no MOZ_lightmap: not a scene.lit.glb");
    const extras = plugin.found.extras || {};
    if (extras.encoding !== "RGBM") throw new Error(file.name + ": lightmap encoding " + extras.encoding + ", not RGBM");
    if (model) world.remove(model);
    model = gltf.scene;
    originals = new Map();
    lightmap = null;
    model.traverse((node) => {
      if (!node.isMesh) return;
      originals.set(node, node.material);
      if (node.material.lightMap) lightmap = node.material.lightMap;
    });
    lightmap.colorSpace = THREE.NoColorSpace;
    if (errorMap) errorMap.dispose();
    errorMap = null;
    range = (plugin.found.intensity / Math.PI) * extras.rgbm_range;  // lightmapOn multiplies by pi
    world.add(model);
    frame(gltf);
    state.file = file.name;
    state.job = null;
    state.pass = null;
    applyMode();
    status.textContent = file.name + " (its own lightmap) · drag to orbit, scroll to zoom · click a job to go back";
  }
  document.getElementById("view3d-file").onchange = (e) => {
    const file = e.target.files[0];
    if (file) openFile(file).catch((err) => { state.error = err.message; status.textContent = "3D view: " + err.message; });
  };

  view.show = (job) => {
    if (state.file) return;  // an opened file stays until a job is clicked
    if (!job.latest || !job.latest.lightmap) {
      status.textContent = "No lightmap snapshot yet.";
      return;
    }
    if (loading) return;  // the next refresh (2 s) catches up
    loading = load(job).catch((e) => { state.error = e.message; status.textContent = "3D view: " + e.message; })
                       .finally(() => { loading = null; });
  };
  if (window.lightfarmPendingJob) view.show(window.lightfarmPendingJob);
}
</script>
</body>
</html>
)html";

inline constexpr const char* kLoginPage = R"html(<!doctype html>
<html lang="en">
<head><meta charset="utf-8"><title>lightfarm: token needed</title></head>
<body style="font: 14px system-ui, sans-serif; margin: 2em">
<h1>lightfarm</h1>
<p>This page needs a token (lightfarmd prints where it keeps them when it starts).</p>
<form method="get" action="/">
  <input name="token" type="password" size="70" placeholder="token" autofocus>
  <button>Open</button>
</form>
</body>
</html>
)html";

}  // namespace lf::server
