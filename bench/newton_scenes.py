#!/usr/bin/env python3
"""Newton (NVIDIA Warp) with voxfmt's SDFs against Newton with convex hulls, on the same scenes, initial states,
solvers and time step, in one process and one run: on the CPU device here (no GPU needed), and on a GPU unchanged.

    WARP_CACHE_PATH=.cache/warp PYTHONPATH=build/python .venv-newton/bin/python bench/newton_scenes.py \\
        --json F.json --markdown F.md [--quick] [--device cpu|cuda:0] [--scenes a,b] [--solvers xpbd,mujoco]

Methods (the same bodies, masses and shape settings but for the colliding geometry):
  voxfmt  each mesh a Newton mesh shape whose SDF is the baked asset's (voxfmt.newton: the texture SDF built from the
          asset; Newton's mesh-SDF contact, the triangle mesh's edges against the other body's SDF)
  hull    each dynamic or static mesh as Newton's convex hull of the same mesh (add_shape_convex_hull)

Solvers: Newton's XPBD (10 iterations) and the MuJoCo Warp solver (Newton's contacts, MuJoCo Warp's solver, set up
as Newton's nut-and-bolt SDF example sets it: Newton iterations, elliptic cones, contact stiffness 1e7, damping 1e4).

Scenes (z up, 1 ms steps, gravity 9.81 m/s^2):
  bunny-on-bunny  CGAL's bunny00.off (1 m) upright, dropped half-overlapping (0.25 m off-centre, 5 cm above) onto a
                  static one standing on a box floor, inside four walls (box shapes) that keep it from tumbling off
  peg-0.2mm       a chamfered steel peg (radius 5 mm, 30 mm long; examples/mujoco/shapes.py) released 2 mm above a
                  static block's chamfered blind hole (20 mm deep, 0.2 mm radial clearance), 0.3 mm off its axis
  torus-in-torus  a torus (R 5 cm, r 2 cm) standing upright, dropped centred over a static one lying flat: with
                  its real shape its lower arc enters the other's hole; a hull is a disc that holds it on top

Figures per run: outcome (final speed and whether the body came to rest, < 1 mm/s; the peg's inserted depth; the
dropped body's height), the deepest penetration of the two real shapes at the end (voxfmt's runtime query of the
two assets: the same referee for both methods), wall time per step (collision + solver, median and p99 after the
first step) and the one-off setup (SDF build from the asset, model finalize). Kernel compilation is not timed
(Warp caches it: the first run of a scene compiles). The card or CPU is named in the output.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "examples" / "mujoco"))
import shapes  # noqa: E402  (examples/mujoco/shapes.py: the peg, the block and the torus)

import voxfmt  # noqa: E402
import voxfmt.newton as vn  # noqa: E402

newton, wp = vn.newton, vn.wp
TIMESTEP = 0.001
REST_SPEED = 1e-3  # m/s
UPRIGHT = wp.quat_from_axis_angle(wp.vec3(1.0, 0.0, 0.0), math.pi / 2)  # the bunny mesh is +Y up


@dataclass
class Part:
    name: str
    mesh: tuple[np.ndarray, np.ndarray]  # vertices, triangles in the asset's frame
    asset: Path
    pose: Any  # wp.transform of the asset frame in the world
    static: bool
    density: float = 1000.0


@dataclass
class Scene:
    name: str
    parts: list[Part]
    seconds: float
    cfg: dict
    walls: list[tuple[tuple[float, float, float], tuple[float, float, float]]]  # box centres and half sizes


def baked(name: str, mesh: tuple[np.ndarray, np.ndarray], cache: Path, **settings: Any) -> Path:
    """The mesh written as OFF and baked into the cache on first use."""
    cache.mkdir(parents=True, exist_ok=True)
    off = cache / f"{name}.off"
    asset = cache / f"{name}.vox.h5"
    if not asset.exists():
        shapes.write_off(off, *mesh)
        voxfmt.bake(off, asset, **settings)
    return asset


def make_scenes(cache: Path, quick: bool) -> dict[str, Scene]:
    scenes = {}
    bunny_path = ROOT / "build/cgal-data/data/meshes/bunny00.off"
    bunny = voxfmt.read_mesh(bunny_path)
    bunny_asset = baked("bunny00", bunny, cache, resolution=128 if quick else 306, points=10000)
    # Upright, the bunny's lowest point (its mesh y) is at -0.386 m: standing on the floor (z = 0) its origin is there.
    stand = float(-bunny[0][:, 1].min())
    top = stand + float(bunny[0][:, 1].max())
    scenes["bunny-on-bunny"] = Scene(
        "bunny-on-bunny",
        [
            Part("bunny-static", bunny, bunny_asset, wp.transform((0.0, 0.0, stand), UPRIGHT), True),
            Part("bunny", bunny, bunny_asset, wp.transform((0.25, 0.0, top + stand + 0.05), UPRIGHT), False),
        ],
        0.5 if quick else 3.0,
        {"mu": 0.5, "gap": 0.01},
        [((0, 0.0, -0.05), (1.0, 1.0, 0.05))]
        + [((x, 0.0, 1.0), (0.05, 1.0, 1.0)) for x in (-0.95, 0.95)]
        + [((0.0, y, 1.0), (1.0, 0.05, 1.0)) for y in (-0.95, 0.95)],
    )
    s = shapes.PegInHole(clearance=0.2e-3)
    voxel = 0.13e-3 if not quick else 0.3e-3
    peg = shapes.peg_mesh(s)
    block = shapes.hole_block_mesh(s)
    scenes["peg-0.2mm"] = Scene(
        "peg-0.2mm",
        [
            Part("block", block, baked(f"block-0.2-{voxel}", block, cache, voxel_size=voxel, points=20000),
                 wp.transform_identity(), True),
            Part("peg", peg, baked(f"peg-{voxel}", peg, cache, voxel_size=voxel, points=20000),
                 wp.transform((0.0003, 0.0, s.block_height + 0.002), wp.quat_identity()), False, 7800.0),
        ],
        0.2 if quick else 0.5,
        {"mu": 0.3, "gap": 0.0005},
        [],
    )
    torus = shapes.torus_mesh(0.05, 0.02, 120, 40)
    torus_asset = baked("torus-120x40", torus, cache, resolution=96 if quick else 160, points=8000)
    standing = wp.quat_from_axis_angle(wp.vec3(1.0, 0.0, 0.0), math.pi / 2)
    scenes["torus-in-torus"] = Scene(
        "torus-in-torus",
        [
            Part("torus-flat", torus, torus_asset, wp.transform((0.0, 0.0, 0.02), wp.quat_identity()), True),
            Part("torus", torus, torus_asset, wp.transform((0.0, 0.0, 0.04 + 0.07 + 0.005), standing), False),
        ],
        0.5 if quick else 1.5,
        {"mu": 0.5, "gap": 0.003},
        [((0, 0.0, -0.05), (0.5, 0.5, 0.05))],
    )
    return scenes


def build(scene: Scene, method: str, device: Any) -> tuple[Any, list[int], float]:
    """The scene's model (bodies in Part order, statics at -1) and the seconds its SDFs took to build."""
    builder = newton.ModelBuilder()
    # Contact stiffness and damping as Newton's nut-and-bolt example sets them for the MuJoCo solver (XPBD's contacts
    # are positional and do not read them).
    cfg = newton.ModelBuilder.ShapeConfig(mu=scene.cfg["mu"], gap=scene.cfg["gap"], margin=0.0, ke=1e7, kd=1e4)
    for centre, half in scene.walls:
        builder.add_shape_box(-1, xform=wp.transform(centre, wp.quat_identity()), hx=half[0], hy=half[1], hz=half[2],
                              cfg=cfg)
    bodies, sdf_seconds = [], 0.0
    for part in scene.parts:
        body = -1 if part.static else builder.add_body(xform=part.pose)
        xform = part.pose if part.static else None
        part_cfg = newton.ModelBuilder.ShapeConfig(mu=cfg.mu, gap=cfg.gap, margin=0.0, ke=cfg.ke, kd=cfg.kd,
                                                   density=part.density)
        if method == "voxfmt":
            start = time.perf_counter()
            vn.add_shape(builder, body, voxfmt.load(part.asset), part.mesh, xform=xform, cfg=part_cfg, device=device)
            sdf_seconds += time.perf_counter() - start
        else:
            mesh = newton.Mesh(np.asarray(part.mesh[0], np.float32), np.asarray(part.mesh[1], np.int32).reshape(-1))
            builder.add_shape_convex_hull(body, xform=xform, mesh=mesh, cfg=part_cfg)
        bodies.append(body)
    return vn.finalize(builder, device) if method == "voxfmt" else builder.finalize(device=device), bodies, sdf_seconds


