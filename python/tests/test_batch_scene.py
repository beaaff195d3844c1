"""voxfmt.BatchScene: every environment of a batch through the runtime's query on the CPU (runtime::BatchScene), the
contacts the CUDA kernel must find. Here on the CPU (CI has no GPU): against contacts_batch() on the same poses, with
several assets and pairs, shells and 1.x files, a contact buffer that overflows, and environments with bad poses or
pairs; and the checks of CUDA arrays, which run before a device is touched."""

from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np
import pytest
from conftest import RADIUS, icosphere, write_off

import voxfmt

REPO = Path(__file__).resolve().parents[2]


def random_poses(rng: np.random.Generator, k: int, spread: float, body: voxfmt.Body | None = None) -> np.ndarray:
    """k rotations about the body's centre of mass, which lands within `spread` of the origin."""
    poses = np.tile(np.eye(4, dtype=np.float32), (k, 1, 1))
    for i in range(k):
        q = rng.normal(size=4)
        q /= np.linalg.norm(q)
        w, x, y, z = q
        poses[i, :3, :3] = [[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]]
        centre = np.zeros(3) if body is None else np.asarray(body.center_of_mass)
        poses[i, :3, 3] = rng.normal(size=3) * spread - poses[i, :3, :3] @ centre
    return poses


def size(body: voxfmt.Body) -> float:
    lo, hi = body.bounds
    return float(np.linalg.norm(np.asarray(hi) - np.asarray(lo))) / 2


@pytest.fixture(scope="module")
def bodies(sphere: voxfmt.Body, tmp_path_factory: pytest.TempPathFactory) -> dict[str, voxfmt.Body]:
    folder = tmp_path_factory.mktemp("batch")
    # A shell: an open hemisphere baked as a sheet of thickness (spec §3.1, shell mode).
    v, f = icosphere(3)
    keep = [i for i, t in enumerate(f) if v[t].mean(axis=0)[2] > 0]
    write_off(folder / "cap.off", v * RADIUS, f[keep])
    voxfmt.bake(folder / "cap.off", folder / "cap.vox.h5", resolution=40, points=1500, shell_thickness=0.004,
                threads=1)
    # A format 1.1 file, which 2.x readers convert as they read (spec §3.4).
    sys.path.insert(0, str(REPO / "tests" / "spec"))
    import spec_fixture  # noqa: E402

    legacy = spec_fixture.write_legacy_fixture_h5py(str(folder / "legacy.vox.h5"), grid=spec_fixture.FINE_GRID)
    return {"sphere": sphere, "shell": voxfmt.load(folder / "cap.vox.h5"), "legacy": voxfmt.load(legacy)}


@pytest.mark.parametrize("pair", [("sphere", "sphere"), ("shell", "sphere"), ("legacy", "shell"),
                                  ("legacy", "legacy")])
def test_the_same_contacts_as_contacts_batch(bodies: dict[str, voxfmt.Body], pair: tuple[str, str]) -> None:
    a, b = bodies[pair[0]], bodies[pair[1]]
    rng = np.random.default_rng(5)
    pa = random_poses(rng, 300, 0.0, a)
    pb = random_poses(rng, 300, 0.5 * min(size(a), size(b)), b)
    for proximity in (0.0, 0.002):
        got = voxfmt.BatchScene([a, b]).contacts(pa, pb, stiffness=3e3, proximity=proximity, max_contacts=20000)
        ref = voxfmt.contacts_batch(a, pa.astype(np.float64), b, pb.astype(np.float64), stiffness=3e3,
                                    proximity=proximity, with_contacts=True)
        assert np.array_equal(got.count, ref.count)
        assert (got.count > 0).sum() > 50, "too few poses touch: the test no longer compares contacts"
        assert not got.overflow.any() and not got.error.any()
        np.testing.assert_allclose(got.max_depth, ref.max_depth, rtol=1e-6, atol=1e-9)
        scale = 1 + np.abs(ref.force).max(axis=1, keepdims=True)
        np.testing.assert_allclose(got.force / scale, ref.force / scale, atol=1e-5)
        np.testing.assert_allclose(got.torque / scale, ref.torque / scale, atol=1e-5)
        for k in np.flatnonzero(got.count)[:60]:
            n = got.count[k]
            rows = slice(ref.offsets[k], ref.offsets[k + 1])
            mine = sorted(zip(got.point_of_b[k, :n].astype(bool), got.point_index[k, :n], got.depths[k, :n]))
            theirs = sorted(zip(ref.point_of_b[rows], ref.point_index[rows], ref.depths[rows].astype(np.float32)))
            assert mine == theirs, k


