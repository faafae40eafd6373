#!/usr/bin/env bash
# Viewer benchmark: a synthetic city of SIZE_M x SIZE_M (default 4000 m = 16 km²,
# ~9,700 buildings) exported by bench_export (every format, 3D Tiles and glTF
# included), its viewer page written by `cityforge view`, then opened from disk
# in headless Chromium: prints the page size and the time until the page is
# ready (map and 3D drawn). Run from the repository root after a build.
#
#   bash bench/bench_view.sh [size_m [bench_export options]]
#
# e.g. `bash bench/bench_view.sh 4100 --lod2-cache C.jsonl --texture-ortho S/ortho.tif`
# for LOD2 roofs textured from the ortho (see bench_export.cpp). Then also the
# 3D Tiles view of the page is opened and timed.
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
size="${1:-4000}"
shift || true
"$here/build/bin/bench_export" "$size" "$@"
dir="${TMPDIR:-/tmp}/cityforge_bench_export"
/usr/bin/time -f "view: %e s wall, %U s user + %S s sys, peak %M kB" "$here/build/bin/cityforge" view "$dir" --overwrite
node "$here/tools/validators/view_check.mjs" "$dir/view/index.html" "$dir/view_check" |
  node -e 'let s="";process.stdin.on("data",d=>s+=d).on("end",()=>{const j=JSON.parse(s);console.log(`viewer ready in ${j.load_ms} ms headless; ${j.drawn_map} buildings on the map, ${j.drawn_3d} in 3D; failures: ${j.failures.length}`)})'
ls -l "$dir/view/index.html" "$dir/view/tiles.js" 2>/dev/null | awk '{printf "%s %.1f MB\n", $NF, $5 / 1e6}' || true
if [ "$#" -gt 0 ]; then
  node "$here/tools/validators/view_check.mjs" "$dir/view/index.html" "$dir/view_check_tiles" --source tiles |
    node -e 'let s="";process.stdin.on("data",d=>s+=d).on("end",()=>{const j=JSON.parse(s);console.log(`3D Tiles view: page ready in ${j.load_ms} ms, tileset shown in ${j.source_ms} ms (${j.tiles.loaded}/${j.tiles.total} tiles, ${j.drawn_3d} buildings, ${j.textured_meshes} textured meshes); failures: ${j.failures.length}`)})'
fi
