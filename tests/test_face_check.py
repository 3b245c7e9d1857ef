"""Not a face (issue 23): a full-body take is refused by name, size and labels; stray and mostly-missing markers
are left out of selection and solve, named on one warning line; the real facial takes are untouched."""

from __future__ import annotations

import subprocess
import sys
import warnings

import numpy as np
import pytest

from faceretarget.errors import DataWarning, NotAFaceError
from faceretarget.io import read_c3d, read_rig, write_c3d
from faceretarget.names import marker_region
from faceretarget.numerics import FACE_MAX_MM, face_markers, face_mesh
from faceretarget.performance import Performance
from faceretarget.pipelines import check_face_keys, retarget_take, select_keys

FACIAL = ("Jaw", "Cheeks", "Eyebrows", "Nose")
WALK = "conformance/c3d/sample_26_Walking_Hybrid_1_1.c3d"


def _cli(*args) -> subprocess.CompletedProcess:
    code = "import sys; from faceretarget.cli import main; sys.exit(main(sys.argv[1:]))"
    return subprocess.run([sys.executable, "-c", code, *map(str, args)], capture_output=True, text=True, timeout=600)


def _with_stray(take: Performance, share: float = 0.01, offset_mm: float = 364.0, seed: int = 0) -> Performance:
    """The take plus a marker 'Unlabeled1' present in ``share`` of the frames, ``offset_mm`` off the face."""
    rng = np.random.default_rng(seed)
    T = take.n_frames
    stray = np.full((T, 1, 3), np.nan)
    frames = rng.choice(T, size=max(1, round(share * T)), replace=False)
    centre = np.nanmedian(take.points, axis=1)                              # each frame's face centre
    stray[frames, 0] = centre[frames] + [offset_mm, 40.0, 0.0] + rng.normal(0, 5.0, (len(frames), 3))
    return take.with_points(np.concatenate([take.points, stray], axis=1), list(take.labels) + ["Unlabeled1"])


@pytest.mark.parametrize("name", FACIAL)
def test_real_facial_takes_are_faces_untouched(data_dir, name):
    take = read_c3d(data_dir / "facial-mocap" / f"{name}.c3d")
    chk = face_markers(take.points, take.labels, take.unit, source=name)
    assert chk.keep.all() and chk.dropped == {}
    assert 150 < chk.span_mm < 260                                   # a face: 185-188 mm here
    assert len(chk.labels["face"]) == 41 and chk.labels["body"] == []


def test_full_body_take_is_not_a_face(data_dir):
    take = read_c3d(data_dir / WALK)
    with pytest.raises(NotAFaceError, match=r"Walking_Hybrid_1_1.c3d: not a face: its 24 markers span 1,0\d\d mm, "
                                            r"labels name body places \(R_ASIS, L_ASIS, SACRUM"):
        select_keys(take, 10)


def test_full_body_take_exits_2_in_keys_select_and_retarget(data_dir, tmp_path):
    r = _cli("keys", "select", "--performance", data_dir / WALK, "--k", 10, "--out", tmp_path / "keys")
    assert r.returncode == 2, r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and "not a face" in lines[0] and "mm" in lines[0]
    assert not (tmp_path / "keys").exists()
    # retarget with a facial take's keyshapes: the walking take is refused before any solve
    assert _cli("keys", "select", "--performance", data_dir / "facial-mocap" / "Jaw.c3d", "--k", 8,
                "--out", tmp_path / "jaw").returncode == 0
    r = _cli("retarget", "--performance", data_dir / WALK, "--source-keys", tmp_path / "jaw",
             "--target-keys", tmp_path / "jaw", "--out", tmp_path / "out.npz")
    assert r.returncode == 2 and "not a face" in r.stderr and len(r.stderr.strip().splitlines()) == 1
    assert not (tmp_path / "out.npz").exists()


def test_stray_marker_is_named_and_ignored(data_dir, tmp_path):
    """A real facial take plus a stray 'Unlabeled1' in 1 % of the frames, 364 mm off the face: the keyshapes chosen
    and the retargeted weights are those of the clean take, and one warning names the marker."""
    clean = read_c3d(data_dir / "facial-mocap" / "Jaw.c3d")
    path = write_c3d(tmp_path / "stray.c3d", _with_stray(clean))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        stray = read_c3d(path)
        sel = select_keys(stray, 10)
    msgs = [str(w.message) for w in caught if issubclass(w.category, DataWarning)]
    assert msgs == [f"{path}: 1 marker(s) left out of selection and solve: Unlabeled1 (present in 1% of frames)"]
    ref = select_keys(clean, 10)
    assert sel.frames == ref.frames
    assert sel.geometry.labels == clean.labels
    assert sel.error == pytest.approx(ref.error, rel=1e-9)
    # the solve: the clean take's keyshapes, the stray take retargeted = the clean take retargeted
    from faceretarget.io import read_keys, write_keyshapes

    write_keyshapes(Performance.from_points(ref.geometry.points, ref.geometry.labels, times=clean.times, unit="mm"),
                    ref.frames, tmp_path / "keys", neutral=ref.neutral)
    keys, labels = read_keys(tmp_path / "keys")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        a = retarget_take(stray, keys, keys, source_labels=labels).result.weights
        b = retarget_take(clean, keys, keys, source_labels=labels).result.weights
    np.testing.assert_allclose(a, b, atol=1e-9)


