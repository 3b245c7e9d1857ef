"""Non-negative keyshape weights for a whole take (Chuang Eq. 3.1/3.2), and their temporal filtering.

Every source frame ``f_t`` (``D`` feature coordinates) is decomposed into non-negative weights of
the ``N`` source keyshapes ``K`` (one column per keyshape displacement)::

    min_w  1/2 ||K w_t - f_t||^2        subject to  w_t >= 0                       (Eq. 3.1/3.2)

Frames are independent, so the take is solved as a batch of box-constrained quadratic programs in
``N`` dimensions sharing one Gram matrix ``G = K'K`` (right-hand sides ``b_t = K'f_t``), with exact
active-set methods vectorised over frames.  Both repeatedly solve, for every unfinished frame, the
equality-constrained problem on its free set ``F`` (the other weights fixed at 0 or at their upper
bound), in the cheaper of two equivalent forms: ``G_FF x_F = b_F - G_FU u_U`` when ``|F| <= N/2``,
otherwise through ``G^-1`` on the fixed set (``N - |F|`` unknowns; only while
``cond(G) < 1e10``).  Frames are bucketed by form and set size and every bucket is one stacked
LAPACK solve, so one step over the whole take is a few dozen LAPACK calls.

* **Block principal pivoting** (Kim & Park 2011, "Fast nonnegative matrix factorization: an
  active-set-like method and comparisons"; Judice & Pires 1994 for upper bounds), the default:
  every frame starts from the signs of its unconstrained solution and exchanges all variables that
  break the KKT conditions at once (free but outside the box, at a bound with a gradient pointing
  inside); a frame whose count of violations has not fallen for three iterations exchanges only
  its last violator (Murty's rule).  Most frames finish in three to five iterations.
* **Lawson-Hanson** (BVLS with upper bounds), for strongly correlated keyshapes with sparse
  solutions (keys chosen among the frames of a take, dependent key sets), where full exchanges
  oscillate: chosen when, on a probe of 32 frames, pivoting needs more than 8 solves per frame,
  or more than 5 and more than Lawson-Hanson does; also used to finish any frame pivoting has not
  settled in 20 iterations.  Each frame keeps a
  feasible point and frees one variable per step, so the objective falls at every step.  Frames
  run in chunks of 8 consecutive frames, each starting from the free set of the previous one
  (consecutive frames of a take share most of it).

With ``numba`` installed (``make fast``) a compiled kernel
(:mod:`._nnls_numba`) solves the frames one after another instead, upper bounds included: bounded
Lawson-Hanson (BVLS), each frame starting from the previous frame's point and sets, with the
Cholesky factor of ``G`` on the free set updated (not recomputed) when a variable enters or
leaves.  Consecutive frames of a take share most of their sets, so a frame typically costs one or
two solves on its free set (measured: 1.1 to 4 on every real P1 problem, bounded or not) and well
under a microsecond to a few microseconds, where ``scipy.optimize.nnls`` / ``lsq_linear`` pay tens
of microseconds to milliseconds of Python per frame.  A probe on the first 64 frames hands takes
whose sets change at every frame (dense weights, more than 10 solves per frame) to block pivoting,
which exchanges many variables per step.

Keys chosen among a take's frames can be nearly dependent (hull and k-means selections pick
near-duplicate frames: ``cond(K'K)`` up to 2e14).  When ``cond(G) > 1e10`` the keys are projected
once, ``K = QR`` and ``c_t = Q'f_t`` (``||K w - f||^2 = ||R w - c||^2 + const``, so the per-frame
work does not depend on ``D``), and every frame's optimum gets one step of iterative refinement
with the gradient computed from ``(R, c_t)`` itself (corrected semi-normal equations), so forming
``K'K`` costs no accuracy; the compiled kernel decides the sets at ``1e-4`` of the tolerance,
checks every frame against the exact KKT conditions and finishes a frame that fails in exact mode
(every solve refined, every gradient exact).  The result is exact: it agrees with
:func:`scipy.optimize.nnls` per frame to rounding where the solution is unique, and where it is not
(nearly dependent keys) its objective agrees with scipy's or is lower (``bench/retarget.py
--speed-only``, ``bench/nnls.py``).

A take's products (frames x features x keys) are computed in row blocks small enough for BLAS to
run them on one thread: on a busy machine waking BLAS threads costs milliseconds per call, more than
such a product.

Beyond the thesis, in the spirit of NVIDIA Audio2Face's blendshape solver, the objective can have::

    sum_t [ 1/2 ||K w_t - f_t||^2 + l2/2 ||w_t||^2 + l1 sum_i w_ti ]
          + smooth/2 sum_t ||w_t - w_{t-1}||^2         subject to  0 <= w_t <= upper

* ``upper``: box constraints (e.g. 1, a rig's slider range);
* ``l2``: ridge, ``G + l2 I``; it spreads weight over similar keyshapes;
* ``l1``: sparsity, ``b_t - l1`` (on ``w >= 0`` the L1 norm is linear); it switches weak keys off;
* ``smooth``: temporal coupling of consecutive frames.  The take becomes one QP whose Hessian
  ``M = blockdiag(G_t) + smooth (L (x) I)`` (``L``: path Laplacian over frames) is
  block-tridiagonal, i.e. banded with bandwidth ``N`` in frame-major order.  It is solved by a
  primal-dual active-set iteration on the whole take (block principal pivoting again: solve on
  the free variables with one banded Cholesky of ``M`` restricted to them, LAPACK ``pbtrf``,
  linear in the number of frames; exchange all KKT violators), started from an approximate
  solution: ADMM with ``M`` diagonalised by the eigenvectors of ``G`` and the DCT over frames
  when all frames share one Gram matrix, else the per-frame solution.  Should the active-set
  iteration stall it hands over to Bertsekas' projected Newton method (1982, Armijo search along
  the projection arc), which converges from anywhere.  Either way the final step solves the
  optimality conditions exactly;
* ``mask``: missing markers.  A frame is solved on the rows that exist; frames are grouped by
  mask pattern, each pattern with its own Gram matrix.

A keyshape that moves none of a frame's observed rows gets weight 0 in that frame (any weight
fits equally).  When the observed rows cannot tell the remaining keyshapes apart (fewer rows than
keys, duplicate keys) the weights are not unique; a tiny ridge (``1e-13`` of ``K'K``'s largest
eigenvalue) then picks one solution.  A frame with no observed row gets zero weights (with
``smooth``: whatever its neighbours imply).

:func:`temporal_filter` smooths weight curves afterwards with an adjustable level and
:func:`extremes_removed` reports how much of the curves' extremes that costs.
"""

from __future__ import annotations

import warnings
from functools import partial

import numpy as np
from scipy.fft import dct, idct
from scipy.linalg import cho_solve_banded, cholesky_banded

from ..errors import FitWarning, InvalidDataError
from ..optional import optional_import

__all__ = ["solve_nnls", "temporal_filter", "extremes_removed", "filter_cutoff_hz", "compile_kernels"]

_RIDGE = 1e-13
_INVERSE_COND = 1e10
_EXACT_COND = 1e10
_EXACT_TOL = 1e-4
_SMALL_BATCH = 256
# free-set solves per frame (on the first 64 frames of a take) up to which the compiled kernel goes
# on; above, the vectorised NumPy methods (block pivoting) solve the take.  Measured on 2,028-frame
# synthetic takes with dense, often-changing weights (bench/nnls.py "keyshapes"): 14 solves per
# frame with 40 keys, kernel 40 ms vs pivoting 37 ms; 30 with 83 keys, 450 vs 310 ms.  Every real
# P1 problem (keys chosen among a take's frames, also with the range -1..2) needs 1.1 to 4.
_COMPILED_MAX_SOLVES = 10
_COMPILED_PROBE = 64
# OpenBLAS runs a product on one thread when m*n*k <= 65536 * 4: a take's tall, skinny products
# (frames x features x keys) are computed in row blocks that small.  Waking BLAS threads costs more
# than such a product, and on a busy machine (other processes on the cores) milliseconds per call.
_ONE_THREAD_MNK = 262144


