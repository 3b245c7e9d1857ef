"""A character's own shapes from tracked face landmarks, with the tracker's scores as a prior.

A video tracker such as MediaPipe's Face Landmarker gives, per frame, 3D face landmarks and its own
estimate of the 52 ARKit blendshape scores.  Copying the scores onto a character plays the tracker's
idea of each shape, not the character's: how far the character's jaw opens at ``jawOpen = 1``, how
its lips move for ``mouthFunnel`` are the artist's, and the scores of a monocular tracker are biased
(lips rarely close, brows barely move).  :class:`LandmarkSolver` instead fits the character's own
shapes to the motion of the 68 Multi-PIE points, the way Chuang's Ch. 3 fits keyshapes to tracked
features, and uses the calibrated scores only where the landmarks do not see a shape::

    min_w  sum_p a_p || s R (x_tp - x_0p) - sum_k w_k d_kp ||^2  +  lam sum_k c_k (w_k - q_tk)^2,
    lo <= w <= hi                                                                          (per frame)

* ``x_tp`` the frame's 68 points with the head's motion removed (a similarity fit of the stable
  points, :data:`STABLE68`, onto the actor's neutral ``x_0``, then ``refine`` times onto the
  neutral plus the motion the solved expression gives those points), ``s R`` the similarity that maps
  the actor's neutral face onto the character's (Umeyama on all 68 points), ``d_kp`` shape ``k``'s
  displacement of the character's landmark vertex ``p``;
* ``a_p``: the jaw line (which slides along the silhouette in a video) and depth (estimated from
  one view) count less (``contour_weight``, ``depth_weight``);
* ``q_tk`` the tracker's calibrated score of shape ``k`` (0 when it has none), ``c_k = max(|d_k|^2,
  floor mean_j |d_j|^2)``: each shape's prior as strong as ``lam`` times its own landmark signal,
  and shapes the landmarks do not see (eye gaze, pupils, tongue) follow the tracker.

Per-take gains of the tracker's scores (``gains=True``, what :func:`~faceretarget.pipelines.animate` uses):
a monocular tracker's scores follow the face's timing well but not its amplitude (a wide-open jaw reads
0.6, brows barely move).  Before the per-frame solve, one gain per shape is fitted over the whole take so
that the scaled scores best explain the landmarks' motion (many frames per unknown, so per-frame landmark
noise averages out)::

    min_g  sum_t sum_p a_p || s R (x_tp - x_0p) - sum_k g_k q_tk d_kp ||^2  +  mu sum_k (g_k - 1)^2,
    gain_min <= g <= gain_max      (mu: gain_reg times the mean energy of the columns q_tk d_kp)

and the prior becomes ``g_k q_tk``.  The eye shapes (those whose landmark motion lies mostly on the 12 eye
points, whatever they are called) get a gain of at least 1: a monocular tracker under-reads a closed lid
(MediaPipe scores a real closed eye 0.2-0.5), and where its lid points close less than the lids (a
rendered face), a blink would otherwise be fitted away; ``eye_prior`` multiplies the prior strength of the
scored eye shapes, and ``eye_floor`` keeps each at least at its (gained) score after the solve: the 68 points'
two per lid may close a lid further than the tracker reads it, never open it (P11's 24 cached runs: blink F1
0.74 / 0.72 -> 0.77 / 0.79 onto the same / another character, per frame in the live mode 0.62 -> 0.68, the
lids' error within 0.02x of the peer's).  ``mouth_gains=False`` keeps the gains of the mouth shapes (those whose landmark motion lies
mostly on the jaw line and the lips) at 1: the lips' landmarks see the mouth's size themselves, and on an actor
whose mouth is not the character's a mouth gain scales the tracker's idea of the expression by the two mouths'
difference instead (a smile turned into a grimace: P11's smile direction 0.78 with mouth gains, 0.95 without),
while the brows, which a monocular tracker barely moves, keep theirs.  The gains are bounded (``gain_min``,
``gain_max``): a tracker's amplitude is off by less than a factor of two, and unbounded gains of shapes whose
landmark motion other shapes also explain run to 0 or 4 on real video (``browInnerUp`` 0.01, ``mouthClose`` 0.05
on a news clip: a brow raise the tracker saw, taken away).
Measured by P11 (``bench/fidelity.py``, a webcam's perspective): on takes held out of the choice of ``prior``,
``gains`` and ``eye_prior`` (chosen on a range-of-motion take), the mouth region's error is 0.92x the error of
the tracker's scores copied onto the same character and 0.97x onto another.

The solve is one call of :func:`~faceretarget.numerics.solve_bounded` for the whole take (optionally
with temporal smoothing), or per frame for a live stream.  The neutral ``x_0`` is the median of the
take's quietest frames (lips together, lowest summed scores; :func:`neutral_face`) unless given.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..base import Model, WeightsResult
from ..errors import InvalidDataError
from ..headpose import HeadPose
from ..numerics import denoise_take, similarity_fit, solve_bounded, weight_range
from ..rig import Rig

__all__ = ["LandmarkSolver", "LandmarkResult", "STABLE68", "similarity_fit", "neutral_face"]

#: Points of the 68 that move least with expression on the rigs (under 10 % of the largest landmark
#: motion on ICT and ARKit faces): the temples (0, 1, 15, 16), the nose bridge and tip (27-30) and the
#: inner eye corners (39, 42); the nose base moves with the mouth (up to 22 %), outer corners blink.
STABLE68 = np.r_[0, 1, 15, 16, 27:31, 39, 42]
_CONTOUR = np.arange(17)
_EYES = np.arange(36, 48)
_MOUTH = np.r_[0:17, 48:68]
#: Fewer frames than this: no per-take gains (too little to fit one gain per shape from).
MIN_GAIN_FRAMES = 30


@dataclass(eq=False)
class LandmarkResult(WeightsResult):
    """What :meth:`LandmarkSolver.transform` gives: weights of the character's shapes per frame.

    Attributes
    ----------
    weights : (T, K) float
        In the character's shape order (``names``), inside the solver's range.
    names : list of str
    times : (T,) float or None
    residual : (T,) float
        RMS landmark misfit per frame in the character's units.
    head_scale : (T,) float
        The similarity scale of each frame onto the neutral (the face's distance to the camera).
    prior_gains : (K,) float or None
        The per-take gains of the tracker's scores (``gains=True``), else None.
    """

    weights: np.ndarray
    names: list[str]
    times: np.ndarray | None
    residual: np.ndarray
    head_scale: np.ndarray
    head: HeadPose | None = None
    audio: np.ndarray | None = None
    audio_rate: float | None = None
    source: str = "landmarks"
    prior_gains: np.ndarray | None = None


class LandmarkSolver(Model):
    """Weights of a character's own shapes from 68 tracked landmarks, the tracker's scores as prior.

    Parameters
    ----------
    prior : float
        ``lam``: strength of the tracker's scores relative to each shape's landmark signal.
    floor : float
        Least prior strength of a shape, as a share of the mean ``|d_k|^2``.
    depth_weight : float
        Weight of the depth coordinate (monocular depth is an estimate).
    contour_weight : float
        Weight of the jaw-line points 0-16.
    weight_range : (lo, hi)
        The weights' range (a FACS rig's sliders: ``(0, 1)``).
    smooth : float
        Temporal smoothing of whole-take solves (:func:`~faceretarget.numerics.solve_bounded`'s
        ``smooth``, relative to the mean ``|d_k|^2``); per-frame solves ignore it.
    denoise : bool
        Whole takes: remove capture noise from the landmark motion first, with the noise level
        estimated from the take (:func:`~faceretarget.numerics.denoise_take`: a clean or already
        filtered take, whose spectrum has no noise floor, is left as it is); per-frame solves skip it.
    refine : int
        Solves after the first, each aligning the head to the neutral plus the expression's own
        motion of the stable points found by the previous one (:meth:`align`).
    gains : bool
        Whole takes of at least :data:`MIN_GAIN_FRAMES` frames with a prior: fit one gain per shape of
        the tracker's scores to the landmarks' motion first (module docstring).
    gain_reg : float
        ``mu``: how strongly the gains are held at 1, relative to the mean energy of the gain fit's
        columns.
    gain_min, gain_max : float
        The smallest and the largest gain of a scored shape.
    eye_prior : float
        Factor on the prior strength of the eye shapes (module docstring).
    mouth_gains : bool
        Fit per-take gains for the mouth shapes too (those whose landmark motion lies mostly on the jaw line
        and the lips, whatever they are called); False keeps theirs at 1 (module docstring).
    unscored_prior : float, optional
        ``lam`` of the shapes the tracker gives no score for in a take (all zero): a strong prior would
        hold them at rest.  Default: ``prior``.
    eye_floor : bool
        The eye shapes the tracker scores end at least at their (gained) prior: the landmarks may close a lid
        further than the tracker reads it, never less (module docstring).
    """

    def __init__(self, prior: float = 0.1, floor: float = 0.05, depth_weight: float = 0.5,
                 contour_weight: float = 0.5, weight_range=(0.0, 1.0), smooth: float = 0.0, refine: int = 2,
                 denoise: bool = True, gains: bool = False, gain_reg: float = 0.05, gain_max: float = 4.0,
                 gain_min: float = 0.0,
                 eye_prior: float = 1.0, unscored_prior: float | None = None, mouth_gains: bool = True,
                 eye_floor: bool = False):
        self.unscored_prior = unscored_prior
        self.eye_floor = eye_floor
        self.mouth_gains = mouth_gains
        self.gains = gains
        self.gain_reg = gain_reg
        self.gain_max = gain_max
        self.gain_min = gain_min
        self.eye_prior = eye_prior
        self.prior = prior
        self.floor = floor
        self.depth_weight = depth_weight
        self.contour_weight = contour_weight
        self.weight_range = weight_range
        self.smooth = smooth
        self.refine = refine
        self.denoise = denoise

    # ------------------------------------------------------------------------------------ fit
    def fit(self, character: Rig, neutral: np.ndarray) -> LandmarkSolver:
        """Learn the character's landmark shapes and the actor-to-character map.

        Parameters
        ----------
        character : Rig
            With its 68 landmarks (``landmarks68.txt``).
        neutral : (68, 3) float
            The actor's neutral face, +Y up, +Z toward the camera, any unit (pixels).
        """
        rng = weight_range(self.weight_range, what="LandmarkSolver weight_range")
        if rng is None:
            raise InvalidDataError("LandmarkSolver needs a finite weight range, e.g. (0, 1)")
        if not (isinstance(self.refine, int | np.integer) and 0 <= self.refine <= 10):
            raise InvalidDataError(f"LandmarkSolver refine must be an integer in 0..10, got {self.refine}")
        for name in ("prior", "floor", "depth_weight", "contour_weight", "smooth", "gain_reg", "gain_max",
                     "gain_min", "eye_prior") + (("unscored_prior",) if self.unscored_prior is not None else ()):
            v = getattr(self, name)
            if not (np.isfinite(v) and v >= 0):
                raise InvalidDataError(f"LandmarkSolver {name} must be a finite number >= 0, got {v}")
        lm = character.landmarks
        if lm is None or len(lm) != 68:
            raise InvalidDataError(f"{character.name}: the character needs its 68 landmarks (landmarks68.txt) "
                                   f"to be driven by tracked landmarks, it has {0 if lm is None else len(lm)}")
        X0 = np.asarray(neutral, dtype=np.float64)
        if X0.shape != (68, 3) or not np.isfinite(X0).all():
            raise InvalidDataError(f"LandmarkSolver: the actor's neutral must be (68, 3) finite points, "
                                   f"got shape {X0.shape}")
        C0 = character.neutral.vertices[lm]
        s, R, c = similarity_fit(X0, C0[None])                # character ~ s actor R' + c
        D = character.deltas[:, lm]                          # (K, 68, 3)
        a = np.ones((68, 3))
        a[_CONTOUR] *= self.contour_weight
        a[:, 2] *= self.depth_weight
        sq = np.sqrt(a).reshape(-1)
        K = (D.reshape(len(D), -1) * sq).T                   # (204, K)
        e = (K ** 2).sum(axis=0)
        mean_e = float(e.mean()) if e.size else 1.0
        if mean_e <= 0:
            raise InvalidDataError(f"{character.name}: no shape moves a landmark vertex")
        self.names_ = list(character.names)
        self.neutral_ = X0
        self.scale_ = float(s[0])
        self.rotation_ = R[0]
        self.row_weights_ = sq
        self.keys_ = K
        self.deltas_ = D.reshape(len(D), -1).T              # (204, K), unweighted
        # eye shapes: most of their landmark motion on the 12 eye points (36-47), whatever their names
        eye_e = (D[:, _EYES] ** 2).sum(axis=(1, 2))
        self.eye_shapes_ = eye_e > 0.5 * np.maximum((D ** 2).sum(axis=(1, 2)), 1e-300)
        # mouth shapes: most of their landmark motion on the jaw line and the lips (0-16, 48-67)
        mouth_e = (D[:, _MOUTH] ** 2).sum(axis=(1, 2))
        self.mouth_shapes_ = mouth_e > 0.5 * np.maximum((D ** 2).sum(axis=(1, 2)), 1e-300)
        self.prior_base_ = np.sqrt(np.maximum(e, self.floor * mean_e))
        self.prior_weights_ = np.sqrt(self.prior * np.where(self.eye_shapes_, self.eye_prior, 1.0)) * self.prior_base_
        self.range_ = rng
        self.smooth_ = float(self.smooth) * mean_e
        self.unit_ = character.unit
        return self

    # ------------------------------------------------------------------------------------ apply
    def align(self, points: np.ndarray, expression: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """The frames with the head's motion removed, in the actor's neutral frame.

        Parameters
        ----------
        points : (T, 68, 3) float
            +Y up, +Z toward the camera, the unit of the neutral.
        expression : (T, 68, 3) float, optional
            The expression's own motion of the points in the neutral's frame (from a first solve):
            the stable points are fitted to ``neutral + expression``, so that what little they move
            with the face is not taken for head motion.

        Returns
        -------
        aligned : (T, 68, 3) float
        scale : (T,) float
            Each frame's similarity scale onto the neutral.
        """
        self._check_fitted("align")
        P = self._points(points)
        ref = self.neutral_[STABLE68] if expression is None else self.neutral_[STABLE68] + expression[:, STABLE68]
        s, R, c = similarity_fit(ref, P[:, STABLE68])       # P ~ s ref R' + c
        aligned = np.einsum("tpi,tij->tpj", P - c[:, None], R) / s[:, None, None]
        return aligned, s

    def _points(self, points) -> np.ndarray:
        P = np.asarray(points, dtype=np.float64)
        if P.ndim == 2:
            P = P[None]
        if P.ndim != 3 or P.shape[1:] != (68, 3):
            raise InvalidDataError(f"LandmarkSolver: expected (T, 68, 3) points, got shape {P.shape}")
        bad = ~np.isfinite(P).all(axis=(1, 2))
        if bad.any():
            raise InvalidDataError(f"LandmarkSolver: frame {int(np.flatnonzero(bad)[0])} has non-finite points "
                                   "(frames without a face must be left out or filled first)")
        return P

    def displacements(self, points: np.ndarray, expression: np.ndarray | None = None) -> np.ndarray:
        """The frames' landmark motion on the character, ``s R (x_t - x_0)``: (T, 68, 3) in its units
        (``expression``: as :meth:`align`)."""
        return self._on_character(self.align(points, expression)[0])

    def _on_character(self, aligned: np.ndarray) -> np.ndarray:
        """Aligned frames' motion from the neutral, mapped onto the character: ``s R (x_t - x_0)``."""
        return self.scale_ * np.einsum("tpj,ij->tpi", aligned - self.neutral_, self.rotation_)

    def transform(self, points: np.ndarray, prior: np.ndarray | None = None, times=None, *,
                  smooth: bool = True, scored: np.ndarray | None = None) -> LandmarkResult:
        """Weights of the character's shapes for every frame.

        Parameters
        ----------
        points : (T, 68, 3) float
            Tracked points, +Y up, +Z toward the camera, the unit of the neutral.
        prior : (T, K) float, optional
            The tracker's calibrated scores in the character's shape order (0 where it has none).
        times : (T,) float, optional
        smooth : bool
            Apply the temporal smoothing (``smooth`` parameter) over the frames given.
        scored : (K,) bool, optional
            The shapes the tracker has a score for (``unscored_prior`` applies to the others); by default
            those whose prior is not zero throughout.
        """
        self._check_fitted()
        P = self._points(points)
        T, K = len(P), len(self.names_)
        Q = np.zeros((T, K)) if prior is None else np.asarray(prior, dtype=np.float64)
        if Q.shape != (T, K):
            raise InvalidDataError(f"LandmarkSolver: prior must be (T, K) = ({T}, {K}), got {Q.shape}")
        Q = np.nan_to_num(Q, nan=0.0)
        gains = None
        if self.gains and prior is not None and T >= MIN_GAIN_FRAMES:
            gains = self._prior_gains(P, Q)
            Q = Q * gains
        pw = self.prior_weights_
        if self.unscored_prior is not None and prior is not None:
            scored = np.abs(Q).max(axis=0) > 0 if scored is None else np.asarray(scored, bool).reshape(K)
            lam = np.where(scored, self.prior * np.where(self.eye_shapes_, self.eye_prior, 1.0), float(self.unscored_prior))
            pw = np.sqrt(lam) * self.prior_base_
        A = np.vstack([self.keys_, np.diag(pw)])
        lo, hi = self.range_
        expr = None
        for it in range(1 + self.refine):
            aligned, scale = self.align(P, expr)
            F = self._on_character(aligned).reshape(-1, 68 * 3)
            if self.denoise and smooth and T >= 16:
                F = denoise_take(F, None if times is None else np.asarray(times, dtype=np.float64))[0]
            F = F * self.row_weights_
            B = np.hstack([F, Q * pw])
            W = solve_bounded(A, B, lo, hi, smooth=self.smooth_ if smooth and T > 1 else 0.0)
            if it == self.refine:
                break
            # the solved face's own motion of the points, back in the actor's neutral frame
            expr = np.einsum("tpi,ij->tpj", (W @ self.deltas_.T).reshape(T, 68, 3),
                             self.rotation_) / self.scale_
        if getattr(self, "eye_floor", False) and prior is not None:     # a model saved before the option: off
            e = self.eye_shapes_ & (np.abs(Q).max(axis=0) > 0)
            W[:, e] = np.maximum(W[:, e], np.clip(Q[:, e], lo, hi))
        res = np.sqrt(((W @ self.keys_.T - F) ** 2).mean(axis=1))
        return LandmarkResult(weights=W, names=list(self.names_), times=None if times is None else np.asarray(times),
                              residual=res, head_scale=scale, prior_gains=gains)

    def _prior_gains(self, P: np.ndarray, Q: np.ndarray) -> np.ndarray:
        """(K,) gains of the tracker's scores that best explain the take's landmark motion (module docstring);
        at least 1 for the eye shapes, 1 for shapes the tracker never scores."""
        F = self._on_character(self.align(P)[0]).reshape(len(P), -1) * self.row_weights_     # (T, 204)
        K = self.keys_
        free = np.abs(Q).max(axis=0) > 1e-6
        g = np.ones(Q.shape[1])
        if not free.any():
            return g
        Kf, Qf = K[:, free], Q[:, free]
        Y = F - Q[:, ~free] @ K[:, ~free].T                                                # (T, 204)
        # the normal equations of the fit without forming its (T * 204, K) matrix X, whose column k at frame t
        # is q_tk K_k:  X'X = (K'K) o (Q'Q),  X'y = sum_t q_t o (K' y_t)
        G = (Kf.T @ Kf) * (Qf.T @ Qf)
        rhs = (Qf * (Y @ Kf)).sum(axis=0)
        mu = self.gain_reg * max(float(np.diag(G).mean()), 1e-300)
        sol = np.linalg.solve(G + mu * np.eye(len(G)), rhs + mu)
        g[free] = np.clip(sol, min(getattr(self, "gain_min", 0.0), self.gain_max), self.gain_max)
        g[self.eye_shapes_] = np.maximum(g[self.eye_shapes_], 1.0)       # lids: never below the tracker's own
        if not getattr(self, "mouth_gains", True):                       # a model saved before the option
            g[self.mouth_shapes_] = 1.0
        return g


