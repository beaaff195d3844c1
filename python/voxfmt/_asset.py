"""What the engine modules (voxfmt.warp, voxfmt.newton) accept as an asset."""

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
