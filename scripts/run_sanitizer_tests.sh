#!/usr/bin/env bash
# The sanitizer step of CI: builds the CLI and the test suite with
# AddressSanitizer + UndefinedBehaviorSanitizer (-DCITYFORGE_SANITIZE=ON) into
# build-asan/ and runs the tests registered there (the subset of
# CITYFORGE_SANITIZE_TESTS in tests/CMakeLists.txt: readers, parsers, fuzzing,
# faults, LAZ, geometry and roofs). Any memory error or undefined behaviour
# aborts its test, so CI fails. ccache (shared) makes rebuilds cheap.
#   bash scripts/run_sanitizer_tests.sh [extra ctest arguments]
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
bash "$here/scripts/install_deps.sh"
# -U: the subset comes from tests/CMakeLists.txt, not from an older cache.
cmake -S "$here" -B "$here/build-asan" -G Ninja -DCMAKE_BUILD_TYPE=Release -DCITYFORGE_SANITIZE=ON -DCITYFORGE_BUILD_BENCH=OFF -UCITYFORGE_SANITIZE_TESTS \
  -DCITYFORGE_WERROR=OFF >/dev/null  # warnings are errors in the Release build; GCC 12 warns falsely under -fsanitize (std::regex)
cmake --build "$here/build-asan" --parallel "$(nproc)" --target cityforge_cli cityforge_tests
# halt_on_error: the first report fails the test. Suppressions are commented in
# their files. Leaks are reported too (detect_leaks), third-party ones suppressed.
export ASAN_OPTIONS="halt_on_error=1:abort_on_error=1:detect_leaks=1:detect_stack_use_after_return=0:strict_string_checks=1"
export UBSAN_OPTIONS="halt_on_error=1:print_stacktrace=1:suppressions=$here/tests/sanitizer/ubsan.supp"
export LSAN_OPTIONS="suppressions=$here/tests/sanitizer/lsan.supp:print_suppressions=0"
cd "$here/build-asan"
ctest --output-on-failure --parallel "$(nproc)" "$@"
