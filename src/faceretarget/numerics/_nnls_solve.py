"""Non-negative keyshape weights for a whole take (Chuang Eq. 3.1/3.2): :func:`solve_nnls`.

Every source frame ``f_t`` (``D`` feature coordinates) is decomposed into non-negative weights of
the ``N`` source keyshapes ``K`` (one column per keyshape displacement)::

    min_w  1/2 ||K w_t - f_t||^2        subject to  w_t >= 0                       (Eq. 3.1/3.2)

Frames are independent, so the take is solved as a batch of box-constrained quadratic programs in
``N`` dimensions sharing one Gram matrix ``G = K'K`` (right-hand sides ``b_t = K'f_t``) by exact
methods.  This module checks the input, groups the frames by mask pattern, drops the keys no
observed row moves and projects ill-conditioned keys; the algorithms are in:

=========================== =========================================================================
:mod:`._nnls_box_qp`        every frame's box-constrained QP: the compiled bounded Lawson-Hanson kernel
                            (:mod:`._nnls_numba`) when numba is installed, else the vectorised methods
:mod:`._nnls_active_set`    block principal pivoting and Lawson-Hanson, vectorised over frames
:mod:`._nnls_linalg`        stacked free-set solves, blocked products, least-squares data
:mod:`._nnls_temporal`      the take-wide QP with temporal coupling (``smooth``)
:mod:`._nnls_checks`        input checks
=========================== =========================================================================

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

Beyond the thesis, in the spirit of NVIDIA Audio2Face's blendshape solver, the objective can have::

    sum_t [ 1/2 ||K w_t - f_t||^2 + l2/2 ||w_t||^2 + l1 sum_i w_ti ]
          + smooth/2 sum_t ||w_t - w_{t-1}||^2         subject to  0 <= w_t <= upper

* ``upper``: box constraints (e.g. 1, a rig's slider range);
* ``l2``: ridge, ``G + l2 I``; it spreads weight over similar keyshapes;
* ``l1``: sparsity, ``b_t - l1`` (on ``w >= 0`` the L1 norm is linear); it switches weak keys off;
* ``smooth``: temporal coupling of consecutive frames.  The take becomes one QP with a banded
  Hessian, solved exactly from the per-frame solution (:mod:`._nnls_temporal`);
* ``mask``: missing markers.  A frame is solved on the rows that exist; frames are grouped by
  mask pattern, each pattern with its own Gram matrix.

A keyshape that moves none of a frame's observed rows gets weight 0 in that frame (any weight
fits equally).  When the observed rows cannot tell the remaining keyshapes apart (fewer rows than
keys, duplicate keys) the weights are not unique; a tiny ridge (``1e-13`` of ``K'K``'s largest
eigenvalue) then picks one solution.  A frame with no observed row gets zero weights (with
``smooth``: whatever its neighbours imply).

:func:`~._nnls_filter.temporal_filter` smooths weight curves afterwards with an adjustable level
and :func:`~._nnls_filter.extremes_removed` reports how much of the curves' extremes that costs.
"""

from __future__ import annotations

import warnings

import numpy as np

from ..errors import FitWarning
from ._nnls_box_qp import _box_qp
from ._nnls_checks import _check_finite, _check_inputs, _check_options
from ._nnls_linalg import _LSData, _mm
from ._nnls_temporal import _smooth_qp

__all__ = ["solve_nnls"]

_RIDGE = 1e-13
_INVERSE_COND = 1e10
_EXACT_COND = 1e10


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
    """:func:`~._nnls_temporal._smooth_qp` from the per-frame solution ``W`` (T, N), without the rank ridge
    if possible.

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
