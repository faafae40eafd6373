#!/usr/bin/env bash
# End-to-end benchmark of `cityforge run` on synthetic cities (8 pts/m²,
# LiDAR-like): per-stage seconds, peak memory and buildings per second for
# each size, to see whether the cost is linear in the area.
#
#   bash bench/bench_run.sh [size_m ...]      (default: 1000 2000 4000 = 1, 4, 16 km²)
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
bash "$here/scripts/build.sh" >/dev/null
cf="$here/build/bin/cityforge"
work="${TMPDIR:-/tmp}/cityforge_bench_run"
mkdir -p "$work"
sizes=("$@")
[ ${#sizes[@]} -eq 0 ] && sizes=(1000 2000 4000)
printf "%-8s %-6s %-9s %-8s %-8s %-10s %-10s %-8s %-9s %-10s %s\n" size_m km2 buildings tiles total_s cloud_s detect+fp_s heights_s roofs_s peak_MB bldg/s
for s in "${sizes[@]}"; do
  scene="$work/scene_$s"
  [ -f "$scene/cloud.las" ] || "$cf" synth --out "$scene" --size-m "$s" --seed 1 --cloud-density 8 --quiet
  rm -rf "$work/run_$s"
  start=$(date +%s.%N)
  "$cf" run --ortho "$scene/ortho.tif" --cloud "$scene/cloud.las" --out "$work/run_$s" --tile-size 2000 --overlap-m 100 \
    --vertical-crs EPSG:5773 --quiet
  end=$(date +%s.%N)
  /usr/bin/python3 - "$work/run_$s/run_report.json" "$s" "$start" "$end" <<'PY'
import json, sys
r = json.load(open(sys.argv[1])); s = float(sys.argv[2]); wall = float(sys.argv[4]) - float(sys.argv[3])
st = r["stage_seconds"]; n = r["counts"]["buildings"]
print(f"{s:<8.0f} {s*s/1e6:<6.1f} {n:<9d} {len(r['tiles']):<8d} {wall:<8.1f} {st.get('cloud',0):<8.1f} "
      f"{st.get('detection',0)+st.get('footprints',0):<10.1f} {st.get('heights',0):<10.1f} {st.get('roofs',0):<8.1f} "
      f"{r['peak_memory_mb']:<9.0f} {n/wall:<10.0f}")
PY
done
