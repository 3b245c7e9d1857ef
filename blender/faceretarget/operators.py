"""The panel's buttons: each starts a :class:`~.jobs.Job` (reading the scene in steps, the library's work in the
worker process, the result keyed in steps) and returns at once, so Blender never waits on it."""

from __future__ import annotations

import json
import time
from pathlib import Path

import bpy
import numpy as np
from bpy.props import EnumProperty, StringProperty

from . import jobs, scene

_VIDEO_GLOB = "*.mp4;*.mov;*.avi;*.mkv;*.webm;*.m4v;*.flv"
_TAKE_GLOB = "*.csv;*.c3d;*.npz"
#: Custom property on an action this extension keyed: what made it (for Emotion's re-solve).
ACTION_PROP = "faceretarget_source"


def _settings(context):
    return context.scene.faceretarget


def _idle(context) -> bool:
    return scene.has_character(context) and not jobs.running()


def _check_file(op, path: str, what: str) -> Path | None:
    p = Path(bpy.path.abspath(path)) if path else None
    if p is None or not p.is_file():
        op.report({"ERROR"}, f"{path or 'no file'}: {what} not found")
        return None
    return p


# ------------------------------------------------------------------------------------------- results
def _key_result(job, names: list[str], character, done: dict, source: dict, neck_share: float):
    """Steps keying the worker's result as a new action in the open scene; the summary line."""
    from faceretarget.headpose import HeadPose
    from faceretarget.io import scene_action_steps

    if done.get("landmarks"):
        scene.store_landmarks(names, done["landmarks"])
    with np.load(done["result"]) as z:
        W, t = z["weights"], z["times"]
        head = HeadPose(z["head"]) if "head" in z else None
    chans = scene.channels(character, done["channels"])
    yield
    what = Path(source.get("video") or source.get("take") or "take").stem
    steps = scene_action_steps(character, chans, W, t, head=head, neck_share=neck_share, name=f"faceretarget {what}",
                               sound_file=done.get("wav"), where=what, strip_name="faceretarget audio",
                               replace_sound=True)
    while True:
        try:
            f = next(steps)
        except StopIteration as stop:
            action = stop.value
            break
        job.set_progress(0.9 + 0.1 * f, "keying the action")
        yield
    action[ACTION_PROP] = json.dumps(source)
    fps = bpy.context.scene.render.fps / bpy.context.scene.render.fps_base
    return (f"{action.name}: {len(t)} frames at {fps:.4g} fps on {character.name}, {len(done['drive'])} of "
            f"{len(chans)} shape curves driven")


def animate_body(names: list[str], video: str, s, *, emotion: dict | None = None, style: str | None = None):
    params = {"video": video, "shapes": s.shapes, "head": "video" if s.head else "off",
              "head_amplitude": s.head_amplitude, "emotion": emotion, "style": style}
    neck = float(s.neck_share)

    def body(job):
        yield from jobs.wait_library()
        ch = yield from scene.read_character(job, names, 0.0, 0.08)
        saved = yield from scene.save_character(job, ch)
        params.update(character=str(saved), landmarks=scene.stored_landmarks(names))
        yield
        done = yield from jobs.run_in_worker(job, "animate", params, 0.1, 0.9)
        return (yield from _key_result(job, names, ch, done, {"video": video, **{k: v for k, v in params.items()
                                                                                 if k not in ("character", "landmarks")}},
                                       neck))
    return body


def take_body(names: list[str], take: str, s):
    params = {"take": take, "route": s.take_route, "shapes": s.shapes,
              "source_rig": bpy.path.abspath(s.source_rig) if s.source_rig else None,
              "source_keys": bpy.path.abspath(s.source_keys) if s.source_keys else None}
    neck = float(s.neck_share)

    def body(job):
        yield from jobs.wait_library()
        ch = yield from scene.read_character(job, names, 0.0, 0.08)
        saved = yield from scene.save_character(job, ch)
        params.update(character=str(saved), landmarks=scene.stored_landmarks(names))
        yield
        done = yield from jobs.run_in_worker(job, "take", params, 0.1, 0.9)
        job.lines.append(f"route: {done.get('route')}")
        return (yield from _key_result(job, names, ch, done, {"take": take, "route": done.get("route")}, neck))
    return body


