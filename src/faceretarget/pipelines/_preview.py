"""The side-by-side preview video: the input video beside the animated character, with the audio.

:func:`write_animation_preview` decodes the video, renders the character at each video frame's time
with one :class:`~faceretarget.render.MeshRenderer` (OpenGL through EGL when it can, the NumPy
rasteriser otherwise; one log line says which) and encodes both side by side at the video's frame
rate with the video's audio copied in.  Decoding, rendering and encoding overlap in three threads.
"""

from __future__ import annotations

import os
import queue
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np

from ..errors import InvalidDataError
from ..files import atomic_path, check_output_path, protect_inputs
from ..headpose import HeadPose
from ..io import iter_frames, probe_video, write_video
from ..render import MeshRenderer
from ..rig import Rig

__all__ = ["write_animation_preview", "TakeSampler"]

_QUEUE = 6  # frames in flight between the decode, render and encode threads


class TakeSampler:
    """A take's face weights and head pose at any time (for frames that fall between its samples).

    Weights are interpolated linearly, head rotations by slerp and translations linearly between the
    two nearest frames (between the nearest frames *with* a pose for the head); a time before the
    first or after the last frame holds that frame.

    Parameters
    ----------
    rig : Rig
        The character; ``weights`` are in its shape order.
    weights : (T, K) float
        One row per take frame.
    times : (T,) float
        Seconds, strictly increasing.
    head : HeadPose, optional
        ``T`` frames.  Its translation (metres) is taken relative to its median over the frames that
        have one, so the head moves about the place it usually is (a video capture's translation is
        from the camera).
    turns : list of (indices, centre, Rotation), optional
        Parts of the rig that turn rigidly about a point (an eyeball about its eye joint: the gaze a
        character file carries, :meth:`~faceretarget.characters.CharacterLook.eye_turns`): vertex
        indices, the centre (rig units) and a :class:`scipy.spatial.transform.Rotation` of ``T`` keys
        (slerp between them).
    """

    def __init__(self, rig: Rig, weights: np.ndarray, times: np.ndarray, head: HeadPose | None = None,
                 turns: list | None = None) -> None:
        W = np.asarray(weights, np.float64)
        t = np.asarray(times, np.float64)
        K = rig.n_shapes
        if W.ndim != 2 or W.shape[1] != K:
            raise InvalidDataError(f"preview of {rig.name}: weights have shape {W.shape}, expected (T, {K}) in "
                                   f"the rig's shape order")
        if t.shape != (len(W),):
            raise InvalidDataError(f"preview of {rig.name}: times have shape {t.shape}, expected ({len(W)},) "
                                   f"for weights of shape {W.shape}")
        if not len(W):
            raise InvalidDataError(f"preview of {rig.name}: the take has no frame")
        if not np.isfinite(W).all():
            f = int(np.flatnonzero(~np.isfinite(W).all(axis=1))[0])
            k = int(np.flatnonzero(~np.isfinite(W[f]))[0])
            raise InvalidDataError(f"preview of {rig.name}: frame {f} weight of '{rig.names[k]}' is not finite")
        if not np.isfinite(t).all() or (np.diff(t) <= 0).any():
            raise InvalidDataError(f"preview of {rig.name}: times must be finite and strictly increasing")
        if head is not None and head.n_frames != len(W):
            raise InvalidDataError(f"preview of {rig.name}: head pose ({head.source}) has {head.n_frames} frames, "
                                   f"the weights {len(W)}")
        self.rig, self.weights, self.times = rig, W, t
        # float32 and einsum: a (K,) x (K, 3V) product that never waits for BLAS threads (on a busy
        # 2-core machine a threaded gemv of ICT's 57 shapes took 0.3-10 ms, this 0.2-0.5 ms)
        self._D = np.ascontiguousarray(rig.deltas.reshape(K, -1), dtype=np.float32)
        self._rest = rig.neutral.vertices.reshape(-1).astype(np.float32)
        self._head_t, self._head_q, self._head_tr = _head_samples(head, t)
        self._turns = []
        for idx, centre, rot in turns or ():
            q = np.atleast_2d(rot.as_quat())
            if len(q) != len(W):
                raise InvalidDataError(f"preview of {rig.name}: a turning part has {len(q)} rotations for {len(W)} "
                                       "frames")
            flip = np.cumprod(np.where(np.einsum("ij,ij->i", q[1:], q[:-1]) < 0, -1.0, 1.0))
            q[1:] *= flip[:, None]
            self._turns.append((np.asarray(idx, np.int64), np.asarray(centre, np.float32).reshape(3), q))

    def weights_at(self, time: float) -> np.ndarray:
        """(K,) weights at ``time`` seconds."""
        i, a = _bracket(self.times, time)
        return self.weights[i] if a == 0.0 else (1.0 - a) * self.weights[i] + a * self.weights[i + 1]

    def vertices_at(self, time: float) -> np.ndarray:
        """(V, 3) float32 face vertices (rig units, before head motion) at ``time`` seconds."""
        w = self.weights_at(time).astype(np.float32)
        v = (np.einsum("k,kn->n", w, self._D) + self._rest).reshape(-1, 3)
        if self._turns:
            i, a = _bracket(self.times, time)
            for idx, c, q in self._turns:
                R = _quat_matrix(q[i] if a == 0.0 else _slerp(q[i], q[i + 1], a)).astype(np.float32)
                v[idx] = (v[idx] - c) @ R.T + c
        return v

    def head_at(self, time: float) -> tuple[np.ndarray | None, np.ndarray | None]:
        """Head rotation (3, 3) and translation (3,) metres at ``time``, each None without one."""
        R = tr = None
        if self._head_q is not None:
            i, a = _bracket(self._head_t, time)
            q = self._head_q[i] if a == 0.0 else _slerp(self._head_q[i], self._head_q[i + 1], a)
            R = _quat_matrix(q)
        if self._head_tr is not None:
            tr = np.array([np.interp(time, self._head_tr[0], self._head_tr[1][:, k]) for k in range(3)])
        return R, tr


