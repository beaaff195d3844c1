#!/usr/bin/env python3
"""The way to a Warp volume on the CPU today, OpenVDB's `vdb_tool -mesh2ls ... -write x.nvdb`, against voxfmt's
`voxfmt build` + `voxfmt export --nvdb`, on the same meshes at the same voxel size, in one run: time, peak memory,
file size, and accuracy against exact distances, both files sampled by NVIDIA Warp (CPU device).

    PYTHONPATH=build/python .venv-newton/bin/python bench/nvdb_vs_vdb_tool.py --json F.json --markdown F.md \\
        [--quick] [--meshes DIR] [--resolution 128]

Methods:
  vdb_tool  Debian's OpenVDB 10 vdb_tool: -read MESH.obj -mesh2ls voxel=h width=3 -write X.nvdb (a float level set
            of half-width 3 voxels, uncompressed; its inactive values are +-3 voxels, signs by OpenVDB's flood fill)
  voxfmt    voxfmt build MESH --voxel-size h (band 3) then voxfmt export --nvdb (ZIP): the "distance" level set of
            half-width 2.5 voxels and the "coarse" grid, sampled together as voxfmt.warp.sample_distance does
Both read the same triangles: the mesh as voxfmt's import reads it (assimp), written as OBJ for vdb_tool. The voxel
size h is the mesh's longest bounding-box side / --resolution.

Reference (per mesh, a fixed random set of points): the exact unsigned distance to the triangles (every triangle,
double precision), signed by the parity of a ray's crossings for a closed mesh (every edge shared by two faces:
right whatever the file's face orientation) and otherwise by the generalized winding number (inside where its
magnitude is at least 1/2, the spec's rule; points where it is within 0.1 of 1/2, beside a sheet or across a
hole's cap, count for neither sign). A surface that encloses nothing (voxfmt makes it a shell, SHELL_MODE) has no
inside: its points count for neither method's signs or band error. Points: 2/3 within 2 voxels of the surface (surface samples moved along
their normals), 1/3 anywhere in the box grown by 2 voxels.

Accuracy is measured at each method's own grid points (the reference points moved to the nearest one): there its
values are its samples; between them both interpolate trilinearly, which errs across the distance's kinks and
curvature alike. Figures per mesh and method: wall time and peak resident memory of the tools (GNU time), file
bytes; band error (voxels, grid points within 2 voxels of the surface whose sign is right), wrong signs (grid points
more than 0.1 voxel from the surface whose sign differs from the reference's), depth error beyond the band
(grid points more than 4 voxels inside: |sampled - exact|, voxels). Meshes either tool fails on are listed with the
failure.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
import warp as wp

ROOT = Path(__file__).resolve().parent.parent
import voxfmt  # noqa: E402
import voxfmt.warp  # noqa: E402

QUICK_MESHES = ["bunny00.off", "open_cube.off", "cube-ouvert.off", "elephant.off", "mushroom.off"]


# ------------------------------------------------------------------------------------------------- reference


def closest_distance(points: np.ndarray, tri: np.ndarray) -> np.ndarray:
    """Exact unsigned distance from each point to the nearest of triangles tri (T, 3, 3), chunked (Ericson's
    closest point on a triangle, vectorised)."""
    best = np.full(len(points), np.inf)
    a, b, c = tri[:, 0], tri[:, 1], tri[:, 2]
    ab, ac = b - a, c - a
    for start in range(0, len(points), 64):
        p = points[start:start + 64, None, :]
        ap = p - a
        d1, d2 = np.einsum("ptk,tk->pt", ap, ab), np.einsum("ptk,tk->pt", ap, ac)
        bp = p - b
        d3, d4 = np.einsum("ptk,tk->pt", bp, ab), np.einsum("ptk,tk->pt", bp, ac)
        cp = p - c
        d5, d6 = np.einsum("ptk,tk->pt", cp, ab), np.einsum("ptk,tk->pt", cp, ac)
        va, vb, vc = d3 * d6 - d5 * d4, d5 * d2 - d1 * d6, d1 * d4 - d3 * d2
        with np.errstate(divide="ignore", invalid="ignore"):
            denom = va + vb + vc
            v = np.where(denom != 0, vb / denom, 0.0)
            w = np.where(denom != 0, vc / denom, 0.0)
            # Regions, from the most specific: vertices, edges, the face.
            t_ab = np.clip(d1 / (d1 - d3), 0, 1)
            t_ac = np.clip(d2 / (d2 - d6), 0, 1)
            t_bc = np.clip((d4 - d3) / ((d4 - d3) + (d5 - d6)), 0, 1)
        q = a + v[..., None] * ab + w[..., None] * ac
        edge_ab = (vc <= 0) & (d1 >= 0) & (d3 <= 0)
        edge_ac = (vb <= 0) & (d2 >= 0) & (d6 <= 0)
        edge_bc = (va <= 0) & ((d4 - d3) >= 0) & ((d5 - d6) >= 0)
        q = np.where(edge_bc[..., None], b + np.nan_to_num(t_bc)[..., None] * (c - b), q)
        q = np.where(edge_ac[..., None], a + np.nan_to_num(t_ac)[..., None] * ac, q)
        q = np.where(edge_ab[..., None], a + np.nan_to_num(t_ab)[..., None] * ab, q)
        q = np.where(((d6 >= 0) & (d5 <= d6))[..., None], c, q)
        q = np.where(((d3 >= 0) & (d4 <= d3))[..., None], b, q)
        q = np.where(((d1 <= 0) & (d2 <= 0))[..., None], a, q)
        best[start:start + 64] = np.sqrt(((p - q) ** 2).sum(-1)).min(axis=1)
    return best


def winding_number(points: np.ndarray, tri: np.ndarray) -> np.ndarray:
    """Generalized winding number (Jacobson et al. 2013): the triangles' signed solid angles / 4 pi."""
    out = np.zeros(len(points))
    for start in range(0, len(points), 16):
        p = points[start:start + 16, None, None, :]
        r = tri[None] - p  # (P, T, 3, 3)
        n = np.linalg.norm(r, axis=-1)
        a, b, c = r[..., 0, :], r[..., 1, :], r[..., 2, :]
        det = np.einsum("ptk,ptk->pt", a, np.cross(b, c))
        la, lb, lc = n[..., 0], n[..., 1], n[..., 2]
        denom = (la * lb * lc + np.einsum("ptk,ptk->pt", a, b) * lc + np.einsum("ptk,ptk->pt", b, c) * la
                 + np.einsum("ptk,ptk->pt", c, a) * lb)
        out[start:start + 16] = (2 * np.arctan2(det, denom)).sum(axis=1) / (4 * np.pi)
    return out


