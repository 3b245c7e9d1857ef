"""Fuzzed readers: every file reader on mutated copies of small valid files.

Each reader gets one or more small valid seed files (written here, in a temporary folder, by the
package's own writers or by hand); every case applies one to three mutations to a seed in memory and
writes the result to one file (or, for a rig folder, one file of the folder) before reading it:

* bytes: truncation, bit flips, insertions and deletions of random bytes, a duplicated range, an
  empty file, random garbage, another format's seed under this extension;
* text (OBJ, CSV, BVH, rig side files): a number replaced by ``nan`` / ``inf`` / ``1e30`` /
  ``1e999`` / ``-1`` / ``""`` ..., lines swapped, duplicated, deleted or shuffled, CSV columns
  swapped, deleted or duplicated (in every row, the header only or one row), the text re-encoded as
  UTF-16 / UTF-32 / latin-1 / cp1252 / with a BOM or NUL bytes;
* binary (C3D, WAV, mp4, glb): a float32/float64 NaN, inf or 1e30, or an extreme integer, written
  over the bytes at a position; for ``.glb`` the JSON chunk also gets the text mutations and is
  packed back with correct chunk lengths;
* ``.npz``: an array element set to NaN / inf / 1e30, an array dropped, reshaped, cut to no rows,
  cast to another dtype (strings, ints, complex, object -- a pickle), two arrays swapped, an extra
  array added; then the archive is written again.

The only outcomes allowed (:func:`run_case`): a correct read (finite data of consistent shapes; NaN
only where the format means "missing": an occluded C3D marker) or a
:class:`~faceretarget.errors.FaceRetargetError` whose message names the file, on one printable line
of at most :data:`MAX_MESSAGE` characters besides the path.  Anything else is a failure: another
exception type, non-finite or inconsistent data, a warning that is not a
:class:`~faceretarget.errors.FaceRetargetWarning`, or a case running longer than the per-case time
limit (a ``SIGALRM`` watchdog; a loop inside a C extension is only caught once it returns).

``tests/test_fuzz.py`` draws the same mutations through Hypothesis (2,000 cases per reader in the
short profile); this script draws them from a seeded ``random.Random`` per (reader, case), so a
failure is replayed with ``--reader NAME --case I``.

Usage::

    python bench/fuzz.py [--json] [--cases 100000] [--reader obj ...] [--case I] [--timeout 2]

With ``--json`` the last line of stdout is one JSON object::

    {"readers": {NAME: {"cases": n, "failures": k}}, "cli": {"cases": n, "failures": k}, "startup_s": s}

(``startup_s`` the median of 5 runs of ``faceretarget --version``); every failure is printed before
it, with the reader, the case number, the mutation and the exception.
"""

from __future__ import annotations

import argparse
import contextlib
import functools
import io
import json
import math
import random
import re
import shutil
import signal
import statistics
import struct
import subprocess
import sys
import tempfile
import threading
import time
import warnings
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from faceretarget.errors import FaceRetargetError, FaceRetargetWarning, MissingDependencyError

#: Longest error message allowed, not counting the file path(s) it names.
MAX_MESSAGE = 300
#: Seconds one case may take (``FACERETARGET_FUZZ_TIMEOUT`` in the tests).
TIMEOUT = 2.0

READER_NAMES = ("obj", "rig", "livelinkface", "c3d", "bvh", "wav", "npz_take", "npz_rig", "glb", "video",
                "control_table", "svg")


# ------------------------------------------------------------------------------------------- draws
class RandomDraw:
    """The draw interface of the mutations, from a seeded :class:`random.Random`."""

    def __init__(self, seed: str):
        self.rng = random.Random(seed)

    def integer(self, lo: int, hi: int) -> int:
        """An integer in ``[lo, hi]``."""
        return self.rng.randint(lo, hi)

    def choice(self, seq):
        return seq[self.rng.randrange(len(seq))]

    def data(self, n_max: int) -> bytes:
        return self.rng.randbytes(self.rng.randint(1, n_max))


# ---------------------------------------------------------------------------------------- mutations
_NUMBER = re.compile(rb"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?")
NUMBERS = (b"nan", b"NaN", b"-nan", b"inf", b"-inf", b"Infinity", b"1e30", b"-1e30", b"1e308", b"1e999",
           b"-1e999", b"-0", b"", b"0x1F", b"1_0", b"99999999999999999999", b"2147483648", b"-2147483649",
           b"-1", b"-2", b"-3", b"0", b"3.4e38", b"1e-320", b" ", b"1,5", b"+", b"1e", b"\xff", b"\xc3\xa9")
BINARY_VALUES = tuple(
    [struct.pack(e + "f", v) for e in "<>" for v in (math.nan, math.inf, -math.inf, 1e30, -1e30)]
    + [struct.pack(e + "d", v) for e in "<>" for v in (math.nan, math.inf, 1e30)]
    + [struct.pack(e + f, v) for e in "<>" for f, v in (("h", -1), ("H", 0xFFFF), ("h", 0x7FFF), ("H", 0),
                                                          ("H", 1), ("i", -1), ("I", 0x7FFFFFFF),
                                                          ("I", 0xFFFFFFFF), ("I", 0), ("I", 1))])
ENCODINGS = ("utf-16", "utf-16-le", "utf-16-be", "utf-32", "latin-1", "cp1252", "utf-8-sig", "nul")


def _pos(d, data: bytes) -> int:
    return d.integer(0, max(len(data) - 1, 0))


