#!/usr/bin/env bash
# Builds the libFuzzer targets (tests/fuzz/) in the sanitizer tree of scripts/run-sanitizers.sh (build-asan/:
# clang 14, ASan, UBSan, coverage), seeds each corpus from real files and runs each target for SECONDS_PER_TARGET
# (default 60) with a dictionary. Findings (crash-*, timeout-*, leak-*, oom-*) land in
# build-asan/fuzz/findings/<target>/; exit 1 if there are any.
#   SECONDS_PER_TARGET=600 bash scripts/run-fuzzers.sh              # every target, 10 min each
#   TARGETS="fuzz_mesh_obj fuzz_mesh_stl" bash scripts/run-fuzzers.sh
#   FUZZ_SEED=1 bash scripts/run-fuzzers.sh                          # libFuzzer's seed (default: a random one)
# CI's smoke passes FUZZ_SEED=1: its few seconds a target replay a prefix of the same inputs on every run, so a
# smoke failure is reproducible and CI does not fail on the day a random walk first meets an old path; exploration
# (longer runs, random seeds) is by hand, and what it finds is kept in tests/fuzz/regressions/.
set -euo pipefail
cd "$(dirname "$0")/.."
SECONDS_PER_TARGET=${SECONDS_PER_TARGET:-60}
seed_option=()
[ -n "${FUZZ_SEED:-}" ] && seed_option=(-seed="$FUZZ_SEED")
BUILD_DIR=${BUILD_DIR:-build-asan}
mesh_targets="fuzz_mesh_off fuzz_mesh_obj fuzz_mesh_ply fuzz_mesh_stl fuzz_mesh_gltf"
TARGETS=${TARGETS:-fuzz_asset_reader fuzz_manifest $mesh_targets}
if [ ! -f "$BUILD_DIR/build.ninja" ]; then
  # Configure the sanitizer tree without building or running the whole suite.
  JOBS=${JOBS:-$(nproc)} CTEST_ARGS="-R ^$" bash scripts/run-sanitizers.sh >/dev/null
fi
# shellcheck disable=SC2086
cmake --build "$BUILD_DIR" --target $TARGETS -j "${JOBS:-$(nproc)}"

