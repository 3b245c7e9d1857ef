"""P1 benchmark for blendshape retargeting (Chuang Ch. 3), with solver speed and missing markers.

Protocol P1 of ../shared/EVALUATION.md, ICT-FaceKit -> ARKit face, out of sample:

* key sets ``rom-10``, ``rom-20``, ``rom-40`` chosen on the range-of-motion take ``alex_rom_3.csv`` by
  every selection method (``pca-extrema``, ``hull``, ``kmeans2``, ``kmeans3``, ``nnls-greedy``), and
  ``arkit`` (exact: a correctness check); errors on the other takes;
* kinds ``cross`` (ICT -> ARKit) and ``roundtrip`` (ICT -> ARKit -> ICT; ``arkit`` and ``rom-40`` sets);
* 68 landmark features; capture noise 0 and 0.5 mm on the source landmarks;
* methods ``retarget`` (the package default: signed solve + take-adaptive denoising, then the
  weights kept in the default range), ``retarget-nnls`` (the thesis: weights in [0, the range's top])
  and ``clone`` (the cloning default with the same keys) side by side; every row reports ``w_min``,
  ``w_max``, ``w_outside_01_pct`` and ``oracle_bounded_rel_motion_pct`` (the best blend inside the
  method's range) beside the unconstrained ``oracle_rel_motion_pct``;
* solver speed on the real P1 problems (every rom-K key set x every take, landmark features), in this
  run: :func:`solve_nnls` against ``scipy.optimize.nnls`` called per frame, and :func:`solve_bounded`
  with the default example range ``EXAMPLE_RANGE`` against ``scipy.optimize.lsq_linear(K, f,
  bounds=(lo, hi))`` per frame; best of ``--repeat`` interleaved runs per contender, the worst and
  median problems, the largest weight difference, the objective difference and our KKT residual;
* missing markers: the four ``facial-mocap`` takes retargeted onto their own keyshapes (20, chosen by
  ``nnls-greedy``) complete and with 10 % of the marker samples removed at random; error = share of
  the (complete, head-stabilised) marker motion that is wrong, on every marker including the removed
  ones; and the same on P1 (ICT -> ARKit rom-40) with 10 % of the landmark samples removed.

Usage::

    python bench/retarget.py [--quick] [--json] [--data ../shared/data]

``--quick``: rom-40 only and fewer speed problems; ``--speed-only``: only the solver speed (all
54 problems; lsq_linear per frame takes most of it: about 10 min with ``--repeat 3``, 4 min with 1).
With ``--json`` the last stdout line is one JSON object in P1's layout plus ``nnls_speedup`` and
``bounded_speedup`` (the worst problem's ratio), ``nnls_speedup_median``, ``bounded_speedup_median``,
the same for the NumPy backend (``*_speedup_numpy``), the worst problems (``nnls_worst``,
``bounded_worst``), ``*_max_abs_diff``, ``*_obj_rel_diff`` (ours worse than the reference by at
most, per frame, relative), ``*_obj_rel_gain``, ``*_kkt``, every problem in ``nnls_cases``, and
``missing_markers``.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
import warnings
from pathlib import Path

import numpy as np
from scipy.optimize import lsq_linear, nnls

from cloning import TAKES, _animate, _load  # the P1 loader of bench/cloning.py (same folder)
from faceretarget.cloning import ExpressionCloner, keymodel_rig, keyset_weights
from faceretarget.datasets import add_capture_noise
from faceretarget.errors import SingularKeysError
from faceretarget.io import read_c3d
from faceretarget.metrics import metrics, oracle_rel_motion_pct
from faceretarget.numerics import (
    EXAMPLE_RANGE,
    SELECTION_METHODS,
    RigidAligner,
    select_keyshapes,
    solve_bounded,
    solve_nnls,
)
from faceretarget.retarget import BlendshapeRetargeter
from faceretarget.rig import Rig

REPO = Path(__file__).resolve().parents[1]
METHODS = ("retarget", "retarget-nnls", "clone")
REPEAT = 3


def _model(method, sk, tk):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        if method == "clone":
            try:
                return ExpressionCloner("temporal", features="landmarks").fit(sk, tk)
            except SingularKeysError:      # near-duplicate keys (hull picks neighbouring frames): refused
                return None
        return BlendshapeRetargeter("nnls" if method == "retarget-nnls" else "signed",
                                    features="landmarks").fit(sk, tk)


def _apply(model, pts, times):
    """(target frames, weights)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        W = model.transform(pts, times).weights
        return model.blend(W), W