def _bytes_op(d, data: bytes, foreign: list[bytes]) -> tuple[bytes, str]:
    """One byte-level mutation of ``data``."""
    op = d.choice(("truncate", "bitflip", "insert", "delete", "duplicate", "empty", "garbage", "foreign"))
    n = len(data)
    if op == "truncate":
        p = _pos(d, data)
        return data[:p], f"truncate at {p} of {n}"
    if op == "bitflip":
        out = bytearray(data)
        flips = []
        for _ in range(d.integer(1, 4)):
            if not out:
                break
            p, b = _pos(d, out), d.integer(0, 7)
            out[p] ^= 1 << b
            flips.append(f"{p}.{b}")
        return bytes(out), f"bit flip {' '.join(flips)}"
    if op == "insert":
        p, x = d.integer(0, n), d.data(16)
        return data[:p] + x + data[p:], f"insert {x!r} at {p}"
    if op == "delete":
        p, k = _pos(d, data), d.integer(1, 64)
        return data[:p] + data[p + k:], f"delete {k} at {p}"
    if op == "duplicate":
        p, k, q = _pos(d, data), d.integer(1, 64), d.integer(0, n)
        return data[:q] + data[p:p + k] + data[q:], f"copy {k} from {p} to {q}"
    if op == "empty":
        return b"", "empty file"
    if op == "garbage":
        x = d.data(512)
        return x, f"{len(x)} random bytes"
    x = d.choice(foreign)
    return x, f"another format's file ({x[:8]!r}...)"


def _lines(data: bytes) -> list[bytes]:
    return data.split(b"\n")


def _text_op(d, data: bytes, csv: bool) -> tuple[bytes, str]:
    """One text-level mutation (numbers, lines, columns, encodings)."""
    ops = ["number", "number", "line_swap", "line_dup", "line_del", "line_shuffle", "encoding"]
    if csv:
        ops += ["col_swap", "col_del", "col_dup"]
    op = d.choice(tuple(ops))
    if op == "number":
        m = list(_NUMBER.finditer(data))
        if not m:
            return data, "no number to replace"
        k = d.integer(0, len(m) - 1)
        x = d.choice(NUMBERS)
        a, b = m[k].span()
        return data[:a] + x + data[b:], f"number {k} {m[k].group()!r} -> {x!r}"
    lines = _lines(data)
    if op.startswith("line_"):
        i, j = d.integer(0, len(lines) - 1), d.integer(0, len(lines) - 1)
        if op == "line_swap":
            lines[i], lines[j] = lines[j], lines[i]
            what = f"swap lines {i + 1} and {j + 1}"
        elif op == "line_dup":
            lines.insert(j, lines[i])
            what = f"copy line {i + 1} before line {j + 1}"
        elif op == "line_del":
            del lines[i]
            what = f"delete line {i + 1}"
        else:
            random.Random(i * 7919 + j).shuffle(lines)
            what = f"shuffle lines ({i}, {j})"
        return b"\n".join(lines), what
    if op == "encoding":
        enc = d.choice(ENCODINGS)
        text = data.decode("utf-8", errors="replace")
        if enc == "nul":
            p = d.integer(0, len(data))
            return data[:p] + b"\x00" * d.integer(1, 4) + data[p:], f"NUL bytes at {p}"
        if enc in ("latin-1", "cp1252"):
            p = d.integer(0, len(text))
            text = text[:p] + d.choice(("é", "ÿ", "µ", "ñ", "é,ü")) + text[p:]
        return text.encode(enc, errors="replace"), f"encoded as {enc}"
    rows = [line.split(b",") for line in lines]
    width = max(len(r) for r in rows)
    i, j = d.integer(0, width - 1), d.integer(0, width - 1)
    where = d.choice(("all", "header", "one"))
    one = d.integer(0, len(rows) - 1)
    for r, row in enumerate(rows):
        if where == "header" and r != 0 or where == "one" and r != one or i >= len(row) or j >= len(row):
            continue
        if op == "col_swap":
            row[i], row[j] = row[j], row[i]
        elif op == "col_del":
            del row[i]
        else:
            row.insert(j, row[i])
    what = f"{op} {i},{j} in {where if where != 'one' else f'row {one + 1}'}"
    return b"\n".join(b",".join(r) for r in rows), what


def _binary_op(d, data: bytes) -> tuple[bytes, str]:
    """An extreme float or integer written over the bytes at a position."""
    x = d.choice(BINARY_VALUES)
    p = _pos(d, data)
    if d.integer(0, 1):
        p -= p % len(x)  # aligned, where array data usually is
    return data[:p] + x + data[p + len(x):], f"write {x.hex()} at {p}"


# ---------------------------------------------------------------------------------------------- npz
def _load_npz(data: bytes) -> dict[str, np.ndarray]:
    """The arrays of an ``.npz`` (a new dict; the arrays of a seed are shared, never changed in place)."""
    return dict(_load_npz_cached(data))


@functools.lru_cache(maxsize=16)
def _load_npz_cached(data: bytes) -> dict[str, np.ndarray]:
    with np.load(io.BytesIO(data), allow_pickle=False) as z:
        return {k: z[k] for k in z.files}


def _save_npz(arrays: dict[str, np.ndarray]) -> bytes:
    buf = io.BytesIO()
    np.savez(buf, **arrays)
    return buf.getvalue()


_DTYPES = ("U8", "int64", "int8", "uint8", "bool", "complex128", "float16", "float32", "object", "S4", "V8")


def _npz_op(d, data: bytes) -> tuple[bytes, str]:
    """One mutation of the arrays of an ``.npz`` seed (which is written again)."""
    with np.errstate(all="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore")  # casts that lose values are the point
        return _npz_op_quiet(d, data)


