"""P6: emotion editing on real captured faces (Chuang Ch. 2 on video; issues 15 and 27).

Protocol P6 of ../shared/EVALUATION.md and docs/style.md ("Real faces").  Data: a folder of
talking-face clips of one sentence in several emotions per speaker, named as MEAD
(``M030_front_angry_level3_001.mp4``) or CREMA-D (``1001_DFA_ANG_XX.flv`` + ``.16k.wav``); see
``bench/_emotion_data.py``.  In this run:

1. **Capture** every clip (MediaPipe; cached under ``--cache``), the 68 face points with the head's
   motion removed (``pipelines.face_take``; every take of a speaker shares the neutral take's rest
   face), then every speaker normalised to one canonical face (generalised Procrustes of the
   speakers' neutral rest faces; each speaker's frames moved by the similarity of their rest face
   and re-expressed as the canonical face plus their displacement from their own rest face, so a
   speaker's identity does not count as an emotion).
2. **Alignment** of every emotion take to the same speaker's neutral take: DTW of the audio (MFCC)
   where there is audio, else of face features re-aligned by style (``StyleModel``'s own rule).
3. **Cross-speaker translation** (leave one speaker out, or ``--train`` / ``--test``), every space of
   :data:`CANDIDATES` side by side (issue 27): a :class:`~faceretarget.style.SpeakerStyleModel` (one
   :class:`~faceretarget.style.StyleModel` per emotion, settings chosen by leaving one training
   speaker out; per candidate its space: landmarks, per-region range, ARKit scores or both; the
   training speakers' intensities as acted or equalised; the edit calibrated on held-out training
   speakers or not) fitted on the training speakers' aligned takes, turns the test speaker's
   neutral take into every emotion.  ``rel_err``: frame error against the speaker's real (aligned)
   take over the real take's change from neutral (sqrt of summed squares), in the canonical face of
   step 1.  Baselines in the same run: no edit (1.0), ``additive`` (the training speakers' mean
   emotion offset, in the canonical face), ``plain`` (the thesis's asymmetric model: no prior, no
   correction, 99.9 % variance and energy).  References (not methods, they use the test speaker's
   real take): ``own_offset`` (the test speaker's own mean offset: the best any constant edit can
   do) and ``best_scale`` (the additive offset at the scale that fits the real take best).  The
   candidate ``landmarks`` is issue 15's model; :data:`DEFAULT` is the one the headline numbers,
   the character strip and the video restyle use.
4. **Recognition**: for each held-out emotion take, the style the model gives
   (:meth:`SpeakerStyleModel.recognise`: every emotion's translation of the speaker's neutral take
   fitted to the take's mean change with a free intensity, the least unexplained wins).  Baselines in
   the same run: nearest centroid (Euclidean) of the take's mean offset from the speaker's neutral
   take, centroids from the training speakers, on the tracker's ARKit scores and on the landmark
   offsets in the canonical face; the same by angle (cosine) as references.  Top-1 accuracy,
   confusion tables, chance = 1 / number of emotions.
5. ``--fit-speed``: ``StyleModel.fit`` on three point takes of ``--fit-frames`` frames (synthetic P3
   takes of S07-001's content), seconds, with the progress bars it prints.

Usage::

    python bench/emotion_video.py [--json] [--data DIR] [--train M030,W009] [--test 1001] [--cache DIR]
        [--candidates "NAME;NAME"] [--strip SPEAKER:EMOTION] [--video-restyle SPEAKERS] [--fit-speed]

``--json`` ends stdout with one line: ``{"model", "translation": {EMOTION: {"rel_err",
"additive_rel_err", "ratio", ...}}, "translation_mean_ratio", "worst_emotion_ratio",
"recognition_top1", "recognition_baseline_top1" (ARKit scores), "recognition_landmark_baseline_top1",
"chance", "recognition_confusion", "candidates": {NAME: {...}}, "test_speakers", ...}``.
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
from _emotion_data import audio_of, cached_capture, find_clips  # noqa: E402
from faceretarget.files import cache_dir  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
DATA = REPO.parent / "shared" / "data" / "emotion-video"


# ---------------------------------------------------------------------------------------------- data
def load_speakers(data: Path, cache: Path, speakers=None, log=print, emotions=None) -> dict:
    """``{speaker: {"takes": {emotion: face take}, "scores": {emotion: (T, 51)}, "audio": bool}}``
    (``emotions``: only these besides neutral).  A face take holds the 68 points with the head removed
    and the tracker's raw ARKit scores as its weights."""
    from faceretarget.pipelines import face_take, tracked_take
    from faceretarget.retarget import neutral_face

    clips = find_clips(data)
    if speakers:
        missing = [s for s in speakers if s not in clips]
        if missing:
            raise SystemExit(f"{data}: no clips of speaker(s) {', '.join(missing)} (found {', '.join(clips)})")
        clips = {s: clips[s] for s in speakers}
    out = {}
    for spk, d in clips.items():
        if emotions is not None:
            d = {e: c for e, c in d.items() if e == "neutral" or e in emotions}
        if "neutral" not in d or len(d) < 2:
            log(f"{spk}: skipped (needs a neutral clip and another emotion; has {', '.join(d)})")
            continue
        caps = {e: cached_capture(c, cache, log=lambda *_: None) for e, c in d.items()}
        rc = tracked_take(caps["neutral"])
        n0 = neutral_face(rc.points, rc.weights)
        takes, scores = {}, {}
        for e, cap in caps.items():
            tr = tracked_take(cap)
            f = face_take(cap, neutral=n0).replace(weights=tr.weights, names=list(tr.names))
            a = audio_of(d[e])
            if a is not None:
                f = f.replace(audio=a[0], audio_rate=a[1])
            takes[e] = f
            scores[e] = tr.weights
        out[spk] = {"takes": takes, "scores": scores, "audio": all(t.audio is not None for t in takes.values())}
        log(f"{spk}: {len(takes)} clips ({', '.join(sorted(takes))}), "
            f"{sum(len(t.times) for t in takes.values())} frames, audio {'yes' if out[spk]['audio'] else 'no'}")
    return out


