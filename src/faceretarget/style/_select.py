"""A :class:`~._model.StyleModel` chooses its own settings by cross-validation on its training frames.

The settings that decide how well a style model generalises (the PCA ``variance``, the dimension
rule's ``energy``, the strength ``prior`` of the content prior, and the local correction) depend on
the data: how many aligned frames there are, how noisy they are, how nonlinear the interaction of
style and content is.  Instead of constants picked while looking at one evaluation, every model
picks them from its own training frames, with the task it will be used for:

* **Folds.**  The aligned training frames are cut into ``folds`` (5) contiguous blocks; for each,
  the model is fitted on the other frames, leaving out ``gap`` frames on both sides of the block
  (1 % of the frames, at least the bundle size: neighbouring frames are nearly equal, so without a
  gap a local correction would be validated on frames it has all but seen), and validated on the
  block.
* **Task.**  The known-expression task (Eq. 2.10, 2.11, with the model's ``detail`` rule) for every
  ordered pair of training styles: the block's frames in style ``s`` are translated to every other
  style ``t`` and compared with the block's frames in ``t``.  The score is the summed squared error
  over all pairs and folds, reported relative to that of leaving the input unchanged
  (:attr:`Selection.table`; 1 = no better than no edit).
* **Two stages.**  First ``variance`` x ``energy`` x ``prior`` on the bilinear model alone (no
  local correction), every combination; then, with those, the local correction: off, or kernel
  ridge regression of the training residuals with bandwidth ``h`` (a multiple of the median
  nearest-neighbour distance between the source style's training observations) and ridge ``lam``
  (relative to the kernel's diagonal, 1), searched coordinate-wise over the bandwidth x ridge grid
  (``search``; every fold's model and residuals computed once, every kernel once per bandwidth,
  errors in PCA coefficients plus the fixed part outside the basis).  The setting with the lowest score wins (ties: the
  earlier, simpler one in the grid order).  The model is then refitted on all training frames.
* A setting the user fixes is not searched.  Fewer than ``min_frames`` (30) aligned frames: no
  search; the fallback values (:data:`FALLBACK`) are used.

**Kernel correction** (:func:`kernel_fit`, :func:`kernel_predict`): the residual of the bilinear
model, ``R = Y_target - render(content(Y_source))`` over paired training frames, is regressed on
the source observation with a Gaussian kernel, ``k(y, y') = exp(-|y - y'|^2 / (2 h^2))``,
``alpha = (K + lam I)^-1 R``, and a new frame gets ``k(y, Y_train) alpha``.  Far from the training
frames it tends to 0, that is to the bilinear model alone, where the mean residual of the nearest
frames (the earlier ``local=k`` correction, still available) adds the residuals of dissimilar
frames at any distance.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.linalg import cho_factor, cho_solve
from scipy.spatial import cKDTree

from ..errors import InvalidDataError
from ._bilinear import _ridge_map, choose_dims
from ._pointlocal import score_point_local

__all__ = ["Selection", "GRID", "FALLBACK", "STYLE_RIDGE_GRID", "select_settings", "select_style_ridge", "kernel_fit",
           "kernel_predict", "kernel_rows", "KERNEL_FRAMES", "cv_folds", "group_folds", "pca_of", "ones_weights"]

#: The searched values of every setting.
GRID: dict[str, tuple] = {
    "variance": (0.999, 0.9999, 0.99999, 0.999999),
    "energy": (0.999, 0.9999, 0.99999, 0.999999),
    "prior": (0.1, 1.0, 10.0, 100.0, 1000.0),
    "bandwidth": (3.0, 10.0, 30.0, 100.0),
    "ridge": (1e-3, 1e-2, 1e-1, 1.0),
}

#: Used when there are too few frames to cross-validate.
FALLBACK: dict[str, object] = {"variance": 0.9999, "energy": 0.9999, "prior": 1.0, "local": 0}


@dataclass
class Selection:
    """What the cross-validation chose, and the scores it chose from.

    Attributes
    ----------
    variance, energy, prior : float
    local : 0 or ("kernel", bandwidth, ridge)
    folds, gap : int
    table : list of dict
        Every candidate (``stage`` 1 or 2, its settings, ``score``: validation squared error
        relative to leaving the input unchanged), in the order evaluated.
    """

    variance: float
    energy: float
    prior: float
    local: object
    folds: int = 0
    gap: int = 0
    table: list = field(default_factory=list)

    def settings(self) -> dict:
        return {"variance": self.variance, "energy": self.energy, "prior": self.prior, "local": self.local}


def cv_folds(n: int, folds: int, gap: int) -> list[tuple[np.ndarray, np.ndarray]]:
    """Contiguous validation blocks of ``range(n)`` and their training frames (``gap`` left out each side)."""
    edges = np.linspace(0, n, folds + 1).round().astype(int)
    out = []
    for f in range(folds):
        a, b = int(edges[f]), int(edges[f + 1])
        keep = np.ones(n, bool)
        keep[max(0, a - gap):min(n, b + gap)] = False
        out.append((np.flatnonzero(keep), np.arange(a, b)))
    return out


def group_folds(groups, n: int) -> list[tuple[np.ndarray, np.ndarray]]:
    """Leave-one-group-out folds: each group's frames validated by a model of the other groups'.

    Parameters
    ----------
    groups : (n,) array
        A label per aligned frame (the performer).
    n : int
        The number of frames (checked against ``groups``).
    """
    g = np.asarray(groups)
    if g.shape != (n,):
        raise InvalidDataError(f"groups: expected one label per aligned frame ({n}), got shape {g.shape}")
    return [(np.flatnonzero(g != u), np.flatnonzero(g == u)) for u in dict.fromkeys(g.tolist())]


# ------------------------------------------------------------------------------------------ kernel correction
def pca_of(X: dict[str, np.ndarray]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(mean, singular values, Vt)`` of all styles' frames ``X[style]`` ``(C, D)`` together."""
    allx = np.concatenate(list(X.values()))
    mean = allx.mean(0)
    Z = allx - mean
    n, d = Z.shape
    if n < 2 * d:
        _, sv, vt = np.linalg.svd(Z, full_matrices=False)
        return mean, sv, vt
    # many more frames than coordinates: the (d, d) scatter matrix's eigenvectors are the right
    # singular vectors (5-10x faster than the SVD of the frames; the kept components hold at most
    # 1 - 1e-6 of the variance, far above the squared-condition precision this gives up)
    ev, V = np.linalg.eigh(Z.T @ Z)
    order = np.argsort(ev)[::-1]
    return mean, np.sqrt(np.maximum(ev[order], 0.0)), V[:, order].T.copy()


