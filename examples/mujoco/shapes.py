"""Closed triangle meshes for the MuJoCo examples and the benchmarks (bench/mujoco_compare.py, newton_scenes.py,
force_quality.py): a chamfered peg and a block with a chamfered blind hole, and a torus (metres, z up, watertight,
outward-facing), written as OFF and OBJ, plus readers.

The hole's radius is the peg's plus the radial clearance, so the same peg fits holes of any clearance.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass

import numpy as np

SEGMENTS = 256  # around each circle: the chord is within 0.4 um of a 5 mm circle


@dataclass(frozen=True)
class PegInHole:
    """Dimensions in metres. The block spans [-block/2, block/2]^2 x [0, block_height]; its hole is centred on
    the z axis, ``hole_depth`` deep from the top, with a 45 degree chamfer of ``hole_chamfer`` at the mouth. The
    peg spans z in [0, peg_length] with a 45 degree chamfer of ``peg_chamfer`` at its bottom edge."""

    peg_radius: float = 0.005
    peg_length: float = 0.03
    peg_chamfer: float = 0.0005
    clearance: float = 0.0005  # radial
    block: float = 0.03
    block_height: float = 0.025
    hole_depth: float = 0.02
    hole_chamfer: float = 0.001

    @property
    def hole_radius(self) -> float:
        return self.peg_radius + self.clearance


def peg_mesh(s: PegInHole) -> tuple[np.ndarray, np.ndarray]:
    """Vertices (N, 3) and triangles (M, 3) of the peg."""
    r, c, length = s.peg_radius, s.peg_chamfer, s.peg_length
    # Rings from the bottom up; the bottom and top faces are fans around a centre vertex.
    return _revolve([(r - c, 0.0), (r, c), (r, length)], bottom_cap=True, top_cap=True)


def hole_block_mesh(s: PegInHole) -> tuple[np.ndarray, np.ndarray]:
    """Vertices and triangles of the block with its hole."""
    n, half, top = SEGMENTS, s.block / 2, s.block_height
    angles = 2 * math.pi * np.arange(n) / n
    cos, sin = np.cos(angles), np.sin(angles)
    # The square's boundary at the circle's angles (n is a multiple of 8, so the corners are among them).
    reach = half / np.maximum(np.abs(cos), np.abs(sin))
    square = np.stack([reach * cos, reach * sin], axis=1)
    mouth = s.hole_radius + s.hole_chamfer
    rings = [  # (radius, z) from the mouth down into the hole
        (mouth, top),
        (s.hole_radius, top - s.hole_chamfer),
        (s.hole_radius, top - s.hole_depth),
    ]
    vertices = [np.column_stack([square, np.full(n, top)]), np.column_stack([square, np.zeros(n)])]
    for radius, z in rings:
        vertices.append(np.column_stack([radius * cos, radius * sin, np.full(n, z)]))
    vertices.append(np.array([[0.0, 0.0, top - s.hole_depth], [0.0, 0.0, 0.0]]))
    v = np.concatenate(vertices)
    top_square, bottom_square, hole_rings = 0, n, [2 * n, 3 * n, 4 * n]
    hole_centre, bottom_centre = 5 * n, 5 * n + 1
    i = np.arange(n)
    j = (i + 1) % n
    faces = []
    # Top face: the annulus between the square and the mouth, facing up.
    faces += _band(top_square, hole_rings[0], i, j)
    # The chamfer and the hole's wall, facing the hole's axis.
    faces += _band(hole_rings[0], hole_rings[1], i, j)
    faces += _band(hole_rings[1], hole_rings[2], i, j)
    # The hole's bottom, facing up.
    faces += [np.column_stack([hole_rings[2] + i, hole_rings[2] + j, np.full(n, hole_centre)])]
    # The sides, facing out, and the bottom, facing down.
    faces += _band(bottom_square, top_square, i, j)
    faces += [np.column_stack([bottom_square + j, bottom_square + i, np.full(n, bottom_centre)])]
    return v, np.concatenate(faces)


def _band(lower: int, upper: int, i: np.ndarray, j: np.ndarray) -> list[np.ndarray]:
    # The quads between two rings of n vertices (counter-clockwise seen from above), split in two triangles;
    # oriented so that, walking from `lower` to `upper`, the outside is on the right.
    return [
        np.column_stack([lower + i, lower + j, upper + j]),
        np.column_stack([lower + i, upper + j, upper + i]),
    ]


def _revolve(profile: list[tuple[float, float]], bottom_cap: bool, top_cap: bool) -> tuple[np.ndarray, np.ndarray]:
    n = SEGMENTS
    angles = 2 * math.pi * np.arange(n) / n
    cos, sin = np.cos(angles), np.sin(angles)
    v = [np.column_stack([r * cos, r * sin, np.full(n, z)]) for r, z in profile]
    v.append(np.array([[0.0, 0.0, profile[0][1]], [0.0, 0.0, profile[-1][1]]]))
    vertices = np.concatenate(v)
    bottom_centre, top_centre = len(profile) * n, len(profile) * n + 1
    i = np.arange(n)
    j = (i + 1) % n
    faces = []
    for k in range(len(profile) - 1):
        faces += _band(k * n, (k + 1) * n, i, j)
    last = (len(profile) - 1) * n
    if bottom_cap:
        faces.append(np.column_stack([j, i, np.full(n, bottom_centre)]))
    if top_cap:
        faces.append(np.column_stack([last + i, last + j, np.full(n, top_centre)]))
    return vertices, np.concatenate(faces)


def torus_mesh(R: float, r: float, major: int, minor: int) -> tuple[np.ndarray, np.ndarray]:
    """A closed torus around the z axis (major radius R, tube radius r), `major` x `minor` vertices on it."""
    u = 2 * math.pi * np.arange(major) / major
    v = 2 * math.pi * np.arange(minor) / minor
    uu, vv = np.meshgrid(u, v, indexing="ij")
    vertices = np.stack([(R + r * np.cos(vv)) * np.cos(uu), (R + r * np.cos(vv)) * np.sin(uu), r * np.sin(vv)], -1)
    i, j = np.meshgrid(np.arange(major), np.arange(minor), indexing="ij")
    a = i * minor + j
    b = ((i + 1) % major) * minor + j
    c = ((i + 1) % major) * minor + (j + 1) % minor
    d = i * minor + (j + 1) % minor
    triangles = np.concatenate([np.stack([a, b, c], -1).reshape(-1, 3), np.stack([a, c, d], -1).reshape(-1, 3)])
    return vertices.reshape(-1, 3), triangles


def write_off(path: str | os.PathLike[str], vertices: np.ndarray, faces: np.ndarray) -> None:
    with open(path, "w") as f:
        f.write(f"OFF\n{len(vertices)} {len(faces)} 0\n")
        np.savetxt(f, vertices, fmt="%.9g")
        np.savetxt(f, np.column_stack([np.full(len(faces), 3), faces]), fmt="%d")


def write_obj(path: str | os.PathLike[str], vertices: np.ndarray, faces: np.ndarray) -> None:
    with open(path, "w") as f:
        np.savetxt(f, vertices, fmt="v %.9g %.9g %.9g")
        np.savetxt(f, faces + 1, fmt="f %d %d %d")


def read_off(path: str | os.PathLike[str]) -> tuple[np.ndarray, np.ndarray]:
    """A triangle OFF file (as CGAL's sample meshes): vertices (N, 3) and triangles (M, 3)."""
    tokens = open(path).read().split()
    if tokens[0] != "OFF":
        raise ValueError(f"{path}: not an OFF file")
    nv, nf = int(tokens[1]), int(tokens[2])
    vertices = np.array(tokens[4 : 4 + 3 * nv], dtype=float).reshape(nv, 3)
    faces = np.array(tokens[4 + 3 * nv : 4 + 3 * nv + 4 * nf], dtype=np.int64).reshape(nf, 4)
    if not (faces[:, 0] == 3).all():
        raise ValueError(f"{path}: only triangles are supported")
    return vertices, faces[:, 1:]


def _profile_distance(q: np.ndarray, polygon: np.ndarray, boundary: np.ndarray) -> np.ndarray:
    """Signed distance (negative inside) of points q (N, 2) in the (r, z) half-plane to a solid of revolution
    whose profile is the closed `polygon` (M, 2); `boundary` (M,) says which edges (i -> i+1) are surface (the
    edge on the axis is not)."""
    a = polygon
    b = np.roll(polygon, -1, axis=0)
    best = np.full(len(q), np.inf)
    for i in np.flatnonzero(boundary):
        e = b[i] - a[i]
        t = np.clip(((q - a[i]) @ e) / (e @ e), 0.0, 1.0)
        best = np.minimum(best, np.linalg.norm(q - (a[i] + t[:, None] * e), axis=1))
    # Inside by the crossing number of a ray towards +r.
    inside = np.zeros(len(q), dtype=bool)
    for i in range(len(a)):
        (r0, z0), (r1, z1) = a[i], b[i]
        crosses = (z0 > q[:, 1]) != (z1 > q[:, 1])
        with np.errstate(divide="ignore", invalid="ignore"):
            r_at = r0 + (q[:, 1] - z0) * (r1 - r0) / (z1 - z0)
        inside ^= crosses & (q[:, 0] < r_at)
    return np.where(inside, -best, best)


def _to_profile(points: np.ndarray) -> np.ndarray:
    return np.column_stack([np.hypot(points[:, 0], points[:, 1]), points[:, 2]])


def peg_distance(points: np.ndarray, s: PegInHole) -> np.ndarray:
    """Exact signed distance (metres, negative inside) to the peg of `s` (its own frame), for penetrations
    measured against the shape the meshes approximate (their 256-gons are within 0.4 um of it)."""
    r, c, length = s.peg_radius, s.peg_chamfer, s.peg_length
    profile = np.array([(0.0, 0.0), (r - c, 0.0), (r, c), (r, length), (0.0, length)])
    return _profile_distance(_to_profile(points), profile, np.array([True, True, True, True, False]))


def hole_block_distance(points: np.ndarray, s: PegInHole) -> np.ndarray:
    """Exact signed distance where negative (inside the block; an upper bound outside it) to the block of `s`:
    the box less the hole, max(box, -hole)."""
    half = np.array([s.block / 2, s.block / 2, s.block_height / 2])
    q = np.abs(points - np.array([0.0, 0.0, s.block_height / 2])) - half
    box = np.linalg.norm(np.maximum(q, 0), axis=1) + np.minimum(q.max(axis=1), 0)
    top, rh, ch, up = s.block_height, s.hole_radius, s.hole_chamfer, s.block
    # The hole as a solid: its bottom, wall, chamfer, the chamfer's cone continued above the top, closed.
    profile = np.array([(0.0, top - s.hole_depth), (rh, top - s.hole_depth), (rh, top - ch), (rh + ch, top),
                        (rh + ch + up, top + up), (0.0, top + up)])
    hole = _profile_distance(_to_profile(points), profile, np.array([True, True, True, True, True, False]))
    return np.maximum(box, -hole)
