"""P1 metrics against hand-computed values, the oracle blend, capture noise and the ground truth."""

from __future__ import annotations

import numpy as np
import pytest

from faceretarget.datasets import ArkitPairing, add_capture_noise, keymodels_from_weights, rig_animation
from faceretarget.errors import InvalidDataError
from faceretarget.mesh import Mesh
from faceretarget.metrics import (
    err_pct,
    err_pct_axis,
    lip_vertices,
    lve_mm,
    metrics,
    mve_mm,
    mve_pct_diag,
    oracle_blend,
    oracle_rel_motion_pct,
    rel_motion_pct,
)
from faceretarget.rig import Rig

# ---------------------------------------------------------------- a tiny case computed by hand
# neutral: two vertices; ground truth: 2 frames; prediction off by known vectors.
N0 = np.array([[1.0, 0.0, 0.0], [0.0, 2.0, 0.0]])
GT = np.array([
    [[1.0, 0.0, 3.0], [0.0, 2.0, 0.0]],  # vertex 0 moved by 3 (|v| = sqrt(10)), vertex 1 still (|v| = 2)
    [[4.0, 0.0, 0.0], [0.0, 6.0, 0.0]],  # vertex 0 moved by 3 (|v| = 4), vertex 1 by 4 (|v| = 6)
])
ERR = np.array([
    [[0.0, 0.0, 1.0], [0.0, 0.0, 0.0]],  # frame 0: error 1 on vertex 0
    [[3.0, 4.0, 0.0], [0.0, -2.0, 0.0]],  # frame 1: errors 5 and 2
])
PRED = GT + ERR


def test_rel_motion_pct_by_hand():
    # errors 1 + 0 + 5 + 2 = 8 over motion 3 + 0 + 3 + 4 = 10
    assert rel_motion_pct(PRED, GT, N0) == pytest.approx(80.0)
    assert rel_motion_pct(GT, GT, N0) == 0.0
    # predicting the neutral gets all the motion wrong
    assert rel_motion_pct(np.broadcast_to(N0, GT.shape), GT, N0) == pytest.approx(100.0)
    # a still ground truth: 0 when exact, inf otherwise
    still = np.broadcast_to(N0, GT.shape)
    assert rel_motion_pct(still, still, N0) == 0.0
    assert rel_motion_pct(PRED, still, N0) == float("inf")


def test_err_pct_by_hand():
    f0 = 1.0 / (np.sqrt(10.0) + 2.0)
    f1 = 7.0 / (4.0 + 6.0)
    assert err_pct(PRED, GT) == pytest.approx((f0 + f1) / 2 * 100)
    # per axis: |dx| / sum |x|, mean over frames
    x = (0 / 1 + 3 / 4) / 2 * 100
    y = (0 / 2 + (4 + 2) / 6) / 2 * 100
    assert err_pct_axis(PRED, GT, 0) == pytest.approx(x)
    assert err_pct_axis(PRED, GT, 1) == pytest.approx(y)
    # z: frame 1 has z == 0 everywhere (0/0), so frame 0 alone
    assert err_pct_axis(PRED[:1], GT[:1], 2) == pytest.approx(1 / 3 * 100)
    with pytest.raises(InvalidDataError):
        err_pct_axis(PRED, GT, 3)


def test_distances_by_hand():
    # mean distance (1 + 0 + 5 + 2) / 4 = 2 units
    assert mve_mm(PRED, GT, "cm") == pytest.approx(20.0)
    assert mve_mm(PRED, GT, "m") == pytest.approx(2000.0)
    assert mve_mm(PRED, GT, 1.0) == pytest.approx(2.0)
    # bbox diagonal of the neutral: |(1, 2, 0) - 0| ... min (0, 0, 0), max (1, 2, 0) -> sqrt(5)
    assert mve_pct_diag(PRED, GT, N0) == pytest.approx(2.0 / np.sqrt(5.0) * 100)
    # largest lip error per frame: lips = both vertices -> (1 + 5) / 2; vertex 1 only -> (0 + 2) / 2
    assert lve_mm(PRED, GT, "mm", lips=[0, 1]) == pytest.approx(3.0)
    assert lve_mm(PRED, GT, "cm", lips=[1]) == pytest.approx(10.0)
    with pytest.raises(InvalidDataError):
        lve_mm(PRED, GT, "mm")  # no lips and no rig
    with pytest.raises(InvalidDataError):
        mve_mm(PRED, GT, "furlong")


