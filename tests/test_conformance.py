"""Readers against the established readers (issue 23): every shared conformance file and every variant of the
C3D and BVH formats we can write, read by ours and by ezc3d / py-c3d (C3D), the bvh package / bvhio (BVH)
and pygltflib (glTF), each reference in a child process under a timeout (bench/conformance.py).

A test fails on any difference it does not name: the references' known faults are listed per file in
``KNOWN`` with the bench's :data:`EXPLANATIONS` entry that accounts for them (checked on the file itself).
"""

from __future__ import annotations

import importlib.util
import json
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest

from faceretarget.errors import FaceRetargetError, InputFileError
from faceretarget.io import bvh_world_positions, read_bvh, read_bvh_head, read_c3d

REPO = Path(__file__).resolve().parents[1]
_spec = importlib.util.spec_from_file_location("faceretarget_bench_conformance", REPO / "bench" / "conformance.py")
bench = importlib.util.module_from_spec(_spec)
sys.modules[_spec.name] = bench
_spec.loader.exec_module(bench)
sys.path.insert(0, str(Path(__file__).resolve().parent))
from _c3d_files import DEC, MIPS, C3dSpec, make_c3d, smooth_take  # noqa: E402 - tests/_c3d_files.py

TIMEOUT = 120.0

#: What each reference does on the shared files besides agreeing: ``{file: {reference: explanation key, or
#: "fails: <text of its error>"}}``.  Anything else is a failure of the test.
KNOWN = {
    # a BTS file without POINT:RATE / ANALOG:RATE: ezc3d reads frames without the header's 6 analog samples
    "sample_28_standing.C3D": {"ezc3d": "ezc3d_frame_size"},
    # residual words written as two 16-bit integers in a float file: py-c3d's int32 cast marks them invalid
    "sample_30_admarche2.c3d": {"py-c3d": "pyc3d_residual_cast"},
    "sample_13_golfswing.c3d": {"ezc3d": "fails: OFFSET parameter is not an INT"},
    "sample_02_sgi_int.c3d": {"ezc3d": "fails: MIPS processor type not supported"},
    # the bvh package drops the last frame of a file without a final line ending
    "pybvh_bvh_test3.bvh": {"bvh": "bvh_last_row"},
}
#: Warnings a complete shared file may give (each true of the file); any other warning fails.
ALLOWED_WARNINGS = ("marker(s) missing in every frame", "repeated marker label", "no marker is present in any frame")
#: The one cut file of the shared set: its header declares 1149 frames, it holds 29.
CUT = {"ezc3d_Optotrak.c3d": "holds 29 frame(s) but its header declares 1149"}


def _files(data_dir: Path, sub: str) -> list[Path]:
    return sorted(p for p in (data_dir / "conformance" / sub).iterdir() if p.is_file())


def _check(fmt: str, path: Path, d: dict | None = None) -> dict:
    d = d or bench.check_file(fmt, path, timeout=TIMEOUT)
    known = KNOWN.get(path.name, {})
    assert d["outcome"] == "agree", f"{path.name}: {d['outcome']}: {d['reason']}"
    assert d["agree_with"], d
    assert not d["unexplained"], d
    for ref, why in d["explained"].items():
        assert known.get(ref) == why, f"{path.name}: {ref} differs for a reason the test does not name: {why}"
    for ref, msg in d["failed"].items():
        want = known.get(ref, "")
        assert want.startswith("fails: ") and want[7:] in msg, f"{path.name}: {ref} failed unexpectedly: {msg}"
    for ref, want in known.items():                  # a named fault that no longer happens is news too
        assert ref in d["explained"] or ref in d["failed"], f"{path.name}: {ref} now agrees ({want} obsolete)"
    return d


# ------------------------------------------------------------------------------------------- shared files
def pytest_generate_tests(metafunc):
    if "shared_c3d" in metafunc.fixturenames or "shared_bvh" in metafunc.fixturenames:
        root = REPO.parent / "shared" / "data" / "conformance"
        for name, sub in (("shared_c3d", "c3d"), ("shared_bvh", "bvh")):
            if name in metafunc.fixturenames:
                files = sorted(p.name for p in (root / sub).iterdir()) if (root / sub).is_dir() else ["(none)"]
                metafunc.parametrize(name, files)


