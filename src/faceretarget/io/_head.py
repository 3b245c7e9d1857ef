"""Write synthesized head motion as BVH, glTF node animation or Live Link Face CSV.

==========  ==========================================================================================
``.bvh``    One root joint ``Head``: channels ``Yrotation Xrotation Zrotation`` = yaw, pitch, roll
            in degrees (and ``Xposition Yposition Zposition`` in centimetres first, with a
            translation), at the performance's frame rate.
``.glb``    A node ``head`` with a ``rotation`` channel (quaternions ``x, y, z, w``) and, with a
            translation, a ``translation`` channel in metres, in one animation ``head``
            (:func:`faceretarget.io.gltf.write_glb_head`); combine it with a face by passing the
            same quaternions to ``write_glb(..., head_rotation=...)``.
``.csv``    Live Link Face columns (:func:`faceretarget.io.write_livelinkface`): ``HeadYaw``,
            ``HeadPitch``, ``HeadRoll`` in **radians** (the unit Live Link Face writes) in Live Link
            Face's sign convention, the one ``faceretarget capture`` writes: ``HeadPitch`` is
            positive chin up, so it is the negated right-hand pitch used everywhere else here;
            the 52 blendshape columns zero; no translation (the format has no column for it).
==========  ==========================================================================================
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from ..errors import InvalidDataError, OutputError
from ..performance import Performance

EULER = "YXZ"

__all__ = ["write_head_motion", "head_quaternions", "HEAD_FORMATS"]

HEAD_FORMATS = (".bvh", ".glb", ".csv")
# right-hand yaw, pitch, roll (Y-X-Z, +X the character's left) -> Live Link Face HeadYaw, HeadPitch, HeadRoll
LLF_SIGNS = np.array([1.0, -1.0, 1.0])


def head_quaternions(head_rotation: np.ndarray) -> np.ndarray:
    """(T, 4) unit quaternions ``x, y, z, w`` of (T, 3) yaw, pitch, roll radians (Y-X-Z)."""
    return Rotation.from_euler(EULER, np.asarray(head_rotation, np.float64)).as_quat()


def write_head_motion(path: str | os.PathLike, perf: Performance, protect: tuple = ()) -> Path:
    """Write ``perf.head_rotation`` (radians) and ``perf.head_translation`` (cm) by file extension.

    Parameters
    ----------
    path : path-like
        ``.bvh``, ``.glb`` or ``.csv`` (module docstring).
    perf : Performance
        With ``head_rotation`` (T, 3) yaw, pitch, roll in radians; ``head_translation`` (T, 3)
        centimetres or None.
    protect : tuple of path-like
        Inputs the output must not overwrite.
    """
    from ._bvh import make_head_bvh, write_bvh
    from ._gltf import write_glb_head
    from ._livelinkface import write_livelinkface

    path = Path(path)
    ext = path.suffix.lower()
    if ext not in HEAD_FORMATS:
        raise OutputError(f"{path}: unknown head-motion output format '{ext}' (use {', '.join(HEAD_FORMATS)})")
    for p in protect:
        if p is not None and Path(p).exists() and path.exists() and os.path.samefile(p, path):
            raise OutputError(f"{path}: refusing to overwrite an input file")
    if perf.head_rotation is None:
        raise InvalidDataError(f"{perf.source}: no head rotation to write")
    rot = perf.head_rotation
    tr = perf.head_translation
    if ext == ".bvh":
        bvh = make_head_bvh(np.degrees(rot), perf.fps, tr)
        return write_bvh(path, bvh)
    if ext == ".glb":
        return write_glb_head(path, perf.times, head_quaternions(rot), None if tr is None else tr / 100.0)
    # Live Link Face's HeadPitch is positive chin up (Unreal's pitch), the opposite of the right-hand
    # angle about +X used here; yaw and roll agree (see faceretarget.capture._pose, which reads the
    # same columns)
    llf = rot * LLF_SIGNS
    perf = Performance(perf.times, perf.fps, weights=perf.weights if perf.weights is not None
                       else np.zeros((perf.n_frames, 0)), names=list(perf.names or []),
                       head_rotation=llf, source=perf.source)
    return write_livelinkface(path, perf)
