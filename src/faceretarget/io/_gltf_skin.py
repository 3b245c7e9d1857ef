"""glTF 2.0 binary (``.glb``) skeletons: a skin with joint rotation / translation animation.

What :func:`write_glb_skeleton` writes
--------------------------------------
* One node per joint (named as the joints), children as the hierarchy; each node's rest transform
  is its offset (``translation``, metres) and no rotation: the rest pose of a BVH, every joint frame
  parallel to the world's.
* A ``skin`` over those nodes with ``inverseBindMatrices`` (the inverse of each joint's rest world
  transform) and, so viewers draw the skeleton, a mesh of one thin double pyramid per bone (from a
  joint to each child, or to its end site), every vertex bound to the bone's parent joint with
  weight 1 (``JOINTS_0`` / ``WEIGHTS_0``), placed at the scene root as glTF asks of skinned meshes.
* One animation: a ``rotation`` channel (unit quaternions ``x, y, z, w``, ``LINEAR``, consecutive
  keys on one hemisphere) for every joint and a ``translation`` channel for the joints whose
  translation moves (the root's, position channels), on the same time keys (``times - times[0]``,
  float32 seconds).

Lengths are scaled by ``scale`` (metres per file unit; BVH files are usually in centimetres).
:func:`read_glb_skeleton` reads such a file back (any glTF with a skin: the joints' rest
translations and their animated rotations and translations, sampled at the rotation keys).
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import InputFileError, InvalidDataError
from ..files import check_output_path
from ._gltf import _ARRAY_BUFFER, _accessor, _Builder, _glb_reader, _key_times, _load_glb, _write_glb_file

__all__ = ["GlbSkeleton", "write_glb_skeleton", "read_glb_skeleton", "glb_skin_and_nodes"]


@dataclass(eq=False)
class GlbSkeleton:
    """A skeleton and its joint animation as :func:`read_glb_skeleton` reads it.

    Attributes
    ----------
    names : list of str
    parents : (J,) int
        Parent joint index, -1 for a root.
    rest : (J, 3) float
        Each joint's rest translation in its parent's frame, metres.
    times : (T,) float
    rotations : (T, J, 4) float
        Local rotations, quaternions ``x, y, z, w`` (the rest rotation where not animated).
    translations : (T, J, 3) float
        Local translations, metres (the rest translation where not animated).
    rest_rotations : (J, 4) float or None
        Each joint node's own rotation (quaternion ``x, y, z, w``; identity when None).
    """

    names: list[str]
    parents: np.ndarray
    rest: np.ndarray
    times: np.ndarray
    rotations: np.ndarray
    translations: np.ndarray
    rest_rotations: np.ndarray | None = None


def _bone_mesh(world: np.ndarray, parents: np.ndarray, ends: list[np.ndarray | None], radius: float
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Positions (n, 3), triangles (m, 3) and the joint of each vertex for double pyramids along the bones."""
    pos, tri, joint = [], [], []
    bones = [(int(p), world[int(p)], world[i]) for i, p in enumerate(parents) if p >= 0]
    bones += [(i, world[i], world[i] + e) for i, e in enumerate(ends) if e is not None]
    for j, a, b in bones:
        d = b - a
        length = float(np.linalg.norm(d))
        if length <= 1e-9:
            continue
        u = d / length
        h = np.cross(u, [1.0, 0.0, 0.0] if abs(u[0]) < 0.9 else [0.0, 1.0, 0.0])
        h /= np.linalg.norm(h)
        k = np.cross(u, h)
        r = min(radius, 0.15 * length)
        mid = a + 0.2 * d
        ring = [mid + r * (np.cos(t) * h + np.sin(t) * k) for t in (0.0, np.pi / 2, np.pi, 1.5 * np.pi)]
        base = len(pos)
        pos.extend([a, *ring, b])
        for n in range(4):
            r0, r1 = base + 1 + n, base + 1 + (n + 1) % 4
            tri.append((base, r1, r0))
            tri.append((base + 5, r0, r1))
        joint.extend([j] * 6)
    if not pos:                                          # no bone to draw: a small diamond at the root
        c = world[0]
        pos = [c + radius * np.array(v) for v in ((1, 0, 0), (-1, 0, 0), (0, 1, 0), (0, -1, 0), (0, 0, 1), (0, 0, -1))]
        tri = [(0, 2, 4), (2, 1, 4), (1, 3, 4), (3, 0, 4), (2, 0, 5), (1, 2, 5), (3, 1, 5), (0, 3, 5)]
        joint = [0] * 6
    return np.asarray(pos, dtype=np.float64), np.asarray(tri, dtype=np.int64), np.asarray(joint, dtype=np.int64)


