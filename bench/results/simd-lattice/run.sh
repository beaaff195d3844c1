#!/usr/bin/env bash
# Before and after the SIMD lower bounds and the lattice-point bounds (issue 33), one machine, one session:
#   bash bench/results/simd-lattice/run.sh BEFORE_BUILD AFTER_BUILD
# (each the build folder of the commit named in README.md: its bin/ and python/).
#   1. vps-bench (bunny-bunny, tori-stacked; vps-fine, vps-fine-coherent) and narrowphase-threads, alternated
#      three times;
#   2. contacts_batch from Python (40,000 poses, 1 and 2 threads), alternated twice;
#   3. the after build alone: vps-fine against vps-fine-scalar, interleaved query by query (--interleave).
set -euo pipefail
before=$1 after=$2
out=$(cd "$(dirname "$0")" && pwd)
root=$(cd "$out/../../.." && pwd)
bunny=${VOXFMT_BUNNY:-$root/build/cgal-data/data/meshes/bunny00.off}
python=${PYTHON:-$root/.venv/bin/python}
for round in 1 2 3; do
  for side in before after; do
    build=$([ $side = before ] && echo "$before" || echo "$after")
    "$build/bin/vps-bench" --scenario bunny-bunny tori-stacked --method vps-fine vps-fine-coherent --reps 2000 \
      --poses 200 --cold 50 --cache /tmp/vpscache --bunny "$bunny" --json "$out/vps-bench-$side-$round.json" \
      >"$out/vps-bench-$side-$round.md" 2>/dev/null
    "$build/bin/narrowphase-threads" --cache /tmp/nptcache --json "$out/narrowphase-$side-$round.json" \
      >"$out/narrowphase-$side-$round.txt" 2>&1
  done
done
for round in 1 2; do
  for side in before after; do
    build=$([ $side = before ] && echo "$before" || echo "$after")
    PYTHONPATH="$build/python" "$python" "$root/bench/python_peers.py" --parts batch --batch-poses 40000 \
      --bunny "$bunny" --cache /tmp/pypeers --json "$out/python-batch-$side-$round.json" \
      --markdown "$out/python-batch-$side-$round.md" >/dev/null 2>&1
  done
done
"$after/bin/vps-bench" --scenario bunny-bunny tori-stacked --method vps-fine vps-fine-scalar --interleave --reps 4000 \
  --poses 200 --cold 50 --cache /tmp/vpscache --bunny "$bunny" --json "$out/kernels-interleaved.json" \
  >"$out/kernels-interleaved.md" 2>/dev/null
echo done
