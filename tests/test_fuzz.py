"""Fuzzed readers (issue 14): every reader on mutated copies of small valid files, through Hypothesis.

The mutations, the seeds, the checks of a read and the process that reads the cases are those of
``bench/fuzz.py`` (which runs the same cases at any count, 100,000 per reader in the long profile).
The only outcomes allowed: a correct read (finite data of consistent shapes; NaN only for a C3D
marker the file marks missing) or a ``FaceRetargetError`` naming the file on one short printable
line; never another exception, a hang (``FACERETARGET_FUZZ_TIMEOUT`` s per case, 2 by default), a
crash of the reading process or a warning that is not a ``FaceRetargetWarning``.

``FACERETARGET_FUZZ_CASES`` sets the cases per reader (default 2,000: the short profile of
``make test``, about a minute for all readers).  The regression tests below name what the fuzzer
found, each fixed in the reader.
"""

from __future__ import annotations

import importlib.util
import os
import struct
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest

hypothesis = pytest.importorskip("hypothesis", reason="the fuzz tests need Hypothesis (the test extra)")
from hypothesis import HealthCheck, given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

from faceretarget.errors import DataWarning, FaceRetargetError, InputFileError  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
_spec = importlib.util.spec_from_file_location("faceretarget_bench_fuzz", REPO / "bench" / "fuzz.py")
fz = importlib.util.module_from_spec(_spec)
sys.modules[_spec.name] = fz
_spec.loader.exec_module(fz)

CASES = int(os.environ.get("FACERETARGET_FUZZ_CASES", "2000"))
TIMEOUT = float(os.environ.get("FACERETARGET_FUZZ_TIMEOUT", str(fz.TIMEOUT)))
settings.register_profile("faceretarget-fuzz", max_examples=CASES, deadline=None, database=None,
                          derandomize=True, suppress_health_check=list(HealthCheck), print_blob=False)


class HypothesisDraw:
    """The draw interface of ``bench/fuzz.py``'s mutations, from Hypothesis (which shrinks failures)."""

    def __init__(self, data):
        self._data = data

    def integer(self, lo: int, hi: int) -> int:
        return self._data.draw(st.integers(lo, hi))

    def choice(self, seq):
        return self._data.draw(st.sampled_from(seq))

    def data(self, n_max: int) -> bytes:
        return self._data.draw(st.binary(min_size=1, max_size=n_max))


@pytest.fixture(scope="module")
def seeds(tmp_path_factory):
    return fz.make_seeds(tmp_path_factory.mktemp("fuzz-seeds"))


@pytest.fixture(scope="module")
def worker(tmp_path_factory):
    w = fz.Worker(tmp_path_factory.mktemp("fuzz-work"), TIMEOUT)
    yield w
    w.close()


# slow: a fixed number of hypothesis examples per reader (each parse is fast; ~5-9 s per format)
@pytest.mark.parametrize("reader", fz.READER_NAMES)
def test_fuzzed_reader(reader, seeds, worker):
    """``FACERETARGET_FUZZ_CASES`` mutated files per reader: each read correctly or refused by name."""
    if not seeds[reader]:
        pytest.skip(f"no {reader} seed: writing one needs PyAV (`make capture`)")
    spec = fz.readers()[reader]
    ran = []

    @settings(settings.get_profile("faceretarget-fuzz"))
    @given(st.data())
    def case(data):
        mutated, what = fz.mutate(spec, seeds, HypothesisDraw(data))
        problem = worker.run(reader, mutated)
        ran.append(what)
        assert problem is None, f"{reader}: {what}: {problem}"

    case()
    assert len(ran) >= CASES * 0.95, f"only {len(ran)} of {CASES} cases ran"


