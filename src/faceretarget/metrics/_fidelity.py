"""P11: the main job against ground truth (EVALUATION.md).

A known ARKit take is played on a character, rendered to video, and captured back; these functions
score what came back against what was played, in the character's own geometry and per shape.

* :func:`face_regions`: the face's regions (mouth and lips, lids, brows, cheeks) found from the shapes'
  own displacement: a vertex belongs to the region whose shapes move it most, when they move it by at
  least ``floor`` of that region's largest motion.
* :func:`region_errors`: per region, ``100 * ||X_pred - X_true|| / ||X_true||`` over the region's
  vertices and every frame, where ``X = W @ D`` is the vertex motion the weights give (the error as a
  share of the true motion: 0 is perfect, 100 is as far off as showing nothing).
* :func:`shape_scores`: per shape, correlation and mean absolute error of the weights.
* :func:`blink_f1`: eyes closed where ``eyeBlink >= 0.5``, F1 over frames and both eyes.
* :func:`smile_direction`: on frames whose true smile (mean of ``mouthSmileLeft`` and ``Right``) is at
  least 0.3, the share of (frame, lip corner) pairs where the corner moves the right way: upward (along
  the character's up) when the truth moves it upward, and within 90 degrees of the true motion.
* :func:`head_rotation_error`: the angle between the predicted and the true head rotation, each taken
  relative to its own mean pose (a capture knows the head relative to the actor's rest, not the
  camera's), in degrees per frame.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

__all__ = ["REGION_SHAPES", "KEY_SHAPES", "face_regions", "region_errors", "shape_scores", "blink_f1",
           "smile_direction", "head_rotation_error", "ratio"]

#: ARKit name prefixes of each region's shapes.
REGION_SHAPES: dict[str, tuple[str, ...]] = {
    "mouth": ("jaw", "mouth", "tongue"),
    "lids": ("eyeBlink", "eyeSquint", "eyeWide"),
    "brows": ("brow",),
    "cheeks": ("cheek", "noseSneer"),
}
#: The shapes users notice first (issue 32).
KEY_SHAPES = ("jawOpen", "mouthSmileLeft", "mouthSmileRight", "mouthFunnel", "mouthPucker", "mouthClose",
              "eyeBlinkLeft", "eyeBlinkRight", "browInnerUp", "browDownLeft", "browDownRight")


def face_regions(deltas: np.ndarray, names: list[str], floor: float = 0.1) -> dict[str, np.ndarray]:
    """Vertex indices of each region of :data:`REGION_SHAPES` (module docstring).

    Parameters
    ----------
    deltas : (K, V, 3) float
        The shapes' displacements, named by ``names`` (ARKit names).
    names : list of str
    floor : float
        Share of the region's largest motion a vertex must move to belong to it.
    """
    D = np.asarray(deltas, np.float64)
    mag = np.linalg.norm(D, axis=2)                                   # (K, V)
    reach = np.zeros((len(REGION_SHAPES), D.shape[1]))
    for r, prefixes in enumerate(REGION_SHAPES.values()):
        rows = [k for k, n in enumerate(names) if n.startswith(prefixes)]
        if rows:
            reach[r] = mag[rows].max(axis=0)
    best = reach.argmax(axis=0)
    out = {}
    for r, region in enumerate(REGION_SHAPES):
        top = reach[r].max()
        out[region] = np.flatnonzero((best == r) & (reach[r] > 0) & (reach[r] >= floor * top)) if top > 0 \
            else np.zeros(0, np.int64)
    return out


def region_errors(w_true: np.ndarray, w_pred: np.ndarray, deltas: np.ndarray,
                  regions: dict[str, np.ndarray], pred_deltas: np.ndarray | None = None) -> dict[str, float]:
    """Per region, the error of the vertex motion ``W @ D`` as a percentage of the true motion (module
    docstring); NaN for a region that does not move in the truth.  ``pred_deltas`` (``(K', V, 3)``, the same
    vertices): the prediction's own shapes, ``w_pred`` their weights (a character driven by shapes other than
    the truth's); default ``deltas``."""
    Wt = np.asarray(w_true, np.float64)
    Wp = np.asarray(w_pred, np.float64)
    D = np.asarray(deltas, np.float64)
    Dp = D if pred_deltas is None else np.asarray(pred_deltas, np.float64)
    if len(Wt) != len(Wp) or Wt.shape[1] != len(D) or Wp.shape[1] != len(Dp):
        raise ValueError(f"weights of different shapes: truth {Wt.shape} for {len(D)} shapes, predicted "
                         f"{Wp.shape} for {len(Dp)}")
    out = {}
    for region, idx in regions.items():
        if not len(idx):
            out[region] = float("nan")
            continue
        Xt = Wt @ D[:, idx].reshape(len(D), -1)                       # (T, 3 n)
        Xp = Wp @ Dp[:, idx].reshape(len(Dp), -1)
        den = np.sqrt(np.sum(Xt ** 2))
        out[region] = float(100.0 * np.sqrt(np.sum((Xp - Xt) ** 2)) / den) if den > 0 else float("nan")
    return out


def shape_scores(w_true: np.ndarray, w_pred: np.ndarray, names: list[str],
                 shapes=KEY_SHAPES) -> dict[str, dict[str, float]]:
    """Per shape of ``shapes`` found in ``names``: ``corr`` (NaN where either side is constant) and ``mae``."""
    out = {}
    for s in shapes:
        if s not in names:
            continue
        k = names.index(s)
        a, b = np.asarray(w_true)[:, k], np.asarray(w_pred)[:, k]
        corr = float(np.corrcoef(a, b)[0, 1]) if a.std() > 1e-9 and b.std() > 1e-9 else float("nan")
        out[s] = {"corr": corr, "mae": float(np.abs(a - b).mean())}
    return out


def blink_f1(w_true: np.ndarray, w_pred: np.ndarray, names: list[str], threshold: float = 0.5) -> dict[str, float]:
    """Eyes closed where ``eyeBlinkLeft`` / ``eyeBlinkRight`` >= ``threshold``: precision, recall and F1
    over every frame of both eyes (NaN F1 when neither side ever closes)."""
    cols = [names.index(n) for n in ("eyeBlinkLeft", "eyeBlinkRight") if n in names]
    t = np.asarray(w_true)[:, cols] >= threshold
    p = np.asarray(w_pred)[:, cols] >= threshold
    tp, fp, fn = int((t & p).sum()), int((~t & p).sum()), int((t & ~p).sum())
    f1 = 2 * tp / (2 * tp + fp + fn) if (2 * tp + fp + fn) else float("nan")
    return {"f1": float(f1), "precision": tp / (tp + fp) if tp + fp else float("nan"),
            "recall": tp / (tp + fn) if tp + fn else float("nan"), "closed_frames": int(t.sum())}


def smile_direction(w_true: np.ndarray, w_pred: np.ndarray, names: list[str], corner_deltas: np.ndarray,
                    up, threshold: float = 0.3) -> dict[str, float]:
    """The share of smile frames whose lip corners move the right way (module docstring).

    Parameters
    ----------
    corner_deltas : (K, 2, 3) float
        Each shape's displacement of the two lip corners.
    up : (3,) float
        The character's up direction.
    """
    cols = [names.index(n) for n in ("mouthSmileLeft", "mouthSmileRight") if n in names]
    Wt, Wp = np.asarray(w_true, np.float64), np.asarray(w_pred, np.float64)
    frames = np.flatnonzero(Wt[:, cols].mean(axis=1) >= threshold) if cols else np.zeros(0, np.int64)
    if not len(frames):
        return {"share": float("nan"), "frames": 0}
    C = np.asarray(corner_deltas, np.float64)
    ct = np.einsum("tk,kcd->tcd", Wt[frames], C)                     # (n, 2, 3)
    cp = np.einsum("tk,kcd->tcd", Wp[frames], C)
    u = np.asarray(up, np.float64) / np.linalg.norm(up)
    cos = np.einsum("tcd,tcd->tc", ct, cp) / np.maximum(
        np.linalg.norm(ct, axis=2) * np.linalg.norm(cp, axis=2), 1e-15)
    upward_t, upward_p = ct @ u, cp @ u
    right = (cos > 0) & ((upward_t <= 0) | (upward_p > 0))
    return {"share": float(right.mean()), "frames": int(len(frames)),
            "up_mm_true": float(1000 * np.median(upward_t)), "up_mm_pred": float(1000 * np.median(upward_p))}


def head_rotation_error(q_true: np.ndarray, q_pred: np.ndarray) -> np.ndarray:
    """(T,) degrees between two head rotations (``x, y, z, w`` quaternions), each relative to its own
    mean pose (scipy's ``Rotation.mean``); NaN where either has no pose."""
    qt, qp = np.asarray(q_true, np.float64), np.asarray(q_pred, np.float64)
    ok = np.isfinite(qt).all(axis=1) & np.isfinite(qp).all(axis=1)
    out = np.full(len(qt), np.nan)
    if not ok.any():
        return out
    rt, rp = Rotation.from_quat(qt[ok]), Rotation.from_quat(qp[ok])
    rt, rp = rt.mean().inv() * rt, rp.mean().inv() * rp
    out[ok] = np.degrees((rp.inv() * rt).magnitude())
    return out


def ratio(ours: float, peer: float) -> float:
    """``ours / peer`` (NaN when either is missing or the peer is 0)."""
    if not (np.isfinite(ours) and np.isfinite(peer)) or peer == 0:
        return float("nan")
    return float(ours / peer)
