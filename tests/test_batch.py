"""``faceretarget batch`` (issue 17): the jobs file, outputs equal to the library's, failures isolated,
resume, and a separate ``dask scheduler`` + ``dask worker``.

Real takes (the shared Live Link Face take cut to 240 frames), the real ARKit rig and the procedural
demo characters; each Dask test uses one worker thread.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import socket
import subprocess
import sys
import time
import warnings
from pathlib import Path

import numpy as np
import pytest

from faceretarget.errors import FaceRetargetError, InputFileError, InvalidDataError

FRAMES = 240


def _sha(p: Path) -> str:
    return hashlib.sha256(Path(p).read_bytes()).hexdigest()


def _distributed():
    return pytest.importorskip("distributed", reason="faceretarget batch needs the 'batch' extra "
                               "(dask[distributed]): make batch")


@pytest.fixture(scope="module")
def takes(data_dir, tmp_path_factory):
    """Two short real Live Link Face takes (240 frames of S07-001 and of apfel) in a temporary folder."""
    from faceretarget.io import read_performance, write_livelinkface

    d = tmp_path_factory.mktemp("takes")
    for name, start in (("S07-001", 300), ("apfel", 600)):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")                 # apfel's lost-face rows, dropped
            perf = read_performance(data_dir / "livelinkface" / f"{name}.csv").slice(start, start + FRAMES)
        write_livelinkface(d / f"{name}_short.csv", perf)
    return d


def _jobs_text(data_dir: Path, takes: Path, *, smooth: float = 0.0, extra: str = "") -> str:
    return f"""
out = "out/{{character}}/{{job}}/{{take}}.glb"

[characters.arkit]
rig = "{data_dir / 'arkit-face'}"
[characters.bo]
demo = "bo"

[[jobs]]
name = "cl"
operation = "clone"
takes = ["{takes}/*.csv"]
characters = ["bo"]
source = "arkit"
[jobs.options]
keys = "combined84"

[[jobs]]
name = "rt"
operation = "retarget"
takes = "{takes}/*.csv"
characters = "*"
source = "arkit"
[jobs.options]
smooth = {smooth}
{extra}
"""


@pytest.fixture(scope="module")
def client():
    """A one-worker, one-thread LocalCluster in this process (``processes=False``)."""
    distributed = _distributed()
    import logging

    with distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=False, dashboard_address=None,
                                  silence_logs=logging.ERROR) as cluster, distributed.Client(cluster) as c:
        yield c


def _direct(data_dir: Path, take: Path, op: str, character: str, out: Path, smooth: float = 0.0) -> Path:
    """The same job through the library's own functions (clone_take / retarget_take + write_result)."""
    from faceretarget.cloning import keymodel_pair
    from faceretarget.datasets import make_demo_character
    from faceretarget.io import read_performance, read_rig
    from faceretarget.pipelines import clone_take, retarget_take, write_result

    arkit = read_rig(data_dir / "arkit-face")
    target = arkit if character == "arkit" else make_demo_character(character)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")                  # the manifest records them; shown elsewhere
        perf = read_performance(take)
        if op == "clone":
            sk, tk, _ = keymodel_pair(arkit, target, "combined84")
            job = clone_take(perf, sk, tk, source_rig=arkit)
        else:
            sk, tk, _ = keymodel_pair(arkit, target, "arkit")
            job = retarget_take(perf, sk, tk, source_rig=arkit, filter_level=smooth)
        out.parent.mkdir(parents=True, exist_ok=True)
        return write_result(out, job)


