"""Speech features for aligning takes (Chuang Sec. 2.3.1): MFCC and RASTA-PLP.

Both feature kinds come from ``spafe`` (``spafe.features.mfcc.mfcc``,
``spafe.features.rplp.rplp``) on audio resampled to 16 kHz (so the 25 ms analysis window fits
its 512-point FFT whatever the file's rate), 25 ms Hamming windows every 10 ms, 13 coefficients.
Each recording's coefficients are normalised to zero mean and unit variance (cepstral mean and
variance normalisation), so two recordings made with different levels or microphones, or in
different emotions, compare by their phonetic content.

:func:`time_warp_audio` re-times a recording by a known warp without changing its pitch
(waveform-similarity overlap-add, WSOLA, Verhelst & Roelands 1993); it makes test and benchmark
clips whose true alignment is known.
"""

from __future__ import annotations

from dataclasses import dataclass
from math import gcd

import numpy as np

from ..errors import InvalidDataError

__all__ = ["audio_features", "time_warp_audio", "PiecewiseWarp", "FEATURE_RATE", "AUDIO_FEATURES"]

#: Sample rate (Hz) the features are computed at.
FEATURE_RATE = 16000
#: Feature kinds :func:`audio_features` computes.
AUDIO_FEATURES = ("mfcc", "rplp")




