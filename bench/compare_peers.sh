#!/usr/bin/env bash
# Segmentation side by side with the tools a user would otherwise pick, on the
# SAME image window, the SAME seeds and the SAME final region count:
#  - watershed: cityforge (multi-band Sobel gradient, --h-minima 0, no
#    smoothing: every regional minimum a region) against scikit-image
#    watershed(sobel(gray)) (also every regional minimum), region counts printed;
#  - merging: GRASS GIS i.segment seeded with OUR watershed regions (threshold
#    --grass-threshold) gives K regions; cityforge merges the same seeds until
#    exactly K regions remain (RegionMergingOptions::min_regions), mutual queue;
#  - optionally Orfeo ToolBox otbcli_Segmentation (watershed) when installed.
# Prints wall and CPU seconds of each side and the ratios (peer / cityforge).
# The machine may be shared: CPU seconds are the fairer figure; both are printed.
# What each figure holds: scikit-image = rgb2gray + sobel + watershed in the
# Python process (reading excluded); cityforge watershed = band normalisation
# + gradient + flooding (reading excluded). GRASS i.segment = its whole process
# (start-up, reading the group and seeds, merging, writing the map; the
# script also times r.mapcalc over the same maps as an estimate of that I/O);
# cityforge merging = region graph + merging in process, and also its whole
# process (GDAL reading, writing a GeoTIFF) for the like-for-like ratio.
#
#   bash bench/compare_peers.sh [--raster FILE] [--window col,row,w,h | --centre w,h]
#                               [--synth SIZE_M] [--grass-threshold T] [--install]
#                               [--bench PATH]   (another bench_segment build, e.g. an older one)
#                               [--repeat N]     (runs of our merging; medians count, default 5)
# Default: the Autzen ortho (shared data), 2000 x 2000 px around its centre,
# native 1 ft resolution (--centre 4000,4000: the 16 MP window, clipped to the
# raster). Any GDAL raster with 3 or more bands works (the first 3 are used).
# --synth SIZE_M uses a synthetic town instead.
# Needs build/bin/bench_segment (and build/bin/cityforge for --synth) and the
# GDAL tools. The peers are Debian packages: python3-skimage and grass-core;
# --install installs the missing ones with apt-get (about a minute, needs
# root); otherwise a missing peer is skipped with a message.
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
raster="$here/../shared/data/autzen_oregon/autzen_ortho_1ft_epsg2994.tif"
window="624,1192,2000,2000"
synth=""
grass_threshold="0.1"
centre=""
install=0
bench="$here/build/bin/bench_segment"
repeat=5
while [ $# -gt 0 ]; do
  case "$1" in
    --raster) raster="$2"; shift 2 ;;
    --window) window="$2"; shift 2 ;;
    --centre) centre="$2"; shift 2 ;;
    --install) install=1; shift ;;
    --bench) bench="$2"; shift 2 ;;
    --synth) synth="$2"; window=""; shift 2 ;;
    --grass-threshold) grass_threshold="$2"; shift 2 ;;
    --repeat) repeat="$2"; shift 2 ;;
    *) echo "compare_peers.sh: unknown argument $1" >&2; exit 2 ;;
  esac
done
py=/usr/bin/python3
[[ "$repeat" =~ ^[1-9][0-9]*$ ]] || { echo "compare_peers.sh: --repeat needs a positive count" >&2; exit 2; }
[ -x "$bench" ] || { echo "compare_peers.sh: build bench_segment first (cmake --build build --target bench_segment)" >&2; exit 1; }
[ -r "$raster" ] || [ -n "$synth" ] || { echo "compare_peers.sh: cannot read $raster" >&2; exit 1; }
have_sk() { "$py" -c 'import skimage' 2>/dev/null; }
have_grass() { command -v grass >/dev/null; }
if [ "$install" = 1 ] && { ! have_sk || ! have_grass; }; then
  echo "installing the peers (python3-skimage grass-core) with apt-get"
  DEBIAN_FRONTEND=noninteractive apt-get install -y -q --no-install-recommends python3-skimage grass-core >/dev/null 2>&1 \
    || echo "compare_peers.sh: apt-get install failed; missing peers are skipped" >&2
