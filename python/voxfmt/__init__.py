"""voxfmt: bake triangle meshes into Voxmap-PointShell collision assets, validate and inspect them, and query
contacts between them from NumPy.

    import numpy as np, voxfmt
    voxfmt.bake("bunny.off", "bunny.vox.h5", resolution=128, points=10000)
    bunny = voxfmt.load("bunny.vox.h5")
    pose = np.eye(4); pose[1, 3] = 0.05
    c = voxfmt.contacts(bunny, np.eye(4), bunny, pose)
    force, torque = voxfmt.wrench(c, stiffness=1e4)

Every failure raises a :class:`voxfmt.Error` subclass whose ``code`` is the C++ library's code (an argument of
the wrong Python type to a compiled function is Python's TypeError).
"""

from __future__ import annotations

import copyreg
import json
import operator
import os
from dataclasses import dataclass
from typing import Any, Callable, Literal

import numpy as np
import numpy.typing as npt

from ._errors import AssetError, Error, InternalError, MeshError, OptionError, PoseError, WriteError
from ._voxfmt import Body, Contacts, QueryStats, _library_version, contacts, load, read_mesh, wrench
from ._voxfmt import _asset_is_current, _bake, _BakeSettings, _contacts_batch, _inspect, _Tracker, _validate
from .batch import BatchResult, BatchScene, cuda_status
from .batch import _one_of, _poses_once, _real, _refuse_beyond_pose_memory, _whole

__version__: str = _library_version()

__all__ = [
    "AssetError",
    "Batch",
    "BatchResult",
    "BatchScene",
    "Body",
    "Contacts",
    "Error",
    "InternalError",
    "Issue",
    "MeshError",
    "OptionError",
    "PoseError",
    "QueryStats",
    "Tracker",
    "ValidationReport",
    "WriteError",
    "bake",
    "contacts",
    "contacts_batch",
    "cuda_status",
    "inspect",
    "load",
    "read_mesh",
    "validate",
    "wrench",
]

Path = str | os.PathLike[str]

# The options of `voxfmt build` as keywords of bake() (dashes become underscores), with their defaults: those of
# bake::Settings, read from the extension (the CLI's options read the same struct).
_BAKE_DEFAULTS: dict[str, Any] = {name: getattr(_BakeSettings(), name) for name in _BakeSettings.names}
_UNSIGNED_BITS = {"resolution": 32, "points": 32, "margin": 32, "seed": 64, "threads": 32, "deflate": 31,
                  "max_memory_mib": 40}


def _path(value: Path, what: str) -> str:
    """A path as open() takes it, as text (a name that is not UTF-8 keeps its bytes as surrogates, which the
    bindings encode back); a NUL byte, which would name another file, is refused."""
    try:
        path = os.fsdecode(os.fspath(value))
    except TypeError:
        raise OptionError("BAD_OPTION", f"{what}: expected a path, got {type(value).__name__}") from None
    if "\0" in path:
        raise OptionError("BAD_OPTION", f"{what}: embedded null byte")
    return path


def _optional_int(name: str, value: Any) -> int | None:
    if value is None:
        return None
    if isinstance(value, bool):
        raise OptionError("BAD_OPTION", f"{name}: expected an integer, got a bool")
    try:
        return operator.index(value)
    except TypeError:
        raise OptionError("BAD_OPTION", f"{name}: expected an integer, got {value!r}") from None


def _query_int(name: str, value: Any) -> int | None:
    """An integer query option or None, as contacts() takes it (an int64; its range is the query's to check)."""
    return None if value is None else _whole(name, value, -(2**63), 2**63 - 1)


def _unsigned(name: str, value: Any) -> int:
    if isinstance(value, bool):
        raise OptionError("BAD_OPTION", f"{name}: expected an integer, got a bool")
    try:
        number = operator.index(value)
    except TypeError:
        raise OptionError("BAD_OPTION", f"{name}: expected an integer, got {value!r}") from None
    if not 0 <= number < 2 ** _UNSIGNED_BITS[name]:
        raise OptionError("BAD_OPTION", f"{name} {number} is out of range")
    return number


_BAKE_UNSET_BY_NONE = {"voxel_size": True, "point_spacing": True, "max_memory_mib": True}


