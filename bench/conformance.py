"""Conformance: faceretarget's readers against established readers, on files written by other exporters.

Every C3D, BVH and glTF file of a folder (default: ``../shared/data/conformance`` and the ``.glb``
characters of ``../shared/data/characters``) is read by our reader and by the established readers:

* **C3D**: :func:`faceretarget.io.read_c3d` (``zero_is_missing=False``, the raw samples) against
  ezc3d and py-c3d (``c3d``): every sample's value and NaN mask, the point rate, the first frame and
  the labels (blanks stripped; empty and repeated labels renamed as our reader does);
* **BVH**: :func:`faceretarget.io.read_bvh` against the ``bvh`` package (every channel value of every
  frame, joint names, frame count and time) and bvhio (world positions of every joint by forward
  kinematics, to 1e-4 of the skeleton's size, on up to 200 evenly spaced frames);
* **glTF**: :func:`ours_gltf`, one adapter over our glTF reader (every primitive's POSITION, indices and
  morph-target POSITION, every node's world matrix, every animation sampler's input and output)
  against the same arrays decoded from pygltflib's parse of the file.

Each reader runs in a child process (one per reader, reading the files one after the other) watched by a
timeout per file: ezc3d hangs or crashes on some malformed files, so the file it stops on is read again in
a process of its own, and a reference that fails never stops the run.  Outcomes per file:

``agree``   ours reads it, and agrees to 1e-6 relative (BVH positions: 1e-4 of the skeleton's size)
            with at least one reference; any other reference either failed or differs for a named,
            checked reason (``EXPLANATIONS``);
``differ``  ours reads it but agrees with no reference, or a reference differs for no named reason
            (``max_abs_diff`` says by how much), or no reference could read it to check;
``error``   ours refuses it with a clear error (a ``FaceRetargetError`` naming the file), the reason given;
``crash``   ours raised anything else, or the process died;
``hang``    ours ran past the timeout.

Usage::

    python bench/conformance.py [--json] [--corpus DIR ...] [--timeout 60] [--format c3d|bvh|gltf ...]

With ``--json`` the last line of stdout is one object::

    {"formats": {"c3d"|"bvh"|"gltf": {"files", "agree", "differ", "error", "crash", "hang",
                                       "details": {file: {"outcome", "reason", ...}}}}}
"""

from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
import tempfile
import time
import traceback
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
DATA = Path(os.environ.get("FACERETARGET_DATA", REPO.parent / "shared" / "data"))
EXTENSIONS = {"c3d": (".c3d",), "bvh": (".bvh",), "gltf": (".glb", ".gltf")}
REFERENCES = {"c3d": ("ezc3d", "py-c3d"), "bvh": ("bvh", "bvhio"), "gltf": ("pygltflib",)}
#: Relative agreement of values (float32 files rounded by two readers differ by ~1e-7).
RTOL = 1e-6
#: BVH world positions: agreement as a share of the skeleton's size.
BVH_TOL = 1e-4
#: Frames of a BVH take compared by forward kinematics (bvhio poses one frame at a time in Python).
BVH_FRAMES = 200
TIMEOUT = 60.0
#: Seconds a child may take to start (its imports) before the first file's timeout runs.
STARTUP = 20.0

#: Why a reference may differ from a correct read: ``{name: text}``; each is checked on the file
#: itself before it is used (:func:`explain_c3d`).
EXPLANATIONS = {
    "ezc3d_frame_size": "ezc3d sizes a frame from POINT:USED and ANALOG:USED x ANALOG:RATE / POINT:RATE; this "
                        "file lacks a rate while its header declares analog samples per frame, or its "
                        "parameters give a frame size its data block does not hold (the header's does), so "
                        "ezc3d reads every frame at the wrong size",
    "ezc3d_padding": "ezc3d counts frames from the data block when no parameter holds the count (more "
                     "than 65535 frames), so it reads the zero padding of the last block as extra frames",
    "pyc3d_residual_cast": "py-c3d casts the float residual word to a 32-bit integer; this file stores it as "
                           "two 16-bit integers (a float beyond the int32 range), so py-c3d marks valid "
                           "samples invalid (ezc3d reads the word as we do)",
    "bvh_last_row": "the bvh package drops a last line without a line ending; this file's last frame row has "
                    "none (every other row equal)",
}


