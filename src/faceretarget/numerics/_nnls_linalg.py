"""Linear algebra the NNLS solvers share: stacked free-set solves, blocked products, least-squares data.

The vectorised active-set methods of :mod:`._nnls_active_set` treat a take as a batch of
box-constrained quadratic programs in ``N`` dimensions sharing one Gram matrix ``G = K'K``
(right-hand sides ``b_t = K'f_t``).  Both repeatedly solve, for every unfinished frame, the
equality-constrained problem on its free set ``F`` (the other weights fixed at 0 or at their upper
bound), in the cheaper of two equivalent forms: ``G_FF x_F = b_F - G_FU u_U`` when ``|F| <= N/2``,
otherwise through ``G^-1`` on the fixed set (``N - |F|`` unknowns; only while
``cond(G) < 1e10``).  Frames are bucketed by form and set size and every bucket is one stacked
LAPACK solve, so one step over the whole take is a few dozen LAPACK calls (:func:`_solve_fixed`).

A take's products (frames x features x keys) are computed in row blocks small enough for BLAS to
run them on one thread (:func:`_mm`): on a busy machine waking BLAS threads costs milliseconds per
call, more than such a product.

With ill-conditioned keys the least-squares data behind the Gram system (:class:`_LSData`: the keys
projected once, ``K = QR`` and ``c_t = Q'f_t``) gives the exact gradients of iterative refinement.
"""

from __future__ import annotations

import numpy as np

_SMALL_BATCH = 256
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


# ----------------------------------------------------------------------------- least-squares data
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
