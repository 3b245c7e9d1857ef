"""P6: emotion editing on real captured faces (Chuang Ch. 2 on video; issue 15).

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
3. **Cross-speaker translation** (leave one speaker out, or ``--train`` / ``--test``): for each
   emotion, a :class:`~faceretarget.style.StyleModel` (neutral, emotion) on the training speakers'
   stacked aligned frames, its settings chosen by leaving one training speaker out
   (``fit_frames(groups=)``), turns the test speaker's neutral take into the emotion.  ``rel_err``:
   frame error against the speaker's real (aligned) take over the real take's change from neutral
   (sqrt of summed squares).  Baselines in the same run: no edit (1.0), ``additive`` (the training
   speakers' mean emotion offset, in the canonical face), ``plain`` (the thesis's asymmetric model:
   no prior, no correction, 99.9 % variance and energy).  References (not methods, they use the
   test speaker's real take): ``own_offset`` (the test speaker's own mean offset: the best any
   constant edit can do) and ``best_scale`` (the additive offset at the scale that fits the real
   take best).
4. **Recognition**: for each held-out emotion take (aligned to the speaker's neutral take), the
   style the models infer: every emotion's translation of the neutral take is fitted to the take
   with a free amount ``a >= 0`` (Eq. 2.15's interpolation), and the emotion whose fitted edit
   leaves the smallest error wins.  Baseline in the same run: nearest centroid of the take's mean
   ARKit-score offset from the speaker's neutral take (centroids from the training speakers).
   Top-1 accuracy, confusion table, chance = 1 / number of emotions.
5. ``--fit-speed``: ``StyleModel.fit`` on three point takes of ``--fit-frames`` frames (synthetic P3
   takes of S07-001's content), seconds, with the progress bars it prints.

Usage::

    python bench/emotion_video.py [--json] [--data DIR] [--train M030,W009] [--test 1001] [--cache DIR]

``--json`` ends stdout with one line: ``{"translation": {EMOTION: {"rel_err", "additive_rel_err",
"plain_rel_err", ...}}, "translation_mean_ratio", "recognition_top1", "recognition_baseline_top1",
"chance", "test_speakers", ...}``.
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

REPO = Path(__file__).resolve().parents[1]
DATA = REPO.parent / "shared" / "data" / "emotion-video"


# ---------------------------------------------------------------------------------------------- data
def load_speakers(data: Path, cache: Path, speakers=None, log=print, emotions=None) -> dict:
    """``{speaker: {"takes": {emotion: face take}, "scores": {emotion: (T, 51)}, "audio": bool}}``
    (``emotions``: only these besides neutral)."""
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
            f = face_take(cap, neutral=n0)
            a = audio_of(d[e])
            if a is not None:
                f = f.replace(audio=a[0], audio_rate=a[1])
            takes[e] = f
            scores[e] = tracked_take(cap).weights
        out[spk] = {"takes": takes, "scores": scores, "audio": all(t.audio is not None for t in takes.values())}
        log(f"{spk}: {len(takes)} clips ({', '.join(sorted(takes))}), "
            f"{sum(len(t.times) for t in takes.values())} frames, audio {'yes' if out[spk]['audio'] else 'no'}")
    return out


def canonical_face(rests: dict[str, np.ndarray], iters: int = 10) -> np.ndarray:
    """Generalised Procrustes mean (68, 3) of the speakers' rest faces."""
    from faceretarget.retarget import similarity_fit

    R = list(rests.values())
    can = R[0].copy()
    for _ in range(iters):
        al = []
        for r in R:
            s, rot, c = similarity_fit(can, r[None])
            al.append(((r - c[0]) @ rot[0]) / s[0])
        can = np.mean(al, axis=0)
    return can


def normalise_and_align(speakers: dict, log=print) -> tuple[dict, np.ndarray]:
    """Every speaker's takes on the canonical face and aligned to the speaker's neutral take.

    Returns ``({speaker: {emotion: (C, 68, 3)}}, canonical (68, 3))``; ``C`` = the neutral take's frames.
    """
    from faceretarget.retarget import similarity_fit
    from faceretarget.style import align_performances, realign_by_style, warp_performance

    rests = {s: np.median(d["takes"]["neutral"].points, axis=0) for s, d in speakers.items()}
    can = canonical_face(rests)
    out = {}
    for spk, d in speakers.items():
        s, rot, c = similarity_fit(can, rests[spk][None])

        def to_can(X, s=s, rot=rot, c=c, rest=rests[spk]):
            return can + (((X - c[0]) @ rot[0]) / s[0] - ((rest - c[0]) @ rot[0]) / s[0])

        ref = d["takes"]["neutral"]
        al_takes = {"neutral": to_can(ref.points)}
        for e, take in d["takes"].items():
            if e == "neutral":
                continue
            al = align_performances(ref, take, by="auto")
            if al.by == "face":
                al = realign_by_style(ref, take, al, iterations=2)
            al_takes[e] = to_can(warp_performance(take, al).points)
        out[spk] = al_takes
        log(f"{spk}: aligned {len(al_takes) - 1} emotion takes to neutral by "
            f"{'audio (MFCC)' if d['audio'] else 'face features + style'}")
    return out, can


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


