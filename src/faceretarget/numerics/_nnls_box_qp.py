"""Exact box-constrained QPs of every frame of a take: compiled kernel or vectorised active-set methods.

:func:`_box_qp` solves ``min 1/2 x'Gx - b_t'x, 0 <= x <= ub`` for every row ``b_t`` of ``B``.

With ``numba`` installed (``make fast``) a compiled kernel (:mod:`._nnls_numba`) solves the frames
one after another, upper bounds included (:func:`_compiled_box_qp`): bounded
Lawson-Hanson (BVLS), each frame starting from the previous frame's point and sets, with the
Cholesky factor of ``G`` on the free set updated (not recomputed) when a variable enters or
leaves.  Consecutive frames of a take share most of their sets, so a frame typically costs one or
two solves on its free set (measured: 1.1 to 4 on every real P1 problem, bounded or not) and well
under a microsecond to a few microseconds, where ``scipy.optimize.nnls`` / ``lsq_linear`` pay tens
of microseconds to milliseconds of Python per frame.  A probe on the first 64 frames hands takes
whose sets change at every frame (dense weights, more than 10 solves per frame) to block pivoting,
which exchanges many variables per step.

With ill-conditioned keys (their least-squares data :class:`~._nnls_linalg._LSData` given) the
compiled kernel decides the sets at ``1e-4`` of the tolerance, checks every frame against the exact
KKT conditions and finishes a frame that fails in exact mode (every solve refined, every gradient
exact).

Without numba, or when the probe hands a take over, the vectorised methods of
:mod:`._nnls_active_set` solve it, and with ill-conditioned keys every frame's optimum gets one
step of iterative refinement with the exact gradient.
"""

from __future__ import annotations

import numpy as np

from ..optional import optional_import
from ._nnls_active_set import _active_set_solve, _pivoting_wins
from ._nnls_linalg import _LSData, _solve_fixed

__all__ = ["compile_kernels"]

_EXACT_TOL = 1e-4
# free-set solves per frame (on the first 64 frames of a take) up to which the compiled kernel goes
# on; above, the vectorised NumPy methods (block pivoting) solve the take.  Measured on 2,028-frame
# synthetic takes with dense, often-changing weights (bench/nnls.py "keyshapes"): 14 solves per
# frame with 40 keys, kernel 40 ms vs pivoting 37 ms; 30 with 83 keys, 450 vs 310 ms.  Every real
# P1 problem (keys chosen among a take's frames, also with the range -1..2) needs 1.1 to 4.
_COMPILED_MAX_SOLVES = 10
_COMPILED_PROBE = 64


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
