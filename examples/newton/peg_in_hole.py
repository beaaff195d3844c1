#!/usr/bin/env python3
"""A steel peg (radius 5 mm, 30 mm long, chamfered) released 2 mm above a block's chamfered blind hole, 0.3 mm off
its axis, in Newton with voxfmt assets as the meshes' SDFs: it slides down the chamfer and in. With Newton's convex
hulls (--hull) the block's hull fills the hole and the peg stays on top. Runs on the CPU (--device cpu, the default)
or a GPU; XPBD or the MuJoCo Warp solver (--solver).

    WARP_CACHE_PATH=.cache/warp PYTHONPATH=build/python .venv-newton/bin/python examples/newton/peg_in_hole.py \\
        [--clearance 0.2] [--hull] [--solver xpbd|mujoco] [--device cpu]

The meshes are made by examples/mujoco/shapes.py and baked on first use into --out.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "examples" / "mujoco"))
import shapes  # noqa: E402

import voxfmt  # noqa: E402
import voxfmt.newton  # noqa: E402

newton, wp = voxfmt.newton.newton, voxfmt.newton.wp


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--clearance", type=float, default=0.2, help="radial clearance, mm")
    ap.add_argument("--voxel", type=float, default=0.13, help="voxel size of the bake, mm")
    ap.add_argument("--seconds", type=float, default=0.3)
    ap.add_argument("--solver", choices=("xpbd", "mujoco"), default="xpbd")
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--hull", action="store_true", help="Newton's convex hulls of the same meshes instead")
    ap.add_argument("--out", default=str(ROOT / "out/newton-examples"))
    args = ap.parse_args()
    if not 0 < args.clearance < 2 or not 0.01 <= args.voxel <= 1 or not 0 < args.seconds <= 60:
        print("peg_in_hole: --clearance must be in (0, 2) mm, --voxel in [0.01, 1] mm, --seconds in (0, 60]",
              file=sys.stderr)
        return 2
    wp.config.quiet = True

    s = shapes.PegInHole(clearance=args.clearance * 1e-3)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    parts = {}
    for name, mesh in (("peg", shapes.peg_mesh(s)), (f"block-{args.clearance}", shapes.hole_block_mesh(s))):
        stem = out / f"{name}-{args.voxel}"
        shapes.write_off(Path(f"{stem}.off"), *mesh)
        asset = Path(f"{stem}.vox.h5")
        voxfmt.bake(Path(f"{stem}.off"), asset, voxel_size=args.voxel * 1e-3, points=20000, if_changed=True)
        parts[name.split("-")[0]] = (asset, mesh)

    builder = newton.ModelBuilder()
    # Contact stiffness for the MuJoCo solver as Newton's nut-and-bolt example sets it (XPBD does not read it).
    cfg = newton.ModelBuilder.ShapeConfig(mu=0.3, gap=0.0005, margin=0.0, ke=1e7, kd=1e4)
    steel = newton.ModelBuilder.ShapeConfig(mu=0.3, gap=0.0005, margin=0.0, ke=1e7, kd=1e4, density=7800.0)
    peg = builder.add_body(xform=wp.transform((0.0003, 0.0, s.block_height + 0.002), wp.quat_identity()))
    for body, (asset, mesh), shape_cfg in ((-1, parts["block"], cfg), (peg, parts["peg"], steel)):
        if args.hull:
            vertices, triangles = mesh
            hull = newton.Mesh(vertices.astype(np.float32), triangles.reshape(-1))
            builder.add_shape_convex_hull(body, mesh=hull, cfg=shape_cfg)
        else:
            voxfmt.newton.add_shape(builder, body, asset, mesh, cfg=shape_cfg, device=args.device)
    model = voxfmt.newton.finalize(builder, args.device)
    pipeline = newton.CollisionPipeline(model)
    contacts = pipeline.contacts()
    if args.solver == "xpbd":
        solver = newton.solvers.SolverXPBD(model, iterations=10)
    else:
        solver = newton.solvers.SolverMuJoCo(model, use_mujoco_contacts=False, solver="newton",
                                             integrator="implicitfast", cone="elliptic", iterations=15,
                                             ls_iterations=100, impratio=1.0)
    s0, s1, control = model.state(), model.state(), model.control()
    dt, times = 0.001, []
    for _ in range(int(round(args.seconds / dt))):
        start = time.perf_counter()
        s0.clear_forces()
        pipeline.collide(s0, contacts)
        solver.step(s0, s1, control, contacts, dt)
        s0, s1 = s1, s0
        wp.synchronize_device(args.device)
        times.append(time.perf_counter() - start)
    inserted = s.block_height - float(s0.body_q.numpy()[peg][2])  # the peg's origin is its bottom centre
    print(f"{'hulls' if args.hull else 'voxfmt'}, {args.solver}, clearance {args.clearance} mm: the peg is "
          f"{inserted * 1e3:.2f} mm into the {s.hole_depth * 1e3:.0f} mm hole after {args.seconds} s "
          f"({'fully in' if abs(inserted - s.hole_depth) < 0.5e-3 else 'not in'}); "
          f"step {np.median(times) * 1e3:.1f} ms on {args.device}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