def write_glb_skeleton(path: str | os.PathLike, names: list[str], parents, offsets: np.ndarray,
                       rotations: np.ndarray, translations: np.ndarray, times: np.ndarray, *,
                       scale: float = 0.01, end_sites: list[np.ndarray | None] | None = None,
                       animation_name: str = "take") -> Path:
    """Write a skeleton and its joint animation as a skinned ``.glb`` (module docstring).

    Parameters
    ----------
    path : path-like
        Output ``.glb``.
    names : list of str
        ``J`` joint names.
    parents : (J,) int
        Parent index of each joint (-1 for a root), parents before their children.
    offsets : (J, 3) float
        Rest translation of each joint in its parent's frame (the BVH ``OFFSET``), file units.
    rotations : (T, J, 4) float
        Local rotations per frame, quaternions ``x, y, z, w``.
    translations : (T, J, 3) float
        Local translations per frame (offset plus position channels), file units.
    times : (T,) float
        Seconds, strictly increasing; written relative to ``times[0]``.
    scale : float
        Metres per file unit (0.01 for centimetres).
    end_sites : list of (3,) float or None, optional
        Each joint's BVH end-site offset (drawn as a bone).

    Returns
    -------
    Path
    """
    path = check_output_path(path)
    par = np.asarray(parents, dtype=np.int64).reshape(-1)
    J = len(names)
    off = np.asarray(offsets, dtype=np.float64)
    q = np.asarray(rotations, dtype=np.float64)
    tr = np.asarray(translations, dtype=np.float64)
    t = np.asarray(times, dtype=np.float64).reshape(-1)
    T = t.size
    if par.shape != (J,) or off.shape != (J, 3) or q.shape != (T, J, 4) or tr.shape != (T, J, 3) or T == 0:
        raise InvalidDataError(f"{path}: a skeleton of {J} joints and {T} frames needs parents ({J},), offsets "
                               f"({J}, 3), rotations ({T}, {J}, 4) and translations ({T}, {J}, 3); got {par.shape}, "
                               f"{off.shape}, {q.shape}, {tr.shape}")
    if any(not (p < i) for i, p in enumerate(par)):
        raise InvalidDataError(f"{path}: every joint's parent must come before it")
    for what, a in (("offsets", off), ("rotations", q), ("translations", tr)):
        if not np.isfinite(a).all():
            raise InvalidDataError(f"{path}: the {what} hold a non-finite value; nothing written")
    if not (np.isfinite(scale) and scale > 0):
        raise InvalidDataError(f"{path}: scale must be a positive number of metres per unit, got {scale}")
    t32 = _key_times(path, t)
    # rest pose (metres), world positions of the joints
    rest = off * scale
    world = np.zeros((J, 3))
    for i in range(J):
        world[i] = rest[i] + (world[par[i]] if par[i] >= 0 else 0.0)
    ends = [None if end_sites is None or end_sites[i] is None else np.asarray(end_sites[i], np.float64) * scale
            for i in range(J)]
    size = float(np.ptp(world, axis=0).max()) if J > 1 else 0.1
    pos, tri, joint = _bone_mesh(world, par, ends, radius=max(0.004 * size, 1e-4))
    # keyframes: unit quaternions, one hemisphere per joint track (linear interpolation the short way)
    qn = q / np.linalg.norm(q, axis=2, keepdims=True)
    qn *= np.where(qn[..., 3:] < 0, -1.0, 1.0)
    if T > 1:
        flip = np.cumprod(np.where(np.sign((qn[1:] * qn[:-1]).sum(axis=2)) < 0, -1.0, 1.0), axis=0)
        qn[1:] *= flip[..., None]
    b = _Builder()
    acc_pos = b.accessor(pos.astype(np.float32), "VEC3", target=_ARRAY_BUFFER)
    joints4 = np.zeros((len(pos), 4), np.uint16)
    joints4[:, 0] = joint
    weights4 = np.zeros((len(pos), 4), np.float32)
    weights4[:, 0] = 1.0
    acc_j = b.accessor(joints4, "VEC4", target=_ARRAY_BUFFER, minmax=False)
    acc_w = b.accessor(weights4, "VEC4", target=_ARRAY_BUFFER, minmax=False)
    idx_dtype = np.uint16 if len(pos) <= 65535 else np.uint32
    acc_i = b.accessor(tri.astype(idx_dtype).reshape(-1), "SCALAR", target=34963, minmax=False)
    ibm = np.zeros((J, 4, 4), np.float32)
    ibm[:] = np.eye(4, dtype=np.float32)
    ibm[:, 3, :3] = -world                        # column-major: the translation is the last column
    acc_ibm = b.accessor(ibm.reshape(J, 16), "MAT4", minmax=False)
    t_acc = b.accessor(t32, "SCALAR")
    nodes: list[dict] = []
    for i in range(J):
        node: dict = {"name": str(names[i])}
        if np.any(rest[i] != 0):
            node["translation"] = [float(x) for x in rest[i]]
        kids = [int(c) for c in np.flatnonzero(par == i)]
        if kids:
            node["children"] = kids
        nodes.append(node)
    samplers, channels = [], []
    for i in range(J):
        acc = b.accessor(qn[:, i].astype(np.float32), "VEC4", minmax=False)
        samplers.append({"input": t_acc, "output": acc, "interpolation": "LINEAR"})
        channels.append({"sampler": len(samplers) - 1, "target": {"node": i, "path": "rotation"}})
        tm = tr[:, i] * scale
        if np.abs(tm - rest[i]).max() > 0:
            acc = b.accessor(tm.astype(np.float32), "VEC3", minmax=False)
            samplers.append({"input": t_acc, "output": acc, "interpolation": "LINEAR"})
            channels.append({"sampler": len(samplers) - 1, "target": {"node": i, "path": "translation"}})
    roots = [i for i in range(J) if par[i] < 0]
    nodes.append({"name": "skeleton_mesh", "mesh": 0, "skin": 0})
    gltf = {
        "asset": {"version": "2.0", "generator": "faceretarget"},
        "extras": {"unit": "m"},
        "scene": 0,
        "scenes": [{"nodes": roots + [J]}],
        "nodes": nodes,
        "meshes": [{"name": "bones", "primitives": [{"attributes": {"POSITION": acc_pos, "JOINTS_0": acc_j,
                                                                     "WEIGHTS_0": acc_w},
                                                      "indices": acc_i, "mode": 4}]}],
        "skins": [{"name": "skeleton", "joints": list(range(J)), "inverseBindMatrices": acc_ibm,
                   "skeleton": roots[0]}],
        "animations": [{"name": animation_name, "samplers": samplers, "channels": channels}],
        "buffers": [{"byteLength": 0}],
        "bufferViews": b.views,
        "accessors": b.accessors,
    }
    return _write_glb_file(path, gltf, b)


