"""Nearest rotations: the one polar-decomposition helper behind rigid fits, head poses and
deformation gradients."""

from __future__ import annotations

import numpy as np

__all__ = ["nearest_rotation"]


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
