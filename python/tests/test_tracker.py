"""Tracker: coherent queries over a trajectory give exactly the contacts of independent queries, with less work."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import voxfmt
from conftest import RADIUS, rotation, translation


def trajectory(steps: int) -> np.ndarray:
    """B approaches A, presses in while turning and sliding, rests, and leaves: consecutive 1 kHz-like poses."""
    poses = np.empty((steps, 4, 4))
    for k in range(steps):
        t = k / (steps - 1)
        gap = 2 * RADIUS * (1.03 - 0.06 * np.sin(np.pi * min(1.0, 1.5 * t)))
        poses[k] = translation(gap, 0.02 * RADIUS * t, 0.0) @ rotation([0.3, 1.0, 0.2], 0.4 * t)
    return poses


def test_tracker_matches_independent_queries_and_does_less_work(sphere: voxfmt.Body) -> None:
    poses_b = trajectory(300)
    tracker = voxfmt.Tracker(sphere, sphere)
    lookups_fresh = lookups_tracked = contacts = 0
    for k in range(len(poses_b)):
        fresh = voxfmt.contacts(sphere, np.eye(4), sphere, poses_b[k], proximity=0.01 * RADIUS)
        tracked = tracker.contacts(np.eye(4), poses_b[k], proximity=0.01 * RADIUS)
        assert len(tracked) == len(fresh), k
        np.testing.assert_array_equal(tracked.points, fresh.points)
        np.testing.assert_array_equal(tracked.normals, fresh.normals)
        np.testing.assert_array_equal(tracked.depths, fresh.depths)
        np.testing.assert_array_equal(tracked.point_index, fresh.point_index)
        np.testing.assert_array_equal(tracked.point_of_b, fresh.point_of_b)
        lookups_fresh += fresh.stats.nodes_visited + fresh.stats.points_tested
        lookups_tracked += tracked.stats.nodes_visited + tracked.stats.points_tested
        contacts += len(fresh)
    assert contacts > 1000
    assert lookups_tracked < lookups_fresh
    # At rest (one pose again and again) a step looks up its contacts (a bound and a distance each), after the
    # first two (the jump there, then one traversal from the root).
    rest = poses_b[150]
    for _ in range(2):
        tracker.contacts(np.eye(4), rest, proximity=0.01 * RADIUS)
    for _ in range(20):
        fresh = voxfmt.contacts(sphere, np.eye(4), sphere, rest, proximity=0.01 * RADIUS)
        tracked = tracker.contacts(np.eye(4), rest, proximity=0.01 * RADIUS)
        np.testing.assert_array_equal(tracked.depths, fresh.depths)
        assert len(fresh) > 10
        # At rest only the contacts are looked up: a bound (their sphere's) and a distance each.
        tracked_lookups = tracked.stats.nodes_visited + tracked.stats.points_tested
        fresh_lookups = fresh.stats.nodes_visited + fresh.stats.points_tested
        assert tracked_lookups <= 2 * len(fresh) + 20
        assert fresh_lookups > 2 * tracked_lookups, (fresh_lookups, tracked_lookups)


def test_tracker_batch_equals_the_batch_and_continues_across_calls(sphere: voxfmt.Body) -> None:
    poses_b = trajectory(200)
    stiffness = 300.0
    independent = voxfmt.contacts_batch(sphere, np.eye(4), sphere, poses_b, with_contacts=True, stiffness=stiffness)
    tracker = voxfmt.Tracker(sphere, sphere)
    first = tracker.contacts_batch(np.eye(4), poses_b[:120], with_contacts=True, stiffness=stiffness)
    rest = tracker.contacts_batch(np.eye(4), poses_b[120:], with_contacts=True, stiffness=stiffness)
    count = np.concatenate([first.count, rest.count])
    np.testing.assert_array_equal(count, independent.count)
    np.testing.assert_array_equal(np.concatenate([first.force, rest.force]), independent.force)
    np.testing.assert_array_equal(np.concatenate([first.torque, rest.torque]), independent.torque)
    assert first.depths is not None and rest.depths is not None and independent.depths is not None
    np.testing.assert_array_equal(np.concatenate([first.depths, rest.depths]), independent.depths)
    assert np.count_nonzero(count) > 50
    tracker.reset()
    again = tracker.contacts(np.eye(4), poses_b[100])
    assert len(again) == independent.count[100]


def test_tracker_rejects_what_is_not_a_body_and_bad_poses(sphere: voxfmt.Body) -> None:
    with pytest.raises(voxfmt.OptionError):
        voxfmt.Tracker(sphere, "sphere.vox.h5")  # type: ignore[arg-type]
    tracker = voxfmt.Tracker(sphere, sphere)
    with pytest.raises(voxfmt.PoseError):
        tracker.contacts(np.eye(4), 2 * np.eye(4))
    with pytest.raises(voxfmt.OptionError):
        tracker.contacts(np.eye(4), np.eye(4), proximity=float("nan"))


_BUSY_TRACKER = """
import sys, threading
import numpy as np
import voxfmt

tracker = voxfmt.Tracker(voxfmt.load(sys.argv[1]), voxfmt.load(sys.argv[1]))
apart = np.eye(4)
apart[1, 3] = 0.1
for attempt in range(5):  # a loaded machine may not schedule this thread while one batch runs: a few batches
    worker = threading.Thread(target=lambda: tracker.contacts_batch(np.eye(4), np.repeat(apart[None], 200_000, 0)))
    worker.start()
    while worker.is_alive():
        try:
            tracker.reset()
        except voxfmt.OptionError as e:
            worker.join()
            tracker.reset()  # free again
            print("refused:", e)
            sys.exit(0)
    worker.join()
print("never refused")
sys.exit(1)
"""


def test_a_tracker_busy_on_another_thread_says_so_instead_of_waiting(sphere_asset: Path) -> None:
    # The batch holds the tracker with the GIL released and needs the GIL back before it lets go: a second caller
    # waiting for the tracker while holding the GIL hung both. In a child process, so that a hang fails the test.
    run = subprocess.run([sys.executable, "-c", _BUSY_TRACKER, str(sphere_asset)], capture_output=True, text=True,
                         timeout=300, env=os.environ)
    assert run.returncode == 0, run.stdout + run.stderr
    assert "another thread" in run.stdout
