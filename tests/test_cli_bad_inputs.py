"""Every command checks its options and its output before any work, fails in one line, and starts fast.

The table of bad command lines lives in ``bench/cli_cases.py`` (``bench/fuzz.py`` reports it as
``"cli"``); here each case is one test: exit 2, exactly one ``faceretarget: error:`` line naming the
option or file, no traceback, nothing created, an existing output untouched.  Then: the documented
ranges are in ``--help`` and match the library's, ``--temporal`` means the same on a rig in metres
and in centimetres, a warning is one ``warning:`` line, a few subprocess runs for tracebacks, and
``--version`` / ``--help`` start in under 0.3 s without NumPy.
"""

from __future__ import annotations

import argparse
import dataclasses
import statistics
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "bench"))
from cli_cases import CASES, check_case, make_inputs, missing_need  # noqa: E402 - bench/cli_cases.py
from faceretarget.cli import build_parser  # noqa: E402
from faceretarget.cli._support import Range  # noqa: E402

RUN = [sys.executable, "-c", "import sys; from faceretarget.cli import main; sys.exit(main())"]


@pytest.fixture(scope="module")
def paths(tmp_path_factory):
    d = tmp_path_factory.mktemp("cli_bad")
    p = make_inputs(d)
    yield p
    ro = Path(p["ro"])
    if ro.parent == d:
        ro.chmod(0o755)


@pytest.mark.parametrize("case", CASES, ids=[c.name for c in CASES])
def test_bad_command_line_fails_first_in_one_line(case, paths):
    why = missing_need(case, paths)
    if why:
        pytest.skip(why)
    assert check_case(case, paths) == []


def test_the_table_covers_every_command():
    cmds = {" ".join(c.argv[:2]) if c.argv[0] in ("keys", "appearance", "style", "headmotion") else c.argv[0]
            for c in CASES}
    assert {"animate", "live", "clone", "retarget", "keys compose", "keys select", "capture", "appearance fit",
            "appearance encode", "style fit", "restyle", "headmotion build", "headmotion synth", "demo"} <= cmds
    assert len(CASES) >= 100 and len({c.name for c in CASES}) == len(CASES)


def _actions(parser: argparse.ArgumentParser, prefix: str = ""):
    for a in parser._actions:
        if isinstance(a, argparse._SubParsersAction):
            for name, sub in a.choices.items():
                yield from _actions(sub, f"{prefix}{name} ")
        else:
            yield prefix.strip(), a


def test_every_ranged_option_documents_its_range_in_help():
    ranged = [(cmd, a) for cmd, a in _actions(build_parser()) if isinstance(a.type, Range) or hasattr(a.type, "rng")]
    assert len(ranged) >= 40
    for cmd, a in ranged:
        assert str(a.type) in (a.help or ""), f"{cmd} {a.option_strings}: help does not show {a.type}"
    # no bare float/int options are left: every number has a range
    bare = [(cmd, a.option_strings) for cmd, a in _actions(build_parser()) if a.type in (float, int)]
    assert bare == []


