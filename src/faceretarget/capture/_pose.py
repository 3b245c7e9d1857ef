"""Head pose from MediaPipe's facial transformation matrix, as Live Link Face head angles.

Frame and convention
--------------------
MediaPipe's ``facial_transformation_matrixes`` is a (4, 4) rigid transform from its canonical face
model (centimetres) into a virtual perspective camera's frame: x to the image's right, y up, z
toward the viewer (OpenGL; the face sits at negative z).  The canonical face looks down +z, with
+x on the performer's left, like ARKit's face anchor.

The rotation part ``R`` is decomposed as intrinsic yaw, pitch, roll (Unreal's ``FRotator`` order,
which Live Link Face feeds)::

    R = Ry(yaw) @ Rx(-pitch) @ Rz(roll)

in radians, so that

* ``HeadYaw > 0``: the performer turns their head to their own left (the nose moves to the
  image's right);
* ``HeadPitch > 0``: the performer looks up (chin up);
* ``HeadRoll > 0``: the head tilts toward the performer's right shoulder (counter-clockwise as the
  camera sees it).

Neither Apple nor Epic documents the signs of Live Link Face's ``HeadYaw/HeadPitch/HeadRoll``
columns; these follow the mapping used by the MediaPipe-to-Live-Link tools that drive MetaHumans
(pitch negated, yaw and roll as is).  Translation is the matrix's last column in centimetres in
the same camera frame.
"""

from __future__ import annotations

import numpy as np

from ..errors import InvalidDataError

__all__ = ["matrix_to_pose", "pose_to_matrix"]


def _orthonormal(R: np.ndarray) -> np.ndarray:
    """Nearest rotations (SVD) of (N, 3, 3) matrices that may carry scale or noise."""
    U, _, Vt = np.linalg.svd(R)
    d = np.sign(np.linalg.det(U @ Vt))
    U[..., :, 2] *= d[..., None]
    return U @ Vt


def matrix_to_pose(matrices: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Head yaw, pitch, roll and translation from (4, 4) facial transformation matrices.

    Parameters
    ----------
    matrices : (..., 4, 4) float
        MediaPipe facial transformation matrices (NaN matrices give NaN angles).

    Returns
    -------
    rotation : (..., 3) float
        ``HeadYaw, HeadPitch, HeadRoll`` in radians (convention in the module docstring).
    translation : (..., 3) float
        Head position in centimetres in the camera frame (x right, y up, z toward the viewer).

    Examples
    --------
    >>> M = pose_to_matrix(np.array([0.3, -0.2, 0.1]), np.array([1.0, 2.0, -40.0]))
    >>> r, t = matrix_to_pose(M)
    >>> np.round(r, 6).tolist(), t.tolist()
    ([0.3, -0.2, 0.1], [1.0, 2.0, -40.0])
    """
    M = np.asarray(matrices, dtype=np.float64)
    if M.shape[-2:] != (4, 4):
        raise InvalidDataError(f"facial transformation matrices must be (..., 4, 4), got {M.shape}")
    lead = M.shape[:-2]
    M = M.reshape(-1, 4, 4)
    rot = np.full((M.shape[0], 3), np.nan)
    ok = np.isfinite(M).all(axis=(1, 2))
    if ok.any():
        R = _orthonormal(M[ok, :3, :3])
        # R = Ry(a) Rx(b) Rz(c):  R[1,2] = -sin b;  R[0,2] = sin a cos b;  R[2,2] = cos a cos b;
        #                         R[1,0] = cos b sin c;  R[1,1] = cos b cos c
        b = np.arcsin(np.clip(-R[:, 1, 2], -1.0, 1.0))
        a = np.arctan2(R[:, 0, 2], R[:, 2, 2])
        c = np.arctan2(R[:, 1, 0], R[:, 1, 1])
        rot[ok] = np.stack([a, -b, c], axis=1)
    trans = M[:, :3, 3].copy()
    return rot.reshape(lead + (3,)), trans.reshape(lead + (3,))


def pose_to_matrix(rotation: np.ndarray, translation: np.ndarray | None = None) -> np.ndarray:
    """Inverse of :func:`matrix_to_pose`: (..., 3) yaw, pitch, roll [+ translation] -> (..., 4, 4)."""
    r = np.asarray(rotation, dtype=np.float64)
    yaw, pitch, roll = r[..., 0], -r[..., 1], r[..., 2]
    ca, sa, cb, sb, cc, sc = np.cos(yaw), np.sin(yaw), np.cos(pitch), np.sin(pitch), np.cos(roll), np.sin(roll)
    one, zero = np.ones_like(ca), np.zeros_like(ca)
    Ry = np.stack([np.stack([ca, zero, sa], -1), np.stack([zero, one, zero], -1), np.stack([-sa, zero, ca], -1)], -2)
    Rx = np.stack([np.stack([one, zero, zero], -1), np.stack([zero, cb, -sb], -1), np.stack([zero, sb, cb], -1)], -2)
    Rz = np.stack([np.stack([cc, -sc, zero], -1), np.stack([sc, cc, zero], -1), np.stack([zero, zero, one], -1)], -2)
    M = np.zeros(r.shape[:-1] + (4, 4))
    M[..., :3, :3] = Ry @ Rx @ Rz
    M[..., 3, 3] = 1.0
    if translation is not None:
        M[..., :3, 3] = np.asarray(translation, dtype=np.float64)
    return M
