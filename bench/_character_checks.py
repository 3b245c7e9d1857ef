"""Checks of a character file with the animation written back, in the programs that read it (P7, P8).

Shared by ``bench/characters.py`` and the tests: every function takes the input file, the written file
and what was written (per-node weights, times), runs the consuming program, and returns a dict of
numbers (``None`` for what cannot run here, with ``why``).

* :func:`gltf_checks`: the Khronos glTF validator on input and output (errors the output adds), the
  counts of nodes, meshes, materials, images, textures, skins and animations kept, images byte-identical,
  and three.js (``tests/browser/run_three.mjs`` in headless Chromium with the meshopt decoder, three-vrm for
  ``.vrm``): morph influences against the written weights and the head joint's world rotation against
  the one the written keys give, at every key time.
* :func:`blender_checks`: Blender 4.5 opens the output (``.blend``, or ``.fbx`` through its importer):
  the character's objects all there, every keyed shape-key value inside its slider, frame rate and
  range, the head bone animated.
* :func:`usd_checks`: usd-core composes the layer over the asset; UsdSkel's evaluated blend-shape weights
  equal the written ones; the head joint's world rotation moves.
"""

from __future__ import annotations

import json
import os
import shutil
import struct
import subprocess
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
TOOLS = REPO / ".tools" / "node_modules"
VALIDATOR = Path(os.environ.get("GLTF_VALIDATOR_DIR", TOOLS / "gltf-validator"))
RUN_THREE = REPO / "tests" / "browser" / "run_three.mjs"
VALIDATE = REPO / "tests" / "tools" / "validate_gltf.mjs"


def hide_shapes(ch):
    """The character with every mesh's shapes (and its VRM expressions) removed, in place: what a character
    with only a neutral face looks like to the library."""
    for m in ch.meshes:
        m.shape_names, m.shape_refs = [], []
        m.deltas = np.zeros((0, m.mesh.n_vertices, 3), np.float32)
        m._motion = m._vm2 = None
    ch.__dict__.pop("_face_cache", None)
    ch.expressions = {}
    return ch


def _glb_json(path: Path) -> tuple[dict, bytes]:
    data = path.read_bytes()
    n = struct.unpack_from("<I", data, 12)[0]
    js = json.loads(data[20:20 + n])
    off = 20 + n
    binchunk = b""
    if off + 8 <= len(data):
        m = struct.unpack_from("<I", data, off)[0]
        binchunk = data[off + 8: off + 8 + m]
    return js, binchunk


def validator_errors(path: Path) -> tuple[int | None, str]:
    node = shutil.which("node")
    if node is None or not (VALIDATOR / "package.json").is_file():
        return None, "node or gltf-validator missing (make tools)"
    r = subprocess.run([node, str(VALIDATE), str(path), str(VALIDATOR)], capture_output=True, text=True, timeout=300)
    if r.returncode not in (0, 1):
        return None, r.stderr.strip()[:200]
    rep = json.loads(r.stdout)
    return int(rep["issues"]["numErrors"]), ""


def kept(inp: Path, out: Path) -> dict:
    """Counts of every top-level glTF array in and out, and whether every image's bytes are unchanged."""
    a, abin = _glb_json(inp)
    b, bbin = _glb_json(out)
    counts = {k: (len(a.get(k, [])), len(b.get(k, []))) for k in
              ("nodes", "meshes", "materials", "images", "textures", "skins", "animations", "samplers")}
    ok = all(x == y for k, (x, y) in counts.items() if k != "animations") and \
        counts["animations"][1] == counts["animations"][0] + 1

    def img_bytes(js, binchunk):
        out = []
        for im in js.get("images", []):
            if "bufferView" in im:
                v = js["bufferViews"][im["bufferView"]]
                o = v.get("byteOffset", 0)
                out.append(binchunk[o:o + v["byteLength"]])
            else:
                out.append(im.get("uri", "").encode())
        return out

    same = img_bytes(a, abin) == img_bytes(b, bbin)
    return {"ok": bool(ok and same), "counts": counts, "images_identical": bool(same)}