# ------------------------------------------------------------------------------------------ readers
def _labels(raw: list[str]) -> list[str]:
    """Labels as our C3D reader gives them: blanks stripped, empty ones ``M001``..., repeats ``_2``..."""
    labels = [str(s).strip() or f"M{i + 1:03d}" for i, s in enumerate(raw)]
    seen: dict[str, int] = {}
    for i, s in enumerate(labels):
        seen[s] = seen.get(s, 0) + 1
        if seen[s] > 1:
            labels[i] = f"{s}_{seen[s]}"
    return labels


def read_ours_c3d(path: Path) -> dict:
    from faceretarget.io import read_c3d

    p = read_c3d(path, zero_is_missing=False)
    return {"points": p.points, "rate": np.float64(p.fps), "first_frame": np.int64(round(p.times[0] * p.fps)),
            "labels": list(p.labels)}


def read_ezc3d(path: Path) -> dict:
    import ezc3d

    c = ezc3d.c3d(str(path))
    pts = np.asarray(c["data"]["points"], np.float64)[:3].transpose(2, 1, 0)
    res = np.asarray(c["data"]["meta_points"]["residuals"], np.float64)[0].T if pts.size else np.zeros(pts.shape[:2])
    pts = np.where((res < 0)[..., None], np.nan, pts)
    point = c["parameters"]["POINT"]
    raw: list[str] = []
    k = 1
    while len(raw) < pts.shape[1]:
        key = "LABELS" if k == 1 else f"LABELS{k}"
        if key not in point:
            break
        raw += list(point[key]["value"])
        k += 1
    raw = (raw + [""] * pts.shape[1])[:pts.shape[1]]
    return {"points": pts, "rate": np.float64(c["header"]["points"]["frame_rate"]),
            "first_frame": np.int64(c["header"]["points"]["first_frame"]), "labels": _labels(raw)}


def read_pyc3d(path: Path) -> dict:
    import c3d

    with open(path, "rb") as f, warnings.catch_warnings():
        warnings.simplefilter("ignore")
        r = c3d.Reader(f)
        frames = [np.array(p, np.float64) for _, p, _ in r.read_frames()]
        P = int(r.point_used)
        pts = np.stack(frames)[:, :, :3] if frames else np.zeros((0, P, 3))
        res = np.stack(frames)[:, :, 3] if frames else np.zeros((0, P))
        pts = np.where((res < 0)[..., None], np.nan, pts)
        labels = _labels([str(s) for s in r.point_labels][:P] + [""] * max(0, P - len(r.point_labels)))
        return {"points": pts, "rate": np.float64(r.point_rate), "first_frame": np.int64(r.first_frame - 1),
                "labels": labels}


def read_ours_bvh(path: Path) -> dict:
    from faceretarget.io import bvh_world_positions, read_bvh

    b = read_bvh(path)
    frames = _bvh_frames(b.n_frames)
    world = bvh_world_positions(b)[frames]
    rest = bvh_world_positions(b, *_rest(b))[0]
    return {"names": b.names, "frame_time": np.float64(b.frame_time), "n_frames": np.int64(b.n_frames),
            "motion": b.motion, "world": world, "rest": rest,
            "channels": [f"{j.name}.{c}" for j in b.joints for c in j.channels]}


def _rest(b):
    """The rest pose (identity rotations, joints at their offsets) as ``bvh_world_positions`` inputs."""
    J = len(b.joints)
    q = np.zeros((1, J, 4))
    q[..., 3] = 1.0
    return q, np.array([j.offset for j in b.joints], np.float64)[None]


def _bvh_frames(T: int) -> np.ndarray:
    return np.unique(np.linspace(0, T - 1, min(T, BVH_FRAMES)).round().astype(int))


def read_bvhio(path: Path) -> dict:
    import bvhio

    root = bvhio.readAsHierarchy(str(path))
    joints = [j for j, _, _ in root.layout()]
    T = len(root.Keyframes) if root.Keyframes else 0
    frames = _bvh_frames(T)
    world = np.empty((len(frames), len(joints), 3))
    for k, f in enumerate(frames):
        root.loadPose(int(f))
        world[k] = [tuple(j.PositionWorld) for j in joints]
    return {"names": [j.Name for j in joints], "world": world, "n_frames": np.int64(T)}


def read_bvhpkg(path: Path) -> dict:
    from bvh import Bvh

    with open(path, encoding="utf-8", errors="replace") as f:
        mocap = Bvh(f.read())
    names = mocap.get_joints_names()
    motion = np.array(mocap.frames, dtype=np.float64)
    return {"names": list(names), "frame_time": np.float64(mocap.frame_time), "n_frames": np.int64(mocap.nframes),
            "motion": motion, "channels": [f"{n}.{c}" for n in names for c in mocap.joint_channels(n)]}


