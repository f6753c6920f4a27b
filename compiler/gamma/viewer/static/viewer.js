// The `gammac watch` page: the weathered scene in 3D (three.js, orbit and
// zoom), a switch between the appearance and each property (false colour
// with its colour bar and the run's range), an iteration slider, the run's
// numbers and compile errors, and a brush that paints the images the effect
// reads with mask() (saved beside the effect, which then runs again).  The
// server tells the page about every new
// result over server-sent events (/api/events); the page then fetches the
// state (/api/state), the mesh when it changed (/api/mesh) and the per-vertex
// values of the shown iteration (/api/frame).
import * as THREE from "three";
import { OrbitControls } from "three/addons/controls/OrbitControls.js";

const $ = (id) => document.getElementById(id);
const LOOK_FLOATS = 6;   // per vertex in a frame before the properties: r, g, b, roughness, metallic, occlusion

// matplotlib's viridis, the polynomial fit the PNG renders use (outputs.py)
const VIRIDIS = [
  [0.2777273272234177, 0.005407344544966578, 0.3340998053353061],
  [0.1050930431085774, 1.404613529898575, 1.384590162594685],
  [-0.3308618287255563, 0.214847559468213, 0.09509516302823659],
  [-4.634230498983486, -5.799100973351585, -19.33244095627987],
  [6.228269936347081, 14.17993336680509, 56.69055260068105],
  [4.776384997670288, -13.74514537774601, -65.35303263337234],
  [-5.435455855934631, 4.645852612178535, 26.3124352495832],
];
function viridis(t, out, k) {
  t = Math.min(1, Math.max(0, t));
  for (let c = 0; c < 3; c++) {
    let v = VIRIDIS[6][c];
    for (let i = 5; i >= 0; i--) v = VIRIDIS[i][c] + t * v;
    out[k + c] = Math.min(1, Math.max(0, v));
  }
}

// ---- three.js scene -------------------------------------------------------
const container = $("view");
const renderer = new THREE.WebGLRenderer({ antialias: true, preserveDrawingBuffer: true, alpha: true });
renderer.setPixelRatio(window.devicePixelRatio);
container.appendChild(renderer.domElement);
const scene = new THREE.Scene();
const camera = new THREE.PerspectiveCamera(30, 1, 0.01, 100);
const controls = new OrbitControls(camera, renderer.domElement);
controls.addEventListener("change", draw);
const sun = new THREE.DirectionalLight(0xffffff, 1.6);
scene.add(sun);

// The sky light: an environment (image-based lighting) instead of a
// hemisphere light, so metals have something to reflect.  A small
// equirectangular picture in linear radiance, +Y up (turned to the scene's up
// in loadMesh): a sky brighter towards the horizon, a darker ground, a sharp
// horizon and two soft bright panels for highlights.  Its irradiance matches
// the old HemisphereLight(white, grey, 1.6) within a few per cent (sky 1.56,
// side 1.1-1.16, ground 0.78 against 1.6, 1.2, 0.8), so rough dielectrics
// (and the false-colour views) keep their diffuse shading; they gain a faint
// sky sheen, as in the renderer's pictures.  The PMREM conversion compiles a
// GGX shader once per page: instant on a GPU, about 9 s under SwiftShader.
function skyEnvironment(width = 256, height = 128) {
  const panels = [[45, 30, 3.0, 0.12], [25, -120, 2.0, 0.15]].map(([el, az, k, sigma]) => {
    const e = (el * Math.PI) / 180, a = (az * Math.PI) / 180;
    return { d: [Math.cos(e) * Math.cos(a), Math.sin(e), Math.cos(e) * Math.sin(a)], k, s2: 2 * sigma * sigma };
  });
  const data = new Uint16Array(4 * width * height);   // half floats: filterable everywhere (float32 is not)
  const one = THREE.DataUtils.toHalfFloat(1);
  for (let j = 0; j < height; j++) {
    const e = ((j + 0.5) / height) * Math.PI - Math.PI / 2, s = Math.sin(e), c = Math.cos(e);
    for (let i = 0; i < width; i++) {
      const a = ((i + 0.5) / width - 0.5) * 2 * Math.PI;
      const d = [c * Math.cos(a), s, c * Math.sin(a)];
      let radiance = s > 0 ? 0.5 - 0.15 * s : 0.25;
      for (const p of panels) {
        const angle = Math.acos(Math.min(1, Math.max(-1, d[0] * p.d[0] + d[1] * p.d[1] + d[2] * p.d[2])));
        radiance += p.k * Math.exp(-(angle * angle) / p.s2);
      }
      const k = 4 * (j * width + i);
      data[k] = data[k + 1] = data[k + 2] = THREE.DataUtils.toHalfFloat(radiance);
      data[k + 3] = one;
    }
  }
  const texture = new THREE.DataTexture(data, width, height, THREE.RGBAFormat, THREE.HalfFloatType);
  texture.mapping = THREE.EquirectangularReflectionMapping;
  texture.magFilter = texture.minFilter = THREE.LinearFilter;
  texture.needsUpdate = true;
  const pmrem = new THREE.PMREMGenerator(renderer);
  const target = pmrem.fromEquirectangular(texture);
  pmrem.dispose();
  texture.dispose();
  return target.texture;
}
scene.environment = skyEnvironment();

