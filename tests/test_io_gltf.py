"""glTF binary export: round trips, seam splitting, units, and the Khronos validator (0 errors)."""

from __future__ import annotations

import json
import os
import shutil
import struct
import subprocess
import time
import warnings
from pathlib import Path

import numpy as np
import pytest

from faceretarget.errors import InvalidDataError, OutputError
from faceretarget.io import (
    glb_vertex_order,
    read_glb_rig,
    read_glb_weights,
    read_livelinkface,
    write_animation,
    write_glb,
)
from faceretarget.mesh import Mesh
from faceretarget.rig import Rig

REPO = Path(__file__).resolve().parents[1]
SCRIPT = REPO / "tests" / "tools" / "validate_gltf.mjs"
VALIDATOR = Path(os.environ.get("GLTF_VALIDATOR_DIR", REPO / ".tools" / "node_modules" / "gltf-validator"))


def _require() -> bool:
    return os.environ.get("FACERETARGET_REQUIRE_DATA", "") not in ("", "0")


def validate(path: Path) -> dict:
    """Run the Khronos glTF validator on ``path``; fail on any error, print warnings."""
    node = shutil.which("node")
    reason = None
    if node is None:
        reason = "node not found: cannot run the Khronos glTF validator"
    elif not (VALIDATOR / "package.json").is_file():
        reason = f"gltf-validator not installed at {VALIDATOR} (run `make tools`)"
    if reason:
        if _require():
            pytest.fail(reason)
        pytest.skip(reason)
    r = subprocess.run([node, str(SCRIPT), str(path), str(VALIDATOR)], capture_output=True,
                       text=True, timeout=300)
    assert r.returncode in (0, 1), f"validator could not run: {r.stderr}"
    report = json.loads(r.stdout)
    issues = report["issues"]
    for m in issues["messages"]:
        sev = {0: "ERROR", 1: "WARNING", 2: "INFO", 3: "HINT"}[m["severity"]]
        print(f"gltf-validator {sev} {m['code']} {m.get('pointer', '')}: {m['message']}")
    errors = [m for m in issues["messages"] if m["severity"] == 0]
    assert issues["numErrors"] == 0, errors
    return report


def _rig_back(path: Path) -> Rig:
    """``read_glb_rig`` of a file ``write_glb`` wrote: deprecated (it warns, naming what to call instead),
    it still reads the project's own files back in their vertex order with their shapes."""
    with pytest.warns(DeprecationWarning, match=r"read_glb_rig is deprecated: call faceretarget\.io\.read_character"):
        return read_glb_rig(path)


def _seam_rig(unit: str = "cm") -> Rig:
    """Two quads sharing an edge, each with its own UV island: the shared vertices have 2 UVs."""
    v = np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0], [0, 1, 0], [1, 1, 0], [2, 1, 0.2]], float) * 10
    uvs = np.array([[0, 0], [0.5, 0], [0.5, 1], [0, 1], [0.6, 0], [1, 0], [1, 1], [0.6, 1]])
    m = Mesh(v, [4, 4], [0, 1, 4, 3, 1, 2, 5, 4], uvs, [0, 1, 2, 3, 4, 5, 6, 7], name="seam")
    rng = np.random.default_rng(3)
    return Rig(m, ["jawOpen", "eyeBlink_L", "mouthSmile_R"], rng.normal(size=(3, 6, 3)), unit=unit,
               name="seam")


