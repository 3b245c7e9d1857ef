"""Aligning takes of the same text spoken at different tempos: dynamic time warping (Chuang Sec. 2.3.1).

Two takes of one sentence in different emotions run at different speeds.  Before a style/content
model can pair their frames, every take is put on the reference take's timeline:

1. **Features** per frame: audio features when both takes have audio (MFCC or RASTA-PLP,
   :mod:`._features`), otherwise face features (:func:`face_features`: every coordinate's
   velocity standardised per take, so a constant emotional offset or a
   stronger mouth does not decide the match).
2. **Dynamic time warping** of the two feature sequences (``dtaidistance``'s C implementation,
   :func:`dtw_path`), optionally inside a Sakoe-Chiba band, gives a monotone path of matched frame
   pairs from the first frames to the last.
3. **Warp**: every reference frame gets the take time at the middle of the take frames the path
   matches it to (:func:`path_to_times`), smoothed lightly and kept strictly increasing; feature
   frame times are converted to face frame times through the takes' clocks.
4. **Re-alignment by style** (point takes aligned by face, :func:`realign_by_style`): the
   emotion reshapes the lips' motion, so the take's velocities never quite match the reference's.
   With the first alignment, the change from the reference's style to the take's is learned point
   by point (:mod:`._pointlocal`), the reference is rendered in the take's style, and DTW runs
   again between that rendering and the take, now in the same style; twice.
5. **Resampling**: the take's face frames are interpolated linearly at those times
   (:func:`resample`, :func:`warp_performance`), so the result has the reference's frame count and
   times.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from ..errors import InvalidDataError
from ..performance import Performance
from ..timebase import infer_fps
from ._features import audio_features
from ._pointlocal import fit_point_map, point_count

__all__ = [
    "Alignment",
    "dtw_path",
    "path_to_times",
    "face_features",
    "align_features",
    "align_audio",
    "align_performances",
    "realign_by_style",
    "resample",
    "warp_performance",
    "frame_vectors",
]


@dataclass(eq=False)
class Alignment:
    """A monotone correspondence from a reference take's timeline to another take's.

    Attributes
    ----------
    ref_times : (Tr,) float
        Times (s) of the reference frames the alignment is given at.
    take_times : (Tr,) float
        For every reference frame, the matching time (s) in the take.
    path : (L, 2) int
        The DTW path over feature frames: ``(reference frame, take frame)`` pairs.
    ref_feature_times, take_feature_times : (Fr,), (Ft,) float
        Times of the feature frames the path indexes.
    distance : float
        DTW distance of the path (in feature units).
    by : str
        ``"mfcc"``, ``"rplp"`` or ``"face"``.
    """

    ref_times: np.ndarray
    take_times: np.ndarray
    path: np.ndarray
    ref_feature_times: np.ndarray
    take_feature_times: np.ndarray
    distance: float
    by: str

    def __call__(self, t_ref) -> np.ndarray:
        """Take time (s) matching reference time(s) ``t_ref`` (linear between reference frames)."""
        return np.interp(np.asarray(t_ref, np.float64), self.ref_times, self.take_times)

    def errors_ms(self, true_take_times) -> np.ndarray:
        """``|take_times - truth|`` in milliseconds, per reference frame."""
        truth = np.asarray(true_take_times, np.float64).reshape(-1)
        if truth.shape != self.take_times.shape:
            raise InvalidDataError(f"true warp has {truth.size} times for {self.take_times.size} reference frames")
        return np.abs(self.take_times - truth) * 1000.0


# ------------------------------------------------------------------------------------------- DTW
def dtw_path(ref: np.ndarray, take: np.ndarray, *, window: int | None = None) -> tuple[np.ndarray, float]:
    """Optimal DTW path between two feature sequences (``dtaidistance``, C implementation).

    Parameters
    ----------
    ref : (Fr, d) float
    take : (Ft, d) float
    window : int, optional
        Sakoe-Chiba band half-width in frames: matched frames satisfy ``|i - j| <= window`` plus the
        length difference of the sequences (``dtaidistance``'s ``window``).  ``None``: no band.

    Returns
    -------
    path : (L, 2) int
        Matched ``(ref, take)`` frame pairs from ``(0, 0)`` to ``(Fr - 1, Ft - 1)``, both columns
        non-decreasing.
    distance : float
        The DTW distance (square root of the summed squared Euclidean distances along the path).
    """
    from dtaidistance import dtw_ndim

    a = np.ascontiguousarray(np.asarray(ref, np.float64))
    b = np.ascontiguousarray(np.asarray(take, np.float64))
    if a.ndim == 1:
        a = a[:, None]
    if b.ndim == 1:
        b = b[:, None]
    if a.ndim != 2 or b.ndim != 2 or a.shape[1] != b.shape[1]:
        raise InvalidDataError(f"DTW needs two (frames, d) sequences with the same d, got {a.shape} and {b.shape}")
    if len(a) < 2 or len(b) < 2:
        raise InvalidDataError(f"DTW needs at least 2 frames per sequence, got {len(a)} and {len(b)}")
    if not (np.isfinite(a).all() and np.isfinite(b).all()):
        raise InvalidDataError("DTW features contain NaN or infinite values")
    kw = {}
    if window is not None:
        if window < 1:
            raise InvalidDataError(f"Sakoe-Chiba window must be >= 1 frame, got {window}")
        kw["window"] = int(window)
    if a.shape[1] == 1:
        from dtaidistance import dtw

        path, dist = dtw.warping_path(a[:, 0].copy(), b[:, 0].copy(), use_c=True, include_distance=True, **kw)
    else:
        path, dist = dtw_ndim.warping_path(a, b, use_c=True, include_distance=True, **kw)
    p = np.asarray(path, dtype=np.int64).reshape(-1, 2)
    if len(p) == 0 or tuple(p[0]) != (0, 0) or tuple(p[-1]) != (len(a) - 1, len(b) - 1):
        raise InvalidDataError("DTW found no path through the band; widen the Sakoe-Chiba window")
    return p, float(dist)


def path_to_times(path: np.ndarray, ref_times: np.ndarray, take_times: np.ndarray, *,
                  smooth: int = 2) -> np.ndarray:
    """The take time matched to every reference frame of a DTW path.

    Each reference frame ``i`` is matched to the take frames ``j_lo..j_hi`` on the path; its take
    time is the time at the fractional frame ``(j_lo + j_hi) / 2``.  The result is smoothed by a
    centred moving average over ``2 * smooth + 1`` frames (the path's staircase is quantised to
    whole frames) and made strictly increasing.

    Parameters
    ----------
    path : (L, 2) int
    ref_times : (Fr,) float
    take_times : (Ft,) float
    smooth : int
        Half-width of the moving average (0: none).

    Returns
    -------
    (Fr,) float
    """
    p = np.asarray(path, np.int64)
    Fr = len(ref_times)
    lo = np.full(Fr, np.iinfo(np.int64).max)
    hi = np.full(Fr, -1)
    np.minimum.at(lo, p[:, 0], p[:, 1])
    np.maximum.at(hi, p[:, 0], p[:, 1])
    mid = 0.5 * (lo + hi)
    if smooth > 0 and Fr > 2 * smooth + 1:
        k = 2 * smooth + 1
        pad = np.concatenate([2 * mid[0] - mid[smooth:0:-1], mid, 2 * mid[-1] - mid[-2:-smooth - 2:-1]])
        mid = np.convolve(pad, np.ones(k) / k, mode="valid")
    idx = np.arange(len(take_times), dtype=np.float64)
    t = np.interp(mid, idx, np.asarray(take_times, np.float64))
    # strictly increasing (a flat stretch of the path would give equal times)
    eps = 1e-9 * max(1.0, float(np.abs(t).max(initial=0.0)))
    return np.maximum.accumulate(t + eps * np.arange(Fr))


# ------------------------------------------------------------------------------------------- features
def frame_vectors(perf: Performance) -> np.ndarray:
    """A take's facial configuration vectors ``(T, D)``: weights, or flattened points / vertices.

    Occluded points (NaN) are filled by linear interpolation over time (or the take's mean when a
    coordinate is never seen).
    """
    X = perf.data().reshape(perf.n_frames, -1).astype(np.float64)
    bad = ~np.isfinite(X)
    if bad.any():
        t = np.arange(len(X))
        for j in np.flatnonzero(bad.any(0)):
            ok = ~bad[:, j]
            if not ok.any():
                raise InvalidDataError(f"{perf.source}: coordinate {j} is never observed")
            X[:, j] = np.interp(t, t[ok], X[ok, j])
    return X


def face_features(frames: np.ndarray) -> np.ndarray:
    """Face features of one take for alignment: every coordinate's velocity, standardised per take.

    The velocity (central differences over frames) of every coordinate is scaled to zero mean and
    unit variance over the take; coordinates that never move are dropped (given zero).  A constant
    emotional offset disappears in the velocity, and the standardisation gives every coordinate the
    same vote whatever its amplitude in this take, so coordinates that move rigidly with the speech
    (jaw line, chin, nose) count as much as the lips, where an emotion changes the shape of the
    motion most.  What is matched is *when* each coordinate moves.

    Parameters
    ----------
    frames : (T, D) float
        Facial configuration vectors.

    Returns
    -------
    (T, D) float
    """
    x = np.asarray(frames, np.float64)
    if len(x) < 2:
        return np.zeros_like(x)
    v = np.gradient(x, axis=0)
    v = v - v.mean(0)
    sd = v.std(0)
    live = sd > 1e-9 * max(float(sd.max(initial=0.0)), 1e-300)
    return np.where(live, v / np.where(live, sd, 1.0), 0.0)


def _window_frames(window_s: float | None, rate: float) -> int | None:
    if window_s is None:
        return None
    if not window_s > 0:
        raise InvalidDataError(f"Sakoe-Chiba window must be positive seconds, got {window_s}")
    return max(1, int(round(window_s * rate)))


def align_features(ref: np.ndarray, take: np.ndarray, ref_times, take_times, *, window_s: float | None = None,
                   smooth: int = 2, by: str = "features") -> Alignment:
    """Align two feature sequences and return the take time of every reference feature frame.

    Parameters
    ----------
    ref, take : (Fr, d), (Ft, d) float
    ref_times, take_times : (Fr,), (Ft,) float
        Feature frame times in seconds.
    window_s : float, optional
        Sakoe-Chiba band half-width in seconds.
    smooth : int
        See :func:`path_to_times`.
    """
    rt = np.asarray(ref_times, np.float64)
    tt = np.asarray(take_times, np.float64)
    if len(rt) != len(ref) or len(tt) != len(take):
        raise InvalidDataError("feature frames and their times differ in number")
    rate = infer_fps(rt, default=1.0)
    path, dist = dtw_path(ref, take, window=_window_frames(window_s, rate))
    mapped = path_to_times(path, rt, tt, smooth=smooth)
    return Alignment(rt, mapped, path, rt, tt, dist, by)


def align_audio(ref_audio: np.ndarray, ref_rate: float, take_audio: np.ndarray, take_rate: float, *,
                features: str = "mfcc", window_s: float | None = None, hop: float = 0.01,
                smooth: int = 2) -> Alignment:
    """Align two recordings of the same text by DTW of their speech features.

    Parameters
    ----------
    ref_audio, take_audio : (N,) float
        Mono samples.
    ref_rate, take_rate : float
        Sample rates (Hz).
    features : {"mfcc", "rplp"}
        MFCC or RASTA-PLP (:func:`~._features.audio_features`), each normalised per recording.
    window_s : float, optional
        Sakoe-Chiba band half-width in seconds.
    hop : float
        Feature hop in seconds (the path's resolution before smoothing).

    Returns
    -------
    Alignment
        On the reference's feature frame times (seconds from the first sample).
    """
    fa, ta = audio_features(ref_audio, ref_rate, kind=features, hop=hop)
    fb, tb = audio_features(take_audio, take_rate, kind=features, hop=hop)
    return align_features(fa, fb, ta, tb, window_s=window_s, smooth=smooth, by=features)


def align_performances(ref: Performance, take: Performance, *, by: str = "auto", features: str = "mfcc",
                       window_s: float | None = None) -> Alignment:
    """The take time matching every frame of ``ref`` (both takes say the same text).

    Parameters
    ----------
    ref, take : Performance
        Same kind and size of frames.  With audio (``audio`` and ``audio_rate``) on both, aligned by
        speech features; otherwise by :func:`face_features`.
    by : {"auto", "audio", "face"}
    features : {"mfcc", "rplp"}
        Audio features when aligning by audio.
    window_s : float, optional
        Sakoe-Chiba band half-width in seconds.

    Returns
    -------
    Alignment
        ``ref_times`` are ``ref.times``; ``take_times`` are times on ``take.times``' clock.
    """
    if by not in ("auto", "audio", "face"):
        raise InvalidDataError(f"align by 'auto', 'audio' or 'face', got '{by}'")
    has_audio = all(p.audio is not None and p.audio_rate for p in (ref, take))
    if by == "audio" and not has_audio:
        missing = ref.source if (ref.audio is None or not ref.audio_rate) else take.source
        raise InvalidDataError(f"{missing}: no audio to align by")
    if by == "audio" or (by == "auto" and has_audio):
        al = align_audio(ref.audio, ref.audio_rate, take.audio, take.audio_rate, features=features,
                         window_s=window_s)
        # audio time 0 is the take's first frame time (Performance.audio is synchronous with times[0])
        mapped = np.interp(ref.times - ref.times[0], al.ref_times, al.take_times) + take.times[0]
        return replace(al, ref_times=ref.times.copy(), take_times=mapped)
    xa, xb = frame_vectors(ref), frame_vectors(take)
    if xa.shape[1] != xb.shape[1]:
        raise InvalidDataError(f"{take.source}: frames have {xb.shape[1]} values but {ref.source}'s have "
                               f"{xa.shape[1]}; takes of one model must have the same kind and size")
    return align_features(face_features(xa), face_features(xb), ref.times, take.times, window_s=window_s,
                          by="face")


#: The point-local change used to re-align by style (``("points", neighbours, frames)``): each point
#: alone, remainder averaged over 8 frames (the middle of the selection's grid).
REALIGN_MAP = ("points", 1, 8)


def realign_by_style(ref: Performance, take: Performance, alignment: Alignment, *, iterations: int = 2,
                     window_s: float | None = None) -> Alignment:
    """Refine a face-feature alignment by aligning ``take`` to ``ref`` rendered in the take's style.

    Every iteration resamples the take on the current alignment, fits the point-local change from
    the reference to the take over all paired frames (:func:`~._pointlocal.fit_point_map`,
    :data:`REALIGN_MAP`), renders the reference with that change, and runs DTW of
    :func:`face_features` between the rendering and the take.  On P3 this cuts the 95th
    percentile of the warp error by a third to a half (``docs/style.md``).

    Parameters
    ----------
    ref, take : Performance
        Point takes (``(P, 3)`` frames) of the same text.
    alignment : Alignment
        The first alignment (:func:`align_performances` by face).
    iterations : int
    window_s : float, optional
        Sakoe-Chiba band half-width in seconds.

    Returns
    -------
    Alignment
        ``by`` is ``"face+style"``.
    """
    P = point_count(ref.data().shape[1:])
    if P is None or ref.data().shape[1:] != take.data().shape[1:]:
        raise InvalidDataError(f"{take.source}: re-alignment by style needs point takes of the same (P, 3) shape "
                               f"(P <= 512), got {tuple(ref.data().shape[1:])} and {tuple(take.data().shape[1:])}")
    xa, xb = frame_vectors(ref), frame_vectors(take)
    T = len(xa)
    xa3 = xa.reshape(T, P, 3)
    rest = xa3.mean(0)
    cur = alignment
    for _ in range(int(iterations)):
        xw = resample(xb, take.times, cur(ref.times)).reshape(T, P, 3)
        pm = fit_point_map(xa3, xw, rest, REALIGN_MAP)
        pred = xa + pm.predict(xa3).reshape(T, -1)
        cur = align_features(face_features(pred), face_features(xb), ref.times, take.times, window_s=window_s,
                             by="face+style")
    return cur


# ------------------------------------------------------------------------------------------- resampling
def resample(data: np.ndarray, times: np.ndarray, query: np.ndarray) -> np.ndarray:
    """Linear interpolation of frames ``data`` (T, ...) at times ``times`` to ``query`` (clamped).

    Returns
    -------
    (Q, ...) float
    """
    x = np.asarray(data, np.float64)
    t = np.asarray(times, np.float64)
    q = np.clip(np.asarray(query, np.float64).reshape(-1), t[0], t[-1])
    if len(t) == 1:
        return np.repeat(x, len(q), axis=0)
    k = np.clip(np.searchsorted(t, q, side="right") - 1, 0, len(t) - 2)
    f = ((q - t[k]) / (t[k + 1] - t[k])).reshape((-1,) + (1,) * (x.ndim - 1))
    return (1 - f) * x[k] + f * x[k + 1]


def warp_performance(take: Performance, alignment: Alignment, ref_times=None) -> Performance:
    """``take`` resampled onto the reference timeline of ``alignment`` (audio dropped)."""
    rt = alignment.ref_times if ref_times is None else np.asarray(ref_times, np.float64)
    q = alignment(rt)
    kw = {take.kind: resample(take.data(), take.times, q)}
    if take.kind == "weights":
        kw["names"] = take.names
    fps = infer_fps(rt, default=take.fps)
    return Performance(times=rt.copy(), fps=fps, audio=None,
                       audio_rate=None, labels=take.labels, mesh=take.mesh, unit=take.unit,
                       source=f"{take.source} (aligned)", **kw)
