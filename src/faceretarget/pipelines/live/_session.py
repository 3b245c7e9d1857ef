"""Live mode: a camera or a video, frame by frame, onto a character shown in a local web page.

Each frame, as it arrives::

    decoded frame --MediaPipe--> 478 landmarks, 51 scores, pose matrix
        --68 points, One Euro (streaming)--> LandmarkSolver (T = 1, the calibrated scores as prior)
        --> weights of the character's own shapes   +   head rotation about the rest pose x amplitude
        --> JSON over a WebSocket to the page (three.js), [Live Link Face UDP packet], on_frame

The first ``calibration`` seconds with a face calibrate the session, as ``animate`` does for a
whole take: the actor's neutral face (:func:`~faceretarget.retarget.neutral_face` of those frames),
each score's resting level (:func:`~faceretarget.capture.neutral_baseline`, 5th percentile) and
the head's rest rotation (their mean).  Meanwhile the page gets the head and a neutral face.

A video file is played at its own pace (``realtime``: frame ``i`` is released at its timestamp,
like a camera; a frame not taken before the next one arrives is dropped and counted) or as fast as
the loop runs (``realtime=False``: every frame).  Latency is measured from the moment a decoded
frame is released to the moment its message is handed to the page's queue (and UDP socket).

The page's two sliders come back over the WebSocket: *head amplitude* multiplies the head's
rotation angle about its rest pose; *emotion amount* scales the expression weights (blinks and
gaze excluded).  That is a stand-in for live use: the emotion model (style model, Ch. 5) runs in
the offline ``animate``.
"""

from __future__ import annotations

import math
import os
import threading
import time
import uuid
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from fractions import Fraction
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from ...capture import (
    DEFAULT_SMOOTH,
    UNFILTERED_SCORES,
    FaceTracker,
    OneEuroFilter,
    OneEuroParams,
    calibrate_neutral,
    face_points,
    neutral_baseline,
    pose_from_matrices,
)
from ...characters import ScorePrior, held_shapes
from ...errors import InputFileError, InvalidDataError, OutputError
from ...headpose import HeadPose
from ...names import normalize_name
from ...retarget import LandmarkSolver, neutral_face
from ...rig import Rig
from .._animate import frame_solver
from ._server import LiveServer, parse_address

__all__ = ["LiveSession", "LiveStats", "LiveFrame", "run_live", "character_glb", "LIVE_LIMITS"]

#: Range of the page's sliders (and of the session's parameters).
LIVE_LIMITS = {"head_amplitude": (0.0, 3.0), "emotion_amount": (0.0, 3.0)}
#: Landmarks at the cheek edges (the face width that makes the One Euro ``beta`` unit-free).
_CHEEKS = (234, 454)
#: Seconds without a face after which the filters restart.
_GAP_RESET = 0.5
#: Shapes the emotion slider leaves alone (blinks and gaze are not expression).
_UNSCALED = ("eyeBlink", "eyeLook")


# ------------------------------------------------------------------------------------ results
@dataclass(frozen=True)
class LiveFrame:
    """One frame as sent (what ``on_frame`` receives).

    Attributes
    ----------
    index : int
        The source's frame number.
    t : float
        Seconds from the source's first frame (video time; wall clock for a camera).
    weights : (K,) float
        The character's weights in ``names`` order (zeros while calibrating).
    names : list of str
    head : (4,) float
        The head's rotation ``x, y, z, w`` about its rest pose, amplitude applied (glTF axes).
    calibrating : bool
    latency : float
        Seconds from the frame's release to this moment.
    """

    index: int
    t: float
    weights: np.ndarray
    names: list[str]
    head: np.ndarray
    calibrating: bool
    latency: float


