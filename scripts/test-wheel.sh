#!/usr/bin/env bash
# Proves that the wheel of scripts/build-wheel.sh is self-contained: on a bare Debian 12 root (debootstrap
# minbase with only python3 and python3-venv: no HDF5, assimp, TBB, MPFR, draco, ... and nothing of this
# checkout), in a fresh venv,
#   - `pip install voxfmt-*.whl[test,mujoco]` from a local folder of wheels (timed),
#   - python/tests, tests/mujoco (the plugin inside MuJoCo) and tests/wheel (the libraries mapped after a bake
#     are the wheel's copies, no system copy; the licences; the plugin) pass;
#   - the negative control: the unrepaired wheel (build-wheel-tools/raw/) installs in the same way and fails
#     to import, so the root really lacks the libraries;
#   - `auditwheel show` names manylinux_2_34_x86_64.
# Needs root (debootstrap, chroot) and the network to Debian and PyPI the first time; the root and the wheels it
# installs stay in build-wheel-tools/ (about 2 min the first time, then reused). Usage: bash scripts/test-wheel.sh
set -euo pipefail
cd "$(dirname "$0")/.."
TOOLS=build-wheel-tools
PLAT=manylinux_2_34_x86_64
if [ "$(id -u)" -ne 0 ]; then
  echo "test-wheel: needs root (debootstrap and chroot)" >&2
  exit 2
fi
wheel=$(ls dist/voxfmt-*-"$PLAT".whl 2>/dev/null | head -n1 || true)
raw=$(ls "$TOOLS"/raw/voxfmt-*.whl 2>/dev/null | head -n1 || true)
if [ -z "$wheel" ] || [ -z "$raw" ]; then
  echo "test-wheel: no dist/voxfmt-*-$PLAT.whl or $TOOLS/raw/voxfmt-*.whl: run scripts/build-wheel.sh first" >&2
  exit 2
fi
mkdir -p .logs
log=.logs/test-wheel.log
: >"$log"
fail() {
  tail -n 40 "$log" >&2
  echo "test-wheel: $1; the whole log is $log" >&2
  exit 1
}
start=$SECONDS

# The tag, from the symbol versions the wheel's libraries use; the only library outside the wheel and the
# manylinux policy is libmujoco, left out on purpose (the mujoco wheel brings it: the plugin runs inside MuJoCo).
"$TOOLS/venv/bin/auditwheel" show --json "$wheel" >"$TOOLS/auditwheel-show.json" 2>>"$log" || fail "auditwheel show failed"
python3 - "$TOOLS/auditwheel-show.json" "$PLAT" <<'EOF' || fail "auditwheel show does not give $PLAT"
import json, sys
show = json.load(open(sys.argv[1]))
external = sorted(show["external_libs"])
print(f"test-wheel: auditwheel show: symbols of {show['sym_tag']}, outside the wheel: {', '.join(external)}")
assert show["sym_tag"] == sys.argv[2], show["sym_tag"]
assert [lib for lib in external if not lib.startswith("libmujoco.so.")] == [], external
EOF

# The bare root, made once.
root=$PWD/$TOOLS/root
if [ ! -f "$root/.voxfmt-root" ]; then
  if ! command -v debootstrap >/dev/null; then
    echo "test-wheel: installing debootstrap"
    apt-get install -y -q --no-install-recommends debootstrap >>"$log" 2>&1 ||
      { apt-get update -q >>"$log" 2>&1 && apt-get install -y -q --no-install-recommends debootstrap >>"$log" 2>&1; } ||
      fail "apt-get install debootstrap failed"
  fi
  mirror=$(apt-get indextargets --format '$(REPO_URI)' 'Identifier: Packages' 2>/dev/null | grep -m1 '/debian/$' || true)
  echo "test-wheel: debootstrap bookworm (minbase, python3, python3-venv) into $root (a minute or two)"
  rm -rf "$root" "$root.partial"
  debootstrap --variant=minbase --include=python3,python3-venv bookworm "$root.partial" \
    "${mirror:-http://deb.debian.org/debian/}" >>"$log" 2>&1 || fail "debootstrap failed"
  touch "$root.partial/.voxfmt-root"
  mv "$root.partial" "$root"
fi
# It must lack what the extension links (else the test proves nothing).
for lib in libhdf5 libassimp libtbb libmpfr libdraco libminizip libcurl; do
  if compgen -G "$root/usr/lib/x86_64-linux-gnu/$lib*" >/dev/null; then fail "the root has $lib"; fi
