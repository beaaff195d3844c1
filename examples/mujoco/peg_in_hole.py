#!/usr/bin/env python3
"""A steel peg (radius 5 mm, 30 mm long, chamfered) released 2 mm above a block's chamfered blind hole, 0.3 mm off
its axis, in MuJoCo with voxfmt assets as SDF geoms: it slides down the chamfer and in. MuJoCo's default mesh
geoms collide through convex hulls, which fill the hole: the peg stays on top (--hull shows it).

    PYTHONPATH=build/python .venv/bin/python examples/mujoco/peg_in_hole.py [--clearance 0.2] [--hull] [--viewer]

The meshes are made here (examples/mujoco/shapes.py) and baked on first use into --out.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import mujoco
import numpy as np

import voxfmt
import voxfmt.mujoco

sys.path.insert(0, str(Path(__file__).resolve().parent))
import shapes  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
SCENE = """<mujoco>
  <option timestep="0.001"/>
  <default><geom friction="0.3"/></default>
  <worldbody>
    <light pos="0 0 0.3"/>
    <geom name="floor" type="box" size="0.1 0.1 0.01" pos="0 0 -0.01"/>
  </worldbody>
</mujoco>"""


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--clearance", type=float, default=0.2, help="radial clearance, mm")
    ap.add_argument("--voxel", type=float, default=0.13, help="voxel size, mm")
    ap.add_argument("--seconds", type=float, default=0.5)
    ap.add_argument("--out", default=str(ROOT / "out/mujoco-examples"))
    ap.add_argument("--hull", action="store_true", help="MuJoCo's mesh geoms (convex hulls) instead")
    ap.add_argument("--viewer", action="store_true")
    args = ap.parse_args()
    if not 0 < args.clearance < 2 or not 0.01 <= args.voxel <= 1:
        print("peg_in_hole: --clearance must be in (0, 2) mm and --voxel in [0.01, 1] mm", file=sys.stderr)
        return 2

    s = shapes.PegInHole(clearance=args.clearance * 1e-3)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    files = {}
    for name, mesh in (("peg", shapes.peg_mesh(s)), (f"block-{args.clearance}", shapes.hole_block_mesh(s))):
        stem = out / f"{name}-{args.voxel}"
        shapes.write_off(Path(f"{stem}.off"), *mesh)
        shapes.write_obj(Path(f"{stem}.obj"), *mesh)
        asset = Path(f"{stem}.vox.h5")
        voxfmt.bake(Path(f"{stem}.off"), asset, voxel_size=args.voxel * 1e-3, points=20000, if_changed=True)
        files[name.split("-")[0]] = stem

    voxfmt.mujoco.load_plugin()
    start = (0.0003, 0.0, s.block_height + 0.002)
    peg = voxfmt.mujoco.part(f"{files['peg']}.vox.h5", "peg", pos=start, density=7800.0)
    block = voxfmt.mujoco.part(f"{files['block']}.vox.h5", "block", static=True)
    xml = voxfmt.mujoco.insert(SCENE, peg, block)
    if args.hull:  # the same bodies and masses, with MuJoCo's mesh geoms
        xml = xml.replace(f'type="sdf" mesh="{peg.instance}"', 'type="mesh" mesh="peg_mesh"')
        xml = xml.replace(f'type="sdf" mesh="{block.instance}"', 'type="mesh" mesh="block_mesh"')
        peg_obj, block_obj = (f"{files[name]}.obj" for name in ("peg", "block"))
        xml = xml.replace("<asset>", f'<asset><mesh name="peg_mesh" file="{peg_obj}"/>'
                                     f'<mesh name="block_mesh" file="{block_obj}"/>')
    model = mujoco.MjModel.from_xml_string(xml)
    data = mujoco.MjData(model)
    if args.viewer:
        from mujoco import viewer

        viewer.launch(model, data)
        return 0
    body = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, "peg")
    times = []
    for _ in range(int(args.seconds / model.opt.timestep)):
        t0 = time.perf_counter()
        mujoco.mj_step(model, data)
        times.append(time.perf_counter() - t0)
    inserted = s.block_height - data.xpos[body][2]  # the peg's origin is its bottom centre
    print(f"{'hulls' if args.hull else 'voxfmt'}, clearance {args.clearance} mm: the peg is {inserted * 1e3:.2f} mm "
          f"into the {s.hole_depth * 1e3:.0f} mm hole after {args.seconds} s "
          f"({'fully in' if abs(inserted - s.hole_depth) < 0.5e-3 else 'not in'}); step {np.median(times) * 1e6:.0f} us")
    return 0


if __name__ == "__main__":
    sys.exit(main())
