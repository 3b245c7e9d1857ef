"""Control tables: a target rig's own control (slider) values per keyshape, and control curves.

An artist poses the target rig with its own sliders for each source keyshape (``keys select``
exports them) and saves the slider values in one table (:func:`read_control_table`).

CSV (``.csv``): a header row naming the controls, then one row per key named in the first column::

    key,jawOpen,mouthSmileLeft,browInnerUp
    range,0:1,0:1,0:1
    neutral,0,0,0
    frame_00123,0.42,,0.1
    frame_00456,,0.8,

* ``range`` (required): each control's declared range as ``lo:hi`` (``lo..hi`` also reads), or
  instead two rows ``min`` and ``max``;
* ``neutral`` (optional): the controls at the rig's rest pose (default all 0);
* every other row is a key, named like the source keyshape it poses (``frame_00123``, or its label);
  an empty cell is a slider left at its neutral value.

JSON (``.json``)::

    {"controls": ["jawOpen", "mouthSmileLeft"],
     "range": {"jawOpen": [0, 1], "mouthSmileLeft": [0, 1]},     (or a list of [lo, hi])
     "neutral": {"jawOpen": 0},                                   (optional)
     "keys": {"frame_00123": {"jawOpen": 0.42}, "frame_00456": [0, 0.8]}}

:func:`write_control_template` writes the empty CSV for an artist to fill;
:func:`write_control_curves` writes control curves over time (``time,<controls>`` CSV, or JSON
``{"times": [...], "controls": {name: [...]}}``); Live Link Face CSVs (ARKit controls) go through
:func:`~faceretarget.io.write_animation`.
"""

from __future__ import annotations

import csv
import io as _io
import json
import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import InputFileError, InvalidDataError, OutputError, excerpt
from ..files import atomic_path, check_output_path, input_file, read_text
from ..formats import CSV, JSON
from ..names import normalize_name

__all__ = ["ControlTable", "read_control_table", "write_control_template", "write_control_table",
           "write_control_curves", "CONTROL_TABLE_FORMATS"]

#: Extensions :func:`read_control_table` reads.
CONTROL_TABLE_FORMATS = (CSV, JSON)
#: Largest magnitude of a control value or range end (nothing a slider holds comes near it).
_MAX_VALUE = 1e6
_SPECIAL = ("range", "min", "max", "neutral")


@dataclass(eq=False)
class ControlTable:
    """A target rig's control values per key.

    Attributes
    ----------
    keys : list of str
        Key names (as written), one per row of ``values``.
    controls : list of str
        Control names (as written), one per column.
    values : (K, M) float
        The controls of each key.
    lo, hi : (M,) float
        Each control's declared range.
    neutral : (M,) float
        The controls at rest (what weight 0 of every key gives).
    source : str
        The file, for messages.
    rows : list of str, optional
        Where each key is in the file (``"line 5"``), for messages.
    """

    keys: list[str]
    controls: list[str]
    values: np.ndarray
    lo: np.ndarray
    hi: np.ndarray
    neutral: np.ndarray
    source: str = "controls"
    rows: list[str] | None = None

    def __post_init__(self) -> None:
        K, M = len(self.keys), len(self.controls)
        self.values = np.asarray(self.values, dtype=np.float64).reshape(K, M)
        self.lo = np.asarray(self.lo, dtype=np.float64).reshape(M)
        self.hi = np.asarray(self.hi, dtype=np.float64).reshape(M)
        self.neutral = np.asarray(self.neutral, dtype=np.float64).reshape(M)
        if K == 0 or M == 0:
            raise InvalidDataError(f"{self.source}: a control table needs at least one key row and one control "
                                   f"column, got {K} keys and {M} controls")
        for what, names in (("control", self.controls), ("key", self.keys)):
            seen: set[str] = set()
            for n in names:
                if n in seen:
                    raise InvalidDataError(f"{self.source}: {what} '{excerpt(n, bare=True)}' is named twice")
                seen.add(n)
        same: dict[str, str] = {}
        for c in self.controls:                # two spellings of one control drive one shape twice
            n = normalize_name(c)
            if n in same:
                raise InvalidDataError(f"{self.source}: controls '{excerpt(same[n], bare=True)}' and "
                                       f"'{excerpt(c, bare=True)}' name one control ({excerpt(n, bare=True)}); "
                                       "keep one column")
            same[n] = c
        for what, a in (("values", self.values), ("range", np.stack([self.lo, self.hi])), ("neutral", self.neutral)):
            if not np.isfinite(a).all():
                raise InvalidDataError(f"{self.source}: the {what} hold a non-finite number")
        bad = np.flatnonzero(~(self.lo < self.hi))
        if bad.size:
            j = int(bad[0])
            raise InvalidDataError(f"{self.source}: control '{self.controls[j]}' has range {self.lo[j]:g}:{self.hi[j]:g} "
                                   "(the low end must be below the high end)")

    def in_range(self, values: np.ndarray) -> np.ndarray:
        """Boolean mask of ``values`` ``(..., M)`` inside the declared ranges (ends included)."""
        v = np.asarray(values, dtype=np.float64)
        return (v >= self.lo) & (v <= self.hi)


