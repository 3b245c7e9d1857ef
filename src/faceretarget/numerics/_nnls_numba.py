"""Compiled box-constrained least squares over the frames of a take (optional: used when ``numba`` is installed).

Keyshape weights of consecutive frames share most of their active set, and a take's frames are
small problems (tens of keys): the vectorised active-set methods of :mod:`._nnls_active_set` pay NumPy's
per-call overhead on every one of their small steps, ``scipy.optimize.nnls`` /
``scipy.optimize.lsq_linear`` pay Python's per frame.  This kernel runs the bounded Lawson-Hanson
method (BVLS; Lawson & Hanson 1974, Stark & Parker 1995) on the Gram form::

    min_x  1/2 x'Gx - b_t'x      subject to  0 <= x <= ub        (every row b_t of B)

frame after frame in compiled code:

* **warm start**: each frame starts from the previous frame's point and sets (at 0, free, at the
  upper bound): that point is feasible for every frame, so the method descends from it at once
  (solve on the free set, step back to the box boundary where the solution leaves the box) and, as
  always, ends only when the KKT conditions hold;
* **updated factorisation**: the Cholesky factor of ``G`` on the free set is carried from step to
  step and frame to frame and updated when a variable enters (a new row, ``O(k^2)``) or leaves
  (Givens rotations, ``O(k^2)``) instead of being recomputed (``O(k^3)``): a frame whose sets equal
  its predecessor's costs two triangular solves and one gradient;
* **exact check** for ill-conditioned keys (``cond(G) > 1e10``): a frame's Gram-form optimum gets
  one step of iterative refinement with the gradient computed from the least-squares data
  ``(R, c_t)`` itself (``K = QR`` projected, ``c_t = Q'f_t``: corrected semi-normal equations) and
  is checked against the exact KKT conditions; a frame that fails is finished in exact mode (every
  solve refined, every gradient exact), so forming ``G = R'R`` costs no accuracy.

Install with ``make fast`` (or ``pip install 'numba>=0.60'``); without numba the NumPy path of :mod:`._nnls_box_qp`
is used and the results are the same to rounding.
"""

from __future__ import annotations

import math
import sys
import threading
import time

import numpy as np

from ..errors import MissingDependencyError
from ..optional import optional_import

try:  # pragma: no cover - depends on the environment
    numba = optional_import("numba", "the compiled solver kernel")
except MissingDependencyError:  # pragma: no cover
    numba = None

__all__ = ["available", "box_frames", "compile_kernels", "COMPILE_NOTICE_AFTER", "COMPILE_SECONDS"]

#: Seconds a first call may spend compiling before a terminal is told why it waits.
COMPILE_NOTICE_AFTER = 1.5

AT_ZERO, FREE, AT_UPPER = 0, 1, 2


def available() -> bool:
    """Whether the compiled kernel can be used."""
    return numba is not None


# ----------------------------------------------------------------------------- Cholesky factor of G_FF
def _chol_append_py(G, L, idx, k, j):  # pragma: no cover - compiled by numba
    """Append variable ``j`` to the factor ``L`` of ``G[idx[:k], idx[:k]]``; False when it is dependent."""
    d2 = G[j, j]
    for a in range(k):
        v = G[idx[a], j]
        for p in range(a):
            v -= L[a, p] * L[k, p]
        v /= L[a, a]
        L[k, a] = v
        d2 -= v * v
    if not d2 > 1e-14 * G[j, j]:
        return False
    L[k, k] = math.sqrt(d2)
    idx[k] = j
    return True


