#!/usr/bin/env python3
"""How far an asset's values beyond the band (its estimates) are from the exact signed distance, and how far they
would be if the lattice held exact distances, every 8, 4 or 2 voxels (issue "fidelity": measure before choosing).

    PYTHONPATH=build/python .venv/bin/python bench/deep_accuracy.py ASSET MESH [--samples N] [--steps 8,4,2] [--json OUT]

Needs libigl (`pip install libigl`, in pyproject's `bench` extra) for exact distances to the mesh, in the asset's
units. `--sign pseudonormal` (the default) signs them by pseudonormals, so MESH must be the closed mesh the asset
was baked from; `--sign asset` gives each sampled voxel the side the asset records (spec 3.1: the producer's
winding or shell rule) and the exact unsigned distance, so the magnitudes of an open or self-intersecting part are
measured too (in shell mode the exact distance is u - T/2).

Samples voxel centres whose value is beyond the band (|value| > band + 1/2 voxel), inside and outside, and reports
in voxels: the largest and 99th-percentile error, the share beyond the target of 1 voxel + 1 % of the depth, the
share under the exact depth by more than half a voxel; for the exact lattices the same, and how many of the
sampled coarse bricks hold a voxel beyond the target (what refining those bricks alone would cost); and the
asset's own lattice against exact distances at every lattice point (`--no-lattice` skips it). The asset is
read through the runtime (`Body.signed_distance`: what every consumer sees) and h5py (the grid's numbers).
"""

from __future__ import annotations

import argparse
import json
import sys
import time

import numpy as np


def interpolate(ijk: np.ndarray, step: int, dims: np.ndarray, values) -> np.ndarray:
    """A lattice every `step` voxels (the last point at the grid's end) interpolated at voxels; `values(index)`
    gives the lattice's values at lattice indices (n, 3)."""
    lower = ijk // step
    c0 = lower * step
    c1 = np.minimum(c0 + step, dims - 1)
    t = (ijk - c0) / np.maximum(c1 - c0, 1)
    last = (dims - 2) // step + 1  # the last lattice index along each axis (the grid's end)
    value = np.zeros(len(ijk))
    for corner in range(8):
        d = np.array([(corner >> a) & 1 for a in range(3)])
        weight = np.prod(np.where(d == 1, t, 1 - t), axis=1)
        value += weight * values(np.minimum(lower + d, last))
    return value


def table_values(table: np.ndarray):
    """`interpolate`'s values from a table of the whole lattice."""
    return lambda index: table[index[:, 0], index[:, 1], index[:, 2]]


def import_igl(script: str):
    """libigl, or None after saying it is needed."""
    try:
        import igl
    except ImportError:
        print(f"{script}: needs libigl (pip install libigl) for exact distances", file=sys.stderr)
        return None
    return igl


def read_grid(path: str):
    """The asset through the runtime (what every consumer sees) and its grid's numbers: body, origin, voxel size,
    dims and band (h5py)."""
    import h5py
    import voxfmt

    body = voxfmt.load(path, max_memory_mib=8192)  # a 4096 grid needs ~2 GiB
    with h5py.File(path, "r") as f:
        attrs = f["voxelmap"].attrs
        origin, h = np.asarray(attrs["origin"], float), float(attrs["voxel_size"])
        dims, band = np.asarray(attrs["dims"], int), float(attrs["distance_band"])
    return body, origin, h, dims, band


def read_bricks(path: str) -> np.ndarray | None:
    """The brick table [BD, BH, BW] (h5py; none in a 1.x file)."""
    import h5py

    with h5py.File(path, "r") as f:
        return np.asarray(f["voxelmap/bricks"][()]) if "bricks" in f["voxelmap"] else None


def read_shell_thickness(path: str) -> float:
    """The asset's shell thickness T (metres; 0 unless it was baked in shell mode)."""
    import h5py

    with h5py.File(path, "r") as f:
        attrs = f["voxelmap"].attrs
        return float(attrs["shell_thickness"]) if "shell_thickness" in attrs else 0.0


def exact_distances(points: np.ndarray, V, F, igl, sign: str, current: np.ndarray, shell: float) -> np.ndarray:
    """Exact signed distances (metres) at points: by pseudonormals, or the asset's sides with the unsigned distance
    (less half the shell in shell mode)."""
    if sign == "pseudonormal":
        return igl.signed_distance(points, V, F, sign_type=igl.SIGNED_DISTANCE_TYPE_PSEUDONORMAL)[0]
    unsigned = np.abs(igl.signed_distance(points, V, F, sign_type=igl.SIGNED_DISTANCE_TYPE_UNSIGNED)[0])
    if shell > 0:
        return unsigned - shell / 2
    return np.where(current < 0, -unsigned, unsigned)


