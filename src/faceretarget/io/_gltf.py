"""glTF 2.0 binary (``.glb``) export of a rig driven by weights: morph targets plus an animation.

What :func:`write_glb` writes
-----------------------------
* One node (``node_name``) with one mesh: the rig's neutral as a triangle list (polygons are fanned,
  :meth:`Mesh.triangles`), ``POSITION`` and ``NORMAL`` (float32) and, when the rig has UVs,
  ``TEXCOORD_0`` (``v`` flipped to glTF's top-left origin: ``1 - v``).
* Every key shape as a morph target with ``POSITION`` deltas (float32, with the accessor
  ``min``/``max`` the specification requires); target names in ``mesh.extras.targetNames`` (the
  convention Blender, three.js and Babylon.js read); default ``mesh.weights`` all zero.  Targets
  carry no normal deltas, so viewers shade every frame with the neutral's normals.
* One animation with one ``LINEAR`` sampler: input = ``times - times[0]`` (float32 seconds),
  output = the ``T * K`` weights frame after frame; one channel, path ``"weights"``, on the node.

Units: glTF is in metres, so positions and deltas are scaled by ``rig.mm_per_unit / 1000`` (a
centimetre rig is divided by 100).

Vertex order: OBJ stores UVs per face corner, glTF per vertex.  A vertex with several UVs (on a UV
seam) is split into one glTF vertex per distinct UV, duplicating its position, normal and morph
deltas.  The glTF vertices are ordered by source vertex (copies of one vertex adjacent), so the
order equals the rig's when there are no seams; otherwise :func:`glb_vertex_order` gives, for each
glTF vertex, the rig vertex it came from, and the file stores the same array as
``mesh.extras.sourceVertices``.

Head motion (:func:`write_glb_head`, or ``head=`` in :func:`write_glb`)
-----------------------------------------------------------------------
A node named ``head`` animated by its own ``rotation`` channel (unit quaternions ``x, y, z, w``,
``LINEAR``, which glTF viewers interpolate by slerp) and, when given, a ``translation`` channel
(metres), in the same animation as the face's weights.  With a face, the face node becomes a child
of the ``head`` node, so the face turns with the head; ``head_pivot`` (metres) puts the rotation
centre at the neck rather than at the rig's origin (the face node is offset by ``-head_pivot`` and
the head node sits at ``head_pivot + translation``).
"""

from __future__ import annotations

import functools
import json
import os
import struct
import warnings
from pathlib import Path

import numpy as np

from ..errors import FaceRetargetError, InputFileError, InvalidDataError, excerpt
from ..files import atomic_path, check_output_path
from ..headpose import HeadPose
from ..mesh import Mesh
from ..rig import Rig
from ._gltf_scene import read_gltf_character

__all__ = ["write_glb", "read_glb_weights", "read_glb_rig", "glb_vertex_order", "write_glb_head",
           "read_glb_head"]

_FLOAT, _USHORT, _UINT = 5126, 5123, 5125
_ARRAY_BUFFER, _ELEMENT_ARRAY_BUFFER = 34962, 34963
_GLB_MAGIC, _JSON, _BIN = 0x46546C67, 0x4E4F534A, 0x004E4942
_NP_OF = {_FLOAT: np.float32, _USHORT: np.uint16, _UINT: np.uint32, 5121: np.uint8, 5120: np.int8,
          5122: np.int16}
_NCOMP = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT4": 16}


def _split_seams(mesh: Mesh) -> tuple[np.ndarray, np.ndarray | None, np.ndarray]:
    """(src (V',), uvs (V', 2) or None, triangles (n, 3) in glTF vertex numbering)."""
    tri = mesh.triangles()
    V = mesh.n_vertices
    tuv = mesh.triangle_uv_indices() if mesh.uvs is not None else None
    if tuv is None:
        return np.arange(V), None, tri
    U1 = len(mesh.uvs) + 1
    corner_keys = tri.reshape(-1) * U1 + tuv.reshape(-1) + 1
    used = np.zeros(V, bool)
    used[tri.reshape(-1)] = True
    loose = np.flatnonzero(~used) * U1  # vertices no triangle uses keep a (0, 0) UV
    keys, inv = np.unique(np.concatenate([corner_keys, loose]), return_inverse=True)
    src = keys // U1
    uvi = keys % U1 - 1
    uv = np.where(uvi[:, None] >= 0, mesh.uvs[np.maximum(uvi, 0)], 0.0)
    return src, uv, inv[: corner_keys.size].reshape(-1, 3)


