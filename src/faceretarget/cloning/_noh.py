"""Expression cloning in the manner of Noh and Neumann (SIGGRAPH 2001): the peer baseline.

Noh and Neumann transfer the *motion vectors* of a source animation onto a target face of another
shape and topology, with no key-models at all, in two steps.  This module implements a faithful,
practical version of both; Pyun et al. (2003) compare their example-based method against it.

1. **Dense correspondence.**  A radial-basis-function warp fitted on corresponding feature points
   (here the 68 Multi-PIE landmarks; :class:`scipy.interpolate.RBFInterpolator`, thin-plate spline
   kernel plus a degree-1 polynomial, optional smoothing) maps the source neutral into the target's
   space, which also absorbs a difference of units (centimetres to metres).  Each *target* vertex then
   gets the closest point on the warped source triangle mesh (exact closest point on triangles, with
   barycentric coordinates; polygons are fanned into triangles), among triangles whose normal is
   within ``max_normal_angle`` of the target vertex normal, so the inner upper lip never takes its
   motion from the lower lip facing it.  The barycentric interpolation is kept as a sparse
   ``(V_target, V_source)`` matrix ``P`` with three non-zeros a row.  (Noh and Neumann refine the
   correspondence with a cylindrical projection; the closest point serves the same purpose.)
2. **Motion transfer.**  A source frame's displacement from the source neutral is interpolated at
   every target vertex's corresponding point and mapped into target space by a per-vertex ``3 x 3``
   matrix ``M_i``: ``B(t) = B0 + M (P (A(t) - A0))``, one sparse product and one batched ``3 x 3``
   product for a whole take.  Noh and Neumann adjust each motion vector's *direction* by the rotation
   between local frames of the two surfaces and its *magnitude* by the ratio of local bounding boxes.
   Here the local frames come from ``J_i``, the Jacobian of the RBF warp at the correspondence
   (central finite differences of the warp):

   * default (``local_scale=False``): ``M_i = g Rot(J_i)``, the rotation factor of ``J_i``'s polar
     decomposition (how the warp turns the surface there) times the global scale ``g`` of the
     landmark sets (cube root of the determinant of their least-squares affine map);
   * ``local_scale=True``: ``M_i = S_i J_i``, the full Jacobian (also the warp's local stretch), times a
     local size ratio ``S_i`` (Noh and Neumann's bounding boxes): the target vertices within a ball
     around target vertex ``i`` and their correspondences on the warped source surface are compared
     along the two principal tangent directions of the target neighbourhood by their root-mean-square
     spread (a bounding box one outlying vertex cannot inflate); the motion's tangential components
     are scaled by the target-to-source ratio, clipped to ``[1/max_scale, max_scale]``;
   * ``local_rotation=True`` adds ``R_i``, the smallest rotation taking the warped source surface's
     normal at the correspondence onto the target vertex normal (left out where they differ by more
     than ``max_angle`` degrees): ``M_i = S_i R_i J_i``.

   Measured on the paired ICT-FaceKit and ARKit rigs (protocol P1, Live Link Face takes), the default
   gets the least of the motion wrong: the 68-landmark warp's local stretch is large where landmarks
   crowd (a closed mouth's inner lip landmarks nearly coincide on one face and not on the other) and
   amplified lip motion several times over, and the normal rotation and local size ratios did not
   help either.

Noh and Neumann's further heuristics (automatic feature-point search, lip-contact handling) are left
out: the landmarks are given.  Target vertices beyond the source's extent (ICT-FaceKit's forehead and
neck seen from the smaller ARKit face) take the motion of the nearest source boundary.  When source and
target are the same mesh with the same landmarks, the warp is the identity (a degree-1 polynomial fits
the data exactly, so the RBF part vanishes), every vertex corresponds to itself, ``M_i = I``, and
cloning reproduces the source animation to rounding.

Example (``ict`` and ``arkit`` are :class:`~faceretarget.Rig` objects, ``ict_frames`` a vertex take)::

    cloner = NohNeumannCloner().fit(ict.neutral, arkit.neutral, ict.landmarks, arkit.landmarks)
    arkit_frames = cloner.transform(ict_frames)   # (T, 9409, 3) cm -> (T, 1220, 3) m
"""

from __future__ import annotations

