"""examples/mujoco run in one command each, and bench/mujoco_compare.py --quick writes the JSON the issue asks
for. Machine-independent facts only: no timing is asserted."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

from conftest import MESHES, REPO


def run(*args: str, timeout: int = 300) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, *args], capture_output=True, text=True, timeout=timeout,
                          env=dict(os.environ), cwd=REPO)


def test_peg_example_inserts_where_hulls_jam(tmp_path: Path) -> None:
    # The peg strikes the hole's floor about 1.3 mm deep at 0.2 s (MuJoCo's soft contact, 2.1 and 2.2 assets alike)
    # and is back within 0.5 mm of it by 0.35 s.
    sdf = run("examples/mujoco/peg_in_hole.py", "--clearance", "0.2", "--voxel", "0.3", "--seconds", "0.4",
              "--out", str(tmp_path))
    assert sdf.returncode == 0, sdf.stderr
    assert "voxfmt, clearance 0.2 mm" in sdf.stdout and "(fully in)" in sdf.stdout, sdf.stdout
    hull = run("examples/mujoco/peg_in_hole.py", "--clearance", "0.2", "--voxel", "0.3", "--seconds", "0.3",
               "--out", str(tmp_path), "--hull")
    assert hull.returncode == 0, hull.stderr
    assert "(not in)" in hull.stdout, hull.stdout


def test_bunny_example_runs(tmp_path: Path) -> None:
    out = run("examples/mujoco/bunny_drop.py", "--mesh", str(MESHES / "bunny00.off"), "--resolution", "40",
              "--seconds", "0.5", "--out", str(tmp_path))
    assert out.returncode == 0, out.stderr
    assert "landed at 0.2" in out.stdout, out.stdout


def test_examples_refuse_bad_input(tmp_path: Path) -> None:
    bad = run("examples/mujoco/peg_in_hole.py", "--clearance", "-1", "--out", str(tmp_path))
    assert bad.returncode == 2 and "--clearance" in bad.stderr
    missing = run("examples/mujoco/bunny_drop.py", "--mesh", str(tmp_path / "none.off"), "--out", str(tmp_path))
    assert missing.returncode == 2 and "no such mesh" in missing.stderr


def test_bench_quick_writes_every_run(tmp_path: Path) -> None:
    out_json = tmp_path / "compare.json"
    bench = run("bench/mujoco_compare.py", "--quick", "--scenes", "bunny-on-box,peg-0.2mm", "--cache",
                str(tmp_path / "cache"), "--bunny", str(MESHES / "bunny00.off"), "--json", str(out_json),
                "--markdown", str(tmp_path / "compare.md"), timeout=600)
    assert bench.returncode == 0, bench.stderr[-3000:]
    runs = json.loads(out_json.read_text())["runs"]
    keys = {"scene", "method", "compile_s", "memory_mb", "step_us_p50", "step_us_p99", "max_penetration_mm",
            "rest_time_s", "outcome"}
    assert {(r["scene"], r["method"]) for r in runs} == {
        (s, m) for s in ("bunny-on-box", "peg-0.2mm") for m in ("hull", "native-sdf", "voxfmt")}
    for r in runs:
        assert keys <= set(r), r
        assert set(r["outcome"]) == {"inserted_mm", "inserted"}
        assert r["compile_s"] > 0 and r["memory_mb"] > 0 and 0 < r["step_us_p50"] <= r["step_us_p99"]
    by = {(r["scene"], r["method"]): r for r in runs}
    assert by[("peg-0.2mm", "voxfmt")]["outcome"]["inserted"] is True
    assert by[("peg-0.2mm", "hull")]["outcome"]["inserted"] is False  # the block's hull fills the hole
    assert by[("bunny-on-box", "voxfmt")]["lookups_per_step"] > 0
    assert "| bunny-on-box | voxfmt |" in (tmp_path / "compare.md").read_text()


def test_bench_refuses_bad_input(tmp_path: Path) -> None:
    bad = run("bench/mujoco_compare.py", "--quick", "--scenes", "no-such-scene", "--cache", str(tmp_path))
    assert bad.returncode == 2 and "no-such-scene" in bad.stderr
