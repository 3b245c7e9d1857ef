"""Characters in Blender's own files, read and written back by Blender itself (``bpy``, the ``blender`` extra).

:func:`read_blender_character` opens a ``.blend`` (or imports an ``.fbx`` with Blender's FBX importer,
the route when ufbx is not installed) and builds a :class:`~faceretarget.character.Character` in
Blender's world frame (metres, +Z up):

* every mesh object with its polygons, first UV layer (flipped to glTF's top-left convention) and base
  colour (the Principled BSDF's, or its image texture), posed as the scene shows it (its armature's
  current pose, by linear blend skinning of its vertex groups);
* its shape keys (relative to the basis) as world-space deltas under their exact names;
* every armature bone as a :class:`~faceretarget.character.Joint` (``ref`` ``"armature/bone"``) with
  its current world matrix, so the head is found by name (``Bip01 Head``, ``mixamorig:Head``, ...).

:func:`write_blender_animation` opens the character's own file again and adds one action: every driven
shape key's ``value`` keyed at every frame (``LINEAR``, sliders widened where a weight leaves them), the
head (and neck) pose bone's ``rotation_quaternion`` relative to its current pose, the scene's frame rate
and range set to the take's, and the sound as a strip (``.blend``).  It saves a ``.blend`` or exports an
``.fbx``; every other object, material, bone and action of the file is kept.
"""

from __future__ import annotations

import contextlib
import math
import os
import shutil
import tempfile
from pathlib import Path

import numpy as np

from ..character import Channel, Character, EncodedImage, Joint, Material, SceneMesh, joint_motions, shape_key
from ..errors import InputFileError, OutputError
from ..files import atomic_path
from ..headpose import HeadPose, continuous_quaternions
from ..mesh import Mesh
from ..optional import optional_import
from ._audio import checked_audio
from ._blender import _blender_output, _fcurve, _sound_strip, blender_timebase

__all__ = ["read_blender_character", "write_blender_animation"]

_PURPOSE = "reading and writing Blender characters (.blend; .fbx without ufbx)"


def _bpy():
    from ..optional import install_line

    return optional_import("bpy", _PURPOSE, install_line("bpy"))


def _open(bpy, path: Path) -> None:
    """Open ``path`` in a fresh Blender session: a .blend as the main file, an .fbx imported into an empty scene."""
    ext = path.suffix.lower()
    try:
        if ext == ".blend":
            bpy.ops.wm.open_mainfile(filepath=str(path), load_ui=False)
        else:
            bpy.ops.wm.read_factory_settings(use_empty=True)
            res = bpy.ops.import_scene.fbx(filepath=str(path))
            if "FINISHED" not in res:
                raise InputFileError(f"{path}: Blender's FBX importer did not read the file ({', '.join(res)})")
    except RuntimeError as e:
        raise InputFileError(f"{path}: Blender cannot open the file ({str(e).strip()[:200]})") from e


def read_blender_character(path: str | os.PathLike) -> Character:
    """Read a ``.blend`` or ``.fbx`` character through Blender (module docstring)."""
    path = Path(path)
    if not path.is_file():
        raise InputFileError(f"{path}: file not found" if not path.exists() else f"{path}: is not a file")
    with _blender_output():
        bpy = _bpy()
        _open(bpy, path)
        try:
            return _character(bpy, path)
        finally:
            with contextlib.suppress(Exception):
                bpy.ops.wm.read_factory_settings(use_empty=True)


def _m(M) -> np.ndarray:
    return np.array([list(r) for r in M], dtype=np.float64)


