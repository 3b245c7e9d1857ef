"""Optional dependencies: one way to import them and one error when they are missing.

``import faceretarget`` never needs an optional package; a function that does calls
:func:`optional_import` when it runs, and a missing package raises
:class:`~faceretarget.errors.MissingDependencyError` naming the extra that installs it.
"""

from __future__ import annotations

import importlib
from types import ModuleType

from .errors import MissingDependencyError

__all__ = ["optional_import", "EXTRAS"]

#: Which extra brings each optional package (``pip install 'faceretarget[EXTRA]'``).
EXTRAS: dict[str, str] = {
    "mediapipe": "capture",
    "av": "capture",
    "cv2": "capture",
    "numba": "fast",
    "pxr": "usd",
    "bpy": "blender",
    "moderngl": "preview",
    "dask": "batch",
    "distributed": "batch",
}
#: Core packages a failed import names directly (a broken install): ``pip install <name>``.
CORE_PACKAGES = {"meshopt": "meshopt", "DracoPy": "DracoPy", "ufbx": "ufbx"}


def optional_import(name: str, purpose: str, hint: str | None = None) -> ModuleType:
    """Import ``name`` (a module path such as ``"mediapipe.tasks.python"``) or raise.

    Parameters
    ----------
    name : str
        Module to import.
    purpose : str
        What needs it, for the message (``"video capture"``).
    hint : str, optional
        The install command to print instead of the extra's.

    Raises
    ------
    MissingDependencyError
        ``<purpose> needs the '<package>' package: pip install 'faceretarget[<extra>]'``.
    """
    try:
        return importlib.import_module(name)
    except ImportError as e:
        top = name.split(".")[0]
        extra = EXTRAS.get(top)
        how = hint or (f"pip install 'faceretarget[{extra}]'" if extra else f"pip install {top}")
        raise MissingDependencyError(f"{purpose} needs the '{top}' package ({e}): {how}") from e


def has_module(name: str) -> bool:
    """True when ``name`` can be imported (without importing it)."""
    import importlib.util

    try:
        return importlib.util.find_spec(name) is not None
    except (ImportError, ValueError):
        return False
