#!/usr/bin/env bash
# The README's main job: install dependencies, build, bake CGAL's Stanford bunny (the built-in default sample),
# validate and inspect the asset, then drop it in Bullet with every collision method (bunny_drop). Pass another
# mesh as $1 to use that instead.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/build.sh
OUT=${OUT_DIR:-out}
MESH=${1:-build/cgal-data/data/meshes/bunny00.off}
mkdir -p "$OUT"
name=$(basename "${MESH%.*}")
echo "== voxfmt build $MESH (seed settings: --resolution 306 --points 35000)"
build/bin/voxfmt build "$MESH" -o "$OUT/$name.vox.h5" --resolution 306 --points 35000
echo "== voxfmt validate"
build/bin/voxfmt validate "$OUT/$name.vox.h5"
echo "== voxfmt inspect"
build/bin/voxfmt inspect "$OUT/$name.vox.h5"
echo "== bunny_drop (the seed's Figure 2; the first run computes and caches the HACD decomposition: minutes)"
build/bin/bunny_drop --asset "$OUT/$name.vox.h5" --mesh "$MESH" -o "$OUT/bunny_drop"