def _character(bpy, path: Path) -> Character:
    notes: list[str] = []
    joints: list[Joint] = []
    bone_index: dict[tuple[str, str], int] = {}
    scale = float(bpy.context.scene.unit_settings.scale_length or 1.0)
    for arm in [o for o in bpy.data.objects if o.type == "ARMATURE"]:
        Aw = _m(arm.matrix_world)
        for b in arm.data.bones:
            pb = arm.pose.bones[b.name]
            world = Aw @ _m(pb.matrix)
            parent = bone_index.get((arm.name, b.parent.name), -1) if b.parent else -1
            local = np.linalg.inv(Aw @ _m(arm.pose.bones[b.parent.name].matrix)) @ world if b.parent else world
            bone_index[(arm.name, b.name)] = len(joints)
            world[:3, 3] *= scale
            joints.append(Joint(b.name, parent, world, f"{arm.name}/{b.name}", local))
    meshes: list[SceneMesh] = []
    images: dict[str, EncodedImage | None] = {}
    for obj in bpy.data.objects:
        if obj.type != "MESH" or obj.hide_render:
            continue
        sm = _mesh(bpy, obj, path, bone_index, notes, images, scale)
        if sm is not None:
            meshes.append(sm)
    fmt = "blend" if path.suffix.lower() == ".blend" else "fbx"
    return Character(path, fmt, "Blender 4.5 (bpy)", meshes, joints, up=np.array([0.0, 0.0, 1.0]), front=None,
                     notes=notes, source_unit="m")


def _skin_matrices(obj, me, bone_index) -> tuple[np.ndarray | None, np.ndarray | None, np.ndarray | None]:
    """Per-vertex armature-space linear blend skinning matrices of the object's current pose, and the
    top four (joint, weight) influences; None without an armature modifier."""
    mod = next((m for m in obj.modifiers if m.type == "ARMATURE" and m.object is not None and m.show_render), None)
    if mod is None or not mod.use_vertex_groups:
        return None, None, None
    arm = mod.object
    V = len(me.vertices)
    groups = {g.index: g.name for g in obj.vertex_groups}
    bones = {}
    for gi, gname in groups.items():
        if gname in arm.pose.bones:
            pb = arm.pose.bones[gname]
            bones[gi] = (_m(pb.matrix) @ np.linalg.inv(_m(pb.bone.matrix_local)), bone_index.get((arm.name, gname), -1))
    M = np.zeros((V, 4, 4))
    tot = np.zeros(V)
    jn = np.full((V, 4), -1, np.int64)
    jw = np.zeros((V, 4))
    for v in me.vertices:
        for g in v.groups:
            b = bones.get(g.group)
            if b is None or g.weight <= 0:
                continue
            M[v.index] += g.weight * b[0]
            tot[v.index] += g.weight
            slot = int(np.argmin(jw[v.index]))
            if g.weight > jw[v.index, slot]:
                jn[v.index, slot], jw[v.index, slot] = b[1], g.weight
    ok = tot > 0
    M[ok] /= tot[ok, None, None]
    M[~ok] = np.eye(4)
    A = _m(arm.matrix_world)
    Oinv_A = np.linalg.inv(A) @ _m(obj.matrix_world)
    return np.einsum("ij,vjk,kl->vil", A, M, Oinv_A), jn, jw


