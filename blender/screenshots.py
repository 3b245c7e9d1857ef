"""The pictures of docs/blender-extension.md, made headlessly in a Blender 4.5 with the extension installed.

Blender run as a module has no window, so its user interface (the panel) cannot be captured; what the
extension does to the scene is rendered instead, with Blender's Workbench engine (textures, studio light)
through a camera in front of the character's face:

* ``blender-extension-animate.png``: frames of a CREMA-D video (actor 1001, happy; Open Database License)
  above the same frames of the VALID avatar animated by *Animate from Video* (the action Blender plays: shape
  keys and head bone);
* ``blender-extension-landmarks.png``: *Landmarks Check*: the 68 landmarks found on the avatar drawn on it
  (small spheres at the overlay's points, which Workbench does not draw as a wireframe);
* ``blender-extension-characters.png``: the other shared characters at one frame of the same action.

Run it like the tests run Blender (``python -S`` with NumPy 1.26.4 and bpy; tests/test_blender_extension.py)::

    python -S blender/screenshots.py --zip dist/blender/faceretarget-0.1.0-linux_x64.zip --data ../shared/data \\
        --work /tmp/shots --out docs/img
"""

from __future__ import annotations

import argparse
import importlib
import os
import sys
import time
from pathlib import Path

import numpy as np

# this folder holds the extension's package, also called faceretarget: the library must come from the wheels
sys.path[:] = [p for p in sys.path if Path(p or ".").resolve() != Path(__file__).resolve().parent]
MODULE = "bl_ext.user_default.faceretarget"
#: The video of the pictures: CREMA-D actor 1001, happy (Open Database License; docs/blender-extension.md).
VIDEO = ("emotion-video", "crema-d", "1001_DFA_HAP_XX.flv")


def setup(zip_path: str):
    import bpy

    addon_utils = importlib.import_module("addon_utils")
    bpy.context.preferences.system.use_online_access = False
    bpy.ops.extensions.package_install_files(filepath=zip_path, repo="user_default", enable_on_install=True)
    addon_utils.enable(MODULE, default_set=True)
    return bpy, sys.modules[MODULE]


def open_character(bpy, kind: str, path: Path) -> list[str]:
    bpy.ops.wm.read_homefile(use_empty=True)
    if kind == "glb":
        bpy.ops.import_scene.gltf(filepath=str(path))
    else:
        bpy.ops.import_scene.fbx(filepath=str(path))
    objs = list(bpy.context.scene.objects)
    arms = [o for o in objs if o.type == "ARMATURE"]
    sel = arms or [o for o in objs if o.type == "MESH" and o.data.shape_keys is not None]
    for o in objs:
        o.select_set(o in sel)
    bpy.context.view_layer.objects.active = sel[0]
    return [o.name for o in sel]


def face_camera(bpy, names: list[str], size: int):
    """A camera in front of the face (the stored landmarks' frame), studio light, textured Workbench."""
    import json

    from faceretarget.character import character_frame
    from faceretarget.characters import apply_landmark_record
    from faceretarget.io import read_blender_scene_character

    sc = bpy.context.scene
    objs = [bpy.data.objects[n] for n in names]
    ch = read_blender_scene_character(objs)
    rec = next(json.loads(o["faceretarget_landmarks"]) for o in sc.objects if "faceretarget_landmarks" in o)
    apply_landmark_record(ch, rec)
    P = ch.landmark_positions()
    R = character_frame(ch)                                # world -> head frame (+Y up, +Z out of the face)
    centre = (P.min(0) + P.max(0)) / 2
    extent = float(np.ptp(P, axis=0).max())
    cam_data = bpy.data.cameras.new("shot")
    cam_data.lens = 85
    cam = bpy.data.objects.new("shot", cam_data)
    sc.collection.objects.link(cam)
    z = R[2]
    cam.location = tuple(centre + z * extent * 3.6)
    from mathutils import Matrix

    M = Matrix(np.column_stack([R[0], R[1], R[2]]).tolist()).to_4x4()   # camera looks down -Z: its +Z is the face's
    cam.rotation_euler = M.to_euler()
    sc.camera = cam
    sc.render.engine = "BLENDER_WORKBENCH"
    sc.display.shading.light = "STUDIO"
    sc.display.shading.color_type = "TEXTURE"
    sc.render.resolution_x = sc.render.resolution_y = size
    sc.render.film_transparent = False
    sc.world = sc.world or bpy.data.worlds.new("world")
    return ch, P


def render(bpy, path: Path, frame: int | None = None) -> np.ndarray:
    from PIL import Image

    sc = bpy.context.scene
    if frame is not None:
        sc.frame_set(frame)
    sc.render.filepath = str(path)
    bpy.ops.render.render(write_still=True)
    return np.asarray(Image.open(path).convert("RGB"))


def video_frames(video: Path, frames, size: int) -> list[np.ndarray]:
    """The video's frames (scene frame ``f`` shows video frame ``f - 1``), cropped about the tracked face."""
    from PIL import Image

    from faceretarget.io import iter_frames
    from faceretarget.pipelines import cached_capture

    cap = cached_capture(video, log=lambda *_: None)
    L = cap.landmarks[cap.valid][:, :, :2]
    lo, hi = np.nanmin(L, axis=(0, 1)), np.nanmax(L, axis=(0, 1))
    c, half = (lo + hi) / 2, 0.8 * float((hi - lo).max())
    want = {f - 1 for f in frames}
    out = {}
    for i, _t, rgb in iter_frames(video, max_frames=max(want) + 1):
        if i in want:
            box = (int(c[0] - half), int(c[1] - half), int(c[0] + half), int(c[1] + half))
            out[i] = np.asarray(Image.fromarray(rgb).crop(box).resize((size, size), Image.LANCZOS))
    return [out[f - 1] for f in frames]


