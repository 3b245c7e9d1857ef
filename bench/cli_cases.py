"""Every ``faceretarget`` command under bad options and bad files: one table, run in-process.

Each :class:`Case` is a command line with placeholders for small input files that
:func:`make_inputs` writes in a temporary folder (the embedded demo characters, a 1 s Live Link Face
take, a WAV, stand-in files for a video, a model and a database whose contents are never reached).
Every case must end the same way (:func:`check_case`):

* exit code 2 and exactly one line on stderr, starting ``faceretarget: error:`` and naming what is
  wrong (``Case.expect``: the option, the file or the range);
* no traceback, no warning printed raw;
* nothing created or changed in the folder (no output, no ``.part`` left behind), and an existing
  output named by the case (``Case.existing``) untouched: the same bytes and modification time.

Bad options are refused while parsing (``faceretarget.cli._support.Range``), so these cases also
show that no work starts before the checks.  ``tests/test_cli_bad_inputs.py`` runs the same table
(one test per case); :func:`run_cli_cases` runs it alone for ``bench/fuzz.py``'s ``"cli"`` entry.

Usage::

    python bench/cli_cases.py [--json]
"""

from __future__ import annotations

import contextlib
import io
import json
import os
import shutil
import sys
import tempfile
import time
import wave
from dataclasses import dataclass
from pathlib import Path

DATA = Path(os.environ.get("FACERETARGET_DATA", Path(__file__).resolve().parents[2] / "shared" / "data"))


@dataclass(frozen=True)
class Case:
    """One bad command line.

    Attributes
    ----------
    name : str
        Unique, for test ids and failure lists.
    argv : tuple of str
        Arguments after ``faceretarget``; ``{key}`` is replaced by the path :func:`make_inputs` made.
    expect : str
        Text the error line must contain (an option, a file name, a range).
    existing : str, optional
        An output path (with placeholders) that exists before the run and must stay unchanged.
    needs : str, optional
        ``"video"``: a real video from the shared data and PyAV (skipped without them).
    """

    name: str
    argv: tuple[str, ...]
    expect: str
    existing: str | None = None
    needs: str | None = None


def _c(name: str, cmd: str, expect: str, existing: str | None = None, needs: str | None = None) -> Case:
    return Case(name, tuple(cmd.split()), expect, existing, needs)


_CLONE = "clone --source-rig {ada} --target-rig {bo} --keys arkit --performance {take}"
_RETARGET = "retarget --performance {take} --source-keys {ada} --target-keys {bo} --source-rig {ada}"
_SYNTH = "headmotion synth --db {db} --audio {wav}"
_BUILD = "headmotion build --take {wav} {bvh}"
_RESTYLE = "restyle --model {model} --performance {take} --to angry"
_FIT = "style fit --take neutral={take} --take angry={take2}"

