"""Restyling the face in a video (issue 15, Chuang Fig. 2.6): ``appearance fit --take`` and
``restyle --video`` on short pieces of the shared MEAD / CREMA-D clips."""

from __future__ import annotations

import numpy as np
import pytest

from faceretarget.errors import InvalidDataError

STYLES = {"neutral": "W009_front_neutral_level1_001.mp4", "angry": "W009_front_angry_level3_001.mp4",
          "happy": "W009_front_happy_level3_001.mp4"}
FRAMES = 24


def _run(argv):
    from faceretarget.cli import main

    return main(argv)


@pytest.fixture(scope="module")
def mead(data_dir):
    pytest.importorskip("mediapipe", reason="video capture needs mediapipe (pip install 'faceretarget[capture]')",
                        exc_type=ImportError)
    pytest.importorskip("av", reason="video needs PyAV (pip install 'faceretarget[capture]')")
    from faceretarget.capture import find_model
    from faceretarget.errors import FaceRetargetError

    d = data_dir / "emotion-video" / "mead"
    if not all((d / v).is_file() for v in STYLES.values()):
        pytest.skip(f"{d}: the W009 MEAD clips are not there")
    try:
        find_model()
    except FaceRetargetError as e:
        pytest.skip(str(e))
    return d


@pytest.fixture(scope="module")
def model_file(mead, tmp_path_factory):
    out = tmp_path_factory.mktemp("restyle_video") / "w009.npz"
    argv = ["-q", "appearance", "fit", "--out", str(out), "--max-frames", "40", "--width", "64"]
    for k, v in STYLES.items():
        argv += ["--take", f"{k}={mead / v}"]
    assert _run(argv) == 0
    return out


def _decode(path):
    from faceretarget.io import iter_frames

    return np.stack([f for _, _, f in iter_frames(path)])


def _grey(x):
    return np.asarray(x, np.float64) @ np.array([0.299, 0.587, 0.114])


def test_model_file_holds_both_models_and_amount_zero_is_the_reconstruction(mead, model_file, tmp_path):
    from faceretarget.capture import AppearanceModel, FaceCompositor
    from faceretarget.pipelines import AppearanceStyleModel, capture_take, restyle_video, write_face_video

    m = AppearanceStyleModel.load(model_file)
    assert isinstance(m.appearance_, AppearanceModel) and m.styles_ == ["neutral", "angry", "happy"]
    assert m.reference_ == "neutral" and m.style_.mean_.shape == (len(m.appearance_.names_),)
    video = mead / STYLES["neutral"]
    # the style model at amount 0 returns the input's vectors bit for bit (known and inferred style)
    cap = capture_take(video, audio=False, max_frames=FRAMES, smooth=None)
    from faceretarget.io import iter_frames

    frames = [f for _, _, f in iter_frames(video, max_frames=FRAMES)]
    vec = m.appearance_.transform(frames, cap.landmarks)
    for src in ("neutral", None):
        r = m.transform(vec, "angry", 0.0, source=src)
        assert np.array_equal(r.frames, vec)
    # ... so the restyled video at amount 0 is the unedited reconstruction, frame for frame
    res = restyle_video(video, m, "angry", tmp_path / "zero.mp4", source="neutral", amount=0.0, max_frames=FRAMES,
                        smooth=None)
    assert np.array_equal(res.edited, res.vectors) and np.allclose(res.vectors, vec, atol=1e-6)
    write_face_video(tmp_path / "recon.mp4", video, cap, m.appearance_, vec)
    zero, recon = _decode(tmp_path / "zero.mp4"), _decode(tmp_path / "recon.mp4")
    assert zero.shape == recon.shape == (FRAMES, 256, 256, 3) and np.array_equal(zero, recon)
    # the reconstruction is close to the input inside the face, and the background is the input's
    comp = FaceCompositor(m.appearance_)
    _, a, c = m.appearance_.shape_params(cap.landmarks)
    _, alpha = comp.render_with_mask(frames[5], vec[5], a[5], c[5])
    face = alpha > 0.99
    inp = np.stack(frames)
    err_face = np.abs(_grey(recon[:, face]) - _grey(inp[:, face])).mean()
    assert 2.0 < err_face < 8.0, err_face             # 5.1 measured: a 64-px canvas, 80 % of the texture variance
    far = np.zeros((256, 256), bool)
    far[:, :20] = far[:, -20:] = True                  # the green wall left and right of the head
    assert np.abs(_grey(recon[:, far]) - _grey(inp[:, far])).mean() < 2.0   # H.264 noise only
    # at amount 1 the face changes, the wall does not
    edit = restyle_video(video, m, "angry", tmp_path / "angry.mp4", source="neutral", max_frames=FRAMES, smooth=None)
    angry = _decode(edit.path)
    change = np.abs(_grey(angry[:, face]) - _grey(recon[:, face])).mean()
    assert change > 8.0, change                       # 16 measured
    assert np.abs(_grey(angry[:, far]) - _grey(recon[:, far])).mean() < 1.0
    shapes = m.appearance_.reconstruct_shape(edit.edited) - m.appearance_.reconstruct_shape(edit.vectors)
    assert np.sqrt((shapes**2).sum(-1)).mean() > 0.5                   # canvas pixels (64 px face width)


