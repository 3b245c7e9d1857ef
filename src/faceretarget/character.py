"""``Character``: a character as a user brings it, and which of its shapes drive the face.

A character file (``.glb``/``.gltf``/``.vrm``, ``.fbx``, ``.blend``, ``.usd*``, or a folder of OBJ key
shapes) holds a whole scene: several meshes (head or body, eyes, teeth, tongue, lashes, hair, clothes),
a skeleton, textures, and face shapes under the file's own names.  The readers in :mod:`faceretarget.io`
turn any of them into one :class:`Character`:

* :class:`SceneMesh` per drawable mesh, at rest, in the file's world frame converted to metres (skinned
  meshes posed by their skeleton's rest pose), with its shapes as world-space deltas under their exact
  names, its triangles, UVs and base-colour materials (for renders);
* :class:`Joint` per skeleton joint (rest world matrices), with the face roles found by name
  (:func:`faceretarget.names.find_joints`: head, neck, jaw, eyes);
* where the file says so, its up and front directions (glTF: +Y up; VRM 0.x faces -Z);
* once found, its 68 landmarks as :class:`SurfacePoints` on the face mesh (points on triangles, not
  vertex indices: a low-poly lip corner has no vertex where the landmark is).

What drives the face (:func:`channels`, :func:`choose_shapes`, :func:`face_rig`): every mesh whose
shapes move the face is driven together.  The mesh with the most face shapes is the primary; a shape
of another face mesh (teeth, tongue, lashes) is *tied* to the primary's shape of the same name (the
namespace and a short mesh prefix looked through: ``h_teeth.t_AE_AA_h`` follows
``h_expressions.AE_AA_h``), so one weight curve moves both, as engines do when they drive morph targets
by name.  :func:`face_rig` makes the one :class:`~faceretarget.rig.Rig` the solvers work on: the face
meshes side by side plus the 68 landmark points as extra vertices, one shape per channel, names kept
exactly as in the file (``keep_names``).

Frames: everything is in the file's world frame (metres).  :attr:`Character.frame` is the rotation
from it to the project's head frame (+Y up, +Z out of the face, +X the character's left;
:mod:`faceretarget.headpose`), found from the file's conventions and the face itself.
"""

from __future__ import annotations

import fnmatch
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .errors import InvalidDataError, MissingShapeError
from .headpose import continuous_quaternions
from .mesh import Mesh
from .names import find_joints, is_arkit, normalize_name
from .rig import Rig

__all__ = ["EncodedImage", "Material", "SceneMesh", "Joint", "SurfacePoints", "Channel", "Character", "ShapeChoice",
           "channels", "expression_channels", "mesh_columns", "choose_shapes", "face_rig", "joint_rotations",
           "character_frame", "joint_motions", "is_viseme", "shape_key", "SHAPE_SETS"]

#: What ``--shapes`` takes besides a list of names: the character's ARKit shapes, its visemes, every
#: face shape, a VRM's expressions, or ``auto`` (a VRM's expressions when it has them; else ARKit when it
#: has at least 10 ARKit shapes, else every face shape).
SHAPE_SETS = ("auto", "arkit", "visemes", "all", "expressions")
#: VRM expressions a VRM runtime sets itself (gaze) or that stand for no expression.
_RUNTIME_EXPRESSIONS = frozenset({"lookUp", "lookDown", "lookLeft", "lookRight", "neutral"})
_MIN_ARKIT = 10
#: The least radius of the head's region around the head joint, metres: a human head's reach from its
#: joint (the face lies within it; a body's muscle shapes outside it).
HEAD_RADIUS_M = 0.15


@dataclass(eq=False)
class Material:
    """What a renderer needs of a surface: base colour (linear RGBA factor), its texture, and how its
    alpha and its back faces are drawn (glTF's ``alphaMode``, ``alphaCutoff`` and ``doubleSided``).

    Attributes
    ----------
    name : str
    color : (4,) float
        Base-colour factor, linear RGBA.
    image_source : (H, W, 4) uint8 array or a function returning one (or None), optional
        Base-colour texture, sRGB, rows top-down (as the file stores it); read through :attr:`image`,
        decoded on first use so a character read only to be driven never decodes its textures.
    alpha_mode : ``"OPAQUE"``, ``"MASK"`` or ``"BLEND"``
        ``OPAQUE``: alpha is ignored; ``MASK``: a pixel whose alpha (factor times texture) is under
        :attr:`alpha_cutoff` is not drawn (hair cards, lashes); ``BLEND``: drawn after the opaque
        surfaces, back to front, blended by its alpha.
    alpha_cutoff : float
        ``MASK``'s threshold (glTF's default 0.5).
    double_sided : bool
        Both sides drawn; else back faces (clockwise as seen) are culled.  glTF says so per material
        (default False); readers of formats that do not say draw both sides.
    """

    name: str = "material"
    color: np.ndarray = field(default_factory=lambda: np.array([0.8, 0.8, 0.8, 1.0]))
    image_source: object = None
    alpha_mode: str = "OPAQUE"
    alpha_cutoff: float = 0.5
    double_sided: bool = True

    @property
    def image(self) -> np.ndarray | None:
        """The texture, decoded on first use (``image_source`` may be an array or a function giving one)."""
        src = self.image_source
        if callable(src):
            self.image_source = src = src()
        return src

    @property
    def has_image(self) -> bool:
        return self.image_source is not None