// MeshStandardMaterial with the look per vertex: the colour attribute, and
// `pbr` = (roughness, metallic, occlusion) replacing the material's
// roughness and metalness and multiplying the ambient (sky) light, as the
// renderer's occlusion does (SPEC §8a).  Chunk names of three.js r187.
const material = new THREE.MeshStandardMaterial({ vertexColors: true, roughness: 0.85, metalness: 0 });
material.onBeforeCompile = (shader) => {
  shader.vertexShader = shader.vertexShader
    .replace("#include <common>", "#include <common>\nattribute vec3 pbr;\nvarying vec3 vPbr;")
    .replace("#include <begin_vertex>", "#include <begin_vertex>\n\tvPbr = clamp( pbr, 0.0, 1.0 );");
  shader.fragmentShader = shader.fragmentShader
    .replace("#include <common>", "#include <common>\nvarying vec3 vPbr;")
    .replace("#include <roughnessmap_fragment>", "float roughnessFactor = vPbr.x;")
    .replace("#include <metalnessmap_fragment>", "float metalnessFactor = vPbr.y;")
    .replace("#include <aomap_fragment>", `#include <aomap_fragment>
	{
		float lookOcclusion = vPbr.z;
		reflectedLight.indirectDiffuse *= lookOcclusion;
		#if defined( USE_ENVMAP )
			float lookDotNV = saturate( dot( geometryNormal, geometryViewDir ) );
			reflectedLight.indirectSpecular *= computeSpecularOcclusion( lookDotNV, lookOcclusion, material.roughness );
		#endif
	}`);
};
const FALSE_COLOUR_PBR = [0.85, 0, 1];   // a matte dielectric, unoccluded: the property views
let mesh = null;

function resize() {
  const w = container.clientWidth, h = container.clientHeight;
  renderer.setSize(w, h);
  camera.aspect = w / Math.max(1, h);
  camera.updateProjectionMatrix();
  draw();
}
window.addEventListener("resize", resize);

function draw() {
  sun.position.copy(camera.position).add(camera.up.clone().multiplyScalar(camera.position.length()));
  renderer.render(scene, camera);
}

// ---- state ----------------------------------------------------------------
const viewer = (window.gammaViewer = {
  state: null,        // the last /api/state
  meshVersion: -1,    // the mesh on screen
  shown: null,        // {generation, iteration, show} on screen
  frames: 0,          // frames drawn (tests wait on it)
  vertices: 0,
});

