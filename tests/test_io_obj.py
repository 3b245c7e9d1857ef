"""OBJ meshes and rigs: parsing, exact round trips, errors that name the file and line, real rigs."""

from __future__ import annotations

import time
import warnings

import numpy as np
import pytest

from faceretarget.errors import InputFileError, MissingShapeError, OutputError, TopologyError
from faceretarget.io import (
    read_obj,
    read_obj_vertices,
    read_rig,
    read_rig_npz,
    write_obj,
    write_rig,
    write_rig_npz,
)
from faceretarget.mesh import Mesh
from faceretarget.rig import Rig

MIXED = """\
# a quad, a triangle and a pentagon, every corner form
o test
v 0 0 0
v 1 0 0 1.0
v 1 1 0 0.5 0.5 0.5
v 0 1 0
v 2 0.5 0
vt 0 0
vt 1 0
vt 1 1
vt 0 1
vt 0.5 0.5 0
vn 0 0 1
s off
usemtl skin
f 1/1/1 2/2/1 3/3/1 4/4/1
f -4/-4 -1/-1 -3/-3
f 1/1 2/2 5/5 3/3 4/4
"""


def _write(tmp_path, name, text):
    p = tmp_path / name
    p.write_text(text)
    return p


def test_read_mixed_polygons_uvs_and_relative_indices(tmp_path):
    m = read_obj(_write(tmp_path, "mixed.obj", MIXED))
    assert m.n_vertices == 5
    np.testing.assert_array_equal(m.vertices[2], [1, 1, 0])  # w / colours ignored
    np.testing.assert_array_equal(m.face_counts, [4, 3, 5])
    np.testing.assert_array_equal(m.face_indices, [0, 1, 2, 3, 1, 4, 2, 0, 1, 4, 2, 3])
    np.testing.assert_array_equal(m.face_uv_indices, [0, 1, 2, 3, 1, 4, 2, 0, 1, 4, 2, 3])
    assert m.uvs.shape == (5, 2)
    assert len(m.triangles()) == 2 + 1 + 3


def test_corner_forms_without_uvs(tmp_path):
    text = "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nvn 0 0 1\nf 1//1 2//1 3//1\nf 2 4 3\n"
    m = read_obj(_write(tmp_path, "n.obj", text))
    np.testing.assert_array_equal(m.face_indices, [0, 1, 2, 1, 3, 2])
    assert m.uvs is None and m.face_uv_indices is None


def test_tabs_crlf_indent_and_trailing_comments(tmp_path):
    text = "v\t0 0 0\r\n  v 1 0 0 # x\r\nv 0 1 0\r\nf 1 2 3 # tri\r\n"
    m = read_obj(_write(tmp_path, "t.obj", text))
    assert m.n_vertices == 3 and m.n_faces == 1


def test_write_read_round_trip_is_exact(tmp_path):
    rng = np.random.default_rng(0)
    m0 = read_obj(_write(tmp_path, "mixed.obj", MIXED))
    m = Mesh(rng.normal(size=(5, 3)) * 1e3, m0.face_counts, m0.face_indices,
             rng.random((5, 2)), m0.face_uv_indices)
    back = read_obj(write_obj(tmp_path / "out.obj", m))
    np.testing.assert_array_equal(back.vertices, m.vertices)
    np.testing.assert_array_equal(back.uvs, m.uvs)
    np.testing.assert_array_equal(back.face_counts, m.face_counts)
    np.testing.assert_array_equal(back.face_indices, m.face_indices)
    np.testing.assert_array_equal(back.face_uv_indices, m.face_uv_indices)
    # other positions, same topology
    v2 = m.vertices + 0.125
    np.testing.assert_array_equal(read_obj_vertices(write_obj(tmp_path / "o2.obj", m, v2)), v2)
    assert not list(tmp_path.glob("*.part"))


def test_real_obj_round_trip(data_dir, tmp_path):
    m = read_obj(data_dir / "ict-face" / "generic_neutral_mesh.obj")
    back = read_obj(write_obj(tmp_path / "ict.obj", m))
    np.testing.assert_array_equal(back.vertices, m.vertices)
    np.testing.assert_array_equal(back.uvs, m.uvs)
    np.testing.assert_array_equal(back.face_indices, m.face_indices)
    np.testing.assert_array_equal(back.face_uv_indices, m.face_uv_indices)