def test_single_frame_and_shape_checks():
    assert rel_motion_pct(PRED[1], GT[1], N0) == pytest.approx(7.0 / 7.0 * 100)
    with pytest.raises(InvalidDataError):
        rel_motion_pct(PRED[:, :1], GT, N0)
    with pytest.raises(InvalidDataError):
        rel_motion_pct(PRED, GT, N0[:1])


def _tiny_rig(landmarks=None) -> Rig:
    V = 70
    rng = np.random.default_rng(3)
    neutral = Mesh(rng.normal(size=(V, 3)))
    names = ["browInnerUp_L", "browInnerUp_R", "jawLeft", "cheekRaiser_L", "eyeBlink_L"]
    deltas = rng.normal(size=(len(names), V, 3))
    return Rig(neutral, names, deltas, unit="cm", landmarks=landmarks, name="tiny")


def test_metrics_dict_with_rig():
    rig = _tiny_rig(landmarks=np.arange(68))
    rng = np.random.default_rng(0)
    gt = rig.evaluate(rng.uniform(size=(5, rig.n_shapes)))
    pred = gt + rng.normal(scale=0.01, size=gt.shape)
    m = metrics(pred, gt, rig.neutral, rig)
    assert set(m) == {"rel_motion_pct", "err_pct", "err_pct_x", "err_pct_y", "err_pct_z", "mve_mm",
                      "mve_pct_diag", "lve_mm"}
    assert m["rel_motion_pct"] == pytest.approx(rel_motion_pct(pred, gt, rig.neutral.vertices))
    assert m["mve_mm"] == pytest.approx(mve_mm(pred, gt, 10.0))
    assert m["lve_mm"] == pytest.approx(lve_mm(pred, gt, "cm", lips=np.arange(48, 68)))
    np.testing.assert_array_equal(lip_vertices(rig), np.arange(48, 68))
    # the Rig as neutral supplies the unit; plain arrays without lips give NaN lve
    assert metrics(pred, gt, rig)["mve_mm"] == pytest.approx(m["mve_mm"])
    assert np.isnan(metrics(pred, gt, rig.neutral.vertices, "cm")["lve_mm"])
    # with target keys the oracle is included and is a floor
    keys = rig.neutral.vertices + rig.deltas
    m2 = metrics(pred, gt, rig.neutral, rig, target_keys=keys)
    assert m2["oracle_rel_motion_pct"] == pytest.approx(0.0, abs=1e-8)


def test_oracle_exact_in_span_and_a_floor():
    rng = np.random.default_rng(1)
    V, N, T = 40, 6, 25
    n0 = rng.normal(size=(V, 3))
    keys = n0 + rng.normal(size=(N, V, 3))
    keys = np.concatenate([n0[None], keys])  # a neutral among the keys is harmless
    w = rng.normal(size=(T, N + 1))
    gt = n0 + np.einsum("tn,nvj->tvj", w, keys - n0)
    pred, wf = oracle_blend(gt, keys, n0, return_weights=True)
    np.testing.assert_allclose(pred, gt, atol=1e-10)
    assert wf.shape == (T, N + 1)
    assert oracle_rel_motion_pct(gt, keys, n0) < 1e-8
    # out of span: the oracle equals per-frame least squares and beats any other blend
    gt2 = gt + rng.normal(scale=0.3, size=gt.shape)
    pred2 = oracle_blend(gt2, keys, n0)
    D = (keys - n0).reshape(N + 1, -1)
    w3 = np.linalg.lstsq(D.T, (gt2[3] - n0).ravel(), rcond=None)[0]
    np.testing.assert_allclose(pred2[3], n0 + (w3 @ D).reshape(V, 3), atol=1e-10)
    other = n0 + np.einsum("tn,nvj->tvj", w + rng.normal(scale=0.1, size=w.shape), keys - n0)
    assert np.linalg.norm(pred2 - gt2) < np.linalg.norm(other - gt2)
    with pytest.raises(InvalidDataError):
        oracle_blend(gt, keys[:, :5], n0)


def test_capture_noise_deterministic_and_scaled():
    pts = np.zeros((400, 68, 3))
    a = add_capture_noise(pts, 0.5, "cm", seed=7)
    b = add_capture_noise(pts, 0.5, "cm", seed=7)
    c = add_capture_noise(pts, 0.5, "cm", seed=8)
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, c)
    assert a.std() == pytest.approx(0.05, rel=0.02)  # 0.5 mm in centimetres
    assert add_capture_noise(pts, 0.5, "m", seed=7).std() == pytest.approx(0.0005, rel=0.02)
    np.testing.assert_array_equal(add_capture_noise(pts, 0.0, "cm"), pts)
    with pytest.raises(InvalidDataError):
        add_capture_noise(pts, -1.0, "cm")


