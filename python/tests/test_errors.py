"""Bad input raises a voxfmt.Error subclass with the library's code, and never crashes the interpreter."""

from __future__ import annotations

import concurrent.futures
import copy
import fractions
import math
import multiprocessing
import os
import pickle
import shutil
from pathlib import Path
from typing import Any

import numpy as np
import numpy.lib.recfunctions  # noqa: F401  (np.lib.recfunctions)
import pytest

import voxfmt
import voxfmt.mujoco
from conftest import RADIUS, translation


def raises(kind: type[voxfmt.Error], code: str, call: Any, *args: Any, **kwargs: Any) -> voxfmt.Error:
    with pytest.raises(kind) as info:
        call(*args, **kwargs)
    assert info.value.code == code, info.value
    assert isinstance(info.value, voxfmt.Error) and info.value.message
    assert str(info.value).startswith(code + ": ")
    return info.value


def test_missing_and_corrupt_assets(tmp_path: Path, sphere_asset: Path) -> None:
    missing = tmp_path / "missing.vox.h5"
    error = raises(voxfmt.AssetError, "FILE_NOT_FOUND", voxfmt.load, missing)
    assert str(missing) in error.message
    raises(voxfmt.AssetError, "FILE_NOT_FOUND", voxfmt.inspect, missing)
    garbage = tmp_path / "garbage.vox.h5"
    garbage.write_bytes(b"not an hdf5 file at all" * 100)
    raises(voxfmt.AssetError, "NOT_HDF5", voxfmt.load, garbage)
    # A real asset cut short: HDF5 cannot read it; the code says which way it failed.
    truncated = tmp_path / "truncated.vox.h5"
    truncated.write_bytes(sphere_asset.read_bytes()[: sphere_asset.stat().st_size // 2])
    with pytest.raises(voxfmt.AssetError) as info:
        voxfmt.load(truncated)
    assert info.value.code in {"NOT_HDF5", "READ_FAILED", "MISSING_OBJECT"}
    # validate() reports instead of raising.
    report = voxfmt.validate(garbage)
    assert not report.valid and report.issues[0].code == "NOT_HDF5"
    assert not voxfmt.validate(missing).valid and voxfmt.validate(missing).issues[0].code == "FILE_NOT_FOUND"
    raises(voxfmt.OptionError, "BAD_OPTION", voxfmt.validate, sphere_asset, level="deep")
    raises(voxfmt.OptionError, "BAD_OPTION", voxfmt.load, 42)
    raises(voxfmt.OptionError, "BAD_OPTION", voxfmt.load, sphere_asset, density=-1.0)


def test_bake_errors(tmp_path: Path, sphere_mesh: Path) -> None:
    out = tmp_path / "out.vox.h5"
    raises(voxfmt.MeshError, "INPUT_NOT_FOUND", voxfmt.bake, tmp_path / "nothing.obj", out)
    unknown = tmp_path / "mesh.unknownformat"
    shutil.copy(sphere_mesh, unknown)
    raises(voxfmt.MeshError, "UNSUPPORTED_FORMAT", voxfmt.bake, unknown, out)
    broken = tmp_path / "broken.off"
    broken.write_text("OFF\nfoo bar baz\n")
    raises(voxfmt.MeshError, "IMPORT_FAILED", voxfmt.bake, broken, out)
    # Debian's assimp aborts in an assertion on an OFF that announces more vertices than it has: the import runs
    # in a child process, so the interpreter survives.
    broken.write_text("OFF\n100 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n")
    raises(voxfmt.MeshError, "IMPORT_FAILED", voxfmt.bake, broken, out)
    nan = tmp_path / "nan.off"
    nan.write_text("OFF\n4 4 0\n0 0 0\n1 0 0\n0 1 0\nnan 0 1\n3 0 2 1\n3 0 1 3\n3 1 2 3\n3 0 3 2\n")
    raises(voxfmt.MeshError, "NON_FINITE_COORDINATES", voxfmt.bake, nan, out)
    # Voxels of 1e-12 m (a mesh in the wrong unit): refused before the bake, nothing written.
    raises(voxfmt.MeshError, "SCALE_OUT_OF_RANGE", voxfmt.bake, sphere_mesh, out, unit_scale=1e-10)
    assert not out.exists()
    for options in (
        {"resolution": 0},
        {"resolution": 5000},
        {"points": -3},
        {"branching": 1.0},
        {"up_axis": "up"},
        {"deflate": 12},
        {"band": math.nan},
        {"colour": "red"},  # not an option of voxfmt build
        {"resolution": "high"},
        {"self_intersection_check": "no"},
        {"progress": 3},
        {"seed": -1},  # a uint64: never wrapped to 2^64 - 1
        {"resolution": 64, "voxel_size": 0.01},  # exclude each other, as on the command line
        {"points": 500, "point_spacing": 0.01},
        {"max_memory_mib": 0},  # 0 is the bake's default: refused as on the command line
        {"max_memory_mib": 2**40},
        {"max_memory_mib": 1.5},
    ):
        raises(voxfmt.OptionError, "BAD_OPTION", voxfmt.bake, sphere_mesh, out, **options)
    assert not out.exists()
    # A bake that would need more than max_memory_mib is refused before it starts, as `voxfmt build --max-memory`.
    raises(voxfmt.InternalError, "OUT_OF_MEMORY", voxfmt.bake, sphere_mesh, out, resolution=2048, max_memory_mib=64)
    assert not out.exists()
    assert voxfmt.bake(sphere_mesh, out, resolution=16, points=200, max_memory_mib=64)["status"] == "ok"
    raises(voxfmt.WriteError, "WRITE_FAILED", voxfmt.bake, sphere_mesh, tmp_path / "no" / "dir" / "x.vox.h5",
           resolution=16, points=200)


def test_bad_arrays_and_poses(sphere: voxfmt.Body) -> None:
    eye = np.eye(4)
    for bad_shape in (np.eye(3), np.zeros((4, 4, 1)), np.zeros(16), [[1, 2], [3, 4]]):
        raises(voxfmt.OptionError, "BAD_OPTION", voxfmt.contacts, sphere, bad_shape, sphere, eye)
    raises(voxfmt.OptionError, "BAD_OPTION", voxfmt.contacts, sphere, "pose", sphere, eye)
    raises(voxfmt.OptionError, "BAD_OPTION", voxfmt.contacts, sphere, [["a"] * 4] * 4, sphere, eye)
    scaled = np.diag([2.0, 2.0, 2.0, 1.0])
    reflected = np.diag([1.0, 1.0, -1.0, 1.0])
    sheared = np.eye(4)
    sheared[0, 1] = 0.1
    projective = np.eye(4)
    projective[3, 0] = 0.5
    not_finite = translation(math.inf)
    for bad in (scaled, reflected, sheared, projective, not_finite):
        error = raises(voxfmt.PoseError, "BAD_POSE", voxfmt.contacts, sphere, eye, sphere, bad)
        assert "pose_b" in error.message
    assert isinstance(error, ValueError)
    # Lists and other dtypes that are rigid are accepted.
    pose = translation(2 * RADIUS - 0.002)
    as_list = voxfmt.contacts(sphere, eye.tolist(), sphere, pose.astype(np.float32))
    assert len(as_list) == len(voxfmt.contacts(sphere, eye, sphere, pose))
    # Non-contiguous (a transposed view of a transposed copy) is read with its strides.
    strided = np.asfortranarray(pose)
    assert len(voxfmt.contacts(sphere, eye, sphere, strided)) == len(as_list)
    for options in ({"point_budget": 0}, {"time_budget_us": -1.0}, {"proximity": -0.1}, {"proximity": math.nan}):
        raises(voxfmt.OptionError, "BAD_OPTION", voxfmt.contacts, sphere, eye, sphere, pose, **options)
    raises(voxfmt.OptionError, "BAD_OPTION", sphere.signed_distance, np.zeros((5, 2)))
    raises(voxfmt.OptionError, "BAD_OPTION", sphere.signed_distance, np.zeros(3))
    c = voxfmt.contacts(sphere, eye, sphere, pose)
    raises(voxfmt.OptionError, "BAD_OPTION", voxfmt.wrench, c, -1.0)
    raises(voxfmt.OptionError, "BAD_OPTION", voxfmt.wrench, c, 1.0, reference=np.zeros(4))


def test_batch_rejects_bad_poses_before_running(sphere: voxfmt.Body) -> None:
    poses = np.repeat(np.eye(4)[None], 6, axis=0)
    poses[4, 0, 0] = 3.0
    error = raises(voxfmt.PoseError, "BAD_POSE", voxfmt.contacts_batch, sphere, np.eye(4), sphere, poses)
    assert "poses_b[4]" in error.message
    raises(voxfmt.OptionError, "BAD_OPTION", voxfmt.contacts_batch, sphere, np.repeat(np.eye(4)[None], 5, axis=0), sphere, poses)
    raises(voxfmt.OptionError, "BAD_OPTION", voxfmt.contacts_batch, sphere, np.zeros((6, 3, 4)), sphere, poses)
    raises(voxfmt.OptionError, "BAD_OPTION", voxfmt.contacts_batch, sphere, np.eye(4), sphere, np.eye(4), threads=0)


def test_paths_as_open_takes_them(tmp_path: Path, sphere_asset: Path, sphere_mesh: Path) -> None:
    # A name that is not UTF-8 (str with surrogates, or bytes) is a file like any other; a NUL byte, which would cut
    # the name to another file's, is refused everywhere a path is taken.
    odd = tmp_path / os.fsdecode(b"\xff.vox.h5")
    shutil.copy(sphere_asset, odd)
    body = voxfmt.load(odd)
    assert body.path == str(odd)
    assert voxfmt.load(os.fsencode(str(odd))).path == str(odd)
    assert voxfmt.validate(odd).valid
    assert voxfmt.inspect(odd)["voxelmap"]
    missing = tmp_path / os.fsdecode(b"\xfe-missing.vox.h5")
    assert str(missing) in raises(voxfmt.AssetError, "FILE_NOT_FOUND", voxfmt.load, missing).message
    summary = voxfmt.bake(sphere_mesh, tmp_path / os.fsdecode(b"\xff-baked.vox.h5"), resolution=16, points=100)
    assert summary["status"] == "ok" and b"\xff-baked.vox.h5" in os.listdir(os.fsencode(tmp_path))
    nul = str(sphere_asset) + "\0ignored"
    for call in (voxfmt.load, voxfmt.validate, voxfmt.inspect, voxfmt.read_mesh):
        assert "embedded null byte" in raises(voxfmt.OptionError, "BAD_OPTION", call, nul).message
    raises(voxfmt.OptionError, "BAD_OPTION", voxfmt.bake, sphere_mesh, str(tmp_path / "x.vox.h5") + "\0z")
    assert not (tmp_path / "x.vox.h5").exists()


def test_numbers_are_judged_alike_compiled_or_not(sphere: voxfmt.Body, sphere_mesh: Path, tmp_path: Path) -> None:
    # A bool is no count or length (max_level=False once meant the root level), an int beyond int64 is an
    # OptionError (not nanobind's TypeError), and a bake's 0 voxel size is refused as on the command line.
    pose = np.eye(4)
    for options in ({"max_level": False}, {"point_budget": True}, {"proximity": True}, {"point_budget": 2**63}):
        raises(voxfmt.OptionError, "BAD_OPTION", voxfmt.contacts, sphere, pose, sphere, pose, **options)
    assert len(voxfmt.contacts(sphere, pose, sphere, pose, max_level=np.int64(2)).depths) > 0
    contacts = voxfmt.contacts(sphere, pose, sphere, pose, proximity=np.float32(0.001))
    # What float() reads that is a real number is one: a 0-d array, a Fraction (as before the rule was shared).
    for proximity in (np.array(0.001), fractions.Fraction(1, 1000)):
        assert len(voxfmt.contacts(sphere, pose, sphere, pose, proximity=proximity).depths) == len(contacts.depths)
    for not_a_number in (np.array(True), 1j, "0.001", np.array([0.001, 0.002])):
        raises(voxfmt.OptionError, "BAD_OPTION", voxfmt.contacts, sphere, pose, sphere, pose, proximity=not_a_number)
    raises(voxfmt.OptionError, "BAD_OPTION", voxfmt.wrench, contacts, True)
    raises(voxfmt.OptionError, "BAD_OPTION", voxfmt.load, sphere.path, max_memory_mib=2**70)
    raises(voxfmt.OptionError, "BAD_OPTION", voxfmt.load, sphere.path, density=True)
    raises(voxfmt.OptionError, "BAD_OPTION", voxfmt.validate, sphere.path, max_memory_mib=2**70)
    out = tmp_path / "zero.vox.h5"
    raises(voxfmt.OptionError, "BAD_OPTION", voxfmt.bake, sphere_mesh, out, voxel_size=0.0)
    raises(voxfmt.OptionError, "BAD_OPTION", voxfmt.bake, sphere_mesh, out, points=None, point_spacing=0.0)
    assert voxfmt.bake(sphere_mesh, out, resolution=16, points=100, voxel_size=None)["status"] == "ok"


ERROR_CLASSES = [voxfmt.Error, voxfmt.AssetError, voxfmt.MeshError, voxfmt.WriteError, voxfmt.OptionError,
                 voxfmt.PoseError, voxfmt.InternalError, voxfmt.mujoco.MujocoVersionError]


@pytest.mark.parametrize("kind", ERROR_CLASSES, ids=lambda kind: kind.__name__)
def test_errors_pickle_and_copy_with_their_class_and_fields(kind: type[voxfmt.Error]) -> None:
    # Exception's own pickling replays cls(one string): an error could not come back from a worker process.
    error = kind("SOME_CODE", "what went wrong", "file.vox.h5", "/voxelmap")
    error.add_note("a note added on the way")
    copies = [pickle.loads(pickle.dumps(error, protocol)) for protocol in range(pickle.HIGHEST_PROTOCOL + 1)]
    for again in copies + [copy.copy(error), copy.deepcopy(error)]:
        assert type(again) is kind
        assert (again.code, again.message, again.file, again.object) == ("SOME_CODE", "what went wrong",
                                                                         "file.vox.h5", "/voxelmap")
        assert str(again) == str(error) == "SOME_CODE: what went wrong" and again.args == error.args
        assert again.__notes__ == ["a note added on the way"]


def load_in_worker(path: str) -> voxfmt.Body:
    return voxfmt.load(path)  # (a compiled function itself is no pickle: nanobind's functions are not)


def test_a_workers_error_arrives_as_the_same_class_with_its_code(tmp_path: Path) -> None:
    missing = tmp_path / "missing.vox.h5"
    spawn = multiprocessing.get_context("spawn")  # a fresh interpreter: everything crosses as pickles
    with concurrent.futures.ProcessPoolExecutor(1, mp_context=spawn) as pool:
        future = pool.submit(load_in_worker, str(missing))
        with pytest.raises(voxfmt.AssetError) as info:
            future.result(timeout=120)
    assert info.value.code == "FILE_NOT_FOUND" and str(missing) in info.value.message
    assert str(info.value).startswith("FILE_NOT_FOUND: ")


def test_contacts_batch_options_are_judged_as_contacts_judges_them(sphere: voxfmt.Body) -> None:
    # The compiled batch took a bool for 1 (point_budget=True: the root level only) and answered a float or an int
    # beyond int64 with a TypeError naming a private function; contacts() says BAD_OPTION.
    pose, poses = np.eye(4), np.repeat(translation(2 * RADIUS - 0.002)[None], 3, axis=0)
    tracker = voxfmt.Tracker(sphere, sphere)
    for options in ({"point_budget": True}, {"point_budget": 2.5}, {"point_budget": 2**70}, {"point_budget": "10"},
                    {"max_level": False}, {"max_level": 1.0}, {"max_level": 2**64}, {"time_budget_us": True},
                    {"time_budget_us": "100"}, {"time_budget_us": 2**2000}, {"cut_level": 1}, {"cut_level": None},
                    {"cut_level": "leaves"}, {"interpolation": 3}, {"interpolation": b"trilinear"}):
        error = raises(voxfmt.OptionError, "BAD_OPTION", voxfmt.contacts_batch, sphere, pose, sphere, poses,
                       **options)
        assert next(iter(options)) in error.message
        if not isinstance(options.get("cut_level", options.get("interpolation", "")), str):
            continue  # contacts() is compiled: a value that is no string is its TypeError
        raises(voxfmt.OptionError, "BAD_OPTION", voxfmt.contacts, sphere, pose, sphere, poses[0], **options)
    for interpolation in (None, 3):
        raises(voxfmt.OptionError, "BAD_OPTION", tracker.contacts, pose, poses[0], interpolation=interpolation)
        raises(voxfmt.OptionError, "BAD_OPTION", tracker.contacts_batch, pose, poses, interpolation=interpolation)
    # Valid values, NumPy's included, give what contacts() gives.
    for options in ({"point_budget": np.int64(int(sphere.levels[2]))}, {"max_level": np.int32(1)},
                    {"max_level": 10**6}, {"time_budget_us": np.float32(1e6)}, {"time_budget_us": 10**6},
                    {"cut_level": "points", "max_level": 2}, {"interpolation": "tricubic"}):
        batch = voxfmt.contacts_batch(sphere, pose, sphere, poses, **options)
        single = voxfmt.contacts(sphere, pose, sphere, poses[0], **options)
        assert list(batch.count) == [len(single)] * 3 and batch.max_depth[0] == single.max_depth


def test_packed_records_and_broadcast_points(sphere: voxfmt.Body) -> None:
    # A field of packed records is float64 with strides of 25 bytes, which no float64 view takes: it is copied, not
    # refused as "not numbers". A broadcast view of 24 bytes asking for 10^11 distances is refused up front.
    records = np.zeros(4, dtype=[("tag", "u1"), ("x", "f8"), ("y", "f8"), ("z", "f8")])
    records["x"] = [0.0, 0.05, 0.2, -0.3]
    points = np.lib.recfunctions.structured_to_unstructured(records[["x", "y", "z"]], copy=False)
    assert points.strides[0] == 25
    np.testing.assert_array_equal(sphere.signed_distance(points), sphere.signed_distance(np.array(points)))
    raises(voxfmt.InternalError, "OUT_OF_MEMORY", sphere.signed_distance, np.broadcast_to(np.zeros(3), (10**11, 3)))


def test_float32_rotations_are_rigid_enough(sphere: voxfmt.Body) -> None:
    # A rotation made in float32 (from a quaternion, then composed down a chain of bodies, as a simulator on a GPU
    # hands them over) is some 1e-6 from orthonormal: a 1e-6 rule refused 18 % of ten-link chains.
    rng = np.random.default_rng(7)

    def rotation32(q: np.ndarray) -> np.ndarray:
        w, x, y, z = (q / np.linalg.norm(q)).astype(np.float32)
        one, two = np.float32(1), np.float32(2)
        return np.array([[one - two * (y * y + z * z), two * (x * y - w * z), two * (x * z + w * y)],
                         [two * (x * y + w * z), one - two * (x * x + z * z), two * (y * z - w * x)],
                         [two * (x * z - w * y), two * (y * z + w * x), one - two * (x * x + y * y)]], np.float32)

    poses = np.repeat(np.eye(4, dtype=np.float32)[None], 2000, axis=0)
    for k in range(len(poses)):
        r = np.eye(3, dtype=np.float32)
        for _ in range(10):
            r = r @ rotation32(rng.normal(size=4))
        poses[k, :3, :3] = r
    off = np.abs(np.einsum("kji,kjl->kil", poses[:, :3, :3].astype(np.float64), poses[:, :3, :3].astype(np.float64))
                 - np.eye(3)).max(axis=(1, 2))
    assert off.max() > 1e-6  # the old rule's refusals are among them
    eye = np.repeat(np.eye(4, dtype=np.float32)[None], len(poses), axis=0)
    voxfmt.contacts_batch(sphere, eye, sphere, poses)
    voxfmt.BatchScene([sphere]).contacts(eye, poses)
    voxfmt.contacts(sphere, eye[0], sphere, poses[int(off.argmax())])
    slightly_scaled = np.eye(4)
    slightly_scaled[:3, :3] *= 1.0001  # 2e-4 off: a scale, still refused
    raises(voxfmt.PoseError, "BAD_POSE", voxfmt.contacts, sphere, np.eye(4), sphere, slightly_scaled)
