"""contacts_batch agrees with contacts() + wrench() pose by pose, on any number of threads."""

from __future__ import annotations

import concurrent.futures
import copy
import multiprocessing
import os
import pickle
import shutil
from pathlib import Path

import numpy as np
import pytest

import voxfmt
from conftest import RADIUS, rotation, translation


def random_poses(count: int, seed: int) -> np.ndarray:
    """Poses of B around A (at the origin) from touching-and-overlapping to apart, random orientations."""
    rng = np.random.default_rng(seed)
    poses = np.empty((count, 4, 4))
    for k in range(count):
        direction = rng.normal(size=3)
        direction /= np.linalg.norm(direction)
        distance = 2 * RADIUS * rng.uniform(0.9, 1.05)
        poses[k] = translation(*(direction * distance)) @ rotation(rng.normal(size=3), rng.uniform(0, np.pi))
    return poses


@pytest.mark.parametrize("threads", [1, 2, 3])
def test_batch_equals_single_calls(sphere: voxfmt.Body, threads: int) -> None:
    poses_b = random_poses(40, seed=threads)
    poses_a = np.repeat(rotation([0.0, 0.0, 1.0], 0.3)[None], 40, axis=0)
    stiffness = 500.0
    batch = voxfmt.contacts_batch(sphere, poses_a, sphere, poses_b, threads=threads, with_contacts=True,
                                  stiffness=stiffness)
    assert len(batch) == 40 and batch.count.dtype == np.int64 and batch.force.shape == (40, 3)
    assert batch.offsets is not None and batch.points is not None and batch.depths is not None
    assert batch.point_index is not None
    assert batch.offsets[0] == 0 and batch.offsets[-1] == len(batch.points)
    assert 5 < np.count_nonzero(batch.count) < 40  # the poses include both cases
    for k in range(40):
        single = voxfmt.contacts(sphere, poses_a[k], sphere, poses_b[k])
        force, torque = voxfmt.wrench(single, stiffness)
        assert batch.count[k] == len(single)
        assert batch.max_depth[k] == single.max_depth
        np.testing.assert_allclose(batch.force[k], force, rtol=1e-12, atol=1e-15)
        np.testing.assert_allclose(batch.torque[k], torque, rtol=1e-12, atol=1e-15)
        rows = slice(batch.offsets[k], batch.offsets[k + 1])
        np.testing.assert_array_equal(batch.points[rows], single.points)
        np.testing.assert_array_equal(batch.depths[rows], single.depths)
        np.testing.assert_array_equal(batch.point_index[rows], single.point_index)


def test_one_pose_broadcasts_and_options_apply(sphere: voxfmt.Body) -> None:
    poses_b = random_poses(12, seed=7)
    broadcast = voxfmt.contacts_batch(sphere, np.eye(4), sphere, poses_b, threads=2)
    repeated = voxfmt.contacts_batch(sphere, np.repeat(np.eye(4)[None], 12, axis=0), sphere, poses_b, threads=2)
    np.testing.assert_array_equal(broadcast.count, repeated.count)
    assert broadcast.offsets is None and broadcast.points is None
    coarse = voxfmt.contacts_batch(sphere, np.eye(4), sphere, poses_b, point_budget=int(sphere.levels[2]))
    for k in range(12):
        single = voxfmt.contacts(sphere, np.eye(4), sphere, poses_b[k], point_budget=int(sphere.levels[2]))
        assert coarse.count[k] == len(single)
    empty = voxfmt.contacts_batch(sphere, np.eye(4), sphere, np.zeros((0, 4, 4)))
    assert len(empty) == 0 and empty.force.shape == (0, 3)


def test_an_empty_side_against_a_stack_is_a_count_mismatch_not_a_crash(sphere: voxfmt.Body) -> None:
    none = np.zeros((0, 4, 4))
    with pytest.raises(voxfmt.OptionError, match="5 poses where the other side has 0"):
        voxfmt.contacts_batch(sphere, none, sphere, random_poses(5, seed=3))
    assert len(voxfmt.contacts_batch(sphere, none, sphere, np.eye(4))) == 0
    assert len(voxfmt.Tracker(sphere, sphere).contacts_batch(none, np.eye(4))) == 0