# ------------------------------------------------------------------------------------------ glTF
#: Extensions that change how accessors are decoded: our reader cannot read files that require them.


def ours_gltf(path: str | os.PathLike) -> dict[str, np.ndarray]:
    """Accessor-level data of a glTF file through faceretarget's glTF reader (:class:`faceretarget.io.GltfDocument`,
    the one the character reader uses: meshopt, Draco, sparse accessors, ``.gltf`` with external buffers).

    Keys: ``mesh{m}.prim{p}.POSITION`` ``(N, 3)``, ``mesh{m}.prim{p}.indices`` ``(M,)``,
    ``mesh{m}.prim{p}.target{t}.POSITION`` ``(N, 3)``, ``node{n}.world`` ``(4, 4)`` (the node's world
    matrix in the default scene, column vectors), ``anim{a}.sampler{s}.input`` ``(K,)`` and
    ``.output`` ``(K, C)``.  The one place the bench touches the reader: point it at a new reader here.
    A Draco-compressed primitive's arrays come from the Draco data (the accessors it replaces have none).

    Raises
    ------
    FaceRetargetError
        A file the reader cannot decode (naming the extension or the part at fault).
    """
    from faceretarget.io import GltfDocument
    from faceretarget.io._gltf_scene import _scene_nodes, _world_matrices

    path = Path(path)
    doc = GltfDocument(path)
    gltf = doc.json
    out: dict[str, np.ndarray] = {}
    for m, mesh in enumerate(gltf.get("meshes", [])):
        for p, prim in enumerate(mesh.get("primitives", [])):
            if "KHR_draco_mesh_compression" in prim.get("extensions", {}):
                continue                                # pygltflib cannot decode it: nothing to compare
            if "POSITION" in prim.get("attributes", {}):
                out[f"mesh{m}.prim{p}.POSITION"] = doc.accessor(prim["attributes"]["POSITION"])
            if "indices" in prim:
                out[f"mesh{m}.prim{p}.indices"] = doc.accessor(prim["indices"]).reshape(-1)
            for t, tg in enumerate(prim.get("targets", [])):
                if "POSITION" in tg:
                    out[f"mesh{m}.prim{p}.target{t}.POSITION"] = doc.accessor(tg["POSITION"])
    world, _, parent = _world_matrices(doc)
    for n in _scene_nodes(doc, parent):
        out[f"node{n}.world"] = world[n]
    for a, anim in enumerate(gltf.get("animations", [])):
        for s, smp in enumerate(anim.get("samplers", [])):
            out[f"anim{a}.sampler{s}.input"] = doc.accessor(smp["input"]).reshape(-1)
            out[f"anim{a}.sampler{s}.output"] = doc.accessor(smp["output"])
    return out


_COMPONENT = {5120: np.int8, 5121: np.uint8, 5122: np.int16, 5123: np.uint16, 5125: np.uint32, 5126: np.float32}
_WIDTH = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT2": 4, "MAT3": 9, "MAT4": 16}


