"""Chuang's appearance model (thesis Sec. 2.2.1): shape PCA + shape-free texture PCA, one vector per frame.

* **Shape.**  The 2-D image landmarks of every frame are aligned by generalised Procrustes analysis
  (translation, rotation, uniform scale), so head motion in the image plane is removed, and the
  aligned shapes are expressed on a canvas where the mean shape is ``width`` pixels wide.  PCA of
  the aligned shapes keeps the fewest components explaining ``shape_variance`` of the variance
  (thesis: 99 %).
* **Texture.**  Each frame is warped onto the mean shape piecewise-affinely (Delaunay triangulation
  of the mean shape; each canvas pixel's triangle and barycentric coordinates are computed once in
  :class:`~faceretarget.capture.PiecewiseAffineWarp`, per frame only the sampling map changes and
  ``cv2.remap`` applies it).  The pixels inside the mesh form one texture vector per colour
  channel, in grey levels 0..255; PCA per channel keeps ``texture_variance`` of each channel's
  variance (thesis: 80 %).
* **Configuration vector** (the thesis' Eq. 2.3): shape coefficients followed by the texture
  coefficients of R, G and B, the texture part multiplied by
  ``texture_scale_ = sqrt(sum of retained shape variances / sum of retained texture variances)``
  so both parts have the same total variance (shape in canvas pixels, texture in grey levels
  would otherwise differ by orders of magnitude; this is the commensurate weighting of Cootes et
  al.'s combined appearance models, applied to the texture instead of the shape).
"""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np

from ..base import Model
from ..errors import InvalidDataError
from ..performance import Performance
from ._warp import PiecewiseAffineWarp

__all__ = ["AppearanceModel", "procrustes_align"]

_CHANNELS = "rgb"
#: MediaPipe's 468 face-mesh points (the 10 iris points move inside the eye and are left out).
MESH_POINTS = np.arange(468)


def _to_complex(x: np.ndarray) -> np.ndarray:
    return x[..., 0] + 1j * x[..., 1]


def _to_real(z: np.ndarray) -> np.ndarray:
    return np.stack([z.real, z.imag], axis=-1)


