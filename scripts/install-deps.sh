#!/usr/bin/env bash
# Installs every Debian package the project needs. Safe to run twice: it runs
# `apt-get update` only when something is missing and installs only what is missing.
set -euo pipefail

PACKAGES=(
  build-essential cmake ninja-build ccache pkg-config git clang-format-14
  libeigen3-dev
  libassimp-dev
  libopenvdb-dev libtbb-dev libblosc-dev libboost-iostreams-dev
  libhdf5-dev hdf5-tools
  libcgal-dev libcgal-demo libgmp-dev libmpfr-dev
  libbullet-dev libbullet-extras-dev libfcl-dev
  libcli11-dev nlohmann-json3-dev
  libssl-dev libpng-dev
  libgtest-dev libgmock-dev libbenchmark-dev
  python3 python3-h5py python3-numpy python3-matplotlib
)

missing=()
for p in "${PACKAGES[@]}"; do
  if ! dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed"; then
    missing+=("$p")
  fi
done

if [ ${#missing[@]} -eq 0 ]; then
  echo "install-deps: all ${#PACKAGES[@]} packages already installed"
  exit 0
fi

SUDO=""
if [ "$(id -u)" -ne 0 ]; then SUDO="sudo"; fi
echo "install-deps: installing ${#missing[@]} missing package(s): ${missing[*]}"
export DEBIAN_FRONTEND=noninteractive
$SUDO apt-get update -qq
$SUDO apt-get install -y -qq --no-install-recommends "${missing[@]}"
