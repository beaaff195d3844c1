"""bench/estimate_transform.cpp's chamfer transform on a baked box, against the box's exact distance.

    python tests/bench/check_estimate_transform.py VOXFMT ESTIMATE_TRANSFORM WORKDIR

A box (not a cube) is baked small; its value bricks' values from `estimate-transform --values` must be settled (the
last pass lowered none), upper bounds of the exact distance (a path is no shorter than the straight line), within
the chamfer metric's 8 % of it plus the lattice's slack, and each the least of its seed and its value-brick
neighbours' values plus their step (the rule a reader could check). Exits non-zero with the first failure.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import h5py
import numpy as np

HALF = np.array([0.031, 0.022, 0.014])  # metres


def write_box(path: Path) -> None:
    corners = np.array([[x, y, z] for z in (-1, 1) for y in (-1, 1) for x in (-1, 1)], float) * HALF
    quads = [(0, 2, 3, 1), (4, 5, 7, 6), (0, 1, 5, 4), (2, 6, 7, 3), (0, 4, 6, 2), (1, 3, 7, 5)]
    faces = [(a, b, c) for a, b, c, d in quads] + [(a, c, d) for a, b, c, d in quads]
    lines = ["OFF", f"{len(corners)} {len(faces)} 0"] + [" ".join(f"{v:.9f}" for v in p) for p in corners]
    lines += [f"3 {a} {b} {c}" for a, b, c in faces]
    path.write_text("\n".join(lines) + "\n")


def box_distance(x: np.ndarray) -> np.ndarray:
    """Unsigned distance to the box's surface."""
    q = np.abs(x) - HALF
    return np.abs(np.linalg.norm(np.maximum(q, 0), axis=-1) + np.minimum(q.max(axis=-1), 0))


def chamfer(offset: np.ndarray) -> np.ndarray:
    """The length of the shortest path of voxel steps 1, sqrt 2, sqrt 3 along integer offsets."""
    s = np.sort(np.abs(offset), axis=-1)
    return s[..., 0] * np.sqrt(3) + (s[..., 1] - s[..., 0]) * np.sqrt(2) + (s[..., 2] - s[..., 1])


def main() -> int:
    voxfmt_cli, transform, work = sys.argv[1], sys.argv[2], Path(sys.argv[3])
    work.mkdir(parents=True, exist_ok=True)
    write_box(work / "box.off")
    asset, values = work / "box.vox.h5", work / "box.values.f32"
    subprocess.run([voxfmt_cli, "build", str(work / "box.off"), "-o", str(asset), "--resolution", "40",
                    "--points", "2000", "-q"], check=True)
    subprocess.run([transform, str(asset), "--values", str(values), "--json", str(work / "box.json")], check=True)
    figures = json.loads((work / "box.json").read_text())
    assert figures["passes"][-1]["lowered"] == 0, f"not settled: {figures['passes']}"

    with h5py.File(asset, "r") as f:
        attrs = f["voxelmap"].attrs
        origin, h, dims = np.asarray(attrs["origin"], float), float(attrs["voxel_size"]), np.asarray(attrs["dims"])
        bricks = (dims + 7) // 8
        table = f["voxelmap/bricks"][...].reshape(bricks[2], bricks[1], bricks[0]).transpose(2, 1, 0)
        codes = f["voxelmap/brick_values"][...]
        lattice = np.asarray(f["voxelmap/lattice"], float).transpose(2, 1, 0) / h  # voxels, [a, b, c]
    per_brick = np.fromfile(values, np.float32).reshape(-1, 512)
    assert per_brick.shape[0] == codes.shape[0], "one row of values a value brick"

    # The values on the grid (nan outside value bricks), and which are estimates.
    value = np.full(tuple(dims), np.nan)
    estimate = np.zeros(tuple(dims), bool)
    for bi, bj, bk in np.argwhere(table >= 0):
        e = table[bi, bj, bk]
        w, hh, d = (min(8, dims[a] - 8 * b) for a, b in enumerate((bi, bj, bk)))
        block = (slice(8 * bi, 8 * bi + w), slice(8 * bj, 8 * bj + hh), slice(8 * bk, 8 * bk + d))
        value[block] = per_brick[e].reshape(8, 8, 8).transpose(2, 1, 0)[:w, :hh, :d]
        estimate[block] = (codes[e].reshape(8, 8, 8).transpose(2, 1, 0) % 2 == 0)[:w, :hh, :d]
    ijk = np.argwhere(estimate)
    assert len(ijk) > 1000, f"too few estimates to test ({len(ijk)})"
    got = value[estimate]
    exact = box_distance(origin + h * ijk) / h

    below = got < exact - 1e-3
    assert not below.any(), f"{below.sum()} values below the exact distance, e.g. {got[below][:3]} < {exact[below][:3]}"
    lattice_slack = float(np.max(lattice - box_distance(origin + h * np.stack(np.meshgrid(
        *[np.minimum(np.arange(n) * 8, d - 1) for n, d in zip(lattice.shape, dims)], indexing="ij"), -1)) / h))
    over = got > 1.09 * exact + lattice_slack + 1.0
    assert not over.any(), f"{over.sum()} values beyond 1.09 x exact + slack, e.g. {got[over][:3]} vs {exact[over][:3]}"

    # The fixed point: each estimate is the least of its seed and its value-brick neighbours' values plus their step.
    seed = np.full(len(ijk), np.inf)
    cell = np.minimum(ijk // 8, np.array(lattice.shape) - 2)
    for q in range(8):
        corner = cell + np.array([q & 1, q >> 1 & 1, q >> 2])
        at = np.minimum(corner * 8, dims - 1)
        seed = np.minimum(seed, lattice[corner[:, 0], corner[:, 1], corner[:, 2]] + chamfer(at - ijk))
    best = seed
    padded = np.pad(value, 1, constant_values=np.nan)
    for dx in (-1, 0, 1):
        for dy in (-1, 0, 1):
            for dz in (-1, 0, 1):
                if dx == dy == dz == 0:
                    continue
                n = padded[ijk[:, 0] + 1 + dx, ijk[:, 1] + 1 + dy, ijk[:, 2] + 1 + dz]
                offer = np.where(np.isnan(n), np.inf, n + np.sqrt(abs(dx) + abs(dy) + abs(dz)))
                best = np.minimum(best, offer)
    gap = np.abs(best - got)
    assert gap.max() < 1e-3, f"not the least of seed and neighbours: {gap.max()} voxels apart"
    print(f"check_estimate_transform: {len(ijk)} estimates, none below the exact distance, largest over it "
          f"{(got - exact).max():.2f} voxels, a fixed point within {gap.max():.1e}; passes {len(figures['passes'])}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
