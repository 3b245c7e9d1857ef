"""P3 and P4 benchmark: emotion editing with style/content models, and speech alignment (Chuang Ch. 2).

Protocols P3 and P4 of ../shared/EVALUATION.md.

**P3** (:func:`faceretarget.style.make_p3_takes`): the mouth and jaw channels of a real Live Link
Face take are the content (``S07-001``, 67 s, the headline and the plots; then ``apfel``, 64 s,
another take of the same performer, reported beside it); the ``emotions6`` vectors neutral, happy,
angry and sad the styles; every styled take is the ``ict-face`` rig's 68 landmarks at the Pyun
Sec. 2 composition of emotion and content, each style at its own known smooth tempo
(:data:`faceretarget.style.DEFAULT_WARPS`).  The happy, angry and sad takes are aligned to the
neutral one by DTW of face features (no audio) and re-aligned by style (``realign_by_style``, as
``StyleModel.fit`` does), the error of the recovered warp (and of the first pass) is reported in
ms, and the models are trained on the first ``--train`` share (60 %) of the neutral timeline
(neutral, happy, angry) and tested on the rest, against the rig's ground truth at the same
content, with the P1 metrics (``faceretarget.metrics.metrics``; ``rel_motion_pct`` is the
headline).  Tasks:

* known expression: the neutral test frames rendered angry (input style given);
* unknown expression: the same, the input's style inferred (held constant over 1 s windows);
  also from the happy take's test frames (its own timeline);
* untrained expression: sad, fitted from the sad take's training part next to the neutral one,
  then the neutral test frames rendered sad;
* interpolation / extrapolation (Eq. 2.15): neutral -> angry at amounts 0..3 against the rig
  driven at that share of the angry weights, with the range guard's score and flag.

Baseline in the same run: adding the mean target-minus-source offset of the aligned training
frames.  Variants: the shipped defaults (every setting cross-validated, including the choice
between the bilinear translation with its correction and the point-local translation), the
bilinear model with the correction its own stage of the selection preferred, the point-local
translation with its best cross-validated setting (whether or not it won), the content prior
alone, the thesis's plain least squares (neither; also with 99.9 % variance and energy), the
bilinear model's rendering instead of the input plus the change, n-frame bundles (n = 3), and the
default model trained on perfectly aligned frames (the alignment's cost).

**P4**: known warp: shared speech clips (LibriTTS and RAVDESS) re-timed piecewise by a known
function (pitch kept, WSOLA), aligned back by DTW of MFCC and of RASTA-PLP; median and 95th
percentile error of the recovered warp in ms over all reference frames.  RAVDESS pairs (same
actor and sentence, two emotions): DTW paths drawn over the MFCC distance matrix, and, lacking a
ground truth, the agreement of MFCC and RASTA-PLP paths and the forward/backward consistency.

Plots (Pillow) under ``--out`` (default out/style): ``sym_convergence.png`` (symmetric fit
objective per iteration, like thesis Fig. 2.10), ``unknown_convergence.png`` (unknown-expression
residual per iteration, Fig. 2.11), ``p3_alignment.png``, ``p3_trajectory.png``,
``p4_known_warp.png``, ``p4_ravdess.png``.

Usage::

    python bench/style.py [--json] [--data ../shared/data] [--out out/style] [--content S07-001,apfel]

``--json`` ends stdout with one JSON line (``known_err_pct``, ``known_baseline_err_pct``,
``unknown_err_pct``, ``untrained_err_pct``, ``align_median_ms``, ``align_p95_ms`` (P4, MFCC),
``sym_iters``, ``p3_align_median_ms``, ... and ``variants``, ``p4``).
"""

from __future__ import annotations

import argparse
import json
import re
import sys
import time
import warnings
from pathlib import Path

import numpy as np

from _plot import font as _font  # bench/_plot.py (same folder)
from _plot import nice_step as _nice_step
from faceretarget.datasets import make_p3_takes
from faceretarget.io import read_audio as read_wav
from faceretarget.io import read_livelinkface, read_rig
from faceretarget.metrics import metrics, rel_motion_pct
from faceretarget.style import (
    PiecewiseWarp,
    StyleModel,
    StyleRangeWarning,
    align_audio,
    align_performances,
    audio_features,
    frame_vectors,
    realign_by_style,
    time_warp_audio,
    warp_performance,
)

REPO = Path(__file__).resolve().parents[1]
TRAIN_STYLES = ["neutral", "happy", "angry"]
P4_RATES = [1.0, 0.7, 1.35, 0.85, 1.2]           # the known piecewise re-timing (input speed-up per segment)
EMOTION = {"01": "neutral", "03": "happy", "04": "sad", "05": "angry"}
DEFAULT = "default (cross-validated)"
BILINEAR = "bilinear + best correction"
POINTS = "point-local translation"
PREVIOUS = "previous defaults (kNN 8)"
PRIOR_ONLY = "previous, content prior only"
#: The settings shipped before the cross-validated selection (picked by hand on S07-001).
OLD = {"variance": 0.9999, "energy": 0.9999, "prior": 1.0, "local": 8}


def log(*a) -> None:
    print(*a, flush=True)


# ================================================================================== plotting (Pillow)




def _ticks(lo: float, hi: float, n: int = 5) -> list[float]:
    step = _nice_step((hi - lo) / n if hi > lo else 1.0)
    start = np.ceil(lo / step) * step
    return [float(v) for v in np.arange(start, hi + 1e-9 * step, step)]