def grid(rows: list[list[np.ndarray]], labels: list[str], path: Path) -> None:
    from PIL import Image, ImageDraw

    h, w = rows[0][0].shape[:2]
    pad = 4
    img = Image.new("RGB", (len(rows[0]) * (w + pad) + pad, len(rows) * (h + pad) + pad + 18), (255, 255, 255))
    for r, row in enumerate(rows):
        for c, tile in enumerate(row):
            img.paste(Image.fromarray(tile), (pad + c * (w + pad), 18 + pad + r * (h + pad)))
    d = ImageDraw.Draw(img)
    for c, lab in enumerate(labels):
        d.text((pad + c * (w + pad) + 4, 3), lab, fill=(0, 0, 0))
    img.save(path)


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--zip", required=True)
    ap.add_argument("--data", required=True, type=Path)
    ap.add_argument("--work", required=True, type=Path)
    ap.add_argument("--out", required=True, type=Path)
    ap.add_argument("--size", type=int, default=320)
    a = ap.parse_args()
    a.work.mkdir(parents=True, exist_ok=True)
    a.out.mkdir(parents=True, exist_ok=True)
    bpy, ext = setup(a.zip)
    from faceretarget.io import read_rig, write_glb, write_plain_glb

    video = a.data.joinpath(*VIDEO)
    valid = write_plain_glb(a.data / "characters" / "valid" / "AIAN_F_1_Busi.glb", a.work / "AIAN.glb")
    names = open_character(bpy, "glb", valid)

    # the landmarks check first, on the character at rest: the overlay's 68 points as small spheres
    # (Workbench draws no wireframe in a rendered picture)
    bpy.ops.faceretarget.landmarks_show()
    ext.jobs.drive(timeout=300)
    print(bpy.context.window_manager.faceretarget_state.report)
    ov = bpy.data.objects["faceretarget landmarks"]
    co = np.empty(68 * 3, np.float32)
    ov.data.vertices.foreach_get("co", co)
    face_camera(bpy, names, a.size)
    extent = float(np.ptp(co.reshape(68, 3), axis=0).max())
    mat = bpy.data.materials.new("landmark")
    mat.diffuse_color = (0.1, 0.9, 0.2, 1.0)
    dots = []
    for i, p in enumerate(co.reshape(68, 3)):
        bpy.ops.mesh.primitive_uv_sphere_add(radius=extent * 0.012, location=tuple(p), segments=12, ring_count=6)
        s = bpy.context.active_object
        s.name = f"lm{i}"
        s.data.materials.append(mat)
        dots.append(s)
    bpy.context.scene.display.shading.color_type = "MATERIAL"
    lm = render(bpy, a.work / "landmarks.png")
    grid([[lm]], ["68 landmarks found on the avatar"], a.out / "blender-extension-landmarks.png")
    for s in dots:
        bpy.data.objects.remove(s)
    bpy.ops.faceretarget.landmarks_hide()
    bpy.context.scene.display.shading.color_type = "TEXTURE"
    for o in bpy.context.scene.objects:
        o.select_set(o.name in names)
    bpy.context.view_layer.objects.active = bpy.data.objects[names[0]]

    t0 = time.perf_counter()
    bpy.ops.faceretarget.animate_video(filepath=str(video))
    ext.jobs.drive(timeout=900)
    print(bpy.context.window_manager.faceretarget_state.report, f"{time.perf_counter() - t0:.1f} s")
    end = bpy.context.scene.frame_end
    frames = [int(round(x)) for x in np.linspace(1 + 0.1 * end, 0.9 * end, 5)]
    shots = [render(bpy, a.work / f"valid_{f}.png", f) for f in frames]
    vids = video_frames(video, frames, a.size)
    grid([vids, shots], [f"frame {f}" for f in frames], a.out / "blender-extension-animate.png")

    # the other characters at one frame of the same video
    tiles, labels = [], []
    chars = [("rocketbox", "fbx", a.data / "characters" / "rocketbox" / "Female_Adult_01_facial.fbx")]
    for name in ("ict-face", "arkit-face"):
        rig = read_rig(a.data / name)
        p = a.work / f"{name}.glb"
        write_glb(p, rig, np.zeros((1, rig.n_shapes)), np.zeros(1))
        chars.append((name, "glb", p))
    for label, kind, path in chars:
        names = open_character(bpy, kind, path)
        bpy.ops.faceretarget.animate_video(filepath=str(video))
        ext.jobs.drive(timeout=900)
        print(label, bpy.context.window_manager.faceretarget_state.report)
        face_camera(bpy, names, a.size)
        bpy.context.scene.display.shading.color_type = "MATERIAL" if kind == "fbx" else "OBJECT"
        tiles.append(render(bpy, a.work / f"{label}.png", frames[2]))
        labels.append(f"{label}, frame {frames[2]}")
    grid([[vids[2]] + tiles], [f"video, frame {frames[2]}"] + labels, a.out / "blender-extension-characters.png")
    ext.jobs.shutdown()
    return 0


if __name__ == "__main__":
    code = main()
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(code)          # bpy's exit handler waits forever on the render's GL threads (llvmpipe) here
