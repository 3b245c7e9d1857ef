"""Long work without freezing Blender: a worker process and jobs stepped by a timer on the main thread.

* The library's heavy work (capture, landmark search, solves, live tracking) runs in one worker process
  (:func:`faceretarget.pipelines.serve_jobs`, started with Blender's own Python and ``sys.path``);
  its answers arrive as JSON lines read by a thread into a queue.
* Whatever must touch Blender's data (reading the selected character, keying the action, posing the
  live character) runs on the main thread in small steps: each :class:`Job` is a generator, and the
  timer :func:`_tick` runs the jobs' steps for at most :data:`BUDGET` seconds, then gives the main
  thread back to Blender.
* Progress goes to Blender's progress indicator (``window_manager.progress_*``) and the panel's bar;
  the panel's *Cancel* button (``faceretarget.cancel``) stops a job and kills the worker.

Blender run in the background (``blender -b``, or the ``bpy`` module) has no event loop to call timers:
:func:`drive` plays its part (tests, scripts).
"""

from __future__ import annotations

import contextlib
import importlib
import itertools
import json
import os
import queue
import shutil
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Generator
from pathlib import Path

import bpy

#: Seconds of main-thread work a timer tick may take before it returns.
BUDGET = 0.015
#: Seconds between two ticks while a job runs.
INTERVAL = 0.01

_jobs: list[Job] = []
_import: dict = {"thread": None, "error": None, "done": False}
_worker: Worker | None = None
_ids = itertools.count(1)
#: Called with each tick's duration: wall-clock and main-thread CPU seconds, and what it ran (the
#: longest step's job label and place, or ``finish`` for a job's undo step and reports) (measurements).
tick_hooks: list[Callable[[float, float, str], None]] = []
#: What a job's step yields when it only waits (for the worker): the tick ends at once.
IDLE = "idle"


# ------------------------------------------------------------------------------------------- library
def start_import() -> None:
    """Import the library in a thread (a second or two of imports that must not freeze the UI)."""
    if _import["thread"] is not None:
        return

    def run():
        try:
            for mod in ("faceretarget.io", "faceretarget.character", "faceretarget.headpose"):
                importlib.import_module(mod)
        except BaseException as e:  # noqa: BLE001 - reported when a job needs the library
            _import["error"] = e
        _import["done"] = True

    t = threading.Thread(target=run, name="faceretarget-import", daemon=True)
    _import["thread"] = t
    t.start()


def wait_library() -> Generator[None, None, None]:
    """Steps until the library is imported (a missing wheel is an error naming it)."""
    start_import()
    while not _import["done"]:
        yield IDLE
    if not _import.get("frozen"):
        import gc

        gc.freeze()              # the library's objects out of the collector's passes (no 100 ms pauses)
        _import["frozen"] = True
    if _import["error"] is not None:
        e = _import["error"]
        raise JobError(f"the faceretarget library cannot be imported ({type(e).__name__}: {e}); reinstall the "
                       "extension (docs/blender-extension.md)")


# ------------------------------------------------------------------------------------------- errors
class JobError(Exception):
    """A job's failure, one line for the user (the worker's message names the file or shape)."""


# ------------------------------------------------------------------------------------------- worker
def _log_path() -> Path:
    return Path(tempfile.gettempdir()) / f"faceretarget-worker-{os.getpid()}.log"


