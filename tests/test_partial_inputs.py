"""Inputs understood only in part never pass silently (issue 23, item 5): in the C3D, BVH, SVG, control-table,
jobs-file and audio readers, a feature that is not read, two names for one thing, or a file with nothing usable
in it is a clear error or one warning line; and the documented exit code (2, one line) holds when the operating
system refuses a file."""

from __future__ import annotations

import errno
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest

from faceretarget.errors import DataWarning, FaceRetargetError, InputFileError, InvalidDataError

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _c3d_files import C3dSpec, make_c3d, smooth_take  # noqa: E402 - tests/_c3d_files.py


def _warns(fn, *args, **kw) -> list[str]:
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        fn(*args, **kw)
    assert all(issubclass(w.category, DataWarning) for w in caught), [w.category for w in caught]
    return [str(w.message) for w in caught]


# ------------------------------------------------------------------------------------------- C3D
def test_c3d_unknown_unit_and_no_valid_sample(tmp_path, data_dir):
    from faceretarget.io import read_c3d

    p = tmp_path / "u.c3d"
    p.write_bytes(make_c3d(C3dSpec(smooth_take(), [f"m{i}" for i in range(12)], units="px")))
    msgs = _warns(read_c3d, p)
    assert msgs == [f"{p}: POINT:UNITS is 'px', not a length unit (mm, cm, m, in); the points are taken as "
                    "millimetres, C3D's default"]
    with pytest.warns(DataWarning):
        assert read_c3d(tmp_path / "u.c3d").unit is None
    p.write_bytes(make_c3d(C3dSpec(smooth_take(), [f"m{i}" for i in range(12)], units="millimeters")))
    assert read_c3d(p).unit == "mm"
    basket = data_dir / "conformance" / "c3d" / "sample_16_basketball.c3d"       # every residual is -1
    assert _warns(read_c3d, basket) == [f"{basket}: no marker is present in any frame (every sample invalid): "
                                        "the file holds no usable point"]


# ------------------------------------------------------------------------------------------- BVH
_BVH = """HIERARCHY
ROOT Hips
{
  OFFSET 0 0 0
  CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation
  JOINT Head
  {
    OFFSET 0 10 0
    CHANNELS 3 Zrotation Xrotation Yrotation
    End Site
    {
      OFFSET 0 5 0
    }
  }
  JOINT Head
  {
    OFFSET 0 -10 0
    CHANNELS 3 Zrotation Xrotation Yrotation
  }
}
MOTION
Frames: 2
Frame Time: 0.04
0 0 0 0 0 0 1 2 3 4 5 6
0 0 0 0 0 0 1 2 3 4 5 6
0 0 0 0 0 0 1 2 3 4 5 6
"""


def test_bvh_extra_rows_and_one_name_for_two_joints(tmp_path):
    from faceretarget.io import read_bvh

    p = tmp_path / "t.bvh"
    p.write_text(_BVH)
    msgs = _warns(read_bvh, p)
    assert msgs == [f"{p}: 3 frame rows but 'Frames: 2'; the first 2 are read (line 26 on is not)",
                    f"{p}: joint name(s) Head used by more than one joint; a name finds the first of them (head "
                    "motion, key frames)"]
    with pytest.warns(DataWarning):
        assert read_bvh(p).n_frames == 2


# ------------------------------------------------------------------------------------------- SVG
_SVG = ('<svg xmlns="http://www.w3.org/2000/svg" viewBox="0 0 100 100"><g transform="{t}">'
        '<path id="mouth" d="M 10 50 C 30 {y} 70 {y} 90 50"/></g><circle id="pupil" cx="{cx}" cy="30" r="3"/></svg>')


def _drawings(folder: Path, key_transform: str = "translate(0,0)", key_cx: int = 40) -> Path:
    folder.mkdir()
    (folder / "neutral.svg").write_text(_SVG.format(t="translate(0,0)", y=50, cx=40))
    (folder / "jawOpen.svg").write_text(_SVG.format(t=key_transform, y=80, cx=key_cx))
    return folder


def test_svg_transforms_that_differ_are_an_error_and_moved_shapes_a_warning(tmp_path):
    from faceretarget.targets import read_target

    t = read_target(_drawings(tmp_path / "same"))              # only the path differs: read as it is
    assert t.kind == "drawing" and t.n_keys == 1
    with pytest.raises(InvalidDataError, match=r"jawOpen.svg: path 'mouth' is transformed by 'translate\(5,0\)' "
                                               r"where .*neutral.svg has 'translate\(0,0\)'; transforms are not blended"):
        read_target(_drawings(tmp_path / "moved", key_transform="translate(5,0)"))
    msgs = _warns(read_target, _drawings(tmp_path / "eyes", key_cx=45))
    assert len(msgs) == 1 and "jawOpen.svg: <circle id=pupil> drawn otherwise than in" in msgs[0]
    assert "only <path> elements are animated" in msgs[0]


# ------------------------------------------------------------------------------------------- control tables
def test_control_table_two_spellings_of_one_control_and_unknown_json_keys(tmp_path):
    from faceretarget.io import read_control_table

    p = tmp_path / "c.csv"
    p.write_text("key,jawOpen,JawOpen\nrange,0:1,0:1\nframe_00001,0.5,0.2\n")
    with pytest.raises(InvalidDataError, match=r"c.csv: controls 'jawOpen' and 'JawOpen' name one control \(jawOpen\)"):
        read_control_table(p)
    p.write_text("key,eyeBlink_L,eyeBlinkLeft\nrange,0:1,0:1\nframe_00001,0.5,0.2\n")
    with pytest.raises(InvalidDataError, match="name one control .eyeBlinkLeft."):
        read_control_table(p)
    j = tmp_path / "c.json"
    j.write_text('{"controls": ["jawOpen"], "range": [[0, 1]], "netural": {"jawOpen": 0.2}, '
                 '"keys": {"frame_00001": [0.5]}}')
    with pytest.raises(InputFileError, match="c.json: unknown key 'netural'"):
        read_control_table(j)