def test_round_trip_synthetic(tmp_path):
    rig = _seam_rig()
    T = 40
    times = 5.0 + np.arange(T) / 30.0
    w = np.random.default_rng(4).random((T, 3))
    out = write_glb(tmp_path / "s.glb", rig, w, times, node_name="head")
    names, t, back = read_glb_weights(out)
    assert names == rig.names
    np.testing.assert_array_equal(t, (times - times[0]).astype(np.float32))
    np.testing.assert_array_equal(back, w.astype(np.float32))
    src = glb_vertex_order(rig.neutral)
    np.testing.assert_array_equal(src, [0, 1, 1, 2, 3, 4, 4, 5])  # vertices 1 and 4 are on the seam
    g = _rig_back(out)
    assert g.n_vertices == 8 and g.names == rig.names and g.unit == "m"
    np.testing.assert_allclose(g.neutral.vertices, rig.neutral.vertices[src] / 100, atol=1e-6)
    np.testing.assert_allclose(g.deltas, rig.deltas[:, src] / 100, atol=1e-6)  # cm -> m
    # each glTF vertex carries the UV its corners used
    corner_uv = {}
    for c, (vi, ui) in enumerate(zip(g.neutral.face_indices, g.neutral.face_uv_indices, strict=True)):
        corner_uv.setdefault(int(vi), set()).add(tuple(g.neutral.uvs[ui]))
        assert c >= 0
    assert all(len(s) == 1 for s in corner_uv.values())
    validate(out)


def test_named_weights_are_mapped_with_one_warning(tmp_path):
    rig = _seam_rig(unit="m")
    w = np.array([[0.1, 0.2, 0.3, 0.4], [0.5, 0.6, 0.7, 0.8]])
    with pytest.warns(UserWarning, match="tongueOut") as ws:
        out = write_glb(tmp_path / "n.glb", rig, w, [0, 0.1],
                        names=["MouthSmileRight", "JawOpen", "tongueOut", "EyeBlinkLeft"])
    assert len(ws) == 1
    _, _, back = read_glb_weights(out)
    np.testing.assert_allclose(back, [[0.2, 0.4, 0.1], [0.6, 0.8, 0.5]], atol=1e-7)
    g = _rig_back(out)
    np.testing.assert_allclose(g.deltas, rig.deltas[:, glb_vertex_order(rig.neutral)], atol=1e-6)


def test_bad_inputs(tmp_path):
    rig = _seam_rig()
    with pytest.raises(InvalidDataError, match=r"shape \(3, 3\) for 3 times and 3 shapes, got \(3, 2\)"):
        write_glb(tmp_path / "a.glb", rig, np.zeros((3, 2)), [0, 1, 2])
    with pytest.raises(InvalidDataError, match="frame 2 time"):
        write_glb(tmp_path / "a.glb", rig, np.zeros((3, 3)), [0, 1, 1])
    w = np.zeros((3, 3))
    w[1, 2] = np.nan
    with pytest.raises(InvalidDataError, match="frame 1 weight 'mouthSmileRight' is nan"):
        write_glb(tmp_path / "a.glb", rig, w, [0, 1, 2])
    assert not list(tmp_path.iterdir())


def test_unwritable_output_leaves_nothing(tmp_path):
    rig = _seam_rig()
    with pytest.raises(OutputError, match=r"no_such_folder"):
        write_glb(tmp_path / "no_such_folder" / "x.glb", rig, np.zeros((2, 3)), [0, 1])
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o500)
    try:
        target = ro
        if os.access(ro, os.W_OK):  # root ignores permissions; sysfs refuses new files even to root
            if not Path("/sys/kernel").is_dir():
                pytest.skip("running as root without /sys: no read-only folder to try")
            target = Path("/sys")
        with pytest.raises(OutputError, match=rf"{target}.*(not writable|cannot write)"):
            write_animation(target / "x.glb", rig=rig, weights=np.zeros((2, 3)), times=[0, 1])
        assert not list(ro.iterdir())
    finally:
        ro.chmod(0o700)


def test_arkit_rig_with_real_take_validates(arkit_rig, data_dir, tmp_path):
    perf = read_livelinkface(data_dir / "livelinkface" / "S07-001.csv")
    with pytest.warns(UserWarning, match="tongueOut"):  # the ARKit test rig has no tongueOut shape
        out = write_glb(tmp_path / "arkit.glb", arkit_rig, perf.weights, perf.times, names=perf.names)
    names, t, w = read_glb_weights(out)
    assert names == arkit_rig.names and w.shape == (2028, 51)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        expect = arkit_rig.map_weights(perf.names, perf.weights)
    np.testing.assert_array_equal(w, expect.astype(np.float32))
    assert t[-1] == pytest.approx(perf.duration, abs=1e-5)
    g = _rig_back(out)
    src = glb_vertex_order(arkit_rig.neutral)
    np.testing.assert_allclose(g.deltas, arkit_rig.deltas[:, src], atol=1e-6)  # already metres
    report = validate(out)
    assert report["info"]["animationCount"] == 1 and report["info"]["maxAttributes"] >= 2


