"""The take written straight into a copy of a binary FBX (no Blender), checked in its consumers: ufbx evaluates
the written curves, Blender 4.5 imports them, and both agree with the Blender-written route."""

from __future__ import annotations

import pickle
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from faceretarget.character import _rotation_part, channels, character_frame, mesh_columns, shape_key
from faceretarget.errors import InputFileError, MissingDependencyError
from faceretarget.headpose import HeadPose
from faceretarget.io import check_character_route, read_character, write_character_animation
from faceretarget.io._fbx_binary import FbxArray, encode_fbx, parse_fbx
from faceretarget.io._fbx_write import KTIME_V7, direct_write_problem

HERE = Path(__file__).resolve().parent
ROCKETBOX = ("rocketbox", "Female_Adult_01_facial.fbx")
HEAD = "Bip01 Head"


@pytest.fixture(scope="module")
def rocketbox(chars):
    pytest.importorskip("ufbx")
    return read_character(chars.joinpath(*ROCKETBOX))


def _take(character, T: int = 300, C: int = 50, seed: int = 0):
    """``C`` channels of random but smooth weights in [0, 1] at 30 fps and a head turning up to 15 degrees
    about each axis."""
    rng = np.random.default_rng(seed)
    chans = channels(character)[:C]
    t = np.arange(T) / 30.0
    f, ph = rng.uniform(0.1, 1.5, (3, len(chans))), rng.uniform(0, 2 * np.pi, (3, len(chans)))
    W = np.clip(0.5 + 0.5 * np.sin(2 * np.pi * f[None] * t[:, None, None] + ph[None]).mean(axis=1), 0.0, 1.0)
    ang = np.radians(15) * np.stack([np.sin(2 * np.pi * 0.4 * t), np.sin(2 * np.pi * 0.27 * t + 1),
                                     np.sin(2 * np.pi * 0.33 * t + 2)], axis=1)
    return chans, W, t, HeadPose.from_rotation(Rotation.from_euler("xyz", ang))