def _npz_op_quiet(d, data: bytes) -> tuple[bytes, str]:
    arrays = _load_npz(data)
    keys = sorted(arrays)
    k = d.choice(keys)
    a = arrays[k]
    op = d.choice(("value", "value", "drop", "shape", "dtype", "swap", "extra"))
    if op == "value":
        if a.dtype.kind not in "fiu" or a.size == 0:
            arrays[k] = np.array(d.choice((math.nan, math.inf, 1e30, -1)))
            return _save_npz(arrays), f"{k} replaced by a scalar"
        x = d.choice((math.nan, math.inf, -math.inf, 1e30, -1e30, -1.0, 1e9, 0.0))
        i = d.integer(0, a.size - 1)
        b = a.astype(np.float64) if a.dtype.kind != "f" else a.copy()
        b.flat[i] = x
        if a.dtype.kind in "iu" and math.isfinite(x) and d.integer(0, 1):
            b = b.astype(a.dtype)  # an out-of-range index kept as an integer
        arrays[k] = b
        return _save_npz(arrays), f"{k}[{i}] = {x}"
    if op == "drop":
        del arrays[k]
        return _save_npz(arrays), f"drop {k}"
    if op == "shape":
        how = d.choice(("T", "none", "first", "last", "flat", "add", "double", "scalar"))
        b = {"T": lambda: a.T, "none": lambda: a[:0], "first": lambda: a[:1], "last": lambda: a[:-1],
             "flat": lambda: a.reshape(-1), "add": lambda: a[None], "double": lambda: np.concatenate([a, a]),
             "scalar": lambda: a.reshape(-1)[:1].reshape(())}
        try:
            arrays[k] = b[how]()
        except (ValueError, IndexError):
            arrays[k] = a.reshape(-1)
        return _save_npz(arrays), f"{k} reshaped ({how})"
    if op == "dtype":
        dt = d.choice(_DTYPES)
        try:
            arrays[k] = a.astype(dt)
        except (ValueError, TypeError, OverflowError):
            arrays[k] = np.zeros(a.shape, dt)
        return _save_npz(arrays), f"{k} as {dt}"
    if op == "swap":
        k2 = d.choice(keys)
        arrays[k], arrays[k2] = arrays[k2], arrays[k]
        return _save_npz(arrays), f"swap {k} and {k2}"
    name = d.choice(("vertices", "weights", "names", "times", "fps", "poses", "unit", "format", "faces", "x"))
    arrays[name] = d.choice((np.zeros(3), np.array("abc"), np.ones((2, 2)), np.array([], np.float64)))
    return _save_npz(arrays), f"extra {name}"


# ---------------------------------------------------------------------------------------------- glb
def _glb_json_op(d, data: bytes) -> tuple[bytes, str]:
    """A text mutation of the JSON chunk of a ``.glb``, packed back with correct lengths."""
    _, version, _ = struct.unpack_from("<III", data, 0)
    n, _ = struct.unpack_from("<II", data, 12)
    js, rest = data[20:20 + n], data[20 + n:]
    js2, what = _text_op(d, js, csv=False)
    js2 += b" " * (-len(js2) % 4)
    out = struct.pack("<II", len(js2), 0x4E4F534A) + js2 + rest
    return struct.pack("<III", 0x46546C67, version, 12 + len(out)) + out, f"JSON: {what}"


# ------------------------------------------------------------------------------------------ readers
@dataclass
class Reader:
    """A reader under test: seeds, how a case file is named, how it is read and checked."""

    name: str
    suffix: str
    kind: str  # text | csv | binary | npz | glb | folder
    read: Callable[[Path], object]
    check: Callable[[object], str | None]


def _finite(a, what: str, nan_ok: bool = False) -> str | None:
    a = np.asarray(a)
    if a.dtype.kind not in "fc":
        return None
    bad = np.isinf(a) if nan_ok else ~np.isfinite(a)
    return f"{what} holds non-finite values" if bad.any() else None


def _first(*problems) -> str | None:
    return next((p for p in problems if p), None)


def check_mesh(m) -> str | None:
    """Problems of a Mesh read from a file (None when consistent and finite)."""
    v = np.asarray(m.vertices)
    if v.ndim != 2 or v.shape[1] != 3 or len(v) == 0:
        return f"vertices have shape {v.shape}"
    fc, fi = np.asarray(m.face_counts), np.asarray(m.face_indices)
    if fc.size and (fc.min() < 3 or fc.sum() != fi.size):
        return "face counts do not match the face indices"
    if fi.size and (fi.min() < 0 or fi.max() >= len(v)):
        return "a face index is out of range"
    if m.uvs is not None:
        u, ui = np.asarray(m.uvs), np.asarray(m.face_uv_indices)
        if u.ndim != 2 or u.shape[1] != 2 or ui.size != fi.size or (ui.size and (ui.min() < 0 or ui.max() >= len(u))):
            return "UVs do not match the faces"
        if _finite(u, "uvs"):
            return "uvs hold non-finite values"
    return _finite(v, "vertices")


def check_head(h, T: int, nan_ok: bool = False) -> str | None:
    q = np.asarray(h.quaternions)
    if q.shape != (T, 4):
        return f"head quaternions have shape {q.shape} for {T} frames"
    if h.translation is not None and np.shape(h.translation) != (T, 3):
        return "head translation has the wrong shape"
    return _first(_finite(q, "head quaternions", nan_ok),
                  None if h.translation is None else _finite(h.translation, "head translation", nan_ok))


def check_performance(p, nan_points: bool = False) -> str | None:
    """Problems of a take read from a file: finite, consistent shapes (NaN only for missing markers)."""
    t = np.asarray(p.times)
    T = t.size
    if t.ndim != 1 or T == 0:
        return f"times have shape {t.shape}"
    if not np.isfinite(t).all() or (np.diff(t) <= 0).any():
        return "times are not finite and increasing"
    if not (math.isfinite(p.fps) and p.fps > 0):
        return f"fps is {p.fps}"
    problems = []
    if p.weights is not None:
        w = np.asarray(p.weights)
        problems += [None if w.ndim == 2 and w.shape[0] == T and w.shape[1] == len(p.names)
                     else f"weights {w.shape} for {T} frames, {len(p.names)} names", _finite(w, "weights")]
    if p.points is not None:
        x = np.asarray(p.points)
        problems += [None if x.ndim == 3 and x.shape[0] == T and x.shape[2] == 3 and x.shape[1] == len(p.labels)
                     else f"points {x.shape}", _finite(x, "points", nan_points)]
    if p.vertices is not None:
        v = np.asarray(p.vertices)
        problems += [None if v.ndim == 3 and v.shape[0] == T and v.shape[2] == 3 else f"vertices {v.shape}",
                     _finite(v, "vertices")]
        if p.mesh is not None:
            problems.append(check_mesh(p.mesh) or (None if p.mesh.n_vertices == v.shape[1] else "mesh size"))
    if p.head is not None:
        problems.append(check_head(p.head, T))
    if p.curves is not None:
        problems.append(_finite(p.curves, "curves"))
    return _first(*problems)