def _dashed(d, pts, color, width, on=7.0, off=5.0) -> None:
    pos = 0.0
    for (xa, ya), (xb, yb) in zip(pts[:-1], pts[1:], strict=True):
        L = float(np.hypot(xb - xa, yb - ya))
        t = 0.0
        while t < L:
            phase = pos % (on + off)
            seg = min((on - phase) if phase < on else (on + off - phase), L - t)
            if phase < on and L > 0:
                a, b = t / L, (t + seg) / L
                d.line([(xa + a * (xb - xa), ya + a * (yb - ya)), (xa + b * (xb - xa), ya + b * (yb - ya))],
                       fill=color, width=width)
            t += seg
            pos += seg


def panel(d, box, series, title, xlabel, ylabel, *, logy=False, ylim=None, legend=True) -> None:
    """One line-plot panel in ``box`` = (x0, y0, x1, y1); series = [(label, x, y, rgb, dashed)].

    ``legend``: True (inside, top right), "outside" (right of the axes) or False.
    """
    f_t, f_s = _font(14), _font(11)
    x0, y0, x1, y1 = box
    ax0, ax1, ay0, ay1 = x0 + 58, x1 - (230 if legend == "outside" else 12), y0 + 44, y1 - 38
    xs = np.concatenate([np.asarray(s[1], float) for s in series])
    ys = np.concatenate([np.asarray(s[2], float) for s in series])
    tr = (lambda v: np.log10(np.maximum(v, 1e-300))) if logy else (lambda v: np.asarray(v, float))
    yv = tr(ys[np.isfinite(ys)])
    xlo, xhi = float(np.min(xs)), float(np.max(xs))
    if xhi <= xlo:
        xhi = xlo + 1
    ylo, yhi = (float(np.min(yv)), float(np.max(yv))) if ylim is None else (float(tr(ylim[0])), float(tr(ylim[1])))
    if yhi <= ylo:
        yhi = ylo + (1.0 if not logy else 0.5)
    pad = 0.05 * (yhi - ylo)
    ylo, yhi = ylo - pad, yhi + pad

    def X(v):
        return ax0 + (np.asarray(v, float) - xlo) / (xhi - xlo) * (ax1 - ax0)

    def Y(v):
        return ay1 - (tr(v) - ylo) / (yhi - ylo) * (ay1 - ay0)

    d.text((ax0, y0 + 4), title, fill=(0, 0, 0), font=f_t)
    for t in _ticks(ylo, yhi):
        yy = ay1 - (t - ylo) / (yhi - ylo) * (ay1 - ay0)
        d.line([(ax0, yy), (ax1, yy)], fill=(228, 228, 228))
        lab = f"1e{t:g}" if logy else f"{t:g}"
        d.text((ax0 - 6 - d.textlength(lab, font=f_s), yy - 7), lab, fill=(60, 60, 60), font=f_s)
    for t in _ticks(xlo, xhi):
        xx = X(t)
        d.line([(xx, ay1), (xx, ay1 + 4)], fill=(0, 0, 0))
        lab = f"{t:g}"
        d.text((xx - d.textlength(lab, font=f_s) / 2, ay1 + 6), lab, fill=(60, 60, 60), font=f_s)
    d.line([(ax0, ay0), (ax0, ay1), (ax1, ay1)], fill=(0, 0, 0))
    d.text(((ax0 + ax1) / 2 - d.textlength(xlabel, font=f_s) / 2, ay1 + 20), xlabel, fill=(0, 0, 0), font=f_s)
    d.text((x0 + 2, ay0 - 17), ylabel, fill=(0, 0, 0), font=f_s)
    for _lab, x, y, c, dashed in series:
        x, y = np.asarray(x, float), np.asarray(y, float)
        ok = np.isfinite(y)
        pts = list(zip(X(x[ok]).tolist(), Y(y[ok]).tolist(), strict=True))
        if len(pts) == 1:
            px, py = pts[0]
            d.ellipse([px - 3, py - 3, px + 3, py + 3], fill=c)
        elif dashed:
            _dashed(d, pts, c, 2)
        else:
            d.line(pts, fill=c, width=2)
    if legend:
        ly = ay0 + 4
        for lab, *_rest in series:
            c, dashed = _rest[2], _rest[3]
            lx = ax1 + 16 if legend == "outside" else ax1 - 190
            if dashed:
                _dashed(d, [(lx, ly + 7), (lx + 24, ly + 7)], c, 2)
            else:
                d.line([(lx, ly + 7), (lx + 24, ly + 7)], fill=c, width=2)
            d.text((lx + 30, ly), lab, fill=(0, 0, 0), font=f_s)
            ly += 15


def figure(path: Path, title: str, panels: list[dict], cols: int = 2, pw: int = 560, ph: int = 340) -> Path:
    from PIL import Image, ImageDraw

    rows = (len(panels) + cols - 1) // cols
    W, H = cols * pw + 20, 44 + rows * ph
    img = Image.new("RGB", (W, H), (255, 255, 255))
    d = ImageDraw.Draw(img)
    d.text((12, 10), title, fill=(0, 0, 0), font=_font(17))
    for n, p in enumerate(panels):
        r, c = divmod(n, cols)
        box = (10 + c * pw, 40 + r * ph, 10 + (c + 1) * pw, 40 + (r + 1) * ph)
        panel(d, box, **p)
    img.save(path, format="PNG")
    return path


COL = [(31, 119, 180), (214, 39, 40), (44, 160, 44), (255, 127, 14), (148, 103, 189), (23, 190, 207),
       (127, 127, 127)]


# ================================================================================== P3
def p3_metrics(pred, gt, p3) -> dict[str, float]:
    m = metrics(pred, gt, p3.neutral, p3.unit, lips=p3.lips if p3.lips.size else None)
    return {k: round(float(v), 4) for k, v in m.items()}


