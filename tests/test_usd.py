"""USD output (``io/_usd.py``): usd-core's validators, UsdSkel's own evaluation, and Blender's importer.

The take: the ARKit rig driven by 200 frames of the real Live Link Face take S07-001 with frames
60-62 dropped (an uneven take: a gap of four frame steps), and a synthetic head motion (the take's
head columns are all zero) with a pivot behind the face.

Tolerances (float32 storage): USD stores points, offsets, weights and quaternions as float32.
The face's coordinates reach 0.094 m, where one float32 step is 7.5e-9 m, and UsdSkel adds 51
float32 products per vertex; the errors measured are about 4e-8 m on the face and 1.5e-7 m
after the head transform, so the checks use 1e-6 m (the face moves up to 3.9e-3 m in these frames:
1e-6 m is 2.5e-4 of the motion), 1e-5 rad for head rotations, and 1e-4 m inside Blender.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from faceretarget.errors import InvalidDataError, MissingDependencyError, OutputError
from faceretarget.headpose import HeadPose
from faceretarget.io import read_performance, usd_prim_names, write_animation, write_usd
from faceretarget.rig import Rig

pxr = pytest.importorskip("pxr", reason="usd-core is not installed (pip install 'faceretarget[usd]' or `make extras`)")
from pxr import Gf, Sdf, Usd, UsdGeom, UsdSkel, Vt  # noqa: E402

T_TAKE = 200
DROP = slice(60, 63)  # frames removed: the take becomes uneven
PIVOT = np.array([0.0, -0.05, -0.06])  # metres: behind and below the face, like a neck
TOL = 1e-6  # metres (module docstring)


# ---------------------------------------------------------------------------------------- fixtures
@pytest.fixture(scope="module")
def take(data_dir, arkit_rig):
    perf = read_performance(data_dir / "livelinkface" / "S07-001.csv")
    keep = np.ones(T_TAKE, bool)
    keep[DROP] = False
    w = arkit_rig.map_weights(perf.names, perf.weights[:T_TAKE], warn=False)[keep]
    t = perf.times[:T_TAKE][keep]
    s = t - t[0]
    angles = np.stack([0.35 * np.sin(2.0 * s), 0.2 * np.sin(3.0 * s + 1.0), 0.12 * np.cos(1.5 * s)], axis=1)
    trans = np.stack([0.01 * np.sin(s), 0.02 * s, -0.015 * s], axis=1)
    head = HeadPose.from_euler("YXZ", angles, trans, source="synthetic head")
    return arkit_rig, w, t, head


@pytest.fixture(scope="module")
def files(take, tmp_path_factory):
    rig, w, t, head = take
    d = tmp_path_factory.mktemp("usd")
    out = {
        "skel.usda": write_usd(d / "skel.usda", rig, w, t, head=head, head_pivot=PIVOT),
        "skel.usdc": write_usd(d / "skel.usdc", rig, w, t),
        "bake.usda": write_usd(d / "bake.usda", rig, w, t, bake=True, head=head, head_pivot=PIVOT),
        "bake.usdc": write_usd(d / "bake.usdc", rig, w, t, bake=True),
    }
    return out


def world_expected(rig: Rig, w: np.ndarray, head: HeadPose | None) -> np.ndarray:
    """(T, V, 3) metres: the rig's frames, moved by the head about PIVOT when given."""
    v = rig.evaluate(w) * (rig.mm_per_unit / 1000.0)
    if head is None:
        return v
    R = head.as_matrix()
    return PIVOT + head.translation[:, None, :] + np.einsum("tij,tvj->tvi", R, v - PIVOT)


def head_of(name: str, head: HeadPose) -> HeadPose | None:
    return head if name.endswith(".usda") else None