# ---------------------------------------------------------------------------------------- reading
def _number(path: Path, where: str, s) -> float:
    if isinstance(s, bool) or not isinstance(s, int | float | str):
        raise InputFileError(f"{path}: {where}: {excerpt(s)} is not a number")
    try:
        v = float(s)
    except ValueError:
        raise InputFileError(f"{path}: {where}: {excerpt(s)} is not a number") from None
    if not abs(v) <= _MAX_VALUE:
        raise InputFileError(f"{path}: {where}: {excerpt(s)} is not a finite number within +-{_MAX_VALUE:g}")
    return v


def _range_cell(path: Path, where: str, s: str) -> tuple[float, float]:
    for sep in ("..", ":"):
        if sep in s:
            a, b = s.split(sep, 1)
            return _number(path, where, a.strip()), _number(path, where, b.strip())
    raise InputFileError(f"{path}: {where}: range {excerpt(s)} is not 'lo:hi' (e.g. 0:1)")


def _read_csv(path: Path) -> ControlTable:
    text = read_text(path)
    try:
        rows = list(csv.reader(_io.StringIO(text)))
    except csv.Error as e:
        raise InputFileError(f"{path}: not a CSV table ({excerpt(e, 80)})") from None
    rows = [(n + 1, r) for n, r in enumerate(rows) if any(c.strip() for c in r)]
    if len(rows) < 2:
        raise InputFileError(f"{path}: a control table needs a header row of control names and rows of keys")
    _, header = rows[0]
    controls = [c.strip() for c in header[1:]]
    while controls and not controls[-1]:
        controls.pop()
    if not controls:
        raise InputFileError(f"{path}: line 1: the header names no control (key,<control>,<control>,...)")
    for j, c in enumerate(controls):
        if not c or not c.isprintable():
            raise InputFileError(f"{path}: line 1: column {j + 2} has no control name ({excerpt(c)})")
    M = len(controls)
    special: dict[str, tuple[int, list[str]]] = {}
    keys: list[str] = []
    cells: list[tuple[int, list[str]]] = []
    for ln, r in rows[1:]:
        name = r[0].strip() if r else ""
        extra = [c for c in r[1 + M:] if c.strip()]
        if extra:
            raise InputFileError(f"{path}: line {ln}: {len(r) - 1} values for {M} controls")
        vals = [c.strip() for c in r[1:1 + M]] + [""] * max(0, M - (len(r) - 1))
        if not name:
            raise InputFileError(f"{path}: line {ln}: the row has no key name in its first column")
        if not name.isprintable() or len(name) > 200:
            raise InputFileError(f"{path}: line {ln}: key name {excerpt(name)} is not a name")
        low = name.lower()
        if low in _SPECIAL:
            if low in special:
                raise InputFileError(f"{path}: line {ln}: a second '{name}' row")
            special[low] = (ln, vals)
            continue
        keys.append(name)
        cells.append((ln, vals))
    if "range" in special:
        ln, vals = special["range"]
        if "min" in special or "max" in special:
            raise InputFileError(f"{path}: line {ln}: give a 'range' row or 'min' and 'max' rows, not both")
        lohi = []
        for j, s in enumerate(vals):
            if not s:
                raise InputFileError(f"{path}: line {ln}: no range for control '{controls[j]}'")
            lohi.append(_range_cell(path, f"line {ln}, control '{controls[j]}'", s))
        lo, hi = np.array(lohi).T
    elif "min" in special and "max" in special:
        ends = []
        for key in ("min", "max"):
            ln, vals = special[key]
            for j, s in enumerate(vals):
                if not s:
                    raise InputFileError(f"{path}: line {ln}: no {key} for control '{controls[j]}'")
            ends.append([_number(path, f"line {ln}, control '{controls[j]}'", s) for j, s in enumerate(vals)])
        lo, hi = np.array(ends)
    else:
        raise InputFileError(f"{path}: no 'range' row: declare each control's range in a row named 'range' "
                             "(cells lo:hi, e.g. 0:1) or in rows 'min' and 'max'")
    neutral = np.zeros(M)
    if "neutral" in special:
        ln, vals = special["neutral"]
        neutral = np.array([0.0 if not s else _number(path, f"line {ln}, control '{controls[j]}'", s)
                            for j, s in enumerate(vals)])
    if not keys:
        raise InputFileError(f"{path}: no key rows (one row per source keyshape, named like it)")
    values = np.array([[neutral[j] if not s else _number(path, f"line {ln}, control '{controls[j]}'", s)
                        for j, s in enumerate(vals)] for ln, vals in cells])
    return ControlTable(keys, controls, values, lo, hi, neutral, source=str(path),
                        rows=[f"line {ln}" for ln, _ in cells])


