"""One head pose: every producer fills a HeadPose the same way, and a known nod and turn comes out
of every writer with the same sign and size.

The known motion, in the package's frame (+Y up, +Z forward out of the face, +X the character's
left): frame 0 at rest, frame 1 a nod down by 10 degrees, frame 2 a turn to the character's left by
20 degrees, frame 3 both (turn, then nod).  Geometrically: after the nod the face direction (+Z)
points down (y < 0) by 10 degrees; after the turn it points to the character's left (x > 0) by 20.
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from faceretarget.headpose import HeadPose, mirror_yxz
from faceretarget.io import (
    read_bvh,
    read_bvh_head,
    read_glb_head,
    read_livelinkface,
    read_marker_head,
    read_smplx_head,
    write_head_motion,
)
from faceretarget.performance import Performance

YPR_DEG = np.array([[0.0, 0.0, 0.0], [0.0, 10.0, 0.0], [20.0, 0.0, 0.0], [20.0, 10.0, 0.0]])  # Y-X-Z, degrees
KNOWN = Rotation.from_euler("YXZ", YPR_DEG, degrees=True)


def _face_direction(R: np.ndarray) -> np.ndarray:
    return np.einsum("tij,j->ti", R, [0.0, 0.0, 1.0])


def assert_known_motion(pose: HeadPose, atol_deg: float = 1e-6) -> None:
    """The pose is the known nod and turn: same rotations, and the face looks where it should."""
    assert pose.n_frames == 4 and pose.valid.all()
    rel = pose.rotation * KNOWN.inv()
    assert np.degrees(rel.magnitude()).max() < atol_deg
    f = _face_direction(pose.as_matrix())
    assert np.allclose(f[0], [0, 0, 1], atol=1e-6)
    assert f[1, 1] < 0 and np.degrees(np.arcsin(-f[1, 1])) == pytest.approx(10.0, abs=max(atol_deg, 1e-6))
    assert f[2, 0] > 0 and np.degrees(np.arctan2(f[2, 0], f[2, 2])) == pytest.approx(20.0, abs=max(atol_deg, 1e-6))


# ---------------------------------------------------------------------------------------- producers
def test_producer_livelinkface_reader(tmp_path):
    """Live Link Face's HeadYaw/HeadPitch/HeadRoll: radians, pitch positive chin up."""
    from faceretarget.io._livelinkface import EYE_COLUMNS, HEAD_COLUMNS, LLF_NAMES

    llf = np.radians(YPR_DEG * [1, -1, 1])              # a nod down is a negative (chin-down) HeadPitch
    header = ",".join(("Timecode", "BlendShapeCount") + LLF_NAMES + HEAD_COLUMNS + EYE_COLUMNS)
    rows = [f"00:00:00:{i:02d}.000,61," + ",".join(["0"] * 52 + [f"{x:.12f}" for x in llf[i]] + ["0"] * 6)
            for i in range(4)]
    p = tmp_path / "take.csv"
    p.write_text(header + "\n" + "\n".join(rows) + "\n")
    assert_known_motion(read_livelinkface(p, timecode_rate=60).head, atol_deg=1e-8)


def test_producer_capture_matrices():
    """MediaPipe's facial transformation matrices (canonical face -> camera), scaled, cm."""
    from faceretarget.capture import pose_from_matrices

    M = np.zeros((5, 4, 4))
    M[:4, :3, :3] = KNOWN.as_matrix() * 1.3                # MediaPipe's matrices may carry a scale
    M[:4, :3, 3] = [1.0, 2.0, -40.0]
    M[:4, 3, 3] = 1.0
    M[4] = np.nan                                          # a frame without a face
    pose = pose_from_matrices(M)
    assert not pose.valid[4]
    assert_known_motion(pose[:4])
    np.testing.assert_allclose(pose.translation[:4], [[0.01, 0.02, -0.40]] * 4)   # metres


def test_producer_bvh_reader(tmp_path):
    """A Neck > Neck1 > Head chain with the motion on the Head joint's Y-X-Z channels (degrees, cm); its
    position channels hold the full local translation (the offset), as exporters write them."""
    lines = ["HIERARCHY", "ROOT Neck", "{", "OFFSET 0 0 0", "CHANNELS 3 Zrotation Xrotation Yrotation",
             "JOINT Neck1", "{", "OFFSET 0 5 0", "CHANNELS 3 Zrotation Xrotation Yrotation", "JOINT Head", "{",
             "OFFSET 0 5 0", "CHANNELS 6 Xposition Yposition Zposition Yrotation Xrotation Zrotation",
             "End Site", "{", "OFFSET 0 10 0", "}", "}", "}", "}", "MOTION", "Frames: 4", "Frame Time: 0.033333"]
    for ypr in YPR_DEG:
        lines.append(" ".join(["0"] * 6 + ["0", "5", "0"] + [f"{x:.9f}" for x in ypr]))
    p = tmp_path / "head.bvh"
    p.write_text("\n".join(lines) + "\n")
    take = read_bvh_head(p)
    assert_known_motion(take.head)
    np.testing.assert_allclose(take.head.translation, 0.0, atol=1e-12)