@dataclass(eq=False)
class LiveStats:
    """What a live session did, and how fast.

    Attributes
    ----------
    source : str
    decoded : int
        Frames the source released.
    processed : int
        Frames tracked (``decoded - dropped``).
    dropped : int
        Frames released while the loop was busy and replaced by a newer one (real time only).
    no_face : int
        Processed frames without a face.
    calibration_frames : int
        Frames with a face used to calibrate (sent with a neutral face).
    solved : int
        Frames whose weights were solved and sent.
    seconds : float
        Wall time from the first released frame to the last message.
    latency : (solved,) float
        Seconds from each solved frame's release to its message.
    stages : dict of str -> (n,) float
        Seconds per frame in ``decode`` (video), ``track`` (MediaPipe), ``points`` (68 points and
        filters), ``solve``, ``head``, ``send``.
    interrupted : bool
        Stopped by Ctrl-C.
    params : dict
        The slider values at the end.
    pages, page_dropped : int
        Pages connected at the end, and frames dropped for connected pages that fell behind.
    llf_packets : int
        Live Link Face packets sent.
    frames, times, weights, points, head, amounts
        With ``record``: per solved frame, the source frame numbers, times (s), weights
        ``(T, K)`` in ``names`` order, the tracked 68 points ``(T, 68, 3)`` (pixels, +Y up, +Z to
        the camera, unfiltered), the head sent (:class:`HeadPose`), and ``(T, 2)`` the head
        amplitude and emotion amount in force.
    held : (K,) bool, optional
        After calibration: the shapes the tracker's scores hold in every frame
        (:func:`~faceretarget.characters.held_shapes`, as ``animate`` holds them).
    """

    source: str
    names: list[str]
    decoded: int = 0
    processed: int = 0
    dropped: int = 0
    no_face: int = 0
    calibration_frames: int = 0
    solved: int = 0
    seconds: float = 0.0
    latency: np.ndarray = field(default_factory=lambda: np.zeros(0))
    stages: dict = field(default_factory=dict)
    interrupted: bool = False
    params: dict = field(default_factory=dict)
    pages: int = 0
    page_dropped: int = 0
    llf_packets: int = 0
    frames: np.ndarray | None = None
    times: np.ndarray | None = None
    weights: np.ndarray | None = None
    points: np.ndarray | None = None
    head: HeadPose | None = None
    amounts: np.ndarray | None = None
    held: np.ndarray | None = None

    @property
    def fps(self) -> float:
        """Processed frames per second of wall time."""
        return self.processed / self.seconds if self.seconds > 0 else 0.0

    def latency_ms(self, q: float) -> float:
        """The ``q``-th percentile of the latency in milliseconds (NaN without solved frames)."""
        return float(np.percentile(self.latency, q) * 1000.0) if self.latency.size else float("nan")

    @property
    def latency_p50(self) -> float:
        """Median latency, ms."""
        return self.latency_ms(50)

    @property
    def latency_p95(self) -> float:
        """95th-percentile latency, ms."""
        return self.latency_ms(95)

    def stage_ms(self, name: str, q: float = 50) -> float:
        """The ``q``-th percentile of a stage's time per frame, ms (NaN when it never ran)."""
        s = self.stages.get(name)
        return float(np.percentile(s, q) * 1000.0) if s is not None and len(s) else float("nan")

    def summary(self) -> str:
        """A few lines: frames, fps, latency p50/p95, stage medians."""
        lines = [f"{self.source}: {self.processed} frames in {self.seconds:.2f} s ({self.fps:.1f} fps); "
                 f"{self.solved} solved, {self.calibration_frames} calibrating, {self.no_face} without a face, "
                 f"{self.dropped} dropped" + (" (stopped by Ctrl-C)" if self.interrupted else "")]
        if self.latency.size:
            lines.append(f"latency, decoded frame to weights sent: p50 {self.latency_p50:.1f} ms, "
                         f"p95 {self.latency_p95:.1f} ms, max {self.latency.max() * 1000:.1f} ms")
        elif self.processed:
            lines.append("no frame was solved: the calibration needs its seconds of frames with a face"
                         + (" (no face was found)" if self.no_face == self.processed else ""))
        parts = [f"{k} {self.stage_ms(k):.2f}" for k in ("decode", "track", "points", "solve", "head", "send")
                 if k in self.stages and len(self.stages[k])]
        if parts:
            lines.append("per frame (median ms): " + ", ".join(parts))
        if self.page_dropped:
            lines.append(f"{self.page_dropped} frames dropped for pages that fell behind")
        if self.llf_packets:
            lines.append(f"{self.llf_packets} Live Link Face packets sent")
        return "\n".join(lines)


# ------------------------------------------------------------------------------------ sources
@dataclass
class _Frame:
    index: int
    t: float
    rgb: np.ndarray
    ready: float
    decode: float


class _Mailbox:
    """The latest released frame (an older one not yet taken is dropped), or the end."""

    def __init__(self):
        self._cv = threading.Condition()
        self._frame: _Frame | None = None
        self._done = False
        self._error: BaseException | None = None
        self.released = 0
        self.dropped = 0

    def put(self, frame: _Frame) -> None:
        with self._cv:
            if self._frame is not None:
                self.dropped += 1
            self._frame = frame
            self.released += 1
            self._cv.notify()

    def finish(self, error: BaseException | None = None) -> None:
        with self._cv:
            self._done = True
            self._error = error
            self._cv.notify()

    def get(self, stop: threading.Event) -> _Frame | None:
        with self._cv:
            while self._frame is None and not self._done and not stop.is_set():
                self._cv.wait(0.1)
            if self._frame is not None:
                f, self._frame = self._frame, None
                return f
            if self._error is not None:
                raise self._error
            return None


