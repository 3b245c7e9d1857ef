"""What faceretarget writes, played by Blender 4.5 itself (the ``bpy`` module, ``make blender``).

Every file is read back with Blender's own code (glTF, FBX and BVH importers, ``open_mainfile``) and
the depsgraph-evaluated vertices / bone rotations are compared with the rig driven by the take
(``tests/_blender.py``).  Take: 200 frames of the real Live Link Face take S07-001 on the ARKit
rig, with a synthetic head motion (the take's head columns are zero).  Errors are the max abs
vertex difference over the take's max abs face displacement (without the head motion).
"""

from __future__ import annotations

import sys
import warnings
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from faceretarget.errors import InvalidDataError, MissingDependencyError, OutputError
from faceretarget.headpose import HeadPose
from faceretarget.io import (
    read_performance,
    write_animation,
    write_blend,
    write_fbx,
    write_glb,
    write_head_motion,
)
from faceretarget.mesh import Mesh
from faceretarget.performance import Performance
from faceretarget.rig import Rig
from faceretarget.timebase import frame_times

TOL = 1e-4
PIVOT = np.array([0.0, -0.08, -0.03])  # metres: below and behind the ARKit face (a neck)


@pytest.fixture(scope="module")
def B():
    """The Blender helper module (skips the test when bpy is missing)."""
    sys.path.insert(0, str(Path(__file__).parent))
    import _blender  # skips when bpy is missing; imports it quietly (faceretarget.io.import_bpy)

    return _blender


@pytest.fixture(scope="module")
def take(arkit_rig, data_dir):
    """(rig, weights (T, K) in the rig's order, times (T,), head) for frames 400..599 of S07-001."""
    perf = read_performance(data_dir / "livelinkface" / "S07-001.csv")
    sl = slice(400, 600)
    w = arkit_rig.map_weights(perf.names, perf.weights[sl], warn=False)
    t = perf.times[sl]
    s = t - t[0]
    angles = np.stack([0.45 * np.sin(2.1 * s), 0.25 * np.sin(3.3 * s + 1.0), 0.15 * np.cos(4.7 * s)], axis=1)
    tr = np.stack([0.01 * np.sin(1.3 * s), 0.015 * np.cos(2.0 * s), 0.005 * s], axis=1)
    head = HeadPose.from_euler("YXZ", angles, tr, source="synthetic head")
    return arkit_rig, w, t, head


def expected(rig: Rig, w: np.ndarray, head: HeadPose | None = None, pivot=PIVOT) -> np.ndarray:
    """(T, V, 3) metres: the rig driven by ``w``, turned about ``pivot`` and moved by ``head``."""
    v = rig.evaluate(w) * rig.mm_per_unit / 1000.0
    if head is None:
        return v
    R = head.rotation.as_matrix()
    out = np.einsum("tij,tvj->tvi", R, v - pivot) + pivot
    return out + head.translation[:, None] if head.translation is not None else out


def rel_error(got: np.ndarray, want: np.ndarray, rig: Rig, w: np.ndarray) -> float:
    """max |got - want| over the take's max face displacement from the neutral (metres)."""
    face = rig.evaluate(w) * rig.mm_per_unit / 1000.0
    motion = np.abs(face - rig.neutral.vertices * rig.mm_per_unit / 1000.0).max()
    return float(np.abs(got - want).max() / motion)


def angle(q: np.ndarray, head: HeadPose) -> np.ndarray:
    """(T,) radians between quaternions ``q`` (x, y, z, w) and ``head``'s rotations."""
    return (Rotation.from_quat(q) * head.rotation.inv()).magnitude()


# ------------------------------------------------------------------------------------------------ (a)
def test_glb_in_blender_gltf_importer(B, take, tmp_path):
    rig, w, t, head = take
    path = write_glb(tmp_path / "take.glb", rig, w, t, head=head, head_pivot=PIVOT)
    scene = B.load_scene(path, fps=30)
    frames = scene.frames_for(t)
    want = expected(rig, w, head)
    got = scene.vertices(frames, reference=want[0])
    err = rel_error(got, want, rig, w)
    rot = angle(scene.head_rotations(frames), head)
    print(f"\n.glb in Blender's glTF importer: vertex error {err:.2e} of the motion, head rotation "
          f"error {rot.max():.2e} rad over {len(t)} frames")
    assert err < TOL
    assert rot.max() < 1e-4