# ---------------------------------------------------------------------------------------- jobs file
def test_read_jobs_expands_globs_characters_and_templates(data_dir, takes, tmp_path):
    from faceretarget.pipelines import read_jobs

    path = tmp_path / "jobs.toml"
    path.write_text(_jobs_text(data_dir, takes))
    spec = read_jobs(path)
    assert spec.manifest == tmp_path / "batch.jsonl"
    assert [g.name for g in spec.groups] == ["cl", "rt"]
    # clone: 2 takes x bo; retarget: 2 takes x (arkit, bo) ("*" = every character, in file order)
    assert len(spec.jobs) == 6
    ids = [j.id for j in spec.jobs]
    assert len(set(ids)) == 6 and ids[0].startswith("cl:bo:")
    assert {j.out for j in spec.jobs} == {tmp_path / "out" / c / g / f"{t}.glb" for g, c in
                                           [("cl", "bo"), ("rt", "arkit"), ("rt", "bo")]
                                           for t in ("S07-001_short", "apfel_short")}
    rt = [j for j in spec.jobs if j.group == "rt"][0]
    assert rt.fit["solver"] == "signed" and rt.fit["smooth"] == 0.0 and rt.apply == {"head": "auto", "bake": False}
    # exclude drops files by name; headmotion-synth needs no character
    path.write_text(_jobs_text(data_dir, takes).replace('takes = ["', 'exclude = ["apfel*"]\ntakes = ["'))
    assert sum(j.group == "cl" for j in read_jobs(path).jobs) == 1


BAD = [
    # (name, edit of the good file, text the one-line error must hold besides the file name)
    ("toml", lambda s: s + "\n[[jobs]\n", "not a valid TOML jobs file"),
    ("top-key", lambda s: "outt = 'x'\n" + s, "unknown key 'outt'"),
    ("operation", lambda s: s.replace('"clone"', '"cloen"'), "jobs #1 ('cl'), key 'operation'"),
    ("glob", lambda s: s.replace('/*.csv"]', '/*.cvs"]'), "key 'takes': '"),
    ("character", lambda s: s.replace('characters = ["bo"]', 'characters = ["boo"]'),
     "key 'characters': no character 'boo'"),
    ("option", lambda s: s.replace('keys = "combined84"', 'kyes = "combined84"'), "key 'options.kyes'"),
    ("option-value", lambda s: s.replace('keys = "combined84"', 'method = "fast"'), "key 'options.method'"),
    ("range", lambda s: s.replace("smooth = 0.0", "temporal = 5000"), "key 'options.temporal'"),
    ("nnls-only", lambda s: s.replace("smooth = 0.0", "l1 = 0.1"), "applies to solver = \"nnls\" only"),
    ("placeholder", lambda s: s.replace("{take}.glb", "{actor}.glb"), "unknown placeholder {actor}"),
    ("format", lambda s: s.replace("{take}.glb", "{take}.xyz"), "key 'out'"),
    ("collision", lambda s: s.replace("/{job}/", "/"), "is written by two jobs"),
    ("source", lambda s: s.replace('source = "arkit"\n[jobs.options]\nkeys', '[jobs.options]\nkeys'),
     "key 'source'"),
    ("rig", lambda s: s.replace("arkit-face", "no-such-rig"), "characters.arkit, key 'rig': not found"),
    ("demo", lambda s: s.replace('demo = "bo"', 'demo = "bob"'), "characters.bo, key 'demo'"),
]


@pytest.mark.parametrize("name,edit,expect", BAD, ids=[b[0] for b in BAD])
def test_read_jobs_errors_name_the_file_and_key(data_dir, takes, tmp_path, name, edit, expect):
    from faceretarget.pipelines import read_jobs

    path = tmp_path / "jobs.toml"
    path.write_text(edit(_jobs_text(data_dir, takes)))
    with pytest.raises((InvalidDataError, InputFileError)) as e:
        read_jobs(path)
    msg = str(e.value)
    assert msg.startswith(str(path)) and expect in msg and "\n" not in msg, msg