# ------------------------------------------------------------------------ what the fuzzer found
# Cases of bench/fuzz.py (``--reader R --case I`` replays one) that failed before their fix: the
# mutation is checked first, so a change of the mutation engine cannot silently test something else.
FOUND = [
    # ezc3d crashed (SIGSEGV) or looped for minutes: the C3D reader is now our own, every count checked
    ("c3d", 164, "seed 0; copy 12 from 2505 to 2037; write ffffff7f at 680; write 00000000 at 1417"),
    ("c3d", 217, "seed 0; write 7fffffff at 680; write caf249f1 at 2056; write caf249f1 at 572"),
    ("c3d", 27, "seed 0; write ffffffff at 978; truncate at 2380 of 2560"),
    ("c3d", 146, "seed 0; copy 49 from 759 to 830"),
    # a stream whose codec FFmpeg does not know: AttributeError on codec_context None
    ("video", 48, "seed 0; write 01000000 at 384; write 00000001 at 840; delete 13 at 1267"),
    # a signalling NaN in a float32 accessor: RuntimeWarning from the cast
    ("glb", 2728, "seed 0; write 7fc00000 at 2763"),
    # a 1e308 coordinate overflowed guess_unit's norm: RuntimeWarning
    ("rig", 618, "seed 0: neutral.obj: number 14 b'0.010000000000000002' -> b'1e308'"),
    # a control character in a joint name went into the message
    ("bvh", 1417, "seed 1; insert b'\\x1b\\xe8\\xca' at 291"),
    # scipy: UnboundLocalError (a RIFF without fmt chunk), MemoryError (a data chunk of 3.8 GB), and a
    # RuntimeWarning averaging NaN channels
    ("wav", 1, "seed 1; write 0000807f at 16"),
    ("wav", 172, "seed 0; insert b'\\x9f\\xa3\\n7\\x87\\xf2\\x9c\\xd4' at 288; write ffffffff at 418"),
    ("wav", 22, "seed 1; write 0000807f at 193; copy 17 from 428 to 739"),
    # np.load left a broken zip's file open (ResourceWarning); bool times divided by zero in infer_fps
    ("npz_take", 1, "seed 0; faces as uint8; truncate at 1888 of 2983"),
    ("npz_take", 166, "seed 0; times as bool"),
    # names where the deltas were: ValueError converting strings in Rig
    ("npz_rig", 22, "seed 0; swap names and deltas"),
    # found by the 20,000-case run: a face index beyond int64 (OverflowError), a signalling NaN in a
    # C3D float parameter (RuntimeWarning), a .npy header numpy's tokenizer chokes on (TokenError)
    ("obj", 8359, "seed 1; number 41 b'1' -> b'\\xc3\\xa9'; number 34 b'3' -> b'99999999999999999999'"),
    ("c3d", 11131, "seed 0; insert b'\\xfc' at 1265; write ffff at 966"),
    ("npz_take", 6243, "seed 2; mocap_frame_rate[0] = 1000000000.0; mocap_frame_rate[0] = inf"),
    # found by the 100,000-case run: control characters of C3D labels in a warning; a joint with
    # 'Xrotation Xrotation' (scipy refuses the Euler sequence ZXX: ValueError)
    ("c3d", 78740, "seed 0; bit flip 1291.4 536.5; write 7fffffff at 252; write 7f800000 at 552"),
    ("bvh", 33057, "seed 1; bit flip 311.0 356.0"),
    # a glTF whose targetNames do not name every morph target: names and weights disagreed
    ("glb", 29047, "seed 0; write ea8ca039593e2946 at 438"),
]


@pytest.mark.parametrize(("reader", "number", "mutation"), FOUND, ids=[f"{r}-{n}" for r, n, _ in FOUND])
def test_found_case(reader, number, mutation, seeds, worker):
    if not seeds[reader]:
        pytest.skip(f"no {reader} seed: writing one needs PyAV (`make capture`)")
    case, what = fz.mutate(fz.readers()[reader], seeds, fz.RandomDraw(f"{reader}:{number}"))
    assert what.startswith(mutation), f"the mutation engine changed: case {number} is now {what!r}"
    assert worker.run(reader, case) is None


# ----------------------------------------------------------------------- regressions, by hand
def _in_time(fn, seconds=5.0):
    """``fn()`` under the fuzzer's watchdog (a hang fails the test instead of stalling it)."""
    try:
        with fz.watchdog(seconds):
            return fn()
    except fz.CaseTimeout:
        pytest.fail(f"no answer within {seconds} s")


