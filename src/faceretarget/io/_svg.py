"""2-D drawings as retargeting keys: SVG paths and 2-D point sets, animated SVG out, raster previews.

A :class:`Drawing` is the ``<path>`` elements of an SVG file in document order, each path's
commands made absolute (``M L C Q Z``; ``H V`` become ``L``, ``S T`` become ``C Q`` with the
reflected control point, relative commands absolute), and every point the commands use in one
``(N, 2)`` array in SVG user units (+y down).  Those conversions are affine in the points, so a
weighted blend of converted drawings is the converted blend of the drawings.  Arcs (``A``) have no
such points and are refused; elements other than ``<path>`` (circles, text, images) stay as the
neutral drawing has them.  Two drawings are keys of one character when they have the same paths
with the same command sequences (:meth:`Drawing.check_like`): point ``i`` of one is point ``i``
of the other.

A 2-D point set (``.npy`` ``(P, 2)``, or ``.csv`` of ``x,y`` rows) is a drawing of dots: one path
drawing each point as a round dot.

:func:`write_svg_animation` writes frames as one SVG with SMIL ``<animate attributeName="d">``
per path (``values`` one per frame, ``keyTimes`` from the frame times, linear between frames, on
a loop); :func:`write_svg_frames` writes one static SVG per frame; :func:`render_drawing`
rasterises a frame (straight segments through the curves, PIL) for ``.png`` / ``.mp4`` previews
(:func:`write_drawing_preview`).
"""

from __future__ import annotations

import copy
import os
import re
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import InputFileError, InvalidDataError, OutputError, excerpt
from ..files import atomic_dir, atomic_path, check_output_path, input_file, read_text
from ..formats import CSV, MP4, NPY, PNG, SVG

__all__ = ["Drawing", "read_svg_drawing", "read_point_set", "write_svg_animation", "write_svg_frames",
           "read_svg_animation", "render_drawing", "write_drawing_preview", "DRAWING_FORMATS", "POINT_SET_FORMATS"]

SVG_NS = "http://www.w3.org/2000/svg"
#: Key drawing files :func:`read_svg_drawing` / :func:`read_point_set` read.
DRAWING_FORMATS = (SVG,)
POINT_SET_FORMATS = (NPY, CSV)
_ARGS = {"M": 2, "L": 2, "H": 1, "V": 1, "C": 6, "S": 4, "Q": 4, "T": 2, "A": 7, "Z": 0}
_NPTS = {"M": 1, "L": 1, "C": 3, "Q": 2, "Z": 0}
_TOKEN = re.compile(r"([MmLlHhVvCcSsQqTtAaZz])|([-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?)|([\s,]+)|(.)")
_MAX_COORD = 1e7
_MAX_POINTS = 1 << 20
ET.register_namespace("", SVG_NS)
ET.register_namespace("xlink", "http://www.w3.org/1999/xlink")


def _tag(el: ET.Element) -> str:
    return el.tag.rsplit("}", 1)[-1] if isinstance(el.tag, str) else ""


