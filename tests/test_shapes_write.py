"""New shapes written into a copy of the character's own file (issue 25): glTF / VRM morph targets, Blender
shape keys (.fbx, .blend), an OBJ folder; read back by our readers they are the deltas given (float32, or
within half a step of the file's own quantization), the file's own shapes, images and everything else
unchanged, the Khronos validator adds nothing; and the contact sheet of ``character inspect --sheet``.

Issue 34: the glTF copy of a VALID avatar with its 51 generated ARKit shapes is at most twice the input's size
(sparse / quantized / meshopt-compressed targets, the input's bytes kept), and three.js (headless Chromium) and
Blender's glTF importer read the same displacements as we do; a Draco-compressed input gets its targets too."""

from __future__ import annotations

import collections
import json
import os
import shutil
import struct
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pytest

from faceretarget.character import character_frame
from faceretarget.characters import drive_rig
from faceretarget.errors import InvalidDataError, MissingShapeError, OutputError
from faceretarget.io import read_character, write_character_shapes
from faceretarget.mesh import Mesh
from faceretarget.pipelines import shape_sheet

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _browser import CHROMIUM, PUPPETEER_DIR, THREE_DIR, browser_missing  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
VALIDATOR = Path(os.environ.get("GLTF_VALIDATOR_DIR", REPO / ".tools" / "node_modules" / "gltf-validator"))
#: Half the step of a VALID avatar's own SHORT-normalized position grid, in metres (the head's is 27.4 um on
#: AIAN_F_1_Busi, 28.8 um on Black_M_2_Busi): how far a new shape stored at the file's precision may be off.
VALID_HALF_STEP = 1.5e-5
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


def _three(path: Path, *args: str) -> dict | None:
    """``tests/browser/run_three.mjs`` on ``path`` (three.js's GLTFLoader in headless Chromium): its JSON report;
    None when node, three.js or Chromium are missing (a failure under FACERETARGET_REQUIRE_BROWSER=1)."""
    reason = browser_missing("the three.js check", three=True)
    if reason:
        if os.environ.get("FACERETARGET_REQUIRE_BROWSER", "") not in ("", "0"):
            pytest.fail(reason)
        return None
    env = dict(os.environ, CHROMIUM=str(CHROMIUM), THREE_DIR=str(THREE_DIR), PUPPETEER_CORE_DIR=str(PUPPETEER_DIR))
    r = subprocess.run(["node", str(REPO / "tests" / "browser" / "run_three.mjs"), str(path), "--timeout", "150",
                        *args], capture_output=True, text=True, timeout=200, env=env)
    assert r.returncode == 0, r.stderr[-500:]
    assert "browser warn" not in r.stderr and "browser error" not in r.stderr, r.stderr[-500:]
    return json.loads(r.stdout)


def _three_morphs(path: Path, names: list[str]) -> tuple[dict | None, float, float]:
    """three.js's decoded base positions and the named targets of every primitive against our decoding of the
    same accessors (local units): (report, largest base difference, largest target difference)."""
    from faceretarget.io import GltfDocument
    from faceretarget.io._gltf_scene import _primitive, _target_names  # noqa: PLC2701 (our decoding, test only)

    rep = _three(path, "--morph-data", ",".join(names))
    if rep is None:
        return None, 0.0, 0.0
    doc = GltfDocument(path)
    base_err = target_err = 0.0
    for m in rep["meshes"]:
        gm = doc.json["meshes"][m["mesh"]]
        prim = gm["primitives"][m["primitive"]]
        tn = _target_names(doc, gm, max(len(p.get("targets", [])) for p in gm["primitives"]))
        base = _primitive(doc, m["mesh"], m["primitive"], prim, {})[0]
        assert m["relative"] and m["count"] == len(base)
        base_err = max(base_err, float(np.abs(np.reshape(m["position"], (-1, 3)) - base).max()))
        for n, arr in m["targets"].items():
            ours = doc.accessor(prim["targets"][tn.index(n)]["POSITION"])
            target_err = max(target_err, float(np.abs(np.reshape(arr, (-1, 3)) - ours).max()))
    return rep, base_err, target_err


