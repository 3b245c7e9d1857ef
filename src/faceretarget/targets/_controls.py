"""Control-vector targets: keys posed with the target rig's own sliders (Chuang Fig. 3.8)."""

from __future__ import annotations

import os
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import DataWarning, InvalidDataError, OutputError
from ..formats import BVH, CSV, JSON
from ..io import ControlTable, holds_head, write_animation, write_control_curves
from ..mesh import Mesh
from ..names import ARKIT_NAMES, normalize_name, split_parent
from ..numerics import range_metric, solve_bounded, solve_inequality
from ..rig import Rig
from ._base import Target, _quiet

__all__ = ["ControlTarget", "RangeReport", "CONTROL_RANGES"]

#: What a :class:`ControlTarget` does with controls outside their declared ranges (the first is the default).
CONTROL_RANGES = ("solve", "report", "clip", "project")

#: Formats written from the curves alone (``.csv``: Live Link Face for ARKit controls, else ``time,<controls>``).
_CURVE_FORMATS = (CSV, JSON)


def _is_arkit(name: str) -> bool:
    n = normalize_name(name)
    return n in ARKIT_NAMES or split_parent(n) in ARKIT_NAMES


@dataclass
class RangeReport:
    """How much of a take's control curves stays inside the controls' declared ranges.

    Attributes
    ----------
    inside_pct : float
        Share of all values (frames x controls) inside their range, per cent.
    frames_inside_pct : float
        Share of frames with every control inside, per cent.
    worst : str
        The control most often outside (empty when none is).
    worst_outside_pct : float
        Its share of frames outside, per cent.
    max_excess : float
        Largest distance outside a range, in the control's own units.
    ranges : str
        How the written curves were brought into the ranges (:data:`CONTROL_RANGES`).
    """

    inside_pct: float
    frames_inside_pct: float
    worst: str
    worst_outside_pct: float
    max_excess: float
    ranges: str = "solve"

    def line(self) -> str:
        s = (f"controls inside their declared range: {self.inside_pct:.2f} % of the values, "
             f"{self.frames_inside_pct:.1f} % of the frames")
        if self.worst:
            s += (f"; most often outside: '{self.worst}' ({self.worst_outside_pct:.1f} % of the frames), "
                  f"largest excess {self.max_excess:.3g}")
            s += {"report": " (written as solved)", "clip": "; written clipped to the ranges",
                  "project": "; written as the nearest in-range controls (in the rig's metric)",
                  "solve": "; solved again inside the ranges"}[self.ranges]
        return s


