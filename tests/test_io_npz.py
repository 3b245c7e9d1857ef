""".npz takes, OBJ sequences and the read_performance / write_animation dispatch."""

from __future__ import annotations

import numpy as np
import pytest

from faceretarget.errors import InputFileError, InvalidDataError, OutputError, TopologyError
from faceretarget.io import (
    read_glb_weights,
    read_livelinkface,
    read_npz_performance,
    read_obj_sequence,
    read_performance,
    write_animation,
    write_npz,
    write_obj,
    write_obj_sequence,
)
from faceretarget.mesh import Mesh
from faceretarget.rig import Rig


def _mesh() -> Mesh:
    v = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [2, 0.5, 0]], float)
    return Mesh(v, [4, 3], [0, 1, 2, 3, 1, 4, 2], np.random.default_rng(0).random((7, 2)),
                np.arange(7), name="m")


def _take(T=12, seed=0):
    rng = np.random.default_rng(seed)
    m = _mesh()
    verts = m.vertices + rng.normal(scale=0.1, size=(T, 5, 3))
    times = 1.0 + np.arange(T) / 24.0
    return m, verts, times


def _rig() -> Rig:
    rng = np.random.default_rng(5)
    return Rig(_mesh(), ["jawOpen", "eyeBlink_L"], rng.normal(size=(2, 5, 3)), unit="cm", name="r")


def test_npz_round_trip(tmp_path):
    m, verts, times = _take()
    out = write_npz(tmp_path / "take.npz", verts, times, m, unit="cm")
    z = np.load(out)
    assert z["vertices"].shape == (12, 5, 3) and z["faces"].shape == (3, 3)
    perf = read_npz_performance(out)
    np.testing.assert_array_equal(perf.vertices, verts)
    np.testing.assert_array_equal(perf.times, times)
    assert perf.fps == pytest.approx(24.0) and perf.unit == "cm"
    assert perf.mesh.same_topology(m)
    np.testing.assert_array_equal(perf.mesh.face_uv_indices, m.face_uv_indices)


def test_npz_weights_and_missing_keys(tmp_path):
    p = tmp_path / "w.npz"
    np.savez(p, weights=np.full((3, 2), 0.5), names=np.array(["JawOpen", "eyeBlink_L"]))
    with pytest.warns(UserWarning, match="assuming 30 fps"):
        perf = read_npz_performance(p)
    assert perf.kind == "weights" and perf.names == ["JawOpen", "eyeBlink_L"] and perf.fps == 30.0
    assert read_npz_performance(p, fps=60).times[1] == pytest.approx(1 / 60)
    q = tmp_path / "other.npz"
    np.savez(q, foo=np.zeros(3))
    with pytest.raises(InputFileError, match=r"other\.npz: holds neither .*keys: foo"):
        read_npz_performance(q)
    bad = tmp_path / "bad.npz"
    bad.write_text("not a zip")
    with pytest.raises(InputFileError, match=r"bad\.npz: not a readable"):
        read_npz_performance(bad)


def test_write_npz_checks_shapes(tmp_path):
    m, verts, times = _take()
    with pytest.raises(InvalidDataError, match=r"11 times for 12 frames"):
        write_npz(tmp_path / "a.npz", verts, times[:-1])
    with pytest.raises(InvalidDataError, match=r"\(T, V, 3\), got \(12, 15\)"):
        write_npz(tmp_path / "a.npz", verts.reshape(12, 15), times)
    with pytest.raises(InvalidDataError, match="reserved"):
        write_npz(tmp_path / "a.npz", verts, times, faces=np.zeros(3))
    assert not list(tmp_path.iterdir())


def test_obj_sequence_round_trip(tmp_path):
    m, verts, times = _take()
    out = write_obj_sequence(tmp_path / "seq", m, verts, times)
    files = sorted(p.name for p in out.iterdir())
    assert files[0] == "frame_00000.obj" and files[-1] == "times.txt" and len(files) == 13
    perf = read_obj_sequence(out)
    np.testing.assert_array_equal(perf.vertices, verts)
    np.testing.assert_array_equal(perf.times, times)
    assert perf.mesh.same_topology(m)
    with pytest.raises(OutputError, match="already holds frame_"):
        write_obj_sequence(out, m, verts[:3], times[:3])