# ---------------------------------------------------------------------------------------- running
def test_small_batch_equals_the_library_and_fits_each_model_once(data_dir, takes, tmp_path, client, monkeypatch):
    from faceretarget.pipelines import read_manifest, run_batch
    from faceretarget.pipelines.batch import _run

    fits, reads = [], []
    for op in ("clone", "retarget"):
        fn = _run._FITTERS[op]
        monkeypatch.setitem(_run._FITTERS, op, lambda m, f, r, fn=fn: (fits.append(m.character.name), fn(m, f, r))[1])
    load = _run._load_rig
    monkeypatch.setattr(_run, "_load_rig", lambda c: (reads.append(c.name), load(c))[1])
    path = tmp_path / "jobs.toml"
    path.write_text(_jobs_text(data_dir, takes))
    s = run_batch(path, client=client)
    assert s.exit_code == 0 and s.count("ok") == 6 and s.models == 3
    assert sorted(fits) == ["arkit", "bo", "bo"]              # one fit per model, not per take
    # each rig read once by a worker (and the demo character built once more on the client, for its hash)
    assert reads.count("arkit") == 1 and reads.count("bo") == 2
    recs = read_manifest(tmp_path / "batch.jsonl")
    assert len(recs) == 6 and all(r["status"] == "ok" for r in recs)
    for r in recs:
        out = Path(r["output"])
        assert _sha(out) == r["output_hash"] and r["frames"] == FRAMES
        assert r["inputs"][r["input"]] == _sha(Path(r["input"]))
        ref = _direct(data_dir, Path(r["input"]), r["operation"], r["character"], tmp_path / "ref" / out.name)
        assert out.read_bytes() == ref.read_bytes(), r["job"]     # byte for byte the library's output
    assert not list((tmp_path / "out").rglob("*.part"))
    assert "bo" in s.table() and "total" in s.table() and "up to date" in s.table()
    # the jobs' warnings (in the manifest) are in the summary too: each once, with its count of jobs
    recorded = [w for r in recs for w in r["warnings"]]
    lines = s.warning_lines()
    assert recorded and len(lines) == len(set(recorded))
    for w in set(recorded):
        n = sum(w in r["warnings"] for r in recs)
        assert f"warning: {w} ({n} job{'s' if n > 1 else ''})" in lines


def test_resume_skips_done_jobs_and_reruns_exactly_what_changed(data_dir, takes, tmp_path, client):
    import shutil

    from faceretarget.io import read_performance, write_livelinkface
    from faceretarget.pipelines import read_manifest, run_batch

    tk = tmp_path / "takes"
    shutil.copytree(takes, tk)
    path = tmp_path / "jobs.toml"
    path.write_text(_jobs_text(data_dir, tk))
    manifest = tmp_path / "batch.jsonl"
    assert run_batch(path, client=client).ran == 6
    first = {r["job"]: r for r in read_manifest(manifest)}

    s = run_batch(path, client=client)                       # a finished batch: nothing runs
    assert s.ran == 0 and s.count("skipped") == 6 and s.exit_code == 0
    assert len(read_manifest(manifest)) == 6

    path.write_text(_jobs_text(data_dir, tk, smooth=1.0))    # an option of one job group: its 4 jobs
    s = run_batch(path, client=client)
    assert {o.job.id for o in s.outcomes if o.status == "ok"} == {j for j in first if j.startswith("rt:")}
    assert s.count("skipped") == 2

    (tmp_path / "out" / "bo" / "cl" / "apfel_short.glb").unlink()           # a deleted output
    with open(manifest, "ab") as f:                                      # and a torn last line
        f.write(b'{"job": "cl:bo:takes/apfel_sh')
    s = run_batch(path, client=client)
    assert [o.job.id for o in s.outcomes if o.status == "ok"] == ["cl:bo:takes/apfel_short.csv"]
    lines = manifest.read_bytes().split(b"\n")
    assert json.loads(lines[-2])["job"] == "cl:bo:takes/apfel_short.csv"  # appended on a line of its own

    perf = read_performance(tk / "S07-001_short.csv")              # a changed take: its 3 jobs
    write_livelinkface(tk / "S07-001_short.csv", perf.with_weights(np.clip(perf.weights * 0.9, 0, 1), perf.names))
    s = run_batch(path, client=client)
    assert sorted(o.job.id for o in s.outcomes if o.status == "ok") == [
        "cl:bo:takes/S07-001_short.csv", "rt:arkit:takes/S07-001_short.csv", "rt:bo:takes/S07-001_short.csv"]
    assert run_batch(path, client=client).ran == 0
    assert run_batch(path, client=client, resume=False).ran == 6          # --no-resume: everything again


