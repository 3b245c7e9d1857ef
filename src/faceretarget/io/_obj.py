"""Wavefront OBJ meshes: a fast vectorised reader and an exact writer.

Only geometry is read: ``v`` (positions; a fourth ``w`` or trailing vertex colours are ignored),
``vt`` (texture coordinates; ``w`` ignored) and ``f`` (polygons of any size, with ``a``, ``a/b``,
``a//c`` or ``a/b/c`` corners and negative, relative indices).  Normals (``vn``), groups, objects,
materials, smoothing groups and lines are skipped.  The vertex order of the file is kept exactly,
so meshes exported from the same rig stay in correspondence.

Writing uses Python's shortest round-trip float representation, so ``read_obj(write_obj(m))``
gives back bit-identical vertices and UVs.

A mesh sequence is a folder of ``frame_00000.obj``, ``frame_00001.obj``, ... (same vertex order)
with a ``times.txt`` holding one time in seconds per line (:func:`write_obj_sequence`,
:func:`read_obj_sequence`).
"""

from __future__ import annotations

import os
import re
import warnings
from pathlib import Path

import numpy as np

from ..errors import DataWarning, InputFileError, InvalidDataError, OutputError, TopologyError, excerpt
from ..files import atomic_dir, atomic_path, check_output_path
from ..formats import OBJ
from ..mesh import Mesh
from ..performance import Performance
from ..rig import RigFrames

__all__ = ["read_obj", "read_obj_vertices", "write_obj", "format_obj", "write_obj_sequence",
           "read_obj_sequence"]


# ---------------------------------------------------------------------------------------- reading
class _Lines:
    """The lines of an OBJ file, classified with numpy (no per-line Python loop on the fast path)."""

    def __init__(self, path: Path):
        if not path.exists():
            raise InputFileError(f"{path}: file not found")
        if path.is_dir():
            raise InputFileError(f"{path}: is a folder, expected an OBJ file")
        try:
            raw = path.read_bytes()
        except OSError as e:
            raise InputFileError(f"{path}: cannot read ({e.strerror or e})") from e
        if b"\r" in raw:
            raw = raw.replace(b"\r\n", b"\n").replace(b"\r", b"\n")
        if b"\t" in raw:
            raw = raw.replace(b"\t", b" ")
        self.path = path
        # utf-8 never uses byte 0x0A inside a multi-byte sequence, so lines match one to one
        self.lines = raw.decode("utf-8", errors="replace").split("\n")
        arr = np.frombuffer(raw + b"\n\n\n", np.uint8)
        starts = np.concatenate([[0], np.flatnonzero(arr[: len(raw)] == 10) + 1])
        c0, c1, c2 = arr[starts], arr[starts + 1], arr[starts + 2]
        if (c0 == 32).any():  # indented lines: strip them and classify the slow way
            self.lines = [line.lstrip() for line in self.lines]
            heads = [line[:3] for line in self.lines]
            c0 = np.array([ord(h[0]) if len(h) > 0 else 0 for h in heads])
            c1 = np.array([ord(h[1]) if len(h) > 1 else 0 for h in heads])
            c2 = np.array([ord(h[2]) if len(h) > 2 else 0 for h in heads])
        self.is_v = (c0 == ord("v")) & (c1 == 32)
        self.is_vt = (c0 == ord("v")) & (c1 == ord("t")) & (c2 == 32)
        self.is_f = (c0 == ord("f")) & (c1 == 32)

    def select(self, mask: np.ndarray) -> tuple[list[str], np.ndarray]:
        """The lines where ``mask`` holds and their 1-based line numbers."""
        idx = np.flatnonzero(mask)
        lines = self.lines
        return [lines[i] for i in idx.tolist()], idx + 1


