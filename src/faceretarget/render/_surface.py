"""A mesh's surface as a glTF viewer draws it, for the NumPy rasteriser and the OpenGL renderer alike.

A :class:`Surface` gives each triangle a :class:`~faceretarget.character.Material` and its corners
texture coordinates, and the mesh per-vertex colours.  A pixel's base colour is the material's factor
times its base-colour texture (sampled per pixel, bilinear on the nearest level of a mip pyramid,
decoded from sRGB before filtering) times the vertex colour, all linear RGBA; then

* ``OPAQUE`` materials ignore alpha;
* ``MASK`` materials drop the pixels whose alpha is under ``alpha_cutoff`` (hair cards, lashes:
  what is behind them shows);
* ``BLEND`` materials are drawn after everything opaque, without writing depth (as three.js's
  GLTFLoader sets them), material by material from the farthest (mean depth of its vertices) to the
  nearest and within one back to front, each pixel mixed with what is under it by its alpha
  (``a * colour + (1 - a) * below``, in sRGB as WebGL blends);
* a material that is not ``double_sided`` shows only its front faces (counter-clockwise as seen).

The mip pyramid is made here once per texture (each level the 2 x 2 mean of the one above, in linear
light, stored as sRGB bytes) and both renderers sample the same levels: the OpenGL one uploads them to
an sRGB texture (``GL_LINEAR_MIPMAP_NEAREST``: a sixth less of llvmpipe's time than blending two levels,
as three.js does, for a difference under a tenth of Delta E), the NumPy one picks each triangle's
level from how many texels a pixel spans on it (exact for an orthographic camera, where that is
constant over a triangle), as OpenGL does per pixel.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..character import Material
from ..errors import InvalidDataError

__all__ = ["Surface", "scene_surface", "ALPHA_MODES"]

ALPHA_MODES = ("OPAQUE", "MASK", "BLEND")
#: sRGB byte -> linear light.
_LINEAR = np.where(np.arange(256) / 255.0 <= 0.04045, np.arange(256) / 255.0 / 12.92,
                   ((np.arange(256) / 255.0 + 0.055) / 1.055) ** 2.4).astype(np.float32)
#: RGBA bytes -> linear RGBA: ``_DECODE[_CHANNELS, bytes]`` (alpha is linear already).
_DECODE = np.stack([_LINEAR] * 3 + [np.arange(256, dtype=np.float32) / 255.0])
_CHANNELS = np.arange(4)


@dataclass(eq=False)
class Surface:
    """How a mesh looks: materials per triangle, texture coordinates per corner, colours per vertex.

    Parameters
    ----------
    materials : list of Material
        Base colour (linear RGBA factor), texture (sRGB, rows top-down), alpha mode and sides.
    triangle_material : (F,) int
        Each triangle's material (the mesh's ``triangles()`` order).
    uvs : (F, 3, 2) float, optional
        Texture coordinates of each triangle's corners, glTF's convention (``v`` down, repeating).
    vertex_colors : (V, 3 or 4) float, optional
        Linear RGB(A) per vertex (glTF's ``COLOR_0``), multiplying the base colour.
    """

    materials: list[Material]
    triangle_material: np.ndarray
    uvs: np.ndarray | None = None
    vertex_colors: np.ndarray | None = None
    _textures: dict = field(default_factory=dict, repr=False)

    def __post_init__(self) -> None:
        if not self.materials:
            raise InvalidDataError("a surface needs at least one material")
        for m in self.materials:
            if m.alpha_mode not in ALPHA_MODES:
                raise InvalidDataError(f"material '{m.name}': alpha mode must be one of {ALPHA_MODES}, got "
                                       f"'{m.alpha_mode}'")
        self.triangle_material = np.asarray(self.triangle_material, np.int64).reshape(-1)
        if self.triangle_material.size and (self.triangle_material.min() < 0
                                            or self.triangle_material.max() >= len(self.materials)):
            raise InvalidDataError(f"triangle materials must be in 0..{len(self.materials) - 1}")
        if self.uvs is not None:
            self.uvs = np.asarray(self.uvs, np.float64)
            if self.uvs.shape != (self.triangle_material.size, 3, 2) or not np.isfinite(self.uvs).all():
                raise InvalidDataError(f"surface uvs must be finite ({self.triangle_material.size}, 3, 2), got "
                                       f"{self.uvs.shape}")
        if self.vertex_colors is not None:
            c = np.clip(np.asarray(self.vertex_colors, np.float64), 0.0, 1.0)
            if c.ndim != 2 or c.shape[1] not in (3, 4):
                raise InvalidDataError(f"vertex colours must be (V, 3) or (V, 4), got {c.shape}")
            self.vertex_colors = c if c.shape[1] == 4 else np.concatenate([c, np.ones((len(c), 1))], axis=1)

    def check(self, n_triangles: int, n_vertices: int, name: str = "mesh") -> None:
        """Raise :class:`~faceretarget.errors.InvalidDataError` unless it fits a mesh of that size."""
        if self.triangle_material.size != n_triangles:
            raise InvalidDataError(f"{name}: the surface has {self.triangle_material.size} triangle materials, the "
                                   f"mesh {n_triangles} triangles")
        if self.vertex_colors is not None and len(self.vertex_colors) != n_vertices:
            raise InvalidDataError(f"{name}: the surface has {len(self.vertex_colors)} vertex colours, the mesh "
                                   f"{n_vertices} vertices")

    # ------------------------------------------------------------------ per material
    def texture(self, k: int) -> _MipTexture | None:
        """Material ``k``'s texture as a mip pyramid (made once, shared by materials of one image)."""
        if self.uvs is None:
            return None
        img = self.materials[k].image
        if img is None:
            return None
        key = id(img)
        if key not in self._textures:
            self._textures[key] = (img, _MipTexture(img))
        return self._textures[key][1]

    def modes(self) -> np.ndarray:
        """(M,) 0 opaque, 1 mask, 2 blend per material."""
        return np.array([ALPHA_MODES.index(m.alpha_mode) for m in self.materials], np.int64)

    def double_sided(self) -> np.ndarray:
        """(M,) bool per material."""
        return np.array([bool(m.double_sided) for m in self.materials])

    def factors(self) -> np.ndarray:
        """(M, 4) linear RGBA base-colour factors."""
        out = np.ones((len(self.materials), 4))
        for k, m in enumerate(self.materials):
            c = np.asarray(m.color, np.float64).reshape(-1)
            out[k, :min(4, c.size)] = c[:4]
        return np.clip(out, 0.0, 1.0)

    # ------------------------------------------------------------------ NumPy sampling
    def base_color(self, tris: np.ndarray, t: np.ndarray, B: np.ndarray, lod: np.ndarray | None) -> np.ndarray:
        """(n, 4) linear RGBA base colour at n points: triangle ``t`` (n,) of ``tris`` (F, 3), barycentrics
        ``B`` (n, 3), texture level of detail ``lod`` (F,) per triangle (``None``: level 0)."""
        mat = self.triangle_material[t]
        out = np.empty((len(t), 4))
        fac = self.factors()
        for k in np.unique(mat):
            rows = np.flatnonzero(mat == k)
            col = np.broadcast_to(fac[k], (rows.size, 4)).copy()
            tex = self.texture(int(k))
            if tex is not None:
                uv = np.einsum("pk,pkd->pd", B[rows], self.uvs[t[rows]])
                col *= tex.sample(uv, np.zeros(rows.size) if lod is None else lod[t[rows]])
            out[rows] = col
        if self.vertex_colors is not None:
            out *= np.einsum("pk,pkd->pd", B, self.vertex_colors[tris[t]])
        return out

    def lod(self, p: np.ndarray, tris: np.ndarray) -> np.ndarray | None:
        """(F,) level of detail of each triangle's texture on the image: log2 of the texels (of level 0) one
        pixel spans, the longer of the pixel's two sides mapped (OpenGL's rho); ``p`` (V, 2+) pixels."""
        if self.uvs is None:
            return None
        size = np.ones((len(self.materials), 2))
        for k in range(len(self.materials)):
            tex = self.texture(k)
            if tex is not None:
                size[k] = tex.levels[0].shape[1], tex.levels[0].shape[0]
        wh = size[self.triangle_material]                          # (F, 2) texels per unit uv
        q = p[tris, :2]                                            # (F, 3, 2) pixels
        T = self.uvs * wh[:, None, :]                              # (F, 3, 2) texels
        dP = np.stack([q[:, 1] - q[:, 0], q[:, 2] - q[:, 0]], axis=2)   # (F, 2, 2) columns: edges
        dT = np.stack([T[:, 1] - T[:, 0], T[:, 2] - T[:, 0]], axis=2)
        det = dP[:, 0, 0] * dP[:, 1, 1] - dP[:, 0, 1] * dP[:, 1, 0]
        ok = np.abs(det) > 1e-12
        inv = np.empty_like(dP)
        d = np.where(ok, det, 1.0)
        inv[:, 0, 0], inv[:, 0, 1] = dP[:, 1, 1] / d, -dP[:, 0, 1] / d
        inv[:, 1, 0], inv[:, 1, 1] = -dP[:, 1, 0] / d, dP[:, 0, 0] / d
        J = dT @ inv                                               # texels per pixel: columns d/dx, d/dy
        rho = np.maximum(np.linalg.norm(J[:, :, 0], axis=1), np.linalg.norm(J[:, :, 1], axis=1))
        return np.where(ok, np.log2(np.maximum(rho, 1e-12)), 0.0)

    def alpha_keep(self, tris: np.ndarray, lod: np.ndarray | None):
        """The fragment filter of the ``MASK`` materials: ``keep(tt, L0, L1, L2)`` -> bool mask."""
        modes = self.modes()
        cut = np.array([float(m.alpha_cutoff) for m in self.materials])

        def keep(tt, L0, L1, L2):
            k = np.ones(tt.size, bool)
            mask = modes[self.triangle_material[tt]] == 1
            if mask.any():
                rows = np.flatnonzero(mask)
                B = np.stack([L0[rows], L1[rows], L2[rows]], axis=1)
                a = self.base_color(tris, tt[rows], B, lod)[:, 3]
                k[rows] = a >= cut[self.triangle_material[tt[rows]]]
            return k

        return keep


class _MipTexture:
    """A texture's mip levels as sRGB RGBA bytes (level 0 the image), and sampling on the nearest level."""

    def __init__(self, img: np.ndarray) -> None:
        im = np.asarray(img)
        if im.ndim == 2:
            im = np.repeat(im[:, :, None], 3, axis=2)
        if im.dtype != np.uint8:
            im = np.clip(np.round(np.asarray(im, np.float64) * 255.0), 0, 255).astype(np.uint8)
        if im.shape[2] == 3:
            im = np.concatenate([im, np.full(im.shape[:2] + (1,), 255, np.uint8)], axis=2)
        self.levels = [np.ascontiguousarray(im[:, :, :4])]
        lin = _DECODE[_CHANNELS, self.levels[0]]
        while lin.shape[0] > 1 or lin.shape[1] > 1:
            lin = _half(lin)
            self.levels.append(_encode(lin))
        self._lin: dict[int, np.ndarray] = {}

    def linear(self, k: int) -> np.ndarray:
        """Level ``k`` as linear float32 RGBA (decoded once)."""
        if k not in self._lin:
            self._lin[k] = _DECODE[_CHANNELS, self.levels[k]]
        return self._lin[k]

    def sample(self, uv: np.ndarray, lod: np.ndarray) -> np.ndarray:
        """(n, 4) linear RGBA at ``uv`` (n, 2) (repeating): bilinear on the level nearest the level of detail
        ``lod`` (n,) (OpenGL's ``GL_LINEAR_MIPMAP_NEAREST``: level 0 up to 0.5, then the nearest, a half rounded
        down)."""
        top = len(self.levels) - 1
        lod = np.nan_to_num(lod, nan=0.0)
        k0 = np.clip(np.ceil(lod + 0.5).astype(np.int64) - 1, 0, top)
        out = np.zeros((len(uv), 4))
        for k in np.unique(k0):
            rows = np.flatnonzero(k0 == k)
            out[rows] = self._bilinear(int(k), uv[rows])
        return out

    def _bilinear(self, k: int, uv: np.ndarray) -> np.ndarray:
        img = self.linear(k)
        h, w = img.shape[:2]
        return bilinear(uv, h, w, lambda yy, xx: img[np.mod(yy, h), np.mod(xx, w)])


def bilinear(uv: np.ndarray, h: int, w: int, at) -> np.ndarray:
    """Bilinear look-up of ``uv`` (n, 2) (v down, repeating) in an ``h`` x ``w`` image whose texels at integer
    rows and columns ``at(rows, cols)`` gives (it wraps them); both renderers' texture sampling."""
    x = uv[:, 0] * w - 0.5
    y = uv[:, 1] * h - 0.5
    x0 = np.floor(x).astype(np.int64)
    y0 = np.floor(y).astype(np.int64)
    fx, fy = (x - x0)[:, None], (y - y0)[:, None]
    return ((at(y0, x0) * (1 - fx) + at(y0, x0 + 1) * fx) * (1 - fy)
            + (at(y0 + 1, x0) * (1 - fx) + at(y0 + 1, x0 + 1) * fx) * fy)


def _half(a: np.ndarray) -> np.ndarray:
    """The next mip level: the mean of each 2 x 2 block (of 2 x 1 or 1 x 2 along a side of one texel; an odd
    last row or column left out, as OpenGL's level sizes are)."""
    h, w = a.shape[:2]
    if h > 1:
        a = a[0:h - h % 2:2] + a[1:h - h % 2 + 1:2]
    if w > 1:
        a = a[:, 0:w - w % 2:2] + a[:, 1:w - w % 2 + 1:2]
    return a * np.float32(1.0 / ((2 if h > 1 else 1) * (2 if w > 1 else 1)))


_STEPS = 1 << 16
_c = (np.arange(_STEPS) + 0.5) / _STEPS
#: linear light in 65536 steps -> sRGB byte (a step is far finer than a byte's at every level)
_SRGB = np.round(255.0 * np.where(_c <= 0.0031308, 12.92 * _c, 1.055 * _c ** (1 / 2.4) - 0.055)).astype(np.uint8)
del _c


def _encode(lin: np.ndarray) -> np.ndarray:
    """Linear float RGBA -> sRGB RGBA bytes (alpha stays linear)."""
    out = np.empty(lin.shape[:2] + (4,), np.uint8)
    q = np.clip(lin[:, :, :3] * np.float32(_STEPS), 0, _STEPS - 1).astype(np.int32)
    np.take(_SRGB, q, out=out[:, :, :3])
    out[:, :, 3] = np.round(np.clip(lin[:, :, 3], 0.0, 1.0) * 255.0)
    return out


def front_facing(p: np.ndarray, tris: np.ndarray) -> np.ndarray:
    """(F,) whether each triangle faces the viewer: counter-clockwise as seen, i.e. clockwise in the
    image's pixel rows (``p`` (V, 2+) pixel x right, pixel y down)."""
    x, y = p[tris, 0], p[tris, 1]
    area = (x[:, 1] - x[:, 0]) * (y[:, 2] - y[:, 0]) - (x[:, 2] - x[:, 0]) * (y[:, 1] - y[:, 0])
    return area < 0


def scene_surface(meshes) -> tuple:
    """Several :class:`~faceretarget.character.SceneMesh` as one mesh and its :class:`Surface` (their
    materials, texture coordinates and vertex colours), vertices in order: what
    :class:`~faceretarget.render.MeshRenderer` or :func:`~faceretarget.render.render_mesh` draw.

    Returns
    -------
    mesh : Mesh
        Triangles only.
    surface : Surface
    """
    from ..character import Material
    from ..mesh import Mesh

    verts, tris, mats, tmat, uvs, cols = [], [], [], [], [], []
    n = 0
    for m in meshes:
        t = m.mesh.triangles()
        own = m.materials or [Material("default")]
        tm = m.triangle_material if m.triangle_material is not None and m.materials else np.zeros(len(t), np.int64)
        verts.append(m.mesh.vertices)
        tris.append(t + n)
        tmat.append(np.asarray(tm, np.int64) + len(mats))
        mats.extend(own)
        uvs.append(m.mesh.uvs[m.mesh.triangle_uv_indices()] if m.mesh.uvs is not None else np.zeros((len(t), 3, 2)))
        cols.append(m.vertex_colors if m.vertex_colors is not None else np.ones((m.mesh.n_vertices, 4)))
        n += m.mesh.n_vertices
    if not verts:
        raise InvalidDataError("scene_surface needs at least one mesh")
    T = np.concatenate(tris)
    mesh = Mesh(np.concatenate(verts), np.full(len(T), 3), T.reshape(-1), name="scene")
    any_cols = any(m.vertex_colors is not None for m in meshes)
    return mesh, Surface(mats, np.concatenate(tmat), np.concatenate(uvs), np.concatenate(cols) if any_cols else None)
