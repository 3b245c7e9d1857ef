"""A contact sheet of a character's face shapes: ``faceretarget character inspect FILE --sheet OUT.png``.

:func:`shape_sheet` renders the neutral face and every chosen shape at weight 1 (each channel with the
shapes of other meshes tied to it: teeth, lashes follow) with the software renderer
(:func:`~faceretarget.render.render_scene`, textures on), the same front view of the face for every
tile, cropped to the face: the landmarks' box when they were found, else the box of the face mesh's
vertices its shapes move most (over a fifth of the largest motion), seen along :func:`~faceretarget.character.character_frame`.  Tiles go in a
grid of ``cols`` columns with the shape's name under each; PNG, or JPEG by suffix.
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from ..character import Character, channels, character_frame, choose_shapes
from ..errors import InvalidDataError, MissingShapeError, OutputError
from ..files import atomic_path, check_output_path
from ..formats import PNG
from ..names import normalize_name

__all__ = ["shape_sheet"]


def _quiet(*_a) -> None:
    pass


def _face_box(ch: Character) -> tuple[np.ndarray, np.ndarray, float, float]:
    """Centre, the head frame (rows x, y, z), width and height of the face in the world frame."""
    R = character_frame(ch)
    if ch.landmarks is not None:
        pts = ch.landmark_positions()
        pad = (1.35, 1.35)
    else:                                   # the vertices the face shapes move most, their 1-99 % box
        from ..capture import face_region

        pts = face_region(ch)
        m = ch.meshes[ch.primary]
        mv = np.sqrt(m.vertex_motion2().max(axis=0)) if m.n_shapes else np.zeros(0)
        if mv.size and mv.max() > 0 and (mv > 0.2 * mv.max()).sum() >= 20:
            pts = m.mesh.vertices[mv > 0.2 * mv.max()]
        pad = (1.3, 1.3)
    q = pts @ R.T
    lo, hi = np.percentile(q, 1, axis=0), np.percentile(q, 99, axis=0)
    c = ((lo + hi) / 2.0) @ R
    w, h = float(hi[0] - lo[0]) * pad[0], float(hi[1] - lo[1]) * pad[1]
    side = max(w, h, 1e-6)
    return c, R, side, side


def shape_sheet(character: Character, out: str | os.PathLike, *, shapes: str = "all", cols: int = 8,
                tile: int = 224, log: Callable[..., None] = _quiet) -> Path:
    """Render every chosen shape at weight 1 into one picture (module docstring).

    Parameters
    ----------
    character : Character
        Read (and with landmarks, when found; :func:`~faceretarget.characters.load_character`).
    out : path-like
        ``.png``, ``.jpg`` or ``.jpeg``.
    shapes : str
        ``"all"`` (every face shape curve), ``"arkit"``, ``"visemes"``, or comma-separated names /
        patterns (:func:`~faceretarget.character.choose_shapes`).
    cols : int
        Tiles per row.
    tile : int
        Tile size in pixels (square).

    Returns
    -------
    Path
        ``out``.
    """
    from PIL import Image, ImageDraw, ImageFont

    from ..render import look_at, render_scene

    out = Path(out)
    fmt = {PNG: "PNG", ".jpg": "JPEG", ".jpeg": "JPEG"}.get(out.suffix.lower())
    if fmt is None:
        raise OutputError(f"{out}: the contact sheet is a .png or .jpg")
    check_output_path(out)
    t0 = time.perf_counter()
    chans = channels(character)
    if not chans:
        raise MissingShapeError(character.no_shapes_message())
    spec = "all" if shapes in (None, "", "auto") else shapes
    choice = choose_shapes(chans, spec, who=character.name)
    if not choice.drive:
        raise InvalidDataError(f"{character.name}: no shape matches --shapes {shapes}")
    c, R, w, h = _face_box(character)
    cam = look_at(c, R[2], R[1], w, (tile, tile))
    # only the meshes in front of the face box (a body's far parts cost time and are cropped anyway)
    meshes = character.meshes
    only = []
    for i, m in enumerate(meshes):
        q = (m.mesh.vertices - c) @ R.T
        if (np.abs(q[:, 0]) < w).any() and (np.abs(q[:, 1]) < h).any():
            only.append(i)
    tiles, labels = [], []
    rest = [m.mesh.vertices for m in meshes]
    order = [None] + list(choice.drive)
    # ARKit's mouthClose closes the lips of an open jaw: alone it pushes one lip through the other, so it is
    # shown on jawOpen, as it plays
    by_name = {normalize_name(ch.name): i for i, ch in enumerate(chans)}
    jaw = by_name.get("jawOpen")
    said = time.perf_counter()
    for k in order:
        if time.perf_counter() - said > 1.0:            # a few seconds of rendering: say how far it is
            log(f"contact sheet: {len(tiles)}/{len(order)} rendered")
            said = time.perf_counter()
        verts: list = [None] * len(meshes)
        with_jaw = k is not None and jaw is not None and normalize_name(chans[k].name) == "mouthClose"
        for kk in ([] if k is None else [k] + ([jaw] if with_jaw else [])):
            for mi, s, wgt in chans[kk].weighted():
                if verts[mi] is None:
                    verts[mi] = rest[mi].astype(np.float64, copy=True)
                verts[mi] += wgt * meshes[mi].deltas[s]
        img = render_scene(meshes, cam, vertices=verts, only=only).image
        tiles.append(img)
        labels.append("neutral" if k is None else f"{chans[jaw].name} + {chans[k].name}" if with_jaw
                      else chans[k].name)
    n = len(tiles)
    cols = max(1, min(int(cols), n))
    rows = -(-n // cols)
    fs = max(10, tile // 16)
    lh = fs + 8
    pad = 4
    sheet = Image.new("RGB", (cols * (tile + pad) + pad, rows * (tile + lh + pad) + pad), (24, 25, 28))
    draw = ImageDraw.Draw(sheet)
    try:
        font = ImageFont.load_default(size=fs)
    except (TypeError, OSError, ImportError):  # Pillow < 10.1 or no FreeType
        font = ImageFont.load_default()
    for k, (img, text) in enumerate(zip(tiles, labels, strict=True)):
        r, cc = divmod(k, cols)
        x0, y0 = pad + cc * (tile + pad), pad + r * (tile + lh + pad)
        sheet.paste(Image.fromarray(img), (x0, y0))
        while len(text) > 4 and draw.textlength(text, font=font) > tile:
            text = text[:-2] + "…" if not text.endswith("…") else text[:-2] + "…"
        tw = draw.textlength(text, font=font)
        draw.text((x0 + max(0.0, (tile - tw) / 2), y0 + tile + 3), text, fill=(235, 235, 235), font=font)
    with atomic_path(out) as tmp:
        if fmt == "JPEG":
            sheet.save(tmp, format="JPEG", quality=85)
        else:
            sheet.save(tmp, format="PNG")
    secs = time.perf_counter() - t0
    log(f"wrote {out}: the neutral and {n - 1} shape(s) of {character.name} ({choice.basis}) in {cols} columns, "
        f"{secs:.1f} s")
    return out