fi
run_sk=1; run_grass=1
have_sk || { run_sk=0; echo "scikit-image not installed (Debian: python3-skimage; or pass --install): watershed comparison skipped"; }
have_grass || { run_grass=0; echo "GRASS GIS not installed (Debian: grass-core; or pass --install): merging comparison skipped"; }
work="$(mktemp -d /tmp/cityforge_peers.XXXXXX)"
trap 'rm -rf "$work"' EXIT
if [ -n "$synth" ]; then
  "$here/build/bin/cityforge" synth --quiet --out "$work/scene" --size-m "$synth" --cloud-density 0
  raster="$work/scene/ortho.tif"
fi
# The window as a plain 3-band GeoTIFF that every tool reads alike.
if [ -n "$centre" ] && [ -z "$synth" ]; then
  IFS=, read -r cw ch <<< "$centre"
  read -r rw rh < <(gdalinfo "$raster" | sed -n 's/^Size is \(.*\), \(.*\)/\1 \2/p')
  cw=$(( cw < rw ? cw : rw )); ch=$(( ch < rh ? ch : rh ))
  window="$(( (rw - cw) / 2 )),$(( (rh - ch) / 2 )),$cw,$ch"
fi
if [ -n "$window" ]; then
  IFS=, read -r c r w h <<< "$window"
  gdal_translate -q -of GTiff -co COMPRESS=NONE -b 1 -b 2 -b 3 -srcwin "$c" "$r" "$w" "$h" "$raster" "$work/ortho.tif"
else
  gdal_translate -q -of GTiff -co COMPRESS=NONE -b 1 -b 2 -b 3 "$raster" "$work/ortho.tif"
fi
ortho="$work/ortho.tif"
size=$(gdalinfo "$ortho" | sed -n 's/^Size is \(.*\), \(.*\)/\1 x \2/p')
echo "image: $raster${window:+ window $window} ($size px); load average: $(cut -d' ' -f1-3 /proc/loadavg)"
json() { "$py" -c "import json,sys; d=json.load(open(sys.argv[1])); print(eval(sys.argv[2], {}, {'d': d}))" "$@"; }
cpu_of() { awk '{print $2 + $3}' "$1"; }  # /usr/bin/time -f "%e %U %S": user + sys
wall_of() { awk '{print $1}' "$1"; }

echo "== cityforge watershed (--h-minima 0, no smoothing)"
"$bench" --raster "$ortho" --h-minima 0 --smoothing 0 --scales 0.001 --strategies mutual \
  --seeds-out "$work/seeds.tif" --json "$work/cf_ws.json" > "$work/cf_ws.txt"
cf_regions=$(json "$work/cf_ws.json" 'd["watershed"]["regions"]')
# Our side counts the band normalisation (percentile stretch) as scikit-image's
# side counts rgb2gray: both prepare the image for the gradient.
cf_ws=$(json "$work/cf_ws.json" 'd["watershed"]["seconds"] + d["watershed"]["normalize_seconds"]')
cf_ws_cpu=$(json "$work/cf_ws.json" 'd["watershed"]["cpu_seconds"] + d["watershed"]["normalize_cpu_seconds"]')
echo "watershed: $cf_regions regions in $cf_ws s wall, $cf_ws_cpu s CPU (band normalisation included, reading the image excluded)"

sk_regions=nan; sk_ws=nan; sk_cpu=nan
if [ "$run_sk" = 1 ]; then
echo "== scikit-image $("$py" -c 'import skimage; print(skimage.__version__)') watershed(sobel(rgb2gray))"
/usr/bin/time -f "%e %U %S" -o "$work/sk.time" "$py" - "$ortho" > "$work/sk.txt" <<'PY'
import sys, time, numpy as np
from skimage import io, filters, segmentation, color
img = io.imread(sys.argv[1])
t = time.perf_counter()
c = time.process_time()
ws = segmentation.watershed(filters.sobel(color.rgb2gray(img[..., :3])))
print(int(ws.max()), time.perf_counter() - t, time.process_time() - c)
PY
read -r sk_regions sk_ws sk_cpu < "$work/sk.txt"
echo "watershed: $sk_regions regions in $sk_ws s wall, $sk_cpu s CPU (reading the image excluded)"
fi

