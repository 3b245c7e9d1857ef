"""Emotion editing on real faces (issue 15, protocol P6): performer-aware settings, the capped kernel
correction, progress of ``style fit``, and the P6 pipeline on two real MEAD speakers."""

from __future__ import annotations

import sys
import warnings
from pathlib import Path

import numpy as np
import pytest

from faceretarget.errors import InvalidDataError
from faceretarget.style import StyleModel, _select, group_folds, kernel_fit, kernel_rows

REPO = Path(__file__).resolve().parents[1]


def _two_performers(rng, n=80, P=12):
    """Two performers' aligned (neutral, angry) point frames: shared content, own rest faces and
    own emotion offsets (the second one's weaker)."""
    t = np.linspace(0, 4 * np.pi, n)
    rest = rng.normal(size=(P, 3))
    content = np.stack([np.sin(t), np.cos(1.3 * t), np.sin(0.7 * t)], 1) @ rng.normal(size=(3, P * 3))
    off = rng.normal(size=P * 3)
    frames = {"neutral": [], "angry": []}
    for k, scale in enumerate((1.0, 0.6)):
        base = rest.ravel() + 0.3 * k + content
        frames["neutral"].append(base)
        frames["angry"].append(base + scale * off + 0.05 * content)
    return ({s: np.concatenate(v).reshape(-1, P, 3) for s, v in frames.items()},
            np.repeat(["a", "b"], n))


def test_group_folds_leave_one_performer_out():
    g = np.array(["a", "a", "b", "c", "b"])
    folds = group_folds(g, 5)
    assert [va.tolist() for _, va in folds] == [[0, 1], [2, 4], [3]]
    assert [tr.tolist() for tr, _ in folds] == [[2, 3, 4], [0, 1, 3], [0, 1, 2, 4]]
    with pytest.raises(InvalidDataError, match="one label per aligned frame"):
        group_folds(g, 4)


def test_settings_are_chosen_by_leaving_a_performer_out():
    frames, groups = _two_performers(np.random.default_rng(0))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        m = StyleModel().fit_frames(frames, groups=groups)
        blocks = StyleModel().fit_frames(frames)
    assert (m.selection_.folds, m.selection_.gap) == (2, 0)          # one fold per performer
    assert blocks.selection_.folds == 5
    with pytest.raises(InvalidDataError, match="one label per aligned frame"):
        StyleModel().fit_frames(frames, groups=groups[:-1])


def test_kernel_correction_uses_evenly_spaced_frames_of_long_takes():
    rng = np.random.default_rng(1)
    n = _select.KERNEL_FRAMES + 300
    Y = rng.normal(size=(n, 4))
    R = np.sin(Y @ rng.normal(size=(4, 2)))
    keep = kernel_rows(n)
    assert len(keep) == _select.KERNEL_FRAMES and keep[0] == 0 and keep[-1] == n - 1
    assert np.all(np.diff(keep) >= 1) and np.all(np.diff(keep) <= 2)
    assert np.array_equal(kernel_rows(50), np.arange(50))
    Ys, h, alpha = kernel_fit(Y, R, 3.0, 0.1)
    Ys2, h2, alpha2 = kernel_fit(Y[keep], R[keep], 3.0, 0.1)
    assert np.array_equal(Ys, Ys2) and h == h2 and np.allclose(alpha, alpha2, rtol=0, atol=1e-12)


def test_style_fit_progress_bar_changes_nothing(capsys):
    frames, _ = _two_performers(np.random.default_rng(2), n=60)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        quiet = StyleModel().fit_frames(frames)
        shown = StyleModel(progress=True).fit_frames(frames)
    err = capsys.readouterr().err
    assert "style fit" in err and "settings" in err
    assert quiet.settings_ == shown.settings_
    x = frames["neutral"][:10]
    assert np.array_equal(quiet.known(x, "neutral", "angry", warn=False).frames,
                          shown.known(x, "neutral", "angry", warn=False).frames)


@pytest.fixture(scope="module")
def p6(data_dir, tmp_path_factory):
    """P6 on the three shared speakers (MEAD M030, W009 without audio; CREMA-D 1001 with audio), their
    neutral, angry, happy and sad clips, leave one speaker out: issue 15's model (``landmarks``, as
    acted) and the default speaker-independent one."""
    from conftest import require_data

    if not require_data():
        pytest.importorskip("mediapipe")
    clips = data_dir / "emotion-video"
    if not clips.is_dir():
        pytest.fail(f"{clips} missing") if require_data() else pytest.skip(f"{clips} missing")
    sys.path.insert(0, str(REPO / "bench"))
    try:
        import emotion_video as ev
    finally:
        sys.path.remove(str(REPO / "bench"))
    sp = ev.load_speakers(clips, tmp_path_factory.mktemp("captures"), ["1001", "M030", "W009"], log=lambda *_: None,
                          emotions=("angry", "happy", "sad"))
    frames, can, aligned = ev.normalise_and_align(sp, log=lambda *_: None)
    scores = {s: {e: w.mean(0) for e, w in d["scores"].items()} for s, d in sp.items()}
    train_of = {t: [s for s in frames if s != t] for t in frames}
    cands = {k: ev.CANDIDATES[k] for k in ("landmarks", ev.DEFAULT)}
    res = ev.evaluate(frames, scores, train_of, log=lambda *_: None, aligned=aligned, can=can, candidates=cands)
    return ev, frames, res, ev.summarise(res)


# slow: its fixture fits P6's speaker models leave-one-speaker-out over 19 real takes (~28 s, once per module)
def test_p6_translation_and_recognition_on_three_real_speakers(p6):
    ev, frames, res, summ = p6
    for d in frames.values():                                    # every take on the neutral's timeline
        assert {e: v.shape for e, v in d.items()} == {e: d["neutral"].shape for e in d}
    base = {(r["speaker"], r["emotion"]): r for r in res["baselines"]}
    assert set(base) == {(s, e) for s in ("1001", "M030", "W009") for e in ("angry", "happy", "sad")}
    for r in base.values():
        # the speaker's own mean offset is the best any constant edit can do; the models cannot see it
        assert r["own_offset_rel_err"] < r["additive_rel_err"]
        # the thesis's plain model extrapolates from one or two training speakers: worse than no edit on every
        # take (measured 1.14-59.8 with the captures smoothed both ways; 1.2 and more when they lagged)
        assert r["plain_rel_err"] > 1.0
    assert np.median([r["plain_rel_err"] for r in base.values()]) > 2.0          # measured 2.58
    old, new = summ["landmarks"], summ[ev.DEFAULT]
    # gains chosen on held-out training speakers: sad is not shared (measured 0.04-0.2), anger and
    # happiness more (0.38-0.75)
    for m in new["models"].values():
        assert m["gain_source"] == {e: "held-out speakers" for e in ("angry", "happy", "sad")}
        assert m["gain"]["sad"] < 0.25 < 0.35 < min(m["gain"]["angry"], m["gain"]["happy"])
        assert max(m["gain"].values()) <= 1.0
    # issue 15's model is worse than the additive offset (measured 1.048; sad 1.089); the speaker-
    # independent one better (0.958; sad 0.749, angry 0.985, happy 1.011)
    assert old["translation_mean_ratio"] > 1.0
    assert new["translation_mean_ratio"] < 0.98
    assert new["translation"]["sad"]["ratio"] < 0.8 and new["worst_emotion_ratio"] < 1.05
    rec = new["recognition"]                                      # measured 6 of 9
    assert len(rec) == 9
    assert sum(r["model"] == r["emotion"] for r in rec) >= 5
