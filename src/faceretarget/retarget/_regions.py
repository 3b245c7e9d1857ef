"""Face regions for retargeting: solve each region on its own, blend the target across the seams.

A face retargeted as one piece lets a mouth keyshape pull the brows (and the other way round);
Chuang (Sec. 3.4) and every production solver split it.  A :class:`Regions` object holds

* on the **source** side, which feature points (markers, landmarks) each region solves on;
* on the **target** side, a partition of unity ``masks_`` ``(R, Vt)``: how much of each target
  vertex follows each region's weights.  Inside a region a vertex follows it fully; within
  ``width`` of another region the memberships fall off smoothly, so the target keyshapes blend
  across the seam with no visible step::

      B(t) = B0 + sum_r  m_r  *  sum_k w_rk(t) (B_k - B0)

Three ways to make one:

* :func:`default_regions`: ``upper`` (brows, eyes, nose bridge) and ``lower`` (nose base, mouth,
  jaw).  With the 68 Multi-PIE landmarks as features the split is semantic (indices 17-30 and
  36-47 upper); otherwise at the middle of the feature points' vertical range.  On the target the
  seam is at the height of landmark 30 (nose tip) when the target has the 68 landmarks, else at the
  same relative height of the target's moving vertices as on the source;
* :func:`load_regions` reads a JSON file::

      {"width": 0.02,                                  (optional, target units; default 12 % of the face)
       "regions": {
          "upper": {"source": ["LBrow", "RBrow", 12], "target": [0, 1, 2, ...]},
          "lower": {"source": [...], "target": "lower_vertices.txt"}}}

  ``source``: marker labels or 0-based feature indices; ``target``: 0-based target vertex indices
  (a list or a text file of them).  Target vertices no region names join the nearest region;
* ``Regions(source=..., target=...)`` in Python.

The vertical axis is +Y (Y-up, like OBJ, glTF, the shared rigs and the shared marker takes);
pass ``up=2`` for Z-up data.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

from ..base import Model
from ..errors import InputFileError, InvalidDataError
from ..numerics import smoothstep

__all__ = ["Regions", "default_regions", "load_regions", "UPPER68"]

# Multi-PIE 68: 17-26 brows, 27-30 nose bridge, 36-47 eyes (0-16 jaw, 31-35 nose base, 48-67 mouth)
UPPER68 = np.r_[17:31, 36:48]
_NOSE_TIP = 30




def _moving_part(V: np.ndarray, deltas: np.ndarray | None) -> np.ndarray:
    """(n, 3) vertices of ``V`` (Vt, 3) that some keyshape of ``deltas`` (K, Vt, 3) moves (more than
    1e-3 of the largest motion); all of ``V`` without deltas or motion."""
    moving = np.ones(len(V), dtype=bool)
    if deltas is not None and len(deltas):
        m = np.linalg.norm(deltas, axis=2).max(axis=0)
        if m.max() > 0:
            moving = m > 1e-3 * m.max()
    return V[moving]


def _memberships(V: np.ndarray, owner: np.ndarray, names: list[str], width: float) -> np.ndarray:
    """(R, Vt) memberships from the (Vt,) owning region of each vertex of ``V`` (Vt, 3): 1 inside the
    region, falling off smoothly to 0 at ``width`` from it; columns normalised to sum to 1."""
    R = len(names)
    W = np.zeros((R, len(V)))
    for r in range(R):
        inside = owner == r
        if not inside.any():
            raise InvalidDataError(f"region '{names[r]}' holds no target vertex")
        d, _ = cKDTree(V[inside]).query(V, distance_upper_bound=width)
        W[r] = np.where(np.isfinite(d), 1.0 - smoothstep(np.nan_to_num(d, posinf=width) / width), 0.0)
        W[r, inside] = np.maximum(W[r, inside], 1.0)
    # inside its own region a vertex keeps full weight; near a seam memberships are shared
    return W / W.sum(axis=0, keepdims=True)


class Regions(Model):
    """Source feature subsets and smoothly blended target vertex memberships.

    Parameters
    ----------
    source : dict of str -> sequence of int or str
        Region name -> feature points (indices into the feature points, or marker labels resolved
        by :meth:`resolve`).  Every feature point should belong to at least one region.
    target : dict of str -> sequence of int, optional
        Region name -> target vertex indices (same names as ``source``).  When omitted the target
        split comes from ``seam`` (upper/lower regions only).
    width : float, optional
        Blend width across seams, in target units (default 12 % of the size of the target's
        moving part).
    seam : float, optional
        For a two-region upper/lower split without target sets: the seam's height on the target.
    up : int
        Index of the vertical axis (1 = +Y).

    Attributes
    ----------
    names : list of str
    source_idx_ : list of (n_r,) int
        After :meth:`fit`: the feature points of each region.
    masks_ : (R, Vt) float
        After :meth:`fit`: each target vertex's membership per region (columns sum to 1).
    width_ : float
        The blend width used.
    seam_ : float
        The seam's height (upper/lower split without target sets).
    """

    def __init__(self, source: dict, target: dict | None = None, *, width: float | None = None,
                 seam: float | None = None, up: int = 1) -> None:
        if not source:
            raise InvalidDataError("regions: no regions given")
        if target is not None and set(target) != set(source):
            raise InvalidDataError(f"regions: source regions {sorted(source)} and target regions "
                                   f"{sorted(target)} differ")
        self.source = {k: list(v) for k, v in source.items()}
        self.target = None if target is None else {k: np.asarray(v, dtype=np.int64).reshape(-1)
                                                   for k, v in target.items()}
        self.width = width
        self.seam = seam
        self.up = int(up)

    @property
    def names(self) -> list[str]:
        return list(self.source)

    def __len__(self) -> int:
        return len(self.names)

    def __repr__(self) -> str:
        return f"Regions({', '.join(self.names)})"

    def fit(self, n_points: int, target_neutral: np.ndarray, *, labels: list[str] | None = None,
            deltas: np.ndarray | None = None, landmarks: np.ndarray | None = None,
            source_points: np.ndarray | None = None) -> Regions:
        """Resolve the source regions (:meth:`resolve`) and place them on the target
        (:meth:`fit_target`); returns self."""
        self.source_idx_ = self.resolve(n_points, labels)
        self.fit_target(target_neutral, deltas, landmarks, source_points)
        return self

    # ------------------------------------------------------------------ source side
    def resolve(self, n_points: int, labels: list[str] | None = None) -> list[np.ndarray]:
        """Feature indices of each region (labels looked up in ``labels``)."""
        out = []
        covered = np.zeros(n_points, dtype=bool)
        for name in self.names:
            idx = []
            for s in self.source[name]:
                if isinstance(s, str) and not s.lstrip("-").isdigit():
                    if not labels or s not in labels:
                        raise InvalidDataError(f"region '{name}': marker '{s}' is not among the source "
                                               f"feature points ({', '.join(labels or []) or 'unlabelled'})")
                    idx.append(labels.index(s))
                else:
                    i = int(s)
                    if not 0 <= i < n_points:
                        raise InvalidDataError(f"region '{name}': feature index {i} is outside 0..{n_points - 1}")
                    idx.append(i)
            if not idx:
                raise InvalidDataError(f"region '{name}' has no source feature points")
            a = np.unique(np.asarray(idx, dtype=np.int64))
            covered[a] = True
            out.append(a)
        if not covered.all():
            miss = np.flatnonzero(~covered)
            raise InvalidDataError(f"regions: feature point(s) {', '.join(map(str, miss[:10]))} belong to no "
                                   "region")
        return out

    # ------------------------------------------------------------------ target side
    def fit_target(self, neutral: np.ndarray, deltas: np.ndarray | None = None,
                   landmarks: np.ndarray | None = None, source_points: np.ndarray | None = None) -> np.ndarray:
        """Compute the target memberships ``masks_`` ``(R, Vt)`` (the second half of :meth:`fit`).

        Parameters
        ----------
        neutral : (Vt, 3) float
            The target's neutral.
        deltas : (K, Vt, 3) float, optional
            Target keyshape displacements: their moving vertices define the face's extent.
        landmarks : (68,) int, optional
            The target's 68 landmarks (places the default seam at the nose tip).
        source_points : (P, 3) float, optional
            The source feature points at rest (for the default seam's relative height).
        """
        V = np.asarray(neutral, dtype=np.float64)
        face = _moving_part(V, deltas)
        size = float(np.linalg.norm(face.max(axis=0) - face.min(axis=0)))
        width = self.width if self.width is not None else 0.12 * size
        if not width > 0:
            raise InvalidDataError(f"regions: blend width must be > 0, got {width}")
        if self.target is not None:
            owner = self._owners_from_sets(V)
        else:
            if len(self.names) != 2:
                raise InvalidDataError("regions: without target vertex sets only a two-region upper/lower "
                                       "split can be placed on the target")
            h = V[:, self.up]
            seam = self.seam
            if seam is None and landmarks is not None and len(landmarks) == 68:
                seam = float(V[int(landmarks[_NOSE_TIP]), self.up])
            if seam is None:
                seam = self._default_seam(face, source_points)
            self.seam_ = seam
            owner = np.where(h >= seam, 0, 1)
        self.masks_ = _memberships(V, owner, self.names, width)
        self.width_ = float(width)
        return self.masks_

    def _owners_from_sets(self, V: np.ndarray) -> np.ndarray:
        """(Vt,) region index of each target vertex (``V`` (Vt, 3)) from the target vertex sets;
        vertices no set names join the nearest named vertex's region."""
        sets = []
        for name in self.names:
            t = self.target[name]
            if t.size == 0:
                raise InvalidDataError(f"region '{name}' has no target vertices")
            if t.min() < 0 or t.max() >= len(V):
                raise InvalidDataError(f"region '{name}': target vertex index outside 0..{len(V) - 1}")
            sets.append(t)
        # vertices nobody named join the nearest named one's region
        owner = np.full(len(V), -1)
        for r, t in enumerate(sets):
            owner[t] = np.where(owner[t] < 0, r, owner[t])
        free = np.flatnonzero(owner < 0)
        if free.size:
            named = np.flatnonzero(owner >= 0)
            _, j = cKDTree(V[named]).query(V[free])
            owner[free] = owner[named[j]]
        return owner

    def _default_seam(self, face: np.ndarray, source_points: np.ndarray | None) -> float:
        """Seam height on the target's moving part ``face`` (n, 3): at the relative height between the
        source's upper and lower feature points (``source_points`` (P, 3)), else halfway."""
        frac = 0.5
        if source_points is not None and getattr(self, "source_idx_", None) is not None:
            y = np.asarray(source_points)[:, self.up]
            lo_, hi_ = y.min(), y.max()
            up_min = y[self.source_idx_[0]].min()
            lo_max = y[self.source_idx_[1]].max()
            if hi_ > lo_:
                frac = float(np.clip((0.5 * (up_min + lo_max) - lo_) / (hi_ - lo_), 0.1, 0.9))
        fy = face[:, self.up]
        return float(fy.min() + frac * (fy.max() - fy.min()))

    def split(self, deltas: np.ndarray) -> np.ndarray:
        """Target key shapes ``(K, Vt, 3)`` split by the regions' memberships: ``(R x K, Vt, 3)``,
        region-major (all keys of the first region, then the next)."""
        self._check_fitted("split")
        d = np.asarray(deltas, dtype=np.float64)
        M = self.masks_
        if d.ndim != 3 or d.shape[1] != M.shape[1]:
            raise InvalidDataError(f"regions: key shapes must be (K, {M.shape[1]}, 3), got {d.shape}")
        return (M[:, None, :, None] * d[None]).reshape(len(M) * len(d), M.shape[1], 3)

    # ------------------------------------------------------------------ persistence
    def to_dict(self) -> dict:
        d = {"regions": {n: {"source": [s if isinstance(s, str) else int(s) for s in self.source[n]]}
                         for n in self.names}, "up": self.up}
        if self.target is not None:
            for n in self.names:
                d["regions"][n]["target"] = self.target[n].tolist()
        if self.width is not None:
            d["width"] = self.width
        if self.seam is not None:
            d["seam"] = self.seam
        return d

    @classmethod
    def from_dict(cls, d: dict, where: str = "regions") -> Regions:
        if not isinstance(d, dict) or not isinstance(d.get("regions"), dict) or not d["regions"]:
            raise InputFileError(f"{where}: expected {{\"regions\": {{name: {{\"source\": [...], "
                                 f"\"target\": [...]}}}}}}")
        src, tgt = {}, {}
        for name, r in d["regions"].items():
            if not isinstance(r, dict) or "source" not in r:
                raise InputFileError(f"{where}: region '{name}' needs a \"source\" list of markers or indices")
            src[name] = r["source"]
            if "target" in r:
                tgt[name] = r["target"]
        if tgt and set(tgt) != set(src):
            raise InputFileError(f"{where}: give \"target\" vertices for every region or for none "
                                 f"(missing for {', '.join(sorted(set(src) - set(tgt)))})")
        return cls(src, tgt or None, width=d.get("width"), seam=d.get("seam"), up=int(d.get("up", 1)))


def default_regions(source_points: np.ndarray, *, landmarks68: bool = False, up: int = 1,
                    width: float | None = None) -> Regions:
    """Upper/lower face regions from the source feature points at rest.

    Parameters
    ----------
    source_points : (P, 3) float
        The feature points (at the neutral).
    landmarks68 : bool
        The features are the 68 Multi-PIE landmarks in their usual order: split semantically.
    up : int
        Vertical axis.
    width : float, optional
        Target blend width (see :class:`Regions`).
    """
    P = np.asarray(source_points, dtype=np.float64)
    if landmarks68 and len(P) == 68:
        upper = UPPER68
    else:
        y = P[:, up]
        upper = np.flatnonzero(y >= 0.5 * (y.min() + y.max()))
    lower = np.setdiff1d(np.arange(len(P)), upper)
    if upper.size == 0 or lower.size == 0:
        raise InvalidDataError("regions: the feature points do not spread vertically; give regions explicitly")
    return Regions({"upper": upper.tolist(), "lower": lower.tolist()}, width=width, up=up)


def load_regions(path: str | os.PathLike) -> Regions:
    """Read a regions JSON file (see the module docstring); target lists may name text files."""
    p = Path(path)
    if not p.is_file():
        raise InputFileError(f"{p}: regions file not found")
    try:
        d = json.loads(p.read_text(encoding="utf-8"))
    except (json.JSONDecodeError, UnicodeDecodeError) as e:
        raise InputFileError(f"{p}: not a JSON regions file ({e})") from None
    if isinstance(d, dict) and isinstance(d.get("regions"), dict):
        for name, r in d["regions"].items():
            if isinstance(r, dict) and isinstance(r.get("target"), str):
                f = (p.parent / r["target"]) if not Path(r["target"]).is_absolute() else Path(r["target"])
                if not f.is_file():
                    raise InputFileError(f"{p}: region '{name}': target vertex file {f} not found")
                try:
                    r["target"] = np.loadtxt(f, dtype=np.int64, ndmin=1).tolist()
                except ValueError as e:
                    raise InputFileError(f"{f}: expected 0-based vertex indices ({e})") from None
    return Regions.from_dict(d, str(p))