grass_regions=""; g_wall=nan; g_cpu=nan; cf_final=nan; cf_merge=nan; cf_merge_cpu=nan
cf_proc=nan; cf_proc_cpu=nan; g_io=nan; g_io_cpu=nan
if [ "$run_grass" = 1 ]; then
echo "== GRASS GIS $(grass --version 2>&1 | head -1 | awk '{print $3}') i.segment seeds=<our $cf_regions regions> threshold=$grass_threshold"
cat > "$work/grass.sh" <<SH
set -e
r.in.gdal --quiet input="$ortho" output=ortho
r.in.gdal --quiet input="$work/seeds.tif" output=seeds_raw
bands=\$(g.list type=raster pattern='ortho.*' separator=,)
g.region raster=\$(echo "\$bands" | cut -d, -f1)
r.mapcalc --quiet "seeds = int(seeds_raw)"
i.group --quiet group=g input="\$bands"
/usr/bin/time -f "%e %U %S" -o "$work/grass.time" i.segment --quiet group=g output=seg seeds=seeds threshold=$grass_threshold minsize=1 memory=4000
r.stats --quiet -n seg | wc -l > "$work/grass.count"
# What reading the group and the seeds and writing one map costs GRASS (its
# i.segment time includes them): r.mapcalc over the same four maps.
b1=\$(echo "\$bands" | cut -d, -f1); b2=\$(echo "\$bands" | cut -d, -f2); b3=\$(echo "\$bands" | cut -d, -f3)
/usr/bin/time -f "%e %U %S" -o "$work/grass_io.time" r.mapcalc --quiet expression="io = int(\$b1 + \$b2 + \$b3 + seeds)"
SH
grass --tmp-location "$ortho" --exec bash "$work/grass.sh" > "$work/grass.log" 2>&1 || { echo "GRASS run failed:"; tail -5 "$work/grass.log"; exit 1; }
grass_regions=$(tr -d ' ' < "$work/grass.count")
echo "i.segment: $grass_regions regions in $(wall_of "$work/grass.time") s wall, $(cpu_of "$work/grass.time") s CPU"

echo "== cityforge merging the same seeds to $grass_regions regions (mutual queue)"
# Our side takes well under a second, so one load spike swings a single run
# by 20 %: it runs $repeat times (separate processes) and the medians count;
# the spread is printed. GRASS's side is one run of ~45 s, which averages
# the load over its own length.
for ((k = 1; k <= repeat; k++)); do
  "$bench" --raster "$ortho" --seeds-in "$work/seeds.tif" --scales 1e9 --min-regions "$grass_regions" --strategies mutual \
    --json "$work/cf_merge_$k.json" > "$work/cf_merge.txt"
done
med() {  # median (and min-max) of a field over the runs
  "$py" - "$1" "$work"/cf_merge_*.json <<'PY'
import json, statistics, sys
v = [eval(sys.argv[1], {}, {'d': json.load(open(f))['merging']['mutual']}) for f in sys.argv[2:]]
print(statistics.median(v), min(v), max(v))
PY
}
cf_final=$(json "$work/cf_merge_1.json" 'd["merging"]["mutual"]["regions"]')
read -r cf_merge cf_merge_lo cf_merge_hi < <(med 'd["seconds"]')
read -r cf_merge_cpu cf_cpu_lo cf_cpu_hi < <(med 'd["cpu_seconds"]')
read -r cf_graph _ _ < <(med 'd["graph_seconds"]')
read -r cf_graph_cpu _ _ < <(med 'd.get("graph_cpu_seconds", float("nan"))')
echo "merging: $cf_regions -> $cf_final regions, median of $repeat runs: $cf_merge s wall ($cf_merge_lo-$cf_merge_hi), $cf_merge_cpu s CPU ($cf_cpu_lo-$cf_cpu_hi) (region graph included: $cf_graph s wall, $cf_graph_cpu s CPU)"
# The same as a whole process, like the GRASS figure: start-up, reading the
# image and the seeds (GDAL), normalising, merging and writing the labels.
/usr/bin/time -f "%e %U %S" -o "$work/cf_proc.time" "$bench" --raster "$ortho" --seeds-in "$work/seeds.tif" --scales 1e9 \
  --min-regions "$grass_regions" --strategies mutual --labels-out "$work/cf_labels.tif" > /dev/null