@pytest.fixture(scope="module")
def shared(data_dir) -> dict[str, dict]:
    """Every shared conformance file checked (each reader once over a format's files)."""
    out = {}
    for fmt in ("c3d", "bvh"):
        files = _files(data_dir, fmt)
        out.update({p.name: d for p, d in zip(files, bench.check_files(fmt, files, TIMEOUT), strict=True)})
    return out


def test_shared_c3d_agree_with_references(data_dir, shared, shared_c3d):
    path = data_dir / "conformance" / "c3d" / shared_c3d
    d = _check("c3d", path, shared[shared_c3d])
    for w in d["warnings"]:                                      # no misleading warning on a complete file
        assert any(a in w for a in ALLOWED_WARNINGS) or CUT.get(path.name, "\0") in w, w
    if path.name in CUT:
        assert any(CUT[path.name] in w for w in d["warnings"])


def test_shared_bvh_agree_with_references(data_dir, shared, shared_bvh):
    d = _check("bvh", data_dir / "conformance" / "bvh" / shared_bvh, shared[shared_bvh])
    assert d["warnings"] == []
    assert "bvhio" in d["agree_with"]                                     # forward kinematics within 1e-4 of the size


def test_sgi_dec_and_intel_samples_hold_the_same_take(data_dir):
    """c3d.org's sample_02: one take as DEC integers, SGI/MIPS integers and Intel floats."""
    c = data_dir / "conformance" / "c3d"
    dec, sgi, pc = (read_c3d(c / f"sample_02_{k}.c3d", zero_is_missing=False) for k in ("dec_int", "sgi_int", "pc_real"))
    np.testing.assert_array_equal(np.isnan(sgi.points), np.isnan(dec.points))
    step = 0.28118187                                                   # POINT:SCALE of the integer files
    assert np.nanmax(np.abs(sgi.points - dec.points)) <= step * 1.000001  # at most one integer step apart
    assert np.nanmedian(np.abs(sgi.points - dec.points)) == 0.0
    assert sgi.labels == dec.labels == pc.labels and sgi.fps == dec.fps == 50.0
    fin = np.isfinite(pc.points)
    np.testing.assert_array_equal(np.isfinite(dec.points), fin)
    assert np.abs(pc.points[fin] - dec.points[fin]).max() < 0.5 * 0.2812   # within half a quantisation step


def test_bandai_six_channel_bones_keep_their_length(data_dir):
    """Every joint has 6 channels holding the full local translation: bone lengths are the offsets' (they
    were twice that when position channels were added to the offsets), and the head stays on the neck."""
    b = read_bvh(data_dir / "conformance" / "bvh" / "bandai1_bow_active_001.bvh")
    W = bvh_world_positions(b)
    par = np.array([j.parent for j in b.joints])
    kids = np.flatnonzero(par >= 1)             # every joint below the hips (the root and hips carry the motion)
    for i in kids:                              # whose position channels hold the offset itself (to 1e-5 cm)
        assert np.abs(b.local_translations(i) - b.joints[i].offset).max() < 1e-5
    lengths = np.linalg.norm(W[:, kids] - W[:, par[kids]], axis=2)
    offsets = np.array([np.linalg.norm(b.joints[i].offset) for i in kids])
    assert np.abs(lengths - offsets).max() < 1e-5
    head = read_bvh_head(b).head
    assert np.abs(head.translation).max() < 0.02                       # metres; was a constant 0.22 m


def test_mixamo_head_found_by_role(data_dir):
    take = read_bvh_head(data_dir / "conformance" / "bvh" / "bvhpy_test_freebvh.bvh")
    assert take.head.n_frames == 69 and take.head.valid.all()
    b = read_bvh(data_dir / "conformance" / "bvh" / "bvhpy_test_freebvh.bvh")
    explicit = read_bvh_head(b, joints=("mixamorig:Neck", "mixamorig:Head")).head
    np.testing.assert_allclose(take.head.as_quat(), explicit.as_quat(), atol=1e-12)