@dataclass(eq=False)
class Drawing:
    """The animatable points of a 2-D drawing.

    Attributes
    ----------
    commands : list of list of str
        Per path, its absolute commands (``M L C Q Z``).
    points : (N, 2) float
        The distinct points, in SVG user units (+x right, +y down).
    index : (S,) int
        The point each command slot uses, in path then command order (``arange(N)`` for SVG
        paths; each point twice for a point set's dots).
    path_ids : list of str
        Each path's ``id`` (or ``path<i>``), for messages.
    root : xml.etree.ElementTree.Element
        The SVG document the paths come from (styles, other elements); :func:`write_svg_animation`
        writes a copy of it.
    source : str
    transforms : list of str
        Per path, the ``transform`` attributes of its groups and itself, outermost first (``""``:
        none).  Points are blended in each path's own coordinates, so key drawings must transform
        every path as the neutral does (:meth:`check_like`).
    """

    commands: list[list[str]]
    points: np.ndarray
    index: np.ndarray
    path_ids: list[str]
    root: ET.Element = field(repr=False)
    source: str = "drawing"
    transforms: list[str] = field(default_factory=list)

    @property
    def n_points(self) -> int:
        return int(len(self.points))

    def check_like(self, other: Drawing) -> None:
        """Raise :class:`InvalidDataError` naming ``other``'s file and path unless both drawings have
        the same paths with the same command sequences (so their points correspond one to one)."""
        if len(other.commands) != len(self.commands):
            raise InvalidDataError(f"{other.source}: {len(other.commands)} paths, {self.source} has "
                                   f"{len(self.commands)}; key drawings need the same paths in the same order")
        for i, (a, b) in enumerate(zip(self.commands, other.commands, strict=True)):
            if a != b:
                j = next((n for n, (x, y) in enumerate(zip(a, b, strict=False)) if x != y), min(len(a), len(b)))
                got = b[j] if j < len(b) else "the end"
                want = a[j] if j < len(a) else "the end"
                raise InvalidDataError(f"{other.source}: path '{other.path_ids[i]}' differs from {self.source} at "
                                       f"command {j}: {got} where the other has {want} (key drawings need the same "
                                       "path structure, point order kept)")
        if other.n_points != self.n_points or not np.array_equal(other.index, self.index):
            raise InvalidDataError(f"{other.source}: {other.n_points} points, {self.source} has {self.n_points}")
        for i, (a, b) in enumerate(zip(self.transforms, other.transforms, strict=False)):
            if a != b:
                raise InvalidDataError(f"{other.source}: path '{other.path_ids[i]}' is transformed by "
                                       f"{excerpt(b or 'nothing')} where {self.source} has {excerpt(a or 'nothing')}; "
                                       "transforms are not blended (apply them to the paths: Inkscape Path > "
                                       "Object to Path, ungroup)")

    def static_changes(self, other: Drawing) -> list[str]:
        """The elements other than ``<path>`` (circles, text, images...) that ``other`` draws differently:
        they are never animated (the output keeps the neutral's), so a key that moves one is read only in part."""
        mine, theirs = _statics(self.root), _statics(other.root)
        out = [f"<{t}{' id=' + i if i else ''}>" for (t, i, a), o in zip(mine, theirs, strict=False) if (t, i, a) != o]
        if len(mine) != len(theirs):
            out.append(f"{abs(len(mine) - len(theirs))} element(s) {'more' if len(theirs) > len(mine) else 'fewer'}")
        return out

    def path_data(self, points: np.ndarray) -> list[str]:
        """Each path's ``d`` attribute for ``points`` ``(N, 2)``."""
        slots = np.asarray(points, dtype=np.float64)[self.index]
        out, s = [], 0
        for cmds in self.commands:
            parts = []
            for c in cmds:
                n = _NPTS[c]
                parts.append(c if n == 0 else c + " " + " ".join(f"{_num(x)} {_num(y)}" for x, y in slots[s:s + n]))
                s += n
            out.append(" ".join(parts))
        return out

    def polylines(self, points: np.ndarray, steps: int = 12) -> list[list[tuple[np.ndarray, bool]]]:
        """Per path, its subpaths as ``(polyline (n, 2), closed)`` (curves sampled at ``steps`` points)."""
        slots = np.asarray(points, dtype=np.float64)[self.index]
        u = np.linspace(0.0, 1.0, steps + 1)[1:, None]
        out, s = [], 0
        for cmds in self.commands:
            subs: list[tuple[np.ndarray, bool]] = []
            cur: list[np.ndarray] = []
            for c in cmds:
                n = _NPTS[c]
                p = slots[s:s + n]
                s += n
                if c == "M":
                    if len(cur) > 0:
                        subs.append((np.vstack(cur), False))
                    cur = [p]
                elif c == "L":
                    cur.append(p)
                elif c == "C":
                    p0 = cur[-1][-1]
                    cur.append(((1 - u) ** 3) * p0 + 3 * ((1 - u) ** 2) * u * p[0] + 3 * (1 - u) * u ** 2 * p[1]
                               + u ** 3 * p[2])
                elif c == "Q":
                    p0 = cur[-1][-1]
                    cur.append(((1 - u) ** 2) * p0 + 2 * (1 - u) * u * p[0] + u ** 2 * p[1])
                elif c == "Z" and cur:
                    subs.append((np.vstack(cur), True))
                    start = cur[0][:1]
                    cur = [start]
            if len(cur) > 1 or (cur and not subs):
                subs.append((np.vstack(cur), False))
            out.append(subs)
        return out


def _num(x: float) -> str:
    s = f"{float(x):.7f}".rstrip("0").rstrip(".")
    return "0" if s in ("-0", "") else s


