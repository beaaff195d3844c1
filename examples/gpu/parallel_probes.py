"""4,096 haptic probes pressed into a bunny at once, stepped from PyTorch (or NumPy) with the batched wrench.

Each environment holds a small sphere (the probe) pulled toward a target point inside the bunny by a spring, as a
haptic device's handle pulls its proxy; the contact wrench from voxfmt.BatchScene pushes it back out. Every step
is one batched call for all environments: on a CUDA device when PyTorch has one (poses stay on the GPU; nothing is
copied to the host but the final summary), on the CPU otherwise — the same code either way.

  PYTHONPATH=build/python .venv/bin/python examples/gpu/parallel_probes.py [--envs 4096] [--steps 200] [--device cuda|cpu]

It prints how far the probes sank (they settle where the spring and the contact stiffness balance, at the
surface plus spring/stiffness of the pull) and the time a step takes.
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

import voxfmt

REPO = Path(__file__).resolve().parents[2]


def icosphere_off(path: Path, radius: float) -> None:
    t = (1 + math.sqrt(5)) / 2
    v = np.array([(-1, t, 0), (1, t, 0), (-1, -t, 0), (1, -t, 0), (0, -1, t), (0, 1, t), (0, -1, -t), (0, 1, -t),
                  (t, 0, -1), (t, 0, 1), (-t, 0, -1), (-t, 0, 1)], float)
    f = [(0, 11, 5), (0, 5, 1), (0, 1, 7), (0, 7, 10), (0, 10, 11), (1, 5, 9), (5, 11, 4), (11, 10, 2), (10, 7, 6),
         (7, 1, 8), (3, 9, 4), (3, 4, 2), (3, 2, 6), (3, 6, 8), (3, 8, 9), (4, 9, 5), (2, 4, 11), (6, 2, 10),
         (8, 6, 7), (9, 8, 1)]
    v = v / np.linalg.norm(v, axis=1, keepdims=True) * radius
    path.write_text("OFF\n%d %d 0\n" % (len(v), len(f)) + "".join("%.12g %.12g %.12g\n" % tuple(p) for p in v) +
                    "".join("3 %d %d %d\n" % t for t in f))


def at_least_one(text: str) -> int:
    value = int(text)
    if value < 1:
        raise argparse.ArgumentTypeError(f"expected a count >= 1, got {value}")
    return value


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--envs", type=at_least_one, default=4096)
    parser.add_argument("--steps", type=at_least_one, default=500)
    parser.add_argument("--device", choices=["auto", "cuda", "cpu"], default="auto")
    parser.add_argument("--bunny", default=str(REPO / "build/cgal-data/data/meshes/bunny00.off"))
    parser.add_argument("--cache", default=os.path.join(tempfile.gettempdir(), "voxfmt-parallel-probes"))
    args = parser.parse_args()
    cache = Path(args.cache)
    cache.mkdir(parents=True, exist_ok=True)
    # Baked again only where the mesh (another --bunny) or the options changed.
    voxfmt.bake(args.bunny, cache / "bunny.vox.h5", resolution=96, points=4000, unit_scale=0.15, if_changed=True)
    icosphere_off(cache / "probe.off", 0.004)
    voxfmt.bake(cache / "probe.off", cache / "probe.vox.h5", resolution=16, points=200, if_changed=True)
    bunny, probe = voxfmt.load(cache / "bunny.vox.h5"), voxfmt.load(cache / "probe.vox.h5")
    scene = voxfmt.BatchScene([bunny, probe], pairs=[(1, 0)])  # A = the probe (the wrench acts on it)

    use_cuda = args.device == "cuda" or (args.device == "auto" and voxfmt.cuda_status()[0])
    try:
        import torch
    except ImportError:
        torch = None
    if use_cuda and torch is None:
        print("parallel_probes: --device cuda needs PyTorch", file=sys.stderr)
        return 2
    xp_device = "cuda" if use_cuda else "cpu"

    # Targets: points on a sphere around the bunny's centre, 60 % of the way in, so every probe presses into it.
    rng = np.random.default_rng(1)
    centre = np.asarray(bunny.center_of_mass)
    directions = rng.normal(size=(args.envs, 3))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    reach = 0.6 * float(np.linalg.norm(bunny.points - centre, axis=1).mean())
    target = centre + directions * reach * 0.6
    start = centre + directions * reach * 2.0
    pose_b = np.tile(np.eye(4, dtype=np.float32), (args.envs, 1, 1))
    if torch is not None and use_cuda:
        pos = torch.tensor(start, dtype=torch.float32, device="cuda")
        goal = torch.tensor(target, dtype=torch.float32, device="cuda")
        vel = torch.zeros_like(pos)
        poses_a = torch.eye(4, dtype=torch.float32, device="cuda").repeat(args.envs, 1, 1)
        poses_b = torch.tensor(pose_b, device="cuda")
    else:
        pos, goal, vel = start.astype(np.float32), target.astype(np.float32), np.zeros_like(start, dtype=np.float32)
        poses_a, poses_b = pose_b.copy(), pose_b
    mass, spring, damping, stiffness, dt = 0.01, 20.0, 0.5, 2000.0, 1e-3
    step_times = []
    for _ in range(args.steps):
        begin = time.perf_counter()
        poses_a[:, :3, 3] = pos
        r = scene.contacts(poses_a, poses_b, stiffness=stiffness, check=False)
        accel = (spring * (goal - pos) - damping * vel + r.force) / mass
        vel = vel + dt * accel
        pos = pos + dt * vel
        if use_cuda:
            torch.cuda.synchronize()
        step_times.append(time.perf_counter() - begin)
    depth = r.max_depth.cpu().numpy() if use_cuda else r.max_depth
    errors = int((r.error != 0).sum())
    print(f"{args.envs} probes on {xp_device}: {args.steps} steps, median step {1e3 * np.median(step_times):.2f} ms "
          f"({args.envs / np.median(step_times):,.0f} environment steps/s)")
    print(f"touching at the end: {int((depth > 0).sum())} of {args.envs}; deepest {1e3 * float(depth.max()):.2f} mm, "
          f"median {1e3 * float(np.median(depth)):.2f} mm; errors {errors}")
    return 0 if errors == 0 else 1


if __name__ == "__main__":
    sys.exit(main())
