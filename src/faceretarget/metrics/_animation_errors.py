"""Metrics and ground truth of evaluation protocol P1 (paired rigs, see ``EVALUATION.md``).

Every metric compares predicted target vertices ``pred`` with the ground truth ``gt``, both
``(T, V, 3)`` (a single ``(V, 3)`` frame is taken as ``T = 1``), vectorised over frames:

========================  ====================================================================
``rel_motion_pct``        ``sum_t,j |v - v^| / sum_t,j |v - v0| * 100``: the share of the facial
                          motion that is wrong (the headline; independent of origin and scale)
``err_pct``               Pyun et al. 2003, Eq. 12: per frame ``sum_j |v_j - v^_j| / sum_j |v_j|``,
                          averaged over frames, in %; in the target rig's own coordinates
``err_pct_x/y/z``         the same per axis, with absolute values of that coordinate
``mve_mm``                mean vertex distance in millimetres
``mve_pct_diag``          the same over the neutral's bounding-box diagonal, in %
``lve_mm``                per frame the largest distance over the lip vertices, averaged over frames
``oracle_rel_motion_pct`` ``rel_motion_pct`` of :func:`oracle_blend`, the least-squares best blend
                          of the target key-models: the floor no key-blending method can beat
========================  ====================================================================

Norms are Euclidean norms of 3-vectors (``v`` ground truth, ``v^`` predicted, ``v0`` the target
neutral).  ``unit`` is the rig's unit (``"cm"``, ``"m"``, ...; see :data:`faceretarget.units.UNIT_TO_MM`),
millimetres per unit as a number, or the :class:`~faceretarget.rig.Rig` itself.

Ground truth: :func:`rig_animation` drives a rig with named ARKit weights (``Rig.map_weights`` gives a
whole weight to both halves of a split shape and 0 to shapes the weights lack), and
:class:`ArkitPairing` does so for a source and a target rig at once.
"""

from __future__ import annotations

import numpy as np

from ..errors import InvalidDataError
from ..mesh import Mesh
from ..numerics import solve_bounded
from ..rig import Rig
from ..units import mm_per_unit

__all__ = [
    "rel_motion_pct",
    "err_pct",
    "err_pct_axis",
    "mve_mm",
    "mve_pct_diag",
    "lve_mm",
    "lip_vertices",
    "oracle_blend",
    "oracle_rel_motion_pct",
    "metrics",
    "LIP_LANDMARKS",
]

#: Positions of the lip landmarks (outer and inner lip contour) among the 68 Multi-PIE landmarks.
LIP_LANDMARKS = np.arange(48, 68)


# ---------------------------------------------------------------------------------------- helpers
def _frames(a, what: str) -> np.ndarray:
    a = np.asarray(a, dtype=np.float64)
    if a.ndim == 2:
        a = a[None]
    if a.ndim != 3 or a.shape[2] != 3:
        raise InvalidDataError(f"{what} must have shape (T, V, 3) or (V, 3), got {a.shape}")
    return a


def _pair(pred, gt) -> tuple[np.ndarray, np.ndarray]:
    p, g = _frames(pred, "predicted vertices"), _frames(gt, "ground-truth vertices")
    if p.shape != g.shape:
        raise InvalidDataError(f"predicted vertices {p.shape} and ground truth {g.shape} differ in shape")
    return p, g


def _neutral(neutral, n_vertices: int | None = None) -> np.ndarray:
    if isinstance(neutral, Rig):
        neutral = neutral.neutral
    if isinstance(neutral, Mesh):
        neutral = neutral.vertices
    n = np.asarray(neutral, dtype=np.float64)
    if n.ndim != 2 or n.shape[1] != 3 or (n_vertices is not None and n.shape[0] != n_vertices):
        want = f"({n_vertices}, 3)" if n_vertices is not None else "(V, 3)"
        raise InvalidDataError(f"target neutral must have shape {want}, got {n.shape}")
    return n




def _ratio(num: float, den: float) -> float:
    """``num / den * 100``; 0 when both are 0, inf when only the denominator is."""
    if den > 0:
        return float(num / den * 100.0)
    return 0.0 if num == 0 else float("inf")


def _norm3(x: np.ndarray) -> np.ndarray:
    """Euclidean norms of the 3-vectors of ``x`` ``(..., 3)``; faster than ``np.linalg.norm`` on big takes."""
    return np.sqrt(np.einsum("...i,...i->...", x, x))