def test_cli_restyle_video_keeps_frame_count_rate_size_and_audio(mead, model_file, data_dir, tmp_path, capsys):
    from faceretarget.io import probe_video, read_video_audio

    out = tmp_path / "angry.mp4"
    rc = _run(["restyle", "--video", str(mead / STYLES["neutral"]), "--appearance", str(model_file), "--to", "angry",
               "--from", "neutral", "--amount", "1.5", "--max-frames", "20", "--out", str(out)])
    assert rc == 0, capsys.readouterr().err
    log = capsys.readouterr().out
    assert "restyled 20 frames neutral -> angry at amount 1.5" in log and f"wrote {out}" in log
    info = probe_video(out)
    assert (info.width, info.height) == (256, 256) and abs(info.fps - 25.0) < 1e-6
    assert len(_decode(out)) == 20 and not info.has_audio
    # a video with audio (CREMA-D, 29.97 fps, 480 x 360) keeps its audio, rate, size and frame count
    flv = data_dir / "emotion-video" / "crema-d" / "1001_DFA_NEU_XX.flv"
    if not flv.is_file():
        pytest.skip(f"{flv} not found")
    out2 = tmp_path / "crema.mp4"
    rc = _run(["-q", "restyle", "--video", str(flv), "--appearance", str(model_file), "--to", "happy",
               "--max-frames", "30", "--out", str(out2)])
    assert rc == 0, capsys.readouterr().err
    i2, i0 = probe_video(out2), probe_video(flv)
    assert (i2.width, i2.height) == (i0.width, i0.height) and abs(i2.fps - i0.fps) < 1e-3
    assert len(_decode(out2)) == 30 and i2.has_audio
    audio, rate = read_video_audio(out2)
    assert rate == i0.audio_rate and audio.size / rate > 0.9          # the input's audio, about 1 s of it


@pytest.fixture(scope="module")
def speaker_file(mead, data_dir, tmp_path_factory):
    """A speaker style model (issue 27) from M030 (MEAD) and 1001 (CREMA-D), neutral and angry, by the CLI:
    W009, whose video is restyled below, is a speaker it has never seen."""
    crema = data_dir / "emotion-video" / "crema-d"
    out = tmp_path_factory.mktemp("speakers") / "speakers.npz"
    argv = ["-q", "style", "fit", "--out", str(out),
            "--take", f"M030:neutral={mead / 'M030_front_neutral_level1_001.mp4'}",
            "--take", f"M030:angry={mead / 'M030_front_angry_level3_001.mp4'}",
            "--take", f"1001:neutral={crema / '1001_DFA_NEU_XX.flv'}", "--take", f"1001:angry={crema / '1001_DFA_ANG_XX.flv'}"]
    assert _run(argv) == 0
    return out


