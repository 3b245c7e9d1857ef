"""Compositing emotional and verbal key-models with per-vertex importance (Pyun et al. 2003).

Pyun et al. ("An Example-Based Approach for Facial Expression Cloning", SCA 2003, Sec. 2 and the
Appendix) do not sculpt every emotion x viseme combination: they build the combined key-models
from an emotional key-model and a verbal (viseme) key-model.  Plain superposition of the two
displacements can spoil the viseme where both move the same vertices (the emotion adds to or
cancels the mouth shape), so the composition is decided per vertex by how *important* that vertex
is to speech and to emotion.  This module is our reading of that construction:

**Importance (Appendix).**  For the viseme key-models, with displacements ``Dv[j]`` from the
neutral face, the raw importance of vertex ``i`` is the largest displacement any viseme gives it,
normalised to [0, 1] over the face::

    p1_i = max_j |Dv[j, i]| / max_i' max_j |Dv[j, i']|

A vertex that matters (``p1_i > S1``) makes its surroundings matter too: it spreads its importance
to every vertex within distance ``L_p`` on the neutral face, falling off linearly to 0 at ``L_p``::

    p_i = max(p1_i, max_{k: p1_k > S1, d(k, i) < L_p} p1_k (1 - d(k, i) / L_p))

The emotional importance ``e_i`` is the same computed from the emotional key-models with radius
``L_e``.  Distances ``d`` are either straight-line (Euclidean) distances between neutral vertices
(the default) or shortest paths along the neutral mesh's edges (an upper bound of the geodesic
distance that, unlike the straight line, does not reach across the mouth or the eye slits); see
``distance``.

**Composition (Eq. 13).**  For an emotional displacement ``d_e`` and a verbal displacement ``d_p``
of the same vertex: where the vertex is important to both speech and emotion
(``min(p_i, e_i) > S2``) the verbal displacement is kept whole and only the part of the emotional
displacement perpendicular to it is added; elsewhere the two are superposed::

    u = d_p / |d_p|
    d = d_p + d_e - (d_e . u) u        (important to both: lip sync kept exactly along d_p)
    d = d_p + d_e                      (otherwise)

so the composite moves exactly ``|d_p|`` along the viseme's direction at the vertices that make the
viseme.  A hard switch at ``S2`` would leave a seam on the face, so the two rules are blended by a
smooth ramp ``beta_i`` of ``m_i = min(p_i, e_i)``::

    d = d_p + d_e - beta_i * gamma_i * (d_e . u) u
    beta_i = smoothstep((m_i - (S2 - w/2)) / w)       # 0 below S2 - w/2, 1 above S2 + w/2

with ``w`` the ramp width (``blend_width``; ``w = 0`` is the hard switch of the paper).  ``gamma_i``
guards the direction ``u`` where the viseme barely moves the vertex: it is
``smoothstep(|d_p| / tau)``, 1 once ``|d_p| >= tau`` and falling to 0 at ``|d_p| = 0``, with ``tau`` a
small length (``min_displacement`` times the bounding-box diagonal).  Where ``|d_p|`` is that small
its direction is noise, and the rule falls back to superposition.

Parameters and defaults (all settable on :func:`compose_key_models` and :func:`build_key_models`):

=====================  ==========  ==============================================================
name                   paper       meaning (default)
=====================  ==========  ==============================================================
``spread_threshold``   ``S1``      raw importance above which a vertex spreads importance (0.5)
``viseme_radius``      ``L_p``     spreading radius of speech importance, as a fraction of the
                                   neutral's bounding-box diagonal (0.05)
``emotion_radius``     ``L_e``     the same for emotional importance (0.05)
``blend_threshold``    ``S2``      ``min(p, e)`` above which the perpendicular rule applies (0.3)
``blend_width``        --          width of the ramp from superposition to the perpendicular rule,
                                   centred on ``S2`` (0.1: the ramp runs over [0.25, 0.35])
``min_displacement``   --          ``tau`` above as a fraction of the bounding-box diagonal (1e-4)
``distance``           --          ``"euclidean"`` (default) or ``"geodesic"`` (edge paths; needs
                                   ``mesh``)
=====================  ==========  ==============================================================

The paper leaves ``S1``, ``S2``, ``L_p``, ``L_e`` to the user; the defaults are ours.

**Caveat.**  The rule keeps each vertex's motion *along its own* ``d_p``; it does not keep the
relative position of two vertices, such as the upper and lower lip.  A closed-lip viseme moves the
lips little (the neutral's lips are nearly closed already), so an emotion that opens the jaw
(surprise and fear, AU26) or raises one lip more than the other keeps most of that motion in the
perpendicular part.  On the ICT-FaceKit rig the inner-lip gap of ``PP`` is about 0 cm, of
``surprised+PP`` about 1.0 cm (plain superposition: 0.9 cm) and of ``happy+PP`` about -0.2 cm
(lips overlapping; superposition: 0 cm).
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import dijkstra
from scipy.spatial import cKDTree

from ..errors import InvalidDataError, TopologyError
from ..mesh import Mesh
from ..names import ARKIT_NAMES
from ..numerics import smoothstep
from ..rig import Rig
from ._tables import EMOTIONS, VISEMES, table_shapes, weight_vector

__all__ = [
    "Importance",
    "raw_importance",
    "propagate_importance",
    "vertex_importance",
    "blend_weight",
    "compose_displacements",
    "compose_key_models",
    "build_key_models",
]

_SEED_CHUNK = 256  # Dijkstra sources per batch: bounds the (chunk, V) distance block in memory


@dataclass(eq=False)
class Importance:
    """Per-vertex importances behind a composition.

    Attributes
    ----------
    viseme : (V,) float
        Speech importance ``p`` in [0, 1], after spreading.
    emotion : (V,) float
        Emotional importance ``e`` in [0, 1], after spreading.
    beta : (V,) float
        Blend weight of the perpendicular rule in [0, 1] (0: superposition, 1: verbal displacement
        kept whole), from ``min(p, e)`` (see :func:`blend_weight`).
    viseme_raw, emotion_raw : (V,) float
        ``p1`` and ``e1``: the importances before spreading.
    """

    viseme: np.ndarray
    emotion: np.ndarray
    beta: np.ndarray
    viseme_raw: np.ndarray
    emotion_raw: np.ndarray


# ---------------------------------------------------------------------------------------------- helpers


def _as_positions(neutral: np.ndarray | Mesh) -> np.ndarray:
    v = neutral.vertices if isinstance(neutral, Mesh) else np.asarray(neutral, dtype=np.float64)
    if v.ndim != 2 or v.shape[1] != 3:
        raise InvalidDataError(f"neutral vertices must have shape (V, 3), got {v.shape}")
    if not np.isfinite(v).all():
        raise InvalidDataError("neutral vertices contain non-finite values")
    return v


def _as_displacements(d: np.ndarray, n_vertices: int, what: str) -> np.ndarray:
    d = np.asarray(d, dtype=np.float64)
    if d.ndim == 2:
        d = d[None]
    if d.ndim != 3 or d.shape[1:] != (n_vertices, 3):
        raise TopologyError(f"{what} must have shape (N, {n_vertices}, 3), got {d.shape}")
    if not np.isfinite(d).all():
        k = int(np.flatnonzero(~np.isfinite(d).reshape(len(d), -1).all(1))[0])
        raise InvalidDataError(f"{what}: key-model {k} has non-finite values")
    return d


def _bbox_diagonal(x: np.ndarray) -> float:
    return float(np.linalg.norm(x.max(0) - x.min(0))) if len(x) else 0.0


def _resolve_distance(distance: str, mesh: Mesh | None) -> str:
    if distance not in ("euclidean", "geodesic"):
        raise InvalidDataError(f"distance must be 'euclidean' or 'geodesic', got '{distance}'")
    if distance == "geodesic" and (mesh is None or mesh.n_faces == 0):
        raise InvalidDataError("distance='geodesic' needs a mesh with faces")
    return distance


# ---------------------------------------------------------------------------------------------- importance
def raw_importance(displacements: np.ndarray) -> np.ndarray:
    """Raw per-vertex importance ``p1`` of a family of key-models (Appendix).

    Parameters
    ----------
    displacements : (N, V, 3) float
        Key-models minus the neutral.

    Returns
    -------
    (V,) float in [0, 1]
        ``max_j |d[j, i]|`` divided by its maximum over the vertices; all zeros when nothing moves.
    """
    d = np.asarray(displacements, dtype=np.float64)
    if d.ndim == 2:
        d = d[None]
    if d.shape[0] == 0:
        return np.zeros(d.shape[1])
    m = np.linalg.norm(d, axis=-1).max(axis=0)
    top = float(m.max()) if m.size else 0.0
    return m / top if top > 0 else np.zeros_like(m)


def propagate_importance(raw: np.ndarray, positions: np.ndarray, radius: float, *,
                         threshold: float = 0.5, mesh: Mesh | None = None,
                         distance: str = "euclidean") -> np.ndarray:
    """Spread importance from the vertices that matter to their surroundings (Appendix).

    Every vertex ``k`` with ``raw[k] > threshold`` (a seed) gives each vertex ``i`` closer than
    ``radius`` the importance ``raw[k] * (1 - d(k, i) / radius)``; a vertex keeps the largest of its
    own raw importance and what the seeds give it.

    Parameters
    ----------
    raw : (V,) float
        Raw importance ``p1`` (or ``e1``) in [0, 1].
    positions : (V, 3) float
        Neutral vertex positions.
    radius : float
        ``L_p`` (or ``L_e``) as an absolute length in the units of ``positions``.  ``0`` disables
        spreading.
    threshold : float
        ``S1``.
    mesh : Mesh, optional
        The neutral's topology, for ``distance="geodesic"``.
    distance : {"euclidean", "geodesic"}
        ``"euclidean"`` (default): straight-line distance between neutral vertices
        (``scipy.spatial.cKDTree``); it reaches across the mouth slit, so the lower lip's speech
        importance also covers the upper lip, which closes against it.
        ``"geodesic"``: shortest path along the mesh edges (``scipy.sparse.csgraph.dijkstra``), an
        upper bound of the surface distance that keeps the two lips (and the eyelids) apart.

    Returns
    -------
    (V,) float in [0, 1]
    """
    raw = np.asarray(raw, dtype=np.float64).reshape(-1)
    x = _as_positions(positions)
    if len(raw) != len(x):
        raise TopologyError(f"importance has {len(raw)} entries for {len(x)} vertices")
    if mesh is not None and mesh.n_vertices != len(x):
        raise TopologyError(f"mesh has {mesh.n_vertices} vertices but the neutral has {len(x)}")
    if not (np.isfinite(radius) and radius >= 0):
        raise InvalidDataError(f"spreading radius must be a non-negative length, got {radius}")
    out = raw.copy()
    seeds = np.flatnonzero(raw > threshold)
    if radius == 0 or seeds.size == 0:
        return out
    how = _resolve_distance(distance, mesh)
    if how == "euclidean":
        pairs = cKDTree(x[seeds]).sparse_distance_matrix(
            cKDTree(x), radius, output_type="ndarray"
        )
        if pairs.size:
            vals = raw[seeds[pairs["i"]]] * (1.0 - pairs["v"] / radius)
            np.maximum.at(out, pairs["j"], vals)
        return out
    e = mesh.edges()
    lengths = np.linalg.norm(x[e[:, 0]] - x[e[:, 1]], axis=1)
    graph = coo_matrix((lengths, (e[:, 0], e[:, 1])), shape=(len(x), len(x))).tocsr()
    for start in range(0, seeds.size, _SEED_CHUNK):
        s = seeds[start:start + _SEED_CHUNK]
        dist = dijkstra(graph, directed=False, indices=s, limit=radius)  # (chunk, V), inf beyond
        fall = np.clip(1.0 - dist / radius, 0.0, None)  # inf -> 0
        np.maximum(out, (raw[s, None] * fall).max(axis=0), out=out)
    return out


def vertex_importance(displacements: np.ndarray, neutral: np.ndarray | Mesh, *,
                      radius: float = 0.05, threshold: float = 0.5, mesh: Mesh | None = None,
                      distance: str = "euclidean") -> tuple[np.ndarray, np.ndarray]:
    """Importance of every vertex to a family of key-models: raw, then spread.

    Parameters
    ----------
    displacements : (N, V, 3) float
        Key-models of one family (visemes, or emotions) minus the neutral.
    neutral : (V, 3) float or Mesh
        The neutral face.
    radius : float
        Spreading radius as a fraction of the neutral's bounding-box diagonal.
    threshold, mesh, distance
        As in :func:`propagate_importance`.

    Returns
    -------
    spread : (V,) float
        ``p`` (or ``e``) in [0, 1].
    raw : (V,) float
        ``p1`` (or ``e1``).
    """
    x = _as_positions(neutral)
    d = _as_displacements(displacements, len(x), "displacements")
    raw = raw_importance(d)
    spread = propagate_importance(raw, x, radius * _bbox_diagonal(x), threshold=threshold,
                                  mesh=mesh, distance=distance)
    return spread, raw


def blend_weight(viseme_importance: np.ndarray, emotion_importance: np.ndarray, *,
                 threshold: float = 0.3, width: float = 0.1) -> np.ndarray:
    """Weight ``beta`` of the perpendicular rule from ``min(p, e)``, ramped around ``S2``.

    Parameters
    ----------
    viseme_importance, emotion_importance : (V,) float
        ``p`` and ``e``.
    threshold : float
        ``S2``.
    width : float
        Ramp width ``w``: ``beta`` rises smoothly (smoothstep) from 0 at ``S2 - w/2`` to 1 at
        ``S2 + w/2`` and is 0.5 at ``S2``.  ``0`` gives the hard switch ``min(p, e) > S2``.

    Returns
    -------
    (V,) float in [0, 1]

    Examples
    --------
    >>> blend_weight(np.array([1.0, 0.3, 1.0, 0.2]), np.array([1.0, 1.0, 0.0, 0.9]))
    array([1. , 0.5, 0. , 0. ])
    """
    m = np.minimum(np.asarray(viseme_importance, np.float64), np.asarray(emotion_importance, np.float64))
    if width < 0:
        raise InvalidDataError(f"blend width must be >= 0, got {width}")
    if width == 0:
        return (m > threshold).astype(np.float64)
    return smoothstep((m - (threshold - 0.5 * width)) / width)


# ---------------------------------------------------------------------------------------------- composition
def compose_displacements(emotion_disp: np.ndarray, viseme_disp: np.ndarray, beta: np.ndarray, *,
                          min_length: float = 0.0) -> np.ndarray:
    """Eq. 13 with the smooth blend: ``d = d_p + d_e - beta * gamma * (d_e . u) u``.

    Parameters
    ----------
    emotion_disp : (..., V, 3) float
        Emotional displacements ``d_e``.
    viseme_disp : (..., V, 3) float
        Verbal displacements ``d_p``; broadcast against ``emotion_disp``.
    beta : (V,) float
        Per-vertex weight of the perpendicular rule (:func:`blend_weight`).
    min_length : float
        ``tau``: below this length of ``d_p`` the removal of ``d_e``'s component along it fades out
        (``gamma = smoothstep(|d_p| / tau)``); at ``0`` only exactly-zero ``d_p`` is skipped.

    Returns
    -------
    (..., V, 3) float
        The composite displacements.
    """
    de = np.asarray(emotion_disp, dtype=np.float64)
    dp = np.asarray(viseme_disp, dtype=np.float64)
    length = np.linalg.norm(dp, axis=-1)
    safe = np.where(length > 0, length, 1.0)
    u = dp / safe[..., None]
    if min_length > 0:
        gamma = smoothstep(length / min_length)
    else:
        gamma = (length > 0).astype(np.float64)
    along = np.sum(de * u, axis=-1)  # (..., V)
    return dp + de - (np.asarray(beta, np.float64) * gamma * along)[..., None] * u


def compose_key_models(neutral: np.ndarray | Mesh, emotion_disp: np.ndarray, viseme_disp: np.ndarray,
                       mesh: Mesh | None = None, *, spread_threshold: float = 0.5,
                       viseme_radius: float = 0.05, emotion_radius: float = 0.05,
                       blend_threshold: float = 0.3, blend_width: float = 0.1,
                       min_displacement: float = 1e-4, distance: str = "euclidean",
                       return_importance: bool = False):
    """Composite every emotional key-model with every verbal key-model (Sec. 2, Eq. 13, Appendix).

    Parameters
    ----------
    neutral : (V, 3) float or Mesh
        The neutral face (positions only are used; a Mesh is also taken as ``mesh`` when ``mesh`` is
        not given).
    emotion_disp : (Ne, V, 3) float
        Emotional key-models minus the neutral (the neutral emotion, all zeros, may be among them).
    viseme_disp : (Nv, V, 3) float
        Verbal key-models minus the neutral.
    mesh : Mesh, optional
        The neutral's faces, needed only for ``distance="geodesic"``.
    spread_threshold : float
        ``S1`` (0.5).
    viseme_radius, emotion_radius : float
        ``L_p`` and ``L_e`` as fractions of the neutral's bounding-box diagonal (0.05 each).
    blend_threshold : float
        ``S2`` (0.3).
    blend_width : float
        Width of the ramp around ``S2`` (0.1).
    min_displacement : float
        ``tau`` as a fraction of the bounding-box diagonal (1e-4).
    distance : {"euclidean", "geodesic"}
        How spreading measures distance (see :func:`propagate_importance`).
    return_importance : bool
        Also return the :class:`Importance` behind the composition.

    Returns
    -------
    displacements : (Ne * Nv, V, 3) float
        Row ``e * Nv + v`` composites emotion ``e`` with viseme ``v``.
    importance : Importance
        Only when ``return_importance``.
    """
    if mesh is None and isinstance(neutral, Mesh):
        mesh = neutral
    x = _as_positions(neutral)
    V = len(x)
    if mesh is not None and mesh.n_vertices != V:
        raise TopologyError(f"mesh has {mesh.n_vertices} vertices but the neutral has {V}")
    de = _as_displacements(emotion_disp, V, "emotion_disp")
    dp = _as_displacements(viseme_disp, V, "viseme_disp")
    diag = _bbox_diagonal(x)
    p, p1 = vertex_importance(dp, x, radius=viseme_radius, threshold=spread_threshold,
                              mesh=mesh, distance=distance)
    e, e1 = vertex_importance(de, x, radius=emotion_radius, threshold=spread_threshold,
                              mesh=mesh, distance=distance)
    beta = blend_weight(p, e, threshold=blend_threshold, width=blend_width)
    out = compose_displacements(de[:, None], dp[None], beta, min_length=min_displacement * diag)
    out = out.reshape(-1, V, 3)
    if return_importance:
        return out, Importance(viseme=p, emotion=e, beta=beta, viseme_raw=p1, emotion_raw=e1)
    return out


def build_key_models(rig: Rig, **params):
    """The 84 key-models of Pyun et al. for any ARKit-style rig.

    The 6 emotional and 13 verbal key-models are evaluated on ``rig`` from
    :data:`~faceretarget.cloning.tables.EMOTIONS` and :data:`~faceretarget.cloning.tables.VISEMES`;
    every emotion is composited with every viseme by :func:`compose_key_models`, and the 6 pure
    emotions are appended.  Shapes the tables use that the rig lacks get weight 0, named once in a
    warning.  Whole shapes drive split halves (``browInnerUp`` -> ``browInnerUpLeft``/``Right``).

    Parameters
    ----------
    rig : Rig
    **params
        Passed to :func:`compose_key_models` (``spread_threshold``, ``viseme_radius``,
        ``emotion_radius``, ``blend_threshold``, ``blend_width``, ``min_displacement``,
        ``distance``, ``return_importance``).  The rig's neutral is passed as ``mesh``, so
        ``distance="geodesic"`` works when it has faces.

    Returns
    -------
    labels : list of str
        84 labels in the order of
        :func:`~faceretarget.cloning.tables.combined_weight_vectors`: ``"neutral+PP"``, ...,
        ``"angry+U"``, then ``"neutral"``, ``"happy"``, ..., ``"angry"``.
    vertices : (84, V, 3) float
        The key-models (neutral plus displacement).
    importance : Importance
        Only when ``return_importance=True``.
    """
    used = set(table_shapes())
    shapes = [n for n in ARKIT_NAMES if n in used]
    e_labels, v_labels = list(EMOTIONS), list(VISEMES)
    W = np.stack([weight_vector(EMOTIONS[k], shapes) for k in e_labels]
                 + [weight_vector(VISEMES[k], shapes) for k in v_labels])
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        Wr = rig.map_weights(shapes, W, source="emotion/viseme tables")
    for w in caught:  # re-issue pointing at the caller of build_key_models
        warnings.warn(
            f"{w.message} (the key-models are built without them)", w.category, stacklevel=2
        )
    # rig.evaluate(Wr) - neutral, without the round trip through absolute positions
    disp = (Wr @ rig.deltas.reshape(rig.n_shapes, -1)).reshape(len(W), rig.n_vertices, 3)
    de, dp = disp[: len(e_labels)], disp[len(e_labels):]
    res = compose_key_models(rig.neutral.vertices, de, dp, mesh=rig.neutral, **params)
    comp, imp = res if params.get("return_importance") else (res, None)
    labels = [f"{e}+{v}" for e in e_labels for v in v_labels] + e_labels
    verts = np.concatenate([comp, de], axis=0) + rig.neutral.vertices
    if imp is not None:
        return labels, verts, imp
    return labels, verts