# ------------------------------------------------------------------------------------- validation
def usd_problems(stage) -> tuple[list[str], list[str]]:
    """(errors, warnings) from every registered UsdValidation validator (what ``usdchecker`` runs in
    usd-core >= 25), or from ``UsdUtils.ComplianceChecker`` in older usd-core."""
    try:
        from pxr import UsdValidation
    except ImportError:  # pragma: no cover - usd-core < 24.11
        UsdValidation = None
    if UsdValidation is not None and hasattr(UsdValidation, "ValidationRegistry"):
        reg = UsdValidation.ValidationRegistry()
        names = [m.name for m in reg.GetAllValidatorMetadata() if not m.isSuite]
        assert len(names) >= 20, names  # the UsdGeom, UsdSkel, UsdShade, UsdUtils... validators loaded
        ctx = UsdValidation.ValidationContext(reg.GetOrLoadValidatorsByName(names))
        found = ctx.Validate(stage)
        err = [f"{e.GetName()}: {e.GetMessage()}" for e in found
               if e.GetType() == UsdValidation.ValidationErrorType.Error]
        warn = [f"{e.GetName()}: {e.GetMessage()}" for e in found
                if e.GetType() != UsdValidation.ValidationErrorType.Error]
        return err, warn
    from pxr.UsdUtils import ComplianceChecker  # pragma: no cover

    checker = ComplianceChecker()  # pragma: no cover
    checker.CheckCompliance(stage.GetRootLayer().realPath)  # pragma: no cover
    return checker.GetErrors() + checker.GetFailedChecks(), checker.GetWarnings()  # pragma: no cover


@pytest.mark.parametrize("name", ["skel.usda", "skel.usdc", "bake.usda", "bake.usdc"])
def test_validators_report_no_errors(files, name):
    errors, warnings_ = usd_problems(Usd.Stage.Open(str(files[name])))
    for w in warnings_:
        print("usd warning:", w)
    assert errors == []
    assert warnings_ == []


def test_validators_catch_a_broken_binding(files, tmp_path):
    """Control: the same validators do flag a skel binding without SkelBindingAPI and a stage
    without upAxis / metersPerUnit, so 'no errors' above means something."""
    copy = Sdf.Layer.CreateAnonymous(".usda")
    copy.TransferContent(Sdf.Layer.FindOrOpen(str(files["skel.usdc"])))
    stage = Usd.Stage.Open(copy)
    stage.GetPrimAtPath("/Face/Rig/Mesh").RemoveAPI(UsdSkel.BindingAPI)
    stage.ClearMetadata("upAxis")
    stage.ClearMetadata("metersPerUnit")
    assert copy.Export(str(tmp_path / "broken.usda"))
    errors, _ = usd_problems(Usd.Stage.Open(str(tmp_path / "broken.usda")))
    assert any("SkelBindingAPI" in e for e in errors), errors
    assert any("upAxis" in e for e in errors), errors


# ------------------------------------------------------------------------ stage, time codes, names
@pytest.mark.parametrize("name", ["skel.usda", "bake.usdc"])
def test_stage_metadata_and_time_codes(files, take, name):
    rig, w, t, _ = take
    stage = Usd.Stage.Open(str(files[name]))
    assert UsdGeom.GetStageUpAxis(stage) == UsdGeom.Tokens.y
    assert UsdGeom.GetStageMetersPerUnit(stage) == 1.0
    assert stage.GetTimeCodesPerSecond() == 30.0 == stage.GetFramesPerSecond()
    assert stage.GetDefaultPrim().GetPath() == Sdf.Path("/Face")
    codes = (t - t[0]) * 30.0
    attr = (UsdSkel.Animation(next(p for p in stage.Traverse() if p.IsA(UsdSkel.Animation)))
            .GetBlendShapeWeightsAttr() if name.startswith("skel")
            else UsdGeom.Mesh(next(p for p in stage.Traverse() if p.IsA(UsdGeom.Mesh))).GetPointsAttr())
    samples = np.array(attr.GetTimeSamples())
    np.testing.assert_allclose(samples, codes, rtol=0, atol=1e-9)
    # real time codes, not a renumbering: the dropped frames leave a gap of four steps
    assert samples[60] - samples[59] == pytest.approx(4.0, abs=2e-3)
    assert stage.GetStartTimeCode() == 0.0 and stage.GetEndTimeCode() == pytest.approx(codes[-1], abs=1e-9)
    assert len(samples) == T_TAKE - 3


def test_usd_extension_is_crate_and_usda_is_text(take, tmp_path):
    rig, w, t, _ = take
    with open(write_usd(tmp_path / "a.usd", rig, w[:5], t[:5]), "rb") as f:
        assert f.read(8) == b"PXR-USDC"
    assert write_usd(tmp_path / "a.usda", rig, w[:5], t[:5]).read_text().startswith("#usda 1.0")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.usd", "a.usda"]  # no temporary files left