def _head_samples(head: HeadPose | None, t: np.ndarray):
    """Times and sign-continuous quaternions of the frames with a pose, and (times, translation
    relative to its median) of those with a translation; None where there is none."""
    if head is None:
        return None, None, None
    ok = head.valid
    tq = q = trs = None
    if ok.any():
        tq = t[ok]
        q = head.quaternions[ok].copy()
        flip = np.cumprod(np.where(np.einsum("ij,ij->i", q[1:], q[:-1]) < 0, -1.0, 1.0))
        q[1:] *= flip[:, None]
    if head.translation is not None:
        okt = ok & np.isfinite(head.translation).all(axis=1)
        if okt.any():
            tr = head.translation[okt]
            trs = (t[okt], tr - np.median(tr, axis=0))
    return tq, q, trs


def _bracket(times: np.ndarray, t: float) -> tuple[int, float]:
    """Index ``i`` and fraction ``a`` with ``t`` = (1 - a) times[i] + a times[i + 1], held at the ends."""
    n = len(times)
    if n == 1 or t <= times[0]:
        return 0, 0.0
    if t >= times[-1]:
        return n - 1, 0.0
    i = int(np.searchsorted(times, t, side="right")) - 1
    return i, float((t - times[i]) / (times[i + 1] - times[i]))


def _slerp(q0: np.ndarray, q1: np.ndarray, a: float) -> np.ndarray:
    """Spherical interpolation of two unit quaternions on the same hemisphere."""
    d = float(np.clip(q0 @ q1, -1.0, 1.0))
    if d > 0.9995:
        q = q0 + a * (q1 - q0)
    else:
        th = np.arccos(d)
        q = (np.sin((1 - a) * th) * q0 + np.sin(a * th) * q1) / np.sin(th)
    return q / np.linalg.norm(q)


def _quat_matrix(q: np.ndarray) -> np.ndarray:
    """Rotation matrix of a unit quaternion ``x, y, z, w``."""
    x, y, z, w = q
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ])


def _scale_to_height(rgb: np.ndarray, height: int) -> np.ndarray:
    """The frame resized to ``height`` rows (bilinear), its width rounded to an even number."""
    h, w = rgb.shape[:2]
    new_w = max(2, int(round(w * height / h / 2.0)) * 2)
    if (h, w) == (height, new_w):
        return rgb
    from PIL import Image

    return np.asarray(Image.fromarray(rgb).resize((new_w, height), Image.BILINEAR))


class _Worker:
    """Run ``fn`` in a daemon thread; :meth:`join` re-raises what it raised."""

    def __init__(self, fn: Callable[[], object], name: str, on_error: Callable[[], None]) -> None:
        self.result: object = None
        self.error: BaseException | None = None

        def run() -> None:
            try:
                self.result = fn()
            except BaseException as e:  # handed to the caller in join()
                self.error = e
                on_error()

        self.thread = threading.Thread(target=run, name=name, daemon=True)
        self.thread.start()

    def join(self) -> object:
        self.thread.join()
        if self.error is not None:
            raise self.error
        return self.result


