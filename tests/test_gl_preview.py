"""The fast preview renderer (OpenGL through EGL) against the NumPy rasteriser, and the side-by-side
preview video (issue 13, item 2)."""

from __future__ import annotations

import os
import sys
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from faceretarget.errors import InputFileError, InvalidDataError, MissingDependencyError, OutputError
from faceretarget.headpose import HeadPose
from faceretarget.optional import install_line
from faceretarget.render import DEFAULT_BACKGROUND, DEFAULT_COLOR, MeshRenderer, gl_available, render_mesh

BG = np.round(np.asarray(DEFAULT_BACKGROUND) * 255).astype(np.uint8)
REQUIRE = os.environ.get("FACERETARGET_REQUIRE_DATA", "") not in ("", "0")


@pytest.fixture(scope="module")
def gl():
    """Skips, naming what is missing (``pip install 'faceretarget[preview]'`` or the Debian packages
    that ``make gl`` installs), unless moderngl and an EGL driver are here."""
    ok, why = gl_available()
    if not ok:
        pytest.skip(f"no OpenGL preview renderer: {why}")
    return why


def _mask(img: np.ndarray) -> np.ndarray:
    return (img != BG).any(axis=2)


def _iou(a: np.ndarray, b: np.ndarray) -> float:
    ma, mb = _mask(a), _mask(b)
    return float((ma & mb).sum() / (ma | mb).sum())


def _centroid_x(img: np.ndarray) -> float:
    return float(np.nonzero(_mask(img))[1].mean())


def _red_x(img: np.ndarray) -> float:
    """Mean column of the red marker's pixels."""
    red = (img[..., 0] > 150) & (img[..., 1] < 90)
    assert red.sum() > 100
    return float(np.nonzero(red)[1].mean())


def _expression(rig) -> np.ndarray:
    w = np.zeros(rig.n_shapes)
    for name, value in [("jawOpen", 0.8), ("mouthSmileLeft", 0.7), ("mouthSmileRight", 0.7),
                        ("browInnerUpLeft", 0.8), ("eyeBlinkRight", 1.0)]:
        w[rig.index(name)] = value
    return rig.evaluate(w)


# ---------------------------------------------------------------------- renderer
@pytest.mark.parametrize("case", ["neutral", "expression", "expression+head"])
def test_gl_matches_numpy_on_ict(gl, ict_rig, case):
    """Same camera, shading and head transform: measured mean |difference| 0.0000-0.0004 grey levels,
    silhouette IoU 0.99998-1.0 (a few edge pixels) at 512 x 512."""
    v = ict_rig.neutral.vertices if case == "neutral" else _expression(ict_rig)
    R = t = None
    if case == "expression+head":
        R = Rotation.from_euler("YXZ", [15.0, -10.0, 5.0], degrees=True).as_matrix()
        t = np.array([0.01, -0.005, 0.02])  # metres
    kw = dict(mm_per_unit=ict_rig.mm_per_unit)
    with MeshRenderer(ict_rig.neutral, (512, 512), backend="gl", **kw) as g, \
            MeshRenderer(ict_rig.neutral, (512, 512), backend="numpy", **kw) as n:
        assert g.backend.startswith("gl (EGL, ") and g.reason == ""
        assert n.backend == "numpy"
        a, b = g.render(v, R, t), n.render(v, R, t)
    assert a.shape == b.shape == (512, 512, 3) and a.dtype == b.dtype == np.uint8
    d = np.abs(a.astype(np.int16) - b)
    assert _mask(a).mean() > 0.25  # the face fills a good part of the frame
    assert _iou(a, b) >= 0.998
    assert d.mean() < 0.05
    assert (d > 2).mean() < 1e-3  # off by more than 2 grey levels: silhouette-edge pixels only


