"""voxfmt.warp: the asset's NanoVDB grids in Warp volumes (CPU device) against the runtime's own field, the file of
`voxfmt export` the same grids, and the refusals."""

from __future__ import annotations

import os
import subprocess
from pathlib import Path

import numpy as np
import pytest
import warp as wp

import voxfmt
import voxfmt.warp
from conftest import MESHES


@wp.kernel
def _sample(volume: wp.uint64, points: wp.array(dtype=wp.vec3), out: wp.array(dtype=float)):
    i = wp.tid()
    out[i] = wp.volume_sample_f(volume, wp.volume_world_to_index(volume, points[i]), wp.Volume.LINEAR)


@wp.kernel
def _sample_both(distance: wp.uint64, coarse: wp.uint64, width: float, points: wp.array(dtype=wp.vec3),
                 out: wp.array(dtype=float)):
    i = wp.tid()
    out[i] = voxfmt.warp.sample_distance(distance, coarse, width, points[i])


def sample(volume: wp.Volume, points: np.ndarray) -> np.ndarray:
    out = wp.zeros(len(points), dtype=float, device="cpu")
    wp.launch(_sample, dim=len(points), inputs=[volume.id, wp.array(points.astype(np.float32), dtype=wp.vec3,
                                                                     device="cpu"), out], device="cpu")
    return out.numpy()


def random_points(body: voxfmt.Body, n: int, seed: int = 1) -> np.ndarray:
    lo, hi = body.bounds
    return np.random.default_rng(seed).uniform(lo, hi, size=(n, 3))


def test_the_level_set_is_the_runtimes_distance_near_the_surface(assets: dict[str, Path]) -> None:
    body = voxfmt.load(assets["bunny"])
    distance, coarse = voxfmt.warp.volumes(body, "cpu")
    h = body.voxel_size
    width = distance.voxfmt_width
    assert width == pytest.approx(2.5 * h)  # voxfmt build's band of 3: 2.5 voxels stored completely
    assert np.allclose(distance.get_voxel_size(), h) and np.allclose(coarse.get_voxel_size(), 8 * h)
    points = random_points(body, 100000)
    d = body.signed_distance(points)
    w = sample(distance, points)
    near = np.abs(d) < h  # every corner of their cells is stored and within the width
    assert near.sum() > 1000
    assert np.abs(w[near] - d[near]).max() < 1e-6  # metres
    # Everywhere: the sign (tiles signed from the asset), and the clamp a cell's diagonal past the width (leaves).
    assert np.all(np.sign(w[np.abs(d) > h]) == np.sign(d[np.abs(d) > h]))
    assert np.abs(w).max() <= (width + np.sqrt(3) * h) * (1 + 1e-6)


def test_an_open_meshs_level_set_keeps_the_runtimes_zero(tmp_path: Path) -> None:
    # Across a hole's cap the runtime's field jumps (-2.5 to +3.6 voxels between neighbours); clamped at the width
    # there, a cell's interpolation moved its zero, and points a tenth of a voxel from the surface changed sign.
    asset = tmp_path / "open.vox.h5"
    voxfmt.bake(MESHES / "cube-ouvert.off", asset, resolution=32, points=500)
    body = voxfmt.load(asset)
    distance, _ = voxfmt.warp.volumes(body, "cpu")
    points = random_points(body, 200000, seed=1)
    d = body.signed_distance(points)
    w = sample(distance, points)
    near = (np.abs(d) < body.voxel_size) & (np.abs(d) > 1e-3 * body.voxel_size)
    assert near.sum() > 10000
    assert np.all(np.sign(w[near]) == np.sign(d[near]))


