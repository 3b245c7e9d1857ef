"""Rigs on disk: a folder of OBJ key shapes, and a single ``.npz`` cache.

Folder of OBJs
--------------
One OBJ per shape, all with the same vertex order.  The neutral is found by name (file stem,
case-insensitive): ``neutral``, ``generic_neutral_mesh`` or anything ending in ``_neutral``; or it
is given explicitly.  Every other OBJ (except those matching ``exclude``) is a key shape, stored as
``shape - neutral``; its name is the file stem normalised to ARKit camelCase
(:func:`faceretarget.names.normalize_name`), the stem itself is kept in ``Rig.source_names``.
Key shapes are ordered by file name (case-insensitively, then exactly).  ``landmarks68.txt`` (or
``landmarks.txt``) beside them holds whitespace-separated 0-based vertex indices.

``key_weights.csv`` beside them (optional; written for key-model sets, read into
:attr:`Rig.basis <faceretarget.rig.Rig.basis>`) says what each key shape is as weights of named
base shapes (ARKit)::

    file,browDownLeft,browDownRight,...,tongueOut
    happy_PP.obj,0,0,...,0

one row per key-shape OBJ (``file`` its file name), one column per base shape.  The same file in a
keyshape folder (:mod:`faceretarget.io._keyshapes`) names the ``frame_00123.obj`` files.  A key
shape without a row leaves the rig without a basis (one warning); rows of other files are ignored.

``.npz`` cache layout
---------------------
Written by :func:`write_rig_npz`, read by :func:`read_rig_npz` (``allow_pickle=False``):

================== ====================== ==================================================
key                shape, dtype           meaning
================== ====================== ==================================================
``format``         () str                 ``"faceretarget.rig/1"``
``name``           () str                 rig label
``unit``           () str                 ``"mm"``, ``"cm"``, ``"m"`` or ``"in"``
``neutral``        (V, 3) float64         neutral vertex positions
``face_counts``    (F,) int64             corners per polygon
``face_indices``   (sum(face_counts),)    0-based vertex index per corner
``uvs``            (U, 2) float64         texture coordinates (only when the neutral has UVs)
``face_uv_indices`` (sum(face_counts),)   0-based UV index per corner (only with ``uvs``)
``names``          (K,) str               normalised key shape names
``source_names``   (K,) str               names as found in the files (optional)
``deltas``         (K, V, 3) float64      key shape minus neutral
``landmarks``      (P,) int64             landmark vertex indices (optional)
``basis``          (K, M) float64         each key shape as base-shape weights (optional)
``basis_names``    (M,) str               the base shape names (with ``basis``)
================== ====================== ==================================================
"""

from __future__ import annotations

import fnmatch
import os
import warnings
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from ..errors import (
    DataWarning,
    InputFileError,
    InvalidDataError,
    MissingShapeError,
    OutputError,
    TopologyError,
    excerpt,
)
from ..files import atomic_dir, atomic_path, check_output_path, load_npz_arrays, read_text
from ..formats import OBJ
from ..mesh import Mesh
from ..rig import Rig
from ..units import guess_unit, normalize_unit
from ._arrays import npz_array, npz_mesh, npz_scalar
from ._obj import read_obj, read_obj_vertices, write_obj

__all__ = ["read_rig", "write_rig", "write_rig_npz", "read_rig_npz", "NEUTRAL_NAMES",
           "RIG_NPZ_FORMAT", "KEY_WEIGHTS"]

#: File stems (case-insensitive) taken as the neutral; any stem ending in ``_neutral`` also is.
NEUTRAL_NAMES: tuple[str, ...] = ("neutral", "generic_neutral_mesh")
RIG_NPZ_FORMAT = "faceretarget.rig/1"
#: The side file of a rig or keyshape folder giving each key shape as base-shape (ARKit) weights.
KEY_WEIGHTS = "key_weights.csv"
_LANDMARK_FILES = ("landmarks68.txt", "landmarks.txt")


def write_key_weights(path: Path, files: Sequence[str], basis: np.ndarray, names: Sequence[str]) -> None:
    """Write ``key_weights.csv`` (module docstring): one row per file, exact (``%.17g``) values."""
    lines = [",".join(["file", *names])]
    for f, row in zip(files, np.asarray(basis, dtype=np.float64), strict=True):
        lines.append(",".join([f, *(f"{v:.17g}" for v in row.tolist())]))
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")


