"""Command line: ``faceretarget clone | keys compose | demo``.

Every error a user can act on is printed as one line (``faceretarget: error: ...``) naming the file,
shape or frame, and the exit code is non-zero (2 for bad input, 1 otherwise).  Outputs are written to a
temporary name and renamed when complete, and an output path that names an input is refused.
"""

from __future__ import annotations

import argparse
import sys
import time
import warnings
from pathlib import Path

import numpy as np

from . import __version__
from .errors import FaceRetargetError, InvalidDataError, OutputError

__all__ = ["main"]


class _Log:
    def __init__(self, quiet: bool):
        self.quiet = quiet

    def __call__(self, *a):
        if not self.quiet:
            print(*a, flush=True)


def _protect(out: Path, inputs: list) -> None:
    o = out.resolve()
    for p in inputs:
        if p is None:
            continue
        p = Path(p).resolve()
        if o == p or (p.is_dir() and p in o.parents and o.suffix == ""):
            raise OutputError(f"{out}: refusing to write over the input '{p}'")


def _write_clone(out: Path, cloner, weights: np.ndarray, times: np.ndarray, log) -> None:
    from .io import write_animation

    rig = cloner.target_keys
    write_animation(out, rig=rig, weights=weights, names=list(cloner.names_), times=times)
    log(f"wrote {out} ({len(times)} frames, {len(cloner.names_)} target key-models)")


def _source_frames(perf, source_rig, log):
    """Source meshes (or feature points) of a performance, playing weight takes on their rig."""
    if perf.kind == "weights":
        if source_rig is None:
            raise InvalidDataError(
                f"{perf.source}: a weight take needs the source rig it was captured for (--source-rig DIR)"
            )
        log(f"playing {perf.n_frames} frames of weights on {source_rig.name}")
        return source_rig.evaluate(source_rig.map_weights(perf.names, perf.weights, source=perf.source))
    return perf.data()


def cmd_clone(args, log) -> int:
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            return _clone(args, log)
        finally:
            seen = set()
            for c in caught:
                msg = str(c.message)
                if msg not in seen:
                    seen.add(msg)
                    log(f"warning: {msg}")


def _clone(args, log) -> int:
    from .cloning import ExpressionCloner, keymodel_pair
    from .io import load_rig, read_performance

    out = Path(args.out)
    inputs = [args.performance, args.source_keys, args.target_keys, args.source_rig, args.target_rig, args.keys_from]
    _protect(out, inputs)
    t0 = time.perf_counter()
    perf = read_performance(args.performance, fps=args.fps)
    source_rig = load_rig(args.source_rig, neutral=args.source_neutral) if args.source_rig else None
    if args.source_keys or args.target_keys:
        if not (args.source_keys and args.target_keys):
            raise InvalidDataError("give both --source-keys and --target-keys")
        sk = load_rig(args.source_keys, neutral=args.source_neutral, landmarks=args.source_landmarks)
        tk = load_rig(args.target_keys, neutral=args.target_neutral, landmarks=args.target_landmarks)
        log(f"key-models: {sk.n_shapes} pairs from {args.source_keys} and {args.target_keys}")
        if source_rig is None and perf.kind == "weights":
            source_rig = sk
    else:
        if not (args.source_rig and args.target_rig):
            raise InvalidDataError("give --source-keys/--target-keys, or --source-rig/--target-rig with --keys")
        target_rig = load_rig(args.target_rig, neutral=args.target_neutral, landmarks=args.target_landmarks)
        if args.source_landmarks is not None:
            source_rig = load_rig(args.source_rig, neutral=args.source_neutral, landmarks=args.source_landmarks)
        rom = read_performance(args.keys_from) if args.keys_from else None
        if args.keys.startswith("rom-") and rom is None:
            if perf.kind == "weights":
                log("no --keys-from take: choosing key frames from the performance itself")
                rom = perf
            else:
                raise InvalidDataError(f"--keys {args.keys} needs a range-of-motion weight take (--keys-from)")
        sk, tk, _ = keymodel_pair(source_rig, target_rig, args.keys, rom=rom)
        log(f"key-models: {args.keys}, {sk.n_shapes} pairs generated on {source_rig.name} and {target_rig.name}")
    frames = _source_frames(perf, source_rig, log)
    features = args.features
    cloner = ExpressionCloner(args.method, features=features).fit(sk, tk)
    w = cloner.transform(frames, perf.times)
    if cloner.noise_sigma_ > 0:
        log(f"estimated capture noise {cloner.noise_sigma_ * sk.mm_per_unit:.3f} mm: denoised over time")
    log(f"cloned {perf.n_frames} frames with '{args.method}' in {time.perf_counter() - t0:.2f} s; "
        f"frames outside the key-models (>35% unexplained): {(cloner.outside_ > 0.35).mean():.1%}")
    _write_clone(out, cloner, w, perf.times, log)
    return 0


