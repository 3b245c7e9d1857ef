"""USD characters (UsdSkel) read with usd-core, and the animation added as a layer over the asset.

:func:`read_usd_character` opens a ``.usd`` / ``.usda`` / ``.usdc`` / ``.usdz`` stage and builds a
:class:`~faceretarget.character.Character` in the stage's world frame converted to metres
(``metersPerUnit``; up axis from ``upAxis``):

* every ``Mesh`` prim: points posed at the skeleton's rest pose (UsdSkel linear blend skinning with the
  rest transforms and the bind transforms, the mesh's ``geomBindTransform``) or by its world transform,
  its faces, its ``st`` UVs (flipped to glTF's top-left convention) and its bound material's diffuse
  colour or texture (UsdPreviewSurface);
* its blend shapes (``skel:blendShapes`` / ``skel:blendShapeTargets``: sparse ``offsets`` at
  ``pointIndices``) as world-space deltas under their names;
* every skeleton joint as a :class:`~faceretarget.character.Joint` named by the last element of its
  path (``Bip01_Pelvis/.../Bip01_Head`` -> ``Bip01_Head``), ``ref`` ``"<skeleton path>|<joint token>"``.

:func:`write_usd_animation` writes a new layer and leaves the asset untouched: the layer has the asset
as its sublayer (relative path), so every prim keeps its path; it defines a ``SkelAnimation`` under
each skeleton's root (blend-shape weights of every bound shape, and the head and neck joints' local
rotations relative to their rest pose at the take's time codes) and points the skeleton's
``skel:animationSource`` at it.  The sound is a ``SpatialAudio`` prim playing ``<out>.wav`` beside it.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from ..character import (
    Channel,
    Character,
    EncodedImage,
    Joint,
    Material,
    SceneMesh,
    joint_motions,
    joint_rotations,
)
from ..errors import InputFileError, OutputError
from ..files import atomic_path, check_output_path
from ..formats import USDA, USDC, WAV
from ..headpose import HeadPose
from ..mesh import Mesh
from ..optional import optional_import

__all__ = ["read_usd_character", "write_usd_animation"]


def _pxr():
    optional_import("pxr", "reading and writing USD characters")
    from pxr import Gf, Sdf, Usd, UsdGeom, UsdShade, UsdSkel, Vt

    return Gf, Sdf, Usd, UsdGeom, UsdShade, UsdSkel, Vt


def _np(m) -> np.ndarray:
    """A Gf.Matrix4d (row vectors, translation in the last row) as a column-vector 4 x 4 array."""
    return np.array(m, dtype=np.float64).T


def read_usd_character(path: str | os.PathLike) -> Character:
    """Read a USD character (module docstring)."""
    path = Path(path)
    if not path.is_file():
        raise InputFileError(f"{path}: file not found" if not path.exists() else f"{path}: is not a file")
    Gf, Sdf, Usd, UsdGeom, UsdShade, UsdSkel, Vt = _pxr()
    try:
        stage = Usd.Stage.Open(str(path))
    except Exception as e:  # pxr raises Tf.ErrorException
        raise InputFileError(f"{path}: usd-core cannot open it ({str(e).strip()[:160]})") from e
    if stage is None:
        raise InputFileError(f"{path}: usd-core cannot open it")
    mpu = float(UsdGeom.GetStageMetersPerUnit(stage) or 0.01)
    up = np.array([0.0, 0.0, 1.0]) if UsdGeom.GetStageUpAxis(stage) == UsdGeom.Tokens.z else np.array([0.0, 1.0, 0.0])
    t = Usd.TimeCode.Default()
    xcache = UsdGeom.XformCache(t)
    notes: list[str] = []
    joints, skin_of = _skins(stage, xcache, mpu, notes)
    meshes: list[SceneMesh] = []
    images: dict[str, EncodedImage | None] = {}
    for prim in stage.Traverse():
        if not prim.IsA(UsdGeom.Mesh) or UsdGeom.Imageable(prim).ComputeVisibility(t) == UsdGeom.Tokens.invisible:
            continue
        sm = _mesh(prim, path, skin_of.get(str(prim.GetPath())), xcache, mpu, notes, images, Sdf, UsdGeom,
                   UsdShade, UsdSkel)
        if sm is not None:
            meshes.append(sm)
    return Character(path, "usd", "usd-core", meshes, joints, up=up, front=None, notes=notes,
                     source_unit={0.01: "cm", 1.0: "m", 0.001: "mm"}.get(round(mpu, 6), f"{mpu:g} m"))


def _skins(stage, xcache, mpu: float, notes: list) -> tuple[list[Joint], dict[str, tuple]]:
    """Every skeleton's joints (rest world matrices, metres) and, per skinned mesh prim path, its skinning
    query, the joints' world skinning matrices (J, 4, 4) and its first joint's index."""
    Gf, Sdf, Usd, UsdGeom, UsdShade, UsdSkel, Vt = _pxr()
    joints: list[Joint] = []
    skin_of: dict[str, tuple] = {}              # mesh path -> (skinning query, skin xforms (J,4,4) world, joint offset)
    cache = UsdSkel.Cache()
    for root_prim in stage.Traverse():
        if not root_prim.IsA(UsdSkel.Root):
            continue
        cache.Populate(UsdSkel.Root(root_prim), Usd.PrimDefaultPredicate)
        for binding in cache.ComputeSkelBindings(UsdSkel.Root(root_prim), Usd.PrimDefaultPredicate):
            skel = binding.GetSkeleton()
            q = cache.GetSkelQuery(skel)
            names = [str(j) for j in q.GetJointOrder()]
            topo = q.GetTopology()
            rest = [_np(m) for m in (skel.GetRestTransformsAttr().Get() or [])]
            bind = [_np(m) for m in (skel.GetBindTransformsAttr().Get() or [])]
            if len(rest) != len(names) or len(bind) != len(names):
                notes.append(f"{skel.GetPath()}: rest or bind transforms missing; its meshes are taken as they are")
                continue
            S = _np(xcache.GetLocalToWorldTransform(skel.GetPrim()))
            skel_space = []
            for j in range(len(names)):
                p = topo.GetParent(j)
                skel_space.append(rest[j] if p < 0 else skel_space[p] @ rest[j])
            off = len(joints)
            for j, n in enumerate(names):
                world = S @ skel_space[j]
                world[:3, 3] *= mpu
                p = topo.GetParent(j)
                joints.append(Joint(n.split("/")[-1], off + p if p >= 0 else -1, world,
                                    f"{skel.GetPath()}|{n}", rest[j]))
            skinx = np.stack([S @ skel_space[j] @ np.linalg.inv(bind[j]) for j in range(len(names))])
            for sq in binding.GetSkinningTargets():
                skin_of[str(sq.GetPrim().GetPath())] = (sq, skinx, off)
    return joints, skin_of


def point_maps(prim, skin, xcache, V: int) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None]:
    """A mesh prim's points to the world at rest: per-point (V, 4, 4) matrices (linear blend skinning with
    the skeleton's rest pose and the geomBindTransform, or the prim's world transform), and the top four
    skin joints and weights (None without a skin).  A mesh bound to a skeleton only for its blend shapes
    (no joint influences, as :func:`~faceretarget.io.write_usd` writes a face) is placed by its transform."""
    if skin is None or not skin[0].HasJointInfluences():
        M = np.broadcast_to(np.array(xcache.GetLocalToWorldTransform(prim), dtype=np.float64).T, (V, 4, 4))
        return M, None, None
    sq, skinx, _off = skin
    geom = np.array(sq.GetGeomBindTransform(), dtype=np.float64).T
    ji, jw = sq.ComputeJointInfluences()
    n = sq.GetNumInfluencesPerComponent()
    ji = np.asarray(ji, dtype=np.int64).reshape(-1, n)
    jw = np.asarray(jw, dtype=np.float64).reshape(-1, n)
    if len(ji) == 1:                                  # constant interpolation: one set for every point
        ji, jw = np.repeat(ji, V, axis=0), np.repeat(jw, V, axis=0)
    M = (jw[:, :, None, None] * skinx[ji]).sum(axis=1) @ geom
    tot = jw.sum(axis=1)
    M[tot <= 0] = skinx[0] @ geom if len(skinx) else np.eye(4)
    order = np.argsort(-jw, axis=1)[:, :4]
    sj = np.take_along_axis(ji, order, axis=1) + _off
    sw = np.take_along_axis(jw, order, axis=1)
    return M, sj, sw


def _mesh(prim, path, skin, xcache, mpu, notes, images, Sdf, UsdGeom, UsdShade, UsdSkel) -> SceneMesh | None:
    m = UsdGeom.Mesh(prim)
    pts = m.GetPointsAttr().Get()
    if pts is None or len(pts) == 0:
        return None
    local = np.asarray(pts, dtype=np.float64)
    V = len(local)
    counts = np.asarray(m.GetFaceVertexCountsAttr().Get() or [], dtype=np.int64)
    idx = np.asarray(m.GetFaceVertexIndicesAttr().Get() or [], dtype=np.int64)
    ok_faces = counts >= 3
    starts = np.r_[0, np.cumsum(counts)[:-1]] if len(counts) else np.zeros(0, np.int64)
    corner = np.concatenate([np.arange(s, s + c) for s, c in zip(starts[ok_faces], counts[ok_faces], strict=True)]) \
        if ok_faces.any() else np.zeros(0, np.int64)
    if m.GetOrientationAttr().Get() == UsdGeom.Tokens.leftHanded:
        notes.append(f"{prim.GetPath()}: left-handed orientation; faces kept as written")
    M, sj, sw = point_maps(prim, skin, xcache, V)
    L = M[:, :3, :3]
    world = ((L * local[:, None, :]).sum(axis=2) + M[:, :3, 3]) * mpu
    names, deltas = [], []
    bapi = UsdSkel.BindingAPI(prim)
    shapes = bapi.GetBlendShapesAttr().Get() if bapi.GetBlendShapesAttr() else None
    targets = bapi.GetBlendShapeTargetsRel().GetTargets() if bapi.GetBlendShapeTargetsRel() else []
    if shapes:
        stage = prim.GetStage()
        for name, tgt in zip(shapes, targets, strict=False):
            bs = UsdSkel.BlendShape(stage.GetPrimAtPath(tgt))
            off = np.asarray(bs.GetOffsetsAttr().Get() or [], dtype=np.float64).reshape(-1, 3)
            pi = bs.GetPointIndicesAttr().Get()
            d = np.zeros((V, 3))
            if pi is not None and len(pi):
                pi = np.asarray(pi, dtype=np.int64)
                if pi.max() >= V or len(pi) != len(off):
                    raise InputFileError(f"{path}: blend shape {tgt} does not fit mesh {prim.GetPath()}")
                d[pi] = off
            elif len(off) == V:
                d = off
            names.append(str(name))
            deltas.append((L * d[:, None, :]).sum(axis=2) * mpu)
        if len(shapes) != len(targets):
            notes.append(f"{prim.GetPath()}: {len(shapes)} blend shape names for {len(targets)} targets")
    uvs = fuv = None
    pv = UsdGeom.PrimvarsAPI(prim)
    st = next((pv.GetPrimvar(n) for n in ("st", "UVMap", "st0", "uv") if pv.HasPrimvar(n)), None)
    if st is not None and st.Get() is not None:
        vals = np.asarray(st.Get(), dtype=np.float64).reshape(-1, 2)
        ind = np.asarray(st.GetIndices() or [], dtype=np.int64) if st.IsIndexed() else None
        interp = st.GetInterpolation()
        if interp == UsdGeom.Tokens.faceVarying:
            per_corner = ind if ind is not None and len(ind) else np.arange(len(idx))
            fuv = per_corner[corner]
        elif interp in (UsdGeom.Tokens.vertex, UsdGeom.Tokens.varying):
            per_vertex = ind if ind is not None and len(ind) else np.arange(V)
            fuv = per_vertex[idx[corner]]
        if fuv is not None and (fuv.max(initial=-1) >= len(vals)):
            fuv = None
        if fuv is not None:
            uvs = np.stack([vals[:, 0], 1.0 - vals[:, 1]], axis=1)
    mat = _material(prim, path, notes, images, UsdShade)
    mesh = Mesh(world, counts[ok_faces], idx[corner], uvs, fuv, name=prim.GetName())
    D = np.stack(deltas).astype(np.float32) if deltas else np.zeros((0, V, 3), np.float32)
    name = prim.GetName() if prim.GetName() != "Mesh" else prim.GetParent().GetName()
    return SceneMesh(name, str(prim.GetPath()), mesh, names, D, [mat], None, skin_joints=sj, skin_weights=sw)


def _material(prim, path, notes, images, UsdShade) -> Material:
    mat, _ = UsdShade.MaterialBindingAPI(prim).ComputeBoundMaterial()
    if not mat:
        return Material("default")
    shader = mat.ComputeSurfaceSource()[0]
    if not shader:
        return Material(mat.GetPrim().GetName())
    inp = shader.GetInput("diffuseColor")
    col = np.array([0.8, 0.8, 0.8, 1.0])
    img = None
    if inp:
        src = inp.GetConnectedSource()
        if src and src[0]:
            tex = UsdShade.Shader(src[0].GetPrim())
            f = tex.GetInput("file")
            asset = f.Get() if f else None
            if asset is not None:
                p = asset.resolvedPath or str(Path(path).parent / asset.path)
                if p in images:
                    img = images[p]
                elif Path(p).is_file():
                    img = images[p] = EncodedImage(None, p, Path(p).name, notes)
                else:
                    notes.append(f"missing texture: '{asset.path}' not found; rendered in its base colour")
                    images[p] = None
                col = np.ones(4)
        elif inp.Get() is not None:
            col = np.r_[np.asarray(inp.Get(), dtype=np.float64), 1.0]
    return Material(mat.GetPrim().GetName(), col, img)


# ------------------------------------------------------------------------------------------ writing
def export_layer(layer, asset: Path, out: Path, tmp: Path) -> None:
    """Save a layer over ``asset`` as ``out`` (written to ``tmp``, the atomic stand-in): the asset referenced
    relative to ``out``'s folder, text for ``.usda`` and crate otherwise."""
    from pxr import Tf

    layer.subLayerPaths[0] = os.path.relpath(asset, out.resolve().parent).replace(os.sep, "/")
    dst = tmp.with_name(tmp.name + (USDA if out.suffix.lower() == USDA else USDC))
    try:
        if not layer.Export(str(dst)):
            raise OutputError(f"{out}: USD could not write the layer")
        os.replace(dst, tmp)
    except Tf.ErrorException as e:
        raise OutputError(f"{out}: USD could not write the layer ({str(e).strip()[:160]})") from e
    finally:
        dst.unlink(missing_ok=True)


