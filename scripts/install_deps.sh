#!/usr/bin/env bash
# Installs the Debian 12 packages cityforge needs to build, test and run.
# Idempotent: packages already present are left alone; safe to run again.
set -euo pipefail

PACKAGES=(
  build-essential cmake pkg-config ninja-build ccache
  libgdal-dev gdal-bin libproj-dev proj-bin
  libgeographiclib-dev
  libcgal-dev libeigen3-dev libboost-dev
  libopencv-dev libopencv-imgproc-dev libopencv-core-dev
  libopencv-calib3d-dev libopencv-features2d-dev libopencv-imgcodecs-dev colmap
  catch2 libtbb-dev nlohmann-json3-dev libcli11-dev libgeos-dev libnanoflann-dev
  libxml2-utils libsqlite3-dev python3
  libxgboost-dev libtorch-dev
  openmpi-bin
  chromium postgresql-15 postgresql-15-postgis-3
)

missing=()
for p in "${PACKAGES[@]}"; do
  if ! dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed"; then
    missing+=("$p")
  fi
done

# The tests validate our JSON outputs (reports, CityJSON) with ajv from npm.
if ! command -v node >/dev/null 2>&1 || ! command -v npm >/dev/null 2>&1; then
  missing+=(nodejs npm)
fi

if [ ${#missing[@]} -eq 0 ]; then
  echo "cityforge: all build dependencies are installed" >&2
else
  SUDO=""
  if [ "$(id -u)" -ne 0 ]; then SUDO="sudo"; fi
  echo "cityforge: installing ${missing[*]}" >&2
  export DEBIAN_FRONTEND=noninteractive
  $SUDO apt-get update -qq
  $SUDO apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
fi

# JSON Schema validator for the tests (tools/schema_check, pinned by its lock file).
here="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
if [ ! -d "$here/tools/schema_check/node_modules/ajv" ]; then
  echo "cityforge: installing the JSON Schema validator (npm ci)" >&2
  (cd "$here/tools/schema_check" && npm ci --no-audit --no-fund --loglevel=error >/dev/null)
fi

# glTF validator + headless-Chromium driver (tools/validators) and the web
# viewer's bundler and libraries (web/), each pinned by its lock file. The
# browser is Debian's chromium: playwright-core never downloads one.
for d in tools/validators web; do
  if [ ! -f "$here/$d/node_modules/.package-lock.json" ] || [ "$here/$d/package-lock.json" -nt "$here/$d/node_modules/.package-lock.json" ]; then
    echo "cityforge: installing npm packages of $d (npm ci)" >&2
    (cd "$here/$d" && PLAYWRIGHT_SKIP_BROWSER_DOWNLOAD=1 npm ci --no-audit --no-fund --loglevel=error >/dev/null)
  fi
done