class ControlTarget(Target):
    """Keys given as the target rig's control values (a :class:`~faceretarget.io.ControlTable`).

    The controls of a frame are the neutral controls plus the weighted key offsets, ``c(t) = c0 +
    sum_k w_k(t) (C_k - c0)`` (linear blending; ``W @ C`` when the neutral is all 0).  When the
    rig's own shapes are given (``rig``, its shapes named like the controls: an ARKit rig for ARKit
    controls), :attr:`solve_keys` is the rig posed at each key's controls, so the solve is the one a
    mesh target of those shapes gets and the curves, played on the rig, give the same faces; without
    it the keys are measured in the controls themselves, each scaled by its declared range.

    Parameters
    ----------
    table : ControlTable
    rig : Rig, optional
        The target rig's shapes (for ``.glb`` / ``.usd`` / ``.blend`` / ``.fbx`` / ``.npz`` output
        and previews); each control must drive one of its shapes.
    ranges : {"solve", "report", "clip", "project"}
        What happens to controls outside their declared ranges; the share outside as first solved
        is reported in every case (:meth:`range_report`).  ``"solve"`` (default): the key weights of
        every frame whose controls leave a range are solved again, the blend of the keys nearest to
        the solved one in the target's geometry (the metric the solvers keep weights in range in)
        whose controls ``c0 + w @ (C - c0)`` are all inside their ranges
        (:func:`~faceretarget.numerics.solve_inequality`, a linear-inequality least-squares per
        frame); the curves are still a blend of the keys, so they play exactly the faces of a mesh
        target of the same keys driven by those weights (:meth:`key_weights`).  ``"report"``:
        written as first solved; ``"clip"``: each control clipped to its range; ``"project"``: per
        frame, the in-range controls whose face is nearest to the solved one (box-constrained least
        squares in the rig's shapes, :func:`~faceretarget.numerics.solve_bounded`; in the controls
        scaled by their ranges without a rig), no longer a blend of the keys.
    """

    kind = "controls"

    def __init__(self, table: ControlTable, rig: Rig | None = None, *, ranges: str = "solve") -> None:
        super().__init__(table.source, table.keys, table.rows)
        if ranges not in CONTROL_RANGES:
            raise InvalidDataError(f"control ranges must be one of {', '.join(CONTROL_RANGES)}, got {ranges!r}")
        self.table = table
        self.rig = rig
        self.ranges = ranges
        self.controls = list(table.controls)
        self.arkit = all(_is_arkit(c) for c in self.controls)
        C = table.values - table.neutral                          # (K, M) key offsets
        self._offsets = C
        posed = np.abs(C).max(axis=1) > 0
        if not posed.any():
            raise InvalidDataError(f"{table.source}: no key is posed (every row is empty or at the neutral "
                                   "controls): pose the target for each keyshape and type its slider values")
        if not posed.all():
            rest = [k for k, p in zip(table.keys, posed, strict=True) if not p]
            warnings.warn(f"{table.source}: {len(rest)} of {len(posed)} key(s) left at rest ({', '.join(rest[:6])}"
                          f"{' ...' if len(rest) > 6 else ''}): those keyshapes will not move the target",
                          DataWarning, stacklevel=2)
        if rig is not None:
            M = len(self.controls)
            drive = rig.map_weights(self.controls, np.eye(M), source=table.source, warn=False)  # (M, K_rig)
            dead = [self.controls[j] for j in range(M) if not np.abs(drive[j]).any()]
            if len(dead) == M:
                raise InvalidDataError(f"{table.source}: no control drives a shape of the rig '{rig.name}' ('{dead[0]}', "
                                       "...); name the columns like the rig's shapes")
            if dead:
                warnings.warn(f"{table.source}: control(s) {', '.join(dead[:8])} move no shape of the rig '{rig.name}', "
                              "so its previews and mesh outputs do not show them; the control curves written "
                              "(.csv / .json) keep their values", DataWarning, stacklevel=2)
            self._drive = drive
            shapes = drive @ rig.deltas.reshape(rig.n_shapes, -1)                   # (M, 3V) per control
            rest = rig.evaluate(table.neutral @ drive)
            deltas = rig.evaluate(table.values @ drive) - rest
            self._keys = Rig(rig.neutral.with_vertices(rest), list(table.keys), deltas, rig.unit, rig.landmarks, None,
                             table.source)
            self.formats = tuple(dict.fromkeys(_CURVE_FORMATS + tuple(_rig_formats())))
        else:
            span = table.hi - table.lo
            pts = np.zeros((len(self.controls), 3))
            pts[:, 0] = table.neutral / span
            deltas = np.zeros((len(table.keys), len(self.controls), 3))
            deltas[:, :, 0] = C / span
            self._keys = Rig(Mesh(pts, name="controls"), list(table.keys), deltas, "mm", None, None, table.source)
            self.formats = _CURVE_FORMATS
            shapes = np.diag(1.0 / span)
        self._metric = range_metric(shapes.T) if ranges == "project" else None
        self._key_metric = (range_metric(self._keys.deltas.reshape(self._keys.n_shapes, -1).T) if ranges == "solve"
                            else None)

    @property
    def solve_keys(self) -> Rig:
        return self._keys

    def describe(self) -> str:
        rig = f", shapes of '{self.rig.name}'" if self.rig is not None else ", no rig shapes"
        return (f"control target {self.name}: {self.n_keys} keys x {len(self.controls)} controls"
                f"{' (ARKit names)' if self.arkit else ''}{rig}")

    def solved(self, weights: np.ndarray) -> np.ndarray:
        """Control curves ``(T, M)`` as solved: ``c0 + W @ (C - c0)``."""
        W = self._weights(weights)
        return self.table.neutral + W @ self._offsets

    def key_weights(self, weights: np.ndarray) -> np.ndarray:
        """The key weights ``(T, K)`` the curves are a blend of: with ``ranges="solve"`` every frame
        whose controls leave a range solved again inside them (:class:`ControlTarget`), else ``weights``."""
        W = self._weights(weights)
        if self.ranges != "solve":
            return W
        return solve_inequality(self._key_metric, W, self._offsets.T, self.table.lo, self.table.hi,
                                offset=self.table.neutral)

    def params(self, weights: np.ndarray) -> np.ndarray:
        """Control curves ``(T, M)``: :meth:`solved`, then brought into the ranges as ``ranges`` says."""
        if self.ranges == "solve":          # a blend of the keys inside the ranges (up to rounding: clipped)
            return np.clip(self.solved(self.key_weights(weights)), self.table.lo, self.table.hi)
        return self.in_ranges(self.solved(weights))

    def in_ranges(self, controls: np.ndarray) -> np.ndarray:
        """``controls`` ``(T, M)`` after the ``ranges`` policy (unchanged for ``"report"``; ``"solve"``
        works on the key weights, :meth:`params`)."""
        c = np.atleast_2d(np.asarray(controls, dtype=np.float64))
        if self.ranges == "solve":
            raise InvalidDataError("ranges='solve' solves the key weights again: use params(weights)")
        lo, hi = self.table.lo, self.table.hi
        if self.ranges == "clip":
            return np.clip(c, lo, hi)
        if self.ranges == "project":
            out = c.copy()
            bad = ~self.table.in_range(c).all(axis=1)
            if bad.any():
                R = self._metric
                out[bad] = solve_bounded(R, c[bad] @ R.T, lo, hi)
            return out
        return c

    def range_report(self, controls: np.ndarray) -> RangeReport:
        """:class:`RangeReport` of unclipped control curves ``(T, M)``."""
        c = np.atleast_2d(np.asarray(controls, dtype=np.float64))
        inside = self.table.in_range(c)
        per = 100.0 * (1.0 - inside.mean(axis=0))
        j = int(np.argmax(per))
        excess = np.maximum(self.table.lo - c, c - self.table.hi).max()
        return RangeReport(100.0 * float(inside.mean()), 100.0 * float(inside.all(axis=1).mean()),
                           self.controls[j] if per[j] > 0 else "", float(per[j]), float(max(excess, 0.0)),
                           self.ranges)

    def holds_head(self, path) -> bool:
        ext = self.output_ext(path)
        if ext == CSV:
            return self.arkit
        if ext == JSON:
            return False
        return holds_head(path)

    def check_output(self, path) -> Path:
        path = Path(path)
        ext = self.output_ext(path)
        if ext not in _CURVE_FORMATS and self.rig is None and ext in _rig_formats():
            raise OutputError(f"{path}: writing {ext if ext != 'folder' else 'an OBJ sequence'} plays the controls on "
                              f"the target rig's shapes; give the rig (--target-rig DIR) or write "
                              f"{', '.join(_CURVE_FORMATS)} (control curves)")
        return super().check_output(path)

    def write(self, path: str | os.PathLike, weights: np.ndarray, times: np.ndarray, *, head=None,
              log=_quiet, **extra) -> Path:
        """Write the control curves: ``.csv`` (Live Link Face layout when the controls are ARKit names,
        else ``time,<controls>``), ``.json``, or -- with the rig -- any animation format, the rig's
        shapes driven by the controls (:func:`~faceretarget.io.write_animation`).

        ``extra`` passes ``timecode``, ``timecode_rate``, ``curves``, ``curve_names``, ``audio``,
        ``audio_rate`` and ``bake`` to the animation writers that hold them.
        """
        path = self.check_output(path)
        extra.pop("progress", None)
        raw = self.solved(weights)
        rep = self.range_report(raw)
        if self.ranges == "solve":
            W = self._weights(weights)
            Wk = self.key_weights(W)
            again = int((Wk != W).any(axis=1).sum())
            c = np.clip(self.solved(Wk), self.table.lo, self.table.hi)        # = params(W)
            log(f"controls inside their declared ranges: {self.range_report(c).inside_pct:.2f} % of the values; "
                f"{again} of {len(W)} frames solved again inside the ranges (the nearest blend of the keys in the "
                f"target's geometry; {rep.inside_pct:.2f} % of the values were inside as first solved)")
        else:
            log(rep.line())
            if self.ranges == "report" and rep.inside_pct < 99.0:
                log(f"note: {100 - rep.inside_pct:.1f} % of the control values are outside their ranges as written; a "
                    "rig that clamps its sliders will not play them: the default --control-ranges solve keeps them "
                    "inside")
            c = self.in_ranges(raw)
        ext = self.output_ext(path)
        if ext == JSON or (ext == CSV and not self.arkit):
            return write_control_curves(path, times, c, self.controls)
        if ext == CSV:
            keep = {k: v for k, v in extra.items() if k in ("timecode", "timecode_rate", "curves", "curve_names")}
            return write_animation(path, weights=c, names=self.controls, times=times, head=head, **keep)
        live = np.abs(self._drive).any(axis=1)      # controls that drive none of the rig's shapes were warned about
        return write_animation(path, rig=self.rig, weights=c[:, live], names=[n for n, k in zip(self.controls, live,
                               strict=True) if k], times=times, head=head, **extra)


def _rig_formats() -> list[str]:
    from ..io import WRITERS

    return [k for k in WRITERS if k not in (CSV, BVH)]
