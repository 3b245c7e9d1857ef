"""A hand-drawn 2-D cartoon face as SVG key drawings (a 2-D retargeting target, Chuang Fig. 3.11).

The neutral face is a few SVG paths written by hand (head, brows, eyes with pupils, nose, lips
and the mouth's opening) in a 400 x 480 view; each ARKit-named key is the same drawing with some
of its points moved (the jaw drops the lower lip and the chin, a smile lifts a mouth corner, a
blink lowers an upper lid onto the lower one, ...).  Every key has the neutral's paths and
commands, so the keys blend point by point (:class:`~faceretarget.targets.DrawingTarget`).
"""

from __future__ import annotations

import os
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np

from ..errors import InvalidDataError
from ..files import atomic_dir

__all__ = ["DRAWN_FACE_KEYS", "drawn_face_svgs", "write_drawn_face"]

# (id, style, commands with points); points in a 400 x 480 view, +y down.  The character's left is
# the viewer's right (x > 200).
_PATHS: list[tuple[str, str, str]] = [
    ("head", 'fill="#f6d7b0" stroke="#5b3a29" stroke-width="4"',
     "M 200 50 C 283 50 350 135 350 240 C 350 345 283 430 200 430 C 117 430 50 345 50 240 C 50 135 117 50 200 50 Z"),
    ("browRight", 'fill="none" stroke="#4a2f1f" stroke-width="9" stroke-linecap="round"',
     "M 105 165 C 125 145 165 140 185 158"),
    ("browLeft", 'fill="none" stroke="#4a2f1f" stroke-width="9" stroke-linecap="round"',
     "M 215 158 C 235 140 275 145 295 165"),
    ("eyeRight", 'fill="#ffffff" stroke="#2b2b2b" stroke-width="4"',
     "M 112 210 C 128 188 172 188 188 210 C 172 228 128 228 112 210 Z"),
    ("eyeLeft", 'fill="#ffffff" stroke="#2b2b2b" stroke-width="4"',
     "M 212 210 C 228 188 272 188 288 210 C 272 228 228 228 212 210 Z"),
    ("pupilRight", 'fill="#2b2b2b" stroke="none"',
     "M 150 199 C 156 199 161 204 161 210 C 161 216 156 221 150 221 C 144 221 139 216 139 210 "
     "C 139 204 144 199 150 199 Z"),
    ("pupilLeft", 'fill="#2b2b2b" stroke="none"',
     "M 250 199 C 256 199 261 204 261 210 C 261 216 256 221 250 221 C 244 221 239 216 239 210 "
     "C 239 204 244 199 250 199 Z"),
    ("nose", 'fill="none" stroke="#8a5a3c" stroke-width="4" stroke-linecap="round"',
     "M 200 225 C 196 252 186 276 190 288 C 195 297 209 297 213 289"),
    ("mouthOpening", 'fill="#5a1f1f" stroke="none"',
     "M 140 345 C 170 350 230 350 260 345 C 230 352 170 352 140 345 Z"),
    ("upperLip", 'fill="#c0504d" stroke="#7a2e2c" stroke-width="3"',
     "M 140 345 C 165 330 185 336 200 340 C 215 336 235 330 260 345 C 230 350 170 350 140 345 Z"),
    ("lowerLip", 'fill="#c0504d" stroke="#7a2e2c" stroke-width="3"',
     "M 140 345 C 170 352 230 352 260 345 C 240 372 160 372 140 345 Z"),
]

Deform = Callable[[str, np.ndarray], np.ndarray]


def _near(p: np.ndarray, x: float, y: float, r: float) -> np.ndarray:
    """Falloff 1 at (x, y), 0 from distance r on (smooth)."""
    d = np.hypot(p[:, 0] - x, p[:, 1] - y) / r
    return np.clip(1.0 - d, 0.0, 1.0) ** 2 * (3 - 2 * np.clip(1.0 - d, 0.0, 1.0))


def _jaw(pid: str, p: np.ndarray) -> np.ndarray:
    d = np.zeros_like(p)
    drop = 44 * np.clip(1 - np.abs(p[:, 0] - 200) / 60, 0, 1) ** 0.7      # 0 at the mouth corners
    if pid == "lowerLip":
        d[:, 1] = drop
    elif pid == "mouthOpening":
        d[4:6, 1] = drop[4:6]                                             # its lower edge
    elif pid == "head":
        d[:, 1] = 38 * np.clip((p[:, 1] - 300) / 130, 0, 1)
        d[:, 0] = -0.1 * (p[:, 0] - 200) * np.clip((p[:, 1] - 300) / 130, 0, 1)
    return d


def _corner(side: float, dx: float, dy: float) -> Deform:
    def f(pid: str, p: np.ndarray) -> np.ndarray:
        d = np.zeros_like(p)
        if pid in ("upperLip", "lowerLip", "mouthOpening"):
            x0 = 200 + 60 * side
            g = _near(p, x0, 345, 75)
            d[:, 0] = dx * side * g
            d[:, 1] = dy * g
        return d
    return f


def _pucker(pid: str, p: np.ndarray) -> np.ndarray:
    d = np.zeros_like(p)
    if pid in ("upperLip", "lowerLip", "mouthOpening"):
        d[:, 0] = -0.45 * (p[:, 0] - 200)
        d[:, 1] = 0.35 * (p[:, 1] - 346)
    return d