def test_range_messages_name_option_value_and_range(capsys):
    from faceretarget.cli import main

    assert main(["headmotion", "synth", "--db", "x.npz", "--audio", "a.wav", "--out", "h.bvh",
                 "--amplitude", "1e30"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ["faceretarget: error: headmotion synth: argument --amplitude: '1e30' is outside the range "
                   "[0, 10] (see 'faceretarget headmotion synth --help')"]
    r = Range(0, 5, lo_open=True)
    assert str(r) == "(0, 5]" and r("5") == 5.0 and str(Range(1, integer=True)) == ">= 1"
    for bad in ("0", "5.01", "nan", "inf", "x"):
        with pytest.raises(argparse.ArgumentTypeError):
            r(bad)
    with pytest.raises(argparse.ArgumentTypeError):
        Range(1, integer=True)("2.5")


def test_cli_ranges_match_the_library():
    from faceretarget.cli import _animate, _live, _main
    from faceretarget.pipelines import LIVE_LIMITS, MAX_TEMPORAL

    assert (_main.TEMPORAL.lo, _main.TEMPORAL.hi) == (0, MAX_TEMPORAL)
    assert (_live.HEAD_AMPLITUDE.lo, _live.HEAD_AMPLITUDE.hi) == LIVE_LIMITS["head_amplitude"]
    assert (_live.EMOTION_AMOUNT.lo, _live.EMOTION_AMOUNT.hi) == LIVE_LIMITS["emotion_amount"]
    assert (_animate.HEAD_AMPLITUDE.lo, _animate.HEAD_AMPLITUDE.hi) == (0, 10)   # pipelines.animate's check


def _scaled(rig, k: float, unit: str):
    mesh = dataclasses.replace(rig.neutral, vertices=rig.neutral.vertices * k)
    return dataclasses.replace(rig, neutral=mesh, deltas=rig.deltas * k, unit=unit)


def test_temporal_is_relative_to_the_keys_so_units_do_not_matter():
    """The same ``temporal`` on one rig in cm and in m (x 0.01) gives the same weights (to the solver's
    tolerance: 1.1e-4 measured), where the same absolute ``smooth`` differs by 0.66 (46x smoother in m);
    it smooths (mean frame-to-frame change 0.0076 -> 0.0054 at 1); values above MAX_TEMPORAL and
    temporal with the signed solver are refused."""
    from faceretarget.cloning import keymodel_pair
    from faceretarget.datasets import make_demo_character, make_demo_take
    from faceretarget.errors import InvalidDataError
    from faceretarget.pipelines import MAX_TEMPORAL, retarget_take

    ada, bo = make_demo_character("ada"), make_demo_character("bo")
    take = make_demo_take(seconds=2.0, fps=30.0, seed=4)
    W = {}
    for k, unit in ((1.0, "cm"), (0.01, "m")):
        src = _scaled(ada, k, unit)
        sk, tk, _ = keymodel_pair(src, bo, "arkit")
        for name, kw in (("none", {"temporal": 0.0}), ("relative", {"temporal": 1.0}), ("absolute", {"smooth": 1.0})):
            job = retarget_take(take, sk, tk, source_rig=src, solver="nnls", denoise=False, **kw)
            W[unit, name] = job.result.weights
    assert np.abs(W["m", "relative"] - W["cm", "relative"]).max() < 1e-3
    assert np.abs(W["m", "absolute"] - W["cm", "absolute"]).max() > 0.1
    step = {n: float(np.abs(np.diff(W["cm", n], axis=0)).mean()) for n in ("none", "relative")}
    assert step["relative"] < 0.8 * step["none"], step
    with pytest.raises(InvalidDataError, match="temporal"):
        retarget_take(take, sk, tk, source_rig=src, solver="nnls", temporal=MAX_TEMPORAL * 1.01)
    with pytest.raises(InvalidDataError, match="nnls"):
        retarget_take(take, sk, tk, source_rig=src, temporal=1.0)


def test_appearance_memory_estimate():
    from faceretarget.pipelines import APPEARANCE_BYTES, appearance_memory

    assert appearance_memory(128, 100) == APPEARANCE_BYTES * 100 * 128**2
    assert appearance_memory(100000, 98) > 2**45           # the 92 GiB allocation of the issue and more


def _run(args, **kw):
    return subprocess.run(RUN + [str(a) for a in args], capture_output=True, text=True, timeout=120, **kw)


def test_subprocess_errors_have_no_traceback(paths):
    d = Path(paths["d"])
    runs = [
        ["retarget", "--performance", paths["take"], "--source-keys", paths["ada"], "--target-keys", paths["bo"],
         "--source-rig", paths["ada"], "--solver", "nnls", "--temporal", "1e12", "--out", d / "out" / "r.glb"],
        ["headmotion", "synth", "--db", paths["db"], "--audio", paths["wav"], "--amplitude", "-1",
         "--out", d / "out" / "h.bvh"],
        ["clone", "--source-keys", paths["noneutral"], "--target-keys", paths["bo_keys"], "--performance",
         paths["take"], "--out", d / "out" / "c.glb"],
    ]
    for args in runs:
        p = _run(args)
        lines = p.stderr.strip().splitlines()
        assert p.returncode == 2, p.stderr
        assert len(lines) == 1 and lines[0].startswith("faceretarget: error:"), p.stderr
        assert "Traceback" not in p.stderr + p.stdout
    assert not any((d / "out").iterdir())


def test_a_warning_is_one_line(paths, tmp_path):
    """A take whose reader warns (Live Link Face rows without a face dropped): one 'warning:' line on
    stdout, nothing raw on stderr, and the job still runs."""
    rows = Path(paths["take"]).read_text().splitlines()
    head = rows[0].split(",")
    assert head[1].lower() == "blendshapecount"
    for i in (5, 6):
        rows[i] = rows[i].split(",")[0] + ",0"             # what the app writes when it loses the face
    take = tmp_path / "gappy.csv"
    take.write_text("\n".join(rows) + "\n")
    out = tmp_path / "c.glb"
    p = _run(["clone", "--source-rig", paths["ada"], "--target-rig", paths["bo"], "--keys", "arkit",
              "--performance", take, "--out", out])
    assert p.returncode == 0, p.stderr
    assert p.stderr == ""
    lines = p.stdout.splitlines()
    dropped = [ln for ln in lines if "gappy.csv" in ln and "dropped 2 row(s)" in ln]
    assert len(dropped) == 1 and dropped[0].startswith("warning: "), p.stdout
    assert "Warning:" not in p.stdout and out.stat().st_size > 1000


def test_startup_without_numpy_and_fast():
    """``faceretarget --version`` / ``--help`` import no NumPy or SciPy and start in < 0.3 s (median of 5)."""
    code = ("import sys; from faceretarget.cli import build_parser; build_parser(); "
            "import faceretarget; print(sorted(m for m in ('numpy', 'scipy', 'PIL', 'numba', 'pygltflib', 'tqdm') "
            "if m in sys.modules))")
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert p.stdout.strip() == "[]", p.stdout + p.stderr
    for args in (["--version"], ["--help"]):
        times = []
        for _ in range(5):
            t0 = time.perf_counter()
            p = _run(args)
            times.append(time.perf_counter() - t0)
            assert p.returncode == 0 and p.stdout
        assert statistics.median(times) < 0.3, (args, times)
    # the public API still works through the lazy re-exports
    import faceretarget
    from faceretarget import Mesh, Rig

    assert faceretarget.Performance.__name__ == "Performance" and Rig.__module__ == "faceretarget.rig"
    assert Mesh is faceretarget.Mesh and "HeadPose" in dir(faceretarget)
