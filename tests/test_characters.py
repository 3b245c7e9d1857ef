"""Characters as users bring them (issue 22): every reader and writer route on the shared characters,
the compressed glTF variants checked against the uncompressed truth, the landmarks found against the
reference ones, the animation written back and read by the programs that consume it, and each bad input."""

from __future__ import annotations

import json
import shutil
import struct
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from faceretarget.character import Channel, channels, choose_shapes, is_viseme, joint_motions, joint_rotations
from faceretarget.characters import load_character
from faceretarget.errors import (
    FaceNotFoundError,
    InputFileError,
    InvalidDataError,
    MissingShapeError,
    OutputError,
)
from faceretarget.headpose import HeadPose
from faceretarget.io import read_character, write_character_animation, write_glb
from faceretarget.pipelines import animate, capture_take

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "bench"))
import _character_checks as checks  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _vrm import make_vrm  # noqa: E402

REPO = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def take(data_dir):
    """60 frames of a shared video, captured once."""
    pytest.importorskip("mediapipe")
    return capture_take(data_dir / "video" / "WDA_KatieHill_000.mp4", neutral_percentile=5.0, max_frames=60)


def _tools(*need):
    node = shutil.which("node")
    missing = [n for n in need if not (checks.TOOLS / n / "package.json").is_file()]
    return node is not None and not missing


# ------------------------------------------------------------------------------------------ glTF reader
def _glb(path: Path, js: dict, binchunk: bytes) -> Path:
    body = json.dumps(js).encode()
    body += b" " * ((-len(body)) % 4)
    binchunk += b"\0" * ((-len(binchunk)) % 4)
    with open(path, "wb") as f:
        f.write(struct.pack("<III", 0x46546C67, 2, 12 + 8 + len(body) + 8 + len(binchunk)))
        f.write(struct.pack("<II", len(body), 0x4E4F534A) + body)
        f.write(struct.pack("<II", len(binchunk), 0x004E4942) + binchunk)
    return path


