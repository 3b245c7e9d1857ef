"""Rigid head-motion removal from marker takes (Chuang Ch. 3).

Before facial motion can be analysed, the head's rigid motion has to be taken out of the marker
trajectories.  As in the thesis, a subset of markers that move (almost) rigidly with the skull is
chosen; in every frame the least-squares rotation and translation taking a reference pose of that
subset onto the frame's markers is solved for (Kabsch / Umeyama without scale, by SVD, batched over
all frames), and its inverse is applied to every marker, leaving the face in head coordinates.

The subset is given by the user (labels or indices) or chosen by :func:`select_rigid_markers`:
for every pair of markers the standard deviation over the take of their distance is measured (zero
for two points of one rigid body); starting from all markers, the marker whose mean variation to
the remaining markers is largest is dropped, again and again, until ``n`` remain.  Dropping one at a
time lets the remaining scores be re-measured without the markers that moved most.

Pose convention: with ``R`` = :attr:`AlignResult.rotations` ``[t]``, ``d`` =
:attr:`AlignResult.translations` ``[t]`` and ``c`` = :attr:`RigidAligner.center_` (the centroid of
the subset's reference pose), a point ``h`` in head coordinates is at ``x = R (h - c) + c + d`` in
frame ``t``.  So ``d`` is how far the head (its subset centroid) moved, independent of where the
capture volume's origin is, and ``R`` is the head's rotation about that centroid;
:meth:`AlignResult.pose_matrices` gives the same pose as ``(T, 4, 4)`` matrices, and the aligned
take carries it as its :class:`~faceretarget.headpose.HeadPose` (in the package's axes, metres).
"""

from __future__ import annotations

import warnings
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation  # noqa: F401  (the examples use it)

from ..base import Model
from ..errors import DataWarning, InvalidDataError, format_ranges
from ..headpose import HeadPose
from ..performance import Performance
from ..units import normalize_unit, scale
from ._rotations import nearest_rotation

__all__ = ["RigidAligner", "AlignResult", "fit_rigid", "similarity_fit", "select_rigid_markers"]