_END = object()


def _put(q: queue.Queue, item, stop: threading.Event) -> bool:
    """Put ``item`` unless ``stop`` is set first; False when stopped."""
    while not stop.is_set():
        try:
            q.put(item, timeout=0.1)
            return True
        except queue.Full:
            continue
    return False


def _get(q: queue.Queue, stop: threading.Event):
    """The next item, or ``_END`` once ``stop`` is set."""
    while not stop.is_set():
        try:
            return q.get(timeout=0.1)
        except queue.Empty:
            continue
    return _END


def _decoded(video: Path, max_frames: int | None, size: int, stop: threading.Event,
             out: queue.Queue) -> int:
    """Decode ``video`` into ``out`` as ``(index, time, frame scaled to size rows)``; then ``_END``."""
    n = 0
    try:
        for i, t, rgb in iter_frames(video, max_frames=max_frames):
            if not _put(out, (i, t, _scale_to_height(rgb, size)), stop):
                break
            n += 1
    finally:
        _put(out, _END, stop)
    return n


def write_animation_preview(out: str | os.PathLike, video: str | os.PathLike, rig: Rig, weights: np.ndarray,
                            times: np.ndarray, head: HeadPose | None = None, *,
                            frame_times: np.ndarray | None = None, size: int = 512, backend: str = "auto",
                            progress: bool = False, colors: np.ndarray | None = None, pivot: np.ndarray | None = None,
                            surface=None, fit_to: np.ndarray | None = None, turns: list | None = None,
                            log: Callable[..., None] = print) -> dict:
    """Write an mp4 of ``video`` beside the character playing the take, with the video's audio.

    Parameters
    ----------
    out : path-like
        The ``.mp4`` to write (whole or not at all; never the input video).
    video : path-like
        Any video FFmpeg reads (PyAV: ``make preview``).
    rig : Rig
        The character.
    weights : (T, K) float
        The take's weights in the rig's shape order.
    times : (T,) float
        Seconds of each take frame, strictly increasing.
    head : HeadPose, optional
        ``T`` frames of head motion (rotation about the neutral's centroid; translation relative to
        its median, see :class:`TakeSampler`).
    frame_times : (N,) float, optional
        The take time (seconds, the clock of ``times``) to show at each video frame; when given, only
        the first ``N`` video frames are written.  By default the preview ends with the take (video frames up
        to half a frame past its last time; a take of the first seconds previews those seconds), and the take
        and the video share one clock:
        a video frame ``s`` seconds after the video's first frame shows the take at time ``s`` (a take
        captured from this video, even one whose first frames had no face and start later, lines up).
    size : int
        Height of the output in pixels: each video frame is scaled to it (its width kept in
        proportion, rounded to an even number) and the character is rendered ``size x size``.
    backend : ``"auto"``, ``"gl"`` or ``"numpy"``
        The renderer (:class:`~faceretarget.render.MeshRenderer`).
    progress : bool
        Show a progress bar.
    colors : (V, 3) float, optional
        sRGB colour per vertex (default clay).
    pivot : (3,) float, optional
        Centre of the head's rotation, rig units (default the neutral's centroid).
    surface : Surface, optional
        The character's materials, textures and vertex colours (:class:`~faceretarget.render.Surface`;
        :func:`~faceretarget.characters.character_look`), drawn as a glTF viewer draws them.
    fit_to : (N, 3) float, optional
        The points the camera frames (default the rig's vertices).
    turns : list, optional
        Rigid parts turning with the take (the eyes with the gaze: :class:`TakeSampler`).
    log : callable
        Receives one line naming the renderer in use (and why the fast one is not, if so).

    Returns
    -------
    dict
        ``frames`` (written), ``render_s`` (seconds spent rendering the character), ``total_s``
        (the whole call), ``fps`` (frames / total_s), ``backend`` (the renderer's :attr:`backend`),
        ``codec``, ``width``, ``height``.

    Raises
    ------
    InvalidDataError
        Weights, times, head pose or ``frame_times`` of the wrong shape (the message gives it).
    InputFileError
        An unreadable video.
    OutputError
        ``out`` is the input video or cannot be written.
    MissingDependencyError
        PyAV is missing (or ``backend="gl"`` and OpenGL is not available).
    """
    t_start = time.perf_counter()
    video = Path(video)
    protect_inputs(out, [video])
    out = check_output_path(out)
    size = int(size)
    if size < 16:
        raise InvalidDataError(f"{out}: preview size must be at least 16 pixels, got {size}")
    sampler = TakeSampler(rig, weights, times, head, turns)
    max_frames = None
    ft = None
    if frame_times is not None:
        ft = np.asarray(frame_times, np.float64)
        if ft.ndim != 1 or not len(ft) or not np.isfinite(ft).all():
            raise InvalidDataError(f"{out}: frame_times must be (N,) finite seconds, got shape {ft.shape}")
        max_frames = len(ft)
    info = probe_video(video)
    fps = info.fps
    audio_s = len(ft) / fps if ft is not None else (info.duration or None)
    t_end = float(np.max(times)) if np.size(times) else 0.0
    if ft is None and fps and (info.n_frames or 0) > int(np.floor(t_end * fps + 0.5)) + 1:
        # the video runs past the animation (a take of its first frames): the preview ends with the animation
        max_frames = int(np.floor(t_end * fps + 0.5)) + 1
        audio_s = max_frames / fps
    extra = {} if colors is None else {"color": colors}
    with MeshRenderer(rig.neutral, (size, size), backend=backend, mm_per_unit=rig.mm_per_unit, pivot=pivot,
                      surface=surface, fit_to=fit_to, **extra) as renderer:
        if renderer.reason:
            log(f"preview: rendering with {renderer.backend} (slow), not OpenGL: {renderer.reason}")
        else:
            log(f"preview: rendering with {renderer.backend}")
        render_s = [0.0]

        def composed(frames: Iterator) -> Iterator[np.ndarray]:
            for i, t, rgb in frames:
                tt = ft[i] if ft is not None else t
                R, tr = sampler.head_at(tt)
                r0 = time.perf_counter()
                img = renderer.render(sampler.vertices_at(tt), R, tr)
                render_s[0] += time.perf_counter() - r0
                yield np.concatenate([rgb, img], axis=1)

        with atomic_path(out, protect=(video,)) as tmp:
            n, codec, shape = _run_threads(video, tmp, composed, fps, max_frames, size,
                                           audio_from=video if info.has_audio else None,
                                           audio_s=audio_s, progress=progress, total=max_frames or info.n_frames)
        backend_name = renderer.backend
    total = time.perf_counter() - t_start
    return {"frames": n, "render_s": render_s[0], "total_s": total, "fps": n / total if total > 0 else 0.0,
            "backend": backend_name, "codec": codec, "width": shape[1], "height": shape[0]}


