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
import time
from collections.abc import Callable, Generator
from pathlib import Path
from typing import TypeVar

import numpy as np

from ..character import Channel, Character, EncodedImage, Joint, Material, SceneMesh, joint_motions, shape_key
from ..errors import InputFileError, MissingShapeError, OutputError
from ..files import atomic_path
from ..formats import BLEND
from ..headpose import HeadPose, continuous_quaternions
from ..mesh import Mesh
from ._audio import checked_audio
from ._blender import _blender_output, _fcurve, _sound_strip, blender_timebase, import_bpy

__all__ = ["read_blender_character", "write_blender_animation", "read_blender_scene_character", "scene_character_steps",
           "character_objects", "run_steps", "scene_action_steps", "head_bones", "HeadBone"]

T = TypeVar("T")

_PURPOSE = "reading and writing Blender characters (.blend; .fbx without ufbx)"


def _bpy():
    """bpy through :func:`~faceretarget.io.import_bpy`: isolated from the user's Blender set-up, quiet."""
    return import_bpy(_PURPOSE)


def _open(bpy, path: Path) -> None:
    """Open ``path`` in a fresh Blender session: a .blend as the main file, an .fbx imported into an empty scene."""
    ext = path.suffix.lower()
    try:
        if ext == BLEND:
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


def run_steps(steps: Generator[float, None, T]) -> T:
    """Run a step generator (:func:`scene_character_steps`, :func:`scene_action_steps`) to its end; its result."""
    while True:
        try:
            next(steps)
        except StopIteration as stop:
            return stop.value


def character_objects(objects) -> list:
    """The whole character of some Blender objects (the selection): the mesh objects among them, their
    armatures (an Armature modifier's object or the parent), the armatures among them, and every visible
    mesh object those armatures deform or parent (eyes, teeth, hair), in scene order without duplicates."""
    objects = [o for o in objects if o is not None]
    arms = {o.name: o for o in objects if o.type == "ARMATURE"}
    for o in objects:
        if o.type != "MESH":
            continue
        for m in o.modifiers:
            if m.type == "ARMATURE" and m.object is not None:
                arms.setdefault(m.object.name, m.object)
        if o.parent is not None and o.parent.type == "ARMATURE":
            arms.setdefault(o.parent.name, o.parent)
    names = {o.name for o in objects if o.type == "MESH"}
    out = []
    for o in _scene_objects(objects):
        if o.type == "ARMATURE" and o.name in arms:
            out.append(o)
        elif o.type == "MESH" and (o.name in names or (_visible(o) and (
                (o.parent is not None and o.parent.name in arms)
                or any(m.type == "ARMATURE" and m.object is not None and m.object.name in arms for m in o.modifiers)))):
            out.append(o)
    return out


def _scene_objects(objects) -> list:
    """The objects of the scene the given objects are in (Blender's order), or the objects themselves."""
    import bpy

    scene = bpy.context.scene
    try:
        return list(scene.objects)
    except (AttributeError, ReferenceError):
        return list(objects)


def _visible(obj) -> bool:
    try:
        return not obj.hide_render and obj.visible_get()
    except (RuntimeError, ReferenceError):
        return not obj.hide_render


def read_blender_scene_character(objects=None, *, name: str | None = None) -> Character:
    """The character in the open Blender scene as a :class:`~faceretarget.character.Character`.

    Parameters
    ----------
    objects : iterable of bpy objects, optional
        The character, or any of its objects (its face mesh, its armature): :func:`character_objects`
        completes it.  Default: the selected objects (else every object of the scene).
    name : str, optional
        The character's name (default: its armature's, else its first mesh object's).

    Returns
    -------
    Character
        Blender's world frame (metres, +Z up), format ``"blend"``, route ``"Blender scene (bpy)"``, no
        path (the scene may differ from any saved file): meshes posed as the scene shows them, their
        relative shape keys, the armatures' bones (module docstring).  The same code as
        :func:`read_blender_character` reads a file with.
    """
    return run_steps(scene_character_steps(objects, name=name))


