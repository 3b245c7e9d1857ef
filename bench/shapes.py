"""Generated expression shapes (issue 25): hide a character's own face shapes, generate the ARKit set from a
template by deformation transfer, and measure what a user sees.

Characters: every character file (``.glb .gltf .vrm .fbx .blend .usd*``) and rig folder under
``--characters`` (default ``../shared/data``: ``ict-face``, ``arkit-face``, ``characters/rocketbox``,
``characters/valid``; the robot has no human face) plus the demo characters ``ada`` and ``bo``.  Per
character, after hiding every face shape it has (its landmarks found again on the neutral's render; a rig's
own landmark file kept; a neutral character, with none, is measured as it is):

* ``shapes``: how many were generated, ``seconds`` the whole generation (landmarks, registration, solve);
* ``blink_gap_pct`` (lid gap left at ``eyeBlink*`` = 1 over the open gap, worst lid landmark pair, %),
  ``lid_inside_eye`` (face vertices the blinks move into an eyeball), ``lip_gap_pct`` (inner-lip gap at
  ``jawOpen + mouthClose`` over the gap at ``jawOpen``), ``lips_in_teeth`` (face vertices near the mouth
  that ``jawOpen + mouthClose`` puts inside the teeth's convex hull), ``teeth_showing_px`` (pixels of teeth and
  tongue seen outside the mouth opening on a 400-pixel front view of the mouth at ``jawOpen``, ``mouthFunnel``,
  ``mouthLowerDown*``: teeth through the lips or chin), ``inverted_triangles`` (over every shape and
  ``jawOpen`` + each mouth shape), ``mirror_err_pct`` (left/right pairs, on symmetric faces), and the same
  numbers of the artist's shapes where they are ARKit (``artist``);
* ``mouth_corr``: the main job (:func:`faceretarget.pipelines.animate`) on both shared videos with the
  generated shapes, the worse video; ``residual_ratio``: the landmark-fit residual (RMS, per frame, mean)
  with the generated shapes over that with the artist's own shapes, the worse video (where it has shapes);
* ``direction_cos``: the median over the large shapes of the cosine between the generated and the
  artist's 68-landmark motion (where the artist's shapes are ARKit).

``ict-face`` is generated from ``arkit-face`` (from itself it would be trivial), every other from
``ict-face``; the ``template`` field says which.

Usage::

    python bench/shapes.py [--json] [--characters DIR] [--video V ...] [--out DIR]

The last line with ``--json``: ``{"characters": {NAME: {"ok", "error", "shapes", "mouth_corr",
"residual_ratio", "blink_gap_pct", "lip_gap_pct", "inverted_triangles", "mirror_err_pct", "seconds", ...}}}``
(null where it does not apply).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
import traceback
import warnings
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _character_checks import hide_shapes  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
DATA = REPO.parent / "shared" / "data"
EXTS = (".glb", ".gltf", ".vrm", ".fbx", ".blend", ".usd", ".usda", ".usdc", ".usdz")
SKIP_DIRS = ("robot", "conformance", "video", "speech", "livelinkface", "facial-mocap", "headmotion",
             "emotion-video")


def find_characters(root: Path) -> dict:
    """``{name: source}``: rig folders (a folder with OBJ files and landmarks68.txt) and character files under
    ``root``, skipping data folders that hold no human face."""
    out = {}
    if root.is_file() or (root / "landmarks68.txt").is_file():
        return {root.stem if root.is_file() else root.name: root}
    for p in sorted(root.rglob("*")):
        if any(part in SKIP_DIRS for part in p.relative_to(root).parts):
            continue
        if p.is_dir() and (p / "landmarks68.txt").is_file() and any(p.glob("*.obj")):
            out[p.name] = p
        elif p.is_file() and p.suffix.lower() in EXTS:
            out[p.stem] = p
    return out


def residual(ch, shapes: str, cap) -> float:
    """Mean per-frame RMS landmark-fit residual of the take on the character's shapes, over the character's
    outer-eye-corner distance."""
    from faceretarget.characters import drive_rig
    from faceretarget.pipelines import face_take
    from faceretarget.retarget import LandmarkSolver, neutral_face

    rig = drive_rig(ch, shapes).rig
    ft = face_take(cap)
    prior = None if ft.weights is None else rig.map_weights(ft.names, ft.weights, warn=False)
    sol = LandmarkSolver().fit(rig, neutral_face(ft.points))
    res = sol.transform(ft.points, prior, ft.times).residual
    lm = ch.landmark_positions()
    return float(res.mean() / np.linalg.norm(lm[36] - lm[45]))


def direction_cos(ref, gen, names) -> float | None:
    from faceretarget.transfer import shape_delta

    cs, big = [], []
    for n in names:
        a, b = shape_delta(ref, n), shape_delta(gen, n)
        if a is None or b is None:
            continue
        la, lb = ref.landmarks.positions(a), gen.landmarks.positions(b)
        na, nb = np.linalg.norm(la), np.linalg.norm(lb)
        if na > 0 and nb > 0:
            cs.append(float((la * lb).sum() / na / nb))
            big.append(na)
    if not cs:
        return None
    big = np.asarray(big)
    sel = big >= np.percentile(big, 50)
    return round(float(np.median(np.asarray(cs)[sel])), 4)


def one(name: str, src, caps: dict, work: Path, log) -> dict:
    from faceretarget.characters import generate_shapes, load_character
    from faceretarget.io import character_from_rig, read_character
    from faceretarget.names import ARKIT_NAMES, normalize_name
    from faceretarget.pipelines import animate
    from faceretarget.transfer import shape_metrics

    keys = ("ok", "error", "template", "shapes", "mouth_corr", "residual_ratio", "blink_gap_pct", "lid_inside_eye",
            "lip_gap_pct", "lips_in_teeth", "teeth_showing_px", "inverted_triangles", "mirror_err_pct", "seconds",
            "direction_cos", "artist")
    res = {k: None for k in keys}
    res["ok"] = False
    try:
        os.environ["FACERETARGET_CACHE"] = str(work / f"cache-{name}")
        if isinstance(src, Path):
            ref = load_character(src, need_shapes=False)   # a neutral character: nothing to hide or compare with
            hidden = hide_shapes(read_character(src))
            if not src.is_dir():
                hidden.path = None                    # its landmarks are found again, on the neutral
            else:
                hidden.landmarks = ref.landmarks      # a rig folder's own landmark file
        else:
            ref = load_character(character_from_rig(src))
            hidden = hide_shapes(character_from_rig(src))
            hidden.landmarks = ref.landmarks
        template = "arkit-face" if name == "ict-face" else "ict-face"
        if template == "arkit-face":
            template = DATA / "arkit-face"
        res["template"] = Path(str(template)).name
        t0 = time.perf_counter()
        gen = generate_shapes(hidden, template=template)
        res["seconds"] = round(time.perf_counter() - t0, 2)
        ch = gen.apply()
        res["shapes"] = len(gen.shape_names)
        m = shape_metrics(ch)
        res.update({k: (round(v, 3) if isinstance(v, float) else v) for k, v in m.items()})
        ref_arkit = sorted({normalize_name(n) for mi in ref.face_meshes() for n in ref.meshes[mi].shape_names}
                           & set(ARKIT_NAMES))
        if len(ref_arkit) >= 10:
            res["artist"] = {k: (round(v, 3) if isinstance(v, float) else v) for k, v in shape_metrics(ref).items()}
            res["direction_cos"] = direction_cos(ref, ch, gen.shape_names)
        corr, ratio = [], []
        for cap in caps.values():
            r = animate(cap, ch, shapes="arkit", log=lambda *_: None)
            corr.append(r.mouth_corr)
            if ref.face_meshes():
                ratio.append(residual(ch, "arkit", r.take) / residual(ref, "auto", r.take))
        res["mouth_corr"] = round(float(min(corr)), 4)
        res["mouth_corr_each"] = [round(float(c), 4) for c in corr]
        if ratio:
            res["residual_ratio"] = round(float(max(ratio)), 3)
        res["timings"] = {k: round(v, 2) for k, v in gen.timings.items()}
        res["notes"] = gen.notes
        res["ok"] = True
    except Exception as e:  # the bench reports every character, whatever goes wrong
        res["error"] = " ".join(str(e).split())[:300]
        res["error_type"] = type(e).__name__
        res["traceback"] = traceback.format_exc(limit=6)[-1200:]
        log(res["traceback"])
    return res


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--characters", type=Path, default=DATA)
    ap.add_argument("--video", type=Path, nargs="*", default=None)
    ap.add_argument("--no-demo", action="store_true", help="without the demo characters")
    ap.add_argument("--out", type=Path, default=None, help="keep the caches here")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)

    def log(*a):
        print(*a, file=sys.stderr if args.json else sys.stdout, flush=True)

    from faceretarget.pipelines import capture_take

    videos = args.video or sorted((DATA / "video").glob("*.mp4"))
    work = args.out or Path(tempfile.mkdtemp(prefix="faceretarget-shapes-"))
    work.mkdir(parents=True, exist_ok=True)
    todo: dict = find_characters(args.characters) if args.characters.exists() else {}
    if not args.no_demo:
        from faceretarget.datasets import make_demo_character

        for n in ("ada", "bo"):
            todo[f"demo-{n}"] = make_demo_character(n)
    caps = {}
    for v in videos:
        t0 = time.perf_counter()
        caps[v.stem] = capture_take(v, neutral_percentile=5.0)
        log(f"captured {v.name} in {time.perf_counter() - t0:.1f} s")
    out = {}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for name, src in todo.items():
            log(f"--- {name}")
            out[name] = r = one(name, src, caps, work, log)
            log(json.dumps({k: r[k] for k in ("ok", "error", "template", "shapes", "mouth_corr", "residual_ratio",
                                              "blink_gap_pct", "lid_inside_eye", "lip_gap_pct", "lips_in_teeth",
                                              "teeth_showing_px", "inverted_triangles",
                                              "mirror_err_pct", "direction_cos", "seconds")}))
    if args.json:
        print(json.dumps({"characters": out}, default=lambda o: o.tolist() if hasattr(o, "tolist") else str(o)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
