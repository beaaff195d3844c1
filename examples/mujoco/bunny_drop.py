#!/usr/bin/env python3
"""The seed's bunny dropped on a table in MuJoCo, colliding through its voxfmt asset (the plugin
voxfmt.sdf.asset): the same baked file Bullet loads. With --on-bunny it falls half-overlapping onto a second,
static bunny inside four walls (without them it tumbles off, whatever the collision method).

    PYTHONPATH=build/python .venv/bin/python examples/mujoco/bunny_drop.py [--on-bunny] [--viewer]

The asset is baked on first use (CGAL's bunny00.off, 1 m, at --resolution voxels across) into --out.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

import mujoco
import numpy as np

import voxfmt
import voxfmt.mujoco

ROOT = Path(__file__).resolve().parents[2]
UPRIGHT = (math.sqrt(0.5), math.sqrt(0.5), 0.0, 0.0)  # the mesh is +Y up, MuJoCo is +Z up

TABLE = """<mujoco>
  <option timestep="0.001"/>
  <worldbody>
    <light pos="0 0 3"/>
    <geom name="table" type="box" size="1 1 0.1" pos="0 0 -0.1" rgba="0.6 0.6 0.6 1"/>
    {walls}
  </worldbody>
</mujoco>"""
WALLS = "".join(
    f'<geom name="wall{i}" type="box" size="{sx} {sy} 0.75" pos="{px} {py} 0.75" rgba="0.8 0.8 0.9 0.3"/>'
    for i, (sx, sy, px, py) in enumerate([(0.05, 0.8, 0.8, 0), (0.05, 0.8, -0.8, 0), (0.8, 0.05, 0, 0.65),
                                          (0.8, 0.05, 0, -0.65)])
)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--mesh", default=str(ROOT / "build/cgal-data/data/meshes/bunny00.off"))
    ap.add_argument("--out", default=str(ROOT / "out/mujoco-examples"), help="where the baked asset goes")
    ap.add_argument("--resolution", type=int, default=116, help="voxels across the bunny")
    ap.add_argument("--seconds", type=float, default=3.0)
    ap.add_argument("--on-bunny", action="store_true", help="drop it on a static bunny inside walls")
    ap.add_argument("--viewer", action="store_true", help="watch it in MuJoCo's viewer")
    args = ap.parse_args()

    asset = Path(args.out) / f"bunny-{args.resolution}.vox.h5"
    if not Path(args.mesh).exists():
        print(f"bunny_drop: {args.mesh}: no such mesh (CGAL's sample meshes: cmake unpacks them into build/)",
              file=sys.stderr)
        return 2
    asset.parent.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    # Baked again only where the mesh (another --mesh) or the options changed.
    if voxfmt.bake(args.mesh, asset, resolution=args.resolution, points=20000, if_changed=True)["status"] == "ok":
        print(f"baked {asset} in {time.perf_counter() - t0:.1f} s (once)")

    # Where the upright bunny stands on z = 0: its lowest point, from the asset's own point shell.
    rotation = np.zeros(9)
    mujoco.mju_quat2Mat(rotation, np.array(UPRIGHT))
    body = voxfmt.load(asset)
    heights = body.points @ rotation.reshape(3, 3).T
    stand, top = -heights[:, 2].min(), heights[:, 2].max() - heights[:, 2].min()

    # The three lines: the plugin, the MJCF pieces of a part, the model.
    voxfmt.mujoco.load_plugin()
    parts = [voxfmt.mujoco.part(asset, "bunny", pos=(0.25 if args.on_bunny else 0.0, 0, stand + 0.2 +
                                                    (top if args.on_bunny else 0.0)), quat=UPRIGHT)]
    if args.on_bunny:
        parts.append(voxfmt.mujoco.part(asset, "base", pos=(0, 0, stand), quat=UPRIGHT, static=True))
    t0 = time.perf_counter()
    model = mujoco.MjModel.from_xml_string(voxfmt.mujoco.insert(TABLE.format(walls=WALLS if args.on_bunny else ""),
                                                                *parts))
    data = mujoco.MjData(model)
    print(f"model compiled and loaded in {time.perf_counter() - t0:.2f} s")

    if args.viewer:
        from mujoco import viewer

        viewer.launch(model, data)
        return 0
    bunny = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, "bunny")
    velocity = np.zeros(6)
    steps = int(args.seconds / model.opt.timestep)
    landed, slow_since, step_time = None, None, []
    for i in range(steps):
        t0 = time.perf_counter()
        mujoco.mj_step(model, data)
        step_time.append(time.perf_counter() - t0)
        if landed is None and data.ncon:
            landed = i
        mujoco.mj_objectVelocity(model, data, mujoco.mjtObj.mjOBJ_BODY, bunny, velocity, 0)
        speed = np.linalg.norm(velocity[3:])  # of the centre of mass
        slow_since = (slow_since if slow_since is not None else i) if speed < 1e-3 else None
    print(f"landed at {landed * model.opt.timestep if landed is not None else float('nan'):.3f} s; step "
          f"{np.median(step_time) * 1e6:.0f} us (median); {data.ncon} contacts at the end")
    if slow_since is not None:
        print(f"at rest (centre of mass below 1 mm/s) since {slow_since * model.opt.timestep:.2f} s, at "
              f"z = {data.xpos[bunny][2]:.4f} m")
    else:
        print(f"still moving at the end: {np.linalg.norm(velocity[3:]) * 1e3:.2f} mm/s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
