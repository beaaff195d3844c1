#!/usr/bin/env python3
"""What better estimates in value bricks would give (issue "fidelity": measure before choosing a format change).

    PYTHONPATH=build/python .venv/bin/python bench/estimate_oracle.py ASSET MESH [--json OUT] [--producer-values F]

A value brick keeps a code per voxel, so its voxels beyond the band could hold any estimate at no cost in size;
format 2.1 puts the lattice's interpolation there (spec §3.1). This script rebuilds the asset's field voxel by
voxel (`Body.signed_distance` at every voxel centre), replaces the value bricks' estimates, and measures the field
as the runtime samples it (trilinear between voxel centres) for
  format 2.1       the asset's own estimates;
  band sources     an upper bound any reader could trust: |d_b| + |v - b| with b a voxel with a stored distance
                   or a lattice point (value l_b), the least such that sources carried from voxel to neighbouring
                   voxel reach (what a producer could compute without the mesh);
  chamfer sources  the same sources carried as a 26-neighbour chamfer transform (paths of voxel steps 1, sqrt 2,
                   sqrt 3 through the whole grid, two raster passes): cheap, 1.08-Lipschitz, still an upper bound;
  chamfer, capped by 2.1's
                   the least of that and format 2.1's estimate (which a reader's bounds on 2.1 assume);
  chamfer, value bricks only
                   with --producer-values: bench/estimate_transform.cpp's values (paths inside value bricks only,
                   coarse lattice points reached through each voxel's cell), what the producer above would store;
  exact            libigl's exact distance (what an exact transform would give).
It reports depth_slope.py's figure (largest rise of depth per voxel along inward lines from 1/50 of the shell's
points, 12 voxels deep, steps of a tenth of a voxel; 1 is the exact distance's), the share of lines steeper than
1.2, and deep_accuracy.py's errors on the same sampled voxels. Needs libigl and SciPy; MESH as in deep_accuracy.py.
"""

from __future__ import annotations

import argparse
import os
import sys

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from deep_accuracy import deep_voxels, figures, import_igl, read_grid, write_json  # noqa: E402
from depth_slope import inward_lines  # noqa: E402


def dense_field(body, origin, h, dims) -> np.ndarray:
    """Every voxel's value (voxels), [i, j, k]."""
    field = np.empty(int(np.prod(dims)))
    ii, jj, kk = np.meshgrid(*[np.arange(d) for d in dims], indexing="ij")
    ijk = np.stack([ii.ravel(), jj.ravel(), kk.ravel()], -1)
    for s in range(0, len(ijk), 1 << 21):
        field[s:s + (1 << 21)] = body.signed_distance(origin + h * ijk[s:s + (1 << 21)]) / h
    return field.reshape(*dims)


def brick_table(path: str, dims) -> np.ndarray:
    """The brick table [bi, bj, bk] (>= 0: a value brick's index)."""
    import h5py

    with h5py.File(path, "r") as f:
        bricks = (dims + 7) // 8
        return f["voxelmap/bricks"][...].reshape(bricks[2], bricks[1], bricks[0]).transpose(2, 1, 0)


def on_grid(table, per_brick: np.ndarray, dims, fill) -> np.ndarray:
    """Arrays of 512 values a value brick (x fastest, the value bricks' order) as one array [i, j, k]."""
    grid = np.full(tuple(int(d) for d in dims), fill, per_brick.dtype)
    for bi, bj, bk in np.argwhere(table >= 0):
        write_brick(grid, (bi, bj, bk), per_brick[table[bi, bj, bk]].reshape(8, 8, 8).transpose(2, 1, 0))
    return grid


def write_brick(grid, brick, block) -> None:
    """grid[8 brick + local] = block[local] ([i, j, k]), the voxels beyond the grid dropped."""
    view = grid[tuple(slice(8 * b, 8 * b + 8) for b in brick)]
    view[...] = block[:view.shape[0], :view.shape[1], :view.shape[2]]


