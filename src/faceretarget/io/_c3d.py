"""C3D optical motion capture files: labelled 3D marker trajectories.

Written with `ezc3d <https://github.com/pyomeca/ezc3d>`_; read here, in Python, with every count
and pointer of the header and parameter section checked against the file first (ezc3d trusts them
and crashed or hung on fuzzed files), the point data giving the values ezc3d gives.  Only the point
(marker) data are used; analog channels, force plates and events are skipped on read and not
written.  Big-endian (MIPS) files are not supported.

A C3D sample whose residual is negative is invalid (the marker was occluded); such samples become
NaN.  Some systems instead write a gap as a point at exactly ``(0, 0, 0)``; with
``zero_is_missing=True`` (the default) those samples are NaN too.

Times are ``(first_frame + i) / rate`` where ``first_frame`` is the header's 0-based first frame, so
a take cut out of a longer recording keeps its place in time; :func:`write_c3d` writes
``round(times[0] * fps)`` back as the first frame.
"""

from __future__ import annotations

import math
import os
import struct
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import DataWarning, InputFileError, InvalidDataError, OutputError, excerpt
from ..files import atomic_path, check_output_path, input_file
from ..optional import optional_import
from ..performance import Performance

__all__ = ["read_c3d", "write_c3d"]


def _ezc3d():
    return optional_import("ezc3d", "writing C3D files")


def _param(group: dict, name: str):
    p = group.get(name)
    return None if p is None else p.get("value")


def _labels(point: dict, n: int) -> tuple[list[str], list[str]]:
    """``POINT:LABELS`` then ``LABELS2``, ``LABELS3``, ... (C3D's way past 255 labels).

    Returns the ``n`` labels (blanks stripped, empty ones named ``M001``..., repeats suffixed
    ``_2``, ``_3``...) and the sorted repeated labels.
    """
    raw = list(_param(point, "LABELS") or [])
    k = 2
    while len(raw) < n and _param(point, f"LABELS{k}") is not None:
        raw += list(_param(point, f"LABELS{k}"))
        k += 1
    raw = [str(s).strip() for s in raw[:n]]
    raw += [""] * (n - len(raw))
    labels = [s or f"M{i + 1:03d}" for i, s in enumerate(raw)]
    seen: dict[str, int] = {}
    dup: list[str] = []
    for i, s in enumerate(labels):
        if s in seen:
            seen[s] += 1
            dup.append(s)
            labels[i] = f"{s}_{seen[s]}"
        else:
            seen[s] = 1
    return labels, sorted(set(dup))


# ------------------------------------------------------------------------------------------ reading
# ezc3d trusts every count and pointer of a file: on fuzzed files a negative description length, an
# empty POINT:SCALE, a point count larger than the file, an analog channel without a scale or a
# ROTATION group of a truncated file made it crash (SIGSEGV) or loop for minutes.  So the reader is
# this module's own: the header and parameter records are walked with every count checked against
# the file, and the point data are one NumPy view of the frames the file really holds.  The values
# are those ezc3d gives (its conventions for frame counts, rates, DEC floats and residuals).

# parameters whose first value is used: present but empty is an error
_FIRST_VALUE = (("POINT", "USED"), ("POINT", "FRAMES"), ("POINT", "RATE"), ("POINT", "SCALE"))


@dataclass(frozen=True)
class _C3d:
    """What :func:`_parse_c3d` found: parameters and where the point data are."""

    params: dict          # {(GROUP, NAME): list of numbers, or of strings for a char parameter}
    dec: bool             # DEC (VAX) floats instead of IEEE
    n_points: int
    scale: float          # POINT:SCALE; negative: float data
    frames: int | None    # frames the file declares (None: no usable count)
    first_frame: int      # 0-based
    rate: float           # POINT:RATE, else the header's rate
    frame_bytes: int      # one frame: points and analog samples
    data_start: int       # byte offset of frame 0
    size: int             # file size in bytes


def _dec_floats(b: np.ndarray) -> np.ndarray:
    """DEC (VAX F) floats, as (..., 4) uint8, to float32 (ezc3d's conversion)."""
    b = np.asarray(b, np.uint8)
    e = np.where(b[..., 1] != 0, b[..., 1] - 1, 0).astype(np.uint8)
    return np.ascontiguousarray(np.stack([b[..., 2], b[..., 3], b[..., 0], e], axis=-1)).view("<f4")[..., 0]