def test_gl_matches_numpy_with_vertex_colours_off_square(gl, arkit_rig):
    """Per-vertex sRGB colours (interpolated, then decoded per pixel in both) on a 200 x 320 image:
    measured mean |difference| 5e-5 grey levels, no pixel off by more than 2."""
    v = arkit_rig.neutral.vertices
    color = np.random.default_rng(0).random((len(v), 3))
    with MeshRenderer(arkit_rig.neutral, (200, 320), backend="gl", color=color) as g, \
            MeshRenderer(arkit_rig.neutral, (200, 320), backend="numpy", color=color) as n:
        a, b = g.render(v), n.render(v)
    assert a.shape == b.shape == (320, 200, 3)
    d = np.abs(a.astype(np.int16) - b)
    assert d.mean() < 0.05 and (d > 2).mean() < 1e-3 and _iou(a, b) >= 0.998


@pytest.mark.parametrize("backend", ["numpy", "gl"])
def test_head_yaw_and_translation_move_the_face_the_right_way(request, ict_rig, backend):
    """+20 degrees of yaw turns the face toward the character's left, image right in the front view:
    a red patch on the nose tip moves right by its projected displacement (measured +12.3 px, 0.1 px
    from the prediction), while the silhouette's centroid moves left (-16.7 px: the head swings about
    its centroid, behind the face, so the far cheek, ear and neck go left).  A translation of 1 cm along
    +X moves everything right by exactly camera.scale x 1 cm (ICT is in cm, the translation in metres)."""
    if backend == "gl":
        request.getfixturevalue("gl")
    v = ict_rig.neutral.vertices
    nose = int(np.argmax(v[:, 2]))  # the nose tip: the most forward vertex
    patch = np.linalg.norm(v - v[nose], axis=1) < 0.05 * ict_rig.neutral.bbox_diagonal()
    color = np.tile(DEFAULT_COLOR, (len(v), 1))
    color[patch] = (0.9, 0.1, 0.1)
    R = Rotation.from_euler("y", 20.0, degrees=True).as_matrix()
    with MeshRenderer(ict_rig.neutral, (256, 256), backend=backend, color=color,
                      mm_per_unit=ict_rig.mm_per_unit) as r:
        rest, yaw, moved = r.render(v), r.render(v, R), r.render(v, None, np.array([0.01, 0.0, 0.0]))
        cam = r.camera
        predicted = cam.project(r.transform(v, R)[patch])[:, 0].mean() - cam.project(v[patch])[:, 0].mean()
    nose_shift = _red_x(yaw) - _red_x(rest)
    assert predicted > 10.0
    assert nose_shift == pytest.approx(predicted, abs=1.5)
    assert _centroid_x(yaw) - _centroid_x(rest) < -10.0
    assert _centroid_x(moved) - _centroid_x(rest) == pytest.approx(cam.scale * 1.0, abs=0.5)
    assert _red_x(moved) - _red_x(rest) == pytest.approx(cam.scale * 1.0, abs=0.5)


def test_numpy_backend_is_render_mesh_of_the_moved_mesh(arkit_rig):
    """The head transform is R (v - centroid) + centroid + t (metres to rig units): the renderer's
    picture equals render_mesh of those vertices with the same camera, bit for bit."""
    v = arkit_rig.neutral.vertices
    R = Rotation.from_euler("YXZ", [-25.0, 12.0, 0.0], degrees=True).as_matrix()
    t = np.array([0.0, 0.01, 0.0])
    with MeshRenderer(arkit_rig.neutral, (128, 160), backend="numpy", mm_per_unit=arkit_rig.mm_per_unit) as r:
        img = r.render(v, R, t)
        c = v.mean(axis=0)
        manual = (v - c) @ R.T + c + t * 1000.0 / arkit_rig.mm_per_unit
        np.testing.assert_allclose(r.transform(v, R, t), manual, atol=1e-12)
        assert np.array_equal(img, render_mesh(manual, arkit_rig.neutral, camera=r.camera))
    assert img.shape == (160, 128, 3)


def test_gl_falls_back_to_numpy_and_says_what_to_install(monkeypatch, arkit_rig):
    monkeypatch.setitem(sys.modules, "moderngl", None)  # `import moderngl` raises ImportError
    with MeshRenderer(arkit_rig.neutral, (64, 64)) as r:
        assert r.backend == "numpy"
        assert install_line("moderngl") in r.reason
        assert _mask(r.render(arkit_rig.neutral.vertices)).any()
    with pytest.raises(MissingDependencyError, match=r"make preview .*pip install 'moderngl"):
        MeshRenderer(arkit_rig.neutral, (64, 64), backend="gl")
    with pytest.raises(InvalidDataError, match="unknown render backend 'vulkan'"):
        MeshRenderer(arkit_rig.neutral, backend="vulkan")