def _chol_delete_py(L, idx, k, p):  # pragma: no cover - compiled by numba
    """Remove position ``p`` from the factor ``L`` of ``G[idx[:k], idx[:k]]`` (Givens rotations)."""
    for i in range(p, k - 1):
        idx[i] = idx[i + 1]
        for c in range(i + 2):
            L[i, c] = L[i + 1, c]
    for i in range(p, k - 1):             # rows p..k-2 have one entry above the diagonal: rotate it away
        a = L[i, i]
        b = L[i, i + 1]
        if b != 0.0:
            r = math.sqrt(a * a + b * b)
            cs = a / r
            sn = b / r
            for row in range(i, k - 1):
                li = L[row, i]
                lj = L[row, i + 1]
                L[row, i] = cs * li + sn * lj
                L[row, i + 1] = cs * lj - sn * li
        L[i, i + 1] = 0.0


def _chol_solve_py(L, k, rhs, z):  # pragma: no cover - compiled by numba
    """``z[:k]`` with ``L L' z = rhs[:k]``."""
    for a in range(k):
        v = rhs[a]
        for p in range(a):
            v -= L[a, p] * z[p]
        z[a] = v / L[a, a]
    for a in range(k - 1, -1, -1):
        v = z[a]
        for p in range(a + 1, k):
            v -= L[p, a] * z[p]
        z[a] = v / L[a, a]


# ----------------------------------------------------------------------------- gradients and free-set solves
def _neg_gradient_py(G, b, x, w, exact, R, c, r, ridge, l1):  # pragma: no cover - compiled by numba
    """``w = b - G x``; in exact mode from the least-squares data: ``R'(c - R x) - ridge x - l1``."""
    N = G.shape[0]
    if exact:
        m = R.shape[0]
        for a in range(m):
            r[a] = c[a]
        for j in range(N):
            xj = x[j]
            if xj != 0.0:
                for a in range(m):
                    r[a] -= R[a, j] * xj
        for i in range(N):
            w[i] = -ridge * x[i] - l1
        for a in range(m):
            ra = r[a]
            if ra != 0.0:
                for i in range(N):
                    w[i] += R[a, i] * ra
    else:
        for i in range(N):
            w[i] = b[i]
        for j in range(N):
            xj = x[j]
            if xj != 0.0:
                for i in range(N):
                    w[i] -= G[j, i] * xj


def _free_solve_py(G, L, idx, k, b, ub, s, x, z, rhs, xp, iu, w, exact, R, c, r,
                   ridge, l1):  # pragma: no cover - compiled by numba
    """The minimiser ``z[:k]`` on the free set ``idx[:k]`` with the other variables at their bounds."""
    N = G.shape[0]
    nu = 0
    for j in range(N):                     # the variables at their upper bound
        if s[j] == AT_UPPER:
            iu[nu] = j
            nu += 1
    for a in range(k):
        i = idx[a]
        v = b[i]
        for u in range(nu):
            j = iu[u]
            v -= G[i, j] * x[j]
        rhs[a] = v
    _chol_solve(L, k, rhs, z)
    if exact:                              # one step of iterative refinement with the exact gradient
        for i in range(N):
            xp[i] = x[i]
        for a in range(k):
            xp[idx[a]] = z[a]
        _neg_gradient(G, b, xp, w, True, R, c, r, ridge, l1)
        for a in range(k):
            rhs[a] = w[idx[a]]
        _chol_solve(L, k, rhs, xp)
        for a in range(k):
            z[a] += xp[a]


