"""Geometry the transfer needs: similarity alignment, closest points on triangles, normals, the
per-triangle gradient operator."""

from __future__ import annotations

import numpy as np

__all__ = ["umeyama", "closest_points", "vertex_normals", "gradient_operator", "triangle_areas"]


def umeyama(src: np.ndarray, dst: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
    """Similarity ``(s, R, t)`` with ``s R src + t`` closest to ``dst`` in least squares (Umeyama 1991)."""
    ms, md = src.mean(axis=0), dst.mean(axis=0)
    a, b = src - ms, dst - md
    U, S, Vt = np.linalg.svd(b.T @ a / len(src))
    D = np.eye(3)
    if np.linalg.det(U) * np.linalg.det(Vt) < 0:
        D[2, 2] = -1.0
    R = U @ D @ Vt
    var = (a * a).sum() / len(src)
    s = float(np.trace(np.diag(S) @ D) / var)
    return s, R, md - s * R @ ms


def triangle_areas(V: np.ndarray, T: np.ndarray) -> np.ndarray:
    return 0.5 * np.linalg.norm(np.cross(V[T[:, 1]] - V[T[:, 0]], V[T[:, 2]] - V[T[:, 0]]), axis=1)


def vertex_normals(V: np.ndarray, T: np.ndarray) -> np.ndarray:
    """Area-weighted unit vertex normals."""
    fn = np.cross(V[T[:, 1]] - V[T[:, 0]], V[T[:, 2]] - V[T[:, 0]])
    n = np.zeros_like(V, dtype=np.float64)
    for k in range(3):
        np.add.at(n, T[:, k], fn)
    return n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-30)


def closest_points(V: np.ndarray, T: np.ndarray, P: np.ndarray, *, point_normals: np.ndarray | None = None,
                   min_cos: float = 0.3) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Closest point of the surface ``(V, T)`` to each of ``P`` (:func:`faceretarget.cloning.closest_points_on_mesh`,
    exact); with ``point_normals``, only triangles facing the same way (cosine at least ``min_cos``) unless none
    near faces that way.

    Returns
    -------
    tri : (n,) int
        Index into ``T``.
    bary : (n, 3) float
    dist : (n,) float
    """
    from ..cloning import closest_points_on_mesh

    return closest_points_on_mesh(P, V, T, point_normals=point_normals, min_cos=min_cos)


def gradient_operator(V: np.ndarray, T: np.ndarray):
    """Sparse ``(3F, n)`` operator: row ``3t + c`` gives component ``c`` of the gradient on triangle ``t``
    of a piecewise-linear function given at the vertices."""
    from scipy.sparse import csr_matrix

    p0, p1, p2 = V[T[:, 0]], V[T[:, 1]], V[T[:, 2]]
    n = np.cross(p1 - p0, p2 - p0)
    a2 = np.linalg.norm(n, axis=1)
    a2 = np.where(a2 < 1e-30, 1e-30, a2)
    un = n / a2[:, None]
    grads = [np.cross(un, p2 - p1), np.cross(un, p0 - p2), np.cross(un, p1 - p0)]   # (F, 3) each, times 1/(2A)
    F = len(T)
    rows, cols, vals = [], [], []
    for i in range(3):
        g = grads[i] / a2[:, None]
        for c in range(3):
            rows.append(3 * np.arange(F) + c)
            cols.append(T[:, i])
            vals.append(g[:, c])
    return csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(3 * F, len(V)))