# ----------------------------------------------------------- UsdSkel evaluates the rig, frame by frame
def skel_points(stage, mesh_prim, root_prim):
    """Posed points ``(n, V, 3)`` at every weight time code, computed by UsdSkel's own queries
    (SkelCache -> AnimQuery weights -> blend-shape mapper -> BlendShapeQuery deformed points)."""
    cache = UsdSkel.Cache()
    cache.Populate(UsdSkel.Root(root_prim), Usd.PrimDefaultPredicate)
    skinning = cache.GetSkinningQuery(mesh_prim)
    assert skinning.HasBlendShapes() and not skinning.HasJointInfluences()
    skel = UsdSkel.BindingAPI(mesh_prim).GetInheritedSkeleton()
    anim = cache.GetSkelQuery(skel).GetAnimQuery()
    assert anim, "the skeleton has no animation source"
    shapes = UsdSkel.BlendShapeQuery(UsdSkel.BindingAPI(mesh_prim))
    point_indices = shapes.ComputeBlendShapePointIndices()
    offsets = shapes.ComputeSubShapePointOffsets()
    rest = UsdGeom.Mesh(mesh_prim).GetPointsAttr().Get()
    mapper = skinning.GetBlendShapeMapper()
    codes = UsdSkel.Animation(anim.GetPrim()).GetBlendShapeWeightsAttr().GetTimeSamples()
    out = []
    for c in codes:
        wts = anim.ComputeBlendShapeWeights(c)
        if mapper is not None and not mapper.IsIdentity():
            wts = mapper.Remap(wts)
        sub_w, shape_i, sub_i = shapes.ComputeSubShapeWeights(wts)
        pts = Vt.Vec3fArray(rest)
        assert shapes.ComputeDeformedPoints(sub_w, shape_i, sub_i, point_indices, offsets, pts)
        out.append(np.array(pts, dtype=np.float64))
    return np.array(codes), np.stack(out)


@pytest.mark.parametrize("name", ["skel.usda", "skel.usdc"])
def test_usdskel_blend_shapes_reproduce_the_rig(files, take, name):
    rig, w, t, head = take
    stage = Usd.Stage.Open(str(files[name]))
    root = "/Face/Head/Rig" if name.endswith(".usda") else "/Face/Rig"
    mesh = stage.GetPrimAtPath(root + "/Mesh")
    codes, pts = skel_points(stage, mesh, stage.GetPrimAtPath(root))
    local = rig.evaluate(w)
    err = np.abs(pts - local).max()
    motion = np.abs(local - rig.neutral.vertices).max()
    print(f"{name}: UsdSkel points vs rig.evaluate: max {err:.2e} m (motion {motion:.2e} m)")
    assert motion > 1e-3  # the take really moves the face
    assert err < TOL
    # the points in the world (with the Head xform above the face when present)
    world = np.stack([p @ np.array(UsdGeom.XformCache(c).GetLocalToWorldTransform(mesh))[:3, :3]
                      + np.array(UsdGeom.XformCache(c).GetLocalToWorldTransform(mesh))[3, :3]
                      for c, p in zip(codes, pts, strict=True)])
    werr = np.abs(world - world_expected(rig, w, head_of(name, head))).max()
    print(f"{name}: world points vs rig + head pose: max {werr:.2e} m")
    assert werr < TOL


def test_blend_shape_tokens_keep_names_and_prims_are_valid(take, tmp_path):
    """Names that are not identifiers: tokens keep them, prim names are sanitised and unique, and
    UsdSkel still maps every weight to its shape."""
    rig, w, t, _ = take
    odd = Rig(rig.neutral, ["smile:01", "smile_01", "3smile"], rig.deltas[[24, 22, 43]], unit=rig.unit,
              name="odd")
    ww = w[:20][:, [24, 22, 43]]
    path = write_usd(tmp_path / "odd.usda", odd, ww, t[:20])
    stage = Usd.Stage.Open(str(path))
    mesh = stage.GetPrimAtPath("/Face/Rig/Mesh")
    binding = UsdSkel.BindingAPI(mesh)
    assert list(binding.GetBlendShapesAttr().Get()) == odd.names
    anim = UsdSkel.Animation(stage.GetPrimAtPath("/Face/Rig/Animation"))
    assert list(anim.GetBlendShapesAttr().Get()) == odd.names
    prims = [p.name for p in binding.GetBlendShapeTargetsRel().GetTargets()]
    assert prims == usd_prim_names(odd.names)
    assert len(set(prims)) == 3 and all(Sdf.Path.IsValidIdentifier(p) for p in prims)
    _, pts = skel_points(stage, mesh, stage.GetPrimAtPath("/Face/Rig"))
    assert np.abs(pts - odd.evaluate(ww)).max() < TOL