async function loadMesh(state) {
  const bytes = await (await fetch(`/api/mesh?version=${state.mesh.version}`)).arrayBuffer();
  const head = new Uint32Array(bytes, 0, 2);
  const n = head[0], m = head[1];
  const positions = new Float32Array(bytes, 8, 3 * n);
  const normals = new Float32Array(bytes, 8 + 12 * n, 3 * n);
  const index = new Uint32Array(bytes, 8 + 24 * n, 3 * m);
  const uvs = new Float32Array(bytes, 8 + 24 * n + 12 * m, 2 * n);
  const geometry = new THREE.BufferGeometry();
  geometry.setAttribute("position", new THREE.BufferAttribute(positions, 3));
  geometry.setAttribute("normal", new THREE.BufferAttribute(normals, 3));
  geometry.setAttribute("color", new THREE.BufferAttribute(new Float32Array(3 * n).fill(0.8), 3));
  const pbr = new Float32Array(3 * n);
  for (let i = 0; i < n; i++) pbr.set(FALSE_COLOUR_PBR, 3 * i);
  geometry.setAttribute("pbr", new THREE.BufferAttribute(pbr, 3));
  geometry.setAttribute("uv", new THREE.BufferAttribute(uvs, 2));   // where the brush paints the mask
  geometry.setIndex(new THREE.BufferAttribute(index, 1));
  geometry.computeBoundingSphere();
  const firstMesh = mesh === null;
  if (mesh) { scene.remove(mesh); mesh.geometry.dispose(); }
  mesh = new THREE.Mesh(geometry, material);
  scene.add(mesh);
  viewer.meshVersion = state.mesh.version;
  viewer.vertices = n;
  if (paint.atlas) loadPoints(paint.index);   // the scene (so the texels' places) may have changed
  if (firstMesh) {
    const c = state.camera;
    camera.position.fromArray(c.eye);
    camera.up.fromArray(c.up);
    camera.fov = c.fov;
    // the sky's +Y to the scene's up (the shader turns world directions back)
    const up = new THREE.Vector3().fromArray(c.up).normalize();
    scene.environmentRotation.setFromQuaternion(new THREE.Quaternion().setFromUnitVectors(new THREE.Vector3(0, 1, 0), up));
    const r = geometry.boundingSphere.radius;
    camera.near = r / 100; camera.far = r * 100;
    controls.target.fromArray(c.target);
    camera.updateProjectionMatrix();
    controls.update();
  }
}

async function showFrame() {
  const state = viewer.state;
  if (!state || !mesh || state.iterations < 1) return;
  const slider = $("iteration");
  const iteration = Math.min(Number(slider.value), state.iterations);
  const show = $("show").value;
  const key = `${state.generation}/${state.quality}/${iteration}/${show}`;
  if (viewer.shownKey === key) return;
  const response = await fetch(`/api/frame?generation=${state.generation}&iteration=${iteration}`);
  if (!response.ok || viewer.state !== state) return;   // a newer result arrived meanwhile
  const bytes = await response.arrayBuffer();
  // a frame (watch.py, ViewerWriter): float32 colour (3n), roughness (n),
  // metallic (n), occlusion (n), then each property (n)
  const n = viewer.vertices;
  if (bytes.byteLength < 4 * (LOOK_FLOATS + state.properties.length) * n) return;
  const colours = mesh.geometry.getAttribute("color");
  const out = colours.array;
  const pbrAttribute = mesh.geometry.getAttribute("pbr");
  const pbr = pbrAttribute.array;
  const property = state.properties.findIndex((p) => p.name === show);
  if (property < 0) {
    out.set(new Float32Array(bytes, 0, 3 * n));
    const roughness = new Float32Array(bytes, 4 * 3 * n, n);
    const metallic = new Float32Array(bytes, 4 * 4 * n, n);
    const occlusion = new Float32Array(bytes, 4 * 5 * n, n);
    for (let i = 0; i < n; i++) {
      pbr[3 * i] = roughness[i];
      pbr[3 * i + 1] = metallic[i];
      pbr[3 * i + 2] = occlusion[i];
    }
    $("colourbar").hidden = true;
  } else {
    for (let i = 0; i < n; i++) pbr.set(FALSE_COLOUR_PBR, 3 * i);
    const values = new Float32Array(bytes, 4 * (LOOK_FLOATS * n + property * n), n);
    const { min, max } = state.properties[property];
    const span = max > min ? max - min : 1;
    for (let i = 0; i < n; i++) viridis((values[i] - min) / span, out, 3 * i);
    $("colourbar").hidden = false;
    $("range-min").textContent = fmt(min);
    $("range-max").textContent = fmt(max);
  }
  colours.needsUpdate = true;
  pbrAttribute.needsUpdate = true;
  viewer.shownKey = key;
  viewer.shown = { generation: state.generation, iteration, show, quality: state.quality };
  $("iteration-label").textContent = `${iteration} / ${state.iterations}`;
  draw();
  viewer.frames++;
}


