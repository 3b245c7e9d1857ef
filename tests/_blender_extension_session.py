"""One session of a fresh headless Blender 4.5 with the extension installed from its zip (run by
tests/test_blender_extension.py in a child process; writes a JSON report the tests check).

The child plays Blender 4.5's Python: ``python -S`` (no site-packages) with only NumPy 1.26.4 (the
NumPy Blender ships), the ``bpy`` module and the standard library on ``sys.path``; the extension's
wheels (faceretarget, SciPy, MediaPipe, ...) come from the zip, installed by Blender's own extension
installer into a temporary user folder with online access off.  Every operator then runs on every
shared character opened in Blender, and what it keys is compared with the library's own functions
run here on the same inputs.

Usage (the test does this)::

    python -S tests/_blender_extension_session.py --zip ZIP --data ../shared/data --work DIR --out report.json
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import threading
import time
import traceback
from pathlib import Path

import numpy as np

MODULE = "bl_ext.user_default.faceretarget"
VIDEO = "video/WDA_AOC_000.mp4"           # 200 frames at 25 fps
OTHER_VIDEO = "video/WDA_KatieHill_000.mp4"
LLF = "livelinkface/MySlate_3_Jason_Millers_iPhone.csv"


class Session:
    def __init__(self, args):
        self.a = args
        self.data = Path(args.data)
        self.work = Path(args.work)
        self.work.mkdir(parents=True, exist_ok=True)
        self.report: dict = {"characters": {}}
        self.ticks: list[tuple[float, float, str]] = []

    # ---------------------------------------------------------------------------------- setup
    def install(self) -> None:
        import importlib

        import bpy

        addon_utils = importlib.import_module("addon_utils")     # on sys.path once bpy is imported
        self.bpy = bpy
        r = self.report["install"] = {"numpy": np.__version__, "bpy": bpy.app.version_string}
        prefs = bpy.context.preferences
        prefs.system.use_online_access = False
        t0 = time.perf_counter()
        res = bpy.ops.extensions.package_install_files(filepath=str(self.a.zip), repo="user_default",
                                                       enable_on_install=True)
        r["seconds"] = round(time.perf_counter() - t0, 2)
        r["result"] = sorted(res)
        r["enabled"] = MODULE in prefs.addons
        addon_utils.enable(MODULE, default_set=True)
        self.ext = sys.modules[MODULE]
        import faceretarget

        r["library"] = faceretarget.__file__
        r["library_from_extension"] = "/extensions/.local/" in faceretarget.__file__
        import numpy

        r["numpy_after"] = numpy.__version__
        r["numpy_file"] = numpy.__file__
        r["imports"] = self.import_wheels(Path(faceretarget.__file__).parents[1])
        self.jobs = self.ext.jobs
        self.jobs.tick_hooks.append(lambda wall, cpu, what: self.ticks.append((wall, cpu, what)))

    def import_wheels(self, site: Path) -> dict:
        """Every top-level module of every wheel the extension installed, imported here beside NumPy 1.26.4."""
        import importlib
        import importlib.metadata

        done, failed = [], {}
        for dist in importlib.metadata.distributions(path=[str(site)]):
            top = (dist.read_text("top_level.txt") or "").split()
            if not top:                                    # no top_level.txt: the packages among its files
                top = sorted({f.parts[0].removesuffix(".py") for f in dist.files or []
                              if f.parts and not f.parts[0].endswith((".dist-info", ".data", ".libs"))
                              and (f.suffix == ".py" or len(f.parts) > 1)})
            for mod in top:
                if mod.startswith("_") or "/" in mod or mod in ("tests", "test", "docs", "examples"):
                    continue
                try:
                    importlib.import_module(mod)
                    done.append(mod)
                except Exception as e:  # noqa: BLE001 - the report names it
                    failed[mod] = f"{type(e).__name__}: {str(e)[:200]}"
        return {"imported": sorted(done), "failed": failed}

    def fresh(self) -> None:
        self.bpy.ops.wm.read_homefile(use_empty=True)

    # ---------------------------------------------------------------------------------- characters
    def characters(self) -> dict[str, tuple[str, Path]]:
        from faceretarget.io import read_rig, write_glb, write_plain_glb

        out = {}
        for p in sorted((self.data / "characters" / "valid").glob("*.glb")):
            out[p.stem] = ("glb", write_plain_glb(p, self.work / f"{p.stem}.plain.glb"))
        fbx = self.data / "characters" / "rocketbox" / "Female_Adult_01_facial.fbx"
        out[fbx.stem] = ("fbx", fbx)
        for name in ("ict-face", "arkit-face"):
            rig = read_rig(self.data / name)
            p = self.work / f"{name}.glb"
            write_glb(p, rig, np.zeros((1, rig.n_shapes)), np.zeros(1))
            out[name] = ("glb", p)
        if self.a.only:
            out = {k: v for k, v in out.items() if k in self.a.only.split(",")}
        return out

    def open_character(self, kind: str, path: Path) -> list:
        bpy = self.bpy
        self.fresh()
        if kind == "glb":
            bpy.ops.import_scene.gltf(filepath=str(path))
        else:
            bpy.ops.import_scene.fbx(filepath=str(path))
        arms = [o for o in bpy.context.scene.objects if o.type == "ARMATURE"]
        meshes = [o for o in bpy.context.scene.objects if o.type == "MESH" and o.data.shape_keys is not None]
        for o in bpy.context.scene.objects:
            o.select_set(False)
        sel = arms or meshes
        for o in sel:
            o.select_set(True)
        bpy.context.view_layer.objects.active = sel[0]
        bpy.ops.ed.undo_push(message="character opened")
        return [o.name for o in sel]

    # ---------------------------------------------------------------------------------- helpers
    def run_op(self, op, **kw) -> dict:
        """Run an operator and drive its job to the end; the job's outcome."""
        st = self.bpy.context.window_manager.faceretarget_state
        st.report = ""
        n0 = len(self.ticks)
        t0 = time.perf_counter()
        c0 = time.thread_time()
        res = op(**kw)
        op_wall, op_cpu = time.perf_counter() - t0, time.thread_time() - c0
        self.jobs.drive(timeout=900)
        ticks = self.ticks[n0:]
        job = self.jobs.last_job
        return {"result": sorted(res), "report": st.report, "kind": st.report_kind,
                "slowest_step": None if job is None else [round(job.slowest[0] * 1000, 1),
                                                           round(job.slowest[1] * 1000, 1), job.slowest[2]],
                "seconds": round(time.perf_counter() - t0, 2), "op_ms": round(op_wall * 1000, 1),
                "op_cpu_ms": round(op_cpu * 1000, 1), "ticks": len(ticks),
                "max_tick_ms": round(max((w for w, _, _ in ticks), default=0) * 1000, 1),
                "max_tick_cpu_ms": round(max((c for _, c, _ in ticks), default=0) * 1000, 1),
                "slowest_tick": _slowest(ticks)}

    def scene_character(self, names: list[str]):
        from faceretarget.characters import apply_landmark_record
        from faceretarget.io import read_blender_scene_character

        objs = [self.bpy.data.objects[n] for n in names]
        ch = read_blender_scene_character(objs)
        rec = next((json.loads(o["faceretarget_landmarks"]) for o in self.bpy.context.scene.objects
                    if "faceretarget_landmarks" in o), None)
        if rec is not None:
            assert apply_landmark_record(ch, rec), "the stored landmarks do not fit the character"
        return ch, rec

    def keyed(self, action) -> dict:
        """``{(object, key block): (frames, values)}`` and head bone curves of an action (layered, slotted)."""
        out = {}
        strip = action.layers[0].strips[0]
        for slot in action.slots:
            bag = strip.channelbag(slot)
            if bag is None:
                continue
            for fc in bag.fcurves:
                co = np.empty(len(fc.keyframe_points) * 2, np.float32)
                fc.keyframe_points.foreach_get("co", co)
                co = co.reshape(-1, 2)
                out[(slot.name_display, fc.data_path, fc.array_index)] = co
        return out

    def compare(self, action, character, chans_W, times, head=None, head_keys=None) -> dict:
        """The keyed shape keys against the library's weights ``(T, C)`` (``chans_W = (channels, W)``)."""
        bpy = self.bpy
        chans, W = chans_W
        keyed = self.keyed(action)
        fps = bpy.context.scene.render.fps / bpy.context.scene.render.fps_base
        frames = 1.0 + (times - times[0]) * fps
        diff, fdiff, n, outside, missing = 0.0, 0.0, 0, 0, []
        for c, ch in enumerate(chans):
            for mi, k in ch.binds:
                m = character.meshes[mi]
                obj = bpy.data.objects[m.ref]
                name = m.shape_names[k]
                dp = f'key_blocks["{bpy.utils.escape_identifier(name)}"].value'
                co = next((v for (slot, path, _i), v in keyed.items() if path == dp and slot == obj.name), None)
                if co is None:
                    missing.append(f"{m.ref}/{name}")
                    continue
                diff = max(diff, float(np.abs(co[:, 1] - W[:, c]).max()))
                fdiff = max(fdiff, float(np.abs(co[:, 0] - frames).max()))
                kb = obj.data.shape_keys.key_blocks[name]
                lo, hi = np.float32(kb.slider_min), np.float32(kb.slider_max)
                outside += int(((co[:, 1] < lo) | (co[:, 1] > hi)).sum())
                n += 1
        out = {"curves": n, "max_diff": diff, "max_frame_diff": fdiff, "outside_slider": outside, "missing": missing[:5],
               "fps": fps, "frame_start": bpy.context.scene.frame_start, "frame_end": bpy.context.scene.frame_end,
               "frames": int(len(times))}
        rot = {k: v for k, v in keyed.items() if k[1].endswith("rotation_quaternion")}
        out["head_curves"] = len(rot)
        if rot:
            bones = sorted({k[1] for k in rot})
            q = np.stack([rot[(next(s for (s, p, i) in rot if p == bones[0]), bones[0], i)][:, 1] for i in range(4)], 1)
            q = q / np.linalg.norm(q, axis=1, keepdims=True)
            ang = 2 * np.degrees(np.arccos(np.clip(np.abs(q @ q[0]), -1, 1)))
            out["head_bone"] = bones[0]
            out["head_range_deg"] = float(ang.max())
            if head_keys is not None:
                out["head_max_diff"] = max(
                    float(np.abs(rot[(s, p, i)][:, 1] - head_keys[p][:, i]).max()) for (s, p, i) in rot if p in head_keys)
        ed = bpy.context.scene.sequence_editor
        strips = [] if ed is None else [s for s in ed.strips if s.name.startswith("faceretarget audio")]
        out["sound_frames"] = int(strips[0].frame_final_duration) if strips else 0
        out["sound_packed"] = bool(strips and strips[0].sound.packed_file is not None)
        return out

    def head_reference(self, character, head, neck_share=0.0) -> dict:
        from faceretarget.io import head_bones

        keys = {}
        for hb in head_bones(character, neck_share):
            keys[f'pose.bones["{self.bpy.utils.escape_identifier(hb.pose_bone.name)}"].rotation_quaternion'] = \
                hb.quaternions(head.rotation)
        return keys

    def action_of(self, names: list[str]):
        for o in self.bpy.context.scene.objects:
            if o.type == "MESH" and o.data.shape_keys is not None and o.data.shape_keys.animation_data:
                a = o.data.shape_keys.animation_data.action
                if a is not None and "faceretarget_source" in a:
                    return a
        return None

    # ---------------------------------------------------------------------------------- the operators
    def animate(self, name: str, names: list[str], cap) -> dict:
        from faceretarget.pipelines import animate

        bpy = self.bpy
        sc = bpy.context.scene
        before = {"fps": sc.render.fps, "frame_end": sc.frame_end, "actions": len(bpy.data.actions)}
        r = self.run_op(bpy.ops.faceretarget.animate_video, filepath=str(self.data / VIDEO))
        action = self.action_of(names)
        r["ok"] = action is not None
        if action is None:
            return r
        ch, rec = self.scene_character(names)
        r["landmarks"] = None if rec is None else rec["source"]
        # the library's animate on the same inputs: the video's capture, the character as the scene holds it
        # (with the stored landmarks), here in this process
        bpy.ops.ed.undo()
        sc = bpy.context.scene                             # undo replaced the scene's data
        undone = {"fps": sc.render.fps, "frame_end": sc.frame_end, "actions": len(bpy.data.actions),
                  "ours": [a.name for a in bpy.data.actions if "faceretarget_source" in a]}
        r["undo"] = undone
        r["undo_ok"] = (undone["fps"] == before["fps"] and undone["frame_end"] == before["frame_end"]
                        and not undone["ours"])
        ch, _ = self.scene_character(names)
        ref = animate(cap, ch)
        head_keys = self.head_reference(ch, ref.head) if ref.head is not None else None
        bpy.ops.ed.redo()
        action = self.action_of(names)
        r["redo_ok"] = action is not None
        ch, _ = self.scene_character(names)
        r.update(self.compare(action, ch, (ref.drive.channels, ref.drive.full_weights(ref.weights)), ref.times,
                              head_keys=head_keys))
        r["driven"] = len(ref.drive.choice.drive)
        r["mouth_corr"] = ref.mouth_corr
        return r

    def take(self, name: str, names: list[str], path: Path, route: str = "auto", source_keys: Path | None = None,
             expect_error: bool = False) -> dict:
        from faceretarget.pipelines import apply_take

        bpy = self.bpy
        s = bpy.context.scene.faceretarget
        s.take_route = route
        s.source_keys = str(source_keys) if source_keys else ""
        r = self.run_op(bpy.ops.faceretarget.apply_take, filepath=str(path))
        action = self.action_of(names)
        src = json.loads(action["faceretarget_source"]) if action is not None else {}
        r["ok"] = action is not None and src.get("take") == str(path)
        if not r["ok"] or expect_error:
            return r
        r["route"] = src.get("route")
        ch, _ = self.scene_character(names)
        ref = self._take_reference(path, ch, r["route"], source_keys)
        r.update(self.compare(action, ch, (ref[0], ref[1]), ref[2]))
        r["same_as_apply_take"] = float(np.abs(apply_take(path, ch, route=r["route"], source_keys=source_keys).weights
                                               - ref[1]).max())
        bpy.ops.ed.undo()
        return r

    def _take_reference(self, path: Path, ch, route: str, source_keys):
        """The library's clone / retarget / animate on the take, composed as the command line does."""
        from faceretarget.character import channels
        from faceretarget.characters import character_weights, drive_rig
        from faceretarget.cloning import keymodel_pair
        from faceretarget.datasets import make_demo_character
        from faceretarget.io import read_keys, read_performance
        from faceretarget.performance import Performance
        from faceretarget.pipelines import animate, arkit_curves, clone_take, landmark_points, retarget_take

        perf = read_performance(path)
        if route == "clone":
            drive = drive_rig(ch, "arkit", need_landmarks=False)
            src = make_demo_character("ada")
            sk, tk, _ = keymodel_pair(src, drive.rig, "arkit")
            W, names = arkit_curves(clone_take(perf, sk, tk, source_rig=src))
            return drive.channels, character_weights(drive, W, names), perf.times
        if route == "retarget":
            drive = drive_rig(ch, "arkit", need_landmarks=False)
            sk, labels = read_keys(source_keys)
            sk, tk, _ = keymodel_pair(sk, drive.rig, "arkit")
            W, names = arkit_curves(retarget_take(perf, sk, tk, source_labels=labels))
            return drive.channels, character_weights(drive, W, names), perf.times
        if perf.kind == "weights":
            src = make_demo_character("ada")
            pts = src.evaluate(src.map_weights(perf.names, perf.weights, warn=False), src.landmarks)
            tracked = perf.replace(points=pts, labels=[f"lm{i}" for i in range(68)], unit=src.unit)
        else:
            tracked = Performance(perf.times, perf.fps, points=landmark_points(perf), labels=[f"lm{i}" for i in range(68)],
                                  unit=perf.unit, head=perf.head, source=perf.source)
        res = animate(tracked, ch, head="video" if perf.head is not None else "off")
        assert len(res.drive.channels) == len(channels(ch))
        return res.drive.channels, res.drive.full_weights(res.weights), res.times

    def emotion(self, name: str, names: list[str], cap, style: Path) -> dict:
        from faceretarget.pipelines import animate
        from faceretarget.style import StyleModel

        bpy = self.bpy
        r0 = self.run_op(bpy.ops.faceretarget.animate_video, filepath=str(self.data / VIDEO))
        r = {"animate": r0["report"]}
        rl = self.run_op(bpy.ops.faceretarget.load_style, filepath=str(style))
        s = bpy.context.scene.faceretarget
        r["emotions"] = [e.name for e in s.emotions]
        r["load_report"] = rl["report"]
        for e in s.emotions:
            e.amount = 0.6 if e.name == "angry" else 0.0
        r.update(self.run_op(bpy.ops.faceretarget.emotion_resolve))
        action = self.action_of(names)
        src = json.loads(action["faceretarget_source"]) if action is not None else {}
        r["ok"] = src.get("emotion") == {"angry": 0.6}       # as the extension rounds a slider (4 decimals)
        if not r["ok"]:
            return r
        ch, _ = self.scene_character(names)
        ref = animate(cap, ch, emotion={"angry": 0.6}, style=StyleModel.load(style))
        plain = animate(cap, ch)
        r.update(self.compare(action, ch, (ref.drive.channels, ref.drive.full_weights(ref.weights)), ref.times))
        r["emotion_change"] = float(np.abs(ref.weights - plain.weights).max())
        bpy.ops.ed.undo()
        bpy.ops.ed.undo()
        return r

    def live(self, name: str, names: list[str], frames: int | None) -> dict:
        bpy = self.bpy
        s = bpy.context.scene.faceretarget
        s.live_source = "video"
        s.live_video = str(self.data / VIDEO)
        st = bpy.context.window_manager.faceretarget_state
        obj = next(o for o in bpy.context.scene.objects if o.type == "MESH" and o.data.shape_keys is not None
                   and len(o.data.shape_keys.key_blocks) > 20)
        before = np.empty(len(obj.data.shape_keys.key_blocks), np.float32)
        obj.data.shape_keys.key_blocks.foreach_get("value", before)
        n0 = len(self.ticks)
        bpy.ops.faceretarget.live_start()
        job = self.jobs.running("Live")[0]
        moved = {"max": 0.0, "evaluated_m": 0.0}

        def evaluated() -> np.ndarray:
            me = obj.evaluated_get(bpy.context.evaluated_depsgraph_get()).data
            co = np.empty(len(me.vertices) * 3, np.float32)
            me.vertices.foreach_get("co", co)
            return co.reshape(-1, 3)

        rest = evaluated()

        def watch():
            now = np.empty_like(before)
            obj.data.shape_keys.key_blocks.foreach_get("value", now)
            moved["max"] = max(moved["max"], float(np.abs(now - before).max()))
            if st.live_frames and st.live_frames % 25 == 0:       # what the viewport draws moves too
                moved["evaluated_m"] = max(moved["evaluated_m"], float(np.abs(evaluated() - rest).max()))
            return frames is not None and st.live_frames >= frames

        self.jobs.drive(until=watch, timeout=120)
        stopped = None
        if job.status == "running":
            bpy.ops.faceretarget.live_stop()
            stopped = time.perf_counter()
        self.jobs.drive(timeout=30)
        after = np.empty_like(before)
        obj.data.shape_keys.key_blocks.foreach_get("value", after)
        stats = getattr(job, "live_stats", {}) or {}
        ticks = self.ticks[n0:]
        pid = getattr(job, "live_pid", None)
        return {"ok": job.status == "done", "report": st.report, "viewport_fps": stats.get("viewport_fps"),
                "applied": stats.get("applied"), "worker_fps": stats.get("fps"), "processed": stats.get("processed"),
                "dropped": stats.get("dropped"), "worker_stages_ms": stats.get("stages_ms"),
                "apply_ms": stats.get("apply_ms"), "moved": moved["max"], "evaluated_moved_m": moved["evaluated_m"], "restored": float(np.abs(after - before).max()),
                "stop_seconds": None if stopped is None else round(time.perf_counter() - stopped, 2),
                "live_worker_gone": pid is not None and not _alive(pid), "live_flag": st.live,
                "threads": [t.name for t in threading.enumerate() if t.name.startswith("faceretarget") and t.is_alive()
                            and t.name != "faceretarget-worker-reader"],
                "max_tick_ms": round(max((w for w, _, _ in ticks), default=0) * 1000, 1),
                "max_tick_cpu_ms": round(max((c for _, c, _ in ticks), default=0) * 1000, 1),
                "slowest_tick": _slowest(ticks)}

    def landmarks(self, name: str, names: list[str]) -> dict:
        bpy = self.bpy
        r = self.run_op(bpy.ops.faceretarget.landmarks_show)
        ov = bpy.data.objects.get("faceretarget landmarks")
        r["overlay_points"] = 0 if ov is None else len(ov.data.vertices)
        if ov is None:
            return r
        co = np.empty(68 * 3, np.float32)
        ov.data.vertices.foreach_get("co", co)
        P = co.reshape(68, 3).astype(np.float64)
        # move the nose tip 4 mm to the character's left (along the line of the outer eye corners)
        side = P[45] - P[36]
        side /= np.linalg.norm(side)
        ov.data.vertices[30].co = tuple(P[30] + 0.004 * side)
        r2 = self.run_op(bpy.ops.faceretarget.landmarks_accept)
        ch, rec = self.scene_character(names)
        new = ch.landmark_positions()
        r["accept_report"] = r2["report"]
        r["source"] = rec["source"] if rec else None
        r["moved_mm"] = float(np.linalg.norm(new[30] - P[30]) * 1000)
        r["to_target_mm"] = float(np.linalg.norm(new[30] - (P[30] + 0.004 * side)) * 1000)
        r["others_moved_mm"] = float(np.linalg.norm(np.delete(new - P, 30, axis=0), axis=1).max() * 1000)
        bpy.ops.faceretarget.landmarks_hide()
        r["overlay_after_hide"] = bpy.data.objects.get("faceretarget landmarks") is not None
        return r

    # ---------------------------------------------------------------------------------- the rest
    def cancel(self, names: list[str]) -> dict:
        bpy = self.bpy
        actions = {a.name for a in bpy.data.actions}
        bpy.ops.faceretarget.animate_video(filepath=str(self.data / OTHER_VIDEO))
        job = self.jobs.running()[0]
        self.jobs.drive(until=lambda: job.progress > 0.2 and job.stage == "capture", timeout=120)
        pid = self.jobs.worker_pid()
        t0 = time.perf_counter()
        bpy.ops.faceretarget.cancel()
        self.jobs.drive(timeout=10)
        gone = pid is not None and not _alive(pid)
        return {"stage_at_cancel": job.stage, "progress_at_cancel": round(job.progress, 3), "status": job.status,
                "worker_gone": gone, "seconds": round(time.perf_counter() - t0, 3),
                "new_actions": sorted({a.name for a in bpy.data.actions} - actions),
                "report": bpy.context.window_manager.faceretarget_state.report}

    def unregister(self) -> dict:
        import addon_utils

        bpy = self.bpy
        pid = self.jobs.worker_pid()
        tick = self.jobs._tick
        addon_utils.disable(MODULE, default_set=True)
        time.sleep(0.5)
        left = [n for n in dir(bpy.types) if n.startswith("FACERETARGET_")]
        return {"worker_was": pid, "worker_gone": pid is None or not _alive(pid),
                "classes_left": left, "scene_prop": hasattr(bpy.types.Scene, "faceretarget"),
                "wm_prop": hasattr(bpy.types.WindowManager, "faceretarget_state"),
                "operators_left": [n for n in dir(bpy.ops.faceretarget) if not n.startswith("_")],
                "timer": bpy.app.timers.is_registered(tick),
                "threads": [t.name for t in threading.enumerate() if t.name.startswith("faceretarget") and t.is_alive()],
                "children": _children()}

    # ---------------------------------------------------------------------------------- inputs
    def inputs(self) -> dict:
        """The takes (a 68-point C3D and a vertex .npz played from a real Live Link Face take on the ARKit
        face) and a style model fitted on MEAD videos, made here with the installed library."""
        from faceretarget.io import read_performance, read_rig, write_animation, write_c3d
        from faceretarget.performance import Performance
        from faceretarget.pipelines import capture_take, face_takes, fit_style

        rig = read_rig(self.data / "arkit-face")
        llf = read_performance(self.data / LLF)
        W = rig.map_weights(llf.names, llf.weights, warn=False)
        T = min(len(W), 120)
        t = np.arange(T) / 30.0
        pts = rig.evaluate(W[:T], rig.landmarks) * 1000.0          # metres -> mm
        c3d = write_c3d(self.work / "arkit68.c3d", Performance(t, 30.0, points=pts, labels=[f"lm{i}" for i in range(68)],
                                                                unit="mm", source="arkit68"))
        npz = self.work / "arkit_vertices.npz"
        write_animation(npz, rig=rig, weights=W[:T], names=list(rig.names), times=t)
        bad = self.work / "bad_take.csv"
        bad.write_text("this,is,not\na,take,at all\n")
        mead = self.data / "emotion-video" / "mead"
        vids = {e: mead / f"M030_front_{e}_level{1 if e == 'neutral' else 3}_001.mp4" for e in ("neutral", "angry", "happy")}
        import warnings

        t0 = time.perf_counter()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            style = fit_style(face_takes(vids), reference="neutral").save(self.work / "style.npz")
        style_s = time.perf_counter() - t0
        t0 = time.perf_counter()
        cap = capture_take(self.data / VIDEO, neutral_percentile=5.0)
        self.report["inputs"] = {"style_seconds": round(style_s, 1), "capture_seconds": round(time.perf_counter() - t0, 1),
                                 "capture_frames": cap.n_frames}
        return {"c3d": c3d, "npz": npz, "bad": bad, "style": Path(style), "cap": cap, "llf": self.data / LLF,
                "arkit": self.data / "arkit-face"}

    def run(self) -> dict:
        print("installing the extension", flush=True)          # progress lines for the test's heartbeat
        self.install()
        if self.a.after_install:                              # a check that needs the extension installed
            job = json.loads(Path(self.a.after_install).read_text())
            print("the library beside the installed extension", flush=True)
            res = subprocess.run(job["cmd"], env=job["env"], capture_output=True, text=True, timeout=600)
            self.report["after_install"] = {"returncode": res.returncode, "stdout": res.stdout[-20000:],
                                            "stderr": res.stderr[-3000:]}
        inp = self.inputs()
        chars = self.characters()
        first = True
        for i, (name, (kind, path)) in enumerate(chars.items()):
            print(f"character {i + 1}/{len(chars)}: {name}", flush=True)
            rep = self.report["characters"][name] = {}
            try:
                t0 = time.perf_counter()
                names = self.open_character(kind, path)
                rep["objects"] = names
                rep["animate"] = self.animate(name, names, inp["cap"])
                if first:                                  # animate(video) = animate(its capture): the reference's input
                    from faceretarget.pipelines import animate

                    ch, _ = self.scene_character(names)
                    a = animate(self.data / VIDEO, ch).weights
                    b = animate(inp["cap"], ch).weights
                    rep["video_equals_capture"] = float(np.abs(a - b).max())
                rep["take_llf"] = self.take(name, names, inp["llf"])
                rep["take_c3d"] = self.take(name, names, inp["c3d"])
                rep["take_npz"] = self.take(name, names, inp["npz"], source_keys=inp["arkit"],
                                            expect_error=name.startswith(("AIAN", "Black")))
                rep["emotion"] = self.emotion(name, names, inp["cap"], inp["style"])
                rep["landmarks"] = self.landmarks(name, names)
                rep["live"] = self.live(name, names, None if first else 50)    # the whole video on the first
                if first:
                    rep["bad_take"] = self.take(name, names, inp["bad"], expect_error=True)
                    rep["cancel"] = self.cancel(names)
                rep["seconds"] = round(time.perf_counter() - t0, 1)
            except Exception as e:  # noqa: BLE001 - the report says what failed
                rep["exception"] = f"{type(e).__name__}: {e}"
                rep["traceback"] = traceback.format_exc()[-3000:]
            first = False
        self.report["ticks"] = {"n": len(self.ticks), "max_ms": round(max((w for w, _, _ in self.ticks), default=0) * 1000, 1),
                                "max_cpu_ms": round(max((c for _, c, _ in self.ticks), default=0) * 1000, 1),
                                "p99_ms": round(float(np.percentile([w for w, _, _ in self.ticks], 99)) * 1000, 1)
                                if self.ticks else None,
                                "slowest": _slowest(self.ticks), "over_50_ms": sorted(
                                    {what for _, c, what in self.ticks if c > 0.05})}
        self.report["unregister"] = self.unregister()
        self.report["load"] = os.getloadavg()
        return self.report


