"""``StyleModel``: edit the emotion of a take, keeping what is said (Chuang 2004, Ch. 2).

The pipeline from takes to edited takes:

1. **Alignment** (:mod:`._align`): the takes (one per style, all saying the same text) are put on
   the reference take's timeline by DTW, by audio when they have it, else by face features.
2. **Facial configuration vectors**: every frame of any :class:`~faceretarget.performance.Performance`
   (blendshape weights, feature points, mesh vertices, or appearance vectors stored as weights)
   flattened to ``D`` numbers, compressed by PCA over all aligned training frames to the ``K``
   components that keep a fraction ``variance`` of the variance, ``z = P'(x - mean)``.
3. **Observation vectors** ``y = [c0, z]``: a constant first coordinate ``c0 = offset * rms(z)``
   (``offset`` 10 by default) lets the bilinear models, which are linear in content, carry each
   style's mean face: the model's first content component becomes (nearly) constant, it multiplies
   every style's mean, and it is the component the unknown-expression iteration keeps in range
   (:meth:`SymmetricBilinearModel.infer`).  The dimension rule skips it (``keep_first=1``).
4. **n-frame bundles** (Sec. 2.3.4, Eq. 2.14): with ``bundle = n > 1`` the observation of frame
   ``t`` is ``[y_t, ..., y_{t+n-1}]``, so style and content are learned from short motion snippets;
   decoding averages the ``n`` estimates of every frame.
5. **Models** (:mod:`._bilinear`): an asymmetric model (known-expression tasks, new styles) and a
   symmetric model (unknown expression) on the same observations.

Tasks (Sec. 2.3.3): :meth:`StyleModel.known` (input style given, Eq. 2.10, 2.11),
:meth:`StyleModel.unknown` (style and content inferred, Eq. 2.12, 2.13, style constant over
``window`` frames), :meth:`StyleModel.add_style` (an untrained expression fitted from examples of
it next to the same text in a known style).  All take ``amount``: Eq. 2.15 interpolates
(``0 < amount < 1``) or extrapolates (``amount > 1``, exaggeration) between the input's style and
the target; every result carries a :class:`RangeReport` saying how far it left the range of the
training data.

Files: ``save`` / ``load`` of :class:`~faceretarget.base.Model` (one ``.npz`` format for every model;
the alignments and the cross-validation's scores of :meth:`StyleModel.fit` are not saved).

**Local correction** (our addition; by default kernel ridge regression chosen by cross-validation,
:mod:`._select`; ``local=k``: the mean of ``k`` nearest frames, as below): a bilinear model is linear in the
content, but emotion and speech can interact nonlinearly (on the P3 data the composition keeps the
lips' motion along the speech direction and only the perpendicular part of the emotion, so the
effect of the emotion on the mouth depends on the mouth shape).  For a source -> target
translation the model keeps its training residuals ``R = Y_target - render(content(Y_source))``
over paired training frames; every input frame gets the mean residual of the ``local`` training
frames nearest to it in the source style's observation space added to its rendering (for Eq. 2.15
``(1 - alpha) R_source->source + alpha R_source->target``).  With ``local=0`` the output is the
bilinear model's alone.

**Point-local translation** (``local=("points", m, k)``, :mod:`._pointlocal`; chosen by the
cross-validation when it predicts held-out training blocks better): for frames of points, the
known- and unknown-expression edits are the input plus, at every point, the change learned from
the paired training frames as a function of that point and its ``m - 1`` neighbours (affine, plus
the mean remainder of the ``k`` nearest training frames), instead of the bilinear translation.
Point takes aligned by face are re-aligned by style (:func:`~._align.realign_by_style`,
``realign`` iterations) before the models are fitted.
"""

from __future__ import annotations

import warnings
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from ..base import Model
from ..errors import InvalidDataError, StyleFitWarning, StyleRangeWarning
from ..names import normalize_name
from ..performance import Performance
from ._align import Alignment, align_performances, frame_vectors, realign_by_style, warp_performance
from ._bilinear import AsymmetricBilinearModel, InferResult, SymmetricBilinearModel
from ._pointlocal import fit_point_map, point_count
from ._select import (
    STYLE_RIDGE_GRID,
    kernel_fit,
    kernel_predict,
    ones_weights,
    pca_of,
    select_settings,
    select_style_ridge,
)

__all__ = ["StyleModel", "Restyled", "RangeReport", "StyleRangeWarning", "StyleFitWarning", "bundle_frames", "unbundle_frames"]

#: BLAS threads while a model is fitted (None: the library's default, every core).
FIT_BLAS_THREADS: int | None = 1

#: The range guard measures each PCA component's excess in units of its training range, but at
#: least this share of the widest component's range: components holding only noise-level variation
#: (which the point-local translation does not reproduce exactly) do not decide plausibility.
RANGE_FLOOR = 0.05


@dataclass
class RangeReport:
    """How far a result lies outside the training data's range.

    Attributes
    ----------
    score : float
        Largest excess over all frames and PCA components beyond the training range
        ``[lo_k, hi_k]``, in units of that range's width, or of :data:`RANGE_FLOOR` times the
        widest component's when that is larger (0: inside everywhere).
    outside : bool
        ``score > margin``.
    frames_outside : float
        Share of frames whose excess is above ``margin``.
    margin : float
    """

    score: float
    outside: bool
    frames_outside: float
    margin: float


@dataclass
class Restyled:
    """A restyled take.

    Attributes
    ----------
    frames : (T, ...) float
        In the input's frame layout.
    range : RangeReport
    inferred : InferResult or None
        For the unknown-expression task: the inferred style and content (in bundle frames).
    style_weights : (T, S) float or None
        For the unknown-expression task: each frame's style vector expressed as an affine
        combination of the training styles (least squares, summing to 1).
    local : bool
        Whether the local correction was applied (it needs paired training frames of the source
        and target styles).
    take : Performance or None
        The edited take (:meth:`StyleModel.transform`; None for the array-level tasks).
    """

    frames: np.ndarray
    range: RangeReport
    inferred: InferResult | None = None
    style_weights: np.ndarray | None = None
    local: bool = False
    take: Performance | None = None


