"""``Performance``: one take sampled in time, with whichever channels its source gives.

The one take type of the package.  A take holds at least one channel:

============= ======================================= ===========================================
channel       arrays                                  comes from
============= ======================================= ===========================================
weights       ``(T, K)`` + ``names`` (ARKit names)    Live Link Face CSV, video capture, a solve
points        ``(T, P, 2|3)`` + ``labels``, NaN =     C3D markers, landmarks (video capture)
              a sample that is missing
vertices      ``(T, V, 3)`` + ``mesh``                OBJ sequences, ``.npz``
head          :class:`~faceretarget.headpose.HeadPose` Live Link Face head columns, video capture,
                                                      BVH / SMPL-X, rigid markers, synthesis
audio         ``(N,)`` float32 in [-1, 1] + rate      WAV, the video's sound
curves        ``(T, C)`` + ``curve_names``            Live Link Face eye angles (``LeftEyeYaw``...)
============= ======================================= ===========================================

Each channel is validated once, here: shapes against the frame count, finite weights and
vertices, strictly increasing finite times.  ``unit`` is the length unit of points and vertices.
``timecode`` + ``timecode_rate`` place the take on a clock (Live Link Face's ``Timecode``
column): frame ``i`` happened at ``timecode + times[i]`` seconds since midnight.  Curves and the
timecode ride along with the face channel: results of a clone or retarget, and every writer that
can hold them (Live Link Face CSV), carry them from the input take.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from .errors import InvalidDataError
from .headpose import HeadPose
from .mesh import Mesh
from .timebase import check_times, infer_fps

__all__ = ["Performance", "CHANNELS"]

#: The face channels, in the order :attr:`Performance.kind` prefers them.
CHANNELS = ("vertices", "points", "weights")


@dataclass(eq=False)
class Performance:
    """A take: what a face (and head) did over time.

    Parameters
    ----------
    times : (T,) float
        Time of each frame in seconds, strictly increasing (starts where the take starts; not
        necessarily at 0).
    fps : float
        Nominal frame rate (the median rate when frames are irregular, :func:`~faceretarget.timebase.infer_fps`).
    weights : (T, K) float, optional
        Blendshape weights, columns named by ``names`` (ARKit camelCase).
    names : list of str
        Weight column names.
    points : (T, P, 2|3) float, optional
        Feature point tracks (markers, landmarks); NaN marks a missing sample.
    labels : list of str
        Point labels.
    vertices : (T, V, 3) float, optional
        A mesh sequence; ``mesh`` gives its faces.
    mesh : Mesh, optional
        Topology (and rest shape) for ``vertices``.
    head : HeadPose, optional
        Head rotation (and translation in metres) per frame, in the package's one frame
        (:mod:`faceretarget.headpose`).
    audio : (N,) float32, optional
        Mono samples in [-1, 1] synchronous with ``times[0]``; ``audio_rate`` in Hz.
    unit : str, optional
        Unit of points / vertices.
    source : str
        Where the take came from (file name), used in messages.
    timecode : float, optional
        Seconds since midnight at ``times == 0`` (so frame ``i`` is at ``timecode + times[i]``), in
        ``[0, 86400)``; given with ``timecode_rate``.
    timecode_rate : float, optional
        Frames per second of the timecode's frame field (``HH:MM:SS:FF``; Live Link Face: 60).
    curves : (T, C) float, optional
        Other per-frame values that are not key-shape weights, named by ``curve_names`` (Live Link
        Face's eye angles in radians: ``LeftEyeYaw, LeftEyePitch, LeftEyeRoll, RightEyeYaw, ...``).
    curve_names : list of str
        Curve names (unique).
    """

    times: np.ndarray
    fps: float
    weights: np.ndarray | None = None
    names: list[str] = field(default_factory=list)
    points: np.ndarray | None = None
    labels: list[str] = field(default_factory=list)
    vertices: np.ndarray | None = None
    mesh: Mesh | None = None
    head: HeadPose | None = None
    audio: np.ndarray | None = None
    audio_rate: float | None = None
    unit: str | None = None
    source: str = "performance"
    timecode: float | None = None
    timecode_rate: float | None = None
    curves: np.ndarray | None = None
    curve_names: list[str] = field(default_factory=list)

    def __post_init__(self) -> None:
        self.times = check_times(self.times, self.source)
        T = self.times.size
        if all(x is None for x in (self.weights, self.points, self.vertices, self.head)):
            raise InvalidDataError(f"{self.source}: a performance holds weights, points, vertices or a head pose")
        if not (np.isfinite(self.fps) and self.fps > 0):
            raise InvalidDataError(f"{self.source}: fps must be positive, got {self.fps}")
        self.fps = float(self.fps)
        if self.weights is not None:
            self._check_weights(T)
        if self.points is not None:
            self._check_points(T)
        if self.vertices is not None:
            self._check_vertices(T)
        if self.head is not None:
            if not isinstance(self.head, HeadPose):
                raise InvalidDataError(f"{self.source}: head must be a HeadPose, got {type(self.head).__name__}")
            if self.head.n_frames != T:
                raise InvalidDataError(f"{self.source}: the head pose has {self.head.n_frames} frames, the take {T}")
        if self.audio is not None:
            self._check_audio()
        self._check_timecode()
        if self.curves is not None:
            self._check_curves(T)
        elif self.curve_names:
            raise InvalidDataError(f"{self.source}: curve_names given without curves")

    def _check_timecode(self) -> None:
        if (self.timecode is None) != (self.timecode_rate is None):
            raise InvalidDataError(f"{self.source}: give timecode and timecode_rate together")
        if self.timecode is None:
            return
        tc, rate = float(self.timecode), float(self.timecode_rate)
        if not (np.isfinite(tc) and 0.0 <= tc < 86400.0):
            raise InvalidDataError(f"{self.source}: timecode must be seconds since midnight in [0, 86400), got {tc}")
        if not (np.isfinite(rate) and rate > 0):
            raise InvalidDataError(f"{self.source}: timecode_rate must be positive, got {rate}")
        self.timecode, self.timecode_rate = tc, rate

    def _check_curves(self, T: int) -> None:
        c = np.asarray(self.curves, dtype=np.float64)
        names = [str(n) for n in self.curve_names]
        if c.ndim != 2 or c.shape != (T, len(names)):
            raise InvalidDataError(f"{self.source}: curves must be ({T}, {len(names)}) for {len(names)} curve "
                                   f"names, got {c.shape}")
        if not np.isfinite(c).all():
            f, k = (int(x[0]) for x in np.nonzero(~np.isfinite(c)))
            raise InvalidDataError(f"{self.source}: frame {f} curve '{names[k]}' is {c[f, k]}")
        dup = sorted({n for n in names if names.count(n) > 1})
        if dup:
            raise InvalidDataError(f"{self.source}: curve '{dup[0]}' is named twice")
        self.curves, self.curve_names = c, names

    def _check_weights(self, T: int) -> None:
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

    def _check_points(self, T: int) -> None:
        p = np.asarray(self.points, dtype=np.float64)
        if p.ndim != 3 or p.shape[0] != T or p.shape[2] not in (2, 3):
            raise InvalidDataError(f"{self.source}: points must be ({T}, P, 2|3), got {p.shape}")
        if np.isinf(p).any():
            f = int(np.nonzero(np.isinf(p))[0][0])
            raise InvalidDataError(f"{self.source}: frame {f} has an infinite point coordinate")
        if self.labels and len(self.labels) != p.shape[1]:
            raise InvalidDataError(f"{self.source}: {len(self.labels)} labels for {p.shape[1]} points")
        self.points = p
        self.labels = list(self.labels)

    def _check_vertices(self, T: int) -> None:
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

    def _check_audio(self) -> None:
        a = np.asarray(self.audio, dtype=np.float32).reshape(-1)
        if not np.isfinite(a).all():
            raise InvalidDataError(f"{self.source}: the audio holds non-finite samples")
        if self.audio_rate is None or not (np.isfinite(self.audio_rate) and self.audio_rate > 0):
            raise InvalidDataError(f"{self.source}: audio needs a positive audio_rate, got {self.audio_rate}")
        self.audio = a
        self.audio_rate = float(self.audio_rate)

    # ------------------------------------------------------------------ constructors
    @staticmethod
    def _times_fps(n: int, times, fps) -> tuple[np.ndarray, float]:
        if times is None:
            if fps is None:
                raise InvalidDataError("give times or fps")
            return np.arange(n) / float(fps), float(fps)
        t = np.asarray(times, dtype=np.float64)
        if fps is None:
            d = np.diff(t.reshape(-1))
            ok = np.isfinite(t).all() and (d > 0).all()
            fps = infer_fps(t, default=30.0) if ok else 30.0  # bad times: __post_init__ names the frame
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

    @classmethod
    def from_head(cls, head: HeadPose, times=None, fps=None, **kw) -> Performance:
        t, f = cls._times_fps(head.n_frames, times, fps)
        return cls(times=t, fps=f, head=head, **kw)

    # ------------------------------------------------------------------ properties
    @property
    def channels(self) -> tuple[str, ...]:
        """The channels present, of ``"weights"``, ``"points"``, ``"vertices"``, ``"head"``, ``"audio"``,
        ``"curves"``."""
        have = [c for c in ("weights", "points", "vertices", "head") if getattr(self, c) is not None]
        if self.audio is not None:
            have.append("audio")
        if self.curves is not None:
            have.append("curves")
        return tuple(have)

    @property
    def kind(self) -> str:
        """The face channel methods work on: ``"vertices"``, ``"points"`` or ``"weights"`` (the first
        present, in that order), or ``"head"`` for a take of head motion only."""
        for c in CHANNELS:
            if getattr(self, c) is not None:
                return c
        return "head"

    @property
    def n_frames(self) -> int:
        return int(self.times.size)

    @property
    def duration(self) -> float:
        return float(self.times[-1] - self.times[0]) if self.n_frames else 0.0

    def data(self) -> np.ndarray:
        """The array of the face channel :attr:`kind` names."""
        if self.kind == "head":
            raise InvalidDataError(f"{self.source}: a take of head motion only has no face data")
        return getattr(self, self.kind)

    # ------------------------------------------------------------------ new takes from this one
    def replace(self, **changes) -> Performance:
        """A copy with ``changes`` (field names), validated again."""
        return replace(self, **changes)

    def select(self, *channels: str) -> Performance:
        """A take with only ``channels`` (names of :attr:`channels`; ``"audio"`` and ``"curves"`` included;
        the timecode is kept)."""
        unknown = set(channels) - {"weights", "points", "vertices", "head", "audio", "curves"}
        if unknown:
            raise InvalidDataError(f"unknown channel(s) {', '.join(sorted(unknown))}")
        drop: dict = {}
        if "weights" not in channels:
            drop.update(weights=None, names=[])
        if "points" not in channels:
            drop.update(points=None, labels=[])
        if "vertices" not in channels:
            drop.update(vertices=None, mesh=None)
        if "head" not in channels:
            drop["head"] = None
        if "audio" not in channels:
            drop.update(audio=None, audio_rate=None)
        if "curves" not in channels:
            drop.update(curves=None, curve_names=[])
        return replace(self, **drop)

    def slice(self, start: int, stop: int | None = None) -> Performance:
        """Frames ``start:stop`` as a new performance (audio is dropped; curves and timecode kept)."""
        s = slice(start, stop)
        kw = {c: getattr(self, c)[s] for c in CHANNELS + ("curves",) if getattr(self, c) is not None}
        head = None if self.head is None else self.head[s]
        return replace(self, times=self.times[s], audio=None, audio_rate=None, head=head, **kw)

    def _carried(self) -> dict:
        """What a new face channel keeps of this take besides times: head, audio, timecode, curves."""
        return dict(head=self.head, audio=self.audio, audio_rate=self.audio_rate, source=self.source,
                    timecode=self.timecode, timecode_rate=self.timecode_rate, curves=self.curves,
                    curve_names=list(self.curve_names))

    def with_weights(self, weights: np.ndarray, names: list[str]) -> Performance:
        """This take's times, head, audio, timecode and curves with new weights as its only face channel."""
        return Performance(self.times, self.fps, weights=weights, names=list(names), **self._carried())

    def with_points(self, points: np.ndarray, labels: list[str] | None = None, unit: str | None = None) -> Performance:
        """This take's times, head, audio, timecode and curves with new points as its only face channel."""
        return Performance(self.times, self.fps, points=points, labels=list(self.labels if labels is None else labels),
                           unit=self.unit if unit is None else unit, **self._carried())

    def with_vertices(self, vertices: np.ndarray, mesh: Mesh | None = None, unit: str | None = None) -> Performance:
        """This take's times, head, audio, timecode and curves with new vertices as its only face channel."""
        return Performance(self.times, self.fps, vertices=vertices, mesh=mesh, unit=unit, **self._carried())
