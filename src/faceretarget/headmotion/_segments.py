"""Phrases and segments of speech from its pitch contour alone (Chuang 2004, Sec. 4.2.1).

* A **segment** runs from one pitch onset (the start of a voiced run) to the next: one voiced run
  followed by the voiceless stretch after it.  The last segment of the audio ends with the audio.
* A **phrase** is a run of segments between pauses: a voiceless stretch longer than ``pause``
  (default 0.3 s, a common minimum for a perceived pause between intonation phrases; short
  voiceless consonants and stop closures are well below it) ends a phrase.  The pause itself
  belongs to the phrase's last segment (as its following voiceless length), so segments tile the
  speech from the first onset to the end without holes.

Pitch is expressed in semitones relative to a reference (the median F0 of the whole take or input
audio), so speakers with different voice ranges compare by intonation shape, not register.

Phrase statistics (columns of :attr:`Segmentation.phrase_stats`, :data:`PHRASE_STATS`): speaking
rate (voiced onsets per second of phrase), mean voiced run length (s), mean voiceless length
between the phrase's runs (s, 0 for a one-run phrase), pitch min and max (the 5th and 95th
percentiles of the voiced frames, robust to stray frames), mean and standard deviation, in
semitones.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..numerics import runs
from ._pitch import PitchTrack

__all__ = ["Segmentation", "segment_speech", "PHRASE_STATS"]

PHRASE_STATS: tuple[str, ...] = ("rate", "voiced_mean", "voiceless_mean", "pitch_min", "pitch_max",
                                 "pitch_mean", "pitch_std")


@dataclass
class Segmentation:
    """Segments and phrases of one audio.

    Attributes
    ----------
    start : (S,) float
        Segment start = pitch onset, seconds.
    voiced_end : (S,) float
        End of the segment's voiced run.
    end : (S,) float
        Segment end = the next onset (or the end of the audio).
    phrase : (S,) int
        Phrase of each segment.
    shape : (S, n_shape) float
        The voiced run's pitch, semitones re ``reference_hz``, resampled to ``n_shape`` points
        (length-normalised).
    phrase_start, phrase_end : (P,) float
        First onset and end of the last voiced run of each phrase.
    phrase_stats : (P, 7) float
        :data:`PHRASE_STATS` per phrase.
    reference_hz : float
        The pitch reference of the semitones.
    duration : float
        Length of the audio, seconds.
    """

    start: np.ndarray
    voiced_end: np.ndarray
    end: np.ndarray
    phrase: np.ndarray
    shape: np.ndarray
    phrase_start: np.ndarray
    phrase_end: np.ndarray
    phrase_stats: np.ndarray
    reference_hz: float
    duration: float

    @property
    def n_segments(self) -> int:
        return int(self.start.size)

    @property
    def n_phrases(self) -> int:
        return int(self.phrase_start.size)

    @property
    def voiced_len(self) -> np.ndarray:
        """(S,) voiced run length, s."""
        return self.voiced_end - self.start

    @property
    def gap_len(self) -> np.ndarray:
        """(S,) following voiceless length, s."""
        return self.end - self.voiced_end

    def phrase_segments(self, p: int) -> np.ndarray:
        """Indices of the segments of phrase ``p``."""
        return np.flatnonzero(self.phrase == p)


def _resample_rows(st: np.ndarray, s: np.ndarray, e: np.ndarray, n: int) -> np.ndarray:
    """(R, n) each run ``st[s:e]`` linearly resampled to ``n`` points spanning the run."""
    L = (e - s).astype(np.float64)
    u = np.linspace(0.0, 1.0, n)
    pos = s[:, None] + u[None, :] * (L[:, None] - 1.0)  # fractional frame index
    i0 = np.clip(np.floor(pos).astype(int), 0, st.size - 1)
    i1 = np.clip(i0 + 1, 0, st.size - 1)
    i1 = np.minimum(i1, (e - 1)[:, None])
    w = pos - np.floor(pos)
    return st[i0] * (1 - w) + st[i1] * w


def segment_speech(track: PitchTrack, *, pause: float = 0.3, n_shape: int = 16,
                   reference_hz: float | None = None) -> Segmentation:
    """Cut speech into phrases and segments (module docstring).

    Parameters
    ----------
    track : PitchTrack
        Cleaned pitch (:func:`extract_pitch`).
    pause : float
        Voiceless stretches longer than this (seconds) end a phrase.
    n_shape : int
        Points of the length-normalised pitch shape of each segment.
    reference_hz : float, optional
        Pitch reference for semitones (default: the track's median).

    Returns
    -------
    Segmentation
        Empty (0 segments, 0 phrases) when the audio has no voiced frame.
    """
    ref = track.median_hz if reference_hz is None else float(reference_hz)
    v = track.voiced
    s, e = runs(v)
    dt = track.time_step
    h = dt / 2
    S = s.size
    if S == 0:
        z = np.zeros(0)
        return Segmentation(z, z, z, np.zeros(0, int), np.zeros((0, n_shape)), z, z,
                            np.zeros((0, len(PHRASE_STATS))), ref, track.duration)
    st = 12.0 * np.log2(track.f0 / ref)
    start = track.times[s] - h
    vend = track.times[e - 1] + h
    end = np.r_[start[1:], track.duration]
    gaps = end - vend
    cut = gaps[:-1] > pause  # a phrase ends after segment i
    phrase = np.r_[0, np.cumsum(cut)].astype(int)
    shape = _resample_rows(np.nan_to_num(st), s, e, n_shape)
    P = int(phrase[-1]) + 1
    first = np.r_[0, np.flatnonzero(cut) + 1]
    last = np.r_[np.flatnonzero(cut), S - 1]
    p_start = start[first]
    p_end = vend[last]
    stats = np.zeros((P, len(PHRASE_STATS)))
    for p in range(P):
        a, b = int(first[p]), int(last[p]) + 1
        dur = max(p_end[p] - p_start[p], dt)
        fa, fb = int(s[a]), int(e[b - 1])
        vals = st[fa:fb][v[fa:fb]]
        inner = gaps[a:b - 1]
        stats[p] = ((b - a) / dur, float(np.mean(vend[a:b] - start[a:b])),
                    float(inner.mean()) if inner.size else 0.0,
                    np.percentile(vals, 5), np.percentile(vals, 95), vals.mean(), vals.std())
    return Segmentation(start=start, voiced_end=vend, end=end, phrase=phrase, shape=shape,
                        phrase_start=p_start, phrase_end=p_end, phrase_stats=stats, reference_hz=ref,
                        duration=track.duration)
