"""P11 for characters driven by their own shapes (issue 32): the main job against ground truth when the
character's face shapes are not ARKit-named (a VALID avatar's ``RsmileClose_h``, ``LeyeClose_h``, ...).

Each character under ``--characters`` whose shapes carry fewer than 10 ARKit names (others are P11's,
``bench/fidelity.py``) gets the ARKit set generated (:func:`~faceretarget.characters.generate_shapes`, deformation
transfer from the packaged ICT-FaceKit): the truth is a real ARKit take (``--takes``, the most active ``--seconds``)
played on those generated shapes, rendered as ``bench/fidelity.py`` renders it (a webcam 0.6 m away, set-ups
``webcam`` and ``turned``, real head motion), and captured once.  The main job then drives the character's
**own** shapes from that video (:func:`~faceretarget.pipelines.animate` on the file as it is, no generated shape in
it), and the error is geometric: per region (mouth, lids, brows, cheeks: regions of the generated shapes'
motion), the face mesh's motion ``W_own @ D_own`` against the truth's ``W_arkit @ D_generated``, as % of the true
motion.  Three ways are scored on the same frames:

* ``ours``: the main job as shipped (the tracker's scores reach the own shapes through
  :class:`~faceretarget.characters.ScorePrior`: the mouth's scores of a frame fitted together, the others by
  :func:`~faceretarget.characters.score_map`'s rows);
* ``names_only``: the main job with the scores taken by name only (what it did before: none reach such a
  character, every shape is solved from the 68 points alone);
* ``scores_mapped``: no landmarks, the tracker's scores through the same map
  (:class:`~faceretarget.characters.ScorePrior`: the peer a user could build).

Usage::

    python bench/own_shapes.py [--json] [--characters DIR] [--takes DIR] [--seconds S] [--setups webcam,turned]

The last line with ``--json``: ``{"characters": {NAME: {"runs": n, "ours": {region: median %}, "names_only":
{...}, "scores_mapped": {...}}}}``.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import fidelity as P11  # noqa: E402

WAYS = ("ours", "names_only", "scores_mapped")


def own_deltas(character, drive) -> np.ndarray:
    """``(K, V, 3)``: the driving channels' motion of the landmark mesh (the drive rig's shape order)."""
    lm = character.landmarks
    mesh = character.meshes[lm.mesh]
    D = np.zeros((len(drive.choice.drive), mesh.mesh.n_vertices, 3))
    for r, c in enumerate(drive.choice.drive):
        for mi, k, w in drive.channels[c].weighted():
            if mi == lm.mesh:
                D[r] += w * mesh.deltas[k]
    return D


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--characters", type=Path, default=P11.DATA / "characters")
    ap.add_argument("--takes", type=Path, default=P11.DATA / "livelinkface")
    ap.add_argument("--head", type=Path, default=P11.DATA / "headmotion" / "zeggs_067_Speech_2_x_1_0.bvh")
    ap.add_argument("--seconds", type=float, default=12.0)
    ap.add_argument("--setups", default="webcam,turned")
    ap.add_argument("--json", action="store_true")
    a = ap.parse_args(argv)
    warnings.simplefilter("ignore")
    import faceretarget.characters._score_map as score_map_module
    from faceretarget.characters import ScorePrior, drive_rig, load_character
    from faceretarget.errors import FaceRetargetError
    from faceretarget.io import read_livelinkface
    from faceretarget.metrics._fidelity import region_errors
    from faceretarget.pipelines import animate, capture_take

    work = Path(tempfile.mkdtemp(prefix="own-shapes-"))
    result = {}
    for path in P11.find_characters(a.characters):
        t0 = time.perf_counter()
        try:
            own = load_character(path)
        except FaceRetargetError as e:
            print(f"{path.name}: left out ({str(e)[:100]})", flush=True)
            continue
        if len(P11.Target._arkit(own)) >= 10:
            print(f"{path.name}: ARKit-named shapes, P11's (bench/fidelity.py)", flush=True)
            continue
        truth = P11.Target(path, generate=True)
        drive = drive_rig(own, "auto")
        D_own = own_deltas(own, drive)
        if D_own.shape[1] != truth.deltas.shape[1]:
            print(f"{path.name}: left out (its generated shapes are on another mesh)", flush=True)
            continue
        print(f"{path.name}: {D_own.shape[0]} own shapes, truth on {len(truth.names)} generated ARKit shapes "
              f"({time.perf_counter() - t0:.1f} s)", flush=True)
        errs = {w: [] for w in WAYS}
        for take_path in P11.find_takes(a.takes):
            perf = read_livelinkface(take_path)
            s0, s1 = P11.active_window(perf.weights, perf.times, a.seconds)
            t = np.arange(s0, s1, 1.0 / P11.FPS)
            W = np.clip(P11.resample(perf.weights, perf.times, t), 0.0, 1.0)
            head = P11.head_truth(a.head, len(t))
            Wt = truth.weights(W, perf.names)
            for setup in [s for s in a.setups.split(",") if s]:
                video = work / f"{path.stem}-{take_path.stem}-{setup}.mp4"
                P11.render_video(truth, Wt, head, setup, video)
                cap = capture_take(video, neutral_percentile=5.0, progress=False, log=lambda *_: None)
                line = []
                for way in WAYS:
                    if way == "scores_mapped":
                        Wo = ScorePrior(drive.rig, list(cap.names))(cap.weights)
                        names = list(drive.rig.names)
                    else:
                        saved = score_map_module.MIN_NAMED
                        score_map_module.MIN_NAMED = 0 if way == "names_only" else saved
                        try:
                            res = animate(cap, own, log=lambda *_: None)
                        finally:
                            score_map_module.MIN_NAMED = saved
                        Wo, names = res.weights, list(res.names)
                    n = min(len(Wt), len(Wo))
                    Wo = Wo[:n][:, [names.index(x) for x in drive.rig.names]]
                    e = region_errors(Wt[:n], Wo, truth.deltas, truth.regions, pred_deltas=D_own)
                    errs[way].append(e)
                    line.append(f"{way} " + " ".join(f"{r} {v:.0f}" for r, v in e.items()))
                print(f"  {take_path.stem} {setup}: " + "; ".join(line), flush=True)
        result[path.stem] = {"runs": len(errs["ours"])}
        for way in WAYS:
            result[path.stem][way] = {r: float(np.median([e[r] for e in errs[way]])) for r in P11.REGIONS}
        print(f"{path.stem} ({len(errs['ours'])} runs), median error % of the true motion:", flush=True)
        for way in WAYS:
            print(f"  {way:14s} " + "  ".join(f"{r} {result[path.stem][way][r]:5.1f}" for r in P11.REGIONS),
                  flush=True)
    if a.json:
        print(json.dumps({"characters": result}))
    return 0 if result else 2


if __name__ == "__main__":
    sys.exit(main())
