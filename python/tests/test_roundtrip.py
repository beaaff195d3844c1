"""bake -> load -> contacts on two spheres, whose contact is known in closed form."""

from __future__ import annotations

import gc
import math
from pathlib import Path

import numpy as np
import pytest

import voxfmt
from conftest import POINTS, RADIUS, rotation, translation


def test_body_geometry_and_mass(sphere: voxfmt.Body) -> None:
    n = len(sphere.points)
    assert sphere.points.shape == (n, 3) and sphere.points.dtype == np.float32
    assert sphere.normals.shape == (n, 3)
    assert 0.5 * POINTS < n < 1.5 * POINTS
    radii = np.linalg.norm(sphere.points, axis=1)
    np.testing.assert_allclose(radii, RADIUS, atol=0.002 * RADIUS)
    # Inward unit normals: opposite to the position on a sphere centred at the origin.
    np.testing.assert_allclose(np.linalg.norm(sphere.normals, axis=1), 1.0, atol=1e-3)
    cosine = np.einsum("ij,ij->i", sphere.normals, sphere.points) / radii
    assert np.all(cosine < -0.95)
    levels = sphere.levels
    assert levels[0] == 0 and levels[-1] == n and np.all(np.diff(levels) > 0)
    assert sphere.sphere_radii.shape == (n,)
    assert sphere.sphere_radii[0] >= RADIUS * 0.99  # the root's sphere holds the whole shell
    assert sphere.voxel_size == pytest.approx(voxfmt.inspect(sphere.path)["voxelmap"]["voxel_size"])
    assert max(sphere.dims) >= 2 * RADIUS / sphere.voxel_size
    volume = 4 / 3 * math.pi * RADIUS**3
    assert sphere.volume == pytest.approx(volume, rel=0.01)
    dense = voxfmt.load(sphere.path, density=1000.0)
    assert dense.mass == pytest.approx(1000.0 * sphere.volume)
    np.testing.assert_allclose(dense.center_of_mass, 0.0, atol=1e-6)
    np.testing.assert_allclose(dense.inertia, np.eye(3) * 0.4 * dense.mass * RADIUS**2, rtol=0.02, atol=1e-12)


def test_signed_distance_is_negative_inside(sphere: voxfmt.Body) -> None:
    h = sphere.voxel_size
    direction = np.array([[1.0, 0, 0], [0, 1.0, 0], [0.6, 0.0, 0.8], [-0.48, 0.6, -0.64]])
    for offset in (-1.5 * h, -0.5 * h, 0.5 * h, 1.5 * h):
        d = sphere.signed_distance(direction * (RADIUS + offset))
        assert d.shape == (4,) and d.dtype == np.float64
        np.testing.assert_allclose(d, offset, atol=0.15 * h)
    centre = sphere.signed_distance(np.zeros((1, 3)))[0]
    # An estimate this deep: spec §3.1 bounds it within 4 sqrt(3) voxels of the exact depth (half a voxel diagonal
    # more between voxel centres), the lattice's 10 % farther than 16 voxels from the surface besides.
    assert centre == pytest.approx(-RADIUS, abs=(4.5 * math.sqrt(3)) * h + 0.1 * RADIUS)


def overlap_pose(depth: float) -> np.ndarray:
    """B's pose: along x, overlapping A (at the origin) by `depth`."""
    return translation(2 * RADIUS - depth)


@pytest.mark.parametrize("depth_voxels", [0.5, 1.5, 3.0])
def test_sphere_on_sphere_depth_normal_and_wrench(sphere: voxfmt.Body, depth_voxels: float) -> None:
    h = sphere.voxel_size
    depth = depth_voxels * h
    # Rotating both bodies about their centres must not change anything but the points' order.
    spin = rotation([0.3, 1.0, -0.2], 0.7)
    pose_b = overlap_pose(depth) @ rotation([1.0, 0.2, 0.5], -1.1)
    c = voxfmt.contacts(sphere, spin, sphere, pose_b)
    assert len(c) > 0
    assert c.max_depth == pytest.approx(depth, abs=0.25 * h)
    assert np.all(c.depths > 0)
    # Every contact lies in the lens where the spheres overlap, and A must move along -x.
    assert np.all(np.abs(c.points[:, 0] - (RADIUS - depth / 2)) <= depth / 2 + 0.5 * h)
    mean_normal = c.normals.mean(axis=0)
    mean_normal /= np.linalg.norm(mean_normal)
    assert mean_normal[0] < -0.98
    force, torque = voxfmt.wrench(c, 1000.0)
    assert force.shape == (3,) and torque.shape == (3,)
    assert force[0] < 0 and abs(force[1]) < 0.1 * abs(force[0]) and abs(force[2]) < 0.1 * abs(force[0])
    np.testing.assert_allclose(force, 1000.0 * (c.depths[:, None] * c.normals).sum(axis=0))
    # Central contact: about A's centre of mass the torque is small next to |F| R.
    assert np.linalg.norm(torque) < 0.05 * np.linalg.norm(force) * RADIUS
    assert c.stats.points_tested > 0 and c.stats.levels_completed == len(sphere.levels) - 1


