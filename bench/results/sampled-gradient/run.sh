#!/usr/bin/env bash
# Before and after a contact's gradient normal comes from its distance sample (issue 33), one machine, one session:
#   bash bench/results/sampled-gradient/run.sh BEFORE_BUILD AFTER_BUILD [ISSUE_BUILD]
# (each the build folder of the commit named in README.md: its bin/ and python/; ISSUE_BUILD, the commit issue 33
# measured, needs only its python/).
#   1. vps-bench (bunny-bunny, tori-stacked; vps-fine, vps-fine-coherent) and narrowphase-threads, alternated
#      three times;
#   2. tori-stacked alone, alternated three more times;
#   3. contacts_batch from Python (40,000 poses, 1 and 2 threads), alternated twice (with ISSUE_BUILD's package
#      too where given: the issue's target is 2x its poses/s).
# (haptic_loop is not run: the haptic renderer uses the points' own normals, which this change leaves alone.)
set -euo pipefail
before=$1 after=$2 issue=${3:-}
out=$(cd "$(dirname "$0")" && pwd)
root=$(cd "$out/../../.." && pwd)
bunny=${VOXFMT_BUNNY:-$root/build/cgal-data/data/meshes/bunny00.off}
python=${PYTHON:-$root/.venv/bin/python}
build_of() {
  case $1 in
    before) echo "$before" ;;
    after) echo "$after" ;;
    issue) echo "$issue" ;;
  esac
}
for round in 1 2 3; do
  for side in before after; do
    build=$(build_of $side)
    "$build/bin/vps-bench" --scenario bunny-bunny tori-stacked --method vps-fine vps-fine-coherent --reps 2000 \
      --poses 200 --cold 50 --cache /tmp/vpscache --bunny "$bunny" --json "$out/vps-bench-$side-$round.json" \
      >"$out/vps-bench-$side-$round.md" 2>/dev/null
    "$build/bin/narrowphase-threads" --cache /tmp/nptcache --json "$out/narrowphase-$side-$round.json" \
      >"$out/narrowphase-$side-$round.txt" 2>&1
  done
done
# tori-stacked alone (most of this change's effect: 1,724 contacts a query), alternated three more times.
for round in 1 2 3; do
  for side in before after; do
    "$(build_of $side)/bin/vps-bench" --scenario tori-stacked --method vps-fine --reps 4000 --poses 200 --cold 50 \
      --cache /tmp/vpscache --bunny "$bunny" --json "$out/tori-$side-$round.json" >"$out/tori-$side-$round.md" \
      2>/dev/null
  done
done
for round in 1 2; do
  for side in ${issue:+issue} before after; do
    PYTHONPATH="$(build_of $side)/python" "$python" "$root/bench/python_peers.py" --parts batch --batch-poses 40000 \
      --bunny "$bunny" --cache /tmp/pypeers --json "$out/python-batch-$side-$round.json" \
      --markdown "$out/python-batch-$side-$round.md" >/dev/null 2>&1
  done
done
echo done
