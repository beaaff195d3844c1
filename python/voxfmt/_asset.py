"""What the engine modules (voxfmt.warp, voxfmt.newton) accept as an asset, and as a Warp device."""

from __future__ import annotations

import os
from typing import Any

from . import _voxfmt
from ._errors import OptionError


def as_body(asset: Any) -> Any:
    """A loaded asset: a voxfmt.Body as it is, a path loaded (and judged as voxfmt.load judges it: a damaged asset
    raises its code)."""
    if isinstance(asset, _voxfmt.Body):
        return asset
    if isinstance(asset, (str, os.PathLike)):
        return _voxfmt.load(asset)
    raise OptionError("BAD_OPTION", f"asset: expected a path or a voxfmt.Body, got {type(asset).__name__}")


def warp_device(wp: Any, device: Any) -> Any:
    """``wp.get_device(device)``; a device Warp does not know, or this machine lacks (``"cuda:0"`` without a GPU),
    is BAD_OPTION before any work, not Warp's ValueError after it."""
    try:
        return wp.get_device(device)
    except (ValueError, RuntimeError, TypeError) as error:
        raise OptionError("BAD_OPTION", f"device {device!r}: {error}") from None
