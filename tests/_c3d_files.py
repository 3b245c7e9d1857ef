"""C3D files written byte by byte, in every variant of the format the C3D specification allows, for the
conformance tests (tests/test_conformance.py): Intel, DEC (VAX) and SGI/MIPS (big-endian) processor types;
integer (scaled) and float storage; analog samples in every frame; header events and an EVENT group;
header and parameter counts that disagree; frame counts beyond 65535 (TRIAL fields, POINT:LONG_FRAMES, a
float POINT:FRAMES); a file with no parameters at all.

The writer is independent of faceretarget's reader: the tests read every file with ezc3d and py-c3d too,
and compare all three with the points written here.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass, field

import numpy as np

INTEL, DEC, MIPS = 84, 85, 86


def _ieee_to_dec(values: np.ndarray) -> bytes:
    """float32 values as DEC (VAX F) floats: IEEE little-endian bytes ``i0 i1 i2 i3`` -> ``i2 i3+1 i0 i1``
    (the exponent bias differs by 2, a factor 4)."""
    b = np.asarray(values, "<f4").reshape(-1).view(np.uint8).reshape(-1, 4).astype(np.int16)
    out = np.stack([b[:, 2], np.where(b[:, 3] | b[:, 2] | b[:, 1] | b[:, 0], b[:, 3] + 1, 0), b[:, 0], b[:, 1]], 1)
    return out.astype(np.uint8).tobytes()


@dataclass
class C3dSpec:
    """What :func:`make_c3d` writes.  ``points`` (T, P, 3) in mm; NaN = an invalid sample (residual -1)."""

    points: np.ndarray
    labels: list[str]
    rate: float = 100.0
    processor: int = INTEL
    floats: bool = True              # float storage (POINT:SCALE < 0) or scaled 16-bit integers
    scale: float = 0.1               # |POINT:SCALE| for integer storage (mm per unit)
    analog_channels: int = 0
    analog_per_frame: int = 0        # samples of each channel per point frame
    first_frame: int = 1             # header word 4 (1-based)
    events: list[tuple[str, float]] = field(default_factory=list)
    # disagreements and omissions
    header_points: int | None = None         # header word 2 (default: P)
    header_analog: int | None = None         # header word 3 (default: channels x samples)
    header_scale_sign: int | None = None     # sign of the header's scale (default: the parameter's)
    header_last: int | None = None           # header word 5 (default first + T - 1, capped at 65535)
    point_frames: object = "int"             # POINT:FRAMES: "int" (16 bit), "float", None (absent) or a number
    trial_fields: bool = False               # TRIAL:ACTUAL_START_FIELD / ACTUAL_END_FIELD
    long_frames: bool = False                # POINT:LONG_FRAMES (float)
    analog_rate: bool = True                 # ANALOG:RATE present
    point_rate: bool = True                  # POINT:RATE present
    parameters: bool = True                  # a parameter section at all
    units: str = "mm"
    extra_blocks: int = 0                    # whole blocks of zeros after the data


class _Out:
    """Bytes in the file's byte order."""

    def __init__(self, proc: int):
        self.proc = proc
        self.e = ">" if proc == MIPS else "<"

    def ints(self, fmt: str, *v) -> bytes:
        return struct.pack(self.e + fmt, *v)

    def floats(self, values) -> bytes:
        a = np.asarray(values, np.float32).reshape(-1)
        if self.proc == DEC:
            return _ieee_to_dec(a)
        return a.astype(self.e + "f4").tobytes()


def _param(o: _Out, gid: int, name: str, typ: int, dims: list[int], data: bytes, last: bool = False) -> bytes:
    nm = name.encode()
    body = struct.pack("<bB", typ, len(dims)) + bytes(dims) + data + b"\0"   # no description
    off = 0 if last else 2 + len(body)
    return struct.pack("<bb", len(nm), gid) + nm + o.ints("H", off) + body


def _group(o: _Out, gid: int, name: str) -> bytes:
    nm = name.encode()
    return struct.pack("<bb", len(nm), -gid) + nm + o.ints("H", 3) + b"\0"


def _chars(strings: list[str]) -> tuple[list[int], bytes]:
    w = max([1] + [len(s) for s in strings])
    return [w, len(strings)], b"".join(s.ljust(w).encode() for s in strings)