def scene_character_steps(objects=None, *, name: str | None = None) -> Generator[float, None, Character]:
    """:func:`read_blender_scene_character` in steps: yields the fraction done after every few milliseconds of
    work (a shape key, a thousand vertices), so a user interface can keep its main thread responsive;
    the character is the generator's return value (:func:`run_steps`)."""
    bpy = _bpy()
    if objects is None:
        objects = list(bpy.context.selected_objects) or list(bpy.context.scene.objects)
    objs = character_objects(list(objects))
    meshes = [o for o in objs if o.type == "MESH"]
    if not meshes:
        raise MissingShapeError("the selection holds no mesh object: select the character's face mesh or its "
                                "armature")
    arms = [o for o in objs if o.type == "ARMATURE"]
    name = name or (arms[0].name if arms else meshes[0].name)
    playing = _unplay(bpy, arms)          # the character as it is without the actions this module keyed
    if playing:
        yield 0.0
    try:
        ch = yield from _character_steps(bpy, None, arms, meshes)
    finally:
        _replay(bpy, playing)
    ch.format, ch.route, ch.name = "blend", "Blender scene (bpy)", name
    return ch


def _unplay(bpy, arms: list) -> list:
    """Take the actions :func:`scene_action_steps` keyed off the armatures (their bones back in the pose
    they had before); what to put back (:func:`_replay`)."""
    out = []
    for arm in arms:
        ad = arm.animation_data
        act = ad.action if ad is not None else None
        if act is not None and "faceretarget_rest" in act:
            out.append((arm, act, ad.action_slot, {b.name: (b.rotation_mode, tuple(b.rotation_quaternion))
                                                   for b in arm.pose.bones}))
            _restore_rest(bpy, arm)
    return out


def _replay(bpy, playing: list) -> None:
    for arm, act, slot, pose in playing:
        for bone, (mode, q) in pose.items():
            pb = arm.pose.bones.get(bone)
            if pb is not None:
                pb.rotation_mode = mode
                pb.rotation_quaternion = q
        arm.animation_data.action = act
        if slot is not None:
            arm.animation_data.action_slot = slot
    if playing:
        bpy.context.view_layer.update()


def _m(M) -> np.ndarray:
    return np.array([list(r) for r in M], dtype=np.float64)


def _inv_affine(M: np.ndarray) -> np.ndarray:
    """Inverses of affine 4x4 matrices ``(..., 4, 4)`` (last row 0 0 0 1: Blender's object and bone
    matrices) by the cross-product formula, without LAPACK.  Inside Blender, ``np.linalg.inv`` goes to
    OpenBLAS's threaded ``gesv``, whose threads spin against Blender's main thread: on two cores with two
    other busy processes, inverting an avatar's 129 bone matrices held the main thread 35-205 ms of CPU and
    1.2-1.5 s of wall time (the extension's slowest tick).  Singular matrices raise as ``np.linalg.inv`` does."""
    M = np.asarray(M, dtype=np.float64)
    A, t = M[..., :3, :3], M[..., :3, 3]
    r0, r1, r2 = A[..., 0, :], A[..., 1, :], A[..., 2, :]
    c0, c1, c2 = np.cross(r1, r2), np.cross(r2, r0), np.cross(r0, r1)
    det = np.einsum("...i,...i->...", r0, c0)
    scale = np.maximum(np.abs(A).max(axis=(-2, -1)), 1e-300) ** 3
    if not (np.abs(det) > 1e-12 * scale).all():
        raise np.linalg.LinAlgError("Singular matrix")
    inv = np.stack([c0, c1, c2], axis=-1) / det[..., None, None]
    out = np.zeros(M.shape)
    out[..., :3, :3] = inv
    out[..., :3, 3] = -np.einsum("...ij,...j->...i", inv, t)
    out[..., 3, 3] = 1.0
    return out


