"""What a user sees of a character's face shapes: do the lids close, do the lips meet, does a triangle
flip, do left and right mirror each other.  Each works on any character with landmarks and ARKit-named
shapes (artist-made or generated)."""

from __future__ import annotations

import numpy as np

from ..character import Character, character_frame
from ..names import normalize_name

__all__ = ["blink_gap_pct", "lip_gap_pct", "inverted_triangles", "mirror_err_pct", "shape_metrics", "shape_delta",
           "eye_parts", "lips_in_teeth", "teeth_showing_px", "lid_gap_pct"]

LID_PAIRS = ((37, 41), (38, 40), (43, 47), (44, 46))
LIP_PAIRS = ((61, 67), (62, 66), (63, 65))
MOUTH_SHAPES = ("mouthClose", "mouthFunnel", "mouthPucker", "mouthLeft", "mouthRight", "mouthSmileLeft",
                "mouthSmileRight", "mouthFrownLeft", "mouthFrownRight", "mouthDimpleLeft", "mouthDimpleRight",
                "mouthStretchLeft", "mouthStretchRight", "mouthRollLower", "mouthRollUpper", "mouthShrugLower",
                "mouthShrugUpper", "mouthPressLeft", "mouthPressRight", "mouthLowerDownLeft", "mouthLowerDownRight",
                "mouthUpperUpLeft", "mouthUpperUpRight")


def shape_delta(character: Character, name: str, mesh: int | None = None) -> np.ndarray | None:
    """``(V, 3)`` delta of the ARKit shape ``name`` on the landmark mesh (or ``mesh``), or None."""
    mi = character.landmarks.mesh if mesh is None else mesh
    m = character.meshes[mi]
    for k, n in enumerate(m.shape_names):
        if normalize_name(n) == name:
            return m.deltas[k].astype(np.float64)
    return None


def _lm(character: Character, delta) -> np.ndarray:
    V = character.meshes[character.landmarks.mesh].mesh.vertices
    return character.landmarks.positions(V + (0 if delta is None else delta))


def _side_pairs(character: Character, side: str) -> list[tuple[int, int]]:
    F = character_frame(character)
    rest = _lm(character, None)
    a, b = rest[36:42].mean(0) @ F[0], rest[42:48].mean(0) @ F[0]
    left = LID_PAIRS[2:] if b > a else LID_PAIRS[:2]
    right = LID_PAIRS[:2] if b > a else LID_PAIRS[2:]
    return list(left if side == "Left" else right)


def _rim_gap_pct(character: Character, side: str, d: np.ndarray) -> float | None:
    """Worst remaining gap between the lid rims of one eye's opening at weight 1 over the open gap, over the
    rim points whose open gap is at least a third of the widest (near the corners the gap vanishes); None when
    the face mesh has no opening around that eye (:func:`~faceretarget.transfer.lid_margins`)."""
    from ._parts import landmark_skin, lid_margins

    m = character.meshes[character.landmarks.mesh]
    V = m.mesh.vertices.astype(np.float64)
    T = m.mesh.triangles()
    skin = landmark_skin(character)
    lm = _lm(character, None)
    eye = _side_pairs(character, side)[0][0]
    for rim in lid_margins(V, T[skin[T].all(axis=1)], lm, character_frame(character)):
        if eye not in rim.eye:
            continue
        P0, P1 = V[rim.vertices], V[rim.vertices] + d[rim.vertices]
        Q0 = np.einsum("nk,nkd->nd", rim.weight, V[rim.partner])
        Q1 = np.einsum("nk,nkd->nd", rim.weight, (V + d)[rim.partner])
        g0, g1 = np.linalg.norm(P0 - Q0, axis=1), np.linalg.norm(P1 - Q1, axis=1)
        ok = g0 >= g0.max() / 3.0
        return 100.0 * float((g1[ok] / g0[ok]).max()) if ok.any() and g0.max() > 1e-9 else None
    return None