def ray_parity_inside(points: np.ndarray, tri: np.ndarray) -> np.ndarray:
    """Inside a closed mesh by the parity of a ray's crossings (any orientation of its faces), along a fixed
    direction off every axis (Moeller-Trumbore, vectorised)."""
    direction = np.array([0.8017, 0.3315, 0.4975])
    a, e1, e2 = tri[:, 0], tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    pvec = np.cross(direction, e2)
    det = np.einsum("tk,tk->t", e1, pvec)
    ok = np.abs(det) > 1e-300
    inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
    crossings = np.zeros(len(points), dtype=np.int64)
    for start in range(0, len(points), 64):
        t = points[start:start + 64, None, :] - a
        u = np.einsum("ptk,tk->pt", t, pvec) * inv
        q = np.cross(t, e1)
        v = np.einsum("k,ptk->pt", direction, q) * inv
        dist = np.einsum("ptk,tk->pt", q, e2) * inv
        hit = ok & (u >= 0) & (v >= 0) & (u + v <= 1) & (dist > 0)
        crossings[start:start + 64] = hit.sum(axis=1)
    return crossings % 2 == 1


def is_closed(triangles: np.ndarray) -> bool:
    """Every edge shared by exactly two triangles (whatever their orientation)."""
    edges = np.sort(np.concatenate([triangles[:, [0, 1]], triangles[:, [1, 2]], triangles[:, [2, 0]]]), axis=1)
    _, counts = np.unique(edges, axis=0, return_counts=True)
    return bool(len(counts)) and bool(np.all(counts == 2))