def check_rig(r) -> str | None:
    d = np.asarray(r.deltas)
    V = r.neutral.n_vertices
    problems = [check_mesh(r.neutral),
                None if d.shape == (len(r.names), V, 3) else f"deltas {d.shape} for {len(r.names)} names",
                _finite(d, "deltas")]
    if r.landmarks is not None:
        lm = np.asarray(r.landmarks)
        problems.append(None if lm.size == 0 or (lm.min() >= 0 and lm.max() < V) else "landmark out of range")
    if r.basis is not None:
        b = np.asarray(r.basis)
        problems += [None if b.shape == (len(r.names), len(r.basis_names)) else f"basis {b.shape}",
                     _finite(b, "basis")]
    return _first(*problems)


def _read_obj(path):
    from faceretarget.io import read_obj

    return read_obj(path)


def _read_rig(path):
    from faceretarget.io import read_rig

    return read_rig(path)


def _read_llf(path):
    from faceretarget.io import read_livelinkface

    return read_livelinkface(path)


def _read_c3d(path):
    from faceretarget.io import read_c3d

    return read_c3d(path)


def _read_bvh(path):
    from faceretarget.io import read_bvh, read_bvh_head

    b = read_bvh(path)
    return b, read_bvh_head(b)


def _check_bvh(res) -> str | None:
    b, p = res
    m = np.asarray(b.motion)
    C = sum(len(j.channels) for j in b.joints)
    return _first(None if m.shape == (b.n_frames, C) else f"motion {m.shape} for {C} channels",
                  _finite(m, "motion"), None if math.isfinite(b.frame_time) and b.frame_time > 0 else "frame time",
                  check_performance(p))


def _read_wav(path):
    from faceretarget.io import read_audio

    return read_audio(path)


def _check_wav(res) -> str | None:
    x, rate = res
    x = np.asarray(x)
    if x.ndim != 1 or x.size == 0 or x.dtype != np.float32:
        return f"samples {x.shape} {x.dtype}"
    if not (math.isfinite(rate) and rate > 0):
        return f"rate {rate}"
    return _finite(x, "samples") or (None if np.abs(x).max() <= 1.0 else "samples outside [-1, 1]")


def _read_npz_take(path):
    from faceretarget.io import read_performance

    return read_performance(path)


def _read_npz_rig(path):
    from faceretarget.io import read_rig_npz

    return read_rig_npz(path)


def _glb_rig(path):
    """``read_glb_rig`` without its DeprecationWarning (any warning but a FaceRetargetWarning is a finding)."""
    from faceretarget.io import read_glb_rig

    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", "read_glb_rig is deprecated", DeprecationWarning)
        return read_glb_rig(path)


def _read_glb(path):
    from faceretarget.io import read_glb_weights, read_gltf_character, read_head_motion

    out = []
    for f in (read_head_motion, read_glb_weights, _glb_rig, read_gltf_character):
        try:
            out.append(f(path))
        except FaceRetargetError as e:
            out.append(e)
    if all(isinstance(x, FaceRetargetError) for x in out):
        raise out[0]
    return out


def _check_glb(res) -> str | None:
    head, weights, rig, character = res
    problems = []
    if not isinstance(character, Exception):
        for m in character.meshes:
            problems += [_finite(m.mesh.vertices, f"{m.name} vertices"), _finite(m.deltas, f"{m.name} deltas"),
                         None if m.deltas.shape == (m.n_shapes, m.mesh.n_vertices, 3) else f"{m.name} deltas shape"]
        problems += [_finite(j.world, f"joint {j.name}") for j in character.joints]
    if not isinstance(head, Exception):
        problems.append(check_performance(head))
    if not isinstance(weights, Exception):
        names, t, w = weights
        problems += [None if w.shape == (t.size, len(names)) else f"weights {w.shape}", _finite(t, "times"),
                     _finite(w, "weights")]
    if not isinstance(rig, Exception):
        problems.append(check_rig(rig))
    return _first(*problems)


def _read_video(path):
    from faceretarget.io import iter_frames, probe_video

    info = probe_video(path)
    return info, list(iter_frames(path))


def _check_video(res) -> str | None:
    info, frames = res
    if not (math.isfinite(info.fps) and info.fps > 0 and info.width > 0 and info.height > 0):
        return f"video info {info}"
    if not (math.isfinite(info.duration) and info.duration >= 0):
        return f"video duration {info.duration}"
    t = np.array([f[1] for f in frames])
    if not np.isfinite(t).all() or (np.diff(t) <= 0).any():
        return "frame times are not finite and increasing"
    shapes = {f[2].shape for f in frames}
    if len(shapes) != 1 or any(len(s) != 3 or s[2] != 3 for s in shapes) or any(f[2].dtype != np.uint8 for f in frames):
        return f"frame shapes {shapes}"
    return None


def _check_perf_nan_points(p) -> str | None:
    return check_performance(p, nan_points=True)


def _read_controls(path):
    from faceretarget.io import read_control_table

    return read_control_table(path)


def _check_controls(t) -> str | None:
    K, M = len(t.keys), len(t.controls)
    if np.shape(t.values) != (K, M) or any(np.shape(a) != (M,) for a in (t.lo, t.hi, t.neutral)):
        return f"control table shapes {np.shape(t.values)} for {K} keys x {M} controls"
    return _first(_finite(t.values, "values"), _finite(t.lo, "lo"), _finite(t.hi, "hi"),
                  _finite(t.neutral, "neutral"), None if np.all(t.lo <= t.hi) else "a range with lo > hi")


def _read_svg(path):
    from faceretarget.io import read_svg_drawing

    return read_svg_drawing(path)


def _check_svg(d) -> str | None:
    pts = np.asarray(d.points)
    if pts.ndim != 2 or pts.shape[1] != 2 or len(pts) == 0:
        return f"drawing points of shape {pts.shape}"
    idx = np.asarray(d.index)
    if idx.size and (idx.min() < 0 or idx.max() >= len(pts)):
        return "a command slot points outside the drawing's points"
    return _finite(pts, "points")


