"""Live Link Face CSV takes (Epic Games' iPhone app): 52 ARKit weights per row plus head and eyes.

Layout::

    Timecode,BlendShapeCount,EyeBlinkLeft,...,TongueOut,HeadYaw,HeadPitch,HeadRoll,LeftEyeYaw,
    LeftEyePitch,LeftEyeRoll,RightEyeYaw,RightEyePitch,RightEyeRoll
    12:21:59:06.595,61,0.0009391578,...

``Timecode`` is ``HH:MM:SS:FF.fff``: ``FF.fff`` is a frame number with a fractional sub-frame in a
timecode base whose rate the file does not state.  The reader infers it as the smallest standard
rate (24, 25, 30, 48, 50, 60, 100, 120) above the largest ``FF`` in the take (pass
``timecode_rate`` when a short take never reaches the top frames).  The shared takes use a 60 base
with a row every 1 or 2 frames (60 or 30 fps).

Rows Live Link Face writes when it loses the face, ``<timecode>,0`` (a blendshape count of 0 and
no values), are dropped wherever they are, with one warning; the remaining frames keep their real
times, so the take has a gap there.
"""

from __future__ import annotations

import math
import os
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import DataWarning, InputFileError, InvalidDataError, excerpt, format_ranges
from ..files import atomic_path, check_output_path, input_file, read_text
from ..headpose import HeadPose
from ..names import ARKIT_NAMES, normalize_name, split_parent
from ..performance import Performance
from ..timebase import infer_fps
from ._obj import _is_number

__all__ = ["read_livelinkface", "write_livelinkface", "LiveLinkFaceInfo", "HEAD_COLUMNS",
           "EYE_COLUMNS", "TIMECODE_RATES", "LLF_NAMES"]

#: Standard timecode rates the reader chooses from.
TIMECODE_RATES: tuple[int, ...] = (24, 25, 30, 48, 50, 60, 100, 120)
HEAD_COLUMNS: tuple[str, ...] = ("HeadYaw", "HeadPitch", "HeadRoll")
EYE_COLUMNS: tuple[str, ...] = ("LeftEyeYaw", "LeftEyePitch", "LeftEyeRoll",
                                "RightEyeYaw", "RightEyePitch", "RightEyeRoll")
#: The 52 weight column names as Live Link Face spells them (PascalCase), in its order.
LLF_NAMES: tuple[str, ...] = tuple(n[:1].upper() + n[1:] for n in ARKIT_NAMES)
_DAY = 86400.0
_MAX_GAP = 60.0  # a timecode this soon after midnight follows one just before it


@dataclass
class LiveLinkFaceInfo:
    """What a Live Link Face file holds besides the weights (see :func:`read_livelinkface`).

    Attributes
    ----------
    start_timecode : str
        Timecode of the first kept row, as written.
    start_seconds : float
        That timecode in seconds since midnight (``Performance.times`` are relative to it).
    timecode_rate : int
        The (inferred or given) timecode base rate, frames per second.
    eye_rotation : (T, 6) float or None
        ``LeftEyeYaw, LeftEyePitch, LeftEyeRoll, RightEyeYaw, RightEyePitch, RightEyeRoll`` as in
        the file.
    dropped_lines : list of int
        1-based file lines that were dropped (trailing junk, no-face rows).
    """

    start_timecode: str
    start_seconds: float
    timecode_rate: int
    eye_rotation: np.ndarray | None = None
    dropped_lines: list[int] = field(default_factory=list)


def _parse_timecode(s: str) -> tuple[int, int, int, float] | None:
    parts = s.strip().split(":")
    if len(parts) != 4:
        return None
    try:
        h, m, sec = int(parts[0]), int(parts[1]), int(parts[2])
        ff = float(parts[3])
    except ValueError:
        return None
    if not (0 <= h < 24 and 0 <= m < 60 and 0 <= sec < 60 and 0 <= ff < TIMECODE_RATES[-1]):
        return None
    if not math.isfinite(ff):
        return None
    return h, m, sec, ff




