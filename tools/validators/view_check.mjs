// Opens a cityforge viewer page from disk in Debian's headless Chromium
// (playwright-core, never a downloaded browser) and checks it the way a user
// would look at it:
//
//   node view_check.mjs PAGE.html OUTDIR --expect-buildings N [--expect-meshed M]
//        [--click-id ID --expect-height H] [--click3d-id ID] [--source glb|tiles]
//        [--expect-textured]
//
// - the page loads with no console error, no page error and no request
//   leaving the disk (file: and data: only);
// - buildings drawn on the map == N, buildings drawn in 3D == M;
// - clicking building ID on the map shows its id and height H (to the shown digits);
// - clicking building ID in the 3D view selects it;
// - with --source tiles: the 3D view shows the 3D Tiles tileset (tiles.js beside
//   the page), every content tile loaded, and the 3D checks run on it;
// - with --expect-textured: some 3D mesh carries a texture (the ortho on roofs);
// - a screenshot goes to OUTDIR/viewer.png.
// Prints a JSON summary; exit 0 = every check passed.
import { chromium } from "playwright-core";
import fs from "node:fs";
import path from "node:path";
import { pathToFileURL } from "node:url";

const [page_path, outdir, ...rest] = process.argv.slice(2);
const arg = (name) => {
  const i = rest.indexOf(name);
  return i >= 0 ? rest[i + 1] : null;
};
const failures = [];
const summary = {};
fs.mkdirSync(outdir, { recursive: true });
const userData = fs.mkdtempSync(path.join(outdir, "chromium-profile-"));
const context = await chromium.launchPersistentContext(userData, {
  executablePath: process.env.CITYFORGE_CHROMIUM || "/usr/bin/chromium",
  headless: true,
  viewport: { width: 1400, height: 800 },
  args: ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run", "--disable-background-networking",
         "--disable-component-update", "--disable-sync", "--enable-unsafe-swiftshader"],
});
try {
  const page = context.pages()[0] || (await context.newPage());
  const consoleErrors = [];
  page.on("console", (m) => { if (m.type() === "error") consoleErrors.push(m.text()); });
  page.on("pageerror", (e) => consoleErrors.push(`page error: ${e.message}`));
  const remote = [];
  await page.route("**/*", (route) => {
    const u = route.request().url();
    if (u.startsWith("file:") || u.startsWith("data:") || u.startsWith("blob:")) return route.continue();
    remote.push(u);
    return route.abort();
  });
  const t0 = Date.now();
  await page.goto(pathToFileURL(path.resolve(page_path)).href, { waitUntil: "load", timeout: 120000 });
  await page.waitForFunction(() => window.cityforgeViewer && (window.cityforgeViewer.ready || window.cityforgeViewer.error), null, { timeout: 120000 });
  summary.load_ms = Date.now() - t0;
  const source = arg("--source");
  if (source !== null) {
    const t1 = Date.now();
    const ok = await page.evaluate(async (s) => {
      const v = window.cityforgeViewer;
      if (!v.sources || !v.sources.includes(s)) return false;
      await v.showSource(s);
      return true;
    }, source);
    summary.source_ms = Date.now() - t1;
    if (!ok) failures.push(`the page offers no 3D source '${source}'`);
  }
  const st = await page.evaluate(() => ({ ...window.cityforgeViewer, mapPoint: undefined, scenePoint: undefined, showSource: undefined }));
  summary.source = st.source;
  summary.tiles = { loaded: st.tilesLoaded, total: st.tilesTotal };
  summary.textured_meshes = st.textured3d;
  summary.box = st.box;
  if (source === "tiles" && !(st.tilesTotal > 0 && st.tilesLoaded === st.tilesTotal)) failures.push(`tiles loaded ${st.tilesLoaded} of ${st.tilesTotal}`);
  if (rest.includes("--expect-textured") && !(st.textured3d > 0)) failures.push("no textured mesh in 3D");
  summary.drawn_map = st.drawn2d;
  summary.drawn_3d = st.drawn3d;
  if (st.error) failures.push(`viewer error: ${st.error}`);
  const expectN = arg("--expect-buildings");
  if (expectN !== null && st.drawn2d !== Number(expectN)) failures.push(`map draws ${st.drawn2d} buildings, the model has ${expectN}`);
  const expectM = arg("--expect-meshed");
  if (expectM !== null && st.drawn3d !== Number(expectM)) failures.push(`3D draws ${st.drawn3d} buildings, the model has ${expectM}`);
  const shownCount = await page.textContent("#n-buildings");
  if (expectN !== null && Number(shownCount) !== Number(expectN)) failures.push(`summary says ${shownCount} buildings`);

  const clickId = arg("--click-id");
  if (clickId !== null) {
    const p = await page.evaluate((id) => window.cityforgeViewer.mapPoint(id), clickId);
    if (!p) failures.push(`building ${clickId} is not on the map`);
    else {
      const box = await (await page.$("#map")).boundingBox();
      await page.mouse.click(box.x + p[0], box.y + p[1]);
      const id = await page.textContent("#sel-id").catch(() => null);
      const h = await page.textContent("#sel-height").catch(() => null);
      summary.map_click = { id, height: h };
      if (id !== clickId) failures.push(`map click on ${clickId} shows building ${id}`);
      const eh = arg("--expect-height");
      if (eh !== null && !(h !== null && Math.abs(Number(h) - Number(eh)) < 0.0015)) failures.push(`map click shows height ${h}, expected ${eh}`);
    }
  }
  const click3d = arg("--click3d-id");
  if (click3d !== null) {
    await page.evaluate(() => document.getElementById("info").replaceChildren());
    const p = await page.evaluate((id) => window.cityforgeViewer.scenePoint(id), click3d);
    if (!p) failures.push(`building ${click3d} is not in the 3D view`);
    else {
      const box = await (await page.$("#scene")).boundingBox();
      await page.mouse.click(box.x + p[0], box.y + p[1]);
      const id = await page.textContent("#sel-id").catch(() => null);
      summary.scene_click = { id };
      if (id !== click3d) failures.push(`3D click on ${click3d} shows building ${id}`);
    }
  }
  await page.screenshot({ path: path.join(outdir, "viewer.png") });
  summary.screenshot = path.join(outdir, "viewer.png");
  summary.console_errors = consoleErrors;
  summary.remote_requests = remote;
  if (consoleErrors.length) failures.push(`console errors: ${consoleErrors.join(" | ")}`);
  if (remote.length) failures.push(`requests off the disk: ${remote.join(", ")}`);
} catch (e) {
  failures.push(String(e && e.message ? e.message : e));
} finally {
  await context.close();
  fs.rmSync(userData, { recursive: true, force: true });
}
summary.failures = failures;
console.log(JSON.stringify(summary, null, 1));
process.exit(failures.length ? 1 : 0);