def _weight_columns(model, W, truth, keys_plus_neutral, neutral, cache, ckey) -> dict:
    """w_min, w_max, w_outside_01_pct and the bounded oracle (best blend inside the model's range)."""
    rng = model.weight_range_
    if ckey not in cache:
        cache[ckey] = oracle_rel_motion_pct(truth, keys_plus_neutral, neutral, weight_range=rng)
    return {"w_min": float(W.min()), "w_max": float(W.max()),
            "w_outside_01_pct": float(((W < 0) | (W > 1)).mean() * 100),
            "weight_range": None if rng is None else [float(rng[0]), float(rng[1])],
            "oracle_bounded_rel_motion_pct": float(cache[ckey])}


def p1(ict: Rig, ark: Rig, rom, takes, quick: bool, log) -> tuple[list[dict], list]:
    rows = []
    problems = []          # (K, F) solver problems for the speed test
    ks = (40,) if quick else (10, 20, 40)
    keysets = [("arkit", None)] + [(f"rom-{k}", m) for k in ks for m in SELECTION_METHODS]
    gts = {t: (_animate(ict, takes[t]), _animate(ark, takes[t])) for t in TAKES}
    lm = ict.landmarks
    oracles: dict = {}
    for keys, sel in keysets:
        t0 = time.perf_counter()
        labels, U, names = keyset_weights(keys, ict, rom=rom, selection=sel or "pca-extrema")
        sk, tk = keymodel_rig(ict, labels, U, names), keymodel_rig(ark, labels, U, names)
        t_sel = time.perf_counter() - t0
        models = {m: _model(m, sk, tk) for m in METHODS}
        back = {m: _model(m, tk, sk) for m in METHODS}
        Kl = sk.deltas[:, lm].reshape(sk.n_shapes, -1).T
        for ti, take in enumerate(TAKES):
            src, gtb = gts[take]
            times = takes[take].times
            if keys != "arkit":
                problems.append((keys, sel, take, Kl, (src[:, lm] - ict.neutral.vertices[lm]).reshape(len(src), -1)))
            for noise in ((0.0,) if keys == "arkit" else (0.0, 0.5)):
                pts = src[:, lm]
                if noise:
                    pts = add_capture_noise(pts, noise, ict.unit, seed=ti)
                for m in METHODS:
                    if models[m] is None:
                        continue
                    pred, W = _apply(models[m], pts, times)
                    base = dict(method=m, source="ict-face", keys=keys, selection=sel or "", features="landmarks",
                                take=take, noise_mm=noise)
                    met = metrics(pred, gtb, ark.neutral.vertices, ark.unit, target_keys=tk.deltas + tk.neutral.vertices)
                    rng = models[m].weight_range_
                    wc = _weight_columns(models[m], W, gtb, tk.deltas + tk.neutral.vertices, ark.neutral.vertices,
                                         oracles, ("cross", keys, sel, take, None if rng is None else tuple(rng)))
                    rows.append(dict(base, target="arkit-face", kind="cross", **met, **wc))
                    if keys not in ("arkit", "rom-40"):
                        continue                  # round trips for the arkit and rom-40 sets only
                    mid = pred[:, ark.landmarks]
                    rt, W2 = _apply(back[m], mid, times)
                    met = metrics(rt, src, ict.neutral.vertices, ict.unit, target_keys=sk.deltas + sk.neutral.vertices)
                    rng = back[m].weight_range_
                    wc = _weight_columns(back[m], np.hstack([W, W2]), src, sk.deltas + sk.neutral.vertices,
                                         ict.neutral.vertices, oracles,
                                         ("roundtrip", keys, sel, take, None if rng is None else tuple(rng)))
                    rows.append(dict(base, target="ict-face", kind="roundtrip", **met, **wc))
        cr = [r for r in rows if r["keys"] == keys and r["selection"] == (sel or "") and r["kind"] == "cross"
              and r["method"] == "retarget"]
        log(f"  {keys:7s} {sel or '':12s} select {t_sel:5.1f} s  retarget cross rel_motion "
            + " ".join(f"{r['take'][:5]}/{r['noise_mm']}: {r['rel_motion_pct']:.2f}" for r in cr))
    return rows, problems


