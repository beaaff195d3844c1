#!/usr/bin/env python3
"""Which coarse bricks would need a finer source than the 8-voxel lattice for deep values within 1 voxel + 1 % of
the depth, and how well a finer local lattice there would do (issue "fidelity", part 1: measure before choosing).

    PYTHONPATH=build/python .venv/bin/python bench/deep_refinement.py ASSET MESH [--threshold 0.75] [--json OUT]

Needs libigl (`pip install libigl`) for exact distances; MESH is the closed mesh the asset was baked from, in the
asset's units. With the lattice made exact (libigl at every brick corner), each coarse brick is probed at its
centre and its six face centres: a brick is flagged where the interpolated lattice (at least the band's edge) is
more than THRESHOLD voxels from the exact distance at a probe. Then, over voxels sampled beyond the band (as
`deep_accuracy.py` samples them), it reports how many stay beyond the target when the flagged bricks take
  exact   every voxel's exact distance (what storing them as value bricks would give),
  local s a local lattice every s voxels (4 or 2) of exact distances, interpolated,
and how many beyond-target voxels lie in value bricks (their estimates are the lattice's too), with the bytes a
flagged brick would take (512 codes, or (8/s + 1)^3 values).
"""

from __future__ import annotations

import argparse
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from deep_accuracy import deep_voxels, import_igl, interpolate, read_grid, table_values, write_json  # noqa: E402


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("asset")
    ap.add_argument("mesh")
    ap.add_argument("--threshold", type=float, default=0.75, help="probe error (voxels) that flags a brick")
    ap.add_argument("--samples", type=int, default=60000)
    ap.add_argument("--json")
    args = ap.parse_args()
    igl = import_igl("deep_refinement")
    if igl is None:
        return 2
    import h5py

    body, origin, h, dims, band = read_grid(args.asset)
    bricks = (dims + 7) // 8
    with h5py.File(args.asset, "r") as f:
        table = f["voxelmap/bricks"][...].reshape(bricks[2], bricks[1], bricks[0]).transpose(2, 1, 0)
    V, F = igl.read_triangle_mesh(args.mesh)

    def exact_unsigned(ijk: np.ndarray) -> np.ndarray:
        return np.abs(igl.signed_distance(origin + h * ijk, V, F, sign_type=igl.SIGNED_DISTANCE_TYPE_UNSIGNED)[0]) / h

    def exact_every(step: int):
        """`interpolate`'s values of a lattice every `step` voxels: exact distances, computed where asked."""
        return lambda index: exact_unsigned(np.minimum(index * step, dims - 1))

    axes = [np.unique(np.minimum(np.arange(0, d + 8, 8), d - 1)) for d in dims]
    grid = np.stack(np.meshgrid(*axes, indexing="ij"), -1)
    lattice = exact_unsigned(grid.reshape(-1, 3)).reshape(grid.shape[:3])

    def estimate(ijk: np.ndarray) -> np.ndarray:
        return np.maximum(interpolate(ijk, 8, dims, table_values(lattice)), band - 0.5)

    start = time.perf_counter()
    coarse = np.argwhere(table < 0)
    probes = np.array([[4, 4, 4], [0, 4, 4], [7, 4, 4], [4, 0, 4], [4, 7, 4], [4, 4, 0], [4, 4, 7]])
    worst = np.zeros(len(coarse))
    for probe in probes:
        points = np.minimum(coarse * 8 + probe, dims - 1)
        worst = np.maximum(worst, np.abs(estimate(points) - exact_unsigned(points)))
    flagged = worst > args.threshold
    flagged_set = set(map(tuple, coarse[flagged]))
    probe_s = time.perf_counter() - start

    ijk, current = deep_voxels(body, origin, h, dims, band, args.samples)
    sign = np.sign(current)
    exact = igl.signed_distance(origin + h * ijk, V, F, sign_type=igl.SIGNED_DISTANCE_TYPE_PSEUDONORMAL)[0] / h
    brick = ijk // 8
    in_value = table[brick[:, 0], brick[:, 1], brick[:, 2]] >= 0
    in_flagged = np.array([tuple(b) in flagged_set for b in brick])
    lattice_estimate = estimate(ijk)

    def beyond(magnitude: np.ndarray) -> np.ndarray:
        return np.abs(sign * magnitude - exact) > 1 + 0.01 * np.abs(exact)

    rows = {"exact 8-lattice": lattice_estimate,
            "flagged: exact": np.where(in_flagged, np.abs(exact), lattice_estimate)}
    for step in (4, 2):
        local = np.maximum(interpolate(ijk, step, dims, exact_every(step)), band - 0.5)
        rows[f"flagged: local lattice every {step}"] = np.where(in_flagged, local, lattice_estimate)
    result = {"asset": args.asset, "mesh": args.mesh, "threshold": args.threshold, "coarse_bricks": len(coarse),
              "flagged_bricks": int(flagged.sum()), "probe_seconds_numpy": round(probe_s, 2),
              "samples": len(ijk), "samples_in_value_bricks": int(in_value.sum()), "rows": {}}
    print(f"deep_refinement: {args.asset}: {flagged.sum()} of {len(coarse)} coarse bricks flagged "
          f"({flagged.mean():.2%}) at {args.threshold} voxel; {len(ijk)} deep voxels sampled")
    print("| values | beyond target in coarse bricks | in value bricks | largest error in coarse bricks | "
          "bytes per flagged brick |")
    print("|---|---|---|---|---|")
    for name, magnitude in rows.items():
        b = beyond(magnitude)
        error = np.abs(sign * magnitude - exact)[~in_value]
        size = {"exact 8-lattice": 0, "flagged: exact": 1024}.get(name, 2 * (8 // (4 if "4" in name else 2) + 1) ** 3)
        result["rows"][name] = {"beyond_coarse": int((b & ~in_value).sum()), "beyond_value": int((b & in_value).sum()),
                                "max_error_coarse": round(float(error.max()), 3), "bytes_per_flagged_brick": size}
        print(f"| {name} | {int((b & ~in_value).sum())} | {int((b & in_value).sum())} | {error.max():.2f} | {size} |")
    write_json(args.json, result)
    return 0


if __name__ == "__main__":
    sys.exit(main())