def _world_rotation(js: dict, node: int, local_rot: dict[int, np.ndarray]) -> np.ndarray:
    """World rotation (3 x 3, scale removed) of ``node`` with some nodes' rotations replaced."""
    from scipy.spatial.transform import Rotation

    parent = {c: i for i, n in enumerate(js["nodes"]) for c in n.get("children", [])}
    M = np.eye(3)
    i = node
    while i is not None:
        n = js["nodes"][i]
        if "matrix" in n:
            L = np.asarray(n["matrix"]).reshape(4, 4).T[:3, :3]
        else:
            q = local_rot.get(i, n.get("rotation", [0, 0, 0, 1]))
            L = Rotation.from_quat(q).as_matrix() * np.asarray(n.get("scale", [1, 1, 1]))
        M = L @ M
        i = parent.get(i)
    U, _, Vt = np.linalg.svd(M)
    return U @ Vt


def three_checks(out: Path, clip: str, weights: dict[str, np.ndarray], times: np.ndarray,
                 head_node: int | None, head_keys: np.ndarray | None, vrm: bool = False, max_times: int = 40,
                 vrma: Path | None = None) -> dict:
    """Play ``out`` in three.js; compare morph influences to ``weights`` ({node name: (T, K)}) and the head
    node's world rotation to what the keys give, at up to ``max_times`` key times.  ``vrm``: through three-vrm
    (which sets the targets its expressions bind itself: those are not compared); ``vrma``: playing that VRM
    Animation through three-vrm instead of the file's clip (everything compared)."""
    node = shutil.which("node")
    chromium = os.environ.get("CHROMIUM") or shutil.which("chromium") or "/usr/bin/chromium"
    if node is None or not (TOOLS / "three" / "package.json").is_file() or not Path(chromium).is_file():
        return {"ok": None, "why": "node, three.js or Chromium missing (make tools browser)"}
    if (vrm or vrma is not None) and not (TOOLS / "@pixiv" / "three-vrm-animation" / "package.json").is_file():
        return {"ok": None, "why": "three-vrm or three-vrm-animation missing (make tools)"}
    t32 = (times - times[0]).astype(np.float32).astype(np.float64)
    pick = np.unique(np.linspace(0, len(t32) - 1, min(max_times, len(t32))).round().astype(int))
    js, _ = _glb_json(out)
    head_name = None if head_node is None else js["nodes"][head_node].get("name")
    args = [node, str(RUN_THREE), str(out), "--clip", clip, "--morphs", "all", "--head", "none", "--timeout", "120",
            "--times", ",".join(f"{t:.9g}" for t in t32[pick])]
    if head_name:
        args += ["--world", head_name]
    if vrma is not None:
        args += ["--vrma", str(vrma)]
    elif vrm:
        args += ["--vrm"]
    env = dict(os.environ, CHROMIUM=str(chromium))
    r = subprocess.run(args, capture_output=True, text=True, timeout=240, env=env)
    if r.returncode != 0:
        return {"ok": False, "why": r.stderr.strip()[-300:]}
    rep = json.loads(r.stdout)
    worst = 0.0
    missing = []
    bound = _expression_bound(js) if vrm and vrma is None else {}
    for name, W in weights.items():
        got = rep["morphs"].get(name)
        if got is None:
            missing.append(name)
            continue
        cols = [k for k in range(W.shape[1]) if k not in bound.get(name, ())]
        worst = max(worst, float(np.abs(np.asarray(got)[:, cols] - W[pick][:, cols].astype(np.float32)).max()))
    ang = None
    if head_name and head_keys is not None:
        from scipy.spatial.transform import Rotation

        got = np.asarray(rep["world"][head_name])
        want = np.stack([Rotation.from_matrix(_world_rotation(js, head_node, {head_node: head_keys[k]})).as_quat()
                         for k in pick])
        ang = float((Rotation.from_quat(got) * Rotation.from_quat(want).inv()).magnitude().max())
    ok = not missing and worst <= 1e-6 and (ang is None or ang <= 1e-6)
    out = {"ok": bool(ok), "morph_max_err": worst, "head_max_err_rad": ang, "missing": missing,
           "times": int(len(pick)), "three": rep.get("three")}
    if vrm and vrma is None:        # three-vrm's expression manager sets these itself on every update
        out["expression_bound_targets"] = int(sum(len(v) for v in _expression_bound(js).values()))
    return out