def test_tricubic_reading_is_contacts_batchs(bodies: dict[str, voxfmt.Body]) -> None:
    a = b = bodies["sphere"]
    rng = np.random.default_rng(7)
    pa = random_poses(rng, 200, 0.0, a)
    pb = random_poses(rng, 200, 0.5 * size(a), b)
    scene = voxfmt.BatchScene([a, b])
    got = scene.contacts(pa, pb, stiffness=3e3, interpolation="tricubic")
    ref = voxfmt.contacts_batch(a, pa.astype(np.float64), b, pb.astype(np.float64), stiffness=3e3,
                                interpolation="tricubic")
    trilinear = scene.contacts(pa, pb, stiffness=3e3)
    assert np.array_equal(got.count, ref.count) and (got.count > 0).sum() > 50
    scale = 1 + np.abs(ref.force).max(axis=1, keepdims=True)
    np.testing.assert_allclose(got.force / scale, ref.force / scale, atol=1e-5)
    touching = got.max_depth > 0
    assert (got.force[touching] != trilinear.force[touching]).any(axis=1).mean() > 0.5, "tricubic read as trilinear"
    for bad in ("cubic", None, 3):
        with pytest.raises(voxfmt.OptionError, match="interpolation"):
            scene.contacts(pa, pb, interpolation=bad)
    poses = FakeCudaArray((8, 4, 4), "float32")
    with pytest.raises(voxfmt.OptionError, match="trilinearly only"):
        scene.contacts(poses, poses, interpolation="tricubic")


def test_pairs_and_pair_index(bodies: dict[str, voxfmt.Body]) -> None:
    scene = voxfmt.BatchScene([bodies["sphere"], bodies["shell"]], pairs=[(0, 1), (1, 0), (0, 0)])
    rng = np.random.default_rng(8)
    pa, pb = random_poses(rng, 90, 0.0), random_poses(rng, 90, 0.05)
    index = np.arange(90, dtype=np.int32) % 3
    got = scene.contacts(pa, pb, index, stiffness=10.0)
    for p, (a, b) in enumerate([("sphere", "shell"), ("shell", "sphere"), ("sphere", "sphere")]):
        envs = index == p
        ref = voxfmt.contacts_batch(bodies[a], pa[envs].astype(np.float64), bodies[b], pb[envs].astype(np.float64),
                                    stiffness=10.0)
        assert np.array_equal(got.count[envs], ref.count), (a, b)


def test_overflow_is_counted_and_the_rest_kept(sphere: voxfmt.Body) -> None:
    scene = voxfmt.BatchScene([sphere])
    pa = np.tile(np.eye(4, dtype=np.float32), (4, 1, 1))
    pb = pa.copy()
    pb[:, 0, 3] = [0.02, 0.04, 0.099, 0.5]  # deep, deep, grazing, apart
    full = scene.contacts(pa, pb, max_contacts=10000)
    few = scene.contacts(pa, pb, max_contacts=5)
    assert np.array_equal(few.count, full.count)
    assert np.array_equal(few.overflow, np.maximum(full.count - 5, 0))
    assert full.count[3] == 0 and full.count[0] > 5
    assert np.array_equal(few.depths, full.depths[:, :5])
    assert np.array_equal(few.force, full.force)


def test_cpu_poses_of_either_byte_order_or_integers_are_read_as_contacts_batch_reads_them(sphere: voxfmt.Body) -> None:
    scene = voxfmt.BatchScene([sphere])
    pa = np.tile(np.eye(4), (3, 1, 1))
    pb = pa.copy()
    pb[:, 0, 3] = [0.02, 0.04, 0.5]
    native = scene.contacts(pa, pb)
    swapped = scene.contacts(pa.astype(">f8"), pb.astype(">f8"))
    assert np.array_equal(swapped.count, native.count) and np.array_equal(swapped.force, native.force)
    integers = scene.contacts(pa.astype(np.int64), pa.astype(np.int32))
    assert np.array_equal(integers.count, scene.contacts(pa, pa).count)
    mixed = scene.contacts(pa.astype(np.float32), pb)  # float32 beside float64: both read as float64
    assert np.array_equal(mixed.count, native.count) and np.array_equal(mixed.force, native.force)
    assert np.array_equal(scene.contacts(pa.astype(np.float32), pa.astype(np.int64)).count, integers.count)
    # NumPy beside a CUDA array: the CUDA batch's coded error (a NumPy 2 array's device is the str "cpu").
    with pytest.raises(voxfmt.OptionError, match="poses_a: expected a CUDA array"):
        scene.contacts(pa.astype(np.float32), FakeCudaArray((3, 4, 4), "float32"))