def solver_for(model: Any, name: str) -> Any:
    if name == "xpbd":
        return newton.solvers.SolverXPBD(model, iterations=10)
    # Newton's contacts, MuJoCo Warp's solver, configured as Newton's nut-and-bolt example does.
    return newton.solvers.SolverMuJoCo(model, use_mujoco_contacts=False, solver="newton", integrator="implicitfast",
                                       cone="elliptic", iterations=15, ls_iterations=100, impratio=1.0, njmax=2000,
                                       nconmax=2000)


def pose_matrix(q: np.ndarray) -> np.ndarray:
    """A 4x4 matrix from Warp's transform (px, py, pz, qx, qy, qz, qw)."""
    x, y, z, w = q[3:7] / np.linalg.norm(q[3:7])
    m = np.eye(4)
    m[:3, :3] = [
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ]
    m[:3, 3] = q[:3]
    return m


def run(scene: Scene, method: str, solver_name: str, device: Any) -> dict:
    start = time.perf_counter()
    model, bodies, sdf_seconds = build(scene, method, device)
    setup = time.perf_counter() - start
    pipeline = newton.CollisionPipeline(model)
    contacts = pipeline.contacts()
    solver = solver_for(model, solver_name)
    s0, s1, control = model.state(), model.state(), model.control()
    steps = int(round(scene.seconds / TIMESTEP))
    times = []
    dynamic = next(b for b, p in zip(bodies, scene.parts) if not p.static)
    part = scene.parts[bodies.index(dynamic)]
    lowest = math.inf
    for _ in range(steps):
        t0 = time.perf_counter()
        s0.clear_forces()
        pipeline.collide(s0, contacts)
        solver.step(s0, s1, control, contacts, TIMESTEP)
        s0, s1 = s1, s0
        wp.synchronize_device(device)
        times.append(time.perf_counter() - t0)
        lowest = min(lowest, float(s0.body_q.numpy()[dynamic][2]))
    q = s0.body_q.numpy()[dynamic]
    qd = s0.body_qd.numpy()[dynamic]
    speed = float(np.linalg.norm(qd[:3]))
    finite = bool(np.all(np.isfinite(q)))
    # The referee: voxfmt's runtime query of the two real shapes at their final poses.
    statics = [p for p in scene.parts if p.static]
    depth = None
    if finite and statics:
        a, b = voxfmt.load(statics[0].asset), voxfmt.load(part.asset)
        pose_a = pose_matrix(np.array([*statics[0].pose.p, *statics[0].pose.q]))
        found = voxfmt.contacts(a, pose_a, b, pose_matrix(q))
        depth = float(found.max_depth) if len(found) else 0.0
    result = {
        "scene": scene.name,
        "method": method,
        "solver": solver_name,
        "steps": steps,
        "final_speed_m_s": speed if finite else None,
        "at_rest": bool(finite and speed < REST_SPEED),
        "final_height_m": float(q[2]) if finite else None,
        "lowest_height_m": lowest if finite else None,
        "deepest_penetration_m": depth,
        "step_ms_p50": float(np.median(times[1:]) * 1e3),
        "step_ms_p99": float(np.percentile(times[1:], 99) * 1e3),
        "setup_s": setup,
        "sdf_build_s": sdf_seconds if method == "voxfmt" else None,
    }
    if scene.name.startswith("peg"):
        s = shapes.PegInHole(clearance=0.2e-3)
        inserted = s.block_height - float(q[2])
        result["inserted_m"] = inserted if finite else None
        result["inserted"] = bool(finite and abs(inserted - s.hole_depth) < 0.5e-3)
    return result