def landmarks_body(names: list[str], points: np.ndarray | None = None, accept: bool = False):
    def body(job):
        yield from jobs.wait_library()
        ch = yield from scene.read_character(job, names, 0.0, 0.3)
        saved = yield from scene.save_character(job, ch)
        params = {"character": str(saved), "landmarks": scene.stored_landmarks(names),
                  "points": None if points is None else np.asarray(points).tolist()}
        yield
        done = yield from jobs.run_in_worker(job, "landmarks", params, 0.3, 1.0)
        rec = done["landmarks"]
        if accept:
            rec["source"] = "checked in Blender" if points is None else "moved in Blender"
        if done.get("found") or accept:
            scene.store_landmarks(names, rec)
        obj = scene.show_landmarks(np.asarray(done["positions"]), names)
        obj["faceretarget_shown"] = json.dumps(np.asarray(done["positions"]).round(9).tolist())
        return f"landmarks of {ch.name}: 68 on {done['mesh']} ({rec['source']})"
    return body


def live_body(names: list[str], source, s, state):
    params = {"source": source, "shapes": s.shapes, "head_amplitude": s.head_amplitude, "realtime": True}
    neck = float(s.neck_share)

    def body(job):
        yield from jobs.wait_library()
        ch = yield from scene.read_character(job, names, 0.0, 0.5)
        saved = yield from scene.save_character(job, ch)
        params.update(character=str(saved), landmarks=scene.stored_landmarks(names))
        yield
        w = jobs.Worker(background=False)                # its own process, at full priority: stopping ends it
        job.on_cancel.append(w.kill)
        jid, box = w.submit("live", job.folder, params)
        job.live = {"stop": lambda: w.stop_job(jid), "stopping": None}
        pose = None
        applied, first, last_i = 0, None, -1
        apply_s: list[float] = []
        evaluate = bpy.app.background                    # no viewport to evaluate the scene: do it here
        try:
            while True:
                latest = None
                while True:
                    try:
                        msg = box.get_nowait()
                    except Exception:  # noqa: BLE001 - queue.Empty
                        break
                    if "frame" in msg:
                        latest = msg["frame"]
                    elif "live" in msg:
                        pose = scene.LivePose(ch, msg["live"]["channels"], msg["live"]["drive"], neck)
                        state.live = True
                        job.set_progress(0.5, "live")
                    elif "error" in msg:
                        raise jobs.JobError(msg["error"])
                    elif "log" in msg:
                        job.lines.append(msg["log"])
                    elif "done" in msg:
                        done = msg["done"]
                        if done.get("landmarks"):
                            scene.store_landmarks(names, done["landmarks"])
                        secs = (time.perf_counter() - first) if first else 0.0
                        fps = (applied - 1) / secs if applied > 1 and secs > 0 else 0.0
                        job.live_stats = {"viewport_fps": fps, "applied": applied, **done,
                                          "apply_ms": float(np.median(apply_s) * 1000) if apply_s else None}
                        if pose is not None:
                            pose.restore()
                            pose = None
                        state.live = False
                        yield from w.quit_steps()
                        return (f"live: {applied} frames shown at {fps:.1f} fps (worker: {done['processed']} tracked at "
                                f"{done['fps']:.1f} fps, {done['dropped']} dropped)")
                if latest is not None and pose is not None and latest["i"] != last_i and not latest["cal"]:
                    a = time.perf_counter()
                    pose.apply(np.asarray(latest["w"]), np.asarray(latest["q"]))
                    if evaluate:
                        bpy.context.view_layer.update()
                    apply_s.append(time.perf_counter() - a)
                    last_i = latest["i"]
                    applied += 1
                    now = time.perf_counter()
                    first = first or now
                    state.live_frames = applied
                    state.live_fps = (applied - 1) / (now - first) if now > first else 0.0
                st = job.live["stopping"]
                if st is not None and time.perf_counter() - st > 3.0:
                    w.kill()                             # the session did not end in time
                    raise jobs.JobError("live: the worker did not stop in 3 s and was ended")
                if not w.alive:
                    raise jobs.JobError(f"live: the worker process ended (see {w.log_path})")
                yield jobs.IDLE
        finally:
            w.inbox.pop(jid, None)
            if w.alive:                                  # an error or a cancel: no waiting
                w.kill()
            job.live_pid = w.proc.pid
            state.live = False
            if pose is not None:
                pose.restore()
    return body


