#!/usr/bin/env bash
# Sets up (if needed), builds and runs the whole test suite with ctest.
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
bash "$here/scripts/build.sh"
cd "$here/build"
ctest --output-on-failure --parallel "$(nproc)" "$@"