def _to_feature_rate(x: np.ndarray, rate: float) -> np.ndarray:
    from scipy.signal import resample_poly

    r = int(round(rate))
    if r == FEATURE_RATE:
        return x
    g = gcd(r, FEATURE_RATE)
    return resample_poly(x, FEATURE_RATE // g, r // g)


def audio_features(samples: np.ndarray, rate: float, *, kind: str = "mfcc", n: int = 13, hop: float = 0.01,
                   win: float = 0.025, normalize: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """MFCC or RASTA-PLP coefficients of a recording, one row per analysis frame.

    Parameters
    ----------
    samples : (N,) float
        Mono samples.
    rate : float
        Sample rate in Hz (resampled to 16 kHz first).
    kind : {"mfcc", "rplp"}
        ``"mfcc"``: mel-frequency cepstral coefficients (24 mel filters, pre-emphasis 0.97);
        ``"rplp"``: RASTA-PLP cepstra (24 Bark filters, RASTA filtering of the log auditory spectrum),
        as Chuang used.
    n : int
        Coefficients per frame.
    hop, win : float
        Frame step and window length in seconds.
    normalize : bool
        Zero mean and unit variance per coefficient over the recording.

    Returns
    -------
    features : (F, n) float
    times : (F,) float
        Centre of each analysis window in seconds from the first sample.
    """
    from spafe.utils.preprocessing import SlidingWindow

    if kind not in AUDIO_FEATURES:
        raise InvalidDataError(f"audio features must be one of {', '.join(AUDIO_FEATURES)}, got '{kind}'")
    x = np.asarray(samples, np.float64).reshape(-1)
    if not np.isfinite(x).all():
        raise InvalidDataError("audio samples contain NaN or infinite values")
    if not (rate > 0):
        raise InvalidDataError(f"audio rate must be positive, got {rate}")
    x = _to_feature_rate(x, rate)
    if len(x) < int(win * FEATURE_RATE) + int(hop * FEATURE_RATE):
        raise InvalidDataError(f"recording too short for features ({len(x) / FEATURE_RATE:.3f} s)")
    # a deterministic dither far below any real signal keeps log() finite in digital silence
    x = x + 1e-7 * np.random.default_rng(0).standard_normal(len(x))
    window = SlidingWindow(win, hop, "hamming")
    if kind == "mfcc":
        from spafe.features.mfcc import mfcc

        F = mfcc(x, fs=FEATURE_RATE, num_ceps=n, pre_emph=True, window=window, nfilts=24, nfft=512)
    else:
        from spafe.features.rplp import rplp

        with np.errstate(divide="ignore", invalid="ignore"):
            F = rplp(x, fs=FEATURE_RATE, order=n, window=window, nfilts=24, nfft=512)
    F = np.asarray(F, np.float64)
    F[~np.isfinite(F)] = 0.0
    if normalize:
        sd = F.std(0)
        F = (F - F.mean(0)) / np.where(sd > 1e-12, sd, 1.0)
    times = np.arange(len(F)) * (int(hop * FEATURE_RATE) / FEATURE_RATE) + 0.5 * win
    return F, times


def time_warp_audio(samples: np.ndarray, rate: float, warp, duration: float | None = None, *,
                    frame: float = 0.03, tolerance: float = 0.006) -> np.ndarray:
    """Re-time a recording by a known warp, keeping its pitch (WSOLA).

    Parameters
    ----------
    samples : (N,) float
        Mono samples.
    rate : float
        Sample rate in Hz.
    warp : callable
        ``warp(t_out) -> t_in``: the input time (s) heard at output time ``t_out`` (s); monotone.
    duration : float, optional
        Output length in seconds (default: until ``warp`` passes the input's end).
    frame : float
        Overlap-add frame length in seconds (half-overlapping Hann windows).
    tolerance : float
        How far (s) a frame may be moved from its target input position to continue the waveform
        smoothly; the true warp holds to within this.

    Returns
    -------
    (M,) float
    """
    x = np.asarray(samples, np.float64).reshape(-1)
    N = max(8, int(round(frame * rate)) // 2 * 2)
    H = N // 2
    D = int(round(tolerance * rate))
    win = 0.5 - 0.5 * np.cos(2 * np.pi * np.arange(N) / N)          # periodic Hann: sums to 1 at N/2
    if duration is None:
        t_end = len(x) / rate
        hi = t_end
        while float(warp(hi)) < t_end:
            hi *= 2
        lo = 0.0
        for _ in range(60):
            mid = 0.5 * (lo + hi)
            lo, hi = (mid, hi) if float(warp(mid)) < t_end else (lo, mid)
        duration = hi
    M = int(round(duration * rate))
    K = M // H + 1
    out = np.zeros(K * H + N)
    xp = np.concatenate([np.zeros(N + D), x, np.zeros(2 * N + 2 * D)])   # padded: index shift N + D
    off = N + D
    prev = None
    for k in range(K):
        centre_out = (k * H + H) / rate                                  # frame centre in output time
        target = int(round(float(warp(centre_out)) * rate)) - H + off    # frame start in padded input
        target = min(max(target, D), len(xp) - N - D - 1)
        if prev is None:
            s = target
        else:
            nat = xp[prev + H: prev + H + N]                            # the natural continuation
            seg = xp[target - D: target + D + N]
            c = np.correlate(seg, nat, mode="valid")                    # (2D + 1,)
            s = target - D + int(np.argmax(c))
        out[k * H: k * H + N] += win * xp[s: s + N]
        prev = s
    return out[:M]


@dataclass(frozen=True)
class PiecewiseWarp:
    """A piecewise-linear re-timing: input segment ``i`` is played at ``rates[i]`` times its speed.

    Attributes
    ----------
    in_knots, out_knots : (n + 1,) float
        Segment boundaries in input and output seconds.
    """

    in_knots: np.ndarray
    out_knots: np.ndarray

    @classmethod
    def from_rates(cls, duration: float, rates) -> PiecewiseWarp:
        """Equal input segments over ``duration`` seconds, segment ``i`` sped up by ``rates[i]`` (> 0)."""
        r = np.asarray(rates, np.float64).reshape(-1)
        if r.size == 0 or (r <= 0).any() or not np.isfinite(r).all():
            raise InvalidDataError(f"warp rates must be positive numbers, got {rates}")
        kin = np.linspace(0.0, float(duration), r.size + 1)
        kout = np.concatenate([[0.0], np.cumsum(np.diff(kin) / r)])
        return cls(kin, kout)

    @property
    def duration(self) -> float:
        """Output length in seconds."""
        return float(self.out_knots[-1])

    def input_time(self, t_out) -> np.ndarray:
        """Input time heard at output time ``t_out`` (the warp :func:`time_warp_audio` takes)."""
        return np.interp(np.asarray(t_out, np.float64), self.out_knots, self.in_knots)

    def output_time(self, t_in) -> np.ndarray:
        """Output time at which input time ``t_in`` is heard."""
        return np.interp(np.asarray(t_in, np.float64), self.in_knots, self.out_knots)
