"""The worker process of a host application (the Blender extension): the long jobs, away from its UI thread.

A host that must never block (Blender's main thread) starts one Python process running
:func:`serve_jobs` and talks to it in JSON lines.  Requests on the worker's stdin::

    {"id": 7, "kind": "animate", "dir": "/tmp/job7", "params": {...}}    a job (below)
    {"stop": 7}                                                         stop job 7 (a live session)
    {"quit": true}                                                      finish

Answers on its stdout, one JSON object a line, each with the job's ``id``::

    {"id": 7, "progress": 0.42, "stage": "capture"}     fraction of the job done
    {"id": 7, "log": "..."}  {"id": 7, "warning": "..."}  one line each
    {"id": 7, "frame": {...}}                            a live frame
    {"id": 7, "done": {...}}                             the result (arrays in DIR/result.npz)
    {"id": 7, "error": "one line naming the file or shape", "type": "InputFileError"}

Everything the libraries print (MediaPipe, TensorFlow Lite) goes to stderr: stdout carries the
protocol only.  Jobs (``params``):

``animate``
    ``character`` (a pickled :class:`~faceretarget.character.Character`, e.g. from
    :func:`~faceretarget.io.read_blender_scene_character`), ``landmarks`` (a
    :func:`landmark_record` or None), ``video``, ``shapes``, ``head``, ``head_amplitude``, and for
    emotion ``style`` + ``emotion`` (``{name: amount}``): :func:`animate` on the video's capture
    (:func:`capture_take`, cached by the video's SHA-256 in ``FACERETARGET_CACHE``/captures).
``take``
    ``character``, ``landmarks``, ``take``, ``route``, ``source_rig``, ``source_keys``, ``shapes``:
    :func:`apply_take`.
``landmarks``
    ``character``, ``landmarks``, optional ``points`` ``(68, 3)`` to put on the face mesh's surface
    (points moved by hand): the 68 landmarks found (or snapped) and their positions.
``style_info``
    ``style``: the style model's emotions.
``live``
    ``character``, ``landmarks``, ``source`` (a video file or a camera index), ``shapes``,
    ``head_amplitude``, ``realtime``, ``max_frames``: a :class:`LiveSession` whose frames are sent as
    they are solved until its source ends or the job is stopped.

Every result holds the character's channels (``[name, [[mesh ref, shape name], ...]]``: the shapes each
weight column drives), so the host keys the right shape keys without solving anything itself.
"""

from __future__ import annotations

import hashlib
import json
import os
import pickle
import queue
import sys
import threading
import time
import traceback
import warnings
from collections.abc import Callable
from pathlib import Path

import numpy as np

from ...errors import FaceRetargetError, FaceRetargetWarning, InvalidDataError
from ...files import cache_dir, cache_enabled, file_sha256

__all__ = ["serve_jobs", "JOB_KINDS", "capture_cache_path", "cached_capture", "WorkerChannel"]

#: The jobs :func:`serve_jobs` runs.
JOB_KINDS = ("animate", "take", "landmarks", "style_info", "live")


class WorkerChannel:
    """The protocol's output: JSON lines on a private copy of stdout (thread-safe)."""

    def __init__(self, stream):
        self.stream = stream
        self.lock = threading.Lock()

    def send(self, **msg) -> None:
        line = json.dumps(msg, separators=(",", ":"), allow_nan=False, default=_jsonable)
        with self.lock:
            self.stream.write(line + "\n")
            self.stream.flush()


def _jsonable(x):
    if isinstance(x, np.ndarray):
        return x.tolist()
    if isinstance(x, np.generic):
        return x.item()
    if isinstance(x, Path):
        return str(x)
    raise TypeError(type(x).__name__)


# ------------------------------------------------------------------------------------- caches
def character_parts(character) -> list:
    """The character pickled for the worker as a list of byte buffers to write one after the other: a header,
    the pickle (protocol 5, its arrays out of band, so pickling copies none of them), then each array's bytes
    (:func:`read_character_parts` reads them back).  A host writes them a step at a time: pickled in band, a
    VALID avatar (30 MB) held Blender's main thread 100-170 ms in one step."""
    buffers: list = []
    main = pickle.dumps(character, protocol=5, buffer_callback=buffers.append)
    views = [b.raw() for b in buffers]
    sizes = [len(main)] + [v.nbytes for v in views]
    head = len(sizes).to_bytes(8, "little") + b"".join(n.to_bytes(8, "little") for n in sizes)
    return [head, main, *views]


