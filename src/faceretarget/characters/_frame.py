"""The face's own frame, when the file holds the head turned.

A character's head frame (:func:`~faceretarget.character.character_frame`: +Y up, +Z out of the face, +X the
character's left) comes from the file's axes and the direction the landmark search found the face from, one of
four views along them.  A head modelled or scanned turned (25 degrees of yaw, 15 of roll) keeps that axis
frame, and everything that works in the head frame goes wrong with it: the face's symmetry plane is not found
(no mirror-image shapes), the generated blinks stay 32 % open, the lips are told apart along a tilted line.

:func:`face_turn` finds the face's symmetry plane on its skin (the mirror image of the face about the plane
lands on the face: the mean distance, capped, minimised over the plane's normal and offset, started from the
left-right landmark pairs) and, when the face is that symmetric and the plane's normal is more than
:data:`FACE_TURN_DEG` off the file's left-right axis, turns the character's ``up`` and ``front`` to the face:
left-right the plane's normal, up the file's up made square to it (a pitch leaves no trace in a symmetry
plane).  On the shared characters, upright in their files, the plane is within 0.11 degrees of their axes.
"""

from __future__ import annotations

import numpy as np

from ..character import Character, character_frame

__all__ = ["face_turn", "face_pitch_turn", "symmetry_plane", "FACE_TURN_DEG", "FACE_SYMMETRIC_PCT",
           "PITCH_BIAS_DEG", "PITCH_TOLERANCE_DEG"]

#: Degrees between the face's symmetry plane and the file's left-right axis over which the face's own frame is
#: used (the shared characters, upright: 0.00-0.11).
FACE_TURN_DEG = 1.0
#: The face's mean mirror distance (% of the outer-eye-corner distance) up to which its symmetry plane is trusted
#: (the shared characters: 0.0-0.8).
FACE_SYMMETRIC_PCT = 3.0

#: What the landmarker reads as the pitch (degrees, + looking down) of a face held upright in its file, square to
#: the camera: 1.1-5.6 on the seven shared characters, 4.3 their median.
PITCH_BIAS_DEG = 4.0
#: A reading further than this from :data:`PITCH_BIAS_DEG` is a head the file holds pitched (a 17-degree nod read
#: 16.3): the head frame is tipped by the difference.
PITCH_TOLERANCE_DEG = 8.0

#: Left-right landmark pairs of the 68-point scheme (the character's right, left): jaw, brows, nose, eyes, lips.
_PAIRS = ([(i, 16 - i) for i in range(8)] + [(17 + i, 26 - i) for i in range(5)] + [(31, 35), (32, 34)]
          + [(36, 45), (37, 44), (38, 43), (39, 42), (40, 47), (41, 46)]
          + [(48, 54), (49, 53), (50, 52), (59, 55), (58, 56), (60, 64), (61, 63), (67, 65)])


