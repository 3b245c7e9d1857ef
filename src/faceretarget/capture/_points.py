"""The 68 Multi-PIE feature points out of MediaPipe's 478 face landmarks, in a rig's axes.

Every rig of the package marks its 68 Multi-PIE landmarks (``landmarks68.txt``); MediaPipe's Face
Landmarker gives 478 points of its own canonical mesh.  :data:`MEDIAPIPE_68` picks, for each of the
68 points in the usual order (jaw line 0-16, brows 17-26, nose 27-35, eyes 36-47, lips 48-67), the
MediaPipe landmark at the same place on the face (the correspondence widely used to compare the two
trackers).  :func:`face_points` returns them with +Y up and +Z toward the camera (image y and
MediaPipe's depth flipped: a rotation by 180 degrees about X, so no mirror), in pixels.
"""

from __future__ import annotations

import numpy as np

from ..errors import InvalidDataError

__all__ = ["MEDIAPIPE_68", "face_points", "mouth_opening"]

#: MediaPipe Face Landmarker index of each of the 68 Multi-PIE landmarks, in Multi-PIE order.
MEDIAPIPE_68 = np.array([
    162, 234, 93, 58, 172, 136, 149, 148, 152, 377, 378, 365, 397, 288, 323, 454, 389,   # jaw 0-16
    71, 63, 105, 66, 107, 336, 296, 334, 293, 301,                                      # brows 17-26
    168, 197, 5, 4, 75, 97, 2, 326, 305,                                                # nose 27-35
    33, 160, 158, 133, 153, 144, 362, 385, 387, 263, 373, 380,                          # eyes 36-47
    61, 39, 37, 0, 267, 269, 291, 405, 314, 17, 84, 181,                                # outer lips 48-59
    78, 82, 13, 312, 308, 317, 14, 87,                                                  # inner lips 60-67
], dtype=np.int64)


def face_points(landmarks: np.ndarray) -> np.ndarray:
    """The 68 Multi-PIE points of MediaPipe landmarks, +Y up and +Z toward the camera.

    Parameters
    ----------
    landmarks : (T, 478, 3) or (478, 3) float
        MediaPipe landmarks in pixels (``x`` right, ``y`` down, ``z`` depth, smaller nearer the
        camera, on the scale of ``x``), as :class:`~faceretarget.capture.Capture` holds them.

    Returns
    -------
    (T, 68, 3) or (68, 3) float, pixels
    """
    L = np.asarray(landmarks, dtype=np.float64)
    if L.shape[-2:] != (478, 3):
        raise InvalidDataError(f"face_points: expected (..., 478, 3) MediaPipe landmarks, got shape {L.shape}")
    P = L[..., MEDIAPIPE_68, :].copy()
    P[..., 1] *= -1.0
    P[..., 2] *= -1.0
    return P


def mouth_opening(points68: np.ndarray) -> np.ndarray:
    """Inner-lip opening over the distance between the outer eye corners, per frame.

    Parameters
    ----------
    points68 : (T, 68, 3) or (T, 68, 2) float
        The 68 Multi-PIE points (any unit: the ratio has none).

    Returns
    -------
    (T,) float
        ``|p62 - p66| / |p36 - p45|`` (upper and lower inner lip middles; outer eye corners).
    """
    P = np.asarray(points68, dtype=np.float64)
    if P.ndim != 3 or P.shape[1] != 68:
        raise InvalidDataError(f"mouth_opening: expected (T, 68, D) points, got shape {P.shape}")
    return np.linalg.norm(P[:, 62] - P[:, 66], axis=-1) / np.linalg.norm(P[:, 36] - P[:, 45], axis=-1)