def test_cpu_poses_of_half_or_long_double_are_read_as_float64(sphere: voxfmt.Body) -> None:
    # The batch reads float32 and float64; a pair of another float was passed on as it was and refused, though
    # contacts() and contacts_batch() take it.
    scene = voxfmt.BatchScene([sphere])
    pa = np.tile(np.eye(4), (3, 1, 1))
    pb = pa.copy()
    pb[:, 0, 3] = [0.02, 0.04, 0.5]
    for dtype in (np.float16, np.longdouble):
        a, b = pa.astype(dtype), pb.astype(dtype)
        converted = scene.contacts(a, b)
        as_float64 = scene.contacts(a.astype(np.float64), b.astype(np.float64))
        assert np.array_equal(converted.count, as_float64.count) and np.array_equal(converted.force, as_float64.force)
        assert np.array_equal(converted.count, voxfmt.contacts_batch(sphere, a, sphere, b).count)
    native = scene.contacts(pa, pb)
    assert np.array_equal(scene.contacts(pa.astype(np.float16), pb.astype(np.float32)).count, native.count)
    assert np.array_equal(scene.contacts(pa.astype(np.longdouble), pb).force, native.force)


def test_outputs_beyond_the_machines_memory_are_refused_up_front(sphere: voxfmt.Body) -> None:
    # 40,000 environments x 2^24 contacts would be 22 TB of zeroed outputs: a MemoryError or the kernel's kill.
    scene = voxfmt.BatchScene([sphere])
    poses = np.tile(np.eye(4, dtype=np.float32), (40000, 1, 1))
    with pytest.raises(voxfmt.InternalError, match="40000 environments x 16777216 contacts") as caught:
        scene.contacts(poses, poses, max_contacts=1 << 24)
    assert caught.value.code == "OUT_OF_MEMORY"
    assert scene.contacts(poses[:2], poses[:2], max_contacts=1 << 10).depths.shape == (2, 1 << 10)


def test_bad_environments_are_coded_errors(sphere: voxfmt.Body) -> None:
    scene = voxfmt.BatchScene([sphere])
    pa = np.tile(np.eye(4, dtype=np.float32), (3, 1, 1))
    pb = pa.copy()
    pb[1, 0, 0] = 2.0  # scaled: not rigid
    with pytest.raises(voxfmt.PoseError, match="environment 1"):
        scene.contacts(pa, pb)
    unchecked = scene.contacts(pa, pb, check=False)
    assert unchecked.error.tolist() == [0, 4, 0]
    with pytest.raises(voxfmt.OptionError, match="pair"):
        scene.contacts(pa, pa, np.array([0, 3, 0], dtype=np.int32))
    # Never another pair by a cast: 2**32 + 0 would wrap to pair 0, 0.9 floor to it.
    for index in (np.array([0, 2**32, 0], dtype=np.int64), np.array([0.0, 0.9, 0.0])):
        with pytest.raises(voxfmt.OptionError, match="pair_index"):
            scene.contacts(pa, pa, index)
    with pytest.raises(voxfmt.OptionError):
        voxfmt.BatchScene([sphere], pairs=[(0, 2)])
    with pytest.raises(voxfmt.OptionError, match="at least one Body"):
        voxfmt.BatchScene([])
    with pytest.raises(voxfmt.OptionError):
        scene.contacts(pa, pb[:2])
    # Judged from the shapes before any copy: a billion-environment view of one pose, or of one pair index, is a
    # coded error at once, not a 119 GB copy ending in MemoryError.
    huge = np.broadcast_to(np.eye(4, dtype=np.float32), (10**9, 4, 4))
    for call in (lambda: scene.contacts(pa[:1], huge), lambda: scene.contacts(pa, pa, np.broadcast_to(np.int32(0), (10**10,))),
                 lambda: scene.contacts(pa[0], pa[0])):
        with pytest.raises(voxfmt.OptionError) as error:
            call()
        assert error.value.code == "BAD_OPTION"
    with pytest.raises(voxfmt.InternalError) as error:
        scene.contacts(huge, huge)
    assert error.value.code == "OUT_OF_MEMORY"


