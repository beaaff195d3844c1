#!/usr/bin/env bash
# The test suite under AddressSanitizer + UndefinedBehaviorSanitizer (the `asan` preset's settings) in
# build-asan/: any report fails the run. Slower than the release run (about 3x); ccache keeps rebuilds short.
set -euo pipefail
cd "$(dirname "$0")/.."
export BUILD_DIR=${BUILD_DIR:-build-asan}
export BUILD_TYPE=RelWithDebInfo
export CMAKE_ARGS="-DVOXFMT_SANITIZE=address,undefined ${CMAKE_ARGS:-}"
export ASAN_OPTIONS=${ASAN_OPTIONS:-detect_leaks=1:abort_on_error=1}
export UBSAN_OPTIONS=${UBSAN_OPTIONS:-print_stacktrace=1:halt_on_error=1}
bash scripts/run-tests.sh