# ------------------------------------------------------------------------------------------------ (b)
def test_weights_outside_unit_range_glb_clamps_blend_does_not(B, take, tmp_path):
    rig, w, t, head = take
    w2 = 1.8 * w - 0.3
    assert w2.min() < 0 and w2.max() > 1
    want = expected(rig, w2)

    glb = B.load_scene(write_glb(tmp_path / "wide.glb", rig, w2, t), fps=30)
    keys = glb.shape_keys()
    outside = np.concatenate([k.outside() for k in keys.values()])
    got = glb.vertices(glb.frames_for(t), reference=want[0])
    glb_err = rel_error(got, want, rig, w2)

    blend = B.load_scene(write_blend(tmp_path / "wide.blend", rig, w2, t))
    keys_b = blend.shape_keys()
    outside_b = np.concatenate([k.outside() for k in keys_b.values()])
    got_b = blend.vertices(blend.frames_for(t), reference=want[0])
    blend_err = rel_error(got_b, want, rig, w2)
    # Blender's FBX importer sizes the sliders from every keyed value: FBX keeps the range too
    times = frame_times(len(t), 30.0)  # FBX is baked at integer frames
    fbx = B.load_scene(write_fbx(tmp_path / "wide.fbx", rig, w2, times))
    outside_f = np.concatenate([k.outside() for k in fbx.shape_keys().values()])
    fbx_err = rel_error(fbx.vertices(fbx.frames_for(times), reference=want[0]), want, rig, w2)
    print(f"\nweights in [{w2.min():.2f}, {w2.max():.2f}]: .glb (Blender's glTF importer) has "
          f"{outside.mean():.1%} of {outside.size} keyed values outside their sliders and plays "
          f"{glb_err:.1%} of the motion off; .blend: {outside_b.mean():.1%} outside, error {blend_err:.2e}; "
          f".fbx: {outside_f.mean():.1%} outside, error {fbx_err:.2e}")
    assert outside.mean() > 0.05 and glb_err > 0.05  # the importer's sliders clamp the take
    assert not outside_b.any() and not outside_f.any()
    assert blend_err < TOL and fbx_err < TOL
    for k, name in enumerate(rig.names):
        kb = keys_b[name]
        assert kb.slider_min <= min(0.0, w2[:, k].min()) and kb.slider_max >= max(1.0, w2[:, k].max())
        np.testing.assert_allclose(kb.values, w2[:, k], atol=1e-6)


# ------------------------------------------------------------------------------------------------ (c)
def test_blend_scene_timing_head_and_audio(B, take, tmp_path):
    rig, w, t, head = take
    rate = 16000
    audio = (0.3 * np.sin(2 * np.pi * 220 * np.arange(int(rate * (t[-1] - t[0] + 0.5))) / rate))
    stereo = np.stack([audio, -audio], axis=1)
    q = head.quaternions.copy()
    q[:3] = np.nan  # no pose at the start: identity
    q[50:55] = np.nan  # a gap: hold frame 49
    gappy = HeadPose(q, head.translation, source="gappy head")
    path = write_blend(tmp_path / "take.blend", rig, w, t, head=gappy, audio=stereo, audio_rate=rate,
                       head_pivot=PIVOT)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["take.blend"]  # no temporary left

    scene = B.load_scene(path)
    sc = scene.scene
    fps = 1.0 / np.median(np.diff(t))
    assert sc.render.fps == 30 and abs(sc.render.fps / sc.render.fps_base - fps) < 1e-4
    frames = scene.frames_for(t)
    assert sc.frame_start == 1 and sc.frame_end == int(np.ceil(frames[-1] - 1e-6))
    # every key at 1 + (t - t0) * fps exactly (S07-001's frames are not evenly spaced)
    keys = scene.shape_keys()
    assert set(keys) == set(rig.names)
    for k in keys.values():
        np.testing.assert_allclose(k.frames, frames, atol=1e-4)
    assert np.abs(np.diff(frames) - 1).max() > 1e-4  # uneven indeed

    filled = head.quaternions.copy()
    filled[:3] = (0, 0, 0, 1)
    filled[50:55] = filled[49]
    tr = head.translation.copy()
    tr[:3] = 0
    tr[50:55] = tr[49]
    want_head = HeadPose(filled, tr)
    rot = angle(scene.head_rotations(frames), want_head)
    want = expected(rig, w, want_head)
    got = scene.vertices(frames, reference=want[0])
    err = rel_error(got, want, rig, w)

    strips = scene.sound_strips()
    assert len(strips) == 1
    s = strips[0]
    seconds = len(audio) / rate
    print(f"\n.blend: fps {sc.render.fps}/{sc.render.fps_base:.6f}, frames {sc.frame_start}..{sc.frame_end}, "
          f"head rotation error {rot.max():.2e} rad, vertex error {err:.2e}, sound strip at frame "
          f"{s.frame_start:g} for {s.frame_final_duration} frames ({seconds:.3f} s = {seconds * fps:.2f} frames), "
          f"packed {s.sound.packed_file.size} bytes")
    assert rot.max() < 1e-4 and err < TOL
    assert s.frame_start == 1 and abs(s.frame_final_duration - seconds * fps) <= 1.0
    assert s.sound.packed_file is not None and s.sound.packed_file.size >= 4 * len(audio)