def _json_vector(path: Path, what: str, obj, controls: list[str], default: float | None) -> np.ndarray:
    """A per-control value from a ``{control: value}`` mapping or a list in control order."""
    M = len(controls)
    if isinstance(obj, list):
        if len(obj) != M:
            raise InputFileError(f"{path}: {what} has {len(obj)} values for {M} controls")
        return np.array([_number(path, f"{what}[{j}]", v) for j, v in enumerate(obj)])
    if isinstance(obj, dict):
        unknown = [k for k in obj if k not in controls]
        if unknown:
            raise InputFileError(f"{path}: {what} names control '{excerpt(unknown[0], bare=True)}', which is not "
                                 "in 'controls'")
        out = []
        for c in controls:
            if c not in obj:
                if default is None:
                    raise InputFileError(f"{path}: {what} has no value for control '{c}'")
                out.append(default)
            else:
                out.append(_number(path, f"{what}['{c}']", obj[c]))
        return np.array(out)
    raise InputFileError(f"{path}: {what} must be a list or an object, got {type(obj).__name__}")


def _read_json(path: Path) -> ControlTable:
    try:
        doc = json.loads(read_text(path))
    except ValueError as e:
        raise InputFileError(f"{path}: not JSON ({excerpt(e, 80)})") from None
    if not isinstance(doc, dict):
        raise InputFileError(f"{path}: a control table is a JSON object with 'controls', 'range' and 'keys'")
    if unknown := sorted(set(doc) - {"controls", "range", "neutral", "keys"}):
        raise InputFileError(f"{path}: unknown key '{excerpt(unknown[0], bare=True)}' (a control table has "
                             "'controls', 'range', 'neutral' and 'keys')")
    controls = doc.get("controls")
    if not isinstance(controls, list) or not controls or not all(isinstance(c, str) and c for c in controls):
        raise InputFileError(f"{path}: 'controls' must be a non-empty list of control names")
    if "range" not in doc:
        raise InputFileError(f"{path}: no 'range': declare each control's range ({{\"name\": [lo, hi]}} or a list "
                             "of [lo, hi])")
    rng = doc["range"]
    if isinstance(rng, dict):
        missing = [c for c in controls if c not in rng]
        if missing:
            raise InputFileError(f"{path}: 'range' has no entry for control '{excerpt(missing[0], bare=True)}'")
        pairs = [rng[c] for c in controls]
    elif isinstance(rng, list) and len(rng) == len(controls):
        pairs = rng
    else:
        raise InputFileError(f"{path}: 'range' must map every control to [lo, hi]")
    lohi = []
    for c, p in zip(controls, pairs, strict=True):
        if not (isinstance(p, list) and len(p) == 2):
            raise InputFileError(f"{path}: range of control '{excerpt(c, bare=True)}' must be [lo, hi], got {excerpt(p)}")
        lohi.append([_number(path, f"range of '{c}'", v) for v in p])
    lo, hi = np.array(lohi).T
    neutral = (_json_vector(path, "'neutral'", doc["neutral"], controls, 0.0) if "neutral" in doc
               else np.zeros(len(controls)))
    keys = doc.get("keys")
    if not isinstance(keys, dict) or not keys:
        raise InputFileError(f"{path}: 'keys' must map each key name to its control values")
    names, values = [], []
    for name, v in keys.items():
        row = _json_vector(path, f"key '{excerpt(name, bare=True)}'", v, controls, np.nan)
        row = np.where(np.isnan(row), neutral, row)          # a slider not named is left at its neutral value
        names.append(name)
        values.append(row)
    return ControlTable(names, list(controls), np.array(values), lo, hi, neutral, source=str(path),
                        rows=[f"keys['{excerpt(n, bare=True)}']" for n in names])


def read_control_table(path: str | os.PathLike) -> ControlTable:
    """Read a control table (module docstring): ``.csv`` or ``.json``.

    Returns
    -------
    ControlTable

    Raises
    ------
    InputFileError
        A missing file, an unknown extension, no ``range``, a cell that is not a number (naming the
        line and the control), a row of the wrong length, or a key or control named twice.
    """
    path = input_file(path)
    ext = path.suffix.lower()
    if ext == CSV:
        return _read_csv(path)
    if ext == JSON:
        return _read_json(path)
    raise InputFileError(f"{path}: unknown control-table format '{ext}' (use {', '.join(CONTROL_TABLE_FORMATS)})")


