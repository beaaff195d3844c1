"""Shared fixtures: a sphere mesh made here (an icosphere written as OFF) and its baked asset."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import numpy.typing as npt
import pytest

import voxfmt

RADIUS = 0.05  # metres
RESOLUTION = 48
POINTS = 3000


def icosphere(subdivisions: int) -> tuple[np.ndarray, np.ndarray]:
    """Vertices (unit sphere) and outward-wound triangles of a subdivided icosahedron."""
    t = (1 + math.sqrt(5)) / 2
    verts = [(-1, t, 0), (1, t, 0), (-1, -t, 0), (1, -t, 0), (0, -1, t), (0, 1, t),
             (0, -1, -t), (0, 1, -t), (t, 0, -1), (t, 0, 1), (-t, 0, -1), (-t, 0, 1)]
    faces = [(0, 11, 5), (0, 5, 1), (0, 1, 7), (0, 7, 10), (0, 10, 11), (1, 5, 9), (5, 11, 4), (11, 10, 2),
             (10, 7, 6), (7, 1, 8), (3, 9, 4), (3, 4, 2), (3, 2, 6), (3, 6, 8), (3, 8, 9), (4, 9, 5), (2, 4, 11),
             (6, 2, 10), (8, 6, 7), (9, 8, 1)]
    v = [np.array(p, float) / np.linalg.norm(p) for p in verts]
    for _ in range(subdivisions):
        midpoint: dict[tuple[int, int], int] = {}

        def mid(i: int, j: int) -> int:
            key = (min(i, j), max(i, j))
            if key not in midpoint:
                m = v[i] + v[j]
                v.append(m / np.linalg.norm(m))
                midpoint[key] = len(v) - 1
            return midpoint[key]

        new_faces = []
        for a, b, c in faces:
            ab, bc, ca = mid(a, b), mid(b, c), mid(c, a)
            new_faces += [(a, ab, ca), (b, bc, ab), (c, ca, bc), (ab, bc, ca)]
        faces = new_faces
    return np.array(v), np.array(faces)


def write_off(path: Path, vertices: np.ndarray, faces: np.ndarray) -> None:
    lines = ["OFF", f"{len(vertices)} {len(faces)} 0"]
    lines += [f"{x:.12g} {y:.12g} {z:.12g}" for x, y, z in vertices]
    lines += [f"3 {a} {b} {c}" for a, b, c in faces]
    path.write_text("\n".join(lines) + "\n")


@pytest.fixture(scope="session")
def sphere_mesh(tmp_path_factory: pytest.TempPathFactory) -> Path:
    v, f = icosphere(4)
    path = tmp_path_factory.mktemp("mesh") / "sphere.off"
    write_off(path, v * RADIUS, f)
    return path


@pytest.fixture(scope="session")
def sphere_asset(sphere_mesh: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("asset") / "sphere.vox.h5"
    voxfmt.bake(sphere_mesh, out, resolution=RESOLUTION, points=POINTS, threads=1)
    return out


@pytest.fixture(scope="session")
def sphere(sphere_asset: Path) -> voxfmt.Body:
    return voxfmt.load(sphere_asset)


def translation(x: float = 0.0, y: float = 0.0, z: float = 0.0) -> np.ndarray:
    pose = np.eye(4)
    pose[:3, 3] = (x, y, z)
    return pose


def rotation(axis: npt.ArrayLike, angle: float) -> np.ndarray:
    """4x4 rotation about a unit axis (Rodrigues)."""
    k = np.asarray(axis, float) / np.linalg.norm(axis)
    kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    pose = np.eye(4)
    pose[:3, :3] = np.eye(3) + math.sin(angle) * kx + (1 - math.cos(angle)) * kx @ kx
    return pose