def readers() -> dict[str, Reader]:
    """Every reader under test (without seeds: :func:`make_seeds`)."""
    return {r.name: r for r in (
        Reader("obj", ".obj", "text", _read_obj, check_mesh),
        Reader("rig", "", "folder", _read_rig, check_rig),
        Reader("livelinkface", ".csv", "csv", _read_llf, check_performance),
        Reader("c3d", ".c3d", "binary", _read_c3d, _check_perf_nan_points),
        Reader("bvh", ".bvh", "text", _read_bvh, _check_bvh),
        Reader("wav", ".wav", "binary", _read_wav, _check_wav),
        Reader("npz_take", ".npz", "npz", _read_npz_take, check_performance),
        Reader("npz_rig", ".npz", "npz", _read_npz_rig, check_rig),
        Reader("glb", ".glb", "glb", _read_glb, _check_glb),
        Reader("video", ".mp4", "binary", _read_video, _check_video),
        Reader("control_table", ".csv", "csv", _read_controls, _check_controls),
        Reader("svg", ".svg", "text", _read_svg, _check_svg),
    )}


# -------------------------------------------------------------------------------------------- seeds
_HAND_OBJ = b"""# a hand-written OBJ: comments, normals, groups, negative and a//c corners, CRLF\r
o face\r
v 0 0 0\r
v 1.0 0 0 1.0\r
v 1 1 0  0.5 0.5 0.5\r
v 0 1 0\r
vt 0 0\r
vt 1 0\r
vt 1 1\r
vt 0 1\r
vn 0 0 1\r
g front\r
usemtl skin\r
s 1\r
f 1/1/1 2/2/1 3/3/1 4/4/1\r
f -4//1 -2//1 -1//1\r
l 1 2\r
"""

_HAND_BVH = b"""HIERARCHY
ROOT Hips
{
\tOFFSET 0.0 0.0 0.0
\tCHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation
\tJOINT Neck
\t{
\t\tOFFSET 0.0 150.0 0.0
\t\tCHANNELS 3 Zrotation Xrotation Yrotation
\t\tJOINT Neck1
\t\t{
\t\t\tOFFSET 0.0 5.0 0.0
\t\t\tCHANNELS 3 Zrotation Xrotation Yrotation
\t\t\tJOINT Head
\t\t\t{
\t\t\t\tOFFSET 0.0 8.0 1.0
\t\t\t\tCHANNELS 3 Zrotation Xrotation Yrotation
\t\t\t\tEnd Site
\t\t\t\t{
\t\t\t\t\tOFFSET 0.0 10.0 0.0
\t\t\t\t}
\t\t\t}
\t\t}
\t}
}
MOTION
Frames: 4
Frame Time: 0.0333333
0 90 0 0 0 0 1 2 3 0.5 -1 2 4 5 -6
0.1 90.2 0 0 1 0 2 2 3 0.5 -1 2 4 6 -6
0.2 90.4 0 0 2 0 3 2 3 0.5 -1 2 4 7 -6
0.3 90.6 0 0 3 0 4 2 3 0.5 -1 2 4 8 -6
"""


def _tiny_mesh():
    from faceretarget.mesh import Mesh

    v = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [0.5, 1.5, 0.1]], np.float64) * 0.1
    uv = np.array([[0, 0], [1, 0], [1, 1], [0, 1], [0.5, 1]], np.float64)
    return Mesh(v, [4, 3], [0, 1, 2, 3, 3, 2, 4], uv, [0, 1, 2, 3, 3, 2, 4], name="tiny")


def tiny_rig():
    """A 5-vertex rig (a quad and a triangle, UVs, metres) with 2 key shapes, 3 landmarks and a basis."""
    from faceretarget.rig import Rig

    m = _tiny_mesh()
    rng = np.random.default_rng(0)
    deltas = rng.normal(scale=0.01, size=(2, 5, 3))
    basis = np.array([[1.0, 0.0, 0.25], [0.0, 1.0, 0.5]])
    return Rig(m, ["jawOpen", "eyeBlinkLeft"], deltas, unit="m", landmarks=np.array([0, 2, 4]), name="tiny",
               basis=basis, basis_names=["jawOpen", "eyeBlinkLeft", "mouthClose"])


def _head(T: int, translation: bool = True):
    from faceretarget.headpose import HeadPose

    t = np.linspace(0, 1, T)
    ang = np.stack([0.2 * np.sin(3 * t), 0.1 * np.cos(2 * t), 0.05 * t], axis=1)
    tr = np.stack([0.01 * t, 0.02 * t, -0.01 * t], axis=1) if translation else None
    return HeadPose.from_euler("YXZ", ang, tr)


