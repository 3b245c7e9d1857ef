"""``faceretarget batch``: a library of takes onto many characters on Dask's distributed scheduler,
resumable and fault tolerant.

How a batch runs (docs/batch.md):

* The jobs file (:func:`~faceretarget.pipelines.read_jobs`) expands into one job per (input,
  character).  Every input, rig folder and option file is hashed (SHA-256) on the client.
* **Work once.**  Each rig is read by one Dask task.  Each distinct model (a character's cloner or
  retargeter, its rig for ``animate`` with the style model, a head-motion database) is keyed by the
  content hash of its rig files and fit options, and fitted once, as one Dask task from the rig
  tasks' futures; its future is handed to every job that uses it, so the model travels from worker
  to worker (never through the scheduler) and only to the workers that run its jobs.  Jobs carry
  paths and options only: workers read their inputs and write their outputs themselves (a shared
  file system on a cluster).
* **Resumable, idempotent.**  Every output is written atomically (a temporary name, renamed when
  complete).  The client appends one JSON line per finished job to the manifest (``batch.jsonl``:
  job, input hashes, options, character hash, output hash, seconds, status, error), flushed and
  fsynced line by line; reading it tolerates a torn last line.  A job is up to date, and skipped,
  when its last record succeeded with the same job key (inputs, options, character and model
  hashes, output path, package version) and its output still has the recorded hash; anything
  else runs.  So a changed rig or option re-runs exactly the jobs it affects, and re-running a
  finished batch does nothing.
* **Failures isolated.**  A job catches its own errors: a bad take fails that job with the
  one-line :class:`~faceretarget.errors.FaceRetargetError` message (in the manifest and the
  summary) and is not retried; the batch goes on.  A lost worker is not the job's fault: Dask
  re-runs the tasks it held on another worker (``distributed.scheduler.allowed-failures``, 3 by
  default), recomputing a lost model from its inputs; a task that killed that many workers fails its
  job (``KilledWorker``).
* One progress bar (jobs done / failed / running), the dashboard address when the dashboard can
  be served (bokeh installed), and a summary table per character (jobs, frames, seconds).
"""

from __future__ import annotations

import contextlib
import datetime as _dt
import fcntl
import glob as _glob
import hashlib
import json
import logging
import os
import time
import uuid
import warnings
import zipfile
from collections import Counter, deque
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ... import __version__
from ...errors import DataWarning, FaceRetargetError, InvalidDataError
from ...files import file_sha256
from ...formats import NPZ
from ...optional import VIDEO_NEEDS, has_module, optional_import, output_needs, require
from .._progress import ticking
from ._jobs import BatchSpec, Character, Job, read_jobs

__all__ = ["run_batch", "read_manifest", "local_cluster", "BatchSummary", "JobOutcome", "ClusterError",
           "MANIFEST_FIELDS", "WORKER_CONFIG", "file_sha256", "CONNECT_TIMEOUT"]

#: Seconds ``--scheduler`` waits for the scheduler to answer (Dask's default is 30 s of silence).
CONNECT_TIMEOUT = 5.0

#: The fields of one manifest line (``batch.jsonl``), in order.
MANIFEST_FIELDS = ("job", "status", "error", "operation", "character", "input", "output", "output_hash",
                   "inputs", "character_hash", "model", "options", "key", "frames", "seconds", "warnings",
                   "worker", "run", "finished", "version")


#: Dask settings of the workers :func:`local_cluster` starts (recommended for a cluster's workers too).
WORKER_CONFIG = {"distributed.nanny.pre-spawn-environ.MALLOC_TRIM_THRESHOLD_": None,
                 "distributed.worker.profile.enabled": False,
                 "distributed.admin.tick.interval": "500ms",
                 "distributed.admin.system-monitor.interval": "2s",
                 "distributed.worker.memory.monitor-interval": "1s"}


class ClusterError(FaceRetargetError):
    """The Dask cluster could not be reached (``--scheduler``), or no worker joined it."""


def _quiet(*_a) -> None:
    return None


def _one_line(text) -> str:
    return " ".join(str(text).split())


# ------------------------------------------------------------------------------------------ hashing
def _digest(obj) -> str:
    return hashlib.sha256(json.dumps(obj, sort_keys=True, separators=(",", ":")).encode()).hexdigest()


def _plain(v):
    """Options as JSON: paths as strings, tuples as lists."""
    if isinstance(v, Path):
        return str(v)
    if isinstance(v, tuple | list):
        return [_plain(x) for x in v]
    if isinstance(v, dict):
        return {k: _plain(x) for k, x in v.items()}
    return v