# ------------------------------------------------------------------------------------------- operators
class _OnCharacter:
    """Available with a character selected and no job running."""

    bl_options = {"REGISTER"}

    @classmethod
    def poll(cls, context):
        return _idle(context)


class _FileOp:
    filepath: StringProperty(subtype="FILE_PATH")
    filter_glob: StringProperty(default="*", options={"HIDDEN"})

    def invoke(self, context, event):
        context.window_manager.fileselect_add(self)
        return {"RUNNING_MODAL"}


class _CharacterFileOp(_OnCharacter, _FileOp):
    """A file picker whose file a job puts on the selected character (``body(names, path, settings)``)."""

    what = "file"
    label = "{name}"
    undo: str | None = None

    def execute(self, context):
        path = _check_file(self, self.filepath, self.what)
        if path is None:
            return {"CANCELLED"}
        names = scene.character_names(context)
        jobs.submit(jobs.Job(self.label.format(name=path.name), self.body(names, str(path), _settings(context)),
                             undo=self.undo))
        return {"FINISHED"}


class FACERETARGET_OT_animate_video(_CharacterFileOp, bpy.types.Operator):
    """Capture a video of a face and animate the selected character: its own shape keys and head bone, the
    sound as a strip, a new action; the scene's rate and range follow the video"""

    bl_idname = "faceretarget.animate_video"
    bl_label = "Animate from Video"
    filter_glob: StringProperty(default=_VIDEO_GLOB, options={"HIDDEN"})
    what, label, undo = "video", "Animate from {name}", "faceretarget: Animate from video"
    body = staticmethod(animate_body)


class FACERETARGET_OT_apply_take(_CharacterFileOp, bpy.types.Operator):
    """Put a take (Live Link Face CSV, C3D, .npz) on the selected character through the clone, retarget or
    landmark route, as a new action"""

    bl_idname = "faceretarget.apply_take"
    bl_label = "Apply a Take"
    filter_glob: StringProperty(default=_TAKE_GLOB, options={"HIDDEN"})
    what, label, undo = "take", "Apply {name}", "faceretarget: Apply a take"
    body = staticmethod(take_body)


class FACERETARGET_OT_load_style(_FileOp, bpy.types.Operator):
    """Read a style model's emotions into the Emotion sliders"""

    bl_idname = "faceretarget.load_style"
    bl_label = "Load Style Model"
    bl_options = {"REGISTER"}
    filter_glob: StringProperty(default="*.npz", options={"HIDDEN"})

    @classmethod
    def poll(cls, context):
        return not jobs.running()

    def execute(self, context):
        path = _check_file(self, self.filepath, "style model")
        if path is None:
            return {"CANCELLED"}
        scene_name = context.scene.name

        def body(job):
            yield from jobs.wait_library()
            done = yield from jobs.run_in_worker(job, "style_info", {"style": str(path)}, 0.0, 1.0)
            st = bpy.data.scenes[scene_name].faceretarget
            st.style = str(path)
            old = {e.name: e.amount for e in st.emotions}
            st.emotions.clear()
            for name in done["styles"]:
                if name == "neutral":
                    continue
                e = st.emotions.add()
                e.name, e.amount = name, old.get(name, 0.0)
            return f"{path.name}: emotions {', '.join(done['styles'])}"

        jobs.submit(jobs.Job(f"Load {path.name}", body))
        return {"FINISHED"}


def source_action(names: list[str]):
    """The action this extension keyed last on the character (the one its face's shape keys play)."""
    for n in names:
        o = bpy.data.objects.get(n)
        if o is None or o.type != "MESH" or o.data.shape_keys is None:
            continue
        ad = o.data.shape_keys.animation_data
        if ad is not None and ad.action is not None and ACTION_PROP in ad.action:
            return ad.action
    return None