def _character(bpy, path: Path) -> Character:
    arms = [o for o in bpy.data.objects if o.type == "ARMATURE"]
    meshes = [o for o in bpy.data.objects if o.type == "MESH" and not o.hide_render]
    return run_steps(_character_steps(bpy, path, arms, meshes))


def _character_steps(bpy, path: Path | None, arms: list, mesh_objects: list) -> Generator[float, None, Character]:
    notes: list[str] = []
    joints: list[Joint] = []
    bone_index: dict[tuple[str, str], int] = {}
    bone_skin: dict[tuple[str, str], np.ndarray] = {}
    scale = float(bpy.context.scene.unit_settings.scale_length or 1.0)
    for arm in arms:
        Aw = _m(arm.matrix_world)
        bones = list(arm.data.bones)
        pose = np.array([_m(arm.pose.bones[b.name].matrix) for b in bones]).reshape(-1, 4, 4)
        rest = np.array([_m(b.matrix_local) for b in bones]).reshape(-1, 4, 4)
        world_all = Aw @ pose
        inv_world = _inv_affine(world_all) if len(bones) else world_all
        skin = pose @ _inv_affine(rest) if len(bones) else pose    # armature-space skinning matrix of each bone
        row = {b.name: i for i, b in enumerate(bones)}
        for i, b in enumerate(bones):
            world = world_all[i].copy()
            parent = bone_index.get((arm.name, b.parent.name), -1) if b.parent else -1
            local = inv_world[row[b.parent.name]] @ world if b.parent else world.copy()
            bone_index[(arm.name, b.name)] = len(joints)
            bone_skin[(arm.name, b.name)] = skin[i]
            world[:3, 3] *= scale
            joints.append(Joint(b.name, parent, world, f"{arm.name}/{b.name}", local))
        yield 0.0
    meshes: list[SceneMesh] = []
    images: dict[str, EncodedImage | None] = {}
    work = [max(1, len(o.data.vertices)) * (1 + _n_keys(o)) for o in mesh_objects]
    done = 0
    for obj, w in zip(mesh_objects, work, strict=True):
        sm = None
        for f in _mesh_steps(bpy, obj, path, (bone_index, bone_skin), notes, images, scale):
            if isinstance(f, SceneMesh):
                sm = f
            else:
                yield (done + f * w) / sum(work)
        done += w
        if sm is not None:
            meshes.append(sm)
    fmt = "blend" if path is None or path.suffix.lower() == BLEND else "fbx"
    return Character(path, fmt, "Blender 4.5 (bpy)", meshes, joints, up=np.array([0.0, 0.0, 1.0]), front=None,
                     notes=notes, source_unit="m")


def _n_keys(obj) -> int:
    keys = obj.data.shape_keys
    return len(keys.key_blocks) if keys is not None else 0


#: Vertices whose vertex groups are read at a time, and for how long at most before a step generator yields.
_STEP_VERTICES = 100
_STEP_SECONDS = 0.004


