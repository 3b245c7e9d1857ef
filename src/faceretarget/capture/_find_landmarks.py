"""A character's 68 landmarks found automatically: render its neutral head, find the face, pick the surface.

No hand-made landmark file: :func:`find_landmarks`

1. frames the face: the vertices of the face mesh that its shapes move (the face region, whatever else
   the mesh holds: a whole body, a neck), centred in a square of twice their extent;
2. finds the front: the file's own convention first where it has one (a VRM), else each of the four
   directions across the up axis (and, when the file's up is unknown, both common up axes), rendering
   the character as it looks (:func:`faceretarget.render.render_scene`: every mesh, textures) and
   keeping the view in which MediaPipe's Face Landmarker finds a face most frontally;
3. zooms on the face found (a second, larger render centred on it) and runs the landmarker again;
4. takes the 68 Multi-PIE points of its 478 (:data:`CHARACTER_68`) and puts each on the face mesh's
   surface under it (a render of the face mesh alone, so hair or eyeballs of other meshes never get a
   landmark): a triangle and barycentric coordinates, not a vertex, so a low-poly lip corner lands where the
   corner is; a point just past the silhouette (the jaw line seen from the front) takes the nearest surface
   pixel;
5. corrects what one frontal pick gets wrong: the inner lips onto the right lip (:func:`_separate_lips`),
   points that fell through a hole of the face onto its front surface (:func:`_front_surface`), the jaw line
   onto the face mesh's own edge when the mesh is cut along it (a mask: :func:`_jaw_onto_edge`), and lid
   points that fell into the eye's opening (onto an eyeball of the same mesh, through it, or onto nothing)
   onto the lid's rim (:func:`_lids_on_rim`).

It returns the points and what it saw (:class:`LandmarkSearch`: the views tried, the chosen front, the
final render with the 68 points for a check picture).  A face the landmarker cannot find in any view
(a robot, an animal) is a :class:`~faceretarget.errors.FaceNotFoundError` saying what was tried.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from ..character import Character, SurfacePoints
from ..errors import FaceNotFoundError
from ..render import look_at, pick, render_scene
from ._points import MEDIAPIPE_68

__all__ = ["find_landmarks", "LandmarkSearch", "face_region", "face_pitch", "CHARACTER_68", "FINDER_VERSION"]

#: The version of what :func:`find_landmarks` does.  The landmark cache searches a character again when its
#: cached landmarks were found by another version (:mod:`faceretarget.characters`).  2 (issue 34): the jaw
#: line onto a mask's edge, lid points out of the eye's opening onto the lids.  3: a head the file holds turned
#: or nodding is looked at again, square to the face (:mod:`faceretarget.characters`' ``_frame``).  4: a face
#: mesh wound inside out is drawn from both sides (it was found from behind, left and right swapped).
FINDER_VERSION = 4


@dataclass(eq=False)
class LandmarkSearch:
    """What :func:`find_landmarks` tried and saw.

    Attributes
    ----------
    landmarks : SurfacePoints
    up, front : (3,) float
        The character's up and facing directions found.
    views : list of dict
        Per view tried: ``up``, ``front``, ``found`` (bool), ``frontal`` (0..1, how squarely the face
        looked at the camera).
    image : (H, W, 3) uint8
        The final render.
    points : (68, 2) float
        The 68 points in it (pixels).
    snapped : (68,) float
        Pixels each point moved to reach the face surface (0 over the surface).
    seconds : float
    camera : Camera
        The final render's camera.
    depth : (68,) float
        The landmarker's relative depth of each point (pixels, smaller nearer the camera).
    pose : (4, 4) float or None
        The landmarker's facial transformation matrix on the final render (its canonical face in the
        camera's frame: :func:`face_pitch` reads how far the face looks down in it).
    """

    landmarks: SurfacePoints
    up: np.ndarray
    front: np.ndarray
    views: list = field(default_factory=list)
    image: np.ndarray | None = None
    points: np.ndarray | None = None
    snapped: np.ndarray | None = None
    seconds: float = 0.0
    camera: object = None
    depth: np.ndarray | None = None
    pose: np.ndarray | None = None


def face_pitch(pose: np.ndarray) -> float:
    """Degrees the landmarker's face looks down (+) or up (-) in its camera's frame, from a facial
    transformation matrix (the X angle of its rotation as intrinsic Y-X-Z angles, scale removed)."""
    from scipy.spatial.transform import Rotation

    M = np.asarray(pose, dtype=np.float64)[:3, :3]
    M = M / np.cbrt(np.linalg.det(M))
    return float(Rotation.from_matrix(M).as_euler("YXZ", degrees=True)[1])


def face_region(character: Character, mesh: int | None = None) -> np.ndarray:
    """``(N, 3)`` rest positions of the face mesh's vertices its shapes move (more than 5 % of the most
    any vertex moves); all its vertices when too few move."""
    mi = character.primary if mesh is None else mesh
    m = character.meshes[mi]
    if m.n_shapes:
        mv = np.sqrt(m.vertex_motion2().max(axis=0))
        sel = mv > 0.05 * mv.max() if mv.max() > 0 else np.zeros(len(mv), bool)
        if sel.sum() >= 20:
            return m.mesh.vertices[sel]
    return head_part(character, m.mesh.vertices)


def head_part(character: Character, V: np.ndarray) -> np.ndarray:
    """The vertices of a mesh without face shapes that make its head: those near the head joint and
    above the neck joint when the skeleton has them; else, for a tall mesh (a whole figure, taller than
    twice its width), its top eighth along the up direction; else all of them."""
    up = np.array([0.0, 1.0, 0.0]) if character.up is None else np.asarray(character.up, dtype=np.float64)
    up = up / np.linalg.norm(up)
    head, neck = character.joint("head"), character.joint("neck")
    if head is not None:
        h = V @ up
        ref = neck.position if neck is not None else head.position
        r = 2.5 * float(np.linalg.norm(head.position - neck.position)) if neck is not None else 0.0
        r = max(r, 0.15)
        sel = (np.linalg.norm(V - head.position, axis=1) < r) & (h >= float(ref @ up))
        if sel.sum() >= 20:
            return V[sel]
    h = V @ up
    height = float(np.ptp(h))
    flat = V - np.outer(h, up)
    width = float(np.ptp(flat, axis=0).max())
    if height > 2.0 * width:
        sel = h >= h.max() - 0.125 * height
        if sel.sum() >= 20:
            return V[sel]
    return V


def _candidates(character: Character) -> list[tuple[np.ndarray, np.ndarray]]:
    ups = [np.asarray(character.up, float)] if character.up is not None else [np.array([0.0, 1.0, 0.0]),
                                                                               np.array([0.0, 0.0, 1.0])]
    out = []
    for up in ups:
        up = up / np.linalg.norm(up)
        a = np.array([0.0, 0.0, 1.0]) if abs(up[2]) < 0.9 else np.array([0.0, -1.0, 0.0])
        a = a - up * (a @ up)
        a /= np.linalg.norm(a)
        b = np.cross(up, a)
        fronts = [a, -a, b, -b]
        if character.front is not None:
            f = np.asarray(character.front, float)
            fronts = [f] + [x for x in fronts if not np.allclose(x, f)]
        out += [(up, f) for f in fronts]
    return out


def _frontal(px: np.ndarray) -> float:
    """How squarely a found face looks at the camera (1 frontal, 0 in profile): the balance of the two
    eyes' outer corners about the nose bridge."""
    p = px[CHARACTER_68]
    left = np.linalg.norm(p[45, :2] - p[27, :2])
    right = np.linalg.norm(p[36, :2] - p[27, :2])
    return float(min(left, right) / max(left, right, 1e-9))