def read_livelinkface(path: str | os.PathLike, *, timecode_rate: int | None = None,
                      with_info: bool = False) -> Performance | tuple[Performance, LiveLinkFaceInfo]:
    """Read a Live Link Face CSV take.

    Parameters
    ----------
    path : path-like
        The ``.csv`` file.
    timecode_rate : int, optional
        The timecode base rate; inferred from the largest frame number when omitted.
    with_info : bool
        Also return a :class:`LiveLinkFaceInfo` (absolute start timecode, rate, eye angles).

    Returns
    -------
    Performance
        ``weights`` (T, K) with ``names`` in ARKit camelCase (every weight column of the file,
        normally the 52 ARKit shapes; unknown columns are kept under their normalised name),
        ``times`` (T,) seconds relative to the first kept row (so ``times[0] == 0``),
        ``fps = 1 / median(diff(times))``, ``head`` a :class:`~faceretarget.headpose.HeadPose`
        from ``HeadYaw, HeadPitch, HeadRoll`` (radians, Live Link Face's signs; the shared takes
        hold zeros) when the file has those columns, ``source`` the file path; ``timecode`` the
        first kept row's timecode in seconds since midnight and ``timecode_rate`` the timecode
        base rate (so :func:`write_livelinkface` writes the same timecodes back); ``curves`` the
        eye angles ``LeftEyeYaw ... RightEyeRoll`` (radians, as in the file; ``curve_names`` those
        column names) when the file has the six eye columns.
    LiveLinkFaceInfo
        Only with ``with_info=True``.

    Raises
    ------
    InputFileError
        Missing or empty file, a header without ``Timecode``, a malformed row (wrong column count,
        bad timecode, non-numeric value or a time that does not increase) before the last good row
        (naming its 1-based line), or no valid row.  Malformed rows after the last good row are
        dropped with one warning naming their lines.
    InvalidDataError
        A NaN or infinite value in a kept row (naming the file, line and column).
    """
    path = input_file(path)
    lines = read_text(path, encoding="utf-8-sig").splitlines()
    first, header, names, cols = _header(path, lines)
    _check_curves(path, header, names)
    rows = _classify_rows(lines, first, len(header))
    rate = _timecode_rate(path, rows, timecode_rate)
    _parse_values(lines, rows, header)
    t_abs = _row_times(rows, rate, lines)
    good, trailing, noface = _kept_rows(path, rows)
    data = rows.values[good]                                    # columns 1.. of the header
    lines_kept = rows.lineno[good]
    times_abs = t_abs[good]
    if not np.isfinite(data).all():
        r, c = (int(x[0]) for x in np.nonzero(~np.isfinite(data)))
        raise InvalidDataError(f"{path}: line {int(lines_kept[r])}: column '{header[c + 1]}' is "
                               f"{data[r, c]} (frame {r})")
    weights = data[:, [j - 1 for j in cols["weights"]]] if cols["weights"] else np.zeros((len(good), 0))
    head = data[:, [j - 1 for j in cols["head"]]] if cols["head"] else None
    eyes = data[:, [j - 1 for j in cols["eyes"]]] if cols["eyes"] else None
    times = times_abs - times_abs[0]
    pose = None if head is None else HeadPose.from_livelinkface(head, source=str(path))
    perf = Performance(times=times, fps=infer_fps(times, default=float(rate)), weights=weights, names=names,
                       head=pose, source=str(path), timecode=float(times_abs[0]) % _DAY, timecode_rate=rate,
                       curves=eyes, curve_names=list(EYE_COLUMNS) if eyes is not None else [])
    if not with_info:
        return perf
    info = LiveLinkFaceInfo(
        start_timecode=lines[int(lines_kept[0]) - 1].split(",", 1)[0].strip(),
        start_seconds=float(times_abs[0]), timecode_rate=rate, eye_rotation=eyes,
        dropped_lines=sorted(trailing + noface))
    return perf, info