def cmd_keys_compose(args, log) -> int:
    from .cloning import build_key_models
    from .io import load_rig, save_rig_obj
    from .rig import Rig

    out = Path(args.out)
    _protect(out, [args.rig])
    rig = load_rig(args.rig, neutral=args.neutral)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        labels, verts = build_key_models(rig)
    for c in caught:
        log(f"warning: {c.message}")
    # the pure "neutral" emotion is the rest face itself: it is written once, as the neutral
    keep = [i for i, lab in enumerate(labels) if lab != "neutral"]
    safe = [labels[i].replace("+", "_") for i in keep]
    keys = Rig(rig.neutral, safe, verts[keep] - rig.neutral.vertices, rig.unit, rig.landmarks, None,
               f"{rig.name}:composed")
    save_rig_obj(keys, out)
    log(f"wrote the neutral and {len(safe)} composed key-models (84 key-models) as OBJ to {out}")
    return 0


def cmd_demo(args, log) -> int:
    from .demo import run_demo

    return run_demo(Path(args.out), log=log)


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="faceretarget", description="Facial performance retargeting and expression cloning.")
    p.add_argument("--version", action="version", version=f"faceretarget {__version__}")
    p.add_argument("--quiet", "-q", action="store_true", help="print errors only")
    sub = p.add_subparsers(dest="command", required=True)

    c = sub.add_parser("clone", help="clone a performance onto another character (Pyun et al. 2003)",
                       description="Clone a performance from source key-models onto target key-models. "
                       "Either give key-model folders paired by file name (--source-keys/--target-keys), or two "
                       "ARKit-style rigs and a standard key set (--source-rig/--target-rig --keys).")
    c.add_argument("--performance", required=True, help="take: Live Link Face .csv (weights), .npz, OBJ-sequence folder")
    c.add_argument("--out", required=True, help="output: .glb, .npz, .csv, or a folder (OBJ sequence)")
    c.add_argument("--source-keys", help="folder of source key-model OBJs (neutral + expressions)")
    c.add_argument("--target-keys", help="folder of target key-model OBJs with the same file names")
    c.add_argument("--source-rig", help="source ARKit-style rig folder (also plays a weight take)")
    c.add_argument("--target-rig", help="target ARKit-style rig folder")
    c.add_argument("--keys", default="combined84",
                   help="key set for rigs: combined84, emotions6, visemes13, arkit, rom-K (default combined84)")
    c.add_argument("--keys-from", help="range-of-motion weight take for rom-K")
    c.add_argument("--features", default="landmarks", help="landmarks (landmarks68.txt), all, or a file of vertex indices")
    c.add_argument("--method", default="temporal", choices=["temporal", "linear", "pyun"],
                   help="weight functions (default temporal: linear cardinal + take-adaptive denoising)")
    c.add_argument("--fps", type=float, help="frame rate of an OBJ sequence without times.txt")
    c.add_argument("--source-landmarks", help="landmark index file for the source (default landmarks68.txt)")
    c.add_argument("--target-landmarks", help="landmark index file for the target")
    c.add_argument("--source-neutral", help="the source folder's neutral OBJ when it is not named neutral*")
    c.add_argument("--target-neutral", help="the target folder's neutral OBJ when it is not named neutral*")
    c.set_defaults(func=cmd_clone)

    k = sub.add_parser("keys", help="key-model tools")
    ksub = k.add_subparsers(dest="keys_command", required=True)
    kc = ksub.add_parser("compose", help="write the 84 composed emotion x viseme key-models of a rig as OBJ")
    kc.add_argument("--rig", required=True, help="ARKit-style rig folder")
    kc.add_argument("--out", required=True, help="output folder")
    kc.add_argument("--neutral", help="the rig's neutral OBJ when it is not named neutral*")
    kc.set_defaults(func=cmd_keys_compose)

    d = sub.add_parser("demo", help="run the main job end to end on the embedded demo characters")
    d.add_argument("--out", default="out/demo", help="output folder (default out/demo)")
    d.set_defaults(func=cmd_demo)
    return p


def main(argv=None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    log = _Log(args.quiet)
    try:
        return int(args.func(args, log) or 0)
    except FaceRetargetError as e:
        print(f"faceretarget: error: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("faceretarget: interrupted", file=sys.stderr)
        return 130
    except OSError as e:
        print(f"faceretarget: error: {e.filename or ''}: {e.strerror or e}", file=sys.stderr)
        return 1


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
