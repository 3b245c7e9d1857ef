"""P11 (issue 32): the main job against ground truth, by a round trip, beside the peer most users would pick.

Truth: real ARKit takes (Live Link Face ``.csv`` under ``--takes``, default ``../shared/data/livelinkface``; the
most active ``--seconds`` of each, resampled to 30 fps) played on every character with ARKit shapes under
``--characters`` (default ``../shared/data``: rig folders and character files with a human face; see below for
those without ARKit-named shapes), with real head motion from speech capture (``--head``, default the ZEGGS take's BVH head, relative to
its mean pose: the shared takes carry no head rotation).  Each is rendered to an mp4 with the project's preview
renderer (the character's textures sampled per vertex, or its material colours) as a webcam sees a face
``--distance`` metres away (0.6 by default: the perspective of a pinhole camera, the picture cropped to the face;
0: an orthographic camera, as P11 was before), in two set-ups:

* ``webcam``: the camera in front, the key light above and to the left;
* ``turned``: the camera turned 15 degrees about the head's vertical axis and the key light from the right.

A character without ARKit-named shapes (the VALID avatars) gets them generated first
(:func:`~faceretarget.characters.generate_shapes`, as ``faceretarget character shapes`` does; ``--no-generate`` leaves
it out): P11 counts generated shapes, and these avatars have textured eyes, where a tracker can see a blink.

The video is captured once (:func:`~faceretarget.pipelines.capture_take`, MediaPipe) and given to

* **ours**: the main job (:func:`~faceretarget.pipelines.animate`) onto the **same** character and onto
  **another** one (the next character in the list); on another character the truth is the same ARKit weights
  on its own ARKit shapes (both characters' shapes mean the same expressions by name);
* **the peer**: MediaPipe's own ARKit scores (the capture's, after its gap filling, the take's neutral removed
  and smoothing: the same calibration ours gets) copied onto the character's shapes by name;
* **the raw peer** (``peer_raw``): the same scores as the tracker gives them, copied straight, as web avatar
  players do (issue 32's peer; no face: 0).

Scores (:mod:`faceretarget.metrics._fidelity`), ours and the peer's on the same frames, and ours / peer:
per-region error as % of the true motion (``mouth``, ``lids``, ``brows``, ``cheeks``; regions from the
shapes' own displacement), per-shape correlation and mean absolute error (:data:`KEY_SHAPES`), blink F1
(closed at >= 0.5), smile direction (share of smile frames whose lip corners move the right way) and the
median head-rotation error in degrees.

Usage::

    python bench/fidelity.py [--json] [--characters DIR] [--takes DIR] [--head FILE] [--seconds S]
                             [--setups webcam,turned] [--distance M] [--solver default|all-gains|legacy] [--no-generate]
                             [--figure PNG [--figure-character NAME]] [--out DIR] [--live]

``--live`` also plays each video through the live mode (``faceretarget live``: each frame as it comes, causal
filters, a 1 s calibration) onto the same targets, scored on the frames it solved; its peer is MediaPipe's raw
scores on those frames (what an avatar app copies live).

The last line with ``--json``: ``{"runs": [{character, take, setup, target, ours: {...}, peer: {...}}],
"summary": {...}, "live": {"runs": [...], "summary": {...}}}`` (``live`` with ``--live``).
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
import traceback
import warnings
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

REPO = Path(__file__).resolve().parents[1]
DATA = REPO.parent / "shared" / "data"
FPS = 30.0
EXTS = (".glb", ".gltf", ".vrm", ".fbx", ".blend", ".usd", ".usda", ".usdc", ".usdz")
SKIP_DIRS = ("conformance", "video", "speech", "livelinkface", "facial-mocap", "headmotion", "emotion-video")
#: The two set-ups: the camera's yaw (degrees, about the head's vertical axis) and the key light's direction
#: in view space (x right, y up, z toward the viewer).
SETUPS = {"webcam": (0.0, (-0.35, 0.45, 0.82)), "turned": (15.0, (0.6, 0.3, 0.75))}
REGIONS = ("mouth", "lids", "brows", "cheeks")
#: The camera's distance from the face, metres: a webcam's on a desk.  The picture is the crop of its frame
#: around the face (the face's perspective is a webcam's whatever the crop: it depends only on the distance).
DISTANCE = 0.6


# --------------------------------------------------------------------------------------------- inputs
def find_characters(root: Path) -> list[Path]:
    """Rig folders (at least 10 OBJs: a neutral and its shapes) and character files under ``root``."""
    def rig_folder(p: Path) -> bool:                 # a neutral and its shapes as OBJs (any names)
        return p.is_dir() and sum(f.suffix.lower() == ".obj" for f in p.iterdir()) >= 10

    if root.is_file() or rig_folder(root):
        return [root]
    out = []
    for p in sorted(root.rglob("*")):
        if any(part in SKIP_DIRS for part in p.relative_to(root).parts):
            continue
        if rig_folder(p):
            out.append(p)
        elif p.is_file() and p.suffix.lower() in EXTS:
            out.append(p)
    return out


def find_takes(root: Path) -> list[Path]:
    return [root] if root.is_file() else sorted(root.glob("*.csv"))


def active_window(weights: np.ndarray, times: np.ndarray, seconds: float) -> tuple[float, float]:
    """The ``seconds`` of the take where its weights vary most (summed variance), or the whole take."""
    if times[-1] - times[0] <= seconds:
        return float(times[0]), float(times[-1])
    starts = np.arange(times[0], times[-1] - seconds, 1.0)
    score = [weights[(times >= s) & (times <= s + seconds)].var(axis=0).sum() for s in starts]
    s = float(starts[int(np.argmax(score))])
    return s, s + seconds


def resample(weights: np.ndarray, times: np.ndarray, t: np.ndarray) -> np.ndarray:
    return np.stack([np.interp(t, times, weights[:, k]) for k in range(weights.shape[1])], axis=1)


def head_truth(path: Path, n: int) -> Rotation:
    """``n`` frames at 30 fps of real head rotation (relative to its mean pose) from a head-motion file."""
    from faceretarget.io import read_head_motion

    perf = read_head_motion(path)
    q = perf.head.quaternions
    ok = np.isfinite(q).all(axis=1)
    t = perf.times[ok]
    r = Rotation.from_quat(q[ok])
    tt = np.minimum(np.arange(n) / FPS, t[-1])
    from scipy.spatial.transform import Slerp

    rr = Slerp(t, r)(tt)
    return rr.mean().inv() * rr


# ------------------------------------------------------------------------------------------ character
class Target:
    """A character loaded once: its drive rig, its ARKit channels, their displacement of the landmark mesh,
    the regions, the lip corners' displacement."""

    def __init__(self, path: Path, generate: bool = False):
        from faceretarget.characters import drive_rig, load_character
        from faceretarget.errors import MissingShapeError
        from faceretarget.metrics._fidelity import face_regions

        self.path = path
        self.name = path.stem if path.is_file() else path.name
        self.generated = False
        try:
            ch = load_character(path)
        except MissingShapeError:                                   # a neutral face: shapes to generate
            if not generate:
                raise
            ch = load_character(path, need_shapes=False)
        if len(self._arkit(ch)) < 10 and generate:          # its ARKit shapes made by deformation transfer
            from faceretarget.characters import generate_shapes

            ch = generate_shapes(ch, replace=False).apply()
            self.generated, self.name = True, self.name + "+arkit"
        self.character = ch
        self.drive = drive_rig(ch, "auto")
        chans = self.drive.channels
        self.arkit = self._arkit(ch)                                 # ARKit name -> channel index
        if len(self.arkit) < 10:
            raise ValueError(f"{len(self.arkit)} ARKit-named shapes (needs 10; --generate makes them)")
        self.names = list(self.arkit)
        lm = ch.landmarks
        mesh = ch.meshes[lm.mesh]
        D = np.zeros((len(self.names), mesh.mesh.n_vertices, 3))
        for r, n in enumerate(self.names):
            for mi, k, w in chans[self.arkit[n]].weighted():
                if mi == lm.mesh:
                    D[r] += w * mesh.deltas[k]
        self.deltas = D
        self.regions = face_regions(D, self.names)
        corners = np.array([48, 54])
        tri, bary = lm.triangles[corners], lm.bary[corners]
        self.corner_deltas = np.einsum("cj,kcjd->kcd", bary, D[:, tri])    # (K, 2, 3)
        self.up = np.asarray(ch.up if ch.up is not None else [0.0, 1.0, 0.0], np.float64)

    @staticmethod
    def _arkit(ch) -> dict[str, int]:
        from faceretarget.character import channels
        from faceretarget.names import ARKIT_NAMES, normalize_name

        arkit, out = set(ARKIT_NAMES), {}
        for c, chan in enumerate(channels(ch)):
            n = normalize_name(chan.name)
            if n in arkit and n not in out:
                out[n] = c
        return out

    def weights(self, W: np.ndarray, names: list[str]) -> np.ndarray:
        """``(T, K)`` weights in :attr:`names` order from curves named ``names`` (any spelling; 0 where absent)."""
        from faceretarget.names import normalize_name

        idx = {normalize_name(n): i for i, n in enumerate(names)}
        out = np.zeros((len(W), len(self.names)))
        for r, n in enumerate(self.names):
            if n in idx:
                out[:, r] = W[:, idx[n]]
        return out


