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


def _closest_on_triangles(P: np.ndarray, A: np.ndarray, B: np.ndarray, C: np.ndarray) -> np.ndarray:
    """Barycentric coordinates ``(n, 3)`` of the point of each triangle ``A B C`` nearest ``P`` (vectorised
    Ericson, Real-Time Collision Detection 5.1.5)."""
    ab, ac, ap = B - A, C - A, P - A
    d1, d2 = (ab * ap).sum(1), (ac * ap).sum(1)
    bp = P - B
    d3, d4 = (ab * bp).sum(1), (ac * bp).sum(1)
    cp = P - C
    d5, d6 = (ab * cp).sum(1), (ac * cp).sum(1)
    va = d3 * d6 - d5 * d4
    vb = d5 * d2 - d1 * d6
    vc = d1 * d4 - d3 * d2
    den = va + vb + vc
    den = np.where(np.abs(den) < 1e-30, 1e-30, den)
    v, w = vb / den, vc / den
    out = np.stack([1 - v - w, v, w], axis=1)
    eps = 1e-30

    def put(mask, val):
        out[mask] = val[mask] if val.ndim == 2 else val

    e_bc = (va <= 0) & ((d4 - d3) >= 0) & ((d5 - d6) >= 0)
    t = (d4 - d3) / np.maximum((d4 - d3) + (d5 - d6), eps)
    put(e_bc, np.stack([0 * t, 1 - t, t], 1))
    e_ac = (vb <= 0) & (d2 >= 0) & (d6 <= 0)
    t = d2 / np.where(np.abs(d2 - d6) < eps, eps, d2 - d6)
    put(e_ac, np.stack([1 - t, 0 * t, t], 1))
    e_ab = (vc <= 0) & (d1 >= 0) & (d3 <= 0)
    t = d1 / np.where(np.abs(d1 - d3) < eps, eps, d1 - d3)
    put(e_ab, np.stack([1 - t, t, 0 * t], 1))
    put((d6 >= 0) & (d5 <= d6), np.array([0.0, 0.0, 1.0]))
    put((d3 >= 0) & (d4 <= d3), np.array([0.0, 1.0, 0.0]))
    put((d1 <= 0) & (d2 <= 0), np.array([1.0, 0.0, 0.0]))
    return out


def closest_points(V: np.ndarray, T: np.ndarray, P: np.ndarray, *, k: int = 8, normals: np.ndarray | None = None,
                   point_normals: np.ndarray | None = None, min_cos: float = 0.3,
                   tree=None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Closest point of the surface ``(V, T)`` to each of ``P``: among the ``k`` triangles whose centroids
    are nearest, the nearest point; with ``normals`` (per triangle of ``T``) and ``point_normals``, a
    triangle facing away (cosine below ``min_cos``) is taken only when no candidate faces the same way.

    Returns
    -------
    tri : (n,) int
        Index into ``T``.
    bary : (n, 3) float
    dist : (n,) float
    """
    from scipy.spatial import cKDTree

    if tree is None:
        tree = cKDTree(V[T].mean(axis=1))
    k = min(k, len(T))
    _, cand = tree.query(P, k=k)
    cand = cand.reshape(len(P), k)
    best_d = np.full(len(P), np.inf)
    best_t = np.zeros(len(P), np.int64)
    best_b = np.zeros((len(P), 3))
    for j in range(k):
        t = cand[:, j]
        tv = T[t]
        b = _closest_on_triangles(P, V[tv[:, 0]], V[tv[:, 1]], V[tv[:, 2]])
        q = np.einsum("nk,nkd->nd", b, V[tv])
        d = np.linalg.norm(q - P, axis=1)
        if normals is not None and point_normals is not None:
            bad = (normals[t] * point_normals).sum(1) < min_cos
            d = d + bad * 1e3 * (1.0 + d)
        better = d < best_d
        best_d[better], best_t[better], best_b[better] = d[better], t[better], b[better]
    q = np.einsum("nk,nkd->nd", best_b, V[T[best_t]])
    return best_t, best_b, np.linalg.norm(q - P, axis=1)


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
