"""The animation written straight into a copy of the user's binary ``.fbx`` (no Blender).

:func:`write_fbx_animation` reads the character's file as a node tree (:mod:`faceretarget.io._fbx_binary`),
changes only its animation and timing, and writes the tree back; every other record (models, geometry,
skin, blend shapes, materials, texture paths, bind poses, the header's time stamps) is written as the
very bytes it was read from.  What changes:

* the file's own animation (``AnimationStack`` / ``AnimationLayer`` / ``AnimationCurveNode`` /
  ``AnimationCurve`` objects and their connections) is removed, as Blender's exporter writes only the
  take too, and one stack named after the take with one layer takes its place;
* every driven blend shape channel (``BlendShapeChannel`` deformer) gets a ``DeformPercent`` curve node
  and curve: the weight (summed over the channels that bind it, times each bind weight:
  :func:`~faceretarget.character.mesh_columns`) times 100, one linear key per frame;
* the head (and neck, and eye) bones get an ``R`` curve node on ``Lcl Rotation`` with ``X Y Z`` curves
  in degrees, in the node's rotation order, turning the bone by the take's rotation about its rest pose
  exactly as :func:`~faceretarget.character.joint_rotations` does (the node's ``PostRotation`` taken into
  account; its ``PreRotation`` cancels);
* ``Definitions`` counts and templates, ``GlobalSettings`` time mode, frame rate and time span, and
  ``Takes`` say the new take.

Key times start at 0 (the take's first frame), in FBX ticks (46186158000 a second; 141120000 in a
file that opts into FBX 8's ticks with ``TCDefinition`` 0).  The copy is written whole or not at all.

What the writer cannot do (an ASCII FBX, a character not read by ufbx, a shape or bone it cannot find
in the file) is a :class:`DirectWriteUnsupported` naming the reason, so the caller can take the Blender
route instead.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from ..character import Channel, Character, joint_motions, joint_rotations, mesh_columns
from ..errors import FaceRetargetError
from ..files import atomic_path
from ..headpose import HeadPose
from ._fbx_binary import FbxArray, FbxDocument, FbxNode, encode_fbx, is_binary_fbx, parse_fbx

__all__ = ["write_fbx_animation", "DirectWriteUnsupported", "direct_write_problem", "direct_file_problem"]

KTIME_V7, KTIME_V8 = 46186158000, 141120000
_ANIM_TYPES = ("AnimationStack", "AnimationLayer", "AnimationCurveNode", "AnimationCurve")
_SEP = b"\x00\x01"
#: Key attributes as Blender's exporter writes them: linear interpolation (the tangent bits unused).
_KEY_FLAGS = (1 << 2) | (1 << 8) | (1 << 13) | (1 << 14)
_KEY_DATA = (0.0, 0.0, 9.419963346924634e-30, 0.0)
_KEY_VERSION = 4008
#: FBX ``TimeMode`` values of the standard rates (14: custom, with ``CustomFrameRate``).
_TIME_MODES = ((120.0, 1), (100.0, 2), (60.0, 3), (50.0, 4), (48.0, 5), (30.0, 6), (30 / 1.001, 9), (25.0, 10),
               (24.0, 11), (24 / 1.001, 13), (96.0, 15), (72.0, 16), (60 / 1.001, 17), (120 / 1.001, 18))
#: FBX rotation orders (``RotationOrder`` enum) as scipy's extrinsic axis sequences.
_ORDERS = {0: "xyz", 1: "xzy", 2: "yzx", 3: "yxz", 4: "zxy", 5: "zyx", 6: "xyz"}


class DirectWriteUnsupported(FaceRetargetError):
    """The direct writer cannot write this character (the message says why); Blender's route can."""


def direct_write_problem(character: Character) -> str | None:
    """Why :func:`write_fbx_animation` cannot write ``character`` (None when it can): it needs a binary FBX
    read by ufbx (whose joint and mesh names are the file's own)."""
    path = Path(character.path) if character.path is not None else None
    if path is None or not path.is_file():
        return "the character's file is not there"
    if not str(character.route).startswith("ufbx"):
        return f"the character was read by {character.route}, not ufbx"
    return direct_file_problem(path)


def direct_file_problem(path: Path) -> str | None:
    """Why the FBX file ``path`` cannot be edited directly (None when it can): an ASCII FBX or a binary one
    outside versions 7100-7700 (read from its first 27 bytes)."""
    with open(path, "rb") as f:
        head = f.read(27)
    if not is_binary_fbx(head):
        return f"{path.name} is an ASCII FBX"
    version = int.from_bytes(head[23:27], "little")
    if not 7100 <= version < 8000:
        return f"{path.name} is a binary FBX of version {version} (7100-7700 are edited directly)"
    return None


