"""C3D optical motion capture files: labelled 3D marker trajectories.

Written with `ezc3d <https://github.com/pyomeca/ezc3d>`_; read here, in Python, with every count
and pointer of the header and parameter section checked against the file first (ezc3d trusts them
and crashed or hung on fuzzed files), the point data giving the values ezc3d and py-c3d give
(``tests/test_conformance.py``, docs/conformance.md).  Intel, DEC (VAX) and SGI/MIPS (big-endian)
processor types, integer and float storage.  Only the point (marker) data are used; analog channels,
force plates and events are read past (they size the frames) and not written.

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
from ..formats import C3D
from ..optional import optional_import
from ..performance import Performance
from ..units import normalize_unit

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
# the file, and the point data are one NumPy view of the frames the file really holds.
#
# Exporters disagree with each other, and sometimes with themselves, on the counts that size a frame
# (header word 2 against POINT:USED; header word 3 against ANALOG:USED x ANALOG:RATE / POINT:RATE,
# which some files lack; the header's DATA_START block against POINT:DATA_START; the sign of the scale
# in the header against POINT:SCALE).  A wrong frame size reads a smooth take as garbage, so every
# combination the file's own values allow is tried against what the data block holds: the layout
# whose declared frames end in the file's last 512-byte block wins (the parameters when several do,
# unless their frames are much less smooth), and a layout other than the parameters' is read with a
# warning naming the disagreement.  The frame count follows c3d.org's rules (POINT:FRAMES, read as
# unsigned, or as a float; at 65535 TRIAL:ACTUAL_START_FIELD / ACTUAL_END_FIELD or POINT:LONG_FRAMES),
# with the header's frame range as the fallback; a file with no count the data agrees with gives the
# frames it holds, without the zero padding of its last block.

# parameters whose first value is used: present but empty is an error
_FIRST_VALUE = (("POINT", "USED"), ("POINT", "FRAMES"), ("POINT", "RATE"), ("POINT", "SCALE"))
#: Processor types of the parameter section's fourth byte.
_INTEL, _DEC, _MIPS = 84, 85, 86
_BLOCK = 512


@dataclass(frozen=True)
class _C3d:
    """What :func:`_parse_c3d` found: parameters and where the point data are."""

    params: dict          # {(GROUP, NAME): list of numbers, or of strings for a char parameter}
    dec: bool             # DEC (VAX) floats instead of IEEE
    big: bool             # SGI / MIPS: big-endian words
    n_points: int
    scale: float          # negative: float data
    frames: int           # frames to read (all complete)
    declared: int | None  # frames the file declares (None: no usable count)
    first_frame: int      # 0-based
    rate: float           # POINT:RATE, else the header's rate
    frame_bytes: int      # one frame: points and analog samples
    data_start: int       # byte offset of frame 0
    size: int             # file size in bytes
    notes: tuple[str, ...] = ()   # disagreements between the header, the parameters and the data


def _dec_floats(b: np.ndarray) -> np.ndarray:
    """DEC (VAX F) floats, as (..., 4) uint8, to float32 (ezc3d's conversion)."""
    b = np.asarray(b, np.uint8)
    e = np.where(b[..., 1] != 0, b[..., 1] - 1, 0).astype(np.uint8)
    return np.ascontiguousarray(np.stack([b[..., 2], b[..., 3], b[..., 0], e], axis=-1)).view("<f4")[..., 0]


def _floats(block: bytes, dec: bool, big: bool = False) -> list[float]:
    a = np.frombuffer(block, np.uint8).reshape(-1, 4)
    with np.errstate(invalid="ignore"):  # a signalling NaN stays a NaN
        v = _dec_floats(a) if dec else a.copy().view(">f4" if big else "<f4")[:, 0]
        return v.astype(np.float64).tolist()


def _strings(block: bytes, dims: bytes) -> list[str]:
    """A char parameter as ezc3d reads it: one string per column of ``dims[0]`` characters, NULs
    dropped and trailing blanks removed."""
    if not dims or dims[0] == 0:
        return []
    w = dims[0]
    cols = [block[k:k + w].replace(b"\0", b"").decode("utf-8", "replace").rstrip() for k in range(0, len(block), w)]
    return cols if len(dims) > 1 else ["".join(cols)]


def _c3d_parameters(bad, raw, pos: int, dec: bool, big: bool = False, end: int | None = None
                    ) -> dict[tuple[str, str], list]:
    """``{(GROUP, NAME): values}`` of the parameter records from byte ``pos`` on, every count checked.

    ``end``: where the parameter section ends (its block count); a record pointing past it is the last
    one (py-c3d's reading: an SGI sample's last record points into the data).
    """
    n = len(raw)
    stop = n if end is None else min(end, n)
    e = ">" if big else "<"
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
        off = struct.unpack_from(e + "H", raw, name_end)[0]
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
            values = (_strings(block, dims) if typ == -1 else _floats(block, dec, big) if typ == 4
                      else list(struct.unpack(f"{e}{count}{'b' if typ == 1 else 'h'}", block)))
            params.append((gid, name, values))
        dlen = struct.unpack_from("<b", raw, q)[0]
        end = q + 1 + max(dlen, 0)
        if end > n:
            raise bad("the parameter section runs past the end of the file")
        if gid < 0:
            groups[-gid] = name
        if off == 0 or name_end + off >= stop:
            break
        pos = name_end + off
    else:
        raise bad("more than 65536 parameter records")
    out = {(groups.get(g, ""), name): v for g, name, v in params}
    for key in _FIRST_VALUE:
        if key in out and not (out[key] and isinstance(out[key][0], int | float)):
            raise bad(f"parameter {key[0]}:{key[1]} has no number")
    return out


@dataclass(frozen=True)
class _Header:
    """The numbers of the 512-byte header record (words 2-12)."""

    points: int
    analog: int          # analog samples per 3D frame, all channels (word 3)
    first: int
    last: int
    scale: float
    data_block: int
    rate: float


def _header(raw, dec: bool, big: bool) -> _Header:
    e = ">" if big else "<"
    points, analog, first, last = struct.unpack_from(e + "HHHH", raw, 2)
    scale = _floats(bytes(raw[12:16]), dec, big)[0]
    data_block = struct.unpack_from(e + "H", raw, 16)[0]
    rate = _floats(bytes(raw[20:24]), dec, big)[0]
    return _Header(points, analog, first, last, scale, data_block, rate)


def _processor(raw, size: int) -> tuple[int | None, int]:
    """``(processor type, byte offset of the parameter section)``; type None when the file has no
    parameter section (its block pointer is not a block between the header and the end)."""
    block = raw[0]
    base = (block - 1) * _BLOCK
    if block < 2 or base + 4 > size or raw[base + 3] not in (_INTEL, _DEC, _MIPS):
        return None, base
    return raw[base + 3], base


def _declared_frames(p: dict, head: _Header, value) -> list[tuple[int, str, bool]]:
    """The frame counts a file declares, most trusted first: ``(count, where, is_16_bit)``.

    c3d.org's rules: POINT:FRAMES (a signed 16-bit parameter read as unsigned, or a float); at 65535,
    TRIAL:ACTUAL_START_FIELD / ACTUAL_END_FIELD (each two 16-bit words) or POINT:LONG_FRAMES; then the
    header's first and last frame (0-based when the first is 0, as ezc3d writes it).
    """
    out: list[tuple[int, str, bool]] = []
    v = p.get(("POINT", "FRAMES"))
    frames = None
    if v and isinstance(v[0], int | float) and math.isfinite(v[0]):
        frames = int(v[0]) + (65536 if isinstance(v[0], int) and v[0] < 0 else 0)
        sixteen = isinstance(v[0], int)
    if frames is None or frames == 65535:
        s, e = p.get(("TRIAL", "ACTUAL_START_FIELD")), p.get(("TRIAL", "ACTUAL_END_FIELD"))
        if s and e and len(s) >= 2 and len(e) >= 2 and all(isinstance(x, int) for x in (*s[:2], *e[:2])):
            start = (s[0] & 0xFFFF) + ((s[1] & 0xFFFF) << 16)
            end = (e[0] & 0xFFFF) + ((e[1] & 0xFFFF) << 16)
            if end >= start:
                out.append((end - start + 1, "TRIAL:ACTUAL_START_FIELD/ACTUAL_END_FIELD", False))
        long = value("POINT", "LONG_FRAMES", 0.0)
        if math.isfinite(long) and long >= 1:
            out.append((int(long), "POINT:LONG_FRAMES", False))
    if frames is not None and frames > 0:
        out.append((frames, "POINT:FRAMES", sixteen))
    n = (head.last - head.first + 1) if head.first else head.last + 1
    if n > 0:
        out.append((n, "the header's frame range", True))
    seen: set[int] = set()
    return [x for x in out if not (x[0] in seen or seen.add(x[0]))]


@dataclass(frozen=True)
class _Layout:
    points: int
    analog: int
    word: int            # 2: integers, 4: floats
    start: int           # byte offset of frame 0
    why: tuple[str, ...]  # the sources it differs from the parameters in

    @property
    def frame_bytes(self) -> int:
        return (self.points * 4 + self.analog) * self.word


def _layouts(p: dict, head: _Header, value, size: int) -> list[_Layout]:
    """Every frame layout the file's values allow, the parameters' first."""
    def pair(param, header, why: str) -> list[tuple[int, str | None]]:
        """The parameter's value, then the header's when it differs (``why`` it is another layout)."""
        if param is None:
            return [] if header is None else [(header, None)]
        return [(param, None)] + ([(header, why)] if header is not None and header != param else [])

    used = p.get(("POINT", "USED"))
    n_used = int(used[0]) if used and 0 < used[0] < 2**31 else None
    pts = pair(n_used, head.points or None, f"the header's {head.points} points per frame (POINT:USED {n_used})")
    scale = p.get(("POINT", "SCALE"))
    w_param = (4 if scale[0] < 0 else 2) if scale and math.isfinite(scale[0]) else None
    w_head = (4 if head.scale < 0 else 2) if math.isfinite(head.scale) and head.scale != 0 else None
    words = pair(w_param, w_head if w_param is not None else (w_head or 2),
                 f"the header's {'float' if head.scale < 0 else 'integer'} storage (scale {head.scale:g})")
    n_analog, a_rate, p_rate = value("ANALOG", "USED", -1), value("ANALOG", "RATE", 0.0), value("POINT", "RATE", 0.0)
    a_param = None
    if n_analog == 0:
        a_param = 0
    elif 0 < n_analog < 2**31 and p_rate > 0 and math.isfinite(a_rate / p_rate) and a_rate > 0:
        a_param = int(n_analog) * int(a_rate / p_rate)
    analogs = pair(a_param, head.analog, f"the header's {head.analog} analog samples per frame")
    d = p.get(("POINT", "DATA_START"))
    s_param = (int(d[0]) - 1) * _BLOCK if d and isinstance(d[0], int) and d[0] >= 2 else None
    starts = pair(s_param, (head.data_block - 1) * _BLOCK if head.data_block >= 2 else None,
                  f"the header's data block {head.data_block}")
    out = []
    for P, wp in pts:
        for w, ww in words:
            for A, wa in analogs:
                for s, ws in starts:
                    if s + (P * 4 + A) * w <= size:
                        out.append(_Layout(P, A, w, s, tuple(x for x in (wp, ww, wa, ws) if x)))
    return out


def _roughness(lay: _Layout, raw, big: bool, dec: bool, n: int = 200) -> float:
    """How much the first ``n`` frames jump from frame to frame, against their spread (small for a
    take read with its own frame size, about 1 for bytes read at the wrong stride)."""
    T = min(n, (len(raw) - lay.start) // lay.frame_bytes)
    if T < 3:
        return math.inf
    xyz, _ = _point_words(raw, lay.start, lay.frame_bytes, lay.points, lay.word, T, big, dec, 1.0)
    with np.errstate(invalid="ignore", over="ignore"):
        x = np.where(np.abs(xyz) < 1e12, xyz, np.nan)
        jump = np.nanmedian(np.abs(np.diff(x, axis=0))) if np.isfinite(np.diff(x, axis=0)).any() else math.inf
        spread = np.nanmedian(np.abs(x - np.nanmedian(x, axis=0))) if np.isfinite(x).any() else 0.0
    return float(jump / spread) if spread > 0 else (0.0 if jump == 0 else math.inf)


def _choose_layout(layouts: list[_Layout], declared: list[tuple[int, str, bool]], raw, size: int, big: bool,
                   dec: bool) -> tuple[_Layout, int | None]:
    """The layout the data agrees with and the frame count it holds completely (None: no declared
    count ends in the file's last block, or before zeros only)."""
    def complete(lay: _Layout) -> int | None:
        avail = (size - lay.start) // lay.frame_bytes
        for n, _, sixteen in declared:
            for k in range(0, (avail // 65536 + 1) if sixteen else 1):
                m = n + 65536 * k
                end = lay.start + m * lay.frame_bytes
                if m >= 1 and end <= size and (size - end < _BLOCK or not _any_byte(raw, end)):
                    return m
        return None

    fits = [(lay, m) for lay in layouts if (m := complete(lay)) is not None]
    pool = fits or [(lay, None) for lay in layouts]
    if len({lay.frame_bytes for lay, _ in pool}) > 1 or (not fits and len(pool) > 1):
        # several frame sizes agree with the file: the parameters' unless its frames are much rougher
        rough = [_roughness(lay, raw, big, dec) for lay, _ in pool]
        best = int(np.argmin(rough))
        if not rough[0] <= 2.0 * rough[best] + 1e-3:
            return pool[best]
    return pool[0]


def _parse_c3d(path: Path, raw) -> _C3d:
    """The header and parameters of the C3D bytes ``raw``; :class:`InputFileError` naming the file for
    anything that does not fit in it."""
    def bad(why: str) -> InputFileError:
        return InputFileError(f"{path}: cannot read as a C3D file ({why})")

    size = len(raw)
    if size < _BLOCK:
        raise bad(f"{size} bytes, shorter than a C3D header")
    if raw[1] != 0x50:
        raise bad("no C3D header: its second byte is not 0x50")
    proc, base = _processor(raw, size)
    notes: list[str] = []
    if proc is None:
        if raw[0] >= 2 and base + 4 <= size:
            raise bad(f"processor type {raw[base + 3]}")
        # no parameter section: the header alone (its words as Intel, or big-endian when only that fits)
        big = struct.unpack_from("<H", raw, 16)[0] * _BLOCK > size >= struct.unpack_from(">H", raw, 16)[0] * _BLOCK
        dec, p = False, {}
        notes.append(f"no parameter section (block pointer {raw[0]}): read from the header alone, "
                     "markers named M001...")
    else:
        dec, big = proc == _DEC, proc == _MIPS
        blocks = raw[base + 2]
        p = _c3d_parameters(bad, raw, base + 4, dec, big, base + blocks * _BLOCK if blocks else None)
    head = _header(raw, dec, big)

    def value(group: str, name: str, default: float) -> float:
        v = p.get((group, name))
        return float(v[0]) if v and isinstance(v[0], int | float) else default

    if proc is not None and not any(g == "POINT" for g, _ in p):
        notes.append("no POINT parameters: read from the header")
    used = value("POINT", "USED", 0)
    if not (0 < used < 2**31 or 0 < head.points):
        raise InputFileError(f"{path}: the C3D file holds no 3D point data (POINT:USED = {used:g}, "
                             f"header {head.points} points)")
    layouts = _layouts(p, head, value, size)
    if not layouts:
        n = int(used) if 0 < used < 2**31 else head.points
        raise InputFileError(f"{path}: the C3D file holds no complete frame of {n} 3D point(s) "
                             f"(data block {head.data_block} of a {size}-byte file)")
    declared = _declared_frames(p, head, value)
    lay, complete = _choose_layout(layouts, declared, raw, size, big, dec)
    if lay.why:
        notes.append(f"the parameters disagree with {', '.join(lay.why)}; the data block holds frames of "
                     f"{lay.points} point(s) and {lay.analog} analog sample(s) ({lay.frame_bytes} bytes, "
                     f"{'float' if lay.word == 4 else 'integer'}) from byte {lay.start}: read that way")
    avail = (size - lay.start) // lay.frame_bytes
    capped = avail > 65535 and any(sixteen and n == 65535 for n, _, sixteen in declared)
    if complete is not None:
        frames, want = complete, complete
    elif declared and not capped:
        want = declared[0][0]
        frames = min(avail, want)
        if avail > want:
            notes.append(f"{avail - want} frame(s) after the {want} its {declared[0][1]} declares "
                         "were not read")
    else:                           # no count, or a 16-bit one at its limit: the frames the data holds
        frames, want = _without_padding(raw, lay, avail), None
    scale = value("POINT", "SCALE", head.scale)
    if (scale < 0) != (lay.word == 4):
        scale = head.scale if (head.scale < 0) == (lay.word == 4) else (-1.0 if lay.word == 4 else 1.0)
    point_rate = value("POINT", "RATE", 0.0)
    rate = point_rate if point_rate != 0 else head.rate
    return _C3d(p, dec, big, lay.points, scale, frames, want, head.first - 1 if head.first else 0, rate,
                lay.frame_bytes, lay.start, size, tuple(notes))


def _any_byte(raw, start: int) -> bool:
    """Whether any byte from ``start`` on is not zero (more than a block of zeros is padding too)."""
    return bool(np.frombuffer(raw, np.uint8, offset=start).any()) if start < len(raw) else False


def _without_padding(raw, lay: _Layout, avail: int) -> int:
    """Frames of a file that declares no count: the ones it holds, less all-zero frames that start in
    its last 512-byte block (the padding of the block)."""
    T = avail
    size = len(raw)
    while T > 0:
        a = lay.start + (T - 1) * lay.frame_bytes
        if a < size - _BLOCK or any(raw[a:a + lay.frame_bytes]):
            break
        T -= 1
    return T


def _point_words(raw, start: int, frame_bytes: int, P: int, word: int, T: int, big: bool, dec: bool,
                 scale: float) -> tuple[np.ndarray, np.ndarray]:
    """``(T, P, 3)`` coordinates and ``(T, P)`` residuals (negative: invalid) of ``T`` frames."""
    rec = np.dtype({"names": ["p"], "formats": [(np.uint8, (P, 4 * word))], "itemsize": frame_bytes})
    u8 = np.frombuffer(raw, rec, count=T, offset=start)["p"].reshape(T, P, 4, word)  # raw words
    if big:                                   # SGI / MIPS: every word big-endian; as Intel from here on
        u8 = u8[..., ::-1]
    with np.errstate(invalid="ignore", over="ignore"):
        if word == 4:
            xyz = _dec_floats(u8[:, :, :3]) if dec else u8[:, :, :3].copy().view("<f4")[..., 0]
            w = u8[:, :, 3].copy().view("<i2")                                      # (T, P, 2)
            residual = w[..., 0 if dec else 1] * -scale
        else:
            xyz = u8[:, :, :3].copy().view("<i2")[..., 0] * scale
            residual = u8[:, :, 3, 1].view(np.int8) * scale
        return xyz.astype(np.float64), np.asarray(residual, np.float64)


def _c3d_points(c: _C3d, raw) -> tuple[np.ndarray, np.ndarray]:
    """``(T, P, 3)`` positions and ``(T, P)`` residuals of the complete frames (NaN where the residual
    is negative, as ezc3d gives them)."""
    word = 4 if c.scale < 0 else 2
    xyz, residual = _point_words(raw, c.data_start, c.frame_bytes, c.n_points, word, c.frames, c.big, c.dec,
                                 c.scale)
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
        does not fit in the file), an unknown processor type, a file without 3D points or frames, or
        one without a positive point rate.
    InvalidDataError
        An infinite coordinate.

    Warns
    -----
    DataWarning
        Markers that are missing in every frame (naming them), repeated labels, a truncated file
        (fewer frames than it declares), frames sized other than the parameters say (the header's
        point count, analog samples, storage or data block: whichever the data block holds, named),
        data after the declared frames, or a file without parameters (read from its header alone).
    """
    path = input_file(path)
    try:
        with open(path, "rb") as f:
            raw = f.read()
    except OSError as e:
        raise InputFileError(f"{path}: cannot read ({e.strerror or e})") from e
    c = _parse_c3d(path, raw)
    if c.frames < 1:
        raise InputFileError(f"{path}: the C3D file holds no frame of its {c.n_points} 3D point(s)")
    xyz, residual = _c3d_points(c, raw)
    n_frames = len(xyz)
    if not (np.isfinite(c.rate) and c.rate > 0):
        raise InputFileError(f"{path}: the C3D file has no positive point rate (POINT:RATE = {c.rate:g})")
    point = {name: {"value": v} for (g, name), v in c.params.items() if g == "POINT"}
    units = _param(point, "UNITS")
    unit = str(units[0]).strip() if units and isinstance(units[0], str) and units[0].strip() else None
    if unit is not None:
        try:
            unit = normalize_unit(unit)
        except InvalidDataError:
            warnings.warn(f"{path}: POINT:UNITS is {excerpt(unit)}, not a length unit (mm, cm, m, in); the points "
                          "are taken as millimetres, C3D's default", DataWarning, stacklevel=2)
            unit = None
    labels, dup = _labels(point, c.n_points)
    if dup:
        warnings.warn(f"{path}: repeated marker label(s) {', '.join(excerpt(d, bare=True) for d in dup[:20])}"
                      f"{' ...' if len(dup) > 20 else ''}; later ones renamed with "
                      "a _2, _3... suffix", DataWarning, stacklevel=2)
    pts = _marker_points(path, xyz, residual, labels, zero_is_missing)
    for note in c.notes:
        warnings.warn(f"{path}: {note}", DataWarning, stacklevel=2)
    if c.declared is not None and n_frames < c.declared:
        warnings.warn(f"{path}: holds {n_frames} frame(s) but its header declares {c.declared}; "
                      "the file may be truncated", DataWarning, stacklevel=2)
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
    if never.size and never.size == len(labels):
        warnings.warn(f"{path}: no marker is present in any frame (every sample invalid): the file holds no "
                      "usable point", DataWarning, stacklevel=3)
    elif never.size:
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
        named = tmp.with_name(tmp.name + C3D)  # ezc3d appends .c3d to any other name
        try:
            c.write(str(named))
            os.replace(named, tmp)
        except (RuntimeError, ValueError, TypeError) as e:
            raise OutputError(f"{path}: cannot write C3D ({e})") from e
        finally:
            named.unlink(missing_ok=True)
