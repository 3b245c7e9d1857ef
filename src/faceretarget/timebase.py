"""Frame times: the one place a frame rate is inferred from times, and times made from a rate.

A take's ``times`` are seconds, strictly increasing, not necessarily evenly spaced (dropped frames,
Live Link Face's lost-face rows).  Its nominal frame rate is the median rate,
``1 / median(diff(times))`` (:func:`infer_fps`); a take of one frame has no rate of its own and
takes the caller's ``default`` (a file's declared rate, or what the user passed).
"""

from __future__ import annotations

import numpy as np

from .errors import InvalidDataError

__all__ = ["infer_fps", "frame_times", "check_times", "is_regular", "even_grid"]


def check_times(times, source: str = "times") -> np.ndarray:
    """``times`` as a (T,) float64 array, finite and strictly increasing, or an error naming the frame."""
    t = np.asarray(times, dtype=np.float64).reshape(-1)
    if not np.isfinite(t).all():
        raise InvalidDataError(f"{source}: frame {int(np.flatnonzero(~np.isfinite(t))[0])} has a non-finite time")
    d = np.diff(t)
    if d.size and (d <= 0).any():
        k = int(np.flatnonzero(d <= 0)[0]) + 1
        raise InvalidDataError(f"{source}: frame {k} time {t[k]:.6f} s does not increase after {t[k - 1]:.6f} s")
    return t


def infer_fps(times, default: float | None = None, *, source: str = "times") -> float:
    """Nominal frame rate of frame ``times``: ``1 / median(diff(times))``.

    Parameters
    ----------
    times : (T,) float
        Seconds, strictly increasing.
    default : float, optional
        The rate of a take with fewer than two frames (which has no rate of its own).

    Raises
    ------
    InvalidDataError
        Fewer than two frames and no ``default``.

    >>> infer_fps([0.0, 0.04, 0.08, 0.16])
    25.0
    """
    t = np.asarray(times, dtype=np.float64).reshape(-1)
    if t.size < 2:
        if default is None:
            raise InvalidDataError(f"{source}: a frame rate cannot be inferred from {t.size} frame(s); give fps")
        return float(default)
    step = float(np.median(np.diff(t)))
    if not (np.isfinite(step) and step > 0):
        raise InvalidDataError(f"{source}: times must be finite and increase to give a frame rate")
    return 1.0 / step


def frame_times(n: int, fps: float, start: float = 0.0) -> np.ndarray:
    """``start + arange(n) / fps``: times of ``n`` evenly spaced frames."""
    fps = float(fps)
    if not (np.isfinite(fps) and fps > 0):
        raise InvalidDataError(f"fps must be positive, got {fps}")
    return start + np.arange(int(n)) / fps


def is_regular(times, tolerance: float = 0.25) -> bool:
    """True when every frame step is within ``tolerance`` of the median step."""
    return not even_grid(times, tolerance)[1]


def even_grid(times, tolerance: float = 0.25) -> tuple[np.ndarray, bool]:
    """An evenly spaced grid at the median step over ``times``, and whether it differs from them.

    Returns ``(times, False)`` when every step is within ``tolerance`` of the median step (a regular
    take), else ``(grid, True)`` with the grid spanning the same interval (dropped frames filled).
    """
    t = np.asarray(times, dtype=np.float64)
    d = np.diff(t)
    if d.size == 0:
        return t, False
    step = float(np.median(d))
    if np.all(np.abs(d - step) <= tolerance * step):
        return t, False
    n = int(round((t[-1] - t[0]) / step)) + 1
    return t[0] + step * np.arange(n), True
