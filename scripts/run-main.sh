#!/usr/bin/env bash
# The README's main job: install dependencies, build, then write a sample asset, validate and inspect it.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/build.sh
OUT=${OUT_DIR:-out}
mkdir -p "$OUT"
echo "== writing the analytic sphere asset to $OUT/sphere.vox.h5"
build/bin/write_sphere_asset "$OUT/sphere.vox.h5"
echo "== voxfmt validate"
build/bin/voxfmt validate "$OUT/sphere.vox.h5"
echo "== voxfmt inspect"
build/bin/voxfmt inspect "$OUT/sphere.vox.h5"
