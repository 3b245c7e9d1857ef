"""Take-adaptive denoising of feature trajectories: a take is a time series.

Capture noise (optical markers, video landmarks) is independent from frame to frame while facial
motion is not.  Per-frame least squares amplifies that noise through the weakly observed key-model
directions; smoothing over time removes it, but how much to smooth depends on the noise level and
on each component's own signal.  Both are estimated from the take itself, so nothing is tuned per
data set:

1. the noise standard deviation ``sigma`` from the highest quarter of the DCT spectrum of every
   feature coordinate (median absolute value / 0.6745: white noise is spread evenly over frequencies
   while facial motion lives at the low end).  Noise is only declared when the spectrum has really
   flattened into a floor, i.e. the top quarter is at least ``flatness`` (0.9) times as strong as the
   quarter below it; a clean take, whose spectrum is still falling there, is left untouched;
2. the trajectories are rotated into an orthonormal basis estimated from the take (the noise stays
   white under a rotation), and each component gets a Whittaker smoother ``(I + lambda D'D) z = y``
   (second differences), solved exactly in the DCT domain, with ``lambda`` chosen per component by
   Stein's unbiased risk estimate (SURE) for the known ``sigma``.  A component with no signal above
   the noise is smoothed flat; a clean take (``sigma = 0``) is left exactly as it is;
3. which basis?  The take's principal axes separate the strong components well, but where the
   signal is weaker than the noise (most key-model directions seen through 68 landmarks) the
   sample eigenvectors are nearly random, and the error that causes is a variance term.  So the
   smoothing is done in four equally defensible bases, all estimated from the take, and the results
   are averaged (``basis="ensemble"``, the default): (a) the take's principal axes; (b) the
   principal axes after one shared SURE smoother for all channels; (c) the eigenvectors of the
   lag-1 autocovariance (white noise has none); (d) the principal axes clearly above the noise
   (eigenvalue > ``sigma^2 (1 + sqrt(C/T))^2``, the edge of the noise's Marchenko-Pastur bulk)
   completed by the input's own coordinate axes (for key-span coordinates: the key-model SVD axes
   in singular-value order).  ``basis="pca"`` uses (a) alone.

Frames that are not evenly spaced (dropped frames) are resampled to an even grid first and back
afterwards.

Long takes are denoised in overlapping windows (``chunk`` frames, ``overlap`` shared with the next
window, cross-faded linearly), each with the noise level estimated once from the whole take, so
memory stays bounded and time grows linearly with the take's length; a take shorter than one window
is denoised in one piece.
"""

from __future__ import annotations

import numpy as np
from scipy.fft import dct, idct

from ..timebase import even_grid

__all__ = ["estimate_noise_sigma", "sure_whittaker", "denoise_take", "CHUNK", "OVERLAP"]

#: Frames denoised at once in a long take, and the frames two windows share.
CHUNK = 16384
OVERLAP = 1024

_LAMBDAS = np.concatenate([[0.0], np.logspace(-4, 12, 65)])


