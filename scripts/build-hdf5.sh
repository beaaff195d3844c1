#!/usr/bin/env bash
# HDF5 for the wheel (scripts/build-wheel.sh): the upstream source of the HDF5 that the normal build links, from
# Debian 12's source package hdf5 1.10.8+repack1-1 (its .orig tarball: HDF5 1.10.8, repacked by Debian without
# some PDFs; Debian's patches, which rename the library and relax its version check, are not applied), built
# with its own configure script as one shared C library without its tools, its
# C++/Fortran/high-level libraries and, above all, without libcurl: Debian's libhdf5 links libcurl for its S3
# driver, which voxfmt never uses, and would bring 26 more libraries into the wheel. Thread-safe like Debian's
# (Python threads may read assets at once); deflate only, no szip.
#
# Usage: bash scripts/build-hdf5.sh PREFIX    installs into PREFIX (lib/, include/, COPYING, SOURCE); does
# nothing when PREFIX already holds this version. The source is fetched with apt-get from the Debian archive
# that /etc/apt names (verified against its signed index) into a private apt state, without touching the
# system's apt configuration or needing root.
set -euo pipefail
cd "$(dirname "$0")/.."
PREFIX=${1:?usage: build-hdf5.sh PREFIX}
VERSION=1.10.8+repack1-1
mkdir -p "$PREFIX"
PREFIX=$(cd "$PREFIX" && pwd)
if [ -f "$PREFIX/SOURCE" ] && grep -qx "hdf5 $VERSION (Debian source package)" "$PREFIX/SOURCE" &&
  ls "$PREFIX"/lib/libhdf5.so.* >/dev/null 2>&1; then
  echo "build-hdf5: $PREFIX has hdf5 $VERSION"
  exit 0
fi

work=$PREFIX.work
# Autoconf refuses a build folder whose path has a space in it ("unsafe absolute working directory name").
case "$work" in
  *[[:space:]]*)
    echo "build-hdf5: $work: HDF5's configure cannot build in a path with spaces; move the checkout" >&2
    exit 1
    ;;
esac
rm -rf "$work"
mkdir -p "$work"/apt/{lists/partial,cache/archives/partial} "$work/src"
mkdir -p .logs
log=.logs/build-hdf5.log
: >"$log"
fail() {
  tail -n 20 "$log" >&2
  echo "build-hdf5: $1 failed; the whole log is $log" >&2
  exit 1
}

# The deb-src line of the system's own Debian archive (the first deb.debian.org-style URI apt uses).
uri=$(apt-get indextargets --format '$(REPO_URI)' 'Identifier: Packages' 2>/dev/null | grep -m1 '/debian/$' || true)
uri=${uri:-http://deb.debian.org/debian/}
echo "deb-src [signed-by=/usr/share/keyrings/debian-archive-keyring.gpg] $uri bookworm main" >"$work/apt/sources.list"
apt_opts=(-o Dir::Etc::SourceList="$work/apt/sources.list" -o Dir::Etc::SourceParts=/dev/null
  -o Dir::State::Lists="$work/apt/lists" -o Dir::Cache="$work/apt/cache" -o APT::Sandbox::User=root)
echo "build-hdf5: fetching Debian's source of hdf5 $VERSION (log: $log)"
apt-get "${apt_opts[@]}" update >>"$log" 2>&1 || fail "apt-get update (deb-src)"
(cd "$work/src" && apt-get "${apt_opts[@]}" --download-only source "hdf5=$VERSION") >>"$log" 2>&1 ||
  fail "apt-get source hdf5=$VERSION"
mkdir -p "$work/src/hdf5"
tar -xzf "$work/src/hdf5_${VERSION%-*}.orig.tar.gz" -C "$work/src/hdf5" --strip-components=1 || fail "unpacking the source"

echo "build-hdf5: building the C library (shared, thread-safe, zlib, no curl; a few minutes on 2 cores)"
start=$SECONDS
export CCACHE_BASEDIR=${CCACHE_BASEDIR:-$PWD}
cc=gcc
if command -v ccache >/dev/null; then cc="ccache gcc"; fi
mkdir -p "$work/build"
(cd "$work/build" && CC=$cc CFLAGS="-O2" "$work/src/hdf5/configure" --prefix="$PREFIX" --libdir="$PREFIX/lib" \
  --enable-shared --disable-static --enable-threadsafe --disable-hl --disable-cxx --disable-fortran \
  --disable-java --disable-tests --disable-tools --disable-ros3-vfd --disable-mirror-vfd \
  --disable-embedded-libinfo --with-zlib=yes --with-szlib=no) >>"$log" 2>&1 || fail "configuring HDF5"
make -C "$work/build" -j "${JOBS:-$(nproc)}" >>"$log" 2>&1 || fail "compiling HDF5"
make -C "$work/build" install >>"$log" 2>&1 || fail "installing HDF5"
cp "$work/src/hdf5/COPYING" "$PREFIX/COPYING"
echo "hdf5 $VERSION (Debian source package)" >"$PREFIX/SOURCE"
rm -rf "$work"
echo "build-hdf5: $PREFIX/lib has HDF5 $VERSION ($((SECONDS - start)) s)"