def _tiny(tmp_path: Path, variant: str) -> tuple[Path, np.ndarray, np.ndarray, np.ndarray]:
    """A two-node glTF of one quad mesh with two morph targets, written plainly or with quantized, meshopt,
    sparse or Draco-compressed data; returns the file, the world positions, the deltas and the triangles."""
    rng = np.random.default_rng(3)
    P = np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0], [0, 0, 0.5]], np.float32) * 0.1
    T = np.array([[0, 1, 4], [1, 2, 4], [2, 3, 4], [3, 0, 4]], np.uint16)
    D = np.zeros((2, 5, 3), np.float32)
    D[0, 4] = [0, 0.02, 0.01]
    D[1, [0, 1]] = rng.normal(0, 0.01, (2, 3))
    views, accessors, chunks = [], [], []

    def add(data: bytes, extra=None):
        off = sum(len(c) for c in chunks)
        chunks.append(data + b"\0" * ((-len(data)) % 4))
        views.append({"buffer": 0, "byteOffset": off, "byteLength": len(data), **(extra or {})})
        return len(views) - 1

    def acc(arr, type_, ctype, **kw):
        a = {"bufferView": add(np.ascontiguousarray(arr).tobytes()), "componentType": ctype, "count": len(arr),
             "type": type_, **kw}
        accessors.append(a)
        return len(accessors) - 1

    prim: dict = {"mode": 4}
    used = []
    if variant == "quantized":                       # KHR_mesh_quantization: normalized int16 + node scale
        s = 0.1
        q = np.round(P / s * 32767).astype(np.int16)
        pos = acc(np.c_[q, np.zeros(5, np.int16)], "VEC3", 5122, normalized=True, byteOffset=0)
        views[-1]["byteStride"] = 8
        accessors[-1]["count"] = 5
        tq = [acc(np.c_[np.round(d / s * 32767).astype(np.int16), np.zeros(5, np.int16)], "VEC3", 5122,
                  normalized=True) for d in D]
        for k in tq:
            views[accessors[k]["bufferView"]]["byteStride"] = 8
        used = ["KHR_mesh_quantization"]
        node_scale = [s, s, s]
        P_q = q.astype(np.float64) / 32767                   # the normalized values; the node scales them
        D_true = np.stack([np.round(d / s * 32767) / 32767 for d in D])
        prim["attributes"] = {"POSITION": pos}
        prim["targets"] = [{"POSITION": k} for k in tq]
        prim["indices"] = acc(T.reshape(-1), "SCALAR", 5123)
        P_true = P_q
    else:
        node_scale = [1, 1, 1]
        P_true, D_true = P.astype(np.float64), D.astype(np.float64)
        if variant == "meshopt":
            import meshopt

            used = ["EXT_meshopt_compression"]
            chunks.append(b"")

            def moacc(arr, type_, ctype, mode="ATTRIBUTES"):
                arr = np.ascontiguousarray(arr)
                stride = arr.itemsize * (arr.shape[1] if arr.ndim == 2 and mode == "ATTRIBUTES" else 1)
                enc = meshopt.encode_gltf_buffer(arr if mode == "ATTRIBUTES" else arr.astype(np.uint32), mode)
                count = len(arr) if mode == "ATTRIBUTES" else arr.size
                off = sum(len(c) for c in chunks)
                chunks.append(enc + b"\0" * ((-len(enc)) % 4))
                views.append({"buffer": 1, "byteOffset": 0, "byteLength": arr.nbytes,
                              "extensions": {"EXT_meshopt_compression": {
                                  "buffer": 0, "byteOffset": off, "byteLength": len(enc), "byteStride": stride,
                                  "count": count, "mode": mode}}})
                accessors.append({"bufferView": len(views) - 1, "componentType": ctype, "count": len(arr),
                                  "type": type_})
                return len(accessors) - 1
            prim["attributes"] = {"POSITION": moacc(P, "VEC3", 5126)}
            accessors[-1].update(min=P.min(0).tolist(), max=P.max(0).tolist())
            prim["targets"] = [{"POSITION": moacc(d, "VEC3", 5126)} for d in D]
            idx = T.reshape(-1, 3).astype(np.uint16)
            prim["indices"] = moacc(idx.reshape(-1, 3), "SCALAR", 5123, mode="TRIANGLES")
            accessors[-1]["count"] = idx.size
        elif variant == "sparse":
            prim["attributes"] = {"POSITION": acc(P, "VEC3", 5126, min=P.min(0).tolist(), max=P.max(0).tolist())}
            tg = []
            for d in D:
                nz = np.flatnonzero(np.abs(d).sum(1) > 0).astype(np.uint16)
                a = {"componentType": 5126, "count": 5, "type": "VEC3",
                     "sparse": {"count": len(nz), "indices": {"bufferView": add(nz.tobytes()), "componentType": 5123},
                                "values": {"bufferView": add(np.ascontiguousarray(d[nz]).tobytes())}}}
                accessors.append(a)
                tg.append({"POSITION": len(accessors) - 1})
            prim["targets"] = tg
            prim["indices"] = acc(T.reshape(-1), "SCALAR", 5123)
        elif variant == "draco":
            import DracoPy

            used = ["KHR_draco_mesh_compression"]
            enc = DracoPy.encode(P, T.astype(np.uint32), quantization_bits=0)
            dm = DracoPy.decode(enc)                  # Draco may reorder the points: the truth is its order
            P_true = np.asarray(dm.points, np.float64)
            order = [int(np.argmin(np.linalg.norm(P - p, axis=1))) for p in P_true]
            D_true = D[:, order].astype(np.float64)
            pa = {"componentType": 5126, "count": 5, "type": "VEC3", "min": P.min(0).tolist(),
                  "max": P.max(0).tolist()}
            accessors.append(pa)
            prim["attributes"] = {"POSITION": len(accessors) - 1}
            prim["targets"] = [{"POSITION": acc(D_true[k].astype(np.float32), "VEC3", 5126)} for k in range(2)]
            accessors.append({"componentType": 5123, "count": 12, "type": "SCALAR"})
            prim["indices"] = len(accessors) - 1
            prim["extensions"] = {"KHR_draco_mesh_compression": {"bufferView": add(bytes(enc)),
                                                                  "attributes": {"POSITION": 0}}}
            T = np.asarray(dm.faces)
        else:
            prim["attributes"] = {"POSITION": acc(P, "VEC3", 5126, min=P.min(0).tolist(), max=P.max(0).tolist())}
            prim["targets"] = [{"POSITION": acc(d, "VEC3", 5126)} for d in D]
            prim["indices"] = acc(T.reshape(-1), "SCALAR", 5123)
    js = {"asset": {"version": "2.0"}, "scene": 0, "scenes": [{"nodes": [0]}],
          "nodes": [{"name": "Head", "children": [1], "translation": [0, 1.5, 0]},
                    {"name": "face", "mesh": 0, "scale": node_scale}],
          "meshes": [{"name": "face", "primitives": [prim], "extras": {"targetNames": ["viseme_sil", "jawOpen"]}}],
          "accessors": accessors, "bufferViews": views, "buffers": [{"byteLength": sum(len(c) for c in chunks)}]}
    if used:
        js["extensionsUsed"] = js["extensionsRequired"] = used
    if variant == "meshopt":
        js["buffers"].append({"byteLength": 4096, "extensions": {"EXT_meshopt_compression": {"fallback": True}}})
    world = P_true * np.array(node_scale) + [0, 1.5, 0]
    return _glb(tmp_path / f"{variant}.glb", js, b"".join(chunks)), world, D_true * np.array(node_scale), T


@pytest.mark.parametrize("variant", ["plain", "quantized", "meshopt", "sparse", "draco"])
def test_glb_variants_read_the_same_mesh_and_shapes(tmp_path, variant):
    path, world, deltas, _ = _tiny(tmp_path, variant)
    ch = read_character(path)
    assert [m.name for m in ch.meshes] == ["face"]
    m = ch.meshes[0]
    assert m.shape_names == ["viseme_sil", "jawOpen"]             # names exactly as in the file
    np.testing.assert_allclose(m.mesh.vertices, world, atol=1e-6)
    np.testing.assert_allclose(m.deltas, deltas, atol=1e-6)
    assert ch.roles == {"head": 0}


def test_unsupported_required_extension_is_named(tmp_path):
    path, *_ = _tiny(tmp_path, "plain")
    data = path.read_bytes()
    n = struct.unpack_from("<I", data, 12)[0]
    js = json.loads(data[20:20 + n])
    js["extensionsRequired"] = js["extensionsUsed"] = ["EXT_made_up_compression"]
    bad = _glb(tmp_path / "bad.glb", js, data[20 + n + 8:])
    with pytest.raises(InputFileError, match="EXT_made_up_compression"):
        read_character(bad)
    (tmp_path / "x.txt").write_text("x")
    with pytest.raises(InputFileError, match="not a character format"):
        read_character(tmp_path / "x.txt")


