"""Live Link Face CSV: real takes, timecode rates, junk rows, errors naming file/line/column, round trips."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from faceretarget.errors import DataWarning, InputFileError, InvalidDataError
from faceretarget.headpose import HeadPose
from faceretarget.io import read_livelinkface, write_livelinkface
from faceretarget.io._livelinkface import EYE_COLUMNS, HEAD_COLUMNS, LLF_NAMES
from faceretarget.mesh import Mesh
from faceretarget.names import ARKIT_NAMES
from faceretarget.performance import Performance
from faceretarget.rig import Rig

HEADER = ",".join(("Timecode", "BlendShapeCount") + LLF_NAMES + HEAD_COLUMNS + EYE_COLUMNS)
NCOL = 2 + 52 + 9


def _row(tc: str, value: float = 0.1, n: int = 61) -> str:
    return f"{tc},{n}," + ",".join([f"{value:.10f}"] * n)


def _csv(tmp_path, rows, name="take.csv", header=HEADER):
    p = tmp_path / name
    p.write_text(header + "\n" + "".join(r + "\n" for r in rows))
    return p


def _frames(n, start="01:02:03", step=2, rate=60):
    out = []
    f = 0
    s = int(start[-2:])
    for _ in range(n):
        out.append(f"{start[:-2]}{s:02d}:{f:02d}.500")
        f += step
        if f >= rate:
            f -= rate
            s += 1
    return out


# ------------------------------------------------------------------------------------ real takes
TAKES = {  # file: (rows kept, expected fps)
    "MySlate_3_Jason_Millers_iPhone.csv": (328, 60.0),
    "S07-001.csv": (2028, 30.0),
    "alex_rom_3.csv": (4030, 30.0),
    "apfel.csv": (1891, 30.0),
}


@pytest.mark.parametrize("name", sorted(TAKES))
def test_real_takes(data_dir, name):
    with warnings.catch_warnings(record=True) as ws:
        warnings.simplefilter("always")
        perf, info = read_livelinkface(data_dir / "livelinkface" / name, with_info=True)
    n, fps = TAKES[name]
    assert perf.n_frames == n
    assert perf.fps == pytest.approx(fps, rel=0.01)
    assert perf.names == list(ARKIT_NAMES)
    assert perf.times[0] == 0.0 and np.all(np.diff(perf.times) > 0)
    assert perf.head.n_frames == n and info.eye_rotation.shape == (n, 6)
    assert info.timecode_rate == 60
    assert 0.0 <= perf.weights.min() and perf.weights.max() < 1.2
    if name == "apfel.csv":  # 35 rows where the app lost the face, one warning for all of them
        assert len(ws) == 1 and "35 row(s)" in str(ws[0].message) and "224-226" in str(ws[0].message)
        assert len(info.dropped_lines) == 35
    else:
        assert not ws


def test_real_round_trip(data_dir, tmp_path):
    src = data_dir / "livelinkface" / "MySlate_3_Jason_Millers_iPhone.csv"
    perf, info = read_livelinkface(src, with_info=True)
    out = write_livelinkface(tmp_path / "out.csv", perf, rate=info.timecode_rate,
                             start=info.start_timecode, eye_rotation=info.eye_rotation)
    back, info2 = read_livelinkface(out, with_info=True)
    assert back.names == perf.names and info2.start_timecode == info.start_timecode
    np.testing.assert_allclose(back.weights, perf.weights, atol=1e-9)
    np.testing.assert_allclose(back.times, perf.times, atol=1e-6)
    np.testing.assert_allclose(info2.eye_rotation, info.eye_rotation, atol=1e-9)
    # the same text, line for line, as the app wrote (values have 10 decimals in both)
    assert out.read_text().splitlines()[1] == src.read_text().splitlines()[1]


def test_extra_column_warns_once_when_mapped_onto_a_rig(tmp_path):
    header = HEADER.replace("TongueOut,", "TongueOut,MyCustomShape,")
    rows = [f"00:00:00:{i:02d}.000,61," + ",".join(["0.25"] * (NCOL - 1)) for i in range(5)]
    perf = read_livelinkface(_csv(tmp_path, rows, header=header))
    assert "myCustomShape" in perf.names and len(perf.names) == 53
    base = Mesh.from_triangles(np.eye(3), [[0, 1, 2]])
    rig = Rig(base, ["jawOpen", "eyeBlink_L"], np.zeros((2, 3, 3)), name="tiny")
    with pytest.warns(UserWarning) as ws:
        w = rig.map_weights(perf.names, perf.weights, source=perf.source)
    assert len(ws) == 1
    msg = str(ws[0].message)
    assert "myCustomShape" in msg and "tongueOut" in msg and "take.csv" in msg
    assert w.shape == (5, 2) and np.all(w == 0.25)


# ------------------------------------------------------------------------------------ synthetic
def test_write_read_round_trip(tmp_path):
    rng = np.random.default_rng(1)
    T = 50
    times = np.arange(T) / 30.0 + 0.004  # sub-frame offsets
    perf = Performance.from_weights(rng.random((T, 52)), ARKIT_NAMES, times=times,
                                    head=HeadPose.from_livelinkface(rng.normal(size=(T, 3)) * 0.1))
    out = write_livelinkface(tmp_path / "rt.csv", perf, start="10:00:00:00.000")
    text = out.read_text().splitlines()
    assert text[0] == HEADER and text[1].startswith("10:00:00:00.000,61,")
    assert text[2].startswith("10:00:00:02.000,61,")
    assert all(len(line.split(",")) == NCOL for line in text)
    back = read_livelinkface(out)
    assert back.names == list(ARKIT_NAMES)
    np.testing.assert_allclose(back.weights, perf.weights, atol=1e-9)
    np.testing.assert_allclose(back.times, perf.times - perf.times[0], atol=1e-6)
    np.testing.assert_allclose(back.head.to_livelinkface(), perf.head.to_livelinkface(), atol=1e-9)
    assert back.fps == pytest.approx(30.0)


def test_writer_maps_names_and_averages_split_halves(tmp_path):
    perf = Performance.from_weights([[0.2, 0.4, 0.9, 0.5]], ["browInnerUp_L", "browInnerUp_R",
                                                             "JawOpen", "cheekRaiser_L"], times=[0.0])
    with pytest.warns(UserWarning, match="cheekRaiser_L"):
        out = write_livelinkface(tmp_path / "m.csv", perf)
    back = read_livelinkface(out)
    w = dict(zip(back.names, back.weights[0], strict=True))
    assert w["browInnerUp"] == pytest.approx(0.3) and w["jawOpen"] == pytest.approx(0.9)
    assert w["eyeBlinkLeft"] == 0.0


def test_timecode_rate_is_inferred_not_assumed(tmp_path):
    rows = [_row(f"00:00:0{s}:{f:02d}.000") for s in range(2) for f in range(0, 24, 2)]
    _, info = read_livelinkface(_csv(tmp_path, rows), with_info=True)
    assert info.timecode_rate == 24
    perf = read_livelinkface(_csv(tmp_path, rows, "b.csv"), timecode_rate=30)
    assert perf.fps == pytest.approx(15.0)


def test_midnight_wrap(tmp_path):
    rows = [_row("23:59:59:56.000"), _row("23:59:59:58.000"), _row("00:00:00:00.000"),
            _row("00:00:00:02.000")]
    perf, info = read_livelinkface(_csv(tmp_path, rows), with_info=True)
    np.testing.assert_allclose(perf.times, np.arange(4) * 2 / 60, atol=1e-9)
    assert info.start_seconds == pytest.approx(86400 - 4 / 60)
    # a row hours back in time is junk, not a second midnight
    rows = [_row("12:00:00:00.000"), _row("12:00:00:02.000"), _row("03:00:00:00.000")]
    with pytest.warns(UserWarning, match="line\\(s\\) 4 "):
        assert read_livelinkface(_csv(tmp_path, rows, "b.csv")).n_frames == 2


def test_trailing_junk_rows_are_dropped_with_one_warning(tmp_path):
    good = [_row(tc) for tc in _frames(6)]
    junk = ["01:02:03:40.5", "garbage,1,2", _row("01:02:03:00.000")]  # short, bad, goes back in time
    with pytest.warns(UserWarning) as ws:
        perf = read_livelinkface(_csv(tmp_path, good + junk))
    assert len(ws) == 1
    assert "take.csv" in str(ws[0].message) and "line(s) 8-10" in str(ws[0].message)
    assert perf.n_frames == 6


def test_junk_row_in_the_middle_names_the_line(tmp_path):
    rows = [_row(tc) for tc in _frames(6)]
    rows[3] = rows[3][:40]
    with pytest.raises(InputFileError, match=r"take\.csv: line 5: has \d+ columns, the header has 63"):
        read_livelinkface(_csv(tmp_path, rows))
    rows = [_row(tc) for tc in _frames(6)]
    rows[2] = rows[2].replace("0.1000000000", "abc", 1)
    with pytest.raises(InputFileError, match=r"take\.csv: line 4: column 'EyeBlinkLeft' value 'abc'"):
        read_livelinkface(_csv(tmp_path, rows))
    rows = [_row(tc) for tc in _frames(6)]
    rows[2] = _row("01:02:03:00.000")
    with pytest.raises(InputFileError, match=r"line 4: time does not increase"):
        read_livelinkface(_csv(tmp_path, rows))


def test_nan_weight_names_file_line_and_column(tmp_path):
    rows = [_row(tc) for tc in _frames(4)]
    cells = rows[2].split(",")
    cells[2 + ARKIT_NAMES.index("jawOpen")] = "nan"
    rows[2] = ",".join(cells)
    with pytest.raises(InvalidDataError, match=r"take\.csv: line 4: column 'JawOpen' is nan"):
        read_livelinkface(_csv(tmp_path, rows))
    cells[2 + ARKIT_NAMES.index("jawOpen")] = "inf"
    rows[2] = ",".join(cells)
    with pytest.raises(InvalidDataError, match=r"take\.csv: line 4: column 'JawOpen' is inf"):
        read_livelinkface(_csv(tmp_path, rows))


def test_empty_csv_names_the_file(tmp_path):
    p = tmp_path / "empty.csv"
    p.write_text("")
    with pytest.raises(InputFileError, match=r"empty\.csv: empty file"):
        read_livelinkface(p)
    with pytest.raises(InputFileError, match=r"hdr\.csv: no valid data row"):
        read_livelinkface(_csv(tmp_path, [], "hdr.csv"))


def test_all_junk_csv_names_the_file(tmp_path):
    rows = ["not,a,row", "12:00", "x" * 20]
    with pytest.raises(InputFileError, match=r"junk\.csv: no valid data row \(3 row"):
        read_livelinkface(_csv(tmp_path, rows, "junk.csv"))


def test_not_a_live_link_face_csv(tmp_path):
    p = tmp_path / "other.csv"
    p.write_text("a,b,c\n1,2,3\n")
    with pytest.raises(InputFileError, match=r"other\.csv: line 1: header must start with 'Timecode'"):
        read_livelinkface(p)
    with pytest.raises(InputFileError, match=r"missing\.csv: file not found"):
        read_livelinkface(tmp_path / "missing.csv")


# ---------------------------------------------------------------------- takes that drive nothing (issue 14)
def _csv_with_header(data_dir, tmp_path, edit, rows=30):
    lines = (data_dir / "livelinkface" / "S07-001.csv").read_text().splitlines()[: rows + 1]
    header = lines[0].split(",")
    header, keep = edit(header)
    body = [",".join(c for j, c in enumerate(line.split(",")) if j in keep) for line in lines[1:]]
    out = tmp_path / "edited.csv"
    out.write_text(",".join(header) + "\n" + "\n".join(body) + "\n")
    return out


def test_a_csv_without_curves_is_an_error(data_dir, tmp_path):
    from faceretarget.errors import InputFileError

    def only_head(h):
        keep = [0, 1] + [j for j, c in enumerate(h) if c.startswith("Head")]
        return [h[j] for j in keep], set(keep)

    with pytest.raises(InputFileError, match="no blendshape curve columns.*drive nothing"):
        read_livelinkface(_csv_with_header(data_dir, tmp_path, only_head))

    def unknown(h):
        return [c if j < 2 or c.startswith(("Head", "LeftEye", "RightEye")) else f"col{j}" for j, c in enumerate(h)], \
            set(range(len(h)))

    with pytest.raises(InputFileError, match="none of its .* curve columns is an ARKit blendshape"):
        read_livelinkface(_csv_with_header(data_dir, tmp_path, unknown))


def test_a_missing_standard_curve_is_a_warning_naming_it(data_dir, tmp_path):
    def no_jaw(h):
        keep = [j for j, c in enumerate(h) if c != "JawOpen"]
        return [h[j] for j in keep], set(keep)

    with pytest.warns(DataWarning, match=r"1 of the 52 ARKit curves are missing.*jawOpen"):
        perf = read_livelinkface(_csv_with_header(data_dir, tmp_path, no_jaw))
    assert "jawOpen" not in perf.names and len(perf.names) == 51


def test_prefixed_curve_names_are_mapped(data_dir, tmp_path):
    ref = read_livelinkface(data_dir / "livelinkface" / "S07-001.csv")

    def prefixed(h):
        return [c if j < 2 or c.startswith(("Head", "LeftEye", "RightEye")) else f"blendshape_{c}"
                for j, c in enumerate(h)], set(range(len(h)))

    import warnings as w

    with w.catch_warnings():
        w.simplefilter("error")                 # all 52 found: no warning at all
        perf = read_livelinkface(_csv_with_header(data_dir, tmp_path, prefixed))
    assert perf.names == ref.names
    np.testing.assert_array_equal(perf.weights, ref.weights[: perf.n_frames])


def test_an_impossible_weight_is_an_error_naming_frame_and_curve(data_dir, tmp_path):
    """A 1e30 weight used to flow through clone/retarget to vertices 4e28 m away (issue 14)."""
    from faceretarget.cli import main
    from faceretarget.io import MAX_TAKE_WEIGHT, read_performance

    lines = (data_dir / "livelinkface" / "S07-001.csv").read_text().splitlines()[:40]
    header = lines[0].split(",")
    j = header.index("JawOpen")
    cells = lines[12].split(",")
    cells[j] = "1e30"
    lines[12] = ",".join(cells)
    bad = tmp_path / "bad.csv"
    bad.write_text("\n".join(lines) + "\n")
    with pytest.raises(InvalidDataError, match=r"frame 11 .*'jawOpen' is 1e\+30, outside the plausible range \+-10"):
        read_performance(bad)
    assert MAX_TAKE_WEIGHT == 10.0
    out = tmp_path / "o.glb"
    rc = main(["-q", "clone", "--source-rig", str(data_dir / "arkit-face"), "--target-rig", str(data_dir / "ict-face"),
               "--keys", "arkit", "--performance", str(bad), "--out", str(out)])
    assert rc == 2 and not out.exists()