def test_producer_smplx_reader(tmp_path):
    poses = np.zeros((4, 165))
    poses[:, 45:48] = KNOWN.as_rotvec()                   # the head joint; the neck at rest
    np.savez(tmp_path / "smplx.npz", poses=poses, mocap_frame_rate=30)
    assert_known_motion(read_smplx_head(tmp_path / "smplx.npz").head, atol_deg=1e-8)


def test_producer_rigid_markers():
    """Markers on a head (mm, the package's axes) moved by the known rotation about their centroid."""
    rng = np.random.default_rng(0)
    cap = rng.normal(0, 60, (6, 3))
    cap -= cap.mean(axis=0)
    X = np.einsum("tij,pj->tpi", KNOWN.as_matrix(), cap) + [0.0, 1500.0, 0.0]
    take = read_marker_head(Performance.from_points(X, fps=30.0, unit="mm"))
    assert_known_motion(take.head)


def test_producer_rigid_aligner_in_other_axes():
    """A Z-up capture (+Y forward, +X to the performer's right): the aligner's ``axes`` brings the
    pose into the package's frame."""
    from faceretarget.numerics import RigidAligner

    rng = np.random.default_rng(1)
    cap = rng.normal(0, 60, (8, 3))
    X = np.einsum("tij,pj->tpi", KNOWN.as_matrix(), cap)     # package axes
    A = np.array([[-1.0, 0, 0], [0, 0, 1], [0, 1, 0]])      # capture -> package (its own inverse)
    res = RigidAligner(subset=list(range(8)), reference=0, axes=A).fit_transform(
        Performance.from_points(X @ A, fps=30.0, unit="mm"))
    assert_known_motion(res.take.head)


def test_producer_head_motion_synthesis():
    """The database's mean pose is the synthesis' rest: a database of a head held in the known
    pose synthesizes exactly that pose at amplitude 0."""
    from faceretarget.headmotion import HeadMotionDatabase

    sr, fps, secs = 16000, 30.0, 6.0
    t = np.arange(int(secs * sr)) / sr
    voiced = (np.sin(2 * np.pi * 1.5 * t) > -0.3).astype(float)
    audio = (0.3 * voiced * np.sin(2 * np.pi * np.cumsum(140 + 20 * np.sin(t)) / sr)).astype(np.float32)
    n = int(secs * fps)
    held = Rotation.from_euler("YXZ", np.repeat(YPR_DEG[3:], n, axis=0), degrees=True)
    take = Performance(np.arange(n) / fps, fps, head=HeadPose.from_rotation(held), audio=audio, audio_rate=sr,
                       source="held")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        db = HeadMotionDatabase(mirror=False).fit([take])
        out = db.transform(audio[: 2 * sr], sr, amplitude=0.0).take.head
    np.testing.assert_allclose(out.to_euler("YXZ", degrees=True), np.broadcast_to(YPR_DEG[3], (out.n_frames, 3)),
                               atol=1e-9)


# ---------------------------------------------------------------------------------------- writers
@pytest.fixture
def known_take():
    return Performance(np.arange(4) / 30.0, 30.0, head=HeadPose.from_rotation(KNOWN, np.zeros((4, 3))),
                       source="known")


def test_writer_livelinkface(tmp_path, known_take):
    p = write_head_motion(tmp_path / "head.csv", known_take)
    lines = p.read_text().splitlines()
    cols = lines[0].split(",")
    vals = np.array([[float(x) for x in line.split(",")[2:]] for line in lines[1:]])
    yaw, pitch = vals[:, cols.index("HeadYaw") - 2], vals[:, cols.index("HeadPitch") - 2]
    np.testing.assert_allclose(np.degrees(yaw), [0, 0, 20, 20], atol=1e-7)
    np.testing.assert_allclose(np.degrees(pitch), [0, -10, 0, -10], atol=1e-7)   # chin up positive
    assert_known_motion(read_livelinkface(p).head, atol_deg=1e-7)


def test_writer_bvh(tmp_path, known_take):
    b = read_bvh(write_head_motion(tmp_path / "head.bvh", known_take))
    ch = b.joints[0].channels
    rot = b.motion[:, [ch.index("Yrotation"), ch.index("Xrotation"), ch.index("Zrotation")]]
    np.testing.assert_allclose(rot, YPR_DEG, atol=1e-6)                        # nod down = +Xrotation
    assert_known_motion(read_bvh_head(b, joints=("Head",)).head, atol_deg=1e-5)


def test_writer_gltf(tmp_path, known_take):
    _, pose = read_glb_head(write_head_motion(tmp_path / "head.glb", known_take))
    assert_known_motion(pose, atol_deg=1e-4)                                   # float32 in the file


def test_mirror_turns_the_other_way():
    m = HeadPose.from_rotation(KNOWN).mirrored()
    f = _face_direction(m.as_matrix())
    assert f[2, 0] < 0 and f[1, 1] < 0                      # the turn flips, the nod stays
    np.testing.assert_allclose(mirror_yxz(*mirror_yxz(YPR_DEG))[0], YPR_DEG)