def test_obj_sequence_natural_order_and_fps(tmp_path):
    m, verts, _ = _take(T=11)
    seq = tmp_path / "nat"
    seq.mkdir()
    for i in range(11):
        write_obj(seq / f"f{i}.obj", m, verts[i])
    with pytest.warns(UserWarning, match="assuming 30 fps"):
        perf = read_obj_sequence(seq)
    np.testing.assert_array_equal(perf.vertices, verts)  # f2 before f10
    assert read_obj_sequence(seq, fps=25).times[-1] == pytest.approx(10 / 25)
    (seq / "f11.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    with pytest.raises(TopologyError, match=r"f11\.obj: frame has 3 vertices but f0\.obj has 5"):
        read_obj_sequence(seq, fps=25)
    (seq / "f11.obj").unlink()
    (seq / "times.txt").write_text("0\n0.1\nabc\n")
    with pytest.raises(InputFileError, match=r"times\.txt:3: time 'abc'"):
        read_obj_sequence(seq)


def test_read_performance_dispatch(tmp_path, data_dir):
    m, verts, times = _take()
    assert read_performance(write_npz(tmp_path / "a.npz", verts, times, m)).kind == "vertices"
    assert read_performance(write_obj_sequence(tmp_path / "s", m, verts, times)).n_frames == 12
    one = read_performance(write_obj(tmp_path / "one.obj", m, verts[0]), fps=24)
    assert one.n_frames == 1 and one.fps == 24
    perf = read_performance(data_dir / "livelinkface" / "MySlate_3_Jason_Millers_iPhone.csv")
    assert perf.kind == "weights" and perf.n_frames == 328
    with pytest.raises(InputFileError, match=r"take\.fbx: unknown take format '\.fbx'"):
        (tmp_path / "take.fbx").write_text("")
        read_performance(tmp_path / "take.fbx")
    with pytest.raises(InputFileError, match=r"gone\.csv: not found"):
        read_performance(tmp_path / "gone.csv")


def test_write_animation_every_format(tmp_path):
    rig = _rig()
    T = 6
    w = np.linspace(0, 1, T * 2).reshape(T, 2)
    times = np.arange(T) / 30.0
    g = write_animation(tmp_path / "a.glb", rig=rig, weights=w, times=times)
    names, t, back = read_glb_weights(g)
    np.testing.assert_array_equal(back, w.astype(np.float32))
    n = write_animation(tmp_path / "a.npz", rig=rig, weights=w, times=times)
    np.testing.assert_allclose(read_npz_performance(n).vertices, rig.evaluate(w))
    c = write_animation(tmp_path / "a.csv", rig=rig, weights=w, times=times)
    perf = read_livelinkface(c)
    np.testing.assert_allclose(perf.weights[:, perf.names.index("jawOpen")], w[:, 0], atol=1e-9)
    np.testing.assert_allclose(perf.weights[:, perf.names.index("eyeBlinkLeft")], w[:, 1], atol=1e-9)
    s = write_animation(tmp_path / "seq", rig=rig, weights=w[:, ::-1], names=["eyeBlinkLeft", "jawOpen"],
                        times=times)
    np.testing.assert_allclose(read_obj_sequence(s).vertices, rig.evaluate(w))
    v = write_animation(tmp_path / "v.npz", vertices=rig.evaluate(w), mesh=rig.neutral, times=times)
    assert read_npz_performance(v).mesh is not None


def test_write_animation_errors_leave_nothing(tmp_path):
    rig = _rig()
    w = np.zeros((2, 2))
    with pytest.raises(OutputError, match=r"out\.xyz: unknown output format '\.xyz'"):
        write_animation(tmp_path / "out.xyz", rig=rig, weights=w, times=[0, 1])
    with pytest.raises(OutputError, match=r"missing_dir"):
        write_animation(tmp_path / "missing_dir" / "x.npz", rig=rig, weights=w, times=[0, 1])
    (tmp_path / "file").write_text("")
    with pytest.raises(OutputError, match=r"'.*file' is a file, not a folder"):
        write_animation(tmp_path / "file" / "x.glb", rig=rig, weights=w, times=[0, 1])
    with pytest.raises(OutputError, match=r"\.glb needs a rig and weights"):
        write_animation(tmp_path / "x.glb", vertices=np.zeros((2, 5, 3)), times=[0, 1])
    assert sorted(p.name for p in tmp_path.iterdir()) == ["file"]


def test_vertex_output_from_a_rig_is_written_chunk_by_chunk(tmp_path):
    """A take written from a rig and weights (RigFrames, a chunk of frames at a time) is the same
    file content as from the evaluated (T, V, 3) array; a non-finite frame leaves nothing behind."""
    from faceretarget.datasets import make_demo_character
    from faceretarget.io import write_obj_sequence
    from faceretarget.rig import RigFrames

    rig = make_demo_character("bo")
    W = np.random.default_rng(2).uniform(0, 1, (2500, rig.n_shapes))
    t = np.arange(2500) / 30.0
    a = np.load(write_npz(tmp_path / "a.npz", rig.evaluate(W), t, rig.neutral))
    b = np.load(write_npz(tmp_path / "b.npz", RigFrames(rig, W), t, rig.neutral))
    assert sorted(a.files) == sorted(b.files)
    for k in a.files:
        np.testing.assert_array_equal(a[k], b[k])
    seq = write_obj_sequence(tmp_path / "seq", rig.neutral, RigFrames(rig, W[:3]), t[:3])
    back = read_npz_performance(tmp_path / "b.npz")
    assert back.n_frames == 2500 and len(list(seq.glob("frame_*.obj"))) == 3
    W[1700, 0] = np.nan
    with pytest.raises(InvalidDataError, match="frame 1700 vertex"):
        write_npz(tmp_path / "c.npz", RigFrames(rig, W), t, rig.neutral)
    assert not (tmp_path / "c.npz").exists() and not list(tmp_path.glob(".c.npz*"))
