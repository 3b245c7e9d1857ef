"""A character's 68 landmarks found automatically: render its neutral head, find the face, pick the surface.

No hand-made landmark file: :func:`find_landmarks`

1. frames the face: the vertices of the face mesh that its shapes move (the face region, whatever else
   the mesh holds: a whole body, a neck), centred in a square of twice their extent;
2. finds the front: the file's own convention first where it has one (a VRM), else each of the four
   directions across the up axis (and, when the file's up is unknown, both common up axes), rendering
   the character as it looks (:func:`faceretarget.render.render_scene`: every mesh, textures) and
   keeping the view in which MediaPipe's Face Landmarker finds a face most frontally;
3. zooms on the face found (a second, larger render centred on it) and runs the landmarker again;
4. takes the 68 Multi-PIE points of its 478 (:data:`CHARACTER_68`) and puts each
   on the face mesh's surface under it (a render of the face mesh alone, so hair or eyeballs never get
   a landmark): a triangle and barycentric coordinates, not a vertex, so a low-poly lip corner lands
   where the corner is; a point just past the silhouette (the jaw line seen from the front) takes the
   nearest surface pixel.

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

__all__ = ["find_landmarks", "LandmarkSearch", "face_region", "CHARACTER_68"]


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
    ok = tris[:, 0] >= 0
    if ok.sum() < 20:
        return
    V = character.meshes[prim].mesh.vertices
    f = np.asarray(front, dtype=np.float64)
    P = np.einsum("pk,pkd->pd", bary[ok], V[tris[ok]])
    depth = np.full(len(tris), np.nan)
    depth[ok] = P @ f
    inner = np.arange(17, 68)
    med = float(np.nanmedian(depth[inner]))
    width = float(np.ptp(P, axis=0).max())
    bad = np.flatnonzero(ok & (depth < med - 0.5 * width))
    if not len(bad):
        return
    faces = character.meshes[prim].mesh.triangles()
    ys, xs = np.nonzero(alone.mesh == prim)
    tri_at = alone.triangle[ys, xs]
    tdepth = V[faces[tri_at]].mean(axis=1) @ f
    good_px = tdepth >= med - 0.5 * width
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
    own = tracker is None
    tr = FaceTracker(images=True, min_detection=0.3, min_presence=0.3) if own else tracker
    try:
        views = []
        images = []
        best = None
        for up, front in _candidates(character):
            cam = look_at(centre, front, up, 2.0 * extent, (320, 320))
            img = render_scene(character.meshes, cam).image
            images.append(img)
            r = tr.track(img, 0.0)
            v = {"up": up.tolist(), "front": front.tolist(), "found": r is not None,
                 "frontal": None if r is None else _frontal(r[0])}
            views.append(v)
            if r is not None and (best is None or v["frontal"] > best[0]):
                best = (v["frontal"], up, front, r[0], cam)
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
        _, up, front, px, cam = best
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
        img2 = render_scene(character.meshes, cam2).image
        r2 = tr.track(img2, 0.0)
        if r2 is None:                                   # the zoom lost it: keep the first view's points
            cam2, img2, px2 = cam, render_scene(character.meshes, cam).image, px
        else:
            px2 = r2[0]
        pts = px2[CHARACTER_68, :2]
        alone = render_scene(character.meshes, cam2, only=[prim], textures=False)
        tris, bary, dist = pick(alone, character.meshes, pts, prim, radius=max(6, size // 40))
        _separate_lips(character, prim, alone, pts, tris, bary, radius=max(4, size // 40))
        _front_surface(character, prim, alone, pts, tris, bary, front, radius=max(8, size // 25))
        if (tris < 0).any():
            bad = np.flatnonzero((tris < 0).any(axis=1))
            raise FaceNotFoundError(
                f"{character.path or character.name}: {len(bad)} of the 68 landmarks found on the render (e.g. "
                f"{int(bad[0])}) are not over the face mesh '{character.meshes[prim].name}'; give them with "
                "--landmarks FILE", views=views)
        log(f"landmarks: face found facing {np.round(front, 3).tolist()} (up {np.round(up, 3).tolist()}), "
            f"{len(views)} view(s) tried, {int((dist > 0).sum())} of 68 snapped to the surface")
        return LandmarkSearch(SurfacePoints(prim, tris, bary, "found on a render"), up, front, views, img2, pts,
                              dist, time.perf_counter() - t0, cam2, px2[CHARACTER_68, 2])
    finally:
        if own:
            tr.close()
