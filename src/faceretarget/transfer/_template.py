"""Templates: a face with expression shapes whose motion is transferred (the packaged ICT-FaceKit face;
:func:`faceretarget.characters.load_template` also takes any character with ARKit shapes)."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import InputFileError
from ..names import ARKIT_NAMES

__all__ = ["Template", "TEMPLATES", "packaged_template_path", "packaged_template", "ict_to_arkit"]

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


def packaged_template() -> Template:
    """The ICT-FaceKit template packaged in the wheel, its shapes under ARKit names."""
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
