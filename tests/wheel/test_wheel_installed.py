"""The binary wheel as installed (scripts/test-wheel.sh runs this in a bare Debian root, in a venv that has the
wheel and nothing of this checkout): the package comes from site-packages, every library it needs comes from its
own voxfmt.libs/, never from the system, and the MuJoCo plugin is in the package."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import sysconfig
from pathlib import Path

import voxfmt
import voxfmt.mujoco as vm

PACKAGE = Path(voxfmt.__file__).resolve().parent
LIBS = PACKAGE.parent / "voxfmt.libs"

# Run in a fresh interpreter: pytest may have loaded libraries (ssl's libcrypto) that voxfmt does not use.
PROBE = r"""
import json, sys, tempfile, os
import numpy as np
import voxfmt
folder = tempfile.mkdtemp()
mesh = os.path.join(folder, "tetra.off")
with open(mesh, "w") as f:
    f.write("OFF\n4 4 0\n0 0 0\n0.1 0 0\n0 0.1 0\n0 0 0.1\n3 0 2 1\n3 0 1 3\n3 0 3 2\n3 1 2 3\n")
voxfmt.bake(mesh, os.path.join(folder, "t.vox.h5"), resolution=16, points=200)
body = voxfmt.load(os.path.join(folder, "t.vox.h5"))
voxfmt.contacts(body, np.eye(4), body, np.eye(4))
with open("/proc/self/maps") as maps:  # address perms offset device inode [path]
    print(json.dumps(sorted({f[5] for f in (line.split() for line in maps) if len(f) >= 6 and f[5].startswith("/")})))
"""


def test_the_package_is_the_installed_one() -> None:
    assert PACKAGE.parent == Path(sysconfig.get_paths()["purelib"]).resolve(), PACKAGE
    assert (PACKAGE / "_voxfmt.pyi").exists() and (PACKAGE / "py.typed").exists()


def test_the_libraries_are_the_wheels_own() -> None:
    copies = sorted(p.name for p in LIBS.iterdir())
    assert any(name.startswith("libhdf5-") for name in copies), copies
    assert not any(name.startswith("libcurl") for name in copies), copies  # HDF5 built without it
    mapped = json.loads(subprocess.run([sys.executable, "-c", PROBE], check=True, capture_output=True,
                                       text=True).stdout)
    mapped_names = {os.path.basename(path): path for path in mapped}
    # Every copy is loaded by the bake and the queries (all are the extension's dependencies), from voxfmt.libs.
    for name in copies:
        assert name in mapped_names, f"{name} is not loaded: {sorted(mapped_names)}"
        assert Path(mapped_names[name]).parent.resolve() == LIBS.resolve(), mapped_names[name]
    # And no system copy of any of them: libhdf5-1a2b3c4d.so.103... is libhdf5.so.* or Debian's libhdf5_serial.so.*.
    stems = {name.split("-")[0] for name in copies}
    for path in mapped:
        base = os.path.basename(path)
        assert not any(base.startswith((stem + ".so", stem + "_serial.so")) for stem in stems), path


def test_the_wheel_lists_each_librarys_licence() -> None:
    info = next(PACKAGE.parent.glob("voxfmt-*.dist-info"))
    third = info / "licenses" / "third_party"
    table = (third / "README.md").read_text()
    for copy in LIBS.iterdir():
        row = next((line for line in table.splitlines() if line.startswith(f"| {copy.name} |")), None)
        assert row is not None, f"{copy.name} is not in {third / 'README.md'}"
        licence = row.strip("| ").split(" | ")[-1]
        assert (third / licence).stat().st_size > 0, licence


def test_the_mujoco_plugin_comes_with_it() -> None:
    path = Path(vm.plugin_path())
    assert path.parent == PACKAGE and path.exists(), path
    assert vm.load_plugin() == str(path)
