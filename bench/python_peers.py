#!/usr/bin/env python3
"""voxfmt from Python, and its Python peers on the same poses, in one process, one run.

    pip install .[bench]            # voxfmt plus mujoco, coal, python-fcl, trimesh (each optional)
    python bench/python_peers.py --json bench/results/python-peers.json --markdown bench/results/python-peers.md

Parts (``--parts``, default all):
  overhead  the cost of voxfmt.contacts() above the C++ query_contacts call on the same poses (the C++ loop is
            voxfmt._voxfmt._time_query: one scratch, no Python in between)
  batch     contacts_batch on bunny-on-bunny poses, 1 thread vs 2 (and more with --threads)
  peers     per pair, on the same relative poses: voxfmt fine and coarse, Coal and python-fcl (mesh-mesh BVH
            collide, all contacts with penetration depth), MuJoCo (mj_collision on a two-body model: mesh geoms,
            which it collides through their convex hulls, and for the tori its analytic torus SDF plugin);
            contacts found and depth error where the depth is known by construction (the tori)

Scenarios (mesh frames, metres; the same constructions as bench/vps_bench/scenarios.cpp):
  bunny-bunny   CGAL's bunny00.off scaled to 0.15 m, two of them: B approaches A from a random direction in a
                random orientation until voxfmt's fine query first reports penetration (bisection), then stops
                0.5 mm short to goes 1.5 mm further (depth not known exactly: no depth error is reported)
  tori-stacked  two tori (R 0.05 m, r 0.02 m, 358 x 100 = 35,800 vertices) on a common axis, 0.5 mm overlap
                along the whole ring, random spins and common placement (exact depth 0.5 mm)
  tori-gap      the same 1 mm apart (exact: nothing touches)
Assets are baked at resolution 306 with 35,000 points (as vps-bench) into --cache and reused.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import math
import os
import platform
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

import voxfmt
from voxfmt import _voxfmt

TORUS_R, TORUS_r = 0.05, 0.02
TORUS_SEGMENTS = (358, 100)
STACK_OVERLAP, STACK_GAP = 0.0005, 0.001
COARSE_BUDGET = 800  # points: the coarse shell of the seed


# ------------------------------------------------------------------------------------------------ geometry


def rotation_matrix(q: np.ndarray) -> np.ndarray:
    w, x, y, z = q / np.linalg.norm(q)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def random_rotation(rng: np.random.Generator) -> np.ndarray:
    return rotation_matrix(rng.normal(size=4))


def rotation_y(angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def pose(rotation: np.ndarray, translation: np.ndarray) -> np.ndarray:
    p = np.eye(4)
    p[:3, :3] = rotation
    p[:3, 3] = translation
    return p


def torus_off(path: Path) -> None:
    """The torus of vps-bench: axis y, outward triangles, `major` x `minor` vertices."""
    major, minor = TORUS_SEGMENTS
    u = 2 * np.pi * np.arange(major) / major
    v = 2 * np.pi * np.arange(minor) / minor
    uu, vv = np.meshgrid(u, v, indexing="ij")
    ring = TORUS_R + TORUS_r * np.cos(vv)
    vertices = np.stack([ring * np.cos(uu), TORUS_r * np.sin(vv), ring * np.sin(uu)], axis=-1).reshape(-1, 3)
    i, j = np.meshgrid(np.arange(major), np.arange(minor), indexing="ij")

    def index(a: np.ndarray, b: np.ndarray) -> np.ndarray:
        return (a % major) * minor + (b % minor)

    t1 = np.stack([index(i, j), index(i, j + 1), index(i + 1, j + 1)], axis=-1).reshape(-1, 3)
    t2 = np.stack([index(i, j), index(i + 1, j + 1), index(i + 1, j)], axis=-1).reshape(-1, 3)
    faces = np.concatenate([t1, t2])
    with open(path, "w") as out:
        out.write(f"OFF\n{len(vertices)} {len(faces)} 0\n")
        np.savetxt(out, vertices, fmt="%.17g")
        np.savetxt(out, np.hstack([np.full((len(faces), 1), 3), faces]), fmt="%d")


def read_off(path: Path, scale: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    with open(path) as f:
        words = f.read().split()
    assert words[0] == "OFF", path
    nv, nf = int(words[1]), int(words[2])
    at = 4
    vertices = np.array(words[at : at + 3 * nv], float).reshape(nv, 3) * scale
    at += 3 * nv
    faces = []
    for _ in range(nf):
        n = int(words[at])
        ids = [int(w) for w in words[at + 1 : at + 1 + n]]
        faces += [(ids[0], ids[k], ids[k + 1]) for k in range(1, n - 1)]
        at += 1 + n
    return vertices, np.array(faces, np.int64)


@dataclass
class Mesh:
    name: str
    vertices: np.ndarray
    faces: np.ndarray
    body: voxfmt.Body


def baked(name: str, mesh_path: Path, unit_scale: float, cache: Path) -> Mesh:
    asset = cache / f"{name}-r306-p35000.vox.h5"
    if not asset.exists():
        print(f"baking {mesh_path} -> {asset} (resolution 306, 35,000 points)", file=sys.stderr)
        voxfmt.bake(mesh_path, asset, resolution=306, points=35000, unit_scale=unit_scale)
    vertices, faces = read_off(mesh_path, unit_scale)
    return Mesh(name, vertices, faces, voxfmt.load(asset))


# ------------------------------------------------------------------------------------------------ scenarios


@dataclass
class Scenario:
    name: str
    a: Mesh
    b: Mesh
    poses_a: np.ndarray  # (K, 4, 4)
    poses_b: np.ndarray
    exact_depth: float | None  # metres; negative: a gap
    description: str


def bunny_poses(bunny: voxfmt.Body, count: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """B approaches A (at the origin) along a random direction until voxfmt's fine query first penetrates (a
    bisection over all poses at once with contacts_batch), then stops 0.5 mm short to goes 1.5 mm in."""
    directions = rng.normal(size=(count, 3))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    rotations = np.array([random_rotation(rng) for _ in range(count)])
    lo = np.zeros(count)  # overlapping
    hi = np.full(count, 2.5 * float(np.linalg.norm(bunny.points, axis=1).max()))  # apart
    eye = np.eye(4)

    def poses_at(t: np.ndarray) -> np.ndarray:
        p = np.repeat(eye[None], count, axis=0)
        p[:, :3, :3] = rotations
        p[:, :3, 3] = directions * t[:, None]
        return p

    for _ in range(30):
        mid = 0.5 * (lo + hi)
        touching = voxfmt.contacts_batch(bunny, eye, bunny, poses_at(mid)).max_depth > 0
        lo = np.where(touching, mid, lo)
        hi = np.where(touching, hi, mid)
    depth = rng.uniform(-0.0005, 0.0015, size=count)
    return np.repeat(eye[None], count, axis=0), poses_at(hi - depth)


def tori_poses(count: int, offset: float, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    a, b = np.empty((count, 4, 4)), np.empty((count, 4, 4))
    for k in range(count):
        world = random_rotation(rng)
        shift = rng.uniform(-0.05, 0.05, size=3)
        b[k] = pose(world @ rotation_y(rng.uniform(0, 2 * np.pi)), shift)
        a[k] = pose(world @ rotation_y(rng.uniform(0, 2 * np.pi)), shift + world @ np.array([0, offset, 0]))
    return a, b


# ------------------------------------------------------------------------------------------------ methods


@dataclass
class Outcome:
    contacts: int
    depth: float  # deepest penetration reported, metres (0 when none)


Method = Callable[[np.ndarray, np.ndarray], Outcome]


def voxfmt_method(s: Scenario, point_budget: int | None) -> Method:
    def run(pa: np.ndarray, pb: np.ndarray) -> Outcome:
        c = voxfmt.contacts(s.a.body, pa, s.b.body, pb, point_budget=point_budget)
        return Outcome(len(c), c.max_depth)

    return run


def fcl_method(s: Scenario) -> Method | None:
    if importlib.util.find_spec("fcl") is None:
        return None
    import fcl

    def model(m: Mesh) -> Any:
        bvh = fcl.BVHModel()
        bvh.beginModel(len(m.vertices), len(m.faces))
        bvh.addSubModel(m.vertices, m.faces)
        bvh.endModel()
        return bvh

    ga, gb = model(s.a), model(s.b)
    request = fcl.CollisionRequest(num_max_contacts=1_000_000, enable_contact=True)

    def run(pa: np.ndarray, pb: np.ndarray) -> Outcome:
        oa = fcl.CollisionObject(ga, fcl.Transform(pa[:3, :3], pa[:3, 3]))
        ob = fcl.CollisionObject(gb, fcl.Transform(pb[:3, :3], pb[:3, 3]))
        result = fcl.CollisionResult()
        fcl.collide(oa, ob, request, result)
        depth = max((c.penetration_depth for c in result.contacts), default=0.0)
        return Outcome(len(result.contacts), depth)

    return run


def coal_method(s: Scenario) -> Method | None:
    if importlib.util.find_spec("coal") is None:
        return None
    import coal

    def model(m: Mesh) -> Any:
        bvh = coal.BVHModelOBBRSS()
        bvh.beginModel(len(m.faces), len(m.vertices))
        bvh.addVertices(np.ascontiguousarray(m.vertices))
        bvh.addTriangles(np.ascontiguousarray(m.faces))
        bvh.endModel()
        return bvh

    ga, gb = model(s.a), model(s.b)
    request = coal.CollisionRequest()
    request.num_max_contacts = 1_000_000
    request.enable_contact = True

    def run(pa: np.ndarray, pb: np.ndarray) -> Outcome:
        result = coal.CollisionResult()
        coal.collide(ga, coal.Transform3s(pa[:3, :3], pa[:3, 3]), gb, coal.Transform3s(pb[:3, :3], pb[:3, 3]),
                     request, result)
        contacts = result.getContacts()
        # Coal reports a signed distance per contact (negative when penetrating).
        depth = max((-c.penetration_depth if c.penetration_depth < 0 else c.penetration_depth for c in contacts),
                    default=0.0)
        return Outcome(len(contacts), depth)

    return run


def mujoco_method(s: Scenario, cache: Path, sdf: bool) -> Method | None:
    """Two free bodies on a model of their own; contacts from mj_collision after mj_kinematics. With `sdf`, each
    torus is MuJoCo's analytic torus SDF (plugin mujoco.sdf.torus, the exact shape: better than a mesh SDF); without,
    mesh geoms, which MuJoCo collides through their convex hulls (its mesh SDF needs the sdflib plugin, which the
    PyPI wheel does not ship)."""
    if importlib.util.find_spec("mujoco") is None:
        return None
    import mujoco

    if sdf:
        if s.a.name != "torus" or s.b.name != "torus":
            return None
        # The plugin's torus lies in its xy plane (axis z); the mesh's axis is y: rotate -90 degrees about x.
        q = f"{math.cos(-math.pi / 4)} {math.sin(-math.pi / 4)} 0 0"
        xml = f"""<mujoco>
  <extension><plugin plugin="mujoco.sdf.torus"><instance name="torus">
    <config key="radius1" value="{TORUS_R}"/><config key="radius2" value="{TORUS_r}"/>
  </instance></plugin></extension>
  <asset><mesh name="torus"><plugin instance="torus"/></mesh></asset>
  <option sdf_iterations="10" sdf_initpoints="40"/>
  <worldbody>
    <body name="a"><freejoint/><geom type="sdf" mesh="torus" quat="{q}"><plugin instance="torus"/></geom></body>
    <body name="b"><freejoint/><geom type="sdf" mesh="torus" quat="{q}"><plugin instance="torus"/></geom></body>
  </worldbody>
