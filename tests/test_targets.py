"""Targets of any parameterisation (issue 16): control tables, skeletons, 2-D drawings.

Control curves played on the rig equal the mesh-target result; rotation blending keeps bone
lengths while blending joint positions shortens them; animated SVGs read back to the blended
points; bad tables, drawings and key frames fail naming the file and row / path / frame; the
``retarget`` command writes every kind.
"""

from __future__ import annotations

import json
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from faceretarget.cli import main
from faceretarget.cloning import keymodel_rig
from faceretarget.datasets import write_drawn_face
from faceretarget.errors import InputFileError, InvalidDataError, MissingShapeError
from faceretarget.io import (
    Bvh,
    BvhJoint,
    ControlTable,
    read_bvh,
    read_glb_skeleton,
    read_livelinkface,
    read_svg_animation,
    read_svg_drawing,
    write_bvh,
    write_control_table,
)
from faceretarget.mesh import Mesh
from faceretarget.names import ARKIT_NAMES
from faceretarget.numerics import blend_rotations
from faceretarget.pipelines import retarget_take, target_weights, write_result
from faceretarget.rig import Rig
from faceretarget.targets import ControlTarget, bone_lengths, read_target

sys.path.insert(0, str(Path(__file__).parent))

FRAMES = slice(450, 750)


@pytest.fixture(scope="module")
def take(data_dir):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return read_livelinkface(data_dir / "livelinkface" / "S07-001.csv").slice(FRAMES.start, FRAMES.stop)


def _rom_keys(take, n=8):
    """``n`` frames of the take as key weight vectors over the 52 ARKit names (a P1-style key set)."""
    W = np.zeros((take.n_frames, len(ARKIT_NAMES)))
    col = {c: j for j, c in enumerate(take.names)}
    from faceretarget.names import normalize_name

    for j, name in enumerate(ARKIT_NAMES):
        for c, k in col.items():
            if normalize_name(c) == name:
                W[:, j] = take.weights[:, k]
    frames = np.linspace(0, take.n_frames - 1, n).round().astype(int)
    return [f"frame_{f:05d}" for f in frames], W[frames]


