"""Thousands of environments in one call: voxfmt.BatchScene.

A scene holds assets (Bodies) and the pairs an environment may hold; each call takes, per environment, a pair
index and the two bodies' 4x4 poses, and returns per environment the contact count, the deepest penetration, the
penalty wrench on A and, on request, the contacts themselves in buffers of a size you choose, with the number that
did not fit always reported (``overflow``). NumPy poses run on the CPU; CUDA poses (PyTorch, CuPy: anything with
``__cuda_array_interface__``) run on the GPU, on your stream, without a copy or an allocation when you pass the
outputs (``out=``), so the call can be captured in a CUDA graph. The CPU runs the runtime's query
(runtime::BatchScene), the device the query core's environment; both find the same contacts, so code written for
the GPU runs everywhere and gives the same answers.
"""

from __future__ import annotations

import contextlib
import functools
import math
import operator
import os
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from ._errors import InternalError, OptionError, PoseError
from ._voxfmt import Body, _batch_cpu, _cuda_status

__all__ = ["BatchScene", "BatchResult", "cuda_status"]

# Why an environment has no result (the `error` output).
_ENV_ERRORS = {
    1: "its tree is deeper than the depth-first walk takes (48 levels; the device walks level by level)",
    2: "a pose has a non-finite entry",
    3: "a pose's last row is not 0 0 0 1",
    4: "a pose's rotation part is not orthonormal (|R^T R - I| > 1e-5)",
    5: "a pose's rotation part has determinant -1 (a reflection)",
    6: "its pair index names no pair of the scene",
    7: "a level of its walk opened more nodes than the device's frontier holds (a fault of voxfmt: please report it)",
}


@functools.cache
def cuda_status() -> tuple[bool, str]:
    """(True, device name) if this build of voxfmt has CUDA support and a device can be used, else (False, why).
    Asked once per process (a device does not come or go while it runs)."""
    ok, text = _cuda_status()
    return bool(ok), str(text)


@dataclass
class BatchResult:
    """Per-environment results (E environments), as arrays of the poses' kind (NumPy, PyTorch or CuPy) and device.
    ``force``/``torque`` (E, 3) act on A (torque about A's centre of mass in the world); ``overflow`` counts the
    contacts beyond ``max_contacts``; ``error`` is 0, or why the environment has no result. With max_contacts = K > 0,
    environment e's contacts are rows ``[:count[e]]`` (at most K) of ``points[e]``, ``normals[e]`` (K, 3),
    ``depths[e]``, ``point_index[e]`` and ``point_of_b[e]`` (K,)."""

    count: Any
    max_depth: Any
    force: Any
    torque: Any
    overflow: Any
    error: Any
    points: Any = None
    normals: Any = None
    depths: Any = None
    point_index: Any = None
    point_of_b: Any = None


def _on_cuda(array: Any) -> bool:
    device = getattr(array, "device", None)
    return hasattr(array, "__cuda_array_interface__") or getattr(device, "type", None) == "cuda"


def _cpu_poses(poses_a: Any, poses_b: Any) -> tuple[Any, Any]:
    """Poses for the CPU batch, as contacts_batch takes them: float32 or float64 as given where both are of one (the
    GPU's float32 gives the same results here), else both as float64 (integers, mixed dtypes, float16, long double);
    in this machine's byte order. What is not numbers is left for the batch to refuse with its message."""
    a, b = np.asarray(poses_a), np.asarray(poses_b)
    # The batch reads float32 and float64 only: a pair of float16 or of long double is converted like the rest.
    if a.dtype.kind == b.dtype.kind == "f" and a.dtype.itemsize == b.dtype.itemsize and a.dtype.itemsize in (4, 8):
        a, b = a.astype(a.dtype.newbyteorder("="), copy=False), b.astype(b.dtype.newbyteorder("="), copy=False)
    elif a.dtype.kind in "iuf" and b.dtype.kind in "iuf":
        a, b = a.astype(np.float64, copy=False), b.astype(np.float64, copy=False)
    return np.ascontiguousarray(a), np.ascontiguousarray(b)