def glb_vertex_order(mesh: Mesh) -> np.ndarray:
    """For each vertex :func:`write_glb` writes, the index of the ``mesh`` vertex it copies.

    Returns
    -------
    (V',) int
        ``arange(V)`` when no vertex has several UVs.
    """
    return _split_seams(mesh)[0]


class _Builder:
    def __init__(self) -> None:
        self.chunks: list[bytes] = []
        self.size = 0
        self.views: list[dict] = []
        self.accessors: list[dict] = []

    def view(self, arr: np.ndarray, target: int | None = None) -> int:
        data = np.ascontiguousarray(arr).tobytes()
        pad = (-self.size) % 4
        if pad:
            self.chunks.append(b"\0" * pad)
            self.size += pad
        v = {"buffer": 0, "byteOffset": self.size, "byteLength": len(data)}
        if target is not None:
            v["target"] = target
        self.chunks.append(data)
        self.size += len(data)
        self.views.append(v)
        return len(self.views) - 1

    def accessor(self, arr: np.ndarray, type_: str, *, target: int | None = None,
                 minmax: bool = True) -> int:
        ctype = {np.dtype(np.float32): _FLOAT, np.dtype(np.uint16): _USHORT,
                 np.dtype(np.uint32): _UINT}[arr.dtype]
        n = _NCOMP[type_]
        flat = arr.reshape(-1, n)
        acc: dict = {"bufferView": self.view(flat, target), "componentType": ctype,
                     "count": int(flat.shape[0]), "type": type_}
        if minmax and flat.shape[0]:
            acc["min"] = [float(x) if ctype == _FLOAT else int(x) for x in flat.min(axis=0)]
            acc["max"] = [float(x) if ctype == _FLOAT else int(x) for x in flat.max(axis=0)]
        self.accessors.append(acc)
        return len(self.accessors) - 1


def _key_times(path, t: np.ndarray) -> np.ndarray:
    """Keyframe times relative to the first, as float32 seconds, strictly increasing (or an error)."""
    if not np.isfinite(t).all():
        raise InvalidDataError(f"{path}: times are not all finite")
    t32 = (t - t[0]).astype(np.float32)
    if t.size > 1 and not (np.diff(t32) > 0).all():
        k = int(np.flatnonzero(np.diff(t32) <= 0)[0]) + 1
        raise InvalidDataError(f"{path}: frame {k} time {t[k]:.6f} s does not increase after "
                               f"{t[k - 1]:.6f} s (in float32 seconds)")
    return t32


