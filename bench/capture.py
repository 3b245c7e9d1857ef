"""Capture benchmark (issue 4): MediaPipe tracking speed, landmark jitter, face share, appearance model.

On each shared video (``video/*.mp4``, 512 x 512, 25 fps, 8 s):

* **Speed.**  Decoding (PyAV, to RGB arrays) is timed alone over the whole video; tracking is the
  time spent inside MediaPipe's FaceLandmarker (VIDEO mode, 478 landmarks + blendshapes + matrix,
  including the conversion of its results to arrays), measured frame by frame during a separate
  tracking run.  ``track fps`` = frames / tracking time, ``total fps`` = frames / (decode +
  tracking).  Model loading is excluded and reported separately.
* **Face share.**  Frames where MediaPipe found a face.
* **Landmark jitter on the steadiest second.**  The 468 mesh landmarks (x, y) of every frame are
  aligned to the take's mean shape by a similarity transform (generalised Procrustes), which
  removes head translation, in-plane rotation and scale, and are scaled back to image pixels by the
  median face scale.  Frame-to-frame displacement ``d_t = sqrt(mean_i |x_t,i - x_t-1,i|^2)``
  (RMS over points, pixels).  The steadiest second is the 25-frame window with the smallest mean
  ``d_t`` of the raw tracks; jitter is the RMS of ``d_t`` over that window, raw and after the
  default One Euro filter (``OneEuroParams()``), on the same window.  Real expression motion in
  that second counts too, so this is an upper bound of the tracker's noise.  The same RMS
  frame-to-frame change of the 51 blendshape scores is reported.
* **Appearance model** (Chuang Sec. 2.2.1; 99 % shape, 80 % texture variance, 128-pixel canvas):
  fitted per video on the first 75 % of the frames (gaps filled, no smoothing); fit time;
  reconstruction error in sample (those frames) and out of sample (the last 25 %): shape RMS in
  image pixels and shape-free texture RMS in grey levels (0..255, over the face pixels and R, G,
  B).

Usage::

    python bench/capture.py [--json] [--data ../shared/data] [--png-dir out/capture]

Prints a table; with ``--json`` the last stdout line is one JSON object.  ``--png-dir`` also writes
overlay frames and an appearance reconstruction strip (original warp | shape-free reconstruction |
reconstruction on its own shape) for looking at.  Run it on an otherwise idle machine for the
speed numbers (the load average is printed with them).
"""

from __future__ import annotations

import os

# The PCA of the appearance model is small: one BLAS thread avoids oversubscribing a shared machine
# (measured: 0.5-0.8 s instead of 2-5 s per fit with 2 threads under load).  MediaPipe does not use
# OpenBLAS, so this leaves the tracking speed alone.  Set the variable to override.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse  # noqa: E402
import json  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

from faceretarget.capture import (  # noqa: E402
    AppearanceModel,
    FaceTracker,
    OneEuroParams,
    draw_overlay,
    procrustes_align,
    track_video,
)
from faceretarget.errors import FaceRetargetError  # noqa: E402
from faceretarget.io import iter_frames  # noqa: E402

REPO = Path(__file__).resolve().parents[1]


def _steady_jitter(raw_lm: np.ndarray, lms: dict[str, np.ndarray], win: int) -> dict:
    """Jitter (px) of each landmark track on the raw track's steadiest window."""
    def disp(L):
        al, _, a, _ = procrustes_align(L[:, :468, :2])
        al = al * np.median(1.0 / np.abs(a))
        return np.sqrt(np.mean(np.sum(np.diff(al, axis=0) ** 2, axis=-1), axis=-1))

    d0 = disp(raw_lm)
    mov = np.convolve(d0, np.ones(win) / win, "valid")
    s = int(np.argmin(mov))
    out = {"window_start_frame": s + 1, "raw_px": float(np.sqrt(np.mean(d0[s:s + win] ** 2)))}
    for k, L in lms.items():
        d = disp(L)
        out[f"{k}_px"] = float(np.sqrt(np.mean(d[s:s + win] ** 2)))
    return out