class EncodedImage:
    """A texture kept encoded (PNG, JPEG, WebP ... bytes, or a file) until a render needs its pixels;
    picklable, so characters travel to worker processes.  Calling it gives ``(H, W, 4)`` uint8 or None
    (and appends a line to ``notes`` when the image cannot be decoded)."""

    def __init__(self, data: bytes | None = None, path: str | None = None, name: str = "", notes: list | None = None):
        self.data, self.path, self.name = data, path, name
        self.notes = notes if notes is not None else []
        self._pixels: np.ndarray | None = None
        self._done = False

    def __getstate__(self):
        return {"data": self.data, "path": self.path, "name": self.name, "notes": self.notes,
                "_pixels": self._pixels, "_done": self._done}

    def __call__(self) -> np.ndarray | None:
        if not self._done:
            import io

            from PIL import Image, UnidentifiedImageError

            self._done = True
            try:
                raw = self.data if self.data is not None else Path(self.path).read_bytes()
                with Image.open(io.BytesIO(raw)) as im:
                    self._pixels = np.asarray(im.convert("RGBA"))
            except (UnidentifiedImageError, OSError, ValueError) as e:
                self.notes.append(f"texture '{self.name}' could not be decoded ({str(e)[:60]}); rendered in its "
                                  "base colour")
        return self._pixels


@dataclass(eq=False)
class SceneMesh:
    """One drawable mesh of a character at rest.

    Attributes
    ----------
    name : str
        The node / object name (unique within the character).
    ref : str
        Where it lives in the file, for writing back: ``"node:12"`` (glTF node index), a Blender object
        name, a USD prim path, an OBJ file.
    mesh : Mesh
        Rest-pose vertices in the file's world frame, metres; triangles; UVs per vertex (glTF's
        top-left convention, ``v`` down) when it has them.
    shape_names : list of str
        Its shapes exactly as the file names them.
    deltas : (K, V, 3) float32
        Each shape's world-space vertex motion at weight 1, metres.
    materials : list of Material
    triangle_material : (F,) int, optional
        Material of each triangle (``mesh.triangles()`` order).
    shape_refs : list of int, optional
        Each shape's index in the file (glTF morph target index); ``range(K)`` when None.
    joint : str, optional
        The joint a rigid mesh follows entirely (an eyeball skinned to ``LeftEye``).
    skin_joints : (V, 4) int, optional / skin_weights : (V, 4) float, optional
        Linear-blend-skinning influences (joint indices into :attr:`Character.joints`), for posing.
    vertex_colors : (V, 4) float, optional
        Per-vertex colour, linear RGBA (glTF's ``COLOR_0``), multiplying the material's base colour.
    """

    name: str
    ref: str
    mesh: Mesh
    shape_names: list[str] = field(default_factory=list)
    deltas: np.ndarray | None = None
    materials: list[Material] = field(default_factory=list)
    triangle_material: np.ndarray | None = None
    shape_refs: list[int] | None = None
    joint: str | None = None
    skin_joints: np.ndarray | None = None
    skin_weights: np.ndarray | None = None
    vertex_colors: np.ndarray | None = None

    def __post_init__(self) -> None:
        V = self.mesh.n_vertices
        K = len(self.shape_names)
        d = np.zeros((0, V, 3), np.float32) if self.deltas is None else np.asarray(self.deltas, np.float32)
        if d.shape != (K, V, 3):
            raise InvalidDataError(f"{self.name}: deltas must be ({K}, {V}, 3) for {K} shapes, got {d.shape}")
        if not np.isfinite(d).all():
            k = int(np.flatnonzero(~np.isfinite(d).reshape(K, -1).all(axis=1))[0])
            raise InvalidDataError(f"{self.name}: shape '{self.shape_names[k]}' has non-finite values")
        self.deltas = d
        if self.vertex_colors is not None:
            c = np.asarray(self.vertex_colors, np.float64)
            if c.ndim != 2 or c.shape[0] != V or c.shape[1] not in (3, 4):
                raise InvalidDataError(f"{self.name}: vertex_colors must be ({V}, 4), got {c.shape}")
            self.vertex_colors = np.concatenate([c, np.ones((V, 1))], axis=1) if c.shape[1] == 3 else c
        if self.shape_refs is None:
            self.shape_refs = list(range(K))

    @property
    def n_shapes(self) -> int:
        return len(self.shape_names)

    def motion(self) -> np.ndarray:
        """(K,) the largest vertex motion of each shape, metres."""
        if self.n_shapes == 0:
            return np.zeros(0)
        if getattr(self, "_motion", None) is None:
            self._motion = np.sqrt(self.vertex_motion2().max(axis=1))
        return self._motion

    def vertex_motion2(self) -> np.ndarray:
        """(K, V) squared motion of every vertex in every shape (computed once)."""
        if getattr(self, "_vm2", None) is None:
            d = self.deltas
            self._vm2 = (d * d).sum(axis=2, dtype=np.float64)
        return self._vm2