@_glb_reader
def read_glb_skeleton(path: str | os.PathLike) -> GlbSkeleton:
    """Read the first skin of a ``.glb``: its joints, their rest translations and their animation.

    Channels are sampled at the keys of the first joint rotation channel (every channel of a file
    :func:`write_glb_skeleton` wrote shares them); joints without a channel keep their rest transform.

    Raises
    ------
    InputFileError
        No skin, no animated joint, a joint whose parent is not a joint of the skin, or channels
        with other keys than the rotation keys.
    """
    path = Path(path)
    gltf, binchunk = _load_glb(path)
    skins = gltf.get("skins") or []
    if not skins:
        raise InputFileError(f"{path}: no skin (skeleton) in the file")
    joints = [int(j) for j in skins[0]["joints"]]
    nodes = gltf["nodes"]
    pos_of = {n: i for i, n in enumerate(joints)}
    parents = np.full(len(joints), -1)
    for n in joints:
        for c in nodes[n].get("children", []):
            if c in pos_of:
                parents[pos_of[c]] = pos_of[n]
    rest = np.array([nodes[n].get("translation", [0.0, 0.0, 0.0]) for n in joints], dtype=np.float64)
    rest_q = np.array([nodes[n].get("rotation", [0.0, 0.0, 0.0, 1.0]) for n in joints], dtype=np.float64)
    chans: dict[tuple[int, str], tuple[np.ndarray, np.ndarray]] = {}
    for anim in (gltf.get("animations") or [])[:1]:
        for ch in anim.get("channels", []):
            tg = ch.get("target", {})
            if tg.get("node") in pos_of and tg.get("path") in ("rotation", "translation"):
                s = anim["samplers"][ch["sampler"]]
                tt = _accessor(path, gltf, binchunk, s["input"]).reshape(-1)
                v = _accessor(path, gltf, binchunk, s["output"])
                chans[(pos_of[tg["node"]], tg["path"])] = (tt, v)
    rot_keys = [v for (j, p), v in chans.items() if p == "rotation"]
    if not rot_keys:
        raise InputFileError(f"{path}: no joint rotation animation")
    times = rot_keys[0][0]
    T, J = len(times), len(joints)
    q = np.broadcast_to(rest_q, (T, J, 4)).copy()
    tr = np.broadcast_to(rest, (T, J, 3)).copy()
    for (j, p), (tt, v) in chans.items():
        if len(tt) != T or not np.allclose(tt, times):
            raise InputFileError(f"{path}: the {p} channel of joint '{nodes[joints[j]].get('name', j)}' has other "
                                 "keyframe times than the rotations")
        if p == "rotation":
            q[:, j] = v.reshape(T, 4)
        else:
            tr[:, j] = v.reshape(T, 3)
    if not (np.isfinite(q).all() and np.isfinite(tr).all() and np.isfinite(times).all()):
        raise InputFileError(f"{path}: the joint animation holds non-finite values")
    names = [str(nodes[n].get("name", f"joint{n}")) for n in joints]
    return GlbSkeleton(names, parents, rest, times.astype(np.float64), q, tr, rest_q)


@_glb_reader
def glb_skin_and_nodes(path: str | os.PathLike) -> tuple[bool, list[str]]:
    """Whether a ``.glb`` has a skin, and the names of its nodes (``""`` for an unnamed one)."""
    gltf, _ = _load_glb(Path(path))
    names = [str(n.get("name", "")) if isinstance(n, dict) else "" for n in gltf.get("nodes", []) or []]
    return bool(gltf.get("skins")), names