def read_pygltflib(path: Path) -> dict:
    """The arrays of :func:`ours_gltf`, decoded from pygltflib's parse of the file (sparse accessors
    applied, normalized integers scaled, matrices or TRS composed by hand)."""
    import pygltflib

    g = pygltflib.GLTF2().load(str(path))
    blob = g.binary_blob() if path.suffix.lower() == ".glb" else None

    def buffer(i: int) -> bytes:
        if blob is not None and i == 0 and not g.buffers[0].uri:
            return blob
        if not g.buffers[i].uri:                  # a meshopt fallback buffer: only decoded views refer to it
            return b""
        return g.get_data_from_buffer_uri(g.buffers[i].uri)

    def view(i: int) -> tuple[bytes, int, int | None]:
        v = g.bufferViews[i]
        ext = (v.extensions or {}).get("EXT_meshopt_compression")
        if ext:                               # meshoptimizer's own decoder on pygltflib's parse
            import meshopt

            src = buffer(ext.get("buffer", 0))[ext.get("byteOffset", 0): ext.get("byteOffset", 0) + ext["byteLength"]]
            filt = ext.get("filter", "NONE")
            data = meshopt.decode_gltf_buffer(src, ext["count"], ext["byteStride"], ext.get("mode", "ATTRIBUTES"),
                                              None if filt == "NONE" else filt)
            return np.ascontiguousarray(data).tobytes(), 0, v.byteStride or ext["byteStride"]
        return buffer(v.buffer), v.byteOffset or 0, v.byteStride

    def accessor(i: int) -> np.ndarray:
        a = g.accessors[i]
        dt, n = np.dtype(_COMPONENT[a.componentType]), _WIDTH[a.type]
        if a.bufferView is None:
            arr = np.zeros((a.count, n), dt)
        else:
            data, off, stride = view(a.bufferView)
            stride = stride or n * dt.itemsize
            rows = [np.frombuffer(data, dt, n, off + (a.byteOffset or 0) + k * stride) for k in range(a.count)]
            arr = np.array(rows, dt).reshape(a.count, n)
        if a.sparse is not None:
            sp = a.sparse
            d, o, _ = view(sp.indices.bufferView)
            idx = np.frombuffer(d, np.dtype(_COMPONENT[sp.indices.componentType]), sp.count,
                                o + (sp.indices.byteOffset or 0))
            d, o, _ = view(sp.values.bufferView)
            vals = np.frombuffer(d, dt, sp.count * n, o + (sp.values.byteOffset or 0)).reshape(sp.count, n)
            arr = arr.copy()
            arr[idx.astype(np.int64)] = vals
        out = arr.astype(np.float64)
        if a.normalized and dt.kind in "iu":
            out = np.maximum(out / np.iinfo(dt).max, -1.0)
        return out

    out: dict[str, np.ndarray] = {}
    for m, mesh in enumerate(g.meshes or []):
        for p, prim in enumerate(mesh.primitives or []):
            if prim.attributes.POSITION is not None:
                out[f"mesh{m}.prim{p}.POSITION"] = accessor(prim.attributes.POSITION)
            if prim.indices is not None:
                out[f"mesh{m}.prim{p}.indices"] = accessor(prim.indices).reshape(-1)
            for t, tg in enumerate(prim.targets or []):
                pos = tg.get("POSITION") if isinstance(tg, dict) else getattr(tg, "POSITION", None)
                if pos is not None:
                    out[f"mesh{m}.prim{p}.target{t}.POSITION"] = accessor(pos)

    def local(nd) -> np.ndarray:
        if nd.matrix is not None:
            return np.asarray(nd.matrix, np.float64).reshape(4, 4).T
        x, y, z, w = nd.rotation or [0.0, 0.0, 0.0, 1.0]
        r = np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                      [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                      [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])
        m = np.eye(4)
        m[:3, :3] = r @ np.diag(nd.scale or [1.0, 1.0, 1.0])
        m[:3, 3] = nd.translation or [0.0, 0.0, 0.0]
        return m

    def visit(i: int, parent: np.ndarray) -> None:
        if f"node{i}.world" in out:
            return
        out[f"node{i}.world"] = parent @ local(g.nodes[i])
        for c in g.nodes[i].children or []:
            visit(c, out[f"node{i}.world"])

    if g.scenes:
        for r in g.scenes[g.scene or 0].nodes or []:
            visit(r, np.eye(4))
    for a, anim in enumerate(g.animations or []):
        for s, smp in enumerate(anim.samplers or []):
            out[f"anim{a}.sampler{s}.input"] = accessor(smp.input).reshape(-1)
            out[f"anim{a}.sampler{s}.output"] = accessor(smp.output)
    return out


def _ours_gltf_child(path: Path) -> dict:
    return {"arrays": ours_gltf(path)}


def _pygltflib_child(path: Path) -> dict:
    return {"arrays": read_pygltflib(path)}


def _selftest(path: Path) -> dict:
    """A reader that hangs on a file whose text says ``hang`` and dies on ``crash`` (tests of the isolation)."""
    text = path.read_text(errors="replace")
    if "hang" in text:
        time.sleep(3600)
    if "crash" in text:
        os._exit(139)
    return {"text": np.array(text)}


READERS = {"selftest": _selftest, "ours-c3d": read_ours_c3d, "ezc3d": read_ezc3d, "py-c3d": read_pyc3d,
           "ours-bvh": read_ours_bvh, "bvhio": read_bvhio, "bvh": read_bvhpkg,
           "ours-gltf": _ours_gltf_child, "pygltflib": _pygltflib_child}


# ------------------------------------------------------------------------------------- child runs
@dataclass
class Run:
    """One reader on one file: ``status`` ok | error | crash | hang; ``data`` what it read."""

    status: str
    data: dict | None = None
    message: str = ""
    warnings: list[str] = field(default_factory=list)
    seconds: float = 0.0


