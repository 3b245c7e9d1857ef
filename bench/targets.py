"""Retargeting onto any parameterisation (issue 16, Chuang Ch. 3): control vectors, skeletons, drawings.

* ``controls`` -- P1 with control-vector targets.  rom-40 keys are chosen on ``alex_rom_3.csv``
  (pivoted QR on the source's 68 landmarks, as ``keyset_weights``); each key's control vector is
  that ROM frame's 52 ARKit weights, written to a control table (``out/targets/rom40_<target>.csv``,
  range 0:1) and read back.  Each P1 take (``S07-001``, ``apfel``, ``MySlate_3``) is retargeted from
  the source rig's landmarks onto (a) the mesh keys (the target rig at the ROM weights,
  ``keymodel_rig``) and (b) the control table with the rig's shapes, by the default solve, whose
  frames with controls outside their ranges are solved again inside them (``--control-ranges
  solve``, the default since issue 24).  The curves of (b) played on the rig are compared with the
  mesh keys driven by the same key weights: ``max_rel_diff_vs_mesh`` is the largest vertex
  difference over the largest vertex motion of (a), worst take and target
  (``max_rel_diff_vs_unconstrained_mesh``: against (a) itself, what the range solve changes).
  ``in_range_pct`` is the share of control values inside the declared ranges as written (not
  clipped: solved inside), ``in_range_pct_as_first_solved`` the same for the curves of the
  take's weights as first solved (``--control-ranges report``); the P1 error against ground truth
  (the target rig driven by the take's own weights) is given for both, for the nearest in-range
  controls (``project``) and for the weight range [0, 1] instead of the default.  Pairs: ICT ->
  ARKit (``arkit-face``) and ARKit -> ICT (``ict-face``, its own ARKit-named shapes).
* ``skeleton`` -- the ``facial-mocap`` ``Cheeks`` markers (head motion removed) retargeted onto a
  skeleton whose K key poses are frames of ``headmotion/beat_2_scott_0_1_1.bvh`` (chosen by pivoted
  QR on the joints' world positions, frame 0 the rest pose), paired with K source keyshapes chosen
  from the take.  ``bone_length_max_dev`` is the largest change of any bone's length (cm, forward
  kinematics of the blended rotations) over all frames; the same from the written ``.bvh`` read
  back; ``vertex_blend_shrink_pct`` is the mean shortening of the bones when the joint positions of
  the same keys are blended linearly with the same weights (control-vertex blending), with its
  largest value and the share of bone-frames shortened by more than 1 %.  The ``.glb`` skin is
  checked by the Khronos validator when it is installed (``make tools``).
* ``svg`` -- the Live Link Face take ``S07-001`` (frames 450-1049) on the ``arkit-face`` rig,
  retargeted through 15 of its ARKit shapes onto the hand-drawn cartoon face
  (:mod:`faceretarget.datasets`, keys ``out/targets/face_keys``): the animated SVG
  (``out/targets/face.svg``), read back (``roundtrip_max_diff``), a contact sheet and an MP4 preview,
  and a screenshot by headless Chromium (``out/targets/face_chromium.png``, of the first frame's
  static SVG and of the animation 4 s in); ``renders`` is true when Chromium drew the face (its ink
  overlaps our rasteriser's by ``chromium_iou``).

Usage::

    python bench/targets.py [--json] [--data ../shared/data] [--out out/targets] [--only controls,skeleton,svg]

With ``--json`` the last stdout line is ``{"controls": {"max_rel_diff_vs_mesh", "in_range_pct", ...},
"skeleton": {"bone_length_max_dev", "vertex_blend_shrink_pct", ...}, "svg": {"frames", "renders", ...}}``.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import time
import warnings
from pathlib import Path

import numpy as np

from faceretarget.cloning import keymodel_rig, keyset_weights
from faceretarget.datasets import write_drawn_face
from faceretarget.io import (
    ControlTable,
    read_bvh,
    read_c3d,
    read_livelinkface,
    read_rig,
    read_svg_animation,
    read_svg_drawing,
    render_drawing,
    write_control_table,
)
from faceretarget.mesh import Mesh
from faceretarget.metrics import metrics
from faceretarget.numerics import select_keyshapes
from faceretarget.pipelines import retarget_take, select_keys, target_weights, write_result
from faceretarget.rig import Rig
from faceretarget.targets import bone_lengths, read_target

REPO = Path(__file__).resolve().parents[1]
TAKES = ("S07-001", "apfel", "MySlate_3_Jason_Millers_iPhone")
SKELETON_KEYS = 10
SVG_FRAMES = slice(450, 1050)


def _quiet(*_a) -> None:
    return None


# ------------------------------------------------------------------------------------------ controls
def controls(data: Path, out: Path, log) -> dict:
    ict, ark = read_rig(data / "ict-face"), read_rig(data / "arkit-face")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        rom = read_livelinkface(data / "livelinkface" / "alex_rom_3.csv")
        takes = {t: read_livelinkface(data / "livelinkface" / f"{t}.csv") for t in TAKES}
    res: dict = {"keys": "rom-40 (pivoted-qr on alex_rom_3)", "takes": list(TAKES), "targets": {}}
    worst, inside, total = 0.0, 0, 0
    for src, tgt in ((ict, ark), (ark, ict)):
        labels, U, names = keyset_weights("rom-40", src, rom=rom, selection="pivoted-qr")
        sk, tk = keymodel_rig(src, labels, U, names), keymodel_rig(tgt, labels, U, names)
        table = out / f"rom40_{tgt.name}.csv"
        write_control_table(table, ControlTable(labels, list(names), U, np.zeros(len(names)), np.ones(len(names)),
                                                np.zeros(len(names))))
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            target = read_target(table, rig=tgt)                       # the default: solved inside the ranges
            reported = read_target(table, rig=tgt, ranges="report")    # as first solved
            projected = read_target(table, rig=tgt, ranges="project")
        row: dict = {"source": src.name, "table": str(table.relative_to(REPO) if table.is_relative_to(REPO) else table),
                     "per_take": {}}
        C_all, C01_all, Cp_all, Cr_all = [], [], [], []
        for name, take in takes.items():
            t0 = time.perf_counter()
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                mesh = retarget_take(take, sk, tk, source_rig=src)
                ctrl = retarget_take(take, sk, target, source_rig=src)
                ctrl01 = retarget_take(take, sk, target, source_rig=src, weight_range=(0.0, 1.0))
            Vm = mesh.model.blend(mesh.result.weights)
            motion = np.abs(Vm - tgt.neutral.vertices).max()
            W = target_weights(ctrl)                                   # the key weights as first solved
            t1 = time.perf_counter()
            C = target.params(W)                                       # the default's curves
            solve_s = time.perf_counter() - t1
            Wk = target.key_weights(W)                                 # the weights they are a blend of
            Vc = tgt.evaluate(tgt.map_weights(names, C, warn=False))
            Vk = tk.evaluate(tk.map_weights(target.names, Wk, warn=False))
            rel = float(np.abs(Vc - Vk).max() / motion)
            rel_unc = float(np.abs(Vc - Vm).max() / motion)
            truth = tgt.evaluate(tgt.map_weights(take.names, take.weights, warn=False))
            Cr = reported.params(W)
            Vr = tgt.evaluate(tgt.map_weights(names, Cr, warn=False))
            C01 = reported.params(target_weights(ctrl01))
            V01 = tgt.evaluate(tgt.map_weights(names, C01, warn=False))
            m_def = metrics(Vc, truth, tgt.neutral.vertices, tgt.unit)
            m_rep = metrics(Vr, truth, tgt.neutral.vertices, tgt.unit)
            m01 = metrics(V01, truth, tgt.neutral.vertices, tgt.unit)
            Cp = projected.in_ranges(Cr)
            mp = metrics(tgt.evaluate(tgt.map_weights(names, Cp, warn=False)), truth, tgt.neutral.vertices, tgt.unit)
            rep = target.range_report(C)
            rep0 = target.range_report(Cr)
            again = float((Wk != W).any(axis=1).mean() * 100)
            row["per_take"][name] = {"frames": int(take.n_frames), "max_rel_diff_vs_mesh": rel,
                                     "max_rel_diff_vs_unconstrained_mesh": rel_unc,
                                     "in_range_pct": rep.inside_pct, "rel_motion_pct": m_def["rel_motion_pct"],
                                     "frames_solved_again_pct": again, "range_solve_ms_per_frame":
                                         1000 * solve_s / take.n_frames,
                                     "in_range_pct_as_first_solved": rep0.inside_pct,
                                     "rel_motion_pct_as_first_solved": m_rep["rel_motion_pct"],
                                     "in_range_pct_w01": target.range_report(C01).inside_pct,
                                     "rel_motion_pct_w01": m01["rel_motion_pct"],
                                     "in_range_pct_projected": target.range_report(Cp).inside_pct,
                                     "rel_motion_pct_projected": mp["rel_motion_pct"],
                                     "projected_max_rel_diff_vs_mesh": float(np.abs(
                                         tgt.evaluate(tgt.map_weights(names, Cp, warn=False)) - Vm).max() / motion),
                                     "seconds": time.perf_counter() - t0}
            worst = max(worst, rel)
            C_all.append(C)
            Cr_all.append(Cr)
            C01_all.append(C01)
            Cp_all.append(Cp)
            log(f"controls {src.name} -> {tgt.name} {name}: in range {rep.inside_pct:.2f} % as written (P1 rel motion "
                f"{m_def['rel_motion_pct']:.2f} %; {again:.1f} % of the frames solved again, "
                f"{1000 * solve_s / take.n_frames:.2f} ms per frame); curves vs mesh keys at the same weights "
                f"{rel:.2e}, vs the unconstrained mesh result {rel_unc:.3f}; as first solved {rep0.inside_pct:.2f} % "
                f"in range (P1 {m_rep['rel_motion_pct']:.2f} %); projected: P1 {mp['rel_motion_pct']:.2f} %; "
                f"weights in [0, 1]: {target.range_report(C01).inside_pct:.2f} % in range, P1 "
                f"{m01['rel_motion_pct']:.2f} %")
        C = np.concatenate(C_all)
        rep = target.range_report(C)
        rep0 = target.range_report(np.concatenate(Cr_all))
        inside += int(target.table.in_range(C).sum())
        total += C.size
        below = float((C < target.table.lo).mean() * 100)
        above = float((C > target.table.hi).mean() * 100)
        row.update({"in_range_pct": rep.inside_pct, "frames_in_range_pct": rep.frames_inside_pct,
                    "below_pct": below, "above_pct": above,
                    "in_range_pct_as_first_solved": rep0.inside_pct,
                    "frames_in_range_pct_as_first_solved": rep0.frames_inside_pct,
                    "worst_control_as_first_solved": rep0.worst,
                    "worst_control_outside_pct_as_first_solved": rep0.worst_outside_pct,
                    "max_excess_as_first_solved": rep0.max_excess,
                    "in_range_pct_w01": target.range_report(np.concatenate(C01_all)).inside_pct,
                    "in_range_pct_projected": target.range_report(np.concatenate(Cp_all)).inside_pct})
        res["targets"][tgt.name] = row
        log(f"controls -> {tgt.name}: as written {rep.line()}; as first solved {rep0.line()}")
    res["max_rel_diff_vs_mesh"] = worst
    res["in_range_pct"] = 100.0 * inside / total
    return res


# ------------------------------------------------------------------------------------------ skeleton
def skeleton(data: Path, out: Path, log) -> dict:
    take = read_c3d(data / "facial-mocap" / "Cheeks.c3d")
    sel = select_keys(take, SKELETON_KEYS, "pivoted-qr")
    geo = sel.geometry
    names = [f"key{f:05d}" for f in sel.frames]
    sk = Rig(Mesh(sel.neutral, name="markers"), names, geo.points[sel.frames] - sel.neutral, take.unit or "mm",
             None, None, "Cheeks keys")
    bvh_path = data / "headmotion" / "beat_2_scott_0_1_1.bvh"
    bvh = read_bvh(bvh_path)
    from faceretarget.io import bvh_world_positions

    world = bvh_world_positions(bvh)
    X = (world[1:] - world[0]).reshape(len(world) - 1, -1)
    frames = sorted(int(f) + 1 for f in select_keyshapes(X, SKELETON_KEYS, "pivoted-qr"))
    mapping = {"neutral": 0, **{n: f for n, f in zip(names, frames, strict=True)}}
    (out / "skeleton_frames.json").write_text(json.dumps(mapping, indent=1) + "\n", encoding="utf-8")
    target = read_target(bvh_path, frames=out / "skeleton_frames.json")
    t0 = time.perf_counter()
    job = retarget_take(take, sk, target, source_labels=list(take.labels), solver="nnls")
    W = target_weights(job)
    dt = time.perf_counter() - t0
    signed = target_weights(retarget_take(take, sk, target, source_labels=list(take.labels)))
    P = target.world_positions(W)
    L0 = target.rest_bone_lengths()
    ok = L0 > 1e-9
    L = bone_lengths(P, target.parents)
    dev = float(np.abs(L - L0).max())
    Pv = target.vertex_blend(W)
    Lv = bone_lengths(Pv, target.parents)[:, ok]
    ratio = Lv / L0[ok]
    shrink = 100.0 * np.maximum(0.0, 1.0 - ratio)
    stretch = 100.0 * np.maximum(0.0, ratio - 1.0)
    K = len(names)
    pairs = np.array([[0.5 if i in (a, b) else 0.0 for i in range(K)] for a in range(K) for b in range(a + 1, K)])
    mid = 100.0 * np.maximum(0.0, 1.0 - bone_lengths(target.vertex_blend(pairs), target.parents)[:, ok] / L0[ok])
    mid_rot = np.abs(bone_lengths(target.world_positions(pairs), target.parents) - L0).max()
    Ls = bone_lengths(target.vertex_blend(signed), target.parents)[:, ok]
    change_signed = 100.0 * np.abs(Ls / L0[ok] - 1.0)
    Ls_rot = bone_lengths(target.world_positions(signed), target.parents)
    write_result(out / "skeleton.bvh", job)
    write_result(out / "skeleton.glb", job)
    back = read_bvh(out / "skeleton.bvh")
    Lf = bone_lengths(bvh_world_positions(back), target.parents)
    dev_file = float(np.abs(Lf - L0).max())
    pose_err = float(np.abs(bvh_world_positions(back) - P).max())
    res = {"source": "facial-mocap/Cheeks.c3d", "frames": int(take.n_frames), "keys": SKELETON_KEYS,
           "bvh": "headmotion/beat_2_scott_0_1_1.bvh", "key_frames": frames, "joints": len(bvh.joints),
           "bones": int(ok.sum()), "unit": "cm", "weights_min": float(W.min()), "weights_max": float(W.max()),
           "bone_length_max_dev": dev, "bone_length_max_rel_dev": float((np.abs(L - L0)[:, ok] / L0[ok]).max()),
           "bone_length_max_dev_bvh_file": dev_file, "bvh_file_max_joint_err_cm": pose_err,
           "vertex_blend_shrink_pct": float(shrink.mean()), "vertex_blend_shrink_max_pct": float(shrink.max()),
           "vertex_blend_bone_frames_shrunk_over_1pct": float((shrink > 1).mean() * 100),
           "vertex_blend_stretch_pct": float(stretch.mean()), "vertex_blend_stretch_max_pct": float(stretch.max()),
           "vertex_blend_length_error_pct": float(np.abs(ratio - 1).mean() * 100),
           "midpoint_pairs": int(len(pairs)), "midpoint_vertex_blend_shrink_pct": float(mid.mean()),
           "midpoint_vertex_blend_shrink_max_pct": float(mid.max()), "midpoint_rotation_blend_bone_max_dev": float(mid_rot),
           "vertex_blend_bone_length_max_dev": float(np.abs(bone_lengths(Pv, target.parents) - L0).max()),
           "solver": "nnls (non-negative, weights in [0, 1.5]: the thesis)", "weight_sum_max": float(W.sum(axis=1).max()),
           "signed_bone_length_max_dev": float(np.abs(Ls_rot - L0).max()),
           "signed_vertex_blend_length_change_pct": float(change_signed.mean()),
           "signed_vertex_blend_length_change_max_pct": float(change_signed.max()),
           "seconds": dt, "glb_validator": _validate(out / "skeleton.glb")}
    log(f"skeleton: {take.n_frames} frames onto {len(bvh.joints)} joints; rotation blend bone lengths kept to "
        f"{dev:.2e} cm (from the written BVH {dev_file:.2e} cm); joint-position blend of the same weights: bones "
        f"shorter by {shrink.mean():.2f} % on average ({shrink.max():.1f} % at most), longer by {stretch.mean():.2f} %; "
        f"half-way between two keys: shorter by {mid.mean():.2f} % on average ({mid.max():.1f} % at most)")
    return res


def _validate(glb: Path) -> dict | str:
    node = shutil.which("node")
    vdir = Path(os.environ.get("GLTF_VALIDATOR_DIR", REPO / ".tools" / "node_modules" / "gltf-validator"))
    if node is None or not (vdir / "package.json").is_file():
        return "skipped: node or gltf-validator missing (make tools)"
    r = subprocess.run([node, str(REPO / "tests" / "tools" / "validate_gltf.mjs"), str(glb), str(vdir)],
                       capture_output=True, text=True, timeout=300)
    try:
        i = json.loads(r.stdout)["issues"]
    except (ValueError, KeyError):
        return f"failed: {r.stderr.strip()[:200]}"
    return {"errors": i["numErrors"], "warnings": i["numWarnings"], "infos": i["numInfos"]}


# ------------------------------------------------------------------------------------------ svg
def _chromium() -> str | None:
    c = os.environ.get("CHROMIUM") or shutil.which("chromium") or "/usr/bin/chromium"
    return c if Path(c).is_file() else None


def _screenshot(chromium: str, svg: Path, png: Path, size: tuple[int, int], ms: int) -> bool:
    png.unlink(missing_ok=True)
    cmd = [chromium, "--headless", "--no-sandbox", "--disable-gpu", "--hide-scrollbars",
           f"--window-size={size[0]},{size[1]}", f"--virtual-time-budget={ms}", f"--screenshot={png}",
           svg.resolve().as_uri()]
    subprocess.run(cmd, capture_output=True, timeout=120)
    return png.is_file()


def _ink(img: np.ndarray) -> np.ndarray:
    """Pixels that are part of the drawing's dark outlines and features (not skin or background)."""
    a = img[..., :3].astype(np.float64)
    return a.mean(axis=2) < 140