# ---------------------------------------------------------------------------------------- reading
def _parse_d(path: Path, pid: str, d: str) -> tuple[list[str], list[tuple[float, float]]]:
    """Absolute commands and the points they use, from a path's ``d``."""
    toks: list[str | float] = []
    for m in _TOKEN.finditer(d):
        if m.group(1):
            toks.append(m.group(1))
        elif m.group(2):
            v = float(m.group(2))
            if not abs(v) <= _MAX_COORD:
                raise InputFileError(f"{path}: path '{pid}': coordinate {excerpt(m.group(2))} is not finite or "
                                     f"beyond +-{_MAX_COORD:g}")
            toks.append(v)
        elif m.group(4):
            raise InputFileError(f"{path}: path '{pid}': unexpected {excerpt(m.group(4))} in its path data")
    cmds: list[str] = []
    pts: list[tuple[float, float]] = []
    cur = np.zeros(2)
    start = np.zeros(2)
    last_c = last_q = None             # the previous cubic / quadratic control point (for S / T)
    i, cmd = 0, None
    while i < len(toks):
        t = toks[i]
        if isinstance(t, str):
            cmd = t
            i += 1
            if cmd in "Zz":
                cmds.append("Z")
                cur = start.copy()
                last_c = last_q = None
                continue
        elif cmd is None:
            raise InputFileError(f"{path}: path '{pid}': path data must start with a command (M)")
        elif cmd in "Zz":
            raise InputFileError(f"{path}: path '{pid}': numbers after Z")
        up = cmd.upper()
        if up == "A":
            raise InputFileError(f"{path}: path '{pid}': arc commands (A) are not supported; convert arcs to "
                                 "curves (Inkscape: Path > Object to Path keeps them; use 'Add nodes' or export "
                                 "with absolute curves)")
        n = _ARGS[up]
        args = toks[i:i + n]
        if len(args) < n or not all(isinstance(a, float) for a in args):
            raise InputFileError(f"{path}: path '{pid}': command {cmd} needs {n} numbers")
        i += n
        a = np.asarray(args, dtype=np.float64)
        rel = cmd.islower()
        base = cur if rel else np.zeros(2)
        if up in ("M", "L"):
            p = a + base
            cmds.append("M" if up == "M" else "L")
            pts.append(tuple(p))
            if up == "M":
                start = p.copy()
                cmd = "l" if rel else "L"      # numbers after M are line-tos
            cur = p
            last_c = last_q = None
        elif up in ("H", "V"):
            p = cur.copy()
            k = 0 if up == "H" else 1
            p[k] = a[0] + (cur[k] if rel else 0.0)
            cmds.append("L")
            pts.append(tuple(p))
            cur = p
            last_c = last_q = None
        elif up in ("C", "S"):
            if up == "C":
                c1, c2, p = a[0:2] + base, a[2:4] + base, a[4:6] + base
            else:
                c1 = 2 * cur - last_c if last_c is not None else cur.copy()
                c2, p = a[0:2] + base, a[2:4] + base
            cmds.append("C")
            pts.extend([tuple(c1), tuple(c2), tuple(p)])
            cur, last_c, last_q = p, c2, None
        elif up in ("Q", "T"):
            if up == "Q":
                c1, p = a[0:2] + base, a[2:4] + base
            else:
                c1 = 2 * cur - last_q if last_q is not None else cur.copy()
                p = a[0:2] + base
            cmds.append("Q")
            pts.extend([tuple(c1), tuple(p)])
            cur, last_q, last_c = p, c1, None
        if len(pts) > _MAX_POINTS:
            raise InputFileError(f"{path}: more than {_MAX_POINTS} path points")
    if cmds and cmds[0] != "M":
        raise InputFileError(f"{path}: path '{pid}': path data must start with M")
    return cmds, pts


def _parse_svg(path: Path) -> ET.Element:
    text = read_text(path)
    if "<!ENTITY" in text:
        raise InputFileError(f"{path}: SVG files with entity declarations are not read")
    try:
        root = ET.fromstring(text)
    except ET.ParseError as e:
        raise InputFileError(f"{path}: not an SVG (XML) file ({excerpt(e, 80)})") from None
    if _tag(root) != "svg":
        raise InputFileError(f"{path}: the root element is <{excerpt(_tag(root), bare=True)}>, not <svg>")
    return root


