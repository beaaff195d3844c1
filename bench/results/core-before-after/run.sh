#!/usr/bin/env bash
# Before (9a8c3c9, /work/before/build) and after (this tree, build/), alternated, one machine, one session.
set -euo pipefail
cd /work/main
for round in 1 2; do
  for side in before after; do
    bin=$([ $side = before ] && echo /work/before/build/bin || echo build/bin)
    $bin/vps-bench --scenario bunny-bunny tori-stacked --method vps-fine vps-fine-coherent --reps 2000 --poses 200 \
      --cold 50 --trajectories --steps 1000 --cache /tmp/vpscache --json /tmp/perf/vps-bench-$side-$round.json > /tmp/perf/vps-bench-$side-$round.md 2>&1
    $bin/narrowphase-threads --cache /tmp/nptcache --json /tmp/perf/narrowphase-$side-$round.json > /tmp/perf/narrowphase-$side-$round.txt 2>&1
  done
done
echo done