class _Hasher:
    """File hashes for one run (a file named by several jobs is read once)."""

    def __init__(self):
        self._files: dict[tuple, str] = {}
        self._chars: dict[str, str] = {}

    def file(self, path: Path) -> str:
        st = os.stat(path)                        # the file itself (a symlink's target), as it is now
        key = (st.st_dev, st.st_ino, st.st_size, st.st_mtime_ns)
        if key not in self._files:
            self._files[key] = file_sha256(path)
        return self._files[key]

    def options(self, opts: dict) -> tuple[dict, dict]:
        """``(options with files replaced by their hashes, {file: hash})``."""
        files: dict[str, str] = {}

        def walk(v):
            if isinstance(v, Path):
                files[str(v)] = self.file(v)
                return {"file": files[str(v)]}
            if isinstance(v, tuple | list):
                return [walk(x) for x in v]
            return v
        return {k: walk(v) for k, v in opts.items()}, files

    def character(self, c: Character) -> str:
        if c.name not in self._chars:
            parts: dict = {"neutral": c.neutral, "source_neutral": c.source_neutral,
                           "target_neutral": c.target_neutral}
            if c.demo is not None:
                parts["demo"] = _rig_digest(_load_rig(c))
            roots = [p for p in (c.rig, c.source_keys, c.target_keys) if p is not None]
            parts["files"] = [[_rel(f, roots), self.file(f)] for f in c.files()]
            self._chars[c.name] = _digest(parts)
        return self._chars[c.name]


def _rel(f: Path, roots: list[Path]) -> str:
    for i, r in enumerate(roots):
        if r.is_dir() and r in f.parents:
            return f"{i}:{f.relative_to(r)}"
    return f.name


def _rig_digest(rig) -> str:
    h = hashlib.sha256()
    for a in (rig.neutral.vertices, rig.deltas, rig.neutral.face_counts, rig.neutral.face_indices,
              np.asarray([] if rig.landmarks is None else rig.landmarks)):
        h.update(np.ascontiguousarray(a).tobytes())
    h.update("\n".join(rig.names).encode())
    return h.hexdigest()


# ------------------------------------------------------------------------------------------ manifest
def read_manifest(path: str | os.PathLike) -> list[dict]:
    """The records of a manifest (``batch.jsonl``), oldest first; ``[]`` when it does not exist.

    A line cut short (a batch killed while appending; the next batch starts a line of its own after
    it) is ignored; any other line that is not a job record is skipped with a
    :class:`~faceretarget.errors.DataWarning` naming the file and line.
    """
    path = Path(path)
    if not path.is_file():
        return []
    lines = path.read_bytes().split(b"\n")
    out = []
    for i, line in enumerate(lines, 1):
        if not line.strip():
            continue
        try:
            rec = json.loads(line)
            if not isinstance(rec, dict) or "job" not in rec:
                raise ValueError("not a job record")
        except (ValueError, UnicodeDecodeError):
            if line.rstrip().endswith(b"}"):           # not cut short by a kill: damaged
                warnings.warn(f"{path}, line {i}: not a manifest record; ignored", DataWarning, stacklevel=2)
            continue
        out.append(rec)
    return out