def test_poses_and_references_that_are_not_real_finite_numbers_are_refused(sphere: voxfmt.Body) -> None:
    for pose in (np.eye(4) + 0j, np.eye(4, dtype=bool)):  # complex: the imaginary part would be dropped
        with pytest.raises(voxfmt.OptionError, match="real numbers"):
            voxfmt.contacts(sphere, pose, sphere, np.eye(4))
    touching = voxfmt.contacts(sphere, np.eye(4), sphere, random_poses(1, seed=5)[0])
    with pytest.raises(voxfmt.OptionError, match="finite"):
        voxfmt.wrench(touching, 1.0, reference=[np.nan, 0, 0])
    with pytest.raises(voxfmt.InternalError) as caught:
        voxfmt.contacts_batch(sphere, np.eye(4), sphere, np.broadcast_to(np.eye(4), (10**9, 4, 4)))
    assert caught.value.code == "OUT_OF_MEMORY"


def test_pose_lists_are_read_as_their_arrays(sphere: voxfmt.Body) -> None:
    # A list is made an array once (it was converted three times); the batch is the array's, every kind of list.
    poses_b = random_poses(6, seed=11)
    expected = voxfmt.contacts_batch(sphere, np.eye(4), sphere, poses_b, with_contacts=True)
    tracker = voxfmt.Tracker(sphere, sphere)
    for a, b in ((np.eye(4).astype(int).tolist(), poses_b.tolist()), (tuple(map(tuple, np.eye(4))), list(poses_b))):
        for batch in (voxfmt.contacts_batch(sphere, a, sphere, b, with_contacts=True),
                      tracker.contacts_batch(a, b, with_contacts=True)):
            np.testing.assert_array_equal(batch.count, expected.count)
            np.testing.assert_array_equal(batch.force, expected.force)
            np.testing.assert_array_equal(batch.points, expected.points)
        tracker.reset()
    with pytest.raises(voxfmt.OptionError, match="real numbers"):
        voxfmt.contacts_batch(sphere, np.eye(4, dtype=bool).tolist(), sphere, poses_b)
    with pytest.raises(voxfmt.OptionError, match="ragged"):
        voxfmt.contacts_batch(sphere, np.eye(4), sphere, [np.eye(4), np.eye(3)])


def batch_in_worker(body: voxfmt.Body, poses: np.ndarray) -> tuple[float, np.ndarray]:
    return body.mass, voxfmt.contacts_batch(body, np.eye(4), body, poses, threads=1).count


def test_a_body_pickles_and_copies_as_its_file_loaded_again(
    sphere_asset: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    body = voxfmt.load(sphere_asset, density=1000.0)
    pose = translation(2 * RADIUS - 0.002)
    expected = voxfmt.contacts(body, np.eye(4), body, pose)
    assert len(expected) > 0
    copies = [pickle.loads(pickle.dumps(body, protocol)) for protocol in range(2, pickle.HIGHEST_PROTOCOL + 1)]
    for again in copies + [copy.copy(body), copy.deepcopy(body), copy.deepcopy([body, body])[1]]:
        assert type(again) is voxfmt.Body and again is not body
        assert again.path == str(sphere_asset) and again.density == 1000.0 and again.mass == body.mass
        np.testing.assert_array_equal(again.points, body.points)
        c = voxfmt.contacts(again, np.eye(4), again, pose)
        np.testing.assert_array_equal(c.depths, expected.depths)
        np.testing.assert_array_equal(c.points, expected.points)
    # A relative path is pickled as the file the load found: a worker started in another folder, or a pickle made
    # after a chdir, finds the same file.
    monkeypatch.chdir(sphere_asset.parent)
    loaded_here = voxfmt.load(sphere_asset.name, max_memory_mib=4096)
    relative = pickle.dumps(loaded_here)
    monkeypatch.chdir(tmp_path)
    assert pickle.loads(relative).path == str(sphere_asset)
    again = pickle.loads(pickle.dumps(loaded_here))  # pickled after the chdir
    assert again.path == str(sphere_asset) and again._max_memory_mib == 4096  # the load's budget too
    # A file gone since is the load's coded error.
    gone = tmp_path / "gone.vox.h5"
    shutil.copy(sphere_asset, gone)
    pickled = pickle.dumps(voxfmt.load(gone))
    os.unlink(gone)
    with pytest.raises(voxfmt.AssetError) as info:
        pickle.loads(pickled)
    assert info.value.code == "FILE_NOT_FOUND"
    # What a process pool does with it: each worker loads the file and finds the same contacts.
    poses = np.stack([translation(x * RADIUS) for x in (1.9, 2.0, 3.0)])
    spawn = multiprocessing.get_context("spawn")
    with concurrent.futures.ProcessPoolExecutor(1, mp_context=spawn) as pool:
        mass, count = pool.submit(batch_in_worker, body, poses).result(timeout=120)
    assert mass == body.mass
    np.testing.assert_array_equal(count, voxfmt.contacts_batch(body, np.eye(4), body, poses).count)
    assert count[0] > 0 and count[2] == 0
