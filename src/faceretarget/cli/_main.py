"""Command line: ``faceretarget animate | clone | retarget | keys compose | keys select | capture | appearance |
style fit | restyle | headmotion build | headmotion synth | live | batch | demo``.

Every error a user can act on is printed as one line (``faceretarget: error: ...``) naming the file,
shape or frame, and the exit code is non-zero (2 for bad input, 1 otherwise).  Outputs are written to a
temporary name and renamed when complete, and an output path that names an input is refused.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from .. import __version__
from ..errors import InvalidDataError
from ..formats import CSV
from ._support import (
    FPS,
    NO_CACHE_HELP,
    NON_NEGATIVE,
    Parser,
    Range,
    check_out,
    check_out_folder,
    neutral_option,
    parse_and_run,
    protect,
    warnings_to_log,
)

__all__ = ["main"]


_protect = protect

#: ``retarget --temporal``: relative to the source keys' mean squared norm; the same bound as
#: :data:`faceretarget.pipelines.MAX_TEMPORAL` (a test keeps them equal; the parser does not import it).
TEMPORAL = Range(0, 1000)
#: ``keys select --k``.
KEYS = Range(1, 10000, integer=True)


def _rig(path, neutral=None, landmarks=None, flag: str = "--neutral", log=None, args=None):
    """The rig folder ``path`` (None without one); a missing neutral names the command's ``flag``; ``log``
    says which rig is read (a large rig takes a second).  A character file (.glb, .fbx, ...) gives its face
    rig on its ARKit shapes (``args.shapes``), and the :class:`~faceretarget.characters.DriveRig` is kept as
    ``args.character`` for the output."""
    from ..io import is_character_file, read_rig

    if not path:
        return None
    if log is not None:
        log(f"reading {path}")
    if is_character_file(path):
        from ..characters import drive_rig, load_character

        drive = drive_rig(load_character(path, find=False, mesh=getattr(args, "mesh", None)),
                          getattr(args, "shapes", "arkit") or "arkit", need_landmarks=False)
        if args is not None:
            args.character = drive
        return drive.rig
    with neutral_option(flag):
        return read_rig(path, neutral=neutral, landmarks=landmarks)


def _character_out(args, rig_path, out: Path) -> bool:
    """``--out`` for a character file given as the target: True when it writes back into a copy of it."""
    from ..io import is_character_file

    if not rig_path or not is_character_file(rig_path):
        return False
    from ._animate import character_out

    return character_out(rig_path, out)


def cmd_clone(args, log) -> int:
    with warnings_to_log(log):
        return _clone(args, log)


def _head_choice(value: str, out: Path, target=None, back: bool = False):
    """``--head auto|off|FILE`` checked before any work: the file exists and ``out`` can hold a head (as
    ``target`` writes it, when the target keys are controls, a skeleton or drawings)."""
    from ..errors import InputFileError, OutputError
    from ..io import HEAD_READ_FORMATS, holds_head
    from ..pipelines import face_and_head_formats

    if value in ("auto", "off"):
        return value
    head = Path(value)
    if not head.is_file():
        raise InputFileError(f"{head}: head-motion file not found (--head takes auto, off or a file)")
    if head.suffix.lower() not in HEAD_READ_FORMATS:
        raise InputFileError(f"{head}: unknown head-motion format '{head.suffix}' (use {', '.join(HEAD_READ_FORMATS)})")
    if not back and not (target.holds_head(out) if target is not None and target.kind != "mesh" else holds_head(out)):
        ok = ", ".join(face_and_head_formats())
        raise OutputError(f"{out}: this format cannot hold head motion from {head}; write one that can ({ok}) "
                          "or drop --head")
    return head


def _target(args, log):
    """``--target-keys`` as a Target when it is not mesh keyshapes (a control table, a BVH / glTF
    skeleton, a folder of drawings), else None (the mesh route as before)."""
    from ..targets import read_target, target_kind

    if not args.target_keys or target_kind(args.target_keys) == "mesh":
        if getattr(args, "target_frames", None):
            raise InvalidDataError("--target-frames applies to skeleton target keys (.bvh, .glb)")
        return None
    rig = _rig(args.target_rig, args.target_neutral, None, "--target-neutral", log) if args.target_rig else None
    tgt = read_target(args.target_keys, rig=rig, frames=args.target_frames, ranges=args.control_ranges)
    if rig is not None and tgt.kind != "controls":
        raise InvalidDataError(f"--target-rig applies to control-table target keys, not to {tgt.kind} keys")
    return tgt


def _clone_keys(args, perf, source_rig, log, target=None):
    """The key-model pair of ``clone``: two folders paired by file name, or a standard set of two rigs."""
    from ..cloning import keymodel_pair
    from ..io import read_performance

    if args.source_keys or args.target_keys:
        if not (args.source_keys and args.target_keys):
            raise InvalidDataError("give both --source-keys and --target-keys")
        sk = _rig(args.source_keys, args.source_neutral, args.source_landmarks, "--source-neutral", log)
        tk = target if target is not None else _rig(args.target_keys, args.target_neutral, args.target_landmarks,
                                                       "--target-neutral", log)
        log(f"key-models: {sk.n_shapes} pairs from {args.source_keys} and {args.target_keys}")
        return sk, tk
    if not (args.source_rig and args.target_rig):
        raise InvalidDataError("give --source-keys/--target-keys, or --source-rig/--target-rig with --keys")
    target_rig = _rig(args.target_rig, args.target_neutral, args.target_landmarks, "--target-neutral", log, args)
    rom = read_performance(args.keys_from) if args.keys_from else None
    if args.keys.startswith("rom-") and rom is None:
        if perf.kind != "weights":
            raise InvalidDataError(f"--keys {args.keys} needs a range-of-motion weight take (--keys-from)")
        log("no --keys-from take: choosing key frames from the performance itself")
        rom = perf
    sk, tk, _ = keymodel_pair(source_rig, target_rig, args.keys, rom=rom)
    log(f"key-models: {args.keys}, {sk.n_shapes} pairs generated on {source_rig.name} and {target_rig.name}")
    return sk, tk


_BAKE_HELP = "USD output: time-sampled mesh points instead of blend shapes + weights"
_RANGE_HELP = ("range every output weight stays in: LO HI, 'auto' (default: 0 1 for an ARKit-style target "
               "rig's own shapes, -0.5 1.5 for example-based key-models) or 'none' (unconstrained)")


def _weight_range(words: list[str]):
    """``--weight-range``: 'auto', 'none' or LO HI."""
    from ..numerics import weight_range

    if len(words) == 1 and words[0].strip().lower() == "auto":
        return "auto"
    return weight_range(" ".join(words), what="--weight-range")


def _clone(args, log) -> int:
    out = check_out(args.out, [args.performance, args.source_keys, args.target_keys, args.source_rig,
                               args.target_rig, args.keys_from, args.target_frames,
                               None if args.head in ("auto", "off") else args.head])
    back = _character_out(args, args.target_rig, out)
    log(f"cloning {args.performance} onto {args.target_rig or args.target_keys}")
    # the heavy imports after the quick checks
    from ..io import read_performance
    from ..pipelines import check_result_path, clone_take, write_result

    target = _target(args, log)                            # controls, skeleton or drawings: their own formats
    if not back:
        check_result_path(out, bake=args.bake, target=target)  # before any work: format, folder, --bake
    head = _head_choice(args.head, out, target, back)
    weight_range = _weight_range(args.weight_range)
    perf = read_performance(args.performance, fps=args.fps)
    source_rig = _rig(args.source_rig, args.source_neutral,
                      args.source_landmarks if not (args.source_keys or args.target_keys) else None,
                      "--source-neutral", log)
    args.character = None
    sk, tk = _clone_keys(args, perf, source_rig, log, target)
    if target is None and not back:
        check_result_path(out, keys=tk, bake=args.bake)    # a .csv needs ARKit keys: known before the solve
    job = clone_take(perf, sk, tk, source_rig=source_rig, method=args.method, features=args.features,
                     weight_range=weight_range, log=log)
    write_result(out, job, head=head, bake=args.bake, progress=not log.quiet, character=args.character,
                 neck_share=args.neck_share, log=log)
    return 0


def cmd_keys_compose(args, log) -> int:
    out = check_out_folder(args.out, [args.rig])            # before any work (and the heavy imports)
    from ..io import write_rig
    from ..pipelines import compose_keys

    keys = compose_keys(_rig(args.rig, args.neutral, log=log), log=log)
    write_rig(keys, out)
    log(f"wrote the neutral and {keys.n_shapes} composed key-models (84 key-models) as OBJ to {out}")
    return 0


def _subset(text: str | None):
    return [s.strip() for s in text.split(",")] if text else None


def cmd_keys_select(args, log) -> int:
    out = check_out_folder(args.out, [args.performance, args.source_rig])     # before any work
    log(f"reading {args.performance}")
    template = None
    if args.controls_template:
        template = check_out(args.controls_template, [args.performance, args.source_rig, args.template_rig],
                             exts=(CSV,), option="--controls-template")
    from ..io import read_performance, write_keyshapes
    from ..performance import Performance
    from ..pipelines import select_keys

    perf = read_performance(args.performance, fps=args.fps)
    rig = _rig(args.source_rig, args.source_neutral, flag="--source-neutral", log=log)
    sel = select_keys(perf, args.k, args.method, source_rig=rig,
                      features=args.features, neutral_frame=args.neutral_frame, align=not args.no_align,
                      rigid_subset=_subset(args.rigid_subset), progress=not log.quiet, log=log)
    geo = sel.geometry
    if perf.kind == "points":
        aligned = Performance.from_points(geo.points, geo.labels, times=perf.times, unit=perf.unit, source=perf.source)
        write_keyshapes(aligned, sel.frames, out, neutral=sel.neutral, progress=not log.quiet)
    else:
        write_keyshapes(geo.points, sel.frames, out, mesh=geo.mesh, neutral=sel.neutral, basis=sel.basis,
                        basis_names=sel.basis_names, progress=not log.quiet)
    extra = ", key_weights.csv" if sel.basis is not None else ""
    log(f"wrote {out}: {len(sel.frames)} keyshapes, neutral.obj, keyshapes.txt{extra} and contact_sheet.png; model "
        "the target counterparts under the same file names (frame_*.obj) beside the target's neutral.obj")
    if template is not None:
        from ..io import keyshape_filename, write_control_template
        from ..names import ARKIT_NAMES

        controls = list(_rig(args.template_rig, flag="--template-rig").names) if args.template_rig else list(ARKIT_NAMES)
        keys = [keyshape_filename(f)[:-4] for f in sel.frames]
        write_control_template(template, keys, controls)
        log(f"wrote {template}: a control table to fill, one row per keyshape ({len(keys)}), one column per control "
            f"({len(controls)}), range 0:1; pose the target with its sliders for each keyshape and type the values "
            "(an empty cell is a slider left at rest), then retarget with --target-keys "
            f"{template.name}")
    return 0


def cmd_retarget(args, log) -> int:
    with warnings_to_log(log):
        return _retarget(args, log)


def _retarget(args, log) -> int:
    out = check_out(args.out, [args.performance, args.source_keys, args.target_keys, args.source_rig, args.regions,
                               args.target_rig, args.target_frames, None if args.head in ("auto", "off") else args.head])
    back = _character_out(args, args.target_keys, out)
    log(f"retargeting {args.performance} onto {args.target_keys}")
    # the heavy imports after the quick checks
    from ..cloning import keymodel_pair
    from ..io import is_character_file, is_keyshape_folder, read_keys, read_performance
    from ..pipelines import check_result_path, retarget_take, write_result
    from ..retarget import load_regions

    target = None if back else _target(args, log)          # controls, skeleton or drawings: their own formats
    if not back:
        check_result_path(out, bake=args.bake, target=target)  # before any work: format, folder, --bake
    head = _head_choice(args.head, out, target, back)
    for opt, v in (("--temporal", args.temporal), ("--l1", args.l1)):
        if v and args.solver != "nnls":
            raise InvalidDataError(f"{opt} {v:g} applies to --solver nnls only (the default 'signed' solve has no "
                                   f"such term{'; smooth its curves with --smooth' if opt == '--temporal' else ''})")
    weight_range = _weight_range(args.weight_range)
    perf = read_performance(args.performance, fps=args.fps)
    rig = _rig(args.source_rig, args.source_neutral, flag="--source-neutral", log=log)
    log(f"reading the keyshapes {args.source_keys} and {args.target_keys}")
    with neutral_option("--source-neutral"):
        sk, labels = read_keys(args.source_keys, neutral=args.source_neutral, landmarks=args.source_landmarks,
                               rig=rig)
    args.character = None
    if target is not None:
        tk = target
    elif is_character_file(args.target_keys):               # a character file: its ARKit shapes
        tk = _rig(args.target_keys, args=args)
    else:
        with neutral_option("--target-neutral"):
            tk, _ = read_keys(args.target_keys, neutral=args.target_neutral, landmarks=args.target_landmarks)
    if target is None and not is_keyshape_folder(args.source_keys) and not is_keyshape_folder(args.target_keys):
        # two ARKit-style rigs: pair their shapes through the ARKit names (split halves, aliases)
        rig = sk if rig is None else rig
        sk, tk, _ = keymodel_pair(sk, tk, "arkit")
    log(f"keyshapes: {sk.n_shapes} source from {args.source_keys}, "
        f"{tk.n_keys if target is not None else tk.n_shapes} target from {args.target_keys}")
    if target is None and not back:
        check_result_path(out, keys=tk, bake=args.bake)    # a .csv needs ARKit keys: known before the solve
    regions = None
    if args.regions:
        regions = args.regions if args.regions in ("upper-lower", "default") else load_regions(args.regions)
    if perf.kind == "weights" and rig is None:
        raise InvalidDataError(f"{perf.source}: a weight take needs the rig it drives (--source-rig DIR)")
    job = retarget_take(perf, sk, tk, source_labels=labels, source_rig=rig, check=args.check, log=log,
                        solver=args.solver, weight_range=weight_range, l1=args.l1, l2=args.l2,
                        temporal=args.temporal,
                        denoise=not args.no_denoise, filter_level=args.smooth, regions=regions,
                        align=not args.no_align, rigid_subset=_subset(args.rigid_subset))
    write_result(out, job, head=head, bake=args.bake, progress=not log.quiet, character=args.character,
                 neck_share=args.neck_share, log=log)
    return 0


def cmd_demo(args, log) -> int:
    from ..pipelines import run_demo

    out = check_out_folder(args.out, parents=True)          # before any work (missing folders are created)
    return run_demo(out, log=log, progress=not log.quiet)


_HEAD_HELP = ("head motion written with the face (.glb head node, .csv head columns): auto (default) = the "
              "take's own, off = none, or a head-motion file (.bvh, SMPL-X .npz, .c3d, .glb, .csv) resampled "
              "to the take's times")


_FRAMES_HELP = ("skeleton target keys: which frames are the key poses: a .json {key: frame} (\"neutral\": the rest "
                "pose, default frame 0), a .csv of key,frame rows, or a .txt/.json list of key names for frames 1, 2, ...")
_CLIP_HELP = ("control targets: frames whose controls leave their declared ranges are solved again inside them "
              "(solve, the default: the nearest blend of the keys in the target's geometry), written as first "
              "solved (report), clipped (clip), or replaced by the nearest in-range controls in the rig's shapes "
              "(project); the share outside as first solved is reported either way")


def _register_clone(sub) -> None:
    """``faceretarget clone``."""
    c = sub.add_parser("clone", help="clone a performance onto another character (Pyun et al. 2003)",
                       description="Clone a performance from source key-models onto target key-models. "
                       "Either give key-model folders paired by file name (--source-keys/--target-keys), or two "
                       "ARKit-style rigs and a standard key set (--source-rig/--target-rig --keys).")
    c.add_argument("--performance", required=True, help="take: Live Link Face .csv (weights), .npz, OBJ-sequence folder")
    c.add_argument("--out", required=True, help="output: .glb, .npz, .csv, or a folder (OBJ sequence)")
    c.add_argument("--head", default="auto", metavar="auto|off|FILE", help=_HEAD_HELP)
    c.add_argument("--bake", action="store_true", help=_BAKE_HELP)
    c.add_argument("--source-keys", help="folder of source key-model OBJs (neutral + expressions)")
    c.add_argument("--target-keys", help="folder of target key-model OBJs with the same file names, or target keys "
                   "in the target's own parameters: a control table (.csv/.json), a BVH or glTF skin (with "
                   "--target-frames), a folder of SVG drawings or 2-D point sets (docs/targets.md)")
    c.add_argument("--source-rig", help="source ARKit-style rig folder (also plays a weight take)")
    c.add_argument("--target-rig", help="target ARKit-style rig folder or character file (.glb/.vrm/.fbx/.blend/.usd*; "
                   "an --out in its own format writes the animation back into a copy of it) (with a control table: the "
                   "rig whose shapes "
                   "the controls drive, for .glb/.usd/.blend output)")
    c.add_argument("--target-frames", help=_FRAMES_HELP)
    c.add_argument("--control-ranges", default="solve", choices=["solve", "report", "clip", "project"],
                   help=_CLIP_HELP)
    c.add_argument("--keys", default="combined84",
                   help="key set for rigs: combined84, emotions6, visemes13, arkit, rom-K (default combined84)")
    c.add_argument("--keys-from", help="range-of-motion weight take for rom-K")
    c.add_argument("--features", default="landmarks", help="landmarks (landmarks68.txt), all, or a file of vertex indices")
    c.add_argument("--method", default="temporal", choices=["temporal", "linear", "pyun"],
                   help="weight functions (default temporal: linear cardinal + take-adaptive denoising)")
    c.add_argument("--weight-range", nargs="+", default=["auto"], metavar="LO HI", help=_RANGE_HELP)
    c.add_argument("--fps", type=FPS, help=f"frame rate of an OBJ sequence without times.txt, {FPS}")
    c.add_argument("--source-landmarks", help="landmark index file for the source (default landmarks68.txt)")
    c.add_argument("--target-landmarks", help="landmark index file for the target")
    c.add_argument("--source-neutral", help="the source folder's neutral OBJ when it is not named neutral*")
    c.add_argument("--target-neutral", help="the target folder's neutral OBJ when it is not named neutral*")
    _character_options(c)
    c.set_defaults(func=cmd_clone)


def _character_options(p) -> None:
    """``--shapes`` / ``--mesh`` / ``--neck-share`` for a target given as a character file (.glb, .fbx, ...)."""
    from ._animate import NECK_SHARE

    p.add_argument("--shapes", default="arkit", help="a target character file's shapes the ARKit curves drive "
                   "(default arkit; or names/patterns separated by commas)")
    p.add_argument("--mesh", help="a target character file's face mesh when it holds several heads")
    p.add_argument("--neck-share", type=NECK_SHARE, default=0.0,
                   help=f"a target character's neck share of the head rotation, {NECK_SHARE} (default 0)")


def _register_keys(sub) -> None:
    """``faceretarget keys compose | select``."""
    k = sub.add_parser("keys", help="key-model tools")
    ksub = k.add_subparsers(dest="keys_command", required=True)
    kc = ksub.add_parser("compose", help="write the 84 composed emotion x viseme key-models of a rig as OBJ")
    kc.add_argument("--rig", required=True, help="ARKit-style rig folder")
    kc.add_argument("--out", required=True, help="output folder")
    kc.add_argument("--neutral", help="the rig's neutral OBJ when it is not named neutral*")
    kc.set_defaults(func=cmd_keys_compose)
    ks = ksub.add_parser("select", help="choose keyshape frames of a take for an artist to model (Chuang Ch. 3)",
                         description="Choose k keyshape frames of a source take and export them (OBJ per frame, "
                         "neutral.obj, keyshapes.txt, contact_sheet.png) for an artist to model the target "
                         "counterparts.  Marker takes lose their rigid head motion first.")
    ks.add_argument("--performance", required=True, help="take: .c3d markers, .csv weights (with --source-rig), "
                    ".npz, OBJ-sequence folder")
    ks.add_argument("--k", type=KEYS, default=20, help=f"number of keyshapes, {KEYS} (default 20)")
    ks.add_argument("--method", default="pivoted-qr",
                    help="pivoted-qr (default: keys for retargeting other takes too), nnls-greedy (best "
                    "non-negative fit of this take), pca-extrema (the thesis), hull, kmeans (= kmeans2), kmeans3")
    ks.add_argument("--out", required=True, help="output folder")
    ks.add_argument("--source-rig", help="rig folder a weight take drives (frames exported as its meshes)")
    ks.add_argument("--source-neutral", help="the rig's neutral OBJ when it is not named neutral*")
    ks.add_argument("--features", default="landmarks", help="with a rig: landmarks (default) or all vertices")
    ks.add_argument("--neutral-frame", type=Range(0, integer=True), help="frame of a marker/mesh take at rest, "
                    ">= 0 (default the first complete frame)")
    ks.add_argument("--rigid-subset", help="comma-separated markers that move with the skull (default automatic)")
    ks.add_argument("--no-align", action="store_true", help="keep the markers' rigid head motion")
    ks.add_argument("--fps", type=FPS, help=f"frame rate of an OBJ sequence without times.txt, {FPS}")
    ks.add_argument("--controls-template", help="also write an empty control table (.csv) for a target posed with its "
                    "own sliders: one row per keyshape, one column per control (docs/targets.md)")
    ks.add_argument("--template-rig", help="with --controls-template: the target rig whose shape names are the "
                    "columns (default the 52 ARKit names)")
    ks.set_defaults(func=cmd_keys_select)


def _register_retarget(sub) -> None:
    """``faceretarget retarget``."""
    r = sub.add_parser("retarget", help="retarget a take through source/target keyshapes (Chuang Ch. 3)",
                       description="Decompose every frame of a take into source keyshape weights and play them "
                       "on the target keyshapes.  Keyshape folders are exported frames (frame_*.obj + neutral.obj, "
                       "see 'keys select') or ARKit-style rig folders paired by shape name.")
    r.add_argument("--performance", required=True, help="take: .c3d, .csv (with --source-rig), .npz, OBJ folder")
    r.add_argument("--source-keys", required=True, help="source keyshape folder")
    r.add_argument("--target-keys", required=True, help="target keyshape folder (same file or shape names), or "
                   "target keys in the target's own parameters: a control table (.csv/.json, rows named like the "
                   "source keyshapes), a BVH or glTF skin (with --target-frames), a folder of SVG drawings or 2-D "
                   "point sets (neutral.svg + one per key; docs/targets.md)")
    r.add_argument("--out", required=True, help="output: .glb, .csv (Live Link Face; keys ARKit-named or defined "
                   "by ARKit weights), .npz or a folder (OBJ sequence); control targets .csv/.json curves (and the "
                   "rig's formats with --target-rig), skeletons .bvh/.glb, drawings .svg/.png/.mp4/.npz or a folder")
    r.add_argument("--target-rig", help="with a control table: the target rig whose shapes the controls drive "
                   "(.glb/.usd/.blend output and the solve in the rig's geometry)")
    r.add_argument("--target-frames", help=_FRAMES_HELP)
    r.add_argument("--control-ranges", default="solve", choices=["solve", "report", "clip", "project"],
                   help=_CLIP_HELP)
    r.add_argument("--head", default="auto", metavar="auto|off|FILE", help=_HEAD_HELP)
    r.add_argument("--bake", action="store_true", help=_BAKE_HELP)
    r.add_argument("--source-rig", help="rig a weight take drives")
    r.add_argument("--regions", help="upper-lower, or a regions JSON file (see docs/retargeting.md)")
    r.add_argument("--smooth", type=NON_NEGATIVE, default=0.0,
                   help=f"low-pass level of the weight curves, {NON_NEGATIVE} (0 = none, the default)")
    r.add_argument("--solver", default="signed", choices=["signed", "nnls"],
                   help="signed least squares (default; new takes) or non-negative (the thesis)")
    r.add_argument("--weight-range", nargs="+", default=["auto"], metavar="LO HI", help=_RANGE_HELP)
    r.add_argument("--l1", type=NON_NEGATIVE, default=0.0, help=f"nnls: sparsity weight, {NON_NEGATIVE} (default 0)")
    r.add_argument("--l2", type=NON_NEGATIVE, default=0.0, help=f"ridge weight, {NON_NEGATIVE} (default 0)")
    r.add_argument("--temporal", type=TEMPORAL, default=0.0,
                   help=f"nnls: temporal smoothness inside the solve, {TEMPORAL}, in units of the source keys' mean "
                   "squared norm (the same for a rig in m or cm): 0 none (default), about 1 visibly smoother, "
                   "100 and more nearly constant weights; the solve stops converging from about 3000")
    r.add_argument("--no-denoise", action="store_true", help="do not estimate and remove capture noise")
    r.add_argument("--check", action="store_true", help="print the consistency report of the target keyshapes")
    r.add_argument("--rigid-subset", help="comma-separated markers that move with the skull (default automatic)")
    r.add_argument("--no-align", action="store_true", help="keep the markers' rigid head motion")
    r.add_argument("--source-neutral", help="neutral OBJ of the source folder (default neutral.obj / neutral*)")
    r.add_argument("--target-neutral", help="neutral OBJ of the target folder (default neutral.obj / neutral*)")
    r.add_argument("--source-landmarks", help="landmark index file for mesh source keys")
    r.add_argument("--target-landmarks", help="landmark index file for the target")
    r.add_argument("--fps", type=FPS, help=f"frame rate of an OBJ sequence without times.txt, {FPS}")
    _character_options(r)
    r.set_defaults(func=cmd_retarget)


def _register_demo(sub) -> None:
    """``faceretarget demo``."""
    d = sub.add_parser("demo", help="run the main job end to end on the embedded demo characters")
    d.add_argument("--out", default="out/demo", help="output folder (default out/demo)")
    d.set_defaults(func=cmd_demo)


def build_parser() -> argparse.ArgumentParser:
    p = Parser(prog="faceretarget", description="Facial performance retargeting and expression cloning.")
    p.add_argument("--version", action="version", version=f"faceretarget {__version__}")
    p.add_argument("--quiet", "-q", action="store_true", help="print errors only")
    p.add_argument("--no-cache", action="store_true", help=NO_CACHE_HELP)
    sub = p.add_subparsers(dest="command", required=True)

    _register_clone(sub)
    _register_keys(sub)
    _register_retarget(sub)
    from ._animate import register as _register_animate
    from ._batch import register as _register_batch
    from ._capture import register as _register_capture
    from ._character import register as _register_character
    from ._headmotion import register as _register_headmotion
    from ._live import register as _register_live
    from ._style import register as _register_style

    _register_animate(sub)
    _register_character(sub)
    _register_capture(sub)
    _register_style(sub)
    _register_headmotion(sub)
    _register_live(sub)
    _register_batch(sub)

    _register_demo(sub)
    return p


def main(argv=None) -> int:
    """Run ``faceretarget`` with ``argv`` (default ``sys.argv[1:]``); returns the exit code: 0, 2 for bad
    options or input (one ``faceretarget: error:`` line on stderr), 1 for system errors."""
    return parse_and_run(build_parser(), argv)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
