"""Compiled Lawson-Hanson NNLS over the frames of a take (optional: used when ``numba`` is installed).

Sparse keyshape weights (a few non-zero keys out of tens, strongly correlated keys) are where the
vectorised active-set methods of :mod:`faceretarget.numerics` pay NumPy's per-call overhead on
every one of their many small steps.  This kernel runs Lawson and Hanson's active-set method (1974,
the algorithm of ``scipy.optimize.nnls``) on the Gram form ``min 1/2 x'Gx - b'x, x >= 0`` frame
after frame in compiled code, each frame starting from the previous frame's free set (consecutive
frames of a take share most of it): the start set is pruned until its solution is positive, so the
method starts from a feasible point and ends, as always, only when the KKT conditions hold.

Install with ``pip install 'faceretarget[fast]'``; without numba the NumPy path is used and the
results are the same to rounding.
"""

from __future__ import annotations

import numpy as np

try:  # pragma: no cover - depends on the environment
    import numba
except ImportError:  # pragma: no cover
    numba = None

__all__ = ["available", "lawson_hanson_frames", "free_set_solve"]


def available() -> bool:
    """Whether the compiled kernel can be used."""
    return numba is not None


def _lh_frames_py(G, B, tol, max_iter, warm):  # pragma: no cover - compiled by numba
    T, N = B.shape
    X = np.zeros((T, N))
    free_out = np.zeros((T, N), dtype=np.bool_)
    stuck = np.zeros(T, dtype=np.bool_)
    P = np.zeros(N, dtype=np.bool_)
    idx = np.empty(N, dtype=np.int64)
    L = np.empty((N, N))
    z = np.empty(N)
    x = np.zeros(N)
    w = np.empty(N)
    banned = np.zeros(N, dtype=np.bool_)
    for t in range(T):
        b = B[t]
        bscale = 1e-300
        for i in range(N):
            if abs(b[i]) > bscale:
                bscale = abs(b[i])
        thr = tol * bscale
        for i in range(N):
            x[i] = 0.0
            banned[i] = False
            if not warm:
                P[i] = False
        # ---- solve on the free set (Cholesky), used by the warm start and the main loop
        it = 0
        first = True
        while True:
            if first and warm:
                # warm start: prune the previous free set until its solution is positive
                while True:
                    k = _gather(P, idx)
                    if k == 0:
                        break
                    ok = _chol_solve(G, b, idx, k, L, z)
                    if ok and _all_positive(z, k):
                        for a in range(k):
                            x[idx[a]] = z[a]
                        break
                    for a in range(k):
                        if (not ok) or z[a] <= 0.0:
                            P[idx[a]] = False
            first = False
            # gradient w = b - G x and the entering variable
            for i in range(N):
                s = b[i]
                for j in range(N):
                    if x[j] != 0.0:
                        s -= G[i, j] * x[j]
                w[i] = s
            jbest = -1
            best = thr
            for i in range(N):
                if (not P[i]) and (not banned[i]) and w[i] > best:
                    best = w[i]
                    jbest = i
            if jbest < 0:
                break
            if it >= max_iter:
                stuck[t] = True
                break
            it += 1
            P[jbest] = True
            # inner loop: keep the point feasible
            while True:
                k = _gather(P, idx)
                ok = _chol_solve(G, b, idx, k, L, z)
                if not ok:                      # the entering key is dependent on the free ones
                    P[jbest] = False
                    banned[jbest] = True
                    break
                if _all_positive(z, k):
                    for a in range(k):
                        x[idx[a]] = z[a]
                    break
                # step toward z until the first free weight reaches zero
                alpha = 2.0
                for a in range(k):
                    if z[a] <= 0.0:
                        xi = x[idx[a]]
                        r = xi / (xi - z[a]) if xi - z[a] > 0.0 else 0.0
                        if r < alpha:
                            alpha = r
                if alpha > 1.0:
                    alpha = 1.0
                moved = False
                for a in range(k):
                    i = idx[a]
                    x[i] = x[i] + alpha * (z[a] - x[i])
                    if x[i] <= 0.0 or (z[a] <= 0.0 and abs(x[i]) <= 1e-14 * bscale):
                        x[i] = 0.0
                        P[i] = False
                        moved = True
                if not moved:                   # rounding: drop the most negative
                    amin = 0
                    for a in range(1, k):
                        if z[a] < z[amin]:
                            amin = a
                    x[idx[amin]] = 0.0
                    P[idx[amin]] = False
            # an entering key that left again at once made no progress: skip it until x changes
            if P[jbest]:
                for i in range(N):
                    banned[i] = False
            else:
                banned[jbest] = True
        for i in range(N):
            X[t, i] = x[i]
            free_out[t, i] = P[i]
    return X, free_out, stuck


