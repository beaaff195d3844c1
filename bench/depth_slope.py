"""How steeply depth rises along lines into a baked object, against the distance band (issue 31, item 6).

Bakes the mesh at each band, walks 1/50 of the point shell's points inward along their normals in steps of a
tenth of a voxel, 12 voxels deep, with Body.signed_distance, and reports the largest rise of depth per voxel
travelled (1 for the exact distance; a haptic tool pushed in feels the field's slope as stiffness), its 99th
percentile over the lines and the share of lines above 1.2, with the bake's time and the file's size. Past the band
the depth is an estimate (spec §3.1): settled in value bricks (format 2.2), the lattice interpolated in coarse
bricks; where the two meet, or an estimate sits above the exact depth beside a stored one, the depth climbs faster.

  .venv/bin/python bench/depth_slope.py [--mesh MESH] [--bands 3,6,10] [--reference] [--json OUT]

--reference adds the same lines through exact distances at the voxel centres, interpolated as the runtime does:
the slope a field stored at voxels can reach (the exact distance itself rises 1 voxel per voxel).
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
CORNERS = np.array([[c & 1, c >> 1 & 1, c >> 2 & 1] for c in range(8)])  # a cell's 8 voxels from its base voxel


def inward_lines(body, depth_of=None, with_points=False):
    """Per inward line (from 1/50 of the shell's points, along their normals, 12 voxels deep, steps of STEP voxel)
    reaching at least 20 samples inside: its depths (voxels) and their rises per voxel travelled (and its points,
    with_points). `depth_of(points)` gives the depth (voxels) at points in metres (default: the body's own field)."""
    h = body.voxel_size
    if depth_of is None:
        def depth_of(points):
            return -body.signed_distance(points) / h
    s = np.arange(0, 12, STEP) * h
    for p, n in zip(body.points[::50].astype(np.float64), body.normals[::50].astype(np.float64)):
        points = p[None, :] + s[:, None] * n[None, :]
        depth = depth_of(points)
        if (depth > 0).sum() >= 20:
            yield (depth, np.diff(depth) / STEP, points) if with_points else (depth, np.diff(depth) / STEP)


def max_slope(path: str, depth_of=None) -> dict:
    """The largest rise over the inward lines, where it is, its 99th percentile over the lines (each line's
    largest) and the share of lines rising faster than 1.2 voxels per voxel."""
    worst, at, per_line, kinds = 0.0, None, [], {"value": 0, "coarse": 0, "both": 0}
    kind_of = None if depth_of else brick_kinds(path)
    for depth, slope, points in inward_lines(voxfmt.load(path), depth_of, with_points=True):
        k = int(np.argmax(slope))
        per_line.append(float(slope[k]))
        if kind_of and slope[k] > 1.2:
            kinds[kind_of(points[k], points[k + 1])] += 1
        if slope[k] > worst:
            worst, at = float(slope[k]), {"travelled_voxels": round(k * STEP, 2), "depth_from": float(depth[k]),
                                          "depth_to": float(depth[k + 1])}
    lines = np.array(per_line)
    return {"max_slope": worst, "where": at, "p99_slope": float(np.percentile(lines, 99)) if len(lines) else 0.0,
            "lines": len(lines), "lines_over_1_2": float((lines > 1.2).mean()) if len(lines) else 0.0,
            **({"over_1_2_in_bricks": kinds} if kind_of else {})}


def brick_kinds(path: str):
    """kind_of(a, b): whether the voxels a step from point a to point b interpolates (metres) lie in value bricks
    only, coarse bricks only, or both."""
    import h5py

    from estimate_oracle import brick_table  # it imports this module at its top

    with h5py.File(path, "r") as f:
        vm = f["voxelmap"]
        origin = np.asarray(vm.attrs["origin"], dtype=np.float64)
        h = float(vm.attrs["voxel_size"])
        dims = np.asarray(vm.attrs["dims"], dtype=np.int64)
    table = brick_table(path, dims)

    def kind_of(a, b):
        voxels = np.concatenate([np.floor((x - origin) / h).astype(np.int64) + CORNERS for x in (a, b)])
        voxels = np.clip(voxels, 0, dims - 1) // 8
        value = table[tuple(voxels.T)] >= 0
        return "value" if value.all() else "coarse" if not value.any() else "both"

    return kind_of


def exact_voxels_depth(path: str, mesh: str):
    """depth_of for inward_lines: exact signed distances (libigl, pseudonormals: a closed mesh) at the asset's voxel
    centres, interpolated trilinearly as the runtime samples its field: the slope the target can ask of any field
    stored at voxels."""
    import h5py
    import igl

    with h5py.File(path, "r") as f:
        origin = np.asarray(f["voxelmap"].attrs["origin"], dtype=np.float64)
        h = float(f["voxelmap"].attrs["voxel_size"])
    V, F = igl.read_triangle_mesh(mesh)

    def depth_of(points):
        u = (points - origin) / h
        base = np.floor(u)
        t = u - base
        centres = origin + h * (base[:, None, :] + CORNERS[None]).reshape(-1, 3)
        exact = igl.signed_distance(centres, V, F, sign_type=igl.SIGNED_DISTANCE_TYPE_PSEUDONORMAL)[0]
        weights = np.prod(np.where(CORNERS[None] == 1, t[:, None, :], 1 - t[:, None, :]), axis=2)
        return -(exact.reshape(-1, 8) * weights).sum(1) / h

    return depth_of


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--mesh", default=os.path.join(REPO, "build/cgal-data/data/meshes/bunny00.off"))
    parser.add_argument("--resolution", type=int, default=306)
    parser.add_argument("--points", type=int, default=35000)
    parser.add_argument("--bands", default="3,6,10")
    parser.add_argument("--voxfmt", default=os.path.join(REPO, "build/bin/voxfmt"))
    parser.add_argument("--reference", action="store_true",
                        help="also the slope of exact distances at the voxels, interpolated as the runtime does (needs "
                             "libigl and a closed mesh): what a field stored at voxels can reach")
    parser.add_argument("--json", help="write the results here")
    args = parser.parse_args()
    rows, reference = [], None
    with tempfile.TemporaryDirectory() as tmp:
        for band in [float(b) for b in args.bands.split(",")]:
            path = os.path.join(tmp, f"band{band:g}.vox.h5")
            start = time.monotonic()
            subprocess.run([args.voxfmt, "build", args.mesh, "-o", path, "--resolution", str(args.resolution),
                            "--points", str(args.points), "--band", f"{band:g}", "-q"], check=True)
            row = {"band": band, "bake_s": round(time.monotonic() - start, 2), "file_mb": os.path.getsize(path) / 1e6}
            row.update(max_slope(path))
            rows.append(row)
            if args.reference and reference is None:
                reference = max_slope(path, exact_voxels_depth(path, args.mesh))
    print(f"{'band':>9} {'bake s':>7} {'file MB':>8} {'max slope':>10} {'p99':>6} {'lines > 1.2':>12}  "
          "(their steepest step in value / coarse / both bricks)")
    for r in rows + ([dict(reference, band="exact", bake_s=0, file_mb=0)] if reference else []):
        kinds = r.get("over_1_2_in_bricks")
        print(f"{r['band']:>9} {r['bake_s']:>7.2f} {r['file_mb']:>8.2f} {r['max_slope']:>10.2f} {r['p99_slope']:>6.2f} "
              f"{100 * r['lines_over_1_2']:>11.1f}%" + ("  " + " / ".join(str(v) for v in kinds.values()) if kinds else ""))
    if args.json:
        with open(args.json, "w") as fh:
            json.dump({"mesh": os.path.basename(args.mesh), "resolution": args.resolution, "points": args.points,
                       "command": " ".join(sys.argv), "runs": rows, "exact_at_voxels": reference}, fh, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
