"""Generate a neutral character's expression shapes by deformation transfer (:func:`generate_shapes`): the
character-level job that loads the template and the character and runs :mod:`faceretarget.transfer`'s method."""

from __future__ import annotations

import copy
import dataclasses
import functools
import time
from dataclasses import dataclass, field

import numpy as np

from ..character import Character, character_frame
from ..errors import InvalidDataError, MissingShapeError
from ..names import ARKIT_NAMES, normalize_name
from ..transfer import (
    SEAM,
    LidMargin,
    Part,
    Template,
    closest_points,
    components,
    find_parts,
    gradient_operator,
    landmark_skin,
    lid_margins,
    register_template,
    triangle_areas,
    vertex_normals,
)
from ._template import load_template

__all__ = ["generate_shapes", "GeneratedShapes", "LID_PAIRS", "LIP_PAIRS", "EYE_LOOK_DEGREES", "METHODS"]

#: Upper and lower eyelid landmarks facing each other (68-point numbering).
LID_PAIRS = ((37, 41), (38, 40), (43, 47), (44, 46))
#: Upper and lower inner-lip landmarks facing each other.
LIP_PAIRS = ((61, 67), (62, 66), (63, 65))
#: How far the eyeballs turn for ``eyeLook*`` at weight 1, degrees (ARKit's range as measured on iPhone takes).
EYE_LOOK_DEGREES = {"Up": 25.0, "Down": 25.0, "In": 30.0, "Out": 30.0}
#: ``deformation``: Sumner & Popovic's deformation transfer; ``barycentric``: the template's displacement
#: at each vertex's corresponding point, rotated and scaled by the landmark similarity.
METHODS = ("deformation", "barycentric")
#: Weight of the positional anchor (the barycentric transfer) relative to the gradient term, per unit of
#: (outer-eye-corner distance)^-2, and of the lid / lip landmark constraints.
_ANCHOR, _PIN = 0.05, 20000.0


@dataclass(eq=False)
class GeneratedShapes:
    """What :func:`generate_shapes` made.

    Attributes
    ----------
    character : Character
        The character the shapes were generated for (unchanged).
    added : dict
        ``{SceneMesh.name: {shape name: (V, 3) float32}}`` world-space deltas in metres.
    skipped : list of str
        Shapes the character already has (kept; ``replace=True`` replaces them).
    notes : list of str
    shape_notes : dict
        ``{shape: note}`` for shapes that needed a correction (lids closed onto the eyeballs, lips met).
    timings : dict
        Seconds: ``landmarks``, ``register``, ``factor``, ``shapes``, ``total``.
    template : str
    info : dict
        Registration numbers (``landmark_error``, ``size``), the coverage, the parts found.
    """

    character: Character
    added: dict
    skipped: list = field(default_factory=list)
    notes: list = field(default_factory=list)
    shape_notes: dict = field(default_factory=dict)
    timings: dict = field(default_factory=dict)
    template: str = ""
    info: dict = field(default_factory=dict)
    replace: bool = False

    @property
    def shape_names(self) -> list[str]:
        seen: list[str] = []
        for d in self.added.values():
            seen += [n for n in d if n not in seen]
        return seen

    def apply(self) -> Character:
        """A copy of the character with the generated shapes appended to its meshes (same-named shapes
        replaced when generated with ``replace=True``); ``shape_refs`` of new shapes are -1 (not in the file)."""
        ch = copy.copy(self.character)
        meshes = []
        for m in ch.meshes:
            new = self.added.get(m.name)
            if not new:
                meshes.append(m)
                continue
            names, deltas, refs = list(m.shape_names), list(m.deltas), list(m.shape_refs)
            for n, d in new.items():
                hit = [k for k, x in enumerate(names) if normalize_name(x) == n]
                if hit and self.replace:
                    deltas[hit[0]] = d
                    continue
                names.append(n)
                deltas.append(d)
                refs.append(-1)
            D = np.stack(deltas).astype(np.float32) if deltas else np.zeros((0, m.mesh.n_vertices, 3), np.float32)
            meshes.append(dataclasses.replace(m, shape_names=names, deltas=D, shape_refs=refs))
        ch.meshes = meshes
        ch.neutral_head = None
        ch.notes = list(ch.notes) + [f"{len(self.shape_names)} face shapes generated from {self.template}"]
        for attr in ("_face_cache",):
            if attr in ch.__dict__:
                del ch.__dict__[attr]
        return ch


def _wanted(spec, tmpl: Template) -> list[str]:
    if spec is None or spec == "arkit":
        return [a for a in ARKIT_NAMES if a in tmpl.shapes]
    names = [s.strip() for s in (spec.split(",") if isinstance(spec, str) else spec) if s.strip()]
    out = []
    for n in names:
        a = normalize_name(n)
        if a not in ARKIT_NAMES:
            raise MissingShapeError(f"--shapes: '{n}' is not an ARKit shape name (e.g. eyeBlinkLeft, jawOpen)")
        if a not in tmpl.shapes:
            raise MissingShapeError(f"--shapes: the template {tmpl.name} has no '{a}'"
                                    + (" (ICT-FaceKit has no tongue)" if a == "tongueOut" else ""))
        if a not in out:
            out.append(a)
    return out


def _rotation(axis: int, deg: float) -> np.ndarray:
    a = np.radians(deg)
    c, s = np.cos(a), np.sin(a)
    if axis == 0:
        return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def _eye_turn(name: str, side: str) -> np.ndarray | None:
    """Head-frame rotation of an eyeball of ``side`` for an ``eyeLook*`` shape, or None."""
    if not name.startswith("eyeLook"):
        return None
    rest = name[len("eyeLook"):]
    d = next((k for k in EYE_LOOK_DEGREES if rest.startswith(k)), None)
    if d is None or not rest.endswith(side.capitalize()):
        return None
    a = EYE_LOOK_DEGREES[d]
    if d == "Up":
        return _rotation(0, -a)
    if d == "Down":
        return _rotation(0, a)
    inward = (d == "In") == (side == "left")           # the left eye looks in toward -X
    return _rotation(1, -a if inward else a)


def _kabsch(X: np.ndarray, Y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    cx, cy = X.mean(0), Y.mean(0)
    U, _, Vt = np.linalg.svd((Y - cy).T @ (X - cx))
    D = np.eye(3)
    D[2, 2] = np.sign(np.linalg.det(U @ Vt))
    R = U @ D @ Vt
    return R, cy - R @ cx


def _deformation_gradients(V: np.ndarray, T: np.ndarray, D: np.ndarray) -> np.ndarray:
    """``(F, 3, 3)`` Sumner & Popovic deformation gradient of each triangle (a fourth vertex off the normal)."""
    def frame(P):
        e1, e2 = P[T[:, 1]] - P[T[:, 0]], P[T[:, 2]] - P[T[:, 0]]
        n = np.cross(e1, e2)
        n = n / np.sqrt(np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-30))
        return np.stack([e1, e2, n], axis=2)
    A, B = frame(V), frame(V + D)
    det = np.abs(np.linalg.det(A))
    ok = det > 1e-24 * np.median(det + 1e-300)
    Q = np.tile(np.eye(3), (len(T), 1, 1))
    Q[ok] = B[ok] @ np.linalg.inv(A[ok])
    # a template triangle that folds over (its own sculpt's flaw at the lips' inner edge) would fold the
    # character's too: keep its rotation and stretch, with every stretch at least a quarter
    U, S, Vt = np.linalg.svd(Q)
    flip = np.linalg.det(U @ Vt) < 0
    bad = flip | (S.min(axis=1) < 0.25)
    if bad.any():
        Ub, Sb, Vb = U[bad], np.maximum(S[bad], 0.25), Vt[bad]
        f = flip[bad]
        Ub[f, :, 2] *= -1
        Q[bad] = Ub @ (Sb[:, :, None] * Vb)
    return Q


def generate_shapes(character, *, template="ict-face", shapes="arkit", replace: bool = False, progress=None,
                    mesh: str | None = None, landmarks=None, method: str = "deformation",
                    symmetric: bool = True, log=None) -> GeneratedShapes:
    """Generate a character's expression shapes from a template's by deformation transfer.

    The story (each step one method of :class:`_Transfer`): read the character and the template, find the
    face's skin, register the template onto it and find each face vertex's corresponding template point,
    factorise the deformation-transfer system once, transfer every shape (lids and lips pinned, folds
    untangled), make a symmetric face's shapes mirror images, and move the other parts (eyes, teeth, the
    rest of the head) with the skin.

    Parameters
    ----------
    character : path-like or Character
        A character file / rig folder or one already read; face shapes it has are hidden from nothing:
        those it already has are kept (listed in ``skipped``) unless ``replace``.
    template : str, path-like or Template
        ``"ict-face"`` (packaged), ``"arkit-face"`` or a rig folder / character file with ARKit shapes
        (:func:`~faceretarget.characters.load_template`).
    shapes : str or list of str
        ``"arkit"`` (every ARKit shape the template has) or ARKit names.
    replace : bool
        Generate shapes the character already has too (they replace the artist's in :meth:`GeneratedShapes.apply`).
    progress : callable, optional
        Called with one line per step and per shape.
    mesh, landmarks : ``--mesh`` and ``--landmarks`` of :func:`~faceretarget.characters.load_character`.
    method : str
        ``"deformation"`` (default) or ``"barycentric"`` (:data:`METHODS`).
    symmetric : bool
        On a face that is its own mirror image (each vertex's mirror within 2 % of the outer-eye-corner
        distance of a vertex, mean over the face), make ``xxxLeft`` and ``xxxRight`` exact mirror images (the
        mean of the two) and the other shapes symmetric.

    Returns
    -------
    GeneratedShapes
    """
    say = progress or log or (lambda *_: None)
    if method not in METHODS:
        raise InvalidDataError(f"method must be one of {', '.join(METHODS)}, not '{method}'")
    job = _Transfer(character, template, shapes, replace, mesh, landmarks, method, say)
    if not job.todo:                            # every shape asked is the character's own, kept: nothing to do
        job.timings["total"] = time.perf_counter() - job.t_all
        say(f"nothing to generate: '{job.ch.name}' has all {len(job.skipped)} of the shapes asked")
        return GeneratedShapes(job.ch, {}, job.skipped, job.notes, {}, job.timings, job.tmpl.name, {}, replace)
    job.find_skin()
    job.register()
    job.prepare_lips_and_mirror(symmetric)
    job.factorise()
    job.transfer_shapes()
    if job.mirror is not None:
        job.symmetrise()
    return job.result()