# ------------------------------------------------------------------------------------------- C3D variants
LABELS = [f"m{i}" for i in range(12)]


def _variants() -> dict[str, C3dSpec]:
    pts = smooth_take()
    return {
        "intel-float": C3dSpec(pts, LABELS),
        "intel-int": C3dSpec(pts, LABELS, floats=False),
        "dec-float": C3dSpec(pts, LABELS, processor=DEC, analog_channels=2, analog_per_frame=2),
        "dec-int": C3dSpec(pts, LABELS, processor=DEC, floats=False, analog_channels=2, analog_per_frame=2),
        "mips-float": C3dSpec(pts, LABELS, processor=MIPS),
        "mips-int": C3dSpec(pts, LABELS, processor=MIPS, floats=False),
        "mips-analog": C3dSpec(pts, LABELS, processor=MIPS, floats=False, analog_channels=3, analog_per_frame=4),
        "analog-float": C3dSpec(pts, LABELS, analog_channels=3, analog_per_frame=4),
        "analog-int": C3dSpec(pts, LABELS, floats=False, analog_channels=5, analog_per_frame=10),
        "events": C3dSpec(pts, LABELS, events=[("HS", 0.2), ("TO", 0.5)]),
        "first-frame-41": C3dSpec(pts, LABELS, first_frame=41),
        "frames-float": C3dSpec(pts, LABELS, point_frames="float"),
        "no-frames": C3dSpec(pts, LABELS, point_frames=None),
        "extra-zero-blocks": C3dSpec(pts, LABELS, extra_blocks=3),
        # disagreements: the data decide
        "no-analog-rate": C3dSpec(pts, LABELS, analog_channels=3, analog_per_frame=4, analog_rate=False),
        "no-rates": C3dSpec(pts, LABELS, analog_channels=2, analog_per_frame=3, analog_rate=False,
                            point_rate=False),
        "header-scale-sign": C3dSpec(pts, LABELS, header_scale_sign=1),
        "header-11-points": C3dSpec(pts[:, :11], LABELS[:11]),          # POINT:USED patched to 12 below
        "no-parameters": C3dSpec(pts, LABELS, parameters=False),
    }


#: Warnings each variant must give (substrings), none for the others.
VARIANT_WARNINGS = {
    "header-11-points": "the header's 11 points per frame (POINT:USED 12)",
    "no-parameters": "no parameter section",
}
#: The references' faults on the variants (as in KNOWN; "wrong" = reads values that are not the take's).
VARIANT_KNOWN = {
    "dec-float": {}, "dec-int": {},
    "mips-float": {"ezc3d": "fails"}, "mips-int": {"ezc3d": "fails"}, "mips-analog": {"ezc3d": "fails"},
    "frames-float": {"ezc3d": "fails"},
    "no-analog-rate": {"ezc3d": "ezc3d_frame_size"},
    "no-rates": {"ezc3d": "ezc3d_frame_size"},
    "header-scale-sign": {"py-c3d": "fails"},
    "header-11-points": {"ezc3d": "ezc3d_frame_size", "py-c3d": "fails"},
    "no-parameters": {"ezc3d": "fails", "py-c3d": "fails"},
}


def _write_variant(tmp_path: Path, name: str, spec: C3dSpec) -> Path:
    raw = make_c3d(spec)
    if name == "header-11-points":                      # POINT:USED 12 while the header and the data hold 11
        i = raw.index(b"USED", 512)
        raw = raw[:i + 8] + (12).to_bytes(2, "little") + raw[i + 10:]
    path = tmp_path / f"{name}.c3d"
    path.write_bytes(raw)
    return path


@pytest.fixture(scope="module")
def variants(tmp_path_factory) -> dict[str, tuple[Path, dict]]:
    """Every C3D variant written and checked against the references."""
    folder = tmp_path_factory.mktemp("c3d-variants")
    paths = [_write_variant(folder, n, spec) for n, spec in sorted(_variants().items())]
    return {p.stem: (p, d) for p, d in zip(paths, bench.check_files("c3d", paths, TIMEOUT), strict=True)}


