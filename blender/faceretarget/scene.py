"""The open scene's side of the jobs: the selected character, its stored landmarks, the landmark overlay,
and the live pose.  Everything the library computes arrives from the worker; this module only reads and
writes Blender data (through the library's :mod:`faceretarget.io` Blender functions)."""

from __future__ import annotations

import json

import bpy
import numpy as np

#: Custom property holding a character's landmarks (the library's landmark record, JSON) on its face mesh.
LANDMARKS_PROP = "faceretarget_landmarks"
#: The overlay object showing the landmarks.
OVERLAY = "faceretarget landmarks"
#: The 68 points' outlines (jaw, brows, nose, eyes, lips) drawn as edges of the overlay.
_OUTLINES = [range(0, 17), range(17, 22), range(22, 27), range(27, 31), range(31, 36), [*range(36, 42), 36],
             [*range(42, 48), 42], [*range(48, 60), 48], [*range(60, 68), 60]]


def selected_objects(context) -> list:
    """The selected objects (else the active one)."""
    objs = list(context.selected_objects or [])
    if not objs and context.active_object is not None:
        objs = [context.active_object]
    return objs


def has_character(context) -> bool:
    """Whether the selection holds a mesh with shape keys or an armature deforming one (for ``poll``)."""
    for o in selected_objects(context):
        if o.type == "MESH" and o.data.shape_keys is not None:
            return True
        if o.type == "ARMATURE" and any(c.type == "MESH" and c.data.shape_keys is not None for c in o.children):
            return True
    return False


def character_names(context) -> list[str]:
    """The names of the selected character's objects (the library completes the selection)."""
    from faceretarget.io import character_objects

    return [o.name for o in character_objects(selected_objects(context))]


def objects(names: list[str]) -> list:
    out = []
    for n in names:
        o = bpy.data.objects.get(n)
        if o is None:
            raise ReferenceError(f"object '{n}' of the character is gone")
        out.append(o)
    return out


def read_character(job, names: list[str], lo: float = 0.0, hi: float = 0.1):
    """Steps reading the character (:func:`faceretarget.io.scene_character_steps`); the Character."""
    from faceretarget.io import scene_character_steps

    steps = scene_character_steps(objects(names))
    while True:
        try:
            f = next(steps)
        except StopIteration as stop:
            return stop.value
        job.set_progress(lo + (hi - lo) * f, "reading the character")
        yield


#: Bytes of the pickled character written a step (a VALID avatar pickles to 30 MB: written at once, with the
#: pickling, it held the main thread for 130-170 ms; 4 MB a step, one step of writing held it 102 ms under load).
_WRITE_CHUNK = 1 << 20


def save_character(job, character):
    """Steps writing the character into the job's folder for the worker (its pickle with the arrays out of band,
    :func:`faceretarget.pipelines.worker.character_parts`: pickling copies no array, 1 ms for a VALID avatar
    where its 28 MB pickle took 6-16 ms outside Blender), then 1 MB a step; the path."""
    from faceretarget.pipelines.worker import character_parts

    yield                                                  # the reading's last step and the pickling apart
    parts = character_parts(character)
    path = job.folder / "character.pkl"
    with open(path, "wb") as f:
        for part in parts:
            view = memoryview(part).cast("B")
            for i in range(0, len(view), _WRITE_CHUNK):
                yield
                f.write(view[i:i + _WRITE_CHUNK])
    return path


def stored_landmarks(names: list[str]) -> dict | None:
    """The landmark record stored on one of the character's meshes, if any."""
    for n in names:
        o = bpy.data.objects.get(n)
        if o is not None and LANDMARKS_PROP in o:
            try:
                return json.loads(o[LANDMARKS_PROP])
            except (TypeError, ValueError):
                return None
    return None


def store_landmarks(names: list[str], record: dict) -> None:
    """Keep a landmark record on its mesh object (saved with the .blend; others' records removed)."""
    for n in names:
        o = bpy.data.objects.get(n)
        if o is not None and LANDMARKS_PROP in o and o.name != record["mesh"]:
            del o[LANDMARKS_PROP]
    o = bpy.data.objects.get(record["mesh"])
    if o is not None:
        o[LANDMARKS_PROP] = json.dumps(record)


def channels(character, spec: list) -> list:
    """The worker's channels (``[name, [[mesh ref, shape name], ...]]``) as the library's Channel objects."""
    from faceretarget.character import Channel

    index = {m.ref: i for i, m in enumerate(character.meshes)}
    out = []
    for name, binds in spec:
        b = []
        for ref, shape in binds:
            mi = index[ref]
            b.append((mi, character.meshes[mi].shape_names.index(shape)))
        out.append(Channel(name, tuple(b)))
    return out