def neutral_face(points: np.ndarray, scores: np.ndarray | None = None, share: float = 0.1) -> np.ndarray:
    """The actor's neutral face from a take: the median of its quietest frames, head motion removed.

    Parameters
    ----------
    points : (T, 68, 3) float
        Tracked points (+Y up, +Z toward the camera).
    scores : (T, S) float, optional
        The tracker's (calibrated) scores.  The quietest frames are those best ranked by their
        lip gap (inner lips, over the eye-corner distance) plus, when given, their summed scores.
    share : float
        Share of the frames used (at least one).

    Returns
    -------
    (68, 3) float
        In the frame and scale of the quietest frame.
    """
    P = np.asarray(points, dtype=np.float64)
    if P.ndim != 3 or P.shape[1:] != (68, 3) or len(P) == 0 or not np.isfinite(P).all():
        raise InvalidDataError(f"neutral_face: expected finite (T, 68, 3) points with T >= 1, got shape {P.shape}")
    n = max(1, int(round(share * len(P))))
    # a neutral face is still and has its lips together: rank the frames by their inner-lip gap over
    # the eye-corner distance, and by the summed scores when given, and take the best by both ranks
    gap = np.linalg.norm(P[:, 62] - P[:, 66], axis=1) / np.linalg.norm(P[:, 36] - P[:, 45], axis=1)
    rank = np.argsort(np.argsort(gap, kind="stable"), kind="stable").astype(np.float64)
    if scores is not None:
        S = np.asarray(scores, dtype=np.float64)
        if len(S) != len(P):
            raise InvalidDataError(f"neutral_face: {len(S)} score rows for {len(P)} frames")
        rank += np.argsort(np.argsort(np.nansum(S, axis=1), kind="stable"), kind="stable")
    order = np.argsort(rank, kind="stable")
    Q = P[np.sort(order[:n])]
    ref = Q[0]
    for _ in range(2):                                   # align to the reference, median, again
        s, R, c = similarity_fit(ref[STABLE68], Q[:, STABLE68])
        aligned = np.einsum("tpi,tij->tpj", Q - c[:, None], R) / s[:, None, None]
        ref = np.median(aligned, axis=0)
    return ref