def deep_voxels(body, origin, h, dims, band, samples: int) -> tuple[np.ndarray, np.ndarray]:
    """Up to `samples` random voxels whose value is beyond the band, and their values (voxels)."""
    rng = np.random.default_rng(1)
    ijk = np.stack([rng.integers(0, d, 8 * samples) for d in dims], -1)
    current = body.signed_distance(origin + h * ijk) / h
    deep = np.flatnonzero(np.abs(current) > band + 0.5)[:samples]
    return ijk[deep], current[deep]


def lattice_accuracy(path: str, origin, h: float, dims, V, F, igl, samples: int = 0) -> dict:
    """The asset's own lattice against the exact unsigned distance at every lattice point (voxels above it: the
    spec promises [u, (1 + e1) u + e0], the bake is exact within 16 voxels of the surface)."""
    import h5py

    with h5py.File(path, "r") as f:
        stored = np.asarray(f["voxelmap/lattice"], float)  # [c, b, a]
    axes = [np.minimum(np.arange(n) * 8, d - 1) for n, d in zip(stored.shape[::-1], dims)]
    grid = np.stack(np.meshgrid(*axes[::-1], indexing="ij"), -1)[..., ::-1].reshape(-1, 3)  # [c, b, a] -> (i, j, k)
    stored = stored.reshape(-1)
    if 0 < samples < len(stored):  # a random subset (a 4096 grid has 135 M lattice points)
        pick = np.random.default_rng(2).choice(len(stored), samples, replace=False)
        grid, stored = grid[pick], stored[pick]
    exact = np.abs(igl.signed_distance(origin + h * grid, V, F, sign_type=igl.SIGNED_DISTANCE_TYPE_UNSIGNED)[0]) / h
    over = stored / h - exact
    far = exact > 16
    return {"points": int(over.size), "max_over": round(float(over.max()), 3),
            "p99_over": round(float(np.percentile(over, 99)), 3),
            "min_over": round(float(over.min()), 6), "beyond_16_voxels": int(far.sum()),
            "mean_over_beyond_16": round(float(over[far].mean()), 4) if far.any() else 0.0,
            "over_1_voxel": int((over > 1).sum())}


def figures(estimate: np.ndarray, exact: np.ndarray) -> dict:
    out = {}
    error = estimate - exact
    beyond = np.abs(error) > 1 + 0.01 * np.abs(exact)
    for side, mask in (("inside", exact < 0), ("outside", exact > 0)):
        e = np.abs(error[mask])
        out[side] = {
            "samples": int(mask.sum()),
            "max_error": round(float(e.max()), 3) if e.size else 0.0,
            "p99_error": round(float(np.percentile(e, 99)), 3) if e.size else 0.0,
            "beyond_target_share": round(float(beyond[mask].mean()), 5) if e.size else 0.0,
            "under_by_half_share": round(float((np.abs(estimate[mask]) < np.abs(exact[mask]) - 0.5).mean()), 5)
            if e.size else 0.0,
        }
    return out