def _skin_steps(obj, me, bones):
    """Per-vertex armature-space linear blend skinning matrices of the object's current pose, and the
    top four (joint, weight) influences (the generator's value: ``(M, joints, weights)``, Nones without
    an armature modifier); yields the fraction of vertices read."""
    mod = next((m for m in obj.modifiers if m.type == "ARMATURE" and m.object is not None and m.show_render), None)
    if mod is None or not mod.use_vertex_groups:
        return None, None, None
    arm = mod.object
    V = len(me.vertices)
    index, skin = bones
    mats = {}
    for g in obj.vertex_groups:
        if g.name in arm.pose.bones:
            m = skin.get((arm.name, g.name))
            if m is None:                                   # an armature outside the character
                pb = arm.pose.bones[g.name]
                m = _m(pb.matrix) @ _inv_affine(_m(pb.bone.matrix_local))
            mats[g.index] = (m, index.get((arm.name, g.name), -1))
    vi, gi, wi = [], [], []
    verts = me.vertices
    a = 0
    while a < V:                    # a step reads vertices for a few milliseconds (wigs carry dozens of groups each)
        until = time.perf_counter() + _STEP_SECONDS
        while a < V and time.perf_counter() < until:
            for v in verts[a:a + _STEP_VERTICES]:
                i = v.index
                for g in v.groups:
                    vi.append(i)
                    gi.append(g.group)
                    wi.append(g.weight)
            a += _STEP_VERTICES
        yield min(1.0, a / V)
    vi, gi, wi = np.array(vi, np.int64), np.array(gi, np.int64), np.array(wi, np.float64)
    ok = (wi > 0) & np.isin(gi, np.fromiter(mats, np.int64, len(mats)))
    vi, gi, wi = vi[ok], gi[ok], wi[ok]
    groups = sorted(mats)
    slot = np.searchsorted(np.array(groups, np.int64), gi)
    B = np.stack([mats[g][0] for g in groups]) if groups else np.zeros((0, 4, 4))
    J = np.array([mats[g][1] for g in groups], np.int64)
    Bf = B.reshape(-1, 16)
    M = np.stack([np.bincount(vi, weights=wi * Bf[slot, c], minlength=V) for c in range(16)], axis=1).reshape(V, 4, 4)
    tot = np.bincount(vi, weights=wi, minlength=V)
    has = tot > 0
    M[has] /= tot[has, None, None]
    M[~has] = np.eye(4)
    yield 1.0
    # the four largest influences of each vertex (ties: the group listed first)
    order = np.lexsort((np.arange(len(vi)), -wi, vi))
    vs = vi[order]
    rank = np.arange(len(vs)) - np.searchsorted(vs, vs)
    top = rank < 4
    jn = np.full((V, 4), -1, np.int64)
    jw = np.zeros((V, 4))
    jn[vs[top], rank[top]] = J[slot[order][top]]
    jw[vs[top], rank[top]] = wi[order][top]
    A = _m(arm.matrix_world)
    Oinv_A = _inv_affine(A) @ _m(obj.matrix_world)
    return A @ M @ Oinv_A, jn, jw