</mujoco>"""
    else:
        files = {}
        for m in (s.a, s.b):
            path = cache / f"mujoco-{m.name}.stl"
            if not path.exists():
                write_stl(path, m.vertices, m.faces)
            files[m.name] = path
        xml = f"""<mujoco>
  <asset><mesh name="ma" file="{files[s.a.name].resolve()}"/><mesh name="mb" file="{files[s.b.name].resolve()}"/></asset>
  <worldbody>
    <body name="a"><freejoint/><geom type="mesh" mesh="ma"/></body>
    <body name="b"><freejoint/><geom type="mesh" mesh="mb"/></body>
  </worldbody>
</mujoco>"""
    model = mujoco.MjModel.from_xml_string(xml)
    data = mujoco.MjData(model)

    def place(p: np.ndarray, at: int) -> None:
        # A free joint's qpos: position, then the orientation quaternion (w, x, y, z). The body frame is the
        # mesh frame (MuJoCo's re-centring of a mesh is in the geom's own pos/quat).
        quat = np.empty(4)
        mujoco.mju_mat2Quat(quat, np.ascontiguousarray(p[:3, :3]).flatten())
        data.qpos[at : at + 3] = p[:3, 3]
        data.qpos[at + 3 : at + 7] = quat

    def run(pa: np.ndarray, pb: np.ndarray) -> Outcome:
        place(pa, 0)
        place(pb, 7)
        mujoco.mj_kinematics(model, data)
        mujoco.mj_collision(model, data)
        n = int(data.ncon)
        depth = float(max(-data.contact.dist[:n].min(), 0.0)) if n else 0.0
        return Outcome(n, depth)

    return run


def write_stl(path: Path, vertices: np.ndarray, faces: np.ndarray) -> None:
    tri = vertices[faces]
    normals = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    normals /= np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-300)
    record = np.zeros(len(faces), dtype=[("n", "<f4", 3), ("v", "<f4", (3, 3)), ("attr", "<u2")])
    record["n"] = normals
    record["v"] = tri
    with open(path, "wb") as f:
        f.write(b"\0" * 80)
        f.write(np.uint32(len(faces)).tobytes())
        f.write(record.tobytes())


# ------------------------------------------------------------------------------------------------ timing


def percentile_us(samples_ns: list[int], q: float) -> float:
    return float(np.percentile(np.array(samples_ns) / 1000.0, q))


@dataclass
class MethodResult:
    method: str
    scenario: str
    poses: int
    p50_us: float
    p90_us: float
    mean_us: float
    contacts_mean: float
    touching_share: float
    depth_err_max_m: float | None
    skipped: str = ""
    extra: dict[str, Any] = field(default_factory=dict)


def time_method(name: str, run: Method, s: Scenario, reps: int, budget_s: float) -> MethodResult:
    samples: list[int] = []
    outcomes: list[Outcome] = []
    start = time.perf_counter()
    measured = 0
    for k in range(len(s.poses_a)):
        pa, pb = s.poses_a[k], s.poses_b[k]
        outcome = run(pa, pb)  # warm-up, and the outcome
        outcomes.append(outcome)
        for _ in range(reps):
            t0 = time.perf_counter_ns()
            run(pa, pb)
            samples.append(time.perf_counter_ns() - t0)
        measured += 1
        if time.perf_counter() - start > budget_s and measured >= 5:
            break
    depth_err = None
    if s.exact_depth is not None:
        exact = max(s.exact_depth, 0.0)
        depth_err = max(abs(o.depth - exact) for o in outcomes)
    return MethodResult(
        method=name,
        scenario=s.name,
        poses=measured,
        p50_us=percentile_us(samples, 50),
        p90_us=percentile_us(samples, 90),
        mean_us=float(np.mean(samples) / 1000.0),
        contacts_mean=float(np.mean([o.contacts for o in outcomes])),
        touching_share=float(np.mean([o.depth > 0 for o in outcomes])),
        depth_err_max_m=depth_err,
    )


def overhead(s: Scenario, iterations: int, rounds: int = 5) -> list[dict[str, Any]]:
    """Python contacts() vs the C++ loop on the same pose pairs: per pose, the best of `rounds` alternating runs
    of `iterations` calls each (the least disturbed by other processes), then the median over the poses. The
    row "far" moves B 10 m away: the query itself is then a bounding-sphere test, so what remains is the
    binding's cost alone."""
    rows = []
    cases = [("fine", None, s.poses_b), ("coarse", COARSE_BUDGET, s.poses_b)]
    far = s.poses_b.copy()
    far[:, :3, 3] += 10.0
    cases.append(("far", None, far))
    for label, budget, poses_b in cases:
        py, cpp = [], []
        for k in range(len(s.poses_a)):
            pa, pb = s.poses_a[k], poses_b[k]
            best_py = best_cpp = math.inf
            voxfmt.contacts(s.a.body, pa, s.b.body, pb, point_budget=budget)
            for _ in range(rounds):
                best_cpp = min(best_cpp, _voxfmt._time_query(s.a.body, pa, s.b.body, pb, iterations, budget, None, 0.0))
                t0 = time.perf_counter()
                for _ in range(iterations):
                    voxfmt.contacts(s.a.body, pa, s.b.body, pb, point_budget=budget)
                best_py = min(best_py, (time.perf_counter() - t0) / iterations)
            py.append(best_py)
            cpp.append(best_cpp)
        diff = np.array(py) - np.array(cpp)
        rows.append(
            {
                "scenario": s.name,
                "query": label,
                "poses": len(py),
                "iterations": iterations,
                "rounds": rounds,
                "python_us_median": float(np.median(py) * 1e6),
                "cpp_us_median": float(np.median(cpp) * 1e6),
                "overhead_us_median": float(np.median(diff) * 1e6),
                "overhead_us_p90": float(np.percentile(diff, 90) * 1e6),
            }
        )
    return rows