@dataclass(eq=False)
class Joint:
    """A skeleton joint at rest.

    Attributes
    ----------
    name : str
    parent : int
        Index of the parent joint in :attr:`Character.joints`, -1 for a root.
    world : (4, 4) float
        Rest world matrix (the file's world frame, metres).
    ref : str
        Where it lives in the file (``"node:33"``, a Blender bone name, a USD joint path).
    local : (4, 4) float, optional
        Rest matrix relative to the parent (what an animation channel replaces).
    """

    name: str
    parent: int
    world: np.ndarray
    ref: str = ""
    local: np.ndarray | None = None

    @property
    def position(self) -> np.ndarray:
        return np.asarray(self.world, dtype=np.float64)[:3, 3]


@dataclass(eq=False)
class SurfacePoints:
    """Points on a mesh's surface: triangle and barycentric coordinates, so they follow every shape.

    Attributes
    ----------
    mesh : int
        Index of the mesh in :attr:`Character.meshes`.
    triangles : (P, 3) int
        The three vertices of the triangle each point lies on.
    bary : (P, 3) float
        Barycentric coordinates (rows sum to 1).
    source : str
        How they were found (``"found on a render"``, ``"cache"``, a landmark file).
    """

    mesh: int
    triangles: np.ndarray
    bary: np.ndarray
    source: str = ""

    def __post_init__(self) -> None:
        self.triangles = np.asarray(self.triangles, dtype=np.int64).reshape(-1, 3)
        self.bary = np.asarray(self.bary, dtype=np.float64).reshape(-1, 3)
        if len(self.triangles) != len(self.bary):
            raise InvalidDataError(f"surface points: {len(self.triangles)} triangles for {len(self.bary)} "
                                   "barycentric rows")

    def __len__(self) -> int:
        return len(self.triangles)

    def positions(self, vertices: np.ndarray) -> np.ndarray:
        """``(P, 3)`` (or ``(T, P, 3)`` for ``(T, V, 3)`` vertices) points on the given vertices."""
        v = np.asarray(vertices)
        return np.einsum("...pkd,pk->...pd", v[..., self.triangles, :], self.bary)

    def matrix(self, n_vertices: int):
        """The ``(P, V)`` sparse matrix taking vertices to these points."""
        from scipy.sparse import csr_matrix

        P = len(self)
        return csr_matrix((self.bary.reshape(-1), (np.repeat(np.arange(P), 3), self.triangles.reshape(-1))),
                          shape=(P, n_vertices))


@dataclass(frozen=True)
class Channel:
    """One weight curve of the character: a primary shape and the shapes of other meshes tied to it, or a
    VRM expression and the morph targets it binds.

    Attributes
    ----------
    name : str
        The primary shape's exact name, or the expression's (what outputs call the curve).
    binds : tuple of (mesh, shape) pairs
        Every shape this curve drives (mesh index in :attr:`Character.meshes`, shape index in it).
    weights : tuple of float, optional
        How much of each bound shape the curve plays at weight 1 (a VRM expression's bind weights); 1 for
        every shape when None.
    """

    name: str
    binds: tuple[tuple[int, int], ...]
    weights: tuple[float, ...] | None = None

    def weighted(self):
        """``(mesh, shape, weight)`` of every bound shape."""
        w = self.weights if self.weights is not None else (1.0,) * len(self.binds)
        return [(mi, k, float(x)) for (mi, k), x in zip(self.binds, w, strict=True)]