def symmetry_plane(V: np.ndarray, skin: np.ndarray, lm: np.ndarray, up: np.ndarray, *, n_points: int = 1000
                   ) -> tuple[np.ndarray, np.ndarray, float]:
    """The face's symmetry plane: unit normal (3,) toward the character's left, a point on it (3,), and the mean
    distance (% of the outer-eye-corner distance) of the face's mirror image from the face.

    ``V`` (N, 3) the head mesh's vertices, ``skin`` (N,) bool the face's skin, ``lm`` (68, 3) its landmarks,
    ``up`` (3,) the file's up.  The mirror distance of up to ``n_points`` skin points within 1.5 eye-corner
    distances of the face's centre, each capped at a tenth of that distance (a point whose mirror image falls
    off the mesh counts no more), is minimised (Nelder-Mead, from the best of a 7 x 7 grid of normals within
    17 degrees of the landmark pairs' direction)."""
    from scipy.optimize import minimize
    from scipy.spatial import cKDTree

    size = float(np.linalg.norm(lm[36] - lm[45]))
    S = V[skin]
    P = S[np.linalg.norm(S - lm[17:68].mean(axis=0), axis=1) < 1.5 * size]
    if len(P) > n_points:
        P = P[np.random.default_rng(0).choice(len(P), n_points, replace=False)]
    tree = cKDTree(S)
    d = np.array([lm[b] - lm[a] for a, b in _PAIRS])
    x0 = (d / np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-30)).mean(axis=0)
    x0 /= np.linalg.norm(x0)
    c0 = np.array([0.5 * (lm[a] + lm[b]) for a, b in _PAIRS]).mean(axis=0)
    e1 = np.cross(x0, up)
    if np.linalg.norm(e1) < 1e-6:
        e1 = np.cross(x0, [0.0, 0.0, 1.0] if abs(x0[2]) < 0.9 else [1.0, 0.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(x0, e1)
    cap = 0.1 * size

    def plane(p):
        x = x0 + p[0] * e1 + p[1] * e2
        return x / np.linalg.norm(x), c0 + p[2] * size * x0

    def cost(p):
        x, c = plane(p)
        dist, _ = tree.query(P - 2.0 * ((P - c) @ x)[:, None] * x)
        return float(np.minimum(dist, cap).mean()) / size

    grid = [(a, b, 0.0) for a in np.linspace(-0.3, 0.3, 7) for b in np.linspace(-0.3, 0.3, 7)]
    start = min(grid, key=cost)
    res = minimize(cost, start, method="Nelder-Mead", options={"xatol": 1e-5, "fatol": 1e-8, "maxiter": 600})
    x, c = plane(res.x)
    return x, c, 100.0 * float(res.fun)


def face_turn(ch: Character, log=None) -> float | None:
    """Turn ``ch.up`` / ``ch.front`` to the face's own frame when the file holds the head turned (module
    docstring), in place; the degrees it was turned, or None when the file's frame is kept (no landmarks, a
    face not symmetric enough to tell, or one square to the file's axes)."""
    from ..transfer import landmark_skin

    if ch.landmarks is None:
        return None
    lm = ch.landmark_positions()
    if not np.isfinite(lm).all() or np.linalg.norm(lm[36] - lm[45]) < 1e-9:
        return None                                 # landmarks that span nothing tell no plane
    m = ch.meshes[ch.landmarks.mesh].mesh
    V = m.vertices.astype(np.float64)
    F = character_frame(ch)
    x, _, pct = symmetry_plane(V, landmark_skin(ch), lm, F[1])
    deg = float(np.degrees(np.arccos(np.clip(abs(x @ F[0]), -1.0, 1.0))))
    if pct > FACE_SYMMETRIC_PCT or deg <= FACE_TURN_DEG:
        return None
    y = F[1] - (F[1] @ x) * x
    y /= np.linalg.norm(y)
    ch.up, ch.front = y, np.cross(x, y)
    msg = (f"the face is turned {deg:.1f} degrees from the file's axes (its symmetry plane, {pct:.2f} % mirror "
           f"distance): its own frame used, facing {np.round(ch.front, 3).tolist()}")
    ch.notes.append(msg)
    if log is not None:
        log(msg)
    return deg


def face_pitch_turn(ch: Character, pitch: float, log=None) -> float | None:
    """Tip ``ch.up`` / ``ch.front`` about the head frame's left-right axis when the landmarker read the face on a
    render square to that frame as looking ``pitch`` degrees down (+) or up (-), more than
    :data:`PITCH_TOLERANCE_DEG` off what it reads on an upright face (:data:`PITCH_BIAS_DEG`); the degrees
    tipped, or None.  A symmetry plane tells nothing of a pitch (:func:`face_turn`): a head the file holds
    nodding 17 degrees had its lip and jaw landmarks picked from below, the jaw line 22 % of the eye-corner
    distance off where the upright copy's are."""
    off = float(pitch) - PITCH_BIAS_DEG
    if not np.isfinite(off) or abs(off) <= PITCH_TOLERANCE_DEG:
        return None
    F = character_frame(ch)
    t = np.radians(off)
    ch.up = F[1] * np.cos(t) + F[2] * np.sin(t)
    ch.front = F[2] * np.cos(t) - F[1] * np.sin(t)
    msg = (f"the face looks {abs(off):.1f} degrees {'down' if off > 0 else 'up'} in the file's frame (the "
           f"landmarker reads {pitch:.1f}, {PITCH_BIAS_DEG:g} on an upright face): its own frame used, facing "
           f"{np.round(ch.front, 3).tolist()}")
    ch.notes.append(msg)
    if log is not None:
        log(msg)
    return off
