#!/usr/bin/env bash
# Viewer benchmark: a synthetic city of SIZE_M x SIZE_M (default 4000 m = 16 km²,
# ~9,700 buildings) exported by bench_export (every format, 3D Tiles and glTF
# included), its viewer page written by `cityforge view`, then opened from disk
# in headless Chromium: prints the page size and the time until the page is
# ready (map and 3D drawn). Run from the repository root after a build.
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
size="${1:-4000}"
"$here/build/bin/bench_export" "$size"
dir="${TMPDIR:-/tmp}/cityforge_bench_export"
/usr/bin/time -f "view: %e s, peak %M kB" "$here/build/bin/cityforge" view "$dir" --overwrite
node "$here/tools/validators/view_check.mjs" "$dir/view/index.html" "$dir/view_check" |
  node -e 'let s="";process.stdin.on("data",d=>s+=d).on("end",()=>{const j=JSON.parse(s);console.log(`viewer ready in ${j.load_ms} ms headless; ${j.drawn_map} buildings on the map, ${j.drawn_3d} in 3D; failures: ${j.failures.length}`)})'