def _video_frames(path: Path, max_frames: int | None) -> Iterator[_Frame]:
    from ...io import iter_frames

    it = iter_frames(path, max_frames=max_frames)
    while True:
        a = time.perf_counter()
        try:
            i, t, rgb = next(it)
        except StopIteration:
            return
        b = time.perf_counter()
        yield _Frame(i, t, rgb, b, b - a)


def _pump_video(path: Path, max_frames: int | None, box: _Mailbox, stop: threading.Event) -> None:
    """Release the video's frames at their timestamps (real time) into ``box``."""
    err = None
    try:
        start = None
        for f in _video_frames(path, max_frames):
            if start is None:
                start = time.perf_counter() - f.t
            wait = start + f.t - time.perf_counter()
            if wait > 0 and stop.wait(wait):
                break
            if stop.is_set():
                break
            f.ready = time.perf_counter()
            box.put(f)
    except BaseException as e:  # noqa: BLE001 - handed to the session's thread
        err = e
    box.finish(err)


def _open_camera(index: int):
    from ...optional import optional_import

    cv2 = optional_import("cv2", "camera input")
    logging = getattr(getattr(cv2, "utils", None), "logging", None)
    level = logging.getLogLevel() if logging is not None else None
    try:
        if logging is not None:  # OpenCV logs every backend it tries; the error below says it once
            logging.setLogLevel(logging.LOG_LEVEL_SILENT)
        cap = cv2.VideoCapture(int(index))
    finally:
        if logging is not None:
            logging.setLogLevel(level)
    if not cap.isOpened():
        cap.release()
        raise InputFileError(f"camera {index}: cannot be opened (no such camera, or in use)")
    return cv2, cap


def _pump_camera(index: int, cv2, cap, max_frames: int | None, box: _Mailbox, stop: threading.Event) -> None:
    """Grab camera frames as they come into ``box`` (times from the first grab)."""
    err = None
    try:
        t0 = None
        i = 0
        while not stop.is_set() and (max_frames is None or i < max_frames):
            ok, bgr = cap.read()
            now = time.perf_counter()
            if not ok:
                if i == 0:
                    err = InputFileError(f"camera {index}: gives no frames")
                break
            t0 = now if t0 is None else t0
            rgb = cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)
            done = time.perf_counter()
            box.put(_Frame(i, now - t0, rgb, done, done - now))
            i += 1
    except BaseException as e:  # noqa: BLE001 - handed to the session's thread
        err = e
    finally:
        cap.release()
    box.finish(err)


# ------------------------------------------------------------------------------------ character
def character_glb(character: Rig) -> bytes:
    """The character as a ``.glb`` for the page: its shapes as morph targets at rest, a ``head`` node.

    The head node turns about a neck pivot below the face, at the chin's height and the back of
    the mesh (metres, from the neutral's bounding box).
    """
    import tempfile

    from ...io import write_glb

    v = character.neutral.vertices * (character.mm_per_unit / 1000.0)
    lo, hi = v.min(axis=0), v.max(axis=0)
    pivot = np.array([(lo[0] + hi[0]) / 2, lo[1], lo[2]])
    with tempfile.TemporaryDirectory(prefix="faceretarget-live-") as d:
        p = Path(d) / "character.glb"
        write_glb(p, character, np.zeros((1, character.n_shapes)), np.zeros(1),
                  head=HeadPose.identity(1), head_pivot=pivot)
        return p.read_bytes()


def _check_param(name: str, value) -> float:
    lo, hi = LIVE_LIMITS[name]
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise InvalidDataError(f"{name} must be a number in [{lo}, {hi}], got {value!r}") from None
    if not (math.isfinite(v) and lo <= v <= hi):
        raise InvalidDataError(f"{name} must be a number in [{lo}, {hi}], got {value!r}")
    return v