def write_fbx_animation(out: str | os.PathLike, character: Character, chans: list[Channel], W: np.ndarray,
                        t: np.ndarray, *, head: HeadPose | None = None, neck_share: float = 0.0,
                        gaze: dict | None = None, name: str = "faceretarget", log=None) -> Path:
    """Write a copy of the character's binary FBX with the take as its one animation (module docstring).

    Parameters
    ----------
    out : path-like
        The copy (``.fbx``).
    character : Character
        Read from a binary FBX by ufbx (:func:`direct_write_problem`).
    chans : list of Channel
    W : (T, C) float
        One column per channel.
    t : (T,) float
        Seconds, strictly increasing; the first frame is time 0 in the file.
    head, neck_share, gaze
        As :func:`~faceretarget.character.joint_motions`.

    Raises
    ------
    DirectWriteUnsupported
        The file or character is one this writer cannot do (the message says why).
    InputFileError
        The character's file is not a well-formed binary FBX ("X.fbx: truncated binary FBX at byte N").
    """
    log = log or (lambda *_: None)
    out = Path(out)
    problem = direct_write_problem(character)
    if problem is not None:
        raise DirectWriteUnsupported(f"{out}: {problem}")
    src = Path(character.path)
    doc = parse_fbx(src.read_bytes(), str(src))
    scene = _Scene(doc, out)
    scene.drop_animation()
    t = np.asarray(t, dtype=np.float64).reshape(-1)
    ticks = np.round((t - t[0]) * _ktime(doc)).astype(np.int64)
    layer = scene.add_take(name, int(ticks[-1]), t)
    keyed = 0
    for mi, cols in mesh_columns(chans, np.asarray(W, dtype=np.float64)).items():
        ids = scene.shape_channels(character.meshes[mi])
        for k, col in cols.items():
            scene.curve_node(layer, "DeformPercent", ids[k], "DeformPercent", {"DeformPercent": 100.0 * col}, ticks)
            keyed += 1
    placed = []
    for role, j, rot in joint_motions(character, head, neck_share, gaze):
        model = scene.model(j.ref)
        xyz = _lcl_rotation(scene, model, character, j, rot)
        scene.curve_node(layer, "R", model.props[0], "Lcl Rotation", dict(zip("XYZ", xyz.T, strict=True)), ticks)
        placed.append(f"{j.name} ({role})")
    scene.update_definitions()
    data = encode_fbx(doc)
    with atomic_path(out) as tmp:
        Path(tmp).write_bytes(data)
    if placed:
        log(f"head{' and gaze' if gaze else ''} rotation on the character's bone(s): {', '.join(placed)}")
    elif head is not None:
        log(f"{character.name}: no head bone; the head motion is left out of {out.name}")
    log(f"wrote {out} ({len(t)} frames, {keyed} shape curve(s); everything else of {src.name} kept as it was)")
    return out


def _ktime(doc: FbxDocument) -> int:
    """Ticks a second: FBX 7's, unless the file opts into FBX 8's (``OtherFlags/TCDefinition`` 0)."""
    hdr = doc.root.find("FBXHeaderExtension")
    flags = hdr.find("OtherFlags") if hdr is not None else None
    tc = flags.find("TCDefinition") if flags is not None else None
    return KTIME_V8 if tc is not None and tc.props and tc.props[0] == 0 else KTIME_V7


def _name(node: FbxNode) -> str:
    """An object's name without its class (``b"Bip01 Head\\x00\\x01Model"`` -> ``"Bip01 Head"``)."""
    raw = node.props[1] if len(node.props) > 1 else b""
    raw = raw if isinstance(raw, bytes) else str(raw).encode()
    return raw.split(_SEP)[0].decode("utf-8", "replace")


def _p70(node: FbxNode | None) -> dict[str, list]:
    """``{property name: values}`` of a ``Properties70`` block's ``P`` records."""
    p = node.find("Properties70") if node is not None else None
    if p is None:
        return {}
    return {rec.props[0].decode("utf-8", "replace"): rec.props[4:] for rec in p.children if rec.props}