def normalise_and_align(speakers: dict, log=print) -> tuple[dict, np.ndarray, dict]:
    """Every speaker's takes aligned to the speaker's neutral take, and put on one canonical face.

    Returns ``(frames, canonical, aligned)``: ``frames`` ``{speaker: {emotion: (C, 68, 3)}}`` on the
    canonical face of all the speakers given (the frame the errors are measured in; ``C`` = the
    neutral take's frames), ``canonical`` ``(68, 3)``, and ``aligned`` ``{speaker: {emotion:
    Performance}}``: the takes on their neutral timeline in the speaker's own face frame, with their
    aligned ARKit scores (what the models are given).
    """
    from faceretarget.style import align_speaker_takes, canonical_face

    aligned = align_speaker_takes({s: d["takes"] for s, d in speakers.items()})
    rests = {s: np.median(d["neutral"].points, axis=0) for s, d in aligned.items()}
    can = canonical_face(rests)
    out = {}
    for spk, d in aligned.items():
        out[spk] = {e: to_canonical(p.points, can, rests[spk]) for e, p in d.items()}
        log(f"{spk}: aligned {len(d) - 1} emotion takes to neutral by "
            f"{'audio (MFCC)' if speakers[spk]['audio'] else 'face features + style'}")
    return out, can, aligned


def to_canonical(X: np.ndarray, can: np.ndarray, rest: np.ndarray) -> np.ndarray:
    """Points ``(T, 68, 3)`` of a speaker whose rest face is ``rest``: the canonical face plus their
    displacement from the rest, rotated and scaled by the rest's similarity onto the canonical face."""
    from faceretarget.numerics import similarity_fit

    s, rot, c = similarity_fit(can, rest[None])
    return can + (np.asarray(X) - rest) @ rot[0] / s[0]