def _speed_problems(ict, rom, takes):
    """The solver problems of :func:`p1` (rom-K keys x takes, landmark features) without the P1 runs."""
    lm = ict.landmarks
    frames = {}                                   # every take's landmark displacements, computed once
    for take in TAKES:
        src = ict.evaluate(ict.map_weights(takes[take].names, takes[take].weights, warn=False), vertices=lm)
        frames[take] = (src - ict.neutral.vertices[lm]).reshape(len(src), -1)
    out = []
    for k in (10, 20, 40):
        for sel in SELECTION_METHODS:
            labels, U, names = keyset_weights(f"rom-{k}", ict, rom=rom, selection=sel)
            sk = keymodel_rig(ict, labels, U, names)
            Kl = sk.deltas[:, lm].reshape(sk.n_shapes, -1).T
            for take in TAKES:
                out.append((f"rom-{k}", sel, take, Kl, frames[take]))
    return out


def _scipy_loop(K, F, bounds=None):
    """The reference, frame by frame: ``scipy.optimize.nnls``, or ``lsq_linear(K, f, bounds)`` (its default
    method, trf) with ``bounds``."""
    if bounds is None:
        return np.stack([nnls(K, f)[0] for f in F])
    return np.stack([lsq_linear(K, f, bounds=bounds).x for f in F])


def _agreement(K, F, W, Wref, lo, hi) -> dict:
    """How ``W`` (ours) compares with ``Wref`` (the per-frame reference) on ``min 1/2 ||K w - f||^2, lo <= w <= hi``.

    ``obj_rel_diff``: the largest per-frame ``(J - J_ref) / J_ref`` (``J_ref`` floored at 1e-12 of the
    frame's ``1/2 ||f||^2``); positive means ours is worse.  Where the keys are nearly dependent the
    weights are not unique (or the reference stops early), so the objective is what must agree.
    ``obj_rel_gain``: the largest ``(J_ref - J) / J_ref`` (ours lower).  ``kkt``: our largest violation
    of the optimality conditions relative to ``max |K'(f - K lo)|`` per frame (the solver's ``tol``
    scale).
    """
    def obj(X):
        R = X @ K.T - F
        return 0.5 * np.einsum("ij,ij->i", R, R)

    J, Jr = obj(W), obj(Wref)
    floor = np.maximum(1e-12 * 0.5 * np.einsum("ij,ij->i", F, F), 1e-300)
    rel = (J - Jr) / np.maximum(Jr, floor)
    g = (W @ K.T - F) @ K
    width = 1e-12 * (hi - lo if np.isfinite(hi) else 1.0)
    at_lo, at_hi = W <= lo + width, W >= hi - width
    viol = np.where(at_lo, np.maximum(-g, 0.0), np.where(at_hi, np.maximum(g, 0.0), np.abs(g)))
    scale = np.maximum(np.abs((F - lo * K.sum(axis=1)) @ K).max(axis=1), 1e-300)
    return dict(max_abs_diff=float(np.abs(W - Wref).max()), obj_rel_diff=float(rel.max()),
                obj_rel_gain=float(-rel.min()), kkt=float((viol.max(axis=1) / scale).max()))