def _brow(side: float, inner: float, outer: float) -> Deform:
    def f(pid: str, p: np.ndarray) -> np.ndarray:
        d = np.zeros_like(p)
        if pid == ("browLeft" if side > 0 else "browRight"):
            t = np.clip(np.abs(p[:, 0] - 200) / 100, 0, 1)          # 0 inner .. 1 outer
            d[:, 1] = -(inner * (1 - t) + outer * t)
        return d
    return f


def _blink(side: float, amount: float) -> Deform:
    def f(pid: str, p: np.ndarray) -> np.ndarray:
        d = np.zeros_like(p)
        if pid == ("eyeLeft" if side > 0 else "eyeRight"):
            up = np.arange(len(p)) < 4                               # M and the upper lid's curve
            d[up, 1] = amount * (222 - p[up, 1]) * np.where(np.abs(p[up, 0] - (200 + 50 * side)) < 30, 1.0, 0.6)
            if amount < 0:
                d[~up, 1] = -0.5 * amount * (p[~up, 1] - 210)
        elif pid == ("pupilLeft" if side > 0 else "pupilRight") and amount > 0:
            d[:, 1] = amount * (219 - p[:, 1]) * (p[:, 1] < 219)
        return d
    return f


#: The keys :func:`drawn_face_svgs` draws (ARKit names) and how each moves the drawing.
_DEFORMS: dict[str, Deform] = {
    "jawOpen": _jaw,
    "mouthSmileLeft": _corner(1.0, 14.0, -18.0),
    "mouthSmileRight": _corner(-1.0, 14.0, -18.0),
    "mouthFrownLeft": _corner(1.0, 2.0, 16.0),
    "mouthFrownRight": _corner(-1.0, 2.0, 16.0),
    "mouthPucker": _pucker,
    "browInnerUp": lambda pid, p: _brow(1, 22, 4)(pid, p) + _brow(-1, 22, 4)(pid, p),
    "browDownLeft": _brow(1.0, -16.0, -6.0),
    "browDownRight": _brow(-1.0, -16.0, -6.0),
    "browOuterUpLeft": _brow(1.0, 2.0, 22.0),
    "browOuterUpRight": _brow(-1.0, 2.0, 22.0),
    "eyeBlinkLeft": _blink(1.0, 1.0),
    "eyeBlinkRight": _blink(-1.0, 1.0),
    "eyeWideLeft": _blink(1.0, -0.45),
    "eyeWideRight": _blink(-1.0, -0.45),
}
DRAWN_FACE_KEYS: tuple[str, ...] = tuple(_DEFORMS)


def _parse(d: str) -> tuple[list[str], np.ndarray]:
    toks = d.split()
    cmds, pts = [], []
    i = 0
    while i < len(toks):
        c = toks[i]
        n = {"M": 1, "C": 3, "Z": 0}[c]
        cmds.append(c)
        pts.extend([(float(toks[i + 1 + 2 * k]), float(toks[i + 2 + 2 * k])) for k in range(n)])
        i += 1 + 2 * n
    return cmds, np.asarray(pts, dtype=np.float64)


def _svg(paths: list[tuple[str, str, list[str], np.ndarray]], title: str) -> str:
    body = []
    for pid, style, cmds, pts in paths:
        parts, s = [], 0
        for c in cmds:
            n = {"M": 1, "C": 3, "Z": 0}[c]
            parts.append(c + "".join(f" {x:.3f} {y:.3f}" for x, y in pts[s:s + n]))
            s += n
        body.append(f'  <path id="{pid}" {style} d="{" ".join(parts)}"/>')
    return ('<?xml version="1.0" encoding="UTF-8"?>\n'
            '<svg xmlns="http://www.w3.org/2000/svg" width="400" height="480" viewBox="0 0 400 480">\n'
            f"  <title>{title}</title>\n"
            '  <rect x="0" y="0" width="400" height="480" fill="#eef3f8"/>\n' + "\n".join(body) + "\n</svg>\n")


def drawn_face_svgs(keys: Sequence[str] | None = None) -> tuple[str, dict[str, str]]:
    """The neutral face and its key drawings as SVG texts.

    Parameters
    ----------
    keys : sequence of str, optional
        ARKit names among :data:`DRAWN_FACE_KEYS` (default all).

    Returns
    -------
    neutral : str
    keys : dict of str to str
        Key name -> SVG text (the neutral's paths with some points moved).
    """
    names = list(DRAWN_FACE_KEYS if keys is None else keys)
    bad = [k for k in names if k not in _DEFORMS]
    if bad:
        raise InvalidDataError(f"the drawn face has no key '{bad[0]}' (it draws {', '.join(DRAWN_FACE_KEYS)})")
    base = [(pid, style, *_parse(d)) for pid, style, d in _PATHS]
    out = {}
    for k in names:
        out[k] = _svg([(pid, st, c, p + _DEFORMS[k](pid, p)) for pid, st, c, p in base], f"drawn face: {k}")
    return _svg(base, "drawn face: neutral"), out


def write_drawn_face(folder: str | os.PathLike, keys: Sequence[str] | None = None) -> Path:
    """Write ``neutral.svg`` and one ``<key>.svg`` per key into ``folder`` (whole or not at all): a
    drawing target folder for ``retarget --target-keys``."""
    neutral, svgs = drawn_face_svgs(keys)
    folder = Path(folder)
    with atomic_dir(folder) as tmp:
        (tmp / "neutral.svg").write_text(neutral, encoding="utf-8")
        for k, text in svgs.items():
            (tmp / f"{k}.svg").write_text(text, encoding="utf-8")
    return folder
