"""``faceretarget demo``: the main job end to end on the embedded procedural characters.

No data from outside the package is needed.  Two parts:

1. The main job, :func:`~faceretarget.pipelines.animate` (the same function as ``faceretarget
   animate VIDEO``): "ada" performs a take with her head moving; what a video tracker would give is
   stood in for by her 68 landmarks as a camera sees them (head motion, 1 px = 1/400 of her face
   scale, 0.5 mm of noise) and her weights with noise as the tracker's scores.  ``animate`` drives
   "bo"'s own shapes from the landmarks and writes ``animate.glb`` (face and head) and
   ``preview.mp4`` (ada rendered as the input video beside bo; needs PyAV, ``make demo`` installs
   it), and the result is compared with bo driven by ada's true weights.
2. Example-based cloning on the same characters: only ada's 68 landmarks are "captured" (0.5 mm
   of noise); an artist's key-models are stood in for by 20 frames of a separate range-of-motion
   take (pivoted QR) modelled on both characters; the take is cloned onto bo (different topology
   and proportions, his own broader smile) with the paper's method and the package default, and
   compared with the ground truth.  Writes ``clone.glb`` (bo's key-models as morph targets),
   ``preview.png`` and ``metrics.json``.
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
from ..headpose import HeadPose
from ..io import write_glb
from ..metrics import FIGURES, figure_line, metrics
from ..performance import Performance
from ..render import render_frames, render_grid, save_png

__all__ = ["run_demo"]


def _demo_head(times: np.ndarray) -> HeadPose:
    """A nod and a turn (degrees: yaw 12, pitch 6, roll 3) and a small sway (metres)."""
    ang = np.c_[12 * np.sin(2 * np.pi * times / 3.1), 6 * np.sin(2 * np.pi * times / 1.7 + 1), 3 * np.sin(times)]
    tr = np.c_[0.01 * np.sin(times), 0.005 * np.sin(1.3 * times), np.zeros_like(times)]
    return HeadPose.from_euler("YXZ", ang, tr, degrees=True, source="demo head")


def _tracked_demo(ada, take, src: np.ndarray, head: HeadPose, noise_mm: float) -> Performance:
    """What a video tracker gives of ada: her 68 landmarks seen by a camera (head motion, pixels, white
    noise) and her weights with noise as the tracker's scores."""
    rng = np.random.default_rng(11)
    X = add_capture_noise(src[:, ada.landmarks], noise_mm, ada.unit, seed=0)
    pivot = ada.neutral.vertices.mean(axis=0)
    R = head.as_matrix()
    px = 400.0 / np.ptp(ada.neutral.vertices[:, 0])            # ada's face 400 px wide
    m = 1000.0 / ada.mm_per_unit                                 # metres -> rig units
    P = px * (np.einsum("tij,tpj->tpi", R, X - pivot) + pivot + m * head.translation[:, None])
    scores = np.clip(take.weights + rng.normal(0, 0.03, take.weights.shape), 0.0, 1.0)
    return Performance(take.times, take.fps, points=P, labels=[f"lm{i}" for i in range(68)], unit="px",
                       weights=scores, names=list(take.names), head=head, source="ada (tracked)")


def _source_video(path: Path, ada, src: np.ndarray, head: HeadPose, fps: float, size: int,
                  progress: bool = False) -> None:
    """ada's take rendered with her head moving, as the "input video" of the preview."""
    from tqdm.auto import tqdm

    from ..io import write_video
    from ..render import MeshRenderer

    with MeshRenderer(ada.neutral, (size, size), color=demo_vertex_colors("ada"),
                      mm_per_unit=ada.mm_per_unit) as r, tqdm(total=len(src), desc="input video", unit="frame",
                                                               disable=not progress, leave=False) as bar:
        R, T = head.as_matrix(), head.translation
        write_video(path, (r.render(src[i], R[i], T[i]) for i in range(len(src))), fps, on_frame=bar.update)