def fitted_amount_error(change: np.ndarray, observed: np.ndarray) -> float:
    """Residual of ``observed ~ a * change`` with the best ``a >= 0`` (both (C, 68, 3) changes)."""
    c, o = change.ravel(), observed.ravel()
    a = max(0.0, float(c @ o) / max(float(c @ c), 1e-300))
    return float(np.sum((o - a * c) ** 2))


def nearest_centroid(feat: dict, train: list[str], test: str, emotion: str, labels: list[str]) -> str:
    cents = {}
    for s in train:
        for e in labels:
            if e in feat[s]:
                cents.setdefault(e, []).append(feat[s][e] - feat[s]["neutral"])
    x = feat[test][emotion] - feat[test]["neutral"]
    return min(cents, key=lambda e: float(np.linalg.norm(x - np.mean(cents[e], axis=0))))


# ---------------------------------------------------------------------------------------------- evaluation
def evaluate(frames: dict, scores: dict, train_of: dict, log=print) -> dict:
    """Translation and recognition for every test speaker (``train_of[test]`` = its training speakers)."""
    trans: dict[str, dict[str, list]] = {}
    per_take = []
    rec_rows = []
    for test, train in train_of.items():
        emos = [e for e in frames[test] if e != "neutral"]
        neu = frames[test]["neutral"]
        changes = {}
        for e in sorted({e for s in train for e in frames[s] if e != "neutral"}):
            tr = [s for s in train if e in frames[s]]
            t0 = time.perf_counter()
            model = fit_translation(frames, tr, e)
            changes[e] = translate(model, neu, e) - neu
            if e not in emos:
                continue
            real = frames[test][e]
            off = mean_offset(frames, tr, e)
            own = np.mean(real - neu, axis=0)
            scale = np.linspace(0.0, 2.0, 81)
            row = {
                "rel_err": rel_err(neu + changes[e], real, neu),
                "additive_rel_err": rel_err(neu + off, real, neu),
                "plain_rel_err": rel_err(translate(fit_translation(frames, tr, e, plain=True), neu, e), real, neu),
                "own_offset_rel_err": rel_err(neu + own, real, neu),
                "best_scale_rel_err": min(rel_err(neu + c * off, real, neu) for c in scale),
                "settings": {k: (list(v) if isinstance(v, tuple) else v) for k, v in model.settings_.items()},
                "seconds": time.perf_counter() - t0,
            }
            per_take.append({"speaker": test, "emotion": e, "train": tr, **row})
            for k in ("rel_err", "additive_rel_err", "plain_rel_err", "own_offset_rel_err", "best_scale_rel_err"):
                trans.setdefault(e, {}).setdefault(k, []).append(row[k])
            log(f"  {test} {e:10s} model {row['rel_err']:.3f}  additive {row['additive_rel_err']:.3f}  plain "
                f"{row['plain_rel_err']:.3f}  | own offset {row['own_offset_rel_err']:.3f}, best scale "
                f"{row['best_scale_rel_err']:.3f}  ({row['seconds']:.1f} s)")
        labels = sorted(changes)
        for e in emos:
            obs = frames[test][e] - neu
            err = {c: fitted_amount_error(changes[c], obs) for c in labels}
            guess = min(err, key=err.get)
            base = nearest_centroid(scores, train, test, e, labels)
            rec_rows.append({"speaker": test, "emotion": e, "model": guess, "baseline": base, "labels": labels})
    return {"per_take": per_take, "translation": trans, "recognition": rec_rows}


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
                    characters: list[Path], out: Path, n_cols: int = 4, log=print) -> dict:
    """The test speaker's neutral take, its translation into ``emotion`` and the real take, each
    retargeted onto every character (:class:`~faceretarget.retarget.LandmarkSolver`, as ``animate``
    does) and rendered at ``n_cols`` times: rows neutral / edited / real per character.  Returns the
    PNG path and, per character, the mean absolute weight difference edited-vs-real against
    neutral-vs-real (how much closer the edit brings the character to the real emotion)."""
    from faceretarget.io import read_rig
    from faceretarget.render import render_frames, render_grid, save_png
    from faceretarget.retarget import LandmarkSolver

    neu = frames[speaker]["neutral"]
    real = frames[speaker][emotion]
    edited = translate(fit_translation(frames, [s for s in train if emotion in frames[s]], emotion), neu, emotion)
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
    ap.add_argument("--cache", type=Path, default=REPO / "out" / "emotion_video" / "captures")
    ap.add_argument("--out", type=Path, default=REPO / "out" / "emotion_video")
    ap.add_argument("--fit-speed", action="store_true", help="also time style fit on 3 x --fit-frames frames")
    ap.add_argument("--fit-frames", type=int, default=2000)
    ap.add_argument("--video-restyle", default="1001",
                    help="speaker(s) whose held-out neutral video is restyled through the appearance model "
                         "(bench/_video_restyle.py; '' for none)")
    ap.add_argument("--strip", default="W009:happy", help="SPEAKER:EMOTION of the character strip ('' for none)")
    ap.add_argument("--character", action="append", type=Path, help="character rig folder(s) of the strip "
                    "(default ../shared/data/ict-face and arkit-face)")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)
    log = print
    train = [s for s in (args.train or "").split(",") if s]
    test = [s for s in (args.test or "").split(",") if s]
    speakers = load_speakers(args.data, args.cache, sorted(set(train + test)) or None, log)
    if len(speakers) < 2:
        raise SystemExit(f"{args.data}: P6 needs at least two speakers with a neutral clip, found {len(speakers)}")
    frames, can = normalise_and_align(speakers, log)
    scores = {s: {e: np.nanmean(w, axis=0) for e, w in d["scores"].items()} for s, d in speakers.items()}
    tests = test or list(frames)
    train_of = {t: (train or [s for s in frames if s != t]) for t in tests}
    for t, tr in train_of.items():
        if t in tr:
            raise SystemExit(f"speaker {t} is both a training and a test speaker")
    log("cross-speaker translation (rel_err; 1.0 = no edit):")
    ev = evaluate(frames, scores, train_of, log)
    trans = {e: {k: float(np.mean(v)) for k, v in d.items()} for e, d in sorted(ev["translation"].items())}
    ratios = [r["rel_err"] / r["additive_rel_err"] for r in ev["per_take"]]
    rec = ev["recognition"]
    top1 = float(np.mean([r["model"] == r["emotion"] for r in rec]))
    base1 = float(np.mean([r["baseline"] == r["emotion"] for r in rec]))
    chance = float(np.mean([1.0 / len(r["labels"]) for r in rec]))
    res = {
        "translation": trans,
        "translation_mean_ratio": float(np.mean(ratios)),
        "translation_mean_ratio_plain": float(np.mean([r["plain_rel_err"] / r["additive_rel_err"]
                                                       for r in ev["per_take"]])),
        "translation_mean_ratio_own_offset": float(np.mean([r["own_offset_rel_err"] / r["additive_rel_err"]
                                                            for r in ev["per_take"]])),
        "translation_mean_ratio_best_scale": float(np.mean([r["best_scale_rel_err"] / r["additive_rel_err"]
                                                            for r in ev["per_take"]])),
        "below_additive": f"{sum(x < 1 for x in ratios)}/{len(ratios)}",
        "recognition_top1": top1,
        "recognition_baseline_top1": base1,
        "chance": chance,
        "recognition_confusion": confusion(rec, "model"),
        "recognition_baseline_confusion": confusion(rec, "baseline"),
        "test_speakers": tests,
        "train_speakers": train_of,
        "per_take": ev["per_take"],
    }
    log("\nper emotion (mean over test speakers): model / additive / plain")
    for e, d in trans.items():
        log(f"  {e:10s} {d['rel_err']:.3f} / {d['additive_rel_err']:.3f} / {d['plain_rel_err']:.3f}")
    log(f"mean ratio model / additive: {res['translation_mean_ratio']:.3f} (target <= 0.75); below additive on "
        f"{res['below_additive']} takes; own-offset reference {res['translation_mean_ratio_own_offset']:.3f}, "
        f"best-scale reference {res['translation_mean_ratio_best_scale']:.3f}")
    log(f"recognition top-1: model {top1:.1%}, ARKit nearest-centroid baseline {base1:.1%}, chance {chance:.1%} "
        f"({len(rec)} takes)")
    if args.strip:
        spk, _, emo = args.strip.partition(":")
        if spk in frames and emo in frames[spk]:
            chars = args.character or [REPO.parent / "shared" / "data" / "ict-face",
                                       REPO.parent / "shared" / "data" / "arkit-face"]
            res["character_strip"] = character_strip(frames, can, spk, train_of.get(spk, [s for s in frames if s != spk]),
                                                     emo, chars, args.out, log=log)
    if args.video_restyle:
        import _video_restyle

        res["video_restyle"] = {}
        for spk in [s for s in args.video_restyle.split(",") if s]:
            res["video_restyle"][spk] = r = _video_restyle.run(args.data, spk, ("angry", "happy"), args.out,
                                                               cache=args.cache, log=log)
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