def _floats(block: bytes, dec: bool) -> list[float]:
    a = np.frombuffer(block, np.uint8).reshape(-1, 4)
    with np.errstate(invalid="ignore"):  # a signalling NaN stays a NaN
        return (_dec_floats(a) if dec else a.copy().view("<f4")[:, 0]).astype(np.float64).tolist()


def _strings(block: bytes, dims: bytes) -> list[str]:
    """A char parameter as ezc3d reads it: one string per column of ``dims[0]`` characters, NULs
    dropped and trailing blanks removed."""
    if not dims or dims[0] == 0:
        return []
    w = dims[0]
    cols = [block[k:k + w].replace(b"\0", b"").decode("utf-8", "replace").rstrip() for k in range(0, len(block), w)]
    return cols if len(dims) > 1 else ["".join(cols)]


def _c3d_parameters(bad, raw, pos: int, dec: bool) -> dict[tuple[str, str], list]:
    """``{(GROUP, NAME): values}`` of the parameter records from byte ``pos`` on, every count checked."""
    n = len(raw)
    groups: dict[int, str] = {}
    params: list[tuple[int, str, list]] = []
    for _ in range(65536):
        if pos + 2 > n:
            raise bad("the parameter section runs past the end of the file")
        nchar, gid = struct.unpack_from("<bb", raw, pos)
        if nchar == 0:
            break
        if gid == 0:
            raise bad(f"parameter record at byte {pos} has group id 0")
        name_end = pos + 2 + abs(nchar)
        if name_end + 3 > n:
            raise bad("the parameter section runs past the end of the file")
        name = bytes(raw[pos + 2:name_end]).split(b"\0")[0].decode("ascii", "replace").strip().upper()
        off = struct.unpack_from("<H", raw, name_end)[0]
        q = name_end + 2
        if gid > 0:
            typ, nd = struct.unpack_from("<bb", raw, q) if q + 2 <= n else (0, 0)
            if typ not in (-1, 1, 2, 4) or not 0 <= nd <= 7 or q + 2 + nd > n:
                raise bad(f"parameter {name[:20]!r} at byte {pos} has data type {typ} with {nd} dimension(s)")
            dims = bytes(raw[q + 2:q + 2 + nd])
            count = math.prod(dims) if nd else (0 if typ == -1 else 1)
            q += 2 + nd
            if q + count * abs(typ) + 1 > n:
                raise bad(f"parameter {name[:20]!r} at byte {pos} runs past the end of the file")
            block = bytes(raw[q:q + count * abs(typ)])
            q += count * abs(typ)
            values = (_strings(block, dims) if typ == -1 else _floats(block, dec) if typ == 4
                      else list(struct.unpack(f"<{count}{'b' if typ == 1 else 'h'}", block)))
            params.append((gid, name, values))
        dlen = struct.unpack_from("<b", raw, q)[0]
        end = q + 1 + max(dlen, 0)
        if end > n:
            raise bad("the parameter section runs past the end of the file")
        if gid < 0:
            groups[-gid] = name
        if off == 0:
            break
        pos = name_end + off
    else:
        raise bad("more than 65536 parameter records")
    out = {(groups.get(g, ""), name): v for g, name, v in params}
    for key in _FIRST_VALUE:
        if key in out and not (out[key] and isinstance(out[key][0], int | float)):
            raise bad(f"parameter {key[0]}:{key[1]} has no number")
    return out


