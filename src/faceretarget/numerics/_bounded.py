"""Weights inside a range: box-constrained least squares for whole takes, and the weight range type.

A blend of key shapes plays right in an artist's tool only when its weights stay near [0, 1]:
Blender hard-limits shape-key sliders to +-10 and its glTF importer sizes them from the first
keyframe, Maya and Unity clamp or distort beyond their slider ranges, and a weight of 18 multiplies
every sculpting difference between an artist's key-models by 18.  An unconstrained solve reproduces
the motion by cancelling huge weights wherever the keys are correlated (range-of-motion frames,
composed emotion x viseme sets), so the range is part of the solve, not a clip afterwards::

    min_w  1/2 ||K w - f_t||^2    subject to    lo <= w <= hi        (every frame t)

solved for a whole take at once by :func:`~._nnls_solve.solve_nnls` after the shift ``w = lo + v``
(``0 <= v <= hi - lo``).

:func:`weight_range` reads a range given as ``None`` (unconstrained), a pair, or ``"lo,hi"`` text.
"""

from __future__ import annotations

import numpy as np

from ..errors import InvalidDataError
from ..names import is_arkit, normalize_name
from ._nnls_solve import solve_nnls

__all__ = ["solve_bounded", "solve_inequality", "range_metric", "weight_range", "auto_weight_range", "WeightRange", "FACS_RANGE", "EXAMPLE_RANGE"]

WeightRange = tuple[float, float]

#: Weights of a FACS / ARKit-style rig's own shapes: each a slider from rest to full.
FACS_RANGE: WeightRange = (0.0, 1.0)
#: Example-based key sets (range-of-motion frames, composed emotion x viseme sets, an artist's
#: key-models): the narrowest of [0, 1], [-0.25, 1.25], [-0.5, 1.5], [-1, 2] that keeps P1 (rom-40
#: cross, 68 landmarks, clean and 0.5 mm noise) within 10 % of the motion (worst 9.4 %; [-0.25, 1.25]
#: reaches 11.2 %, [0, 1] 47 %; README "Weight ranges").
EXAMPLE_RANGE: WeightRange = (-0.5, 1.5)


def weight_range(value, *, what: str = "weight range") -> WeightRange | None:
    """A checked ``(lo, hi)`` range with ``lo < hi`` (``-inf``/``inf`` allowed), or None for none.

    Parameters
    ----------
    value : None, (lo, hi), or str
        ``None``, ``"none"`` or ``"off"`` -> None; a pair of numbers; ``"lo,hi"`` or ``"lo hi"``.

    Raises
    ------
    InvalidDataError
        Not two numbers, NaN, ``lo >= hi`` or an infinite ``lo`` with a finite ``hi`` (naming
        ``what``).

    Examples
    --------
    >>> weight_range("0,1"), weight_range((-0.25, 1.25)), weight_range(None)
    ((0.0, 1.0), (-0.25, 1.25), None)
    """
    if value is None or (isinstance(value, str) and value.strip().lower() in ("none", "off", "")):
        return None
    try:
        parts = value.replace(",", " ").split() if isinstance(value, str) else list(value)
        lo, hi = (float(p) for p in parts)
    except (TypeError, ValueError):
        raise InvalidDataError(f"{what} must be two numbers LO HI, got {value!r}") from None
    if not lo < hi:
        raise InvalidDataError(f"{what} must have LO < HI, got {lo:g} {hi:g}")
    if (lo, hi) == (-np.inf, np.inf):
        return None
    if not np.isfinite(lo):
        raise InvalidDataError(f"{what}: LO must be a finite number (or give no range), got {lo:g}")
    return lo, hi


def auto_weight_range(value, key_names) -> WeightRange | None:
    """The range ``value`` asks for, with ``"auto"`` decided by the target keys' names.

    ``"auto"``: :data:`FACS_RANGE` when every key is an ARKit shape (a FACS-style rig played by its
    own sliders), else :data:`EXAMPLE_RANGE`; anything else goes through :func:`weight_range`.

    Examples
    --------
    >>> auto_weight_range("auto", ["jawOpen", "eyeBlink_L"]), auto_weight_range("auto", ["frame00012"])
    ((0.0, 1.0), (-0.5, 1.5))
    """
    if isinstance(value, str) and value.strip().lower() == "auto":
        names = list(key_names)
        return FACS_RANGE if names and all(is_arkit(normalize_name(n)) for n in names) else EXAMPLE_RANGE
    return weight_range(value)