def _mesh(bpy, obj, path: Path, bone_index, notes, images, scale) -> SceneMesh | None:
    me = obj.data
    V = len(me.vertices)
    if V == 0:
        return None
    co = np.empty(V * 3, np.float32)
    me.vertices.foreach_get("co", co)
    local = co.reshape(V, 3).astype(np.float64)
    counts = np.empty(len(me.polygons), np.int32)
    me.polygons.foreach_get("loop_total", counts)
    loops = np.empty(len(me.loops), np.int32)
    me.loops.foreach_get("vertex_index", loops)
    ok = counts >= 3
    starts = np.empty(len(me.polygons), np.int32)
    me.polygons.foreach_get("loop_start", starts)
    corner = np.concatenate([np.arange(s, s + c) for s, c in zip(starts[ok], counts[ok], strict=True)]) \
        if ok.any() else np.zeros(0, np.int64)
    uvs = fuv = None
    if me.uv_layers.active is not None and len(me.loops):
        uv = np.empty(len(me.loops) * 2, np.float32)
        me.uv_layers.active.data.foreach_get("uv", uv)
        uv = uv.reshape(-1, 2).astype(np.float64)
        uvs = np.stack([uv[:, 0], 1.0 - uv[:, 1]], axis=1)
        fuv = corner
    M, jn, jw = _skin_matrices(obj, me, bone_index)
    if M is None:
        G = _m(obj.matrix_world)
        L = np.broadcast_to(G[:3, :3], (V, 3, 3))
        T = np.broadcast_to(G[:3, 3], (V, 3))
    else:
        L, T = M[:, :3, :3], M[:, :3, 3]
    world = ((L * local[:, None, :]).sum(axis=2) + T) * scale
    names, deltas = [], []
    keys = me.shape_keys
    if keys is not None and keys.use_relative:
        kbs = keys.key_blocks
        basis = kbs[0] if len(kbs) else None
        for kb in list(kbs)[1:]:
            rel = kb.relative_key if kb.relative_key is not None else basis
            a = np.empty(V * 3, np.float32)
            b = np.empty(V * 3, np.float32)
            kb.data.foreach_get("co", a)
            rel.data.foreach_get("co", b)
            d = (a - b).reshape(V, 3).astype(np.float64)
            names.append(kb.name)
            deltas.append((L * d[:, None, :]).sum(axis=2) * scale)
    elif keys is not None:
        notes.append(f"{obj.name}: absolute shape keys (a keyed blend, not expressions) are left out")
    mats = [_material(bpy, s.material, images, notes) for s in obj.material_slots] or [Material("default")]
    tri_mat = None
    if len(mats) > 1:
        mi = np.empty(len(me.polygons), np.int32)
        me.polygons.foreach_get("material_index", mi)
        tri_mat = np.repeat(mi[ok], counts[ok] - 2).astype(np.int64)
    mesh = Mesh(world, counts[ok], loops[corner], uvs, fuv, name=obj.name)
    D = np.stack(deltas).astype(np.float32) if deltas else np.zeros((0, V, 3), np.float32)
    return SceneMesh(obj.name, obj.name, mesh, names, D, mats, tri_mat, skin_joints=jn, skin_weights=jw)


def _material(bpy, mat, images, notes) -> Material:
    if mat is None:
        return Material("default")
    col = np.array(list(mat.diffuse_color), dtype=np.float64)
    img = None
    if mat.use_nodes and mat.node_tree is not None:
        bsdf = next((n for n in mat.node_tree.nodes if n.type == "BSDF_PRINCIPLED"), None)
        if bsdf is not None:
            inp = bsdf.inputs.get("Base Color")
            if inp is not None:
                if not inp.is_linked:
                    col = np.array(list(inp.default_value), dtype=np.float64)
                else:
                    node = inp.links[0].from_node
                    if node.type == "TEX_IMAGE" and node.image is not None:
                        img = _image(bpy, node.image, images, notes)
                        col = np.ones(4)
    return Material(mat.name, col, img)


def _image(bpy, image, images, notes) -> EncodedImage | None:
    key = image.name
    if key in images:
        return images[key]
    out = None
    try:
        if image.packed_file is not None:
            out = EncodedImage(bytes(image.packed_file.data), None, image.name, notes)
        else:
            p = Path(bpy.path.abspath(image.filepath))
            if p.is_file():
                out = EncodedImage(None, str(p), image.name, notes)
            else:
                notes.append(f"missing texture: '{image.filepath}' of image '{image.name}' not found; rendered in its "
                             "base colour")
    except (AttributeError, RuntimeError, OSError):
        out = None
    images[key] = out
    return out


