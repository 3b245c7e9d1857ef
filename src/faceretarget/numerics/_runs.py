"""Runs of True in a boolean mask (voiced stretches, frames with a face, gaps)."""

from __future__ import annotations

import numpy as np

__all__ = ["runs"]


def runs(mask) -> tuple[np.ndarray, np.ndarray]:
    """Start and end (exclusive) indices of the runs of True in a 1-D bool array.

    Examples
    --------
    >>> s, e = runs(np.array([0, 1, 1, 0, 1], bool))
    >>> s.tolist(), e.tolist()
    ([1, 4], [3, 5])
    """
    m = np.asarray(mask, bool).reshape(-1).astype(np.int8)
    d = np.diff(np.concatenate([[0], m, [0]]))
    return np.flatnonzero(d == 1), np.flatnonzero(d == -1)
