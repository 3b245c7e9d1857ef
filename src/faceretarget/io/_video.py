"""Video in and out with PyAV: decode RGB frames with their times, read the audio, write an mp4."""

from __future__ import annotations

import os
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass
from fractions import Fraction
from pathlib import Path

import numpy as np

from ..errors import InputFileError, OutputError, excerpt
from ..optional import optional_import

__all__ = ["VideoInfo", "probe_video", "iter_frames", "read_video_audio", "write_video"]


def _av():
    return optional_import("av", "reading and writing video")


@dataclass(frozen=True)
class VideoInfo:
    """What a video file holds.

    Attributes
    ----------
    path : Path
    width, height : int
        Frame size in pixels.
    fps : float
        Average frame rate.
    n_frames : int
        Frame count the container states (0 when unknown).
    duration : float
        Seconds (0 when unknown).
    codec : str
    has_audio : bool
    audio_rate : int
        Sample rate of the first audio stream (0 without audio).
    """

    path: Path
    width: int
    height: int
    fps: float
    n_frames: int
    duration: float
    codec: str
    has_audio: bool
    audio_rate: int


def _open(path: Path):
    av = _av()
    if not path.exists():
        raise InputFileError(f"{path}: file not found")
    if not path.is_file():
        raise InputFileError(f"{path}: not a file")
    try:
        return av.open(str(path), metadata_errors="replace")
    except (av.FFmpegError, ValueError) as e:
        why = excerpt(getattr(e, "strerror", None) or e, 120)
        raise InputFileError(f"{path}: not a readable video file ({why})") from e


def _video_stream(c, path: Path):
    v = c.streams.video[0] if c.streams.video else None
    if v is None or v.codec_context is None or not (v.codec_context.width > 0 and v.codec_context.height > 0):
        c.close()
        raise InputFileError(f"{path}: holds no video stream" if v is None else
                             f"{path}: its video stream cannot be decoded (unknown codec or no frame size)")
    return v


def _rate(v) -> Fraction:
    """The stream's frame rate: average, else guessed, else 30 (a broken header's 0 or negative ignored)."""
    return next((r for r in (v.average_rate, v.guessed_rate) if r is not None and r > 0), Fraction(30))


def probe_video(path: str | os.PathLike) -> VideoInfo:
    """Read a video's header (no decoding).

    Raises
    ------
    InputFileError
        Missing file, not a media file FFmpeg can open, or no video stream.
    """
    path = Path(path)
    c = _open(path)
    try:
        v = _video_stream(c, path)
        rate = _rate(v)
        dur = float(v.duration * v.time_base) if v.duration is not None and v.time_base else (
            c.duration / 1e6 if c.duration else 0.0)
        dur = dur if np.isfinite(dur) and dur > 0 else 0.0  # unknown
        a = c.streams.audio[0] if c.streams.audio else None
        return VideoInfo(path, int(v.codec_context.width), int(v.codec_context.height), float(rate),
                         int(v.frames or 0), float(dur), str(v.codec_context.name), a is not None,
                         int(a.rate) if a is not None else 0)
    finally:
        c.close()


def iter_frames(path: str | os.PathLike, max_frames: int | None = None,
                duration: float | None = None) -> Iterator[tuple[int, float, np.ndarray]]:
    """Decode a video's frames in order.

    Parameters
    ----------
    path : path-like
    max_frames : int, optional
        Stop after this many frames.
    duration : float, optional
        Stop at frames whose time (from the first frame) reaches ``duration`` seconds.

    Yields
    ------
    index : int
    time : float
        Presentation time in seconds relative to the first frame.
    rgb : (H, W, 3) uint8

    Raises
    ------
    InputFileError
        Unreadable file, no video stream, a frame that fails to decode (naming its index), or no
        frame at all.
    """
    av = _av()
    path = Path(path)
    c = _open(path)
    i = 0
    try:
        v = _video_stream(c, path)
        v.thread_type = "AUTO"
        rate = float(_rate(v))
        t0 = None
        prev = -np.inf
        it = c.decode(v)
        while max_frames is None or i < max_frames:
            try:
                frame = next(it)
            except StopIteration:
                break
            except (av.FFmpegError, ValueError) as e:
                why = excerpt(getattr(e, "strerror", None) or e, 120)
                raise InputFileError(f"{path}: frame {i}: cannot decode ({why})") from e
            t = frame.time
            if t is None or not np.isfinite(t):  # no timestamp: the nominal rate
                t = prev + 1.0 / rate if i else 0.0
            else:
                t0 = t if t0 is None else t0
                t = float(t - t0)
            if t <= prev:  # broken timestamps: fall back to the nominal rate
                t = prev + 1.0 / rate
            if duration is not None and t >= duration - 1e-9:
                break
            prev = t
            try:
                rgb = frame.to_ndarray(format="rgb24")
            except (av.FFmpegError, ValueError) as e:
                raise InputFileError(f"{path}: frame {i}: cannot convert to RGB ({excerpt(e, 120)})") from e
            yield i, t, rgb
            i += 1
    finally:
        c.close()
    if i == 0:
        raise InputFileError(f"{path}: no video frame could be decoded")


