"""``BlendshapeRetargeter``: Chuang's keyshape retargeting (Ch. 3) for any take, as one estimator.

Source keyshapes ``S_k`` (frames of a source take, or a rig's shapes) and the artist's target
counterparts ``B_k`` are paired by name.  Every source frame is decomposed into keyshape weights
and the same weights play the target keyshapes::

    f_t ~ sum_k w_tk (S_k - S_0)        B(t) = B_0 + sum_k w_tk (B_k - B_0)

Solvers (``solver=``):

``"nnls"`` (the thesis, Eq. 3.1/3.2)
    ``0 <= w_t <= hi`` by :func:`~faceretarget.numerics.solve_nnls` (``hi`` the weight range's
    top), with its optional L2, L1 and temporal terms and per-frame masks for missing markers.  Exact and
    interpretable when the keyshapes come from the take being retargeted (the thesis's workflow):
    every frame then lies in the cone of the keys.  A *new* take usually does not (a jaw-open frame
    is not a non-negative sum of ROM frames that each mix jaw and smile), and there it loses
    a third of the motion (P1: 29-37 % ``rel_motion_pct``).
``"signed"`` (default)
    Least squares in the keys' span, weights of either sign, so a new take is expressed by
    differences of keys as well as sums; the minimum-norm solution where keys are dependent.
    Per-frame masks are honoured (each mask pattern solved on the rows present).  The weights then
    go into the weight range as :class:`~faceretarget.cloning.ExpressionCloner` does: per frame, the
    in-range weights whose *target* face is nearest to the unconstrained one (box-constrained least
    squares in the target keyshapes' metric, :func:`~faceretarget.numerics.solve_bounded`).

Weight range (``weight_range=``, default ``"auto"``): [0, 1] when the keyshapes are an
ARKit/FACS-style rig's own shapes, :data:`~faceretarget.numerics.EXAMPLE_RANGE` for example-based
keyshapes; ``None`` for unconstrained ``"signed"`` weights (``"nnls"`` then has no upper bound).
``"nnls"`` needs a range starting at 0.  A weight filter (``filter_level``) is followed by a clip to
the range, so every output stays inside it.

Denoising (``denoise="auto"``): the capture noise of the take is estimated from its own spectrum
(:func:`~faceretarget.numerics.estimate_noise_sigma`) and the coordinates of the frames in
the keys' span are smoothed by the take-adaptive SURE/Whittaker ensemble of
:func:`~faceretarget.numerics.denoise_take` (the same as ``ExpressionCloner``'s
``"temporal"`` method).  ``denoise=False`` disables it, a float gives the noise sigma.  With
``"signed"`` it acts on the solved span coordinates, so masked frames are denoised too; with
``"nnls"`` it acts on the frames before the solve and needs a complete take.

Regions (``regions=``): a :class:`~faceretarget.retarget.Regions`, ``"upper-lower"`` for
the default split, or ``None``.  Each region is solved on its own feature points and the target
keyshapes are split by the regions' smooth memberships, so :attr:`target_keys_` then holds ``R x K``
shapes named ``key@region`` and :meth:`transform` returns ``(T, R x K)`` weights.

After the solve ``filter_level`` (0 = none) low-passes the weight curves
(:func:`~faceretarget.numerics.temporal_filter`) and :attr:`RetargetResult.extremes_removed`
reports what that cost the curves' peaks.
"""

from __future__ import annotations

import copy
import warnings
from dataclasses import dataclass

import numpy as np

from ..base import Model, WeightsResult
from ..errors import InvalidDataError, MissingShapeError, SingularKeysError, TopologyError
from ..headpose import HeadPose
from ..numerics import (
    AlignResult,
    RigidAligner,
    auto_weight_range,
    denoise_take,
    estimate_noise_sigma,
    extremes_removed,
    fit_rigid,
    range_metric,
    solve_bounded,
    solve_nnls,
    temporal_filter,
)
from ..performance import Performance
from ..rig import Rig, resolve_features
from ..timebase import infer_fps
from ._regions import Regions, default_regions

__all__ = ["BlendshapeRetargeter", "RetargetResult", "SOLVERS"]

SOLVERS = ("signed", "nnls")