# ----------------------------------------------------------------------------- the kernel
def _descend_py(G, L, idx, k, b, ub, s, x, z, rhs, xp, iu, w, ratio, exact, R, c, r, ridge, l1, solves,
                t):  # pragma: no cover - compiled by numba
    """Move the feasible ``x`` to the minimiser on its free set, stepping back to the box boundary on the way.

    Every step solves on the free set; when the solution leaves the box, ``x`` moves toward it until
    the first free variable reaches its bound, which is then fixed there.  Returns the new free count.
    """
    while k > 0:
        _free_solve(G, L, idx, k, b, ub, s, x, z, rhs, xp, iu, w, exact, R, c, r, ridge, l1)
        solves[t] += 1
        alpha = 2.0
        for a in range(k):
            i = idx[a]
            ra = 2.0
            if z[a] <= 0.0:
                d = x[i] - z[a]
                ra = x[i] / d if d > 0.0 else 0.0
            elif z[a] >= ub[i]:
                d = z[a] - x[i]
                ra = (ub[i] - x[i]) / d if d > 0.0 else 0.0
            ratio[a] = ra
            if ra < alpha:
                alpha = ra
        if alpha > 1.0:                         # inside the box: take it
            for a in range(k):
                x[idx[a]] = z[a]
            break
        if alpha < 0.0:
            alpha = 0.0
        for a in range(k - 1, -1, -1):
            i = idx[a]
            v = x[i] + alpha * (z[a] - x[i])
            if ratio[a] <= alpha or v <= 0.0 or v >= ub[i]:     # reached its bound: fix it there
                up = z[a] >= ub[i] if ratio[a] <= alpha else v >= ub[i]
                s[i] = AT_UPPER if up else AT_ZERO
                x[i] = ub[i] if up else 0.0
                _chol_delete(L, idx, k, a)
                k -= 1
            else:
                x[i] = v
    return k


def _polish_py(G, L, idx, k, b, ub, s, x, w, rhs, dz, R, c, r, ridge, l1,
               thr):  # pragma: no cover - compiled by numba
    """One step of iterative refinement of a Gram-form optimum ``x`` with the exact gradient, and the
    exact KKT check; False (``x`` still feasible) when the exact numbers call for more steps."""
    N = G.shape[0]
    _neg_gradient(G, b, x, w, True, R, c, r, ridge, l1)
    if k > 0:
        for a in range(k):
            rhs[a] = w[idx[a]]
        _chol_solve(L, k, rhs, dz)
        for a in range(k):
            v = x[idx[a]] + dz[a]
            if not (v > 0.0 and v < ub[idx[a]]):
                return False
        for a in range(k):
            i = idx[a]
            x[i] += dz[a]
            d = dz[a]
            for j in range(N):
                w[j] -= G[i, j] * d
    for i in range(N):
        if (s[i] == AT_ZERO and w[i] > thr) or (s[i] == AT_UPPER and -w[i] > thr):
            return False
    return True