# slow: restyles a real video end to end through the CLI (tracking, model, warp, encode) (~6 s)
def test_cli_speaker_model_restyles_an_unseen_persons_video(mead, model_file, speaker_file, tmp_path, capsys):
    from faceretarget.pipelines import AppearanceStyleModel, restyle_video
    from faceretarget.style import SpeakerStyleModel

    spk = SpeakerStyleModel.load(speaker_file)
    assert spk.speakers_ == ["M030", "1001"] and spk.styles_ == ["neutral", "angry"]
    assert spk.gain_source_ == {"angry": "held-out speakers"} and 0.0 < spk.gain_["angry"] <= 1.0
    video = mead / STYLES["neutral"]
    app = AppearanceStyleModel.load(model_file).appearance_
    zero = restyle_video(video, app, "angry", tmp_path / "z.mp4", speakers=spk, amount=0.0, max_frames=FRAMES,
                         smooth=None)
    assert np.array_equal(zero.edited, zero.vectors)                   # amount 0: the input's own vectors
    one = restyle_video(video, app, "angry", tmp_path / "a.mp4", speakers=spk, amount=1.0, max_frames=FRAMES,
                        smooth=None)
    ks = app.n_shape
    assert np.array_equal(one.edited[:, ks:], one.vectors[:, ks:])      # the texture stays the input's ...
    shapes = app.reconstruct_shape(one.edited) - app.reconstruct_shape(one.vectors)
    moved = np.sqrt((shapes**2).sum(-1))
    assert 0.1 < moved.mean() < 10.0                                   # ... the shape moves (canvas pixels)
    # anger lowers the brows towards the eyes (MediaPipe's brow 105, 334 over the eye tops 159, 386)
    from faceretarget.pipelines import capture_take, speaker_edited_landmarks

    cap = capture_take(video, audio=False, max_frames=FRAMES, smooth=None)
    L, _ = speaker_edited_landmarks(cap, spk, "angry")
    L0 = cap.landmarks[cap.valid]
    gap = lambda x: (x[:, [159, 386], 1] - x[:, [105, 334], 1]).mean()  # noqa: E731  (image y points down)
    assert gap(L) < gap(L0)
    # the command line: the same, an .mp4 of the input's frames
    out = tmp_path / "cli.mp4"
    rc = _run(["restyle", "--video", str(video), "--appearance", str(model_file), "--speakers", str(speaker_file),
               "--to", "angry", "--max-frames", "20", "--out", str(out)])
    assert rc == 0, capsys.readouterr().err
    assert "with the speaker model" in capsys.readouterr().out and len(_decode(out)) == 20
    assert _run(["restyle", "--video", str(video), "--appearance", str(model_file), "--speakers", str(speaker_file),
                 "--to", "happy", "--out", str(tmp_path / "h.mp4")]) == 2
    err = _one_error_line(capsys)
    assert str(speaker_file) in err and "'happy'" in err and not (tmp_path / "h.mp4").exists()
    assert _run(["style", "fit", "--take", f"M030:neutral={video}", "--take", f"angry={video}",
                 "--out", str(tmp_path / "x.npz")]) == 2
    assert "name the speaker of every take" in _one_error_line(capsys)


def _one_error_line(capsys) -> str:
    err = capsys.readouterr().err.strip()
    assert err.startswith("faceretarget: error:") and "\n" not in err, err
    return err


