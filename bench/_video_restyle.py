"""P6, "the video itself" (Chuang Ch. 2, Fig. 2.6): restyle a held-out neutral clip's appearance
vectors and render the edited faces back into the frames.

For one speaker (MEAD naming, any speaker; :func:`_emotion_data.find_clips`):

1. Every clip is tracked (MediaPipe, no smoothing; cached) and every emotion take aligned to the
   neutral take by its 68 face points (DTW of face features + re-alignment by style, as
   :class:`~faceretarget.pipelines.AppearanceStyleModel` does).
2. **Held-out split on the aligned timeline**: the first ``train`` share (60 %) of the neutral
   take's frames and, of every emotion take, the frames up to the aligned time of that cut.  The
   appearance model is fitted on those frames only (every clip), the style model on the aligned
   appearance vectors of that part (neutral + every emotion); the last 40 % of the neutral take is
   held out from both.
3. **(a) Reconstruction** of the unedited held-out frames: encode -> decode -> composite
   (:class:`~faceretarget.capture.FaceCompositor`) against the input frame, inside the face region
   (convex hull of the tracked face mesh): mean absolute grey-level error, PSNR, and the
   reconstructed shape's distance from the tracked points in image pixels.  The same on the
   training part of the neutral take for comparison.
4. **(b) Edit** of the held-out frames to each target emotion (known expression, neutral -> target,
   amount 1) against the speaker's real take of that emotion at the aligned frames (the nearest real
   frame to the aligned time): shape error (Procrustes-aligned to the model's reference, in image
   pixels of the input) and shape-free texture error (mean absolute grey level over the canvas face
   pixels), for the edit, the no-edit baseline (the input's vector), and the additive baseline (the
   input's vector plus the mean training difference target - neutral).  ``floor``: the real frame's
   own reconstruction through the model, the best any edit in this model could do.
5. **(c) Strip** ``restyle_strip_<speaker>.png``: held-out frames; rows input / reconstruction /
   edited to each target / the real take at the aligned time.

:func:`run` returns the numbers as a dict (``bench/emotion_video.py`` calls it); run alone::

    python bench/_video_restyle.py [--data DIR] [--speaker W009] [--to angry,happy] [--out out/emotion_video]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
import warnings
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from _emotion_data import cached_capture, find_clips  # noqa: E402  (bench/_emotion_data.py, same folder)
from _plot import font as _font  # noqa: E402
from faceretarget.files import cache_dir  # noqa: E402

DATA = Path(__file__).resolve().parents[2] / "shared" / "data" / "emotion-video"
CACHE = cache_dir("bench", "emotion_video")           # the user's cache folder, never the checkout
GREY = np.array([0.299, 0.587, 0.114])


def _quiet(*_a) -> None:
    return None


def capture_clip(video: Path, cache: Path | None, log=_quiet):
    """The clip's capture without smoothing (the appearance model's setting), cached under ``cache``."""
    return cached_capture(video, cache, log, tag=".raw-n5", audio=False, neutral_percentile=5.0, smooth=None)


def _frames(video: Path, cap) -> np.ndarray:
    from faceretarget.io import iter_frames

    F = np.stack([f for _, _, f in iter_frames(video, max_frames=cap.n_frames)])
    return F[cap.valid]


def _hull_mask(points: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    import cv2

    m = np.zeros(size, np.uint8)
    hull = cv2.convexHull(np.round(points).astype(np.int32))
    cv2.fillConvexPoly(m, hull, 1)
    return m.astype(bool)


def _recon_errors(comp, app, frames, vecs, lms) -> dict:
    """(a): composite of the unedited vectors vs the input, inside the tracked face's hull."""
    from faceretarget.capture import image_shapes

    _, a, c = app.shape_params(lms)
    tracked = lms[:, app.points_, :2]
    shapes = image_shapes(app, app.reconstruct_shape(vecs), a, c)
    abs_err, sq_err, n = 0.0, 0.0, 0
    for k in range(len(frames)):
        out = comp.render(frames[k], vecs[k], a[k], c[k], tracked=tracked[k])
        m = _hull_mask(tracked[k], frames[k].shape[:2])
        d = (out[m].astype(np.float64) - frames[k][m]) @ GREY
        abs_err += float(np.abs(d).sum())
        sq_err += float((d**2).sum())
        n += int(m.sum())
    mse = sq_err / max(n, 1)
    return {"grey_mae": abs_err / max(n, 1), "psnr_db": float(10 * np.log10(255.0**2 / max(mse, 1e-12))),
            "shape_px": float(np.linalg.norm(shapes - tracked, axis=-1).mean()), "frames": int(len(frames))}


