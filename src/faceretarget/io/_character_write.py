"""The animation written back into the user's own character file.

:func:`write_character_animation` writes a copy of the character's file with one animation added and
nothing else changed:

``.glb`` / ``.vrm`` / ``.gltf`` in, the same format out (:func:`_write_gltf`)
    The JSON is kept as it is (every node, mesh, material, texture, skin, extension and existing
    animation) and one animation is appended: a ``weights`` channel on every node that draws a face
    mesh (all its morph targets: the driven ones from the weights, the others at the mesh's default
    weights), and a ``rotation`` channel on the character's own head joint (and neck, with
    ``neck_share``) relative to its rest pose.  The new data is appended to the binary chunk (``.glb``,
    ``.vrm``) or written to ``<out>.anim.bin`` (``.gltf``, whose other files are referenced where they
    are); images and every other byte range are untouched.  The sound goes beside it (``<out>.wav``).
``.fbx`` in, ``.fbx`` out
    The binary file's node tree is copied with its animation replaced by the take: ``DeformPercent``
    curves on the driven blend shape channels and ``Lcl Rotation`` curves on the head bones, every other
    record written as the bytes it was read from (:mod:`faceretarget.io._fbx_write`, no Blender).  An
    ASCII FBX, or a character Blender read, goes the ``.blend`` way below.
``.fbx`` / ``.blend`` in (``.blend`` out, or what the direct FBX writer cannot do)
    Blender opens the character's own scene and adds an action on the shape keys and the head bone
    (:mod:`faceretarget.io._blender_scene`).
``.usd*`` in
    A new layer that references the asset and adds the animation (:mod:`faceretarget.io._usd_scene`).

Head rotation: the take's head pose is in the head frame (+Y up, +Z out of the face;
:mod:`faceretarget.headpose`); :func:`~faceretarget.character.joint_rotations` turns it into the joint's
local rotation keys:
``local(t) = local_rest * (G^-1 R_w(t)^(1-s) G)`` for the head and ``... R_w(t)^s ...`` for the neck,
with ``G`` the joint's rest world rotation, ``R_w`` the head rotation in the file's world frame and
``s`` the neck share, so the head ends exactly at ``R_w`` times its rest world rotation.
"""

from __future__ import annotations

import copy
import json
import os
import struct
from pathlib import Path

import numpy as np

from ..character import Channel, Character, joint_motions, joint_rotations, mesh_columns
from ..errors import InvalidDataError, MissingDependencyError, OutputError
from ..files import atomic_path, check_output_path
from ..formats import (
    CHARACTER_FORMATS,
    FBX,
    GLB,
    VRM,
    VRMA,
    WAV,
    character_format_of,
    extension,
    format_named,
)
from ..headpose import HeadPose

__all__ = ["write_character_animation", "writes_back", "WRITE_BACK", "write_vrma", "check_motion", "write_plain_glb"]

#: Output extensions that write back into the user's file, per character format (from
#: :data:`faceretarget.formats.CHARACTER_FORMATS`, VRM under both of its versions' names).
WRITE_BACK = {n: f.writes_back for f in CHARACTER_FORMATS.values() for n in (f.name, *f.aliases) if f.writes_back}
_GLB_MAGIC, _JSON, _BIN = 0x46546C67, 0x4E4F534A, 0x004E4942
_FLOAT = 5126


def writes_back(character, out: str | os.PathLike) -> bool:
    """Whether writing ``out`` puts the animation back into a copy of the character's own file.

    ``character`` is a :class:`~faceretarget.character.Character` or the path of a character file."""
    if isinstance(character, Character):
        fmt, path = format_named(character.format), character.path
    else:
        path = Path(character)
        fmt = character_format_of(path)
    return path is not None and fmt is not None and extension(out) in fmt.writes_back


