"""voxfmt assets as MuJoCo SDF geoms: the plugin ``voxfmt.sdf.asset`` and the MJCF that uses it.

    import mujoco, voxfmt.mujoco
    voxfmt.mujoco.load_plugin()
    bunny = voxfmt.mujoco.part("bunny.vox.h5", name="bunny", pos=(0, 0, 0.5), density=1000.0)
    model = mujoco.MjModel.from_xml_string(voxfmt.mujoco.insert(scene_xml, bunny))

The plugin answers MuJoCo's distance and gradient queries from the asset's voxelmap (the file Bullet loads too);
MuJoCo's own SDF collision (``mjc_SDF``) searches for the contacts. The plugin library is built for exactly one
MuJoCo release, :data:`MUJOCO_VERSION`; :func:`load_plugin` checks it.
"""

from __future__ import annotations

import ctypes
import hashlib
import os
import re
import threading
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from typing import Sequence

import numpy as np
import numpy.typing as npt

from ._errors import Error

__all__ = [
    "MUJOCO_VERSION",
    "PLUGIN_NAME",
    "MujocoVersionError",
    "Part",
    "evaluate",
    "field_bytes",
    "insert",
    "load_plugin",
    "loaded_files",
    "lookup_profile",
    "part",
    "plugin_path",
]

#: The MuJoCo release the plugin is built against and works with (the `mujoco` wheel's version; CMake reads it
#: from this line, and python/requirements-dev.txt pins the same).
MUJOCO_VERSION = "4.0.0"
#: The plugin's name in MJCF (``<plugin plugin="voxfmt.sdf.asset">``).
PLUGIN_NAME = "voxfmt.sdf.asset"
_LIBRARY = "libvoxfmt_mujoco.so"

_lock = threading.Lock()
_library: ctypes.CDLL | None = None


class MujocoVersionError(Error, ImportError):
    """The installed ``mujoco`` is not the release the plugin was built for (code VERSION_UNSUPPORTED)."""


def plugin_path() -> str:
    """Where the plugin library is: ``$VOXFMT_MUJOCO_PLUGIN`` if set, else ``libvoxfmt_mujoco.so`` beside this
    package (CMake builds it into ``build/python/voxfmt/``; ``pip install`` puts it into the package)."""
    return os.environ.get("VOXFMT_MUJOCO_PLUGIN") or os.path.join(os.path.dirname(__file__), _LIBRARY)


def _mujoco():  # type: ignore[no-untyped-def]
    try:
        import mujoco
    except ImportError as e:
        raise MujocoVersionError(
            "VERSION_UNSUPPORTED", f"cannot import mujoco ({e}): pip install mujoco=={MUJOCO_VERSION}"
        ) from None
    if mujoco.__version__ != MUJOCO_VERSION:
        raise MujocoVersionError(
            "VERSION_UNSUPPORTED",
            f"the voxfmt MuJoCo plugin is built for mujoco {MUJOCO_VERSION}, this Python has {mujoco.__version__} "
            f"(pip install mujoco=={MUJOCO_VERSION}, or rebuild voxfmt against it)",
        )
    return mujoco


def load_plugin() -> str:
    """Registers the plugin ``voxfmt.sdf.asset`` with MuJoCo, once per process (later calls do nothing), and
    returns the library's path. Raises MujocoVersionError if ``mujoco`` is missing or not
    :data:`MUJOCO_VERSION`, and AssetError (FILE_NOT_FOUND) if the library was not built."""
    global _library
    with _lock:
        if _library is not None:
            return plugin_path()
        mujoco = _mujoco()  # loads libmujoco, which the plugin's library needs by soname
        path = plugin_path()
        if not os.path.exists(path):
            from ._errors import AssetError

            raise AssetError(
                "FILE_NOT_FOUND",
                f"{path}: the voxfmt MuJoCo plugin was not built (CMake builds it when the build's Python has "
                f"mujoco=={MUJOCO_VERSION}: VOXFMT_MUJOCO)",
                path,
            )
        try:
            library = ctypes.CDLL(os.path.abspath(path))
        except OSError as e:
            raise MujocoVersionError("VERSION_UNSUPPORTED", f"{path}: cannot load the plugin: {e}", path) from None
        built = int(library.voxfmt_mujoco_built_version())
        if built != mujoco.mj_version():
            raise MujocoVersionError(
                "VERSION_UNSUPPORTED",
                f"{path} was built against MuJoCo {built}, this process runs {mujoco.mj_version()}",
                path,
            )
        library.voxfmt_mujoco_evaluate.restype = ctypes.c_int
        library.voxfmt_mujoco_evaluate.argtypes = [
            ctypes.c_char_p,
            ctypes.c_int,
            ctypes.c_void_p,
            ctypes.c_void_p,
            ctypes.c_void_p,
            ctypes.c_char_p,
            ctypes.c_int,
        ]
        library.voxfmt_mujoco_loaded_files.restype = ctypes.c_int
        library.voxfmt_mujoco_field_bytes.restype = ctypes.c_longlong
        library.voxfmt_mujoco_field_bytes.argtypes = [ctypes.c_char_p]
        library.voxfmt_mujoco_profile.restype = None
        library.voxfmt_mujoco_profile.argtypes = [ctypes.c_int, ctypes.c_void_p]
        _library = library
        return path