def _expression_bound(js: dict) -> dict[str, set[int]]:
    """``{node name: {morph target index}}`` of the targets a VRM's expressions bind."""
    out: dict[str, set[int]] = {}
    ext = js.get("extensions", {})
    nodes = js.get("nodes", [])
    for e in ext.get("VRMC_vrm", {}).get("expressions", {}).get("preset", {}).values():
        for b in e.get("morphTargetBinds", []):
            out.setdefault(nodes[b["node"]].get("name"), set()).add(int(b["index"]))
    for g in ext.get("VRM", {}).get("blendShapeMaster", {}).get("blendShapeGroups", []):
        for b in g.get("binds", []):
            for n in nodes:
                if n.get("mesh") == b.get("mesh"):
                    out.setdefault(n.get("name"), set()).add(int(b["index"]))
    return out


def gltf_checks(inp: Path, out: Path, written: dict) -> dict:
    """Everything for a glTF / VRM written back (module docstring); ``written`` is what
    :func:`written_gltf` gives."""
    ein, why = validator_errors(inp)
    eout, why2 = validator_errors(out)
    res = {"validator_errors": None if eout is None else {"input": ein, "output": eout, "added": eout - (ein or 0)},
           "kept": kept(inp, out)}
    res["three"] = three_checks(out, written["clip"], written["weights"], written["times"], written["head_node"],
                                written["head_keys"])
    if out.suffix.lower() == ".vrm":     # a VRM as VRM apps play it: three-vrm, the .vrma beside it
        vrma = out.with_suffix(".vrma")
        res["three_vrm"] = three_checks(out, written["clip"], written["weights"], written["times"],
                                        written["head_node"], written["head_keys"], vrm=True,
                                        vrma=vrma if vrma.is_file() else None)
    if eout is None:
        res["validator_why"] = why or why2
    return res


def written_gltf(out: Path, clip: str = "faceretarget") -> dict:
    """What the animation ``clip`` of ``out`` holds: per mesh node name its (T, K) weights, the times, the
    head node and its rotation keys (read from the file with the project's own accessor reader)."""
    from faceretarget.io import GltfDocument

    doc = GltfDocument(out)
    js = doc.json
    anim = next(a for a in js["animations"] if a.get("name") == clip)
    weights, head_node, head_keys, times = {}, None, None, None
    for ch in anim["channels"]:
        s = anim["samplers"][ch["sampler"]]
        t = doc.accessor(s["input"]).reshape(-1)
        v = doc.accessor(s["output"])
        times = t if times is None else times
        n = ch["target"]["node"]
        if ch["target"]["path"] == "weights":
            weights[js["nodes"][n].get("name")] = v.reshape(len(t), -1)
        elif ch["target"]["path"] == "rotation" and head_node is None:
            head_node, head_keys = n, v.reshape(len(t), 4)
    return {"clip": clip, "weights": weights, "times": times, "head_node": head_node, "head_keys": head_keys}