def range_metric(B: np.ndarray) -> np.ndarray:
    """Upper-triangular ``L'`` ``(N, N)`` with ``||L' w||^2 = ||B w||^2`` (``B`` ``(M, N)``, any ``M``).

    The metric in which an in-range blend is chosen nearest to an unconstrained one, measured on the
    shapes ``B`` it plays (a target rig's key displacements, one column per key).  A relative ridge of
    1e-9 keeps it positive definite when shapes repeat.
    """
    B = np.asarray(B, dtype=np.float64)
    G = B.T @ B
    G[np.diag_indices_from(G)] += 1e-9 * max(float(np.trace(G)) / max(len(G), 1), 1e-300)
    return np.linalg.cholesky(G).T


def solve_bounded(K: np.ndarray, F: np.ndarray, lower, upper, *, smooth: float = 0.0,
                  mask: np.ndarray | None = None, tol: float = 1e-10, backend: str = "auto") -> np.ndarray:
    """Least-squares weights of every frame of a take inside ``[lower, upper]``.

    Minimises ``sum_t 1/2 ||K w_t - f_t||^2 + smooth/2 sum_t ||w_t - w_{t-1}||^2`` over
    ``lower <= W <= upper``; exact to ``tol`` on the optimality conditions (every frame that is
    inside the range where the unconstrained fit already was gets that fit).

    Parameters
    ----------
    K : (D, N) float
        Key shapes, one column per key (feature displacements from the neutral).
    F : (T, D) or (D,) float
        Frames (feature displacements).
    lower, upper : float or (N,) float
        The range; ``lower`` finite, ``upper`` finite or ``inf``.
    smooth, mask, tol, backend
        As :func:`~._nnls_solve.solve_nnls`.

    Returns
    -------
    W : (T, N) or (N,) float
        Inside the range exactly (clipped after the solve against rounding); a weight at a bound
        equals it.

    Raises
    ------
    InvalidDataError
        A lower bound that is not finite, ``lower >= upper``, or :func:`~._nnls_solve.solve_nnls`'s input errors.

    Examples
    --------
    Two correlated keys: the exact fit needs weights 10 and -10, a range keeps them playable.

    >>> K = np.array([[1.0, 0.9], [0.0, 0.1]])
    >>> np.linalg.solve(K, [1.0, -1.0]).round(4).tolist()
    [10.0, -10.0]
    >>> solve_bounded(K, np.array([1.0, -1.0]), 0.0, 1.0).round(4).tolist()
    [1.0, 0.0]
    >>> solve_bounded(K, np.array([1.0, -1.0]), -1.0, 2.0).round(4).tolist()
    [1.9, -1.0]
    """
    K = np.asarray(K, dtype=np.float64)
    if K.ndim != 2 or 0 in K.shape:
        raise InvalidDataError(f"solve_bounded: keyshape matrix K must be (D, N) with D, N > 0, got shape {K.shape}")
    N = K.shape[1]
    try:
        lo = np.broadcast_to(np.asarray(lower, dtype=np.float64), (N,)).copy()
        hi = np.broadcast_to(np.asarray(upper, dtype=np.float64), (N,)).copy()
    except ValueError:
        raise InvalidDataError(f"solve_bounded: lower and upper must be numbers or have one bound per key ({N}), "
                               f"got shapes {np.shape(lower)} and {np.shape(upper)}") from None
    if not np.isfinite(lo).all():
        raise InvalidDataError("solve_bounded: the lower bounds must be finite")
    if np.isnan(hi).any() or not (hi > lo).all():
        raise InvalidDataError("solve_bounded: every upper bound must be above its lower bound")
    F = np.asarray(F, dtype=np.float64)
    if F.ndim in (1, 2) and F.shape[-1] == K.shape[0]:      # else solve_nnls names the shape error
        F = F - K @ lo                                      # the frames seen from w = lo
    V = solve_nnls(K, F, upper=hi - lo, smooth=smooth, mask=mask, tol=tol, backend=backend)
    W = V + lo
    np.copyto(W, hi, where=V >= hi - lo)                    # exactly at the bound (V + lo may round below)
    return np.clip(W, lo, hi)