@pytest.mark.parametrize("name", sorted(_variants()))
def test_c3d_variant(variants, name):
    spec = _variants()[name]
    path, d = variants[name]
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        perf = read_c3d(path, zero_is_missing=False)
    msgs = [str(w.message) for w in caught]
    want = VARIANT_WARNINGS.get(name)
    assert [m for m in msgs if want is None or want not in m] == [], msgs
    if want:
        assert any(want in m for m in msgs), msgs
    # ours against the take written: NaN where invalid, values to float32 or to half the integer scale
    truth = spec.points
    np.testing.assert_array_equal(np.isnan(perf.points), np.isnan(truth))
    fin = np.isfinite(truth)
    tol = 1e-4 if spec.floats else 0.5 * spec.scale + 1e-4          # the scale is a float32
    assert np.abs(perf.points[fin] - truth[fin]).max() <= tol
    assert perf.labels == (spec.labels if spec.parameters else [f"M{i + 1:03d}" for i in range(truth.shape[1])])
    assert perf.fps == pytest.approx(spec.rate, rel=1e-7)
    assert round(perf.times[0] * perf.fps) == spec.first_frame - 1
    # and against the references: agree with at least one, every other one's fault named
    known = VARIANT_KNOWN.get(name, {})
    for ref, msg in d.get("failed", {}).items():
        assert known.get(ref) == "fails", f"{ref} failed: {msg}"
    for ref, why in d.get("explained", {}).items():
        assert known.get(ref) == why, f"{ref}: {why}"
    assert not d.get("unexplained"), d
    if {"ezc3d", "py-c3d"} - set(known):
        assert d["outcome"] == "agree", d["reason"]
    else:                        # no reference reads it right: the take written (checked above) decides
        assert d["outcome"] == "differ" and not d["agree_with"]


@pytest.mark.parametrize("how", ["trial", "long-frames", "float", "at-65535"])
def test_c3d_more_than_65535_frames(tmp_path, how):
    """70,001 frames: the count from TRIAL fields, POINT:LONG_FRAMES, a float POINT:FRAMES, or (POINT:FRAMES at
    its 65535 limit and nothing else) from the data without the zero padding of the last block."""
    T = 70001
    rng = np.random.default_rng(1)
    pts = np.cumsum(rng.normal(size=(T, 2, 3)), axis=0) + [0.0, 1000.0, 0.0]
    kw = {"trial": dict(trial_fields=True, point_frames=65535), "long-frames": dict(long_frames=True, point_frames=65535),
          "float": dict(point_frames="float"), "at-65535": dict(point_frames=65535)}[how]
    path = tmp_path / f"{how}.c3d"
    path.write_bytes(make_c3d(C3dSpec(pts, ["a", "b"], **kw)))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        perf = read_c3d(path, zero_is_missing=False)
    assert perf.n_frames == T
    assert np.abs(perf.points - pts).max() < 1e-3
    ez = bench.run("ezc3d", path, TIMEOUT)
    if ez.status == "ok":                                 # ezc3d reads the padding as 15 more frames
        assert len(ez.data["points"]) == T + 15
        assert bench.explain_c3d(path, {"points": perf.points}, ez.data, "ezc3d") == "ezc3d_padding"


def test_c3d_truncated_and_padded_counts(tmp_path):
    """A file cut inside its data warns (naming the counts); a whole extra block of zeros does not."""
    raw = make_c3d(C3dSpec(smooth_take(), LABELS))
    cut = tmp_path / "cut.c3d"
    cut.write_bytes(raw[:len(raw) - 3000])
    with pytest.warns(UserWarning, match=r"holds \d+ frame\(s\) but its header declares 120"):
        assert read_c3d(cut).n_frames < 120
    odd = tmp_path / "odd.c3d"                         # not a whole number of blocks, every frame there
    data_end = 1024 + 120 * 12 * 16
    odd.write_bytes(raw[:data_end + 100])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert read_c3d(odd).n_frames == 120


