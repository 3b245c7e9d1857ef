"""Emotion on a speaker the model has never seen (issue 27): ``style.SpeakerStyleModel`` learns style
models from several speakers in a space that does not depend on who is speaking.

Synthetic speakers (:func:`speakers`) share an emotion's direction but act it at different
intensities, have their own faces (size, rotation, position) and one emotion they do not agree on;
the real speakers of protocol P6 are in ``tests/test_emotion_video.py``.
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from faceretarget.errors import InvalidDataError, NotFittedError
from faceretarget.names import ARKIT_NAMES
from faceretarget.performance import Performance
from faceretarget.style import SpeakerStyleModel, align_speaker_takes, canonical_face

FAST = {"variance": 0.9999, "energy": 0.9999, "prior": 10.0, "local": 0}
SCORES = list(ARKIT_NAMES[:12])


def _rot(a: float) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def speakers(intensity=None, C=60, seed=0, face=None):
    """``{speaker: {style: Performance}}``, aligned: 68 points and 12 scores per frame.

    Every speaker says the same content (speech motion of the mouth and jaw) in ``neutral``,
    ``angry`` (one direction, each speaker at their own intensity) and ``sad`` (a direction of each
    speaker's own, as unrelated as P6's speakers' sad).  ``face[s] = (scale, angle)``: the speaker's
    face size and in-plane rotation.
    """
    rng = np.random.default_rng(99)
    base = rng.normal(0, 30, (68, 3))
    t = np.arange(C) / 25.0
    content = np.stack([np.sin(2 * np.pi * 1.3 * t), np.cos(2 * np.pi * 0.7 * t), np.sin(2 * np.pi * 2.1 * t)], 1)
    speech = rng.normal(0, 1, (3, 68, 3))
    speech[:, :48] *= 0.1                                              # the mouth and jaw move most
    angry = rng.normal(0, 1, (68, 3))
    M = rng.normal(0, 0.02, (len(SCORES), 68 * 3))                     # what the tracker's scores see
    intensity = intensity or {"A": 1.0, "B": 0.35, "C": 0.7, "D": 0.5}
    face = face or {"A": (1.0, 0.0), "B": (1.2, 0.1), "C": (0.9, -0.15), "D": (1.05, 0.05)}
    r = np.random.default_rng(seed)
    out = {}
    for i, (s, k) in enumerate(intensity.items()):
        scale, ang = face[s]
        ident = base + r.normal(0, 2, (68, 3))
        sad = np.random.default_rng(100 + i).normal(0, 1, (68, 3))
        d = {}
        for st, off in (("neutral", 0.0), ("angry", k * 3.0 * (angry + 0.3 * r.normal(0, 1, (68, 3)))),
                        ("sad", 2.0 * sad)):
            disp = np.einsum("tc,cpj->tpj", content, speech) * 2.0 + off + r.normal(0, 0.05, (C, 68, 3))
            pts = scale * (ident + disp) @ _rot(ang).T + [5.0 * i, -3.0, 1.0]
            sc = 0.2 + disp.reshape(C, -1) @ M.T
            d[st] = Performance(t, 25.0, points=pts, labels=[f"lm{j}" for j in range(68)], unit="mm",
                                weights=sc, names=SCORES, source=f"{s}_{st}")
        out[s] = d
    return out


def _to_canonical(pts, can, rest):
    from faceretarget.numerics import similarity_fit

    s, R, _ = similarity_fit(can, rest[None])
    return (pts - rest) @ R[0] / s[0]


def _rel(pred, real, neu):
    return float(np.sqrt(np.sum((pred - real) ** 2) / np.sum((real - neu) ** 2)))


def _fit(train, **kw):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return SpeakerStyleModel(style=FAST, **kw).fit(train, aligned=True)


@pytest.fixture(scope="module")
def data():
    return speakers()


def test_calibrated_direction_space_beats_the_additive_offset_on_a_new_speaker(data):
    train = {s: data[s] for s in ("A", "B", "C")}
    test = data["D"]
    n = test["neutral"]
    m = _fit(train)
    keep = _fit(train, intensity="keep", calibrate=False)
    # the speakers agree on angry (gain near 1) and not on sad (gain near 0), from held-out speakers only
    assert m.gain_source_ == {"angry": "held-out speakers", "sad": "held-out speakers"}
    assert m.gain_["angry"] > 0.8 and m.gain_["sad"] < 0.3
    assert keep.gain_ == {"angry": 1.0, "sad": 1.0}
    # typical intensity: the mean of the speakers' offset sizes, each speaker's own size kept
    k = {s: m.speaker_intensity_[s]["angry"] for s in train}
    assert m.intensity_["angry"] == pytest.approx(np.mean(list(k.values())))
    assert k["B"] / k["A"] == pytest.approx(0.35, rel=0.1)
    # translation of the new speaker's neutral take, errors in one canonical frame
    can = canonical_face({s: np.median(d["neutral"].points, 0) for s, d in data.items()})
    rests = {s: np.median(d["neutral"].points, 0) for s, d in data.items()}
    neu = _to_canonical(n.points, can, rests["D"])
    res = {}
    for e in ("angry", "sad"):
        real = _to_canonical(test[e].points, can, rests["D"])
        add = np.mean([np.mean(_to_canonical(train[s][e].points - train[s]["neutral"].points + rests[s], can,
                                             rests[s]), 0) for s in train], 0)
        res[e] = {"additive": _rel(neu + add, real, neu),
                  "model": _rel(_to_canonical(m.transform(n, e).frames, can, rests["D"]), real, neu),
                  "keep": _rel(_to_canonical(keep.transform(n, e).frames, can, rests["D"]), real, neu)}
    # sad: the mean offset of speakers who disagree adds error (measured 1.19, the model as acted the
    # same); the calibrated model leaves it unedited (1.00).  angry: D acts at 0.5, the others at 1.0,
    # 0.35 and 0.7; the calibrated model comes closer (0.49) than their mean offset (0.54)
    assert res["sad"]["additive"] > 1.1 and res["sad"]["keep"] > 1.1
    assert res["sad"]["model"] < 1.02
    assert res["angry"]["model"] < 0.95 * res["angry"]["additive"]
    assert np.mean([res[e]["model"] / res[e]["additive"] for e in res]) < 0.9


def test_amount_is_the_same_on_every_face(data):
    m = _fit({s: data[s] for s in ("A", "B", "C")}, space="landmarks")
    n = data["D"]["neutral"]
    r1 = m.transform(n, "angry")
    d1 = r1.frames - n.points
    # amount 0 returns the take, amount 2 doubles the change
    assert np.array_equal(m.transform(n, "angry", 0.0).frames, n.points)
    np.testing.assert_allclose(m.transform(n, "angry", 2.0).frames - n.points, 2 * d1, atol=1e-9)
    # the same speaker filmed closer and tilted: the same edit, scaled and rotated with the face
    R = _rot(0.3)
    moved = n.with_points(1.7 * n.points @ R.T + 4.0)
    d2 = m.transform(moved, "angry").frames - moved.points
    np.testing.assert_allclose(d2, 1.7 * d1 @ R.T, atol=1e-6 * np.abs(d2).max())
    # the edit's size in the space is gain x the typical intensity of what the speakers share
    size = np.linalg.norm(m.change(n, "angry")[0].mean(0))
    assert 0.5 * m.gain_["angry"] * m.intensity_["angry"] < size < 1.2 * m.intensity_["angry"]


@pytest.mark.parametrize("space", ["landmarks", "range", "arkit", "both"])
def test_recognises_a_new_speakers_weak_emotion(data, space):
    m = _fit({s: data[s] for s in ("A", "C", "D")}, space=space)
    weak = data["B"]                                                   # acts angry at 0.35
    r = m.recognise(weak["angry"], weak["neutral"])
    assert r.style == "angry" and r.ranking[0] == "angry"
    assert r.unexplained["angry"] < 0.5 < r.unexplained["sad"] <= 1.0
    # its intensity, estimated from the take itself, against the others' typical (1.0, 0.7, 0.5)
    assert r.intensity["angry"] == pytest.approx(0.35 / np.mean([1.0, 0.7, 0.5]), rel=0.25)
    assert m.recognise(weak["neutral"], weak["neutral"]).style == "neutral"
    if space in ("arkit", "both"):                                    # the edit carries the scores too
        e = m.transform(weak["neutral"], "angry")
        assert e.take.weights.shape == weak["neutral"].weights.shape
        assert not np.array_equal(e.take.weights, weak["neutral"].weights)
        assert e.take.weights.min() >= 0 and e.take.weights.max() <= 1


def test_the_command_line_offers_every_space():
    from faceretarget.cli._style import SPACES as CLI_SPACES
    from faceretarget.style import SPACES

    assert CLI_SPACES == SPACES and SpeakerStyleModel().space == SPACES[0]


def test_arkit_decoder_ridge_chosen_by_held_out_speakers(data):
    m = _fit({s: data[s] for s in ("A", "B", "C")}, space="arkit")
    assert m.decoder_ridge_ in (1e-2, 1e-1, 1.0, 10.0)
    assert m.decoder_.shape == (len(SCORES), 204)
    fixed = _fit({s: data[s] for s in ("A", "B", "C")}, space="arkit", decoder_ridge=1.0)
    assert fixed.decoder_ridge_ == 1.0


def test_one_emotion_of_one_speaker_takes_the_median_gain(data):
    train = {s: dict(data[s]) for s in ("A", "B", "C")}
    train["A"]["happy"] = train["A"]["angry"].replace(points=train["A"]["angry"].points[::-1].copy())
    m = _fit(train)
    assert m.gain_source_["happy"] == "median of the other emotions"
    assert m.gain_["happy"] == pytest.approx(np.median([m.gain_["angry"], m.gain_["sad"]]))
    assert m.styles_ == ["neutral", "angry", "sad", "happy"]


def test_save_load_gives_identical_edits(tmp_path, data):
    m = _fit({s: data[s] for s in ("A", "B")}, space="both")
    path = m.save(tmp_path / "speakers.npz")
    m2 = SpeakerStyleModel.load(path)
    n = data["C"]["neutral"]
    assert np.array_equal(m.transform(n, "angry", 1.3).frames, m2.transform(n, "angry", 1.3).frames)
    assert m.recognise(data["C"]["sad"], n) == m2.recognise(data["C"]["sad"], n)
    assert m2.gain_ == m.gain_ and m2.gain_source_["angry"] == "held-out speakers"


def test_bad_input_names_the_speaker_and_style(data):
    with pytest.raises(NotFittedError):
        SpeakerStyleModel().transform(data["A"]["neutral"], "angry")
    with pytest.raises(InvalidDataError, match="space must be one of"):
        SpeakerStyleModel(space="pixels").fit(data, aligned=True)
    with pytest.raises(InvalidDataError, match="speaker 'A': needs a 'neutral' take"):
        SpeakerStyleModel().fit({"A": {"angry": data["A"]["angry"]}}, aligned=True)
    bad = {"A": {"neutral": data["A"]["neutral"], "angry": data["A"]["angry"].slice(0, 30)}}
    with pytest.raises(InvalidDataError, match="speaker 'A': aligned takes differ in length"):
        SpeakerStyleModel().fit(bad, aligned=True)
    no_scores = {s: {e: Performance(p.times, p.fps, points=p.points, labels=p.labels, source=p.source)
                     for e, p in d.items()} for s, d in data.items()}
    with pytest.raises(InvalidDataError, match="speaker 'A', neutral: this space needs the tracker's ARKit scores"):
        SpeakerStyleModel(space="arkit").fit(no_scores, aligned=True)
    m = _fit({s: data[s] for s in ("A", "B")})
    with pytest.raises(InvalidDataError, match="unknown target style 'happy'"):
        m.transform(data["C"]["neutral"], "happy")
    flat = Performance.from_points(np.zeros((5, 10, 3)), [f"p{i}" for i in range(10)], fps=25.0, source="ten.c3d")
    with pytest.raises(InvalidDataError, match="ten.c3d.*68 face points"):
        m.transform(flat, "angry")


def test_unaligned_takes_are_aligned_per_speaker(data):
    # a speaker's angry take played 20 % slower: aligned back onto the neutral timeline by face features
    d = data["A"]
    slow_t = d["angry"].times * 1.2
    slow = Performance(slow_t, 25.0 / 1.2, points=d["angry"].points, labels=d["angry"].labels,
                       weights=d["angry"].weights, names=d["angry"].names, source="A_angry_slow")
    al = align_speaker_takes({"A": {"neutral": d["neutral"], "angry": slow}}, realign=0)
    assert al["A"]["angry"].n_frames == d["neutral"].n_frames
    np.testing.assert_allclose(al["A"]["angry"].points[5:-5], d["angry"].points[5:-5], atol=0.5)
    np.testing.assert_allclose(al["A"]["angry"].weights[5:-5], d["angry"].weights[5:-5], atol=0.05)


def test_an_emotional_take_goes_back_through_neutral(data):
    m = _fit({s: data[s] for s in ("A", "B", "C")})
    d = data["D"]
    off = lambda p: np.linalg.norm((p - d["neutral"].points).mean(0))  # noqa: E731
    back = m.transform(d["angry"], "neutral", source="angry", neutral=d["neutral"]).frames
    assert off(back) < 0.6 * off(d["angry"].points)                   # measured 22.5 -> 10.3
    # angry -> sad: back to neutral by the angry model, then sad at its (near 0) gain
    to_sad = m.transform(d["angry"], "sad", source="angry", neutral=d["neutral"]).frames
    assert np.allclose(to_sad, back, atol=0.2 * off(d["angry"].points))