def reference_points(vertices: np.ndarray, triangles: np.ndarray, h: float, count: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    tri = vertices[triangles]
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    near = 2 * count // 3
    pick = rng.choice(len(tri), size=near, p=area / area.sum())
    u, v = rng.random(near), rng.random(near)
    flip = u + v > 1
    u[flip], v[flip] = 1 - u[flip], 1 - v[flip]
    t = tri[pick]
    surface = t[:, 0] + u[:, None] * (t[:, 1] - t[:, 0]) + v[:, None] * (t[:, 2] - t[:, 0])
    normal = np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])
    normal /= np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-300)
    surface += normal * rng.uniform(-2 * h, 2 * h, size=(near, 1))
    lo, hi = vertices.min(0) - 2 * h, vertices.max(0) + 2 * h
    box = rng.uniform(lo, hi, size=(count - near, 3))
    return np.concatenate([surface, box])


# ------------------------------------------------------------------------------------------------- the tools


def timed(command: list[str], work: Path) -> tuple[int, float, float, str]:
    """Exit status, wall seconds and peak resident MiB of a command (GNU time's figures: the command's own, not
    this Python's), and its stderr's end."""
    report = work / "time.txt"
    r = subprocess.run(["/usr/bin/time", "-f", "%e %M", "-o", str(report), *command], stdout=subprocess.DEVNULL,
                       stderr=subprocess.PIPE, text=True)
    seconds, kib = report.read_text().split()[-2:]
    return r.returncode, float(seconds), float(kib) / 1024, r.stderr[-300:]


@wp.kernel
def _sample_level_set(volume: wp.uint64, points: wp.array(dtype=wp.vec3), out: wp.array(dtype=float)):
    i = wp.tid()
    out[i] = wp.volume_sample_f(volume, wp.volume_world_to_index(volume, points[i]), wp.Volume.LINEAR)


@wp.kernel
def _sample_voxfmt(distance: wp.uint64, coarse: wp.uint64, width: float, points: wp.array(dtype=wp.vec3),
                   out: wp.array(dtype=float)):
    i = wp.tid()
    out[i] = voxfmt.warp.sample_distance(distance, coarse, width, points[i])


def sample_file(path: Path, points: np.ndarray, level_set_width: float | None) -> np.ndarray:
    """The file's first grid sampled at the points; with `level_set_width` (voxfmt's files), the level set and the
    coarse grid after it, as voxfmt.warp.sample_distance reads them."""
    volume = wp.Volume.load_from_nvdb(path.read_bytes(), device="cpu")
    pts = wp.array(points.astype(np.float32), dtype=wp.vec3, device="cpu")
    out = wp.zeros(len(points), dtype=float, device="cpu")
    if level_set_width is not None:
        coarse = volume.load_next_grid()
        wp.launch(_sample_voxfmt, dim=len(points), inputs=[volume.id, coarse.id, level_set_width, pts, out],
                  device="cpu")
    else:
        wp.launch(_sample_level_set, dim=len(points), inputs=[volume.id, pts, out], device="cpu")
    return out.numpy().astype(np.float64)