@dataclass(eq=False)
class Character:
    """A character file read whole: its meshes, skeleton, shapes and (once found) landmarks.

    Attributes
    ----------
    path : Path or None
        The file (or folder) it came from.
    format : str
        ``"gltf"``, ``"vrm0"``, ``"vrm1"``, ``"fbx"``, ``"blend"``, ``"usd"``, ``"obj"`` or ``"npz"``.
    route : str
        Which reader and decoders it took (``"glTF reader + meshopt + KHR_mesh_quantization"``,
        ``"ufbx"``, ``"Blender 4.5 (bpy)"``, ``"usd-core"``, ...).
    meshes : list of SceneMesh
    joints : list of Joint
    up, front : (3,) float or None
        The character's up and facing directions in the world frame when known.
    landmarks : SurfacePoints, optional
    expressions : dict
        VRM expressions by their VRM 1.0 names: ``{name: {"binds": [(mesh, shape, weight), ...], "preset",
        "binary", "overrides", "colors"}}``.
    notes : list of str
        What the reader skipped or assumed, one line each.
    source_unit : str
        The file's own length unit before conversion to metres.
    named_roles : dict
        ``{role: joint index}`` the file states itself (a VRM's humanoid bones); they win over names.
    face_filter : list of int, optional
        The face mesh chosen by the user (``--mesh``) when the file holds several heads.
    timings : dict
        Seconds spent reading and finding landmarks (set by ``characters.load_character``).
    search : object
        What the landmark search saw (:class:`~faceretarget.capture.LandmarkSearch`), when it ran.
    neutral_head : int, optional
        The head mesh of a character read without face shapes (``load_character(..., need_shapes=False)``,
        :meth:`head_mesh`): where its landmarks are found and its shapes are generated.
    """

    path: Path | None
    format: str
    route: str
    meshes: list[SceneMesh]
    joints: list[Joint] = field(default_factory=list)
    up: np.ndarray | None = None
    front: np.ndarray | None = None
    landmarks: SurfacePoints | None = None
    expressions: dict = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)
    source_unit: str = "m"
    name: str = ""
    named_roles: dict = field(default_factory=dict)
    face_filter: list | None = None
    timings: dict = field(default_factory=dict)
    search: object = None
    neutral_head: int | None = None

    def __post_init__(self) -> None:
        if not self.name:
            self.name = Path(self.path).stem if self.path is not None else "character"
        seen: set[str] = set()
        for m in self.meshes:                                    # unique mesh names for messages and outputs
            base, k = m.name, 2
            while m.name in seen:
                m.name = f"{base}.{k}"
                k += 1
            seen.add(m.name)

    # ------------------------------------------------------------------------------- skeleton
    @property
    def roles(self) -> dict[str, int]:
        """``{role: joint index}`` for head, neck, jaw, leftEye, rightEye (:func:`~faceretarget.names.find_joints`)."""
        found = find_joints([j.name for j in self.joints], [j.parent for j in self.joints])
        found.update({r: int(i) for r, i in self.named_roles.items() if 0 <= int(i) < len(self.joints)})
        return found

    def joint(self, role: str) -> Joint | None:
        i = self.roles.get(role)
        return None if i is None else self.joints[i]

    # ------------------------------------------------------------------------------- face
    def face_meshes(self) -> list[int]:
        """Indices of the meshes whose shapes move the face, the primary first.

        A mesh counts when it has a shape that moves; with a head joint, only shapes that move a
        vertex near the head (within the head-to-neck distance times 3, or a quarter of the
        skeleton's height) count, so a body mesh's muscle shapes do not.
        """
        key = (tuple(self.face_filter or ()), len(self.meshes), len(self.joints))
        if getattr(self, "_face_cache", (None,))[0] == key:
            return list(self._face_cache[1])
        near = self._head_region()
        scored = []
        for i, m in enumerate(self.meshes):
            if m.n_shapes == 0:
                continue
            moving = m.motion() > 1e-7
            if near is not None and moving.any():
                c, r = near
                dist = np.linalg.norm(m.mesh.vertices - c, axis=1)
                close = dist < r
                moved = np.sqrt(m.vertex_motion2()[:, close].max(axis=1, initial=0.0)) > 1e-7
                moving &= moved
            n = int(moving.sum())
            if n:
                scored.append((n, m.mesh.n_vertices, i))
        scored.sort(key=lambda x: (-x[0], -x[1], x[2]))
        order = [i for _, _, i in scored]
        if self.face_filter:
            prim = int(self.face_filter[0])
            if prim not in order:
                order = []
            else:
                pv = self.meshes[prim].mesh.vertices
                c, r = (pv.min(axis=0) + pv.max(axis=0)) / 2.0, 0.75 * float(np.ptp(pv, axis=0).max())
                order = [prim] + [i for i in order if i != prim
                                  and np.linalg.norm(self.meshes[i].mesh.vertices.mean(axis=0) - c) < r]
        self._face_cache = (key, list(order))
        return order

    def _head_region(self) -> tuple[np.ndarray, float] | None:
        head = self.joint("head")
        if head is None:
            return None
        neck = self.joint("neck")
        pos = np.array([j.position for j in self.joints])
        height = float(np.ptp(pos, axis=0).max()) if len(pos) > 1 else 0.0
        r = 3.0 * float(np.linalg.norm(head.position - neck.position)) if neck is not None else 0.0
        # at least a head: a skeleton of a head joint alone (a head node over a face, as write_glb adds) spans
        # nothing, and its 0.25 * height would leave the face outside its own head
        r = max(r, 0.25 * height, HEAD_RADIUS_M)
        return head.position, r

    @property
    def primary(self) -> int:
        """The face mesh with the most face shapes (where the landmarks are found)."""
        face = self.face_meshes()
        if not face:
            if self.neutral_head is not None:
                return int(self.neutral_head)
            raise MissingShapeError(self.no_shapes_message())
        return face[0]

    def head_mesh(self) -> int:
        """The mesh that holds the face, with or without face shapes: the primary face mesh; else the
        ``--mesh`` choice; else the mesh with most vertices in the head joint's region; else the mesh
        with most vertices in the top eighth of the figure (its highest part along :attr:`up`)."""
        face = self.face_meshes()
        if face:
            return face[0]
        if self.face_filter:
            return int(self.face_filter[0])
        if self.neutral_head is not None:
            return int(self.neutral_head)
        drawn = [i for i, m in enumerate(self.meshes) if len(m.mesh.triangles())]
        if not drawn:
            raise InvalidDataError(f"{self.path or self.name}: no mesh with triangles")
        near = self._head_region()
        if near is not None:
            c, r = near
            n = [int((np.linalg.norm(self.meshes[i].mesh.vertices - c, axis=1) < r).sum()) for i in drawn]
            if max(n) > 0:
                return drawn[int(np.argmax(n))]
        up = np.array([0.0, 1.0, 0.0]) if self.up is None else np.asarray(self.up, dtype=np.float64)
        h = [self.meshes[i].mesh.vertices @ up for i in drawn]
        top = max(float(x.max()) for x in h)
        bottom = min(float(x.min()) for x in h)
        cut = top - 0.125 * (top - bottom)
        n = [int((x >= cut).sum()) for x in h]
        return drawn[int(np.argmax(n))]

    def no_shapes_message(self) -> str:
        found = ", ".join(f"{m.name} ({m.mesh.n_vertices} vertices)" for m in self.meshes[:6]) or "no mesh"
        more = f" and {len(self.meshes) - 6} more" if len(self.meshes) > 6 else ""
        return (f"{self.path or self.name}: no face shapes (morph targets / shape keys / blend shapes that move the "
                f"face) in {len(self.meshes)} mesh(es): {found}{more}. Give a character with expression shapes, or "
                "generate them: faceretarget character shapes FILE --out OUT")

    def landmark_positions(self, weights: np.ndarray | None = None, chans: list[Channel] | None = None) -> np.ndarray:
        """The 68 landmarks at rest ``(68, 3)`` (or for channel weights ``(T, C)``: ``(T, 68, 3)``)."""
        if self.landmarks is None:
            raise InvalidDataError(f"{self.name}: no landmarks found yet")
        m = self.meshes[self.landmarks.mesh]
        rest = self.landmarks.positions(m.mesh.vertices)
        if weights is None:
            return rest
        chans = chans if chans is not None else channels(self)
        W = np.asarray(weights, dtype=np.float64)
        D = self._landmark_deltas(chans)
        return rest + np.einsum("tc,cpd->tpd", W.reshape(-1, len(chans)), D).reshape(W.shape[:-1] + (len(rest), 3))

    def _landmark_deltas(self, chans: list[Channel]) -> np.ndarray:
        lm = self.landmarks
        out = np.zeros((len(chans), len(lm), 3))
        d = self.meshes[lm.mesh].deltas
        for c, ch in enumerate(chans):
            for mi, k, w in ch.weighted():
                if mi == lm.mesh:
                    out[c] += w * lm.positions(d[k].astype(np.float64))
        return out

    def summary(self) -> str:
        face = self.face_meshes()
        roles = self.roles
        j = ", ".join(f"{r} {self.joints[i].name}" for r, i in roles.items()) or "no face joints"
        fm = ", ".join(f"{self.meshes[i].name} ({self.meshes[i].n_shapes})" for i in face) or "none"
        return (f"{self.name}: {self.format} via {self.route}; {len(self.meshes)} mesh(es), face meshes: {fm}; "
                f"{len(self.joints)} joints ({j})")


