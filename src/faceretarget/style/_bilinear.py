"""Bilinear style/content models (Tenenbaum & Freeman 2000; Chuang 2004, Sec. 2.3).

Training data are ``S`` styles (emotions) times ``C`` contents (aligned frames of the same text)
of ``K``-dimensional observations, an array ``Y`` of shape ``(S, C, K)``.

**Asymmetric model** (Chuang Eq. 2.8, 2.9): every style has its own linear map of a shared content
vector, ``y_sc = A_s b_c`` with ``A_s`` ``(K, J)`` and ``b_c`` ``(J,)``.  Stacking the styles'
observations into one ``(S K, C)`` matrix ``Y = [A_1; ...; A_S] [b_1 ... b_C]``, the least-squares
fit of rank ``J`` is its truncated SVD ``Y ~ U_J S_J V_J'``: the stacked ``A = U_J S_J`` and
``B = V_J'``.

**Symmetric model** (Chuang Eq. 2.6, 2.7): style and content are both vectors, of ``I`` and ``J``
dimensions, and interact through a core tensor ``W`` ``(I, J, K)``::

    y_sc,k = sum_ij a_s,i W_ijk b_c,j

Tenenbaum & Freeman fit it by alternating SVDs of "vector transposed" matrices: with ``B``
fixed, the SVD of ``(Y B')^VT`` gives the style vectors (its first ``I`` right singular
vectors); with ``A`` fixed, the SVD of ``(Y^VT A')^VT`` gives the content vectors; repeat until the
fit stops improving; then ``W = ((Y B')^VT A')^VT``.  The vector transpose only re-indexes the
three-way array, so here the same steps are written as products along the style and the content
axis of ``Y`` (the higher-order orthogonal iteration): the style step is the SVD of ``Y`` projected
on the content vectors, reshaped ``(S, J K)``, the content step the SVD of ``Y`` projected on the
style vectors, reshaped ``(C, I K)``.  With orthonormal style and content vectors the squared
error is ``||Y||^2 - ||W||^2`` and every step can only lower it (:attr:`objective_`).

**Dimensions.**  ``J`` (and ``I``) are the smallest numbers whose components keep a fraction
``energy`` of the squared singular values of the stacked matrix (of ``Y`` reshaped ``(S, C K)`` for
``I``), not counting the first ``keep_first`` components, which are always kept; ``J`` is at most
``K`` (content must be recoverable from one style's observation, Eq. 2.10) and ``I`` at most
``S``.  ``content_dims`` / ``style_dims`` override the rule.

**Tasks** (Sec. 2.3.3): known expression: the content of an observation in a known style is the
least-squares ``b = A_s^+ y`` (Eq. 2.10) and ``A_t b`` renders it in style ``t`` (Eq. 2.11); with the
symmetric model, content given style ``b = [W a]^+ y`` and style given content ``a = [W^VT b]^+ y``
(Eq. 2.12, 2.13) alternate to infer both (:meth:`SymmetricBilinearModel.infer`); a new style is
fitted from examples with known content (:meth:`AsymmetricBilinearModel.fit_style`).

**Content prior** (our addition, on by default, ``prior=False`` for the thesis's plain solve): the
least-squares content ``A_s^+ y`` amplifies noise along content directions that style ``s`` barely
shows (components that only another style expresses give ``A_s`` tiny singular values; on the P3
data ``cond(A_neutral)`` reaches 1e4 to 1e6).  The models therefore keep the mean ``mu`` and
covariance ``Sigma`` of the training content vectors and the residual variance ``sigma^2`` per
coordinate of every style, and solve for the most probable content under ``b ~ N(mu, Sigma)``,
``y = A_s b + N(0, sigma^2 I)``::

    b = (A_s' A_s + sigma^2 Sigma^-1)^-1 (A_s' y + sigma^2 Sigma^-1 mu)

which is Eq. 2.10 where the data determine the content and the training mean where they do not;
``A_t b`` is then the conditional expectation of the target-style observation.  ``prior`` may be a
number ``p``, the prior's strength: ``sigma^2`` is replaced by ``p sigma^2`` (``True`` is 1, ``False``
or 0 the plain solve; large ``p`` pulls every content to the training mean, so a translation
tends to adding the mean style difference, the additive baseline).  :class:`~._model.StyleModel`
chooses ``p`` by cross-validation on its training frames (:mod:`._select`).

Files: ``save`` / ``load`` of :class:`~faceretarget.base.Model` (one ``.npz`` format for every model).
"""

from __future__ import annotations

import numpy as np

from ..base import Model
from ..errors import InvalidDataError

__all__ = [
    "AsymmetricBilinearModel",
    "SymmetricBilinearModel",
    "InferResult",
    "choose_dims",
    "BilinearModel",
]


