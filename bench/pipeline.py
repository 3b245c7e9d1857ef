"""The main job end to end: a video onto a character (``faceretarget animate``), measured (issue 13).

For every video (default: both of ``../shared/data/video``) and character (default ``ict-face`` and
``arkit-face``), in this run:

* speed, frames per second of each stage: ``capture`` (decode + MediaPipe + post-processing),
  ``solve`` (68 points onto the character's own shapes), ``write`` (the ``.glb``), ``preview`` (the
  side-by-side mp4 with the NumPy rasteriser) and ``preview_fast`` (OpenGL through EGL when it is
  available, else null), and ``end_to_end`` (capture + solve + write, the job without preview);
* agreement with the video, no ground truth needed: ``mouth_corr``, the correlation over the take of
  the tracked mouth opening (inner-lip landmarks over the eye-corner distance) and the character's
  (its own lip vertices); ``mouth_corr_emotion`` the same with ``--emotion angry:0.6`` (a style
  model fitted in this run on one MEAD speaker's takes, ``--style-speaker``); ``head_median_err_deg``
  the median angle between the head written into the ``.glb`` (read back) and the tracked head
  (about its rest pose);
* live (``faceretarget live``, when the live pipeline is installed): frames per second and the
  per-frame latency from decoded frame to weights (p50/p95) on the first video, paced at its rate.

Usage::

    python bench/pipeline.py [--json] [--video FILE ...] [--character DIR ...] [--max-frames N]

With ``--json`` the last stdout line is ``{"videos": {"NAME/CHARACTER": {...}}, "live": {...}}``.
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
DATA = REPO.parent / "shared" / "data"


def _style(speaker: str, log):
    """A style model (neutral, angry, happy, sad) on one MEAD speaker's face takes."""
    from faceretarget.pipelines import face_takes, fit_style

    mead = DATA / "emotion-video" / "mead"
    vids = {e: mead / f"{speaker}_front_{e}_level{1 if e == 'neutral' else 3}_001.mp4"
            for e in ("neutral", "angry", "happy", "sad")}
    missing = [str(v) for v in vids.values() if not v.is_file()]
    if missing:
        log(f"no style model: {missing[0]} missing")
        return None
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return fit_style(face_takes(vids), reference="neutral")


def _head_err(glb: Path, res) -> float:
    from faceretarget.io import read_head_motion

    head = read_head_motion(glb).head
    tracked = res.take.head.rotation
    rel = tracked.mean().inv() * tracked
    return float(np.median(np.degrees((head.rotation.inv() * rel).magnitude())))


def _preview_fps(video, rig, res, backend, tmp: Path, log) -> tuple[float | None, str]:
    from faceretarget.errors import MissingDependencyError
    from faceretarget.pipelines._preview import write_animation_preview

    try:
        info = write_animation_preview(tmp / f"preview_{backend}.mp4", video, rig, res.weights, res.times, res.head,
                                       size=512, backend=backend, log=lambda *_: None)
    except MissingDependencyError as e:
        log(f"  preview ({backend}): not available: {e}")
        return None, str(e)
    return info["frames"] / info["total_s"], info["backend"]


def run_one(video: Path, char_dir: Path, style, max_frames, log) -> dict:
    from faceretarget.io import read_rig
    from faceretarget.pipelines import animate, capture_take, tracked_take

    rig = read_rig(char_dir)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        t0 = time.perf_counter()
        cap = capture_take(video, max_frames=max_frames, neutral_percentile=5.0)
        t_cap = time.perf_counter() - t0
    n = int(cap.valid.sum())
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        glb = tmp / "out.glb"
        res = animate(tracked_take(cap), rig, out=glb)
        res_e = animate(tracked_take(cap), rig, emotion="angry:0.6", style=style) if style is not None else None
        t_solve, t_write = res.timings["solve"], res.timings["write"]
        slow, slow_backend = _preview_fps(video, rig, res, "numpy", tmp, log)
        fast, fast_backend = _preview_fps(video, rig, res, "gl", tmp, log)
        out = {"frames": n, "capture_fps": n / t_cap, "solve_fps": n / t_solve, "write_fps": n / t_write,
               "preview_fps": slow, "preview_fast_fps": fast, "preview_fast_backend": fast_backend,
               "end_to_end_fps": n / (t_cap + t_solve + t_write),
               "mouth_corr": res.mouth_corr,
               "mouth_corr_emotion": None if res_e is None else res_e.mouth_corr,
               "head_median_err_deg": _head_err(glb, res)}
    f = lambda v: "n/a" if v is None else f"{v:.1f}"  # noqa: E731
    log(f"{video.stem} -> {rig.name}: {n} frames; capture {out['capture_fps']:.1f} fps, solve "
        f"{out['solve_fps']:.0f} fps, write {out['write_fps']:.0f} fps, end to end {out['end_to_end_fps']:.1f} fps; "
        f"preview NumPy {f(slow)} fps, fast {f(fast)} fps ({fast_backend}); mouth correlation "
        f"{out['mouth_corr']:.3f}, with angry:0.6 {'n/a' if res_e is None else f'{res_e.mouth_corr:.3f}'}; "
        f"head {out['head_median_err_deg']:.3f} deg (median)")
    return out


def run_live(video: Path, char_dir: Path, log) -> dict | None:
    try:
        from faceretarget.pipelines import run_live
    except ImportError:
        log("live: not available in this build")
        return None
    from faceretarget.io import read_rig

    stats = run_live(video, read_rig(char_dir), serve=None, realtime=True, log=lambda *_: None)
    out = {"fps": stats.fps, "latency_p50_ms": stats.latency_p50, "latency_p95_ms": stats.latency_p95}
    log(f"live {video.stem} -> {char_dir.name}: {out['fps']:.1f} fps, latency p50 {out['latency_p50_ms']:.1f} ms, "
        f"p95 {out['latency_p95_ms']:.1f} ms")
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--video", action="append", type=Path, help="video(s) (default both shared videos)")
    ap.add_argument("--character", action="append", type=Path, help="character rig folder(s) "
                    "(default ict-face and arkit-face)")
    ap.add_argument("--style-speaker", default="M030", help="MEAD speaker of the emotion model (default M030)")
    ap.add_argument("--max-frames", type=int)
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)
    log = print
    videos = args.video or [DATA / "video" / "WDA_AOC_000.mp4", DATA / "video" / "WDA_KatieHill_000.mp4"]
    chars = args.character or [DATA / "ict-face", DATA / "arkit-face"]
    style = _style(args.style_speaker, log)
    res = {"videos": {}}
    for v in videos:
        for c in chars:
            res["videos"][f"{v.stem}/{c.name}"] = run_one(v, c, style, args.max_frames, log)
    res["live"] = run_live(videos[0], chars[0], log)
    if args.json:
        print(json.dumps(res))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
