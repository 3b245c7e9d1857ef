"""Exact active-set methods for a batch of box-constrained QPs, vectorised over the frames of a take.

Both solve ``min 1/2 x'Gx - b_t'x, 0 <= x <= ub`` for every row ``b_t`` of ``B`` (one frame each)
and repeatedly solve, for every unfinished frame, the equality-constrained problem on its free set
(the stacked solves of :func:`~._nnls_linalg._solve_fixed`):

* **Block principal pivoting** (Kim & Park 2011, "Fast nonnegative matrix factorization: an
  active-set-like method and comparisons"; Judice & Pires 1994 for upper bounds), the default:
  every frame starts from the signs of its unconstrained solution and exchanges all variables that
  break the KKT conditions at once (free but outside the box, at a bound with a gradient pointing
  inside); a frame whose count of violations has not fallen for three iterations exchanges only
  its last violator (Murty's rule).  Most frames finish in three to five iterations
  (:func:`_bpp`).
* **Lawson-Hanson** (BVLS with upper bounds), for strongly correlated keyshapes with sparse
  solutions (keys chosen among the frames of a take, dependent key sets), where full exchanges
  oscillate: chosen when, on a probe of 32 frames, pivoting needs more than 8 solves per frame,
  or more than 5 and more than Lawson-Hanson does; also used to finish any frame pivoting has not
  settled in 20 iterations.  Each frame keeps a
  feasible point and frees one variable per step, so the objective falls at every step.  Frames
  run in chunks of 8 consecutive frames, each starting from the free set of the previous one
  (consecutive frames of a take share most of it; :func:`_lh`).

:func:`_pivoting_wins` probes which of the two a take needs and :func:`_active_set_solve` runs it;
:func:`~._nnls_box_qp._box_qp` calls them when the compiled kernel does not solve the take.
"""

from __future__ import annotations

import numpy as np

from ._nnls_linalg import _mm, _solve_fixed


# ----------------------------------------------------------------------------- block principal pivoting
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


# ----------------------------------------------------------------------------- Lawson-Hanson
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


# ----------------------------------------------------------------------------- choice between them
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
