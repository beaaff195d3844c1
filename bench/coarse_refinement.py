#!/usr/bin/env python3
"""What finer sources in coarse bricks would give (issue "fidelity": measure before choosing a format change).

    PYTHONPATH=build/python .venv/bin/python bench/coarse_refinement.py ASSET MESH [--json OUT]
        [--feet 0,1 --feet-disc 0,3 --feet-blend 8:24,4:16 --no-refined]

A coarse brick stores no values: the runtime interpolates the lattice (exact distances at brick corners, 8 voxels
apart; beyond 16 voxels up to 10 % over, spec §3.3). After estimate_oracle.py, the errors beyond 1 voxel + 1 % of
depth are nearly all there (90 % of deep voxels are in coarse bricks on the 306 bunny). This script keeps the value
bricks' estimates at the chamfer transform (what bench/estimate_transform.cpp computes) and replaces the coarse
bricks' field by
  exact 8-lattice        the lattice's interpolation with exact corners (no far slack);
  4-lattice everywhere   exact distances on a lattice twice as fine (27 points a brick, 7 of them its own),
                         interpolated trilinearly;
  4-lattice where flagged
                         the same in the bricks a producer can flag without a search: near the surface (a corner
                         within NEAR voxels) or on a ridge of the distance (two corners' directions to their nearest
                         surface points more than ANGLE apart: the medial axis, where interpolation cuts the peak);
                         the exact 8-lattice elsewhere;
  2-lattice on ridges    the flagged variant, but every 2 voxels (125 points a brick) in the ridge bricks
                         (--ridge ANGLE), where a 4-voxel interpolation still cuts the peak; and that only in
                         the ridge bricks where the 4-lattice misses it by more than --ridge-tolerance.
and, with --feet, the coarse bricks' field from what the bake's lattice stage already holds instead of new points:
  feet                   each voxel's least distance to the nearest surface points ("feet") of the lattice points
                         around it (never below the exact distance; exact at a ridge whose sheets both have a
                         foot), over the brick's 8 corners or (a penalty > 0, continuous) the 4^3 points around;
  feet blended           the exact 8-lattice's interpolation up to NEAR voxels deep, the feet beyond FAR, blended
                         linearly between (--feet-blend): near the surface the corners' feet lie far to the side,
                         and the interpolation of a nearly flat distance is exact;
  feet, discs            with --feet-disc R: the distance to a disc of radius R around each foot in its tangent
                         plane instead of to the foot (no sideways over-estimate on a flat sheet); with
                         --feet-curvature T each disc at most as wide as keeps the sphere of the surface's curvature
                         at its foot within T voxels (libigl's principal curvatures), --feet-edges-plain none
                         on a triangle's edge or vertex, --feet-pseudonormal each disc normal to the surface's
                         pseudonormal at its foot, --feet-checked T each disc the widest of R, 3R/4, R/2, R/4 whose
                         rim (16 samples at the radius and at half of it) lies within T voxels of the surface or
                         behind it as seen from the lattice point: a disc behind the surface cannot under-estimate
                         (a straight line to it crosses the surface), so only discs in front of it are cut;
                         --feet-checked-by asset judges the rims by the asset's own field (its band) instead of
                         the mesh;
and reports estimate_oracle.py's figures (slope along inward lines, errors on sampled deep voxels against libigl's
exact distance), the flagged bricks and the values they would add. Needs libigl and SciPy; MESH as in
deep_accuracy.py. At the grid's far faces the last lattice cell is shorter than 8 voxels; the 4-lattice's weights
here ignore that (a few bricks).
"""

from __future__ import annotations

import argparse
import os
import sys

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from deep_accuracy import deep_voxels, import_igl, read_grid, write_json  # noqa: E402
from estimate_oracle import (brick_table, chamfer_sources, dense_field, lattice_voxels,  # noqa: E402
                             value_brick_estimates, variant_figures, write_brick)


