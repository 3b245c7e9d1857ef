"""Preview video speed (issue 13, item 2): the OpenGL (EGL) renderer against the NumPy rasteriser.

The character is ``ict-face`` (9,409 vertices, 18,460 triangles) rendered 512 x 512, playing the
Live Link Face take ``S07-001`` (weights interpolated at each video frame's time); the video is
``video/WDA_AOC_000.mp4`` (512 x 512, 25 fps, 200 frames, with audio).  In the same run, for each
renderer:

* **render only**: :class:`faceretarget.render.MeshRenderer` frames at the video's frame times
  (take sampling, vertices, normals, drawing and reading the pixels back), frames per second;
* **render + encode**: :func:`faceretarget.pipelines.write_animation_preview`, the whole preview
  (decode, render, encode a 1024 x 512 H.264 mp4 with the audio copied; three threads), frames per
  second of the whole call, including setting up the renderer;

and, to say where the time goes, decoding alone (``iter_frames``) and encoding alone
(``write_video`` of 1024 x 512 frames made beforehand).  The ratio GL / NumPy is of this run.

Usage::

    python bench/preview.py [--json] [--data ../shared/data] [--frames 200] [--png-dir out/preview]

Prints a table; with ``--json`` the last stdout line is one JSON object.  ``--png-dir`` writes one
frame of each renderer and one preview frame.  The machine's load average is printed with the numbers
(other jobs on a shared 2-core machine slow every figure).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from faceretarget.io import iter_frames, read_performance, read_rig, write_video
from faceretarget.pipelines import TakeSampler, write_animation_preview
from faceretarget.render import MeshRenderer, save_png

REPO = Path(__file__).resolve().parents[1]
SIZE = 512


def render_only(rig, sampler: TakeSampler, times: np.ndarray, backend: str, png: Path | None) -> dict:
    """Frames per second of sampling + rendering the character at ``times``."""
    with MeshRenderer(rig.neutral, (SIZE, SIZE), backend=backend, mm_per_unit=rig.mm_per_unit) as r:
        first = r.render(sampler.vertices_at(times[0]), *sampler.head_at(times[0]))  # warm-up
        t0, c0 = time.perf_counter(), time.process_time()
        for t in times:
            r.render(sampler.vertices_at(t), *sampler.head_at(t))
        wall, cpu = time.perf_counter() - t0, time.process_time() - c0
        name = r.backend
    if png is not None:
        save_png(png / f"render_{backend}.png", first)
    n = len(times)
    return {"backend": name, "frames": n, "fps": n / wall, "ms_per_frame": 1000 * wall / n,
            "cpu_ms_per_frame": 1000 * cpu / n}


def whole_preview(rig, W, times, head, video: Path, n: int, backend: str, tmp: Path, png: Path | None) -> dict:
    out = tmp / f"preview_{backend}.mp4"
    c0 = time.process_time()
    info = write_animation_preview(out, video, rig, W, times, head, frame_times=np.arange(n) / 25.0,
                                   size=SIZE, backend=backend, log=lambda *_: None)
    info["cpu_ms_per_frame"] = 1000 * (time.process_time() - c0) / info["frames"]
    if png is not None:
        for i, _t, rgb in iter_frames(out, max_frames=n // 2 + 1):
            if i == n // 2:
                save_png(png / f"preview_{backend}.png", rgb)
    return info


def codec_floor(video: Path, n: int, tmp: Path) -> dict:
    """Decoding alone and encoding alone (1024 x 512 frames held in memory), frames per second."""
    t0 = time.perf_counter()
    frames = [f for _, _, f in iter_frames(video, max_frames=n)]
    dec = len(frames) / (time.perf_counter() - t0)
    big = [np.ascontiguousarray(np.concatenate([f, f[:, ::-1]], axis=1)) for f in frames]
    t0 = time.perf_counter()
    codec = write_video(tmp / "encode.mp4", iter(big), 25.0, audio_from=video, audio_duration=len(big) / 25.0)
    enc = len(big) / (time.perf_counter() - t0)
    return {"decode_fps": dec, "encode_fps": enc, "codec": codec}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--json", action="store_true", help="end with one JSON line")
    ap.add_argument("--data", type=Path, default=Path(os.environ.get("FACERETARGET_DATA", REPO.parent / "shared" / "data")))
    ap.add_argument("--frames", type=int, default=200, help="video frames (200 = the whole 8 s video)")
    ap.add_argument("--png-dir", type=Path, default=None)
    args = ap.parse_args(argv)
    video = args.data / "video" / "WDA_AOC_000.mp4"
    rig = read_rig(args.data / "ict-face")
    take = read_performance(args.data / "livelinkface" / "S07-001.csv")
    W = rig.map_weights(take.names, take.weights, warn=False)
    sampler = TakeSampler(rig, W, take.times, take.head)
    times = np.arange(args.frames) / 25.0  # the video's frame times (the take starts at 0 s too)
    if args.png_dir is not None:
        args.png_dir.mkdir(parents=True, exist_ok=True)
    load0 = os.getloadavg()[0]
    res: dict = {}
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        for backend in ("gl", "numpy"):
            res[backend] = {"render": render_only(rig, sampler, times, backend, args.png_dir),
                            "preview": whole_preview(rig, W, take.times, take.head, video, args.frames, backend,
                                                     tmp, args.png_dir)}
        res["codec"] = codec_floor(video, args.frames, tmp)
    load1 = os.getloadavg()[0]
    g, n = res["gl"], res["numpy"]
    res["ratio_gl_numpy"] = {"render": g["render"]["fps"] / n["render"]["fps"],
                             "preview": g["preview"]["fps"] / n["preview"]["fps"]}
    env = {"cpus": os.cpu_count(), "loadavg_1min_before": load0, "loadavg_1min_after": load1,
           "gl_backend": g["render"]["backend"]}
    print(f"machine: {env['cpus']} cpus, 1-min load average {load0:.2f} before, {load1:.2f} after")
    print(f"ict-face {rig.n_vertices} vertices, {SIZE} x {SIZE}, {args.frames} frames of {video.name}")
    print(f"{'renderer':<46} {'render fps':>10} {'ms/frame':>9} {'preview fps':>12}")
    for key in ("gl", "numpy"):
        r, p = res[key]["render"], res[key]["preview"]
        print(f"{r['backend']:<46} {r['fps']:>10.1f} {r['ms_per_frame']:>9.2f} {p['fps']:>12.1f}")
    print(f"GL / NumPy: render {res['ratio_gl_numpy']['render']:.1f}x, preview {res['ratio_gl_numpy']['preview']:.1f}x")
    c = res["codec"]
    print(f"alone: decode {c['decode_fps']:.0f} fps, encode ({c['codec']}, 1024 x 512) {c['encode_fps']:.0f} fps")
    if g["render"]["backend"] == "numpy":
        print("note: OpenGL was not available, both rows are the NumPy renderer")
    if args.json:
        print(json.dumps({"preview": res, "env": env}, separators=(",", ":"), default=float))
    return 0


if __name__ == "__main__":
    sys.exit(main())
