// Bundles the viewer (web/src) into one HTML template with its script and
// styles inline: `node web/build.mjs OUT.html`. cityforge embeds the template
// and fills the data placeholder, so a page works from disk, offline.
import fs from "node:fs";
import path from "node:path";
import { fileURLToPath } from "node:url";

const here = path.dirname(fileURLToPath(import.meta.url));
const out = process.argv[2];
if (!out) {
  console.error("usage: node web/build.mjs OUT.html");
  process.exit(2);
}
let esbuild;
try {
  esbuild = await import("esbuild");
} catch {
  console.error("cityforge: web/node_modules is missing: run scripts/install_deps.sh (npm ci in web/)");
  process.exit(1);
}
const result = await esbuild.build({
  entryPoints: [path.join(here, "src/main.js")],
  bundle: true,
  minify: true,
  format: "iife",
  target: "es2020",
  write: false,
  legalComments: "none",
  logLevel: "error",
});
const js = result.outputFiles[0].text.replace(/<\/script/gi, "<\\/script");
const css = fs.readFileSync(path.join(here, "src/style.css"), "utf8");
const html = fs
  .readFileSync(path.join(here, "src/index.html"), "utf8")
  .replace("/*CITYFORGE_STYLE*/", () => css)
  .replace("/*CITYFORGE_SCRIPT*/", () => js);
if (!html.includes("<!--CITYFORGE_DATA-->")) throw new Error("index.html lacks the data placeholder");
fs.mkdirSync(path.dirname(out), { recursive: true });
fs.writeFileSync(out + ".tmp", html);
fs.renameSync(out + ".tmp", out);
