"""examples/newton and bench/newton_scenes.py --quick, on the CPU device: the peg goes into the 0.2 mm hole with
voxfmt's SDFs and jams on the block's convex hull, with XPBD and with the MuJoCo Warp solver. Outcomes only: no
timing is asserted."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

from conftest import REPO


def run(*args: str, timeout: int = 900) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, *args], capture_output=True, text=True, timeout=timeout,
                          env=dict(os.environ), cwd=REPO)


def test_the_peg_goes_in_with_voxfmt_and_jams_on_hulls(tmp_path: Path) -> None:
    for solver in ("xpbd", "mujoco"):
        sdf = run("examples/newton/peg_in_hole.py", "--voxel", "0.3", "--seconds", "0.2", "--solver", solver,
                  "--out", str(tmp_path))
        assert sdf.returncode == 0, sdf.stderr
        assert f"voxfmt, {solver}, clearance 0.2 mm" in sdf.stdout and "(fully in)" in sdf.stdout, sdf.stdout
    hull = run("examples/newton/peg_in_hole.py", "--voxel", "0.3", "--seconds", "0.2", "--hull", "--out",
               str(tmp_path))
    assert hull.returncode == 0, hull.stderr
    assert "(not in)" in hull.stdout, hull.stdout


def test_the_benchmark_writes_its_figures(tmp_path: Path) -> None:
    out = tmp_path / "newton.json"
    r = run("bench/newton_scenes.py", "--quick", "--scenes", "peg-0.2mm", "--solvers", "xpbd", "--json", str(out),
            "--markdown", str(tmp_path / "newton.md"), "--cache", str(tmp_path / "cache"))
    assert r.returncode == 0, r.stderr
    report = json.loads(out.read_text())
    assert report["newton"] == "1.8.0" and report["device"]
    runs = {(x["method"], x["solver"]): x for x in report["runs"]}
    assert runs[("voxfmt", "xpbd")]["inserted"] and not runs[("hull", "xpbd")]["inserted"]
    assert runs[("voxfmt", "xpbd")]["deepest_penetration_m"] < 1e-4
    assert "| peg-0.2mm | xpbd | voxfmt | yes |" in (tmp_path / "newton.md").read_text()


def test_the_example_refuses_bad_input(tmp_path: Path) -> None:
    bad = run("examples/newton/peg_in_hole.py", "--clearance", "-1", "--out", str(tmp_path))
    assert bad.returncode == 2 and "--clearance" in bad.stderr
