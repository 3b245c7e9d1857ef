"""Example-based expression cloning (Pyun et al. 2003) with a take-aware default.

An artist gives key-model pairs: source key-models (expressions of the performer's face, or of a
source rig) and the target character's counterparts.  Every input frame is described by its
feature-point displacements, turned into weights of the key-models, and the target key-models are
blended with those weights, so the output keeps the target's own style.

Three ways to compute the weights (``method``):

``"pyun"``
    The paper, faithfully: PCA parameter vectors (Sec. 3) and cardinal basis weight functions with
    a least-squares linear part and cubic B-spline radial part (Sec. 4), one frame at a time.
``"linear"``
    The cardinal linear part alone, computed in the full feature space (no PCA truncation) as
    the minimum-norm least-squares blend of the key-models.  It is cardinal too (a key-model's own
    features give that key-model weight 1) and, unlike the radial part, it extrapolates sensibly to
    expressions between and beyond the keys.
``"temporal"`` (default)
    ``"linear"`` on the whole take at once with take-adaptive denoising
    (:mod:`faceretarget.numerics`): capture noise is independent from frame to frame, the
    face is not, and the noise level is estimated from the take itself.  On a clean take it equals
    ``"linear"``.

Whatever the method, the weights stay inside a range (``weight_range``, default ``"auto"``:
[0, 1] for an ARKit/FACS-style target rig's own shapes, :data:`~faceretarget.numerics.EXAMPLE_RANGE`
for example-based key-models) where an artist's tool plays them.  The range is part of the solve,
not a clip afterwards: the method's weights ``w*`` (denoised for ``"temporal"``) are replaced, frame
by frame, by the in-range weights whose *target* face is nearest to the face ``w*`` makes,
``min ||B (w - w*)||`` over ``lo <= w <= hi`` with ``B`` the target key-models' displacements
(box-constrained least squares, :func:`~faceretarget.numerics.solve_bounded`, in the ``N x N``
Cholesky factor of ``B'B``).  Measuring in the target's geometry matters: correlated key-models
(range-of-motion frames) reach a source expression by cancelling large weights, and among the
in-range blends the one nearest at the source's 68 feature points can be far on the target's face
(P1 rom-40, worst of 12 experiments at [-1, 2]: 9.3 % in the target's metric, 10.1 % at the source's
feature points).
``weight_range=None`` keeps the unconstrained weights.

Whatever the method, the output for frame ``t`` is ``B0 + sum_i w_i(t) (B_i - B0)``: the target
neutral plus the weighted target key-model displacements (Eq. 9-11), so it can be written as a
morph-target animation with the target key-models as morph targets.

Beyond the paper: near-duplicate key-models are reported by name instead of producing a singular
solve, and every frame gets an *outside score*, the share of its feature motion the key-models
cannot express (the paper's stated limitation), with a warning when many frames lie outside.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np

from ..base import Model, WeightsResult
from ..errors import FitWarning, InvalidDataError, MissingShapeError, SingularKeysError, TopologyError
from ..headpose import HeadPose
from ..numerics import auto_weight_range, denoise_take, estimate_noise_sigma, range_metric, solve_bounded
from ..performance import Performance
from ..rig import Rig, resolve_features
from ._cardinal import CardinalBasis
from ._features import FeaturePCA, feature_vectors

__all__ = ["ExpressionCloner", "CloneResult", "METHODS"]

METHODS = ("temporal", "linear", "pyun")


@dataclass(eq=False)
class CloneResult(WeightsResult):
    """What :meth:`ExpressionCloner.transform` gives for one take.

    Attributes
    ----------
    weights : (T, N) float
        Key-model weights, columns named by ``names`` (the target key-models'
        :attr:`ExpressionCloner.target_keys_`).
    names : list of str
    times : (T,) float or None
        Frame times (None for an array given without times).
    outside : (T,) float
        Each frame's outside score: the share of its feature motion the key-models cannot express
        (less what capture noise explains).
    noise_sigma : float
        Noise level removed (``"temporal"``), in the source's units; 0 when none was.
    head, audio, audio_rate, source
        Carried from the input take.
    """

    weights: np.ndarray
    names: list[str]
    times: np.ndarray | None
    outside: np.ndarray
    noise_sigma: float = 0.0
    head: HeadPose | None = None
    audio: np.ndarray | None = None
    audio_rate: float | None = None
    source: str = "clone"


class ExpressionCloner(Model):
    """Clone a performance from source key-models onto target key-models.

    Parameters
    ----------
    method : {"temporal", "linear", "pyun"}
        How frames become key-model weights (see the module docstring).
    features : "landmarks", "all", a file of vertex indices, or an index array
        Feature points on the source (Pyun Sec. 3).
    eig_threshold : float
        ``"pyun"`` only: PCA axes with an eigenvalue below this fraction of the largest are dropped.
    noise_sigma : float, optional
        ``"temporal"`` only: noise standard deviation of the feature points in the source's units;
        estimated from each take when omitted, ``0`` turns denoising off.
    duplicate_tol : float
        Key-models whose feature vectors differ by less than this fraction of the typical key-model
        displacement are reported as duplicates (:class:`~faceretarget.errors.SingularKeysError`).
    outside_warn : float
        Warn when more than 5 % of a take's frames have an outside score above this.
    weight_range : "auto", (lo, hi) or None
        Range every weight stays in (module docstring); ``"auto"`` decides at :meth:`fit` from the
        key-model names, None solves without bounds.

    Attributes
    ----------
    names_ : list of str
        Key-model names, in the order of the weights.
    weight_range_ : (lo, hi) or None
        The range in force.
    range_metric_ : (N, N) float
        Upper Cholesky factor of the target key-models' Gram matrix (the in-range projection's metric).
    feature_idx_ : (P,) int
    target_keys_ : Rig
        The target key-models in weight order (neutral + key-models as shapes): the morph
        targets a written animation plays.
    """

    def __init__(self, method: str = "temporal", features="landmarks", eig_threshold: float = 1e-6,
                 noise_sigma: float | None = None, duplicate_tol: float = 1e-3, outside_warn: float = 0.35,
                 weight_range="auto"):
        if method not in METHODS:
            raise InvalidDataError(f"unknown cloning method '{method}', use one of {', '.join(METHODS)}")
        self.method = method
        self.features = features
        self.eig_threshold = eig_threshold
        self.noise_sigma = noise_sigma
        self.duplicate_tol = duplicate_tol
        self.outside_warn = outside_warn
        self.weight_range = weight_range

    # ------------------------------------------------------------------ fitting
    def fit(self, source_keys: Rig, target_keys: Rig) -> ExpressionCloner:
        """Learn the weight functions from paired key-models.

        Parameters
        ----------
        source_keys, target_keys : Rig
            Each a neutral plus key-models as named shapes; paired by name (every source key-model
            needs a target counterpart; extra target shapes are ignored).
        """
        names = list(source_keys.names)
        missing = [n for n in names if n not in target_keys]
        if missing:
            raise MissingShapeError(
                f"{target_keys.name}: no target key-model for source key-model(s) {', '.join(missing)}"
            )
        if not names:
            raise InvalidDataError(f"{source_keys.name}: no key-models besides the neutral")
        idx = resolve_features(self.features, source_keys.n_vertices, source_keys.landmarks, who=source_keys.name)
        self.weight_range_ = auto_weight_range(self.weight_range, names)
        X = source_keys.deltas[:, idx].reshape(len(names), -1)          # (N, 3P)
        self._check_duplicates(X, names)
        tidx = [target_keys.index(n) for n in names]
        self.names_ = names
        self.feature_idx_ = idx
        self.source_neutral_ = source_keys.neutral.vertices.copy()
        self.target_neutral_ = target_keys.neutral.vertices.copy()
        self.target_deltas_ = target_keys.deltas[tidx].reshape(len(names), -1)   # (N, 3Vt)
        self.source_unit_ = source_keys.unit
        self.target_unit_ = target_keys.unit
        same = len(tidx) == target_keys.n_shapes and tidx == list(range(len(tidx)))
        self.target_keys_ = target_keys if same else target_keys.subset(names)
        # key-model span of the features, for the linear methods and the outside score
        U, S, Vt = np.linalg.svd(X.T, full_matrices=False)
        rank = int((S > 1e-9 * S[0]).sum()) if S.size and S[0] > 0 else 0
        if rank < len(names):
            warnings.warn(
                f"{source_keys.name}: the {len(names)} key-models span only {rank} independent feature "
                "directions; weights are the minimum-norm solution",
                FitWarning,
                stacklevel=2,
            )
        self.U_, self.S_, self.Vt_ = U[:, :rank], S[:rank], Vt[:rank]
        self.wmap_ = (self.Vt_.T / self.S_) @ self.U_.T                    # (N, 3P)
        self.key_scale_ = float(np.sqrt((X**2).sum(axis=1).mean()))
        self.range_metric_ = range_metric(self.target_deltas_.T)
        if self.method == "pyun":
            P0 = np.vstack([np.zeros((1, X.shape[1])), X])                  # neutral + key-models
            self.pca_ = FeaturePCA(self.eig_threshold).fit(P0)
            self.basis_ = CardinalBasis(radial=True).fit(self.pca_.transform(P0), ["neutral"] + names)
        return self

    def _check_duplicates(self, X: np.ndarray, names: list[str]) -> None:
        Z = np.vstack([np.zeros((1, X.shape[1])), X])
        labels = ["neutral"] + names
        scale = np.sqrt((X**2).sum(axis=1).mean())
        if scale == 0:
            raise SingularKeysError("every key-model has the neutral's feature points: nothing to blend")
        sq = (Z**2).sum(axis=1)
        D2 = sq[:, None] + sq[None, :] - 2 * Z @ Z.T
        np.fill_diagonal(D2, np.inf)
        i, j = np.unravel_index(int(np.argmin(D2)), D2.shape)
        d = np.sqrt(max(D2[i, j], 0.0))
        if d < self.duplicate_tol * scale:
            a, b = sorted((i, j))
            raise SingularKeysError(
                f"key-models '{labels[a]}' and '{labels[b]}' are near duplicates at the feature points "
                f"(distance {d:.3g} vs typical key-model displacement {scale:.3g}); remove one or use "
                "more feature points"
            )

    # ------------------------------------------------------------------ applying
    def _features_of(self, perf_or_array) -> tuple[np.ndarray, np.ndarray | None]:
        self._check_fitted()
        times = None
        if isinstance(perf_or_array, Performance):
            times = perf_or_array.times
            if perf_or_array.kind == "weights":
                raise InvalidDataError(
                    f"{perf_or_array.source}: a weight take must be played on its source rig first "
                    "(Rig.evaluate) before cloning"
                )
            arr = perf_or_array.data()
            src = perf_or_array.source
        else:
            arr = np.asarray(perf_or_array, dtype=np.float64)
            src = "input"
        if arr.ndim == 2:
            arr = arr[None]
        if arr.ndim != 3 or arr.shape[2] != 3:
            raise InvalidDataError(f"{src}: expected frames of shape (T, V, 3), got {arr.shape}")
        V, P = len(self.source_neutral_), len(self.feature_idx_)
        if arr.shape[1] == V:
            F = feature_vectors(arr, self.source_neutral_, self.feature_idx_)
        elif arr.shape[1] == P:
            F = feature_vectors(arr, self.source_neutral_[self.feature_idx_], None)
        else:
            raise TopologyError(
                f"{src}: frames have {arr.shape[1]} points; the source key-models have {V} vertices "
                f"and {P} feature points"
            )
        if not np.isfinite(F).all():
            t = int(np.flatnonzero(~np.isfinite(F).all(axis=1))[0])
            raise InvalidDataError(f"{src}: frame {t} has missing or non-finite feature points")
        return F, times

    def transform(self, perf_or_vertices, times: np.ndarray | None = None) -> CloneResult:
        """Key-model weights of a take (:class:`CloneResult`; ``.weights`` is ``(T, N)``).

        Parameters
        ----------
        perf_or_vertices : Performance or (T, V, 3) / (T, P, 3) array
            Source meshes (all vertices) or just the feature points, in the source's units.
        times : (T,) float, optional
            Frame times for arrays (uneven spacing is handled by ``"temporal"``).
        """
        F, ptimes = self._features_of(perf_or_vertices)
        times = ptimes if times is None else np.asarray(times, dtype=np.float64)
        C = F @ self.U_                                                     # coordinates in the key span
        resid = F - C @ self.U_.T
        sigma = estimate_noise_sigma(F) if self.noise_sigma is None else float(self.noise_sigma)
        # share of each frame's motion the key-models cannot express, less what capture noise explains
        r2 = (resid**2).sum(axis=1) - (F.shape[1] - self.U_.shape[1]) * sigma**2
        floor = 0.1 * self.key_scale_
        outside = np.sqrt(np.maximum(r2, 0.0)) / np.maximum(np.linalg.norm(F, axis=1), floor)
        frac = float((outside > self.outside_warn).mean())
        if frac > 0.05:
            worst = int(np.argmax(outside))
            warnings.warn(
                f"{frac:.0%} of frames lie outside the key-models (worst frame {worst}: "
                f"{outside[worst]:.0%} of its motion unexplained); add key-models that cover them",
                FitWarning,
                stacklevel=2,
            )
        used = 0.0
        if self.method == "temporal" and sigma > 0 and len(F) >= 8:
            C, used = denoise_take(C, times, sigma=sigma)
        if self.method == "pyun":
            W = self.basis_.transform(self.pca_.transform(F))[:, 1:]
        else:
            W = (C / self.S_) @ self.Vt_
        if self.weight_range_ is not None:
            W = self._in_range(W)
        res = CloneResult(W, list(self.names_), times, outside, used)
        if isinstance(perf_or_vertices, Performance):
            res.carry(perf_or_vertices)      # head, audio, timecode, curves of the input take
        return res

    def _in_range(self, W: np.ndarray) -> np.ndarray:
        """Weights ``(T, N)`` inside :attr:`weight_range_` whose target face is nearest to that of
        ``W`` ``(T, N)`` (module docstring): ``min ||L' (w - w_t)||`` with ``L L' = B'B``."""
        lo, hi = self.weight_range_
        W = np.asarray(W, dtype=np.float64)
        rows = ~((W >= lo) & (W <= hi)).all(axis=1)              # frames already inside are their own
        if not rows.any():                                         # nearest point: nothing to solve
            return W.copy()
        Lt = self.range_metric_
        res = W.copy()
        res[rows] = solve_bounded(Lt, W[rows] @ Lt.T, lo, hi)
        return res

    def blend(self, weights: np.ndarray) -> np.ndarray:
        """Target meshes ``(T, Vt, 3)`` for key-model weights ``(T, N)`` (Eq. 9-11), one matrix product."""
        self._check_fitted("blend")
        w = np.atleast_2d(np.asarray(weights, dtype=np.float64))
        out = (w @ self.target_deltas_).reshape(len(w), -1, 3)
        out += self.target_neutral_
        return out

    def stream_frame(self, frame: np.ndarray) -> np.ndarray:
        """Clone one frame as it arrives (no look-ahead, no denoising): ``(V|P, 3) -> (Vt, 3)``."""
        self._check_fitted("stream_frame")
        f = np.asarray(frame, dtype=np.float64)
        if f.shape[0] == len(self.source_neutral_):
            x = (f[self.feature_idx_] - self.source_neutral_[self.feature_idx_]).reshape(-1)
        else:
            x = (f - self.source_neutral_[self.feature_idx_]).reshape(-1)
        if self.method == "pyun":
            w = self.basis_.transform(self.pca_.transform(x[None]))[0, 1:]
        else:
            w = self.wmap_ @ x
        if self.weight_range_ is not None:
            w = self._in_range(w[None])[0]
        return (w @ self.target_deltas_).reshape(-1, 3) + self.target_neutral_