def test_cli_errors_name_the_file(mead, model_file, tmp_path, capsys):
    from faceretarget.io import write_video

    video = str(mead / STYLES["neutral"])
    out = tmp_path / "o.mp4"
    base = ["restyle", "--video", video, "--to", "angry", "--out", str(out)]
    missing = tmp_path / "nope.npz"
    assert _run(base + ["--appearance", str(missing)]) == 2
    assert str(missing) in _one_error_line(capsys)
    assert _run(["restyle", "--video", video, "--appearance", str(model_file), "--to", "sad", "--out", str(out)]) == 2
    err = _one_error_line(capsys)
    assert str(model_file) in err and "'sad'" in err and "neutral, angry, happy" in err
    assert _run(base + ["--appearance", str(model_file), "--from", "bored"]) == 2
    assert "'bored'" in _one_error_line(capsys)
    # a plain appearance model (no style model) is refused naming the file and how to make one
    plain = tmp_path / "plain.npz"
    from faceretarget.pipelines import AppearanceStyleModel

    AppearanceStyleModel.load(model_file).appearance_.save(plain)
    assert _run(base + ["--appearance", str(plain)]) == 2
    err = _one_error_line(capsys)
    assert str(plain) in err and "--take" in err
    # a video without a face
    black = tmp_path / "black.mp4"
    write_video(black, [np.zeros((64, 64, 3), np.uint8)] * 5, 25.0)
    assert _run(["-q", "restyle", "--video", str(black), "--appearance", str(model_file), "--to", "angry",
                 "--out", str(out)]) == 2
    err = _one_error_line(capsys)
    assert str(black) in err and "no face" in err
    # --video and --performance exclude each other; --video needs --appearance, .mp4 output
    assert _run(base + ["--performance", "x.csv", "--appearance", str(model_file)]) == 2
    assert "not allowed" in _one_error_line(capsys)
    assert _run(base) == 2 and "--appearance" in _one_error_line(capsys)
    assert _run(["restyle", "--video", video, "--appearance", str(model_file), "--to", "angry",
                 "--out", str(tmp_path / "o.csv")]) == 2
    assert ".mp4" in _one_error_line(capsys)
    assert _run(base + ["--appearance", str(model_file), "--out", video]) == 2   # never over the input
    assert "refusing" in _one_error_line(capsys)
    assert not list(tmp_path.glob("o.*")) and not list(tmp_path.glob(".o.mp4*"))
    # appearance fit --take needs two styles
    assert _run(["appearance", "fit", "--take", f"neutral={video}", "--out", str(tmp_path / "m.npz")]) == 2
    assert "at least 2 styles" in _one_error_line(capsys)


def test_compositor_puts_a_face_back_where_it_was():
    """Synthetic: a textured face rendered from its own vector lands on itself; a moved shape moves it."""
    pytest.importorskip("cv2", reason="warping needs OpenCV (pip install 'faceretarget[capture]')")
    from faceretarget.capture import AppearanceModel, FaceCompositor, image_shapes

    rng = np.random.default_rng(0)
    ang = np.linspace(0, 2 * np.pi, 16, endpoint=False)
    base = np.c_[np.cos(ang), np.sin(ang)] * 30
    base = np.concatenate([base, 0.5 * base[::2], [[0.0, 0.0]]]) + 64       # 25 points, a disc
    yy, xx = np.mgrid[0:128, 0:128]
    frames, lms = [], []
    for _ in range(20):
        t = rng.normal(0, 2, 2)
        lm = base + t + rng.normal(0, 0.5, base.shape)
        img = np.full((128, 128, 3), 40, np.uint8)
        ring = ((xx - 64 - t[0]) ** 2 + (yy - 64 - t[1]) ** 2) < 31**2
        img[ring] = (200 + 40 * np.sin((xx[ring] - t[0]) / 4))[:, None].astype(np.uint8)
        frames.append(img)
        lms.append(lm)
    frames, lms = np.stack(frames), np.stack(lms)
    m = AppearanceModel(1.0, 1.0, width=60, points=np.arange(len(base))).fit(frames, lms)
    vec = m.transform(frames, lms)
    b, a, c = m.shape_params(lms)
    back = image_shapes(m, m.reconstruct_shape(vec), a, c)
    assert np.abs(back - lms).max() < 1e-6                    # all variance kept: the shapes exactly
    comp = FaceCompositor(m, feather=0.1)
    out, alpha = comp.render_with_mask(frames[3], vec[3], a[3], c[3], tracked=lms[3])
    inside = alpha > 0.99
    assert inside.sum() > 1500 and np.abs(out[inside].astype(float) - frames[3][inside]).mean() < 3.0
    assert np.array_equal(out[:8], frames[3][:8]) and np.array_equal(out[:, :8], frames[3][:, :8])  # untouched
    with pytest.raises(InvalidDataError, match="feather"):
        FaceCompositor(m, feather=2.0)