def choose_dims(singular_values: np.ndarray, energy: float, cap: int, keep_first: int = 0) -> int:
    """The number of components that keep ``energy`` of the squared singular values.

    Parameters
    ----------
    singular_values : (n,) float
        In decreasing order.
    energy : float
        Fraction in (0, 1].
    cap : int
        At most this many.
    keep_first : int
        Components always kept and left out of the energy count.

    Returns
    -------
    int
        ``keep_first + m`` with ``m`` the smallest count whose squared singular values (after the
        first ``keep_first``) sum to at least ``energy`` of theirs, clipped to ``[1, cap]``.

    Examples
    --------
    >>> choose_dims(np.array([3.0, 2.0, 1.0, 1e-9]), 0.999, 4)
    3
    """
    s2 = np.asarray(singular_values, np.float64) ** 2
    if not (0 < energy <= 1):
        raise InvalidDataError(f"energy must be in (0, 1], got {energy}")
    rest = s2[keep_first:]
    total = float(rest.sum())
    if total <= 0:
        m = 0
    else:
        frac = np.cumsum(rest) / total
        m = int(np.searchsorted(frac, energy * (1 - 1e-12)) + 1)
    return int(max(1, min(cap, keep_first + m, len(s2))))


def _check_Y(Y) -> np.ndarray:
    Y = np.asarray(Y, np.float64)
    if Y.ndim != 3:
        raise InvalidDataError(f"training data must be (styles, contents, dims), got shape {Y.shape}")
    S, C, K = Y.shape
    if S < 2:
        raise InvalidDataError(f"a style/content model needs at least 2 styles, got {S}")
    if C < 2 or K < 1:
        raise InvalidDataError(f"training data needs at least 2 contents and 1 dimension, got {Y.shape}")
    if not np.isfinite(Y).all():
        s, c, _ = (int(v[0]) for v in np.nonzero(~np.isfinite(Y)))
        raise InvalidDataError(f"training data: style {s} content {c} is not finite")
    return Y


def _style_names(styles, S: int) -> list[str]:
    if styles is None:
        return [f"style{i}" for i in range(S)]
    names = [str(s) for s in styles]
    if len(names) != S or len(set(names)) != S:
        raise InvalidDataError(f"need {S} distinct style names, got {names}")
    return names


def _frames(y, K: int, what: str) -> tuple[np.ndarray, bool]:
    y = np.asarray(y, np.float64)
    single = y.ndim == 1
    if single:
        y = y[None]
    if y.ndim != 2 or y.shape[1] != K:
        raise InvalidDataError(f"{what} must be (frames, {K}), got {y.shape}")
    if not np.isfinite(y).all():
        raise InvalidDataError(f"{what}: frame {int(np.flatnonzero(~np.isfinite(y).all(1))[0])} is not finite")
    return y, single