def write_glb(path: str | os.PathLike, rig: Rig, weights: np.ndarray, times: np.ndarray,
              names: list[str] | None = None, node_name: str = "face", *,
              animation_name: str = "take", head: HeadPose | None = None,
              head_pivot: tuple[float, float, float] | np.ndarray = (0.0, 0.0, 0.0)) -> Path:
    """Write the rig with its key shapes as morph targets, animated by ``weights``.

    Parameters
    ----------
    path : path-like
        Output ``.glb``.
    rig : Rig
        Neutral mesh and key shapes (any unit; written in metres).
    weights : (T, K) float
        Weights per frame: in the rig's shape order when ``names`` is None, otherwise the columns
        named by ``names`` (mapped with :meth:`Rig.map_weights`, which warns once about names the
        rig lacks).
    times : (T,) float
        Frame times in seconds, strictly increasing; written relative to ``times[0]``.
    names : list of str, optional
        Names of the columns of ``weights``.
    node_name : str
        Name of the glTF node carrying the mesh and animated by the animation.
    animation_name : str
        Name of the animation.
    head : HeadPose, optional
        Head motion per frame (:mod:`faceretarget.headpose`): adds a ``head`` node, parent of the
        face node, with a rotation channel (and a translation channel, metres, when the pose has
        one) in the same animation (module docstring).  Every frame needs a pose.
    head_pivot : 3 floats
        Rotation centre of the head in the rig's coordinates, metres.

    Returns
    -------
    Path
        ``path``.

    Raises
    ------
    InvalidDataError
        Wrong weight shape, non-finite weights, times that do not increase (also after rounding to
        float32), a rig without key shapes, or malformed head keyframes.
    OutputError
        The file cannot be written (nothing partial is left).
    """
    path = check_output_path(path)
    w, t = _checked_weights(path, rig, weights, times, names)
    t32 = _key_times(path, t)

    b = _Builder()
    src, primitive = _mesh_primitive(b, rig)
    t_acc = b.accessor(t32, "SCALAR")
    w_acc = b.accessor(w.astype(np.float32).reshape(-1), "SCALAR", minmax=False)

    head_keys = None if head is None else _head_keys(path, b, t.size, head, head_pivot)

    gltf = _face_document(b, rig, src, primitive, node_name, animation_name, t_acc, w_acc)
    if head_keys is not None:
        _add_head(gltf, head_keys, t_acc, child=0)
    return _write_glb_file(path, gltf, b)


def _checked_weights(path: Path, rig: Rig, weights: np.ndarray, times: np.ndarray,
                     names: list[str] | None) -> tuple[np.ndarray, np.ndarray]:
    """``weights`` as (T, K) in the rig's shape order and ``times`` as (T,), checked."""
    w = np.asarray(weights, dtype=np.float64)
    if w.ndim == 1:  # a single frame
        w = w[None]
    if names is not None:
        if w.shape[-1] != len(names):
            raise InvalidDataError(f"{path}: weights have {w.shape[-1]} columns for {len(names)} names")
        w = rig.map_weights(list(names), w, source=str(path))
    if rig.n_shapes == 0:
        raise InvalidDataError(f"{rig.name}: the rig has no key shapes to animate")
    t = np.asarray(times, dtype=np.float64).reshape(-1)
    if w.ndim != 2 or w.shape != (t.size, rig.n_shapes):
        raise InvalidDataError(f"{path}: weights must have shape ({t.size}, {rig.n_shapes}) for "
                               f"{t.size} times and {rig.n_shapes} shapes, got {w.shape}")
    if t.size == 0:
        raise InvalidDataError(f"{path}: no frames to write")
    if not np.isfinite(w).all():
        f, k = (int(x[0]) for x in np.nonzero(~np.isfinite(w)))
        raise InvalidDataError(f"{path}: frame {f} weight '{rig.names[k]}' is {w[f, k]}")
    return w, t


def _mesh_primitive(b: _Builder, rig: Rig) -> tuple[np.ndarray, dict]:
    """Store the neutral (in metres) and the morph targets in ``b``.

    Returns the source vertex of each glTF vertex (:func:`glb_vertex_order`) and the mesh primitive.
    """
    scale = rig.mm_per_unit / 1000.0
    mesh = rig.neutral
    src, uv, tri = _split_seams(mesh)
    pos = (mesh.vertices[src] * scale).astype(np.float32)
    nrm = mesh.vertex_normals()[src]
    zero = np.linalg.norm(nrm, axis=1) < 0.5
    nrm[zero] = (0.0, 0.0, 1.0)
    nrm = (nrm / np.linalg.norm(nrm, axis=1, keepdims=True)).astype(np.float32)

    points = len(tri) == 0                              # a point set (markers, landmarks): POINTS
    attrs = {"POSITION": b.accessor(pos, "VEC3", target=_ARRAY_BUFFER)}
    if not points:
        attrs["NORMAL"] = b.accessor(nrm, "VEC3", target=_ARRAY_BUFFER)
    if uv is not None:
        uv32 = np.stack([uv[:, 0], 1.0 - uv[:, 1]], axis=1).astype(np.float32)
        attrs["TEXCOORD_0"] = b.accessor(uv32, "VEC2", target=_ARRAY_BUFFER, minmax=False)
    targets = []
    for k in range(rig.n_shapes):
        d = (rig.deltas[k][src] * scale).astype(np.float32)
        targets.append({"POSITION": b.accessor(d, "VEC3", target=_ARRAY_BUFFER)})
    if points:                                          # glTF mode 0, no indices: every vertex a point
        return src, {"attributes": attrs, "mode": 0, "targets": targets}
    idx_dtype = np.uint16 if len(src) <= 65535 else np.uint32
    indices = b.accessor(tri.astype(idx_dtype).reshape(-1), "SCALAR", target=_ELEMENT_ARRAY_BUFFER,
                         minmax=False)
    return src, {"attributes": attrs, "indices": indices, "mode": 4, "targets": targets}