def read_key_weights(folder: Path, files: Sequence[str], who: str) -> tuple[np.ndarray | None, list[str] | None]:
    """``(basis (K, M), names)`` of ``files`` from ``folder/key_weights.csv``; ``(None, None)`` without
    the file, or (with a warning) when a file has no row."""
    path = folder / KEY_WEIGHTS
    if not path.is_file():
        return None, None
    lines = [ln for ln in read_text(path, encoding="utf-8-sig").splitlines() if ln.strip()]
    if not lines or lines[0].split(",")[0].strip().lower() != "file":
        raise InputFileError(f"{path}: line 1 must be 'file,<base shape>,...'")
    names = [c.strip() for c in lines[0].split(",")[1:]]
    rows: dict[str, np.ndarray] = {}
    for n, line in enumerate(lines[1:], 2):
        cells = line.split(",")
        if len(cells) != len(names) + 1:
            raise InputFileError(f"{path}: line {n}: {len(cells)} columns, the header has {len(names) + 1}")
        try:
            vals = np.array([float(c) for c in cells[1:]])
        except ValueError:
            raise InputFileError(f"{path}: line {n}: a weight is not a number") from None
        if not np.isfinite(vals).all():
            raise InputFileError(f"{path}: line {n}: a weight is not finite")
        rows[cells[0].strip()] = vals
    missing = [f for f in files if f not in rows]
    if missing:
        warnings.warn(f"{path}: no row for {', '.join(missing[:5])}{' ...' if len(missing) > 5 else ''}; "
                      f"the key shapes of {who} are read without their base-shape weights", DataWarning,
                      stacklevel=3)
        return None, None
    return np.stack([rows[f] for f in files]) if files else np.zeros((0, len(names))), names


def _is_neutral_name(stem: str) -> bool:
    s = stem.lower()
    return s in NEUTRAL_NAMES or s.endswith("_neutral")


def _is_index(token: str) -> bool:
    try:
        return abs(int(token)) < 2**62
    except ValueError:
        return False


def _read_landmarks(path: Path, n_vertices: int) -> np.ndarray:
    toks = read_text(path).split()
    try:
        lm = np.array([int(t) for t in toks], dtype=np.int64)
    except (ValueError, OverflowError):
        bad = next(t for t in toks if not _is_index(t))
        raise InputFileError(f"{path}: landmark {excerpt(bad)} is not an integer vertex index") from None
    if lm.size == 0:
        raise InputFileError(f"{path}: no landmark indices found")
    out = (lm < 0) | (lm >= n_vertices)
    if out.any():
        k = int(np.flatnonzero(out)[0])
        raise InputFileError(
            f"{path}: landmark {k} is vertex {int(lm[k])}, outside 0..{n_vertices - 1} of the neutral")
    return lm