def lid_gap_pct(character: Character, side: str, d: np.ndarray) -> float | None:
    """Remaining lid gap of the character's ``side`` (``"Left"`` / ``"Right"``) eye under the head mesh's
    motion ``d`` over the open gap, %: along the whole rim of the eye's opening where the face mesh has one
    (:func:`_rim_gap_pct`), else the worst lid landmark pair; None when neither can be measured."""
    d = np.asarray(d, np.float64)
    rim = _rim_gap_pct(character, side, d)
    if rim is not None:
        return rim
    return _pair_gap_pct(_lm(character, None), _lm(character, d), _side_pairs(character, side))


def _pair_gap_pct(open_: np.ndarray, closed: np.ndarray, pairs) -> float | None:
    """The worst pair's gap in ``closed`` over its gap in ``open_`` (landmark positions), %."""
    worst = None
    for up, lo in pairs:
        g0 = np.linalg.norm(open_[up] - open_[lo])
        if g0 < 1e-9:
            continue
        pct = 100.0 * float(np.linalg.norm(closed[up] - closed[lo]) / g0)
        worst = pct if worst is None else max(worst, pct)
    return worst


def blink_gap_pct(character: Character, eyes=None) -> tuple[float | None, int | None]:
    """Remaining lid gap at ``eyeBlinkLeft`` / ``eyeBlinkRight`` = 1 over the open gap, worst of both eyes, %:
    along the whole rim of the eye's opening where the face mesh has one (:func:`_rim_gap_pct`), else at the
    lid landmark pairs (landmarks that sit badly close while the lids stay open: the rim says so); and the
    number of face vertices inside an eyeball at weight 1 that were not at rest (``eyes``: parts with
    ``centre`` and ``radius``; None when none is given)."""
    worst, inside = None, None
    V = character.meshes[character.landmarks.mesh].mesh.vertices
    for side in ("Left", "Right"):
        d = shape_delta(character, f"eyeBlink{side}")
        if d is None:
            continue
        g = lid_gap_pct(character, side, d)
        if g is not None:
            worst = g if worst is None else max(worst, g)
        if eyes:
            inside = inside or 0
            for e in eyes:
                d0 = np.linalg.norm(V - e.centre, axis=1)
                d1 = np.linalg.norm(V + d - e.centre, axis=1)
                tol = 0.02 * e.radius
                inside += int(((d1 < e.radius - tol) & (d0 >= e.radius - tol)).sum())
    return worst, inside


def lip_gap_pct(character: Character) -> float | None:
    """Inner-lip gap at ``jawOpen + mouthClose`` = 1 over the gap at ``jawOpen`` = 1, worst pair, %."""
    jo, mc = shape_delta(character, "jawOpen"), shape_delta(character, "mouthClose")
    if jo is None or mc is None:
        return None
    return _pair_gap_pct(_lm(character, jo), _lm(character, jo + mc), LIP_PAIRS)


def inverted_triangles(character: Character, names: list[str] | None = None, mesh: int | None = None) -> int:
    """Triangles of the face mesh whose normal turns by more than 90 degrees at weight 1 of a shape (but
    ``mouthClose``, which is made to play on an open jaw), or of ``jawOpen`` plus a mouth shape, summed over
    the shapes and pairs."""
    mi = character.landmarks.mesh if mesh is None else mesh
    m = character.meshes[mi]
    V = m.mesh.vertices.astype(np.float64)
    T = m.mesh.triangles()

    def normals(P):
        return np.cross(P[T[:, 1]] - P[T[:, 0]], P[T[:, 2]] - P[T[:, 0]])

    n0 = normals(V)
    ok = np.linalg.norm(n0, axis=1) > 1e-14
    names = names or sorted({normalize_name(n) for n in m.shape_names})
    combos = [[n] for n in names if n != "mouthClose"]        # mouthClose alone is no pose: on an open jaw
    if "jawOpen" in names:
        combos += [["jawOpen", n] for n in MOUTH_SHAPES if n in names and n != "jawOpen"]
    total = 0
    for c in combos:
        ds = [shape_delta(character, n, mi) for n in c]
        if any(d is None for d in ds):
            continue
        n1 = normals(V + sum(ds))
        total += int(((n0 * n1).sum(1)[ok] < 0).sum())
    return total