def test_cuda_status_says_why() -> None:
    ok, text = voxfmt.cuda_status()
    assert isinstance(ok, bool) and text  # a device name, or why there is none (CI: no driver)


class FakeCudaArray:
    """What a CUDA array shows of itself (__cuda_array_interface__ v3), for the checks that run before any device is
    touched: they need no GPU."""

    def __init__(self, shape: tuple[int, ...], dtype: str, strides: tuple[int, ...] | None = None,
                 address: int = 0) -> None:
        self.shape = shape
        self.__cuda_array_interface__ = {"shape": shape, "typestr": np.dtype(dtype).str, "data": (address, False),
                                         "version": 3, "strides": strides}


def cuda_outputs(envs: int, k: int = 0, **replace: FakeCudaArray) -> voxfmt.BatchResult:
    arrays = {"count": FakeCudaArray((envs,), "int32"), "max_depth": FakeCudaArray((envs,), "float32"),
              "force": FakeCudaArray((envs, 3), "float32"), "torque": FakeCudaArray((envs, 3), "float32"),
              "overflow": FakeCudaArray((envs,), "int32"), "error": FakeCudaArray((envs,), "int32")}
    if k:
        arrays |= {"points": FakeCudaArray((envs, k, 3), "float32"), "normals": FakeCudaArray((envs, k, 3), "float32"),
                   "depths": FakeCudaArray((envs, k), "float32"), "point_index": FakeCudaArray((envs, k), "int32"),
                   "point_of_b": FakeCudaArray((envs, k), "uint8")}
    arrays |= replace
    return voxfmt.BatchResult(**arrays)


@pytest.mark.parametrize(("change", "message"), [
    ({"count": FakeCudaArray((8,), "int64")}, "out.count: expected int32, got int64"),
    ({"force": FakeCudaArray((8, 4), "float32")}, r"out.force: expected shape \(8, 3\), got \(8, 4\)"),
    ({"torque": FakeCudaArray((8, 3), "float32", strides=(4, 32))}, "out.torque: not C-contiguous"),
    ({"error": np.zeros(8, dtype=np.int32)}, "out.error: expected a CUDA array"),
    ({"depths": FakeCudaArray((8, 3), "float32")}, r"out.depths: expected shape \(8, 4\)"),
])
def test_cuda_outputs_of_the_wrong_kind_are_coded_errors_not_copies(
        sphere: voxfmt.Body, change: dict[str, object], message: str) -> None:
    # Checked before the device is looked for: the same error with a GPU or without one.
    scene = voxfmt.BatchScene([sphere])
    poses = FakeCudaArray((8, 4, 4), "float32")
    with pytest.raises(voxfmt.OptionError, match=message):
        scene.contacts(poses, poses, max_contacts=4, out=cuda_outputs(8, 4, **change))


def test_cuda_poses_of_the_wrong_kind_are_coded_errors(sphere: voxfmt.Body) -> None:
    scene = voxfmt.BatchScene([sphere])
    good = FakeCudaArray((8, 4, 4), "float32")
    with pytest.raises(voxfmt.OptionError, match="poses_a: expected float32, got float64"):
        scene.contacts(FakeCudaArray((8, 4, 4), "float64"), good)
    with pytest.raises(voxfmt.OptionError, match=r"poses_b: expected shape \(8, 4, 4\)"):
        scene.contacts(good, FakeCudaArray((7, 4, 4), "float32"))
    with pytest.raises(voxfmt.OptionError, match="pair_index: expected int32"):
        scene.contacts(good, good, FakeCudaArray((8,), "int64"))
    with pytest.raises(voxfmt.OptionError, match=r"poses_a: expected shape \(E, 4, 4\), got \(\)"):
        scene.contacts(FakeCudaArray((), "float32"), good)
    with pytest.raises(voxfmt.OptionError, match="out: expected a BatchResult"):
        scene.contacts(good, good, out={"count": None})
    with pytest.raises(voxfmt.OptionError, match=r"out.points: missing \(out= made for max_contacts=0"):
        scene.contacts(good, good, max_contacts=3, out=cuda_outputs(8, 0))
    with pytest.raises(voxfmt.OptionError, match="max_contacts"):
        scene.contacts(good, good, max_contacts=-1)