def test_c3d_processor_type_unknown(tmp_path):
    raw = bytearray(make_c3d(C3dSpec(smooth_take(), LABELS)))
    raw[512 + 3] = 90
    (tmp_path / "p.c3d").write_bytes(bytes(raw))
    with pytest.raises(InputFileError, match="p.c3d: cannot read as a C3D file .processor type 90"):
        read_c3d(tmp_path / "p.c3d")


# ------------------------------------------------------------------------------------------- BVH variants
def _bvh_text(orders, six: bool, root_offset, *, eol="\n", indent="\t", comments=False, names=None,
              frames: int = 12) -> tuple[str, np.ndarray]:
    """A 4-joint chain (root, spine, neck, head) with the given rotation channel orders; returns the text and
    the motion written."""
    names = names or ["Hips", "Spine", "Neck", "Head"]
    offsets = [root_offset, (0.0, 10.0, -1.0), (0.5, 12.0, 2.0), (0.0, 8.0, 1.5)]
    rng = np.random.default_rng(3)
    lines, cols = ["HIERARCHY"], []
    if comments:
        lines.append("# written by a test")
    for i, (n, off, order) in enumerate(zip(names, offsets, orders, strict=True)):
        pad = indent * i
        lines += [f"{pad}{'ROOT' if i == 0 else 'JOINT'} {n}", f"{pad}{{",
                  f"{pad}{indent}OFFSET {off[0]:.4f} {off[1]:.4f} {off[2]:.4f}"]
        pos = i == 0 or six
        ch = (["Xposition", "Yposition", "Zposition"] if pos else []) + [f"{a}rotation" for a in order]
        lines.append(f"{pad}{indent}CHANNELS {len(ch)} {' '.join(ch)}")
        if pos:     # full local translation: the offset moved a little (the root wanders)
            cols.append(np.asarray(off) + rng.normal(0, 0.5 if i == 0 else 0.05, (frames, 3)))
        cols.append(rng.uniform(-40, 40, (frames, 3)))
    lines += [indent * 4 + "End Site", indent * 4 + "{", indent * 5 + "OFFSET 0.0 5.0 0.0", indent * 4 + "}"]
    lines += [indent * i + "}" for i in range(3, -1, -1)]
    motion = np.round(np.concatenate(cols, axis=1), 4)
    lines += ["MOTION", f"Frames: {frames}", "Frame Time: 0.0333333"]
    if comments:
        lines.append("// frame rows follow")
    lines += [" ".join(f"{v:.4f}" for v in row) for row in motion]
    return eol.join(lines) + eol, motion


BVH_VARIANTS = {
    "zxy-3": dict(orders=["ZXY"] * 4, six=False, root_offset=(0, 0, 0)),
    "xyz-yzx-zyx-yxz": dict(orders=["XYZ", "YZX", "ZYX", "YXZ"], six=False, root_offset=(0, 0, 0)),
    "six-channels-every-joint": dict(orders=["ZXY", "ZXY", "ZXY", "ZXY"], six=True, root_offset=(0, 0, 0)),
    "root-offset": dict(orders=["ZYX", "XZY", "ZXY", "YZX"], six=False, root_offset=(3.0, 90.0, -2.0)),
    "crlf-spaces": dict(orders=["ZXY"] * 4, six=False, root_offset=(0, 85.0, 0), eol="\r\n", indent="  "),
    "namespaced": dict(orders=["ZXY"] * 4, six=False, root_offset=(0, 0, 0),
                       names=["mixamorig:Hips", "mixamorig:Spine", "mixamorig:Neck", "mixamorig:Head"]),
}


@pytest.mark.parametrize("name", sorted(BVH_VARIANTS))
def test_bvh_variant(tmp_path, name):
    kw = dict(BVH_VARIANTS[name])
    text, motion = _bvh_text(**kw)
    path = tmp_path / f"{name}.bvh"
    path.write_bytes(text.encode())
    b = read_bvh(path)
    np.testing.assert_array_equal(b.motion, motion)
    d = _check("bvh", path)                         # channel values equal the bvh package's, FK bvhio's
    assert set(d["agree_with"]) == {"bvh", "bvhio"}
    head = read_bvh_head(b)                         # found by role, namespaced or not
    assert head.head.n_frames == 12