// ---- painting a mask ----------------------------------------------------
// The brush paints into a canvas the size of the mask image, at the texture
// coordinates under the pointer (the mesh's own UVs, the ones mask() reads),
// a soft disk of `brush` texels; the painted mask shows on the mesh as a red
// glow.  Undo restores the canvas before the last stroke; Save sends it as a
// PNG, which replaces the file, and the effect runs again as after an edit.
// A mask laid out in the scene's atlas (a mesh without UVs) is painted in
// space instead: every texel whose scene point is within the brush's radius
// of the point under the pointer, so a stroke crosses the atlas's seams.
const paint = (viewer.paint = { canvas: document.createElement("canvas"), index: -1, undo: [], saved: 0,
                               strokes: 0, texture: null, painting: false, masks: [], atlas: false,
                               points: null, perTexel: 0 });
const paintContext = paint.canvas.getContext("2d", { willReadFrequently: true });
const raycaster = new THREE.Raycaster();

async function loadMask(index) {
  const blob = await (await fetch(`/api/mask?index=${index}&t=${Date.now()}`)).blob();
  const image = await createImageBitmap(blob);
  paint.canvas.width = image.width;
  paint.canvas.height = image.height;
  paintContext.fillStyle = "black";
  paintContext.fillRect(0, 0, image.width, image.height);
  paintContext.drawImage(image, 0, 0);
  paint.index = index;
  paint.undo = [];
  paint.atlas = Boolean(paint.masks[index] && paint.masks[index].atlas);
  paint.points = null;
  if (paint.atlas) await loadPoints(index);
  if (paint.texture) paint.texture.dispose();
  paint.texture = new THREE.CanvasTexture(paint.canvas);
  paint.texture.colorSpace = THREE.NoColorSpace;
  paint.texture.wrapS = paint.texture.wrapT = THREE.RepeatWrapping;
  showPaint();
}

function showPaint() {
  const on = $("paint").checked && paint.texture !== null;
  material.emissiveMap = on ? paint.texture : null;
  material.emissive.setRGB(on ? 0.8 : 0, on ? 0.1 : 0, on ? 0.1 : 0);
  material.needsUpdate = true;
  controls.enabled = !$("paint").checked;   // the left button paints instead of turning the view
  draw();
}

async function loadPoints(index) {
  const response = await fetch(`/api/mask-points?index=${index}&t=${Date.now()}`);
  if (!response.ok || index !== paint.index) return;   // not ready (the scene is loading) or superseded
  const bytes = await response.arrayBuffer();
  const size = new Uint32Array(bytes, 0, 1)[0];
  if (size !== paint.canvas.width) return;
  paint.perTexel = new Float32Array(bytes, 4, 1)[0];
  paint.points = new Float32Array(bytes, 8, 3 * size * size);
}

function paintAtPoint(p) {
  const w = paint.canvas.width, h = paint.canvas.height, points = paint.points;
  const radius = Math.max(1, Number($("brush-size").value)) * paint.perTexel, r2 = radius * radius;
  const strength = Number($("brush-strength").value), target = $("erase").checked ? 0 : 255;
  const image = paintContext.getImageData(0, 0, w, h), data = image.data;
  for (let t = 0, k = 0; t < w * h; t++, k += 3) {
    const dx = points[k] - p.x, dy = points[k + 1] - p.y, dz = points[k + 2] - p.z;
    const d2 = dx * dx + dy * dy + dz * dz;       // NaN (no point here) compares false
    if (!(d2 < r2)) continue;
    const a = strength * (1 - Math.sqrt(d2) / radius);   // the UV brush's soft disk, in space
    for (let c = 0; c < 3; c++) data[4 * t + c] = Math.round(data[4 * t + c] + a * (target - data[4 * t + c]));
    data[4 * t + 3] = 255;
  }
  paintContext.putImageData(image, 0, 0);
  paint.texture.needsUpdate = true;
}