def write_character_animation(out: str | os.PathLike, character: Character, chans: list[Channel],
                              weights: np.ndarray, times: np.ndarray, *, head: HeadPose | None = None,
                              audio: np.ndarray | None = None, audio_rate: float | None = None,
                              neck_share: float = 0.0, gaze: dict | None = None, name: str = "faceretarget",
                              log=None) -> Path:
    """Write the animation back into a copy of the character's own file (module docstring).

    Parameters
    ----------
    out : path-like
        The copy; its extension chooses the route (:data:`WRITE_BACK`).
    character : Character
    chans : list of Channel
        The character's channels (:func:`~faceretarget.character.channels`).
    weights : (T, C) float
        One column per channel.
    times : (T,) float
        Seconds, strictly increasing.
    head : HeadPose, optional
        Head rotation per frame in the head frame; goes on the head joint (a note when it has none).
    audio, audio_rate : optional
        Written beside the file as ``<out>.wav`` (glTF) or into the scene (Blender) / a sound prim (USD).
    neck_share : float
        Share of the head rotation the neck joint takes (0..1).
    gaze : dict, optional
        ``{"leftEye": Rotation, "rightEye": Rotation}`` (head frame, relative to the head): on the eye joints.
    """
    log = log or (lambda *_: None)
    out = check_output_path(out)
    W = np.asarray(weights, dtype=np.float64)
    t = np.asarray(times, dtype=np.float64).reshape(-1)
    if W.ndim != 2 or W.shape != (len(t), len(chans)):
        raise InvalidDataError(f"{out}: weights must be ({len(t)}, {len(chans)}) for {len(t)} times and "
                               f"{len(chans)} channels, got {W.shape}")
    if not np.isfinite(W).all():
        f = int(np.flatnonzero(~np.isfinite(W).all(axis=1))[0])
        raise InvalidDataError(f"{out}: frame {f} has a non-finite weight; nothing written")
    if len(t) == 0 or not np.isfinite(t).all() or (np.diff(t) <= 0).any():
        raise InvalidDataError(f"{out}: times must be finite and strictly increasing")
    src = Path(character.path) if character.path is not None else None
    if src is not None and src.exists() and out.exists() and os.path.samefile(src, out):
        raise OutputError(f"{out}: is the character's own file; write the animation to a copy (another name)")
    if not writes_back(character, out):
        raise OutputError(f"{out}: a {character.format} character is written back as "
                          f"{' or '.join(WRITE_BACK.get(character.format, ()))}")
    check_motion(out, len(t), head, gaze)
    fmt = character.format
    if fmt in ("gltf", "vrm0", "vrm1"):
        path = _write_gltf(out, character, chans, W, t, head, neck_share, gaze, name, log)
        if fmt.startswith("vrm") and chans and all(c.name in character.expressions for c in chans):
            vrma = out.with_suffix(VRMA)
            check_output_path(vrma)
            write_vrma(vrma, character, chans, W, t, head=head, neck_share=neck_share, name=name)
            log(f"wrote {vrma} (the same animation as VRM expressions and humanoid head rotation, for VRM runtimes "
                "such as three-vrm, which set the expression-bound morph targets and the bones themselves)")
    elif fmt == "fbx" and extension(out) == FBX:
        return _write_fbx(out, character, chans, W, t, head, audio, audio_rate, neck_share, gaze, name, log)
    elif fmt in ("fbx", "blend"):
        from ._blender_scene import write_blender_animation

        return write_blender_animation(out, character, chans, W, t, head=head, audio=audio, audio_rate=audio_rate,
                                       neck_share=neck_share, gaze=gaze, name=name, log=log)
    else:
        from ._usd_scene import write_usd_animation

        return write_usd_animation(out, character, chans, W, t, head=head, audio=audio, audio_rate=audio_rate,
                                   neck_share=neck_share, gaze=gaze, name=name, log=log)
    if audio is not None and audio_rate:
        from ._audio import checked_audio, write_wav

        wav = out.with_suffix(WAV)
        check_output_path(wav)
        with atomic_path(wav) as tmp:
            write_wav(tmp, *checked_audio(wav, audio, audio_rate))
        log(f"wrote {wav} (the sound, beside the animation)")
    return path


def _write_fbx(out: Path, character: Character, chans: list[Channel], W: np.ndarray, t: np.ndarray, head, audio,
               audio_rate, neck_share: float, gaze, name: str, log) -> Path:
    """An FBX character into ``.fbx``: straight into a copy of its binary file
    (:func:`~faceretarget.io._fbx_write.write_fbx_animation`); a file that writer cannot do (an ASCII FBX, a
    character Blender read) goes through Blender, with a line saying why, or is an error naming the file
    when Blender's ``bpy`` is not installed."""
    from ..optional import has_module, install_line
    from ._fbx_write import DirectWriteUnsupported, write_fbx_animation

    try:
        return write_fbx_animation(out, character, chans, W, t, head=head, neck_share=neck_share, gaze=gaze,
                                   name=name, log=log)
    except DirectWriteUnsupported as e:
        why = str(e).removeprefix(f"{out}: ")
    if not has_module("bpy"):
        raise MissingDependencyError(f"{out}: cannot write the animation into a copy of {Path(character.path).name} "
                                     f"directly ({why}), and the Blender route needs the 'bpy' package, which is not "
                                     f"installed: {install_line('bpy')}")
    log(f"{out.name}: written through Blender ({why})")
    from ._blender_scene import write_blender_animation

    return write_blender_animation(out, character, chans, W, t, head=head, audio=audio, audio_rate=audio_rate,
                                   neck_share=neck_share, gaze=gaze, name=name, log=log)


