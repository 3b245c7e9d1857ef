"""Command line: ``faceretarget clone | retarget | keys compose | keys select | capture | appearance |
style fit | restyle | headmotion build | headmotion synth | demo``.

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

from .. import __version__
from ..errors import InvalidDataError, OutputError
from ._support import protect, run_command, warnings_to_log

__all__ = ["main"]


_protect = protect


def _write_clone(out: Path, cloner, weights: np.ndarray, times: np.ndarray, log) -> None:
    from ..io import write_animation

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
    with warnings_to_log(log):
        return _clone(args, log)


def _clone(args, log) -> int:
    from ..cloning import ExpressionCloner, keymodel_pair
    from ..io import load_rig, read_performance

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
    from ..cloning import build_key_models
    from ..io import load_rig, save_rig_obj
    from ..rig import Rig

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


# ----------------------------------------------------------------------------- retargeting (Chuang Ch. 3)
def _geometry_take(perf, source_rig, log, *, align: bool = True, rigid_subset=None):
    """``(points (T, P, 3), labels, neutral or None, mesh or None, aligner)`` of a take for keyshape work."""
    from ..numerics import RigidAligner

    if perf.kind == "weights":
        if source_rig is None:
            raise InvalidDataError(f"{perf.source}: a weight take needs the rig it drives (--source-rig DIR)")
        log(f"playing {perf.n_frames} frames of weights on {source_rig.name}")
        V = source_rig.evaluate(source_rig.map_weights(perf.names, perf.weights, source=perf.source))
        return V, [], source_rig.neutral.vertices, source_rig.neutral, None
    if perf.kind == "vertices":
        return perf.vertices, [], None, perf.mesh, None
    pts = perf.points
    al = None
    if pts.shape[2] == 2:                       # 2-D landmark tracks: keyshapes in the image plane (z = 0)
        log(f"{perf.source}: 2-D points; keyshapes are exported with z = 0 and no head-motion removal")
        pts = np.concatenate([pts, np.zeros(pts.shape[:2] + (1,))], axis=2)
        return pts, list(perf.labels), None, None, None
    if align and pts.shape[1] >= 4:
        subset = [s.strip() for s in rigid_subset.split(",")] if rigid_subset else None
        al = RigidAligner(subset=subset)
        perf = al.fit_transform(perf)
        log(al.report(perf.unit))
        pts = perf.points
    return pts, list(perf.labels), None, None, al


def cmd_keys_select(args, log) -> int:
    from ..io import export_keyshapes, load_rig, read_performance
    from ..numerics import SELECTION_METHODS, reconstruction_error, select_keyshapes
    from ..rig import resolve_features

    out = Path(args.out)
    _protect(out, [args.performance, args.source_rig])
    method = {"kmeans": "kmeans2", "pca": "pca-extrema", "greedy": "nnls-greedy", "qr": "pivoted-qr"}.get(
        args.method, args.method)
    if method not in SELECTION_METHODS:
        raise InvalidDataError(f"unknown selection method '{args.method}', use one of "
                               f"{', '.join(SELECTION_METHODS)} (kmeans = kmeans2)")
    if args.k < 1:
        raise InvalidDataError(f"--k must be at least 1, got {args.k}")
    t0 = time.perf_counter()
    perf = read_performance(args.performance, fps=args.fps)
    rig = load_rig(args.source_rig, neutral=args.source_neutral) if args.source_rig else None
    pts, labels, neutral, mesh, _ = _geometry_take(perf, rig, log, align=not args.no_align,
                                                   rigid_subset=args.rigid_subset)
    T = len(pts)
    complete = np.isfinite(pts).all(axis=(1, 2))
    if not complete.any():
        raise InvalidDataError(f"{perf.source}: no frame has every marker; fill gaps first")
    if neutral is None:
        nf = int(np.flatnonzero(complete)[0]) if args.neutral_frame is None else args.neutral_frame
        if not 0 <= nf < T:
            raise InvalidDataError(f"--neutral-frame {nf} is outside the take's frames 0..{T - 1}")
        if not complete[nf]:
            raise InvalidDataError(f"{perf.source}: neutral frame {nf} has missing markers; choose another")
        neutral = pts[nf]
        log(f"source neutral: frame {nf}")
    feats = np.arange(pts.shape[1])
    if rig is not None and args.features != "all":
        feats = resolve_features(args.features, rig.n_vertices, rig.landmarks, who=rig.name)
    cand = np.flatnonzero(complete)
    X = (pts[cand][:, feats] - neutral[feats]).reshape(len(cand), -1)
    if args.k > len(cand):
        raise InvalidDataError(f"--k {args.k} is more than the {len(cand)} complete frames of {perf.source}")
    frames = cand[np.asarray(select_keyshapes(X, args.k, method), dtype=int)]
    err = reconstruction_error(X, np.searchsorted(cand, frames))
    log(f"selected {len(frames)} keyshapes with {method} in {time.perf_counter() - t0:.2f} s; "
        f"non-negative reconstruction error of the take {100 * err:.2f} %")
    chosen = sorted(frames.tolist())
    if perf.kind == "points":
        from ..performance import Performance

        aligned = Performance.from_points(pts, labels, times=perf.times, unit=perf.unit, source=perf.source)
        export_keyshapes(aligned, chosen, out, neutral=neutral)
    else:
        export_keyshapes(pts, chosen, out, mesh=mesh, neutral=neutral)
    log(f"wrote {out}: {len(frames)} keyshapes, neutral.obj, keyshapes.txt and contact_sheet.png; model the "
        "target counterparts under the same file names (frame_*.obj) beside the target's neutral.obj")
    return 0


def _load_keys(folder, neutral, landmarks, rig=None):
    """Keyshapes from an exported/artist folder (``frame_*.obj``) or an ARKit-style rig folder."""
    from ..io import is_keyshape_folder, load_rig, read_marker_labels, read_target_keyshapes

    if folder is None:
        return None, []
    if Path(folder).is_dir() and is_keyshape_folder(folder):
        keys = read_target_keyshapes(folder, neutral=neutral)
        if landmarks is not None:
            keys.landmarks = np.loadtxt(landmarks, dtype=np.int64, ndmin=1)
        elif rig is not None and rig.n_vertices == keys.n_vertices:
            keys.landmarks = rig.landmarks
        return keys, read_marker_labels(folder)
    return load_rig(folder, neutral=neutral, landmarks=landmarks), []


def cmd_retarget(args, log) -> int:
    with warnings_to_log(log):
        return _retarget(args, log)


def _retarget(args, log) -> int:
    from ..io import load_rig, read_performance, write_animation
    from ..names import ARKIT_NAMES, normalize_name
    from ..performance import Performance
    from ..retarget import BlendshapeRetargeter, check_consistency, load_regions

    out = Path(args.out)
    _protect(out, [args.performance, args.source_keys, args.target_keys, args.source_rig, args.regions])
    t0 = time.perf_counter()
    perf = read_performance(args.performance, fps=args.fps)
    rig = load_rig(args.source_rig, neutral=args.source_neutral) if args.source_rig else None
    from ..io import is_keyshape_folder

    sk, labels = _load_keys(args.source_keys, args.source_neutral, args.source_landmarks, rig)
    tk, _ = _load_keys(args.target_keys, args.target_neutral, args.target_landmarks)
    rigs = not is_keyshape_folder(args.source_keys) and not is_keyshape_folder(args.target_keys)
    if rigs:
        # two ARKit-style rigs: pair their shapes through the ARKit names (split halves, aliases)
        from ..cloning import keymodel_pair

        if rig is None:
            rig = sk
        sk, tk, _ = keymodel_pair(sk, tk, "arkit")
    log(f"keyshapes: {sk.n_shapes} source from {args.source_keys}, {tk.n_shapes} target from {args.target_keys}")
    if perf.kind == "weights":
        if rig is None:
            raise InvalidDataError(f"{perf.source}: a weight take needs the rig it drives (--source-rig DIR)")
        frames = _source_frames(perf, rig, log)
        take = Performance.from_vertices(frames, times=perf.times, source=perf.source)
        take.head_rotation = perf.head_rotation
    else:
        take = perf
    regions = None
    if args.regions:
        regions = args.regions if args.regions in ("upper-lower", "default") else load_regions(args.regions)
    if args.check:
        rep = check_consistency(sk, tk)
        log(rep.table())
    rt = BlendshapeRetargeter(args.solver, upper=args.upper, l1=args.l1, l2=args.l2, smooth=args.temporal,
                              denoise=not args.no_denoise, filter_level=args.smooth, regions=regions,
                              align=not args.no_align,
                              rigid_subset=[s.strip() for s in args.rigid_subset.split(",")] if args.rigid_subset else None)
    rt.fit(sk, tk, source_labels=labels)
    W = rt.transform(take)
    if getattr(rt, "aligner_", None) is not None:
        log(rt.aligner_.report(perf.unit))
    if rt.noise_sigma_ > 0:
        log(f"estimated capture noise {rt.noise_sigma_ * sk.mm_per_unit:.3f} mm: denoised over time")
    if args.smooth:
        log(f"weight filter level {args.smooth}: removed {100 * rt.extremes_removed_:.1f} % of the extremes")
    log(f"retargeted {perf.n_frames} frames with '{args.solver}' in {time.perf_counter() - t0:.2f} s")
    ext = out.suffix.lower()
    if ext == ".csv":
        kw = rt.key_weights(W)
        arkit = [normalize_name(n) for n in rt.names_]
        if not all(n in ARKIT_NAMES for n in arkit):
            raise OutputError(f"{out}: a Live Link Face CSV needs ARKit-named target keys ({rt.names_[0]} is not "
                              "one); write .glb or .npz instead")
        write_animation(out, weights=kw, names=arkit, times=perf.times, head_rotation=take.head_rotation)
    else:
        write_animation(out, rig=rt.target_keys, weights=W, names=list(rt.weight_names_), times=perf.times)
    log(f"wrote {out} ({perf.n_frames} frames, {len(rt.weight_names_)} target keyshapes)")
    return 0


def cmd_demo(args, log) -> int:
    from ..pipelines import run_demo

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
    ks = ksub.add_parser("select", help="choose keyshape frames of a take for an artist to model (Chuang Ch. 3)",
                         description="Choose k keyshape frames of a source take and export them (OBJ per frame, "
                         "neutral.obj, keyshapes.txt, contact_sheet.png) for an artist to model the target "
                         "counterparts.  Marker takes lose their rigid head motion first.")
    ks.add_argument("--performance", required=True, help="take: .c3d markers, .csv weights (with --source-rig), "
                    ".npz, OBJ-sequence folder")
    ks.add_argument("--k", type=int, default=20, help="number of keyshapes (default 20)")
    ks.add_argument("--method", default="pivoted-qr",
                    help="pivoted-qr (default: keys for retargeting other takes too), nnls-greedy (best "
                    "non-negative fit of this take), pca-extrema (the thesis), hull, kmeans (= kmeans2), kmeans3")
    ks.add_argument("--out", required=True, help="output folder")
    ks.add_argument("--source-rig", help="rig folder a weight take drives (frames exported as its meshes)")
    ks.add_argument("--source-neutral", help="the rig's neutral OBJ when it is not named neutral*")
    ks.add_argument("--features", default="landmarks", help="with a rig: landmarks (default) or all vertices")
    ks.add_argument("--neutral-frame", type=int, help="frame of a marker/mesh take at rest (default the first "
                    "complete frame)")
    ks.add_argument("--rigid-subset", help="comma-separated markers that move with the skull (default automatic)")
    ks.add_argument("--no-align", action="store_true", help="keep the markers' rigid head motion")
    ks.add_argument("--fps", type=float, help="frame rate of an OBJ sequence without times.txt")
    ks.set_defaults(func=cmd_keys_select)

    r = sub.add_parser("retarget", help="retarget a take through source/target keyshapes (Chuang Ch. 3)",
                       description="Decompose every frame of a take into source keyshape weights and play them "
                       "on the target keyshapes.  Keyshape folders are exported frames (frame_*.obj + neutral.obj, "
                       "see 'keys select') or ARKit-style rig folders paired by shape name.")
    r.add_argument("--performance", required=True, help="take: .c3d, .csv (with --source-rig), .npz, OBJ folder")
    r.add_argument("--source-keys", required=True, help="source keyshape folder")
    r.add_argument("--target-keys", required=True, help="target keyshape folder (same file or shape names)")
    r.add_argument("--out", required=True, help="output: .glb, .csv (Live Link Face; ARKit-named keys), .npz "
                   "or a folder (OBJ sequence)")
    r.add_argument("--source-rig", help="rig a weight take drives")
    r.add_argument("--regions", help="upper-lower, or a regions JSON file (see docs/retargeting.md)")
    r.add_argument("--smooth", type=float, default=0.0, help="low-pass level of the weight curves (0 = none)")
    r.add_argument("--solver", default="signed", choices=["signed", "nnls"],
                   help="signed least squares (default; new takes) or non-negative (the thesis)")
    r.add_argument("--upper", type=float, help="nnls: upper bound of the weights (e.g. 1)")
    r.add_argument("--l1", type=float, default=0.0, help="nnls: sparsity weight")
    r.add_argument("--l2", type=float, default=0.0, help="ridge weight")
    r.add_argument("--temporal", type=float, default=0.0, help="nnls: temporal smoothness weight in the solve")
    r.add_argument("--no-denoise", action="store_true", help="do not estimate and remove capture noise")
    r.add_argument("--check", action="store_true", help="print the consistency report of the target keyshapes")
    r.add_argument("--rigid-subset", help="comma-separated markers that move with the skull (default automatic)")
    r.add_argument("--no-align", action="store_true", help="keep the markers' rigid head motion")
    r.add_argument("--source-neutral", help="neutral OBJ of the source folder (default neutral.obj / neutral*)")
    r.add_argument("--target-neutral", help="neutral OBJ of the target folder (default neutral.obj / neutral*)")
    r.add_argument("--source-landmarks", help="landmark index file for mesh source keys")
    r.add_argument("--target-landmarks", help="landmark index file for the target")
    r.add_argument("--fps", type=float, help="frame rate of an OBJ sequence without times.txt")
    r.set_defaults(func=cmd_retarget)

    from ._capture import register as _register_capture
    from ._headmotion import register as _register_headmotion
    from ._style import register as _register_style

    _register_capture(sub)
    _register_style(sub)
    _register_headmotion(sub)

    d = sub.add_parser("demo", help="run the main job end to end on the embedded demo characters")
    d.add_argument("--out", default="out/demo", help="output folder (default out/demo)")
    d.set_defaults(func=cmd_demo)
    return p


def main(argv=None) -> int:
    parser = build_parser()
    return run_command(parser.parse_args(argv))


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