#: The 68 points on a character's render: :data:`~faceretarget.capture.MEDIAPIPE_68` but for the jaw line's
#: ends (0, 16: MediaPipe's 127 / 356 instead of 162 / 389) and the brows' outer ends (17, 26: 70 / 300, the
#: upper brow edge, instead of 71 / 301).  On renders of four faces with independently made Multi-PIE
#: landmarks (ICT-FaceKit, the ARKit face, the two demo characters) these lay nearer the reference on every
#: face, by 3-15 % of the eye-corner distance; tracking a video keeps MEDIAPIPE_68 (there the other four
#: gave 2-4 % larger landmark-fit residuals on ict-face and arkit-face), and since the solve works on each
#: point's motion, a few millimetres between the two conventions at rest do not matter to it.
CHARACTER_68 = MEDIAPIPE_68.copy()
CHARACTER_68[[0, 16, 17, 26]] = [127, 356, 70, 300]
#: Inner-lip points on the upper lip and on the lower lip, with the outer-lip middle that tells each lip.
_UPPER_INNER, _LOWER_INNER, _UPPER_REF, _LOWER_REF = (61, 62, 63), (65, 66, 67), 51, 57


def _separate_lips(character: Character, prim: int, alone, pts: np.ndarray, tris: np.ndarray, bary: np.ndarray,
                   radius: int) -> None:
    """Put the inner-lip points of a closed mouth on the right lip.

    At rest the lips touch and the landmarker puts the upper and the lower inner-lip points on the same
    line, so the surface under them may be either lip.  Each surface point is told upper or lower lip by
    how it moves over all the face's shapes (its motion correlated with that of the outer upper-lip
    middle, point 51, or of the outer lower-lip middle, point 57), and an inner point on the wrong lip
    moves to the nearest pixel of the right one (within ``radius``).  Changes ``tris`` and ``bary``.
    """
    m = character.meshes[prim]
    if m.n_shapes == 0:
        return
    D = m.deltas.astype(np.float64).transpose(1, 0, 2).reshape(m.mesh.n_vertices, -1)     # (V, 3K)

    def sig(tv, bw):
        return np.einsum("...k,...kd->...d", bw, D[tv])

    up, lo = sig(tris[_UPPER_REF], bary[_UPPER_REF]), sig(tris[_LOWER_REF], bary[_LOWER_REF])
    if np.linalg.norm(up - lo) < 1e-9 * max(np.linalg.norm(up), np.linalg.norm(lo), 1e-12):
        return

    def lower_score(S):                     # > 0: moves like the lower lip
        S = np.atleast_2d(S)
        n = np.linalg.norm(S, axis=1) + 1e-12
        return (S @ lo) / (n * np.linalg.norm(lo) + 1e-12) - (S @ up) / (n * np.linalg.norm(up) + 1e-12)

    faces = m.mesh.triangles()
    ys, xs = np.nonzero(alone.mesh == prim)
    if not len(xs):
        return
    tri_at = alone.triangle[ys, xs]
    proj = alone.camera.project(m.mesh.vertices)
    for group, want_lower in ((_UPPER_INNER, False), (_LOWER_INNER, True)):
        for k in group:
            if tris[k, 0] < 0:
                continue
            if (lower_score(sig(tris[k], bary[k]))[0] > 0) == want_lower:
                continue
            x, y = pts[k]
            near = np.flatnonzero((xs - x) ** 2 + (ys - y) ** 2 <= radius ** 2)
            if not near.size:
                continue
            cand_t = tri_at[near]
            ut, inv = np.unique(cand_t, return_inverse=True)
            sc = lower_score(D[faces[ut]].mean(axis=1))
            ok = (sc > 0) if want_lower else (sc < 0)
            good = near[ok[inv]]
            if not good.size:
                continue
            j = good[np.argmin((xs[good] - x) ** 2 + (ys[good] - y) ** 2)]
            from ..render import barycentric_2d

            tv = faces[tri_at[j]]
            tris[k] = tv
            bary[k] = barycentric_2d(proj[tv, :2], np.array([xs[j], ys[j]], dtype=np.float64))


