#!/usr/bin/env bash
# Trains the detector models shipped in models/ (used by `cityforge footprints`
# ortho-only when no --model is given), reproducibly, from the dev sets only:
#   models/default_rgb_fine.cfdet    RGB(A) at 0.26-0.30 m: the five OpenAerialMap places and the 0.3 m synthetic town
#                                    (CNN pixel stage, finer segments: see README "session 15"; its map the
#                                    mean under the 8 flips/transposes: README "Test-time augmentation")
#   models/default_rgb_coarse.cfdet  RGB at 0.48-0.50 m: the seven SpaceNet-1 Rio tiles (EPSG:4326) and the 0.5 m synthetic town
#   models/default_pan.cfdet         one band: SpaceNet-4 Atlanta pan west (UInt16) plus the green band of every RGB set above
# `footprints` without --model takes, for the image's bands, the default model whose training GSDs (in its
# header) are nearest the image's GSD (src/pipeline/train_run.hpp, default_model_path).
# Never reads ../shared/data/holdout/. Same data, same seed -> same model bytes (whatever the thread count).
#
#   scripts/train_default_models.sh [BUILD_DIR]      (default build/; data from ../shared/data or $CITYFORGE_DATA)
# Experiments: $CITYFORGE_MODELS_OUT writes the two models elsewhere (default models/),
# $CITYFORGE_ONLY=rgb|pan trains the RGB ones or the pan one, $CITYFORGE_TRAIN_ARGS adds train options; the shipped models take none.
# Prints each model's cross-validation figures (5 spatial folds, 60 m blocks).
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
build="${1:-$here/build}"
cf="$build/bin/cityforge"
data="${CITYFORGE_DATA:-$here/../shared/data}"
work="$(mktemp -d)"
trap 'rm -rf "$work"' EXIT
[ -x "$cf" ] || { echo "train_default_models: build cityforge first ($cf missing)" >&2; exit 1; }

"$cf" --quiet synth --out "$work/synth_a" --size-m 400 --gsd 0.5 --seed 101 --cloud-density 0
"$cf" --quiet synth --out "$work/synth_b" --size-m 300 --gsd 0.3 --seed 102 --cloud-density 0

rgb=(
  oam_zanzibar_rgb/zanzibar_z19_north_rgb.tif oam_zanzibar_rgb/zanzibar_z19_north_buildings.geojson
  oam_kampala_rgba/kampala_z19_east_rgba.tif oam_kampala_rgba/kampala_z19_east_buildings.geojson
  oam_nairobi_rgb/nairobi_z19_east_rgb.tif oam_nairobi_rgb/nairobi_z19_east_buildings.geojson
  oam_catanduanes_banepa/catanduanes_z19_a_rgb.tif oam_catanduanes_banepa/catanduanes_z19_a_buildings.geojson
  oam_catanduanes_banepa/banepa_z19_a_rgba.tif oam_catanduanes_banepa/banepa_z19_a_buildings.geojson
)
for i in 50 51 52 53 54 55 56; do
  rgb+=(spacenet1_rio_rgb/3band_013022223130_Public_img${i}_rgb.tif spacenet1_rio_rgb/3band_013022223130_Public_img${i}_buildings.geojson)
done
fine=() coarse=()
pan=(--ortho "$data/spacenet4_atlanta_pan_west/atlanta_pan_0p5m_west.tif" --labels "$data/spacenet4_atlanta_pan_west/buildings_west.geojson")
for ((k = 0; k < ${#rgb[@]}; k += 2)); do
  img="$data/${rgb[k]}" lab="$data/${rgb[k+1]}"
  case "$img" in *spacenet1_rio*) coarse+=(--ortho "$img" --labels "$lab") ;; *) fine+=(--ortho "$img" --labels "$lab") ;; esac
  # The green band as a panchromatic stand-in (an alpha band stays the mask).
  g="$work/pan_$(basename "${rgb[k]}")"
  if gdalinfo "$img" | grep -q "ColorInterp=Alpha"; then
    gdal_translate -q -b 2 -b 4 -colorinterp gray,alpha "$img" "$g"
  else
    gdal_translate -q -b 2 "$img" "$g"
  fi
  pan+=(--ortho "$g" --labels "$lab")
done
coarse+=(--ortho "$work/synth_a/ortho.tif" --labels "$work/synth_a/truth.geojson")
fine+=(--ortho "$work/synth_b/ortho.tif" --labels "$work/synth_b/truth.geojson")
for t in synth_a synth_b; do
  gdal_translate -q -b 2 "$work/$t/ortho.tif" "$work/pan_$t.tif"
  pan+=(--ortho "$work/pan_$t.tif" --labels "$work/$t/truth.geojson")
done

# Segmentation scales hold at 0.3 m and shrink with coarser images (segments
# of the same ground size: Rio and Atlanta at 0.5 m merge at 18, 36, 72);
# the pixel stage filters 0.8 m cells (factor 3 at 0.3 m, 2 at 0.5 m).
common=(--seed 1 --reference-gsd-m 0.3 --pixel-cell-m 0.8)
# shellcheck disable=SC2206  # experiments: extra train options, split on blanks
[ -n "${CITYFORGE_TRAIN_ARGS:-}" ] && common+=(${CITYFORGE_TRAIN_ARGS})
out="${CITYFORGE_MODELS_OUT:-$here/models}"
only="${CITYFORGE_ONLY:-}"
mkdir -p "$out"
# The fine RGB model: the CNN pixel stage and finer first segments, which win
# OAM's cross-validation (README "session 15"), and the CNN's map averaged over
# the 8 flips and transposes (OAM 0.552 / 0.556 / 0.569 on seeds 1-3 against
# 0.534 / 0.550 / 0.555: README "Test-time augmentation"); the coarse one keeps the common options.
fine_opts=(--pixel-stage cnn --scales 20,40,80,160 --merge-thresholds 0.7,0.8,0.9,0.95 --pixel-cnn-tta 8)
if [ "$only" != pan ]; then
  echo "== $out/default_rgb_fine.cfdet" >&2
  "$cf" train "${fine[@]}" "${common[@]}" "${fine_opts[@]}" --out "$out/default_rgb_fine.cfdet" --overwrite
  echo "== $out/default_rgb_coarse.cfdet" >&2
  "$cf" train "${coarse[@]}" "${common[@]}" --out "$out/default_rgb_coarse.cfdet" --overwrite
fi
# The pan model: fewer watershed basins (h-minima 6) and a segment labelled
# building from 35 % label cover, chosen on Atlanta's CV (dark roofs among
# tree shadows; README "Atlanta pan").
pan_opts=(--h-minima 6 --min-label-share 0.35)
if [ "$only" != rgb ]; then
  echo "== $out/default_pan.cfdet" >&2
  "$cf" train "${pan[@]}" "${common[@]}" "${pan_opts[@]}" --out "$out/default_pan.cfdet" --overwrite
fi