def test_no_egl_library_falls_back_naming_the_debian_packages(monkeypatch, arkit_rig):
    try:
        import moderngl
    except ImportError as e:
        pytest.skip(f"moderngl cannot be imported ({e}): pip install 'faceretarget[preview]'")

    def no_egl(*a, **k):
        raise Exception("libEGL.so.1 not loaded")  # what glcontext raises without the library

    monkeypatch.setattr(moderngl, "create_standalone_context", no_egl)
    with MeshRenderer(arkit_rig.neutral, (64, 64)) as r:
        assert r.backend == "numpy"
        assert "libEGL.so.1 not loaded" in r.reason
        assert "apt-get install libegl1 libgl1-mesa-dri libegl-mesa0" in r.reason
    assert gl_available() == (False, r.reason)


def test_renderer_bad_input_names_the_shape(arkit_rig):
    with MeshRenderer(arkit_rig.neutral, (32, 32), backend="numpy") as r:
        with pytest.raises(InvalidDataError, match=r"\(10, 3\), the mesh has \(1220, 3\)"):
            r.render(np.zeros((10, 3)))
        with pytest.raises(InvalidDataError, match=r"head rotation must be a finite \(3, 3\)"):
            r.render(arkit_rig.neutral.vertices, np.eye(4))


# ---------------------------------------------------------------------- preview video
@pytest.fixture(scope="module")
def av():
    if REQUIRE:
        import av as _av  # fail, do not skip, when the data (and what reads it) are required

        return _av
    return pytest.importorskip("av", reason="PyAV is not installed: pip install 'faceretarget[capture]'")


@pytest.fixture(scope="module")
def clip(av, data_dir, tmp_path_factory) -> Path:
    """The first 50 frames (2 s at 25 fps) of a real 512 x 512 talking-head video, with its audio."""
    from faceretarget.io import iter_frames, write_video

    src = data_dir / "video" / "WDA_AOC_000.mp4"
    if not src.is_file():
        if REQUIRE:
            pytest.fail(f"{src} not found")
        pytest.skip(f"{src} not found")
    out = tmp_path_factory.mktemp("clip") / "clip.mp4"
    write_video(out, (f for _, _, f in iter_frames(src, max_frames=50)), 25.0, audio_from=src, audio_duration=2.0)
    return out


@pytest.fixture(scope="module")
def take(data_dir, arkit_rig):
    """The first 3 s of a real Live Link Face take (30 fps) on the ARKit rig, with a head turning and
    nodding (the take's own head rotation is zero there)."""
    from faceretarget.io import read_performance

    p = read_performance(data_dir / "livelinkface" / "S07-001.csv")
    n = int(np.searchsorted(p.times, 3.0))
    W = arkit_rig.map_weights(p.names, p.weights, warn=False)[:n]
    t = p.times[:n]
    angles = np.stack([20 * np.sin(2 * np.pi * t / 3), 8 * np.sin(2 * np.pi * t / 2), 0 * t], axis=1)
    return W, t, HeadPose.from_euler("YXZ", angles, degrees=True)


def _decode(path: Path) -> list[np.ndarray]:
    from faceretarget.io import iter_frames

    return [f for _, _, f in iter_frames(path)]


