// Validates cityforge's 3D Tiles and glTF output.
//
//   node validate_3dtiles.mjs tileset DIR/tileset.json [--expect-buildings N]
//   node validate_3dtiles.mjs glb FILE.glb [--expect-buildings N]
//
// Every glb goes through the Khronos glTF validator (gltf-validator from npm):
// any error fails. The CesiumGS 3d-tiles-validator is not published on the npm
// registry this project installs from, so the tileset rules it checks for our
// kind of tileset are checked here: asset version, geometric errors (non-negative,
// never larger than the parent's), oriented boxes (12 numbers, child boxes and
// every content vertex inside their tile's box after the glTF y-up -> z-up
// rotation and node translation), content present, and the EXT_mesh_features /
// EXT_structural_metadata payload (feature ids within featureCount and the
// property table, property columns of the right length and type, string offsets
// monotone, building ids unique across the tileset).
// Prints a JSON summary on stdout; exit 0 = no errors.
import fs from "node:fs";
import path from "node:path";
import validator from "gltf-validator";

const errors = [];
const warnings = [];
const fail = (where, msg) => errors.push(`${where}: ${msg}`);

function parseGlb(bytes, where) {
  const dv = new DataView(bytes.buffer, bytes.byteOffset, bytes.byteLength);
  if (dv.getUint32(0, true) !== 0x46546c67) throw new Error(`${where}: not a glb`);
  const jsonLen = dv.getUint32(12, true);
  const json = JSON.parse(new TextDecoder().decode(bytes.subarray(20, 20 + jsonLen)));
  const binStart = 20 + jsonLen + 8;
  const binLen = dv.getUint32(20 + jsonLen, true);
  return { json, bin: bytes.subarray(binStart, binStart + binLen) };
}

function viewBytes(glb, index) {
  const v = glb.json.bufferViews[index];
  return glb.bin.subarray(v.byteOffset || 0, (v.byteOffset || 0) + v.byteLength);
}

function accessorFloats(glb, index) {
  const a = glb.json.accessors[index];
  const b = viewBytes(glb, a.bufferView);
  const comps = { SCALAR: 1, VEC2: 2, VEC3: 3, VEC4: 4 }[a.type];
  if (a.componentType !== 5126) throw new Error(`accessor ${index} is not FLOAT`);
  return new Float32Array(b.buffer.slice(b.byteOffset + (a.byteOffset || 0), b.byteOffset + (a.byteOffset || 0) + a.count * comps * 4));
}

async function validateGlb(file, bytes) {
  const report = await validator.validateBytes(new Uint8Array(bytes), { maxIssues: 200, uri: file });
  for (const m of report.issues.messages) {
    if (m.severity === 0) fail(file, `glTF validator ${m.code} ${m.pointer || ""} ${m.message}`);
    else if (m.severity === 1) warnings.push(`${file}: ${m.code} ${m.message}`);
  }
  return report.issues;
}

