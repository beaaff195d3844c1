"""How steeply depth rises along lines into a baked object, against the distance band (issue 31, item 6).

Bakes the mesh at each band, walks 1/50 of the point shell's points inward along their normals in steps of a
tenth of a voxel, 12 voxels deep, with Body.signed_distance, and reports the largest rise of depth per voxel
travelled (1 for the exact distance; a haptic tool pushed in feels the field's slope as stiffness), with the
bake's time and the file's size. Past the band the depth is the lattice's interpolated estimate (spec §3.1),
which may sit up to ~4 voxels above the exact depth: the step from the last stored voxel to the first estimate.

  .venv/bin/python bench/depth_slope.py [--mesh MESH] [--bands 3,6,10] [--json OUT]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time

import numpy as np

import voxfmt

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


STEP = 0.1  # voxels between samples along a line


def inward_lines(body, depth_of=None):
    """Per inward line (from 1/50 of the shell's points, along their normals, 12 voxels deep, steps of STEP voxel)
    reaching at least 20 samples inside: its depths (voxels) and their rises per voxel travelled. `depth_of(points)`
    gives the depth (voxels) at points in metres (default: the body's own field)."""
    h = body.voxel_size
    if depth_of is None:
        def depth_of(points):
            return -body.signed_distance(points) / h
    s = np.arange(0, 12, STEP) * h
    for p, n in zip(body.points[::50].astype(np.float64), body.normals[::50].astype(np.float64)):
        depth = depth_of(p[None, :] + s[:, None] * n[None, :])
        if (depth > 0).sum() >= 20:
            yield depth, np.diff(depth) / STEP


def max_slope(path: str) -> dict:
    worst, at = 0.0, None
    for depth, slope in inward_lines(voxfmt.load(path)):
        k = int(np.argmax(slope))
        if slope[k] > worst:
            worst, at = float(slope[k]), {"travelled_voxels": round(k * STEP, 2), "depth_from": float(depth[k]),
                                          "depth_to": float(depth[k + 1])}
    return {"max_slope": worst, "where": at}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--mesh", default=os.path.join(REPO, "build/cgal-data/data/meshes/bunny00.off"))
    parser.add_argument("--resolution", type=int, default=306)
    parser.add_argument("--points", type=int, default=35000)
    parser.add_argument("--bands", default="3,6,10")
    parser.add_argument("--voxfmt", default=os.path.join(REPO, "build/bin/voxfmt"))
    parser.add_argument("--json", help="write the results here")
    args = parser.parse_args()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for band in [float(b) for b in args.bands.split(",")]:
            path = os.path.join(tmp, f"band{band:g}.vox.h5")
            start = time.monotonic()
            subprocess.run([args.voxfmt, "build", args.mesh, "-o", path, "--resolution", str(args.resolution),
                            "--points", str(args.points), "--band", f"{band:g}", "-q"], check=True)
            row = {"band": band, "bake_s": round(time.monotonic() - start, 2), "file_mb": os.path.getsize(path) / 1e6}
            row.update(max_slope(path))
            rows.append(row)
    print(f"{'band':>5} {'bake s':>7} {'file MB':>8} {'max slope (voxels/voxel)':>25}")
    for r in rows:
        print(f"{r['band']:>5g} {r['bake_s']:>7.2f} {r['file_mb']:>8.2f} {r['max_slope']:>25.2f}")
    if args.json:
        with open(args.json, "w") as fh:
            json.dump({"mesh": os.path.basename(args.mesh), "resolution": args.resolution, "points": args.points,
                       "command": " ".join(sys.argv), "runs": rows}, fh, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
