"""New shapes written into a copy of the character's own file (issue 25): glTF / VRM morph targets, Blender
shape keys (.fbx, .blend), an OBJ folder; read back by our readers they are the deltas given (float32),
the file's own shapes, images and everything else unchanged, the Khronos validator adds nothing; and the
contact sheet of ``character inspect --sheet``."""

from __future__ import annotations

import collections
import json
import shutil
import struct
import subprocess
import tempfile
import time
from pathlib import Path

import numpy as np
import pytest

from faceretarget.character import character_frame
from faceretarget.characters import drive_rig
from faceretarget.errors import InvalidDataError, MissingShapeError, OutputError
from faceretarget.io import read_character, write_character_shapes
from faceretarget.pipelines import shape_sheet

REPO = Path(__file__).resolve().parents[1]
VALIDATOR = REPO / ".tools" / "node_modules" / "gltf-validator"
ARKIT = ["jawOpen", "eyeBlinkLeft", "eyeBlinkRight", "mouthSmileLeft", "mouthSmileRight", "browInnerUp",
         "mouthFunnel", "mouthPucker", "cheekPuff", "mouthClose", "browDownLeft", "browDownRight"]


def _field(V: np.ndarray, seed: int, amp: float = 0.004) -> np.ndarray:
    """A smooth random displacement field on the vertices (metres)."""
    r = np.random.default_rng(seed)
    s = float(np.ptp(V, axis=0).max())
    k = r.normal(size=(3, 3)) * 3.0 / s
    ph = r.uniform(0, 2 * np.pi, 3)
    return (amp * np.sin(V @ k.T + ph)).astype(np.float32)


def _added(ch, names, mesh=None):
    sm = ch.meshes[ch.face_meshes()[0] if mesh is None else mesh]
    return sm, {sm.name: {n: _field(sm.mesh.vertices, k) for k, n in enumerate(names)}}


def _validator(path: Path) -> collections.Counter | None:
    if shutil.which("node") is None or not (VALIDATOR / "package.json").is_file():
        return None
    with tempfile.TemporaryFile("w+") as f:           # a file, not a pipe: a long report is not cut
        subprocess.run(["node", str(REPO / "tests" / "tools" / "validate_gltf.mjs"), str(path), str(VALIDATOR)],
                       stdout=f, text=True, timeout=300)
        f.seek(0)
        issues = json.load(f)["issues"]
    return collections.Counter((m["severity"], m["code"]) for m in issues["messages"] if m["severity"] <= 1)


def _glb_parts(path: Path) -> tuple[dict, bytes]:
    data = path.read_bytes()
    n = struct.unpack_from("<I", data, 12)[0]
    return json.loads(data[20:20 + n]), data[20 + n + 8:]


def _without_new_expressions(ext1, ext0):
    """``ext1`` with the VRM expressions ``ext0`` does not have taken out (VRM 1.0 custom, 0.x groups)."""
    if not isinstance(ext1, dict) or not isinstance(ext0, dict):
        return ext1
    out = json.loads(json.dumps(ext1))
    if "VRMC_vrm" in out:
        e1, e0 = out["VRMC_vrm"].get("expressions", {}), ext0["VRMC_vrm"].get("expressions", {})
        e1["custom"] = {k: v for k, v in e1.get("custom", {}).items() if k in e0.get("custom", {})}
        if not e1["custom"] and "custom" not in e0:
            del e1["custom"]
    if "VRM" in out:
        g0 = ext0["VRM"].get("blendShapeMaster", {}).get("blendShapeGroups", [])
        out["VRM"]["blendShapeMaster"]["blendShapeGroups"] = out["VRM"]["blendShapeMaster"]["blendShapeGroups"][:len(g0)]
    return out