def test_a_well_formed_cuda_call_without_a_device_says_so(sphere: voxfmt.Body) -> None:
    if voxfmt.cuda_status()[0]:
        pytest.skip("a CUDA device is present: the fake arrays would be launched")
    scene = voxfmt.BatchScene([sphere])
    poses = FakeCudaArray((8, 4, 4), "float32")
    with pytest.raises(voxfmt.InternalError, match="no CUDA device"):
        scene.contacts(poses, poses, max_contacts=2, out=cuda_outputs(8, 2))
    assert voxfmt.cuda_status() is voxfmt.cuda_status()  # asked once per process


class RecordingDeviceScene:
    """Stands in for the compiled device scene: records what a launch would be given, and on which device."""

    def __init__(self, cuda: "RecordedCuda | None" = None) -> None:
        self.calls: list[tuple[object, ...]] = []
        self.cuda = cuda
        self.launched_on: list[int] = []

    def run(self, **args: object) -> None:
        self.calls.append(args)
        if self.cuda is not None:
            self.launched_on.append(self.cuda.current_device)


class RecordedCuda:
    """Stands in for CUDA's answers (batch._cuda): which device holds an address (`held`, by address), the current
    device, and the devices made current in turn."""

    def __init__(self, held: dict[int, int], current: int = 0) -> None:
        self.held = held
        self.current_device = current
        self.made_current: list[int] = []
        self.synchronized: list[int] = []

    def device_of(self, address: int) -> tuple[int, str]:
        return (self.held[address], "") if address in self.held else (-1, "cudaErrorInvalidValue: not a CUDA address")

    def current(self) -> tuple[int, str]:
        return self.current_device, ""

    def make_current(self, device: int) -> str:
        self.made_current.append(device)
        self.current_device = device
        return ""

    def synchronize(self, stream: int) -> str:
        self.synchronized.append(stream)
        return ""


@pytest.mark.parametrize("k", [0, 3])
def test_arrays_that_only_show_the_cuda_interface_are_launched_in_place(
        sphere: voxfmt.Body, k: int, monkeypatch: pytest.MonkeyPatch) -> None:
    # Every array by the address its __cuda_array_interface__ gives (nothing converted, nothing copied), in the
    # order the device scene takes them; no device needed: the launch is recorded, not made.
    from voxfmt import batch

    monkeypatch.setattr(batch, "cuda_status", lambda: (True, "a recorded device"))
    scene = voxfmt.BatchScene([sphere])
    recorder = RecordingDeviceScene()
    scene._device_scenes[0] = recorder
    names = [name for name, _, _ in batch._output_specs(8, k)]
    addresses = [0xa0000, 0xb0000, 0xc0000] + [0x1000 * (n + 1) for n in range(len(names))]
    monkeypatch.setattr(batch, "_cuda", RecordedCuda({address: 0 for address in addresses}))
    outputs = voxfmt.BatchResult(**{name: FakeCudaArray(shape, dtype, address=0x1000 * (n + 1))
                                    for n, (name, dtype, shape) in enumerate(batch._output_specs(8, k))})
    poses_a = FakeCudaArray((8, 4, 4), "float32", address=0xa0000)
    poses_b = FakeCudaArray((8, 4, 4), "float32", address=0xb0000)
    pairs = FakeCudaArray((8,), "int32", address=0xc0000)
    assert scene.contacts(poses_a, poses_b, pairs, stiffness=5.0, proximity=0.25, max_contacts=k, out=outputs,
                          stream=77, check=False) is outputs
    (args,) = recorder.calls
    expected = {"envs": 8, "poses_a": 0xa0000, "poses_b": 0xb0000, "pair_index": 0xc0000, "proximity": 0.25,
                "stiffness": 5.0, "max_contacts": k, "stream": 77,
                "points": 0, "normals": 0, "depths": 0, "point_index": 0, "point_of_b": 0}
    expected |= {name: 0x1000 * (n + 1) for n, name in enumerate(names)}
    assert args == expected
    # The names are the compiled device scene's own (where this build has one): a keyword it lacks would fail.
    device_scene = getattr(voxfmt._voxfmt, "_DeviceScene", None)
    if device_scene is not None:
        signature = device_scene.run.__doc__ or ""
        for name in expected:
            assert f"{name}: " in signature, (name, signature)