def mirror_err_pct(character: Character, *, symmetric_tol: float = 0.02) -> float | None:
    """How far left/right shape pairs are from mirror images about the face's symmetry plane: the motion
    of ``xxxLeft`` minus the mirrored motion of ``xxxRight`` at the mirrored vertex, RMS over the moving
    vertices of the face's skin (the piece of the mesh the landmarks are on), over the RMS motion, %, the
    worst pair; None when the face is not symmetric (its mirrored vertices further than ``symmetric_tol``
    of the outer-eye-corner distance from the mesh, mean)."""
    from scipy.spatial import cKDTree

    mi = character.landmarks.mesh
    V = character.meshes[mi].mesh.vertices.astype(np.float64)
    F = character_frame(character)
    lm = _lm(character, None)
    size = float(np.linalg.norm(lm[36] - lm[45]))
    from ._parts import landmark_skin

    H = (V - lm[27:36].mean(0)) @ F.T                    # head frame about the nose line
    skin = landmark_skin(character)
    near = skin & (np.linalg.norm(V - lm[17:68].mean(0), axis=1) < 1.5 * size)
    idx = np.flatnonzero(near)
    Hm = H[idx] * np.array([-1.0, 1.0, 1.0])
    x0 = float(np.median(H[idx, 0]))
    Hm[:, 0] += 2 * x0
    dist, mate = cKDTree(H[idx]).query(Hm)
    mate = idx[mate]
    if float(dist.mean()) > symmetric_tol * size:
        return None
    worst = None
    names = {normalize_name(n) for n in character.meshes[mi].shape_names}
    for n in sorted(names):
        if not n.endswith("Left") or n[:-4] + "Right" not in names:
            continue
        dl, dr = shape_delta(character, n), shape_delta(character, n[:-4] + "Right")
        hl = dl[idx] @ F.T
        hr = (dr[mate] @ F.T) * np.array([-1.0, 1.0, 1.0])
        mag = np.sqrt((hl ** 2).sum(1))
        sel = mag > 0.1 * mag.max() if mag.max() > 0 else None
        if sel is None or sel.sum() < 3:
            continue
        err = np.sqrt(((hl[sel] - hr[sel]) ** 2).sum(1).mean()) / np.sqrt((mag[sel] ** 2).mean())
        worst = 100.0 * float(err) if worst is None else max(worst, 100.0 * float(err))
    return worst


def eye_parts(character: Character) -> list:
    """The character's eyeballs (:class:`~faceretarget.transfer.Part` with ``centre`` and ``radius``), found
    as :func:`~faceretarget.characters.generate_shapes` finds them."""
    from ._parts import find_parts, landmark_skin

    mi = character.landmarks.mesh
    skin = landmark_skin(character)
    lm = _lm(character, None)
    size = float(np.linalg.norm(lm[36] - lm[45]))
    return [p for p in find_parts(character, mi, skin, lm, character_frame(character), size) if p.role == "eye"]


def _mouth_parts(character: Character) -> tuple:
    """The face mesh's index, rest vertices and skin (its piece holding the landmarks), the landmarks, the
    outer-eye-corner distance, and the teeth / tongue pieces (:func:`~faceretarget.transfer.find_parts`)."""
    from ._parts import find_parts, landmark_skin

    mi = character.landmarks.mesh
    m = character.meshes[mi]
    V = m.mesh.vertices.astype(np.float64)
    skin = landmark_skin(character)
    lm = _lm(character, None)
    size = float(np.linalg.norm(lm[36] - lm[45]))
    parts = [p for p in find_parts(character, mi, skin, lm, character_frame(character), size)
             if p.role in ("lower", "upper")]
    return mi, V, skin, lm, size, parts