def test_preview_video_side_by_side_with_audio(clip, take, arkit_rig, tmp_path):
    from faceretarget.io import probe_video
    from faceretarget.pipelines import TakeSampler, write_animation_preview

    W, times, head = take
    out = tmp_path / "preview.mp4"
    lines: list[str] = []
    info = write_animation_preview(out, clip, arkit_rig, W, times, head, log=lines.append)
    src, got = probe_video(clip), probe_video(out)
    frames, inputs = _decode(out), _decode(clip)
    assert len(frames) == info["frames"] == len(inputs) == 50
    assert got.fps == pytest.approx(src.fps) == pytest.approx(25.0)
    assert (got.width, got.height) == (512 + 512, 512) == (info["width"], info["height"])
    assert got.has_audio and got.audio_rate == src.audio_rate
    assert len(lines) == 1 and info["backend"] in lines[0]
    assert info["fps"] > 0 and 0 < info["render_s"] <= info["total_s"]
    # left: the video itself; right: the character at the video frame's time (t = 1.2 s falls between
    # take frames 36 and 37) with the head turned 11.8 degrees and nodding, through the lossy codec:
    # measured 2.2 grey levels on the video, 1.8 on the character's pixels (24.4 from its neutral)
    k = 30
    sampler = TakeSampler(arkit_rig, W, times, head)
    with MeshRenderer(arkit_rig.neutral, (512, 512), backend="numpy", mm_per_unit=arkit_rig.mm_per_unit) as r:
        R, t = sampler.head_at(k / 25.0)
        want = r.render(sampler.vertices_at(k / 25.0), R, t)
        rest = r.render(arkit_rig.neutral.vertices)
    left, right = frames[k][:, :512].astype(np.int16), frames[k][:, 512:].astype(np.int16)
    face = _mask(want) | _mask(rest)
    err_video = np.abs(left - inputs[k]).mean()
    err_want, err_rest = (np.abs(right - x)[face].mean() for x in (want, rest))
    print(f"video {err_video:.2f}, character {err_want:.2f} (neutral: {err_rest:.2f}) grey levels")
    assert err_video < 3.0
    assert err_want < 3.0
    assert err_rest > 3 * err_want  # the character moves: it is not the neutral


def test_preview_scales_the_video_and_follows_frame_times(clip, take, arkit_rig, tmp_path):
    from faceretarget.pipelines import TakeSampler, write_animation_preview

    W, times, head = take
    out = tmp_path / "small.mp4"
    ft = np.linspace(2.9, 0.1, 12)  # the take played backwards for 12 frames
    info = write_animation_preview(out, clip, arkit_rig, W, times, None, frame_times=ft, size=320,
                                   backend="numpy", log=lambda *_: None)
    frames = _decode(out)
    assert info["backend"] == "numpy" and len(frames) == 12
    assert frames[0].shape == (320, 640, 3)
    sampler = TakeSampler(arkit_rig, W, times)
    with MeshRenderer(arkit_rig.neutral, (320, 320), backend="numpy", mm_per_unit=arkit_rig.mm_per_unit) as r:
        want = r.render(sampler.vertices_at(ft[5]))
    assert np.abs(frames[5][:, 320:].astype(np.int16) - want).mean() < 2.0


def test_preview_shares_the_videos_clock(clip, arkit_rig, tmp_path):
    """A take starting 1 s into the video (a capture whose first second had no face) with the jaw
    opening over 2 s: frames before 1 s hold its first frame, later ones show the take at the video
    frame's own time (measured 2.0 grey levels from those, 6.3 and 9.8 from what a clock starting at
    the take's first frame would show)."""
    from faceretarget.pipelines import TakeSampler, write_animation_preview

    late = np.arange(1.0, 4.0, 1 / 30)
    W = np.zeros((len(late), arkit_rig.n_shapes))
    W[:, arkit_rig.index("jawOpen")] = np.clip((late - 1.0) / 2.0, 0.0, 1.0)  # opens over 2 s
    out = tmp_path / "late.mp4"
    write_animation_preview(out, clip, arkit_rig, W, late, None, size=256, backend="numpy", log=lambda *_: None)
    frames = _decode(out)
    sampler = TakeSampler(arkit_rig, W, late)
    with MeshRenderer(arkit_rig.neutral, (256, 256), backend="numpy", mm_per_unit=arkit_rig.mm_per_unit) as r:
        # video frame, the take time it shows, the time a clock starting at times[0] would show
        for k, t, alt in [(10, 1.0, 1.4), (45, 1.8, 2.8)]:
            want, other = r.render(sampler.vertices_at(t)), r.render(sampler.vertices_at(alt))
            got = frames[k][:, 256:].astype(np.int16)
            face = _mask(want) | _mask(other)
            err_want, err_other = (np.abs(got - x)[face].mean() for x in (want, other))
            print(f"frame {k}: {err_want:.2f} grey levels from take time {t} s, {err_other:.2f} from {alt} s")
            assert err_want < 0.5 * err_other, k