def look(target: Target, size: int, yaw: float | str = "front", light=None):
    """The character as the preview renderer shows it, carrying every ARKit shape in ``target.names`` order:
    the look rig, its shapes as a ``(K, 3 V)`` matrix, and a renderer (a context manager) from ``yaw`` with
    the key light ``light`` (the renderer's own by default)."""
    from faceretarget.characters import look_rig
    from faceretarget.render import MeshRenderer

    rig, colors, pivot = look_rig(target.drive, channels=[target.arkit[n] for n in target.names])
    r = MeshRenderer(rig.neutral, (size, size), color=colors, pivot=pivot, mm_per_unit=rig.mm_per_unit,
                     view=yaw, head_room=35.0, **({} if light is None else {"light": light}))
    return rig, rig.deltas.reshape(len(rig.names), -1), r


def figure(rows: list[tuple[str, Target, tuple, tuple[str, ...]]], out: Path, size: int = 300) -> Path:
    """Truth, ours and the peer side by side: one row per ``(what, target, (Wt, Wo, Wp), shape names)``, at the
    frame where the truth's mean of those shapes peaks (the character at rest pose, front view)."""
    from faceretarget.render import render_grid, save_png

    imgs, labels = [], []
    for what, target, (Wt, Wo, Wp), names in rows:
        cols = [target.names.index(n) for n in names if n in target.names]
        f = int(np.argmax(Wt[:, cols].mean(axis=1)))
        rig, D, r = look(target, size)
        with r:
            for who, W in (("truth", Wt), ("ours", Wo), ("peer", Wp)):
                imgs.append(r.render(rig.neutral.vertices + (W[f] @ D).reshape(-1, 3)))
                labels.append(f"{what} {who}: {W[f, cols].mean():.2f}")
    return save_png(out, render_grid(imgs, labels, cols=3))