work=$BUILD_DIR/fuzz
corpus=$work/corpus
mkdir -p "$corpus/asset" "$corpus/manifest"
# Assets: those the tests and the main job made (the small ones), a sphere written here, the kept regressions.
for f in build/Testing/*.vox.h5 out/*.vox.h5 out/library/*.vox.h5; do
  [ -f "$f" ] && [ "$(stat -c %s "$f")" -lt 2000000 ] && cp "$f" "$corpus/asset/" || true
done
cp tests/fuzz/regressions/*.vox.h5 "$corpus/asset/" 2>/dev/null || true
# The 2.x layout and its hostile variants (tests/reads/hostile_files.py: declared sizes, chunking, strings, values).
/usr/bin/python3 tests/reads/hostile_files.py "$work/hostile" >/dev/null
for f in "$work"/hostile/*.vox.h5; do [ "$(stat -c %s "$f")" -lt 300000 ] && cp "$f" "$corpus/asset/" || true; done
for writer in build/bin/write_sphere_asset "$BUILD_DIR/bin/write_sphere_asset"; do
  if [ -x "$writer" ]; then "$writer" "$corpus/asset/sphere.vox.h5" >/dev/null 2>&1 && break; fi
done
printf '%s\n' '{"input":"a.off","output":"a.vox.h5","status":"ok","size":100}' \
  '{"input":"b.off","output":"b.vox.h5","status":"failed","code":"ZERO_VOLUME"}' >"$corpus/manifest/seed.jsonl"
# Meshes: a tetrahedron and a cube in every format, and CGAL's small sample meshes where they are.
python3 tests/fuzz/make_mesh_seeds.py "$corpus"
for f in build/cgal-data/data/meshes/*.off build/cgal-data/data/meshes/*.ply; do
  [ -f "$f" ] && [ "$(stat -c %s "$f")" -lt 20000 ] && cp "$f" "$corpus/${f##*.}/" || true
done
for f in tests/fuzz/regressions/*.{off,obj,ply,stl,gltf}; do
  [ -f "$f" ] && cp "$f" "$corpus/${f##*.}/"
done

{
  for word in HDF TREE HEAP GCOL OHDR SNOD voxfmt format_version voxelmap pointshell mass_properties provenance \
    layers distances points normals sphere_centers sphere_radii child_begin child_count level_offsets voxel_size \
    dims origin distance_band index_order zyx bricks brick_values lattice brick_edge distance_quantum \
    estimate_quantum lattice_error shell_thickness margin generator build_warnings input output status code size; do
    printf '"%s"\n' "$word"
  done
} >"$work/asset.dict"
cp "$work/asset.dict" "$work/manifest.dict"
{
  for word in "OFF" "v " "vn " "vt " "f " "o " "g " "usemtl" "mtllib" "ply" "format ascii 1.0" \
    "format binary_little_endian 1.0" "element vertex" "element face" "property float" "property double" \
    "property list uchar int vertex_indices" "end_header" "solid" "facet normal" "outer loop" "vertex" "endloop" \
    "endfacet" "endsolid" "asset" "version" "scenes" "nodes" "meshes" "primitives" "attributes" "POSITION" \
    "indices" "buffers" "bufferViews" "accessors" "byteLength" "byteOffset" "componentType" "count" "VEC3" \
    "SCALAR" "matrix" "data:application/octet-stream;base64," "nan" "inf" "1e308" "-0"; do
    printf '"%s"\n' "$word"
  done
} >"$work/mesh.dict"

# A UBSan report in this project's code is a finding (the default would print it and go on); in an isolated child
# (a library's parser) it ends the child, which the parent reports as a failed read.
export UBSAN_OPTIONS=${UBSAN_OPTIONS:-print_stacktrace=1:halt_on_error=1:suppressions=$PWD/tests/sanitizers/ubsan.supp}
status=0
for target in $TARGETS; do
  case "$target" in
    fuzz_asset_reader) kind=asset dict=asset max_len=300000 ;;
    fuzz_manifest) kind=manifest dict=manifest max_len=300000 ;;
    fuzz_mesh_*) kind=${target#fuzz_mesh_} dict=mesh max_len=65536 ;;
    *) echo "run-fuzzers: unknown target $target" >&2; exit 2 ;;
  esac
  findings=$work/findings/$target
  mkdir -p "$findings" "$work/run/$target" "$corpus/$kind"
  echo "run-fuzzers: $target for ${SECONDS_PER_TARGET}s"
  # Readers and imports run isolated, as in production: a crash inside HDF5, assimp or CGAL's readers is a
  # handled error, not a finding. The fuzzer's run folder holds nothing else, so findings are not mixed up.
  # -malloc_limit_mb: one allocation may be large (HDF5 in the isolated child reserves the ~4 GB a damaged object
  # header claims, never touches it, then fails the read: libFuzzer's malloc hook, still armed in the child, took
  # that for an out-of-memory finding); real memory use is still bounded by -rss_limit_mb.
  (cd "$work/run/$target" && VOXFMT_READ_ISOLATION=1 "$OLDPWD/$BUILD_DIR/bin/$target" \
    -max_total_time="$SECONDS_PER_TARGET" -dict="$OLDPWD/$work/$dict.dict" -artifact_prefix="$OLDPWD/$findings/" \
    -max_len=$max_len -timeout=30 -rss_limit_mb=4096 -malloc_limit_mb=65536 -print_final_stats=1 "${seed_option[@]}" \
    "$OLDPWD/$corpus/$kind" 2>&1 |
    grep -E "^(stat::|INFO: (seed|Loaded)|#[0-9]+[[:space:]]+(DONE|INITED))|ERROR|SUMMARY|Test unit written" | tail -15) || status=1
  if [ -n "$(ls -A "$findings")" ]; then
    echo "run-fuzzers: findings in $findings"
    # The run's output above keeps only libFuzzer's summary: each finding again, with what the target printed.
    for finding in "$findings"/*; do
      echo "run-fuzzers: $target on ${finding##*/}:"
      (cd "$work/run/$target" && VOXFMT_READ_ISOLATION=1 timeout 120 "$OLDPWD/$BUILD_DIR/bin/$target" "$OLDPWD/$finding" 2>&1 |
        grep -vE "^(INFO|Running|Executed)" | tail -40) || true
    done
    status=1
  fi
done
exit $status