def _check_gltf(src: Path, out: Path, ch, sm, added):
    """Read back: new shapes equal (1e-5 m), old shapes and every mesh unchanged, the validator adds
    nothing, JSON and binary kept apart from the added data (so images are byte-identical)."""
    ch2 = read_character(out)
    sm2 = next(m for m in ch2.meshes if m.name == sm.name)
    errs = []
    for n, d in added[sm.name].items():
        errs.append(float(np.abs(sm2.deltas[sm2.shape_names.index(n)] - d).max()))
    assert max(errs) < 1e-5, errs
    for a, b in zip(ch.meshes, ch2.meshes, strict=True):
        assert a.name == b.name and np.array_equal(a.mesh.vertices, b.mesh.vertices)
        assert b.shape_names[:a.n_shapes] == a.shape_names and np.array_equal(b.deltas[:a.n_shapes], a.deltas)
    js0, bin0 = _glb_parts(src)
    js1, bin1 = _glb_parts(out)
    assert bin1[:len(bin0.rstrip(b"\0"))] == bin0.rstrip(b"\0")             # the binary chunk only grows
    for key in ("nodes", "materials", "textures", "images", "samplers", "skins", "extensions", "scenes"):
        if key == "nodes":
            strip = [{k: v for k, v in n.items() if k != "weights"} for n in js1.get(key, [])]
            assert strip == [{k: v for k, v in n.items() if k != "weights"} for n in js0.get(key, [])]
        elif key == "extensions":                   # a VRM's expressions gain the new shapes', nothing else changes
            assert _without_new_expressions(js1.get(key), js0.get(key)) == js0.get(key), key
        else:
            assert js1.get(key) == js0.get(key), key
    assert js1["accessors"][:len(js0["accessors"])] == js0["accessors"]
    assert js1["bufferViews"][:len(js0["bufferViews"])] == js0["bufferViews"]
    va, vb = _validator(src), _validator(out)
    if va is not None:
        assert not (vb - va), vb - va
    return ch2, max(errs)


def test_valid_avatar_morph_targets_round_trip(tmp_path, chars):
    """A VALID avatar (meshopt, quantized, skinned, WebP): 12 ARKit shapes and one that replaces an existing one."""
    src = chars / "valid" / "AIAN_F_1_Busi.glb"
    ch = read_character(src)
    sm, added = _added(ch, ARKIT)
    own = sm.shape_names[0]
    logs: list[str] = []
    out = write_character_shapes(tmp_path / "busi.glb", ch, {sm.name: {**added[sm.name], own: _field(
        sm.mesh.vertices, 99)}}, log=logs.append)
    assert any(own in m and "kept" in m for m in logs)
    ch2, err = _check_gltf(src, out, ch, sm, added)
    print(f"VALID glb: max error {err:.2e} m")
    from faceretarget.io import GltfDocument

    doc = GltfDocument(out)                    # its targets have normals: the new ones too, zero for a shift
    gm = doc.json["meshes"][doc.json["nodes"][int(sm.ref.split(":")[1])]["mesh"]]
    shift = {sm.name: {"shift": np.tile(np.float32([0.001, -0.002, 0.0005]), (sm.mesh.n_vertices, 1))}}
    doc2 = GltfDocument(write_character_shapes(tmp_path / "shift.glb", ch, shift))
    for p, p2 in zip(gm["primitives"], doc2.json["meshes"][doc.json["nodes"][int(sm.ref.split(":")[1])]["mesh"]][
            "primitives"], strict=True):
        assert "NORMAL" in p["targets"][-1]
        assert np.abs(doc2.accessor(p2["targets"][-1]["NORMAL"])).max() < 1e-4
    sm2 = ch2.meshes[ch.meshes.index(sm)]
    assert sm2.n_shapes == sm.n_shapes + len(ARKIT)
    # the new ARKit names are found by --shapes arkit
    dr = drive_rig(ch2, "arkit", need_landmarks=False)
    assert {c.name for c in dr.channels} >= set(ARKIT)
    # a mesh with no morph targets at all (the hair) gets its first, with names
    wig = next(m for m in ch.meshes if m.n_shapes == 0 and m.mesh.n_vertices > 1000)
    d = _field(wig.mesh.vertices, 11)
    w2 = read_character(write_character_shapes(tmp_path / "wig.glb", ch, {wig.name: {"jawOpen": d}}))
    w2m = w2.meshes[ch.meshes.index(wig)]
    assert w2m.shape_names == ["jawOpen"] and np.abs(w2m.deltas[0] - d).max() < 1e-5
    va, vb = _validator(src), _validator(tmp_path / "wig.glb")
    assert va is None or not (vb - va)
    # replace=True: the file's own shape replaced, indices unchanged
    new = _field(sm.mesh.vertices, 7)
    out2 = write_character_shapes(tmp_path / "busi2.glb", ch, {sm.name: {own: new}}, replace=True)
    ch3 = read_character(out2)
    sm3 = ch3.meshes[ch.meshes.index(sm)]
    assert sm3.shape_names == sm.shape_names
    assert np.abs(sm3.deltas[0] - new).max() < 1e-5 and np.array_equal(sm3.deltas[1:], sm.deltas[1:])