def _mm(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """``A @ B`` for a tall ``A`` (n, m) and a small ``B`` (m, k), in row blocks BLAS runs on one thread.

    Returns
    -------
    (n, k) float
    """
    n, m = A.shape
    k = B.shape[1]
    rows = _ONE_THREAD_MNK // max(m * k, 1)
    if n <= rows or rows < 8:
        return A @ B
    out = np.empty((n, k), dtype=np.result_type(A, B))
    for i in range(0, n, rows):
        np.matmul(A[i:i + rows], B, out=out[i:i + rows])
    return out


# ----------------------------------------------------------------------------- batched dense solves
def _solve_sets(P: np.ndarray, inverse: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The form each row of :func:`_solve_fixed` is solved in, and the set it is solved on.

    Parameters
    ----------
    P : (n, N) bool
        Free variables.
    inverse : bool
        Whether ``G^-1`` is available (otherwise every row uses the free-set form).

    Returns
    -------
    free_form : (n,) bool
        Row solved on its free set (else through ``G^-1`` on its fixed set).
    ks : (n,) int
        Size of the set each row is solved on.
    cols : (sum(ks),) int
        The rows' sets one after another, each ascending.
    start : (n,) int
        Where each row's set starts in ``cols``.
    """
    n, N = P.shape
    k = P.sum(axis=1)
    free_form = 2 * k <= N if inverse else np.ones(n, dtype=bool)
    S = P ^ ~free_form[:, None]                                 # the set each row is solved on
    ks = np.where(free_form, k, N - k)
    cols = np.nonzero(S)[1]                                     # each row's set, ascending
    start = np.concatenate([[0], np.cumsum(ks)[:-1]])
    return free_form, ks, cols, start


def _buckets(free_form: np.ndarray, ks: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Group the rows of :func:`_solve_fixed` into one stacked solve per form and (padded) size.

    Parameters
    ----------
    free_form : (n,) bool
    ks : (n,) int
        Set sizes (see :func:`_solve_sets`).

    Returns
    -------
    kp : (n,) int
        Size each row's system is padded to.
    perm : (n,) int
        Rows ordered by bucket.
    bounds : (b - 1,) int
        Where each bucket after the first starts in ``perm``.
    """
    n = len(ks)
    # one LAPACK call per form and size; a small batch (where the call overhead dominates) is padded
    # with identity rows to one call per form
    if n <= _SMALL_BATCH:
        kp = np.zeros_like(ks)
        for form in (True, False):
            sel = free_form == form
            if sel.any():
                kp[sel] = ks[sel].max()
    else:
        kp = ks
    key = 2 * kp + free_form
    perm = np.argsort(key, kind="stable")
    bounds = np.flatnonzero(np.diff(key[perm])) + 1
    return kp, perm, bounds


def _fixed_rhs(G: np.ndarray, H: np.ndarray | None, C: np.ndarray, P: np.ndarray, A0: np.ndarray | None,
               free_form: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray | None, np.ndarray | None]:
    """Starting point and right-hand sides of the systems :func:`_solve_fixed` solves.

    Parameters
    ----------
    G, H : (N, N) float
    C : (n, N) float
    P : (n, N) bool
    A0 : (n, N) float or None
    free_form : (n,) bool

    Returns
    -------
    X : (n, N) float
        The fixed variables at their values, the free ones at 0.
    R : (n, N) float
        Right-hand sides: ``c - G x`` (free-set form) or ``a - H c`` (fixed-set form).
    Z : (n, N) float or None
        ``H c`` (``None`` when every row uses the free-set form).
    lam : (n, N) float or None
        Zeros, for the multipliers of the fixed-set form rows (``None`` as ``Z``).
    """
    n, N = P.shape
    if A0 is None:
        X = np.zeros((n, N))
        R = C.copy()
    else:
        X = np.where(P, 0.0, A0)
        R = C - _mm(X, G)
    Z = lam = None
    if not free_form.all():
        Z = _mm(C, H)
        a = ~free_form
        R[a] = -Z[a] if A0 is None else (A0 - Z)[a]
        lam = np.zeros((n, N))
    return X, R, Z, lam


def _stacked_solves(G: np.ndarray, H: np.ndarray | None, R: np.ndarray, X: np.ndarray, lam: np.ndarray | None,
                    free_form: np.ndarray, ks: np.ndarray, cols: np.ndarray, start: np.ndarray) -> None:
    """Solve every row's system of :func:`_solve_fixed`, one stacked LAPACK call per bucket.

    Parameters
    ----------
    G, H : (N, N) float
    R : (n, N) float
        Right-hand sides (see :func:`_fixed_rhs`).
    X : (n, N) float
        Receives the solutions on the free sets of the free-set form rows (in place).
    lam : (n, N) float or None
        Receives the multipliers on the fixed sets of the fixed-set form rows (in place).
    free_form, ks, cols, start
        The rows' forms and sets (see :func:`_solve_sets`).
    """
    N = G.shape[0]
    kp, perm, bounds = _buckets(free_form, ks)
    Gf, Rf, Xf = G.ravel(), R.ravel(), X.reshape(-1)
    Hf = None if H is None else H.ravel()
    cols = np.append(cols, 0)                                   # padding reads a harmless entry
    for rows in np.split(perm, bounds):
        kk, ff = int(kp[rows[0]]), bool(free_form[rows[0]])
        if kk == 0:
            continue
        j = np.arange(kk)
        real = j < ks[rows][:, None]                            # (m, kk): not padding
        idx = np.where(real, cols[np.minimum(start[rows][:, None] + j, len(cols) - 1)], 0)
        A = (Gf if ff else Hf)[idx[:, :, None] * N + idx[:, None, :]]
        flat = rows[:, None] * N + idx
        rhs = Rf[flat]
        if not real.all():
            pair = real[:, :, None] & real[:, None, :]
            A = np.where(pair, A, np.eye(kk))
            rhs = np.where(real, rhs, 0.0)
        x = np.linalg.solve(A, rhs[..., None])[..., 0]
        if not real.all():
            flat, x = flat[real], x[real]
        if ff:
            Xf[flat] = x
        else:
            lam.reshape(-1)[flat] = x


def _solve_fixed(G: np.ndarray, H: np.ndarray | None, C: np.ndarray, P: np.ndarray,
                 A0: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Minimise ``1/2 x'Gx - c_t'x`` over the free variables ``P[t]`` with the others fixed at ``A0[t]``.

    Each row is solved in the cheaper of two equivalent forms: on the free set,
    ``G_FF x_F = c_F - G_FA a_A``, or through ``H = G^-1`` on the fixed set,
    ``x = H (c + lambda)`` with ``H_AA lambda_A = a_A - (H c)_A`` (``lambda``: the multipliers of the
    fixed variables), so no system is larger than ``N / 2``.  Rows are bucketed by form and size and
    every bucket is one stacked LAPACK call.

    Parameters
    ----------
    G, H : (N, N) float
        Symmetric positive definite matrix and its inverse (``None``: free-set form only).
    C : (n, N) float
    P : (n, N) bool
        Free variables.
    A0 : (n, N) float, optional
        Values of the fixed variables (ignored where ``P``); zero when omitted.

    Returns
    -------
    X : (n, N) float
    Y : (n, N) float
        Gradient ``G x_t - c_t`` (zero on the free variables up to rounding).
    """
    free_form, ks, cols, start = _solve_sets(P, H is not None)
    X, R, Z, lam = _fixed_rhs(G, H, C, P, A0, free_form)
    _stacked_solves(G, H, R, X, lam, free_form, ks, cols, start)
    if Z is None:
        return X, _mm(X, G) - C
    ai = np.flatnonzero(~free_form)
    X[ai] = np.where(P[ai], Z[ai] + _mm(lam[ai], H), X[ai])
    fi = np.flatnonzero(free_form)
    lam[fi] = _mm(X[fi], G) - C[fi]                                 # gradient; on fixed-set rows it is lambda
    return X, lam


def _bpp_start(G: np.ndarray, H: np.ndarray | None, B: np.ndarray,
               ub: np.ndarray | None) -> tuple[np.ndarray, np.ndarray, np.ndarray | None, np.ndarray | None]:
    """Initial sets of :func:`_bpp`: the signs of the unconstrained solutions (and where they exceed ``ub``).

    Parameters
    ----------
    G, H : (N, N) float
        Matrix and its inverse (``None``: solve with ``G``).
    B : (n, N) float
    ub : (N,) float or None

    Returns
    -------
    P, U : (n, N) bool
        Free variables and variables at their upper bound.
    fin, ubf : (N,) bool and (N,) float, or None without ``ub``
        Which bounds are finite, and the bounds with 0 for the infinite ones.
    """
    fin = None if ub is None else np.isfinite(ub)
    ubf = None if ub is None else np.where(fin, ub, 0.0)
    X0 = _mm(B, H) if H is not None else np.linalg.solve(G, B.T).T
    P = X0 > 0
    U = np.zeros_like(P)
    if ub is not None:
        U = fin & (X0 >= ub)
        P &= ~U
    return P, U, fin, ubf


def _bpp_violations(Pt: np.ndarray, Ut: np.ndarray, Xt: np.ndarray, Yt: np.ndarray, bscale: np.ndarray,
                    tol: float, fin: np.ndarray | None,
                    ubf: np.ndarray | None) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The variables of :func:`_bpp`'s rows that break the KKT conditions, by kind.

    Parameters
    ----------
    Pt, Ut : (m, N) bool
        Free variables and variables at their upper bound.
    Xt, Yt : (m, N) float
        Solutions on the free sets and their gradients.
    bscale : (m,) float
        Scale of each row's right-hand side (gradient tolerance ``tol * bscale``).
    tol : float
    fin, ubf : (N,) bool and (N,) float, or None without upper bounds

    Returns
    -------
    v_neg, v_in, v_over, v_out : (m, N) bool
        Free but negative; at 0 with a gradient pointing inside; free but above the bound; at the
        bound with a gradient pointing inside.
    """
    xs = tol * np.maximum(np.abs(Xt).max(axis=1), 1.0)[:, None]
    ys = tol * bscale[:, None]
    v_neg = Pt & (Xt < -xs)
    v_in = ~Pt & ~Ut & (Yt < -ys)
    if fin is not None:
        v_over = Pt & fin & (Xt > ubf + xs)
        v_out = Ut & (Yt > ys)
    else:
        v_over = v_out = np.zeros_like(Pt)
    return v_neg, v_in, v_over, v_out


def _exchange_rule(V: np.ndarray, nv: np.ndarray, todo: np.ndarray, ninf: np.ndarray, backup: np.ndarray,
                   viol: tuple[np.ndarray, ...]) -> tuple[np.ndarray, ...]:
    """The violators :func:`_bpp` exchanges: all of them, or only the last one (Murty's rule) in rows
    whose count of violators has not fallen for three iterations.

    Parameters
    ----------
    V : (m, N) bool
        All violators of the unfinished rows ``todo``.
    nv : (m,) int
        Their counts.
    todo : (m,) int
    ninf, backup : (n,) int
        Every row's smallest count so far and remaining tries before Murty's rule (updated in place).
    viol : four (m, N) bool
        The violators by kind (see :func:`_bpp_violations`).

    Returns
    -------
    four (m, N) bool
        The violators to exchange, by kind.
    """
    N = V.shape[1]
    better = nv < ninf[todo]
    ninf[todo[better]] = nv[better]
    backup[todo[better]] = 3
    use_backup = ~better & (backup[todo] <= 0)
    backup[todo[~better & ~use_backup]] -= 1
    if use_backup.any():                                        # Murty: only the last violator
        last = N - 1 - np.argmax(V[:, ::-1], axis=1)
        single = np.zeros_like(V)
        single[np.arange(len(V)), last] = True
        sel = np.where(use_backup[:, None], single, True)
        viol = tuple(v & sel for v in viol)
    return viol


def _bpp(G: np.ndarray, H: np.ndarray | None, B: np.ndarray, ub: np.ndarray | None, tol: float,
         max_iter: int, stats: dict | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Block principal pivoting for ``min 1/2 x'Gx - b_t'x, 0 <= x <= ub`` for every row ``b_t`` of ``B``.

    Starts from the signs of the unconstrained solutions; exchanges every KKT violator at once, or
    only the last one (Murty's rule) when a row's count of violators has not fallen for three
    iterations.

    Returns
    -------
    X : (n, N) float
    free : (n, N) bool
        Final free sets.
    unconverged : (k,) int
        Rows still violating the KKT conditions after ``max_iter`` iterations.
    """
    n, N = B.shape
    X = np.zeros((n, N))
    P, U, fin, ubf = _bpp_start(G, H, B, ub)
    bscale = np.maximum(np.abs(B).max(axis=1), 1e-300)
    ninf = np.full(n, N + 1)
    backup = np.full(n, 3)
    todo = np.arange(n)
    Pfin = np.zeros_like(P)
    for it in range(max_iter):
        Pt, Ut = P[todo], U[todo]
        A0 = Ut * ubf if ub is not None else None
        # the fixed-set form is less stable: rows still cycling after 8 iterations use the free-set form
        Xt, Yt = _solve_fixed(G, H if it < 8 else None, B[todo], Pt, A0)
        if stats is not None:
            stats["solves"] = stats.get("solves", 0) + len(todo)
        viol = _bpp_violations(Pt, Ut, Xt, Yt, bscale[todo], tol, fin, ubf)
        V = viol[0] | viol[1] | viol[2] | viol[3]
        nv = V.sum(axis=1)
        done = nv == 0
        rows = todo[done]
        X[rows], Pfin[rows] = Xt[done], Pt[done]
        keep = ~done
        todo = todo[keep]
        if todo.size == 0:
            break
        V, nv = V[keep], nv[keep]
        v_neg, v_in, v_over, v_out = _exchange_rule(V, nv, todo, ninf, backup, tuple(v[keep] for v in viol))
        Pn, Un = P[todo], U[todo]
        P[todo] = (Pn & ~v_neg & ~v_over) | v_in | v_out
        U[todo] = (Un & ~v_out) | v_over
    return X, Pfin, todo


def _lh_step(Z: np.ndarray, Y: np.ndarray, Xa: np.ndarray, Fa: np.ndarray, Ua: np.ndarray,
             ub: np.ndarray | None, fin: np.ndarray, ubf: np.ndarray, bscale: np.ndarray,
             tol: float) -> np.ndarray:
    """One Lawson-Hanson step of :func:`_lh`'s active rows, given their solutions on the free sets.

    A row whose solution leaves the box steps back to the box boundary (the variables it hits are
    fixed there); a feasible row moves to its solution and frees the variable that violates the KKT
    conditions most, if any.

    Parameters
    ----------
    Z, Y : (m, N) float
        Solutions on the free sets and their gradients.
    Xa : (m, N) float
        Current feasible points (updated in place).
    Fa, Ua : (m, N) bool
        Free variables and variables at their upper bound (updated in place).
    ub : (N,) float or None
    fin, ubf : (N,) bool, (N,) float
        Which bounds are finite, and the bounds with 0 for the infinite ones.
    bscale : (m,) float
        Scale of each row's right-hand side (gradient tolerance ``tol * bscale``).
    tol : float

    Returns
    -------
    (k,) int
        Rows that are optimal (no violator left).
    """
    lo = Fa & (Z < 0.0)
    hi = (Fa & fin & (Z > ubf)) if ub is not None else np.zeros_like(lo)
    bad = (lo | hi).any(axis=1)
    b = np.flatnonzero(bad)
    if b.size:                                                  # step back to the box boundary
        xb, zb, lb, hb = Xa[b], Z[b], lo[b], hi[b]
        with np.errstate(divide="ignore", invalid="ignore"):
            r = np.where(lb, xb / (xb - zb), np.where(hb, (ubf - xb) / (zb - xb), np.inf))
        r = np.maximum(r, 0.0)
        alpha = np.minimum(r.min(axis=1), 1.0)
        hit = (lb | hb) & (r <= alpha[:, None])
        up = hit & hb
        Xa[b] = np.where(hit, np.where(up, ubf, 0.0), xb + alpha[:, None] * (zb - xb))
        Fa[b] &= ~hit
        Ua[b] |= up
    g = np.flatnonzero(~bad)
    done = np.zeros(0, dtype=np.int64)
    if g.size:                                                  # optimal on the free set: KKT check
        yg, Fg, Ug = Y[g], Fa[g], Ua[g]
        s = tol * bscale[g][:, None]
        v = np.where(~Fg & ~Ug & (yg < -s), -yg, 0.0) + np.where(Ug & (yg > s), yg, 0.0)
        j = np.argmax(v, axis=1)
        more = v[np.arange(len(g)), j] > 0
        m = np.flatnonzero(more)
        Fg[m, j[m]] = True
        Ug[m, j[m]] = False
        Xa[g], Fa[g], Ua[g] = Z[g], Fg, Ug
        done = g[~more]
    return done


def _lh_retire(f: np.ndarray, done: np.ndarray, over: np.ndarray, Z: np.ndarray, Xa: np.ndarray,
               Fa: np.ndarray, Ua: np.ndarray, ubf: np.ndarray, W: np.ndarray, Wfree: np.ndarray,
               stuck: np.ndarray) -> np.ndarray:
    """Store the results of :func:`_lh`'s finished rows and set up their chunks' next rows.

    Parameters
    ----------
    f : (m,) int
        The active rows.
    done : (k,) int
        Optimal rows (indices into ``f``).
    over : (m,) bool
        Rows stopped by the step limit.
    Z : (m, N) float
        Solutions on the free sets (the optimal rows' results).
    Xa : (m, N) float
        Feasible points (the stopped rows' results; reset in place to the next row's start).
    Fa, Ua : (m, N) bool
        Free variables and variables at their upper bound.
    ubf : (N,) float
    W, Wfree, stuck : (n, N) float, (n, N) bool, (n,) bool
        Results of all rows (written in place).

    Returns
    -------
    (k',) int
        All finished rows (indices into ``f``).
    """
    if done.size:
        W[f[done]], Wfree[f[done]] = Z[done], Fa[done]
    if over.any():
        o = np.flatnonzero(over)
        W[f[o]], Wfree[f[o]], stuck[f[o]] = Xa[o], Fa[o], True
        done = np.concatenate([done, o])
    if done.size:
        Xa[done] = np.where(Ua[done], ubf, 0.0)                 # next row: same sets, feasible start
    return done


def _lh(G: np.ndarray, H: np.ndarray | None, B: np.ndarray, ub: np.ndarray | None, tol: float,
        max_steps: int, chunk: int = 1,
        stats: dict | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Lawson-Hanson's active-set method (BVLS with upper bounds), vectorised over rows.

    Every row keeps a feasible point; a step solves on the free set and either steps back to the
    boundary of the box (freeing no variable) or frees the variable that violates the KKT conditions
    most.  The objective falls at every step, so there is no cycling, whatever the conditioning.
    Rows are processed in chunks of ``chunk`` consecutive rows: a chunk's next row starts from the
    free set its previous row ended with (consecutive frames of a take usually share most of it).

    Returns
    -------
    X : (n, N) float
    free : (n, N) bool
    unconverged : (k,) int
        Rows stopped after ``max_steps`` steps (their point is feasible, not optimal).
    """
    n, N = B.shape
    W = np.zeros((n, N))
    Wfree = np.zeros((n, N), dtype=bool)
    stuck = np.zeros(n, dtype=bool)
    fin = np.zeros(N, dtype=bool) if ub is None else np.isfinite(ub)
    ubf = np.zeros(N) if ub is None else np.where(fin, ub, 0.0)
    starts = np.arange(0, n, chunk)
    ends = np.minimum(starts + chunk, n)
    C = len(starts)
    cur = starts.copy()
    X = np.zeros((C, N))
    Fm = np.zeros((C, N), dtype=bool)
    Um = np.zeros((C, N), dtype=bool)
    nst = np.zeros(C, dtype=np.int64)
    bs = np.maximum(np.abs(B).max(axis=1), 1e-300)
    act = np.arange(C)
    while act.size:
        f = cur[act]
        Fa, Ua, Xa = Fm[act], Um[act], X[act]
        Z, Y = _solve_fixed(G, H, B[f], Fa, Ua * ubf if ub is not None else None)
        if stats is not None:
            stats["solves"] = stats.get("solves", 0) + len(act)
        done = _lh_step(Z, Y, Xa, Fa, Ua, ub, fin, ubf, bs[f], tol)
        nst[act] += 1
        over = (nst[act] >= max_steps) & ~np.isin(np.arange(len(act)), done)
        done = _lh_retire(f, done, over, Z, Xa, Fa, Ua, ubf, W, Wfree, stuck)
        X[act], Fm[act], Um[act] = Xa, Fa, Ua
        if done.size:
            rows = act[done]
            cur[rows] += 1
            nst[rows] = 0
            act = act[cur[act] < ends[act]]
    return W, Wfree, np.flatnonzero(stuck)


def compile_kernels(verbose: bool = False) -> float:
    """Compile the numba NNLS kernel now, or load it from numba's on-disk cache; the seconds it took.

    The first whole-take solve on a machine otherwise waits about 15 s for the compiler (a terminal
    is told after 1.5 s); ``make demo`` runs this once with ``verbose`` (one line).  Without numba
    (the ``fast`` extra) nothing happens.
    """
    from . import _nnls_numba

    return _nnls_numba.compile_kernels(verbose)


def _use_compiled(backend: str) -> bool:
    """Whether the compiled kernel (:mod:`._nnls_numba`) may solve (``backend`` "auto" or "numba")."""
    if backend == "numpy":
        return False
    from . import _nnls_numba

    if backend == "numba" and not _nnls_numba.available():
        optional_import("numba", "solve_nnls(backend='numba')")
    return _nnls_numba.available()


def _compiled_box_qp(G: np.ndarray, B: np.ndarray, ub: np.ndarray | None, tol: float, max_iter: int,
                     refine: _LSData | None, inverse: bool,
                     probe: bool = True) -> tuple[np.ndarray, np.ndarray] | None:
    """:func:`_box_qp` by the compiled kernel, frame after frame, each warm-started from the previous.

    With ``probe`` (and more than ``2 _COMPILED_PROBE`` frames) the kernel stops after the first
    ``_COMPILED_PROBE`` frames when they needed more than ``_COMPILED_MAX_SOLVES`` free-set solves
    per frame (dense weights whose sets change at every frame are faster by block pivoting) and
    None is returned.  Frames stopped by ``max_iter`` are finished by the NumPy methods.
    """
    from ._nnls_numba import box_frames

    n = len(B)
    # with ill-conditioned keys (exact data given) the sets are decided at a tighter tolerance: a
    # gradient of tol |b| along a near-duplicate key's direction is still worth a visible share of
    # the objective (the kernel's gradients are exact enough for 1e-4 of it)
    X, _, st, _, done = box_frames(G, B, ub, exact=None if refine is None else refine.data,
                                   tol=tol if refine is None else tol * _EXACT_TOL,
                                   max_iter=max_iter, probe=_COMPILED_PROBE if probe and n > 2 * _COMPILED_PROBE
                                   else 0, max_solves=_COMPILED_MAX_SOLVES)
    if done < n:
        return None
    stuck = np.flatnonzero(st)
    if stuck.size:
        sub = None if refine is None else refine.rows(stuck)
        X[stuck], st_bad = _box_qp(G, B[stuck], ub, tol, max_iter, sub, inverse, backend="numpy")
        stuck = stuck[st_bad]
    return X, stuck


def _pivoting_wins(G: np.ndarray, H: np.ndarray | None, B: np.ndarray, ub: np.ndarray | None, tol: float,
                   max_iter: int) -> bool:
    """Whether block pivoting (else Lawson-Hanson in chunks of 8 rows) solves ``B``, by probing both.

    Pivoting, unless on a probe of 32 rows it needs more than 8 solves per row, or more than 5 and
    more than Lawson-Hanson needs on 4 runs of 8 consecutive rows.

    Parameters
    ----------
    G, H : (N, N) float
        Matrix and its inverse (``None``: free-set form only).
    B : (n, N) float
    ub : (N,) float or None
    tol : float
    max_iter : int
    """
    n = len(B)
    use_bpp = True
    if n > 64:                                                  # probe: which method needs fewer solves?
        probe = np.unique(np.linspace(0, n - 1, 32).astype(np.int64))
        sb: dict = {}
        _, _, slow = _bpp(G, H, B[probe], ub, tol, min(12, max_iter), sb)
        per_bpp = sb["solves"] / len(probe) + 4 * slow.size / len(probe)
        if per_bpp > 8:
            use_bpp = False
        elif per_bpp > 5:
            runs = np.linspace(0, n - 8, 4).astype(np.int64)[:, None] + np.arange(8)
            sl: dict = {}
            _lh(G, H, B[runs.ravel()], ub, tol, max_iter, 8, sl)
            use_bpp = per_bpp <= sl["solves"] / runs.size
    return use_bpp


def _active_set_solve(G: np.ndarray, H: np.ndarray | None, B: np.ndarray, ub: np.ndarray | None, tol: float,
                      max_iter: int, use_bpp: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Block pivoting finished by Lawson-Hanson, or Lawson-Hanson in chunks of 8 rows throughout.

    Parameters
    ----------
    G, H : (N, N) float
    B : (n, N) float
    ub : (N,) float or None
    tol : float
    max_iter : int
    use_bpp : bool

    Returns
    -------
    X : (n, N) float
    free : (n, N) bool
    unconverged : (k,) int
    """
    if use_bpp:
        X, free, todo = _bpp(G, H, B, ub, tol, min(20, max_iter))
        stuck = np.zeros(0, dtype=np.int64)
        if todo.size:
            X[todo], free[todo], st = _lh(G, H, B[todo], ub, tol, max_iter)
            stuck = todo[st]
    else:
        X, free, stuck = _lh(G, H, B, ub, tol, max_iter, chunk=8)
    return X, free, stuck


def _box_qp(G: np.ndarray, B: np.ndarray, ub: np.ndarray | None, tol: float, max_iter: int,
            refine: _LSData | None = None, inverse: bool = True,
            backend: str = "auto") -> tuple[np.ndarray, np.ndarray]:
    """Solve ``min 1/2 x'Gx - b_t'x, 0 <= x <= ub`` exactly for every row ``b_t`` of ``B``.

    The compiled kernel (:func:`_compiled_box_qp`) when numba is installed, unless its probe finds
    dense, fast-changing sets; else block principal pivoting (few iterations over large batches),
    unless on a probe of 32 rows it
    needs more than 8 solves per row, or more than 5 and more than Lawson-Hanson with chunks of 8
    consecutive rows needs (probed on 4 runs of 8 rows): strongly correlated keys, sparse
    solutions, where full exchanges oscillate.  Rows that pivoting has not settled after 20
    iterations are finished by Lawson-Hanson.

    Parameters
    ----------
    G : (N, N) float, symmetric positive definite
    B : (n, N) float
    ub : (N,) float or None
        Upper bounds (``inf`` for none).
    tol : float
        Relative KKT tolerance.
    max_iter : int
        Iterations per row (pivoting stops at ``min(20, max_iter)``, Lawson-Hanson at ``max_iter``).
    refine : _LSData, optional
        The least-squares data behind ``G`` and ``B``: ``refine(X)`` is the exact negative gradient
        ``b_t - G x_t`` ``(n, N)``, for iterative refinement (ill-conditioned ``G``).
    inverse : bool
        Allow solving through ``G^-1`` on the fixed set (when ``G`` is well conditioned).
    backend : {"auto", "numpy", "numba"}
        "numba": the compiled kernel without its probe.

    Returns
    -------
    X : (n, N) float
    unconverged : (k,) int
        Rows stopped by ``max_iter``.
    """
    n, N = B.shape
    if n == 0:
        return np.zeros((0, N)), np.zeros(0, dtype=np.int64)
    if _use_compiled(backend):
        done = _compiled_box_qp(G, B, ub, tol, max_iter, refine, inverse, probe=backend != "numba")
        if done is not None:
            return done
    H = None
    if inverse:
        H = np.linalg.inv(G)
        H = 0.5 * (H + H.T)
    use_bpp = _pivoting_wins(G, H, B, ub, tol, max_iter)
    X, free, stuck = _active_set_solve(G, H, B, ub, tol, max_iter, use_bpp)
    if refine is not None:                                      # one step of iterative refinement
        R = np.where(free, refine(X), 0.0)
        X += _solve_fixed(G, H, R, free)[0]
    np.maximum(X, 0.0, out=X)
    if ub is not None:
        np.minimum(X, np.where(np.isfinite(ub), ub, np.inf), out=X)
    return X, stuck


# ----------------------------------------------------------------------------- temporal coupling
def _admm_start(G: np.ndarray, B: np.ndarray, ub: np.ndarray | None, s: float, X0: np.ndarray,
                iters: int = 150, rtol: float = 1e-4) -> np.ndarray:
    """Approximate solution of the temporally coupled QP by ADMM, to start the active-set method.

    With one Gram matrix for all frames the Hessian ``I (x) G + s L (x) I`` is diagonalised by the
    eigenvectors of ``G`` and the DCT-II over frames (the eigenvectors of the path Laplacian ``L``),
    so every ADMM step ``x = (H + rho I)^-1 (b + rho (z - u))``, ``z = clip(x + u)`` costs two DCTs
    and two ``(T, N) x (N, N)`` products.
    """
    T, N = B.shape
    lam, V = np.linalg.eigh(G)
    ev = lam[None, :] + s * (2.0 - 2.0 * np.cos(np.pi * np.arange(T) / T))[:, None]
    rho = float(np.sqrt(max(ev.min(), 1e-12 * ev.max()) * ev.max()))
    inv = 1.0 / (ev + rho)
    hi = np.inf if ub is None else ub
    z = np.clip(X0, 0.0, hi)
    u = np.zeros_like(z)
    scale = max(float(np.abs(z).max()), 1.0)
    for _ in range(iters):
        R = dct(B + rho * (z - u), type=2, norm="ortho", axis=0) @ V
        x = idct((R * inv) @ V.T, type=2, norm="ortho", axis=0)
        zn = np.clip(x + u, 0.0, hi)
        u += x - zn
        done = max(float(np.abs(x - zn).max()), float(np.abs(zn - z).max())) <= rtol * scale
        z = zn
        if done:
            break
    return z


def _banded_hessian(Gs: list[np.ndarray], pat: np.ndarray, s: float) -> np.ndarray:
    """The Hessian ``M = blockdiag(G_pat[t]) + s (L (x) I)`` of the temporally coupled QP, banded.

    Parameters
    ----------
    Gs : list of (N, N) float
        Gram matrices, one per mask pattern.
    pat : (T,) int
        Pattern of every frame.
    s : float
        Temporal coupling.

    Returns
    -------
    (N + 1, T N) float
        Lower band storage (``cholesky_banded(..., lower=True)``) in frame-major order:
        ``ab[d, i] = M[i + d, i]``.
    """
    T, N = len(pat), Gs[0].shape[0]
    n = T * N
    Gst = np.stack(Gs)
    Gl = np.zeros((len(Gs), N, N))                              # Gl[p, d, j] = G_p[j + d, j]
    for d in range(N):
        Gl[:, d, : N - d] = np.diagonal(Gst, offset=-d, axis1=1, axis2=2)
    base = np.zeros((N + 1, n))
    base[:N] = Gl[pat].transpose(1, 0, 2).reshape(N, n)
    deg = np.full(T, 2.0)
    deg[[0, -1]] = 1.0
    if T == 1:
        deg[:] = 0.0
    base[0] += s * np.repeat(deg, N)
    base[N, : n - N] = -s
    return base


def _hessian_product(Gs: list[np.ndarray], groups: list[tuple[int, np.ndarray]], s: float,
                     X: np.ndarray) -> np.ndarray:
    """``M x`` for the temporally coupled QP's Hessian ``M = blockdiag(G_pat[t]) + s (L (x) I)``.

    Parameters
    ----------
    Gs : list of (N, N) float
    groups : list of (int, (k,) int)
        Every pattern with its frames.
    s : float
    X : (T, N) float

    Returns
    -------
    (T, N) float
    """
    Y = np.empty_like(X)
    for p, rows in groups:
        Y[rows] = X[rows] @ Gs[p]
    dX = np.diff(X, axis=0)
    Y[:-1] -= s * dX
    Y[1:] += s * dX
    return Y


def _banded_solve_fixed(base: np.ndarray, fixed: np.ndarray, rhs: np.ndarray) -> np.ndarray:
    """Solve ``M y = rhs`` on the free variables, ``y = rhs`` on the ``fixed`` ones.

    Parameters
    ----------
    base : (N + 1, T N) float
        ``M`` in lower band storage (see :func:`_banded_hessian`).
    fixed : (T, N) bool
    rhs : (T, N) float

    Returns
    -------
    (T, N) float
    """
    T, N = fixed.shape
    n = T * N
    ff = fixed.ravel()
    ab = base.copy()
    for d in range(1, N + 1):
        ab[d, : n - d][ff[: n - d] | ff[d:]] = 0.0
    ab[0, ff] = 1.0
    cb = cholesky_banded(ab, lower=True, check_finite=False)
    return cho_solve_banded((cb, True), rhs.ravel(), check_finite=False).reshape(T, N)


def _objective(X: np.ndarray, HX: np.ndarray, B: np.ndarray) -> float:
    """``1/2 x'Mx - b'x`` from ``X``, ``HX = M x`` and ``B``, all (T, N) float."""
    return float(np.sum(X * (0.5 * HX - B)))


def _kkt_error(X: np.ndarray, g: np.ndarray, hi, gs: float) -> float:
    """Largest violation of the KKT conditions of ``0 <= X <= hi`` with gradient ``g``, relative to ``gs``.

    Parameters
    ----------
    X, g : (T, N) float
    hi : float or (N,) float
        Upper bounds (``inf`` for none).
    gs : float
        Gradient scale.
    """
    v = np.where(X <= 0.0, np.maximum(-g, 0.0), np.where(X >= hi, np.maximum(g, 0.0), np.abs(g)))
    return float(v.max()) / gs


def _take_active_set(hess, solve, B: np.ndarray, X0: np.ndarray, hi, fin: np.ndarray, ubf: np.ndarray,
                     gs: float, tol: float, max_iter: int) -> tuple[bool, np.ndarray | None, int]:
    """Primal-dual active-set iteration (block principal pivoting) on the whole temporally coupled take.

    Exchanges every KKT violator at once; gives up when the count of violators has not fallen for
    three iterations.

    Parameters
    ----------
    hess : callable
        ``hess(X)``: the Hessian product ``M x``, (T, N) float.
    solve : callable
        ``solve(fixed, rhs)``: ``M y = rhs`` on the free variables, ``y = rhs`` on the fixed ones.
    B : (T, N) float
    X0 : (T, N) float
        Starting point (its signs and bounds give the first sets).
    hi : float or (N,) float
    fin, ubf : (N,) bool, (N,) float
        Which bounds are finite, and the bounds with 0 for the infinite ones.
    gs : float
        Gradient scale.
    tol : float
    max_iter : int

    Returns
    -------
    converged : bool
    X : (T, N) float or None
        The solution if converged, else the iterate with the fewest violators (``None``: no iteration).
    iterations : int
    """
    lo = X0 <= 0.0
    up = (X0 >= hi) & ~lo
    best = (np.inf, None)
    stall = 0
    it = 0
    while it < max_iter:
        it += 1
        Xfix = np.where(up, ubf, 0.0)
        fixed = lo | up
        rhs = np.where(fixed, Xfix, B - hess(Xfix))
        X = solve(fixed, rhs)
        X[fixed] = Xfix[fixed]
        g = hess(X) - B
        tl = tol * gs
        v_neg = ~fixed & (X < 0.0)
        v_over = ~fixed & fin & (X > ubf)
        v_in = lo & (g < -tl)
        v_out = up & (g > tl)
        nv = int(v_neg.sum() + v_over.sum() + v_in.sum() + v_out.sum())
        if nv == 0:
            return True, np.clip(X, 0.0, hi), it
        if nv < best[0]:
            best, stall = (nv, X), 0
        else:
            stall += 1
            if stall >= 3:
                break
        lo = (lo & ~v_in) | v_neg
        up = (up & ~v_out) | v_over
    return False, best[1], it


def _armijo_arc(hess, B: np.ndarray, X: np.ndarray, fx: float, g: np.ndarray, step: np.ndarray,
                bind: np.ndarray, slope: float, hi) -> tuple[np.ndarray, np.ndarray, float] | None:
    """Armijo search along the projection arc ``clip(X + alpha step)``, ``alpha = 1, 1/2, ...`` (40 tries).

    Parameters
    ----------
    hess : callable
        ``hess(X)``: the Hessian product ``M x``, (T, N) float.
    B, X, g, step : (T, N) float
        Linear term, current point, its gradient and the Newton step.
    fx : float
        Objective at ``X``.
    bind : (T, N) bool
        Variables held at their bound.
    slope : float
        ``-g'step`` over the other variables.
    hi : float or (N,) float

    Returns
    -------
    (X, M x, objective) at the accepted point, or None when no step is accepted.
    """
    alpha = 1.0
    for _ls in range(40):
        Xa = np.clip(X + alpha * step, 0.0, hi)
        HXa = hess(Xa)
        fa = _objective(Xa, HXa, B)
        need = 1e-4 * (alpha * slope + float(np.sum(g[bind] * (X[bind] - Xa[bind]))))
        if fx - fa >= need - 1e-15 * abs(fx):
            return Xa, HXa, fa
        alpha *= 0.5
    return None


def _projected_newton(hess, solve, B: np.ndarray, X: np.ndarray, hi, diag: np.ndarray, ub: np.ndarray | None,
                      fin: np.ndarray, gs: float, tol: float, max_iter: int,
                      it: int) -> tuple[np.ndarray, bool]:
    """Bertsekas' projected Newton method (1982) on the temporally coupled take, globally convergent.

    Parameters
    ----------
    hess, solve : callable
        As for :func:`_take_active_set`.
    B : (T, N) float
    X : (T, N) float
        Feasible starting point.
    hi : float or (N,) float
    diag : (T, N) float
        Diagonal of the Hessian.
    ub : (N,) float or None
    fin : (N,) bool
    gs : float
        Gradient scale.
    tol : float
    max_iter : int
        Iterations in all, of which ``it`` are used already.

    Returns
    -------
    X : (T, N) float
    converged : bool
    """
    HX = hess(X)
    fx = _objective(X, HX, B)
    eps0 = 1e-3 * (1.0 if ub is None else float(np.min(np.where(fin, ub, 1.0))))
    while it < max_iter:
        it += 1
        g = HX - B
        if _kkt_error(X, g, hi, gs) <= tol:
            return X, True
        w = float(np.abs(X - np.clip(X - g / diag, 0.0, hi)).max())
        eps = min(eps0, w)
        bind = ((X <= eps) & (g > 0)) | ((X >= hi - eps) & (g < 0))
        step = solve(bind, np.where(bind, -g / diag, -g))
        free = ~bind
        slope = float(np.sum(-g[free] * step[free]))
        accepted = _armijo_arc(hess, B, X, fx, g, step, bind, slope, hi)
        if accepted is None:
            return X, False
        X, HX, fx = accepted
    return X, _kkt_error(X, HX - B, hi, gs) <= tol


def _smooth_qp(Gs: list[np.ndarray], pat: np.ndarray, B: np.ndarray, ub: np.ndarray | None, s: float,
               X0: np.ndarray, tol: float, max_iter: int, pdas: bool = True) -> tuple[np.ndarray, bool]:
    """Exact solution of the take-wide QP with temporal coupling ``s``.

    Minimises ``sum_t 1/2 x_t'G_{pat[t]}x_t - b_t'x_t + s/2 sum_t ||x_t - x_{t-1}||^2`` over
    ``0 <= x <= ub``.  The Hessian is banded (bandwidth ``N``, frame-major order); every step
    factorises it restricted to the free variables (the others get identity rows).  Primal-dual
    active-set iterations from an ADMM start (one pattern) or from ``X0``; projected Newton
    (Bertsekas 1982) if they stall.

    Parameters
    ----------
    Gs : list of (N, N) float
        Gram matrices, one per mask pattern.
    pat : (T,) int
        Pattern of every frame.
    B : (T, N) float
    ub : (N,) float or None
    s : float
    X0 : (T, N) float
        Starting point (the per-frame solution).
    pdas : bool
        Try the primal-dual active-set iteration first (otherwise projected Newton only).

    Returns
    -------
    X : (T, N) float
    converged : bool
    """
    T, N = B.shape
    base = _banded_hessian(Gs, pat, s)
    diag = base[0].reshape(T, N)
    hi = np.inf if ub is None else ub
    groups = [(p, np.flatnonzero(pat == p)) for p in range(len(Gs))]
    hess = partial(_hessian_product, Gs, groups, s)
    solve = partial(_banded_solve_fixed, base)
    gs = max(float(np.abs(B).max()), float(np.abs(np.stack(Gs)).max()) * 1e-12, 1e-300)
    fin = np.zeros(N, dtype=bool) if ub is None else np.isfinite(ub)
    ubf = np.zeros(N) if ub is None else np.where(fin, ub, 0.0)
    if pdas and len(Gs) == 1 and T > 1:
        X0 = _admm_start(Gs[0], B, ub, s, X0)
    # primal-dual active set (block principal pivoting on the whole take)
    Xbest, it = None, 0
    if pdas:
        converged, Xbest, it = _take_active_set(hess, solve, B, X0, hi, fin, ubf, gs, tol, max_iter)
        if converged:
            return Xbest, True
    # fallback: projected Newton (Bertsekas 1982) with an Armijo search, globally convergent
    X = np.clip(Xbest if Xbest is not None else X0, 0.0, hi)
    return _projected_newton(hess, solve, B, X, hi, diag, ub, fin, gs, tol, max_iter, it)


# ----------------------------------------------------------------------------- public API
def _as_float(name: str, value) -> float:
    v = float(value)
    if not np.isfinite(v) or v < 0:
        raise InvalidDataError(f"{name} must be a finite number >= 0, got {value}")
    return v


def _check_inputs(K, F, upper, mask):
    K = np.asarray(K, dtype=np.float64)
    if K.ndim != 2 or K.shape[0] == 0 or K.shape[1] == 0:
        raise InvalidDataError(f"keyshape matrix K must be (D, N) with D, N > 0, got shape {K.shape}")
    K = np.ascontiguousarray(K)                                 # (frames x features) @ K runs faster
    D, N = K.shape
    bad = None if np.isfinite(K).all() else ~np.isfinite(K).all(axis=0)
    if bad is not None:
        raise InvalidDataError(f"keyshape matrix K has NaN or infinite values in key column(s) "
                               f"{', '.join(map(str, np.flatnonzero(bad)[:10]))}")
    F = np.asarray(F, dtype=np.float64)
    single = F.ndim == 1
    if single:
        F = F[None, :]
    if F.ndim != 2 or F.shape[1] != D:
        raise InvalidDataError(f"frames F must be (T, {D}) to match K ({D} rows, {N} keys), "
                               f"got shape {F.shape if not single else F.shape[1:]}")
    T = len(F)
    rows = None
    if mask is not None:
        m = np.asarray(mask)
        if single and m.ndim == 1:
            m = m[None, :]
        if m.ndim != 2 or m.shape[0] != T or m.shape[1] == 0 or D % m.shape[1]:
            raise InvalidDataError(f"mask must be (T, D) = ({T}, {D}) or per marker (T, P) with D a multiple "
                                   f"of P, got shape {np.shape(mask)}")
        rows = np.repeat(m.astype(bool), D // m.shape[1], axis=1)
    if rows is not None:
        _check_finite(F, rows)
    else:
        # without a mask F is checked through F K ((T, N) values instead of (T, D), :func:`_solve_frames`):
        # a NaN or inf reaches every key that moves its feature; the features no key moves are checked here
        idle = ~K.any(axis=1)
        if idle.any():
            _check_finite(F[:, idle], None)
    ub = None
    if upper is not None:
        ub = np.broadcast_to(np.asarray(upper, dtype=np.float64), (N,)).copy() if np.ndim(upper) == 0 \
            else np.asarray(upper, dtype=np.float64)
        if ub.shape != (N,):
            raise InvalidDataError(f"upper must be a scalar or have one bound per key ({N}), "
                                   f"got shape {ub.shape}")
        if np.isnan(ub).any() or (ub <= 0).any():
            raise InvalidDataError("upper bounds must be > 0 (inf for none); drop a key to switch it off")
        if np.isinf(ub).all():
            ub = None
    return K, F, single, rows, ub


def _check_finite(F: np.ndarray, rows: np.ndarray | None) -> None:
    """Raise naming the first frame of ``F`` (T, D) with a NaN or infinite value where ``rows`` (T, D) is
    true (everywhere when None)."""
    bad = ~np.isfinite(F) if rows is None else (~np.isfinite(F) & rows)
    if bad.any():
        frames = np.flatnonzero(bad.any(axis=1))
        raise InvalidDataError(f"frame {frames[0]} has NaN or infinite feature values"
                               + (f" ({len(frames)} frames in all)" if len(frames) > 1 else "")
                               + (" where the mask says they are present" if rows is not None else "")
                               + "; mark missing markers with mask=")


def _check_options(l2, l1, smooth, tol, backend) -> tuple[float, float, float, float]:
    """Validated weights of the terms ``l2``, ``l1``, ``smooth`` and tolerance ``tol`` of :func:`solve_nnls`.

    Raises
    ------
    faceretarget.errors.InvalidDataError
        A negative or non-finite weight, a non-positive tolerance or an unknown backend.
    """
    l2, l1, smooth = _as_float("l2", l2), _as_float("l1", l1), _as_float("smooth", smooth)
    tol = float(tol)
    if backend not in ("auto", "numpy", "numba"):
        raise InvalidDataError(f"unknown backend '{backend}', use auto, numpy or numba")
    if not tol > 0:
        raise InvalidDataError(f"tol must be > 0, got {tol}")
    return l2, l1, smooth, tol


def _mask_patterns(F: np.ndarray,
                   rows: np.ndarray | None) -> tuple[list | np.ndarray, np.ndarray, np.ndarray]:
    """The distinct masks of a take and the frames' missing values set to 0.

    Parameters
    ----------
    F : (T, D) float
    rows : (T, D) bool or None
        Present feature coordinates (``None``: all).

    Returns
    -------
    pats : (p, D) bool, or ``[None]`` without a mask
        The distinct masks.
    pat : (T,) int
        Every frame's mask.
    F : (T, D) float
    """
    T = len(F)
    if rows is None:
        pats, pat = [None], np.zeros(T, dtype=np.int64)
    else:
        pats, pat = np.unique(rows, axis=0, return_inverse=True)
        pat = pat.ravel()
        F = np.where(rows, F, 0.0)
    return pats, pat, F


def _pattern_system(K: np.ndarray, F: np.ndarray, G_all: np.ndarray, pat: np.ndarray, p: int,
                    r: np.ndarray | None, l2: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The least-squares data and Gram matrix of the frames with mask pattern ``p``.

    Parameters
    ----------
    K : (D, N) float
    F : (T, D) float
    G_all : (N, N) float
        ``K'K``.
    pat : (T,) int
    p : int
    r : (D,) bool or None
        The pattern's present rows (``None``: all).
    l2 : float

    Returns
    -------
    frames : (t,) int
    Kp : (d, N) float
    Fp : (t, d) float
        Keyshapes and frames on the present rows.
    G : (N, N) float
        ``Kp'Kp + l2 I``.
    """
    N = K.shape[1]
    if r is None:
        frames, Kp, Fp, G = np.arange(len(F)), K, F, G_all.copy()
    else:
        frames = np.flatnonzero(pat == p)
        Kp, Fp = K[r], F[frames][:, r]
        G = Kp.T @ Kp
    G[np.diag_indices(N)] += l2
    return frames, Kp, Fp, G


def _live_keys(G: np.ndarray, floor: float, l2: float,
               ev: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """The keys that move an observed row, their Gram matrix (with a rank ridge if needed) and its spectrum.

    Parameters
    ----------
    G : (N, N) float
    floor : float
        Rank ridge: ``1e-13`` of ``K'K``'s largest eigenvalue.
    l2 : float
    ev : (N,) float, optional
        Eigenvalues of ``G`` if known (used when every key is live).

    Returns
    -------
    live : (k,) int
    Gl : (k, k) float
    ev : (k,) float
        Eigenvalues of ``Gl`` (``[1]`` without live keys).
    ridge : float
        Ridge in ``Gl``: ``l2``, plus ``floor`` when the keys cannot be told apart.
    """
    # keys that do not move any observed row: weight 0 (any value fits equally; 0 is the smallest)
    live = np.flatnonzero(np.diag(G) > floor)
    if live.size == len(G):
        Gl = G.copy()
        ev = np.linalg.eigvalsh(Gl) if ev is None else ev
    else:
        Gl = G[np.ix_(live, live)]
        ev = np.linalg.eigvalsh(Gl) if live.size else np.ones(1)
    ridge = l2
    if ev[0] < floor:                                           # keys the observed rows cannot tell apart
        Gl[np.diag_indices(len(live))] += floor
        ridge += floor
        ev = ev + floor
    return live, Gl, ev, ridge


class _LSData:
    """The least-squares data behind a Gram system, for exact gradients (ill-conditioned keys).

    ``G = R'R + ridge I`` and ``B = C R - l1`` with ``R`` (m, k) ``K``'s triangular QR factor when
    ``K`` (d, k) has more rows than columns (``C = F Q``: ``||K w - f||^2 = ||R w - c||^2 + const``,
    so the per-frame work does not depend on ``d``), else ``K`` itself with ``C = F``.
    """

    __slots__ = ("R", "C", "ridge", "l1")

    def __init__(self, R: np.ndarray, C: np.ndarray, ridge: float, l1: float):
        self.R, self.C, self.ridge, self.l1 = R, C, ridge, l1

    @classmethod
    def project(cls, K: np.ndarray, F: np.ndarray, ridge: float, l1: float) -> _LSData:
        """From keys ``K`` (d, k) and frames ``F`` (t, d)."""
        if K.shape[0] > K.shape[1]:
            Q, R = np.linalg.qr(K)
            return cls(R, _mm(F, Q), ridge, l1)
        return cls(K, F, ridge, l1)

    @property
    def data(self) -> tuple[np.ndarray, np.ndarray, float, float]:
        return self.R, self.C, self.ridge, self.l1

    def rows(self, rows) -> _LSData:
        """The data of the frames ``rows`` (an index array or a slice)."""
        return _LSData(self.R, self.C[rows], self.ridge, self.l1)

    def rhs(self) -> np.ndarray:
        """``B = C R - l1`` (t, k)."""
        return _mm(self.C, self.R) - self.l1

    def __call__(self, X: np.ndarray) -> np.ndarray:
        """The exact negative gradient ``b_t - G x_t`` (t, k) at ``X`` (t, k)."""
        return _mm(self.C - _mm(X, self.R.T), self.R) - self.ridge * X - self.l1


def _pattern_rhs(Kp: np.ndarray, Fp: np.ndarray, live: np.ndarray, exact: _LSData | None,
                 l1: float) -> np.ndarray:
    """``B = Fp Kp - l1`` (t, N), from the projected data ``exact`` on the live keys when given."""
    if exact is None:
        Bp = _mm(Fp, Kp)
        if l1:
            Bp -= l1
        return Bp
    Bp = np.empty((len(Fp), Kp.shape[1]))
    Bp[:, live] = exact.rhs()
    dead = np.setdiff1d(np.arange(Kp.shape[1]), live)
    if dead.size:
        Bp[:, dead] = _mm(Fp, Kp[:, dead]) - l1
    return Bp


def _solve_frames(K: np.ndarray, F: np.ndarray, rows: np.ndarray | None, ub: np.ndarray | None, l2: float,
                  l1: float, tol: float, max_iter: int, backend: str
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[np.ndarray], list[np.ndarray],
                             list[np.ndarray]]:
    """Every frame's weights on its own (no temporal term), frames grouped by mask pattern.

    Parameters
    ----------
    K : (D, N) float
    F : (T, D) float
    rows : (T, D) bool or None
    ub : (N,) float or None
    l2, l1, tol : float
    max_iter : int
    backend : str

    Returns
    -------
    W : (T, N) float
    pat : (T,) int
        Every frame's mask pattern.
    B : (T, N) float
        Linear terms ``K_p'f_t - l1``.
    Gs, Graw : list of (N, N) float
        Gram matrices per pattern, with and without the rank ridge.
    stuck : list of (k,) int
        Frames that did not converge.
    """
    T, N = len(F), K.shape[1]
    G_all = K.T @ K
    ev_all = np.linalg.eigvalsh(G_all)
    floor = _RIDGE * max(float(ev_all[-1]), 1e-300)
    pats, pat, F = _mask_patterns(F, rows)
    Gs: list[np.ndarray] = []
    Graw: list[np.ndarray] = []                                 # without the rank ridge
    one = rows is None                                          # one pattern: every frame, every row
    B = None if one else np.empty((T, N))
    W = None if one else np.zeros((T, N))
    stuck: list[np.ndarray] = []
    for p, r in enumerate(pats):
        frames, Kp, Fp, G = _pattern_system(K, F, G_all, pat, p, r, l2)
        live, Gl, ev, ridge = _live_keys(G, floor, l2, ev_all + l2 if r is None else None)
        Graw.append(G)
        Gs.append(G + floor * np.eye(N) if (ridge != l2 or live.size < N) else G)
        exact = None
        if live.size and ev[-1] > _EXACT_COND * ev[0]:       # normal equations lose digits: refine
            with np.errstate(invalid="ignore", over="ignore"):
                exact = _LSData.project(Kp[:, live], Fp, ridge, l1)
        with np.errstate(invalid="ignore", over="ignore"):    # a NaN or inf in F is reported below
            Bp = _pattern_rhs(Kp, Fp, live, exact, l1)
        if one:
            if not np.isfinite(Bp).all():                       # NaN or inf in F (checked here: cheaper)
                _check_finite(F, None)
            B = Bp
            W = np.zeros((T, N))
        else:
            B[frames] = Bp
        if live.size == 0:
            continue
        ubl = None if ub is None else ub[live]
        Wp, bad = _box_qp(Gl, Bp[:, live] if live.size < N else Bp, ubl, tol, max_iter, exact,
                          inverse=ev[-1] < _INVERSE_COND * ev[0], backend=backend)
        if live.size < N or not one:
            W[np.ix_(frames, live)] = Wp
        else:
            W = Wp
        stuck.append(frames[bad])
    return W, pat, B, Gs, Graw, stuck


def _smooth_take(Gs: list[np.ndarray], Graw: list[np.ndarray], pat: np.ndarray, B: np.ndarray,
                 ub: np.ndarray | None, smooth: float, W: np.ndarray, tol: float,
                 max_iter: int) -> tuple[np.ndarray, bool]:
    """:func:`_smooth_qp` from the per-frame solution ``W`` (T, N), without the rank ridge if possible.

    Returns
    -------
    W : (T, N) float
    converged : bool
    """
    try:                                                        # smoothing may resolve rank deficiency
        return _smooth_qp(Graw, pat, B, ub, smooth, W, tol, max_iter)
    except np.linalg.LinAlgError:
        return _smooth_qp(Gs, pat, B, ub, smooth, W, tol, max_iter)


def _unconverged_frames_message(stuck: list[np.ndarray], max_iter: int) -> str | None:
    """The warning about the frames ``stuck`` (lists of frame numbers) that did not converge, or None."""
    if not any(s.size for s in stuck):
        return None
    bad = np.sort(np.concatenate(stuck))
    if bad.size:
        return (f"solve_nnls: {bad.size} frame(s) did not converge in {max_iter} iterations "
                f"(first: frame {bad[0]}); their weights are approximate")
    return None


def solve_nnls(K: np.ndarray, F: np.ndarray, *, upper=None, l2: float = 0.0, l1: float = 0.0,
               smooth: float = 0.0, mask: np.ndarray | None = None, tol: float = 1e-10,
               max_iter: int | None = None, backend: str = "auto") -> np.ndarray:
    """Non-negative keyshape weights of every frame of a take (Chuang Eq. 3.1/3.2).

    Minimises, over ``W`` with ``0 <= W <= upper``::

        sum_t [ 1/2 ||K w_t - f_t||^2 + l2/2 ||w_t||^2 + l1 sum_i w_ti ] + smooth/2 sum_t ||w_t - w_{t-1}||^2

    With the defaults this is ``scipy.optimize.nnls(K, f_t)`` for every frame, solved for the
    whole take at once (see the module docstring for the algorithms).

    Parameters
    ----------
    K : (D, N) float
        Keyshapes, one column per keyshape (its feature displacements from the neutral).
    F : (T, D) or (D,) float
        Frames, one row per frame (feature displacements).
    upper : float or (N,) float, optional
        Upper bounds of the weights (e.g. 1); ``inf`` for none.
    l2 : float
        Ridge weight: shares weight among similar keyshapes.
    l1 : float
        Sparsity weight (in units of ``K'f``): switches weakly used keyshapes off.
    smooth : float
        Temporal smoothness weight (in units of ``K'K``); couples consecutive rows of ``F``, which
        must then be consecutive frames of one take.
    mask : (T, D) or (T, P) bool, optional
        Which feature coordinates (or which markers, ``D / P`` coordinates each, in the order of
        ``F``'s columns) are present.  Missing values are ignored and may be NaN.
    tol : float
        Relative tolerance of the optimality (KKT) conditions.
    max_iter : int, optional
        Pivoting iterations per frame (default ``50 + 10 N``), or with ``smooth`` active-set and
        Newton iterations of the whole take (default 100).  Weights that do not converge are
        returned as they are, with a :class:`~faceretarget.errors.FitWarning`.
    backend : {"auto", "numpy", "numba"}
        ``"auto"`` solves frame after frame with a compiled bounded Lawson-Hanson kernel
        warm-started from the previous frame (:mod:`._nnls_numba`) when ``numba`` is installed
        (``make fast``; a probe hands dense, fast-changing weights to block
        pivoting), else with the vectorised NumPy methods; ``"numpy"``: the NumPy methods;
        ``"numba"``: the kernel always (:class:`~faceretarget.errors.MissingDependencyError`
        without numba).  The results agree to rounding (the temporal term is NumPy's either way).

    Returns
    -------
    W : (T, N) or (N,) float

    Raises
    ------
    faceretarget.errors.InvalidDataError
        Mismatched shapes, NaN/infinite values that are not masked, negative weights of terms or
        non-positive upper bounds.

    Examples
    --------
    >>> K = np.array([[1.0, 0.0], [0.0, 1.0], [1.0, 1.0]])
    >>> solve_nnls(K, np.array([[2.0, -1.0, 1.0]])).round(6)
    array([[1.5, 0. ]])
    """
    K, F, single, rows, ub = _check_inputs(K, F, upper, mask)
    l2, l1, smooth, tol = _check_options(l2, l1, smooth, tol, backend)
    N = K.shape[1]
    T = len(F)
    if T == 0:
        return np.zeros((0, N))
    if max_iter is None:
        max_iter = 100 if smooth > 0 else 50 + 10 * N
    W, pat, B, Gs, Graw, stuck = _solve_frames(K, F, rows, ub, l2, l1, tol, max_iter, backend)
    if smooth > 0:
        W, ok = _smooth_take(Gs, Graw, pat, B, ub, smooth, W, tol, max_iter)
        msg = None if ok else (f"solve_nnls: the temporally smoothed solution did not converge in {max_iter} "
                               "iterations; the weights are approximate")
    else:
        msg = _unconverged_frames_message(stuck, max_iter)
    if msg is not None:
        warnings.warn(msg, FitWarning, stacklevel=2)
    return W[0] if single else W


# ----------------------------------------------------------------------------- filtering
def filter_cutoff_hz(level: float) -> float:
    """Cutoff frequency (-3 dB) of :func:`temporal_filter` at ``level``: ``10 Hz / level``.

    Level 1 keeps motion up to 10 Hz (removes frame-to-frame jitter, keeps speech articulation),
    2 up to 5 Hz, 5 up to 2 Hz, 10 up to 1 Hz (only slow expression changes); 0 is no filtering
    (``inf``).
    """
    level = _as_float("level", level)
    return np.inf if level == 0 else 10.0 / level


def temporal_filter(W: np.ndarray, level: float, fps: float) -> np.ndarray:
    """Zero-phase Gaussian low-pass filtering of weight curves, with an adjustable level.

    The filter is the heat kernel of the frame sequence, ``exp(-tau L)`` with ``L`` the path
    Laplacian (reflecting ends), applied exactly in the DCT domain: a discrete Gaussian of variance
    ``2 tau`` frames^2, frequency response ``exp(-tau (2 - 2 cos w))`` ~ ``exp(-tau w^2)``.
    ``tau = ln(2) / (2 w_c^2)`` puts the -3 dB point of that Gaussian at ``w_c = 2 pi f_c / fps``,
    ``f_c`` = :func:`filter_cutoff_hz` ``(level)``; ``tau`` grows continuously from 0 with the
    level.  Its kernel is
    non-negative and sums to one, so filtered weights stay within the range of the input (bounds
    such as ``0 <= w <= 1`` are kept) and every curve's peak-to-peak shrinks monotonically as the
    level grows.

    Parameters
    ----------
    W : (T, N) float
        Weight curves, one row per frame.
    level : float
        0 for none; larger is smoother (see :func:`filter_cutoff_hz`).
    fps : float
        Frame rate of ``W``.

    Returns
    -------
    (T, N) float
    """
    W = np.asarray(W, dtype=np.float64)
    level = _as_float("level", level)
    fps = float(fps)
    if not (np.isfinite(fps) and fps > 0):
        raise InvalidDataError(f"fps must be > 0, got {fps}")
    if W.ndim != 2:
        raise InvalidDataError(f"weights must be (T, N), got shape {W.shape}")
    if not np.isfinite(W).all():
        frame = int(np.flatnonzero(~np.isfinite(W).all(axis=1))[0])
        raise InvalidDataError(f"frame {frame} has NaN or infinite weights")
    T = len(W)
    if level == 0 or T < 2:
        return W.copy()
    wc = 2.0 * np.pi * filter_cutoff_hz(level) / fps
    tau = 0.5 * np.log(2.0) / wc**2
    gain = np.exp(-tau * (2.0 - 2.0 * np.cos(np.pi * np.arange(T) / T)))
    out = idct(dct(W, type=2, norm="ortho", axis=0) * gain[:, None], type=2, norm="ortho", axis=0)
    return np.clip(out, W.min(axis=0), W.max(axis=0))          # rounding only


def extremes_removed(W: np.ndarray, Wf: np.ndarray) -> float:
    """How much of the weight curves' extremes filtering removed, in percent.

    The mean over curves (columns) that move at all of ``100 (1 - ptp(Wf) / ptp(W))``: the share of
    each curve's peak-to-peak range lost.  0 means untouched, 100 flattened.

    Parameters
    ----------
    W, Wf : (T, N) float
        Curves before and after filtering.
    """
    W = np.asarray(W, dtype=np.float64)
    Wf = np.asarray(Wf, dtype=np.float64)
    if W.shape != Wf.shape or W.ndim != 2:
        raise InvalidDataError(f"weights before {W.shape} and after {Wf.shape} filtering must be "
                               "equal (T, N)")
    r0 = np.ptp(W, axis=0)
    moving = r0 > 0
    if not moving.any():
        return 0.0
    return float(np.mean(100.0 * (1.0 - np.ptp(Wf, axis=0)[moving] / r0[moving])))
