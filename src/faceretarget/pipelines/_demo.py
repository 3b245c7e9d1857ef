"""``faceretarget demo``: the main job end to end on the embedded procedural characters.

No data from outside the package is needed.  Source character "ada" performs a take (seeded ARKit
weight curves); only her 68 landmarks are "captured", with 0.5 mm of Gaussian capture noise.  An
artist's key-models are stood in for by 20 frames of a separate range-of-motion take chosen by PCA
extrema and modelled on both characters; the take is cloned onto "bo" (different topology and
proportions, his own broader smile) with the paper's method and with the package default, and
compared with the ground truth (bo driven by the same weights).  Writes ``clone.glb`` (bo's
key-models as morph targets, the take as morph-weight animation), ``preview.png`` and
``metrics.json``.
"""

from __future__ import annotations

import json
import time
import warnings
from pathlib import Path

import numpy as np

from ..cloning import ExpressionCloner, keymodel_pair
from ..datasets import add_capture_noise, demo_vertex_colors, make_demo_character, make_demo_take
from ..files import atomic_path
from ..io import write_glb
from ..metrics import metrics
from ..render import render_frames, render_grid, save_png

__all__ = ["run_demo"]


def run_demo(out: Path, log=print, noise_mm: float = 0.5) -> int:
    t0 = time.perf_counter()
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    ada, bo = make_demo_character("ada"), make_demo_character("bo")
    rom = make_demo_take(seconds=40.0, fps=30.0, seed=1)
    take = make_demo_take(seconds=6.0, fps=30.0, seed=7)
    log(f"characters: ada {ada.n_vertices} vertices, bo {bo.n_vertices} vertices, {ada.n_shapes} ARKit shapes each")
    sk, tk, _ = keymodel_pair(ada, bo, "rom-20", rom=rom)
    log(f"key-models: 20 frames of a {rom.duration:.0f} s range-of-motion take (pivoted QR), on both characters")
    src = ada.evaluate(ada.map_weights(take.names, take.weights, warn=False))
    truth = bo.evaluate(bo.map_weights(take.names, take.weights, warn=False))
    captured = add_capture_noise(src[:, ada.landmarks], noise_mm, ada.unit, seed=0)
    log(f"performance: {take.n_frames} frames at {take.fps:g} fps, 68 landmarks with {noise_mm} mm capture noise")
    rows, results = [], {}
    for method in ("pyun", "linear", "temporal"):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")   # the procedural takes span fewer directions than 20 keys
            c = ExpressionCloner(method).fit(sk, tk)
            w = c.transform(captured, take.times).weights
        pred = c.blend(w)
        m = metrics(pred, truth, bo.neutral.vertices, bo, target_keys=tk.deltas + bo.neutral.vertices)
        results[method] = {"weights": w, "pred": pred, "metrics": m}
        rows.append(f"  {method:9s} rel_motion {m['rel_motion_pct']:6.2f} %   err (Eq. 12) {m['err_pct']:.4f} %   "
                    f"mean vertex error {m['mve_mm']:.3f} mm   lips {m['lve_mm']:.2f} mm")
    log("cloning ada -> bo, against ground truth (share of the motion that is wrong; oracle floor "
        f"{results['temporal']['metrics']['oracle_rel_motion_pct']:.2f} %):")
    for r in rows:
        log(r)
    best = results["temporal"]
    glb = out / "clone.glb"
    write_glb(glb, tk, best["weights"], take.times, names=list(tk.names), node_name="bo")
    frames = np.linspace(10, take.n_frames - 10, 5).astype(int)
    size = (220, 240)
    ca, cb = demo_vertex_colors("ada"), demo_vertex_colors("bo")
    src_imgs = list(render_frames(src[frames], ada.neutral, size, color=ca))
    pyun_imgs = list(render_frames(results["pyun"]["pred"][frames], bo.neutral, size, color=cb))
    our_imgs = list(render_frames(best["pred"][frames], bo.neutral, size, color=cb))
    gt_imgs = list(render_frames(truth[frames], bo.neutral, size, color=cb))
    labels = ([f"ada (source) t={take.times[f]:.1f}s" for f in frames] + ["bo: pyun"] * len(frames)
              + ["bo: faceretarget"] * len(frames) + ["bo: ground truth"] * len(frames))
    sheet = render_grid(src_imgs + pyun_imgs + our_imgs + gt_imgs, labels, cols=len(frames))
    save_png(out / "preview.png", sheet)
    summary = {m: {k: float(v) for k, v in r["metrics"].items()} for m, r in results.items()}
    with atomic_path(out / "metrics.json") as tmp:
        tmp.write_text(json.dumps(summary, indent=2))
    log(f"wrote {glb}, {out / 'preview.png'}, {out / 'metrics.json'} in {time.perf_counter() - t0:.1f} s")
    return 0