def run_p3(data: Path, content: str, train_frac: float, out: Path | None, curve: tuple = ()) -> dict:
    """P3 on one content take; plots under ``out`` (None: none)."""
    t0 = time.perf_counter()
    rig = read_rig(data / "ict-face")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        perf = read_livelinkface(data / "livelinkface" / f"{content}.csv")
    p3 = make_p3_takes(rig, perf, ("neutral", "happy", "angry", "sad"))
    t_gen = time.perf_counter() - t0
    ref = p3.takes["neutral"]
    T = ref.n_frames
    log(f"P3 data: content {content} ({p3.content_duration:.1f} s), ict-face 68 landmarks; takes: "
        + ", ".join(f"{s} {p.n_frames} frames" for s, p in p3.takes.items()) + f"  [{t_gen:.1f} s]")

    # ---------------------------------------------------------------- alignment (face features)
    t0 = time.perf_counter()
    aligned, align_err, first_err = {"neutral": ref.points}, {}, {}
    als = {}
    for s in ("happy", "angry", "sad"):
        al0 = align_performances(ref, p3.takes[s])
        al = realign_by_style(ref, p3.takes[s], al0)                   # what StyleModel.fit does
        als[s] = al
        aligned[s] = frame_vectors(warp_performance(p3.takes[s], al)).reshape(T, -1, 3)
        truth_t = p3.true_take_time(s, "neutral", ref.times)
        align_err[s], first_err[s] = al.errors_ms(truth_t), al0.errors_ms(truth_t)
    t_align = time.perf_counter() - t0
    pooled = np.concatenate(list(align_err.values()))
    pooled0 = np.concatenate(list(first_err.values()))
    log(f"P3 alignment (DTW of face features, then re-aligned by style; {t_align:.1f} s): "
        + "; ".join(f"{s} median {np.median(e):.1f} ms p95 {np.percentile(e, 95):.0f} ms (first pass "
                    f"{np.median(first_err[s]):.1f} / {np.percentile(first_err[s], 95):.0f})"
                    for s, e in align_err.items()))

    split = int(round(train_frac * T))
    tr, te = slice(0, split), slice(split, T)
    times_te = ref.times[te]
    gt = {s: p3.truth_on(s, "neutral", ref.times) for s in ("neutral", "happy", "angry", "sad")}
    x_in = ref.points[te]

    # ---------------------------------------------------------------- baselines
    def offset(src, dst, frames):
        return frames + (aligned[dst][tr] - aligned[src][tr]).mean(0)

    t0 = time.perf_counter()
    base_known = offset("neutral", "angry", x_in)
    t_base = time.perf_counter() - t0
    base_sad = offset("neutral", "sad", x_in)

    # happy test frames on the happy take's own timeline (content beyond the split)
    hp = p3.takes["happy"]
    c_split = p3.warps["neutral"].content_time(ref.times[split])
    hsel = p3.warps["happy"].content_time(hp.times) > c_split
    x_happy = hp.points[hsel]
    gt_from_happy = p3.render("angry", p3.warps["happy"].content_time(hp.times[hsel]))
    base_from_happy = offset("happy", "angry", x_happy)

    results: dict[str, dict] = {}
    base = {
        "known": p3_metrics(base_known, gt["angry"][te], p3),
        "unknown_from_happy": p3_metrics(base_from_happy, gt_from_happy, p3),
        "untrained": p3_metrics(base_sad, gt["sad"][te], p3),
    }

    def run_variant(name, frames, **kw):
        t0 = time.perf_counter()
        m = StyleModel(**kw).fit_frames({s: frames[s][tr] for s in TRAIN_STYLES})
        st = m.settings_
        t_fit = time.perf_counter() - t0
        t0 = time.perf_counter()
        k = m.known(x_in, "neutral", "angry", warn=False)
        t_known = time.perf_counter() - t0
        t0 = time.perf_counter()
        u = m.unknown(x_in, "angry", window=30, warn=False)
        t_unknown = time.perf_counter() - t0
        uh = m.unknown(x_happy, "angry", window=30, warn=False)
        dims = {"K": int(m.n_components_), "J": int(m.asymmetric_.content_dims_), "I": int(m.symmetric_.style_dims_)}
        m.add_style("sad", frames["sad"][tr], like=("neutral", frames["neutral"][tr]))
        sd = m.known(x_in, "neutral", "sad", warn=False)
        r = {
            "known": p3_metrics(k.frames, gt["angry"][te], p3),
            "unknown": p3_metrics(u.frames, gt["angry"][te], p3),
            "unknown_from_happy": p3_metrics(uh.frames, gt_from_happy, p3),
            "untrained": p3_metrics(sd.frames, gt["sad"][te], p3),
            **dims, "K_with_sad": int(m.n_components_),
            "sym_iters": int(m.symmetric_.n_iter_),
            "unknown_iters": int(u.inferred.n_iter), "unknown_resets": int(u.inferred.reset),
            "unknown_style_weights": [round(float(v), 3) for v in u.style_weights.mean(0)[:3]],
            "unknown_style_accuracy": float(np.mean(u.inferred.nearest == 0)),
            "from_happy_style_weights": [round(float(v), 3) for v in uh.style_weights.mean(0)[:3]],
            "from_happy_style_accuracy": float(np.mean(uh.inferred.nearest == 1)),
            "settings": {k: (list(v) if isinstance(v, tuple) else v) for k, v in st.items()},
            "fit_s": round(t_fit, 3), "known_ms_per_frame": 1000 * t_known / len(x_in),
            "unknown_ms_per_frame": 1000 * t_unknown / len(x_in),
        }
        results[name] = r
        log(f"  {name:<28s} known {r['known']['rel_motion_pct']:6.2f}  unknown {r['unknown']['rel_motion_pct']:6.2f}  "
            f"from happy {r['unknown_from_happy']['rel_motion_pct']:6.2f}  untrained {r['untrained']['rel_motion_pct']:6.2f}"
            f"   (K {r['K']}, J {r['J']}, I {r['I']}; fit {t_fit:.1f} s)")
        return m, u, uh

    log(f"P3 tasks, rel_motion_pct on the held-out {T - split} frames ({(T - split) / 30:.0f} s):")
    m_def, u_def, uh_def = run_variant(DEFAULT, aligned)
    chosen = dict(m_def.settings_)
    log(f"  settings chosen by cross-validation on the training frames: {chosen}")
    # the bilinear model with the correction its own stage of the selection preferred (the default
    # when the point-local translation did not win); rendering-only and bundles only apply to it
    s2 = [r for r in m_def.selection_.table if r["stage"] == 2]
    best2 = min(s2, key=lambda r: r["score"])["local"] if s2 else chosen["local"]
    bil = {**chosen, "local": tuple(best2) if isinstance(best2, list) else best2}
    run_variant(BILINEAR, aligned, **bil)
    s3 = [r for r in m_def.selection_.table if r["stage"] == 3]
    if s3:                                                              # the point-local translation's best
        run_variant(POINTS, aligned, **{**chosen, "local": tuple(min(s3, key=lambda r: r["score"])["local"])})
    run_variant("CV settings, no correction", aligned, **{**chosen, "local": 0})
    run_variant(PREVIOUS, aligned, **OLD)
    run_variant(PRIOR_ONLY, aligned, **{**OLD, "local": 0})
    run_variant("thesis (plain least squares)", aligned, **{**OLD, "prior": False, "local": 0})
    run_variant("thesis, 99.9% var/energy", aligned, prior=False, local=0, variance=0.999, energy=0.999)
    run_variant("bilinear, rendering only", aligned, **bil, detail=False)
    run_variant("bilinear, bundles n=3", aligned, **bil, bundle=3)
    run_variant("default, true alignment", gt)

    # ---------------------------------------------------------------- interpolation / extrapolation (Eq. 2.15)
    interp = []
    m_i = StyleModel(**chosen).fit_frames({s: aligned[s][tr] for s in TRAIN_STYLES})
    content_te = p3.warps["neutral"].content_time(times_te)
    for a in (0.0, 0.5, 1.0, 1.5, 2.0, 3.0, 5.0):
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            r = m_i.known(x_in, "neutral", "angry", amount=a)
        truth = p3.render("angry", content_te, amount=a)
        interp.append({"amount": a, "rel_motion_pct": round(rel_motion_pct(r.frames, truth, p3.neutral), 3),
                       "range_score": round(r.range.score, 3), "outside": bool(r.range.outside),
                       "warned": any(issubclass(c.category, StyleRangeWarning) for c in caught),
                       "frames_outside": round(r.range.frames_outside, 4)})

    # ---------------------------------------------------------------- symmetric fit convergence (Fig. 2.10)
    Yobs = np.stack([m_i.encode(aligned[s][tr]) for s in TRAIN_STYLES])
    from faceretarget.style import SymmetricBilinearModel

    conv = {}
    Jd = m_i.symmetric_.content_dims_
    for I, J, init in ((3, Jd, "svd"), (2, Jd, "svd"), (2, 8, "svd"), (3, Jd, 0), (2, 8, 0), (1, 8, 0)):
        sm = SymmetricBilinearModel(style_dims=I, content_dims=J, tol=1e-13, max_iter=60, init=init).fit(Yobs, TRAIN_STYLES)
        conv[f"I={I}, J={J}, {'SVD' if init == 'svd' else 'random'} init"] = sm.objective_ / float(np.sum(Yobs**2))
    sym_default_iters = int(m_i.symmetric_.n_iter_)
    log(f"symmetric fit: {sym_default_iters} iteration(s) from the SVD start (I = {results[DEFAULT]['I']}, "
        f"J = {Jd}); from random starts: "
        + ", ".join(f"{k.split(',')[0]},{k.split(',')[1]} {len(v) - 1}" for k, v in conv.items() if "random" in k))

    # ---------------------------------------------------------------- training length (learning curve)
    lengths = {}
    for n in [c for c in curve if c <= split]:
        sl = slice(split - n, split)                      # the n training frames nearest the test part
        t0 = time.perf_counter()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            mc = StyleModel().fit_frames({s: aligned[s][sl] for s in TRAIN_STYLES})
            kc = mc.known(x_in, "neutral", "angry", warn=False).frames
        bc = x_in + (aligned["angry"][sl] - aligned["neutral"][sl]).mean(0)
        e_m = p3_metrics(kc, gt["angry"][te], p3)["rel_motion_pct"]
        e_b = p3_metrics(bc, gt["angry"][te], p3)["rel_motion_pct"]
        lengths[int(n)] = {"seconds_of_training": round(n / 30.0, 2), "known": e_m, "baseline": e_b,
                           "ratio": e_m / e_b, "fit_s": round(time.perf_counter() - t0, 2)}
        log(f"  training length {n} frames ({n / 30:.1f} s): known {e_m:.2f} baseline {e_b:.2f} ratio {e_m / e_b:.2f}")

    d = results[DEFAULT]
    sel = m_def.selection_
    summary = {
        "training_length": lengths,
        "settings": {k: (list(v) if isinstance(v, tuple) else v) for k, v in chosen.items()},
        "cv": None if sel is None else {"folds": sel.folds, "gap": sel.gap,
                                         "best_stage1": sorted([r for r in sel.table if r["stage"] == 1],
                                                               key=lambda r: r["score"])[:5],
                                         "stage2": sorted([r for r in sel.table if r["stage"] == 2],
                                                          key=lambda r: r["score"])[:8],
                                         "stage3": sorted([r for r in sel.table if r["stage"] == 3],
                                                          key=lambda r: r["score"])},
        "content": content, "frames": T, "train_frames": split, "test_frames": T - split,
        "align_median_ms": {s: round(float(np.median(e)), 2) for s, e in align_err.items()},
        "align_p95_ms": {s: round(float(np.percentile(e, 95)), 2) for s, e in align_err.items()},
        "align_pooled_median_ms": round(float(np.median(pooled)), 2),
        "align_pooled_p95_ms": round(float(np.percentile(pooled, 95)), 2),
        "align_first_pass_median_ms": round(float(np.median(pooled0)), 2),
        "align_first_pass_p95_ms": round(float(np.percentile(pooled0, 95)), 2),
        "align_s": round(t_align, 2), "baseline": base, "variants": results, "default": d,
        "interpolation": interp, "sym_convergence": {str(k): [float(x) for x in v] for k, v in conv.items()},
        "baseline_ms_per_frame": 1000 * t_base / len(x_in),
    }
    if out is None:
        return summary
    # ---------------------------------------------------------------- plots
    out.mkdir(parents=True, exist_ok=True)
    figure(out / "sym_convergence.png", "Symmetric bilinear fit: squared error / ||Y||^2 per iteration "
           "(alternating SVDs; cf. thesis Fig. 2.10)", [
               {"series": [(k, np.arange(len(v)), np.maximum(v, 1e-16), COL[i % 3], "random" in k)
                           for i, (k, v) in enumerate(conv.items())],
                "title": "P3 training data (neutral, happy, angry)", "xlabel": "iteration",
                "ylabel": "relative error", "logy": True, "legend": "outside"}], cols=1, pw=860)
    figure(out / "unknown_convergence.png", "Unknown expression: residual per iteration (cf. thesis Fig. 2.11)", [
               {"series": [("input neutral", np.arange(1, len(u_def.inferred.history) + 1),
                            u_def.inferred.history, COL[0], False),
                           ("input happy", np.arange(1, len(uh_def.inferred.history) + 1),
                            uh_def.inferred.history, COL[1], False)],
                "title": "P3 test frames, style constant over 30-frame windows", "xlabel": "iteration",
                "ylabel": "mean sq. residual", "logy": True}], cols=1, pw=760)
    figure(out / "p3_alignment.png", "P3: face-feature DTW alignment to the neutral take, re-aligned by style", [
        {"series": [(s, ref.times, als[s].take_times - p3.true_take_time(s, "neutral", ref.times) * 1.0,
                     COL[i], False) for i, s in enumerate(als)],
         "title": "recovered minus true warp (s)", "xlabel": "neutral take time (s)", "ylabel": "error (s)"},
        {"series": [(s, ref.times, als[s].take_times, COL[i], False) for i, s in enumerate(als)]
         + [(f"{s} true", ref.times, p3.true_take_time(s, "neutral", ref.times), COL[i], True)
            for i, s in enumerate(als)],
         "title": "warp: take time against neutral time", "xlabel": "neutral take time (s)",
         "ylabel": "take time (s)", "legend": False}])
    # a lip landmark's vertical trajectory over 8 s of test
    lip = 57   # lower lip centre (outer contour) among the 68 landmarks
    sel = slice(0, min(240, len(x_in)))
    kd = m_i.known(x_in, "neutral", "angry", warn=False)
    figure(out / "p3_trajectory.png", "P3 known expression neutral -> angry: lower-lip landmark height (cm)", [
        {"series": [("rig truth (angry)", times_te[sel], gt["angry"][te][sel, lip, 1], (0, 0, 0), False),
                    ("default model", times_te[sel], kd.frames[sel, lip, 1], COL[0], False),
                    ("additive baseline", times_te[sel], base_known[sel, lip, 1], COL[1], True),
                    ("input (neutral)", times_te[sel], x_in[sel, lip, 1], (150, 150, 150), True)],
         "title": "first 8 s of the held-out part", "xlabel": "time (s)", "ylabel": "y (cm)",
         "legend": "outside"}], cols=1, pw=1000)

    return summary


