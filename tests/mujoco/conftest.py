"""Fixtures of the MuJoCo plugin's tests: a sphere (an icosphere made here) and CGAL's bunny, baked once per
session, and a helper that runs MuJoCo for a while."""

from __future__ import annotations

import math
import os
import sys
from pathlib import Path

import numpy as np
import pytest

import voxfmt
import voxfmt.mujoco as vm

REPO = Path(os.environ.get("VOXFMT_REPO", Path(__file__).resolve().parents[2]))
MESHES = Path(os.environ.get("VOXFMT_SAMPLE_MESHES", REPO / "build/cgal-data/data/meshes"))
sys.path.insert(0, str(REPO / "examples" / "mujoco"))

SPHERE_RADIUS = 0.1
SPHERE_VOXEL = 0.005
BUNNY_RESOLUTION = 58  # voxels across: the leaf size of MuJoCo's default octree (depth 6) on the 1 m bunny
UPRIGHT = (math.sqrt(0.5), math.sqrt(0.5), 0.0, 0.0)  # the bunny mesh is +Y up


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


@pytest.fixture(scope="session", autouse=True)
def plugin() -> str:
    return vm.load_plugin()


@pytest.fixture(scope="session")
def sphere_asset(tmp_path_factory: pytest.TempPathFactory) -> Path:
    import shapes

    folder = tmp_path_factory.mktemp("sphere")
    v, f = icosphere(5)
    shapes.write_off(folder / "sphere.off", v * SPHERE_RADIUS, f)
    voxfmt.bake(folder / "sphere.off", folder / "sphere.vox.h5", voxel_size=SPHERE_VOXEL, points=2000)
    return folder / "sphere.vox.h5"


@pytest.fixture(scope="session")
def bunny_asset(tmp_path_factory: pytest.TempPathFactory) -> Path:
    mesh = MESHES / "bunny00.off"
    if not mesh.exists():
        pytest.skip(f"{mesh}: CGAL's sample meshes are not unpacked")
    out = tmp_path_factory.mktemp("bunny") / "bunny.vox.h5"
    voxfmt.bake(mesh, out, resolution=BUNNY_RESOLUTION, points=5000)
    return out


def speed(model, data, body: int) -> float:  # type: ignore[no-untyped-def]
    """The linear speed of the body's centre of mass (metres per second)."""
    import mujoco

    velocity = np.zeros(6)
    mujoco.mj_objectVelocity(model, data, mujoco.mjtObj.mjOBJ_BODY, body, velocity, 0)  # at the centre of mass
    return float(np.linalg.norm(velocity[3:]))
