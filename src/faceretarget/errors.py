"""Exceptions a user can act on.

Every error raised for bad input is a :class:`FaceRetargetError` whose message names the file,
shape, frame or row at fault.  The command line prints the message on one line and exits non-zero.
"""

from __future__ import annotations

__all__ = [
    "FaceRetargetError",
    "InputFileError",
    "TopologyError",
    "MissingShapeError",
    "InvalidDataError",
    "SingularKeysError",
    "OutputError",
]


class FaceRetargetError(Exception):
    """Base class of every error faceretarget raises for bad input or output."""


class InputFileError(FaceRetargetError, ValueError):
    """A file could not be read or holds something that is not what was expected."""


class TopologyError(FaceRetargetError, ValueError):
    """Meshes that must share a vertex order do not (vertex counts or faces differ)."""


class MissingShapeError(FaceRetargetError, KeyError):
    """A required key shape, neutral or key-model is absent."""

    def __str__(self) -> str:  # KeyError would quote the message
        return str(self.args[0]) if self.args else ""


class InvalidDataError(FaceRetargetError, ValueError):
    """Array data is malformed: wrong shape, NaN or infinite values, bad times."""


class SingularKeysError(FaceRetargetError, ValueError):
    """Key-models are (near) duplicates of each other, so weights cannot be solved for."""


class OutputError(FaceRetargetError, OSError):
    """An output could not be written; nothing partial is left behind."""