def render_video(target: Target, W: np.ndarray, head: Rotation, setup: str, out: Path, size: int = 512,
                 distance: float = DISTANCE) -> int:
    """The take (``W`` in ``target.names`` order, 30 fps) on the character as an mp4, seen by a camera
    ``distance`` metres from the face (0: orthographic); frames written."""
    from faceretarget.io._video import write_video

    rig, D, r = look(target, size, *SETUPS[setup])
    V0 = rig.neutral.vertices
    R = head.as_matrix()
    with r:
        frames = (r.render(perspective(r, r.transform(V0 + (W[i] @ D).reshape(-1, 3), R[i]), distance))
                  for i in range(len(W)))
        write_video(out, frames, FPS)
    return len(W)


def perspective(r, V: np.ndarray, distance: float) -> np.ndarray:
    """``V`` (mesh units, head motion applied) as a pinhole camera ``distance`` metres in front of the framed
    face sees it, for the renderer's orthographic camera: each point pulled toward the view axis by
    ``d / (d - z)`` (``z`` toward the camera from the framing's centre), so that the centre plane keeps its
    size and nearer parts grow as they do in a webcam's picture (0: ``V`` unchanged)."""
    if not distance:
        return V
    cam = r.camera
    d = distance * r.units_per_metre
    v = (V - cam.center) @ cam.rotation.T
    if (v[:, 2] >= 0.5 * d).any():
        raise ValueError(f"the face reaches within half of the camera's {distance} m distance")
    v[:, :2] *= (d / (d - v[:, 2]))[:, None]
    return v @ cam.rotation + cam.center


