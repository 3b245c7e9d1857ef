"""The one target abstraction: what a character's keys are and how key weights become its parameters."""

from __future__ import annotations

import os
from abc import ABC, abstractmethod
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np

from ..errors import InvalidDataError, MissingShapeError, OutputError
from ..files import check_output_path
from ..headpose import HeadPose
from ..names import normalize_name
from ..rig import Rig

__all__ = ["Target", "MeshTarget"]


def _quiet(*_a) -> None:
    return None


class Target(ABC):
    """A retargeting target: ``K`` named keys posed in the target's own parameters.

    The source side (keyshape weights per frame, by any solver, with regions, smoothing and the
    consistency check) never changes; a target only turns the ``(T, K)`` key weights into its own
    parameters (:meth:`params`) and writes them (:meth:`write`).  :attr:`solve_keys` is the target's
    key geometry as a :class:`~faceretarget.rig.Rig` (a mesh, or a point set): the metric in which a
    solver keeps weights inside their range, and what regions and the consistency check look at.

    Attributes
    ----------
    kind : str
        ``"mesh"``, ``"controls"``, ``"skeleton"`` or ``"drawing"``.
    name : str
        Where the target came from (for messages).
    names : list of str
        The keys' names, normalised as :class:`~faceretarget.rig.Rig` names are; a source keyshape
        pairs with the key of its name.
    """

    kind: str = "target"
    #: Output extensions (``"folder"`` for a folder) :meth:`write` knows.
    formats: tuple[str, ...] = ()

    def __init__(self, name: str, names: Sequence[str], where: Sequence[str] | None = None) -> None:
        self.name = str(name)
        self.names = [normalize_name(n) for n in names]
        self._where = list(where) if where is not None else None
        self._given = [str(n) for n in names]

    @property
    def n_keys(self) -> int:
        return len(self.names)

    #: What a key is called in messages ("keys", "key drawings", "key poses").
    key_word: str = "keys"

    def _weights(self, weights) -> np.ndarray:
        """Key weights as a ``(T, K)`` float array, the columns checked against the keys."""
        W = np.atleast_2d(np.asarray(weights, dtype=np.float64))
        if W.shape[1] != self.n_keys:
            raise InvalidDataError(f"{self.name}: {W.shape[1]} weight columns for {self.n_keys} {self.key_word}")
        return W

    @property
    @abstractmethod
    def solve_keys(self) -> Rig:
        """The key geometry the solvers measure the target in (shapes in :attr:`names` order)."""

    @abstractmethod
    def params(self, weights: np.ndarray):
        """The target's parameters for key weights ``(T, K)`` (columns in :attr:`names` order)."""

    @abstractmethod
    def write(self, path: str | os.PathLike, weights: np.ndarray, times: np.ndarray, *,
              head: HeadPose | None = None, log: Callable[..., None] = _quiet, **extra) -> Path:
        """Write the target driven by key weights ``(T, K)`` at ``times`` to ``path`` (by extension)."""

    def describe(self) -> str:
        """One line for the log."""
        return f"{self.kind} target {self.name}: {self.n_keys} keys"

    # ------------------------------------------------------------------ outputs
    def output_ext(self, path: str | os.PathLike) -> str:
        p = Path(path)
        return "folder" if p.is_dir() or p.suffix == "" else p.suffix.lower()

    def holds_head(self, path: str | os.PathLike) -> bool:
        """Whether :meth:`write` puts head motion into ``path`` beside the target."""
        return False

    def check_output(self, path: str | os.PathLike) -> Path:
        """Raise :class:`OutputError` before any work when :meth:`write` cannot write ``path``."""
        path = Path(path)
        ext = self.output_ext(path)
        if ext not in self.formats:
            raise OutputError(f"{path}: a {self.kind} target ({self.name}) is written as "
                              f"{', '.join(f if f != 'folder' else 'a folder' for f in self.formats)}, not '{ext}'")
        return path if ext == "folder" else check_output_path(path)

    # ------------------------------------------------------------------ pairing
    def check_keys(self, source_names: Sequence[str], source: str = "the source keyshapes") -> None:
        """Raise naming the file and row unless every source keyshape has a key here and every key a
        source keyshape (a row named after no source key is usually a typo)."""
        src = [normalize_name(n) for n in source_names]
        missing = [n for n in source_names if normalize_name(n) not in self.names]
        if missing:
            raise MissingShapeError(f"{self.name}: no key for source keyshape(s) {', '.join(missing[:8])}"
                                    f"{' ...' if len(missing) > 8 else ''} (keys here: "
                                    f"{', '.join(self._given[:8])}{' ...' if len(self._given) > 8 else ''})")
        extra = [i for i, n in enumerate(self.names) if n not in src]
        if extra:
            i = extra[0]
            where = f" ({self._where[i]})" if self._where else ""
            raise MissingShapeError(f"{self.name}: key '{self._given[i]}'{where} matches no source keyshape in "
                                    f"{source} ({len(extra)} such key(s)); name every key like the source "
                                    "keyshape it poses")

    def key_order(self, names: Sequence[str]) -> np.ndarray:
        """Column of each of :attr:`names` in weights whose columns are ``names``."""
        pos = {normalize_name(n): j for j, n in enumerate(names)}
        return np.array([pos[n] for n in self.names], dtype=np.int64)


class MeshTarget(Target):
    """Mesh keyshapes (a :class:`~faceretarget.rig.Rig`): today's target, written by
    :func:`faceretarget.pipelines.write_result` through the animation writers."""

    kind = "mesh"

    def __init__(self, rig: Rig) -> None:
        super().__init__(rig.name, rig.names)
        self.rig = rig
        from ..io import WRITERS

        self.formats = tuple(WRITERS)

    @property
    def solve_keys(self) -> Rig:
        return self.rig

    def params(self, weights: np.ndarray) -> np.ndarray:
        """The target meshes ``(T, V, 3)``."""
        return self.rig.evaluate(np.asarray(weights, dtype=np.float64))

    def holds_head(self, path) -> bool:
        from ..io import holds_head

        return holds_head(path)

    def check_keys(self, source_names, source: str = "the source keyshapes") -> None:
        """Mesh targets may hold more shapes than the source keys (a whole rig): only missing ones fail."""
        missing = [n for n in source_names if n not in self.rig]
        if missing:
            raise MissingShapeError(f"{self.name}: no target keyshape for source keyshape(s) {', '.join(missing[:8])}")

    def write(self, path, weights, times, *, head=None, log=_quiet, **extra) -> Path:
        from ..io import write_animation

        extra.pop("progress", None)

        return write_animation(path, rig=self.rig, weights=weights, names=list(self.rig.names), times=times,
                               head=head, **extra)
