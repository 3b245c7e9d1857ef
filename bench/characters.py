"""Characters as users bring them (protocol P8, issue 22): every character file of a folder, the shared
videos, no hand-made information.

For every character file (``.glb .gltf .vrm .fbx .blend .usd .usda .usdc .usdz``) under ``--characters``
(default ``../shared/data/characters``) and, unless ``--no-rigs``, glTF versions of the shared rigs
(``ict-face``, ``arkit-face``) and the demo characters (``ada``, ``bo``) written here *without* their
landmarks (whose reference landmarks give the landmark error), in this run:

* ``route`` and the ``meshes`` / ``joints`` found, ``shapes_used`` of ``shapes_total``;
* ``prepare_s``: reading the file and finding its landmarks with an empty cache, ``prepare_cached_s``: the
  same again with the cache filled;
* ``landmarks_nme_inner`` / ``landmarks_nme_contour``: mean distance of the 51 inner and 17 contour points
  found to the reference ones, over the outer-eye-corner distance (where a reference exists);
* per video (default both of ``../shared/data/video``, each captured once): ``faceretarget animate``
  onto the character written back in its own format; ``mouth_corr`` (the tracked and the character's
  mouth opening, the worse of the videos) and ``fps`` (frames over the video's capture seconds, measured
  once, plus this character's solve and write seconds; the worse of the videos);
* ``output_checks`` on the first video's file: the Khronos validator (errors the output adds to the
  input's), what is kept (counts, images byte-identical), three.js in headless Chromium (influences and
  head joint world rotation against what was written), Blender (``.fbx`` / ``.blend``) and usd-core
  (USD).

Usage::

    python bench/characters.py [--json] [--characters DIR] [--video V ...] [--no-rigs] [--out DIR]

The last line with ``--json``: ``{"characters": {NAME: {"ok", "error", "route", "meshes", "shapes_used",
"shapes_total", "landmarks_nme_inner", "landmarks_nme_contour", "mouth_corr", "fps", "prepare_s",
"prepare_cached_s", "output_checks": {"validator_errors", "kept", "three", "blender"}}}}`` (null where it
does not apply).  Targets: ``mouth_corr`` >= 0.9, ``fps`` >= 30, prepare <= 10 s first and <= 1 s
cached for a 2 MB file, every output check passing; a character without a human face gives a clear
error.
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
import _character_checks as checks  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
DATA = REPO.parent / "shared" / "data"
EXTS = (".glb", ".gltf", ".vrm", ".fbx", ".blend", ".usd", ".usda", ".usdc", ".usdz")
INNER, CONTOUR = np.arange(17, 68), np.arange(17)


def rig_characters(folder: Path, log) -> dict[str, tuple[Path, np.ndarray]]:
    """glTF files of the shared rigs and the demo characters, without landmarks; with their reference
    landmark positions (metres, the file's frame)."""
    from faceretarget.datasets import make_demo_character
    from faceretarget.io import read_rig, write_glb

    out = {}
    rigs = []
    for name in ("ict-face", "arkit-face"):
        if (DATA / name).is_dir():
            rigs.append((name, read_rig(DATA / name)))
    for name in ("ada", "bo"):
        rigs.append((f"demo-{name}", make_demo_character(name)))
    from faceretarget.io import glb_vertex_order

    for name, rig in rigs:
        p = folder / f"{name}.glb"
        write_glb(p, rig, np.zeros((1, rig.n_shapes)), np.zeros(1))
        ref = rig.neutral.vertices[rig.landmarks] * rig.mm_per_unit / 1000.0
        # the reference landmarks as vertices of the .glb (UV seams split vertices): for --landmarks
        src = glb_vertex_order(rig.neutral)
        first = {int(s): i for i, s in reversed(list(enumerate(src)))}
        (folder / f"{name}.reference68.txt").write_text(" ".join(str(first[int(v)]) for v in rig.landmarks))
        out[name] = (p, ref)
        log(f"wrote {p.name} ({rig.n_vertices} vertices, {rig.n_shapes} shapes, no landmark file)")
    return out


def nme(found: np.ndarray, ref: np.ndarray) -> tuple[float, float]:
    d = np.linalg.norm(found - ref, axis=1) / np.linalg.norm(ref[36] - ref[45])
    return float(d[INNER].mean()), float(d[CONTOUR].mean())


def out_ext(path: Path) -> str:
    ext = path.suffix.lower()
    return {".gltf": ".glb", ".usdz": ".usda", ".usdc": ".usda", ".usd": ".usda"}.get(ext, ext)


def one(name: str, path: Path, ref, caps: dict, cap_seconds: dict, work: Path, log) -> dict:
    from faceretarget.characters import drive_rig, load_character
    from faceretarget.io import check_character_route
    from faceretarget.pipelines import animate

    res = {k: None for k in ("route", "meshes", "joints", "shapes_used", "shapes_total", "landmarks_nme_inner",
                             "landmarks_nme_contour", "mouth_corr", "fps", "prepare_s", "prepare_cached_s",
                             "size_mb", "output_checks")}
    res.update(ok=False, error=None, file=str(path), size_mb=round(path.stat().st_size / 1e6, 2))
    try:
        cache = work / f"cache-{name}"
        os.environ["FACERETARGET_CACHE"] = str(cache)
        out = work / "animated" / f"{name}{out_ext(path)}"
        out.parent.mkdir(exist_ok=True)
        check_character_route(path, out)
        t0 = time.perf_counter()
        ch = load_character(path)
        drive = drive_rig(ch)
        res["prepare_s"] = round(time.perf_counter() - t0, 3)
        t0 = time.perf_counter()
        ch2 = load_character(path)
        drive_rig(ch2)
        res["prepare_cached_s"] = round(time.perf_counter() - t0, 3)
        res["route"] = ch.route
        res["meshes"] = [ch.meshes[i].name for i in ch.face_meshes()]
        res["joints"] = {r: ch.joints[i].name for r, i in ch.roles.items()}
        res["shapes_used"] = len(drive.choice.drive)
        res["shapes_total"] = int(sum(ch.meshes[i].n_shapes for i in ch.face_meshes()))
        log(f"{name}: {ch.summary()}; {drive.summary}")
        if ref is not None:
            res["landmarks_nme_inner"], res["landmarks_nme_contour"] = (round(x, 4) for x in
                                                                        nme(ch.landmark_positions(), ref))
        corr, fps = [], []
        first = None
        for k, (vname, cap) in enumerate(caps.items()):
            o = out if k == 0 else out.with_name(f"{name}.{vname}{out_ext(path)}")
            r = animate(cap, ch, out=o, log=lambda *_: None)
            corr.append(r.mouth_corr)
            steps = cap_seconds[vname] + sum(v for key, v in r.timings.items() if key in ("solve", "write"))
            fps.append(len(r.times) / steps)
            if first is None:
                first = (o, r)
        if ref is not None:                     # the same job on the reference landmarks (P8: within 0.02)
            refc = [animate(cap, load_character(path, landmarks=path.with_suffix(".reference68.txt")),
                            log=lambda *_: None).mouth_corr for cap in caps.values()]
            res["mouth_corr_reference"] = round(float(min(refc)), 4)
            res["mouth_corr_delta"] = round(float(max(abs(a - b) for a, b in zip(corr, refc, strict=True))), 4)
        res["mouth_corr"] = round(float(min(corr)), 4)
        res["mouth_corr_each"] = [round(float(c), 4) for c in corr]
        res["fps"] = round(float(min(fps)), 1)
        res["output_checks"] = output_checks(path, first[0], first[1], caps)
        res["ok"] = True
    except Exception as e:  # the bench reports every character, whatever goes wrong
        res["error"] = " ".join(str(e).split())[:400]
        res["error_type"] = type(e).__name__
        if not hasattr(e, "__module__") or not type(e).__module__.startswith("faceretarget"):
            res["traceback"] = traceback.format_exc(limit=4)[-800:]
    return res


def output_checks(inp: Path, out: Path, res, caps) -> dict:
    ext = out.suffix.lower()
    oc = {"validator_errors": None, "kept": None, "three": None, "blender": None, "usd": None}
    if ext in (".glb", ".vrm"):
        g = checks.gltf_checks(inp if inp.suffix.lower() != ".gltf" else out, out, checks.written_gltf(out))
        oc.update(validator_errors=g["validator_errors"], kept=g["kept"], three=g["three"])
    elif ext in (".fbx", ".blend"):
        fps = len(res.times) / max(res.times[-1] - res.times[0], 1e-9) * (len(res.times) - 1) / len(res.times)
        oc["blender"] = checks.blender_checks(inp, out, fps, len(res.times))
    elif ext in (".usda", ".usdc", ".usd"):
        from faceretarget.character import mesh_columns

        d = res.drive
        names = {d.character.meshes[mi].shape_names[k]: col
                 for mi, cols in mesh_columns(d.channels, d.full_weights(res.weights)).items() for k, col in cols.items()}
        oc["usd"] = checks.usd_checks(out, names, res.times)
    return oc


def passed(oc: dict) -> bool | None:
    vals = []
    v = oc.get("validator_errors")
    if v is not None:
        vals.append(v["added"] <= 0)
    for k in ("kept", "three", "blender", "usd"):
        x = oc.get(k)
        if x is not None and x.get("ok") is not None:
            vals.append(bool(x["ok"]))
    return None if not vals else all(vals)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--characters", type=Path, default=DATA / "characters")
    ap.add_argument("--video", type=Path, nargs="*", default=None)
    ap.add_argument("--no-rigs", action="store_true", help="only the files under --characters")
    ap.add_argument("--out", type=Path, default=None, help="keep the written files here")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)
    quiet = args.json

    def log(*a):
        print(*a, file=sys.stderr if quiet else sys.stdout, flush=True)

    from faceretarget.pipelines import capture_take

    videos = args.video or sorted((DATA / "video").glob("*.mp4"))
    if not videos:
        ap.error("no video: give --video FILE")
    work = args.out or Path(tempfile.mkdtemp(prefix="faceretarget-characters-"))
    work.mkdir(parents=True, exist_ok=True)
    files = sorted(p for p in args.characters.rglob("*") if p.suffix.lower() in EXTS and p.is_file()) \
        if args.characters.is_dir() else []
    todo = {p.stem: (p, None) for p in files}
    if not args.no_rigs:
        todo.update(rig_characters(work, log))
    caps, cap_seconds = {}, {}
    for v in videos:
        t0 = time.perf_counter()
        caps[v.stem] = capture_take(v, neutral_percentile=5.0)
        cap_seconds[v.stem] = time.perf_counter() - t0          # counted in every character's end-to-end fps
        log(f"captured {v.name} in {cap_seconds[v.stem]:.1f} s")
    out = {}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for name, (p, ref) in todo.items():
            log(f"--- {name} ({p})")
            out[name] = r = one(name, p, ref, caps, cap_seconds, work, log)
            r["output_checks_pass"] = passed(r["output_checks"]) if r["output_checks"] else None
            log(json.dumps({k: r[k] for k in ("ok", "error", "mouth_corr", "fps", "prepare_s", "prepare_cached_s",
                                              "landmarks_nme_inner", "landmarks_nme_contour", "output_checks_pass")}))
    rows = [("character", "ok", "shapes", "nme in/ct %", "mouth", "fps", "prep s", "cached s", "checks")]
    for n, r in out.items():
        nm = "-" if r["landmarks_nme_inner"] is None else f"{100 * r['landmarks_nme_inner']:.1f}/" \
            f"{100 * r['landmarks_nme_contour']:.1f}"
        rows.append((n, "yes" if r["ok"] else "NO", f"{r['shapes_used']}/{r['shapes_total']}", nm,
                     "-" if r["mouth_corr"] is None else f"{r['mouth_corr']:.3f}", r["fps"] or "-",
                     r["prepare_s"] or "-", r["prepare_cached_s"] or "-", r.get("output_checks_pass")))
    for row in rows:
        log("  ".join(f"{str(c):>14}" if i else f"{str(c):<28}" for i, c in enumerate(row)))
    for n, r in out.items():
        if r["error"]:
            log(f"{n}: {r['error']}")
    if args.json:
        print(json.dumps({"characters": out}, default=lambda o: o.tolist() if hasattr(o, "tolist") else str(o)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