#: The table: every command, bad files (missing, wrong extension, unwritable or missing output
#: folder, output = an input, an existing output) and out-of-range options.
CASES: tuple[Case, ...] = (
    # ---- animate
    _c("animate-missing-video", "animate {d}/nope.mp4 --character {ada} --out {out}/a.glb", "nope.mp4"),
    _c("animate-out-ext", "animate {video} --character {ada} --out {out}/a.txt", ".txt"),
    _c("animate-out-missing-folder", "animate {video} --character {ada} --out {missing}/a.glb", "missing"),
    _c("animate-out-unwritable", "animate {video} --character {ada} --out {ro}/a.glb", "a.glb"),
    _c("animate-head-amplitude", "animate {video} --character {ada} --out {out}/a.glb --head-amplitude 11",
       "--head-amplitude"),
    _c("animate-preview-size", "animate {video} --character {ada} --out {out}/a.glb --preview-size 0", "--preview-size"),
    _c("animate-max-frames", "animate {video} --character {ada} --out {out}/a.glb --max-frames 0", "--max-frames"),
    _c("animate-missing-head-db", "animate {video} --character {ada} --out {out}/a.glb --head speech "
       "--head-db {d}/nope.npz", "--head-db"),
    _c("animate-no-neutral", "animate {video} --character {noneutral} --out {out}/a.glb", "--neutral"),
    _c("animate-character-out-ext", "animate {video} --character {glb} --out {out}/a.vrm", ".vrm"),
    _c("animate-character-txt", "animate {video} --character {junk} --out {out}/a.glb", "junk.csv"),
    _c("animate-neck-share", "animate {video} --character {glb} --out {out}/a.glb --neck-share 2", "--neck-share"),
    _c("animate-shapes-on-folder", "animate {video} --character {ada} --out {out}/a.glb --shapes all", "--shapes"),
    _c("animate-character-landmarks-missing", "animate {video} --character {glb} --out {out}/a.glb "
       "--landmarks {d}/nope.txt", "nope.txt"),
    _c("character-inspect-missing", "character inspect {d}/nope.glb", "nope.glb"),
    _c("character-inspect-out-ext", "character inspect {glb} --out {out}/check.jpg", "check.jpg"),
    _c("character-inspect-not-a-character", "character inspect {junk}", "not a character format"),
    _c("animate-existing-out", "animate {video} --character {ada} --out {out}/old.glb --head-amplitude -1",
       "--head-amplitude", existing="{out}/old.glb"),
    # ---- live
    _c("live-missing-video", "live --video {d}/nope.mp4 --character {ada} --serve off", "nope.mp4"),
    _c("live-missing-character", "live --video {video} --character {d}/nochar --serve off", "nochar"),
    _c("live-max-frames", "live --video {video} --character {ada} --serve off --max-frames 0", "--max-frames"),
    _c("live-camera", "live --camera -1 --character {ada} --serve off", "--camera"),
    _c("live-head-amplitude", "live --video {video} --character {ada} --head-amplitude 4", "--head-amplitude"),
    _c("live-emotion-amount", "live --video {video} --character {ada} --emotion-amount nan", "--emotion-amount"),
    _c("live-wait", "live --video {video} --character {ada} --wait -1", "--wait"),
    _c("live-no-neutral", "live --video {video} --character {noneutral} --serve off", "--neutral"),
    # ---- clone
    _c("clone-missing-take", "clone --source-rig {ada} --target-rig {bo} --keys arkit --performance {d}/nope.csv "
       "--out {out}/c.glb", "nope.csv"),
    _c("clone-out-ext", _CLONE + " --out {out}/c.xyz", ".xyz"),
    _c("clone-out-missing-folder", _CLONE + " --out {missing}/c.glb", "missing"),
    _c("clone-out-unwritable", _CLONE + " --out {ro}/c.glb", "c.glb"),
    _c("clone-out-is-input", _CLONE + " --out {take}", "input"),
    _c("clone-bake-glb", _CLONE + " --bake --out {out}/c.glb", "USD"),
    _c("clone-head-only-format", _CLONE + " --out {out}/c.bvh", "head motion only"),
    _c("clone-fps", _CLONE + " --fps 0 --out {out}/c.glb", "--fps"),
    _c("clone-no-neutral", "clone --source-keys {noneutral} --target-keys {bo_keys} --performance {take} "
       "--out {out}/c.glb", "--source-neutral"),
    _c("clone-existing-out", _CLONE + " --bake --out {out}/old.glb", "USD", existing="{out}/old.glb"),
    # ---- retarget
    _c("retarget-temporal-huge", _RETARGET + " --solver nnls --temporal 1e12 --out {out}/r.glb", "--temporal"),
    _c("retarget-temporal-negative", _RETARGET + " --solver nnls --temporal -1 --out {out}/r.glb", "--temporal"),
    _c("retarget-temporal-signed", _RETARGET + " --temporal 5 --out {out}/r.glb", "--solver nnls"),
    _c("retarget-smooth", _RETARGET + " --smooth -1 --out {out}/r.glb", "--smooth"),
    _c("retarget-l1", _RETARGET + " --solver nnls --l1 nan --out {out}/r.glb", "--l1"),
    _c("retarget-l2", _RETARGET + " --l2 -0.5 --out {out}/r.glb", "--l2"),
    _c("retarget-missing-keys", "retarget --performance {take} --source-keys {d}/nokeys --target-keys {bo} "
       "--source-rig {ada} --out {out}/r.glb", "nokeys"),
    _c("retarget-out-ext", _RETARGET + " --out {out}/r.txt", ".txt"),
    _c("retarget-out-unwritable", _RETARGET + " --out {ro}/r.glb", "r.glb"),
    _c("retarget-out-is-input", _RETARGET + " --out {take}", "input"),
    _c("retarget-no-neutral", "retarget --performance {take} --source-keys {noneutral} --target-keys {bo_keys} "
       "--source-rig {ada} --out {out}/r.glb", "--source-neutral"),
    _c("retarget-existing-out", _RETARGET + " --temporal 1e30 --out {out}/old.glb", "--temporal",
       existing="{out}/old.glb"),
    # ---- keys compose / select
    _c("compose-missing-rig", "keys compose --rig {d}/norig --out {out}/composed", "norig"),
    _c("compose-out-is-file", "keys compose --rig {ada} --out {take}", "take.csv"),
    _c("compose-out-unwritable", "keys compose --rig {ada} --out {ro}/composed", "composed"),
    _c("compose-no-neutral", "keys compose --rig {noneutral} --out {out}/composed", "--neutral"),
    _c("select-k", "keys select --performance {take} --source-rig {ada} --k 0 --out {out}/sel", "--k"),
    _c("select-fps", "keys select --performance {take} --source-rig {ada} --fps -30 --out {out}/sel", "--fps"),
    _c("select-missing-take", "keys select --performance {d}/nope.csv --source-rig {ada} --out {out}/sel", "nope.csv"),
    _c("select-not-a-face", "keys select --performance {body} --k 3 --out {out}/sel", "not a face"),
    _c("retarget-not-a-face", "retarget --performance {body} --source-keys {ada_keys} --target-keys {bo_keys} "
       "--out {out}/r.glb", "not a face"),
    _c("select-out-is-file", "keys select --performance {take} --source-rig {ada} --out {take2}", "take2.csv"),
    _c("select-out-missing-folder", "keys select --performance {take} --source-rig {ada} --out {missing}/sel",
       "missing"),
    # ---- capture
    _c("capture-timecode-rate", "capture {video} --out {out}/cap.csv --timecode-rate 0", "--timecode-rate"),
    _c("capture-duration", "capture {video} --out {out}/cap.csv --duration -1", "--duration"),
    _c("capture-max-frames", "capture {video} --out {out}/cap.csv --max-frames 0", "--max-frames"),
    _c("capture-max-gap", "capture {video} --out {out}/cap.csv --max-gap -2", "--max-gap"),
    _c("capture-percentile", "capture {video} --out {out}/cap.csv --neutral-percentile 101", "--neutral-percentile"),
    _c("capture-missing-video", "capture {d}/nope.mp4 --out {out}/cap.csv", "nope.mp4"),
    _c("capture-out-ext", "capture {video} --out {out}/cap.txt", ".txt"),
    _c("capture-out-unwritable", "capture {video} --out {ro}/cap.csv", "cap.csv"),
    _c("capture-existing-out", "capture {video} --out {out}/old.csv --duration 0", "--duration",
       existing="{out}/old.csv"),
    # ---- appearance fit / encode
    _c("appearance-width-small", "appearance fit {video} --out {out}/app.npz --width 4", "--width"),
    _c("appearance-variance", "appearance fit {video} --out {out}/app.npz --shape-variance 0", "--shape-variance"),
    _c("appearance-texture-variance", "appearance fit {video} --out {out}/app.npz --texture-variance 1.5",
       "--texture-variance"),
    _c("appearance-missing-video", "appearance fit {d}/nope.mp4 --out {out}/app.npz", "nope.mp4"),
    _c("appearance-out-ext", "appearance fit {video} --out {out}/app.csv", ".csv"),
    _c("appearance-width-memory", "appearance fit {realvideo} --out {out}/app.npz --width 100000", "available",
       needs="video"),
    _c("encode-missing-model", "appearance encode {video} --model {d}/nope.npz --out {out}/enc.npz", "nope.npz"),
    _c("encode-out-is-input", "appearance encode {video} --model {model} --out {model}", "input"),
    _c("encode-max-frames", "appearance encode {video} --model {model} --out {out}/enc.npz --max-frames -1",
       "--max-frames"),
    # ---- style fit / restyle
    _c("style-one-take", "style fit --take neutral={take} --out {out}/style.npz", "at least 2"),
    _c("style-missing-take", "style fit --take neutral={take} --take angry={d}/nope.csv --out {out}/style.npz",
       "nope.csv"),
    _c("style-out-ext", _FIT + " --out {out}/style.csv", ".csv"),
    _c("style-out-is-input", _FIT + " --out {take}", "take.csv"),
    _c("style-out-unwritable", _FIT + " --out {ro}/style.npz", "style.npz"),
    _c("style-variance", _FIT + " --variance 2 --out {out}/style.npz", "--variance"),
    _c("style-bundle", _FIT + " --bundle 0 --out {out}/style.npz", "--bundle"),
    _c("style-reference", _FIT + " --reference happy --out {out}/style.npz", "--reference"),
    _c("style-speakers-mixed", "style fit --take M030:neutral={video} --take angry={video} --out {out}/style.npz",
       "name the speaker of every take"),
    _c("style-speakers-no-neutral", "style fit --take M030:angry={video} --take M030:happy={video} "
       "--out {out}/style.npz", "'neutral' take"),
    _c("style-speakers-not-video", "style fit --take M030:neutral={take} --take M030:angry={take2} "
       "--out {out}/style.npz", "videos"),
    _c("style-speakers-twice", "style fit --take M030:neutral={video} --take M030:neutral={video} "
       "--out {out}/style.npz", "twice"),
    _c("style-speakers-space", "style fit --take M030:neutral={video} --take M030:angry={video} --space pixels "
       "--out {out}/style.npz", "--space"),
    _c("restyle-amount-huge", _RESTYLE + " --amount 1e30 --out {out}/rs.csv", "--amount"),
    _c("restyle-amount-nan", _RESTYLE + " --amount nan --out {out}/rs.csv", "--amount"),
    _c("restyle-window", _RESTYLE + " --window 0 --out {out}/rs.csv", "--window"),
    _c("restyle-margin", _RESTYLE + " --margin -1 --out {out}/rs.csv", "--margin"),
    _c("restyle-missing-model", "restyle --model {d}/nope.npz --performance {take} --to angry --out {out}/rs.csv",
       "nope.npz"),
    _c("restyle-out-ext", _RESTYLE + " --out {out}/rs.txt", ".txt"),
    _c("restyle-out-is-input", _RESTYLE + " --out {take}", "input"),
    _c("restyle-existing-out", _RESTYLE + " --amount 4 --out {out}/old.csv", "--amount", existing="{out}/old.csv"),
    _c("restyle-video-missing-appearance", "restyle --video {video} --appearance {d}/nope.npz --to angry "
       "--out {out}/rv.mp4", "nope.npz"),
    _c("restyle-video-no-appearance", "restyle --video {video} --to angry --out {out}/rv.mp4", "--appearance"),
    _c("restyle-video-and-take", _RESTYLE + " --video {video} --out {out}/rv.mp4", "not allowed"),
    _c("restyle-video-out-ext", "restyle --video {video} --appearance {model} --to angry --out {out}/rv.csv", ".csv"),
    _c("restyle-video-out-is-input", "restyle --video {video} --appearance {model} --to angry --out {video}", "input"),
    _c("restyle-video-feather", "restyle --video {video} --appearance {model} --to angry --feather 2 "
       "--out {out}/rv.mp4", "--feather"),
    _c("restyle-video-missing-speakers", "restyle --video {video} --appearance {model} --speakers {d}/nope.npz "
       "--to angry --out {out}/rv.mp4", "nope.npz"),
    _c("restyle-video-neutral-without-speakers", "restyle --video {video} --appearance {model} --neutral-video "
       "{video} --to angry --out {out}/rv.mp4", "--neutral-video"),
    _c("appearance-fit-one-take", "appearance fit --take neutral={video} --out {out}/app.npz", "at least 2 styles"),
    # ---- headmotion build / synth
    _c("build-pause-negative", _BUILD + " --pause -1 --out {out}/db.npz", "--pause"),
    _c("build-pause-long", _BUILD + " --pause 6 --out {out}/db.npz", "--pause"),
    _c("build-fps", _BUILD + " --fps 0 --out {out}/db.npz", "--fps"),
    _c("build-f0", _BUILD + " --f0-min 500 --f0-max 60 --out {out}/db.npz", "--f0-min"),
    _c("build-missing-motion", "headmotion build --take {wav} {d}/nope.bvh --out {out}/db.npz", "nope.bvh"),
    _c("build-out-ext", _BUILD + " --out {out}/db.txt", ".txt"),
    _c("build-out-missing-folder", _BUILD + " --out {missing}/db.npz", "missing"),
    _c("synth-amplitude-huge", _SYNTH + " --amplitude 1e30 --out {out}/h.bvh", "--amplitude"),
    _c("synth-amplitude-negative", _SYNTH + " --amplitude -1 --out {out}/h.bvh", "--amplitude"),
    _c("synth-motion-range-negative", _SYNTH + " --motion-range 20 -1 8 --out {out}/h.bvh", "--motion-range"),
    _c("synth-motion-range-two", _SYNTH + " --motion-range 20 10 --out {out}/h.bvh", "--motion-range"),
    _c("synth-fps", _SYNTH + " --fps 0 --out {out}/h.bvh", "--fps"),
    _c("synth-seed", _SYNTH + " --seed -3 --out {out}/h.bvh", "--seed"),
    _c("synth-missing-db", "headmotion synth --db {d}/nope.npz --audio {wav} --out {out}/h.bvh", "nope.npz"),
    _c("synth-out-ext", _SYNTH + " --out {out}/h.txt", ".txt"),
    _c("synth-out-unwritable", _SYNTH + " --out {ro}/h.bvh", "h.bvh"),
    _c("synth-nothing", _SYNTH + " --no-rotation --no-translation --out {out}/h.bvh", "nothing to write"),
    _c("synth-existing-out", _SYNTH + " --amplitude 11 --out {out}/old.bvh", "--amplitude", existing="{out}/old.bvh"),
    # ---- the output is checked before the inputs are even read (the junk take would fail later)
    _c("clone-out-before-reading", "clone --source-rig {ada} --target-rig {bo} --keys arkit --performance {junk} "
       "--out {ro}/c.glb", "c.glb"),
    _c("clone-bake-before-reading", "clone --source-rig {ada} --target-rig {bo} --keys arkit --performance {junk} "
       "--bake --out {out}/c.npz", "USD"),
    _c("retarget-out-before-reading", "retarget --performance {junk} --source-keys {ada} --target-keys {bo} "
       "--source-rig {ada} --out {missing}/r.glb", "missing"),
    _c("select-out-before-reading", "keys select --performance {junk} --source-rig {ada} --out {ro}/sel", "sel"),
    _c("build-out-before-reading", "headmotion build --take {wav} {bvh} --out {ro}/db.npz", "db.npz"),
    _c("restyle-out-before-reading", "restyle --model {model} --performance {junk} --to angry --out {ro}/rs.csv",
       "rs.csv"),
    _c("style-out-before-reading", "style fit --take neutral={junk} --take angry={take2} --out {ro}/style.npz",
       "style.npz"),
    _c("synth-out-before-reading", "headmotion synth --db {db} --audio {wav} --out {ro}/h.bvh", "h.bvh"),
    # ---- batch: the jobs file is checked before any cluster starts (a CSV is not TOML)
    _c("batch-missing-jobs", "batch {d}/nope.toml", "nope.toml"),
    _c("batch-not-toml", "batch {take}", "not a valid TOML"),
    _c("batch-workers", "batch {take} --workers 0", "--workers"),
    _c("batch-scheduler-and-workers", "batch {take} --workers 2 --scheduler tcp://127.0.0.1:1", "--scheduler"),
    # ---- demo and the parser itself
    _c("demo-out-is-file", "demo --out {take}", "take.csv"),
    _c("demo-out-under-file", "demo --out {take}/demo", "take.csv"),
    _c("demo-out-unwritable", "demo --out {ro}/demo", "demo"),
    _c("unknown-command", "transmogrify --out {out}/x.glb", "transmogrify"),
    _c("missing-required", "clone --performance {take}", "--out"),
    _c("not-a-number", _SYNTH + " --amplitude loud --out {out}/h.bvh", "--amplitude"),
)