def test_preview_ends_with_the_animation_not_the_video(clip, take, arkit_rig, tmp_path):
    """Issue 34: a take of the video's first second (``--max-frames``) previews one second, not the whole
    video with the last pose held (was: 50 frames, 2 s of audio)."""
    from faceretarget.io import probe_video
    from faceretarget.pipelines import write_animation_preview

    W, times, head = take
    n = int(np.searchsorted(times, 1.0))                 # 31 take frames: 0 .. 0.9999 s
    out = tmp_path / "short.mp4"
    info = write_animation_preview(out, clip, arkit_rig, W[:n], times[:n], None, size=128, backend="numpy",
                                   log=lambda *_: None)
    got = probe_video(out)
    # video frames at 0 .. 1.0 s (25 fps; a frame within half a frame of the take's end shows it)
    assert info["frames"] == len(_decode(out)) == 26
    assert got.duration == pytest.approx(1.04, abs=0.1)


def test_take_sampler_interpolates_and_holds(arkit_rig):
    from faceretarget.pipelines import TakeSampler

    K = arkit_rig.n_shapes
    W = np.zeros((3, K))
    W[1, 0], W[2, 0] = 1.0, 0.5
    times = np.array([0.0, 0.1, 0.2])
    head = HeadPose.from_euler("YXZ", [[0.0, 0, 0], [np.nan] * 3, [40.0, 0, 0]], [[0, 0, 0.5]] * 3, degrees=True)
    s = TakeSampler(arkit_rig, W, times, head)
    assert s.weights_at(0.05)[0] == pytest.approx(0.5) and s.weights_at(0.15)[0] == pytest.approx(0.75)
    assert s.weights_at(-1.0)[0] == 0.0 and s.weights_at(9.0)[0] == 0.5  # held at the ends
    R, t = s.head_at(0.05)  # a quarter of the way from 0 to 40 degrees (frame 1 has no pose)
    assert Rotation.from_matrix(R).as_euler("YXZ", degrees=True)[0] == pytest.approx(10.0)
    np.testing.assert_allclose(t, 0.0)  # translation relative to its median: the head stays in frame


def test_preview_errors_write_nothing(clip, take, arkit_rig, tmp_path, monkeypatch):
    from faceretarget.pipelines import write_animation_preview

    W, times, head = take
    out = tmp_path / "p.mp4"
    T, K = W.shape
    with pytest.raises(InvalidDataError, match=rf"weights have shape \({T}, {K - 1}\), expected \(T, {K}\)"):
        write_animation_preview(out, clip, arkit_rig, W[:, 1:], times, head, log=lambda *_: None)
    with pytest.raises(InvalidDataError, match=rf"times have shape \({T - 1},\), expected \({T},\)"):
        write_animation_preview(out, clip, arkit_rig, W, times[:-1], head, log=lambda *_: None)
    with pytest.raises(InputFileError, match="missing.mp4: file not found"):
        write_animation_preview(out, tmp_path / "missing.mp4", arkit_rig, W, times, head, log=lambda *_: None)
    before = clip.read_bytes()
    with pytest.raises(OutputError, match="refusing to write over the input"):
        write_animation_preview(clip, clip, arkit_rig, W, times, head, backend="numpy", log=lambda *_: None)
    assert clip.read_bytes() == before

    # a failure half-way through (here: the renderer, at the 6th frame) leaves no file and no temporary
    calls = {"n": 0}
    real = MeshRenderer.render

    def failing(self, *a, **k):
        calls["n"] += 1
        if calls["n"] == 6:
            raise InvalidDataError("renderer failed at frame 5")
        return real(self, *a, **k)

    monkeypatch.setattr(MeshRenderer, "render", failing)
    with pytest.raises(InvalidDataError, match="frame 5"):
        write_animation_preview(out, clip, arkit_rig, W, times, head, backend="numpy", log=lambda *_: None)
    assert calls["n"] == 6
    assert sorted(p.name for p in tmp_path.iterdir()) == []
