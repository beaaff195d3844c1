#!/usr/bin/env bash
# Installs dependencies (only what is missing) and builds the project into build/ (Release, Ninja, ccache).
# TARGETS="a b" builds only those targets (and what they need): scripts/run-main.sh builds only its programs.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/install-deps.sh
BUILD_DIR=${BUILD_DIR:-build}
# ccache keys on paths relative to the checkout, so a fresh clone elsewhere reuses the cache.
export CCACHE_BASEDIR=${CCACHE_BASEDIR:-$PWD}
# One line per stage; the compiler's output goes to a log, shown (its end) only if the build fails. VERBOSE=1
# shows everything as it happens.
mkdir -p .logs
log=.logs/build-$(basename "$BUILD_DIR").log
run() {
  if [ "${VERBOSE:-0}" = 1 ]; then "$@"; return; fi
  if ! "$@" >>"$log" 2>&1; then
    grep -E "error|Error|FAILED" "$log" | tail -n 20 >&2 || true
    tail -n 20 "$log" >&2
    echo "build: failed; the whole log is $log" >&2
    exit 1
  fi
}
: >"$log"
start=$SECONDS
echo "build: configuring $BUILD_DIR (log: $log)"
run cmake -S . -B "$BUILD_DIR" -G Ninja -DCMAKE_BUILD_TYPE=${BUILD_TYPE:-Release} ${CMAKE_ARGS:-}
if [ -n "${TARGETS:-}" ]; then
  echo "build: compiling $TARGETS on ${JOBS:-$(nproc)} cores (minutes the first time; ccache makes the next ones quick) ..."
  # shellcheck disable=SC2086 # a list of target names
  run cmake --build "$BUILD_DIR" -j "${JOBS:-$(nproc)}" --target $TARGETS
  echo "build: $TARGETS in $BUILD_DIR/bin are up to date ($((SECONDS - start)) s)"
else
  echo "build: compiling on ${JOBS:-$(nproc)} cores (a fresh build takes 10-20 min on 2 cores; ccache makes the next ones quick) ..."
  run cmake --build "$BUILD_DIR" -j "${JOBS:-$(nproc)}"
  echo "build: $BUILD_DIR/bin is up to date ($((SECONDS - start)) s)"
fi