def _blender_shape_keys(path: Path, character, added: dict) -> dict[str, tuple[float, float]]:
    """Blender's glTF importer on ``path`` (on its plain copy when meshopt-compressed: Blender 4.5 does not
    decode EXT_meshopt_compression): per mesh, the largest difference (m) of its shape keys from what our
    reader reads from ``path`` and from the deltas given, world space."""
    bpy = pytest.importorskip("bpy")
    from faceretarget.io import read_blender_scene_character, write_plain_glb
    from faceretarget.io._blender import BLENDER_AXES, _blender_output  # noqa: PLC2701 (test only)

    src = path
    if "EXT_meshopt_compression" in json.dumps(_glb_parts(path)[0].get("extensionsUsed", [])):
        src = write_plain_glb(path, path.with_name(path.stem + ".plain.glb"))
    with _blender_output():
        bpy.ops.wm.read_factory_settings(use_empty=True)
        assert "FINISHED" in bpy.ops.import_scene.gltf(filepath=str(src))
        blender = read_blender_scene_character()
        bpy.ops.wm.read_factory_settings(use_empty=True)
    A = np.asarray(BLENDER_AXES)
    ours = read_character(path)
    out = {}
    for mname, shapes in added.items():
        sm = next(m for m in ours.meshes if m.name == mname)
        b = next(m for m in blender.meshes if m.name == mname)
        assert b.mesh.n_vertices == sm.mesh.n_vertices
        assert np.abs(b.mesh.vertices - sm.mesh.vertices @ A.T).max() < 1e-5        # Blender's order is ours
        e_read = e_given = 0.0
        for n, d in shapes.items():
            got = b.deltas[b.shape_names.index(n)]
            e_read = max(e_read, float(np.abs(got - sm.deltas[sm.shape_names.index(n)] @ A.T).max()))
            e_given = max(e_given, float(np.abs(got - np.asarray(d, np.float64) @ A.T).max()))
        out[mname] = (e_read, e_given)
    return out


def _check_gltf(src: Path, out: Path, ch, sm, added, tol: float = 1e-5):
    """Read back: new shapes equal (``tol`` m), old shapes and every mesh unchanged, the validator adds
    nothing, JSON and binary kept apart from the added data (so images are byte-identical)."""
    ch2 = read_character(out)
    sm2 = next(m for m in ch2.meshes if m.name == sm.name)
    errs = []
    for n, d in added[sm.name].items():
        errs.append(float(np.abs(sm2.deltas[sm2.shape_names.index(n)] - d).max()))
    assert max(errs) < tol, errs
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
    ch2, err = _check_gltf(src, out, ch, sm, added, VALID_HALF_STEP)
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
    assert w2m.shape_names == ["jawOpen"] and np.abs(w2m.deltas[0] - d).max() < VALID_HALF_STEP
    va, vb = _validator(src), _validator(tmp_path / "wig.glb")
    assert va is None or not (vb - va)
    # replace=True: the file's own shape replaced, indices unchanged
    new = _field(sm.mesh.vertices, 7)
    out2 = write_character_shapes(tmp_path / "busi2.glb", ch, {sm.name: {own: new}}, replace=True)
    ch3 = read_character(out2)
    sm3 = ch3.meshes[ch.meshes.index(sm)]
    assert sm3.shape_names == sm.shape_names
    assert np.abs(sm3.deltas[0] - new).max() < VALID_HALF_STEP and np.array_equal(sm3.deltas[1:], sm.deltas[1:])


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
    rep = _three(out, "--times", "0", "--head", "none")
    if rep is not None:
        assert rep["names"][-2:] == ["jawOpen", "eyeBlinkLeft"]


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
    ch2, err = _check_gltf(src, out, ch, sm, added, VALID_HALF_STEP)
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