def test_blend_ntsc_rate_and_polygons(B, tmp_path):
    """29.97 fps (30 / 1.001) on integer frames; quads and an n-gon kept, UVs kept, vertex order kept."""
    v = np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0], [0, 1, 0], [1, 1, 0], [2, 1, 0], [1.5, 1.8, 0.2],
                  [-1, 0.5, 0], [-0.5, 1.5, 0]], float)
    counts = np.array([4, 4, 5])  # two quads and a pentagon
    idx = np.array([0, 1, 4, 3, 1, 2, 5, 4, 3, 4, 6, 8, 7])
    uvs = v[:, :2] / 3
    mesh = Mesh(v, counts, idx, uvs, idx.copy(), name="quads")
    rng = np.random.default_rng(0)
    rig = Rig(mesh, ["jawOpen", "mouthSmileLeft"], rng.normal(0, 0.1, (2, len(v), 3)), unit="cm")
    times = np.arange(40) * 1001 / 30000  # NTSC 29.97
    w = np.stack([np.linspace(0, 1, 40), np.linspace(1, -0.5, 40)], axis=1)
    scene = B.load_scene(write_blend(tmp_path / "ntsc.blend", rig, w, times))
    sc = scene.scene
    assert sc.render.fps == 30 and abs(sc.render.fps_base - 1.001) < 1e-6
    assert (sc.frame_start, sc.frame_end) == (1, 40)
    np.testing.assert_allclose(scene.shape_keys()["jawOpen"].frames, np.arange(1, 41), atol=1e-4)
    me = scene.mesh_object().data
    assert [len(p.vertices) for p in me.polygons] == counts.tolist()
    assert [i for p in me.polygons for i in p.vertices] == idx.tolist()
    uv = np.array([d.uv[:] for d in me.uv_layers["UVMap"].data])
    np.testing.assert_allclose(uv, uvs[idx], atol=1e-6)
    frames = scene.frames_for(times)
    got = scene.vertices(frames)  # no reordering: the vertex order is ours
    assert rel_error(got, expected(rig, w), rig, w) < TOL


# ------------------------------------------------------------------------------------------------ (d)
def test_fbx_in_blender_fbx_importer(B, take, tmp_path):
    """Blender's FBX exporter bakes integer frames: a take on a 30 fps grid plays within 1e-4."""
    rig, w, t, head = take
    times = frame_times(len(t), 30.0, start=t[0])
    path = write_fbx(tmp_path / "take.fbx", rig, w, times, head=head, head_pivot=PIVOT)
    scene = B.load_scene(path)
    frames = scene.frames_for(times)
    want = expected(rig, w, head)
    got = scene.vertices(frames, reference=want[0])
    err = rel_error(got, want, rig, w)
    rot = angle(scene.head_rotations(frames), head)
    unit = _fbx_unit_scale(path)
    scales = {o.name: tuple(round(x, 6) for x in o.matrix_world.to_scale()) for o in scene.scene.objects}
    print(f"\n.fbx in Blender's FBX importer: UnitScaleFactor {unit:g} (cm), object scales {scales}, "
          f"fps {scene.fps:g}, vertex error {err:.2e}, head rotation error {rot.max():.2e} rad")
    assert unit == 1.0  # centimetres in the file; Blender's importer scales back to metres
    assert err < TOL and rot.max() < 1e-4
    assert scene.fps == 30

    # S07-001's own (uneven) times: the FBX holds what the .blend plays at every integer frame
    frames = np.arange(1, int(np.floor(1 + (t[-1] - t[0]) * 30)) + 1)
    fbx = B.load_scene(write_fbx(tmp_path / "uneven.fbx", rig, w, t, head=head, head_pivot=PIVOT))
    v_fbx = fbx.vertices(frames, reference=want[0])
    blend = B.load_scene(write_blend(tmp_path / "uneven.blend", rig, w, t, head=head, head_pivot=PIVOT))
    v_blend = blend.vertices(frames, reference=want[0])
    uneven = rel_error(v_fbx, v_blend, rig, w)
    print(f".fbx of uneven times vs .blend at {len(frames)} integer frames: {uneven:.2e}")
    assert uneven < TOL