# ---------------------------------------------------------------------------------------------- methods
def rel_err(pred: np.ndarray, real: np.ndarray, neutral: np.ndarray) -> float:
    """Error against the real take over the real take's change from neutral (1.0 = no edit)."""
    return float(np.sqrt(np.sum((pred - real) ** 2) / max(np.sum((real - neutral) ** 2), 1e-300)))


def mean_offset(frames: dict, speakers: list[str], emotion: str) -> np.ndarray:
    """The speakers' mean (over speakers) of their mean aligned emotion-minus-neutral offset."""
    return np.mean([np.mean(frames[s][emotion] - frames[s]["neutral"], axis=0) for s in speakers], axis=0)


def fit_translation(frames: dict, speakers: list[str], emotion: str, plain: bool = False):
    """A (neutral, emotion) StyleModel on the speakers' stacked aligned frames."""
    from faceretarget.style import StyleModel

    stack = {"neutral": np.concatenate([frames[s]["neutral"] for s in speakers]),
             emotion: np.concatenate([frames[s][emotion] for s in speakers])}
    groups = np.concatenate([[s] * len(frames[s]["neutral"]) for s in speakers])
    kw = dict(prior=False, local=False, variance=0.999, energy=0.999) if plain else {}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return StyleModel(**kw).fit_frames(stack, groups=groups if len(speakers) > 1 else None)


def translate(model, neutral: np.ndarray, emotion: str) -> np.ndarray:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return np.asarray(model.known(neutral, "neutral", emotion).frames).reshape(neutral.shape)


#: The spaces measured side by side (issue 27): name -> :class:`~faceretarget.style.SpeakerStyleModel`
#: parameters.  "landmarks" is issue 15's model (the canonical face's millimetres, as acted).
CANDIDATES = {
    "landmarks": dict(space="landmarks", intensity="keep", calibrate=False),
    "range": dict(space="range", intensity="keep", calibrate=False),
    "arkit": dict(space="arkit", intensity="keep", calibrate=False),
    "landmarks, equalised": dict(space="landmarks", intensity="equalise", calibrate=False),
    "landmarks, equalised, calibrated": dict(space="landmarks", intensity="equalise", calibrate=True),
    "range, equalised, calibrated": dict(space="range", intensity="equalise", calibrate=True),
    "arkit, equalised, calibrated": dict(space="arkit", intensity="equalise", calibrate=True),
    "both, equalised, calibrated": dict(space="both", intensity="equalise", calibrate=True),
}
#: The model the headline numbers, the character strip and ``SpeakerStyleModel()``'s defaults use.
DEFAULT = "both, equalised, calibrated"


def nearest_centroid(feat: dict, train: list[str], test: str, emotion: str, labels: list[str],
                     cosine: bool = False) -> str:
    """The emotion whose centroid (over the training speakers) of mean offsets from neutral is nearest
    to the take's mean offset from its speaker's neutral take: Euclidean, or by angle (``cosine``)."""
    cents = {}
    for s in train:
        for e in labels:
            if e in feat[s]:
                d = feat[s][e] - feat[s]["neutral"]
                cents.setdefault(e, []).append(d / max(np.linalg.norm(d), 1e-300) if cosine else d)
    x = feat[test][emotion] - feat[test]["neutral"]
    if cosine:
        return max(cents, key=lambda e: float(x.ravel() @ np.mean(cents[e], axis=0).ravel()
                                                / max(np.linalg.norm(np.mean(cents[e], axis=0)), 1e-300)))
    return min(cents, key=lambda e: float(np.linalg.norm(x - np.mean(cents[e], axis=0))))