# ------------------------------------------------------------------------------------------ issue 34: size
def _neutral_glb(path: Path, mesh, *, draco: bool = False) -> Path:
    """A ``.glb`` of one mesh and nothing else (POSITION, NORMAL, triangles; float32), its attributes and
    triangles Draco-compressed (KHR_draco_mesh_compression, required) when ``draco``."""
    P = np.asarray(mesh.vertices, np.float32)
    T = np.asarray(mesh.triangles(), np.uint32)
    N = np.asarray(mesh.vertex_normals(), np.float32)
    chunks, views, accessors = [], [], []

    def view(data: bytes, target: int | None = None) -> int:
        views.append({"buffer": 0, "byteOffset": sum(len(c) for c in chunks), "byteLength": len(data)})
        if target:
            views[-1]["target"] = target
        chunks.append(data + b"\0" * ((-len(data)) % 4))
        return len(views) - 1

    def acc(a: np.ndarray, type_: str, ctype: int, data: bool = True, **kw) -> int:
        accessors.append({"componentType": ctype, "count": len(a), "type": type_, **kw})
        if data:
            accessors[-1]["bufferView"] = view(np.ascontiguousarray(a).tobytes(), 34963 if type_ == "SCALAR" else 34962)
        return len(accessors) - 1

    prim: dict = {}
    if draco:
        import DracoPy

        enc = DracoPy.encode(P, T, quantization_bits=14, normals=N.astype(np.float64), normal_quantization_bits=10)
        dm = DracoPy.decode(enc)                      # Draco may reorder the points: the accessors describe its order
        P = np.asarray(dm.points, np.float32)
        ids = {a["attribute_type"]: a["unique_id"] for a in dm.attributes}      # 0 POSITION, 1 NORMAL
        prim["attributes"] = {"POSITION": acc(P, "VEC3", 5126, False, min=P.min(0).tolist(), max=P.max(0).tolist()),
                              "NORMAL": acc(P, "VEC3", 5126, False)}
        prim["indices"] = acc(np.asarray(dm.faces).reshape(-1), "SCALAR", 5125, False)
        prim["extensions"] = {"KHR_draco_mesh_compression": {"bufferView": view(bytes(enc)),
                                                              "attributes": {"POSITION": ids[0], "NORMAL": ids[1]}}}
    else:
        prim["attributes"] = {"POSITION": acc(P, "VEC3", 5126, min=P.min(0).tolist(), max=P.max(0).tolist()),
                              "NORMAL": acc(N, "VEC3", 5126)}
        prim["indices"] = acc(T.reshape(-1), "SCALAR", 5125)
    binchunk = b"".join(chunks)
    js = {"asset": {"version": "2.0"}, "scene": 0, "scenes": [{"nodes": [0]}], "nodes": [{"name": "face", "mesh": 0}],
          "meshes": [{"name": "face", "primitives": [prim]}], "accessors": accessors, "bufferViews": views,
          "buffers": [{"byteLength": len(binchunk)}]}
    if draco:
        js["extensionsUsed"] = js["extensionsRequired"] = ["KHR_draco_mesh_compression"]
    body = json.dumps(js).encode()
    body += b" " * ((-len(body)) % 4)
    path.write_bytes(struct.pack("<III", 0x46546C67, 2, 28 + len(body) + len(binchunk))
                     + struct.pack("<II", len(body), 0x4E4F534A) + body
                     + struct.pack("<II", len(binchunk), 0x004E4942) + binchunk)
    return path


@pytest.fixture(scope="module")
def aian_written(chars, tmp_path_factory):
    """AIAN_F_1_Busi with its 51 ARKit shapes generated (51 on the head, teeth, glands and wig, 4 on each eye),
    written into a .glb copy: (input, output, character, added)."""
    from faceretarget.characters import generate_shapes

    src = chars / "valid" / "AIAN_F_1_Busi.glb"
    gen = generate_shapes(src)
    out = tmp_path_factory.mktemp("aian") / "aian_arkit.glb"
    logs: list[str] = []
    write_character_shapes(out, gen.character, gen.added, log=logs.append)
    print(logs[-1])
    return src, out, gen.character, gen.added