def exact_distance(igl, points, V, F) -> np.ndarray:
    """libigl's signed distance (pseudonormals) at points, in chunks."""
    out = np.empty(len(points))
    for s in range(0, len(points), 1 << 18):
        out[s:s + (1 << 18)] = igl.signed_distance(points[s:s + (1 << 18)], V, F,
                                                   sign_type=igl.SIGNED_DISTANCE_TYPE_PSEUDONORMAL)[0]
    return out


def trilinear_weights(points_per_axis: int) -> np.ndarray:
    """[512, points^3]: each voxel of a brick ([i, j, k], i slowest) as trilinear weights of a lattice of
    `points_per_axis` points an axis ([a, b, c], a slowest) from the brick's corner to the next brick's, 8 voxels."""
    cells = points_per_axis - 1
    spacing = 8 / cells
    local = np.arange(8)
    cell = np.minimum(local // spacing, cells - 1).astype(int)
    t = (local - cell * spacing) / spacing
    axis = np.zeros((8, points_per_axis))  # [voxel, point] weights along one axis
    axis[local, cell] = 1 - t
    axis[local, cell + 1] += t
    return np.einsum("ia,jb,kc->ijkabc", axis, axis, axis).reshape(512, -1)


def feet_values(coarse, table, feet, normals, LD, top, penalty: float, disc=0.0) -> np.ndarray:
    """[coarse bricks, 512] signed values: the least distance from each voxel to the nearest surface points `feet`
    (voxel coordinates, [lattice points, 3]) of the lattice points around it. Penalty 0: the brick's 8 corners
    (not continuous from one brick to the next); > 0: the 4^3 points around, each plus `penalty` times how far the
    voxel is (L-infinity, voxels) beyond the 8 cells around the point (0 for the brick's corners), continuous.
    disc > 0: the distance to a disc of that radius (voxels) around each foot in its tangent plane (`normals`,
    [lattice points, 3], unit; a zero normal: the foot alone) instead of to the foot alone; an array [LD]: a radius
    a lattice point."""
    feet = feet.reshape(*LD, 3)
    local = np.stack(np.meshgrid(*[np.arange(8)] * 3, indexing="ij"), -1).reshape(512, 3)
    offsets = [(a, b, c) for a in (0, 1) for b in (0, 1) for c in (0, 1)] if penalty == 0 else \
        [(a, b, c) for a in range(-1, 3) for b in range(-1, 3) for c in range(-1, 3)]
    out = np.empty((len(coarse), 512))
    for s in range(0, len(coarse), 2000):
        bricks = coarse[s:s + 2000]
        x = (bricks[:, None, :] * 8 + local[None]).astype(float)
        best = np.full((len(bricks), 512), np.inf)
        for off in offsets:
            q = bricks + off
            valid = ((q >= 0) & (q < LD)).all(1)
            q = np.clip(q, 0, LD - 1)
            foot = feet[tuple(q.T)]
            d = np.linalg.norm(x - foot[:, None, :], axis=2)
            p = np.minimum(q * 8, top)
            radius = disc[tuple(q.T)][:, None] if np.ndim(disc) else disc
            if np.any(radius > 0):
                normal = normals.reshape(-1, 3)[np.ravel_multi_index(tuple(q.T), tuple(LD))]
                plane = np.einsum("nva,na->nv", x - foot[:, None, :], normal)
                lateral = np.sqrt(np.maximum(d * d - plane * plane, 0))
                to_disc = np.sqrt(plane * plane + np.maximum(lateral - radius, 0) ** 2)
                d = np.where(np.linalg.norm(normal, axis=1)[:, None] > 0.5, to_disc, d)
            if penalty > 0:
                d += penalty * np.maximum(np.abs(x - p[:, None, :]).max(2) - 8, 0)
            best = np.minimum(best, np.where(valid[:, None], d, np.inf))
        sign = np.where(table[tuple(bricks.T)] == -2, -1.0, 1.0)
        out[s:s + 2000] = sign[:, None] * best
    return out


def checked_disc_radii(signed_distance, feet, normals, side, disc: float, h: float, tolerance: float) -> np.ndarray:
    """Per foot (metres, [n, 3], with unit plane normals [n, 3] and the side of its lattice point, +1 outside): the
    widest of disc, 3/4, 1/2, 1/4 of it (voxels) whose rim, 8 samples at the radius and 8 at half of it, lies no
    more than `tolerance` voxels in front of the surface as seen from the lattice point, by `signed_distance(points)`
    (metres, positive outside); 0 where none does."""
    helper = np.where(np.abs(normals[:, :1]) < 0.9, [[1.0, 0, 0]], [[0, 1.0, 0]])
    e1 = np.cross(normals, helper)
    e1 /= np.maximum(np.linalg.norm(e1, axis=1, keepdims=True), 1e-12)
    e2 = np.cross(normals, e1)
    angles = np.arange(8) * np.pi / 4
    rim = np.cos(angles)[None, :, None] * e1[:, None] + np.sin(angles)[None, :, None] * e2[:, None]  # [n, 8, 3]
    radii = np.zeros(len(feet))
    open_ = np.ones(len(feet), bool)  # no wider disc has passed yet
    for r in (disc, 0.75 * disc, 0.5 * disc, 0.25 * disc):
        todo = np.flatnonzero(open_)
        if not len(todo):
            break
        samples = np.concatenate([feet[todo, None] + h * r * rim[todo], feet[todo, None] + 0.5 * h * r * rim[todo]], 1)
        signed = signed_distance(samples.reshape(-1, 3))
        in_front = (side[todo, None] * signed.reshape(len(todo), 16)).max(1) / h
        ok = in_front <= tolerance
        radii[todo[ok]] = r
        open_[todo[ok]] = False
    return radii


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("asset")
    ap.add_argument("mesh")
    ap.add_argument("--samples", type=int, default=60000, help="deep voxels sampled (default 60000)")
    ap.add_argument("--flags", default="16:45,8:45,16:30",
                    help="NEAR:ANGLE pairs for the flagged variants (default 16:45,8:45,16:30)")
    ap.add_argument("--ridge", default="16:45",
                    help="NEAR:ANGLE of the 2-lattice variant: ridge bricks (ANGLE) every 2 voxels, the other bricks "
                         "within NEAR voxels every 4 (default 16:45; '' skips it)")
    ap.add_argument("--ridge-tolerance", type=float, default=1.0,
                    help="voxels: a ridge brick keeps its 2-lattice where the 4-lattice is further off (default 1)")
    ap.add_argument("--reach", type=int, choices=(1, 2), default=1,
                    help="the value bricks' chamfer transform: steps to the 26 neighbours (1) or the 5^3 (2)")
    ap.add_argument("--feet", default="",
                    help="comma-separated penalties for the feet variants (0: the least distance to the 8 corners' "
                         "nearest surface points; > 0: over the 4^3 points around, each beyond its 8 cells penalised "
                         "by that many voxels a voxel; default '' skips them)")
    ap.add_argument("--feet-disc", default="0",
                    help="comma-separated disc radii (voxels) for the feet variants: 0 the feet alone, R > 0 a disc of "
                         "radius R around each in its tangent plane (default 0)")
    ap.add_argument("--feet-curvature", type=float, default=0,
                    help="voxels: each disc at most as wide as keeps the surface's sphere of curvature at its foot "
                         "within this of the disc (default 0: the radius alone)")
    ap.add_argument("--feet-edges-plain", action="store_true",
                    help="with --feet-curvature: no disc for a foot on a triangle's edge or vertex")
    ap.add_argument("--feet-pseudonormal", action="store_true",
                    help="the discs' planes normal to the surface's pseudonormal at each foot")
    ap.add_argument("--feet-checked", type=float, default=None,
                    help="voxels: each disc the widest of R, 3R/4, R/2, R/4 whose rim samples lie no more than this in "
                         "front of the surface as seen from the lattice point (pseudonormal signs: a closed mesh); "
                         "none of them: no disc")
    ap.add_argument("--feet-checked-by", choices=("mesh", "asset"), default="mesh",
                    help="--feet-checked's signed distances: exact, from the mesh (libigl), or the asset's own field "
                         "(its stored band, where the rims lie: no search; default mesh)")
    ap.add_argument("--feet-blend", default="8:24",
                    help="comma-separated NEAR:FAR depths (voxels) of the blended feet variants (default 8:24)")
    ap.add_argument("--no-refined", action="store_true", help="skip the finer-lattice variants")
    ap.add_argument("--json", help="write the figures here")
    args = ap.parse_args()
    igl = import_igl("coarse_refinement")
    if igl is None:
        return 2
    body, origin, h, dims, band = read_grid(args.asset)
    V, F = igl.read_triangle_mesh(args.mesh)
    field = dense_field(body, origin, h, dims)
    estimate, stored, lattice = value_brick_estimates(args.asset, dims)
    table = brick_table(args.asset, dims)
    sign = np.sign(field)
    chamfer, _ = chamfer_sources(field, np.ones(field.shape, bool), stored, lattice, h, dims, reach=args.reach)
    base = field.copy()
    base[estimate] = sign[estimate] * np.maximum(chamfer.reshape(field.shape)[estimate], band - 0.5)

    coarse = np.argwhere(table < 0)
    top = np.asarray(dims) - 1
    m = np.stack(np.meshgrid(*[np.arange(3)] * 3, indexing="ij"), -1).reshape(-1, 3)
    points = np.minimum(coarse[:, None, :] * 8 + 4 * m[None], top).reshape(-1, 3)
    print(f"coarse_refinement: {args.asset}: {len(coarse)} coarse bricks, {len(table.ravel()) - len(coarse)} value "
          f"bricks; exact distances at {len(points)} points", flush=True)
    fine = (exact_distance(igl, origin + h * points, V, F) / h).reshape(len(coarse), 27)
    corners = fine.reshape(-1, 3, 3, 3)[:, ::2, ::2, ::2].reshape(-1, 8)
    fine_values = fine @ trilinear_weights(3).T  # [n, 512]
    exact8_values = corners @ trilinear_weights(2).T

    # What a producer has at the lattice: its values (the asset's) and the nearest surface points (libigl's here;
    # the bake's lattice keys hold the nearest triangles).
    LD = np.asarray(lattice.shape)
    P = origin + h * lattice_voxels(LD, dims).reshape(-1, 3)
    _, foot_triangle, nearest = igl.point_mesh_squared_distance(P, V, F)
    direction = P - nearest
    direction /= np.maximum(np.linalg.norm(direction, axis=1), 1e-12)[:, None]
    direction = direction.reshape(*LD, 3)
    corner_at = [np.minimum(coarse + [a, b, c], LD - 1) for a in (0, 1) for b in (0, 1) for c in (0, 1)]
    depth = np.min([lattice[tuple(q.T)] for q in corner_at], axis=0) / h
    g = np.stack([direction[tuple(q.T)] for q in corner_at], 1)
    least_cos = np.einsum("nik,njk->nij", g, g).reshape(len(coarse), -1).min(1)

    def variant(values) -> np.ndarray:
        f = base.copy()
        for brick, block in zip(coarse, values.reshape(-1, 8, 8, 8)):
            write_brick(f, brick, block)
        return f

    points4 = points.reshape(len(coarse), 27, 3)

    def added_values(*sources) -> int:
        """The points that bricks' sources ([bricks, points, 3] each) need beyond the 8-lattice, each once."""
        needed = np.concatenate([q.reshape(-1, 3) for q in sources])
        needed = needed[~((needed % 8 == 0) | (needed == top)).all(1)]
        return int(len(np.unique(needed, axis=0))) if len(needed) else 0

    def flags(pair: str):
        near, angle = (float(x) for x in pair.split(":"))
        return near, angle, depth <= near, least_cos < np.cos(np.radians(angle))

    fields = {"format 2.1 lattice (chamfer in value bricks)": (base, 0, 0)}
    fields["exact 8-lattice"] = (variant(exact8_values), 0, 0)
    discs = [float(x) for x in args.feet_disc.split(",") if x]
    disc_normals = direction  # towards each lattice point from its foot
    if args.feet_pseudonormal:
        # The surface's own normal at each foot (libigl's pseudonormal: a face's, or the angle-weighted normal of the
        # faces around an edge or a vertex), not the direction to the lattice point.
        disc_normals = igl.signed_distance(P, V, F, sign_type=igl.SIGNED_DISTANCE_TYPE_PSEUDONORMAL)[3]
        disc_normals = disc_normals / np.maximum(np.linalg.norm(disc_normals, axis=1, keepdims=True), 1e-12)
    if args.feet_curvature > 0 and any(discs):
        # Each foot's disc no wider than keeps a sphere of the surface's radius of curvature there (libigl's
        # principal curvatures, the larger, at its triangle's vertices) within the tolerance of the disc.
        _, _, k1, k2, _ = igl.principal_curvature(V.astype(np.float64), F)
        kappa = np.maximum(np.abs(k1), np.abs(k2))[F[foot_triangle]].max(1) * h  # per voxel
        sized = np.sqrt(2 * args.feet_curvature / np.maximum(kappa, 1e-9))
        if args.feet_edges_plain:
            # A foot on an edge or a vertex has no tangent plane of its own (its direction is any in the normal
            # cone): no disc there.
            triangle = [V[F[foot_triangle, c]].astype(np.float64) for c in range(3)]
            bary = igl.barycentric_coordinates(nearest.astype(np.float64), *triangle)
            sized = np.where(np.asarray(bary).min(1) > 1e-6, sized, 0.0)
            print(f"coarse_refinement: {100 * float((sized == 0).mean()):.1f} % of the feet on an edge or a vertex")
        sized = sized.reshape(*LD)
    checked = {}
    if args.feet_checked is not None:
        side = np.sign(igl.signed_distance(P, V, F, sign_type=igl.SIGNED_DISTANCE_TYPE_PSEUDONORMAL)[0])
        if args.feet_checked_by == "asset":  # the asset's own band: what a producer or a reader has
            def signed_distance(points):
                return body.signed_distance(points.astype(np.float64))
        else:
            def signed_distance(points):
                return igl.signed_distance(points, V, F, sign_type=igl.SIGNED_DISTANCE_TYPE_PSEUDONORMAL)[0]
        for disc in [r for r in discs if r > 0]:
            checked[disc] = checked_disc_radii(signed_distance, nearest, disc_normals.reshape(-1, 3), side, disc, h,
                                               args.feet_checked).reshape(*LD)
            widths = checked[disc]
            print(f"coarse_refinement: discs of {disc:g} checked: " + ", ".join(
                f"{100 * float((widths == w).mean()):.1f} % {w:g}" for w in np.unique(widths)[::-1]), flush=True)
    for penalty, disc in [(float(x), r) for x in args.feet.split(",") if x for r in discs]:
        radius = np.minimum(sized, disc) if args.feet_curvature > 0 and disc > 0 else disc
        if disc in checked:
            radius = checked[disc]
        values = feet_values(coarse, table, (nearest - origin) / h, disc_normals, LD, top, penalty, radius)
        name = "8 corners" if penalty == 0 else f"4^3 points around, penalty {penalty:g}"
        if disc > 0:
            name += f", discs of {disc:g} voxels"
            if args.feet_curvature > 0:
                name += f" at most, each within {args.feet_curvature:g} voxel of its sphere of curvature"
                name += " (none on an edge or a vertex)" if args.feet_edges_plain else ""
            name += ", planes by pseudonormals" if args.feet_pseudonormal else ""
            name += (f", each checked behind the surface within {args.feet_checked:g} voxel by the "
                     f"{args.feet_checked_by}'s distances") if disc in checked else ""
        fields[f"feet: least distance to the nearest surface points of the {name}"] = (variant(values), 0, 0)
        # Deep, where the feet are near the exact distance and the interpolation cuts ridges, the feet; near the
        # surface, where the corners' feet lie far to the side, the interpolation; blended between the depths.
        for blend in [b for b in args.feet_blend.split(",") if b]:
            near, far = (float(x) for x in blend.split(":"))
            w = np.clip((np.abs(exact8_values) - near) / (far - near), 0, 1)
            fields[f"the interpolation up to {near:g} voxels deep, the feet of the {name} beyond {far:g}, blended"] = (
                variant(exact8_values + w * (values - exact8_values)), 0, 0)
    if args.no_refined:
        args.flags, args.ridge = "", ""
    else:
        fields["4-lattice everywhere"] = (variant(fine_values), len(coarse), added_values(points4))
    for pair in [p for p in args.flags.split(",") if p]:
        near, angle, close, ridge = flags(pair)
        flag = close | ridge
        fields[f"4-lattice where a corner is within {near:g} voxels or directions differ by > {angle:g} deg"] = (
            variant(np.where(flag[:, None], fine_values, exact8_values)), int(flag.sum()), added_values(points4[flag]))
    if args.ridge:
        near, angle, close, ridge = flags(args.ridge)
        m5 = np.stack(np.meshgrid(*[np.arange(5)] * 3, indexing="ij"), -1).reshape(-1, 3)
        points2 = np.minimum(coarse[ridge][:, None, :] * 8 + 2 * m5[None], top)  # [ridge bricks, 125, 3]
        fine2 = (exact_distance(igl, origin + h * points2.reshape(-1, 3), V, F) / h).reshape(len(points2), 125)
        values = np.where((close | ridge)[:, None], fine_values, exact8_values)
        ridge_values = fine2 @ trilinear_weights(5).T
        four = values[ridge]
        values[ridge] = ridge_values
        fields[f"2-lattice where directions differ by > {angle:g} deg, 4-lattice within {near:g} voxels"] = (
            variant(values), int((close | ridge).sum()), added_values(points4[close & ~ridge], points2))
        # A producer that computed the 2-lattice keeps it only where the 4-lattice's interpolation misses it.
        off = np.abs(ridge_values - four).max(1) > args.ridge_tolerance
        values[np.flatnonzero(ridge)[~off]] = four[~off]
        on_four = close | ridge
        on_four[np.flatnonzero(ridge)[off]] = False
        fields[f"the same, 2-lattice only where the 4-lattice is > {args.ridge_tolerance:g} voxel off "
               f"({int(off.sum())} of {len(off)} ridge bricks)"] = (
            variant(values), int((close | ridge).sum()), added_values(points4[on_four], points2[off]))

    ijk, _ = deep_voxels(body, origin, h, dims, band, args.samples)
    reference = exact_distance(igl, origin + h * ijk, V, F) / h
    file_bytes = os.path.getsize(args.asset)
    result = {"asset": args.asset, "mesh": args.mesh, "band": band, "coarse_bricks": int(len(coarse)),
              "value_bricks": int((table >= 0).sum()), "file_bytes": file_bytes, "variants": {}}
    print("| coarse bricks | refined bricks | values added (float32) | max slope | p99 | lines > 1.2 | "
          "inside: max error, beyond 1 voxel + 1 % | outside: the same |")
    print("|---|---|---|---|---|---|---|---|")
    for name, (f, refined, values) in fields.items():
        figured, cells = variant_figures(f, body, origin, h, ijk, reference)
        result["variants"][name] = {"refined_bricks": refined, "added_values": values, **figured}
        added = 4 * values
        print(f"| {name} | {refined} | {added / 1e6:.2f} MB ({100 * added / file_bytes:.1f} % of the file) | {cells}",
              flush=True)
    write_json(args.json, result)
    return 0


if __name__ == "__main__":
    sys.exit(main())
