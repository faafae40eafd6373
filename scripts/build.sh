#!/usr/bin/env bash
# Installs dependencies if missing and builds cityforge (Release) into build/.
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
bash "$here/scripts/install_deps.sh"
cmake -S "$here" -B "$here/build" -G Ninja -DCMAKE_BUILD_TYPE=Release -DCITYFORGE_WERROR=ON >/dev/null
cmake --build "$here/build" --parallel "$(nproc)"
