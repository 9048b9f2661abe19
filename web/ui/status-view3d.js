// The status page's 3D view (status.html), served at /ui/status-view3d.js; a
// module, to import three.js by the names the page's import map gives it.
// Shows the selected job's scene.lightmapped.glb (written before the first
// pass) lit by its latest lightmap, RGBM-decoded in the shader (value =
// range * rgb * a, README "scene.lit.glb"), or that lightmap on white, or the
// per-texel error; and the job's probes. window.lightfarmView.state is what a
// test reads: the job and pass shown, frames drawn, probes shown, and any error.
const status = document.getElementById("view3d-status");
const state = { job: null, pass: null, mode: "lit", frames: 0, ready: false, error: null, file: null, probes: 0,
                exposure: 1 };
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
  // A bake of several atlas pages: each primitive's TEXCOORD_1 is on its
  // page, and a job's lightmap and error map hold every page stacked; the
  // primitive's extras say where its page lies in them (v = offset + scale
  // x its v). A scene.lit.glb opened from disk has each page's lightmap on
  // that page's materials.
  const pageTextures = new Map();
  const onPage = (texture, geometry) => {
    const stacked = geometry.userData.lightfarm_lightmap_stacked_v;
    if (!stacked || !texture) return texture;
    const key = texture.uuid + stacked.join(",");
    if (!pageTextures.has(key)) {
      const page = texture.clone();
      page.offset.set(0, stacked[0]);
      page.repeat.set(1, stacked[1]);
      page.needsUpdate = true;  // a clone is a texture of its own to upload (of the same image)
      pageTextures.set(key, page);
    }
    return pageTextures.get(key);
  };
  const lightmapOn = (material, node) => {
    material.lightMap = originals.get(node).lightMap || onPage(lightmap, node.geometry);
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
      // A mesh left out of the lightmap (lightmap scale 0; its primitive's extras say so): its own material.
      if (node.geometry.userData.lightfarm_no_lightmap || (state.mode === "error" && !errorMap)) node.material = original;
      else if (state.mode === "lit") node.material = lightmapOn(original.clone(), node);
      else if (state.mode === "lightmap") node.material = Object.assign(lightmapOn(white.clone(), node), { side: original.side });
      else node.material = new THREE.MeshBasicMaterial({ map: onPage(errorMap, node.geometry), side: original.side });
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

  // Probes (issue #34): small spheres at their reference points, each shaded
  // by the irradiance / pi its own capture gives there for every normal
  // (its SH9 convolved with the clamped cosine: Ramamoorthi & Hanrahan's
  // A_l / pi = 1, 2/3, 1/4, as gi/probes/probe_eval.cpp's
  // sh9_irradiance_over_pi), so a person sees placement and leaks at a
  // glance; a dropped probe (inside geometry, far from everything) is dark red.
  let probeGroup = null;
  const shBasis = (x, y, z) => [0.28209479177387814, 0.4886025119029199 * x, 0.4886025119029199 * y,
    0.4886025119029199 * z, 1.0925484305920792 * z * x, 1.0925484305920792 * x * y,
    0.31539156525252005 * (3 * y * y - 1), 1.0925484305920792 * z * y, 0.5462742152960396 * (z * z - x * x)];
  const shBand = [1, 2 / 3, 2 / 3, 2 / 3, 0.25, 0.25, 0.25, 0.25, 0.25];
  function showProbes(doc, radius) {
    if (probeGroup) {
      world.remove(probeGroup);
      probeGroup.traverse((o) => { if (o.isMesh) { o.geometry.dispose(); o.material.dispose(); } });
      probeGroup = null;
    }
    state.probes = 0;
    if (!doc) return;
    if (doc.format !== "lightfarm.probes" || !Array.isArray(doc.probes)) throw new Error("not a lightfarm probes.json");
    probeGroup = new THREE.Group();
    for (const p of doc.probes) {
      const geometry = new THREE.IcosahedronGeometry(radius, 2);
      const normal = geometry.attributes.normal, colour = new Float32Array(3 * normal.count);
      for (let v = 0; v < normal.count; ++v) {
        const y = shBasis(normal.getX(v), normal.getY(v), normal.getZ(v));
        for (let c = 0; c < 3; ++c) {
          let e = 0;
          for (let k = 0; k < 9; ++k) e += p.sh9[k][c] * shBand[k] * y[k];
          colour[3 * v + c] = p.valid ? Math.max(e, 0) : [0.25, 0, 0][c];
        }
      }
      geometry.setAttribute("color", new THREE.BufferAttribute(colour, 3));
      const sphere = new THREE.Mesh(geometry, new THREE.MeshBasicMaterial({ vertexColors: true }));
      sphere.position.set(p.position[0], p.position[1], p.position[2]);
      probeGroup.add(sphere);
    }
    world.add(probeGroup);
    state.probes = doc.probes.length;
  }
  // The exposure the server's previews use (protocol/display_tone.h,
  // automatic_exposure): the geometric mean luminance of the lit values
  // (above 1e-4 of the brightest) brought to 0.18. What is shown sets its own: a job's from the server, a
  // file's or a probe set's from its own values (a file kept the previous
  // job's, issue #36).
  function setExposure(values) {
    const luminance = (i) => 0.2126 * values[i] + 0.7152 * values[i + 1] + 0.0722 * values[i + 2];
    let brightest = 0;
    for (let i = 0; i + 2 < values.length; i += 3) if (Number.isFinite(luminance(i))) brightest = Math.max(brightest, luminance(i));
    const least = Math.max(1e-8, 1e-4 * brightest);  // display_tone.h, kExposureFloor
    let logSum = 0, lit = 0;
    for (let i = 0; i + 2 < values.length; i += 3) {
      const lum = luminance(i);
      if (Number.isFinite(lum) && lum > least) { logSum += Math.log(lum); lit++; }
    }
    state.exposure = lit ? 0.18 / Math.exp(logSum / lit) : 1;
    renderer.toneMappingExposure = state.exposure;
  }
  // A probe set's values: each valid probe's mean radiance (its SH9's band 0).
  const probeValues = (doc) => doc.probes.filter((p) => p.valid).flatMap((p) => p.sh9[0].map((c) => c * 0.28209479177387814));
  // An RGBM lightmap's values (range x rgb x a), read back through a canvas.
  function lightmapValues(texture, scale) {
    const image = texture.image, canvas = document.createElement("canvas");
    canvas.width = image.width;
    canvas.height = image.height;
    const context = canvas.getContext("2d");
    context.drawImage(image, 0, 0);
    const data = context.getImageData(0, 0, canvas.width, canvas.height).data, out = [];
    for (let i = 0; i < data.length; i += 4)
      if (data[i + 3] > 0) for (let c = 0; c < 3; ++c) out.push(scale * (data[i + c] / 255) * (data[i + 3] / 255));
    return out;
  }
  const sizeOf = (object) => new THREE.Box3().setFromObject(object).getSize(new THREE.Vector3()).length() || 1;
  // The job's newest probe set: probes.json once it ends, else its newest snapshot's.
  async function jobProbes(job) {
    const latest = job.latest && job.latest.probes;
    if (!latest) return null;
    const name = job.state === "succeeded" ? "probes.json" : latest.file.replace(/\.exr$/, ".json");
    const r = await fetch(job.links.artifacts + "/" + name, { credentials: "same-origin", cache: "no-cache" });
    if (!r.ok) throw new Error(name + ": " + r.status + " " + r.statusText);
    return r.json();
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
    const probes = await jobProbes(job);
    // The light the view lays on the scene: the lightmap, else the ambient
    // occlusion (the server's RGBM and error map follow the same order).
    const image = job.latest.lightmap || job.latest.ao;
    if (!image) {  // probes alone: no atlas, no scene to show them in
      showProbesAlone(probes);
      state.job = job.id;
      status.textContent = state.probes + " probes · drag to orbit, scroll to zoom";
      state.error = null;
      state.ready = true;
      return;
    }
    const pass = image.pass;
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
      for (const page of pageTextures.values()) page.dispose();  // clones of the old ones (their own uploads)
      pageTextures.clear();
      lightmap = rgbm.texture;
      errorMap = error.texture;
      range = Number(rgbm.headers.get("X-Lightfarm-Rgbm-Range")) || 1;
      state.exposure = Number(rgbm.headers.get("X-Lightfarm-Exposure")) || 1;
      renderer.toneMappingExposure = state.exposure;
      state.pass = Number(rgbm.headers.get("X-Lightfarm-Pass"));
      applyMode();
    }
    if (probes || probeGroup) {
      showProbes(probes, sizeOf(model) / 120);
      draw();
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
  // Probes with no scene to show them in (a probes-only job, a probes.json
  // opened from disk): spheres sized by their spread (the first call only
  // measures it), the view framed on them, exposure from their values.
  function showProbesAlone(doc) {
    if (model) world.remove(model);
    model = null;
    showProbes(doc, 0.01);
    showProbes(doc, sizeOf(probeGroup) / 12 || 0.05);
    setExposure(probeValues(doc));
    frame({ scene: probeGroup });
    state.pass = null;
    draw();
  }
  async function openProbes(file) {
    showProbesAlone(JSON.parse(await file.text()));
    state.file = file.name;
    state.job = null;
    status.textContent = file.name + ": " + state.probes + " probes · click a job to go back";
  }
  async function openFile(file) {
    if (file.name.endsWith(".json")) return openProbes(file);
    status.textContent = "opening " + file.name + "…";
    let plugin = null;
    const loader = new GLTFLoader().register((parser) => (plugin = new MozLightmap(parser)));
    const gltf = await loader.parseAsync(await file.arrayBuffer(), "");
    if (!plugin || !plugin.found) throw new Error(file.name + " has no MOZ_lightmap: not a scene.lit.glb");
    const extras = plugin.found.extras || {};
    if (extras.encoding !== "RGBM") throw new Error(file.name + ": lightmap encoding " + extras.encoding + ", not RGBM");
    showProbes(null, 0);
    if (model) world.remove(model);
    model = gltf.scene;
    originals = new Map();
    lightmap = null;
    // A bake on atlas pages: each page's materials have that page's lightmap
    // (the loader's copies of one texture share its image).
    const pages = new Map();
    model.traverse((node) => {
      if (!node.isMesh) return;
      originals.set(node, node.material);
      if (!node.material.lightMap) return;
      lightmap = node.material.lightMap;
      lightmap.colorSpace = THREE.NoColorSpace;
      pages.set(lightmap.image, lightmap);
    });
    if (errorMap) errorMap.dispose();
    errorMap = null;
    range = (plugin.found.intensity / Math.PI) * extras.rgbm_range;  // lightmapOn multiplies by pi
    setExposure([...pages.values()].flatMap((page) => lightmapValues(page, range)));  // every page's, as the job's
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
    if (!job.latest || (!job.latest.lightmap && !job.latest.ao && !job.latest.probes)) {
      status.textContent = "No lightmap, ambient occlusion or probes snapshot yet.";
      return;
    }
    if (loading) return;  // the next refresh (2 s) catches up
    loading = load(job).catch((e) => { state.error = e.message; status.textContent = "3D view: " + e.message; })
                       .finally(() => { loading = null; });
  };
  if (window.lightfarmPendingJob) view.show(window.lightfarmPendingJob);
}
