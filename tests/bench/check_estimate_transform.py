"""bench/estimate_transform.cpp's chamfer transform on a baked box, against the box's exact distance.

    python tests/bench/check_estimate_transform.py VOXFMT ESTIMATE_TRANSFORM WORKDIR

A box (not a cube) is baked small; its value bricks' values from `estimate-transform --values` (with steps to the
26 neighbours, and to the 5^3) must be settled (the last pass lowered none), upper bounds of the exact distance (a
path is no shorter than the straight line), within the metric's 8 % (3 %) of it plus the lattice's slack, and each
the least of its seed and its value-brick neighbours' values plus their step (the rule a reader could check), and
the same whether the passes skip settled bricks or visit all, on one thread or two (slabs of brick layers); held
as 16-bit fixed point, never below the floats. Run brick by brick (`--by-brick`), the same values to the byte. In
place on the codes (`--in-codes`, steps of the estimate quantum, stored distances fixed): the tool's own check finds
no estimate off, this script's integer recomputation of the rule agrees, every estimate is an upper bound, and two
threads give the values of one. Exits non-zero with the first failure.
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


def steps(reach: int):
    """The steps to the (2 reach + 1)^3 neighbours and their lengths."""
    r = range(-reach, reach + 1)
    return [((dx, dy, dz), np.sqrt(dx * dx + dy * dy + dz * dz)) for dx in r for dy in r for dz in r
            if (dx, dy, dz) != (0, 0, 0)]


def offset_lengths(reach: int) -> np.ndarray:
    """[17, 17, 17]: the shortest path of steps from the centre to each offset -8 .. 8, by relaxation."""
    length = np.full((17, 17, 17), np.inf)
    length[8, 8, 8] = 0
    while True:
        padded = np.pad(length, reach, constant_values=np.inf)
        best = length.copy()
        for (dx, dy, dz), s in steps(reach):
            best = np.minimum(best, padded[reach + dx:reach + dx + 17, reach + dy:reach + dy + 17,
                                           reach + dz:reach + dz + 17] + s)
        if np.all(best >= length - 1e-9):
            return length
        length = best


def chamfer(offset: np.ndarray, lengths: np.ndarray) -> np.ndarray:
    """The length of the shortest path of steps along integer offsets (each axis within -8 .. 8)."""
    return lengths[offset[..., 0] + 8, offset[..., 1] + 8, offset[..., 2] + 8]


def bake_box(voxfmt_cli: str, work: Path) -> Path:
    """The box written to WORK/box.off and baked small with `voxfmt build`; the asset's path."""
    work.mkdir(parents=True, exist_ok=True)
    write_box(work / "box.off")
    asset = work / "box.vox.h5"
    subprocess.run([voxfmt_cli, "build", str(work / "box.off"), "-o", str(asset), "--resolution", "40",
                    "--points", "2000", "-q"], check=True)
    return asset


def main() -> int:
    voxfmt_cli, transform, work = sys.argv[1], sys.argv[2], Path(sys.argv[3])
    asset = bake_box(voxfmt_cli, work)
    # The 26-neighbour metric is within 8 % of the Euclidean; the 5^3 one within 3 %.
    for reach, metric in ((1, 1.09), (2, 1.03)):
        check(transform, asset, work, reach, metric)
    check_by_brick(transform, asset, work)
    check_in_codes(transform, asset, work)
    return 0


def run_values(transform: str, asset: Path, out: Path, *options: str) -> dict:
    """Runs the tool with `options`, its values written to `out`; its JSON figures."""
    figures = out.with_suffix(".json")
    subprocess.run([transform, str(asset), "--values", str(out), "--json", str(figures), *options], check=True,
                   stdout=subprocess.DEVNULL)
    return json.loads(figures.read_text())