class _Transfer:
    """The state of one :func:`generate_shapes` run, one method per step of its story."""

    def __init__(self, character, template, shapes, replace: bool, mesh, landmarks, method: str, say):
        from ._load import load_character

        self.say, self.method, self.replace = say, method, replace
        self.t_all = time.perf_counter()
        self.timings = {}
        t0 = time.perf_counter()
        ch = load_character(character, landmarks=landmarks, mesh=mesh, need_shapes=False, log=say)
        if ch.landmarks is None:
            raise InvalidDataError(f"{ch.name}: no landmarks")
        self.timings["landmarks"] = time.perf_counter() - t0
        self.ch = ch
        self.tmpl = tmpl = load_template(template, log=say)
        wanted = _wanted(shapes, tmpl)
        have = {normalize_name(n) for m in ch.meshes for n in m.shape_names}
        self.skipped = [a for a in wanted if a in have and not replace]
        self.todo = [a for a in wanted if a not in self.skipped]
        self.notes = list(tmpl.notes)
        if self.skipped:
            self.notes.append(f"kept the character's own {', '.join(self.skipped)} (replace=True to generate them)")
        self.head = ch.landmarks.mesh
        self.hm = ch.meshes[self.head]
        self.V = self.hm.mesh.vertices.astype(np.float64)
        self.T = self.hm.mesh.triangles().astype(np.int64)
        if self.hm.mesh.winds_inward():            # inside out: every normal used here turned outward
            self.T = self.T[:, ::-1].copy()
            self.notes.append(f"the triangles of '{self.hm.name}' wind inward (normals into the head, as from an "
                              "inside-out export): its shapes made as on the outward mesh; the file keeps its "
                              "winding, which a viewer culling back faces shows inside out")
        self.lm = ch.landmark_positions()
        self.F = character_frame(ch)
        self.size = float(np.linalg.norm(self.lm[36] - self.lm[45]))

    def find_skin(self) -> None:
        """The face's skin (:func:`~faceretarget.transfer.landmark_skin`: the head mesh's piece that holds the
        landmarks, with the islands sewn to it that hold some), near the face; landmarks that landed on another
        piece (an eyeball, teeth) put on it."""
        ch, V, T = self.ch, self.V, self.T
        centre = self.lm[17:68].mean(axis=0)
        near = np.linalg.norm(V - centre, axis=1) < 1.8 * self.size
        self.skin = landmark_skin(ch)
        self.seams = _island_seams(V, T, np.flatnonzero(self.skin), self.size)
        self.region = self.skin & near
        self.rt = T[self.region[T].all(axis=1)]
        snapped = _onto_skin(ch, V, self.rt, self.region)
        if snapped:
            self.notes.append(f"landmarks {', '.join(map(str, snapped))} were on another piece of '{self.hm.name}' "
                              "(an eyeball, teeth): put on the nearest point of the face's skin")
            self.lm = ch.landmark_positions()

    def register(self) -> None:
        """The template registered onto the skin; each face vertex's closest compatible template point and its
        coverage (1 on the template, fading off it and towards its outer border)."""
        from scipy.spatial import cKDTree

        tmpl, V, size = self.tmpl, self.V, self.size
        t0 = time.perf_counter()
        n_face = int(self.region.sum())
        self.say(f"registering the template {tmpl.name} ({len(tmpl.vertices)} vertices) onto '{self.hm.name}' "
                 f"({n_face} face vertices)")
        if n_face > _DENSE_FACE:
            dense = (f"'{self.hm.name}' has {n_face:,} vertices in the face, {n_face / len(tmpl.vertices):.1f}x the "
                     f"template's: generation takes minutes and may leave triangles turned over at the mouth's "
                     f"corners (a face of 74k vertices: 6 min and 5,319 turned over; of 18.7k: 39 s and none); a "
                     f"copy decimated to {_DENSE_FACE // 1000}k face vertices or fewer is quicker and cleaner")
            self.say(f"{n_face:,} face vertices: this takes minutes (a note follows at the end)")
            self.notes.append(dense)
        reg, info = register_template(tmpl.vertices, tmpl.triangles, (tmpl.lm_triangles, tmpl.lm_bary), V, self.rt,
                                      self.lm, log=self.say)
        self.timings["register"] = time.perf_counter() - t0
        self.reg, self.info = reg, info
        self.sR = (info["s"] * info["R"]).T
        tt = self.tt = tmpl.triangles
        tn = np.cross(reg[tt[:, 1]] - reg[tt[:, 0]], reg[tt[:, 2]] - reg[tt[:, 0]])
        self.tn = tn / np.maximum(np.linalg.norm(tn, axis=1, keepdims=True), 1e-30)
        vn = vertex_normals(V, self.T)
        self.ridx = ridx = np.flatnonzero(self.region)
        t_lm_reg = np.einsum("pk,pkd->pd", tmpl.lm_bary, reg[tmpl.lm_triangles])
        t_side = _mouth_side(reg, t_lm_reg, self.F, size, tt)
        self.t_tri_side = np.sign(t_side[tt].sum(axis=1))
        self.c_side = _mouth_side(V, self.lm, self.F, size, self.T, self.seams)
        self.ctri, self.cbar, cdist = self.corr(V[ridx], vn[ridx], self.c_side[ridx])
        te = np.concatenate([tt[:, [0, 1]], tt[:, [1, 2]], tt[:, [2, 0]]])
        te.sort(axis=1)
        ue, cnt = np.unique(te, axis=0, return_counts=True)
        bverts = np.unique(ue[cnt == 1].ravel())
        blab = components(len(reg), np.c_[ue[cnt == 1], ue[cnt == 1][:, :1]]) if len(bverts) else None
        if blab is not None:
            sizes = np.bincount(blab[bverts])
            outer = bverts[blab[bverts] == sizes.argmax()]
            dborder = cKDTree(reg[outer]).query(reg)[0] / size
        else:
            dborder = np.full(len(reg), np.inf)
        inner_w = np.clip(dborder / 0.25, 0.0, 1.0)
        inner_w = inner_w * inner_w * (3 - 2 * inner_w)
        w_t = np.einsum("nk,nk->n", self.cbar, inner_w[tt[self.ctri]])
        f = np.clip(1.0 - (cdist / size - 0.03) / 0.17, 0.0, 1.0)
        self.w = w = np.zeros(len(V))
        w[ridx] = w_t * f * f * (3 - 2 * f)
        info["coverage_vertices"] = int((w > 0.5).sum())
        self.free = np.flatnonzero(w > 1e-3)
        if len(self.free) < 20:
            raise InvalidDataError(f"{self.ch.name}: the template covers no part of '{self.hm.name}' "
                                   "(registration failed)")

    def corr(self, P, normals, side):
        """Closest compatible template point: a point of the character's upper lip only on the template's
        upper lip, of the lower only on the lower (closed lips touch: nearness alone mixes them)."""
        tt = self.tt
        tri = np.zeros(len(P), np.int64)
        bar = np.zeros((len(P), 3))
        dist = np.zeros(len(P))
        for sd in (-1, 0, 1):
            sel = np.flatnonzero(side == sd)
            if not len(sel):
                continue
            allowed = np.flatnonzero(self.t_tri_side != -sd) if sd else np.arange(len(tt))
            sub = tt[allowed]
            t_, b_, d_ = closest_points(self.reg, sub, P[sel], k=8, normals=self.tn[allowed],
                                        point_normals=normals[sel], min_cos=0.3)
            tri[sel], bar[sel], dist[sel] = allowed[t_], b_, d_
        return tri, bar, dist

    def template_motion(self, a: str) -> np.ndarray:
        """The template's motion of shape ``a`` in the character's frame."""
        return self.tmpl.shapes[a] @ self.sR

    def carried(self, d_t: np.ndarray) -> np.ndarray:
        """A template motion carried to the face vertices at their corresponding points, times coverage."""
        ub = np.zeros((len(self.V), 3))
        ub[self.ridx] = np.einsum("nk,nkd->nd", self.cbar, d_t[self.tt[self.ctri]]) * self.w[self.ridx, None]
        return ub

    def prepare_lips_and_mirror(self, symmetric: bool) -> None:
        """Inner-lip landmarks on the lip that opens with the jaw; a symmetric face's mirror map (its lid
        points made mirror images too)."""
        if "jawOpen" in self.tmpl.shapes:
            moved = _separate_lips(self.ch, self.V, self.carried(self.template_motion("jawOpen")), self.size)
            if moved:
                self.notes.append(f"inner-lip landmarks {', '.join(map(str, moved))} moved onto the lip that opens "
                                  "with the jaw")
        if _lips_one_surface(self.V, self.rt, self.ch.landmarks.triangles, self.ch.landmark_positions()):
            self.notes.append(f"the lips of '{self.hm.name}' are one surface (no opening between them, as on a scan): "
                              "the mouth shapes stretch it instead of parting the lips; for a mouth that opens, cut "
                              "the lips apart along the lip line (and give the mouth an inside) before generating")
        self.mirror = _mirror_map(self.V, self.lm, self.F, self.skin, self.size) if symmetric else None
        if self.mirror is not None:
            _mirror_landmarks(self.ch, self.V, self.rt, self.F, self.mirror[2])
            self.lm = self.ch.landmark_positions()

    def factorise(self) -> None:
        """The system, factorised once: gradients of the free vertices' motion on the triangles that touch
        them, a positional anchor, and the lid and lip landmark rows (points on triangles)."""
        from scipy.sparse import csr_matrix, diags

        V, w, free, size, ch = self.V, self.w, self.free, self.size, self.ch
        self.ft = ft = self.T[(w[self.T] > 1e-3).any(axis=1)]
        self.Gfull = gradient_operator(V, ft)
        self.col = col = np.full(len(V), -1)
        col[free] = np.arange(len(free))
        self.G = self.Gfull[:, free]
        area = triangle_areas(V, ft)
        self.Aw = diags(np.repeat(area, 3))
        self.varea = np.zeros(len(V))
        for k in range(3):
            np.add.at(self.varea, ft[:, k], area / 3.0)
        self.lam = _ANCHOR / size ** 2
        self.pin_ids = pin_ids = sorted({i for p in LID_PAIRS + LIP_PAIRS for i in p})
        ltri, lbar = ch.landmarks.triangles[pin_ids], ch.landmarks.bary[pin_ids]
        rows, cols, vals = [], [], []
        for r, (tv, bv) in enumerate(zip(ltri, lbar, strict=True)):
            for v, b in zip(tv, bv, strict=True):
                if col[v] >= 0 and b != 0:
                    rows.append(r)
                    cols.append(col[v])
                    vals.append(b)
        self.Cm = csr_matrix((vals, (rows, cols)), shape=(len(pin_ids), len(free)))
        self.mu = _PIN * float(self.varea[free].mean()) / size ** 2
        keep = (col[self.seams] >= 0).all(axis=1)
        if len(self.seams) and "jawOpen" in self.tmpl.shapes:   # a closed mouth's lips may touch, and part
            jaw = self.carried(self.template_motion("jawOpen"))
            keep &= np.linalg.norm(jaw[self.seams[:, 0]] - jaw[self.seams[:, 1]], axis=1) <= 0.02 * size
        self.welds = self.seams[keep]
        D = csr_matrix((np.tile([1.0, -1.0], len(self.welds)),
                        (np.repeat(np.arange(len(self.welds)), 2), col[self.welds].ravel())),
                       shape=(len(self.welds), len(free)))
        t0 = time.perf_counter()
        self.K = (self.G.T @ self.Aw @ self.G + self.lam * diags(self.varea[free])
                  + self.mu * (self.Cm.T @ self.Cm) + self.mu * (D.T @ D)).tocsc()
        self.solve = _factorized(self.K)
        # the lid rims (eye openings of the face mesh): a blink pins all of each rim shut, solved with its own
        # factorisation (the rims' rows added), made when a blink needs it
        self.margins = [m for m in lid_margins(V, self.rt, self.lm, self.F) if (col[m.vertices] >= 0).all()] \
            if self.method != "barycentric" else []
        self.margin_solvers: dict = {}
        self.timings["factor"] = time.perf_counter() - t0
        self.say(f"factorised the {len(free)}-vertex system in {self.timings['factor']:.2f} s"
                 + (f"; the lid rims of {len(self.margins)} eye opening(s) found" if self.margins else ""))

    def margin_solve(self, sel: tuple[int, ...]):
        """The system with the rims ``sel`` pinned in place of their eyes' lid landmarks (those rows
        released: a landmark a little off the rim, pinned onto the rims' meeting line too, folded the lid
        between them): the rims' rows, the solve, the released rows' matrix and indices."""
        from scipy.sparse import csr_matrix

        if sel not in self.margin_solvers:
            idx = np.concatenate([self.col[self.margins[i].vertices] for i in sel])
            Cb = csr_matrix((np.ones(len(idx)), (np.arange(len(idx)), idx)), shape=(len(idx), len(self.free)))
            rel = [r for r, i in enumerate(self.pin_ids) if any(i in self.margins[j].eye for j in sel)]
            Cl = self.Cm[rel]
            K = self.K + self.mu * (Cb.T @ Cb) - self.mu * (Cl.T @ Cl)
            self.margin_solvers[sel] = (Cb, _factorized(K.tocsc()), Cl, rel)
        return self.margin_solvers[sel]

    def solve_shape(self, a: str, rhs: np.ndarray, d_t: np.ndarray, pins: np.ndarray) -> np.ndarray:
        """The free vertices' motion (``rhs`` holds the landmark ``pins``): for a blink, the closing lids' rims
        pinned instead of their landmarks."""
        solver, margins = self.solve, self.margins
        if margins and a.startswith("eyeBlink"):
            mt = _margin_targets(a, margins, self.V, self.eyes, self.tmpl, d_t, self.size, self.sR)
            if mt is not None:
                starts = np.cumsum([0] + [len(m.vertices) for m in margins])
                sel = tuple(i for i in range(len(margins)) if not np.isnan(mt[starts[i]:starts[i + 1]]).any())
                if sel:
                    Cb, solver, Cl, rel = self.margin_solve(sel)
                    rows = np.concatenate([np.arange(starts[i], starts[i + 1]) for i in sel])
                    rhs = rhs + self.mu * (Cb.T @ mt[rows]) - self.mu * (Cl.T @ pins[rel])
        return np.column_stack([solver(rhs[:, c]) for c in range(3)])

    def lm_pos(self, D: np.ndarray) -> np.ndarray:
        return self.ch.landmarks.positions(self.V + D)[self.pin_ids]

    def outside(self, x: np.ndarray, a: str | None = None) -> np.ndarray:
        """``x`` with the face's vertices out of the eyeballs, and, for the shape ``a``, out of the lower teeth
        in the shape's poses (:func:`_outside_teeth`)."""
        x = _outside_eyes(x, self.V, self.eyes, self.size)
        if a not in ("jawOpen", "mouthClose") or not self.teeth or self.method == "barycentric":
            return x
        return _outside_teeth(x, self.V, self.teeth, self.chin, self.size,
                              self.added.get("jawOpen") if a == "mouthClose" else None)

    def kept(self, a: str):
        """What a shape's untangling keeps in place while it can (sparse rows over the vertices): the pinned lid
        and lip landmark points, and for a blink the pinned rims instead of their eyes' lid landmarks."""
        return self.keep_rims if a.startswith("eyeBlink") else self.keep

    def poses(self, a: str, jaw) -> tuple:
        """What a shape is untangled in: alone (None) and, a mouth shape of the deformation transfer, on the
        open jaw (``jaw``, the ``jawOpen`` motion; ``mouthClose`` only there: alone it is no pose)."""
        if self.method == "barycentric" or not a.startswith("mouth") or jaw is None:
            return (None,)
        return (jaw,) if a == "mouthClose" else (None, jaw)

    def untangle(self, a: str, u: np.ndarray) -> np.ndarray:
        """The shape's motion with no triangle turned over in its poses (:func:`_untangle`)."""
        return _untangle(self.outside(u, a), self.V, self.ft, self.adj, self.kept(a), self.w <= 1e-3, self.size,
                         poses=self.poses(a, self.added.get("jawOpen")), project=lambda x: self.outside(x, a))

    def transfer_shapes(self) -> None:
        """Every shape: the template's deformation gradients under each character triangle, solved for the free
        vertices with the lids and lips pinned, then pushed out of the eyeballs and untangled."""
        from scipy.spatial import cKDTree

        ch, V, ft, size = self.ch, self.V, self.ft, self.size
        # per character triangle: the template triangle under its centroid; per vertex: coverage
        fnrm = np.cross(V[ft[:, 1]] - V[ft[:, 0]], V[ft[:, 2]] - V[ft[:, 0]])
        fnrm /= np.maximum(np.linalg.norm(fnrm, axis=1, keepdims=True), 1e-30)
        ttri_c, _, _ = self.corr(V[ft].mean(axis=1), fnrm, np.sign(self.c_side[ft].sum(axis=1)))
        wt = self.w[ft].mean(axis=1)
        grad0 = (self.Gfull @ V).reshape(-1, 3, 3)                # per triangle: rows d/dk of x_c -> J[k, c]
        self.parts = find_parts(ch, self.head, self.skin, self.lm, self.F, size)
        self.info["parts"] = [(ch.meshes[p.mesh].name, p.role, p.side, len(p.vertices)) for p in self.parts]
        self.eyes = [p for p in self.parts if p.role == "eye"]
        self.skin_idx = skin_idx = np.flatnonzero(self.skin)
        self.skin_tree = cKDTree(V[skin_idx])
        # the skin the lower teeth keep their place behind: the lower lip (outer and inner landmarks) and the
        # chin's middle.  Fitted to the chin alone, the teeth went down with the skin's stretch and came out
        # through the lower lip on jawOpen (1,829 pixels of teeth showing outside the mouth on a VALID avatar,
        # 0 now)
        jaw_ids = [7, 8, 9, 55, 56, 57, 58, 59, 65, 66, 67]
        self.chin = skin_idx[np.min(np.linalg.norm(V[skin_idx][:, None] - self.lm[None, jaw_ids], axis=2),
                                    axis=1) < 0.08 * size]
        # the lower teeth (each a closed piece that rides the jaw) and the skin about the mouth kept out of them
        mouth = self.lm[60:68].mean(axis=0)
        near = skin_idx[np.linalg.norm(V[skin_idx] - mouth, axis=1) < 0.6 * size]
        self.teeth = [t for t in (_Teeth.of(ch.meshes[p.mesh].mesh.vertices[p.vertices], V, near)
                                  for p in self.parts if p.role == "lower") if t is not None]
        self.pair_rows = {i: r for r, i in enumerate(self.pin_ids)}
        self.added: dict[str, np.ndarray] = {}
        self.shape_notes = {}
        self.adj = _adjacency(len(V), np.r_[ft, self.welds[:, [0, 1, 1]]] if len(self.welds) else ft)
        self.keep = _point_rows(ch.landmarks.triangles[self.pin_ids], ch.landmarks.bary[self.pin_ids], len(V))
        rims = [v for m in self.margins for v in m.vertices]            # a blink's rims, not smoothed open again
        lids = [i for i in self.pin_ids if not any(i in m.eye for m in self.margins)]
        self.keep_rims = _point_rows(np.r_[ch.landmarks.triangles[lids], np.repeat(rims, 3).reshape(-1, 3)],
                                     np.r_[ch.landmarks.bary[lids], np.tile([1.0, 0.0, 0.0], (len(rims), 1))], len(V))
        t0 = time.perf_counter()
        self.order = sorted(self.todo, key=lambda a: (a == "mouthClose", a))           # mouthClose after jawOpen
        free = self.free
        for k, a in enumerate(self.order):
            d_t = self.template_motion(a)                                # the template's motion, character frame
            ub = self.carried(d_t)
            if self.method == "barycentric":
                u = ub
            else:
                Q = _deformation_gradients(self.reg, self.tt, d_t)[ttri_c]
                Q = np.eye(3) + wt[:, None, None] * (Q - np.eye(3))
                target = np.einsum("fkc,fdc->fkd", grad0, Q) - grad0    # J Q^T - J: the gradient of the motion
                pins = ch.landmarks.positions(ub)[self.pin_ids]
                note = _pin_targets(a, pins, self.lm_pos, self.pair_rows, ch, V, self.added, self.eyes, self.tmpl,
                                    d_t, size, self.sR)
                if note:
                    self.shape_notes[a] = note
                rhs = (self.G.T @ (self.Aw @ target.reshape(-1, 3)) + self.lam * self.varea[free, None] * ub[free]
                       + self.mu * (self.Cm.T @ pins))
                u = np.zeros((len(V), 3))
                u[free] = self.solve_shape(a, rhs, d_t, pins)
            self.added[a] = self.untangle(a, u)
            self.say(f"shape {k + 1}/{len(self.order)} {a}")
        self.t_shapes = t0

    def symmetrise(self) -> None:
        """A symmetric face: left/right shapes made mirror images and the others symmetric, then the lids and lips
        closed again where averaging opened them, and untangled: a ``xxxRight`` shape first takes the mirror
        image of what untangling changed in its ``xxxLeft`` but at its own pinned points (untangled on its
        own, each side gave way its own way: ict-face's pairs mirrored to 0.03 %, now 0.003 %)."""
        V, free, added = self.V, self.free, self.added
        _symmetrise(added, self.mirror, self.F)
        changed: dict = {}
        for a in self.order:
            u_s = added[a]
            if self.method != "barycentric":
                pins = self.Cm @ u_s[free]
                _pin_targets(a, pins, self.lm_pos, self.pair_rows, self.ch, V, added, self.eyes, self.tmpl,
                             self.template_motion(a), self.size, self.sR)
                rhs = (self.G.T @ (self.Aw @ (self.Gfull @ u_s)) + self.lam * self.varea[free, None] * u_s[free]
                       + self.mu * (self.Cm.T @ pins))
                u_s = u_s.copy()
                u_s[free] = self.solve_shape(a, rhs, self.template_motion(a), pins)
            u_s = self.outside(u_s)
            if a.endswith("Right") and a[:-5] + "Left" in changed:      # its own pinned points kept
                mc = _mirrored(changed[a[:-5] + "Left"], self.mirror, self.F)
                mc[self.kept(a).tocoo().col] = 0.0
                u_s = u_s + mc
            added[a] = self.untangle(a, u_s)
            changed[a] = added[a] - u_s
        self.notes.append("the face is symmetric: left/right shapes made mirror images and the others symmetric")
        self.mirror_blinks()

    def mirror_blinks(self) -> None:
        """The two blinks made mirror images once more, if both lids stay closed (:data:`CLOSED_PCT`) and no
        more triangles turn over.  Closed again one side at a time (:meth:`symmetrise`), each side follows its
        own triangulation and pins: on a Rocketbox head, symmetric to 0.3 % of the eye-corner distance, the
        blinks ended 6.7 % from mirror images (lids 2.9 % open; made mirror images 0 % and 4.6 %).  A face
        whose two eye openings differ (a VALID avatar's, 17 %) keeps each side's blink: made mirror images,
        its lids stayed 21-42 % open."""
        from ..transfer import lid_gap_pct

        added = self.added
        L, R = added.get("eyeBlinkLeft"), added.get("eyeBlinkRight")
        if L is None or R is None or self.method == "barycentric":
            return
        idx = self.mirror[0]
        left = L.copy()
        left[idx] = 0.5 * (L[idx] + _mirrored(R, self.mirror, self.F)[idx])
        left = self.untangle("eyeBlinkLeft", left)           # the average may turn what each side had unfolded
        right = R.copy()
        right[idx] = _mirrored(left, self.mirror, self.F)[idx]
        right = self.outside(right)
        gaps = [lid_gap_pct(self.ch, "Left", left), lid_gap_pct(self.ch, "Right", right)]
        if any(g is None or g > CLOSED_PCT for g in gaps):
            return
        if self.turned(left) + self.turned(right) > self.turned(L) + self.turned(R):
            return
        added["eyeBlinkLeft"], added["eyeBlinkRight"] = left, right
        self.notes.append(f"the blinks made mirror images (lids {max(gaps):.1f} % open at most)")

    def turned(self, u: np.ndarray) -> int:
        """How many face triangles the motion ``u`` turns over (normal reversed)."""
        n0, ok = self._rest_normals
        return int(_flipped(n0, ok, self.V + u, self.ft).sum())

    @functools.cached_property
    def _rest_normals(self) -> tuple[np.ndarray, np.ndarray]:
        """The face triangles' rest normals and which are not degenerate (:meth:`turned`'s reference)."""
        n0 = _normals(self.V, self.ft)
        return n0, (n0 * n0).sum(axis=1) > 1e-28

    def sewn(self) -> dict:
        """``{mesh: (vertices, {shape: motion})}`` of the pieces sewn to the skin: the smoothest continuation of
        the skin's motion from their seams (:func:`_seam_system`), untangled as the skin's shapes are."""
        by_mesh: dict = {}
        for p in self.parts:
            if p.role == "sewn":
                by_mesh.setdefault(p.mesh, []).append(p.vertices)
        out = {}
        for mi, vs in by_mesh.items():
            m = self.ch.meshes[mi]
            P, T = m.mesh.vertices.astype(np.float64), m.mesh.triangles()
            S = np.unique(np.concatenate(vs))
            B, solve, seam = _seam_system(P, T, S, self.V, self.skin_idx, self.size)
            fixed = np.ones(len(P), bool)
            fixed[S] = False
            TS = T[~fixed[T].any(axis=1)]
            fixed[S[seam]] = True                               # the seams keep the skin's motion
            adj, motion, none = _adjacency(len(P), TS), {}, _point_rows(np.zeros((0, 3), int), np.zeros((0, 3)), len(P))
            for a in self.order:
                d = np.zeros((len(P), 3))
                rhs = B @ self.added[a]
                d[S] = np.column_stack([solve(rhs[:, c]) for c in range(3)])
                motion[a] = _untangle(d, P, TS, adj, none, fixed, self.size,
                                      poses=self.poses(a, motion.get("jawOpen")))
            out[mi] = (S, motion)
        return out

    def result(self) -> GeneratedShapes:
        """The shapes of every mesh: the face's, and the other parts': eyes turn, the lower teeth and tongue ride
        the jaw, pieces sewn to the skin continue its motion, the rest follows the skin."""
        self.timings["shapes"] = time.perf_counter() - self.t_shapes
        ch, todo, added, size = self.ch, self.todo, self.added, self.size
        out: dict[str, dict[str, np.ndarray]] = {self.hm.name: {a: added[a].astype(np.float32) for a in todo}}
        sewn = self.sewn()
        for p in self.parts:
            m = ch.meshes[p.mesh]
            P = m.mesh.vertices[p.vertices].astype(np.float64)
            if p.role == "follow":
                dist, nn = self.skin_tree.query(P)
                fade = np.clip(1.0 - (dist / size - 0.03) / 0.07, 0.0, 1.0)
                if not (fade > 0).any():
                    continue
            dst = out.setdefault(m.name, {})
            for a in todo:
                d = dst.get(a)
                if d is None:
                    d = np.zeros((m.mesh.n_vertices, 3), np.float32)
                if p.role == "eye":
                    Rh = _eye_turn(a, p.side)
                    if Rh is None:
                        continue
                    Rw = self.F.T @ Rh @ self.F
                    d[p.vertices] = (P - p.centre) @ Rw.T + p.centre - P
                elif p.role == "lower":
                    if len(self.chin) < 3:
                        continue
                    Rj, tj = _kabsch(self.V[self.chin], self.V[self.chin] + added[a][self.chin])
                    d[p.vertices] = P @ Rj.T + tj - P
                elif p.role == "follow":
                    d[p.vertices] = added[a][self.skin_idx[nn]] * fade[:, None]
                elif p.role == "sewn":
                    S, motion = sewn[p.mesh]                    # every piece of the mesh sewn on, at once
                    d[S] = motion[a][S]
                else:
                    continue
                dst[a] = d
        out = {mn: {a: d for a, d in sd.items() if np.abs(d).max() > 0} for mn, sd in out.items()}
        out = {mn: sd for mn, sd in out.items() if sd}
        self.timings["total"] = time.perf_counter() - self.t_all
        self.info["coverage"] = self.w
        self.say(f"generated {len(todo)} shapes on {len(out)} mesh(es) in {self.timings['total']:.1f} s")
        return GeneratedShapes(ch, out, self.skipped, self.notes, self.shape_notes, self.timings, self.tmpl.name,
                               self.info, self.replace)