def _child(reader: str, path: str, out: str) -> int:
    """Read ``path`` with ``reader`` and write the result (or the error) to ``out`` as an ``.npz``."""
    from faceretarget.errors import FaceRetargetError

    ours = reader.startswith("ours-")
    t0 = time.perf_counter()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            data = READERS[reader](Path(path))
            status, message = "ok", ""
        except FaceRetargetError as e:
            data, message = None, str(e)
            status = "error" if (not ours or (path in message and "\n" not in message)) else "crash"
        except Exception as e:  # noqa: BLE001 - a reference's failure, or ours crashing, is the result
            data, message = None, f"{type(e).__name__}: {e}"
            status = "crash" if ours else "error"
            if ours:
                message += " | " + traceback.format_exc(limit=3).replace("\n", " ")
    mine = [str(w.message) for w in caught if not ours or "faceretarget" in (w.filename or "")
            or str(path) in str(w.message)]
    arrays: dict[str, np.ndarray] = {}
    meta = {"status": status, "message": message, "warnings": mine if ours else [],
            "seconds": time.perf_counter() - t0}
    for k, v in (data or {}).items():
        if k == "arrays":
            for kk, vv in v.items():
                arrays["arr:" + kk] = np.asarray(vv)
        elif isinstance(v, list):
            meta[k] = v
        else:
            arrays[k] = np.asarray(v)
    np.savez(out, meta=np.array(json.dumps(meta)), **arrays)
    return 0


