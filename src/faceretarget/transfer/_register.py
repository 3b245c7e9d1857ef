"""Dense correspondence: a template face registered onto a character's face surface.

Similarity alignment of the 68 landmarks (Umeyama), a thin-plate-spline warp that puts the template's
landmarks on the character's, then non-rigid ICP (Amberg, Romdhani & Vetter 2007): one affine transform
per template vertex, found by minimising

    E(X) = ||(alpha M (x) G) X||^2 + ||W (D X - U)||^2 + beta^2 ||D_L X - U_L||^2

(stiffness between neighbouring vertices' transforms, distance of each vertex to its closest compatible
point ``U`` of the character's surface, distance of the landmarks to the character's), with a decreasing
stiffness schedule; each step one sparse linear solve (scipy.sparse).
"""

from __future__ import annotations

import numpy as np

from ._geometry import closest_points, umeyama, vertex_normals

__all__ = ["register_template", "INNER"]

#: Landmarks used for the similarity and the warp: all but the jaw line, whose convention differs
#: between a 3D template (the jaw bone) and a silhouette seen on a render.
INNER = np.arange(17, 68)


def _edges(T: np.ndarray) -> np.ndarray:
    e = np.concatenate([T[:, [0, 1]], T[:, [1, 2]], T[:, [2, 0]]])
    e.sort(axis=1)
    return np.unique(e, axis=0)


def register_template(tv: np.ndarray, tt: np.ndarray, t_lm: tuple[np.ndarray, np.ndarray], cv: np.ndarray,
                      ct: np.ndarray, c_lm: np.ndarray, *, schedule=(30.0, 10.0, 3.0, 1.0), iterations: int = 2,
                      log=None) -> tuple[np.ndarray, dict]:
    """Register the template ``(tv, tt)`` onto the character surface ``(cv, ct)``.

    Parameters
    ----------
    tv, tt : template vertices (its own frame) and triangles
    t_lm : (triangles (68, 3), bary (68, 3))
        The template's 68 landmarks as surface points.
    cv, ct : the character's face vertices (world frame, any unit) and triangles
    c_lm : (68, 3) the character's landmarks

    Returns
    -------
    registered : (N, 3) float
        The template's vertices on the character's surface (character frame).
    info : dict
        ``s, R, t`` (the similarity: template frame to the character's), ``size`` (outer eye corners'
        distance), ``landmark_error`` (mean, over ``size``), seconds.
    """
    from scipy.interpolate import RBFInterpolator
    from scipy.sparse import coo_matrix, csr_matrix, diags, kron, vstack
    from scipy.sparse.linalg import spsolve
    from scipy.spatial import cKDTree

    log = log or (lambda *_: None)
    ltri, lbar = t_lm
    t_l = np.einsum("pk,pkd->pd", lbar, tv[ltri])
    s, R, t = umeyama(t_l[INNER], c_lm[INNER])
    size = float(np.linalg.norm(c_lm[36] - c_lm[45]))
    centre = c_lm[INNER].mean(axis=0)
    # normalised frame: the character's landmarks about the origin, outer-eye-corner distance 1
    X0 = ((s * tv @ R.T + t) - centre) / size
    L = (c_lm - centre) / size
    C = (cv - centre) / size
    lm0 = np.einsum("pk,pkd->pd", lbar, X0[ltri])
    warp = RBFInterpolator(lm0[INNER], (L - lm0)[INNER], kernel="thin_plate_spline", smoothing=1e-4)
    X = X0 + warp(X0)
    n = len(X)
    E = _edges(tt)
    M = coo_matrix((np.r_[-np.ones(len(E)), np.ones(len(E))], (np.r_[np.arange(len(E)), np.arange(len(E))],
                                                                np.r_[E[:, 0], E[:, 1]])), shape=(len(E), n)).tocsr()
    G = diags([1.0, 1.0, 1.0, 1.0])
    MG = kron(M, G).tocsr()
    rows = np.repeat(np.arange(n), 4)
    cols = np.arange(4 * n)

    def dmat(P):
        return csr_matrix((np.c_[P, np.ones(n)].reshape(-1), (rows, cols)), shape=(n, 4 * n))

    lrows = np.repeat(np.arange(68), 12)
    lcols = (4 * ltri[:, :, None] + np.arange(4)[None, None, :]).reshape(-1)

    def lmat(P):
        vals = (lbar[:, :, None] * np.c_[P, np.ones(n)][ltri]).reshape(-1)
        return csr_matrix((vals, (lrows, lcols)), shape=(68, 4 * n))

    lw = np.ones(68)
    lw[:17] = 0.3                                         # the jaw line: a weaker pull (different convention)
    tree = cKDTree(C[ct].mean(axis=1))
    cn_tri = np.cross(C[ct[:, 1]] - C[ct[:, 0]], C[ct[:, 2]] - C[ct[:, 0]])
    cn_tri /= np.maximum(np.linalg.norm(cn_tri, axis=1, keepdims=True), 1e-30)
    # the character surface's open boundary: a template vertex whose closest point lies on it is not pulled
    ce = np.concatenate([ct[:, [0, 1]], ct[:, [1, 2]], ct[:, [2, 0]]])
    ce.sort(axis=1)
    ue, cnt = np.unique(ce, axis=0, return_counts=True)
    on_border = np.zeros(len(C), bool)
    on_border[ue[cnt == 1].ravel()] = True
    D0 = dmat(X)
    Xs = np.zeros((4 * n, 3))
    Xs[0::4], Xs[1::4], Xs[2::4] = np.eye(3)[0], np.eye(3)[1], np.eye(3)[2]
    beta0 = 3.0
    for alpha in schedule:
        beta = beta0 * (alpha / schedule[0]) ** 0.5
        for _ in range(iterations):
            P = D0 @ Xs
            nrm = vertex_normals(P, tt)
            tri, bar, dist = closest_points(C, ct, P, k=6, normals=cn_tri, point_normals=nrm, min_cos=0.5, tree=tree)
            U = np.einsum("nk,nkd->nd", bar, C[ct[tri]])
            w = (dist < 0.15) & ((cn_tri[tri] * nrm).sum(1) > 0.5)
            w &= ~(on_border[ct[tri]].any(axis=1) & (bar.min(axis=1) < 1e-6))
            W = diags(w.astype(float))
            A = vstack([alpha * MG, W @ D0, beta * diags(lw) @ lmat(X)]).tocsr()
            B = np.vstack([np.zeros((MG.shape[0], 3)), w[:, None] * U, beta * lw[:, None] * L])
            Xs = spsolve((A.T @ A).tocsc(), A.T @ B)
            Xs = np.asarray(Xs).reshape(4 * n, 3)
        log(f"non-rigid ICP: stiffness {alpha:g}, {int(w.sum())} of {n} template vertices on the surface, "
            f"mean distance {float(dist[w].mean()) * size * 1000:.2f} mm")
    P = D0 @ Xs
    lm_err = float(np.linalg.norm(np.einsum("pk,pkd->pd", lbar, P[ltri]) - L, axis=1)[INNER].mean())
    return P * size + centre, {"s": s, "R": R, "t": t, "size": size, "landmark_error": lm_err}