def _crop_box(points: np.ndarray, size: tuple[int, int], grow: float = 1.45) -> tuple[int, int, int]:
    """A square (x0, y0, side) around the points, ``grow`` times their larger extent, inside the frame."""
    lo, hi = points.min(0), points.max(0)
    ctr, side = (lo + hi) / 2, int(round(grow * float((hi - lo).max())))
    side = min(side, size[0], size[1])
    x0 = int(np.clip(round(ctr[0] - side / 2), 0, size[1] - side))
    y0 = int(np.clip(round(ctr[1] - side / 2 - 0.05 * side), 0, size[0] - side))
    return x0, y0, side


def _cell(img: np.ndarray, box, cell: int) -> np.ndarray:
    from PIL import Image

    x0, y0, s = box
    return np.asarray(Image.fromarray(img[y0:y0 + s, x0:x0 + s]).resize((cell, cell), Image.LANCZOS))


def _strip(path: Path, rows: list[tuple[str, list[np.ndarray]]], title: str, cols: list[str]) -> None:
    from PIL import Image, ImageDraw

    cell = rows[0][1][0].shape[0]
    left, top, gap = 150, 44, 4
    W = left + len(cols) * (cell + gap)
    H = top + len(rows) * (cell + gap)
    img = Image.new("RGB", (W, H), (255, 255, 255))
    d = ImageDraw.Draw(img)
    d.text((8, 6), title, fill=(0, 0, 0), font=_font(15))
    for j, c in enumerate(cols):
        d.text((left + j * (cell + gap) + 4, 26), c, fill=(60, 60, 60), font=_font(12))
    for i, (label, cells) in enumerate(rows):
        y = top + i * (cell + gap)
        for k, line in enumerate(label.split("\n")):
            d.text((8, y + cell // 2 - 16 + 16 * k), line, fill=(0, 0, 0), font=_font(13))
        for j, im in enumerate(cells):
            img.paste(Image.fromarray(im), (left + j * (cell + gap), y))
    path.parent.mkdir(parents=True, exist_ok=True)
    img.save(path)


def run(data_dir: str | Path = DATA, speaker: str = "W009", to_emotion: str | tuple[str, ...] = ("angry", "happy"),
        out_dir: str | Path = "out/emotion_video", *, train: float = 0.6, cache: str | Path | None = CACHE,
        width: int = 128, strip_frames: int = 5, cell: int = 176, speakers=None, log=_quiet) -> dict:
    """P6 "the video itself" for one speaker (module docstring).

    Parameters
    ----------
    data_dir : path
        Folder holding the speaker's clips (MEAD naming, searched recursively).
    speaker : str
    to_emotion : str or tuple of str
        Target emotion(s) for the held-out neutral frames.
    out_dir : path
        Where ``restyle_strip_<speaker>.png`` goes.
    train : float
        Share of the aligned timeline (from the start) used for training.
    cache : path, optional
        Capture cache folder (None: track every run).
    width : int
        Appearance model canvas width, pixels.
    speakers : SpeakerStyleModel, optional
        Fitted on *other* speakers (issue 27): the held-out frames are also edited by it, the shape
        through :func:`~faceretarget.pipelines.speaker_edited_landmarks` and the appearance model, the
        texture kept (``cross_speaker`` in ``shape_px`` / ``texture_grey``; a row of the strip).

    Returns
    -------
    dict
        ``reconstruction`` {``held_out``, ``train``: {``grey_mae``, ``psnr_db``, ``shape_px``,
        ``frames``}}, ``edit`` {emotion: {``shape_px``, ``texture_grey``: {``edited``, ``no_edit``,
        ``additive``, ``floor``}, ``shape_rel``, ``texture_rel`` (edited / no edit),
        ``shape_rel_additive``, ``texture_rel_additive`` (edited / additive), ``range_score``}},
        ``strip``, ``frames``, ``model``, ``seconds``.
    """
    from faceretarget.capture import AppearanceModel, FaceCompositor
    from faceretarget.pipelines import AppearanceStyleModel, face_take, tracked_take
    from faceretarget.retarget import neutral_face
    from faceretarget.style import align_performances, realign_by_style, resample

    t_start = time.perf_counter()
    targets = (to_emotion,) if isinstance(to_emotion, str) else tuple(to_emotion)
    clips = find_clips(Path(data_dir)).get(speaker)
    if not clips or "neutral" not in clips:
        raise SystemExit(f"{data_dir}: no neutral clip of speaker {speaker}")
    missing = [e for e in targets if e not in clips]
    if missing:
        raise SystemExit(f"{data_dir}: speaker {speaker} has no clip of {', '.join(missing)}")
    emotions = ["neutral"] + [e for e in clips if e != "neutral"]
    caps = {e: capture_clip(clips[e].video, cache, log) for e in emotions}
    frames = {e: _frames(clips[e].video, caps[e]) for e in emotions}
    lms = {e: caps[e].landmarks[caps[e].valid] for e in emotions}
    times = {e: caps[e].times[caps[e].valid] for e in emotions}
    # 1. alignment of every take to the neutral one by the face points
    rc = tracked_take(caps["neutral"])
    n0 = neutral_face(rc.points, rc.weights)
    faces = {e: face_take(caps[e], neutral=n0) for e in emotions}
    ref_t = times["neutral"]
    C = len(ref_t)
    at = {"neutral": ref_t}
    for e in emotions[1:]:
        al = align_performances(faces["neutral"], faces[e], by="face")
        at[e] = realign_by_style(faces["neutral"], faces[e], al, iterations=2)(ref_t)
    # 2. the split: first `train` of the neutral timeline
    n_train = int(round(train * C))
    cut = {e: at[e][n_train - 1] for e in emotions}
    fit_idx = {e: np.flatnonzero(times[e] <= cut[e] + 1e-9) for e in emotions}
    t0 = time.perf_counter()
    app = AppearanceModel(0.99, 0.80, width=width).fit(
        np.concatenate([frames[e][fit_idx[e]] for e in emotions]), np.concatenate([lms[e][fit_idx[e]] for e in emotions]))
    log(f"{speaker}: appearance model on {sum(len(v) for v in fit_idx.values())} training frames "
        f"({time.perf_counter() - t0:.1f} s): {app.n_shape} shape + {sum(app.n_texture)} texture modes")
    vec = {e: app.transform(frames[e], lms[e]) for e in emotions}
    aligned = {e: resample(vec[e], times[e], at[e]) for e in emotions}
    t0 = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        model = AppearanceStyleModel().fit_aligned(app, {e: aligned[e][:n_train] for e in emotions}, "neutral")
    fit_s = time.perf_counter() - t0
    log(f"{speaker}: style model on {n_train} aligned frames x {len(emotions)} styles ({fit_s:.1f} s): "
        f"{model.style_.settings_}")
    comp = FaceCompositor(app)
    held = np.arange(n_train, C)
    # (a) reconstruction of unedited frames
    recon = {"held_out": _recon_errors(comp, app, frames["neutral"][held], vec["neutral"][held], lms["neutral"][held]),
             "train": _recon_errors(comp, app, frames["neutral"][:n_train], vec["neutral"][:n_train],
                                    lms["neutral"][:n_train])}
    # (b) edits vs the real takes at the aligned frames
    _, a_in, _ = app.shape_params(lms["neutral"][held])
    px = float(np.mean(1.0 / np.abs(a_in)))                       # canvas pixel -> image pixel of the input
    x = vec["neutral"][held]
    edit: dict = {}
    edited: dict = {}
    nearest: dict = {}
    for e in targets:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            r = model.transform(x, e, 1.0, source="neutral")
        edited[e] = r.frames
        j = np.abs(times[e][None, :] - at[e][held][:, None]).argmin(axis=1)
        nearest[e] = j
        true_shape, _, _, _ = _aligned_shapes(app, lms[e][j])
        true_tex = np.stack([app.warp_.sample(frames[e][k], lms[e][k, app.points_, :2]) for k in j]).astype(np.float64)
        offset = (aligned[e][:n_train] - aligned["neutral"][:n_train]).mean(0)
        cand = {"edited": r.frames, "no_edit": x, "additive": x + offset, "floor": vec[e][j]}
        if speakers is not None and e in speakers.styles_:
            from faceretarget.pipelines import speaker_edited_landmarks

            L, _ = speaker_edited_landmarks(caps["neutral"], speakers, e)
            cross = x.copy()
            cross[:, :app.n_shape] = app.shape_params(L[held])[0]
            cand["cross_speaker"] = edited[e + " (other speakers)"] = cross
        sh, tx = {}, {}
        for k, v in cand.items():
            sh[k] = px * float(np.linalg.norm(app.reconstruct_shape(v) - true_shape, axis=-1).mean())
            tx[k] = float(np.abs((app.reconstruct_texture(v) - true_tex) @ GREY).mean())
        edit[e] = {"shape_px": sh, "texture_grey": tx, "shape_rel": sh["edited"] / sh["no_edit"],
                   "texture_rel": tx["edited"] / tx["no_edit"], "shape_rel_additive": sh["edited"] / sh["additive"],
                   "texture_rel_additive": tx["edited"] / tx["additive"], "range_score": r.range.score}
        if "cross_speaker" in sh:
            edit[e]["cross_speaker_shape_rel"] = sh["cross_speaker"] / sh["no_edit"]
            log(f"{speaker} -> {e} by the model of other speakers: shape px {sh['cross_speaker']:.2f} "
                f"({sh['cross_speaker'] / sh['no_edit']:.2f} of no edit; the same speaker's own model "
                f"{sh['edited']:.2f})")
        log(f"{speaker} -> {e}: shape px edited {sh['edited']:.2f} / no edit {sh['no_edit']:.2f} / additive "
            f"{sh['additive']:.2f} / floor {sh['floor']:.2f}; texture grey edited {tx['edited']:.2f} / no edit "
            f"{tx['no_edit']:.2f} / additive {tx['additive']:.2f} / floor {tx['floor']:.2f}")
    # (c) strip
    pick = held[np.linspace(0, len(held) - 1, strip_frames + 2).round().astype(int)[1:-1]]
    _, a_all, c_all = app.shape_params(lms["neutral"])
    tr_all = lms["neutral"][:, app.points_, :2]
    size = frames["neutral"].shape[1:3]
    boxes = [_crop_box(tr_all[k], size) for k in pick]
    rows = [("input\n(held out)", [_cell(frames["neutral"][k], b, cell) for k, b in zip(pick, boxes, strict=True)]),
            ("reconstruction\n(no edit)", [_cell(comp.render(frames["neutral"][k], vec["neutral"][k], a_all[k],
                                                             c_all[k], tracked=tr_all[k]), b, cell)
                                           for k, b in zip(pick, boxes, strict=True)])]
    for e in targets:
        for key, label in ((e, f"edited\n-> {e}"), (e + " (other speakers)", f"-> {e}, model\nof other speakers")):
            if key not in edited:
                continue
            ed = [comp.render(frames["neutral"][k], edited[key][k - n_train], a_all[k], c_all[k], tracked=tr_all[k])
                  for k in pick]
            rows.append((label, [_cell(im, b, cell) for im, b in zip(ed, boxes, strict=True)]))
        real = []
        for k in pick:
            jj = nearest[e][k - n_train]
            real.append(_cell(frames[e][jj], _crop_box(lms[e][jj, app.points_, :2], size), cell))
        rows.append((f"real {e}\n(aligned)", real))
    strip = Path(out_dir) / f"restyle_strip_{speaker}.png"
    _strip(strip, rows, f"{speaker}: held-out neutral frames restyled through the appearance model "
           f"(trained on the first {train:.0%} of the aligned takes)",
           [f"t = {ref_t[k] - ref_t[0]:.2f} s" for k in pick])
    return {"speaker": speaker, "targets": list(targets), "reconstruction": recon, "edit": edit, "strip": str(strip),
            "frames": {"neutral": int(C), "train": int(n_train), "held_out": int(len(held))},
            "model": {"shape_modes": app.n_shape, "texture_modes": list(app.n_texture), "width": width,
                      "style_settings": {k: (list(v) if isinstance(v, tuple) else v)
                                         for k, v in model.style_.settings_.items()},
                      "style_fit_s": fit_s, "image_px_per_canvas_px": px},
            "seconds": time.perf_counter() - t_start}


def _aligned_shapes(app, landmarks):
    from faceretarget.capture import procrustes_align

    return procrustes_align(np.asarray(landmarks)[:, app.points_, :2], app.reference_)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--data", type=Path, default=DATA)
    p.add_argument("--speaker", default="W009", help="speaker(s), comma-separated")
    p.add_argument("--to", default="angry,happy")
    p.add_argument("--out", type=Path, default=Path("out/emotion_video"))
    p.add_argument("--cache", type=Path, default=CACHE)
    p.add_argument("--json", action="store_true")
    a = p.parse_args(argv)
    res = {s: run(a.data, s, tuple(a.to.split(",")), a.out, cache=a.cache, log=print) for s in a.speaker.split(",")}
    if a.json:
        print(json.dumps(res))
    return 0


if __name__ == "__main__":
    sys.exit(main())