def test_the_far_field_comes_from_the_coarse_grid_within_the_estimate_bound(assets: dict[str, Path]) -> None:
    body = voxfmt.load(assets["bunny"])
    distance, coarse = voxfmt.warp.volumes(body, "cpu")
    points = random_points(body, 50000, seed=2)
    out = wp.zeros(len(points), dtype=float, device="cpu")
    wp.launch(_sample_both, dim=len(points),
              inputs=[distance.id, coarse.id, distance.voxfmt_width,
                      wp.array(points.astype(np.float32), dtype=wp.vec3, device="cpu"), out], device="cpu")
    w, d = out.numpy(), body.signed_distance(points)
    h = body.voxel_size
    near = np.abs(d) < h
    assert np.abs(w[near] - d[near]).max() < 1e-6
    # Beyond the band, in coarse bricks, both are the same lattice interpolated: mostly equal. In
    # value bricks the asset's estimates are settled (format 2.2), never below the exact distance u, while the
    # interpolation may lie below u by up to its bound (4 sqrt(3) voxels); both lie above u by at most 8 sqrt(3).
    core = voxfmt._voxfmt._export_core(body)
    origin, dims = np.asarray(core["body_doubles"])[:3], np.asarray(core["field_dims"])
    voxel = np.clip(np.rint((points - origin) / h).astype(np.int64), 0, dims[:3] - 1)
    brick = voxel // 8
    entry = np.asarray(core["bricks"])[(brick[:, 2] * dims[4] + brick[:, 1]) * dims[3] + brick[:, 0]]
    far = np.abs(d) > 3 * h
    error = np.abs(w - d) / h
    assert np.count_nonzero(far & (entry < 0)) > 1000 and np.count_nonzero(far & (entry >= 0)) > 100
    assert np.median(error[far & (entry < 0)]) < 1e-4  # a point's 8 voxels may reach into a value brick
    assert error[far].max() < 8 * np.sqrt(3)
    assert np.all(np.sign(w) == np.sign(d))


def test_the_exported_file_holds_the_same_grids(assets: dict[str, Path], tmp_path: Path) -> None:
    body = voxfmt.load(assets["bunny"])
    out = tmp_path / "bunny.nvdb"
    r = subprocess.run([os.environ["VOXFMT_BIN"], "export", str(assets["bunny"]), "--nvdb", str(out)],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    from_file = wp.Volume.load_from_nvdb(out.read_bytes(), device="cpu")
    in_memory, _ = voxfmt.warp.volumes(body, "cpu")
    points = random_points(body, 20000, seed=3)
    assert np.array_equal(sample(from_file, points), sample(in_memory, points))
    info = from_file.get_grid_info()
    assert (info.name, info.grid_index, info.grid_count) == ("distance", 0, 2)
    assert from_file.load_next_grid().get_grid_info().name == "coarse"
    data, summary = voxfmt.warp.nvdb(assets["bunny"])
    assert data[:8] == b"NanoVDB0" and summary["distance_leaves"] > 0


def test_one_grid_at_a_time_and_the_refusals(assets: dict[str, Path], tmp_path: Path) -> None:
    coarse = voxfmt.warp.volume(assets["cube"], "cpu", grid="coarse")
    assert coarse.get_grid_info().name == "coarse"
    with pytest.raises(voxfmt.OptionError):
        voxfmt.warp.volume(assets["cube"], "cpu", grid="fine")
    with pytest.raises(voxfmt.OptionError):
        voxfmt.warp.nvdb(assets["cube"], width=0.1)
    # NumPy's scalars are numbers too (BatchScene takes them); its bool is not.
    assert voxfmt.warp.nvdb(assets["cube"], width=np.float32(3.0))[1] == voxfmt.warp.nvdb(assets["cube"], width=3)[1]
    with pytest.raises(voxfmt.OptionError):
        voxfmt.warp.nvdb(assets["cube"], width=np.bool_(True))
    # A device Warp does not know, or this machine lacks, is refused before the grids are built.
    for device in ("bogus", "cuda:97"):
        with pytest.raises(voxfmt.OptionError) as error:
            voxfmt.warp.volumes(assets["cube"], device)
        assert error.value.code == "BAD_OPTION" and repr(device) in str(error.value)
    with pytest.raises(voxfmt.OptionError):
        voxfmt.warp.nvdb(42)
    # An array of names is no name (NumPy's truth value error), a string no bool ("no" compressed).
    for call in (lambda: voxfmt.warp.volume(assets["cube"], "cpu", grid=np.array(["distance", "coarse"])),
                 lambda: voxfmt.warp.nvdb(assets["cube"], compress="no")):
        with pytest.raises(voxfmt.OptionError) as error:
            call()
        assert error.value.code == "BAD_OPTION"
    assert voxfmt.warp.nvdb(assets["cube"], compress=np.bool_(False))[1]["uncompressed_bytes"] > 0
    missing = tmp_path / "none.vox.h5"
    with pytest.raises(voxfmt.Error) as error:
        voxfmt.warp.volumes(missing)
    assert error.value.code == "FILE_NOT_FOUND"