def test_bvh_comment_lines_are_skipped(tmp_path):
    """Whole-line '#' and '//' comments (no reference reads them: bvhio and the bvh package refuse the file)."""
    text, motion = _bvh_text(["ZXY"] * 4, False, (0, 0, 0), comments=True)
    plain, _ = _bvh_text(["ZXY"] * 4, False, (0, 0, 0))
    (tmp_path / "c.bvh").write_text(text)
    (tmp_path / "p.bvh").write_text(plain)
    b, p = read_bvh(tmp_path / "c.bvh"), read_bvh(tmp_path / "p.bvh")
    np.testing.assert_array_equal(b.motion, motion)
    np.testing.assert_array_equal(bvh_world_positions(b), bvh_world_positions(p))


def test_bvh_names_with_spaces_and_bad_names(tmp_path):
    """3ds Max Biped names ('Bip01 Head') are one name, and the head is found by role."""
    text, _ = _bvh_text(["ZXY"] * 4, False, (0, 0, 0), names=["Bip01", "Bip01 Spine", "Bip01 Neck", "Bip01 Head"])
    (tmp_path / "biped.bvh").write_text(text)
    b = read_bvh(tmp_path / "biped.bvh")
    assert b.names == ["Bip01", "Bip01 Spine", "Bip01 Neck", "Bip01 Head"]
    assert read_bvh_head(b).head.n_frames == 12
    text2 = text.replace("Bip01 Head", "Bip01 Tail")
    (tmp_path / "nohead.bvh").write_text(text2)
    with pytest.raises(FaceRetargetError, match=r"nohead.bvh: no head joint found .*Bip01 Tail"):
        read_bvh_head(tmp_path / "nohead.bvh")


def test_glb_skin_head_found_by_role(tmp_path):
    """A character's skin animation (namespaced joints) gives the same head motion as the same pose in a BVH."""
    from faceretarget.io import bvh_pose, read_head_motion, write_glb_skeleton

    text, _ = _bvh_text(["ZXY", "XYZ", "YZX", "ZYX"], False, (0, 90.0, 0),
                        names=["mixamorig:Hips", "mixamorig:Spine", "mixamorig:Neck", "mixamorig:Head"])
    (tmp_path / "t.bvh").write_text(text)
    b = read_bvh(tmp_path / "t.bvh")
    q, pos = bvh_pose(b)
    off = np.array([j.offset for j in b.joints])
    write_glb_skeleton(tmp_path / "t.glb", b.names, [j.parent for j in b.joints], off, q, pos,
                       np.arange(b.n_frames) / 30.0)
    g = read_head_motion(tmp_path / "t.glb").head
    h = read_bvh_head(b).head
    assert g.n_frames == h.n_frames == 12
    assert (g.rotation.inv() * h.rotation).magnitude().max() < 1e-6       # float32 keyframes
    np.testing.assert_allclose(g.translation, h.translation, atol=1e-7)


# ------------------------------------------------------------------------------------------- glTF adapter
def test_gltf_adapter_agrees_on_written_files(tmp_path, arkit_rig):
    from faceretarget.io import write_glb, write_glb_skeleton

    W = np.random.default_rng(0).uniform(0, 1, (5, arkit_rig.n_shapes))
    write_glb(tmp_path / "face.glb", arkit_rig, W, np.arange(5) / 30.0)
    J = 4
    q = np.tile([0.0, 0.0, 0.0, 1.0], (3, J, 1))
    q[:, 2] = [0.0, np.sin(0.2), 0.0, np.cos(0.2)]
    off = np.array([[0, 90.0, 0], [0, 10, 0], [0, 12, 1], [0, 8, 1]])
    write_glb_skeleton(tmp_path / "skel.glb", ["Hips", "Spine", "Neck", "Head"], [-1, 0, 1, 2], off, q,
                       np.broadcast_to(off, (3, J, 3)), np.arange(3) / 30.0)
    for f in ("face.glb", "skel.glb"):
        d = bench.check_file("gltf", tmp_path / f, timeout=TIMEOUT)
        assert d["outcome"] == "agree", d["reason"]
    arrays = bench.ours_gltf(tmp_path / "face.glb")
    assert sum(k.endswith(".POSITION") and ".target" in k for k in arrays) == arkit_rig.n_shapes


