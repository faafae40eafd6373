#!/usr/bin/env bash
# Segmentation against the tools a user would otherwise pick (Debian packages):
# scikit-image (watershed; RAG + merge_hierarchical on OUR watershed regions),
# GRASS GIS i.segment (region growing seeded with OUR watershed regions) and
# Orfeo ToolBox (otbcli_Segmentation watershed). Prints seconds and ratios.
#
#   bash bench/compare_peers.sh [size_m]     (default 1000 m = 2000 x 2000 px)
# Needs: build/bin/cityforge (scripts/build.sh) and, installed by this script,
# python3-skimage grass-core otb-bin.
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
size="${1:-1000}"
cf="$here/build/bin/cityforge"
export DEBIAN_FRONTEND=noninteractive
for p in python3-skimage grass-core otb-bin; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || apt-get install -y -qq --no-install-recommends "$p" >/dev/null
done
work="$(mktemp -d /tmp/cityforge_peers.XXXXXX)"
trap 'rm -rf "$work"' EXIT
"$cf" synth --quiet --out "$work/scene" --size-m "$size" --cloud-density 0
ortho="$work/scene/ortho.tif"
now() { date +%s.%N; }

echo "== cityforge (watershed + mutual merging, scales 10..60)"
"$cf" segment --quiet --ortho "$ortho" --out "$work/cf" --scales 10,20,30,40,50,60 --strategy mutual
/usr/bin/python3 - "$work/cf/segment_report.json" > "$work/cf.txt" <<'PY'
import json, sys
r = json.load(open(sys.argv[1]))
merge = sum(s["seconds"] for s in r["scales"])
print(r["oversegmentation"]["regions"], r["oversegmentation"]["seconds"], merge, r["scales"][-1]["regions_after"])
PY
read -r cf_regions cf_ws cf_merge cf_final < "$work/cf.txt"
echo "watershed: $cf_regions regions in $cf_ws s; merging 6 scales: $cf_merge s (-> $cf_final regions)"

echo "== scikit-image $(/usr/bin/python3 -c 'import skimage; print(skimage.__version__)')"
gdal_translate -q -of GTiff -co COMPRESS=NONE "$ortho" "$work/ortho_plain.tif"
gdal_translate -q -of GTiff -co COMPRESS=NONE -ot UInt32 "$work/cf/oversegmentation.tif" "$work/seeds_plain.tif"
/usr/bin/python3 - "$work/ortho_plain.tif" "$work/seeds_plain.tif" > "$work/sk.txt" <<'PY'
import sys, time, numpy as np
from skimage import io, filters, segmentation, color
try:
    from skimage import graph
    graph.rag_mean_color
except AttributeError:  # scikit-image < 0.20 keeps the RAG in skimage.future
    from skimage.future import graph
img = io.imread(sys.argv[1]).astype(np.float64)
t = time.perf_counter()
grad = filters.sobel(color.rgb2gray(img / 255.0))
ws = segmentation.watershed(grad)
t_ws = time.perf_counter() - t
seeds = io.imread(sys.argv[2]).astype(np.int64)
t = time.perf_counter()
rag = graph.rag_mean_color(img, seeds)
t_rag = time.perf_counter() - t
def weight(g, src, dst, n):
    diff = g.nodes[dst]['mean color'] - g.nodes[n]['mean color']
    return {'weight': np.linalg.norm(diff)}
def merge(g, src, dst):
    g.nodes[dst]['total color'] += g.nodes[src]['total color']
    g.nodes[dst]['pixel count'] += g.nodes[src]['pixel count']
    g.nodes[dst]['mean color'] = g.nodes[dst]['total color'] / g.nodes[dst]['pixel count']
t = time.perf_counter()
out = graph.merge_hierarchical(seeds, rag, thresh=20, rag_copy=False, in_place_merge=True,
                               merge_func=merge, weight_func=weight)
t_merge = time.perf_counter() - t
print(len(np.unique(ws)), t_ws, t_rag, t_merge, len(np.unique(out)))
PY
read -r sk_regions sk_ws sk_rag sk_merge sk_final < "$work/sk.txt"
echo "watershed: $sk_regions regions in $sk_ws s; RAG on our $cf_regions regions $sk_rag s + merge_hierarchical $sk_merge s (-> $sk_final regions)"

echo "== GRASS GIS i.segment (seeds = our watershed regions)"
cat > "$work/grass.sh" <<SH
set -e
r.in.gdal --quiet input="$ortho" output=ortho
r.in.gdal --quiet input="$work/cf/oversegmentation.tif" output=seeds
g.region raster=ortho.red
i.group group=g input=ortho.red,ortho.green,ortho.blue
t=\$(date +%s.%N)
i.segment --quiet group=g output=seg seeds=seeds threshold=0.05 minsize=1 memory=4000
echo "\$t \$(date +%s.%N)" > "$work/grass.txt"
SH
grass --tmp-location "$ortho" --exec bash "$work/grass.sh" >/dev/null 2>&1 || echo "GRASS run failed"
if [ -s "$work/grass.txt" ]; then read -r g0 g1 < "$work/grass.txt"; grass_s=$(echo "$g1 - $g0" | bc -l); else grass_s=nan; fi
echo "i.segment on the same seeds: $grass_s s"

echo "== Orfeo ToolBox otbcli_Segmentation (watershed)"
t0=$(now)
timeout "${OTB_TIMEOUT:-900}" otbcli_Segmentation -in "$ortho" -filter watershed -mode raster -mode.raster.out "$work/otb.tif" uint32 >/dev/null 2>&1 || echo "OTB run failed or timed out after ${OTB_TIMEOUT:-900} s"
otb_s=$(echo "$(now) - $t0" | bc -l)
echo "otbcli_Segmentation watershed: $otb_s s"

echo "== ratios (peer seconds / cityforge seconds)"
/usr/bin/python3 - "$cf_ws" "$cf_merge" "$sk_ws" "$sk_rag" "$sk_merge" "$grass_s" "$otb_s" <<'PY'
import sys
cf_ws, cf_merge, sk_ws, sk_rag, sk_merge, grass, otb = map(float, sys.argv[1:])
print(f"watershed: skimage / cityforge = {sk_ws / cf_ws:.1f}x; OTB / cityforge = {otb / cf_ws:.1f}x")
print(f"merging:   skimage RAG+merge / cityforge = {(sk_rag + sk_merge) / cf_merge:.0f}x; GRASS i.segment / cityforge = {grass / cf_merge:.0f}x")
PY
