#!/usr/bin/env bash
# Peak memory of heights, cloud rasterize and footprints on large clouds:
# held whole versus read window by window (--max-points-in-memory), with
# /usr/bin/time -v. Prints points, peak RSS, bytes per point, wall and CPU
# seconds, and whether the windowed outputs equal the whole-cloud ones.
#
#   bash bench/bench_stream.sh [SIZE_M NX NY [DENSITY]]   (default 700 4 4 8: ~63 M points)
#   BENCH_DIR=/tmp/x WHOLE=0 bash bench/bench_stream.sh 700 8 8   (skip the whole-cloud runs)
set -euo pipefail
here=$(cd "$(dirname "$0")/.." && pwd)
bin=${BIN:-$here/build/bin}
size=${1:-700} nx=${2:-4} ny=${3:-4} density=${4:-8}
dir=${BENCH_DIR:-/tmp/cityforge_bench_stream_${size}_${nx}x${ny}}
whole=${WHOLE:-1}
[ -f "$dir/mosaic.las" ] || nice -n 10 "$bin/bench_stream" "$dir" "$size" "$nx" "$ny" "$density" 5
points=$(nice -n 10 "$bin/cityforge" info "$dir/mosaic.las" --json 2>/dev/null | python3 -c 'import json,sys; j=json.load(sys.stdin); print(j.get("points", j.get("point_count", 0)))' || echo 0)
echo "cloud: $dir/mosaic.las, $points points"
measure() {  # label, command...
    local label=$1; shift
    local log; log=$(mktemp)
    /usr/bin/time -v nice -n 10 "$@" --quiet > /dev/null 2> "$log" || { echo "$label: FAILED"; tail -5 "$log"; return; }
    python3 - "$label" "$points" "$log" <<'PY'
import re, sys
label, points, log = sys.argv[1], int(sys.argv[2]), open(sys.argv[3]).read()
rss = int(re.search(r"Maximum resident set size \(kbytes\): (\d+)", log).group(1)) * 1024
user = float(re.search(r"User time \(seconds\): ([\d.]+)", log).group(1))
sys_ = float(re.search(r"System time \(seconds\): ([\d.]+)", log).group(1))
m = re.search(r"Elapsed \(wall clock\) time \(h:mm:ss or m:ss\): (?:(\d+):)?(\d+):([\d.]+)", log)
wall = int(m.group(1) or 0) * 3600 + int(m.group(2)) * 60 + float(m.group(3))
print(f"{label:34s} peak {rss / 2**30:6.2f} GiB  {rss / max(points, 1):7.1f} bytes/point  wall {wall:7.1f} s  CPU {user + sys_:7.1f} s")
PY
    rm -f "$log"
}
out=$dir/out
mkdir -p "$out"
big=100000000000  # a budget no file reaches: held whole
for mode in whole windows; do
    [ "$mode" = whole ] && [ "$whole" = 0 ] && continue
    budget=$([ "$mode" = whole ] && echo $big || echo 20000000)
    measure "heights ($mode)" "$bin/cityforge" heights --footprints "$dir/mosaic_footprints.gpkg" --cloud "$dir/mosaic.las" \
        --out "$out/heights_$mode.geojson" --max-points-in-memory $budget --overwrite
    measure "cloud rasterize --gsd 1 ($mode)" "$bin/cityforge" cloud rasterize --cloud "$dir/mosaic.las" --gsd 1 \
        --out "$out/rasters_$mode" --max-points-in-memory $budget --overwrite
    measure "footprints cloud_only ($mode)" "$bin/cityforge" footprints --cloud "$dir/mosaic.las" --gsd 1 \
        --out "$out/footprints_$mode.geojson" --max-points-in-memory $budget --overwrite
done
if [ "$whole" = 1 ]; then
    for f in heights_X.geojson footprints_X.geojson rasters_X/dsm.tif rasters_X/dtm.tif rasters_X/ndsm.tif rasters_X/density.tif; do
        a=$out/${f/X/whole} b=$out/${f/X/windows}
        cmp -s "$a" "$b" && echo "same bytes: ${f/X/*}" || echo "DIFFERENT: ${f/X/*}"
    done
fi
