"""VRM 0.x and 1.0 test characters made from a glTF avatar (no VRM file is in ../shared/data).

:func:`make_vrm` adds to a copy of a ``.glb`` what a VRM exporter adds: the ``VRM`` (0.x) or ``VRMC_vrm``
(1.0) extension with the meta, the humanoid map of the skeleton's bones (found by name) and expressions
binding some of the face mesh's morph targets (viseme presets), and for 0.x the model turned to face -Z
as VRM 0.x files do.  Everything else of the file is byte-for-byte the same.
"""

from __future__ import annotations

import json
import struct
from pathlib import Path

import numpy as np

HUMANOID = {"hips": "Hips", "spine": "Spine", "chest": "Spine1", "neck": "Neck", "head": "Head",
            "leftEye": "LeftEye", "rightEye": "RightEye", "leftUpperLeg": "LeftUpLeg", "leftLowerLeg": "LeftLeg",
            "leftFoot": "LeftFoot", "rightUpperLeg": "RightUpLeg", "rightLowerLeg": "RightLeg",
            "rightFoot": "RightFoot", "leftUpperArm": "LeftArm", "leftLowerArm": "LeftForeArm",
            "leftHand": "LeftHand", "rightUpperArm": "RightArm", "rightLowerArm": "RightForeArm",
            "rightHand": "RightHand", "leftShoulder": "LeftShoulder", "rightShoulder": "RightShoulder"}


def _read(path: Path) -> tuple[dict, bytes]:
    data = path.read_bytes()
    n = struct.unpack_from("<I", data, 12)[0]
    return json.loads(data[20:20 + n]), data[20 + n + 8:]


def _write(path: Path, js: dict, binchunk: bytes) -> Path:
    body = json.dumps(js).encode()
    body += b" " * ((-len(body)) % 4)
    with open(path, "wb") as f:
        f.write(struct.pack("<III", 0x46546C67, 2, 12 + 8 + len(body) + 8 + len(binchunk)))
        f.write(struct.pack("<II", len(body), 0x4E4F534A) + body)
        f.write(struct.pack("<II", len(binchunk), 0x004E4942) + binchunk)
    return path


def make_vrm(glb: Path, out: Path, version: str, expressions: dict[str, str]) -> Path:
    """A VRM ``version`` ("0" or "1") of ``glb`` whose expressions bind the named morph targets of the
    mesh that has them (``{expression: target name}``)."""
    js, binchunk = _read(glb)
    names = {n.get("name"): i for i, n in enumerate(js["nodes"])}
    bones = {b: names[n] for b, n in HUMANOID.items() if n in names}
    mesh_i = next(i for i, m in enumerate(js["meshes"]) if m.get("extras", {}).get("targetNames"))
    targets = js["meshes"][mesh_i]["extras"]["targetNames"]
    node_i = next(i for i, n in enumerate(js["nodes"]) if n.get("mesh") == mesh_i)
    meta = {"name": glb.stem, "version": "1", "authors": ["faceretarget tests"], "licenseUrl":
            "https://vrm.dev/licenses/1.0/"}
    if version == "1":
        js.setdefault("extensionsUsed", []).append("VRMC_vrm")
        js.setdefault("extensions", {})["VRMC_vrm"] = {
            "specVersion": "1.0", "meta": meta,
            "humanoid": {"humanBones": {b: {"node": i} for b, i in bones.items()}},
            "expressions": {"preset": {e: {"morphTargetBinds": [{"node": node_i, "index": targets.index(t),
                                                                   "weight": 1.0}]}
                                       for e, t in expressions.items()}}}
    else:
        js.setdefault("extensionsUsed", []).append("VRM")
        js.setdefault("extensions", {})["VRM"] = {
            "specVersion": "0.0", "exporterVersion": "faceretarget-tests",
            "meta": {"title": glb.stem, "version": "1", "author": "faceretarget tests"},
            "humanoid": {"humanBones": [{"bone": b, "node": i, "useDefaultValues": True} for b, i in bones.items()]},
            "blendShapeMaster": {"blendShapeGroups": [
                {"name": e, "presetName": e, "binds": [{"mesh": mesh_i, "index": targets.index(t), "weight": 100}]}
                for e, t in expressions.items()]},
            "firstPerson": {}, "materialProperties": []}
        hips = js["nodes"][bones["hips"]]                 # VRM 0.x faces -Z: the skeleton turned half a turn
        q = np.array(hips.get("rotation", [0, 0, 0, 1]), dtype=np.float64)
        from scipy.spatial.transform import Rotation

        hips["rotation"] = (Rotation.from_euler("y", 180, degrees=True) * Rotation.from_quat(q)).as_quat().tolist()
        t = np.array(hips.get("translation", [0, 0, 0]), dtype=np.float64)
        hips["translation"] = [-t[0], t[1], -t[2]]
    return _write(out, js, binchunk)
