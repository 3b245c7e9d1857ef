"""Keyshape selection methods (Chuang Sec. 3.3, EVALUATION.md P2) and the artist export round trip."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from scipy.optimize import nnls
from scipy.spatial import ConvexHull

from faceretarget.errors import InvalidDataError, MissingShapeError, TopologyError
from faceretarget.io import read_keyshapes, read_obj, write_keyshapes, write_obj
from faceretarget.mesh import Mesh
from faceretarget.numerics._selection import (
    SELECTION_METHODS,
    hull_selection,
    kmeans_selection,
    nnls_greedy,
    nnls_greedy_path,
    pca_extrema,
    reconstruction_error,
    select_keyshapes,
)
from faceretarget.performance import Performance

METHODS = ["pca-extrema", "hull", "kmeans2", "kmeans3", "nnls-greedy"]


def structured_take(T: int = 240, D: int = 30, n_basis: int = 5, seed: int = 0) -> np.ndarray:
    """Smooth non-negative activations of a few localised 'expression' displacements, plus noise."""
    rng = np.random.default_rng(seed)
    basis = rng.normal(size=(n_basis, D)) * (rng.random((n_basis, D)) < 0.4)
    t = np.arange(T)[:, None]
    act = np.maximum(0.0, np.sin(2 * np.pi * t / rng.uniform(40, 120, n_basis) + rng.uniform(0, 6, n_basis)))
    act *= rng.uniform(0.5, 1.5, n_basis)
    return act @ basis + 0.02 * rng.normal(size=(T, D))


@pytest.fixture(scope="module")
def take() -> np.ndarray:
    return structured_take()


def test_registry_names():
    assert set(METHODS) <= set(SELECTION_METHODS)


@pytest.mark.parametrize("method", METHODS)
def test_methods_return_distinct_valid_deterministic(method, take):
    for k in (1, 2, 5, 13) if method != "nnls-greedy" else (1, 2, 6):   # (the greedy path is tested below)
        a = select_keyshapes(take, k, method)
        b = select_keyshapes(take, k, method)
        assert a.shape == (k,) and np.issubdtype(a.dtype, np.integer)
        assert len(set(a.tolist())) == k
        assert a.min() >= 0 and a.max() < len(take)
        np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize("method", METHODS)
def test_methods_on_duplicate_frames_still_distinct(method):
    X = np.repeat(np.eye(3), 4, axis=0)          # 12 frames, only 3 distinct
    idx = select_keyshapes(X, 6, method)
    assert len(set(idx.tolist())) == 6


def test_bad_inputs():
    X = structured_take(50, 8)
    with pytest.raises(InvalidDataError, match="unknown keyshape selection method"):
        select_keyshapes(X, 3, "nope")
    for m in METHODS:
        with pytest.raises(InvalidDataError, match="cannot choose"):
            select_keyshapes(X, 51, m)
    X[3, 2] = np.nan
    with pytest.raises(InvalidDataError, match="frame 3"):
        select_keyshapes(X, 3, "hull")


def test_pca_extrema_sets_are_nested_so_error_never_rises(take):
    full = pca_extrema(take, 20)
    errs = []
    for k in range(1, 21):
        np.testing.assert_array_equal(pca_extrema(take, k), full[:k])
        errs.append(reconstruction_error(take, full[:k]))
    assert np.all(np.diff(errs) <= 1e-12 * errs[0])


def test_hull_picks_hull_vertices_of_a_2d_blob():
    rng = np.random.default_rng(3)
    X = rng.normal(size=(400, 2)) * [3.0, 1.0]
    hv = set(ConvexHull(X).vertices.tolist())
    n = len(hv)
    for k in (3, 5, n):
        idx = hull_selection(X, k)
        assert set(idx.tolist()) <= hv
    assert set(hull_selection(X, n).tolist()) == hv
    # pruned to k, the polygon keeps nearly the largest area any k hull vertices span
    ring = ConvexHull(X).vertices

    def area(ids):
        p = X[[i for i in ring if i in set(ids)]]           # in hull order
        return 0.5 * abs(np.dot(p[:, 0], np.roll(p[:, 1], -1)) - np.dot(p[:, 1], np.roll(p[:, 0], -1)))

    from itertools import combinations

    for k in (3, 4, 5):
        best = max(area(c) for c in combinations(ring.tolist(), k))
        assert area(hull_selection(X, k).tolist()) >= 0.9 * best
    # more than the hull: the outer hull first, then the next layer
    idx = hull_selection(X, n + 3)
    assert set(idx[:n].tolist()) == hv and not set(idx[n:].tolist()) & hv


def test_hull_of_collinear_frames():
    X = np.linspace(0, 1, 20)[:, None] * np.array([[1.0, 2.0, 3.0]])
    idx = hull_selection(X, 2)
    assert set(idx.tolist()) == {0, 19}


def test_kmeans_centres_snap_to_real_frames():
    rng = np.random.default_rng(5)
    centres = np.array([[0.0, 0.0, 0.0], [10.0, 0.0, 0.0], [0.0, 10.0, 0.0], [0.0, 0.0, 10.0]])
    lab = np.repeat(np.arange(4), 50)
    X = centres[lab] + rng.normal(size=(200, 3))
    for dims in (2, 3):
        idx = kmeans_selection(X, 4, dims)
        assert sorted(lab[idx].tolist()) == [0, 1, 2, 3]   # one frame per blob
    idx = kmeans_selection(X, 4, 3)
    for i in idx:                                       # the frame nearest its blob's mean
        members = np.flatnonzero(lab == lab[i])
        mean = X[members].mean(axis=0)
        assert i == members[np.argmin(np.linalg.norm(X[members] - mean, axis=1))]
    np.testing.assert_array_equal(kmeans_selection(X, 4, 3, seed=1), kmeans_selection(X, 4, 3, seed=1))


def test_reconstruction_error_matches_scipy_per_frame(take):
    keys = pca_extrema(take, 6)
    K = take[keys].T
    r = np.array([nnls(K, x)[1] for x in take])
    assert reconstruction_error(take, keys) == pytest.approx(np.sqrt((r**2).sum() / take.size), rel=1e-9)
    assert reconstruction_error(take, np.arange(len(take))) < 1e-9
    # the neutral is an implicit key: a frame opposite every key reconstructs as zero
    X = np.array([[1.0, 0.0], [-1.0, 0.0]])
    assert reconstruction_error(X, [0]) == pytest.approx(np.sqrt(1.0 / 4))


def test_nnls_greedy_beats_pca_extrema_at_every_k_synthetic(take):
    ks = range(2, 13)
    path = nnls_greedy_path(take, max(ks))
    solo = nnls_greedy_path(take, max(ks), guard=False)
    pca = pca_extrema(take, max(ks))
    errs = []
    for k in ks:
        e_new = reconstruction_error(take, path[k - 1])
        e_pca = reconstruction_error(take, pca[:k])
        assert e_new <= e_pca * (1 + 1e-9), k
        assert reconstruction_error(take, solo[k - 1]) <= e_pca * (1 + 1e-9), k   # on its own too
        errs.append(e_new)
    assert np.all(np.diff(errs) <= 1e-12 * errs[0])          # never rises with k
    np.testing.assert_array_equal(nnls_greedy(take, 7), path[6])


def test_nnls_greedy_never_worse_than_pca_on_noise():
    # unstructured noise, where no method has an edge: the default (guarded) search is still never worse
    rng = np.random.default_rng(0)
    X = rng.normal(size=(120, 4))
    for k in (2, 3, 4):
        assert reconstruction_error(X, nnls_greedy(X, k)) <= reconstruction_error(X, pca_extrema(X, k)) * (1 + 1e-9)


def test_nnls_greedy_on_real_landmarks(data_dir, ict_rig):
    from faceretarget.io import read_livelinkface

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        perf = read_livelinkface(data_dir / "livelinkface" / "MySlate_3_Jason_Millers_iPhone.csv")
    W = ict_rig.map_weights(perf.names, perf.weights, warn=False)
    X = W @ ict_rig.deltas[:, ict_rig.landmarks].reshape(ict_rig.n_shapes, -1)
    path = nnls_greedy_path(X, 10)
    pca = pca_extrema(X, 10)
    for k in range(2, 11):
        assert reconstruction_error(X, path[k - 1]) <= reconstruction_error(X, pca[:k]) * (1 + 1e-9), k


# ------------------------------------------------------------------------------ export
def _points_take(T=30, P=7, seed=1) -> Performance:
    rng = np.random.default_rng(seed)
    pts = rng.normal(size=(T, P, 3)) * 10
    return Performance.from_points(pts, labels=[f"m{j}" for j in range(P)], fps=60, source="markers.c3d")


def test_export_points_and_read_back(tmp_path):
    perf = _points_take()
    frames = [3, 17, 8]
    out = write_keyshapes(perf, frames, tmp_path / "keys", labels=["open", "smile", "frown"])
    names = sorted(p.name for p in out.iterdir())
    assert names == ["contact_sheet.png", "frame_00003.obj", "frame_00008.obj", "frame_00017.obj", "keyshapes.txt",
                     "markers.txt"]
    m = read_obj(out / "frame_00017.obj")
    assert m.n_faces == 0
    np.testing.assert_array_equal(m.vertices, perf.points[17])
    assert "m3" in (out / "frame_00017.obj").read_text()
    from PIL import Image

    with Image.open(out / "contact_sheet.png") as im:
        assert im.size[0] > 200 and im.size[1] > 200
    # the artist's folder: a target neutral plus one shape per frame, same file names
    tgt = tmp_path / "target"
    tgt.mkdir()
    neutral = Mesh.from_triangles(np.random.default_rng(2).normal(size=(5, 3)), np.array([[0, 1, 2], [2, 3, 4]]))
    write_obj(tgt / "neutral.obj", neutral)
    shapes = {f: neutral.vertices + f * 0.01 for f in frames}
    for f, v in shapes.items():
        write_obj(tgt / f"frame_{f:05d}.obj", neutral, v)
    (tgt / "keyshapes.txt").write_text((out / "keyshapes.txt").read_text())
    rig = read_keyshapes(tgt)                   # order and labels from keyshapes.txt
    assert rig.names == ["open", "smile", "frown"]
    assert rig.source_names == ["frame_00003", "frame_00017", "frame_00008"]
    np.testing.assert_allclose(rig.deltas[1], shapes[17] - neutral.vertices)
    rig2 = read_keyshapes(tgt, [8, "open", "frame_00017"])
    assert rig2.names == ["frown", "open", "smile"]
    np.testing.assert_allclose(rig2.deltas[0], shapes[8] - neutral.vertices)


def test_read_target_names_the_missing_frame(tmp_path):
    neutral = Mesh.from_triangles(np.eye(3), np.array([[0, 1, 2]]))
    write_obj(tmp_path / "neutral.obj", neutral)
    write_obj(tmp_path / "frame_00004.obj", neutral)
    with pytest.raises(MissingShapeError, match=r"frame 123 \(frame_00123\.obj\)"):
        read_keyshapes(tmp_path, [4, 123])
    with pytest.raises(MissingShapeError, match="labelled 'smile'"):
        read_keyshapes(tmp_path, ["smile"])
    write_obj(tmp_path / "frame_00005.obj", Mesh(np.zeros((4, 3))))
    with pytest.raises(TopologyError, match="frame 5"):
        read_keyshapes(tmp_path, [4, 5])
    (tmp_path / "neutral.obj").unlink()
    with pytest.raises(MissingShapeError, match="neutral"):
        read_keyshapes(tmp_path, [4])


def test_export_mesh_take(tmp_path):
    mesh = Mesh.from_triangles(np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0.2]]),
                               np.array([[0, 1, 2], [1, 3, 2]]))
    V = mesh.vertices[None] + np.linspace(0, 1, 10)[:, None, None] * [0.0, 0.0, 0.3]
    perf = Performance.from_vertices(V, mesh=mesh, fps=30)
    out = write_keyshapes(perf, np.array([9, 0]), tmp_path / "k", contact_sheet=False)
    m = read_obj(out / "frame_00009.obj")
    assert m.n_faces == 2
    np.testing.assert_allclose(m.vertices, V[9])
    assert not (out / "contact_sheet.png").exists()


def test_export_rejects_bad_input(tmp_path):
    perf = _points_take()
    with pytest.raises(InvalidDataError, match="outside"):
        write_keyshapes(perf, [30], tmp_path / "a")
    with pytest.raises(InvalidDataError, match="more than once"):
        write_keyshapes(perf, [1, 1], tmp_path / "a")
    pts = perf.points.copy()
    pts[2, 4] = np.nan
    with pytest.raises(InvalidDataError, match="frame 2 has a missing point 'm4'"):
        write_keyshapes(Performance.from_points(pts, labels=perf.labels, fps=60), [2], tmp_path / "a")
    w = Performance.from_weights(np.zeros((3, 2)), ["jawOpen", "mouthClose"], fps=30)
    with pytest.raises(InvalidDataError, match="weights"):
        write_keyshapes(w, [0], tmp_path / "a")
    assert not (tmp_path / "a").exists()


def test_pivoted_qr_picks_one_frame_per_direction_and_skips_still_frames():
    from faceretarget.numerics import pivoted_qr

    rng = np.random.default_rng(0)
    dirs = np.eye(6)[:, :5].T * 10                                   # 5 orthogonal motions in 6-D
    X = np.vstack([d * rng.uniform(0.5, 1.0, (20, 1)) + rng.normal(0, 0.05, (20, 6)) for d in dirs])
    X = np.vstack([X, rng.normal(0, 0.01, (30, 6))])                 # still frames: noise only
    sel = pivoted_qr(X, 5)
    assert sorted(np.asarray(sel) // 20) == [0, 1, 2, 3, 4]          # one frame of each direction
    assert (np.asarray(pivoted_qr(X, 8)) < 100).all()                # still frames never chosen
    assert list(pivoted_qr(X, 3)) == list(pivoted_qr(X, 6))[:3]      # nested in k
    # the chosen keys' directions are nearly orthogonal (well conditioned)
    K = X[sel]
    assert np.linalg.cond(K / np.linalg.norm(K, axis=1, keepdims=True)) < 1.5