# ---------------------------------------------------------------------------------------------- scores
def scores(target: Target, Wt: np.ndarray, Wp: np.ndarray, qt: np.ndarray, qp: np.ndarray | None) -> dict:
    from faceretarget.metrics import _fidelity as F

    head = F.head_rotation_error(qt, qp) if qp is not None else np.full(len(qt), np.nan)
    return {"regions": F.region_errors(Wt, Wp, target.deltas, target.regions),
            "shapes": F.shape_scores(Wt, Wp, target.names),
            "blink": F.blink_f1(Wt, Wp, target.names),
            "smile": F.smile_direction(Wt, Wp, target.names, target.corner_deltas, target.up),
            "head_deg": float(np.nanmedian(head)) if np.isfinite(head).any() else float("nan")}


def compare(ours: dict, peer: dict) -> dict:
    from faceretarget.metrics._fidelity import ratio

    return {"regions": {k: ratio(ours["regions"][k], peer["regions"][k]) for k in ours["regions"]},
            "head": ratio(ours["head_deg"], peer["head_deg"])}


def run_one(src: Target, dst: Target, cap, res, Wtake: np.ndarray, names: list[str], head: Rotation,
            raw=None) -> dict:
    """Ours, the peer (``cap``'s scores) and, given the video's raw track ``raw``, the raw peer against the truth
    on the same frames."""
    n = min(len(Wtake), len(res.weights), len(cap.weights))
    Wt = dst.weights(Wtake[:n], names)
    ours = dst.weights(res.weights[:n], res.names)
    capw = np.nan_to_num(cap.weights[:n])
    peer = dst.weights(capw, cap.names)
    qt = head.as_quat()[:n]
    qo = res.head.quaternions[:n] if res.head is not None else None
    qp = cap.head.quaternions[:n] if cap.head is not None else None
    o, p = scores(dst, Wt, ours, qt, qo), scores(dst, Wt, peer, qt, qp)
    out = {"frames": n, "ours": o, "peer": p, "ratio": compare(o, p), "mouth_corr": res.mouth_corr,
           "_weights": (Wt, ours, peer)}
    if raw is not None:
        pr = scores(dst, Wt, dst.weights(np.nan_to_num(raw.weights[:n]), raw.names), qt, raw.head.quaternions[:n])
        out.update(peer_raw=pr, ratio_raw=compare(o, pr))
    return out


