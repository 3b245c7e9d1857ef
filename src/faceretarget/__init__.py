"""faceretarget: facial performance retargeting, expression cloning and style editing.

The shared vocabulary is :class:`Mesh`, :class:`Rig` and :class:`Performance`; readers and writers
live in :mod:`faceretarget.io`, Pyun et al.'s example-based cloning in :mod:`faceretarget.cloning`.
"""

from .errors import FaceRetargetError
from .mesh import Mesh
from .performance import Performance
from .rig import Rig

__version__ = "0.1.0"

__all__ = ["Mesh", "Rig", "Performance", "FaceRetargetError", "__version__"]