# ------------------------------------------------------------------------------------------ writing
def write_blender_animation(out: Path, character: Character, chans: list[Channel], W: np.ndarray, t: np.ndarray,
                            *, head: HeadPose | None = None, audio=None, audio_rate=None, neck_share: float = 0.0,
                            gaze: dict | None = None, name: str = "faceretarget", log=None) -> Path:
    """Open the character's own file in Blender, add the action, save ``out`` (.blend or .fbx)."""
    log = log or (lambda *_: None)
    with _blender_output():
        bpy = _bpy()
    kind = out.suffix.lower()
    sound = checked_audio(out, audio, audio_rate) if kind == ".blend" else None
    scratch = Path(tempfile.mkdtemp(prefix=f".{out.name}.", suffix=".part", dir=out.parent))
    msgs: list[str] = []
    try:
        with _blender_output():
            _open(bpy, Path(character.path))
            _animate_scene(bpy, out, character, chans, W, t, head, neck_share, gaze, name, sound, scratch,
                           start=1.0 if kind == ".blend" else 0.0, msgs=msgs)
            tmp_out = scratch / out.name
            if kind == ".blend":
                res = bpy.ops.wm.save_as_mainfile(filepath=str(tmp_out), check_existing=False, compress=True,
                                                  relative_remap=True, copy=True)
            else:
                res = bpy.ops.export_scene.fbx(
                    filepath=str(tmp_out), check_existing=False, use_selection=False, add_leaf_bones=False,
                    bake_anim=True, bake_anim_use_all_bones=True, bake_anim_use_nla_strips=False,
                    bake_anim_use_all_actions=False, bake_anim_force_startend_keying=True, bake_anim_step=1.0,
                    bake_anim_simplify_factor=0.0, path_mode="AUTO")
            if "FINISHED" not in res or not tmp_out.is_file():
                raise OutputError(f"{out}: Blender did not write the file ({', '.join(sorted(res))})")
        with atomic_path(out) as tmp:
            os.replace(tmp_out, tmp)
    except RuntimeError as e:
        raise OutputError(f"{out}: Blender could not write the file ({str(e).strip()[:200]})") from e
    finally:
        shutil.rmtree(scratch, ignore_errors=True)
        with contextlib.suppress(Exception):
            bpy.ops.wm.read_factory_settings(use_empty=True)
    for m in msgs:
        log(m)
    log(f"wrote {out} ({len(t)} frames; the character's own scene from {Path(character.path).name}, with action "
        f"'{name}')")
    return out


def _keep_existing(idblock) -> None:
    """An action the file already plays on ``idblock`` stays in the file (a fake user) when ours replaces it."""
    ad = idblock.animation_data
    if ad is not None and ad.action is not None:
        ad.action.use_fake_user = True


def _key_block(obj, want: str):
    kbs = obj.data.shape_keys.key_blocks if obj.data.shape_keys else None
    if kbs is None:
        return None
    if want in kbs:
        return kbs[want]
    k = shape_key(want)
    return next((kb for kb in kbs if shape_key(kb.name) == k), None)


