"""Non-negative keyshape weights (Chuang Eq. 3.1/3.2) and weight-curve filtering."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from scipy.optimize import lsq_linear, nnls

from faceretarget.datasets import keyshape_problem
from faceretarget.datasets import rom_problem as _rom_problem
from faceretarget.errors import InvalidDataError, MissingDependencyError
from faceretarget.numerics import extremes_removed, filter_cutoff_hz, solve_nnls, temporal_filter


def random_problem(D, N, T, seed):
    rng = np.random.default_rng(seed)
    K = rng.standard_normal((D, N))
    W = np.maximum(rng.standard_normal((T, N)), 0.0)
    return K, W @ K.T + 0.3 * rng.standard_normal((T, D))


def rom_problem(D, N, T, seed, n_basis=51, noise=0.002):
    return _rom_problem(D, N, T, seed, n_basis=n_basis, noise=noise, rom_frames=1500)


def per_frame_nnls(K, F):
    return np.array([nnls(K, f)[0] for f in F])


def check_kkt(K, F, W, upper=None, l2=0.0, l1=0.0, tol=1e-7):
    """w within bounds; gradient >= 0 at 0, <= 0 at the upper bound, 0 in between (relative to |K'f|)."""
    ub = np.inf if upper is None else np.broadcast_to(upper, W.shape)
    g = (W @ K.T - F) @ K + l2 * W + l1
    scale = np.maximum(np.abs(F @ K).max(axis=1, keepdims=True), 1.0)
    assert (W >= 0).all()
    assert (W <= ub).all()
    at0 = W <= 0
    atu = W >= ub
    inside = ~at0 & ~atu
    assert (g[at0] >= -tol * np.broadcast_to(scale, W.shape)[at0]).all()
    assert (g[atu] <= tol * np.broadcast_to(scale, W.shape)[atu]).all()
    assert (np.abs(g[inside]) <= tol * np.broadcast_to(scale, W.shape)[inside]).all()


# ----------------------------------------------------------------------------- plain NNLS vs scipy
@pytest.mark.parametrize("D,N,T,seed", [(204, 10, 300, 0), (204, 40, 300, 1), (123, 84, 200, 2),
                                        (30, 30, 200, 3)])
def test_random_matches_scipy_per_frame(D, N, T, seed):
    K, F = random_problem(D, N, T, seed)
    W = solve_nnls(K, F)
    assert W.shape == (T, N)
    assert np.abs(W - per_frame_nnls(K, F)).max() <= 1e-6
    check_kkt(K, F, W)


@pytest.mark.parametrize("D,N,T,seed", [(204, 40, 400, 4), (204, 83, 200, 5), (123, 84, 200, 6),
                                        (123, 20, 300, 7)])
def test_keyshape_like_matches_scipy_per_frame(D, N, T, seed):
    K, F = keyshape_problem(D, N, T, seed)
    assert np.linalg.cond(K) > 20                 # correlated columns, as with real keyshapes
    W = solve_nnls(K, F)
    assert np.abs(W - per_frame_nnls(K, F)).max() <= 1e-6
    check_kkt(K, F, W)
    assert 0.05 < (W == 0).mean() < 0.95          # a real mix of active and inactive keys


def test_ill_conditioned_keys_are_refined():
    K, _ = keyshape_problem(123, 30, 200, 8)
    K[:, 1] = K[:, 0] + 1e-4 * K[:, 1]            # two keyshapes nearly the same: cond(K) > 1e5
    assert np.linalg.cond(K) > 1e5
    F = np.maximum(np.random.default_rng(0).standard_normal((200, 30)), 0) @ K.T
    for FF in (F, F + 0.01 * np.random.default_rng(1).standard_normal(F.shape)):
        W = solve_nnls(K, FF)
        assert np.abs(W - per_frame_nnls(K, FF)).max() <= 1e-6
        check_kkt(K, FF, W)


def test_duplicate_and_zero_keys_give_an_optimal_solution():
    K, F = keyshape_problem(60, 8, 100, 9)
    K = np.hstack([K, K[:, :1], np.zeros((60, 1))])   # an exact duplicate and a key that moves nothing
    W = solve_nnls(K, F)
    R = per_frame_nnls(K, F)
    assert np.linalg.norm(W @ K.T - F, axis=1) == pytest.approx(np.linalg.norm(R @ K.T - F, axis=1), rel=1e-6)
    assert (W[:, -1] == 0).all()
    assert np.isfinite(W).all() and (W >= 0).all()


@pytest.mark.parametrize("D,N,seed", [(204, 40, 30), (123, 30, 31)])
def test_rom_keys_match_scipy_with_both_methods(D, N, seed):
    from faceretarget.numerics._nnls_active_set import _bpp, _lh

    K, F = rom_problem(D, N, 240, seed)
    R = per_frame_nnls(K, F)
    assert (R == 0).mean() > 0.6                   # sparse weights
    W = solve_nnls(K, F)
    assert np.abs(W - R).max() <= 1e-6
    check_kkt(K, F, W)
    G, B = K.T @ K, F @ K
    H = np.linalg.inv(G)
    for chunk in (1, 8):                           # Lawson-Hanson: cold, warm-started from the previous frame
        X, _, stuck = _lh(G, H, B, None, 1e-10, 500, chunk)
        assert stuck.size == 0
        assert np.abs(X - R).max() <= 1e-6
    X, _, todo = _bpp(G, H, B, None, 1e-10, 500)   # block principal pivoting on its own
    assert todo.size == 0
    assert np.abs(X - R).max() <= 1e-6


def test_dependent_rom_keys_fit_as_well_as_scipy():
    K, F = rom_problem(123, 50, 200, 32, n_basis=30)   # 50 keys spanning 30 dimensions
    assert np.linalg.matrix_rank(K) < K.shape[1]
    W = solve_nnls(K, F)
    R = per_frame_nnls(K, F)
    assert (W >= 0).all()
    fit, ref = np.linalg.norm(W @ K.T - F, axis=1), np.linalg.norm(R @ K.T - F, axis=1)
    assert fit == pytest.approx(ref, rel=1e-7, abs=1e-12)


def test_lawson_hanson_with_upper_bounds():
    from faceretarget.numerics._nnls_active_set import _lh

    K, F = keyshape_problem(60, 10, 80, 33, noise=0.1)
    F = 1.5 * F
    G, B = K.T @ K, F @ K
    ub = np.linspace(0.4, 1.0, 10)
    R = np.array([lsq_linear(K, f, bounds=(0, ub), method="bvls", tol=1e-14).x for f in F])
    for chunk in (1, 8):
        X, _, stuck = _lh(G, None, B, ub, 1e-10, 500, chunk)
        assert stuck.size == 0
        assert np.abs(X - R).max() <= 1e-6
    W = solve_nnls(K, F, upper=ub)
    assert np.abs(W - R).max() <= 1e-6


def test_single_frame_and_empty_take():
    K, F = random_problem(20, 5, 3, 10)
    w = solve_nnls(K, F[0])
    assert w.shape == (5,)
    assert np.abs(w - nnls(K, F[0])[0]).max() <= 1e-10
    assert solve_nnls(K, F[:0]).shape == (0, 5)


def test_exact_keyshapes_are_recovered():
    K, _ = keyshape_problem(123, 20, 10, 11)
    rng = np.random.default_rng(1)
    Wt = np.abs(rng.standard_normal((50, 20))) * (rng.random((50, 20)) > 0.5)
    W = solve_nnls(K, Wt @ K.T)
    assert np.abs(W - Wt).max() < 1e-9


# ----------------------------------------------------------------------------- extras
def test_upper_bound_matches_lsq_linear():
    K, F = keyshape_problem(123, 15, 120, 12, noise=0.1)
    F = 1.6 * F                                    # push weights above the bound
    ub = np.linspace(0.5, 1.0, 15)
    for upper in (1.0, ub):
        W = solve_nnls(K, F, upper=upper)
        R = np.array([lsq_linear(K, f, bounds=(0, upper), method="bvls", tol=1e-14).x for f in F])
        assert np.abs(W - R).max() <= 1e-6
        assert (W <= np.broadcast_to(upper, W.shape) + 0).all()
        assert (W == np.broadcast_to(upper, W.shape)).any()      # the bound is active somewhere
        check_kkt(K, F, W, upper=upper)
    assert np.array_equal(solve_nnls(K, F, upper=np.inf), solve_nnls(K, F))


def test_l2_and_l1_match_augmented_problem():
    K, F = keyshape_problem(60, 12, 150, 13)
    N = K.shape[1]
    for l2, l1 in [(0.5, 0.0), (0.0, 0.2), (0.3, 0.4)]:
        W = solve_nnls(K, F, l2=l2, l1=l1, upper=2.0)
        # 1/2||Kw-f||^2 + l2/2||w||^2 + l1 1'w  ==  1/2||Ka w - fa||^2 + const  with rows sqrt(l2) I and
        # fa shifted so that Ka'fa = K'f - l1 1
        Ka = np.vstack([K, np.sqrt(l2) * np.eye(N)])
        shift = Ka @ np.linalg.solve(Ka.T @ Ka, np.full(N, l1))
        R = np.array([lsq_linear(Ka, np.r_[f, np.zeros(N)] - shift, bounds=(0, 2.0), method="bvls",
                                 tol=1e-14).x for f in F])
        assert np.abs(W - R).max() <= 1e-6
        check_kkt(K, F, W, upper=2.0, l2=l2, l1=l1)
    assert (solve_nnls(K, F, l1=0.5) == 0).mean() > (solve_nnls(K, F) == 0).mean()   # l1 sparsifies


def smooth_reference(K, F, s, upper=None, rows=None):
    """The smoothed problem as one bounded least-squares problem over the whole take."""
    T, _ = F.shape
    N = K.shape[1]
    blocks, rhs = [], []
    for t in range(T):
        r = np.ones(K.shape[0], dtype=bool) if rows is None else rows[t]
        Bk = np.zeros((r.sum(), T * N))
        Bk[:, t * N:(t + 1) * N] = K[r]
        blocks.append(Bk)
        rhs.append(F[t][r])
    blocks.append(np.sqrt(s) * np.kron(np.diff(np.eye(T), axis=0), np.eye(N)))
    rhs.append(np.zeros((T - 1) * N))
    A, b = np.vstack(blocks), np.concatenate(rhs)
    ub = np.inf if upper is None else upper
    return lsq_linear(A, b, bounds=(0, ub), method="bvls", tol=1e-14).x.reshape(T, N), A, b


@pytest.mark.parametrize("s,upper", [(0.5, None), (20.0, 0.7), (2000.0, None)])
def test_smooth_matches_reference(s, upper):
    K, F = keyshape_problem(30, 6, 30, 14, noise=0.2)
    W = solve_nnls(K, F, smooth=s, upper=upper)
    R, _, _ = smooth_reference(K, F, s, upper)
    assert np.abs(W - R).max() <= 1e-6
    # optimality conditions of the coupled problem
    g = (W @ K.T - F) @ K
    dW = np.diff(W, axis=0)
    g[:-1] -= s * dW
    g[1:] += s * dW
    scale = np.abs(F @ K).max()
    hi = np.inf if upper is None else upper
    assert (g[W <= 0] >= -1e-7 * scale).all()
    assert (np.abs(g[(W > 0) & (W < hi)]) <= 1e-7 * scale).all()
    assert (g[W >= hi] <= 1e-7 * scale).all()
    # smoothing lowers frame-to-frame motion
    assert np.abs(np.diff(W, axis=0)).sum() < np.abs(np.diff(solve_nnls(K, F, upper=upper), axis=0)).sum()


def test_smooth_projected_newton_fallback():
    from faceretarget.numerics._nnls_box_qp import _box_qp
    from faceretarget.numerics._nnls_temporal import _smooth_qp

    K, F = keyshape_problem(30, 6, 40, 15, noise=0.2)
    G, B = K.T @ K, F @ K
    ub = np.full(6, 0.7)
    W0, _ = _box_qp(G, B, ub, 1e-10, 100)
    W, ok = _smooth_qp([G], np.zeros(40, dtype=np.int64), B, ub, 5.0, W0, 1e-10, 200, pdas=False)
    assert ok
    assert np.abs(W - smooth_reference(K, F, 5.0, 0.7)[0]).max() <= 1e-6


def test_smooth_with_mask_and_missing_frame():
    K, F = keyshape_problem(30, 8, 24, 16, noise=0.2)
    mask = np.random.default_rng(3).random((24, 10)) > 0.3
    mask[5] = False                                # a frame with no marker at all
    F = F.copy()
    F[~np.repeat(mask, 3, axis=1)] = np.nan
    W = solve_nnls(K, F, mask=mask, smooth=3.0, upper=1.0)
    R, _, _ = smooth_reference(K, np.nan_to_num(F), 3.0, 1.0, rows=np.repeat(mask, 3, axis=1))
    assert np.abs(W - R).max() <= 1e-6
    assert W[5].any()                              # filled in from its neighbours


# ----------------------------------------------------------------------------- missing markers
def test_mask_equals_reduced_problem():
    K, F = keyshape_problem(123, 20, 150, 17)
    rng = np.random.default_rng(4)
    mask = rng.random((150, 41)) > 0.15            # per marker (3 coordinates each)
    mask[:50] = True                               # many frames share the full pattern
    mask[7, :] = False
    rows = np.repeat(mask, 3, axis=1)
    Fn = np.where(rows, F, np.nan)                 # missing values may be NaN
    W = solve_nnls(K, Fn, mask=mask)
    for t in range(150):
        r = rows[t]
        ref = nnls(K[r], F[t][r])[0] if r.any() else np.zeros(20)
        assert np.abs(W[t] - ref).max() <= 1e-6, t
    assert not W[7].any()
    assert np.array_equal(solve_nnls(K, F, mask=rows), W)   # (T, D) mask: the same


def test_mask_with_too_few_rows_is_still_optimal():
    K, F = keyshape_problem(60, 12, 30, 18)
    mask = np.ones((30, 20), dtype=bool)
    mask[3, 3:] = False                            # 9 rows for 12 keys: weights not unique
    W = solve_nnls(K, F, mask=mask)
    r = np.repeat(mask[3], 3)
    ref = nnls(K[r], F[3][r])[0]
    fit, best = np.linalg.norm(K[r] @ W[3] - F[3][r]), np.linalg.norm(K[r] @ ref - F[3][r])
    assert fit == pytest.approx(best, abs=1e-6)


# ----------------------------------------------------------------------------- errors
def test_errors_name_the_problem():
    K, F = random_problem(12, 3, 5, 19)
    with pytest.raises(InvalidDataError, match=r"\(T, 12\)"):
        solve_nnls(K, F[:, :10])
    with pytest.raises(InvalidDataError, match="K must be"):
        solve_nnls(K[0], F)
    Fb = F.copy()
    Fb[3, 2] = np.nan
    with pytest.raises(InvalidDataError, match="frame 3"):
        solve_nnls(K, Fb)
    mask = np.ones((5, 4), dtype=bool)
    mask[3, 0] = False                             # the NaN is in marker 0 of frame 3: fine when masked
    assert np.isfinite(solve_nnls(K, Fb, mask=mask)).all()
    mask[3, 0] = True
    with pytest.raises(InvalidDataError, match="frame 3"):
        solve_nnls(K, Fb, mask=mask)
    with pytest.raises(InvalidDataError, match="mask"):
        solve_nnls(K, F, mask=np.ones((5, 5), dtype=bool))
    Kb = K.copy()
    Kb[0, 1] = np.inf
    with pytest.raises(InvalidDataError, match="column"):
        solve_nnls(Kb, F)
    with pytest.raises(InvalidDataError, match="upper"):
        solve_nnls(K, F, upper=[1.0, 1.0])
    with pytest.raises(InvalidDataError, match="upper"):
        solve_nnls(K, F, upper=0.0)
    for kw in ({"l2": -1.0}, {"l1": np.nan}, {"smooth": -0.1}, {"tol": 0.0}):
        with pytest.raises(InvalidDataError):
            solve_nnls(K, F, **kw)


def test_nonconvergence_warns():
    K, F = keyshape_problem(60, 20, 40, 20)
    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        solve_nnls(K, F, max_iter=1)
    assert any("did not converge" in str(x.message) for x in w)


# ----------------------------------------------------------------------------- filtering
def test_filter_level_zero_is_identity_and_bounds_are_kept():
    _, F = keyshape_problem(30, 8, 10, 21)
    W = np.clip(np.random.default_rng(5).standard_normal((300, 8)).cumsum(axis=0) * 0.05, 0, 1)
    assert np.array_equal(temporal_filter(W, 0, 60.0), W)
    Wf = temporal_filter(W, 2.0, 60.0)
    assert Wf.shape == W.shape
    assert (Wf >= 0).all() and (Wf <= 1).all()
    assert np.allclose(Wf.mean(axis=0), W.mean(axis=0))      # a low-pass keeps each curve's mean
    assert extremes_removed(W, W) == 0.0


def test_filter_cutoff_mapping():
    assert filter_cutoff_hz(0) == np.inf
    assert filter_cutoff_hz(1) == pytest.approx(10.0)
    assert filter_cutoff_hz(5) == pytest.approx(2.0)
    # the response at the cutoff is -3 dB: a sinusoid there keeps ~1/sqrt(2) of its amplitude
    fps, T = 60.0, 6000
    x = np.sin(2 * np.pi * 2.0 * np.arange(T) / fps)[:, None]
    y = temporal_filter(x, 5.0, fps)
    assert np.ptp(y[1000:-1000]) / np.ptp(x[1000:-1000]) == pytest.approx(2**-0.5, rel=0.03)


def test_extremes_removed_is_monotone_in_level():
    rng = np.random.default_rng(6)
    t = np.arange(600) / 60.0
    W = np.sin(2 * np.pi * rng.uniform(0.2, 3, 10) * t[:, None]) + 0.2 * rng.standard_normal((600, 10))
    W = np.maximum(W, 0.0)
    levels = [0, 0.25, 0.5, 1, 2, 4, 8, 16]
    removed = [extremes_removed(W, temporal_filter(W, lv, 60.0)) for lv in levels]
    assert removed[0] == 0.0
    assert all(b >= a for a, b in zip(removed[:-1], removed[1:], strict=True))
    assert removed[-1] > 50.0


def test_filter_errors():
    with pytest.raises(InvalidDataError):
        temporal_filter(np.zeros((5, 2)), -1, 30)
    with pytest.raises(InvalidDataError):
        temporal_filter(np.zeros((5, 2)), 1, 0)
    with pytest.raises(InvalidDataError, match="frame 2"):
        temporal_filter(np.array([[0.0], [1.0], [np.nan]]), 1, 30)
    with pytest.raises(InvalidDataError):
        extremes_removed(np.zeros((5, 2)), np.zeros((4, 2)))


@pytest.mark.parametrize("seed", [40, 41])
def test_backends_agree_with_scipy_on_rom_keys(seed):
    """The compiled kernel (numba, when installed) and the NumPy methods give scipy's weights."""
    from faceretarget.numerics import _nnls_numba

    K, F = rom_problem(204, 40, 300, seed)
    ref = per_frame_nnls(K, F)
    Wn = solve_nnls(K, F, backend="numpy")
    assert np.linalg.norm(Wn @ K.T - F, axis=1) == pytest.approx(np.linalg.norm(ref @ K.T - F, axis=1), rel=1e-6)
    if not _nnls_numba.available():
        with pytest.raises(MissingDependencyError, match="numba"):
            solve_nnls(K, F, backend="numba")
        return
    Wc = solve_nnls(K, F, backend="numba")
    assert np.linalg.norm(Wc @ K.T - F, axis=1) == pytest.approx(np.linalg.norm(ref @ K.T - F, axis=1), rel=1e-6)
    unique = np.linalg.matrix_rank(K) == K.shape[1]
    if unique:
        assert np.abs(Wc - ref).max() <= 1e-6
    check_kkt(K, F, Wc)


# ----------------------------------------------------------------------------- compiled box kernel
def bounded_rom_problem(T, seed, near_duplicates=False):
    """P1-like keys (chosen among a ROM take's frames), the problem in v = w + 1 with 0 <= v <= 3
    (the weight range -1..2), optionally with near-duplicate keys (cond(K'K) > 1e12, like hull sets)."""
    K, F = rom_problem(204, 30, T, seed)
    if near_duplicates:
        rng = np.random.default_rng(seed)
        for j in (3, 11, 20):
            K[:, j + 1] = K[:, j] + 1e-6 * np.linalg.norm(K[:, j]) * rng.standard_normal(204) / np.sqrt(204)
    F = 3.0 * F                                    # weights 3 w: beyond both ends of the range
    return K, F + K.sum(axis=1), np.full(30, 3.0)


def per_frame_bvls(K, F, ub):
    return np.array([lsq_linear(K, f, bounds=(0, ub), method="bvls", tol=1e-14).x for f in F])


@pytest.mark.parametrize("start", [0, 1, 2])
def test_box_kernel_matches_numpy_from_any_start(start):
    """Every start (all at 0, all free, all at the upper bound) and the warm start from frame to frame
    reach the NumPy methods' optimum; the sets come back with the weights."""
    nb = pytest.importorskip("numba")
    del nb
    from faceretarget.numerics._nnls_box_qp import _box_qp
    from faceretarget.numerics._nnls_numba import box_frames

    K, F, ub = bounded_rom_problem(200, 50)
    G, B = K.T @ K, F @ K
    X, S, stuck, solves, done = box_frames(G, B, ub, start=np.full(30, start, dtype=np.int8))
    assert done == 200 and not stuck.any()
    Xn, _ = _box_qp(G, B, ub, 1e-10, 500, backend="numpy")
    assert np.abs(X - Xn).max() <= 1e-9
    assert np.abs(X - per_frame_bvls(K, F, ub)).max() <= 1e-6
    assert np.array_equal(S == 0, X == 0) and np.array_equal(S == 2, X == 3.0)
    assert 0.01 < (S == 2).mean() and 0.01 < (S == 0).mean()   # both bounds active
    # a frame repeated: its sets are its predecessor's, one solve each
    _, _, _, solves, _ = box_frames(G, np.repeat(B[:1], 5, axis=0), ub)
    assert solves[1:].tolist() == [1, 1, 1, 1]


@pytest.mark.parametrize("upper", [None, 3.0])
def test_box_kernel_exact_mode_on_near_duplicate_keys(upper):
    """cond(K'K) > 1e12: the kernel's Gram-form optimum is refined with gradients from the projected
    least-squares data (K = QR) and checked against the exact KKT conditions."""
    pytest.importorskip("numba")
    K, F, ub = bounded_rom_problem(240, 51, near_duplicates=True)
    ev = np.linalg.eigvalsh(K.T @ K)
    assert ev[-1] / ev[0] > 1e12
    if upper is None:
        F = F - K.sum(axis=1)                      # plain NNLS
    W = solve_nnls(K, F, upper=upper, backend="numba")
    Wn = solve_nnls(K, F, upper=upper, backend="numpy")
    R = per_frame_nnls(K, F) if upper is None else per_frame_bvls(K, F, ub)
    J, Jn, Jr = (0.5 * np.linalg.norm(X @ K.T - F, axis=1) ** 2 for X in (W, Wn, R))
    slack = 1e-12 * 0.5 * np.linalg.norm(F, axis=1) ** 2
    # barely determined along the near-duplicates: the objectives agree, and ours is never worse
    # than scipy's (whose per-frame active-set solves lose digits here: up to 1 % higher)
    assert (np.abs(J - Jn) <= 1e-5 * Jn + slack).all()
    assert (J <= Jr * (1 + 1e-7) + slack).all()    # the kernel decides the sets at 1e-4 tol here
    assert (Jn <= Jr * (1 + 1e-6) + slack).all()
    for X in (W, Wn):
        check_kkt(K, F, X, upper=upper, tol=1e-9)


def test_box_kernel_probe_hands_dense_problems_to_pivoting(monkeypatch):
    """Dense weights whose sets change at every frame: the probe stops the kernel after 64 frames and
    block pivoting solves the take; the answers are the same either way."""
    pytest.importorskip("numba")
    from faceretarget.numerics import _nnls_box_qp
    from faceretarget.numerics._nnls_numba import box_frames

    K, F = keyshape_problem(204, 40, 400, 52)
    G, B = K.T @ K, F @ K
    _, _, _, solves, done = box_frames(G, B, probe=64, max_solves=0.5)
    assert done == 64 and solves[64:].sum() == 0
    W = solve_nnls(K, F, upper=1.0)
    monkeypatch.setattr(_nnls_box_qp, "_COMPILED_MAX_SOLVES", 0.5)
    Wp = solve_nnls(K, F, upper=1.0)
    assert np.abs(W - Wp).max() <= 1e-9
    assert np.abs(W - per_frame_bvls(K, F, np.ones(40))).max() <= 1e-6


def test_box_kernel_stuck_frames_are_finished_by_numpy():
    pytest.importorskip("numba")
    from faceretarget.numerics._nnls_box_qp import _compiled_box_qp

    K, F, ub = bounded_rom_problem(100, 53)
    G, B = K.T @ K, F @ K
    X, stuck = _compiled_box_qp(G, B, ub, 1e-10, 2, None, True)   # 2 entering steps: many frames stop
    Xr, _ = _compiled_box_qp(G, B, ub, 1e-10, 500, None, True)
    assert stuck.size < 100
    ok = np.setdiff1d(np.arange(100), stuck)
    assert np.abs(X[ok] - Xr[ok]).max() <= 1e-9


def test_blocked_products_equal_matmul():
    from faceretarget.numerics._nnls_linalg import _mm

    rng = np.random.default_rng(54)
    for n, m, k in [(1, 204, 40), (31, 204, 40), (1000, 204, 40), (999, 30, 7), (50, 3000, 100)]:
        A, B = rng.standard_normal((n, m)), rng.standard_normal((m, k))
        assert np.abs(_mm(A, B) - A @ B).max() <= 1e-12 * np.abs(A).max() * np.abs(B).max() * m


def test_nan_in_a_feature_no_key_moves_is_reported():
    K, F = random_problem(12, 3, 6, 55)
    K[4] = 0.0                                     # feature 4 moves with no key
    for bad in (np.nan, np.inf):
        Fb = F.copy()
        Fb[2, 4] = bad
        with warnings.catch_warnings():
            warnings.simplefilter("error")         # no RuntimeWarning from the products on the way
            with pytest.raises(InvalidDataError, match="frame 2"):
                solve_nnls(K, Fb)
            Fb = F.copy()
            Fb[5, 1] = bad
            with pytest.raises(InvalidDataError, match="frame 5"):
                solve_nnls(K, Fb, upper=1.0)