def _content_prior(B: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Mean ``(J,)`` and precision ``(J, J)`` of training content vectors ``B`` ``(C, J)``."""
    mu = B.mean(0)
    cov = np.atleast_2d(np.cov(B.T))
    cov = cov + 1e-10 * max(float(np.trace(cov)) / len(cov), 1e-300) * np.eye(len(cov))
    return mu, np.linalg.inv(cov)


def _solve_content(M: np.ndarray, y: np.ndarray, prec: np.ndarray | None, mu: np.ndarray | None,
                   var) -> np.ndarray:
    """Contents for ``y_t = M' b_t``: ``M`` ``(J, K)`` shared or ``(T, J, K)`` per frame; MAP with a prior."""
    if M.ndim == 2:
        G = M @ M.T
        r = y @ M.T
        if prec is not None:
            G = G + var * prec
            r = r + var * (prec @ mu)
        J = len(G)
        G = G + 1e-12 * max(float(np.trace(G)) / J, 1e-300) * np.eye(J)
        return np.linalg.solve(G, r.T).T
    G = M @ M.transpose(0, 2, 1)
    r = np.einsum("tjk,tk->tj", M, y)
    if prec is not None:
        G = G + var * prec
        r = r + var * (prec @ mu)
    J = G.shape[1]
    eps = 1e-12 * np.maximum(np.trace(G, axis1=1, axis2=2) / J, 1e-300)
    return np.linalg.solve(G + eps[:, None, None] * np.eye(J), r[..., None])[..., 0]


def _ridge_map(b: np.ndarray, y: np.ndarray, ridge: float, toward: np.ndarray | None) -> np.ndarray:
    """``A`` ``(K, J)`` minimising ``||y - b A'||^2 + ridge tr(b'b) / J ||A - A0||^2`` (``A0 = toward`` or 0)."""
    G = b.T @ b
    J = len(G)
    lam = max(float(ridge), 1e-12) * max(float(np.trace(G)) / J, 1e-300)
    r = b.T @ y                                                        # (J, K)
    if toward is not None:
        r = r + lam * np.asarray(toward, np.float64).T
    return np.linalg.solve(G + lam * np.eye(J), r).T


class BilinearModel(Model):
    """What the asymmetric and symmetric models share (``BilinearModel.load`` reads either)."""

    kind = ""

    def style_index(self, style) -> int:
        """Index of a style given by name or index."""
        self._check_fitted()
        if isinstance(style, (int, np.integer)):
            if not 0 <= int(style) < len(self.styles_):
                raise InvalidDataError(f"style index {style} outside 0..{len(self.styles_) - 1}")
            return int(style)
        if style not in self.styles_:
            raise InvalidDataError(f"unknown style '{style}'; the model has {', '.join(self.styles_)}")
        return self.styles_.index(style)


# ============================================================================================ asymmetric
class AsymmetricBilinearModel(BilinearModel):
    """``y_sc = A_s b_c``: one linear map per style of a shared content vector (Eq. 2.8, 2.9).

    Parameters
    ----------
    content_dims : int, optional
        ``J``; default from ``energy``.
    energy : float
        Retained energy of the dimension rule (module docstring).
    keep_first : int
        Leading components always kept and left out of the energy count (1 when the data carry a
        constant coordinate, whose component is each style's mean).

    Attributes
    ----------
    styles_ : list of str
    style_matrices_ : (S, K, J) float
        ``A_s``.
    content_vectors_ : (C, J) float
        ``b_c`` of the training contents.
    singular_values_ : (min(SK, C),) float
        Of the stacked training matrix.
    noise_var_ : (S,) float
        Mean squared training residual per coordinate of every style (``sigma^2`` of the prior).
    content_dims_ : int
    rmse_ : float
        Root mean square training residual per coordinate.
    """

    kind = "asymmetric"

    def __init__(self, content_dims: int | None = None, energy: float = 0.999, keep_first: int = 0,
                 prior: bool | float = True):
        self.content_dims = content_dims
        self.energy = energy
        self.keep_first = keep_first
        self.prior = prior

    def fit(self, Y, styles=None) -> AsymmetricBilinearModel:
        """Fit to training data ``Y`` ``(S, C, K)`` (style ``s``, content ``c``); returns self."""
        Y = _check_Y(Y)
        self.__dict__.pop("_prior_cache", None)
        S, C, K = Y.shape
        M = Y.transpose(0, 2, 1).reshape(S * K, C)
        U, s, Vt = np.linalg.svd(M, full_matrices=False)
        cap = min(K, len(s))
        J = int(self.content_dims) if self.content_dims is not None else choose_dims(s, self.energy, cap,
                                                                                      self.keep_first)
        if not 1 <= J <= cap:
            raise InvalidDataError(f"content_dims must be in 1..{cap} (at most the {K} dimensions), got {J}")
        self.styles_ = _style_names(styles, S)
        self.singular_values_ = s
        self._svd = (M, U, s, Vt, S, K, C)
        return self._set_rank(J)

    def _set_rank(self, J: int) -> AsymmetricBilinearModel:
        """Keep ``J`` components of the training SVD (right after :meth:`fit`; the selection tries several)."""
        M, U, s, Vt, S, K, C = self._svd
        self.__dict__.pop("_prior_cache", None)
        self.style_matrices_ = (U[:, :J] * s[:J]).reshape(S, K, J)
        self.content_vectors_ = Vt[:J].T.copy()
        self.content_dims_ = J
        R = M - (U[:, :J] * s[:J]) @ Vt[:J]
        self.rmse_ = float(np.sqrt(np.mean(R**2)))
        self.noise_var_ = np.maximum((R**2).reshape(S, K * C).mean(1), 1e-300)
        return self

    @property
    def n_dims(self) -> int:
        return int(self.style_matrices_.shape[1])

    def _prior(self):
        if not hasattr(self, "_prior_cache"):
            self._prior_cache = _content_prior(self.content_vectors_)
        return self._prior_cache

    def style_matrix(self, style) -> np.ndarray:
        """``A_s`` ``(K, J)`` of a style (name or index), or a given ``(K, J)`` matrix unchanged."""
        if isinstance(style, np.ndarray) and style.ndim == 2:
            return style
        return self.style_matrices_[self.style_index(style)]

    def content(self, y, style, *, prior: bool | None = None) -> np.ndarray:
        """Content of observations in a known style (Eq. 2.10).

        Parameters
        ----------
        y : (T, K) or (K,) float
        style : str or int
        prior : bool, optional
            Most probable content under the content prior (module docstring); ``False``: the
            thesis's least-squares ``b = A_s^+ y``.  Default: the model's ``prior``.

        Returns
        -------
        (T, J) or (J,) float
        """
        self._check_fitted()
        y, single = _frames(y, self.n_dims, "observations")
        use = self.prior if prior is None else prior
        i = self.style_index(style)
        A = self.style_matrices_[i]
        if use:
            mu, prec = self._prior()
            b = _solve_content(A.T, y, prec, mu, float(use) * float(self.noise_var_[i]))
        else:
            b = y @ np.linalg.pinv(A).T
        return b[0] if single else b

    def render(self, b, style) -> np.ndarray:
        """Observations of contents ``b`` ``(T, J)`` in a style, ``y = A_s b`` (Eq. 2.11)."""
        self._check_fitted()
        b, single = _frames(b, self.content_dims_, "content vectors")
        y = b @ self.style_matrix(style).T
        return y[0] if single else y

    def translate(self, y, source, target, *, prior: bool | None = None) -> np.ndarray:
        """Known expression: the content of ``y`` (style ``source``) rendered in ``target`` (Eq. 2.10, 2.11)."""
        return self.render(self.content(y, source, prior=prior), target)

    def interpolate(self, b, source, target, alpha) -> np.ndarray:
        """Eq. 2.15: contents ``b`` in the style ``(1 - alpha) A_source + alpha A_target``.

        ``alpha`` is a number or ``(T,)`` per frame; outside [0, 1] it extrapolates (exaggerates).
        """
        b, single = _frames(b, self.content_dims_, "content vectors")
        As, At = self.style_matrix(source), self.style_matrix(target)
        al = np.broadcast_to(np.asarray(alpha, np.float64).reshape(-1, 1), (len(b), 1))
        y = (1 - al) * (b @ As.T) + al * (b @ At.T)
        return y[0] if single else y

    def fit_style(self, y, b, *, ridge: float = 0.0, toward: np.ndarray | None = None) -> np.ndarray:
        """A new style's matrix from examples with known content: ``A = argmin ||A b - y||``.

        Parameters
        ----------
        y : (T, K) float
            Observations in the new style.
        b : (T, J) float
            Their contents (for example :meth:`content` of the same frames in a known style).
        ridge : float
            Tikhonov weight relative to the mean squared content (0: plain least squares):
            ``A = argmin ||A b - y||^2 + ridge tr(b'b) / J ||A - A0||^2``.
        toward : (K, J) float, optional
            ``A0``, the matrix the estimate is shrunk towards (default 0).

        Returns
        -------
        (K, J) float
        """
        self._check_fitted()
        y, _ = _frames(y, self.n_dims, "new-style observations")
        b, _ = _frames(b, self.content_dims_, "content vectors")
        if len(y) != len(b):
            raise InvalidDataError(f"{len(y)} new-style frames but {len(b)} content vectors")
        if ridge <= 0 and len(y) < self.content_dims_:
            raise InvalidDataError(f"a new style needs at least {self.content_dims_} example frames, got {len(y)} "
                                   "(or a ridge > 0)")
        return _ridge_map(b, y, ridge, toward)

    def insert_dims(self, positions) -> AsymmetricBilinearModel:
        """Insert zero observation coordinates before ``positions`` (as :func:`numpy.insert`); returns self.

        Used when the observation space grows (a new style moves the face in new directions): the
        existing styles do not move along the new coordinates.
        """
        self._check_fitted()
        self.style_matrices_ = np.insert(self.style_matrices_, positions, 0.0, axis=1)
        return self

    def add_style(self, name: str, y, b, *, ridge: float = 0.0, toward: np.ndarray | None = None
                  ) -> AsymmetricBilinearModel:
        """Fit (:meth:`fit_style`) and append a new style; returns self."""
        if name in self.styles_:
            raise InvalidDataError(f"style '{name}' is already in the model")
        A = self.fit_style(y, b, ridge=ridge, toward=toward)
        y, _ = _frames(y, self.n_dims, "new-style observations")
        var = max(float(np.mean((y - np.asarray(b) @ A.T) ** 2)), 1e-300)
        self.style_matrices_ = np.concatenate([self.style_matrices_, A[None]])
        self.noise_var_ = np.append(self.noise_var_, var)
        self.styles_ = [*self.styles_, str(name)]
        return self


def _style_windows(T: int, window: int | None) -> tuple[np.ndarray, np.ndarray]:
    """Style windows of ``window`` frames (all ``T`` when None), for :meth:`SymmetricBilinearModel.infer`.

    Returns the window boundaries ``(n_windows + 1,) int`` and every frame's window ``(T,) int``.
    """
    n = T if window is None else int(window)
    if n < 1:
        raise InvalidDataError(f"style window must be >= 1 frame, got {window}")
    windows = np.append(np.arange(0, T, n), T)
    widx = np.repeat(np.arange(len(windows) - 1), np.diff(windows))
    return windows, widx


def _window_means(v: np.ndarray, windows: np.ndarray) -> np.ndarray:
    """Mean ``(n_windows,)`` of the per-frame values ``v`` ``(T,)`` over every window."""
    return np.add.reduceat(v, windows[:-1]) / np.diff(windows)


def _rescale_windows(aw: np.ndarray, b: np.ndarray, widx: np.ndarray, m1: np.ndarray,
                     ref: float) -> tuple[np.ndarray, np.ndarray]:
    """``(aw l, b / l)`` with ``l = m1 / ref`` per window (1 where ``m1`` is about 0), so ``m1 -> ref``.

    ``aw`` ``(n_windows, I)`` window styles, ``b`` ``(T, J)`` contents, ``widx`` ``(T,)`` each frame's
    window, ``m1`` ``(n_windows,)`` the windows' current values of the quantity to bring to ``ref``.
    """
    lam = np.where(np.abs(m1) > 1e-12 * abs(ref), m1 / ref, 1.0)
    return aw * lam[:, None], b / lam[widx][:, None]


# ============================================================================================ symmetric
class InferResult:
    """What :meth:`SymmetricBilinearModel.infer` found.

    Attributes
    ----------
    style : (T, I) float
        Style vector of every frame (constant over each window).
    content : (T, J) float
    window_style : (n_windows, I) float
    windows : (n_windows + 1,) int
        Frame boundaries of the windows.
    nearest : (T,) int
        Index of the training style nearest to each frame's style vector.
    history : list of float
        Mean squared residual per coordinate after each iteration.
    n_iter : int
    reset : int
        How often a frame's first content component was re-initialised.
    """

    def __init__(self, style, content, window_style, windows, nearest, history, n_iter, reset):
        self.style, self.content, self.window_style, self.windows = style, content, window_style, windows
        self.nearest, self.history, self.n_iter, self.reset = nearest, history, n_iter, reset


class SymmetricBilinearModel(BilinearModel):
    """``y_k = sum_ij a_i W_ijk b_j``: style and content vectors through a core tensor (Eq. 2.6, 2.7).

    Parameters
    ----------
    style_dims, content_dims : int, optional
        ``I`` and ``J``; default from ``energy``.
    energy : float
        Retained energy of the dimension rule (module docstring).
    keep_first : int
        Leading components always kept and left out of the energy count.
    max_iter : int
        Alternating iterations of the fit.
    tol : float
        Stop when the squared error falls by less than ``tol`` times ``||Y||^2`` in an iteration.
    prior : bool
        Solve for content under the content prior (module docstring) by default.
    init : "svd" or int
        Initial content vectors: the asymmetric model's (``"svd"``, Tenenbaum & Freeman), or
        random orthonormal ones from this seed (to watch the alternation converge).

    Attributes
    ----------
    styles_ : list of str
    core_ : (I, J, K) float
        ``W``.
    style_vectors_ : (S, I) float
        ``a_s`` (orthonormal columns).
    content_vectors_ : (C, J) float
        ``b_c`` (orthonormal columns).
    objective_ : (n_iter + 1,) float
        Squared training error ``||Y - W x A x B||^2`` at the start (initial content vectors with
        their best style vectors) and after each iteration.
    n_iter_ : int
    style_dims_, content_dims_ : int
    noise_var_ : float
        Mean squared training residual per coordinate (``sigma^2`` of the content prior).
    rmse_ : float
    """

    kind = "symmetric"

    def __init__(self, style_dims: int | None = None, content_dims: int | None = None, energy: float = 0.999,
                 keep_first: int = 0, max_iter: int = 200, tol: float = 1e-12, prior: bool | float = True,
                 init: str | int = "svd"):
        self.init = init
        self.style_dims = style_dims
        self.content_dims = content_dims
        self.energy = energy
        self.keep_first = keep_first
        self.max_iter = max_iter
        self.tol = tol
        self.prior = prior

    def fit(self, Y, styles=None) -> SymmetricBilinearModel:
        """Fit to training data ``Y`` ``(S, C, K)`` by alternating SVDs; returns self."""
        Y = _check_Y(Y)
        self.__dict__.pop("_prior_cache", None)
        S, C, K = Y.shape
        s_c = np.linalg.svd(Y.transpose(0, 2, 1).reshape(S * K, C), compute_uv=False)
        s_s = np.linalg.svd(Y.reshape(S, C * K), compute_uv=False)
        capJ, capI = min(K, C, S * K), S
        J = int(self.content_dims) if self.content_dims is not None else choose_dims(s_c, self.energy, capJ,
                                                                                      self.keep_first)
        I = int(self.style_dims) if self.style_dims is not None else choose_dims(s_s, self.energy, capI,
                                                                                  self.keep_first)
        if not 1 <= J <= capJ:
            raise InvalidDataError(f"content_dims must be in 1..{capJ}, got {J}")
        if not 1 <= I <= capI:
            raise InvalidDataError(f"style_dims must be in 1..{capI} (the number of styles), got {I}")
        total = float(np.sum(Y**2))
        if isinstance(self.init, str):
            if self.init != "svd":
                raise InvalidDataError(f"init must be 'svd' or a random seed, got '{self.init}'")
            # initial content vectors: the asymmetric model's (T&F Sec. 3.2)
            B = np.linalg.svd(Y.transpose(0, 2, 1).reshape(S * K, C), full_matrices=False)[2][:J].T
        else:
            B = np.linalg.qr(np.random.default_rng(int(self.init)).standard_normal((C, J)))[0]
        A = None
        hist = []
        for it in range(self.max_iter + 1):
            Z = np.einsum("sck,cj->sjk", Y, B).reshape(S, J * K)        # (Y B')^VT, transposed
            Us, ss, _ = np.linalg.svd(Z, full_matrices=False)
            A = Us[:, :I]
            if it == 0:                                                 # the starting point's error
                hist.append(max(total - float(np.sum(ss[:I] ** 2)), 0.0))
            Z2 = np.einsum("sck,si->cik", Y, A).reshape(C, I * K)       # (Y^VT A')^VT, transposed
            Uc, sc, _ = np.linalg.svd(Z2, full_matrices=False)
            B = Uc[:, :J]
            err = total - float(np.sum(sc[:J] ** 2))                    # ||Y||^2 - ||W||^2
            hist.append(max(err, 0.0))
            if hist[-2] - hist[-1] <= self.tol * total:
                break
        W = np.einsum("sck,si,cj->ijk", Y, A, B)
        # deterministic signs: the first coordinate of every style / content vector's sum positive
        sa = np.sign(A.sum(0))
        sa[sa == 0] = 1
        sb = np.sign(B.sum(0))
        sb[sb == 0] = 1
        A, B = A * sa, B * sb
        W = W * sa[:, None, None] * sb[None, :, None]
        self.styles_ = _style_names(styles, S)
        self.core_ = W
        self.style_vectors_ = A
        self.content_vectors_ = B
        self.objective_ = np.asarray(hist)
        self.n_iter_ = len(hist) - 1
        self.style_dims_, self.content_dims_ = I, J
        R = Y - np.einsum("ijk,si,cj->sck", W, A, B)
        self.rmse_ = float(np.sqrt(np.mean(R**2)))
        self.noise_var_ = np.array(max(self.rmse_**2, 1e-300))
        return self

    @property
    def n_dims(self) -> int:
        return int(self.core_.shape[2])

    def _prior(self):
        if not hasattr(self, "_prior_cache"):
            self._prior_cache = _content_prior(self.content_vectors_)
        return self._prior_cache

    def style_vector(self, style) -> np.ndarray:
        """``a_s`` ``(I,)`` of a style (name or index), or a given ``(I,)`` vector unchanged."""
        if isinstance(style, np.ndarray) and style.ndim == 1:
            return style
        return self.style_vectors_[self.style_index(style)]

    def render(self, b, a) -> np.ndarray:
        """``y_k = sum_ij a_i W_ijk b_j`` for contents ``b`` ``(T, J)`` and a style (``(I,)``, ``(T, I)`` or a name)."""
        self._check_fitted()
        b, single = _frames(b, self.content_dims_, "content vectors")
        a = self.style_vector(a) if not (isinstance(a, np.ndarray) and a.ndim == 2) else a
        a = np.broadcast_to(np.asarray(a, np.float64), (len(b), self.style_dims_))
        y = np.einsum("ti,ijk,tj->tk", a, self.core_, b, optimize=True)
        return y[0] if single else y

    def content(self, y, a, *, prior: bool | None = None) -> np.ndarray:
        """Content given the style: ``b = [W a]^+ y`` (Eq. 2.12); ``a`` a style name, ``(I,)`` or ``(T, I)``.

        ``prior``: most probable content under the content prior (default: the model's ``prior``).
        """
        self._check_fitted()
        y, single = _frames(y, self.n_dims, "observations")
        use = self.prior if prior is None else prior
        if isinstance(a, np.ndarray) and a.ndim == 2:
            if a.shape != (len(y), self.style_dims_):
                raise InvalidDataError(f"per-frame styles must be ({len(y)}, {self.style_dims_}), got {a.shape}")
            mu, prec = self._prior() if use else (None, None)
            Ma = np.einsum("ti,ijk->tjk", a, self.core_)
            b = _solve_content(Ma, y, prec, mu, float(use) * float(self.noise_var_))
        else:
            b = self._content(y, self.style_vector(a)[None], np.array([0, len(y)]), None, use)
        return b[0] if single else b

    def _content(self, y, aw, windows, fixed_first, prior: bool):
        """Contents with style ``aw[w]`` over frames ``windows[w]:windows[w + 1]``.

        ``fixed_first`` (T,): the first component where finite (solved for the others), else NaN.
        """
        mu, prec = self._prior() if prior else (None, None)
        var = float(prior) * float(self.noise_var_)
        J = self.content_dims_
        Ma = np.einsum("wi,ijk->wjk", aw, self.core_)                   # y_t = Ma_w' b_t
        G = Ma @ Ma.transpose(0, 2, 1)
        if prior:
            G = G + var * prec
            P11 = prec[1:, 1:]
        b = np.empty((len(y), J))
        for w in range(len(aw)):
            s, e = int(windows[w]), int(windows[w + 1])
            r = y[s:e] @ Ma[w].T
            if prior:
                r = r + var * (prec @ mu)
            Gw = G[w] + 1e-12 * max(float(np.trace(G[w])) / J, 1e-300) * np.eye(J)
            bw = np.linalg.solve(Gw, r.T).T
            if fixed_first is not None and J > 1:
                m = np.flatnonzero(np.isfinite(fixed_first[s:e]))
                if m.size:
                    f = fixed_first[s:e][m]
                    yr = y[s:e][m] - f[:, None] * Ma[w, 0]
                    G1 = Ma[w, 1:] @ Ma[w, 1:].T
                    r1 = yr @ Ma[w, 1:].T
                    if prior:
                        # the prior of the other components given the first (Gaussian conditioning)
                        mr = mu[1:][None] - np.linalg.solve(P11, prec[1:, :1] @ (f[None] - mu[:1, None])).T
                        G1 = G1 + var * P11
                        r1 = r1 + var * (mr @ P11.T)
                    G1 = G1 + 1e-12 * max(float(np.trace(G1)) / (J - 1), 1e-300) * np.eye(J - 1)
                    b1 = np.linalg.solve(G1, r1.T).T
                    bw[m] = np.concatenate([f[:, None], b1], axis=1)
            b[s:e] = bw
        return b

    def _style(self, y, b, windows):
        """Least-squares style vector of every window given the contents (Eq. 2.13)."""
        Mb = np.einsum("tj,ijk->tik", b, self.core_)                    # (T, I, K): y_t = Mb_t' a
        G = Mb @ Mb.transpose(0, 2, 1)
        r = np.einsum("tik,tk->ti", Mb, y)
        Gw = np.add.reduceat(G, windows[:-1], axis=0)
        rw = np.add.reduceat(r, windows[:-1], axis=0)
        I = self.style_dims_
        eps = 1e-12 * np.maximum(np.trace(Gw, axis1=1, axis2=2) / I, 1e-300)
        return np.linalg.solve(Gw + eps[:, None, None] * np.eye(I), rw[..., None])[..., 0]

    def infer(self, y, *, window: int | None = None, max_iter: int = 100, tol: float = 1e-10,
              init=None, reinit_first: bool = True, margin: float = 0.5, prior: bool | None = None,
              anchor: tuple[np.ndarray, float] | None = None) -> InferResult:
        """Unknown expression: alternate content given style and style given content (Eq. 2.12, 2.13).

        The style is held constant over windows of ``window`` frames (the whole input when
        ``None``); the content is free per frame.  Starting from the mean training style vector
        (or ``init``), every iteration solves all contents, re-initialises the first content
        component where it left the training range, solves every window's style, and fixes the
        bilinear scale ambiguity (``a -> l a``, ``b -> b / l``, which leaves the fit unchanged but
        scales any re-rendering in another style): with ``anchor`` by the coordinates every training
        style reproduces as a constant (the pipeline's constant coordinate), else by scaling each
        window so its mean first content component equals the training mean.

        First-content-component re-initialisation: the first content component of the training
        contents spans a narrow range (with a constant coordinate in the data it is the component
        that carries each style's mean face).  During the alternation a frame whose first component
        leaves that range, widened by ``margin`` times its width on both sides, has it reset to the
        training mean and the other components solved again with it fixed; without this the
        alternation can trade style for content and drift out of the space the model was trained
        on.  The returned contents are solved freely given the final styles.

        Parameters
        ----------
        y : (T, K) float
        window : int, optional
            Frames per style window.
        max_iter : int
        tol : float
            Stop when the mean squared residual changes by less than ``tol`` times the mean square
            of ``y``.
        init : (I,) float or str, optional
            Initial style.
        reinit_first : bool
            Apply the re-initialisation.
        margin : float
            See above.
        prior : bool, optional
            Content solves under the content prior (default: the model's ``prior``).
        anchor : (indices, value), optional
            Observation coordinates that are ``value`` in every training style (a constant
            coordinate); the scale of each window is chosen so that rendering its contents with the
            mean training style reproduces ``value`` there on average.

        Returns
        -------
        InferResult
        """
        self._check_fitted()
        y, _ = _frames(y, self.n_dims, "observations")
        use_prior = self.prior if prior is None else prior
        windows, widx = _style_windows(len(y), window)
        first = self._first_range(margin)                               # (lo, hi, mean, anchored)
        aw = np.tile(self._initial_style(init), (len(windows) - 1, 1))
        aw, hist, resets = self._alternate(y, aw, windows, widx, use_prior, first, reinit_first and first[3],
                                           anchor, max_iter, tol)
        aw, b = self._final_contents(y, aw, windows, widx, use_prior, first, anchor)
        d = ((aw[:, None, :] - self.style_vectors_[None]) ** 2).sum(-1)
        nearest = np.argmin(d, axis=1)[widx]
        return InferResult(aw[widx], b, aw, windows, nearest, hist, len(hist), resets)

    def _first_range(self, margin: float) -> tuple[float, float, float, bool]:
        """The training range of the first content component, as :meth:`infer` uses it.

        Returns ``(lo, hi, mean, anchored)``: the range of the training contents' first component
        widened by ``margin`` times its width on both sides, its training mean, and whether it is
        constant-like (mean more than 3 standard deviations from 0), so that it can anchor the
        scale and be re-initialised.
        """
        B0 = self.content_vectors_[:, 0]
        lo, hi = float(B0.min()), float(B0.max())
        pad = margin * (hi - lo)
        lo, hi = lo - pad, hi + pad
        mean_first = float(B0.mean())
        # the first content component anchors the scale only when it is constant-like (a mean)
        anchored = abs(mean_first) > 3.0 * float(B0.std())
        return lo, hi, mean_first, anchored

    def _initial_style(self, init) -> np.ndarray:
        """The starting style vector ``(I,)`` of :meth:`infer`.

        The mean training style vector when ``init`` is None, the vector of the style named
        ``init``, else ``init`` itself as a float array.
        """
        return self.style_vectors_.mean(0) if init is None else (
            self.style_vector(init) if isinstance(init, str) else np.asarray(init, np.float64))

    def _alternate(self, y, aw, windows, widx, use_prior, first, reinit_first, anchor, max_iter: int,
                   tol: float) -> tuple[np.ndarray, list[float], int]:
        """The alternation of :meth:`infer`: contents given styles, styles given contents, until it settles.

        ``y`` ``(T, K)``; ``aw`` ``(n_windows, I)`` the starting window styles; ``windows`` the window
        boundaries and ``widx`` ``(T,)`` each frame's window; ``first`` from :meth:`_first_range`.
        Every iteration solves all contents, re-initialises out-of-range first components (when
        ``reinit_first``, :meth:`_reinit_first`), solves every window's style and fixes the scale
        (:meth:`_fix_scale`).  Stops after ``max_iter`` iterations or when the mean squared residual
        changes by at most ``tol`` times the mean square of ``y``.  Returns ``(aw, history, resets)``.
        """
        ms = max(float(np.mean(y**2)), 1e-300)
        hist: list[float] = []
        resets = 0
        for _ in range(max_iter):
            b = self._content(y, aw, windows, None, use_prior)
            if reinit_first and self.content_dims_ > 1:
                b, n_reset = self._reinit_first(y, aw, windows, b, use_prior, first)
                resets += n_reset
            aw = self._style(y, b, windows)
            aw, b = self._fix_scale(aw, b, windows, widx, anchor, first)
            Ma = np.einsum("wi,ijk->wjk", aw, self.core_)
            r = y - np.einsum("tj,tjk->tk", b, Ma[widx])
            hist.append(float(np.mean(r**2)))
            if len(hist) > 1 and abs(hist[-2] - hist[-1]) <= tol * ms:
                break
        return aw, hist, resets

    def _reinit_first(self, y, aw, windows, b, use_prior, first) -> tuple[np.ndarray, int]:
        """Contents ``b`` ``(T, J)`` with every out-of-range first component reset to the training mean.

        A frame whose first component is outside ``first``'s ``(lo, hi)`` (or not finite) gets it
        fixed at the training mean and its other components solved again given it
        (:meth:`_content`).  Returns the contents and the number of frames reset.
        """
        lo, hi, mean_first, _ = first
        out = (b[:, 0] < lo) | (b[:, 0] > hi) | ~np.isfinite(b[:, 0])
        if not out.any():
            return b, 0
        fixed = np.where(out, mean_first, np.nan)
        return self._content(y, aw, windows, fixed, use_prior), int(out.sum())

    def _fix_scale(self, aw, b, windows, widx, anchor, first) -> tuple[np.ndarray, np.ndarray]:
        """Fix the bilinear scale ambiguity of every window: ``a -> l a``, ``b -> b / l``.

        With ``anchor = (indices, value)``: ``l`` makes the mean over the window of the anchored
        coordinates, rendered with the mean training style, equal ``value``; else, when the first
        content component is constant-like (``first``, :meth:`_first_range`), ``l`` makes the window's
        mean first component equal the training mean; else nothing changes.  Returns ``(aw, b)``.
        """
        _, _, mean_first, anchored = first
        # scale: mean first content component of each window = training mean
        if anchor is not None:
            idx, val = np.asarray(anchor[0]).reshape(-1), float(anchor[1])
            Mm = np.einsum("i,ijk->jk", self.style_vectors_[: len(self.styles_)].mean(0),
                           self.core_[..., idx])
            c = (b @ Mm).mean(1)                                    # per frame
            return _rescale_windows(aw, b, widx, _window_means(c, windows), val)
        if anchored:
            return _rescale_windows(aw, b, widx, _window_means(b[:, 0], windows), mean_first)
        return aw, b

    def _final_contents(self, y, aw, windows, widx, use_prior, first,
                        anchor) -> tuple[np.ndarray, np.ndarray]:
        """The contents ``(T, J)`` returned by :meth:`infer`, solved freely given the final window styles.

        Without ``anchor`` and with a constant-like first component (``first``), each window is
        rescaled so its mean first component equals the training mean.  Returns ``(aw, b)``.
        """
        # the final contents given the final styles, unconstrained (the re-initialisation only steers
        # the alternation)
        _, _, mean_first, anchored = first
        b = self._content(y, aw, windows, None, use_prior)
        if anchor is None and anchored:
            aw, b = _rescale_windows(aw, b, widx, _window_means(b[:, 0], windows), mean_first)
        return aw, b

    def fit_style(self, y, b) -> np.ndarray:
        """A new style vector from examples with known contents ``b``: least squares (Eq. 2.13)."""
        self._check_fitted()
        y, _ = _frames(y, self.n_dims, "new-style observations")
        b, _ = _frames(b, self.content_dims_, "content vectors")
        if len(y) != len(b):
            raise InvalidDataError(f"{len(y)} new-style frames but {len(b)} content vectors")
        return self._style(y, b, np.array([0, len(y)]))[0]

    def insert_dims(self, positions) -> SymmetricBilinearModel:
        """Insert zero observation coordinates before ``positions`` (as :func:`numpy.insert`); returns self."""
        self._check_fitted()
        self.core_ = np.insert(self.core_, positions, 0.0, axis=2)
        return self

    def add_style(self, name: str, y, b, *, extend: bool = True, ridge: float = 0.0,
                  toward: np.ndarray | None = None) -> SymmetricBilinearModel:
        """Append a new style fitted from examples ``y`` ``(T, K)`` with known contents ``b`` ``(T, J)``.

        ``extend=True`` (default): the style gets a dimension of its own, a new core slice
        ``W_I = argmin ||y - W_I' b||`` and the style vector ``e_I`` (the training styles get 0
        there), so it can show what no training style shows.  ``extend=False``: the least-squares
        style vector in the existing style space (:meth:`fit_style`).  Returns self.
        """
        if name in self.styles_:
            raise InvalidDataError(f"style '{name}' is already in the model")
        if not extend:
            a = self.fit_style(y, b)
            self.style_vectors_ = np.concatenate([self.style_vectors_, a[None]])
        else:
            self._check_fitted()
            y, _ = _frames(y, self.n_dims, "new-style observations")
            b, _ = _frames(b, self.content_dims_, "content vectors")
            if len(y) != len(b) or (ridge <= 0 and len(y) < self.content_dims_):
                raise InvalidDataError(f"a new style needs as many content vectors as frames and at least "
                                       f"{self.content_dims_} frames (or a ridge > 0), got {len(y)} and {len(b)}")
            Wn = _ridge_map(b, y, ridge, None if toward is None else np.asarray(toward).T).T   # (J, K)
            self.core_ = np.concatenate([self.core_, Wn[None]], axis=0)
            S = len(self.style_vectors_)
            self.style_vectors_ = np.concatenate([np.c_[self.style_vectors_, np.zeros(S)],
                                                  np.eye(1, self.style_dims_ + 1, self.style_dims_)])
            self.style_dims_ += 1
        self.styles_ = [*self.styles_, str(name)]
        return self
