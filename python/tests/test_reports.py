"""validate(), inspect() and bake() give what the CLI prints (one serialisation in the libraries)."""

from __future__ import annotations

import json
import os
import subprocess
from pathlib import Path

import pytest

import voxfmt

CLI = os.environ.get("VOXFMT_BIN")
needs_cli = pytest.mark.skipif(not CLI, reason="VOXFMT_BIN (the voxfmt CLI) not given")


def test_validate_a_good_asset(sphere_asset: Path) -> None:
    for level in ("quick", "full"):
        report = voxfmt.validate(sphere_asset, level)
        assert report.valid and bool(report) and report.errors == ()
        assert all(issue.severity != "error" for issue in report.issues)


def test_validate_reports_locations(sphere_asset: Path, tmp_path: Path) -> None:
    h5py = pytest.importorskip("h5py")
    broken = tmp_path / "broken.vox.h5"
    broken.write_bytes(sphere_asset.read_bytes())
    with h5py.File(broken, "r+") as f:
        normals = f["/pointshell/normals"]
        normals[0] = (3.0, 0.0, 0.0)
    report = voxfmt.validate(broken)
    assert not report.valid
    issue = next(i for i in report.issues if i.code == "NORMAL_NOT_UNIT")
    assert issue.severity == "error" and issue.location == "/pointshell/normals" and issue.message


@needs_cli
def test_inspect_equals_the_cli(sphere_asset: Path) -> None:
    assert CLI
    printed = subprocess.run([CLI, "inspect", "--json", str(sphere_asset)], check=True, capture_output=True, text=True)
    assert voxfmt.inspect(sphere_asset) == json.loads(printed.stdout)


@needs_cli
def test_bake_summary_has_the_cli_keys(sphere_mesh: Path, tmp_path: Path) -> None:
    assert CLI
    printed = subprocess.run(
        [CLI, "build", str(sphere_mesh), "-o", str(tmp_path / "cli.vox.h5"), "--json", "--resolution", "20",
         "--points", "400"],
        check=True, capture_output=True, text=True,
    )
    cli = json.loads(printed.stdout)
    ours = voxfmt.bake(sphere_mesh, tmp_path / "py.vox.h5", resolution=20, points=400)

    def keys(value: object, prefix: str = "") -> set[str]:
        if isinstance(value, dict):
            return {prefix + k for k in value} | {x for k, v in value.items() for x in keys(v, prefix + k + ".")}
        return set()

    assert keys(ours) == keys(cli)
    assert ours["voxelmap"] == cli["voxelmap"] and ours["pointshell"] == cli["pointshell"]
    assert ours["source_sha256"] == cli["source_sha256"]