# ------------------------------------------------------------------------------------- channels
_NS = re.compile(r"^.*[.:|/]")
_SEP = re.compile(r"[\s_\-.]+")


def shape_key(name: str) -> str:
    """A shape name compared across meshes: namespace removed, lower case, separators dropped.

    >>> shape_key("h_expressions.AE_AA_h"), shape_key("AE_AA_h")
    ('aeaah', 'aeaah')
    """
    return _SEP.sub("", _NS.sub("", name.strip())).lower()


def _tie_keys(name: str) -> list[str]:
    """Keys under which a secondary mesh's shape may be tied: its own, and without a short mesh prefix
    (``t_AE_AA_h`` -> ``AE_AA_h``) or a short mesh suffix (``jawOpen_teeth``)."""
    bare = _NS.sub("", name.strip())
    keys = [shape_key(bare)]
    m = re.match(r"^[A-Za-z]{1,4}_(.+)$", bare)
    if m:
        keys.append(shape_key(m.group(1)))
    m = re.match(r"^(.+)_[A-Za-z]{1,5}$", bare)
    if m:
        keys.append(shape_key(m.group(1)))
    return keys


def channels(character: Character) -> list[Channel]:
    """The character's weight curves: each face shape of the primary mesh, with the same-named shapes
    of the other face meshes tied to it; a shape of another face mesh with no partner is a curve of
    its own.  Shapes that move nothing are left out."""
    face = character.face_meshes()
    if not face:
        raise MissingShapeError(character.no_shapes_message())
    prim = face[0]
    pm = character.meshes[prim]
    moving = pm.motion() > 1e-7
    out: list[list] = []
    by_key: dict[str, int] = {}
    for k, n in enumerate(pm.shape_names):
        if not moving[k]:
            continue
        by_key.setdefault(shape_key(n), len(out))
        out.append([n, [(prim, k)]])
    for mi in face[1:]:
        m = character.meshes[mi]
        mv = m.motion() > 1e-7
        for k, n in enumerate(m.shape_names):
            if not mv[k]:
                continue
            hit = next((by_key[key] for key in _tie_keys(n) if key in by_key), None)
            if hit is not None and all(b[0] != mi for b in out[hit][1]):
                out[hit][1].append((mi, k))
            else:
                name = n if all(o[0] != n for o in out) else f"{m.name}/{n}"
                by_key.setdefault(shape_key(n), len(out))
                out.append([name, [(mi, k)]])
    return [Channel(n, tuple(b)) for n, b in out]


