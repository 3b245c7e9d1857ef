"""Test helper: open a file in Blender itself (the ``bpy`` module) and read back what Blender plays.

Reused by every test that checks a writer against Blender's own importers (``.glb``, ``.blend``,
``.fbx``, ``.usd*``, ``.bvh``).  Importing it skips the test when bpy is missing (``make blender``) and
imports bpy through :func:`faceretarget.io.import_bpy`::

    scene = load_scene(path)                      # fresh factory scene + Blender's own importer
    frames = scene.frames_for(times)              # scene frame of each take frame
    v = scene.vertices(frames, reference=want[0]) # (F, V, 3) metres, our axes and vertex order
    q = scene.head_rotations(frames)              # (F, 4) x, y, z, w in our axes
    keys = scene.shape_keys()                     # {name: ShapeKeyTrack(frames, values, lo, hi)}

Axes: Blender is +Z up; everything returned here is in ours (glTF's: +Y up, +Z forward), through
the inverse of Blender's glTF import conversion ``(x, y, z) -> (x, -z, y)``.  Vertices are the
depsgraph-evaluated mesh (shape keys, modifiers, parents) in world space, in metres as Blender shows
them (no unit scaling undone).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

from faceretarget.io import import_bpy  # noqa: E402
from faceretarget.optional import has_module  # noqa: E402

if not has_module("bpy"):
    pytest.skip("Blender's Python module is not installed: make blender", allow_module_level=True)
bpy = import_bpy()                  # import bpy, without bpy 4.5's NumPy-1.x audio message (docs/blender.md)

#: Our axes -> Blender's: ``v_blender = AXES @ v`` (Blender's glTF importer).
AXES = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])


@dataclass
class ShapeKeyTrack:
    """One shape key as Blender holds it: its keyframes and its slider range."""

    frames: np.ndarray  # (n,) scene frames of the keys
    values: np.ndarray  # (n,) keyed values
    slider_min: float
    slider_max: float

    def outside(self) -> np.ndarray:
        """(n,) bool: keyed values Blender clamps to the slider when it plays them."""
        lo, hi = np.float32(self.slider_min), np.float32(self.slider_max)
        v = self.values.astype(np.float32)
        return (v < lo) | (v > hi)


def fresh_scene() -> None:
    """Blender's factory settings with an empty scene (every importer enabled)."""
    bpy.ops.wm.read_factory_settings(use_empty=True)


def load_scene(path, *, fps: float | None = None, bvh_scale: float = 0.01) -> BlenderScene:
    """Open ``path`` in a fresh Blender scene with Blender's own reader for its extension.

    Parameters
    ----------
    path : path-like
        ``.glb`` / ``.gltf`` (``import_scene.gltf``), ``.blend`` (``open_mainfile``), ``.fbx``
        (``import_scene.fbx``), ``.usd`` / ``.usda`` / ``.usdc`` / ``.usdz`` (``wm.usd_import``) or
        ``.bvh`` (``import_anim.bvh``, scene fps and duration taken from the file).
    fps : float, optional
        Scene frame rate set before importing a ``.glb`` (Blender's glTF importer keys time ``t`` at
        frame ``t * fps``, default Blender's 24) or a ``.usd*`` (default: the stage's
        timeCodesPerSecond, read with pxr when installed; Blender keys time code ``c`` at frame ``c``).
    bvh_scale : float
        Scale of the BVH importer (our BVH files are in centimetres: 0.01 gives metres).
    """
    path = Path(path)
    ext = path.suffix.lower()
    fresh_scene()
    if ext == ".blend":
        bpy.ops.wm.open_mainfile(filepath=str(path), load_ui=False)
        return BlenderScene(path, ext, start=1.0)
    scene = bpy.context.scene
    if fps is not None:
        scene.render.fps = max(1, int(round(fps)))
        scene.render.fps_base = scene.render.fps / float(fps)
    if ext in (".glb", ".gltf"):
        _finished(bpy.ops.import_scene.gltf(filepath=str(path)), path)
        return BlenderScene(path, ext, start=0.0)
    if ext == ".fbx":
        _finished(bpy.ops.import_scene.fbx(filepath=str(path)), path)
        return BlenderScene(path, ext, start=1.0)
    if ext in (".usd", ".usda", ".usdc", ".usdz"):
        # Blender's USD importer puts time code c at frame c and leaves the scene's fps alone: play
        # the stage at its timeCodesPerSecond (read with pxr when installed) unless fps is given
        start, tcps = _usd_timing(path)
        if fps is None and tcps is not None:
            scene.render.fps = max(1, int(round(tcps)))
            scene.render.fps_base = scene.render.fps / tcps
        _finished(bpy.ops.wm.usd_import(filepath=str(path)), path)
        return BlenderScene(path, ext, start=start if start is not None else float(scene.frame_start))
    if ext == ".bvh":
        _finished(bpy.ops.import_anim.bvh(filepath=str(path), global_scale=bvh_scale, frame_start=1,
                                          update_scene_fps=True, update_scene_duration=True,
                                          rotate_mode="NATIVE"), path)
        return BlenderScene(path, ext, start=1.0)
    raise ValueError(f"{path}: no Blender reader for '{ext}'")


