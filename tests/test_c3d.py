"""C3D marker files: read, write, missing samples, errors, and the shared facial mocap takes."""

from __future__ import annotations

import ezc3d
import numpy as np
import pytest

from faceretarget.errors import InputFileError, InvalidDataError, OutputError
from faceretarget.io import read_c3d, write_c3d
from faceretarget.performance import Performance

TAKES = {"Jaw": 1590, "Cheeks": 1499, "Eyebrows": 902, "Nose": 962}


def _take(T=40, P=5, fps=100.0, start_frame=0, seed=0):
    rng = np.random.default_rng(seed)
    pts = rng.uniform(-300, 900, size=(T, P, 3))
    pts[3, 1] = np.nan
    pts[10:14, 4] = np.nan
    times = (start_frame + np.arange(T)) / fps
    return Performance(times=times, fps=fps, points=pts, labels=[f"mk{i}" for i in range(P)], unit="mm",
                       source="synthetic")


def _raw_c3d(path, points, residuals, labels, rate=60.0):
    """Write points (3, P, T) with given residuals (P, T) straight through ezc3d."""
    c = ezc3d.c3d()
    c["parameters"]["POINT"]["RATE"]["value"] = [rate]
    c["parameters"]["POINT"]["LABELS"]["value"] = labels
    c["parameters"]["POINT"]["UNITS"]["value"] = ["mm"]
    data = np.ones((4,) + points.shape[1:])
    data[:3] = points
    c["data"]["points"] = data
    c["data"]["meta_points"] = {"residuals": residuals[None].astype(float)}
    c.write(str(path))


def test_round_trip(tmp_path):
    perf = _take(start_frame=7)
    out = write_c3d(tmp_path / "take.c3d", perf)
    assert out == tmp_path / "take.c3d"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["take.c3d"]  # nothing left behind
    back = read_c3d(out)
    assert back.labels == perf.labels
    assert back.fps == 100.0 and back.unit == "mm" and back.source == str(out)
    np.testing.assert_allclose(back.times, perf.times, atol=1e-12)
    np.testing.assert_array_equal(np.isnan(back.points), np.isnan(perf.points))
    np.testing.assert_allclose(back.points, perf.points, rtol=1e-6, atol=1e-4)  # C3D stores float32


def test_round_trip_defaults(tmp_path):
    pts = np.arange(2 * 3 * 3, dtype=float).reshape(2, 3, 3) + 1.0
    perf = Performance.from_points(pts, fps=30)  # no labels, no unit
    back = read_c3d(write_c3d(tmp_path / "x.c3d", perf, unit="m"))
    assert back.labels == ["M001", "M002", "M003"]
    assert back.unit == "m" and back.fps == 30.0
    np.testing.assert_allclose(back.points, pts, rtol=1e-6)


def test_negative_residual_and_zeros_are_missing(tmp_path):
    T, P = 6, 3
    pts = np.arange(3 * P * T, dtype=float).reshape(3, P, T) + 10.0
    res = np.zeros((P, T))
    res[1, 2] = -1.0  # invalid sample with non-zero coordinates
    pts[:, 2, 4] = 0.0  # a gap written as the origin
    _raw_c3d(tmp_path / "gaps.c3d", pts, res, ["a", " b ", "c"])
    perf = read_c3d(tmp_path / "gaps.c3d")
    assert perf.labels == ["a", "b", "c"]  # blanks stripped
    missing = np.isnan(perf.points).any(axis=2)
    assert np.isnan(perf.points[missing]).all()
    assert sorted(zip(*np.nonzero(missing), strict=True)) == [(2, 1), (4, 2)]
    kept = read_c3d(tmp_path / "gaps.c3d", zero_is_missing=False)
    np.testing.assert_array_equal(kept.points[4, 2], [0.0, 0.0, 0.0])
    assert np.isnan(kept.points[2, 1]).all()


def test_repeated_and_empty_labels(tmp_path):
    pts = np.ones((3, 3, 4))
    _raw_c3d(tmp_path / "dup.c3d", pts, np.zeros((3, 4)), ["nose", "nose", ""])
    with pytest.warns(UserWarning, match="repeated marker label"):
        perf = read_c3d(tmp_path / "dup.c3d")
    assert perf.labels == ["nose", "nose_2", "M003"]