# ------------------------------------------------------------------------------------ session
class LiveSession:
    """A live retargeting session: frames in as they arrive, weights out to a page and more.

    Parameters
    ----------
    source : path-like or int
        A video file, or a camera index (OpenCV ``VideoCapture``).
    character : Rig
        With its 68 landmarks and ARKit-named shapes (driven by
        :class:`~faceretarget.retarget.LandmarkSolver`).
    serve : (host, port) or "HOST:PORT", optional
        Serve the page there (port 0: any free port, see :attr:`url`); None: no page.
    max_frames : int, optional
        Stop after this many frames of the source.
    realtime : bool
        Release a video's frames at their timestamps (dropping frames the loop cannot take in
        time); False: process every frame as fast as possible.  A camera is always real time.
    emotion_amount : float
        Scale of the expression weights (blinks and gaze kept), in [0, 3]; a stand-in for the
        emotion model of ``animate``.
    head_amplitude : float
        Factor on the head's rotation angle about its rest pose, in [0, 3].
    calibration : float
        Seconds of frames with a face that calibrate the neutral face, scores and head rest.
    smooth : OneEuroParams or None
        Streaming One Euro filter of the points, scores and head angles (``capture``'s default).
    llf_target : (host, port) or "HOST[:PORT]", optional
        Also send each solved frame as a Live Link Face UDP packet there (the 52 ARKit curves of
        the character's weights, head yaw/pitch/roll; port 11111 when not given).
    wait_for_viewer : float
        Seconds to wait, when serving, for a page to connect before the source starts (0: none).
    model : path-like, optional
        FaceLandmarker ``.task`` file.
    solver : LandmarkSolver, optional
        Its parameters are used (a fresh copy is fitted at calibration); default
        :func:`~faceretarget.pipelines.frame_solver`.
    record : bool
        Keep the solved frames' weights, points and head in :class:`LiveStats` (memory grows
        with the session: about 2 KB per frame).
    on_frame : callable, optional
        Called with each :class:`LiveFrame`, in the session's thread.
    log : callable
        Progress lines.
    """

    def __init__(self, source: str | os.PathLike | int, character: Rig, *,
                 serve: tuple[str, int] | str | None = None, max_frames: int | None = None,
                 realtime: bool = True, emotion_amount: float = 1.0, head_amplitude: float = 1.0,
                 calibration: float = 1.0, smooth: OneEuroParams | None = DEFAULT_SMOOTH,
                 llf_target: tuple[str, int] | str | None = None, wait_for_viewer: float = 0.0,
                 model: str | os.PathLike | None = None, solver: LandmarkSolver | None = None,
                 record: bool = True, on_frame: Callable[[LiveFrame], None] | None = None,
                 log: Callable[..., None] = print):
        if isinstance(source, bool) or not isinstance(source, (int, str, os.PathLike)):
            raise InvalidDataError(f"live source must be a video file or a camera index, got {source!r}")
        self.camera = source if isinstance(source, int) else None
        self.video = None if self.camera is not None else Path(source)
        if self.video is not None and not self.video.is_file():
            raise InputFileError(f"{self.video}: video not found")
        if max_frames is not None and int(max_frames) < 1:
            raise InvalidDataError(f"max_frames must be at least 1, got {max_frames}")
        if not (math.isfinite(calibration) and calibration >= 0):
            raise InvalidDataError(f"calibration must be seconds >= 0, got {calibration}")
        lm = character.landmarks
        if lm is None or len(lm) != 68:
            raise InvalidDataError(f"{character.name}: live mode needs the character's 68 landmarks "
                                   "(landmarks68.txt) to drive its shapes from the tracked face")
        self.character = character
        self.names = list(character.names)
        self.max_frames = None if max_frames is None else int(max_frames)
        self.realtime = bool(realtime) or self.camera is not None
        self.calibration = float(calibration)
        self.smooth = smooth
        self.wait_for_viewer = float(wait_for_viewer)
        self.model = model
        self.solver_template = solver or frame_solver()
        self.record = record
        self.on_frame = on_frame
        self.log = log
        self._params = {"head_amplitude": _check_param("head_amplitude", head_amplitude),
                        "emotion_amount": _check_param("emotion_amount", emotion_amount)}
        self._params_lock = threading.Lock()
        self.serve = parse_address(serve) if isinstance(serve, str) else serve
        self.llf_target = (parse_address(llf_target, what="--llf", default_port=11111) if isinstance(llf_target, str)
                           else llf_target)
        self.source_name = f"camera {self.camera}" if self.camera is not None else str(self.video)
        self._scaled = np.array([not normalize_name(n).startswith(_UNSCALED) for n in self.names])
        self._stop = threading.Event()
        self.server: LiveServer | None = None
        self._tracker: FaceTracker | None = None
        self._udp = None
        self._llf_map = None
        self._camera = None
        self._started = False

    # ------------------------------------------------------------------------------ control
    @property
    def url(self) -> str | None:
        """The page's address while serving."""
        return self.server.url if self.server is not None else None

    @property
    def params(self) -> dict:
        """The current slider values: ``head_amplitude``, ``emotion_amount``."""
        with self._params_lock:
            return dict(self._params)

    def set_params(self, **values) -> dict:
        """Change ``head_amplitude`` and/or ``emotion_amount`` (checked); every page is told."""
        bad = set(values) - set(LIVE_LIMITS)
        if bad:
            raise InvalidDataError(f"unknown live parameter(s) {', '.join(sorted(bad))} "
                                   f"(use {', '.join(LIVE_LIMITS)})")
        checked = {k: _check_param(k, v) for k, v in values.items()}
        with self._params_lock:
            self._params.update(checked)
            now = dict(self._params)
        if self.server is not None:
            self.server.broadcast({"type": "params", **now})
        return now

    def _on_message(self, msg: dict) -> None:
        if msg.get("type") == "params":
            self.set_params(**{k: v for k, v in msg.items() if k in LIVE_LIMITS})

    def stop(self) -> None:
        """Ask :meth:`run` to finish after the current frame (from any thread)."""
        self._stop.set()

    # ------------------------------------------------------------------------------ life cycle
    def start(self) -> LiveSession:
        """Open the tracker, warm the solver, start the page's server and the UDP socket."""
        if self._started:
            return self
        try:
            self._start()
        except BaseException:
            self.close()
            raise
        self._started = True
        return self

    def _start(self) -> None:
        t0 = time.perf_counter()
        if self.camera is not None and self._camera is None:
            self._camera = _open_camera(self.camera)
        self._tracker = FaceTracker(self.model)
        warm = LandmarkSolver(**self.solver_template.get_params())
        lm = self.character.neutral.vertices[self.character.landmarks]
        warm.fit(self.character, lm).transform(lm[None], smooth=False)   # loads the compiled kernel
        self._tracker.track(np.zeros((64, 64, 3), np.uint8), 0.0)          # builds MediaPipe's graph
        if self.llf_target is not None:
            import socket

            from ...io import arkit_curve_map

            self._llf_map = arkit_curve_map(self.names, self.character.basis, self.character.basis_names,
                                            source=self.character.name)
            host, port = self.llf_target
            try:
                info = socket.getaddrinfo(host, port, type=socket.SOCK_DGRAM)[0]
            except OSError as e:
                raise OutputError(f"--llf {host}:{port}: cannot resolve the address ({e})") from None
            self._udp = socket.socket(info[0], socket.SOCK_DGRAM)
            self._udp_addr = info[4]
            self._llf_device = str(uuid.uuid4()).upper()
            fps = 60.0
            if self.video is not None:
                from ...io import probe_video

                fps = float(probe_video(self.video).fps or 60.0)
            self._llf_rate = Fraction(fps).limit_denominator(1001)
        if self.serve is not None:
            host, port = self.serve
            self.server = LiveServer(host, port, glb=character_glb(self.character), on_message=self._on_message,
                                     hello=self._hello)
            self.log(f"live page: {self.server.url} (the character {self.character.name}, "
                     f"{self.character.n_shapes} shapes)")
        self.log(f"tracker and solver ready in {time.perf_counter() - t0:.2f} s")

    def _hello(self) -> list:
        return [{"type": "hello", "source": self.source_name, "character": self.character.name,
                 "names": self.names, "params": self.params}]

    def close(self) -> None:
        """Close the page's server, the tracker and the UDP socket."""
        self._stop.set()
        if self.server is not None:
            self.server.close()
        if self._tracker is not None:
            self._tracker.close()
            self._tracker = None
        if self._udp is not None:
            self._udp.close()
            self._udp = None
        if self._camera is not None:
            self._camera[1].release()
            self._camera = None

    def __enter__(self) -> LiveSession:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.close()

    # ------------------------------------------------------------------------------ the loop
    def _frames(self, box: _Mailbox | None) -> Iterator[_Frame]:
        if box is None:
            yield from _video_frames(self.video, self.max_frames)
            return
        while True:
            f = box.get(self._stop)
            if f is None:
                return
            yield f

    def run(self) -> LiveStats:
        """Process the source until it ends, ``max_frames``, :meth:`stop` or Ctrl-C; the summary."""
        self.start()
        stats = LiveStats(source=self.source_name, names=list(self.names))
        st = _State(self, stats)
        box = None
        pump = None
        cap = None
        if self.realtime:
            box = _Mailbox()
            if self.camera is not None:
                cv2, cap = self._camera or _open_camera(self.camera)
                self._camera = None
                pump = threading.Thread(target=_pump_camera, args=(self.camera, cv2, cap, self.max_frames, box,
                                                                   self._stop), daemon=True)
            else:
                pump = threading.Thread(target=_pump_video, args=(self.video, self.max_frames, box, self._stop),
                                        daemon=True)
        self.log(f"live: {self.source_name} onto {self.character.name}"
                 + (" in real time" if self.realtime else " as fast as possible")
                 + (f", calibrating on the first {self.calibration:g} s" if self.calibration > 0 else ""))
        restore = _stop_on_ctrl_c(self._stop, stats)
        try:
            if self.server is not None and self.wait_for_viewer > 0:
                self.log(f"waiting up to {self.wait_for_viewer:g} s for the page to connect: open {self.server.url}")
                end = time.perf_counter() + self.wait_for_viewer
                while not (self._stop.is_set() or self.server.wait_for_clients(1, 0.2)):
                    if time.perf_counter() > end:
                        self.log("no page connected; starting anyway")
                        break
            if pump is not None and not self._stop.is_set():
                pump.start()
                cap = None  # the pump releases it
            for f in self._frames(box):
                st.process(f)
                if self._stop.is_set():
                    break
        except KeyboardInterrupt:
            stats.interrupted = True
        finally:
            restore()
            self._stop.set()
            if pump is not None and pump.is_alive():
                pump.join(5.0)
            if cap is not None:
                cap.release()
        st.finish(box)
        if self.server is not None:
            self.server.broadcast({"type": "end", "summary": stats.summary()})
        self._stop.clear()
        return stats