def similarity_fit(reference: np.ndarray, points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Scale, rotation and translation with ``points[t] ~ s_t reference @ R_t.T + c_t`` (Umeyama).

    Parameters
    ----------
    reference : (S, 3) or (T, S, 3) float
        One reference for all frames, or one per frame.
    points : (T, S, 3) float

    Returns
    -------
    s : (T,) float
    R : (T, 3, 3) float, proper rotations
    c : (T, 3) float
    """
    X = np.asarray(points, dtype=np.float64)
    Y = np.broadcast_to(np.asarray(reference, dtype=np.float64), X.shape)
    mx, my = X.mean(axis=1), Y.mean(axis=1)
    Xc, Yc = X - mx[:, None], Y - my[:, None]
    C = np.einsum("tsi,tsj->tij", Xc, Yc)                # cross-covariance, points x reference
    U, S, Vt = np.linalg.svd(C)
    d = np.sign(np.linalg.det(U @ Vt))
    D = np.ones((len(X), 3))
    D[:, 2] = d
    R = np.einsum("tij,tj,tjk->tik", U, D, Vt)
    s = (S * D).sum(axis=1) / np.maximum((Yc ** 2).sum(axis=(1, 2)), 1e-300)
    c = mx - s[:, None] * np.einsum("tij,tj->ti", R, my)
    return s, R, c


def fit_rigid(reference: np.ndarray, points: np.ndarray, weights: np.ndarray | None = None
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Least-squares rotation and translation ``points[t] ~ reference @ R[t].T + t[t]`` for every frame.

    Weighted Kabsch / Umeyama (no scale) by one batched SVD; reflections are never returned.
    Markers that are NaN in a frame (or in the reference) are left out of that frame's fit.

    Parameters
    ----------
    reference : (S, 3) or (T, S, 3) float
        The pose to move (one for all frames, or one per frame).
    points : (T, S, 3) float
        Where the markers are in each frame; NaN for missing.
    weights : (T, S) or (S,) float, optional
        Non-negative weight of each marker (1 when omitted).

    Returns
    -------
    rotations : (T, 3, 3) float
        Proper rotations (det +1); NaN in frames with fewer than 3 usable markers or with all
        usable markers on one line.
    translations : (T, 3) float
        NaN likewise.
    rms : (T,) float
        Weighted RMS distance between the moved reference and the points, over the markers used.
    n_used : (T,) int
        Markers used in each frame.

    Examples
    --------
    >>> ref = np.array([[0., 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]])
    >>> Rz = np.array([[0., -1, 0], [1, 0, 0], [0, 0, 1]])
    >>> R, t, rms, n = fit_rigid(ref, (ref @ Rz.T + [1, 2, 3])[None])
    >>> bool(np.allclose(R[0], Rz)), t[0].round(6).tolist(), bool(rms[0] < 1e-9), int(n[0])
    (True, [1.0, 2.0, 3.0], True, 4)
    """
    X = np.asarray(points, dtype=np.float64)
    if X.ndim != 3 or X.shape[2] != 3:
        raise InvalidDataError(f"points must be (T, S, 3), got {X.shape}")
    T, S, _ = X.shape
    A = np.broadcast_to(np.asarray(reference, dtype=np.float64), X.shape)
    w = np.ones((T, S)) if weights is None else np.broadcast_to(np.asarray(weights, dtype=np.float64), (T, S))
    ok = np.isfinite(X).all(axis=2) & np.isfinite(A).all(axis=2) & (w > 0)
    w = np.where(ok, w, 0.0)
    X = np.where(ok[..., None], X, 0.0)
    A = np.where(ok[..., None], A, 0.0)
    W = w.sum(axis=1)
    Ws = np.where(W > 0, W, 1.0)[:, None]
    ca = np.einsum("ts,tsi->ti", w, A) / Ws
    cx = np.einsum("ts,tsi->ti", w, X) / Ws
    A0 = A - ca[:, None]
    X0 = X - cx[:, None]
    H = np.einsum("ts,tsi,tsj->tij", w, A0, X0)  # sum_s w a x^T
    U, sv, Vt = np.linalg.svd(H)
    R = nearest_rotation(svd=(np.swapaxes(Vt, 1, 2), np.swapaxes(U, 1, 2)))  # V diag(1, 1, d) U^T
    t = cx - np.einsum("tij,tj->ti", R, ca)
    r = np.einsum("tsj,tij->tsi", A0, R) - X0
    rms = np.sqrt(np.einsum("ts,ts->t", w, (r**2).sum(axis=2)) / Ws[:, 0])
    n_used = ok.sum(axis=1)
    bad = (n_used < 3) | (sv[:, 1] <= 1e-12 * np.maximum(sv[:, 0], 1e-300))
    R[bad] = np.nan
    t[bad] = np.nan
    rms[bad] = np.nan
    return R, t, rms, n_used


def _pair_variation(X: np.ndarray, min_frames: int = 3) -> np.ndarray:
    """(P, P) standard deviation over frames of each pair's distance; inf for pairs seen < min_frames."""
    T, P, _ = X.shape
    V = np.empty((P, P))
    for i in range(P):
        d = np.linalg.norm(X - X[:, i : i + 1], axis=2)  # (T, P), NaN where either is missing
        seen = np.isfinite(d)
        n = seen.sum(axis=0)
        dz = np.where(seen, d, 0.0)
        mean = dz.sum(axis=0) / np.maximum(n, 1)
        var = (np.where(seen, d - mean, 0.0) ** 2).sum(axis=0) / np.maximum(n, 1)
        V[i] = np.where(n >= min_frames, np.sqrt(var), np.inf)
    np.fill_diagonal(V, 0.0)
    return np.maximum(V, V.T)


def select_rigid_markers(points: np.ndarray, n: int = 8, *, min_presence: float = 0.5,
                         max_frames: int = 2000) -> np.ndarray:
    """Indices of the ``n`` markers that move most rigidly together over a take.

    Parameters
    ----------
    points : (T, P, 3) float
        Marker trajectories, NaN for missing samples.
    n : int
        How many markers to keep (at least 3).
    min_presence : float
        Markers present in fewer than this fraction of frames are not considered (unless fewer
        than ``n`` markers qualify, then the ``n`` most present ones are the candidates).
    max_frames : int
        At most this many evenly spaced frames are measured (speed on long takes).

    Returns
    -------
    (n,) int, ascending.

    Notes
    -----
    For every pair ``(i, j)`` the standard deviation over frames of ``|x_i - x_j|`` is measured
    (frames where both are present; pairs seen together in fewer than 3 frames count as
    infinitely variable).  Starting from every candidate marker, the one whose mean variation to
    the other remaining candidates is largest is dropped, repeatedly, until ``n`` remain.

    Examples
    --------
    >>> rng = np.random.default_rng(0)
    >>> base = rng.normal(size=(6, 3)) * 50
    >>> X = np.repeat(base[None], 20, axis=0)
    >>> X[:, 4:] += rng.normal(size=(20, 2, 3)) * 5      # markers 4 and 5 move on their own
    >>> select_rigid_markers(X, 4).tolist()
    [0, 1, 2, 3]
    """
    X = np.asarray(points, dtype=np.float64)
    if X.ndim != 3 or X.shape[2] != 3:
        raise InvalidDataError(f"points must be (T, P, 3), got {X.shape}")
    T, P, _ = X.shape
    if not 3 <= n <= P:
        raise InvalidDataError(f"cannot choose {n} rigid markers from {P} (need 3 <= n <= {P})")
    if T > max_frames:
        X = X[np.linspace(0, T - 1, max_frames).round().astype(int)]
    presence = np.isfinite(X).all(axis=2).mean(axis=0)
    cand = np.flatnonzero(presence >= min_presence)
    if cand.size < n:
        cand = np.sort(np.argsort(-presence, kind="stable")[:n])
    V = _pair_variation(X[:, cand])
    active = list(range(cand.size))
    while len(active) > n:
        sub = V[np.ix_(active, active)]
        score = sub.sum(axis=1) / (len(active) - 1)
        del active[int(np.argmax(score))]
    return cand[np.asarray(active, dtype=int)]




@dataclass(eq=False)
class AlignResult:
    """A take with its rigid head motion removed (:meth:`RigidAligner.transform`).

    Attributes
    ----------
    take : Performance
        ``points`` (T, P, 3) in head coordinates (NaN where the input is NaN, and in every frame
        without a head pose) and ``head``, the pose that was removed (in the package's axes,
        metres; :mod:`faceretarget.headpose`); labels, times, unit, audio and source kept.
    rotations : (T, 3, 3) float
        Per-frame head rotation (head to capture coordinates); NaN in frames with fewer than 3
        subset markers.
    translations : (T, 3) float
        Per-frame displacement of the subset centroid, in the take's unit (module docstring).
    center : (3,) float
        The centre of the rotations (:attr:`RigidAligner.center_`).
    residual : (T,) float
        Per-frame RMS distance, in the take's unit, between the aligned reference and the subset
        markers present: how rigid the subset really was.
    n_used : (T,) int
        Subset markers present in each frame.
    subset_names : str
        The rigid markers, for reports.
    n_subset : int
        How many there are.
    """

    take: Performance
    rotations: np.ndarray
    translations: np.ndarray
    center: np.ndarray
    residual: np.ndarray
    n_used: np.ndarray
    subset_names: str = ""
    n_subset: int = 0

    def pose_matrices(self) -> np.ndarray:
        """(T, 4, 4) head-to-capture transforms: ``x = M[:3, :3] h + M[:3, 3]``."""
        R, d, c = self.rotations, self.translations, self.center
        M = np.zeros((len(R), 4, 4))
        M[:, :3, :3] = R
        M[:, :3, 3] = c + d - np.einsum("tij,j->ti", R, c)
        M[:, 3, 3] = 1.0
        return M

    def report(self, unit: str | None = None) -> str:
        """One line: the subset and the RMS residual (median, 95th percentile, max)."""
        r = self.residual[np.isfinite(self.residual)]
        u = f" {unit}" if unit else ""
        n = self.n_subset
        if not r.size:
            return f"rigid subset ({n}): {self.subset_names}; no frame could be aligned"
        nan = len(self.residual) - r.size
        return (f"rigid subset ({n}): {self.subset_names}; RMS residual median {np.median(r):.3g}{u}, "
                f"95% {np.percentile(r, 95):.3g}{u}, max {r.max():.3g}{u} over {r.size} frame(s)"
                + (f"; {nan} frame(s) without a pose" if nan else ""))


class RigidAligner(Model):
    """Remove rigid head motion from a marker take by aligning a rigid subset of markers.

    Parameters
    ----------
    subset : sequence of str or int, optional
        Labels or indices of markers that move with the skull.  Chosen by
        :func:`select_rigid_markers` when omitted.
    n_auto : int
        Size of the automatically chosen subset.
    reference : ``"median"``, ``"first"``, int or array
        The subset's pose in head coordinates.  ``"median"``: a robust generalised Procrustes
        mean: starting from the first frame with every subset marker present, align every frame
        to the reference and replace it by the per-marker median of the aligned frames (then
        rigidly placed back onto that first frame), up to ``max_iter`` times.  ``"first"``: the first
        frame with every subset marker present.  An int: that frame (every subset marker must be
        present).  An array: positions ``(S, 3)`` of the subset or ``(P, 3)`` of every marker.
    axes : (3, 3) array, optional
        Maps the capture's axes to the package's (+Y up, +Z forward, +X the performer's left) for
        the head pose of the aligned take (:meth:`~faceretarget.headpose.HeadPose.in_axes`); None
        (default): the capture is already in those axes, as the shared takes are.  For a Z-up
        capture with +Y forward and +X to the performer's right, ``[[-1, 0, 0], [0, 0, 1], [0, 1, 0]]``.
    max_iter : int
        Iterations of the ``"median"`` reference.
    min_presence : float
        See :func:`select_rigid_markers`.

    Attributes
    ----------
    subset_ : (S,) int
        Indices of the rigid markers.
    subset_labels_ : list of str
        Their labels (empty when the take has none).
    reference_ : (S, 3) float
        Their pose in head coordinates.
    center_ : (3,) float
        Centroid of ``reference_``, the centre of the head rotations.
    n_points_ : int
        Markers in the take it was fitted on.

    Examples
    --------
    >>> rng = np.random.default_rng(1)
    >>> face = rng.normal(size=(10, 3)) * 40
    >>> ang = np.linspace(0, 0.3, 50)
    >>> Rz = Rotation.from_rotvec(np.c_[0 * ang, 0 * ang, ang]).as_matrix()
    >>> X = np.einsum("tij,pj->tpi", Rz, face) + [5.0, 0, 0]
    >>> al = RigidAligner(n_auto=6).fit(Performance.from_points(X, fps=60))
    >>> out = al.transform(Performance.from_points(X, fps=60)).take
    >>> float(np.abs(out.points - out.points[0]).max()) < 1e-9
    True
    """

    def __init__(self, subset: Sequence[str | int] | None = None, n_auto: int = 8,
                 reference: str | int | np.ndarray = "median", axes: np.ndarray | None = None,
                 max_iter: int = 5, min_presence: float = 0.5) -> None:
        self.subset = subset
        self.n_auto = n_auto
        self.reference = reference
        self.axes = axes
        self.max_iter = max_iter
        self.min_presence = min_presence

    # ------------------------------------------------------------------ helpers
    @staticmethod
    def _points(perf: Performance) -> np.ndarray:
        if perf.points is None or perf.points.shape[2] != 3:
            what = perf.kind if perf.points is None else "2D points"
            raise InvalidDataError(f"{perf.source}: rigid alignment needs 3D marker points, this take "
                                   f"holds {what}")
        return perf.points

    def _resolve_subset(self, perf: Performance) -> np.ndarray:
        P = perf.points.shape[1]
        idx = []
        for s in self.subset:
            if isinstance(s, str):
                if s not in perf.labels:
                    raise InvalidDataError(f"{perf.source}: rigid subset marker '{s}' is not in the take "
                                           f"(markers: {', '.join(perf.labels) or 'unlabelled'})")
                idx.append(perf.labels.index(s))
            else:
                i = int(s)
                if not -P <= i < P:
                    raise InvalidDataError(f"{perf.source}: rigid subset index {i} is outside 0..{P - 1}")
                idx.append(i % P)
        idx = np.asarray(idx, dtype=int)
        if np.unique(idx).size != idx.size:
            raise InvalidDataError(f"{perf.source}: the rigid subset names a marker twice")
        return idx

    def _subset_in(self, perf: Performance) -> np.ndarray:
        """The fitted subset's indices in another take (by label when both are labelled)."""
        if self.subset_labels_ and perf.labels:
            missing = [s for s in self.subset_labels_ if s not in perf.labels]
            if missing:
                raise InvalidDataError(f"{perf.source}: rigid subset marker(s) {', '.join(missing)} "
                                       "are not in this take")
            return np.asarray([perf.labels.index(s) for s in self.subset_labels_], dtype=int)
        if perf.points.shape[1] != self.n_points_:
            raise InvalidDataError(f"{perf.source}: the take has {perf.points.shape[1]} markers, the aligner "
                                   f"was fitted on {self.n_points_} (and one of them has no labels)")
        return self.subset_

    def _first_complete(self, Xs: np.ndarray) -> int | None:
        full = np.flatnonzero(np.isfinite(Xs).all(axis=(1, 2)))
        return int(full[0]) if full.size else None

    def _reference(self, perf: Performance, Xs: np.ndarray) -> np.ndarray:
        ref = self.reference
        names = ", ".join(self.subset_labels_) if self.subset_labels_ else str(self.subset_.tolist())
        if isinstance(ref, str):
            if ref not in ("median", "first"):
                raise InvalidDataError(f"reference must be 'median', 'first', a frame index or an array, got {ref!r}")
            k = self._first_complete(Xs)
            if k is None:
                if ref == "first":
                    raise InvalidDataError(f"{perf.source}: no frame has every rigid subset marker "
                                           f"({names}) present; use reference='median'")
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore", RuntimeWarning)
                    start = np.nanmedian(Xs, axis=0)
            else:
                start = Xs[k]
            if ref == "first":
                return start.copy()
            return self._median_reference(start, Xs)
        if isinstance(ref, int | np.integer):
            k = int(ref)
            if not -len(Xs) <= k < len(Xs):
                raise InvalidDataError(f"{perf.source}: reference frame {k} is outside 0..{len(Xs) - 1}")
            if not np.isfinite(Xs[k]).all():
                raise InvalidDataError(f"{perf.source}: reference frame {k} misses rigid subset marker(s) "
                                       f"({names})")
            return Xs[k].copy()
        arr = np.asarray(ref, dtype=np.float64)
        S, P = self.subset_.size, perf.points.shape[1]
        if arr.shape == (P, 3):
            arr = arr[self.subset_]
        if arr.shape != (S, 3) or not np.isfinite(arr).all():
            raise InvalidDataError(f"reference array must be finite ({S}, 3) or ({P}, 3), got {arr.shape}")
        return arr.copy()

    def _median_reference(self, start: np.ndarray, Xs: np.ndarray) -> np.ndarray:
        ref = start
        scale = float(np.linalg.norm(start - start.mean(axis=0), axis=1).mean()) or 1.0
        for _ in range(self.max_iter):
            R, t, _, _ = fit_rigid(ref, Xs)
            aligned = np.einsum("tsi,tij->tsj", Xs - t[:, None], R)  # R^T (x - t)
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", RuntimeWarning)
                new = np.nanmedian(aligned, axis=0)
            if not np.isfinite(new).all():
                break
            R0, t0, _, _ = fit_rigid(new, start[None])  # keep head coordinates on the starting pose
            if not np.isfinite(R0).all():
                break
            new = new @ R0[0].T + t0[0]
            change = float(np.abs(new - ref).max())
            ref = new
            if change < 1e-9 * scale:
                break
        return ref

    # ------------------------------------------------------------------ API
    def fit(self, perf: Performance) -> RigidAligner:
        """Choose (or look up) the rigid subset and its reference pose from ``perf``; returns self."""
        X = self._points(perf)
        P = X.shape[1]
        if P < 3:
            raise InvalidDataError(f"{perf.source}: rigid alignment needs at least 3 markers, the take has {P}")
        if self.subset is None:
            subset = select_rigid_markers(X, min(self.n_auto, P), min_presence=self.min_presence)
        else:
            subset = self._resolve_subset(perf)
        if subset.size < 3:
            raise InvalidDataError(f"{perf.source}: a rigid subset needs at least 3 markers, got {subset.size}")
        labels = [perf.labels[i] for i in subset] if perf.labels else []
        Xs = X[:, subset]
        absent = np.flatnonzero(~np.isfinite(Xs).all(axis=2).any(axis=0))
        if absent.size:
            which = [labels[i] if labels else str(subset[i]) for i in absent]
            raise InvalidDataError(f"{perf.source}: rigid subset marker(s) {', '.join(which)} are missing in "
                                   "every frame")
        self.subset_, self.subset_labels_, self.n_points_ = subset, labels, P
        self.reference_ = self._reference(perf, Xs)
        self.center_ = self.reference_.mean(axis=0)
        sv = np.linalg.svd(self.reference_ - self.center_, compute_uv=False)
        if sv[1] <= 1e-3 * sv[0]:
            raise InvalidDataError(f"{perf.source}: the rigid subset markers lie on one line; the head "
                                   "rotation about it cannot be found (choose other markers)")
        return self

    def transform(self, perf: Performance) -> AlignResult:
        """``perf`` with the head motion removed, and the motion that was removed (:class:`AlignResult`)."""
        self._check_fitted()
        X = self._points(perf)
        sub = self._subset_in(perf)
        R, t, rms, n = fit_rigid(self.reference_, X[:, sub])
        bad = np.flatnonzero(~np.isfinite(R).all(axis=(1, 2)))
        if bad.size:
            warnings.warn(f"{perf.source}: {bad.size} frame(s) have fewer than 3 usable of the {sub.size} "
                          f"rigid markers, frame(s) {format_ranges(bad, limit=10)}; their head pose and "
                          "stabilised points are NaN", DataWarning, stacklevel=2)
        c = self.center_
        d = t + np.einsum("tij,j->ti", R, c) - c
        points = np.einsum("tpi,tij->tpj", X - (c + d)[:, None], R) + c  # R^T (x - c - d) + c
        to_m = scale(normalize_unit(perf.unit, what=perf.source), "m") if perf.unit else 1.0
        pose = HeadPose.from_matrix(R, d * to_m, source=perf.source)
        if self.axes is not None:
            pose = pose.in_axes(self.axes)
        take = Performance(times=perf.times, fps=perf.fps, points=points, labels=list(perf.labels), head=pose,
                           unit=perf.unit, audio=perf.audio, audio_rate=perf.audio_rate, source=perf.source)
        names = ", ".join(self.subset_labels_) if self.subset_labels_ else str(self.subset_.tolist())
        return AlignResult(take, R, d, c.copy(), rms, n, names, int(sub.size))

    def fit_transform(self, perf: Performance) -> AlignResult:
        """``fit(perf).transform(perf)``."""
        return self.fit(perf).transform(perf)
