"""The GPU batch's scripts run end to end on the CPU (CI has no GPU): bench/gpu_batch.py --prepare, the device
check's flow (scripts/gpu/check.py on voxfmt's CPU path, which runs the kernel's code), --report, the
parallel-probes example, and the CUDA-graph example (which needs a device, and says so without one). On a GPU machine scripts/gpu-check.sh runs the same check on the device."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

REPO = Path(os.environ.get("VOXFMT_REPO", Path(__file__).resolve().parents[2]))
MESHES = Path(os.environ.get("VOXFMT_SAMPLE_MESHES", REPO / "build/cgal-data/data/meshes"))


def run(*args: str) -> str:
    proc = subprocess.run([sys.executable, *args], capture_output=True, text=True, cwd=REPO, timeout=600)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    return proc.stdout


def test_prepare_check_and_report_agree(tmp_path: Path) -> None:
    folder = tmp_path / "input"
    run("bench/gpu_batch.py", "--prepare", str(folder), "--poses", "600", "--bunny", str(MESHES / "bunny00.off"))
    cpu = json.loads((folder / "cpu.json").read_text())
    assert cpu["poses"] == 600 and cpu["cpu_poses_per_s"] > 0 and cpu["touching"] > 300
    run("scripts/gpu/check.py", "--input", str(folder / "gpu-batch-input.npz"), "--backend", "cpu", "--asset",
        cpu["asset"], "--max-envs", "64", "--reps", "3", "--json", str(tmp_path / "device.json"))
    device = json.loads((tmp_path / "device.json").read_text())
    for case, proximity in (("touching", 0.0), ("near", 1e-3)):
        assert device["agreement"][case] == {"environments": 600, "identical": 600, "differs": {}, "errors": 0,
                                             "proximity_m": proximity, "max_contacts": 8}, case
    assert [r["envs"] for r in device["latency"]] == [1, 64]
    assert device["min_blocks"] == 0  # no register cap on the CPU path
    run("bench/gpu_batch.py", "--report", str(tmp_path / "device.json"), "--input", str(folder), "--json",
        str(tmp_path / "result.json"), "--markdown", str(tmp_path / "result.md"), "--variants",
        str(tmp_path / "device.json"))
    result = json.loads((tmp_path / "result.json").read_text())
    assert [v["every_output_equal"] for v in result["variants"]] == [True, True]
    assert "| lanes a block | register cap (blocks a multiprocessor) |" in (tmp_path / "result.md").read_text()
    for key in ("device", "gpu_poses_per_s", "cpu_poses_per_s", "device_memory_mb", "latency", "agreement"):
        assert key in result, key
    # The Python path's device check, its flow on NumPy poses (on a GPU machine: CuPy and PyTorch poses).
    run("scripts/gpu/python_check.py", "--asset", cpu["asset"], "--poses", str(folder / "gpu-batch-input.npz"),
        "--frameworks", "numpy", "--json", str(tmp_path / "python.json"))
    python = json.loads((tmp_path / "python.json").read_text())
    assert [(r["environments"], r["identical"]) for r in python["agreement"].values()] == [(600, 600)] * 2


def test_parallel_probes_press_into_the_bunny(tmp_path: Path) -> None:
    out = run("examples/gpu/parallel_probes.py", "--envs", "128", "--steps", "400", "--device", "cpu", "--bunny",
              str(MESHES / "bunny00.off"), "--cache", str(tmp_path))
    touching = int(out.split("touching at the end: ")[1].split(" of ")[0])
    assert touching > 100, out
    assert "errors 0" in out, out


def test_the_cuda_graph_example_replays_what_direct_calls_give(tmp_path: Path) -> None:
    # With a device and PyTorch: every replay of the captured call equals a direct call. Without (CI): it says why.
    out = run("examples/gpu/cuda_graph.py", "--envs", "256", "--steps", "20", "--bunny", str(MESHES / "bunny00.off"),
              "--cache", str(tmp_path))
    if "no CUDA graph without a CUDA device" in out:
        return
    assert "replays equal to direct calls: 20 of 20" in out, out


def test_the_python_checks_comparison_finds_any_differing_output() -> None:
    sys.path.insert(0, str(REPO / "scripts/gpu"))
    from types import SimpleNamespace

    import numpy as np
    import python_check

    rng = np.random.default_rng(1)
    ref = SimpleNamespace(count=np.array([2, 0, 5], np.int32), max_depth=rng.random(3, np.float32),
                          force=rng.random((3, 3), np.float32), torque=rng.random((3, 3), np.float32),
                          overflow=np.array([0, 0, 3], np.int32), error=np.zeros(3, np.int32),
                          points=rng.random((3, 2, 3), np.float32), normals=rng.random((3, 2, 3), np.float32),
                          depths=rng.random((3, 2), np.float32), point_index=rng.integers(0, 9, (3, 2), np.int32),
                          point_of_b=rng.integers(0, 2, (3, 2), np.uint8))
    got = SimpleNamespace(**{k: v.copy() for k, v in vars(ref).items()})
    got.normals[1, 0] = 9.0  # environment 1 has no contacts: its rows are not compared
    assert python_check.compare(ref, got, 2) == {"environments": 3, "identical": 3, "differs": {}}
    got.force[2, 0] = np.nextafter(got.force[2, 0], np.float32(2))  # one ulp
    got.point_index[0, 1] += 1
    assert python_check.compare(ref, got, 2) == {"environments": 3, "identical": 1,
                                                 "differs": {"force": 1, "point_index": 1}}


def test_the_device_checks_agreement_finds_any_differing_output() -> None:
    sys.path.insert(0, str(REPO / "scripts/gpu"))
    import numpy as np
    from check import agreement

    rng = np.random.default_rng(0)
    ref = {"count": np.array([3, 0, 12], np.int32), "max_depth": rng.random(3, np.float32),
           "force": rng.random((3, 3), np.float32), "torque": rng.random((3, 3), np.float32),
           "overflow": np.array([0, 0, 4], np.int32), "error": np.zeros(3, np.int32),
           "points": rng.random((3, 8, 3), np.float32), "normals": rng.random((3, 8, 3), np.float32),
           "depths": rng.random((3, 8), np.float32), "point_index": rng.integers(0, 99, (3, 8), np.int32),
           "point_of_b": rng.integers(0, 2, (3, 8), np.uint8)}
    got = {k: v.copy() for k, v in ref.items()}
    got["points"][1, 5] = 7.0  # past environment 1's contacts (it has none): not compared
    assert agreement(ref, got)["identical"] == 3
    got["depths"][0, 2] = np.nextafter(got["depths"][0, 2], np.float32(1))  # one ulp, in a written row
    got["torque"][2, 1] += 1e-3
    result = agreement(ref, got)
    assert result["identical"] == 1 and set(result["differs"]) == {"depths", "torque"}, result
    assert result["differs"]["depths"]["environments"] == 1
