"""Templates: a face with expression shapes whose motion is transferred (:func:`load_template`)."""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import InputFileError, MissingShapeError
from ..names import ARKIT_NAMES, normalize_name

__all__ = ["Template", "load_template", "TEMPLATES", "packaged_template_path", "ict_to_arkit"]

#: What ``--template`` takes by name.
TEMPLATES = ("ict-face", "arkit-face")
#: ICT-FaceKit shapes that have no ARKit counterpart.
_ICT_EXTRA = ("cheekRaiser", "PupilDilate")


def packaged_template_path() -> Path:
    """The ICT-FaceKit template inside the package (``data/templates/ict-face.npz``)."""
    return Path(__file__).resolve().parent.parent / "data" / "templates" / "ict-face.npz"


@dataclass(eq=False)
class Template:
    """A face and its expression shapes, in metres.

    Attributes
    ----------
    name : str
    vertices : (N, 3) float
    triangles : (F, 3) int
    lm_triangles, lm_bary : (68, 3)
        The 68 landmarks as points on triangles (vertex ``i`` is ``(i, i, i), (1, 0, 0)``).
    shapes : dict
        ``{ARKit name: (N, 3) delta}``.
    notes : list of str
    """

    name: str
    vertices: np.ndarray
    triangles: np.ndarray
    lm_triangles: np.ndarray
    lm_bary: np.ndarray
    shapes: dict
    notes: list = field(default_factory=list)

    def landmarks(self, delta: np.ndarray | None = None) -> np.ndarray:
        V = self.vertices if delta is None else delta
        return np.einsum("pk,pkd->pd", self.lm_bary, V[self.lm_triangles])


def ict_to_arkit(names: list[str], deltas: list[np.ndarray]) -> tuple[dict, list[str]]:
    """ICT-FaceKit shapes under ARKit names: ``_L`` / ``_R`` to ``Left`` / ``Right``, ``browInnerUp`` and
    ``cheekPuff`` the sums of their halves; ``cheekRaiser`` and ``PupilDilate`` dropped."""
    out: dict[str, np.ndarray] = {}
    notes = []
    for n, d in zip(names, deltas, strict=True):
        base, side = (n[:-2], n[-1]) if n[-2:] in ("_L", "_R") else (n, "")
        if base in _ICT_EXTRA:
            continue
        if base in ("browInnerUp", "cheekPuff"):
            out[base] = out.get(base, 0) + d
            continue
        a = base + {"L": "Left", "R": "Right", "": ""}[side]
        if a in ARKIT_NAMES:
            out[a] = d
    missing = [a for a in ARKIT_NAMES if a not in out]
    if missing:
        notes.append(f"the template has no {', '.join(missing)}: not generated")
    return out, notes


def _packaged_ict() -> Template:
    p = packaged_template_path()
    if not p.is_file():
        raise InputFileError(f"{p}: the packaged ICT-FaceKit template is missing (rebuild it with "
                             "tools/make_template.py)")
    z = np.load(p)
    V = z["neutral"].astype(np.float64)
    names = [str(n) for n in z["names"]]
    deltas = []
    for i in range(len(names)):
        d = np.zeros_like(V)
        d[np.cumsum(z[f"gap_{i}"].astype(np.int64))] = z[f"delta_{i}"].astype(np.float64)
        deltas.append(d)
    shapes, notes = ict_to_arkit(names, deltas)
    lm = z["landmarks"].astype(np.int64)
    return Template("ict-face", V, z["triangles"].astype(np.int64), np.stack([lm] * 3, 1),
                    np.tile([1.0, 0.0, 0.0], (68, 1)), shapes, notes)


def _from_character(path, log) -> Template:
    from ..character import channels
    from ..pipelines import load_character

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
        return _packaged_ict()
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