def _one_line(msg: str, path: Path) -> None:
    assert path.name in msg and msg.isprintable(), msg
    assert len(msg.replace(str(path), "")) <= fz.MAX_MESSAGE, msg


def test_bvh_negative_channel_count_is_an_error_not_a_hang(tmp_path):
    """The parser stepped back by the count (``k += 2 + cnt``) and never ended."""
    from faceretarget.io import read_bvh

    p = tmp_path / "neg.bvh"
    p.write_text("HIERARCHY\nROOT Head\n{\n OFFSET 0 0 0\n CHANNELS -2 Xrotation Yrotation\n}\n"
                 "MOTION\nFrames: 1\nFrame Time: 0.1\n0 0\n")
    with pytest.raises(InputFileError, match=r"neg\.bvh: line 5: channel count -2 is negative"):
        _in_time(lambda: read_bvh(p))


def test_bvh_values_that_would_overflow_are_refused(tmp_path):
    """Hypothesis: a 1e308 offset plus a 1e308 position overflowed to inf in the joint chain."""
    from faceretarget.io import read_bvh

    p = tmp_path / "big.bvh"
    p.write_text("HIERARCHY\nROOT Head\n{\n OFFSET 1e308 0 0\n CHANNELS 3 Xposition Yposition Zposition\n}\n"
                 "MOTION\nFrames: 1\nFrame Time: 0.1\n1e308 0 0\n")
    with pytest.raises(InputFileError, match=r"big\.bvh: line 4: value '1e308' is beyond \+-1e\+15"):
        read_bvh(p)


def _c3d_seed(tmp_path) -> tuple[Path, bytes]:
    from faceretarget.io import write_c3d
    from faceretarget.performance import Performance

    pts = np.random.default_rng(0).normal(size=(10, 4, 3)) * 10
    p = write_c3d(tmp_path / "seed.c3d", Performance.from_points(pts, ["a", "b", "c", "d"], fps=60.0))
    return p, p.read_bytes()


def test_c3d_truncated_by_100_bytes_warns(tmp_path):
    """Cut inside the last block's padding: every frame is still there, so no warning (vendors write files
    that end with their last frame: 25 of 87 complete ones warned before); cut inside a frame, it warns."""
    import warnings

    from faceretarget.io import read_c3d

    p, raw = _c3d_seed(tmp_path)
    full = read_c3d(p)
    cut = tmp_path / "cut.c3d"
    cut.write_bytes(raw[:-100])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        back = read_c3d(cut)
    np.testing.assert_array_equal(back.points, full.points)
    cut.write_bytes(raw[:1536 + 10 * 4 * 16 - 100])  # data start (block 4) + 10 frames, less 100 bytes
    with pytest.warns(DataWarning, match=r"cut\.c3d: holds 8 frame\(s\) but its header declares 10"):
        back = read_c3d(cut)
    np.testing.assert_array_equal(back.points, full.points[:8])


def _c3d_param(raw: bytes, group_id: int, name: bytes) -> int:
    """Byte offset of parameter ``name`` of group ``group_id`` (its name-length byte)."""
    for j in range(512, len(raw) - len(name)):
        if raw[j + 2:j + 2 + len(name)] == name and raw[j] in (len(name), 256 - len(name)) and raw[j + 1] == group_id:
            return j
    raise AssertionError(name)


