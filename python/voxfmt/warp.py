"""voxfmt assets as NVIDIA Warp volumes: the asset's distance field as NanoVDB grids, built in memory from the runtime's
own field (no file, no GPU needed), on any Warp device.

    import warp as wp, voxfmt.warp
    distance, coarse = voxfmt.warp.volumes("bunny.vox.h5", device="cuda:0")
    # in a kernel: voxfmt.warp.sample_distance(distance.id, coarse.id, width, x) for a world point x in the grid

Two grids, float32, metres, in the asset's frame (index (i, j, k) at the asset's voxel centre):

- ``distance``: a narrow-band level set whose leaves are the asset's bricks near the surface. Its voxel values are
  the asset's stored distances within ``width`` of the surface, clamped to ``+-width`` beyond it; its tiles are
  signed from the asset's own inside/outside (so open meshes keep their signs). Between voxel centres it is read
  trilinearly, so in cells that straddle the clamp a sample lies below the runtime's by up to about a fifth of a
  voxel (take a width a voxel above the depth you read). ``width`` is the band the asset stores completely:
  ``distance_band - 1/2`` voxels (2.5 voxels for ``voxfmt build``'s default band), or a width you give.
- ``coarse``: one unsigned distance every 8 voxels (the asset's lattice), whose trilinear interpolation is the
  runtime's estimate in coarse bricks: the far field's magnitude where the level set is clamped, whose sign the level
  set's tiles carry (:func:`sample_distance` combines them as the runtime does there). It is an estimate, not a
  bound either way: up to 4 sqrt(3) voxels below the exact distance, and above it by up to 8 sqrt(3) voxels near
  the clamp (in value bricks a format 2.2 asset's own estimates are settled instead: never below the exact
  distance). Outside the asset's grid both grids hold their background (``+width``, and the largest lattice
  value), not a distance: :func:`sample_distance` is for points within the grid (``voxfmt.Body.signed_distance``
  continues the field beyond it as a lower bound).

``voxfmt export ASSET --nvdb OUT.nvdb`` writes the same grids to a file (``wp.Volume.load_from_nvdb`` reads it).
Needs ``warp-lang`` (``pip install 'voxfmt[warp]'``); tested with the version in :data:`WARP_VERSION`.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from . import _voxfmt
from ._asset import as_body, warp_device
from ._errors import OptionError
from .batch import _real

WARP_VERSION = "1.19.0"
"""The warp-lang release this module is tested with. It uses Warp's public volume API only (NanoVDB 32.x grids), so
other 1.x releases from 1.19 on are accepted."""


def _import_warp() -> Any:
    """warp, if an accepted release is installed; ImportError naming what to install otherwise."""
    try:
        import warp
    except ImportError as error:
        raise ImportError(
            f"voxfmt.warp needs NVIDIA Warp (warp-lang {WARP_VERSION}): pip install 'voxfmt[warp]'"
        ) from error
    major, minor = (int(part) for part in warp.__version__.split(".")[:2])
    if major != 1 or minor < 19:
        raise ImportError(
            f"voxfmt.warp needs warp-lang >= 1.19, < 2 (tested: {WARP_VERSION}); found {warp.__version__}: "
            "pip install 'voxfmt[warp]'"
        )
    return warp


wp = _import_warp()


def nvdb(asset: Any, *, width: float | None = None, compress: bool = True) -> tuple[bytes, dict[str, Any]]:
    """The asset's grids as the bytes of one ``.nvdb`` file (``distance``, then ``coarse``), and what they hold
    (``level_set_width`` in metres, leaf and voxel counts, ``uncompressed_bytes``).

    ``asset`` is a path (loaded and validated as :func:`voxfmt.load` does) or a :class:`voxfmt.Body`. ``width`` is the
    level set's half-width in voxels (default: the asset's complete band, ``distance_band - 1/2``); ``compress``
    uses NanoVDB's ZIP codec. A grid that reaches more than 2^20 voxels from the world origin is refused
    (``VALUE_OUT_OF_RANGE``: NanoVDB's readers map index to world in float).
    """
    if width is not None and not 0.5 <= _real("width", width) <= 32767:
        raise OptionError("BAD_OPTION", f"width: expected a number of voxels in [0.5, 32767], got {width!r}")
    if not isinstance(compress, (bool, np.bool_)):  # "no" is true
        raise OptionError("BAD_OPTION", f"compress: expected True or False, got {compress!r}")
    body = as_body(asset)
    data, info = _voxfmt._nanovdb(body, float(width or 0.0), bool(compress))
    return data, dict(info)


def volumes(asset: Any, device: Any = None, *, width: float | None = None) -> tuple[Any, Any]:
    """The asset's ``distance`` and ``coarse`` grids as two ``wp.Volume`` on ``device`` (default: Warp's default
    device). Arguments as :func:`nvdb`. The level set's width in metres is ``distance.voxfmt_width``."""
    device = warp_device(wp, device)
    data, info = nvdb(asset, width=width, compress=False)
    distance = wp.Volume.load_from_nvdb(data, device=device)
    coarse = distance.load_next_grid()
    distance.voxfmt_width = info["level_set_width"]
    coarse.voxfmt_width = info["level_set_width"]
    return distance, coarse


def volume(asset: Any, device: Any = None, *, grid: str = "distance", width: float | None = None) -> Any:
    """One of the asset's grids as a ``wp.Volume`` (``grid``: ``"distance"``, the narrow-band level set, or
    ``"coarse"``, the far field); see :func:`volumes`."""
    if not isinstance(grid, str) or grid not in ("distance", "coarse"):
        raise OptionError("BAD_OPTION", f"grid: expected 'distance' or 'coarse', got {grid!r}")
    distance, coarse = volumes(asset, device, width=width)
    return distance if grid == "distance" else coarse  # the coarse volume keeps the buffer they share alive


@wp.func
def sample_distance(distance: wp.uint64, coarse: wp.uint64, width: float, x: wp.vec3) -> float:
    """Signed distance (metres, negative inside) at world point ``x``: the level set where it is not clamped, else
    the coarse grid's estimate, at least ``width`` (the level set says the surface is no nearer), with the level
    set's sign: the runtime's own rule for voxels of coarse bricks."""
    d = wp.volume_sample_f(distance, wp.volume_world_to_index(distance, x), wp.Volume.LINEAR)
    if wp.abs(d) < width * 0.999:
        return d
    c = wp.volume_sample_f(coarse, wp.volume_world_to_index(coarse, x), wp.Volume.LINEAR)
    return wp.sign(d) * wp.max(c, width)