class FakeCudaErrors(FakeCudaArray):
    """An error output the check can read (all environments fine), as a framework's array answers max()."""

    def __len__(self) -> int:
        return self.shape[0]

    def max(self) -> int:
        return 0


def test_a_checked_call_waits_for_its_own_stream_before_reading_the_errors(
        sphere: voxfmt.Body, monkeypatch: pytest.MonkeyPatch) -> None:
    # A stream= that is not the framework's current one: the check reads `error` on the current stream, so the
    # launch's stream is waited for first (after the launch); an unchecked call (a CUDA graph) never waits.
    from voxfmt import batch

    monkeypatch.setattr(batch, "cuda_status", lambda: (True, "a recorded device"))
    cuda = RecordedCuda({0xa0000: 0, 0xb0000: 0} | {0x1000 * (n + 1): 0 for n in range(6)})
    monkeypatch.setattr(batch, "_cuda", cuda)
    scene = voxfmt.BatchScene([sphere])
    scene._device_scenes[0] = RecordingDeviceScene()
    arrays = {name: (FakeCudaErrors if name == "error" else FakeCudaArray)(shape, dtype, address=0x1000 * (n + 1))
              for n, (name, dtype, shape) in enumerate(batch._output_specs(8, 0))}
    outputs = voxfmt.BatchResult(**arrays)
    poses_a = FakeCudaArray((8, 4, 4), "float32", address=0xa0000)
    poses_b = FakeCudaArray((8, 4, 4), "float32", address=0xb0000)
    scene.contacts(poses_a, poses_b, out=outputs, stream=77, check=False)
    assert cuda.synchronized == []
    scene.contacts(poses_a, poses_b, out=outputs, stream=77)
    assert cuda.synchronized == [77] and len(scene._device_scenes[0].calls) == 2


def cuda_call_on_recorded_devices(sphere: voxfmt.Body, monkeypatch: pytest.MonkeyPatch, held: dict[int, int],
                                  current: int) -> tuple[voxfmt.BatchScene, RecordedCuda]:
    """A scene whose device scenes record their launches, CUDA's answers recorded (`held`: device by address)."""
    from voxfmt import batch

    monkeypatch.setattr(batch, "cuda_status", lambda: (True, "a recorded device"))
    cuda = RecordedCuda(held, current)
    monkeypatch.setattr(batch, "_cuda", cuda)
    scene = voxfmt.BatchScene([sphere])
    for device in range(4):
        scene._device_scenes[device] = RecordingDeviceScene(cuda)
    return scene, cuda


def addressed_outputs(envs: int, first: int) -> voxfmt.BatchResult:
    from voxfmt import batch

    return voxfmt.BatchResult(**{name: FakeCudaArray(shape, dtype, address=first + 0x100 * n)
                                 for n, (name, dtype, shape) in enumerate(batch._output_specs(envs, 0))})


# Poses at 0xa000 and 0xb000, the outputs from 0x2000 (addressed_outputs): all on device 2, as CUDA would say.
POSES_BY_ADDRESS = (FakeCudaArray((8, 4, 4), "float32", address=0xa000),
                    FakeCudaArray((8, 4, 4), "float32", address=0xb000))
ALL_ON_DEVICE_2 = {0xa000: 2, 0xb000: 2} | {0x2000 + 0x100 * n: 2 for n in range(6)}


def test_arrays_that_name_no_device_are_launched_where_cuda_says_they_are(
        sphere: voxfmt.Body, monkeypatch: pytest.MonkeyPatch) -> None:
    # Only __cuda_array_interface__ (Numba, JAX, ...): the device comes from CUDA by the poses' address, is made
    # current for the launch (the caller's current device 0 restored after), and the scene of that device runs.
    scene, cuda = cuda_call_on_recorded_devices(sphere, monkeypatch, ALL_ON_DEVICE_2, current=0)
    scene.contacts(*POSES_BY_ADDRESS, out=addressed_outputs(8, 0x2000), check=False)
    assert [len(scene._device_scenes[d].calls) for d in range(4)] == [0, 0, 1, 0]
    assert scene._device_scenes[2].launched_on == [2]
    assert cuda.made_current == [2, 0] and cuda.current_device == 0


