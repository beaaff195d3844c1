"""A batched contact query captured in a CUDA graph and replayed: the learning loop's way to call it 1,000s of times.

BatchScene.contacts(..., out=..., check=False) on CUDA arrays allocates nothing of its own on the host side and
waits for nothing, so PyTorch can capture it with the rest of a step. The graph reads the poses from the tensors it
was captured with: a step copies new poses into them and replays. This script captures one call, replays it over a
trajectory of poses, and checks every replay against a direct call on the same poses.

  PYTHONPATH=build/python .venv/bin/python examples/gpu/cuda_graph.py [--envs 4096] [--steps 100]

It needs PyTorch with a CUDA device; without one it says why and exits 0 (there is nothing to capture).
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

import voxfmt

REPO = Path(__file__).resolve().parents[2]


def device_reason() -> str | None:
    """None if a graph can be captured here, else why not."""
    ok, why = voxfmt.cuda_status()
    if not ok:
        return why
    try:
        import torch
    except ImportError:
        return "PyTorch is not installed"
    return None if torch.cuda.is_available() else "PyTorch sees no CUDA device"


def poses_along(envs: int, steps: int, reach: float) -> np.ndarray:
    """(steps, envs, 4, 4) float32: B slides past A along a line per environment, turning as it goes."""
    rng = np.random.default_rng(3)
    start = rng.normal(size=(envs, 3)) * reach
    way = rng.normal(size=(envs, 3)) * reach / steps
    out = np.tile(np.eye(4, dtype=np.float32), (steps, envs, 1, 1))
    for s in range(steps):
        angle = 0.01 * s
        c, si = np.cos(angle), np.sin(angle)
        out[s, :, :3, :3] = np.array([[c, -si, 0], [si, c, 0], [0, 0, 1]], dtype=np.float32)
        out[s, :, :3, 3] = start + s * way
    return out


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--envs", type=int, default=4096)
    parser.add_argument("--steps", type=int, default=100)
    parser.add_argument("--max-contacts", type=int, default=16)
    parser.add_argument("--bunny", default=str(REPO / "build/cgal-data/data/meshes/bunny00.off"))
    parser.add_argument("--cache", default=os.path.join(tempfile.gettempdir(), "voxfmt-cuda-graph"))
    args = parser.parse_args()
    why = device_reason()
    if why is not None:
        print(f"cuda_graph: no CUDA graph without a CUDA device ({why}); nothing to capture")
        return 0
    import torch

    cache = Path(args.cache)
    cache.mkdir(parents=True, exist_ok=True)
    asset = cache / "bunny.vox.h5"
    voxfmt.bake(args.bunny, asset, resolution=96, points=4000, unit_scale=0.15, if_changed=True)
    bunny = voxfmt.load(asset)
    scene = voxfmt.BatchScene([bunny])
    trajectory = torch.tensor(poses_along(args.envs, args.steps, 0.05), device="cuda")
    poses_a = torch.eye(4, dtype=torch.float32, device="cuda").repeat(args.envs, 1, 1)
    poses_b = trajectory[0].clone()  # the graph reads these: new poses are copied in
    k = args.max_contacts

    out = scene.new_outputs(poses_b, k)
    call = dict(stiffness=2e4, max_contacts=k, out=out, check=False)
    # Warm up on a side stream (uploads the assets, sizes the memory pool), as PyTorch asks before a capture.
    side = torch.cuda.Stream()
    side.wait_stream(torch.cuda.current_stream())
    with torch.cuda.stream(side):
        scene.contacts(poses_a, poses_b, **call)
    torch.cuda.current_stream().wait_stream(side)
    graph = torch.cuda.CUDAGraph()
    with torch.cuda.graph(graph):
        scene.contacts(poses_a, poses_b, **call)

    replay_s, direct_s, mismatches = [], [], 0
    for step in range(args.steps):
        poses_b.copy_(trajectory[step])
        torch.cuda.synchronize()
        begin = time.perf_counter()
        graph.replay()
        torch.cuda.synchronize()
        replay_s.append(time.perf_counter() - begin)
        replayed = {n: getattr(out, n).clone() for n in ("count", "force", "torque", "error", "depths", "point_index")}
        begin = time.perf_counter()
        direct = scene.contacts(poses_a, trajectory[step], stiffness=2e4, max_contacts=k)
        torch.cuda.synchronize()
        direct_s.append(time.perf_counter() - begin)
        # Contact rows past an environment's count are not written: compared only where they are.
        written = torch.arange(k, device="cuda")[None, :] < torch.clamp(direct.count, max=k)[:, None]
        same = all(torch.equal(replayed[n], getattr(direct, n)) for n in ("count", "force", "torque", "error"))
        same &= all(torch.equal(replayed[n][written], getattr(direct, n)[written]) for n in ("depths", "point_index"))
        mismatches += not same
    touching = int((out.count > 0).sum())
    print(f"{args.envs} environments, {args.steps} steps on {torch.cuda.get_device_name()}: graph replay "
          f"{1e3 * np.median(replay_s):.3f} ms, direct call {1e3 * np.median(direct_s):.3f} ms (medians, host clock)")
    print(f"touching at the last step: {touching} of {args.envs}; replays equal to direct calls: "
          f"{args.steps - mismatches} of {args.steps}")
    return 0 if mismatches == 0 else 1


if __name__ == "__main__":
    sys.exit(main())