def test_marker_never_present_warns(tmp_path):
    pts = np.ones((3, 2, 4))
    res = np.zeros((2, 4))
    res[1] = -1
    _raw_c3d(tmp_path / "never.c3d", pts, res, ["ok", "ghost"])
    with pytest.warns(UserWarning, match="missing in every frame: ghost"):
        perf = read_c3d(tmp_path / "never.c3d")
    assert np.isnan(perf.points[:, 1]).all()


def test_missing_and_unreadable_files(tmp_path):
    with pytest.raises(InputFileError, match="nope.c3d: file not found"):
        read_c3d(tmp_path / "nope.c3d")
    with pytest.raises(InputFileError, match="not a file"):
        read_c3d(tmp_path)
    bad = tmp_path / "bad.c3d"
    bad.write_text("this is not a C3D file at all")
    with pytest.raises(InputFileError, match="bad.c3d: cannot read as a C3D file"):
        read_c3d(bad)
    empty = tmp_path / "empty.c3d"
    empty.write_bytes(b"")
    with pytest.raises(InputFileError, match="empty.c3d"):
        read_c3d(empty)


def test_file_without_points(tmp_path):
    c = ezc3d.c3d()
    c["parameters"]["POINT"]["RATE"]["value"] = [60]
    c["parameters"]["ANALOG"]["RATE"]["value"] = [600]
    c["parameters"]["ANALOG"]["LABELS"]["value"] = ["emg"]
    c["data"]["analogs"] = np.zeros((1, 1, 100))
    del c["data"]["rotations"]
    c.write(str(tmp_path / "analog.c3d"))
    with pytest.raises(InputFileError, match="analog.c3d: the C3D file holds no 3D point data"):
        read_c3d(tmp_path / "analog.c3d")


def test_write_rejects(tmp_path):
    w = Performance.from_weights(np.zeros((3, 1)), ["jawOpen"], fps=30)
    with pytest.raises(InvalidDataError, match="holds 3D points, this take holds weights"):
        write_c3d(tmp_path / "w.c3d", w)
    flat = Performance.from_points(np.zeros((3, 2, 2)), fps=30)
    with pytest.raises(InvalidDataError, match="2D points"):
        write_c3d(tmp_path / "f.c3d", flat)
    uneven = Performance.from_points(np.ones((3, 2, 3)), times=[0.0, 0.1, 0.25], fps=10)
    with pytest.raises(InvalidDataError, match=r"frame 2 .* not on the 10 fps grid"):
        write_c3d(tmp_path / "u.c3d", uneven)
    with pytest.raises(OutputError, match="does not exist"):
        write_c3d(tmp_path / "no" / "such" / "x.c3d", _take())
    assert sorted(p.name for p in tmp_path.iterdir()) == []


def test_write_off_grid_start_warns(tmp_path):
    perf = Performance.from_points(np.ones((3, 1, 3)), times=np.array([0.05, 0.15, 0.25]), fps=10)
    with pytest.warns(UserWarning, match="not a whole frame"):
        write_c3d(tmp_path / "s.c3d", perf)
    np.testing.assert_allclose(read_c3d(tmp_path / "s.c3d").times, [0.0, 0.1, 0.2])


@pytest.mark.parametrize("name", sorted(TAKES))
def test_real_takes(data_dir, name):
    perf = read_c3d(data_dir / "facial-mocap" / f"{name}.c3d")
    assert perf.points.shape == (TAKES[name], 41, 3)
    assert perf.fps == 60.0 and perf.unit == "mm"
    assert len(set(perf.labels)) == 41
    assert {"Chin", "Mouth_Lend", "Leye_Up", "ForeHead_M", "NoseTop"} <= set(perf.labels)
    assert perf.times[0] == 0.0 and np.allclose(np.diff(perf.times), 1 / 60)
    assert np.isfinite(perf.points).all()  # these takes have no gaps
    # a face in millimetres: about 14 cm wide and 22 cm tall
    extent = np.ptp(perf.points[0], axis=0)
    assert 100 < extent.max() < 300


def test_truncated_file_warns(data_dir, tmp_path):
    cut = tmp_path / "cut.c3d"
    cut.write_bytes((data_dir / "facial-mocap" / "Jaw.c3d").read_bytes()[:20000])
    with pytest.warns(UserWarning, match="header declares 1590; the file may be truncated"):
        perf = read_c3d(cut)
    assert 0 < perf.n_frames < 1590
