"""The tracker's ARKit scores on a character's own shapes, whatever they are called.

The main job holds the character's shapes toward the tracker's scores where its 68 points see little
(:func:`~faceretarget.pipelines.video_solver`).  A character whose shapes carry ARKit names takes each
score by name.  One whose shapes are its own (a VALID avatar's ``RsmileClose_h``, ``LeyeClose_h``, ...) took
none: every shape was solved from the 68 points alone, and a broad smile came out as a grimace with the
brows pulled down.  :func:`score_map` reaches such shapes through geometry instead of names: each ARKit
shape of the packaged template (ICT-FaceKit) moves the template's 68 landmarks; that motion, carried onto
the character's landmarks by the similarity between the two neutral faces, is matched by a mix of the
character's shapes' landmark motion, each weight within [0, 1] (bounded least squares: unbounded, a jaw drop
no shape reaches became five times a viseme); the mix is that score's row.
"""

from __future__ import annotations

import functools

import numpy as np

from ..names import normalize_name
from ..rig import Rig

__all__ = ["score_map", "by_name", "MIN_NAMED"]

#: Fewer shapes than this taken by name, and the scores reach the shapes through the template instead.
MIN_NAMED = 10


def by_name(rig: Rig, names: list[str]) -> bool:
    """Whether :func:`score_map` takes the scores ``names`` by name (at least :data:`MIN_NAMED` of the rig's
    shapes are named after one)."""
    return int((np.abs(rig.map_weights(list(names), np.eye(len(names)), warn=False)).max(axis=0) > 0).sum()) \
        >= MIN_NAMED


def score_map(rig: Rig, names: list[str], *, log=None) -> np.ndarray:
    """``(len(names), K)``: how each tracker score (ARKit ``names``) drives the rig's ``K`` shapes.

    By name when at least :data:`MIN_NAMED` of the rig's shapes are named after scores
    (:meth:`~faceretarget.rig.Rig.map_weights`); else through the template's landmark motion (module
    docstring), for the rig's 68 landmarks (``rig.landmarks``); a score the template has no shape for
    (``tongueOut``) drives nothing, nor do the gaze scores (``eyeLook*``: they turn the eyeballs, and the lids
    that follow them matched a VALID avatar's eye-closing shapes, closing its eyes when the actor looked
    down).

    Parameters
    ----------
    rig : Rig
        The solve rig, with its 68 landmark vertices.
    names : list of str
        The tracker's score names.
    """
    from ..numerics import similarity_fit, solve_bounded

    names = list(names)
    if by_name(rig, names) or rig.landmarks is None or len(rig.landmarks) != 68 or rig.n_shapes == 0:
        return rig.map_weights(names, np.eye(len(names)), warn=False)
    T0, motions = _template_landmarks()
    C0 = rig.neutral.vertices[rig.landmarks].astype(np.float64)
    s, R, _ = similarity_fit(T0, C0[None])               # character ~ s template R' + c
    A = rig.deltas[:, rig.landmarks].astype(np.float64).reshape(rig.n_shapes, -1).T      # (204, K)
    out = np.zeros((len(names), rig.n_shapes))
    rows, targets = [], []
    for i, n in enumerate(names):
        a = normalize_name(n)
        d = motions.get(a)
        if d is None or a.startswith("eyeLook"):     # gaze turns the eyeballs; its lid motion is not a lid shape
            continue
        rows.append(i)
        targets.append((float(s[0]) * d @ R[0].T).reshape(-1))
    if rows:                                         # every score's mix at once, each within [0, 1]
        out[rows] = solve_bounded(A, np.array(targets), 0.0, 1.0)
        out[out < 1e-3] = 0.0                        # round-off, no drive
    if log is not None:
        reached = int((out.max(axis=0) > 0).sum())
        log(f"{rig.name}: its shapes carry no ARKit names; the tracker's scores reach {reached} of its "
            f"{rig.n_shapes} shapes through the ARKit template's landmark motion")
    return out


@functools.lru_cache(maxsize=1)
def _template_landmarks() -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """The packaged template's 68 neutral landmarks and each ARKit shape's motion of them (read once)."""
    from ..transfer import packaged_template

    t = packaged_template()
    T0 = np.einsum("pj,pjd->pd", t.lm_bary, t.vertices[t.lm_triangles])
    return T0, {a: np.einsum("pj,pjd->pd", t.lm_bary, d[t.lm_triangles]) for a, d in t.shapes.items()}
