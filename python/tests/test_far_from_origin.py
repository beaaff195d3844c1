"""An asset far from its frame's origin (a part in a plant's or a map's coordinates) is queried as precisely as the
same asset at the origin: the runtime holds its points from the shell's centre and folds that into the pose in
double. In single precision 1e6 m out, its points were rounded to decimetres and its spheres padded by metres:
false contacts at rest, none where the parts overlapped."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import voxfmt
from conftest import icosphere, rotation, translation, write_off

RADIUS, SMALL = 0.5, 0.35


@pytest.fixture(scope="module")
def spheres(tmp_path_factory: pytest.TempPathFactory) -> dict[tuple[float, float], voxfmt.Body]:
    folder = tmp_path_factory.mktemp("far")
    v, f = icosphere(3)
    bodies = {}
    for offset in (0.0, 1e5, 1e7):
        for radius in (RADIUS, SMALL):  # sizes apart: the small one's points go into the large one's field
            mesh = folder / f"sphere-{radius}-{offset:g}.off"
            write_off(mesh, v * radius + offset, f)
            asset = folder / f"sphere-{radius}-{offset:g}.vox.h5"
            voxfmt.bake(mesh, asset, resolution=40, points=800, threads=1)
            bodies[offset, radius] = voxfmt.load(asset)
    return bodies


@pytest.mark.parametrize("offset", [1e5, 1e7])
def test_contacts_far_out_are_those_at_the_origin(spheres: dict[tuple[float, float], voxfmt.Body],
                                                  offset: float) -> None:
    # Two bakes of one sphere, near and far: their point shells are sampled apart, so the contacts agree in what
    # the geometry fixes (the deepest, how many) rather than point by point.
    shift = translation(offset, offset, offset)
    for gap in (-0.2, -0.05, 0.02, 0.2):  # overlapping by 0.2 m, by 5 cm, then 2 cm and 20 cm apart
        pose_b = translation(RADIUS + SMALL + gap) @ rotation([1, 2, 3], 0.4)
        far_pose_b = shift @ pose_b @ np.linalg.inv(shift)  # about its own centre, as the near B turns
        found = {}
        for at, pose in ((0.0, pose_b), (offset, far_pose_b)):
            found[at] = voxfmt.contacts(spheres[at, RADIUS], np.eye(4), spheres[at, SMALL], pose)
            batch = voxfmt.contacts_batch(spheres[at, RADIUS], np.eye(4), spheres[at, SMALL], pose[None],
                                          with_contacts=True)
            np.testing.assert_array_equal(batch.points, found[at].points)
        near, far = found[0.0], found[offset]
        voxel = spheres[0.0, RADIUS].voxel_size
        if gap > 0:
            assert len(near) == 0 and len(far) == 0, (gap, len(far))
            continue
        assert abs(far.max_depth - (-gap)) < 0.5 * voxel and abs(far.max_depth - near.max_depth) < 0.5 * voxel
        assert abs(len(far) - len(near)) <= 0.15 * len(near), (len(far), len(near))
        # Every contact lies in the lens where the spheres overlap, far out as near.
        centre_b = far_pose_b[:3, :3] @ np.full(3, offset) + far_pose_b[:3, 3]
        reach = np.linalg.norm(far.points - offset, axis=1), np.linalg.norm(far.points - centre_b, axis=1)
        assert np.all(reach[0] <= RADIUS + voxel) and np.all(reach[1] <= SMALL + voxel)


def test_points_are_in_the_asset_frame_wherever_it_lies(spheres: dict[tuple[float, float], voxfmt.Body]) -> None:
    for (offset, radius), body in spheres.items():
        lo, hi = body.bounds
        points = np.asarray(body.points, dtype=np.float64)
        assert points.shape == (800, 3)
        slack = 1e-6 * max(1.0, offset)
        assert np.all(points >= lo - slack) and np.all(points <= hi + slack)
        np.testing.assert_allclose(np.linalg.norm(points - offset, axis=1), radius, atol=0.02 + slack)