// Checks the metadata payload; returns the building ids and the positions in the glb's node frame (z-up).
function checkMetadata(file, glb) {
  const g = glb.json;
  const used = g.extensionsUsed || [];
  for (const e of ["EXT_mesh_features", "EXT_structural_metadata"]) if (!used.includes(e)) fail(file, `extensionsUsed lacks ${e}`);
  const meta = g.extensions && g.extensions.EXT_structural_metadata;
  if (!meta) return { ids: [], points: [] };
  const table = meta.propertyTables[0];
  const cls = meta.schema.classes[table.class];
  if (!cls) fail(file, `property table class ${table.class} not in the schema`);
  const columns = {};
  for (const [name, p] of Object.entries(table.properties)) {
    const def = cls.properties[name];
    if (!def) { fail(file, `property ${name} not in class`); continue; }
    const values = viewBytes(glb, p.values);
    if (def.type === "STRING") {
      const ob = viewBytes(glb, p.stringOffsets);
      if ((p.stringOffsetType || "UINT32") !== "UINT32") fail(file, `${name}: unexpected offset type`);
      const off = new Uint32Array(ob.buffer.slice(ob.byteOffset, ob.byteOffset + ob.byteLength));
      if (off.length !== table.count + 1) fail(file, `${name}: ${off.length} string offsets for ${table.count} rows`);
      const col = [];
      for (let i = 0; i < table.count; ++i) {
        if (off[i + 1] < off[i]) fail(file, `${name}: string offsets decrease at ${i}`);
        col.push(new TextDecoder().decode(values.subarray(off[i], off[i + 1])));
      }
      if (off[table.count] !== values.byteLength) fail(file, `${name}: last string offset ${off[table.count]} != ${values.byteLength}`);
      columns[name] = col;
    } else if (def.type === "SCALAR") {
      const size = { FLOAT64: 8, INT64: 8, FLOAT32: 4, UINT32: 4, INT32: 4 }[def.componentType];
      if (values.byteLength !== size * table.count) fail(file, `${name}: ${values.byteLength} bytes for ${table.count} ${def.componentType}`);
      if ((g.bufferViews[p.values].byteOffset || 0) % size) fail(file, `${name}: values not aligned to ${size} bytes`);
    } else fail(file, `${name}: unexpected type ${def.type}`);
  }
  const ids = columns.id || [];
  if (!columns.id) fail(file, "no id property");
  if (new Set(ids).size !== ids.length) fail(file, "building ids repeat in the property table");
  const points = [];
  const translation = (g.nodes[0] && g.nodes[0].translation) || [0, 0, 0];
  const seen = new Set();
  for (const mesh of g.meshes) {
    for (const prim of mesh.primitives) {
      const fx = prim.extensions && prim.extensions.EXT_mesh_features;
      if (!fx) { fail(file, "primitive without EXT_mesh_features"); continue; }
      const set = fx.featureIds[0];
      if (set.propertyTable !== 0) fail(file, "feature ids do not name the property table");
      const fid = accessorFloats(glb, prim.attributes[`_FEATURE_ID_${set.attribute}`]);
      const distinct = new Set(fid);
      if (distinct.size > set.featureCount) fail(file, `${distinct.size} distinct feature ids > featureCount ${set.featureCount}`);
      for (const v of distinct) {
        if (!Number.isInteger(v) || v < 0 || v >= table.count) fail(file, `feature id ${v} outside the property table (${table.count} rows)`);
        seen.add(v);
      }
      const pos = accessorFloats(glb, prim.attributes.POSITION);
      for (let i = 0; i < pos.length; i += 3) {
        // glTF y-up -> 3D Tiles z-up: (x, y, z) -> (x, -z, y), after the node translation.
        const x = pos[i] + translation[0], y = pos[i + 1] + translation[1], z = pos[i + 2] + translation[2];
        points.push([x, -z, y]);
      }
    }
  }
  if (seen.size !== table.count) fail(file, `${table.count} rows in the property table but ${seen.size} features drawn`);
  return { ids, points };
}

function boxContains(box, p, tol) {
  const c = box.slice(0, 3), axes = [box.slice(3, 6), box.slice(6, 9), box.slice(9, 12)];
  const d = [p[0] - c[0], p[1] - c[1], p[2] - c[2]];
  for (const a of axes) {
    const len2 = a[0] * a[0] + a[1] * a[1] + a[2] * a[2];
    const t = (d[0] * a[0] + d[1] * a[1] + d[2] * a[2]) / len2;  // in units of the half axis
    if (Math.abs(t) > 1 + tol / Math.sqrt(len2)) return false;
  }
  return true;
}

function boxCorners(box) {
  const out = [];
  for (let i = 0; i < 8; ++i) {
    const p = box.slice(0, 3);
    for (let a = 0; a < 3; ++a) {
      const s = (i >> a) & 1 ? 1 : -1;
      for (let k = 0; k < 3; ++k) p[k] += s * box[3 + 3 * a + k];
    }
    out.push(p);
  }
  return out;
}

