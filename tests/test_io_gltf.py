"""glTF binary export: round trips, seam splitting, units, and the Khronos validator (0 errors)."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import time
import warnings
from pathlib import Path

import numpy as np
import pytest

from faceretarget.errors import InvalidDataError, OutputError
from faceretarget.io import (
    glb_vertex_order,
    read_glb_rig,
    read_glb_weights,
    read_livelinkface,
    write_animation,
    write_glb,
)
from faceretarget.mesh import Mesh
from faceretarget.rig import Rig

REPO = Path(__file__).resolve().parents[1]
SCRIPT = REPO / "tests" / "tools" / "validate_gltf.mjs"
VALIDATOR = Path(os.environ.get("GLTF_VALIDATOR_DIR", REPO / ".tools" / "node_modules" / "gltf-validator"))


def _require() -> bool:
    return os.environ.get("FACERETARGET_REQUIRE_DATA", "") not in ("", "0")


def validate(path: Path) -> dict:
    """Run the Khronos glTF validator on ``path``; fail on any error, print warnings."""
    node = shutil.which("node")
    reason = None
    if node is None:
        reason = "node not found: cannot run the Khronos glTF validator"
    elif not (VALIDATOR / "package.json").is_file():
        reason = f"gltf-validator not installed at {VALIDATOR} (run `make tools`)"
    if reason:
        if _require():
            pytest.fail(reason)
        pytest.skip(reason)
    r = subprocess.run([node, str(SCRIPT), str(path), str(VALIDATOR)], capture_output=True,
                       text=True, timeout=300)
    assert r.returncode in (0, 1), f"validator could not run: {r.stderr}"
    report = json.loads(r.stdout)
    issues = report["issues"]
    for m in issues["messages"]:
        sev = {0: "ERROR", 1: "WARNING", 2: "INFO", 3: "HINT"}[m["severity"]]
        print(f"gltf-validator {sev} {m['code']} {m.get('pointer', '')}: {m['message']}")
    errors = [m for m in issues["messages"] if m["severity"] == 0]
    assert issues["numErrors"] == 0, errors
    return report


def _seam_rig(unit: str = "cm") -> Rig:
    """Two quads sharing an edge, each with its own UV island: the shared vertices have 2 UVs."""
    v = np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0], [0, 1, 0], [1, 1, 0], [2, 1, 0.2]], float) * 10
    uvs = np.array([[0, 0], [0.5, 0], [0.5, 1], [0, 1], [0.6, 0], [1, 0], [1, 1], [0.6, 1]])
    m = Mesh(v, [4, 4], [0, 1, 4, 3, 1, 2, 5, 4], uvs, [0, 1, 2, 3, 4, 5, 6, 7], name="seam")
    rng = np.random.default_rng(3)
    return Rig(m, ["jawOpen", "eyeBlink_L", "mouthSmile_R"], rng.normal(size=(3, 6, 3)), unit=unit,
               name="seam")


def test_round_trip_synthetic(tmp_path):
    rig = _seam_rig()
    T = 40
    times = 5.0 + np.arange(T) / 30.0
    w = np.random.default_rng(4).random((T, 3))
    out = write_glb(tmp_path / "s.glb", rig, w, times, node_name="head")
    names, t, back = read_glb_weights(out)
    assert names == rig.names
    np.testing.assert_array_equal(t, (times - times[0]).astype(np.float32))
    np.testing.assert_array_equal(back, w.astype(np.float32))
    src = glb_vertex_order(rig.neutral)
    np.testing.assert_array_equal(src, [0, 1, 1, 2, 3, 4, 4, 5])  # vertices 1 and 4 are on the seam
    g = read_glb_rig(out)
    assert g.n_vertices == 8 and g.names == rig.names and g.unit == "m"
    np.testing.assert_allclose(g.neutral.vertices, rig.neutral.vertices[src] / 100, atol=1e-6)
    np.testing.assert_allclose(g.deltas, rig.deltas[:, src] / 100, atol=1e-6)  # cm -> m
    # each glTF vertex carries the UV its corners used
    corner_uv = {}
    for c, (vi, ui) in enumerate(zip(g.neutral.face_indices, g.neutral.face_uv_indices, strict=True)):
        corner_uv.setdefault(int(vi), set()).add(tuple(g.neutral.uvs[ui]))
        assert c >= 0
    assert all(len(s) == 1 for s in corner_uv.values())
    validate(out)


def test_named_weights_are_mapped_with_one_warning(tmp_path):
    rig = _seam_rig(unit="m")
    w = np.array([[0.1, 0.2, 0.3, 0.4], [0.5, 0.6, 0.7, 0.8]])
    with pytest.warns(UserWarning, match="tongueOut") as ws:
        out = write_glb(tmp_path / "n.glb", rig, w, [0, 0.1],
                        names=["MouthSmileRight", "JawOpen", "tongueOut", "EyeBlinkLeft"])
    assert len(ws) == 1
    _, _, back = read_glb_weights(out)
    np.testing.assert_allclose(back, [[0.2, 0.4, 0.1], [0.6, 0.8, 0.5]], atol=1e-7)
    g = read_glb_rig(out)
    np.testing.assert_allclose(g.deltas, rig.deltas[:, glb_vertex_order(rig.neutral)], atol=1e-6)


def test_bad_inputs(tmp_path):
    rig = _seam_rig()
    with pytest.raises(InvalidDataError, match=r"shape \(3, 3\) for 3 times and 3 shapes, got \(3, 2\)"):
        write_glb(tmp_path / "a.glb", rig, np.zeros((3, 2)), [0, 1, 2])
    with pytest.raises(InvalidDataError, match="frame 2 time"):
        write_glb(tmp_path / "a.glb", rig, np.zeros((3, 3)), [0, 1, 1])
    w = np.zeros((3, 3))
    w[1, 2] = np.nan
    with pytest.raises(InvalidDataError, match="frame 1 weight 'mouthSmileRight' is nan"):
        write_glb(tmp_path / "a.glb", rig, w, [0, 1, 2])
    assert not list(tmp_path.iterdir())


def test_unwritable_output_leaves_nothing(tmp_path):
    rig = _seam_rig()
    with pytest.raises(OutputError, match=r"no_such_folder"):
        write_glb(tmp_path / "no_such_folder" / "x.glb", rig, np.zeros((2, 3)), [0, 1])
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o500)
    try:
        target = ro
        if os.access(ro, os.W_OK):  # root ignores permissions; sysfs refuses new files even to root
            if not Path("/sys/kernel").is_dir():
                pytest.skip("running as root without /sys: no read-only folder to try")
            target = Path("/sys")
        with pytest.raises(OutputError, match=rf"{target}.*(not writable|cannot write)"):
            write_animation(target / "x.glb", rig=rig, weights=np.zeros((2, 3)), times=[0, 1])
        assert not list(ro.iterdir())
    finally:
        ro.chmod(0o700)


def test_arkit_rig_with_real_take_validates(arkit_rig, data_dir, tmp_path):
    perf = read_livelinkface(data_dir / "livelinkface" / "S07-001.csv")
    with pytest.warns(UserWarning, match="tongueOut"):  # the ARKit test rig has no tongueOut shape
        out = write_glb(tmp_path / "arkit.glb", arkit_rig, perf.weights, perf.times, names=perf.names)
    names, t, w = read_glb_weights(out)
    assert names == arkit_rig.names and w.shape == (2028, 51)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        expect = arkit_rig.map_weights(perf.names, perf.weights)
    np.testing.assert_array_equal(w, expect.astype(np.float32))
    assert t[-1] == pytest.approx(perf.duration, abs=1e-5)
    g = read_glb_rig(out)
    src = glb_vertex_order(arkit_rig.neutral)
    np.testing.assert_allclose(g.deltas, arkit_rig.deltas[:, src], atol=1e-6)  # already metres
    report = validate(out)
    assert report["info"]["animationCount"] == 1 and report["info"]["maxAttributes"] >= 2


def test_ict_rig_2000_frames(ict_rig, data_dir, tmp_path):
    perf = read_livelinkface(data_dir / "livelinkface" / "alex_rom_3.csv").slice(0, 2000)
    t0 = time.perf_counter()
    with pytest.warns(UserWarning, match="tongueOut"):
        out = write_glb(tmp_path / "ict.glb", ict_rig, perf.weights, perf.times, names=perf.names)
    dt = time.perf_counter() - t0
    print(f"write_glb ICT rig (9409 verts, 57 targets), 2000 frames: {dt:.2f} s, "
          f"{out.stat().st_size / 1e6:.1f} MB")
    assert dt < 20.0
    g = read_glb_rig(out)
    src = glb_vertex_order(ict_rig.neutral)
    assert g.n_vertices == len(src) >= 9409 and g.n_shapes == 57
    np.testing.assert_allclose(g.deltas, ict_rig.deltas[:, src] / 100.0, atol=1e-6)  # cm -> m
    diag = np.linalg.norm(g.neutral.vertices.max(0) - g.neutral.vertices.min(0))
    assert 0.15 < diag < 0.6  # a human face in metres
    validate(out)


def test_point_set_keys_write_a_valid_points_primitive(tmp_path):
    """Keyshapes exported from markers are point sets (no faces): the .glb holds a POINTS primitive
    (mode 0, no indices) with the morph targets, the Khronos validator accepts it, and it reads back."""
    rng = np.random.default_rng(5)
    pts = Mesh(rng.normal(size=(12, 3)) * 30.0, name="markers")
    rig = Rig(pts, ["frame_00010", "frame_00042"], rng.normal(size=(2, 12, 3)), unit="mm", name="markers")
    w = rng.random((25, 2))
    out = write_glb(tmp_path / "points.glb", rig, w, np.arange(25) / 60.0)
    report = validate(out)
    assert report["issues"]["numErrors"] == 0
    g = read_glb_rig(out)
    assert g.neutral.n_faces == 0 and g.names == rig.names
    np.testing.assert_allclose(g.neutral.vertices, rig.neutral.vertices / 1000, atol=1e-6)
    np.testing.assert_allclose(g.deltas, rig.deltas / 1000, atol=1e-6)
    names, _, back = read_glb_weights(out)
    np.testing.assert_array_equal(back, w.astype(np.float32))


def test_readme_marker_keys_command_writes_a_valid_glb(data_dir, tmp_path):
    """The README's marker route (issue 14): keys select on Jaw.c3d, the same point sets as the
    'artist's' target keys, retarget Cheeks.c3d to .glb: the validator accepts the file."""
    import shutil as sh

    from faceretarget.cli import main

    jaw, cheeks = data_dir / "facial-mocap" / "Jaw.c3d", data_dir / "facial-mocap" / "Cheeks.c3d"
    keys = tmp_path / "jaw_keys"
    assert main(["-q", "keys", "select", "--performance", str(jaw), "--k", "8", "--out", str(keys)]) == 0
    target = tmp_path / "target_keys"
    sh.copytree(keys, target)
    out = tmp_path / "t.glb"
    assert main(["-q", "retarget", "--performance", str(cheeks), "--source-keys", str(keys),
                 "--target-keys", str(target), "--out", str(out)]) == 0
    validate(out)
    assert read_glb_rig(out).neutral.n_faces == 0


@pytest.mark.parametrize("ext", [".glb", ".npz", ".csv", ".usda"])
def test_no_writer_accepts_non_finite_values(ext, tmp_path):
    """issue 14: output sanity at the writer, one place for every format."""
    from faceretarget.errors import InvalidDataError
    from faceretarget.io import write_animation

    rig = _seam_rig()
    w = np.random.default_rng(1).random((10, 3))
    w[4, 1] = np.nan
    out = tmp_path / f"x{ext}"
    with pytest.raises(InvalidDataError, match=r"weights hold a non-finite value at frame 4 \('eyeBlinkLeft'\)"):
        write_animation(out, rig=rig, weights=w, times=np.arange(10) / 30.0)
    assert not out.exists()
    with pytest.raises(InvalidDataError, match="times must be finite"):
        write_animation(out, rig=rig, weights=np.zeros((10, 3)), times=np.r_[np.arange(9) / 30.0, np.inf])
    assert not out.exists()
