"""Synthetic keyshape problems for the NNLS tests and ``bench/nnls.py`` (one generator for both).

``keyshape_problem``: keyshapes like a face's (smooth, localised marker displacements, several keys
per facial region moving in similar directions, so correlated columns) and a take of smooth,
often-zero weight curves plus capture noise.  ``rom_problem``: keyshapes chosen by PCA extrema
among the frames of a synthetic range-of-motion take (as P1's ``rom-K`` sets) and frames of another
take of the same face: strongly correlated keys, sparse weights, linearly dependent keys when
``N > n_basis`` (like P1's ``combined84``).
"""

from __future__ import annotations

import numpy as np

__all__ = ["keyshape_problem", "rom_problem"]


def keyshape_problem(D: int, N: int, T: int, seed: int, noise: float = 0.02) -> tuple[np.ndarray, np.ndarray]:
    """Keyshapes ``K`` ``(D, N)`` (unit columns) and a take ``F`` ``(T, D)``."""
    rng = np.random.default_rng(seed)
    P = D // 3
    pts = rng.uniform(-1, 1, (P, 3))
    regions = max(3, N // 5)
    centre = pts[rng.choice(P, regions, replace=False)]
    direction = rng.standard_normal((regions, 3))
    K = np.zeros((D, N))
    for j in range(N):                          # one key at a time: the draws' order fixes the problem
        r = j % regions
        c = centre[r] + 0.1 * rng.standard_normal(3)
        d = direction[r] + 0.25 * rng.standard_normal(3)
        bump = np.exp(-np.sum((pts - c) ** 2, axis=1) / (2 * rng.uniform(0.3, 0.8) ** 2))
        K[:, j] = (bump[:, None] * (d + 0.05 * rng.standard_normal((P, 3)))).ravel()
    K /= np.linalg.norm(K, axis=0)
    t = np.arange(T) / 60.0
    phase = 2 * np.pi * rng.uniform(0.1, 2, (N, 1)) * t + rng.uniform(0, 6, (N, 1))
    W = np.maximum(0.0, np.sin(phase) - 0.3).T
    return K, W @ K.T + noise * rng.standard_normal((T, D))


def rom_problem(D: int, N: int, T: int, seed: int, n_basis: int = 51, noise: float = 0.002,
                rom_frames: int = 3000) -> tuple[np.ndarray, np.ndarray]:
    """Keyshapes ``K`` ``(D, N)`` chosen among ``rom_frames`` frames of a range-of-motion take, and a take."""
    from ..numerics import pca_extrema

    rng = np.random.default_rng(seed)
    basis, _ = keyshape_problem(D, n_basis, 2, seed)           # the face's own blendshapes

    def take(n):
        t = np.arange(n) / 60.0
        f, ph = rng.uniform(0.05, 0.8, (n_basis, 1)), rng.uniform(0, 6, (n_basis, 1))
        cut = rng.uniform(0.2, 0.8, (n_basis, 1))
        return np.maximum(0.0, np.sin(2 * np.pi * f * t + ph) - cut).T @ basis.T

    rom = take(rom_frames)
    return rom[pca_extrema(rom, N)].T, take(T) + noise * rng.standard_normal((T, D))