def test_robot_three_primitives_and_weight_animations(tmp_path, chars):
    """RobotExpressive: a mesh of three primitives (each gets its slice), its weight animations widened."""
    src = chars / "robot" / "RobotExpressive.glb"
    ch = read_character(src)
    sm, added = _added(ch, ["jawOpen", "eyeBlinkLeft"])
    out = write_character_shapes(tmp_path / "robot.glb", ch, added)
    _, err = _check_gltf(src, out, ch, sm, added)
    print(f"RobotExpressive glb: max error {err:.2e} m")
    js, _ = _glb_parts(out)
    mesh = js["meshes"][js["nodes"][int(sm.ref.split(':')[1])]["mesh"]]
    assert len(mesh["primitives"]) == 3 and all(len(p["targets"]) == 5 for p in mesh["primitives"])
    assert mesh["extras"]["targetNames"][-2:] == ["jawOpen", "eyeBlinkLeft"]
    # three.js (headless Chromium) loads it with the new morph targets under their names
    chromium = shutil.which("chromium") or "/usr/bin/chromium"
    if shutil.which("node") and (REPO / ".tools" / "node_modules" / "three").is_dir() and Path(chromium).is_file():
        r = subprocess.run(["node", str(REPO / "tests" / "browser" / "run_three.mjs"), str(out), "--times", "0",
                            "--head", "none"], capture_output=True, text=True, timeout=200)
        assert r.returncode == 0, r.stderr[-300:]
        assert json.loads(r.stdout)["names"][-2:] == ["jawOpen", "eyeBlinkLeft"]


@pytest.mark.parametrize("version", ["0", "1"])
def test_vrm_stays_a_vrm_with_its_expressions(tmp_path, chars, version):
    import sys

    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from _vrm import make_vrm

    src = make_vrm(chars / "valid" / "Black_M_2_Busi.glb", tmp_path / f"b{version}.vrm", version,
                   {"aa": "h_expressions.AE_AA_h", "blinkLeft": "h_expressions.LeyeClose_h"})
    ch = read_character(src)
    sm, added = _added(ch, ARKIT[:3])
    out = write_character_shapes(tmp_path / f"o{version}.vrm", ch, added)
    ch2, err = _check_gltf(src, out, ch, sm, added)
    assert ch2.format == f"vrm{version}"
    assert {k: v for k, v in ch2.expressions.items() if k in ch.expressions} == ch.expressions   # kept as they were
    # issue 34: each new shape is bound to an expression of its name, so a VRM player (which sets expressions,
    # not morph targets) plays it: a custom expression (1.0) / blend shape group (0.x) at full weight
    new = {k: v for k, v in ch2.expressions.items() if k not in ch.expressions}
    assert set(new) == set(added[sm.name]), sorted(new)
    mi = next(i for i, m in enumerate(ch2.meshes) if m.name == sm.name)
    for name, e in new.items():
        assert not e["preset"] and e["binds"] == [(mi, ch2.meshes[mi].shape_names.index(name), 1.0)], (name, e)
    print(f"VRM {version}: max error {err:.2e} m")


