#!/usr/bin/env bash
# End-to-end benchmark of `cityforge run` on synthetic cities (8 pts/m²,
# LiDAR-like): per-stage seconds, peak memory and buildings per second for
# each size, to see whether the cost is linear in the area. CPU seconds
# (user + system of the whole run, from /usr/bin/time) are printed beside the
# wall time: on a shared machine the wall time follows the load, the CPU time
# the work. The stage shares are of the run's own stage seconds.
#
#   bash bench/bench_run.sh [size_m ...]      (default: 1000 2000 4000 = 1, 4, 16 km²)
#   NICE=10 bash bench/bench_run.sh 1000      (run niced on a shared machine)
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
bash "$here/scripts/build.sh" >/dev/null
cf="$here/build/bin/cityforge"
work="${TMPDIR:-/tmp}/cityforge_bench_run"
mkdir -p "$work"
sizes=("$@")
[ ${#sizes[@]} -eq 0 ] && sizes=(1000 2000 4000)
nice_level=${NICE:-0}
printf "%-8s %-6s %-9s %-6s %-8s %-8s %-8s %-18s %-18s %-18s %-18s %-8s %s\n" size_m km2 buildings tiles wall_s cpu_s cpu_s/km2 "cloud_s (share)" "detect+fp_s" "heights_s" "roofs_s" peak_MB bldg/cpu_s
for s in "${sizes[@]}"; do
  scene="$work/scene_$s"
  [ -f "$scene/cloud.las" ] || nice -n "$nice_level" "$cf" synth --out "$scene" --size-m "$s" --seed 1 --cloud-density 8 --quiet
  rm -rf "$work/run_$s"
  start=$(date +%s.%N)
  /usr/bin/time -f "%U %S" -o "$work/time_$s.txt" nice -n "$nice_level" "$cf" run --ortho "$scene/ortho.tif" --cloud "$scene/cloud.las" --out "$work/run_$s" --tile-size 2000 --overlap-m 100 \
    --vertical-crs EPSG:5773 --quiet
  end=$(date +%s.%N)
  /usr/bin/python3 - "$work/run_$s/run_report.json" "$s" "$start" "$end" "$work/time_$s.txt" <<'PY'
import json, sys
r = json.load(open(sys.argv[1])); s = float(sys.argv[2]); wall = float(sys.argv[4]) - float(sys.argv[3])
cpu = sum(float(v) for v in open(sys.argv[5]).read().split()[-2:])
st = r["stage_seconds"]; n = r["counts"]["buildings"]
stages = {"cloud": st.get("cloud", 0), "detect": st.get("detection", 0) + st.get("footprints", 0), "heights": st.get("heights", 0), "roofs": st.get("roofs", 0)}
total = sum(v for k, v in st.items() if k != "total") or 1.0
cell = lambda v: f"{v:.1f} ({100 * v / total:.0f} %)"
km2 = s * s / 1e6
print(f"{s:<8.0f} {km2:<6.1f} {n:<9d} {len(r['tiles']):<6d} {wall:<8.1f} {cpu:<8.1f} {cpu / km2:<8.1f} {cell(stages['cloud']):<18s} "
      f"{cell(stages['detect']):<18s} {cell(stages['heights']):<18s} {cell(stages['roofs']):<18s} {r['peak_memory_mb']:<8.0f} {n / cpu:.1f}")
others = {k: v for k, v in st.items() if k not in ("cloud", "detection", "footprints", "heights", "roofs", "total")}
if others: print("         other stages: " + ", ".join(f"{k} {v:.1f} s ({100 * v / total:.0f} %)" for k, v in sorted(others.items())))
PY
done
