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
    (:mod:`faceretarget.cloning.temporal`): capture noise is independent from frame to frame, the
    face is not, and the noise level is estimated from the take itself.  On a clean take it equals
    ``"linear"``.

Whatever the method, the output for frame ``t`` is ``B0 + sum_i w_i(t) (B_i - B0)``: the target
neutral plus the weighted target key-model displacements (Eq. 9-11), so it can be written as a
morph-target animation with the target key-models as morph targets.

Beyond the paper: near-duplicate key-models are reported by name instead of producing a singular
solve, and every frame gets an *outside score*, the share of its feature motion the key-models
cannot express (the paper's stated limitation), with a warning when many frames lie outside.
"""

from __future__ import annotations

import json
import warnings
from pathlib import Path

import numpy as np

from ..errors import FitWarning, InvalidDataError, MissingShapeError, SingularKeysError, TopologyError
from ..numerics import denoise_take, estimate_noise_sigma
from ..performance import Performance
from ..rig import Rig, resolve_features
from ._cardinal import CardinalBasis
from ._features import FeaturePCA, feature_vectors

__all__ = ["ExpressionCloner", "METHODS"]

METHODS = ("temporal", "linear", "pyun")


class ExpressionCloner:
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

    Attributes
    ----------
    names_ : list of str
        Key-model names, in the order of the weights.
    feature_idx_ : (P,) int
    outside_ : (T,) float
        Outside score of the frames of the last :meth:`transform`.
    noise_sigma_ : float
        Noise level used in the last :meth:`transform` (``"temporal"``).
    """

    def __init__(self, method: str = "temporal", features="landmarks", eig_threshold: float = 1e-6,
                 noise_sigma: float | None = None, duplicate_tol: float = 1e-3, outside_warn: float = 0.35):
        if method not in METHODS:
            raise InvalidDataError(f"unknown cloning method '{method}', use one of {', '.join(METHODS)}")
        self.method = method
        self.features = features
        self.eig_threshold = eig_threshold
        self.noise_sigma = noise_sigma
        self.duplicate_tol = duplicate_tol
        self.outside_warn = outside_warn

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
        self._target_rig = target_keys.subset(names) if len(tidx) != target_keys.n_shapes or tidx != list(range(len(tidx))) else target_keys
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

    def transform(self, perf_or_vertices, times: np.ndarray | None = None) -> np.ndarray:
        """Key-model weights ``(T, N)`` for a take.

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
        self.outside_ = np.sqrt(np.maximum(r2, 0.0)) / np.maximum(np.linalg.norm(F, axis=1), floor)
        frac = float((self.outside_ > self.outside_warn).mean())
        if frac > 0.05:
            worst = int(np.argmax(self.outside_))
            warnings.warn(
                f"{frac:.0%} of frames lie outside the key-models (worst frame {worst}: "
                f"{self.outside_[worst]:.0%} of its motion unexplained); add key-models that cover them",
                FitWarning,
                stacklevel=2,
            )
        self.noise_sigma_ = 0.0
        if self.method == "temporal" and sigma > 0 and len(F) >= 8:
            C, self.noise_sigma_ = denoise_take(C, times, sigma=sigma)
        if self.method == "pyun":
            return self.basis_.weights(self.pca_.transform(F))[:, 1:]
        return (C / self.S_) @ self.Vt_

    def blend(self, weights: np.ndarray) -> np.ndarray:
        """Target meshes ``(T, Vt, 3)`` for key-model weights ``(T, N)`` (Eq. 9-11), one matrix product."""
        w = np.atleast_2d(np.asarray(weights, dtype=np.float64))
        out = (w @ self.target_deltas_).reshape(len(w), -1, 3)
        out += self.target_neutral_
        return out

    def clone(self, perf: Performance) -> Performance:
        """Clone a take: a weight Performance on the target key-models (see :attr:`target_keys`)."""
        w = self.transform(perf)
        return Performance(perf.times, perf.fps, weights=w, names=list(self.names_),
                           head_rotation=perf.head_rotation, head_translation=perf.head_translation,
                           audio=perf.audio, audio_rate=perf.audio_rate, source=perf.source)

    @property
    def target_keys(self) -> Rig:
        """The target key-models in weight order (a Rig: neutral + key-models as shapes)."""
        return self._target_rig

    def stream_frame(self, frame: np.ndarray) -> np.ndarray:
        """Clone one frame as it arrives (no look-ahead, no denoising): ``(V|P, 3) -> (Vt, 3)``."""
        f = np.asarray(frame, dtype=np.float64)
        if f.shape[0] == len(self.source_neutral_):
            x = (f[self.feature_idx_] - self.source_neutral_[self.feature_idx_]).reshape(-1)
        else:
            x = (f - self.source_neutral_[self.feature_idx_]).reshape(-1)
        if self.method == "pyun":
            w = self.basis_.weights(self.pca_.transform(x[None]))[0, 1:]
        else:
            w = self.wmap_ @ x
        return (w @ self.target_deltas_).reshape(-1, 3) + self.target_neutral_

    # ------------------------------------------------------------------ persistence
    def save(self, path) -> None:
        """Save to ``.npz`` (arrays plus a JSON ``meta`` entry: method, names, units)."""
        from ..files import atomic_path

        arrays = {k: getattr(self, k) for k in ("feature_idx_", "source_neutral_", "target_neutral_",
                                                "target_deltas_", "U_", "S_", "Vt_", "wmap_")}
        if self.method == "pyun":
            arrays.update(pca_mean=self.pca_.mean_, pca_components=self.pca_.components_,
                          pca_eigenvalues=self.pca_.eigenvalues_, centers=self.basis_.centers_,
                          dilation=self.basis_.dilation_, linear=self.basis_.linear_, radial=self.basis_.radial_)
        meta = dict(method=self.method, names=self.names_, source_unit=self.source_unit_,
                    target_unit=self.target_unit_, key_scale=self.key_scale_, noise_sigma=self.noise_sigma,
                    outside_warn=self.outside_warn, format="faceretarget.ExpressionCloner/1")
        with atomic_path(path) as tmp:
            with open(tmp, "wb") as fh:
                np.savez(fh, meta=np.array(json.dumps(meta)), **arrays)

    @classmethod
    def load(cls, path) -> ExpressionCloner:
        z = np.load(Path(path), allow_pickle=False)
        meta = json.loads(str(z["meta"]))
        self = cls(method=meta["method"], features=z["feature_idx_"], noise_sigma=meta["noise_sigma"],
                   outside_warn=meta["outside_warn"])
        for k in ("feature_idx_", "source_neutral_", "target_neutral_", "target_deltas_", "U_", "S_", "Vt_", "wmap_"):
            setattr(self, k, z[k])
        self.names_ = meta["names"]
        self.source_unit_, self.target_unit_ = meta["source_unit"], meta["target_unit"]
        self.key_scale_ = meta["key_scale"]
        if self.method == "pyun":
            self.pca_ = FeaturePCA()
            self.pca_.mean_, self.pca_.components_, self.pca_.eigenvalues_ = z["pca_mean"], z["pca_components"], z["pca_eigenvalues"]
            b = CardinalBasis()
            b.centers_, b.dilation_, b.linear_, b.radial_ = z["centers"], z["dilation"], z["linear"], z["radial"]
            self.basis_ = b
        # faces are not saved: the loaded target keys carry vertices and deltas (enough for .glb
        # morph targets as points, .npz and blending)
        from ..mesh import Mesh

        self._target_rig = Rig(Mesh(self.target_neutral_), list(self.names_),
                               self.target_deltas_.reshape(len(self.names_), -1, 3), self.target_unit_,
                               name="loaded:target-keys")
        return self