def test_c3d_counts_beyond_the_file_are_errors(tmp_path):
    """What crashed ezc3d: POINT:USED beyond the file, an empty POINT:SCALE, a parameter past the end."""
    from faceretarget.io import read_c3d

    _, raw = _c3d_seed(tmp_path)
    p = tmp_path / "bad.c3d"
    used = _c3d_param(raw, 1, b"USED")
    value = used + 2 + 4 + 2 + 2                     # name, next pointer, type, dims: the int16 value
    assert struct.unpack_from("<h", raw, value)[0] == 4
    p.write_bytes(raw[:value] + struct.pack("<h", 30000) + raw[value + 2:])
    with pytest.warns(DataWarning, match=r"bad\.c3d: the parameters disagree with the header's 4 points per frame "
                      r"\(POINT:USED 30000\); the data block holds frames of 4 point"):
        assert read_c3d(p).points.shape[1] == 4     # the header's count is the one the data hold
    p.write_bytes(raw[:2] + struct.pack("<H", 30000) + raw[4:value] + struct.pack("<h", 30000) + raw[value + 2:])
    with pytest.raises(InputFileError, match=r"bad\.c3d: the C3D file holds no complete frame of 30000"):
        read_c3d(p)
    scale = _c3d_param(raw, 1, b"SCALE")
    offset, dims = scale + 2 + 5, scale + 2 + 5 + 2 + 1
    assert raw[dims] == 0 and raw[dims - 1] == 4      # a float scalar: no dimension, 4 bytes
    bad = bytearray(raw)
    bad[dims:dims + 5] = b"\x01\x00"                   # one dimension of size 0, no value (3 bytes less)
    struct.pack_into("<H", bad, offset, struct.unpack_from("<H", raw, offset)[0] - 3)
    p.write_bytes(bytes(bad))
    with pytest.raises(InputFileError, match=r"bad\.c3d: cannot read as a C3D file \(parameter POINT:SCALE has no"):
        read_c3d(p)
    p.write_bytes(raw[:used + 4])
    with pytest.raises(InputFileError, match=r"bad\.c3d: cannot read as a C3D file \(.*end of the file"):
        read_c3d(p)


def test_csv_renamed_npz_says_it_is_not_an_npz(tmp_path):
    """np.load talked about allow_pickle."""
    from faceretarget.io import read_performance, read_rig_npz

    p = tmp_path / "take.npz"
    p.write_text("Timecode,BlendShapeCount,EyeBlinkLeft\n00:00:00:00.000,1,0.5\n")
    for read in (read_performance, read_rig_npz):
        with pytest.raises(InputFileError) as e:
            read(p)
        msg = str(e.value)
        assert "take.npz: not a readable .npz file: not a zip archive" in msg and "pickle" not in msg
        _one_line(msg, p)


def test_npz_broken_zip_leaves_no_open_file(tmp_path):
    """np.load leaked the file of a zip it could not open (ResourceWarning at garbage collection)."""
    import gc

    from faceretarget.io import read_performance

    p = tmp_path / "broken.npz"
    p.write_bytes(b"PK\x03\x04" + bytes(200))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(InputFileError, match=r"broken\.npz: not a readable \.npz file"):
            read_performance(p)
        gc.collect()


def test_npz_wrong_dtypes_are_named(tmp_path):
    """Strings where numbers belong raised ValueError in the constructors; bool times divided by 0."""
    from faceretarget.io import read_performance

    p = tmp_path / "w.npz"
    np.savez(p, weights=np.array([["a", "b"]]), names=np.array(["jawOpen", "x"]))
    with pytest.raises(InputFileError, match=r"w\.npz: 'weights' holds <U1 values, expected numbers"):
        read_performance(p, fps=30.0)
    np.savez(p, weights=np.zeros((3, 1)), names=np.array(["jawOpen"]), times=np.array([False, True, True]))
    with pytest.raises(InputFileError, match=r"w\.npz: 'times' holds bool values"):
        read_performance(p)
    np.savez(p, weights=np.zeros((3, 1)), names=np.array(["jawOpen"]), times=np.array([0.0, 0.1, 0.1]))
    with pytest.raises(FaceRetargetError, match=r"w\.npz: frame 2 time 0.100000 s does not increase"):
        read_performance(p)


def test_binary_csv_message_is_short_and_escaped(tmp_path):
    """A binary file read as a Live Link Face CSV put 200 characters of garbage in the message."""
    from faceretarget.io import read_livelinkface

    p = tmp_path / "bin.csv"
    p.write_bytes(np.random.default_rng(3).integers(0, 256, 600, dtype=np.uint8).tobytes())
    with pytest.raises(InputFileError) as e:
        read_livelinkface(p)
    _one_line(str(e.value), p)
    assert len(str(e.value).replace(str(p), "")) < 160


