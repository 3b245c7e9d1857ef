"""ufbx's view of an FBX take, in a child process (ufbx 0.0.5's binding crashes when its wrappers are collected).

``python _fbx_ufbx_child.py SRC OUT TIMES.npy HEAD RESULT.pickle`` pickles: per mesh node of ``SRC`` and
``OUT`` (vertex count, face count, blend channel names), the largest vertex difference between them, the
blend channel names of ``OUT`` and their weights evaluated at each time (``(T, K)``), the world rotation of the
node ``HEAD`` at each time (``(T, 3, 3)``) and the first stack's name and time span.  Then it leaves without
cleaning up.
"""

from __future__ import annotations

import gc
import os
import pickle
import sys

import numpy as np
import ufbx


def _load(path: str):
    axes = ufbx.CoordinateAxes(ufbx.CoordinateAxis.POSITIVE_X, ufbx.CoordinateAxis.POSITIVE_Y,
                               ufbx.CoordinateAxis.POSITIVE_Z)
    return ufbx.load_file(path, target_axes=axes, target_unit_meters=1.0, load_external_files=False,
                          ignore_missing_external_files=True)


def _mat(m) -> np.ndarray:
    A = np.eye(4)
    A[:3, :] = np.array([list(m.c0), list(m.c1), list(m.c2), list(m.c3)]).T
    return A


def _meshes(path: str, keep: list) -> dict:
    s = _load(path)
    keep.append(s)
    out = {}
    for i in range(len(s.nodes)):
        n = s.nodes[i]
        m = n.mesh
        keep += [n, m]
        if m is None:
            continue
        names = []
        bds = m.blend_deformers
        keep.append(bds)
        for b in range(len(bds)):
            chs = bds[b].channels
            keep.append(chs)
            names += [chs[c].name for c in range(len(chs))]
        out[n.name] = (m.num_vertices, m.num_faces, names, np.asarray(m.vertices, dtype=np.float64).copy())
    return out


def _evaluate(path: str, times: np.ndarray, head: str, keep: list):
    s = _load(path)
    stack = s.anim_stacks[0]
    anim = stack.anim
    chans = s.blend_channels
    keep += [s, stack, anim, chans]
    names = [chans[i].name for i in range(len(chans))]
    W = np.zeros((len(times), len(names)))
    R = np.zeros((len(times), 3, 3))
    for f, t in enumerate(times):
        e = ufbx.evaluate_scene(s, anim, float(t))
        ec = e.blend_channels
        h = e.find_node(head)
        keep += [e, ec, h]
        W[f] = [ec[i].weight for i in range(len(names))]
        R[f] = _mat(h.node_to_world)[:3, :3]
    return names, W, R, (stack.name, stack.time_begin, stack.time_end)


def main(src: str, out: str, times: str, head: str, result: str) -> None:
    gc.disable()
    keep: list = []
    a, b = _meshes(src, keep), _meshes(out, keep)
    moved = max((float(np.abs(a[n][3] - b[n][3]).max()) for n in a if n in b), default=np.inf)
    names, W, R, stack = _evaluate(out, np.load(times), head, keep)
    with open(result, "wb") as f:
        pickle.dump(({n: v[:3] for n, v in a.items()}, {n: v[:3] for n, v in b.items()}, moved, names, W, R, stack), f)
        f.flush()
        os.fsync(f.fileno())
    os._exit(0)


if __name__ == "__main__":
    main(*sys.argv[1:6])
