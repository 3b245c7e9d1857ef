"""Settings (saved with the scene) and the running state (the window manager's, never saved)."""

from __future__ import annotations

import bpy
from bpy.props import (
    BoolProperty,
    CollectionProperty,
    EnumProperty,
    FloatProperty,
    IntProperty,
    PointerProperty,
    StringProperty,
)

SHAPES = [("auto", "Auto", "ARKit shapes when the character has at least 10, else every face shape"),
          ("arkit", "ARKit", "The character's ARKit-named shapes"),
          ("visemes", "Visemes", "The character's viseme shapes"),
          ("all", "All", "Every face shape")]
ROUTES = [("auto", "Auto", "Clone a weight take onto ARKit shapes, else solve the 68 landmarks"),
          ("clone", "Clone", "Pyun's cloning with key-models paired by ARKit names (weight takes)"),
          ("retarget", "Retarget", "Chuang's keyshape retargeting (point and vertex takes, with source keys)"),
          ("landmarks", "Landmarks", "The 68 face points solved on the character's own shapes (any character)")]


class FACERETARGET_PG_emotion(bpy.types.PropertyGroup):
    name: StringProperty(name="Emotion")
    amount: FloatProperty(name="Amount", description="Share of this emotion in the face (Eq. 5.1)", min=0.0,
                          max=1.0, default=0.0, subtype="FACTOR")


class FACERETARGET_PG_settings(bpy.types.PropertyGroup):
    shapes: EnumProperty(name="Shapes", items=SHAPES, default="auto",
                         description="Which of the character's shapes the solve drives")
    head: BoolProperty(name="Head motion", default=True, description="Key the tracked head motion on the head bone")
    head_amplitude: FloatProperty(name="Head amplitude", min=0.0, max=3.0, default=1.0,
                                  description="Factor on the head's rotation")
    neck_share: FloatProperty(name="Neck share", min=0.0, max=1.0, default=0.0, subtype="FACTOR",
                              description="Share of the head rotation the neck bone takes")
    take_route: EnumProperty(name="Route", items=ROUTES, default="auto")
    source_rig: StringProperty(name="Source rig", subtype="DIR_PATH",
                               description="The rig a weight take drives (empty: the embedded ARKit demo face)")
    source_keys: StringProperty(name="Source keys", subtype="DIR_PATH",
                                description="Retarget route: a keyshape folder or an ARKit-style rig folder")
    style: StringProperty(name="Style model", subtype="FILE_PATH",
                          description="A style model (.npz) fitted on face takes of emotions ('faceretarget style fit')")
    emotions: CollectionProperty(type=FACERETARGET_PG_emotion)
    live_source: EnumProperty(name="Source", items=[("video", "Video", "A video file played at its pace"),
                                                    ("camera", "Camera", "A camera")], default="video")
    live_video: StringProperty(name="Video", subtype="FILE_PATH")
    camera: IntProperty(name="Camera", min=0, max=16, default=0)


class FACERETARGET_PG_state(bpy.types.PropertyGroup):
    running: BoolProperty(default=False)
    job: StringProperty(default="")
    stage: StringProperty(default="")
    progress: FloatProperty(default=0.0, min=0.0, max=1.0, subtype="FACTOR")
    report: StringProperty(default="")
    report_kind: StringProperty(default="INFO")
    live: BoolProperty(default=False)
    live_fps: FloatProperty(default=0.0)
    live_frames: IntProperty(default=0)


CLASSES = (FACERETARGET_PG_emotion, FACERETARGET_PG_settings, FACERETARGET_PG_state)


def attach() -> None:
    bpy.types.Scene.faceretarget = PointerProperty(type=FACERETARGET_PG_settings)
    bpy.types.WindowManager.faceretarget_state = PointerProperty(type=FACERETARGET_PG_state)


def detach() -> None:
    for owner, name in ((bpy.types.Scene, "faceretarget"), (bpy.types.WindowManager, "faceretarget_state")):
        if hasattr(owner, name):
            delattr(owner, name)
