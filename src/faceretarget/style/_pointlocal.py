"""Point-local style translation: the change an emotion makes at a feature point, as a function of
the face around that point (our addition to Chuang 2004, Ch. 2).

A bilinear model maps a whole frame in one style to a whole frame in another by one linear map
of the content.  When emotion and speech interact (an angry mouth is not the neutral mouth plus a
constant offset: how the emotion shows at the lips depends on how open they are), that map has to
be learned from the training frames, and with a few hundred frames of ``3 P`` numbers it
extrapolates poorly to mouth shapes the training part did not show.  Faces are local: the change
at a lip corner depends mostly on where that lip corner and its neighbours are.  The point-local
translation learns, for every feature point ``v`` separately, the change from a source style ``s``
to a target style ``t``::

    x_t[v] - x_s[v] = f_v(u),   u = the source frame's points N(v) (v and its m - 1 nearest
                                    neighbours on the mean face), 3 m numbers

with ``f_v`` an affine map (least squares over the training frames) plus the mean of what the
affine map leaves at the ``k`` training frames nearest to ``u`` (in the 3 m numbers of that point's
neighbourhood, where nearest neighbours are meaningful, unlike in the whole frame's ``3 P``).  ``m``
and ``k`` (0: the affine map alone) are chosen by the same blocked cross-validation as the bilinear
model's settings (:func:`score_point_local`, called by :func:`~._select.select_settings`), which
keeps this translation only when it predicts the held-out blocks better than the bilinear model
with its correction.

It needs frames of points ``(P, 3)`` (feature points, markers, landmarks, or a mesh of at most
:data:`MAX_POINTS` vertices); weight takes keep the bilinear translation.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

__all__ = ["POINT_GRID", "MAX_POINTS", "point_count", "neighbours", "PointMap", "fit_point_map",
           "score_point_local"]

#: Searched values: neighbourhood size ``m`` and nearest training frames ``k`` (0: affine only).
POINT_GRID: dict[str, tuple] = {"neighbours": (1, 3), "frames": (0, 3, 8, 20)}
#: Frames with more points than this keep the bilinear translation (cost grows with the points).
MAX_POINTS = 512
#: Ridge of the affine part, relative to the mean squared (standardised) input: a numerical guard.
LINEAR_RIDGE = 1e-3


def point_count(frame_shape) -> int | None:
    """``P`` when frames are ``(P, 3)`` points with ``P <= MAX_POINTS``, else None."""
    fs = tuple(int(v) for v in frame_shape)
    if len(fs) == 2 and fs[1] == 3 and 1 <= fs[0] <= MAX_POINTS:
        return fs[0]
    return None


def neighbours(rest: np.ndarray, m: int) -> np.ndarray:
    """``(P, m)`` indices: every point and its ``m - 1`` nearest others on ``rest`` ``(P, 3)``."""
    rest = np.asarray(rest, np.float64).reshape(-1, 3)
    m = int(min(max(int(m), 1), len(rest)))
    d = np.linalg.norm(rest[:, None] - rest[None], axis=-1)
    d[np.diag_indices_from(d)] = -1.0                                   # the point itself first
    return np.argsort(d, axis=1, kind="stable")[:, :m]


def _inputs(X: np.ndarray, nb: np.ndarray) -> np.ndarray:
    """``(P, n, 3 m)`` local inputs of frames ``X`` ``(n, P, 3)``."""
    n = len(X)
    return np.ascontiguousarray(X[:, nb].reshape(n, nb.shape[0], -1).transpose(1, 0, 2))


@dataclass
class _Prep:
    """A source style's training inputs, centred and scaled per point, with their affine features."""

    nb: np.ndarray          # (P, m)
    mu: np.ndarray          # (P, d)
    sc: np.ndarray          # (P,) rms spread of u about mu
    U: np.ndarray           # (P, n, d) standardised
    F: np.ndarray           # (P, n, d + 1) affine features [1, U]
    Gl: np.ndarray          # (P, d + 1, d + 1) their normal matrix with the guard ridge


def _prepare(Xs: np.ndarray, nb: np.ndarray) -> _Prep:
    U = _inputs(Xs, nb)
    mu = U.mean(1)
    U = U - mu[:, None]
    sc = np.sqrt(np.mean(np.sum(U * U, axis=-1), axis=1))
    sc = np.where(sc > 1e-12 * max(float(sc.max(initial=0.0)), 1e-300), sc, 1.0)
    U = U / sc[:, None, None]
    P, n, d = U.shape
    F = np.concatenate([np.ones((P, n, 1)), U], axis=-1)
    Gl = np.matmul(F.transpose(0, 2, 1), F)
    Gl[:, np.arange(1, d + 1), np.arange(1, d + 1)] += LINEAR_RIDGE * n
    return _Prep(nb, mu, sc, U, F, Gl)