def solve_inequality(L: np.ndarray, W: np.ndarray, A: np.ndarray, lower, upper, *, offset=None,
                     tol: float = 1e-9) -> np.ndarray:
    """The blend nearest to each frame's weights whose linear values stay inside their ranges.

    Per frame ``t``::

        min_w  ||L (w - w_t)||^2    subject to    lower <= offset + A w <= upper

    where ``offset + A w`` are values the weights drive linearly (a control table's slider values,
    ``c0 + W @ (C - c0)``; a key set's ARKit curves, ``W @ U``).  Unlike a box on the weights
    (:func:`solve_bounded`), these are general linear inequalities.  Frames already inside are
    returned unchanged; the others are solved exactly as a least-distance programme (Lawson and
    Hanson 1974, Ch. 23: ``z = L (w - w_t)`` with ``E z >= f_t``, through one NNLS of the
    constraints' dual), a few hundred microseconds per frame with 40 keys and 104 inequalities.

    Parameters
    ----------
    L : (N, N) float
        The metric (:func:`range_metric` of the shapes the weights play: the target's geometry).
    W : (T, N) or (N,) float
        The solved weights.
    A : (M, N) float
        Value ``j`` of a frame is ``offset_j + A[j] @ w``.
    lower, upper : float or (M,) float
        The values' ranges (``-inf`` / ``inf``: no bound on that side).
    offset : (M,) float, optional
        The values at zero weights (default 0).
    tol : float
        Frames whose values are inside to ``tol`` (relative to each range's width, or absolute
        for a one-sided range) are left as they are.

    Returns
    -------
    (T, N) or (N,) float
        Weights whose values are inside the ranges up to rounding (about 1e-12 of the shapes'
        scale; clip the values when writing them).

    Raises
    ------
    InvalidDataError
        Shapes that do not agree, a range with ``lower > upper``, or ranges no blend can reach (a
        value that no weight moves and that is outside its range).

    Examples
    --------
    Two keys whose values are their sum and their difference, both kept in [0, 1]:

    >>> A = np.array([[1.0, 1.0], [1.0, -1.0]])
    >>> solve_inequality(np.eye(2), np.array([0.9, 0.4]), A, 0.0, 1.0).round(6).tolist()
    [0.75, 0.25]
    """
    from scipy.linalg import solve_triangular
    from scipy.optimize import nnls

    L = np.asarray(L, dtype=np.float64)
    A = np.atleast_2d(np.asarray(A, dtype=np.float64))
    W = np.asarray(W, dtype=np.float64)
    single = W.ndim == 1
    W2 = np.atleast_2d(W)
    N, M = W2.shape[1], A.shape[0]
    if L.shape != (N, N) or A.shape[1] != N:
        raise InvalidDataError(f"solve_inequality: L must be ({N}, {N}) and A ({M}, {N}) for weights of {N} "
                               f"columns, got {L.shape} and {A.shape}")
    try:
        lo = np.broadcast_to(np.asarray(lower, dtype=np.float64), (M,)).copy()
        hi = np.broadcast_to(np.asarray(upper, dtype=np.float64), (M,)).copy()
        off = np.zeros(M) if offset is None else np.broadcast_to(np.asarray(offset, dtype=np.float64), (M,)).copy()
    except ValueError:
        raise InvalidDataError(f"solve_inequality: lower, upper and offset must be numbers or have one entry per "
                               f"value ({M})") from None
    if np.isnan(lo).any() or np.isnan(hi).any() or (lo > hi).any():
        raise InvalidDataError("solve_inequality: every lower bound must be at most its upper bound")
    width = np.where(np.isfinite(hi - lo), hi - lo, 1.0)
    slack = tol * np.maximum(width, 1e-300)
    V = off + W2 @ A.T
    bad = ((V < lo - slack) | (V > hi + slack)).any(axis=1)
    out = W2.copy()
    if bad.any():
        # every bound as a row of G w >= h, then z = L (w - w_t): E z >= h - G w_t with E = G L^-1
        has_lo, has_hi = np.isfinite(lo), np.isfinite(hi)
        G = np.concatenate([A[has_lo], -A[has_hi]])
        h = np.concatenate([lo[has_lo] - off[has_lo], off[has_hi] - hi[has_hi]])
        Linv = solve_triangular(L, np.eye(N), lower=False) if np.allclose(L, np.triu(L)) else np.linalg.inv(L)
        E = G @ Linv
        norm = np.linalg.norm(E, axis=1)
        moved = norm > 1e-12 * max(float(norm.max(initial=0.0)), 1e-300)
        if not moved.all() and (h[~moved] > 0).any():
            raise InvalidDataError("solve_inequality: a value that no weight moves is outside its range")
        E, G, h = E[moved] / norm[moved, None], G[moved] / norm[moved, None], h[moved] / norm[moved]
        Mt = np.vstack([E.T, np.zeros((1, len(E)))])         # (N + 1, m): the dual NNLS's matrix, last row f_t
        b = np.zeros(N + 1)
        b[N] = 1.0
        for t in np.flatnonzero(bad):
            f = h - G @ W2[t]
            if f.max(initial=0.0) <= 0.0:
                continue
            Mt[N] = f
            u, _ = nnls(Mt, b, maxiter=50 * Mt.shape[1])
            r = Mt @ u - b
            if abs(r[N]) < 1e-12:
                raise InvalidDataError(f"solve_inequality: frame {t}: no blend keeps every value inside its range")
            out[t] = W2[t] + Linv @ (-r[:N] / r[N])
    return out[0] if single else out