def batch_scaling(bunny: voxfmt.Body, poses_a: np.ndarray, poses_b: np.ndarray, threads: list[int],
                  repeats: int) -> list[dict[str, Any]]:
    rows = []
    base = None
    for t in threads:
        voxfmt.contacts_batch(bunny, poses_a[:100], bunny, poses_b[:100], threads=t)
        best = math.inf
        for _ in range(repeats):
            t0 = time.perf_counter()
            out = voxfmt.contacts_batch(bunny, poses_a, bunny, poses_b, threads=t)
            best = min(best, time.perf_counter() - t0)
        throughput = len(poses_a) / best
        base = base or throughput
        rows.append(
            {
                "threads": t,
                "poses": len(poses_a),
                "seconds_best_of": repeats,
                "seconds": best,
                "poses_per_s": throughput,
                "speedup": throughput / base,
                "touching_share": float(np.mean(out.max_depth > 0)),
            }
        )
    return rows


# ------------------------------------------------------------------------------------------------ main


def peer_version(module: str) -> str | None:
    if importlib.util.find_spec(module) is None:
        return None
    from importlib import metadata

    distribution = {"fcl": "python-fcl"}.get(module, module)
    try:
        return metadata.version(distribution)
    except metadata.PackageNotFoundError:
        return "unknown"