# ================================================================================== P4
def run_p4(data: Path, out: Path) -> dict:
    clips = sorted((data / "speech" / "libritts").glob("*.wav"))[:6] + sorted((data / "speech" / "ravdess").glob("*.wav"))[:4]
    errs = {"mfcc": [], "rplp": [], "mfcc_window": []}
    per_clip = []
    t_feat = {"mfcc": 0.0, "rplp": 0.0}
    demo = None
    for f in clips:
        x, r = read_wav(f)
        warp = PiecewiseWarp.from_rates(len(x) / r, P4_RATES)
        y = time_warp_audio(x, r, warp.input_time, warp.duration)
        row = {"clip": f.name, "seconds": round(len(x) / r, 2)}
        for kind, win in (("mfcc", None), ("rplp", None), ("mfcc_window", 0.3)):
            feat = "mfcc" if kind.startswith("mfcc") else "rplp"
            t0 = time.perf_counter()
            al = align_audio(x, r, y, r, features=feat, window_s=win)
            if win is None:
                t_feat[feat] += time.perf_counter() - t0
            e = al.errors_ms(warp.output_time(al.ref_times))
            errs[kind].append(e)
            row[kind] = {"median_ms": round(float(np.median(e)), 2), "p95_ms": round(float(np.percentile(e, 95)), 2)}
            if demo is None and kind == "mfcc":
                demo = (f.name, al.ref_times, al.take_times, warp.output_time(al.ref_times))
        per_clip.append(row)
    pooled = {k: np.concatenate(v) for k, v in errs.items()}
    summary = {k: {"median_ms": round(float(np.median(v)), 2), "p95_ms": round(float(np.percentile(v, 95)), 2)}
               for k, v in pooled.items()}
    log(f"P4 known warp ({len(clips)} clips, rates {P4_RATES}): "
        + "; ".join(f"{k} median {v['median_ms']:.1f} ms p95 {v['p95_ms']:.1f} ms" for k, v in summary.items()))

    # ---------------------------------------------------------------- RAVDESS pairs
    files = sorted((data / "speech" / "ravdess").glob("*.wav"))
    groups: dict[tuple[str, str], list[Path]] = {}
    for f in files:
        m = re.fullmatch(r"(\d\d)-(\d\d)-(\d\d)-(\d\d)-(\d\d)-(\d\d)-(\d\d)", f.stem)
        if not m:
            continue
        groups.setdefault((m.group(7), m.group(5)), []).append(f)
    pairs = []
    for (actor, stmt), fs in sorted(groups.items()):
        emos = {}
        for f in fs:
            emos.setdefault(f.stem.split("-")[2], f)
        if len(emos) >= 2:
            a, b = sorted(emos)[:2]
            pairs.append((actor, stmt, emos[a], emos[b]))
    rav = []
    panels_img = []
    for actor, stmt, fa, fb in pairs:
        xa, ra = read_wav(fa)
        xb, rb = read_wav(fb)
        am = align_audio(xa, ra, xb, rb, features="mfcc")
        ap = align_audio(xa, ra, xb, rb, features="rplp")
        back = align_audio(xb, rb, xa, ra, features="mfcc")
        # forward/backward consistency: going a -> b -> a should return to the start
        rt = np.interp(am.take_times, back.ref_times, back.take_times)
        cons = np.abs(rt - am.ref_times) * 1000
        agree = np.abs(np.interp(am.ref_times, ap.ref_times, ap.take_times) - am.take_times) * 1000
        ea, eb = EMOTION.get(fa.stem.split("-")[2], "?"), EMOTION.get(fb.stem.split("-")[2], "?")
        rav.append({"actor": actor, "statement": stmt, "a": fa.name, "b": fb.name, "emotions": [ea, eb],
                    "seconds": [round(len(xa) / ra, 2), round(len(xb) / rb, 2)],
                    "dtw_distance_per_step_mfcc": round(am.distance / len(am.path), 3),
                    "mfcc_vs_rplp_median_ms": round(float(np.median(agree)), 1),
                    "fwd_bwd_median_ms": round(float(np.median(cons)), 1),
                    "fwd_bwd_p95_ms": round(float(np.percentile(cons, 95)), 1)})
        Fa, _ = audio_features(xa, ra)
        Fb, _ = audio_features(xb, rb)
        panels_img.append((f"actor {actor}, sentence {stmt}: {ea} ({fa.stem[6:8]}) vs {eb}", Fa, Fb, am, ap))
    log(f"P4 RAVDESS: {len(rav)} pairs; MFCC vs RASTA-PLP path median difference "
        + ", ".join(f"{r['mfcc_vs_rplp_median_ms']:.0f}" for r in rav) + " ms; forward/backward median "
        + ", ".join(f"{r['fwd_bwd_median_ms']:.0f}" for r in rav) + " ms")

    out.mkdir(parents=True, exist_ok=True)
    _ravdess_png(out / "p4_ravdess.png", panels_img)
    name, rt_, tt_, truth_ = demo
    figure(out / "p4_known_warp.png", f"P4 known warp: {name} re-timed piecewise (rates {P4_RATES}), MFCC DTW", [
        {"series": [("recovered", rt_, tt_, COL[0], False), ("true", rt_, truth_, (0, 0, 0), True)],
         "title": "warp", "xlabel": "original time (s)", "ylabel": "re-timed time (s)"},
        {"series": [("error", rt_, (tt_ - truth_) * 1000, COL[1], False)],
         "title": "recovered minus true (ms)", "xlabel": "original time (s)", "ylabel": "ms"}])
    return {"known_warp": summary, "known_warp_clips": per_clip, "rates": P4_RATES, "ravdess": rav,
            "feature_s": {k: round(v, 3) for k, v in t_feat.items()}}