def loaded_files() -> int:
    """How many asset files the plugin has loaded in this process: each file once, however many geoms and models
    name it (a file baked again counts again; a failed load does not count)."""
    load_plugin()
    assert _library is not None
    return int(_library.voxfmt_mujoco_loaded_files())


def _asset_path_bytes(asset_path: str | os.PathLike[str]) -> bytes:
    """The absolute path as the plugin's C interface takes it; a NUL byte would cut it to another file's name."""
    from . import _path

    return os.fsencode(os.path.abspath(_path(asset_path, "asset_path")))


def field_bytes(asset_path: str | os.PathLike[str]) -> int:
    """Heap bytes of the field the plugin holds for the asset (what a model using it adds to MuJoCo's own model),
    loading it through the plugin's cache. Raises AssetError for a file the plugin cannot use."""
    load_plugin()
    assert _library is not None
    n = int(_library.voxfmt_mujoco_field_bytes(_asset_path_bytes(asset_path)))
    if n < 0:
        evaluate(asset_path, np.zeros((0, 3)))  # raises the load's error
    return n


def lookup_profile(restart: bool = True) -> dict[str, float]:
    """Profiles the plugin's lookups in this process (one profile for every thread and model): since the last
    call, the calls MuJoCo made of ``sdf_distance`` and ``sdf_gradient``, the voxelmap lookups they cost (a point
    repeated on a thread is answered from that thread's last evaluations), and the nanoseconds those lookups take
    replayed in a loop without MuJoCo (``lookup_ns``; what the lookups cost of a step, as opposed to MuJoCo's own
    search), and ``collisions``, the SDF pair tests MuJoCo ran with one of the plugin's geoms as the SDF.
    ``restart`` starts a new profile, ``False`` stops profiling. Profiling records every looked-up point: not for
    timing a step."""
    load_plugin()
    assert _library is not None
    out = np.zeros(5)
    _library.voxfmt_mujoco_profile(1 if restart else 0, out.ctypes.data)
    return dict(zip(("distance_calls", "gradient_calls", "lookups", "lookup_ns", "collisions"), out.tolist()))