def _paths(root: ET.Element) -> list[ET.Element]:
    return [el for el in root.iter() if _tag(el) == "path"]


def _path_transforms(root: ET.Element) -> list[str]:
    """Each ``<path>``'s transform chain (its groups' ``transform`` attributes and its own), document order."""
    out: list[str] = []

    def walk(el: ET.Element, chain: str) -> None:
        t = " ".join(x for x in (chain, (el.get("transform") or "").strip()) if x)
        if _tag(el) == "path":
            out.append(t)
        for c in el:
            walk(c, t)

    walk(root, "")
    return out


#: Drawn elements that are not paths: kept as the neutral draws them, never animated.
_STATIC = ("circle", "ellipse", "rect", "line", "polyline", "polygon", "text", "image", "use")


def _statics(root: ET.Element) -> list[tuple[str, str, tuple]]:
    return [(_tag(el), el.get("id") or "", tuple(sorted((k, v) for k, v in el.attrib.items() if k != "id")))
            for el in root.iter() if _tag(el) in _STATIC]


def read_svg_drawing(path: str | os.PathLike) -> Drawing:
    """Read the ``<path>`` elements of an SVG file as a :class:`Drawing` (module docstring).

    Raises
    ------
    InputFileError
        Not an SVG, no ``<path>``, a path without ``d``, malformed path data or arcs (naming the
        file and the path's id).
    """
    path = input_file(path)
    root = _parse_svg(path)
    els = _paths(root)
    if not els:
        raise InputFileError(f"{path}: no <path> element to animate")
    commands, points, ids = [], [], []
    for i, el in enumerate(els):
        pid = el.get("id") or f"path{i}"
        d = el.get("d")
        if not d or not d.strip():
            raise InputFileError(f"{path}: path '{excerpt(pid, bare=True)}' has no path data (d)")
        c, p = _parse_d(path, excerpt(pid, bare=True), d)
        commands.append(c)
        points.extend(p)
        ids.append(pid)
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    return Drawing(commands, pts, np.arange(len(pts)), ids, root, source=str(path), transforms=_path_transforms(root))


def _dots_root(n: int) -> ET.Element:
    root = ET.Element(f"{{{SVG_NS}}}svg")
    ET.SubElement(root, f"{{{SVG_NS}}}path", {"id": "points", "fill": "none", "stroke": "#1f2937",
                                              "stroke-width": "6", "stroke-linecap": "round"})
    return root


def read_point_set(path: str | os.PathLike) -> Drawing:
    """Read a 2-D point set (``.npy`` ``(P, 2)`` or a ``.csv`` of ``x,y`` rows, an optional header
    line) as a :class:`Drawing` of dots (:attr:`Drawing.points` is the ``(P, 2)`` set).

    Raises
    ------
    InputFileError
        Another shape than ``(P, 2)``, non-finite values, a line that is not two numbers.
    """
    path = input_file(path)
    ext = path.suffix.lower()
    if ext == NPY:
        try:
            with open(path, "rb") as f:
                a = np.load(f, allow_pickle=False)
        except (ValueError, OSError, EOFError) as e:
            raise InputFileError(f"{path}: not a NumPy array file ({excerpt(e, 80)})") from None
        if a.dtype.kind not in "fiu":
            raise InputFileError(f"{path}: the array holds {a.dtype}, not numbers")
        a = a.astype(np.float64)
    elif ext == CSV:
        rows = []
        for n, line in enumerate(read_text(path).splitlines(), 1):
            s = line.strip()
            if not s:
                continue
            parts = [p.strip() for p in s.split(",")]
            try:
                rows.append([float(p) for p in parts])
            except ValueError:
                if not rows and n == 1:
                    continue                    # a header line
                raise InputFileError(f"{path}: line {n}: {excerpt(s)} is not 'x,y'") from None
        a = np.asarray(rows, dtype=np.float64) if rows else np.zeros((0, 2))
    else:
        raise InputFileError(f"{path}: unknown point-set format '{ext}' (use {', '.join(POINT_SET_FORMATS)})")
    if a.ndim != 2 or a.shape[1] != 2 or len(a) == 0:
        raise InputFileError(f"{path}: a 2-D point set must be (P, 2) with P >= 1, got {a.shape}")
    if not (np.abs(a) <= _MAX_COORD).all():
        raise InputFileError(f"{path}: a point is not finite or beyond +-{_MAX_COORD:g}")
    P = len(a)
    return Drawing([["M", "L"] * P], a, np.repeat(np.arange(P), 2), ["points"], _dots_root(P), source=str(path))