done

# Wheels of the dependencies (numpy; pytest and h5py for the tests; mujoco and its own), for this CPython.
house=$TOOLS/wheelhouse
if [ ! -f "$house/.complete" ]; then
  echo "test-wheel: downloading the dependencies' wheels into $house"
  rm -rf "$house"
  "$TOOLS/venv/bin/pip" download --disable-pip-version-check --only-binary :all: -d "$house" "$wheel[test,mujoco]" \
    >>"$log" 2>&1 || fail "pip download failed"
  rm -f "$house"/voxfmt-*.whl
  touch "$house/.complete"
fi

# What goes into the root: the two wheels, the dependencies, the tests and what they read.
work=$root/voxfmt-test
rm -rf "$work"
mkdir -p "$work/wheels" "$work/repo/python" "$work/repo/tests/fuzz" "$work/repo/examples" "$work/repo/spec" \
  "$work/repo/build/cgal-data/data/meshes"
cp "$wheel" "$work/wheels/"
mkdir -p "$work/raw" && cp "$raw" "$work/raw/"
cp -r "$house" "$work/wheelhouse"
cp -r python/tests python/requirements-dev.txt "$work/repo/python/"
cp -r tests/mujoco tests/spec tests/wheel "$work/repo/tests/"
cp -r tests/fuzz/regressions "$work/repo/tests/fuzz/"
cp spec/issue-codes.md "$work/repo/spec/"
cp -r examples/mujoco "$work/repo/examples/"
mkdir -p "$work/repo/bench" && cp bench/mujoco_compare.py "$work/repo/bench/"
tar -xzf /usr/share/doc/libcgal-dev/data.tar.gz -C "$work/repo/build/cgal-data" data/meshes/bunny00.off
cat >"$work/run.sh" <<EOF
set -euo pipefail
cd /voxfmt-test
python3 -m venv venv
start=\$EPOCHREALTIME
venv/bin/pip install --disable-pip-version-check -q --no-index --find-links wheelhouse "wheels/$(basename "$wheel")"
echo "installed in \$(awk -v a=\$start -v b=\$EPOCHREALTIME 'BEGIN { printf "%.1f", b - a }') s: pip install $(basename "$wheel") (and numpy) into a fresh venv"
venv/bin/pip install --disable-pip-version-check -q --no-index --find-links wheelhouse "wheels/$(basename "$wheel")[test,mujoco]"
cd repo
# One pytest per folder, as ctest runs them (each has its own conftest).
for tests in python/tests tests/mujoco tests/wheel; do
  echo "pytest \$tests:"
  VOXFMT_REPO=/voxfmt-test/repo PYTHONDONTWRITEBYTECODE=1 ../venv/bin/python -m pytest -q -p no:cacheprovider \$tests
done
cd ..
python3 -m venv venv-raw
venv-raw/bin/pip install --disable-pip-version-check -q --no-index --find-links wheelhouse "raw/$(basename "$raw")"
if venv-raw/bin/python -c "import voxfmt" 2>raw-import.txt; then
  echo "negative control: the unrepaired wheel imports: the root has the libraries" >&2
  exit 1
fi
if ! grep -q "cannot open shared object file" raw-import.txt; then
  cat raw-import.txt >&2
  echo "negative control: the unrepaired wheel failed for another reason than a missing library" >&2
  exit 1
fi
echo "negative control: the unrepaired wheel fails as it should: \$(tail -n1 raw-import.txt)"
EOF
echo "test-wheel: installing $(basename "$wheel") into a fresh venv in the root and running its tests there"
# A private mount namespace: /proc is mounted for the root only and goes away with the namespace.
set +e
env -i PATH=/usr/sbin:/usr/bin:/sbin:/bin HOME=/root LANG=C.UTF-8 \
  unshare --mount --propagation private --fork -- \
  sh -c 'mount -t proc proc "$1/proc" && exec chroot "$1" /bin/bash /voxfmt-test/run.sh' sh "$root" 2>&1 | tee -a "$log" |
  grep -E "^installed in|^pytest |passed|failed|error|negative control"
status=${PIPESTATUS[0]}
set -e
[ "$status" -eq 0 ] || fail "the tests in the bare root failed (exit $status)"
rm -rf "$work"
echo "test-wheel: the wheel is self-contained ($((SECONDS - start)) s)"