def _bad_float_line(path: Path, sel: list[str], numbers: np.ndarray, ncoord: int,
                    what: str) -> InputFileError:
    """Find the first malformed ``v``/``vt`` line and describe it (called only on failure)."""
    for lineno, line in zip(numbers.tolist(), sel, strict=True):
        body = line.split("#", 1)[0].split()[1:]
        if len(body) < ncoord:
            return InputFileError(
                f"{path}:{lineno}: {what} needs {ncoord} numbers, got {len(body)}: {excerpt(line.strip())}")
        for tok in body[:ncoord]:
            try:
                float(tok)
            except ValueError:
                return InputFileError(
                    f"{path}:{lineno}: {what} coordinate {excerpt(tok)} is not a number: {excerpt(line.strip())}")
    return InputFileError(f"{path}: cannot parse the {what} lines")


def _parse_floats(path: Path, sel: list[str], numbers: np.ndarray, ncoord: int, what: str) -> np.ndarray:
    if not sel:
        return np.zeros((0, ncoord))
    try:
        arr = np.loadtxt(sel, usecols=tuple(range(1, ncoord + 1)), dtype=np.float64,
                         comments="#", ndmin=2)
    except (ValueError, IndexError) as e:
        raise _bad_float_line(path, sel, numbers, ncoord, what) from e
    if arr.shape != (len(sel), ncoord):  # pragma: no cover - loadtxt guarantees this
        raise _bad_float_line(path, sel, numbers, ncoord, what)
    finite = np.isfinite(arr).all(axis=1)
    if not finite.all():
        k = int(np.flatnonzero(~finite)[0])
        raise InputFileError(
            f"{path}:{int(numbers[k])}: {what} {k + 1} has a non-finite coordinate: {excerpt(sel[k].strip())}")
    return arr


def _parse_faces(path: Path, fl: list[str], numbers: np.ndarray, n_v_before: np.ndarray,
                 n_vt_before: np.ndarray, nv: int, nvt: int):
    """Return counts, vertex indices, uv indices (or None) for the ``f`` lines ``fl``."""
    if not fl:
        return np.zeros(0, np.int64), np.zeros(0, np.int64), None
    bodies = [line[2:].split("#", 1)[0] if "#" in line else line[2:] for line in fl]
    counts = np.fromiter((len(b.split()) for b in bodies), np.int64, len(bodies))
    bad = counts < 3
    if bad.any():
        j = int(np.flatnonzero(bad)[0])
        raise InputFileError(
            f"{path}:{int(numbers[j])}: a face needs at least 3 corners, got {int(counts[j])}")
    joined = " ".join(bodies)
    ntok = int(counts.sum())
    k = joined.split(maxsplit=1)[0].count("/")
    vi = ti = None
    if k <= 2 and joined.count("/") == k * ntok:
        flat = joined.replace("//", "/0/").replace("/", " ") if k else joined
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("error")
                nums = np.fromstring(flat, dtype=np.int64, sep=" ")
        except (ValueError, DeprecationWarning):
            nums = None
        if nums is not None and nums.size == ntok * (k + 1):
            nums = nums.reshape(ntok, k + 1)
            vi = nums[:, 0]
            ti = nums[:, 1] if k >= 1 else None
    if vi is None:  # mixed corner forms or bad tokens: parse corner by corner
        vi_l: list[int] = []
        ti_l: list[int] = []
        for lineno, body in zip(numbers.tolist(), bodies, strict=True):
            for tok in body.split():
                parts = tok.split("/")
                try:
                    vi_l.append(int(parts[0]))
                    ti_l.append(int(parts[1]) if len(parts) > 1 and parts[1] else 0)
                    if abs(vi_l[-1]) >= 2**62 or abs(ti_l[-1]) >= 2**62:  # no int64 holds it: no index
                        raise ValueError
                except ValueError:
                    raise InputFileError(
                        f"{path}:{lineno}: face corner {excerpt(tok)} is not a vertex index") from None
        vi = np.asarray(vi_l, np.int64)
        ti = np.asarray(ti_l, np.int64)
    face_of = np.repeat(np.arange(len(fl)), counts)

    def resolve(idx: np.ndarray, n_before: np.ndarray, n_total: int, what: str) -> np.ndarray:
        out = idx - 1
        neg = idx < 0
        if neg.any():  # relative: -1 is the last one defined before this face
            out[neg] = n_before[face_of[neg]] + idx[neg]
        bad = (idx == 0) | (out < 0) | (out >= n_total)
        if bad.any():
            c = int(np.flatnonzero(bad)[0])
            raise InputFileError(
                f"{path}:{int(numbers[face_of[c]])}: face refers to {what} {int(idx[c])} but the file "
                f"has {n_total} {'vertices' if what == 'vertex' else what + 's'}")
        return out

    vidx = resolve(vi, n_v_before, nv, "vertex")
    uvidx = None
    if ti is not None and nvt:
        has = ti != 0
        if has.all():
            uvidx = resolve(ti, n_vt_before, nvt, "texture coordinate")
        elif has.any():
            warnings.warn(f"{path}: some face corners have texture coordinates and some do not; "
                          "UVs are ignored", DataWarning, stacklevel=3)
    return counts, vidx, uvidx