@pytest.mark.parametrize(("move", "message"), [
    ({0xb000: 1}, r"poses_b: on CUDA device 1, the poses on 2"),
    ({0x2300: 3}, r"out.torque: on CUDA device 3, the poses on 2"),
    ({0xa000: None}, r"poses_a: CUDA cannot tell which device holds it \(cudaErrorInvalidValue"),
])
def test_arrays_elsewhere_or_unknown_to_cuda_are_coded_errors(
        sphere: voxfmt.Body, monkeypatch: pytest.MonkeyPatch, move: dict[int, int | None], message: str) -> None:
    held = {address: device for address, device in (ALL_ON_DEVICE_2 | move).items() if device is not None}
    scene, cuda = cuda_call_on_recorded_devices(sphere, monkeypatch, held, current=0)
    with pytest.raises(voxfmt.OptionError, match=message):
        scene.contacts(*POSES_BY_ADDRESS, out=addressed_outputs(8, 0x2000), check=False)
    assert all(not s.calls for s in scene._device_scenes.values()) and cuda.made_current == []


class FakeTorchLikeArray(FakeCudaArray):
    """A CUDA array that names its device, as a PyTorch tensor's device.index does."""

    def __init__(self, shape: tuple[int, ...], dtype: str, address: int, device: int) -> None:
        super().__init__(shape, dtype, address=address)
        self.device = type("Device", (), {"index": device})()


def test_an_array_naming_another_device_than_cuda_found_for_the_poses_is_refused(
        sphere: voxfmt.Body, monkeypatch: pytest.MonkeyPatch) -> None:
    # poses_a names no device (CUDA finds it on 2), poses_b names device 1: each check passed before (one skipped
    # the comparison while the device was unknown, the other every array that names its own), and the kernel ran
    # on 2 with a pointer into 1's memory.
    scene, cuda = cuda_call_on_recorded_devices(sphere, monkeypatch, ALL_ON_DEVICE_2, current=0)
    poses_b = FakeTorchLikeArray((8, 4, 4), "float32", address=0xb000, device=1)
    with pytest.raises(voxfmt.OptionError, match=r"poses_b: on CUDA device 1, the poses on 2"):
        scene.contacts(POSES_BY_ADDRESS[0], poses_b, out=addressed_outputs(8, 0x2000), check=False)
    assert all(not s.calls for s in scene._device_scenes.values())


@pytest.mark.parametrize("options", [{"proximity": math.nan}, {"proximity": -1.0}, {"stiffness": math.inf},
                                     {"stiffness": -5.0}])
def test_cuda_options_are_judged_as_the_cpus(sphere: voxfmt.Body, options: dict[str, float]) -> None:
    # The CUDA path passed them to the kernel: a NaN proximity culled every root (0 contacts, silently).
    scene = voxfmt.BatchScene([sphere])
    poses = FakeCudaArray((8, 4, 4), "float32")
    for on in (poses, np.repeat(np.eye(4, dtype=np.float32)[None], 8, axis=0)):
        with pytest.raises(voxfmt.OptionError, match=f"{next(iter(options))} must be finite and >= 0"):
            scene.contacts(on, on, **options)


def test_a_tie_goes_to_as_points_as_on_the_gpu(sphere_asset: Path) -> None:
    # Two loads of one asset at one position: a tie of size, point count and position. The CPU batch broke it by
    # the objects' addresses (pairs (0, 1) and (1, 0) alike), the GPU gives it to A's points: which shell the
    # contacts come from differed between the two batches.
    a, b = voxfmt.load(sphere_asset), voxfmt.load(sphere_asset)
    scene = voxfmt.BatchScene([a, b], [(0, 1), (1, 0)])
    poses_a = np.repeat(np.eye(4, dtype=np.float32)[None], 2, axis=0)
    poses_b = poses_a.copy()
    c, s = np.cos(0.3), np.sin(0.3)
    poses_b[:, :3, :3] = [[c, -s, 0], [s, c, 0], [0, 0, 1]]
    r = scene.contacts(poses_a, poses_b, np.array([0, 1], np.int32), max_contacts=4, proximity=0.002)
    assert (r.count > 0).all()
    assert not r.point_of_b[:, : int(r.count.min())].any()  # A's points, whichever body A is
    # contacts_batch() is contacts() for many poses, ties included (the address rule, either order).
    for first, second in ((a, b), (b, a)):
        single = voxfmt.contacts(first, poses_a[0], second, poses_b[0], proximity=0.002)
        batch = voxfmt.contacts_batch(first, poses_a[:1], second, poses_b[:1], proximity=0.002)
        assert int(batch.count[0]) == len(single)