function paintAt(u, v) {
  const w = paint.canvas.width, h = paint.canvas.height;
  const x = (u - Math.floor(u)) * w, y = (1 - (v - Math.floor(v))) * h;   // v up, as mask() samples
  const r = Math.max(1, Number($("brush-size").value));
  const strength = Number($("brush-strength").value);
  const colour = $("erase").checked ? "0,0,0" : "255,255,255";
  const g = paintContext.createRadialGradient(x, y, 0, x, y, r);
  g.addColorStop(0, `rgba(${colour},${strength})`);
  g.addColorStop(1, `rgba(${colour},0)`);
  paintContext.fillStyle = g;
  paintContext.fillRect(x - r, y - r, 2 * r, 2 * r);
  paint.texture.needsUpdate = true;
}

function strokeAt(event) {
  const rect = renderer.domElement.getBoundingClientRect();
  const pointer = new THREE.Vector2(((event.clientX - rect.left) / rect.width) * 2 - 1,
                                    -((event.clientY - rect.top) / rect.height) * 2 + 1);
  raycaster.setFromCamera(pointer, camera);
  const hit = mesh && raycaster.intersectObject(mesh)[0];
  if (hit && paint.atlas) {
    if (paint.points) { paintAtPoint(mesh.worldToLocal(hit.point.clone())); draw(); }
  } else if (hit && hit.uv) { paintAt(hit.uv.x, hit.uv.y); draw(); }
}

renderer.domElement.addEventListener("pointerdown", (event) => {
  if (!$("paint").checked || paint.index < 0 || event.button !== 0) return;
  paint.undo.push(paintContext.getImageData(0, 0, paint.canvas.width, paint.canvas.height));
  if (paint.undo.length > 20) paint.undo.shift();
  paint.painting = true;
  renderer.domElement.setPointerCapture(event.pointerId);
  strokeAt(event);
});
renderer.domElement.addEventListener("pointermove", (event) => { if (paint.painting) strokeAt(event); });
renderer.domElement.addEventListener("pointerup", () => {
  if (paint.painting) paint.strokes++;
  paint.painting = false;
});
$("paint").addEventListener("change", showPaint);
$("mask").addEventListener("change", () => loadMask(Number($("mask").value)));
$("undo").addEventListener("click", () => {
  const before = paint.undo.pop();
  if (!before) return;
  paintContext.putImageData(before, 0, 0);
  paint.texture.needsUpdate = true;
  draw();
});
$("save-mask").addEventListener("click", async () => {
  const blob = await new Promise((resolve) => paint.canvas.toBlob(resolve, "image/png"));
  const response = await fetch(`/api/mask?index=${paint.index}`, { method: "POST", body: blob });
  $("paint-note").textContent = response.ok ? "saved: running again" : `not saved: ${await response.text()}`;
  if (response.ok) paint.saved++;
});
// the sum of the canvas's grey levels (tests follow a stroke and an undo by it)
viewer.maskSum = () => paintContext.getImageData(0, 0, paint.canvas.width, paint.canvas.height).data
  .reduce((sum, value, i) => (i % 4 === 0 ? sum + value : sum), 0);

function showMasks(state) {
  const masks = state.masks || [];
  const panel = $("paint-panel"), select = $("mask");
  panel.hidden = masks.length === 0;
  paint.masks = masks;
  const names = masks.map((m) => `${m.name}${m.atlas ? " (atlas)" : ""}`).join();
  if (select.dataset.names !== names) {
    select.dataset.names = names;
    select.innerHTML = "";
    masks.forEach((m, i) => { if (m.paintable) select.add(new Option(m.name, i)); });
    if (select.options.length) loadMask(Number(select.value));
  }
  const bare = state.mesh && !state.mesh.has_uvs;
  $("paint").disabled = bare || select.options.length === 0;
  $("paint-note").textContent = bare ? "the mesh has no texture coordinates: move the mask away, and a new " +
    "one is made in the mesh's atlas"
    : select.options.length === 0 ? "only 8-bit PNG masks can be painted here" : $("paint-note").textContent;
}

const fmt = (x) => (Math.abs(x) >= 1e4 || (Math.abs(x) < 1e-3 && x !== 0) ? x.toExponential(2) : Number(x.toPrecision(4)).toString());