def markdown(report: dict[str, Any]) -> str:
    lines = [f"# voxfmt from Python and its peers ({report['machine']})", "", f"Command: `{report['command']}`",
             "", f"Load average at the start: {report['load_average_at_start']} (the machine is shared; "
             "times are wall-clock per call).", ""]
    if report.get("overhead"):
        lines += ["## contacts() overhead above the C++ call", "",
                  "| scenario | query | poses | Python µs | C++ µs | overhead µs (median) | overhead µs (p90) |",
                  "|---|---|---|---|---|---|---|"]
        for r in report["overhead"]:
            lines.append(f"| {r['scenario']} | {r['query']} | {r['poses']} | {r['python_us_median']:.2f} | "
                         f"{r['cpp_us_median']:.2f} | {r['overhead_us_median']:.2f} | {r['overhead_us_p90']:.2f} |")
        lines.append("")
    if report.get("batch"):
        lines += ["## contacts_batch, bunny on bunny", "", "| threads | poses | s | poses/s | speed-up |",
                  "|---|---|---|---|---|"]
        for r in report["batch"]:
            lines.append(f"| {r['threads']} | {r['poses']} | {r['seconds']:.3f} | {r['poses_per_s']:.0f} | "
                         f"{r['speedup']:.2f}× |")
        lines.append("")
    if report.get("peers"):
        lines += ["## Per pair, same poses", "",
                  "| scenario | method | poses | p50 µs | p90 µs | contacts (mean) | touching | depth error max (mm) |",
                  "|---|---|---|---|---|---|---|---|"]
        for r in report["peers"]:
            if r["skipped"]:
                lines.append(f"| {r['scenario']} | {r['method']} | – | – | – | – | – | not run: {r['skipped']} |")
                continue
            err = "–" if r["depth_err_max_m"] is None else f"{r['depth_err_max_m'] * 1000:.3f}"
            lines.append(f"| {r['scenario']} | {r['method']} | {r['poses']} | {r['p50_us']:.1f} | {r['p90_us']:.1f} | "
                         f"{r['contacts_mean']:.1f} | {r['touching_share']:.0%} | {err} |")
        lines.append("")
    return "\n".join(lines)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--parts", default="overhead,batch,peers")
    parser.add_argument("--bunny", default=os.environ.get("VOXFMT_BUNNY", "build/cgal-data/data/meshes/bunny00.off"))
    parser.add_argument("--cache", default="out/python-peers")
    parser.add_argument("--poses", type=int, default=20, help="poses per scenario for overhead and peers")
    parser.add_argument("--batch-poses", type=int, default=10000)
    parser.add_argument("--threads", default="1,2")
    parser.add_argument("--reps", type=int, default=20, help="timed repetitions per pose and method")
    parser.add_argument("--iterations", type=int, default=2000, help="calls per pose in the overhead part")
    parser.add_argument("--budget", type=float, default=60.0, help="seconds per method and scenario at most")
    parser.add_argument("--seed", type=int, default=20261122)
    parser.add_argument("--json")
    parser.add_argument("--markdown")
    args = parser.parse_args()
    parts = set(args.parts.split(","))
    cache = Path(args.cache)
    cache.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(args.seed)

    bunny = baked("bunny00-0.15m", Path(args.bunny), 0.15, cache)
    torus_path = cache / "torus-R0.05-r0.02-358x100.off"
    if not torus_path.exists():
        torus_off(torus_path)
    torus = baked("torus", torus_path, 1.0, cache)

    pa, pb = bunny_poses(bunny.body, args.poses, rng)
    scenarios = [Scenario("bunny-bunny", bunny, bunny, pa, pb, None,
                          "two 0.15 m bunnies, touching by voxfmt's fine query, then 0.5 mm short to 1.5 mm in")]
    pa, pb = tori_poses(args.poses, 2 * TORUS_r - STACK_OVERLAP, rng)
    scenarios.append(Scenario("tori-stacked", torus, torus, pa, pb, STACK_OVERLAP,
                              "two tori stacked on a common axis, 0.5 mm overlap along the whole ring"))
    pa, pb = tori_poses(args.poses, 2 * TORUS_r + STACK_GAP, rng)
    scenarios.append(Scenario("tori-gap", torus, torus, pa, pb, -STACK_GAP, "the same 1 mm apart"))

    report: dict[str, Any] = {
        "command": " ".join([Path(sys.argv[0]).as_posix()] + sys.argv[1:]),
        "machine": f"{platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}",
        "voxfmt": voxfmt.__version__,
        "voxfmt_module": os.path.relpath(voxfmt.__file__),
        "load_average_at_start": list(os.getloadavg()),
        "peer_versions": {name: peer_version(name) for name in ("coal", "fcl", "mujoco", "trimesh")},
        "scenarios": {s.name: s.description for s in scenarios},
    }
    if "overhead" in parts:
        report["overhead"] = [row for s in scenarios for row in overhead(s, args.iterations)]
    if "batch" in parts:
        ba, bb = bunny_poses(bunny.body, args.batch_poses, rng)
        report["batch"] = batch_scaling(bunny.body, ba, bb, [int(t) for t in args.threads.split(",")], 3)
    if "peers" in parts:
        rows = []
        for s in scenarios:
            methods: list[tuple[str, Method | None, str]] = [
                ("voxfmt-fine", voxfmt_method(s, None), ""),
                ("voxfmt-coarse", voxfmt_method(s, COARSE_BUDGET), ""),
            ]
            for name, factory, package in (("coal", coal_method, "coal"), ("fcl", fcl_method, "python-fcl")):
                methods.append((name, factory(s), f"{package} not installed"))
            methods.append(("mujoco-mesh", mujoco_method(s, cache, sdf=False), "mujoco not installed"))
            if s.a.name == "torus":
                methods.append(("mujoco-sdf", mujoco_method(s, cache, sdf=True), "mujoco not installed"))
            for name, run, why in methods:
                if run is None:
                    rows.append(MethodResult(name, s.name, 0, 0, 0, 0, 0, 0, None, skipped=why).__dict__)
                    continue
                print(f"{s.name}: {name}", file=sys.stderr)
                rows.append(time_method(name, run, s, args.reps, args.budget).__dict__)
        report["peers"] = rows
    text = json.dumps(report, indent=2)
    if args.json:
        Path(args.json).write_text(text + "\n")
    else:
        print(text)
    md = markdown(report)
    if args.markdown:
        Path(args.markdown).write_text(md + "\n")
    print(md, file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