def _check_curves(path: Path, header: list[str], names: list[str]) -> None:
    """A take whose columns drive no ARKit shape is an error; missing standard curves a warning naming them."""
    if not names:
        raise InputFileError(f"{path}: no blendshape curve columns (the header has only "
                             f"{', '.join(header[:8])}): the take would drive nothing")
    known = {n if n in ARKIT_NAMES else split_parent(n) for n in names} & set(ARKIT_NAMES)
    if not known:
        shown = ", ".join(repr(n) for n in names[:4])
        raise InputFileError(f"{path}: none of its {len(names)} curve columns is an ARKit blendshape "
                             f"(first: {shown}); the take would drive nothing. Expected names such as "
                             "'JawOpen' or 'eyeBlink_L' (known prefixes like 'blendshape_' are removed)")
    missing = [n for n in ARKIT_NAMES if n not in known]
    if missing:
        more = f" and {len(missing) - 8} more" if len(missing) > 8 else ""
        warnings.warn(f"{path}: {len(missing)} of the 52 ARKit curves are missing and will be 0: "
                      f"{', '.join(missing[:8])}{more}", DataWarning, stacklevel=3)


# the kinds of row the reader tells apart
_OK, _NOFACE, _JUNK = 0, 1, 2


@dataclass
class _Rows:
    """Every non-blank row after the header: 1-based line, kind, parsed timecode, values, why junk."""

    lineno: np.ndarray
    kind: np.ndarray
    tc: list
    values: np.ndarray
    why: dict


def _header(path: Path, lines: list[str]) -> tuple[int, list[str], list[str], dict]:
    """The header line's index, its cells, the weight names and the columns of weights, head, eyes."""
    first = next((i for i, line in enumerate(lines) if line.strip()), None)
    if first is None:
        raise InputFileError(f"{path}: empty file; expected a Live Link Face CSV "
                             "(header 'Timecode,BlendShapeCount,EyeBlinkLeft,...')")
    header = [c.strip() for c in lines[first].split(",")]
    if header[0].lower() != "timecode":
        raise InputFileError(f"{path}: line {first + 1}: header must start with 'Timecode', got {excerpt(header[0])}; "
                             "is this a Live Link Face CSV?")
    skip = {"timecode", "blendshapecount"}
    other = set(HEAD_COLUMNS) | set(EYE_COLUMNS)
    w_idx = [j for j, c in enumerate(header) if c.lower() not in skip and c not in other]
    head_idx = [header.index(c) if c in header else -1 for c in HEAD_COLUMNS]
    eye_idx = [header.index(c) if c in header else -1 for c in EYE_COLUMNS]
    cols = {"weights": w_idx, "head": head_idx if min(head_idx) >= 0 else None,
            "eyes": eye_idx if min(eye_idx) >= 0 else None}
    return first, header, [normalize_name(header[j]) for j in w_idx], cols


def _classify_rows(lines: list[str], first: int, ncol: int) -> _Rows:
    """Pass 1: the structure of every row (no values parsed yet)."""
    lineno, kind, tcs, why = [], [], [], {}
    for i in range(first + 1, len(lines)):
        line = lines[i]
        if not line.strip():
            continue
        n = line.count(",") + 1
        cell0 = line.split(",", 1)[0]
        tc = _parse_timecode(cell0)
        k = _OK
        if n == 2 and line.split(",", 1)[1].strip() == "0" and tc is not None:
            k = _NOFACE
            why[len(kind)] = "no face (blendshape count 0)"
        elif n != ncol:
            k = _JUNK
            why[len(kind)] = f"has {n} columns, the header has {ncol}"
        elif tc is None:
            k = _JUNK
            why[len(kind)] = f"timecode {excerpt(cell0)} is not HH:MM:SS:FF.fff"
        lineno.append(i + 1)
        kind.append(k)
        tcs.append(tc)
    return _Rows(np.asarray(lineno, np.int64), np.asarray(kind, np.int8), tcs,
                 np.full((len(kind), ncol - 1), np.nan), why)