def _seam_system(P: np.ndarray, T: np.ndarray, S: np.ndarray, V: np.ndarray, skin_idx: np.ndarray, size: float):
    """The motion of the vertices ``S`` of a mesh (``P``, ``T``) sewn to the skin (``V[skin_idx]``): the
    smoothest (least squared differences along the edges) that gives each seam vertex the motion of the skin
    vertex it sits on, pieces sewn to each other moving together at their own seams.  Returns ``B`` (sparse,
    ``len(S)`` x ``len(V)``), a solve (the motion of ``S`` is ``solve(B @ u)`` for a motion ``u`` of ``V``)
    and the indices into ``S`` of the seam vertices.
    The nearest skin vertex's motion (``follow``) copied a discontinuous field into the inside of a mouth sewn
    to the lips, and it folded; split as teeth at the lips' line it tore."""
    from scipy.sparse import coo_matrix, diags
    from scipy.spatial import cKDTree

    n, tol, weld = len(S), SEAM * size, 1e4
    loc = np.full(len(P), -1)
    loc[S] = np.arange(n)
    tri = loc[T[(loc[T] >= 0).all(axis=1)]]
    e = np.concatenate([tri[:, [0, 1]], tri[:, [1, 2]], tri[:, [2, 0]]])
    A = coo_matrix((np.ones(2 * len(e)), (np.r_[e[:, 0], e[:, 1]], np.r_[e[:, 1], e[:, 0]])), shape=(n, n)).tocsr()
    A.data[:] = 1.0
    pairs = np.array(sorted(cKDTree(P[S]).query_pairs(tol)), dtype=np.int64).reshape(-1, 2)
    W = coo_matrix((np.full(2 * len(pairs), weld), (np.r_[pairs[:, 0], pairs[:, 1]], np.r_[pairs[:, 1], pairs[:, 0]])),
                   shape=(n, n)).tocsr()
    A = A + W
    dist, nn = cKDTree(V[skin_idx]).query(P[S])
    tw = np.flatnonzero(dist <= tol)
    B = coo_matrix((np.full(len(tw), weld), (tw, skin_idx[nn[tw]])), shape=(n, len(V))).tocsr()
    twin = np.zeros(n)
    twin[tw] = weld
    K = diags(np.asarray(A.sum(axis=1)).ravel() + twin + 1e-9) - A
    return B, _factorized(K.tocsc()), tw