def write_json(path: str | None, result: dict) -> None:
    """The figures as JSON at path (none without one)."""
    if path:
        with open(path, "w") as f:
            json.dump(result, f, indent=1)
            f.write("\n")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("asset")
    ap.add_argument("mesh")
    ap.add_argument("--samples", type=int, default=60000, help="deep voxels sampled (default 60000)")
    ap.add_argument("--steps", default="8,4,2", help="exact lattices to try, voxels apart (default 8,4,2)")
    ap.add_argument("--json", help="write the figures here")
    ap.add_argument("--no-lattice", action="store_true", help="skip the asset's lattice against exact distances")
    ap.add_argument("--lattice-samples", type=int, default=0,
                    help="compare this many random lattice points (default: every one)")
    ap.add_argument("--sign", choices=("pseudonormal", "asset"), default="pseudonormal",
                    help="sides of the exact distances: the mesh's pseudonormals (a closed mesh) or the asset's own "
                    "(an open or self-intersecting one; default pseudonormal)")
    args = ap.parse_args()
    igl = import_igl("deep_accuracy")
    if igl is None:
        return 2
    body, origin, h, dims, band = read_grid(args.asset)
    bricks = read_bricks(args.asset)
    shell = read_shell_thickness(args.asset)
    V, F = igl.read_triangle_mesh(args.mesh)
    ijk, current = deep_voxels(body, origin, h, dims, band, args.samples)
    start = time.perf_counter()
    exact = exact_distances(origin + h * ijk, V, F, igl, args.sign, current, shell) / h
    exact_us = (time.perf_counter() - start) / len(ijk) * 1e6
    result = {"asset": args.asset, "mesh": args.mesh, "sign": args.sign, "shell_thickness": shell,
              "voxel_size": h, "dims": dims.tolist(), "band": band,
              "exact_us_per_point": round(exact_us, 2), "sign_disagreements": int((np.sign(current) != np.sign(exact)).sum()),
              "current": figures(current, exact), "exact_lattice": {}}
    # Value bricks (near the surface: format 2.2's settled estimates) and coarse bricks (the lattice interpolated).
    kinds = []
    if bricks is not None:
        in_value = bricks[ijk[:, 2] // 8, ijk[:, 1] // 8, ijk[:, 0] // 8] >= 0
        for kind, mask in (("value bricks", in_value), ("coarse bricks", ~in_value)):
            result["current_" + kind.replace(" ", "_")] = figures(current[mask], exact[mask])
            kinds.append((f"current estimates, {kind}", result["current_" + kind.replace(" ", "_")]))
    if not args.no_lattice:
        result["stored_lattice"] = lattice_accuracy(args.asset, origin, h, dims, V, F, igl, args.lattice_samples)
    steps = [int(s) for s in args.steps.split(",")]
    for step in steps:
        axes = [np.unique(np.minimum(np.arange(0, d + step, step), d - 1)) for d in dims]
        grid = np.stack(np.meshgrid(*axes, indexing="ij"), -1)
        points = origin + h * grid.reshape(-1, 3)
        unsigned = np.abs(igl.signed_distance(points, V, F, sign_type=igl.SIGNED_DISTANCE_TYPE_UNSIGNED)[0])
        if shell > 0:  # the lattice holds |u - T/2| in shell mode
            unsigned = np.abs(unsigned - shell / 2)
        table = (unsigned / h).reshape(grid.shape[:3])
        # The runtime's rule beyond the band: the interpolated magnitude, at least the band's edge, signed.
        estimate = np.sign(current) * np.maximum(interpolate(ijk, step, dims, table_values(table)), band - 0.5)
        entry = figures(estimate, exact)
        entry["lattice_points"] = len(points)
        if step == 8:
            beyond = np.abs(estimate - exact) > 1 + 0.01 * np.abs(exact)
            brick = np.ravel_multi_index((ijk // 8).T, tuple((dims + 7) // 8))
            sampled, inverse = np.unique(brick, return_inverse=True)
            bad = np.zeros(len(sampled), bool)
            np.logical_or.at(bad, inverse, beyond)
            entry["sampled_bricks"], entry["bricks_beyond_target"] = len(sampled), int(bad.sum())
        result["exact_lattice"][str(step)] = entry
    rows = [("current estimates", result["current"])] + kinds + [
        (f"exact lattice every {s}", result["exact_lattice"][str(s)]) for s in steps]
    print(f"deep_accuracy: {args.asset}, {len(ijk)} voxels beyond the band, exact distances {exact_us:.1f} µs each")
    print("| values | side | max error | p99 | beyond 1 voxel + 1 % | under by > 1/2 voxel |")
    print("|---|---|---|---|---|---|")
    for name, entry in rows:
        for side in ("inside", "outside"):
            e = entry[side]
            print(f"| {name} | {side} | {e['max_error']:.2f} | {e['p99_error']:.2f} | "
                  f"{100 * e['beyond_target_share']:.2f} % | {100 * e['under_by_half_share']:.2f} % |")
    e8 = result["exact_lattice"].get("8")
    if e8:
        print(f"coarse bricks with a voxel beyond the target under an exact lattice: {e8['bricks_beyond_target']} "
              f"of {e8['sampled_bricks']} sampled")
    s = result.get("stored_lattice")
    if s:
        print(f"the asset's lattice: {s['points']} points, above the exact distance by at most {s['max_over']:.3f} voxel "
              f"(p99 {s['p99_over']:.3f}), {s['over_1_voxel']} by more than 1; beyond 16 voxels "
              f"({s['beyond_16_voxels']} points) {s['mean_over_beyond_16']:.3f} on average")
    write_json(args.json, result)
    return 0


if __name__ == "__main__":
    sys.exit(main())