def device_name(device: Any) -> str:
    d = wp.get_device(device)
    if d.is_cuda:
        return d.name
    model = "unknown CPU"
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                model = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return f"{model} ({os.cpu_count()} cores)"


def markdown(report: dict) -> str:
    lines = [
        f"Newton {report['newton']} / Warp {report['warp']} on {report['device']}, {report['timestep_s'] * 1e3:g} ms steps.",
        "",
        "| scene | solver | method | at rest | final speed (m/s) | outcome | deepest penetration (mm) | step p50 / p99 (ms) |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in report["runs"]:
        if "inserted_m" in r:
            outcome = f"inserted {r['inserted_m'] * 1e3:.2f} mm" + (" (fully in)" if r["inserted"] else " (not in)")
        else:
            outcome = "diverged" if r["final_height_m"] is None else f"height {r['final_height_m']:.4f} m"
        depth = "—" if r["deepest_penetration_m"] is None else f"{r['deepest_penetration_m'] * 1e3:.3f}"
        speed = "—" if r["final_speed_m_s"] is None else f"{r['final_speed_m_s']:.1e}"
        lines.append(
            f"| {r['scene']} | {r['solver']} | {r['method']} | {'yes' if r['at_rest'] else 'no'} | {speed} | {outcome} "
            f"| {depth} | {r['step_ms_p50']:.2f} / {r['step_ms_p99']:.2f} |"
        )
    return "\n".join(lines) + "\n"


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--json", help="write the figures here")
    ap.add_argument("--markdown", help="write the table here")
    ap.add_argument("--quick", action="store_true", help="coarser assets and shorter runs (CI)")
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--scenes", default="bunny-on-bunny,peg-0.2mm,torus-in-torus")
    ap.add_argument("--solvers", default="xpbd,mujoco")
    ap.add_argument("--methods", default="voxfmt,hull")
    ap.add_argument("--cache", default=str(ROOT / "out/newton-scenes"))
    args = ap.parse_args()
    wp.config.quiet = True
    scenes = make_scenes(Path(args.cache), args.quick)
    unknown = [s for s in args.scenes.split(",") if s not in scenes]
    if unknown:
        print(f"newton_scenes: unknown scene(s) {unknown}; known: {sorted(scenes)}", file=sys.stderr)
        return 2
    runs = []
    for name in args.scenes.split(","):
        for solver in args.solvers.split(","):
            for method in args.methods.split(","):
                r = run(scenes[name], method, solver, args.device)
                runs.append(r)
                print(json.dumps(r), flush=True)
    report = {
        "newton": newton.__version__,
        "warp": wp.__version__,
        "voxfmt": voxfmt.__version__,
        "device": device_name(args.device),
        "platform": platform.platform(),
        "timestep_s": TIMESTEP,
        "quick": args.quick,
        "runs": runs,
    }
    if args.json:
        Path(args.json).write_text(json.dumps(report, indent=2) + "\n")
    table = markdown(report)
    if args.markdown:
        Path(args.markdown).write_text(table)
    print(table)
    return 0


if __name__ == "__main__":
    sys.exit(main())