def test_far_and_mostly_missing_markers(data_dir):
    take = read_c3d(data_dir / "facial-mocap" / "Nose.c3d")
    T = take.n_frames
    far = np.nanmedian(take.points, axis=1, keepdims=True) + [[[0.0, 0.0, 420.0]]]     # every frame, on a table
    half = take.points[:, :1].copy() + 1.0
    half[: int(0.6 * T)] = np.nan                                                     # present in 40 %
    pts = np.concatenate([take.points, far, half], axis=1)
    chk = face_markers(pts, list(take.labels) + ["Table", "Chin_copy"], "mm", source="nose")
    assert set(chk.dropped) == {"Table", "Chin_copy"}
    assert "times as far from the face centre" in chk.dropped["Table"] and "40%" in chk.dropped["Chin_copy"]
    assert chk.keep[:41].all()


def test_units_and_labels_decide(data_dir):
    """The same facial take in metres is the same face; mislabelled 'mm' that are micrometres are not a face, nor
    is a face-sized take labelled like a body."""
    take = read_c3d(data_dir / "facial-mocap" / "Cheeks.c3d")
    assert face_markers(take.points / 1000.0, take.labels, "m").span_mm == pytest.approx(
        face_markers(take.points, take.labels, "mm").span_mm)
    with pytest.raises(NotAFaceError, match="not a face: its 41 markers span 186,691 mm"):
        face_markers(take.points * 1000.0, take.labels, "mm", source="x")        # 'mm' that are micrometres
    body = ["LASI", "RASI", "LKNE", "RKNE", "LANK", "RANK", "LHEE", "RHEE", "LTOE", "RTOE"] * 5
    with pytest.raises(NotAFaceError, match="labels name body places"):
        face_markers(take.points[:, :41], (body + ["C7"])[:41], "mm", source="x")
    assert FACE_MAX_MM == 500.0
    assert [marker_region(s) for s in ("Leyebrow_M", "Rcheek_up", "ForeHead_L", "L_SHANK_2", "root-1")] == \
        ["face", "face", "face", "body", None]


def test_meshes_by_the_part_that_moves(data_dir):
    """A mesh take is checked by the span of its moving part (metres, cm and mm alike): the ARKit face rig
    played (its shapes move only the face) passes; a 1.7 m body that moves everywhere does not."""
    rig = read_rig(data_dir / "arkit-face")
    check_face_keys(rig)                                                                  # the source keys: a face
    W = np.random.default_rng(0).uniform(0, 1, (10, rig.n_shapes))
    span = face_mesh(rig.evaluate(W), rig.unit, source="arkit")
    assert 50 < span < 300
    body = np.random.default_rng(1).uniform(0, 1.7, (1, 500, 3)) + np.linspace(0, 0.3, 8)[:, None, None]
    with pytest.raises(NotAFaceError, match=r"walk: not a face: the part of the mesh that moves spans 1,\d\d\d mm"):
        face_mesh(body, "m", source="walk")
    with pytest.raises(NotAFaceError, match="not a face"):
        select_keys(Performance(np.arange(8) / 30, 30.0, vertices=body, unit="m", source="walk"), 3)


def test_head_motion_from_markers_needs_a_face(data_dir):
    """Head motion from markers chooses the most rigid markers: of a walking take, a leg. Refused."""
    from faceretarget.io import read_head_motion

    with pytest.raises(NotAFaceError, match="not a face"):
        read_head_motion(data_dir / WALK)
    assert read_head_motion(data_dir / "facial-mocap" / "Jaw.c3d").head.valid.all()


def test_tracked_landmarks_in_pixels_are_not_judged_by_size():
    """Video landmarks carry unit 'px' (or are 2-D): no length scale, so the span is not checked (a face fills a
    1080p frame at 900 px); strays are still found."""
    rng = np.random.default_rng(0)
    pts = rng.uniform(0, 900, (20, 68, 3))
    chk = face_markers(pts, [f"lm{i}" for i in range(68)], "px", source="video")
    assert chk.keep.all() and np.isnan(chk.span_mm)
    assert np.isnan(face_mesh(pts, "px")) and np.isnan(face_markers(pts[..., :2], None, None).span_mm)
