"""FBX characters read whole with ufbx (binary and ASCII FBX 6 / 7), no Blender needed.

:func:`read_fbx_character` loads the file with `ufbx <https://ufbx.github.io>`_'s Python binding, asking
it to convert the scene to metres and +Y up whatever the exporter's axes and unit (Rocketbox and 3ds
Max: centimetres; Maya: either), and builds a :class:`~faceretarget.character.Character`:

* every mesh instance (node) is a :class:`~faceretarget.character.SceneMesh`: its control points (the
  vertex order Blender's FBX importer keeps too), polygons, the first UV set (flipped to glTF's top-left
  convention), posed at rest in world space by its skin clusters (``bone world x geometry-to-bone``,
  linear blend) or its node;
* every blend shape channel is a shape under the channel's full name (``blendShape1.AK_25_JawOpen``);
  an in-between channel takes its key at full weight;
* every node is a :class:`~faceretarget.character.Joint` (``ref`` the node name), so ``Bip01 Head``,
  ``mixamorig:Head`` and the like are found by role;
* base-colour textures are read from the file when embedded, else from the path it names (relative to
  the FBX first); a texture that cannot be found is a note and the mesh renders in its colour.

The binding (ufbx 0.0.5 on PyPI) frees parts of the scene when some of its Python wrappers are dropped,
and a later access then crashes the process.  So every wrapper is kept referenced until the whole
character is copied to NumPy, and the reading runs in a child Python process (also from a Dask worker,
which may not fork): a crash of the binding on some file is an :class:`~faceretarget.errors.InputFileError` saying
so, never the end of the user's program.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from ..character import Character, EncodedImage, Joint, Material, SceneMesh
from ..errors import InputFileError, excerpt
from ..mesh import Mesh
from ..optional import optional_import

__all__ = ["read_fbx_character"]


def _ufbx():
    return optional_import("ufbx", "reading .fbx characters (pip install ufbx)")


def _mat(m) -> np.ndarray:
    """A ufbx Matrix (four columns) as a 4 x 4 array."""
    A = np.eye(4)
    A[:3, :] = np.array([list(m.c0), list(m.c1), list(m.c2), list(m.c3)], dtype=np.float64).T
    return A


def read_fbx_character(path: str | os.PathLike) -> Character:
    """Read an ``.fbx`` character (module docstring).

    Raises
    ------
    InputFileError
        Not an FBX file ufbx can read (its own message, naming the file).
    """
    path = Path(path)
    if not path.is_file():
        raise InputFileError(f"{path}: file not found" if not path.exists() else f"{path}: is not a file")
    _ufbx()                                          # a missing package is reported here, in the parent
    return _in_child(path)


def _in_child(path: Path) -> Character:
    """Read ``path`` in a child Python process (a crash of the binding ends only the child); works from a
    daemonic process too (a Dask worker), where ``multiprocessing`` may not start children."""
    import pickle
    import subprocess
    import sys
    import tempfile

    with tempfile.TemporaryDirectory(prefix="faceretarget-fbx-") as d:
        out = Path(d) / "character.pickle"
        code = "import sys; from faceretarget.io._fbx_scene import _child; _child(sys.argv[1], sys.argv[2])"
        try:
            r = subprocess.run([sys.executable, "-c", code, str(path), str(out)], capture_output=True, timeout=300)
        except subprocess.TimeoutExpired:
            raise InputFileError(f"{path}: the FBX reader (ufbx) did not finish in 300 s") from None
        if r.returncode != 0 or not out.is_file():
            raise InputFileError(f"{path}: the FBX reader (ufbx) stopped on this file (exit code {r.returncode}); "
                                 "open it in Blender and save it as .blend or .glb, then use that file")
        kind, payload = pickle.loads(out.read_bytes())
    if kind == "error":
        raise InputFileError(payload)
    return payload


def _child(path: str, out: str) -> None:
    """The child's side of :func:`_in_child`: read, pickle to ``out``, and leave without cleaning up."""
    import pickle

    keep: list = []                          # the binding's wrappers live until the process ends
    try:
        res = ("ok", _read_here(Path(path), keep))
    except InputFileError as e:
        res = ("error", str(e))
    except Exception as e:  # anything else the binding raises: one line naming the file
        res = ("error", f"{path}: the FBX reader failed ({type(e).__name__}: {excerpt(e, 100)})")
    with open(out, "wb") as f:
        pickle.dump(res, f, protocol=pickle.HIGHEST_PROTOCOL)
        f.flush()
        os.fsync(f.fileno())
    os._exit(0)                              # no clean-up of the wrappers (see the module docstring)


def _read_here(path: Path, keep: list) -> Character:
    ufbx = _ufbx()
    try:
        scene = ufbx.load_file(
            str(path), target_axes=ufbx.CoordinateAxes(ufbx.CoordinateAxis.POSITIVE_X, ufbx.CoordinateAxis.POSITIVE_Y,
                                                        ufbx.CoordinateAxis.POSITIVE_Z),
            target_unit_meters=1.0, load_external_files=False, ignore_missing_external_files=True,
            ignore_animation=True)
    except Exception as e:  # ufbx raises its own error classes (UfbxError subclasses)
        raise InputFileError(f"{path}: not an FBX file ufbx can read ({excerpt(e, 100)})") from e
    keep.append(scene)
    return _character(path, scene, keep)