def test_a_scenes_bodies_and_pairs_are_read_only(sphere: voxfmt.Body) -> None:
    # A device keeps the scene of its first call: pairs changed after it would be run with the old table.
    scene = voxfmt.BatchScene([sphere, sphere], [(0, 1)])
    with pytest.raises(AttributeError):
        scene.pairs = [(1, 0)]  # type: ignore[misc]
    with pytest.raises(AttributeError):
        scene.bodies.append(sphere)  # type: ignore[attr-defined]
    assert scene.pairs == ((0, 1),) and len(scene.bodies) == 2


def test_read_only_cuda_outputs_are_refused(sphere: voxfmt.Body) -> None:
    scene = voxfmt.BatchScene([sphere])
    poses = FakeCudaArray((8, 4, 4), "float32")
    out = cuda_outputs(8)
    out.force.__cuda_array_interface__["data"] = (0x2000, True)
    with pytest.raises(voxfmt.OptionError, match="out.force: read-only"):
        scene.contacts(poses, poses, out=out)


def test_new_outputs_are_refused_for_arrays_no_framework_allocates(sphere: voxfmt.Body) -> None:
    scene = voxfmt.BatchScene([sphere])
    with pytest.raises(voxfmt.OptionError, match="use PyTorch or CuPy, or pass out="):
        scene.new_outputs(FakeCudaArray((8, 4, 4), "float32"), 4)
    with pytest.raises(voxfmt.OptionError, match="expected a CUDA array"):
        scene.new_outputs(np.zeros((8, 4, 4), np.float32))
    with pytest.raises(voxfmt.OptionError, match="max_contacts"):
        scene.new_outputs(FakeCudaArray((8, 4, 4), "float32"), -1)


def test_the_first_failing_environment_is_named_with_its_own_reason(sphere: voxfmt.Body) -> None:
    scene = voxfmt.BatchScene([sphere])
    pa = np.tile(np.eye(4, dtype=np.float32), (6, 1, 1))
    pb = pa.copy()
    pb[1, :3, :3] = np.diag([1, 1, -1])  # a reflection
    pb[4, 0, 3] = np.inf  # non-finite: a different reason, later
    with pytest.raises(voxfmt.PoseError, match=r"environment 1: .*reflection.*2 environments failed"):
        scene.contacts(pa, pb)


def test_arguments_that_would_be_truncated_or_misread_are_refused(sphere: voxfmt.Body) -> None:
    # A float pair or option would be floored (pair 0.9 runs pair 0), a bool taken for an integer.
    for pairs in ([(0.9, 0)], [("0", "0")], [(True, 0)], [(0, 0, 0)], 5):
        with pytest.raises(voxfmt.OptionError):
            voxfmt.BatchScene([sphere], pairs=pairs)  # type: ignore[arg-type]
    for bodies in (["sphere.vox.h5"], sphere, None):
        with pytest.raises(voxfmt.OptionError):
            voxfmt.BatchScene(bodies)  # type: ignore[arg-type]
    scene = voxfmt.BatchScene([sphere])
    poses = np.tile(np.eye(4, dtype=np.float32), (2, 1, 1))
    for options in ({"max_contacts": 2.7}, {"max_contacts": "3"}, {"stiffness": "x"}, {"proximity": None},
                    {"threads": 2.5}, {"threads": True}):
        with pytest.raises(voxfmt.OptionError):
            scene.contacts(poses, poses, **options)


def test_poses_too_many_to_copy_are_refused_before_the_copy(sphere: voxfmt.Body) -> None:
    # A broadcast view of 5e9 poses takes no memory; its contiguous copy would take 320 GB.
    scene = voxfmt.BatchScene([sphere])
    poses = np.broadcast_to(np.eye(4, dtype=np.float32), (5 * 10**9, 4, 4))
    with pytest.raises(voxfmt.InternalError) as caught:
        scene.contacts(poses, poses)
    assert caught.value.code == "OUT_OF_MEMORY"