def _similarity(z: np.ndarray, ref: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Least-squares similarity of each row of (N, P) complex ``z`` onto (P,) ``ref``: ``a (z - cz) + cr``."""
    cz = z.mean(axis=1, keepdims=True)
    zc = z - cz
    cr = ref.mean()
    rc = ref - cr
    a = (np.conj(zc) @ rc) / np.maximum(np.sum(np.abs(zc) ** 2, axis=1), 1e-300)
    return a, cz[:, 0], np.full(z.shape[0], cr)


def procrustes_align(shapes: np.ndarray, reference: np.ndarray | None = None, iters: int = 20,
                     tol: float = 1e-10) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Align 2-D shapes by similarity transforms (generalised Procrustes analysis when no reference).

    Parameters
    ----------
    shapes : (N, P, 2) float
    reference : (P, 2) float, optional
        Align every shape to this one.  Without it, the mean is estimated iteratively (GPA): align
        to the current mean, average, normalise the mean to unit size and to the first shape's
        orientation, repeat.
    iters, tol : int, float
        GPA iterations and convergence threshold on the mean's change.

    Returns
    -------
    aligned : (N, P, 2) float
        ``a_n * (x_n - c_n) + c_ref`` in complex notation.
    mean : (P, 2) float
        The reference (or the GPA mean: centred, unit Frobenius norm).
    a : (N,) complex
        Rotation and scale of each shape (``|a|`` scale, ``angle(a)`` rotation).
    c : (N,) complex
        Each shape's centroid, so ``x_n = (aligned_n - c_ref) / a_n + c_n``.
    """
    X = np.asarray(shapes, dtype=np.float64)
    if X.ndim != 3 or X.shape[2] != 2:
        raise InvalidDataError(f"shapes must be (N, P, 2), got {X.shape}")
    if not np.isfinite(X).all():
        n = int(np.flatnonzero(~np.isfinite(X).all(axis=(1, 2)))[0])
        raise InvalidDataError(f"shape of frame {n} has NaN points; drop frames without a face first")
    z = _to_complex(X)
    if reference is not None:
        m = _to_complex(np.asarray(reference, dtype=np.float64))
    else:
        m0 = z[0] - z[0].mean()
        m0 = m0 / np.linalg.norm(m0)
        m = m0
        for _ in range(iters):
            a, c, cr = _similarity(z, m)
            new = (a[:, None] * (z - c[:, None])).mean(axis=0)
            b, _, _ = _similarity(new[None], m0)  # keep the first shape's orientation
            new = b[0] * (new - new.mean())
            new /= np.linalg.norm(new)
            done = np.linalg.norm(new - m) < tol
            m = new
            if done:
                break
    a, c, cr = _similarity(z, m)
    aligned = a[:, None] * (z - c[:, None]) + cr[:, None]
    return _to_real(aligned), _to_real(m), a, c


def _pca(X: np.ndarray, retain: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Mean (D,), basis (K, D) with orthonormal rows, variances (K,) keeping ``retain`` of the variance.

    ``retain >= 1`` keeps every component with non-negligible variance (exact reconstruction of
    the training data).  With fewer samples than dimensions (textures: N frames << D pixels) the
    N x N Gram matrix is diagonalised instead of a full SVD (about ten times less work), and the
    basis is re-orthonormalised (QR) so projections stay exact.
    """
    X = np.asarray(X, dtype=np.float64)
    N, D = X.shape
    mean = X.mean(axis=0)
    Xc = X - mean
    if N < D:
        lam, U = np.linalg.eigh(Xc @ Xc.T)
        lam, U = np.clip(lam[::-1], 0.0, None), U[:, ::-1]
    else:
        _, s, Vt = np.linalg.svd(Xc, full_matrices=False)
        lam = s**2
    var = lam / max(N - 1, 1)
    tot = var.sum()
    if tot <= 0:
        return mean, np.zeros((0, D)), var[:0]
    nz = int(np.sum(var > var[0] * 1e-12))
    if retain >= 1.0:
        k = nz
    else:
        k = int(np.searchsorted(np.cumsum(var) / tot, retain - 1e-12) + 1)
        k = min(max(k, 1), nz)
    if N < D:
        B = (U[:, :k].T @ Xc) / np.sqrt(lam[:k])[:, None]
        Q, R = np.linalg.qr(B.T)
        basis = Q.T * np.sign(np.diag(R))[:, None]  # keep each mode's direction
    else:
        basis = Vt[:k]
    return mean, basis, var[:k]


class AppearanceModel(Model):
    """Appearance model of a face in video: shape and texture PCA (Chuang, thesis Sec. 2.2.1).

    Parameters
    ----------
    shape_variance : float
        Fraction of the aligned-shape variance to retain (thesis: 0.99; 1 keeps everything).
    texture_variance : float
        Fraction of each colour channel's texture variance to retain (thesis: 0.80).
    width : int
        Width in pixels of the mean shape on the texture canvas (texture resolution).
    points : (P,) int, optional
        Landmark indices to model (default MediaPipe's 468 mesh points, iris excluded).
    margin : int
        Canvas pixels around the mean shape.

    Attributes
    ----------
    reference_ : (P, 2) float
        The Procrustes reference every shape is aligned to (the GPA mean, on the canvas).
    mean_shape_ : (P, 2) float
        Mean of the aligned shapes in canvas pixels (PCA mean; the texture canvas' shape).
    shape_basis_ : (Ks, 2P) float
        Orthonormal shape modes (x0, y0, x1, y1, ...); ``shape_var_`` (Ks,) their variances.
    points_ : (P,) int
        The landmark indices modelled.
    triangles_ : (F, 3) int
        Triangulation of the mean shape; ``canvas_`` (height, width) the texture canvas.
    warp_ : PiecewiseAffineWarp
        The per-pixel barycentric map of that triangulation (mask ``warp_.mask``; rebuilt on load).
    texture_mean_ : (N, 3) float
        Mean shape-free texture, grey levels.
    texture_basis_ : list of 3 (Kc, N) float
        Orthonormal texture modes per channel R, G, B; ``texture_var_`` their variances.
    texture_scale_ : float
        Factor applied to the texture coefficients in the configuration vector.
    names_ : list of str
        Configuration vector entries: ``shape0..``, ``tex_r0..``, ``tex_g0..``, ``tex_b0..``.

    Examples
    --------
    >>> rng = np.random.default_rng(0)
    >>> base = rng.uniform(0, 60, (12, 2))
    >>> lm = base + rng.normal(0, 1, (30, 12, 2))
    >>> frames = rng.integers(0, 255, (30, 64, 64, 3)).astype(np.uint8)
    >>> m = AppearanceModel(1.0, 1.0, width=40, points=np.arange(12)).fit(frames, lm)
    >>> v = m.transform(frames, lm)
    >>> v.shape[0], len(m.names_) == v.shape[1]
    (30, True)
    """

    def __init__(self, shape_variance: float = 0.99, texture_variance: float = 0.80, width: int = 128,
                 points: np.ndarray | None = None, margin: int = 2):
        for n, v in (("shape_variance", shape_variance), ("texture_variance", texture_variance)):
            if not 0 < v <= 1:
                raise InvalidDataError(f"{n} must be in (0, 1], got {v}")
        if width < 8:
            raise InvalidDataError(f"width must be at least 8 pixels, got {width}")
        self.shape_variance = float(shape_variance)
        self.texture_variance = float(texture_variance)
        self.width = int(width)
        self.points = None if points is None else np.asarray(points, dtype=np.int64)
        self.margin = int(margin)

    # ------------------------------------------------------------------ helpers
    def _pts(self, landmarks: np.ndarray) -> np.ndarray:
        L = np.asarray(landmarks, dtype=np.float64)
        if L.ndim == 2:
            L = L[None]
        if L.ndim != 3 or L.shape[2] < 2:
            raise InvalidDataError(f"landmarks must be (N, P, 2|3), got {L.shape}")
        idx = getattr(self, "points_", None)
        if idx is None:
            idx = self.points if self.points is not None else (MESH_POINTS if L.shape[1] >= 468 else np.arange(L.shape[1]))
        if idx.max() >= L.shape[1]:
            raise InvalidDataError(f"landmarks have {L.shape[1]} points, the model uses index {int(idx.max())}")
        return L[:, idx, :2]

    @property
    def warp_(self) -> PiecewiseAffineWarp:
        self._check_fitted("warp_")
        return self._warp

    @property
    def n_shape(self) -> int:
        return int(self.shape_basis_.shape[0])

    @property
    def n_texture(self) -> tuple[int, int, int]:
        return tuple(int(b.shape[0]) for b in self.texture_basis_)

    # ------------------------------------------------------------------ fitting
    def fit(self, frames: np.ndarray | Iterable[np.ndarray], landmarks: np.ndarray) -> AppearanceModel:
        """Learn the shape and texture models.

        Parameters
        ----------
        frames : (N, H, W, 3) uint8 array, or an iterable of N such frames
            RGB frames (an iterable is consumed once, so whole videos need not be in memory).
        landmarks : (N, P, 2|3) float
            Their landmarks in pixels (e.g. :attr:`Capture.landmarks` of the frames with a face).

        Returns
        -------
        self
        """
        S = self._pts(landmarks)
        N = S.shape[0]
        if N < 2:
            raise InvalidDataError(f"an appearance model needs at least 2 frames, got {N}")
        self.points_ = (self.points if self.points is not None
                        else MESH_POINTS if np.asarray(landmarks).shape[1] >= 468 else np.arange(S.shape[1]))
        _, unit_mean, _, _ = procrustes_align(S)
        # canvas: mean shape upright as in the first frame, `width` pixels wide, `margin` around
        lo, hi = unit_mean.min(axis=0), unit_mean.max(axis=0)
        k = (self.width - 1) / (hi[0] - lo[0])
        mean = (unit_mean - lo) * k + self.margin
        size = (int(np.ceil(mean[:, 1].max())) + self.margin + 1, int(np.ceil(mean[:, 0].max())) + self.margin + 1)
        aligned, _, _, _ = procrustes_align(S, mean)
        m, basis, var = _pca(aligned.reshape(N, -1), self.shape_variance)
        self.reference_ = mean
        self.shape_mean_flat_ = m
        self.mean_shape_ = m.reshape(-1, 2)
        self.shape_basis_, self.shape_var_ = basis, var
        self._warp = PiecewiseAffineWarp(self.mean_shape_, shape=size)
        self.triangles_, self.canvas_ = self._warp.triangles, self._warp.shape
        tex = np.empty((N, self._warp.n_pixels, 3), dtype=np.float32)
        n = 0
        for img in frames:
            if n >= N:
                raise InvalidDataError(f"more frames than the {N} landmark sets given")
            tex[n] = self._sample(img, S[n], n)
            n += 1
        if n != N:
            raise InvalidDataError(f"{n} frames for {N} landmark sets")
        self.texture_mean_ = np.empty((self._warp.n_pixels, 3))
        self.texture_basis_, self.texture_var_ = [], []
        for c in range(3):
            mc, bc, vc = _pca(tex[:, :, c].astype(np.float64), self.texture_variance)
            self.texture_mean_[:, c] = mc
            self.texture_basis_.append(bc)
            self.texture_var_.append(vc)
        tv = sum(float(v.sum()) for v in self.texture_var_)
        self.texture_scale_ = float(np.sqrt(self.shape_var_.sum() / tv)) if tv > 0 else 1.0
        self._names()
        return self

    def _names(self) -> None:
        self.names_ = [f"shape{i}" for i in range(self.n_shape)] + [
            f"tex_{ch}{i}" for ch, b in zip(_CHANNELS, self.texture_basis_, strict=True) for i in range(b.shape[0])]

    def _sample(self, img: np.ndarray, shape: np.ndarray, n: int) -> np.ndarray:
        img = np.asarray(img)
        if img.ndim != 3 or img.shape[2] != 3:
            raise InvalidDataError(f"frame {n}: expected an (H, W, 3) RGB image, got {img.shape}")
        return self._warp.sample(img, shape)

    # ------------------------------------------------------------------ analysis
    def shape_params(self, landmarks: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Shape coefficients (N, Ks) of landmark sets, with each set's similarity ``a``, ``c`` (N,) complex."""
        self._check_fitted()
        S = self._pts(landmarks)
        aligned, _, a, c = procrustes_align(S, self.reference_)
        b = (aligned.reshape(S.shape[0], -1) - self.shape_mean_flat_) @ self.shape_basis_.T
        return b, a, c

    def texture_params(self, frames: np.ndarray | Iterable[np.ndarray], landmarks: np.ndarray) -> np.ndarray:
        """Texture coefficients (N, Kr + Kg + Kb), unscaled, of frames with their landmarks."""
        self._check_fitted()
        S = self._pts(landmarks)
        out = np.zeros((S.shape[0], sum(self.n_texture)))
        n = 0
        for img in frames:
            if n >= S.shape[0]:
                raise InvalidDataError(f"more frames than the {S.shape[0]} landmark sets given")
            t = self._sample(img, S[n], n).astype(np.float64) - self.texture_mean_
            out[n] = np.concatenate([t[:, c] @ self.texture_basis_[c].T for c in range(3)])
            n += 1
        if n != S.shape[0]:
            raise InvalidDataError(f"{n} frames for {S.shape[0]} landmark sets")
        return out

    def transform(self, frames: np.ndarray | Iterable[np.ndarray], landmarks: np.ndarray) -> np.ndarray:
        """Configuration vectors (Eq. 2.3): ``[shape coefficients, texture_scale_ * texture coefficients]``.

        Parameters
        ----------
        frames : (N, H, W, 3) uint8 or an iterable of N frames
        landmarks : (N, P, 2|3) float, pixels

        Returns
        -------
        (N, Ks + Kr + Kg + Kb) float, columns named by :attr:`names_`
        """
        b, _, _ = self.shape_params(landmarks)
        t = self.texture_params(frames, landmarks)
        return np.concatenate([b, self.texture_scale_ * t], axis=1)


    def split(self, vectors: np.ndarray) -> tuple[np.ndarray, list[np.ndarray]]:
        """Shape coefficients (N, Ks) and unscaled per-channel texture coefficients of vectors."""
        self._check_fitted()
        v = np.atleast_2d(np.asarray(vectors, dtype=np.float64))
        if v.shape[1] != len(self.names_):
            raise InvalidDataError(f"configuration vectors must have {len(self.names_)} columns, got {v.shape[1]}")
        ks = self.n_shape
        tex, o = [], ks
        for k in self.n_texture:
            tex.append(v[:, o:o + k] / self.texture_scale_)
            o += k
        return v[:, :ks], tex

    # ------------------------------------------------------------------ synthesis
    def reconstruct_shape(self, vectors: np.ndarray) -> np.ndarray:
        """(N, P, 2) shapes on the canvas (pixels) from configuration vectors."""
        b, _ = self.split(vectors)
        return (self.shape_mean_flat_ + b @ self.shape_basis_).reshape(b.shape[0], -1, 2)

    def reconstruct_texture(self, vectors: np.ndarray) -> np.ndarray:
        """(N, n_pixels, 3) shape-free textures in grey levels (float) from configuration vectors."""
        _, tex = self.split(vectors)
        out = np.repeat(self.texture_mean_[None], tex[0].shape[0], axis=0)
        for c in range(3):
            out[:, :, c] += tex[c] @ self.texture_basis_[c]
        return out

    def inverse_transform(self, vectors: np.ndarray, shape_free: bool = False) -> np.ndarray:
        """Images of configuration vectors, for inspection.

        Parameters
        ----------
        vectors : (N, D) or (D,) float
        shape_free : bool
            True: the texture on the mean shape; False: the texture warped (piecewise-affinely) onto
            the vector's own shape.

        Returns
        -------
        (N, height, width, 3) uint8
            Canvas images, black outside the face: the model canvas (``warp_.shape``) for
            ``shape_free``, else that canvas with ``pad = width // 8`` pixels more on every side
            (a shape may reach beyond the mean's box).
        """
        tex = np.clip(np.rint(self.reconstruct_texture(vectors)), 0, 255).astype(np.uint8)
        imgs = self.warp_.unpack(tex)
        if shape_free:
            return imgs
        pad = max(self.width // 8, 2)
        shapes = self.reconstruct_shape(vectors) + pad
        size = (self.warp_.shape[0] + 2 * pad, self.warp_.shape[1] + 2 * pad)
        out = np.zeros((imgs.shape[0],) + size + (3,), dtype=np.uint8)
        for n in range(imgs.shape[0]):
            fwd = PiecewiseAffineWarp(shapes[n], self.warp_.triangles, shape=size)
            out[n] = fwd.warp(imgs[n], self.mean_shape_)
        return out

    def evaluate(self, frames: np.ndarray | Iterable[np.ndarray], landmarks: np.ndarray) -> dict:
        """Reconstruction errors of frames through the model.

        Returns
        -------
        dict
            ``shape_rms_px``: RMS point error in image pixels (reconstructed shape mapped back by the
            inverse similarity); ``texture_rms``: RMS error of the shape-free texture in grey levels
            over the face pixels and the three channels; ``frames``.
        """
        S = self._pts(landmarks)
        b, a, c = self.shape_params(landmarks)
        rec = _to_complex((self.shape_mean_flat_ + b @ self.shape_basis_).reshape(S.shape[0], -1, 2))
        cr = _to_complex(self.reference_).mean()
        back = _to_real((rec - cr) / a[:, None] + c[:, None])
        shape_rms = float(np.sqrt(np.mean(np.sum((back - S) ** 2, axis=-1))))
        se, n = 0.0, 0
        for i, img in enumerate(frames):
            t = self._sample(img, S[i], i).astype(np.float64)
            d = t - self.texture_mean_
            r = np.stack([(d[:, ch] @ self.texture_basis_[ch].T) @ self.texture_basis_[ch] for ch in range(3)], 1)
            se += float(np.sum((d - r) ** 2))
            n += d.size
        return {"shape_rms_px": shape_rms, "texture_rms": float(np.sqrt(se / max(n, 1))), "frames": int(S.shape[0])}

    def to_performance(self, vectors: np.ndarray, times: np.ndarray, fps: float | None = None,
                       source: str = "appearance") -> Performance:
        """Configuration vectors as a weights :class:`~faceretarget.Performance` named by :attr:`names_`."""
        self._check_fitted()
        return Performance.from_weights(vectors, self.names_, times=times, fps=fps, source=source)

    def _after_load(self) -> None:
        self._warp = PiecewiseAffineWarp(self.mean_shape_, self.triangles_, shape=tuple(self.canvas_))