def _character(path: Path, scene, keep: list) -> Character:
    notes: list[str] = []
    nodes = keep_(keep, scene.nodes)
    n_nodes = len(nodes)
    node_list = [keep_(keep, nodes[i]) for i in range(n_nodes)]
    ids = {node_list[i].element_id: i for i in range(n_nodes)}
    parent = [-1] * n_nodes
    for i, nd in enumerate(node_list):
        ch = keep_(keep, nd.children)
        for k in range(len(ch)):
            parent[ids[keep_(keep, ch[k]).element_id]] = i
    joints, names = [], []
    for i, nd in enumerate(node_list):
        p = parent[i]
        name = nd.name or ("root" if nd.is_root else f"node{i}")
        names.append(name)
        joints.append(Joint(name, p, _mat(nd.node_to_world), name, _mat(nd.node_to_parent)))
    # the scene root adds the unit and axis conversion: it is not a joint a user animates
    meshes: list[SceneMesh] = []
    unit = float(scene.settings.unit_meters) if scene.settings.unit_meters else 1.0
    source_unit = {0.01: "cm", 1.0: "m", 0.001: "mm", 0.0254: "in"}.get(round(unit, 4), f"{unit:g} m")
    textures: dict[str, object] = {}
    for i, nd in enumerate(node_list):
        fm = keep_(keep, nd.mesh)
        if fm is None:
            continue
        sm = _mesh(path, nd, fm, names[i], ids, notes, textures, keep)
        if sm is not None:
            meshes.append(sm)
    ch = Character(path, "fbx", "ufbx", meshes, joints, up=np.array([0.0, 1.0, 0.0]), front=None,
                   notes=notes, source_unit=source_unit)
    return ch


def keep_(keep: list, obj):
    """``obj``, kept referenced until the read is over (see the module docstring)."""
    keep.append(obj)
    return obj


def _mesh(path: Path, nd, fm, name: str, ids: dict, notes: list, textures: dict, keep: list) -> SceneMesh | None:
    verts = np.asarray(fm.vertices, dtype=np.float64).reshape(-1, 3)
    V = len(verts)
    if V == 0:
        return None
    vi = np.asarray(keep_(keep, fm.vertex_indices), dtype=np.int64)
    faces = keep_(keep, fm.faces)
    fl = [keep_(keep, faces[k]) for k in range(len(faces))]
    counts = np.array([f.num_indices for f in fl], dtype=np.int64)
    begins = np.array([f.index_begin for f in fl], dtype=np.int64)
    ok = counts >= 3
    corner = np.concatenate([np.arange(b, b + c) for b, c in zip(begins[ok], counts[ok], strict=True)]) \
        if ok.any() else np.zeros(0, np.int64)
    face_idx = vi[corner]
    uvs = fuv = None
    uvattr = keep_(keep, fm.vertex_uv)
    if uvattr.exists:
        vals = np.asarray(keep_(keep, uvattr.values), dtype=np.float64).reshape(-1, 2)
        ind = np.asarray(keep_(keep, uvattr.indices), dtype=np.int64)
        uvs = np.stack([vals[:, 0], 1.0 - vals[:, 1]], axis=1)        # glTF's top-left convention
        fuv = ind[corner]
    # world pose: skin clusters or the geometry-to-world matrix
    G = _mat(nd.geometry_to_world)
    skin_defs = keep_(keep, fm.skin_deformers)
    L = None
    world = verts @ G[:3, :3].T + G[:3, 3]
    sj = sw = None
    if len(skin_defs):
        sk = keep_(keep, skin_defs[0])
        M, sj, sw = _skin(sk, V, ids, keep)
        if M is not None:
            L = M[:, :3, :3]
            world = (L * verts[:, None, :]).sum(axis=2) + M[:, :3, 3]
    # blend shapes
    shape_names, deltas = [], []
    bds = keep_(keep, fm.blend_deformers)
    for bd_i in range(len(bds)):
        bd = keep_(keep, bds[bd_i])
        chans = keep_(keep, bd.channels)
        for c_i in range(len(chans)):
            ch = keep_(keep, chans[c_i])
            kfs = keep_(keep, ch.keyframes)
            if not len(kfs):
                continue
            kl = [keep_(keep, kfs[k]) for k in range(len(kfs))]
            kf = min(kl, key=lambda k: abs(k.target_weight - 1.0))
            shp = keep_(keep, kf.shape)
            d = np.zeros((V, 3))
            offv = np.asarray(keep_(keep, shp.offset_vertices), dtype=np.int64)
            offp = np.asarray(keep_(keep, shp.position_offsets), dtype=np.float64).reshape(-1, 3)
            if offv.size:
                if offv.max() >= V:
                    raise InputFileError(f"{path}: blend shape '{ch.name}' moves vertex {int(offv.max())} of a "
                                         f"mesh of {V}")
                d[offv] = offp
            d = (L * d[:, None, :]).sum(axis=2) if L is not None else d @ G[:3, :3].T
            shape_names.append(ch.name or shp.name)
            deltas.append(d)
    mats = []
    fmats = keep_(keep, fm.materials)
    for k in range(len(fmats)):
        mats.append(_material(path, keep_(keep, fmats[k]), notes, textures, keep))
    tri_mat = None
    fmi = keep_(keep, fm.face_material)
    if len(mats) > 1:
        fmat = np.asarray(fmi, dtype=np.int64)[ok] if len(fmi) else None
        if fmat is not None and fmat.size:
            tri_mat = np.repeat(fmat, counts[ok] - 2)
    mesh = Mesh(world, counts[ok], face_idx, uvs, fuv, name=name)
    D = np.stack(deltas).astype(np.float32) if deltas else np.zeros((0, V, 3), np.float32)
    return SceneMesh(name, name, mesh, shape_names, D, mats, tri_mat, skin_joints=sj, skin_weights=sw)