def measure(mesh: Path, work: Path, resolution: int, points: int) -> dict:
    vertices, triangles = voxfmt.read_mesh(mesh)
    if len(triangles) == 0:
        return {"mesh": mesh.name, "error": "no triangles"}
    h = float((vertices.max(0) - vertices.min(0)).max()) / resolution
    obj = work / (mesh.stem + ".obj")
    with obj.open("w") as f:
        f.write("".join(f"v {x:.17g} {y:.17g} {z:.17g}\n" for x, y, z in vertices))
        f.write("".join(f"f {a + 1} {b + 1} {c + 1}\n" for a, b, c in triangles))
    result: dict = {"mesh": mesh.name, "triangles": int(len(triangles)), "voxel_size": h}
    # voxfmt: bake, then export.
    asset, ours = work / (mesh.stem + ".vox.h5"), work / (mesh.stem + ".voxfmt.nvdb")
    code, bake_s, bake_mib, err = timed([os.environ["VOXFMT_BIN"], "build", str(mesh), "-o", str(asset),
                                         "--voxel-size", repr(h), "--points", "1000", "-q"], work)
    if code == 0:
        code, export_s, export_mib, err = timed([os.environ["VOXFMT_BIN"], "export", str(asset), "--nvdb", str(ours)],
                                                work)
    result["voxfmt"] = ({"error": err.strip().splitlines()[-1] if err.strip() else f"exit {code}"} if code else
                        {"seconds": bake_s + export_s, "bake_s": bake_s, "export_s": export_s,
                         "peak_mib": max(bake_mib, export_mib), "bytes": ours.stat().st_size,
                         "asset_bytes": asset.stat().st_size})
    # vdb_tool.
    theirs = work / (mesh.stem + ".vdb_tool.nvdb")
    code, seconds, mib, err = timed(["vdb_tool", "-read", str(obj), "-mesh2ls", f"voxel={h!r}", "width=3",
                                     "-write", str(theirs)], work)
    result["vdb_tool"] = ({"error": err.strip().splitlines()[-1] if err.strip() else f"exit {code}"}
                          if code or not theirs.exists() else
                          {"seconds": seconds, "peak_mib": mib, "bytes": theirs.stat().st_size})
    # A surface that encloses nothing (voxfmt bakes it as a shell two voxels thick, SHELL_MODE) has no inside to get
    # right: its points count for neither method's signs or band.
    closed = is_closed(triangles)
    sheet = "error" not in result["voxfmt"] and any(c == "SHELL_MODE" for c, _ in voxfmt.load(asset).build_warnings)
    result["closed"], result["sheet"] = closed, sheet
    # Accuracy against the reference, at each method's own grid points (where its values are samples, not
    # interpolations: trilinear interpolation of any distance field errs across its kinks and curvature).
    p = reference_points(vertices, triangles, h, points, seed=len(triangles))
    tri = vertices[triangles]
    for method, path in (("voxfmt", ours), ("vdb_tool", theirs)):
        if "error" in result[method]:
            continue
        # Index (0, 0, 0) of the grid, as Warp reads its transform (voxfmt: the asset's voxel (0, 0, 0)).
        info = wp.Volume.load_from_nvdb(path.read_bytes(), device="cpu").get_grid_info()
        origin = np.asarray(info.translation, dtype=np.float64)
        nodes = origin + np.round((p - origin) / h) * h
        unsigned = closest_distance(nodes, tri)
        if closed:  # the parity of crossings: right whatever the file's face orientation
            inside = ray_parity_inside(nodes, tri)
            ambiguous = np.zeros(len(nodes), dtype=bool)
        else:  # the spec's rule; either orientation of a part is its inside
            winding = np.abs(winding_number(nodes, tri))
            inside = winding >= 0.5
            ambiguous = np.abs(winding - 0.5) <= 0.1
        exact = np.where(inside, -1.0, 1.0) * unsigned
        # voxfmt export's default width: the band voxfmt build stores completely (its default band 3, less 1/2).
        sampled = sample_file(path, nodes, 2.5 * h if method == "voxfmt" else None)
        # Where the winding number is near 1/2 (beside an open sheet, across a hole's cap) the inside is a matter of
        # rounding: such points count for neither sign.
        signed = (np.abs(exact) > 0.1 * h) & ~ambiguous & ~sheet
        wrong = signed & (np.sign(sampled) != np.sign(exact))
        band = (np.abs(exact) < 2 * h) & ~wrong & ~ambiguous & ~sheet
        deep = exact < -4 * h
        error = np.abs(sampled - exact) / h
        result[method].update({
            "band_points": int(band.sum()),
            "band_error_voxels_max": float(error[band].max()) if band.any() else None,
            "wrong_signs": int(wrong.sum()),
            "signed_points": int(signed.sum()),
            "deep_points": int(deep.sum()),
            "deep_error_voxels_max": float(error[deep].max()) if deep.any() else None,
            "deep_error_voxels_mean": float(error[deep].mean()) if deep.any() else None,
        })
    return result


