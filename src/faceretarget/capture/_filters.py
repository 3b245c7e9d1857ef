"""Post-processing of tracked signals: gap filling, neutral calibration, One Euro jitter filter.

All functions work on arrays whose first axis is time, ``(T, ...)``, and are vectorised over the
other axes (channels, landmarks, coordinates); only the causal One Euro recursion loops over time.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import InvalidDataError
from ..numerics import runs

__all__ = ["OneEuroParams", "one_euro", "OneEuroFilter", "fill_gaps", "neutral_baseline", "calibrate_neutral"]


@dataclass(frozen=True)
class OneEuroParams:
    """Parameters of the One Euro filter (Casiez, Roussel and Vogel, CHI 2012).

    The filter is a first-order low-pass whose cutoff frequency rises with the signal's speed::

        cutoff(t) = min_cutoff + beta * |dx/dt|_smoothed

    so slow movements (where jitter shows) are smoothed hard and fast movements (where lag shows)
    pass with little delay.

    Attributes
    ----------
    min_cutoff : float
        Cutoff in Hz when the signal is still.  Lower = less jitter, more lag on slow motion.
    beta : float
        Speed coefficient, in Hz per (signal unit / s).  Higher = less lag on fast motion.  It
        depends on the signal's units; :mod:`faceretarget.capture` applies it to face-relative
        units (see ``docs/capture.md``).
    d_cutoff : float
        Cutoff in Hz of the low-pass applied to the speed estimate itself (1 Hz in the paper).
    """

    min_cutoff: float = 1.0
    beta: float = 5.0
    d_cutoff: float = 1.0

    def __post_init__(self) -> None:
        if not (self.min_cutoff > 0 and self.d_cutoff > 0 and self.beta >= 0):
            raise InvalidDataError(f"One Euro filter needs min_cutoff > 0, d_cutoff > 0, beta >= 0; got "
                                   f"{self.min_cutoff}, {self.beta}, {self.d_cutoff}")

    @classmethod
    def parse(cls, text: str) -> OneEuroParams | None:
        """``"off"`` -> None; ``"on"`` -> defaults; ``"MIN_CUTOFF[,BETA[,D_CUTOFF]]"`` -> those values."""
        t = text.strip().lower()
        if t in ("off", "none", "no", "0"):
            return None
        if t in ("on", "default", "yes"):
            return cls()
        try:
            vals = [float(v) for v in t.split(",")]
        except ValueError:
            raise InvalidDataError(f"--smooth {text!r}: expected 'off', 'on' or MIN_CUTOFF[,BETA[,D_CUTOFF]]") from None
        if not 1 <= len(vals) <= 3:
            raise InvalidDataError(f"--smooth {text!r}: expected 1 to 3 numbers")
        d = cls()
        return cls(*vals, *(d.beta, d.d_cutoff)[len(vals) - 1:])


def _alpha(cutoff: np.ndarray | float, dt: float) -> np.ndarray | float:
    tau = 1.0 / (2.0 * np.pi * cutoff)
    return 1.0 / (1.0 + tau / dt)


def one_euro(x: np.ndarray, times: np.ndarray, params: OneEuroParams | None = None, *,
             vector_axis: int | None = None, scale: float = 1.0, both_ways: bool = False) -> np.ndarray:
    """Filter a signal over time with the One Euro filter (causal, as in the paper; or both ways).

    Parameters
    ----------
    x : (T, ...) float
        Samples; every trailing element is filtered independently (NaN frames are not allowed:
        filter each contiguous run separately, see :func:`runs`).
    times : (T,) float
        Sample times in seconds, strictly increasing (irregular steps are handled exactly).
    params : OneEuroParams, optional
        Defaults to ``OneEuroParams()``.
    vector_axis : int, optional
        When given, the speed that drives the cutoff is the Euclidean norm over this axis (e.g. the
        x, y[, z] of a landmark), so a point's coordinates share one cutoff.
    scale : float
        The speed is divided by ``scale`` before ``beta`` applies (makes ``beta`` unit-free: pass
        e.g. the face width in pixels for pixel landmarks).
    both_ways : bool
        For a whole recording (not a live stream): the mean of the filter run forwards in time and
        run backwards, whose lags are equal and opposite, so the result does not lag (a causal
        pass delays a slow head turn by 2-3 frames at 30 fps); jitter is smoothed as much.

    Returns
    -------
    (T, ...) float64
        Filtered samples; the first sample is passed through (causal).
    """
    p = params or OneEuroParams()
    x = np.asarray(x, dtype=np.float64)
    t = np.asarray(times, dtype=np.float64).reshape(-1)
    if x.shape[0] != t.size:
        raise InvalidDataError(f"one_euro: {t.size} times for {x.shape[0]} samples")
    if both_ways:
        fwd = one_euro(x, t, p, vector_axis=vector_axis, scale=scale)
        if x.shape[0] < 2:
            return fwd
        bwd = one_euro(x[::-1], t[-1] - t[::-1], p, vector_axis=vector_axis, scale=scale)[::-1]
        return 0.5 * (fwd + bwd)
    out = np.empty_like(x)
    if x.shape[0] == 0:
        return out
    if not np.isfinite(x).all():
        raise InvalidDataError("one_euro: the signal holds NaN or infinite samples; filter finite runs only")
    dts = np.diff(t)
    if (dts <= 0).any():
        raise InvalidDataError("one_euro: times must be strictly increasing")
    prev = out[0] = x[0]
    dprev = np.zeros_like(x[0])
    for i in range(1, x.shape[0]):
        dt = dts[i - 1]
        dx = (x[i] - prev) / dt
        dprev = dprev + _alpha(p.d_cutoff, dt) * (dx - dprev)
        speed = np.abs(dprev) if vector_axis is None else np.linalg.norm(dprev, axis=vector_axis, keepdims=True)
        a = _alpha(p.min_cutoff + p.beta * speed / scale, dt)
        prev = out[i] = prev + a * (x[i] - prev)
    return out


class OneEuroFilter:
    """The One Euro filter of :func:`one_euro` one sample at a time, for a live stream.

    Feeding the samples of a signal one by one gives what :func:`one_euro` gives for the whole
    signal (the same arithmetic in the same order)::

        f = OneEuroFilter(params, vector_axis=-1, scale=face_width)
        for t, x in stream:
            y = f(x, t)

    Parameters
    ----------
    params : OneEuroParams, optional
        Defaults to ``OneEuroParams()``.
    vector_axis : int, optional
        Axis of a sample whose Euclidean norm is the speed (see :func:`one_euro`).
    scale : float
        The speed is divided by ``scale`` before ``beta`` applies (see :func:`one_euro`).
    """

    def __init__(self, params: OneEuroParams | None = None, *, vector_axis: int | None = None,
                 scale: float = 1.0):
        if not (np.isfinite(scale) and scale > 0):
            raise InvalidDataError(f"OneEuroFilter: scale must be a positive number, got {scale}")
        self.params = params or OneEuroParams()
        self.vector_axis = vector_axis
        self.scale = float(scale)
        self.reset()

    def reset(self) -> None:
        """Forget the past: the next sample passes through (as after a gap in the signal)."""
        self._t: float | None = None
        self._prev = None
        self._dprev = None

    @property
    def started(self) -> bool:
        """True once a sample has been filtered since the last :meth:`reset`."""
        return self._t is not None

    def __call__(self, x: np.ndarray, t: float) -> np.ndarray:
        """Filter one sample.

        Parameters
        ----------
        x : (...) float
            The sample (finite), the same shape every call.
        t : float
            Its time in seconds, later than the previous sample's.

        Returns
        -------
        (...) float64
            The filtered sample (a new array; the first sample after a reset is passed through).
        """
        x = np.array(x, dtype=np.float64)
        t = float(t)
        if not np.isfinite(x).all():
            raise InvalidDataError("OneEuroFilter: the sample holds NaN or infinite values (reset after a gap)")
        if self._t is None:
            self._t, self._prev, self._dprev = t, x, np.zeros_like(x)
            return x.copy()
        if x.shape != self._prev.shape:
            raise InvalidDataError(f"OneEuroFilter: sample shape {x.shape} differs from the first sample's "
                                   f"{self._prev.shape}")
        dt = t - self._t
        if not dt > 0:
            raise InvalidDataError(f"OneEuroFilter: time {t} s does not follow the previous sample's {self._t} s")
        p = self.params
        dx = (x - self._prev) / dt
        self._dprev = self._dprev + _alpha(p.d_cutoff, dt) * (dx - self._dprev)
        speed = (np.abs(self._dprev) if self.vector_axis is None
                 else np.linalg.norm(self._dprev, axis=self.vector_axis, keepdims=True))
        a = _alpha(p.min_cutoff + p.beta * speed / self.scale, dt)
        self._prev = self._prev + a * (x - self._prev)
        self._t = t
        return np.array(self._prev, dtype=np.float64)




def fill_gaps(x: np.ndarray, valid: np.ndarray, max_gap: int, times: np.ndarray | None = None
              ) -> tuple[np.ndarray, np.ndarray]:
    """Fill short runs of invalid frames by linear interpolation in time.

    Parameters
    ----------
    x : (T, ...) float
        Samples (values of invalid frames are ignored).
    valid : (T,) bool
        Frames that hold a measurement.
    max_gap : int
        Runs of at most this many invalid frames *between two valid frames* are interpolated; longer
        runs, and runs at the start or end of the take, stay invalid (NaN).
    times : (T,) float, optional
        Frame times (interpolation weights); frame indices when omitted.

    Returns
    -------
    filled : (T, ...) float64
        ``x`` with interpolated frames, NaN where still invalid.
    interpolated : (T,) bool
        Frames that were filled.

    >>> y, f = fill_gaps(np.array([0., 9, 2, 9, 9, 9, 6]), np.array([1, 0, 1, 0, 0, 0, 1], bool), 2)
    >>> y.tolist(), f.tolist()
    ([0.0, 1.0, 2.0, nan, nan, nan, 6.0], [False, True, False, False, False, False, False])
    """
    x = np.array(x, dtype=np.float64)
    v = np.asarray(valid, dtype=bool).reshape(-1)
    if v.size != x.shape[0]:
        raise InvalidDataError(f"fill_gaps: mask has {v.size} frames, the signal {x.shape[0]}")
    t = np.arange(v.size, dtype=np.float64) if times is None else np.asarray(times, dtype=np.float64)
    x[~v] = np.nan
    filled = np.zeros_like(v)
    for a, b in zip(*runs(~v), strict=True):
        if a == 0 or b == v.size or b - a > max_gap:
            continue
        w = ((t[a:b] - t[a - 1]) / (t[b] - t[a - 1])).reshape((-1,) + (1,) * (x.ndim - 1))
        x[a:b] = (1 - w) * x[a - 1] + w * x[b]
        filled[a:b] = True
    return x, filled


def neutral_baseline(weights: np.ndarray, frames: tuple[int, int] | None = None,
                     percentile: float | None = None, valid: np.ndarray | None = None) -> np.ndarray:
    """Per-channel score of the performer's neutral face.

    Parameters
    ----------
    weights : (T, K) float
        Blendshape scores (NaN in frames without a face).
    frames : (start, stop), optional
        Frame range ``start:stop`` where the performer holds a neutral face: the baseline is the
        mean score over those frames.
    percentile : float, optional
        Otherwise, the per-channel ``percentile``-th percentile over the take (e.g. 5): a channel's
        resting level when the take has no neutral section.
    valid : (T,) bool, optional
        Frames to use (default: frames without NaN).

    Returns
    -------
    (K,) float
    """
    w = np.asarray(weights, dtype=np.float64)
    ok = np.isfinite(w).all(axis=1) if valid is None else np.asarray(valid, bool) & np.isfinite(w).all(axis=1)
    if frames is not None:
        a, b = frames
        if not (0 <= a < b <= w.shape[0]):
            raise InvalidDataError(f"neutral frames {a}:{b} are outside the take's {w.shape[0]} frames")
        sel = np.zeros(w.shape[0], bool)
        sel[a:b] = True
        sel &= ok
        if not sel.any():
            raise InvalidDataError(f"neutral frames {a}:{b} hold no tracked face")
        return w[sel].mean(axis=0)
    if percentile is None:
        raise InvalidDataError("neutral_baseline: give frames or percentile")
    if not 0 <= percentile <= 100:
        raise InvalidDataError(f"neutral percentile must be in [0, 100], got {percentile}")
    if not ok.any():
        raise InvalidDataError("neutral_baseline: no frame with a tracked face")
    return np.percentile(w[ok], percentile, axis=0)


def calibrate_neutral(weights: np.ndarray, baseline: np.ndarray) -> np.ndarray:
    """Remove the neutral face's scores: ``clip((w - b) / (1 - b), 0, 1)`` per channel.

    A channel that reads ``b`` on the neutral face then reads 0 there, and a full activation (1)
    still reads 1: the range ``[b, 1]`` is stretched onto ``[0, 1]``.  NaN stays NaN.

    >>> calibrate_neutral(np.array([[0.2, 0.5, 1.0]]), np.array([0.2, 0.0, 0.5])).tolist()
    [[0.0, 0.5, 1.0]]
    """
    w = np.asarray(weights, dtype=np.float64)
    b = np.clip(np.asarray(baseline, dtype=np.float64), 0.0, 0.95)
    with np.errstate(invalid="ignore"):
        return np.clip((w - b) / (1.0 - b), 0.0, 1.0)