def estimate_noise_sigma(Y: np.ndarray, flatness: float = 0.9) -> float:
    """White-noise standard deviation of the columns of ``Y`` ``(T, C)``, or 0 when no noise floor shows.

    The median absolute DCT coefficient of the top quarter of frequencies (/ 0.6745) estimates the
    noise; it is trusted only when the spectrum is flat there (top quarter >= ``flatness`` x the
    quarter below), which white noise is and facial motion is not.
    """
    Y = np.asarray(Y, dtype=np.float64)
    T = len(Y)
    if T < 16:
        return 0.0
    if Y.shape[1] > 4096:   # a median needs no more columns than this: take an even subset
        Y = Y[:, np.linspace(0, Y.shape[1] - 1, 4096).astype(np.int64)]
    C = np.abs(dct(Y - Y.mean(0), type=2, norm="ortho", axis=0))
    top = float(np.median(C[(3 * T) // 4:]))
    mid = float(np.median(C[T // 2:(3 * T) // 4]))
    if mid <= 0 or top < flatness * mid:
        return 0.0
    return top / 0.6745


def sure_whittaker(Y: np.ndarray, sigma: float, order: int = 2) -> tuple[np.ndarray, np.ndarray]:
    """Whittaker-smooth every column of ``Y`` ``(T, C)`` with a SURE-chosen strength per column.

    Returns the smoothed ``(T, C)`` array and the chosen ``lambda`` per column.
    """
    Y = np.asarray(Y, dtype=np.float64)
    T = len(Y)
    if T < 8 or sigma <= 0:
        return Y.copy(), np.zeros(Y.shape[1])
    C = dct(Y, type=2, norm="ortho", axis=0)
    eig = (2.0 - 2.0 * np.cos(np.pi * np.arange(T) / T)) ** order     # eigenvalues of D'D (DCT basis)
    G = 1.0 / (1.0 + _LAMBDAS[:, None] * eig[None, :])                   # (L, T) gains
    risk = ((1.0 - G) ** 2) @ (C**2) + 2.0 * sigma**2 * G.sum(axis=1)[:, None]   # (L, C)
    best = np.argmin(risk, axis=0)
    Z = idct(C * G[best].T, type=2, norm="ortho", axis=0)
    return Z, _LAMBDAS[best]




def _common_smoothed(Y: np.ndarray, sigma: float) -> np.ndarray:
    """DCT coefficients of ``Y`` smoothed with one SURE-chosen Whittaker lambda for all columns."""
    T, p = Y.shape
    D = dct(Y, type=2, norm="ortho", axis=0)
    eig = (2.0 - 2.0 * np.cos(np.pi * np.arange(T) / T)) ** 2
    G = 1.0 / (1.0 + _LAMBDAS[:, None] * eig[None, :])
    risk = ((1.0 - G) ** 2) @ (D**2).sum(axis=1) + 2.0 * sigma**2 * p * G.sum(axis=1)
    return D * G[int(np.argmin(risk))][:, None]


def _bases(Yc: np.ndarray, sigma: float, kind: str) -> list[np.ndarray]:
    """Orthonormal ``(C, C)`` bases (columns) estimated from the centred take ``Yc``."""
    T, p = Yc.shape
    ev, E = np.linalg.eigh(Yc.T @ Yc / T)
    ev, E = ev[::-1], E[:, ::-1]
    out = [E]
    if kind == "pca":
        return out
    Ds = _common_smoothed(Yc, sigma)
    out.append(np.linalg.eigh(Ds.T @ Ds)[1])
    G1 = Yc[1:].T @ Yc[:-1]
    out.append(np.linalg.eigh(G1 + G1.T)[1])
    k = int((ev > sigma**2 * (1.0 + np.sqrt(p / T)) ** 2).sum())
    if 0 < k < p:
        Et = E[:, :k]
        Q, _ = np.linalg.qr(np.eye(p) - Et @ Et.T)     # input axes in order, made orthogonal to Et
        out.append(np.hstack([Et, Q[:, : p - k]]))
    return out


def _denoise_window(Y: np.ndarray, times: np.ndarray | None, sigma: float | None,
                    basis: str) -> tuple[np.ndarray, float]:
    """One window of :func:`denoise_take`."""
    if len(Y) < 8:
        return Y.copy(), 0.0
    grid, resampled = (times, False) if times is None else even_grid(np.asarray(times, dtype=np.float64))
    Yg = _interp_columns(grid, times, Y) if resampled else Y
    if sigma is None:
        sigma = estimate_noise_sigma(Yg)
    if sigma <= 0:
        return Y.copy(), 0.0
    mu = Yg.mean(axis=0)
    Yc = Yg - mu
    bases = _bases(Yc, sigma, basis)
    out = sum(sure_whittaker(Yc @ E, sigma)[0] @ E.T for E in bases) / len(bases) + mu
    if resampled:
        out = _interp_columns(times, grid, out)
    return out, float(sigma)


def denoise_take(Y: np.ndarray, times: np.ndarray | None = None, sigma: float | None = None,
                 basis: str = "ensemble", *, chunk: int = CHUNK, overlap: int = OVERLAP) -> tuple[np.ndarray, float]:
    """Denoise trajectories ``Y`` ``(T, C)``; returns ``(Y_denoised, sigma_used)``.

    Parameters
    ----------
    Y : (T, C) float
        One row per frame (feature displacements or their coordinates in the key-model basis,
        columns ordered by importance).
    times : (T,) float, optional
        Frame times; uneven spacing is resampled to an even grid and back.
    sigma : float, optional
        Noise standard deviation in ``Y``'s units; estimated from the take when omitted, ``0``
        disables denoising.
    basis : {"ensemble", "pca"}
        Smooth in four bases estimated from the take and average (default), or in the take's
        principal axes only.
    chunk, overlap : int
        Window length and overlap (frames) for takes longer than ``chunk`` (module docstring).
    """
    Y = np.asarray(Y, dtype=np.float64)
    T = len(Y)
    if T <= chunk:
        return _denoise_window(Y, times, sigma, basis)
    if not 0 < overlap < chunk // 2:
        raise ValueError(f"overlap must be in (0, chunk / 2), got {overlap} for chunk {chunk}")
    t = None if times is None else np.asarray(times, dtype=np.float64)
    if sigma is None:
        grid = Y if t is None else _denoise_grid(Y, t)
        sigma = estimate_noise_sigma(grid)
    if sigma <= 0:
        return Y.copy(), 0.0
    out = np.zeros_like(Y)
    weight = np.zeros(T)
    step = chunk - overlap
    starts = list(range(0, T - overlap, step))
    for a in starts:
        b = min(a + chunk, T)
        piece, _ = _denoise_window(Y[a:b], None if t is None else t[a:b], sigma, basis)
        w = np.ones(b - a)
        if a > 0:                                       # fade in over the overlap with the previous window
            w[:overlap] = (np.arange(overlap) + 0.5) / overlap
        if b < T:                                       # fade out over the overlap with the next one
            w[-overlap:] = np.minimum(w[-overlap:], (overlap - 0.5 - np.arange(overlap)) / overlap)
        out[a:b] += w[:, None] * piece
        weight[a:b] += w
    return out / weight[:, None], float(sigma)


def _denoise_grid(Y: np.ndarray, times: np.ndarray) -> np.ndarray:
    """``Y`` on an even grid (for the noise estimate of an unevenly sampled take)."""
    grid, resampled = even_grid(times)
    return _interp_columns(grid, times, Y) if resampled else Y


def _interp_columns(t_new: np.ndarray, t: np.ndarray, Y: np.ndarray) -> np.ndarray:
    """Every column of ``Y`` (sampled at ``t``) linearly interpolated at ``t_new``."""
    return np.stack([np.interp(t_new, t, Y[:, j]) for j in range(Y.shape[1])], axis=1)