def test_usd_prim_names():
    assert usd_prim_names(["jawOpen", "mouth.L", "mouth_L", "1up", "a b", ""]) == [
        "jawOpen", "mouth_L", "mouth_L_2", "_up", "a_b", "shape"]


# ------------------------------------------------------------------------------------- head xform
def test_head_xform_equals_the_head_pose(files, take):
    rig, w, t, head = take
    stage = Usd.Stage.Open(str(files["skel.usda"]))
    xf = UsdGeom.Xformable(stage.GetPrimAtPath("/Face/Head"))
    order = [str(op.GetOpName()) for op in xf.GetOrderedXformOps()]
    assert order == ["xformOp:translate", "xformOp:translate:pivot", "xformOp:orient",
                     "!invert!xformOp:translate:pivot"]
    codes = (t - t[0]) * 30.0
    R = head.as_matrix()
    ang, tra = [], []
    for i, c in enumerate(codes):
        M = np.array(xf.GetLocalTransformation(Usd.TimeCode(float(c))))  # row vectors: p' = p M
        Rf = M[:3, :3].T
        ang.append(Rotation.from_matrix(Rf @ R[i].T).magnitude())
        tra.append(np.abs(M[3, :3] - (PIVOT + head.translation[i] - R[i] @ PIVOT)).max())
        q = xf.GetOrderedXformOps()[2].Get(float(c))
        assert isinstance(q, Gf.Quatf)
    print(f"head: rotation error max {max(ang):.2e} rad, translation error max {max(tra):.2e} m")
    assert max(ang) < 1e-5
    assert max(tra) < TOL
    assert np.ptp(head.translation, axis=0).max() > 0.05  # the head really moves


# ------------------------------------------------------------------------------------------ baked
@pytest.mark.parametrize("name", ["bake.usda", "bake.usdc"])
def test_baked_points_equal_the_rig(files, take, name):
    rig, w, t, head = take
    stage = Usd.Stage.Open(str(files[name]))
    assert not any(p.IsA(UsdSkel.BlendShape) or p.IsA(UsdSkel.Skeleton) for p in stage.Traverse())
    mesh_path = "/Face/Head/Mesh" if name.endswith(".usda") else "/Face/Mesh"
    mesh = UsdGeom.Mesh(stage.GetPrimAtPath(mesh_path))
    codes = mesh.GetPointsAttr().GetTimeSamples()
    pts = np.stack([np.array(mesh.GetPointsAttr().Get(c), dtype=np.float64) for c in codes])
    local = rig.evaluate(w)
    err = np.abs(pts - local).max()
    ext = np.stack([np.array(mesh.GetExtentAttr().Get(c), dtype=np.float64) for c in codes])
    print(f"{name}: baked points vs rig.evaluate: max {err:.2e} m")
    assert err < TOL
    np.testing.assert_allclose(ext[:, 0], local.min(axis=1), atol=TOL)
    np.testing.assert_allclose(ext[:, 1], local.max(axis=1), atol=TOL)
    np.testing.assert_allclose(np.array(mesh.GetPointsAttr().Get()), rig.neutral.vertices, atol=TOL)
    world = np.stack([p @ np.array(UsdGeom.XformCache(c).GetLocalToWorldTransform(mesh.GetPrim()))[:3, :3]
                      + np.array(UsdGeom.XformCache(c).GetLocalToWorldTransform(mesh.GetPrim()))[3, :3]
                      for c, p in zip(codes, pts, strict=True)])
    assert np.abs(world - world_expected(rig, w, head_of(name, head))).max() < TOL


