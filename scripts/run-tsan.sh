#!/usr/bin/env bash
# The threaded tests under ThreadSanitizer: the `tsan-threads` presets of CMakePresets.json, in
# build-tsan-threads/. Only what the tests need is built — libvoxfmt, the runtime, the Bullet integration and
# five test programs on exact spheres made in code (no bake, CGAL or OpenVDB) — and any report fails the run
# (TSAN_OPTIONS=halt_on_error=1). What CI runs.
#   test_bullet_threads   a pile of VPS bodies sharing one object: the narrow phase on 2 and 4 threads
#                         (ParallelCollisionDispatcher) and Bullet's btCollisionDispatcherMt in a Mt world
#   test_runtime_threads  one object queried from 4 threads; LatestValue between two threads
#   test_batch_scene      runtime::BatchScene's environments on 2 and 3 worker threads
#   test_haptics          RealtimeLoop.*: the loop's own thread
#   test_format           Write.*Progress*: a write's progress, told from its compressing and checking threads
# Bullet is Debian's uninstrumented build: races inside Bullet are invisible to TSan, this project's are not.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/install-deps.sh
# ccache keys on paths relative to the checkout, so a fresh clone elsewhere reuses the cache.
export CCACHE_BASEDIR=${CCACHE_BASEDIR:-$PWD}
start=$SECONDS
cmake --preset tsan-threads ${CMAKE_ARGS:-} >/dev/null
cmake --build --preset tsan-threads -j "${JOBS:-$(nproc)}"
built=$SECONDS
ctest --preset tsan-threads -j "${JOBS:-$(nproc)}"
echo "run-tsan: built in $((built - start)) s, tests in $((SECONDS - built)) s"
