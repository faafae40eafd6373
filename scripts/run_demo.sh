#!/usr/bin/env bash
# Sets up (if needed), builds and runs the pipeline that exists so far on the
# sample scene described in samples/. Outputs go to out/demo/.
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
bash "$here/scripts/build.sh"
out="$here/out/demo"
mkdir -p "$out"
cf="$here/build/bin/cityforge"
# The demo is re-runnable: every step regenerates its outputs (same bytes).
cfw=("$cf" --overwrite)
# The sample scene is regenerated from its recipe (samples/sample_scene.args):
# same seed, same bytes, so nothing large is committed.
# shellcheck disable=SC2046
"${cfw[@]}" synth --out "$out/scene" $(grep -v '^#' "$here/samples/sample_scene.args")
"$cf" info "$out/scene/ortho.tif"
"$cf" info "$out/scene/cloud.las"
"${cfw[@]}" segment --ortho "$out/scene/ortho.tif" --out "$out/segments" --config "$here/samples/segment.json"
"${cfw[@]}" cloud rasterize --cloud "$out/scene/cloud.las" --grid "$out/scene/ortho.tif" --out "$out/rasters"
# Footprints from the cloud on the ortho's grid, then their heights.
"${cfw[@]}" footprints --cloud "$out/scene/cloud.las" --ortho "$out/scene/ortho.tif" --out "$out/footprints.gpkg"
"${cfw[@]}" heights --footprints "$out/footprints.gpkg" --cloud "$out/scene/cloud.las" --out "$out/buildings.gpkg"
# City models in every format. The synthetic cloud names no vertical datum;
# EGM96 height is named so that CityGML and CityJSON carry one.
"${cfw[@]}" export --in "$out/buildings.gpkg" --out "$out/model" --vertical-crs EPSG:5773
# Audits of the footprints (against the scene's truth) and of their rectangle fits.
"${cfw[@]}" audit footprints --pred "$out/footprints.gpkg" --ref "$out/scene/truth.geojson" --ortho "$out/scene/ortho.tif" --out "$out/audit_footprints"
"${cfw[@]}" audit rectangles --in "$out/footprints.gpkg" --out "$out/audit_rectangles"
# The whole chain in one command, tiled (400 px tiles, see samples/run.json).
"$cf" run --ortho "$out/scene/ortho.tif" --cloud "$out/scene/cloud.las" --config "$here/samples/run.json" --out "$out/run"
echo "cityforge demo: outputs in $out" >&2