def test_centimetre_rig_is_written_in_metres(take, tmp_path):
    rig, w, t, _ = take
    cm = Rig(rig.neutral.with_vertices(rig.neutral.vertices * 100.0), rig.names, rig.deltas * 100.0, unit="cm")
    stage = Usd.Stage.Open(str(write_usd(tmp_path / "cm.usdc", cm, w[:10], t[:10], bake=True)))
    mesh = UsdGeom.Mesh(stage.GetPrimAtPath("/Face/Mesh"))
    c = mesh.GetPointsAttr().GetTimeSamples()[7]
    assert np.abs(np.array(mesh.GetPointsAttr().Get(c)) - rig.evaluate(w[7])).max() < TOL
    assert stage.GetRootLayer().customLayerData["sourceUnit"] == "cm"


# --------------------------------------------------------------------------- registry and failures
def test_write_animation_chooses_usd_and_passes_bake(take, tmp_path):
    rig, w, t, head = take
    names = rig.names
    p = write_animation(tmp_path / "r.usda", rig=rig, weights=w[:30], names=names, times=t[:30], head=head[:30],
                        bake=True)
    stage = Usd.Stage.Open(str(p))
    mesh = UsdGeom.Mesh(stage.GetPrimAtPath("/Face/Head/Mesh"))
    assert len(mesh.GetPointsAttr().GetTimeSamples()) == 30
    p = write_animation(tmp_path / "r.usdc", rig=rig, weights=w[:30], times=t[:30])
    assert Usd.Stage.Open(str(p)).GetPrimAtPath("/Face/Rig/Mesh").HasAPI(UsdSkel.BindingAPI)
    with pytest.raises(OutputError, match="r2.usd: a USD file needs a rig and weights"):
        write_animation(tmp_path / "r2.usd", times=t[:30], head=head[:30])


def test_bad_input_leaves_nothing(take, tmp_path):
    rig, w, t, head = take
    q = head.as_quat()
    q[5] = np.nan
    with pytest.raises(InvalidDataError, match=r"bad\.usda: frame 5 has no head pose"):
        write_usd(tmp_path / "bad.usda", rig, w, t, head=HeadPose(q, head.translation))
    with pytest.raises(InvalidDataError, match="bad.usdc"):
        write_usd(tmp_path / "bad.usdc", rig, w[:, :10], t)
    with pytest.raises(OutputError, match=r"bad\.abc: a USD file must end in"):
        write_usd(tmp_path / "bad.abc", rig, w, t)
    with pytest.raises(OutputError):
        write_usd(tmp_path / "missing" / "x.usda", rig, w, t)
    assert list(tmp_path.iterdir()) == []


def test_missing_usd_core_names_the_extra(take, tmp_path, monkeypatch):
    import sys

    rig, w, t, _ = take
    monkeypatch.setitem(sys.modules, "pxr", None)  # import pxr -> ImportError
    with pytest.raises(MissingDependencyError, match=r"make usd .*pip install 'usd-core"):
        write_usd(tmp_path / "x.usda", rig, w[:3], t[:3])
    assert list(tmp_path.iterdir()) == []


# ----------------------------------------------------------------------------------------- Blender
SAMPLE = [0, 1, 37, 59, 60, 61, 120, T_TAKE - 4]  # indices into the kept frames (59 -> 60 is the gap)


@pytest.fixture(scope="module")
def B():
    """The shared Blender helper (``tests/_blender.py``); skips the test when bpy is missing."""
    sys.path.insert(0, str(Path(__file__).parent))
    import _blender  # skips when bpy is missing; imports it quietly (faceretarget.io.import_bpy)

    return _blender