def _env() -> dict:
    return dict(os.environ, PYTHONPATH=os.pathsep.join([str(REPO / "src"), os.environ.get("PYTHONPATH", "")]),
                OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1")


def _load_run(out: Path) -> Run:
    z = np.load(out, allow_pickle=False)
    meta = json.loads(str(z["meta"]))
    data = {k: z[k] for k in z.files if k != "meta" and not k.startswith("arr:")}
    arrs = {k[4:]: z[k] for k in z.files if k.startswith("arr:")}
    if arrs:
        data["arrays"] = arrs
    for k, v in meta.items():
        if k not in ("status", "message", "warnings", "seconds"):
            data[k] = v
    return Run(meta["status"], data if meta["status"] == "ok" else None, meta["message"], meta["warnings"],
               meta.get("seconds", 0.0))


def run(reader: str, path: Path, timeout: float = TIMEOUT) -> Run:
    """``reader`` on ``path`` in a child process (a hang or a crash of the reader is the result)."""
    with tempfile.TemporaryDirectory(prefix="conformance-") as tmp:
        out = Path(tmp) / "out.npz"
        t0 = time.perf_counter()
        try:
            p = subprocess.run([sys.executable, str(Path(__file__).resolve()), "--child", reader, str(path), str(out)],
                               capture_output=True, text=True, timeout=timeout, env=_env())
        except subprocess.TimeoutExpired:
            return Run("hang", message=f"no result after {timeout:g} s", seconds=timeout)
        if p.returncode != 0 or not out.is_file():
            tail = (p.stderr or "").strip().splitlines()[-1:] or [""]
            return Run("crash", message=f"exit code {p.returncode} {tail[0][:200]}",
                       seconds=time.perf_counter() - t0)
        return _load_run(out)


def run_many(reader: str, paths: list[Path], timeout: float = TIMEOUT) -> list[Run]:
    """:func:`run` on every path, the files read one after the other by one child process (the start-up of a
    process per file dominated); a file that hangs or kills the child is run again on its own."""
    paths = list(paths)
    if len(paths) <= 1:
        return [run(reader, p, timeout) for p in paths]
    with tempfile.TemporaryDirectory(prefix="conformance-") as tmp:
        listing = Path(tmp) / "files.txt"
        listing.write_text("\n".join(str(p) for p in paths), encoding="utf-8")
        proc = subprocess.Popen([sys.executable, str(Path(__file__).resolve()), "--child-batch", reader, str(listing),
                                 tmp], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=_env())
        done, last = 0, time.perf_counter()
        while proc.poll() is None:                          # results appear one by one: a silent child hangs
            while (Path(tmp) / f"{done}.npz").is_file() and (Path(tmp) / f"{done}.ok").is_file():
                done, last = done + 1, time.perf_counter()
            if time.perf_counter() - last > timeout + (STARTUP if done == 0 else 0.0):
                proc.kill()
                break
            time.sleep(0.05)
        proc.wait()
        out = [_load_run(Path(tmp) / f"{i}.npz") for i in range(len(paths))
               if (Path(tmp) / f"{i}.ok").is_file()]
    k = len(out)
    if k < len(paths):                                      # the file the child stopped on, alone; then the rest
        out.append(run(reader, paths[k], timeout))
        out += run_many(reader, paths[k + 1:], timeout)
    return out


def _child_batch(reader: str, listing: str, folder: str) -> int:
    for i, path in enumerate(Path(listing).read_text(encoding="utf-8").splitlines()):
        _child(reader, path, str(Path(folder) / f"{i}.npz"))
        (Path(folder) / f"{i}.ok").touch()                 # the .npz is complete
    return 0


# ------------------------------------------------------------------------------------- comparison
@dataclass
class Cmp:
    """Ours against one reference: ``ok`` when they agree, ``diff`` the largest difference, ``why`` what differs."""

    ok: bool
    diff: float
    why: str = ""
    note: str = ""


def _values(a: np.ndarray, b: np.ndarray, what: str, tol: float | None = None) -> Cmp:
    """Shape, NaN mask and values (to ``RTOL`` of the reference's largest magnitude, or ``tol``)."""
    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    if a.shape != b.shape:
        return Cmp(False, math.inf, f"{what}: shape {a.shape} against {b.shape}")
    na, nb = np.isnan(a), np.isnan(b)
    if (na != nb).any():
        return Cmp(False, math.inf, f"{what}: {int((na != nb).sum())} value(s) missing in one reader only")
    fin = ~na
    d = float(np.abs(a[fin] - b[fin]).max()) if fin.any() else 0.0
    scale = float(np.abs(b[fin]).max()) if fin.any() else 0.0
    limit = tol if tol is not None else RTOL * max(scale, 1e-300)
    return Cmp(d <= limit, d, "" if d <= limit else f"{what}: differ by {d:.3g} (limit {limit:.3g})")


def compare_c3d(ours: dict, ref: dict) -> Cmp:
    c = _values(ours["points"], ref["points"], "points")
    if not c.ok:
        return c
    if abs(float(ours["rate"]) - float(ref["rate"])) > RTOL * abs(float(ref["rate"])):
        return Cmp(False, c.diff, f"rate {float(ours['rate']):g} against {float(ref['rate']):g}")
    if int(ours["first_frame"]) != int(ref["first_frame"]):
        return Cmp(False, c.diff, f"first frame {int(ours['first_frame'])} against {int(ref['first_frame'])}")
    if list(ours["labels"]) != list(ref["labels"]):
        bad = next(i for i, (x, y) in enumerate(zip(ours["labels"], ref["labels"], strict=False)) if x != y) \
            if len(ours["labels"]) == len(ref["labels"]) else -1
        return Cmp(False, c.diff, f"labels differ (first at {bad})")
    return c


def compare_bvh(ours: dict, ref: dict, which: str) -> Cmp:
    if list(ours["names"]) != list(ref["names"]):
        return Cmp(False, math.inf, f"joint names differ ({len(ours['names'])} against {len(ref['names'])})")
    if int(ours["n_frames"]) != int(ref["n_frames"]):
        return Cmp(False, math.inf, f"{int(ours['n_frames'])} frames against {int(ref['n_frames'])}")
    if which == "bvh":
        if list(ours["channels"]) != list(ref["channels"]):
            return Cmp(False, math.inf, "channel names differ")
        if abs(float(ours["frame_time"]) - float(ref["frame_time"])) > 1e-12:
            return Cmp(False, math.inf, "frame time differs")
        return _values(ours["motion"], ref["motion"], "channel values", tol=0.0)
    size = float(np.ptp(ours["rest"], axis=0).max()) or 1.0
    c = _values(ours["world"], ref["world"], "world positions", tol=BVH_TOL * size)
    rel = f"{c.diff / size:.2g} of the skeleton's size {size:.4g}"
    return Cmp(c.ok, c.diff, c.why + (f" ({rel})" if c.why else ""), rel)


def compare_gltf(ours: dict, ref: dict) -> Cmp:
    a, b = ours["arrays"], ref["arrays"]
    if set(a) != set(b):
        extra = sorted(set(a) ^ set(b))[:3]
        return Cmp(False, math.inf, f"different arrays ({', '.join(extra)} ...)")
    worst = Cmp(True, 0.0)
    for k in sorted(a):
        c = _values(a[k], b[k], k)
        if not c.ok:
            return c
        worst = max(worst, c, key=lambda x: x.diff)
    return worst


def explain_c3d(path: Path, ours: dict, ref: dict, which: str) -> str | None:
    """The name of the :data:`EXPLANATIONS` entry that accounts for ``which``'s difference, checked on the
    file, or None."""
    from faceretarget.io import _c3d

    raw = path.read_bytes()
    c = _c3d._parse_c3d(path, raw)
    p = c.params
    head = _c3d._header(raw, c.dec, c.big)
    if which == "ezc3d":
        no_rate = ("POINT", "RATE") not in p or ("ANALOG", "RATE") not in p
        if (no_rate and head.analog > 0) or any(n.startswith("the parameters disagree") for n in c.notes):
            return "ezc3d_frame_size"
        T, Tr = len(ours["points"]), len(ref["points"])
        if Tr > T and ref["points"].shape[1:] == ours["points"].shape[1:] and not _c3d._any_byte(
                raw, c.data_start + T * c.frame_bytes) and _values(ours["points"], ref["points"][:T], "").ok:
            return "ezc3d_padding"
    if which == "py-c3d" and c.scale < 0 and ours["points"].shape == ref["points"].shape:
        mism = np.isnan(ours["points"]).any(2) != np.isnan(ref["points"]).any(2)
        if mism.any() and not np.isnan(ours["points"]).any(2)[mism].any():
            w = _residual_floats(raw, c)
            with np.errstate(invalid="ignore"):
                beyond = ~(np.abs(w) < 2.0**31)
            fin = np.isfinite(ours["points"]).all(2) & np.isfinite(ref["points"]).all(2)
            same = np.allclose(ours["points"][fin], ref["points"][fin], rtol=RTOL, atol=0)
            if beyond[mism].all() and same:
                return "pyc3d_residual_cast"
    return None


def explain_bvh(path: Path, ours: dict, ref: dict, which: str) -> str | None:
    """As :func:`explain_c3d`, for the BVH references."""
    if which == "bvh" and not path.read_bytes().rstrip(b" \t").endswith((b"\n", b"\r")):
        m, r = np.asarray(ours["motion"]), np.asarray(ref["motion"])
        if len(r) == len(m) - 1 and r.shape[1:] == m.shape[1:] and np.array_equal(m[:-1], r):
            return "bvh_last_row"
    return None


def _residual_floats(raw: bytes, c) -> np.ndarray:
    """(T, P) the fourth word of every float point sample read as a float."""
    rec = np.dtype({"names": ["p"], "formats": [(np.uint8, (c.n_points, 16))], "itemsize": c.frame_bytes})
    u8 = np.frombuffer(raw, rec, count=c.frames, offset=c.data_start)["p"].reshape(c.frames, c.n_points, 4, 4)
    return u8[:, :, 3].copy().view(">f4" if c.big else "<f4")[..., 0].astype(np.float64)


# ------------------------------------------------------------------------------------------ files
def check_files(fmt: str, paths: list[Path], timeout: float = TIMEOUT) -> list[dict]:
    """:func:`check_file` of every path, each reader running over all of them in one child (:func:`run_many`)."""
    runs = {r: run_many(r, paths, timeout) for r in (f"ours-{fmt}", *REFERENCES[fmt])}
    return [check_file(fmt, p, timeout, {r: v[i] for r, v in runs.items()}) for i, p in enumerate(paths)]


def check_file(fmt: str, path: Path, timeout: float = TIMEOUT, runs: dict[str, Run] | None = None) -> dict:
    """One file: ``{"outcome", "reason", "max_abs_diff", "references", "warnings", "seconds"}``, and when ours
    reads it ``agree_with`` (references), ``explained`` ({reference: :data:`EXPLANATIONS` key}),
    ``unexplained`` ({reference: what differs}) and ``failed`` ({reference: its error})."""
    runs = runs or {r: run(r, path, timeout) for r in (f"ours-{fmt}", *REFERENCES[fmt])}
    ours = runs[f"ours-{fmt}"]
    refs = {r: runs[r] for r in REFERENCES[fmt]}
    detail: dict = {"warnings": ours.warnings, "seconds": round(ours.seconds, 3),
                    "references": {r: (x.status if x.status == "ok" else f"{x.status}: {x.message[:160]}")
                                   for r, x in refs.items()}}
    if ours.status != "ok":
        detail.update(outcome=ours.status, reason=ours.message[:400], max_abs_diff=None)
        return detail
    agree, other = [], []
    worst = 0.0
    for r, x in refs.items():
        if x.status != "ok":
            continue
        c = (compare_c3d(ours.data, x.data) if fmt == "c3d" else compare_bvh(ours.data, x.data, r) if fmt == "bvh"
             else compare_gltf(ours.data, x.data))
        if c.ok:
            agree.append(f"{r} (max abs diff {c.diff:.3g}{', ' + c.note if c.note else ''})")
            worst = max(worst, c.diff)
        else:
            why = (explain_c3d(path, ours.data, x.data, r) if fmt == "c3d" else
                   explain_bvh(path, ours.data, x.data, r) if fmt == "bvh" else None)
            other.append((r, c, why))
    unexplained = [(r, c) for r, c, why in other if why is None]
    explained = [f"{r} differs, explained: {EXPLANATIONS[why]} ({c.why})" for r, c, why in other if why]
    detail.update(agree_with=[a.split(" ")[0] for a in agree], explained={r: why for r, _, why in other if why},
                  unexplained={r: c.why for r, c in unexplained},
                  failed={r: x.message[:200] for r, x in refs.items() if x.status != "ok"})
    if agree and not unexplained:
        detail.update(outcome="agree", max_abs_diff=worst,
                      reason="; ".join([f"agrees with {', '.join(agree)}"] + explained))
    elif not agree and not other:
        detail.update(outcome="differ", max_abs_diff=None,
                      reason="no reference reader could read it to check: " +
                             "; ".join(f"{r}: {x.message[:120]}" for r, x in refs.items()))
    elif not agree and not unexplained:
        detail.update(outcome="differ", max_abs_diff=None,
                      reason="no reference reads it right: " + "; ".join(
                          explained + [f"{r} fails: {x.message[:120]}" for r, x in refs.items() if x.status != "ok"]))
    else:
        d = max([c.diff for _, c in unexplained] or [worst])
        detail.update(outcome="differ", max_abs_diff=d if math.isfinite(d) else None,
                      reason="; ".join([f"agrees with {', '.join(agree)}"] * bool(agree) + explained
                                       + [f"{r}: {c.why}" for r, c in unexplained]))
    return detail


def corpus_files(folders: list[Path], formats: list[str]) -> dict[str, list[Path]]:
    out: dict[str, list[Path]] = {f: [] for f in formats}
    for folder in folders:
        files = [folder] if folder.is_file() else sorted(p for p in folder.rglob("*") if p.is_file())
        for p in files:
            for f in formats:
                if p.suffix.lower() in EXTENSIONS[f]:
                    out[f].append(p)
    return out


def default_corpus() -> list[Path]:
    out = [DATA / "conformance"]
    out += sorted((DATA / "characters").rglob("*.glb")) if (DATA / "characters").is_dir() else []
    return [p for p in out if p.exists()]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--json", action="store_true")
    ap.add_argument("--corpus", nargs="+", type=Path, help="folders or files (default: the shared conformance files "
                    "and the .glb characters)")
    ap.add_argument("--format", nargs="+", choices=sorted(EXTENSIONS), default=sorted(EXTENSIONS))
    ap.add_argument("--timeout", type=float, default=TIMEOUT, help="seconds per reader and file")
    ap.add_argument("--child", nargs=3, metavar=("READER", "PATH", "OUT"), help=argparse.SUPPRESS)
    ap.add_argument("--child-batch", nargs=3, metavar=("READER", "LIST", "DIR"), help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.child:
        return _child(*args.child)
    if args.child_batch:
        return _child_batch(*args.child_batch)
    folders = args.corpus or default_corpus()
    files = corpus_files(folders, args.format)
    result: dict = {"formats": {}}
    for fmt in args.format:
        counts = {"files": len(files[fmt]), "agree": 0, "differ": 0, "error": 0, "crash": 0, "hang": 0}
        details: dict = {}
        for path, d in zip(files[fmt], check_files(fmt, files[fmt], args.timeout), strict=True):
            counts[d["outcome"]] += 1
            name = str(path.relative_to(folders[0])) if len(folders) == 1 and folders[0].is_dir() else str(path)
            details[name] = d
            print(f"{fmt:5s} {d['outcome']:7s} {name}: {d['reason'][:300]}", flush=True)
            for w in d["warnings"]:
                print(f"      warning: {w[:300]}")
        result["formats"][fmt] = {**counts, "details": details}
    print()
    print(f"{'format':8s}{'files':>7s}{'agree':>7s}{'differ':>8s}{'error':>7s}{'crash':>7s}{'hang':>6s}")
    for fmt, r in result["formats"].items():
        print(f"{fmt:8s}{r['files']:7d}{r['agree']:7d}{r['differ']:8d}{r['error']:7d}{r['crash']:7d}{r['hang']:6d}")
    if args.json:
        print(json.dumps(result, default=float))
    return 0


if __name__ == "__main__":
    sys.exit(main())
