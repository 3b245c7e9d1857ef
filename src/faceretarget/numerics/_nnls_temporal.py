"""The take-wide QP of :func:`~._nnls_solve.solve_nnls` with temporal coupling ``smooth > 0`` (:func:`_smooth_qp`).

With ``smooth`` the objective couples consecutive frames::

    sum_t [ 1/2 ||K w_t - f_t||^2 + l2/2 ||w_t||^2 + l1 sum_i w_ti ]
          + smooth/2 sum_t ||w_t - w_{t-1}||^2         subject to  0 <= w_t <= upper

The take becomes one QP whose Hessian ``M = blockdiag(G_t) + smooth (L (x) I)`` (``L``: path
Laplacian over frames) is block-tridiagonal, i.e. banded with bandwidth ``N`` in frame-major order.  It is solved by a
primal-dual active-set iteration on the whole take (block principal pivoting again: solve on
the free variables with one banded Cholesky of ``M`` restricted to them, LAPACK ``pbtrf``,
linear in the number of frames; exchange all KKT violators), started from an approximate
solution: ADMM with ``M`` diagonalised by the eigenvectors of ``G`` and the DCT over frames
when all frames share one Gram matrix, else the per-frame solution.  Should the active-set
iteration stall it hands over to Bertsekas' projected Newton method (1982, Armijo search along
the projection arc), which converges from anywhere.  Either way the final step solves the
optimality conditions exactly.
"""

from __future__ import annotations

from functools import partial

import numpy as np
from scipy.fft import dct, idct
from scipy.linalg import cho_solve_banded, cholesky_banded


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
