#!/usr/bin/env python3
"""MuJoCo's own mesh collisions against the voxfmt SDF plugin, on the same scenes, initial states and time step,
in one process and one run.

    PYTHONPATH=build/python .venv/bin/python bench/mujoco_compare.py --json F.json --markdown F.md [--quick]

Methods (every one sees the same model but for the colliding geoms):
  hull        <geom type="mesh">: MuJoCo collides meshes through their convex hulls
  native-sdf  <geom type="sdf" mesh=...> without a plugin: MuJoCo's octree SDF of the mesh, built at compile
              time (octree depth --depth, MuJoCo's default 6)
  voxfmt      <geom type="sdf"> with the plugin voxfmt.sdf.asset on the baked asset, at the matching voxel size:
              an octree of depth D has leaves of 1.1 x extent / 2^D, so the bunny is baked at 2^D / 1.1 voxels
              across and the peg and block at the block's leaf size
Both SDF methods run MuJoCo's own SDF collision (mjc_SDF) at the same sdf_initpoints / sdf_iterations (--sdf,
default: MuJoCo's 40/10 and the cheaper 10/5).

Scenes (z up, 1 ms steps, MuJoCo's default solver and contact parameters):
  bunny-on-box    CGAL's bunny00.off (1 m, 75,408 faces) upright, dropped from 0.2 m onto a 2 x 2 x 0.2 m box (3 s);
                  and (--rest-trials) 5 more drops turned about the vertical, for the rest
  bunny-on-bunny  a bunny dropped half-overlapping (0.25 m off-centre) onto a static one standing on the floor,
                  inside four walls (without them it tumbles off with every method)
  peg-0.5mm       a chamfered steel peg (radius 5 mm, 30 mm long) released 2 mm above a static block's
  peg-0.2mm       chamfered blind hole (20 mm deep) with 0.5 / 0.2 mm radial clearance, 0.3 mm off its axis;
                  friction 0.3 (the peg slides on the chamfers)

Figures per run: model compile time (for voxfmt plus the bake, done once offline, reported apart), model and
field memory, wall time of mj_step p50/p99 over the steps after first contact, the largest penetration of the
exact meshes (their vertices against the other body's exact mesh, or the peg's and block's exact shapes,
every step for boxes, every 10th step between meshes), the time at which the dropped body comes to rest for good (speed of its fastest point below
1 mm/s from then on), the peg's inserted depth; for voxfmt also the lookups per step and their time replayed
without MuJoCo (the rest of the step is MuJoCo's own search and solver).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import re
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "examples" / "mujoco"))
import shapes  # noqa: E402  (examples/mujoco/shapes.py: the peg and the block)

TIMESTEP = 0.001
REST_SPEED = 1e-3  # m/s: the fastest point of the body
SOLREF = os.environ.get("SOLREF", "0.02 1")
UPRIGHT = (math.sqrt(0.5), math.sqrt(0.5), 0.0, 0.0)  # the bunny mesh is +Y up: a quarter turn about x


# ------------------------------------------------------------------------------------------- exact meshes


def quat_to_matrix(q: np.ndarray) -> np.ndarray:
    w, x, y, z = q / np.linalg.norm(q)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


class ExactMesh:
    """Signed distance to a closed triangle mesh near its surface: the nearest triangle within `reach` (a grid
    of buckets finds the candidates), signed by the angle-weighted pseudonormal of the nearest feature (face,
    edge or vertex), which is exact for a closed, consistently oriented mesh."""

    def __init__(self, vertices: np.ndarray, faces: np.ndarray, reach: float) -> None:
        self.v = np.asarray(vertices, dtype=float)
        self.f = np.asarray(faces, dtype=np.int64)
        self.reach = reach
        a, b, c = (self.v[self.f[:, k]] for k in range(3))
        n = np.cross(b - a, c - a)
        self.face_normal = n / np.linalg.norm(n, axis=1, keepdims=True)
        # Vertex pseudonormals: face normals weighted by the face's angle at the vertex.
        vn = np.zeros_like(self.v)
        for k in range(3):
            p, q, r = (self.v[self.f[:, (k + j) % 3]] for j in range(3))
            e1, e2 = q - p, r - p
            cos = np.einsum("ij,ij->i", e1, e2) / (np.linalg.norm(e1, axis=1) * np.linalg.norm(e2, axis=1))
            np.add.at(vn, self.f[:, k], self.face_normal * np.arccos(np.clip(cos, -1, 1))[:, None])
        self.vertex_normal = vn / np.linalg.norm(vn, axis=1, keepdims=True)
        # Edge pseudonormals: the sum of the two faces' normals, keyed by the sorted vertex pair.
        edges = np.concatenate([self.f[:, [0, 1]], self.f[:, [1, 2]], self.f[:, [2, 0]]])
        key = np.sort(edges, axis=1)
        key = key[:, 0] * len(self.v) + key[:, 1]
        order = np.argsort(key, kind="stable")
        self.edge_keys = key[order]
        sums = np.tile(self.face_normal, (3, 1))[order]
        starts = np.flatnonzero(np.r_[True, self.edge_keys[1:] != self.edge_keys[:-1]])
        self.edge_keys = self.edge_keys[starts]
        self.edge_normal = np.add.reduceat(sums, starts)
        # Buckets: a triangle is in every cell its box grown by `reach` touches, so a point's own cell holds
        # every triangle within `reach` of it.
        self.cell = max(reach, 2 * float(np.median(np.linalg.norm(b - a, axis=1))))
        lo = np.minimum(np.minimum(a, b), c) - reach
        hi = np.maximum(np.maximum(a, b), c) + reach
        self.origin = lo.min(axis=0)
        ilo = np.floor((lo - self.origin) / self.cell).astype(np.int64)
        ihi = np.floor((hi - self.origin) / self.cell).astype(np.int64)
        self.dims = ihi.max(axis=0) + 1
        cells, tris = [], []
        span = ihi - ilo + 1
        for dx in range(int(span[:, 0].max())):
            for dy in range(int(span[:, 1].max())):
                for dz in range(int(span[:, 2].max())):
                    keep = (dx < span[:, 0]) & (dy < span[:, 1]) & (dz < span[:, 2])
                    idx = ilo[keep] + np.array([dx, dy, dz])
                    cells.append(self._cell_id(idx))
                    tris.append(np.flatnonzero(keep))
        cells_all, tris_all = np.concatenate(cells), np.concatenate(tris)
        order = np.argsort(cells_all, kind="stable")
        self.bucket_cells, self.bucket_start = np.unique(cells_all[order], return_index=True)
        self.bucket_tris = tris_all[order]
        self.bucket_end = np.r_[self.bucket_start[1:], len(order)]

    def _cell_id(self, idx: np.ndarray) -> np.ndarray:
        return (idx[:, 0] * self.dims[1] + idx[:, 1]) * self.dims[2] + idx[:, 2]

    def signed_distance(self, points: np.ndarray) -> np.ndarray:
        """Signed distance (negative inside) of points in the mesh's frame; +inf beyond `reach`."""
        out = np.full(len(points), np.inf)
        idx = np.floor((points - self.origin) / self.cell).astype(np.int64)
        inside_grid = np.all((idx >= 0) & (idx < self.dims), axis=1)
        cand = np.flatnonzero(inside_grid)
        if len(cand) == 0:
            return out
        slot = np.searchsorted(self.bucket_cells, self._cell_id(idx[cand]))
        slot = np.minimum(slot, len(self.bucket_cells) - 1)
        found = self.bucket_cells[slot] == self._cell_id(idx[cand])
        cand, slot = cand[found], slot[found]
        counts = self.bucket_end[slot] - self.bucket_start[slot]
        if counts.sum() == 0:
            return out
        point_of_pair = np.repeat(cand, counts)
        offsets = np.repeat(self.bucket_start[slot] - np.r_[0, np.cumsum(counts)[:-1]], counts)
        tri = self.bucket_tris[np.arange(counts.sum()) + offsets]
        d2, normal = self._closest(points[point_of_pair], tri)
        # The nearest pair of each point.
        order = np.lexsort((d2, point_of_pair))
        first = np.r_[True, point_of_pair[order][1:] != point_of_pair[order][:-1]]
        best = order[first]
        p = points[point_of_pair[best]]
        dist = np.sqrt(d2[best])
        closest_to_p = p - self._closest_points[best]
        sign = np.where(np.einsum("ij,ij->i", closest_to_p, normal[best]) < 0, -1.0, 1.0)
        result = np.where(dist <= self.reach, sign * dist, np.inf)
        out[point_of_pair[best]] = result
        return out

    def _closest(self, p: np.ndarray, tri: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        # Closest point of each triangle to each point and the pseudonormal of the feature it lies on: the
        # projection onto the plane if it falls inside, else the nearest of the three edges (a vertex where the
        # edge's parameter clamps).
        f = self.f[tri]
        corners = [self.v[f[:, k]] for k in range(3)]
        n = len(p)
        dot = lambda x, y: np.einsum("ij,ij->i", x, y)  # noqa: E731
        normal_f = self.face_normal[tri]
        projected = p - dot(p - corners[0], normal_f)[:, None] * normal_f
        inside = np.ones(n, dtype=bool)
        for k in range(3):
            e = corners[(k + 1) % 3] - corners[k]
            inside &= dot(np.cross(e, projected - corners[k]), normal_f) >= 0
        best = np.where(inside, dot(p - projected, p - projected), np.inf)
        closest = projected.copy()
        normal = normal_f.copy()
        for k in range(3):
            i, j = k, (k + 1) % 3
            a, b = corners[i], corners[j]
            e = b - a
            t = np.clip(dot(p - a, e) / np.maximum(dot(e, e), 1e-300), 0.0, 1.0)
            q = a + t[:, None] * e
            d2 = dot(p - q, p - q)
            better = d2 < best
            best = np.where(better, d2, best)
            closest[better] = q[better]
            key = np.sort(f[:, [i, j]], axis=1)
            slot = np.searchsorted(self.edge_keys, key[:, 0] * len(self.v) + key[:, 1])
            feature_normal = self.edge_normal[np.minimum(slot, len(self.edge_keys) - 1)]
            feature_normal = np.where((t <= 0)[:, None], self.vertex_normal[f[:, i]], feature_normal)
            feature_normal = np.where((t >= 1)[:, None], self.vertex_normal[f[:, j]], feature_normal)
            normal[better] = feature_normal[better]
        self._closest_points = closest
        return best, normal


class AnalyticShape:
    """The peg's or the block's exact signed distance (examples/mujoco/shapes.py: within 0.4 um of their meshes,
    exact inside, where penetrations are measured)."""

    def __init__(self, function: Any, spec: shapes.PegInHole) -> None:
        self.function, self.spec = function, spec

    def signed_distance(self, points: np.ndarray) -> np.ndarray:
        return self.function(points, self.spec)


def box_signed_distance(points: np.ndarray, half: np.ndarray) -> np.ndarray:
    q = np.abs(points) - half
    outside = np.linalg.norm(np.maximum(q, 0), axis=1)
    return outside + np.minimum(q.max(axis=1), 0)


# -------------------------------------------------------------------------------------------------- scenes


@dataclass
class Body:
    name: str
    mesh: str  # the mesh file (OBJ, for MuJoCo) and its asset
    asset: str
    pos: tuple[float, float, float]
    quat: tuple[float, float, float, float] = (1.0, 0.0, 0.0, 0.0)
    static: bool = False
    density: float = 1000.0


@dataclass
class Scene:
    name: str
    bodies: list[Body]
    boxes: list[tuple[str, tuple[float, float, float], tuple[float, float, float]]]  # name, half-size, centre
    seconds: float
    friction: float = 1.0
    # Pairs whose penetration is measured: (body, body or box name).
    pairs: list[tuple[str, str]] = field(default_factory=list)
    peg: shapes.PegInHole | None = None


@dataclass
class Assets:
    """Meshes (vertices, faces) by name, their OBJ files and their baked assets per resolution key."""

    folder: Path
    meshes: dict[str, tuple[np.ndarray, np.ndarray]] = field(default_factory=dict)
    exact: dict[str, ExactMesh | AnalyticShape] = field(default_factory=dict)
    prefilter: dict[str, str] = field(default_factory=dict)  # an asset of each mesh, to find candidate vertices
    prefilter_voxel: dict[str, float] = field(default_factory=dict)


def lowest_z(vertices: np.ndarray, quat: tuple[float, float, float, float]) -> float:
    return float((vertices @ quat_to_matrix(np.array(quat)).T)[:, 2].min())


def make_scenes(assets: Assets, names: list[str], quick: bool) -> list[Scene]:
    scenes = []
    bunny_v, _ = assets.meshes["bunny"]
    rest = -lowest_z(bunny_v, UPRIGHT)  # the upright bunny's origin height when it stands on z = 0
    top = float((bunny_v @ quat_to_matrix(np.array(UPRIGHT)).T)[:, 2].max()) + rest
    if "bunny-on-box" in names:
        scenes.append(
            Scene(
                "bunny-on-box",
                [Body("bunny", "bunny", "bunny", (0.0, 0.0, rest + 0.2), UPRIGHT)],
                [("table", (1.0, 1.0, 0.1), (0.0, 0.0, -0.1))],
                1.5 if quick else 3.0,
                pairs=[("bunny", "table")],
            )
        )
    if "bunny-on-bunny" in names:
        walls = [
            ("floor", (1.0, 1.0, 0.1), (0.0, 0.0, -0.1)),
            ("wall+x", (0.05, 0.8, 0.75), (0.8, 0.0, 0.75)),
            ("wall-x", (0.05, 0.8, 0.75), (-0.8, 0.0, 0.75)),
            ("wall+y", (0.8, 0.05, 0.75), (0.0, 0.65, 0.75)),
            ("wall-y", (0.8, 0.05, 0.75), (0.0, -0.65, 0.75)),
        ]
        scenes.append(
            Scene(
                "bunny-on-bunny",
                [
                    Body("base", "bunny", "bunny", (0.0, 0.0, rest), UPRIGHT, static=True),
                    Body("bunny", "bunny", "bunny", (0.25, 0.0, top + rest + 0.05), UPRIGHT),
                ],
                walls,
                1.5 if quick else 3.0,
                pairs=[("bunny", "base")] + [("bunny", w[0]) for w in walls],
            )
        )
    for clearance in (0.5, 0.2):
        name = f"peg-{clearance}mm"
        if name not in names:
            continue
        s = shapes.PegInHole(clearance=clearance * 1e-3)
        scenes.append(
            Scene(
                name,
                [
                    Body("block", f"block-{clearance}", f"block-{clearance}", (0.0, 0.0, 0.0), static=True),
                    Body("peg", "peg", "peg", (0.0003, 0.0, s.block_height + 0.002), density=7800.0),
                ],
                [("floor", (0.1, 0.1, 0.01), (0.0, 0.0, -0.01))],
                0.5 if quick else 1.0,
                friction=0.3,
                pairs=[("peg", "block")],
                peg=s,
            )
        )
    return scenes


# ------------------------------------------------------------------------------------------------- methods


def octree_leaf(extent: np.ndarray, depth: int) -> float:
    """The edge of MuJoCo's finest octree cells for a mesh of this extent: its box is 1.1 x the mesh's."""
    return float(1.1 * extent.max() / 2**depth)


def mjcf(scene: Scene, method: str, assets: Assets, resolution_key: str, sdf: tuple[int, int]) -> str:
    import voxfmt.mujoco as vm

    option = (
        f'<option timestep="{TIMESTEP}" sdf_initpoints="{sdf[0]}" sdf_iterations="{sdf[1]}"/>'
        f'<default><geom friction="{scene.friction}" solref="{SOLREF}"/></default>'
    )
    world = "".join(
        f'<geom name="{n}" type="box" size="{h[0]} {h[1]} {h[2]}" pos="{c[0]} {c[1]} {c[2]}"/>'
        for n, h, c in scene.boxes
    )
    doc = f"<mujoco>{option}<worldbody>{world}</worldbody></mujoco>"
    parts = []
    for b in scene.bodies:
        asset = str(assets.folder / f"{b.asset}-{resolution_key}.vox.h5")
        parts.append(
            vm.part(asset, b.name, pos=b.pos, quat=b.quat, density=b.density, static=b.static)
        )
    if method == "voxfmt":
        return vm.insert(doc, *parts)
    # The same bodies, inertials and poses; the geom is MuJoCo's mesh or its octree SDF of the mesh.
    gtype = "mesh" if method == "hull" else "sdf"
    meshes = sorted({b.mesh for b in scene.bodies})
    asset_xml = "".join(f'<mesh name="{m}" file="{assets.folder / (m + ".obj")}"/>' for m in meshes)
    bodies = ""
    for b, p in zip(scene.bodies, parts):
        inertial = re.search(r"<inertial[^>]*/>", p.body).group(0)  # type: ignore[union-attr]
        joint = "" if b.static else "<freejoint/>"
        q = " ".join(f"{x:.10g}" for x in b.quat)
        bodies += (
            f'<body name="{b.name}" pos="{b.pos[0]} {b.pos[1]} {b.pos[2]}" quat="{q}">{joint}{inertial}'
            f'<geom name="{b.name}" type="{gtype}" mesh="{b.mesh}"/></body>'
        )
    doc = doc.replace("<worldbody>", f"<asset>{asset_xml}</asset><worldbody>")
    return doc.replace("</worldbody>", bodies + "</worldbody>")


# --------------------------------------------------------------------------------------------------- runs


@dataclass
class Run:
    scene: str
    method: str
    resolution: str
    sdf: tuple[int, int]
    figures: dict[str, Any] = field(default_factory=dict)


def penetration(scene: Scene, model: Any, data: Any, assets: Assets) -> float:
    """The deepest vertex of each measured pair's exact mesh inside the other's (metres, 0 if none)."""
    import mujoco
    import voxfmt.mujoco as vm

    def pose(name: str) -> tuple[np.ndarray, np.ndarray]:
        i = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, name)
        return data.xpos[i].copy(), data.xmat[i].reshape(3, 3).copy()

    bodies = {b.name: b for b in scene.bodies}
    boxes = {n: (np.array(h), np.array(c)) for n, h, c in scene.boxes}
    deepest = 0.0
    for a, b in scene.pairs:
        pa, ra = pose(a)
        va = assets.meshes[bodies[a].mesh][0] @ ra.T + pa
        if b in boxes:
            half, centre = boxes[b]
            d = box_signed_distance(va - centre, half)
            deepest = max(deepest, float(-d.min()))
            continue
        pb, rb = pose(b)
        vb = assets.meshes[bodies[b].mesh][0] @ rb.T + pb
        # A's vertices in B's mesh frame and B's in A's. The vertices a coarse field (the bench's own asset of
        # the mesh: near the surface its stored distances, within a small fraction of a voxel of the truth) puts
        # within half a voxel of the other mesh are the only candidates; their distance is the exact mesh's.
        for verts, (p, r), other in ((va, (pb, rb), bodies[b].mesh), (vb, (pa, ra), bodies[a].mesh)):
            local = (verts - p) @ r
            exact = assets.exact[other]
            if isinstance(exact, AnalyticShape):
                deepest = max(deepest, float(-exact.signed_distance(local).min()))
                continue
            coarse = vm.evaluate(assets.prefilter[other], local)
            near = np.flatnonzero(coarse < 0.5 * assets.prefilter_voxel[other])
            if len(near):
                d = exact.signed_distance(local[near])
                d = np.where(np.isfinite(d), d, coarse[near])  # beyond the exact search's reach
                deepest = max(deepest, float(-d.min()))
    return deepest