def test_valid_avatar_read_whole(chars):
    ch = read_character(chars / "valid" / "AIAN_F_1_Busi.glb")
    assert ch.format == "gltf" and "EXT_meshopt_compression" in ch.route
    assert len(ch.meshes) == 8
    face = [ch.meshes[i].name for i in ch.face_meshes()]
    assert face == ["H_DDS_HighRes", "h_TeethDown"]
    body = ch.meshes[ch.primary]
    assert body.n_shapes == 65 and body.shape_names[0] == "h_expressions.AE_AA_h"
    height = np.ptp(body.mesh.vertices[:, 1])
    assert 1.6 < height < 1.8                                      # metres, skinned at rest (quantized + IBMs)
    assert {r: ch.joints[i].name for r, i in ch.roles.items()} == {
        "neck": "Neck", "head": "Head", "leftEye": "LeftEye", "rightEye": "RightEye"}
    chans = channels(ch)
    tied = [c for c in chans if len(c.binds) == 2]
    # the lower teeth's 19 viseme shapes (t_AE_AA_h ...) follow the face's; t_MPB_h has no partner (MPB_Up_h, MPB_Down_h)
    assert len(tied) == 18 and tied[0].name == "h_expressions.AE_AA_h"
    assert any(c.name == "t_MPB_h" and len(c.binds) == 1 for c in chans)
    eye = next(m for m in ch.meshes if m.name == "h_L_eye")
    assert eye.joint == "LeftEye"                                  # a rigid eyeball follows its joint


def test_robot_three_primitives_and_its_moods(chars):
    ch = read_character(chars / "robot" / "RobotExpressive.glb")
    head = ch.meshes[ch.primary]
    assert head.name == "Head" and head.shape_names == ["Angry", "Surprised", "Sad"]
    assert head.mesh.n_vertices == 302 + 876 + 564                 # every primitive of the mesh
    with pytest.raises(FaceNotFoundError, match="--landmarks"):
        load_character(chars / "robot" / "RobotExpressive.glb")


def test_fbx_by_ufbx_equals_blender_importer(chars):
    """ufbx (the default route) and Blender's FBX importer read the same vertices and shapes."""
    path = chars / "rocketbox" / "Female_Adult_01_facial.fbx"
    a = read_character(path)
    assert a.route == "ufbx" and a.source_unit == "cm"
    m = a.meshes[0]
    assert m.n_shapes == 175 and m.shape_names[24] == "blendShape1.AK_10_EyeBlinkRight"
    assert 1.70 < np.ptp(m.mesh.vertices[:, 1]) < 1.78            # centimetres -> metres
    assert a.joint("head").name == "Bip01 Head"
    pytest.importorskip("bpy")
    b = read_character(path, prefer="blender")
    mb = b.meshes[0]
    from faceretarget.io._blender import BLENDER_AXES

    np.testing.assert_allclose(mb.mesh.vertices, m.mesh.vertices @ BLENDER_AXES.T, atol=2e-5)
    k = mb.shape_names.index("AK_25_JawOpen")
    np.testing.assert_allclose(mb.deltas[k], m.deltas[m.shape_names.index("blendShape1.AK_25_JawOpen")]
                               @ BLENDER_AXES.T, atol=2e-5)


def test_fbx_textures_found_in_the_textures_folder_beside_the_export(tmp_path, chars):
    """Rocketbox's FBX names its textures by an exporter's absolute Windows path (``D:/temp/.../textures/
    f001_head_color.tga``); a user's copy keeps them in ``Textures/`` beside the FBX's ``Export/`` folder, in
    whatever case: found there and decoded, and a texture found nowhere is one note."""
    from PIL import Image

    src = chars / "rocketbox" / "Female_Adult_01_facial.fbx"
    plain = read_character(src)
    assert any("missing texture" in n and "f001_head_color" in n for n in plain.notes)
    (tmp_path / "Export").mkdir()
    (tmp_path / "Textures").mkdir()
    fbx = tmp_path / "Export" / src.name
    shutil.copyfile(src, fbx)
    Image.new("RGB", (8, 8), (200, 30, 40)).save(tmp_path / "Textures" / "F001_HEAD_COLOR.TGA")
    ch = read_character(fbx)
    found = [m for sm in ch.meshes for m in sm.materials if m.image_source is not None]
    assert len(found) == 1 and str(found[0].image_source.path).endswith("F001_HEAD_COLOR.TGA")
    px = found[0].image
    assert px.shape == (8, 8, 4) and tuple(px[0, 0]) == (200, 30, 40, 255)
    assert not any("f001_head_color" in n for n in ch.notes)
    assert any("f001_body_color" in n for n in ch.notes)


def test_slow_reads_are_cached_by_content(tmp_path, chars, monkeypatch):
    """An .fbx read out of process is kept by its SHA-256: read back the same, fast; a damaged entry or an
    edited file is read again."""
    monkeypatch.setenv("FACERETARGET_CACHE", str(tmp_path / "cache"))
    src = tmp_path / "rb.fbx"
    shutil.copyfile(chars / "rocketbox" / "Female_Adult_01_facial.fbx", src)
    a = load_character(src, find=False)
    entries = list((tmp_path / "cache" / "characters").glob("*.pickle"))
    assert len(entries) == 1
    lines = []
    b = load_character(src, find=False, log=lines.append)
    assert any("from the cache" in ln for ln in lines) and b.timings["read"] < 0.5
    assert b.path == src and b.meshes[0].shape_names == a.meshes[0].shape_names
    np.testing.assert_array_equal(b.meshes[0].deltas, a.meshes[0].deltas)
    entries[0].write_bytes(b"not a pickle")
    lines = []
    c = load_character(src, find=False, log=lines.append)
    assert not any("from the cache" in ln for ln in lines) and c.meshes[0].n_shapes == 175
    with open(src, "ab") as f:                   # another file: another entry
        f.write(b"\0" * 16)
    load_character(src, find=False)
    assert len(list((tmp_path / "cache" / "characters").glob("*.pickle"))) == 2