# ---------------------------------------------------------------------------------------- writing
def _check_frames(path: Path, drawing: Drawing, points: np.ndarray, times: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    p = np.asarray(points, dtype=np.float64)
    t = np.asarray(times, dtype=np.float64).reshape(-1)
    if p.ndim != 3 or p.shape[1:] != (drawing.n_points, 2) or len(p) != t.size or t.size == 0:
        raise InvalidDataError(f"{path}: frames must be ({t.size}, {drawing.n_points}, 2) for {t.size} times, "
                               f"got {p.shape}")
    if not (np.isfinite(p).all() and np.isfinite(t).all()):
        raise InvalidDataError(f"{path}: the frames hold a non-finite value; nothing written")
    if t.size > 1 and not (np.diff(t) > 0).all():
        raise InvalidDataError(f"{path}: frame times must increase")
    return p, t


def _frame_root(drawing: Drawing, frame: np.ndarray) -> ET.Element:
    root = copy.deepcopy(drawing.root)
    for el, d in zip(_paths(root), drawing.path_data(frame), strict=True):
        el.set("d", d)
    _size_box(root, drawing)
    return root


def _size_box(root: ET.Element, drawing: Drawing) -> None:
    """Give a document without ``viewBox`` one around its points (point sets)."""
    if root.get("viewBox") is None and root.get("width") is None:
        lo, hi = drawing.points.min(axis=0), drawing.points.max(axis=0)
        pad = 0.1 * max(float((hi - lo).max()), 1.0)
        lo, hi = lo - pad, hi + pad
        root.set("viewBox", f"{_num(lo[0])} {_num(lo[1])} {_num(hi[0] - lo[0])} {_num(hi[1] - lo[1])}")
        root.set("width", "512")
        root.set("height", str(max(1, int(round(512 * (hi[1] - lo[1]) / (hi[0] - lo[0]))))))


def _tostring(root: ET.Element) -> str:
    return '<?xml version="1.0" encoding="UTF-8"?>\n' + ET.tostring(root, encoding="unicode") + "\n"


def write_svg_animation(path: str | os.PathLike, drawing: Drawing, points: np.ndarray, times: np.ndarray) -> Path:
    """Write frames of a drawing as one animated SVG (SMIL), whole or not at all.

    Each ``<path>`` gets its first frame as ``d`` and an ``<animate attributeName="d">`` with one
    value per frame, ``keyTimes`` ``(times - times[0]) / duration``, ``calcMode="linear"``,
    repeating; the rest of the document is the drawing's own.

    Parameters
    ----------
    path : path-like
        Output ``.svg``.
    drawing : Drawing
        The neutral drawing (structure and styles).
    points : (T, N, 2) float
        The drawing's points per frame.
    times : (T,) float
        Seconds, strictly increasing.
    """
    path = check_output_path(path)
    p, t = _check_frames(path, drawing, points, times)
    root = _frame_root(drawing, p[0])
    if len(t) > 1:
        dur = float(t[-1] - t[0])
        key_times = ";".join(_num(x) for x in np.clip((t - t[0]) / dur, 0.0, 1.0))
        per_frame = [drawing.path_data(f) for f in p]
        for i, el in enumerate(_paths(root)):
            an = ET.SubElement(el, f"{{{SVG_NS}}}animate")
            an.set("attributeName", "d")
            an.set("dur", f"{dur:.6f}s")
            an.set("repeatCount", "indefinite")
            an.set("calcMode", "linear")
            an.set("keyTimes", key_times)
            an.set("values", ";".join(fr[i] for fr in per_frame))
    with atomic_path(path) as tmp:
        tmp.write_text(_tostring(root), encoding="utf-8")
    return path


def write_svg_frames(folder: str | os.PathLike, drawing: Drawing, points: np.ndarray, times: np.ndarray) -> Path:
    """Write one static SVG per frame (``frame_00000.svg`` ...) and ``times.txt`` into ``folder``,
    whole or not at all."""
    folder = Path(folder)
    p, t = _check_frames(folder, drawing, points, times)
    with atomic_dir(folder) as tmp:
        for i, f in enumerate(p):
            (tmp / f"frame_{i:05d}.svg").write_text(_tostring(_frame_root(drawing, f)), encoding="utf-8")
        (tmp / "times.txt").write_text("\n".join(f"{x:.6f}" for x in t) + "\n", encoding="utf-8")
    return folder


def read_svg_animation(path: str | os.PathLike) -> tuple[np.ndarray, np.ndarray, Drawing]:
    """Read an animated SVG written by :func:`write_svg_animation` back.

    Returns
    -------
    times : (T,) float
        Seconds from the first frame.
    points : (T, N, 2) float
    drawing : Drawing
        Its first frame.
    """
    drawing = read_svg_drawing(path)
    els = _paths(drawing.root)
    frames, dur, key_times = None, 0.0, None
    for i, el in enumerate(els):
        an = next((a for a in el if _tag(a) == "animate" and a.get("attributeName") == "d"), None)
        if an is None:
            raise InputFileError(f"{path}: path '{drawing.path_ids[i]}' is not animated")
        vals = [v for v in an.get("values", "").split(";")]
        if frames is None:
            frames = [[] for _ in vals]
            dur = float(an.get("dur", "0s").rstrip("s"))
            key_times = np.array([float(x) for x in an.get("keyTimes", "").split(";")])
        if len(vals) != len(frames):
            raise InputFileError(f"{path}: path '{drawing.path_ids[i]}' has {len(vals)} frames, another {len(frames)}")
        for f, v in enumerate(vals):
            c, p = _parse_d(Path(path), drawing.path_ids[i], v)
            if c != drawing.commands[i]:
                raise InputFileError(f"{path}: frame {f} of path '{drawing.path_ids[i]}' changes its structure")
            frames[f].extend(p)
    pts = np.asarray(frames, dtype=np.float64)
    return key_times * dur, pts, drawing


# ---------------------------------------------------------------------------------------- pictures
_NAMED = {"black": (0, 0, 0), "white": (255, 255, 255), "red": (255, 0, 0), "green": (0, 128, 0),
          "blue": (0, 0, 255), "gray": (128, 128, 128), "grey": (128, 128, 128), "yellow": (255, 255, 0),
          "orange": (255, 165, 0), "pink": (255, 192, 203), "brown": (165, 42, 42), "purple": (128, 0, 128)}


def _color(s: str | None):
    if s is None:
        return None
    s = s.strip().lower()
    if s in ("none", "transparent", ""):
        return None
    if s in _NAMED:
        return _NAMED[s]
    m = re.fullmatch(r"#([0-9a-f]{3}|[0-9a-f]{6})", s)
    if m:
        h = m.group(1)
        h = "".join(c * 2 for c in h) if len(h) == 3 else h
        return tuple(int(h[k:k + 2], 16) for k in (0, 2, 4))
    m = re.fullmatch(r"rgb\(\s*(\d+)\s*,\s*(\d+)\s*,\s*(\d+)\s*\)", s)
    if m:
        return tuple(min(255, int(x)) for x in m.groups())
    return (0, 0, 0)


def _styles(root: ET.Element) -> list[dict[str, str]]:
    """Per ``<path>``, its fill, stroke and stroke-width (attributes and ``style``, inherited from groups)."""
    out = []

    def walk(el: ET.Element, inherited: dict[str, str]) -> None:
        st = dict(inherited)
        for k in ("fill", "stroke", "stroke-width"):
            if el.get(k) is not None:
                st[k] = el.get(k)
        for part in (el.get("style") or "").split(";"):
            if ":" in part:
                k, v = (x.strip() for x in part.split(":", 1))
                if k in ("fill", "stroke", "stroke-width"):
                    st[k] = v
        if _tag(el) == "path":
            out.append(st)
        for ch in el:
            walk(ch, st)

    walk(root, {"fill": "black"})
    return out


def _view(drawing: Drawing, frames: np.ndarray) -> tuple[float, float, float, float]:
    vb = drawing.root.get("viewBox")
    if vb:
        try:
            x, y, w, h = (float(v) for v in vb.replace(",", " ").split())
            if w > 0 and h > 0:
                return x, y, w, h
        except ValueError:
            pass
    lo = frames.reshape(-1, 2).min(axis=0)
    hi = frames.reshape(-1, 2).max(axis=0)
    pad = 0.1 * max(float((hi - lo).max()), 1.0)
    return float(lo[0] - pad), float(lo[1] - pad), float(hi[0] - lo[0] + 2 * pad), float(hi[1] - lo[1] + 2 * pad)


def render_drawing(drawing: Drawing, points: np.ndarray, size: int = 512, *,
                   view: tuple[float, float, float, float] | None = None,
                   background=(255, 255, 255)) -> np.ndarray:
    """Rasterise one frame of a drawing (its ``<path>`` elements: fill, stroke, stroke width).

    Parameters
    ----------
    drawing : Drawing
    points : (N, 2) float
        The frame's points.
    size : int
        Width of the picture in pixels (the height follows the ``viewBox``).
    view : (x, y, w, h), optional
        The part of the plane shown (default the document's ``viewBox``).

    Returns
    -------
    (H, W, 3) uint8
    """
    from PIL import Image, ImageDraw

    p = np.asarray(points, dtype=np.float64)
    x0, y0, w, h = view or _view(drawing, p[None])
    s = size / w
    H = max(1, int(round(h * s)))
    ss = 2                                              # supersampled, then reduced (smooth edges)
    im = Image.new("RGB", (size * ss, H * ss), tuple(background))
    dr = ImageDraw.Draw(im)
    for subs, st in zip(drawing.polylines(p), _styles(drawing.root), strict=True):
        fill, stroke = _color(st.get("fill")), _color(st.get("stroke"))
        try:
            sw = float(re.sub(r"[a-z%]+$", "", st.get("stroke-width", "1")))
        except ValueError:
            sw = 1.0
        for poly, closed in subs:
            q = [((x - x0) * s * ss, (y - y0) * s * ss) for x, y in poly]
            if fill is not None and len(q) >= 3:
                dr.polygon(q, fill=fill)
            if stroke is not None:
                width = max(1, int(round(sw * s * ss)))
                if len(q) == 1 or np.ptp(poly, axis=0).max() == 0:
                    x, y = q[0]
                    r = width / 2
                    dr.ellipse([x - r, y - r, x + r, y + r], fill=stroke)
                else:
                    dr.line(q + ([q[0]] if closed else []), fill=stroke, width=width, joint="curve")
    return np.asarray(im.resize((size, H), Image.LANCZOS))


def write_drawing_preview(path: str | os.PathLike, drawing: Drawing, points: np.ndarray, times: np.ndarray, *,
                          size: int = 512, max_tiles: int = 12, progress: bool = False) -> Path:
    """A picture of drawing frames: ``.png`` (a contact sheet of up to ``max_tiles`` frames evenly
    spread over the take, labelled with their times) or ``.mp4`` (every frame; needs PyAV, the
    ``preview`` extra).

    Parameters
    ----------
    path : path-like
    drawing : Drawing
    points : (T, N, 2) float
    times : (T,) float
    size : int
        Width of a frame in pixels.
    progress : bool
        A progress bar while the ``.mp4``'s frames are drawn and encoded (about 15 frames/s).
    """
    path = check_output_path(path)
    p, t = _check_frames(path, drawing, points, times)
    view = _view(drawing, p)
    ext = path.suffix.lower()
    if ext == PNG:
        from ..render import render_grid, save_png

        idx = np.unique(np.linspace(0, len(p) - 1, min(max_tiles, len(p))).round().astype(int))
        tiles = [render_drawing(drawing, p[i], size // 2 if len(idx) > 1 else size, view=view) for i in idx]
        sheet = render_grid(tiles, [f"{t[i] - t[0]:.2f} s" for i in idx], background=(255, 255, 255),
                            text_color=(20, 20, 20)) if len(idx) > 1 else tiles[0]
        return save_png(path, sheet)
    if ext == MP4:
        from tqdm.auto import tqdm

        from ..timebase import infer_fps
        from ._video import write_video

        fps = infer_fps(t, default=30.0) if len(t) > 1 else 30.0
        with atomic_path(path) as tmp, tqdm(total=len(p), desc=f"drawing {path.name}", unit="frame",
                                            disable=not progress, leave=False) as bar:
            write_video(tmp, (render_drawing(drawing, f, size, view=view) for f in p), fps, on_frame=bar.update)
        return path
    raise OutputError(f"{path}: a drawing preview is a .png or an .mp4, not '{ext}'")