def _stop_on_ctrl_c(stop: threading.Event, stats: LiveStats) -> Callable[[], None]:
    """In the main thread, the first Ctrl-C ends the run at the next frame instead of raising KeyboardInterrupt
    wherever the main thread is: inside MediaPipe's tracker call it left the tracker's native state half-done
    and its result thread crashed (SIGSEGV, seen under load); a second Ctrl-C interrupts at once.  Returns
    what puts the previous handler back."""
    import signal

    if threading.current_thread() is not threading.main_thread():
        return lambda: None
    previous = signal.getsignal(signal.SIGINT)
    if previous is not signal.default_int_handler:          # ignored, or an application's own handler: theirs
        return lambda: None

    def handler(signum, frame):
        stats.interrupted = True
        stop.set()
        signal.signal(signal.SIGINT, previous)                 # the next Ctrl-C raises KeyboardInterrupt

    signal.signal(signal.SIGINT, handler)
    return lambda: signal.signal(signal.SIGINT, previous)


class _State:
    """Per-run state of :meth:`LiveSession.run`: filters, calibration, solver, records."""

    def __init__(self, session: LiveSession, stats: LiveStats):
        self.s = session
        self.stats = stats
        self.tracker = session._tracker
        self.first_ready: float | None = None
        self.last_sent: float | None = None
        self.stage = {k: [] for k in ("decode", "track", "points", "solve", "head", "send")}
        self.latency: list[float] = []
        self.filters = None
        self.blinks = np.zeros(0, dtype=int)
        self.last_face_t = -np.inf
        self.cal_t0: float | None = None
        self.cal_points: list[np.ndarray] = []
        self.cal_scores: list[np.ndarray] = []
        self.cal_rot: list[np.ndarray] = []
        self.solver: LandmarkSolver | None = None
        self.base = None
        self.prior_map = None
        self.prior_filter = None
        self.held = None
        self.rest = None
        self.first_rot = None
        self.rec: dict[str, list] = {k: [] for k in ("frames", "times", "weights", "points", "head", "amounts")}
        K = len(session.names)
        self.zeros = np.zeros(K)
        self.names_json = None
        if session.calibration <= 0:
            self.cal_t0 = -np.inf

    # -------------------------------------------------------------------------- per frame
    def process(self, f: _Frame) -> None:
        s, stats = self.s, self.stats
        if self.first_ready is None:
            self.first_ready = f.ready
        stats.processed += 1
        if s.video is not None:
            self.stage["decode"].append(f.decode)
        a = time.perf_counter()
        found = self.tracker.track(f.rgb, f.t)
        b = time.perf_counter()
        self.stage["track"].append(b - a)
        if found is None:
            stats.no_face += 1
            return
        lm, scores, matrix = found
        if f.t - self.last_face_t > _GAP_RESET:
            self._reset_filters(lm)
        self.last_face_t = f.t
        raw = face_points(lm)
        P, S, euler = raw, np.clip(scores, 0.0, 1.0), pose_from_matrices(matrix[None]).to_euler("YXZ")[0]
        if self.filters is not None and np.isfinite(euler).all():
            fp, fs, fh = self.filters
            Sf = np.array(fs(S, f.t), dtype=np.float64)
            Sf[self.blinks] = S[self.blinks]          # a blink is over in a few frames: the filter only delays it
            P, S, euler = fp(raw, f.t), np.clip(Sf, 0.0, 1.0), fh(euler, f.t)
        rot = Rotation.from_euler("YXZ", euler) if np.isfinite(euler).all() else Rotation.identity()
        c = time.perf_counter()
        self.stage["points"].append(c - b)

        calibrating = self.solver is None
        params = s.params
        if calibrating:
            if self.first_rot is None:
                self.first_rot = rot
            if self.cal_t0 is None:
                self.cal_t0 = f.t
            self.cal_points.append(P)
            self.cal_scores.append(S)
            self.cal_rot.append(rot.as_quat())
            stats.calibration_frames += 1
            W = self.zeros
            if f.t - self.cal_t0 >= s.calibration and len(self.cal_points) >= 3:
                self._calibrate()
            rest = self.first_rot
        else:
            pf = self.prior_filter
            prior = self.prior_map(calibrate_neutral(S, self.base)[None],
                                   smooth=None if pf is None else lambda X: pf(X[0], f.t)[None])[0]
            # the shapes the scores hold, in every frame (not only those scored above 0 in this one)
            W = self.solver.transform(P[None], prior[None], smooth=False, scored=self.held).weights[0]
            amount = params["emotion_amount"]
            if amount != 1.0:
                lo, hi = self.solver.range_
                W = np.where(s._scaled, np.clip(W * amount, lo, hi), W)
            rest = self.rest
        d = time.perf_counter()
        if not calibrating:
            self.stage["solve"].append(d - c)
        q = Rotation.from_rotvec((rest.inv() * rot).as_rotvec() * params["head_amplitude"]).as_quat()
        e = time.perf_counter()
        self.stage["head"].append(e - d)

        self._send(f, W, q, calibrating, rot, rest, params)
        g = time.perf_counter()
        self.stage["send"].append(g - e)
        self.last_sent = g
        lat = g - f.ready
        if not calibrating:
            stats.solved += 1
            self.latency.append(lat)
            if s.record:
                r = self.rec
                r["frames"].append(f.index)
                r["times"].append(f.t)
                r["weights"].append(W)
                r["points"].append(raw)
                r["head"].append(q)
                r["amounts"].append((params["head_amplitude"], params["emotion_amount"]))
        if s.on_frame is not None:
            s.on_frame(LiveFrame(index=f.index, t=f.t, weights=W, names=s.names, head=q, calibrating=calibrating,
                                 latency=lat))

    def _reset_filters(self, lm: np.ndarray) -> None:
        p = self.s.smooth
        if p is None:
            self.filters = self.prior_filter = None
            return
        width = float(np.linalg.norm(lm[_CHEEKS[0], :2] - lm[_CHEEKS[1], :2]))
        # the blink scores pass unfiltered: causal, the One Euro filter (1 Hz at rest) delayed each blink by a
        # frame and took only 12-22 % of their jitter at rest on the shared videos; on P11's renders the live
        # blink F1 went 0.68 -> 0.76 (24 cached runs) with the blinks unfiltered
        # (the same scores a whole take's post-processing leaves unfiltered: capture.UNFILTERED_SCORES)
        self.blinks = np.array([i for i, n in enumerate(self.tracker.names) if n in UNFILTERED_SCORES], dtype=int)
        self.filters = (OneEuroFilter(p, vector_axis=-1, scale=max(width, 1.0)), OneEuroFilter(p),
                        OneEuroFilter(p))
        self.prior_filter = OneEuroFilter(p)      # the mouth's jointly fitted prior (ScorePrior's smooth)

    def _calibrate(self) -> None:
        s = self.s
        P = np.array(self.cal_points)
        S = np.array(self.cal_scores)
        self.base = neutral_baseline(S, percentile=5)
        neutral = neutral_face(P, calibrate_neutral(S, self.base))
        tpl = s.solver_template
        self.solver = LandmarkSolver(**tpl.get_params()).fit(s.character, neutral)
        self.prior_map = ScorePrior(s.character, list(self.tracker.names), log=s.log)
        self.held = self.stats.held = held_shapes(s.character, list(self.tracker.names), self.prior_map.rows)
        self.rest = Rotation.from_quat(np.array(self.cal_rot)).mean()
        s.log(f"calibrated on {len(P)} frames ({self.stats.calibration_frames} with a face): neutral face, "
              f"score baseline (mean {self.base.mean():.3f}), head rest {np.degrees(self.rest.magnitude()):.1f} deg "
              "from the camera axis")

    def _send(self, f: _Frame, W: np.ndarray, q: np.ndarray, calibrating: bool, rot, rest, params) -> None:
        import json

        s = self.s
        if s.server is not None:
            if self.names_json is None:
                self.names_json = json.dumps(s.names)
            msg = (f'{{"type":"frame","frame":{int(f.index)},"t":{round(float(f.t), 6)!r},'
                   f'"calibrating":{"true" if calibrating else "false"},'
                   f'"weights":{json.dumps(np.round(W, 5).tolist())},"names":{self.names_json},'
                   f'"head":{json.dumps(np.round(q, 6).tolist())}}}')
            s.server.broadcast(msg)
        if s._udp is not None and not calibrating:
            from ...io import livelinkface_packet

            curves = np.clip(W @ s._llf_map, 0.0, 1.0)
            angles = HeadPose(q[None]).to_livelinkface()[0]
            rate = s._llf_rate
            frames = f.t * rate.numerator / rate.denominator
            try:
                s._udp.sendto(livelinkface_packet(curves, angles, frame=int(frames), subframe=frames - int(frames),
                                                  rate=(rate.numerator, rate.denominator), subject="faceretarget",
                                                  device_id=s._llf_device), s._udp_addr)
                self.stats.llf_packets += 1
            except OSError:
                pass

    # -------------------------------------------------------------------------- end
    def finish(self, box: _Mailbox | None) -> None:
        stats, s = self.stats, self.s
        stats.dropped = box.dropped if box is not None else 0
        stats.decoded = box.released if box is not None else stats.processed
        if self.first_ready is not None and self.last_sent is not None:
            stats.seconds = self.last_sent - self.first_ready
        stats.latency = np.array(self.latency)
        stats.stages = {k: np.array(v) for k, v in self.stage.items()}
        stats.params = s.params
        if s.server is not None:
            stats.pages = s.server.n_clients
            stats.page_dropped = s.server.dropped
        if s.record:
            r = self.rec
            K = len(s.names)
            stats.frames = np.array(r["frames"], dtype=np.int64)
            stats.times = np.array(r["times"], dtype=np.float64)
            stats.weights = np.array(r["weights"]).reshape(-1, K)
            stats.points = np.array(r["points"]).reshape(-1, 68, 3)
            stats.head = HeadPose(np.array(r["head"]).reshape(-1, 4), source=f"{stats.source} (live head)")
            stats.amounts = np.array(r["amounts"], dtype=np.float64).reshape(-1, 2)