def test_landmark_cache_is_the_users_keyed_by_content(tmp_path, chars, monkeypatch):
    """Issue 31: found landmarks go to the user's cache folder ($XDG_CACHE_HOME/faceretarget when
    FACERETARGET_CACHE is unset), named by the file's SHA-256: a read-only character folder is left as it was,
    the second load reads them back, a copy elsewhere finds them too, and --no-cache neither reads nor writes."""
    pytest.importorskip("mediapipe")
    from faceretarget.characters import landmark_cache_path
    from faceretarget.files import cache_dir

    monkeypatch.delenv("FACERETARGET_CACHE", raising=False)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    assert cache_dir() == tmp_path / "xdg" / "faceretarget"
    folder = tmp_path / "assets"
    folder.mkdir()
    f = folder / "busi.glb"
    shutil.copyfile(chars / "valid" / "Black_M_2_Busi.glb", f)
    folder.chmod(0o555)
    try:
        a = load_character(f)
        assert sorted(x.name for x in folder.iterdir()) == ["busi.glb"]
        entry = landmark_cache_path(f)
        assert entry.parent == tmp_path / "xdg" / "faceretarget" / "landmarks" and entry.is_file()
        lines = []
        b = load_character(f, log=lines.append)
        assert any("read from the cache" in ln for ln in lines), lines
        np.testing.assert_array_equal(a.landmarks.triangles, b.landmarks.triangles)
    finally:
        folder.chmod(0o755)
    moved = tmp_path / "elsewhere.glb"                     # same content, another path: the same entry
    shutil.copyfile(f, moved)
    lines = []
    load_character(moved, log=lines.append)
    assert any(str(entry) in ln for ln in lines), lines
    entry.unlink()
    monkeypatch.setenv("FACERETARGET_NO_CACHE", "1")
    lines = []
    c = load_character(moved, log=lines.append)
    assert not entry.exists() and not any("cache" in ln and "looking" not in ln for ln in lines), lines
    np.testing.assert_array_equal(a.landmarks.triangles, c.landmarks.triangles)
    # the command line's --no-cache: the same, for the command and the processes it starts
    monkeypatch.delenv("FACERETARGET_NO_CACHE")
    r = subprocess.run([sys.executable, "-m", "faceretarget.cli", "--no-cache", "character", "inspect", str(moved),
                        "--json"], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    assert not list((tmp_path / "xdg" / "faceretarget" / "landmarks").glob("*.json"))     # nothing cached


# ------------------------------------------------------------------------------------------ shapes
def test_shape_choice_arkit_visemes_names_and_duplicates():
    names = ["blendShape1.AK_25_JawOpen", "blendShape1.SR_21_Jaw_Open", "blendShape1.AA_VI_10_aa", "Fcl_MTH_A",
             "viseme_sil", "h_expressions.Chew_h"] + [f"blendShape1.AK_{i:02d}_{n}" for i, n in enumerate(
                 ["EyeBlinkLeft", "EyeBlinkRight", "MouthSmileLeft", "MouthSmileRight", "BrowInnerUp", "CheekPuff",
                  "MouthFunnel", "MouthPucker", "NoseSneerLeft"])]
    chans = [Channel(n, ((0, i),)) for i, n in enumerate(names)]
    c = choose_shapes(chans)
    assert c.basis == "arkit" and names.index("blendShape1.AK_25_JawOpen") in c.drive
    assert names.index("blendShape1.SR_21_Jaw_Open") not in c.drive   # same ARKit name, worse spelt
    v = choose_shapes(chans, "visemes")
    assert [names[i] for i in v.drive] == ["blendShape1.AA_VI_10_aa", "Fcl_MTH_A", "viseme_sil"]
    n = choose_shapes(chans, "viseme_*,*chew*")
    assert [names[i] for i in n.drive] == ["viseme_sil", "h_expressions.Chew_h"]
    with pytest.raises(MissingShapeError, match="no shape named 'smile'"):
        choose_shapes(chans, "smile")
    M = np.zeros((len(names), 68, 3))
    M[:, 10, 0] = 1.0                                   # every shape moves one landmark the same way ...
    M[5] = 0.0                                          # ... but Chew_h, which moves none
    a = choose_shapes(chans, "all", M)
    assert a.drive == [0] and "near-duplicates" in a.rest and a.rest["move no landmark"] == ["h_expressions.Chew_h"]
    assert is_viseme("blendShape1.AA_VI_01_PP") and not is_viseme("blendShape1.AK_25_JawOpen")


def test_joint_rotations_turn_the_head_by_the_pose(chars):
    """The keys written on the head (and neck) joint give the head exactly R_w times its rest world rotation."""
    from scipy.spatial.transform import Rotation

    from faceretarget.character import character_frame

    ch = read_character(chars / "valid" / "Black_M_2_Busi.glb")
    ch.front = np.array([0.0, 0.0, 1.0])
    R = Rotation.from_euler("xyz", [[10, 20, -5], [-15, 5, 30]], degrees=True)
    pose = HeadPose.from_rotation(R)
    F = character_frame(ch)
    head, neck = ch.joint("head"), ch.joint("neck")
    for share in (0.0, 0.4):
        moves = {role: joint_rotations(ch, j, rot) for role, j, rot in joint_motions(ch, pose, share)}
        qh, qn = moves["head"], moves.get("neck")
        for t in range(2):
            Ln = neck.local.copy()
            if qn is not None:
                Ln[:3, :3] = Rotation.from_quat(qn[t]).as_matrix() * np.linalg.norm(neck.local[:3, :3], axis=0)
            Lh = head.local.copy()
            Lh[:3, :3] = Rotation.from_quat(qh[t]).as_matrix() * np.linalg.norm(head.local[:3, :3], axis=0)
            parent = ch.joints[neck.parent].world
            world = parent @ Ln @ Lh                       # Head is Neck's child in this skeleton
            U, _, Vt = np.linalg.svd(world[:3, :3])
            G = np.linalg.svd(head.world[:3, :3])
            G = G[0] @ G[2]
            want = F.T @ R[t].as_matrix() @ F @ G
            np.testing.assert_allclose(U @ Vt, want, atol=1e-9)


# ------------------------------------------------------------------------------------------ landmarks
def test_landmarks_found_near_the_reference_and_cached(tmp_path, data_dir, ict_rig):
    """ict-face as a .glb without its landmark file: the 68 found are within the targets (inner <= 5 %,
    contour <= 10 % of the eye-corner distance), and the second load reads them from the cache."""
    pytest.importorskip("mediapipe")
    p = write_glb(tmp_path / "ict.glb", ict_rig, np.zeros((1, ict_rig.n_shapes)), np.zeros(1))
    ch = load_character(p)
    assert ch.landmarks.source == "found on a render" and np.allclose(ch.front, [0, 0, 1])
    ref = ict_rig.neutral.vertices[ict_rig.landmarks] / 100.0
    e = np.linalg.norm(ch.landmark_positions() - ref, axis=1) / np.linalg.norm(ref[36] - ref[45])
    print(f"ict-face landmarks: inner {e[17:].mean():.3f}, contour {e[:17].mean():.3f}")
    assert e[17:].mean() <= 0.05 and e[:17].mean() <= 0.10
    again = load_character(p)
    assert again.timings["landmarks"] < 0.5 and again.search is None
    np.testing.assert_allclose(again.landmark_positions(), ch.landmark_positions(), atol=1e-9)
    # --landmarks: 68 vertex indices of the face mesh override the cache
    idx = tmp_path / "lm.txt"
    idx.write_text(" ".join(map(str, range(68))))
    own = load_character(p, landmarks=idx)
    np.testing.assert_allclose(own.landmark_positions(), own.meshes[0].mesh.vertices[:68])
    with pytest.raises(InputFileError, match="68 vertex indices"):
        idx.write_text("1 2 3")
        load_character(p, landmarks=idx)


def _welded_pieces(V, T):
    """Connected piece of each vertex, vertices at one position (UV seams) counted as one."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    w = np.unique(np.round(V * 1e7).astype(np.int64), axis=0, return_inverse=True)[1].reshape(-1)
    e = w[np.concatenate([T[:, [0, 1]], T[:, [1, 2]]])]
    n = int(w.max()) + 1
    return connected_components(coo_matrix((np.ones(len(e)), (e[:, 0], e[:, 1])), shape=(n, n)), directed=False)[1][w]


@pytest.mark.parametrize("name", ["arkit-face", "ict-face"])
def test_found_jaw_line_within_10_percent(tmp_path, data_dir, name):
    """Issue 34: the jaw line found on arkit-face (a mask, its hand-made jaw points on its edge; 17.9 % before,
    the frontal pick landed on the steep strip in front of the edge) and ict-face (a whole head) within 10 % of
    the eye-corner distance of the hand-made points, the inner points within 5 %."""
    pytest.importorskip("mediapipe")
    from faceretarget.io import read_rig

    rig = read_rig(data_dir / name)
    p = write_glb(tmp_path / f"{name}.glb", rig, np.zeros((1, rig.n_shapes)), np.zeros(1))
    ch = load_character(p, cache=False)
    ref = rig.neutral.vertices[rig.landmarks] * rig.mm_per_unit / 1000.0
    e = np.linalg.norm(ch.landmark_positions() - ref, axis=1) / np.linalg.norm(ref[36] - ref[45])
    print(f"{name} landmarks: inner {e[17:].mean():.3f}, jaw line {e[:17].mean():.3f}")
    assert e[:17].mean() <= 0.10 and e[17:].mean() <= 0.05


def test_rocketbox_lid_landmarks_on_the_lids(tmp_path, chars):
    """Issue 34: Rocketbox's eyeballs are pieces of its one body mesh; the untextured render showed them in the
    eye openings and 7 of the 8 lid points (37, 38, 40, 41, 43, 44, 46, 47) landed on them.  Each is now on the
    face's skin (the piece that holds the nose), on the rim of the opening: nearer its eyeball than the eye's
    width (not on the brow or the cheek)."""
    pytest.importorskip("mediapipe")
    ch = load_character(chars / "rocketbox" / "Female_Adult_01_facial.fbx", cache=False)
    lm = ch.landmarks
    m = ch.meshes[lm.mesh].mesh
    V, T = m.vertices, m.triangles()
    piece = _welded_pieces(V, T)
    skin = piece[lm.triangles[30, 0]]
    P = ch.landmark_positions()
    eye = np.linalg.norm(P[36] - P[45])
    lids = [37, 38, 40, 41, 43, 44, 46, 47]
    on = piece[lm.triangles[lids, 0]]
    assert (on == skin).all(), dict(zip(lids, on.tolist(), strict=True))
    balls = [c for c in np.unique(piece) if c != skin and (np.linalg.norm(V[piece == c] - P[[37, 44]].mean(0),
                                                                            axis=1) < eye).any()]
    assert len(balls) == 2                                       # the two eyeballs, in the same mesh
    for k in lids:
        d = min(np.linalg.norm(V[piece == c] - P[k], axis=1).min() for c in balls)
        assert d < 0.15 * eye, (k, d / eye)
    # the check picture (character inspect --out) marks them where they went, not where the landmarker saw them
    from PIL import Image

    from faceretarget.characters._load import _check_picture

    img = np.asarray(Image.open(_check_picture(ch, tmp_path / "check.png")))
    for k in lids:
        x, y = np.round(ch.search.camera.project(P[k:k + 1])[0, :2]).astype(int)
        assert tuple(img[y, x]) == (40, 220, 60), (k, img[y, x])


def test_landmarks_cached_by_an_earlier_search_are_searched_again(tmp_path, data_dir, arkit_rig, monkeypatch):
    """The cache entry records the search's version (``finder``, format faceretarget.landmarks/1 kept): an
    entry an earlier search wrote (no ``finder``) is searched again and replaced; the same record given as
    ``--landmarks FILE.json`` is used as it is."""
    pytest.importorskip("mediapipe")
    from faceretarget.capture import FINDER_VERSION
    from faceretarget.characters import landmark_cache_path

    monkeypatch.setenv("FACERETARGET_CACHE", str(tmp_path / "cache"))
    p = write_glb(tmp_path / "arkit.glb", arkit_rig, np.zeros((1, arkit_rig.n_shapes)), np.zeros(1))
    a = load_character(p)
    entry = landmark_cache_path(p)
    d = json.loads(entry.read_text())
    assert d["format"] == "faceretarget.landmarks/1" and d["finder"] == FINDER_VERSION
    old = dict(d, triangles=[d["triangles"][0]] * 68, bary=[[1.0, 0.0, 0.0]] * 68)
    del old["finder"]
    entry.write_text(json.dumps(old))
    lines = []
    b = load_character(p, log=lines.append)
    assert any("earlier search" in ln for ln in lines), lines
    np.testing.assert_array_equal(b.landmarks.triangles, a.landmarks.triangles)
    assert json.loads(entry.read_text())["finder"] == FINDER_VERSION
    given = tmp_path / "given.json"
    given.write_text(json.dumps(old))
    c = load_character(p, landmarks=given)
    np.testing.assert_array_equal(c.landmarks.triangles, np.asarray(old["triangles"]))


# ------------------------------------------------------------------------------------------ the main job
def test_animate_writes_back_into_the_glb(tmp_path, chars, take):
    src = chars / "valid" / "Black_M_2_Busi.glb"
    out = tmp_path / "busi.glb"
    res = animate(take, src, out=out)
    # 0.896 measured (0.898 with every shape in a score's mix) since the tracker's scores reach the avatar's own
    # shapes (characters.score_map), 0.90+ when its shapes followed the landmarks alone: against ground truth its
    # mouth error fell 89.5 -> 70.6 % (bench/own_shapes.py), so this proxy is held at 0.85 as for the ARKit
    # characters (test_animate)
    assert res.mouth_corr >= 0.85
    d = res.drive
    assert {d.character.meshes[i].name for i in d.character.face_meshes()} == {"H_DDS_HighRes", "h_TeethDown"}
    assert 0.0 <= res.weights.min() and res.weights.max() <= 1.0
    k = checks.kept(src, out)
    assert k["ok"] and k["images_identical"], k
    w = checks.written_gltf(out)
    assert set(w["weights"]) == {"H_DDS_HighRes", "h_TeethDown"} and w["head_node"] is not None
    full = d.full_weights(res.weights)
    ci = next(i for i, c in enumerate(d.channels) if c.name == "h_expressions.MouthOpen_h")
    np.testing.assert_allclose(w["weights"]["H_DDS_HighRes"][:, 26], full[:, ci], atol=1e-6)
    teeth = dict(d.channels[ci].binds)
    np.testing.assert_allclose(w["weights"]["h_TeethDown"][:, teeth[5]], full[:, ci], atol=1e-6)
    errs, why = checks.validator_errors(out)
    if errs is not None:
        assert errs == 0
    if _tools("three"):
        three = checks.three_checks(out, "faceretarget", w["weights"], w["times"], w["head_node"], w["head_keys"],
                                    max_times=12)
        assert three["ok"], three
    # gaze on the eye joints (the avatar has no eyeLook shapes): rotation channels on LeftEye and RightEye
    js, _ = checks._glb_json(out)
    anim = js["animations"][-1]
    rotated = {js["nodes"][c["target"]["node"]]["name"] for c in anim["channels"] if c["target"]["path"] == "rotation"}
    assert rotated == {"Head", "LeftEye", "RightEye"} and set(res.gaze) == {"leftEye", "rightEye"}
    with pytest.raises(OutputError, match="character's own file"):
        write_character_animation(src, d.character, d.channels, full, res.times)


def test_gaze_scores_turn_the_eyes():
    """eyeLookOutLeft = 1 turns the left eye 30 degrees toward the character's left (+X); eyeLookUpRight = 1
    turns the right eye up (+Y) by 25 degrees."""
    from faceretarget.pipelines import gaze_rotations

    names = ["eyeLookOutLeft", "eyeLookUpRight", "jawOpen"]
    g = gaze_rotations(names, np.array([[1.0, 1.0, 0.3]]))
    left = g["leftEye"].apply([0, 0, 1])[0]
    right = g["rightEye"].apply([0, 0, 1])[0]
    np.testing.assert_allclose(left, [np.sin(np.radians(30)), 0, np.cos(np.radians(30))], atol=1e-12)
    np.testing.assert_allclose(right, [0, np.sin(np.radians(25)), np.cos(np.radians(25))], atol=1e-12)
    assert gaze_rotations(["jawOpen"], np.zeros((2, 1))) == {}


def test_animate_writes_back_with_blender(tmp_path, chars, take):
    pytest.importorskip("bpy")
    src = chars / "rocketbox" / "Female_Adult_01_facial.fbx"
    for ext in (".blend", ".fbx"):
        out = tmp_path / f"rb{ext}"
        res = animate(take, src, out=out)
        assert res.mouth_corr >= 0.9
        b = checks.blender_checks(src, out, 25.0, len(res.times))
        assert b["ok"], b
        assert b["outside_slider"] == 0 and b["head_rotation_curves"] >= 4


def test_usd_layer_over_the_asset(tmp_path, chars, take):
    """A USD character (Rocketbox exported by Blender): the written layer composes over the untouched asset
    and UsdSkel evaluates the written weights."""
    pytest.importorskip("pxr")
    bpy = pytest.importorskip("bpy")
    from faceretarget.io._blender import _blender_output

    asset = tmp_path / "asset" / "rocketbox.usdc"
    asset.parent.mkdir()
    with _blender_output():
        bpy.ops.wm.read_factory_settings(use_empty=True)
        bpy.ops.import_scene.fbx(filepath=str(chars / "rocketbox" / "Female_Adult_01_facial.fbx"))
        bpy.ops.wm.usd_export(filepath=str(asset), export_armatures=True, export_shapekeys=True,
                              export_animation=False, export_textures=False)
        bpy.ops.wm.read_factory_settings(use_empty=True)
    before = asset.read_bytes()
    out = tmp_path / "anim.usda"
    res = animate(take, asset, out=out)
    assert asset.read_bytes() == before
    full = res.drive.full_weights(res.weights)
    names = {res.drive.character.meshes[mi].shape_names[k]: full[:, c]
             for c, ch in enumerate(res.drive.channels) for mi, k in ch.binds}
    u = checks.usd_checks(out, names, res.times)
    assert u["ok"] and u["weights_compared"] > 1000 and u["joint_world_change"] > 1e-4, u
    from pxr import Usd, UsdGeom  # the layer shows the asset at its size and upright

    a, b = Usd.Stage.Open(str(asset)), Usd.Stage.Open(str(out))
    assert UsdGeom.GetStageUpAxis(a) == UsdGeom.Tokens.z      # Blender's export: Z up, so the fallback (Y) would differ
    assert (UsdGeom.GetStageMetersPerUnit(b), UsdGeom.GetStageUpAxis(b)) == \
        (UsdGeom.GetStageMetersPerUnit(a), UsdGeom.GetStageUpAxis(a))


# ------------------------------------------------------------------------------------------ bad input
def test_no_face_shapes_two_heads_and_the_cli(tmp_path, chars, arkit_rig):
    plain, *_ = _tiny(tmp_path, "plain")
    data = plain.read_bytes()
    n = struct.unpack_from("<I", data, 12)[0]
    js = json.loads(data[20:20 + n])
    del js["meshes"][0]["primitives"][0]["targets"]
    del js["meshes"][0]["extras"]
    flat = _glb(tmp_path / "flat.glb", js, data[20 + n + 8:])
    with pytest.raises(MissingShapeError, match="no face shapes.*character shapes"):
        load_character(flat)
    # two copies of one head side by side: two heads
    two = tmp_path / "two.glb"
    js2 = json.loads(json.dumps(json.loads(data[20:20 + n])))
    js2["nodes"][0]["name"] = "Root"                     # no head joint to tell which head is the character's
    js2["nodes"].append({"name": "face2", "mesh": 0, "translation": [1.0, 0, 0]})
    js2["scenes"][0]["nodes"].append(2)
    _glb(two, js2, data[20 + n + 8:])
    with pytest.raises(InvalidDataError, match="--mesh"):
        load_character(two, find=False)
    assert load_character(two, find=False, mesh="face2").face_meshes()[0] == 1
    run = [sys.executable, "-m", "faceretarget.cli._main"]
    r = subprocess.run(run + ["character", "inspect", str(flat)], capture_output=True, text=True, timeout=120)
    assert r.returncode == 2 and "no face shapes" in r.stderr and "Traceback" not in r.stderr
    r = subprocess.run(run + ["animate", str(chars / "video.mp4"), "--character", str(plain), "--out",
                              str(tmp_path / "x.vrm")], capture_output=True, text=True, timeout=120)
    assert r.returncode == 2


def test_a_written_take_with_a_head_node_off_the_origin_reads_back_as_a_character(tmp_path, arkit_rig):
    """write_glb's ``head`` node at a pivot off the origin is the file's only joint: its head region (where face
    shapes count) must still hold the face, not the 1 cm a lone joint's skeleton spans."""
    from scipy.spatial.transform import Rotation

    T = 10
    w = np.zeros((T, arkit_rig.n_shapes))
    w[:, arkit_rig.names.index("jawOpen")] = np.linspace(0, 1, T)
    q = Rotation.from_euler("y", np.linspace(0, 10, T)[:, None], degrees=True).as_quat()
    pivot = (0.0, -0.0086, 0.0412)                       # the face's centre, 4 cm from the origin
    path = write_glb(tmp_path / "take.glb", arkit_rig, w, np.arange(T) / 30.0, head=HeadPose(q), head_pivot=pivot)
    ch = load_character(path, find=False)
    assert ch.face_meshes() == [0] and ch.meshes[0].n_shapes == arkit_rig.n_shapes
    assert np.allclose(ch.joint("head").position, pivot, atol=1e-6)


def test_character_inspect_cli(tmp_path, chars):
    pytest.importorskip("mediapipe")
    pic = tmp_path / "check.png"
    r = subprocess.run([sys.executable, "-m", "faceretarget.cli._main", "character", "inspect",
                        str(chars / "valid" / "Black_M_2_Busi.glb"), "--out", str(pic), "--json"],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    rep = json.loads(r.stdout.strip().splitlines()[-1])
    assert rep["face_meshes"] == ["H_DDS_HighRes", "h_TeethDown"] and rep["joints"]["head"] == "Head"
    assert len(rep["drive"]) == 58 and "mouth" in rep["regions"]
    from PIL import Image

    with Image.open(pic) as im:
        assert im.size == (512, 512)


@pytest.mark.parametrize("version", ["0", "1"])
def test_vrm_read_driven_and_written_back(tmp_path, chars, take, version):
    """VRM 0.x (facing -Z) and 1.0: the humanoid map gives the joints, the front is the file's, the
    animation is written back into a .vrm that three.js plays (with three-vrm: every target its expressions
    do not bind)."""
    src = make_vrm(chars / "valid" / "Black_M_2_Busi.glb", tmp_path / f"busi{version}.vrm", version,
                   {"aa": "h_expressions.AE_AA_h", "oh": "h_expressions.UH_OO_h", "ih": "h_expressions.TD_I_h",
                    "blinkLeft": "h_expressions.LeyeClose_h", "lookUp": "h_expressions.LbrowUp_h"})
    ch = read_character(src)
    assert ch.format == f"vrm{version}" and ch.named_roles["head"] == ch.roles["head"]
    assert np.allclose(ch.front, [0, 0, -1] if version == "0" else [0, 0, 1])
    assert set(ch.expressions) == {"aa", "oh", "ih", "blinkLeft", "lookUp"}
    out = tmp_path / f"out{version}.vrm"
    res = animate(take, src, out=out, shapes="all")            # the raw morph targets: a .vrm alone
    assert res.mouth_corr >= 0.85 and not out.with_suffix(".vrma").exists()     # as the .glb test
    assert checks.kept(src, out)["ok"]
    tools = _tools("three", "@pixiv/three-vrm", "@pixiv/three-vrm-animation")
    if tools:
        w = checks.written_gltf(out)
        plain = checks.three_checks(out, "faceretarget", w["weights"], w["times"], w["head_node"], w["head_keys"],
                                    max_times=8)
        assert plain["ok"], plain
    # through the expressions (the default for a VRM): the same animation as a .vrma for VRM runtimes
    out = tmp_path / f"expr{version}.vrm"
    res = animate(take, src, out=out)
    assert res.drive.choice.basis == "VRM expressions" and set(res.names) == {"aa", "oh", "ih", "blinkLeft"}
    assert res.drive.choice.rest == {"set by the VRM look-at": ["lookUp"]}
    assert out.with_suffix(".vrma").is_file()
    if tools:
        w = checks.written_gltf(out)
        vrm = checks.three_checks(out, "faceretarget", w["weights"], w["times"], w["head_node"], w["head_keys"],
                                  vrma=out.with_suffix(".vrma"), max_times=8)
        assert vrm["ok"], vrm


def test_gltf_json_copy_keeps_the_files_where_they_are(tmp_path, chars):
    """A .gltf written back: the JSON beside the binary chunk it came from and NAME.anim.bin, read whole
    again with the same meshes and the new animation."""
    src = chars / "valid" / "Black_M_2_Busi.glb"
    ch = read_character(src)
    chans = channels(ch)
    T = 5
    W = np.linspace(0, 1, T)[:, None] * np.ones((1, len(chans)))
    out = tmp_path / "copy" / "busi.gltf"
    out.parent.mkdir()
    write_character_animation(out, ch, chans, W, np.arange(T) / 25.0)
    assert (out.parent / "busi.bin").is_file() and (out.parent / "busi.anim.bin").is_file()
    back = read_character(out)
    assert [m.name for m in back.meshes] == [m.name for m in ch.meshes]
    np.testing.assert_allclose(back.meshes[0].mesh.vertices, ch.meshes[0].mesh.vertices, atol=1e-7)
    from faceretarget.io import GltfDocument

    doc = GltfDocument(out)
    anim = doc.json["animations"][-1]
    w = doc.accessor(anim["samplers"][0]["output"]).reshape(T, -1)
    np.testing.assert_allclose(w[:, 0], W[:, 0], atol=1e-7)