def test_fbx_ntsc_times_exact_blender_importer_uses_integer_fps(B, tmp_path):
    """At 29.97 fps the .fbx holds the take's exact times; Blender's FBX importer turns FBX time into
    frames with the integer fps (30), so in Blender the keys land 0.1 % late: a Blender limitation
    (the .blend keys the same take at frames 1, 2, 3 ... exactly)."""
    rig = Rig(Mesh.from_triangles(np.eye(3), [[0, 1, 2]]), ["jawOpen"], np.full((1, 3, 3), 0.1), unit="m")
    t = np.arange(300) * 1001 / 30000
    w = np.linspace(0, 1, 300)[:, None]
    scene = B.load_scene(write_fbx(tmp_path / "ntsc.fbx", rig, w, t))
    k = scene.shape_keys()["jawOpen"]
    r = scene.scene.render
    assert (r.fps, round(r.fps_base, 6)) == (30, 1.001)
    np.testing.assert_allclose((k.frames - 1) / r.fps, t, atol=1e-6)  # FBX seconds = the take's times
    np.testing.assert_allclose(k.values, w[:, 0], atol=1e-6)
    print(f"\n29.97 fps .fbx in Blender: last key at frame {k.frames[-1]:.3f} instead of 300 "
          f"(the importer's integer fps)")


def _fbx_unit_scale(path: Path) -> float:
    """``GlobalSettings`` ``UnitScaleFactor`` of a binary FBX (Blender's own FBX parser)."""
    from io_scene_fbx import parse_fbx

    root, _ = parse_fbx.parse(str(path))
    for e in root.elems:
        if e.id == b"GlobalSettings":
            for p in (x for x in e.elems if x.id == b"Properties70") :
                for prop in p.elems:
                    if prop.props[0] == b"UnitScaleFactor":
                        return float(prop.props[4])
    raise AssertionError(f"{path}: no UnitScaleFactor")


# ------------------------------------------------------------------------------------------------ (e)
def test_bvh_head_in_blender_bvh_importer(B, take, tmp_path):
    rig, w, t, head = take
    perf = Performance(t, 1.0 / np.median(np.diff(t)), head=head, source="synthetic head")
    path = write_head_motion(tmp_path / "head.bvh", perf)
    scene = B.load_scene(path)
    frames = 1.0 + np.arange(len(t))
    rot = angle(scene.head_rotations(frames, name="Head"), head)
    print(f"\n.bvh in Blender's BVH importer: head rotation error {rot.max():.2e} rad over {len(t)} frames, "
          f"scene fps {scene.fps:g}")
    assert rot.max() < 1e-4


# ------------------------------------------------------------------------------------------------ checks
def test_weight_beyond_blender_slider_limit(take, tmp_path):
    rig, w, t, _ = take
    bad = w.copy()
    bad[17, rig.index("jawOpen")] = 12.5
    with pytest.raises(InvalidDataError, match=r"frame 17 weight 'jawOpen' is 12\.5.*\+-10"):
        write_blend(tmp_path / "bad.blend", rig, bad, t)
    assert list(tmp_path.iterdir()) == []


def test_registry_and_missing_bpy(take, tmp_path, monkeypatch):
    rig, w, t, _ = take
    with pytest.raises(OutputError, match="needs a rig and weights"):
        write_animation(tmp_path / "x.blend", weights=w, times=t)
    monkeypatch.setitem(sys.modules, "bpy", None)  # as if bpy were not installed
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        with pytest.raises(MissingDependencyError, match=r"make blender .*--no-deps 'bpy"):
            write_animation(tmp_path / "x.fbx", rig=rig, weights=w, times=t)
    assert list(tmp_path.iterdir()) == []