def expression_channels(character: Character) -> tuple[list[Channel], dict[str, str]]:
    """A VRM's expressions as channels (each the morph targets it binds, with their weights), and why the
    others are left out: gaze expressions (the VRM runtime's look-at sets them), binary ones, those that
    override others or change material colours (a runtime would not play them as a plain sum of targets)."""
    out, skipped = [], {}
    for name, e in character.expressions.items():
        why = ("set by the VRM look-at" if name in _RUNTIME_EXPRESSIONS else "binary" if e["binary"]
               else "overrides other expressions" if e["overrides"] else "changes material colours" if e["colors"]
               else "binds no morph target" if not e["binds"] else None)
        if why:
            skipped[name] = why
            continue
        out.append(Channel(name, tuple((mi, k) for mi, k, _ in e["binds"]), tuple(w for _, _, w in e["binds"])))
    return out, skipped


# ------------------------------------------------------------------------------------- shape sets
_VISEME_WORDS = {"sil", "pp", "ff", "th", "dd", "kk", "ch", "ss", "nn", "rr", "aa", "e", "ee", "ih", "oh", "ou",
                 "i", "o", "u", "a", "mbp", "pbm", "fv", "l", "w", "wq", "r", "s", "sh", "t", "k"}


def is_viseme(name: str) -> bool:
    """Whether a shape name is a viseme's: ``viseme_aa``, ``V_Open``, Oculus (``sil``, ``PP``, ``FF``,
    ... ``U``), VRM (``aa``, ``ih``, ``ou``, ``ee``, ``oh``), VRoid ``Fcl_MTH_A``, numbered sets such as
    ``AA_VI_10_aa``.

    >>> [is_viseme(n) for n in ("viseme_sil", "blendShape1.AA_VI_01_PP", "Fcl_MTH_A", "ou", "jawOpen")]
    [True, True, True, True, False]
    """
    bare = _NS.sub("", name.strip())
    low = bare.lower()
    if "viseme" in low or re.match(r"^(?:v|vis|vi)[_\- ]", low) or re.search(r"(?:^|_)vi_\d", low):
        return True
    if re.match(r"^fcl_mth_[aiueo]$", low):
        return True
    return _SEP.sub("", low) in _VISEME_WORDS


@dataclass
class ShapeChoice:
    """Which channels drive the face and why the others stay at rest.

    Attributes
    ----------
    drive : list of int
        Indices into the channel list, in channel order.
    rest : dict
        ``{reason: [channel names]}`` for the channels left at rest.
    basis : str
        What was chosen (``"arkit"``, ``"visemes"``, ``"all"`` or ``"names"``).
    """

    drive: list[int]
    rest: dict[str, list[str]]
    basis: str

    def summary(self, chans: list[Channel]) -> str:
        """One line: which shapes drive, which stay at rest and why."""
        total = len(chans)
        parts = [f"drives {len(self.drive)} of {total} shape curve(s) ({self.basis})"]
        for why, names in self.rest.items():
            shown = ", ".join(names[:4]) + (f" ... (+{len(names) - 4})" if len(names) > 4 else "")
            parts.append(f"{len(names)} at rest ({why}: {shown})")
        return "; ".join(parts)


def choose_shapes(chans: list[Channel], spec: str = "auto", landmark_motion: np.ndarray | None = None,
                  *, who: str = "character") -> ShapeChoice:
    """Choose the channels that drive the face.

    Parameters
    ----------
    chans : list of Channel
    spec : str
        ``"auto"`` (ARKit when the character has >= 10 ARKit shapes, else all), ``"arkit"``, ``"visemes"``,
        ``"all"``, or comma-separated names / ``fnmatch`` patterns (exact names, any case).
    landmark_motion : (C, P, 3) float, optional
        Each channel's motion of the landmark points: channels that move no landmark (less than 1 % of
        the largest) cannot be seen by a landmark solve and stay at rest, and of two near-duplicate
        channels (same landmark motion within 5 %) only the first drives.
    who : str
        For messages.

    Returns
    -------
    ShapeChoice
    """
    names = [c.name for c in chans]
    arkit = _arkit_channels(names)
    visemes = [i for i, n in enumerate(names) if is_viseme(n)]
    rest: dict[str, list[str]] = {}
    spec = (spec or "auto").strip()
    if spec == "auto":
        spec = "arkit" if len(arkit) >= _MIN_ARKIT else "all"
    if spec == "arkit":
        if not arkit:
            raise MissingShapeError(f"{who}: --shapes arkit: no ARKit-named shape among {len(names)} "
                                    f"(e.g. {', '.join(names[:4])}); use --shapes all or name them")
        drive = sorted(arkit.values())
        dup = [names[i] for i in sorted(set(_arkit_all(names)) - set(drive))]
        if dup:
            rest["same ARKit name as a shape that drives"] = dup
        vis = [names[i] for i in visemes if i not in drive]
        if vis:
            rest["visemes; --shapes visemes to use them"] = vis
        other = [names[i] for i in range(len(names)) if i not in drive and i not in visemes and names[i] not in dup]
        if other:
            rest["not ARKit; --shapes all to use them"] = other
    elif spec == "visemes":
        if not visemes:
            raise MissingShapeError(f"{who}: --shapes visemes: no viseme shape among {len(names)} "
                                    f"(e.g. {', '.join(names[:4])})")
        drive = visemes
        other = [names[i] for i in range(len(names)) if i not in drive]
        if other:
            rest["not visemes"] = other
    elif spec == "all":
        drive = list(range(len(names)))
    else:
        pats = [p.strip() for p in spec.split(",") if p.strip()]
        drive = []
        for p in pats:
            hit = [i for i, n in enumerate(names)
                   if fnmatch.fnmatchcase(n.lower(), p.lower()) or shape_key(n) == shape_key(p)]
            if not hit:
                raise MissingShapeError(f"{who}: --shapes: no shape named '{p}' (the character has "
                                        f"{', '.join(names[:6])}{' ...' if len(names) > 6 else ''})")
            drive += [i for i in hit if i not in drive]
        drive.sort()
        other = [names[i] for i in range(len(names)) if i not in drive]
        if other:
            rest["not named in --shapes"] = other
        spec = "names"
    if landmark_motion is not None and drive:
        # an ARKit shape the landmarks do not see (gaze, tongue, cheek squint) still follows the tracker's score
        seen_anyway = set(_arkit_channels(names).values())
        drive = _seen_and_distinct(drive, names, np.asarray(landmark_motion, dtype=np.float64), rest, seen_anyway)
    if not drive:
        raise MissingShapeError(f"{who}: none of the chosen shapes moves the face's landmarks")
    return ShapeChoice(drive, rest, spec)