class Worker:
    """The worker process: ``python -S -c "serve_jobs()"`` with this process's ``sys.path``."""

    def __init__(self, *, background: bool = True):
        env = dict(os.environ)
        env["PYTHONPATH"] = os.pathsep.join(p for p in sys.path if p and os.path.isdir(p))
        env["PYTHONNOUSERSITE"] = "1"
        env["FACERETARGET_NICE"] = "10" if background else "0"   # applied by the worker itself (no fork hook)
        env.setdefault("PYTHONUNBUFFERED", "1")
        for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
            env.setdefault(var, "1")                       # one core for the work, the others for Blender
        self.log_path = _log_path()
        self._log = open(self.log_path, "ab")  # noqa: SIM115 - the worker's stderr for its lifetime
        self.proc = subprocess.Popen(
            [sys.executable, "-S", "-c", "from faceretarget.pipelines import serve_jobs; serve_jobs()"],
            stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=self._log, env=env, text=True, bufsize=1,
            start_new_session=True)
        self.inbox: dict[int, queue.Queue] = {}
        self.ready = threading.Event()
        self.reader = threading.Thread(target=self._read, name="faceretarget-worker-reader", daemon=True)
        self.reader.start()

    def _read(self) -> None:
        for line in self.proc.stdout:
            try:
                msg = json.loads(line)
            except ValueError:
                continue
            jid = int(msg.get("id", 0))
            if jid == 0:
                self.ready.set()
                continue
            box = self.inbox.get(jid)
            if box is not None:
                box.put(msg)
        for box in list(self.inbox.values()):
            box.put({"error": "the faceretarget worker process ended", "type": "WorkerExit"})

    @property
    def alive(self) -> bool:
        return self.proc.poll() is None

    def submit(self, kind: str, folder: Path, params: dict) -> tuple[int, queue.Queue]:
        jid = next(_ids)
        box: queue.Queue = queue.Queue()
        self.inbox[jid] = box
        self._send({"id": jid, "kind": kind, "dir": str(folder), "params": params})
        return jid, box

    def stop_job(self, jid: int) -> None:
        self._send({"stop": jid})

    def _send(self, msg: dict) -> None:
        try:
            self.proc.stdin.write(json.dumps(msg) + "\n")
            self.proc.stdin.flush()
        except (BrokenPipeError, OSError, ValueError) as e:
            raise JobError(f"the faceretarget worker process is gone (see {self.log_path})") from e

    def close(self, timeout: float = 2.0) -> None:
        """Ask the worker to quit; kill it when it does not within ``timeout`` seconds."""
        with contextlib.suppress(Exception):
            self._send({"quit": True})
            self.proc.stdin.close()
        try:
            self.proc.wait(timeout)
        except subprocess.TimeoutExpired:
            self.kill()
        self.reader.join(1.0)
        self._log.close()

    def quit_steps(self, timeout: float = 3.0) -> Generator[str, None, None]:
        """Steps while the worker quits (killed after ``timeout`` seconds): the main thread never waits on it."""
        with contextlib.suppress(Exception):
            self._send({"quit": True})
            self.proc.stdin.close()
        end = time.perf_counter() + timeout
        while self.proc.poll() is None and time.perf_counter() < end:
            yield IDLE
        if self.proc.poll() is None:
            self.kill()
        with contextlib.suppress(Exception):
            self._log.close()

    def kill(self) -> None:
        with contextlib.suppress(ProcessLookupError, OSError):
            self.proc.kill()
        with contextlib.suppress(Exception):
            self.proc.wait(5.0)
        with contextlib.suppress(Exception):
            self._log.close()


def worker() -> Worker:
    """The running worker (started on first use, restarted after a cancel killed it)."""
    global _worker
    if _worker is None or not _worker.alive:
        _worker = Worker()
    return _worker


def stop_worker() -> None:
    global _worker
    if _worker is not None:
        _worker.close()
        _worker = None


def kill_worker() -> None:
    global _worker
    if _worker is not None:
        _worker.kill()
        _worker = None


def worker_pid() -> int | None:
    """The worker's process id while it runs (tests check nothing is left)."""
    return _worker.proc.pid if _worker is not None and _worker.alive else None


def run_in_worker(job: Job, kind: str, params: dict, lo: float, hi: float,
                  on_message: Callable[[dict], None] | None = None) -> Generator[None, None, dict]:
    """Steps while the worker runs a job; its ``done`` result (progress mapped onto ``lo .. hi``)."""
    w = worker()
    jid, box = w.submit(kind, job.folder, params)
    job.worker_job = jid
    try:
        while True:
            try:
                msg = box.get_nowait()
            except queue.Empty:
                if not w.alive and box.empty():
                    raise JobError(f"the faceretarget worker process ended (see {w.log_path})") from None
                yield IDLE
                continue
            if "progress" in msg:
                job.set_progress(lo + (hi - lo) * float(msg["progress"]), msg.get("stage", ""))
            elif "log" in msg:
                job.lines.append(msg["log"])
            elif "warning" in msg:
                job.warnings.append(msg["warning"])
            elif "error" in msg:
                raise JobError(msg["error"])
            elif "done" in msg:
                return msg["done"]
            elif on_message is not None:
                on_message(msg)
    finally:
        job.worker_job = None
        w.inbox.pop(jid, None)


