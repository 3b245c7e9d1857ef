"""The ``faceretarget`` command line: a thin shell over :mod:`faceretarget.pipelines` and the methods.

Every error a user can act on is printed as one line (``faceretarget: error: ...``) naming the file,
shape or frame, and the exit code is non-zero (2 for bad input, 1 otherwise).
"""

from ._main import build_parser, main

__all__ = ["main", "build_parser"]
