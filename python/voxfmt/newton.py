"""voxfmt assets as Newton SDF shapes: a baked asset's distance field becomes the texture SDF that Newton's mesh
collision samples, so a Newton scene collides with voxfmt's certified signs, exact band and validation instead of an
SDF baked on a CUDA device at load time.

    import newton, voxfmt.newton
    builder = newton.ModelBuilder()
    body = builder.add_body(xform=wp.transform((0, 0, 0.2), wp.quat_identity()))
    voxfmt.newton.add_shape(builder, body, "bunny.vox.h5", "bunny.off")   # the mesh the asset was baked from
    model = voxfmt.newton.finalize(builder)                                  # on the CPU too

The texture SDF (Newton's layout: a coarse grid at brick corners, 8-cell bricks stored as 9^3 samples with an apron,
values quantised over one range) is built from the runtime's own field: near the surface every sample is the asset's
stored distance within one quantum (uint16: 1/65535 of the range, about 5e-4 voxel), and elsewhere the runtime's
estimate within the asset's estimate quantum.

Coupled to Newton's internals in two places only, both in this module's last section (building the textures from the
arrays, and giving a CPU model its SDFs): :data:`NEWTON_VERSION` and :data:`WARP_VERSION` are the releases this
module runs with, checked at import (``pip install 'voxfmt[newton]'`` installs them).
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Sequence
from typing import Any

import numpy as np

from . import _voxfmt
from ._asset import as_body, warp_device
from ._errors import OptionError
from .batch import _real

NEWTON_VERSION = "1.8.0"
"""The newton release this module is built for (it reads two of Newton's internal structures: pinned)."""
WARP_VERSION = "1.19.0"
"""The warp-lang release that newton release was tested with here."""


def _import_newton() -> tuple[Any, Any]:
    """newton and warp at the pinned releases; ImportError naming what to install otherwise."""
    hint = f"pip install 'voxfmt[newton]' (newton=={NEWTON_VERSION}, warp-lang=={WARP_VERSION})"
    try:
        import newton
        import warp
    except ImportError as error:
        raise ImportError(f"voxfmt.newton needs Newton {NEWTON_VERSION} and NVIDIA Warp {WARP_VERSION}: {hint}") from error
    if newton.__version__ != NEWTON_VERSION or warp.__version__ != WARP_VERSION:
        raise ImportError(
            f"voxfmt.newton supports newton {NEWTON_VERSION} with warp-lang {WARP_VERSION} (it reads Newton's internal "
            f"texture SDF layout); found newton {newton.__version__}, warp-lang {warp.__version__}: {hint}"
        )
    return newton, warp


newton, wp = _import_newton()

TEXTURE_FORMATS = ("uint16", "uint8", "float32")


def texture_layout(asset: Any, *, texture_format: str = "uint16", coarse_tolerance: float | None = None) -> dict:
    """The asset's texture SDF as NumPy arrays, [z][y][x] (x fastest), metres, in the asset's frame:

    - ``coarse`` (float32, bricks + 1 per axis): signed distances at brick corners;
    - ``slots`` (uint32, one per brick): ``(bz << 20) | (by << 10) | bx``, the brick's block in ``texels``, or
      ``0xFFFFFFFF`` where the coarse grid is interpolated instead;
    - ``texels`` (``texture_format``, a cube of ``blocks_per_side * 9`` samples a side): the stored bricks' 9^3
      samples, a sample's metres ``value_min + value_range * code / 65535`` (uint16; 255 for uint8; float32: metres);
    - ``lower`` (sample (0, 0, 0), the asset's voxel (0, 0, 0)), ``cell`` (the voxel size), ``bricks``, and what was
      stored: ``value_bricks``, ``coarse_stored``, ``max_quantisation_error`` (metres).

    The layout Newton, and with a different slot encoding PhysX (``PxSDFDesc``), read. ``coarse_tolerance``
    (voxels): how far the coarse grid may be from the runtime's estimate before a brick is stored (default: the
    asset's estimate quantum).
    """
    if not isinstance(texture_format, str) or texture_format not in TEXTURE_FORMATS:
        raise OptionError("BAD_OPTION", f"texture_format: expected one of {TEXTURE_FORMATS}, got {texture_format!r}")
    tolerance = -1.0 if coarse_tolerance is None else _voxels("coarse_tolerance", coarse_tolerance)
    return dict(_voxfmt._texture_sdf(as_body(asset), texture_format, tolerance))


def _voxels(name: str, value: Any) -> float:
    """A finite number of voxels >= 0, or BAD_OPTION: NaN as a tolerance once stored no brick at all (every
    comparison with it false), 2 voxels off through Newton's sampler."""
    number = _real(name, value)
    if not math.isfinite(number) or number < 0:
        raise OptionError("BAD_OPTION", f"{name}: expected a finite number of voxels >= 0, got {value!r}")
    return number


def sdf(asset: Any, *, texture_format: str = "uint16", device: Any = None) -> Any:
    """The asset's distance field as a ``newton.SDF`` (a texture SDF on ``device``, default Warp's), in the asset's
    frame: give it to ``newton.Mesh(..., sdf=...)`` of the asset's surface, or use :func:`add_shape`."""
    device = warp_device(wp, device)
    layout = texture_layout(asset, texture_format=texture_format)
    texture_data, _, _ = _texture_sdf_data(layout, texture_format, device)
    return newton.SDF.create_from_data(texture_data=texture_data)


def _unit_scale(body: Any) -> float:
    try:
        return float(json.loads(body.build_parameters or "{}").get("unit_scale", 1.0))
    except (ValueError, TypeError, AttributeError):
        return 1.0


def _surface_arrays(vertices: Any, triangles: Any) -> tuple[np.ndarray, np.ndarray]:
    """(V, 3) finite float32 vertices and (T * 3,) int32 indices within [0, V) (given as (T, 3) or flat), or
    BAD_OPTION: a reshape or a cast would silently make another mesh of (V, 2) vertices, float or 64-bit indices."""
    try:
        v, t = np.asarray(vertices), np.asarray(triangles)
    except ValueError:
        raise OptionError("BAD_OPTION", "surface: vertices and triangles must be arrays, not ragged lists") from None
    if v.ndim != 2 or v.shape[1] != 3 or not np.issubdtype(v.dtype, np.number) or np.iscomplexobj(v):
        raise OptionError("BAD_OPTION", f"surface: expected (V, 3) real vertices, got shape {v.shape} of {v.dtype}")
    v = v.astype(np.float32)
    if not np.isfinite(v).all():
        raise OptionError("BAD_OPTION", "surface: a vertex is not finite (in float32)")
    if t.ndim == 1 and t.size % 3 == 0:  # Newton's own layout (newton.Mesh.indices): three indices a triangle
        t = t.reshape(-1, 3)
    if (t.ndim != 2 or t.shape[1] != 3 or t.dtype == np.bool_ or not np.issubdtype(t.dtype, np.integer)
            or np.issubdtype(t.dtype, np.timedelta64)):
        raise OptionError("BAD_OPTION", f"surface: expected (T, 3) integer triangles, got shape {t.shape} of {t.dtype}")
    if t.size and (int(t.min()) < 0 or int(t.max()) >= len(v)):
        raise OptionError("BAD_OPTION", f"surface: a triangle names vertex {int(t.min()) if int(t.min()) < 0 else int(t.max())}, "
                                        f"not one of the {len(v)} vertices")
    return v, t.astype(np.int32).reshape(-1)


def mesh(asset: Any, surface: Any, *, texture_format: str = "uint16", device: Any = None) -> Any:
    """A ``newton.Mesh`` of the asset's surface carrying the asset's SDF. ``surface`` is the mesh the asset was baked
    from: a file (read as ``voxfmt build`` reads it, scaled by the asset's recorded ``unit_scale``) or a
    ``(vertices (V, 3), triangles (T, 3))`` pair in the asset's frame, whose mesh then has the asset's mass
    properties (volume, centre of mass and inertia at unit density, as Newton's meshes have them: right for an open
    or broken mesh too, whose triangles enclose no volume); or a ``newton.Mesh``, copied with everything it holds
    (``is_solid``, its mass properties, normals, ...) but its SDF, which is the asset's."""
    body = as_body(asset)
    if isinstance(surface, newton.Mesh):
        shape_mesh = surface.copy()
        shape_mesh.sdf = sdf(body, texture_format=texture_format, device=device)
        return shape_mesh
    if isinstance(surface, (str, os.PathLike)):
        vertices, triangles = _voxfmt.read_mesh(surface, unit_scale=_unit_scale(body))
    elif isinstance(surface, Sequence) and len(surface) == 2:
        vertices, triangles = surface
    else:
        raise OptionError(
            "BAD_OPTION", "surface: expected a mesh file, a (vertices, triangles) pair or a newton.Mesh, got "
            f"{type(surface).__name__}"
        )
    vertices, triangles = _surface_arrays(vertices, triangles)
    shape_mesh = newton.Mesh(
        vertices, triangles, sdf=sdf(body, texture_format=texture_format, device=device), compute_inertia=False
    )
    shape_mesh.mass = float(body.volume)
    shape_mesh.com = wp.vec3(*(float(c) for c in body.center_of_mass))
    shape_mesh.inertia = wp.mat33(*(float(i) / float(body.density) for i in np.asarray(body.inertia).ravel()))
    shape_mesh.has_inertia = True
    return shape_mesh


def add_shape(
    builder: Any,
    body: int,
    asset: Any,
    surface: Any,
    *,
    xform: Any = None,
    cfg: Any = None,
    texture_format: str = "uint16",
    device: Any = None,
    label: str | None = None,
) -> int:
    """Adds the asset to ``builder`` as a mesh shape of ``body`` (-1: static) that collides through the asset's SDF;
    returns the shape's index. ``surface`` as for :func:`mesh`; ``xform`` the shape's pose in the body's frame,
    ``cfg`` a ``newton.ModelBuilder.ShapeConfig``. Finalize with :func:`finalize` (on CUDA,
    ``builder.finalize()`` does the same)."""
    shape_mesh = mesh(asset, surface, texture_format=texture_format, device=device)
    return builder.add_shape_mesh(body, xform=xform, mesh=shape_mesh, cfg=cfg, label=label)


def finalize(builder: Any, device: Any = None) -> Any:
    """``builder.finalize(device)``, also on the CPU: there Newton refuses meshes with SDFs (it would build them with
    CUDA), so the model is finalized without them and given the meshes' SDFs afterwards, as Newton's CUDA path
    would have."""
    device = warp_device(wp, device)
    if device.is_cuda:
        return builder.finalize(device=device)
    meshes = {id(m): m for m in builder.shape_source if isinstance(m, newton.Mesh) and m.sdf is not None}
    detached = {key: m.sdf for key, m in meshes.items()}
    for m in meshes.values():
        m.sdf = None
    try:
        model = builder.finalize(device=device)
    finally:
        for key, m in meshes.items():
            m.sdf = detached[key]
    _attach_sdfs(model, builder, device)
    return model


# ---- Newton's internals (newton 1.8.0): the only code that reads them.


def _texture_sdf_data(layout: dict, texture_format: str, device: Any) -> tuple[Any, Any, Any]:
    """Newton's TextureSDFData (and its two textures, which it must outlive) from a texture layout: the dictionary
    Newton's own SDF builder produces and caches (newton/_src/geometry/_sdf_cache.py, format 2), uploaded by
    Newton's own function."""
    from newton._src.geometry.sdf_texture import QuantizationMode, create_sparse_sdf_textures

    bz, by, bx = layout["slots"].shape
    slots = np.ascontiguousarray(layout["slots"].transpose(2, 1, 0))  # Newton indexes slots [x][y][z]
    lower = np.asarray(layout["lower"], dtype=np.float64)
    cell = float(layout["cell"])
    mode = {"uint16": QuantizationMode.UINT16, "uint8": QuantizationMode.UINT8, "float32": QuantizationMode.FLOAT32}
    sparse = {
        "coarse_sdf": layout["coarse"],
        "subgrid_data": layout["texels"],
        "subgrid_start_slots": slots,
        "coarse_dims": (bx, by, bz),
        "subgrid_tex_size": layout["texels"].shape[0],
        "num_subgrids": int(np.count_nonzero(slots != 0xFFFFFFFF)),
        "min_extents": lower,
        "max_extents": lower + np.array([bx, by, bz], dtype=np.float64) * 8 * cell,
        "cell_size": np.full(3, cell),
        "subgrid_size": 8,
        "quantization_mode": mode[texture_format],
        "subgrids_min_sdf_value": float(layout["value_min"]),
        "subgrids_sdf_value_range": float(layout["value_range"]),
    }
    return create_sparse_sdf_textures(sparse, device=str(device), paired_samples=True)


def _attach_sdfs(model: Any, builder: Any, device: Any) -> None:
    """Gives a model finalized on the CPU its meshes' texture SDFs, in the tables Newton's CUDA finalize fills
    (ModelBuilder.finalize: _shape_sdf_index, _texture_sdf_data and the textures it keeps alive)."""
    from newton._src.geometry.sdf_texture import TextureSDFData

    index = [-1] * len(builder.shape_source)
    table, coarse, subgrid, slots, seen = [], [], [], [], {}
    for shape, source in enumerate(builder.shape_source):
        the_sdf = getattr(source, "sdf", None) if isinstance(source, newton.Mesh) else None
        if the_sdf is None or the_sdf.texture_data is None:
            continue
        if id(the_sdf) not in seen:
            seen[id(the_sdf)] = len(table)
            table.append(the_sdf.texture_data)
            coarse.append(the_sdf._coarse_texture)
            subgrid.append(the_sdf._subgrid_texture)
            slots.append(the_sdf.texture_data.subgrid_start_slots)
        index[shape] = seen[id(the_sdf)]
    if len(index) != model.shape_count:
        raise RuntimeError("voxfmt.newton: the model's shapes are not the builder's (a Newton release this was not made for?)")
    model._shape_sdf_index = wp.array(index, dtype=wp.int32, device=device)
    model._texture_sdf_data = wp.array(table, dtype=TextureSDFData, device=device)
    model._texture_sdf_coarse_textures = coarse
    model._texture_sdf_subgrid_textures = subgrid
    model._texture_sdf_subgrid_start_slots = slots
