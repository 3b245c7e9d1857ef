"""Protocol P3 data: real speech content with emotions layered on by a rig, each at its own tempo.

The content is the mouth and jaw channels of a real Live Link Face take; each style is an entry of
:data:`~faceretarget.cloning.tables.EMOTIONS`.  A styled frame is the rig at the composition of the
emotion's displacement ``d_e`` with the content's displacement ``d_p(t)`` by Pyun et al.'s Sec. 2
rule (:func:`~faceretarget.cloning.composition.compose_displacements`, with the per-vertex blend
weight ``beta`` of :func:`~faceretarget.cloning.composition.compose_key_models` computed from the
emotion and viseme tables on the whole mesh), so around the mouth the emotion and the speech
interact nonlinearly::

    x_s(t) = x0 + d_p(t) + d_e(s) - beta * gamma(d_p(t)) * (d_e(s) . u(t)) u(t),   u = d_p / |d_p|

Each style is played at its own tempo: style ``s``'s frame ``k`` (its own time ``tau = k / fps``)
shows the content at time ``phi_s(tau)``, a known smooth monotone warp (:class:`StyleWarp`)::

    phi(tau) = r0 * (tau + a * P / (2 pi) * (sin(2 pi tau / P + ph) - sin(ph)))
    phi'(tau) = r0 * (1 + a cos(2 pi tau / P + ph)) > 0          (a < 1)

so the takes have different lengths and must be aligned before a style/content model can pair
their frames.  The takes have no audio: alignment is by face features.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..cloning import (
    EMOTIONS,
    VISEMES,
    compose_displacements,
    compose_key_models,
    table_shapes,
    weight_vector,
)
from ..errors import InvalidDataError
from ..names import ARKIT_NAMES, normalize_name
from ..performance import Performance
from ..rig import Rig

__all__ = ["StyleWarp", "P3Takes", "make_p3_takes", "DEFAULT_WARPS", "content_channels"]


@dataclass(frozen=True)
class StyleWarp:
    """A smooth monotone time warp ``phi(tau)`` from a style take's time to the content's time.

    Parameters
    ----------
    rate : float
        Mean tempo ``r0`` (content seconds per style second; > 1 plays faster).
    amplitude : float
        Relative tempo modulation ``a`` in [0, 1).
    period : float
        Period ``P`` of the modulation, seconds.
    phase : float
        Phase ``ph`` of the modulation, radians.
    """

    rate: float = 1.0
    amplitude: float = 0.0
    period: float = 6.0
    phase: float = 0.0

    def __post_init__(self) -> None:
        if not (self.rate > 0 and 0 <= self.amplitude < 1 and self.period > 0):
            raise InvalidDataError(f"bad warp {self}: need rate > 0, 0 <= amplitude < 1, period > 0")

    def content_time(self, tau) -> np.ndarray:
        """``phi(tau)``: content time (s) shown at style time ``tau`` (s)."""
        t = np.asarray(tau, dtype=np.float64)
        w = 2 * np.pi / self.period
        return self.rate * (t + self.amplitude / w * (np.sin(w * t + self.phase) - np.sin(self.phase)))

    def style_time(self, content_t, *, step: float = 1e-3) -> np.ndarray:
        """``phi^-1``: the style time (s) at which content time ``content_t`` is shown."""
        c = np.asarray(content_t, dtype=np.float64)
        top = float(np.max(c, initial=0.0))
        n = int(np.ceil((top / self.rate / (1 - self.amplitude) + 1.0) / step)) + 2
        grid = np.arange(n) * step
        return np.interp(c, self.content_time(grid), grid)


#: The P3 tempo of each style: neutral is mildly warped too, so no take is the content's own clock.
DEFAULT_WARPS: dict[str, StyleWarp] = {
    "neutral": StyleWarp(1.0, 0.10, 11.0, 0.0),
    "happy": StyleWarp(1.08, 0.15, 7.0, 1.0),
    "sad": StyleWarp(0.85, 0.15, 9.0, 2.0),
    "surprised": StyleWarp(1.05, 0.20, 6.0, 0.5),
    "afraid": StyleWarp(1.12, 0.20, 8.0, 3.0),
    "angry": StyleWarp(1.15, 0.20, 5.0, 4.0),
}


def content_channels(names) -> list[int]:
    """Columns of ``names`` that are mouth or jaw channels (``jaw*``, ``mouth*``, ARKit spelling)."""
    out = []
    for j, n in enumerate(names):
        m = normalize_name(n)
        if m.startswith("jaw") or m.startswith("mouth"):
            out.append(j)
    return out


@dataclass(eq=False)
class P3Takes:
    """Styled takes with their ground truth (see :func:`make_p3_takes`).

    Attributes
    ----------
    takes : dict of str to Performance
        One point take ``(T_s, P, 3)`` per style, at its own tempo, times from 0.
    warps : dict of str to StyleWarp
        ``warps[s].content_time(takes[s].times)`` is the content time of every frame.
    features : (P,) int
        Rig vertices used as feature points.
    neutral : (P, 3) float
        The rig's neutral at the features.
    lips : (L,) int
        Positions of the lip landmarks among the features (empty when the features are not the
        68 landmarks).
    unit : str
        The rig's unit.
    content_duration : float
        Seconds of content.
    """

    takes: dict[str, Performance]
    warps: dict[str, StyleWarp]
    features: np.ndarray
    neutral: np.ndarray
    lips: np.ndarray
    unit: str
    content_duration: float
    _content_times: np.ndarray = field(repr=False, default=None)
    _content_disp: np.ndarray = field(repr=False, default=None)      # (Tc, P, 3)
    _emotion_disp: dict = field(repr=False, default=None)            # style -> (P, 3)
    _beta: np.ndarray = field(repr=False, default=None)
    _tau: float = 0.0

    def render(self, style: str, content_t, amount: float = 1.0) -> np.ndarray:
        """Ground truth: the rig's features in ``style`` showing the content at times ``content_t``.

        Parameters
        ----------
        style : str
        content_t : (T,) float
            Content times in seconds (clipped to the content's span).
        amount : float
            Scale of the emotion's weights (0.5: half the emotion; 1.5: the rig driven 50% beyond
            it), the ground truth of interpolation and exaggeration.

        Returns
        -------
        (T, P, 3) float
        """
        if style not in self._emotion_disp:
            raise InvalidDataError(f"P3: unknown style '{style}', have {', '.join(self._emotion_disp)}")
        c = np.clip(np.asarray(content_t, np.float64).reshape(-1), 0.0, self.content_duration)
        src = self._content_times
        k = np.clip(np.searchsorted(src, c, side="right") - 1, 0, len(src) - 2)
        f = np.clip((c - src[k]) / (src[k + 1] - src[k]), 0.0, 1.0)[:, None, None]
        dp = (1 - f) * self._content_disp[k] + f * self._content_disp[k + 1]
        de = amount * self._emotion_disp[style]
        return self.neutral + compose_displacements(de, dp, self._beta, min_length=self._tau)

    def truth_on(self, style: str, ref_style: str, ref_times) -> np.ndarray:
        """Ground truth of ``style`` at the content that ``ref_style``'s take shows at ``ref_times``."""
        return self.render(style, self.warps[ref_style].content_time(ref_times))

    def true_take_time(self, take_style: str, ref_style: str, ref_times) -> np.ndarray:
        """Where in ``take_style``'s take (its own seconds) the content of ``ref_style`` at ``ref_times`` is."""
        return self.warps[take_style].style_time(self.warps[ref_style].content_time(ref_times))