# ------------------------------------------------------------------------------------------ controls
def test_control_target_curves_play_the_mesh_target_result(arkit_rig, ict_rig, take, tmp_path):
    labels, U = _rom_keys(take)
    names = list(ARKIT_NAMES)
    sk, tk = keymodel_rig(ict_rig, labels, U, names), keymodel_rig(arkit_rig, labels, U, names)
    table = write_control_table(tmp_path / "keys.csv", ControlTable(labels, names, U, np.zeros(52), np.ones(52),
                                                                    np.zeros(52)))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        target = read_target(table, rig=arkit_rig)                          # default: solved inside the ranges
        as_solved = read_target(table, rig=arkit_rig, ranges="report")
        mesh = retarget_take(take, sk, tk, source_rig=ict_rig)
        ctrl = retarget_take(take, sk, target, source_rig=ict_rig)
    Vm = mesh.model.blend(mesh.result.weights)
    motion = np.abs(Vm - arkit_rig.neutral.vertices).max()
    W = target_weights(ctrl)
    # as first solved: W @ C (linear blending), exactly the mesh target's faces, partly outside the ranges
    C0 = as_solved.params(W)
    np.testing.assert_allclose(C0, W @ U, rtol=0, atol=1e-12)
    V0 = arkit_rig.evaluate(arkit_rig.map_weights(names, C0, warn=False))
    assert np.abs(V0 - Vm).max() / motion < 1e-9
    rep0 = target.range_report(C0)
    assert 0 < rep0.inside_pct < 100 and rep0.inside_pct == pytest.approx(100 * ((C0 >= 0) & (C0 <= 1)).mean())
    # the default: the frames outside solved again inside the ranges, still a blend of the keys (the mesh keys
    # driven by those weights give the same faces), frames already inside unchanged, nearer than clipping
    C = target.params(W)
    Wk = target.key_weights(W)
    assert ((C >= 0) & (C <= 1)).all() and target.range_report(C).inside_pct == 100.0
    np.testing.assert_allclose(C, Wk @ U, rtol=0, atol=1e-9)
    Vc = arkit_rig.evaluate(arkit_rig.map_weights(names, C, warn=False))
    Vk = tk.evaluate(tk.map_weights(target.names, Wk, warn=False))
    assert np.abs(Vc - Vk).max() / motion < 1e-9
    inside0 = ((C0 >= 0) & (C0 <= 1)).all(axis=1)
    np.testing.assert_array_equal(Wk[inside0], W[inside0])
    from scipy.optimize import minimize

    from faceretarget.numerics import range_metric

    # each frame solved again is the nearest in-range blend in the target's geometry: SciPy's SLSQP on the
    # same problem finds no nearer one
    Lk = range_metric(tk.deltas.reshape(tk.n_shapes, -1).T)
    for t in np.flatnonzero(~inside0)[:: max(1, int((~inside0).sum()) // 4)][:4]:
        def dist(w, t=t):
            return 0.5 * float(np.sum((Lk @ (w - W[t])) ** 2))

        ref = minimize(dist, np.zeros(len(labels)), jac=lambda w, t=t: Lk.T @ (Lk @ (w - W[t])), method="SLSQP",
                       constraints=[{"type": "ineq", "fun": lambda w: w @ U, "jac": lambda w: U.T},
                                    {"type": "ineq", "fun": lambda w: 1 - w @ U, "jac": lambda w: -U.T}],
                       options={"ftol": 1e-15, "maxiter": 500})
        assert dist(Wk[t]) <= ref.fun * (1 + 1e-6) + 1e-18
    # projecting into the ranges: every value inside, frames already inside unchanged
    proj = read_target(table, rig=arkit_rig, ranges="project")
    Cp = proj.in_ranges(C)
    assert ((Cp >= 0) & (Cp <= 1)).all()
    inside = ((C >= 0) & (C <= 1)).all(axis=1)
    np.testing.assert_array_equal(Cp[inside], C[inside])
    # the Live Link Face CSV holds the curves (3 decimals) and a .glb plays them on the rig's shapes
    write_result(tmp_path / "out.csv", ctrl)
    back = read_livelinkface(tmp_path / "out.csv")
    got = arkit_rig.map_weights(back.names, back.weights, warn=False)
    want = arkit_rig.map_weights(names, C, warn=False)
    assert np.abs(got - want).max() < 6e-4
    write_result(tmp_path / "out.glb", ctrl)
    assert (tmp_path / "out.glb").stat().st_size > 0


def test_control_table_without_a_rig_writes_curves(tmp_path):
    (tmp_path / "t.json").write_text(json.dumps({
        "controls": ["jaw", "lipCorner"], "range": {"jaw": [0, 10], "lipCorner": [-1, 1]}, "neutral": {"lipCorner": 0.5},
        "keys": {"a": {"jaw": 10}, "b": [0, -1]}}))
    t = read_target(tmp_path / "t.json")
    assert t.kind == "controls" and t.names == ["a", "b"]
    W = np.array([[0.0, 0.0], [1.0, 0.0], [0.5, 0.5], [0.0, 2.0]])
    as_solved = read_target(tmp_path / "t.json", ranges="report").params(W)
    np.testing.assert_allclose(as_solved, [[0, 0.5], [10, 0.5], [5, -0.25], [0, -2.5]])
    assert t.range_report(as_solved).inside_pct == pytest.approx(7 / 8 * 100)
    # the default solves the last frame again: the nearest blend whose lipCorner stays in [-1, 1] is key b at 1
    np.testing.assert_allclose(t.key_weights(W), [[0, 0], [1, 0], [0.5, 0.5], [0, 1]], atol=1e-12)
    np.testing.assert_allclose(t.params(W), [[0, 0.5], [10, 0.5], [5, -0.25], [0, -1]], atol=1e-12)
    clipped = read_target(tmp_path / "t.json", ranges="clip").params(W)
    np.testing.assert_allclose(clipped[-1], [0, -1])
    t.write(tmp_path / "c.json", W, np.arange(4) / 30)
    doc = json.loads((tmp_path / "c.json").read_text())
    np.testing.assert_allclose(doc["controls"]["lipCorner"], t.params(W)[:, 1])
    with pytest.raises(Exception, match="target-rig"):
        t.check_output(tmp_path / "c.glb")


# ------------------------------------------------------------------------------------------ skeleton
def _arm_bvh(path: Path) -> Path:
    """A root, shoulder, elbow, wrist chain: frame 0 straight, frame 1 elbow bent 90 degrees, frame 2
    shoulder raised, frame 3 root moved."""
    joints = [BvhJoint("Hips", -1, np.zeros(3), ("Xposition", "Yposition", "Zposition", "Zrotation", "Xrotation",
                                                 "Yrotation")),
              BvhJoint("Shoulder", 0, np.array([0.0, 10.0, 0.0]), ("Zrotation", "Xrotation", "Yrotation")),
              BvhJoint("Elbow", 1, np.array([30.0, 0.0, 0.0]), ("Zrotation", "Xrotation", "Yrotation")),
              BvhJoint("Wrist", 2, np.array([25.0, 0.0, 0.0]), ("Zrotation", "Xrotation", "Yrotation"),
                       np.array([8.0, 0.0, 0.0]))]
    m = np.zeros((4, 15))
    m[1, 9] = 90.0           # elbow Z
    m[2, 6] = 70.0           # shoulder Z
    m[2, 8] = 30.0           # shoulder Y
    m[3, 0:3] = (5.0, -2.0, 1.0)
    return write_bvh(path, Bvh(joints, 1 / 30, m, source=str(path)))


def test_rotation_blending_keeps_bone_lengths_and_vertex_blending_shrinks(tmp_path):
    bvh = _arm_bvh(tmp_path / "arm.bvh")
    (tmp_path / "frames.csv").write_text("key,frame\nneutral,0\nbend,1\nraise,2\nstep,3\n")
    t = read_target(bvh, frames=tmp_path / "frames.csv")
    assert t.kind == "skeleton" and t.names == ["bend", "raise", "step"]
    rng = np.random.default_rng(0)
    W = np.vstack([np.eye(3), [[0.5, 0.0, 0.0], [0.5, 0.5, 0.0]], rng.uniform(-0.5, 1.5, (40, 3))])
    P = t.world_positions(W)
    L0 = t.rest_bone_lengths()
    assert np.abs(bone_lengths(P, t.parents) - L0).max() < 1e-9
    ref = read_bvh(bvh)
    from faceretarget.io import bvh_world_positions

    np.testing.assert_allclose(P[:3], bvh_world_positions(ref)[1:], atol=1e-9)         # exact at the keys
    # half way to the bent elbow: the rotation blend bends 45 degrees, the position blend cuts the corner
    q = blend_rotations(t.rest_rotations, t.key_rotations, W[3:4])
    assert Rotation.from_quat(q[0, 2]).magnitude() == pytest.approx(np.pi / 4)
    Lv = bone_lengths(t.vertex_blend(W[3:4]), t.parents)[0]
    assert Lv[2] < 0.75 * L0[2] and Lv[2] == pytest.approx(L0[2] * np.sqrt(0.5), rel=1e-9)
    # the root moves linearly
    np.testing.assert_allclose(t.params(np.array([[0, 0, 0.5]]))[1][0, 0], [2.5, -1.0, 0.5])
    # BVH and skinned glTF out
    times = np.arange(len(W)) / 30
    t.write(tmp_path / "out.bvh", W, times)
    back = read_bvh(tmp_path / "out.bvh")
    assert np.abs(bone_lengths(bvh_world_positions(back), t.parents) - L0).max() < 1e-9
    np.testing.assert_allclose(bvh_world_positions(back), P, atol=1e-4)
    t.write(tmp_path / "out.glb", W, times)
    sk = read_glb_skeleton(tmp_path / "out.glb")
    assert sk.names == ["Hips", "Shoulder", "Elbow", "Wrist"] and len(sk.times) == len(W)
    qa, qb = sk.rotations, t.params(W)[0]
    assert np.abs(np.abs((qa * qb).sum(axis=2)) - 1).max() < 1e-6
    from test_io_gltf import validate

    validate(tmp_path / "out.glb")


def test_beat_bvh_keys_keep_bone_lengths(data_dir):
    bvh = data_dir / "headmotion" / "beat_2_scott_0_1_1.bvh"
    t = read_target(bvh, frames={"neutral": 0, "a": 100, "b": 400, "c": 800})
    W = np.random.default_rng(1).uniform(-0.5, 1.5, (50, 3))
    L0 = t.rest_bone_lengths()
    assert np.abs(bone_lengths(t.world_positions(W), t.parents) - L0).max() < 1e-9
    shrink = 1 - bone_lengths(t.vertex_blend(np.full((1, 3), 1 / 3)), t.parents)[0] / np.maximum(L0, 1e-12)
    assert shrink[L0 > 1e-6].max() > 0.05                  # a convex joint-position blend shortens limbs


# ------------------------------------------------------------------------------------------ drawings
def test_svg_round_trip_and_point_sets(tmp_path):
    write_drawn_face(tmp_path / "face")
    t = read_target(tmp_path / "face")
    assert t.kind == "drawing" and t.n_keys == 15
    W = np.random.default_rng(2).uniform(-0.2, 1.2, (25, t.n_keys))
    P = t.params(W)
    times = np.arange(25) / 25
    t.write(tmp_path / "face.svg", W, times)
    tt, back, _ = read_svg_animation(tmp_path / "face.svg")
    assert back.shape == P.shape and np.abs(back - P).max() < 1e-6
    np.testing.assert_allclose(tt, times, atol=1e-6)
    t.write(tmp_path / "frames", W, times)
    f7 = read_svg_drawing(tmp_path / "frames" / "frame_00007.svg")
    assert np.abs(f7.points - P[7]).max() < 1e-6
    t.write(tmp_path / "sheet.png", W, times)
    assert (tmp_path / "sheet.png").stat().st_size > 1000
    # a key is exactly its drawing
    k = t.names.index("jawOpen")
    key = read_svg_drawing(tmp_path / "face" / "jawOpen.svg")
    np.testing.assert_allclose(t.params(np.eye(t.n_keys)[[k]])[0], key.points, atol=1e-12)
    # 2-D point sets
    pts = tmp_path / "pts"
    pts.mkdir()
    base = np.random.default_rng(3).uniform(0, 100, (12, 2))
    np.save(pts / "neutral.npy", base)
    np.save(pts / "up.npy", base + [0, -5])
    (pts / "right.csv").write_text("x,y\n" + "\n".join(f"{x + 3},{y}" for x, y in base))
    p = read_target(pts)
    np.testing.assert_allclose(p.params(np.array([[0.5, 1.0]])), [base + [1.5, -5]] if p.names == ["right", "up"]
                               else [base + [3, -2.5]])
    p.write(tmp_path / "pts.svg", np.array([[0.0, 0.0], [1.0, 1.0]]), [0.0, 1.0])
    _, b2, _ = read_svg_animation(tmp_path / "pts.svg")
    np.testing.assert_allclose(b2[1][::2], base + [3, -5], atol=1e-6)           # each dot is M x y L x y


# ------------------------------------------------------------------------------------------ bad inputs
def test_bad_targets_name_the_file_and_row(tmp_path):
    (tmp_path / "norange.csv").write_text("key,jawOpen\nframe_00001,0.5\n")
    with pytest.raises(InputFileError, match=r"norange\.csv: no 'range' row"):
        read_target(tmp_path / "norange.csv")
    (tmp_path / "bad.csv").write_text("key,jawOpen,smile\nrange,0:1,0:1\nframe_00001,0.5,x\n")
    with pytest.raises(InputFileError, match=r"bad\.csv: line 3, control 'smile'"):
        read_target(tmp_path / "bad.csv")
    (tmp_path / "t.csv").write_text("key,jawOpen\nrange,0:1\nframe_00001,0.5\nframe_00002,0.7\nfrme_00003,1\n")
    t = read_target(tmp_path / "t.csv")
    with pytest.raises(MissingShapeError, match=r"t\.csv: key 'frme_00003' \(line 5\) matches no source keyshape"):
        t.check_keys(["frame_00001", "frame_00002"])
    with pytest.raises(MissingShapeError, match=r"t\.csv: no key for source keyshape\(s\) frame_00004"):
        t.check_keys(["frame_00001", "frame_00002", "frame_00004"])
    # drawings of another structure
    write_drawn_face(tmp_path / "face", ["jawOpen", "eyeBlinkLeft"])
    svg = (tmp_path / "face" / "eyeBlinkLeft.svg").read_text()
    (tmp_path / "face" / "eyeBlinkLeft.svg").write_text(svg.replace('d="M 105', 'd="M 100 100 L 105', 1))
    with pytest.raises(InvalidDataError, match=r"eyeBlinkLeft\.svg: path 'browRight' differs .* at command 1"):
        read_target(tmp_path / "face")
    # a key frame outside the BVH
    bvh = _arm_bvh(tmp_path / "arm.bvh")
    with pytest.raises(InvalidDataError, match=r"arm\.bvh: key 'far' is frame 9, outside the file's frames 0\.\.3"):
        read_target(bvh, frames={"far": 9})
    with pytest.raises(InvalidDataError, match="--target-frames"):
        read_target(bvh)


# ------------------------------------------------------------------------------------------ command line
def test_retarget_command_writes_control_curves_and_drawings(data_dir, arkit_rig, take, tmp_path):
    perf = tmp_path / "take.csv"
    from faceretarget.io import write_livelinkface

    write_livelinkface(perf, take)
    keys = tmp_path / "src_keys"
    tmpl = tmp_path / "table.csv"
    rig = str(data_dir / "arkit-face")
    assert main(["-q", "keys", "select", "--performance", str(perf), "--source-rig", rig, "--k", "6", "--out",
                 str(keys), "--controls-template", str(tmpl)]) == 0
    lines = tmpl.read_text().splitlines()
    assert lines[0].split(",")[1:] == list(ARKIT_NAMES) and lines[1].startswith("range,0:1")
    # the "artist" fills the template with each key's ARKit weights (key_weights.csv)
    kw = [ln.split(",") for ln in (keys / "key_weights.csv").read_text().splitlines()]
    head = kw[0][1:]
    rows = {r[0][:-4]: dict(zip(head, r[1:], strict=True)) for r in kw[1:]}
    filled = [lines[0], lines[1]]
    from faceretarget.names import normalize_name

    for ln in lines[2:]:
        k = ln.split(",")[0]
        vals = {normalize_name(c): v for c, v in rows[k].items()}
        filled.append(",".join([k] + [vals.get(c, "") for c in ARKIT_NAMES]))
    tmpl.write_text("\n".join(filled) + "\n")
    out = tmp_path / "curves.json"
    assert main(["-q", "retarget", "--performance", str(perf), "--source-rig", rig, "--source-keys", str(keys),
                 "--target-keys", str(tmpl), "--out", str(out)]) == 0
    doc = json.loads(out.read_text())
    from faceretarget.io import read_keys

    sk, _ = read_keys(keys, rig=arkit_rig)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        job = retarget_take(take, sk, read_target(tmpl), source_rig=arkit_rig)
    C = read_target(tmpl).params(target_weights(job))
    got = np.array([doc["controls"][c] for c in ARKIT_NAMES]).T
    np.testing.assert_allclose(got, C, atol=1e-9)
    # a drawing target through the command line (its keys named like the source keys)
    face = tmp_path / "face"
    write_drawn_face(face, ["jawOpen", "eyeBlinkLeft", "mouthSmileLeft", "browInnerUp", "eyeBlinkRight", "mouthPucker"])
    for src, dst in zip(sorted(p.stem for p in face.glob("*.svg") if p.stem != "neutral"),
                        sorted(p.stem for p in keys.glob("frame_*.obj")), strict=True):
        (face / f"{src}.svg").rename(face / f"{dst}.svg")
    svg = tmp_path / "face.svg"
    assert main(["-q", "retarget", "--performance", str(perf), "--source-rig", rig, "--source-keys", str(keys),
                 "--target-keys", str(face), "--out", str(svg)]) == 0
    _, pts, _ = read_svg_animation(svg)
    assert pts.shape == (take.n_frames, 92, 2)
    # a bad output format for a drawing is refused before any work, nothing written
    assert main(["-q", "retarget", "--performance", str(perf), "--source-rig", rig, "--source-keys", str(keys),
                 "--target-keys", str(face), "--out", str(tmp_path / "x.bvh")]) == 2
    assert not (tmp_path / "x.bvh").exists()


def test_mesh_targets_are_one_kind_of_target(arkit_rig):
    from faceretarget.targets import MeshTarget, as_target

    t = as_target(arkit_rig)
    assert isinstance(t, MeshTarget) and t.solve_keys is arkit_rig and t.names == arkit_rig.names
    W = np.zeros((2, arkit_rig.n_shapes))
    W[1, 3] = 1
    np.testing.assert_allclose(t.params(W)[1], arkit_rig.neutral.vertices + arkit_rig.deltas[3])
    pts = Rig(Mesh(np.zeros((3, 3))), ["a"], np.ones((1, 3, 3)), "mm")
    with pytest.raises(MissingShapeError):
        as_target(pts).check_keys(["b"])
    with pytest.raises(InvalidDataError):
        ControlTarget(ControlTable(["a"], ["x"], [[1.0]], [0.0], [1.0], [0.0]), ranges="wrap")


def test_an_unfilled_control_table_is_an_error_and_rest_keys_a_warning():
    from faceretarget.errors import DataWarning, InvalidDataError

    blank = ControlTable(["a", "b"], ["x", "y"], np.zeros((2, 2)), [0.0, 0.0], [1.0, 1.0], [0.0, 0.0], "t.csv")
    with pytest.raises(InvalidDataError, match="t.csv: no key is posed"):
        ControlTarget(blank)
    half = ControlTable(["a", "b"], ["x", "y"], [[0.5, 0.0], [0.0, 0.0]], [0.0, 0.0], [1.0, 1.0], [0.0, 0.0], "t.csv")
    with pytest.warns(DataWarning, match="1 of 2 key.* left at rest \\(b\\)"):
        t = ControlTarget(half)
    assert np.allclose(t.params(np.array([[1.0, 1.0]])), [[0.5, 0.0]])


def test_a_whole_arkit_rig_drives_a_drawing_of_some_of_its_shapes(arkit_rig, take, tmp_path):
    from faceretarget.targets import read_target

    face = tmp_path / "face"
    names = ["jawOpen", "eyeBlinkLeft", "mouthSmileLeft"]
    write_drawn_face(face, names)
    lines = []
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        job = retarget_take(take.slice(0, 120), arkit_rig, read_target(face), source_rig=arkit_rig, log=lines.append)
        # the same solve with the three shapes given explicitly
        ref = retarget_take(take.slice(0, 120), arkit_rig.subset(names), read_target(face), source_rig=arkit_rig)
    assert any(f"the 3 of {arkit_rig.n_shapes} shapes" in ln for ln in lines)
    np.testing.assert_allclose(target_weights(job), target_weights(ref), atol=1e-12)
    # source keyshapes that are not a rig's ARKit shapes must all be posed: a missing key is an error
    odd = Rig(arkit_rig.neutral, ["frame_1", "frame_2", "jawOpen"], arkit_rig.deltas[:3], arkit_rig.unit)
    with pytest.raises(MissingShapeError, match="no key for source keyshape"):
        retarget_take(take.slice(0, 10), odd, read_target(face), source_rig=arkit_rig)
