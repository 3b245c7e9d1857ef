"""C3D optical motion capture files: labelled 3D marker trajectories.

Read and written with `ezc3d <https://github.com/pyomeca/ezc3d>`_.  Only the point (marker) data
is used; analog channels, force plates and events are ignored on read and not written.

A C3D sample whose residual is negative is invalid (the marker was occluded); such samples become
NaN.  Some systems instead write a gap as a point at exactly ``(0, 0, 0)``; with
``zero_is_missing=True`` (the default) those samples are NaN too.

Times are ``(first_frame + i) / rate`` where ``first_frame`` is the header's 0-based first frame, so
a take cut out of a longer recording keeps its place in time; :func:`write_c3d` writes
``round(times[0] * fps)`` back as the first frame.
"""

from __future__ import annotations

import os
import struct
import warnings
from pathlib import Path

import numpy as np

from ..errors import DataWarning, InputFileError, InvalidDataError, OutputError
from ..files import atomic_path, check_output_path, input_file
from ..optional import optional_import
from ..performance import Performance

__all__ = ["read_c3d", "write_c3d"]


def _ezc3d():
    return optional_import("ezc3d", "reading and writing C3D files")


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


def _declared_frames(path: Path) -> int | None:
    """Frame count the raw C3D header declares (``last - first + 1``), or None when unreadable."""
    try:
        with open(path, "rb") as f:
            head = f.read(512)
            if len(head) < 512 or head[1] != 0x50 or head[0] < 1:
                return None
            f.seek((head[0] - 1) * 512)
            ph = f.read(4)
    except OSError:
        return None
    if len(ph) < 4:
        return None
    endian = ">" if ph[3] == 86 else "<"  # processor type 86 = MIPS (big-endian); Intel, DEC little
    first, last = struct.unpack(endian + "HH", head[6:10])
    return last - first + 1 if last >= first >= 1 else None


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
        Missing, unreadable or malformed file, a file without 3D points or frames, or one without a
        positive point rate.

    Warns
    -----
    DataWarning
        Markers that are missing in every frame (naming them), repeated labels, or a file holding
        fewer frames than its header declares (a truncated file).
    """
    path = input_file(path)
    c = _open_c3d(path)
    data = _point_data(path, c)
    n_points, n_frames = int(data.shape[1]), int(data.shape[2])
    point = c["parameters"]["POINT"]
    rate = _point_rate(path, c, point)
    units = _param(point, "UNITS")
    unit = str(units[0]).strip() if units is not None and len(units) and str(units[0]).strip() else None
    labels, dup = _labels(point, n_points)
    if dup:
        warnings.warn(f"{path}: repeated marker label(s) {', '.join(dup)}; later ones renamed with "
                      "a _2, _3... suffix", DataWarning, stacklevel=2)

    pts = _marker_points(path, c, data, labels, zero_is_missing)
    declared = _declared_frames(path)
    if declared is not None and n_frames < declared:
        warnings.warn(f"{path}: holds {n_frames} frame(s) but its header declares {declared}; "
                      "the file may be truncated", DataWarning, stacklevel=2)
    first = int(c["header"]["points"]["first_frame"])
    times = (first + np.arange(n_frames)) / rate
    return Performance(times=times, fps=rate, points=pts, labels=labels, unit=unit, source=str(path))


def _open_c3d(path: Path):
    """The ``ezc3d.c3d`` of ``path`` (an :class:`InputFileError` when ezc3d cannot read it)."""
    ezc3d = _ezc3d()
    try:
        return ezc3d.c3d(str(path))
    except (OSError, RuntimeError, ValueError, IndexError) as e:
        raise InputFileError(f"{path}: cannot read as a C3D file "
                             f"({str(e).strip() or type(e).__name__})") from e


def _point_data(path: Path, c) -> np.ndarray:
    """The (4, P, T) point array of the file; an error when it holds no point or no frame."""
    data = c["data"]["points"]
    if data.ndim != 3 or data.shape[1] == 0 or data.shape[2] == 0:
        n_p = data.shape[1] if data.ndim == 3 else 0
        raise InputFileError(f"{path}: the C3D file holds no 3D point data ({n_p} points, "
                             f"{data.shape[2] if data.ndim == 3 else 0} frames)")
    return data


def _point_rate(path: Path, c, point: dict) -> float:
    """The point rate: the header's, else ``POINT:RATE``; it must be positive."""
    rate = float(c["header"]["points"]["frame_rate"] or 0.0)
    prate = _param(point, "RATE")
    if not rate > 0 and prate is not None and len(prate):
        rate = float(prate[0])
    if not (np.isfinite(rate) and rate > 0):
        raise InputFileError(f"{path}: the C3D file has no positive point rate (POINT:RATE = {rate})")
    return rate


def _marker_points(path: Path, c, data: np.ndarray, labels: list[str], zero_is_missing: bool) -> np.ndarray:
    """(T, P, 3) marker positions, NaN where missing (warns, for the caller, about never-seen markers)."""
    n_points, n_frames = int(data.shape[1]), int(data.shape[2])
    pts = np.ascontiguousarray(np.asarray(data[:3], dtype=np.float64).transpose(2, 1, 0))  # (T, P, 3)
    missing = ~np.isfinite(pts).all(axis=2)
    meta = c["data"]["meta_points"] if "meta_points" in c["data"].keys() else {}
    res = meta.get("residuals")
    if res is not None and np.shape(res) == (1, n_points, n_frames):
        missing |= np.asarray(res[0]).T < 0
    if zero_is_missing:
        missing |= (pts == 0.0).all(axis=2)
    pts[missing] = np.nan
    never = np.flatnonzero(missing.all(axis=0))
    if never.size:
        warnings.warn(f"{path}: marker(s) missing in every frame: {', '.join(labels[i] for i in never)}",
                      DataWarning, stacklevel=3)
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