def make_seeds(folder: Path, data_dir: Path | None = None) -> dict[str, list]:
    """Small valid files for every reader, written in ``folder``: ``{reader: [bytes or {file: bytes}]}``.

    ``data_dir`` (``../shared/data``) is not needed; nothing is read from it.
    """
    from scipy.io import wavfile

    from faceretarget.io import (
        write_animation,
        write_c3d,
        write_head_motion,
        write_npz,
        write_obj,
        write_rig,
        write_rig_npz,
        write_video,
    )
    from faceretarget.names import ARKIT_NAMES
    from faceretarget.performance import Performance

    folder.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(1)
    seeds: dict[str, list] = {}
    mesh, rig = _tiny_mesh(), tiny_rig()

    seeds["obj"] = [write_obj(folder / "tiny.obj", mesh).read_bytes(), _HAND_OBJ]

    rdir = write_rig(rig, folder / "rig")
    seeds["rig"] = [{p.name: p.read_bytes() for p in sorted(rdir.iterdir())}]

    T = 10
    times = np.arange(T) / 30.0
    w = rng.uniform(0, 1, (T, len(ARKIT_NAMES)))
    llf = write_animation(folder / "take.csv", weights=w, names=list(ARKIT_NAMES), times=times,
                          head=_head(T, False)).read_bytes()
    lines = llf.split(b"\n")
    lines.insert(5, lines[5].split(b",")[0] + b",0")  # a lost-face row, as Live Link Face writes it
    hand = b"\r\n".join(lines[:3] + [lines[5].split(b",")[0][:-1] + b"9,0"] + lines[3:]) + b"\r\n0\r\n"
    seeds["livelinkface"] = [llf, hand]

    pts = rng.normal(size=(T, 4, 3)) * 10.0
    pts[3, 1] = np.nan
    c3d = write_c3d(folder / "markers.c3d", Performance.from_points(
        pts, ["Chin", "Nose", "Leye_Up", "Reye_Up"], times=(np.arange(T) + 5) / 60.0, fps=60.0, unit="mm"))
    seeds["c3d"] = [c3d.read_bytes()]

    bvh = write_head_motion(folder / "head.bvh", Performance.from_head(_head(T), fps=30.0))
    seeds["bvh"] = [bvh.read_bytes(), _HAND_BVH]

    wav16 = folder / "a16.wav"
    wavfile.write(wav16, 8000, (rng.normal(size=200) * 3000).astype(np.int16))
    wavf = folder / "af.wav"
    wavfile.write(wavf, 16000, rng.uniform(-0.5, 0.5, (100, 2)).astype(np.float32))
    seeds["wav"] = [wav16.read_bytes(), wavf.read_bytes()]

    verts = mesh.vertices[None] + rng.normal(scale=0.01, size=(4, 5, 3))
    take_v = write_npz(folder / "verts.npz", verts, np.arange(4) / 30.0, mesh, unit="m").read_bytes()
    take_w = _save_npz({"weights": rng.uniform(0, 1, (6, 3)), "names": np.array(["jawOpen", "a", "b"]),
                        "times": np.arange(6) / 30.0})
    smplx = _save_npz({"poses": rng.normal(scale=0.1, size=(6, 165)), "mocap_frame_rate": np.array(30.0)})
    seeds["npz_take"] = [take_v, take_w, smplx]
    seeds["npz_rig"] = [write_rig_npz(rig, folder / "rig.npz").read_bytes()]

    glb = write_animation(folder / "anim.glb", rig=rig, weights=rng.uniform(0, 1, (6, 2)),
                          times=np.arange(6) / 30.0, head=_head(6))
    seeds["glb"] = [glb.read_bytes()]

    from faceretarget.datasets import drawn_face_svgs
    from faceretarget.io import ControlTable, write_control_table

    ct = ControlTable(["frame_00002", "frame_00030", "smile"], ["jawOpen", "mouthSmileLeft", "browInnerUp"],
                      [[0.4, 0.0, 0.1], [0.0, 0.8, 0.0], [0.05, 0.6, 0.25]], [0, 0, -1], [1, 1, 1], [0, 0, 0.0])
    hand_ct = (b"key,jawOpen,mouthSmileLeft,browInnerUp\r\nmin,0,0,-1\r\nmax,1,1,1\r\n"
               b"frame_00002,0.42,,0.1\r\nframe_00030,,0.8,\r\n")
    seeds["control_table"] = [write_control_table(folder / "controls.csv", ct).read_bytes(), hand_ct]
    neutral_svg, key_svgs = drawn_face_svgs(["jawOpen"])
    seeds["svg"] = [neutral_svg.encode(), key_svgs["jawOpen"].encode()]

    frames = [np.full((32, 32, 3), 60 * i, np.uint8) + np.arange(32, dtype=np.uint8)[None, :, None] for i in range(3)]
    try:
        write_video(folder / "clip.mp4", frames, 10.0)
        seeds["video"] = [(folder / "clip.mp4").read_bytes()]
    except MissingDependencyError:  # PyAV (the capture / preview extra) not installed
        seeds["video"] = []
    return seeds


# -------------------------------------------------------------------------------------- one case
def mutate(reader: Reader, seeds: dict[str, list], d) -> tuple[object, str]:
    """A mutated copy of one of ``reader``'s seeds and a description of the mutation."""
    own = seeds[reader.name]
    i = d.integer(0, len(own) - 1)
    seed = own[i]
    foreign = [s for k, v in seeds.items() if k != reader.name for s in v if isinstance(s, bytes)]
    steps = [f"seed {i}"]
    if reader.kind == "folder":
        files = dict(seed)
        name = d.choice(sorted(files))
        op = d.integer(0, 9)
        if op == 0:
            del files[name]
            return files, f"seed {i}: remove {name}"
        if op == 1:
            new = d.choice(("x_neutral.obj", "extra.obj", "identity001.obj", "Neutral.OBJ", "landmarks68.txt"))
            files[new] = files[name]
            return files, f"seed {i}: copy {name} to {new}"
        data, what = _mutate_bytes(reader, d, files[name], foreign)
        files[name] = data
        return files, f"seed {i}: {name}: {what}"
    data, what = _mutate_bytes(reader, d, seed, foreign)
    return data, "; ".join(steps + [what])


def _mutate_bytes(reader: Reader, d, data: bytes, foreign: list[bytes]) -> tuple[bytes, str]:
    steps = []
    for _ in range(d.integer(1, 3)):
        kind = reader.kind
        if kind == "folder":
            kind = "text"
        choices = ["bytes"] + {"text": ["text", "text"], "csv": ["csv", "csv"], "binary": ["binary"],
                               "npz": ["npz", "npz"], "glb": ["glb", "binary"]}[kind]
        family = d.choice(tuple(choices))
        if family == "npz":
            try:
                data, what = _npz_op(d, data)
            except Exception:  # an earlier mutation left no readable npz: mutate its bytes instead
                data, what = _bytes_op(d, data, foreign)
        elif family == "glb":
            try:
                data, what = _glb_json_op(d, data)
            except struct.error:
                data, what = _bytes_op(d, data, foreign)
        elif family in ("text", "csv"):
            data, what = _text_op(d, data, csv=family == "csv")
        elif family == "binary":
            data, what = _binary_op(d, data)
        else:
            data, what = _bytes_op(d, data, foreign)
        steps.append(what)
    return data, "; ".join(steps)