def _face_document(b: _Builder, rig: Rig, src: np.ndarray, primitive: dict, node_name: str,
                   animation_name: str, t_acc: int, w_acc: int) -> dict:
    """The glTF JSON of the face node, its mesh and its weight animation (buffer length set later)."""
    mesh = rig.neutral
    mesh_extras: dict = {"targetNames": list(rig.names)}
    if len(src) != mesh.n_vertices or not np.array_equal(src, np.arange(mesh.n_vertices)):
        mesh_extras["sourceVertices"] = src.tolist()
    return {
        "asset": {"version": "2.0", "generator": "faceretarget"},
        "extras": {"unit": "m", "sourceUnit": rig.unit, "rig": rig.name},
        "scene": 0,
        "scenes": [{"nodes": [0]}],
        "nodes": [{"name": node_name, "mesh": 0}],
        "meshes": [{
            "name": rig.name,
            "primitives": [primitive],
            "weights": [0.0] * rig.n_shapes,
            "extras": mesh_extras,
        }],
        "animations": [{
            "name": animation_name,
            "samplers": [{"input": t_acc, "output": w_acc, "interpolation": "LINEAR"}],
            "channels": [{"sampler": 0, "target": {"node": 0, "path": "weights"}}],
        }],
        "buffers": [{"byteLength": 0}],
        "bufferViews": b.views,
        "accessors": b.accessors,
    }


def _write_glb_file(path: Path, gltf: dict, b: _Builder) -> Path:
    pad = (-b.size) % 4
    bin_len = b.size + pad
    gltf["buffers"][0]["byteLength"] = b.size
    js = json.dumps(gltf, separators=(",", ":")).encode("utf-8")
    js += b" " * ((-len(js)) % 4)
    total = 12 + 8 + len(js) + 8 + bin_len
    with atomic_path(path) as tmp, open(tmp, "wb") as f:
        f.write(struct.pack("<III", _GLB_MAGIC, 2, total))
        f.write(struct.pack("<II", len(js), _JSON))
        f.write(js)
        f.write(struct.pack("<II", bin_len, _BIN))
        for c in b.chunks:
            f.write(c)
        f.write(b"\0" * pad)
    return path


def _head_arrays(path: Path, head: HeadPose, T: int) -> tuple[np.ndarray, np.ndarray | None]:
    """A writer's head pose, checked: quaternions ``(T, 4)`` x, y, z, w with w >= 0 and consecutive
    keys on the same hemisphere (so linear/slerp interpolation takes the short way), and the
    translation ``(T, 3)`` metres or None (glTF, USD)."""
    if not isinstance(head, HeadPose):
        raise InvalidDataError(f"{path}: head must be a HeadPose, got {type(head).__name__}")
    if head.n_frames != T:
        raise InvalidDataError(f"{path}: the head pose has {head.n_frames} frames for {T} times")
    if not head.valid.all():
        f = int(np.flatnonzero(~head.valid)[0])
        raise InvalidDataError(f"{path}: frame {f} has no head pose (fill or drop it first)")
    q = head.as_quat()
    q = q * np.where(q[:, 3:] < 0, -1.0, 1.0)
    flip = np.cumprod(np.where(np.r_[1.0, np.sign((q[1:] * q[:-1]).sum(axis=1))] < 0, -1.0, 1.0))
    q = q * flip[:, None]
    tr = None
    if head.translation is not None:
        tr = np.asarray(head.translation, dtype=np.float64)
        if not np.isfinite(tr).all():
            f = int(np.flatnonzero(~np.isfinite(tr).all(axis=1))[0])
            raise InvalidDataError(f"{path}: frame {f} head translation is not finite")
    return q, tr