def test_ict_rig_2000_frames(ict_rig, data_dir, tmp_path):
    perf = read_livelinkface(data_dir / "livelinkface" / "alex_rom_3.csv").slice(0, 2000)
    t0 = time.perf_counter()
    with pytest.warns(UserWarning, match="tongueOut"):
        out = write_glb(tmp_path / "ict.glb", ict_rig, perf.weights, perf.times, names=perf.names)
    dt = time.perf_counter() - t0
    print(f"write_glb ICT rig (9409 verts, 57 targets), 2000 frames: {dt:.2f} s, "
          f"{out.stat().st_size / 1e6:.1f} MB")
    assert dt < 20.0
    g = _rig_back(out)
    src = glb_vertex_order(ict_rig.neutral)
    assert g.n_vertices == len(src) >= 9409 and g.n_shapes == 57
    np.testing.assert_allclose(g.deltas, ict_rig.deltas[:, src] / 100.0, atol=1e-6)  # cm -> m
    diag = np.linalg.norm(g.neutral.vertices.max(0) - g.neutral.vertices.min(0))
    assert 0.15 < diag < 0.6  # a human face in metres
    validate(out)


def test_point_set_keys_write_a_valid_points_primitive(tmp_path):
    """Keyshapes exported from markers are point sets (no faces): the .glb holds a POINTS primitive
    (mode 0, no indices) with the morph targets, the Khronos validator accepts it, and it reads back."""
    rng = np.random.default_rng(5)
    pts = Mesh(rng.normal(size=(12, 3)) * 30.0, name="markers")
    rig = Rig(pts, ["frame_00010", "frame_00042"], rng.normal(size=(2, 12, 3)), unit="mm", name="markers")
    w = rng.random((25, 2))
    out = write_glb(tmp_path / "points.glb", rig, w, np.arange(25) / 60.0)
    report = validate(out)
    assert report["issues"]["numErrors"] == 0
    g = _rig_back(out)
    assert g.neutral.n_faces == 0 and g.names == rig.names
    np.testing.assert_allclose(g.neutral.vertices, rig.neutral.vertices / 1000, atol=1e-6)
    np.testing.assert_allclose(g.deltas, rig.deltas / 1000, atol=1e-6)
    names, _, back = read_glb_weights(out)
    np.testing.assert_array_equal(back, w.astype(np.float32))


def test_readme_marker_keys_command_writes_a_valid_glb(data_dir, tmp_path):
    """The README's marker route (issue 14): keys select on Jaw.c3d, the same point sets as the
    'artist's' target keys, retarget Cheeks.c3d to .glb: the validator accepts the file."""
    import shutil as sh

    from faceretarget.cli import main

    jaw, cheeks = data_dir / "facial-mocap" / "Jaw.c3d", data_dir / "facial-mocap" / "Cheeks.c3d"
    keys = tmp_path / "jaw_keys"
    assert main(["-q", "keys", "select", "--performance", str(jaw), "--k", "8", "--out", str(keys)]) == 0
    target = tmp_path / "target_keys"
    sh.copytree(keys, target)
    out = tmp_path / "t.glb"
    assert main(["-q", "retarget", "--performance", str(cheeks), "--source-keys", str(keys),
                 "--target-keys", str(target), "--out", str(out)]) == 0
    validate(out)
    assert _rig_back(out).neutral.n_faces == 0