def test_rig_animation_name_map():
    rig = _tiny_rig()
    # Live Link Face spelling; a whole browInnerUp drives both halves, jawLeft is a direction,
    # TongueOut is not in the rig (dropped), cheekRaiser gets 0
    names = ["BrowInnerUp", "JawLeft", "TongueOut", "EyeBlinkLeft"]
    w = np.array([[0.5, 0.25, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]])
    got = rig_animation(rig, names, w)
    d = rig.deltas
    want0 = rig.neutral.vertices + 0.5 * d[rig.index("browInnerUpLeft")] \
        + 0.5 * d[rig.index("browInnerUpRight")] + 0.25 * d[rig.index("jawLeft")]
    np.testing.assert_allclose(got[0], want0)
    np.testing.assert_allclose(got[1], rig.neutral.vertices + d[rig.index("eyeBlinkLeft")])
    U = np.eye(4)
    keys = keymodels_from_weights(rig, names, U)
    assert keys.shape == (4, rig.n_vertices, 3)
    np.testing.assert_allclose(keys[2], rig.neutral.vertices)  # tongueOut alone: the neutral
    with pytest.raises(InvalidDataError):
        rig_animation(rig, names, w[:, :3])


def _llf_weights(path, rows):
    """The 52 ARKit weight curves of the first ``rows`` rows of a Live Link Face CSV."""
    from faceretarget.io import read_livelinkface

    take = read_livelinkface(path).slice(0, rows)
    return take.names, take.weights


def test_arkit_pairing_on_real_rigs(data_dir, ict_rig, arkit_rig):
    names, w = _llf_weights(data_dir / "livelinkface" / "S07-001.csv", 300)
    assert w.shape == (300, 52)
    pair = ArkitPairing(ict_rig, arkit_rig)
    A, B = pair.animations(names, w)
    assert A.shape == (300, ict_rig.n_vertices, 3) and B.shape == (300, arkit_rig.n_vertices, 3)
    # the "arkit" key set (neutral + each shape at 1) spans every frame: the oracle is exact
    U = np.vstack([np.zeros(52), np.eye(52)])
    sk, tk = pair.keymodels(names, U)
    assert sk.shape == (53, ict_rig.n_vertices, 3) and tk.shape == (53, arkit_rig.n_vertices, 3)
    assert oracle_rel_motion_pct(B, tk, arkit_rig.neutral) < 1e-8
    assert oracle_rel_motion_pct(A, sk, ict_rig.neutral) < 1e-8
    # ICT splits browInnerUp: a whole ARKit weight drives both halves equally
    k = names.index("browInnerUp")   # the reader gives ARKit camelCase names
    lo, hi = ict_rig.index("browInnerUpLeft"), ict_rig.index("browInnerUpRight")
    np.testing.assert_allclose(sk[1 + k], ict_rig.neutral.vertices + ict_rig.deltas[lo] + ict_rig.deltas[hi])
    # a few emotions-style keys: the oracle is a floor between 0 and 100 %
    rng = np.random.default_rng(0)
    U6 = np.clip(rng.uniform(-0.5, 1.0, size=(6, 52)), 0, 1)
    _, tk6 = pair.keymodels(names, U6)
    floor = oracle_rel_motion_pct(B, tk6, arkit_rig.neutral)
    assert 0.0 < floor < 100.0
    m = metrics(B, B, arkit_rig.neutral, arkit_rig)
    assert m["rel_motion_pct"] == 0.0 and m["lve_mm"] == 0.0
    swapped = pair.swapped()
    assert swapped.source is arkit_rig and swapped.target is ict_rig


def test_a_printed_figure_says_what_it_means_what_is_good_and_what_to_do():
    """Issue 34: one style for every number a command prints."""
    from faceretarget.metrics import FIGURES, figure_line

    ok = figure_line("rel_motion", 12.0)
    assert ok == ("motion error 12.0 %: the share of the true motion that is wrong (0 is perfect, 100 as far off as "
                  "a face that does not move); good under 30 %")
    bad = figure_line("rel_motion", 45.0, "add key-models")
    assert bad.endswith("good under 30 %, so not good: add key-models")
    assert "so not good: check the character's landmarks" in figure_line("mouth_corr", 0.5)
    assert "so not good" not in figure_line("mouth_corr", 0.95)                 # higher is better there
    for f in FIGURES.values():
        assert f.meaning and f.advice and np.isfinite(f.bound)
        line = f.line(f.bound)
        assert "\n" not in line and "so not good" not in line                  # the bound itself is good
