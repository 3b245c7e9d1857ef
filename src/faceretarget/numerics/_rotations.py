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
    if svd is None:
        U, _, Vt = np.linalg.svd(np.asarray(matrices, dtype=np.float64))
    else:
        U, Vt = svd
    d = np.sign(np.linalg.det(U @ Vt))
    d = np.where(d == 0, 1.0, d)
    U = U.copy()
    U[..., :, 2] *= d[..., None]
    return U @ Vt