def read_obj(path: str | os.PathLike) -> Mesh:
    """Read an OBJ file into a :class:`~faceretarget.mesh.Mesh`, keeping its vertex order.

    Parameters
    ----------
    path : path-like
        The ``.obj`` file.

    Returns
    -------
    Mesh
        ``vertices`` (V, 3) float64, ``face_counts`` (F,), ``face_indices`` (sum(face_counts),),
        and when the file has ``vt`` lines used by every face corner, ``uvs`` (U, 2) and
        ``face_uv_indices`` (sum(face_counts),).  ``name`` is the file path.

    Raises
    ------
    InputFileError
        Missing file, no vertices, a non-numeric or non-finite coordinate, or a bad face index;
        the message names the file and the 1-based line number.
    """
    path = Path(path)
    L = _Lines(path)
    vl, vnum = L.select(L.is_v)
    if not vl:
        raise InputFileError(f"{path}: no vertices ('v x y z' lines) found; is this an OBJ file?")
    v = _parse_floats(path, vl, vnum, 3, "vertex")
    vtl, vtnum = L.select(L.is_vt)
    vt = _parse_floats(path, vtl, vtnum, 2, "texture coordinate") if vtl else None
    fl, fnum = L.select(L.is_f)
    n_v_before = np.cumsum(L.is_v)[L.is_f]
    n_vt_before = np.cumsum(L.is_vt)[L.is_f]
    counts, vidx, uvidx = _parse_faces(path, fl, fnum, n_v_before, n_vt_before, len(v),
                                       0 if vt is None else len(vt))
    try:
        return Mesh(v, counts, vidx, vt if uvidx is not None else None, uvidx, name=str(path))
    except InvalidDataError as e:  # pragma: no cover - checks above catch these first
        raise InputFileError(str(e)) from e


def read_obj_vertices(path: str | os.PathLike) -> np.ndarray:
    """Read only the vertex positions of an OBJ file (fast path for key shapes and sequences).

    Returns
    -------
    (V, 3) float64

    Raises
    ------
    InputFileError
        As :func:`read_obj`.
    """
    path = Path(path)
    L = _Lines(path)
    vl, vnum = L.select(L.is_v)
    if not vl:
        raise InputFileError(f"{path}: no vertices ('v x y z' lines) found; is this an OBJ file?")
    return _parse_floats(path, vl, vnum, 3, "vertex")


# ---------------------------------------------------------------------------------------- writing
def _rows(prefix: str, arr: np.ndarray, precision: int | None) -> str:
    if arr.size == 0:
        return ""
    if precision is None:  # shortest repr that round-trips exactly
        fmt = prefix + " " + " ".join(["{!r}"] * arr.shape[1]) + "\n"
        return "".join(fmt.format(*row) for row in arr.tolist())
    fmt = prefix + " " + " ".join([f"%.{precision}g"] * arr.shape[1]) + "\n"
    return "".join(fmt % tuple(row) for row in arr.tolist())