def test_apart_and_proximity(sphere: voxfmt.Body) -> None:
    h = sphere.voxel_size
    gap = 1.0 * h
    apart = translation(2 * RADIUS + gap)
    assert len(voxfmt.contacts(sphere, np.eye(4), sphere, apart)) == 0
    near = voxfmt.contacts(sphere, np.eye(4), sphere, apart, proximity=2 * gap)
    assert len(near) > 0 and np.all(near.depths < 0)
    assert near.depths.max() == pytest.approx(-gap, abs=0.25 * h)
    force, _ = voxfmt.wrench(near, 1000.0)
    np.testing.assert_array_equal(force, 0.0)  # proximity points push nothing


def test_budgets_cut_the_tree(sphere: voxfmt.Body) -> None:
    pose_b = overlap_pose(2 * sphere.voxel_size)
    full = voxfmt.contacts(sphere, np.eye(4), sphere, pose_b)
    coarse = voxfmt.contacts(sphere, np.eye(4), sphere, pose_b, point_budget=int(sphere.levels[2]))
    assert coarse.stats.points_tested < full.stats.points_tested
    assert coarse.stats.deepest_level < full.stats.deepest_level
    assert coarse.max_depth >= full.max_depth - 1e-9  # sphere semantics: a cut level is conservative
    timed = voxfmt.contacts(sphere, np.eye(4), sphere, pose_b, time_budget_us=1e6)
    assert not timed.stats.time_budget_hit and len(timed) == len(full)


def test_max_level_cuts_at_a_level_and_cut_level_says_what_it_reports(sphere: voxfmt.Body) -> None:
    pose_b = overlap_pose(2 * sphere.voxel_size)
    full = voxfmt.contacts(sphere, np.eye(4), sphere, pose_b)
    level = full.stats.deepest_level - 1
    spheres = voxfmt.contacts(sphere, np.eye(4), sphere, pose_b, max_level=level)
    points = voxfmt.contacts(sphere, np.eye(4), sphere, pose_b, max_level=level, cut_level="points")
    assert spheres.stats.deepest_level == points.stats.deepest_level == level
    # The level's points only; spheres reach deeper than the points themselves, points no deeper than the tree's.
    assert 0 < len(points) < len(full) and points.point_index.max() < sphere.levels[level + 1]
    assert spheres.max_depth >= full.max_depth - 1e-9 >= points.max_depth - 1e-9
    batch = voxfmt.contacts_batch(sphere, np.eye(4)[None], sphere, pose_b[None], max_level=level, cut_level="points")
    assert batch.count[0] == len(points) and batch.max_depth[0] == points.max_depth
    for bad in ({"max_level": -1}, {"cut_level": "leaves"}):
        with pytest.raises(voxfmt.OptionError) as error:
            voxfmt.contacts(sphere, np.eye(4), sphere, pose_b, **bad)
        assert error.value.code == "BAD_OPTION"