def _angles(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """Degrees between rotation parts, per frame."""
    A = np.array([_rotation_part(a) for a in A])
    B = np.array([_rotation_part(b) for b in B])
    return np.degrees(np.arccos(np.clip((np.einsum("tij,tij->t", A, B) - 1) / 2, -1, 1)))


def _same(a, b) -> bool:
    """Two records alike: name, property types and values (arrays by their bytes), children."""
    if a.name != b.name or a.types != b.types or len(a.props) != len(b.props) or len(a.children) != len(b.children):
        return False
    for p, q in zip(a.props, b.props, strict=True):
        if isinstance(p, FbxArray):
            if not isinstance(q, FbxArray) or not np.array_equal(p.values, q.values):
                return False
        elif p != q:
            return False
    return all(_same(x, y) for x, y in zip(a.children, b.children, strict=True))


def test_binary_fbx_round_trip_and_truncation(chars):
    src = chars.joinpath(*ROCKETBOX)
    data = src.read_bytes()
    doc = parse_fbx(data, str(src))
    assert doc.version == 7700 and encode_fbx(doc) == data          # byte for byte, footer and time stamps too
    for n in (30, 1000, 1_779_721, len(data) - 100):
        with pytest.raises(InputFileError, match=r"X\.fbx: truncated binary FBX at byte \d+"):
            parse_fbx(data[:n], "X.fbx")


def test_fbx_take_written_directly(rocketbox, tmp_path):
    """ufbx reads the copy with the input's meshes and shapes, and evaluates every driven shape's weight and the
    head bone's world rotation as the take says; every other record of the file is the input's."""
    ch = rocketbox
    chans, W, t, head = _take(ch)
    out = tmp_path / "direct.fbx"
    lines: list[str] = []
    t0 = time.perf_counter()
    write_character_animation(out, ch, chans, W, t, head=head, log=lines.append)
    seconds = time.perf_counter() - t0
    print(f"direct FBX write: {seconds:.3f} s for {len(t)} frames, {len(chans)} channels")
    assert "through Blender" not in " ".join(lines) and HEAD in " ".join(lines)
    # the file: only the animation, its definitions, time settings and takes changed
    a, b = parse_fbx(Path(ch.path).read_bytes()), parse_fbx(out.read_bytes())
    anim = {"AnimationStack", "AnimationLayer", "AnimationCurveNode", "AnimationCurve"}
    for na, nb in zip(a.root.children, b.root.children, strict=True):
        if na.name == "Objects":
            kept = [o for o in na.children if o.name not in anim]
            assert all(_same(x, y) for x, y in zip(kept, [o for o in nb.children if o.name not in anim], strict=True))
            made = [o for o in nb.children if o.name in anim]
            assert sum(o.name == "AnimationStack" for o in made) == 1
            assert sum(o.name == "AnimationCurveNode" for o in made) == len(mesh_columns(chans, W)[0]) + 1
        elif na.name not in ("Connections", "Definitions", "GlobalSettings", "Takes"):
            assert _same(na, nb), na.name
    gs = {r.props[0]: r.props[4:] for r in b.root.find("GlobalSettings").find("Properties70").children}
    assert gs[b"TimeMode"] == [6] and gs[b"TimeSpanStop"] == [round(t[-1] * KTIME_V7)]
    # ufbx evaluates it
    np.save(tmp_path / "times.npy", t)
    res = tmp_path / "ufbx.pickle"
    r = subprocess.run([sys.executable, str(HERE / "_fbx_ufbx_child.py"), str(ch.path), str(out),
                        str(tmp_path / "times.npy"), HEAD, str(res)], capture_output=True, timeout=300)
    assert r.returncode == 0 and res.is_file(), r.stderr.decode()[-2000:]
    before, after, moved, names, Wf, R, stack = pickle.loads(res.read_bytes())
    assert before == after and moved == 0.0 and stack[0] == "faceretarget"
    exp = np.zeros_like(Wf)
    sm = ch.meshes[0]
    for k, col in mesh_columns(chans, W)[0].items():
        exp[:, names.index(sm.shape_names[k])] = col
    weight_err = np.abs(Wf - exp).max()
    F, G = character_frame(ch), _rotation_part(ch.joint("head").world)
    head_err = _angles(R, F.T @ head.rotation.as_matrix() @ F @ G).max()
    print(f"ufbx: weight max error {weight_err:.2e} over {(exp != 0).any(axis=0).sum()} shapes, head world rotation "
          f"max error {head_err:.2e} deg")
    assert (exp != 0).any(axis=0).sum() >= 45 and weight_err < 1e-6 and head_err < 1e-3


def test_fbx_direct_write_in_blender_and_timing(rocketbox, tmp_path):
    """Blender 4.5 imports the copy: shape key values per frame are the take's weights, the head pose bone's
    world rotation per frame is the one of the Blender-written copy; the direct writer is many times faster."""
    pytest.importorskip("bpy")
    from faceretarget.io import import_bpy
    from faceretarget.io._blender import _blender_output
    from faceretarget.io._blender_scene import write_blender_animation

    ch = rocketbox
    chans, W, t, head = _take(ch)
    direct, ref = tmp_path / "direct.fbx", tmp_path / "blender.fbx"
    t0 = time.perf_counter()
    write_character_animation(direct, ch, chans, W, t, head=head)
    t1 = time.perf_counter()
    write_blender_animation(ref, ch, chans, W, t, head=head)
    t2 = time.perf_counter()
    print(f"per take: direct {t1 - t0:.3f} s, Blender {t2 - t1:.3f} s, {(t2 - t1) / (t1 - t0):.0f}x")
    assert t1 - t0 < (t2 - t1) / 3
    frames = 1 + np.round(t * 30).astype(int)                # Blender's importer puts time 0 at frame 1

    def read(path: Path):
        with _blender_output():
            bpy = import_bpy()
            bpy.ops.wm.read_factory_settings(use_empty=True)
            bpy.ops.import_scene.fbx(filepath=str(path))
            scene = bpy.context.scene
            arm = next(o for o in bpy.data.objects if o.type == "ARMATURE" and HEAD in o.pose.bones)
            keys = [o.data.shape_keys for o in bpy.data.objects if o.type == "MESH" and o.data.shape_keys]
            vals = {kb.name: np.zeros(len(frames)) for k in keys for kb in k.key_blocks}
            R = np.zeros((len(frames), 4, 4))
            for i, f in enumerate(frames):
                scene.frame_set(int(f))
                for k in keys:
                    for kb in k.key_blocks:
                        vals[kb.name][i] = kb.value
                R[i] = np.array(arm.matrix_world) @ np.array(arm.pose.bones[HEAD].matrix)
            bpy.ops.wm.read_factory_settings(use_empty=True)
        return vals, R

    vd, Rd = read(direct)
    _, Rr = read(ref)
    driven = {shape_key(ch.meshes[0].shape_names[k]): col for k, col in mesh_columns(chans, W)[0].items()}
    got = {shape_key(n): v for n, v in vd.items()}
    weight_err = max(np.abs(got[k] - col).max() for k, col in driven.items())
    still = max(np.abs(v).max() for k, v in got.items() if k not in driven and k != shape_key("Basis"))
    head_err = _angles(Rd, Rr).max()
    turned = _angles(Rd, np.repeat(Rd[:1], len(Rd), axis=0)).max()
    print(f"Blender: shape key max error {weight_err:.2e} ({len(driven)} keys), head vs the Blender-written copy "
          f"max {head_err:.2e} deg (the head turns up to {turned:.1f} deg)")
    assert weight_err < 1e-6 and still == 0.0 and head_err < 1e-3 and turned > 10


def test_fbx_direct_write_refuses_and_falls_back(rocketbox, tmp_path, monkeypatch):
    """An ASCII FBX is not edited directly (Blender's route, or an error naming the file without bpy); a truncated
    binary FBX is an error naming the file and byte; nothing is written."""
    import copy

    import faceretarget.optional as opt

    ch = copy.copy(rocketbox)
    chans, W, t, head = _take(ch, T=5, C=3)
    ascii_ = tmp_path / "ascii.fbx"
    ascii_.write_text("; FBX 7.4.0 project file\nFBXHeaderExtension:  {\n}\n")
    ch.path = ascii_
    assert "ASCII" in direct_write_problem(ch)
    real = opt.has_module
    monkeypatch.setattr(opt, "has_module", lambda n: n != "bpy" and real(n))
    with pytest.raises(MissingDependencyError, match=r"out\.fbx: .*ascii\.fbx directly \(ascii\.fbx is an ASCII FBX\)"):
        write_character_animation(tmp_path / "out.fbx", ch, chans, W, t, head=head)
    # before any work: a binary FBX into .fbx needs no bpy; into .blend, or an ASCII FBX, does
    check_character_route(rocketbox.path, tmp_path / "out.fbx")
    for src, out in ((rocketbox.path, "out.blend"), (ascii_, "out.fbx")):
        with pytest.raises(MissingDependencyError, match=rf"{out}.*'bpy'"):
            check_character_route(src, tmp_path / out)
    cut = tmp_path / "cut.fbx"
    cut.write_bytes(Path(rocketbox.path).read_bytes()[:1_000_000])
    ch.path = cut
    with pytest.raises(InputFileError, match=r"cut\.fbx: truncated binary FBX at byte 1000000"):
        write_character_animation(tmp_path / "out.fbx", ch, chans, W, t, head=head)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["ascii.fbx", "cut.fbx"]
