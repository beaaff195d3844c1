#!/usr/bin/env bash
# The README's main job: install dependencies, build the two programs it runs, batch-convert CGAL's whole sample
# mesh library (default bake settings) into out/library/ with a manifest, a summary and an HTML report (report/), bake CGAL's Stanford
# bunny at the seed's settings, validate and inspect it (summary, a slice picture, the point shell as PLY, the
# voxelmap as OpenVDB), then drop it in Bullet with every collision method (bunny_drop). Pass another mesh as $1
# to use that instead of the bunny. Safe to run again: the library step skips the assets that are up to date.
# The terminal gets one line per step and the results; the long outputs go to files named as it runs
# ($OUT/logs/). Environment: BUILD_DIR (build), OUT_DIR (out), LIBRARY_DIR.
set -euo pipefail
# A mesh and folders given relative to where the job is started, before it moves to the repository.
[ -n "${1:-}" ] && set -- "$(realpath -m -- "$1")"
for var in BUILD_DIR OUT_DIR LIBRARY_DIR; do
  [ -n "${!var:-}" ] && export "$var=$(realpath -m -- "${!var}")"
done
cd "$(dirname "$0")/.."
start=$SECONDS
# The main job needs no CUDA compiler (install-deps skips its download; scripts/run-tests.sh adds it).
VOXFMT_CUDA=OFF VOXFMT_NEWTON=OFF TARGETS="voxfmt_cli bunny_drop" bash scripts/build.sh  # the rest (tests, benchmarks): scripts/run-tests.sh
BUILD=${BUILD_DIR:-build}
BIN=$BUILD/bin
OUT=${OUT_DIR:-out}
LIBRARY=${LIBRARY_DIR:-$BUILD/cgal-data/data/meshes}
MESH=${1:-$BUILD/cgal-data/data/meshes/bunny00.off}
LOGS=$OUT/logs
mkdir -p "$OUT" "$LOGS"

echo "== 1/4 voxfmt batch $LIBRARY -> $OUT/library (CGAL's sample library, default settings; some meshes are broken on purpose)"
# Exit 1 means some meshes failed (recorded in the manifest with their reason): expected for this library.
# Exit 2 (bad arguments, unreadable input, another batch on the same manifest) stops the job. On a terminal batch
# draws a bar (and prints the failures); elsewhere it writes a line per mesh, which goes to the log. --report then
# writes the library's HTML report into $OUT/library/report/ and prints its path.
status=0
if [ -t 2 ]; then
  "$BIN/voxfmt" batch "$LIBRARY" -o "$OUT/library" --timeout 300 --report || status=$?
else
  "$BIN/voxfmt" batch "$LIBRARY" -o "$OUT/library" --timeout 300 --report 2>"$LOGS/batch.log" || status=$?
  echo "(one line per mesh: $LOGS/batch.log)"
fi
if [ "$status" -ge 2 ]; then
  [ -t 2 ] || tail -n 5 "$LOGS/batch.log" >&2
  exit "$status"
fi

name=$(basename "${MESH%.*}")
asset=$OUT/$name.vox.h5
echo "== 2/4 voxfmt build $MESH (seed settings: --resolution 306 --points 35000)"
"$BIN/voxfmt" build "$MESH" -o "$asset" --resolution 306 --points 35000

echo "== 3/4 voxfmt validate, inspect, exports"
"$BIN/voxfmt" validate "$asset"
"$BIN/voxfmt" inspect "$asset" >"$OUT/$name-inspect.txt"
dims_z=$("$BIN/voxfmt" inspect "$asset" --json | python3 -c 'import json,sys; print(json.load(sys.stdin)["voxelmap"]["dims"][2])')
"$BIN/voxfmt" inspect "$asset" --slice "z=$((dims_z / 2))" --png "$OUT/$name-slice-z.png"
"$BIN/voxfmt" inspect "$asset" --ply "$OUT/$name-pointshell.ply" --vdb "$OUT/$name.vdb"
echo "(the asset's summary: $OUT/$name-inspect.txt)"

echo "== 4/4 bunny_drop (the seed's Figure 2: narrow-phase time per method, bunny on a table and on a bunny)"
# The HACD decomposition comes from bench/data/ when it was made from this mesh with these parameters, else it
# is computed (minutes) and cached in $OUT/bunny_drop/. Its per-run lines go to the log; HACD's show.
"$BIN/bunny_drop" --asset "$asset" --mesh "$MESH" -o "$OUT/bunny_drop" \
  2> >(tee "$LOGS/bunny_drop.log" | grep --line-buffered -v '^run: ' >&2)
/usr/bin/python3 scripts/plot_bunny_drop.py "$OUT/bunny_drop/bunny_drop.csv" "$OUT/bunny_drop/bunny_drop.png"
echo "main job: done in $((SECONDS - start)) s; results in $OUT/, logs in $LOGS/"
