#!/usr/bin/env bash
# Installs the Debian 12 packages cityforge needs to build, test and run.
# Idempotent: packages already present are left alone; safe to run again.
set -euo pipefail

PACKAGES=(
  build-essential cmake pkg-config ninja-build
  libgdal-dev gdal-bin libproj-dev proj-bin
  libgeographiclib-dev
  libcgal-dev libeigen3-dev libboost-dev
  libopencv-imgproc-dev libopencv-core-dev
  catch2 libtbb-dev nlohmann-json3-dev libcli11-dev libgeos-dev libnanoflann-dev
  libxml2-utils
)

missing=()
for p in "${PACKAGES[@]}"; do
  if ! dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed"; then
    missing+=("$p")
  fi
done

if [ ${#missing[@]} -eq 0 ]; then
  echo "cityforge: all build dependencies are installed" >&2
  exit 0
fi

SUDO=""
if [ "$(id -u)" -ne 0 ]; then SUDO="sudo"; fi
echo "cityforge: installing ${missing[*]}" >&2
export DEBIAN_FRONTEND=noninteractive
$SUDO apt-get update -qq
$SUDO apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
