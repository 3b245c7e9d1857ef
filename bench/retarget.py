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
* solver speed: :func:`solve_nnls` on the real P1 problems (every rom-K key set x every take, landmark
  features) against ``scipy.optimize.nnls`` called per frame, in this run, with the largest
  weight difference;
* missing markers: the four ``facial-mocap`` takes retargeted onto their own keyshapes (20, chosen by
  ``nnls-greedy``) complete and with 10 % of the marker samples removed at random; error = share of
  the (complete, head-stabilised) marker motion that is wrong, on every marker including the removed
  ones; and the same on P1 (ICT -> ARKit rom-40) with 10 % of the landmark samples removed.

Usage::

    python bench/retarget.py [--quick] [--json] [--data ../shared/data]

``--quick``: rom-40 only and fewer speed problems; ``--speed-only``: only the solver speed (all
54 problems, about 3 min).  With ``--json`` the last stdout line is one JSON
object in P1's layout plus ``nnls_speedup``, ``nnls_max_abs_diff``, ``missing_markers``.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
import warnings
from pathlib import Path

import numpy as np
from scipy.optimize import nnls

from cloning import TAKES, _animate, _load  # the P1 loader of bench/cloning.py (same folder)
from faceretarget.cloning import ExpressionCloner, keymodel_rig, keyset_weights
from faceretarget.datasets import add_capture_noise
from faceretarget.errors import SingularKeysError
from faceretarget.io import read_c3d
from faceretarget.metrics import metrics, oracle_rel_motion_pct
from faceretarget.numerics import SELECTION_METHODS, RigidAligner, select_keyshapes, solve_nnls
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
    out = []
    for k in (10, 20, 40):
        for sel in SELECTION_METHODS:
            labels, U, names = keyset_weights(f"rom-{k}", ict, rom=rom, selection=sel)
            sk = keymodel_rig(ict, labels, U, names)
            Kl = sk.deltas[:, lm].reshape(sk.n_shapes, -1).T
            for take in TAKES:
                src = _animate(ict, takes[take])
                out.append((f"rom-{k}", sel, take, Kl, (src[:, lm] - ict.neutral.vertices[lm]).reshape(len(src), -1)))
    return out


def _scipy_loop(K, F):
    return np.stack([nnls(K, f)[0] for f in F])


def speed(problems, quick: bool, log) -> dict:
    """solve_nnls against scipy's nnls per frame on real P1 problems (single thread recommended)."""
    cases = []
    sel = problems if not quick else problems[:3]
    for keys, method, take, K, F in sel:
        t_ref = np.inf
        for _ in range(REPEAT):                    # best of REPEAT for every contender
            t0 = time.perf_counter()
            Wref = _scipy_loop(K, F)
            t_ref = min(t_ref, time.perf_counter() - t0)
        best = {}
        for backend in ("auto", "numpy"):
            best[backend] = np.inf
            for _ in range(REPEAT):
                t0 = time.perf_counter()
                Wb = solve_nnls(K, F, backend=backend)
                best[backend] = min(best[backend], time.perf_counter() - t0)
            if backend == "auto":
                W = Wb
        rel_fit = (np.linalg.norm(F - W @ K.T) - np.linalg.norm(F - Wref @ K.T)) / max(np.linalg.norm(F), 1e-300)
        cases.append(dict(keys=keys, selection=method, take=take, frames=len(F), scipy_s=t_ref, ours_s=best["auto"],
                          numpy_s=best["numpy"], speedup=t_ref / best["auto"],
                          speedup_numpy=t_ref / best["numpy"], max_abs_diff=float(np.abs(W - Wref).max()),
                          rel_fit_diff=float(rel_fit)))
    from faceretarget.numerics import _nnls_numba

    sp = np.array([c["speedup"] for c in cases])
    spn = np.array([c["speedup_numpy"] for c in cases])
    md = max(c["max_abs_diff"] for c in cases)
    backend = "numba kernel" if _nnls_numba.available() else "NumPy (numba not installed)"
    log(f"  solve_nnls ({backend}) vs scipy nnls per frame on {len(cases)} P1 problems: speedup min "
        f"{sp.min():.1f}x, median {np.median(sp):.1f}x, max {sp.max():.1f}x; max |dW| {md:.2e}")
    log(f"  NumPy backend alone: min {spn.min():.1f}x, median {np.median(spn):.1f}x, max {spn.max():.1f}x")
    return dict(nnls_speedup=float(sp.min()), nnls_speedup_median=float(np.median(sp)),
                nnls_speedup_numpy_median=float(np.median(spn)), nnls_max_abs_diff=md,
                nnls_backend=backend, nnls_cases=cases)


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
    sp = speed(problems, args.quick, log)
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
