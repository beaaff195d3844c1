"""Shared fixtures of the Warp and Newton tests (run with .venv-newton, on the CPU device): small assets baked here
from CGAL's sample meshes, once per session."""

from __future__ import annotations

import os
from pathlib import Path

import pytest
import warp as wp

import voxfmt

MESHES = Path(os.environ.get("VOXFMT_SAMPLE_MESHES", "build/cgal-data/data/meshes"))
REPO = Path(os.environ.get("VOXFMT_REPO", Path(__file__).resolve().parents[2]))

wp.config.quiet = True


@pytest.fixture(scope="session")
def assets(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """Paths of baked assets: the bunny (1 m, 64 voxels across), a 0.1 m sphere and a 0.4 m cube."""
    folder = tmp_path_factory.mktemp("assets")
    out = {}
    for name, mesh, settings in (
        ("bunny", "bunny00.off", {"resolution": 64, "points": 2000}),
        ("sphere", "sphere.off", {"resolution": 40, "points": 2000, "unit_scale": 0.1}),
        ("cube", "cube.off", {"resolution": 32, "points": 2000, "unit_scale": 0.2}),
    ):
        out[name] = folder / f"{name}.vox.h5"
        voxfmt.bake(MESHES / mesh, out[name], **settings)
    return out
