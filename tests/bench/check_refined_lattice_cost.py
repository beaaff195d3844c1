"""bench/refined_lattice/refined_lattice_cost.cpp on a baked box: it runs, and what it finds holds.

    python tests/bench/check_refined_lattice_cost.py VOXFMT REFINED_LATTICE_COST WORKDIR

A box (not a cube) is baked small; the tool must find every lattice value at or above the exact distance to the
mesh (spec §3.3: the lattice never under-estimates), flag some of the coarse bricks near the surface (a 16-voxel
reach covers the whole small grid), count its new points as the flags imply (19 a flagged brick at most, at least
one), and finish with no distance above its bound; with `--carry`, the distances found without a search are
never below the exact ones and, on a box's few large faces, equal to them. A finely meshed torus then makes the
carried distances walk over the surface (a walk here finds the exact ones) and settle: none below exact, all
within a voxel of it; the corners' triangles alone (`--carry-steps corners`) neither walk nor offer, and are never
nearer than the full carry. Exits non-zero with the first failure.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import h5py

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "examples" / "mujoco"))
from check_estimate_transform import bake_box  # noqa: E402
from shapes import torus_mesh, write_off  # noqa: E402


def main() -> int:
    voxfmt_cli, tool, work = sys.argv[1], sys.argv[2], Path(sys.argv[3])
    asset = bake_box(voxfmt_cli, work)
    figures_path = work / "refined.json"
    subprocess.run([tool, str(asset), str(work / "box.off"), "--threads", "2", "--carry", "--json", str(figures_path)],
                   check=True, stdout=subprocess.DEVNULL)
    figures = json.loads(figures_path.read_text())
    with h5py.File(asset, "r") as f:
        lattice_points = f["voxelmap/lattice"].size
        coarse = int((f["voxelmap/bricks"][...] < 0).sum())
    assert figures["lattice_points"] == lattice_points, figures
    assert figures["corners_above_lattice"] == 0, f"lattice values below the exact distance: {figures}"
    assert figures["coarse_bricks"] == coarse, f"{figures['coarse_bricks']} coarse bricks, the file has {coarse}"
    assert 0 < figures["flagged"] <= coarse, figures
    assert figures["near"] == figures["flagged"] or figures["ridge"] > 0, figures
    assert 0 < figures["every4_points"] <= 19 * figures["flagged"], figures
    carried = figures["carried"]
    assert carried["lowest_voxels"] >= -1e-9, f"a carried distance below the exact one: {carried}"
    assert carried["max_over_voxels"] <= 1e-6, f"carried distances above the exact ones on a box: {carried}"
    torus = check_torus(voxfmt_cli, tool, work)
    print(f"check_refined_lattice_cost: torus {torus['every4_points']} points carried in {torus['carried']['rounds']} "
          f"rounds, {torus['carried']['walk_steps']} walk steps, at most {torus['carried']['max_over_voxels']:.3f} "
          "voxel above exact")
    print(f"check_refined_lattice_cost: {figures['flagged']} of {coarse} coarse bricks flagged, "
          f"{figures['every4_points']} points every 4 voxels, {figures['every2_points']} every 2")
    return 0


def check_torus(voxfmt_cli: str, tool: str, work: Path) -> dict:
    """A torus of small triangles (each about a voxel): its every-4 points carried without a search."""
    write_off(work / "torus.off", *torus_mesh(0.05, 0.02, 240, 96))
    asset = work / "torus.vox.h5"
    subprocess.run([voxfmt_cli, "build", str(work / "torus.off"), "-o", str(asset), "--resolution", "96",
                    "--points", "2000", "-q"], check=True)
    figures_path = work / "torus.json"
    subprocess.run([tool, str(asset), str(work / "torus.off"), "--threads", "2", "--carry", "--json",
                    str(figures_path)], check=True, stdout=subprocess.DEVNULL)
    figures = json.loads(figures_path.read_text())
    carried = figures["carried"]
    assert figures["every4_points"] > 0, figures
    assert carried["settled"], f"carried distances did not settle: {carried}"
    assert carried["walk_steps"] > 0, f"no point walked over the surface: {carried}"
    assert carried["lowest_voxels"] >= -1e-9, f"a carried distance below the exact one: {carried}"
    assert carried["max_over_voxels"] <= 1.0, f"carried distances over a voxel above exact: {carried}"
    # The corners' triangles alone: no walk, no offers, never below exact, and never nearer than the full carry
    # (each later step only lowers a distance).
    subprocess.run([tool, str(asset), str(work / "torus.off"), "--threads", "2", "--carry", "--carry-steps", "corners",
                    "--json", str(figures_path)], check=True, stdout=subprocess.DEVNULL)
    corners = json.loads(figures_path.read_text())["carried"]
    assert corners["steps"] == "corners" and corners["walk_steps"] == 0 and corners["rounds"] == 0, corners
    assert corners["lowest_voxels"] >= -1e-9, f"a corner's distance below the exact one: {corners}"
    assert corners["max_over_voxels"] >= carried["max_over_voxels"], f"corners nearer than the carry: {corners}"
    return figures


if __name__ == "__main__":
    sys.exit(main())