def _skin(sk, V: int, ids: dict, keep: list):
    clusters = keep_(keep, sk.clusters)
    cl = [keep_(keep, clusters[k]) for k in range(len(clusters))]
    mats = []
    bone = []
    for c in cl:
        bn = keep_(keep, c.bone_node)
        B = _mat(bn.node_to_world) if bn is not None else np.eye(4)
        mats.append(B @ _mat(c.geometry_to_bone))
        bone.append(ids.get(bn.element_id, -1) if bn is not None else -1)
    if not mats:
        return None, None, None
    C = np.stack(mats)
    M = np.zeros((V, 4, 4))
    tot = np.zeros(V)
    jn = np.full((V, 4), -1, np.int64)
    jw = np.zeros((V, 4))
    for k, c in enumerate(cl):
        vv = np.asarray(keep_(keep, c.vertices), dtype=np.int64)
        ww = np.asarray(keep_(keep, c.weights), dtype=np.float64)
        if not vv.size:
            continue
        vv, ww = vv[vv < V], ww[vv < V]
        M[vv] += ww[:, None, None] * C[k]
        tot[vv] += ww
        slot = np.argmin(jw[vv], axis=1)
        better = ww > jw[vv, slot]
        jn[vv[better], slot[better]] = bone[k]
        jw[vv[better], slot[better]] = ww[better]
    ok = tot > 0
    M[ok] /= tot[ok, None, None]
    M[~ok] = np.eye(4)
    return M, jn, jw


def _material(path: Path, m, notes: list, textures: dict, keep: list) -> Material:
    pbr = keep_(keep, m.pbr)
    base = keep_(keep, pbr.base_color)
    col = np.array([0.8, 0.8, 0.8, 1.0])
    try:
        v = base.value_vec4
        if base.has_value:
            col = np.array([v.x, v.y, v.z, 1.0])
    except AttributeError:
        pass
    tex = keep_(keep, base.texture)
    image = None
    if tex is not None:
        key = tex.filename or tex.relative_filename or tex.name
        if key not in textures:
            textures[key] = _texture(path, tex, notes)
        image = textures[key]
    return Material(m.name or "material", col, image)


#: Folder names (lower case) where exporters and asset libraries keep a model's textures: looked in beside the
#: FBX and beside its folder (``Export/model.fbx`` with ``Textures/``, Rocketbox's layout).
_TEXTURE_FOLDERS = ("textures", "texture", "tex", "maps", "images", "materials")


def _texture(path: Path, tex, notes: list):
    content = bytes(tex.content) if len(tex.content) else b""   # read now: the scene is gone after the read
    found = None if content else _texture_file(path, [tex.relative_filename, tex.filename, tex.absolute_filename])
    if not content and found is None:
        named = str(tex.relative_filename or tex.filename)
        notes.append(f"missing texture: '{Path(named.replace(chr(92), '/')).name}' (named {excerpt(named, 60)}) "
                     "is not in the file, beside it nor in a textures folder near it; rendered in its base colour")
        return None
    return EncodedImage(content or None, None if content else str(found), tex.name or tex.filename, notes)


def _texture_file(path: Path, names: list) -> Path | None:
    """The file a texture names, found where a user's copy keeps it: the path as written (relative to the FBX),
    then its file name beside the FBX or in a textures folder beside the FBX or beside its folder, the name's
    case ignored (a Windows exporter's ``F001_Body.TGA``)."""
    names = [str(f).replace("\\", "/") for f in names if f]
    for f in names:
        p = path.parent / f
        if p.is_file():
            return p
    wanted = {Path(f).name.lower() for f in names}
    if not wanted:
        return None
    folders = [path.parent]
    for base in (path.parent, path.parent.parent):
        try:
            folders += sorted(d for d in base.iterdir() if d.is_dir() and d.name.lower() in _TEXTURE_FOLDERS)
        except OSError:
            continue
    for d in folders:
        try:
            hit = sorted(f for f in d.iterdir() if f.name.lower() in wanted and f.is_file())
        except OSError:
            continue
        if hit:
            return hit[0]
    return None