def _gather_py(mask, idx):  # pragma: no cover - compiled by numba
    """Indices of the true entries of ``mask`` into ``idx``; returns their count."""
    k = 0
    for i in range(mask.shape[0]):
        if mask[i]:
            idx[k] = i
            k += 1
    return k


def _all_positive_py(z, k):  # pragma: no cover - compiled by numba
    for a in range(k):
        if z[a] <= 0.0:
            return False
    return True


def _chol_solve_py(G, b, idx, k, L, z):  # pragma: no cover - compiled by numba
    """Solve ``G[idx, idx] z = b[idx]`` by Cholesky into ``z[:k]``; False when not positive definite."""
    for j in range(k):
        gj = idx[j]
        s = G[gj, gj]
        for p in range(j):
            s -= L[j, p] * L[j, p]
        if s <= 1e-300:
            return False
        d = np.sqrt(s)
        L[j, j] = d
        for i in range(j + 1, k):
            gi = idx[i]
            s = G[gi, gj]
            for p in range(j):
                s -= L[i, p] * L[j, p]
            L[i, j] = s / d
    for i in range(k):
        s = b[idx[i]]
        for p in range(i):
            s -= L[i, p] * z[p]
        z[i] = s / L[i, i]
    for i in range(k - 1, -1, -1):
        s = z[i]
        for p in range(i + 1, k):
            s -= L[p, i] * z[p]
        z[i] = s / L[i, i]
    return True


def _free_solve_py(G, R, free):  # pragma: no cover - compiled by numba
    T, N = R.shape
    out = np.zeros((T, N))
    idx = np.empty(N, dtype=np.int64)
    L = np.empty((N, N))
    z = np.empty(N)
    for t in range(T):
        k = _gather(free[t], idx)
        if k == 0:
            continue
        if _chol_solve(G, R[t], idx, k, L, z):
            for a in range(k):
                out[t, idx[a]] = z[a]
    return out


if numba is not None:  # pragma: no branch
    _gather = numba.njit(cache=True, nogil=True)(_gather_py)
    _all_positive = numba.njit(cache=True, nogil=True)(_all_positive_py)
    _chol_solve = numba.njit(cache=True, nogil=True)(_chol_solve_py)
    _lh_frames = numba.njit(cache=True, nogil=True)(_lh_frames_py)
    _free_solve = numba.njit(cache=True, nogil=True)(_free_solve_py)


def free_set_solve(G: np.ndarray, R: np.ndarray, free: np.ndarray) -> np.ndarray:
    """``d_t`` with ``G_FF d_F = r_F`` on each row's free set ``F`` (0 elsewhere); compiled."""
    return _free_solve(np.ascontiguousarray(G, dtype=np.float64), np.ascontiguousarray(R, dtype=np.float64),
                       np.ascontiguousarray(free, dtype=np.bool_))


def lawson_hanson_frames(G: np.ndarray, B: np.ndarray, tol: float = 1e-10, max_iter: int = 500,
                         warm: bool = True) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``min 1/2 x'Gx - b_t'x, x >= 0`` for every row ``b_t`` of ``B`` (compiled; needs numba).

    Parameters
    ----------
    G : (N, N) float, symmetric positive definite
    B : (T, N) float
    tol : float
        Relative KKT tolerance (of ``max |b_t|``).
    max_iter : int
        Variables entered per frame before giving up.
    warm : bool
        Start each frame from the previous frame's free set.

    Returns
    -------
    X : (T, N) float
    free : (T, N) bool
    stuck : (T,) bool
        Frames stopped by ``max_iter``.
    """
    if numba is None:
        raise RuntimeError("numba is not installed: pip install 'faceretarget[fast]'")
    G = np.ascontiguousarray(G, dtype=np.float64)
    B = np.ascontiguousarray(B, dtype=np.float64)
    return _lh_frames(G, B, float(tol), int(max_iter), bool(warm))
