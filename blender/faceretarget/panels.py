"""The sidebar panel: View3D > Sidebar > faceretarget."""

from __future__ import annotations

import bpy

from . import jobs, scene


class _Panel:
    bl_space_type = "VIEW_3D"
    bl_region_type = "UI"
    bl_category = "faceretarget"


class FACERETARGET_PT_main(_Panel, bpy.types.Panel):
    bl_idname = "FACERETARGET_PT_main"
    bl_label = "faceretarget"

    def draw(self, context):
        layout = self.layout
        st = context.window_manager.faceretarget_state
        if scene.has_character(context):
            sel = scene.selected_objects(context)
            layout.label(text=f"Character: {sel[0].name}" + (f" (+{len(sel) - 1})" if len(sel) > 1 else ""),
                         icon="OUTLINER_OB_ARMATURE")
        else:
            layout.label(text="Select a character (a mesh with shape keys, or its armature)", icon="INFO")
        if st.running:
            row = layout.row(align=True)
            row.progress(factor=st.progress, type="BAR", text=f"{st.job}: {st.stage}")
            row.operator("faceretarget.cancel", text="", icon="CANCEL")
        if st.report:
            icon = {"ERROR": "ERROR", "WARNING": "ERROR"}.get(st.report_kind, "INFO")
            layout.label(text=st.report, icon=icon)
        layout.operator("faceretarget.import_gltf", icon="IMPORT")


class FACERETARGET_PT_animate(_Panel, bpy.types.Panel):
    bl_parent_id = "FACERETARGET_PT_main"
    bl_label = "Animate from Video"

    def draw(self, context):
        s = context.scene.faceretarget
        col = self.layout.column()
        col.prop(s, "shapes")
        row = col.row(align=True)
        row.prop(s, "head")
        sub = row.row(align=True)
        sub.active = s.head
        sub.prop(s, "head_amplitude", text="Amplitude")
        col.prop(s, "neck_share")
        col.operator("faceretarget.animate_video", icon="FILE_MOVIE")


class FACERETARGET_PT_take(_Panel, bpy.types.Panel):
    bl_parent_id = "FACERETARGET_PT_main"
    bl_label = "Apply a Take"
    bl_options = {"DEFAULT_CLOSED"}

    def draw(self, context):
        s = context.scene.faceretarget
        col = self.layout.column()
        col.prop(s, "take_route")
        col.prop(s, "source_rig")
        col.prop(s, "source_keys")
        col.operator("faceretarget.apply_take", icon="FILE")


class FACERETARGET_PT_emotion(_Panel, bpy.types.Panel):
    bl_parent_id = "FACERETARGET_PT_main"
    bl_label = "Emotion"
    bl_options = {"DEFAULT_CLOSED"}

    def draw(self, context):
        s = context.scene.faceretarget
        col = self.layout.column()
        row = col.row(align=True)
        row.prop(s, "style", text="")
        row.operator("faceretarget.load_style", text="", icon="FILEBROWSER")
        for e in s.emotions:
            col.prop(e, "amount", text=e.name, slider=True)
        if not s.emotions:
            col.label(text="Load a style model to get its emotions")
        col.operator("faceretarget.emotion_resolve", icon="FILE_REFRESH")


class FACERETARGET_PT_live(_Panel, bpy.types.Panel):
    bl_parent_id = "FACERETARGET_PT_main"
    bl_label = "Live"
    bl_options = {"DEFAULT_CLOSED"}

    def draw(self, context):
        s = context.scene.faceretarget
        st = context.window_manager.faceretarget_state
        col = self.layout.column()
        col.prop(s, "live_source", expand=True)
        col.prop(s, "live_video" if s.live_source == "video" else "camera")
        if jobs.running("Live"):
            col.label(text=f"{st.live_frames} frames, {st.live_fps:.1f} fps", icon="REC")
            col.operator("faceretarget.live_stop", icon="PAUSE")
        else:
            col.operator("faceretarget.live_start", icon="PLAY")


class FACERETARGET_PT_landmarks(_Panel, bpy.types.Panel):
    bl_parent_id = "FACERETARGET_PT_main"
    bl_label = "Landmarks Check"
    bl_options = {"DEFAULT_CLOSED"}

    def draw(self, context):
        col = self.layout.column()
        rec = scene.stored_landmarks([o.name for o in scene.selected_objects(context)]) \
            if scene.has_character(context) else None
        col.label(text=f"Stored: {rec['source']} ({rec['mesh']})" if rec else "Not found yet", icon="SHADING_WIRE")
        col.operator("faceretarget.landmarks_show", icon="HIDE_OFF")
        row = col.row(align=True)
        row.operator("faceretarget.landmarks_move", icon="GRAB")
        row.operator("faceretarget.landmarks_accept", icon="CHECKMARK")
        col.operator("faceretarget.landmarks_hide", icon="HIDE_ON")


CLASSES = (FACERETARGET_PT_main, FACERETARGET_PT_animate, FACERETARGET_PT_take, FACERETARGET_PT_emotion,
           FACERETARGET_PT_live, FACERETARGET_PT_landmarks)
