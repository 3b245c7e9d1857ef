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

Each mix is kept to the few shapes that explain the motion, as an artist's mapping would be: a bounded lasso
(:data:`SPARSITY`) picks them, and the bounded least squares on those alone gives their weights.  Every shape
allowed, 68 points cannot tell a smile's corner lift from the same lift plus a little of a disgust shape
(corners down, upper lip up) and a jaw thrust: a VALID avatar's ``mouthSmileLeft`` took 15 shapes, disgust
among them, and its broad smiles bared the teeth with flat corners.  With the lasso it takes 2
(``LsmileClose_h`` 1.0, ``LsmileOpen_h`` 0.49), 3.6 shapes a score on average instead of 13.2, and the
median fit residual goes from 0.50 to 0.52 of the template's motion.

A row per score cannot say that a smile, an open jaw and a raised upper lip *together* are the avatar's open
smile: summed row by row, a VALID avatar's broad smile came out as its subtle closed smile plus its snarl
(``RlipUp_h``) plus four visemes for the jaw, and read as a grimace.  :class:`ScorePrior` (what ``animate`` and
the live modes hold the shapes toward) therefore fits the mouth's scores of each frame *together*: their summed
template motion is matched by the same bounded lasso and bounded least squares, once per frame, so that the
avatar's own combined expression (``RsmileOpen_h``, ``LsmileOpen_h``) can take it; the brows' and eyes' scores
keep their rows (fitted together per frame, they mixed a brow shape into another's motion).
"""

from __future__ import annotations

import functools

import numpy as np

from ..names import normalize_name
from ..rig import Rig

__all__ = ["score_map", "ScorePrior", "by_name", "held_shapes", "MIN_NAMED"]

#: Fewer shapes than this taken by name, and the scores reach the shapes through the template instead.
MIN_NAMED = 10
#: The lasso weight that picks each score's shapes (:func:`_sparse_support`).
SPARSITY = 0.15


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
    down).  Each row holds the few shapes a bounded lasso keeps (module docstring).

    Parameters
    ----------
    rig : Rig
        The solve rig, with its 68 landmark vertices.
    names : list of str
        The tracker's score names.
    """
    names = list(names)
    if not _by_template(rig, names):
        return rig.map_weights(names, np.eye(len(names)), warn=False)
    return _template_rows(rig, *_carried_motion(rig, names), log=log)


def _template_rows(rig: Rig, A: np.ndarray, M: np.ndarray, *, log=None) -> np.ndarray:
    """:func:`score_map` through the template, from :func:`_carried_motion`'s ``A`` and ``M``."""
    from ..numerics import solve_bounded

    out = np.zeros((len(M), rig.n_shapes))
    rows = np.flatnonzero(np.abs(M).max(axis=1) > 0)
    if len(rows):                                    # each score's few shapes, then their mix within [0, 1]
        B = M[rows]
        keep = _sparse_support(A, B, SPARSITY)
        for r, b, k in zip(rows, B, keep, strict=True):
            if k.any():
                out[r, k] = solve_bounded(A[:, k], b, 0.0, 1.0)
        out[out < 1e-3] = 0.0                        # round-off, no drive
    if log is not None:
        reached = int((out.max(axis=0) > 0).sum())
        log(f"{rig.name}: its shapes carry no ARKit names; the tracker's scores reach {reached} of its "
            f"{rig.n_shapes} shapes through the ARKit template's landmark motion")
    return out


class ScorePrior:
    """What a frame's tracker scores hold a character's shapes toward: ``prior(S)``, ``(T, K)`` for the ``(T,
    len(names))`` scores ``S`` (NaN counts as 0).

    Taken by name (or when the rig has no 68 landmarks) it is ``S @ rows``.  Reached through the template, the
    scores whose template motion lies mostly on the jaw line and lips (jaw, mouth, cheek and nose-sneer shapes:
    74-100 % of it there, the brows' and eyes' 0-3 %) are fitted together per frame (module docstring): their
    summed motion, carried onto the character as :func:`score_map` carries one score's, is matched by the bounded
    lasso of :data:`SPARSITY` (solved exactly: the lasso's linear term is a shift of the target, ``A' q = p``) and
    the bounded least squares on the shapes it keeps; the other scores add their rows.  A rig whose shapes'
    landmark motion has no such shift (more shapes than the 68 points' 204 coordinates, or shapes that move them
    alike) keeps the rows.  0.6 ms a frame, 9 ms a
    take of 164 frames on a VALID avatar.  The lasso's choice between near-equal mixes of the same motion can
    switch from one frame to the next (an open smile, or a viseme with a raised lip): ``smooth`` filters the
    jointly fitted part over time (``animate``: the capture's One Euro filter both ways over the take; the live
    modes: causal, half a frame of lag), which took a VALID avatar's landmark jitter (median second difference
    of its 68 landmark vertices) on the README's video from 2.50 to 1.90 mm (1.98 row by row; live 2.42 -> 2.06,
    2.03 row by row).

    Attributes
    ----------
    rows : (len(names), K) float
        :func:`score_map` (what :func:`held_shapes` reads).
    """

    def __init__(self, rig: Rig, names: list[str], *, log=None):
        names = list(names)
        self.mouth = None
        if not _by_template(rig, names):
            self.rows = score_map(rig, names, log=log)
            return
        A, M = _carried_motion(rig, names)                  # once, for the rows and the joint fit
        self.rows = _template_rows(rig, A, M, log=log)
        E = (M.reshape(len(names), -1, 3) ** 2).sum(axis=2)
        mouth = E[:, _LOWER].sum(axis=1) > 0.5 * E.sum(axis=1)
        if not mouth.any():
            return
        p0 = SPARSITY * np.sqrt(np.maximum((A * A).sum(axis=0), 0.0))          # the lasso's weight on each shape
        q0 = np.linalg.pinv(A).T @ p0                                             # A' q0 = p0
        if np.linalg.norm(A.T @ q0 - p0) > 1e-8 * np.linalg.norm(p0):
            return          # more shapes than the 68 points have coordinates (or fewer independent ones): rows
        self.mouth, self.A, self.M, self.q0 = mouth, A, M[mouth], q0

    def __call__(self, S: np.ndarray, *, smooth=None) -> np.ndarray:
        """``(T, K)``; ``smooth``: a function of the ``(T, K)`` jointly fitted part (the mouth's), returning it
        filtered over the frames (None: as it is)."""
        S = np.nan_to_num(np.atleast_2d(np.asarray(S, np.float64)))
        if self.mouth is None:
            return S @ self.rows
        joint = self._joint(S[:, self.mouth] @ self.M)
        if smooth is not None:
            joint = np.clip(smooth(joint), 0.0, 1.0)
        return S[:, ~self.mouth] @ self.rows[~self.mouth] + joint

    def _joint(self, B: np.ndarray) -> np.ndarray:
        """The frames' summed mouth motion ``B`` (T, 204) matched by the lasso's few shapes, each frame's mix within
        [0, 1]."""
        from ..numerics import solve_bounded

        X = solve_bounded(self.A, B - np.linalg.norm(B, axis=1, keepdims=True) * self.q0, 0.0, 1.0)
        keep = X.reshape(len(B), -1) > 1e-3              # the lasso's few shapes
        out = np.zeros((len(B), self.A.shape[1]))
        pats, which = np.unique(keep, axis=0, return_inverse=True)
        for j, pat in enumerate(pats):                   # then their mix within [0, 1], frames of one support at once
            if pat.any():
                fr, cols = np.flatnonzero(which.ravel() == j), np.flatnonzero(pat)
                out[np.ix_(fr, cols)] += solve_bounded(self.A[:, cols], B[fr], 0.0, 1.0).reshape(len(fr), -1)
        return out


def held_shapes(rig: Rig, names: list[str], smap: np.ndarray) -> np.ndarray:
    """``(K,)`` bool: the shapes the tracker's scores hold (the solver's ``prior``; the others get its weak
    ``unscored_prior``), whatever they scored in a frame: taken by name, those a score reaches; reached through
    the template, every shape, 0 where no score reaches it (left free, the 5 of a VALID avatar's 58 shapes no
    score reaches took up what the landmarks' fit left: mouth error 66.9 -> 78.4 %, ``bench/own_shapes.py``).
    ``animate`` and the live modes hold the same shapes."""
    if by_name(rig, list(names)):
        return np.abs(np.asarray(smap)).max(axis=0) > 0
    return np.ones(rig.n_shapes, bool)


def _sparse_support(A: np.ndarray, B: np.ndarray, mu: float, *, iters: int = 100,
                    tol: float = 1e-6) -> np.ndarray:
    """``(len(B), K)`` bool: the shapes each target's bounded lasso keeps: ``min 1/2 ||A x - b||^2 + mu ||b||
    sum_k ||A_k|| x_k`` over ``0 <= x <= 1`` (coordinate descent, every target at once): a shape that adds
    little to the fit costs more than it gains."""
    G = A.T @ A
    C = B @ A                                         # (n, K)
    d = np.diag(G).copy()
    pen = mu * np.linalg.norm(B, axis=1)[:, None] * np.sqrt(np.maximum(d, 0.0))[None, :]
    X = np.zeros_like(C)
    for _ in range(iters):
        change = 0.0
        for k in np.flatnonzero(d > 0):
            r = C[:, k] - X @ G[k] + d[k] * X[:, k]
            new = np.clip((r - pen[:, k]) / d[k], 0.0, 1.0)
            change = max(change, float(np.abs(new - X[:, k]).max()))
            X[:, k] = new
        if change < tol:
            break
    return X > 1e-3


#: The jaw line and lips of the 68 landmarks (where a mouth score's template motion lies).
_LOWER = np.r_[0:17, 48:68]


def _by_template(rig: Rig, names: list[str]) -> bool:
    """Whether the scores reach the rig's shapes through the template (else by name, or not at all)."""
    return not (by_name(rig, names) or rig.landmarks is None or len(rig.landmarks) != 68 or rig.n_shapes == 0)


def _carried_motion(rig: Rig, names: list[str]) -> tuple[np.ndarray, np.ndarray]:
    """``A`` (204, K): the rig's shapes' motion of its 68 landmarks; ``M`` (len(names), 204): each score's template
    motion carried onto them by the similarity between the two neutral faces (0 for a score the template has no
    shape for, and for gaze: it turns the eyeballs, and its lid motion is not a lid shape)."""
    from ..numerics import similarity_fit

    T0, motions = _template_landmarks()
    C0 = rig.neutral.vertices[rig.landmarks].astype(np.float64)
    s, R, _ = similarity_fit(T0, C0[None])               # character ~ s template R' + c
    A = rig.deltas[:, rig.landmarks].astype(np.float64).reshape(rig.n_shapes, -1).T
    M = np.zeros((len(names), A.shape[0]))
    for i, n in enumerate(names):
        a = normalize_name(n)
        d = motions.get(a)
        if d is not None and not a.startswith("eyeLook"):
            M[i] = (float(s[0]) * d @ R[0].T).reshape(-1)
    return A, M


@functools.lru_cache(maxsize=1)
def _template_landmarks() -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """The packaged template's 68 neutral landmarks and each ARKit shape's motion of them (read once)."""
    from ..transfer import packaged_template

    t = packaged_template()
    T0 = np.einsum("pj,pjd->pd", t.lm_bary, t.vertices[t.lm_triangles])
    return T0, {a: np.einsum("pj,pjd->pd", t.lm_bary, d[t.lm_triangles]) for a, d in t.shapes.items()}
