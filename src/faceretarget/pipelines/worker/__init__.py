"""The worker, the part of :mod:`faceretarget.pipelines` that a host application runs its long jobs in (the
Blender extension starts it as a child process): :func:`serve_jobs` reads JSON-line requests (``animate``,
``take``, ``landmarks``, ``style_info``, ``live``: :data:`JOB_KINDS`) and answers on a :class:`WorkerChannel`
with progress, log lines, live frames and results, each job the library's own (:func:`~faceretarget.pipelines.animate`,
:func:`~faceretarget.pipelines.apply_take`, :class:`~faceretarget.pipelines.LiveSession`), a video's capture
cached by its content (:func:`cached_capture`, :func:`capture_cache_path`).  The protocol is in ``_serve.py``.
Everything here is also importable from :mod:`faceretarget.pipelines`.
"""

from ._serve import (
    JOB_KINDS,
    WorkerChannel,
    cached_capture,
    capture_cache_path,
    character_parts,
    read_character_parts,
    serve_jobs,
)

__all__ = ["serve_jobs", "JOB_KINDS", "WorkerChannel", "cached_capture", "capture_cache_path", "character_parts",
           "read_character_parts"]