def evaluate(
    asset_path: str | os.PathLike[str], points: npt.ArrayLike, *, gradients: bool = False
) -> npt.NDArray[np.float64] | tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    """The field the plugin gives MuJoCo for the asset at ``asset_path``, at ``points`` (N, 3) in the asset
    frame, metres: distances (N,), negative inside, and with ``gradients=True`` also the unit gradients (N, 3).
    The asset is loaded through the plugin's cache (the same object MuJoCo's geoms use). Raises AssetError for a
    file the plugin cannot use."""
    from ._errors import OptionError

    load_plugin()
    assert _library is not None
    raw = np.asarray(points)
    if raw.dtype.kind not in "iuf":  # as every array of the package: complex, bool or object are no coordinates
        raise OptionError("BAD_OPTION", f"points: expected an array of real numbers, got dtype {raw.dtype.name}")
    p = np.ascontiguousarray(raw, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 3:
        raise OptionError("BAD_OPTION", f"points: expected shape (N, 3), got {p.shape}")
    n = p.shape[0]
    distances = np.empty(n)
    grads = np.empty((n, 3)) if gradients else None
    message = ctypes.create_string_buffer(4096)
    status = _library.voxfmt_mujoco_evaluate(
        _asset_path_bytes(asset_path),
        n,
        p.ctypes.data,
        distances.ctypes.data,
        grads.ctypes.data if grads is not None else None,
        message,
        len(message),
    )
    if status != 0:
        from ._errors import make_error

        text = message.value.decode(errors="replace")
        code, _, rest = text.partition(": ")
        raise make_error(code, rest, os.fspath(asset_path), "")
    return (distances, grads) if grads is not None else distances


@dataclass(frozen=True)
class Part:
    """One baked part as MJCF pieces (see :func:`part`). ``extension`` and ``asset`` are shared by every part of
    the same file: :func:`insert` writes them once."""

    name: str
    file: str  #: absolute path of the asset
    instance: str  #: the plugin instance's name, and the mesh's
    extension: str  #: ``<instance>`` for ``<extension><plugin plugin="voxfmt.sdf.asset">``
    asset: str  #: ``<mesh>`` for ``<asset>``
    body: str  #: ``<body>`` for ``<worldbody>``: joint (unless static), ``<inertial>``, the SDF geom
    mass: float
    center_of_mass: tuple[float, float, float] = field(default=(0.0, 0.0, 0.0))


def _numbers(values: Sequence[float] | npt.ArrayLike) -> str:
    return " ".join(f"{float(v):.10g}" for v in np.asarray(values, dtype=float).ravel())


def _vector(what: str, values: Sequence[float] | npt.ArrayLike, size: int) -> npt.NDArray[np.float64]:
    from ._errors import OptionError

    raw = np.asarray(values)
    if raw.dtype.kind not in "iuf" or raw.shape != (size,):
        raise OptionError("BAD_OPTION", f"{what}: expected {size} real numbers, got {values!r}")
    v = raw.astype(np.float64)
    if not np.isfinite(v).all():
        raise OptionError("BAD_OPTION", f"{what}: expected finite numbers, got {_numbers(v)}")
    return v


# XML 1.0 holds no other control characters, not even escaped: MJCF could not carry them.
_NOT_IN_XML = re.compile("[\x00-\x08\x0b\x0c\x0e-\x1f\ufffe\uffff\ud800-\udfff]")
_XML_NAME = re.compile(r"[A-Za-z_][A-Za-z0-9_.\-]*")
_GEOM_SET_BY_PART = ("name", "type", "mesh")


def _text(what: str, value: object) -> str:
    from ._errors import OptionError

    if not isinstance(value, str):
        raise OptionError("BAD_OPTION", f"{what}: expected a string, got {type(value).__name__}")
    if _NOT_IN_XML.search(value):
        raise OptionError("BAD_OPTION", f"{what}: {value!r} holds a character an MJCF (XML) file cannot")
    return value


def _attribute(value: str) -> str:
    # Line breaks and tabs escaped too: a parser would read them back as spaces.
    return (
        value.replace("&", "&amp;")
        .replace('"', "&quot;")
        .replace("<", "&lt;")
        .replace(">", "&gt;")
        .replace("\n", "&#10;")
        .replace("\r", "&#13;")
        .replace("\t", "&#9;")
    )


def _geom_attributes(geom: dict[str, str] | None) -> str:
    from ._errors import OptionError

    extra = ""
    for key, value in (geom or {}).items():
        if not isinstance(key, str) or not _XML_NAME.fullmatch(key):
            raise OptionError("BAD_OPTION", f"geom: {key!r} is not an attribute name")
        if key in _GEOM_SET_BY_PART:
            raise OptionError("BAD_OPTION", f"geom: {key!r} is set by part() itself")
        extra += f' {key}="{_attribute(_text(f"geom[{key!r}]", str(value)))}"'
    return extra


def part(
    asset_path: str | os.PathLike[str],
    name: str,
    *,
    pos: Sequence[float] = (0.0, 0.0, 0.0),
    quat: Sequence[float] = (1.0, 0.0, 0.0, 0.0),
    density: float = 1000.0,
    static: bool = False,
    geom: dict[str, str] | None = None,
) -> Part:
    """The MJCF pieces of a body made of the asset at ``asset_path``: a plugin instance and mesh named after the
    file, and a body ``name`` at ``pos``/``quat`` (the asset frame's pose; MuJoCo's quaternion order w x y z)
    with a free joint (none if ``static``), an ``<inertial>`` from the asset's own mass properties at
    ``density`` (kg/m^3) and an SDF geom with the extra ``geom`` attributes (e.g. ``{"friction": "0.3"}``).

    The asset is read once here (AssetError if it cannot be); MuJoCo reads it again through the plugin's cache
    when it compiles the model, from the absolute path written into the MJCF."""
    from . import _path, load
    from ._errors import OptionError

    path = os.path.abspath(_path(asset_path, "asset_path"))
    try:
        encoded = path.encode()
    except UnicodeEncodeError:  # a name that is not UTF-8 (os.fsdecode's surrogates): MJCF is UTF-8 text
        raise OptionError("BAD_OPTION", f"asset_path: {path!r} is not UTF-8, which an MJCF file cannot name") from None
    _text("asset_path", path)
    name = _text("name", name)
    position = _vector("pos", pos, 3)
    orientation = _vector("quat", quat, 4)
    if not orientation.any():
        raise OptionError("BAD_OPTION", "quat: (0, 0, 0, 0) is no orientation")
    extra = _geom_attributes(geom)
    body = load(path, density=density)
    instance = "voxfmt_" + re.sub(r"[^A-Za-z0-9_]", "_", os.path.basename(path).split(".")[0])
    instance += "_" + hashlib.sha1(encoded).hexdigest()[:8]
    extension = f'<instance name="{instance}"><config key="file" value="{_attribute(path)}"/></instance>'
    asset = f'<mesh name="{instance}"><plugin instance="{instance}"/></mesh>'
    inertia = np.asarray(body.inertia)
    full = [inertia[0, 0], inertia[1, 1], inertia[2, 2], inertia[0, 1], inertia[0, 2], inertia[1, 2]]
    joint = "" if static else "<freejoint/>"
    xml = (
        f'<body name="{_attribute(name)}" pos="{_numbers(position)}" quat="{_numbers(orientation)}">{joint}'
        f'<inertial pos="{_numbers(body.center_of_mass)}" mass="{body.mass:.10g}" fullinertia="{_numbers(full)}"/>'
        f'<geom name="{_attribute(name)}" type="sdf" mesh="{instance}"{extra}><plugin instance="{instance}"/></geom>'
        "</body>"
    )
    com = tuple(float(c) for c in body.center_of_mass)
    return Part(name, path, instance, extension, asset, xml, float(body.mass), com)  # type: ignore[arg-type]


def insert(mjcf: str, *parts: Part) -> str:
    """``mjcf`` (a whole ``<mujoco>`` document) with the parts added: the plugin's ``<extension>`` entry, each
    file's mesh in ``<asset>`` once, and each part's body at the end of ``<worldbody>``. Sections the document
    lacks are created; an instance or mesh it already has is not repeated (MuJoCo refuses a repeat). The
    document is parsed as XML (comments kept; an XML declaration or a comment before ``<mujoco>`` is not): an
    MJCF file that is not well-formed XML is an OptionError."""
    from ._errors import OptionError

    try:
        root = ET.fromstring(mjcf, parser=ET.XMLParser(target=ET.TreeBuilder(insert_comments=True)))
    except ET.ParseError as e:
        raise OptionError("BAD_OPTION", f"mjcf: not a well-formed XML document: {e}") from None
    if root.tag != "mujoco":
        raise OptionError("BAD_OPTION", f"mjcf: expected a <mujoco> ... </mujoco> document, got <{root.tag}>")
    instances = {i.get("name") for i in root.iterfind("extension/plugin/instance")}
    meshes = {m.get("name") for m in root.iterfind("asset/mesh")}
    new_instances: dict[str, Part] = {p.instance: p for p in parts if p.instance not in instances}
    if new_instances:
        plugin = root.find(f"extension/plugin[@plugin='{PLUGIN_NAME}']")
        if plugin is None:
            extension = root.find("extension")
            if extension is None:
                extension = ET.Element("extension")
                root.insert(0, extension)  # before the assets and bodies that name its instances
            plugin = ET.SubElement(extension, "plugin", plugin=PLUGIN_NAME)
        for p in new_instances.values():
            plugin.append(ET.fromstring(p.extension))
    new_meshes = {p.instance: p for p in parts if p.instance not in meshes}
    if new_meshes:
        asset = _last_section(root, "asset")
        for p in new_meshes.values():
            asset.append(ET.fromstring(p.asset))
    if parts:
        worldbody = _last_section(root, "worldbody")
        for p in parts:
            worldbody.append(ET.fromstring(p.body))
    return ET.tostring(root, encoding="unicode")


def _last_section(root: ET.Element, section: str) -> ET.Element:
    found = root.findall(section)
    return found[-1] if found else ET.SubElement(root, section)