def _mesh_steps(bpy, obj, path: Path | None, bones, notes, images, scale):
    """One mesh object as a :class:`SceneMesh` (yielded last; None when it has no vertex), yielding the
    fraction done before it."""
    me = obj.data
    V = len(me.vertices)
    if V == 0:
        yield None
        return
    co = np.empty(V * 3, np.float32)
    me.vertices.foreach_get("co", co)
    local = co.reshape(V, 3).astype(np.float64)
    yield 0.0
    counts = np.empty(len(me.polygons), np.int32)
    me.polygons.foreach_get("loop_total", counts)
    loops = np.empty(len(me.loops), np.int32)
    me.loops.foreach_get("vertex_index", loops)
    ok = counts >= 3
    starts = np.empty(len(me.polygons), np.int32)
    me.polygons.foreach_get("loop_start", starts)
    kept = counts[ok].astype(np.int64)
    corner = (np.repeat(starts[ok].astype(np.int64) - (np.cumsum(kept) - kept), kept) + np.arange(int(kept.sum()))
              if ok.any() else np.zeros(0, np.int64))
    yield 0.0
    uvs = fuv = None
    if me.uv_layers.active is not None and len(me.loops):
        uv = np.empty(len(me.loops) * 2, np.float32)
        me.uv_layers.active.data.foreach_get("uv", uv)
        uv = uv.reshape(-1, 2).astype(np.float64)
        uvs = np.stack([uv[:, 0], 1.0 - uv[:, 1]], axis=1)
        fuv = corner
    yield 0.0
    keys = me.shape_keys
    K = len(keys.key_blocks) if keys is not None else 0
    share = 1.0 / (1 + K)
    skin = _skin_steps(obj, me, bones)
    while True:
        try:
            f = next(skin)
        except StopIteration as stop:
            M, jn, jw = stop.value
            break
        yield f * share
    if M is None:
        G = _m(obj.matrix_world)
        L = np.broadcast_to(G[:3, :3], (V, 3, 3))
        T = np.broadcast_to(G[:3, 3], (V, 3))
    else:
        L, T = M[:, :3, :3], M[:, :3, 3]
    world = (np.einsum("vij,vj->vi", L, local) + T) * scale
    yield share
    names = []
    D = np.zeros((max(K - 1, 0), V, 3), np.float32)
    if keys is not None and keys.use_relative:
        kbs = keys.key_blocks
        basis = kbs[0] if len(kbs) else None
        # the coordinates of a key other keys are relative to (the basis) are read once
        shared = {basis.name} | {kb.relative_key.name for kb in kbs if kb.relative_key is not None}
        read: dict[str, np.ndarray] = {}

        def coords(kb) -> np.ndarray:
            if kb.name in read:
                return read[kb.name]
            a = np.empty(V * 3, np.float32)
            kb.data.foreach_get("co", a)
            if kb.name in shared:
                read[kb.name] = a
            return a

        for k, kb in enumerate(list(kbs)[1:], 1):
            rel = kb.relative_key if kb.relative_key is not None else basis
            d = (coords(kb) - coords(rel)).reshape(V, 3).astype(np.float64)
            D[len(names)] = np.einsum("vij,vj->vi", L, d) * scale
            names.append(kb.name)
            yield share * (1 + k)
    elif keys is not None:
        notes.append(f"{obj.name}: absolute shape keys (a keyed blend, not expressions) are left out")
    yield 1.0
    mats = [_material(bpy, s.material, images, notes) for s in obj.material_slots] or [Material("default")]
    tri_mat = None
    if len(mats) > 1:
        mi = np.empty(len(me.polygons), np.int32)
        me.polygons.foreach_get("material_index", mi)
        tri_mat = np.repeat(mi[ok], counts[ok] - 2).astype(np.int64)
    yield 1.0
    mesh = Mesh(world, counts[ok], loops[corner], uvs, fuv, name=obj.name)
    D = D[:len(names)]
    yield SceneMesh(obj.name, obj.name, mesh, names, D, mats, tri_mat, skin_joints=jn, skin_weights=jw)


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
def write_scene_copy(character: Character, out: Path, edit: Callable, *, fbx_options: dict | None = None) -> tuple:
    """Blender opens the character's own file, ``edit(bpy, scratch_folder, msgs)`` changes the scene, and the
    scene is saved as ``out`` (``.blend``; else Blender's FBX exporter with ``fbx_options``), whole or not at
    all; what ``edit`` returned and the lines it left in ``msgs``."""
    with _blender_output():
        bpy = _bpy()
    scratch = Path(tempfile.mkdtemp(prefix=f".{out.name}.", suffix=".part", dir=out.parent))
    msgs: list[str] = []
    try:
        with _blender_output():
            _open(bpy, Path(character.path))
            _file_shape_names(bpy, character)
            value = edit(bpy, scratch, msgs)
            tmp_out = scratch / out.name
            if out.suffix.lower() == BLEND:
                res = bpy.ops.wm.save_as_mainfile(filepath=str(tmp_out), check_existing=False, compress=True,
                                                  relative_remap=True, copy=True)
            else:
                res = bpy.ops.export_scene.fbx(filepath=str(tmp_out), check_existing=False, use_selection=False,
                                               add_leaf_bones=False, path_mode="AUTO", **(fbx_options or {}))
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
    return value, msgs