@pytest.mark.parametrize("name", ["skel.usda", "skel.usdc", "bake.usda", "bake.usdc"])
def test_blender_plays_the_file(B, files, take, name):
    """Blender's USD importer: shape keys + action (or a Mesh Sequence Cache) and a Transform Cache
    for the head; time code c plays at scene frame c (its fps is not set by the importer; we set 30)."""
    rig, w, t, head = take
    h = head_of(name, head)
    face = np.abs(rig.evaluate(w) - rig.neutral.vertices).max(axis=(1, 2))
    sample = sorted(set(SAMPLE) | {int(np.argmax(face))})  # with the frame the face moves most
    scene = B.load_scene(files[name], fps=30.0)
    frames = scene.frames_for(t)[sample]
    np.testing.assert_allclose(frames, ((t - t[0]) * 30.0)[sample], atol=1e-9)  # frame = USD time code
    got = scene.vertices(frames)  # Blender's vertex order, which must be ours (USD keeps it)
    want = world_expected(rig, w[sample], None if h is None else h[sample])
    assert got.shape == want.shape
    still = world_expected(rig, np.zeros_like(w[sample]), None if h is None else h[sample])
    err = np.abs(got - want).max()
    face_motion = np.abs(want - still).max()
    print(f"Blender {B.bpy.app.version_string} {name}: evaluated vertices vs rig (+ head): max {err:.2e} m; "
          f"face motion {face_motion:.2e} m, head motion {np.abs(still - still[:1]).max():.2e} m")
    assert err < 1e-4
    assert face_motion > 3e-3  # the blend shapes move the face well beyond the tolerance
    ob = scene.mesh_object()
    if name.startswith("skel"):  # blend shapes arrive as shape keys driven by an action
        keys = scene.shape_keys()
        assert sorted(keys) == sorted(rig.names)
        k = rig.names.index("jawOpen")
        np.testing.assert_allclose(keys["jawOpen"].frames, (t - t[0]) * 30.0, atol=1e-3)  # float32 frames
        np.testing.assert_allclose(keys["jawOpen"].values, w[:, k], atol=1e-6)
    else:  # baked points arrive through a Mesh Sequence Cache modifier
        assert any(m.type == "MESH_SEQUENCE_CACHE" for m in ob.modifiers)
    cached = [o for o in scene.scene.objects if any(c.type == "TRANSFORM_CACHE" for c in o.constraints)]
    if h is None:
        assert cached == []
        return
    # the head: Blender merges the Head xform into its one child (Rig, or Mesh when baked), which
    # plays it through a Transform Cache constraint; world = AXES @ [R | pivot + t - R pivot]
    assert len(cached) == 1
    assert np.abs(still - still[:1]).max() > 0.05  # the head moves the face far more than the tolerance
    ang, tra = [], []
    R = h[sample].as_matrix()
    for i, f in enumerate(frames):
        B._frame_set(float(f))
        W = np.array(cached[0].evaluated_get(B.bpy.context.evaluated_depsgraph_get()).matrix_world)
        M = B.AXES.T @ W[:3, :4]
        ang.append(Rotation.from_matrix(M[:, :3] @ R[i].T).magnitude())
        tra.append(np.abs(M[:, 3] - (PIVOT + h.translation[sample[i]] - R[i] @ PIVOT)).max())
    print(f"Blender {name}: head rotation error max {max(ang):.2e} rad, translation {max(tra):.2e} m")
    assert max(ang) < 1e-5
    assert max(tra) < TOL


def test_blender_clamps_weights_outside_its_sliders_baked_does_not(B, take, tmp_path):
    """Known limit of Blender 4.5's USD importer: shape keys get sliders [0, 1] and Blender clamps
    to them, so weights outside [0, 1] play clamped (UsdSkel itself does not clamp); the baked file
    plays them exactly."""
    rig, _, _, _ = take
    k = rig.names.index("jawOpen")
    w = np.zeros((5, rig.n_shapes))
    w[:, k] = [0.0, 0.5, 1.0, 1.5, -0.3]
    t = np.arange(5) / 30.0
    want = rig.evaluate(w)
    errs = {}
    for bake in (False, True):
        path = write_usd(tmp_path / f"range{int(bake)}.usdc", rig, w, t, bake=bake)
        if not bake:
            stage = Usd.Stage.Open(str(path))
            _, pts = skel_points(stage, stage.GetPrimAtPath("/Face/Rig/Mesh"), stage.GetPrimAtPath("/Face/Rig"))
            assert np.abs(pts - want).max() < TOL  # UsdSkel plays 1.5 and -0.3 as written
        scene = B.load_scene(path, fps=30.0)
        errs[bake] = np.abs(scene.vertices(scene.frames_for(t)) - want).max(axis=(1, 2))
    print(f"Blender, weights 0, 0.5, 1, 1.5, -0.3: blend shapes off by {np.round(errs[False], 6).tolist()} m, "
          f"baked off by {errs[True].max():.1e} m")
    assert errs[False][:3].max() < 1e-6 and errs[False][3:].min() > 5e-3  # clamped at 1.5 and -0.3
    assert errs[True].max() < 1e-6


