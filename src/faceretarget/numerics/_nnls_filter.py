"""Low-pass filtering of keyshape weight curves (after :func:`~._nnls_solve.solve_nnls`).

:func:`temporal_filter` smooths weight curves afterwards with an adjustable level (cutoff
frequency :func:`filter_cutoff_hz`) and :func:`extremes_removed` reports how much of the curves'
extremes that costs.
"""

from __future__ import annotations

import numpy as np
from scipy.fft import dct, idct

from ..errors import InvalidDataError
from ._nnls_checks import _as_float

__all__ = ["temporal_filter", "extremes_removed", "filter_cutoff_hz"]


def filter_cutoff_hz(level: float) -> float:
    """Cutoff frequency (-3 dB) of :func:`temporal_filter` at ``level``: ``10 Hz / level``.

    Level 1 keeps motion up to 10 Hz (removes frame-to-frame jitter, keeps speech articulation),
    2 up to 5 Hz, 5 up to 2 Hz, 10 up to 1 Hz (only slow expression changes); 0 is no filtering
    (``inf``).
    """
    level = _as_float("level", level)
    return np.inf if level == 0 else 10.0 / level


def temporal_filter(W: np.ndarray, level: float, fps: float) -> np.ndarray:
    """Zero-phase Gaussian low-pass filtering of weight curves, with an adjustable level.

    The filter is the heat kernel of the frame sequence, ``exp(-tau L)`` with ``L`` the path
    Laplacian (reflecting ends), applied exactly in the DCT domain: a discrete Gaussian of variance
    ``2 tau`` frames^2, frequency response ``exp(-tau (2 - 2 cos w))`` ~ ``exp(-tau w^2)``.
    ``tau = ln(2) / (2 w_c^2)`` puts the -3 dB point of that Gaussian at ``w_c = 2 pi f_c / fps``,
    ``f_c`` = :func:`filter_cutoff_hz` ``(level)``; ``tau`` grows continuously from 0 with the
    level.  Its kernel is
    non-negative and sums to one, so filtered weights stay within the range of the input (bounds
    such as ``0 <= w <= 1`` are kept) and every curve's peak-to-peak shrinks monotonically as the
    level grows.

    Parameters
    ----------
    W : (T, N) float
        Weight curves, one row per frame.
    level : float
        0 for none; larger is smoother (see :func:`filter_cutoff_hz`).
    fps : float
        Frame rate of ``W``.

    Returns
    -------
    (T, N) float
    """
    W = np.asarray(W, dtype=np.float64)
    level = _as_float("level", level)
    fps = float(fps)
    if not (np.isfinite(fps) and fps > 0):
        raise InvalidDataError(f"fps must be > 0, got {fps}")
    if W.ndim != 2:
        raise InvalidDataError(f"weights must be (T, N), got shape {W.shape}")
    if not np.isfinite(W).all():
        frame = int(np.flatnonzero(~np.isfinite(W).all(axis=1))[0])
        raise InvalidDataError(f"frame {frame} has NaN or infinite weights")
    T = len(W)
    if level == 0 or T < 2:
        return W.copy()
    wc = 2.0 * np.pi * filter_cutoff_hz(level) / fps
    tau = 0.5 * np.log(2.0) / wc**2
    gain = np.exp(-tau * (2.0 - 2.0 * np.cos(np.pi * np.arange(T) / T)))
    out = idct(dct(W, type=2, norm="ortho", axis=0) * gain[:, None], type=2, norm="ortho", axis=0)
    return np.clip(out, W.min(axis=0), W.max(axis=0))          # rounding only


def extremes_removed(W: np.ndarray, Wf: np.ndarray) -> float:
    """How much of the weight curves' extremes filtering removed, in percent.

    The mean over curves (columns) that move at all of ``100 (1 - ptp(Wf) / ptp(W))``: the share of
    each curve's peak-to-peak range lost.  0 means untouched, 100 flattened.

    Parameters
    ----------
    W, Wf : (T, N) float
        Curves before and after filtering.
    """
    W = np.asarray(W, dtype=np.float64)
    Wf = np.asarray(Wf, dtype=np.float64)
    if W.shape != Wf.shape or W.ndim != 2:
        raise InvalidDataError(f"weights before {W.shape} and after {Wf.shape} filtering must be "
                               "equal (T, N)")
    r0 = np.ptp(W, axis=0)
    moving = r0 > 0
    if not moving.any():
        return 0.0
    return float(np.mean(100.0 * (1.0 - np.ptp(Wf, axis=0)[moving] / r0[moving])))