def _main_job(out: Path, ada, bo, take, src, truth, noise_mm: float, log, progress: bool = False) -> dict:
    """The main job (:func:`animate`) on the procedural take, compared with the ground truth."""
    from ._animate import animate

    head = _demo_head(take.times - take.times[0])
    tracked = _tracked_demo(ada, take, src, head, noise_mm)
    try:
        import av  # noqa: F401  (the preview video needs PyAV)
        video = out / "ada_input.mp4"
        log(f"rendering ada's take as the input video ({video.name})")
        _source_video(video, ada, src, head, take.fps, 384, progress)
        preview = out / "preview.mp4"
    except ImportError:
        video = preview = None
        from ..optional import install_line

        log(f"no preview video: PyAV is missing ({install_line('av')}; make demo installs it)")
    res = animate(tracked, bo, out=out / "animate.glb", preview=preview, preview_size=384,
                  preview_video=video, preview_colors=demo_vertex_colors("bo"), progress=progress, log=log)
    pred = bo.evaluate(res.weights)
    m = metrics(pred, truth, bo.neutral.vertices, bo)
    log("animate ada -> bo (bo's own shapes from the tracked landmarks), against bo driven by ada's true weights:")
    advice = "check the character's landmarks and the shapes that drive (--shapes)"
    log("  " + figure_line("rel_motion", m["rel_motion_pct"], advice))
    log(f"  {figure_line('lips_mm', m['lve_mm'])}")
    log(f"  {figure_line('mouth_corr', res.mouth_corr)}")
    return {k: float(v) for k, v in m.items()} | {"mouth_corr": res.mouth_corr}


def run_demo(out: Path, log=print, noise_mm: float = 0.5, progress: bool = False) -> int:
    """The demo (module docstring) into ``out``; ``progress``: progress indicators for its longer steps."""
    t0 = time.perf_counter()
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    ada, bo = make_demo_character("ada"), make_demo_character("bo")
    rom = make_demo_take(seconds=40.0, fps=30.0, seed=1)
    take = make_demo_take(seconds=6.0, fps=30.0, seed=7)
    log(f"characters: ada {ada.n_vertices} vertices, bo {bo.n_vertices} vertices, {ada.n_shapes} ARKit shapes each")
    src = ada.evaluate(ada.map_weights(take.names, take.weights, warn=False))
    truth = bo.evaluate(bo.map_weights(take.names, take.weights, warn=False))
    log(f"performance: {take.n_frames} frames at {take.fps:g} fps")
    summary = {"animate": _main_job(out, ada, bo, take, src, truth, noise_mm, log, progress)}
    sk, tk, _ = keymodel_pair(ada, bo, "rom-20", rom=rom)
    log(f"key-models: 20 frames of a {rom.duration:.0f} s range-of-motion take (pivoted QR), on both characters")
    captured = add_capture_noise(src[:, ada.landmarks], noise_mm, ada.unit, seed=0)
    results = {}
    log("cloning ada -> bo through key-models, against ground truth: the paper's method (pyun), linear and the "
        "default (temporal); " + FIGURES["rel_motion"].meaning + f", good under {FIGURES['rel_motion'].bound:g} %; "
        "Eq. 12 is Pyun et al.'s own error measure (lower is better); lips as above")
    for method in ("pyun", "linear", "temporal"):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")   # the procedural takes span fewer directions than 20 keys
            c = ExpressionCloner(method).fit(sk, tk)
            w = c.transform(captured, take.times).weights
        pred = c.blend(w)
        m = metrics(pred, truth, bo.neutral.vertices, bo, target_keys=tk.deltas + bo.neutral.vertices)
        results[method] = {"weights": w, "pred": pred, "metrics": m}
        verdict = "good" if FIGURES["rel_motion"].good(m["rel_motion_pct"]) else "not good"
        log(f"  {method:9s} motion error {m['rel_motion_pct']:6.2f} % ({verdict})   Eq. 12 {m['err_pct']:.4f} %   "
            f"lips {m['lve_mm']:.2f} mm")
    log(f"  (the best possible blend of these key-models, a floor no method can go under: "
        f"{results['temporal']['metrics']['oracle_rel_motion_pct']:.2f} %; the paper's methods miss it with 20 "
        "key-models, the default keeps the take's timing and comes closest)")
    best = results["temporal"]
    glb = out / "clone.glb"
    write_glb(glb, tk, best["weights"], take.times, names=list(tk.names), node_name="bo")
    frames = np.linspace(10, take.n_frames - 10, 5).astype(int)
    log("rendering preview.png (source, paper, faceretarget, ground truth)")
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
    summary |= {m: {k: float(v) for k, v in r["metrics"].items()} for m, r in results.items()}
    with atomic_path(out / "metrics.json") as tmp:
        tmp.write_text(json.dumps(summary, indent=2))
    log(f"wrote {glb}, {out / 'preview.png'}, {out / 'metrics.json'} in {time.perf_counter() - t0:.1f} s")
    return 0
