"""Style/content models, alignment and expression sliders (faceretarget.style, Chuang 2004 Ch. 2, 5)."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from faceretarget.errors import InvalidDataError
from faceretarget.io import read_audio as read_wav
from faceretarget.style import (
    AlphaCurves,
    AsymmetricBilinearModel,
    BilinearModel,
    ExpressionSliders,
    PiecewiseWarp,
    StyleFitWarning,
    StyleModel,
    StyleRangeWarning,
    SymmetricBilinearModel,
    align_audio,
    align_features,
    bundle_frames,
    choose_dims,
    face_features,
    time_warp_audio,
    unbundle_frames,
)


# ------------------------------------------------------------------------------------------ helpers
def _orth_angle(a: np.ndarray, b: np.ndarray) -> float:
    """Largest sine of the principal angles between the column spans of a and b."""
    qa, qb = np.linalg.qr(a)[0], np.linalg.qr(b)[0]
    s = np.linalg.svd(qa.T @ qb, compute_uv=False)
    return float(np.sqrt(max(0.0, 1.0 - s.min() ** 2)))


def _bilinear_frames(S=5, C=80, D=30, J=4, seed=0, C_test=40):
    """Frames x_sc = M_s b_c with b_c = [1, random]: exactly bilinear (offsets included)."""
    rng = np.random.default_rng(seed)
    M = rng.standard_normal((S, D, J))
    b = np.c_[np.ones(C + C_test), rng.standard_normal((C + C_test, J - 1))]
    X = np.einsum("sdj,cj->scd", M, b)
    return X[:, :C], X[:, C:], M, b


# ------------------------------------------------------------------------------------------ models
def test_asymmetric_reconstructs_exact_bilinear_data_with_right_J():
    rng = np.random.default_rng(1)
    S, K, J, C = 4, 10, 5, 60
    A = rng.standard_normal((S, K, J))
    B = rng.standard_normal((J, C))
    Y = np.einsum("skj,jc->sck", A, B)
    m = AsymmetricBilinearModel(energy=0.9999).fit(Y, ["a", "b", "c", "d"])
    assert m.content_dims_ == J
    rec = np.einsum("skj,cj->sck", m.style_matrices_, m.content_vectors_)
    assert np.abs(rec - Y).max() < 1e-8
    # Eq. 2.10 / 2.11 on new content: exact, with and without the content prior
    bn = rng.standard_normal((7, J))
    y0, y2 = bn @ A[0].T, bn @ A[2].T
    for prior in (False, True):
        assert np.abs(m.translate(y0, "a", "c", prior=prior) - y2).max() < 1e-6
    assert choose_dims(np.array([3.0, 2.0, 1.0, 1e-9]), 0.999, 4) == 3
    assert choose_dims(np.array([100.0, 2.0, 1.0, 1e-9]), 0.999, 4, keep_first=1) == 3


def test_symmetric_recovers_factors_and_objective_decreases():
    rng = np.random.default_rng(2)
    S, C, K, I, J = 6, 50, 12, 3, 4
    a = rng.standard_normal((S, I))
    b = rng.standard_normal((C, J))
    W = rng.standard_normal((I, J, K))
    Y = np.einsum("si,ijk,cj->sck", a, W, b)
    for init in ("svd", 0, 1):
        m = SymmetricBilinearModel(energy=0.99999, tol=1e-15, max_iter=300, init=init).fit(Y)
        assert (m.style_dims_, m.content_dims_) == (I, J)
        obj = m.objective_
        assert np.all(np.diff(obj) <= 1e-10 * np.sum(Y**2)), obj      # monotone non-increasing
        assert obj[-1] < 1e-16 * np.sum(Y**2)
        # factors up to the model's invariances (an invertible map of each factor space)
        assert _orth_angle(m.style_vectors_, a) < 1e-6
        assert _orth_angle(m.content_vectors_, b) < 1e-6
        assert m.rmse_ < 1e-8
    # from a random start the alternation takes several iterations, each lowering the error
    m = SymmetricBilinearModel(style_dims=2, content_dims=3, tol=1e-14, max_iter=100, init=3).fit(Y)
    assert m.n_iter_ >= 3 and np.all(np.diff(m.objective_) <= 1e-12 * np.sum(Y**2))


def test_tasks_recover_truth_on_synthetic_bilinear_data():
    train, test, M, b = _bilinear_frames()
    styles = ["s0", "s1", "s2", "s3"]
    model = StyleModel().fit_frames({s: train[i] for i, s in enumerate(styles)})
    assert model.asymmetric_.content_dims_ == 4
    scale = np.abs(test).max()
    # known expression s0 -> s3
    r = model.known(test[0], "s0", "s3", warn=False)
    assert np.abs(r.frames - test[3]).max() < 1e-6 * scale and not r.range.outside
    # unknown expression: input in s2 (not told), rendered in s1; the style is found
    u = model.unknown(test[2], "s1", warn=False)
    assert np.abs(u.frames - test[1]).max() < 1e-4 * scale
    assert np.all(u.inferred.nearest == 2)
    np.testing.assert_allclose(u.style_weights.mean(0), [0, 0, 1, 0], atol=1e-4)
    # untrained expression s4 (moves the face outside the training PCA basis), fitted from examples
    model.add_style("s4", train[4], like=("s0", train[0]))
    assert model.n_components_ > 12
    r4 = model.known(test[0], "s0", "s4", warn=False)
    assert np.abs(r4.frames - test[4]).max() < 1e-5 * scale
    # the symmetric model got a dimension of its own for the new style
    assert model.symmetric_.style_dims_ == model.symmetric_.core_.shape[0] == 5


def test_unknown_expression_windows_and_first_component_guard():
    train, test, _, _ = _bilinear_frames(seed=3)
    model = StyleModel(local=0).fit_frames({f"s{i}": train[i] for i in range(4)})
    mixed = np.concatenate([test[1][:20], test[3][20:]])          # the style changes half way
    u = model.unknown(mixed, "s0", window=10, warn=False)
    assert list(u.inferred.nearest[:20]) == [1] * 20 and list(u.inferred.nearest[20:]) == [3] * 20
    truth = np.concatenate([test[0][:20], test[0][20:]])
    assert np.abs(u.frames - truth).max() < 1e-4 * np.abs(truth).max()
    assert u.inferred.history[-1] <= u.inferred.history[0]


def test_bundles_round_trip_and_bundled_model():
    Y = np.random.default_rng(4).standard_normal((20, 3))
    Yb = bundle_frames(Y, 4)
    assert Yb.shape == (17, 12)
    np.testing.assert_allclose(unbundle_frames(Yb, 4), Y)
    train, test, _, _ = _bilinear_frames(seed=5)
    model = StyleModel(bundle=3).fit_frames({f"s{i}": train[i] for i in range(3)})
    r = model.known(test[0], "s0", "s2", warn=False)
    assert r.frames.shape == test[0].shape
    assert np.abs(r.frames - test[2]).max() < 1e-5 * np.abs(test).max()


def test_interpolation_endpoints_and_range_guard():
    train, test, _, _ = _bilinear_frames(seed=6)
    model = StyleModel().fit_frames({f"s{i}": train[i] for i in range(4)})
    x = test[0]
    r0 = model.known(x, "s0", "s2", amount=0.0, warn=False)
    r1 = model.known(x, "s0", "s2", amount=1.0, warn=False)
    scale = np.abs(test).max()
    assert np.abs(r0.frames - test[0]).max() < 1e-6 * scale
    assert np.abs(r1.frames - test[2]).max() < 1e-6 * scale
    half = model.known(x, "s0", "s2", amount=0.5, warn=False)
    np.testing.assert_allclose(half.frames, 0.5 * (test[0] + test[2]), atol=1e-6 * scale)
    assert not r1.range.outside
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        big = model.known(x, "s0", "s2", amount=6.0)
    assert big.range.outside and big.range.score > big.range.margin
    assert any(issubclass(c.category, StyleRangeWarning) for c in caught)
    # the asymmetric model's Eq. 2.15 itself
    A = model.asymmetric_
    bq = A.content(model.encode(x), "s0")
    np.testing.assert_allclose(A.interpolate(bq, "s0", "s2", 0.0), A.render(bq, "s0"))
    np.testing.assert_allclose(A.interpolate(bq, "s0", "s2", 1.0), A.render(bq, "s2"))


def test_save_load_round_trip(tmp_path):
    train, test, _, _ = _bilinear_frames(seed=7)
    model = StyleModel().fit_frames({f"s{i}": train[i] for i in range(4)})
    model.add_style("s4", train[4], like=("s1", train[1]))
    p = model.save(tmp_path / "m.npz")
    back = StyleModel.load(p)
    assert back.styles_ == model.styles_ and back.n_components_ == model.n_components_
    for a, b in ((model.known(test[1], "s1", "s4", warn=False), back.known(test[1], "s1", "s4", warn=False)),
                 (model.unknown(test[2], "s0", warn=False), back.unknown(test[2], "s0", warn=False))):
        np.testing.assert_allclose(a.frames, b.frames, rtol=1e-10, atol=1e-10)
        assert a.local == b.local
    for cls, m in ((AsymmetricBilinearModel, model.asymmetric_), (SymmetricBilinearModel, model.symmetric_)):
        q = m.save(tmp_path / f"{cls.kind}.npz")
        m2 = cls.load(q)
        for k, v in vars(m).items():
            if k.endswith("_") and isinstance(v, np.ndarray):
                np.testing.assert_array_equal(getattr(m2, k), v)
        assert type(BilinearModel.load(q)) is cls
    with pytest.raises(Exception, match="holds a SymmetricBilinearModel, not a StyleModel"):
        StyleModel.load(q)
    with pytest.raises(Exception, match="not found"):
        StyleModel.load(tmp_path / "missing.npz")


# ------------------------------------------------------------------------------------------ alignment
def test_dtw_recovers_known_piecewise_warp_on_synthetic_signal():
    fps = 30.0
    t = np.arange(0, 12, 1 / fps)
    rng = np.random.default_rng(8)
    freqs, phases = rng.uniform(0.2, 1.5, (6, 4)), rng.uniform(0, 6.3, (6, 4))

    def signal(tt):
        return np.stack([np.sin(2 * np.pi * freqs[d] * tt[:, None] + phases[d]).sum(1) for d in range(6)], axis=1)

    warp = PiecewiseWarp.from_rates(12.0, [1.0, 0.6, 1.5, 0.8, 1.25])
    tt = np.arange(0, warp.duration, 1 / fps)
    ref, take = signal(t), signal(warp.input_time(tt)) * 1.7 + 0.3        # other amplitude and offset
    al = align_features(face_features(ref), face_features(take), t, tt)
    e = al.errors_ms(warp.output_time(t))
    assert np.median(e) < 1000 / fps and np.percentile(e, 95) < 2.5 * 1000 / fps
    # a Sakoe-Chiba band that contains the truth gives the same answer
    al2 = align_features(face_features(ref), face_features(take), t, tt, window_s=3.0)
    assert np.median(al2.errors_ms(warp.output_time(t))) < 1000 / fps


def test_mfcc_alignment_of_real_speech_retimed_by_known_warp(data_dir):
    x, r = read_wav(sorted((data_dir / "speech" / "libritts").glob("*.wav"))[0])
    warp = PiecewiseWarp.from_rates(len(x) / r, [1.0, 0.7, 1.35, 0.85, 1.2])
    y = time_warp_audio(x, r, warp.input_time, warp.duration)
    assert abs(len(y) / r - warp.duration) < 0.01
    for feat in ("mfcc", "rplp"):
        al = align_audio(x, r, y, r, features=feat)
        e = al.errors_ms(warp.output_time(al.ref_times))
        assert np.median(e) < 33.0, (feat, np.median(e))
    # takes with audio are aligned by it, on their face frames' clock (times not starting at 0)
    from faceretarget.performance import Performance
    from faceretarget.style import align_performances, warp_performance

    t_ref = np.arange(0, len(x) / r, 1 / 30)
    t_take = np.arange(0, warp.duration, 1 / 30)
    pts = lambda tt: np.stack([np.sin(tt), np.cos(2 * tt), tt], axis=1)[:, None, :]  # noqa: E731
    ref = Performance.from_points(pts(t_ref), times=t_ref + 5.0, fps=30, audio=x, audio_rate=r)
    take = Performance.from_points(pts(warp.input_time(t_take)), times=t_take + 2.0, fps=30, audio=y, audio_rate=r)
    al = align_performances(ref, take)
    assert al.by == "mfcc"
    assert np.median(al.errors_ms(warp.output_time(t_ref) + 2.0)) < 33.0
    w = warp_performance(take, al)
    assert w.n_frames == ref.n_frames and np.median(np.abs(w.points - ref.points)) < 0.05


# slow: P3: DTW alignment and bilinear fits over real takes (~7 s)
def test_p3_face_alignment_and_known_expression(data_dir, ict_rig):
    from faceretarget.datasets import make_p3_takes
    from faceretarget.io import read_livelinkface
    from faceretarget.metrics import rel_motion_pct
    from faceretarget.style import (
        align_performances,
        frame_vectors,
        realign_by_style,
        warp_performance,
    )

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        perf = read_livelinkface(data_dir / "livelinkface" / "S07-001.csv")
    p3 = make_p3_takes(ict_rig, perf, ("neutral", "happy", "angry"), duration=30.0)
    ref = p3.takes["neutral"]
    assert p3.takes["angry"].n_frames < ref.n_frames < p3.takes["happy"].n_frames + 200
    aligned = {"neutral": ref.points}
    for s in ("happy", "angry"):
        al = align_performances(ref, p3.takes[s])
        truth = p3.true_take_time(s, "neutral", ref.times)
        assert np.median(al.errors_ms(truth)) < 33.0
        al2 = realign_by_style(ref, p3.takes[s], al)                        # what StyleModel.fit does
        e1, e2 = al.errors_ms(truth), al2.errors_ms(truth)
        assert al2.by == "face+style" and np.median(e2) < 33.0
        assert np.percentile(e2, 95) < 0.8 * np.percentile(e1, 95), (s, np.percentile(e1, 95), np.percentile(e2, 95))
        aligned[s] = frame_vectors(warp_performance(p3.takes[s], al2)).reshape(ref.points.shape)
    n = int(0.6 * ref.n_frames)
    model = StyleModel().fit_frames({s: v[:n] for s, v in aligned.items()})
    gt = p3.truth_on("angry", "neutral", ref.times[n:])
    pred = model.known(ref.points[n:], "neutral", "angry", warn=False).frames
    base = ref.points[n:] + (aligned["angry"][:n] - aligned["neutral"][:n]).mean(0)
    assert any(r["stage"] == 3 for r in model.selection_.table)            # point-local candidates scored
    assert rel_motion_pct(pred, gt, p3.neutral) < 0.7 * rel_motion_pct(base, gt, p3.neutral)


def _local_nonlinear_takes(P=12, C=700, seed=3):
    """Points moving independently; the 'style' change at each point depends nonlinearly on that
    point alone (a bend that only shows when the point is displaced), so no linear map of whole
    frames reproduces it, and the point-local translation can."""
    rng = np.random.default_rng(seed)
    rest = rng.standard_normal((P, 3)) * 3.0
    t = np.arange(C) / 30.0
    f = rng.uniform(0.2, 1.5, (P, 3))
    ph = rng.uniform(0, 2 * np.pi, (P, 3))
    disp = np.sin(2 * np.pi * f[None] * t[:, None, None] + ph[None])          # (C, P, 3), |d| <= 1
    x0 = rest[None] + disp
    bend = np.stack([0.4 * disp[..., 1] ** 2, -0.3 * np.abs(disp[..., 0]), 0.5 * disp[..., 0] * disp[..., 2]], -1)
    x1 = x0 + np.array([0.2, 0.1, -0.1]) + bend
    return x0, x1


def test_point_local_translation_learns_a_local_nonlinear_change(tmp_path):
    from faceretarget.style._pointlocal import fit_point_map, neighbours

    x0, x1 = _local_nonlinear_takes()
    tr, te = slice(0, 500), slice(500, None)
    rest = x0[tr].mean(0)
    nb = neighbours(rest, 3)
    assert nb.shape == (12, 3) and np.all(nb[:, 0] == np.arange(12))
    truth = x1[te] - x0[te]
    err = {}
    for spec in (("points", 1, 0), ("points", 1, 8), ("points", 3, 8)):
        pm = fit_point_map(x0[tr], x1[tr], rest, spec)
        err[spec] = float(np.sqrt(np.mean((pm.predict(x0[te]) - truth) ** 2)))
    additive = float(np.sqrt(np.mean((truth - (x1[tr] - x0[tr]).mean(0)) ** 2)))
    # the bend is even in the displacement: no affine map (of the point or of the frame) sees it
    assert err[("points", 1, 0)] < 1.05 * additive and err[("points", 1, 8)] < 0.3 * additive, (err, additive)
    assert err[("points", 1, 8)] < 0.06

    # the model's selection picks the point-local translation here, and it behaves like a translation
    third = x0 + np.array([0.0, -0.15, 0.05])                                # a third, additive style
    model = StyleModel().fit_frames({"a": x0[tr], "b": x1[tr], "c": third[tr]})
    assert model.settings_["local"][0] == "points"
    assert any(r["stage"] == 3 for r in model.selection_.table)
    r = model.known(x0[te], "a", "b", warn=False)
    assert r.local and r.frames.shape == x0[te].shape
    # the guard sees the edit about as far out as the true frames (independent oscillators leave
    # the training range of the PCA coefficients anyway), and an exaggeration much further
    assert r.range.score < model.range_report(x1[te], warn=False).score + 0.2
    assert model.known(x0[te], "a", "b", amount=4.0, warn=False).range.score > r.range.score + 1.0
    assert np.sqrt(np.mean((r.frames - x1[te]) ** 2)) < 0.05
    np.testing.assert_array_equal(model.known(x0[te], "a", "b", amount=0.0, warn=False).frames, x0[te])
    half = model.known(x0[te], "a", "b", amount=0.5, warn=False).frames
    np.testing.assert_allclose(half, 0.5 * (x0[te] + r.frames), atol=1e-12)
    u = model.unknown(x0[te], "b", window=50, warn=False)
    assert np.all(u.inferred.nearest == 0) and np.sqrt(np.mean((u.frames - x1[te]) ** 2)) < 0.05
    back = StyleModel.load(model.save(tmp_path / "pl.npz"))
    assert back.settings_["local"] == model.settings_["local"]
    np.testing.assert_allclose(back.known(x0[te], "a", "b", warn=False).frames, r.frames, atol=1e-9)
    # an added style is paired with 'a' only: d -> b goes through a
    fourth = x0 + np.array([0.1, 0.0, 0.1])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", StyleFitWarning)
        model.add_style("d", fourth[tr], like=("a", x0[tr]))
    assert model._point_path("d", "b") == ["d", "a", "b"]
    assert np.sqrt(np.mean((model.known(fourth[te], "d", "b", warn=False).frames - x1[te]) ** 2)) < 0.06


def test_point_local_spec_is_validated_and_weights_keep_the_bilinear_path():
    from faceretarget.style._model import _local_spec
    from faceretarget.style._pointlocal import point_count

    assert _local_spec(["points", 3, 8]) == ("points", 3, 8)
    for bad in (("points", 0, 8), ("points", 1, -1), ("points", 1.5, 3), ("points", "x", 3)):
        with pytest.raises(InvalidDataError, match="point-local"):
            _local_spec(bad)
    assert point_count((68, 3)) == 68 and point_count((52,)) is None and point_count((5000, 3)) is None
    from faceretarget.performance import Performance
    from faceretarget.style import align_performances, realign_by_style

    rng = np.random.default_rng(0)
    w = Performance.from_weights(rng.random((40, 3)), ["jawOpen", "mouthClose", "browInnerUp"], fps=30.0,
                                 source="w.csv")
    with pytest.raises(InvalidDataError, match=r"w\.csv.*point takes"):
        realign_by_style(w, w, align_performances(w, w))
    train, test, _, _ = _bilinear_frames(seed=5)                           # flat (weights-like) frames
    model = StyleModel().fit_frames({f"s{i}": train[i] for i in range(4)})
    assert not (isinstance(model.settings_["local"], tuple) and model.settings_["local"][0] == "points")


# ------------------------------------------------------------------------------------------ sliders
def test_sliders_reproduce_single_emotion_and_blend_linearly():
    rng = np.random.default_rng(9)
    N, P = 6, 15
    src = rng.standard_normal((N + 1, P, 3))
    targets = {e: rng.standard_normal((N + 1, 40, 3)) for e in ("neutral", "happy", "angry")}
    sl = ExpressionSliders(upper=1.0).fit(src, targets)
    W = rng.uniform(0, 1, (25, N))
    frames = src[0] + np.einsum("tn,npk->tpk", W, src[1:] - src[0])
    np.testing.assert_allclose(sl.weights(frames), W, atol=1e-8)
    single = sl.retarget(frames, "happy")
    np.testing.assert_allclose(sl.transform(frames, [0.0, 1.0, 0.0]), single, atol=1e-10)
    np.testing.assert_allclose(single, targets["happy"][0] + np.einsum("tn,npk->tpk", W, targets["happy"][1:]
                                                                      - targets["happy"][0]), atol=1e-7)
    mix = sl.transform(frames, [0.0, 0.3, 0.7])
    np.testing.assert_allclose(mix, 0.3 * single + 0.7 * sl.retarget(frames, "angry"), atol=1e-10)
    # alpha curves: barycentric over time, keys interpolated
    times = np.linspace(0, 2, 25)
    curves = AlphaCurves(["neutral", "angry"], {"neutral": 1.0, "angry": [(0.0, 0.0), (2.0, 1.0)]})
    a = curves(times)
    np.testing.assert_allclose(a.sum(1), 1.0)
    out = sl.transform(frames, curves, times)
    w_ang = a[:, 1][:, None, None]
    np.testing.assert_allclose(out, (1 - w_ang) * sl.retarget(frames, "neutral") + w_ang * sl.retarget(frames, "angry"),
                               atol=1e-10)
    with pytest.raises(InvalidDataError):
        sl.transform(frames, [0.0, 0.0, 0.0])
    with pytest.raises(InvalidDataError):
        AlphaCurves(["neutral"], {"angry": 1.0})


# ------------------------------------------------------------------------------------------ CLI
def _cli_main():
    from faceretarget.cli import main

    return main


@pytest.fixture(scope="module")
def takes(tmp_path_factory):
    from faceretarget.cloning import EMOTIONS, weight_vector
    from faceretarget.datasets import StyleWarp, make_demo_character, make_demo_take
    from faceretarget.io import write_livelinkface, write_rig
    from faceretarget.names import ARKIT_NAMES
    from faceretarget.performance import Performance

    d = tmp_path_factory.mktemp("style_cli")
    base = make_demo_take(seconds=8.0, fps=30.0, seed=11)
    names = list(base.names)
    out = {}
    for s, warp in (("neutral", StyleWarp(1.0, 0.0)), ("angry", StyleWarp(1.15, 0.2, 3.0)),
                    ("happy", StyleWarp(0.9, 0.15, 4.0))):
        tau = np.arange(0, warp.style_time(base.times[-1]), 1 / 30)
        ct = warp.content_time(tau)
        W = np.stack([np.interp(ct, base.times, base.weights[:, j]) for j in range(len(names))], axis=1)
        e = weight_vector(EMOTIONS[s], ARKIT_NAMES)
        W = np.clip(W + e[[ARKIT_NAMES.index(n) for n in names]], 0, 1)
        write_livelinkface(d / f"{s}.csv", Performance.from_weights(W, names, times=tau))
        out[s] = d / f"{s}.csv"
    write_rig(make_demo_character("ada"), d / "ada")
    return d, out


def test_cli_fit_and_restyle_end_to_end(takes, capsys):
    from faceretarget.io import read_glb_weights, read_livelinkface

    main = _cli_main()
    d, f = takes
    model = d / "m.npz"
    rc = main(["style", "fit", "--take", f"neutral={f['neutral']}", "--take", f"angry={f['angry']}",
               "--take", f"happy={f['happy']}", "--out", str(model)])
    out = capsys.readouterr().out
    assert rc == 0 and model.exists() and "aligned angry to neutral by face" in out
    rc = main(["restyle", "--model", str(model), "--performance", str(f["neutral"]), "--to", "angry",
               "--from", "neutral", "--out", str(d / "r.csv")])
    assert rc == 0
    r = read_livelinkface(d / "r.csv")
    neutral = read_livelinkface(f["neutral"])
    assert r.n_frames == neutral.n_frames
    col = [n.lower() for n in r.names].index("browdownleft")
    assert r.weights[:, col].mean() > 0.6 > neutral.weights[:, col].mean()       # angry brows
    rc = main(["restyle", "--model", str(model), "--performance", str(f["neutral"]), "--to", "happy",
               "--amount", "0.5", "--window", "1.0", "--rig", str(d / "ada"), "--out", str(d / "r.glb")])
    out = capsys.readouterr().out
    assert rc == 0 and "inferred style" in out
    names, times, w = read_glb_weights(d / "r.glb")
    assert w.shape[0] == neutral.n_frames


def test_cli_point_takes_use_the_point_local_translation(tmp_path, capsys):
    from faceretarget.io import read_npz_performance, write_npz

    main = _cli_main()
    x0, x1 = _local_nonlinear_takes(C=600)
    t = np.arange(len(x0)) / 30.0
    write_npz(tmp_path / "a.npz", x0, t)
    write_npz(tmp_path / "b.npz", x1, t)
    rc = main(["style", "fit", "--take", f"a={tmp_path / 'a.npz'}", "--take", f"b={tmp_path / 'b.npz'}",
               "--local", "points:1:8", "--out", str(tmp_path / "m.npz")])
    out = capsys.readouterr().out
    assert rc == 0 and "aligned b to a by face+style" in out
    rc = main(["restyle", "--model", str(tmp_path / "m.npz"), "--performance", str(tmp_path / "a.npz"),
               "--from", "a", "--to", "b", "--out", str(tmp_path / "r.npz")])
    out = capsys.readouterr().out
    assert rc == 0 and "by the point-local translation" in out
    r = read_npz_performance(tmp_path / "r.npz")
    assert r.vertices.shape == x0.shape
    err = np.sqrt(np.mean((r.vertices[:500] - x1[:500]) ** 2))
    assert err < 0.1 * np.sqrt(np.mean((x0[:500] - x1[:500]) ** 2)), err


def test_cli_bad_input_is_one_line_exit_2(takes, capsys, tmp_path):
    main = _cli_main()
    d, f = takes
    rc = main(["style", "fit", "--take", f"neutral={f['neutral']}", "--take", f"angry={tmp_path / 'nope.csv'}",
               "--out", str(tmp_path / "m.npz")])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and "nope.csv" in err[0] and not (tmp_path / "m.npz").exists()
    # mismatched takes: a point take next to weight takes
    from faceretarget.io import write_npz

    write_npz(tmp_path / "pts.npz", np.zeros((30, 5, 3)) + np.arange(30)[:, None, None], np.arange(30) / 30.0)
    rc = main(["style", "fit", "--take", f"neutral={f['neutral']}", "--take", f"angry={tmp_path / 'pts.npz'}",
               "--out", str(tmp_path / "m.npz")])
    err = capsys.readouterr().err
    assert rc == 2 and "pts.npz" in err and "weights" in err
    rc = main(["style", "fit", "--take", f"neutral={f['neutral']}", "--out", str(tmp_path / "m.npz")])
    assert rc == 2 and "at least 2" in capsys.readouterr().err
    rc = main(["style", "fit", "--take", f"neutral{f['neutral']}", "--take", f"angry={f['angry']}",
               "--out", str(tmp_path / "m.npz")])
    assert rc == 2 and "STYLE=PATH" in capsys.readouterr().err
    rc = main(["restyle", "--model", str(tmp_path / "missing.npz"), "--performance", str(f["neutral"]),
               "--to", "angry", "--out", str(tmp_path / "o.csv")])
    assert rc == 2 and "missing.npz" in capsys.readouterr().err
    # refusing to overwrite the input take
    before = f["neutral"].read_bytes()
    rc = main(["restyle", "--model", str(tmp_path / "missing.npz"), "--performance", str(f["neutral"]),
               "--to", "angry", "--out", str(f["neutral"])])
    assert rc == 2 and "input" in capsys.readouterr().err and f["neutral"].read_bytes() == before


# ------------------------------------------------------------------------------------------ settings by cross-validation
def _nonlinear_styles(C=240, D=6, S=3, seed=0, nonlin=1.0, noise=0.0):
    """A Lissajous content trajectory ``b`` (2 dims, covering its square); style s:
    ``x = M_s [1, b] + nonlin * G_s sin(W_s b)``.

    Each style bends the content by its own functions (``W_s``), more of them in all than the ``D``
    dimensions hold, so no bilinear model reproduces the styles when ``nonlin > 0``.
    """
    rng = np.random.default_rng(seed)
    t = np.arange(C) / 30.0
    J = 2
    b = np.stack([np.sin(2 * np.pi * 0.71 * t), np.sin(2 * np.pi * 0.43 * t + 1.0)], 1)
    M = rng.standard_normal((S, D, J + 1))
    G = 0.5 * rng.standard_normal((S, D, D))
    W = rng.standard_normal((S, D, J))
    X = {}
    for s in range(S):
        x = np.c_[np.ones(C), b] @ M[s].T + nonlin * np.sin(b @ W[s].T) @ G[s].T
        X[f"s{s}"] = x + noise * rng.standard_normal(x.shape)
    return X


def _known_err(m, X, idx):
    err = 0.0
    for s in X:
        for t in X:
            if s != t:
                err += float(np.sum((m.known(X[s][idx], s, t, warn=False).frames - X[t][idx]) ** 2))
    return err


def test_cv_folds_are_contiguous_blocks_with_a_gap():
    from faceretarget.style import cv_folds

    sp = cv_folds(100, 4, 3)
    assert [len(v) for _, v in sp] == [25, 25, 25, 25]
    tr, va = sp[1]
    assert va[0] == 25 and va[-1] == 49 and np.all(np.diff(va) == 1)
    assert not set(tr) & set(range(22, 53)) and set(tr) == set(range(0, 22)) | set(range(53, 100))


def test_kernel_correction_interpolates_and_vanishes_far_away():
    from faceretarget.style import kernel_fit, kernel_predict

    rng = np.random.default_rng(3)
    Y = rng.standard_normal((60, 4))
    R = np.c_[np.sin(Y[:, 0]), Y[:, 1] ** 2]
    km = kernel_fit(Y, R, bandwidth=3.0, ridge=1e-6)
    assert np.abs(kernel_predict(km, Y) - R).max() < 1e-2                 # tiny ridge: reproduces training
    assert np.abs(kernel_predict(km, Y + 1e3)).max() < 1e-12              # far from the data: no correction


def test_cv_picks_the_known_best_local_correction():
    """On non-bilinear synthetic styles, the kernel setting chosen by cross-validation on the training
    part is (within 10 %) the one with the lowest error on held-out later content."""
    X = _nonlinear_styles(C=400, nonlin=1.0, noise=0.01)
    tr, te = slice(0, 300), slice(300, 400)
    base = {"variance": 0.999999, "energy": 0.999999, "prior": 1.0}
    m = StyleModel(**base).fit_frames({s: x[tr] for s, x in X.items()})
    chosen = m.settings_["local"]
    assert isinstance(chosen, tuple) and chosen[0] == "kernel"        # the model is not bilinear: a correction wins
    held = {}
    for spec in [0] + [("kernel", h, lam) for h in (3.0, 10.0, 30.0, 100.0) for lam in (1e-3, 1e-2, 1e-1, 1.0)]:
        mm = StyleModel(**base, local=spec).fit_frames({s: x[tr] for s, x in X.items()})
        held[spec] = _known_err(mm, X, te)
    best = min(held.values())
    assert held[chosen] <= 1.1 * best, (chosen, held[chosen], best)
    assert held[chosen] < 0.5 * held[0]                                 # and it halves the bilinear model's error
    # the scores are recorded, relative to leaving the input unchanged (< 1: better than no edit)
    s2 = [r for r in m.selection_.table if r["stage"] == 2]
    assert 1 + 4 + 3 <= len(s2) <= 17 and min(r["score"] for r in s2) < 0.1   # coordinate search: a row, a column


def test_cv_picks_the_held_out_best_prior_strength():
    """Few noisy frames: the content prior's strength chosen by cross-validation on the training part is
    (within 10 %) the best of the grid on held-out later frames."""
    fix = {"variance": 0.999999, "energy": 0.999999, "local": 0}
    Xn = _nonlinear_styles(C=400, D=12, nonlin=0.0, noise=0.3, seed=5)
    tr, te = slice(0, 80), slice(80, 400)
    m = StyleModel(**fix).fit_frames({s: x[tr] for s, x in Xn.items()})
    held = {p: _known_err(StyleModel(**fix, prior=p).fit_frames({s: x[tr] for s, x in Xn.items()}), Xn, te)
            for p in (0.1, 1.0, 10.0, 100.0, 1000.0)}
    assert held[m.settings_["prior"]] <= 1.1 * min(held.values()), (m.settings_, held)
    assert len([r for r in m.selection_.table if r["stage"] == 1]) == 5


def test_selected_settings_survive_save_and_fallback_without_enough_frames(tmp_path):
    X = _nonlinear_styles(C=150, nonlin=1.0, noise=0.01)
    m = StyleModel().fit_frames(X)
    assert m.selection_ is not None and set(m.settings_) == {"variance", "energy", "prior", "local"}
    x = X["s0"][:40]
    r1 = m.known(x, "s0", "s2", warn=False).frames
    m2 = StyleModel.load(m.save(tmp_path / "m.npz"))
    assert m2.settings_ == m.settings_
    assert np.allclose(m2.known(x, "s0", "s2", warn=False).frames, r1, atol=1e-9)
    small = StyleModel().fit_frames({s: v[:20] for s, v in X.items()})
    assert small.selection_ is not None and small.selection_.table == []
    assert small.settings_ == {"variance": 0.9999, "energy": 0.9999, "prior": 1.0, "local": 0}
    fixed = StyleModel(variance=0.999, energy=0.999, prior=2.0, local=("kernel", 10.0, 0.1)).fit_frames(X)
    assert fixed.selection_ is None and fixed.settings_["local"] == ("kernel", 10.0, 0.1)
    with pytest.raises(InvalidDataError):
        StyleModel(local="nearest").fit_frames(X)


def test_untrained_style_from_few_examples_is_shrunk_towards_the_additive_offset():
    """A new style fitted from a short stretch whose content varies in only a few directions: plain
    least squares extrapolates wildly on other content (the P3 MySlate_3 failure); the shrinkage
    chosen by cross-validation on the examples stays at least as good as the additive offset."""
    rng = np.random.default_rng(11)
    S, D, J, C, T, Ct = 3, 40, 10, 300, 40, 100
    M = rng.standard_normal((S, D, J))
    Mn = M[0].copy()
    Mn[:, 0] += 2 * rng.standard_normal(D)                            # a new mean face ...
    Mn += 0.05 * rng.standard_normal((D, J))                          # ... and a small change of the content's effect
    b = np.c_[np.ones(C + Ct), rng.standard_normal((C + Ct, J - 1))]
    X = np.einsum("sdj,cj->scd", M, b) + 0.1 * rng.standard_normal((S, C + Ct, D))
    mix = rng.standard_normal((3, J - 1))
    be = np.c_[np.ones(T), rng.standard_normal((T, 3)) @ mix + 0.05 * rng.standard_normal((T, J - 1))]
    ex_known = be @ M[0].T + 0.1 * rng.standard_normal((T, D))
    ex_new = be @ Mn.T + 0.1 * rng.standard_normal((T, D))
    x_in, truth = b[C:] @ M[0].T, b[C:] @ Mn.T
    base = np.sqrt(np.mean((x_in + (ex_new - ex_known).mean(0) - truth) ** 2))

    def err(shrink, n=T):
        m = StyleModel(variance=0.999, energy=0.999, prior=1.0, local=0).fit_frames(
            {f"s{i}": X[i, :C] for i in range(S)})
        m.add_style("new", ex_new[:n], like=("s0", ex_known[:n]), shrink=shrink)
        r = m.known(x_in, "s0", "new", warn=False)
        return float(np.sqrt(np.mean((r.frames - truth) ** 2))), m

    plain, _ = err(0.0)
    auto, m = err("auto")
    assert plain > 3 * base                                            # the failure
    assert auto < base and 0 < m.added_["new"]["shrink"] < 100          # the fix
    assert len(m.added_["new"]["table"]) == 8
    # too few examples to cross-validate: a rule (J / T) and a warning
    with pytest.warns(StyleFitWarning, match="too few"):
        few, m = err("auto", 20)
    assert m.added_["new"]["shrink"] == pytest.approx(m.asymmetric_.content_dims_ / 20)
    assert few < 2 * base
    with pytest.raises(InvalidDataError):
        err(-1.0)