def _timecode_rate(path: Path, rows: _Rows, given: int | None) -> int:
    """The timecode base rate: given, or the smallest standard rate above the largest frame number."""
    if given is not None:
        return int(given)
    max_ff = max((tc[3] for tc, k in zip(rows.tc, rows.kind, strict=True) if k != _JUNK), default=0.0)
    rate = next((r for r in TIMECODE_RATES if r > max_ff), None)
    if rate is None:
        raise InputFileError(f"{path}: frame numbers reach {max_ff:g}, above every standard "
                             f"timecode rate {TIMECODE_RATES}; pass timecode_rate")
    return rate


def _parse_values(lines: list[str], rows: _Rows, header: list[str]) -> None:
    """Pass 2a: the numbers of every structurally good row, in one vectorised parse (row by row,
    to name the bad cell, only when that fails); a row with a non-number becomes junk."""
    ok = np.flatnonzero(rows.kind == _OK)
    if not ok.size:
        return
    sel = [lines[int(rows.lineno[j]) - 1] for j in ok]
    try:
        vals = np.loadtxt(sel, delimiter=",", usecols=range(1, len(header)), dtype=np.float64, ndmin=2,
                          comments=None)
        if vals.shape == (ok.size, len(header) - 1):
            rows.values[ok] = vals
            return
    except ValueError:
        pass
    for j, line in zip(ok.tolist(), sel, strict=True):
        cells = line.split(",")
        try:
            rows.values[j] = [float(c) for c in cells[1:]]
        except ValueError:
            c, cell = next((c, cell) for c, cell in enumerate(cells[1:], 1) if not _is_number(cell))
            rows.kind[j] = _JUNK
            rows.why[j] = f"column {excerpt(header[c])} value {excerpt(cell.strip())} is not a number"


def _row_times(rows: _Rows, rate: int, lines: list[str]) -> np.ndarray:
    """Pass 2b: each row's absolute time (a day added after midnight); frames at or above the rate
    and times that do not increase make a row junk."""
    t_abs = np.full(len(rows.kind), np.nan)
    prev_t: float | None = None
    offset = 0.0  # whole days added after a midnight wrap
    for j, tc in enumerate(rows.tc):
        if tc is None:
            continue
        h, m, s, ff = tc
        if ff >= rate:
            cell0 = lines[int(rows.lineno[j]) - 1].split(",", 1)[0] if rows.kind[j] == _OK else ""
            rows.kind[j] = _JUNK
            rows.why[j] = f"frame {ff:g} of timecode {excerpt(cell0)} is not below the timecode rate {rate}"
            continue
        t = h * 3600 + m * 60 + s + ff / rate + offset
        if prev_t is not None and t < prev_t and 0 < t + _DAY - prev_t < _MAX_GAP:
            offset += _DAY  # passed midnight
            t += _DAY
        t_abs[j] = t
        if rows.kind[j] == _JUNK:
            continue
        if prev_t is not None and t <= prev_t:
            rows.kind[j] = _JUNK
            rows.why[j] = "time does not increase after the previous row"
            continue
        prev_t = t
    return t_abs