def _head_keys(path: Path, b: _Builder, T: int, head: HeadPose, pivot) -> dict:
    """Check head keyframes and store them: accessor ids of rotation (and translation)."""
    q, tr = _head_arrays(path, head, T)
    pv = np.asarray(pivot, dtype=np.float64).reshape(3)
    keys = {"rotation": b.accessor(q.astype(np.float32), "VEC4", minmax=False), "pivot": pv}
    if tr is not None:
        keys["translation"] = b.accessor((tr + pv).astype(np.float32), "VEC3", minmax=False)
    return keys


def _add_head(gltf: dict, keys: dict, t_acc: int, child: int | None) -> None:
    """Add the ``head`` node (parent of node ``child``) with its channels in animation 0."""
    nodes = gltf["nodes"]
    head: dict = {"name": "head"}
    pv = keys["pivot"]
    if np.any(pv != 0):
        head["translation"] = [float(x) for x in pv]
    if child is not None:
        head["children"] = [child]
        if np.any(pv != 0):
            nodes[child]["translation"] = [float(-x) for x in pv]
    nodes.append(head)
    h = len(nodes) - 1
    gltf["scenes"][0]["nodes"] = [h]
    anim = gltf["animations"][0]
    for p in ("rotation", "translation"):
        if p in keys:
            anim["samplers"].append({"input": t_acc, "output": keys[p], "interpolation": "LINEAR"})
            anim["channels"].append({"sampler": len(anim["samplers"]) - 1, "target": {"node": h, "path": p}})


def write_glb_head(path: str | os.PathLike, times: np.ndarray, head: HeadPose, *, animation_name: str = "head",
                   pivot: tuple[float, float, float] | np.ndarray = (0.0, 0.0, 0.0)) -> Path:
    """Write a ``.glb`` holding only a ``head`` node animated by rotation (and translation) keys.

    Parameters
    ----------
    path : path-like
        Output ``.glb``.
    times : (T,) float
        Keyframe times in seconds, strictly increasing; written relative to ``times[0]``.
    head : HeadPose
        The head's rotation per frame (and translation in metres), in glTF's axes (+Y up, +Z
        forward; :mod:`faceretarget.headpose`).
    animation_name : str
    pivot : 3 floats
        Rest position of the head node (metres), added to every translation key.

    Returns
    -------
    Path
        ``path``.
    """
    path = check_output_path(path)
    t = np.asarray(times, dtype=np.float64).reshape(-1)
    if t.size == 0:
        raise InvalidDataError(f"{path}: no frames to write")
    t32 = _key_times(path, t)
    b = _Builder()
    t_acc = b.accessor(t32, "SCALAR")
    keys = _head_keys(path, b, t.size, head, pivot)
    gltf = {
        "asset": {"version": "2.0", "generator": "faceretarget"},
        "extras": {"unit": "m"},
        "scene": 0,
        "scenes": [{"nodes": []}],
        "nodes": [],
        "animations": [{"name": animation_name, "samplers": [], "channels": []}],
        "buffers": [{"byteLength": 0}],
        "bufferViews": b.views,
        "accessors": b.accessors,
    }
    _add_head(gltf, keys, t_acc, child=None)
    return _write_glb_file(path, gltf, b)