# ---------------------------------------------------------------------------------------- inputs
def _write_wav(path: Path, seconds: float = 0.5, rate: int = 16000) -> None:
    n = int(seconds * rate)
    with wave.open(str(path), "wb") as w:
        w.setnchannels(1)
        w.setsampwidth(2)
        w.setframerate(rate)
        w.writeframes(bytes(2 * n))


def _unwritable(d: Path) -> Path:
    """A folder no file can be created in: a read-only folder, or (as root, who may write anywhere
    the mode bits forbid) ``/sys``."""
    if hasattr(os, "geteuid") and os.geteuid() != 0:
        ro = d / "readonly"
        ro.mkdir(exist_ok=True)
        ro.chmod(0o555)
        return ro
    return Path("/sys")


def make_inputs(d: Path) -> dict[str, str]:
    """Write the small inputs of the table into folder ``d``; returns the placeholder -> path map."""
    from faceretarget.datasets import make_demo_character, make_demo_take
    from faceretarget.io import write_livelinkface, write_rig

    d = Path(d)
    names = ["jawOpen", "mouthSmileLeft", "mouthSmileRight", "eyeBlinkLeft", "eyeBlinkRight", "browInnerUp"]
    for who in ("ada", "bo"):
        rig = make_demo_character(who)
        write_rig(rig, d / who)
        (d / who / "landmarks68.txt").write_text(" ".join(map(str, rig.landmarks)))
        write_rig(rig.subset(names), d / f"{who}_keys")
        (d / f"{who}_keys" / "landmarks68.txt").write_text(" ".join(map(str, rig.landmarks)))
    shutil.copytree(d / "ada_keys", d / "noneutral")
    for f in (d / "noneutral").glob("neutral*"):
        f.unlink()
    write_livelinkface(d / "take.csv", make_demo_take(seconds=1.0, fps=30.0, seed=4))
    write_livelinkface(d / "take2.csv", make_demo_take(seconds=1.0, fps=30.0, seed=5))
    _write_wav(d / "speech.wav")
    (d / "junk.csv").write_text("not,a,take\n1,2\n")       # fails when read: the output must fail first
    (d / "motion.bvh").write_text("HIERARCHY\n")            # never read: every case fails before
    (d / "clip.mp4").write_bytes(b"\x00\x00\x00\x18ftypmp42" + bytes(64))
    (d / "model.npz").write_bytes(b"PK\x05\x06" + bytes(18))
    (d / "db.npz").write_bytes(b"PK\x05\x06" + bytes(18))
    from faceretarget.io import write_glb

    ada = make_demo_character("ada")
    write_glb(d / "ada.glb", ada, [[0.0] * ada.n_shapes], [0.0])     # a character file (never read: the checks fail first)
    _write_body(d / "body.c3d")
    (d / "out").mkdir()
    real = DATA / "emotion-video" / "mead" / "M030_front_angry_level3_001.mp4"
    return {"d": str(d), "out": str(d / "out"), "missing": str(d / "missing"), "ro": str(_unwritable(d)),
            "ada": str(d / "ada"), "bo": str(d / "bo"), "ada_keys": str(d / "ada_keys"),
            "bo_keys": str(d / "bo_keys"), "noneutral": str(d / "noneutral"), "take": str(d / "take.csv"),
            "take2": str(d / "take2.csv"), "junk": str(d / "junk.csv"), "wav": str(d / "speech.wav"), "bvh": str(d / "motion.bvh"),
            "video": str(d / "clip.mp4"), "model": str(d / "model.npz"), "db": str(d / "db.npz"),
            "realvideo": str(real), "glb": str(d / "ada.glb"), "body": str(d / "body.c3d")}


