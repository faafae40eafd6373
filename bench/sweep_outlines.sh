#!/usr/bin/env bash
# Outlines from ortho + cloud on many varied synthetic towns (issue #17):
# each variant of the generator on each seed, scored against the exact truth
# by build/bin/bench_accuracy (F1 at IoU 0.5, mean IoU, mean |area error|),
# then the mean per variant over the seeds. Measure on seeds you did not
# look at while changing the code.
#
#   bash bench/sweep_outlines.sh [SEED ...]          (default: 210 211 212)
#   SIZE=300 VARIANTS="default dark" bash bench/sweep_outlines.sh 213
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
bin="$here/build/bin/bench_accuracy"
[ -x "$bin" ] || { echo "sweep_outlines: build first (bash scripts/build.sh)" >&2; exit 1; }
seeds=("$@")
[ ${#seeds[@]} -gt 0 ] || seeds=(210 211 212)
declare -A V=(
  [default]=""
  [slope]="slope=0.1 undulation=3"
  [groundlike]="ground_like=0.5"
  [trees]="trees=0.8"
  [dark]="dark=0.4"
  [dark4]="dark=0.4 density=4 sun_el=25"
  [oblique]="oblique=0.6"
  [sun]="sun_az=300 sun_el=25"
  [dens4]="density=4"
  [dens20]="density=20"
  [mix]="slope=0.08 ground_like=0.4 oblique=0.5 trees=0.6 sun_az=230 sun_el=30 dark=0.2"
  [terraced]="terraced=0.5"
  [round]="round=0.5"
)
variants=(${VARIANTS:-default slope groundlike trees dark dark4 oblique sun dens4 dens20 mix terraced round})
work="$(mktemp -d /tmp/cityforge_sweep.XXXXXX)"
trap 'rm -rf "$work"' EXIT
printf '%-11s %6s %7s %7s %9s\n' variant seed F1 IoU "|area|%"
for v in "${variants[@]}"; do
  for s in "${seeds[@]}"; do
    # shellcheck disable=SC2086
    line=$("$bin" size="${SIZE:-300}" seed="$s" stages=outlines ${V[$v]} dir="$work/t" | grep '^outlines')
    f1=$(sed -E 's/.*F1 ([0-9.]+).*/\1/' <<<"$line")
    iou=$(sed -E 's/.*mean IoU ([0-9.]+).*/\1/' <<<"$line")
    area=$(sed -E 's/.*mean \|area error\| ([0-9.]+) %.*/\1/' <<<"$line")
    printf '%-11s %6s %7s %7s %9s\n' "$v" "$s" "$f1" "$iou" "$area"
    echo "$v $f1 $iou $area" >>"$work/all"
  done
done
echo "mean over seeds ${seeds[*]}:"
awk '{n[$1]++; f[$1]+=$2; i[$1]+=$3; a[$1]+=$4} END {for (v in n) printf "%-11s F1 %.3f  IoU %.3f  |area| %.2f %%\n", v, f[v]/n[v], i[v]/n[v], a[v]/n[v]}' "$work/all" | sort