# ---------------------------------------------------------------------------------------------- evaluation
def evaluate(frames: dict, scores: dict, train_of: dict, log=print, *, aligned: dict | None = None,
             can: np.ndarray | None = None, candidates: dict | None = None) -> dict:
    """Translation and recognition for every test speaker (``train_of[test]`` = its training speakers).

    ``frames``: the metric frame (:func:`normalise_and_align`); ``scores``: ``{speaker: {emotion: mean
    ARKit scores}}`` (the trivial baseline's features); ``aligned`` and ``can``: what the candidate
    models are fitted on and the canonical face their edits are measured in; ``candidates``: name ->
    :class:`SpeakerStyleModel` parameters (default :data:`CANDIDATES`).
    """
    from faceretarget.style import SpeakerStyleModel

    candidates = CANDIDATES if candidates is None else candidates
    base_rows, rec_base, cand = [], [], {n: {"per_take": [], "recognition": [], "models": {}} for n in candidates}
    lm_feat = {s: {e: v.mean(0) for e, v in d.items()} for s, d in frames.items()}
    for test, train in train_of.items():
        emos = [e for e in frames[test] if e != "neutral"]
        neu = frames[test]["neutral"]
        labels = sorted({e for s in train for e in frames[s] if e != "neutral"})
        for e in emos:
            tr = [s for s in train if e in frames[s]]
            if not tr:
                continue
            real = frames[test][e]
            off = mean_offset(frames, tr, e)
            own = np.mean(real - neu, axis=0)
            scale = np.linspace(0.0, 2.0, 81)
            base_rows.append({
                "speaker": test, "emotion": e, "train": tr,
                "additive_rel_err": rel_err(neu + off, real, neu),
                "plain_rel_err": rel_err(translate(fit_translation(frames, tr, e, plain=True), neu, e), real, neu),
                "own_offset_rel_err": rel_err(neu + own, real, neu),
                "best_scale_rel_err": min(rel_err(neu + c * off, real, neu) for c in scale)})
            rec_base.append({"speaker": test, "emotion": e, "labels": labels,
                             "arkit": nearest_centroid(scores, train, test, e, labels),
                             "landmarks": nearest_centroid(lm_feat, train, test, e, labels),
                             "arkit_cosine": nearest_centroid(scores, train, test, e, labels, cosine=True),
                             "landmarks_cosine": nearest_centroid(lm_feat, train, test, e, labels, cosine=True)})
        if aligned is None:
            continue
        n_take = aligned[test]["neutral"]
        rest = np.median(n_take.points, axis=0)
        for name, cfg in candidates.items():
            t0 = time.perf_counter()
            m = SpeakerStyleModel(**cfg).fit({s: aligned[s] for s in train}, aligned=True)
            fit_s = time.perf_counter() - t0
            cand[name]["models"][test] = {
                "gain": m.gain_, "gain_source": m.gain_source_, "intensity": m.intensity_,
                "speaker_intensity": m.speaker_intensity_, "decoder_ridge": m.decoder_ridge_, "fit_s": fit_s,
                "settings": {e: {k: (list(v) if isinstance(v, tuple) else v) for k, v in mm.settings_.items()}
                             for e, mm in m.models_.items()}}
            for e in emos:
                if e not in m.styles_:
                    continue
                pred = to_canonical(m.transform(n_take, e, neutral=n_take).frames, can, rest)
                cand[name]["per_take"].append({"speaker": test, "emotion": e,
                                               "rel_err": rel_err(pred, frames[test][e], neu)})
                r = m.recognise(aligned[test][e], n_take)
                cand[name]["recognition"].append({"speaker": test, "emotion": e, "model": r.style,
                                                  "labels": m.styles_[1:], "intensity": r.intensity.get(e),
                                                  "unexplained": r.unexplained})
            log(f"  {test} {name:34s} fitted in {fit_s:5.1f} s; gains " +
                " ".join(f"{e[:4]} {g:.2f}" for e, g in m.gain_.items()))
    return {"baselines": base_rows, "recognition_baselines": rec_base, "candidates": cand}