def _parse_c3d(path: Path, raw) -> _C3d:
    """The header and parameters of the C3D bytes ``raw``; :class:`InputFileError` naming the file for
    anything that does not fit in it."""
    def bad(why: str) -> InputFileError:
        return InputFileError(f"{path}: cannot read as a C3D file ({why})")

    size = len(raw)
    if size < 512:
        raise bad(f"{size} bytes, shorter than a C3D header")
    if raw[1] != 0x50:
        raise bad("no C3D header: its second byte is not 0x50")
    base = (raw[0] - 1) * 512
    if raw[0] < 2 or base + 4 > size:
        raise bad(f"the parameter section (block {raw[0]}) is outside the file")
    proc = raw[base + 3]
    if proc not in (84, 85):
        raise bad("big-endian (MIPS) files are not supported" if proc == 86 else f"processor type {proc}")
    dec = proc == 85
    p = _c3d_parameters(bad, raw, base + 4, dec)
    first, last, _, = struct.unpack_from("<HHH", raw, 6)
    head_scale, data_block = _floats(bytes(raw[12:16]), dec)[0], struct.unpack_from("<H", raw, 16)[0]
    head_rate = _floats(bytes(raw[20:24]), dec)[0]

    def value(group: str, name: str, default: float) -> float:
        v = p.get((group, name))
        return float(v[0]) if v and isinstance(v[0], int | float) else default

    n_points = value("POINT", "USED", 0)
    if not 0 < n_points < 2**31:
        raise InputFileError(f"{path}: the C3D file holds no 3D point data (POINT:USED = {n_points:g})")
    # frames as ezc3d counts them: 1-based header frames (0-based when the first is 0), or POINT:FRAMES
    frames = (last - first + 1) if first else last + 1
    declared = value("POINT", "FRAMES", 0)
    if math.isfinite(declared) and int(declared) != 0:
        frames = int(declared)
    scale = value("POINT", "SCALE", -1.0)
    point_rate = value("POINT", "RATE", 0.0)
    rate = point_rate if point_rate != 0 else head_rate
    # analog samples follow the points in every frame (read past, never used)
    n_analog, sub = value("ANALOG", "USED", 0), 1.0
    if math.isfinite(point_rate) and int(point_rate) != 0:
        sub = value("ANALOG", "RATE", 0.0) / point_rate
    if not (0 <= n_analog < 2**31 and math.isfinite(sub) and 0 <= sub < 2**31):
        raise bad(f"{n_analog:g} analog channel(s) at {sub:g} sample(s) per frame")
    frame_bytes = int(n_points) * (16 if scale < 0 else 8) + int(n_analog) * int(sub) * (4 if head_scale < 0 else 2)
    data_start = (data_block - 1) * 512
    if data_block < 2 or data_start + frame_bytes > size:
        raise InputFileError(f"{path}: the C3D file holds no complete frame of {int(n_points)} 3D point(s) "
                             f"(data block {data_block} of a {size}-byte file)")
    return _C3d(p, dec, int(n_points), scale, frames if frames > 0 else None, first - 1 if first else 0,
                rate, frame_bytes, data_start, size)


def _c3d_points(c: _C3d, raw) -> tuple[np.ndarray, np.ndarray]:
    """``(T, P, 3)`` positions and ``(T, P)`` residuals of the complete frames (NaN where the residual
    is negative, as ezc3d gives them)."""
    T = (c.size - c.data_start) // c.frame_bytes
    if c.frames is not None:
        T = min(T, c.frames)
    P, word = c.n_points, 4 if c.scale < 0 else 2
    rec = np.dtype({"names": ["p"], "formats": [(np.uint8, (P, 4 * word))], "itemsize": c.frame_bytes})
    u8 = np.frombuffer(raw, rec, count=T, offset=c.data_start)["p"].reshape(T, P, 4, word)  # raw words
    with np.errstate(invalid="ignore", over="ignore"):
        if word == 4:
            xyz = _dec_floats(u8[:, :, :3]) if c.dec else u8[:, :, :3].copy().view("<f4")[..., 0]
            w = u8[:, :, 3].copy().view("<i2")                                      # (T, P, 2)
            residual = w[..., 0 if c.dec else 1] * -c.scale
        else:
            xyz = u8[:, :, :3].copy().view("<i2")[..., 0] * c.scale
            residual = u8[:, :, 3, 1].view(np.int8) * c.scale
        xyz = xyz.astype(np.float64)
        residual = np.asarray(residual, np.float64)
        xyz[residual < 0] = np.nan
    return xyz, residual