@dataclass(eq=False)
class RetargetResult(WeightsResult):
    """What :meth:`BlendshapeRetargeter.transform` gives for one take.

    Attributes
    ----------
    weights : (T, W) float
        Weights of :attr:`BlendshapeRetargeter.target_keys_`, columns named by ``names``.
    names : list of str
    times : (T,) float
    noise_sigma : float
        Capture noise estimated (or given) in the take, in the source's units.
    extremes_removed : float
        Share of the weight curves' extremes removed by ``filter_level``.
    alignment : AlignResult or None
        The head-motion removal of a marker take (its pose and residuals).
    head : HeadPose or None
        The take's head motion (its own, or the one removed from the markers).
    audio, audio_rate, source
        Carried from the input take.
    """

    weights: np.ndarray
    names: list[str]
    times: np.ndarray
    noise_sigma: float = 0.0
    extremes_removed: float = 0.0
    alignment: AlignResult | None = None
    head: HeadPose | None = None
    audio: np.ndarray | None = None
    audio_rate: float | None = None
    source: str = "retarget"
    default_fps = 60.0


class BlendshapeRetargeter(Model):
    """Retarget takes through paired source and target keyshapes.

    Parameters
    ----------
    solver : {"signed", "nnls"}
        See the module docstring.
    features : ``"auto"``, ``"landmarks"``, ``"all"`` or (P,) int
        Source points the solve looks at: ``"auto"`` takes the rig's 68 landmarks when the source
        keys have them, else every point (marker sets).
    weight_range : "auto", (lo, hi) or None
        Range every weight stays in (module docstring); decided at :meth:`fit` for ``"auto"``.
    l2, l1, smooth : float
        Optional terms of :func:`solve_nnls` (``"nnls"`` only, except ``l2``: ridge for both).
    denoise : ``"auto"``, bool or float
        See the module docstring.
    filter_level : float
        Low-pass level of the weight curves after the solve (0 = none).
    regions : Regions, ``"upper-lower"`` or None
        Face regions solved separately.
    align : bool
        Remove rigid head motion of marker takes (:class:`RigidAligner` onto the source neutral)
        before solving.
    rigid_subset : sequence of str or int, optional
        The markers that move with the skull (chosen automatically when omitted).

    Attributes
    ----------
    names_ : list of str
        Keyshape names (weight columns without regions).
    weight_names_ : list of str
        Names of the columns :meth:`transform` returns.
    target_keys_ : Rig
        The target keyshapes in the order of those columns (split by region: ``key@region``).
    regions_ : Regions or None
        The regions, fitted to the keys.
    weight_range_ : (lo, hi) or None
        The range in force.
    range_metric_ : (R x K, R x K) float
        Upper Cholesky factor of the target keyshapes' Gram matrix (``"signed"``'s in-range metric).
    """

    def __init__(self, solver: str = "signed", *, features="auto", weight_range="auto",
                 l2: float = 0.0, l1: float = 0.0, smooth: float = 0.0, denoise="auto",
                 filter_level: float = 0.0, regions: Regions | str | None = None, align: bool = True,
                 rigid_subset=None) -> None:
        if solver not in SOLVERS:
            raise InvalidDataError(f"unknown solver '{solver}', use one of {', '.join(SOLVERS)}")
        self.solver = solver
        self.features = features
        self.weight_range = weight_range
        self.l2 = l2
        self.l1 = l1
        self.smooth = smooth
        self.denoise = denoise
        self.filter_level = filter_level
        self.regions = regions
        self.align = align
        self.rigid_subset = rigid_subset

    # ------------------------------------------------------------------ fitting
    def fit(self, source_keys: Rig, target_keys: Rig, source_labels: list[str] | None = None) -> BlendshapeRetargeter:
        """Pair the keyshapes by name and prepare the solve.

        Parameters
        ----------
        source_keys : Rig
            Source neutral and keyshapes (a rig, or point sets read with
            :func:`~faceretarget.io.read_keyshapes`).
        target_keys : Rig
            Target neutral and keyshapes; every source keyshape needs one of the same name.
        source_labels : list of str, optional
            Marker labels of the source points (to match takes and regions by label).
        """
        names = list(source_keys.names)
        if not names:
            raise InvalidDataError(f"{source_keys.name}: no keyshapes besides the neutral")
        missing = [n for n in names if n not in target_keys]
        if missing:
            raise MissingShapeError(f"{target_keys.name}: no target keyshape for source keyshape(s) "
                                    f"{', '.join(missing[:8])}{' ...' if len(missing) > 8 else ''}")
        spec = self.features
        if isinstance(spec, str) and spec == "auto":
            spec = "landmarks" if source_keys.landmarks is not None and len(source_keys.landmarks) else "all"
        idx = resolve_features(spec, source_keys.n_vertices, source_keys.landmarks, who=source_keys.name)
        tk = target_keys.subset(names) if list(target_keys.names) != names else target_keys
        self.weight_range_ = self._range(names)
        self.names_ = names
        self.feature_idx_ = idx
        self.source_labels_ = list(source_labels or [])
        self.source_neutral_ = source_keys.neutral.vertices.copy()
        self.source_unit_ = source_keys.unit
        K = source_keys.deltas[:, idx].reshape(len(names), -1).T              # (D, N)
        self.K_ = K
        scale = float(np.sqrt((K**2).sum(axis=0).mean()))
        if scale == 0:
            raise SingularKeysError(f"{source_keys.name}: every keyshape equals the neutral at the feature points")
        self.key_scale_ = scale
        # regions
        reg = copy.deepcopy(self.regions)                                      # never change a parameter
        pts0 = self.source_neutral_[idx]
        if isinstance(reg, str):
            if reg not in ("upper-lower", "default"):
                raise InvalidDataError(f"unknown regions '{reg}': use 'upper-lower', a Regions or a JSON file")
            lm68 = (source_keys.landmarks is not None and len(idx) == 68
                    and np.array_equal(idx, np.asarray(source_keys.landmarks)))
            reg = default_regions(pts0, landmarks68=lm68)
        if reg is not None:
            reg.fit(len(idx), tk.neutral.vertices, labels=self.source_labels_ or None, deltas=tk.deltas,
                    landmarks=tk.landmarks, source_points=pts0)
            self.regions_ = reg
            self.region_rows_ = reg.source_idx_
            deltas = reg.split(tk.deltas)                                      # (R x K, Vt, 3)
            wnames = [f"{n}@{r}" for r in reg.names for n in names]
            self.target_keys_ = Rig(tk.neutral, wnames, deltas, tk.unit, tk.landmarks, None,
                                    f"{tk.name}:regions")
            self.weight_names_ = wnames
        else:
            self.regions_ = None
            self.region_rows_ = [np.arange(len(idx))]
            self.target_keys_ = tk
            self.weight_names_ = names
        self._prepare()
        self.range_metric_ = range_metric(self.target_keys_.deltas.reshape(self.target_keys_.n_shapes, -1).T)
        return self

    def _range(self, names: list[str]) -> tuple[float, float] | None:
        """The weight range for keyshapes ``names``; ``"nnls"`` keeps 0 as its floor."""
        wr = auto_weight_range(self.weight_range, names)
        if self.solver == "nnls":
            if wr is None:
                return (0.0, np.inf)
            if self.weight_range == "auto" or (isinstance(self.weight_range, str)
                                               and self.weight_range.strip().lower() == "auto"):
                return (0.0, wr[1])
            if wr[0] != 0:
                raise InvalidDataError(f"the 'nnls' solver keeps weights >= 0; weight range {wr[0]:g} "
                                       f"{wr[1]:g} needs the 'signed' solver")
        return wr

    def _prepare(self) -> None:
        """Per-region span bases of the keys (for the signed solve and the denoiser)."""
        self.spans_ = []
        for rows in self.region_rows_:
            cols = (rows[:, None] * 3 + np.arange(3)).reshape(-1)
            Kr = self.K_[cols]
            U, S, Vt = np.linalg.svd(Kr, full_matrices=False)
            tol = 1e-9 * S[0] if S.size and S[0] > 0 else 0.0
            rank = int((S > tol).sum())
            self.spans_.append((cols, U[:, :rank], S[:rank], Vt[:rank]))

    # ------------------------------------------------------------------ applying
    def source_features(self, perf_or_array, labels: list[str] | None = None
                        ) -> tuple[np.ndarray, np.ndarray | None, AlignResult | None]:
        """Feature displacements ``(T, D)`` of a take (NaN where a marker is missing), its times, and
        the head-motion removal of a marker take."""
        self._check_fitted("source_features")
        times = None
        src = "input"
        alignment = None
        if isinstance(perf_or_array, Performance):
            perf = perf_or_array
            src = perf.source
            times = perf.times
            if perf.kind == "weights":
                raise InvalidDataError(f"{src}: a weight take must be played on its source rig first "
                                       "(faceretarget retarget --source-rig, or Rig.evaluate)")
            flat = perf.kind == "points" and perf.points.shape[2] == 2
            if perf.kind == "points" and not flat and self.align and perf.points.shape[1] >= 4:
                alignment = self._aligned(perf)
                perf = alignment.take
            arr = perf.data()
            if flat:                              # 2-D tracks: image-plane keyshapes (z = 0)
                if np.abs(self.source_neutral_[:, 2]).max() > 0:
                    raise InvalidDataError(f"{src}: the take has 2-D points but the source keyshapes are 3-D; "
                                           "select keyshapes from a 2-D take (they are exported with z = 0)")
                arr = np.concatenate([arr, np.zeros(arr.shape[:2] + (1,))], axis=2)
            labels = perf.labels if perf.kind == "points" else None
        else:
            arr = np.asarray(perf_or_array, dtype=np.float64)
        if arr.ndim == 2:
            arr = arr[None]
        if arr.ndim != 3 or arr.shape[2] != 3:
            raise InvalidDataError(f"{src}: expected frames of shape (T, V, 3), got {arr.shape}")
        V, P = len(self.source_neutral_), len(self.feature_idx_)
        if labels and self.source_labels_ and labels != self.source_labels_:
            missing = [s for s in self.source_labels_ if s not in labels]
            if missing:
                raise TopologyError(f"{src}: marker(s) {', '.join(missing[:8])} of the source keyshapes are "
                                    "not in the take")
            arr = arr[:, [labels.index(s) for s in self.source_labels_]]
        if arr.shape[1] == V:
            pts = arr[:, self.feature_idx_]
            rest = self.source_neutral_[self.feature_idx_]
        elif arr.shape[1] == P:
            pts = arr
            rest = self.source_neutral_[self.feature_idx_]
        else:
            raise TopologyError(f"{src}: frames have {arr.shape[1]} points; the source keyshapes have {V} "
                                f"vertices and {P} feature points")
        return (pts - rest).reshape(len(pts), -1), times, alignment

    def _aligned(self, perf: Performance) -> AlignResult:
        """Remove the take's head motion, then place its head frame on the source keys' neutral."""
        al = RigidAligner(subset=self.rigid_subset)
        res = al.fit_transform(perf)
        if len(self.source_neutral_) == perf.points.shape[1]:
            # one rigid move of the whole aligned take: its rigid subset onto the keys' neutral
            sub = al.subset_
            R, t, _ = fit_rigid(al.reference_, self.source_neutral_[sub][None])[:3]
            if np.isfinite(R).all():
                res.take = res.take.with_points(res.take.points @ R[0].T + t[0])
        return res

    def _sigma(self, F: np.ndarray) -> float:
        if self.denoise is False or self.denoise is None:
            return 0.0
        if self.denoise is True or (isinstance(self.denoise, str) and self.denoise == "auto"):
            Fc = F[np.isfinite(F).all(axis=1)]
            return estimate_noise_sigma(Fc) if len(Fc) >= 8 else 0.0
        s = float(self.denoise)
        if s < 0:
            raise InvalidDataError(f"denoise sigma must be >= 0, got {s}")
        return s

    def transform(self, perf_or_array, times: np.ndarray | None = None) -> RetargetResult:
        """Keyshape weights of a take (:class:`RetargetResult`; ``.weights`` is ``(T, len(weight_names_))``).

        Parameters
        ----------
        perf_or_array : Performance or (T, V, 3) / (T, P, 3) array
            Source meshes, feature points or markers (NaN for a missing marker).
        times : (T,) float, optional
            Frame times for arrays (the denoiser and the filter need them; default 60 fps).
        """
        F, ptimes, alignment = self.source_features(perf_or_array)
        if times is None:
            times = ptimes if ptimes is not None else np.arange(len(F)) / 60.0
        times = np.asarray(times, dtype=np.float64)
        sigma = self._sigma(F)
        finite = np.isfinite(F)
        present = finite.reshape(len(F), -1, 3).all(axis=2)                   # (T, P)
        out = []
        for cols, U, S, Vt in self.spans_:
            rows = cols[::3] // 3
            Fr = F[:, cols]
            pr = present[:, rows]
            if self.solver == "signed":
                W = self._signed(Fr, pr, U, S, Vt, cols, times, sigma)
            else:
                W = self._nnls(Fr, pr, U, cols, times, sigma)
            out.append(W)
        W = np.hstack(out)
        if self.solver == "signed" and self.weight_range_ is not None:
            lo, hi = self.weight_range_
            W = solve_bounded(self.range_metric_, W @ self.range_metric_.T, lo, hi)
        removed = 0.0
        if self.filter_level and len(W) >= 4:
            Wf = temporal_filter(W, self.filter_level, infer_fps(times, default=60.0))
            removed = extremes_removed(W, Wf)
            W = Wf
            if self.weight_range_ is not None:
                W = np.clip(W, *self.weight_range_)
        res = RetargetResult(W, list(self.weight_names_), times, sigma, removed, alignment)
        if isinstance(perf_or_array, Performance):
            p = perf_or_array
            res.carry(p)                     # head, audio, timecode, curves of the input take
            res.head = alignment.take.head if alignment is not None and p.head is None else p.head
        return res

    def _signed(self, Fr, pr, U, S, Vt, cols, times, sigma):
        K = self.K_[cols]
        l2 = float(self.l2)
        T = len(Fr)
        if pr.all():
            if l2 > 0:
                C = (Fr @ U) * (S**2 / (S**2 + l2))
            else:
                C = Fr @ U
        else:
            # each mask pattern on its own rows: coordinates of the least-squares fit in the span
            C = np.zeros((T, U.shape[1]))
            pats, inv = np.unique(pr, axis=0, return_inverse=True)
            inv = inv.reshape(-1)
            for p_i, pat in enumerate(pats):
                fr = np.flatnonzero(inv == p_i)
                if not pat.any():
                    continue
                rc = np.flatnonzero(np.repeat(pat, 3))
                Kp = K[rc]
                G = Kp.T @ Kp
                G += (l2 + 1e-12 * max(np.trace(G), 1e-300)) * np.eye(G.shape[0])
                Wp = np.linalg.solve(G, Kp.T @ Fr[np.ix_(fr, rc)].T).T        # (n, N)
                C[fr] = Wp @ (Vt.T * S)
        if sigma > 0 and T >= 8:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", RuntimeWarning)
                C, _ = denoise_take(C, times, sigma=sigma)
        return (C / S) @ Vt

    def _nnls(self, Fr, pr, U, cols, times, sigma):
        K = self.K_[cols]
        if sigma > 0 and pr.all() and len(Fr) >= 8:
            C = Fr @ U
            Cd, _ = denoise_take(C, times, sigma=sigma)
            Fr = Fr + (Cd - C) @ U.T                                          # denoise inside the span only
        mask = None if pr.all() else pr
        Fr = np.where(np.isfinite(Fr), Fr, 0.0) if mask is not None else Fr
        upper = self.weight_range_[1] if self.weight_range_ is not None else None
        return solve_nnls(K, Fr, upper=upper, l2=self.l2, l1=self.l1, smooth=self.smooth, mask=mask)

    def blend(self, weights: np.ndarray) -> np.ndarray:
        """Target meshes ``(T, Vt, 3)`` for weights ``(T, len(weight_names_))``: one matrix product."""
        self._check_fitted("blend")
        rig = self.target_keys_
        w = np.atleast_2d(np.asarray(weights, dtype=np.float64))
        if w.shape[1] != rig.n_shapes:
            raise InvalidDataError(f"{w.shape[1]} weight columns for {rig.n_shapes} target keyshapes")
        return (w @ rig.deltas.reshape(rig.n_shapes, -1)).reshape(len(w), -1, 3) + rig.neutral.vertices

    def key_weights(self, weights: np.ndarray) -> np.ndarray:
        """Weights ``(T, K)`` per keyshape from region weights ``(T, R x K)``.

        Each key's region weights are averaged by how much of the key's target motion lies in each
        region (what a rig without split shapes, or a Live Link Face CSV, can hold).
        """
        w = np.atleast_2d(np.asarray(weights, dtype=np.float64))
        if self.regions_ is None:
            return w
        R, N = len(self.regions_), len(self.names_)
        rig = self.target_keys_
        mass = np.abs(rig.deltas).sum(axis=(1, 2)).reshape(R, N)
        share = mass / np.maximum(mass.sum(axis=0, keepdims=True), 1e-300)
        return (w.reshape(len(w), R, N) * share[None]).sum(axis=1)