# ---------------------------------------------------------------------------------------- writing
def _fmt(v: float) -> str:
    return f"{float(v):.10g}"


def write_control_template(path: str | os.PathLike, keys: Sequence[str], controls: Sequence[str], *,
                           lo: Sequence[float] | float = 0.0, hi: Sequence[float] | float = 1.0,
                           neutral: Sequence[float] | None = None) -> Path:
    """Write the empty control table an artist fills: one row per key, one column per control.

    Parameters
    ----------
    path : path-like
        Output ``.csv``.
    keys : sequence of str
        Key names (the source keyshapes' names, e.g. ``frame_00123``).
    controls : sequence of str
        The target rig's control names.
    lo, hi : float or sequence of float
        The controls' declared range (the ``range`` row).
    neutral : sequence of float, optional
        The controls at rest (a ``neutral`` row; default none, i.e. all 0).
    """
    path = check_output_path(path)
    if path.suffix.lower() != CSV:
        raise OutputError(f"{path}: a control-table template is a .csv")
    M = len(controls)
    lo_a = np.broadcast_to(np.asarray(lo, dtype=np.float64), (M,))
    hi_a = np.broadcast_to(np.asarray(hi, dtype=np.float64), (M,))
    ControlTable(list(keys), list(controls), np.zeros((len(keys), M)), lo_a, hi_a,
                 np.zeros(M) if neutral is None else neutral, source=str(path))     # the same checks as a read
    buf = _io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(["key", *controls])
    w.writerow(["range", *[f"{_fmt(a)}:{_fmt(b)}" for a, b in zip(lo_a, hi_a, strict=True)]])
    if neutral is not None:
        w.writerow(["neutral", *[_fmt(v) for v in neutral]])
    for k in keys:
        w.writerow([k, *[""] * M])
    with atomic_path(path) as tmp:
        tmp.write_text(buf.getvalue(), encoding="utf-8")
    return path


def write_control_table(path: str | os.PathLike, table: ControlTable) -> Path:
    """Write a :class:`ControlTable` as a ``.csv`` (``range`` and ``neutral`` rows, then one row per
    key; values in full precision, so :func:`read_control_table` gives them back exactly)."""
    path = check_output_path(path)
    if path.suffix.lower() != CSV:
        raise OutputError(f"{path}: a control table is written as .csv")
    buf = _io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(["key", *table.controls])
    w.writerow(["range", *[f"{float(a)!r}:{float(b)!r}" for a, b in zip(table.lo, table.hi, strict=True)]])
    w.writerow(["neutral", *[repr(float(v)) for v in table.neutral]])
    for k, row in zip(table.keys, table.values, strict=True):
        w.writerow([k, *[repr(float(v)) for v in row]])
    with atomic_path(path) as tmp:
        tmp.write_text(buf.getvalue(), encoding="utf-8")
    return path


def write_control_curves(path: str | os.PathLike, times: np.ndarray, values: np.ndarray,
                         controls: Sequence[str]) -> Path:
    """Write control curves: ``.csv`` (``time,<controls>``, one row per frame) or ``.json``
    (``{"times": [...], "controls": {name: [...]}}``).

    Parameters
    ----------
    path : path-like
    times : (T,) float
        Seconds, written relative to ``times[0]``.
    values : (T, M) float
        Control values per frame.
    controls : sequence of str
        The ``M`` control names.
    """
    path = check_output_path(path)
    t = np.asarray(times, dtype=np.float64).reshape(-1)
    v = np.asarray(values, dtype=np.float64)
    if v.shape != (t.size, len(controls)):
        raise InvalidDataError(f"{path}: control values must be ({t.size}, {len(controls)}), got {v.shape}")
    if not (np.isfinite(v).all() and np.isfinite(t).all()):
        raise InvalidDataError(f"{path}: control curves hold a non-finite value; nothing written")
    t = t - t[0] if t.size else t
    ext = path.suffix.lower()
    if ext == JSON:
        doc = {"times": [round(float(x), 9) for x in t],
               "controls": {c: [float(x) for x in v[:, j]] for j, c in enumerate(controls)}}
        text = json.dumps(doc)
    elif ext == CSV:
        buf = _io.StringIO()
        w = csv.writer(buf, lineterminator="\n")
        w.writerow(["time", *controls])
        for i in range(t.size):
            w.writerow([f"{t[i]:.6f}", *[repr(float(x)) for x in v[i]]])
        text = buf.getvalue()
    else:
        raise OutputError(f"{path}: control curves are written as .csv or .json, not '{ext}'")
    with atomic_path(path) as tmp:
        tmp.write_text(text, encoding="utf-8")
    return path