def _write_body(path: Path) -> None:
    """A full-body marker take (Plug-in Gait labels, 1.7 m tall, walking 1 m): 'not a face'."""
    import numpy as np

    from faceretarget.io import write_c3d
    from faceretarget.performance import Performance

    labels = ["LFHD", "RFHD", "C7", "LSHO", "RSHO", "LASI", "RASI", "LKNE", "RKNE", "LANK", "RANK", "LTOE", "RTOE"]
    height = np.array([1650, 1650, 1450, 1400, 1400, 950, 950, 500, 500, 80, 80, 20, 20], float)
    side = np.array([-80, 80, 0, -180, 180, -120, 120, -100, 100, -100, 100, -100, 100], float)
    rest = np.stack([side, height, np.zeros(len(labels))], axis=1)
    walk = np.linspace(0, 1000, 30)[:, None, None] * np.array([0.0, 0.0, 1.0])
    write_c3d(path, Performance.from_points(rest[None] + walk, labels, fps=30.0, unit="mm"))


def missing_need(case: Case, paths: dict[str, str]) -> str | None:
    """Why ``case`` cannot run here (a reason to skip), or None."""
    if case.needs == "video":
        if not Path(paths["realvideo"]).is_file():
            return f"shared data not found ({paths['realvideo']}; set FACERETARGET_DATA)"
        try:
            import av  # noqa: F401
        except ImportError:
            return "PyAV not installed (pip install 'faceretarget[video]')"
    return None


