"""Smooth ramps."""

from __future__ import annotations

import numpy as np

__all__ = ["smoothstep"]


def smoothstep(x) -> np.ndarray:
    """``3t^2 - 2t^3`` of ``t = clip(x, 0, 1)``: 0 at and below 0, 1 at and above 1, C1 between.

    >>> smoothstep([-1.0, 0.5, 2.0]).tolist()
    [0.0, 0.5, 1.0]
    """
    t = np.clip(np.asarray(x, dtype=np.float64), 0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)