# ------------------------------------------------------------------------------------------- jobs files
def test_jobs_file_keys_that_apply_to_nothing(tmp_path):
    from faceretarget.pipelines.batch._jobs import read_jobs

    (tmp_path / "takes").mkdir()
    (tmp_path / "takes" / "a.csv").write_text("x")
    (tmp_path / "keys_s").mkdir()
    (tmp_path / "keys_t").mkdir()
    base = ('[characters.robot]\nsource_keys = "keys_s"\ntarget_keys = "keys_t"\n{extra}\n'
            '[[jobs]]\noperation = "clone"\ntakes = "takes/*.csv"\ncharacters = "*"\n')
    p = tmp_path / "jobs.toml"
    p.write_text(base.format(extra=""))
    assert len(read_jobs(p).jobs) == 1
    p.write_text(base.format(extra='neutral = "Neutral.obj"'))
    with pytest.raises(InvalidDataError, match=r"characters.robot, key 'neutral': applies to 'rig', which this "
                                               "character does not give"):
        read_jobs(p)
    p.write_text('[characters.ada]\ndemo = "ada"\nlandmarks = "l.txt"\n[[jobs]]\noperation = "animate"\n'
                 'takes = "takes/*.csv"\ncharacters = "*"\n')
    (tmp_path / "l.txt").write_text("1\n")
    with pytest.raises(InvalidDataError, match=r"key 'landmarks': applies to 'rig'.*a demo character has its own"):
        read_jobs(p)


# ------------------------------------------------------------------------------------------- audio
def _wav(path: Path, x: np.ndarray, rate: int) -> Path:
    from scipy.io import wavfile

    wavfile.write(path, rate, x)
    return path


def test_audio_silence_clipping_cancelling_channels_and_low_rates(tmp_path):
    from faceretarget.io import read_audio

    t = np.arange(16000) / 16000.0
    voice = (0.3 * np.sin(2 * np.pi * 180 * t)).astype(np.float32)
    assert _warns(read_audio, _wav(tmp_path / "ok.wav", voice, 16000)) == []
    p = _wav(tmp_path / "silent.wav", np.zeros(16000, np.int16), 16000)
    assert _warns(read_audio, p) == [f"{p}: the audio is silent (peak -inf dBFS, under -60): no speech to drive head "
                                     "motion or emotion"]
    p = _wav(tmp_path / "hot.wav", 4 * voice, 16000)
    msgs = _warns(read_audio, p)
    assert len(msgs) == 1 and "of the float samples lie beyond +-1 (peak 1.2) and are clipped" in msgs[0]
    p = _wav(tmp_path / "phase.wav", np.stack([voice, -voice], axis=1), 16000)
    msgs = _warns(read_audio, p)
    assert any("its 2 channels cancel when averaged to mono" in m for m in msgs), msgs
    p = _wav(tmp_path / "low.wav", voice[:4000], 4000)
    assert _warns(read_audio, p) == [f"{p}: sampled at 4000 Hz, under the 8000 Hz of telephone speech: pitch and "
                                     "speech features will not be found"]


# ------------------------------------------------------------------------------------------- the system refuses
def test_system_errors_exit_2_in_one_line(tmp_path, monkeypatch, capsys, data_dir):
    """Permission denied (simulated: the tests run as root), a folder given as a file, and a full disk: exit 2, one
    line naming the file, nothing written."""
    import faceretarget.files as files
    import faceretarget.io._c3d as c3d_module
    from faceretarget.cli import main
    from faceretarget.cli._support import run_command

    take = data_dir / "facial-mocap" / "Nose.c3d"

    def denied(*a, **k):
        raise PermissionError(errno.EACCES, "Permission denied", str(take))

    monkeypatch.setattr(c3d_module, "open", denied, raising=False)
    assert main(["keys", "select", "--performance", str(take), "--k", "3", "--out", str(tmp_path / "k")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and f"{take}: cannot read (Permission denied)" in err[0]
    monkeypatch.undo()
    # a folder where a file is expected
    (tmp_path / "take.c3d").mkdir()
    assert main(["keys", "select", "--performance", str(tmp_path / "take.c3d"), "--k", "3",
                 "--out", str(tmp_path / "k")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and f"{tmp_path / 'take.c3d'}: no .obj frames found" in err[0]   # a folder: OBJ frames
    # disk full while the output is renamed into place
    def full(*a, **k):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(files.os, "replace", full)
    out = tmp_path / "nose.c3d"
    from faceretarget.io import read_c3d, write_c3d

    with pytest.raises(FaceRetargetError, match="nose.c3d: cannot write .No space left on device."):
        write_c3d(out, read_c3d(take))
    monkeypatch.undo()
    assert not out.exists() and not list(tmp_path.glob(".nose.c3d.*"))
    # any OSError that reaches the command line (a reader that does not wrap it): 2 and one line

    class Args:
        quiet = False

        @staticmethod
        def func(args, log):
            raise IsADirectoryError(errno.EISDIR, "Is a directory", "/some/take.glb")

    assert run_command(Args) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ["faceretarget: error: /some/take.glb: Is a directory"]