def _amount(amount) -> float:
    try:
        a = float(amount)
    except (TypeError, ValueError) as e:
        raise InvalidDataError(f"amount must be a number, got {amount!r}") from e
    if not np.isfinite(a):
        raise InvalidDataError(f"amount must be finite, got {amount}")
    return a


def _local_spec(local):
    """``local`` normalised: ``"auto"``, ``0`` (off), an int ``k`` (nearest-frame mean),
    ``("kernel", bandwidth, ridge)`` or ``("points", neighbours, frames)``."""
    if isinstance(local, str):
        if local != "auto":
            raise InvalidDataError(f"local must be 'auto', a number of frames, ('kernel', bandwidth, ridge) or "
                                   f"('points', neighbours, frames), got {local!r}")
        return local
    if isinstance(local, (list, tuple)) and len(local) == 3 and local[0] == "points":
        try:
            m, k = int(local[1]), int(local[2])
        except (TypeError, ValueError) as e:
            raise InvalidDataError(f"a point-local translation is ('points', neighbours >= 1, frames >= 0), "
                                   f"got {local!r}") from e
        if m < 1 or k < 0 or m != float(local[1]) or k != float(local[2]):
            raise InvalidDataError(f"a point-local translation is ('points', neighbours >= 1, frames >= 0), "
                                   f"got {local!r}")
        return ("points", m, k)
    if isinstance(local, (list, tuple)):
        if len(local) != 3 or local[0] != "kernel" or not (float(local[1]) > 0 and float(local[2]) > 0):
            raise InvalidDataError(f"a kernel correction is ('kernel', bandwidth > 0, ridge > 0), got {local!r}")
        return ("kernel", float(local[1]), float(local[2]))
    k = int(local)
    if k < 0:
        raise InvalidDataError(f"local must be >= 0, got {local}")
    return k


def bundle_frames(Y: np.ndarray, n: int) -> np.ndarray:
    """Eq. 2.14: stack ``n`` consecutive frames into one observation.

    Parameters
    ----------
    Y : (T, K) or (S, T, K) float
    n : int

    Returns
    -------
    (T - n + 1, n K) or (S, T - n + 1, n K) float
    """
    Y = np.asarray(Y, np.float64)
    T = Y.shape[-2]
    if n < 1 or n > T:
        raise InvalidDataError(f"bundle size must be in 1..{T} (frames), got {n}")
    if n == 1:
        return Y
    return np.concatenate([Y[..., i:T - n + 1 + i, :] for i in range(n)], axis=-1)


def unbundle_frames(Yb: np.ndarray, n: int) -> np.ndarray:
    """Invert :func:`bundle_frames` by averaging every frame's ``n`` estimates: ``(T, K)``."""
    Yb = np.asarray(Yb, np.float64)
    if n == 1:
        return Yb
    Tb, nK = Yb.shape
    K = nK // n
    out = np.zeros((Tb + n - 1, K))
    cnt = np.zeros(Tb + n - 1)
    for i in range(n):
        out[i:i + Tb] += Yb[:, i * K:(i + 1) * K]
        cnt[i:i + Tb] += 1
    return out / cnt[:, None]