# ------------------------------------------------------------------------------ quads, n-gons, UVs
def small_rig() -> Rig:
    """Two quads and a triangle sharing edges, with a UV seam (vertex 1 has two UVs), in mm."""
    from faceretarget.mesh import Mesh

    v = np.array([[0, 0, 0], [10, 0, 0], [20, 0, 0], [0, 10, 0], [10, 10, 0], [20, 10, 0], [10, 20, 0]], float)
    counts = [4, 4, 3]
    idx = [0, 1, 4, 3, 1, 2, 5, 4, 3, 4, 6]
    uvs = np.array([[0, 0], [0.5, 0], [0.55, 0], [1, 0], [0, 0.5], [0.5, 0.5], [1, 0.5], [0.5, 1]], float)
    uv_idx = [0, 1, 5, 4, 2, 3, 6, 5, 4, 5, 7]
    mesh = Mesh(v, counts, idx, uvs, uv_idx, name="small")
    d = np.zeros((2, 7, 3))
    d[0, 6] = (0, 0, 5)
    d[1, [4, 5]] = (1, 2, 3)
    return Rig(mesh, ["up", "side"], d, unit="mm", name="small")


def test_polygons_and_face_varying_uvs(tmp_path):
    rig = small_rig()
    w = np.array([[0.0, 0.0], [1.0, 0.5], [0.25, 1.0]])
    path = write_usd(tmp_path / "small.usda", rig, w, [0.0, 0.1, 0.2])
    stage = Usd.Stage.Open(str(path))
    mesh = UsdGeom.Mesh(stage.GetPrimAtPath("/Face/Rig/Mesh"))
    assert list(mesh.GetFaceVertexCountsAttr().Get()) == [4, 4, 3]
    assert list(mesh.GetFaceVertexIndicesAttr().Get()) == rig.neutral.face_indices.tolist()
    assert mesh.GetSubdivisionSchemeAttr().Get() == UsdGeom.Tokens.none
    st = UsdGeom.PrimvarsAPI(mesh).GetPrimvar("st")
    assert st.GetInterpolation() == UsdGeom.Tokens.faceVarying
    assert st.GetTypeName() == Sdf.ValueTypeNames.TexCoord2fArray
    np.testing.assert_allclose(np.array(st.ComputeFlattened()), rig.neutral.uvs[rig.neutral.face_uv_indices],
                               atol=1e-7)
    np.testing.assert_allclose(np.array(mesh.GetPointsAttr().Get()), rig.neutral.vertices / 1000.0, atol=1e-9)
    _, pts = skel_points(stage, mesh.GetPrim(), stage.GetPrimAtPath("/Face/Rig"))
    np.testing.assert_allclose(pts, rig.evaluate(w) / 1000.0, atol=1e-9)
    # a shape that moves one vertex stores one offset
    up = UsdSkel.BlendShape(stage.GetPrimAtPath("/Face/Rig/Mesh/up"))
    assert list(up.GetPointIndicesAttr().Get()) == [6]
    errors, warnings_ = usd_problems(stage)
    assert errors == [] and warnings_ == []


def test_blender_reads_polygons_and_uvs(B, tmp_path):
    rig = small_rig()
    path = write_usd(tmp_path / "small.usdc", rig, np.zeros((2, 2)), [0.0, 0.1])
    me = B.load_scene(path).mesh_object().data
    assert [len(p.vertices) for p in me.polygons] == [4, 4, 3]
    assert [list(p.vertices) for p in me.polygons] == [[0, 1, 4, 3], [1, 2, 5, 4], [3, 4, 6]]
    uv = np.array([d.uv[:] for d in me.uv_layers[0].data])
    np.testing.assert_allclose(uv, rig.neutral.uvs[rig.neutral.face_uv_indices], atol=1e-7)