function drawRamp() {
  const canvas = $("ramp"), ctx = canvas.getContext("2d");
  const rgb = [0, 0, 0];
  for (let x = 0; x < canvas.width; x++) {
    viridis(x / (canvas.width - 1), rgb, 0);
    ctx.fillStyle = `rgb(${rgb.map((v) => Math.round(v * 255)).join(",")})`;
    ctx.fillRect(x, 0, 1, canvas.height);
  }
}

function showNumbers(state) {
  const rows = [["generation", state.generation], ["quality", state.quality]];
  const r = state.run;
  if (r) {
    rows.push(["surfels", r.surfels.toLocaleString()], ["triangles", r.triangles.toLocaleString()],
              ["γ-tons per iteration", r.tons_per_iteration.toLocaleString()],
              ["compile + surfels", `${r.setup_seconds.toFixed(2)} s`],
              ["since the save", `${r.seconds_since_save.toFixed(2)} s`],
              ["simulation", `${r.run_seconds.toFixed(2)} s`]);
    const it = r.records[Math.min(Number($("iteration").value), r.records.length) - 1];
    if (it) {
      rows.push(["emitted", it.emitted.toLocaleString()], ["settled", it.settled.toLocaleString()],
                ["escaped", it.escaped.toLocaleString()], ["interactions", it.interactions.toLocaleString()]);
      for (const [name, sum] of Object.entries(it.property_sums)) rows.push([`Σ ${name}`, fmt(sum)]);
    }
  }
  $("numbers").innerHTML = "";
  for (const [k, v] of rows) {
    const tr = $("numbers").insertRow();
    tr.insertCell().textContent = k;
    tr.insertCell().textContent = v;
  }
}

function showErrors(state) {
  const box = $("errors");
  if (!state.error) { box.hidden = true; box.textContent = ""; return; }
  box.hidden = false;
  box.textContent = state.error.text;
}

async function refresh() {
  const state = await (await fetch("/api/state")).json();
  viewer.state = state;
  const status = $("status");
  status.textContent = state.status === "running" ? `running (${state.quality})` : state.status;
  status.className = `status ${state.status}`;
  $("files").textContent = `${state.effect} on ${state.scene}`;
  $("quality-state").textContent = state.iterations ? `showing: ${state.quality} result` : "";
  if (!viewer.qualityShown) {          // the page starts with the server's --preview
    viewer.qualityShown = true;
    const choice = Array.from($("quality").options).find((o) => Math.abs(Number(o.value) - state.preview) < 1e-9);
    if (choice) $("quality").value = choice.value;
    else $("quality").add(new Option(`${state.preview} of the γ-tons (--preview), then refine`, state.preview), 0), ($("quality").value = String(state.preview));
  }
  showErrors(state);
  showMasks(state);
  const select = $("show");
  const wanted = ["appearance", ...state.properties.map((p) => p.name)];
  const current = Array.from(select.options).map((o) => o.value);
  if (wanted.join() !== current.join()) {
    const keep = select.value;
    select.innerHTML = "";
    for (const name of wanted) select.add(new Option(name, name));
    // until the user picks: the appearance if the effect has one, else its first property
    const fallback = state.appearance ? "appearance" : wanted[1] || "appearance";
    select.value = viewer.picked && wanted.includes(keep) ? keep : fallback;
  }
  const slider = $("iteration");
  const atEnd = Number(slider.value) >= Number(slider.max);
  slider.max = Math.max(1, state.iterations);
  if (atEnd) slider.value = slider.max;          // follow the newest iteration unless the user looks back
  showNumbers(state);
  if (state.mesh && state.mesh.version !== viewer.meshVersion) await loadMesh(state);
  await showFrame();
}

let pending = Promise.resolve();
const queueRefresh = () => (pending = pending.then(refresh).catch((e) => console.error(e)));

$("show").addEventListener("change", () => { viewer.picked = true; viewer.shownKey = null; showFrame(); });
$("iteration").addEventListener("input", () => { showNumbers(viewer.state); showFrame(); });
$("quality").addEventListener("change", async () => {
  await fetch("/api/preview", { method: "POST", body: $("quality").value });
});

drawRamp();
resize();
const events = new EventSource("/api/events");
events.onmessage = queueRefresh;
events.onopen = () => { $("status").textContent = "connected"; queueRefresh(); };
events.onerror = () => { $("status").textContent = "disconnected"; $("status").className = "status error"; };
