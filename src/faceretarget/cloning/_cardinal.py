"""Pyun et al. Sec. 4: cardinal basis weight functions (linear part + cubic B-spline radial part).

For key-models with parameter vectors ``p_1..p_M`` the weight function of key-model ``i`` is

    w_i(p) = sum_l a_il A_l(p) + sum_j r_ij R_j(p)

with ``A = (1, p_1, ..., p_d)`` the linear basis and ``R_j(p) = B(|p - p_j| / alpha_j)`` a cubic
B-spline of the distance to example ``j`` dilated by ``alpha_j``, the distance from ``p_j`` to its
nearest other example.  The linear coefficients are the least-squares fit of the cardinal conditions
``w_i(p_j) = delta_ij``; the radial coefficients interpolate what the linear part leaves over
(``R r = w'``), so every ``w_i`` is exactly cardinal at the examples.  Because the linear part
reproduces constants and the residuals of the cardinal conditions sum to zero, ``sum_i w_i(p) = 1``.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.distance import cdist

from ..base import Model
from ..errors import SingularKeysError

__all__ = ["cubic_bspline", "CardinalBasis"]


def cubic_bspline(x: np.ndarray) -> np.ndarray:
    """Uniform cubic B-spline of ``|x|``, support ``[0, 2)``, scaled so that ``B(0) = 1``."""
    a = np.abs(np.asarray(x, dtype=np.float64))
    out = np.zeros_like(a)
    m1 = a < 1
    m2 = (a >= 1) & (a < 2)
    out[m1] = (4 - 6 * a[m1] ** 2 + 3 * a[m1] ** 3) / 4
    out[m2] = (2 - a[m2]) ** 3 / 4
    return out


class CardinalBasis(Model):
    """Cardinal weight functions over example parameter vectors.

    Parameters
    ----------
    radial : bool
        Include the B-spline radial part (Pyun); ``False`` leaves the least-squares linear part only.

    Attributes
    ----------
    centers_ : (M, d) float
    dilation_ : (M,) float
    linear_ : (d + 1, M) float
    radial_ : (M, M) float
    """

    def __init__(self, radial: bool = True):
        self.radial = radial

    def fit(self, P: np.ndarray, labels: list[str] | None = None) -> CardinalBasis:
        P = np.asarray(P, dtype=np.float64)
        M = len(P)
        D = cdist(P, P)
        np.fill_diagonal(D, np.inf)
        nn = D.min(axis=1)
        j = int(np.argmin(nn))
        scale = float(np.median(nn[np.isfinite(nn)])) if M > 1 else 1.0
        if M > 1 and nn[j] <= 1e-9 * max(scale, 1e-300):
            k = int(np.argmin(D[j]))
            lab = labels or [str(i) for i in range(M)]
            raise SingularKeysError(
                f"key-models '{lab[j]}' and '{lab[k]}' have the same parameter vector: remove one"
            )
        self.centers_ = P
        self.dilation_ = nn if M > 1 else np.ones(1)
        A = np.hstack([np.ones((M, 1)), P])
        self.linear_ = np.linalg.pinv(A) @ np.eye(M)          # (d+1, M)
        resid = np.eye(M) - A @ self.linear_                 # (M, M): what the linear part misses
        if self.radial:
            R = self._radial_matrix(P)
            try:
                self.radial_ = np.linalg.solve(R, resid)
            except np.linalg.LinAlgError as e:
                raise SingularKeysError(f"radial basis matrix is singular ({e})") from e
        else:
            self.radial_ = np.zeros((M, M))
        return self

    def _radial_matrix(self, P: np.ndarray) -> np.ndarray:
        return cubic_bspline(cdist(P, self.centers_) / self.dilation_[None, :])

    def transform(self, P: np.ndarray) -> np.ndarray:
        """Weights ``(T, M)`` of the examples at parameter vectors ``P`` ``(T, d)``."""
        self._check_fitted()
        P = np.atleast_2d(np.asarray(P, dtype=np.float64))
        w = np.hstack([np.ones((len(P), 1)), P]) @ self.linear_
        if self.radial:
            w += self._radial_matrix(P) @ self.radial_
        return w