def copy_stage_metrics(stage, asset: Path) -> None:
    """Give a layer over ``asset`` the asset's ``metersPerUnit`` and ``upAxis``: a stage reads them from its root
    layer only, so without them a centimetre or Z-up asset is shown at the wrong size or on its back."""
    from pxr import Usd, UsdGeom

    base = Usd.Stage.Open(str(asset))
    mpu = UsdGeom.GetStageMetersPerUnit(base)
    up = UsdGeom.GetStageUpAxis(base)
    del base
    UsdGeom.SetStageMetersPerUnit(stage, float(mpu or 0.01))
    UsdGeom.SetStageUpAxis(stage, up)


def write_usd_animation(out: Path, character: Character, chans: list[Channel], W: np.ndarray, t: np.ndarray, *,
                        head: HeadPose | None = None, audio=None, audio_rate=None, neck_share: float = 0.0,
                        gaze: dict | None = None, name: str = "faceretarget", log=None) -> Path:
    """A layer over the character's USD asset that adds the animation (module docstring)."""
    from ._audio import checked_audio, write_wav
    from ._usd import _nice_fps, _write_audio

    log = log or (lambda *_: None)
    Gf, Sdf, Usd, UsdGeom, UsdShade, UsdSkel, Vt = _pxr()
    asset = Path(character.path).resolve()
    if out.resolve() == asset:
        raise OutputError(f"{out}: is the asset itself; write the animation layer to another file")
    sound = checked_audio(out, audio, audio_rate)
    wav = out.with_suffix(WAV) if sound is not None else None
    if wav is not None:
        check_output_path(wav)
    from ..timebase import infer_fps

    fps = _nice_fps(infer_fps(t, default=30.0))
    codes = (t - t[0]) * fps
    # the weight of every bound blend shape, per mesh prim
    from ..character import mesh_columns

    per_mesh: dict[str, dict[str, np.ndarray]] = {}
    for mi, cols in mesh_columns(chans, W).items():
        m = character.meshes[mi]
        per_mesh.setdefault(m.ref, {}).update({m.shape_names[k]: col for k, col in cols.items()})

    with atomic_path(out) as tmp:
        layer = Sdf.Layer.CreateAnonymous("faceretarget.usda")
        layer.subLayerPaths.append(str(asset))              # absolute while composing, relative when saved
        stage = Usd.Stage.Open(layer)
        copy_stage_metrics(stage, asset)
        stage.SetTimeCodesPerSecond(fps)
        stage.SetFramesPerSecond(fps)
        stage.SetStartTimeCode(0.0)
        stage.SetEndTimeCode(float(codes[-1]))
        layer.customLayerData = {"generator": "faceretarget", "asset": asset.name}
        done = []
        cache = UsdSkel.Cache()
        for root_prim in [p for p in stage.Traverse() if p.IsA(UsdSkel.Root)]:
            cache.Populate(UsdSkel.Root(root_prim), Usd.PrimDefaultPredicate)
            for binding in cache.ComputeSkelBindings(UsdSkel.Root(root_prim), Usd.PrimDefaultPredicate):
                skel = binding.GetSkeleton()
                names, weights = [], []
                for sq in binding.GetSkinningTargets():
                    shapes = per_mesh.get(str(sq.GetPrim().GetPath()), {})
                    for n, col in shapes.items():
                        if n not in names:
                            names.append(n)
                            weights.append(col)
                jroles = [(j, joint_rotations(character, j, rot)) for _, j, rot in
                          joint_motions(character, head, neck_share, gaze) if j.ref.startswith(f"{skel.GetPath()}|")]
                if not names and not jroles:
                    continue
                anim = UsdSkel.Animation.Define(stage, root_prim.GetPath().AppendChild(f"{name}_anim"))
                if names:
                    anim.CreateBlendShapesAttr(Vt.TokenArray(names))
                    attr = anim.CreateBlendShapeWeightsAttr()
                    Wm = np.stack(weights, axis=1).astype(np.float32)
                    for f, code in enumerate(codes):
                        attr.Set(Vt.FloatArray.FromNumpy(Wm[f]), Usd.TimeCode(float(code)))
                if jroles:
                    anim.CreateJointsAttr(Vt.TokenArray([j.ref.split("|", 1)[1] for j, _ in jroles]))
                    tr, sc = [], []
                    for j, _ in jroles:
                        R = j.local
                        s = np.linalg.norm(R[:3, :3], axis=0)
                        tr.append(Gf.Vec3f(*R[:3, 3].tolist()))
                        sc.append(Gf.Vec3h(*s.tolist()))
                    anim.CreateTranslationsAttr(Vt.Vec3fArray(tr))
                    anim.CreateScalesAttr(Vt.Vec3hArray(sc))
                    rot = anim.CreateRotationsAttr()
                    for f, code in enumerate(codes):
                        qs = [Gf.Quatf(float(q[f, 3]), Gf.Vec3f(*q[f, :3].tolist())) for _, q in jroles]
                        rot.Set(Vt.QuatfArray(qs), Usd.TimeCode(float(code)))
                UsdSkel.BindingAPI.Apply(skel.GetPrim()).CreateAnimationSourceRel().SetTargets([anim.GetPath()])
                done.append(str(skel.GetPath()))
        if not done:
            raise OutputError(f"{out}: no skeleton of {asset.name} binds the character's face meshes; nothing to animate")
        if sound is not None:
            dp = stage.GetDefaultPrim() or next(iter(stage.GetPseudoRoot().GetChildren()), None)
            _write_audio(stage, dp.GetPath(), wav.name, len(sound[0]) / sound[1], fps, Sdf)
        del stage
        export_layer(layer, asset, out, tmp)
    if sound is not None:
        with atomic_path(wav) as wtmp:
            write_wav(wtmp, *sound)
    log(f"wrote {out} (a layer over {asset.name}: {len(t)} time codes at {fps:g} fps on {', '.join(done)})")
    return out