def test_gltf_json_and_obj_folder(tmp_path, chars, arkit_rig):
    """A .gltf copy (the new data in NAME.shapes.bin) and an OBJ folder in the head frame."""
    from faceretarget.io import write_glb

    src = write_glb(tmp_path / "arkit.glb", arkit_rig, np.zeros((1, arkit_rig.n_shapes)), np.zeros(1))
    ch = read_character(src)
    sm, added = _added(ch, ["cheekPuffBig", "jawOpen"])
    (tmp_path / "copy").mkdir()
    out = write_character_shapes(tmp_path / "copy" / "a.gltf", ch, added)
    assert (tmp_path / "copy" / "a.shapes.bin").is_file()
    ch2 = read_character(out)
    sm2 = ch2.meshes[0]
    assert np.abs(sm2.deltas[sm2.shape_names.index("cheekPuffBig")] - added[sm.name]["cheekPuffBig"]).max() < 1e-5
    assert np.array_equal(sm2.deltas[sm2.shape_names.index("jawOpen")], sm.deltas[sm.shape_names.index("jawOpen")])
    folder = write_character_shapes(str(tmp_path / "rig") + "/", ch, added, replace=True)
    rig = read_character(folder)
    R = character_frame(ch)
    r = rig.meshes[0]
    assert r.mesh.n_vertices == sm.mesh.n_vertices and np.abs(r.mesh.vertices - sm.mesh.vertices @ R.T).max() < 1e-6
    for n, d in added[sm.name].items():
        assert np.abs(r.deltas[r.shape_names.index(n)] - d @ R.T).max() < 1e-5
    assert r.n_shapes == sm.n_shapes + 1


def test_bad_inputs_are_named(tmp_path, chars):
    src = chars / "robot" / "RobotExpressive.glb"
    ch = read_character(src)
    sm = ch.meshes[ch.face_meshes()[0]]
    V = sm.mesh.n_vertices
    with pytest.raises(InvalidDataError, match="no mesh 'Nope'"):
        write_character_shapes(tmp_path / "a.glb", ch, {"Nope": {"x": np.zeros((V, 3))}})
    with pytest.raises(InvalidDataError, match=f"'x'.*{V} vertices"):
        write_character_shapes(tmp_path / "a.glb", ch, {sm.name: {"x": np.zeros((V - 1, 3))}})
    bad = np.zeros((V, 3))
    bad[5, 1] = np.nan
    with pytest.raises(InvalidDataError, match="'x' has a non-finite delta"):
        write_character_shapes(tmp_path / "a.glb", ch, {sm.name: {"x": bad}})
    with pytest.raises(OutputError, match="own file"):
        write_character_shapes(src, ch, {sm.name: {"x": np.zeros((V, 3))}})
    with pytest.raises(OutputError, match="written as"):
        write_character_shapes(tmp_path / "a.fbx", ch, {sm.name: {"x": np.zeros((V, 3))}})
    assert not list(tmp_path.iterdir())


def test_blender_shape_keys_fbx_and_blend(tmp_path, chars):
    """Rocketbox (.fbx read by ufbx): shape keys added through Blender, as .blend and .fbx; then the .blend
    (read by Blender) gets one replaced.  Read back, the keys are the deltas (Blender's frame)."""
    pytest.importorskip("bpy")
    from faceretarget.io._blender import BLENDER_AXES  # noqa: PLC2701 (the Y-up -> Z-up turn, test only)

    src = chars / "rocketbox" / "Female_Adult_01_facial.fbx"
    ch = read_character(src)
    sm, added = _added(ch, ["jawOpen", "eyeBlinkLeft"])
    A = np.asarray(BLENDER_AXES)
    res = {}
    for ext in (".blend", ".fbx"):
        out = write_character_shapes(tmp_path / f"rb{ext}", ch, added)
        ch2 = read_character(out, prefer="blender")
        sm2 = ch2.meshes[0]
        assert np.abs(sm2.mesh.vertices - sm.mesh.vertices @ A.T).max() < 1e-5
        res[ext] = max(float(np.abs(sm2.deltas[sm2.shape_names.index(n)] - d @ A.T).max())
                       for n, d in added[sm.name].items())
        assert res[ext] < 1e-5, res
        old = [k for k, n in enumerate(sm2.shape_names) if n not in added[sm.name]]
        assert len(old) >= sm.n_shapes
    print(f"Blender shape keys: max error {res}")
    # issue 34: the .fbx copy keeps the file's own shape names (Blender's importer had dropped the deformer part,
    # 'blendShape1.AA_VI_00_Sil' came back as 'AA_VI_00_Sil'): read by ufbx, as an engine reads it
    back = read_character(tmp_path / "rb.fbx")
    names = [n for m in back.meshes for n in m.shape_names]
    assert set(sm.shape_names) <= set(names) and set(added[sm.name]) <= set(names), sorted(set(sm.shape_names) - set(names))[:3]
    blend = tmp_path / "rb.blend"
    ch2 = read_character(blend)
    sm2 = ch2.meshes[0]
    new = _field(sm2.mesh.vertices, 5)
    out = write_character_shapes(tmp_path / "rb2.blend", ch2, {sm2.name: {"jawOpen": new}}, replace=True)
    ch3 = read_character(out)
    sm3 = ch3.meshes[0]
    assert sm3.shape_names == sm2.shape_names
    k = sm3.shape_names.index("jawOpen")
    assert np.abs(sm3.deltas[k] - new).max() < 1e-5
    keep = [i for i in range(sm2.n_shapes) if i != k]
    assert np.abs(sm3.deltas[keep] - sm2.deltas[keep]).max() < 1e-6


