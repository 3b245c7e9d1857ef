"""Keyshape selection from a take (Chuang Sec. 3.3): which frames an artist should model.

``pca_extrema`` projects every frame onto the principal axes of the take and takes the two extreme
frames of each axis in turn, skipping frames already chosen or closer than ``min_distance`` (a
fraction of the take's RMS spread) to a chosen one.
"""

from __future__ import annotations

import numpy as np

from ..errors import InvalidDataError

__all__ = ["pca_extrema", "SELECTION_METHODS", "select_keyshapes"]


def pca_extrema(X: np.ndarray, k: int, min_distance: float = 0.05) -> np.ndarray:
    """Indices of ``k`` frames of ``X`` ``(T, D)`` at the extremes of its principal axes.

    Parameters
    ----------
    X : (T, D) float
        One row per frame (feature displacements).
    k : int
        Number of frames to choose.
    min_distance : float
        Frames closer than this fraction of the take's RMS distance from its mean to an already
        chosen frame are treated as duplicates and skipped.

    Returns
    -------
    (k,) int, in the order chosen.
    """
    X = np.asarray(X, dtype=np.float64)
    T = len(X)
    if k < 1 or k > T:
        raise InvalidDataError(f"cannot choose {k} keyshapes from a take of {T} frames")
    Xc = X - X.mean(axis=0)
    _, _, vt = np.linalg.svd(Xc, full_matrices=False)
    # SVD axes have no sign: fix it (largest coordinate positive) so the choice order is reproducible
    big = np.argmax(np.abs(vt), axis=1)
    vt = vt * np.sign(vt[np.arange(len(vt)), big])[:, None]
    proj = Xc @ vt.T
    spread = float(np.sqrt((Xc**2).sum(axis=1).mean())) or 1.0
    tol = min_distance * spread
    chosen: list[int] = []
    for axis in range(proj.shape[1]):
        order_hi = np.argsort(-proj[:, axis])
        order_lo = order_hi[::-1]
        for order in (order_hi, order_lo):
            for i in order[: max(50, T // 20)]:
                i = int(i)
                if i in chosen:
                    continue
                if chosen and np.min(np.linalg.norm(X[chosen] - X[i], axis=1)) < tol:
                    continue
                chosen.append(i)
                break
            if len(chosen) == k:
                return np.asarray(chosen)
    # fewer distinct extremes than asked: fill with the frames farthest from the chosen ones
    while len(chosen) < k:
        d = np.min(np.linalg.norm(X[:, None, :] - X[chosen][None], axis=2), axis=1) if chosen else np.linalg.norm(Xc, axis=1)
        chosen.append(int(np.argmax(d)))
    return np.asarray(chosen)


SELECTION_METHODS = {"pca-extrema": pca_extrema}


def select_keyshapes(X: np.ndarray, k: int, method: str = "pca-extrema", **kw) -> np.ndarray:
    """Choose ``k`` keyshape frames of ``X`` ``(T, D)`` with a named method."""
    if method not in SELECTION_METHODS:
        raise InvalidDataError(f"unknown keyshape selection method '{method}', use one of {sorted(SELECTION_METHODS)}")
    return SELECTION_METHODS[method](X, k, **kw)