def _kept_rows(path: Path, rows: _Rows) -> tuple[np.ndarray, list[int], list[int]]:
    """The good rows; an error for junk before the last of them, a warning for what is dropped."""
    good = np.flatnonzero(rows.kind == _OK)
    if not good.size:
        first = f"; first problem: line {rows.lineno[0]} {rows.why.get(0, '')}" if len(rows.kind) else ""
        raise InputFileError(f"{path}: no valid data row ({len(rows.kind)} row(s) after the header, none "
                             f"usable{first})")
    last = int(good[-1])
    mid_junk = np.flatnonzero(rows.kind[:last] == _JUNK)
    if mid_junk.size:
        j = int(mid_junk[0])
        more = f"; {mid_junk.size - 1} more bad row(s) follow" if mid_junk.size > 1 else ""
        raise InputFileError(f"{path}: line {rows.lineno[j]}: {rows.why[j]} (malformed rows are only dropped at "
                             f"the end of a take{more})")
    trailing = rows.lineno[last + 1:].tolist()
    noface = rows.lineno[:last][rows.kind[:last] == _NOFACE].tolist()
    if trailing:
        warnings.warn(f"{path}: dropped {len(trailing)} malformed row(s) at the end of the take, "
                      f"line(s) {format_ranges(trailing)} ({rows.why[last + 1]})", DataWarning, stacklevel=3)
    if noface:
        warnings.warn(f"{path}: dropped {len(noface)} row(s) where Live Link Face lost the face "
                      f"(blendshape count 0), line(s) {format_ranges(noface)}; the take has gaps there",
                      DataWarning, stacklevel=3)
    return good, trailing, noface




def _timecodes(t_abs: np.ndarray, rate: int, decimals: int) -> list[str]:
    scale = rate * 10**decimals
    ticks = np.round(np.asarray(t_abs) * scale).astype(np.int64) % int(_DAY * scale)
    secs, rem = np.divmod(ticks, scale)
    h, r = np.divmod(secs, 3600)
    m, s = np.divmod(r, 60)
    width = 3 + decimals if decimals else 2
    ff = rem / 10**decimals
    return [f"{a:02d}:{b:02d}:{c:02d}:{f:0{width}.{decimals}f}"
            for a, b, c, f in zip(h.tolist(), m.tolist(), s.tolist(), ff.tolist(), strict=True)]


def _to_arkit_columns(names: list[str], weights: np.ndarray, source: str) -> np.ndarray:
    """(T, 52) weights in Live Link Face column order from any named weights."""
    norm = [normalize_name(n) for n in names]
    col = {n: j for j, n in enumerate(ARKIT_NAMES)}
    out = np.zeros((weights.shape[0], len(ARKIT_NAMES)))
    halves: dict[int, list[int]] = {}
    dropped = []
    for j, n in enumerate(norm):
        if n in col:
            out[:, col[n]] = weights[:, j]
        elif (p := split_parent(n)) is not None and p in col:
            halves.setdefault(col[p], []).append(j)
        else:
            dropped.append(names[j])
    for c, js in halves.items():
        if not any(norm[i] == ARKIT_NAMES[c] for i in range(len(norm))):
            out[:, c] = weights[:, js].mean(axis=1)
    if dropped:
        shown = ", ".join(dropped[:5]) + (f" (+{len(dropped) - 5} more)" if len(dropped) > 5 else "")
        if len(dropped) == len(names):
            warnings.warn(f"{source}: none of its {len(names)} channel(s) is an ARKit shape ({shown}), so every "
                          "Live Link Face CSV curve is 0; give it ARKit shapes first ('faceretarget character "
                          "shapes')", DataWarning, stacklevel=3)
        else:
            warnings.warn(f"{source}: {len(dropped)} channel(s) are not ARKit shapes and are not written "
                          f"to the Live Link Face CSV: {shown}", DataWarning, stacklevel=3)
    return out