class _Scene:
    """The records :func:`write_fbx_animation` reads and changes: objects by id, connections, templates."""

    def __init__(self, doc: FbxDocument, out: Path):
        self.doc, self.out = doc, out
        root = doc.root
        self.objects = root.find("Objects") or root.add("Objects", block=True)
        self.connections = root.find("Connections") or root.add("Connections", block=True)
        self.by_id = {o.props[0]: o for o in self.objects.children if o.props}
        self.next_id = max((i for i in self.by_id if isinstance(i, int)), default=1_000_000) + 1

    def new_id(self) -> int:
        while self.next_id in self.by_id:
            self.next_id += 1
        self.next_id += 1
        return self.next_id - 1

    def links(self, kind: str = "OO"):
        """``(child, parent)`` ids of the connections of ``kind``, in file order."""
        k = kind.encode()
        return [(c.props[1], c.props[2]) for c in self.connections.children if len(c.props) >= 3 and c.props[0] == k]

    def drop_animation(self) -> None:
        gone = {o.props[0] for o in self.objects.children if o.name in _ANIM_TYPES}
        self.objects.children = [o for o in self.objects.children if o.name not in _ANIM_TYPES]
        self.connections.children = [c for c in self.connections.children
                                     if len(c.props) < 3 or (c.props[1] not in gone and c.props[2] not in gone)]
        for i in gone:
            self.by_id.pop(i, None)

    def add(self, kind: str, name: bytes, cls: bytes, sub: bytes = b"", *, block: bool = False) -> FbxNode:
        node = self.objects.add(kind, self.new_id(), name + _SEP + cls, sub, block=block)
        self.by_id[node.props[0]] = node
        return node

    def connect(self, child: int, parent: int, prop: str | None = None) -> None:
        if prop is None:
            self.connections.add("C", b"OO", child, parent)
        else:
            self.connections.add("C", b"OP", child, parent, prop.encode())

    def add_take(self, name: str, end: int, t: np.ndarray) -> int:
        """The stack and its layer (the layer's id), and the file's time settings and takes for ``0..end``."""
        stack = self.add("AnimationStack", name.encode(), b"AnimStack", block=True)
        props = stack.add("Properties70")
        for p in ("LocalStart", "LocalStop", "ReferenceStart", "ReferenceStop"):
            props.add("P", p.encode(), b"KTime", b"Time", b"", end if p.endswith("Stop") else 0)
        layer = self.add("AnimationLayer", b"BaseLayer", b"AnimLayer", block=True)
        self.connect(layer.props[0], stack.props[0])
        self._time_settings(end, t)
        takes = FbxNode("Takes", block=True)
        takes.add("Current", name.encode())
        take = takes.add("Take", name.encode())
        take.add("FileName", (name + ".tak").encode())
        take.add("LocalTime", 0, end)
        take.add("ReferenceTime", 0, end)
        old = self.doc.root.find("Takes")
        kids = self.doc.root.children
        if old is not None:
            kids[kids.index(old)] = takes
        else:
            kids.append(takes)
        return layer.props[0]

    def _time_settings(self, end: int, t: np.ndarray) -> None:
        from ._blender import blender_timebase

        fps, base, _ = blender_timebase(t, 0.0)
        rate = fps / base
        mode, custom = next(((m, r) for r, m in _TIME_MODES if abs(r - rate) < 1e-4), (14, rate))
        gs = self.doc.root.find("GlobalSettings") or self.doc.root.add("GlobalSettings")
        props = gs.find("Properties70") or gs.add("Properties70")
        for key, kind, label, value, code in (("TimeMode", b"enum", b"", mode, b"I"),
                                              ("TimeSpanStart", b"KTime", b"Time", 0, b"L"),
                                              ("TimeSpanStop", b"KTime", b"Time", end, b"L"),
                                              ("CustomFrameRate", b"double", b"Number", float(custom), b"D")):
            rec = next((r for r in props.children if r.props and r.props[0] == key.encode()), None)
            if rec is None:
                props.add("P", key.encode(), kind, label, b"", value, types=b"SSSS" + code)
            else:
                rec.props[4:] = [value]
                rec.types = rec.types[:4] + code

    def curve_node(self, layer: int, label: str, target: int, prop: str, curves: dict[str, np.ndarray],
                   ticks: np.ndarray) -> FbxNode:
        """A curve node ``label`` on ``target``'s property ``prop`` with one linear curve per item of ``curves``
        (``{"X": values, ...}``, a key at each of ``ticks``)."""
        node = self.add("AnimationCurveNode", label.encode(), b"AnimCurveNode")
        props = node.add("Properties70")
        self.connect(node.props[0], layer)
        self.connect(node.props[0], target, prop)
        times = FbxArray.of(b"l", ticks)
        for item, values in curves.items():
            v = np.asarray(values, dtype=np.float64)
            props.add("P", f"d|{item}".encode(), b"Number", b"", b"A", float(v[0]))
            curve = self.add("AnimationCurve", b"", b"AnimCurve")
            curve.add("Default", float(v[0]))
            curve.add("KeyVer", _KEY_VERSION, types=b"I")
            curve.add("KeyTime", times)
            curve.add("KeyValueFloat", FbxArray.of(b"f", v.astype(np.float32)))
            curve.add("KeyAttrFlags", FbxArray.of(b"i", [_KEY_FLAGS]))
            curve.add("KeyAttrDataFloat", FbxArray.of(b"f", _KEY_DATA))
            curve.add("KeyAttrRefCount", FbxArray.of(b"i", [len(ticks)]))
            self.connect(curve.props[0], node.props[0], f"d|{item}")
        return node

    def model(self, name: str) -> FbxNode:
        """The one ``Model`` object called ``name``."""
        found = [o for o in self.objects.children if o.name == "Model" and _name(o) == name]
        if len(found) != 1:
            raise DirectWriteUnsupported(f"{self.out}: {len(found)} models named '{name}' in the file")
        return found[0]

    def shape_channels(self, sm) -> list[int]:
        """The ``BlendShapeChannel`` id of each shape of scene mesh ``sm`` (ufbx's order: the mesh's blend
        shape deformers, then their channels that have a shape, in connection order; names checked)."""
        model = self.model(sm.ref if sm.ref else sm.name)
        oo = self.links("OO")
        kids: dict[int, list[int]] = {}
        for c, p in oo:
            kids.setdefault(p, []).append(c)
        geo = [c for c in kids.get(model.props[0], []) if getattr(self.by_id.get(c), "name", "") == "Geometry"]
        chans = []
        for g in geo[:1]:
            for d in kids.get(g, []):
                o = self.by_id.get(d)
                if o is None or o.name != "Deformer" or o.props[2] != b"BlendShape":
                    continue
                for c in kids.get(d, []):
                    ch = self.by_id.get(c)
                    if ch is not None and ch.props[2] == b"BlendShapeChannel" and any(
                            getattr(self.by_id.get(s), "name", "") == "Geometry" for s in kids.get(c, [])):
                        chans.append(c)
        names = [_name(self.by_id[c]) for c in chans]
        if names != list(sm.shape_names):
            raise DirectWriteUnsupported(f"{self.out}: the blend shape channels of '{sm.name}' in the file are not "
                                         f"the {len(sm.shape_names)} shapes ufbx read")
        return chans

    def template(self, kind: str) -> dict[str, list]:
        """The ``Definitions`` template properties of object type ``kind``."""
        defs = self.doc.root.find("Definitions")
        for ot in defs.find_all("ObjectType") if defs is not None else []:
            if ot.props and ot.props[0] == kind.encode():
                pt = ot.find("PropertyTemplate")
                return _p70(pt)
        return {}

    def update_definitions(self) -> None:
        """Object counts per type (and the total) as the objects now are; templates for the animation types."""
        defs = self.doc.root.find("Definitions")
        if defs is None:
            defs = FbxNode("Definitions")
            defs.add("Version", 100, types=b"I")
            defs.add("Count", 0, types=b"I")
            kids = self.doc.root.children
            kids.insert(kids.index(self.objects), defs)
        counts: dict[bytes, int] = {}
        for o in self.objects.children:
            counts[o.name.encode()] = counts.get(o.name.encode(), 0) + 1
        have = {ot.props[0] for ot in defs.find_all("ObjectType") if ot.props}
        for kind in _ANIM_TYPES:
            if kind.encode() not in have and counts.get(kind.encode()):
                _add_template(defs, kind)
        total = 0
        for ot in list(defs.find_all("ObjectType")):
            n = 1 if ot.props[0] == b"GlobalSettings" else counts.get(ot.props[0], 0)
            if n == 0 and ot.props[0].decode() in _ANIM_TYPES:
                defs.children.remove(ot)
                continue
            c = ot.find("Count") or ot.add("Count", 0, types=b"I")
            c.props[0] = n
            total += n
        c = defs.find("Count")
        if c is not None:
            c.props[0] = total