def _box_frames_py(G, B, ub, R, C, ridge, l1, tol, max_iter, exact, state, probe,
                   max_solves):  # pragma: no cover - numba
    T, N = B.shape
    m = R.shape[0]
    X = np.zeros((T, N))
    S = np.zeros((T, N), dtype=np.int8)
    stuck = np.zeros(T, dtype=np.bool_)
    solves = np.zeros(T, dtype=np.int64)
    L = np.zeros((N, N))
    idx = np.zeros(N, dtype=np.int64)
    s = state.copy()
    x = np.zeros(N)
    z = np.zeros(N)
    w = np.zeros(N)
    rhs = np.zeros(N)
    xp = np.zeros(N)
    iu = np.zeros(N, dtype=np.int64)
    r = np.zeros(m)
    ratio = np.zeros(N)
    banned = np.zeros(N, dtype=np.bool_)
    k = 0
    for i in range(N):                     # the starting point: feasible, with the starting sets
        if s[i] == AT_UPPER:
            x[i] = ub[i]
        elif s[i] == FREE:
            if _chol_append(G, L, idx, k, i):
                k += 1
            else:
                s[i] = AT_ZERO
    for t in range(T):
        b = B[t]
        c = C[t]
        bscale = 1e-300
        for i in range(N):
            if abs(b[i]) > bscale:
                bscale = abs(b[i])
        thr = tol * bscale
        for i in range(N):
            banned[i] = False
        # warm start: the previous frame's point (feasible here too) and sets; in Gram form first
        ex = False
        k = _descend(G, L, idx, k, b, ub, s, x, z, rhs, xp, iu, w, ratio, ex, R, c, r, ridge, l1, solves,
                     t)
        it = 0
        while True:
            _neg_gradient(G, b, x, w, ex, R, c, r, ridge, l1)
            jbest = -1
            best = thr
            skipped = False
            for i in range(N):
                v = w[i] if s[i] == AT_ZERO else (-w[i] if s[i] == AT_UPPER else 0.0)
                if v > best:
                    if banned[i]:
                        skipped = True
                    else:
                        best = v
                        jbest = i
            if jbest < 0:
                if skipped:                 # only violators that made no progress (rounding): not optimal
                    stuck[t] = True
                    break
                if ex or not exact or _polish(G, L, idx, k, b, ub, s, x, w, rhs, xp, R, c, r, ridge, l1, thr):
                    break
                # the exact numbers disagree with the Gram form: finish this frame in exact mode
                ex = True
                k = _descend(G, L, idx, k, b, ub, s, x, z, rhs, xp, iu, w, ratio, ex, R, c, r, ridge, l1,
                             solves, t)
                continue
            if it >= max_iter:
                stuck[t] = True
                break
            it += 1
            if not _chol_append(G, L, idx, k, jbest):      # dependent on the free keys
                banned[jbest] = True
                continue
            k += 1
            s[jbest] = FREE                                 # x[jbest] stays at its bound: feasible
            k = _descend(G, L, idx, k, b, ub, s, x, z, rhs, xp, iu, w, ratio, ex, R, c, r, ridge, l1,
                         solves, t)
            # an entering variable that left again at once made no progress: skip it until x changes
            if s[jbest] == FREE:
                for i in range(N):
                    banned[i] = False
            else:
                banned[jbest] = True
        for i in range(N):
            X[t, i] = x[i]
            S[t, i] = s[i]
        if t + 1 == probe and t > 0:        # the probe: too many solves per frame (the first is cold)?
            total = 0
            for q in range(1, probe):
                total += solves[q]
            if total > max_solves * (probe - 1):
                return X, S, stuck, solves, probe
    return X, S, stuck, solves, T


if numba is not None:  # pragma: no branch
    # the helpers are inlined into the kernel: a call passing a dozen arrays costs more than a
    # small frame's arithmetic
    _jit = numba.njit(cache=True, nogil=True, error_model="numpy")
    _inl = numba.njit(cache=True, nogil=True, error_model="numpy", inline="always")
    _chol_append = _inl(_chol_append_py)
    _chol_delete = _inl(_chol_delete_py)
    _chol_solve = _inl(_chol_solve_py)
    _neg_gradient = _inl(_neg_gradient_py)
    _free_solve = _inl(_free_solve_py)
    _descend = _inl(_descend_py)
    _polish = _inl(_polish_py)
    _box_frames = _jit(_box_frames_py)