def _glb_reader(fn):
    """A ``.glb`` reader whose malformed input (a JSON key, index or type that is not what glTF says,
    an accessor outside the buffer) raises :class:`InputFileError` naming the file, never a KeyError."""
    @functools.wraps(fn)
    def read(path, *args, **kwargs):
        try:
            return fn(path, *args, **kwargs)
        except FaceRetargetError as e:
            if str(path) in str(e):
                raise
            raise InputFileError(f"{path}: {e}") from e
        except (KeyError, IndexError, TypeError, ValueError, AttributeError, struct.error, OverflowError) as e:
            raise InputFileError(f"{path}: malformed glTF ({type(e).__name__}: {excerpt(e, 80)})") from e
    return read


@_glb_reader
def read_glb_head(path: str | os.PathLike, node: str = "head") -> tuple[np.ndarray, HeadPose]:
    """Read the rotation (and translation) keyframes of node ``node`` of a ``.glb``.

    Returns
    -------
    times : (T,) float64
    head : HeadPose
        The rotations and, with a translation channel, the translation in metres (including the
        node's rest position).
    """
    path = Path(path)
    gltf, binchunk = _load_glb(path)
    ids = [i for i, n in enumerate(gltf.get("nodes", [])) if n.get("name") == node]
    if not ids:
        raise InputFileError(f"{path}: no node named '{node}'")
    found: dict[str, tuple[np.ndarray, np.ndarray]] = {}
    for anim in gltf.get("animations", []):
        for ch in anim.get("channels", []):
            tg = ch.get("target", {})
            if tg.get("node") == ids[0] and tg.get("path") in ("rotation", "translation"):
                s = anim["samplers"][ch["sampler"]]
                found[tg["path"]] = (_accessor(path, gltf, binchunk, s["input"]).astype(np.float64).reshape(-1),
                                     _accessor(path, gltf, binchunk, s["output"]).astype(np.float64))
    if "rotation" not in found:
        raise InputFileError(f"{path}: node '{node}' has no rotation animation")
    t, q = found["rotation"]
    tr = found["translation"][1] if "translation" in found else None
    _check_keyframes(path, t, q, 4, "rotation")
    if tr is not None:
        _check_keyframes(path, found["translation"][0], tr, 3, "translation")
        if len(tr) != len(q):
            raise InputFileError(f"{path}: {len(tr)} translation and {len(q)} rotation keyframes")
    return t, HeadPose(q.reshape(-1, 4), tr, source=str(path))


def _check_keyframes(path: Path, t: np.ndarray, v: np.ndarray, width: int, what: str) -> None:
    """Keyframe times finite and increasing, ``width`` finite values per keyframe (glTF has no "missing")."""
    if v.size != t.size * width or t.size == 0:
        raise InputFileError(f"{path}: {what} output has {v.size} values for {t.size} keyframes")
    if not (np.isfinite(t).all() and np.isfinite(v).all()):
        raise InputFileError(f"{path}: {what} keyframes hold NaN or infinite values")
    if (np.diff(t) <= 0).any():
        raise InputFileError(f"{path}: {what} keyframe times do not increase")


# ---------------------------------------------------------------------------------------- reading
def _load_glb(path: Path) -> tuple[dict, bytes]:
    if not path.is_file():
        raise InputFileError(f"{path}: file not found")
    data = path.read_bytes()
    if len(data) < 20:
        raise InputFileError(f"{path}: too short to be a .glb file")
    magic, version, total = struct.unpack_from("<III", data, 0)
    if magic != _GLB_MAGIC or version != 2:
        raise InputFileError(f"{path}: not a glTF 2.0 binary file")
    if total > len(data):
        raise InputFileError(f"{path}: truncated ({len(data)} of {total} bytes)")
    off, gltf, binchunk = 12, None, b""
    while off + 8 <= total:
        n, kind = struct.unpack_from("<II", data, off)
        body = data[off + 8: off + 8 + n]
        if kind == _JSON:
            try:
                gltf = json.loads(body.decode("utf-8"))
            except ValueError as e:  # UnicodeDecodeError and JSONDecodeError are ValueErrors
                raise InputFileError(f"{path}: the JSON chunk is not UTF-8 JSON ({excerpt(e, 80)})") from e
            if not isinstance(gltf, dict):
                raise InputFileError(f"{path}: the JSON chunk is not a glTF object")
        elif kind == _BIN:
            binchunk = body
        off += 8 + n
    if gltf is None:
        raise InputFileError(f"{path}: no JSON chunk")
    return gltf, binchunk