def _add_template(defs: FbxNode, kind: str) -> None:
    """An ``ObjectType`` entry for an animation type, with the FBX SDK's default template."""
    ot = defs.add("ObjectType", kind.encode())
    ot.add("Count", 0, types=b"I")
    rows = {"AnimationStack": ("FbxAnimStack", [(b"Description", b"KString", b"", b"", b""),
                                                 *((p, b"KTime", b"Time", b"", 0) for p in (
                                                     b"LocalStart", b"LocalStop", b"ReferenceStart",
                                                     b"ReferenceStop"))]),
            "AnimationLayer": ("FbxAnimLayer", [(b"Weight", b"Number", b"", b"A", 100.0),
                                                 *((p, b"bool", b"", b"", 0) for p in (b"Mute", b"Solo", b"Lock")),
                                                 (b"Color", b"ColorRGB", b"Color", b"", 0.8, 0.8, 0.8),
                                                 *((p, b"enum", b"", b"", 0) for p in (
                                                     b"BlendMode", b"RotationAccumulationMode",
                                                     b"ScaleAccumulationMode")),
                                                 (b"BlendModeBypass", b"ULongLong", b"", b"", 0)]),
            "AnimationCurveNode": ("FbxAnimCurveNode", [(b"d", b"Compound", b"", b"")])}.get(kind)
    if rows is None:
        return
    p70 = ot.add("PropertyTemplate", rows[0].encode()).add("Properties70")
    for row in rows[1]:
        types = b"SSSS" + b"".join(b"D" if isinstance(v, float) else b"I" if row[1] in (b"bool", b"enum") else b"L"
                                   for v in row[4:])
        p70.add("P", *row, types=types)


