"""Live mode, the part of :mod:`faceretarget.pipelines` that runs while a camera or a video plays: a
:class:`LiveSession` solves each frame onto a character as it arrives (MediaPipe, the landmark solve, the head)
and :func:`run_live` (``faceretarget live``, the Blender extension's live job) shows it in a local three.js page
served by :class:`LiveServer` (the standard library's HTTP server and a small RFC 6455 WebSocket, in
``_server.py``; the session in ``_session.py``).  Everything here is also importable from
:mod:`faceretarget.pipelines`.
"""

from ._server import LiveServer
from ._session import LIVE_LIMITS, LiveFrame, LiveSession, LiveStats, character_glb, run_live

__all__ = ["run_live", "LiveSession", "LiveStats", "LiveFrame", "LiveServer", "character_glb", "LIVE_LIMITS"]
