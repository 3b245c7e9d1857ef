"""Does the preview look like the character?  One frame of ``faceretarget animate`` against three.js (issue 34).

``animate VIDEO --character FILE --out x.glb --head off`` (the library call, the first ``--frames`` frames of
the video) writes the animation back into a copy of the character's file; frame ``--frame`` is then drawn

* by the preview as it is now (:func:`faceretarget.characters.character_look`: materials, textures per
  pixel, alpha modes, sides; the OpenGL renderer and the NumPy one),
* by the preview as it was (:func:`faceretarget.characters.look_rig`: the textures sampled at the vertices,
  one colour per vertex, the same camera),
* by three.js from ``x.glb`` (``tests/browser/render_three.mjs``: the same orthographic camera and lights),

and each of ours is compared with three.js by the mean CIE 1976 Delta E over the face, the eyes, the lips
and the hair (``bench/_look_compare.py``).  The head is off so that the picture compares looks, not head
motion (the preview turns the whole cropped head about the head joint, the file turns the head joint); the
eyes turn with the gaze the file carries on the eye joints (the look of before did not turn them).
With ``--speed`` it also times the whole preview video of those frames for the character with each look
(frames per second, the OpenGL renderer).

Usage::

    python bench/preview_look.py [--character FILE] [--video FILE] [--frames 60] [--frame 30]
                                 [--png-dir DIR] [--speed] [--json]

Writes ``look_<character>_<frame>.png`` (vertex colours | preview | three.js | Delta E of each against
three.js, the regions outlined) into ``--png-dir`` (default ``out/preview_look``).  Needs the shared data,
MediaPipe, node, three.js and puppeteer-core (``make tools browser``) and Chromium.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
import warnings
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import _look_compare as lc  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
DATA = Path(os.environ.get("FACERETARGET_DATA", REPO.parent / "shared" / "data"))


def _renders(drive, look, res, n: int, size: int) -> tuple[dict, object]:
    """Our pictures of frame ``n``: the preview (OpenGL, NumPy; its vertices as the preview video takes them,
    the eyes turned by the gaze the file carries) and the vertex-colour look of before (no gaze), one camera."""
    from faceretarget.characters import look_rig
    from faceretarget.pipelines import TakeSampler
    from faceretarget.render import MeshRenderer

    out = {}
    kw = dict(pivot=look.pivot, mm_per_unit=look.rig.mm_per_unit)
    v = TakeSampler(look.rig, res.weights, res.times, None, look.eye_turns(res.gaze)).vertices_at(res.times[n])
    with MeshRenderer(look.rig.neutral, (size, size), backend="gl", surface=look.surface, fit_to=look.frame,
                      **kw) as r:
        cam = r.camera
        out["preview (OpenGL)"] = r.render(v)
    with MeshRenderer(look.rig.neutral, (size, size), backend="numpy", surface=look.surface, camera=cam, **kw) as r:
        out["preview (NumPy)"] = r.render(v)
    old, colors, pivot = look_rig(drive)
    with MeshRenderer(old.neutral, (size, size), backend="gl", color=colors, camera=cam, pivot=pivot,
                      mm_per_unit=old.mm_per_unit) as r:
        out["vertex colours (before)"] = r.render(old.evaluate(res.weights[n]))
    return out, cam


def _speed(video: Path, drive, look, res, tmp: Path) -> dict:
    """Frames per second of the whole preview video, with the surface and with vertex colours."""
    from faceretarget.characters import look_rig
    from faceretarget.pipelines import write_animation_preview

    old, colors, pivot = look_rig(drive)
    fps = {}
    for name, rig, kw in (("vertex colours", old, {"colors": colors, "pivot": pivot}),
                          ("surface", look.rig, {"surface": look.surface, "pivot": look.pivot, "fit_to": look.frame,
                                                 "turns": look.eye_turns(res.gaze)})):
        c0 = time.process_time()
        info = write_animation_preview(tmp / f"speed_{name[0]}.mp4", video, rig, res.weights, res.times, None,
                                       backend="gl", log=lambda *_: None, **kw)
        fps[name] = {"fps": info["fps"], "render_ms_per_frame": 1000 * info["render_s"] / info["frames"],
                     "cpu_ms_per_frame": 1000 * (time.process_time() - c0) / info["frames"],
                     "frames": info["frames"]}
    return fps


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--character", type=Path, default=DATA / "characters" / "valid" / "AIAN_F_1_Busi.glb")
    ap.add_argument("--video", type=Path, default=DATA / "video" / "WDA_KatieHill_000.mp4")
    ap.add_argument("--frames", type=int, default=60, help="video frames animated")
    ap.add_argument("--frame", type=int, default=30, help="the frame compared")
    ap.add_argument("--size", type=int, default=512)
    ap.add_argument("--png-dir", type=Path, default=REPO / "out" / "preview_look")
    ap.add_argument("--speed", action="store_true", help="also time the preview video with each look")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)
    env, why = lc.tools()
    if env is None:
        print(f"cannot run three.js: {why}")
        return 2
    from faceretarget.character import character_frame
    from faceretarget.characters import character_look
    from faceretarget.pipelines import animate
    from faceretarget.render import save_png

    args.png_dir.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        glb = tmp / f"anim{args.character.suffix}"
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            res = animate(args.video, args.character, out=glb, head="off", max_frames=args.frames)
        drive = res.drive
        look = character_look(drive)
        n = min(args.frame, len(res.times) - 1)
        w = res.weights[n]
        ours, cam = _renders(drive, look, res, n, args.size)
        spec = lc.three_spec(cam, character_frame(drive.character), float(res.times[n]))
        t0 = time.perf_counter()
        info = lc.render_three(glb, spec, tmp / "three.png", env)
        three_s = time.perf_counter() - t0
        theirs = lc.read_png(tmp / "three.png")
        masks = lc.regions(drive, look, cam, w)
        scores = {k: lc.compare(img, theirs, masks) for k, img in ours.items()}
        speed = _speed(args.video, drive, look, res, tmp) if args.speed else None
    stem = f"look_{args.character.stem}_{n}"
    panels = [("vertex colours (before)", ours["vertex colours (before)"]), ("preview", ours["preview (OpenGL)"]),
              ("three.js", theirs)]
    save_png(args.png_dir / f"{stem}.png", lc.side_by_side(panels))
    de = [(f"dE {k.split(' (')[0]}", lc.delta_e_image(lc.delta_e(ours[k], theirs)))
          for k in ("vertex colours (before)", "preview (OpenGL)")]
    save_png(args.png_dir / f"{stem}_delta_e.png", lc.side_by_side(de, masks, outlined=(0, 1)))
    print(f"{args.character.name}, frame {n} ({res.times[n]:.2f} s) of {args.video.name}; three.js r{info['three']} "
          f"in {info['browser']} ({three_s:.1f} s); mean Delta E (CIE 1976) against three.js:")
    print(f"{'':26} {'face':>6} {'eyes':>6} {'lips':>6} {'hair':>6}")
    for k, s in scores.items():
        print(f"{k:26} " + " ".join("   n/a" if s[r] is None else f"{s[r]:6.2f}" for r in ("face", "eyes", "lips", "hair")))
    print("pixels: " + ", ".join(f"{r} {scores['preview (OpenGL)'][r + '_px']}" for r in ("face", "eyes", "lips", "hair")))
    print(f"wrote {args.png_dir / stem}.png and {stem}_delta_e.png")
    if speed:
        for k, v in speed.items():
            print(f"preview video ({k}): {v['fps']:.1f} frames/s, render {v['render_ms_per_frame']:.1f} ms/frame, "
                  f"CPU {v['cpu_ms_per_frame']:.1f} ms/frame ({v['frames']} frames)")
        print(f"1-min load average {os.getloadavg()[0]:.2f} on {os.cpu_count()} cpus")
    if args.json:
        print(json.dumps({"scores": scores, "speed": speed, "frame": n, "time": float(res.times[n])}, default=float))
    return 0


if __name__ == "__main__":
    sys.exit(main())