class CaseTimeout(BaseException):
    """A case ran past its time limit (a BaseException, so readers' handlers cannot swallow it)."""


@contextlib.contextmanager
def watchdog(seconds: float) -> Iterator[None]:
    """Raise :class:`CaseTimeout` in the block after ``seconds`` (SIGALRM; main thread only)."""
    if threading.current_thread() is not threading.main_thread() or not hasattr(signal, "setitimer"):
        yield
        return

    def _alarm(signum, frame):
        raise CaseTimeout

    old = signal.signal(signal.SIGALRM, _alarm)
    signal.setitimer(signal.ITIMER_REAL, seconds)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, old)


def _write_case(reader: Reader, case, work: Path) -> tuple[Path, tuple[str, ...]]:
    """Write the case's file(s) in ``work``; return the path to read and the names a message may use."""
    if reader.kind == "folder":
        folder = work / "rig"
        work.mkdir(parents=True, exist_ok=True)
        if folder.exists():
            shutil.rmtree(folder)
        folder.mkdir()
        for name, data in case.items():
            (folder / name).write_bytes(data)
        return folder, (str(folder),)
    work.mkdir(parents=True, exist_ok=True)
    path = work / f"case{reader.suffix}"
    path.write_bytes(case)
    return path, (str(path),)


def _message_problem(msg: str, names: tuple[str, ...]) -> str | None:
    if not any(n in msg for n in names):
        return "the message does not name the file"
    if not msg.isprintable():
        return "the message is not one printable line"
    rest = msg
    for n in names:
        rest = rest.replace(n, "")
    if len(rest) > MAX_MESSAGE:
        return f"the message is {len(rest)} characters long (besides the path)"
    return None


def run_case(reader: Reader, case, work: Path, timeout: float = TIMEOUT) -> str | None:
    """Read one mutated file; None when the outcome is allowed, else what went wrong."""
    path, names = _write_case(reader, case, work)
    t0 = time.perf_counter()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            with watchdog(timeout):
                result = reader.read(path)
            problem = reader.check(result)
        except CaseTimeout:
            return f"hang: no answer within {timeout:g} s"
        except FaceRetargetError as e:
            problem = _message_problem(str(e), names)
            if problem:
                problem = f"{type(e).__name__}: {problem}: {str(e)[:400]!r}"
        except Exception as e:  # every other exception is what the fuzzer looks for
            where = _where(e)
            return f"{type(e).__name__} ({where}): {str(e)[:300]!r}"
    dt = time.perf_counter() - t0
    if problem is None and dt > timeout:
        problem = f"slow: {dt:.1f} s (inside a C extension?)"
    stray = [w for w in caught if not issubclass(w.category, FaceRetargetWarning)]
    if problem is None and stray:
        w = stray[0]
        problem = f"stray warning {w.category.__name__} ({Path(w.filename).name}:{w.lineno}): {str(w.message)[:200]!r}"
    if problem is None:
        for w in caught:
            p = _message_problem(str(w.message), names)
            if p:
                return f"{w.category.__name__}: {p}: {str(w.message)[:400]!r}"
    return problem


def _where(e: BaseException) -> str:
    """The innermost frame of the traceback inside faceretarget (else the innermost)."""
    import traceback

    tb = traceback.extract_tb(e.__traceback__)
    ours = [f for f in tb if "faceretarget" in f.filename and "bench" not in f.filename]
    f = (ours or tb)[-1] if tb else None
    return f"{Path(f.filename).name}:{f.lineno}" if f else "?"


# ---------------------------------------------------------------------------------------------- main
def startup_seconds(runs: int = 5) -> float | None:
    """Median wall time of ``faceretarget --version`` (the venv's console script)."""
    exe = Path(sys.executable).parent / "faceretarget"
    if not exe.exists():
        return None
    times = []
    for _ in range(runs):
        t0 = time.perf_counter()
        done = subprocess.run([str(exe), "--version"], capture_output=True, check=False)
        times.append(time.perf_counter() - t0)
        if done.returncode != 0:
            return None
    return statistics.median(times)


class Worker:
    """A child process that reads the cases, so a crash or a hang inside a C extension (ezc3d, FFmpeg)
    is one failed case instead of the end of the run.

    Cases go to the child's stdin and outcomes come back on its stdout as length-prefixed pickles
    (both ends are this module).  The child has its own ``SIGALRM`` watchdog (:func:`run_case`); the
    parent kills it when no answer comes ``timeout + 5`` s after a case and starts a new one.  The
    child runs with one BLAS / FFmpeg thread and an address-space limit (``memory_gb``), so a file
    that asks for a huge allocation fails as a ``MemoryError`` there.
    """

    def __init__(self, work: Path, timeout: float = TIMEOUT, memory_gb: float = 4.0):
        self.work, self.timeout, self.memory_gb = Path(work), timeout, memory_gb
        self.proc = None
        self.restarts = 0

    def _start(self) -> None:
        import os

        env = dict(os.environ, OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1", MKL_NUM_THREADS="1",
                   NUMBA_NUM_THREADS="1")
        self.proc = subprocess.Popen([sys.executable, str(Path(__file__).resolve()), "--worker", str(self.work),
                                      "--memory-gb", str(self.memory_gb)],
                                     stdin=subprocess.PIPE, stdout=subprocess.PIPE, env=env)

    def run(self, reader: str, case) -> str | None:
        """The outcome of one case (None when allowed, else what went wrong)."""
        import pickle

        if self.proc is None or self.proc.poll() is not None:
            self._start()
        blob = pickle.dumps((reader, case, self.timeout))
        try:
            self.proc.stdin.write(struct.pack("<I", len(blob)) + blob)
            self.proc.stdin.flush()
            reply = self._read(self.timeout + 5.0)
        except (BrokenPipeError, OSError):
            reply = None
        if reply is not None:
            return pickle.loads(reply)
        code = self.proc.poll()
        if code is None:  # no answer: a hang inside a C extension
            self.proc.kill()
            self.proc.wait()
            what = f"hang: no answer within {self.timeout + 5:g} s (killed)"
        else:
            what = f"crash: the reader process died ({_signal_name(code)})"
        self.proc = None
        self.restarts += 1
        return what

    def _read(self, seconds: float) -> bytes | None:
        import os
        import select

        fd = self.proc.stdout.fileno()
        deadline = time.monotonic() + seconds
        buf = b""
        need = 4
        while len(buf) < need:
            left = deadline - time.monotonic()
            if left <= 0 or not select.select([fd], [], [], left)[0]:
                return None
            chunk = os.read(fd, need - len(buf))
            if not chunk:
                return None
            buf += chunk
            if need == 4 and len(buf) == 4:
                need = 4 + struct.unpack("<I", buf)[0]
        return buf[4:]

    def close(self) -> None:
        if self.proc is not None:
            with contextlib.suppress(OSError):
                self.proc.stdin.close()
            try:
                self.proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
            self.proc = None


