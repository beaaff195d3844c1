#!/usr/bin/env bash
# Builds the libFuzzer targets (tests/fuzz/) with clang 14, AddressSanitizer and UBSan into build-fuzz/, seeds
# each corpus from real files, and runs each target for SECONDS (default 60) with the format's names as a
# dictionary. Findings (crash-*, timeout-*, leak-*) land in build-fuzz/findings/<target>/; exit 1 if there are any.
#   SECONDS_PER_TARGET=600 bash scripts/run-fuzzers.sh
set -euo pipefail
cd "$(dirname "$0")/.."
SECONDS_PER_TARGET=${SECONDS_PER_TARGET:-60}
bash scripts/install-deps.sh >/dev/null  # clang-14 and libclang-rt-14-dev (libFuzzer) among them
export CCACHE_BASEDIR=$PWD
cmake -S . -B build-fuzz -G Ninja -DCMAKE_BUILD_TYPE=RelWithDebInfo -DCMAKE_C_COMPILER=clang-14 \
  -DCMAKE_CXX_COMPILER=clang++-14 -DVOXFMT_SANITIZE=fuzzer-no-link,address,undefined -DVOXFMT_FUZZ=ON \
  -DVOXFMT_BUILD_TOOLS=OFF -DVOXFMT_BUILD_TESTS=OFF -DVOXFMT_BUILD_EXAMPLES=OFF -DVOXFMT_BUILD_BULLET=OFF \
  -DVOXFMT_BUILD_PYTHON=OFF -DVOXFMT_INSTALL=OFF >/dev/null
cmake --build build-fuzz --target fuzz_asset_reader fuzz_manifest -j "${JOBS:-$(nproc)}"

# Seeds: assets the tests and the main job made (any found), a tiny one written here, and manifest lines.
corpus=build-fuzz/corpus
mkdir -p "$corpus/asset" "$corpus/manifest"
for f in build/Testing/*.vox.h5 out/*.vox.h5 out/library/*.vox.h5; do
  [ -f "$f" ] && [ "$(stat -c %s "$f")" -lt 2000000 ] && cp "$f" "$corpus/asset/" || true
done
cp tests/fuzz/regressions/*.vox.h5 "$corpus/asset/" 2>/dev/null || true
if [ -x build/bin/write_sphere_asset ]; then build/bin/write_sphere_asset "$corpus/asset/sphere.vox.h5" >/dev/null || true; fi
printf '%s\n' '{"input":"a.off","output":"a.vox.h5","status":"ok","size":100}' \
  '{"input":"b.off","output":"b.vox.h5","status":"failed","code":"ZERO_VOLUME"}' >"$corpus/manifest/seed.jsonl"
dict=build-fuzz/voxfmt.dict
{
  for word in HDF TREE HEAP GCOL OHDR SNOD voxfmt format_version voxelmap pointshell mass_properties provenance \
    layers distances points normals sphere_centers sphere_radii child_begin child_count level_offsets voxel_size \
    dims origin distance_band index_order zyx input output status code size; do
    printf '"%s"\n' "$word"
  done
} >"$dict"

status=0
for target in fuzz_asset_reader fuzz_manifest; do
  kind=${target#fuzz_}; kind=${kind%_reader}
  findings=build-fuzz/findings/$target
  mkdir -p "$findings" "build-fuzz/work/$target"
  echo "run-fuzzers: $target for ${SECONDS_PER_TARGET}s"
  (cd "build-fuzz/work/$target" && VOXFMT_READ_ISOLATION=1 ../../bin/$target -max_total_time="$SECONDS_PER_TARGET" \
    -dict="../../voxfmt.dict" -artifact_prefix="../../findings/$target/" -max_len=300000 -timeout=30 \
    -print_final_stats=1 "../../corpus/$kind" 2>&1 | tail -25) || status=1
  if ls "$findings" | grep -q .; then
    echo "run-fuzzers: findings in $findings"
    status=1
  fi
done
exit $status
