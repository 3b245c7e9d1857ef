"""USD export (``.usd``, ``.usda``, ``.usdc``) of a rig driven by weights, through Pixar's ``usd-core``.

What :func:`write_usd` writes (``docs/usd.md`` has the full story)
-------------------------------------------------------------------
Stage metadata: ``metersPerUnit = 1`` (the rig is written in metres whatever its unit),
``upAxis = "Y"`` (the package's frame is glTF's: +Y up, +Z forward out of the face, +X the
character's left), ``timeCodesPerSecond = framesPerSecond = fps`` (the take's rate,
:func:`faceretarget.timebase.infer_fps`, snapped to an integer or an NTSC rate ``n * 1000 / 1001``
when within 1e-6 of one), ``startTimeCode = 0``, ``endTimeCode`` the last frame's code, and
``defaultPrim = "Face"``.  Frame ``i`` is keyed at time code ``(times[i] - times[0]) * fps``: the
real times, so a take with dropped frames keeps its gaps (codes need not be integers).

Default layout (UsdSkel blend shapes)::

    /Face                      Xform (kind = component)
      Head                     Xform, only with ``head=`` (time-sampled translate + orient)
        Rig                    SkelRoot (extent: the face over the whole take)
          Skeleton             Skeleton, one joint "root" (identity bind and rest transforms),
                               skel:animationSource -> Animation
          Animation            SkelAnimation: blendShapes (tokens), blendShapeWeights (float[],
                               one time sample per frame)
          Mesh                 Mesh: points (neutral, metres), faceVertexCounts / faceVertexIndices,
                               primvars:st (faceVarying, indexed) when the rig has UVs,
                               skel:skeleton, skel:blendShapes, skel:blendShapeTargets
            <shape>            BlendShape per key shape: offsets + pointIndices of the vertices
                               that move (a key shape that moves nothing keeps one zero offset)

(without ``head=`` the ``Rig`` SkelRoot sits directly under ``/Face``).  UsdSkel only binds blend
shapes through a skeleton, hence the one-joint ``Skeleton`` (Blender's own USD exporter makes the
same one for shape keys); the mesh has no joint influences, so the joint moves nothing.

Names: the ``blendShapes`` tokens of the mesh and of the animation are the rig's shape names
unchanged (UsdSkel matches the two arrays by token, and Blender names its shape keys after the
mesh's tokens); only the BlendShape *prim* names are made valid identifiers
(:func:`usd_prim_names`: ``smile:01`` -> ``smile_01``, a leading digit -> ``_``) and unique
(``_2``, ``_3``, ... suffixes), and ``skel:blendShapeTargets`` lists them in the tokens' order.

Baked layout (``bake=True``): no skeleton and no blend shapes; ``/Face[/Head]/Mesh`` has
``points`` time-sampled per frame (the rig evaluated :class:`~faceretarget.rig.RigFrames` chunk by
chunk, stored as float32) with a matching time-sampled ``extent``; its default ``points`` are the
neutral.

Head (``head=``): an Xform ``Head`` above the face with ``xformOpOrder = [xformOp:translate,
xformOp:translate:pivot, xformOp:orient, !invert!xformOp:translate:pivot]``: the translation
(metres; only when the pose has one) and the rotation (``quatf``, consecutive keys on one
hemisphere so USD's slerp takes the short way) per frame, about ``head_pivot`` (metres, static;
the pivot ops only when it is not zero).  A point ``p`` of the face goes to
``pivot + translation + R (p - pivot)``, exactly what :func:`~faceretarget.io.write_glb` writes.

Precision: points, offsets, weights and quaternions are float32 (USD's ``point3f``,
``vector3f``, ``float``, ``quatf``); time codes are float64.

Files are written whole or not at all: USD writes a temporary file beside ``path``, renamed into
place when complete.  ``.usd`` is written as crate (binary), like ``.usdc``.  Memory: a crate file
is built on disk, and a baked take is evaluated and appended to it ``256`` frames at a time (a
20,000-frame ARKit take peaks about 140 MB above the interpreter, the same as 2,000 frames); a
``.usda`` is text that USD holds in memory until it writes it, so bake long takes to ``.usdc``.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from ..errors import InvalidDataError, OutputError
from ..files import atomic_path, check_output_path
from ..formats import USD, USDA, USDC, WAV
from ..headpose import HeadPose
from ..optional import optional_import
from ..rig import Rig, RigFrames
from ..timebase import check_times, infer_fps
from ._audio import checked_audio, write_wav
from ._gltf import _checked_weights, _head_arrays

__all__ = ["write_usd", "USD_FORMATS", "usd_prim_names"]

#: Extensions :func:`write_usd` writes, with the Sdf file format each one gets.
USD_FORMATS = {USD: "usdc", USDA: "usda", USDC: "usdc"}

#: Frames evaluated at once when baking points (bounded memory: ``chunk x V x 3`` float64).
_BAKE_CHUNK = 256


def _pxr():
    """The ``pxr`` modules this writer uses (or :class:`MissingDependencyError` naming the extra)."""
    optional_import("pxr", "USD output")
    from pxr import Gf, Kind, Sdf, Usd, UsdGeom, UsdSkel, Vt

    return Gf, Kind, Sdf, Usd, UsdGeom, UsdSkel, Vt


def usd_prim_names(names: list[str]) -> list[str]:
    """Valid, unique USD prim names for shape ``names`` (order kept).

    Characters other than ASCII letters, digits and ``_`` become ``_``, and so does a leading
    digit (as ``Tf.MakeValidIdentifier`` does); a name already taken gets ``_2``, ``_3``, ...

    Parameters
    ----------
    names : list of str

    Returns
    -------
    list of str
        One identifier per name.

    >>> usd_prim_names(["jawOpen", "mouth.L", "mouth_L", "1up"])
    ['jawOpen', 'mouth_L', 'mouth_L_2', '_up']
    """
    out: list[str] = []
    taken: set[str] = set()
    for n in names:
        base = "".join(c if (c.isascii() and (c.isalnum() or c == "_")) else "_" for c in str(n)) or "shape"
        if base[0].isdigit():
            base = "_" + base[1:]
        name, k = base, 2
        while name in taken:
            name, k = f"{base}_{k}", k + 1
        taken.add(name)
        out.append(name)
    return out


def _nice_fps(fps: float) -> float:
    """``fps`` snapped to an integer or an NTSC rate (``n * 1000 / 1001``) within 1e-6 of it."""
    for cand in (round(fps), round(fps * 1.001) / 1.001):
        if cand > 0 and abs(fps - cand) <= 1e-6 * fps:
            return float(cand)
    return float(fps)


def write_usd(path: str | os.PathLike, rig: Rig, weights: np.ndarray, times: np.ndarray,
              names: list[str] | None = None, *, head: HeadPose | None = None, bake: bool = False,
              head_pivot: tuple[float, float, float] | np.ndarray = (0.0, 0.0, 0.0),
              audio: np.ndarray | None = None, audio_rate: float | None = None) -> Path:
    """Write the rig animated by ``weights`` as a USD stage (module docstring, ``docs/usd.md``).

    Parameters
    ----------
    path : path-like
        Output ``.usd`` (crate), ``.usdc`` (crate) or ``.usda`` (text).
    rig : Rig
        Neutral mesh and key shapes (any unit; written in metres).
    weights : (T, K) float
        Weights per frame: in the rig's shape order when ``names`` is None, otherwise the columns
        named by ``names`` (mapped with :meth:`Rig.map_weights`, which warns once about names the
        rig lacks).
    times : (T,) float
        Frame times in seconds, strictly increasing; frame ``i`` is written at time code
        ``(times[i] - times[0]) * fps`` with ``fps`` inferred from ``times`` (30 for one frame).
    names : list of str, optional
        Names of the columns of ``weights``.
    head : HeadPose, optional
        Head motion per frame (:mod:`faceretarget.headpose`; every frame needs a pose): an
        animated ``Head`` Xform above the face.
    bake : bool
        Write time-sampled ``points`` (the evaluated rig, metres) instead of UsdSkel blend shapes.
    head_pivot : 3 floats
        Rotation centre of the head in the rig's coordinates, metres.
    audio : (n,) or (n, channels) float, optional
        The soundtrack (samples in [-1, 1], starting at ``times[0]``): written beside the stage as
        ``<name>.wav`` (16-bit PCM) and referenced by a ``UsdMedia.SpatialAudio`` prim
        ``/Face/Audio`` (non-spatial, from time code 0), which Omniverse and usdview play.
    audio_rate : float, optional
        Its sampling rate in Hz (an integer rate).

    Returns
    -------
    Path
        ``path``.

    Raises
    ------
    MissingDependencyError
        ``usd-core`` is not installed (the message says how: ``make usd``).
    InvalidDataError
        Wrong weight shape, non-finite weights, times that do not increase, a rig without key
        shapes, or a head pose with missing frames.
    OutputError
        Not a ``.usd`` / ``.usda`` / ``.usdc`` path, or the file cannot be written (nothing partial
        is left).
    """
    path = Path(path)
    ext = path.suffix.lower()
    if ext not in USD_FORMATS:
        raise OutputError(f"{path}: a USD file must end in {', '.join(USD_FORMATS)}, not '{ext or path.name}'")
    path = check_output_path(path)
    w, t = _checked_weights(path, rig, weights, times, names)
    t = check_times(t, source=str(path))
    pivot = np.asarray(head_pivot, dtype=np.float64).reshape(-1)
    if pivot.shape != (3,) or not np.isfinite(pivot).all():
        raise InvalidDataError(f"{path}: head_pivot must be 3 finite numbers (metres), got {head_pivot!r}")
    head_keys = None if head is None else _head_arrays(path, head, t.size)
    sound = checked_audio(path, audio, audio_rate)
    wav = path.with_suffix(WAV) if sound is not None else None
    if wav is not None:
        check_output_path(wav)
    Sdf = _pxr()[2]
    from pxr import Tf

    fps = _nice_fps(infer_fps(t, default=30.0, source=str(path)))
    codes = (t - t[0]) * fps
    if codes.size > 1 and not (np.diff(codes) > 0).all():  # pragma: no cover - check_times guards
        raise InvalidDataError(f"{path}: time codes do not increase")
    scale = rig.mm_per_unit / 1000.0

    crate = USD_FORMATS[ext] == "usdc"
    with atomic_path(path) as tmp:
        # Sdf picks the file format from the extension, so USD writes beside the temporary file
        out = tmp.with_name(tmp.name + (USDC if crate else USDA))
        try:
            try:
                if crate:  # on disk from the start: a baked take is saved chunk by chunk (appended)
                    layer = Sdf.Layer.CreateNew(str(out))
                else:  # text is written in one go from memory
                    layer = Sdf.Layer.CreateAnonymous("faceretarget.usda")
                _author(layer, rig, w, codes, fps, scale, head_keys, pivot, bake,
                        None if wav is None else (wav.name, len(sound[0]) / sound[1]))
                ok = layer.Save() if crate else layer.Export(str(out))
            except Tf.ErrorException as e:
                raise OutputError(f"{path}: USD could not write the stage ({str(e).strip()})") from e
            if not ok:
                raise OutputError(f"{path}: USD could not write the stage")
            del layer
            os.replace(out, tmp)
            if wav is not None:                 # the sidecar first: the stage never names a missing file
                with atomic_path(wav) as wtmp:
                    write_wav(wtmp, *sound)
        finally:
            out.unlink(missing_ok=True)
    return path


def _author(layer, rig: Rig, w: np.ndarray, codes: np.ndarray, fps: float, scale: float, head_keys,
            pivot: np.ndarray, bake: bool, sound: tuple[str, float] | None = None) -> None:
    """Build the whole stage in ``layer`` (module docstring)."""
    Gf, Kind, Sdf, Usd, UsdGeom, UsdSkel, Vt = _pxr()
    stage = Usd.Stage.Open(layer)
    layer.customLayerData = {"generator": "faceretarget", "rig": str(rig.name), "sourceUnit": str(rig.unit)}
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)
    UsdGeom.SetStageMetersPerUnit(stage, 1.0)
    stage.SetTimeCodesPerSecond(fps)
    stage.SetFramesPerSecond(fps)
    stage.SetStartTimeCode(0.0)
    stage.SetEndTimeCode(float(codes[-1]))

    root = UsdGeom.Xform.Define(stage, "/Face")
    Usd.ModelAPI(root.GetPrim()).SetKind(Kind.Tokens.component)
    stage.SetDefaultPrim(root.GetPrim())
    parent = root.GetPath()
    if head_keys is not None:
        parent = _write_head(stage, layer, parent, codes, *head_keys, pivot, Gf, UsdGeom).GetPath()
    if bake:
        _write_baked(stage, layer, parent, rig, w, codes, scale, Sdf, UsdGeom, Vt)
    else:
        _write_skel(stage, layer, parent, rig, w, codes, scale, Gf, Sdf, UsdGeom, UsdSkel, Vt)
    if sound is not None:
        _write_audio(stage, root.GetPath(), *sound, fps, Sdf)


def _write_audio(stage, parent, wav_name: str, seconds: float, fps: float, Sdf) -> None:
    """A ``SpatialAudio`` prim playing the sidecar WAV (relative asset path) from time code 0."""
    from pxr import UsdMedia

    audio = UsdMedia.SpatialAudio.Define(stage, parent.AppendChild("Audio"))
    audio.CreateFilePathAttr(Sdf.AssetPath(f"./{wav_name}"))
    audio.CreateAuralModeAttr(UsdMedia.Tokens.nonSpatial)
    audio.CreatePlaybackModeAttr(UsdMedia.Tokens.onceFromStartToEnd)
    audio.CreateStartTimeAttr(0.0)
    audio.CreateEndTimeAttr(float(seconds * fps))


def _mesh(stage, mesh_path, rig: Rig, scale: float, Sdf, UsdGeom, Vt):
    """The face Mesh prim with the neutral (metres), its faces and UVs (``primvars:st``)."""
    m = rig.neutral
    mesh = UsdGeom.Mesh.Define(stage, mesh_path)
    pts = (m.vertices * scale).astype(np.float32)
    mesh.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(pts))
    mesh.CreateExtentAttr(Vt.Vec3fArray.FromNumpy(np.stack([pts.min(0), pts.max(0)])))
    mesh.CreateFaceVertexCountsAttr(Vt.IntArray.FromNumpy(m.face_counts.astype(np.int32)))
    mesh.CreateFaceVertexIndicesAttr(Vt.IntArray.FromNumpy(m.face_indices.astype(np.int32)))
    mesh.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)  # a polygon face, not a subdivision cage
    mesh.CreateOrientationAttr(UsdGeom.Tokens.rightHanded)
    if m.uvs is not None and m.n_faces:
        idx = m.face_uv_indices if m.face_uv_indices is not None else m.face_indices
        if m.face_uv_indices is not None or len(m.uvs) == m.n_vertices:
            st = UsdGeom.PrimvarsAPI(mesh).CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray,
                                                         UsdGeom.Tokens.faceVarying)
            st.Set(Vt.Vec2fArray.FromNumpy(m.uvs.astype(np.float32)))
            st.SetIndices(Vt.IntArray.FromNumpy(np.asarray(idx, dtype=np.int32)))
    return mesh


def _write_skel(stage, layer, parent, rig: Rig, w: np.ndarray, codes: np.ndarray, scale: float,
                Gf, Sdf, UsdGeom, UsdSkel, Vt) -> None:
    """SkelRoot > Skeleton + SkelAnimation + Mesh with one BlendShape per key shape."""
    skel_root = UsdSkel.Root.Define(stage, parent.AppendChild("Rig"))
    skel = UsdSkel.Skeleton.Define(stage, skel_root.GetPath().AppendChild("Skeleton"))
    skel.CreateJointsAttr(Vt.TokenArray(["root"]))
    skel.CreateJointNamesAttr(Vt.TokenArray(["root"]))
    ident = Vt.Matrix4dArray([Gf.Matrix4d(1.0)])
    skel.CreateBindTransformsAttr(ident)
    skel.CreateRestTransformsAttr(ident)

    anim = UsdSkel.Animation.Define(stage, skel_root.GetPath().AppendChild("Animation"))
    tokens = Vt.TokenArray([str(n) for n in rig.names])
    anim.CreateBlendShapesAttr(tokens)
    weights_attr = anim.CreateBlendShapeWeightsAttr()
    UsdSkel.BindingAPI.Apply(skel.GetPrim()).CreateAnimationSourceRel().SetTargets([anim.GetPath()])

    mesh = _mesh(stage, skel_root.GetPath().AppendChild("Mesh"), rig, scale, Sdf, UsdGeom, Vt)
    binding = UsdSkel.BindingAPI.Apply(mesh.GetPrim())
    binding.CreateSkeletonRel().SetTargets([skel.GetPath()])
    binding.CreateBlendShapesAttr(tokens)
    targets = []
    moving = np.abs(rig.deltas).max(axis=2) > 0  # (K, V)
    for k, prim_name in enumerate(usd_prim_names(rig.names)):
        bs = UsdSkel.BlendShape.Define(stage, mesh.GetPath().AppendChild(prim_name))
        idx = np.flatnonzero(moving[k])
        if idx.size == 0:
            idx = np.zeros(1, np.int64)  # UsdSkel wants at least one offset; this one is zero
        bs.CreateOffsetsAttr(Vt.Vec3fArray.FromNumpy((rig.deltas[k, idx] * scale).astype(np.float32)))
        bs.CreatePointIndicesAttr(Vt.IntArray.FromNumpy(idx.astype(np.int32)))
        targets.append(bs.GetPath())
    binding.CreateBlendShapeTargetsRel().SetTargets(targets)

    w32 = w.astype(np.float32)
    attr_path = weights_attr.GetPath()
    for i, code in enumerate(codes):
        layer.SetTimeSample(attr_path, float(code), Vt.FloatArray.FromNumpy(w32[i]))

    # the SkelRoot's extent covers the face over the whole take (bounds evaluated chunk by chunk)
    lo, hi = np.full(3, np.inf), np.full(3, -np.inf)
    for _, v in RigFrames(rig, w).chunks(_BAKE_CHUNK):
        lo = np.minimum(lo, v.min(axis=(0, 1)) * scale)
        hi = np.maximum(hi, v.max(axis=(0, 1)) * scale)
    skel_root.CreateExtentAttr(Vt.Vec3fArray.FromNumpy(np.stack([lo, hi]).astype(np.float32)))


def _write_baked(stage, layer, parent, rig: Rig, w: np.ndarray, codes: np.ndarray, scale: float,
                 Sdf, UsdGeom, Vt) -> None:
    """A Mesh whose points (and extent) are time-sampled per frame."""
    mesh = _mesh(stage, parent.AppendChild("Mesh"), rig, scale, Sdf, UsdGeom, Vt)
    p_path, e_path = mesh.GetPointsAttr().GetPath(), mesh.GetExtentAttr().GetPath()
    for a, v in RigFrames(rig, w).chunks(_BAKE_CHUNK):
        v32 = (v * scale).astype(np.float32)
        for j in range(len(v32)):
            code = float(codes[a + j])
            layer.SetTimeSample(p_path, code, Vt.Vec3fArray.FromNumpy(v32[j]))
            layer.SetTimeSample(e_path, code, Vt.Vec3fArray.FromNumpy(
                np.stack([v32[j].min(axis=0), v32[j].max(axis=0)])))
        if not layer.anonymous:  # a crate file: append this chunk to it and free its memory
            layer.Save()


def _write_head(stage, layer, parent, codes: np.ndarray, q: np.ndarray, tr: np.ndarray | None,
                pivot: np.ndarray, Gf, UsdGeom):
    """The ``Head`` Xform: translate (time-sampled), pivot, orient (time-sampled), inverse pivot."""
    xf = UsdGeom.Xform.Define(stage, parent.AppendChild("Head"))
    # each Add*Op appends to xformOpOrder: translate, pivot, orient, inverse pivot (UsdGeomXformable's
    # pivot idiom; the pivot ops only when the pivot is not the origin)
    translate = xf.AddTranslateOp(UsdGeom.XformOp.PrecisionDouble) if tr is not None else None
    has_pivot = bool(np.any(pivot != 0))
    if has_pivot:
        xf.AddTranslateOp(UsdGeom.XformOp.PrecisionDouble, "pivot").Set(Gf.Vec3d(*map(float, pivot)))
    orient = xf.AddOrientOp(UsdGeom.XformOp.PrecisionFloat)
    if has_pivot:
        xf.AddTranslateOp(UsdGeom.XformOp.PrecisionDouble, "pivot", True)
    q32 = q.astype(np.float32)
    o_path = orient.GetAttr().GetPath()
    t_path = translate.GetAttr().GetPath() if translate is not None else None
    for i, code in enumerate(codes):
        x, y, z, w_ = (float(c) for c in q32[i])
        layer.SetTimeSample(o_path, float(code), Gf.Quatf(w_, x, y, z))
        if t_path is not None:
            layer.SetTimeSample(t_path, float(code), Gf.Vec3d(*map(float, tr[i])))
    return xf