def format_obj(mesh: Mesh, vertices: np.ndarray | None = None, *, precision: int | None = None,
               header: str | None = None) -> str:
    """The OBJ text of ``mesh`` (with ``vertices`` (V, 3) replacing its positions when given)."""
    v = mesh.vertices if vertices is None else np.asarray(vertices, dtype=np.float64)
    if v.shape != mesh.vertices.shape:
        raise InvalidDataError(
            f"{mesh.name}: vertices must have shape {mesh.vertices.shape}, got {v.shape}")
    if not np.isfinite(v).all():
        bad = int(np.flatnonzero(~np.isfinite(v).all(axis=1))[0])
        raise InvalidDataError(f"{mesh.name}: vertex {bad} is not finite; nothing written")
    parts = []
    if header:
        parts.append("".join(f"# {line}\n" for line in header.splitlines()))
    parts.append(_rows("v", v, precision))
    has_uv = mesh.uvs is not None and mesh.face_uv_indices is not None
    if has_uv:
        parts.append(_rows("vt", mesh.uvs, precision))
    if mesh.n_faces:
        vi = (mesh.face_indices + 1).tolist()
        if has_uv:
            ui = (mesh.face_uv_indices + 1).tolist()
            corners = [f"{a}/{b}" for a, b in zip(vi, ui, strict=True)]
        else:
            corners = [str(a) for a in vi]
        ends = np.cumsum(mesh.face_counts).tolist()
        start = 0
        faces = []
        for end in ends:
            faces.append("f " + " ".join(corners[start:end]) + "\n")
            start = end
        parts.append("".join(faces))
    return "".join(parts)


def write_obj(path: str | os.PathLike, mesh: Mesh, vertices: np.ndarray | None = None, *,
              precision: int | None = None, header: str | None = None) -> Path:
    """Write ``mesh`` as an OBJ file, whole or not at all.

    Parameters
    ----------
    path : path-like
        Output ``.obj`` file; its folder must exist.
    mesh : Mesh
        Faces and UVs to write (``v``, ``vt`` and ``f a/t`` lines; ``f a`` without UVs).
    vertices : (V, 3) float, optional
        Positions to write instead of ``mesh.vertices`` (same count).
    precision : int, optional
        Significant digits; by default the shortest representation that reads back exactly.
    header : str, optional
        Comment lines written first.

    Returns
    -------
    Path
        ``path``.

    Raises
    ------
    OutputError
        The file cannot be written (nothing partial is left).
    """
    path = check_output_path(path)
    text = format_obj(mesh, vertices, precision=precision, header=header)
    with atomic_path(path) as tmp:
        tmp.write_text(text, encoding="utf-8")
    return path


# ------------------------------------------------------------------------------- OBJ sequences
_FRAME_PATTERN = "frame_{:05d}.obj"
_TIMES_FILE = "times.txt"
_DIGITS = re.compile(r"(\d+)")


def _natural_key(name: str) -> list:
    return [int(p) if p.isdigit() else p.lower() for p in _DIGITS.split(name)]