def _dist(pred, gt) -> np.ndarray:
    p, g = _pair(pred, gt)
    return _norm3(p - g)  # (T, V)


# ---------------------------------------------------------------------------------------- metrics
def rel_motion_pct(pred, gt, neutral) -> float:
    """``sum_t,j |v - v^| / sum_t,j |v - v0| * 100``: the share of the motion that is wrong.

    >>> n = np.zeros((2, 3)); gt = n + [[1.0, 0, 0], [0, 2.0, 0]]
    >>> rel_motion_pct(gt + [0, 0, 0.3], gt, n)
    20.0
    """
    p, g = _pair(pred, gt)
    n = _neutral(neutral, g.shape[1])
    return _ratio(float(_norm3(p - g).sum()), float(_norm3(g - n).sum()))


def err_pct(pred, gt) -> float:
    """Pyun et al.'s Eq. 12: per frame ``sum_j |v_j - v^_j| / sum_j |v_j| * 100``, mean over frames."""
    p, g = _pair(pred, gt)
    num = _norm3(p - g).sum(axis=1)
    den = _norm3(g).sum(axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        return float(np.mean(num / den) * 100.0)


def err_pct_axis(pred, gt, axis: int) -> float:
    """Eq. 12 for one coordinate (0 = x, 1 = y, 2 = z) with absolute values, mean over frames, in %."""
    if axis not in (0, 1, 2):
        raise InvalidDataError(f"axis must be 0, 1 or 2, got {axis}")
    p, g = _pair(pred, gt)
    num = np.abs(p[..., axis] - g[..., axis]).sum(axis=1)
    den = np.abs(g[..., axis]).sum(axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        return float(np.mean(num / den) * 100.0)


def mve_mm(pred, gt, unit) -> float:
    """Mean vertex distance over all frames and vertices, in millimetres."""
    return float(_dist(pred, gt).mean() * mm_per_unit(unit))


def mve_pct_diag(pred, gt, neutral) -> float:
    """Mean vertex distance over the neutral's bounding-box diagonal, in %."""
    d = _dist(pred, gt)
    n = _neutral(neutral, d.shape[1])
    return _ratio(float(d.mean()), float(np.linalg.norm(n.max(0) - n.min(0))))


def lip_vertices(rig: Rig) -> np.ndarray:
    """The rig's lip vertices: its landmarks 48-67 of the 68 Multi-PIE landmarks."""
    if rig.landmarks is None or rig.landmarks.size != 68:
        n = 0 if rig.landmarks is None else rig.landmarks.size
        raise InvalidDataError(f"{rig.name}: lip vertices need the 68 landmarks, the rig has {n}")
    return rig.landmarks[LIP_LANDMARKS]


def lve_mm(pred, gt, unit, lips=None) -> float:
    """Per frame the largest distance over the lip vertices, averaged over frames, in millimetres.

    ``lips`` are vertex indices; when ``None``, ``unit`` must be a :class:`Rig` with 68 landmarks and
    its landmarks 48-67 are used.
    """
    d = _dist(pred, gt)
    if lips is None:
        if not isinstance(unit, Rig):
            raise InvalidDataError("lve_mm: give the lip vertex indices or pass the Rig as unit")
        lips = lip_vertices(unit)
    lips = np.asarray(lips, dtype=np.int64).reshape(-1)
    if lips.size == 0 or lips.min() < 0 or lips.max() >= d.shape[1]:
        raise InvalidDataError(f"lip vertex indices must be a non-empty subset of 0..{d.shape[1] - 1}")
    return float(d[:, lips].max(axis=1).mean() * mm_per_unit(unit))


# ---------------------------------------------------------------------------------------- oracle
def oracle_blend(gt, target_keys, target_neutral, *, return_weights: bool = False, weight_range=None):
    """The least-squares best blend of the target key-models' displacements against the ground truth.

    ``B^(t) = B0 + sum_i w_i(t) (B_i - B0)`` with ``w(t)`` minimising ``||B^(t) - B(t)||`` for every
    frame at once (one least-squares solve with ``T`` right-hand sides), unconstrained or inside
    ``weight_range``.  No method that blends these key-models (inside that range) can do better.

    Parameters
    ----------
    gt : (T, V, 3) float
        Ground-truth target animation.
    target_keys : (N, V, 3) float
        Target key-models (a neutral among them contributes nothing and is harmless).
    target_neutral : (V, 3) float, Mesh or Rig
    return_weights : bool
        Also return the ``(T, N)`` weights (minimum-norm when keys are linearly dependent).
    weight_range : (lo, hi), optional
        Keep every weight inside (box-constrained least squares on the ``N x N`` triangular factor
        of the key-models, :func:`~faceretarget.numerics.solve_bounded`).

    Returns
    -------
    (T, V, 3) float, and ``(T, N)`` weights when asked.
    """
    g = _frames(gt, "ground-truth vertices")
    keys = np.asarray(target_keys, dtype=np.float64)
    T, V, _ = g.shape
    n = _neutral(target_neutral, V)
    if keys.ndim != 3 or keys.shape[1:] != (V, 3):
        raise InvalidDataError(f"target key-models must have shape (N, {V}, 3), got {keys.shape}")
    D = (keys - n).reshape(len(keys), -1)  # (N, 3V)
    G = (g - n).reshape(T, -1)  # (T, 3V)
    if weight_range is None:
        w = np.linalg.lstsq(D.T, G.T, rcond=None)[0].T  # (T, N)
    else:
        Q, R = np.linalg.qr(D.T)  # ||D'w - g||^2 = ||R w - Q'g||^2 + what no blend reaches
        w = solve_bounded(R, G @ Q, *weight_range)
    pred = (w @ D).reshape(T, V, 3) + n
    return (pred, w) if return_weights else pred


def oracle_rel_motion_pct(gt, target_keys, target_neutral, weight_range=None) -> float:
    """:func:`rel_motion_pct` of :func:`oracle_blend`: the floor for blending these key-models
    (inside ``weight_range`` when given)."""
    n = _neutral(target_neutral)
    return rel_motion_pct(oracle_blend(gt, target_keys, n, weight_range=weight_range), gt, n)


def metrics(pred, gt, neutral, unit=None, lips=None, *, target_keys=None) -> dict[str, float]:
    """All P1 metrics as a dict (keys as in the P1 JSON).

    ``neutral`` may be an array, a Mesh or the target Rig, ``unit`` a unit name, millimetres per unit
    or the Rig (``None`` when ``neutral`` is the Rig).  ``lve_mm`` uses ``lips``, else the lip landmarks of a Rig passed as ``unit`` or
    ``neutral``; without either it is NaN.  With ``target_keys`` (N, V, 3) the dict also holds
    ``oracle_rel_motion_pct``.
    """
    p, g = _pair(pred, gt)
    n = _neutral(neutral, g.shape[1])
    rig = unit if isinstance(unit, Rig) else neutral if isinstance(neutral, Rig) else None
    if lips is None and rig is not None and rig.landmarks is not None and rig.landmarks.size == 68:
        lips = lip_vertices(rig)
    if unit is None:
        if rig is None:
            raise InvalidDataError("metrics: give the unit, or the target Rig as neutral")
        unit = rig
    mm = mm_per_unit(unit)
    diff = p - g
    d = _norm3(diff)                                   # (T, V), computed once for every metric
    with np.errstate(divide="ignore", invalid="ignore"):
        frame_err = d.sum(axis=1) / _norm3(g).sum(axis=1)
        axis_err = [np.abs(diff[..., a]).sum(axis=1) / np.abs(g[..., a]).sum(axis=1) for a in range(3)]
    diag = float(np.linalg.norm(n.max(0) - n.min(0)))
    if lips is not None:
        lips = np.asarray(lips, dtype=np.int64).reshape(-1)
    out = {
        "rel_motion_pct": _ratio(float(d.sum()), float(_norm3(g - n).sum())),
        "err_pct": float(np.mean(frame_err) * 100.0),
        "err_pct_x": float(np.mean(axis_err[0]) * 100.0),
        "err_pct_y": float(np.mean(axis_err[1]) * 100.0),
        "err_pct_z": float(np.mean(axis_err[2]) * 100.0),
        "mve_mm": float(d.mean() * mm),
        "mve_pct_diag": _ratio(float(d.mean()), diag),
        "lve_mm": float("nan") if lips is None else float(d[:, lips].max(axis=1).mean() * mm),
    }
    if target_keys is not None:
        out["oracle_rel_motion_pct"] = oracle_rel_motion_pct(g, target_keys, n)
    return out