def _slowest(ticks) -> list | None:
    """The tick that held the main thread longest (CPU ms, wall ms, what it ran)."""
    if not ticks:
        return None
    w, c, what = max(ticks, key=lambda t: t[1])
    return [round(c * 1000, 1), round(w * 1000, 1), what]


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    try:                                               # a zombie child is gone for our purpose
        with open(f"/proc/{pid}/stat") as f:
            return f.read().split()[2] != "Z"
    except OSError:
        return False


def _children() -> list[int]:
    me = os.getpid()
    out = []
    for d in Path("/proc").iterdir():
        if d.name.isdigit():
            try:
                parts = (d / "stat").read_text().split()
                if int(parts[3]) == me and parts[2] != "Z":
                    out.append(int(d.name))
            except (OSError, IndexError, ValueError):
                pass
    return out


def main() -> int:
    import faulthandler

    faulthandler.enable()
    ap = argparse.ArgumentParser()
    ap.add_argument("--zip", required=True)
    ap.add_argument("--data", required=True)
    ap.add_argument("--work", required=True)
    ap.add_argument("--out", required=True)
    ap.add_argument("--only", default="", help="comma-separated character names")
    ap.add_argument("--after-install", default="", help="a JSON file {cmd, env}: a command run once the extension "
                    "is installed, its output kept in the report")
    a = ap.parse_args()
    s = Session(a)
    try:
        report = s.run()
    except Exception as e:  # noqa: BLE001
        s.report["fatal"] = f"{type(e).__name__}: {e}"
        s.report["traceback"] = traceback.format_exc()[-4000:]
        report = s.report
    Path(a.out).write_text(json.dumps(report, indent=1, default=lambda x: x.tolist() if hasattr(x, "tolist") else str(x)))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