def summarise(ev: dict) -> dict:
    """Per candidate: translation ratios against the additive baseline and recognition top-1."""
    add = {(r["speaker"], r["emotion"]): r for r in ev["baselines"]}
    out = {}
    for name, c in ev["candidates"].items():
        rows = [dict(add[(r["speaker"], r["emotion"])], **r) for r in c["per_take"]]
        if not rows:
            continue
        ratios = [r["rel_err"] / r["additive_rel_err"] for r in rows]
        per_e = {}
        for e in sorted({r["emotion"] for r in rows}):
            rr = [r for r in rows if r["emotion"] == e]
            m, a = float(np.mean([r["rel_err"] for r in rr])), float(np.mean([r["additive_rel_err"] for r in rr]))
            per_e[e] = {"rel_err": m, "additive_rel_err": a, "ratio": m / a,
                        "plain_rel_err": float(np.mean([r["plain_rel_err"] for r in rr])),
                        "own_offset_rel_err": float(np.mean([r["own_offset_rel_err"] for r in rr])),
                        "best_scale_rel_err": float(np.mean([r["best_scale_rel_err"] for r in rr]))}
        rec = c["recognition"]
        worst = max(per_e, key=lambda e: per_e[e]["ratio"])
        out[name] = {
            "translation_mean_ratio": float(np.mean(ratios)),
            "translation": per_e,
            "worst_emotion": worst, "worst_emotion_ratio": per_e[worst]["ratio"],
            "below_additive": f"{sum(x < 1 for x in ratios)}/{len(ratios)}",
            "recognition_top1": float(np.mean([r["model"] == r["emotion"] for r in rec])) if rec else None,
            "recognition_confusion": confusion(rec, "model"),
            "per_take": rows, "recognition": rec, "models": c["models"],
        }
    return out


def confusion(rows: list[dict], key: str) -> dict:
    out: dict[str, dict[str, int]] = {}
    for r in rows:
        out.setdefault(r["emotion"], {})
        out[r["emotion"]][r[key]] = out[r["emotion"]].get(r[key], 0) + 1
    return out


def fit_speed(frames_n: int, log=print) -> dict:
    """``StyleModel.fit`` on three point takes of ``frames_n`` frames (P3 takes of S07-001's content),
    before (the kernel correction regressed on every training frame, BLAS on every core) and after
    (on at most ``KERNEL_FRAMES``, one BLAS thread), in this run; the settings each chose."""
    from faceretarget.datasets import make_p3_takes
    from faceretarget.io import read_livelinkface, read_rig
    from faceretarget.style import StyleModel, _model, _select

    data = REPO.parent / "shared" / "data"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        p3 = make_p3_takes(read_rig(data / "ict-face"), read_livelinkface(data / "livelinkface" / "S07-001.csv"),
                           ("neutral", "happy", "angry"))
    sub = {s: p3.takes[s].slice(0, frames_n) for s in ("neutral", "happy", "angry")}
    out = {"frames": {s: len(t.times) for s, t in sub.items()}}
    cap, threads = _select.KERNEL_FRAMES, _model.FIT_BLAS_THREADS
    for name, k, th in (("before", 10**9, None), ("after", cap, threads)):
        _select.KERNEL_FRAMES, _model.FIT_BLAS_THREADS = k, th
        try:
            t0 = time.perf_counter()
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                m = StyleModel(progress=True).fit(sub, reference="neutral")
            out[name + "_s"] = time.perf_counter() - t0
            out[name + "_settings"] = {a: (list(b) if isinstance(b, tuple) else b) for a, b in m.settings_.items()}
        finally:
            _select.KERNEL_FRAMES, _model.FIT_BLAS_THREADS = cap, threads
        log(f"style fit on 3 takes of {frames_n} frames, {name}: {out[name + '_s']:.1f} s, settings "
            f"{out[name + '_settings']}")
    out["speedup"] = out["before_s"] / out["after_s"]
    return out