def _declared_device(array: Any) -> int | None:
    """The CUDA device an array names (a PyTorch tensor's ``device.index``, a CuPy array's ``device.id``), or None:
    an array that shows only ``__cuda_array_interface__`` names none, and CUDA tells its device from its address."""
    device = getattr(array, "device", None)
    for attribute in ("index", "id"):  # torch.device, cupy.cuda.Device (a NumPy 2 array's device is the str "cpu")
        index = getattr(device, attribute, None)
        if isinstance(index, (int, np.integer)) and not isinstance(index, bool):
            return int(index)
    return None


class _NativeCuda:
    """The CUDA runtime's answers the batch needs beyond the launch: which device holds an address, which is
    current, and making one current (the compiled module's; a test puts a recording one in its place)."""

    @staticmethod
    def _call(name: str, *args: Any) -> Any:
        from . import _voxfmt

        return getattr(_voxfmt, name)(*args)

    def device_of(self, address: int) -> tuple[int, str]:
        return self._call("_cuda_device_of", address)

    def current(self) -> tuple[int, str]:
        return self._call("_cuda_current_device")

    def make_current(self, device: int) -> str:
        return self._call("_cuda_make_current", device)

    def synchronize(self, stream: int) -> str:
        return self._call("_cuda_synchronize_stream", stream)


_cuda = _NativeCuda()


def _cuda_interface(name: str, array: Any) -> dict[str, Any]:
    try:
        interface = array.__cuda_array_interface__
    except AttributeError:
        raise OptionError("BAD_OPTION", f"{name}: expected a CUDA array (PyTorch, CuPy, or anything with "
                          f"__cuda_array_interface__), got {type(array).__name__}") from None
    except Exception as e:  # noqa: BLE001 (any framework's refusal, e.g. a PyTorch tensor that requires grad)
        raise OptionError("BAD_OPTION", f"{name}: its __cuda_array_interface__ is not available: {e}") from None
    return dict(interface)


def _pointer(name: str, array: Any) -> int:
    """The device address of a checked CUDA array (0 for None): what the kernel reads and writes."""
    return 0 if array is None else int(_cuda_interface(name, array)["data"][0])


def _check_cuda_array(name: str, array: Any, dtype: str, shape: tuple[int, ...], device: int | None) -> None:
    """A coded error (OptionError) unless `array` is a C-contiguous CUDA array of `dtype` and `shape`, on `device`
    where both name theirs (_launch_device asks CUDA for the others): the kernel reads and writes the caller's
    memory itself, never a converted copy."""
    interface = _cuda_interface(name, array)
    got = np.dtype(interface["typestr"])
    if got != np.dtype(dtype):
        raise OptionError("BAD_OPTION", f"{name}: expected {dtype}, got {got}")
    got_shape = tuple(int(n) for n in interface["shape"])
    if got_shape != shape:
        raise OptionError("BAD_OPTION", f"{name}: expected shape {shape}, got {got_shape}")
    strides = interface.get("strides")
    if strides is not None:
        expected, step = [], got.itemsize
        for n in reversed(shape):
            expected.append(step)
            step *= n
        if any(n > 1 and s != e for n, s, e in zip(shape, strides, reversed(expected))):
            raise OptionError("BAD_OPTION", f"{name}: not C-contiguous (strides {tuple(strides)}): pass a contiguous "
                              "array (.contiguous() in PyTorch, cupy.ascontiguousarray)")
    named = _declared_device(array)
    if named is not None and device is not None and named != device:
        raise OptionError("BAD_OPTION", f"{name}: on CUDA device {named}, the poses on {device}")


def _launch_device(arrays: dict[str, Any], device: int | None) -> int:
    """The device of the launch: the one the poses name, else the one CUDA says holds the first array (poses_a);
    every array that names no device must be there too (asked of CUDA by its address: an array on another device is
    a coded error, never a launch that reads another device's memory)."""
    for name, array in arrays.items():
        if array is None or _declared_device(array) is not None:
            continue
        address = _pointer(name, array)
        held, why = _cuda.device_of(address) if address else _cuda.current()
        if held < 0:
            raise OptionError("BAD_OPTION", f"{name}: CUDA cannot tell which device holds it ({why})")
        if device is None:
            device = int(held)
        elif held != device:
            raise OptionError("BAD_OPTION", f"{name}: on CUDA device {held}, the poses on {device}")
    # Arrays that name their device, against the one CUDA found (poses_a may name none, poses_b another).
    for name, array in arrays.items():
        named = None if array is None else _declared_device(array)
        if named is not None and named != device:
            raise OptionError("BAD_OPTION", f"{name}: on CUDA device {named}, the poses on {device}")
    return int(device)  # type: ignore[arg-type]  (set: the first array, poses_a, names its device or CUDA did)


