#!/usr/bin/env bash
# Installs every Debian package the project needs, then the Python package's build and test tools into .venv/
# (a virtual environment in the checkout, ignored by git; CMake builds the Python package with it). Safe to run
# twice: it runs `apt-get update` only when something is missing and installs only what is missing.
set -euo pipefail
cd "$(dirname "$0")/.."
mkdir -p .logs  # every step below logs here, whichever of them runs

PACKAGES=(
  build-essential cmake ninja-build ccache pkg-config git clang-format-14 clang-14 libclang-rt-14-dev
  libeigen3-dev
  libassimp-dev
  libopenvdb-dev libtbb-dev libblosc-dev libboost-iostreams-dev
  libnanovdb-dev libnanovdb-tools libopenvdb-tools zlib1g-dev libdeflate-dev
  libhdf5-dev hdf5-tools
  libcgal-dev libcgal-demo libgmp-dev libmpfr-dev
  libbullet-dev libbullet-extras-dev libfcl-dev
  libcli11-dev nlohmann-json3-dev
  libssl-dev libpng-dev
  libgtest-dev libgmock-dev libbenchmark-dev
  python3 python3-h5py python3-numpy python3-matplotlib
  python3-dev python3-venv
  chromium chromium-driver python3-selenium
)

missing=()
for p in "${PACKAGES[@]}"; do
  if ! dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed"; then
    missing+=("$p")
  fi
done

if [ ${#missing[@]} -eq 0 ]; then
  echo "install-deps: all ${#PACKAGES[@]} packages already installed"
else
  SUDO=""
  if [ "$(id -u)" -ne 0 ]; then SUDO="sudo"; fi
  # apt's and dpkg's thousands of lines go to a log, named (with its end) only if something fails.
  mkdir -p .logs
  log=.logs/install-deps.log
  echo "install-deps: installing ${#missing[@]} missing package(s) with apt-get (log: $log) ..."
  export DEBIAN_FRONTEND=noninteractive
  start=$SECONDS
  if ! { $SUDO apt-get update -q && $SUDO apt-get install -y -q --no-install-recommends "${missing[@]}"; } >"$log" 2>&1; then
    tail -n 20 "$log" >&2
    echo "install-deps: apt-get failed; the whole log is $log" >&2
    exit 1
  fi
  echo "install-deps: installed ${#missing[@]} package(s) in $((SECONDS - start)) s"
fi

# The Python tools (python/requirements-dev.txt), from PyPI into .venv/ with Debian's interpreter. pip's
# `--dry-run` would still reach the index, so the check is an import.
VENV=.venv
MUJOCO_PIN=$(sed -n 's/^mujoco==//p' python/requirements-dev.txt)
if ! "$VENV/bin/python" -c "import nanobind, numpy, pytest, h5py, igl, mujoco; assert mujoco.__version__ == '$MUJOCO_PIN'" \
    >/dev/null 2>&1; then
  echo "install-deps: setting up $VENV with python/requirements-dev.txt (log: .logs/pip.log) ..."
  mkdir -p .logs
  if ! { /usr/bin/python3 -m venv "$VENV" &&
    "$VENV/bin/python" -m pip install --disable-pip-version-check -r python/requirements-dev.txt; } >.logs/pip.log 2>&1; then
    tail -n 20 .logs/pip.log >&2
    echo "install-deps: pip failed; the whole log is .logs/pip.log" >&2
    exit 1
  fi
else
  echo "install-deps: $VENV has the Python tools"
fi

# Newton and Warp for voxfmt.newton and voxfmt.warp (python/requirements-newton.txt) in a second environment,
# .venv-newton/: Newton's MuJoCo Warp solver needs another MuJoCo release than .venv's plugin. Their tests and examples
# run on the CPU device. VOXFMT_NEWTON=OFF skips it (the tests that need it are then not configured).
NEWTON_PIN=$(sed -n 's/^newton\[sim\]==//p' python/requirements-newton.txt)
if [ "${VOXFMT_NEWTON:-ON}" != OFF ] && ! .venv-newton/bin/python -c \
    "import newton, warp, mujoco_warp, pytest, h5py; assert newton.__version__ == '$NEWTON_PIN'" >/dev/null 2>&1; then
  echo "install-deps: setting up .venv-newton with python/requirements-newton.txt (log: .logs/pip-newton.log) ..."
  mkdir -p .logs
  if ! { /usr/bin/python3 -m venv .venv-newton &&
    .venv-newton/bin/python -m pip install --disable-pip-version-check -r python/requirements-newton.txt; } \
    >.logs/pip-newton.log 2>&1; then
    tail -n 20 .logs/pip-newton.log >&2
    echo "install-deps: pip failed; the whole log is .logs/pip-newton.log" >&2
    exit 1
  fi
fi

# A CUDA compiler from PyPI (python/requirements-cuda.txt: nvcc, its runtime headers and static runtime), so that
# the CUDA batch (loaders/gpu) compiles on every machine, GPU or not: CI builds the kernels it cannot run.
# VOXFMT_CUDA=OFF skips it (CMake then finds no CUDA compiler and builds no CUDA part).
if [ "${VOXFMT_CUDA:-AUTO}" != OFF ] && ! ls "$VENV"/lib/python3*/site-packages/nvidia/cu13/bin/nvcc >/dev/null 2>&1; then
  echo "install-deps: adding nvcc to $VENV (python/requirements-cuda.txt; log: .logs/pip-cuda.log) ..."
  if ! "$VENV/bin/python" -m pip install --disable-pip-version-check -r python/requirements-cuda.txt \
      >.logs/pip-cuda.log 2>&1; then
    tail -n 20 .logs/pip-cuda.log >&2
    echo "install-deps: pip failed; the whole log is .logs/pip-cuda.log" >&2
    exit 1
  fi
fi