def read_character_parts(data: bytes):
    """The character of :func:`character_parts`' buffers written one after the other."""
    view = memoryview(data)
    n = int.from_bytes(view[:8], "little")
    sizes = [int.from_bytes(view[8 + 8 * i:16 + 8 * i], "little") for i in range(n)]
    if n < 1 or 8 + 8 * n + sum(sizes) != len(view):
        raise InvalidDataError(f"the character file for the worker is {len(view)} bytes, its header says "
                               f"{8 + 8 * n + sum(sizes)}: written incompletely")
    parts, at = [], 8 + 8 * n
    for size in sizes:
        parts.append(view[at:at + size])
        at += size
    return pickle.loads(parts[0], buffers=parts[1:])


def capture_cache_path(video: str | os.PathLike) -> Path:
    """Where the capture of ``video`` that ``animate`` makes (``neutral_percentile=5``) is cached."""
    from ...errors import InputFileError

    p = Path(video)
    if not p.is_file():
        raise InputFileError(f"{p}: video not found")
    return cache_dir("captures") / f"{file_sha256(p)}-animate.pkl"


def cached_capture(video: str | os.PathLike, *, progress=None, log: Callable[..., None] = print):
    """The capture :func:`~faceretarget.pipelines.animate` makes of ``video``
    (:func:`~faceretarget.pipelines.capture_take` with ``neutral_percentile=5``), read from the cache when
    it holds it (keyed by the video's SHA-256), else made and cached."""
    from ...files import atomic_path
    from .._capture import capture_take

    path = capture_cache_path(video)
    if cache_enabled() and path.is_file():
        try:
            with open(path, "rb") as f:
                cap = pickle.load(f)
            log(f"capture of {Path(video).name}: read from the cache {path}")
            return cap
        except (OSError, pickle.UnpicklingError, EOFError, AttributeError, ImportError):
            pass
    cap = capture_take(video, neutral_percentile=5.0, progress=progress or False, log=log)
    if not cache_enabled():
        return cap
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        with atomic_path(path) as tmp, open(tmp, "wb") as f:
            pickle.dump(cap, f, protocol=pickle.HIGHEST_PROTOCOL)
    except OSError:
        log("capture: no writable cache folder; it will be made again next time")
    return cap


# ------------------------------------------------------------------------------------- the server
class _Server:
    def __init__(self, out: WorkerChannel):
        self.out = out
        self.characters: dict[str, object] = {}     # pickle SHA-256 -> Character (landmarks found once)
        self.stops: dict[int, threading.Event] = {}
        self.requests: queue.Queue = queue.Queue()

    # ---- input: a thread, so a stop reaches a running live job
    def read(self, stream) -> None:
        for line in stream:
            line = line.strip()
            if not line:
                continue
            try:
                msg = json.loads(line)
            except ValueError:
                continue
            if "stop" in msg:
                ev = self.stops.get(int(msg["stop"]))
                if ev is not None:
                    ev.set()
                continue
            self.requests.put(msg)
        self.requests.put({"quit": True})

    def run(self) -> None:
        while True:
            msg = self.requests.get()
            if msg.get("quit"):
                return
            self.job(msg)

    def job(self, msg: dict) -> None:
        jid = int(msg.get("id", 0))
        kind = msg.get("kind")
        stop = self.stops.setdefault(jid, threading.Event())
        send = self.out.send
        try:
            if kind not in JOB_KINDS:
                raise InvalidDataError(f"unknown job '{kind}' (one of {', '.join(JOB_KINDS)})")
            folder = Path(msg["dir"])
            params = dict(msg.get("params") or {})
            job = _Job(self, jid, folder, params, stop)
            with warnings.catch_warnings(record=True) as caught:
                warnings.simplefilter("always")
                result = getattr(job, kind)()
            seen = set()
            for w in caught:
                text = " ".join(str(w.message).split())
                if issubclass(w.category, FaceRetargetWarning) and text not in seen:
                    seen.add(text)
                    send(id=jid, warning=text)
            send(id=jid, done=result)
        except FaceRetargetError as e:
            send(id=jid, error=" ".join(str(e).split()), type=type(e).__name__)
        except Exception as e:  # noqa: BLE001 - one line to the host, the traceback to stderr
            traceback.print_exc(file=sys.stderr)
            text = " ".join(str(e).split()) or type(e).__name__
            send(id=jid, error=f"{type(e).__name__}: {text}"[:400], type=type(e).__name__)
        finally:
            self.stops.pop(jid, None)