def _accessor(path: Path, gltf: dict, binchunk: bytes, i: int) -> np.ndarray:
    if not isinstance(i, int) or i < 0:
        raise InputFileError(f"{path}: accessor index {excerpt(i)} is not a glTF index")
    acc = gltf["accessors"][i]
    n = _NCOMP[acc["type"]]
    dt = np.dtype(_NP_OF[acc["componentType"]])
    count = acc["count"]
    if not isinstance(count, int) or not 0 <= count <= 1 << 26:
        raise InputFileError(f"{path}: accessor {i} has count {excerpt(count)}")
    if "bufferView" not in acc:
        return np.zeros((count, n), dt)
    view = gltf["bufferViews"][acc["bufferView"]]
    if view.get("buffer", 0) != 0:
        raise InputFileError(f"{path}: external buffers are not supported")
    start = view.get("byteOffset", 0) + acc.get("byteOffset", 0)
    stride = view.get("byteStride", n * dt.itemsize)
    if not (isinstance(start, int) and isinstance(stride, int) and start >= 0 and stride >= n * dt.itemsize
            and start + max(count - 1, 0) * stride + n * dt.itemsize * (count > 0) <= len(binchunk)):
        raise InputFileError(f"{path}: accessor {i} ({count} x {n} {dt}) lies outside the binary chunk "
                             f"of {len(binchunk)} bytes")
    arr = np.ndarray((count, n), dt, buffer=binchunk, offset=start, strides=(stride, dt.itemsize)).copy()
    if dt.kind == "f":
        with np.errstate(invalid="ignore"):  # a signalling NaN is reported by the callers' checks
            arr = arr.astype(np.float64)
    if acc.get("normalized") and dt.kind in "iu":
        arr = arr.astype(np.float64) / np.iinfo(dt).max
    return arr


@_glb_reader
def read_glb_weights(path: str | os.PathLike) -> tuple[list[str], np.ndarray, np.ndarray]:
    """Read the morph-target weight animation of a ``.glb`` (the first ``"weights"`` channel).

    Returns
    -------
    names : list of str
        Morph target names (``mesh.extras.targetNames``; ``target0``... when absent).
    times : (T,) float64
        Keyframe times in seconds.
    weights : (T, K) float64
    """
    path = Path(path)
    gltf, binchunk = _load_glb(path)
    for anim in gltf.get("animations", []):
        for ch in anim.get("channels", []):
            if ch.get("target", {}).get("path") == "weights":
                node = gltf["nodes"][ch["target"]["node"]]
                mesh = gltf["meshes"][node["mesh"]]
                K = len(mesh["primitives"][0].get("targets", []))
                names = mesh.get("extras", {}).get("targetNames") or [f"target{k}" for k in range(K)]
                s = anim["samplers"][ch["sampler"]]
                t = _accessor(path, gltf, binchunk, s["input"]).astype(np.float64).reshape(-1)
                w = _accessor(path, gltf, binchunk, s["output"]).astype(np.float64).reshape(-1)
                if w.size != t.size * K:
                    raise InputFileError(f"{path}: weight output has {w.size} values for {t.size} "
                                         f"keyframes of {K} targets")
                _check_keyframes(path, t, w, K, "weight")
                if not isinstance(names, list) or len(names) != K:
                    raise InputFileError(f"{path}: mesh.extras.targetNames does not name the {K} morph targets")
                return [str(n) for n in names], t, w.reshape(t.size, K)
    raise InputFileError(f"{path}: no morph-target weight animation found")


#: What :func:`read_glb_rig` warns (it is kept for old callers).
_GLB_RIG_DEPRECATED = ("read_glb_rig is deprecated: call faceretarget.io.read_character(path) and use its primary "
                       "face mesh, character.meshes[character.primary] (faceretarget.character.face_rig(character) "
                       "gives the rig the solvers use); read_glb_rig returns that mesh as a Rig")


