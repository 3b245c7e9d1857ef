"""``faceretarget batch`` on Dask (issue 17): throughput with 1 and 2 workers, overhead against the
library called directly in a loop, and two fault injections.

The library (``--jobs``, default 200 jobs) is made from the shared data in a temporary folder:

* the four shared Live Link Face takes, replicated under different names by symlinks, cloned
  (``combined84`` key-models generated on both rigs) onto ``ict-face`` and the demo character
  ``bo``, and retargeted (the two rigs' own ARKit shapes) onto ``arkit-face`` and the demo
  character ``ada``, the takes playing on ``arkit-face``;
* captured landmarks: the two shared talking-head videos captured once (MediaPipe, the ``capture``
  extra) into capture ``.npz`` files (478 landmarks, scores, head pose), replicated likewise and
  animated (``animate``: the character's own shapes from the 68 face points, tracked head) onto
  all four characters.  Without MediaPipe the library is Live Link Face takes only (said on stdout).

Measured in one run, every worker a process with one thread, BLAS single-threaded everywhere
(``OMP_NUM_THREADS=1`` etc., as Dask's nanny sets for its workers):

1. ``direct``: the same jobs through the public library in one loop, each rig read and each model
   fitted once (what a careful script does): ``ExpressionCloner`` / ``BlendshapeRetargeter``
   ``fit``, ``source_geometry`` + ``transform`` + ``write_result`` per take, ``animate`` per
   capture.  It runs in a fresh process whose clock starts after ``import faceretarget.pipelines``,
   as a Dask worker's does (``bench/batch.py --direct JOBS.toml``).
2. ``run_batch`` on a LocalCluster of 1 worker, then of 2 (cluster started and its workers' imports
   done before the clock starts; the clock covers planning and hashing, the fits, the jobs, the
   manifest): ``jobs_per_s_1``, ``jobs_per_s_2``, ``scaling`` = their ratio (target >= 1.7 on two
   free cores), ``overhead_pct`` = 1-worker time over the direct loop's, minus 1 (target <= 10 %).
   Each is the fastest of ``--repeat`` runs (2), which removes some of other processes' load.
   The 2-worker run is the clean reference: every later run's outputs are compared to its hashes.
3. ``worker_kill``: 2 workers; one worker process is SIGKILLed (by its PID) when about a third of
   the jobs are recorded.  ``complete``: every job succeeded exactly once in this run's manifest
   records, every output present with the recorded hash, no temporary file left; ``outputs_equal``:
   byte-equal to the clean run.
4. ``resume``: ``faceretarget batch JOBS --workers 2`` as a separate process group, SIGKILLed
   (client, scheduler, nannies, workers) when about half the jobs are recorded; then the same
   command again (resuming is the default).  ``missing_jobs``: jobs without a successful record
   after the kill; ``rerun_jobs``: records the second run appended; ``outputs_equal``: all outputs
   byte-equal to the clean run.

The machine's load (``os.getloadavg``) is printed before and after: on a shared 2-core machine the
2-worker numbers are depressed while others run; re-run on a quiet machine.

Usage::

    python bench/batch.py [--json] [--jobs 200] [--repeat 2] [--data ../shared/data] [--keep DIR]

With ``--json`` the last line of stdout is ``{"jobs", "jobs_per_s_1", "jobs_per_s_2", "scaling",
"overhead_pct", "worker_kill": {"complete", "outputs_equal"}, "resume": {"rerun_jobs",
"missing_jobs", "outputs_equal"}}``.
"""

from __future__ import annotations

import os

for _v in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS"):
    os.environ[_v] = "1"                          # before NumPy: the direct loop like a Dask worker

import argparse  # noqa: E402
import hashlib  # noqa: E402
import json  # noqa: E402
import shutil  # noqa: E402
import signal  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import threading  # noqa: E402
import time  # noqa: E402
import warnings  # noqa: E402
from pathlib import Path  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
DATA = Path(os.environ.get("FACERETARGET_DATA", REPO.parent / "shared" / "data"))
EXE = Path(sys.executable).with_name("faceretarget")
LLF = ("MySlate_3_Jason_Millers_iPhone.csv", "S07-001.csv", "apfel.csv", "alex_rom_3.csv")
VIDEOS = ("WDA_AOC_000.mp4", "WDA_KatieHill_000.mp4")