def _animate_scene(bpy, out: Path, character: Character, chans: list[Channel], W: np.ndarray, t: np.ndarray,
                   head: HeadPose | None, neck_share: float, gaze, name: str, sound, scratch: Path, start: float,
                   msgs: list) -> None:
    scene = bpy.context.scene
    fps, base, frames = blender_timebase(t, start)
    scene.render.fps, scene.render.fps_base = fps, base
    scene.frame_start = int(start)
    scene.frame_end = max(int(start), int(math.ceil(frames[-1] - 1e-6)))
    linear = bpy.types.Keyframe.bl_rna.properties["interpolation"].enum_items["LINEAR"].value
    action = bpy.data.actions.new(name)
    strip = action.layers.new("Layer").strips.new(type="KEYFRAME")
    co = np.empty((len(t), 2), np.float32)
    co[:, 0] = frames
    from ..character import mesh_columns

    per_obj: dict[str, list[tuple[str, np.ndarray]]] = {}
    for mi, cols in mesh_columns(chans, W).items():
        m = character.meshes[mi]
        per_obj.setdefault(m.ref, []).extend((m.shape_names[k], col) for k, col in cols.items())
    missing = []
    keyed = 0
    for obj_name, shapes in per_obj.items():
        obj = bpy.data.objects.get(obj_name)
        if obj is None or obj.type != "MESH" or obj.data.shape_keys is None:
            missing.append(obj_name)
            continue
        key = obj.data.shape_keys
        _keep_existing(key)
        slot = action.slots.new(id_type="KEY", name=obj.name)
        key.animation_data_create()
        key.animation_data.action = action
        key.animation_data.action_slot = slot
        bag = strip.channelbag(slot, ensure=True)
        for sname, col in shapes:
            kb = _key_block(obj, sname)
            if kb is None:
                missing.append(f"{obj_name}/{sname}")
                continue
            kb.slider_min = float(min(kb.slider_min, np.floor(col.min() * 100) / 100))
            kb.slider_max = float(max(kb.slider_max, np.ceil(col.max() * 100) / 100))
            co[:, 1] = col
            _fcurve(bag, f'key_blocks["{bpy.utils.escape_identifier(kb.name)}"].value', 0, co, linear)
            keyed += 1
    if missing:
        raise OutputError(f"{out}: Blender's copy of the character lacks {', '.join(missing[:4])}"
                          f"{' ...' if len(missing) > 4 else ''} (a name the file reader and Blender read differently)")
    motions = joint_motions(character, head, neck_share, gaze)
    if motions:
        _joint_action(bpy, out, character, motions, action, strip, frames, linear, msgs)
    if sound is not None:
        _sound_strip(bpy, scene, out, sound, scratch)
    msgs.append(f"keyed {keyed} shape key(s) on {len(per_obj)} object(s)")


def _joint_action(bpy, out, character, motions: list, action, strip, frames, linear, msgs) -> None:
    from scipy.spatial.transform import Rotation

    from ..character import character_frame
    from ._blender import BLENDER_AXES

    F = character_frame(character)
    # the character's world frame -> Blender's world: identity for a Blender read, Y-up -> Z-up for ufbx
    A = np.eye(3) if character.route.startswith("Blender") else BLENDER_AXES
    placed = []
    for role, j, rot in motions:
        bone = j.ref.split("/")[-1] if "/" in j.ref else j.name
        arm = next((o for o in bpy.data.objects if o.type == "ARMATURE" and bone in o.pose.bones), None)
        if arm is None:
            continue
        pb = arm.pose.bones[bone]
        G = _m(arm.matrix_world)[:3, :3] @ _m(pb.matrix)[:3, :3]
        U, _, Vt = np.linalg.svd(G)
        G = U @ Vt
        Rb = A @ F.T @ rot.as_matrix() @ F @ A.T
        P0 = Rotation.from_quat(np.r_[pb.rotation_quaternion[1:], pb.rotation_quaternion[0]]).as_matrix() \
            if pb.rotation_mode == "QUATERNION" else np.array(pb.matrix_basis.to_3x3())
        wxyz = continuous_quaternions(Rotation.from_matrix(P0 @ (G.T @ Rb @ G)).as_quat())[:, [3, 0, 1, 2]]
        pb.rotation_mode = "QUATERNION"
        if arm.animation_data is None or arm.animation_data.action != action:
            _keep_existing(arm)
            slot = action.slots.new(id_type="OBJECT", name=arm.name)
            arm.animation_data_create()
            arm.animation_data.action = action
            arm.animation_data.action_slot = slot
        bag = strip.channelbag(arm.animation_data.action_slot, ensure=True)
        co = np.empty((len(frames), 2), np.float32)
        co[:, 0] = frames
        for i in range(4):
            co[:, 1] = wxyz[:, i]
            _fcurve(bag, f'pose.bones["{bpy.utils.escape_identifier(bone)}"].rotation_quaternion', i, co, linear)
        placed.append(f"{bone} ({role})")
    msgs.append(f"head and gaze rotation on the bone(s) {', '.join(placed)}" if placed else
                f"{character.name}: no head bone; the head motion is left out")