def lattice_voxels(shape, dims) -> np.ndarray:
    """[a, b, c, 3]: each lattice point's voxel (brick corners, the last along an axis clamped to the grid)."""
    return np.stack(np.meshgrid(*[np.minimum(np.arange(n) * 8, d - 1) for n, d in zip(shape, dims)], indexing="ij"),
                    -1)


def value_brick_estimates(path: str, dims) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Masks [i, j, k] of the value bricks' estimates and of their stored distances, and the lattice (metres,
    [a, b, c])."""
    import h5py

    with h5py.File(path, "r") as f:
        codes = f["voxelmap/brick_values"][...]
        lattice = np.asarray(f["voxelmap/lattice"], float).transpose(2, 1, 0)  # [a, b, c]
    table = brick_table(path, dims)
    kind = on_grid(table, (1 + codes % 2).astype(np.int8), dims, 0)  # 1 an estimate, 2 a stored distance
    return kind == 1, kind == 2, lattice


def source_values(field, stored, lattice, h, dims) -> np.ndarray:
    """The sources' values [i, j, k] (voxels, float32): |d| at the stored distances, the lattice's value at its points
    (the lesser where both), 1e30 elsewhere."""
    value = np.full(tuple(int(d) for d in dims), np.float32(1e30), np.float32)
    value[stored] = np.abs(field[stored])
    corner = lattice_voxels(lattice.shape, dims).reshape(-1, 3)
    l = (lattice.reshape(-1) / h).astype(np.float32)
    keep = l < value[corner[:, 0], corner[:, 1], corner[:, 2]]
    value[corner[keep, 0], corner[keep, 1], corner[keep, 2]] = l[keep]
    return value


def band_sources(field, estimate, stored, lattice, h, dims, rounds: int = 64) -> np.ndarray:
    """The upper bound of the module's doc at the value bricks' estimates (magnitudes, voxels): sources carried from
    voxel to 6-neighbour (vector propagation, Danielsson 1980), Jacobi rounds until none changes, each voxel keeping
    the source b of least |d_b| + |v - b| it was offered: what a producer would compute."""
    shape = tuple(int(d) for d in dims)
    value = source_values(field, stored, lattice, h, dims)  # |d_b| of the voxel's source (each its own at first)
    best = value.copy()  # |d_b| + |v - b|
    grid = np.stack(np.meshgrid(*[np.arange(d, dtype=np.int16) for d in shape], indexing="ij"), -1)
    source = grid.copy()
    for _ in range(rounds):
        changed = 0
        for axis in range(3):
            for step in (1, -1):
                to = [slice(None)] * 3
                fr = [slice(None)] * 3
                to[axis] = slice(1, None) if step == 1 else slice(None, -1)
                fr[axis] = slice(None, -1) if step == 1 else slice(1, None)
                to, fr = tuple(to), tuple(fr)
                offer = source[fr]
                cand = value[fr] + np.linalg.norm((grid[to] - offer).astype(np.float32), axis=-1)
                better = cand < best[to] - 1e-6
                changed += int(better.sum())
                best[to] = np.where(better, cand, best[to])
                value[to] = np.where(better, value[fr], value[to])
                source[to] = np.where(better[..., None], offer, source[to])
        if changed == 0:
            break
    return best[estimate].astype(np.float64)


def chamfer_sources(field, estimate, stored, lattice, h, dims, passes: int = 4,
                    reach: int = 1) -> tuple[np.ndarray, int]:
    """The same sources, carried as a 26-neighbour chamfer transform: the least |d_b| + the length of a path of
    voxel steps (1, sqrt 2, sqrt 3) from b, in raster passes forward and back until one lowers nothing (at most
    `passes`; on the 306 bunny the second settles it). A path is no shorter than the straight line, so the
    value stays an upper bound; and it is 1-Lipschitz in the chamfer metric (at most 1.08 times the Euclidean), so a
    reader can check neighbouring values differ by at most their step. `reach` 2 takes steps to the 5^3 neighbours
    instead (lengths sqrt(a^2 + b^2 + c^2), a metric within ~2 % of the Euclidean). Returns the magnitudes at the
    estimates and the passes it took."""
    shape = tuple(int(d) for d in dims)
    value = source_values(field, stored, lattice, h, dims)
    offsets = range(-reach, reach + 1)
    x = np.arange(shape[0], dtype=np.float32)
    v = np.ascontiguousarray(value.transpose(2, 1, 0))  # [k, j, i]: rows along i contiguous

    def shifted(a, di: int, axis: int):
        """a[.., i + di, ..] along `axis` (1e30 beyond the grid)."""
        out = np.full_like(a, np.float32(1e30))
        src = [slice(None)] * a.ndim
        dst = [slice(None)] * a.ndim
        if di < 0:
            src[axis], dst[axis] = slice(None, di), slice(-di, None)
        elif di > 0:
            src[axis], dst[axis] = slice(di, None), slice(None, -di)
        out[tuple(dst)] = a[tuple(src)]
        return out

    def step(*d: int) -> np.float32:
        return np.float32(np.sqrt(sum(x * x for x in d)))

    def sweep(forward: bool) -> int:
        """One raster pass (k, then j, then i ascending, or all descending); the voxels it lowered."""
        back = -1 if forward else 1  # where the voxels already visited lie
        ks = range(shape[2]) if forward else range(shape[2] - 1, -1, -1)
        js = range(shape[1]) if forward else range(shape[1] - 1, -1, -1)
        lowered = 0
        for k in ks:
            plane = v[k]  # [j, i]
            before = plane.copy()
            for dk in range(1, reach + 1):
                if not 0 <= k + back * dk < shape[2]:
                    continue
                for dj in offsets:
                    prev = shifted(v[k + back * dk], dj, 0)
                    for di in offsets:
                        np.minimum(plane, shifted(prev, di, 1) + step(di, dj, dk), out=plane)
            for j in js:
                row = plane[j]
                for dj in range(1, reach + 1):
                    if 0 <= j + back * dj < shape[1]:
                        for di in offsets:
                            np.minimum(row, shifted(plane[j + back * dj], di, 0) + step(di, dj), out=row)
                # along i: row[i] = least row[i'] + |i - i'| over the i' visited before i
                if forward:
                    row[:] = np.minimum.accumulate(row - x) + x
                else:
                    row[:] = (np.minimum.accumulate((row + x)[::-1]) - x[::-1])[::-1]
            lowered += int((plane < before - np.float32(1e-4)).sum())
        return lowered

    done = 0
    for n in range(passes):
        changed = sweep(forward=n % 2 == 0)
        done = n + 1
        if n >= 1 and changed == 0:
            break
    return v.transpose(2, 1, 0)[estimate].astype(np.float64), done


def slopes(field, body, origin, h) -> np.ndarray:
    """The largest rise of depth per voxel along each of depth_slope.py's inward lines, in the dense field sampled
    as the runtime samples it (trilinear between voxel centres)."""
    from scipy.ndimage import map_coordinates

    def depth_of(points):
        return -map_coordinates(field, ((points - origin) / h).T, order=1, mode="nearest")

    return np.array([slope.max() for _, slope in inward_lines(body, depth_of)])


def variant_figures(field, body, origin, h, ijk, reference) -> tuple[dict, str]:
    """A field's figures (JSON): its slopes along the inward lines and its errors at the sampled deep voxels ijk
    against the exact distances `reference`; and the same as the table's cells."""
    s = slopes(field, body, origin, h)
    acc = figures(field[ijk[:, 0], ijk[:, 1], ijk[:, 2]], reference)
    out = {"max_slope": round(float(s.max()), 3), "p99_slope": round(float(np.percentile(s, 99)), 3),
           "lines": int(s.size), "lines_over_1_2": round(float((s > 1.2).mean()), 4), "accuracy": acc}
    cells = (f"{s.max():.2f} | {np.percentile(s, 99):.2f} | {100 * (s > 1.2).mean():.1f} % | "
             f"{acc['inside']['max_error']:.2f}, {100 * acc['inside']['beyond_target_share']:.2f} % | "
             f"{acc['outside']['max_error']:.2f}, {100 * acc['outside']['beyond_target_share']:.2f} % |")
    return out, cells


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("asset")
    ap.add_argument("mesh")
    ap.add_argument("--samples", type=int, default=60000, help="deep voxels sampled (default 60000)")
    ap.add_argument("--json", help="write the figures here")
    ap.add_argument("--producer-values", help="also measure these values (bench/estimate_transform.cpp --values: "
                    "float32 voxels, 512 a value brick): the chamfer transform as a producer runs it")
    args = ap.parse_args()
    igl = import_igl("estimate_oracle")
    if igl is None:
        return 2
    body, origin, h, dims, band = read_grid(args.asset)
    V, F = igl.read_triangle_mesh(args.mesh)
    field = dense_field(body, origin, h, dims)
    # The sampling must be the runtime's: check it on one line.
    p = body.points[0].astype(np.float64) + np.outer(np.arange(0, 12, 0.5) * h, body.normals[0])
    from scipy.ndimage import map_coordinates
    gap = np.abs(body.signed_distance(p) / h - map_coordinates(field, ((p - origin) / h).T, order=1)).max()
    assert gap < 1e-3, f"the dense field is not the runtime's ({gap} voxels apart)"
    estimate, stored, lattice = value_brick_estimates(args.asset, dims)
    where = np.argwhere(estimate)
    sign = np.sign(field[estimate])
    exact = igl.signed_distance(origin + h * where, V, F, sign_type=igl.SIGNED_DISTANCE_TYPE_PSEUDONORMAL)[0] / h

    def with_estimates(magnitudes):
        """Format 2.1's field with these magnitudes at the value-brick estimates, never inside the band."""
        variant = field.copy()
        variant[estimate] = sign * np.maximum(magnitudes, band - 0.5)
        return variant

    fields = {"format 2.1": field}
    fields["band sources"] = with_estimates(band_sources(field, estimate, stored, lattice, h, dims))
    chamfer, passes = chamfer_sources(field, estimate, stored, lattice, h, dims)
    fields["chamfer sources"] = with_estimates(chamfer)
    # Capped by format 2.1's estimate (the lattice's interpolation), so every bound a reader derives from 2.1's
    # estimates still holds.
    fields["chamfer, capped by 2.1's"] = with_estimates(np.minimum(chamfer, np.abs(field[estimate])))
    producer = None
    if args.producer_values:
        per_brick = np.fromfile(args.producer_values, np.float32).reshape(-1, 512)
        producer = on_grid(brick_table(args.asset, dims), per_brick, dims, np.float32(np.nan))[estimate]
        fields["chamfer, value bricks only"] = with_estimates(producer)
    fields["exact"] = with_estimates(np.abs(exact))
    ijk, current = deep_voxels(body, origin, h, dims, band, args.samples)
    reference = igl.signed_distance(origin + h * ijk, V, F, sign_type=igl.SIGNED_DISTANCE_TYPE_PSEUDONORMAL)[0] / h
    result = {"asset": args.asset, "mesh": args.mesh, "band": band, "value_brick_estimates": int(estimate.sum()),
              "value_brick_estimates_below_exact": int((np.abs(fields["band sources"][estimate]) <
                                                        np.abs(exact) - 1e-3).sum()),
              "chamfer_below_exact": int((chamfer < np.abs(exact) - 1e-3).sum()), "chamfer_passes": passes,
              "value_bricks_only_above_chamfer": None if producer is None else {
                  "max": round(float((producer - chamfer).max()), 4),
                  "share_over_0_01": round(float((producer - chamfer > 0.01).mean()), 5),
                  "below_exact": int((producer < np.abs(exact) - 1e-3).sum())},
              "variants": {}}
    print(f"estimate_oracle: {args.asset}: {estimate.sum()} value-brick voxels hold estimates")
    print("| value-brick estimates | max slope | p99 | lines > 1.2 | inside: max error, beyond 1 voxel + 1 % "
          "| outside: the same |")
    print("|---|---|---|---|---|---|")
    for name, f in fields.items():
        result["variants"][name], cells = variant_figures(f, body, origin, h, ijk, reference)
        print(f"| {name} | {cells}")
    write_json(args.json, result)
    return 0


if __name__ == "__main__":
    sys.exit(main())
