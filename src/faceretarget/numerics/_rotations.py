"""Nearest rotations: the one polar-decomposition helper behind rigid fits, head poses and
deformation gradients; exp-map blending of key rotations (skeletal retargeting targets)."""

from __future__ import annotations

import numpy as np

from ..errors import InvalidDataError

__all__ = ["nearest_rotation", "blend_rotations"]


def nearest_rotation(matrices: np.ndarray | None = None, *, svd: tuple[np.ndarray, np.ndarray] | None = None
                     ) -> np.ndarray:
    """Proper rotations nearest (in the Frobenius norm) to ``(..., 3, 3)`` matrices.

    The rotation factor of the polar decomposition, with the sign of its last singular direction
    flipped when needed so that the determinant is +1 (never a reflection).

    Parameters
    ----------
    matrices : (..., 3, 3) float
        Matrices that may carry scale, shear or noise.
    svd : (U, Vt), optional
        Their singular vectors when already computed (``matrices`` is then not used).

    Returns
    -------
    (..., 3, 3) float

    Examples
    --------
    >>> R = nearest_rotation(np.diag([2.0, 3.0, -1.0])[None])
    >>> np.round(R[0], 6).tolist(), round(float(np.linalg.det(R[0])), 6)
    ([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]], 1.0)
    """
    if svd is not None:
        # the rigid fit's (Kabsch) evaluation, U diag(1, 1, d) Vt in one einsum: the same rotation
        # as below, kept in this order so that aligned takes stay bit-identical to earlier releases
        # (a last-bit change flips near-tied pivots of pivoted-QR key selection downstream)
        U, Vt = svd
        d = np.sign(np.linalg.det(U) * np.linalg.det(Vt))
        D = np.ones(U.shape[:-1])
        D[..., 2] = np.where(d == 0, 1.0, d)
        return np.einsum("...ij,...j,...jk->...ik", U, D, Vt)
    U, _, Vt = np.linalg.svd(np.asarray(matrices, dtype=np.float64))
    d = np.sign(np.linalg.det(U @ Vt))
    d = np.where(d == 0, 1.0, d)
    U[..., :, 2] *= d[..., None]
    return U @ Vt


def blend_rotations(rest: np.ndarray, keys: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """Blend key rotations by weights in the log map about a rest rotation (exp-map blending).

    Every key is expressed as its offset from the rest rotation, ``D_k = R_0^-1 R_k``, taken to its
    rotation vector ``r_k = log(D_k)`` (angle <= pi); the blend is ``R(w) = R_0 exp(sum_k w_k r_k)``.
    So ``w = 0`` gives the rest, a unit vector ``e_k`` gives key ``k`` exactly, a single key scaled
    by ``w`` turns by ``w`` times its angle about the same axis (``slerp(R_0, R_k, w)``), and any
    weights -- negative ones and sums above 1 from a signed solve included -- give a proper rotation.
    A normalised weighted quaternion sum would need weights that sum to 1 and fails where they cancel.

    Parameters
    ----------
    rest : (..., 4) float
        Rest rotations as unit quaternions ``x, y, z, w`` (one per joint, say ``(J, 4)``).
    keys : (K, ..., 4) float
        Key rotations, the same joints for each of ``K`` keys.
    weights : (T, K) float
        Key weights per frame.

    Returns
    -------
    (T, ..., 4) float
        Unit quaternions ``x, y, z, w`` with ``w >= 0``.

    Examples
    --------
    >>> from scipy.spatial.transform import Rotation
    >>> rest = Rotation.identity().as_quat()[None]
    >>> key = Rotation.from_euler("z", [90], degrees=True).as_quat()[None, None]
    >>> q = blend_rotations(rest, key, np.array([[0.5]]))
    >>> round(float(Rotation.from_quat(q[0, 0]).as_euler("xyz", degrees=True)[2]), 6)
    45.0
    """
    from scipy.spatial.transform import Rotation

    rest = np.asarray(rest, dtype=np.float64)
    keys = np.asarray(keys, dtype=np.float64)
    w = np.atleast_2d(np.asarray(weights, dtype=np.float64))
    shape = rest.shape[:-1]
    K = keys.shape[0]
    if rest.shape[-1] != 4 or keys.shape[1:] != rest.shape or w.shape[1] != K:
        raise InvalidDataError(f"rest (..., 4), keys (K, ..., 4) and weights (T, K) do not match: {rest.shape}, "
                         f"{keys.shape}, {w.shape}")
    R0 = Rotation.from_quat(rest.reshape(-1, 4))
    n = len(R0)
    logs = np.empty((K, n, 3))
    for k in range(K):
        logs[k] = (R0.inv() * Rotation.from_quat(keys[k].reshape(-1, 4))).as_rotvec()
    v = (w @ logs.reshape(K, -1)).reshape(len(w), n, 3)                    # (T, n, 3)
    q = (Rotation.from_quat(np.broadcast_to(rest.reshape(1, n, 4), (len(w), n, 4)).reshape(-1, 4))
         * Rotation.from_rotvec(v.reshape(-1, 3))).as_quat()
    q *= np.where(q[:, 3:] < 0, -1.0, 1.0)
    return q.reshape((len(w),) + shape + (4,))