def test_gltf_adapter_decodes_meshopt_and_names_what_it_cannot(tmp_path, data_dir):
    """The glTF reader decodes EXT_meshopt_compression and KHR_mesh_quantization (a VALID avatar agrees with
    pygltflib's parse decoded by meshoptimizer's own decoder), and a file requiring an extension it does not
    decode is an error naming it."""
    from faceretarget.headpose import HeadPose
    from faceretarget.io import write_glb_head

    d = bench.check_file("gltf", data_dir / "characters" / "valid" / "Black_M_2_Busi.glb", timeout=TIMEOUT)
    assert d["outcome"] == "agree" and d["max_abs_diff"] < 1e-6, d
    src = write_glb_head(tmp_path / "h.glb", np.arange(3) / 30.0, HeadPose.identity(3))
    raw = src.read_bytes()
    n = int.from_bytes(raw[12:16], "little")
    doc = json.loads(raw[20:20 + n])
    body = json.dumps({**doc, "extensionsRequired": ["EXT_made_up"], "extensionsUsed": ["EXT_made_up"]}).encode()
    body += b" " * (-len(body) % 4)
    rest = raw[20 + n:]
    out = raw[:8] + (12 + 8 + len(body) + len(rest)).to_bytes(4, "little") + len(body).to_bytes(4, "little") \
        + raw[16:20] + body + rest
    p = tmp_path / "madeup.glb"
    p.write_bytes(out)
    d = bench.check_file("gltf", p, timeout=TIMEOUT)
    assert d["outcome"] == "error" and str(p) in d["reason"] and "EXT_made_up" in d["reason"], d


# ------------------------------------------------------------------------------------------- the bench
def test_a_hang_or_a_crash_is_isolated(tmp_path):
    """One child reads every file; the file it hangs or dies on is run alone (hang / crash), the rest still read."""
    names = ["a", "hang", "b", "crash", "c"]
    for n in names:
        (tmp_path / f"{n}.txt").write_text(n)
    runs = bench.run_many("selftest", [tmp_path / f"{n}.txt" for n in names], timeout=2.0)
    assert [r.status for r in runs] == ["ok", "hang", "ok", "crash", "ok"]
    assert [str(r.data["text"]) for r in runs if r.status == "ok"] == ["a", "b", "c"]



def test_bench_json_on_a_corpus(tmp_path, capsys):
    """``--json --corpus DIR``: the last line is the issue's object, a broken file an error, nothing a crash."""
    _write_variant(tmp_path, "intel-int", _variants()["intel-int"])
    (tmp_path / "broken.c3d").write_bytes(b"\x02\x50" + b"\0" * 100)
    text, _ = _bvh_text(["ZXY"] * 4, True, (0, 0, 0))
    (tmp_path / "sub").mkdir()
    (tmp_path / "sub" / "t.bvh").write_text(text)
    assert bench.main(["--json", "--corpus", str(tmp_path), "--timeout", str(TIMEOUT)]) == 0
    out = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert set(out) == {"formats"} and set(out["formats"]) == {"c3d", "bvh", "gltf"}
    for r in out["formats"].values():
        assert set(r) == {"files", "agree", "differ", "error", "crash", "hang", "details"}
        assert r["files"] == r["agree"] + r["differ"] + r["error"] + r["crash"] + r["hang"]
        assert r["crash"] == r["hang"] == 0
        assert all({"outcome", "reason"} <= set(d) for d in r["details"].values())
    c3d = out["formats"]["c3d"]
    assert (c3d["files"], c3d["agree"], c3d["error"]) == (2, 1, 1)
    assert "broken.c3d" in c3d["details"]["broken.c3d"]["reason"]
    assert out["formats"]["bvh"]["agree"] == 1 and out["formats"]["gltf"]["files"] == 0