# ------------------------------------------------------------------------------------------------ main
def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--characters", type=Path, default=DATA)
    ap.add_argument("--takes", type=Path, default=DATA / "livelinkface")
    ap.add_argument("--head", type=Path, default=DATA / "headmotion" / "zeggs_067_Speech_2_x_1_0.bvh")
    ap.add_argument("--seconds", type=float, default=12.0, help="the most active seconds of each take")
    ap.add_argument("--setups", default="webcam,turned")
    ap.add_argument("--distance", type=float, default=DISTANCE, help="the camera's distance from the face in metres "
                    f"(default {DISTANCE}: a webcam's perspective; 0: an orthographic camera, P11 before this option)")
    ap.add_argument("--max-characters", type=int, default=0, help="only the first N characters (0: all)")
    ap.add_argument("--no-generate", action="store_true", help="leave out characters without ARKit shapes instead "
                    "of generating them (faceretarget character shapes; P11 counts generated shapes)")
    ap.add_argument("--out", type=Path, default=None, help="keep the rendered videos here")
    ap.add_argument("--figure-character", default="", help="only runs of characters whose name holds this")
    ap.add_argument("--solver", choices=["default", "all-gains", "legacy"], default="default",
                    help="for comparison: all-gains, issue 32's first solver (per-take gains on every shape, "
                    "0-4); legacy, the solver before issue 32 (prior 0.1, no per-take gains)")
    ap.add_argument("--figure", type=Path, default=None, help="write truth / ours / peer at a smile and a blink "
                    "frame (the same-character run with the most blinking) as a PNG")
    ap.add_argument("--live", action="store_true", help="also play each video through the live mode (LiveSession, "
                    "frame by frame, causal filters, 1 s calibration) onto the same targets; its peer is MediaPipe's "
                    "raw scores on the same frames")
    ap.add_argument("--json", action="store_true")
    a = ap.parse_args(argv)
    warnings.simplefilter("ignore")
    from faceretarget.capture import DEFAULT_SMOOTH, track_video
    from faceretarget.io import read_livelinkface
    from faceretarget.pipelines import animate

    setups = [s for s in a.setups.split(",") if s]
    from faceretarget.pipelines import video_solver
    from faceretarget.retarget import LandmarkSolver

    def solver():
        if a.solver == "all-gains":
            return LandmarkSolver(prior=10.0, gains=True, unscored_prior=0.1)
        return LandmarkSolver() if a.solver == "legacy" else video_solver()

    targets, skipped = [], {}
    for p in find_characters(a.characters):
        try:
            t0 = time.perf_counter()
            targets.append(Target(p, generate=not a.no_generate))
            print(f"character {targets[-1].name}: {len(targets[-1].names)} ARKit shapes, regions "
                  + ", ".join(f"{k} {len(v)}" for k, v in targets[-1].regions.items())
                  + f" ({time.perf_counter() - t0:.1f} s)", flush=True)
        except Exception as e:  # noqa: BLE001 - a character without ARKit shapes is left out, said why
            skipped[p.name] = f"{type(e).__name__}: {str(e)[:120]}"
    if a.max_characters:
        targets = targets[:a.max_characters]
    for k, v in skipped.items():
        print(f"character {k}: left out ({v})", flush=True)
    if not targets:
        print("no character with ARKit shapes", file=sys.stderr)
        return 2
    work = a.out or Path(tempfile.mkdtemp(prefix="fidelity-"))
    work.mkdir(parents=True, exist_ok=True)
    runs, live_runs = [], []
    for take_path in find_takes(a.takes):
        perf = read_livelinkface(take_path)
        s0, s1 = active_window(perf.weights, perf.times, a.seconds)
        t = np.arange(s0, s1, 1.0 / FPS)
        Wtake = np.clip(resample(perf.weights, perf.times, t), 0.0, 1.0)
        head = head_truth(a.head, len(t))
        for i, src in enumerate(targets):
            for setup in setups:
                t0 = time.perf_counter()
                video = work / f"{src.name}-{take_path.stem}-{setup}.mp4"
                try:
                    render_video(src, src.weights(Wtake, perf.names), head, setup, video, distance=a.distance)
                    raw = track_video(video)              # tracked once: the raw peer's scores, the live peer's
                    cap = raw.postprocess(neutral_percentile=5.0, smooth=DEFAULT_SMOOTH)     # as capture_take does
                    dsts = [("same", src)] + ([("other", targets[(i + 1) % len(targets)])] if len(targets) > 1 else [])
                    for kind, dst in dsts:
                        res = animate(cap, dst.character, solver=solver())
                        r = run_one(src, dst, cap, res, Wtake, perf.names, head, raw=raw)
                        r.update(character=src.name, take=take_path.stem, setup=setup, target=kind,
                                 onto=dst.name, window=[round(s0, 2), round(s1, 2)],
                                 detected=float(cap.detected.mean()), seconds=round(time.perf_counter() - t0, 1))
                        runs.append(r)
                        print(line(r), flush=True)
                    if a.live:
                        for kind, dst in dsts:
                            r = run_live(src, dst, video, raw, Wtake, perf.names, head)
                            r.update(character=src.name, take=take_path.stem, setup=setup, target=kind, onto=dst.name,
                                     window=[round(s0, 2), round(s1, 2)], detected=r["detected"],
                                     seconds=round(time.perf_counter() - t0, 1))
                            live_runs.append(r)
                            print("live: " + line(r), flush=True)
                except Exception as e:  # noqa: BLE001 - one failed run is reported, the rest go on
                    runs.append({"character": src.name, "take": take_path.stem, "setup": setup,
                                 "error": f"{type(e).__name__}: {e}", "traceback": traceback.format_exc()[-2000:]})
                    print(f"{src.name} {take_path.stem} {setup}: ERROR {type(e).__name__}: {e}", flush=True)
    if a.figure:
        same = [r for r in runs if r.get("target") == "same" and a.figure_character in r["character"]]
        if same:
            smile, blink = ("mouthSmileLeft", "mouthSmileRight"), ("eyeBlinkLeft", "eyeBlinkRight")

            def peak(r, names):                        # the run's strongest true value of those shapes
                tgt = next(t for t in targets if t.name == r["character"])
                cols = [tgt.names.index(n) for n in names if n in tgt.names]
                return float(r["_weights"][0][:, cols].mean(axis=1).max()) if cols else 0.0

            rows = []
            for what, names in (("smile", smile), ("blink", blink)):
                best = max(same, key=lambda r, names=names: peak(r, names))
                tgt = next(t for t in targets if t.name == best["character"])
                rows.append((what, tgt, best["_weights"], names))
                print(f"figure, {what}: {best['character']}, {best['take']}, {best['setup']}")
            print(f"figure: {figure(rows, a.figure)}")
    for r in runs:
        r.pop("_weights", None)
    summ = summary(runs)
    print(table(summ))
    out = {"runs": runs, "summary": summ, "skipped": skipped}
    if a.live:
        for r in live_runs:
            r.pop("_weights", None)
        out["live"] = {"runs": live_runs, "summary": summary(live_runs)}
        print("live mode (faceretarget live: each frame as it comes; peer: MediaPipe's raw scores, same frames):")
        print(table(out["live"]["summary"]))
    if a.json:
        print(json.dumps(out, default=float))
    return 0


