#!/usr/bin/env bash
# The test suite under AddressSanitizer + UndefinedBehaviorSanitizer (clang 14) in build-asan/: any report fails
# the run. The same tree carries libFuzzer's coverage instrumentation (fuzzer-no-link) and the fuzz targets, so
# scripts/run-fuzzers.sh reuses it instead of compiling the bake a third time. -O2 with line tables only: stack
# traces name files and lines, CGAL's templates compile far faster than with full -g, and Eigen is inlined (at
# -O1 the real-time examples ran 50-100x slower than release).
#   SANITIZER_SCOPE=all      (default) every test, the bake included (what CI runs), but haptic_loop and the quick
#                            benchmarks (tests/CMakeLists.txt says why)
#   SANITIZER_SCOPE=runtime  what needs no bake: libvoxfmt, the runtime, haptics, the Bullet shapes on exact spheres
# The Python extension is not built (CPython would have to load the sanitizer runtime first), so the python.*
# tests are not in this run; the CLI's pytest tests are, against the instrumented voxfmt.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/install-deps.sh
scope=${SANITIZER_SCOPE:-all}
BUILD_DIR=${BUILD_DIR:-build-asan}
case "$scope" in
  all) tools=ON ;;
  runtime) tools=OFF ;;
  *) echo "run-sanitizers: SANITIZER_SCOPE must be all or runtime, not '$scope'" >&2; exit 2 ;;
esac
export CCACHE_BASEDIR=$PWD
echo "run-sanitizers: ASan + UBSan (clang 14), scope $scope, in $BUILD_DIR"
flags="-O2 -gline-tables-only -DNDEBUG"
cmake -S . -B "$BUILD_DIR" -G Ninja -DCMAKE_BUILD_TYPE=RelWithDebInfo -DCMAKE_C_COMPILER=clang-14 \
  -DCMAKE_CXX_COMPILER=clang++-14 -DCMAKE_C_FLAGS_RELWITHDEBINFO="$flags" -DCMAKE_CXX_FLAGS_RELWITHDEBINFO="$flags" \
  -DVOXFMT_SANITIZE=fuzzer-no-link,address,undefined -DVOXFMT_FUZZ=ON -DVOXFMT_BUILD_TOOLS=$tools \
  -DVOXFMT_BUILD_EXAMPLES=$tools -DVOXFMT_BUILD_PYTHON=OFF -DVOXFMT_INSTALL=OFF -DVOXFMT_CUDA=OFF >/dev/null
cmake --build "$BUILD_DIR" -j "${JOBS:-$(nproc)}"
export ASAN_OPTIONS=${ASAN_OPTIONS:-detect_leaks=1:abort_on_error=1}
# Third-party headers with known reports are suppressed by name, each with its reason (tests/sanitizers/).
export UBSAN_OPTIONS=${UBSAN_OPTIONS:-print_stacktrace=1:halt_on_error=1:suppressions=$PWD/tests/sanitizers/ubsan.supp}
# The mixed-scene example simulates 0.2 s instead of 1.5 s (its narrow phase is 50-100x slower instrumented).
export VOXFMT_EXAMPLE_SECONDS=${VOXFMT_EXAMPLE_SECONDS:-0.2}
cd "$BUILD_DIR"
ctest --output-on-failure -j "${JOBS:-$(nproc)}" ${CTEST_ARGS:-}