def _bake_setting(name: str, value: Any) -> Any:
    """A bake option checked against its default's type (ranges are checked by the bake, as for the CLI)."""
    default = _BAKE_DEFAULTS[name]
    if isinstance(default, bool):
        if not isinstance(value, bool):
            raise OptionError("BAD_OPTION", f"{name}: expected a bool")
        return value
    if isinstance(default, str):
        if not isinstance(value, str):
            raise OptionError("BAD_OPTION", f"{name}: expected a string such as {default!r}, got {value!r}")
        return value
    if isinstance(default, int):
        return _unsigned(name, value)
    return _real(name, value)


def bake(
    mesh_path: Path,
    out_path: Path,
    *,
    resolution: int | None = None,
    points: int | None = None,
    progress: Callable[[str, float], object] | None = None,
    if_changed: bool = False,
    **options: Any,
) -> dict[str, Any]:
    """Bakes a mesh (any format assimp reads: OBJ, PLY, STL, OFF, glTF, ...) into an asset at ``out_path``.

    The asset is validated in full in memory and replaces ``out_path`` atomically. Returns the build summary,
    the same dict as ``voxfmt build --json`` prints. ``options`` are the other ``voxfmt build`` options, dashes
    as underscores: voxel_size (metres, instead of resolution), point_spacing (metres, instead of points),
    each excluding the other as on the command line (resolution 128 and points 10000 when neither is given),
    branching, margin, band, shell_thickness, unit_scale, up_axis, self_intersection_check (bool; the CLI's
    --no-self-intersection-check is ``False``), seed, deflate, threads (0 = all cores), max_memory_mib (what the
    voxelmap and the point shell may each need at their peak, beyond which the bake is refused up front:
    InternalError OUT_OF_MEMORY; default 3/4 of this machine's memory).

    ``progress(stage, fraction)`` is called as each stage starts (fraction of the whole bake, 0..1), and again (up
    to 5 times a second) as the long "voxelmap + point shell" stage computes its voxelmap or waits for its point
    shell, and as "write" compresses and checks the asset; an exception it raises stops the bake and is raised
    again here. Without it, Ctrl-C stops the bake as promptly (with ``threads=1``, a point shell of millions of
    points is waited for).

    ``if_changed=True``: where ``out_path`` already is a bake of this mesh as it is now (its SHA-256) with these
    options, nothing is baked and ``{"status": "up_to_date", "input": ..., "output": ...}`` is returned: a cache
    of bakes that follows its meshes and settings (one named by the settings alone keeps another mesh's asset).

    Raises MeshError (ZERO_VOLUME, IMPORT_FAILED, ...), OptionError (BAD_OPTION), WriteError, InternalError.
    """
    unknown = sorted(set(options) - set(_BAKE_DEFAULTS))
    if unknown:
        raise OptionError(
            "BAD_OPTION", f"unknown bake option(s) {', '.join(unknown)}; known: {', '.join(sorted(_BAKE_DEFAULTS))}"
        )
    if progress is not None and not callable(progress):
        raise OptionError("BAD_OPTION", "progress must be a callable (stage, fraction) or None")
    # voxel_size, point_spacing and max_memory_mib: None is not given (as resolution=None); 0, the bake's "unset", is
    # refused as on the command line, where it would silently be ignored.
    options = {name: value for name, value in options.items() if value is not None or not _BAKE_UNSET_BY_NONE.get(name)}
    for name in _BAKE_UNSET_BY_NONE:
        if name in options and not _real(name, options[name]) > 0:
            raise OptionError("BAD_OPTION", f"{name} must be a finite number > 0, not {options[name]!r}")
    chosen = {"resolution": resolution, "points": points}
    for (name, value), instead in zip(chosen.items(), ("voxel_size", "point_spacing")):
        if value is not None and options.get(instead) is not None:
            raise OptionError("BAD_OPTION", f"{name} and {instead} exclude each other (as on the command line): give one")
    chosen = {name: _BAKE_DEFAULTS[name] if value is None else value for name, value in chosen.items()}
    settings = _BakeSettings()
    for name, value in {**chosen, **options}.items():
        setattr(settings, name, _bake_setting(name, value))
    if not isinstance(if_changed, bool):
        raise OptionError("BAD_OPTION", f"if_changed: expected a bool, got {if_changed!r}")
    if if_changed and _asset_is_current(out_path, mesh_path, settings):
        return {"status": "up_to_date", "input": os.fspath(mesh_path), "output": os.fspath(out_path)}
    summary = _bake(_path(mesh_path, "mesh_path"), _path(out_path, "out_path"), settings, progress)
    result: dict[str, Any] = json.loads(summary)
    return result


