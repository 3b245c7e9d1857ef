"""faceretarget: facial performance retargeting, expression cloning and style editing.

The shared vocabulary is :class:`Mesh`, :class:`Rig`, :class:`Performance` (one take, with any of
weights, points, vertices, a :class:`HeadPose` and audio) and :class:`Model` (the protocol of every
fitted model).  Readers and writers live in :mod:`faceretarget.io`, the methods in
:mod:`faceretarget.cloning` (Pyun et al. 2003), :mod:`faceretarget.retarget`,
:mod:`faceretarget.style`, :mod:`faceretarget.headmotion` and :mod:`faceretarget.capture` (Chuang
2004), the jobs a user runs in :mod:`faceretarget.pipelines`.  See ``docs/architecture.md``.
"""

from .base import Model
from .errors import FaceRetargetError
from .headpose import HeadPose
from .mesh import Mesh
from .performance import Performance
from .rig import Rig

__version__ = "0.1.0"

__all__ = ["Mesh", "Rig", "Performance", "HeadPose", "Model", "FaceRetargetError", "__version__"]
