#!/usr/bin/env bash
# The test suite under AddressSanitizer + UndefinedBehaviorSanitizer (the `asan` preset's settings) in
# build-asan/: any report fails the run. Slower than the release run (about 3x); ccache keeps rebuilds short.
#   SANITIZER_SCOPE=all      (default) every test, the bake included: ~45 min cold on 2 cores (CGAL's templates)
#   SANITIZER_SCOPE=runtime  what needs no bake: libvoxfmt (read, write, validate), the runtime, haptics and the
#                            Bullet shapes on exact spheres made in code; ~5 min cold, what CI runs
set -euo pipefail
cd "$(dirname "$0")/.."
scope=${SANITIZER_SCOPE:-all}
export BUILD_TYPE=RelWithDebInfo
case "$scope" in
  all) export BUILD_DIR=${BUILD_DIR:-build-asan} ;;
  runtime)
    export BUILD_DIR=${BUILD_DIR:-build-asan-runtime}
    CMAKE_ARGS="-DVOXFMT_BUILD_TOOLS=OFF -DVOXFMT_BUILD_EXAMPLES=OFF -DVOXFMT_BUILD_PYTHON=OFF -DVOXFMT_INSTALL=OFF ${CMAKE_ARGS:-}"
    ;;
  *) echo "run-sanitizers: SANITIZER_SCOPE must be all or runtime, not '$scope'" >&2; exit 2 ;;
esac
export CMAKE_ARGS="-DVOXFMT_SANITIZE=address,undefined ${CMAKE_ARGS:-}"
export ASAN_OPTIONS=${ASAN_OPTIONS:-detect_leaks=1:abort_on_error=1}
export UBSAN_OPTIONS=${UBSAN_OPTIONS:-print_stacktrace=1:halt_on_error=1}
echo "run-sanitizers: ASan + UBSan, scope $scope, in $BUILD_DIR"
bash scripts/run-tests.sh