def test_cli_clone_to_blend_matches_glb(B, tmp_path):
    """``faceretarget clone --out take.blend``: the registry's .blend writer gets the same weights as
    the .glb of the same command."""
    from faceretarget.cli import main
    from faceretarget.datasets import make_demo_character, make_demo_take
    from faceretarget.io import read_glb_weights, write_livelinkface, write_rig

    ada, bo = make_demo_character("ada"), make_demo_character("bo")
    write_rig(ada, tmp_path / "ada")
    write_rig(bo, tmp_path / "bo")
    take = make_demo_take(seconds=2.0, fps=30.0, seed=4)
    write_livelinkface(tmp_path / "take.csv", take)
    args = ["--quiet", "clone", "--source-rig", str(tmp_path / "ada"), "--target-rig", str(tmp_path / "bo"),
            "--keys", "arkit", "--performance", str(tmp_path / "take.csv"), "--out"]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        assert main(args + [str(tmp_path / "take.glb")]) == 0
        assert main(args + [str(tmp_path / "take.blend")]) == 0
    names, times, w = read_glb_weights(tmp_path / "take.glb")
    scene = B.load_scene(tmp_path / "take.blend")
    keys = scene.shape_keys()
    got = np.stack([keys[n].values for n in names], axis=1)
    print(f"\nclone -> .blend vs .glb: {len(times)} frames x {len(names)} keys, max weight difference "
          f"{np.abs(got - w).max():.1e}")
    np.testing.assert_allclose(got, w, atol=1e-6)
    np.testing.assert_allclose(keys[names[0]].frames, 1 + times * scene.fps, atol=1e-3)


def test_blend_invalid_faces_warn_and_keep_vertices(B, tmp_path):
    """A duplicate face is removed by Blender's mesh validation: one DataWarning naming the file;
    the vertices (and so the animation) are unchanged."""
    from faceretarget.errors import DataWarning

    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]], float)
    rig = Rig(Mesh(v, [3, 3, 3], [0, 1, 2, 0, 1, 2, 1, 3, 2]), ["jawOpen"], np.full((1, 4, 3), 0.1), unit="m")
    with pytest.warns(DataWarning, match=r"dup\.blend: Blender corrected invalid geometry"):
        path = write_blend(tmp_path / "dup.blend", rig, np.array([[0.5], [1.0]]), [0.0, 0.1])
    scene = B.load_scene(path)
    assert len(scene.mesh_object().data.polygons) == 2
    got = scene.vertices(scene.frames_for([0.0, 0.1]))
    np.testing.assert_allclose(got, expected(rig, np.array([[0.5], [1.0]])), atol=1e-7)


# ------------------------------------------------------------------------------------ issue 12, done when
def test_quick_start_plays_in_blender_against_ground_truth(B, data_dir, ict_rig, arkit_rig, tmp_path):
    """The README's quick start (clone ICT -> ARKit, rom-40 keys from alex_rom_3, S07-001) written for
    Blender (.blend) and opened in Blender 4.5 plays within 10 % of the ground truth's motion (the ARKit
    rig driven by the take's own weights) with no keyed value outside its slider; the same command
    to .glb is what a user got before (clamped sliders); ``--keys arkit`` to .glb plays the truth."""
    from faceretarget.cli import main
    from faceretarget.metrics import rel_motion_pct

    csv = data_dir / "livelinkface" / "S07-001.csv"
    perf = read_performance(csv)
    truth = arkit_rig.evaluate(arkit_rig.map_weights(perf.names, perf.weights, warn=False))
    truth = truth * arkit_rig.mm_per_unit / 1000.0
    neutral = arkit_rig.neutral.vertices * arkit_rig.mm_per_unit / 1000.0
    sample = np.arange(0, perf.n_frames, 20)                  # 102 of the 2,028 frames
    rom = ["--keys", "rom-40", "--keys-from", str(data_dir / "livelinkface" / "alex_rom_3.csv")]
    base = ["--quiet", "clone", "--source-rig", str(data_dir / "ict-face"), "--target-rig",
            str(data_dir / "arkit-face"), "--performance", str(csv), "--head", "off"]
    from faceretarget.io import glb_vertex_order

    first_copy = {}                                           # glTF vertex order: our vertex -> its first copy
    for k, v in enumerate(glb_vertex_order(arkit_rig.neutral)):
        first_copy.setdefault(int(v), k)
    glb_order = np.array([first_copy[v] for v in range(arkit_rig.n_vertices)])
    out = {}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for name, keys, ext in (("rom40", rom, ".blend"), ("rom40", rom, ".glb"), ("arkit", ["--keys", "arkit"], ".glb")):
            path = tmp_path / f"{name}{ext}"
            assert main(base + keys + ["--out", str(path)]) == 0
            scene = B.load_scene(path, fps=perf.fps if ext == ".glb" else None)
            frames = scene.frames_for(perf.times)[sample]
            order = glb_order if ext == ".glb" else np.arange(arkit_rig.n_vertices)
            got = scene.vertices(frames, order=order)
            tracks = scene.shape_keys().values()
            n_keys = sum(len(k.values) for k in tracks)
            clamped = sum(int(k.outside().sum()) for k in tracks)
            out[name, ext] = (rel_motion_pct(got, truth[sample], neutral), clamped, n_keys)
    for (name, ext), (rel, clamped, n) in out.items():
        print(f"\n{name} keys -> {ext} in Blender: {rel:.2f} % of the motion wrong, {clamped} of {n} keyed "
              "values outside their sliders")
    rel, clamped, _ = out["rom40", ".blend"]
    assert rel <= 10.0 and clamped == 0
    assert out["rom40", ".glb"][1] > 0                        # the glTF importer's [0, 1] sliders clamp
    rel, clamped, _ = out["arkit", ".glb"]
    assert rel < 0.01 and clamped == 0