def read_c3d(path: str | os.PathLike, *, zero_is_missing: bool = True) -> Performance:
    """Read the labelled marker trajectories of a C3D file.

    Parameters
    ----------
    path : path-like
        The ``.c3d`` file.
    zero_is_missing : bool
        Also treat a sample at exactly ``(0, 0, 0)`` as missing (how some systems write gaps).

    Returns
    -------
    Performance
        ``points`` (T, P, 3) marker positions in the file's unit, NaN where a marker is missing
        (negative residual, NaN in the file, or an exact zero with ``zero_is_missing``);
        ``labels`` (P,) from ``POINT:LABELS`` (and ``LABELS2``...) with surrounding blanks removed
        (an empty label becomes ``M001``..., a repeated one gets ``_2``, ``_3``... with a warning);
        ``times`` (T,) ``(first_frame + i) / rate`` seconds; ``fps`` the point rate
        (``POINT:RATE``); ``unit`` ``POINT:UNITS`` as written (e.g. ``"mm"``; None when absent);
        ``source`` the path.

    Raises
    ------
    InputFileError
        Missing, unreadable or malformed file (a count or pointer of the header or a parameter that
        does not fit in the file), a big-endian (MIPS) file, a file without 3D points or frames, or
        one without a positive point rate.
    InvalidDataError
        An infinite coordinate.

    Warns
    -----
    DataWarning
        Markers that are missing in every frame (naming them), repeated labels, or a truncated file:
        fewer frames than its header declares, or a size that is not a whole number of 512-byte
        blocks.
    """
    path = input_file(path)
    try:
        with open(path, "rb") as f:
            raw = f.read()
    except OSError as e:
        raise InputFileError(f"{path}: cannot read ({e.strerror or e})") from e
    c = _parse_c3d(path, raw)
    xyz, residual = _c3d_points(c, raw)
    n_frames = len(xyz)
    if not (np.isfinite(c.rate) and c.rate > 0):
        raise InputFileError(f"{path}: the C3D file has no positive point rate (POINT:RATE = {c.rate:g})")
    point = {name: {"value": v} for (g, name), v in c.params.items() if g == "POINT"}
    units = _param(point, "UNITS")
    unit = str(units[0]).strip() if units and isinstance(units[0], str) and units[0].strip() else None
    labels, dup = _labels(point, c.n_points)
    if dup:
        warnings.warn(f"{path}: repeated marker label(s) {', '.join(excerpt(d, bare=True) for d in dup[:20])}"
                      f"{' ...' if len(dup) > 20 else ''}; later ones renamed with "
                      "a _2, _3... suffix", DataWarning, stacklevel=2)
    pts = _marker_points(path, xyz, residual, labels, zero_is_missing)
    if c.frames is not None and n_frames < c.frames:
        warnings.warn(f"{path}: holds {n_frames} frame(s) but its header declares {c.frames}; "
                      "the file may be truncated", DataWarning, stacklevel=2)
    elif c.size % 512:
        warnings.warn(f"{path}: {c.size} bytes, not a whole number of 512-byte C3D blocks; the file may be "
                      f"truncated (all {n_frames} frame(s) were read)", DataWarning, stacklevel=2)
    times = (c.first_frame + np.arange(n_frames)) / c.rate
    return Performance(times=times, fps=c.rate, points=pts, labels=labels, unit=unit, source=str(path))


def _marker_points(path: Path, xyz: np.ndarray, residual: np.ndarray, labels: list[str],
                   zero_is_missing: bool) -> np.ndarray:
    """(T, P, 3) marker positions, NaN where missing (warns, for the caller, about never-seen markers)."""
    pts = xyz
    missing = ~np.isfinite(pts).all(axis=2) & ~np.isinf(pts).any(axis=2)
    missing |= residual < 0
    if zero_is_missing:
        missing |= (pts == 0.0).all(axis=2)
    pts[missing] = np.nan
    never = np.flatnonzero(missing.all(axis=0))
    if never.size:
        shown = ", ".join(excerpt(labels[i], bare=True) for i in never[:20]) + (
            f" and {never.size - 20} more" if never.size > 20 else "")
        warnings.warn(f"{path}: marker(s) missing in every frame: {shown}", DataWarning, stacklevel=3)
    return pts


