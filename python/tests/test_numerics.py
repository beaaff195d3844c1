"""Numerical edge cases a physics or robotics user reaches: poses and proximities far beyond the objects' size.
Fresh, batched and coherent queries must agree there too, and find what the distances say."""

from __future__ import annotations

import numpy as np
import pytest

import voxfmt
from conftest import POINTS, translation


@pytest.mark.parametrize(("distance", "proximity"), [(1e17, 1.01e17), (1e20, 2e20), (1e17, 1e300)])
def test_a_proximity_reaching_a_body_astronomically_far_finds_every_point(sphere: voxfmt.Body, distance: float,
                                                                          proximity: float) -> None:
    # 1e17 m is ~5e19 voxels: the squared distance to the grid overflows float. The vector bound kernel made it
    # inf and culled every sphere (0 contacts, or some), while the coherent query's scalar bounds found them all.
    pose_b = translation(distance)
    fresh = voxfmt.contacts(sphere, np.eye(4), sphere, pose_b, proximity=proximity)
    coherent = voxfmt.Tracker(sphere, sphere).contacts(np.eye(4), pose_b, proximity=proximity)
    batch = voxfmt.contacts_batch(sphere, np.eye(4), sphere, pose_b[None], proximity=proximity, threads=1,
                                  with_contacts=True)
    assert len(fresh) == POINTS and len(coherent) == POINTS and batch.count[0] == POINTS
    np.testing.assert_array_equal(fresh.depths, coherent.depths)
    np.testing.assert_array_equal(fresh.depths, batch.depths)
    assert np.all(np.isfinite(fresh.depths)) and np.all(fresh.depths < -0.99 * distance)