def check_by_brick(transform: str, asset: Path, work: Path) -> None:
    """Brick by brick, on one thread or two, floats or 16-bit: the raster passes' values to the byte."""
    for fixed in ((), ("--fixed16",)):
        raster = work / "raster.f32"
        run_values(transform, asset, raster, *fixed)
        for threads in ("1", "2"):
            by_brick = work / f"by-brick-{threads}.f32"
            figures = run_values(transform, asset, by_brick, "--by-brick", "--threads", threads, *fixed)
            assert figures["by_brick"] and figures["passes"], "no brick-wise rounds"
            assert by_brick.read_bytes() == raster.read_bytes(), f"by brick ({threads} threads, {fixed}) differs"
    print("check_estimate_transform: brick by brick: the raster passes' values, 1 and 2 threads, float and 16-bit")


def check_in_codes(transform: str, asset: Path, work: Path) -> None:
    """In place on the codes: settled, checked, an upper bound, and the rule recomputed here in integers."""
    one, two = work / "codes-1.f32", work / "codes-2.f32"
    figures = run_values(transform, asset, one, "--in-codes")
    assert figures["check_wrong"] == 0, f"the tool's check found {figures['check_wrong']} estimates off the rule"
    run_values(transform, asset, two, "--in-codes", "--threads", "2")
    assert one.read_bytes() == two.read_bytes(), "two threads changed the values"
    with h5py.File(asset, "r") as f:
        attrs = f["voxelmap"].attrs
        origin, h, dims = np.asarray(attrs["origin"], float), float(attrs["voxel_size"]), np.asarray(attrs["dims"])
        q, dq = float(attrs["estimate_quantum"]), float(attrs["distance_quantum"])
        bricks = (dims + 7) // 8
        table = f["voxelmap/bricks"][...].reshape(bricks[2], bricks[1], bricks[0]).transpose(2, 1, 0)
        codes = f["voxelmap/brick_values"][...].astype(np.int64)
        lattice = np.asarray(f["voxelmap/lattice"], float).transpose(2, 1, 0)  # metres, [a, b, c]
    per_brick = np.fromfile(one, np.float32).reshape(-1, 512)
    # Magnitudes in steps of q on the grid (-1 outside value bricks), which voxels are estimates.
    units = np.full(tuple(dims), -1, np.int64)
    estimate = np.zeros(tuple(dims), bool)
    for bi, bj, bk in np.argwhere(table >= 0):
        e = table[bi, bj, bk]
        w, hh, d = (min(8, dims[a] - 8 * b) for a, b in enumerate((bi, bj, bk)))
        block = (slice(8 * bi, 8 * bi + w), slice(8 * bj, 8 * bj + hh), slice(8 * bk, 8 * bk + d))
        c = codes[e].reshape(8, 8, 8).transpose(2, 1, 0)[:w, :hh, :d]
        v = per_brick[e].reshape(8, 8, 8).transpose(2, 1, 0)[:w, :hh, :d].astype(np.float64)
        stored = c % 2 == 1
        units[block] = np.where(stored, np.ceil(np.abs(c >> 1) * dq / q - 1e-9), np.rint(v * h / q))
        estimate[block] = ~stored
    ijk = np.argwhere(estimate)
    got = units[estimate]
    exact = box_distance(origin + h * ijk) / h
    assert (got * q / h >= exact - 1e-3).all(), "an estimate below the exact distance"
    per_voxel = h / q
    axis = [int(np.ceil(np.sqrt(k) * per_voxel - 1e-9)) for k in range(4)]

    def path(offset: np.ndarray) -> np.ndarray:
        s = np.sort(np.abs(offset), axis=-1)
        return s[:, 0] * axis[3] + (s[:, 1] - s[:, 0]) * axis[2] + (s[:, 2] - s[:, 1]) * axis[1]

    best = np.full(len(ijk), 1 << 30, np.int64)
    cell = ijk // 8
    for corner in range(8):
        point = cell + np.array([corner & 1, corner >> 1 & 1, corner >> 2])
        at = np.minimum(point * 8, dims - 1)
        l_steps = np.minimum(16383, np.ceil(lattice[point[:, 0], point[:, 1], point[:, 2]] / q - 1e-9)).astype(np.int64)
        best = np.minimum(best, l_steps + path(at - ijk))
    best = np.minimum(best, 16383)
    padded = np.pad(units, 1, constant_values=-1)
    for dx in (-1, 0, 1):
        for dy in (-1, 0, 1):
            for dz in (-1, 0, 1):
                if dx == dy == dz == 0:
                    continue
                n = padded[ijk[:, 0] + 1 + dx, ijk[:, 1] + 1 + dy, ijk[:, 2] + 1 + dz]
                best = np.where(n >= 0, np.minimum(best, n + axis[abs(dx) + abs(dy) + abs(dz)]), best)
    off = best != got
    assert not off.any(), f"{off.sum()} estimates are not the least of seed and neighbours, e.g. {got[off][:3]} vs " \
                          f"{best[off][:3]}"
    print(f"check_estimate_transform: in place on the codes: {len(ijk)} estimates, each the least of its seed and "
          f"neighbours in steps of q, none below the exact distance, the same on two threads")