# ----------------------------------------------------------------------------------------- VRM animation
#: VRM 1.0 expression presets (the names a ``.vrma`` may use under ``preset``).
VRM_PRESETS = frozenset({"happy", "angry", "sad", "relaxed", "surprised", "aa", "ih", "ou", "ee", "oh", "blink",
                         "blinkLeft", "blinkRight", "lookUp", "lookDown", "lookLeft", "lookRight", "neutral"})


def write_vrma(path: Path, character: Character, chans: list[Channel], W: np.ndarray, t: np.ndarray, *,
               head: HeadPose | None = None, neck_share: float = 0.0, name: str = "faceretarget") -> Path:
    """A VRM Animation (``.vrma``, the ``VRMC_vrm_animation`` extension) of expression weights and head rotation.

    Each channel must be one of the character's VRM expressions: an expression node per channel whose
    ``translation.x`` is the weight; the humanoid ``hips``, ``neck`` and ``head`` nodes at rest with identity
    rotations (VRM's normalized humanoid), the head (and neck) keyed with the head pose's rotation in the head
    frame (+Z out of the face, as VRM 1.0 faces; VRM runtimes turn it for a VRM 0.x model), split by
    ``neck_share``.
    """
    from scipy.spatial.transform import Rotation

    from ..headpose import continuous_quaternions

    t32 = (t - t[0]).astype(np.float32)
    nodes = [{"name": "hips", "translation": [0.0, 1.0, 0.0], "children": [1]},
             {"name": "neck", "translation": [0.0, 0.45, 0.0], "children": [2]},
             {"name": "head", "translation": [0.0, 0.1, 0.0]}]
    chunks: list[bytes] = []
    views, accessors, samplers, channels_ = [], [], [], []

    def add(arr: np.ndarray, type_: str, minmax: bool = False) -> int:
        data = np.ascontiguousarray(arr, dtype=np.float32).tobytes()
        off = sum(len(c) for c in chunks)
        chunks.append(data)
        views.append({"buffer": 0, "byteOffset": off, "byteLength": len(data)})
        acc = {"bufferView": len(views) - 1, "componentType": _FLOAT, "count": len(arr), "type": type_}
        if minmax:
            acc["min"], acc["max"] = [float(np.min(arr))], [float(np.max(arr))]
        accessors.append(acc)
        return len(accessors) - 1

    t_acc = add(t32, "SCALAR", minmax=True)
    if head is not None:
        for node, share in ((2, 1.0 - neck_share), (1, neck_share)):
            if share <= 0:
                continue
            q = continuous_quaternions(Rotation.from_rotvec(head.rotation.as_rotvec() * share).as_quat())
            samplers.append({"input": t_acc, "output": add(q, "VEC4"), "interpolation": "LINEAR"})
            channels_.append({"sampler": len(samplers) - 1, "target": {"node": node, "path": "rotation"}})
    preset, custom = {}, {}
    for c, ch in enumerate(chans):
        nodes.append({"name": f"expression_{ch.name}"})
        (preset if ch.name in VRM_PRESETS else custom)[ch.name] = {"node": len(nodes) - 1}
        v = np.zeros((len(t), 3))
        v[:, 0] = W[:, c]
        samplers.append({"input": t_acc, "output": add(v, "VEC3"), "interpolation": "LINEAR"})
        channels_.append({"sampler": len(samplers) - 1, "target": {"node": len(nodes) - 1, "path": "translation"}})
    binchunk = b"".join(chunks)
    js = {"asset": {"version": "2.0", "generator": "faceretarget"},
          "extensionsUsed": ["VRMC_vrm_animation"],
          "extensions": {"VRMC_vrm_animation": {
              "specVersion": "1.0",
              "humanoid": {"humanBones": {"hips": {"node": 0}, "neck": {"node": 1}, "head": {"node": 2}}},
              "expressions": {"preset": preset, "custom": custom}}},
          "scene": 0, "scenes": [{"nodes": [0] + list(range(3, len(nodes)))}], "nodes": nodes,
          "animations": [{"name": name, "samplers": samplers, "channels": channels_}],
          "buffers": [{"byteLength": len(binchunk)}], "bufferViews": views, "accessors": accessors}
    _write_glb(path, js, binchunk)
    return path