def read_rig(folder: str | os.PathLike, neutral: str | os.PathLike | None = None,
             unit: str | None = None, landmarks: str | os.PathLike | np.ndarray | None = None,
             exclude: Sequence[str] = ("identity[0-9]*",)) -> Rig:
    """Load a blendshape rig from a folder of OBJ files.

    Parameters
    ----------
    folder : path-like
        Folder holding the neutral and one OBJ per key shape (same vertex order in all).
    neutral : path-like, optional
        The neutral OBJ (a path, or a file name inside ``folder``).  By default the file whose stem
        is ``neutral`` / ``generic_neutral_mesh`` / ends in ``_neutral`` (case-insensitive).
    unit : str, optional
        ``"mm"``, ``"cm"``, ``"m"`` or ``"in"``; guessed from the face size
        (:func:`faceretarget.units.guess_unit`) when omitted.
    landmarks : path-like or (P,) int, optional
        Landmark vertex indices or a file of them; by default ``landmarks68.txt`` (or
        ``landmarks.txt``) in ``folder`` when present.
    exclude : sequence of str
        ``fnmatch`` patterns (case-insensitive, on the file stem) of OBJs that are not key shapes.
        The default skips ICT-FaceKit's identity modes ``identity000`` and ``identity001``.

    Returns
    -------
    Rig
        ``deltas`` (K, V, 3) in file-name order, ``source_names`` the file stems, ``name`` the
        folder name.

    Raises
    ------
    InputFileError
        The folder is missing or holds no OBJ; a malformed OBJ or landmark file.
    MissingShapeError
        No neutral found (the message lists the names looked for).
    TopologyError
        A key shape's vertex count differs from the neutral's (names the file and both counts).
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise InputFileError(f"{folder}: rig folder not found" if not folder.exists()
                             else f"{folder}: is not a folder; a rig is a folder of OBJ files")
    objs = sorted((p for p in folder.iterdir() if p.suffix.lower() == OBJ and p.is_file()),
                  key=lambda p: (p.name.lower(), p.name))
    npath = _neutral_path(folder, objs, neutral)
    keys = _key_shape_files(objs, npath, exclude)
    base = _read_neutral(npath)
    V = base.n_vertices
    deltas = _key_shape_deltas(keys, base, npath)
    lm = _rig_landmarks(folder, landmarks, V)
    if unit is None:
        unit = guess_unit(base)
    else:
        unit = normalize_unit(unit, what=str(folder))
    stems = [p.stem for p in keys]
    basis, basis_names = read_key_weights(folder, [p.name for p in keys], str(folder))
    return Rig(base, stems, deltas, unit=unit, landmarks=lm, source_names=stems,
               name=folder.resolve().name or str(folder), basis=basis, basis_names=basis_names)


def _neutral_path(folder: Path, objs: list[Path], neutral: str | os.PathLike | None) -> Path:
    """The neutral OBJ: ``neutral`` (a path, or a name in ``folder``) or the one OBJ named like one."""
    if neutral is not None:
        npath = Path(neutral)
        if not npath.is_absolute() and not npath.exists():
            npath = folder / npath
        if not npath.exists():
            raise MissingShapeError(f"{npath}: neutral OBJ not found")
        return npath
    cands = [p for p in objs if _is_neutral_name(p.stem)]
    if not cands:
        raise MissingShapeError(
            f"{folder}: no neutral mesh found among {len(objs)} OBJ file(s); looked for a file "
            f"named {' / '.join(n + OBJ for n in NEUTRAL_NAMES)} or '*_neutral.obj' "
            "(any case); pass neutral=... to choose one")
    if len(cands) > 1:
        raise InputFileError(
            f"{folder}: several files look like the neutral ({', '.join(p.name for p in cands)}); "
            "pass neutral=... to choose one")
    return cands[0]


def _key_shape_files(objs: list[Path], npath: Path, exclude: Sequence[str]) -> list[Path]:
    """The OBJs that are key shapes: all but the neutral and those matching an ``exclude`` pattern."""
    pats = [p.lower() for p in exclude]
    return [p for p in objs
            if not (p.exists() and npath.exists() and p.resolve() == npath.resolve())
            and not any(fnmatch.fnmatchcase(p.stem.lower(), pat) for pat in pats)]


def _read_neutral(npath: Path) -> Mesh:
    """The neutral OBJ as a mesh named after its file."""
    base = read_obj(npath)
    return Mesh(base.vertices, base.face_counts, base.face_indices, base.uvs, base.face_uv_indices,
                name=npath.name)


def _key_shape_deltas(keys: list[Path], base: Mesh, npath: Path) -> np.ndarray:
    """(K, V, 3) each key shape OBJ minus the neutral ``base`` (read from ``npath``)."""
    V = base.n_vertices
    deltas = np.empty((len(keys), V, 3))
    for k, p in enumerate(keys):
        v = read_obj_vertices(p)
        if len(v) != V:
            raise TopologyError(
                f"{p}: key shape has {len(v)} vertices but the neutral {npath.name} has {V}; "
                "every shape must share the neutral's vertex order")
        np.subtract(v, base.vertices, out=deltas[k])
    return deltas


def _rig_landmarks(folder: Path, landmarks: str | os.PathLike | np.ndarray | None,
                   V: int) -> np.ndarray | None:
    """Landmark indices: given, read from the given file, or from ``landmarks68.txt`` / ``landmarks.txt``."""
    if isinstance(landmarks, str | os.PathLike):
        lm = _read_landmarks(Path(landmarks), V)
    elif landmarks is not None:
        lm = np.asarray(landmarks, dtype=np.int64).reshape(-1)
    else:
        lm = None
        for fn in _LANDMARK_FILES:
            if (folder / fn).is_file():
                lm = _read_landmarks(folder / fn, V)
                break
    return lm


def write_rig(rig: Rig, folder: str | os.PathLike, *, precision: int | None = None) -> Path:
    """Write a rig as a folder of OBJs that :func:`read_rig` reads back.

    Writes ``neutral.obj``, one ``<name>.obj`` per key shape (normalised ARKit names), when the
    rig has landmarks ``landmarks68.txt`` (68 landmarks) or ``landmarks.txt``, and when it has a
    :attr:`~faceretarget.rig.Rig.basis` ``key_weights.csv`` (module docstring).  The folder appears
    whole or not at all; an existing folder gets these files added or replaced.

    Parameters
    ----------
    rig : Rig
    folder : path-like
    precision : int, optional
        Significant digits (default: exact round trip).

    Returns
    -------
    Path
        ``folder``.
    """
    folder = check_output_path(folder)
    clash = [n for n in rig.names if _is_neutral_name(n)]
    if clash:
        raise OutputError(f"{folder}: key shape '{clash[0]}' would be taken for the neutral on reload")
    if folder.is_dir():
        stale = [p.name for p in folder.glob("*.obj")
                 if p.stem not in rig.names and p.name != "neutral.obj"]
        if stale:
            raise OutputError(
                f"{folder}: already holds other OBJ files ({', '.join(sorted(stale)[:5])}...) that would "
                "be read as key shapes; write the rig to an empty folder")
        if rig.basis is None and (folder / KEY_WEIGHTS).is_file():
            raise OutputError(f"{folder}: already holds a {KEY_WEIGHTS} that would give these key shapes "
                              "base-shape weights they do not have; write the rig to an empty folder")
    with atomic_dir(folder) as tmp:
        write_obj(tmp / "neutral.obj", rig.neutral, precision=precision)
        for k, n in enumerate(rig.names):
            write_obj(tmp / f"{n}.obj", rig.neutral, rig.neutral.vertices + rig.deltas[k],
                      precision=precision)
        if rig.landmarks is not None:
            fn = "landmarks68.txt" if rig.landmarks.size == 68 else "landmarks.txt"
            (tmp / fn).write_text(" ".join(map(str, rig.landmarks.tolist())) + "\n", encoding="utf-8")
        if rig.basis is not None:
            write_key_weights(tmp / KEY_WEIGHTS, [f"{n}.obj" for n in rig.names], rig.basis, rig.basis_names)
    return folder


# ----------------------------------------------------------------------------------- npz cache
def write_rig_npz(rig: Rig, path: str | os.PathLike) -> Path:
    """Write a rig to one ``.npz`` file (layout in the module docstring), whole or not at all."""
    path = check_output_path(path)
    arrays: dict[str, np.ndarray] = {
        "format": np.array(RIG_NPZ_FORMAT),
        "name": np.array(rig.name),
        "unit": np.array(rig.unit),
        "neutral": rig.neutral.vertices,
        "face_counts": rig.neutral.face_counts,
        "face_indices": rig.neutral.face_indices,
        "names": np.array(rig.names, dtype=str).reshape(-1),
        "deltas": rig.deltas,
    }
    if rig.neutral.uvs is not None and rig.neutral.face_uv_indices is not None:
        arrays["uvs"] = rig.neutral.uvs
        arrays["face_uv_indices"] = rig.neutral.face_uv_indices
    if rig.source_names is not None:
        arrays["source_names"] = np.array(rig.source_names, dtype=str).reshape(-1)
    if rig.landmarks is not None:
        arrays["landmarks"] = rig.landmarks
    if rig.basis is not None:
        arrays["basis"] = rig.basis
        arrays["basis_names"] = np.array(rig.basis_names, dtype=str).reshape(-1)
    with atomic_path(path) as tmp, open(tmp, "wb") as f:
        np.savez(f, **arrays)
    return path


def read_rig_npz(path: str | os.PathLike) -> Rig:
    """Read a rig written by :func:`write_rig_npz`.

    Raises
    ------
    InputFileError
        Missing or unreadable file, not a faceretarget rig, or a required key absent.
    """
    path = Path(path)
    if not path.is_file():
        raise InputFileError(f"{path}: rig file not found")
    data = load_npz_arrays(path)
    fmt = npz_scalar(path, data, "format", "U") if "format" in data else ""
    if not fmt.startswith("faceretarget.rig/"):
        raise InputFileError(f"{path}: not a faceretarget rig cache (no 'format' = '{RIG_NPZ_FORMAT}')")
    missing = [k for k in ("neutral", "face_counts", "face_indices", "names", "deltas", "unit")
               if k not in data]
    if missing:
        raise InputFileError(f"{path}: rig cache lacks {', '.join(missing)}")
    try:
        mesh = npz_mesh(path, data, npz_array(path, data, "neutral", "f", 2))
        src = npz_array(path, data, "source_names", "U", 1)
        bn = npz_array(path, data, "basis_names", "U", 1)
        return Rig(mesh, [str(n) for n in npz_array(path, data, "names", "U", 1)],
                   npz_array(path, data, "deltas", "f", 3), unit=npz_scalar(path, data, "unit", "U"),
                   landmarks=npz_array(path, data, "landmarks", "i", 1),
                   source_names=None if src is None else [str(n) for n in src],
                   name=npz_scalar(path, data, "name", "U") or path.stem, basis=npz_array(path, data, "basis", "f", 2),
                   basis_names=None if bn is None else [str(n) for n in bn])
    except (InvalidDataError, TopologyError) as e:
        raise InputFileError(f"{path}: {e}") from e