def _summary(cases, what: str) -> dict:
    """The worst and median speedups of ``what`` ("nnls" or "bounded") over ``cases``, per backend."""
    sp = np.array([c[f"{what}_speedup"] for c in cases])
    spn = np.array([c[f"{what}_speedup_numpy"] for c in cases])
    w = cases[int(np.argmin(sp))]
    return {f"{what}_speedup": float(sp.min()), f"{what}_speedup_median": float(np.median(sp)),
            f"{what}_speedup_numpy": float(spn.min()), f"{what}_speedup_numpy_median": float(np.median(spn)),
            f"{what}_worst": dict(keys=w["keys"], selection=w["selection"], take=w["take"], frames=w["frames"],
                                  speedup=w[f"{what}_speedup"]),
            f"{what}_max_abs_diff": max(c[f"{what}_max_abs_diff"] for c in cases),
            f"{what}_obj_rel_diff": max(c[f"{what}_obj_rel_diff"] for c in cases),
            f"{what}_obj_rel_gain": max(c[f"{what}_obj_rel_gain"] for c in cases),
            f"{what}_kkt": max(c[f"{what}_kkt"] for c in cases)}


def speed(problems, quick: bool, log, repeat: int = REPEAT) -> dict:
    """Whole-take solves against the scipy reference called per frame, on the real P1 problems.

    ``solve_nnls(K, F)`` against ``scipy.optimize.nnls(K, f)`` and ``solve_bounded(K, F, lo, hi)``
    against ``scipy.optimize.lsq_linear(K, f, bounds=(lo, hi))`` (the default range ``EXAMPLE_RANGE``),
    each with the compiled kernel ("auto") and the NumPy methods alone; best of ``repeat`` runs per
    contender, the runs interleaved so that every contender sees the same machine state.  Speedups
    are reference time / ours; the summary gives the worst problem's and the median.
    """
    from faceretarget.numerics import _nnls_numba

    lo, hi = EXAMPLE_RANGE
    contenders = {
        "nnls_ref": lambda K, F: _scipy_loop(K, F),
        "nnls_auto": lambda K, F: solve_nnls(K, F),
        "nnls_numpy": lambda K, F: solve_nnls(K, F, backend="numpy"),
        "bounded_ref": lambda K, F: _scipy_loop(K, F, (lo, hi)),
        "bounded_auto": lambda K, F: solve_bounded(K, F, lo, hi),
        "bounded_numpy": lambda K, F: solve_bounded(K, F, lo, hi, backend="numpy"),
    }
    solve_nnls(*problems[0][3:])                   # one-time costs (loading the compiled kernel)
    cases = []
    sel = problems if not quick else problems[:3]
    t_start = time.perf_counter()
    for keys, method, take, K, F in sel:
        best = dict.fromkeys(contenders, np.inf)
        out = {}
        for _ in range(repeat):                    # best of `repeat` for every contender, interleaved
            for name, fn in contenders.items():
                t0 = time.perf_counter()
                out[name] = fn(K, F)
                best[name] = min(best[name], time.perf_counter() - t0)
        case = dict(keys=keys, selection=method, take=take, frames=len(F))
        for what, (a, b) in (("nnls", (0.0, np.inf)), ("bounded", (lo, hi))):
            ref = best[f"{what}_ref"]
            case.update({f"{what}_ref_s": ref, f"{what}_s": best[f"{what}_auto"],
                         f"{what}_numpy_s": best[f"{what}_numpy"],
                         f"{what}_speedup": ref / best[f"{what}_auto"],
                         f"{what}_speedup_numpy": ref / best[f"{what}_numpy"]})
            case.update({f"{what}_{k}": v for k, v in
                         _agreement(K, F, out[f"{what}_auto"], out[f"{what}_ref"], a, b).items()})
        cases.append(case)
        log(f"  {keys:6s} {method:11s} {take[:9]:9s} {len(F):5d} frames: nnls {case['nnls_speedup']:6.1f}x "
            f"(numpy {case['nnls_speedup_numpy']:5.1f}x)  bounded {case['bounded_speedup']:7.1f}x "
            f"(numpy {case['bounded_speedup_numpy']:6.1f}x)")
    backend = "numba kernel" if _nnls_numba.available() else "NumPy (numba not installed)"
    res = dict(nnls_backend=backend, speed_repeat=repeat, speed_bench_s=time.perf_counter() - t_start,
               **_summary(cases, "nnls"), **_summary(cases, "bounded"), nnls_cases=cases)
    for what, ref in (("nnls", "scipy nnls"), ("bounded", f"lsq_linear bounds ({lo:g}, {hi:g})")):
        w = res[f"{what}_worst"]
        log(f"  {'solve_nnls' if what == 'nnls' else 'solve_bounded'} ({backend}) vs {ref} per frame on "
            f"{len(cases)} P1 problems: worst {res[f'{what}_speedup']:.1f}x ({w['keys']} {w['selection']} "
            f"{w['take']}, {w['frames']} frames), median {res[f'{what}_speedup_median']:.1f}x; NumPy backend worst "
            f"{res[f'{what}_speedup_numpy']:.1f}x, median {res[f'{what}_speedup_numpy_median']:.1f}x; "
            f"max |dW| {res[f'{what}_max_abs_diff']:.1e}, objective worse by at most "
            f"{res[f'{what}_obj_rel_diff']:.1e} (relative), better by up to {res[f'{what}_obj_rel_gain']:.1e}, "
            f"KKT {res[f'{what}_kkt']:.1e}")
    return res