def write_livelinkface(path: str | os.PathLike, perf: Performance, *, rate: int | None = None,
                       start: float | str | None = None, eye_rotation: np.ndarray | None = None,
                       decimals: int = 3) -> Path:
    """Write a weights performance as a Live Link Face CSV, whole or not at all.

    Parameters
    ----------
    path : path-like
        Output ``.csv``.
    perf : Performance
        Weights (names in any spelling) and/or a head pose.  The 52 ARKit columns are written in
        Live Link Face's order (missing ones as 0, all 0 for a take of head motion only; split
        halves such as ``browInnerUpLeft``/``Right`` averaged into the whole; other names dropped
        with a warning).  ``head`` fills ``HeadYaw, HeadPitch, HeadRoll`` in Live Link Face's
        convention (:meth:`~faceretarget.headpose.HeadPose.to_livelinkface`; zeros when absent,
        and in frames without a pose).
    rate : int, optional
        Timecode base rate (frames per second of the ``FF`` field); default the take's
        ``timecode_rate``, else 60.
    start : float or str, optional
        Timecode of the first frame, seconds since midnight or ``"HH:MM:SS:FF.fff"``; frame ``i``
        is written at ``start + times[i] - times[0]``.  Default: the take's own timecode
        (``perf.timecode + times[0]``, so a take read from a Live Link Face CSV keeps its clock),
        else ``00:00:00:00``.
    eye_rotation : (T, 6) float, optional
        Eye yaw, pitch, roll left then right; default the take's curves named like the six eye
        columns (``LeftEyeYaw`` ...), else zeros.
    decimals : int
        Decimals of the sub-frame part of the timecode (Live Link Face writes 3).

    Returns
    -------
    Path
        ``path``.
    """
    path = check_output_path(path)
    if perf.weights is None and perf.head is None:
        raise InvalidDataError(f"{perf.source}: a Live Link Face CSV holds weights and head angles, this take "
                               f"holds {perf.kind}")
    if rate is None:
        rate = perf.timecode_rate if perf.timecode_rate is not None else 60
    if not float(rate).is_integer() or rate <= 0:
        raise InvalidDataError(f"{perf.source}: a Live Link Face timecode rate is a positive whole number of "
                               f"frames per second, got {rate}")
    rate = int(rate)
    if start is None:
        start = perf.timecode + float(perf.times[0]) if perf.timecode is not None else 0.0
    if eye_rotation is None and perf.curves is not None and set(EYE_COLUMNS) <= set(perf.curve_names):
        eye_rotation = perf.curves[:, [perf.curve_names.index(c) for c in EYE_COLUMNS]]
    if isinstance(start, str):
        tc = _parse_timecode(start)
        if tc is None or tc[3] >= rate:
            raise InvalidDataError(f"start timecode {start!r} is not HH:MM:SS:FF.fff at rate {rate}")
        start = tc[0] * 3600 + tc[1] * 60 + tc[2] + tc[3] / rate
    T = perf.n_frames
    w = (_to_arkit_columns(perf.names, perf.weights, perf.source) if perf.weights is not None
         else np.zeros((T, len(ARKIT_NAMES))))
    head = np.zeros((T, 3)) if perf.head is None else np.nan_to_num(perf.head.to_livelinkface()) + 0.0  # no -0
    eyes = np.zeros((T, 6)) if eye_rotation is None else np.asarray(eye_rotation, dtype=np.float64)
    if eyes.shape != (T, 6):
        raise InvalidDataError(f"{perf.source}: eye_rotation must be ({T}, 6), got {eyes.shape}")
    tcs = _timecodes(float(start) + perf.times - perf.times[0], rate, decimals)
    if len(set(tcs)) != T:
        raise InvalidDataError(f"{perf.source}: frames closer than the timecode resolution "
                               f"(1/{rate} s / 10^{decimals}); raise rate or decimals")
    header = ",".join(("Timecode", "BlendShapeCount") + LLF_NAMES + HEAD_COLUMNS + EYE_COLUMNS)
    count = len(LLF_NAMES) + len(HEAD_COLUMNS) + len(EYE_COLUMNS)
    vals = np.concatenate([w, head, eyes], axis=1)
    fmt = ",".join(["%.10f"] * vals.shape[1])
    body = "".join(f"{tc},{count}," + (fmt % tuple(row)) + "\n" for tc, row in zip(tcs, vals.tolist(), strict=True))
    with atomic_path(path) as tmp:
        tmp.write_text(header + "\n" + body, encoding="utf-8")
    return path
