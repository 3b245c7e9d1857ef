"""Pyun Sec. 3-4 and the package's cloning methods, with real numbers."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from faceretarget.cloning import (
    CardinalBasis,
    ExpressionCloner,
    FeaturePCA,
    cubic_bspline,
    keymodel_pair,
)
from faceretarget.datasets import add_capture_noise, make_demo_character, make_demo_take
from faceretarget.errors import FitWarning, SingularKeysError, TopologyError
from faceretarget.io import read_livelinkface
from faceretarget.metrics import err_pct, rel_motion_pct
from faceretarget.numerics import EXAMPLE_RANGE, denoise_take, estimate_noise_sigma, pca_extrema
from faceretarget.rig import Rig


@pytest.fixture(scope="module")
def demo():
    ada, bo = make_demo_character("ada"), make_demo_character("bo")
    take = make_demo_take(seconds=4.0, fps=30.0, seed=3)
    rom = make_demo_take(seconds=30.0, fps=30.0, seed=11)
    return ada, bo, take, rom


def _anim(rig, take):
    return rig.evaluate(rig.map_weights(take.names, take.weights, warn=False))


def test_cubic_bspline_shape():
    x = np.array([0.0, 0.5, 1.0, 1.5, 2.0, 2.5, -1.0])
    b = cubic_bspline(x)
    assert b[0] == pytest.approx(1.0)
    assert b[2] == pytest.approx(0.25)          # (4 - 6 + 3) / 4
    assert b[4] == 0.0 and b[5] == 0.0
    assert b[6] == b[2]
    # C1 and C2 continuity at the knot |x| = 1
    e = 1e-6
    left = cubic_bspline(np.array([1 - 2 * e, 1 - e, 1.0]))
    right = cubic_bspline(np.array([1.0, 1 + e, 1 + 2 * e]))
    assert (left[2] - left[1]) / e == pytest.approx((right[1] - right[0]) / e, abs=1e-4)


def test_cardinal_basis_is_cardinal_and_partition_of_unity():
    rng = np.random.default_rng(0)
    P = rng.normal(size=(12, 3))
    b = CardinalBasis().fit(P)
    np.testing.assert_allclose(b.transform(P), np.eye(12), atol=1e-9)
    Q = rng.normal(size=(50, 3))
    np.testing.assert_allclose(b.transform(Q).sum(axis=1), 1.0, atol=1e-9)
    # the linear part alone reproduces affine functions of p exactly
    lin = CardinalBasis(radial=False).fit(P)
    f = P @ np.array([1.0, -2.0, 0.5]) + 3.0
    np.testing.assert_allclose(lin.transform(Q) @ f, Q @ np.array([1.0, -2.0, 0.5]) + 3.0, atol=1e-9)


def test_cardinal_basis_names_duplicate_examples():
    P = np.array([[0.0, 0], [1, 0], [1, 0], [0, 1]])
    with pytest.raises(SingularKeysError, match="'b' and 'c'"):
        CardinalBasis().fit(P, ["a", "b", "c", "d"])


def test_feature_pca_threshold():
    rng = np.random.default_rng(1)
    X = rng.normal(size=(20, 3)) @ rng.normal(size=(3, 30))      # rank 3 in 30 dims
    pca = FeaturePCA(eig_threshold=1e-6).fit(X)
    assert pca.n_components == 3
    assert FeaturePCA(eig_threshold=0.9).fit(X).n_components == 1


@pytest.mark.parametrize("method", ["pyun", "linear", "temporal"])
def test_arkit_keys_clone_exactly(demo, method):
    ada, bo, take, _ = demo
    sk, tk, _ = keymodel_pair(ada, bo, "arkit")
    assert sk.n_shapes == 52
    c = ExpressionCloner(method, features="all").fit(sk, tk)
    pred = c.blend(c.transform(_anim(ada, take), take.times).weights)
    truth = _anim(bo, take)
    if method == "pyun":
        # the paper's PCA drops axes below 1e-6 of the largest eigenvalue (two of the demo rig's 52),
        # so it is close but not exact here; the full-span methods are exact
        assert c.pca_.n_components == 50
        assert err_pct(pred, truth) <= 1e-2
    else:
        assert err_pct(pred, truth) <= 1e-6
        assert rel_motion_pct(pred, truth, bo.neutral.vertices) <= 1e-5


def test_default_beats_pyun_with_capture_noise(demo):
    ada, bo, take, rom = demo
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        sk, tk, _ = keymodel_pair(ada, bo, "rom-20", rom=rom)
        truth = _anim(bo, take)
        noisy = add_capture_noise(_anim(ada, take)[:, ada.landmarks], 0.5, "cm", seed=0)
        errs = {}
        for m in ("pyun", "linear", "temporal"):
            c = ExpressionCloner(m).fit(sk, tk)
            res = c.transform(noisy, take.times)
            errs[m] = rel_motion_pct(c.blend(res.weights), truth, bo.neutral.vertices)
    # measured: pyun ~52 %, linear ~59 %, temporal ~19 % on the demo characters
    assert errs["temporal"] < 0.6 * errs["pyun"]
    assert errs["temporal"] < 0.6 * errs["linear"]
    assert res.noise_sigma * 10 == pytest.approx(0.5, rel=0.25)   # estimated noise, in mm


def test_streaming_matches_batch(demo):
    ada, bo, take, rom = demo
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        sk, tk, _ = keymodel_pair(ada, bo, "rom-20", rom=rom)
        for method in ("linear", "pyun"):
            c = ExpressionCloner(method).fit(sk, tk)
            src = _anim(ada, take)[:20]
            batch = c.blend(c.transform(src).weights)
            stream = np.stack([c.stream_frame(f) for f in src])
            np.testing.assert_allclose(stream, batch, atol=1e-9)


def test_duplicate_key_models_are_named(demo):
    ada, bo, _, _ = demo
    d = ada.deltas[[ada.index("jawOpen"), ada.index("jawOpen"), ada.index("eyeBlinkLeft")]]
    sk = Rig(ada.neutral, ["open", "open2", "blink"], d, ada.unit, ada.landmarks)
    tk = Rig(bo.neutral, ["open", "open2", "blink"], bo.deltas[[0, 1, 2]], bo.unit, bo.landmarks)
    with pytest.raises(SingularKeysError, match="'open' and 'open2'"):
        ExpressionCloner().fit(sk, tk)


def test_outside_score_flags_uncovered_motion(demo):
    ada, bo, take, _ = demo
    names = ["jawOpen", "mouthSmileLeft", "mouthSmileRight"]
    sk, tk = ada.subset(names), bo.subset(names)
    c = ExpressionCloner("linear").fit(sk, tk)
    frames = np.stack([ada.neutral.vertices + ada.deltas[ada.index("jawOpen")],
                       ada.neutral.vertices + ada.deltas[ada.index("browInnerUp")]])
    with pytest.warns(FitWarning, match="outside the key-models"):
        res = c.transform(frames)
    assert res.outside[0] < 1e-9
    assert res.outside[1] > 0.5


def test_wrong_frame_size_is_named(demo):
    ada, bo, _, _ = demo
    c = ExpressionCloner("linear").fit(ada.subset(["jawOpen"]), bo.subset(["jawOpen"]))
    with pytest.raises(TopologyError, match="123 points"):
        c.transform(np.zeros((2, 123, 3)))


def test_save_load_round_trip(tmp_path, demo):
    ada, bo, take, rom = demo
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        sk, tk, _ = keymodel_pair(ada, bo, "rom-10", rom=rom)
        for method in ("pyun", "temporal"):
            c = ExpressionCloner(method).fit(sk, tk)
            c.save(tmp_path / f"{method}.npz")
            c2 = ExpressionCloner.load(tmp_path / f"{method}.npz")
            assert c2.target_keys_.names == c.target_keys_.names
            np.testing.assert_allclose(c2.target_keys_.deltas, c.target_keys_.deltas)
            src = _anim(ada, take)
            np.testing.assert_allclose(c2.blend(c2.transform(src, take.times).weights), c.blend(c.transform(src, take.times).weights),
                                       atol=1e-10)


def test_noise_estimate_and_denoising():
    rng = np.random.default_rng(5)
    t = np.arange(600) / 30.0
    clean = np.stack([np.sin(2 * np.pi * f * t + p) for f, p in [(0.3, 0), (0.8, 1), (1.7, 2), (0.5, 3)]], 1)
    assert estimate_noise_sigma(clean) == 0.0            # a clean take shows no noise floor
    noisy = clean + rng.normal(0, 0.2, clean.shape)
    assert estimate_noise_sigma(noisy) == pytest.approx(0.2, rel=0.15)
    den, s = denoise_take(noisy, t)
    assert np.sqrt(((den - clean) ** 2).mean()) < 0.5 * np.sqrt(((noisy - clean) ** 2).mean())
    # dropped frames: uneven times are handled and the output keeps the input's frames
    keep = np.setdiff1d(np.arange(600), np.arange(100, 130))
    den2, _ = denoise_take(noisy[keep], t[keep])
    assert den2.shape == (570, 4)
    assert np.sqrt(((den2 - clean[keep]) ** 2).mean()) < 0.5 * 0.2


def test_pca_extrema_picks_axis_extremes():
    rng = np.random.default_rng(2)
    X = rng.normal(size=(300, 2)) * [5.0, 1.0]
    idx = pca_extrema(X, 4)
    assert len(set(idx.tolist())) == 4
    assert int(np.argmax(X[:, 0])) in idx and int(np.argmin(X[:, 0])) in idx


# ----------------------------------------------------------------------------- real rigs (P1)
@pytest.fixture(scope="module")
def real(ict_rig, arkit_rig, data_dir):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        take = read_livelinkface(data_dir / "livelinkface" / "S07-001.csv")
        rom = read_livelinkface(data_dir / "livelinkface" / "alex_rom_3.csv")
    return ict_rig, arkit_rig, take, rom


# slow: self, cross and round-trip cloning of 51 real ARKit keys on full meshes (~6 s)
def test_real_arkit_keys_exact_self_cross_roundtrip(real):
    ict, ark, take, _ = real
    A, B = _anim(ict, take), _anim(ark, take)
    A, B, take = A[:400], B[:400], take.slice(0, 400)
    for method in ("pyun", "temporal"):
        sk, tk, _ = keymodel_pair(ict, ark, "arkit")
        c = ExpressionCloner(method, features="all").fit(sk, tk)
        cross = c.blend(c.transform(A, take.times).weights)
        assert err_pct(cross, B) <= 1e-4
        sk2, tk2, _ = keymodel_pair(ark, ict, "arkit")
        back = ExpressionCloner(method, features="all").fit(sk2, tk2)
        rt = back.blend(back.transform(cross, take.times).weights)
        assert err_pct(rt, A) <= 1e-4
        ss, st, _ = keymodel_pair(ict, ict, "arkit")
        selfc = ExpressionCloner(method, features="all").fit(ss, st)
        assert err_pct(selfc.blend(selfc.transform(A, take.times).weights), A) <= 1e-4


def test_real_rom40_landmarks_out_of_sample(real):
    """P1 rom-40, ICT -> ARKit, landmark features, the whole S07 take, clean and with 0.5 mm noise:
    every weight inside the default example range, and the motion within the issue-12 target."""
    ict, ark, take, rom = real
    sk, tk, _ = keymodel_pair(ict, ark, "rom-40", rom=rom)
    A, B = _anim(ict, take), _anim(ark, take)
    L = A[:, ict.landmarks]
    noisy = add_capture_noise(L, 0.5, ict.unit, seed=0)
    res, lo, hi = {}, np.inf, -np.inf
    for m in ("pyun", "temporal"):
        c = ExpressionCloner(m).fit(sk, tk)
        assert c.weight_range_ == EXAMPLE_RANGE
        for i, x in enumerate((L, noisy)):
            W = c.transform(x, take.times).weights
            lo, hi = min(lo, W.min()), max(hi, W.max())
            res[m, i] = rel_motion_pct(c.blend(W), B, ark.neutral.vertices)
    assert EXAMPLE_RANGE[0] <= lo and hi <= EXAMPLE_RANGE[1]
    # whole-take bench numbers: pyun 3.6 / 50 %, temporal 3.1 / 8.7 % (clean / noisy)
    assert res["temporal", 0] < 5 and res["temporal", 0] < res["pyun", 0]
    assert res["temporal", 1] < 10 and res["temporal", 1] < 0.5 * res["pyun", 1]
    free = ExpressionCloner(weight_range=None).fit(sk, tk).transform(L, take.times).weights
    assert np.abs(free).max() > 2.5          # unconstrained, the ROM keys cancel large weights


def test_long_takes_are_denoised_in_overlapping_windows():
    """A take longer than one window is denoised window by window (bounded memory, linear time) and
    comes out as clean as in one piece; windows join without a step."""
    rng = np.random.default_rng(3)
    T = 6000
    t = np.arange(T) / 60.0
    clean = np.stack([np.sin(2 * np.pi * f * t + p) for f, p in rng.uniform(0.1, 1.5, (6, 2))], axis=1)
    noisy = clean + rng.normal(0, 0.05, clean.shape)
    whole, s_whole = denoise_take(noisy, t, chunk=10**6)
    parts, s_parts = denoise_take(noisy, t, chunk=1500, overlap=200)
    e_whole = np.sqrt(np.mean((whole - clean) ** 2))
    e_parts = np.sqrt(np.mean((parts - clean) ** 2))
    assert s_parts == pytest.approx(s_whole) and s_whole == pytest.approx(0.05, rel=0.2)
    assert e_parts < 1.1 * e_whole and e_whole < 0.35 * 0.05       # measured: 0.0151 and 0.0147
    seams = np.abs(np.diff(parts - clean, axis=0)).max()
    assert seams < 4 * np.abs(np.diff(whole - clean, axis=0)).max()
    # a take of one window is exactly the one-piece result
    short = noisy[:1000]
    np.testing.assert_array_equal(denoise_take(short, t[:1000])[0], denoise_take(short, t[:1000], chunk=1000)[0])
