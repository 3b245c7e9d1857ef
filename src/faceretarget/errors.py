"""Exceptions and warnings a user can act on.

Every error raised for bad input is a :class:`FaceRetargetError` whose message names the file,
shape, frame or row at fault.  The command line prints the message on one line and exits non-zero.

Warnings are :class:`FaceRetargetWarning` subclasses, never a bare ``UserWarning``, so a caller can
filter exactly what this package says (``warnings.simplefilter("error", DataWarning)``):

======================== =====================================================================
:class:`DataWarning`     an input was read with something dropped or guessed (rows, markers,
                         a frame rate), named in the message
:class:`FitWarning`      a model was fitted or applied where the data do not support it well
                         (dependent key-models, frames outside the key-models)
:class:`StyleRangeWarning`  an emotion edit left the range of its training data
:class:`StyleFitWarning` an untrained style has too few examples to be learned reliably
======================== =====================================================================
"""

from __future__ import annotations

__all__ = [
    "moved_names",
    "FaceRetargetError",
    "InputFileError",
    "TopologyError",
    "MissingShapeError",
    "InvalidDataError",
    "SingularKeysError",
    "OutputError",
    "NotFittedError",
    "MissingDependencyError",
    "FaceNotFoundError",
    "NotAFaceError",
    "FaceRetargetWarning",
    "DataWarning",
    "FitWarning",
    "StyleRangeWarning",
    "StyleFitWarning",
    "format_ranges",
    "excerpt",
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


class NotAFaceError(InvalidDataError):
    """A take or mesh that is not a face: its size or its marker labels say so (a full-body capture)."""


class SingularKeysError(FaceRetargetError, ValueError):
    """Key-models are (near) duplicates of each other, so weights cannot be solved for."""


class OutputError(FaceRetargetError, OSError):
    """An output could not be written; nothing partial is left behind."""


class NotFittedError(FaceRetargetError, AttributeError):
    """A model was applied (or saved) before :meth:`fit` (or ``load``)."""


class MissingDependencyError(FaceRetargetError, ImportError):
    """An optional package is not installed; the message names the extra that brings it."""


class FaceNotFoundError(FaceRetargetError, ValueError):
    """No face where one is needed: the landmarker found none on a character's renders (``views``
    says what was tried) or in a video."""

    def __init__(self, message: str, *, views: list | None = None):
        super().__init__(message)
        self.views = list(views or [])


class FaceRetargetWarning(UserWarning):
    """Base class of every warning faceretarget gives."""


class DataWarning(FaceRetargetWarning):
    """An input was read, but something in it was dropped, repaired or guessed."""


class FitWarning(FaceRetargetWarning):
    """A model was fitted or applied where the data do not support it well."""


class StyleRangeWarning(FaceRetargetWarning):
    """An emotion edit left the range of the training data (extrapolation)."""


class StyleFitWarning(FaceRetargetWarning):
    """An untrained style's examples are too few or too close to a known style to learn it well."""


def format_ranges(indices, limit: int | None = None) -> str:
    """Sorted indices (frames, lines) as runs for a message: ``[5, 6, 7, 9]`` -> ``"5-7, 9"``.

    With ``limit``, at most that many runs are shown and the rest counted.

    >>> format_ranges([5, 6, 7, 9])
    '5-7, 9'
    >>> format_ranges([1, 3, 5], limit=2)
    '1, 3 and 1 more run(s)'
    """
    idx = [int(i) for i in indices]
    if not idx:
        return ""
    runs, start = [], 0
    for k in range(1, len(idx) + 1):
        if k == len(idx) or idx[k] != idx[k - 1] + 1:
            a, b = idx[start], idx[k - 1]
            runs.append(str(a) if a == b else f"{a}-{b}")
            start = k
    more = f" and {len(runs) - limit} more run(s)" if limit is not None and len(runs) > limit else ""
    return ", ".join(runs if limit is None else runs[:limit]) + more


def excerpt(text, limit: int = 40, *, bare: bool = False) -> str:
    """A piece of a bad input for a message: ``repr`` of at most ``limit`` characters of ``text``
    (control characters and undecodable bytes escaped), ``...`` after it when it was longer.  With
    ``bare``, a printable text within the limit (a name) is shown as it is.

    >>> excerpt("12:00:01:02,x")
    "'12:00:01:02,x'"
    >>> excerpt("z" * 50, limit=4)
    "'zzzz'..."
    >>> excerpt("Head", bare=True)
    'Head'
    """
    s = text.decode("utf-8", "backslashreplace") if isinstance(text, bytes) else str(text)
    if bare and len(s) <= limit and s.isprintable():
        return s
    return repr(s[:limit]) + ("..." if len(s) > limit else "")


def moved_names(module: str, names, to: str):
    """A module's ``__getattr__`` for public names that moved to ``to``: each still works for one release,
    with a :class:`DeprecationWarning` naming the new place (``__getattr__ = moved_names(__name__, NAMES,
    "faceretarget.characters")``)."""
    import importlib
    import warnings

    moved = frozenset(names)

    def __getattr__(name: str):
        if name in moved:
            warnings.warn(f"{module}.{name} moved to {to}.{name}; the old name goes in the next release",
                          DeprecationWarning, stacklevel=2)
            return getattr(importlib.import_module(to), name)
        raise AttributeError(f"module {module!r} has no attribute {name!r}")

    return __getattr__