def test_tricubic_interpolation_everywhere_a_query_is_made(sphere: voxfmt.Body) -> None:
    # The C++ tests measure its accuracy against a closed form; here every entry point takes the option, agrees
    # with the others, and refuses a reading it does not know.
    h = sphere.voxel_size
    pose_b = overlap_pose(0.6 * h)
    linear = voxfmt.contacts(sphere, np.eye(4), sphere, pose_b)
    cubic = voxfmt.contacts(sphere, np.eye(4), sphere, pose_b, interpolation="tricubic")
    assert len(linear) > 0 and len(cubic) > 0
    shared, in_linear, in_cubic = np.intersect1d(linear.point_index, cubic.point_index, return_indices=True)
    assert len(shared) > 0.8 * len(linear)
    change = np.abs(cubic.depths[in_cubic] - linear.depths[in_linear])
    assert change.max() > 0 and change.max() < 0.1 * h  # another reading of the same values, not another field
    batch = voxfmt.contacts_batch(sphere, np.eye(4)[None], sphere, pose_b[None], interpolation="tricubic")
    assert batch.count[0] == len(cubic) and batch.max_depth[0] == cubic.max_depth
    tracker = voxfmt.Tracker(sphere, sphere)
    for reading, expected in (("tricubic", cubic), ("trilinear", linear), ("tricubic", cubic)):
        tracked = tracker.contacts(np.eye(4), pose_b, interpolation=reading)
        np.testing.assert_array_equal(tracked.depths, expected.depths)
    along = tracker.contacts_batch(np.eye(4)[None], pose_b[None], interpolation="tricubic")
    assert along.max_depth[0] == cubic.max_depth
    with pytest.raises(voxfmt.OptionError) as error:
        voxfmt.contacts(sphere, np.eye(4), sphere, pose_b, interpolation="cubic")
    assert error.value.code == "BAD_OPTION" and "tricubic" in str(error.value)


def test_views_are_read_only_and_outlive_their_owner(sphere_asset: Path) -> None:
    body = voxfmt.load(sphere_asset)
    points, normals, levels, radii = body.points, body.normals, body.levels, body.sphere_radii
    for array in (points, normals, levels, radii):
        assert not array.flags.writeable
        with pytest.raises(ValueError):
            array[0] = 0
    assert np.shares_memory(points, body.points)  # a view of the body's memory, not a copy
    expected = points.copy()
    c = voxfmt.contacts(body, np.eye(4), body, overlap_pose(0.004))
    depths, contact_points = c.depths, c.points
    assert not depths.flags.writeable and not contact_points.flags.writeable
    expected_depths = depths.copy()
    del body, c
    gc.collect()
    junk = [np.full(100_000, 7.0) for _ in range(20)]  # reuse freed memory, if it had been freed
    np.testing.assert_array_equal(points, expected)
    np.testing.assert_array_equal(depths, expected_depths)
    assert points.base is not None and len(junk) == 20


def test_bake_summary_and_progress(sphere_mesh: Path, tmp_path: Path) -> None:
    calls: list[tuple[str, float]] = []
    out = tmp_path / "s.vox.h5"
    summary = voxfmt.bake(
        sphere_mesh, out, resolution=24, points=500, progress=lambda s, f: calls.append((s, f)), threads=1, seed=7
    )
    assert summary["status"] == "ok" and summary["output"] == str(out)
    assert summary["pointshell"]["points"] == len(voxfmt.load(out).points)
    assert max(summary["voxelmap"]["dims"]) == 24 + 2 * 4  # the longest axis plus the default margins
    fractions = [f for _, f in calls]
    assert len(calls) >= 5 and fractions == sorted(fractions) and fractions[-1] == 1.0
    assert calls[0][0] == "import" and calls[-1][0] == "done"
    # A progress callable that raises stops the bake, and its exception comes back unchanged.
    stopped = tmp_path / "stopped.vox.h5"

    class Stop(Exception):
        pass

    def stop(stage: str, fraction: float) -> None:
        if stage == "repair":
            raise Stop(stage)

    with pytest.raises(Stop):
        voxfmt.bake(sphere_mesh, stopped, resolution=24, points=500, progress=stop)
    assert not stopped.exists()


def test_bake_if_changed_follows_the_mesh_and_the_options(tmp_path, sphere_mesh) -> None:  # type: ignore[no-untyped-def]
    # A cache of bakes named by its settings alone kept another mesh's asset (the examples' --mesh did nothing).
    out = tmp_path / "part.vox.h5"
    assert voxfmt.bake(sphere_mesh, out, resolution=16, points=100, if_changed=True)["status"] == "ok"
    assert voxfmt.bake(sphere_mesh, out, resolution=16, points=100, if_changed=True)["status"] == "up_to_date"
    assert voxfmt.bake(sphere_mesh, out, resolution=20, points=100, if_changed=True)["status"] == "ok"
    moved = tmp_path / "other.off"
    moved.write_text(sphere_mesh.read_text().replace("OFF\n", "OFF\n# another mesh\n", 1))
    assert voxfmt.bake(moved, out, resolution=20, points=100, if_changed=True)["status"] == "ok"  # its bytes differ
    assert voxfmt.bake(moved, out, resolution=20, points=100)["status"] == "ok"  # without: always baked
    with pytest.raises(voxfmt.OptionError):
        voxfmt.bake(moved, out, if_changed="yes")