def test_bad_take_fails_only_its_job_and_the_exit_code(data_dir, takes, tmp_path, capsys):
    _distributed()
    import shutil

    from faceretarget.cli import main
    from faceretarget.pipelines import read_manifest

    tk = tmp_path / "takes"
    shutil.copytree(takes, tk)
    bad = tk / "broken.csv"
    bad.write_text("Timecode,BlendshapeCount,EyeBlinkLeft\n00:00:00:00.000,1,abc\n")
    path = tmp_path / "jobs.toml"
    path.write_text(_jobs_text(data_dir, tk).split("[[jobs]]\nname = \"rt\"")[0])   # the clone group only
    rc = main(["-q", "batch", str(path), "--workers", "1"])                 # a LocalCluster of 1 process
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 1
    recs = {r["job"]: r for r in read_manifest(tmp_path / "batch.jsonl")}
    assert [r["status"] for r in recs.values()].count("ok") == 2
    failed = recs["cl:bo:takes/broken.csv"]
    assert failed["status"] == "failed" and str(bad) in failed["error"] and "\n" not in failed["error"]
    assert failed["output_hash"] is None and not (tmp_path / "out" / "bo" / "cl" / "broken.glb").exists()
    assert err == [f"failed: cl:bo:takes/broken.csv: {failed['error']}"]
    for name in ("S07-001_short", "apfel_short"):
        assert (tmp_path / "out" / "bo" / "cl" / f"{name}.glb").is_file()
    # the next run retries the failed job only (and still fails it)
    assert main(["-q", "batch", str(path), "--workers", "1", "--dry-run"]) == 0
    assert main(["-q", "batch", str(path), "--workers", "1"]) == 1
    assert len(read_manifest(tmp_path / "batch.jsonl")) == 4


def test_headmotion_synth_builds_its_database_once(data_dir, tmp_path, client):
    from faceretarget.headmotion import HeadMotionDatabase, rotation_range
    from faceretarget.io import read_audio, read_bvh_head
    from faceretarget.pipelines import build_head_database, read_jobs, run_batch

    hm = data_dir / "headmotion" / "zeggs_067_Speech_2_x_1_0"
    path = tmp_path / "jobs.toml"
    path.write_text(f"""
[[jobs]]
name = "head"
operation = "headmotion synth"
takes = "{data_dir}/speech/libritts/1089_134686_00001*.wav"
out = "out/{{character}}/{{take}}.bvh"
[jobs.options]
build = [["{hm}.wav", "{hm}.bvh"]]
seed = 3
motion_range = [20, 10, 5]
""")
    s = run_batch(path, client=client)
    assert s.exit_code == 0 and s.models == 1 and s.count("ok") >= 1
    db = build_head_database([(f"{hm}.wav", f"{hm}.bvh")])
    assert isinstance(db, HeadMotionDatabase)
    for o in s.outcomes:
        audio, rate = read_audio(o.job.input)
        ref = db.transform(audio, rate, seed=3, source=str(o.job.input), motion_range=[20, 10, 5]).take.head
        got = read_bvh_head(o.job.out).head
        assert got.n_frames == ref.n_frames == o.frames > 50
        angle = (got.rotation.inv() * ref.rotation).magnitude()          # radians between the poses
        assert np.degrees(angle).max() < 0.01
        assert np.allclose(rotation_range(got), [20, 10, 5], rtol=0.01)  # as far as asked
    bad = path.read_text().replace("motion_range = [20, 10, 5]", "motion_range = [20, 10]")
    path.write_text(bad)
    with pytest.raises(InvalidDataError, match=r"key 'options.motion_range'.*\[YAW, PITCH, ROLL\]"):
        read_jobs(path)


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@contextlib.contextmanager
def _dask_processes(tmp_path: Path):
    """``dask scheduler`` and one ``dask worker`` (1 thread) as separate processes on 127.0.0.1."""
    port = _free_port()
    addr = f"tcp://127.0.0.1:{port}"
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    logs = [open(tmp_path / n, "wb") for n in ("scheduler.log", "worker.log")]
    procs = [subprocess.Popen([sys.executable, "-m", "dask", "scheduler", "--host", "127.0.0.1", "--port", str(port),
                               "--no-dashboard"], stdout=logs[0], stderr=subprocess.STDOUT, env=env, cwd=tmp_path)]
    try:
        deadline = time.monotonic() + 30
        while time.monotonic() < deadline:
            with contextlib.suppress(OSError), socket.create_connection(("127.0.0.1", port), timeout=0.5):
                break
            time.sleep(0.2)
        procs.append(subprocess.Popen([sys.executable, "-m", "dask", "worker", addr, "--nthreads", "1", "--nworkers",
                                       "1", "--no-dashboard"], stdout=logs[1], stderr=subprocess.STDOUT, env=env,
                                      cwd=tmp_path))
        yield addr
    finally:
        for p in reversed(procs):
            p.terminate()
        for p in reversed(procs):
            try:
                p.wait(timeout=15)
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait()
        for f in logs:
            f.close()