# ------------------------------------------------------------------------------------------- jobs
class Job:
    """A job: a generator of main-thread steps (``body(job)``), its progress, and its outcome."""

    def __init__(self, label: str, body: Callable[[Job], Generator], *, undo: str | None = None):
        self.label = label
        self.undo = undo
        self.folder = Path(tempfile.mkdtemp(prefix="faceretarget-job-"))
        self.progress = 0.0
        self.stage = "starting"
        self.lines: list[str] = []
        self.warnings: list[str] = []
        self.status = "running"
        self.message = ""
        self.result = None
        self.worker_job: int | None = None
        self.started = time.perf_counter()
        self.on_cancel: list[Callable[[], None]] = []
        self.slowest: tuple[float, float, str] = (0.0, 0.0, "")     # the longest step: CPU s, wall s, where
        self.last_step: tuple[float, str] = (0.0, "")                 # the longest step of the last tick
        self._steps = body(self)

    def set_progress(self, fraction: float, stage: str = "") -> None:
        self.progress = max(0.0, min(1.0, float(fraction)))
        if stage:
            self.stage = stage
        _show_progress()

    def step(self, until: float) -> None:
        """Run steps until ``until`` (perf_counter) or the end."""
        self.last_step = (0.0, "")
        if self.status == "finishing":                  # the undo step and the reports, a tick of their own
            c = time.thread_time()
            self._finish("done", "")
            self.last_step = (time.thread_time() - c, f"{self.label}: finish (undo step, reports)")
            return
        try:
            while time.perf_counter() < until:
                a, c = time.perf_counter(), time.thread_time()
                where = _where(self._steps)
                idle = next(self._steps) is IDLE
                cpu = time.thread_time() - c
                if cpu > self.last_step[0]:
                    self.last_step = (cpu, f"{self.label}: {where}")
                if cpu > self.slowest[0]:
                    self.slowest = (cpu, time.perf_counter() - a, where)
                if idle:
                    break
        except StopIteration as stop:
            self.result = stop.value
            self.status = "finishing"
        except JobError as e:
            self._finish("error", str(e))
        except (ReferenceError, RuntimeError) as e:          # the scene changed under the job, an operator failed
            self._finish("error", f"{self.label}: {' '.join(str(e).split())[:300]}")
        except Exception as e:  # noqa: BLE001 - one line in the UI, the traceback on the console
            import traceback

            traceback.print_exc()
            self._finish("error", f"{self.label}: {type(e).__name__}: {' '.join(str(e).split())[:300]}")

    def cancel(self) -> None:
        if self.status not in ("running", "finishing"):
            return
        for fn in self.on_cancel:
            with contextlib.suppress(Exception):
                fn()
        if self.worker_job is not None:
            kill_worker()                                  # the only way to stop a capture mid-frame
        with contextlib.suppress(Exception):
            self._steps.close()
        self._finish("cancelled", f"{self.label}: cancelled")

    def _finish(self, status: str, message: str) -> None:
        self.status = status
        self.message = message
        shutil.rmtree(self.folder, ignore_errors=True)
        if status == "done" and self.undo:
            t0 = time.perf_counter()
            with contextlib.suppress(Exception):
                bpy.ops.ed.undo_push(message=self.undo)
            self.undo_seconds = time.perf_counter() - t0
        for w in dict.fromkeys(self.warnings):
            report("WARNING", w)
        if status == "error":
            report("ERROR", message)
        elif status == "cancelled":
            report("INFO", message)
        elif status == "done" and isinstance(self.result, str) and self.result:
            report("INFO", self.result)


def _where(gen) -> str:
    """Where a (nested) step generator stands: its innermost function and line."""
    where = ""
    while gen is not None:
        f = getattr(gen, "gi_frame", None)
        if f is not None:
            where = f"{f.f_code.co_name}:{f.f_lineno}"
        gen = getattr(gen, "gi_yieldfrom", None)
    return where