def character_strip(frames: dict, can: np.ndarray, speaker: str, train: list[str], emotion: str,
                    characters: list[Path], out: Path, n_cols: int = 4, log=print, *, aligned: dict,
                    model: dict | None = None) -> dict:
    """The test speaker's neutral take, its translation into ``emotion`` by a
    :class:`~faceretarget.style.SpeakerStyleModel` (``model``: its parameters, default
    :data:`DEFAULT`'s) fitted on the ``train`` speakers, and the real take, each
    retargeted onto every character (:class:`~faceretarget.retarget.LandmarkSolver`, as ``animate``
    does) and rendered at ``n_cols`` times: rows neutral / edited / real per character.  Returns the
    PNG path and, per character, the mean absolute weight difference edited-vs-real against
    neutral-vs-real (how much closer the edit brings the character to the real emotion)."""
    from faceretarget.io import read_rig
    from faceretarget.render import render_frames, render_grid, save_png
    from faceretarget.retarget import LandmarkSolver
    from faceretarget.style import SpeakerStyleModel

    neu = frames[speaker]["neutral"]
    real = frames[speaker][emotion]
    m = SpeakerStyleModel(**(CANDIDATES[DEFAULT] if model is None else model)).fit(
        {s: aligned[s] for s in train}, aligned=True)
    n_take = aligned[speaker]["neutral"]
    edited = to_canonical(m.transform(n_take, emotion, neutral=n_take).frames, can,
                          np.median(n_take.points, axis=0))
    # the times where the real take departs most from neutral, spread over the take
    idx = np.linspace(0, len(neu) - 1, n_cols + 2).round().astype(int)[1:-1]
    rows, labels, info = [], [], {}
    for cdir in characters:
        rig = read_rig(cdir)
        sol = LandmarkSolver().fit(rig, can)
        W = {k: sol.transform(v).weights for k, v in (("neutral", neu), ("edited", edited), ("real", real))}
        info[cdir.name] = {
            "weight_mae_neutral_vs_real": float(np.mean(np.abs(W["neutral"] - W["real"]))),
            "weight_mae_edited_vs_real": float(np.mean(np.abs(W["edited"] - W["real"]))),
        }
        verts = {k: rig.evaluate(w[idx]) for k, w in W.items()}
        allv = np.concatenate(list(verts.values()))
        imgs = list(render_frames(allv, rig.neutral, size=(200, 200)))
        for r, k in enumerate(("neutral", "edited", "real")):
            rows += imgs[r * len(idx):(r + 1) * len(idx)]
            labels += [f"{cdir.name} {k if k != 'edited' else 'edited -> ' + emotion} t={i / 25:.1f}s" for i in idx]
    grid = render_grid(rows, labels, cols=len(idx), font_size=11)
    out.mkdir(parents=True, exist_ok=True)
    path = save_png(out / f"character_strip_{speaker}_{emotion}.png", grid)
    log(f"character strip: {path}; " + "; ".join(
        f"{c}: weight MAE to the real take {d['weight_mae_neutral_vs_real']:.3f} unedited -> "
        f"{d['weight_mae_edited_vs_real']:.3f} edited" for c, d in info.items()))
    return {"png": str(path), **info}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--data", type=Path, default=DATA, help="folder of clips (default ../shared/data/emotion-video)")
    ap.add_argument("--train", help="training speakers, comma-separated (default: every other speaker)")
    ap.add_argument("--test", help="test speakers, comma-separated (default: every speaker, one at a time)")
    ap.add_argument("--cache", type=Path, default=cache_dir("bench", "emotion_video"),
                    help="captured clips (default: the user's faceretarget cache folder)")
    ap.add_argument("--out", type=Path, default=REPO / "out" / "emotion_video")
    ap.add_argument("--fit-speed", action="store_true", help="also time style fit on 3 x --fit-frames frames")
    ap.add_argument("--fit-frames", type=int, default=2000)
    ap.add_argument("--video-restyle", default="1001",
                    help="speaker(s) whose held-out neutral video is restyled through the appearance model "
                         "(bench/_video_restyle.py; '' for none)")
    ap.add_argument("--strip", default="W009:happy", help="SPEAKER:EMOTION of the character strip ('' for none)")
    ap.add_argument("--character", action="append", type=Path, help="character rig folder(s) of the strip "
                    "(default ../shared/data/ict-face and arkit-face)")
    ap.add_argument("--candidates", help="the spaces to measure, ';'-separated names of CANDIDATES (default: all)")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)
    log = print
    train = [s for s in (args.train or "").split(",") if s]
    test = [s for s in (args.test or "").split(",") if s]
    speakers = load_speakers(args.data, args.cache, sorted(set(train + test)) or None, log)
    if len(speakers) < 2:
        raise SystemExit(f"{args.data}: P6 needs at least two speakers with a neutral clip, found {len(speakers)}")
    frames, can, aligned = normalise_and_align(speakers, log)
    scores = {s: {e: np.nanmean(w, axis=0) for e, w in d["scores"].items()} for s, d in speakers.items()}
    tests = test or list(frames)
    train_of = {t: (train or [s for s in frames if s != t]) for t in tests}
    for t, tr in train_of.items():
        if t in tr:
            raise SystemExit(f"speaker {t} is both a training and a test speaker")
    names = [n.strip() for n in args.candidates.split(";")] if args.candidates else list(CANDIDATES)
    unknown = [n for n in names if n not in CANDIDATES]
    if unknown:
        raise SystemExit(f"--candidates: unknown {unknown}; known: {'; '.join(CANDIDATES)}")
    log("cross-speaker models (leave one speaker out):")
    ev = evaluate(frames, scores, train_of, log, aligned=aligned, can=can,
                  candidates={n: CANDIDATES[n] for n in names})
    summ = summarise(ev)
    head = DEFAULT if DEFAULT in summ else names[0]
    d = summ[head]
    base = ev["baselines"]
    rb = ev["recognition_baselines"]
    chance = float(np.mean([1.0 / len(r["labels"]) for r in rb]))

    def top1(key):
        return float(np.mean([r[key] == r["emotion"] for r in rb]))

    def base_ratio(key):
        return float(np.mean([r[key] / r["additive_rel_err"] for r in base]))

    res = {
        "model": head,
        "model_params": CANDIDATES[head],
        "translation": d["translation"],
        "translation_mean_ratio": d["translation_mean_ratio"],
        "worst_emotion": d["worst_emotion"],
        "worst_emotion_ratio": d["worst_emotion_ratio"],
        "below_additive": d["below_additive"],
        "translation_mean_ratio_plain": base_ratio("plain_rel_err"),
        "translation_mean_ratio_own_offset": base_ratio("own_offset_rel_err"),
        "translation_mean_ratio_best_scale": base_ratio("best_scale_rel_err"),
        "recognition_top1": d["recognition_top1"],
        "recognition_baseline_top1": top1("arkit"),
        "recognition_landmark_baseline_top1": top1("landmarks"),
        "recognition_arkit_cosine_top1": top1("arkit_cosine"),
        "recognition_landmark_cosine_top1": top1("landmarks_cosine"),
        "chance": chance,
        "recognition_confusion": d["recognition_confusion"],
        "recognition_baseline_confusion": confusion(rb, "arkit"),
        "recognition_landmark_baseline_confusion": confusion(rb, "landmarks"),
        "candidates": {n: {k: v for k, v in c.items() if k not in ("per_take", "recognition", "models")}
                       for n, c in summ.items()},
        "candidate_models": {n: c["models"] for n, c in summ.items()},
        "test_speakers": tests,
        "train_speakers": train_of,
        "per_take": d["per_take"],
        "recognition_per_take": d["recognition"],
        "recognition_baselines_per_take": rb,
    }
    log("\ncandidates (leave one speaker out; ratio = rel_err / additive baseline's, mean over takes):")
    log(f"  {'space':34s} {'ratio':>6s} {'worst emotion':>20s} {'below add.':>10s} {'recognition':>11s}")
    for n, c in summ.items():
        log(f"  {n:34s} {c['translation_mean_ratio']:6.3f} {c['worst_emotion']:>12s} {c['worst_emotion_ratio']:6.3f}"
            f"  {c['below_additive']:>10s} {c['recognition_top1']:10.1%}")
    log(f"\nper emotion, {head} (mean over test speakers): model / additive / plain / own offset")
    for e, x in d["translation"].items():
        log(f"  {e:10s} {x['rel_err']:.3f} / {x['additive_rel_err']:.3f} / {x['plain_rel_err']:.3f} / "
            f"{x['own_offset_rel_err']:.3f}  (ratio {x['ratio']:.3f})")
    log(f"mean ratio model / additive: {res['translation_mean_ratio']:.3f} (target < 1, moonshot 0.75); worst "
        f"emotion {res['worst_emotion']} {res['worst_emotion_ratio']:.3f} (target <= 1.05); below additive on "
        f"{res['below_additive']} takes; own-offset reference {res['translation_mean_ratio_own_offset']:.3f}, "
        f"best-scale reference {res['translation_mean_ratio_best_scale']:.3f}")
    log(f"recognition top-1: model {res['recognition_top1']:.1%}; nearest centroid on ARKit scores "
        f"{res['recognition_baseline_top1']:.1%}, on landmark offsets {res['recognition_landmark_baseline_top1']:.1%} "
        f"(by angle: {res['recognition_arkit_cosine_top1']:.1%}, {res['recognition_landmark_cosine_top1']:.1%}); "
        f"chance {chance:.1%} ({len(rb)} takes)")
    if args.strip:
        spk, _, emo = args.strip.partition(":")
        if spk in frames and emo in frames[spk]:
            chars = args.character or [REPO.parent / "shared" / "data" / "ict-face",
                                       REPO.parent / "shared" / "data" / "arkit-face"]
            res["character_strip"] = character_strip(
                frames, can, spk, train_of.get(spk, [s for s in frames if s != spk]), emo, chars, args.out, log=log,
                aligned=aligned, model=CANDIDATES[head])
    if args.video_restyle:
        import _video_restyle
        from faceretarget.style import SpeakerStyleModel

        res["video_restyle"] = {}
        for spk in [s for s in args.video_restyle.split(",") if s]:
            others = [s for s in aligned if s != spk]
            cross = (SpeakerStyleModel(**CANDIDATES[head]).fit({s: aligned[s] for s in others}, aligned=True)
                     if others else None)
            res["video_restyle"][spk] = r = _video_restyle.run(args.data, spk, ("angry", "happy"), args.out,
                                                               cache=args.cache, speakers=cross, log=log)
            rec = r["reconstruction"]["held_out"]
            log(f"video restyle {spk}: unedited held-out frames {rec['grey_mae']:.2f} grey levels "
                f"({rec['psnr_db']:.1f} dB), shape {rec['shape_px']:.2f} px; " + "; ".join(
                    f"-> {e}: shape {d['shape_px']['edited']:.2f} px (no edit {d['shape_px']['no_edit']:.2f}, "
                    f"additive {d['shape_px']['additive']:.2f})" for e, d in r["edit"].items()))
    if args.fit_speed:
        res["fit_speed"] = fit_speed(args.fit_frames, log)
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "p6.json").write_text(json.dumps(res, indent=1))
    if args.json:
        print(json.dumps(res))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