def test_skeleton_target_plays_in_blender_bvh_and_gltf_importers(B, data_dir, tmp_path):
    """A skeletal retarget (issue 16): the .bvh and the skinned .glb, as Blender's own importers pose
    the armature, put every joint where our rotation blend does and keep every bone's length."""
    from faceretarget.targets import bone_lengths, read_target

    t = read_target(data_dir / "headmotion" / "beat_2_scott_0_1_1.bvh",
                    frames={"neutral": 0, "a": 100, "b": 400, "c": 800})
    W = np.random.default_rng(1).uniform(-0.5, 1.5, (20, 3))
    times = np.arange(20) / 30
    ours = (t.world_positions(W) * 0.01) @ B.AXES.T          # cm -> m, our axes -> Blender's
    L0 = t.rest_bone_lengths() * 0.01
    for ext in (".bvh", ".glb"):
        path = t.write(tmp_path / f"skeleton{ext}", W, times)
        scene = B.load_scene(path)
        arm = next(o for o in B.bpy.context.scene.objects if o.type == "ARMATURE")
        got = []
        for f in scene.frames_for(times):
            B.bpy.context.scene.frame_set(int(np.floor(f)), subframe=float(f - np.floor(f)))
            got.append([list(arm.matrix_world @ arm.pose.bones[n].head) for n in t.joint_names])
        got = np.array(got)
        err, dev = np.abs(got - ours).max(), np.abs(bone_lengths(got, t.parents) - L0).max()
        print(f"\nskeleton {ext} in Blender: joints within {err:.1e} m of ours, bone lengths within {dev:.1e} m")
        assert err < 1e-5 and dev < 1e-5


def test_affine_inverse_of_bone_matrices_needs_no_lapack():
    """The scene reader inverts bone and object matrices with the cross-product formula (inside Blender,
    ``np.linalg.inv`` went to OpenBLAS's threaded solver, whose threads held the main thread 35-205 ms under
    load): equal to NumPy's inverse on rotations with scale, shear and translation, one matrix or a stack,
    and a singular matrix raises as NumPy's does.  No Blender needed."""
    from faceretarget.io._blender_scene import _inv_affine

    rng = np.random.default_rng(3)
    M = np.zeros((129, 4, 4))
    M[:, :3, :3] = Rotation.random(129, random_state=4).as_matrix() * rng.uniform(0.01, 100.0, (129, 1, 1))
    M[5, :3, :3] = [[1.0, 0.5, 0.0], [0.0, 2.0, 0.3], [0.1, 0.0, 3.0]]          # a sheared bone
    M[:, :3, 3] = rng.normal(0.0, 5.0, (129, 3))
    M[:, 3, 3] = 1.0
    inv = _inv_affine(M)
    np.testing.assert_allclose(inv, np.linalg.inv(M), rtol=0, atol=1e-12 * np.abs(np.linalg.inv(M)).max())
    np.testing.assert_allclose(np.einsum("nij,njk->nik", M, inv), np.broadcast_to(np.eye(4), M.shape), atol=1e-12)
    np.testing.assert_allclose(_inv_affine(M[7]), np.linalg.inv(M[7]), atol=1e-12)
    flat = np.eye(4)
    flat[2, 2] = 0.0
    with pytest.raises(np.linalg.LinAlgError):
        _inv_affine(flat)