class StyleModel(Model):
    """Style (emotion) and content (speech) of facial takes, separated by bilinear models.

    Parameters
    ----------
    variance : float or "auto"
        Retained variance of the PCA compression.  ``"auto"`` (default): chosen, with ``energy``,
        ``prior`` and ``local``, by blocked cross-validation of the known-expression task on the
        training frames (:mod:`._select`); the values used are in ``settings_``.
    energy : float or "auto"
        Retained energy of the style / content dimension rule (:func:`~._bilinear.choose_dims`).
    content_dims, style_dims : int, optional
        Override the rule.
    bundle : int
        Frames per observation (Eq. 2.14); 1: single frames.
    offset : float
        Constant coordinate ``c0`` in units of the RMS norm of the PCA coefficients (0: none).
    local : "auto", int, ("kernel", bandwidth, ridge) or ("points", neighbours, frames)
        Local correction: 0 off; ``k`` the mean training residual of the ``k`` nearest training
        frames; ``("kernel", h, lam)`` kernel ridge regression of the training residuals on the
        source observation (:func:`~._select.kernel_fit`; ``h`` in units of the median
        nearest-neighbour distance, ``lam`` relative to the kernel's diagonal).
        ``("points", m, k)``: instead of the bilinear translation, the point-local one
        (:mod:`._pointlocal`; frames of ``(P, 3)`` points only): every point's change from the
        paired training frames, affine in the point and its ``m - 1`` neighbours plus the mean
        remainder of the ``k`` nearest training frames.  ``"auto"`` considers all of these
        (the point-local one when frames are points).
    prior : bool, float or "auto"
        Strength of the content prior (:mod:`._bilinear`); ``False`` / 0: the thesis's plain least
        squares, ``True``: 1.
    detail : bool
        Apply an edit as a change to the input (module docstring): the output is the input plus
        the model's rendering in the new style minus its rendering in the input's own style, so
        whatever of the input the model does not capture is kept and ``amount=0`` returns the
        input unchanged.  ``False``: the output is the model's rendering alone (the thesis).
    align : {"auto", "audio", "face"}
        How :meth:`fit` aligns takes (audio when all have it, by default).
    audio_features : {"mfcc", "rplp"}
    window_s : float, optional
        Sakoe-Chiba band of the alignment, seconds.
    cv_folds : int
        Folds of the settings' cross-validation.
    realign : int
        Iterations of re-alignment by style (:func:`~._align.realign_by_style`) for point takes
        aligned by face features; 0: the first DTW alignment only.
    progress : bool
        Show a progress bar (stderr) over the fit's stages: aligning each take, choosing the
        settings (bilinear, then corrections), fitting.

    Attributes
    ----------
    styles_ : list of str
    reference_ : str
        The style whose timeline the training takes were aligned to.
    mean_ : (D,) float
    basis_ : (D, K) float
    offset_ : float
        ``c0``.
    coef_lo_, coef_hi_ : (K,) float
        Range of the training PCA coefficients.
    asymmetric_ : AsymmetricBilinearModel
    symmetric_ : SymmetricBilinearModel
    settings_ : dict
        ``variance``, ``energy``, ``prior``, ``local`` used (chosen or given).
    selection_ : Selection or None
        The cross-validation's choice and scores (None when every setting was given, or loaded).
    alignments_ : dict of str to Alignment
        From :meth:`fit` (not saved).
    take_kind_ : str
        ``"weights"``, ``"points"`` or ``"vertices"``.
    frame_shape_ : tuple
    names_ : list of str
        Weight names (weight takes).
    """

    _transient = ("alignments_", "selection_")

    def __init__(self, variance: float | str = "auto", energy: float | str = "auto", content_dims: int | None = None,
                 style_dims: int | None = None, bundle: int = 1, offset: float = 10.0, local: int | tuple | str = "auto",
                 prior: bool | float | str = "auto", detail: bool = True, align: str = "auto",
                 audio_features: str = "mfcc", window_s: float | None = None, cv_folds: int = 5,
                 realign: int = 2, progress: bool = False):
        self.variance = variance
        self.energy = energy
        self.cv_folds = cv_folds
        self.content_dims = content_dims
        self.style_dims = style_dims
        self.bundle = bundle
        self.offset = offset
        self.local = local
        self.prior = prior
        self.detail = detail
        self.align = align
        self.audio_features = audio_features
        self.window_s = window_s
        self.realign = realign
        self.progress = progress

    # ------------------------------------------------------------------------------------ fitting
    def fit(self, takes: Mapping[str, Performance], reference: str | None = None) -> StyleModel:
        """Align takes of the same text in different styles and fit the models; returns self.

        Parameters
        ----------
        takes : mapping of style name to Performance
            At least two, of the same kind and frame size (weight takes: the same channel names).
        reference : str, optional
            The style whose timeline the others are aligned to (default: the first).
        """
        if len(takes) < 2:
            raise InvalidDataError(f"a style model needs takes in at least 2 styles, got {len(takes)}")
        names = list(takes)
        ref = names[0] if reference is None else reference
        if ref not in takes:
            raise InvalidDataError(f"reference style '{ref}' is not among the takes ({', '.join(names)})")
        base = takes[ref]
        self._set_layout(base)
        frames: dict[str, np.ndarray] = {}
        self.alignments_: dict[str, Alignment] = {}
        with self._bar(len(names) - 1 + 3, "style fit") as bar:
            for s in names:
                p = self._conform(takes[s], base)
                if s == ref:
                    frames[s] = frame_vectors(p)
                    continue
                bar.set_postfix_str(f"aligning {s}")
                al = self._align(base, p)
                self.alignments_[s] = al
                frames[s] = frame_vectors(warp_performance(p, al))
                bar.update(1)
            self.reference_ = ref
            return self._fit_vectors({s: frames[s] for s in names}, bar=bar)

    def _bar(self, total: int, desc: str):
        """A progress bar over the fit's stages (shown when ``progress``; stderr)."""
        from tqdm.auto import tqdm

        return tqdm(total=total, desc=desc, unit="stage", leave=False, disable=not getattr(self, "progress", False))

    def fit_frames(self, frames: Mapping[str, np.ndarray], template: Performance | None = None, *,
                   groups=None) -> StyleModel:
        """Fit from takes already aligned frame by frame: ``frames[style]`` is ``(C, ...)``.

        ``template`` (optional) gives the take layout (kind, names) that :meth:`restyle` expects.
        ``groups`` (optional, ``(C,)``) says which performer each aligned frame comes from when the
        frames of several performers are stacked (each performer's takes aligned to that
        performer's reference take): the ``"auto"`` settings are then chosen by leaving one
        performer out at a time (:func:`~faceretarget.style.group_folds`), for what carries to a
        performer the model has not seen, instead of by blocks of time.
        """
        if len(frames) < 2:
            raise InvalidDataError(f"a style model needs at least 2 styles, got {len(frames)}")
        arrs = {s: np.asarray(v, np.float64) for s, v in frames.items()}
        shapes = {a.shape for a in arrs.values()}
        if len(shapes) != 1:
            raise InvalidDataError(f"aligned takes must all have the same shape, got {sorted(shapes)}")
        first = next(iter(arrs.values()))
        if template is not None:
            self._set_layout(template)
        else:
            self.take_kind_, self.frame_shape_ = "points", tuple(first.shape[1:])
            self.names_, self.labels_, self.unit_ = [], [], None
        self.reference_ = next(iter(arrs))
        self.alignments_ = {}
        if groups is not None:
            groups = np.asarray(groups)
            if groups.shape != (len(first),):
                raise InvalidDataError(f"groups: expected one label per aligned frame ({len(first)}), got shape "
                                       f"{groups.shape}")
        return self._fit_vectors({s: a.reshape(len(a), -1) for s, a in arrs.items()}, groups=groups)

    def _align(self, ref: Performance, take: Performance) -> Alignment:
        """DTW alignment of ``take`` to ``ref``; point takes aligned by face are re-aligned by style."""
        al = align_performances(ref, take, by=self.align, features=self.audio_features, window_s=self.window_s)
        if al.by == "face" and int(getattr(self, "realign", 0)) > 0 and point_count(self.frame_shape_) is not None:
            al = realign_by_style(ref, take, al, iterations=int(self.realign), window_s=self.window_s)
        return al

    def _set_layout(self, p: Performance) -> None:
        self.take_kind_ = p.kind
        self.frame_shape_ = tuple(p.data().shape[1:])
        self.names_ = [normalize_name(n) for n in p.names] if p.kind == "weights" else []
        self.labels_ = list(p.labels)
        self.unit_ = p.unit

    def _conform(self, p: Performance, base: Performance | None = None) -> Performance:
        """``p`` checked against the model's layout (weights reordered by name)."""
        what = p.source
        if p.kind != self.take_kind_:
            raise InvalidDataError(f"{what}: a {p.kind} take, but the model works on {self.take_kind_}")
        if p.kind == "weights":
            idx = {normalize_name(n): j for j, n in enumerate(p.names)}
            missing = [n for n in self.names_ if n not in idx]
            if missing:
                raise InvalidDataError(f"{what}: lacks {len(missing)} channel(s) the model uses: "
                                       f"{', '.join(missing[:6])}{' ...' if len(missing) > 6 else ''}")
            cols = [idx[n] for n in self.names_]
            return Performance(p.times, p.fps, weights=p.weights[:, cols], names=list(self.names_),
                               audio=p.audio, audio_rate=p.audio_rate, source=p.source)
        if tuple(p.data().shape[1:]) != tuple(self.frame_shape_):
            raise InvalidDataError(f"{what}: frames are {tuple(p.data().shape[1:])} but the model's are "
                                   f"{tuple(self.frame_shape_)}")
        return p

    def _fit_vectors(self, X: dict[str, np.ndarray], groups=None, bar=None) -> StyleModel:
        C = {len(x) for x in X.values()}
        if len(C) != 1:
            raise InvalidDataError(f"aligned takes differ in length: {sorted(C)}")
        C = C.pop()
        if C < max(3, self.bundle + 1):
            raise InvalidDataError(f"need at least {max(3, self.bundle + 1)} aligned frames, got {C}")
        if bar is None:
            with self._bar(3, "style fit") as b:
                return self._fit_vectors(X, groups, bar=b)
        from threadpoolctl import threadpool_limits

        # the fit is thousands of small (100-500 wide) products and factorisations: one BLAS thread is
        # as fast on a quiet machine and 2.5x faster when another process holds a core (BLAS
        # threads then wait on each other: 40 s against 16 s for three 2,000-frame takes)
        with threadpool_limits(limits=FIT_BLAS_THREADS, user_api="blas"):
            return self._fit_vectors_resolved(X, C, groups, bar)

    def _fit_vectors_resolved(self, X: dict[str, np.ndarray], C: int, groups, bar) -> StyleModel:

        def step(what: str) -> None:
            bar.set_postfix_str(what)
            bar.update(1)

        self._resolve_settings(X, C, groups, step)
        bar.set_postfix_str("fitting")
        out = self._fit_resolved(X, symmetric=True)
        bar.update(1)
        return out

    def _fit_resolved(self, X: dict[str, np.ndarray], symmetric: bool = True, pca=None) -> StyleModel:
        """Fit with the settings in ``settings_`` (``symmetric=False``: the asymmetric model only;
        ``pca``: ``(mean, singular values, Vt)`` of the frames, when already computed)."""
        styles = list(X)
        st = self.settings_
        variance, energy, prior = float(st["variance"]), float(st["energy"]), float(st["prior"])
        if not 0 < variance <= 1:
            raise InvalidDataError(f"variance must be in (0, 1], got {variance}")
        if not 0 < energy <= 1:
            raise InvalidDataError(f"energy must be in (0, 1], got {energy}")
        if prior < 0:
            raise InvalidDataError(f"prior must be >= 0, got {prior}")
        if pca is None:
            pca = pca_of(X)
        self.mean_, sv, vt = pca
        e = np.cumsum(sv**2) / max(float(np.sum(sv**2)), 1e-300)
        K = int(min(np.searchsorted(e, variance * (1 - 1e-12)) + 1, len(sv)))
        self.basis_ = vt[:K].T.copy()
        Z = {s: (X[s] - self.mean_) @ self.basis_ for s in styles}
        zall = np.concatenate(list(Z.values()))
        self.coef_lo_, self.coef_hi_ = zall.min(0), zall.max(0)
        rms = float(np.sqrt(np.mean(np.sum(zall**2, axis=1))))
        self.offset_ = float(self.offset) * rms
        Y = np.stack([self._observe(Z[s]) for s in styles])
        keep = 1 if self.offset_ > 0 else 0
        self.asymmetric_ = AsymmetricBilinearModel(self.content_dims, energy, keep, prior).fit(Y, styles)
        if symmetric:
            self.symmetric_ = SymmetricBilinearModel(self.style_dims, self.content_dims, energy, keep,
                                                     prior=prior).fit(Y, styles)
        self.styles_ = styles
        self.pair_sets_ = [dict(Z)]
        self._local_cache = {}
        return self

    def _resolve_settings(self, X: dict[str, np.ndarray], C: int, groups=None, step=None) -> None:
        """``settings_``: the fixed settings as given, the ``"auto"`` ones by cross-validation (:mod:`._select`)."""
        fixed = {}
        for k in ("variance", "energy", "prior"):
            v = getattr(self, k)
            if isinstance(v, str):
                if v != "auto":
                    raise InvalidDataError(f"{k} must be a number or 'auto', got {v!r}")
                continue
            fixed[k] = float(v)
        loc = _local_spec(self.local)
        if loc != "auto":
            fixed["local"] = loc
        self.selection_ = None
        if len(fixed) == 4:
            self.settings_ = fixed
            return

        def make(variance, energy, prior):
            m = StyleModel(variance, energy, self.content_dims, self.style_dims, self.bundle, self.offset, 0,
                           prior, self.detail)
            m.settings_ = {"variance": variance, "energy": energy, "prior": prior, "local": 0}
            return m

        P = point_count(self.frame_shape_)
        rest = None if P is None else np.concatenate(list(X.values())).mean(0).reshape(P, 3)
        sel = select_settings(make, X, fixed=fixed, folds=self.cv_folds, points_rest=rest, groups=groups,
                              step=step)
        self.selection_ = sel
        self.settings_ = sel.settings()

    # ------------------------------------------------------------------------------------ encoding
    @property
    def n_components_(self) -> int:
        return int(self.basis_.shape[1])

    def _observe(self, Z: np.ndarray) -> np.ndarray:
        Y = np.concatenate([np.full((len(Z), 1), self.offset_), Z], axis=1) if self.offset_ > 0 else Z
        return bundle_frames(Y, self.bundle)

    def encode(self, frames) -> np.ndarray:
        """Observation vectors (bundled) of frames ``(T, ...)``: ``(T - bundle + 1, bundle * (K + 1))``."""
        self._check_fitted()
        x = self._flat(frames)
        return self._observe((x - self.mean_) @ self.basis_)

    def decode(self, Y: np.ndarray) -> np.ndarray:
        """Frames ``(T, ...)`` of observation vectors (inverse of :meth:`encode`, up to the PCA)."""
        Z = self._coefs(Y)
        return (Z @ self.basis_.T + self.mean_).reshape((len(Z),) + tuple(self.frame_shape_))

    def _coefs(self, Y: np.ndarray) -> np.ndarray:
        y = unbundle_frames(Y, self.bundle)
        return y[:, 1:] if self.offset_ > 0 else y

    def _flat(self, frames) -> np.ndarray:
        x = np.asarray(frames, np.float64)
        D = self.mean_.size
        x = x.reshape(len(x), -1)
        if x.shape[1] != D:
            raise InvalidDataError(f"frames have {x.shape[1]} values but the model's have {D}")
        if len(x) < self.bundle:
            raise InvalidDataError(f"need at least {self.bundle} frames (the bundle size), got {len(x)}")
        if not np.isfinite(x).all():
            raise InvalidDataError(f"frame {int(np.flatnonzero(~np.isfinite(x).all(1))[0])} is not finite")
        return x

    # ------------------------------------------------------------------------------------ guard
    def range_report(self, frames, margin: float = 0.5, *, warn: bool = True) -> RangeReport:
        """How far frames lie outside the training data's range (see :class:`RangeReport`).

        Issues a :class:`StyleRangeWarning` when ``score > margin`` and ``warn``.
        """
        self._check_fitted()
        z = (self._flat(frames) - self.mean_) @ self.basis_
        return self._range(z, margin, warn)

    def _range(self, z: np.ndarray, margin: float, warn: bool) -> RangeReport:
        w = self.coef_hi_ - self.coef_lo_
        width = np.maximum(w, max(RANGE_FLOOR * float(w.max(initial=0.0)), 1e-300))
        ex = np.maximum(np.maximum(z - self.coef_hi_, self.coef_lo_ - z), 0.0) / width
        per_frame = ex.max(axis=1) if ex.size else np.zeros(len(z))
        score = float(per_frame.max(initial=0.0))
        rep = RangeReport(score, score > margin, float(np.mean(per_frame > margin)) if len(z) else 0.0, margin)
        if rep.outside and warn:
            warnings.warn(f"the restyled take leaves the range of the training data by {score:.2f} of its width "
                          f"({rep.frames_outside:.0%} of frames beyond {margin:g}); the face may be implausible "
                          "(reduce the amount)", StyleRangeWarning, stacklevel=3)
        return rep

    # ------------------------------------------------------------------------------------ tasks
    def content(self, frames, style) -> np.ndarray:
        """Content vectors (asymmetric model, Eq. 2.10) of frames in a known style: ``(T_b, J)``."""
        return self.asymmetric_.content(self.encode(frames), style)

    def known(self, frames, source: str, target: str, amount: float = 1.0, *, margin: float = 0.5,
              warn: bool = True) -> Restyled:
        """Known expression: frames in style ``source`` re-rendered in ``target`` (Eq. 2.10, 2.11, 2.15).

        Parameters
        ----------
        frames : (T, ...) float
        source, target : str
        amount : float
            ``alpha`` of Eq. 2.15: 0 keeps the source style, 1 is the target, > 1 exaggerates.
        margin : float
            Threshold of the :class:`RangeReport`.
        """
        self._check_fitted()
        amount = _amount(amount)
        A = self.asymmetric_
        for st in (source, target):
            A.style_index(st)
        x = self._flat(frames)
        if self._points_on():
            src = np.zeros(len(x), int)
            return self._points_result(x, src, [source], target, amount, margin, warn)
        Yin = self.encode(x)
        b = A.content(Yin, source)
        Y = A.interpolate(b, source, target, amount)
        Y0 = A.render(b, source) if self.detail else None
        used = False
        if self._local_on():
            src = np.zeros(len(Yin), int)
            corr = self._local_correction("asym", Yin, src, [source], target, amount)
            if corr is not None:
                Y, used = Y + corr, True
                if self.detail:
                    Y0 = Y0 + self._local_correction("asym", Yin, src, [source], target, 0.0)
        out = self._result(Y, margin, warn, x, Y0)
        out.local = used
        return out

    def unknown(self, frames, target: str, amount: float = 1.0, *, window: int | None = None,
                max_iter: int = 100, margin: float = 0.5, warn: bool = True) -> Restyled:
        """Unknown expression: infer style and content (Eq. 2.12, 2.13), render in ``target``.

        ``window``: frames over which the style is held constant (default: the whole input).
        ``amount`` interpolates from the inferred style vector to the target's (Eq. 2.15).  The
        local correction uses the training style nearest to each window's inferred style.
        """
        self._check_fitted()
        amount = _amount(amount)
        S = self.symmetric_
        at = S.style_vector(target)
        x = self._flat(frames)
        Yin = self.encode(x)
        anchor = None
        if self.offset_ > 0:                                            # the constant coordinate of each bundle block
            block = Yin.shape[1] // self.bundle
            anchor = (np.arange(self.bundle) * block, self.offset_)
        res = S.infer(Yin, window=window, max_iter=max_iter, anchor=anchor)
        if self._points_on():                                          # each frame from its nearest style
            near = res.nearest[np.minimum(np.arange(len(x)), len(res.nearest) - 1)]
            out = self._points_result(x, near, list(self.styles_), target, amount, margin, warn)
            out.inferred = res
            out.style_weights = self._style_weights(res.style)
            return out
        a = (1 - amount) * res.style + amount * at
        Y = S.render(res.content, a)
        Y0 = S.render(res.content, res.style) if self.detail else None
        used = False
        if self._local_on():
            corr = self._local_correction("sym", Yin, res.nearest, list(self.styles_), target, amount)
            if corr is not None:
                Y, used = Y + corr, True
                if self.detail:
                    Y0 = Y0 + self._local_correction("sym", Yin, res.nearest, list(self.styles_), target, 0.0)
        out = self._result(Y, margin, warn, x, Y0)
        out.local = used
        out.inferred = res
        out.style_weights = self._style_weights(res.style)
        return out

    # ------------------------------------------------------------------------------------ local correction
    def _local_pairs(self, kind: str, source: str, target: str):
        """``(tree over source observations, residual source->target, residual source->source)`` or None."""
        key = (kind, source, target)
        cache = self.__dict__.setdefault("_local_cache", {})
        if key in cache:
            return cache[key]
        from scipy.spatial import cKDTree

        found = None
        for ps in self.pair_sets_:
            if source in ps and target in ps and len(ps[source]) >= self.bundle:
                Ys, Yt = self._observe(ps[source]), self._observe(ps[target])
                if kind == "asym":
                    M = self.asymmetric_
                    b = M.content(Ys, source)
                else:
                    M = self.symmetric_
                    b = M.content(Ys, source)
                Rst, Rss = Yt - M.render(b, target), Ys - M.render(b, source)
                loc = self.settings_["local"]
                if isinstance(loc, tuple):
                    found = ("kernel", kernel_fit(Ys, np.concatenate([Rst, Rss], axis=1), loc[1], loc[2]))
                else:
                    found = (cKDTree(Ys), Rst, Rss)
                break
        cache[key] = found
        return found

    def _local_correction(self, kind: str, Yin: np.ndarray, src_index: np.ndarray, sources: list[str],
                          target: str, amount: float) -> np.ndarray | None:
        """Regressed residual (kernel) or mean residual of the ``local`` nearest training frames,
        ``(1 - a) R_ss + a R_st``."""
        corr = np.zeros_like(Yin)
        done = False
        for si in np.unique(src_index):
            pairs = self._local_pairs(kind, sources[si], target)
            if pairs is None:
                continue
            m = src_index == si
            if isinstance(pairs[0], str):                               # kernel ridge regression
                P = kernel_predict(pairs[1], Yin[m])
                h = P.shape[1] // 2
                corr[m] = (1 - amount) * P[:, h:] + amount * P[:, :h]
                done = True
                continue
            tree, Rst, Rss = pairs
            k = int(min(int(self.settings_["local"]), tree.n))
            _, nb = tree.query(Yin[m], k=k)
            nb = nb.reshape(int(m.sum()), k)
            corr[m] = (1 - amount) * Rss[nb].mean(1) + amount * Rst[nb].mean(1)
            done = True
        return corr if done else None

    def _local_on(self) -> bool:
        loc = self.settings_["local"]
        return isinstance(loc, tuple) or int(loc) > 0

    def _points_on(self) -> bool:
        loc = self.settings_["local"]
        return isinstance(loc, tuple) and loc[0] == "points"

    def _point_map(self, source: str, target: str):
        """The point-local change ``source -> target`` fitted on their paired training frames (or None)."""
        key = ("points", source, target)
        cache = self.__dict__.setdefault("_local_cache", {})
        if key not in cache:
            found = None
            P = point_count(self.frame_shape_)
            for ps in self.pair_sets_:
                if source in ps and target in ps and P is not None:
                    xs, xt = (ps[st] @ self.basis_.T + self.mean_ for st in (source, target))
                    found = fit_point_map(xs.reshape(len(xs), P, 3), xt.reshape(len(xt), P, 3),
                                          self.mean_.reshape(P, 3), self.settings_["local"])
                    break
            cache[key] = found
        return cache[key]

    def _point_path(self, source: str, target: str) -> list[str] | None:
        """Styles from ``source`` to ``target`` linked by paired training frames: ``[source, target]``, or
        through one style paired with both (an added style and the training styles), or None."""
        if self._point_map(source, target) is not None:
            return [source, target]
        for mid in self.styles_:
            if mid not in (source, target) and self._point_map(source, mid) is not None \
                    and self._point_map(mid, target) is not None:
                return [source, mid, target]
        return None

    def _points_result(self, x: np.ndarray, src_index: np.ndarray, sources: list[str], target: str,
                       amount: float, margin: float, warn: bool) -> Restyled:
        """The input plus ``amount`` times the point-local change from each frame's source style."""
        P = point_count(self.frame_shape_)
        out = x.copy()
        used = False
        for si in np.unique(src_index):
            sel = src_index == si
            if sources[si] == target:
                continue
            path = self._point_path(sources[si], target)
            if path is None:
                raise InvalidDataError(f"no paired training frames link '{sources[si]}' to '{target}' for the "
                                       "point-local translation; fit with local=0 or a kernel correction")
            y = x[sel].reshape(-1, P, 3)
            for a, b in zip(path[:-1], path[1:], strict=True):           # through the style the examples were paired with
                y = y + self._point_map(a, b).predict(y)
            out[sel] = x[sel] + amount * (y.reshape(int(sel.sum()), -1) - x[sel])
            used = True
        r = Restyled(out.reshape((len(out),) + tuple(self.frame_shape_)),
                     self._range((out - self.mean_) @ self.basis_, margin, warn))
        r.local = used
        return r

    def _style_weights(self, a: np.ndarray) -> np.ndarray:
        """Per-frame affine weights (sum 1) of the training styles reproducing style vectors ``a``."""
        V = self.symmetric_.style_vectors_[: len(self.styles_)]          # (S, I)
        M = np.vstack([V.T, np.ones((1, len(V)))])                        # (I + 1, S)
        rhs = np.vstack([a.T, np.ones((1, len(a)))])
        w = np.linalg.lstsq(M, rhs, rcond=None)[0].T
        return unbundle_frames(np.tile(w, self.bundle), self.bundle) if self.bundle > 1 else w

    def add_style(self, name: str, frames, like: tuple[str, np.ndarray], *, shrink: float | str = "auto") -> StyleModel:
        """Untrained expression: fit a new style from examples of it (translation to a new style).

        The examples' content is found from the same text in a known style (Eq. 2.10) and the new
        style's matrix fitted to it (:meth:`AsymmetricBilinearModel.add_style`; in the symmetric
        model the style gets a dimension of its own).  An untrained expression usually moves the
        face where no training style did (sadness raises the inner brows): when the PCA basis
        keeps less than ``variance`` of the examples' variation, the basis is extended by the
        principal directions of what it misses (the training styles get 0 along them).

        Parameters
        ----------
        name : str
        frames : (T, ...) float
            Frames in the new style.
        like : (style, frames)
            The same text in a known style, aligned frame by frame with ``frames`` (for example by
            :func:`~._align.align_performances` and :func:`~._align.warp_performance`).
        shrink : float or "auto"
            How strongly the new style's matrix is pulled towards the known style's matrix plus the
            examples' mean offset (the additive edit), relative to the mean squared content
            (:func:`~._select.select_style_ridge`); 0: plain least squares (the thesis).
            ``"auto"`` (default): chosen by blocked cross-validation on the examples; the value
            used and the scores are in ``added_[name]``.  A :class:`StyleFitWarning` says when the
            examples leave the style at (or near) the additive offset.
        """
        self._check_fitted()
        known, x_new, x_known = self._style_examples(name, frames, like)
        self._extend_basis(x_new - self.mean_)
        z = (x_new - self.mean_) @ self.basis_
        self.coef_lo_, self.coef_hi_ = (np.minimum(self.coef_lo_, z.min(0)),
                                        np.maximum(self.coef_hi_, z.max(0)))
        y_new, y_known = self.encode(x_new), self.encode(x_known)
        A = self.asymmetric_
        b = A.content(y_known, known)
        Ak = A.style_matrix(known)
        w = ones_weights(A.content_vectors_)
        ridge, table = self._new_style_ridge(name, known, shrink, b, y_new, y_known, Ak, w)
        self._fit_new_style(name, known, y_new, y_known, b, Ak, w, ridge)
        self.added_ = {**getattr(self, "added_", {}), str(name): {"shrink": ridge, "table": table}}
        self.styles_ = [*self.styles_, str(name)]
        self.pair_sets_.append({known: (x_known - self.mean_) @ self.basis_, name: z})
        self._local_cache = {}
        return self

    def _style_examples(self, name: str, frames,
                        like: tuple[str, np.ndarray]) -> tuple[str, np.ndarray, np.ndarray]:
        """Check :meth:`add_style`'s arguments; returns ``(known, x_new, x_known)``.

        ``x_new`` ``(T, D)`` and ``x_known`` ``(T, D)`` are the flattened example frames of the new
        style and of the known style ``known`` (``like``); raises :class:`InvalidDataError` when
        ``name`` is already a style, ``known`` is not one, or the two differ in length.
        """
        known, kf = like
        if name in self.styles_:
            raise InvalidDataError(f"style '{name}' is already in the model")
        if known not in self.styles_:
            raise InvalidDataError(f"unknown style '{known}'; the model has {', '.join(self.styles_)}")
        x_new, x_known = self._flat(frames), self._flat(kf)
        if len(x_new) != len(x_known):
            raise InvalidDataError(f"style '{name}': {len(x_new)} example frames but {len(x_known)} "
                                   f"frames in '{known}'; align them first")
        return known, x_new, x_known

    def _new_style_ridge(self, name: str, known: str, shrink: float | str, b: np.ndarray, y_new: np.ndarray,
                         y_known: np.ndarray, Ak: np.ndarray, w: np.ndarray) -> tuple[float, list]:
        """The shrinkage ``ridge`` of a new style's matrix, and the cross-validation's scores.

        ``shrink="auto"``: chosen by :func:`~._select.select_style_ridge` from the contents ``b``
        ``(T, J)``, the observations ``y_new`` and ``y_known`` ``(T, K)``, the known style's matrix
        ``Ak`` ``(K, J)`` and ``w`` ``(J,)`` (:func:`~._select.ones_weights`), scored on the
        non-constant coordinates, with a :class:`StyleFitWarning` (at :meth:`add_style`'s caller)
        when it ends at the strongest shrinkage or the examples are too few; else ``float(shrink)``
        (checked >= 0) and an empty table.  Returns ``(ridge, table)``.
        """
        const = np.zeros(y_new.shape[1], bool)
        if self.offset_ > 0:
            const[np.arange(self.bundle) * (y_new.shape[1] // self.bundle)] = True
        table: list = []
        if isinstance(shrink, str):
            if shrink != "auto":
                raise InvalidDataError(f"shrink must be a number >= 0 or 'auto', got {shrink!r}")
            ridge, table = select_style_ridge(b, y_new, y_known, Ak, w, score_cols=np.flatnonzero(~const),
                                              detail=self.detail, local=self.settings_["local"],
                                              bundle=self.bundle)
            if not table or ridge >= max(STYLE_RIDGE_GRID):
                how = (f"{len(b)} example frames are too few to cross-validate" if not table else
                       "cross-validation on the examples chose the strongest shrinkage")
                warnings.warn(f"style '{name}': {how}; its matrix stays close to '{known}' plus the "
                              f"examples' mean offset (shrink {ridge:.3g}, {len(b)} frames for {b.shape[1]} "
                              "content dimensions)", StyleFitWarning, stacklevel=3)
        else:
            ridge = float(shrink)
            if not ridge >= 0:
                raise InvalidDataError(f"shrink must be >= 0, got {shrink}")
        return ridge, table

    def _fit_new_style(self, name: str, known: str, y_new: np.ndarray, y_known: np.ndarray, b: np.ndarray,
                       Ak: np.ndarray, w: np.ndarray, ridge: float) -> None:
        """Add the new style to both bilinear models, each pulled by ``ridge`` towards its additive edit.

        The asymmetric model's matrix is pulled towards ``Ak + d w'`` and the symmetric model's new
        core slice towards the known style's ``W a_known`` plus ``d`` along its content weights, with
        ``d`` ``(K,)`` the examples' mean difference ``y_new - y_known``; ``b`` ``(T, J)``: the
        asymmetric model's contents of ``y_known``.
        """
        A, S = self.asymmetric_, self.symmetric_
        d = (y_new - y_known).mean(0)
        A.add_style(name, y_new, b, ridge=ridge, toward=Ak + np.outer(d, w))
        bs = S.content(y_known, known)
        Mk = np.einsum("i,ijk->jk", S.style_vector(known), S.core_)
        S.add_style(name, y_new, bs, ridge=ridge, toward=Mk + np.outer(ones_weights(S.content_vectors_), d))

    def _extend_basis(self, d: np.ndarray) -> int:
        """Grow the PCA basis until it keeps ``variance`` of the rows of ``d`` (about the mean)."""
        z = d @ self.basis_
        tot, kept = float(np.sum(d**2)), float(np.sum(z**2))
        variance = float(self.settings_["variance"])
        if tot <= 0 or kept >= variance * tot:
            return 0
        r = d - z @ self.basis_.T
        _, s, vt = np.linalg.svd(r, full_matrices=False)
        need = variance * tot - kept
        k = int(min(np.searchsorted(np.cumsum(s**2), need * (1 - 1e-12)) + 1, len(s)))
        E = vt[:k].T
        E -= self.basis_ @ (self.basis_.T @ E)                         # orthogonal to the basis (rounding)
        E, _ = np.linalg.qr(E)
        K = self.n_components_
        block = K + (1 if self.offset_ > 0 else 0)
        pos = np.repeat(np.arange(1, self.bundle + 1) * block, k)
        self.asymmetric_.insert_dims(pos)
        self.symmetric_.insert_dims(pos)
        self.basis_ = np.concatenate([self.basis_, E], axis=1)
        self.pair_sets_ = [{st: np.pad(v, ((0, 0), (0, k))) for st, v in ps.items()} for ps in self.pair_sets_]
        self.coef_lo_ = np.concatenate([self.coef_lo_, np.zeros(k)])
        self.coef_hi_ = np.concatenate([self.coef_hi_, np.zeros(k)])
        return k

    def add_style_take(self, name: str, take: Performance, known: str, known_take: Performance) -> StyleModel:
        """:meth:`add_style` from two takes of the same text: ``take`` is aligned to ``known_take`` first."""
        self._check_fitted()
        kt = self._conform(known_take)
        tk = self._conform(take)
        al = self._align(kt, tk)
        return self.add_style(name, frame_vectors(warp_performance(tk, al)), like=(known, frame_vectors(kt)))

    def _result(self, Y: np.ndarray, margin: float, warn: bool, x: np.ndarray | None = None,
                Y0: np.ndarray | None = None) -> Restyled:
        """Frames of rendered observations ``Y``; with ``Y0`` (the input's own rendering) the input
        ``x`` plus the rendered change ``Y - Y0`` (``detail``)."""
        z = self._coefs(Y)
        if Y0 is None or x is None:
            flat = z @ self.basis_.T + self.mean_
        else:
            dz = z - self._coefs(Y0)
            flat = x + dz @ self.basis_.T
            z = (x - self.mean_) @ self.basis_ + dz
        return Restyled(flat.reshape((len(z),) + tuple(self.frame_shape_)), self._range(z, margin, warn))

    # ------------------------------------------------------------------------------------ takes
    def transform(self, take: Performance, to: str, amount: float = 1.0, *, source: str | None = None,
                  window: int | None = None, margin: float = 0.5, warn: bool = True) -> Restyled:
        """A take with its emotion changed to ``to``: known expression when ``source`` is given, else unknown.

        Weight takes come back with weights clipped at 0 (blendshape weights are not negative).

        Returns
        -------
        Restyled
            ``.take``: same times, kind, head motion and audio as ``take``.
        """
        self._check_fitted()
        p = self._conform(take)
        if to not in self.styles_:
            raise InvalidDataError(f"unknown target style '{to}'; the model has {', '.join(self.styles_)}")
        x = frame_vectors(p)
        if source is not None:
            if source not in self.styles_:
                raise InvalidDataError(f"unknown source style '{source}'; the model has {', '.join(self.styles_)}")
            r = self.known(x, source, to, amount, margin=margin, warn=warn)
        else:
            r = self.unknown(x, to, amount, window=window, margin=margin, warn=warn)
        f = r.frames
        if p.kind == "weights":
            r.take = take.with_weights(np.maximum(f, 0.0), self.names_)
        elif p.kind == "points":
            r.take = take.with_points(f)
        else:
            r.take = take.with_vertices(f, take.mesh, take.unit)
        return r

    def _after_load(self) -> None:
        self._local_cache = {}
        self.alignments_ = {}
        self.selection_ = None