def _bench_video(path: Path, png_dir: Path | None) -> dict:
    # decode alone
    t0 = time.perf_counter()
    frames = [rgb for _, _, rgb in iter_frames(path)]
    decode_s = time.perf_counter() - t0
    T = len(frames)
    h, w = frames[0].shape[:2]
    # tracking alone (frames already decoded)
    t0 = time.perf_counter()
    tracker = FaceTracker()
    load_s = time.perf_counter() - t0
    with tracker:
        t0 = time.perf_counter()
        for i, rgb in enumerate(frames):
            tracker.track(rgb, i / 25.0)
        track_wall = time.perf_counter() - t0
    # the capture itself (same tracker settings) for the quality numbers
    tm: dict = {}
    raw = track_video(path, timings=tm, audio=False)
    fps_video = raw.fps
    filled = raw.postprocess(smooth=None)
    smooth = raw.postprocess(smooth=OneEuroParams())
    v = filled.valid
    win = int(round(fps_video))
    jit = _steady_jitter(filled.landmarks[v], {"one_euro": smooth.landmarks[v]}, win)
    s = jit["window_start_frame"] - 1
    wj = {k: float(np.sqrt(np.mean(np.diff(c.weights[v][s:s + win + 1], axis=0) ** 2)))
          for k, c in (("raw", filled), ("one_euro", smooth))}
    # appearance model: first 75 % in sample, last 25 % out of sample
    idx = np.flatnonzero(v)
    n_in = int(round(0.75 * idx.size))
    tr, te = idx[:n_in], idx[n_in:]
    L = filled.landmarks
    t0 = time.perf_counter()
    model = AppearanceModel(0.99, 0.80, width=128).fit((frames[i] for i in tr), L[tr])
    fit_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    vec = model.transform((frames[i] for i in te), L[te])
    encode_ms = 1000 * (time.perf_counter() - t0) / max(te.size, 1)
    ev_in = model.evaluate((frames[i] for i in tr), L[tr])
    ev_out = model.evaluate((frames[i] for i in te), L[te])
    if png_dir is not None:
        from PIL import Image

        stem = path.stem
        for i in (0, T // 2, T - 1):
            img = draw_overlay(frames[i], smooth.landmarks[i] if smooth.valid[i] else None,
                               interpolated=bool(smooth.interpolated[i]), pose=smooth.head.to_livelinkface()[i],
                               label=f"frame {i}")
            Image.fromarray(img).save(png_dir / f"overlay_{stem}_{i:03d}.png")
        j = int(te[len(te) // 2])
        k = int(tr[len(tr) // 2])
        vv = model.transform([frames[k], frames[j]], L[[k, j]])
        rows = []
        pad = max(model.width // 8, 2)
        for n, f in enumerate((k, j)):
            def padded(img):
                return np.pad(img, ((pad, pad), (pad, pad), (0, 0)))
            orig = model.warp_.warp(frames[f], L[f, :468, :2])
            rows.append(np.concatenate([padded(orig), padded(model.inverse_transform(vv[n:n + 1], shape_free=True)[0]),
                                        model.inverse_transform(vv[n:n + 1])[0]], axis=1))
        strip = np.concatenate(rows, axis=0)
        Image.fromarray(strip).resize((strip.shape[1] * 2, strip.shape[0] * 2), Image.NEAREST).save(
            png_dir / f"appearance_{stem}.png")
    return {
        "frames": T, "size": [w, h], "video_fps": fps_video,
        "decode_s": decode_s, "decode_fps": T / decode_s,
        "model_load_s": load_s, "track_s": tracker.seconds, "track_wall_s": track_wall,
        "track_fps": T / tracker.seconds, "total_fps": T / (decode_s + tracker.seconds),
        "face_share": raw.face_fraction,
        "jitter": jit, "weights_jitter": wj,
        "appearance": {
            "train_frames": int(tr.size), "test_frames": int(te.size), "fit_s": fit_s,
            "encode_ms_per_frame": encode_ms, "n_shape": model.n_shape, "n_texture": list(model.n_texture),
            "dims": len(model.names_), "texture_scale": model.texture_scale_, "canvas": list(model.warp_.shape),
            "in_sample": ev_in, "out_of_sample": ev_out, "vector_shape": list(vec.shape),
        },
    }


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--data", default=str(REPO.parent / "shared" / "data"))
    ap.add_argument("--json", action="store_true", help="end with one JSON line")
    ap.add_argument("--png-dir", help="write overlay frames and appearance reconstructions here")
    args = ap.parse_args(argv)
    vdir = Path(args.data) / "video"
    videos = sorted(vdir.glob("*.mp4"))
    if not videos:
        print(f"no videos in {vdir}", file=sys.stderr)
        return 2
    png_dir = Path(args.png_dir) if args.png_dir else None
    if png_dir is not None:
        png_dir.mkdir(parents=True, exist_ok=True)
    load0 = os.getloadavg()[0]
    try:
        res = {v.stem: _bench_video(v, png_dir) for v in videos}
    except FaceRetargetError as e:
        print(f"capture benchmark: {e}", file=sys.stderr)
        return 2
    load1 = os.getloadavg()[0]
    env = {"cpus": os.cpu_count(), "loadavg_1min_before": load0, "loadavg_1min_after": load1,
           "openblas_threads": os.environ.get("OPENBLAS_NUM_THREADS", "default")}
    print(f"machine: {env['cpus']} cpus, 1-min load average {load0:.2f} before, {load1:.2f} after")
    print()
    hdr = ("video", "frames", "decode fps", "track fps", "total fps", "face %", "jitter raw px",
           "jitter 1euro px", "w-jitter raw", "w-jitter 1euro")
    print("| " + " | ".join(hdr) + " |")
    print("|" + "---|" * len(hdr))
    for k, r in res.items():
        j = r["jitter"]
        print(f"| {k} | {r['frames']} | {r['decode_fps']:.0f} | {r['track_fps']:.1f} | {r['total_fps']:.1f} | "
              f"{100 * r['face_share']:.1f} | {j['raw_px']:.3f} | {j['one_euro_px']:.3f} | "
              f"{r['weights_jitter']['raw']:.4f} | {r['weights_jitter']['one_euro']:.4f} |")
    print()
    hdr = ("video", "fit s", "modes shape / tex R,G,B", "shape px in", "shape px out", "tex grey in",
           "tex grey out", "encode ms/frame")
    print("| " + " | ".join(hdr) + " |")
    print("|" + "---|" * len(hdr))
    for k, r in res.items():
        a = r["appearance"]
        print(f"| {k} | {a['fit_s']:.2f} | {a['n_shape']} / {','.join(map(str, a['n_texture']))} | "
              f"{a['in_sample']['shape_rms_px']:.3f} | {a['out_of_sample']['shape_rms_px']:.3f} | "
              f"{a['in_sample']['texture_rms']:.2f} | {a['out_of_sample']['texture_rms']:.2f} | "
              f"{a['encode_ms_per_frame']:.1f} |")
    if args.json:
        print(json.dumps({"capture": res, "env": env}, separators=(",", ":")))
    return 0


if __name__ == "__main__":
    sys.exit(main())
