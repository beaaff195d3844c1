#!/usr/bin/env bash
# The GPU check, run on a CUDA machine that has nvcc, Python and CuPy but none of voxfmt's libraries (the device
# machine of docs/gpu.md): builds the standalone runner (scripts/gpu/standalone.cu + loaders/gpu/src/kernels.cu,
# the kernel voxfmt links) at each block size of $LANES (with the default register cap, device.h: 640 threads'
# worth of blocks) and each register cap of $CAPS (LANES:BLOCKS, the blocks a multiprocessor should hold; 0: no
# cap), runs scripts/gpu/check.py over the inputs bench/gpu_batch.py --prepare wrote here with each (and the default
# size without the bricks' apron), and leaves the JSON files in $OUT (default out/gpu-check): gpu-batch.json is the
# default build's (128 lanes, the apron, the default cap). Then compute-sanitizer's memcheck, racecheck and
# synccheck over a few hundred poses, where the machine has it (sanitizers.txt). Also all of it in one file,
# gpu-check.tar.gz: a borrowed device machine returns eight files at most.
#   bash scripts/gpu-check.sh [INPUT_FOLDER]      # default out/gpu-input; LANES="32 64 128 256", CAPS="128:0 128:6"
set -euo pipefail
cd "$(dirname "$0")/.."
input=${1:-out/gpu-input}
OUT=${OUT:-out/gpu-check}
LANES=${LANES:-32 64 128 256}
case " $LANES " in *" 128 "*) ;; *) LANES="$LANES 128" ;; esac  # the default, always measured
CAPS=${CAPS:-128:0 128:6}  # on an H200: 128 registers uncapped, 80 with six blocks (the default, five: 96)
mkdir -p "$OUT"
[ -f "$input/gpu-batch-input.npz" ] || { echo "gpu-check: no $input/gpu-batch-input.npz (bench/gpu_batch.py --prepare)" >&2; exit 2; }
nvcc=${NVCC:-$(command -v nvcc || echo /usr/local/cuda/bin/nvcc)}
nvidia-smi --query-gpu=name,memory.total,driver_version,clocks.max.sm --format=csv,noheader | tee "$OUT/device.txt" || true
"$nvcc" --version | tail -n 1
build=$(mktemp -d)
start=$SECONDS
# Every build as NAME:LANES:BLOCKS (BLOCKS -: device.h's cap, 0: none), each built in the background into
# $build/NAME.so.
builds=$(for lanes in $LANES; do echo "lanes$lanes:$lanes:-"; done
         for cap in $CAPS; do echo "lanes${cap%:*}-min${cap#*:}:${cap%:*}:${cap#*:}"; done)
for spec in $builds; do
  IFS=: read -r name lanes blocks <<<"$spec"
  cap=()
  [ "$blocks" = - ] || cap=(-DVOXFMT_BLOCK_MIN_BLOCKS="$blocks")
  "$nvcc" -std=c++17 -O3 --fmad=false -arch=native -shared -Xcompiler -fPIC -DVOXFMT_BLOCK_LANES="$lanes" \
    "${cap[@]}" -Xptxas -v -Iloaders/runtime/src -Iloaders/runtime/include \
    scripts/gpu/standalone.cu loaders/gpu/src/kernels.cu -o "$build/$name.so" >"$build/$name.log" 2>&1 &
done
wait
for spec in $builds; do
  echo "${spec%%:*}: $(grep -h 'registers' "$build/${spec%%:*}.log" | tail -n 1)"
done | tee "$OUT/ptxas.txt"
echo "gpu-check: built the runners in $((SECONDS - start)) s"
check() {  # LIBRARY JSON [check.py options]
  local library=$1 json=$2
  shift 2
  echo "== $(basename "$library") $*"
  timeout 300 python3 scripts/gpu/check.py --input "$input/gpu-batch-input.npz" --library "$library" --json "$json" "$@"
}
status=0
check "$build/lanes128.so" "$OUT/gpu-batch.json" || status=1
for spec in $builds; do
  name=${spec%%:*}
  [ "$name" = lanes128 ] || check "$build/$name.so" "$OUT/gpu-batch-$name.json" --reps 20 || status=1
done
check "$build/lanes128.so" "$OUT/gpu-batch-no-apron.json" --no-apron --reps 20 || status=1
if command -v compute-sanitizer >/dev/null; then
  : >"$OUT/sanitizers.txt"
  for tool in memcheck racecheck synccheck; do
    echo "== compute-sanitizer $tool, 256 poses" | tee -a "$OUT/sanitizers.txt"
    timeout 240 compute-sanitizer --tool "$tool" --error-exitcode 9 python3 scripts/gpu/check.py \
      --input "$input/gpu-batch-input.npz" --library "$build/lanes128.so" --json "$build/$tool.json" \
      --agreement-poses 256 --max-envs 16 --reps 1 >>"$OUT/sanitizers.txt" 2>&1 || status=1
    grep -E "ERROR SUMMARY|RACECHECK SUMMARY" "$OUT/sanitizers.txt" | tail -n 1
  done
fi
tar -czf "$build/gpu-check.tar.gz" --exclude=./gpu-check.tar.gz -C "$OUT" . && mv "$build/gpu-check.tar.gz" "$OUT/"
echo "gpu-check: done in $((SECONDS - start)) s (exit $status)"
exit $status