def test_generated_shapes_copy_is_at_most_twice_the_input(aian_written):
    """The copy with 51 generated shapes on 7 meshes: <= 2x the input (was 38.5 MB, 17.6x: dense float32 targets),
    its bytes first and unchanged, the new targets sparse or dense, quantized and meshopt-compressed as the file's
    own are; read back within half a step of the file's own position grid; the validator adds nothing, on the
    copy and on its decoded plain copy (which it can check: it does not decode meshopt)."""
    from faceretarget.io import write_plain_glb

    src, out, ch, added = aian_written
    a, b = src.stat().st_size, out.stat().st_size
    print(f"{src.name}: {a / 1e6:.2f} MB -> {b / 1e6:.2f} MB ({b / a:.2f}x)")
    assert b <= 2 * a, (a, b)
    js0, bin0 = _glb_parts(src)
    js1, bin1 = _glb_parts(out)
    assert bin1[:len(bin0.rstrip(b"\0"))] == bin0.rstrip(b"\0")
    assert js1["bufferViews"][:len(js0["bufferViews"])] == js0["bufferViews"]
    assert js1["accessors"][:len(js0["accessors"])] == js0["accessors"]
    new_acc = js1["accessors"][len(js0["accessors"]):]
    sparse = [x for x in new_acc if "sparse" in x]
    assert sparse and all("bufferView" not in x for x in sparse)                     # zeros under the moved vertices
    assert {x["componentType"] for x in new_acc if "bufferView" in x or "sparse" in x} >= {5122, 5120}  # quantized
    assert all("EXT_meshopt_compression" in v.get("extensions", {}) for v in js1["bufferViews"][len(js0["bufferViews"]):])
    head = js1["meshes"][0]["primitives"][0]["targets"]
    assert len(head) == 65 + 51 and all(set(t) == {"POSITION", "NORMAL"} for t in head)
    ch2 = read_character(out)
    err = 0.0
    for mname, shapes in added.items():
        m0 = next(m for m in ch.meshes if m.name == mname)
        m2 = next(m for m in ch2.meshes if m.name == mname)
        assert m2.shape_names[:m0.n_shapes] == m0.shape_names and np.array_equal(m2.deltas[:m0.n_shapes], m0.deltas)
        for n, d in shapes.items():
            err = max(err, float(np.abs(m2.deltas[m2.shape_names.index(n)] - d).max()))
    print(f"read back: largest error {err:.2e} m")
    assert err < VALID_HALF_STEP
    va, vb = _validator(src), _validator(out)
    if va is not None:
        assert not (vb - va), vb - va
        plain = write_plain_glb(out, out.with_name("plain.glb"))
        assert not (_validator(plain) - va)


def test_generated_shapes_play_in_three_and_blender(aian_written):
    """three.js decodes the copy's new targets (sparse, quantized, meshopt) exactly as we do; Blender's glTF
    importer (on the plain copy) makes shape keys equal to our reading of the file (float32) and to the given
    deltas (within half a step of the file's grid)."""
    src, out, ch, added = aian_written
    rep, base_err, target_err = _three_morphs(out, ["jawOpen", "eyeBlinkLeft", "mouthSmileLeft", "eyeLookInLeft"])
    if rep is not None:
        assert {m["object"] for m in rep["meshes"]} >= {"H_DDS_HighRes", "h_TeethDown", "h_L_eye", "h_wig"}
        print(f"three.js r{rep['three']}: base {base_err:.1e}, targets {target_err:.1e} from our decoding")
        assert base_err == 0 and target_err == 0
    pytest.importorskip("bpy")
    res = _blender_shape_keys(out, ch, added)
    print("Blender (largest |key - ours|, |key - given|, m):", {k: f"{a:.1e} {b:.1e}" for k, (a, b) in res.items()})
    assert max(a for a, _ in res.values()) < 1e-6 and max(b for _, b in res.values()) < VALID_HALF_STEP


def test_draco_input_gets_its_morph_targets(tmp_path, arkit_rig):
    """A Draco-compressed face (KHR_draco_mesh_compression, required): the compressed primitive is kept as it is and
    the new targets are plain accessors in its decoded vertex order (the extension covers attributes and indices,
    not targets); read back exactly, the validator finds nothing, three.js (DRACOLoader) and Blender (its Draco
    decoder) decode the same vertex order and displacement."""
    src = _neutral_glb(tmp_path / "draco.glb", arkit_rig.neutral, draco=True)
    ch = read_character(src)
    sm, added = _added(ch, ARKIT, mesh=0)
    out = write_character_shapes(tmp_path / "draco_shapes.glb", ch, added)
    print(f"Draco face: {src.stat().st_size} -> {out.stat().st_size} bytes (12 shapes, every vertex moves)")
    js0, bin0 = _glb_parts(src)
    js1, bin1 = _glb_parts(out)
    prim0, prim1 = js0["meshes"][0]["primitives"][0], js1["meshes"][0]["primitives"][0]
    assert prim1["extensions"] == prim0["extensions"] and prim1["attributes"] == prim0["attributes"]
    assert bin1[:len(bin0)] == bin0 and len(prim1["targets"]) == len(ARKIT)
    ch2 = read_character(out)
    assert np.array_equal(ch2.meshes[0].mesh.vertices, sm.mesh.vertices)
    err = max(float(np.abs(ch2.meshes[0].deltas[k] - d).max()) for k, d in enumerate(added[sm.name].values()))
    assert err < 1e-8, err                            # float32 kept; a delta dropped only if p + d == p in float32
    v = _validator(out)
    assert v is None or not [k for k in v if k[0] == 0], v
    rep, base_err, target_err = _three_morphs(out, ARKIT[:3])
    if rep is not None:
        assert base_err == 0 and target_err == 0, (base_err, target_err)
    from faceretarget.optional import has_module

    if has_module("bpy"):
        res = _blender_shape_keys(out, ch, added)
        assert res["face"][0] < 1e-6 and res["face"][1] < 1e-6, res


