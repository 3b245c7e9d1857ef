"""Command line: ``faceretarget headmotion build | synth``.

::

    faceretarget headmotion build --take A.wav A.bvh --take B.wav B.npz ... --out DB.npz
    faceretarget headmotion synth --db DB.npz --audio NEW.wav --out HEAD.bvh|HEAD.glb|HEAD.csv \\
        [--amplitude X] [--motion-range YAW PITCH ROLL] [--no-translation] [--no-rotation] [--seed N]

:func:`register` adds the ``headmotion`` command to the main parser's subparsers; the handlers
take ``(args, log)`` and return an exit code, and raise :class:`~faceretarget.errors.FaceRetargetError`
for anything a user can fix (the main program prints it on one line and exits with 2).
:func:`main` runs the same commands stand-alone.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from ..errors import InvalidDataError
from ..formats import NPZ
from ._support import FPS, POSITIVE, Range, check_inputs, check_out, run_alone, warnings_to_log

#: Option ranges (shown in ``--help``).
AMPLITUDE = Range(0, 10)
MOTION_RANGE = Range(0, 360)
PAUSE = Range(0, 5, lo_open=True)
SEED = Range(0, 2**32 - 1, integer=True)

__all__ = ["register", "cmd_headmotion_build", "cmd_headmotion_synth", "main"]


def cmd_headmotion_build(args, log) -> int:
    """``headmotion build``: analyse takes and write a database ``.npz``."""
    pairs = [(Path(a), Path(m)) for a, m in args.take]
    out = check_out(args.out, [p for pair in pairs for p in pair], (NPZ,))      # before any work
    check_inputs(*(("--take", p) for pair in pairs for p in pair))
    if not args.f0_min < args.f0_max:
        raise InvalidDataError(f"--f0-min {args.f0_min:g} must be below --f0-max {args.f0_max:g}")
    log(f"analysing {len(pairs)} take(s) of speech and head motion")
    from ..pipelines import build_head_database
    t0 = time.perf_counter()
    with warnings_to_log(log):
        db = build_head_database(pairs, log=log, fps=args.fps, f0_min=args.f0_min, f0_max=args.f0_max,
                                 pause=args.pause, mirror=not args.no_mirror,
                                 allow_mismatch=args.allow_mismatch)
    db.save(out)
    log(f"wrote {out}: {db.summary()} ({time.perf_counter() - t0:.1f} s)")
    return 0


def cmd_headmotion_synth(args, log) -> int:
    """``headmotion synth``: head motion for new speech, written as .bvh, .glb or .csv."""
    import numpy as np

    from ..headmotion import HeadMotionDatabase
    from ..io import HEAD_FORMATS, read_audio, write_head_motion

    out = check_out(args.out, [args.db, args.audio], HEAD_FORMATS)                # before any work
    check_inputs(("--db", args.db), ("--audio", args.audio))
    if args.no_rotation and args.no_translation:
        raise InvalidDataError("--no-rotation and --no-translation together leave nothing to write")
    log(f"synthesizing head motion for {args.audio} from {args.db}")
    db = HeadMotionDatabase.load(args.db)
    audio, rate = read_audio(args.audio, speech=True)
    try:
        res = db.transform(audio, rate, amplitude=args.amplitude, rotation=not args.no_rotation,
                           translation=not args.no_translation, seed=args.seed, fps=args.fps,
                           source=str(args.audio), motion_range=args.motion_range)
    except InvalidDataError as e:
        raise InvalidDataError(f"{args.audio}: {e}") from e
    perf, info = res.take, res.info
    write_head_motion(out, perf, protect=(args.db, args.audio))
    deg = perf.head.to_euler("YXZ", degrees=True)
    rng = np.percentile(deg, 95, axis=0) - np.percentile(deg, 5, axis=0)
    log(f"{args.audio}: {perf.duration:.1f} s, {info.segmentation.n_phrases} phrase(s), "
        f"{info.segmentation.n_segments} segment(s); pitch {info.pitch_seconds:.2f} s, search and blend "
        f"{info.search_seconds:.3f} s")
    log(f"wrote {out} ({perf.n_frames} frames at {perf.fps:g} fps; yaw/pitch/roll 5-95% range "
        f"{rng[0]:.1f}/{rng[1]:.1f}/{rng[2]:.1f} deg"
        + (", no translation" if perf.head.translation is None else "") + ")")
    return 0


def register(subparsers) -> argparse.ArgumentParser:
    """Add ``headmotion build`` and ``headmotion synth`` to ``subparsers`` (from ``add_subparsers``)."""
    h = subparsers.add_parser("headmotion", help="head motion that follows the speech (Chuang 2004, Ch. 4)",
                              description="Build a database of recorded speech with head motion, and "
                              "synthesize head motion for new speech from it.")
    hs = h.add_subparsers(dest="headmotion_command", required=True)
    b = hs.add_parser("build", help="analyse takes (speech + head motion) into a database .npz",
                      description="Each --take pairs a WAV with its head motion: BVH (Neck > Neck1 > Head), "
                      "SMPL-X .npz (poses) or C3D markers (rigid cluster).")
    b.add_argument("--take", nargs=2, action="append", required=True, metavar=("AUDIO.wav", "MOTION"),
                   help="a take: speech WAV and head motion (.bvh, SMPL-X .npz, .c3d); repeat for more")
    b.add_argument("--out", required=True, help="database .npz to write")
    b.add_argument("--fps", type=FPS, default=30.0, help=f"database frame rate, {FPS} (default 30)")
    b.add_argument("--pause", type=PAUSE, default=0.3,
                   help=f"voiceless seconds that end a phrase, {PAUSE} (default 0.3)")
    b.add_argument("--f0-min", type=POSITIVE, default=60.0, help=f"lowest pitch searched, Hz, {POSITIVE} (default 60)")
    b.add_argument("--f0-max", type=POSITIVE, default=500.0,
                   help=f"highest pitch searched, Hz, {POSITIVE} and above --f0-min (default 500)")
    b.add_argument("--no-mirror", action="store_true", help="do not add left-right mirrored copies")
    b.add_argument("--allow-mismatch", action="store_true",
                   help="accept a WAV and a motion file whose durations differ by more than max(0.5 s, 2 %%) "
                   "(a warning instead of an error)")
    b.set_defaults(func=cmd_headmotion_build)

    s = hs.add_parser("synth", help="head motion for new speech from a database",
                      description="Output by extension: .bvh (Head joint, degrees), .glb (node 'head' "
                      "rotation/translation animation), .csv (Live Link Face HeadYaw/HeadPitch/HeadRoll, "
                      "radians).")
    s.add_argument("--db", required=True, help="database .npz (headmotion build)")
    s.add_argument("--audio", required=True, help="speech WAV")
    s.add_argument("--out", required=True, help="output .bvh, .glb or .csv")
    s.add_argument("--amplitude", type=AMPLITUDE, default=1.0,
                   help=f"scale of the motion, {AMPLITUDE} (default 1; 0 holds the head still)")
    s.add_argument("--motion-range", type=MOTION_RANGE, nargs=3, default=None, metavar=("YAW", "PITCH", "ROLL"),
                   help=f"degrees the head turns, 5-95%% range of each angle, {MOTION_RANGE} (e.g. the speaker's "
                   "own; default: as much as the database speakers, whoever speaks)")
    s.add_argument("--no-translation", action="store_true", help="rotation only")
    s.add_argument("--no-rotation", action="store_true", help="translation only (rotation zero)")
    s.add_argument("--seed", type=SEED, default=None,
                   help=f"pick a near-best alternative, {SEED} (default: the best path, deterministic)")
    s.add_argument("--fps", type=FPS, default=None, help=f"output frame rate, {FPS} (default the database's)")
    s.set_defaults(func=cmd_headmotion_synth)
    return h


def main(argv=None) -> int:
    """Run ``headmotion`` commands stand-alone (``argv`` starts with ``headmotion``)."""
    return run_alone(register, argv)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