@pytest.mark.parametrize("ext", [".glb", ".npz", ".csv", ".usda"])
def test_no_writer_accepts_non_finite_values(ext, tmp_path):
    """issue 14: output sanity at the writer, one place for every format."""
    from faceretarget.errors import InvalidDataError
    from faceretarget.io import write_animation

    rig = _seam_rig()
    w = np.random.default_rng(1).random((10, 3))
    w[4, 1] = np.nan
    out = tmp_path / f"x{ext}"
    with pytest.raises(InvalidDataError, match=r"weights hold a non-finite value at frame 4 \('eyeBlinkLeft'\)"):
        write_animation(out, rig=rig, weights=w, times=np.arange(10) / 30.0)
    assert not out.exists()
    with pytest.raises(InvalidDataError, match="times must be finite"):
        write_animation(out, rig=rig, weights=np.zeros((10, 3)), times=np.r_[np.arange(9) / 30.0, np.inf])
    assert not out.exists()


# ------------------------------------------------------------------ read_glb_rig: the character's face
def _grid(nx: int, ny: int, origin, size: float) -> tuple[np.ndarray, np.ndarray]:
    """An ``nx`` x ``ny`` vertex grid in the XY plane (metres) and its triangles."""
    x, y = np.meshgrid(np.linspace(0, size, nx), np.linspace(0, size, ny))
    P = np.c_[x.ravel(), y.ravel(), np.zeros(x.size)] + origin
    q = np.array([[j * nx + i, j * nx + i + 1, (j + 1) * nx + i + 1, (j + 1) * nx + i]
                  for j in range(ny - 1) for i in range(nx - 1)])
    return P, np.r_[q[:, [0, 1, 2]], q[:, [0, 2, 3]]]


def _avatar_glb(path: Path, meshes: list[tuple[str, list[tuple[np.ndarray, np.ndarray, np.ndarray]]]],
                names: list[str]) -> Path:
    """A ``.glb`` laid out as Ready Player Me ships an ARKit avatar: one node per mesh in file order (the
    eyeballs first), every mesh with the same morph target names; each mesh a list of primitives
    ``(positions, triangles, deltas (K, V, 3))``."""
    chunks, views, accessors = [], [], []

    def acc(arr: np.ndarray, type_: str, ctype: int, **kw) -> int:
        data = np.ascontiguousarray(arr).tobytes()
        views.append({"buffer": 0, "byteOffset": sum(len(c) for c in chunks), "byteLength": len(data)})
        chunks.append(data + b"\0" * (-len(data) % 4))
        accessors.append({"bufferView": len(views) - 1, "componentType": ctype, "count": len(arr), "type": type_, **kw})
        return len(accessors) - 1

    js_meshes = []
    for name, prims in meshes:
        out = []
        for P, T, D in prims:
            P32 = P.astype(np.float32)
            out.append({"attributes": {"POSITION": acc(P32, "VEC3", 5126, min=P32.min(0).tolist(),
                                                       max=P32.max(0).tolist())},
                        "indices": acc(T.astype(np.uint16).ravel(), "SCALAR", 5123), "mode": 4,
                        "targets": [{"POSITION": acc(d.astype(np.float32), "VEC3", 5126)} for d in D]})
        js_meshes.append({"name": name, "primitives": out, "extras": {"targetNames": names}})
    js = {"asset": {"version": "2.0"}, "scene": 0, "scenes": [{"nodes": list(range(len(meshes)))}],
          "nodes": [{"name": name, "mesh": i} for i, (name, _) in enumerate(meshes)], "meshes": js_meshes,
          "accessors": accessors, "bufferViews": views, "buffers": [{"byteLength": sum(len(c) for c in chunks)}]}
    body = json.dumps(js).encode()
    body += b" " * (-len(body) % 4)
    binchunk = b"".join(chunks)
    path.write_bytes(struct.pack("<III", 0x46546C67, 2, 28 + len(body) + len(binchunk))
                     + struct.pack("<II", len(body), 0x4E4F534A) + body
                     + struct.pack("<II", len(binchunk), 0x004E4942) + binchunk)
    return path