def _arkit_all(names: list[str]) -> list[int]:
    return [i for i, n in enumerate(names) if is_arkit(normalize_name(n))]


def _arkit_channels(names: list[str]) -> dict[str, int]:
    """``{ARKit name: channel}``: of several channels spelling one ARKit shape, the one whose own name
    (namespace and set index removed) is spelt most like ARKit's."""
    best: dict[str, tuple[int, int]] = {}
    for i in _arkit_all(names):
        a = normalize_name(names[i])
        bare = _NS.sub("", names[i])
        bare = re.sub(r"^[A-Za-z]{1,3}_?\d{1,3}[_ .\-]+", "", bare)
        score = 0 if bare == a else 1 if bare.lower() == a.lower() else 2 if shape_key(bare) == a.lower() else 3
        if a not in best or score < best[a][0]:
            best[a] = (score, i)
    return {a: i for a, (_, i) in best.items()}


def _seen_and_distinct(drive: list[int], names: list[str], M: np.ndarray, rest: dict,
                       seen_anyway: set = frozenset()) -> list[int]:
    """Drop channels that move no landmark (but those in ``seen_anyway``, which a tracker's score drives)
    and later near-duplicates of earlier ones."""
    flat = M.reshape(len(M), -1)
    norm = np.linalg.norm(flat, axis=1)
    top = float(norm[drive].max()) if drive else 0.0
    keep: list[int] = []
    unseen, dups = [], []
    for i in drive:
        if norm[i] <= 0.01 * top:
            if i in seen_anyway:
                keep.append(i)
            else:
                unseen.append(names[i])
            continue
        twin = next((j for j in keep if norm[j] > 0.01 * top
                     and np.linalg.norm(flat[i] - flat[j]) <= 0.05 * max(norm[i], norm[j])), None)
        if twin is not None:
            dups.append(f"{names[i]} = {names[twin]}")
            continue
        keep.append(i)
    if unseen:
        rest["move no landmark"] = unseen
    if dups:
        rest["near-duplicates"] = dups
    return keep


# ------------------------------------------------------------------------------------- face rig
def face_rig(character: Character, chans: list[Channel] | None = None, drive: list[int] | None = None, *,
             frame: bool = True) -> Rig:
    """The one rig the solvers work on: the face meshes side by side (primary first), plus the 68
    landmark points as extra vertices when found, with one shape per driving channel.

    Parameters
    ----------
    character : Character
    chans : list of Channel, optional
        Default :func:`channels`.
    drive : list of int, optional
        The channels to include (default all).
    frame : bool
        Rotate into the head frame (:attr:`Character.frame`: +Y up, +Z out of the face) when the front
        is known.

    Returns
    -------
    Rig
        Unit ``"m"``; ``names`` the channels' exact names (``keep_names``); ``landmarks`` the indices
        of the 68 landmark vertices when found.
    """
    chans = channels(character) if chans is None else chans
    drive = list(range(len(chans))) if drive is None else list(drive)
    face = character.face_meshes()
    used = sorted({mi for c in drive for mi, _ in chans[c].binds}, key=face.index)
    lm = character.landmarks
    if lm is not None and lm.mesh not in used:
        used.insert(0, lm.mesh)
    offsets, verts, counts, idx = {}, [], [], []
    n = 0
    for mi in used:
        m = character.meshes[mi].mesh
        offsets[mi] = n
        verts.append(m.vertices)
        counts.append(m.face_counts)
        idx.append(m.face_indices + n)
        n += m.n_vertices
    P = 0
    if lm is not None:
        verts.append(character.landmark_positions())
        P = len(lm)
    V = n + P
    D = np.zeros((len(drive), V, 3))
    for r, c in enumerate(drive):
        for mi, k, w in chans[c].weighted():
            if mi in offsets:
                m = character.meshes[mi]
                D[r, offsets[mi]:offsets[mi] + m.mesh.n_vertices] += w * m.deltas[k]
        if lm is not None:
            d = character.meshes[lm.mesh].deltas
            for mi, k, w in chans[c].weighted():
                if mi == lm.mesh:
                    D[r, n:] += w * lm.positions(d[k].astype(np.float64))
    vertices = np.concatenate(verts) if verts else np.zeros((0, 3))
    R = character_frame(character) if frame else np.eye(3)
    vertices = vertices @ R.T
    D = D @ R.T
    mesh = Mesh(vertices, np.concatenate(counts) if counts else np.zeros(0, np.int64),
                np.concatenate(idx) if idx else np.zeros(0, np.int64), name=character.name)
    return Rig(mesh, [chans[c].name for c in drive], D, unit="m",
               landmarks=None if lm is None else np.arange(n, V), source_names=[chans[c].name for c in drive],
               name=character.name, keep_names=True)