def _factorized(K):
    """A solve of the sparse SPD system ``K`` (CHOLMOD when scikit-sparse is installed: faster)."""
    try:
        from sksparse.cholmod import cholesky

        return cholesky(K)
    except ImportError:
        from scipy.sparse.linalg import factorized

        return factorized(K)


def _template_landmarks(tmpl, d_t: np.ndarray, sR: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The template's 68 landmarks in the character's frame (``sR``: the registration's scaled rotation, row
    vectors) and their motion under ``d_t`` (the template's motion, already in that frame)."""
    return tmpl.landmarks() @ sR, np.einsum("pk,pkd->pd", tmpl.lm_bary, d_t[tmpl.lm_triangles])


def _pin_targets(a, pins, lm_pos, rows, ch, V, added, eyes, tmpl, d_t, size, sR) -> str:
    """Set the lid / lip landmark targets (``pins``, in place) where the shape closes them: a blink puts
    each upper lid point and the lower one facing it on one point (where the template's lids meet,
    outside the eyeball), ``mouthClose`` puts the inner lips of the open jaw together.  ``d_t`` is the
    template's motion in the character's frame, ``sR`` (3, 3) the registration's scaled rotation that put
    it there (row vectors: ``x @ sR``)."""
    rest = lm_pos(np.zeros_like(V))
    if a.startswith("eyeBlink"):
        t_l, t_d = _template_landmarks(tmpl, d_t, sR)
        n = 0
        for up, lo in LID_PAIRS:
            g = t_l[up] - t_l[lo]
            gl = float(np.linalg.norm(g))
            closing = -((t_d[up] - t_d[lo]) @ g) / max(gl * gl, 1e-30)
            if closing < 0.5:
                continue
            gh = g / max(gl, 1e-30)
            mu, ml = float(-(t_d[up] @ gh)), float(t_d[lo] @ gh)
            r = np.clip(ml / max(mu + ml, 1e-30), 0.0, 1.0)
            U0, L0 = rest[rows[up]], rest[rows[lo]]
            M = L0 + r * (U0 - L0)
            eye = min(eyes, key=lambda e: np.linalg.norm(e.centre - M)) if eyes else None
            if eye is not None and np.linalg.norm(eye.centre - M) < 2 * eye.radius:
                rad = eye.radius + _margin(size)
                dvec = M - eye.centre
                if np.linalg.norm(dvec) < rad:
                    M = eye.centre + dvec / max(np.linalg.norm(dvec), 1e-30) * rad
            pins[rows[up]] = M - U0
            pins[rows[lo]] = M - L0
            n += 1
        return f"lids closed at {n} landmark pairs" if n else ""
    if a == "mouthClose" and "jawOpen" in added:
        op = lm_pos(added["jawOpen"])
        t_d = np.einsum("pk,pkd->pd", tmpl.lm_bary, d_t[tmpl.lm_triangles])
        for up, lo in LIP_PAIRS:
            U1, L1 = op[rows[up]], op[rows[lo]]
            a_u, a_l = float(np.linalg.norm(t_d[up])), float(np.linalg.norm(t_d[lo]))
            r = a_u / (a_u + a_l) if a_u + a_l > 0 else 0.5      # how much of the closing the upper lip does
            M = U1 + r * (L1 - U1)
            pins[rows[up]] = M - U1
            pins[rows[lo]] = M - L1
        return "inner lips of jawOpen met"
    return ""


#: A lid is closed when its remaining gap is at most this % of the open gap (issue 25's definition).
CLOSED_PCT = 10.0


def _margin(size: float) -> float:
    return max(0.0003, 0.008 * size)


def _outside_eyes(u: np.ndarray, V: np.ndarray, eyes: list[Part], size: float) -> np.ndarray:
    """Push face vertices that a shape moves into an eyeball back onto its sphere plus a margin (never
    deeper than they sit at rest)."""
    if not eyes:
        return u
    for e in eyes:
        near = np.flatnonzero(np.linalg.norm(V - e.centre, axis=1) < 1.6 * e.radius)
        if not len(near):
            continue
        X = V[near] + u[near]
        d = np.linalg.norm(X - e.centre, axis=1)
        d0 = np.linalg.norm(V[near] - e.centre, axis=1)
        want = np.minimum(d0, e.radius + _margin(size))
        bad = d < want
        if bad.any():
            dirs = (X[bad] - e.centre) / np.maximum(d[bad, None], 1e-30)
            u[near[bad]] = e.centre + dirs * want[bad, None] - V[near[bad]]
    return u


@dataclass
class _Teeth:
    """A lower teeth piece (rest vertices ``P``) and the skin vertices about the mouth not inside its convex hull
    at rest (``skin``), which no shape may put inside it."""

    P: np.ndarray
    skin: np.ndarray

    @classmethod
    def of(cls, P: np.ndarray, V: np.ndarray, near: np.ndarray):
        from scipy.spatial import ConvexHull, QhullError

        P = np.asarray(P, np.float64)
        if len(P) < 8:
            return None
        try:
            h = ConvexHull(P)
        except QhullError:                                # a flat piece has no inside
            return None
        inside = (V[near] @ h.equations[:, :3].T + h.equations[:, 3] < 0).all(axis=1)
        return cls(P, near[~inside])


def _outside_teeth(u: np.ndarray, V: np.ndarray, teeth: list[_Teeth], chin: np.ndarray, size: float,
                   pose: np.ndarray | None) -> np.ndarray:
    """Push the skin about the mouth that a shape (``u``, on ``pose``: the open jaw's motion or None) moves into
    the lower teeth out through the nearest face of their convex hull, plus a margin.  The teeth ride the rigid
    motion of the chin's skin (as :meth:`_Transfer.result` moves them), so a lip that the shape moves less
    than the jaw (``mouthClose`` on ``jawOpen``: the floor of a mouth behind the teeth) ends inside them: 2
    vertices of a demo face did."""
    from scipy.spatial import ConvexHull, QhullError

    if len(chin) < 3:
        return u
    o = np.zeros_like(u) if pose is None else pose
    R1, t1 = _kabsch(V[chin], V[chin] + u[chin])
    R0, t0 = _kabsch(V[chin], V[chin] + o[chin])
    for t in teeth:
        P1 = t.P + (t.P @ R1.T + t1 - t.P) + (t.P @ R0.T + t0 - t.P)
        try:
            eq = ConvexHull(P1).equations
        except QhullError:
            continue
        X = V[t.skin] + o[t.skin] + u[t.skin]
        s = X @ eq[:, :3].T + eq[:, 3]                  # signed distance to each face's plane, < 0 inside
        bad = (s < 0).all(axis=1)
        if bad.any():
            j = s[bad].argmax(axis=1)                   # the nearest face
            u[t.skin[bad]] += (_margin(size) - s[bad, j])[:, None] * eq[j, :3]
    return u


def _mirror_map(V, lm, F, skin, size, tol: float = 0.02):
    """``(idx, mate)``: the face vertices and the vertex at each one's mirror position about the face's
    symmetry plane, when the face is symmetric (mean mirror distance within ``tol`` of ``size``)."""
    from scipy.spatial import cKDTree

    near = np.flatnonzero(skin & (np.linalg.norm(V - lm[17:68].mean(0), axis=1) < 1.8 * size))
    H = V @ F.T
    x0 = float(np.median(H[near, 0]))
    Hm = H[near] * np.array([-1.0, 1.0, 1.0])
    Hm[:, 0] += 2 * x0
    dist, mate = cKDTree(H[near]).query(Hm)
    if float(dist.mean()) > tol * size or float(np.percentile(dist, 95)) > 3 * tol * size:
        return None
    return near, near[mate], x0


#: Eye landmarks and their mirror images (the inner lips are left where the lips were told apart: snapped
#: onto the surface again they could change lips).
_MIRROR_LM = ((36, 45), (37, 44), (38, 43), (39, 42), (40, 47), (41, 46))


def _mirror_landmarks(ch: Character, V: np.ndarray, rt: np.ndarray, F: np.ndarray, x0: float) -> None:
    """Make the eye landmarks of a symmetric face mirror images (each pair moved to the mean of one and the
    other's mirror, then onto the skin), in place on ``ch.landmarks``."""
    from ..character import SurfacePoints

    lm = ch.landmarks
    P = lm.positions(V)
    S = F.T @ np.diag([-1.0, 1.0, 1.0]) @ F
    off = F.T @ np.array([2 * x0, 0.0, 0.0])

    def mirror(x):
        return x @ S.T + off

    idx, want = [], []
    for a, b in _MIRROR_LM:
        pa = 0.5 * (P[a] + mirror(P[b]))
        idx += [a, b]
        want += [pa, mirror(pa)]
    tri, bar, _ = closest_points(V, rt, np.asarray(want), k=16)
    T2, B2 = lm.triangles.copy(), lm.bary.copy()
    T2[idx], B2[idx] = rt[tri], bar
    ch.landmarks = SurfacePoints(lm.mesh, T2, B2, lm.source + "; mirrored")


def _mirrored(d: np.ndarray, mirror, F) -> np.ndarray:
    """The mirror image of a motion ``d`` of the vertices (zero off the mirror map's vertices)."""
    idx, mate, _ = mirror
    out = np.zeros_like(d)
    out[idx] = d[mate] @ (F.T @ np.diag([-1.0, 1.0, 1.0]) @ F).T
    return out


def _symmetrise(added: dict, mirror, F) -> None:
    idx, mate, _ = mirror
    S = F.T @ np.diag([-1.0, 1.0, 1.0]) @ F               # the mirror of a world vector

    def mirrored(d):
        return d[mate] @ S.T

    for a in list(added):
        d = added[a]
        if a.endswith("Left") and a[:-4] + "Right" in added:
            r = added[a[:-4] + "Right"]
            left = d.copy()
            left[idx] = 0.5 * (d[idx] + mirrored(r))
            right = r.copy()
            right[idx] = mirrored(left)
            added[a], added[a[:-4] + "Right"] = left, right
        elif not a.endswith(("Left", "Right")):           # a side shape asked without its mate stays one-sided
            out = d.copy()
            out[idx] = 0.5 * (d[idx] + mirrored(d))
            added[a] = out


_UPPER_INNER, _LOWER_INNER = (61, 62, 63), (65, 66, 67)


def _separate_lips(ch: Character, V: np.ndarray, ub: np.ndarray, size: float) -> list[int]:
    """Put each inner-lip landmark of a closed mouth on its own lip (in place on ``ch.landmarks``): at rest
    the upper and the lower inner-lip points lie on one line, and a point on the wrong lip would keep the
    lips from opening or meeting.  A surface point is on the lower lip when its motion under the template's
    ``jawOpen`` (``ub``) is nearer that of the outer lower-lip middle (point 57) than the upper's (51), along
    the line between the two; a point on the wrong lip moves to the nearest vertex clearly on the right one
    within a tenth of ``size``."""
    from ..character import SurfacePoints

    lm = ch.landmarks
    P = lm.positions(V)
    mot = lm.positions(ub)
    up, lo = mot[51], mot[57]
    if np.linalg.norm(lo - up) < 1e-3 * size:
        return []

    span = lo - up

    def lower_score(M):                    # > 0: moves more like the lower lip than like the upper
        return (M - up) @ span / float(span @ span) - 0.5

    tri, bar = lm.triangles.copy(), lm.bary.copy()
    moved = []
    for group, want_lower in ((_UPPER_INNER, False), (_LOWER_INNER, True)):
        for k in group:
            sk = lower_score(mot[k])
            if (sk > 0.1) if want_lower else (sk < -0.1):        # clearly on its lip already
                continue
            d = np.linalg.norm(V - P[k], axis=1)
            sc = lower_score(ub)
            ok = (d < 0.1 * size) & ((sc > 0.1) if want_lower else (sc < -0.1))
            if not ok.any():
                continue
            v = int(np.flatnonzero(ok)[np.argmin(d[ok])])
            tri[k] = v
            bar[k] = (1.0, 0.0, 0.0)
            moved.append(k)
    if moved:
        ch.landmarks = SurfacePoints(lm.mesh, tri, bar, lm.source + "; inner lips separated by the template's jawOpen")
    return moved


def _mouth_side(P: np.ndarray, lm: np.ndarray, F: np.ndarray, size: float, T: np.ndarray | None = None,
                seams: np.ndarray | None = None) -> np.ndarray:
    """+1 for points of the upper lip, -1 of the lower, 0 elsewhere: in the mouth's zone (between the
    corners, within a third of ``size`` of the lips' line), above or below the inner-lip line (the
    middles of the facing inner-lip landmarks and the corners, interpolated across).

    With the mesh's triangles ``T``, where the mouth is a slit (in the zone the upper lip's surface is not
    joined to the lower's), each lip is the piece of the zone holding its outer landmarks: where closed lips
    touch, their inner surfaces lie on the lips' line and the position alone gave points of one lip to the
    other (on a VALID avatar 21 of 583; their template motion then tore the lip and folded it at ``jawOpen``).
    ``seams`` (pairs of vertices, :func:`_island_seams`) join pieces a seam cut apart (lips cut out as their
    own island: without, the island's points were told by position alone and the lips folded where they
    touch)."""
    H = P @ F.T
    L = lm @ F.T
    xs = [L[60, 0], 0.5 * (L[61, 0] + L[67, 0]), 0.5 * (L[62, 0] + L[66, 0]), 0.5 * (L[63, 0] + L[65, 0]), L[64, 0]]
    ys = [L[60, 1], 0.5 * (L[61, 1] + L[67, 1]), 0.5 * (L[62, 1] + L[66, 1]), 0.5 * (L[63, 1] + L[65, 1]), L[64, 1]]
    order = np.argsort(xs)
    xs, ys = np.asarray(xs)[order], np.asarray(ys)[order]
    line = np.interp(H[:, 0], xs, ys)
    zone = (H[:, 0] > xs[0] + 0.05 * size) & (H[:, 0] < xs[-1] - 0.05 * size) & (np.abs(H[:, 1] - line) < size / 3)
    zone &= np.abs(H[:, 2] - L[60:68, 2].mean()) < size / 3
    out = np.where(zone, np.where(H[:, 1] >= line, 1, -1), 0)
    if T is None or not zone.any():
        return out
    TZ = T[zone[T].all(axis=1)]
    if seams is not None and len(seams):
        sz = seams[zone[seams].all(axis=1)]
        TZ = np.r_[TZ, sz[:, [0, 1, 1]]]
    lab = components(len(P), TZ)
    inz = np.flatnonzero(zone)

    def piece(ids):
        return set(lab[inz[np.argmin(np.linalg.norm(P[inz][:, None] - lm[None, list(ids)], axis=2), axis=0)]])

    up, lo = piece((50, 51, 52)), piece((56, 57, 58))
    if up & lo:                                          # the lips are joined in the zone: positions decide
        return out
    out[zone & np.isin(lab, list(up))] = 1
    out[zone & np.isin(lab, list(lo))] = -1
    return out


def _onto_skin(ch: Character, V: np.ndarray, rt: np.ndarray, region: np.ndarray) -> list[int]:
    """Move landmarks that lie on a piece of the head mesh other than the face's skin (a lid point found on
    an eyeball of the same mesh) to the nearest point of the skin (in place on ``ch.landmarks``)."""
    from ..character import SurfacePoints

    lm = ch.landmarks
    bad = np.flatnonzero(~region[lm.triangles].all(axis=1))
    if not len(bad) or not len(rt):
        return []
    P = lm.positions(V)[bad]
    tri, bar, _ = closest_points(V, rt, P, k=16)
    T2, B2 = lm.triangles.copy(), lm.bary.copy()
    T2[bad], B2[bad] = rt[tri], bar
    ch.landmarks = SurfacePoints(lm.mesh, T2, B2, lm.source + "; snapped onto the skin")
    return [int(b) for b in bad]


def _lips_one_surface(V: np.ndarray, T: np.ndarray, lm_tri: np.ndarray, lm: np.ndarray) -> bool:
    """Whether the lips are one surface (no mouth opening between them: a scan, a sculpt): from each middle upper
    inner-lip landmark (61-63) to the lower one facing it (67-65) the shortest path along the mesh's edges ``T`` is
    under a quarter of the mouth's width; across an opening, even lips that touch at rest, it goes round a corner
    of the mouth or through the mouth's inside (at least about half the width)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import dijkstra

    width = float(np.linalg.norm(lm[54] - lm[48]))
    e = np.unique(np.sort(np.concatenate([T[:, [0, 1]], T[:, [1, 2]], T[:, [2, 0]]]), axis=1), axis=0)
    w = np.linalg.norm(V[e[:, 0]] - V[e[:, 1]], axis=1) + 1e-12
    g = coo_matrix((np.r_[w, w], (np.r_[e[:, 0], e[:, 1]], np.r_[e[:, 1], e[:, 0]])), shape=(len(V), len(V))).tocsr()
    for up, low in ((61, 67), (62, 66), (63, 65)):
        d = dijkstra(g, indices=np.unique(lm_tri[up]), min_only=True, limit=0.25 * width)
        if not np.isfinite(d[np.unique(lm_tri[low])]).any():
            return False
    return True


def _island_seams(V: np.ndarray, T: np.ndarray, skin: np.ndarray, size: float) -> np.ndarray:
    """``(n, 2)`` pairs of ``skin`` vertices at one point (:data:`~faceretarget.transfer.SEAM`) on different
    pieces of the mesh: the seams of islands joined to the skin (a lid or the lips cut out by UV or material
    seams, :func:`~faceretarget.transfer.landmark_skin`).  The solve ties those the template's ``jawOpen``
    moves alike (:meth:`_Transfer.factorise`; left alone, the cut-out lips of arkit-face drifted 17 % of the
    eye-corner distance off their seam at ``jawOpen``), and the lips' sides are told across them
    (:func:`_mouth_side`)."""
    from scipy.spatial import cKDTree

    lab = components(len(V), T)
    pairs = cKDTree(V[skin]).query_pairs(SEAM * size, output_type="ndarray")
    if not len(pairs):
        return np.zeros((0, 2), np.int64)
    pairs = skin[pairs]
    return pairs[lab[pairs[:, 0]] != lab[pairs[:, 1]]]


def _point_rows(tri: np.ndarray, bary: np.ndarray, n: int):
    """Sparse ``(len(tri), n)``: each row a surface point (three vertices and barycentric weights)."""
    from scipy.sparse import coo_matrix

    return coo_matrix((np.ravel(bary), (np.repeat(np.arange(len(tri)), 3), np.ravel(tri))), shape=(len(tri), n)).tocsr()


def _adjacency(n: int, T: np.ndarray):
    """Sparse ``(n, n)`` 0/1 operator: which vertices are neighbours (through ``T``)."""
    from scipy.sparse import coo_matrix

    e = np.concatenate([T[:, [0, 1]], T[:, [1, 2]], T[:, [2, 0]]])
    A = coo_matrix((np.ones(2 * len(e)), (np.r_[e[:, 0], e[:, 1]], np.r_[e[:, 1], e[:, 0]])), shape=(n, n)).tocsr()
    A.data[:] = 1.0
    return A


#: Untangling: each triangle keeps at least this share of its rest area facing its rest side (a margin, so that
#: float32 deltas do not turn it over), and the pinned points' stiffness when they have to give (against 1 per
#: edge for the smoothness of the change).
_FACING, _PIN_STIFF = 0.005, 1e4
#: Face vertices over which generation says it is slow and may fold the mouth's corners: the untangling's
#: linearisation holds for steps small against the triangles (measured: a face of 18.7k vertices, 0 turned
#: over in 39 s; of 74k, 5,319 in 386 s; production heads here have 1.2k-4.7k).
_DENSE_FACE = 25_000


def _normals(X: np.ndarray, T: np.ndarray) -> np.ndarray:
    """Each triangle's (unnormalised) normal."""
    return np.cross(X[T[:, 1]] - X[T[:, 0]], X[T[:, 2]] - X[T[:, 0]])


def _flipped(n0: np.ndarray, ok: np.ndarray, X: np.ndarray, T: np.ndarray) -> np.ndarray:
    """Which triangles (of rest normals ``n0``, ``ok`` the non-degenerate ones) face the other way at ``X``."""
    return ((n0 * _normals(X, T)).sum(axis=1) < 0) & ok


def _untangle(u: np.ndarray, V: np.ndarray, T: np.ndarray, adj, pins, fixed: np.ndarray, size: float,
              poses=(None,), project=None, rings: int = 2, tries: int = 3, soft_tries: int = 2):
    """Unfold the triangles a motion turns over (normal reversed at weight 1, alone or added to each of
    ``poses``): the smallest smooth change of the motion around them (least squared differences of the change
    along the edges) under which every triangle near them keeps facing its rest side (:func:`_facing_solve`).
    The region is the turned triangles' vertices and ``rings`` rings more, doubled while some are left; the
    vertices of ``pins`` (sparse rows: the pinned lid and lip points) move only in the last ``soft_tries``
    tries, and then the pinned points stiffly; ``fixed`` ones (no coverage) never; ``project`` (the eyeball
    push) follows, and what it moves stays for the next try.  A change that moves a vertex further than the
    shape moves any is refused; the motion with the fewest turned over is kept.  With one soft try, the
    eyeball push turned over again what it had unfolded: on Rocketbox's blinks the strip under each upper
    lid's edge, folded back under the lid's front skin (175 degrees between their normals, from 81), 4
    triangles; the second try, the pushed vertices held, unfolds it.

    The relaxation this replaces (half steps towards the neighbours' mean) could only shrink motion: it
    stopped with folds left where a surface folded at rest opens by more than a right angle (the corners of a
    closed mouth at ``jawOpen``), and a smooth fill of the motion (harmonic, or as-rigid-as-possible) did too."""
    n0 = _normals(V, T)
    a2 = (n0 * n0).sum(axis=1)
    ok = a2 > 1e-28                                       # as :func:`~faceretarget.transfer.inverted_triangles`
    pinned = np.zeros(len(V), bool)
    pinned[pins.tocoo().col[pins.tocoo().data != 0]] = True
    offs = [np.zeros_like(u) if p is None else p for p in poses]

    def turned(x):
        out = np.zeros(len(T), bool)
        for o in offs:
            out |= _flipped(n0, ok, V + o + x, T)
        return out

    bad = turned(u)
    best, best_n = u, int(bad.sum())
    sel = np.zeros(len(V), bool)
    r, reach = rings, float(np.abs(u).max())
    for attempt in range(tries + soft_tries):
        if not best_n:
            break
        soft = attempt >= tries                           # the last: the pinned points may give a little
        sel[T[bad].ravel()] = True
        reg = sel.copy()
        for _ in range(r):
            reg |= adj @ reg.astype(float) > 0
        reg &= ~fixed if soft else ~(fixed | pinned)
        r = 2 * r if attempt < tries - 1 else rings
        if reg.any():
            x = _unfold_region(best, V, T, n0, a2, ok, reg, pins * np.sqrt(_PIN_STIFF), offs, size)
            if project is not None:                       # where the eyeball puts them, the next try keeps them
                y = project(x.copy())
                fixed = fixed | (np.abs(y - x).max(axis=1) > 1e-6 * size)
                x = y
            bad = turned(x)
            if int(bad.sum()) < best_n and np.abs(x - u).max() <= reach:      # no wilder than the shape
                best, best_n = x, int(bad.sum())
            bad = turned(best)
    return best


def _unfold_region(u, V, T, n0, a2, ok, reg, pins, offs, size) -> np.ndarray:
    """``u`` changed on the vertices ``reg`` (:func:`_facing_solve` on the triangles that touch them)."""
    from scipy.sparse import coo_matrix, diags

    tri = np.flatnonzero(reg[T].any(axis=1) & ok)
    W = np.unique(T[tri])                                 # the vertices the region's triangles touch
    loc = np.full(len(V), -1)
    loc[W] = np.arange(len(W))
    TL = loc[T[tri]]
    fi = np.flatnonzero(reg[W])                           # which of them move
    fl = np.full(len(W), -1)
    fl[fi] = np.arange(len(fi))
    S = []                                                # gathers each triangle's corner k onto its vertex
    for k in range(3):
        on = np.flatnonzero(fl[TL[:, k]] >= 0)
        S.append(coo_matrix((np.ones(len(on)), (fl[TL[on, k]], on)), shape=(len(fi), len(tri))).tocsr())
    e = np.concatenate([TL[:, [0, 1]], TL[:, [1, 2]], TL[:, [2, 0]]])
    e = fl[np.unique(np.sort(e, axis=1), axis=0)]
    deg = np.bincount(e[e >= 0], minlength=len(fi)).astype(float)   # edges to the still border count too
    e = e[(e >= 0).all(axis=1)]
    A = coo_matrix((np.ones(2 * len(e)), (np.r_[e[:, 0], e[:, 1]], np.r_[e[:, 1], e[:, 0]])),
                   shape=(len(fi), len(fi))).tocsr()
    C = pins[:, W[fi]]                                    # the pinned points' change
    Q = (diags(deg + 1e-3) - A + C.T @ C).tocsr()
    P0 = [(V[W] + o[W] + u[W]) / size for o in offs]      # in units of size
    z = _facing_solve(P0, TL, fi, S, n0[tri] / size ** 2, a2[tri] / size ** 4, Q)
    x = u.copy()
    x[W[fi]] += z.reshape(-1, 3) * size
    return x


def _facing_solve(P0: list, TL: np.ndarray, fi: np.ndarray, S: list, N0: np.ndarray, A2: np.ndarray, Q) -> np.ndarray:
    """The change ``z`` (flattened ``(len(fi), 3)``) of the vertices ``fi`` of the local positions ``P0`` (one
    array per pose) minimising ``z' Q z`` plus ``rho`` times the squared shortfall of each triangle ``TL``
    from facing its rest normal ``N0`` (``|N0|^2 = A2``) by ``_FACING`` (or by as much as it already does, when
    less: a corner squeezed but not turned is no fold), ``rho`` stiffened: Gauss-Newton steps (the shortfall
    linearised; one sparse solve each) with a backtracking line search.  ``S[k]`` gathers a triangle's corner
    ``k`` onto ``fi``."""
    from scipy.sparse import coo_matrix, identity, kron
    from scipy.sparse.linalg import spsolve

    nf = len(fi)
    Q3 = kron(Q, identity(3)).tocsr()
    loc = [np.asarray(Sk.argmax(axis=0)).ravel() for Sk in S]               # each corner's row in fi
    has = [np.asarray(Sk.sum(axis=0)).ravel() > 0 for Sk in S]
    want = []
    for P in P0:
        g0 = (N0 * np.cross(P[TL[:, 1]] - P[TL[:, 0]], P[TL[:, 2]] - P[TL[:, 0]])).sum(axis=1) / A2
        want.append(np.where(g0 > 0, np.minimum(g0, _FACING), _FACING))

    def shortfall(z, rho, jac=False):
        D = z.reshape(-1, 3)
        f, rows, cols, vals, sh = float(z @ (Q3 @ z)), [], [], [], []
        for P, wp in zip(P0, want, strict=True):
            X = P.copy()
            X[fi] += D
            e1, e2 = X[TL[:, 1]] - X[TL[:, 0]], X[TL[:, 2]] - X[TL[:, 0]]
            short = np.maximum(0.0, wp - (N0 * np.cross(e1, e2)).sum(axis=1) / A2)
            f += rho * float((short * short).sum())
            if not jac:
                continue
            act = np.flatnonzero(short > 0)
            g1, g2 = np.cross(e2[act], N0[act]) / A2[act, None], np.cross(N0[act], e1[act]) / A2[act, None]
            r0 = len(sh)
            for k, gk in ((0, -(g1 + g2)), (1, g1), (2, g2)):
                on = has[k][act]
                for c in range(3):
                    rows.append(r0 + np.flatnonzero(on))
                    cols.append(3 * loc[k][act[on]] + c)
                    vals.append(-gk[on, c])                                   # d shortfall / d z
            sh.extend(short[act])
        if not jac:
            return f
        J = coo_matrix((np.concatenate(vals) if vals else [], (np.concatenate(rows) if rows else [],
                                                               np.concatenate(cols) if cols else [])),
                       shape=(len(sh), 3 * nf)).tocsr()
        return f, J, np.asarray(sh)

    z = np.zeros(3 * nf)
    for rho in (1e3, 1e6):
        f_was = np.inf
        for _ in range(40):
            f, J, sh = shortfall(z, rho, jac=True)
            if (not len(sh) or float(sh.max()) <= 0.5 * _FACING) and f > (1.0 - 1e-3) * f_was:
                break                                     # every triangle faces its way, and no more to gain
            f_was = f
            grad = 2.0 * (Q3 @ z) + 2.0 * rho * (J.T @ sh)
            step = spsolve((2.0 * Q3 + 2.0 * rho * (J.T @ J)).tocsc(), -grad)
            t, slope = 1.0, float(grad @ step)
            while t > 1e-4 and shortfall(z + t * step, rho) > f + 1e-4 * t * slope:
                t *= 0.5
            z = z + t * step
            if t * float(np.abs(step).max()) < 1e-9:
                break
    return z


def _margin_targets(a: str, margins: list[LidMargin], V: np.ndarray, eyes, tmpl, d_t, size,
                    sR: np.ndarray) -> np.ndarray | None:
    """Per rim vertex (all margins, in order): its motion closing the lids for ``eyeBlink*`` (each rim point
    and the point facing it on the other lid meet where the template's lids meet, outside the eyeball);
    None when the shape closes no eye.  ``d_t`` and ``sR`` as for :func:`_pin_targets`."""
    t_l, t_d = _template_landmarks(tmpl, d_t, sR)
    parts, closes = [], False
    for m in margins:
        ratios = []
        for up, lo in LID_PAIRS:
            if up not in m.eye:
                continue
            g = t_l[up] - t_l[lo]
            gl = float(np.linalg.norm(g))
            if -((t_d[up] - t_d[lo]) @ g) / max(gl * gl, 1e-30) < 0.5:
                continue
            gh = g / max(gl, 1e-30)
            mu, ml = float(-(t_d[up] @ gh)), float(t_d[lo] @ gh)
            ratios.append(float(np.clip(ml / max(mu + ml, 1e-30), 0.0, 1.0)))
        if not ratios:
            parts.append(None)
            continue
        closes = True
        r = float(np.mean(ratios))                            # how far up from the lower lid they meet
        P0 = V[m.vertices]
        Q0 = np.einsum("nk,nkd->nd", m.weight, V[m.partner])
        U0 = np.where(m.upper[:, None], P0, Q0)
        L0 = np.where(m.upper[:, None], Q0, P0)
        M = L0 + r * (U0 - L0)
        eye = min(eyes, key=lambda e: np.linalg.norm(e.centre - M.mean(axis=0))) if eyes else None
        if eye is not None and np.linalg.norm(eye.centre - M.mean(axis=0)) < 2 * eye.radius:
            rad = eye.radius + _margin(size)
            dv = M - eye.centre
            dn = np.linalg.norm(dv, axis=1, keepdims=True)
            M = np.where(dn < rad, eye.centre + dv / np.maximum(dn, 1e-30) * rad, M)
        parts.append(M - P0)
    if not closes:
        return None
    return np.concatenate([p if p is not None else np.full((len(m.vertices), 3), np.nan)
                           for p, m in zip(parts, margins, strict=True)])