def _output_specs(envs: int, k: int) -> list[tuple[str, str, tuple[int, ...]]]:
    specs = [("count", "int32", (envs,)), ("max_depth", "float32", (envs,)), ("force", "float32", (envs, 3)),
             ("torque", "float32", (envs, 3)), ("overflow", "int32", (envs,)), ("error", "int32", (envs,))]
    if k > 0:
        specs += [("points", "float32", (envs, k, 3)), ("normals", "float32", (envs, k, 3)),
                  ("depths", "float32", (envs, k)), ("point_index", "int32", (envs, k)),
                  ("point_of_b", "uint8", (envs, k))]
    return specs


def _stream_of(array: Any) -> int:
    """The stream a CUDA array's producer works on: its framework's current one (PyTorch, CuPy), else the one its
    __cuda_array_interface__ names (v3), else the legacy default stream."""
    module = type(array).__module__.split(".")[0]
    if module == "torch":
        torch = __import__("torch")
        return int(torch.cuda.current_stream(array.device).cuda_stream)
    if module == "cupy":
        return int(__import__("cupy").cuda.get_current_stream().ptr)
    stream = _cuda_interface("poses_a", array).get("stream")
    return int(stream) if stream else 0


@contextlib.contextmanager
def _current_device(array: Any, device: int) -> Iterator[None]:
    """`device` made current while the scene is uploaded and the kernel launched (the poses' device, whichever is
    current in the caller's framework; for other arrays through CUDA itself, the previous device restored after)."""
    module = type(array).__module__.split(".")[0]
    if module == "torch":
        with __import__("torch").cuda.device(device):
            yield
    elif module == "cupy":
        with __import__("cupy").cuda.Device(device):
            yield
    else:
        previous, why = _cuda.current()
        if previous < 0:
            raise InternalError("INTERNAL", f"no current CUDA device: {why}")
        if previous == device:
            yield
            return
        why = _cuda.make_current(device)
        if why:
            raise InternalError("INTERNAL", f"CUDA device {device} cannot be made current: {why}")
        try:
            yield
        finally:
            _cuda.make_current(previous)


def _framework(array: Any) -> Any:
    """The module that made a CUDA array (torch or cupy): it allocates the outputs and names the stream."""
    module = type(array).__module__.split(".")[0]
    if module in ("torch", "cupy"):
        return __import__(module)
    raise OptionError("BAD_OPTION", f"CUDA arrays of {module} are not supported: use PyTorch or CuPy, or pass out=")


def _not_a_number_kind(value: Any) -> bool:
    """Bools, strings, time spans: things float() or an index may read, but no length, stiffness or count. A 0-d
    array (NumPy's, or a framework's scalar) is judged by its dtype where NumPy names one."""
    if isinstance(value, (bool, np.bool_, str, bytes, np.timedelta64, np.datetime64)):
        return True
    kind = getattr(getattr(value, "dtype", None), "kind", None)
    return kind is not None and kind not in "iuf"


def _real(name: str, value: Any) -> float:
    """A number option: an int or a float, NumPy's, a 0-d array, a Fraction: what float() reads, but not a bool, a
    string, a time span, a complex number or None."""
    if _not_a_number_kind(value) or not hasattr(value, "__float__"):
        raise OptionError("BAD_OPTION", f"{name}: expected a number, got {value!r}")
    try:
        return float(value)
    except OverflowError:
        raise OptionError("BAD_OPTION", f"{name}: {value} is beyond a double") from None
    except (TypeError, ValueError):  # an array of more than one element, a framework's refusal
        raise OptionError("BAD_OPTION", f"{name}: expected a number, got {value!r}") from None