def markdown(report: dict) -> str:
    rows = [r for r in report["meshes"] if "voxfmt" in r]
    lines = [
        f"voxfmt {report['voxfmt']} against OpenVDB {report['openvdb']}'s vdb_tool on {report['machine']}, "
        f"{len(rows)} meshes at {report['resolution']} voxels across, {report['points']} points each.",
        "",
        "| | voxfmt build + export | vdb_tool -mesh2ls |",
        "|---|---|---|",
    ]
    s = report["summary"]
    for key, label, fmt in (
        ("failed", "meshes failed", "{:d}"),
        ("seconds", "time, all meshes (s)", "{:.1f}"),
        ("peak_mib_max", "peak memory, largest (MiB)", "{:.0f}"),
        ("bytes", "files, all meshes (MB)", "{:.1f}"),
        ("band_error_voxels_max", "band error, worst mesh (voxels)", "{:.2e}"),
        ("meshes_with_wrong_signs", "meshes with wrong signs", "{:d}"),
        ("wrong_signs", "wrong signs, all points", "{:d}"),
        ("deep_error_voxels_max", "depth error beyond the band, worst (voxels)", "{:.1f}"),
        ("deep_error_voxels_mean", "depth error beyond the band, mean (voxels)", "{:.2f}"),
    ):
        lines.append(f"| {label} | {fmt.format(s['voxfmt'][key])} | {fmt.format(s['vdb_tool'][key])} |")
    lines += ["", "Meshes where either has wrong signs or fails:", "",
              "| mesh | triangles | voxfmt wrong signs | vdb_tool wrong signs | failure |", "|---|---|---|---|---|"]
    for r in rows:
        ours, theirs = r["voxfmt"], r["vdb_tool"]
        bad = ours.get("wrong_signs", 0) or theirs.get("wrong_signs", 0) or "error" in ours or "error" in theirs
        if bad:
            fail = "; ".join(f"{m}: {r[m]['error']}" for m in ("voxfmt", "vdb_tool") if "error" in r[m])
            lines.append(f"| {r['mesh']} | {r['triangles']} | {ours.get('wrong_signs', '—')} | "
                         f"{theirs.get('wrong_signs', '—')} | {fail} |")
    return "\n".join(lines) + "\n"


def summarise(rows: list[dict]) -> dict:
    out = {}
    for method in ("voxfmt", "vdb_tool"):
        ok = [r[method] for r in rows if "error" not in r[method]]
        deep = [m for m in ok if m["deep_error_voxels_max"] is not None]
        out[method] = {
            "failed": sum(1 for r in rows if "error" in r[method]),
            "seconds": sum(m["seconds"] for m in ok),
            "peak_mib_max": max(m["peak_mib"] for m in ok),
            "bytes": sum(m["bytes"] for m in ok) / 1e6,
            "band_error_voxels_max": max(m["band_error_voxels_max"] or 0 for m in ok),
            "meshes_with_wrong_signs": sum(1 for m in ok if m["wrong_signs"]),
            "wrong_signs": sum(m["wrong_signs"] for m in ok),
            "deep_error_voxels_max": max((m["deep_error_voxels_max"] for m in deep), default=0.0),
            "deep_error_voxels_mean": float(np.mean([m["deep_error_voxels_mean"] for m in deep])) if deep else 0.0,
        }
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--json")
    ap.add_argument("--markdown")
    ap.add_argument("--quick", action="store_true", help=f"only {', '.join(QUICK_MESHES)} and the broken shelf")
    ap.add_argument("--meshes", default=str(ROOT / "build/cgal-data/data/meshes"))
    ap.add_argument("--resolution", type=int, default=128)
    ap.add_argument("--points", type=int, default=500)
    args = ap.parse_args()
    wp.config.quiet = True
    os.environ.setdefault("VOXFMT_BIN", str(ROOT / "build/bin/voxfmt"))
    with tempfile.TemporaryDirectory() as folder:
        work = Path(folder)
        shelf = work / "broken-shelf.off"
        subprocess.run([sys.executable, str(ROOT / "bench/make_shelf.py"), "broken", str(shelf)], check=True)
        meshes = [Path(args.meshes) / m for m in QUICK_MESHES] if args.quick else sorted(Path(args.meshes).iterdir())
        rows = []
        for mesh in [*meshes, shelf]:
            try:
                row = measure(mesh, work, args.resolution, args.points)
            except voxfmt.Error as error:
                row = {"mesh": mesh.name, "error": f"{error.code}: {error}"}
            rows.append(row)
            print(json.dumps(row), flush=True)
    tool_version = subprocess.run(["vdb_tool", "-version"], capture_output=True, text=True).stdout.strip()
    report = {
        "voxfmt": voxfmt.__version__,
        "openvdb": tool_version.splitlines()[-1] if tool_version else "10",
        "machine": f"{platform.processor() or platform.machine()}, {os.cpu_count()} cores",
        "resolution": args.resolution,
        "points": args.points,
        "meshes": rows,
        "summary": summarise([r for r in rows if "voxfmt" in r]),
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