def read_video_audio(path: str | os.PathLike, duration: float | None = None) -> tuple[np.ndarray, int] | None:
    """The first audio stream as mono float32 samples in [-1, 1], or None without audio.

    Channels are averaged.  ``duration`` cuts it to that many seconds.  Audio that fails to decode
    returns None (the take is still usable without it).
    """
    av = _av()
    path = Path(path)
    c = _open(path)
    try:
        if not c.streams.audio:
            return None
        a = c.streams.audio[0]
        rate = int(a.rate)
        res = av.AudioResampler(format="flt", layout="mono", rate=rate)
        chunks = []
        try:
            for frame in c.decode(a):
                for f in res.resample(frame):
                    chunks.append(f.to_ndarray().reshape(-1))
            for f in res.resample(None):
                chunks.append(f.to_ndarray().reshape(-1))
        except av.FFmpegError:
            return None
        if not chunks:
            return None
        x = np.concatenate(chunks).astype(np.float32)
        if duration is not None:
            x = x[: int(round(duration * rate))]
        return np.clip(x, -1.0, 1.0), rate
    finally:
        c.close()


def write_video(path: str | os.PathLike, frames: Iterable[np.ndarray], fps: float, *,
                audio_from: str | os.PathLike | None = None, audio_duration: float | None = None,
                crf: int = 23, on_frame: Callable[[], None] | None = None) -> str:
    """Encode RGB frames to an mp4 (H.264 when available, else MPEG-4 part 2), optionally with audio.

    Parameters
    ----------
    path : path-like
        Output file, written in place (wrap it in :func:`faceretarget.io._atomic.atomic_path`).
    frames : iterable of (H, W, 3) uint8
        All frames share one size (even width and height are padded when needed).
    fps : float
        Frame rate.
    audio_from : path-like, optional
        A media file whose first audio stream is copied in unchanged (no re-encoding), up to
        ``audio_duration`` seconds.
    crf : int
        H.264 constant rate factor (lower = better).
    on_frame : callable, optional
        Called after each frame (progress).

    Returns
    -------
    str
        The video codec used.
    """
    av = _av()
    rate = Fraction(fps).limit_denominator(1001)
    codec = "libx264" if "libx264" in av.codecs_available else "mpeg4"
    try:
        out = av.open(str(path), mode="w", format="mp4")
    except av.FFmpegError as e:
        raise OutputError(f"{path}: cannot write ({e.strerror or e})") from e
    src = None
    try:
        vs = None
        for img in frames:
            img = _even_frame(img)
            if vs is None:
                vs = _add_video_stream(out, codec, rate, img, crf)
                a_in = None
                if audio_from is not None:
                    src = av.open(str(audio_from))
                    a_in, a_out = _add_audio_stream(out, src)
            frame = av.VideoFrame.from_ndarray(img, format="rgb24")
            _mux(out, vs.encode(frame))
            if on_frame is not None:
                on_frame()
        if vs is None:
            raise OutputError(f"{path}: no frame to write")
        _mux(out, vs.encode())
        if src is not None and a_in is not None:
            _copy_audio(out, src, a_in, a_out, audio_duration)
    except av.FFmpegError as e:
        raise OutputError(f"{path}: cannot encode the video ({e.strerror or e})") from e
    finally:
        out.close()
        if src is not None:
            src.close()
    return codec


def _even_frame(img: np.ndarray) -> np.ndarray:
    """The frame as contiguous uint8, its height and width padded to even numbers (edge pixels repeated)."""
    img = np.ascontiguousarray(img, dtype=np.uint8)
    h, w = img.shape[:2]
    if h % 2 or w % 2:
        img = np.pad(img, ((0, h % 2), (0, w % 2), (0, 0)), mode="edge")
    return img


def _add_video_stream(out, codec: str, rate: Fraction, img: np.ndarray, crf: int):
    """Add the video stream, sized for ``img``, to the output container ``out``."""
    vs = out.add_stream(codec, rate=rate)
    vs.width, vs.height = img.shape[1], img.shape[0]
    vs.pix_fmt = "yuv420p"
    if codec == "libx264":
        vs.options = {"crf": str(crf), "preset": "veryfast"}
    else:
        vs.bit_rate = 4_000_000
    return vs


def _add_audio_stream(out, src):
    """The first audio stream of ``src`` and its copy added to ``out``; ``(None, None)`` without one."""
    if not src.streams.audio:
        return None, None
    a_in = src.streams.audio[0]
    return a_in, out.add_stream_from_template(a_in)


def _mux(out, packets) -> None:
    """Mux the encoded ``packets`` into ``out``."""
    for pkt in packets:
        out.mux(pkt)


def _copy_audio(out, src, a_in, a_out, audio_duration: float | None) -> None:
    """Copy the packets of stream ``a_in`` of ``src`` to ``a_out`` of ``out``, up to ``audio_duration`` s."""
    for pkt in src.demux(a_in):
        if pkt.dts is None:
            continue
        if audio_duration is not None and pkt.pts is not None and \
                float(pkt.pts * pkt.time_base) >= audio_duration:
            break
        pkt.stream = a_out
        out.mux(pkt)