def _run_threads(video: Path, tmp: Path, composed, fps: float, max_frames: int | None, size: int, *,
                 audio_from: Path | None, audio_s: float | None, progress: bool, total: int | None):
    """Decode (thread), compose in this thread (the OpenGL context lives here), encode (thread).

    Returns (frames written, codec, frame shape)."""
    from tqdm.auto import tqdm

    stop = threading.Event()
    decoded: queue.Queue = queue.Queue(_QUEUE)
    encoded: queue.Queue = queue.Queue(_QUEUE)
    shape = [(0, 0)]

    def to_encode() -> Iterator[np.ndarray]:
        while True:
            item = _get(encoded, stop)
            if item is _END:
                return
            shape[0] = item.shape[:2]
            yield item

    def decoded_frames() -> Iterator:
        while True:
            item = _get(decoded, stop)
            if item is _END:
                return
            yield item

    with tqdm(total=total or None, disable=not progress, desc="preview", unit="frame", leave=False) as bar:
        dec = _Worker(lambda: _decoded(video, max_frames, size, stop, decoded), "preview-decode", stop.set)
        enc = _Worker(lambda: write_video(tmp, to_encode(), fps, audio_from=audio_from, audio_duration=audio_s,
                                          on_frame=lambda: bar.update(1)), "preview-encode", stop.set)
        n = 0
        try:
            for img in composed(decoded_frames()):
                if not _put(encoded, img, stop):
                    break
                n += 1
            _put(encoded, _END, stop)
        except BaseException:
            stop.set()
            enc.thread.join()
            dec.thread.join()
            raise
        try:
            codec = enc.join()  # an encoding error first: it is what stopped the others
        finally:
            stop.set()  # a decoder still waiting to hand over frames (encoding stopped early) ends
        dec.join()  # a decoding error fails the whole preview (the partial file is discarded)
    return n, str(codec), shape[0]