def load() -> str:
    a, b, c = os.getloadavg()
    return f"load average {a:.2f} {b:.2f} {c:.2f} on {os.cpu_count()} cores"


def _sha(p: Path) -> str:
    return hashlib.sha256(p.read_bytes()).hexdigest()


def make_library(root: Path, data: Path, n_jobs: int, log) -> Path:
    """Replicated takes and captures under ``root`` and the jobs file; returns its path."""
    captures = []
    try:
        from faceretarget.pipelines import capture_take

        cdir = root / "captures"
        cdir.mkdir()
        for v in VIDEOS:
            t0 = time.perf_counter()
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                cap = capture_take(data / "video" / v, neutral_percentile=5.0)
            captures.append(cap.write_npz(cdir / f"{Path(v).stem}.npz"))
            log(f"captured {v}: {len(cap.times)} frames in {time.perf_counter() - t0:.1f} s")
    except Exception as e:      # noqa: BLE001  (MediaPipe / PyAV missing: Live Link Face takes only)
        log(f"no captured landmarks ({type(e).__name__}: {e}); the library is Live Link Face takes only")
        captures = []
    # 4 jobs per Live Link Face replica (clone x 2, retarget x 2), 4 per capture replica (animate x 4)
    n_cap = (n_jobs // 4) * 2 // 5 if captures else 0
    n_llf = n_jobs // 4 - n_cap
    (root / "llf").mkdir()
    (root / "lm").mkdir()
    for i in range(n_llf):
        src = data / "livelinkface" / LLF[i % len(LLF)]
        (root / "llf" / f"take{i:03d}_{src.stem}.csv").symlink_to(src)
    for i in range(n_cap):
        src = captures[i % len(captures)]
        (root / "lm" / f"take{i:03d}_{src.stem}.npz").symlink_to(src)
    text = f"""
out = "out/{{character}}/{{job}}/{{take}}.glb"

[characters.arkit]
rig = "{data / 'arkit-face'}"
[characters.ict]
rig = "{data / 'ict-face'}"
[characters.ada]
demo = "ada"
[characters.bo]
demo = "bo"

[[jobs]]
name = "clone"
operation = "clone"
takes = "llf/*.csv"
characters = ["ict", "bo"]
source = "arkit"
[jobs.options]
keys = "combined84"

[[jobs]]
name = "retarget"
operation = "retarget"
takes = "llf/*.csv"
characters = ["arkit", "ada"]
source = "arkit"
"""
    if n_cap:
        text += """
[[jobs]]
name = "animate"
operation = "animate"
takes = "lm/*.npz"
characters = "*"
"""
    path = root / "jobs.toml"
    path.write_text(text)
    return path


def direct_loop(spec) -> float:
    """The jobs through the public library in one loop, each rig read and each model fitted once."""
    from faceretarget.capture import Capture
    from faceretarget.cloning import ExpressionCloner, keymodel_pair
    from faceretarget.datasets import make_demo_character
    from faceretarget.io import read_performance, read_rig
    from faceretarget.pipelines import Transfer, animate, source_geometry, write_result
    from faceretarget.retarget import BlendshapeRetargeter

    t0 = time.perf_counter()
    rigs: dict = {}
    models: dict = {}

    def rig(name):
        if name not in rigs:
            c = spec.characters[name]
            rigs[name] = make_demo_character(c.demo) if c.demo else read_rig(c.rig)
        return rigs[name]

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for job in spec.jobs:
            job.out.parent.mkdir(parents=True, exist_ok=True)
            if job.operation == "animate":
                animate(Capture.read_npz(job.input), rig(job.character), out=job.out)
                continue
            key = (job.operation, job.character)
            if key not in models:
                src = rig(job.source)
                if job.operation == "clone":
                    sk, tk, _ = keymodel_pair(src, rig(job.character), "combined84")
                    m = ExpressionCloner("temporal").fit(sk, tk)
                else:
                    sk, tk, _ = keymodel_pair(src, rig(job.character), "arkit")
                    m = BlendshapeRetargeter().fit(sk, tk)
                models[key] = (m, src, tk)
            m, src, tk = models[key]
            take = read_performance(job.input)
            res = m.transform(source_geometry(take, src, m.feature_idx_, model_vertices=len(m.source_neutral_)),
                              take.times)
            res.carry(take)
            write_result(job.out, Transfer(m, res, 0.0, tk))
    return time.perf_counter() - t0


def _outputs(spec) -> dict:
    return {str(j.out): _sha(j.out) if j.out.is_file() else None for j in spec.jobs}


def _parts(root: Path) -> list[Path]:
    return list((root / "out").rglob("*.part")) if (root / "out").exists() else []


def _fresh(root: Path) -> None:
    shutil.rmtree(root / "out", ignore_errors=True)
    (root / "batch.jsonl").unlink(missing_ok=True)


def _cluster(n: int):
    import distributed

    from faceretarget.pipelines import local_cluster

    cluster = local_cluster(n)                                      # what `faceretarget batch` starts
    client = distributed.Client(cluster)
    client.run(lambda: __import__("faceretarget.pipelines"))       # workers' imports before the clock
    return cluster, client


def _s(times) -> str:
    return ", ".join(f"{t:.2f}" for t in times) + " s"


def timed_batch(spec, n_workers: int, root: Path) -> tuple[float, object]:
    from faceretarget.pipelines import run_batch

    _fresh(root)
    cluster, client = _cluster(n_workers)
    try:
        t0 = time.perf_counter()
        s = run_batch(spec, client=client)
        dt = time.perf_counter() - t0
    finally:
        client.close()
        cluster.close()
    if s.exit_code != 0:
        raise SystemExit(f"batch with {n_workers} worker(s) failed: {[(o.job.id, o.error) for o in s.failed][:3]}")
    return dt, s


def worker_kill(spec, root: Path, clean: dict, log) -> dict:
    from faceretarget.pipelines import read_manifest, run_batch

    _fresh(root)
    cluster, client = _cluster(2)
    result: dict = {}
    killed: list = []

    def watch():
        manifest = root / "batch.jsonl"
        while "summary" not in result:
            n = len(manifest.read_bytes().splitlines()) if manifest.exists() else 0
            if n >= len(spec.jobs) // 3:
                pid = sorted(client.run(os.getpid).values())[0]
                os.kill(pid, signal.SIGKILL)
                killed.append((pid, n))
                return
            time.sleep(0.02)

    w = threading.Thread(target=watch, daemon=True)
    try:
        w.start()
        result["summary"] = s = run_batch(spec, client=client)
        w.join(timeout=5)
    finally:
        client.close()
        cluster.close()
    log(f"worker kill: SIGKILL worker pid {killed[0][0] if killed else '-'} after {killed[0][1] if killed else '-'} "
        f"jobs recorded; batch exit code {s.exit_code}")
    recs = [r for r in read_manifest(root / "batch.jsonl") if r["run"] == s.run]
    ids = [r["job"] for r in recs]
    outs = _outputs(spec)
    complete = (bool(killed) and s.exit_code == 0 and len(ids) == len(set(ids)) == len(spec.jobs)
                and all(r["status"] == "ok" and outs[r["output"]] == r["output_hash"] for r in recs)
                and not _parts(root))
    return {"complete": bool(complete), "outputs_equal": outs == clean}


def kill_and_resume(spec, root: Path, clean: dict, log) -> dict:
    from faceretarget.pipelines import read_manifest

    _fresh(root)
    cmd = [str(EXE), "-q", "batch", str(spec.path), "--workers", "2"]
    p = subprocess.Popen(cmd, start_new_session=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    manifest = root / "batch.jsonl"
    half = len(spec.jobs) // 2
    deadline = time.monotonic() + 600
    while time.monotonic() < deadline and p.poll() is None:
        if manifest.exists() and len(manifest.read_bytes().splitlines()) >= half:
            break
        time.sleep(0.02)
    os.killpg(p.pid, signal.SIGKILL)
    p.wait()
    time.sleep(1.0)
    before = read_manifest(manifest)
    done = {r["job"] for r in before if r["status"] == "ok"}
    missing = len(spec.jobs) - len(done)
    log(f"kill all: SIGKILL the batch's process group with {len(before)} jobs recorded; {missing} missing")
    rc = subprocess.run(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL).returncode
    after = read_manifest(manifest)
    runs = {r["run"] for r in after[len(before):]}
    rerun = len(after) - len(before)
    outs = _outputs(spec)
    log(f"resume: exit code {rc}, {rerun} jobs run in {len(runs)} run(s); temporary files left: {len(_parts(root))}")
    return {"rerun_jobs": rerun, "missing_jobs": missing, "outputs_equal": outs == clean and rc == 0}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--json", action="store_true")
    ap.add_argument("--jobs", type=int, default=200)
    ap.add_argument("--repeat", type=int, default=2, help="timed runs of each configuration; the fastest counts")
    ap.add_argument("--data", type=Path, default=DATA)
    ap.add_argument("--keep", type=Path, help="work in this folder and keep it (default a temporary one)")
    ap.add_argument("--direct", type=Path, help=argparse.SUPPRESS)     # the direct loop of this jobs file
    args = ap.parse_args()
    if args.direct:
        import faceretarget.pipelines  # noqa: F401  (imported before the clock, as on a Dask worker)
        from faceretarget.pipelines import read_jobs

        print(json.dumps({"direct_s": direct_loop(read_jobs(args.direct))}))
        return

    def log(*a):
        print(*a, flush=True)

    import distributed  # noqa: F401  (the batch extra)

    from faceretarget.pipelines import read_jobs

    log(f"start: {load()}")
    root = Path(tempfile.mkdtemp(prefix="fr-batch-")) if args.keep is None else args.keep
    root.mkdir(parents=True, exist_ok=True)
    try:
        spec = read_jobs(make_library(root, args.data, args.jobs, log))
        n = len(spec.jobs)
        log(f"{n} jobs: " + ", ".join(f"{g.name} {sum(j.group == g.name for j in spec.jobs)}" for g in spec.groups))

        times = []
        for _ in range(args.repeat):
            _fresh(root)
            r = subprocess.run([sys.executable, __file__, "--direct", str(spec.path)], capture_output=True, text=True)
            if r.returncode:
                raise SystemExit(f"direct loop failed: {r.stderr.strip().splitlines()[-1:]}")
            times.append(json.loads(r.stdout.strip().splitlines()[-1])["direct_s"])
        t_direct = min(times)
        direct = _outputs(spec)
        _fresh(root)
        log(f"direct loop: {t_direct:.2f} s ({1000 * t_direct / n:.1f} ms per job; runs {_s(times)})")
        from faceretarget.pipelines import run_batch

        t0 = time.perf_counter()
        run_batch(spec, dry_run=True)
        log(f"planning (hashing every input and rig, reading the manifest): {time.perf_counter() - t0:.2f} s")
        runs1 = [timed_batch(spec, 1, root) for _ in range(args.repeat)]
        t1, s1 = min(runs1, key=lambda r: r[0])
        out1 = _outputs(spec)
        log(f"batch, 1 worker: {t1:.2f} s ({1000 * t1 / n:.1f} ms per job; {s1.models} models fitted; "
            f"{sum(o.seconds for o in s1.outcomes) / n * 1000:.1f} ms per job on the worker; runs "
            f"{_s([r[0] for r in runs1])})")
        runs2 = [timed_batch(spec, 2, root) for _ in range(args.repeat)]
        t2, s2 = min(runs2, key=lambda r: r[0])
        clean = _outputs(spec)
        log(f"batch, 2 workers: {t2:.2f} s ({1000 * t2 / n:.1f} ms per job; runs {_s([r[0] for r in runs2])}); "
            f"outputs equal to 1 worker: {out1 == clean}, to the direct loop: {direct == clean}")
        log(f"after the timed runs: {load()}")
        kill = worker_kill(spec, root, clean, log)
        resume = kill_and_resume(spec, root, clean, log)
        log(f"end: {load()}")
        res = {"jobs": n, "jobs_per_s_1": round(n / t1, 2), "jobs_per_s_2": round(n / t2, 2),
               "scaling": round(t1 / t2, 3), "overhead_pct": round(100 * (t1 / t_direct - 1), 1),
               "worker_kill": kill, "resume": resume}
        log(f"jobs/s: 1 worker {res['jobs_per_s_1']}, 2 workers {res['jobs_per_s_2']}, scaling {res['scaling']} "
            f"(target >= 1.7); overhead {res['overhead_pct']} % (target <= 10)")
    finally:
        if args.keep is None:
            shutil.rmtree(root, ignore_errors=True)
    if args.json:
        print(json.dumps(res))


if __name__ == "__main__":
    main()