def _sqdist(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    d = (a * a).sum(1)[:, None] + (b * b).sum(1)[None] - 2.0 * a @ b.T
    return np.maximum(d, 0.0)


def nn_scale(Y: np.ndarray) -> float:
    """Median distance from every row of ``Y`` to its nearest other row (the kernel's length unit)."""
    if len(Y) < 2:
        return 1.0
    d, _ = cKDTree(Y).query(Y, k=2)
    s = float(np.median(d[:, 1]))
    if s <= 0:
        pos = d[:, 1][d[:, 1] > 0]
        s = float(np.median(pos)) if pos.size else 1.0
    return s


#: The kernel correction is regressed on at most this many training frames, evenly spaced
#: (:func:`kernel_rows`): one ``n x n`` Cholesky factorisation per candidate and fold made the
#: settings' search of three 2,000-frame takes take 32 of its 43 s; consecutive frames at 25-60 fps
#: are nearly the same observation, so every other frame of a long take carries the same residuals.
KERNEL_FRAMES = 800


def kernel_rows(n: int, cap: int | None = None) -> np.ndarray:
    """Indices of the training frames the kernel correction uses: all of them, or ``cap`` (default
    :data:`KERNEL_FRAMES`) evenly spaced."""
    cap = KERNEL_FRAMES if cap is None else int(cap)
    if n <= cap:
        return np.arange(n)
    return np.unique(np.linspace(0, n - 1, cap).round().astype(int))


def kernel_fit(Ys: np.ndarray, R: np.ndarray, bandwidth: float, ridge: float,
               scale: float | None = None) -> tuple[np.ndarray, float, np.ndarray]:
    """Kernel ridge regression of residuals ``R`` ``(n, m)`` on observations ``Ys`` ``(n, K)``.

    ``bandwidth`` is in units of :func:`nn_scale` of ``Ys`` (or ``scale``).  At most
    :data:`KERNEL_FRAMES` rows, evenly spaced, are used (:func:`kernel_rows`).  Returns
    ``(Ys, h, alpha)`` for :func:`kernel_predict`.
    """
    keep = kernel_rows(len(Ys))
    Ys, R = Ys[keep], R[keep]
    h = float(bandwidth) * (nn_scale(Ys) if scale is None else scale)
    K = np.exp(-_sqdist(Ys, Ys) / (2 * h * h))
    K[np.diag_indices_from(K)] += float(ridge)
    alpha = cho_solve(cho_factor(K, lower=True, check_finite=False), R, check_finite=False)
    return Ys, h, alpha


def kernel_predict(model: tuple[np.ndarray, float, np.ndarray], Y: np.ndarray) -> np.ndarray:
    """The regressed residual ``(T, m)`` at observations ``Y`` ``(T, K)``."""
    Ys, h, alpha = model
    return np.exp(-_sqdist(Y, Ys) / (2 * h * h)) @ alpha


# ------------------------------------------------------------------------------------------ cross-validation
def _prep_val(m, Xva: dict[str, np.ndarray]) -> dict:
    """What :func:`_sse_known` needs of the validation frames for one PCA basis: the observations,
    the PCA coefficients and the squared error outside the basis (the same for every candidate
    sharing the basis)."""
    Yin, Z, out = {}, {}, {}
    for s, x in Xva.items():
        z = (x - m.mean_) @ m.basis_
        Z[s], Yin[s] = z, m._observe(z)
        r = x - m.mean_ - z @ m.basis_.T
        out[s] = r
    perp = {}
    for s in Xva:
        for t in Xva:
            if t != s:
                perp[(s, t)] = float(np.sum((out[s] - out[t]) ** 2)) if m.detail else float(np.sum(out[t] ** 2))
    return {"Y": Yin, "Z": Z, "perp": perp}


def _sse_known(m, Xva: dict[str, np.ndarray], corr=None, prep: dict | None = None) -> float:
    """Squared error of the known-expression task between every ordered pair of styles.

    ``corr(source, Yin) -> {style: correction}`` adds a local correction (source style included).
    ``prep``: :func:`_prep_val` of ``Xva`` for ``m``'s basis.  The error is computed in PCA
    coefficients plus the (fixed) part outside the basis, which equals the error of the frames.
    """
    if prep is None:
        prep = _prep_val(m, Xva)
    A = m.asymmetric_
    sse = 0.0
    for s in Xva:
        Yin = prep["Y"][s]
        b = A.content(Yin, s)
        c = corr(s, Yin) if corr is not None else None
        if m.detail:
            Y0 = A.render(b, s)
            if c is not None:
                Y0 = Y0 + c[s]
            z0 = m._coefs(Y0)
        for t in Xva:
            if t == s:
                continue
            Y = A.render(b, t)
            if c is not None:
                Y = Y + c[t]
            if m.detail:                                                # x_s + dz B' - x_t
                d = prep["Z"][s] - prep["Z"][t] + m._coefs(Y) - z0
            else:                                                       # z B' + mean - x_t
                d = m._coefs(Y) - prep["Z"][t]
            sse += float(np.sum(d * d)) + prep["perp"][(s, t)]
    return sse


def select_settings(make_model, X: dict[str, np.ndarray], *, fixed: dict | None = None, folds: int = 5,
                    gap: int | None = None, grid: dict | None = None, min_frames: int = 30,
                    search: str = "coordinate", points_rest: np.ndarray | None = None,
                    groups: np.ndarray | None = None, step=None) -> Selection:
    """Choose ``variance``, ``energy``, ``prior`` and the local correction by blocked cross-validation.

    Parameters
    ----------
    make_model : callable
        ``make_model(variance=, energy=, prior=)`` -> an unfitted :class:`~._model.StyleModel`
        with the local correction off (its other settings: bundle, offset, dims, detail).
    X : dict of str to (C, D) float
        Aligned training frames of every style.
    fixed : dict, optional
        Settings not to search (``variance``, ``energy``, ``prior``, ``local``).
    folds, gap, grid, min_frames
        See the module docstring; ``grid`` overrides entries of :data:`GRID`.
    search : {"coordinate", "full"}
        Stage 2 over bandwidth x ridge: ``"full"`` scores the whole grid; ``"coordinate"``
        (default) starts in its middle and alternately scores a whole row (every bandwidth at the
        current ridge) and a whole column (every ridge at the current bandwidth), moving to the best
        candidate scored so far, until a row and a column in turn leave it in place.
    points_rest : (P, 3) float, optional
        The mean face when frames are ``(P, 3)`` points: stage 3 then scores the point-local
        translations (:func:`~._pointlocal.score_point_local`) on the same folds, and one wins
        when it beats the bilinear model with its best correction.
    groups : (C,) array, optional
        Which performer (or recording) each aligned frame comes from.  With two or more groups the
        folds are *leave one group out* instead of contiguous blocks: the settings are then chosen
        for what carries to a performer the model has not seen (:func:`group_folds`).
    """
    fixed = dict(fixed or {})
    g = dict(GRID)
    g.update(grid or {})
    styles = list(X)
    C = len(X[styles[0]])
    if C < min_frames:
        d = {k: fixed.get(k, v) for k, v in FALLBACK.items()}
        return Selection(d["variance"], d["energy"], d["prior"], d["local"])
    if groups is not None and len(np.unique(np.asarray(groups))) >= 2:
        splits = group_folds(groups, C)
        folds, gap = len(splits), 0
    else:
        folds, gap, splits = _fold_plan(make_model, C, folds, gap)
    base = _unchanged_error(X, splits)
    vs, es, ps = _candidate_grids(fixed, g)
    table: list[dict] = []
    (v, e, p), pcas = _select_bilinear(make_model, X, splits, vs, es, ps, base, table)
    if step is not None:
        step("settings: bilinear")
    if "local" in fixed:
        local = fixed["local"]
    else:
        local = _select_local(make_model, X, splits, pcas, (v, e, p), g, search, points_rest, base, table)
    if step is not None:
        step("settings: corrections")
    return Selection(v, e, p, local, folds, gap, table)


def _fold_plan(make_model, C: int, folds: int, gap: int | None) -> tuple[int, int, list]:
    """The cross-validation's folds for ``C`` aligned frames.

    ``gap`` defaults to 1 % of the frames, at least the bundle size of ``make_model``'s models;
    ``folds`` is reduced so every block keeps at least ``max(10, 2 gap + 2)`` frames (at least 2
    folds).  Returns ``(folds, gap, splits)`` with ``splits`` from :func:`cv_folds`.
    """
    probe = make_model(variance=0.9999, energy=0.9999, prior=1.0)
    gap = max(int(probe.bundle), C // 100) if gap is None else int(gap)
    folds = int(max(2, min(folds, C // max(10, 2 * gap + 2))))
    splits = cv_folds(C, folds, gap)
    return folds, gap, splits


def _unchanged_error(X: dict[str, np.ndarray], splits: list) -> float:
    """The score's unit: the squared error of leaving the input unchanged.

    Summed over the validation blocks of ``splits`` and every ordered pair of distinct styles
    ``(s, t)`` of ``X`` (``X[s]`` ``(C, D)`` float), ``|X[s] - X[t]|^2``; at least ``1e-300``.
    """
    styles = list(X)
    base = 0.0                                                         # error of leaving the input unchanged
    for _, va in splits:
        for s in styles:
            for t in styles:
                if t != s:
                    base += float(np.sum((X[s][va] - X[t][va]) ** 2))
    return max(base, 1e-300)


def _candidate_grids(fixed: dict, g: dict) -> tuple[list, list, list]:
    """The searched values ``(variances, energies, priors)``: the fixed value alone, else the grid ``g``'s."""
    vs = [fixed["variance"]] if "variance" in fixed else list(g["variance"])
    es = [fixed["energy"]] if "energy" in fixed else list(g["energy"])
    ps = [float(fixed["prior"])] if "prior" in fixed else list(g["prior"])
    return vs, es, ps


# ------------------------------------------------------------------------------------------ stage 1: bilinear
def _select_bilinear(make_model, X: dict[str, np.ndarray], splits: list, vs: list, es: list, ps: list,
                     base: float, table: list) -> tuple[tuple, dict]:
    """Stage 1: the bilinear model's ``(variance, energy, prior)`` with the lowest fold-summed error.

    Every combination of ``vs`` x ``es`` x ``ps`` is scored on every fold (only when there is more
    than one) and appended to ``table`` as a stage-1 row (score relative to ``base``).  Returns the
    winner (ties: the earlier in grid order) and the folds' PCAs ``{fold: pca_of(training frames)}``
    (empty when nothing was scored), which stage 2 reuses.
    """
    cand = [(v, e, p) for v in vs for e in es for p in ps]
    score = dict.fromkeys(cand, 0.0)
    pcas: dict = {}
    if len(cand) > 1:
        for f, (tr, va) in enumerate(splits):
            pcas[f] = _score_bilinear_fold(make_model, X, tr, va, vs, es, ps, score)
        for c in cand:
            table.append({"stage": 1, "variance": c[0], "energy": c[1], "prior": c[2],
                          "score": score[c] / base})
    return min(cand, key=lambda c: score[c]), pcas


def _score_bilinear_fold(make_model, X: dict[str, np.ndarray], tr: np.ndarray, va: np.ndarray, vs: list,
                         es: list, ps: list, score: dict) -> tuple:
    """Add one fold's known-expression error of every ``(v, e, p)`` candidate to ``score``.

    One asymmetric model per variance is fitted on the training frames ``tr``; the energies only
    change its rank and the priors only its content solve, so candidates giving the same ``K`` and
    ``J`` share their errors.  Validated on the frames ``va``.  Returns the fold's
    :func:`pca_of` of the training frames.
    """
    Xtr = {s: x[tr] for s, x in X.items()}
    Xva = {s: x[va] for s, x in X.items()}
    seen: dict[tuple, dict] = {}
    pca = pca_of(Xtr)
    for v in vs:
        m = make_model(variance=v, energy=es[0], prior=ps[0])._fit_resolved(Xtr, symmetric=False, pca=pca)
        A = m.asymmetric_
        prep = _prep_val(m, Xva)
        for e in es:
            A._set_rank(A.content_dims if A.content_dims is not None else
                        choose_dims(A.singular_values_, e, min(A.n_dims, len(A.singular_values_)),
                                    A.keep_first))
            key = (m.n_components_, A.content_dims_)
            if key in seen:                                     # same K and J: the same model
                for p in ps:
                    score[(v, e, p)] += seen[key][p]
                continue
            seen[key] = {}
            for p in ps:
                m.asymmetric_.prior = p
                err = _sse_known(m, Xva, prep=prep)
                seen[key][p] = err
                score[(v, e, p)] += err
    return pca


# ------------------------------------------------------------------------------------------ stage 2: kernel
def _select_local(make_model, X: dict[str, np.ndarray], splits: list, pcas: dict, vep: tuple, g: dict,
                  search: str, points_rest: np.ndarray | None, base: float, table: list):
    """Stages 2 and 3: the local correction for the bilinear settings ``vep = (v, e, p)``.

    Scores no correction and kernel corrections over the bandwidth x ridge grid of ``g`` (all of it
    for ``search="full"``, else :func:`_coordinate_search`), appends them to ``table`` as stage-2
    rows in grid order, and with ``points_rest`` the point-local candidates as stage-3 rows
    (:func:`_select_point_local`).  Returns the winner: ``0``, ``("kernel", h, lam)`` or
    ``("points", m, k)``.
    """
    v, e, p = vep
    H, L = list(g["bandwidth"]), list(g["ridge"])
    s2: dict = {}
    fold_fits: dict = {}

    def evaluate(cands):
        """Add the fold-summed scores of ``cands``' new ``(h, lam)`` to ``s2`` (:func:`_score_kernels`)."""
        _score_kernels(make_model, X, splits, pcas, vep, cands, s2, fold_fits)

    if search == "full":
        evaluate([(h, lam) for h in H for lam in L])
    else:                                                           # coordinate search from the middle
        _coordinate_search(evaluate, H, L, s2)
    specs = [0] + [("kernel", h, lam) for h in H for lam in L if ("kernel", h, lam) in s2]
    for c in specs:
        table.append({"stage": 2, "variance": v, "energy": e, "prior": p,
                      "local": list(c) if c else 0, "score": s2[c] / base})
    local = min(specs, key=lambda c: s2[c])
    if points_rest is not None:                                     # ---- stage 3: point-local translation
        local = _select_point_local(X, splits, points_rest, vep, local, s2[local], base, table)
    return local


def _coordinate_search(evaluate, H: list, L: list, s2: dict) -> None:
    """Coordinate search over bandwidths ``H`` x ridges ``L``, filling the scores ``s2``.

    Starts in the grid's middle and alternately has ``evaluate`` score a whole row (every bandwidth
    at the current ridge) and a whole column (every ridge at the current bandwidth), moving to the
    best candidate scored so far, until a row and a column in turn leave it in place.
    """
    h, lam = H[(len(H) - 1) // 2], L[(len(L) - 1) // 2]
    axis = 0
    while True:
        evaluate([(x, lam) for x in H] if axis == 0 else [(h, x) for x in L])
        best = min(((c[1], c[2]) for c in s2 if c != 0), key=lambda c: s2[("kernel", *c)])
        if best == (h, lam) and axis == 1:
            break
        moved = best != (h, lam)
        h, lam = best
        if not moved and axis == 0:
            axis = 1
            continue
        if not moved:
            break
        axis = 1 - axis


def _score_kernels(make_model, X: dict[str, np.ndarray], splits: list, pcas: dict, vep: tuple, cands: list,
                   s2: dict, fold_fits: dict) -> None:
    """Fold-summed errors of the kernel candidates ``cands`` ``[(h, lam), ...]`` not yet in ``s2``.

    ``s2`` maps ``("kernel", h, lam)`` (and ``0``, no correction, scored on the first call) to the
    summed known-expression error over the folds; new keys are inserted in the order of ``cands``.
    ``fold_fits`` caches every fold's model and residuals (:func:`_kernel_fold_fit`) across calls.
    """
    cands = [c for c in cands if ("kernel", *c) not in s2]
    if not cands and 0 in s2:
        return
    for c in cands:
        s2[("kernel", *c)] = 0.0
    first = 0 not in s2
    if first:
        s2[0] = 0.0
    for f, (tr, va) in enumerate(splits):
        Xva = {s: x[va] for s, x in X.items()}
        if f not in fold_fits:                                   # the fold's model and residuals, once
            fold_fits[f] = _kernel_fold_fit(make_model, X, tr, Xva, vep, pcas.get(f))
        m, pv, res = fold_fits[f]
        if first:
            s2[0] += _sse_known(m, Xva, prep=pv)
        _score_kernel_fold(m, Xva, pv, res, cands, s2)


def _kernel_fold_fit(make_model, X: dict[str, np.ndarray], tr: np.ndarray, Xva: dict[str, np.ndarray],
                     vep: tuple, pca) -> tuple:
    """One fold's bilinear model with settings ``vep = (v, e, p)`` and its training residuals.

    Returns ``(m, pv, res)``: the asymmetric model fitted on the frames ``tr`` (``pca``: the fold's
    :func:`pca_of`, or None), :func:`_prep_val` of the validation frames ``Xva``, and per source
    style ``s`` the tuple ``(Ys, R, scale)``: its training observations ``(n, K)``, the residuals
    ``Y_t - render(content(Ys))`` of every target style ``t`` side by side ``(n, S K)``, and
    :func:`nn_scale` of ``Ys``.
    """
    v, e, p = vep
    styles = list(X)
    Xtr = {s: x[tr] for s, x in X.items()}
    m = make_model(variance=v, energy=e, prior=p)._fit_resolved(Xtr, symmetric=False, pca=pca)
    pv = _prep_val(m, Xva)
    A = m.asymmetric_
    res = {}
    for s in styles:
        Ys = m.encode(Xtr[s])
        b = A.content(Ys, s)
        R = np.concatenate([m.encode(Xtr[t]) - A.render(b, t) for t in styles], axis=1)
        keep = kernel_rows(len(Ys))                         # as kernel_fit will
        res[s] = (Ys[keep], R[keep], nn_scale(Ys[keep]))
    return m, pv, res


def _score_kernel_fold(m, Xva: dict[str, np.ndarray], pv: dict, res: dict, cands: list, s2: dict) -> None:
    """Add one fold's known-expression error of every kernel candidate ``(h, lam)`` of ``cands`` to ``s2``.

    ``m``, ``pv``, ``res``: the fold's model, validation prep and residuals
    (:func:`_kernel_fold_fit`).  The squared distances are computed once, the kernels once per
    bandwidth ``h`` (in units of each source style's :func:`nn_scale`).
    """
    styles = list(res)
    prep = {s: (Ys, R, _sqdist(Ys, Ys), _sqdist(pv["Y"][s], Ys), sc) for s, (Ys, R, sc) in res.items()}
    Kd = prep[styles[0]][0].shape[1]
    for h in dict.fromkeys(c[0] for c in cands):
        kern = {}
        for s in styles:                                    # the kernels, once per bandwidth
            _, _, D2, Dq, sc = prep[s]
            hh = h * sc
            kern[s] = (np.exp(-D2 / (2 * hh * hh)), np.exp(-Dq / (2 * hh * hh)))
        for lam in [c[1] for c in cands if c[0] == h]:
            preds = _kernel_predictions(kern, prep, lam, Kd)
            s2[("kernel", h, lam)] += _sse_known(m, Xva, lambda s, _y, preds=preds: preds[s], prep=pv)


def _kernel_predictions(kern: dict, prep: dict, lam: float, Kd: int) -> dict:
    """The kernel correction with ridge ``lam`` at the validation observations, per source style.

    ``kern[s]``: the training kernel ``(n, n)`` and the validation-by-training kernel ``(T, n)`` of
    source style ``s``; ``prep[s][1]``: its residuals ``(n, S Kd)``.  Returns
    ``{s: {t: (T, Kd) float}}``, the regressed residual of translating ``s`` to every style ``t``.
    """
    styles = list(kern)
    preds = {}
    for s in styles:
        K0, Kq = kern[s]
        K = K0.copy()
        K[np.diag_indices_from(K)] += lam
        P = Kq @ cho_solve(cho_factor(K, lower=True, overwrite_a=True, check_finite=False),
                           prep[s][1], check_finite=False)
        preds[s] = {t: P[:, i * Kd:(i + 1) * Kd] for i, t in enumerate(styles)}
    return preds


# ------------------------------------------------------------------------------------------ stage 3: points
def _select_point_local(X: dict[str, np.ndarray], splits: list, points_rest: np.ndarray, vep: tuple, local,
                        local_score: float, base: float, table: list):
    """Stage 3: the best point-local translation, if it beats the stage-2 winner.

    Scores every ``("points", m, k)`` candidate (:func:`~._pointlocal.score_point_local`) on
    ``splits``, appends them to ``table`` as stage-3 rows, and returns the best one when its error
    is below ``local_score`` (the error of ``local``, the stage-2 winner), else ``local``.
    """
    v, e, p = vep
    s3 = score_point_local(X, splits, points_rest)
    for c, sc in s3.items():
        table.append({"stage": 3, "variance": v, "energy": e, "prior": p, "local": list(c),
                      "score": sc / base})
    best3 = min(s3, key=s3.get)
    if s3[best3] < local_score:
        local = best3
    return local


# ------------------------------------------------------------------------------------------ untrained styles
#: Searched shrinkage of a new style's matrix (:func:`select_style_ridge`), relative to the mean squared content.
STYLE_RIDGE_GRID: tuple[float, ...] = (0.0, 1e-4, 1e-3, 1e-2, 1e-1, 1.0, 10.0, 100.0)


def ones_weights(B: np.ndarray) -> np.ndarray:
    """``w`` ``(J,)`` with ``B w ~ 1`` (least squares over the rows of ``B``): ``d w'`` adds a constant ``d``."""
    w, *_ = np.linalg.lstsq(B, np.ones(len(B)), rcond=None)
    return w


def select_style_ridge(b: np.ndarray, Yn: np.ndarray, Yk: np.ndarray, Ak: np.ndarray, w: np.ndarray, *,
                       score_cols: np.ndarray, detail: bool = True, local=0, bundle: int = 1, folds: int = 5,
                       grid: tuple[float, ...] = STYLE_RIDGE_GRID, min_frames: int = 30) -> tuple[float, list]:
    """Shrinkage of an untrained style's matrix, by blocked cross-validation on its own examples.

    The new matrix is ``A = argmin ||Yn - b A'||^2 + ridge tr(b'b)/J ||A - A0||^2`` with
    ``A0 = Ak + d w'``: the known style's matrix plus the mean difference ``d`` of the examples
    (``b w ~ 1``), so ``ridge -> inf`` is the additive offset and ``ridge = 0`` the plain least
    squares.  Every ``ridge`` of ``grid`` is scored on the known-expression task ``known -> new``
    over contiguous folds of the examples (gap as in :func:`select_settings`; ``d`` and the kernel
    correction, when ``local`` is one, from the fold's training frames), on the coordinates
    ``score_cols`` (not the constant ones); lowest error wins (ties: the smaller ridge).

    Fewer than ``min_frames`` examples: no search; ``ridge = J / T`` (stronger the fewer frames
    there are per content dimension).  Returns ``(ridge, table)``.
    """
    T, J = b.shape
    if T < min_frames:
        return float(J) / max(T, 1), []
    gap = max(int(bundle), T // 100)
    nf = int(max(2, min(folds, T // max(10, 2 * gap + 2))))
    grid = tuple(float(r) for r in grid)
    err = np.zeros(len(grid))
    kern = isinstance(local, tuple) and local[0] == "kernel"
    for tr, va in cv_folds(T, nf, gap):
        btr, bva = b[tr], b[va]
        d = (Yn[tr] - Yk[tr]).mean(0)
        A0 = Ak + np.outer(d, w)
        As = [_ridge_map(btr, Yn[tr], r, A0) for r in grid]
        if kern:
            Ys = Yk[tr]
            h = float(local[1]) * nn_scale(Ys)
            Km = np.exp(-_sqdist(Ys, Ys) / (2 * h * h))
            Km[np.diag_indices_from(Km)] += float(local[2])
            Kq = np.exp(-_sqdist(Yk[va], Ys) / (2 * h * h))
            Rss = Ys - btr @ Ak.T
            R = np.concatenate([Rss] + [Yn[tr] - btr @ A.T for A in As], axis=1)
            P = Kq @ cho_solve(cho_factor(Km, lower=True, check_finite=False), R, check_finite=False)
            n = Ys.shape[1]
            Pss = P[:, :n]
        for i, A in enumerate(As):
            if detail:
                pred = Yk[va] + bva @ (A - Ak).T
            else:
                pred = bva @ A.T
            if kern:
                pred = pred + P[:, (i + 1) * n:(i + 2) * n] - (Pss if detail else 0.0)
            err[i] += float(np.sum((Yn[va][:, score_cols] - pred[:, score_cols]) ** 2))
    table = [{"ridge": r, "score": float(e)} for r, e in zip(grid, err, strict=True)]
    return grid[int(np.argmin(err))], table