def write_obj_sequence(folder: str | os.PathLike, mesh: Mesh, vertices: np.ndarray | RigFrames,
                       times: np.ndarray, *, precision: int | None = None) -> Path:
    """Write a mesh sequence as ``frame_00000.obj``, ``frame_00001.obj``, ... plus ``times.txt``.

    The folder appears whole or not at all (written beside it, then renamed).  Writing into an
    existing folder that already holds ``frame_*.obj`` files is refused, so frames of two takes
    never mix.

    Parameters
    ----------
    folder : path-like
        Output folder (its parent must exist).
    mesh : Mesh
        Faces and UVs of every frame.
    vertices : (T, V, 3) float, or RigFrames
        Positions per frame (a :class:`~faceretarget.rig.RigFrames` is evaluated a chunk at a time).
    times : (T,) float
        Frame times in seconds, written one per line to ``times.txt``.
    precision : int, optional
        Significant digits (default: exact round trip).

    Returns
    -------
    Path
        ``folder``.
    """
    folder = check_output_path(folder)
    v = vertices if isinstance(vertices, RigFrames) else np.asarray(vertices, dtype=np.float64)
    t = np.asarray(times, dtype=np.float64).reshape(-1)
    if len(v.shape) != 3 or v.shape[1:] != mesh.vertices.shape:
        raise InvalidDataError(f"{folder}: vertices must have shape (T, {mesh.n_vertices}, 3), got {v.shape}")
    if t.size != v.shape[0]:
        raise InvalidDataError(f"{folder}: {t.size} times for {v.shape[0]} frames")
    if folder.is_dir() and any(folder.glob("frame_*.obj")):
        raise OutputError(f"{folder}: already holds frame_*.obj files; write the sequence to a new "
                          "or empty folder so two takes never mix")
    chunks = v.chunks(256) if isinstance(v, RigFrames) else ((a, v[a:a + 256]) for a in range(0, len(v), 256))
    with atomic_dir(folder) as tmp:
        for a, block in chunks:
            if not np.isfinite(block).all():
                f = a + int(np.nonzero(~np.isfinite(block))[0][0])
                raise InvalidDataError(f"{folder}: frame {f} has a non-finite vertex; nothing written")
            for i, frame in enumerate(block, a):
                (tmp / _FRAME_PATTERN.format(i)).write_text(
                    format_obj(mesh, frame, precision=precision), encoding="utf-8")
        (tmp / _TIMES_FILE).write_text("".join(f"{x!r}\n" for x in t.tolist()), encoding="utf-8")
    return folder


def read_obj_sequence(folder: str | os.PathLike, fps: float | None = None) -> Performance:
    """Read a folder of OBJ frames (same vertex order) as a vertices :class:`Performance`.

    Frames are the folder's ``*.obj`` files in natural order (``f2`` before ``f10``).  Times come
    from ``times.txt`` (one time in seconds per line) when present, else from ``fps`` (30 with a
    warning when omitted).

    Returns
    -------
    Performance
        ``vertices`` (T, V, 3), ``mesh`` the first frame, ``source`` the folder.

    Raises
    ------
    InputFileError
        Missing folder, no OBJ in it, or a ``times.txt`` with a bad line or another frame count.
    TopologyError
        A frame with another vertex count (names the file and both counts).
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise InputFileError(f"{folder}: folder not found" if not folder.exists() else f"{folder}: not a folder")
    files = sorted((p for p in folder.iterdir() if p.suffix.lower() == OBJ and p.is_file()),
                   key=lambda p: _natural_key(p.name))
    if not files:
        raise InputFileError(f"{folder}: no .obj frames found")
    mesh = read_obj(files[0])
    V = mesh.n_vertices
    verts = np.empty((len(files), V, 3))
    verts[0] = mesh.vertices
    for i, p in enumerate(files[1:], 1):
        v = read_obj_vertices(p)
        if len(v) != V:
            raise TopologyError(f"{p}: frame has {len(v)} vertices but {files[0].name} has {V}")
        verts[i] = v
    tfile = folder / _TIMES_FILE
    if tfile.is_file():
        rows = [(n, s.strip()) for n, s in enumerate(tfile.read_text(encoding="utf-8").splitlines(), 1)
                if s.strip() and not s.lstrip().startswith("#")]
        try:
            times = np.array([float(s) for _, s in rows])
        except ValueError:
            n, s = next((n, s) for n, s in rows if not _is_number(s))
            raise InputFileError(f"{tfile}:{n}: time {excerpt(s)} is not a number") from None
        if times.size != len(files):
            raise InputFileError(f"{tfile}: {times.size} times for {len(files)} frames")
        perf = Performance.from_vertices(verts, mesh, times=times, fps=fps, source=str(folder))
    else:
        if fps is None:
            warnings.warn(f"{folder}: no {_TIMES_FILE} and no fps given; assuming 30 fps", DataWarning, stacklevel=2)
            fps = 30.0
        perf = Performance.from_vertices(verts, mesh, fps=fps, source=str(folder))
    return perf


def _is_number(s: str) -> bool:
    try:
        float(s)
    except ValueError:
        return False
    return True
