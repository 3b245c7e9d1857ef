"""Piecewise-affine warps between a fixed reference shape and per-frame shapes.

The reference (mean) shape is triangulated once; every pixel of the reference canvas inside the
mesh gets its triangle and barycentric coordinates once.  Warping a frame is then only: place the
frame's points into those barycentric combinations (one ``einsum``), which gives a sampling map,
and apply it with ``cv2.remap`` (bilinear).
"""

from __future__ import annotations

import numpy as np

from ..errors import InvalidDataError
from ..optional import optional_import

__all__ = ["PiecewiseAffineWarp", "rasterize_triangles"]


def rasterize_triangles(points: np.ndarray, triangles: np.ndarray, shape: tuple[int, int]
                        ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Which triangle covers each pixel centre of a canvas, with barycentric coordinates.

    Parameters
    ----------
    points : (P, 2) float
        Vertex positions in pixels (x, y), pixel ``(i, j)`` centred at ``x = j, y = i``.
    triangles : (F, 3) int
        Vertex indices.
    shape : (height, width)

    Returns
    -------
    pixels : (N, 2) int
        Row, column of every covered pixel (row-major order).
    tri : (N,) int
        Covering triangle (the first one in ``triangles`` order where triangles overlap).
    bary : (N, 3) float64
        Barycentric coordinates of the pixel centre in that triangle (sum to 1).
    """
    P = np.asarray(points, dtype=np.float64)
    F = np.asarray(triangles, dtype=np.int64)
    h, w = shape
    owner = np.full((h, w), -1, dtype=np.int64)
    bary = np.zeros((h, w, 3))
    eps = 1e-9
    for f, (i, j, k) in enumerate(F.tolist()):
        a, b, c = P[i], P[j], P[k]
        x0, x1 = int(np.ceil(min(a[0], b[0], c[0]) - eps)), int(np.floor(max(a[0], b[0], c[0]) + eps))
        y0, y1 = int(np.ceil(min(a[1], b[1], c[1]) - eps)), int(np.floor(max(a[1], b[1], c[1]) + eps))
        x0, y0, x1, y1 = max(x0, 0), max(y0, 0), min(x1, w - 1), min(y1, h - 1)
        if x1 < x0 or y1 < y0:
            continue
        det = (b[1] - c[1]) * (a[0] - c[0]) + (c[0] - b[0]) * (a[1] - c[1])
        if abs(det) < 1e-12:
            continue
        yy, xx = np.mgrid[y0:y1 + 1, x0:x1 + 1]
        l0 = ((b[1] - c[1]) * (xx - c[0]) + (c[0] - b[0]) * (yy - c[1])) / det
        l1 = ((c[1] - a[1]) * (xx - c[0]) + (a[0] - c[0]) * (yy - c[1])) / det
        l2 = 1.0 - l0 - l1
        inside = (l0 >= -eps) & (l1 >= -eps) & (l2 >= -eps) & (owner[y0:y1 + 1, x0:x1 + 1] < 0)
        if not inside.any():
            continue
        owner[y0:y1 + 1, x0:x1 + 1][inside] = f
        bary[y0:y1 + 1, x0:x1 + 1][inside] = np.stack([l0, l1, l2], -1)[inside]
    rows, cols = np.nonzero(owner >= 0)
    return np.stack([rows, cols], 1), owner[rows, cols], bary[rows, cols]


class PiecewiseAffineWarp:
    """Warp images from a shape onto a fixed reference shape, triangle by triangle.

    Parameters
    ----------
    reference : (P, 2) float
        Reference (mean) shape in the canvas' pixel coordinates (x, y).
    triangles : (F, 3) int, optional
        Triangulation of the reference; a Delaunay triangulation of ``reference`` when omitted.
    shape : (height, width), optional
        Canvas size; by default the reference's bounding box plus one pixel.

    Attributes
    ----------
    mask : (height, width) bool
        Canvas pixels inside the mesh.
    pixels : (N, 2) int
        Row, column of the ``N`` pixels inside, in row-major order (texture vector order).
    tri, bary : (N,) int, (N, 3) float32
        Each inside pixel's triangle and barycentric coordinates (computed once here).

    Examples
    --------
    A pure translation of the shape moves the sampled texture with it:

    >>> ref = np.array([[0., 0], [20, 0], [0, 20], [20, 20]])
    >>> pw = PiecewiseAffineWarp(ref, shape=(21, 21))
    >>> img = np.zeros((40, 40), np.uint8); img[15:25, 15:25] = 200
    >>> out = pw.warp(img, ref + 10)
    >>> int(out[5:15, 5:15].min()), int(out[:4, :4].max())
    (200, 0)
    """

    def __init__(self, reference: np.ndarray, triangles: np.ndarray | None = None,
                 shape: tuple[int, int] | None = None):
        ref = np.asarray(reference, dtype=np.float64)
        if ref.ndim != 2 or ref.shape[1] != 2 or not np.isfinite(ref).all():
            raise InvalidDataError(f"reference shape must be finite (P, 2), got {ref.shape}")
        if triangles is None:
            from scipy.spatial import Delaunay

            triangles = Delaunay(ref).simplices
        self.reference = ref
        self.triangles = np.asarray(triangles, dtype=np.int64)
        if shape is None:
            shape = (int(np.ceil(ref[:, 1].max())) + 1, int(np.ceil(ref[:, 0].max())) + 1)
        self.shape = (int(shape[0]), int(shape[1]))
        self.pixels, self.tri, bary = rasterize_triangles(ref, self.triangles, self.shape)
        self.bary = bary.astype(np.float32)
        self.mask = np.zeros(self.shape, dtype=bool)
        self.mask[self.pixels[:, 0], self.pixels[:, 1]] = True
        self._corners = self.triangles[self.tri]  # (N, 3) vertex index per pixel corner

    @property
    def n_pixels(self) -> int:
        return int(self.pixels.shape[0])

    def maps(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``cv2.remap`` maps: where each canvas pixel samples the frame whose shape is ``points``.

        Parameters
        ----------
        points : (P, 2) float
            The frame's shape, same point order as the reference, frame pixel coordinates.

        Returns
        -------
        map_x, map_y : (height, width) float32
            Source coordinates; -1e4 outside the mesh (sampled as the border value).
        """
        pts = np.asarray(points, dtype=np.float32)[:, :2]
        src = np.einsum("nk,nkd->nd", self.bary, pts[self._corners])
        map_x = np.full(self.shape, -1e4, dtype=np.float32)
        map_y = np.full(self.shape, -1e4, dtype=np.float32)
        map_x[self.pixels[:, 0], self.pixels[:, 1]] = src[:, 0]
        map_y[self.pixels[:, 0], self.pixels[:, 1]] = src[:, 1]
        return map_x, map_y

    def warp(self, image: np.ndarray, points: np.ndarray, border: float = 0) -> np.ndarray:
        """Warp ``image`` (whose shape is ``points``) onto the reference canvas.

        Returns
        -------
        (height, width[, C]) array of ``image``'s dtype
            Bilinear samples; ``border`` outside the mesh.
        """
        cv2 = optional_import("cv2", "warping face textures")

        mx, my = self.maps(points)
        return cv2.remap(image, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=border)

    def sample(self, image: np.ndarray, points: np.ndarray) -> np.ndarray:
        """The texture vector: ``warp(image, points)`` at the inside pixels, (N,) or (N, C) float32."""
        out = self.warp(image, points)
        return out[self.pixels[:, 0], self.pixels[:, 1]].astype(np.float32)

    def unpack(self, values: np.ndarray, fill: float = 0) -> np.ndarray:
        """Texture vector(s) (..., N[, C]) back to canvas images (..., height, width[, C])."""
        v = np.asarray(values)
        if v.shape[-1] == self.n_pixels:
            out = np.full(v.shape[:-1] + self.shape, fill, dtype=v.dtype)
            out[..., self.pixels[:, 0], self.pixels[:, 1]] = v
            return out
        if v.ndim < 2 or v.shape[-2] != self.n_pixels:
            raise InvalidDataError(f"texture vectors must be (..., {self.n_pixels}[, C]), got {v.shape}")
        out = np.full(v.shape[:-2] + self.shape + v.shape[-1:], fill, dtype=v.dtype)
        out[..., self.pixels[:, 0], self.pixels[:, 1], :] = v
        return out
