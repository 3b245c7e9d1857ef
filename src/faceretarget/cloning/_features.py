"""Pyun et al. Sec. 3: feature points, displacement vectors and the PCA parameter space.

A key-model (or an input frame) is described by the displacements of a set of *feature points*
(vertices) from the neutral face, concatenated into one vector ``x`` of length ``3P``.  The key-models'
vectors are analysed by PCA; an expression's *parameter vector* is its projection onto the principal
axes whose eigenvalue is at least ``eig_threshold`` times the largest one (default ``1e-6``: every
direction the key-models really span is kept, numerical null directions are dropped).
"""

from __future__ import annotations

import numpy as np

from ..base import Model

__all__ = ["feature_vectors", "FeaturePCA"]


def feature_vectors(vertices: np.ndarray, neutral: np.ndarray, idx: np.ndarray | None) -> np.ndarray:
    """Displacement vectors of the feature points.

    Parameters
    ----------
    vertices : (T, V, 3) float
        Full meshes; with ``idx=None`` the rows are already the feature points ``(T, P, 3)``.
    neutral : (V, 3) or (P, 3) float
        Rest positions matching ``vertices``.
    idx : (P,) int or None

    Returns
    -------
    (T, 3P) float
    """
    v = np.asarray(vertices, dtype=np.float64)
    if idx is None or (len(idx) == v.shape[1] == len(neutral) and idx[0] == 0 and np.all(np.diff(idx) == 1)):
        return (v - neutral).reshape(len(v), -1)
    return (v[:, idx] - neutral[idx]).reshape(len(v), -1)


class FeaturePCA(Model):
    """PCA of key-model feature vectors (Pyun Sec. 3).

    Parameters
    ----------
    eig_threshold : float
        Keep principal axes whose eigenvalue is at least this fraction of the largest.
    max_components : int, optional

    Attributes
    ----------
    mean_ : (3P,) float
    components_ : (d, 3P) float
        Orthonormal principal axes, rows.
    eigenvalues_ : (d,) float
    """

    def __init__(self, eig_threshold: float = 1e-6, max_components: int | None = None):
        self.eig_threshold = eig_threshold
        self.max_components = max_components

    def fit(self, X: np.ndarray) -> FeaturePCA:
        X = np.asarray(X, dtype=np.float64)
        self.mean_ = X.mean(axis=0)
        _, s, vt = np.linalg.svd(X - self.mean_, full_matrices=False)
        ev = s**2 / max(len(X) - 1, 1)
        keep = ev >= self.eig_threshold * ev[0] if ev.size and ev[0] > 0 else np.zeros(0, bool)
        if self.max_components is not None:
            keep[self.max_components:] = False
        self.components_ = vt[keep]
        self.eigenvalues_ = ev[keep]
        self.all_eigenvalues_ = ev
        return self

    @property
    def n_components(self) -> int:
        return int(self.components_.shape[0])

    def transform(self, X: np.ndarray) -> np.ndarray:
        """``(T, 3P)`` feature vectors -> ``(T, d)`` parameter vectors."""
        self._check_fitted()
        return (np.asarray(X, dtype=np.float64) - self.mean_) @ self.components_.T