@dataclass(frozen=True)
class Issue:
    """One finding of validate(): ``code`` (spec/issue-codes.md), ``severity`` ("error", "warning", "info"),
    ``message``, and ``location``, the HDF5 object it concerns ("/" for the file itself)."""

    code: str
    severity: str
    message: str
    location: str


@dataclass(frozen=True)
class ValidationReport:
    """What validate() found: ``valid`` is True when no finding has error severity."""

    path: str
    issues: tuple[Issue, ...]

    @property
    def valid(self) -> bool:
        return not any(issue.severity == "error" for issue in self.issues)

    @property
    def errors(self) -> tuple[Issue, ...]:
        return tuple(issue for issue in self.issues if issue.severity == "error")

    def __bool__(self) -> bool:
        return self.valid


def validate(
    path: Path, level: Literal["quick", "full"] = "full", *, max_memory_mib: int | None = None
) -> ValidationReport:
    """Checks an asset file against the format spec, like ``voxfmt validate --level LEVEL``. Never raises for
    a bad file: an unreadable one is reported (FILE_NOT_FOUND, NOT_HDF5, ...) in ``issues``, and one whose read
    would need more than ``max_memory_mib`` (default 768, decided from its metadata before anything is read) as
    OUT_OF_MEMORY."""
    if level not in ("quick", "full"):
        raise OptionError("BAD_OPTION", f"level must be 'quick' or 'full', not {level!r}")
    p = _path(path, "path")
    found = _validate(p, level == "full", _optional_int("max_memory_mib", max_memory_mib))
    return ValidationReport(p, tuple(Issue(*finding) for finding in found))


def inspect(path: Path, *, max_memory_mib: int | None = None) -> dict[str, Any]:
    """The summary of an asset that ``voxfmt inspect --json`` prints (format, bounds, voxelmap, pointshell,
    mass_properties, provenance, warnings). Raises AssetError when the file cannot be read or breaks a rule of
    the format, InternalError (OUT_OF_MEMORY) when reading it would need more than ``max_memory_mib``."""
    result: dict[str, Any] = json.loads(_inspect(_path(path, "path"), _optional_int("max_memory_mib", max_memory_mib)))
    return result


@dataclass(frozen=True)
class Batch:
    """Per-pose results of contacts_batch() (K poses). ``force``/``torque`` act on A (torque about A's centre
    of mass in the world), with the stiffness given. With ``with_contacts=True`` the contacts of pose k are
    rows ``offsets[k]:offsets[k+1]`` of ``points``, ``normals``, ``depths``, ``point_index``, ``point_of_b``."""

    count: npt.NDArray[np.int64]
    max_depth: npt.NDArray[np.float64]
    force: npt.NDArray[np.float64]
    torque: npt.NDArray[np.float64]
    offsets: npt.NDArray[np.int64] | None = None
    points: npt.NDArray[np.float64] | None = None
    normals: npt.NDArray[np.float64] | None = None
    depths: npt.NDArray[np.float64] | None = None
    point_index: npt.NDArray[np.uint32] | None = None
    point_of_b: npt.NDArray[np.bool_] | None = None

    def __len__(self) -> int:
        return len(self.count)


def contacts_batch(
    a: Body,
    poses_a: npt.ArrayLike,
    b: Body,
    poses_b: npt.ArrayLike,
    *,
    threads: int | None = None,
    with_contacts: bool = False,
    stiffness: float = 1.0,
    point_budget: int | None = None,
    time_budget_us: float | None = None,
    proximity: float = 0.0,
    max_level: int | None = None,
    cut_level: str = "spheres",
    interpolation: str = "trilinear",
) -> Batch:
    """contacts() for K pose pairs at once: ``poses_a`` and ``poses_b`` are (K, 4, 4) (either may be one
    (4, 4) pose for all K). The GIL is released; ``threads`` workers (default: every core) split the poses;
    the outputs are allocated once. Returns per-pose ``count``, ``max_depth``, ``force`` and ``torque``
    (penalty wrench with ``stiffness``, as wrench() computes it), plus the flattened contacts with
    ``with_contacts``. ``point_budget``, ``time_budget_us``, ``max_level``, ``cut_level`` and
    ``interpolation`` are contacts()'s.
    Raises PoseError naming the first non-rigid pose before any query runs."""
    if not isinstance(with_contacts, bool):
        raise OptionError("BAD_OPTION", "with_contacts: expected a bool")
    if threads is not None:
        threads = _whole("threads", threads, 1, 1024)
    # Judged here as contacts() judges them: the compiled batch would take a bool for 1 (point_budget=True: the
    # root level only) and answer a float with a TypeError naming itself.
    point_budget, max_level = _query_int("point_budget", point_budget), _query_int("max_level", max_level)
    if time_budget_us is not None:
        time_budget_us = _real("time_budget_us", time_budget_us)
    cut_level = _one_of("cut_level", cut_level, ("spheres", "points"))
    interpolation = _one_of("interpolation", interpolation, ("trilinear", "tricubic"))
    poses_a, poses_b = _poses_once(poses_a), _poses_once(poses_b)
    _refuse_beyond_pose_memory(poses_a, poses_b)
    out = _contacts_batch(a, poses_a, b, poses_b, threads=threads, with_contacts=with_contacts,
                          stiffness=_real("stiffness", stiffness), point_budget=point_budget,
                          time_budget_us=time_budget_us, proximity=_real("proximity", proximity),
                          max_level=max_level, cut_level=cut_level, interpolation=interpolation)
    return Batch(**out)