class FACERETARGET_OT_emotion_resolve(bpy.types.Operator):
    """Solve the character's video again with the emotion sliders (Chuang Eq. 5.1) as a new action"""

    bl_idname = "faceretarget.emotion_resolve"
    bl_label = "Re-solve with Emotion"
    bl_options = {"REGISTER"}

    @classmethod
    def poll(cls, context):
        s = _settings(context)
        return _idle(context) and bool(s.style) and len(s.emotions) > 0

    def execute(self, context):
        s = _settings(context)
        names = scene.character_names(context)
        action = source_action(names)
        src = json.loads(action[ACTION_PROP]) if action is not None else {}
        video = src.get("video")
        if not video:
            self.report({"ERROR"}, "the character's action was not made from a video here: Animate from Video first")
            return {"CANCELLED"}
        if not Path(video).is_file():
            self.report({"ERROR"}, f"{video}: the action's video is not found")
            return {"CANCELLED"}
        emotion = {e.name: round(float(e.amount), 4) for e in s.emotions if e.amount > 0}
        jobs.submit(jobs.Job(f"Emotion on {Path(video).name}",
                             animate_body(names, video, s, emotion=emotion, style=bpy.path.abspath(s.style)),
                             undo="faceretarget: Re-solve with emotion"))
        return {"FINISHED"}


class FACERETARGET_OT_live_start(_OnCharacter, bpy.types.Operator):
    """Drive the selected character live from a camera or a video (tracking in the worker process)"""

    bl_idname = "faceretarget.live_start"
    bl_label = "Start Live"

    def execute(self, context):
        s = _settings(context)
        if s.live_source == "camera":
            source = int(s.camera)
            label = f"camera {source}"
        else:
            p = _check_file(self, s.live_video, "video")
            if p is None:
                return {"CANCELLED"}
            source, label = str(p), p.name
        names = scene.character_names(context)
        state = context.window_manager.faceretarget_state
        jobs.submit(jobs.Job(f"Live from {label}", live_body(names, source, s, state)))
        return {"FINISHED"}


class FACERETARGET_OT_live_stop(bpy.types.Operator):
    """Stop live mode: the tracking ends and the character's pose comes back"""

    bl_idname = "faceretarget.live_stop"
    bl_label = "Stop Live"
    bl_options = {"REGISTER"}

    @classmethod
    def poll(cls, context):
        return bool(jobs.running("Live"))

    def execute(self, context):
        for job in jobs.running("Live"):
            live = getattr(job, "live", None)
            if live is not None and live["stopping"] is None:
                live["stopping"] = time.perf_counter()
                live["stop"]()
        return {"FINISHED"}


class FACERETARGET_OT_landmarks_show(_OnCharacter, bpy.types.Operator):
    """Draw the character's 68 landmarks (found automatically on a render when none are stored)"""

    bl_idname = "faceretarget.landmarks_show"
    bl_label = "Show Landmarks"

    def execute(self, context):
        names = scene.character_names(context)
        jobs.submit(jobs.Job("Landmarks", landmarks_body(names), undo="faceretarget: Show landmarks"))
        return {"FINISHED"}


def _overlay_names(context) -> list[str] | None:
    obj = scene.overlay()
    if obj is None or "faceretarget_character" not in obj:
        return None
    return json.loads(obj["faceretarget_character"])


class FACERETARGET_OT_landmarks_move(bpy.types.Operator):
    """Edit the landmark points (move vertices of the overlay, then Accept)"""

    bl_idname = "faceretarget.landmarks_move"
    bl_label = "Move Points"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        return scene.overlay() is not None and not jobs.running()

    def execute(self, context):
        obj = scene.overlay()
        if context.object is not None and context.object.mode != "OBJECT":
            bpy.ops.object.mode_set(mode="OBJECT")
        for o in context.selected_objects:
            o.select_set(False)
        obj.select_set(True)
        context.view_layer.objects.active = obj
        bpy.ops.object.mode_set(mode="EDIT")
        return {"FINISHED"}