def svg(data: Path, out: Path, log) -> dict:
    from PIL import Image

    ark = read_rig(data / "arkit-face")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        take = read_livelinkface(data / "livelinkface" / "S07-001.csv").slice(SVG_FRAMES.start, SVG_FRAMES.stop)
    keys_dir = out / "face_keys"
    write_drawn_face(keys_dir)
    target = read_target(keys_dir)
    sk = ark.subset([n for n in target.names if n in ark])
    job = retarget_take(take, sk, target, source_rig=ark)
    W = target_weights(job)
    P = target.params(W)
    write_result(out / "face.svg", job)
    write_result(out / "face.png", job)
    mp4 = None
    try:
        write_result(out / "face.mp4", job)
        mp4 = str(out / "face.mp4")
    except Exception as e:  # noqa: BLE001 -- PyAV is optional (the preview extra)
        log(f"svg: no MP4 preview ({e})")
    frames_dir = out / "face_frames"
    write_result(frames_dir, job)
    times, back, _ = read_svg_animation(out / "face.svg")
    rt = float(np.abs(back - P).max())
    res = {"take": "livelinkface/S07-001.csv", "frames_used": [SVG_FRAMES.start, SVG_FRAMES.stop - 1],
           "keys": len(target.names), "points": target.neutral.n_points, "frames": int(len(back)),
           "svg_bytes": (out / "face.svg").stat().st_size, "roundtrip_max_diff": rt,
           "duration_s": float(times[-1]), "mp4": mp4}
    chrome = _chromium()
    renders = False
    if chrome is None:
        res["chromium"] = "skipped: Chromium not found (make browser, or set CHROMIUM)"
    else:
        shot = out / "face_chromium.png"
        shot0 = out / "face_chromium_frame0.png"
        ok_anim = _screenshot(chrome, out / "face.svg", shot, (400, 480), 4000)
        ok0 = _screenshot(chrome, frames_dir / "frame_00000.svg", shot0, (400, 480), 100)
        if ok0:
            got = np.asarray(Image.open(shot0).convert("RGB"))
            ours = render_drawing(read_svg_drawing(frames_dir / "frame_00000.svg"), P[0], 400)
            h = min(got.shape[0], ours.shape[0])
            a, b = _ink(got[:h]), _ink(ours[:h])
            iou = float((a & b).sum() / max((a | b).sum(), 1))
            res["chromium_iou"] = iou
            res["chromium_ink_pixels"] = int(a.sum())
            renders = bool(ok_anim and a.sum() > 500 and iou > 0.5)
        res["chromium_screenshot"] = str(shot)
    res["renders"] = renders
    log(f"svg: {len(back)} frames of {target.neutral.n_points} points written (read back to {rt:.1e}); Chromium "
        f"renders it: {renders}")
    return res


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--json", action="store_true", help="print a JSON summary as the last line")
    ap.add_argument("--data", default=str(REPO.parent / "shared" / "data"))
    ap.add_argument("--out", default=str(REPO / "out" / "targets"))
    ap.add_argument("--only", default="controls,skeleton,svg", help="comma-separated parts to run "
                    "(default all: controls,skeleton,svg)")
    a = ap.parse_args(argv)
    data, out = Path(a.data), Path(a.out)
    out.mkdir(parents=True, exist_ok=True)

    def log(msg: str) -> None:
        print(msg, flush=True)

    t0 = time.perf_counter()
    parts = {"controls": controls, "skeleton": skeleton, "svg": svg}
    only = [p.strip() for p in a.only.split(",") if p.strip()]
    unknown = [p for p in only if p not in parts]
    if unknown:
        ap.error(f"--only: unknown part(s) {', '.join(unknown)} (use {', '.join(parts)})")
    res = {p: parts[p](data, out, log) for p in only}
    res["seconds"] = time.perf_counter() - t0
    if a.json:
        print(json.dumps(res))
    return 0


if __name__ == "__main__":
    sys.exit(main())