def character_frame(character: Character) -> np.ndarray:
    """``(3, 3)`` rotation from the file's world frame to the head frame (+Y up, +Z out of the face, +X
    the character's left); the identity while the front is unknown."""
    up = np.array([0.0, 1.0, 0.0]) if character.up is None else np.asarray(character.up, dtype=np.float64)
    if character.front is None:
        return np.eye(3) if np.allclose(up, [0, 1, 0]) else _basis(up, _any_perpendicular(up))
    return _basis(up, np.asarray(character.front, dtype=np.float64))


def _any_perpendicular(up: np.ndarray) -> np.ndarray:
    a = np.array([0.0, 0.0, 1.0]) if abs(up[2]) < 0.9 else np.array([0.0, -1.0, 0.0])
    return a - up * (a @ up)


def _basis(up: np.ndarray, front: np.ndarray) -> np.ndarray:
    y = up / np.linalg.norm(up)
    z = front - y * (front @ y)
    z = z / np.linalg.norm(z)
    x = np.cross(y, z)
    return np.stack([x, y, z])


def _rotation_part(M: np.ndarray) -> np.ndarray:
    """The proper rotation of a 3x3 (or 4x4) matrix with scale (polar decomposition)."""
    A = np.asarray(M, dtype=np.float64)[:3, :3]
    U, _, Vt = np.linalg.svd(A)
    R = U @ Vt
    if np.linalg.det(R) < 0:
        U[:, -1] *= -1
        R = U @ Vt
    return R


def joint_rotations(character: Character, joint: Joint, rotation) -> np.ndarray:
    """Local rotation keys of ``joint`` that turn it by ``rotation`` (head frame) about its rest pose.

    ``local(t) = local_rest * (G^-1 R_w(t) G)``: ``G`` the joint's rest world rotation and ``R_w`` the rotation
    (a :class:`scipy.spatial.transform.Rotation` of ``T`` keys in the head frame: +Y up, +Z out of the face)
    in the file's world frame.  The joint then ends at ``R_w`` times its rest world rotation, turned further by
    whatever turns its parents (an eye with the head).

    Returns
    -------
    (T, 4) float
        Quaternions ``x, y, z, w`` (consecutive keys on one hemisphere).
    """
    from scipy.spatial.transform import Rotation

    F = character_frame(character)
    Rw = F.T @ rotation.as_matrix() @ F                              # (T, 3, 3) in the world frame
    G = _rotation_part(joint.world)
    L = _rotation_part(joint.local if joint.local is not None else np.eye(4))
    local = L @ (G.T @ Rw @ G)
    return continuous_quaternions(Rotation.from_matrix(local).as_quat())


def joint_motions(character: Character, head=None, neck_share: float = 0.0, gaze: dict | None = None) -> list:
    """Which joints of the character move and how: ``(role, joint, rotation)``, the rotation (head frame, a
    :class:`scipy.spatial.transform.Rotation` per frame) relative to the joint's rest pose.

    The head pose (a :class:`~faceretarget.headpose.HeadPose`) goes on the head joint, ``neck_share`` of it on
    the neck (the head ends at the whole rotation: the two turn about one axis); ``gaze``
    (``{"leftEye": Rotation, "rightEye": Rotation}``, each relative to the head) on the eye joints.  Roles the
    character has no joint for are left out."""
    from scipy.spatial.transform import Rotation

    out = []
    if head is not None:
        roles = (("head", 1.0 - neck_share), ("neck", neck_share)) if neck_share > 0 else (("head", 1.0),)
        for role, share in roles:
            j = character.joint(role)
            if j is not None:
                out.append((role, j, Rotation.from_rotvec(head.rotation.as_rotvec() * share)))
    for role, rot in (gaze or {}).items():
        j = character.joint(role)
        if j is not None:
            out.append((role, j, rot))
    return out


def mesh_columns(chans: list[Channel], W: np.ndarray) -> dict[int, dict[int, np.ndarray]]:
    """``{scene mesh: {shape index: (T,) weight}}`` of every shape a channel drives (the sum over the
    channels that bind it, each times its bind weight)."""
    out: dict[int, dict[int, np.ndarray]] = {}
    for c, ch in enumerate(chans):
        for mi, k, w in ch.weighted():
            col = out.setdefault(mi, {})
            col[k] = col[k] + w * W[:, c] if k in col else w * W[:, c]
    return out
