"""The template of shape generation by name or file: the packaged ICT-FaceKit face, the ARKit reference face,
or any character with ARKit-named face shapes, read like every character (:func:`load_template`)."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from ..character import channels
from ..errors import InputFileError, MissingShapeError
from ..names import ARKIT_NAMES, normalize_name
from ..transfer import Template, packaged_template
from ._load import load_character

__all__ = ["load_template"]


def _from_character(path, log) -> Template:
    ch = load_character(path, log=log)
    prim = ch.primary
    m = ch.meshes[prim]
    shapes = {}
    for c in channels(ch):
        a = normalize_name(c.name)
        if a not in ARKIT_NAMES or a in shapes:
            continue
        d = np.zeros((m.mesh.n_vertices, 3))
        for mi, k, w in c.weighted():
            if mi == prim:
                d += w * m.deltas[k]
        if np.abs(d).max() > 0:
            shapes[a] = d
    if not shapes:
        raise MissingShapeError(f"{path}: the template has no ARKit-named face shapes to transfer")
    lm = ch.landmarks
    if lm is None or lm.mesh != prim:
        raise MissingShapeError(f"{path}: the template's landmarks are not on its face mesh '{m.name}'")
    missing = [a for a in ARKIT_NAMES if a not in shapes]
    notes = [f"the template has no {', '.join(missing)}: not generated"] if missing else []
    return Template(Path(path).name, m.mesh.vertices.astype(np.float64), m.mesh.triangles().astype(np.int64),
                    lm.triangles, lm.bary, shapes, notes)


def load_template(spec="ict-face", *, data: str | os.PathLike | None = None, log=None) -> Template:
    """The template named by ``--template``.

    Parameters
    ----------
    spec : str, path-like or Template
        ``"ict-face"`` (packaged in the wheel), ``"arkit-face"`` (the folder ``data/arkit-face`` when
        ``data`` or ``$FACERETARGET_DATA`` gives the data folder, else ``../shared/data`` of a checkout), or
        any rig folder / character file with ARKit-named face shapes.
    """
    log = log or (lambda *_: None)
    if isinstance(spec, Template):
        return spec
    s = str(spec)
    if s == "ict-face":
        return packaged_template()
    if s == "arkit-face":
        cands = [Path(p) / "arkit-face" for p in (data, os.environ.get("FACERETARGET_DATA")) if p]
        cands.append(Path(__file__).resolve().parents[3].parent / "shared" / "data" / "arkit-face")
        for c in cands:
            if c.is_dir():
                return _from_character(c, log)
        raise InputFileError("--template arkit-face: the ARKit reference face is not packaged (its meshes' rights are "
                             "unclear); give its folder as --template PATH")
    p = Path(s)
    if not p.exists():
        raise InputFileError(f"--template {s}: not 'ict-face', 'arkit-face' nor an existing rig folder or character "
                             "file")
    return _from_character(p, log)