def _euler_matrix(order: str, xyz_deg) -> np.ndarray:
    """Rotation matrices of FBX Euler angles ``(..., 3)`` (degrees, X Y Z) applied in ``order``."""
    from scipy.spatial.transform import Rotation

    a = np.asarray(xyz_deg, dtype=np.float64).reshape(-1, 3)
    idx = ["xyz".index(c) for c in order]
    return Rotation.from_euler(order, a[:, idx], degrees=True).as_matrix()


def _lcl_rotation(scene: _Scene, model: FbxNode, character: Character, joint, rotation) -> np.ndarray:
    """``(T, 3)`` ``Lcl Rotation`` keys (degrees, X Y Z) of ``model`` turning it by ``rotation`` (head frame)
    about its rest pose, as :func:`~faceretarget.character.joint_rotations` turns the joint.

    The node's local rotation is ``Pre * R * Post^-1`` (``Post`` only with ``RotationActive``, as the FBX
    SDK and Blender's importer read it); turning it by ``D`` (in the node's own frame) asks ``R(t) = R0 *
    Post^-1 * D(t) * Post``, ``D = L^-1 * local(t)`` with ``L`` the rest local rotation ufbx read."""
    from scipy.spatial.transform import Rotation

    from ..character import _rotation_part

    tmpl = scene.template("Model")
    props = {**tmpl, **_p70(model)}

    def vec(key, default):
        v = props.get(key)
        return np.array([float(x) for x in v[:3]]) if v is not None and len(v) >= 3 else np.array(default, float)

    active = bool(props.get("RotationActive", [0])[0])
    order = _ORDERS.get(int(props.get("RotationOrder", [0])[0]), "xyz") if active else "xyz"
    post = _euler_matrix("xyz", vec("PostRotation", (0, 0, 0)))[0] if active else np.eye(3)
    rest = vec("Lcl Rotation", (0, 0, 0))
    R0 = _euler_matrix(order, rest)[0]
    local = Rotation.from_quat(joint_rotations(character, joint, rotation)).as_matrix()
    L = _rotation_part(joint.local if joint.local is not None else np.eye(4))
    D = L.T @ local
    R = R0 @ post.T @ D @ post
    return _continuous_euler(R, order, rest)


def _continuous_euler(R: np.ndarray, order: str, rest: np.ndarray) -> np.ndarray:
    """``(T, 3)`` X Y Z degrees of rotations ``R`` in ``order``: of the two Euler solutions the one nearer
    the rest angles ``rest``, each angle unwrapped over the frames starting next to its rest value (so the
    file's linear keys do not spin the long way round)."""
    from scipy.spatial.transform import Rotation

    e = Rotation.from_matrix(R).as_euler(order, degrees=True)          # angles in the order's sequence
    alt = e + np.array([180.0, 0.0, 180.0])
    alt[:, 1] = 180.0 - e[:, 1]
    idx = ["xyz".index(c) for c in order]
    ref = rest[idx]

    def dist(a):
        return np.abs((a - ref + 180.0) % 360.0 - 180.0).sum(axis=1)

    pick = np.where((dist(alt) < dist(e))[:, None], alt, e)
    first = pick[0] - 360.0 * np.round((pick[0] - ref) / 360.0)
    seq = np.degrees(np.unwrap(np.radians(np.vstack([first, pick])), axis=0))[1:]
    out = np.empty_like(seq)
    out[:, idx] = seq
    return out