# ----------------------------------------------------------------------------------------- glTF
def float_accessor(js: dict, new: bytearray, arr: np.ndarray, type_: str, minmax: bool = False) -> int:
    """Append ``arr`` as float32 to ``new`` (bytes that go after the file's own binary data: buffer -1 until
    :func:`_attach_glb_buffer` / :func:`_write_gltf_json` places them) with a buffer view and an accessor of
    ``js`` (``type_`` SCALAR, VEC3 or VEC4; ``min``/``max`` when asked); the accessor's index."""
    views, accessors = js.setdefault("bufferViews", []), js.setdefault("accessors", [])
    data = np.ascontiguousarray(arr, dtype=np.float32)
    new.extend(b"\0" * ((-len(new)) % 4))
    views.append({"buffer": -1, "byteOffset": len(new), "byteLength": data.nbytes})
    new.extend(data.tobytes())
    n = {"SCALAR": 1, "VEC3": 3, "VEC4": 4}[type_]
    acc = {"bufferView": len(views) - 1, "componentType": _FLOAT, "count": int(data.size // n), "type": type_}
    if minmax:
        flat = data.reshape(-1, n)
        acc["min"] = [float(x) for x in flat.min(axis=0)]
        acc["max"] = [float(x) for x in flat.max(axis=0)]
    accessors.append(acc)
    return len(accessors) - 1


def _write_gltf(out: Path, character: Character, chans: list[Channel], W: np.ndarray, t: np.ndarray,
                head: HeadPose | None, neck_share: float, gaze: dict | None, name: str, log) -> Path:
    from ._gltf_scene import GltfDocument

    doc = GltfDocument(character.path)
    js = copy.deepcopy(doc.json)
    to_glb = extension(out) in (GLB, VRM)
    new = bytearray()

    def add(arr: np.ndarray, type_: str, minmax: bool = False) -> int:
        return float_accessor(js, new, arr, type_, minmax)

    t32 = (t - t[0]).astype(np.float32)
    if len(t32) > 1 and not (np.diff(t32) > 0).all():
        raise InvalidDataError(f"{out}: frame times do not increase in float32 seconds")
    t_acc = add(t32, "SCALAR", minmax=True)
    samplers, channels_ = [], []
    cols = mesh_columns(chans, W)
    nodes = js.get("nodes", [])
    done = 0
    for mi, shapes in cols.items():
        sm = character.meshes[mi]
        node_i = int(sm.ref.split(":")[1])
        gmesh = js["meshes"][int(nodes[node_i]["mesh"])]
        K = max(len(p.get("targets", [])) for p in gmesh["primitives"])
        rest = np.asarray(gmesh.get("weights", [0.0] * K), dtype=np.float64)
        if len(rest) != K:
            rest = np.zeros(K)
        M = np.tile(rest, (len(t), 1))
        for k, col in shapes.items():
            M[:, sm.shape_refs[k]] = col
        samplers.append({"input": t_acc, "output": add(M.reshape(-1), "SCALAR"), "interpolation": "LINEAR"})
        channels_.append({"sampler": len(samplers) - 1, "target": {"node": node_i, "path": "weights"}})
        done += 1
    placed = []
    for role, j, rot in joint_motions(character, head, neck_share, gaze):
        q = joint_rotations(character, j, rot)
        ni = int(j.ref.split(":")[1])
        _trs(nodes[ni])
        samplers.append({"input": t_acc, "output": add(q, "VEC4"), "interpolation": "LINEAR"})
        channels_.append({"sampler": len(samplers) - 1, "target": {"node": ni, "path": "rotation"}})
        placed.append(f"{j.name} ({role})")
    _log_joints(log, character, out, head, gaze, placed)
    js.setdefault("animations", []).append({"name": name, "samplers": samplers, "channels": channels_})
    if to_glb:
        binchunk = _attach_glb_buffer(js, doc, bytes(new))
        _write_glb(out, js, binchunk)
    else:
        _write_gltf_json(out, js, doc, bytes(new))
    log(f"wrote {out} ({len(t)} frames on {done} face mesh node(s); everything else of {Path(character.path).name} "
        "kept)")
    return out


def check_motion(out: Path, T: int, head: HeadPose | None, gaze: dict | None) -> None:
    """The head pose and gaze rotations, one valid rotation per frame."""
    if head is not None and (head.n_frames != T or not head.valid.all()):
        raise InvalidDataError(f"{out}: the head pose needs one valid rotation per frame ({T})")
    for role, rot in (gaze or {}).items():
        if len(rot) != T:
            raise InvalidDataError(f"{out}: the {role} gaze has {len(rot)} rotations for {T} frames")


def _log_joints(log, character: Character, out: Path, head, gaze, placed: list[str]) -> None:
    if placed:
        log(f"head{' and gaze' if gaze else ''} rotation on the character's joint(s): {', '.join(placed)}")
    elif head is not None:
        log(f"{character.name}: no head joint; the head motion is left out of {out.name}")


def _trs(node: dict) -> None:
    """Give a node TRS instead of a matrix (animated nodes must have TRS)."""
    if "matrix" not in node:
        return
    from scipy.spatial.transform import Rotation

    M = np.asarray(node.pop("matrix"), dtype=np.float64).reshape(4, 4).T
    s = np.linalg.norm(M[:3, :3], axis=0)
    R = M[:3, :3] / np.where(s > 0, s, 1.0)
    if np.linalg.det(R) < 0:
        s[0], R[:, 0] = -s[0], -R[:, 0]
    node["translation"] = [float(x) for x in M[:3, 3]]
    node["rotation"] = [float(x) for x in Rotation.from_matrix(R).as_quat()]
    node["scale"] = [float(x) for x in s]


def _attach_glb_buffer(js: dict, doc, new: bytes) -> bytes:
    """Put the new views in the GLB binary chunk (buffer 0), after what it holds; return the chunk."""
    buffers = js.setdefault("buffers", [])
    if doc.is_glb and buffers and "uri" not in buffers[0]:
        base = bytes(doc.bin[: int(buffers[0].get("byteLength", len(doc.bin)))])
    else:                                                   # no binary chunk yet: a new buffer 0
        for v in js.get("bufferViews", []):
            if v.get("buffer", 0) != -1:
                v["buffer"] = int(v.get("buffer", 0)) + 1
            ext = v.get("extensions", {}).get("EXT_meshopt_compression")
            if ext is not None and ext.get("buffer", 0) != -1:
                ext["buffer"] = int(ext.get("buffer", 0)) + 1
        buffers.insert(0, {"byteLength": 0})
        base = b""
        for b in buffers[1:]:                               # external files stay where they are, by absolute uri
            if "uri" in b and not b["uri"].startswith("data:"):
                b["uri"] = _rebase(b["uri"], doc.folder, None)
    pad = (-len(base)) % 4
    _place_new_views(js, 0, len(base) + pad)
    chunk = base + b"\0" * pad + new
    buffers[0]["byteLength"] = len(chunk)
    return chunk


def _place_new_views(js: dict, buffer: int, offset: int) -> None:
    """Views (and meshopt-compressed views' data) on the new bytes (``buffer`` -1) point into ``buffer`` at
    ``offset`` onwards."""
    for v in js.get("bufferViews", []):
        for part in (v, v.get("extensions", {}).get("EXT_meshopt_compression")):
            if part is not None and part.get("buffer") == -1:
                part["buffer"] = buffer
                part["byteOffset"] = int(part.get("byteOffset", 0)) + offset


def _rebase(uri: str, src_folder: Path, dst_folder: Path | None) -> str:
    import urllib.parse

    p = (src_folder / urllib.parse.unquote(uri)).resolve()
    if dst_folder is None:
        return p.as_uri()
    return urllib.parse.quote(os.path.relpath(p, dst_folder.resolve()).replace(os.sep, "/"))


def _write_glb(out: Path, js: dict, binchunk: bytes) -> None:
    body = json.dumps(js, separators=(",", ":"), ensure_ascii=False).encode("utf-8")
    body += b" " * ((-len(body)) % 4)
    binpad = binchunk + b"\0" * ((-len(binchunk)) % 4)
    total = 12 + 8 + len(body) + (8 + len(binpad) if binpad else 0)
    with atomic_path(out) as tmp, open(tmp, "wb") as f:
        f.write(struct.pack("<III", _GLB_MAGIC, 2, total))
        f.write(struct.pack("<II", len(body), _JSON))
        f.write(body)
        if binpad:
            f.write(struct.pack("<II", len(binpad), _BIN))
            f.write(binpad)


def _write_gltf_json(out: Path, js: dict, doc, new: bytes, new_name: str | None = None) -> None:
    """A ``.gltf`` copy: external files referenced where they are (relative to the copy), the new data
    in ``<out>.anim.bin`` (or ``new_name`` beside it); a GLB input's binary chunk is written beside it too
    (``<out>.bin``)."""
    buffers = js.setdefault("buffers", [])
    extra: list[tuple[Path, bytes]] = []
    for i, b in enumerate(buffers):
        if "uri" in b and not b["uri"].startswith("data:"):
            b["uri"] = _rebase(b["uri"], doc.folder, out.parent)
        elif "uri" not in b and i == 0 and doc.is_glb:
            p = out.with_suffix(".bin")
            b["uri"] = p.name
            extra.append((p, bytes(doc.bin[: int(b.get("byteLength", len(doc.bin)))])))
    for img in js.get("images", []):
        if "uri" in img and not img["uri"].startswith("data:"):
            img["uri"] = _rebase(img["uri"], doc.folder, out.parent)
    anim = out.with_name(new_name or out.stem + ".anim.bin")
    buffers.append({"uri": anim.name, "byteLength": len(new)})
    _place_new_views(js, len(buffers) - 1, 0)
    for p, data in extra + [(anim, new)]:
        check_output_path(p)
        with atomic_path(p) as tmp:
            Path(tmp).write_bytes(data)
    with atomic_path(out) as tmp:
        Path(tmp).write_text(json.dumps(js, indent=1, ensure_ascii=False), encoding="utf-8")


# ----------------------------------------------------------------------------------------- plain copy
def write_plain_glb(src: str | os.PathLike, out: str | os.PathLike) -> Path:
    """A ``.glb`` copy of a glTF character with its ``EXT_meshopt_compression`` data decoded, for readers
    that do not decode it (Blender 4.5's glTF importer refuses such a file).

    Every buffer view is written plain into one binary chunk (compressed views decoded, meshopt
    fallback buffers dropped, external buffers and data URIs read in); the JSON is otherwise kept as it
    is, so nodes, meshes, morph targets, skins, materials and images are the file's own
    (``KHR_mesh_quantization`` and ``EXT_texture_webp`` stay: Blender reads both).

    Parameters
    ----------
    src : path-like
        ``.glb``, ``.gltf`` or ``.vrm``.
    out : path-like
        The ``.glb`` to write (not ``src``).

    Returns
    -------
    Path
        ``out``.
    """
    from ._gltf_scene import GltfDocument

    out = check_output_path(out)
    doc = GltfDocument(src)
    if out.exists() and os.path.samefile(doc.path, out):
        raise OutputError(f"{out}: is the input file; write the plain copy to another name")
    js = copy.deepcopy(doc.json)
    chunk = bytearray()
    accessors = js.get("accessors", [])
    vertex = {int(accessors[a]["bufferView"]) for m in js.get("meshes", []) for p in m.get("primitives", [])
              for group in [p.get("attributes", {}), *p.get("targets", [])] for a in group.values()
              if "bufferView" in accessors[a]}
    for i, v in enumerate(js.get("bufferViews", [])):
        data = doc.view(i)
        ext = v.pop("extensions", {})
        meshopt = ext.pop("EXT_meshopt_compression", None)
        if ext:
            v["extensions"] = ext
        if (meshopt is not None and meshopt.get("mode", "ATTRIBUTES") == "ATTRIBUTES" and "byteStride" not in v
                and i in vertex):                           # only vertex data has a stride (not sparse data, IBMs)
            v["byteStride"] = int(meshopt["byteStride"])
        chunk.extend(b"\0" * ((-len(chunk)) % 4))
        v.update(buffer=0, byteOffset=len(chunk), byteLength=len(data))
        chunk.extend(data)
    js["buffers"] = [{"byteLength": len(chunk)}] if chunk else []
    for key in ("extensionsUsed", "extensionsRequired"):
        if key in js:
            js[key] = [e for e in js[key] if e != "EXT_meshopt_compression"]
            if not js[key]:
                del js[key]
    _write_glb(out, js, bytes(chunk))
    return out