class _Job:
    """One job of the worker (the module docstring lists them)."""

    def __init__(self, server: _Server, jid: int, folder: Path, params: dict, stop: threading.Event):
        self.server, self.id, self.folder, self.params, self.stop = server, jid, folder, params, stop

    # ---- helpers
    def progress(self, fraction: float, stage: str) -> None:
        self.server.out.send(id=self.id, progress=round(float(min(max(fraction, 0.0), 1.0)), 4), stage=stage)

    def log(self, *parts) -> None:
        text = " ".join(" ".join(str(p).split()) for p in parts)
        self.server.out.send(id=self.id, log=text)

    def character(self, *, find: bool = True):
        """The pickled character with its landmarks (the record given, else found on a render)."""
        from ...characters import apply_landmark_record, load_character

        path = Path(self.params["character"])
        data = path.read_bytes()
        key = hashlib.sha256(data).hexdigest()
        record = self.params.get("landmarks")
        cached = self.server.characters.get(key)
        if cached is not None and (record is None or cached[1] == json.dumps(record, sort_keys=True)):
            return cached[0], False
        ch = read_character_parts(data)
        found = False
        if record and apply_landmark_record(ch, record, "the scene's landmarks"):
            self.log(f"landmarks: {len(ch.landmarks)} from the scene ({ch.landmarks.source})")
        else:
            if record:
                self.log("landmarks: the scene's were made for another face mesh; searching again")
            self.progress(0.02, "landmarks")
            ch = load_character(ch, find=find, log=self.log)
            found = ch.landmarks is not None
        self.server.characters.clear()                   # one character at a time (they are large)
        self.server.characters[key] = (ch, json.dumps(record, sort_keys=True) if record else None)
        return ch, found

    def _channels(self, ch, drive) -> list:
        return [[c.name, [[ch.meshes[mi].ref, ch.meshes[mi].shape_names[k]] for mi, k in c.binds]]
                for c in drive.channels]

    def _save(self, **arrays) -> str:
        from ...files import atomic_path

        out = self.folder / "result.npz"
        with atomic_path(out) as tmp, open(tmp, "wb") as f:
            np.savez(f, **{k: v for k, v in arrays.items() if v is not None})
        return str(out)

    def _done(self, ch, found: bool, drive, W, times, head, audio, audio_rate, **extra) -> dict:
        from ...characters import landmark_record

        npz = self._save(weights=np.asarray(W, np.float64), times=np.asarray(times, np.float64),
                         head=None if head is None else np.asarray(head.quaternions, np.float64))
        wav = None
        if audio is not None and audio_rate:
            from ...io import write_audio

            wav = str(write_audio(self.folder / "sound.wav", audio, audio_rate))
        return {"result": npz, "channels": self._channels(ch, drive), "wav": wav,
                "drive": [int(i) for i in drive.choice.drive], "summary": drive.summary,
                "landmarks": landmark_record(ch) if found else None, "frames": int(len(times)), **extra}

    # ---- jobs
    def animate(self) -> dict:
        from .._animate import AnimateOptions, animate

        p = self.params
        ch, found = self.character()
        self.progress(0.1, "capture")

        def tick(done, total):
            if total:
                self.progress(0.1 + 0.75 * done / total, "capture")

        cap = cached_capture(p["video"], progress=tick, log=self.log)
        self.progress(0.85, "solve")
        emotion = {k: float(v) for k, v in (p.get("emotion") or {}).items() if float(v) > 0} or None
        res = animate(cap, ch, AnimateOptions(shapes=p.get("shapes", "auto"), head=p.get("head", "video"),
                                              head_amplitude=float(p.get("head_amplitude", 1.0)), emotion=emotion,
                                              style=p.get("style") if emotion else None), log=self.log)
        self.progress(1.0, "done")
        return self._done(ch, found, res.drive, res.drive.full_weights(res.weights), res.times, res.head, res.audio,
                          res.audio_rate, mouth_corr=None if np.isnan(res.mouth_corr) else res.mouth_corr,
                          emotions=res.emotions)

    def take(self) -> dict:
        from .._apply import apply_take

        p = self.params
        route = p.get("route", "auto")
        ch, found = self.character(find=True)
        self.progress(0.3, "solve")
        res = apply_take(p["take"], ch, route=route, source_rig=p.get("source_rig") or None,
                         source_keys=p.get("source_keys") or None, shapes=p.get("shapes", "auto"), log=self.log)
        self.progress(1.0, "done")
        return self._done(ch, found, res.drive, res.weights, res.times, res.head, res.audio, res.audio_rate,
                          route=res.route)

    def landmarks(self) -> dict:
        from ...characters import landmark_record, read_landmark_file

        p = self.params
        ch, found = self.character()
        if p.get("points") is not None:
            X = np.asarray(p["points"], dtype=np.float64).reshape(-1, 3)
            if X.shape != (68, 3) or not np.isfinite(X).all():
                raise InvalidDataError(f"landmarks: expected 68 points (x, y, z), got {X.shape[0]}")
            tmp = self.folder / "moved68.txt"
            tmp.write_text("\n".join(" ".join(f"{v:.9g}" for v in row) for row in X))
            lm = read_landmark_file(ch, tmp)
            lm.source = "moved in Blender"
            ch.landmarks = lm
            found = True
        rec = landmark_record(ch)
        return {"landmarks": rec, "positions": ch.landmark_positions(), "found": found,
                "mesh": ch.meshes[ch.landmarks.mesh].ref}

    def style_info(self) -> dict:
        from ...style import StyleModel

        model = StyleModel.load(self.params["style"])
        return {"styles": list(model.styles_)}

    def live(self) -> dict:
        from scipy.spatial.transform import Rotation

        from ...characters import drive_rig
        from ..live import LiveSession

        p = self.params
        ch, found = self.character()
        drive = drive_rig(ch, p.get("shapes", "auto"))
        src = p["source"]
        source = int(src) if isinstance(src, int) or str(src).isdigit() else src
        send = self.server.out.send
        send(id=self.id, live={"channels": self._channels(ch, drive), "drive": [int(i) for i in drive.choice.drive]})

        def on_frame(f) -> None:
            q = Rotation.from_quat(f.head)
            send(id=self.id, frame={"i": int(f.index), "t": round(float(f.t), 6), "cal": bool(f.calibrating),
                                    "w": np.round(f.weights, 6).tolist(), "q": np.round(q.as_quat(), 7).tolist()})

        session = LiveSession(source, drive.rig, serve=None, realtime=bool(p.get("realtime", True)),
                              max_frames=p.get("max_frames"), head_amplitude=float(p.get("head_amplitude", 1.0)),
                              record=False, on_frame=on_frame, log=self.log)
        watcher = threading.Thread(target=lambda: (self.stop.wait(), session.stop()), daemon=True)
        watcher.start()
        with session:
            stats = session.run()
        self.stop.set()
        from ...characters import landmark_record

        stages = {k: round(stats.stage_ms(k), 2) for k in ("decode", "track", "points", "solve", "head", "send")
                  if k in stats.stages and len(stats.stages[k])}
        return {"fps": stats.fps, "processed": stats.processed, "solved": stats.solved, "dropped": stats.dropped,
                "seconds": stats.seconds, "latency_p50": stats.latency_p50 if stats.latency.size else None,
                "stages_ms": stages,
                "landmarks": landmark_record(ch) if found else None}


def serve_jobs(stdin=None, stdout=None) -> None:
    """Run jobs read from ``stdin`` until it closes or a ``quit`` request (module docstring).

    The protocol goes to a private duplicate of the process's stdout; file descriptor 1 is then pointed
    at stderr, so whatever a library prints cannot break a line of it.  ``FACERETARGET_NICE=N`` lowers the
    worker's scheduling priority by ``N`` first (the host's UI thread gets a core before it).
    """
    nice = os.environ.get("FACERETARGET_NICE", "")
    if nice.strip().isdigit() and int(nice) > 0 and hasattr(os, "nice"):
        try:                                             # the host's UI thread gets a core first
            os.nice(int(nice))
        except OSError:
            pass
    if stdout is None:
        fd = os.dup(1)
        os.dup2(2, 1)
        sys.stdout = sys.stderr
        stdout = os.fdopen(fd, "w", encoding="utf-8", buffering=1)
    stdin = stdin or sys.stdin
    server = _Server(WorkerChannel(stdout))
    reader = threading.Thread(target=server.read, args=(stdin,), daemon=True)
    reader.start()
    server.out.send(id=0, ready={"pid": os.getpid(), "time": time.time()})
    server.run()