cf_proc=$(wall_of "$work/cf_proc.time"); cf_proc_cpu=$(cpu_of "$work/cf_proc.time")
echo "merging as a whole process (reading the image and seeds, writing the labels): $cf_proc s wall, $cf_proc_cpu s CPU"
g_wall=$(wall_of "$work/grass.time"); g_cpu=$(cpu_of "$work/grass.time")
g_io=$(wall_of "$work/grass_io.time"); g_io_cpu=$(cpu_of "$work/grass_io.time")
echo "GRASS reading the four maps and writing one (r.mapcalc, part of the i.segment figure): $g_io s wall, $g_io_cpu s CPU"
[ "$cf_final" = "$grass_regions" ] || echo "WARNING: final region counts differ (GRASS $grass_regions, cityforge $cf_final)"
fi

otb_s=""
if command -v otbcli_Segmentation >/dev/null; then
  echo "== Orfeo ToolBox otbcli_Segmentation (watershed)"
  t0=$(date +%s.%N)
  timeout "${OTB_TIMEOUT:-900}" otbcli_Segmentation -in "$ortho" -filter watershed -mode raster -mode.raster.out "$work/otb.tif" uint32 >/dev/null 2>&1 && otb_s=$(echo "$(date +%s.%N) - $t0" | bc -l) || echo "OTB failed or timed out"
  [ -n "$otb_s" ] && echo "otbcli_Segmentation watershed: $otb_s s"
fi

echo "== ratios (peer / cityforge); load average now: $(cut -d' ' -f1-3 /proc/loadavg)"
"$py" - "$cf_ws" "$cf_ws_cpu" "$cf_regions" "$sk_ws" "$sk_cpu" "$sk_regions" "$g_wall" "$g_cpu" \
  "${grass_regions:-nan}" "$cf_merge" "$cf_merge_cpu" "$cf_final" "${otb_s:-nan}" "$cf_proc" "$cf_proc_cpu" "$g_io" "$g_io_cpu" <<'PY'
import sys
cf_ws, cf_ws_cpu, cf_n, sk_ws, sk_cpu, sk_n, g_wall, g_cpu, g_n, cf_m, cf_m_cpu, cf_final, otb, cf_p, cf_p_cpu, g_io, g_io_cpu = map(float, sys.argv[1:])
if sk_ws == sk_ws:
    print(f"watershed: scikit-image {sk_ws:.2f} s wall, {sk_cpu:.2f} s CPU ({sk_n:.0f} regions) / cityforge {cf_ws:.2f} s wall, "
          f"{cf_ws_cpu:.2f} s CPU ({cf_n:.0f} regions, {cf_n / sk_n:.2f} x as many) = {sk_ws / cf_ws:.1f}x wall, {sk_cpu / cf_ws_cpu:.1f}x CPU")
else:
    print("watershed: scikit-image skipped")
if otb == otb:
    print(f"watershed: OTB {otb:.2f} s / cityforge {cf_ws:.2f} s = {otb / cf_ws:.1f}x")
if g_wall == g_wall:
    print(f"merging the same {cf_n:.0f} seeds -> {g_n:.0f} (GRASS) / {cf_final:.0f} (cityforge) regions: "
          f"GRASS i.segment {g_wall:.2f} s wall / cityforge {cf_m:.3f} s wall = {g_wall / cf_m:.0f}x; "
          f"CPU {g_cpu:.2f} s / {cf_m_cpu:.3f} s = {g_cpu / cf_m_cpu:.0f}x")
    print(f"  both as whole processes (reading and writing included on both sides): GRASS {g_wall:.2f} s / cityforge {cf_p:.2f} s wall = "
          f"{g_wall / cf_p:.0f}x; CPU {g_cpu:.2f} s / {cf_p_cpu:.2f} s = {g_cpu / cf_p_cpu:.0f}x")
    print(f"  both without reading and writing (GRASS minus its r.mapcalc I/O figure): CPU {g_cpu - g_io_cpu:.2f} s / {cf_m_cpu:.3f} s = "
          f"{(g_cpu - g_io_cpu) / cf_m_cpu:.0f}x")
else:
    print("merging: GRASS skipped")
PY