def test_gltf_copy_of_a_compressed_avatar(tmp_path, chars):
    """A .gltf copy of a meshopt avatar: its binary chunk beside it (NAME.bin), the new compressed views in
    NAME.shapes.bin; read back, the validator (reading the files beside it) adds nothing, three.js loads it."""
    src = chars / "valid" / "Black_M_2_Busi.glb"
    ch = read_character(src)
    sm, added = _added(ch, ARKIT[:4])
    (tmp_path / "copy").mkdir()
    out = write_character_shapes(tmp_path / "copy" / "b.gltf", ch, added)
    assert sorted(p.name for p in (tmp_path / "copy").iterdir()) == ["b.bin", "b.gltf", "b.shapes.bin"]
    assert (tmp_path / "copy" / "b.bin").read_bytes() == _glb_parts(src)[1][:len((tmp_path / "copy" / "b.bin").read_bytes())]
    ch2 = read_character(out)
    sm2 = next(m for m in ch2.meshes if m.name == sm.name)
    assert max(float(np.abs(sm2.deltas[sm2.shape_names.index(n)] - d).max())
               for n, d in added[sm.name].items()) < VALID_HALF_STEP
    va, vb = _validator(src), _validator(out)
    if va is not None:
        assert not [k for k in vb - va if k[0] == 0], vb - va
    rep, base_err, target_err = _three_morphs(out, ARKIT[:2])
    if rep is not None:
        assert base_err == 0 and target_err == 0


def test_quantized_values_and_normal_deltas():
    """SHORT-normalized values round to the step and refuse what is out of range; a normal delta beyond [-1, 1]
    (a fold turning the normal far) is rescaled into it and still gives the turned normal at weight 1, once
    rounded to BYTE; where no rescaling can (a normal turned over), the array is float32."""
    from faceretarget.io._gltf_targets import Encoding, normal_delta  # noqa: PLC2701 (test only)

    e = Encoding(5122, True)
    assert np.array_equal(e.stored(np.array([[0.5, -0.5, 1.0 / 65534 * 0.9]])), [[16384, -16384, 0]])
    assert e.stored(np.array([[1.01, 0.0, 0.0]])) is None
    b = Encoding(5120, True)
    r = np.random.default_rng(0)

    def unit(v):
        return v / np.linalg.norm(v, axis=1, keepdims=True)

    n0 = unit(r.normal(size=(500, 3)))
    small = unit(n0 + 0.05 * r.normal(size=(500, 3)))
    d, enc = normal_delta(n0, small, b)
    assert enc == b and np.array_equal(d, small - n0)
    from scipy.spatial.transform import Rotation

    m0 = unit(np.array([[0.5, 0.6, 0.62]]))
    axis = unit(np.cross(m0, [[0.0, 0.0, 1.0]]))
    far = np.concatenate([Rotation.from_rotvec(axis[0] * np.radians(a)).apply(m0) for a in (90, 120, 150, 179)])
    m0 = np.repeat(m0, 4, axis=0)
    d, enc = normal_delta(m0, far, b)
    assert np.abs(far - m0).max() > 1.3 and enc == b and np.abs(d).max() <= 1
    got = unit(m0 + enc.stored(d) * enc.step)
    assert np.degrees(np.arccos(np.clip(np.sum(got * far, axis=1), -1, 1))).max() < 1.0
    over = np.array([[0.0, 0.0, 1.0]])                                     # turned over from -Z: nothing helps
    d, enc = normal_delta(np.array([[0.0, 0.0, -1.0]]), over, b)
    assert enc == Encoding() and np.array_equal(d, [[0.0, 0.0, 2.0]])