def write_c3d(path: str | os.PathLike, perf: Performance, *, unit: str | None = None) -> Path:
    """Write a 3D points performance as a C3D file, whole or not at all.

    Parameters
    ----------
    path : path-like
        Output ``.c3d``.
    perf : Performance
        ``points`` (T, P, 3); NaN samples are written as invalid (residual -1, coordinates 0).
        ``labels`` name the markers (``M001``... when absent).  Frames must be evenly spaced at
        ``fps`` (C3D has one rate and no per-frame times); ``times[0] * fps`` is written as the
        first frame when it is a whole non-negative number, else the take starts at frame 0 with a
        warning.
    unit : str, optional
        ``POINT:UNITS``; defaults to ``perf.unit``, then ``"mm"``.

    Returns
    -------
    Path
        ``path``.

    Raises
    ------
    InvalidDataError
        Not a 3D points performance, or frames not evenly spaced at ``fps``.
    OutputError
        The file cannot be written (nothing is left behind).
    """
    path = check_output_path(path)
    if perf.points is None or perf.points.shape[2] != 3:
        what = perf.kind if perf.points is None else "2D points"
        raise InvalidDataError(f"{perf.source}: a C3D file holds 3D points, this take holds {what}")
    pts = perf.points
    T, P, _ = pts.shape
    if T == 0 or P == 0:
        raise InvalidDataError(f"{perf.source}: nothing to write ({T} frames of {P} points)")
    fps = float(perf.fps)
    first = _first_frame(perf, fps, T)
    labels = list(perf.labels) if perf.labels else [f"M{i + 1:03d}" for i in range(P)]
    unit = unit or perf.unit or "mm"

    ezc3d = _ezc3d()
    c = _c3d_of_points(ezc3d, pts, fps, labels, unit, first)
    _save_c3d(path, c)
    return path


def _first_frame(perf: Performance, fps: float, T: int) -> int:
    """The take's first frame number at ``fps`` (0, with a warning, when not a whole number).

    Raises :class:`InvalidDataError` when the frames are not evenly spaced at ``fps``.
    """
    frame = (perf.times - perf.times[0]) * fps
    off = np.abs(frame - np.arange(T))
    if off.max() > 0.01:
        k = int(np.argmax(off > 0.01))
        raise InvalidDataError(f"{perf.source}: frame {k} (t={perf.times[k]:.6f} s) is not on the "
                               f"{fps:g} fps grid; a C3D file needs evenly spaced frames "
                               "(resample the take first)")
    f0 = perf.times[0] * fps
    first = int(round(f0))
    if first < 0 or abs(f0 - first) > 0.01:
        warnings.warn(f"{perf.source}: the first frame time {perf.times[0]:.6f} s is not a whole frame "
                      f"number at {fps:g} fps; written as frame 0", DataWarning, stacklevel=3)
        first = 0
    return first


def _c3d_of_points(ezc3d, pts: np.ndarray, fps: float, labels: list[str], unit: str, first: int):
    """An ``ezc3d.c3d`` holding the (T, P, 3) points (NaN ones invalid: residual -1, coordinates 0)."""
    T, P, _ = pts.shape
    c = ezc3d.c3d()
    c["parameters"]["POINT"]["RATE"]["value"] = [fps]
    c["parameters"]["POINT"]["LABELS"]["value"] = labels
    c["parameters"]["POINT"]["DESCRIPTIONS"]["value"] = [""] * P
    c["parameters"]["POINT"]["UNITS"]["value"] = [unit]
    c["header"]["points"]["first_frame"] = first
    missing = ~np.isfinite(pts).all(axis=2)  # (T, P)
    data = np.ones((4, P, T))
    data[:3] = np.where(missing[..., None], 0.0, pts).transpose(2, 1, 0)
    c["data"]["points"] = data
    c["data"]["meta_points"] = {"residuals": np.where(missing, -1.0, 0.0).T[None]}
    return c


def _save_c3d(path: Path, c) -> None:
    """Write ``c`` to ``path``, whole or not at all."""
    with atomic_path(path) as tmp:
        named = tmp.with_name(tmp.name + ".c3d")  # ezc3d appends .c3d to any other name
        try:
            c.write(str(named))
            os.replace(named, tmp)
        except (RuntimeError, ValueError, TypeError) as e:
            raise OutputError(f"{path}: cannot write C3D ({e})") from e
        finally:
            named.unlink(missing_ok=True)