class Tracker:
    """A pair of bodies queried pose after pose — a trajectory, a simulation, a haptic path. Each query keeps
    the point-sphere tree's last traversal (its front), so a step costs what moved: at rest, about the contacts.
    The contacts are those of contacts() at the same poses, bit for bit and in the same order; only the work
    differs. Full traversals only (no point or time budget). One query at a time per tracker; use one tracker
    per pair (and per thread)."""

    def __init__(self, a: Body, b: Body) -> None:
        if not isinstance(a, Body) or not isinstance(b, Body):
            raise OptionError("BAD_OPTION", "Tracker(a, b): expected two voxfmt.Body objects")
        self._tracker = _Tracker(a, b)

    @property
    def a(self) -> Body:
        return self._tracker.a

    @property
    def b(self) -> Body:
        return self._tracker.b

    def contacts(self, pose_a: npt.ArrayLike, pose_b: npt.ArrayLike, *, proximity: float = 0.0,
                 interpolation: str = "trilinear") -> Contacts:
        """contacts(a, pose_a, b, pose_b), coherent with this pair's earlier queries (a query with another
        ``interpolation`` than the last starts from the root)."""
        return self._tracker._contacts(pose_a, pose_b, _real("proximity", proximity),
                                       _one_of("interpolation", interpolation, ("trilinear", "tricubic")))

    def contacts_batch(
        self,
        poses_a: npt.ArrayLike,
        poses_b: npt.ArrayLike,
        *,
        with_contacts: bool = False,
        stiffness: float = 1.0,
        proximity: float = 0.0,
        interpolation: str = "trilinear",
    ) -> Batch:
        """contacts_batch() over K consecutive poses (a trajectory), in order on one thread, each query coherent
        with the one before (and with this tracker's earlier queries). The GIL is released."""
        if not isinstance(with_contacts, bool):
            raise OptionError("BAD_OPTION", "with_contacts: expected a bool")
        poses_a, poses_b = _poses_once(poses_a), _poses_once(poses_b)
        _refuse_beyond_pose_memory(poses_a, poses_b)
        out = _contacts_batch(self.a, poses_a, self.b, poses_b, with_contacts=with_contacts,
                              stiffness=_real("stiffness", stiffness), proximity=_real("proximity", proximity),
                              tracker=self._tracker,
                              interpolation=_one_of("interpolation", interpolation, ("trilinear", "tricubic")))
        return Batch(**out)

    def reset(self) -> None:
        """Forgets the pair's history: the next query starts from the root."""
        self._tracker.reset()


def _reload(path: str, density: float, max_memory_mib: int | None = None) -> Body:
    """A pickled Body in the process that unpickles it: its file loaded again (FILE_NOT_FOUND if gone since)."""
    return load(path, density=density, max_memory_mib=max_memory_mib)


def _reduce_body(body: Body) -> tuple[Any, ...]:
    # A Body is its file's data, read-only: what is pickled (and copied) is the file load() found (its absolute
    # path as of the load) with the density and memory budget given to it, not the arrays (a worker of
    # multiprocessing or ProcessPoolExecutor reloads it).
    return _reload, (body._absolute_path, body.density, body._max_memory_mib)


copyreg.pickle(Body, _reduce_body)
