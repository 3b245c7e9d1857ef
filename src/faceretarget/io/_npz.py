"""Takes as NumPy ``.npz`` archives, for pipelines that post-process in Python.

Layout written by :func:`write_npz` (read with ``np.load(path)``; no pickles):

================== ====================== =================================================
key                shape, dtype           meaning
================== ====================== =================================================
``vertices``       (T, V, 3) float        vertex positions per frame
``times``          (T,) float64           frame times in seconds
``fps``            () float64             nominal frame rate (median of the time steps)
``face_counts``    (F,) int64             corners per polygon (when a mesh is given)
``face_indices``   (sum(face_counts),)    0-based vertex index per corner (with a mesh)
``faces``          (n, 3) int64           the polygons fanned into triangles (with a mesh)
``uvs``            (U, 2) float64         texture coordinates (mesh with UVs)
``face_uv_indices`` (sum(face_counts),)   UV index per corner (mesh with UVs)
``...``            any                    extra keyword arrays, e.g. ``unit="cm"``
================== ====================== =================================================

:func:`read_npz_performance` also reads weight takes: ``weights`` (T, K) with ``names`` (K,) str.
"""

from __future__ import annotations

import os
import warnings
import zipfile
from pathlib import Path

import numpy as np

from ..errors import DataWarning, InputFileError, InvalidDataError, excerpt
from ..files import atomic_path, check_output_path, load_npz_arrays
from ..mesh import Mesh
from ..performance import Performance
from ..rig import RigFrames
from ..timebase import infer_fps
from ._arrays import npz_array, npz_mesh, npz_scalar

__all__ = ["write_npz", "read_npz_performance"]

_RESERVED = {"vertices", "times", "fps", "face_counts", "face_indices", "faces", "uvs",
             "face_uv_indices"}


def write_npz(path: str | os.PathLike, vertices: np.ndarray | RigFrames, times: np.ndarray,
              mesh: Mesh | None = None, **extra) -> Path:
    """Write a vertex take to ``.npz`` (layout in the module docstring), whole or not at all.

    Parameters
    ----------
    path : path-like
        Output file; use the ``.npz`` extension.
    vertices : (T, V, 3) float, or RigFrames
        Positions per frame (float32 is kept as float32, anything else stored as float64); a
        :class:`~faceretarget.rig.RigFrames` is evaluated and written a chunk of frames at a time.
    times : (T,) float
        Frame times in seconds, strictly increasing.
    mesh : Mesh, optional
        Topology to store (``face_counts``, ``face_indices``, ``faces`` and UVs).
    **extra
        More arrays to store under their keyword (not one of the reserved keys).

    Returns
    -------
    Path
        ``path``.
    """
    path = check_output_path(path)
    v = vertices if isinstance(vertices, RigFrames) else np.asarray(vertices)
    if isinstance(v, np.ndarray) and v.dtype != np.float32:
        v = v.astype(np.float64)
    t = np.asarray(times, dtype=np.float64).reshape(-1)
    if len(v.shape) != 3 or v.shape[2] != 3:
        raise InvalidDataError(f"{path}: vertices must have shape (T, V, 3), got {v.shape}")
    if t.size != v.shape[0]:
        raise InvalidDataError(f"{path}: {t.size} times for {v.shape[0]} frames")
    if not np.isfinite(t).all() or (t.size > 1 and (np.diff(t) <= 0).any()):
        raise InvalidDataError(f"{path}: times must be finite and strictly increasing")
    clash = sorted(_RESERVED & set(extra))
    if clash:
        raise InvalidDataError(f"{path}: extra key(s) {', '.join(clash)} are reserved")
    arrays: dict[str, np.ndarray] = {"times": t}
    if t.size > 1:
        arrays["fps"] = np.float64(infer_fps(t))
    if mesh is not None:
        if mesh.n_vertices != v.shape[1]:
            raise InvalidDataError(
                f"{path}: frames have {v.shape[1]} vertices but the mesh has {mesh.n_vertices}")
        arrays["face_counts"] = mesh.face_counts
        arrays["face_indices"] = mesh.face_indices
        arrays["faces"] = mesh.triangles()
        if mesh.uvs is not None and mesh.face_uv_indices is not None:
            arrays["uvs"] = mesh.uvs
            arrays["face_uv_indices"] = mesh.face_uv_indices
    for k, a in extra.items():
        arrays[k] = np.asarray(a)
    with atomic_path(path) as tmp:
        with zipfile.ZipFile(tmp, "w", zipfile.ZIP_STORED, allowZip64=True) as zf:
            _write_frames(zf, path, v)
            for k, a in arrays.items():
                with zf.open(f"{k}.npy", "w", force_zip64=True) as f:
                    np.lib.format.write_array(f, np.asanyarray(a), allow_pickle=False)
    return path


