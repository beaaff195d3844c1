#!/usr/bin/env python3
"""How good a force is: each query method's penalty force and torque along scripted paths, against the same
penalty model evaluated with exact distances (after Weller, Sagardia et al., "A Benchmarking Suite for 6-DOF Real
Time Collision Response Algorithms", VRST 2010).

    PYTHONPATH=build/python .venv/bin/python bench/force_quality.py --json F.json --markdown F.md
    /usr/bin/python3 bench/force_quality.py --plot F.json OUT.png   # matplotlib only (Debian's python3-matplotlib)

A moving body A is driven along a path at 1 kHz against a static body B (B's frame is the world). Every method
sees the same poses, in one run:
  fine       contacts_batch(): every point of A's shell against B's field
  level L    the shell cut after tree level L (max_level), its points reporting as cut_level says: "points" (each
             for itself, at its true depth: the seed's coarse shell, Bullet's default) or "spheres" (each for its
             sphere: no contact lost, deeper; the runtime's default) -- what a time budget or a coarse setting gives
  coherent   Tracker.contacts_batch(): the same as fine, each step from the last one's traversal
The reference is voxfmt.wrench's model, F = sum k * depth * n over the penetrating points, with the depth and
normal of every point of A's full shell taken from B's exact signed distance (closed form: B is a box or a
torus, and its mesh is fine enough that the closed form is the mesh within 1/200 voxel). Torque about A's centre
of mass.

Paths (B's voxel h; A's points are in B's field, as the query's automatic direction chooses):
  wall-push     CGAL's bunny (0.15 m, tilted) pushed 0 -> 10 voxels into a wall (a 0.4 x 0.4 x 0.1 m box) over
                700 steps, then slid 20 mm along it at 10 voxels for 300 steps
  tori-sliding  two tori (R 50 mm, r 20 mm) on one axis, overlap 0 -> 6 voxels along the whole ring over 600
                steps, then slid 10 mm sideways while spinning 90 degrees at 6 voxels for 400 steps

Figures per path and method, over the steps whose reference depth is at least 0.1 voxel (shallower, the force
is a few quanta of the stored distance), split at 2 voxels deep:
  force magnitude error |(|F| - |F_ref|)| / |F_ref| and angle between F and F_ref (95th percentile, and the share
  of steps within 2 % and 2 degrees up to 2 voxels, within 10 % and 2 degrees beyond);
  torque error |T - T_ref| / (|F_ref| * A's bounding radius) (95th percentile);
  smoothness: the largest step-to-step change of F over the median change (the reference's own beside it), and
  the excess jump: the largest step-to-step change of the error F - F_ref over the reference's median change.
A cut level's points each stand for more surface: its stiffness per point is scaled by (shell points / level's
points), so that the force per area is the reference's; without that, its force is that fraction of the fine one.
  peg-in-hole   a peg (radius 5 mm, 30 mm long) lowered 15 mm into a block's through hole (radius 5.2 mm; the
                block 60 x 60 x 40 mm) without touching, then moved sideways across the clearance and 10 voxels
                into the hole's wall over 700 steps while going 2 mm deeper: a long, nearly conforming contact
  bunny-bunny   CGAL's bunny (0.15 m; A baked with 30,000 points, B with 35,000, so that A's points go into B's
                field) turned over and lowered onto a second one's back, 0 -> 8 voxels over 600 steps, then slid 10
                mm sideways while turning 20 degrees for 400 steps: curved, non-convex contact. Its reference takes
                B's exact distance from its mesh (libigl: `pip install libigl`; the pseudonormal sign), for every
                point of A that B's field does not put more than 2 voxels outside (the field's error is far below
                that: a point it puts farther out is outside and adds nothing).
And the haptic renderer (HapticRenderer::contact_wrench_at, full trees: the same per-point penalty along the
tool's own point normals, classical VPS), through build/bin/haptic-wrench (bench/haptic_wrench.cpp) when built.
Every asset is baked with --resolution voxels along its longest side (306, the seed's) and the distance band
--band (3, voxfmt build's default); other settings are cached under their own names.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "examples" / "mujoco"))
from shapes import read_off, torus_mesh, write_off

HAPTIC_WRENCH = ROOT / "build" / "bin" / "haptic-wrench"  # bench/haptic_wrench.cpp
STIFFNESS = 1000.0  # N/m; every figure is relative, so any value gives the same ones
MIN_DEPTH_VOXELS = 0.1


# ------------------------------------------------------------------------------------------------ meshes

def box_mesh(half: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    corners = np.array([[x, y, z] for z in (-1, 1) for y in (-1, 1) for x in (-1, 1)], float) * half
    quads = [(0, 2, 3, 1), (4, 5, 7, 6), (0, 1, 5, 4), (2, 6, 7, 3), (0, 4, 6, 2), (1, 3, 7, 5)]
    faces = [(a, b, c) for a, b, c, d in quads] + [(a, c, d) for a, b, c, d in quads]
    return corners, np.array(faces)


def oriented(vertices: np.ndarray, faces: np.ndarray, outward) -> np.ndarray:
    """Faces turned so that each normal agrees with outward(centroids) (each face's side is known by construction)."""
    tri = vertices[faces]
    normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    flip = np.einsum("ij,ij->i", normal, outward(tri.mean(axis=1))) < 0
    faces = faces.copy()
    faces[flip] = faces[flip][:, ::-1]
    return faces


def quads(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Two triangles per quad between two closed rings of vertex indices."""
    a1, b1 = np.roll(a, -1), np.roll(b, -1)
    return np.concatenate([np.stack([a, b, b1], -1), np.stack([a, b1, a1], -1)])


def block_with_hole_mesh(a: float, c: float, hole: float, n: int) -> tuple[np.ndarray, np.ndarray]:
    """The box [-a, a]^2 x [-c, c] with a through hole of radius `hole` along z; n (a multiple of 8) points
    around, the square's corners among them."""
    theta = np.arange(n) * 2 * np.pi / n
    ring = np.stack([np.cos(theta), np.sin(theta)], -1)
    square = ring * (a / np.abs(ring).max(axis=1))[:, None]
    circle = ring * hole
    rows = [np.hstack([xy, np.full((n, 1), z)]) for xy, z in ((square, c), (circle, c), (square, -c), (circle, -c))]
    vertices = np.concatenate(rows)
    sq_top, ci_top, sq_bot, ci_bot = (np.arange(n) + k * n for k in range(4))
    faces = np.concatenate([quads(ci_top, sq_top), quads(sq_bot, ci_bot), quads(sq_top, sq_bot), quads(ci_bot, ci_top)])

    def outward(x: np.ndarray) -> np.ndarray:
        out = np.zeros_like(x)
        rho = np.hypot(x[:, 0], x[:, 1])
        cap = np.abs(np.abs(x[:, 2]) - c) < 1e-12
        wall = ~cap & (rho < hole * 1.0001)
        side = ~cap & ~wall
        out[cap, 2] = np.sign(x[cap, 2])
        out[wall, :2] = -x[wall, :2] / rho[wall, None]
        axis = np.abs(x[side, :2]).argmax(axis=1)
        out[np.flatnonzero(side), axis] = np.sign(x[side][np.arange(len(axis)), axis])
        return out

    return vertices, oriented(vertices, faces, outward)


def cylinder_mesh(radius: float, half_length: float, n: int) -> tuple[np.ndarray, np.ndarray]:
    theta = np.arange(n) * 2 * np.pi / n
    ring = np.stack([radius * np.cos(theta), radius * np.sin(theta)], -1)
    vertices = np.concatenate([np.hstack([ring, np.full((n, 1), half_length)]),
                               np.hstack([ring, np.full((n, 1), -half_length)]), [[0, 0, half_length], [0, 0, -half_length]]])
    top, bottom = np.arange(n), np.arange(n) + n
    caps = [np.stack([np.full(n, 2 * n), top, np.roll(top, -1)], -1),
            np.stack([np.full(n, 2 * n + 1), np.roll(bottom, -1), bottom], -1)]
    faces = np.concatenate([quads(top, bottom)] + caps)

    def outward(x: np.ndarray) -> np.ndarray:
        cap = np.abs(np.abs(x[:, 2]) - half_length) < 1e-12
        out = np.hstack([x[:, :2], np.zeros((len(x), 1))])
        out[cap] = [0, 0, 0]
        out[cap, 2] = np.sign(x[cap, 2])
        return out

    return vertices, oriented(vertices, faces, outward)


# ------------------------------------------------------------------------------------------------ exact fields

def box_sdf(x: np.ndarray, half: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Signed distance to a box centred at the origin and its outward unit gradient."""
    q = np.abs(x) - half
    outside = np.linalg.norm(np.maximum(q, 0), axis=1)
    inside = np.minimum(q.max(axis=1), 0)
    grad = np.zeros_like(x)
    out = outside > 0
    grad[out] = np.sign(x[out]) * np.maximum(q[out], 0) / outside[out, None]
    axis = q[~out].argmax(axis=1)
    grad[np.flatnonzero(~out), axis] = np.sign(x[~out][np.arange(len(axis)), axis])
    return outside + inside, grad


def torus_sdf(x: np.ndarray, R: float, r: float) -> tuple[np.ndarray, np.ndarray]:
    """Signed distance to a torus about the z axis and its outward unit gradient."""
    rho = np.maximum(np.hypot(x[:, 0], x[:, 1]), 1e-12)
    qx, qz = rho - R, x[:, 2]
    length = np.maximum(np.hypot(qx, qz), 1e-12)
    grad = np.stack([qx / length * x[:, 0] / rho, qx / length * x[:, 1] / rho, qz / length], -1)
    return length - r, grad


def block_with_hole_sdf(x: np.ndarray, a: float, c: float, hole: float) -> tuple[np.ndarray, np.ndarray]:
    """Exact inside the material (what a penetrating point needs): minus the distance to the nearest face or to
    the hole's wall, and that surface's outward normal; outside it, +1 (no contact) and no gradient."""
    rho = np.maximum(np.hypot(x[:, 0], x[:, 1]), 1e-12)
    gaps = np.stack([a - np.abs(x[:, 0]), a - np.abs(x[:, 1]), c - np.abs(x[:, 2]), rho - hole], -1)
    inside = (gaps > 0).all(axis=1)
    nearest = gaps.argmin(axis=1)
    d = np.where(inside, -gaps.min(axis=1), 1.0)
    grad = np.zeros_like(x)
    for axis in range(3):
        pick = inside & (nearest == axis)
        grad[pick, axis] = np.sign(x[pick, axis])
    wall = inside & (nearest == 3)
    grad[wall, :2] = -x[wall, :2] / rho[wall, None]
    return d, grad


# ------------------------------------------------------------------------------------------------ poses

def rotation(axis: str, degrees: float) -> np.ndarray:
    c, s = np.cos(np.radians(degrees)), np.sin(np.radians(degrees))
    i, j = {"x": (1, 2), "y": (2, 0), "z": (0, 1)}[axis]
    m = np.eye(3)
    m[i, i], m[i, j], m[j, i], m[j, j] = c, -s, s, c
    return m


def pose(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    m = np.eye(4)
    m[:3, :3], m[:3, 3] = R, t
    return m


def wall_push_path(tool, wall_top: float, h: float) -> np.ndarray:
    """The tool's poses: 0 -> 10 voxels into the wall, then slid along it."""
    R0 = rotation("z", 30) @ rotation("x", 20)
    lowest = (tool.points.astype(np.float64) @ R0.T)[:, 2].min()
    depth = np.concatenate([np.linspace(0, 10, 700), np.full(300, 10.0)])
    slide = np.concatenate([np.zeros(700), np.linspace(0, 0.02, 300)])
    return np.stack([pose(R0, np.array([s, 0.0, wall_top - lowest - d * h])) for d, s in zip(depth, slide)])


def tori_path(r: float, h: float) -> np.ndarray:
    overlap = np.concatenate([np.linspace(0, 6, 600), np.full(400, 6.0)])
    slide = np.concatenate([np.zeros(600), np.linspace(0, 0.01, 400)])
    spin = np.concatenate([np.zeros(600), np.linspace(0, 90, 400)])
    return np.stack([pose(rotation("z", w), np.array([s, 0.0, 2 * r - o * h]))
                     for o, s, w in zip(overlap, slide, spin)])


def peg_path(c: float, clearance: float, half_length: float, h: float) -> np.ndarray:
    """The peg descends into the hole, centred (no contact), then is moved sideways across the clearance and 10
    voxels into the wall while it goes 2 mm deeper."""
    descend = np.concatenate([np.linspace(c + half_length + 0.002, c + half_length - 0.015, 300),
                              np.linspace(c + half_length - 0.015, c + half_length - 0.017, 700)])
    offset = np.concatenate([np.zeros(300), np.linspace(0, clearance + 10 * h, 700)])
    return np.stack([pose(np.eye(3), np.array([x, 0.0, z])) for z, x in zip(descend, offset)])


def bunny_path(tool, field, h: float) -> np.ndarray:
    """A turned over and lowered onto B from where their meshes first touch (B's field tells), then slid."""
    R0 = rotation("y", 180) @ rotation("z", 40)
    points = tool.points.astype(np.float64)

    def gap(z: float) -> float:
        return float(field.signed_distance(points @ R0.T + np.array([0.0, 0.0, z])).min())

    lo, hi = 0.0, 0.3  # B's centre to well above it
    for _ in range(40):  # the lowest height at which A is clear of B
        mid = 0.5 * (lo + hi)
        lo, hi = (lo, mid) if gap(mid) > 0 else (mid, hi)
    depth = np.concatenate([np.linspace(0, 8, 600), np.full(400, 8.0)])
    slide = np.concatenate([np.zeros(600), np.linspace(0, 0.01, 400)])
    turn = np.concatenate([np.zeros(600), np.linspace(0, 20, 400)])
    return np.stack([pose(rotation("z", w) @ R0, np.array([s, 0.0, hi - d * h]))
                     for d, s, w in zip(depth, slide, turn)])


def mesh_reference_wrench(tool, poses: np.ndarray, vertices: np.ndarray, faces: np.ndarray, field,
                          margin: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """reference_wrench with B's exact signed distance and outward normal from its mesh (libigl, pseudonormal
    sign), for the points of every step that B's field puts under `margin` (the others are outside: no force),
    in one call for the whole path (libigl builds its tree per call)."""
    import igl

    points = tool.points.astype(np.float64)
    com = np.asarray(tool.center_of_mass, np.float64)
    near_points, owner = [], []
    for k, m in enumerate(poses):
        x = points @ m[:3, :3].T + m[:3, 3]
        near = field.signed_distance(x) < margin
        near_points.append(x[near])
        owner.append(np.full(int(near.sum()), k))
    x, owner = np.concatenate(near_points), np.concatenate(owner)
    d, _, closest, _ = igl.signed_distance(x, vertices, faces, sign_type=igl.SIGNED_DISTANCE_TYPE_PSEUDONORMAL)
    hit = d < 0
    offset = x[hit] - closest[hit]
    normal = -offset / np.maximum(np.linalg.norm(offset, axis=1), 1e-300)[:, None]  # outward: x is inside
    f = STIFFNESS * (-d[hit])[:, None] * normal
    centre = np.einsum("kij,j->ki", poses[:, :3, :3], com) + poses[:, :3, 3]
    force, torque, deepest = np.zeros((len(poses), 3)), np.zeros((len(poses), 3)), np.zeros(len(poses))
    k = owner[hit]
    np.add.at(force, k, f)
    np.add.at(torque, k, np.cross(x[hit] - centre[k], f))
    np.maximum.at(deepest, k, -d[hit])
    return force, torque, deepest


# ------------------------------------------------------------------------------------------------ figures

def reference_wrench(tool, poses: np.ndarray, sdf) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The penalty wrench on the tool from every point of its full shell, with exact depths and normals; and the
    deepest point's depth (metres) per step."""
    points = tool.points.astype(np.float64)
    com = np.asarray(tool.center_of_mass, np.float64)
    force, torque, deepest = np.zeros((len(poses), 3)), np.zeros((len(poses), 3)), np.zeros(len(poses))
    for k, m in enumerate(poses):
        x = points @ m[:3, :3].T + m[:3, 3]
        d, g = sdf(x)
        hit = d < 0
        f = STIFFNESS * (-d[hit])[:, None] * g[hit]
        force[k] = f.sum(axis=0)
        torque[k] = np.cross(x[hit] - (m[:3, :3] @ com + m[:3, 3]), f).sum(axis=0)
        deepest[k] = -d.min() if hit.any() else 0.0
    return force, torque, deepest


def angle_degrees(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    na, nb = np.linalg.norm(a, axis=1), np.linalg.norm(b, axis=1)
    cos = np.einsum("ij,ij->i", a, b) / np.maximum(na * nb, 1e-300)
    return np.degrees(np.arccos(np.clip(cos, -1, 1)))


def step_changes(values: np.ndarray, active: np.ndarray) -> np.ndarray:
    """|values[k] - values[k - 1]| over consecutive steps both in contact."""
    return np.linalg.norm(np.diff(values, axis=0), axis=1)[active[1:] & active[:-1]]


def largest_over_median(changes: np.ndarray, typical: np.ndarray) -> float:
    median = float(np.median(typical)) if typical.size else 0.0
    return float(changes.max() / median) if median > 0 else float("inf")


def smoothness(force: np.ndarray, active: np.ndarray) -> float:
    """Largest step-to-step change of the force over the median change, over consecutive steps in contact."""
    changes = step_changes(force, active)
    return largest_over_median(changes, changes)


def excess_jump(force: np.ndarray, ref_force: np.ndarray, active: np.ndarray) -> float:
    """Largest step-to-step change of the error F - F_ref over the reference's median change: a jump the path
    itself does not make."""
    return largest_over_median(step_changes(force - ref_force, active), step_changes(ref_force, active))


def method_figures(force, torque, ref_force, ref_torque, depth_voxels, lever) -> dict:
    active = depth_voxels >= MIN_DEPTH_VOXELS
    ref_norm = np.linalg.norm(ref_force, axis=1)
    magnitude = np.abs(np.linalg.norm(force, axis=1) - ref_norm) / np.maximum(ref_norm, 1e-300)
    angle = angle_degrees(force, ref_force)
    torque_error = np.linalg.norm(torque - ref_torque, axis=1) / np.maximum(ref_norm * lever, 1e-300)
    out: dict = {}
    for name, band, tolerance in (("shallow", active & (depth_voxels <= 2), 0.02),
                                  ("deep", active & (depth_voxels > 2), 0.10)):
        if not band.any():
            continue
        within = (magnitude[band] <= tolerance) & (angle[band] <= 2.0)
        out[name] = {
            "steps": int(band.sum()),
            "within_share": round(float(within.mean()), 4),
            "tolerance": tolerance,
            "magnitude_error_p95": round(float(np.percentile(magnitude[band], 95)), 5),
            "angle_deg_p95": round(float(np.percentile(angle[band], 95)), 4),
            "torque_error_p95": round(float(np.percentile(torque_error[band], 95)), 5),
        }
    out["smoothness"] = round(smoothness(force, active), 3)
    out["excess_jump"] = round(excess_jump(force, ref_force, active), 3)
    return out


def haptic_wrench(tool_asset: Path, field_asset: Path, poses: np.ndarray,
                  tricubic: bool = False) -> tuple[np.ndarray, np.ndarray, float]:
    """HapticRenderer::contact_wrench_at at every pose, through bench/haptic_wrench.cpp (the renderer is C++), and
    its microseconds per pose (loading excluded); `tricubic`: its depths interpolated so."""
    with tempfile.TemporaryDirectory() as scratch:
        pose_file, out_file = Path(scratch) / "poses.f64", Path(scratch) / "wrench.f64"
        np.ascontiguousarray(poses, dtype="<f8").tofile(pose_file)
        run = subprocess.run([str(HAPTIC_WRENCH), str(tool_asset), str(field_asset), str(pose_file), str(out_file),
                              "--stiffness", str(STIFFNESS)] + (["--tricubic"] if tricubic else []),
                             check=True, capture_output=True, text=True)
        wrench = np.fromfile(out_file, dtype="<f8").reshape(len(poses), 6)
    us_per_pose = float(run.stdout.split()[-1])
    return wrench[:, :3], wrench[:, 3:], us_per_pose


def run_path(name: str, tool, field, poses: np.ndarray, reference, h: float, voxfmt,
             assets: tuple[Path, Path] | None = None) -> dict:
    """`reference`: (force, torque, deepest) of reference_wrench or mesh_reference_wrench; `assets`: the tool's and
    B's files, for the haptic renderer (skipped without them or its program)."""
    identity = np.eye(4)
    ref_force, ref_torque, deepest = reference
    # The reference is the tool's points in B's field; the query must measure the same (for two equal bodies its
    # automatic direction takes B's points in A's field: another penalty model, degrees apart on a curved contact).
    sample = voxfmt.contacts_batch(tool, poses[::25], field, identity, threads=1, with_contacts=True)
    if len(sample.point_of_b) == 0 or np.asarray(sample.point_of_b).any():
        raise SystemExit(f"force_quality: on the {name} path the query does not test the tool's points in B's field "
                         "(the reference's model): make the tool smaller or give it fewer points than B")
    depth_voxels = deepest / h
    lever = float(np.linalg.norm(tool.points - np.asarray(tool.center_of_mass, np.float32), axis=1).max())
    methods: dict[str, dict] = {}
    series: dict[str, list[float]] = {"reference": np.linalg.norm(ref_force, axis=1).round(6).tolist()}
    levels = np.asarray(tool.levels)

    def record(label: str, force: np.ndarray, torque: np.ndarray, scale: float, points: int, us: float) -> None:
        figures = method_figures(force, torque, ref_force, ref_torque, depth_voxels, lever)
        figures.update(stiffness_scale=round(scale, 4), points=points, us_per_step=round(us, 1))
        methods[label] = figures
        series[label] = np.linalg.norm(force, axis=1).round(6).tolist()

    runs = [("fine", None, None)] + [(f"level {level} {cut}", level, cut) for level in range(len(levels) - 2)
                                     for cut in ("points", "spheres")]
    for label, level, cut in runs + [("fine tricubic", None, None), ("coherent", None, None)]:
        start = time.perf_counter()
        if label == "coherent":
            batch = voxfmt.Tracker(tool, field).contacts_batch(poses, identity, stiffness=STIFFNESS)
        else:
            batch = voxfmt.contacts_batch(tool, poses, field, identity, threads=1, stiffness=STIFFNESS,
                                          max_level=level, cut_level=cut or "spheres",
                                          interpolation="tricubic" if label == "fine tricubic" else "trilinear")
        points = int(levels[level + 1]) if level is not None else len(tool.points)
        seconds = time.perf_counter() - start
        # A cut shell has fewer points to share the load: each stands for len(shell) / points of the surface, so
        # its stiffness per point is scaled by that (the force per area stays the reference's).
        scale = len(tool.points) / points
        record(label, batch.force * scale, batch.torque * scale, scale, points, seconds / len(poses) * 1e6)
    if assets and HAPTIC_WRENCH.exists():
        # The haptic renderer (full trees): the same per-point penalty along the tool's own point normals.
        force, torque, us_per_pose = haptic_wrench(*assets, poses)
        record("haptic renderer", force, torque, 1.0, len(tool.points), us_per_pose)
        force, torque, us_per_pose = haptic_wrench(*assets, poses, tricubic=True)
        record("haptic renderer tricubic", force, torque, 1.0, len(tool.points), us_per_pose)
    reference_smoothness = round(smoothness(ref_force, depth_voxels >= MIN_DEPTH_VOXELS), 3)
    return {"path": name, "steps": len(poses), "voxel_size": h, "reference_smoothness": reference_smoothness,
            "methods": methods, "depth_voxels": depth_voxels.round(4).tolist(), "force_norm": series}


# ------------------------------------------------------------------------------------------------ assets

def scaled_bunny(cache: Path, source: str) -> Path:
    """CGAL's bunny centred and scaled to 0.15 m."""
    path = cache / "bunny-0.15m.off"
    if not path.exists():
        v, f = read_off(Path(source))
        v = (v - v.mean(axis=0)) * (0.15 / (v.max(axis=0) - v.min(axis=0)).max())
        write_off(path, v, f)
    return path


DEFAULT_BAND = 3  # voxfmt build's
DEFAULT_RESOLUTION = 306  # the seed's


def asset_file(cache: Path, name: str, bake: tuple[float, int] = (DEFAULT_BAND, DEFAULT_RESOLUTION)) -> Path:
    """Where `baked` keeps the asset called `name` baked with `bake` (band, resolution)."""
    band, resolution = bake
    suffix = ("" if band == DEFAULT_BAND else f"-band{band:g}") + (
        "" if resolution == DEFAULT_RESOLUTION else f"-res{resolution}")
    return cache / f"{name}{suffix}.vox.h5"


def baked(voxfmt, cache: Path, name: str, mesh: tuple[np.ndarray, np.ndarray] | Path, points: int,
          bake: tuple[float, int] = (DEFAULT_BAND, DEFAULT_RESOLUTION)):
    asset = asset_file(cache, name, bake)
    if not asset.exists():
        source = mesh if isinstance(mesh, Path) else cache / f"{name}.off"
        if not isinstance(mesh, Path):
            write_off(source, *mesh)
        print(f"force_quality: baking {asset.name} ...", file=sys.stderr)
        try:
            voxfmt.bake(source, asset, resolution=bake[1], points=points, band=bake[0])
        except voxfmt.Error as e:
            raise SystemExit(f"force_quality: cannot bake {asset.name}: {e}")
    return voxfmt.load(asset)


def measure(args) -> dict:
    import voxfmt

    cache = Path(args.cache)
    cache.mkdir(parents=True, exist_ok=True)
    bake = (args.band, args.resolution)
    paths = []
    if "wall-push" in args.paths:
        half = np.array([0.2, 0.2, 0.05])
        wall = baked(voxfmt, cache, "wall", box_mesh(half), 35000, bake)
        bunny = baked(voxfmt, cache, "bunny-0.15m", scaled_bunny(cache, args.bunny), 35000, bake)
        poses = wall_push_path(bunny, half[2], wall.voxel_size)
        paths.append(run_path("wall-push", bunny, wall, poses,
                              reference_wrench(bunny, poses, lambda x: box_sdf(x, half)), wall.voxel_size, voxfmt,
                              (asset_file(cache, "bunny-0.15m", bake), asset_file(cache, "wall", bake))))
    if "tori-sliding" in args.paths:
        R, r = 0.05, 0.02
        mesh = torus_mesh(R, r, 1440, 480)
        fixed = baked(voxfmt, cache, "torus-b", mesh, 35000, bake)
        moving = baked(voxfmt, cache, "torus-a", mesh, 30000, bake)  # fewer points: its shell goes into B's field
        poses = tori_path(r, fixed.voxel_size)
        paths.append(run_path("tori-sliding", moving, fixed, poses,
                              reference_wrench(moving, poses, lambda x: torus_sdf(x, R, r)), fixed.voxel_size, voxfmt,
                              (asset_file(cache, "torus-a", bake), asset_file(cache, "torus-b", bake))))
    if "peg-in-hole" in args.paths:
        a, c, hole, radius, half_length = 0.03, 0.02, 0.0052, 0.005, 0.015
        block = baked(voxfmt, cache, "block-hole-5.2mm", block_with_hole_mesh(a, c, hole, 1440), 35000, bake)
        peg = baked(voxfmt, cache, "peg-5mm", cylinder_mesh(radius, half_length, 1440), 20000, bake)
        poses = peg_path(c, hole - radius, half_length, block.voxel_size)
        paths.append(run_path("peg-in-hole", peg, block, poses,
                              reference_wrench(peg, poses, lambda x: block_with_hole_sdf(x, a, c, hole)),
                              block.voxel_size, voxfmt,
                              (asset_file(cache, "peg-5mm", bake), asset_file(cache, "block-hole-5.2mm", bake))))
    if "bunny-bunny" in args.paths:
        try:
            import igl
        except ImportError:
            raise SystemExit("force_quality: the bunny-bunny path needs libigl (pip install libigl), or leave it out "
                             "with --paths")

        mesh = scaled_bunny(cache, args.bunny)
        fixed = baked(voxfmt, cache, "bunny-0.15m", mesh, 35000, bake)
        # Fewer points: its shell goes into B's field.
        moving = baked(voxfmt, cache, "bunny-0.15m-30k", mesh, 30000, bake)
        vertices, faces = igl.read_triangle_mesh(str(mesh))
        poses = bunny_path(moving, fixed, fixed.voxel_size)
        reference = mesh_reference_wrench(moving, poses, vertices, faces.astype(np.int64), fixed, 2 * fixed.voxel_size)
        paths.append(run_path("bunny-bunny", moving, fixed, poses, reference, fixed.voxel_size, voxfmt,
                              (asset_file(cache, "bunny-0.15m-30k", bake), asset_file(cache, "bunny-0.15m", bake))))
    return {"benchmark": "force_quality", "band_voxels": args.band, "resolution": args.resolution,
            "stiffness": STIFFNESS, "min_depth_voxels": MIN_DEPTH_VOXELS,
            "machine": f"{platform.node()} ({os.cpu_count()} cores)",
            "command": "bench/force_quality.py " + " ".join(sys.argv[1:]), "paths": paths}


# ------------------------------------------------------------------------------------------------ output

def markdown(result: dict) -> str:
    legend = (f"Steps whose reference depth is at least {result['min_depth_voxels']} voxel; shallow: up to 2 voxels "
              "(within: 2 % and 2 degrees), deep: 2-10 voxels (within: 10 % and 2 degrees). Magnitude and angle of "
              "the force, torque error over |F_ref| x A's radius: 95th percentiles. Smoothness: largest step change "
              "of F over the median one (the reference's own); excess jump: largest step change of F - F_ref over "
              "the reference's median one. Cut levels: stiffness per point x shell points / level's points.")
    header = ("| path | method | points | shallow within | magnitude p95 | angle p95 | torque p95 | deep within | "
              "magnitude p95 | angle p95 | torque p95 | smoothness (reference) | excess jump | µs/step |")
    lines = [f"Force quality, {result['machine']}: `{result['command']}`", "", legend, "", header,
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for p in result["paths"]:
        for name, m in p["methods"].items():
            cells = [p["path"], name, str(m["points"])]
            for band in ("shallow", "deep"):
                b = m.get(band)
                cells += ([f"{100 * b['within_share']:.1f} % of {b['steps']}", f"{100 * b['magnitude_error_p95']:.2f} %",
                           f"{b['angle_deg_p95']:.2f}°", f"{100 * b['torque_error_p95']:.2f} %"] if b else ["—"] * 4)
            cells += [f"{m['smoothness']:.1f} ({p['reference_smoothness']:.1f})", f"{m['excess_jump']:.2f}",
                      f"{m['us_per_step']:.0f}"]
            lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def plot(json_path: str, png_path: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    result = json.loads(Path(json_path).read_text())
    paths = result["paths"]
    fig, axes = plt.subplots(len(paths), 1, figsize=(11, 4.2 * len(paths)), squeeze=False)
    for ax, p in zip(axes[:, 0], paths):
        steps = np.arange(p["steps"])
        # The reference, fine and coherent, the cut levels of 100 points or more, the finest "spheres" cut.
        spheres = [n for n in p["methods"] if n.endswith("spheres")]
        shown = [n for n, m in p["methods"].items()
                 if not n.startswith("level") or (n.endswith("points") and m["points"] >= 100) or n == spheres[-1]]
        for name in ["reference"] + shown:
            values = np.asarray(p["force_norm"][name], float)
            style = {"color": "black", "linewidth": 2.4} if name == "reference" else {"linewidth": 1.0}
            ax.plot(steps, np.where(values > 0, values, np.nan), label=name, **style)
        ax.set_yscale("log")
        ax.set_title(f"{p['path']}: |F| along the path (stiffness {result['stiffness']:g} N/m; cut levels scaled "
                     "by shell points / level points)")
        ax.set_xlabel("step (1 ms)")
        ax.set_ylabel("|F|, N")
        depth = ax.twinx()
        depth.plot(steps, p["depth_voxels"], color="grey", linestyle=":", label="reference depth")
        depth.set_ylabel("deepest point, voxels (dotted)")
        ax.legend(fontsize=7, ncol=2, loc="lower right")
    fig.tight_layout()
    fig.savefig(png_path, dpi=110)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--json", help="write the figures (and the force along each path) here")
    ap.add_argument("--markdown", help="write the table here")
    ap.add_argument("--paths", default="wall-push,tori-sliding,peg-in-hole,bunny-bunny")
    ap.add_argument("--cache", default="out/force-quality", help="meshes and baked assets (reused)")
    ap.add_argument("--band", type=float, default=DEFAULT_BAND,
                    help="bake every asset with this distance band, voxels (voxfmt build --band; 3)")
    ap.add_argument("--resolution", type=int, default=DEFAULT_RESOLUTION,
                    help="bake every asset with this many voxels along its longest side (306)")
    ap.add_argument("--bunny", default=str(ROOT / "build/cgal-data/data/meshes/bunny00.off"))
    ap.add_argument("--plot", nargs=2, metavar=("JSON", "PNG"), help="only draw a results file's forces")
    ap.add_argument("--check-reference", action="store_true",
                    help="only compare the bunny path's mesh reference (libigl) with the closed form on the wall path "
                         "(a test)")
    ap.add_argument("--check", action="store_true",
                    help="exit 1 unless the fine shell meets the targets on every path run and coherent is fine (a test)")
    ap.add_argument("--check-only", default="shallow,deep,jump,coherent",
                    help="with --check, the targets checked: shallow, deep (steps within tolerance), jump (excess "
                         "jump), coherent (coherent = fine)")
    ap.add_argument("--check-also", action="append", default=[], metavar="METHOD:TARGETS",
                    help="with --check, also hold another method to targets (shallow, deep, jump), e.g. "
                         "'fine tricubic:shallow,deep'; repeatable")
    args = ap.parse_args()
    if args.plot:
        plot(*args.plot)
        return 0
    if args.check_reference:
        return check_reference(args)
    args.paths = args.paths.split(",")
    unknown = set(args.paths) - {"wall-push", "tori-sliding", "peg-in-hole", "bunny-bunny"}
    if unknown:
        print(f"force_quality: unknown path(s) {', '.join(sorted(unknown))}", file=sys.stderr)
        return 2
    targets = {"fine": set(args.check_only.split(","))}
    for also in args.check_also:
        method, _, listed = also.partition(":")
        targets[method] = set(listed.split(",")) - {"coherent"} if listed else set()
    for method, wanted in targets.items():
        unknown_targets = wanted - {"shallow", "deep", "jump", "coherent"}
        if unknown_targets or not wanted:
            print(f"force_quality: unknown or no target(s) for {method}: {', '.join(sorted(unknown_targets))}",
                  file=sys.stderr)
            return 2
    result = measure(args)
    table = markdown(result)
    print(table)
    if args.json:
        Path(args.json).write_text(json.dumps(result) + "\n")
    if args.markdown:
        Path(args.markdown).write_text(table)
    return check(result, targets) if args.check else 0


def check_reference(args) -> int:
    """The mesh reference (libigl) against the closed form on the wall path, whose box mesh is the box itself:
    force, torque and depth must agree, or the bunny path's reference is wrong (sign, normal, torque or steps)."""
    import voxfmt

    cache = Path(args.cache)
    cache.mkdir(parents=True, exist_ok=True)
    half = np.array([0.2, 0.2, 0.05])
    bake = (args.band, args.resolution)
    wall = baked(voxfmt, cache, "wall", box_mesh(half), 35000, bake)
    bunny = baked(voxfmt, cache, "bunny-0.15m", scaled_bunny(cache, args.bunny), 35000, bake)
    poses = wall_push_path(bunny, half[2], wall.voxel_size)[::10]
    vertices, faces = box_mesh(half)
    closed = reference_wrench(bunny, poses, lambda x: box_sdf(x, half))
    mesh = mesh_reference_wrench(bunny, poses, vertices.astype(np.float64), faces.astype(np.int64), wall,
                                 2 * wall.voxel_size)
    scale = np.abs(closed[0]).max()
    worst = [float(np.abs(a - b).max() / max(np.abs(a).max(), 1e-300)) for a, b in zip(closed, mesh)]
    print(f"force_quality: mesh reference against the closed form on {len(poses)} wall poses (largest force "
          f"{scale:.3g} N): relative differences force {worst[0]:.2e}, torque {worst[1]:.2e}, depth {worst[2]:.2e}")
    return 0 if max(worst) < 1e-6 else 1


def check(result: dict, targets: dict[str, set[str]]) -> int:
    """The targets that do not depend on the machine (`targets`: per method, those checked): within 2 % and 2
    degrees in 95 % of the shallow steps and 10 % in 95 % of the deep ones, no excess jump above 5 median steps,
    coherent = fine."""
    failures = []
    for p in result["paths"]:
        for name, wanted in targets.items():
            if name not in p["methods"]:
                failures.append(f"{p['path']}: no method {name!r}")
                continue
            method = p["methods"][name]
            for band in ("shallow", "deep"):
                if band in wanted and band in method and method[band]["within_share"] < 0.95:
                    failures.append(f"{p['path']}: {name} within tolerance in {method[band]['within_share']:.1%} of "
                                    f"{band} steps")
            if "jump" in wanted and method["excess_jump"] > 5:
                failures.append(f"{p['path']}: {name}'s error jumps {method['excess_jump']:.1f} median steps")
        if "coherent" in targets["fine"] and p["force_norm"]["coherent"] != p["force_norm"]["fine"]:
            failures.append(f"{p['path']}: coherent's force differs from fine's")
    for failure in failures:
        print(f"force_quality: FAILED {failure}", file=sys.stderr)
    print(f"force_quality: check {'failed' if failures else 'passed'} on {len(result['paths'])} path(s)")
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
