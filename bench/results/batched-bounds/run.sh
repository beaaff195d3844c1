#!/usr/bin/env bash
# Before and after the batched voxelmap bounds (issue 33), alternated twice, one machine, one session:
#   bash bench/results/batched-bounds/run.sh BEFORE_BIN_DIR AFTER_BIN_DIR
# (each a build/bin of the commit named in README.md).
set -euo pipefail
before=$1 after=$2
out=$(cd "$(dirname "$0")" && pwd)
for round in 1 2; do
  for side in before after; do
    bin=$([ $side = before ] && echo "$before" || echo "$after")
    "$bin/vps-bench" --scenario bunny-bunny tori-stacked --method vps-fine vps-fine-coherent --reps 2000 --poses 200 \
      --cold 50 --cache /tmp/vpscache --json "$out/vps-bench-$side-$round.json" >"$out/vps-bench-$side-$round.md" 2>&1
    "$bin/narrowphase-threads" --cache /tmp/nptcache --json "$out/narrowphase-$side-$round.json" \
      >"$out/narrowphase-$side-$round.txt" 2>&1
  done
done
echo done