def _write_frames(zf: zipfile.ZipFile, path: Path, v: np.ndarray | RigFrames, chunk: int = 1024) -> None:
    """The ``vertices`` entry, written (and checked finite) a chunk of frames at a time."""
    dtype = np.dtype(np.float32 if isinstance(v, np.ndarray) and v.dtype == np.float32 else np.float64)
    chunks = v.chunks(chunk) if isinstance(v, RigFrames) else ((a, v[a:a + chunk]) for a in range(0, len(v), chunk))
    with zf.open("vertices.npy", "w", force_zip64=True) as f:
        np.lib.format.write_array_header_1_0(f, {"descr": np.lib.format.dtype_to_descr(dtype), "fortran_order": False,
                                                 "shape": tuple(int(x) for x in v.shape)})
        for a, block in chunks:
            block = np.ascontiguousarray(block, dtype=dtype)
            if not np.isfinite(block).all():
                f_, j = (int(x[0]) for x in np.nonzero(~np.isfinite(block))[:2])
                raise InvalidDataError(f"{path}: frame {a + f_} vertex {j} is not finite; nothing written")
            f.write(block.tobytes())


def read_npz_performance(path: str | os.PathLike, fps: float | None = None) -> Performance:
    """Read a take from ``.npz``: ``vertices`` (T, V, 3) or ``weights`` (T, K) with ``names``.

    Times come from ``times``, else from ``fps`` (the argument, else an ``fps`` key, else 30 with a
    warning).  A mesh is rebuilt from ``face_counts``/``face_indices`` (or ``faces`` (F, n)) with
    the first frame as its positions.  A ``unit`` key, when present, sets ``Performance.unit``.

    Raises
    ------
    InputFileError
        Missing or unreadable file, or neither ``vertices`` nor ``weights``+``names`` in it (the
        message lists the keys found).
    InvalidDataError
        Shapes that do not agree (named in the message).
    """
    path = Path(path)
    data = load_npz_arrays(path)
    if "poses" in data and "vertices" not in data and "weights" not in data:
        from ._head import read_smplx_head

        return read_smplx_head(path)
    if "vertices" not in data and not ("weights" in data and "names" in data):
        keys = [k if k.isprintable() and len(k) <= 20 else excerpt(k, 20) for k in sorted(data)]
        raise InputFileError(f"{path}: holds neither 'vertices' nor 'weights' + 'names' (keys: "
                             f"{', '.join(keys[:10]) or 'none'}{' ...' if len(keys) > 10 else ''})")
    src = str(path)
    try:
        times = npz_array(path, data, "times", "f", (0, 1))
        if times is None and fps is None:
            fps = npz_scalar(path, data, "fps", "f")
            if fps is None:
                warnings.warn(f"{path}: no 'times' and no fps given; assuming 30 fps", DataWarning, stacklevel=2)
                fps = 30.0
        unit = npz_scalar(path, data, "unit", "U")
        if "vertices" in data:
            v = npz_array(path, data, "vertices", "f")
            if v.ndim != 3 or v.shape[-1] != 3 or len(v) == 0:
                raise InvalidDataError(f"{path}: 'vertices' must have shape (T, V, 3), got {v.shape}")
            mesh = npz_mesh(path, data, v[0])
            return Performance.from_vertices(v, mesh, times=times, fps=fps, unit=unit, source=src)
        names = [str(n) for n in npz_array(path, data, "names", "U", (0, 1)).reshape(-1)]
        w = npz_array(path, data, "weights", "f", 2)
        if len(w) == 0:
            raise InputFileError(f"{path}: 'weights' has no frame (shape {w.shape})")
        return Performance.from_weights(w, names, times=times, fps=fps, source=src)
    except InvalidDataError as e:
        msg = str(e)
        raise InvalidDataError(msg if msg.startswith(src) else f"{path}: {msg}") from e
