"""Built-in demo characters and a demo take, so ``make demo`` runs with no data and no downloads.

What these are
--------------
Two *procedural* cartoon faces that faceretarget builds itself from a few dozen numbers each: not
scans, not artist-made rigs, and not anatomically accurate.  They exist so the retargeting pipeline
can be run and looked at end to end on any machine; for real results use a real rig (for example
ICT-FaceKit or an ARKit character).

Each face is a face mask: a curved grid (an elliptical arc per row, narrowing to a chin) whose
height is sculpted with smooth bumps for the brow ridge, eye sockets, cheekbones, nose, lips and
chin.  The grid is cut along the lip line and along each eye line (the cut vertices are doubled),
so the mouth can open and the eyelids can part and close.  Two eyeballs (spherical caps the lids
wrap around) and a tongue behind the lips are separate pieces, so each mesh has four connected
components: skin, two eyeballs, tongue.  Units are centimetres, +Y is up, the face looks toward +Z
and the character's left is +X.  Both faces are exactly left/right symmetric.

* ``make_demo_character("ada")``: 2,797 vertices in 2,612 quads; a narrow tapering jaw and a small
  nose.
* ``make_demo_character("bo")``: 1,888 vertices in 1,737 quads; a wider face and heavier jaw, a
  bigger nose, a wider mouth and a broader, stronger smile.  Its grid is coarser and its vertices
  are numbered differently (eyes and tongue first, then the skin column by column), so nothing about
  vertex order carries over between the two.

Both carry all 52 ARKit shapes (:data:`faceretarget.names.ARKIT_NAMES`) as smooth, localised
displacement fields defined from anatomical anchor points: the jaw rotates about a hinge axis in
front of the ears for ``jawOpen`` (``mouthClose`` undoes it on the lips), the upper lid slides down
over the eyeball for ``eyeBlink*``, the eyeballs turn for ``eyeLook*``, the mouth corners go up and
out for ``mouthSmile*``, the tongue slides out for ``tongueOut``, and so on; amplitudes are 0.15 to
2.7 cm.  ``Left`` is always the character's left (+X); every Left/Right pair (and ``jawLeft`` /
``jawRight``, ``mouthLeft`` / ``mouthRight``) is an exact mirror image.  ``landmarks`` holds 68
vertex indices at the Multi-PIE 68 landmark positions (jaw line 0-16, brows 17-26, nose 27-35,
eyes 36-47, outer lips 48-59, inner lips 60-67; points 0-7, 17-21 and 36-41 are on the character's
right, the image left of a front view).  :func:`demo_vertex_colors` gives preview colours (skin,
lips, eye whites with irises and pupils, tongue) for :func:`faceretarget.render.render_mesh`.

``make_demo_take()`` is a synthetic, seeded take of ARKit weight curves (speech-like jaw and lip
motion, blinks, a smile, a brow raise, small gaze shifts), not a capture.

Examples
--------
>>> ada = make_demo_character("ada")
>>> ada.n_shapes, ada.unit, len(ada.landmarks)
(52, 'cm', 68)
>>> take = make_demo_take(seconds=2.0, fps=30)
>>> take.weights.shape
(60, 52)
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from ..errors import InvalidDataError
from ..mesh import Mesh
from ..names import ARKIT_NAMES
from ..numerics import smoothstep
from ..performance import Performance
from ..rig import Rig

__all__ = ["DEMO_CHARACTERS", "make_demo_character", "demo_vertex_colors", "make_demo_take"]


# ---------------------------------------------------------------------- styles
@dataclass(frozen=True)
class _Style:
    """The numbers that make one demo character (centimetres)."""

    name: str
    ncols: int  # odd: the grid has a centre column
    nrows: int
    skin_order: str  # "row" or "col": how skin vertices are numbered
    extras_first: bool  # number eyeballs and tongue before the skin
    half_width: float  # half the face width at the cheekbones
    jaw_ratio: float  # chin width / cheek width
    y_top: float
    y_eye: float
    y_brow: float
    y_nose_tip: float
    y_nose_base: float
    y_mouth: float
    y_chin: float
    y_bottom: float
    eye_x: float  # eye centre |x|
    eye_half: float  # half the eye opening's width
    eye_up: float  # how far the upper lid edge sits above the eye line
    eye_down: float  # ... and the lower lid edge below it
    eye_radius: float
    eye_grid: int
    nose_height: float
    nose_width: float
    mouth_half: float
    lip: float  # lip fullness (protrusion)
    chin: float
    tongue_grid: int
    jaw_deg: float  # jawOpen rotation
    smile_radius: float
    smile_gain: float
    brow_gain: float
    iris: tuple[float, float, float]  # sRGB colour of the irises (for previews)


DEMO_CHARACTERS: dict[str, _Style] = {
    "ada": _Style(
        name="ada", ncols=45, nrows=53, skin_order="row", extras_first=False,
        half_width=7.3, jaw_ratio=0.36,
        y_top=10.6, y_eye=3.6, y_brow=5.4, y_nose_tip=-0.2, y_nose_base=-1.2, y_mouth=-3.7,
        y_chin=-8.4, y_bottom=-9.7,
        eye_x=3.15, eye_half=1.38, eye_up=0.62, eye_down=0.38, eye_radius=1.45, eye_grid=13,
        nose_height=2.3, nose_width=0.95, mouth_half=2.35, lip=0.6, chin=0.8, tongue_grid=7,
        jaw_deg=12.0, smile_radius=1.9, smile_gain=1.0, brow_gain=1.0, iris=(0.36, 0.24, 0.14),
    ),
    "bo": _Style(
        name="bo", ncols=37, nrows=43, skin_order="col", extras_first=True,
        half_width=8.0, jaw_ratio=0.58,
        y_top=10.2, y_eye=3.3, y_brow=5.2, y_nose_tip=-0.6, y_nose_base=-1.7, y_mouth=-4.2,
        y_chin=-9.2, y_bottom=-10.5,
        eye_x=3.5, eye_half=1.3, eye_up=0.55, eye_down=0.35, eye_radius=1.38, eye_grid=11,
        nose_height=3.0, nose_width=1.35, mouth_half=2.85, lip=0.7, chin=1.0, tongue_grid=6,
        jaw_deg=13.0, smile_radius=2.7, smile_gain=1.3, brow_gain=1.15, iris=(0.22, 0.40, 0.55),
    ),
}


# ---------------------------------------------------------------------- small helpers


def _bump(q):
    """Compact smooth bump: 1 at 0, 0 for |q| >= 1 (C2)."""
    q2 = np.minimum(np.asarray(q, np.float64) ** 2, 1.0)
    return (1.0 - q2) ** 3


def _ell(x, y, cx, cy, rx, ry):
    return _bump(np.sqrt(((x - cx) / rx) ** 2 + ((y - cy) / ry) ** 2))


def _gauss(u, v=0.0):
    return np.exp(-(u * u) - (v * v))


def _rot(axis, deg) -> np.ndarray:
    a = np.asarray(axis, np.float64)
    a = a / np.linalg.norm(a)
    t = np.radians(deg)
    K = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    return np.eye(3) + np.sin(t) * K + (1 - np.cos(t)) * (K @ K)


def _mirror_axis(half: np.ndarray) -> np.ndarray:
    """Exactly symmetric samples: -half[::-1], 0, half."""
    return np.concatenate([-half[::-1], [0.0], half])


# ---------------------------------------------------------------------- the face
class _Face:
    """Builds a face mask for a style and keeps the labels the shapes need."""

    def __init__(self, s: _Style):
        self.s = s
        nr, nc = s.nrows, s.ncols
        # rows: y(r) piecewise linear so that one row lies on the lip line and one on the eye line
        span = s.y_top - s.y_bottom
        self.r_m = int(round((s.y_mouth - s.y_bottom) / span * (nr - 1)))
        self.r_e = int(round((s.y_eye - s.y_bottom) / span * (nr - 1)))
        ys = np.interp(np.arange(nr), [0, self.r_m, self.r_e, nr - 1], [s.y_bottom, s.y_mouth, s.y_eye, s.y_top])
        self.phi_max = np.radians(78.0)
        phis = _mirror_axis(np.linspace(0.0, self.phi_max, nc // 2 + 1)[1:])
        R, C = np.meshgrid(np.arange(nr), np.arange(nc), indexing="ij")
        Y = ys[R]
        w = self._width(Y)
        sphi = np.sin(phis[C])
        X = w * sphi / np.sin(self.phi_max)
        Z = self._height(X, Y)
        self.grid = np.stack([X, Y, Z], -1)  # (nr, nc, 3), before the openings

        # the cuts: columns strictly inside each opening are doubled on the cut row
        xm = X[self.r_m]
        self.mouth_cols = np.flatnonzero(np.abs(xm) < s.mouth_half)
        self.mouth_corner = float(np.abs(xm[self.mouth_cols[-1] + 1]))  # |x| of the corner vertex
        xe = X[self.r_e]
        self.eye_cols = {}
        self.eye_span = {}
        for side in (1, -1):
            cols = np.flatnonzero(np.abs(side * xe - s.eye_x) < s.eye_half)
            self.eye_cols[side] = cols
            a, b = side * xe[cols[0] - 1], side * xe[cols[-1] + 1]
            self.eye_span[side] = (min(a, b), max(a, b))  # (inner |x|, outer |x|) of the corners

        # vertex numbering (canonical; permuted at the end for styles that want another order)
        skin_id = np.arange(nr * nc).reshape(nr, nc)
        nxt = nr * nc
        self.copy_mouth = np.arange(nxt, nxt + self.mouth_cols.size)
        nxt += self.mouth_cols.size
        self.copy_eye = {}
        for side in (-1, 1):
            self.copy_eye[side] = np.arange(nxt, nxt + self.eye_cols[side].size)
            nxt += self.eye_cols[side].size
        n_skin = nxt
        # base (pre-opening) coordinates and labels for skin vertices
        P = np.concatenate([self.grid.reshape(-1, 3), self.grid[self.r_m, self.mouth_cols],
                            self.grid[self.r_e, self.eye_cols[-1]], self.grid[self.r_e, self.eye_cols[1]]])
        ms = np.zeros(n_skin)  # +1: upper lip edge, -1: lower lip edge (the copies)
        ms[skin_id[self.r_m, self.mouth_cols]] = 1.0
        ms[self.copy_mouth] = -1.0
        es = np.zeros(n_skin)
        for side in (-1, 1):
            es[skin_id[self.r_e, self.eye_cols[side]]] = 1.0
            es[self.copy_eye[side]] = -1.0
        self.upper_lid_edge = {side: skin_id[self.r_e, self.eye_cols[side]] for side in (-1, 1)}
        self.upper_lip_edge = skin_id[self.r_m, self.mouth_cols]

        # faces: quads, with the cells just below a cut using the copies
        below = skin_id.copy()
        below[self.r_m, self.mouth_cols] = self.copy_mouth
        for side in (-1, 1):
            below[self.r_e, self.eye_cols[side]] = self.copy_eye[side]
        r0, c0 = np.meshgrid(np.arange(nr - 1), np.arange(nc - 1), indexing="ij")
        r0, c0 = r0.reshape(-1), c0.reshape(-1)
        quads = np.stack([skin_id[r0, c0], skin_id[r0, c0 + 1], skin_id[r0 + 1, c0 + 1], skin_id[r0 + 1, c0]], 1)
        # a cell whose top edge lies on a cut row is below the cut: its top corners are the copies
        quads[:, 2] = below[r0 + 1, c0 + 1]
        quads[:, 3] = below[r0 + 1, c0]
        faces = [quads]

        self.bx, self.by = P[:, 0].copy(), P[:, 1].copy()
        self.ms, self.es = ms, es
        V = P.copy()
        V[:, 1] += self._openings(P)
        verts = [V]

        # eyeballs: front caps of spheres set back until no skin vertex near them is behind them
        self.eye_center = {}
        self.eye_ids = {}
        self.eye_theta = {}
        for side in (-1, 1):
            ev, ef, eth = self._cap(s.eye_grid, s.eye_radius, np.radians(110), cornea=0.07)
            cx, cy = side * s.eye_x, s.y_eye + (s.eye_up - s.eye_down) / 2.0
            near = np.flatnonzero((V[:, 0] - cx) ** 2 + (V[:, 1] - cy) ** 2 < (s.eye_radius * 1.07) ** 2)
            ball = np.sqrt(np.clip((s.eye_radius * 1.07) ** 2 - (V[near, 0] - cx) ** 2 - (V[near, 1] - cy) ** 2,
                                   0.0, None))
            cz = float(np.min(V[near, 2] - ball)) - 0.1
            c = np.array([cx, cy, cz])
            ids = np.arange(nxt, nxt + len(ev))
            self.eye_center[side], self.eye_ids[side] = c, ids
            self.eye_theta[side] = eth
            verts.append(ev + c)
            faces.append(ef + nxt)
            nxt += len(ev)
        # tongue: a flattened cap behind the lips
        lip_z = float(V[self.upper_lip_edge, 2].max())
        tv, tf, _ = self._cap(s.tongue_grid, 1.0, np.radians(70))
        tv = tv * np.array([s.mouth_half * 0.62, 0.45, 1.2])
        self.tongue_center = np.array([0.0, s.y_mouth - 0.35, lip_z - 2.0])
        self.tongue_ids = np.arange(nxt, nxt + len(tv))
        verts.append(tv + self.tongue_center)
        faces.append(tf + nxt)
        nxt += len(tv)

        self.V = np.concatenate(verts)
        self.quads = np.concatenate(faces)
        self.n_skin = n_skin
        self.skin_id = skin_id
        n = len(self.V)
        self.is_skin = np.zeros(n, bool)
        self.is_skin[:n_skin] = True
        pad = n - n_skin
        self.bx = np.concatenate([self.bx, self.V[n_skin:, 0]])
        self.by = np.concatenate([self.by, self.V[n_skin:, 1]])
        self.ms = np.concatenate([self.ms, np.zeros(pad)])
        self.es = np.concatenate([self.es, np.zeros(pad)])

    def colors(self) -> np.ndarray:
        """Per-vertex preview colours (sRGB 0..1): skin, lips, eye whites with irises, tongue."""
        n = len(self.V)
        skin = np.array([0.80, 0.68, 0.60])
        col = np.tile(skin, (n, 1))
        lu, ll = self._lip_masks(self.bx, self.by)
        lip = np.clip(lu + ll, 0.0, 1.0)[:, None] * self.is_skin[:, None]
        col = col * (1.0 - lip) + np.array([0.72, 0.40, 0.40]) * lip
        for side in (-1, 1):
            th = self.eye_theta[side]
            iris = smoothstep((0.42 - th) / 0.08)[:, None]
            pupil = smoothstep((0.2 - th) / 0.06)[:, None]
            c = np.array([0.93, 0.92, 0.88]) * (1.0 - iris) + np.array(self.s.iris) * iris
            col[self.eye_ids[side]] = c * (1.0 - pupil) + 0.05 * pupil
        col[self.tongue_ids] = [0.74, 0.36, 0.38]
        return col

    # ---------------------------------------------------------------- shape of the mask
    def _width(self, y):
        s = self.s
        u = np.clip((s.y_nose_base - y) / (s.y_nose_base - s.y_bottom), 0.0, 1.0)
        lower = 1.0 - (1.0 - s.jaw_ratio) * u ** 1.7
        v = np.clip((y - s.y_eye) / (s.y_top - s.y_eye + 1.5), 0.0, 1.0)
        upper = np.sqrt(1.0 - 0.6 * v * v)
        return s.half_width * lower * upper

    def _front(self, y):
        s = self.s
        z = 8.0 - 0.05 * np.clip(y - s.y_eye, 0, None) ** 2 - 0.008 * np.clip(s.y_eye - y, 0, None) ** 2
        under = np.clip((s.y_chin + 0.6 - y) / (s.y_chin + 0.6 - s.y_bottom), 0.0, 1.0)
        return z - 2.2 * under ** 2

    def _height(self, x, y, wrap: bool = True):
        """Depth (z) of the face at (x, y): the curved mask plus the relief of the features.

        With ``wrap`` the skin around each eye is laid onto a sphere a little larger than the
        eyeball, so the lids wrap around the eyeball the way real lids do.
        """
        s = self.s
        x, y = np.asarray(x, np.float64), np.asarray(y, np.float64)
        w = self._width(y)
        sphi = np.clip(x * np.sin(self.phi_max) / w, -1.0, 1.0)
        D = 0.9 * w / np.sin(self.phi_max)
        z = self._front(y) - D * (1.0 - np.sqrt(1.0 - sphi * sphi)) + self._relief(x, y)
        if wrap:
            Rs = s.eye_radius * 1.07 + 0.08
            cy = s.y_eye + (s.eye_up - s.eye_down) / 2.0
            for side in (-1, 1):
                cx = side * s.eye_x
                z0 = float(self._height(np.float64(cx), np.float64(cy), wrap=False))
                cz = z0 + 0.45 - Rs
                r2 = (x - cx) ** 2 + (y - cy) ** 2
                cap = cz + np.sqrt(np.clip(Rs * Rs - r2, 0.0, None))
                wg = 1.0 - smoothstep((np.sqrt(r2) / Rs - 0.6) / 0.4)
                z = z + wg * (cap - z)
        return z

    def _relief(self, x, y):
        """Height of the features above the base surface."""
        s = self.s
        ax = np.abs(x)
        z = np.zeros_like(x)
        # brow ridge, temples, eye sockets, cheekbones
        brow_y = s.y_brow - 0.05 * (ax - s.eye_x + 0.3) ** 2
        z += 0.5 * _gauss((y - brow_y) / 0.85) * np.exp(-(((ax - s.eye_x + 0.6) / 2.8) ** 4))
        z -= 0.25 * _gauss((ax - s.half_width * 0.78) / 1.3, (y - s.y_brow) / 1.6)
        z -= 0.95 * _gauss((ax - s.eye_x) / 1.75, (y - s.y_eye - 0.1) / 1.2)
        # turn the eye region to face forward (undo the mask's curvature there) so the eyeballs fit
        sphi = s.eye_x * np.sin(self.phi_max) / float(self._width(np.float64(s.y_eye)))
        slope = 0.9 * sphi / np.sqrt(1.0 - sphi * sphi)
        z += slope * (ax - s.eye_x) * _gauss((ax - s.eye_x) / 2.2, (y - s.y_eye) / 1.8)
        z += 0.5 * _gauss((ax - s.eye_x - 1.1) / 1.6, (y - (s.y_eye - 2.1)) / 1.3)
        # nose: bridge from the nasion to the tip, a rounded tip, wings beside the base
        nh, nw = s.nose_height, s.nose_width
        y_n = s.y_eye + 0.55
        t_bridge = np.clip((y_n - y) / (y_n - s.y_nose_tip), 0.0, 1.0)
        h = np.where(y > y_n, 0.2 * nh * _gauss((y - y_n) / 1.1), nh * (0.2 + 0.8 * t_bridge ** 1.4))
        t_base = np.clip((s.y_nose_tip - y) / (s.y_nose_tip - s.y_nose_base), 0.0, 1.0)
        h = np.where(y < s.y_nose_tip, nh * np.sqrt(np.clip(1.0 - t_base ** 2, 0.0, None)), h)
        wn = nw * (0.5 + 0.45 * t_bridge)
        z += h * _gauss(x / wn)
        z += 0.28 * nh * _gauss((ax - 1.1 * nw) / 0.5, (y - (s.y_nose_base + 0.45)) / 0.5)
        # muzzle, lips, groove under the lower lip, chin
        mh = s.mouth_half
        z += 0.8 * _gauss(x / (mh + 1.4), (y - s.y_mouth) / 3.0)
        lu, ll = self._lip_masks(x, y)
        z += s.lip * lu + 1.1 * s.lip * ll
        z -= 0.3 * _gauss(x / (mh * 0.9), (y - (s.y_mouth - 1.45)) / 0.45)
        z += s.chin * _gauss(x / (1.1 + 0.45 * s.half_width * s.jaw_ratio), (y - (s.y_chin + 1.3)) / 1.4)
        return z

    def _lip_masks(self, x, y):
        """Upper and lower lip (vermilion) masks: 1 on the lip, falling to 0 over its border."""
        s = self.s
        mh = s.mouth_half
        q = (x / (mh * 1.02)) ** 2
        taper = np.exp(-(q ** 3))
        d = y - s.y_mouth
        hu = 0.8 * (1.0 - 0.45 * q) + 0.12 * _gauss(x / 0.5)  # the upper lip is tallest at the bow
        hl = 0.95 * (1.0 - 0.5 * q)
        lu = smoothstep((hu - d) / 0.45 + 0.5) * smoothstep(d / 0.3 + 1.0) * taper
        ll = smoothstep((hl + d) / 0.45 + 0.5) * smoothstep(-d / 0.3 + 1.0) * taper
        return lu, ll

    def _eye_profile(self, side, x, upper: bool):
        """Height profile of the eye opening across the eye (0 at the corners)."""
        a, b = self.eye_span[side]
        t = np.clip((side * x - a) / (b - a), 0.0, 1.0)
        # upper lid peaks nearer the nose, lower lid nearer the temple
        k = 0.85 if upper else 1.2
        tk = t ** k
        return 4.0 * tk * (1.0 - tk)

    def _openings(self, P):
        """Vertical offsets that part the lids (and the lips, barely) on the cut rows."""
        s = self.s
        x, y = P[:, 0], P[:, 1]
        dy = np.zeros(len(P))
        for side in (-1, 1):
            up = self._side_weight(x, y, self.es, s.y_eye, self.eye_span[side], side)
            pu = self._eye_profile(side, x, True)
            pl = self._eye_profile(side, x, False)
            d = y - s.y_eye
            dy += up * s.eye_up * pu * (1.0 - smoothstep((d - 0.2) / 1.7))
            dy -= (1.0 - up) * s.eye_down * pl * (1.0 - smoothstep((-d - 0.2) / 1.4))
        pm = np.clip(1.0 - (x / self.mouth_corner) ** 2, 0.0, None)
        dy += np.where(self.ms > 0, 0.03, np.where(self.ms < 0, -0.03, 0.0)) * pm
        return dy

    def _side_weight(self, x, y, cut, y_cut, span, side=None, grow=0.5):
        """1 above a cut, 0 below, continuous around its ends (0.5 at a corner, widening outward).

        ``cut`` is the +1/-1 label of the cut's two edges; ``span`` the (inner, outer) |x| of its
        corners; for a cut around x = 0 pass ``side=None`` and span = (-corner, corner).
        """
        xs = np.abs(x) if side is None else side * x
        a, b = span
        e = np.maximum(np.maximum(a - xs, xs - b), 0.0)
        tau = 0.02 + grow * e
        d = (y - y_cut) + 0.05 * cut
        return smoothstep(d / (2.0 * tau) + 0.5)

    @staticmethod
    def _cap(n, radius, alpha, cornea=0.0):
        """A front-facing (+Z) spherical cap of half-angle ``alpha`` as an n x n quad grid.

        The square grid is mapped onto a disc so the cap's rim is round; ``cornea`` adds a bulge
        at the front (a fraction of the radius).
        """
        t = np.linspace(-1.0, 1.0, n)
        t = (t - t[::-1]) / 2.0  # exactly symmetric
        t = np.sign(t) * np.abs(t) ** 1.35  # rings closer together at the front
        A, B = np.meshgrid(t, t, indexing="xy")  # A across (x), B up (y)
        rho = np.maximum(np.abs(A), np.abs(B))
        r = np.sqrt(A * A + B * B)
        safe = np.where(r > 0, r, 1.0)
        theta = rho * alpha
        u = np.stack([np.sin(theta) * A / safe, np.sin(theta) * B / safe, np.cos(theta)], -1)
        rad = radius * (1.0 + cornea * _gauss(theta / 0.42))
        v = (u * rad[..., None]).reshape(-1, 3)
        idx = np.arange(n * n).reshape(n, n)
        q = np.stack([idx[:-1, :-1], idx[:-1, 1:], idx[1:, 1:], idx[1:, :-1]], -1).reshape(-1, 4)
        return v, q, theta.reshape(-1)


# ---------------------------------------------------------------------- shapes
def _shapes(f: _Face) -> dict[str, np.ndarray]:
    """The demo face's 52 ARKit shapes, each a few lines of displacement field over the same face regions.

    Long because it is a table: one short block per ARKit shape, in ARKit's order, sharing the regions set up
    at the top; split by shape group it would pass the same dozen locals to every piece."""
    s = f.s
    V = f.V
    X, Y = V[:, 0], V[:, 1]
    n = len(V)
    skin = f.is_skin.astype(np.float64)
    ym, ye = s.y_mouth, s.y_eye
    mc = f.mouth_corner
    mh = s.mouth_half
    out: dict[str, np.ndarray] = {}

    def vec(dx, dy, dz, w):
        d = np.zeros((n, 3))
        d[:, 0], d[:, 1], d[:, 2] = dx * w, dy * w, dz * w
        return d

    # -- labels
    up_m = f._side_weight(f.bx, f.by, f.ms, ym, (-mc, mc), None, grow=0.5) * skin
    lo_m = (1.0 - up_m) * skin
    # the jaw: everything below the lip line, blending out toward the cheeks and the hinge
    jaw_w = (1.0 - f._side_weight(f.bx, f.by, f.ms, ym, (-mc, mc), None, grow=0.9)) * skin
    jaw_w *= 1.0 - smoothstep((f.by - ym) / (ye - ym))
    # the lips stay joined at the corners: the jaw's pull fades toward them, so the mouth opens oval
    to_corner = np.sqrt((np.abs(f.bx) - mc) ** 2 + (f.by - ym) ** 2)
    jaw_w *= 0.5 + 0.5 * smoothstep(to_corner / 2.0)
    jaw_w[f.tongue_ids] = 1.0
    mouth = _ell(X, Y, 0.0, ym, mc + 1.3, 1.9) * skin
    center = np.clip(1.0 - (X / (mc + 0.4)) ** 2, 0.0, None)
    corner = {side: (side * mc, ym) for side in (1, -1)}
    hinge = np.array([0.0, s.y_nose_base + 0.2, -1.5])  # the jaw joints, in front of the ears
    cheek_x = mc + 1.9

    def jaw_rotation(deg, w):
        Rm = _rot([1.0, 0.0, 0.0], deg)
        return ((V - hinge) @ Rm.T + hinge - V) * w[:, None]

    # -- jaw
    out["jawOpen"] = jaw_rotation(s.jaw_deg, jaw_w)
    out["jawForward"] = vec(0.0, -0.05, 0.75, jaw_w)
    for name, side in (("jawLeft", 1), ("jawRight", -1)):
        out[name] = vec(side * 0.85, 0.0, -0.05, jaw_w)

    # -- whole-mouth shapes
    lip_up = mouth * up_m
    lip_lo = mouth * lo_m
    # mouthClose undoes jawOpen on the lips (it is a corrective, used together with jawOpen)
    close_w = lo_m * (1.0 - smoothstep((np.abs(X) - mc + 0.3) / 1.6)) * smoothstep((Y - (ym - 2.2)) / 1.2)
    out["mouthClose"] = -jaw_rotation(s.jaw_deg, jaw_w) * close_w[:, None] + vec(0.0, -0.12, 0.02, lip_up * center)
    out["mouthFunnel"] = (vec(0.0, 0.4, 0.5, lip_up) + vec(0.0, -0.5, 0.5, lip_lo)) * (0.35 + 0.65 * center)[:, None]
    out["mouthFunnel"][:, 0] += -0.14 * X * mouth
    out["mouthPucker"] = vec(0.0, 0.0, 0.75, mouth * (0.4 + 0.6 * center)) + vec(0.0, -0.05, 0.0, lip_up) + vec(
        0.0, 0.07, 0.0, lip_lo)
    out["mouthPucker"][:, 0] += -0.32 * np.clip(X / mc, -1.3, 1.3) * mouth
    wide = _ell(X, Y, 0.0, ym, mc + 2.2, 2.4) * skin
    for name, side in (("mouthLeft", 1), ("mouthRight", -1)):
        out[name] = vec(side * 0.9, 0.03, -0.05 * side * np.sign(X), wide)
    roll_lo = lip_lo * _bump((ym - Y) / 1.3)
    roll_up = lip_up * _bump((Y - ym) / 1.3)
    out["mouthRollLower"] = vec(0.0, 0.28, -0.42, roll_lo * (0.3 + 0.7 * center))
    out["mouthRollUpper"] = vec(0.0, -0.25, -0.38, roll_up * (0.3 + 0.7 * center))
    shrug_lo = _ell(X, Y, 0.0, ym - 1.6, mc + 0.6, 2.6) * lo_m
    out["mouthShrugLower"] = vec(0.0, 0.38, 0.3, shrug_lo)
    out["mouthShrugUpper"] = vec(0.0, 0.3, 0.12, lip_up * (0.4 + 0.6 * center))

    # -- sided mouth shapes (side +1 = the character's left, +X)
    for sd, S in (("Left", 1), ("Right", -1)):
        xs = S * X
        cx, cy = corner[S]
        half = smoothstep((xs + 0.8) / 1.6)  # own side of the mouth, fading across the middle
        r = s.smile_radius
        c_smile = _ell(X, Y, cx, cy + 0.25, r, r * 0.95) * skin
        cheek = _ell(X, Y, S * cheek_x, ym + 2.6, 2.4, 2.0) * skin
        g = s.smile_gain
        out[f"mouthSmile{sd}"] = (vec(S * 0.55 * g, 0.75 * g, -0.2 * g, c_smile)
                                  + vec(S * 0.08, 0.35 * g, 0.22, cheek))
        out[f"mouthFrown{sd}"] = vec(S * 0.12, -0.6, -0.05, _ell(X, Y, cx, cy - 0.3, 1.7, 1.8) * skin)
        out[f"mouthDimple{sd}"] = vec(S * 0.32, 0.05, -0.35, _ell(X, Y, cx, cy, 1.5, 1.4) * skin)
        out[f"mouthStretch{sd}"] = (vec(S * 0.65, -0.3, -0.15, _ell(X, Y, cx, cy - 0.2, 2.1, 2.0) * skin)
                                    + vec(0.0, -0.15, 0.0, lip_lo * half))
        out[f"mouthPress{sd}"] = (vec(0.0, -0.12, -0.1, lip_up * half * _bump((Y - ym) / 1.2))
                                  + vec(0.0, 0.14, -0.1, lip_lo * half * _bump((ym - Y) / 1.2)))
        sub = _ell(xs, Y, mh * 0.45, ym, mh * 0.95, 3.0)
        out[f"mouthLowerDown{sd}"] = vec(S * 0.05, -0.55, 0.06, lip_lo * sub)
        out[f"mouthUpperUp{sd}"] = vec(0.0, 0.5, 0.06, lip_up * sub)

    # -- brows, cheeks, nose
    bg = s.brow_gain
    brow_y = s.y_brow
    out["browInnerUp"] = vec(0.0, 0.6 * bg, 0.02, (_ell(X, Y, 1.5, brow_y, 2.1, 2.0)
                                                  + _ell(X, Y, -1.5, brow_y, 2.1, 2.0)) * skin)
    for sd, S in (("Left", 1), ("Right", -1)):
        bx = S * (s.eye_x + 0.2)
        out[f"browDown{sd}"] = vec(-S * 0.22, -0.45 * bg, 0.12, _ell(X, Y, bx - S * 0.5, brow_y, 2.5, 1.6) * skin)
        out[f"browOuterUp{sd}"] = vec(S * 0.05, 0.55 * bg, 0.0, _ell(X, Y, S * (s.eye_x + 1.4), brow_y + 0.1, 2.2, 2.0) * skin)
        out[f"cheekSquint{sd}"] = vec(0.0, 0.35, 0.12, _ell(X, Y, S * (s.eye_x + 0.2), ye - 1.7, 2.0, 1.5) * skin)
        out[f"noseSneer{sd}"] = (vec(S * 0.05, 0.4, 0.05, _ell(X, Y, S * 1.2 * s.nose_width, s.y_nose_base + 1.1, 1.3, 1.6) * skin)
                                 + vec(0.0, -0.12, 0.0, _ell(X, Y, S * 1.3, brow_y - 0.3, 1.2, 1.0) * skin))
    puff = (_ell(X, Y, cheek_x, ym + 0.4, 2.6, 2.6) + _ell(X, Y, -cheek_x, ym + 0.4, 2.6, 2.6)) * skin
    out["cheekPuff"] = vec(np.sign(X) * 0.65, 0.0, 0.75, puff)

    # -- eyes
    for sd, S in (("Left", 1), ("Right", -1)):
        a, b = f.eye_span[S]
        own = (S * X > 0).astype(np.float64) * skin
        up = f._side_weight(f.bx, f.by, f.es, ye, (a, b), S) * own
        lo = (1.0 - up) * own
        d = f.by - ye
        fall_up = (1.0 - smoothstep((d - 0.3) / 1.9)) * up
        fall_lo = (1.0 - smoothstep((-d - 0.2) / 1.4)) * lo
        # gap between the lid edges, as a function of x (0 at and beyond the corners)
        ue = f.upper_lid_edge[S]
        le = f.copy_eye[S]
        ex = V[ue, 0]
        o = np.argsort(ex)
        corners_x = np.array([S * a, S * b])
        gx = np.concatenate([ex[o], corners_x])
        oo = np.argsort(gx)
        gap = np.zeros((len(gx), 3))
        gap[: len(o)] = V[le][o] - V[ue][o]
        gap = gap[oo]
        gx = gx[oo]
        G = np.stack([np.interp(X, gx, gap[:, k], left=0.0, right=0.0) for k in range(3)], 1)
        pu = f._eye_profile(S, X, True)
        pl = f._eye_profile(S, X, False)
        # the closing lid bulges forward over the eyeball, but its edge meets the lower lid's edge
        bulge = pu * fall_up * smoothstep((d + 0.05) / 0.5)
        blink = G * (0.97 * fall_up)[:, None] + vec(0.0, 0.0, 0.25, bulge)
        blink += -G * (0.03 * fall_lo)[:, None]
        out[f"eyeBlink{sd}"] = blink
        out[f"eyeSquint{sd}"] = (-G * (0.3 * fall_lo)[:, None] + G * (0.12 * fall_up)[:, None]
                                 + vec(0.0, 0.1, 0.05, _ell(X, Y, S * (b + 0.2), ye - 0.5, 1.3, 1.5) * skin))
        out[f"eyeWide{sd}"] = vec(0.0, 0.3, 0.04, pu * fall_up) + vec(0.0, -0.1, 0.0, pl * fall_lo)
        # gaze: the eyeball turns about its centre; the lids follow a little
        ids = f.eye_ids[S]
        c = f.eye_center[S]
        gaze = {
            "Up": ([1.0, 0.0, 0.0], -20.0, vec(0.0, 0.15, 0.0, pu * fall_up) + vec(0.0, 0.06, 0.0, pl * fall_lo)),
            "Down": ([1.0, 0.0, 0.0], 25.0, vec(0.0, -0.32, 0.05, pu * fall_up) + vec(0.0, -0.05, 0.0, pl * fall_lo)),
            # In: toward the nose (-S x); Out: toward the temple (+S x)
            "In": ([0.0, 1.0, 0.0], -S * 25.0, vec(-S * 0.04, 0.0, 0.0, (pu * fall_up + pl * fall_lo))),
            "Out": ([0.0, 1.0, 0.0], S * 25.0, vec(S * 0.04, 0.0, 0.0, (pu * fall_up + pl * fall_lo))),
        }
        for direction, (axis, deg, lids) in gaze.items():
            d3 = lids.copy()
            Rm = _rot(axis, deg)
            d3[ids] = (V[ids] - c) @ Rm.T + c - V[ids]
            out[f"eyeLook{direction}{sd}"] = d3

    # -- tongue: slides forward and down out of a slightly parted mouth
    tongue = np.zeros((n, 3))
    tt = f.tongue_ids
    lift = smoothstep((V[tt, 2] - f.tongue_center[2] + 1.2) / 2.4)
    tongue[tt] = np.stack([np.zeros(tt.size), -0.6 - 0.25 * lift, 1.55 + 0.25 * lift], 1)
    tongue += jaw_rotation(6.0, jaw_w * (1 - np.isin(np.arange(n), tt)))
    tongue += vec(0.0, 0.15, 0.05, lip_up * center)
    out["tongueOut"] = tongue
    return out


def _landmarks(f: _Face) -> np.ndarray:
    """68 Multi-PIE landmark vertex indices (points 0-7, 17-21, 36-41 on the character's right, -X)."""
    s = f.s
    V = f.V
    skin = np.flatnonzero(f.is_skin)

    def near(cands, x, y):
        c = np.asarray(cands)
        d = (V[c, 0] - x) ** 2 + (V[c, 1] - y) ** 2
        return int(c[np.argmin(d)])

    lm: list[int] = []
    # jaw line 0-16: down the side of the face from the right temple, round the chin on an
    # elliptical arc from the jaw angle, and up the other side
    y_angle = s.y_mouth - 1.2
    ys = np.linspace(s.y_eye - 0.8, y_angle, 200)
    side = np.stack([f._width(ys) * 0.93, ys], 1)
    x_angle = side[-1, 0]
    t = np.linspace(0.0, np.pi / 2, 200)[1:]
    y_chin = s.y_chin - 0.2
    arc = np.stack([x_angle * np.cos(t), y_angle - (y_angle - y_chin) * np.sin(t)], 1)
    half = np.concatenate([side, arc])  # the right half (+x), temple to chin
    curve = np.concatenate([half * [-1, 1], half[::-1][1:]])
    seg = np.linalg.norm(np.diff(curve, axis=0), axis=1)
    arclen = np.concatenate([[0.0], np.cumsum(seg)])
    at = np.linspace(0.0, arclen[-1], 17)
    jaw_x, jaw_y = np.interp(at, arclen, curve[:, 0]), np.interp(at, arclen, curve[:, 1])
    lm += [near(skin, x, y) for x, y in zip(jaw_x, jaw_y, strict=True)]
    # brows 17-21 (right, outer -> inner), 22-26 (left, inner -> outer)
    bxs = s.eye_x + np.linspace(1.6, -1.7, 5)
    by = s.y_brow - 0.05 * (bxs - s.eye_x + 0.3) ** 2 - 0.1
    lm += [near(skin, -x, y) for x, y in zip(bxs, by, strict=True)]
    lm += [near(skin, x, y) for x, y in zip(bxs[::-1], by[::-1], strict=True)]
    # nose bridge 27-30 (30 = tip), nostril base 31-35
    centre = f.skin_id[:, s.ncols // 2]
    c_rows = centre[(V[centre, 1] > s.y_nose_base) & (V[centre, 1] < s.y_eye + 1.0)]
    tip = int(c_rows[np.argmax(V[c_rows, 2])])
    for y in np.linspace(s.y_eye + 0.35, V[tip, 1], 4)[:3]:
        lm.append(near(centre, 0.0, y))
    lm.append(tip)
    nb = s.y_nose_base + 0.15
    lm += [near(skin, x * s.nose_width, nb) for x in (-1.15, -0.6, 0.0, 0.6, 1.15)]
    # eyes: 36-41 right eye (outer corner, upper lid x2, inner corner, lower lid x2), 42-47 left
    for S in (-1, 1):
        a, b = f.eye_span[S]
        ue, le = f.upper_lid_edge[S], f.copy_eye[S]
        corner_in = f.skin_id[f.r_e, (f.eye_cols[S][0] - 1) if S > 0 else (f.eye_cols[S][-1] + 1)]
        corner_out = f.skin_id[f.r_e, (f.eye_cols[S][-1] + 1) if S > 0 else (f.eye_cols[S][0] - 1)]
        t1, t2 = a + (b - a) / 3.0, a + 2.0 * (b - a) / 3.0
        if S < 0:  # image-left eye: outer, upper (outer->inner), inner, lower (inner->outer)
            pts = [int(corner_out), near(ue, -t2, s.y_eye), near(ue, -t1, s.y_eye), int(corner_in),
                   near(le, -t1, s.y_eye), near(le, -t2, s.y_eye)]
        else:  # image-right eye: inner, upper (inner->outer), outer, lower (outer->inner)
            pts = [int(corner_in), near(ue, t1, s.y_eye), near(ue, t2, s.y_eye), int(corner_out),
                   near(le, t2, s.y_eye), near(le, t1, s.y_eye)]
        lm += pts
    # outer lips 48-59: corner, upper contour left->right, corner, lower contour right->left
    mc = f.mouth_corner
    col_r = f.mouth_cols[0] - 1  # corner columns (-x and +x)
    col_l = f.mouth_cols[-1] + 1
    upper_side = np.flatnonzero(f.is_skin & (f.by > s.y_mouth + 0.1))
    lower_side = np.flatnonzero(f.is_skin & (f.by < s.y_mouth - 0.1))
    lm.append(int(f.skin_id[f.r_m, col_r - 1]))
    for x in (-0.62, -0.3, 0.0, 0.3, 0.62):
        lm.append(near(upper_side, x * mc, s.y_mouth + 0.85 - 0.15 * abs(x)))
    lm.append(int(f.skin_id[f.r_m, col_l + 1]))
    for x in (0.62, 0.3, 0.0, -0.3, -0.62):
        lm.append(near(lower_side, x * mc, s.y_mouth - 0.95 + 0.25 * abs(x)))
    # inner lips 60-67
    lm.append(int(f.skin_id[f.r_m, col_r]))
    lm += [near(f.upper_lip_edge, x * mc, s.y_mouth) for x in (-0.45, 0.0, 0.45)]
    lm.append(int(f.skin_id[f.r_m, col_l]))
    lm += [near(f.copy_mouth, x * mc, s.y_mouth) for x in (0.45, 0.0, -0.45)]
    out = np.asarray(lm, np.int64)
    if out.size != 68 or np.unique(out).size != 68:
        raise AssertionError(f"{s.name}: landmark construction produced {np.unique(out).size} distinct points")
    return out


def _style(name: str) -> _Style:
    key = str(name).lower()
    if key not in DEMO_CHARACTERS:
        raise InvalidDataError(f"unknown demo character '{name}', use one of {sorted(DEMO_CHARACTERS)}")
    return DEMO_CHARACTERS[key]


@functools.lru_cache(maxsize=4)
def _build(key: str) -> dict[str, np.ndarray]:
    """Everything about one character, in its final vertex order (cached; arrays are read-only)."""
    s = DEMO_CHARACTERS[key]
    f = _Face(s)
    shapes = _shapes(f)
    deltas = np.stack([shapes[n] for n in ARKIT_NAMES])
    lm = _landmarks(f)
    # vertex order: optionally extras (eyes, tongue) first and the skin numbered column by column
    n = len(f.V)
    skin_seq = f.skin_id.T.reshape(-1) if s.skin_order == "col" else f.skin_id.reshape(-1)
    rest_skin = np.arange(f.skin_id.size, f.n_skin)
    extras = np.arange(f.n_skin, n)
    order = (np.concatenate([extras, skin_seq, rest_skin]) if s.extras_first
             else np.concatenate([skin_seq, rest_skin, extras]))
    new_of_old = np.empty(n, np.int64)
    new_of_old[order] = np.arange(n)
    out = {
        "vertices": f.V[order],
        "faces": new_of_old[f.quads],
        "deltas": deltas[:, order],
        "landmarks": new_of_old[lm],
        "colors": f.colors()[order],
    }
    for v in out.values():
        v.setflags(write=False)
    return out


def make_demo_character(name: str = "ada") -> Rig:
    """A procedural demo character with all 52 ARKit shapes: ``"ada"`` or ``"bo"``.

    See the module docstring for what the characters are.  Building one takes a few tens of
    milliseconds and the result is the same on every call (a fresh :class:`Rig` each time).
    """
    s = _style(name)
    b = _build(s.name)
    faces = b["faces"]
    mesh = Mesh(b["vertices"].copy(), np.full(len(faces), faces.shape[1]), faces.reshape(-1).copy(),
                name=f"demo-{s.name}")
    return Rig(mesh, list(ARKIT_NAMES), b["deltas"].copy(), unit="cm", landmarks=b["landmarks"].copy(),
               source_names=list(ARKIT_NAMES), name=f"demo-{s.name}")


def demo_vertex_colors(name: str = "ada") -> np.ndarray:
    """``(V, 3)`` sRGB colours in 0..1 for previews of a demo character (or anything retargeted onto it).

    Skin, reddish lips, white eyeballs with an iris and pupil at the front (so gaze shows), and a
    pink tongue, in the character's vertex order; pass as ``color=`` to
    :func:`faceretarget.render.render_mesh`.
    """
    return _build(_style(name).name)["colors"].copy()


# ---------------------------------------------------------------------- the take
def make_demo_take(seconds: float = 6.0, fps: float = 30.0, seed: int = 7) -> Performance:
    """A synthetic talking and emoting take: 52 ARKit weight curves in [0, 1].

    Speech-like syllables drive the jaw and lips in phrases with pauses; the eyes blink every few
    seconds, a smile comes and goes in the middle, the brows rise once, and the gaze shifts a
    little.  The same ``seed`` always gives the same take.
    """
    if not (seconds > 0 and fps > 0):
        raise InvalidDataError(f"demo take needs positive seconds and fps, got {seconds}, {fps}")
    rng = np.random.default_rng(seed)
    T = max(2, int(round(seconds * fps)))
    t = np.arange(T) / fps
    idx = {nm: k for k, nm in enumerate(ARKIT_NAMES)}
    W = np.zeros((T, len(ARKIT_NAMES)))

    def add(name, curve):
        W[:, idx[name]] += curve

    def pulse(t0, width):
        """A smooth bump centred on t0 (raised cosine), 1 at its peak."""
        u = np.clip((t - t0) / width, -1.0, 1.0)
        return 0.5 * (1.0 + np.cos(np.pi * u))

    def envelope(t0, t1, ramp):
        return smoothstep((t - t0) / ramp) * (1.0 - smoothstep((t - t1) / ramp))

    # speech: phrases of syllables at about 4.5 per second with pauses between phrases
    phrases = []
    start = 0.25
    while start < seconds - 0.6:
        length = float(rng.uniform(1.1, 2.0))
        end = min(start + length, seconds - 0.3)
        phrases.append((start, end))
        start = end + float(rng.uniform(0.35, 0.6))
    sounds = ("a", "e", "o", "u", "m", "f")
    odds = (0.26, 0.22, 0.18, 0.14, 0.12, 0.08)
    for p0, p1 in phrases:
        ts = p0 + 0.11
        while ts < p1 - 0.05:
            v = sounds[int(rng.choice(len(sounds), p=odds))]
            amp = float(rng.uniform(0.35, 0.8))
            width = float(rng.uniform(0.1, 0.14))
            b = pulse(ts, width)
            if v == "m":  # bilabial: lips press, jaw barely moves
                add("jawOpen", 0.08 * amp * b)
                add("mouthPressLeft", 0.5 * amp * b)
                add("mouthPressRight", 0.5 * amp * b)
                add("mouthRollLower", 0.2 * amp * b)
            elif v == "f":  # labiodental: lower lip tucks under the teeth
                add("jawOpen", 0.12 * amp * b)
                add("mouthRollLower", 0.55 * amp * b)
                add("mouthUpperUpLeft", 0.15 * amp * b)
                add("mouthUpperUpRight", 0.15 * amp * b)
            else:
                jaw = {"a": 0.7, "e": 0.4, "o": 0.5, "u": 0.25}[v] * amp
                add("jawOpen", jaw * b)
                add("mouthLowerDownLeft", 0.3 * amp * b)
                add("mouthLowerDownRight", 0.3 * amp * b)
                add("mouthUpperUpLeft", 0.12 * amp * b)
                add("mouthUpperUpRight", 0.12 * amp * b)
                add("mouthClose", 0.05 * jaw * b)
                if v == "e":
                    add("mouthStretchLeft", 0.35 * amp * b)
                    add("mouthStretchRight", 0.35 * amp * b)
                elif v == "o":
                    add("mouthFunnel", 0.5 * amp * b)
                elif v == "u":
                    add("mouthPucker", 0.7 * amp * b)
                    add("mouthFunnel", 0.2 * amp * b)
            ts += float(rng.uniform(0.19, 0.27))

    # emotion: a brow raise early, a smile in the middle, a slight frown of concentration late
    raise_env = envelope(0.9, 1.9, 0.3)
    add("browInnerUp", 0.7 * raise_env)
    add("browOuterUpLeft", 0.55 * raise_env)
    add("browOuterUpRight", 0.5 * raise_env)
    add("eyeWideLeft", 0.25 * raise_env)
    add("eyeWideRight", 0.25 * raise_env)
    smile_env = envelope(0.42 * seconds, 0.72 * seconds, 0.45)
    add("mouthSmileLeft", 0.75 * smile_env)
    add("mouthSmileRight", 0.7 * smile_env)
    add("cheekSquintLeft", 0.45 * smile_env)
    add("cheekSquintRight", 0.4 * smile_env)
    add("eyeSquintLeft", 0.3 * smile_env)
    add("eyeSquintRight", 0.3 * smile_env)
    add("mouthDimpleLeft", 0.2 * smile_env)
    add("mouthDimpleRight", 0.2 * smile_env)
    frown_env = envelope(0.8 * seconds, 0.95 * seconds, 0.25)
    add("browDownLeft", 0.45 * frown_env)
    add("browDownRight", 0.5 * frown_env)
    add("noseSneerLeft", 0.15 * frown_env)
    add("noseSneerRight", 0.15 * frown_env)
    add("mouthShrugLower", 0.3 * frown_env)

    # blinks: fast close, slower open; about every 1.5-2.5 s
    tb = float(rng.uniform(0.5, 0.9))
    while tb < seconds - 0.2:
        close = np.clip((t - (tb - 0.07)) / 0.07, 0.0, 1.0)
        opening = np.clip(1.0 - (t - tb) / 0.16, 0.0, 1.0)
        b = smoothstep(np.where(t < tb, close, opening))
        add("eyeBlinkLeft", b)
        add("eyeBlinkRight", b)
        tb += float(rng.uniform(1.5, 2.5))

    # gaze: a few small saccades, held
    gaze_x = np.zeros(T)
    gaze_y = np.zeros(T)
    tg = 0.0
    gx, gy = 0.0, 0.0
    while tg < seconds:
        nxt = tg + float(rng.uniform(0.6, 1.4))
        ngx, ngy = float(rng.uniform(-0.35, 0.35)), float(rng.uniform(-0.25, 0.2))
        step = smoothstep((t - nxt) / 0.06)
        gaze_x += (ngx - gx) * step
        gaze_y += (ngy - gy) * step
        gx, gy, tg = ngx, ngy, nxt
    # gaze_x > 0: looking toward the character's left: left eye out, right eye in
    add("eyeLookOutLeft", np.clip(gaze_x, 0, None))
    add("eyeLookInRight", np.clip(gaze_x, 0, None))
    add("eyeLookInLeft", np.clip(-gaze_x, 0, None))
    add("eyeLookOutRight", np.clip(-gaze_x, 0, None))
    add("eyeLookUpLeft", np.clip(gaze_y, 0, None))
    add("eyeLookUpRight", np.clip(gaze_y, 0, None))
    add("eyeLookDownLeft", np.clip(-gaze_y, 0, None))
    add("eyeLookDownRight", np.clip(-gaze_y, 0, None))

    # a little life everywhere: slow, small noise on the jaw and brows
    for name, amp in (("jawOpen", 0.03), ("browInnerUp", 0.05), ("mouthShrugUpper", 0.05)):
        k = np.arange(T)
        noise = sum(float(rng.uniform(0.3, 1.0)) * np.sin(2 * np.pi * float(rng.uniform(0.2, 0.9)) * k / fps
                                                         + float(rng.uniform(0, 2 * np.pi))) for _ in range(3))
        add(name, amp * (0.5 + 0.5 * noise / 3.0))

    W = np.clip(W, 0.0, 1.0)
    return Performance.from_weights(W, list(ARKIT_NAMES), fps=float(fps), source="demo-take")