# ---------------------------------------------------------------------------------------- checks
def _tree(d: Path) -> dict[str, tuple[int, int, bytes]]:
    """Every file and folder under ``d``: (mtime_ns, size, first bytes)."""
    out = {}
    for p in sorted(d.rglob("*")):
        st = p.lstat()
        head = p.read_bytes()[:256] if p.is_file() else b""
        out[str(p.relative_to(d))] = (st.st_mtime_ns, st.st_size, head)
    return out


def check_case(case: Case, paths: dict[str, str]) -> list[str]:
    """Run ``case`` in-process (``faceretarget.cli.main``); the list of what went wrong (empty: passed)."""
    from faceretarget.cli import main

    argv = [a.format(**paths) for a in case.argv]
    d = Path(paths["d"])
    existing = Path(case.existing.format(**paths)) if case.existing else None
    if existing is not None:
        existing.write_bytes(b"an earlier output\n")
        os.utime(existing, ns=(1_000_000_000_000_000_000, 1_000_000_000_000_000_000))
        before_bytes, before_mtime = existing.read_bytes(), existing.stat().st_mtime_ns
    before = _tree(d)
    out, err = io.StringIO(), io.StringIO()
    problems = []
    t0 = time.perf_counter()
    try:
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            rc = main(argv)
    except BaseException as e:  # noqa: BLE001 - anything escaping main is a failure of the case
        rc = None
        problems.append(f"{type(e).__name__} escaped main: {e}")
    seconds = time.perf_counter() - t0
    lines = err.getvalue().strip().splitlines()
    if rc != 2:
        problems.append(f"exit code {rc}, expected 2")
    if len(lines) != 1 or not lines[0].startswith("faceretarget: error:"):
        problems.append(f"stderr is not one 'faceretarget: error:' line: {err.getvalue()!r}")
    elif case.expect not in lines[0]:
        problems.append(f"the error line does not name {case.expect!r}: {lines[0]!r}")
    both = out.getvalue() + err.getvalue()
    if "Traceback" in both or "Warning:" in both:
        problems.append(f"a traceback or a raw warning was printed: {both!r}")
    after = _tree(d)
    if after != before:
        new = sorted(set(after) - set(before))
        changed = sorted(k for k in before if k in after and after[k] != before[k])
        problems.append(f"the folder changed: new {new}, changed {changed}")
    if existing is not None:
        if not existing.exists() or existing.read_bytes() != before_bytes or existing.stat().st_mtime_ns != before_mtime:
            problems.append(f"the existing output {existing.name} was changed")
        existing.unlink(missing_ok=True)
    if seconds > 20:
        problems.append(f"took {seconds:.1f} s before refusing")
    return problems


