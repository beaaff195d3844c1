#!/usr/bin/env bash
# The GPU check, run on a CUDA machine that has nvcc, Python and CuPy but none of voxfmt's libraries (the device
# machine of docs/gpu.md): builds the standalone runner (scripts/gpu/standalone.cu + loaders/gpu/src/kernels.cu,
# the kernel voxfmt links), runs scripts/gpu/check.py over the inputs bench/gpu_batch.py --prepare wrote here, and
# leaves its JSON in $OUT (default out/gpu-check).
#   bash scripts/gpu-check.sh [INPUT_FOLDER]      # default out/gpu-input
set -euo pipefail
cd "$(dirname "$0")/.."
input=${1:-out/gpu-input}
OUT=${OUT:-out/gpu-check}
mkdir -p "$OUT"
[ -f "$input/gpu-batch-input.npz" ] || { echo "gpu-check: no $input/gpu-batch-input.npz (bench/gpu_batch.py --prepare)" >&2; exit 2; }
nvcc=${NVCC:-$(command -v nvcc || echo /usr/local/cuda/bin/nvcc)}
nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader | tee "$OUT/device.txt" || true
"$nvcc" --version | tail -n 1
start=$SECONDS
"$nvcc" -std=c++17 -O3 --fmad=false -arch=native -shared -Xcompiler -fPIC -Iloaders/runtime/src -Iloaders/runtime/include \
  scripts/gpu/standalone.cu loaders/gpu/src/kernels.cu -o "$OUT/libvoxfmt_gpu_check.so"
echo "gpu-check: built the runner in $((SECONDS - start)) s"
python3 scripts/gpu/check.py --input "$input/gpu-batch-input.npz" --library "$OUT/libvoxfmt_gpu_check.so" \
  --json "$OUT/gpu-batch.json"
