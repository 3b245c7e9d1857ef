"""The command line, end to end on the embedded demo characters (no shared data needed)."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from faceretarget.cli import main
from faceretarget.datasets import make_demo_character, make_demo_take
from faceretarget.io import read_glb_weights, write_livelinkface, write_rig
from faceretarget.rig import Rig


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    d = tmp_path_factory.mktemp("cli")
    ada, bo = make_demo_character("ada"), make_demo_character("bo")
    write_rig(ada, d / "ada")
    write_rig(bo, d / "bo")
    (d / "ada" / "landmarks68.txt").write_text(" ".join(map(str, ada.landmarks)))
    (d / "bo" / "landmarks68.txt").write_text(" ".join(map(str, bo.landmarks)))
    take = make_demo_take(seconds=3.0, fps=30.0, seed=4)
    write_livelinkface(d / "take.csv", take)
    # artist-style key-model folders: neutral + a few expressions, paired by file name
    names = ["jawOpen", "mouthSmileLeft", "mouthSmileRight", "eyeBlinkLeft", "eyeBlinkRight", "browInnerUp"]
    for rig, sub in ((ada, "ada_keys"), (bo, "bo_keys")):
        write_rig(rig.subset(names), d / sub)
        (d / sub / "landmarks68.txt").write_text(" ".join(map(str, rig.landmarks)))
    return d, ada, bo, take


def test_clone_rigs_arkit_keys_to_glb(files, capsys):
    d, ada, bo, take = files
    out = d / "out.glb"
    rc = main(["clone", "--source-rig", str(d / "ada"), "--target-rig", str(d / "bo"), "--keys", "arkit",
               "--features", "all", "--performance", str(d / "take.csv"), "--out", str(out)])
    assert rc == 0
    names, times, w = read_glb_weights(out)
    assert w.shape == (take.n_frames, 52)
    np.testing.assert_allclose(times, take.times - take.times[0], atol=1e-4)
    # arkit keys: the cloned weights are the take's own weights (to the CSV's 3 decimals)
    truth = bo.map_weights(take.names, take.weights, warn=False)
    order = [bo.index(n) for n in names]
    np.testing.assert_allclose(w, truth[:, order], atol=2e-3)


def test_weight_range_on_the_command_line(files, capsys):
    """--weight-range keeps every written weight inside; a .glb whose weights leave [0, 1] says in one
    line which Blender route keeps them; 'none' lets them run free; a bad range is a one-line error."""
    d, ada, bo, take = files
    base = ["clone", "--source-rig", str(d / "ada"), "--target-rig", str(d / "bo"), "--keys", "rom-12",
            "--features", "all", "--performance", str(d / "take.csv")]
    spans = {}
    for rng in (["auto"], ["-0.25", "1.25"], ["none"]):
        out = d / f"range_{'_'.join(rng)}.glb"
        assert main(base + ["--weight-range", *rng, "--out", str(out)]) == 0
        spans[rng[0]] = read_glb_weights(out)[2]
        log = capsys.readouterr().out
        outside = spans[rng[0]].min() < 0 or spans[rng[0]].max() > 1
        assert ("write range_" in log and ".blend" in log) == outside
    assert spans["auto"].min() >= -0.5 - 1e-6 and spans["auto"].max() <= 1.5 + 1e-6
    assert spans["-0.25"].min() >= -0.25 - 1e-6 and spans["-0.25"].max() <= 1.25 + 1e-6
    assert np.abs(spans["none"]).max() > 1.5                      # the free solve cancels large weights
    assert main(base + ["--weight-range", "1", "0", "--out", str(d / "bad.glb")]) == 2
    assert "LO < HI" in capsys.readouterr().err and not (d / "bad.glb").exists()


def test_clone_key_folders_paired_by_name(files):
    d, ada, bo, take = files
    out = d / "keys_out.npz"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        rc = main(["--quiet", "clone", "--source-keys", str(d / "ada_keys"), "--target-keys", str(d / "bo_keys"),
                   "--source-rig", str(d / "ada"), "--performance", str(d / "take.csv"), "--out", str(out)])
    assert rc == 0
    z = np.load(out)
    assert z["vertices"].shape == (take.n_frames, bo.n_vertices, 3)


def test_keys_compose_writes_84_models(files):
    d, ada, _, _ = files
    out = d / "composed"
    assert main(["--quiet", "keys", "compose", "--rig", str(d / "ada"), "--out", str(out)]) == 0
    objs = sorted(out.glob("*.obj"))
    assert len(objs) == 84          # the neutral (pure 'neutral' key-model) + 83 composed key-models
    assert (out / "happyPP.obj").exists() and (out / "angry.obj").exists()   # names in camelCase


def test_errors_are_one_line_and_nonzero(files, capsys, tmp_path):
    d, _, _, _ = files
    # missing neutral
    empty = tmp_path / "noneutral"
    empty.mkdir()
    (empty / "jawOpen.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    rc = main(["clone", "--source-keys", str(empty), "--target-keys", str(d / "bo_keys"),
               "--performance", str(d / "take.csv"), "--out", str(tmp_path / "x.glb")])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and "neutral" in err[0] and "noneutral" in err[0]
    assert not (tmp_path / "x.glb").exists()
    # output folder that does not exist: nothing written, path named
    rc = main(["clone", "--source-rig", str(d / "ada"), "--target-rig", str(d / "bo"), "--keys", "arkit",
               "--performance", str(d / "take.csv"), "--out", str(tmp_path / "nope" / "x.glb")])
    err = capsys.readouterr().err
    assert rc == 2 and "nope" in err
    # refusing to overwrite the input
    before = (d / "take.csv").read_bytes()
    rc = main(["clone", "--source-rig", str(d / "ada"), "--target-rig", str(d / "bo"), "--keys", "arkit",
               "--performance", str(d / "take.csv"), "--out", str(d / "take.csv")])
    assert rc == 2 and "input" in capsys.readouterr().err
    assert (d / "take.csv").read_bytes() == before
    # a key model missing on the target side is named
    rc = main(["clone", "--source-keys", str(d / "ada"), "--target-keys", str(d / "bo_keys"),
               "--performance", str(d / "take.csv"), "--out", str(tmp_path / "y.glb")])
    assert rc == 2 and "no target key-model" in capsys.readouterr().err
    # unknown output format
    rc = main(["clone", "--source-rig", str(d / "ada"), "--target-rig", str(d / "bo"), "--keys", "arkit",
               "--performance", str(d / "take.csv"), "--out", str(tmp_path / "x.xyz")])
    assert rc == 2 and ".xyz" in capsys.readouterr().err
    assert not list(tmp_path.glob("*.part")) and not list(tmp_path.glob(".*.part"))


def test_demo_command(tmp_path, capsys):
    from faceretarget.metrics import FIGURES

    assert main(["demo", "--out", str(tmp_path / "demo")]) == 0
    out = capsys.readouterr().out
    assert "temporal" in out and "motion error" in out
    # issue 34: every figure says what it means and what is good; advice only where it is not good
    for what in ("motion error", "lip error", "mouth correlation"):
        line = next(x for x in out.splitlines() if x.strip().startswith(what))
        assert ": " in line and ("good under" in line or "good over" in line), line
        f = next(f for f in FIGURES.values() if f.what == what)
        value = float(line.strip()[len(what):].split()[0].rstrip(":"))
        assert ("so not good:" in line) == (not f.good(value)), line
    assert "(not good)" in next(x for x in out.splitlines() if x.strip().startswith("pyun"))
    import json

    m = json.loads((tmp_path / "demo" / "metrics.json").read_text())
    assert m["temporal"]["rel_motion_pct"] < m["pyun"]["rel_motion_pct"]
    assert (tmp_path / "demo" / "clone.glb").stat().st_size > 10_000
    assert (tmp_path / "demo" / "preview.png").read_bytes()[:4] == b"\x89PNG"
    video = tmp_path / "demo" / "preview.mp4"
    if video.exists():                       # PyAV: issue 34, bo is previewed with eyes and lips, not in clay
        from faceretarget.io import iter_frames

        frame = next(rgb for i, _, rgb in iter_frames(video, max_frames=61) if i == 60)
        bo = frame[:, frame.shape[1] // 2:].astype(int)
        r, g, b = bo[..., 0], bo[..., 1], bo[..., 2]
        assert ((b > r + 40) & (b > 100)).sum() > 20, "bo's blue irises"
        assert ((r > g + 70) & (r > 150)).sum() > 200, "bo's red lips"


def test_rig_unused(files):
    # keep Rig import meaningful: a subset rig keeps vertex order
    _, ada, _, _ = files
    sub = ada.subset(["jawOpen"])
    assert isinstance(sub, Rig) and sub.n_vertices == ada.n_vertices


def _copy_keys(src, dst):
    import shutil

    shutil.copytree(src, dst)
    return dst


@pytest.mark.parametrize("case", ["vertex_count", "non_numeric", "non_finite", "nan_weight", "empty_csv"])
def test_bad_inputs_one_line_nonzero_no_output(files, tmp_path, capsys, case):
    d, _, _, _ = files
    keys = _copy_keys(d / "ada_keys", tmp_path / "keys")
    perf = d / "take.csv"
    expect = None
    if case == "vertex_count":
        (keys / "jawOpen.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
        expect = "jawOpen"
    elif case == "non_numeric":
        lines = (keys / "browInnerUp.obj").read_text().splitlines()
        lines[3] = "v 0.1 abc 0.3"
        (keys / "browInnerUp.obj").write_text("\n".join(lines) + "\n")
        expect = "browInnerUp.obj"
    elif case == "non_finite":
        lines = (keys / "eyeBlinkLeft.obj").read_text().splitlines()
        lines[5] = "v 0.1 nan 0.3"
        (keys / "eyeBlinkLeft.obj").write_text("\n".join(lines) + "\n")
        expect = "eyeBlinkLeft.obj"
    elif case == "nan_weight":
        rows = perf.read_text().splitlines()
        cells = rows[7].split(",")
        cells[5] = "nan"
        rows[7] = ",".join(cells)
        perf = tmp_path / "nan.csv"
        perf.write_text("\n".join(rows) + "\n")
        expect = "nan.csv"
    elif case == "empty_csv":
        perf = tmp_path / "empty.csv"
        perf.write_text("")
        expect = "empty.csv"
    out = tmp_path / "out.glb"
    rc = main(["clone", "--source-keys", str(keys), "--target-keys", str(d / "bo_keys"), "--source-rig", str(d / "ada"),
               "--performance", str(perf), "--out", str(out)])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2
    assert len(err) == 1 and err[0].startswith("faceretarget: error:") and expect in err[0]
    assert not out.exists()
    assert not [p for p in tmp_path.iterdir() if p.name.endswith(".part")]


def test_neutral_given_by_file(files, tmp_path):
    d, ada, bo, take = files
    keys = _copy_keys(d / "ada_keys", tmp_path / "keys")
    (keys / "neutral.obj").rename(keys / "rest_pose.obj")
    out = tmp_path / "o.npz"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        rc = main(["--quiet", "clone", "--source-keys", str(keys), "--source-neutral", str(keys / "rest_pose.obj"),
                   "--target-keys", str(d / "bo_keys"), "--source-rig", str(d / "ada"),
                   "--performance", str(d / "take.csv"), "--out", str(out)])
    assert rc == 0 and np.load(out)["vertices"].shape == (take.n_frames, bo.n_vertices, 3)