def _ravdess_png(path: Path, items) -> None:
    """DTW paths (MFCC red, RASTA-PLP blue) over each pair's MFCC distance matrix."""
    from PIL import Image, ImageDraw

    cols = 4
    cell = 300
    rows = (len(items) + cols - 1) // cols
    img = Image.new("RGB", (cols * cell + 20, 50 + rows * (cell + 40)), (255, 255, 255))
    d = ImageDraw.Draw(img)
    d.text((12, 10), "P4 RAVDESS pairs: DTW paths (red MFCC, blue RASTA-PLP) over the MFCC distance matrix "
                     "(dark = similar); x: first clip, y: second clip", fill=(0, 0, 0), font=_font(15))
    for n, (title, Fa, Fb, am, ap) in enumerate(items):
        r, c = divmod(n, cols)
        x0, y0 = 10 + c * cell, 44 + r * (cell + 40)
        D = np.sqrt(((Fa[:, None, :] - Fb[None, :, :]) ** 2).sum(-1))
        lo, hi = np.percentile(D, [2, 98])
        g = (255 * np.clip((D - lo) / (hi - lo), 0, 1)).astype(np.uint8)        # dark = similar
        im = Image.fromarray(g.T[::-1].copy(), mode="L").resize((cell - 30, cell - 30)).convert("RGB")
        img.paste(im, (x0 + 20, y0 + 18))
        sx, sy = (cell - 30) / Fa.shape[0], (cell - 30) / Fb.shape[0]
        for al, col in ((ap, (40, 90, 255)), (am, (230, 30, 30))):
            p = al.path
            pts = [(x0 + 20 + (i + 0.5) * sx, y0 + 18 + (cell - 30) - (j + 0.5) * sy) for i, j in p[:: max(1, len(p) // 400)]]
            d.line(pts, fill=col, width=2)
        d.text((x0 + 20, y0 + 2), title, fill=(0, 0, 0), font=_font(11))
    img.save(path, format="PNG")


# ================================================================================== main
def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--json", action="store_true")
    ap.add_argument("--data", default=str(REPO.parent / "shared" / "data"))
    ap.add_argument("--out", default=str(REPO / "out" / "style"))
    ap.add_argument("--content", default="S07-001,apfel,MySlate_3_Jason_Millers_iPhone",
                    help="livelinkface take(s) for the P3 content, comma-separated; the first is the headline "
                         "(and gets the plots)")
    ap.add_argument("--train", type=float, default=0.6, help="share of the timeline used for training")
    ap.add_argument("--curve", default="", help="training lengths in frames for the learning curve of the known "
                    "task on the first content take, comma-separated (e.g. 100,200,400,800; default none)")
    args = ap.parse_args(argv)
    data, out = Path(args.data), Path(args.out)
    if not data.is_dir():
        log(f"shared data not found at {data}")
        return 2
    t0 = time.perf_counter()
    contents = [c.strip() for c in args.content.split(",") if c.strip()]
    curve = tuple(int(c) for c in args.curve.split(",") if c.strip())
    p3_all = [run_p3(data, c, args.train, out if i == 0 else None, curve if i == 0 else ())
              for i, c in enumerate(contents)]
    p3 = p3_all[0]
    p4 = run_p4(data, out)
    total = time.perf_counter() - t0

    d, b = p3["default"], p3["baseline"]
    log("")
    if len(p3_all) > 1:
        log(f"{'P3 per content take':<22s}{'known':>8s}{'base':>7s}{'ratio':>7s}{'unknown':>9s}{'happy->':>9s}"
            f"{'base':>7s}{'sad':>7s}{'base':>7s}{'align ms':>10s}")
        for q in p3_all:
            dq, bq = q["default"], q["baseline"]
            log(f"{q['content'][:21]:<22s}{dq['known']['rel_motion_pct']:8.2f}{bq['known']['rel_motion_pct']:7.2f}"
                f"{dq['known']['rel_motion_pct'] / bq['known']['rel_motion_pct']:7.2f}"
                f"{dq['unknown']['rel_motion_pct']:9.2f}{dq['unknown_from_happy']['rel_motion_pct']:9.2f}"
                f"{bq['unknown_from_happy']['rel_motion_pct']:7.2f}{dq['untrained']['rel_motion_pct']:7.2f}"
                f"{bq['untrained']['rel_motion_pct']:7.2f}{q['align_pooled_median_ms']:10.1f}")
        log("")
        log(f"{'before (previous defaults)':<22s}{'known':>8s}{'ratio':>7s}{'unknown':>9s}{'happy->':>9s}{'sad':>7s}"
            "   settings chosen now")
        for q in p3_all:
            pq, bq = q["variants"][PREVIOUS], q["baseline"]
            log(f"{q['content'][:21]:<22s}{pq['known']['rel_motion_pct']:8.2f}"
                f"{pq['known']['rel_motion_pct'] / bq['known']['rel_motion_pct']:7.2f}"
                f"{pq['unknown']['rel_motion_pct']:9.2f}{pq['unknown_from_happy']['rel_motion_pct']:9.2f}"
                f"{pq['untrained']['rel_motion_pct']:7.2f}   {q['settings']}")
        log("")
        for q in p3_all[1:]:
            log(f"variants on {q['content']}")
            for name, r in q["variants"].items():
                log(f"  {name:<32s}{r['known']['rel_motion_pct']:8.2f}{r['unknown']['rel_motion_pct']:9.2f}"
                    f"{r['unknown_from_happy']['rel_motion_pct']:9.2f}{r['untrained']['rel_motion_pct']:8.2f}")
        log("")
    log(f"P3 headline: content {p3['content']}")
    log(f"{'P3 task (rel_motion_pct %)':<40s}{'method':>10s}{'baseline':>10s}{'ratio':>8s}{'lve_mm':>9s}{'base lve':>9s}")
    rows = [("known expression neutral->angry", d["known"], b["known"]),
            ("unknown expression neutral->angry", d["unknown"], b["known"]),
            ("unknown expression happy->angry", d["unknown_from_happy"], b["unknown_from_happy"]),
            ("untrained expression neutral->sad", d["untrained"], b["untrained"])]
    for name, m, bb in rows:
        log(f"{name:<40s}{m['rel_motion_pct']:10.2f}{bb['rel_motion_pct']:10.2f}"
            f"{m['rel_motion_pct'] / bb['rel_motion_pct']:8.2f}{m['lve_mm']:9.2f}{bb['lve_mm']:9.2f}")
    log("")
    log(f"{'variant':<32s}{'known':>8s}{'unknown':>9s}{'happy->':>9s}{'sad':>8s}{'K':>4s}{'J':>4s}{'I':>3s}")
    for name, r in p3["variants"].items():
        log(f"{name:<32s}{r['known']['rel_motion_pct']:8.2f}{r['unknown']['rel_motion_pct']:9.2f}"
            f"{r['unknown_from_happy']['rel_motion_pct']:9.2f}{r['untrained']['rel_motion_pct']:8.2f}"
            f"{r['K']:4d}{r['J']:4d}{r['I']:3d}")
    log("")
    log(f"{'amount (neutral->angry)':<26s}{'err %':>8s}{'range':>8s}{'flag':>6s}")
    for it in p3["interpolation"]:
        log(f"{it['amount']:<26g}{it['rel_motion_pct']:8.2f}{it['range_score']:8.2f}{str(it['outside']):>6s}")
    log("")
    log(f"alignment: P3 faces median {p3['align_pooled_median_ms']:.1f} ms p95 {p3['align_pooled_p95_ms']:.0f} ms "
        f"(first pass {p3['align_first_pass_median_ms']:.1f} / {p3['align_first_pass_p95_ms']:.0f} ms); "
        f"P4 speech MFCC median {p4['known_warp']['mfcc']['median_ms']:.1f} ms p95 {p4['known_warp']['mfcc']['p95_ms']:.1f} ms, "
        f"RASTA-PLP median {p4['known_warp']['rplp']['median_ms']:.1f} ms p95 {p4['known_warp']['rplp']['p95_ms']:.1f} ms")
    log(f"speed: known expression {d['known_ms_per_frame']:.3f} ms/frame = "
        f"{d['known_ms_per_frame'] / max(p3['baseline_ms_per_frame'], 1e-9):.0f}x the additive baseline; "
        f"unknown {d['unknown_ms_per_frame']:.3f} ms/frame; total bench {total:.0f} s")
    out_json = {
        "known_err_pct": d["known"]["rel_motion_pct"],
        "known_baseline_err_pct": b["known"]["rel_motion_pct"],
        "unknown_err_pct": d["unknown"]["rel_motion_pct"],
        "unknown_from_happy_err_pct": d["unknown_from_happy"]["rel_motion_pct"],
        "unknown_from_happy_baseline_err_pct": b["unknown_from_happy"]["rel_motion_pct"],
        "untrained_err_pct": d["untrained"]["rel_motion_pct"],
        "untrained_baseline_err_pct": b["untrained"]["rel_motion_pct"],
        "known_bilinear_err_pct": p3["variants"][BILINEAR]["known"]["rel_motion_pct"],
        "known_point_local_err_pct": p3["variants"].get(POINTS, {}).get("known", {}).get("rel_motion_pct"),
        "known_thesis_err_pct": p3["variants"]["thesis (plain least squares)"]["known"]["rel_motion_pct"],
        "known_prior_only_err_pct": p3["variants"][PRIOR_ONLY]["known"]["rel_motion_pct"],
        "known_previous_defaults_err_pct": p3["variants"][PREVIOUS]["known"]["rel_motion_pct"],
        "align_median_ms": p4["known_warp"]["mfcc"]["median_ms"],
        "align_p95_ms": p4["known_warp"]["mfcc"]["p95_ms"],
        "p3_align_median_ms": p3["align_pooled_median_ms"],
        "p3_align_first_pass_median_ms": p3["align_first_pass_median_ms"],
        "p3_align_first_pass_p95_ms": p3["align_first_pass_p95_ms"],
        "p3_align_p95_ms": p3["align_pooled_p95_ms"],
        "sym_iters": d["sym_iters"],
        "unknown_iters": d["unknown_iters"],
        "dims": {"K": d["K"], "J": d["J"], "I": d["I"]},
        "targets": {"known_le_half_baseline": d["known"]["rel_motion_pct"] <= 0.5 * b["known"]["rel_motion_pct"],
                    "unknown_below_baseline": d["unknown"]["rel_motion_pct"] < b["known"]["rel_motion_pct"],
                    "align_median_le_33ms": p4["known_warp"]["mfcc"]["median_ms"] <= 33.0,
                    "known_le_half_baseline_every_take": all(
                        q["default"]["known"]["rel_motion_pct"] <= 0.5 * q["baseline"]["known"]["rel_motion_pct"]
                        for q in p3_all),
                    "unknown_below_baseline_every_take": all(
                        q["default"]["unknown"]["rel_motion_pct"] < q["baseline"]["known"]["rel_motion_pct"]
                        for q in p3_all)},
        "p3_takes": {q["content"]: {"known_err_pct": q["default"]["known"]["rel_motion_pct"],
                                    "known_baseline_err_pct": q["baseline"]["known"]["rel_motion_pct"],
                                    "unknown_err_pct": q["default"]["unknown"]["rel_motion_pct"],
                                    "unknown_from_happy_err_pct": q["default"]["unknown_from_happy"]["rel_motion_pct"],
                                    "unknown_from_happy_baseline_err_pct": q["baseline"]["unknown_from_happy"]["rel_motion_pct"],
                                    "untrained_err_pct": q["default"]["untrained"]["rel_motion_pct"],
                                    "untrained_baseline_err_pct": q["baseline"]["untrained"]["rel_motion_pct"],
                                    "align_median_ms": q["align_pooled_median_ms"],
                                    "settings": q["settings"],
                                    "bilinear_known_err_pct": q["variants"][BILINEAR]["known"]["rel_motion_pct"],
                                    "point_local_known_err_pct":
                                        q["variants"].get(POINTS, {}).get("known", {}).get("rel_motion_pct"),
                                    "previous_defaults_known_err_pct": q["variants"][PREVIOUS]["known"]["rel_motion_pct"],
                                    "previous_defaults_unknown_err_pct":
                                        q["variants"][PREVIOUS]["unknown"]["rel_motion_pct"]} for q in p3_all},
        "p3": p3, "p3_other": p3_all[1:], "p4": p4, "seconds": round(total, 1),
    }
    if args.json:
        print(json.dumps(out_json))
    return 0


if __name__ == "__main__":
    sys.exit(main())