def run_live(src: Target, dst: Target, video: Path, raw, Wtake: np.ndarray, names: list[str],
             head: Rotation) -> dict:
    """The live mode on the rendered video (real time off, so every frame is solved): the frames it solved after
    its calibration, against the truth, and MediaPipe's raw scores on the same frames (``raw``, the video's
    :func:`~faceretarget.capture.track_video`) as the peer."""
    from types import SimpleNamespace

    from faceretarget.pipelines.live import LiveSession

    with LiveSession(video, dst.drive.rig, realtime=False, record=True, log=lambda *_: None) as ses:
        st = ses.run()
    fr = np.asarray(st.frames, np.int64)
    res = SimpleNamespace(weights=st.weights, names=list(st.names), head=st.head, mouth_corr=float("nan"))
    peer = SimpleNamespace(weights=raw.weights[fr], names=list(raw.names),
                           head=SimpleNamespace(quaternions=raw.head.quaternions[fr]))
    r = run_one(src, dst, peer, res, Wtake[fr], names, head[fr])
    r["detected"] = float(raw.detected.mean())
    return r


def line(r: dict) -> str:
    o, p = r["ours"], r["peer"]
    reg = " ".join(f"{k} {o['regions'][k]:.0f}/{p['regions'][k]:.0f}" for k in REGIONS)
    return (f"{r['character']} {r['take']} {r['setup']} -> {r['target']} ({r['onto']}): {r['frames']} frames, "
            f"face {r['detected']:.0%}; region err % ours/peer: {reg}; blink F1 {o['blink']['f1']:.2f}/"
            f"{p['blink']['f1']:.2f}; smile right {o['smile']['share']:.2f}/{p['smile']['share']:.2f}; "
            f"head {o['head_deg']:.1f}/{p['head_deg']:.1f} deg; {r['seconds']} s")


