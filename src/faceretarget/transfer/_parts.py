"""The parts of a head that are not its skin: eyeballs, teeth and tongue, lashes and the rest, found by
shape and place (names only as hints), in the head mesh (disconnected pieces) or in other meshes."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["Part", "find_parts", "fit_sphere", "components", "landmark_skin", "LidMargin", "lid_margins", "SEAM"]


@dataclass(eq=False)
class Part:
    """Vertices of one mesh that move together.

    Attributes
    ----------
    mesh : int
    vertices : (n,) int
    role : str
        ``"eye"`` (rotates about ``centre``), ``"lower"`` (rides the jaw), ``"upper"`` (stays),
        ``"sewn"`` (sewn to the skin along a seam, the mesh split there: a mouth's inside, an ear; moves with
        the skin, its seam closed), ``"follow"`` (each vertex follows the nearest skin vertex, fading with
        distance).
    side : str
        ``"left"`` / ``"right"`` for an eye (the character's own sides).
    centre : (3,) float, radius : float
        An eye's sphere.
    """

    mesh: int
    vertices: np.ndarray
    role: str
    side: str = ""
    centre: np.ndarray | None = None
    radius: float = 0.0


def fit_sphere(P: np.ndarray) -> tuple[np.ndarray, float, float]:
    """Least-squares sphere through ``P``: centre, radius and RMS residual over the radius."""
    A = np.c_[2 * P, np.ones(len(P))]
    b = (P * P).sum(1)
    sol, *_ = np.linalg.lstsq(A, b, rcond=None)
    c = sol[:3]
    r = float(np.sqrt(max(sol[3] + c @ c, 1e-30)))
    res = float(np.sqrt(np.mean((np.linalg.norm(P - c, axis=1) - r) ** 2)) / r)
    return c, r, res


def components(n: int, T: np.ndarray) -> np.ndarray:
    """Connected component label of each of ``n`` vertices (through triangles)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    e = np.concatenate([T[:, [0, 1]], T[:, [1, 2]]])
    g = coo_matrix((np.ones(len(e)), (e[:, 0], e[:, 1])), shape=(n, n))
    return connected_components(g, directed=False)[1]


def landmark_skin(character) -> np.ndarray:
    """``(V,)`` bool over the vertices of the character's landmark mesh: the face's skin, the piece (connected
    component) holding most of its 68 landmarks' triangles (an eyeball or teeth of the same mesh are others),
    with the pieces sewn to it (:data:`SEAM`: split off by UV or material seams) that hold landmarks too and
    carry its surface on (:func:`_continues`): a lid or the lips cut out as their own island are skin the
    landmarker saw.  (Rocketbox's pieces holding lid landmarks are the linings inside its lids, flaps on its
    skin: not skin.)"""
    m = character.meshes[character.landmarks.mesh].mesh
    V, T = m.vertices, m.triangles()
    lab = components(m.n_vertices, T)
    held = lab[character.landmarks.triangles.ravel()]
    skin = lab == np.bincount(held).argmax()
    others = [c for c in np.unique(held) if not skin[np.flatnonzero(lab == c)[0]]]
    if others:
        P = character.landmarks.positions(V)
        tol = SEAM * float(np.linalg.norm(P[36] - P[45]))
        for c in others:
            if _continues(V, T, skin, lab == c, tol):
                skin |= lab == c
    return skin


def _continues(V: np.ndarray, T: np.ndarray, skin: np.ndarray, piece: np.ndarray,
               tol: float) -> bool:
    """Whether ``piece`` is sewn to ``skin`` (vertices at one point, within ``tol``) and carries its surface
    on: along the seam, edges on the border of both, and across most of them the two triangles on opposite
    sides of the edge (the lips cut out of the face), whichever way they wind.  Not a piece folded back at its
    seam (both triangles on one side), nor a flap on edges the skin itself is closed across (the linings
    inside Rocketbox's lids)."""
    from scipy.spatial import cKDTree

    sv = np.flatnonzero(skin)
    d, nn = cKDTree(V[sv]).query(V, distance_upper_bound=tol)
    twin = np.full(len(V), -1)
    near = piece & (d <= tol)
    twin[near] = sv[nn[near]]
    if int(near.sum()) < 3:
        return False

    def third(tris):                                         # each edge's triangles: their third vertices
        out: dict = {}
        for t in tris.tolist():
            for k in range(3):
                out.setdefault((min(t[k], t[k - 2]), max(t[k], t[k - 2])), []).append(t[k - 1])
        return out

    tp = T[piece[T].all(axis=1)]
    ts = T[skin[T].all(axis=1) & np.isin(T, twin[near]).any(axis=1)]
    on_piece, on_skin = third(tp), third(ts)
    cos = []
    for (a, b), ds in on_piece.items():
        if len(ds) != 1 or twin[a] < 0 or twin[b] < 0:
            continue
        cs = on_skin.get((min(twin[a], twin[b]), max(twin[a], twin[b])))
        if not cs or len(cs) != 1:
            continue
        e = V[b] - V[a]
        e = e / max(float(np.linalg.norm(e)), 1e-30)
        pc, pd = V[cs[0]] - V[a], V[ds[0]] - V[a]
        pc, pd = pc - (pc @ e) * e, pd - (pd @ e) * e
        cos.append(float(pc @ pd) / max(float(np.linalg.norm(pc) * np.linalg.norm(pd)), 1e-30))
    return bool(cos) and float(np.median(cos)) < 0.0


#: Vertices of two pieces closer than this (times the outer-eye-corner distance) are one point of a seam.
SEAM = 1e-4
_EYE_WORDS = ("eye", "cornea", "iris", "pupil", "sclera")
_NOT_EYE = ("lash", "brow", "lid", "gland", "shadow", "occlusion", "tear", "cartilage")
_LOWER_WORDS = ("down", "lower", "bottom", "tongue", "bot", "jaw")
_UPPER_WORDS = ("up", "upper", "top")


def find_parts(character, head: int, skin: np.ndarray, lm: np.ndarray, frame: np.ndarray, size: float) -> list[Part]:
    """The non-skin parts near the face.

    Parameters
    ----------
    character : Character
    head : int
        The head mesh.
    skin : (n,) bool
        Which of the head mesh's vertices are the face's skin (the rest of its pieces near the face are parts).
    lm : (68, 3) the landmarks; frame : (3, 3) world to head frame; size : outer eye corners' distance.
    """
    from scipy.spatial import cKDTree

    eyes = {"right": lm[36:42].mean(axis=0), "left": lm[42:48].mean(axis=0)}
    if (eyes["left"] @ frame[0]) < (eyes["right"] @ frame[0]):
        eyes = {"left": eyes["right"], "right": eyes["left"]}
    mouth = lm[60:68].mean(axis=0)
    up = frame[1]
    centre = lm[17:68].mean(axis=0)
    pieces = []
    for mi, m in enumerate(character.meshes):
        V = m.mesh.vertices
        near = np.linalg.norm(V - centre, axis=1) < 1.6 * size
        if not near.any():
            continue
        if mi == head:
            lab = components(len(V), m.mesh.triangles())
            for c in np.unique(lab[near & ~skin]):
                idx = np.flatnonzero((lab == c) & ~skin)
                if len(idx):
                    pieces.append((mi, idx, m.name))
        else:
            pieces.append((mi, np.arange(len(V)), m.name))
    parts = []
    skin_tree = cKDTree(character.meshes[head].mesh.vertices[skin]) if skin.any() else None
    for mi, idx, name in pieces:
        P = character.meshes[mi].mesh.vertices[idx]
        low = name.lower()
        # a piece with vertices where the skin has its own (a seam: the mesh split where UVs or materials
        # change) continues the skin's surface: the inside of the mouth sewn to the inner lips is no teeth
        if skin_tree is not None and int((skin_tree.query(P)[0] <= SEAM * size).sum()) >= 3:
            parts.append(Part(mi, idx, "sewn"))
            continue
        c = P.mean(axis=0)
        ext = float(np.ptp(P, axis=0).max())
        if ext > 1.5 * size:                         # hair, body, clothes: only what touches the face follows
            parts.append(Part(mi, idx, "follow"))
            continue
        side = min(eyes, key=lambda k: np.linalg.norm(c - eyes[k]))
        sc, r, res = fit_sphere(P) if len(P) >= 10 else (c, 0.0, 1.0)
        named_eye = any(w in low for w in _EYE_WORDS) and not any(w in low for w in _NOT_EYE)
        round_eye = res < 0.08 and 0.06 * size < r < 0.3 * size and np.linalg.norm(sc - eyes[side]) < 0.3 * size
        if round_eye or (named_eye and np.linalg.norm(c - eyes[side]) < 0.35 * size and len(P) >= 10):
            parts.append(Part(mi, idx, "eye", side, sc, r))
            continue
        if "lash" in low or "brow" in low:
            parts.append(Part(mi, idx, "follow"))
            continue
        if np.linalg.norm(c - mouth) < 0.6 * size and ("teeth" in low or "tooth" in low or "tongue" in low
                                                       or "mouth" in low or "jaw" in low or mi == head
                                                       or (c - mouth) @ character_front(frame) < 0):
            if any(w in low for w in _LOWER_WORDS):
                parts.append(Part(mi, idx, "lower"))
            elif any(w in low for w in _UPPER_WORDS):
                parts.append(Part(mi, idx, "upper"))
            else:                                    # one piece for both: its rows apart at the lips' line
                tri = character.meshes[mi].mesh.triangles()
                loc = np.full(character.meshes[mi].mesh.n_vertices, -1)
                loc[idx] = np.arange(len(idx))
                lab = components(len(idx), loc[tri[(loc[tri] >= 0).all(axis=1)]])
                # each connected row whole, by its middle's side: a row split vertex by vertex had its edge
                # vertices stay while the rest rode the jaw, and tore (a demo face's teeth bar, 4 of 36)
                h = np.bincount(lab, (P - mouth) @ up) / np.bincount(lab)
                parts.append(Part(mi, idx[h[lab] < 0], "lower"))
                parts.append(Part(mi, idx[h[lab] >= 0], "upper"))
            continue
        parts.append(Part(mi, idx, "follow"))
    return parts


def character_front(frame: np.ndarray) -> np.ndarray:
    return frame[2]


@dataclass
class LidMargin:
    """The rim of one eye's opening in the face mesh (its hole's boundary loop), split at the corners into the
    upper and the lower lid; each rim vertex's partner on the other lid is the point of it at the same
    position along the eye (``partner``: two vertices and weights)."""

    eye: tuple[int, ...]                      # its six landmarks (36-41 or 42-47)
    vertices: np.ndarray                      # (n,) rim vertices but the two corners
    upper: np.ndarray                         # (n,) bool
    partner: np.ndarray                       # (n, 2) int: two vertices of the other lid
    weight: np.ndarray                        # (n, 2) float


def lid_margins(V: np.ndarray, T: np.ndarray, lm: np.ndarray, F: np.ndarray) -> list[LidMargin]:
    """The lid rims of a face mesh with eye openings (boundary loops of ``T`` around each eye's landmarks, no
    wider than the eye); none for a face whose eyes are not holes.  A blink that pins only the landmark pairs
    closes those points: where the landmarks sit badly (a low-poly face, eyes without eyeballs) the lids stay
    open between them, so the whole rim is pinned."""
    e = np.sort(np.concatenate([T[:, [0, 1]], T[:, [1, 2]], T[:, [2, 0]]]), axis=1)
    ue, cnt = np.unique(e, axis=0, return_counts=True)
    b = ue[cnt == 1]
    if not len(b):
        return []
    lab = components(len(V), np.c_[b, b[:, :1]])
    bv = np.unique(b.ravel())
    out = []
    for eye in (tuple(range(36, 42)), tuple(range(42, 48))):
        E = lm[list(eye)]
        c = E.mean(axis=0)
        width = float(np.linalg.norm(lm[eye[0]] - lm[eye[3]]))
        near = bv[np.linalg.norm(V[bv] - c, axis=1) < 0.6 * width]
        if len(near) < 6:
            continue
        loop = bv[lab[bv] == np.bincount(lab[near]).argmax()]
        r = np.linalg.norm(V[loop] - c, axis=1)
        if len(loop) < 6 or r.max() > 1.0 * width or r.max() < 0.25 * width:
            continue                                            # not this eye's opening
        x = (V[loop] - c) @ F[0]
        y = (V[loop] - c) @ F[1]
        a, z = int(np.argmin(x)), int(np.argmax(x))
        t = (x - x[a]) / max(x[z] - x[a], 1e-30)
        line = y[a] + t * (y[z] - y[a])
        up = y > line
        keep = np.ones(len(loop), bool)
        keep[[a, z]] = False                                    # the corners stay
        if up[keep].sum() < 2 or (~up[keep]).sum() < 2:
            continue
        partner = np.zeros((len(loop), 2), np.int64)
        weight = np.zeros((len(loop), 2))
        for side in (True, False):
            other = np.flatnonzero((up != side) | ~keep)       # the other lid, corners included
            order = other[np.argsort(x[other])]
            xs = x[order]
            for i in np.flatnonzero((up == side) & keep):
                j = int(np.clip(np.searchsorted(xs, x[i]), 1, len(xs) - 1))
                w = float(np.clip((x[i] - xs[j - 1]) / max(xs[j] - xs[j - 1], 1e-30), 0.0, 1.0))
                partner[i] = loop[order[j - 1]], loop[order[j]]
                weight[i] = 1.0 - w, w
        out.append(LidMargin(eye, loop[keep], up[keep], partner[keep], weight[keep]))
    return out

