"""Weights inside a range for whole takes: :func:`faceretarget.numerics.solve_bounded`.

Optimality (KKT) on random and on ill-conditioned, real-like key sets (keys chosen among the frames
of a range-of-motion take, near-duplicates among them), equality to ``scipy.optimize.lsq_linear``
per frame where the solution is unique, masks, infinite upper bounds, both backends, bad bounds.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import lsq_linear

from faceretarget.datasets import keyshape_problem, rom_problem
from faceretarget.errors import InvalidDataError
from faceretarget.numerics import EXAMPLE_RANGE, FACS_RANGE, solve_bounded, solve_nnls

BACKENDS = ("auto", "numpy")


def pushed_problem(D, N, T, seed, noise=0.1):
    """Keyshape-like keys and frames whose least-squares weights leave [0, 1] on both sides."""
    K, F = keyshape_problem(D, N, T, seed, noise=noise)
    W = np.linalg.lstsq(K, F.T, rcond=None)[0].T
    return K, 1.5 * F - 0.6 * (W.mean(axis=0) @ K.T)


def near_duplicate_problem(T, seed):
    """Keys chosen among a ROM take's frames, with near-duplicates: cond(K'K) > 1e12, like P1's hull sets."""
    K, F = rom_problem(204, 30, T, seed)
    rng = np.random.default_rng(seed)
    for j in (3, 11, 20):
        K[:, j + 1] = K[:, j] + 1e-6 * np.linalg.norm(K[:, j]) * rng.standard_normal(len(K)) / np.sqrt(len(K))
    ev = np.linalg.eigvalsh(K.T @ K)
    assert ev[-1] / ev[0] > 1e12
    return K, F


def per_frame(K, F, lo, hi, method="bvls"):
    kw = dict(method="bvls", tol=1e-14) if method == "bvls" else dict(tol=1e-12)
    return np.array([lsq_linear(K, f, bounds=(lo, hi), **kw).x for f in F])


def objective(K, F, W):
    R = W @ K.T - F
    return 0.5 * np.einsum("ij,ij->i", R, R)


def kkt_violation(K, F, W, lo, hi):
    """Largest violation of the optimality conditions, relative to max |K'(f - K lo)| per frame."""
    lo_ = np.broadcast_to(lo, W.shape)
    hi_ = np.broadcast_to(hi, W.shape)
    assert (W >= lo_).all() and (W <= hi_).all()          # inside the range exactly
    g = (W @ K.T - F) @ K
    viol = np.where(W <= lo_, np.maximum(-g, 0.0), np.where(W >= hi_, np.maximum(g, 0.0), np.abs(g)))
    scale = np.abs((F - np.broadcast_to(lo, (K.shape[1],)) @ K.T) @ K).max(axis=1, keepdims=True)
    return float((viol / scale).max())


# ----------------------------------------------------------------------------- optimality
@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("seed", [0, 1])
def test_random_problems_are_optimal(backend, seed):
    rng = np.random.default_rng(seed)
    K = rng.standard_normal((60, 12))
    F = 1.5 * rng.standard_normal((150, 12)) @ K.T + 0.5 * rng.standard_normal((150, 60))   # weights beyond the range
    lo = -rng.uniform(0.2, 1.0, 12)
    hi = rng.uniform(0.5, 2.0, 12)
    hi[[2, 7]] = np.inf                                     # some keys without an upper bound
    W = solve_bounded(K, F, lo, hi, backend=backend)
    assert W.shape == (150, 12)
    assert kkt_violation(K, F, W, lo, hi) <= 1e-9
    at = (W <= lo) | (W >= hi)
    assert 0.1 < at.mean() < 0.9                            # a real mix of bounds and free weights
    assert np.abs(W - per_frame(K, F, lo, hi)).max() <= 1e-6


@pytest.mark.parametrize("backend", BACKENDS)
def test_near_duplicate_keys_are_optimal(backend):
    """Ill-conditioned real-like keys: the weights are barely determined along the near-duplicate
    directions, so the objective (not the weights) is compared with lsq_linear's, and the KKT
    conditions hold."""
    K, F = near_duplicate_problem(240, 3)
    lo, hi = EXAMPLE_RANGE
    W = solve_bounded(K, F, lo, hi, backend=backend)
    assert kkt_violation(K, F, W, lo, hi) <= 1e-9
    R = per_frame(K, F, lo, hi)
    J, Jr = objective(K, F, W), objective(K, F, R)
    assert (J <= Jr * (1 + 1e-6) + 1e-12 * objective(K, F, np.zeros_like(W))).all()
    assert ((W <= lo) | (W >= hi)).any()                    # the range is active


def test_backends_agree_on_near_duplicate_keys():
    K, F = near_duplicate_problem(200, 4)
    Wa = solve_bounded(K, F, -0.5, 1.5)
    Wn = solve_bounded(K, F, -0.5, 1.5, backend="numpy")
    Ja, Jn = objective(K, F, Wa), objective(K, F, Wn)
    assert Ja == pytest.approx(Jn, rel=1e-6, abs=1e-12 * objective(K, F, np.zeros_like(Wa)).max())