def _median(xs) -> float:
    xs = [x for x in xs if x is not None and np.isfinite(x)]
    return float(np.median(xs)) if xs else float("nan")


def summary(runs: list[dict]) -> dict:
    """Medians over the runs, per target kind (same / other), ours and the peer's and their ratio."""
    out = {}
    for kind in ("same", "other"):
        rs = [r for r in runs if r.get("target") == kind]
        if not rs:
            continue
        d = {"runs": len(rs)}
        for who in ("ours", "peer", "peer_raw"):
            if any(who not in r for r in rs):
                continue
            d[who] = {"regions": {k: _median(r[who]["regions"][k] for r in rs) for k in REGIONS},
                      "blink_f1": _median(r[who]["blink"]["f1"] for r in rs),
                      "smile_share": _median(r[who]["smile"]["share"] for r in rs),
                      "head_deg": _median(r[who]["head_deg"] for r in rs)}
        d["ratio_of_medians"] = {k: d["ours"]["regions"][k] / d["peer"]["regions"][k] for k in REGIONS}
        d["ratio_median"] = {k: _median(r["ratio"]["regions"][k] for r in rs) for k in REGIONS}
        if "peer_raw" in d:
            d["ratio_of_medians_raw"] = {k: d["ours"]["regions"][k] / d["peer_raw"]["regions"][k] for k in REGIONS}
        out[kind] = d
    return out


def table(summ: dict) -> str:
    lines = []
    for kind, d in summ.items():
        lines.append(f"onto the {kind} character ({d['runs']} runs): median of each run's figure, ours / peer "
                     "(ratio of medians)")
        for k in REGIONS:
            lines.append(f"  {k:7s} error % of true motion: {d['ours']['regions'][k]:6.1f} / "
                         f"{d['peer']['regions'][k]:6.1f}  ({d['ratio_of_medians'][k]:.2f}x)")
        # three decimals where issue 32's targets are (0.9, 95 %, 2 deg): 0.948 printed as 0.95 read as met
        lines.append(f"  blink F1: {d['ours']['blink_f1']:.3f} / {d['peer']['blink_f1']:.3f}; smile right: "
                     f"{d['ours']['smile_share']:.3f} / {d['peer']['smile_share']:.3f}; head error: "
                     f"{d['ours']['head_deg']:.2f} / {d['peer']['head_deg']:.2f} deg")
        if "peer_raw" in d:
            r = d["peer_raw"]
            lines.append("  the raw peer (the scores copied straight): "
                         + ", ".join(f"{k} {r['regions'][k]:.1f} ({d['ratio_of_medians_raw'][k]:.2f}x)" for k in REGIONS)
                         + f"; blink F1 {r['blink_f1']:.3f}; smile right {r['smile_share']:.3f}; head {r['head_deg']:.2f} deg")
    return "\n".join(lines)


if __name__ == "__main__":
    raise SystemExit(main())