import numpy as np
from scipy.interpolate import RBFInterpolator
from scipy.sparse import csr_matrix
from scipy.spatial import cKDTree

from ..base import Model
from ..errors import InvalidDataError
from ..mesh import Mesh
from ..numerics import nearest_rotation

__all__ = ["NohNeumannCloner", "closest_points_on_mesh"]

# Frames per chunk in transform() are chosen to keep an intermediate array near this many floats.
_CHUNK_ELEMENTS = 1 << 23


def _unit(v: np.ndarray) -> np.ndarray:
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    return v / np.where(n > 0, n, 1.0)


def _closest_on_triangles(p: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """Barycentric coordinates ``(n, 3)`` of the closest point to ``p`` on triangles ``abc`` (rows).

    Ericson, *Real-Time Collision Detection*, 5.1.5, vectorised: every Voronoi region is evaluated
    and the first that applies (in Ericson's order) wins.  Degenerate triangles give NaN.
    """
    ab, ac = b - a, c - a
    ap, bp, cp = p - a, p - b, p - c
    d1, d2 = np.einsum("ij,ij->i", ab, ap), np.einsum("ij,ij->i", ac, ap)
    d3, d4 = np.einsum("ij,ij->i", ab, bp), np.einsum("ij,ij->i", ac, bp)
    d5, d6 = np.einsum("ij,ij->i", ab, cp), np.einsum("ij,ij->i", ac, cp)
    vc = d1 * d4 - d3 * d2
    vb = d5 * d2 - d1 * d6
    va = d3 * d6 - d5 * d4
    with np.errstate(divide="ignore", invalid="ignore"):
        den = va + vb + vc
        v_in, w_in = vb / den, vc / den
        bary = np.stack([1.0 - v_in - w_in, v_in, w_in], axis=1)
        e_bc = (d4 - d3) / ((d4 - d3) + (d5 - d6))
        e_ac = d2 / (d2 - d6)
        e_ab = d1 / (d1 - d3)
    zero = np.zeros_like(d1)
    one = np.ones_like(d1)
    # lowest priority first; later assignments override
    cases = [
        ((va <= 0) & (d4 - d3 >= 0) & (d5 - d6 >= 0), np.stack([zero, 1 - e_bc, e_bc], 1)),
        ((vb <= 0) & (d2 >= 0) & (d6 <= 0), np.stack([1 - e_ac, zero, e_ac], 1)),
        ((d6 >= 0) & (d5 <= d6), np.stack([zero, zero, one], 1)),
        ((vc <= 0) & (d1 >= 0) & (d3 <= 0), np.stack([1 - e_ab, e_ab, zero], 1)),
        ((d3 >= 0) & (d4 <= d3), np.stack([zero, one, zero], 1)),
        ((d1 <= 0) & (d2 <= 0), np.stack([one, zero, zero], 1)),
    ]
    for mask, val in cases:
        bary = np.where(mask[:, None], val, bary)
    return bary


def closest_points_on_mesh(points: np.ndarray, vertices: np.ndarray, triangles: np.ndarray,
                           point_normals: np.ndarray | None = None, min_cos: float = 0.0,
                           ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Exact closest point on a triangle mesh for each query point, optionally normal-compatible.

    With ``point_normals``, only triangles whose unit normal ``n_f`` has ``n_f . n_p >= min_cos``
    with the query's normal count (so an upper lip never lands on the lower lip facing it); a query
    with no compatible triangle near it falls back to the unconstrained closest point.

    Candidates are the triangles whose centroid lies within ``d0 + R_t`` of the query, where ``d0``
    is an upper bound of the answer (the distance to the nearest vertex, or with normals the best of
    the nearest few compatible triangles) and ``R_t`` the triangle's largest centroid-to-corner
    distance; so the true closest triangle is always among them.

    Parameters
    ----------
    points : (Q, 3) float
    vertices : (V, 3) float
    triangles : (F, 3) int
    point_normals : (Q, 3) float, optional
        Unit normals of the queries, oriented like the triangles (counter-clockwise = outward).
    min_cos : float
        Cosine of the largest admissible angle between query normal and triangle normal.

    Every query gets an answer (a query whose bound finds no triangle, e.g. one near a vertex that is in no
    triangle, is answered over every triangle); a non-finite query is an error naming it.

    Returns
    -------
    triangle : (Q,) int
        Index of the closest triangle.
    bary : (Q, 3) float
        Barycentric coordinates of the closest point in that triangle.
    distance : (Q,) float
    """
    p = np.asarray(points, dtype=np.float64)
    v = np.asarray(vertices, dtype=np.float64)
    tri = np.asarray(triangles, dtype=np.int64)
    Q = len(p)
    corners = v[tri]  # (F, 3, 3)
    cen = corners.mean(axis=1)
    rad = np.linalg.norm(corners - cen[:, None], axis=-1).max(axis=1)
    slack = 1e-9 * (1.0 + float(np.abs(v).max()))
    fn = _unit(np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]))
    if not len(tri):
        raise InvalidDataError(f"closest_points_on_mesh: the mesh has no triangles ({len(v)} vertices)")
    bad = ~np.isfinite(p).all(axis=1)
    if bad.any():
        raise InvalidDataError(f"closest_points_on_mesh: query {int(np.flatnonzero(bad)[0])} is not finite "
                               f"({int(bad.sum())} of {Q})")
    ctree = cKDTree(cen)
    used = v[np.unique(tri)]                 # a vertex in no triangle bounds nothing: it is not on the surface
    if point_normals is None:
        unconstrained = np.ones(Q, bool)
        d0, _ = cKDTree(used).query(p)
    else:
        d0, unconstrained = _compatible_bound(p, used, corners, fn, ctree, point_normals, min_cos)
    q, t = _candidate_pairs(p, cen, rad, ctree, d0, slack)
    bary, dist = _triangle_distances(p, corners, fn, q, t, point_normals, min_cos, unconstrained)
    # per query the candidate with the smallest distance
    order = np.lexsort((dist, q))
    first = np.ones(order.size, bool)
    first[1:] = q[order][1:] != q[order][:-1]
    best = order[first]
    out_t, out_b, out_d = np.zeros(Q, np.int64), np.zeros((Q, 3)), np.full(Q, np.inf)
    out_t[q[best]], out_b[q[best]], out_d[q[best]] = t[best], bary[best], dist[best]
    miss = np.setdiff1d(np.arange(Q), q[best])
    if len(miss):      # no candidate within the bound (degenerate triangles about it): every triangle
        _all_triangles(p, corners, fn, miss, out_t, out_b, out_d)
    return out_t, out_b, out_d


def _all_triangles(p: np.ndarray, corners: np.ndarray, fn: np.ndarray, queries: np.ndarray, out_t: np.ndarray,
                   out_b: np.ndarray, out_d: np.ndarray, chunk: int = 4_000_000) -> None:
    """The closest point of each of ``queries`` over every triangle (unconstrained), in place."""
    F = len(corners)
    step = max(1, chunk // F)
    for i in range(0, len(queries), step):
        qs = queries[i:i + step]
        q = np.repeat(qs, F)
        t = np.tile(np.arange(F), len(qs))
        bary, dist = _triangle_distances(p, corners, fn, q, t, None, 0.0, np.ones(len(p), bool))
        d = dist.reshape(len(qs), F)
        k = np.argmin(np.where(np.isfinite(d), d, np.inf), axis=1)
        rows = np.arange(len(qs)) * F + k
        out_t[qs], out_b[qs], out_d[qs] = k, bary[rows], dist[rows]


def _triangle_distances(p: np.ndarray, corners: np.ndarray, fn: np.ndarray, q: np.ndarray, t: np.ndarray,
                        point_normals: np.ndarray | None, min_cos: float, unconstrained: np.ndarray
                        ) -> tuple[np.ndarray, np.ndarray]:
    """Closest point on triangle ``t[n]`` to query ``q[n]``, for pairs ``(q, t)`` of (n,) ints.

    ``p`` (Q, 3) queries, ``corners`` (F, 3, 3) triangle corners, ``fn`` (F, 3) unit normals.
    Returns barycentrics (n, 3) and distances (n,); degenerate triangles and, with
    ``point_normals`` (Q, 3), triangles not normal-compatible with a query that is not
    ``unconstrained`` (Q,) bool, get distance inf.
    """
    bary = _closest_on_triangles(p[q], corners[t, 0], corners[t, 1], corners[t, 2])
    cp = np.einsum("nk,nkj->nj", bary, corners[t])
    dist = np.linalg.norm(cp - p[q], axis=1)
    dist = np.where(np.isfinite(dist), dist, np.inf)
    if point_normals is not None:
        ok = np.einsum("nj,nj->n", fn[t], point_normals[q]) >= min_cos
        dist = np.where(ok | unconstrained[q], dist, np.inf)
    return bary, dist


def _compatible_bound(p: np.ndarray, v: np.ndarray, corners: np.ndarray, fn: np.ndarray, ctree: cKDTree,
                      point_normals: np.ndarray, min_cos: float) -> tuple[np.ndarray, np.ndarray]:
    """Upper bound (Q,) of each query's distance to a normal-compatible triangle, from the nearest
    k triangles (by centroid, ``ctree``); queries with none among them are ``unconstrained`` (Q,)
    bool and bounded by their nearest vertex of ``v`` (V, 3) instead."""
    Q = len(p)
    k = min(32, len(corners))
    _, near = ctree.query(p, k)
    near = near.reshape(Q, k)
    _, dk = _triangle_distances(p, corners, fn, np.repeat(np.arange(Q), k), near.reshape(-1),
                                point_normals, min_cos, np.zeros(Q, bool))
    d0 = dk.reshape(Q, k).min(axis=1)
    unconstrained = ~np.isfinite(d0)
    if unconstrained.any():
        d0[unconstrained] = cKDTree(v).query(p[unconstrained])[0]
    return d0, unconstrained


def _candidate_pairs(p: np.ndarray, cen: np.ndarray, rad: np.ndarray, ctree: cKDTree, d0: np.ndarray,
                     slack: float) -> tuple[np.ndarray, np.ndarray]:
    """(query, triangle) pairs of (n,) ints whose triangle may hold the closest point: centroid
    ``cen`` (F, 3) within the bound ``d0`` (Q,) plus the triangle's radius ``rad`` (F,)."""
    Q = len(p)
    lists = ctree.query_ball_point(p, d0 + rad.max() + slack)
    lens = np.fromiter((len(x) for x in lists), dtype=np.int64, count=Q)
    q = np.repeat(np.arange(Q), lens)
    t = np.fromiter((i for x in lists for i in x), dtype=np.int64, count=int(lens.sum()))
    keep = np.linalg.norm(p[q] - cen[t], axis=1) <= d0[q] + rad[t] + slack
    return q[keep], t[keep]


def _rotation_between(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``(n, 3, 3)`` smallest rotations taking unit vectors ``a`` onto ``b`` (not antiparallel)."""
    v = np.cross(a, b)
    c = np.einsum("ij,ij->i", a, b)
    K = np.zeros(v.shape[:1] + (3, 3))
    K[:, 0, 1], K[:, 0, 2], K[:, 1, 2] = -v[:, 2], v[:, 1], -v[:, 0]
    K[:, 1, 0], K[:, 2, 0], K[:, 2, 1] = v[:, 2], -v[:, 1], v[:, 0]
    return np.eye(3) + K + (K @ K) / (1.0 + c)[:, None, None]




def _oriented_normals(tgt: Mesh, W: np.ndarray, tri: np.ndarray) -> np.ndarray:
    """(Vt, 3) target vertex normals, flipped if need be to face like the warped source triangles
    (``W`` (Vs, 3) warped source vertices, ``tri`` (F, 3) source triangles)."""
    nt = tgt.vertex_normals()
    fn = np.cross(W[tri[:, 1]] - W[tri[:, 0]], W[tri[:, 2]] - W[tri[:, 0]])
    _, near = cKDTree(W[tri].mean(axis=1)).query(tgt.vertices)
    if float(np.einsum("ij,ij->", nt, fn[near])) < 0:
        nt = -nt
    return nt


def _mean_edge(mesh: Mesh, vertices: np.ndarray) -> float:
    e = mesh.edges()
    if e.size == 0:
        return 0.0
    return float(np.linalg.norm(vertices[e[:, 0]] - vertices[e[:, 1]], axis=1).mean())


class NohNeumannCloner(Model):
    """Noh and Neumann's expression cloning: RBF dense correspondence plus motion-vector transfer.

    Parameters
    ----------
    kernel : str
        :class:`scipy.interpolate.RBFInterpolator` kernel of the warp (one without a shape parameter:
        ``"thin_plate_spline"``, ``"linear"``, ``"cubic"``, ``"quintic"``); always with a degree-1
        polynomial, so an affine relation between the landmark sets is reproduced exactly.
    smoothing : float
        RBF smoothing; the source landmarks are centred and scaled to unit RMS radius first, so the
        value does not depend on the source's unit.  0 interpolates the landmarks exactly.
    local_scale : bool
        ``False``: motion turned by the local rotation of the warp and scaled by the global scale.
        ``True``: full local Jacobian of the warp times the local size ratio (see the module notes).
    local_rotation : bool
        Also rotate the motion by the smallest rotation between the warped source normal and the
        target normal.
    projection : ``"triangle"`` or ``"vertex"``
        Correspondence by the closest point on the warped source triangles (default) or by the
        nearest warped source vertex.
    max_normal_angle : float or None
        Largest angle in degrees between a target vertex normal and the source triangle it may
        correspond to; ``None`` takes the closest point regardless.
    neighbourhood : float
        Radius of the local-scale neighbourhoods in multiples of the larger mean edge length of the
        target and the warped source mesh.
    max_scale : float
        Local scale ratios are clipped to ``[1 / max_scale, max_scale]``.
    max_angle : float
        Normals differing by more than this many degrees get no local rotation.
    fd_step : float
        Finite-difference step of the Jacobian as a fraction of the source landmarks' RMS radius.

    Attributes (after :meth:`fit`)
    ------------------------------
    triangle_ : (Vt,) int
        Source triangle (of ``source_neutral.triangles()``) each target vertex corresponds to; -1 with
        ``projection="vertex"``.
    barycentric_ : (Vt, 3) float
    interpolation_ : scipy.sparse.csr_matrix (Vt, Vs)
        Barycentric interpolation of source vertex data at the correspondences.
    correspondence_ : (Vt, 3) float
        Corresponding points on the source neutral, in source space.
    distance_ : (Vt,) float
        Distance (target units) from each target vertex to the warped source surface.
    jacobian_ : (Vt, 3, 3) float
        Jacobian of the warp at each correspondence.
    global_scale_ : float
        Target size over source size, from the landmarks' least-squares affine map.
    rotation_, scale_ : (Vt, 3, 3) float
        ``R_i`` and ``S_i`` (identities when not asked for).
    transfer_ : (Vt, 3, 3) float
        ``M_i``, mapping a source displacement to a target displacement.
    source_neutral_, target_neutral_ : (Vs, 3), (Vt, 3) float
    """

    def __init__(self, kernel: str = "thin_plate_spline", smoothing: float = 0.0, local_scale: bool = False,
                 *, local_rotation: bool = False, projection: str = "triangle",
                 max_normal_angle: float | None = 90.0, neighbourhood: float = 3.0, max_scale: float = 2.0,
                 max_angle: float = 60.0, fd_step: float = 1e-3) -> None:
        self.kernel = kernel
        self.smoothing = smoothing
        self.local_scale = local_scale
        self.local_rotation = local_rotation
        self.projection = projection
        self.max_normal_angle = max_normal_angle
        self.neighbourhood = neighbourhood
        self.max_scale = max_scale
        self.max_angle = max_angle
        self.fd_step = fd_step

    # ------------------------------------------------------------------ fit
    def fit(self, source_neutral: Mesh, target_neutral: Mesh, source_landmarks, target_landmarks
            ) -> NohNeumannCloner:
        """Build the dense correspondence and the per-vertex transfer matrices.

        Parameters
        ----------
        source_neutral, target_neutral : Mesh
            The two rest faces (any topologies, any units).
        source_landmarks, target_landmarks : (P,) int
            Vertex indices of corresponding feature points (``P >= 4``, not all in one plane).

        Returns
        -------
        self
        """
        if self.projection not in ("triangle", "vertex"):
            raise InvalidDataError(f"projection must be 'triangle' or 'vertex', got {self.projection!r}")
        src, tgt = source_neutral, target_neutral
        Ps, Pt = self._landmark_points(src, tgt, source_landmarks, target_landmarks)
        Xs, Xt = src.vertices, tgt.vertices

        # 1. the warp, on normalised source coordinates so that smoothing is unit-free
        self._fit_warp(Ps, Pt)
        W = self._warp(Xs)  # warped source neutral, target space

        # 2. dense correspondence: closest point on the warped source surface
        tri = src.triangles()
        has_normals = tgt.n_faces > 0 and len(tri) > 0
        nt = _oriented_normals(tgt, W, tri) if has_normals else None
        t_idx, bary, dist, P = self._correspondence(Xt, W, tri, nt, src.n_vertices)
        self.triangle_, self.barycentric_, self.distance_, self.interpolation_ = t_idx, bary, dist, P
        self.correspondence_ = P @ Xs
        Q = P @ W  # correspondences on the warped source surface

        # 3. transfer matrices M = S R J
        J = self._jacobian(self.correspondence_)
        self.jacobian_ = J
        # global scale: of the least-squares affine map between the landmark sets
        A = np.linalg.lstsq(np.c_[Ps - self._mu, np.ones(len(Ps))], Pt, rcond=None)[0][:3]
        self.global_scale_ = float(np.cbrt(abs(np.linalg.det(A))))
        if not self.local_scale:
            J = nearest_rotation(J) * self.global_scale_
        R, S = self._local_adjustments(src, tgt, W, P, Q, nt, dist)
        self.rotation_, self.scale_ = R, S
        self.transfer_ = S @ R @ J
        self.source_neutral_ = Xs.copy()
        self.target_neutral_ = Xt.copy()
        self._after_load()
        return self

    def _landmark_points(self, src: Mesh, tgt: Mesh, source_landmarks, target_landmarks
                         ) -> tuple[np.ndarray, np.ndarray]:
        """(P, 3) source and target landmark positions, checked for the warp."""
        ls = self._landmarks(source_landmarks, src, "source")
        lt = self._landmarks(target_landmarks, tgt, "target")
        if ls.size != lt.size:
            raise InvalidDataError(f"{ls.size} source landmarks but {lt.size} target landmarks")
        Xs, Xt = src.vertices, tgt.vertices
        Ps, Pt = Xs[ls], Xt[lt]
        if ls.size < 4 or np.linalg.matrix_rank(Ps - Ps.mean(0), tol=1e-9 * np.abs(Ps).max()) < 3:
            raise InvalidDataError(
                f"the RBF warp needs at least 4 source landmarks not all in one plane, got {ls.size}"
            )
        return Ps, Pt

    def _fit_warp(self, Ps: np.ndarray, Pt: np.ndarray) -> None:
        """Fit the RBF warp from (P, 3) source to (P, 3) target landmarks, on source coordinates
        centred (``_mu``) and scaled to unit RMS radius (``_s``); stores ``_mu``, ``_s``, ``_rbf``."""
        mu = Ps.mean(axis=0)
        s = float(np.sqrt(((Ps - mu) ** 2).sum(axis=1).mean()))
        try:
            rbf = RBFInterpolator((Ps - mu) / s, Pt, kernel=self.kernel, smoothing=self.smoothing, degree=1)
        except (ValueError, np.linalg.LinAlgError) as exc:
            raise InvalidDataError(f"RBF warp could not be fitted: {exc}") from exc
        self._mu, self._s, self._rbf = mu, s, rbf

    def _correspondence(self, Xt: np.ndarray, W: np.ndarray, tri: np.ndarray, nt: np.ndarray | None,
                        Vs: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, csr_matrix]:
        """Each target vertex's corresponding point on the warped source surface.

        Parameters
        ----------
        Xt : (Vt, 3) float
            Target vertices.
        W : (Vs, 3) float
            Warped source vertices.
        tri : (F, 3) int
            Source triangles.
        nt : (Vt, 3) float or None
            Target normals oriented like the source triangles (None: no normal check).
        Vs : int
            Source vertices.

        Returns
        -------
        triangle : (Vt,) int
            Source triangle, -1 for the nearest vertex (``projection="vertex"`` or no triangles).
        bary : (Vt, 3) float
        distance : (Vt,) float
        interpolation : csr_matrix (Vt, Vs)
            Barycentric interpolation at the correspondences.
        """
        Vt = len(Xt)
        if self.projection == "triangle" and len(tri):
            check = nt is not None and self.max_normal_angle is not None
            t_idx, bary, dist = closest_points_on_mesh(
                Xt, W, tri, nt if check else None,
                np.cos(np.radians(self.max_normal_angle)) if check else 0.0)
            cols = tri[t_idx]
        else:
            dist, nearest = cKDTree(W).query(Xt)
            t_idx = np.full(Vt, -1)
            bary = np.tile([1.0, 0.0, 0.0], (Vt, 1))
            cols = np.stack([nearest, nearest, nearest], axis=1)
        P = csr_matrix((bary.reshape(-1), (np.repeat(np.arange(Vt), 3), cols.reshape(-1))), shape=(Vt, Vs))
        P.sum_duplicates()
        return t_idx, bary, dist, P

    def _local_adjustments(self, src: Mesh, tgt: Mesh, W: np.ndarray, P: csr_matrix, Q: np.ndarray,
                           nt: np.ndarray | None, dist: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``R_i`` and ``S_i`` (Vt, 3, 3): local rotation and scale (identities when not asked for).

        ``W`` (Vs, 3) warped source vertices, ``P`` (Vt, Vs) interpolation, ``Q`` (Vt, 3) the
        correspondences on the warped source, ``nt`` (Vt, 3) oriented target normals (None when the
        meshes have no faces), ``dist`` (Vt,) distances to the warped source surface.
        """
        Xt = tgt.vertices
        Vt = tgt.n_vertices
        eye = np.broadcast_to(np.eye(3), (Vt, 3, 3))
        R, S = eye.copy(), eye.copy()
        if (self.local_rotation or self.local_scale) and nt is not None:
            nw = _unit(P @ src.with_vertices(W).vertex_normals())
            if float(np.einsum("ij,ij->", nt, nw)) < 0:
                nw = -nw
            radius = self.neighbourhood * max(_mean_edge(tgt, Xt), _mean_edge(src, W))
            if self.local_rotation:
                ok = np.einsum("ij,ij->i", nt, nw) >= np.cos(np.radians(self.max_angle))
                R[ok] = _rotation_between(nw[ok], nt[ok])
            if self.local_scale:
                S = self._local_scale(Xt, Q, nt, R, radius, dist)
        return R, S

    @staticmethod
    def _landmarks(idx, mesh: Mesh, which: str) -> np.ndarray:
        a = np.asarray(idx)
        if a.ndim != 1 or not np.issubdtype(a.dtype, np.integer):
            raise InvalidDataError(f"{which} landmarks must be a 1-D array of vertex indices, got {a.dtype} {a.shape}")
        if a.size and (a.min() < 0 or a.max() >= mesh.n_vertices):
            raise InvalidDataError(f"{which} landmark index outside 0..{mesh.n_vertices - 1} ({mesh.name})")
        return a.astype(np.int64)

    def _warp(self, x: np.ndarray) -> np.ndarray:
        x = np.asarray(x, dtype=np.float64)
        return self._rbf((x - self._mu) / self._s)

    def _jacobian(self, c: np.ndarray) -> np.ndarray:
        """``(n, 3, 3)`` Jacobian of the warp at ``c`` by central differences (one warp call)."""
        h = self.fd_step * self._s
        steps = np.eye(3) * h
        pts = np.concatenate([c[None] + steps[:, None], c[None] - steps[:, None]]).reshape(-1, 3)
        f = self._warp(pts).reshape(2, 3, len(c), 3)
        # J[n, i, k] = d warp_i / d x_k
        return ((f[0] - f[1]) / (2 * h)).transpose(1, 2, 0)

    def _local_scale(self, Xt: np.ndarray, Q: np.ndarray, nt: np.ndarray, R: np.ndarray,
                     radius: float, dist: np.ndarray) -> np.ndarray:
        """``(Vt, 3, 3)`` tangential scale ``S_i``: local extents of target over warped source.

        The neighbourhood of target vertex ``i`` is the target vertices within ``radius``; their
        correspondences on the warped source surface give the source's extent of the same region
        (sampled at the same points, so the two meshes' resolutions do not matter).  Vertices (and
        neighbours) farther than ``radius`` from the source surface have no reliable counterpart
        and are left at scale 1 (left out).
        """
        Vt = len(Xt)
        near = dist <= radius
        lists = cKDTree(Xt[near]).query_ball_point(Xt, radius)
        idx = np.flatnonzero(near)
        lens = np.fromiter((len(x) for x in lists), dtype=np.int64, count=Vt)
        i = np.repeat(np.arange(Vt), lens)
        j = idx[np.fromiter((k for x in lists for k in x), dtype=np.int64, count=int(lens.sum()))]
        ot = Xt[j] - Xt[i]
        ow = np.einsum("nab,nb->na", R[i], Q[j] - Q[i])  # into the target's tangent orientation
        # project onto the target tangent plane; per-vertex 3x3 second moments
        ot -= np.einsum("na,na->n", ot, nt[i])[:, None] * nt[i]
        ow -= np.einsum("na,na->n", ow, nt[i])[:, None] * nt[i]
        Ct = np.stack([np.bincount(i, ot[:, a] * ot[:, b], Vt) for a in range(3) for b in range(3)], 1)
        Cw = np.stack([np.bincount(i, ow[:, a] * ow[:, b], Vt) for a in range(3) for b in range(3)], 1)
        Ct, Cw = Ct.reshape(Vt, 3, 3), Cw.reshape(Vt, 3, 3)
        evals, evecs = np.linalg.eigh(Ct)  # the two tangent axes carry the largest eigenvalues
        axes = evecs[:, :, 1:]  # (Vt, 3, 2)
        st = np.sqrt(np.maximum(evals[:, 1:], 0))
        sw = np.sqrt(np.maximum(np.einsum("nak,nab,nbk->nk", axes, Cw, axes), 0))
        with np.errstate(divide="ignore", invalid="ignore"):
            ratio = np.where((sw > 0) & (st > 0), st / sw, 1.0)
        ratio = np.clip(ratio, 1.0 / self.max_scale, self.max_scale)
        ratio[(lens < 4) | ~near] = 1.0
        return np.eye(3) + np.einsum("nak,nk,nbk->nab", axes, ratio - 1.0, axes)

    # ------------------------------------------------------------------ transform
    def _after_load(self) -> None:
        P = self.interpolation_
        self._used = np.unique(P.indices)  # source vertices some target vertex depends on
        self._interp_used = P[:, self._used].tocsr()

    def transform(self, source_vertices) -> np.ndarray:
        """Clone source frames onto the target.

        Parameters
        ----------
        source_vertices : (T, Vs, 3) or (Vs, 3) float
            Source animation in the source's space (same vertex order as the fitted source neutral).

        Returns
        -------
        (T, Vt, 3) or (Vt, 3) float
            Target frames in the target's space.
        """
        self._check_fitted()
        X = np.asarray(source_vertices, dtype=np.float64)
        single = X.ndim == 2
        if single:
            X = X[None]
        Vs, Vt = len(self.source_neutral_), len(self.target_neutral_)
        if X.ndim != 3 or X.shape[1:] != (Vs, 3):
            raise InvalidDataError(f"source frames must have shape (T, {Vs}, 3), got {X.shape}")
        if not np.isfinite(X).all():
            f = int(np.flatnonzero(~np.isfinite(X).reshape(len(X), -1).all(axis=1))[0])
            raise InvalidDataError(f"source frame {f} has a non-finite coordinate")
        T = X.shape[0]
        out = np.empty((T, Vt, 3))
        used, P, M = self._used, self._interp_used, self.transfer_
        n0 = self.source_neutral_[used]
        step = max(1, _CHUNK_ELEMENTS // (3 * max(used.size, Vt)))
        for a in range(0, T, step):
            D = np.take(X[a:a + step], used, axis=1) - n0  # (t, Vu, 3): only vertices that matter
            t = D.shape[0]
            Y = P @ D.transpose(1, 2, 0).reshape(used.size, 3 * t)  # (Vt, 3*t) as [v, j, t]
            out[a:a + t] = (M @ Y.reshape(Vt, 3, t)).transpose(2, 0, 1)
        out += self.target_neutral_
        return out[0] if single else out

    def fit_transform(self, source_neutral: Mesh, target_neutral: Mesh, source_landmarks, target_landmarks,
                      source_vertices) -> np.ndarray:
        """:meth:`fit` then :meth:`transform`."""
        return self.fit(source_neutral, target_neutral, source_landmarks, target_landmarks).transform(
            source_vertices)