def _whole(name: str, value: Any, low: int, high: int) -> int:
    """An integer option in low..high (an int, NumPy's, a 0-d integer array): a float would be floored and a bool
    taken for 0 or 1, silently."""
    try:
        number = None if _not_a_number_kind(value) else operator.index(value)
    except TypeError:
        number = None
    if number is None:
        raise OptionError("BAD_OPTION", f"{name}: expected an integer, got {value!r}")
    if not low <= number <= high:
        raise OptionError("BAD_OPTION", f"{name}: {number} is not in {low}..{high}")
    return number


def _one_of(name: str, value: Any, choices: tuple[str, str]) -> str:
    """A named choice, as the compiled checks word its refusal (which a value that is no string never reaches)."""
    if not isinstance(value, str) or value not in choices:
        raise OptionError("BAD_OPTION", f"{name} must be {choices[0]!r} or {choices[1]!r}, not {value!r}")
    return value


def _refuse_beyond_memory(what: str, needed_bytes: float) -> None:
    """Refused with figures before anything is allocated, not a MemoryError or the kernel's out-of-memory kill
    (the limit the C++ batch applies too: 3/4 of this machine's memory)."""
    memory = float(os.sysconf("SC_PHYS_PAGES")) * float(os.sysconf("SC_PAGE_SIZE"))
    if needed_bytes > 0.75 * memory:
        raise InternalError("OUT_OF_MEMORY", f"{what} need about {needed_bytes / 1e9:.1f} GB, more than 3/4 of this "
                                             f"machine's {memory / 1e9:.0f} GB (smaller batches)")


def _refuse_beyond_pose_memory(poses_a: Any, poses_b: Any) -> None:
    """contacts_batch's memory, judged before anything is made: the poses as matrices and rigid transforms of both
    sides and the per-pose outputs (with_contacts' own memory grows with what is found and is not known before)."""
    count = max(_pose_count(poses_a), _pose_count(poses_b))
    _refuse_beyond_memory(f"{count} poses' matrices, transforms and outputs", count * 1024.0)


def _poses_once(poses: Any) -> Any:
    """A list or tuple of poses as one array, made once: np.shape and the binding's two readings would each convert
    it again (three conversions: 60 ms of 20,000 poses). Numbers become float64, as the binding reads them; anything
    else is left for the binding to refuse with its own message."""
    if not isinstance(poses, (list, tuple)):
        return poses
    try:
        array = np.asarray(poses)
    except ValueError:  # a ragged list
        raise OptionError("BAD_OPTION", "poses: expected (K, 4, 4) matrices or one (4, 4), got a ragged list") from None
    return np.asarray(array, dtype=np.float64) if array.dtype.kind in "iuf" else poses


def _pose_count(poses: Any) -> int:
    """K of a (K, 4, 4) stack (1 for one (4, 4) pose), from its shape alone: nothing is copied."""
    try:
        shape = np.shape(poses)
    except ValueError:  # a ragged list
        raise OptionError("BAD_OPTION", "poses: expected (K, 4, 4) matrices or one (4, 4), got a ragged list") from None
    return int(shape[0]) if len(shape) == 3 else 1


def _environment_count(poses_a: Any, poses_b: Any, pair_index: Any) -> int:
    """E of a CPU call, from the arrays' shapes alone (nothing is copied, so a huge broadcast view is judged before
    a contiguous copy of it is made): (E, 4, 4) poses on both sides, (E,) pair indices."""
    shapes = {}
    for name, array in (("poses_a", poses_a), ("poses_b", poses_b), ("pair_index", pair_index)):
        try:
            shapes[name] = tuple(int(n) for n in np.shape(array))
        except ValueError:  # a ragged list
            raise OptionError("BAD_OPTION", f"{name}: a ragged list, not an array") from None
    for name in ("poses_a", "poses_b"):
        if len(shapes[name]) != 3 or shapes[name][1:] != (4, 4):
            raise OptionError("BAD_OPTION", f"{name}: expected (E, 4, 4) matrices, got shape {shapes[name]}")
    envs = shapes["poses_a"][0]
    if shapes["poses_b"][0] != envs:
        raise OptionError("BAD_OPTION", f"poses_a and poses_b hold different numbers of environments ({envs} and "
                                        f"{shapes['poses_b'][0]})")
    if pair_index is not None and shapes["pair_index"] != (envs,):
        raise OptionError("BAD_OPTION", f"pair_index must hold one pair per environment: expected shape ({envs},), "
                                        f"got {shapes['pair_index']}")
    return envs


