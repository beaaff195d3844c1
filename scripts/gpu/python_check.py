"""The Python package's batch on a device, where voxfmt imports (docs/gpu.md, "Measuring on a GPU"): BatchScene on
CuPy and PyTorch poses against the same scene on NumPy poses (the CPU path), every output of every pose compared for
equality, touching and within 1 mm; then the path a training loop takes — PyTorch poses, `out=` buffers,
`check=False`, on a side stream — timed by CUDA events beside the host clock, its counts and forces compared too.

  python3 scripts/gpu/python_check.py --asset A.vox.h5 --poses P.npz --json OUT.json   # P: poses_a, poses_b
  python3 scripts/gpu/python_check.py ... --frameworks numpy                           # the flow on the CPU alone
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from typing import Any, Callable

import numpy as np

import voxfmt

PER_ENV = ("count", "max_depth", "force", "torque", "overflow", "error")
CONTACTS = ("points", "normals", "depths", "point_index", "point_of_b")
TIMED_ENVS = (1024, 4096, 16384, 65536)


def to_host(a: Any) -> np.ndarray:
    if hasattr(a, "cpu"):  # a PyTorch tensor
        return a.cpu().numpy()
    if hasattr(a, "get"):  # a CuPy array
        return a.get()
    return np.asarray(a)


def compare(ref: voxfmt.BatchResult, got: voxfmt.BatchResult, k: int) -> dict[str, Any]:
    """Environments whose every output equals the reference's (contact rows only where written)."""
    count = to_host(ref.count)
    same = np.ones(len(count), dtype=bool)
    differs: dict[str, int] = {}
    for name in PER_ENV + (CONTACTS if k else ()):
        a, b = to_host(getattr(ref, name)), to_host(getattr(got, name))
        equal = a == b
        if name in CONTACTS:
            written = np.arange(k)[None, :] < np.minimum(count, k)[:, None]
            equal |= ~written.reshape(written.shape + (1,) * (a.ndim - 2))
        per_env = equal.reshape(len(count), -1).all(axis=1)
        same &= per_env
        if not per_env.all():
            differs[name] = int((~per_env).sum())
    return {"environments": len(count), "identical": int(same.sum()), "differs": differs}


def uploaders(frameworks: list[str]) -> dict[str, Callable[[np.ndarray], Any]]:
    ways: dict[str, Callable[[np.ndarray], Any]] = {}
    for name in frameworks:
        if name == "cupy":
            import cupy

            ways[name] = cupy.asarray
        elif name == "torch":
            import torch

            ways[name] = lambda a: torch.from_numpy(a).cuda()
        else:
            ways[name] = np.ascontiguousarray
    return ways


def timed(scene: voxfmt.BatchScene, pa: np.ndarray, pb: np.ndarray, envs: int, reps: int) -> dict[str, Any]:
    """PyTorch poses, out= buffers, check=False, on a side stream: host clock and CUDA events per call."""
    import torch

    pick = np.resize(np.arange(len(pa)), envs)
    ga, gb = torch.from_numpy(pa[pick]).cuda(), torch.from_numpy(pb[pick]).cuda()
    out = scene.new_outputs(gb, 0)
    stream = torch.cuda.Stream()
    host_s, event_s = [], []
    with torch.cuda.stream(stream):
        for rep in range(reps + 3):
            begin, end = torch.cuda.Event(enable_timing=True), torch.cuda.Event(enable_timing=True)
            start = time.perf_counter()
            begin.record(stream)
            scene.contacts(ga, gb, stiffness=2e4, out=out, check=False)
            end.record(stream)
            end.synchronize()
            if rep >= 3:
                host_s.append(time.perf_counter() - start)
                event_s.append(begin.elapsed_time(end) * 1e-3)
    ref = scene.contacts(pa[pick], pb[pick], stiffness=2e4)
    equal = bool((to_host(out.count) == ref.count).all() and (to_host(out.force) == ref.force).all()
                 and (to_host(out.torque) == ref.torque).all())
    stream_s = float(np.median(event_s))
    return {"envs": envs, "host_p50_us": float(np.median(host_s)) * 1e6, "stream_p50_us": stream_s * 1e6,
            "poses_per_s": envs / stream_s, "counts_and_wrench_equal_cpu": equal}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--asset", required=True)
    parser.add_argument("--poses", required=True, help=".npz with poses_a and poses_b, (E, 4, 4) float32")
    parser.add_argument("--frameworks", default="cupy,torch", help="comma-separated: cupy, torch, numpy")
    parser.add_argument("--reps", type=int, default=30, help="timed calls per size (with torch)")
    parser.add_argument("--json", required=True)
    args = parser.parse_args()
    frameworks = [f for f in args.frameworks.split(",") if f]
    data = np.load(args.poses)
    pa, pb = np.ascontiguousarray(data["poses_a"]), np.ascontiguousarray(data["poses_b"])
    scene = voxfmt.BatchScene([voxfmt.load(args.asset)])
    report: dict[str, Any] = {"cuda_status": list(voxfmt.cuda_status()), "agreement": {}, "timed": []}
    ways = uploaders(frameworks)
    for proximity in (0.0, 1e-3):
        ref = scene.contacts(pa, pb, stiffness=2e4, proximity=proximity, max_contacts=8)
        for name, upload in ways.items():
            got = scene.contacts(upload(pa), upload(pb), stiffness=2e4, proximity=proximity, max_contacts=8)
            row = compare(ref, got, 8) | {"output_type": type(got.count).__module__ + "." + type(got.count).__name__}
            report["agreement"][f"{name}, proximity {proximity} m"] = row
            print(f"{name:6} proximity {proximity}: {row}", flush=True)
    if "torch" in frameworks:
        for envs in TIMED_ENVS:
            row = timed(scene, pa, pb, envs, args.reps)
            report["timed"].append(row)
            print(row, flush=True)
    with open(args.json, "w") as fh:
        json.dump(report, fh, indent=1)
    agreed = all(r["identical"] == r["environments"] for r in report["agreement"].values())
    return 0 if agreed and all(r["counts_and_wrench_equal_cpu"] for r in report["timed"]) else 1


if __name__ == "__main__":
    sys.exit(main())