class _Manifest:
    """The manifest open for appending by one batch (an exclusive lock: one batch per manifest)."""

    def __init__(self, path: Path):
        path.parent.mkdir(parents=True, exist_ok=True)
        self.path = path
        self.f = open(path, "ab")
        try:
            fcntl.flock(self.f.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            self.f.close()
            raise ClusterError(f"{path}: another batch is writing this manifest; wait for it or give this "
                               "batch its own ('manifest' in the jobs file)") from None
        size = path.stat().st_size
        if size:
            with open(path, "rb") as r:
                r.seek(size - 1)
                if r.read(1) != b"\n":                 # a torn last line: start on a line of our own
                    self.f.write(b"\n")

    def append(self, rec: dict) -> None:
        self.f.write((json.dumps(rec, separators=(",", ":")) + "\n").encode())
        self.f.flush()
        os.fsync(self.f.fileno())

    def close(self) -> None:
        with contextlib.suppress(OSError):
            fcntl.flock(self.f.fileno(), fcntl.LOCK_UN)
        self.f.close()


# ------------------------------------------------------------------------------------------ planning
@dataclass(frozen=True)
class _Model:
    """What is fitted once and shared: a content hash and what the fit needs."""

    key: str
    operation: str
    character: Character
    source: Character | None
    fit: dict
    character_hash: str = ""
    source_hash: str | None = None

    @property
    def rigs(self) -> list[tuple[str, str, Character]]:
        """``(role, content hash, character)`` of the rigs the fit reads: the character's own (onto its
        rig, and for animate) and the source rig."""
        out = []
        if self.operation == "animate" or (self.operation in ("clone", "retarget") and not self.character.has_keys):
            out.append(("character", self.character_hash, self.character))
        if self.source is not None:
            out.append(("source", self.source_hash, self.source))
        return out


@dataclass
class _Planned:
    job: Job
    model: _Model
    key: str
    inputs: dict
    character_hash: str
    up_to_date: bool = False
    last: dict | None = None


def _plan(spec: BatchSpec, resume: bool) -> list[_Planned]:
    h = _Hasher()
    last: dict[str, dict] = {}
    if resume:
        for rec in read_manifest(spec.manifest):
            last[rec["job"]] = rec
    planned, out_hashes = [], {}
    for job in spec.jobs:
        if job.operation == "headmotion-synth":
            char_hash, src_hash = "", None
            char = Character(name=job.character)
            source = None
        else:
            char = spec.characters[job.character]
            source = spec.characters[job.source] if job.source else None
            char_hash = h.character(char)
            src_hash = h.character(source) if source is not None else None
        fit_opts, fit_files = h.options(job.fit)
        apply_opts, apply_files = h.options(job.apply)
        mkey = _digest({"operation": job.operation, "fit": fit_opts, "character": char_hash, "source": src_hash,
                        "version": __version__})
        model = _Model(mkey, job.operation, char, source, job.fit, char_hash, src_hash)
        inputs = {str(job.input): h.file(job.input), **fit_files, **apply_files}
        key = _digest({"model": mkey, "operation": job.operation, "apply": apply_opts, "input": inputs[str(job.input)],
                       "output": str(job.out), "version": __version__})
        p = _Planned(job, model, key, inputs, char_hash, last=last.get(job.id))
        rec = p.last
        if rec is not None and rec.get("status") == "ok" and rec.get("key") == key and job.out.is_file():
            if job.out not in out_hashes:
                out_hashes[job.out] = file_sha256(job.out)
            p.up_to_date = out_hashes[job.out] == rec.get("output_hash")
        planned.append(p)
    return planned


# ------------------------------------------------------------------------------------------ worker side
@dataclass(eq=False)
class _Fitted:
    """A fitted model as the jobs receive it (one Dask result, fetched once per worker)."""

    operation: str
    model: object = None
    source_rig: object = None
    source_keys: object = None
    target_keys: object = None
    keys: object = None
    character: object = None
    style: object = None
    drive: object = None
    seconds: float = 0.0
    error: str | None = None
    warnings: list = field(default_factory=list)


def _load_rig(c: Character):
    """A character's rig: a :class:`~faceretarget.rig.Rig` (OBJ folder, ``.npz``, demo), or for a character
    file (``.glb``, ``.vrm``, ``.fbx``, ``.blend``, ``.usd*``) the :class:`faceretarget.character.Character`
    with its landmarks (found once and cached beside the file or in the user's cache)."""
    from ...datasets import make_demo_character
    from ...io import is_character_file, read_rig, read_rig_npz

    if c.demo is not None:
        return make_demo_character(c.demo)
    if c.rig.is_dir():
        return read_rig(c.rig, neutral=c.neutral, landmarks=c.landmarks)
    if c.rig.suffix.lower() == NPZ:
        return read_rig_npz(c.rig)
    if is_character_file(c.rig):
        from ...characters import load_character

        return load_character(c.rig, landmarks=c.landmarks)
    raise InvalidDataError(f"{c.rig}: a character's rig is a folder of OBJs, a rig .npz or a character file "
                           "(.glb, .gltf, .vrm, .fbx, .blend, .usd*)")


def _target_rig(rig, f: _Fitted):
    """The rig the ARKit key sets are built on: a character file's face rig on its ARKit shapes (kept in
    ``f.drive`` so the output is written back into a copy of its file)."""
    from ...character import Character as FileCharacter

    if isinstance(rig, FileCharacter):
        from ...characters import drive_rig

        f.drive = drive_rig(rig, "arkit", need_landmarks=False)
        return f.drive.rig
    return rig


class _RigFailed:
    """A rig that could not be read (the one-line message), handed to the fits that needed it."""

    def __init__(self, message: str):
        self.message = message


def _read_rig(c: Character):
    """Dask task: read one character's rig once (OBJ folders are slow to parse); the fits that use it get
    its future.  A bad rig comes back as :class:`_RigFailed` (never raised, so never retried)."""
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")      # the fits see the rig's own warnings when they use it
            return _load_rig(c)
    except FaceRetargetError as e:
        return _RigFailed(f"{c.name}: {_one_line(e)}")


def _fit_clone(m: _Model, f: _Fitted, rigs: dict) -> None:
    from ...cloning import ExpressionCloner, keymodel_pair
    from ...io import read_performance, read_rig

    o, c = m.fit, m.character
    src = rigs.get("source")
    if c.has_keys:
        sk = read_rig(c.source_keys, neutral=c.source_neutral, landmarks=c.source_landmarks)
        tk = read_rig(c.target_keys, neutral=c.target_neutral, landmarks=c.target_landmarks)
    else:
        rom = read_performance(o["keys_from"]) if o["keys_from"] is not None else None
        sk, tk, _ = keymodel_pair(src, _target_rig(rigs["character"], f), o["keys"], rom=rom)
    features = str(o["features"]) if isinstance(o["features"], Path) else o["features"]
    f.model = ExpressionCloner(o["method"], features=features, weight_range=o["weight_range"]).fit(sk, tk)
    f.source_rig, f.keys = src, tk
    if src is None:
        f.source_keys = sk                   # clone_take: a weight take plays on the source keys


def _fit_retarget(m: _Model, f: _Fitted, rigs: dict) -> None:
    from ...cloning import keymodel_pair
    from ...io import is_keyshape_folder, read_keys
    from ...retarget import BlendshapeRetargeter, load_regions

    o, c = m.fit, m.character
    rig = rigs.get("source")
    if c.has_keys:
        sk, labels = read_keys(c.source_keys, neutral=c.source_neutral, landmarks=c.source_landmarks, rig=rig)
        tk, _ = read_keys(c.target_keys, neutral=c.target_neutral, landmarks=c.target_landmarks)
        if not is_keyshape_folder(c.source_keys) and not is_keyshape_folder(c.target_keys):
            rig = sk if rig is None else rig
            sk, tk, _ = keymodel_pair(sk, tk, "arkit")
    else:
        sk, tk, _ = keymodel_pair(rig, _target_rig(rigs["character"], f), "arkit")
        labels = []
    regions = load_regions(o["regions"]) if isinstance(o["regions"], Path) else o["regions"]
    rt = BlendshapeRetargeter(solver=o["solver"], weight_range=o["weight_range"], l1=o["l1"], l2=o["l2"],
                              denoise=o["denoise"], filter_level=o["smooth"], regions=regions, align=o["align"],
                              rigid_subset=None if o["rigid_subset"] is None else list(o["rigid_subset"]))
    rt.fit(sk, tk, source_labels=list(labels))
    if o["temporal"]:
        rt.set_params(smooth=o["temporal"] * rt.key_scale_ ** 2)
    f.model, f.source_rig, f.keys = rt, rig, tk


def _fit_animate(m: _Model, f: _Fitted, rigs: dict) -> None:
    from ...io import read_rig

    c = m.character
    f.character = rigs["character"]
    if c.has_keys:
        f.source_keys = read_rig(c.source_keys, neutral=c.source_neutral, landmarks=c.source_landmarks)
        f.target_keys = read_rig(c.target_keys, neutral=c.target_neutral, landmarks=c.target_landmarks)
    if m.fit["style"] is not None:
        from ...style import StyleModel

        f.style = StyleModel.load(m.fit["style"])


def _fit_headmotion(m: _Model, f: _Fitted, rigs: dict) -> None:
    from ...headmotion import HeadMotionDatabase

    o = m.fit
    if o["db"] is not None:
        f.model = HeadMotionDatabase.load(o["db"])
    else:
        from .._head import build_head_database

        f.model = build_head_database(o["build"], fps=o["build_fps"], f0_min=o["f0_min"], f0_max=o["f0_max"],
                                      pause=o["pause"], mirror=o["mirror"], allow_mismatch=o["allow_mismatch"])


_FITTERS = {"clone": _fit_clone, "retarget": _fit_retarget, "animate": _fit_animate,
            "headmotion-synth": _fit_headmotion}


def _collect(caught) -> list[str]:
    seen: dict[str, None] = {}
    for c in caught:
        seen.setdefault(_one_line(c.message), None)
    return list(seen)[:10]


def _fit_model(m: _Model, *rigs) -> _Fitted:
    """Dask task: fit one shared model from its rigs (``m.rigs`` order, each read once by
    :func:`_read_rig`).  A bad rig or option is returned as ``error`` (never raised, so never
    retried), and fails every job of the model with that message."""
    f = _Fitted(m.operation)
    t0 = time.perf_counter()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            bad = next((r for r in rigs if isinstance(r, _RigFailed)), None)
            if bad is not None:
                raise InvalidDataError(bad.message)
            _FITTERS[m.operation](m, f, {role: r for (role, _, _), r in zip(m.rigs, rigs, strict=True)})
        except FaceRetargetError as e:
            f.error = _one_line(e)
        except Exception as e:                   # noqa: BLE001  (a bug: reported on the jobs, not retried)
            f.error = f"{type(e).__name__}: {_one_line(e)}"
    f.warnings = _collect(caught)
    f.seconds = time.perf_counter() - t0
    return f


def _transfer(job: Job, f: _Fitted) -> int:
    from ...io import read_performance
    from .._clone_retarget import Transfer, _apply, write_result

    take = read_performance(job.input)
    t0 = time.perf_counter()
    rig = f.source_rig if f.source_rig is not None else (f.source_keys if take.kind == "weights" else None)
    res = _apply(f.model, take, rig, _quiet)
    tr = Transfer(f.model, res, time.perf_counter() - t0, f.keys)
    job.out.parent.mkdir(parents=True, exist_ok=True)
    write_result(job.out, tr, head=job.apply["head"], bake=job.apply["bake"], character=f.drive)
    return take.n_frames


def _is_capture(path: Path) -> bool:
    try:
        with zipfile.ZipFile(path) as z:
            return "landmarks.npy" in z.namelist()
    except (OSError, zipfile.BadZipFile):
        return False


def _animate(job: Job, f: _Fitted) -> int:
    from ...io import read_performance
    from .._animate import VIDEO_EXTENSIONS, AnimateOptions, animate

    src = job.input
    if src.suffix.lower() in VIDEO_EXTENSIONS:
        video = src
    elif src.suffix.lower() == NPZ and _is_capture(src):
        from ...capture import Capture

        video = Capture.read_npz(src)
    else:
        video = read_performance(src)
    o = job.apply
    job.out.parent.mkdir(parents=True, exist_ok=True)
    res = animate(video, f.character, AnimateOptions(
        out=job.out, head=o["head"], head_db=o["head_db"], head_amplitude=o["head_amplitude"],
        head_range=o["head_range"], emotion=o["emotion"],
        style=f.style, source_keys=f.source_keys, target_keys=f.target_keys, max_frames=o["max_frames"],
        bake=o["bake"]))
    return len(res.times)


def _headmotion(job: Job, f: _Fitted) -> int:
    from ...io import read_audio, write_head_motion

    o = job.apply
    audio, rate = read_audio(job.input)
    try:
        res = f.model.transform(audio, rate, amplitude=o["amplitude"], rotation=o["rotation"],
                                translation=o["translation"], seed=o["seed"], fps=o["fps"], source=str(job.input),
                                motion_range=o["motion_range"])
    except InvalidDataError as e:
        raise InvalidDataError(f"{job.input}: {e}") from e
    job.out.parent.mkdir(parents=True, exist_ok=True)
    write_head_motion(job.out, res.take, protect=(job.input,))
    return res.take.n_frames


_RUNNERS = {"clone": _transfer, "retarget": _transfer, "animate": _animate, "headmotion-synth": _headmotion}


def _worker_name() -> str:
    with contextlib.suppress(Exception):
        from distributed import get_worker

        return get_worker().address
    return f"pid {os.getpid()}"


def _run_job(job: Job, fitted: _Fitted) -> dict:
    """Dask task: one job, its output written atomically and hashed.  Never raises: a bad input
    comes back as ``status: failed`` with its one-line message (so Dask never retries it)."""
    t0 = time.perf_counter()
    out = {"status": "ok", "error": None, "frames": None, "output_hash": None}
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            if fitted.error is not None:
                raise _ModelFailed(fitted.error)
            out["frames"] = int(_RUNNERS[job.operation](job, fitted))
            out["output_hash"] = file_sha256(job.out)
        except _ModelFailed as e:
            out.update(status="failed", error=f"{job.character} ({job.operation} model): {e}")
        except FaceRetargetError as e:
            out.update(status="failed", error=_one_line(e))
        except Exception as e:                   # noqa: BLE001  (a bug: one line in the manifest, not retried)
            out.update(status="failed", error=f"{type(e).__name__}: {_one_line(e)} ({job.input})")
    out["warnings"] = list(dict.fromkeys(fitted.warnings + _collect(caught)))[:10]
    out["seconds"] = round(time.perf_counter() - t0, 6)
    out["worker"] = _worker_name()
    return out


def _run_jobs(jobs: list[Job], fitted: _Fitted) -> list[dict]:
    """Dask task: several jobs of one model in a row (:func:`_run_job` each), so a short job does not
    pay a scheduler round trip of its own (:data:`CHUNK_JOBS`)."""
    return [_run_job(job, fitted) for job in jobs]


#: At most this many jobs of one model go to a worker as one task (``n`` of them when the batch holds
#: at least ``32 n`` jobs per worker thread): a 75 ms job paid about 6 ms of scheduling on its own.
#: Small enough that the last tasks still spread over the workers.
CHUNK_JOBS = 4


class _ModelFailed(Exception):
    pass


# ------------------------------------------------------------------------------------------ the client
@dataclass
class JobOutcome:
    """What became of one job in this run: ``status`` is ``"ok"``, ``"failed"``, ``"skipped"`` (up to
    date: shown as "up to date") or ``"not run"`` (the batch stopped first); ``warnings``: the job's
    warnings (and its model's), one line each, as the manifest records them."""

    job: Job
    status: str
    error: str | None = None
    frames: int | None = None
    seconds: float = 0.0
    output_hash: str | None = None
    warnings: list = field(default_factory=list)


@dataclass
class BatchSummary:
    """The result of :func:`run_batch`.

    Attributes
    ----------
    outcomes : list of JobOutcome
        One per job of the jobs file, in its order.
    seconds : float
        Wall-clock time of the run (planning, fits and jobs).
    manifest : Path
    models : int
        Models fitted in this run.
    dashboard : str or None
        The Dask dashboard's address when it could be served.
    dry_run : bool
    stopped : str or None
        Why the batch stopped before every job ran (the cluster was lost), else None.
    """

    outcomes: list[JobOutcome]
    seconds: float
    manifest: Path
    models: int = 0
    dashboard: str | None = None
    dry_run: bool = False
    stopped: str | None = None
    run: str = ""

    def count(self, status: str) -> int:
        return sum(o.status == status for o in self.outcomes)

    @property
    def ran(self) -> int:
        """Jobs that ran in this run (succeeded or failed)."""
        return self.count("ok") + self.count("failed")

    @property
    def failed(self) -> list[JobOutcome]:
        return [o for o in self.outcomes if o.status == "failed"]

    @property
    def exit_code(self) -> int:
        """0 when every job succeeded or was up to date (or a dry run), else 1."""
        return 0 if self.dry_run or all(o.status in ("ok", "skipped") for o in self.outcomes) else 1

    def warning_lines(self) -> list[str]:
        """Each distinct warning of the jobs run, once, with how many jobs gave it (``"warning: ... (6 jobs)"``)."""
        counts: Counter = Counter(w for o in self.outcomes for w in dict.fromkeys(o.warnings))
        return [f"warning: {w} ({n} job{'s' if n > 1 else ''})" for w, n in counts.items()]

    def table(self) -> str:
        """Per character: jobs, run, up to date, failed, frames and seconds of the jobs run."""
        rows: dict[str, list] = {}
        for o in self.outcomes:
            r = rows.setdefault(o.job.character, [0, 0, 0, 0, 0, 0.0])
            r[0] += 1
            r[1] += o.status in ("ok", "failed")
            r[2] += o.status == "skipped"
            r[3] += o.status == "failed"
            r[4] += (o.frames or 0) if o.status == "ok" else 0
            r[5] += o.seconds
        tot = [sum(r[i] for r in rows.values()) for i in range(6)]
        w = max([9] + [len(k) for k in rows])
        head = (f"{'character':<{w}} {'jobs':>6} {'run':>6} {'up to date':>10} {'failed':>7} {'frames':>9} "
                f"{'seconds':>9}")
        lines = [head, "-" * len(head)]
        for k, r in list(rows.items()) + [("total", tot)]:
            lines.append(f"{k:<{w}} {r[0]:>6} {r[1]:>6} {r[2]:>10} {r[3]:>7} {r[4]:>9} {r[5]:>9.1f}")
        return "\n".join(lines)


def _cpu_count() -> int:
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:                       # pragma: no cover (not Linux)
        return max(1, os.cpu_count() or 1)


def local_cluster(workers: int | None = None):
    """The LocalCluster ``faceretarget batch`` starts: ``workers`` processes (default one per core) of one
    thread each, BLAS single-threaded (Dask's default for its workers), its dashboard on a free port when
    bokeh is installed.

    Unlike Dask's defaults (:data:`WORKER_CONFIG`): the workers do not get ``MALLOC_TRIM_THRESHOLD_``,
    which fixes glibc's mmap threshold so that every large NumPy temporary becomes an ``mmap`` and
    page faults (the direct loop of ``bench/batch.py`` ran 29 % slower with it); and the workers'
    statistical profiler (100 samples/s, for the dashboard's profile page) is off and their event
    loop wakes less often, so the thread running a job keeps the GIL.  The caller closes it.
    """
    import dask

    distributed = optional_import("distributed", "batch processing (faceretarget batch)")
    with dask.config.set(WORKER_CONFIG):
        return distributed.LocalCluster(n_workers=workers or _cpu_count(), threads_per_worker=1, processes=True,
                                        dashboard_address=":0" if has_module("bokeh") else None,
                                        silence_logs=logging.CRITICAL)


@contextlib.contextmanager
def _cluster(scheduler: str | None, workers: int | None, client, log) -> Iterator:
    """A Dask client: the one given, one connected to ``scheduler``, or a LocalCluster of ``workers``
    processes (default one per core) with one thread each."""
    if client is not None:
        yield client
        return
    distributed = optional_import("distributed", "batch processing (faceretarget batch)")
    if scheduler is not None:
        log(f"connecting to the Dask scheduler at {scheduler} (up to {CONNECT_TIMEOUT:g} s)")
        try:
            c = distributed.Client(scheduler, timeout=CONNECT_TIMEOUT)     # Dask's default waits 30 s
        except (OSError, TimeoutError, ValueError) as e:
            raise ClusterError(f"--scheduler {scheduler}: cannot connect within {CONNECT_TIMEOUT:g} s "
                               f"({_one_line(e)}); is a scheduler running there (dask scheduler)?") from None
        try:
            try:
                c.wait_for_workers(1, timeout=60)
            except (TimeoutError, OSError):
                raise ClusterError(f"--scheduler {scheduler}: no worker joined within 60 s "
                                   "(start some: dask worker " + scheduler + ")") from None
            yield c
        finally:
            c.close()
        return
    log(f"starting a local Dask cluster: {workers or _cpu_count()} worker process(es)")
    cluster = local_cluster(workers)
    try:
        c = distributed.Client(cluster)
        try:
            c.register_plugin(_quiet_workers(distributed))
            yield c
        finally:
            c.close()
    finally:
        cluster.close()


def _quiet_workers(distributed):
    """A worker plugin for our own LocalCluster: its workers ignore Ctrl-C (it reaches the whole
    process group), so only the client reacts (it closes the cluster) and no worker prints a traceback."""

    class QuietWorker(distributed.WorkerPlugin):
        name = "faceretarget-quiet-sigint"

        def setup(self, worker):
            import signal
            import threading

            if threading.current_thread() is threading.main_thread():
                signal.signal(signal.SIGINT, signal.SIG_IGN)

    return QuietWorker()


def _dashboard(client, local: bool) -> str | None:
    with contextlib.suppress(Exception):
        if "dashboard" not in client.scheduler_info().get("services", {}):
            return None
        if local and not has_module("bokeh"):
            return None
        return client.dashboard_link
    return None


def _remove_parts(jobs) -> None:
    """Temporary files an interrupted write of these outputs left behind (a worker killed mid-write)."""
    for job in jobs:
        for p in _glob.glob(str(job.out.parent / f".{_glob.escape(job.out.name)}.*.part")):
            with contextlib.suppress(OSError):
                os.unlink(p)


def _record(p: _Planned, res: dict, run: str) -> dict:
    j = p.job
    rec = {"job": j.id, "status": res["status"], "error": res["error"], "operation": j.operation,
           "character": j.character, "input": str(j.input), "output": str(j.out),
           "output_hash": res.get("output_hash"), "inputs": p.inputs, "character_hash": p.character_hash,
           "model": p.model.key, "options": _plain(j.options), "key": p.key, "frames": res.get("frames"),
           "seconds": res.get("seconds", 0.0), "warnings": res.get("warnings", []), "worker": res.get("worker"),
           "run": run, "finished": _dt.datetime.now(_dt.UTC).isoformat(timespec="milliseconds"),
           "version": __version__}
    return {k: rec[k] for k in MANIFEST_FIELDS}


def run_batch(jobs: str | os.PathLike | BatchSpec, *, scheduler: str | None = None, workers: int | None = None,
              client=None, resume: bool = True, dry_run: bool = False, progress: bool = False,
              window: int | None = None, log: Callable[..., None] = _quiet) -> BatchSummary:
    """Run a jobs file on Dask: every (input, character) job, each model fitted once, resumable.

    Parameters
    ----------
    jobs : path-like or BatchSpec
        The TOML jobs file (:func:`read_jobs`, docs/batch.md) or a spec already read.
    scheduler : str, optional
        ``tcp://HOST:PORT`` of a running Dask scheduler (workers must see the same paths).
    workers : int, optional
        Worker processes of the LocalCluster started otherwise (default one per core, one
        thread each).
    client : distributed.Client, optional
        Use this client (its cluster) instead of starting or connecting one.
    resume : bool
        Skip the jobs the manifest shows up to date (default).  False re-runs every job.
    dry_run : bool
        Plan only: log what would run, start nothing, write nothing.
    progress : bool
        One progress bar (done / failed / running).
    window : int, optional
        Jobs in flight at once (default 4 per worker thread + 4): bounds the scheduler's load and
        the work a killed batch loses.
    log : callable
        Receives the plan, the dashboard address and the summary table.

    Returns
    -------
    BatchSummary
        ``exit_code`` 0 when every job succeeded or was up to date.

    Raises
    ------
    InvalidDataError, InputFileError
        A bad jobs file (naming the file and the key); nothing runs.
    ClusterError
        ``scheduler`` unreachable, no worker, or the manifest locked by another batch.
    MissingDependencyError
        Dask's ``distributed`` is not installed (``make batch``; :func:`faceretarget.optional.install_line`).
    """
    t_start = time.perf_counter()
    spec = jobs if isinstance(jobs, BatchSpec) else read_jobs(jobs)
    _require_packages(spec, cluster=not dry_run and client is None)
    run = uuid.uuid4().hex[:12]
    planned = _plan(spec, resume)
    todo = [p for p in planned if not p.up_to_date]
    models = {p.model.key for p in todo}
    log(f"{spec.path}: {len(planned)} jobs ({len(planned) - len(todo)} up to date, {len(todo)} to run, "
        f"{len(models)} models to fit); manifest {spec.manifest}")
    outcomes = {p.job.id: JobOutcome(p.job, "skipped" if p.up_to_date else "not run", frames=None) for p in planned}
    if dry_run:
        by: Counter = Counter((p.job.group, p.job.character) for p in todo)
        for (g, c), n in by.items():
            log(f"  would run {n} {g} job(s) onto {c}")
        return BatchSummary(list(outcomes.values()), time.perf_counter() - t_start, spec.manifest,
                            models=len(models), dry_run=True, run=run)
    summary = BatchSummary([], 0.0, spec.manifest, models=len(models), run=run)
    if not todo:
        summary.outcomes = list(outcomes.values())
        summary.seconds = time.perf_counter() - t_start
        log("nothing to do: every job is up to date")
        return summary
    distributed = optional_import("distributed", "batch processing (faceretarget batch)")
    manifest = _Manifest(spec.manifest)
    try:
        _remove_parts(p.job for p in todo)
        with _cluster(scheduler, workers, client, log) as cl:
            summary.dashboard = _dashboard(cl, local=scheduler is None and client is None)
            log(f"dashboard: {summary.dashboard}" if summary.dashboard else
                "dashboard: not available (the scheduler serves it when bokeh>=3.1 is installed)")
            summary.stopped = _execute(distributed, cl, todo, outcomes, manifest, run, progress, window, log)
        _remove_parts(p.job for p in todo)
    finally:
        manifest.close()
    summary.outcomes = list(outcomes.values())
    summary.seconds = time.perf_counter() - t_start
    return summary


def _require_packages(spec: BatchSpec, *, cluster: bool) -> None:
    """Raise before anything runs when the batch needs an optional package that is not installed: Dask's
    ``distributed`` (``cluster``), and what the jobs' outputs and video inputs need (``.blend`` /
    ``.fbx``: bpy but for an ``.fbx`` character's own copy, ``.usd*``: usd-core, videos: MediaPipe, PyAV and
    the FaceLandmarker model)."""
    from .._animate import VIDEO_EXTENSIONS

    if cluster:
        require("faceretarget batch (Dask's distributed scheduler)", "distributed")
    seen = set()
    for job in spec.jobs:
        char = spec.characters.get(job.character) if job.operation == "animate" else None
        for name in output_needs(job.out, char.rig if char is not None else None):
            if name not in seen:
                seen.add(name)
                require(f"{spec.path}: job {job.id} (output {job.out.name})", name)
        if job.operation == "animate" and job.input.suffix.lower() in VIDEO_EXTENSIONS and "video" not in seen:
            seen.add("video")
            require(f"{spec.path}: job {job.id} (video {job.input.name}, face tracking)", *VIDEO_NEEDS)


def _execute(distributed, client, todo: list[_Planned], outcomes: dict, manifest: _Manifest, run: str,
             progress: bool, window: int | None, log) -> str | None:
    """Submit the fits and the jobs (a window at a time), record each job as it finishes."""
    from tqdm.auto import tqdm

    todo = sorted(todo, key=lambda p: p.model.key)     # a model's jobs together: they share its worker
    queue = deque(todo)
    left = Counter(p.model.key for p in todo)
    fits: dict[str, object] = {}
    rig_futs: dict[str, object] = {}
    rig_left = Counter(h for mk, m in {p.model.key: p.model for p in todo}.items() for _, h, _ in m.rigs)
    active: dict = {}
    ac = distributed.as_completed()
    threads, t_threads = max(1, sum(client.nthreads().values())), time.monotonic()

    def size() -> int:
        return window or 4 * threads + 4

    chunk = max(1, min(CHUNK_JOBS, len(todo) // (8 * CHUNK_JOBS * threads)))

    def submit(p: _Planned) -> None:
        mk = p.model.key
        group = [p]
        while chunk > 1 and len(group) < chunk and queue and queue[0].model.key == mk:
            group.append(queue.popleft())
        if mk not in fits:
            deps = []
            for _, h, c in p.model.rigs:
                if h not in rig_futs:
                    rig_futs[h] = client.submit(_read_rig, c, key=f"rig-{h[:32]}", pure=False)
                deps.append(rig_futs[h])
                rig_left[h] -= 1
                if not rig_left[h]:
                    rig_futs.pop(h)                 # every fit that reads it holds it now
            fits[mk] = client.submit(_fit_model, p.model, *deps, key=f"fit-{mk[:32]}", pure=False)
        if len(group) == 1:
            fut = client.submit(_run_job, p.job, fits[mk], key=f"job-{p.key[:24]}-{run}", pure=False)
        else:
            fut = client.submit(_run_jobs, [g.job for g in group], fits[mk], key=f"jobs-{p.key[:24]}-{run}",
                                pure=False)
        active[fut] = group
        ac.add(fut)

    done = failed = 0
    stopped = None
    with tqdm(total=len(todo), desc="batch", unit="job", disable=not progress, leave=True) as bar, \
            ticking(bar, progress):
        bar.set_postfix_str("starting the workers, reading the rigs, fitting the models", refresh=False)
        while queue and len(active) < size():
            submit(queue.popleft())
        for fut in ac:
            group = active.pop(fut)
            try:
                got = fut.result()
                results = got if isinstance(got, list) else [got]
            except distributed.KilledWorker as e:
                results = [{"status": "failed", "seconds": 0.0,
                            "error": f"the workers running this job died repeatedly ({_one_line(e)})"}] * len(group)
            except (OSError, distributed.client.CancelledError, distributed.comm.CommClosedError) as e:
                stopped = f"the cluster was lost ({type(e).__name__}: {_one_line(e)})"
                break
            for p, res in zip(group, results, strict=True):
                done, failed = _finish(p, res, run, manifest, outcomes, bar, progress, log, left, fits, done, failed)
            if time.monotonic() - t_threads > 2.0:
                with contextlib.suppress(Exception):
                    threads, t_threads = max(1, sum(client.nthreads().values())), time.monotonic()
            while queue and len(active) < size():
                submit(queue.popleft())
            bar.set_postfix_str(f"done {done}, failed {failed}, running {min(len(active), threads)}", refresh=False)
    if stopped:
        log(f"batch stopped: {stopped}; {done + failed} job(s) recorded in {manifest.path}; run it again to "
            "resume")
        for f in list(active):
            f.cancel()
    return stopped


def _finish(p: _Planned, res: dict, run: str, manifest: _Manifest, outcomes: dict, bar, progress: bool, log,
            left: Counter, fits: dict, done: int, failed: int) -> tuple[int, int]:
    """Record one finished job (manifest, outcome, the failure line, the bar); ``(done, failed)``."""
    rec = _record(p, res, run)
    manifest.append(rec)
    outcomes[p.job.id] = JobOutcome(p.job, rec["status"], rec["error"], rec["frames"], rec["seconds"] or 0.0,
                                    rec["output_hash"], list(rec["warnings"] or []))
    if rec["status"] == "ok":
        done += 1
    else:
        failed += 1
        line = f"failed: {p.job.id}: {rec['error']}"
        if progress:
            bar.write(line)
        else:
            log(line)
    left[p.model.key] -= 1
    if not left[p.model.key]:
        fits.pop(p.model.key, None)             # its last job is done: release the model
    bar.update(1)
    return done, failed