def _content_displacements(rig: Rig, perf: Performance, feat: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    if perf.weights is None:
        raise InvalidDataError(f"{perf.source}: P3 content must be a weight take (Live Link Face)")
    cols = content_channels(perf.names)
    if not cols:
        raise InvalidDataError(f"{perf.source}: no mouth or jaw channels")
    W = rig.map_weights([perf.names[j] for j in cols], perf.weights[:, cols], source=perf.source, warn=False)
    D = rig.deltas[:, feat].reshape(rig.n_shapes, -1)
    return perf.times - perf.times[0], (W @ D).reshape(len(W), len(feat), 3)


def make_p3_takes(rig: Rig, content: Performance, styles=("neutral", "happy", "angry", "sad"), *,
                  features="landmarks", warps: dict[str, StyleWarp] | None = None,
                  fps: float = 30.0, duration: float | None = None) -> P3Takes:
    """Styled takes of one real speech content for protocol P3 (``EVALUATION.md``).

    Parameters
    ----------
    rig : Rig
        An ARKit-style rig (``ict-face``).
    content : Performance
        A weight take; only its mouth and jaw channels are used (:func:`content_channels`).
    styles : sequence of str
        Keys of :data:`~faceretarget.cloning.tables.EMOTIONS`.
    features : "landmarks", "all", int or (P,) int
        Feature vertices: the rig's landmarks, every vertex, every ``n``-th vertex, or indices.
    warps : dict, optional
        Tempo of each style (default :data:`DEFAULT_WARPS`).
    fps : float
        Frame rate of every styled take.
    duration : float, optional
        Use only the first ``duration`` seconds of content.

    Returns
    -------
    P3Takes
    """
    if isinstance(features, str) and features == "landmarks":
        if rig.landmarks is None:
            raise InvalidDataError(f"{rig.name}: no landmarks")
        feat = rig.landmarks
    elif isinstance(features, str) and features == "all":
        feat = np.arange(rig.n_vertices)
    elif np.isscalar(features):
        feat = np.arange(0, rig.n_vertices, int(features))
    else:
        feat = np.asarray(features, dtype=np.int64).reshape(-1)
    warps = dict(DEFAULT_WARPS if warps is None else warps)
    for s in styles:
        if s not in EMOTIONS:
            raise InvalidDataError(f"P3: unknown emotion '{s}', use {', '.join(EMOTIONS)}")
        if s not in warps:
            raise InvalidDataError(f"P3: no warp for style '{s}'")
    ct, cd = _content_displacements(rig, content, feat)
    if duration is not None:
        keep = ct <= duration
        ct, cd = ct[keep], cd[keep]
    T_content = float(ct[-1])
    # beta from the emotion and viseme tables on the whole mesh, exactly as build_key_models does
    shapes = [n for n in ARKIT_NAMES if n in set(table_shapes())]
    We = rig.map_weights(shapes, np.stack([weight_vector(EMOTIONS[k], shapes) for k in EMOTIONS]), warn=False)
    Wv = rig.map_weights(shapes, np.stack([weight_vector(VISEMES[k], shapes) for k in VISEMES]), warn=False)
    flat = rig.deltas.reshape(rig.n_shapes, -1)
    de_all = (We @ flat).reshape(len(We), rig.n_vertices, 3)
    dv_all = (Wv @ flat).reshape(len(Wv), rig.n_vertices, 3)
    _, imp = compose_key_models(rig.neutral.vertices, de_all, dv_all, return_importance=True)
    x0 = rig.neutral.vertices
    tau = 1e-4 * float(np.linalg.norm(x0.max(0) - x0.min(0)))
    emo = {k: de_all[i][feat] for i, k in enumerate(EMOTIONS)}
    lips = np.arange(48, 68) if (rig.landmarks is not None and len(feat) == 68
                                 and np.array_equal(feat, rig.landmarks)) else np.zeros(0, np.int64)
    out = P3Takes({}, {s: warps[s] for s in styles}, feat, x0[feat], lips, rig.unit, T_content,
                  ct, cd, emo, imp.beta[feat], tau)
    for s in styles:
        w = warps[s]
        end = float(w.style_time(T_content))
        tau_k = np.arange(int(np.floor(end * fps)) + 1) / fps
        pts = out.render(s, w.content_time(tau_k))
        out.takes[s] = Performance.from_points(pts, times=tau_k, fps=fps, unit=rig.unit,
                                               source=f"p3:{s}")
    return out