async function checkTileset(file) {
  const ts = JSON.parse(fs.readFileSync(file, "utf8"));
  const dir = path.dirname(file);
  if (!ts.asset || ts.asset.version !== "1.1") fail(file, `asset.version ${ts.asset && ts.asset.version} is not 1.1`);
  if (!(ts.geometricError >= 0)) fail(file, "tileset geometricError missing or negative");
  if (ts.root.geometricError > ts.geometricError) fail(file, "root geometricError exceeds the tileset's");
  const allIds = [];
  let tiles = 0, contents = 0, depth = 0, glbs = 0;
  async function visit(tile, parent, level, where) {
    ++tiles;
    depth = Math.max(depth, level);
    const box = tile.boundingVolume && tile.boundingVolume.box;
    if (!box || box.length !== 12 || !box.every(Number.isFinite)) { fail(where, "boundingVolume.box must be 12 finite numbers"); return; }
    if (!(tile.geometricError >= 0)) fail(where, "geometricError missing or negative");
    if (parent) {
      if (tile.geometricError > parent.geometricError) fail(where, `geometricError ${tile.geometricError} > parent's ${parent.geometricError}`);
      for (const c of boxCorners(box)) if (!boxContains(parent.boundingVolume.box, c, 0.01)) { fail(where, "box not inside the parent's box"); break; }
      if (tile.transform) fail(where, "unexpected transform");
    }
    if (tile.refine && !["ADD", "REPLACE"].includes(tile.refine)) fail(where, `refine ${tile.refine}`);
    if (tile.content) {
      ++contents;
      const uri = path.join(dir, tile.content.uri);
      if (!fs.existsSync(uri)) { fail(where, `content ${tile.content.uri} missing`); }
      else {
        const bytes = fs.readFileSync(uri);
        ++glbs;
        await validateGlb(tile.content.uri, bytes);
        const { ids, points } = checkMetadata(tile.content.uri, parseGlb(new Uint8Array(bytes), uri));
        allIds.push(...ids);
        let outside = 0;
        for (const p of points) if (!boxContains(box, p, 0.01)) ++outside;
        if (outside) fail(tile.content.uri, `${outside} of ${points.length} vertices outside the tile's bounding box`);
        // ECEF sanity: content on the Earth's surface (within 10 km of the WGS84 ellipsoid's range).
        for (const p of points.slice(0, 1)) {
          const r = Math.hypot(p[0], p[1], p[2]);
          if (r < 6350e3 || r > 6400e3) fail(tile.content.uri, `vertex at ${r.toFixed(0)} m from the Earth's centre: not ECEF`);
        }
      }
    }
  }
  // Children one after the other (the glb checks are asynchronous).
  async function walk(tile, parent, level, where) {
    const kids = tile.children;
    await visit(tile, parent, level, where);
    for (let i = 0; i < (kids || []).length; ++i) await walk(kids[i], tile, level + 1, `${where}/children/${i}`);
  }
  await walk(ts.root, null, 0, "root");
  if (new Set(allIds).size !== allIds.length) fail(file, "a building appears in several tiles");
  return { tiles, contents, depth, glbs, buildings: allIds.length, ids: allIds };
}

async function main() {
  const [mode, file, ...rest] = process.argv.slice(2);
  const expectAt = rest.indexOf("--expect-buildings");
  const expected = expectAt >= 0 ? Number(rest[expectAt + 1]) : null;
  let summary;
  if (mode === "tileset") summary = await checkTileset(file);
  else if (mode === "glb") {
    const bytes = fs.readFileSync(file);
    const issues = await validateGlb(file, bytes);
    const { ids } = checkMetadata(file, parseGlb(new Uint8Array(bytes), file));
    summary = { buildings: ids.length, ids, gltf_errors: issues.numErrors, gltf_warnings: issues.numWarnings };
  } else {
    console.error("usage: validate_3dtiles.mjs tileset|glb FILE [--expect-buildings N]");
    process.exit(2);
  }
  if (expected !== null && summary.buildings !== expected) fail(file, `${summary.buildings} buildings, expected ${expected}`);
  const ids = summary.ids;
  delete summary.ids;
  console.log(JSON.stringify({ ...summary, first_ids: ids.slice(0, 3), errors, warnings: warnings.slice(0, 20) }, null, 1));
  process.exit(errors.length ? 1 : 0);
}

main().catch((e) => {
  console.error(e.stack || String(e));
  process.exit(1);
});