# ------------------------------------------------------------------------------------------- landmarks
def show_landmarks(positions: np.ndarray, names: list[str]) -> bpy.types.Object:
    """The overlay: a mesh object of the 68 points (vertices) and their outlines (edges), drawn in front,
    in the scene's collection; replaced when it exists."""
    hide_landmarks()
    P = np.asarray(positions, dtype=np.float64).reshape(68, 3)
    edges = [(a, b) for ring in _OUTLINES for a, b in zip(list(ring)[:-1], list(ring)[1:], strict=True)]
    me = bpy.data.meshes.new(OVERLAY)
    me.from_pydata([tuple(p) for p in P], edges, [])
    me.update()
    obj = bpy.data.objects.new(OVERLAY, me)
    obj["faceretarget_character"] = json.dumps(names)
    obj.show_in_front = True
    obj.display_type = "WIRE"
    obj.hide_render = True
    obj.color = (0.1, 1.0, 0.3, 1.0)
    bpy.context.scene.collection.objects.link(obj)
    return obj


def overlay() -> bpy.types.Object | None:
    return bpy.data.objects.get(OVERLAY)


def overlay_points() -> np.ndarray | None:
    """The overlay's 68 points where the user left them (world space; edit mode flushed first)."""
    obj = overlay()
    if obj is None:
        return None
    if obj.mode == "EDIT":
        obj.update_from_editmode()
    me = obj.data
    if len(me.vertices) != 68:
        return None
    co = np.empty(68 * 3, np.float32)
    me.vertices.foreach_get("co", co)
    M = np.array(obj.matrix_world)
    P = co.reshape(68, 3).astype(np.float64)
    return P @ M[:3, :3].T + M[:3, 3]


def hide_landmarks() -> None:
    obj = overlay()
    if obj is None:
        return
    me = obj.data
    if obj.mode == "EDIT" and bpy.context.view_layer.objects.active == obj:
        bpy.ops.object.mode_set(mode="OBJECT")
    bpy.data.objects.remove(obj)
    if me.users == 0:
        bpy.data.meshes.remove(me)


# ------------------------------------------------------------------------------------------- live pose
class LivePose:
    """Puts live frames on the character: its shape keys' values and its head bones' rotations.

    The values it replaces are kept and put back by :meth:`restore`.
    """

    def __init__(self, character, spec: list, drive: list[int], neck_share: float = 0.0):
        from faceretarget.io import head_bones

        self.character = character
        self.chans = channels(character, spec)
        self.drive = np.asarray(drive, np.int64)
        self.targets = []                                   # (key, kb indices, channel indices, saved values)
        per: dict[str, tuple[list, list]] = {}
        for c, ch in enumerate(self.chans):
            for mi, k in ch.binds:
                m = character.meshes[mi]
                per.setdefault(m.ref, ([], []))
                per[m.ref][0].append(m.shape_names[k])
                per[m.ref][1].append(c)
        for ref, (shapes, cols) in per.items():
            obj = bpy.data.objects[ref]
            key = obj.data.shape_keys
            names = [kb.name for kb in key.key_blocks]
            idx = np.array([names.index(s) for s in shapes], np.int64)
            vals = np.empty(len(names), np.float32)
            key.key_blocks.foreach_get("value", vals)
            self.targets.append((obj, key, idx, np.array(cols, np.int64), vals.copy()))
        self.bones = head_bones(character, neck_share)
        self.saved_bones = [(b.pose_bone, b.pose_bone.rotation_mode, tuple(b.pose_bone.rotation_quaternion))
                            for b in self.bones]
        for b in self.bones:
            b.pose_bone.rotation_mode = "QUATERNION"
        self.frames = 0

    def apply(self, weights: np.ndarray, head_xyzw: np.ndarray | None) -> None:
        full = np.zeros(len(self.chans))
        full[self.drive] = weights
        for _obj, key, idx, cols, saved in self.targets:
            vals = saved.copy()
            vals[idx] = full[cols]
            key.key_blocks.foreach_set("value", vals)
            key.user.update_tag()
        if head_xyzw is not None and self.bones:
            from scipy.spatial.transform import Rotation

            rot = Rotation.from_quat(np.asarray(head_xyzw, dtype=np.float64).reshape(1, 4))
            for b in self.bones:
                b.pose_bone.rotation_quaternion = tuple(b.quaternions(rot)[0])
        self.frames += 1

    def restore(self) -> None:
        for _obj, key, _idx, _cols, saved in self.targets:
            try:
                key.key_blocks.foreach_set("value", saved)
                key.user.update_tag()
            except ReferenceError:
                pass
        for pb, mode, q in self.saved_bones:
            try:
                pb.rotation_quaternion = q
                pb.rotation_mode = mode
            except ReferenceError:
                pass