def _front_surface(character: Character, prim: int, alone, pts: np.ndarray, tris: np.ndarray, bary: np.ndarray,
                   front: np.ndarray, radius: int) -> None:
    """Move a point that fell through a hole of the face (an eye socket or the mouth of a head whose eyes
    and teeth are other meshes: the render of the face mesh alone shows the inside of the back of the head
    there) to the nearest pixel of the face's front surface.  A point is through a hole when it lies
    further behind the others' median depth than half the face's width.  Changes ``tris`` and ``bary``."""
    limit = _front_limit(character, prim, tris, bary, front)
    if limit is None:
        return
    V = character.meshes[prim].mesh.vertices
    f = np.asarray(front, dtype=np.float64)
    ok = tris[:, 0] >= 0
    depth = np.full(len(tris), np.nan)
    depth[ok] = np.einsum("pk,pkd->pd", bary[ok], V[tris[ok]]) @ f
    bad = np.flatnonzero(ok & (depth < limit))
    if not len(bad):
        return
    faces = character.meshes[prim].mesh.triangles()
    ys, xs = np.nonzero(alone.mesh == prim)
    tri_at = alone.triangle[ys, xs]
    tdepth = V[faces[tri_at]].mean(axis=1) @ f
    good_px = tdepth >= limit
    proj = alone.camera.project(V)
    from ..render import barycentric_2d

    for k in bad:
        x, y = pts[k]
        dd = (xs - x) ** 2 + (ys - y) ** 2
        cand = np.flatnonzero(good_px & (dd <= radius ** 2))
        if not len(cand):
            continue
        j = cand[np.argmin(dd[cand])]
        tv = faces[tri_at[j]]
        tris[k] = tv
        bary[k] = barycentric_2d(proj[tv, :2], np.array([xs[j], ys[j]], dtype=np.float64))