def lips_in_teeth(character: Character) -> int | None:
    """Face vertices near the mouth that ``jawOpen + mouthClose`` = 1 puts inside the teeth (inside the convex
    hull of the upper or of the lower teeth, each moved by its own mesh's shapes) and that were not inside at
    rest; None when the character has no teeth or not both shapes."""
    from scipy.spatial import Delaunay

    jo, mc = shape_delta(character, "jawOpen"), shape_delta(character, "mouthClose")
    if jo is None or mc is None:
        return None
    mi, V, skin, lm, size, teeth = _mouth_parts(character)
    teeth = [p for p in teeth if len(p.vertices) >= 8]
    if not teeth:
        return None
    near = np.flatnonzero(skin & (np.linalg.norm(V - lm[60:68].mean(0), axis=1) < 0.4 * size))
    X0, X1 = V[near], V[near] + (jo + mc)[near]
    count = 0
    for p in teeth:
        P = character.meshes[p.mesh].mesh.vertices[p.vertices].astype(np.float64)
        dj, dm = shape_delta(character, "jawOpen", p.mesh), shape_delta(character, "mouthClose", p.mesh)
        P1 = P + (0 if dj is None else dj[p.vertices]) + (0 if dm is None else dm[p.vertices])
        try:
            h0, h1 = Delaunay(P), Delaunay(P1)
        except Exception:  # a flat piece has no volume to be inside of
            continue
        count += int(((h1.find_simplex(X1) >= 0) & (h0.find_simplex(X0) < 0)).sum())
    return count


def teeth_showing_px(character: Character, names=("jawOpen", "mouthFunnel", "mouthLowerDownLeft",
                                                    "mouthLowerDownRight"), size_px: int = 400) -> int | None:
    """What a viewer sees of teeth and tongue where lips or skin should hide them: pixels of the teeth's and
    tongue's own pieces seen outside the mouth opening (the inner-lip landmarks' polygon at the shape, with 15 %
    and 2 px of slack) in a front view of the mouth ``size_px`` wide (1.2 outer-eye-corner distances), summed
    over ``names``; None without teeth pieces or without any of the shapes."""
    from matplotlib.path import Path as MPath

    from ..render import look_at, render_scene

    mi, V, skin, lm, size, parts = _mouth_parts(character)
    F = character_frame(character)
    names = [n for n in names if shape_delta(character, n) is not None]
    if not parts or not names:
        return None
    cam = look_at(lm[48:68].mean(axis=0), F[2], F[1], 1.2 * size, (size_px, size_px))
    in_part = {}
    for p in parts:
        tris = character.meshes[p.mesh].mesh.triangles()
        prev = in_part.get(p.mesh, np.zeros(len(tris), bool))
        in_part[p.mesh] = prev | np.isin(tris, p.vertices).all(axis=1)
    total = 0
    for name in names:
        verts = []
        for i, sm in enumerate(character.meshes):
            d = shape_delta(character, name, i)
            verts.append(sm.mesh.vertices + (0 if d is None else d))
        r = render_scene(character.meshes, cam, vertices=verts, textures=False)
        tooth = np.zeros(r.mesh.shape, bool)
        for mesh, inside_tri in in_part.items():
            sel = r.mesh == mesh
            tooth[sel] = inside_tri[r.triangle[sel]]
        poly = cam.project(character.landmarks.positions(verts[mi])[60:68])[:, :2]
        c = poly.mean(axis=0)
        poly = c + (poly - c) * 1.15 + np.sign(poly - c) * 2.0
        yy, xx = np.nonzero(tooth)
        if len(xx):
            total += int((~MPath(poly).contains_points(np.c_[xx + 0.5, yy + 0.5])).sum())
    return total


def shape_metrics(character: Character, eyes="auto") -> dict:
    """``blink_gap_pct``, ``lid_inside_eye``, ``lip_gap_pct``, ``lips_in_teeth``, ``teeth_showing_px``,
    ``inverted_triangles``, ``mirror_err_pct`` (``eyes="auto"``: :func:`eye_parts`)."""
    if isinstance(eyes, str):
        eyes = eye_parts(character)
    bg, inside = blink_gap_pct(character, eyes)
    return {"blink_gap_pct": bg, "lid_inside_eye": inside, "lip_gap_pct": lip_gap_pct(character),
            "lips_in_teeth": lips_in_teeth(character), "teeth_showing_px": teeth_showing_px(character),
            "inverted_triangles": inverted_triangles(character), "mirror_err_pct": mirror_err_pct(character)}