# slow: starts a real Dask scheduler and worker processes (~11 s, most of it their start-up)
def test_scheduler_option_runs_on_separate_dask_processes(data_dir, takes, tmp_path, capsys):
    _distributed()
    from faceretarget.cli import main
    from faceretarget.io import read_glb_weights
    from faceretarget.pipelines import read_manifest

    path = tmp_path / "jobs.toml"
    path.write_text(_jobs_text(data_dir, takes).split("[[jobs]]\nname = \"rt\"")[0])
    with _dask_processes(tmp_path) as addr:
        rc = main(["batch", str(path), "--scheduler", addr])
    out = capsys.readouterr().out
    assert rc == 0, out
    recs = read_manifest(tmp_path / "batch.jsonl")
    assert len(recs) == 2 and all(r["status"] == "ok" for r in recs)
    assert {r["worker"] for r in recs} != {None} and all(r["worker"].startswith("tcp://127.0.0.1:") for r in recs)
    for r in recs:
        ref = _direct(data_dir, Path(r["input"]), "clone", "bo", tmp_path / "ref" / Path(r["output"]).name)
        n1, w1, t1 = read_glb_weights(r["output"])
        n2, w2, t2 = read_glb_weights(ref)
        assert n1 == n2 and np.array_equal(t1, t2)
        assert np.abs(w1 - w2).max() < 1e-5         # another process (its own BLAS threads): float32 curves agree


def test_unreachable_scheduler_is_one_line_and_nothing_runs(data_dir, takes, tmp_path, capsys):
    _distributed()
    from faceretarget.cli import main

    path = tmp_path / "jobs.toml"
    path.write_text(_jobs_text(data_dir, takes))
    from faceretarget.pipelines import CONNECT_TIMEOUT

    t0 = time.perf_counter()
    rc = main(["batch", str(path), "--scheduler", f"tcp://127.0.0.1:{_free_port()}"])     # Dask's own timeout: 30 s
    seconds = time.perf_counter() - t0
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and "cannot connect" in err[0], err
    assert seconds < CONNECT_TIMEOUT + 3, seconds            # fails within a few seconds
    assert not (tmp_path / "out").exists()


def test_an_output_under_a_regular_file_is_refused_before_anything_runs(data_dir, takes, tmp_path, capsys):
    """Issue 34: was exit 1 (the job failed with NotADirectoryError after the cluster started), now 2."""
    from faceretarget.cli import main

    (tmp_path / "out").write_text("a file where the output folder goes")
    path = tmp_path / "jobs.toml"
    path.write_text(_jobs_text(data_dir, takes))
    rc = main(["batch", str(path)])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1, err
    assert "key 'out'" in err[0] and "is a file, not a folder" in err[0] and str(tmp_path / "out") in err[0]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["jobs.toml", "out"]     # no manifest, nothing run


def test_missing_distributed_names_the_extra(monkeypatch, data_dir, takes, tmp_path):
    from faceretarget.errors import MissingDependencyError
    from faceretarget.pipelines import run_batch

    path = tmp_path / "jobs.toml"
    path.write_text(_jobs_text(data_dir, takes))
    monkeypatch.setitem(sys.modules, "distributed", None)          # as if not installed
    with pytest.raises(MissingDependencyError, match=r"make batch .*pip install 'dask\[distributed\]") as e:
        run_batch(path)
    assert isinstance(e.value, FaceRetargetError)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["jobs.toml"]     # nothing written
