"""Read any take and write any animation, choosing the format from the path.

==================== ==================================== =========================================
path                 :func:`read_performance`             :func:`write_animation`
==================== ==================================== =========================================
``*.csv``            Live Link Face weights               Live Link Face weights
``*.npz``            vertices, or weights + names         vertices (evaluated from rig + weights)
``*.glb``            weight animation (morph targets)     rig + weight animation
``*.obj``            one frame                            --
folder / no suffix   OBJ sequence                         OBJ sequence (``frame_00000.obj``...)
==================== ==================================== =========================================
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from ..errors import InputFileError, InvalidDataError, OutputError
from ..files import check_output_path
from ..headpose import HeadPose
from ..mesh import Mesh
from ..performance import Performance
from ..rig import Rig, RigFrames
from ._gltf import read_glb_weights, write_glb
from ._livelinkface import read_livelinkface, write_livelinkface
from ._npz import read_npz_performance, write_npz
from ._obj import read_obj, read_obj_sequence, write_obj_sequence

__all__ = ["read_performance", "write_animation", "READ_FORMATS", "WRITE_FORMATS"]

READ_FORMATS = (".csv", ".npz", ".glb", ".obj", "folder")
WRITE_FORMATS = (".glb", ".npz", ".csv", "folder")


def read_performance(path: str | os.PathLike, fps: float | None = None) -> Performance:
    """Read a take, choosing the reader from the path.

    Parameters
    ----------
    path : path-like
        ``.csv`` (Live Link Face), ``.c3d`` (optical markers), ``.npz`` (:func:`~faceretarget.io.npz.read_npz_performance`),
        ``.glb`` (morph-target weight animation), ``.obj`` (a single frame at time 0) or a folder of
        OBJ frames (:func:`~faceretarget.io.obj.read_obj_sequence`).
    fps : float, optional
        Frame rate for formats without times (OBJ sequences without ``times.txt``, ``.npz``
        without ``times``, a single ``.obj``).

    Returns
    -------
    Performance

    Raises
    ------
    InputFileError
        Missing path or an unsupported extension (named), or any reader's error.
    """
    path = Path(path)
    if path.is_dir():
        return read_obj_sequence(path, fps=fps)
    if not path.exists():
        raise InputFileError(f"{path}: not found")
    ext = path.suffix.lower()
    if ext == ".csv":
        return read_livelinkface(path)
    if ext == ".npz":
        return read_npz_performance(path, fps=fps)
    if ext == ".glb":
        names, times, weights = read_glb_weights(path)
        return Performance.from_weights(weights, names, times=times, source=str(path))
    if ext == ".c3d":
        from ._c3d import read_c3d

        return read_c3d(path)
    if ext == ".obj":
        mesh = read_obj(path)
        return Performance.from_vertices(mesh.vertices[None], mesh, times=[0.0],
                                         fps=fps or 30.0, source=str(path))
    raise InputFileError(f"{path}: unknown take format '{ext or '(no extension)'}'; supported: "
                         ".csv (Live Link Face), .c3d (markers), .npz, .glb, .obj, or a folder of OBJ frames")


def _weights_for(rig: Rig, weights, names, what: str) -> np.ndarray:
    w = np.asarray(weights, dtype=np.float64)
    if w.ndim == 1:
        w = w[None]
    if names is not None:
        return rig.map_weights(list(names), w, source=what)
    if w.shape[-1] != rig.n_shapes:
        raise InvalidDataError(f"{what}: weights have {w.shape[-1]} columns but rig '{rig.name}' has "
                               f"{rig.n_shapes} shapes; pass names=")
    return w


def write_animation(path: str | os.PathLike, *, rig: Rig | None = None,
                    weights: np.ndarray | None = None, names: list[str] | None = None,
                    vertices: np.ndarray | None = None, mesh: Mesh | None = None,
                    times: np.ndarray, head: HeadPose | None = None) -> Path:
    """Write an animation in the format the output path asks for.

    Parameters
    ----------
    path : path-like
        ``.glb`` (needs ``rig`` and ``weights``), ``.npz`` (``vertices``, or ``rig`` + ``weights``
        evaluated), ``.csv`` (``weights``; Live Link Face layout), or a path without extension / an
        existing folder (OBJ sequence; ``vertices`` + ``mesh``, or ``rig`` + ``weights``).
    rig : Rig, optional
    weights : (T, K) float, optional
        In the rig's shape order, or named by ``names``.
    names : list of str, optional
        Column names of ``weights`` (any spelling); default the rig's names.
    vertices : (T, V, 3) float, optional
    mesh : Mesh, optional
        Topology for ``vertices`` (default the rig's neutral).
    times : (T,) float
        Frame times in seconds, strictly increasing.
    head : HeadPose, optional
        Head motion: the ``.csv`` head columns, the ``.glb`` head node.

    Returns
    -------
    Path
        ``path``.

    Raises
    ------
    OutputError
        Unknown extension, missing data the format needs, or a path that cannot be written (missing
        or read-only folder); nothing partial is left.
    """
    path = Path(path)
    ext = path.suffix.lower()
    is_folder = path.is_dir() or ext == ""
    if not is_folder and ext not in WRITE_FORMATS:
        raise OutputError(f"{path}: unknown output format '{ext}'; use .glb, .npz, .csv or a folder "
                          "(no extension) for an OBJ sequence")
    check_output_path(path)  # fail before any work when the folder is missing or read-only
    t = np.asarray(times, dtype=np.float64).reshape(-1)

    def need_vertices() -> tuple[np.ndarray, Mesh | None]:
        if vertices is not None:
            return np.asarray(vertices, dtype=np.float64), mesh if mesh is not None else (
                rig.neutral if rig is not None else None)
        if rig is None or weights is None:
            raise OutputError(f"{path}: writing {ext or 'an OBJ sequence'} needs vertices, or a rig and weights")
        return RigFrames(rig, _weights_for(rig, weights, names, str(path))), mesh or rig.neutral

    if ext == ".glb":
        if rig is None or weights is None:
            raise OutputError(f"{path}: a .glb needs a rig and weights (morph targets + animation)")
        return write_glb(path, rig, weights, t, names=names, head=head)
    if ext == ".csv":
        if weights is None:
            raise OutputError(f"{path}: a Live Link Face .csv needs weights")
        cols = list(names) if names is not None else (rig.names if rig is not None else None)
        if cols is None:
            raise OutputError(f"{path}: pass names (or a rig) to name the weight columns")
        perf = Performance.from_weights(weights, cols, times=t, head=head,
                                        source=str(path))
        return write_livelinkface(path, perf)
    v, m = need_vertices()
    if ext == ".npz":
        unit = {"unit": rig.unit} if rig is not None else {}
        return write_npz(path, v, t, m, **unit)
    if m is None:
        raise OutputError(f"{path}: an OBJ sequence needs a mesh (or a rig) for its faces")
    return write_obj_sequence(path, m, v, t)