def run_cli_cases(folder: str | os.PathLike | None = None) -> dict:
    """Run the whole table; ``{"cases": n, "failures": k, "failed": [(name, problems), ...], "skipped": m}``."""
    with tempfile.TemporaryDirectory(prefix="fr_cli_cases_", dir=folder) as tmp:
        paths = make_inputs(Path(tmp))
        failed, skipped, n = [], 0, 0
        for case in CASES:
            if missing_need(case, paths):
                skipped += 1
                continue
            n += 1
            problems = check_case(case, paths)
            if problems:
                failed.append((case.name, problems))
        ro = Path(paths["ro"])
        if ro.parent == Path(tmp):
            ro.chmod(0o755)
    return {"cases": n, "failures": len(failed), "failed": failed, "skipped": skipped}


def main(argv=None) -> int:
    import argparse

    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--json", action="store_true", help="print one JSON object as the last line")
    args = p.parse_args(argv)
    t0 = time.perf_counter()
    res = run_cli_cases()
    for name, problems in res["failed"]:
        print(f"FAIL {name}: {'; '.join(problems)}")
    print(f"{res['cases']} cases, {res['failures']} failed, {res['skipped']} skipped "
          f"({time.perf_counter() - t0:.1f} s)")
    if args.json:
        print(json.dumps(res))
    return 1 if res["failures"] else 0


if __name__ == "__main__":
    sys.exit(main())