# ----------------------------------------------------------------------------- equality to scipy
@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("bounds", [EXAMPLE_RANGE, FACS_RANGE, (-1.0, 2.0)])
def test_well_conditioned_keys_match_lsq_linear(backend, bounds):
    K, F = pushed_problem(123, 15, 120, 5)
    assert np.linalg.cond(K) < 1e3
    lo, hi = bounds
    W = solve_bounded(K, F, lo, hi, backend=backend)
    assert ((W <= lo) | (W >= hi)).mean() > 0.05           # the range matters
    assert np.abs(W - per_frame(K, F, lo, hi)).max() <= 1e-6
    assert np.abs(W - per_frame(K, F, lo, hi, method="trf")).max() <= 1e-6   # lsq_linear's default, tight


def test_per_key_bounds_and_single_frame():
    K, F = pushed_problem(60, 8, 40, 6)
    lo = np.linspace(-1.0, 0.0, 8)
    hi = np.linspace(0.5, 2.0, 8)
    W = solve_bounded(K, F, lo, hi)
    assert np.abs(W - per_frame(K, F, lo, hi)).max() <= 1e-6
    w = solve_bounded(K, F[7], lo, hi)
    assert w.shape == (8,)
    assert np.abs(w - W[7]).max() <= 1e-9


# ----------------------------------------------------------------------------- options
def test_infinite_upper_bound():
    K, F = pushed_problem(60, 10, 80, 7)
    assert np.abs(solve_bounded(K, F, 0.0, np.inf) - solve_nnls(K, F)).max() <= 1e-12
    W = solve_bounded(K, F, -0.5, np.inf)
    assert W.min() == -0.5 and W.max() > 1.0                  # bounded below only
    assert np.abs(W - per_frame(K, F, -0.5, np.inf)).max() <= 1e-6


@pytest.mark.parametrize("backend", BACKENDS)
def test_mask_equals_reduced_problems(backend):
    K, F = pushed_problem(90, 10, 60, 8)
    rng = np.random.default_rng(9)
    mask = rng.random((60, 30)) > 0.2                       # per marker (3 coordinates each)
    mask[:20] = True                                        # many frames share the full pattern
    rows = np.repeat(mask, 3, axis=1)
    Fn = np.where(rows, F, np.nan)                          # missing values may be NaN
    lo, hi = EXAMPLE_RANGE
    W = solve_bounded(K, Fn, lo, hi, mask=mask, backend=backend)
    for t in range(60):
        r = rows[t]
        ref = lsq_linear(K[r], F[t][r], bounds=(lo, hi), method="bvls", tol=1e-14).x
        assert np.abs(W[t] - ref).max() <= 1e-6, t


def test_smooth_stays_in_range_and_smooths():
    K, F = pushed_problem(60, 8, 50, 10, noise=0.3)
    lo, hi = EXAMPLE_RANGE
    W0 = solve_bounded(K, F, lo, hi)
    W = solve_bounded(K, F, lo, hi, smooth=0.5 * np.linalg.eigvalsh(K.T @ K)[-1])
    assert (W >= lo).all() and (W <= hi).all()
    assert np.abs(np.diff(W, axis=0)).sum() < 0.8 * np.abs(np.diff(W0, axis=0)).sum()
    # the shift onto solve_nnls: the same problem in v = w - lo
    V = solve_nnls(K, F - K @ np.full(8, lo), upper=hi - lo, smooth=0.5 * np.linalg.eigvalsh(K.T @ K)[-1])
    assert np.abs(W - (V + lo)).max() <= 1e-9


# ----------------------------------------------------------------------------- errors
def test_bad_bounds_raise_naming_the_problem():
    K, F = pushed_problem(30, 4, 5, 11)
    with pytest.raises(InvalidDataError, match="lower bounds must be finite"):
        solve_bounded(K, F, -np.inf, 1.0)
    with pytest.raises(InvalidDataError, match="lower bounds must be finite"):
        solve_bounded(K, F, np.nan, 1.0)
    with pytest.raises(InvalidDataError, match="upper bound must be above"):
        solve_bounded(K, F, 1.0, 1.0)
    with pytest.raises(InvalidDataError, match="upper bound must be above"):
        solve_bounded(K, F, 0.0, [1.0, 1.0, np.nan, 1.0])
    with pytest.raises(InvalidDataError, match=r"one bound per key \(4\)"):
        solve_bounded(K, F, 0.0, [1.0, 2.0])
    with pytest.raises(InvalidDataError, match="K must be"):
        solve_bounded(K[:, 0], F, 0.0, 1.0)
    with pytest.raises(InvalidDataError, match=r"\(T, 30\)"):
        solve_bounded(K, F[:, :20], 0.0, 1.0)