def _file_shape_names(bpy, character: Character) -> None:
    """Give Blender's shape keys the names the file itself holds: Blender's FBX importer drops the deformer
    part of a channel name (``blendShape1.AA_VI_00_Sil`` becomes ``AA_VI_00_Sil``), so its exporter would
    write the copy's shapes under other names than the user's file (an engine's curves and retargeting
    presets bind by name).  A key is renamed only when exactly one of the file's names matches it."""
    for sm in character.meshes:
        obj = bpy.data.objects.get(sm.ref) or bpy.data.objects.get(sm.name)
        keys = obj.data.shape_keys if obj is not None and obj.type == "MESH" else None
        if keys is None:
            continue
        by_key: dict[str, list[str]] = {}
        for n in sm.shape_names:
            by_key.setdefault(shape_key(n), []).append(n)
        have = {kb.name for kb in keys.key_blocks}
        for kb in list(keys.key_blocks)[1:]:
            cands = by_key.get(shape_key(kb.name), [])
            if len(cands) == 1 and cands[0] != kb.name and cands[0] not in have:
                have.discard(kb.name)
                kb.name = cands[0]
                have.add(kb.name)


def write_blender_animation(out: Path, character: Character, chans: list[Channel], W: np.ndarray, t: np.ndarray,
                            *, head: HeadPose | None = None, audio=None, audio_rate=None, neck_share: float = 0.0,
                            gaze: dict | None = None, name: str = "faceretarget", log=None) -> Path:
    """Open the character's own file in Blender, add the action, save ``out`` (.blend or .fbx)."""
    log = log or (lambda *_: None)
    with _blender_output():
        _bpy()                                   # a missing Blender is said before the sound is read
    kind = out.suffix.lower()
    sound = checked_audio(out, audio, audio_rate) if kind == BLEND else None

    def edit(bpy, scratch: Path, msgs: list) -> None:
        _animate_scene(bpy, out, character, chans, W, t, head, neck_share, gaze, name, sound, scratch,
                       start=1.0 if kind == BLEND else 0.0, msgs=msgs)

    _, msgs = write_scene_copy(character, out, edit, fbx_options=dict(
        bake_anim=True, bake_anim_use_all_bones=True, bake_anim_use_nla_strips=False, bake_anim_use_all_actions=False,
        bake_anim_force_startend_keying=True, bake_anim_step=1.0, bake_anim_simplify_factor=0.0))
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


