"""voxfmt.Error and its subclasses: one per kind of failure, each carrying the library's stable code."""

from __future__ import annotations

from typing import Any

__all__ = [
    "Error",
    "AssetError",
    "MeshError",
    "WriteError",
    "OptionError",
    "PoseError",
    "InternalError",
    "make_error",
]


class Error(Exception):
    """A failure of a voxfmt call. ``code`` is the stable code of spec/issue-codes.md (the same string the C++
    library and the CLI report, e.g. ``"ZERO_VOLUME"``); ``message`` is for people; ``file`` and ``object``
    locate it (the file concerned and the HDF5 object inside it, empty when unknown)."""

    def __init__(self, code: str, message: str, file: str = "", object: str = "") -> None:
        super().__init__(f"{code}: {message}")
        self.code = code
        self.message = message
        self.file = file
        self.object = object

    def __reduce__(self) -> tuple[Any, ...]:
        # Exception's own replays cls(*self.args), one string here: a worker's error could not be unpickled
        # (multiprocessing hangs, ProcessPoolExecutor breaks). The state keeps attributes set since (add_note's).
        return type(self), (self.code, self.message, self.file, self.object), self.__dict__


class AssetError(Error):
    """An asset file that cannot be read or breaks a rule of the format (FILE_NOT_FOUND, NOT_HDF5, READ_FAILED,
    a validation code, INVALID_ASSET)."""


class MeshError(Error):
    """A mesh the bake cannot use (INPUT_NOT_FOUND, UNSUPPORTED_FORMAT, IMPORT_FAILED, EMPTY_SCENE,
    NON_FINITE_COORDINATES, ZERO_VOLUME, GRID_TOO_LARGE, SCALE_OUT_OF_RANGE)."""


class WriteError(Error):
    """A file that could not be written (WRITE_FAILED); an earlier file at that path is untouched."""


class OptionError(Error, ValueError):
    """An option or argument outside its range, or an array of the wrong shape (BAD_OPTION)."""


class PoseError(Error, ValueError):
    """A pose that is not a rigid transform (BAD_POSE)."""


class InternalError(Error):
    """Memory ran out or a library failed (OUT_OF_MEMORY, INTERNAL, TIMEOUT, CRASHED)."""


_MESH_CODES = frozenset(
    {
        "INPUT_NOT_FOUND",
        "UNSUPPORTED_FORMAT",
        "IMPORT_FAILED",
        "EMPTY_SCENE",
        "NON_FINITE_COORDINATES",
        "ZERO_VOLUME",
        "GRID_TOO_LARGE",
        "SCALE_OUT_OF_RANGE",
    }
)
_CLASS_OF_CODE: dict[str, type[Error]] = {
    "WRITE_FAILED": WriteError,
    "BAD_OPTION": OptionError,
    "BAD_POSE": PoseError,
    "OUT_OF_MEMORY": InternalError,
    "INTERNAL": InternalError,
    "TIMEOUT": InternalError,
    "CRASHED": InternalError,
    **{code: MeshError for code in _MESH_CODES},
}


def make_error(code: str, message: str, file: str = "", object: str = "") -> Error:
    """The exception for a library error (called by the compiled module)."""
    return _CLASS_OF_CODE.get(code, AssetError)(code, message, file, object)
