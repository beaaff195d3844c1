"""A missing, damaged or hostile asset named in the MJCF is a MuJoCo error that names the file and carries the
voxfmt code (the plugin's init fails with it), and never takes the interpreter down: each model is compiled
in a child interpreter, which must report the error and exit normally."""

from __future__ import annotations

import os
import re
from pathlib import Path

import pytest
from conftest import REPO
from mujoco_child import compile_in_child

import voxfmt.mujoco as vm

# Every code of spec/issue-codes.md: a refused file names one of them (loaders refuse every error finding).
SPEC_CODES = re.findall(r"^\| `([A-Z0-9_]+)`", (REPO / "spec/issue-codes.md").read_text(), re.M)


@pytest.fixture(scope="module")
def bad_files(tmp_path_factory: pytest.TempPathFactory, sphere_asset: Path) -> dict[str, tuple[Path, str]]:
    folder = tmp_path_factory.mktemp("bad")
    good = sphere_asset.read_bytes()
    files = {
        "missing": (folder / "missing.vox.h5", "FILE_NOT_FOUND"),
        "not HDF5": (folder / "text.vox.h5", "NOT_HDF5"),
        "truncated": (folder / "truncated.vox.h5", "NOT_HDF5"),
        "a folder": (folder, "FILE_NOT_FOUND"),
        "a pipe": (folder / "pipe.vox.h5", "FILE_NOT_FOUND"),
    }
    os.mkfifo(folder / "pipe.vox.h5")
    (folder / "text.vox.h5").write_text("not an asset\n")
    (folder / "truncated.vox.h5").write_bytes(good[: len(good) // 3])
    # A byte flipped in the middle of the data: whatever HDF5 or the validation makes of it, an error.
    flipped = bytearray(good)
    for offset in range(len(good) // 2, len(good) // 2 + 64):
        flipped[offset] ^= 0xFF
    (folder / "flipped.vox.h5").write_bytes(bytes(flipped))
    files["flipped"] = (folder / "flipped.vox.h5", "")
    # The fuzzers' regressions: files that crashed or hung HDF5 in the isolated reader's child.
    for hostile in sorted((REPO / "tests/fuzz/regressions").glob("asset-*.vox.h5")):
        files[hostile.name] = (hostile, "")
    return files


def test_bad_assets_are_mujoco_errors_with_the_voxfmt_code(bad_files: dict[str, tuple[Path, str]]) -> None:
    results = compile_in_child([str(path) for path, _ in bad_files.values()])
    for (name, (path, code)), (_, error, message) in zip(bad_files.items(), results):
        if name == "flipped" and error is None:
            continue  # the flip hit bytes nothing reads (padding): the asset is still valid
        assert error == "ValueError", (name, error, message)
        assert "voxfmt.sdf.asset" in message and str(path) in message, (name, message)
        assert code in message, (name, code, message)
        assert any(f"{c}:" in message for c in SPEC_CODES), message


def test_no_file_is_a_clear_error() -> None:
    (_, error, message), = compile_in_child([""])
    assert error == "ValueError" and "BAD_OPTION" in message and "'file'" in message


def test_a_good_file_after_bad_ones_still_loads(sphere_asset: Path, tmp_path: Path) -> None:
    results = compile_in_child([str(tmp_path / "missing.vox.h5"), str(sphere_asset)])
    assert results[0][1] == "ValueError" and results[1][1] is None, results
    assert vm.MUJOCO_VERSION  # the parent's plugin is loaded too (conftest) and untouched