def _usd_timing(path: Path) -> tuple[float | None, float | None]:
    """(startTimeCode, timeCodesPerSecond) of a USD stage, or Nones without pxr."""
    try:
        from pxr import Usd
    except ImportError:
        return None, None
    stage = Usd.Stage.Open(str(path))
    return float(stage.GetStartTimeCode()), float(stage.GetTimeCodesPerSecond())


def _finished(result, path: Path) -> None:
    if "FINISHED" not in result:
        raise RuntimeError(f"{path}: Blender's importer returned {result}")


def to_ours(v_blender: np.ndarray) -> np.ndarray:
    """(..., 3) Blender positions -> our axes."""
    return np.asarray(v_blender, np.float64) @ AXES


def _frame_set(frame: float) -> None:
    scene = bpy.context.scene
    f = math.floor(frame)
    scene.frame_set(int(f), subframe=float(frame - f))


class BlenderScene:
    """The scene Blender built from one file (see the module docstring); valid until the next
    :func:`load_scene` (Blender then frees it: using it raises ``ReferenceError``)."""

    def __init__(self, path: Path, ext: str, start: float) -> None:
        self.path, self.ext, self.start = path, ext, start
        self.scene = bpy.context.scene

    # ---------------------------------------------------------------------------------- time
    @property
    def fps(self) -> float:
        """The scene's frame rate, ``fps / fps_base``."""
        r = self.scene.render
        return r.fps / r.fps_base

    def frames_for(self, times) -> np.ndarray:
        """Scene frame of each time (seconds, relative to ``times[0]``): ``start + (t - t0) * fps``.

        ``start`` is 1 for ``.blend`` / ``.fbx`` / ``.bvh``, 0 for ``.glb`` (Blender's glTF
        importer keys time ``t`` at frame ``t * fps * fps_base``; with ``fps_base`` 1 that is
        ``t * fps``) and the stage's startTimeCode for ``.usd*``.
        """
        t = np.asarray(times, np.float64)
        r = self.scene.render
        rate = r.fps * r.fps_base if self.ext in (".glb", ".gltf") else self.fps
        return self.start + (t - t[0]) * rate

    # ---------------------------------------------------------------------------------- objects
    def mesh_object(self):
        """The one mesh object of the scene."""
        meshes = [o for o in self.scene.objects if o.type == "MESH"]
        if len(meshes) != 1:
            raise AssertionError(f"{self.path}: expected one mesh object, found {[o.name for o in meshes]}")
        return meshes[0]

    def vertex_order(self, reference: np.ndarray, frame: float, *, tol: float = 1e-4) -> np.ndarray:
        """For each vertex of ``reference``, the Blender vertex to read.

        Parameters
        ----------
        reference : (V, 3) float
            Our vertices (metres, our axes, world space) as they should be at scene ``frame``.
        frame : float
            The scene frame at which Blender's evaluated vertices are matched to ``reference``.
        tol : float
            Metres: every reference vertex needs a Blender vertex this close.

        Returns
        -------
        (V,) int
            The identity when Blender's vertices are ours in order; otherwise the nearest Blender
            vertex (seam-split copies of a vertex share its position).
        """
        ref = np.asarray(reference, np.float64)
        got = self._evaluated(float(frame))
        if len(got) == len(ref) and np.abs(got - ref).max() <= tol:
            return np.arange(len(ref))
        d, idx = cKDTree(got).query(ref)
        if d.max() > tol:
            raise AssertionError(f"{self.path}: at frame {frame:g}, reference vertex {int(np.argmax(d))} has no "
                                 f"Blender vertex within {tol} m (nearest {d.max():.3g} m)")
        return idx

    def _evaluated(self, frame: float) -> np.ndarray:
        """(V', 3) Blender's evaluated world-space vertices at ``frame``, our axes (Blender's order)."""
        obj = self.mesh_object()
        _frame_set(frame)
        dg = bpy.context.evaluated_depsgraph_get()
        ev = obj.evaluated_get(dg)
        me = ev.to_mesh()
        try:
            co = np.empty(len(me.vertices) * 3, np.float32)
            me.vertices.foreach_get("co", co)
        finally:
            ev.to_mesh_clear()
        M = np.array(ev.matrix_world)
        return to_ours(co.reshape(-1, 3).astype(np.float64) @ M[:3, :3].T + M[:3, 3])

    def vertices(self, frames, reference=None, order: np.ndarray | None = None) -> np.ndarray:
        """(F, V, 3) evaluated world-space vertices at scene ``frames``, metres, our axes.

        Parameters
        ----------
        frames : (F,) float
            Scene frames (fractional frames are evaluated as subframes).
        reference : (V, 3) float, optional
            Our expected vertices at ``frames[0]`` (metres, world space): the result is in their
            order (:meth:`vertex_order`).  Without it (and without ``order``), Blender's order.
        order : (V,) int, optional
            A precomputed order instead of ``reference``.
        """
        frames = np.asarray(frames, np.float64).reshape(-1)
        if order is None and reference is not None:
            order = self.vertex_order(reference, frames[0])
        out = [self._evaluated(float(f)) for f in frames]
        return np.stack(out) if order is None else np.stack(out)[:, order]

    # ---------------------------------------------------------------------------------- head
    def _head(self, name: str):
        """(object, bone name or None) of the head: an object, or a bone of an armature."""
        for o in self.scene.objects:
            if o.type == "ARMATURE":
                for b in o.data.bones:
                    if b.name.lower() == name.lower():
                        return o, b.name
        for o in self.scene.objects:
            if o.name.lower() == name.lower():
                return o, None
        raise AssertionError(f"{self.path}: no object or bone named '{name}'")

    def head_rotations(self, frames, name: str = "head") -> np.ndarray:
        """(F, 4) world rotation of the head relative to its rest pose, quaternions x, y, z, w, our axes.

        For a bone: ``world(pose) @ world(rest)^-1`` (the armature's world matrix times the pose
        bone's matrix, against the bone's rest matrix); for an object (the glTF ``head`` node): its
        world rotation.
        """
        obj, bone = self._head(name)
        R = []
        for f in np.asarray(frames, np.float64).reshape(-1):
            _frame_set(float(f))
            dg = bpy.context.evaluated_depsgraph_get()
            ev = obj.evaluated_get(dg)
            W = np.array(ev.matrix_world)[:3, :3]
            if bone is None:
                Rb = W
            else:
                pose = np.array(ev.pose.bones[bone].matrix)[:3, :3]
                rest = np.array(obj.data.bones[bone].matrix_local)[:3, :3]
                Rb = (W @ pose) @ np.linalg.inv(W @ rest)
            # strip scale (an FBX import may scale the armature object)
            u, _, vt = np.linalg.svd(Rb)
            R.append(AXES.T @ (u @ vt) @ AXES)
        return Rotation.from_matrix(np.stack(R)).as_quat()

    # ---------------------------------------------------------------------------------- keys
    def shape_keys(self) -> dict[str, ShapeKeyTrack]:
        """Every shape key of the mesh (the Basis excluded): keyed values and slider range."""
        obj = self.mesh_object()
        key = obj.data.shape_keys
        if key is None:
            return {}
        curves = {fc.data_path: fc for fc in _fcurves(key)}
        out = {}
        for kb in key.key_blocks[1:]:
            fc = curves.get(f'key_blocks["{bpy.utils.escape_identifier(kb.name)}"].value')
            if fc is None:
                fr = vals = np.zeros(0)
            else:
                co = np.empty(len(fc.keyframe_points) * 2, np.float32)
                fc.keyframe_points.foreach_get("co", co)
                fr, vals = co.reshape(-1, 2).T.astype(np.float64)
            out[kb.name] = ShapeKeyTrack(fr, vals, float(kb.slider_min), float(kb.slider_max))
        return out

    def sound_strips(self) -> list:
        """The sound strips of the scene's sequencer."""
        ed = self.scene.sequence_editor
        if ed is None:
            return []
        strips = ed.strips_all if hasattr(ed, "strips_all") else ed.sequences_all
        return [s for s in strips if s.type == "SOUND"]


def _fcurves(id_) -> list:
    """The F-curves animating ``id_`` (its action's slot; legacy actions too)."""
    ad = id_.animation_data
    if ad is None or ad.action is None:
        return []
    action = ad.action
    slot = getattr(ad, "action_slot", None)
    if slot is not None and getattr(action, "layers", None):
        for layer in action.layers:
            for strip in layer.strips:
                bag = strip.channelbag(slot)
                if bag is not None:
                    return list(bag.fcurves)
        return []
    return list(action.fcurves)
