"""``Rig``: a neutral mesh plus named key shapes stored as vertex deltas."""

from __future__ import annotations

import os
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .errors import DataWarning, InputFileError, InvalidDataError, MissingShapeError, TopologyError
from .mesh import Mesh
from .names import normalize_name, split_parent
from .units import UNIT_TO_MM, normalize_unit

__all__ = ["Rig", "RigFrames", "resolve_features"]


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
    basis : (K, M) float, optional
        What each key shape is, when it is known: key shape ``k`` is the base rig at the weights
        ``basis[k]`` of the base shapes ``basis_names`` (a key-model set of an ARKit-style rig:
        ARKit weight vectors, :func:`~faceretarget.cloning.keymodel_rig`).  Key weights ``W``
        ``(T, K)`` then convert to base weights as ``W @ basis`` (:meth:`to_basis`).  Kept by
        :meth:`subset` and by the rig files (``.npz``, ``key_weights.csv`` in OBJ folders).
    basis_names : list of str, optional
        The ``M`` base shape names (normalised to ARKit camelCase); given with ``basis``.
    keep_names : bool
        Keep ``names`` exactly as given (a character file's own shape names, written back as they
        are) instead of normalising them; they must then be unique as given.  Lookups by any
        spelling (:meth:`index`, :meth:`map_weights`) still work through the normalised names that
        are unique (:attr:`normalized_names`).
    """

    neutral: Mesh
    names: list[str]
    deltas: np.ndarray
    unit: str = "cm"
    landmarks: np.ndarray | None = None
    source_names: list[str] | None = None
    name: str = "rig"
    basis: np.ndarray | None = None
    basis_names: list[str] | None = None
    keep_names: bool = False
    _index: dict[str, int] = field(default_factory=dict, init=False, repr=False)

    def __post_init__(self) -> None:
        self.names = [str(n) for n in self.names] if self.keep_names else [normalize_name(n) for n in self.names]
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
                    if not self.keep_names else f"{self.name}: two shapes are named '{n}'")
            seen[n] = i
        if self.keep_names:                     # any spelling finds a shape whose normalised name is unique
            norm = [normalize_name(n) for n in self.names]
            for i, n in enumerate(norm):
                if norm.count(n) == 1:
                    seen.setdefault(n, i)
        self._index = seen
        self.unit = normalize_unit(self.unit, what=self.name)
        if self.landmarks is not None:
            lm = np.asarray(self.landmarks, dtype=np.int64).reshape(-1)
            if lm.size and (lm.min() < 0 or lm.max() >= V):
                raise InvalidDataError(f"{self.name}: a landmark index is outside 0..{V - 1}")
            self.landmarks = lm
        self._check_basis()

    def _check_basis(self) -> None:
        if (self.basis is None) != (self.basis_names is None):
            raise InvalidDataError(f"{self.name}: give basis and basis_names together")
        if self.basis is None:
            return
        bn = [normalize_name(n) for n in self.basis_names]
        b = np.asarray(self.basis, dtype=np.float64)
        if b.ndim != 2 or b.shape != (self.n_shapes, len(bn)):
            raise InvalidDataError(f"{self.name}: basis must be ({self.n_shapes}, {len(bn)}) for {self.n_shapes} "
                                   f"key shapes and {len(bn)} base names, got {b.shape}")
        if not np.isfinite(b).all():
            k = int(np.flatnonzero(~np.isfinite(b).all(axis=1))[0])
            raise InvalidDataError(f"{self.name}: the basis weights of key shape '{self.names[k]}' are not finite")
        dup = sorted({n for n in bn if bn.count(n) > 1})
        if dup:
            raise InvalidDataError(f"{self.name}: base shape '{dup[0]}' is named twice in basis_names")
        self.basis, self.basis_names = b, bn

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

    @property
    def normalized_names(self) -> list[str]:
        """The shape names normalised to ARKit camelCase (:attr:`names` unless ``keep_names``)."""
        return self.names if not self.keep_names else [normalize_name(n) for n in self.names]

    def index(self, name: str) -> int:
        """Column of a shape by any spelling of its name."""
        if self.keep_names and name in self._index:
            return self._index[name]
        n = normalize_name(name)
        if n not in self._index:
            raise MissingShapeError(f"{self.name}: no key shape named '{name}'")
        return self._index[n]

    def __contains__(self, name: str) -> bool:
        return (self.keep_names and name in self._index) or normalize_name(name) in self._index

    def shape_mesh(self, name: str, weight: float = 1.0) -> Mesh:
        """The key shape ``name`` at ``weight`` as a full mesh."""
        return self.neutral.with_vertices(
            self.neutral.vertices + weight * self.deltas[self.index(name)], name=name
        )

    # ------------------------------------------------------------------ evaluation
    def evaluate(self, weights: np.ndarray, vertices: np.ndarray | None = None) -> np.ndarray:
        """Vertices for weights in this rig's shape order.

        Parameters
        ----------
        weights : (K,) or (T, K) float
        vertices : (P,) int, optional
            Evaluate only these vertices (feature points: a take's landmarks cost ``T x P``, not
            ``T x V``).

        Returns
        -------
        (V, 3) or (T, V, 3) float (``P`` instead of ``V`` with ``vertices``)
        """
        w = np.asarray(weights, dtype=np.float64)
        if w.shape[-1] != self.n_shapes:
            raise InvalidDataError(
                f"{self.name}: weights have {w.shape[-1]} columns but the rig has {self.n_shapes} shapes"
            )
        if vertices is None:
            D, rest = self.deltas, self.neutral.vertices
        else:
            idx = np.asarray(vertices, dtype=np.int64).reshape(-1)
            if idx.size and (idx.min() < 0 or idx.max() >= self.n_vertices):
                raise InvalidDataError(f"{self.name}: a vertex index is outside 0..{self.n_vertices - 1}")
            D, rest = self.deltas[:, idx], self.neutral.vertices[idx]
        flat = w.reshape(-1, self.n_shapes) @ D.reshape(self.n_shapes, -1)
        out = flat.reshape(w.shape[:-1] + (len(rest), 3))
        return out + rest

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
                f"{source}: {', '.join(unknown)} ({len(unknown)} channel(s)) move nothing on rig '{self.name}', which "
                "has no shape of that name; to play them, give the rig a shape named so",
                DataWarning,
                stacklevel=2,
            )
        return out

    def subset(self, names: list[str]) -> Rig:
        """A rig with only the named shapes, in that order (their :attr:`basis` rows kept)."""
        idx = [self.index(n) for n in names]
        return Rig(self.neutral, [self.names[i] for i in idx], self.deltas[idx], self.unit,
                   self.landmarks, None, self.name, None if self.basis is None else self.basis[idx],
                   self.basis_names, keep_names=self.keep_names)

    def to_basis(self, weights: np.ndarray, names: list[str] | None = None) -> np.ndarray:
        """Key weights as weights of the base shapes (:attr:`basis`): ``W @ basis``.

        Parameters
        ----------
        weights : (K,) or (T, K) float
            In this rig's shape order, or with columns named by ``names``.
        names : list of str, optional
            Key shape names of the columns (any spelling; each must be a shape of this rig).

        Returns
        -------
        (M,) or (T, M) float
            Weights of :attr:`basis_names`.

        Raises
        ------
        InvalidDataError
            The rig has no basis, or the columns do not match its shapes.
        """
        if self.basis is None:
            raise InvalidDataError(f"{self.name}: the key shapes have no basis (they are not defined as "
                                   "combinations of named base shapes)")
        w = np.asarray(weights, dtype=np.float64)
        B = self.basis if names is None else self.basis[[self.index(n) for n in names]]
        if w.shape[-1] != len(B):
            raise InvalidDataError(f"{self.name}: weights have {w.shape[-1]} columns for {len(B)} key shapes")
        return w @ B


def resolve_features(spec, n_vertices: int, landmarks: np.ndarray | None = None, *, who: str = "rig") -> np.ndarray:
    """Vertex indices of the feature points.

    Parameters
    ----------
    spec : ``"landmarks"``, ``"all"``, a path to a text file of 0-based vertex indices, or an array
    n_vertices : int
        Vertex count of the mesh the indices refer to.
    landmarks : (P,) int, optional
        The rig's landmark indices (``landmarks68.txt``), used for ``"landmarks"``.

    Returns
    -------
    (P,) int
    """
    if isinstance(spec, str) and spec == "all":
        return np.arange(n_vertices)
    if isinstance(spec, str) and spec == "landmarks":
        if landmarks is None or len(landmarks) == 0:
            raise InvalidDataError(f"{who}: features 'landmarks' asked for but the rig has no landmarks68.txt")
        idx = np.asarray(landmarks, dtype=np.int64)
    elif isinstance(spec, (str, os.PathLike)):
        p = Path(spec)
        if not p.is_file():
            raise InputFileError(f"{p}: feature point file not found")
        try:
            idx = np.loadtxt(p, dtype=np.int64, ndmin=1)
        except ValueError as e:
            raise InputFileError(f"{p}: feature point file must hold 0-based vertex indices ({e})") from e
    else:
        idx = np.asarray(spec, dtype=np.int64).reshape(-1)
    if idx.size == 0:
        raise InvalidDataError(f"{who}: no feature points")
    if idx.min() < 0 or idx.max() >= n_vertices:
        raise InvalidDataError(f"{who}: feature point index outside 0..{n_vertices - 1}")
    return idx


@dataclass(eq=False)
class RigFrames:
    """The vertices of a rig driven by weights, evaluated only a chunk of frames at a time.

    What a writer of vertex output (``.npz``, OBJ frames) takes instead of a ``(T, V, 3)`` array,
    so a long take never holds every frame's vertices at once.

    Parameters
    ----------
    rig : Rig
    weights : (T, K) float
        In the rig's shape order.
    """

    rig: Rig
    weights: np.ndarray

    def __post_init__(self) -> None:
        w = np.asarray(self.weights, dtype=np.float64)
        if w.ndim != 2 or w.shape[1] != self.rig.n_shapes:
            raise InvalidDataError(f"{self.rig.name}: weights must be (T, {self.rig.n_shapes}), got {w.shape}")
        self.weights = w

    def __len__(self) -> int:
        return int(self.weights.shape[0])

    @property
    def shape(self) -> tuple[int, int, int]:
        return (len(self), self.rig.n_vertices, 3)

    def chunks(self, size: int = 1024):
        """``(start, (n, V, 3) vertices)`` for consecutive chunks of at most ``size`` frames."""
        for a in range(0, len(self), size):
            yield a, self.rig.evaluate(self.weights[a:a + size])