class FACERETARGET_OT_landmarks_accept(bpy.types.Operator):
    """Keep the landmarks as shown (moved points put on the face's surface) for every later solve"""

    bl_idname = "faceretarget.landmarks_accept"
    bl_label = "Accept Landmarks"
    bl_options = {"REGISTER"}

    @classmethod
    def poll(cls, context):
        return scene.overlay() is not None and not jobs.running()

    def execute(self, context):
        names = _overlay_names(context)
        if not names:
            self.report({"ERROR"}, "the landmark overlay does not say which character it belongs to; show it again")
            return {"CANCELLED"}
        obj = scene.overlay()
        P = scene.overlay_points()
        if P is None:
            self.report({"ERROR"}, f"{obj.name}: needs its 68 points (a point was deleted); show the landmarks again")
            return {"CANCELLED"}
        if obj.mode == "EDIT":
            bpy.ops.object.mode_set(mode="OBJECT")
        shown = np.asarray(json.loads(obj.get("faceretarget_shown", "[]")), dtype=np.float64).reshape(-1, 3)
        moved = shown.shape != P.shape or float(np.abs(shown - P).max()) > 1e-6
        jobs.submit(jobs.Job("Landmarks", landmarks_body(names, P if moved else None, accept=True),
                             undo="faceretarget: Accept landmarks"))
        return {"FINISHED"}


class FACERETARGET_OT_landmarks_hide(bpy.types.Operator):
    """Remove the landmark overlay (the stored landmarks stay)"""

    bl_idname = "faceretarget.landmarks_hide"
    bl_label = "Hide Landmarks"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        return scene.overlay() is not None

    def execute(self, context):
        scene.hide_landmarks()
        return {"FINISHED"}


class FACERETARGET_OT_cancel(bpy.types.Operator):
    """Stop the running faceretarget job (its worker process is ended; nothing is keyed)"""

    bl_idname = "faceretarget.cancel"
    bl_label = "Cancel"
    bl_options = {"REGISTER"}

    @classmethod
    def poll(cls, context):
        return bool(jobs.running())

    def execute(self, context):
        jobs.cancel_all()
        return {"FINISHED"}


class FACERETARGET_OT_import_gltf(_FileOp, bpy.types.Operator):
    """Import a glTF character, with its meshopt-compressed data decoded first (Blender's glTF importer does
    not read EXT_meshopt_compression)"""

    bl_idname = "faceretarget.import_gltf"
    bl_label = "Import glTF (meshopt)"
    bl_options = {"REGISTER", "UNDO"}
    filter_glob: StringProperty(default="*.glb;*.gltf;*.vrm", options={"HIDDEN"})
    shading: EnumProperty(items=[("NORMALS", "Normals", ""), ("FLAT", "Flat", ""), ("SMOOTH", "Smooth", "")],
                          default="NORMALS", options={"HIDDEN"})

    def execute(self, context):
        import tempfile

        from faceretarget.errors import FaceRetargetError
        from faceretarget.io import write_plain_glb

        src = _check_file(self, self.filepath, "glTF file")
        if src is None:
            return {"CANCELLED"}
        with tempfile.TemporaryDirectory(prefix="faceretarget-gltf-") as d:
            try:
                plain = write_plain_glb(src, Path(d) / f"{src.stem}.glb")
            except FaceRetargetError as e:
                self.report({"ERROR"}, " ".join(str(e).split()))
                return {"CANCELLED"}
            return bpy.ops.import_scene.gltf(filepath=str(plain))


CLASSES = (FACERETARGET_OT_animate_video, FACERETARGET_OT_apply_take, FACERETARGET_OT_load_style,
           FACERETARGET_OT_emotion_resolve, FACERETARGET_OT_live_start, FACERETARGET_OT_live_stop,
           FACERETARGET_OT_landmarks_show, FACERETARGET_OT_landmarks_move, FACERETARGET_OT_landmarks_accept,
           FACERETARGET_OT_landmarks_hide, FACERETARGET_OT_cancel, FACERETARGET_OT_import_gltf)