def blender_checks(inp: Path, out: Path, fps: float, frames: int) -> dict:
    """Blender opens ``out``: the objects of ``inp`` all there, keyed shape-key values inside their sliders,
    the scene's rate and range, the head bone animated."""
    try:
        import bpy  # noqa: F401
    except ImportError:
        return {"ok": None, "why": "bpy missing (make blender)"}
    from faceretarget.io._blender import _blender_output

    with _blender_output():
        import bpy

        def objects(path: Path) -> set[str]:
            if path.suffix.lower() == ".blend":
                bpy.ops.wm.open_mainfile(filepath=str(path), load_ui=False)
            else:
                bpy.ops.wm.read_factory_settings(use_empty=True)
                bpy.ops.import_scene.fbx(filepath=str(path))
            return {(o.name, o.type) for o in bpy.data.objects}

        before = objects(inp)
        after = objects(out)
        outside = keyed = 0
        head_curves = 0
        for obj in bpy.data.objects:
            key = obj.data.shape_keys if obj.type == "MESH" else None
            if key is not None and key.animation_data and key.animation_data.action:
                act = key.animation_data.action
                for fc in _fcurves(act, key.animation_data):
                    if not fc.data_path.startswith("key_blocks"):
                        continue
                    kb = key.path_resolve(fc.data_path.rsplit(".", 1)[0])
                    vals = np.array([k.co[1] for k in fc.keyframe_points])
                    keyed += len(vals)
                    outside += int(((vals < kb.slider_min - 1e-6) | (vals > kb.slider_max + 1e-6)).sum())
            if obj.type == "ARMATURE" and obj.animation_data and obj.animation_data.action:
                head_curves += sum(1 for fc in _fcurves(obj.animation_data.action, obj.animation_data)
                                   if "rotation_quaternion" in fc.data_path)
        scene = bpy.context.scene
        rate = scene.render.fps / scene.render.fps_base
        rng = (scene.frame_start, scene.frame_end)
        bpy.ops.wm.read_factory_settings(use_empty=True)
    intact = before <= after
    ok = intact and keyed > 0 and outside == 0 and head_curves >= 4 and abs(rate - fps) < 0.01 * fps
    return {"ok": bool(ok), "objects_intact": bool(intact), "keyed_values": keyed, "outside_slider": outside,
            "head_rotation_curves": head_curves, "fps": rate, "frame_range": list(rng), "frames": frames}


def _fcurves(action, animdata):
    """An action's F-curves for the slot ``animdata`` plays (Blender 4.4+ layered actions), or all of them."""
    slot = getattr(animdata, "action_slot", None)
    layers = getattr(action, "layers", None)
    if slot is not None and layers:
        for layer in layers:
            for strip in layer.strips:
                bag = strip.channelbag(slot)
                if bag is not None:
                    yield from bag.fcurves
        return
    yield from getattr(action, "fcurves", [])


def usd_checks(out: Path, weights: dict[str, np.ndarray], times: np.ndarray) -> dict:
    """usd-core composes ``out``; UsdSkel's blend-shape weights at each time code equal ``weights``
    ({blend shape name: (T,)}); the animated joints' world rotation at the first and last code."""
    try:
        from pxr import Usd, UsdGeom, UsdSkel
    except ImportError:
        return {"ok": None, "why": "usd-core missing"}
    stage = Usd.Stage.Open(str(out))
    fps = stage.GetTimeCodesPerSecond()
    codes = (times - times[0]) * fps
    cache = UsdSkel.Cache()
    worst, found, moved = 0.0, 0, None
    for root in [p for p in stage.Traverse() if p.IsA(UsdSkel.Root)]:
        cache.Populate(UsdSkel.Root(root), Usd.PrimDefaultPredicate)
        for binding in cache.ComputeSkelBindings(UsdSkel.Root(root), Usd.PrimDefaultPredicate):
            q = cache.GetSkelQuery(binding.GetSkeleton())
            aq = q.GetAnimQuery()
            if not aq:
                continue
            order = [str(n) for n in aq.GetBlendShapeOrder()]
            for f in np.unique(np.linspace(0, len(codes) - 1, min(30, len(codes))).round().astype(int)):
                w = np.asarray(aq.ComputeBlendShapeWeights(Usd.TimeCode(float(codes[f]))))
                for k, n in enumerate(order):
                    if n in weights:
                        worst = max(worst, abs(float(w[k]) - float(weights[n][f])))
                        found += 1
            xc0 = UsdGeom.XformCache(Usd.TimeCode(0.0))
            xc1 = UsdGeom.XformCache(Usd.TimeCode(float(codes[-1])))
            a = np.array(q.ComputeJointWorldTransforms(xc0))
            b = np.array(q.ComputeJointWorldTransforms(xc1))
            moved = float(np.abs(a - b).max()) if moved is None else max(moved, float(np.abs(a - b).max()))
    ok = found > 0 and worst <= 1e-6
    return {"ok": bool(ok), "weights_compared": found, "weight_max_err": worst, "joint_world_change": moved}