def _with_normals_glb(path: Path, V: np.ndarray, T: np.ndarray, D: np.ndarray, T_normals: np.ndarray) -> Path:
    """A ``.glb`` of one mesh of triangles ``T`` with NORMAL and one morph target (``D``, with its NORMAL
    deltas), the normals those of ``T_normals`` as wound (pygltflib)."""
    import pygltflib

    def vn(P):
        return np.asarray(Mesh.from_triangles(P, T_normals).vertex_normals(), np.float32)

    N0 = vn(V)
    arrays = [(V.astype(np.float32), True), (N0, False), (T.astype(np.uint32).reshape(-1), False),
              (D.astype(np.float32), True), (vn(V + D) - N0, False)]
    blob, views, accessors = b"", [], []
    for a, mm in arrays:
        blob += b"\0" * ((-len(blob)) % 4)
        views.append(pygltflib.BufferView(buffer=0, byteOffset=len(blob), byteLength=a.nbytes))
        blob += a.tobytes()
        scalar = a.ndim == 1
        accessors.append(pygltflib.Accessor(bufferView=len(views) - 1, count=len(a), type="SCALAR" if scalar else "VEC3",
                                            componentType=pygltflib.UNSIGNED_INT if scalar else pygltflib.FLOAT,
                                            min=a.min(0).tolist() if mm else None, max=a.max(0).tolist() if mm else None))
    prim = pygltflib.Primitive(attributes=pygltflib.Attributes(POSITION=0, NORMAL=1), indices=2,
                               targets=[{"POSITION": 3, "NORMAL": 4}])
    g = pygltflib.GLTF2(scene=0, scenes=[pygltflib.Scene(nodes=[0])], nodes=[pygltflib.Node(mesh=0, name="face")],
                        meshes=[pygltflib.Mesh(primitives=[prim], name="face", extras={"targetNames": ["jawOpen"]})],
                        accessors=accessors, bufferViews=views, buffers=[pygltflib.Buffer(byteLength=len(blob))])
    g.set_binary_blob(blob)
    g.save_binary(str(path))
    return path


def test_new_targets_normals_face_the_files_normals_on_a_mesh_wound_inward(tmp_path, data_dir):
    """A mesh wound inward whose normals face outward (a mirror whose winding was not turned): the new targets'
    normal deltas were worked out from the winding, so a shape turned the file's normals the wrong way (up to
    2.5 off the outward-wound file's).  They now face the file's own normals: the same deltas either way."""
    from faceretarget.io import GltfDocument, read_rig

    rig = read_rig(data_dir / "arkit-face")
    k = rig.mm_per_unit / 1000.0
    V, T = rig.neutral.vertices * k, rig.neutral.triangles()
    names = list(rig.names)
    smile = rig.deltas[names.index("mouthSmileLeft")] * k
    got = []
    for tag, tri in (("outward", T), ("inward", T[:, ::-1])):
        src = _with_normals_glb(tmp_path / f"{tag}.glb", V, tri, rig.deltas[names.index("jawOpen")] * k, T)
        ch = read_character(src)
        out = write_character_shapes(tmp_path / f"{tag}_out.glb", ch, {ch.meshes[0].name: {"smile": smile}})
        doc = GltfDocument(out)
        p = doc.json["meshes"][0]["primitives"][0]
        got.append((doc.accessor(p["attributes"]["NORMAL"]), doc.accessor(p["targets"][-1]["NORMAL"])))
    n0, d_out = got[0]
    want = np.asarray(Mesh.from_triangles(V + smile, T).vertex_normals()) - n0
    moving = np.linalg.norm(smile, axis=1) > 1e-4
    assert np.abs(d_out - want)[moving].max() < 1e-3
    assert np.allclose(got[1][0], n0)                                        # the file's normals, outward both
    assert np.abs(got[1][1] - d_out).max() < 1e-4, np.abs(got[1][1] - d_out).max()
