"""Arrays of an ``.npz`` checked before use: the kind of values, the dimensions, one value where one
is expected (every ``.npz`` reader: takes, rigs, SMPL-X poses).  A file's arrays are input like any
other: a string array where numbers belong, a bool time axis or an object array is an
:class:`~faceretarget.errors.InputFileError` naming the file and the key, never a ValueError from a
constructor.
"""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np

from ..errors import DataWarning, InputFileError
from ..mesh import Mesh

__all__ = ["npz_array", "npz_scalar", "npz_mesh"]

_KIND = {"f": ("fiu", "numbers"), "i": ("iu", "integers"), "U": ("US", "text")}


def npz_array(path: Path, data: dict, key: str, kind: str, ndim: int | tuple[int, ...] | None = None):
    """``data[key]`` of an ``.npz`` checked before use (None when absent): ``kind`` ``"f"`` numbers
    (returned as float64), ``"i"`` integers (int64) or ``"U"`` text (str, bytes decoded as UTF-8);
    ``ndim`` the dimensions allowed.  Raises :class:`InputFileError` naming the file and the key."""
    if key not in data:
        return None
    a = np.asarray(data[key])
    kinds, what = _KIND[kind]
    if a.dtype.kind not in kinds:
        raise InputFileError(f"{path}: '{key}' holds {a.dtype} values, expected {what}")
    allowed = (ndim,) if isinstance(ndim, int) else ndim
    if allowed is not None and a.ndim not in allowed:
        raise InputFileError(f"{path}: '{key}' has shape {a.shape}, expected {' or '.join(f'{d}-D' for d in allowed)}")
    if kind == "U":
        return a.astype(str) if a.dtype.kind == "U" else np.vectorize(
            lambda b: b.decode("utf-8", "replace"), otypes=[str])(a) if a.size else a.astype(str)
    with np.errstate(invalid="ignore", over="ignore"):  # signalling NaNs, uint64 beyond int64: checked later
        return a.astype(np.float64 if kind == "f" else np.int64)


def npz_scalar(path: Path, data: dict, key: str, kind: str):
    """A one-value entry (``fps``, ``unit``...) as a float or str, or None when absent."""
    a = npz_array(path, data, key, kind)
    if a is None:
        return None
    if a.size != 1:
        raise InputFileError(f"{path}: '{key}' must hold one value, it holds {a.size}")
    return str(a.reshape(-1)[0]) if kind == "U" else float(a.reshape(-1)[0])


def npz_mesh(path: Path, data: dict, vertices: np.ndarray, counts: str = "face_counts",
             indices: str = "face_indices") -> Mesh | None:
    """The mesh of an ``.npz`` (``face_counts`` + ``face_indices`` [+ ``uvs`` + ``face_uv_indices``],
    or ``faces``) on ``vertices`` (V, 3); None without faces."""
    uvs, uvi = npz_array(path, data, "uvs", "f", 2), npz_array(path, data, "face_uv_indices", "i", 1)
    if uvs is not None and uvs.shape[1] != 2:
        raise InputFileError(f"{path}: 'uvs' must have shape (U, 2), got {uvs.shape}")
    if (uvs is None) != (uvi is None):
        warnings.warn(f"{path}: 'uvs' and 'face_uv_indices' come together, the file has only one; the mesh is "
                      "read without texture coordinates", DataWarning, stacklevel=3)
        uvs = uvi = None
    if counts in data and indices in data:
        return Mesh(vertices, npz_array(path, data, counts, "i", 1), npz_array(path, data, indices, "i", 1),
                    uvs, uvi, name=path.name)
    if "faces" in data:
        return Mesh.from_triangles(vertices, npz_array(path, data, "faces", "i", 2), name=path.name)
    return None
