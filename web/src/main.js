// cityforge viewer: the ortho quick-look with footprints coloured by status
// or an attribute, the LOD1/LOD2 model in 3D (the run's buildings.glb, roofs
// coloured by surface type), the attributes, quality flags and failure reason
// of a clicked building, and the audits' figures. Everything comes from the
// data embedded in the page: it works from disk, offline.
import * as THREE from "three";
import { GLTFLoader } from "three/examples/jsm/loaders/GLTFLoader.js";
import { OrbitControls } from "three/examples/jsm/controls/OrbitControls.js";

const data = JSON.parse(document.getElementById("cityforge-data").textContent);
const byId = new Map(data.buildings.map((b, i) => [b.id, i]));
const state = { selected: -1, colourBy: "status", drawn2d: 0, drawn3d: 0, textured3d: 0, tilesLoaded: 0, tilesTotal: 0, source: null, ready: false, error: null };
// What tests and scripts can read: counts, selection, readiness.
window.cityforgeViewer = state;

const PALETTE = ["#4e79a7", "#f28e2b", "#59a14f", "#e15759", "#76b7b2", "#edc948", "#b07aa1", "#ff9da7", "#9c755f", "#bab0ac"];
const STATUS_COLOURS = { ok: "#2ca25f" };

function escapeHtml(s) {
  return String(s).replace(/[&<>"']/g, (c) => ({ "&": "&amp;", "<": "&lt;", ">": "&gt;", '"': "&quot;", "'": "&#39;" })[c]);
}
function fmt(v) {
  if (v === null || v === undefined || v === "") return "–";
  if (typeof v === "number") return Number.isInteger(v) ? String(v) : v.toFixed(Math.abs(v) >= 100 ? 2 : 3);
  return String(v);
}

// ---------- colours ----------
function ramp(t) {
  // viridis-like, t in [0, 1]
  const stops = [[68, 1, 84], [59, 82, 139], [33, 145, 140], [94, 201, 98], [253, 231, 37]];
  const x = Math.min(1, Math.max(0, t)) * (stops.length - 1);
  const i = Math.min(stops.length - 2, Math.floor(x)), f = x - i;
  const c = stops[i].map((a, k) => Math.round(a + f * (stops[i + 1][k] - a)));
  return `rgb(${c[0]},${c[1]},${c[2]})`;
}
function valueOf(b, field) {
  if (field === "status") return b.status;
  return b.attrs[field];
}
function colourScheme(field) {
  const values = data.buildings.map((b) => valueOf(b, field));
  const numeric = values.filter((v) => typeof v === "number" && Number.isFinite(v));
  if (field !== "status" && numeric.length && numeric.length >= values.filter((v) => v !== null && v !== undefined && v !== "").length) {
    const sorted = numeric.slice().sort((a, b) => a - b);
    const lo = sorted[Math.floor(0.02 * (sorted.length - 1))], hi = sorted[Math.ceil(0.98 * (sorted.length - 1))];
    const span = hi > lo ? hi - lo : 1;
    return {
      colour: (v) => (typeof v === "number" && Number.isFinite(v) ? ramp((v - lo) / span) : "#999"),
      legend: `<span><i style="background:${ramp(0)}"></i>${fmt(lo)}</span><span><i style="background:${ramp(0.5)}"></i>${fmt(lo + span / 2)}</span><span><i style="background:${ramp(1)}"></i>${fmt(hi)}</span><span><i style="background:#999"></i>none</span>`,
    };
  }
  const cats = [...new Set(values.map((v) => (v === null || v === undefined || v === "" ? "none" : String(v))))].sort();
  const map = new Map();
  let k = 0;
  for (const c of cats) map.set(c, field === "status" ? STATUS_COLOURS[c] || (c === "none" ? "#999" : PALETTE[(3 + k++) % PALETTE.length]) : c === "none" ? "#999" : PALETTE[k++ % PALETTE.length]);
  return {
    colour: (v) => map.get(v === null || v === undefined || v === "" ? "none" : String(v)),
    legend: cats.map((c) => `<span><i style="background:${map.get(c)}"></i>${escapeHtml(c)}</span>`).join(""),
  };
}

// ---------- 2D map: ortho + footprints ----------
const map = document.getElementById("map");
const ctx = map.getContext("2d");
const view = { scale: 1, cx: 0, cy: 0 };  // map units per pixel inverse, centre in map units
let ortho = null;
const ext = data.extent;  // [minx, miny, maxx, maxy], relative to data.origin

function fitView() {
  const w = map.clientWidth || 1, h = map.clientHeight || 1;
  view.cx = (ext[0] + ext[2]) / 2, view.cy = (ext[1] + ext[3]) / 2;
  view.scale = 0.95 * Math.min(w / Math.max(ext[2] - ext[0], 1), h / Math.max(ext[3] - ext[1], 1));
}
const toScreen = (x, y) => [map.width / devicePixelRatio / 2 + (x - view.cx) * view.scale, map.height / devicePixelRatio / 2 - (y - view.cy) * view.scale];
const toMap = (px, py) => [view.cx + (px - map.width / devicePixelRatio / 2) / view.scale, view.cy - (py - map.height / devicePixelRatio / 2) / view.scale];

function drawMap() {
  const dpr = devicePixelRatio || 1;
  const w = map.clientWidth, h = map.clientHeight;
  if (map.width !== Math.round(w * dpr) || map.height !== Math.round(h * dpr)) map.width = Math.round(w * dpr), map.height = Math.round(h * dpr);
  ctx.setTransform(dpr, 0, 0, dpr, 0, 0);
  ctx.fillStyle = "#ddd";
  ctx.fillRect(0, 0, w, h);
  if (ortho && ortho.complete && ortho.naturalWidth) {
    const e = data.ortho.extent;
    const [x0, y0] = toScreen(e[0], e[3]), [x1, y1] = toScreen(e[2], e[1]);
    ctx.imageSmoothingEnabled = true;
    ctx.drawImage(ortho, x0, y0, x1 - x0, y1 - y0);
  }
  const scheme = colourScheme(state.colourBy);
  document.getElementById("legend").innerHTML = scheme.legend;
  let drawn = 0;
  data.buildings.forEach((b, i) => {
    if (!b.footprint.length) return;
    ctx.beginPath();
    for (const poly of b.footprint)
      for (const ring of poly) {
        ring.forEach(([x, y], k) => {
          const [sx, sy] = toScreen(x, y);
          if (k === 0) ctx.moveTo(sx, sy);
          else ctx.lineTo(sx, sy);
        });
        ctx.closePath();
      }
    const c = scheme.colour(valueOf(b, state.colourBy));
    ctx.globalAlpha = 0.45;
    ctx.fillStyle = c;
    ctx.fill("evenodd");
    ctx.globalAlpha = 1;
    ctx.lineWidth = i === state.selected ? 3 : 1.2;
    ctx.strokeStyle = i === state.selected ? "#ffea00" : c;
    ctx.stroke();
    ++drawn;
  });
  state.drawn2d = drawn;
}

function pointInRing(ring, x, y) {
  let inside = false;
  for (let i = 0, j = ring.length - 1; i < ring.length; j = i++) {
    const [ax, ay] = ring[i], [bx, by] = ring[j];
    if (ay > y !== by > y && x < ((bx - ax) * (y - ay)) / (by - ay) + ax) inside = !inside;
  }
  return inside;
}
function buildingAt(x, y) {
  for (let i = data.buildings.length - 1; i >= 0; --i)
    for (const poly of data.buildings[i].footprint) {
      if (!pointInRing(poly[0], x, y)) continue;
      if (poly.slice(1).some((h) => pointInRing(h, x, y))) continue;
      return i;
    }
  return -1;
}

let drag = null;
map.addEventListener("mousedown", (e) => (drag = { x: e.offsetX, y: e.offsetY, moved: false }));
map.addEventListener("mousemove", (e) => {
  if (!drag) return;
  const dx = e.offsetX - drag.x, dy = e.offsetY - drag.y;
  if (Math.abs(dx) + Math.abs(dy) > 2) drag.moved = true;
  view.cx -= dx / view.scale, view.cy += dy / view.scale;
  drag.x = e.offsetX, drag.y = e.offsetY;
  drawMap();
});
map.addEventListener("mouseup", (e) => {
  if (drag && !drag.moved) {
    const [x, y] = toMap(e.offsetX, e.offsetY);
    select(buildingAt(x, y));
  }
  drag = null;
});
map.addEventListener("wheel", (e) => {
  e.preventDefault();
  const [x, y] = toMap(e.offsetX, e.offsetY);
  view.scale *= Math.exp(-e.deltaY * 0.0015);
  const [x2, y2] = toMap(e.offsetX, e.offsetY);
  view.cx += x - x2, view.cy += y - y2;
  drawMap();
}, { passive: false });

// A point inside building `id` in map-canvas CSS pixels (for scripted clicks), or null.
state.mapPoint = (id) => {
  const i = byId.get(id);
  if (i === undefined || !data.buildings[i].footprint.length) return null;
  const ring = data.buildings[i].footprint[0][0];
  // Scan the middle row of the outer ring's box for the widest run inside the polygon.
  let y0 = Infinity, y1 = -Infinity, x0 = Infinity, x1 = -Infinity;
  for (const [x, y] of ring) (y0 = Math.min(y0, y)), (y1 = Math.max(y1, y)), (x0 = Math.min(x0, x)), (x1 = Math.max(x1, x));
  for (const fy of [0.5, 0.4, 0.6, 0.3, 0.7, 0.2, 0.8]) {
    const y = y0 + fy * (y1 - y0);
    let best = null, run = 0, start = 0;
    for (let k = 0; k <= 100; ++k) {
      const x = x0 + (k / 100) * (x1 - x0);
      if (k < 100 && buildingAt(x, y) === i) { if (!run) start = x; ++run; }
      else if (run) { if (!best || run > best[0]) best = [run, (start + x) / 2]; run = 0; }
    }
    if (best) return toScreen(best[1], y);
  }
  return null;
};

// ---------- 3D ----------
// Two sources: the run's buildings.glb (embedded in the page as a base64 string
// in a script: Chromium reads a large inline script 5x faster than the same
// text in a non-script data block) and the 3D Tiles tileset (tiles.js beside
// the page: a page opened from disk cannot fetch; loaded as a script only when
// the tileset is first shown, so its parse does not delay the page), drawn
// tile by tile, nearest to the view first. Every mesh knows its glb's
// feature id -> building index table (userData.rows).
const sceneCanvas = document.getElementById("scene");
let renderer = null, camera = null, controls = null, scene = null, meshes = [], highlight = null, modelGroup = null, loadGeneration = 0;
const drawnSet = new Set();

function parseGlbIds(bytes) {
  // The property table's id column (EXT_structural_metadata) maps feature ids to buildings.
  const dv = new DataView(bytes.buffer, bytes.byteOffset, bytes.byteLength);
  const jlen = dv.getUint32(12, true);
  const gltf = JSON.parse(new TextDecoder().decode(bytes.subarray(20, 20 + jlen)));
  const bin = bytes.subarray(28 + jlen);
  const table = gltf.extensions.EXT_structural_metadata.propertyTables[0];
  const p = table.properties.id;
  const vv = gltf.bufferViews[p.values], ov = gltf.bufferViews[p.stringOffsets];
  const off = new Uint32Array(bin.buffer.slice(bin.byteOffset + ov.byteOffset, bin.byteOffset + ov.byteOffset + ov.byteLength));
  const values = bin.subarray(vv.byteOffset, vv.byteOffset + vv.byteLength);
  const dec = new TextDecoder();
  const ids = [];
  for (let i = 0; i < table.count; ++i) ids.push(dec.decode(values.subarray(off[i], off[i + 1])));
  return { ids, extras: gltf.asset.extras || {} };
}

function base64Bytes(text) {
  const bin = atob(text.trim());
  const out = new Uint8Array(bin.length);
  for (let i = 0; i < bin.length; ++i) out[i] = bin.charCodeAt(i);
  return out;
}

function render3d() {
  if (!renderer) return;
  const w = sceneCanvas.clientWidth, h = sceneCanvas.clientHeight;
  const size = renderer.getSize(new THREE.Vector2());
  if (size.x !== w || size.y !== h) {
    renderer.setSize(w, h, false);
    camera.aspect = w / Math.max(h, 1);
    camera.updateProjectionMatrix();
  }
  renderer.render(scene, camera);
}

function rowsOf(bytes) {
  return parseGlbIds(bytes).ids.map((id) => (byId.has(id) ? byId.get(id) : -1));
}

function parseGlb(bytes) {
  return new Promise((resolve, reject) => new GLTFLoader().parse(bytes.buffer.slice(bytes.byteOffset, bytes.byteOffset + bytes.byteLength), "", resolve, reject));
}

// Registers the meshes of a loaded glb (already placed in the scene).
function addMeshes(root, rows) {
  root.updateMatrixWorld(true);
  root.traverse((o) => {
    if (!o.isMesh) return;
    o.userData.rows = rows;
    meshes.push(o);
    if (o.material && o.material.map) state.textured3d += 1;
    const fid = o.geometry.getAttribute("_feature_id_0");
    if (fid) for (let i = 0; i < fid.count; ++i) if (rows[fid.getX(i)] >= 0) drawnSet.add(rows[fid.getX(i)]);
  });
  state.drawn3d = drawnSet.size;
}

function clearModel() {
  ++loadGeneration;
  if (highlight) scene.remove(highlight), highlight.geometry.dispose(), (highlight = null);
  for (const c of [...modelGroup.children]) modelGroup.remove(c);
  meshes = [];
  drawnSet.clear();
  state.drawn3d = 0, state.textured3d = 0, state.tilesLoaded = 0, state.tilesTotal = 0;
}

function fitCamera(object) {
  const box = new THREE.Box3().setFromObject(object, true);
  const centre = box.getCenter(new THREE.Vector3()), radius = box.getSize(new THREE.Vector3()).length() / 2 || 10;
  camera.near = radius / 1000, camera.far = radius * 20;
  camera.updateProjectionMatrix();
  camera.position.set(centre.x + radius * 0.9, centre.y + radius * 1.3, centre.z + radius * 1.5);
  controls.target.copy(centre);
  controls.update();
}

function sceneLabel() {
  const lods = new Set(data.buildings.map((b) => b.lod).filter(Boolean));
  const tiles = state.source === "tiles" ? ` · tiles ${state.tilesLoaded}/${state.tilesTotal}` : "";
  document.getElementById("scene-lod").textContent = `${state.drawn3d} buildings` + (lods.size ? ` (LOD ${[...lods].sort().join(", ")})` : "") + tiles;
}

async function showGlb() {
  const bytes = base64Bytes(window.CITYFORGE_GLB_BASE64);
  const rows = rowsOf(bytes);
  const gltf = await parseGlb(bytes);
  // The glb is in the model CRS minus its origin; the map is relative to data.origin.
  const o = (gltf.parser.json.asset.extras || {}).origin || data.origin;
  gltf.scene.position.set(o[0] - data.origin[0], o[2] - data.origin[2], -(o[1] - data.origin[1]));
  modelGroup.add(gltf.scene);
  addMeshes(gltf.scene, rows);
  return gltf.scene;
}

// Loads tiles.js (window.CITYFORGE_TILES) once, on first use.
let tilesScript = null;
function loadTiles() {
  if (window.CITYFORGE_TILES) return Promise.resolve();
  if (!tilesScript)
    tilesScript = new Promise((resolve, reject) => {
      const el = document.createElement("script");
      el.src = window.CITYFORGE_TILES_SRC;
      el.onload = () => (window.CITYFORGE_TILES ? resolve() : reject(new Error(`${el.src} holds no tileset`)));
      el.onerror = () => reject(new Error(`cannot load ${el.src} (the 3D Tiles bundle beside the page)`));
      document.head.appendChild(el);
    });
  return tilesScript;
}

let lastTileFrame = 0;
async function showTiles(generation) {
  await loadTiles();
  const T = window.CITYFORGE_TILES, m = T.to_page;
  // Content is y-up ECEF (3D Tiles' glTF convention); to_page maps it to the page's frame.
  const holder = new THREE.Group();
  holder.matrixAutoUpdate = false;
  holder.matrix.set(m[0], m[1], m[2], m[3], m[4], m[5], m[6], m[7], m[8], m[9], m[10], m[11], 0, 0, 0, 1);
  modelGroup.add(holder);
  holder.updateMatrixWorld(true);
  const tiles = [];
  const walk = (t) => {
    if (t.content && t.content.uri) {
      const b = t.boundingVolume.box;
      tiles.push({ uri: t.content.uri, centre: new THREE.Vector3(b[0], b[2], -b[1]).applyMatrix4(holder.matrix) });
    }
    for (const c of t.children || []) walk(c);
  };
  walk(T.tileset.root);
  const target = controls ? controls.target : new THREE.Vector3();
  tiles.sort((a, b) => a.centre.distanceTo(target) - b.centre.distanceTo(target) || (a.uri < b.uri ? -1 : 1));
  state.tilesTotal = tiles.length;
  for (const t of tiles) {
    if (generation !== loadGeneration) return holder;
    const bytes = base64Bytes(T.content[t.uri]);
    const gltf = await parseGlb(bytes);
    if (generation !== loadGeneration) return holder;
    holder.add(gltf.scene);
    addMeshes(gltf.scene, rowsOf(bytes));
    state.tilesLoaded += 1;
    sceneLabel();
    // Redraw while tiles stream in, but not after every tile: a frame of many tiles costs
    // as much as loading one in a software renderer (showSource draws the last frame).
    if (performance.now() - lastTileFrame > 1000) render3d(), (lastTileFrame = performance.now());
  }
  return holder;
}

// Shows `source` ("glb" or "tiles") in 3D; resolves when everything is loaded.
async function showSource(source) {
  if (!scene) return;
  clearModel();
  const generation = loadGeneration;
  state.source = source;
  document.getElementById("scene-source").value = source;
  const root = source === "tiles" ? await showTiles(generation) : await showGlb();
  if (generation !== loadGeneration) return;
  if (!state.cameraSet) fitCamera(root), (state.cameraSet = true);
  const box = new THREE.Box3().setFromObject(modelGroup, true);  // precise: tile content is rotated (ECEF)
  state.box = [box.min.x, box.min.y, box.min.z, box.max.x, box.max.y, box.max.z];
  sceneLabel();
  if (state.selected >= 0) setHighlight(state.selected);
  render3d();
}
state.showSource = showSource;

function setHighlight(index) {
  if (!scene) return;
  if (highlight) scene.remove(highlight), highlight.geometry.dispose(), (highlight = null);
  if (index < 0) return render3d();
  const positions = [];
  for (const m of meshes) {
    const g = m.geometry, fid = g.getAttribute("_feature_id_0"), pos = g.getAttribute("position"), idx = g.getIndex(), rows = m.userData.rows;
    for (let t = 0; t < idx.count; t += 3) {
      if (rows[fid.getX(idx.getX(t))] !== index) continue;
      for (let k = 0; k < 3; ++k) {
        const v = new THREE.Vector3().fromBufferAttribute(pos, idx.getX(t + k)).applyMatrix4(m.matrixWorld);
        positions.push(v.x, v.y, v.z);
      }
    }
  }
  const g = new THREE.BufferGeometry();
  g.setAttribute("position", new THREE.Float32BufferAttribute(positions, 3));
  highlight = new THREE.Mesh(g, new THREE.MeshBasicMaterial({ color: 0xffea00, transparent: true, opacity: 0.55, depthTest: false }));
  scene.add(highlight);
  render3d();
}

// True when WebGL draws on the CPU (its renderer string names a software rasteriser).
function softwareWebGl() {
  try {
    const gl = document.createElement("canvas").getContext("webgl2") || document.createElement("canvas").getContext("webgl");
    if (!gl) return false;
    const info = gl.getExtension("WEBGL_debug_renderer_info");
    const name = String(gl.getParameter(info ? info.UNMASKED_RENDERER_WEBGL : gl.RENDERER));
    const lose = gl.getExtension("WEBGL_lose_context");
    if (lose) lose.loseContext();
    return /swiftshader|llvmpipe|softpipe|software/i.test(name);
  } catch {
    return false;
  }
}

async function init3d() {
  const haveGlb = !!window.CITYFORGE_GLB_BASE64, haveTiles = !!(window.CITYFORGE_TILES || window.CITYFORGE_TILES_SRC);
  const sourceSel = document.getElementById("scene-source");
  for (const [v, label, have] of [["glb", "buildings.glb", haveGlb], ["tiles", "3D Tiles", haveTiles]]) {
    if (!have) continue;
    const o = document.createElement("option");
    o.value = v, o.textContent = label;
    sourceSel.appendChild(o);
  }
  state.sources = [...sourceSel.options].map((o) => o.value);
  if (!haveGlb && !haveTiles) {
    document.getElementById("scene-lod").textContent = "(no buildings.glb or 3D Tiles in this run)";
    return;
  }
  try {
    // No multisampling on a software rasteriser (SwiftShader, llvmpipe: headless
    // Chromium, machines without a GPU): there it cost 1-3 s of a 10,000-building page.
    renderer = new THREE.WebGLRenderer({ canvas: sceneCanvas, antialias: !softwareWebGl(), preserveDrawingBuffer: true });
  } catch (e) {
    document.getElementById("scene-lod").innerHTML = `<span class="error">WebGL is not available: ${escapeHtml(e.message)}</span>`;
    return;
  }
  renderer.setPixelRatio(devicePixelRatio || 1);
  scene = new THREE.Scene();
  scene.background = new THREE.Color(0xdfe7ee);
  scene.add(new THREE.HemisphereLight(0xffffff, 0x667788, 1.6));
  const sun = new THREE.DirectionalLight(0xffffff, 1.6);
  sun.position.set(-0.5, 1, 0.6);
  scene.add(sun);
  modelGroup = new THREE.Group();
  scene.add(modelGroup);
  camera = new THREE.PerspectiveCamera(45, 1, 0.1, 1000);
  controls = new OrbitControls(camera, sceneCanvas);
  controls.addEventListener("change", render3d);
  sourceSel.addEventListener("change", () => showSource(sourceSel.value).catch((e) => console.error(e)));
  let down = null;
  sceneCanvas.addEventListener("pointerdown", (e) => (down = [e.offsetX, e.offsetY]));
  sceneCanvas.addEventListener("pointerup", (e) => {
    if (!down || Math.abs(e.offsetX - down[0]) + Math.abs(e.offsetY - down[1]) > 3) return;
    const ndc = new THREE.Vector2((e.offsetX / sceneCanvas.clientWidth) * 2 - 1, -(e.offsetY / sceneCanvas.clientHeight) * 2 + 1);
    const ray = new THREE.Raycaster();
    ray.setFromCamera(ndc, camera);
    const hit = ray.intersectObjects(meshes, false)[0];
    if (!hit) return select(-1);
    const fid = hit.object.geometry.getAttribute("_feature_id_0");
    select(hit.object.userData.rows[fid.getX(hit.face.a)] ?? -1);
  });
  new ResizeObserver(render3d).observe(sceneCanvas);
  await showSource(haveGlb ? "glb" : "tiles");
}

// The screen point (3D canvas CSS pixels) of the centre of building `id`'s highest triangles, or null.
state.scenePoint = (id) => {
  const i = byId.get(id);
  if (!camera || i === undefined) return null;
  let best = null;
  for (const m of meshes) {
    const g = m.geometry, fid = g.getAttribute("_feature_id_0"), pos = g.getAttribute("position"), idx = g.getIndex(), rows = m.userData.rows;
    for (let t = 0; t < idx.count; t += 3) {
      if (rows[fid.getX(idx.getX(t))] !== i) continue;
      const c = new THREE.Vector3();
      for (let k = 0; k < 3; ++k) c.add(new THREE.Vector3().fromBufferAttribute(pos, idx.getX(t + k)).applyMatrix4(m.matrixWorld));
      c.multiplyScalar(1 / 3);
      if (!best || c.y > best.y) best = c;
    }
  }
  if (!best) return null;
  const p = best.clone().project(camera);
  return [((p.x + 1) / 2) * sceneCanvas.clientWidth, ((1 - p.y) / 2) * sceneCanvas.clientHeight];
};

// ---------- info panel ----------
function select(index) {
  state.selected = index;
  const info = document.getElementById("info");
  if (index < 0) {
    info.innerHTML = '<p class="hint">Click a building on the map or in 3D.</p>';
  } else {
    const b = data.buildings[index];
    const ok = b.status === "ok";
    const rows = Object.entries(b.attrs).map(([k, v]) => `<tr><td>${escapeHtml(k)}</td><td>${escapeHtml(fmt(v))}</td></tr>`).join("");
    info.innerHTML =
      `<h2>Building <span id="sel-id">${escapeHtml(b.id)}</span></h2>` +
      `<p>height <b id="sel-height">${escapeHtml(fmt(b.attrs.height_m))}</b> m · status <span class="${ok ? "status-ok" : "status-bad"}" id="sel-status">${escapeHtml(b.status)}</span></p>` +
      (b.reason ? `<p class="status-bad" id="sel-reason">${escapeHtml(b.reason)}</p>` : "") +
      (b.flags.length ? `<p>${b.flags.map((f) => `<span class="flag">${escapeHtml(f)}</span>`).join(" ")}</p>` : '<p class="hint">no quality flags</p>') +
      `<table>${rows}</table>`;
  }
  drawMap();
  setHighlight(index);
}

function initPanels() {
  document.getElementById("title").textContent = data.title;
  document.getElementById("crs").textContent = data.crs;
  const sel = document.getElementById("colour-by");
  for (const f of data.colour_fields) {
    const o = document.createElement("option");
    o.value = f, o.textContent = f.replace(/_/g, " ");
    sel.appendChild(o);
  }
  sel.value = state.colourBy;
  sel.addEventListener("change", () => ((state.colourBy = sel.value), drawMap()));
  const counts = {};
  for (const b of data.buildings) counts[b.status] = (counts[b.status] || 0) + 1;
  document.getElementById("summary").innerHTML =
    `<h2>Model</h2><table><tr><td>buildings</td><td id="n-buildings">${data.buildings.length}</td></tr>` +
    Object.entries(counts).map(([k, v]) => `<tr><td>status ${escapeHtml(k)}</td><td>${v}</td></tr>`).join("") + "</table>";
  document.getElementById("audits").innerHTML = data.audits
    .map((a) => `<h2>${escapeHtml(a.title)}</h2><table>${Object.entries(a.figures).map(([k, v]) => `<tr><td>${escapeHtml(k)}</td><td>${escapeHtml(fmt(v))}</td></tr>`).join("")}</table>`)
    .join("");
}

async function main() {
  initPanels();
  fitView();
  if (data.ortho) {
    ortho = new Image();
    await new Promise((resolve) => {
      ortho.onload = resolve;
      ortho.onerror = resolve;
      ortho.src = data.ortho.src;
    });
  }
  drawMap();
  new ResizeObserver(() => drawMap()).observe(map);
  await init3d();
  state.ready = true;
}
main().catch((e) => {
  state.error = String(e && e.stack ? e.stack : e);
  console.error(e);
});