#: The last job submitted (its outcome, for scripts and tests).
last_job: Job | None = None


def submit(job: Job) -> Job:
    """Start a job (its steps run from the next tick)."""
    global last_job
    last_job = job
    _jobs.append(job)
    _show_progress()
    if not bpy.app.timers.is_registered(_tick):
        bpy.app.timers.register(_tick, first_interval=0.0)
    return job


def running(kind: str | None = None) -> list[Job]:
    return [j for j in _jobs if j.status == "running" and (kind is None or j.label.startswith(kind))]


def _tick() -> float | None:
    t0 = time.perf_counter()
    c0 = time.thread_time()
    until = t0 + BUDGET
    what = (0.0, "")
    for job in list(_jobs):
        if job.status in ("running", "finishing"):
            job.step(until)
            what = max(what, job.last_step)
        if job.status not in ("running", "finishing"):
            _jobs.remove(job)
    _show_progress()
    wall, cpu = time.perf_counter() - t0, time.thread_time() - c0
    for hook in tick_hooks:
        hook(wall, cpu, what[1])
    return INTERVAL if _jobs else None


def drive(until: Callable[[], bool] | None = None, *, timeout: float = 600.0, interval: float = INTERVAL) -> bool:
    """Play the event loop's part where Blender has none (background mode): call the timer until no job
    runs (or ``until()`` is true); False on ``timeout``."""
    end = time.perf_counter() + timeout
    while time.perf_counter() < end:
        if until is not None and until():
            return True
        if not _jobs:
            if bpy.app.timers.is_registered(_tick):
                bpy.app.timers.unregister(_tick)
            return until is None or until()
        nxt = _tick()
        if nxt is None and bpy.app.timers.is_registered(_tick):
            bpy.app.timers.unregister(_tick)
        time.sleep(interval)
    return False


def cancel_all() -> None:
    for job in list(_jobs):
        job.cancel()
    _jobs.clear()


def shutdown() -> None:
    """Everything the extension started, stopped: jobs, the worker, the timer, the import thread's result."""
    cancel_all()
    stop_worker()
    if bpy.app.timers.is_registered(_tick):
        bpy.app.timers.unregister(_tick)
    _show_progress(end=True)


# ------------------------------------------------------------------------------------------- UI state
_progress_on = {"on": False}


def _state():
    wm = bpy.context.window_manager
    return getattr(wm, "faceretarget_state", None) if wm is not None else None


def _show_progress(end: bool = False) -> None:
    """The panel's bar and Blender's progress indicator follow the running job."""
    st = _state()
    job = next((j for j in _jobs if j.status == "running"), None)
    wm = bpy.context.window_manager
    if st is not None:
        st.running = job is not None and not end
        st.job = job.label if job is not None else ""
        st.progress = job.progress if job is not None else 0.0
        st.stage = job.stage if job is not None else ""
    with contextlib.suppress(Exception):
        if job is not None and not end:
            if not _progress_on["on"]:
                wm.progress_begin(0, 1000)
                _progress_on["on"] = True
            wm.progress_update(int(job.progress * 1000))
        elif _progress_on["on"]:
            wm.progress_end()
            _progress_on["on"] = False
    _redraw()


def _redraw() -> None:
    wm = bpy.context.window_manager
    if wm is None:
        return
    for window in wm.windows:
        for area in window.screen.areas:
            if area.type == "VIEW_3D":
                area.tag_redraw()


def report(kind: str, message: str) -> None:
    """A one-line Blender report: the panel's status line, the console and (with a window) a popup."""
    text = " ".join(str(message).split())
    st = _state()
    if st is not None:
        st.report = text
        st.report_kind = kind
    print(f"faceretarget: {kind.lower()}: {text}")
    wm = bpy.context.window_manager
    if kind in ("ERROR", "WARNING") and wm is not None and wm.windows and not bpy.app.background:
        with contextlib.suppress(Exception):
            wm.popup_menu(lambda self, _ctx: self.layout.label(text=text), title="faceretarget",
                          icon="ERROR" if kind == "ERROR" else "INFO")