def check(transform: str, asset: Path, work: Path, reach: int, metric: float) -> None:
    values = work / f"box.reach{reach}.f32"
    subprocess.run([transform, str(asset), "--reach", str(reach), "--values", str(values), "--json",
                    str(work / "box.json")], check=True)

    figures = json.loads((work / "box.json").read_text())
    assert figures["passes"][-1]["lowered"] == 0, f"not settled: {figures['passes']}"
    # Passes that skip the bricks nothing near them changed reach the same values as passes over every brick, and
    # the seed on two threads the same as on one.
    every = work / f"box.reach{reach}.every.f32"
    subprocess.run([transform, str(asset), "--reach", str(reach), "--values", str(every), "--every-brick",
                    "--threads", "2"], check=True, stdout=subprocess.DEVNULL)
    assert values.read_bytes() == every.read_bytes(), "skipping settled bricks changed the values"
    # Held as 16-bit sixteenths of a voxel (steps and seeds rounded up): never below the floats' values, and settled.
    fixed = work / f"box.reach{reach}.fixed16.f32"
    subprocess.run([transform, str(asset), "--reach", str(reach), "--values", str(fixed), "--fixed16", "--json",
                    str(work / "box.fixed16.json")], check=True, stdout=subprocess.DEVNULL)
    floats, sixteenths = np.fromfile(values, np.float32), np.fromfile(fixed, np.float32)
    near = floats < 1e29
    assert (sixteenths[near] >= floats[near] - 1e-6).all(), "16-bit values below the float ones"
    assert json.loads((work / "box.fixed16.json").read_text())["passes"][-1]["lowered"] == 0, "16-bit not settled"

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
    over = got > metric * exact + lattice_slack + 1.0
    assert not over.any(), (f"{over.sum()} values beyond {metric} x exact + slack, e.g. {got[over][:3]} vs "
                            f"{exact[over][:3]}")

    # The fixed point: each estimate is the least of its seed and its value-brick neighbours' values plus their step.
    lengths = offset_lengths(reach)
    seed = np.full(len(ijk), np.inf)
    cell = np.minimum(ijk // 8, np.array(lattice.shape) - 2)
    for q in range(8):
        corner = cell + np.array([q & 1, q >> 1 & 1, q >> 2])
        at = np.minimum(corner * 8, dims - 1)
        seed = np.minimum(seed, lattice[corner[:, 0], corner[:, 1], corner[:, 2]] + chamfer(at - ijk, lengths))
    best = seed
    padded = np.pad(value, reach, constant_values=np.nan)
    for (dx, dy, dz), length in steps(reach):
        n = padded[ijk[:, 0] + reach + dx, ijk[:, 1] + reach + dy, ijk[:, 2] + reach + dz]
        best = np.minimum(best, np.where(np.isnan(n), np.inf, n + length))
    gap = np.abs(best - got)
    assert gap.max() < 1e-3, f"not the least of seed and neighbours: {gap.max()} voxels apart"
    print(f"check_estimate_transform: reach {reach}: {len(ijk)} estimates, none below the exact distance, largest "
          f"over it "
          f"{(got - exact).max():.2f} voxels, a fixed point within {gap.max():.1e}; passes {len(figures['passes'])}")



if __name__ == "__main__":
    sys.exit(main())