def test_read_glb_rig_is_the_face_of_an_avatar_not_its_first_mesh(tmp_path):
    """A Ready Player Me layout: the 120-vertex left eyeball comes first and has the shapes too (only its
    gaze shape moves it); the head's skin is two primitives.  read_glb_rig used to return the eyeball (the
    first primitive of the first mesh); now it is the character reader's face: the head, both primitives
    joined, every shape under its exact name, as read_character's primary mesh."""
    from faceretarget.io import read_character

    names = ["eyeBlinkLeft", "eyeLookUpLeft", "jawOpen", "mouthSmile_L", "viseme_aa"]
    rng = np.random.default_rng(8)

    def deltas(V: int, moving: list[str]) -> np.ndarray:
        D = np.zeros((len(names), V, 3))
        for n in moving:
            D[names.index(n)] = rng.normal(0, 0.003, (V, 3))
        return D

    eye_p, eye_t = _grid(10, 12, (0.03, 1.6, 0.08), 0.024)
    skin_p, skin_t = _grid(12, 12, (-0.08, 1.5, 0.05), 0.16)
    lips_p, lips_t = _grid(8, 3, (-0.03, 1.52, 0.07), 0.06)
    teeth_p, teeth_t = _grid(6, 3, (-0.02, 1.53, 0.06), 0.04)
    head = [(skin_p, skin_t, deltas(len(skin_p), ["eyeBlinkLeft", "jawOpen", "mouthSmile_L", "viseme_aa"])),
            (lips_p, lips_t, deltas(len(lips_p), ["jawOpen", "mouthSmile_L", "viseme_aa"]))]
    path = _avatar_glb(tmp_path / "rpm.glb", [
        ("EyeLeft", [(eye_p, eye_t, deltas(len(eye_p), ["eyeLookUpLeft"]))]),
        ("EyeRight", [(eye_p - [0.06, 0, 0], eye_t, deltas(len(eye_p), ["eyeLookUpLeft"]))]),
        ("Wolf3D_Head", head),
        ("Wolf3D_Teeth", [(teeth_p, teeth_t, deltas(len(teeth_p), ["jawOpen"]))])], names)
    assert len(eye_p) == 120

    with pytest.warns(DeprecationWarning, match="read_character"):
        rig = read_glb_rig(path)
    ch = read_character(path)
    face = ch.meshes[ch.primary]
    assert face.name == "Wolf3D_Head" and rig.name == "Wolf3D_Head"
    assert rig.n_vertices == face.mesh.n_vertices == len(skin_p) + len(lips_p) == 168   # both primitives
    assert rig.names == face.shape_names == names and rig.unit == "m"                   # exact names, all of them
    np.testing.assert_array_equal(rig.neutral.vertices, face.mesh.vertices)
    np.testing.assert_array_equal(rig.neutral.vertices, np.r_[skin_p, lips_p].astype(np.float32))
    np.testing.assert_array_equal(rig.neutral.triangles(), np.r_[skin_t, lips_t + len(skin_p)])
    np.testing.assert_allclose(rig.deltas, np.concatenate([d for _, _, d in head], axis=1), atol=1e-9)
    assert rig.index("mouthSmileLeft") == 3                                             # any spelling finds it


def test_read_glb_rig_reads_the_shared_avatars_as_read_character_does(chars):
    """On real files: RobotExpressive (its head is three primitives; its first mesh is a foot: 64 vertices,
    no shapes, before) and a VALID avatar (EXT_meshopt_compression + KHR_mesh_quantization: 'external
    buffers are not supported', before)."""
    from faceretarget.io import read_character

    for path, vertices, shapes, first in ((chars / "robot" / "RobotExpressive.glb", 302 + 876 + 564, 3, "Angry"),
                                          (chars / "valid" / "AIAN_F_1_Busi.glb", 22249, 65, "h_expressions.AE_AA_h")):
        with pytest.warns(DeprecationWarning, match=r"call faceretarget\.io\.read_character\(path\)"):
            rig = read_glb_rig(path)
        ch = read_character(path)
        face = ch.meshes[ch.primary]
        assert (rig.name, rig.n_vertices, rig.n_shapes, rig.names[0]) == (face.name, vertices, shapes, first), path.name
        assert rig.names == face.shape_names
        np.testing.assert_array_equal(rig.neutral.vertices, face.mesh.vertices)
        np.testing.assert_array_equal(rig.deltas, face.deltas)
        np.testing.assert_array_equal(rig.neutral.triangles(), face.mesh.triangles())