def _remove(points: np.ndarray, frac: float, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    out = points.copy()
    gone = rng.random(points.shape[:2]) < frac
    out[gone] = np.nan
    return out


def missing_markers(data: Path, ict, ark, rom, takes, log) -> dict:
    res = {"mocap": [], "p1": []}
    for f in sorted((data / "facial-mocap").glob("*.c3d")):
        perf = read_c3d(f)
        al = RigidAligner()
        aligned = al.fit_transform(perf).take
        X = aligned.points
        complete = np.isfinite(X).all(axis=(1, 2))
        idx = np.flatnonzero(complete)
        neutral = X[idx[0]]
        Fc = (X[idx] - neutral).reshape(len(idx), -1)
        frames = idx[select_keyshapes(Fc, 20, "nnls-greedy")]
        keys = Rig.__new__(Rig)
        from faceretarget.mesh import Mesh

        keys = Rig(Mesh(neutral), [f"f{i}" for i in frames], X[frames] - neutral, perf.unit or "mm")
        truth = X[idx]
        errs = {}
        for name, inp in (("complete", truth), ("missing10", _remove(truth, 0.10, seed=7))):
            rt = BlendshapeRetargeter(features="all", align=False).fit(keys, keys)
            pred = rt.blend(rt.transform(inp, perf.times[idx]).weights)
            errs[name] = 100 * np.abs(pred - truth).sum() / np.abs(truth - neutral).sum()
        res["mocap"].append(dict(take=f.stem, markers=X.shape[1], frames=len(idx), **errs,
                                 ratio=errs["missing10"] / errs["complete"]))
        log(f"  {f.stem:9s} complete {errs['complete']:.2f} %  10 % samples missing {errs['missing10']:.2f} %  "
            f"ratio {errs['missing10'] / errs['complete']:.2f}")
    labels, U, names = keyset_weights("rom-40", ict, rom=rom, selection="nnls-greedy")
    sk, tk = keymodel_rig(ict, labels, U, names), keymodel_rig(ark, labels, U, names)
    rt = BlendshapeRetargeter(features="landmarks").fit(sk, tk)
    for ti, take in enumerate(TAKES):
        src, gtb = _animate(ict, takes[take]), _animate(ark, takes[take])
        pts = src[:, ict.landmarks]
        e = {}
        for name, inp in (("complete", pts), ("missing10", _remove(pts, 0.10, seed=ti))):
            pred = rt.blend(rt.transform(inp, takes[take].times).weights)
            e[name] = metrics(pred, gtb, ark.neutral.vertices, ark.unit)["rel_motion_pct"]
        res["p1"].append(dict(take=take, **e, ratio=e["missing10"] / e["complete"]))
        log(f"  P1 {take[:9]:9s} complete {e['complete']:.2f} %  10 % missing {e['missing10']:.2f} %  "
            f"ratio {e['missing10'] / e['complete']:.2f}")
    res["worst_ratio"] = max(r["ratio"] for r in res["mocap"] + res["p1"])
    return res


def _table(rows, log) -> None:
    log("\nrel_motion_pct %, out of sample, 68 landmarks (retarget / retarget-nnls / clone; oracle, the oracle "
        "inside retarget's weight range, retarget's weights)")
    keyed = {}
    for r in rows:
        keyed[(r["kind"], r["keys"], r["selection"], r["take"], r["noise_mm"], r["method"])] = r
    combos = sorted({(r["kind"], r["keys"], r["selection"]) for r in rows},
                    key=lambda c: (c[0], int(c[1].split("-")[1]) if "-" in c[1] else 0, c[2]))
    for kind, keys, sel in combos:
        cells = []
        for take in TAKES:
            for noise in (0.0, 0.5):
                got = [keyed.get((kind, keys, sel, take, noise, m)) for m in METHODS]
                if got[0] is None:
                    continue
                cells.append(f"{take[:5]}/{noise}: " + "/".join("-" if g is None else f"{g['rel_motion_pct']:.1f}"
                                                               for g in got)
                             + f" ({got[0]['oracle_rel_motion_pct']:.1f}, in range "
                             f"{got[0]['oracle_bounded_rel_motion_pct']:.1f}; w {got[0]['w_min']:.2f}..{got[0]['w_max']:.2f})")
        log(f"{kind:9s} {keys:7s} {sel:12s} " + "  ".join(cells))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--data", default=str(REPO.parent / "shared" / "data"))
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--json", action="store_true")
    ap.add_argument("--speed-only", action="store_true", help="only the solver speed on the P1 problems")
    ap.add_argument("--repeat", type=int, default=REPEAT, help="timed runs per solver in the speed part (best kept)")
    args = ap.parse_args(argv)
    data = Path(args.data)
    log = print
    rigs, rom, takes = _load(data)
    ict, ark = rigs["ict-face"], rigs["arkit-face"]
    log("P1 retargeting ICT -> ARKit (cross and round trip), out of sample")
    if args.speed_only:
        problems = _speed_problems(ict, rom, takes)
        rows = []
    else:
        rows, problems = p1(ict, ark, rom, takes, args.quick, log)
        _table(rows, log)
    log("\nsolver speed")
    sp = speed(problems, args.quick, log, max(1, args.repeat))
    mm = {}
    if not args.speed_only:
        log("\nmissing markers (10 % of samples removed at random)")
        mm = missing_markers(data, ict, ark, rom, takes, log)
    worst = {}
    for r in rows:
        if r["kind"] == "cross" and r["keys"] == "rom-40" and r["method"] == "retarget":
            worst.setdefault(r["selection"], []).append(r["rel_motion_pct"])
    log("\nrom-40 cross, retarget (default), worst over takes and noise: "
        + ", ".join(f"{s} {max(v):.2f} %" for s, v in worst.items()))
    if args.json:
        out = dict(experiments=rows, **sp, missing_markers=mm)
        print(json.dumps(out))
    return 0


if __name__ == "__main__":
    sys.exit(main())