def test_non_numeric_coordinate_names_file_and_line(tmp_path):
    p = _write(tmp_path, "bad.obj", "v 0 0 0\nv 1 0 0\n# comment\nv 0 abc 0\nf 1 2 3\n")
    with pytest.raises(InputFileError, match=r"bad\.obj:4: .*'abc' is not a number"):
        read_obj(p)
    with pytest.raises(InputFileError, match=r"bad\.obj:4"):
        read_obj_vertices(p)


@pytest.mark.parametrize("value", ["nan", "inf", "-inf"])
def test_non_finite_coordinate_names_file_and_line(tmp_path, value):
    p = _write(tmp_path, "nf.obj", f"v 0 0 0\nv 1 0 0\nv 0 1 {value}\nf 1 2 3\n")
    with pytest.raises(InputFileError, match=r"nf\.obj:3: vertex 3 has a non-finite coordinate"):
        read_obj(p)


def test_short_vertex_line_names_line(tmp_path):
    p = _write(tmp_path, "short.obj", "v 0 0 0\nv 1 0\n")
    with pytest.raises(InputFileError, match=r"short\.obj:2: vertex needs 3 numbers, got 2"):
        read_obj(p)


def test_bad_face_index_names_line(tmp_path):
    p = _write(tmp_path, "f.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\n\nf 1 2 7\n")
    with pytest.raises(InputFileError, match=r"f\.obj:5: face refers to vertex 7 but the file has 3"):
        read_obj(p)
    p = _write(tmp_path, "f2.obj", "v 0 0 0\nv 1 0 0\nf 1 2\n")
    with pytest.raises(InputFileError, match=r"f2\.obj:3: a face needs at least 3 corners"):
        read_obj(p)


def test_no_vertices_and_missing_file_name_the_file(tmp_path):
    with pytest.raises(InputFileError, match=r"empty\.obj: no vertices"):
        read_obj(_write(tmp_path, "empty.obj", "# nothing\n"))
    with pytest.raises(InputFileError, match=r"nope\.obj: file not found"):
        read_obj(tmp_path / "nope.obj")


def test_partial_uvs_are_dropped_with_a_warning(tmp_path):
    text = "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nvt 0 0\nf 1/1 2/1 3/1\nf 2 4 3\n"
    with pytest.warns(UserWarning, match="UVs are ignored"):
        m = read_obj(_write(tmp_path, "p.obj", text))
    assert m.uvs is None


def test_write_obj_unwritable_leaves_nothing(tmp_path):
    m = Mesh.from_triangles(np.eye(3), [[0, 1, 2]])
    with pytest.raises(OutputError, match="missing"):
        write_obj(tmp_path / "missing" / "x.obj", m)
    (tmp_path / "afile").write_text("")
    with pytest.raises(OutputError, match="afile"):
        write_obj(tmp_path / "afile" / "x.obj", m)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["afile"]


# ------------------------------------------------------------------------------------------- rigs
def _tiny_rig_folder(tmp_path, neutral_name="Neutral"):
    f = tmp_path / "rig"
    f.mkdir()
    base = Mesh.from_triangles(np.array([[0, 0, 0], [10, 0, 0], [0, 10, 0], [10, 10, 0.0]]),
                               [[0, 1, 2], [1, 3, 2]])
    write_obj(f / f"{neutral_name}.obj", base)
    write_obj(f / "jawOpen.obj", base, base.vertices + [0, -1, 0])
    write_obj(f / "eyeBlink_L.obj", base, base.vertices + [0, 0, 1])
    write_obj(f / "identity000.obj", base, base.vertices * 2)
    (f / "landmarks68.txt").write_text("0 1\n2 3\n")
    return f, base


def test_load_rig_synthetic(tmp_path):
    f, base = _tiny_rig_folder(tmp_path)
    rig = read_rig(f)
    assert rig.names == ["eyeBlinkLeft", "jawOpen"]  # sorted by file name, identity skipped
    assert rig.source_names == ["eyeBlink_L", "jawOpen"]
    np.testing.assert_allclose(rig.deltas[1], np.tile([0, -1, 0], (4, 1)))
    np.testing.assert_array_equal(rig.landmarks, [0, 1, 2, 3])
    assert rig.unit == "cm"  # a 14-unit face is centimetres
    assert read_rig(f, unit="mm", exclude=()).n_shapes == 3


