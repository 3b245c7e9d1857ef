"""``Performance``: one take sampled in time, as weights, points or vertices."""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from .errors import InvalidDataError
from .mesh import Mesh

__all__ = ["Performance"]


def _check_times(times: np.ndarray, source: str) -> np.ndarray:
    t = np.asarray(times, dtype=np.float64).reshape(-1)
    if not np.isfinite(t).all():
        raise InvalidDataError(f"{source}: frame {int(np.flatnonzero(~np.isfinite(t))[0])} has a non-finite time")
    d = np.diff(t)
    if d.size and (d <= 0).any():
        k = int(np.flatnonzero(d <= 0)[0]) + 1
        raise InvalidDataError(f"{source}: frame {k} time {t[k]:.6f} s does not increase after {t[k - 1]:.6f} s")
    return t


@dataclass(eq=False)
class Performance:
    """A take: what a face did over time, in exactly one of three representations.

    Parameters
    ----------
    times : (T,) float
        Time of each frame in seconds, strictly increasing (starts where the take starts; not
        necessarily at 0).
    fps : float
        Nominal frame rate (the median rate when frames are irregular).
    weights : (T, K) float, optional
        Blendshape weights, columns named by ``names`` (ARKit camelCase).
    names : list of str
        Weight column names.
    points : (T, P, 2|3) float, optional
        Feature point tracks (markers, landmarks); NaN marks an occluded sample.
    labels : list of str
        Point labels.
    vertices : (T, V, 3) float, optional
        A mesh sequence; ``mesh`` gives its faces.
    mesh : Mesh, optional
        Topology (and rest shape) for ``vertices``.
    audio : (N,) float, optional
        Mono audio samples in [-1, 1] synchronous with ``times[0]``; ``audio_rate`` in Hz.
    head_rotation : (T, 3) float, optional
        Head yaw, pitch, roll as the source gives them (a Live Link Face CSV's ``HeadYaw``,
        ``HeadPitch``, ``HeadRoll`` columns unchanged; see that reader for their units).
    head_translation : (T, 3) float, optional
    unit : str, optional
        Unit of points / vertices.
    source : str
        Where the take came from (file name), used in messages.
    """

    times: np.ndarray
    fps: float
    weights: np.ndarray | None = None
    names: list[str] = field(default_factory=list)
    points: np.ndarray | None = None
    labels: list[str] = field(default_factory=list)
    vertices: np.ndarray | None = None
    mesh: Mesh | None = None
    audio: np.ndarray | None = None
    audio_rate: float | None = None
    head_rotation: np.ndarray | None = None
    head_translation: np.ndarray | None = None
    unit: str | None = None
    source: str = "performance"

    def __post_init__(self) -> None:
        self.times = _check_times(self.times, self.source)
        T = self.times.size
        kinds = [x is not None for x in (self.weights, self.points, self.vertices)]
        if sum(kinds) != 1:
            raise InvalidDataError(f"{self.source}: a performance holds exactly one of weights, points or vertices")
        if not (np.isfinite(self.fps) and self.fps > 0):
            raise InvalidDataError(f"{self.source}: fps must be positive, got {self.fps}")
        if self.weights is not None:
            w = np.asarray(self.weights, dtype=np.float64)
            if w.ndim != 2 or w.shape[0] != T or w.shape[1] != len(self.names):
                raise InvalidDataError(
                    f"{self.source}: weights must be ({T}, {len(self.names)}) for {len(self.names)} names, got {w.shape}"
                )
            bad = ~np.isfinite(w)
            if bad.any():
                f, k = (int(x[0]) for x in np.nonzero(bad))
                raise InvalidDataError(
                    f"{self.source}: frame {f} (t={self.times[f]:.3f} s) weight '{self.names[k]}' is {w[f, k]}"
                )
            self.weights = w
            self.names = list(self.names)
        if self.points is not None:
            p = np.asarray(self.points, dtype=np.float64)
            if p.ndim != 3 or p.shape[0] != T or p.shape[2] not in (2, 3):
                raise InvalidDataError(f"{self.source}: points must be ({T}, P, 2|3), got {p.shape}")
            if np.isinf(p).any():
                f = int(np.nonzero(np.isinf(p))[0][0])
                raise InvalidDataError(f"{self.source}: frame {f} has an infinite point coordinate")
            if self.labels and len(self.labels) != p.shape[1]:
                raise InvalidDataError(f"{self.source}: {len(self.labels)} labels for {p.shape[1]} points")
            self.points = p
        if self.vertices is not None:
            v = np.asarray(self.vertices, dtype=np.float64)
            if v.ndim != 3 or v.shape[0] != T or v.shape[2] != 3:
                raise InvalidDataError(f"{self.source}: vertices must be ({T}, V, 3), got {v.shape}")
            bad = ~np.isfinite(v)
            if bad.any():
                f, j = (int(x[0]) for x in np.nonzero(bad)[:2])
                raise InvalidDataError(f"{self.source}: frame {f} vertex {j} is not finite")
            if self.mesh is not None and self.mesh.n_vertices != v.shape[1]:
                raise InvalidDataError(
                    f"{self.source}: frames have {v.shape[1]} vertices but the mesh has {self.mesh.n_vertices}"
                )
            self.vertices = v
        for attr in ("head_rotation", "head_translation"):
            a = getattr(self, attr)
            if a is not None:
                a = np.asarray(a, dtype=np.float64)
                if a.shape != (T, 3):
                    raise InvalidDataError(f"{self.source}: {attr} must be ({T}, 3), got {a.shape}")
                setattr(self, attr, a)

    # ------------------------------------------------------------------ constructors
    @staticmethod
    def _times_fps(n: int, times, fps) -> tuple[np.ndarray, float]:
        if times is None:
            if fps is None:
                raise InvalidDataError("give times or fps")
            return np.arange(n) / float(fps), float(fps)
        t = np.asarray(times, dtype=np.float64)
        if fps is None:
            d = np.diff(t)
            fps = 1.0 / float(np.median(d)) if d.size else 30.0
        return t, float(fps)

    @classmethod
    def from_weights(cls, weights, names, times=None, fps=None, **kw) -> Performance:
        w = np.asarray(weights, dtype=np.float64)
        t, f = cls._times_fps(len(w), times, fps)
        return cls(times=t, fps=f, weights=w, names=list(names), **kw)

    @classmethod
    def from_points(cls, points, labels=None, times=None, fps=None, **kw) -> Performance:
        p = np.asarray(points, dtype=np.float64)
        t, f = cls._times_fps(len(p), times, fps)
        return cls(times=t, fps=f, points=p, labels=list(labels or []), **kw)

    @classmethod
    def from_vertices(cls, vertices, mesh=None, times=None, fps=None, **kw) -> Performance:
        v = np.asarray(vertices, dtype=np.float64)
        t, f = cls._times_fps(len(v), times, fps)
        return cls(times=t, fps=f, vertices=v, mesh=mesh, **kw)

    # ------------------------------------------------------------------ properties
    @property
    def kind(self) -> str:
        """``"weights"``, ``"points"`` or ``"vertices"``."""
        if self.weights is not None:
            return "weights"
        if self.points is not None:
            return "points"
        return "vertices"

    @property
    def n_frames(self) -> int:
        return int(self.times.size)

    @property
    def duration(self) -> float:
        return float(self.times[-1] - self.times[0]) if self.n_frames else 0.0

    def data(self) -> np.ndarray:
        """The take's array, whatever its kind."""
        return {"weights": self.weights, "points": self.points, "vertices": self.vertices}[self.kind]

    def slice(self, start: int, stop: int | None = None) -> Performance:
        """Frames ``start:stop`` as a new performance (audio is dropped)."""
        s = slice(start, stop)
        kw = {self.kind: self.data()[s]}
        out = replace(
            self, times=self.times[s], audio=None, audio_rate=None,
            head_rotation=None if self.head_rotation is None else self.head_rotation[s],
            head_translation=None if self.head_translation is None else self.head_translation[s],
            **kw,
        )
        return out

    def with_weights(self, weights: np.ndarray, names: list[str]) -> Performance:
        return Performance(self.times, self.fps, weights=weights, names=list(names),
                           head_rotation=self.head_rotation, head_translation=self.head_translation,
                           audio=self.audio, audio_rate=self.audio_rate, source=self.source)

    def with_vertices(self, vertices: np.ndarray, mesh: Mesh | None = None, unit: str | None = None) -> Performance:
        return Performance(self.times, self.fps, vertices=vertices, mesh=mesh, unit=unit,
                           head_rotation=self.head_rotation, head_translation=self.head_translation,
                           audio=self.audio, audio_rate=self.audio_rate, source=self.source)
