#!/usr/bin/env bash
# The README's main job: install dependencies, build, batch-convert CGAL's whole sample mesh library (default
# bake settings) into out/library/ with a manifest and a summary, bake CGAL's Stanford bunny at the seed's
# settings, validate and inspect it (summary, a slice picture, the point shell as PLY, the voxelmap as OpenVDB), then drop it in Bullet with every collision
# method (bunny_drop). Pass another mesh as $1 to use that instead of the bunny. Safe to run again: the library
# step skips the assets that are up to date. Environment: BUILD_DIR (build), OUT_DIR (out), LIBRARY_DIR.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/build.sh
BUILD=${BUILD_DIR:-build}
BIN=$BUILD/bin
OUT=${OUT_DIR:-out}
LIBRARY=${LIBRARY_DIR:-$BUILD/cgal-data/data/meshes}
MESH=${1:-$BUILD/cgal-data/data/meshes/bunny00.off}
mkdir -p "$OUT"

echo "== voxfmt batch $LIBRARY -> $OUT/library (CGAL's sample library, default settings; some meshes are broken on purpose)"
# Exit 1 means some meshes failed (recorded in the manifest with their reason): expected for this library.
# Exit 2 (bad arguments, unreadable input, another batch on the same manifest) stops the job.
status=0
$BIN/voxfmt batch "$LIBRARY" -o "$OUT/library" --timeout 300 || status=$?
if [ "$status" -ge 2 ]; then exit "$status"; fi
echo "(manifest: $OUT/library/manifest.jsonl, one JSON line per mesh)"

name=$(basename "${MESH%.*}")
echo "== voxfmt build $MESH (seed settings: --resolution 306 --points 35000)"
$BIN/voxfmt build "$MESH" -o "$OUT/$name.vox.h5" --resolution 306 --points 35000
echo "== voxfmt validate"
$BIN/voxfmt validate "$OUT/$name.vox.h5"
echo "== voxfmt inspect"
$BIN/voxfmt inspect "$OUT/$name.vox.h5"
dims_z=$($BIN/voxfmt inspect "$OUT/$name.vox.h5" --json | python3 -c 'import json,sys; print(json.load(sys.stdin)["voxelmap"]["dims"][2])')
$BIN/voxfmt inspect "$OUT/$name.vox.h5" --slice "z=$((dims_z / 2))" --png "$OUT/$name-slice-z.png"
$BIN/voxfmt inspect "$OUT/$name.vox.h5" --ply "$OUT/$name-pointshell.ply" --vdb "$OUT/$name.vdb"

echo "== bunny_drop (the seed's Figure 2; the first run computes and caches the HACD decomposition: minutes)"
$BIN/bunny_drop --asset "$OUT/$name.vox.h5" --mesh "$MESH" -o "$OUT/bunny_drop"
/usr/bin/python3 scripts/plot_bunny_drop.py "$OUT/bunny_drop/bunny_drop.csv" "$OUT/bunny_drop/bunny_drop.png"