def test_load_rig_explicit_neutral(tmp_path):
    f, _ = _tiny_rig_folder(tmp_path, neutral_name="base_pose")
    with pytest.raises(MissingShapeError):
        read_rig(f)
    rig = read_rig(f, neutral="base_pose.obj")
    assert rig.names == ["eyeBlinkLeft", "jawOpen"]


def test_missing_neutral_lists_names_and_folder(tmp_path):
    f, _ = _tiny_rig_folder(tmp_path, neutral_name="rest")
    with pytest.raises(MissingShapeError) as e:
        read_rig(f)
    msg = str(e.value)
    assert str(f) in msg and "neutral.obj" in msg and "generic_neutral_mesh.obj" in msg
    assert "*_neutral.obj" in msg


def test_key_shape_with_other_vertex_count(tmp_path):
    f, _ = _tiny_rig_folder(tmp_path)
    (f / "mouthClose.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    with pytest.raises(TopologyError, match=r"mouthClose\.obj: key shape has 3 vertices but the "
                                            r"neutral Neutral\.obj has 4"):
        read_rig(f)


def test_missing_rig_folder(tmp_path):
    with pytest.raises(InputFileError, match="nowhere"):
        read_rig(tmp_path / "nowhere")


def test_save_rig_obj_and_npz_round_trip(tmp_path):
    f, _ = _tiny_rig_folder(tmp_path)
    rig = read_rig(f)
    back = read_rig(write_rig(rig, tmp_path / "out"))
    assert back.names == rig.names and back.unit == rig.unit
    np.testing.assert_array_equal(back.deltas, rig.deltas)
    np.testing.assert_array_equal(back.landmarks, rig.landmarks)
    z = read_rig_npz(write_rig_npz(rig, tmp_path / "rig.npz"))
    assert z.names == rig.names and z.source_names == rig.source_names and z.unit == "cm"
    np.testing.assert_array_equal(z.deltas, rig.deltas)
    np.testing.assert_array_equal(z.neutral.face_indices, rig.neutral.face_indices)
    with pytest.raises(InputFileError, match=r"nope\.npz"):
        read_rig_npz(tmp_path / "nope.npz")


# -------------------------------------------------------------------------------------- real rigs
def test_ict_rig(ict_rig):
    r = ict_rig
    assert (r.n_vertices, r.n_shapes, r.unit) == (9409, 57, "cm")
    assert r.neutral.n_faces == 9230 and set(r.neutral.face_counts.tolist()) == {4}
    assert r.neutral.uvs is not None and r.landmarks.size == 68
    assert "eyeBlinkLeft" in r.names and "browInnerUpLeft" in r.names and "cheekRaiserRight" in r.names
    assert "eyeBlink_L" in r.source_names
    assert not any(n.lower().startswith("identity") for n in r.source_names)
    assert r.source_names == sorted(r.source_names, key=lambda s: (s.lower(), s))  # by file name
    assert np.abs(r.deltas[r.index("jawOpen")]).max() > 1.0  # centimetres


def test_arkit_rig(arkit_rig):
    r = arkit_rig
    assert (r.n_vertices, r.n_shapes, r.unit) == (1220, 51, "m")
    assert r.neutral.n_faces == 2304 and r.landmarks.size == 68
    assert "tongueOut" not in r.names and "jawOpen" in r.names


def test_all_ict_objs_load_fast(data_dir):
    files = sorted((data_dir / "ict-face").glob("*.obj"))
    t0 = time.perf_counter()
    meshes = [read_obj(p) for p in files]
    dt = time.perf_counter() - t0
    print(f"read_obj on {len(files)} ICT files: {dt:.2f} s")
    assert all(m.n_vertices == 9409 for m in meshes)
    assert dt < 15.0  # about 1.5 s here; generous for slow CI


def test_real_rig_npz_cache(arkit_rig, tmp_path):
    z = read_rig_npz(write_rig_npz(arkit_rig, tmp_path / "arkit.npz"))
    assert isinstance(z, Rig) and z.names == arkit_rig.names
    np.testing.assert_array_equal(z.deltas, arkit_rig.deltas)
    np.testing.assert_array_equal(z.landmarks, arkit_rig.landmarks)


def test_no_warnings_loading_rigs(data_dir):
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert read_rig(data_dir / "arkit-face").n_shapes == 51