def _signal_name(code: int) -> str:
    if code < 0:
        with contextlib.suppress(ValueError):
            return f"signal {signal.Signals(-code).name}"
    return f"exit code {code}"


def worker_main(work: Path, memory_gb: float) -> None:
    """The child of :class:`Worker`: read cases from stdin, answer on stdout (fd 1 reserved for that)."""
    import os
    import pickle
    import resource

    proto_out = os.fdopen(os.dup(1), "wb", buffering=0)
    proto_in = os.fdopen(os.dup(0), "rb", buffering=0)
    null = os.open(os.devnull, os.O_RDWR)
    for fd in (0, 1) if os.environ.get("FACERETARGET_FUZZ_VERBOSE") else (0, 1, 2):
        os.dup2(null, fd)  # C libraries printing to stdout cannot corrupt the answers
    if memory_gb > 0:
        lim = int(memory_gb * 2**30)
        with contextlib.suppress(ValueError, OSError):
            resource.setrlimit(resource.RLIMIT_AS, (lim, lim))
    specs = readers()
    work.mkdir(parents=True, exist_ok=True)

    def read_exact(n: int) -> bytes | None:
        buf = b""
        while len(buf) < n:
            chunk = proto_in.read(n - len(buf))
            if not chunk:
                return None
            buf += chunk
        return buf

    while True:
        head = read_exact(4)
        if head is None:
            return
        name, case, timeout = pickle.loads(read_exact(struct.unpack("<I", head)[0]))
        try:
            out = run_case(specs[name], case, work / name, timeout)
        except MemoryError:
            out = "MemoryError (the file asked for more memory than the limit)"
        blob = pickle.dumps(out)
        proto_out.write(struct.pack("<I", len(blob)) + blob)


def fuzz(names, cases: int, timeout: float, first: int = 0, log=print) -> dict[str, dict[str, int]]:
    """Run ``cases`` cases per reader; returns ``{reader: {"cases": n, "failures": k}}``."""
    out: dict[str, dict[str, int]] = {}
    specs = readers()
    with tempfile.TemporaryDirectory(prefix="faceretarget-fuzz-") as tmp:
        seeds = make_seeds(Path(tmp) / "seeds")
        worker = Worker(Path(tmp) / "work", timeout)
        try:
            for name in names:
                r = specs[name]
                if not seeds[name]:
                    log(f"{name}: skipped (no seed: {r.suffix} needs an optional package)", file=sys.stderr)
                    continue
                failures = 0
                t0 = time.perf_counter()
                for i in range(first, first + cases):
                    case, what = mutate(r, seeds, RandomDraw(f"{name}:{i}"))
                    problem = worker.run(name, case)
                    if problem:
                        failures += 1
                        log(f"FAIL {name} case {i}: {what}: {problem}")
                out[name] = {"cases": cases, "failures": failures}
                log(f"{name}: {cases} cases, {failures} failure(s), {time.perf_counter() - t0:.1f} s",
                    file=sys.stderr)
        finally:
            worker.close()
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--cases", type=int, default=100_000, help="cases per reader (default 100,000; 2000 quick)")
    ap.add_argument("--reader", nargs="*", choices=READER_NAMES, default=list(READER_NAMES))
    ap.add_argument("--case", type=int, default=None, help="run only this case number (replay a failure)")
    ap.add_argument("--timeout", type=float, default=TIMEOUT, help="seconds per case")
    ap.add_argument("--json", action="store_true", help="print the summary as JSON on the last line")
    ap.add_argument("--worker", type=Path, default=None, help=argparse.SUPPRESS)
    ap.add_argument("--memory-gb", type=float, default=4.0, help="address-space limit of the reader process")
    ap.add_argument("--no-cli", action="store_true", help="skip the table of bad command-line inputs")
    a = ap.parse_args(argv)
    if a.worker is not None:
        worker_main(a.worker, a.memory_gb)
        return 0
    first, n = (a.case, 1) if a.case is not None else (0, a.cases)
    res = fuzz(a.reader, n, a.timeout, first)
    cli = {"cases": 0, "failures": 0}
    if a.case is None and not a.no_cli:                 # the table of bad CLI inputs (bench/cli_cases.py)
        sys.path.insert(0, str(Path(__file__).resolve().parent))
        from cli_cases import run_cli_cases

        got = run_cli_cases()
        cli = {"cases": got["cases"], "failures": got["failures"]}
        for name, problems in got["failed"]:
            print(f"FAIL cli {name}: {problems}")
    summary = {"readers": res, "cli": cli, "startup_s": startup_seconds()}
    if a.json:
        print(json.dumps(summary))
    else:
        for k, v in res.items():
            print(f"{k:14s} {v['cases']:8d} cases {v['failures']:6d} failures")
        print(f"cli            {cli['cases']:8d} cases {cli['failures']:6d} failures")
        print(f"faceretarget --version: {summary['startup_s']} s")
    return 1 if any(v["failures"] for v in res.values()) or cli["failures"] else 0


if __name__ == "__main__":
    sys.exit(main())