def read_glb_rig(path: str | os.PathLike) -> Rig:
    """The face mesh of a ``.glb`` with its morph targets as a :class:`Rig` (unit ``"m"``).  Deprecated:
    call :func:`~faceretarget.io.read_character` (this warns a ``DeprecationWarning`` saying so).

    A thin call of the character reader (:func:`~faceretarget.io.read_character`'s glTF route): the
    character's primary face mesh (:attr:`Character.primary <faceretarget.character.Character.primary>`,
    the mesh whose shapes move the face most; without face shapes, :meth:`Character.head_mesh
    <faceretarget.character.Character.head_mesh>`), its primitives joined, at rest in the file's world
    frame in metres, with every morph target of that mesh under its exact name (``keep_names``; a
    repeated name gets ``.2``, ``.3`` ...), UVs flipped back to OBJ's bottom-left origin.  Compressed and
    quantized files are decoded as :func:`~faceretarget.io.read_gltf_character` decodes them.

    A file :func:`write_glb` wrote reads back with its vertices in the file's order (the rig's, seams
    split: :func:`glb_vertex_order`) and its shapes in the rig's order.  A file whose meshes are all
    point sets (the ``POINTS`` primitive :func:`write_glb` writes for marker keys, which the character
    reader leaves out) gives its first mesh's points, without faces.
    """
    warnings.warn(_GLB_RIG_DEPRECATED, DeprecationWarning, stacklevel=2)
    path = Path(path)
    character = read_gltf_character(path)
    if not character.meshes:
        return _read_point_set(path)
    face = character.meshes[character.head_mesh()]
    m = face.mesh
    uvs = None if m.uvs is None else np.stack([m.uvs[:, 0], 1.0 - m.uvs[:, 1]], axis=1)
    mesh = Mesh(m.vertices, m.face_counts, m.face_indices, uvs, m.face_uv_indices if uvs is not None else None,
                name=face.name)
    names = _unique(face.shape_names)
    return Rig(mesh, names, face.deltas.astype(np.float64), unit="m", source_names=list(face.shape_names),
               name=face.name, keep_names=True)


def _unique(names: list[str]) -> list[str]:
    """``names`` with a repeated one suffixed ``.2``, ``.3`` ... (a :class:`Rig` keeps unique names)."""
    seen: set[str] = set()
    out = []
    for n in names:
        base, k = n, 2
        while n in seen:
            n = f"{base}.{k}"
            k += 1
        seen.add(n)
        out.append(n)
    return out


@_glb_reader
def _read_point_set(path: Path) -> Rig:
    """The first mesh's first primitive of a ``.glb`` whose meshes are all point sets (glTF mode 0), as a
    :class:`Rig` without faces (unit ``"m"``, vertices and targets as stored)."""
    gltf, binchunk = _load_glb(path)
    if not gltf.get("meshes"):
        raise InputFileError(f"{path}: no mesh")
    m = gltf["meshes"][0]
    prim = m["primitives"][0]
    mode = prim.get("mode", 4)
    if mode != 0:
        raise InputFileError(f"{path}: no triangle mesh or point set (the first primitive has mode {mode})")
    pos = _accessor(path, gltf, binchunk, prim["attributes"]["POSITION"]).astype(np.float64)
    mesh = Mesh(pos, name=path.name)
    targets = prim.get("targets", [])
    names = m.get("extras", {}).get("targetNames") or [f"target{k}" for k in range(len(targets))]
    if not isinstance(names, list) or len(names) != len(targets):
        raise InputFileError(f"{path}: mesh.extras.targetNames does not name the {len(targets)} morph targets")
    deltas = np.stack([_accessor(path, gltf, binchunk, tg["POSITION"]).astype(np.float64)
                       for tg in targets]) if targets else np.zeros((0, len(pos), 3))
    return Rig(mesh, list(names), deltas, unit="m", name=m.get("name", path.stem))