def run_live(source: str | os.PathLike | int, character: Rig, *, serve: tuple[str, int] | str | None = None,
             max_frames: int | None = None, realtime: bool = True, emotion_amount: float = 1.0,
             head_amplitude: float = 1.0, llf_target: tuple[str, int] | str | None = None,
             on_frame: Callable[[LiveFrame], None] | None = None, log: Callable[..., None] = print,
             **options) -> LiveStats:
    """Run a live session to its end and return its :class:`LiveStats` (see :class:`LiveSession`).

    Parameters
    ----------
    source : path-like or int
        A video file or a camera index.
    character : Rig
    serve : (host, port) or "HOST:PORT", optional
        Serve the page (``http://host:port/``); None: no page.
    max_frames : int, optional
    realtime : bool
    emotion_amount, head_amplitude : float
        The sliders' starting values (in [0, 3]).
    llf_target : (host, port) or "HOST:PORT", optional
        Live Link Face UDP stream target.
    on_frame : callable, optional
        Called with each :class:`LiveFrame`.
    log : callable
    **options
        ``calibration``, ``smooth``, ``wait_for_viewer``, ``model``, ``solver``, ``record``.

    Returns
    -------
    LiveStats
        Frames, fps, latency p50/p95 (ms) and stage times; the summary is also logged.
    """
    with LiveSession(source, character, serve=serve, max_frames=max_frames, realtime=realtime,
                     emotion_amount=emotion_amount, head_amplitude=head_amplitude, llf_target=llf_target,
                     on_frame=on_frame, log=log, **options) as session:
        stats = session.run()
    log(stats.summary())
    return stats