def test_cli_clone_to_usd_with_and_without_bake(tmp_path, capsys):
    """``clone --out x.usdc`` writes blend shapes (and the one-line note when weights leave [0, 1]);
    ``--bake`` writes points per frame that equal the blend; ``--bake`` into a .glb is an error."""
    import warnings

    from faceretarget.cli import main
    from faceretarget.datasets import make_demo_character, make_demo_take
    from faceretarget.io import write_livelinkface, write_rig

    ada, bo = make_demo_character("ada"), make_demo_character("bo")
    write_rig(ada, tmp_path / "ada")
    write_rig(bo, tmp_path / "bo")
    write_livelinkface(tmp_path / "take.csv", make_demo_take(seconds=2.0, fps=30.0, seed=4))
    args = ["clone", "--source-rig", str(tmp_path / "ada"), "--target-rig", str(tmp_path / "bo"), "--keys", "rom-8",
            "--features", "all", "--performance", str(tmp_path / "take.csv"), "--out"]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        assert main(args + [str(tmp_path / "shapes.usdc")]) == 0
        log = capsys.readouterr().out
        assert main(args + [str(tmp_path / "baked.usdc"), "--bake"]) == 0
        baked_log = capsys.readouterr().out
        assert main(args + [str(tmp_path / "x.glb"), "--bake"]) == 2
    assert "baking applies to USD" in capsys.readouterr().err and not (tmp_path / "x.glb").exists()
    shapes, baked = Usd.Stage.Open(str(tmp_path / "shapes.usdc")), Usd.Stage.Open(str(tmp_path / "baked.usdc"))
    anim = [UsdSkel.Animation(p) for p in shapes.Traverse() if p.IsA(UsdSkel.Animation)][0]
    W = np.array(anim.GetBlendShapeWeightsAttr().Get(0.0))
    assert W.size == 8 and not [p for p in baked.Traverse() if p.IsA(UsdSkel.BlendShape)]
    mesh = [UsdGeom.Mesh(p) for p in baked.Traverse() if p.IsA(UsdGeom.Mesh)][0]
    times = mesh.GetPointsAttr().GetTimeSamples()
    assert len(times) == 60
    attr = anim.GetBlendShapeWeightsAttr()
    W_all = np.array([attr.Get(t) for t in attr.GetTimeSamples()])
    assert W_all.shape == (60, 8)
    assert ("clamps" in log) == bool(((W_all < 0) | (W_all > 1)).any()) and "clamps" not in baked_log


def test_audio_is_a_spatial_audio_prim_with_a_sidecar_wav(take, tmp_path):
    """The soundtrack: ``<name>.wav`` beside the stage, played from time code 0 by a SpatialAudio prim
    that resolves to it; the samples round-trip to 16-bit precision; the stage still validates."""
    from pxr import UsdMedia
    from scipy.io import wavfile

    rig, w, t, head = take
    rate = 16000
    n = int((t[-1] - t[0] + 0.5) * rate)
    audio = 0.5 * np.sin(2 * np.pi * 220 * np.arange(n) / rate)
    out = write_usd(tmp_path / "talk.usda", rig, w, t, head=head, audio=audio, audio_rate=rate)
    wav = tmp_path / "talk.wav"
    r, pcm = wavfile.read(wav)
    assert r == rate and np.abs(pcm / 32767.0 - audio).max() < 1.0 / 32767
    stage = Usd.Stage.Open(str(out))
    prim = UsdMedia.SpatialAudio(stage.GetPrimAtPath("/Face/Audio"))
    assert prim and prim.GetAuralModeAttr().Get() == UsdMedia.Tokens.nonSpatial
    assert Path(prim.GetFilePathAttr().Get().resolvedPath) == wav.resolve()
    assert prim.GetStartTimeAttr().Get() == 0.0
    assert abs(prim.GetEndTimeAttr().Get() / stage.GetTimeCodesPerSecond() - n / rate) < 1e-4  # usda digits
    errors, _ = usd_problems(stage)
    assert not errors, errors
    with pytest.raises(InvalidDataError, match="non-finite"):
        write_usd(tmp_path / "bad.usda", rig, w, t, audio=np.full(10, np.nan), audio_rate=rate)
    assert not (tmp_path / "bad.usda").exists() and not (tmp_path / "bad.wav").exists()
