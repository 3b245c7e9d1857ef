"""``Rig``: a neutral mesh plus named key shapes stored as vertex deltas."""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field

import numpy as np

from .errors import InvalidDataError, MissingShapeError, TopologyError
from .mesh import Mesh
from .names import normalize_name, split_parent

__all__ = ["Rig", "UNIT_TO_MM", "guess_unit"]

#: Millimetres per unit for the units a rig may carry.
UNIT_TO_MM = {"mm": 1.0, "cm": 10.0, "m": 1000.0, "in": 25.4}


def guess_unit(mesh: Mesh) -> str:
    """Guess a face mesh's unit from its size: a human face is about 15-40 cm across.

    A bounding-box diagonal under 2 is taken as metres, under 150 as centimetres, else millimetres.
    Pass the unit explicitly when the guess is wrong (a toy character, a whole body).
    """
    d = mesh.bbox_diagonal()
    if d < 2.0:
        return "m"
    if d < 150.0:
        return "cm"
    return "mm"


@dataclass(eq=False)
class Rig:
    """A blendshape rig: ``vertices(w) = neutral + sum_k w_k * deltas[k]``.

    Parameters
    ----------
    neutral : Mesh
        The rest face; its faces and UVs are shared by every key shape.
    names : list of str
        Key shape names, normalised to ARKit camelCase (see :mod:`faceretarget.names`).
    deltas : (K, V, 3) float
        Each key shape minus the neutral.
    unit : str
        ``"mm"``, ``"cm"``, ``"m"`` or ``"in"``; see :data:`UNIT_TO_MM`.
    landmarks : (P,) int, optional
        Vertex indices of feature points (for example the 68 Multi-PIE landmarks).
    source_names : list of str, optional
        The names as found in the files, for messages and round trips.
    name : str
        A label (usually the folder it came from).
    """

    neutral: Mesh
    names: list[str]
    deltas: np.ndarray
    unit: str = "cm"
    landmarks: np.ndarray | None = None
    source_names: list[str] | None = None
    name: str = "rig"
    _index: dict[str, int] = field(default_factory=dict, init=False, repr=False)

    def __post_init__(self) -> None:
        self.names = [normalize_name(n) for n in self.names]
        d = np.asarray(self.deltas, dtype=np.float64)
        V = self.neutral.n_vertices
        if d.ndim != 3 or d.shape[1:] != (V, 3) or d.shape[0] != len(self.names):
            raise TopologyError(
                f"{self.name}: deltas must have shape ({len(self.names)}, {V}, 3), got {d.shape}"
            )
        if not np.isfinite(d).all():
            k = int(np.flatnonzero(~np.isfinite(d).reshape(len(d), -1).all(1))[0])
            raise InvalidDataError(f"{self.name}: key shape '{self.names[k]}' has non-finite values")
        self.deltas = d
        seen: dict[str, int] = {}
        for i, n in enumerate(self.names):
            if n in seen:
                src = self.source_names or self.names
                raise InvalidDataError(
                    f"{self.name}: shapes '{src[seen[n]]}' and '{src[i]}' both normalise to '{n}'"
                )
            seen[n] = i
        self._index = seen
        if self.unit not in UNIT_TO_MM:
            raise InvalidDataError(f"{self.name}: unknown unit '{self.unit}', use one of {list(UNIT_TO_MM)}")
        if self.landmarks is not None:
            lm = np.asarray(self.landmarks, dtype=np.int64).reshape(-1)
            if lm.size and (lm.min() < 0 or lm.max() >= V):
                raise InvalidDataError(f"{self.name}: a landmark index is outside 0..{V - 1}")
            self.landmarks = lm

    # ------------------------------------------------------------------ basics
    @property
    def n_shapes(self) -> int:
        return len(self.names)

    @property
    def n_vertices(self) -> int:
        return self.neutral.n_vertices

    @property
    def mm_per_unit(self) -> float:
        return UNIT_TO_MM[self.unit]

    def index(self, name: str) -> int:
        """Column of a shape by any spelling of its name."""
        n = normalize_name(name)
        if n not in self._index:
            raise MissingShapeError(f"{self.name}: no key shape named '{name}'")
        return self._index[n]

    def __contains__(self, name: str) -> bool:
        return normalize_name(name) in self._index

    def shape_mesh(self, name: str, weight: float = 1.0) -> Mesh:
        """The key shape ``name`` at ``weight`` as a full mesh."""
        return self.neutral.with_vertices(
            self.neutral.vertices + weight * self.deltas[self.index(name)], name=name
        )

    # ------------------------------------------------------------------ evaluation
    def evaluate(self, weights: np.ndarray) -> np.ndarray:
        """Vertices for weights in this rig's shape order.

        Parameters
        ----------
        weights : (K,) or (T, K) float

        Returns
        -------
        (V, 3) or (T, V, 3) float
        """
        w = np.asarray(weights, dtype=np.float64)
        if w.shape[-1] != self.n_shapes:
            raise InvalidDataError(
                f"{self.name}: weights have {w.shape[-1]} columns but the rig has {self.n_shapes} shapes"
            )
        flat = w.reshape(-1, self.n_shapes) @ self.deltas.reshape(self.n_shapes, -1)
        out = flat.reshape(w.shape[:-1] + (self.n_vertices, 3))
        return out + self.neutral.vertices

    def map_weights(self, names: list[str], weights: np.ndarray, *, source: str = "performance",
                    warn: bool = True) -> np.ndarray:
        """Reorder named weight curves into this rig's shape order.

        Shapes this rig lacks are dropped (listed once in a warning); shapes the performance lacks
        get weight 0.  A whole ARKit weight (``browInnerUp``) drives both halves of a split shape
        (``browInnerUpLeft``/``Right``); two half weights drive a whole shape by their mean.

        Parameters
        ----------
        names : list of str
            Names of the columns of ``weights`` (any spelling).
        weights : (T, K_in) float

        Returns
        -------
        (T, K) float in this rig's order.
        """
        w = np.asarray(weights, dtype=np.float64)
        if w.ndim == 1:
            w = w[None]
        norm = [normalize_name(n) for n in names]
        out = np.zeros((w.shape[0], self.n_shapes))
        used = np.zeros(len(norm), bool)
        halves: dict[str, list[int]] = {}
        for j, n in enumerate(norm):
            if n in self._index:
                out[:, self._index[n]] = w[:, j]
                used[j] = True
            else:
                parent = split_parent(n)
                if parent is not None and parent in self._index:
                    halves.setdefault(parent, []).append(j)
                    used[j] = True
        for parent, cols in halves.items():
            out[:, self._index[parent]] = w[:, cols].mean(axis=1)
        # whole weights driving split halves
        for j, n in enumerate(norm):
            if used[j]:
                continue
            hit = False
            for side in ("Left", "Right"):
                if n + side in self._index:
                    out[:, self._index[n + side]] = w[:, j]
                    hit = True
            used[j] = hit
        unknown = [names[j] for j in np.flatnonzero(~used)]
        if unknown and warn:
            warnings.warn(
                f"{source}: {len(unknown)} channel(s) have no shape in rig '{self.name}' and are "
                f"ignored: {', '.join(unknown)}",
                stacklevel=2,
            )
        return out

    def subset(self, names: list[str]) -> Rig:
        """A rig with only the named shapes, in that order."""
        idx = [self.index(n) for n in names]
        return Rig(self.neutral, [self.names[i] for i in idx], self.deltas[idx], self.unit,
                   self.landmarks, None, self.name)