def _features(prep: _Prep, Xq: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Standardised inputs ``(P, T, d)`` and affine features ``(P, T, d + 1)`` of frames ``Xq``."""
    Uq = (_inputs(Xq, prep.nb) - prep.mu[:, None]) / prep.sc[:, None, None]
    return Uq, np.concatenate([np.ones(Uq.shape[:2] + (1,)), Uq], axis=-1)


def _affine(prep: _Prep, R: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Affine least squares of ``R`` ``(P, n, c)``: ``(W (P, d + 1, c), residual (P, n, c))``."""
    W = np.linalg.solve(prep.Gl, np.matmul(prep.F.transpose(0, 2, 1), R))
    return W, R - np.matmul(prep.F, W)


def _nearest(prep: _Prep, Uq: np.ndarray, k: int) -> np.ndarray:
    """``(P, T, k)`` indices of the ``k`` training frames nearest to every query, per point."""
    n = prep.U.shape[1]
    k = int(min(k, n))
    out = np.empty(Uq.shape[:2] + (k,), np.int64)
    for v in range(len(Uq)):
        _, ii = cKDTree(prep.U[v]).query(Uq[v], k=k, workers=-1)
        out[v] = np.asarray(ii).reshape(Uq.shape[1], k)
    return out


@dataclass
class PointMap:
    """The fitted point-local change from one style to another (see the module docstring)."""

    prep: _Prep
    W: np.ndarray                   # (P, d + 1, 3)
    k: int
    R: np.ndarray                   # (P, n, 3) what the affine map leaves on the training frames

    def predict(self, Xq: np.ndarray) -> np.ndarray:
        """The change ``(T, P, 3)`` at source frames ``Xq`` ``(T, P, 3)``."""
        Uq, Fq = _features(self.prep, np.asarray(Xq, np.float64))
        out = np.matmul(Fq, self.W)
        if self.k > 0:
            ii = _nearest(self.prep, Uq, self.k)
            out = out + np.take_along_axis(self.R[:, :, None, :], ii[..., None], axis=1).mean(2)
        return out.transpose(1, 0, 2)


def fit_point_map(Xs: np.ndarray, Xt: np.ndarray, rest: np.ndarray, spec: tuple) -> PointMap:
    """Fit the change ``Xt - Xs`` (paired frames ``(n, P, 3)``) for ``spec = ("points", m, k)``."""
    _, m, k = spec
    Xs = np.asarray(Xs, np.float64)
    prep = _prepare(Xs, neighbours(rest, int(m)))
    W, R = _affine(prep, (np.asarray(Xt, np.float64) - Xs).transpose(1, 0, 2))
    return PointMap(prep, W, int(k), R)


def score_point_local(X: dict[str, np.ndarray], splits, rest: np.ndarray, grid: dict | None = None) -> dict:
    """Cross-validated squared error of every point-local candidate on the known-expression task.

    Parameters
    ----------
    X : dict of str to (C, P * 3) float
        Aligned training frames of every style.
    splits : list of (train indices, validation indices)
        The folds of :func:`~._select.select_settings`.
    rest : (P, 3) float
        The mean face (neighbourhoods).
    grid : dict, optional
        Overrides of :data:`POINT_GRID`.

    Returns
    -------
    dict
        ``("points", m, k)`` -> summed squared error over folds and ordered style pairs (the same
        sum :func:`~._select.select_settings` scores the bilinear candidates with).
    """
    g = {**POINT_GRID, **(grid or {})}
    styles = list(X)
    P = int(np.asarray(rest).reshape(-1, 3).shape[0])
    F = {s: np.asarray(x, np.float64).reshape(len(x), P, 3) for s, x in X.items()}
    ks = sorted({int(k) for k in g["frames"]})
    score = {("points", int(m), k): 0.0 for m in g["neighbours"] for k in ks}
    nbs = {int(m): neighbours(rest, int(m)) for m in g["neighbours"]}
    kmax = max(ks)
    for tr, va in splits:
        for m, nb in nbs.items():
            for s in styles:
                targets = [t for t in styles if t != s]
                prep = _prepare(F[s][tr], nb)
                W, R = _affine(prep, np.concatenate([(F[t][tr] - F[s][tr]).transpose(1, 0, 2) for t in targets],
                                                    axis=-1))
                Uq, Fq = _features(prep, F[s][va])
                pred = np.matmul(Fq, W)                                  # (P, nv, 3 (S - 1))
                truth = np.concatenate([(F[t][va] - F[s][va]).transpose(1, 0, 2) for t in targets], axis=-1)
                ii = _nearest(prep, Uq, kmax) if kmax > 0 else None
                for k in ks:
                    p = pred
                    if k > 0:
                        kk = min(k, ii.shape[2])
                        p = pred + np.take_along_axis(R[:, :, None, :], ii[:, :, :kk, None], axis=1).mean(2)
                    score[("points", m, k)] += float(np.sum((p - truth) ** 2))
    return score