def _front_limit(character: Character, prim: int, tris: np.ndarray, bary: np.ndarray, front) -> float | None:
    """The depth (along ``front``) behind which a surface is not the face's front but seen through a hole of it:
    half the face's width behind the inner points' median depth (None with fewer than 20 points picked)."""
    ok = tris[:, 0] >= 0
    if ok.sum() < 20:
        return None
    V = character.meshes[prim].mesh.vertices
    P = np.einsum("pk,pkd->pd", bary[ok], V[tris[ok]])
    depth = np.full(len(tris), np.nan)
    depth[ok] = P @ np.asarray(front, dtype=np.float64)
    return float(np.nanmedian(depth[17:68])) - 0.5 * float(np.ptp(P, axis=0).max())


def _welded(V: np.ndarray) -> np.ndarray:
    """Each vertex's index among the distinct positions: the copies an exporter makes along UV and normal seams
    (which split one surface into pieces) count as one vertex."""
    scale = float(np.ptp(V, axis=0).max()) if len(V) else 0.0
    key = np.round(np.asarray(V, np.float64) / (1e-7 * (scale or 1.0))).astype(np.int64)
    return np.unique(key, axis=0, return_inverse=True)[1].reshape(-1)


def _open_edges(faces: np.ndarray, welded: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The mesh's open edges (of one triangle only, seams welded): ``(E, 2)`` vertex pairs and the triangle of each."""
    E = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    tri = np.tile(np.arange(len(faces)), 3)
    ends = np.sort(welded[E], axis=1)
    _, inv, cnt = np.unique(ends[:, 0] * (int(welded.max()) + 1) + ends[:, 1], return_inverse=True,
                            return_counts=True)
    one = (cnt[inv.reshape(-1)] == 1) & (ends[:, 0] != ends[:, 1])
    return E[one], tri[one]


def _jaw_onto_edge(character: Character, prim: int, alone, pts: np.ndarray, tris: np.ndarray,
                   bary: np.ndarray) -> bool:
    """Put the jaw line on the face mesh's own edge when the mesh is cut along it (a mask).

    A face mesh that ends at the face's outline (ARKit's face mesh, MediaPipe's own, a face scan) has its open
    edge where the Multi-PIE contour is, and a frontal render shows the surface in front of it steeply turned
    away: the landmarker's point a few pixels inside the outline lands up to 20 % of the eye-corner distance
    forward of the edge (arkit-face: 17.9 % on average, nearly all of it depth).  When the part of the open edge
    on the render's outline lies within 10 % of the eye-corner distance of every one of the 17 jaw points (the
    landmarker's own error along the contour is up to about that; arkit-face: all within 7.5 %), each goes onto
    its nearest point of that edge: MediaPipe's own face oval is its canonical mesh's edge.  A whole head, or a
    face mesh that goes on past the jaw (a neck, a mask cut well below the chin: the demo faces' edge is 20-51 %
    from their chin points), is left as picked.  Changes ``tris`` and ``bary``; True when it moved them.
    """
    from scipy.ndimage import binary_fill_holes, distance_transform_edt
    from scipy.spatial import cKDTree

    m = character.meshes[prim].mesh
    faces = m.triangles()
    E, Et = _open_edges(faces, _welded(m.vertices))
    if not len(E):
        return False
    jaw = pts[:17]
    reach = 0.10 * float(np.linalg.norm(pts[36] - pts[45]))
    proj = alone.camera.project(m.vertices)[:, :2]
    a, b = proj[E[:, 0]], proj[E[:, 1]]
    lo, hi = jaw.min(axis=0) - reach, jaw.max(axis=0) + reach
    near = np.flatnonzero((np.minimum(a, b) <= hi).all(axis=1) & (np.maximum(a, b) >= lo).all(axis=1))
    if not len(near):
        return False
    n = np.clip(np.ceil(np.linalg.norm(b[near] - a[near], axis=1)).astype(np.int64), 1, 256)   # a sample a pixel
    edge = np.repeat(near, n + 1)
    first = np.repeat(np.cumsum(n + 1) - (n + 1), n + 1)
    t = (np.arange(len(edge)) - first) / np.repeat(n, n + 1)
    xy = a[edge] + t[:, None] * (b[edge] - a[edge])
    H, W = alone.mesh.shape
    ix, iy = np.round(xy[:, 0]).astype(np.int64), np.round(xy[:, 1]).astype(np.int64)
    inside = (ix >= 0) & (ix < W) & (iy >= 0) & (iy < H)
    # the outline: pixels of the face (its holes filled: eyes, mouth) next to the background
    to_background = distance_transform_edt(binary_fill_holes(alone.mesh == prim))
    outer = np.zeros(len(xy), bool)
    outer[inside] = to_background[iy[inside], ix[inside]] <= 1.5
    if not outer.any():
        return False
    edge, t, xy = edge[outer], t[outer], xy[outer]
    d, j = cKDTree(xy).query(jaw)
    if not (d <= reach).all():
        return False
    for k in range(17):
        e = edge[j[k]]
        tv = faces[Et[e]]
        w = np.zeros(3)
        w[int(np.flatnonzero(tv == E[e, 0])[0])] += 1.0 - t[j[k]]
        w[int(np.flatnonzero(tv == E[e, 1])[0])] += t[j[k]]
        tris[k], bary[k] = tv, w
    return True


#: Per eye: its corners, its upper-lid and its lower-lid points.
_EYES = ((36, 39, (37, 38), (40, 41)), (42, 45, (43, 44), (46, 47)))


def _lids_on_rim(character: Character, prim: int, alone, pts: np.ndarray, tris: np.ndarray, bary: np.ndarray,
                 front: np.ndarray) -> list[int]:
    """Put lid points that fell into the eye's opening on the lid's rim.

    The render of the face mesh alone shows, inside an eye's opening, an eyeball that is part of the same mesh
    (Rocketbox: the eyeballs are pieces of the one body mesh), the inside of the back of the head, or nothing;
    the landmarker, which on an untextured render sees no iris, may put the lid points well inside the
    opening.  A lid point whose pixel is not the face's skin (the piece of the mesh, seams welded, that holds
    most of the brow, nose and outer-lip points) in front (:func:`_front_limit`) goes to the first skin pixel
    straight across the line of the eye's corners from it, toward the brows for the upper lid and away from
    them for the lower (within the eye's width): a point nearer the other lid never takes that one, and each
    upper lid point keeps facing its lower one (37-41, 38-40), which a generated blink pins together (the
    nearest skin pixel on the lid's side slid them apart along the rim: arkit-face's generated blink then
    left 11 % of the gap open, 4 % this way, 5 % before).  A corner in the opening goes to the nearest skin
    pixel.  Changes ``tris`` and ``bary``; returns the points moved.
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    from ..render import barycentric_2d

    limit = _front_limit(character, prim, tris, bary, front)
    if limit is None:
        return []
    m = character.meshes[prim].mesh
    faces = m.triangles()
    w = _welded(m.vertices)
    nw = int(w.max()) + 1
    e = w[np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]]])]
    piece = connected_components(coo_matrix((np.ones(len(e)), (e[:, 0], e[:, 1])), shape=(nw, nw)),
                                 directed=False)[1][w]
    held = [k for k in (*range(17, 36), *range(48, 60)) if tris[k, 0] >= 0]
    if not held:
        return []
    skin_piece = np.bincount(piece[tris[held, 0]]).argmax()
    skin_tri = (piece[faces[:, 0]] == skin_piece) & (m.vertices[faces].mean(axis=1) @ np.asarray(front, float)
                                                     >= limit)
    on = alone.mesh == prim
    skin = np.zeros(on.shape, bool)
    skin[on] = skin_tri[alone.triangle[on]]
    H, W = skin.shape
    proj = alone.camera.project(m.vertices)

    def at(q):
        ix, iy = int(round(q[0])), int(round(q[1]))
        return (ix, iy) if 0 <= ix < W and 0 <= iy < H and skin[iy, ix] else None

    def put(k, q, pix):
        tv = faces[alone.triangle[pix[1], pix[0]]]
        tris[k], bary[k] = tv, barycentric_2d(proj[tv, :2], np.asarray(q, np.float64))

    moved = []
    ys, xs = np.nonzero(skin)
    brows = pts[17:27].mean(axis=0)
    for c0, c1, upper, lower in _EYES:
        axis = pts[c1] - pts[c0]
        width = float(np.linalg.norm(axis))
        if width < 1.0:
            continue
        up = np.array([axis[1], -axis[0]]) / width
        if (brows - (pts[c0] + pts[c1]) / 2.0) @ up < 0:
            up = -up
        steps = np.arange(0.25, width, 0.25)[:, None] * up
        for group, sign in ((upper, 1.0), (lower, -1.0)):
            for k in group:
                if at(pts[k]) is not None:
                    continue
                for q in pts[k] + sign * steps:
                    pix = at(q)
                    if pix is not None:
                        put(k, q, pix)
                        moved.append(k)
                        break
        for k in (c0, c1):
            if at(pts[k]) is not None or not len(xs):
                continue
            dd = (xs - pts[k][0]) ** 2 + (ys - pts[k][1]) ** 2
            j = int(np.argmin(dd))
            if dd[j] <= (0.25 * width) ** 2:
                put(k, (xs[j], ys[j]), (xs[j], ys[j]))
                moved.append(k)
    return sorted(moved)


#: Landmarks on the skin whatever hair or eyes a head has: the jaw line, the nose, the outer lips.
_SKIN_POINTS = np.r_[0:17, 27:36, 48:60]


def _face_under(character: Character, prim: int, seen, px: np.ndarray, log) -> int:
    """The mesh the tracker found the face on, for a character with no face shapes: the mesh seen under most
    of the skin landmarks (``seen``, the render they were found on), when it is not ``prim`` (the head mesh
    guessed as the one with most vertices in the head: a dense hair mesh, as on a VRoid avatar, outnumbers the
    face) and holds at least half of them; then it is made the character's
    :attr:`~faceretarget.character.Character.neutral_head`."""
    H, W = seen.mesh.shape
    p = np.rint(px[CHARACTER_68][_SKIN_POINTS, :2]).astype(int)
    inside = (p[:, 0] >= 0) & (p[:, 0] < W) & (p[:, 1] >= 0) & (p[:, 1] < H)
    ids = seen.mesh[p[inside, 1], p[inside, 0]]
    ids = ids[ids >= 0]
    if not len(ids):
        return prim
    counts = np.bincount(ids, minlength=len(character.meshes))
    face = int(np.argmax(counts))
    if face == prim or counts[face] < len(_SKIN_POINTS) / 2 or counts[face] <= counts[prim]:
        return prim
    log(f"landmarks: the face is on '{character.meshes[face].name}' ({int(counts[face])} of "
        f"{len(_SKIN_POINTS)} skin points), not on '{character.meshes[prim].name}' (the mesh with most vertices "
        "in the head): the head mesh is now it")
    character.neutral_head = face
    return face


def find_landmarks(character: Character, *, tracker=None, size: int = 512, log=None) -> LandmarkSearch:
    """Find the character's 68 landmarks on a render of its neutral face (module docstring).

    Parameters
    ----------
    character : Character
        With face shapes (its :attr:`~faceretarget.character.Character.primary` mesh gets the points).
    tracker : FaceTracker, optional
        A MediaPipe tracker in image mode (made here when None).
    size : int
        Pixels across the final render.

    Raises
    ------
    FaceNotFoundError
        No view shows a face the landmarker finds.
    """
    from ._tracker import FaceTracker

    t0 = time.perf_counter()
    log = log or (lambda *_: None)
    prim = character.primary
    region = face_region(character, prim)
    lo, hi = region.min(axis=0), region.max(axis=0)
    centre = (lo + hi) / 2.0
    extent = float((hi - lo).max())
    # a face mesh wound inside out shows, single-sided, only the inside of its back from the front, and from
    # behind the hollow of its face, mirrored (left and right swapped): looked at from both sides
    both = [prim] if character.meshes[prim].mesh.winds_inward() else []
    if both:
        log(f"landmarks: the triangles of '{character.meshes[prim].name}' wind inward (its normals point into "
            "the head, as from an inside-out export): drawn from both sides to look for the face")
    own = tracker is None
    tr = FaceTracker(images=True, min_detection=0.3, min_presence=0.3) if own else tracker
    try:
        views = []
        images = []
        best = None
        for up, front in _candidates(character):
            cam = look_at(centre, front, up, 2.0 * extent, (320, 320))
            seen = render_scene(character.meshes, cam, both_sides=both)
            img = seen.image
            images.append(img)
            r = tr.track(img, 0.0)
            v = {"up": up.tolist(), "front": front.tolist(), "found": r is not None,
                 "frontal": None if r is None else _frontal(r[0])}
            views.append(v)
            log(f"landmarks: view {len(views)} from {np.round(front, 2).tolist()}: "
                + ("no face" if r is None else f"a face, {v['frontal']:.0%} frontal")
                + f" ({time.perf_counter() - t0:.1f} s)")
            if r is not None and (best is None or v["frontal"] > best[0]):
                best = (v["frontal"], up, front, r[0], cam, seen, r[2])
            if r is not None and v["frontal"] > (0.6 if character.front is not None
                                                 and np.allclose(front, character.front) else 0.85):
                break                                    # a face seen squarely: the other sides can only be worse
        if best is None:
            err = FaceNotFoundError(
                f"{character.path or character.name}: no face found on renders of '{character.meshes[prim].name}' "
                f"from {len(views)} directions; give the 68 landmarks with --landmarks FILE (see "
                "'faceretarget character inspect FILE --out check.png' for what was rendered)", views=views)
            err.images = images
            raise err
        _, up, front, px, cam, seen, pose = best
        if not character.face_meshes() and not character.face_filter:     # the head mesh was a guess
            prim = _face_under(character, prim, seen, px, log)
            both = [prim] if character.meshes[prim].mesh.winds_inward() else []
        # zoom on the face found and look again
        p = px[CHARACTER_68]
        mid = (p[:, :2].min(axis=0) + p[:, :2].max(axis=0)) / 2.0
        width_px = float(np.ptp(p[:, 0]))
        R = cam.rotation
        W, H = cam.size
        off = np.array([(mid[0] - W / 2.0) / cam.scale, -(mid[1] - H / 2.0) / cam.scale, 0.0])
        centre2 = cam.center + R.T @ off
        width2 = 1.9 * width_px / cam.scale
        cam2 = look_at(centre2, front, up, width2, (size, size))
        img2 = render_scene(character.meshes, cam2, both_sides=both).image
        r2 = tr.track(img2, 0.0)
        if r2 is None:                                   # the zoom lost it: keep the first view's points
            cam2, img2, px2 = cam, render_scene(character.meshes, cam, both_sides=both).image, px
        else:
            px2, pose = r2[0], r2[2]
        pts = px2[CHARACTER_68, :2]
        alone = render_scene(character.meshes, cam2, only=[prim], textures=False, both_sides=both)
        tris, bary, dist = pick(alone, character.meshes, pts, prim, radius=max(6, size // 40))
        _separate_lips(character, prim, alone, pts, tris, bary, radius=max(4, size // 40))
        _front_surface(character, prim, alone, pts, tris, bary, front, radius=max(8, size // 25))
        if _jaw_onto_edge(character, prim, alone, pts, tris, bary):
            log("landmarks: the face mesh ends along the jaw line (a mask): the jaw line put on its edge")
        lids = _lids_on_rim(character, prim, alone, pts, tris, bary, front)
        if lids:
            log(f"landmarks: {', '.join(map(str, lids))} fell into the eye's opening: put on the lid's rim")
        if (tris < 0).any():
            bad = np.flatnonzero((tris < 0).any(axis=1))
            raise FaceNotFoundError(
                f"{character.path or character.name}: {len(bad)} of the 68 landmarks found on the render (e.g. "
                f"{int(bad[0])}) are not over the face mesh '{character.meshes[prim].name}'; give them with "
                "--landmarks FILE", views=views)
        log(f"landmarks: face found facing {np.round(front, 3).tolist()} (up {np.round(up, 3).tolist()}), "
            f"{len(views)} view(s) tried, {int((dist > 0).sum())} of 68 snapped to the surface")
        return LandmarkSearch(SurfacePoints(prim, tris, bary, "found on a render"), up, front, views, img2, pts,
                              dist, time.perf_counter() - t0, cam2, px2[CHARACTER_68, 2], pose)
    finally:
        if own:
            tr.close()
