"""faceretarget: facial performance retargeting, expression cloning and style editing.

The shared vocabulary is :class:`Mesh`, :class:`Rig`, :class:`Performance` (one take, with any of
weights, points, vertices, a :class:`HeadPose` and audio) and :class:`Model` (the protocol of every
fitted model).  Readers and writers live in :mod:`faceretarget.io`, the methods in
:mod:`faceretarget.cloning` (Pyun et al. 2003), :mod:`faceretarget.retarget`,
:mod:`faceretarget.style`, :mod:`faceretarget.headmotion` and :mod:`faceretarget.capture` (Chuang
2004), the jobs a user runs in :mod:`faceretarget.pipelines`.  See ``docs/architecture.md``.

The names below are loaded on first use (PEP 562), so ``import faceretarget`` (and the command
line's ``--version`` / ``--help``) does not import NumPy or SciPy.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING

if TYPE_CHECKING:  # the re-exports, loaded lazily by __getattr__ below
    from .base import Model
    from .errors import FaceRetargetError
    from .headpose import HeadPose
    from .mesh import Mesh
    from .performance import Performance
    from .rig import Rig

__version__ = "0.1.0"

__all__ = ["Mesh", "Rig", "Performance", "HeadPose", "Model", "FaceRetargetError", "__version__"]

_LAZY = {"Model": ".base", "FaceRetargetError": ".errors", "HeadPose": ".headpose", "Mesh": ".mesh",
         "Performance": ".performance", "Rig": ".rig"}


def __getattr__(name: str):
    """``faceretarget.Rig`` and the other re-exports, imported when first asked for."""
    mod = _LAZY.get(name)
    if mod is None:
        raise AttributeError(f"module 'faceretarget' has no attribute {name!r}")
    value = getattr(importlib.import_module(mod, __name__), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))
