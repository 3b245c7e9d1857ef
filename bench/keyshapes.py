"""P2 benchmark: keyshape selection, reconstruction error against the number of keys (Chuang Fig. 3.6).

Protocol P2 of ../shared/EVALUATION.md.  Data sets:

* ``mocap/<take>``: each ``facial-mocap/*.c3d`` take (41 markers, mm) with the rigid head motion
  removed (:class:`faceretarget.numerics.RigidAligner`, automatic rigid subset, median
  reference).  The takes have no separate neutral: the **first frame** is taken as the neutral, so
  ``X`` holds every frame's marker displacements from it.  Frames with a missing marker are dropped
  (none in the shared takes).
* ``ict68/<take>``: the 68 landmark vertices of the ``ict-face`` rig driven by each ``livelinkface``
  take's weights; the rig's neutral is the neutral.  Converted from cm to mm.

Methods: every entry of :data:`faceretarget.numerics.SELECTION_METHODS` (``pca-extrema``,
``hull``, ``kmeans2``, ``kmeans3``, ``pivoted-qr``, ``nnls-greedy``) plus ``nnls-greedy/noguard``, the new method
without its PCA-extrema guard, to show how it does on its own.  ``nnls-greedy`` grows its sets
one key at a time, so its sets for every k come from one run (:func:`nnls_greedy_path`;
``nnls_greedy(X, k)`` returns exactly ``path[k - 1]``, as the tests check); the other methods are
called once per k.

Error (:func:`faceretarget.numerics.reconstruction_error`): every frame of the take is
fitted with non-negative weights of the k chosen frames (exact NNLS per frame; the neutral is the
implicit zero key), and the residual's RMS over all frames and coordinates is reported in mm, and
as a percentage of the take's RMS motion ``sqrt(mean(X**2))`` (100 % = reconstructing everything as
the neutral).  Every frame is used (no subsampling).  A few errors are recomputed with
``scipy.optimize.nnls`` per frame as a check of the solver.

Usage::

    python bench/keyshapes.py [--json] [--data ../shared/data] [--png out/keyshapes_p2.png] [--kmax 40]

Prints one table per data set (rows k, columns methods, % of RMS motion), writes the plot, and with
``--json`` ends with one line ``{"p2": {dataset: {method: [err_mm at k=2..kmax]}}, "p2_rel_pct": ...,
"new_le_pca_all": bool, "pca_monotone": bool, ...}``.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
import warnings
from pathlib import Path

import numpy as np
from scipy.optimize import nnls as scipy_nnls

from _plot import font as _font  # bench/_plot.py (same folder)
from _plot import nice_step as _nice_step
from faceretarget.io import read_c3d, read_livelinkface, read_rig
from faceretarget.numerics import SELECTION_METHODS, RigidAligner, nnls_greedy_path, reconstruction_error

REPO = Path(__file__).resolve().parents[1]
NEW = "nnls-greedy"
SOLO = "nnls-greedy/noguard"
METHODS = ["pca-extrema", "hull", "kmeans2", "kmeans3", "pivoted-qr", NEW, SOLO]
COLORS = {"pca-extrema": (214, 39, 40), "hull": (255, 127, 14), "kmeans2": (44, 160, 44),
          "kmeans3": (148, 103, 189), "pivoted-qr": (140, 86, 75), NEW: (31, 119, 180), SOLO: (23, 190, 207)}
TOL = 1e-9   # relative tolerance of the comparisons (solver rounding)


def log(*a) -> None:
    print(*a, flush=True)


# ----------------------------------------------------------------------------------- data
def load_datasets(data: Path) -> dict[str, np.ndarray]:
    """Every P2 data set as ``X`` (T, D) displacements from the neutral, in mm."""
    out: dict[str, np.ndarray] = {}
    for f in sorted((data / "facial-mocap").glob("*.c3d")):
        take = read_c3d(f)
        al = RigidAligner()
        res = al.fit_transform(take)
        head = res.take
        log(f"mocap/{f.stem}: {take.n_frames} frames, {take.points.shape[1]} markers; {res.report(take.unit)}")
        p = head.points
        ok = np.isfinite(p).all(axis=(1, 2))
        if not ok.all():
            log(f"  dropping {int((~ok).sum())} frame(s) with a missing marker")
            p = p[ok]
        scale = {"mm": 1.0, "cm": 10.0, "m": 1000.0}.get((take.unit or "mm").strip().lower(), 1.0)
        out[f"mocap/{f.stem}"] = ((p - p[0]) * scale).reshape(len(p), -1)
    rig = read_rig(data / "ict-face")
    D = rig.deltas[:, rig.landmarks].reshape(rig.n_shapes, -1) * rig.mm_per_unit
    for f in sorted((data / "livelinkface").glob("*.csv")):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            take = read_livelinkface(f)
        W = rig.map_weights(take.names, take.weights, warn=False)
        out[f"ict68/{f.stem}"] = W @ D
        log(f"ict68/{f.stem}: {take.n_frames} frames, 68 landmarks of ict-face")
    return out


# ------------------------------------------------------------------------------- measure
def run_dataset(X: np.ndarray, ks: list[int]) -> tuple[dict, dict, dict]:
    """Errors (mm) per method and k, selection seconds per method, and notes."""
    kmax = max(ks)
    sets: dict[str, dict[int, np.ndarray]] = {}
    secs: dict[str, float] = {}
    for m in METHODS[:5]:
        t0 = time.perf_counter()
        sets[m] = {k: SELECTION_METHODS[m](X, k) for k in ks}
        secs[m] = time.perf_counter() - t0
    t0 = time.perf_counter()
    path, info = nnls_greedy_path(X, kmax, return_info=True)
    secs[NEW] = time.perf_counter() - t0
    sets[NEW] = {k: path[k - 1] for k in ks}
    if info["guarded"]:      # the guard acted: run the method again without it
        t0 = time.perf_counter()
        solo = nnls_greedy_path(X, kmax, guard=False)
        secs[SOLO] = time.perf_counter() - t0
        sets[SOLO] = {k: solo[k - 1] for k in ks}
    else:                    # the guard never acted, so the unguarded run is the same run
        secs[SOLO] = secs[NEW]
        sets[SOLO] = sets[NEW]
    errs = {}
    for m in METHODS:
        for k in ks:
            s = sets[m][k]
            if len(s) != k or len(np.unique(s)) != k:
                raise AssertionError(f"{m} returned {len(np.unique(s))} distinct frames for k={k}")
        if m == SOLO and sets[SOLO] is sets[NEW]:
            errs[m] = list(errs[NEW])
        else:
            errs[m] = [reconstruction_error(X, sets[m][k]) for k in ks]
    # spot check of the solver against SciPy per frame
    worst = 0.0
    for k in (ks[0], 10, 20, kmax):
        if k in ks:
            K = X[sets["pca-extrema"][k]].T
            r = np.array([scipy_nnls(K, x)[1] for x in X])
            ref = float(np.sqrt((r**2).sum() / X.size))
            worst = max(worst, abs(errs["pca-extrema"][ks.index(k)] - ref) / max(ref, 1e-300))
    return errs, secs, {"guarded": info["guarded"], "solver_check_rel_diff": worst}


# ---------------------------------------------------------------------------------- plot


def plot(rel: dict[str, dict[str, list[float]]], ks: list[int], path: Path) -> Path:
    """A grid of panels, one per data set: relative error (%) against k per method, with a legend."""
    from PIL import Image, ImageDraw

    names = list(rel)
    cols = 4
    rows = (len(names) + cols - 1) // cols
    pw, ph = 430, 320
    top = 90
    W, H = cols * pw + 20, top + rows * ph + 10
    img = Image.new("RGB", (W, H), (255, 255, 255))
    d = ImageDraw.Draw(img)
    f_title, f_small, f_big = _font(15), _font(12), _font(20)
    d.text((12, 8), "P2 keyshape selection: NNLS reconstruction error vs number of keyshapes "
                    "(RMS residual, % of the take's RMS motion)", fill=(0, 0, 0), font=f_big)
    # legend
    x = 14
    for m in METHODS:
        c = COLORS[m]
        dash = m == SOLO
        _line(d, [(x, 52), (x + 34, 52)], c, 3, dash)
        d.text((x + 40, 44), m + (" (= nnls-greedy where the guard never acted)" if dash else ""),
               fill=(0, 0, 0), font=f_small)
        x += 60 + int(d.textlength(m, font=f_small)) + (int(d.textlength(
            " (= nnls-greedy where the guard never acted)", font=f_small)) if dash else 0)
    for n, name in enumerate(names):
        r, c = divmod(n, cols)
        x0, y0 = 10 + c * pw, top + r * ph
        ax0, ax1 = x0 + 52, x0 + pw - 16
        ay0, ay1 = y0 + 30, y0 + ph - 42
        curves = rel[name]
        ymax = max(max(v) for v in curves.values())
        step = _nice_step(ymax / 5)
        ytop = step * int(np.ceil(ymax / step))

        def X_(k, ax0=ax0, ax1=ax1):
            return ax0 + (k - ks[0]) / (ks[-1] - ks[0]) * (ax1 - ax0)

        def Y_(v, ay0=ay0, ay1=ay1, ytop=ytop):
            return ay1 - v / ytop * (ay1 - ay0)

        d.text((ax0, y0 + 8), name, fill=(0, 0, 0), font=f_title)
        # grid and ticks
        yv = 0.0
        while yv <= ytop + 1e-9:
            yy = Y_(yv)
            d.line([(ax0, yy), (ax1, yy)], fill=(225, 225, 225))
            lab = f"{yv:g}"
            d.text((ax0 - 6 - d.textlength(lab, font=f_small), yy - 7), lab, fill=(60, 60, 60), font=f_small)
            yv += step
        for kt in [ks[0]] + [k for k in ks if k % 10 == 0]:
            xx = X_(kt)
            d.line([(xx, ay1), (xx, ay1 + 5)], fill=(0, 0, 0))
            lab = str(kt)
            d.text((xx - d.textlength(lab, font=f_small) / 2, ay1 + 7), lab, fill=(60, 60, 60), font=f_small)
        d.line([(ax0, ay0), (ax0, ay1), (ax1, ay1)], fill=(0, 0, 0), width=1)
        d.text(((ax0 + ax1) / 2 - 70, ay1 + 22), "number of keyshapes k", fill=(0, 0, 0), font=f_small)
        d.text((x0 + 2, ay0 - 18), "error %", fill=(0, 0, 0), font=f_small)
        # the unguarded curve goes under nnls-greedy: it shows (dashed) only where the two differ
        for m in [m for m in METHODS if m not in (NEW, SOLO)] + [SOLO, NEW]:
            pts = [(X_(k), Y_(v)) for k, v in zip(ks, curves[m], strict=True)]
            _line(d, pts, COLORS[m], 3 if m in (NEW, SOLO) else 2, m == SOLO)
    img.save(path, format="PNG")
    return path




def _line(d, pts, color, width, dashed) -> None:
    if not dashed:
        d.line(pts, fill=color, width=width, joint="curve")
        return
    # dashes along the polyline: 7 px on, 5 px off
    on, off = 7.0, 5.0
    pos = 0.0
    for (xa, ya), (xb, yb) in zip(pts[:-1], pts[1:], strict=True):
        L = float(np.hypot(xb - xa, yb - ya))
        t = 0.0
        while t < L:
            phase = pos % (on + off)
            if phase < on:
                seg = min(on - phase, L - t)
                a = t / L if L else 0.0
                b = (t + seg) / L if L else 0.0
                d.line([(xa + a * (xb - xa), ya + a * (yb - ya)), (xa + b * (xb - xa), ya + b * (yb - ya))],
                       fill=color, width=width)
            else:
                seg = min(on + off - phase, L - t)
            t += seg
            pos += seg


# ---------------------------------------------------------------------------------- main
def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--data", type=Path, default=REPO.parent / "shared" / "data")
    ap.add_argument("--png", type=Path, default=REPO / "out" / "keyshapes_p2.png")
    ap.add_argument("--kmax", type=int, default=40)
    ap.add_argument("--only", default="", help="comma-separated substrings of data set names to run")
    ap.add_argument("--json", action="store_true", help="print a JSON summary as the last line")
    a = ap.parse_args(argv)
    if not a.data.is_dir():
        log(f"data folder not found: {a.data}")
        return 2
    t_all = time.perf_counter()
    datasets = load_datasets(a.data)
    if a.only:
        keep = [s for s in a.only.split(",") if s]
        datasets = {n: X for n, X in datasets.items() if any(s in n for s in keep)}
    ks = list(range(2, a.kmax + 1))
    p2: dict[str, dict[str, list[float]]] = {}
    rel: dict[str, dict[str, list[float]]] = {}
    notes = {}
    for name, X in datasets.items():
        rms = float(np.sqrt((X**2).mean()))
        errs, secs, note = run_dataset(X, ks)
        p2[name] = errs
        rel[name] = {m: [100.0 * e / rms for e in v] for m, v in errs.items()}
        notes[name] = {"rms_motion_mm": rms, "frames": len(X), "dims": X.shape[1],
                       "selection_s": secs, **note}
        log(f"\n{name}: {len(X)} frames x {X.shape[1]} coordinates, RMS motion {rms:.3f} mm; "
            f"error in % of it (mm: x {rms / 100:.4f})")
        log("selection time (s): " + ", ".join(f"{m} {s:.2f}" for m, s in secs.items()))
        if note["guarded"]:
            log(f"{NEW}: the PCA-extrema guard acted at k = {note['guarded']}")
        log("   k " + "".join(f"{m:>21}" for m in METHODS))
        for i, k in enumerate(ks):
            best = min(rel[name][m][i] for m in METHODS)
            cells = "".join(f"{rel[name][m][i]:>20.2f}" + ("*" if rel[name][m][i] <= best * (1 + TOL) else " ")
                            for m in METHODS)
            log(f"{k:>4} {cells}")
    pca_monotone = all(all(b <= a_ * (1 + TOL) for a_, b in zip(v["pca-extrema"][:-1], v["pca-extrema"][1:],
                                                                 strict=True)) for v in p2.values())
    le = {n: [e <= p * (1 + TOL) for e, p in zip(v[NEW], v["pca-extrema"], strict=True)] for n, v in p2.items()}
    le_solo = {n: [e <= p * (1 + TOL) for e, p in zip(v[SOLO], v["pca-extrema"], strict=True)]
               for n, v in p2.items()}
    new_le = all(all(v) for v in le.values())
    solo_wins = sum(sum(v) for v in le_solo.values())
    total = sum(len(v) for v in le_solo.values())
    ratio = {m: float(np.mean([np.mean(np.asarray(v[m]) / np.asarray(v["pca-extrema"])) for v in p2.values()]))
             for m in METHODS}
    log("\nsummary (mean over data sets and k of error / PCA extrema's error):")
    log("  " + ", ".join(f"{m} {r:.3f}" for m, r in ratio.items()))
    log(f"  {NEW} <= pca-extrema at every k on every data set: {new_le}")
    log(f"  {SOLO} (no guard) <= pca-extrema at {solo_wins} of {total} (data set, k) points; loses at "
        + (", ".join(f"{n} k={ks[i]}" for n, v in le_solo.items() for i, ok in enumerate(v) if not ok) or "none"))
    log(f"  pca-extrema error non-increasing in k on every data set: {pca_monotone}")
    log("  solver check against scipy.optimize.nnls per frame, largest relative difference: "
        f"{max(n['solver_check_rel_diff'] for n in notes.values()):.2e}")
    a.png.parent.mkdir(parents=True, exist_ok=True)
    plot(rel, ks, a.png)
    elapsed = time.perf_counter() - t_all
    log(f"  plot: {a.png}\n  total time {elapsed:.1f} s")
    if a.json:
        print(json.dumps({"p2": p2, "p2_rel_pct": rel, "k": ks, "new_method": NEW,
                          "new_le_pca_all": new_le, "pca_monotone": pca_monotone,
                          "solo_le_pca_points": [solo_wins, total], "mean_ratio_to_pca": ratio,
                          "datasets": notes, "png": str(a.png), "seconds": elapsed}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