def test_contact_sheet(tmp_path, chars):
    """The sheet: neutral and every chosen shape, labels under the tiles, without landmarks too."""
    from PIL import Image

    ch = read_character(chars / "robot" / "RobotExpressive.glb")
    t0 = time.perf_counter()
    out = shape_sheet(ch, tmp_path / "s.png", cols=2, tile=96)
    assert time.perf_counter() - t0 < 20
    im = np.asarray(Image.open(out))
    n = 1 + len(ch.meshes[ch.face_meshes()[0]].shape_names)
    rows = -(-n // 2)
    assert im.shape[1] == 2 * (96 + 4) + 4 and im.shape[0] == rows * (96 + 18 + 4) + 4
    tiles = [im[4 + r * 118: 4 + r * 118 + 96, 4 + c * 100: 4 + c * 100 + 96].astype(int)
             for r in range(rows) for c in range(2)][:n]
    assert all(np.abs(t - tiles[0]).sum() > 0 for t in tiles[1:])        # every shape changes the face
    j = shape_sheet(ch, tmp_path / "s.jpg", shapes="Angry,Surprised", tile=64)
    assert Image.open(j).format == "JPEG" and Image.open(j).size == (3 * 68 + 4, 64 + 18 + 8)
    with pytest.raises(MissingShapeError, match="nothing_like_this"):
        shape_sheet(ch, tmp_path / "x.png", shapes="nothing_like_this")


def test_usd_layer_adds_blend_shapes(tmp_path, chars, arkit_rig):
    """USD: a layer over the asset (untouched) adds bound BlendShape prims: a face written by write_usd
    (.usda) and Rocketbox exported by Blender (.usdc, skinned, centimetres); read back by usd-core, and
    UsdSkel's blend shape query and Blender's USD importer see them under their names."""
    pytest.importorskip("pxr")
    from pxr import Usd, UsdSkel

    from faceretarget.io import write_usd

    a = write_usd(tmp_path / "arkit.usda", arkit_rig, np.zeros((1, arkit_rig.n_shapes)), np.zeros(1))
    assets = [(a, tmp_path / "arkit_new.usda")]
    bpy = None
    try:
        import bpy  # noqa: F401
    except ImportError:
        pass
    if bpy is not None:
        from faceretarget.io._blender import _blender_output  # noqa: PLC2701

        rb = tmp_path / "rb.usdc"
        with _blender_output():
            bpy.ops.wm.read_factory_settings(use_empty=True)
            bpy.ops.import_scene.fbx(filepath=str(chars / "rocketbox" / "Female_Adult_01_facial.fbx"))
            bpy.ops.wm.usd_export(filepath=str(rb), export_armatures=True, export_shapekeys=True,
                                  export_animation=False, export_textures=False)
            bpy.ops.wm.read_factory_settings(use_empty=True)
        assets.append((rb, tmp_path / "rb_new.usdc"))
    for src, out in assets:
        before = src.read_bytes()
        ch = read_character(src)
        sm, added = _added(ch, ["cheekPuffBig", "jawOpen"])
        added[sm.name]["jawOpen"] *= 2
        write_character_shapes(out, ch, added, replace=True)
        assert src.read_bytes() == before
        ch2 = read_character(out)
        sm2 = next(m for m in ch2.meshes if m.name == sm.name)
        err = max(float(np.abs(sm2.deltas[sm2.shape_names.index(n)] - d).max()) for n, d in added[sm.name].items())
        assert err < 1e-5, err
        assert sm2.n_shapes == sm.n_shapes + (0 if "jawOpen" in sm.shape_names else 1) + 1
        keep = [k for k, n in enumerate(sm.shape_names) if n not in added[sm.name]]
        assert sm2.shape_names[:sm.n_shapes] == sm.shape_names
        assert np.abs(sm2.deltas[keep] - sm.deltas[keep]).max() == 0, np.abs(sm2.deltas[keep] - sm.deltas[keep]).max()
        print(f"USD {src.name}: max error {err:.2e} m")
        stage = Usd.Stage.Open(str(out))
        q = UsdSkel.BindingAPI(stage.GetPrimAtPath(sm.ref))
        assert "cheekPuffBig" in list(q.GetBlendShapesAttr().Get())
        if bpy is not None and src.suffix == ".usdc":
            with _blender_output():
                bpy.ops.wm.read_factory_settings(use_empty=True)
                bpy.ops.wm.usd_import(filepath=str(out))
                keys = {kb.name for o in bpy.data.objects if o.type == "MESH" and o.data.shape_keys
                        for kb in o.data.shape_keys.key_blocks}
                bpy.ops.wm.read_factory_settings(use_empty=True)
            assert "cheekPuffBig" in keys, sorted(keys)[:5]


def test_sheet_cli_without_landmarks_and_a_mesh_drawn_twice(tmp_path, chars, arkit_rig):
    """``inspect --sheet`` on RobotExpressive (no human face found): the sheet is written before the error;
    a glTF mesh drawn by two nodes turned differently: written, with a warning naming the other node."""
    import sys

    pytest.importorskip("mediapipe")
    sheet = tmp_path / "robot.png"
    r = subprocess.run([sys.executable, "-m", "faceretarget.cli._main", "character", "inspect",
                        str(chars / "robot" / "RobotExpressive.glb"), "--sheet", str(sheet)],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode != 0 and "no face found" in r.stderr and "contact sheet" in r.stderr + r.stdout
    from PIL import Image

    with Image.open(sheet) as im:
        assert im.size == (4 * (224 + 4) + 4, 224 + 22 + 4 + 4)         # neutral and the three moods

    from faceretarget.io import write_glb

    src = write_glb(tmp_path / "a.glb", arkit_rig, np.zeros((1, arkit_rig.n_shapes)), np.zeros(1))
    js, binchunk = _glb_parts(src)
    mesh_node = next(i for i, n in enumerate(js["nodes"]) if "mesh" in n)
    twin = {**js["nodes"][mesh_node], "name": "twin", "rotation": [0.0, 0.7071068, 0.0, 0.7071068]}
    twin.pop("weights", None)
    js["nodes"].append(twin)
    js["scenes"][0]["nodes"].append(len(js["nodes"]) - 1)
    body = json.dumps(js).encode()
    body += b" " * ((-len(body)) % 4)
    two = tmp_path / "two.glb"
    two.write_bytes(struct.pack("<III", 0x46546C67, 2, 28 + len(body) + len(binchunk))
                    + struct.pack("<II", len(body), 0x4E4F534A) + body
                    + struct.pack("<II", len(binchunk), 0x004E4942) + binchunk)
    ch = read_character(two)
    assert len(ch.meshes) == 2
    sm, added = _added(ch, ["x"], mesh=0)
    logs: list[str] = []
    out = write_character_shapes(tmp_path / "two_out.glb", ch, added, log=logs.append)
    assert any("warning" in m and "twin" in m for m in logs), logs
    ch2 = read_character(out)
    assert np.abs(ch2.meshes[0].deltas[-1] - added[sm.name]["x"]).max() < 1e-5
    with pytest.raises(InvalidDataError, match="same glTF mesh"):
        write_character_shapes(tmp_path / "x.glb", ch, {**added, ch.meshes[1].name: added[sm.name]})