def test_utf16_livelinkface_csv_reads_like_utf8(tmp_path):
    """A take saved as "Unicode text" (UTF-16 with a BOM) reads as the same take."""
    from faceretarget.io import read_livelinkface, write_animation
    from faceretarget.names import ARKIT_NAMES

    w = np.random.default_rng(4).uniform(0, 1, (5, len(ARKIT_NAMES)))
    p = write_animation(tmp_path / "a.csv", weights=w, names=list(ARKIT_NAMES), times=np.arange(5) / 30)
    q = tmp_path / "b.csv"
    q.write_bytes(p.read_text(encoding="utf-8").encode("utf-16"))
    a, b = read_livelinkface(p), read_livelinkface(q)
    np.testing.assert_array_equal(a.weights, b.weights)
    np.testing.assert_allclose(b.weights, w, atol=1e-10)


def test_rig_side_files_in_other_encodings(tmp_path):
    """A latin-1 key_weights.csv or a binary landmarks file raised UnicodeDecodeError."""
    from faceretarget.io import read_rig, write_rig

    folder = write_rig(fz.tiny_rig(), tmp_path / "rig")
    kw = folder / "key_weights.csv"
    kw.write_bytes(kw.read_bytes().replace(b"mouthClose", "mouthClosé".encode("latin-1")))
    rig = read_rig(folder)
    assert rig.basis_names[2] == "mouthClos\ufffd" and rig.basis.shape == (2, 3)
    (folder / "landmarks.txt").write_bytes(b"0 \xff\xfe 2\n")
    with pytest.raises(InputFileError, match="landmarks\\.txt: landmark '\ufffd\ufffd' is not an integer"):
        read_rig(folder)


def test_wav_data_chunk_beyond_the_file(tmp_path):
    """SciPy allocated the declared size (MemoryError for 3.8 GB): now the samples present, with a warning."""
    from scipy.io import wavfile

    from faceretarget.io import read_audio

    x = (np.sin(np.arange(400) / 5) * 20000).astype(np.int16)
    p = tmp_path / "a.wav"
    wavfile.write(p, 8000, x)
    raw = bytearray(p.read_bytes())
    data = raw.find(b"data")
    struct.pack_into("<I", raw, data + 4, 0xF0000000)
    p.write_bytes(bytes(raw))
    with pytest.warns(DataWarning, match=r"a\.wav: the data chunk declares 4026531840 bytes but the file holds 800"):
        y, rate = read_audio(p)
    assert rate == 8000.0
    np.testing.assert_allclose(y, x / 32768.0, atol=1e-7)
    p.write_bytes(b"RIFF\x10\x00\x00\x00WAVEdata\x04\x00\x00\x00\x00\x00\x00\x00")  # no fmt chunk
    with pytest.raises(InputFileError, match=r"a\.wav: cannot read as a WAV file"):
        read_audio(p)


def test_glb_malformed_json_and_accessors(tmp_path):
    """JSONDecodeError / UnicodeDecodeError / KeyError escaped the glTF readers."""
    from faceretarget.io import read_glb_weights, read_head_motion, write_animation

    rng = np.random.default_rng(5)
    p = write_animation(tmp_path / "a.glb", rig=fz.tiny_rig(), weights=rng.uniform(0, 1, (6, 2)),
                        times=np.arange(6) / 30.0, head=fz._head(6))
    raw = p.read_bytes()
    n = struct.unpack_from("<I", raw, 12)[0]
    js = raw[20:20 + n]

    def repack(new_json: bytes) -> bytes:
        new_json += b" " * (-len(new_json) % 4)
        body = struct.pack("<II", len(new_json), 0x4E4F534A) + new_json + raw[20 + n:]
        return struct.pack("<III", 0x46546C67, 2, 12 + len(body)) + body

    bad = tmp_path / "bad.glb"
    for broken, what in ((js[:-10], "is not UTF-8 JSON"), (b"\xff" + js, "is not UTF-8 JSON"),
                         (b"[1, 2]", "is not a glTF object"),
                         (js.replace(b'"count":6', b'"count":600000'), "lies outside the binary chunk"),
                         (js.replace(b'"accessors"', b'"accessorz"'), "malformed glTF")):
        bad.write_bytes(repack(broken))
        for read in (read_head_motion, read_glb_weights):
            with pytest.raises(InputFileError, match=what) as e:
                read(bad)
            _one_line(str(e.value), bad)