COMPILE_CHILD = r"""
import json, sys, time
import mujoco
import voxfmt.mujoco as vm
vm.load_plugin()
xml, depth = open(sys.argv[1]).read(), int(sys.argv[2])
start = time.perf_counter()
spec = mujoco.MjSpec.from_string(xml)
for mesh in spec.meshes:
    mesh.octree_maxdepth = depth
model = spec.compile()
mujoco.MjData(model)
print(json.dumps({"compile_s": time.perf_counter() - start}))
"""


def compile_cold(xml: str, depth: int, folder: Path, repeats: int) -> float:
    """Seconds to compile the model and make its data in a fresh interpreter: nothing cached (MuJoCo's mesh
    cache, the plugin's loaded assets), as a user's first load. The best of `repeats`."""
    path = folder / "compile-me.xml"
    path.write_text(xml)
    best = math.inf
    for _ in range(repeats):
        child = subprocess.run([sys.executable, "-c", COMPILE_CHILD, str(path), str(depth)], capture_output=True,
                               text=True, timeout=600)
        if child.returncode != 0:
            raise RuntimeError(f"compiling in a child failed: {child.stderr[-2000:]}")
        best = min(best, json.loads(child.stdout.strip().splitlines()[-1])["compile_s"])
    return best


def simulate(scene: Scene, method: str, assets: Assets, depth: int, sdf: tuple[int, int],
             profile: bool, compile_repeats: int = 3) -> dict[str, Any]:
    import mujoco
    import voxfmt.mujoco as vm

    key = f"d{depth}"
    xml = mjcf(scene, method, assets, key, sdf)
    spec = mujoco.MjSpec.from_string(xml)
    for mesh in spec.meshes:
        mesh.octree_maxdepth = depth  # what native-sdf builds; the others build no octree
    model = spec.compile()
    data = mujoco.MjData(model)
    field_mb = 0.0
    if method == "voxfmt":
        for asset in sorted({b.asset for b in scene.bodies}):
            field_mb += vm.field_bytes(assets.folder / f"{asset}-{key}.vox.h5") / 1e6
    moving = [b for b in scene.bodies if not b.static][0]
    body = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, moving.name)
    verts = assets.meshes[moving.mesh][0]
    reach = float(np.linalg.norm(verts - model.body_ipos[body], axis=1).max())  # COM to the farthest vertex
    meshes_between = any(b not in {n for n, _, _ in scene.boxes} for _, b in scene.pairs)
    steps = int(round(scene.seconds / TIMESTEP))
    step_us = np.zeros(steps)
    com_speed = np.zeros(steps)
    point_speed = np.zeros(steps)
    touching = np.zeros(steps, dtype=bool)
    depth_at = np.full(steps, np.nan)
    velocity = np.zeros(6)
    if profile:
        vm.lookup_profile(True)
    for i in range(steps):
        t0 = time.perf_counter()
        mujoco.mj_step(model, data)
        step_us[i] = (time.perf_counter() - t0) * 1e6
        mujoco.mj_objectVelocity(model, data, mujoco.mjtObj.mjOBJ_BODY, body, velocity, 0)  # at the COM
        com_speed[i] = np.linalg.norm(velocity[3:])
        point_speed[i] = com_speed[i] + np.linalg.norm(velocity[:3]) * reach
        touching[i] = any(body in (model.geom_bodyid[c.geom1], model.geom_bodyid[c.geom2]) for c in data.contact)
        if not meshes_between or i % 10 == 0:
            depth_at[i] = penetration(scene, model, data, assets)
    profiled = vm.lookup_profile(False) if profile else None
    first = int(np.argmax(touching)) if touching.any() else steps
    # At rest from the first step after which the centre of mass stays below 1 mm/s to the end; a rest that
    # starts in the last half second is not one yet.
    moving_steps = np.flatnonzero(com_speed >= REST_SPEED)
    rest_step = int(moving_steps[-1]) + 1 if len(moving_steps) else 0
    rest = round(rest_step * TIMESTEP, 3) if rest_step <= steps - max(100, min(500, steps // 4)) else None
    after = step_us[first:] if first < steps else step_us
    last = slice(steps - max(100, min(500, steps // 4)), steps)  # "at the end": the last half second at most
    figures: dict[str, Any] = {
        "compile_s": round(compile_cold(xml, depth, assets.folder, compile_repeats), 4) if compile_repeats else None,
        "memory_mb": round(model.nbuffer / 1e6 + field_mb, 3),
        "step_us_p50": round(float(np.percentile(after, 50)), 2),
        "step_us_p99": round(float(np.percentile(after, 99)), 2),
        "max_penetration_mm": round(float(np.nanmax(depth_at)) * 1e3, 3),
        "rest_penetration_mm": round(float(np.nanmax(depth_at[last])) * 1e3, 3),
        "first_contact_s": round(first * TIMESTEP, 3) if first < steps else None,
        "rest_time_s": rest,
        "final_com_speed_mm_s": round(float(com_speed[last].max()) * 1e3, 3),
        "final_point_speed_mm_s": round(float(point_speed[last].max()) * 1e3, 3),
        "contacts_final": int(data.ncon),
        "model_mb": round(model.nbuffer / 1e6, 3),
        "field_mb": round(field_mb, 3),
        "mesh_faces": int(model.nmeshface),
        "octree_nodes": int(model.noct),
    }
    if scene.peg is not None:
        s = scene.peg
        inserted = s.block_height - float(data.xpos[body][2])  # the peg's origin is its bottom centre
        figures["outcome"] = {
            "inserted_mm": round(inserted * 1e3, 3),
            # At the hole's bottom: not short of it (jammed), not through it.
            "inserted": bool(abs(inserted - s.hole_depth) < 0.5e-3),
        }
    else:
        figures["outcome"] = {"inserted_mm": None, "inserted": None}
    if profiled:
        figures["sdf_collisions_per_step"] = round(profiled["collisions"] / steps, 3)
        figures["calls_per_step"] = round((profiled["distance_calls"] + profiled["gradient_calls"]) / steps, 1)
        figures["lookups_per_step"] = round(profiled["lookups"] / steps, 1)
        figures["lookup_us_per_step"] = round(profiled["lookup_ns"] / steps / 1e3, 2)
    return figures


REST_YAWS = (20.0, 45.0, 70.0, 110.0, 160.0)  # degrees about z: more drops of the bunny on the box


def rest_trials(method: str, assets: Assets, depth: int, sdf: tuple[int, int], seconds: float) -> dict[str, Any]:
    """The bunny dropped on the box again, turned about the vertical by each of REST_YAWS: one drop may rest or
    rock by chance (MuJoCo's SDF contacts come from a local search whose outcome jumps with the pose), so the
    rest is judged over several. A drop rests if its centre of mass stays below 1 mm/s over its last second."""
    import mujoco

    bunny_v, _ = assets.meshes["bunny"]
    speeds = []
    for yaw in REST_YAWS:
        half = math.radians(yaw) / 2
        turn, quat = np.array([math.cos(half), 0, 0, math.sin(half)]), np.zeros(4)
        mujoco.mju_mulQuat(quat, turn, np.array(UPRIGHT))
        q = tuple(float(x) for x in quat)
        scene = Scene("bunny-on-box", [Body("bunny", "bunny", "bunny", (0.0, 0.0, 0.2 - lowest_z(bunny_v, q)), q)],
                      [("table", (1.0, 1.0, 0.1), (0.0, 0.0, -0.1))], seconds)
        spec = mujoco.MjSpec.from_string(mjcf(scene, method, assets, f"d{depth}", sdf))
        for mesh in spec.meshes:
            mesh.octree_maxdepth = depth
        model = spec.compile()
        data = mujoco.MjData(model)
        velocity = np.zeros(6)
        steps = int(round(seconds / TIMESTEP))
        last = []
        for i in range(steps):
            mujoco.mj_step(model, data)
            if i >= steps - 1000:
                mujoco.mj_objectVelocity(model, data, mujoco.mjtObj.mjOBJ_BODY, 1, velocity, 0)
                last.append(float(np.linalg.norm(velocity[3:])))
        speeds.append(max(last))
    return {
        "rest_trials": len(speeds),
        "rest_trials_at_rest": int(sum(v < REST_SPEED for v in speeds)),
        "rest_trials_final_com_speed_mm_s": [round(v * 1e3, 3) for v in speeds],
    }


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--json", help="write the runs as JSON here")
    ap.add_argument("--markdown", help="write the table as Markdown here")
    ap.add_argument("--quick", action="store_true", help="short runs at MuJoCo's default settings only (CI)")
    ap.add_argument("--scenes", default="bunny-on-box,bunny-on-bunny,peg-0.5mm,peg-0.2mm")
    ap.add_argument("--methods", default="hull,native-sdf,voxfmt")
    ap.add_argument("--depth", default=None, help="octree depths, comma-separated (default 6,7; quick 6)")
    ap.add_argument("--sdf", default=None, help="initpoints/iterations pairs (default 40/10,10/5; quick 40/10)")
    ap.add_argument("--cache", default="out/mujoco-compare", help="meshes and baked assets (reused)")
    ap.add_argument("--bunny", default=str(ROOT / "build/cgal-data/data/meshes/bunny00.off"))
    ap.add_argument("--rest-trials", type=int, choices=(0, 1), default=None,
                    help="1: drop the bunny on the box at 5 more headings (default: 1, quick: 0)")
    args = ap.parse_args()
    import mujoco
    import voxfmt
    import voxfmt.mujoco as vm

    vm.load_plugin()
    if args.rest_trials is None:
        args.rest_trials = 0 if args.quick else 1
    depths = [int(d) for d in (args.depth or ("6" if args.quick else "6,7")).split(",")]
    sdfs = [tuple(int(x) for x in s.split("/")) for s in (args.sdf or ("40/10" if args.quick else "40/10,10/5")).split(",")]
    scene_names = args.scenes.split(",")
    methods = args.methods.split(",")
    for name in scene_names + methods:
        if name not in {"bunny-on-box", "bunny-on-bunny", "peg-0.5mm", "peg-0.2mm", "hull", "native-sdf", "voxfmt"}:
            print(f"mujoco_compare: unknown scene or method {name!r}", file=sys.stderr)
            return 2
    if not os.path.exists(args.bunny):
        print(f"mujoco_compare: {args.bunny}: no such mesh (CGAL's bunny00.off)", file=sys.stderr)
        return 2

    folder = Path(args.cache).resolve()
    folder.mkdir(parents=True, exist_ok=True)
    assets = Assets(folder)
    assets.meshes["bunny"] = shapes.read_off(args.bunny)
    assets.meshes["peg"] = shapes.peg_mesh(shapes.PegInHole())
    for c in (0.5, 0.2):
        assets.meshes[f"block-{c}"] = shapes.hole_block_mesh(shapes.PegInHole(clearance=c * 1e-3))
    for name, (v, f) in assets.meshes.items():
        shapes.write_obj(folder / f"{name}.obj", v, f)
        shapes.write_off(folder / f"{name}.off", v, f)
    # Bake times (the bake is done once, offline) are kept beside the cached assets.
    bakes_file = folder / "bakes.json"
    bake_s: dict[str, float] = json.loads(bakes_file.read_text()) if bakes_file.exists() else {}
    for name, (v, f) in assets.meshes.items():
        if name == "bunny":
            assets.exact[name] = ExactMesh(v, f, reach=0.02)  # deeper than any penetration seen
        elif name == "peg":
            assets.exact[name] = AnalyticShape(shapes.peg_distance, shapes.PegInHole())
        else:
            clearance = float(name.split("-")[1]) * 1e-3
            assets.exact[name] = AnalyticShape(shapes.hole_block_distance, shapes.PegInHole(clearance=clearance))
        for depth in depths:
            # The peg and the block share one voxel size: the block's leaf.
            reference = assets.meshes["block-0.5"][0] if name != "bunny" else v
            ref_extent = reference.max(axis=0) - reference.min(axis=0)
            voxel = octree_leaf(ref_extent, depth)
            out = folder / f"{name}-d{depth}.vox.h5"
            if not out.exists() or f"{name}-d{depth}" not in bake_s:
                t0 = time.perf_counter()
                voxfmt.bake(str(folder / f"{name}.off"), str(out), voxel_size=voxel, points=20000)
                bake_s[f"{name}-d{depth}"] = round(time.perf_counter() - t0, 3)
                bakes_file.write_text(json.dumps(bake_s, indent=1) + "\n")
    for name in assets.meshes:
        assets.prefilter[name] = str(folder / f"{name}-d{depths[0]}.vox.h5")
        assets.prefilter_voxel[name] = voxfmt.load(assets.prefilter[name]).voxel_size
    print(f"assets in {folder}; bakes: " + ", ".join(f"{k} {v:.1f} s" for k, v in bake_s.items()))

    scenes = make_scenes(assets, scene_names, args.quick)
    runs: list[dict[str, Any]] = []
    for scene in scenes:
        for method in methods:
            configs = [(depths[0], (40, 10))] if method == "hull" else [(d, s) for d in depths for s in sdfs]
            for depth, sdf in configs:
                fig = simulate(scene, method, assets, depth, sdf, profile=False,
                               compile_repeats=1 if args.quick else 3)
                if method == "voxfmt":
                    # The same run again (MuJoCo is deterministic), counting and recording the lookups.
                    again = simulate(scene, method, assets, depth, sdf, profile=True, compile_repeats=0)
                    for k in ("sdf_collisions_per_step", "calls_per_step", "lookups_per_step", "lookup_us_per_step"):
                        fig[k] = again[k]
                if scene.name == "bunny-on-box" and args.rest_trials:
                    fig.update(rest_trials(method, assets, depth, sdf, scene.seconds))
                asset = assets.folder / f"{scene.bodies[-1].asset}-d{depth}.vox.h5"
                resolution = {
                    "hull": None,
                    "native-sdf": f"octree depth {depth}",
                    "voxfmt": f"voxel {voxfmt.load(str(asset)).voxel_size * 1e3:.3g} mm (depth {depth}'s leaf)",
                }[method]
                run = {
                    "scene": scene.name,
                    "method": method,
                    "resolution": resolution,
                    "sdf_initpoints": None if method == "hull" else sdf[0],
                    "sdf_iterations": None if method == "hull" else sdf[1],
                    **fig,
                }
                if method == "voxfmt":
                    run["bake_s"] = round(sum(bake_s[f"{a}-d{depth}"] for a in {b.asset for b in scene.bodies}), 3)
                runs.append(run)
                print(json.dumps(run), flush=True)
    result = {
        "machine": f"{platform.node()} ({os.cpu_count()} cores)",
        "mujoco": mujoco.__version__,
        "command": " ".join(sys.argv),
        "timestep_s": TIMESTEP,
        "runs": runs,
    }
    result["ratios"] = ratios(runs)
    if args.json:
        Path(args.json).write_text(json.dumps(result, indent=1) + "\n")
    table = markdown(result)
    print(table)
    if args.markdown:
        Path(args.markdown).write_text(table)
    return 0


def ratios(runs: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """voxfmt against the native SDF at the same scene, resolution (octree depth) and sdf_* settings."""
    out = []
    for v in runs:
        if v["method"] != "voxfmt":
            continue
        depth = v["resolution"].split("depth ")[1].rstrip("'s leaf)")
        for n in runs:
            if (n["method"], n["scene"], n["sdf_initpoints"], n["sdf_iterations"]) == (
                    "native-sdf", v["scene"], v["sdf_initpoints"], v["sdf_iterations"]) and \
                    n["resolution"] == f"octree depth {depth}":
                out.append({
                    "scene": v["scene"], "octree_depth": int(depth),
                    "sdf": f"{v['sdf_initpoints']}/{v['sdf_iterations']}",
                    "step_p50_voxfmt_over_native": round(v["step_us_p50"] / n["step_us_p50"], 3),
                    "compile_voxfmt_over_native": round(v["compile_s"] / n["compile_s"], 3),
                    "memory_voxfmt_over_native": round(v["memory_mb"] / n["memory_mb"], 3),
                    "lookup_share_of_voxfmt_step": round(v.get("lookup_us_per_step", 0) / v["step_us_p50"], 3),
                })
    return out


def markdown(result: dict[str, Any]) -> str:
    def f(x: Any, digits: int = 1) -> str:
        return "—" if x is None else (f"{x:.{digits}f}" if isinstance(x, float) else str(x))

    lines = [
        f"MuJoCo {result['mujoco']}, {result['machine']}, 1 ms steps: `{result['command']}`",
        "",
        "| scene | method | resolution | sdf | compile s | memory MB | step µs p50 / p99 | max pen. mm (rest) | "
        "at rest from s | COM / point mm/s at end | peg in mm | lookups µs/step | drops at rest |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in result["runs"]:
        sdf = "—" if r["sdf_initpoints"] is None else f"{r['sdf_initpoints']}/{r['sdf_iterations']}"
        lines.append(
            f"| {r['scene']} | {r['method']} | {r['resolution'] or 'mesh'} | {sdf} | {f(r['compile_s'], 3)} | "
            f"{f(r['memory_mb'])} | {f(r['step_us_p50'])} / {f(r['step_us_p99'])} | "
            f"{f(r['max_penetration_mm'], 2)} ({f(r['rest_penetration_mm'], 2)}) | {f(r['rest_time_s'], 2)} | "
            f"{f(r['final_com_speed_mm_s'], 2)} / {f(r['final_point_speed_mm_s'], 2)} | "
            f"{f(r['outcome']['inserted_mm'], 2)} | {f(r.get('lookup_us_per_step'))} | "
            + (f"{r['rest_trials_at_rest']} of {r['rest_trials']} |" if "rest_trials" in r else "— |")
        )
    lines += ["", "| scene | octree depth | sdf | voxfmt / native: step p50 | compile | memory | lookups' share of a "
              "voxfmt step |", "|---|---|---|---|---|---|---|"]
    for q in result["ratios"]:
        lines.append(f"| {q['scene']} | {q['octree_depth']} | {q['sdf']} | {q['step_p50_voxfmt_over_native']:.2f} | "
                     f"{q['compile_voxfmt_over_native']:.2f} | {q['memory_voxfmt_over_native']:.2f} | "
                     f"{q['lookup_share_of_voxfmt_step']:.2f} |")
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    sys.exit(main())
