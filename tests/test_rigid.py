"""Rigid head-motion removal: known synthetic motion, subset choice, missing markers, real takes."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from faceretarget.errors import DataWarning, InvalidDataError, NotFittedError
from faceretarget.io import read_c3d
from faceretarget.numerics import RigidAligner, fit_rigid, select_rigid_markers
from faceretarget.performance import Performance

N_RIGID = 6


def _synthetic(T=120, seed=0, noise=0.002):
    """A head of 6 rigid markers and 6 facial markers moving on their own, under known head motion.

    Head coordinates are frame 0's positions (frame 0 has the identity pose).
    Returns the take, the true (T, 3, 3) rotations, (T, 3) translations of ``x = R h + t``, the
    head-coordinate points and the facial (non-rigid) offsets.
    """
    rng = np.random.default_rng(seed)
    head = np.concatenate([rng.normal(size=(N_RIGID, 3)) * [60, 50, 40] + [140, 760, 40],  # skull
                           rng.normal(size=(6, 3)) * [40, 30, 20] + [140, 680, 60]])  # face
    s = np.linspace(0, 1, T)
    rotvec = np.c_[0.25 * np.sin(6 * s), 0.15 * np.sin(9 * s + 1), 0.1 * np.sin(4 * s + 2)]
    rotvec -= rotvec[0]
    R = Rotation.from_rotvec(rotvec).as_matrix()
    t = np.c_[20 * np.sin(5 * s), 8 * np.cos(7 * s), 15 * s]
    t -= t[0]
    face = np.zeros((T, head.shape[0], 3))
    face[:, N_RIGID:] = rng.normal(size=(1, 6, 3)) * np.sin(np.outer(s * 20, np.ones(6)))[..., None] * 6.0
    face[0] = 0.0
    h = head + face + rng.normal(size=face.shape) * noise  # tiny non-rigid jitter on every marker
    h[0] = head
    X = np.einsum("tij,tpj->tpi", R, h) + t[:, None]
    labels = [f"skull{i}" for i in range(N_RIGID)] + [f"face{i}" for i in range(6)]
    perf = Performance(times=np.arange(T) / 60.0, fps=60.0, points=X, labels=labels, unit="mm", source="synth")
    return perf, R, t, h


def _angle_deg(Ra, Rb):
    rel = np.einsum("tji,tjk->tik", Ra, Rb)
    return np.degrees(np.linalg.norm(Rotation.from_matrix(rel).as_rotvec(), axis=1))


@pytest.mark.parametrize("reference", ["median", "first", 0])
def test_recovers_known_motion(reference):
    perf, R, t, h = _synthetic()
    al = RigidAligner(n_auto=N_RIGID, reference=reference)
    res = al.fit_transform(perf)
    out = res.take
    assert al.subset_.tolist() == list(range(N_RIGID))  # the skull markers, not the moving face
    assert al.subset_labels_ == [f"skull{i}" for i in range(N_RIGID)]
    assert _angle_deg(res.rotations, R).max() < 0.1
    # translations is the move of the subset centroid c (origin-free: 0.1 degree at the capture
    # origin 0.8 m away would be 1.4 mm)
    c = al.center_
    assert np.abs(res.translations - (t + np.einsum("tij,j->ti", R, c) - c)).max() < 0.01
    M = res.pose_matrices()
    np.testing.assert_allclose(M[:, :3, :3], res.rotations)
    world = np.einsum("tij,pj->tpi", M[:, :3, :3], h[0, :N_RIGID]) + M[:, None, :3, 3]
    assert np.abs(world - perf.points[:, :N_RIGID]).max() < 0.01
    # head coordinates: skull markers still, facial markers keep only their own motion
    assert np.abs(out.points - h).max() < 0.01
    np.testing.assert_allclose(out.head.to_euler("YXZ", degrees=True),
                               Rotation.from_matrix(R).as_euler("YXZ", degrees=True), atol=0.1)
    np.testing.assert_allclose(out.head.translation, res.translations / 1000.0)  # mm -> m
    assert out.labels == perf.labels and out.unit == "mm" and out.fps == 60.0
    # the residual reports the jitter of the subset (0.002 mm per coordinate)
    assert res.residual.shape == (perf.n_frames,)
    assert np.median(res.residual[1:]) < 0.01
    assert "RMS residual median" in res.report("mm")


def test_head_rotation_angles_name_the_axes():
    _, _, _, h = _synthetic()
    still = np.repeat(h[:1], 4, axis=0)
    moved = still.copy()
    for k, axis in enumerate("YXZ", start=1):  # yaw about Y (up), pitch about X, roll about Z
        moved[k] = still[k] @ Rotation.from_euler(axis, 10, degrees=True).as_matrix().T
    out = RigidAligner(subset=list(range(N_RIGID)), reference=0).fit_transform(
        Performance.from_points(moved, fps=60)).take
    np.testing.assert_allclose(out.head.to_euler("YXZ", degrees=True),
                               [[0, 0, 0], [10, 0, 0], [0, 10, 0], [0, 0, 10]], atol=1e-9)
    # a Z-up capture (+Y forward, +X right) gives the same pose in the package's axes
    A = np.array([[-1.0, 0, 0], [0, 0, 1], [0, 1, 0]])             # capture -> package axes
    zup = Performance.from_points(moved @ A, fps=60)                # A is its own inverse
    out_z = RigidAligner(subset=list(range(N_RIGID)), reference=0, axes=A).fit_transform(zup).take
    np.testing.assert_allclose(out_z.head.to_euler("YXZ", degrees=True), out.head.to_euler("YXZ", degrees=True),
                               atol=1e-9)


def test_user_subset_by_label_or_index_and_other_take():
    perf, R, t, h = _synthetic()
    by_label = RigidAligner(subset=["skull0", "skull2", "skull3", "skull5"]).fit(perf)
    by_index = RigidAligner(subset=[0, 2, 3, -7]).fit(perf)  # -7 is marker 5 of 12
    assert by_label.subset_.tolist() == by_index.subset_.tolist() == [0, 2, 3, 5]
    np.testing.assert_allclose(by_label.transform(perf).rotations, by_index.transform(perf).rotations)
    # a take with the markers in another order is matched by label
    order = np.random.default_rng(3).permutation(perf.points.shape[1])
    other = Performance(perf.times, perf.fps, points=perf.points[:, order],
                        labels=[perf.labels[i] for i in order], unit="mm")
    res = by_label.transform(other)
    np.testing.assert_allclose(res.rotations, by_index.transform(perf).rotations, atol=1e-9)
    np.testing.assert_allclose(res.take.points, h[:, order], atol=0.03)  # 4 markers: noisier


def test_missing_markers():
    perf, R, t, h = _synthetic()
    X = perf.points.copy()
    X[20:30, 1] = np.nan  # still 5 of 6 rigid markers: solved with those
    X[40:44, [0, 1, 2, 3]] = np.nan  # only 2 rigid markers: no pose
    X[50, 8] = np.nan  # a facial marker gap stays a gap
    gappy = Performance(perf.times, perf.fps, points=X, labels=perf.labels, unit="mm", source="gappy.c3d")
    al = RigidAligner(n_auto=N_RIGID)
    with pytest.warns(DataWarning, match=r"gappy.c3d: 4 frame\(s\) have fewer than 3 usable of the 6 rigid "
                                         r"markers, frame\(s\) 40-43"):
        res = al.fit_transform(gappy)
    out = res.take
    assert al.subset_.tolist() == list(range(N_RIGID))
    good = np.ones(perf.n_frames, bool)
    good[40:44] = False
    assert np.isnan(res.rotations[~good]).all() and np.isnan(res.residual[~good]).all()
    assert np.isnan(out.points[~good]).all() and not out.head.valid[~good].any() and out.head.valid[good].all()
    assert _angle_deg(res.rotations[good], R[good]).max() < 0.1
    c = al.center_
    d_true = t + np.einsum("tij,j->ti", R, c) - c
    assert np.abs(res.translations[good] - d_true[good]).max() < 0.01
    assert res.n_used[25] == 5 and res.n_used[41] == 2
    finite = np.isfinite(X).all(axis=2) & good[:, None]
    assert np.abs(out.points[finite] - h[finite]).max() < 0.01
    assert np.isnan(out.points[50, 8]).all()


def test_no_complete_frame():
    perf, R, t, h = _synthetic(T=60)
    X = perf.points.copy()
    for k in range(len(X)):  # every frame misses one rigid marker
        X[k, k % N_RIGID] = np.nan
    gappy = Performance(perf.times, perf.fps, points=X, labels=perf.labels)
    res = RigidAligner(subset=list(range(N_RIGID))).fit_transform(gappy)  # median from the per-marker median
    assert np.isfinite(res.rotations).all()
    assert np.median(res.residual) < 0.01
    # head coordinates are now the per-marker median of the raw take, not frame 0: compare the
    # rotations from frame 0, R[t] R[0]^T, which do not depend on them
    rel_est = np.einsum("tij,kj->tik", res.rotations, res.rotations[0])
    rel_true = np.einsum("tij,kj->tik", R, R[0])
    assert _angle_deg(rel_est, rel_true).max() < 0.1
    with pytest.raises(InvalidDataError, match="no frame has every rigid subset marker"):
        RigidAligner(subset=list(range(N_RIGID)), reference="first").fit(gappy)


def test_select_rigid_markers_prefers_rigid():
    perf, *_ = _synthetic()
    assert select_rigid_markers(perf.points, 4).tolist() == [0, 1, 2, 3] or set(
        select_rigid_markers(perf.points, 4).tolist()) <= set(range(N_RIGID))
    # a marker mostly missing is not a candidate
    X = perf.points.copy()
    X[: int(0.7 * len(X)), 2] = np.nan
    assert 2 not in select_rigid_markers(X, 5).tolist()
    with pytest.raises(InvalidDataError, match="cannot choose 2 rigid markers"):
        select_rigid_markers(X, 2)


def test_fit_rigid_is_reflection_safe_and_weighted():
    rng = np.random.default_rng(5)
    A = rng.normal(size=(8, 3))
    mirrored = A * [-1.0, 1.0, 1.0]
    R, t, rms, n = fit_rigid(A, mirrored[None])
    assert np.linalg.det(R[0]) == pytest.approx(1.0)
    assert rms[0] > 0.1  # a mirror image is not a rigid motion
    # a zero weight removes an outlier
    Rt = Rotation.from_euler("xyz", [10, -20, 5], degrees=True).as_matrix()
    B = A @ Rt.T + [1.0, 2.0, 3.0]
    B[0] += 50.0
    w = np.ones(8)
    w[0] = 0
    R, t, rms, n = fit_rigid(A, B[None], w)
    np.testing.assert_allclose(R[0], Rt, atol=1e-12)
    np.testing.assert_allclose(t[0], [1, 2, 3], atol=1e-12)
    assert n[0] == 7 and rms[0] < 1e-12
    # collinear markers: no pose
    line = np.outer(np.arange(4.0), [1, 2, 3])
    R, *_ = fit_rigid(line, line[None])
    assert np.isnan(R).all()


def test_errors():
    perf, *_ = _synthetic(T=10)
    with pytest.raises(InvalidDataError, match="rigid subset marker 'brow' is not in the take"):
        RigidAligner(subset=["skull0", "skull1", "brow"]).fit(perf)
    with pytest.raises(InvalidDataError, match="at least 3 markers"):
        RigidAligner(subset=["skull0", "skull1"]).fit(perf)
    with pytest.raises(InvalidDataError, match="index 40 is outside"):
        RigidAligner(subset=[0, 1, 40]).fit(perf)
    X = perf.points.copy()
    X[:, 2] = X[:, 0] + 2 * (X[:, 1] - X[:, 0])  # on the line through markers 0 and 1
    with pytest.raises(InvalidDataError, match="lie on one line"):
        RigidAligner(subset=[0, 1, 2]).fit(Performance(perf.times, perf.fps, points=X))
    w = Performance.from_weights(np.zeros((3, 1)), ["jawOpen"], fps=30)
    with pytest.raises(InvalidDataError, match="needs 3D marker points, this take holds weights"):
        RigidAligner().fit(w)
    with pytest.raises(NotFittedError, match="call fit"):
        RigidAligner().transform(perf)
    with pytest.raises(InvalidDataError, match="reference must be"):
        RigidAligner(reference="mean").fit(perf)
    other = Performance(perf.times, perf.fps, points=perf.points, labels=[f"x{i}" for i in range(12)])
    with pytest.raises(InvalidDataError, match="skull0, skull1"):
        RigidAligner(n_auto=6).fit(perf).transform(other)


# Median RMS residual of the automatically chosen 8-marker subset, measured on the shared takes:
# Jaw 0.34 mm, Cheeks 0.35, Eyebrows 0.27, Nose 0.30 (95th percentiles 0.54, 1.16, 0.49, 1.40 mm).
@pytest.mark.parametrize("name", ["Jaw", "Cheeks", "Eyebrows", "Nose"])
def test_real_takes(data_dir, name):
    perf = read_c3d(data_dir / "facial-mocap" / f"{name}.c3d")
    al = RigidAligner()
    res = al.fit_transform(perf)
    out = res.take
    print(f"{name}: {res.report('mm')}")
    r = res.residual
    assert np.isfinite(r).all() and al.subset_.size == 8
    assert np.median(r) < 0.45
    assert np.percentile(r, 95) < 1.6
    # the head moved by centimetres and a few degrees; in head coordinates the markers move less
    assert np.ptp(res.translations, axis=0).max() > 5.0               # mm
    assert 1.0 < np.ptp(out.head.to_euler("YXZ", degrees=True), axis=0).max() < 20.0
    assert np.std(out.points, axis=0).mean() < 0.9 * np.std(perf.points, axis=0).mean()
    sub = out.points[:, al.subset_]
    assert np.median(np.linalg.norm(sub - np.median(sub, axis=0), axis=2)) < 0.5