def scene_action_steps(character: Character, chans: list[Channel], W: np.ndarray, t: np.ndarray, *,
                       head: HeadPose | None = None, neck_share: float = 0.0, gaze: dict | None = None,
                       name: str = "faceretarget",
                       sound=None, scratch: Path | None = None, sound_file: str | os.PathLike | None = None,
                       start: float = 1.0, where: str | os.PathLike = "scene", strip_name: str = "audio",
                       replace_sound: bool = False, msgs: list | None = None) -> Generator[float, None, object]:
    """Key one new action in the open Blender scene, in steps (a few fcurves each; :func:`run_steps`).

    What :func:`write_blender_animation` adds to a file, on the scene Blender has open (the character
    read from it by :func:`read_blender_character` or :func:`read_blender_scene_character`): every
    channel's shape keys keyed at every frame (``LINEAR``, sliders widened where a weight leaves them),
    the head (and neck) bone's ``rotation_quaternion`` relative to its pose (and the eye bones' by
    ``gaze``, ``{role: Rotation}`` relative to the head: :func:`~faceretarget.character.joint_motions`), the scene's frame rate and
    range set to the take's (:func:`~faceretarget.io.blender_timebase`, the take's first frame at
    ``start``), and with ``sound`` (``(samples, rate)`` and a ``scratch`` folder for its WAV) or
    ``sound_file`` (a WAV written already) a sound strip ``strip_name`` packed into the file (a strip of
    that name there before is replaced; with ``replace_sound`` it is removed even when the take has no
    sound, so an earlier take's sound does not play with this one).  An action this function made before, still playing on the
    armature, is taken off first and its bones go back to the pose they had under it, so keys are
    always relative to the character's own pose.  The action an ID played before stays in the file
    (a fake user).

    Parameters
    ----------
    character : Character
    chans : list of Channel
    W : (T, C) float
        One column per channel.
    t : (T,) float
        Seconds, strictly increasing.
    where : path-like
        For messages.

    Returns
    -------
    bpy.types.Action
        The generator's value; tagged ``action["faceretarget"]`` with what made it.
    """
    import json

    bpy = _bpy()
    msgs = [] if msgs is None else msgs
    out = Path(where)
    scene = bpy.context.scene
    fps, base, frames = blender_timebase(t, start)
    scene.render.fps, scene.render.fps_base = fps, base
    scene.frame_start = int(start)
    scene.frame_end = max(int(start), int(math.ceil(frames[-1] - 1e-6)))
    linear = bpy.types.Keyframe.bl_rna.properties["interpolation"].enum_items["LINEAR"].value
    action = bpy.data.actions.new(name)
    action["faceretarget"] = json.dumps({"frames": int(len(t)), "fps": fps / base, "character": character.name})
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
            if keyed % 8 == 0:
                yield keyed / max(1, len(chans))
    if missing:
        raise OutputError(f"{out}: Blender's copy of the character lacks {', '.join(missing[:4])}"
                          f"{' ...' if len(missing) > 4 else ''} (a name the file reader and Blender read differently)")
    yield 1.0
    motions = joint_motions(character, head, neck_share, gaze)
    if motions:
        _joint_action(bpy, out, character, motions, action, strip, frames, linear, msgs)
        yield 1.0
    has_sound = sound is not None or sound_file is not None
    if has_sound or (replace_sound and scene.sequence_editor is not None):
        if sound is not None and scratch is None:
            raise OutputError(f"{out}: a sound strip needs a scratch folder for its WAV")
        editor = scene.sequence_editor_create()
        strips = editor.strips if hasattr(editor, "strips") else editor.sequences
        for old in [x for x in strips if x.name == strip_name or x.name.startswith(f"{strip_name}.")]:
            strips.remove(old)
        if has_sound:
            _sound_strip(bpy, scene, out, sound, scratch, name=strip_name, wav=sound_file)
    msgs.append(f"keyed {keyed} shape key(s) on {len(per_obj)} object(s)")
    return action


def _animate_scene(bpy, out: Path, character: Character, chans: list[Channel], W: np.ndarray, t: np.ndarray,
                   head: HeadPose | None, neck_share: float, gaze, name: str, sound, scratch: Path, start: float,
                   msgs: list) -> None:
    run_steps(scene_action_steps(character, chans, W, t, head=head, neck_share=neck_share, gaze=gaze, name=name,
                                 sound=sound, scratch=scratch, start=start, where=out, msgs=msgs))


class HeadBone:
    """A head, neck or eye pose bone of the open scene and how a rotation in the head frame turns it.

    Attributes
    ----------
    label : str
        ``"Bip01 Head (head)"``.
    pose_bone : bpy.types.PoseBone
    share : float
        The share of the head rotation this bone takes.
    """

    def __init__(self, label: str, pose_bone, share: float, P0: np.ndarray, G: np.ndarray, B: np.ndarray):
        self.label, self.pose_bone, self.share = label, pose_bone, share
        self._P0, self._G, self._B = P0, G, B

    def quaternions(self, rotation) -> np.ndarray:
        """``(T, 4)`` ``rotation_quaternion`` keys (``w, x, y, z``, on one hemisphere) that turn the head by
        ``rotation`` (a scipy ``Rotation`` of ``T`` head poses in the head frame, about the rest pose)."""
        from scipy.spatial.transform import Rotation

        Rh = Rotation.from_rotvec(rotation.as_rotvec().reshape(-1, 3) * self.share).as_matrix()
        Rb = self._B @ Rh @ self._B.T
        G = self._G
        return continuous_quaternions(Rotation.from_matrix(self._P0 @ (G.T @ Rb @ G)).as_quat())[:, [3, 0, 1, 2]]


