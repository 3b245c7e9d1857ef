"""Pitch (F0) of speech by Praat's autocorrelation method (through ``praat-parselmouth``), cleaned.

Cleaning, in order (every threshold is a parameter of :func:`extract_pitch`):

1. Praat ``To Pitch (ac)`` with the human range ``f0_min``..``f0_max`` (default 60-500 Hz) every
   ``time_step`` (10 ms); 0 Hz marks an unvoiced frame.
2. Octave jumps: within each voiced run, a frame more than ``octave_tol`` semitones (default 7,
   well over half an octave) from the run's median is a doubling/halving error and is cleared;
   a whole run more than 12 semitones from the take's median is cleared too.
3. Voiced runs shorter than ``min_voiced`` (50 ms) are dropped (clicks, creak).
4. Gaps shorter than ``max_gap`` (40 ms) inside voiced speech (left by step 2, or Praat dropping a
   frame) are filled by linear interpolation in semitones.  Longer gaps are real voiceless
   regions (consonants, pauses) and stay: they are the boundaries segmentation works with.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import InvalidDataError
from ..numerics import runs

__all__ = ["PitchTrack", "extract_pitch"]


@dataclass
class PitchTrack:
    """A cleaned pitch contour.

    Attributes
    ----------
    times : (N,) float
        Frame centres in seconds from the start of the audio.
    f0 : (N,) float
        Fundamental frequency in Hz, NaN where unvoiced.
    time_step : float
        Seconds between frames.
    duration : float
        Length of the audio in seconds.
    """

    times: np.ndarray
    f0: np.ndarray
    time_step: float
    duration: float

    @property
    def voiced(self) -> np.ndarray:
        """(N,) bool."""
        return np.isfinite(self.f0)

    @property
    def median_hz(self) -> float:
        """Median F0 of the voiced frames (NaN when there are none)."""
        v = self.f0[self.voiced]
        return float(np.median(v)) if v.size else float("nan")

    def semitones(self, reference_hz: float | None = None) -> np.ndarray:
        """(N,) pitch in semitones relative to ``reference_hz`` (default the median), NaN unvoiced."""
        ref = self.median_hz if reference_hz is None else float(reference_hz)
        return 12.0 * np.log2(self.f0 / ref)

    def voiced_intervals(self) -> np.ndarray:
        """(R, 2) start and end times (s) of the voiced runs (end = last frame + one step)."""
        s, e = runs(self.voiced)
        h = self.time_step / 2
        return np.stack([self.times[s] - h, self.times[e - 1] + h], axis=1) if s.size else np.zeros((0, 2))




def _run_median(st: np.ndarray, s: np.ndarray, e: np.ndarray) -> np.ndarray:
    """(N,) the median of each voiced run, broadcast over its frames (NaN elsewhere)."""
    out = np.full(st.shape, np.nan)
    for a, b in zip(s.tolist(), e.tolist(), strict=True):
        out[a:b] = np.median(st[a:b])
    return out


def clean_pitch(f0_hz: np.ndarray, time_step: float, *, octave_tol: float = 7.0, min_voiced: float = 0.05,
                max_gap: float = 0.04) -> np.ndarray:
    """Clean a raw pitch contour (0 or NaN = unvoiced); see the module docstring.

    Returns
    -------
    (N,) float
        Hz, NaN where unvoiced.
    """
    f = np.asarray(f0_hz, np.float64).copy()
    f[~(f > 0)] = np.nan
    if not np.isfinite(f).any():
        return f
    st = 12.0 * np.log2(f / np.nanmedian(f))
    # 2. octave jumps inside runs, then whole runs far from the take's median
    s, e = runs(np.isfinite(st))
    med = _run_median(st, s, e)
    st[np.abs(st - med) > octave_tol] = np.nan
    s, e = runs(np.isfinite(st))
    if s.size:
        take_med = np.nanmedian(st)
        med = _run_median(st, s, e)
        st[np.abs(med - take_med) > 12.0] = np.nan
    # 3. short voiced runs
    min_len = max(1, int(round(min_voiced / time_step)))
    s, e = runs(np.isfinite(st))
    for a, b in zip(s.tolist(), e.tolist(), strict=True):
        if b - a < min_len:
            st[a:b] = np.nan
    # 4. short gaps between voiced frames
    gap = int(round(max_gap / time_step))
    gs, ge = runs(~np.isfinite(st))
    idx = np.arange(st.size)
    ok = np.isfinite(st)
    if ok.sum() >= 2:
        for a, b in zip(gs.tolist(), ge.tolist(), strict=True):
            if a > 0 and b < st.size and b - a <= gap:
                st[a:b] = np.interp(idx[a:b], [a - 1, b], [st[a - 1], st[b]])
    ref = np.nanmedian(f)
    return ref * 2.0 ** (st / 12.0)


def extract_pitch(audio: np.ndarray, rate: float, *, f0_min: float = 60.0, f0_max: float = 500.0,
                  time_step: float = 0.01, octave_tol: float = 7.0, min_voiced: float = 0.05,
                  max_gap: float = 0.04, voicing_threshold: float = 0.45,
                  silence_threshold: float = 0.03) -> PitchTrack:
    """Pitch of speech with Praat, cleaned (module docstring).

    Parameters
    ----------
    audio : (N,) float
        Mono samples in [-1, 1].
    rate : float
        Sampling rate in Hz.
    f0_min, f0_max : float
        Human pitch range searched, Hz.
    time_step : float
        Seconds between pitch frames.
    octave_tol, min_voiced, max_gap : float
        Cleaning thresholds (semitones, seconds, seconds).
    voicing_threshold, silence_threshold : float
        Praat's own thresholds (its defaults).

    Returns
    -------
    PitchTrack
        Frames every ``time_step`` covering the whole audio (frames Praat cannot centre a window
        on, at the very start and end, are unvoiced).
    """
    import parselmouth

    x = np.asarray(audio, np.float64).reshape(-1)
    if not (np.isfinite(rate) and rate > 0):
        raise InvalidDataError(f"audio rate must be positive, got {rate}")
    if not 0 < f0_min < f0_max:
        raise InvalidDataError(f"need 0 < f0_min < f0_max, got {f0_min}, {f0_max}")
    duration = x.size / float(rate)
    n = int(np.floor(duration / time_step))
    times = (np.arange(n) + 0.5) * time_step
    f0 = np.full(n, np.nan)
    # Praat needs at least 3 periods of the lowest pitch in a window
    if duration > 3.0 / f0_min + time_step and np.abs(x).max() > 0:
        snd = parselmouth.Sound(x, sampling_frequency=float(rate))
        p = snd.to_pitch_ac(time_step=time_step, pitch_floor=f0_min, pitch_ceiling=f0_max,
                            voicing_threshold=voicing_threshold, silence_threshold=silence_threshold)
        raw = p.selected_array["frequency"]
        k = np.round(p.xs() / time_step - 0.5).astype(int)
        keep = (k >= 0) & (k < n)
        f0[k[keep]] = raw[keep]
        f0 = clean_pitch(f0, time_step, octave_tol=octave_tol, min_voiced=min_voiced, max_gap=max_gap)
    return PitchTrack(times=times, f0=f0, time_step=float(time_step), duration=float(duration))