def box_frames(G: np.ndarray, B: np.ndarray, ub: np.ndarray | None = None, *, exact=None, tol: float = 1e-10,
               max_iter: int = 500, start: np.ndarray | None = None, probe: int = 0,
               max_solves: float = np.inf) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, int]:
    """``min 1/2 x'Gx - b_t'x, 0 <= x <= ub`` for every row ``b_t`` of ``B``, frame after frame (compiled).

    Parameters
    ----------
    G : (N, N) float, symmetric positive definite
    B : (T, N) float
    ub : (N,) float, optional
        Upper bounds (``inf`` for none; ``None``: none at all).
    exact : (R, C, ridge, l1), optional
        Least-squares data with ``G = R'R + ridge I`` and ``B = C R - l1`` (``R`` (m, N), ``C``
        (T, m)): gradients and one refinement step per solve are computed from them (for
        ill-conditioned ``G``).
    tol : float
        Relative KKT tolerance (of ``max |b_t|``).
    max_iter : int
        Variables entered per frame before giving up.
    start : (N,) int8, optional
        Sets of the first frame (0 at zero, 1 free, 2 at the upper bound); default all at zero.
        Every later frame starts from the sets its predecessor ended with.
    probe, max_solves : int, float
        Stop after the first ``probe`` frames (0: no probe) when frames 1 to ``probe - 1`` needed
        more than ``max_solves`` free-set solves per frame on average (weights whose sets change at
        every frame, faster by block pivoting).

    Returns
    -------
    X : (T, N) float
        Inside ``[0, ub]`` exactly.
    sets : (T, N) int8
        Final sets (0 at zero, 1 free, 2 at the upper bound).
    stuck : (T,) bool
        Frames stopped by ``max_iter``, or left with violators that could not enter (rounding on
        degenerate sets): their point is feasible, not optimal.
    solves : (T,) int
        Free-set solves of every frame (one when its sets equal its predecessor's).
    done : int
        Frames solved: ``T``, or ``probe`` when the probe stopped the kernel.
    """
    if numba is None:
        optional_import("numba", "the compiled solver kernel")
    G = np.ascontiguousarray(G, dtype=np.float64)
    B = np.ascontiguousarray(B, dtype=np.float64)
    N = G.shape[0]
    ub = np.full(N, np.inf) if ub is None else np.ascontiguousarray(ub, dtype=np.float64)
    state = np.zeros(N, dtype=np.int8) if start is None else np.ascontiguousarray(start, dtype=np.int8)
    if exact is None:
        R, C, ridge, l1, on = np.zeros((1, N)), np.zeros((len(B), 1)), 0.0, 0.0, False
    else:
        R, C, ridge, l1 = exact
        R = np.ascontiguousarray(R, dtype=np.float64)
        C = np.ascontiguousarray(C, dtype=np.float64)
        on = True
    args = (G, B, ub, R, C, float(ridge), float(l1), float(tol), int(max_iter), on, state, int(probe),
            float(max_solves))
    if _box_frames.signatures:                        # compiled (or loaded from numba's cache) in this process
        return _box_frames(*args)
    notice = threading.Timer(COMPILE_NOTICE_AFTER, _compile_notice)
    notice.daemon = True
    if sys.stderr is not None and sys.stderr.isatty():    # a person waiting at a terminal, not a log
        notice.start()
    try:
        return _box_frames(*args)
    finally:
        notice.cancel()


#: How long compiling the kernel takes, for the notices (25 s measured on 2 cores, up to a minute on slower ones).
COMPILE_SECONDS = "about 30 s"
_announced = False


def _compile_notice() -> None:
    global _announced
    if _announced:                                    # compile_kernels(verbose=True) said it already
        return
    _announced = True
    sys.stderr.write(f"faceretarget: compiling the NNLS solver kernel with numba (first use only: {COMPILE_SECONDS}, "
                     "cached afterwards)\n")
    sys.stderr.flush()


def compile_kernels(verbose: bool = False) -> float:
    """Compile the kernel now (or load it from numba's on-disk cache) and return the seconds it took.

    The first solve on a machine otherwise waits for it (:data:`COMPILE_SECONDS`); ``make demo`` calls this
    once, with ``verbose``, so the wait is announced once and its length printed after.  Without numba,
    nothing happens (0 s).
    """
    global _announced
    if numba is None:
        return 0.0
    t0 = time.perf_counter()
    fresh = verbose and not _box_frames.signatures
    if fresh:
        print(f"compiling the NNLS solver kernel with numba (once: {COMPILE_SECONDS}, cached afterwards)", flush=True)
        _announced = True
    G = np.eye(2)
    box_frames(G, np.ones((2, 2)), np.ones(2))
    box_frames(G, np.ones((2, 2)), None, exact=(np.eye(2), np.ones((2, 2)), 0.0, 0.0))
    seconds = time.perf_counter() - t0
    if fresh:
        print(f"compiled in {seconds:.0f} s (or loaded from numba's cache); later runs start at once", flush=True)
    return seconds