def head_bones(character: Character, neck_share: float = 0.0) -> list[HeadBone]:
    """The character's head (and neck) pose bones in the open scene, each with the pose it has now (an
    action this module made is taken off first: :func:`scene_action_steps`); bones the scene lacks are
    left out."""
    roles = (("head", 1.0 - neck_share), ("neck", neck_share)) if neck_share > 0 else (("head", 1.0),)
    return [hb for role, share in roles if (j := character.joint(role)) is not None
            and (hb := _pose_bone(character, role, j, share)) is not None]


def _pose_bone(character: Character, role: str, j: Joint, share: float) -> HeadBone | None:
    """The pose bone of joint ``j`` in the open scene, or None when the scene lacks it."""
    from scipy.spatial.transform import Rotation

    from ..character import character_frame
    from ._blender import BLENDER_AXES

    bpy = _bpy()
    F = character_frame(character)
    # the character's world frame -> Blender's world: identity for a Blender read, Y-up -> Z-up for ufbx
    A = np.eye(3) if character.route.startswith("Blender") else BLENDER_AXES
    bone = j.ref.split("/")[-1] if "/" in j.ref else j.name
    arm = next((o for o in bpy.data.objects if o.type == "ARMATURE" and bone in o.pose.bones), None)
    if arm is None:
        return None
    _restore_rest(bpy, arm)
    pb = arm.pose.bones[bone]
    G = _m(arm.matrix_world)[:3, :3] @ _m(pb.matrix)[:3, :3]
    U, _, Vt = np.linalg.svd(G)
    G = U @ Vt
    P0 = Rotation.from_quat(np.r_[pb.rotation_quaternion[1:], pb.rotation_quaternion[0]]).as_matrix() \
        if pb.rotation_mode == "QUATERNION" else np.array(pb.matrix_basis.to_3x3())
    return HeadBone(f"{bone} ({role})", pb, share, P0, G, A @ F.T)


def _restore_rest(bpy, arm) -> None:
    """Take an action this module made off ``arm`` and put its bones back in the pose they had before it."""
    import json

    ad = arm.animation_data
    act = ad.action if ad is not None else None
    if act is None or "faceretarget_rest" not in act:
        return
    rest = json.loads(act["faceretarget_rest"])
    ad.action = None
    for bone, q in rest.items():
        pb = arm.pose.bones.get(bone)
        if pb is not None:
            pb.rotation_mode = "QUATERNION"
            pb.rotation_quaternion = q
    bpy.context.view_layer.update()


def _joint_action(bpy, out, character, motions: list, action, strip, frames, linear, msgs) -> None:
    """Key the rotations of :func:`~faceretarget.character.joint_motions` (head, neck, eyes; each with its
    share already in it) on their pose bones."""
    import json

    placed = []
    # every bone found (and an earlier action of ours taken off) before any is keyed: taking ours off an
    # armature after keying one of its bones would drop those keys
    bones = [(hb, rot) for role, j, rot in motions if (hb := _pose_bone(character, role, j, 1.0)) is not None]
    for hb, rot in bones:
        pb, label = hb.pose_bone, hb.label
        wxyz = hb.quaternions(rot)
        arm = pb.id_data
        bone = pb.name
        rest = json.loads(action.get("faceretarget_rest", "{}"))
        rest[bone] = [float(x) for x in pb.rotation_quaternion] if pb.rotation_mode == "QUATERNION" else \
            [float(x) for x in pb.matrix_basis.to_quaternion()]
        action["faceretarget_rest"] = json.dumps(rest)
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
        placed.append(label)
    msgs.append(f"head and gaze rotation on the bone(s) {', '.join(placed)}" if placed else
                f"{character.name}: no head bone; the head motion is left out")