def _pair_indices(pair_index: Any) -> np.ndarray:
    """pair_index as the int32 array the batch reads, without changing a value: a cast would wrap 2**32 + 1 to 1
    and floor a float 0.9 to 0, silently running another pair. (An int32 that names no pair is the
    environment's error, as on CUDA.)"""
    index = np.asarray(pair_index)
    if index.dtype == np.bool_ or not np.issubdtype(index.dtype, np.integer):
        raise OptionError("BAD_OPTION", f"pair_index: expected integers, got {index.dtype}")
    limits = np.iinfo(np.int32)
    if index.size and (int(index.min()) < limits.min or int(index.max()) > limits.max):
        raise OptionError("BAD_OPTION", f"pair_index: {int(index.max())} names no pair (beyond int32)")
    return np.ascontiguousarray(index, dtype=np.int32)


class BatchScene:
    """Assets and the pairs environments may hold. ``pairs`` are (A, B) indices into ``bodies`` (default: the first
    body against the second, or against itself when it is the only one); each environment
    names its pair with ``pair_index`` (default: pair 0 everywhere). The assets go to the current CUDA device once,
    at the first call with CUDA poses on it, and are shared by every environment there (one scene per device: each
    call makes the poses' device current while it uploads and launches, and checks that every array is there)."""

    def __init__(self, bodies: Sequence[Body], pairs: Sequence[tuple[int, int]] | None = None) -> None:
        if isinstance(bodies, Body) or not isinstance(bodies, Sequence):
            raise OptionError("BAD_OPTION", f"bodies: expected a sequence of Bodies, got {type(bodies).__name__}")
        self._bodies = tuple(bodies)
        for n, body in enumerate(self._bodies):
            if not isinstance(body, Body):
                raise OptionError("BAD_OPTION", f"bodies[{n}]: expected a Body (voxfmt.load), got {type(body).__name__}")
        if not self._bodies:
            raise OptionError("BAD_OPTION", "bodies: a scene needs at least one Body")
        if pairs is None:  # one body against itself, or the first against the second
            pairs = [(0, min(1, len(self._bodies) - 1))]
        if not isinstance(pairs, (Sequence, np.ndarray)):
            raise OptionError("BAD_OPTION", f"pairs: expected a sequence of (A, B) index pairs, got {pairs!r}")
        checked = []
        for pair in pairs:
            if not isinstance(pair, (Sequence, np.ndarray)) or isinstance(pair, str) or len(pair) != 2:
                raise OptionError("BAD_OPTION", f"pairs: expected (A, B) index pairs, got {pair!r}")
            # A float or a string would be floored or parsed into another pair, silently.
            checked.append((_whole("pairs: A", pair[0], 0, 2**31 - 1), _whole("pairs: B", pair[1], 0, 2**31 - 1)))
        self._pairs = tuple(checked)
        if not self._bodies or not self._pairs:
            raise OptionError("BAD_OPTION", "a BatchScene needs bodies and at least one pair")
        for a, b in self._pairs:
            if not (0 <= a < len(self._bodies) and 0 <= b < len(self._bodies)):
                raise OptionError("BAD_OPTION", f"pair ({a}, {b}) names a body the scene does not have")
        self._device_scenes: dict[int, Any] = {}

    # Read-only: a device keeps the scene it was given at its first call (a new BatchScene for other bodies).
    @property
    def bodies(self) -> tuple[Any, ...]:
        return self._bodies

    @property
    def pairs(self) -> tuple[tuple[int, int], ...]:
        return self._pairs

    def device_bytes(self, device: int = 0) -> int:
        """Device memory the assets take on CUDA device `device` (uploading them there if not yet)."""
        device = _whole("device", device, 0, 1 << 16)
        if device in self._device_scenes:
            return int(self._device_scenes[device].device_bytes)
        with _current_device(None, device):  # the upload goes to the current device: this one
            return int(self._device_scene(device).device_bytes)

    def _device_scene(self, device: int) -> Any:
        scene = self._device_scenes.get(device)
        if scene is None:
            from ._voxfmt import _DeviceScene  # type: ignore[attr-defined]

            scene = self._device_scenes[device] = _DeviceScene(self.bodies, self.pairs)
        return scene

    def new_outputs(self, poses: Any, max_contacts: int = 0) -> BatchResult:
        """Output arrays for contacts(..., out=) on CUDA poses (E, 4, 4): allocated by the poses' framework (PyTorch
        or CuPy) on their device, for E environments and `max_contacts` contacts each. What a CUDA graph is
        captured with (examples/gpu/cuda_graph.py)."""
        max_contacts = _whole("max_contacts", max_contacts, 0, 1 << 24)
        envs = int(_cuda_interface("poses", poses)["shape"][0])
        fw = _framework(poses)
        if fw.__name__ == "torch":
            def empty(shape: tuple[int, ...], dtype: str) -> Any:
                return fw.empty(shape, dtype=getattr(fw, dtype), device=poses.device)
        else:
            def empty(shape: tuple[int, ...], dtype: str) -> Any:
                with fw.cuda.Device(_declared_device(poses)):
                    return fw.empty(shape, dtype=dtype)
        specs = _output_specs(envs, max_contacts)
        return BatchResult(**{name: empty(shape, dtype) for name, dtype, shape in specs})

    def contacts(
        self,
        poses_a: Any,
        poses_b: Any,
        pair_index: Any = None,
        *,
        stiffness: float = 1.0,
        proximity: float = 0.0,
        max_contacts: int = 0,
        threads: int | None = None,
        out: BatchResult | None = None,
        stream: int | None = None,
        check: bool = True,
        interpolation: str = "trilinear",
    ) -> BatchResult:
        """Contacts of every environment: poses_a, poses_b (E, 4, 4) rigid body-to-world matrices (float32, or
        float64 on the CPU), pair_index (E,) int32 or None. On CUDA arrays the call is queued on `stream` (default:
        the framework's current stream) and returns at once; with ``check=True`` it then waits to check the
        environments' ``error`` (raising PoseError or OptionError); pass check=False (and ``out``) inside a CUDA
        graph. On NumPy arrays (or anything NumPy reads as numbers: integers and either byte order are converted) it
        runs on `threads` CPU threads (default: every core), ``check`` as on CUDA; `stream` is ignored
        there (as a framework's stream is for its CPU tensors).
        Outputs larger than 3/4 of this machine's memory are refused up front (InternalError, OUT_OF_MEMORY).
        ``interpolation``: 'trilinear' or 'tricubic' (as :func:`voxfmt.contacts`'s; on the CPU only)."""
        stiffness, proximity = _real("stiffness", stiffness), _real("proximity", proximity)
        for name, value in (("stiffness", stiffness), ("proximity", proximity)):  # on CUDA as on the CPU
            if not (math.isfinite(value) and value >= 0):
                raise OptionError("BAD_OPTION", f"batch: {name} must be finite and >= 0, not {value!r}")
        max_contacts = _whole("max_contacts", max_contacts, 0, 1 << 24)
        interpolation = _one_of("interpolation", interpolation, ("trilinear", "tricubic"))
        if _on_cuda(poses_a) or _on_cuda(poses_b):
            if interpolation != "trilinear":
                raise OptionError("BAD_OPTION", "the CUDA batch reads distances trilinearly only (tricubic: NumPy poses)")
            result = self._contacts_cuda(poses_a, poses_b, pair_index, stiffness, proximity, max_contacts, out, stream,
                                         check)
        else:
            if out is not None:
                raise OptionError("BAD_OPTION", "out= is for CUDA arrays; on the CPU the outputs are new arrays")
            if threads is not None:
                threads = _whole("threads", threads, 1, 1024)
            # The poses' contiguous copies and the outputs, judged before either is made (here only: the compiled
            # half allocates what this allows).
            envs = _environment_count(poses_a, poses_b, pair_index)
            _refuse_beyond_memory(f"{envs} environments x {max_contacts} contacts (poses' copies and outputs)",
                                  envs * (2 * 16 * 8 + 40.0 + 33.0 * max_contacts))
            raw = _batch_cpu(self.bodies, self.pairs, *_cpu_poses(poses_a, poses_b),
                             None if pair_index is None else _pair_indices(pair_index),
                             proximity, stiffness, max_contacts, threads, interpolation)
            result = BatchResult(**raw)
        if check:
            _raise_for(result.error)
        return result

    def _contacts_cuda(self, poses_a: Any, poses_b: Any, pair_index: Any, stiffness: float, proximity: float,
                       max_contacts: int, out: BatchResult | None, stream: int | None, wait: bool) -> BatchResult:
        k = max_contacts  # checked by contacts()
        device = _declared_device(poses_a)  # None: CUDA tells it below, once a device is known to be there
        shape = tuple(_cuda_interface("poses_a", poses_a)["shape"])
        if len(shape) != 3:
            raise OptionError("BAD_OPTION", f"poses_a: expected shape (E, 4, 4), got {shape}")
        envs = int(shape[0])
        if out is not None and not isinstance(out, BatchResult):
            raise OptionError("BAD_OPTION", f"out: expected a BatchResult (scene.new_outputs(poses, max_contacts) "
                              f"makes one), got {type(out).__name__}")
        _check_cuda_array("poses_a", poses_a, "float32", (envs, 4, 4), device)
        _check_cuda_array("poses_b", poses_b, "float32", (envs, 4, 4), device)
        if pair_index is not None:
            _check_cuda_array("pair_index", pair_index, "int32", (envs,), device)
        if out is not None:
            for name, dtype, shape in _output_specs(envs, k):
                if getattr(out, name) is None:
                    raise OptionError("BAD_OPTION", f"out.{name}: missing (out= made for max_contacts=0, called with "
                                      f"max_contacts={k}: make it with new_outputs(poses, {k}))")
                _check_cuda_array(f"out.{name}", getattr(out, name), dtype, shape, device)
                if _cuda_interface(f"out.{name}", getattr(out, name))["data"][1]:
                    raise OptionError("BAD_OPTION", f"out.{name}: read-only (its __cuda_array_interface__ says so)")
        ok, why = cuda_status()
        if not ok:
            raise InternalError("INTERNAL", f"CUDA poses, but no CUDA device can be used: {why}")
        arrays = {"poses_a": poses_a, "poses_b": poses_b, "pair_index": pair_index}
        if out is not None:
            arrays |= {f"out.{name}": getattr(out, name) for name, _, _ in _output_specs(envs, k)}
        device = _launch_device(arrays, device)
        with _current_device(poses_a, device):
            if out is None:
                out = self.new_outputs(poses_a, k)
            if stream is None:
                stream = _stream_of(poses_a)
            outputs = {name: _pointer(f"out.{name}", getattr(out, name)) for name, _, _ in _output_specs(envs, k)}
            for name in ("points", "normals", "depths", "point_index", "point_of_b"):
                outputs.setdefault(name, 0)
            self._device_scene(device).run(
                envs=envs, poses_a=_pointer("poses_a", poses_a), poses_b=_pointer("poses_b", poses_b),
                pair_index=_pointer("pair_index", pair_index), proximity=float(proximity), stiffness=float(stiffness),
                max_contacts=k, stream=int(stream), **outputs)
            if wait:
                # The check reads `error` on the framework's current stream, which need not follow the launch's
                # (a stream= of the caller's own): the launch's stream is waited for first.
                why = _cuda.synchronize(int(stream))
                if why:
                    raise InternalError("INTERNAL", f"the batch's stream failed: {why}")
        return out


def _raise_for(error: Any) -> None:
    worst = int(error.max()) if len(error) else 0  # on a CUDA array this waits for the batch
    if worst == 0:
        return
    codes = [int(e) for e in (error.tolist() if hasattr(error, "tolist") else error)]
    # The first environment that failed, with its own reason (not another environment's).
    first = next(i for i, e in enumerate(codes) if e != 0)
    code = codes[first]
    failed = sum(1 for e in codes if e != 0)
    message = f"environment {first}: {_ENV_ERRORS.get(code, 'error ' + str(code))}"
    if failed > 1:
        message += f" ({failed} environments failed; their codes are in the result's error)"
    if code in (2, 3, 4, 5):
        raise PoseError("BAD_POSE", message)
    if code == 7:
        raise InternalError("INTERNAL", message)
    raise OptionError("BAD_OPTION", message)