def make_c3d(spec: C3dSpec) -> bytes:
    """The bytes of a C3D file holding ``spec``."""
    o = _Out(spec.processor)
    pts = np.asarray(spec.points, np.float64)
    T, P, _ = pts.shape
    C, S = spec.analog_channels, spec.analog_per_frame
    scale = -1.0 if spec.floats else abs(spec.scale)
    # ---- data: one record per frame, points (x, y, z, residual word) then analog samples
    frames = []
    rng = np.random.default_rng(7)
    analog = rng.integers(-2000, 2000, size=(T, S, C))
    for t in range(T):
        rec = b""
        for p in range(P):
            x = pts[t, p]
            bad = not np.isfinite(x).all()
            if spec.floats:
                rec += o.floats(np.zeros(3) if bad else x)
                rec += o.floats([-1.0 if bad else 0.25])                     # residual word as a float
            else:
                q = np.zeros(3, int) if bad else np.round(x / scale).astype(int)
                rec += o.ints("hhh", *q)
                rec += o.ints("h", -1 if bad else (0x0100 | 2))              # cameras | residual
        if C and S:
            rec += o.floats(analog[t]) if spec.floats else o.ints(f"{S * C}h", *analog[t].reshape(-1))
        frames.append(rec)
    data = b"".join(frames)
    # ---- parameters
    groups = [(1, "POINT"), (2, "ANALOG")] + ([(3, "TRIAL")] if spec.trial_fields else []) + (
        [(4, "EVENT")] if spec.events else [])
    recs = [_group(o, g, n) for g, n in groups]
    dims, lab = _chars(spec.labels)
    recs.append(_param(o, 1, "USED", 2, [], o.ints("h", P)))
    recs.append(_param(o, 1, "SCALE", 4, [], o.floats([scale])))
    if spec.point_rate:
        recs.append(_param(o, 1, "RATE", 4, [], o.floats([spec.rate])))
    recs.append(_param(o, 1, "LABELS", -1, dims, lab))
    recs.append(_param(o, 1, "UNITS", -1, [len(spec.units)], spec.units.encode()))
    if spec.point_frames == "int":
        recs.append(_param(o, 1, "FRAMES", 2, [], o.ints("H", min(T, 65535))))
    elif spec.point_frames == "float":
        recs.append(_param(o, 1, "FRAMES", 4, [], o.floats([T])))
    elif spec.point_frames is not None:
        recs.append(_param(o, 1, "FRAMES", 2, [], o.ints("H", int(spec.point_frames) & 0xFFFF)))
    if spec.long_frames:
        recs.append(_param(o, 1, "LONG_FRAMES", 4, [], o.floats([T])))
    recs.append(_param(o, 2, "USED", 2, [], o.ints("h", C)))
    if spec.analog_rate:
        recs.append(_param(o, 2, "RATE", 4, [], o.floats([spec.rate * S])))
    if C:
        d, lab = _chars([f"A{i}" for i in range(C)])
        recs.append(_param(o, 2, "LABELS", -1, d, lab))
        recs.append(_param(o, 2, "SCALE", 4, [C], o.floats(np.full(C, 0.01))))
        recs.append(_param(o, 2, "OFFSET", 2, [C], o.ints(f"{C}h", *([0] * C))))
        recs.append(_param(o, 2, "GEN_SCALE", 4, [], o.floats([1.0])))
    if spec.trial_fields:
        start, end = spec.first_frame, spec.first_frame + T - 1
        recs.append(_param(o, 3, "ACTUAL_START_FIELD", 2, [2], o.ints("HH", start & 0xFFFF, start >> 16)))
        recs.append(_param(o, 3, "ACTUAL_END_FIELD", 2, [2], o.ints("HH", end & 0xFFFF, end >> 16)))
    if spec.events:
        n = len(spec.events)
        recs.append(_param(o, 4, "USED", 2, [], o.ints("h", n)))
        times = np.array([[0.0, t] for _, t in spec.events]).reshape(-1)   # (2, n): minutes, seconds
        recs.append(_param(o, 4, "TIMES", 4, [2, n], o.floats(times)))
        d, lab = _chars([s for s, _ in spec.events])
        recs.append(_param(o, 4, "LABELS", -1, d, lab))
    # the last record ends the section (offset 0)
    last = recs.pop()
    recs.append(_relink_last(o, last))
    body = b"".join(recs)
    n_blocks = (4 + len(body) + 511) // 512
    psection = bytes([1, 0x50, n_blocks, spec.processor]) + body
    psection += b"\0" * (n_blocks * 512 - len(psection))
    if not spec.parameters:
        psection = b""
    data_block = 2 + (n_blocks if spec.parameters else 0)
    # ---- header
    hp = spec.header_points if spec.header_points is not None else P
    ha = spec.header_analog if spec.header_analog is not None else C * S
    hs = abs(scale) * (spec.header_scale_sign if spec.header_scale_sign is not None else np.sign(scale))
    last_frame = spec.header_last if spec.header_last is not None else min(spec.first_frame + T - 1, 65535)
    head = bytes([2 if spec.parameters else 1, 0x50])
    head += o.ints("HHHHH", hp, ha, spec.first_frame, last_frame, 10)
    head += o.floats([hs])
    head += o.ints("HH", data_block, S)
    head += o.floats([spec.rate])
    head += b"\0" * (294 - len(head))
    if spec.events:
        n = len(spec.events)
        head += o.ints("HHHHH", 0, 0, 0x3039, n, 0)                   # words 148-152
        head += o.floats([t for _, t in spec.events] + [0.0] * (18 - n))
        head += bytes([1] * n + [0] * (18 - n)) + b"\0\0"
        head += b"".join(s[:4].ljust(4).encode() for s, _ in spec.events) + b"\0" * (4 * (18 - n))
    head += b"\0" * (512 - len(head))
    raw = head + psection + data
    raw += b"\0" * ((-len(raw)) % 512) + b"\0" * (512 * spec.extra_blocks)
    return raw


def _relink_last(o: _Out, rec: bytes) -> bytes:
    """A parameter record with its offset-to-next set to 0 (the last record)."""
    nchar = abs(struct.unpack_from("<b", rec, 0)[0])
    return rec[:2 + nchar] + o.ints("H", 0) + rec[4 + nchar:]


def smooth_take(T: int = 120, P: int = 12, seed: int = 0) -> np.ndarray:
    """(T, P, 3) markers moving smoothly over a face-sized volume (mm), a few samples missing."""
    rng = np.random.default_rng(seed)
    base = rng.uniform(-80, 80, size=(P, 3)) + [0, 1600, 0]
    t = np.arange(T)[:, None, None] / 100.0
    pts = base + 5 * np.sin(2 * np.pi * (t * rng.uniform(0.3, 2.0, (P, 3)) + rng.uniform(0, 1, (P, 3))))
    pts[5, 1] = np.nan
    pts[30:34, 2] = np.nan
    return pts
