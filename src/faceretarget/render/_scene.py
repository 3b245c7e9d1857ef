"""A character as it looks: several meshes with their textures, rendered by one orthographic camera.

:func:`render_scene` draws :class:`~faceretarget.character.SceneMesh` objects (a body or head with its
eyes, teeth, hair; each with base-colour textures or colours, alpha modes and sides) with the NumPy z-buffer
rasteriser of :mod:`faceretarget.render._preview`, textures sampled bilinearly in linear light, a soft key light from
the camera's upper left and an ambient term, so a face tracker sees a plausible face.  It also returns
what was hit at every pixel (mesh, triangle, barycentric coordinates): finding a landmark's point on
the surface under a pixel is a look-up (:func:`pick`).

:func:`look_at` makes the camera: a centre, the direction the camera looks from (toward the viewer)
and the up direction, a width in world units and an image size.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from ..character import SceneMesh
from ..errors import InvalidDataError
from ._preview import Camera, _blend_layers, _linear_to_srgb, _rasterize, _srgb_to_linear, _vertex_normals
from ._surface import ALPHA_MODES, bilinear, front_facing

__all__ = ["look_at", "render_scene", "SceneRender", "pick", "barycentric_2d"]


def look_at(center, toward_viewer, up, width: float, size: tuple[int, int] = (512, 512)) -> Camera:
    """An orthographic camera centred on ``center`` seen from ``toward_viewer`` (a direction), with
    ``up`` up, spanning ``width`` world units across the image."""
    b = np.asarray(toward_viewer, dtype=np.float64)
    b = b / np.linalg.norm(b)
    u = np.asarray(up, dtype=np.float64)
    u = u - b * (u @ b)
    if np.linalg.norm(u) < 1e-9:
        raise InvalidDataError("look_at: the up direction is parallel to the view direction")
    u = u / np.linalg.norm(u)
    r = np.cross(u, b)
    W, H = int(size[0]), int(size[1])
    if not (width > 0 and np.isfinite(width)):
        raise InvalidDataError(f"look_at: width must be positive, got {width}")
    return Camera(np.stack([r, u, b]), np.asarray(center, dtype=np.float64), W / float(width), (W, H))


@dataclass(eq=False)
class SceneRender:
    """One rendered frame.

    Attributes
    ----------
    image : (H, W, 3) uint8
        sRGB.
    mesh : (H, W) int
        Index (into the meshes given) of the mesh seen at each pixel, -1 for background.
    triangle : (H, W) int
        The triangle of that mesh (its ``mesh.triangles()`` order), -1 for background.
    bary : (H, W, 3) float
        Barycentric coordinates on that triangle.
    camera : Camera
    """

    image: np.ndarray
    mesh: np.ndarray
    triangle: np.ndarray
    bary: np.ndarray
    camera: Camera


def render_scene(meshes: Sequence[SceneMesh], camera: Camera, *, vertices: Sequence[np.ndarray | None] | None = None,
                 only: Sequence[int] | None = None, background=(0.92, 0.92, 0.92), ambient: float = 0.45,
                 light=(-0.35, 0.45, 0.82), textures: bool = True, both_sides: Sequence[int] = ()) -> SceneRender:
    """Render meshes with their materials.

    Alpha and sides as a glTF viewer draws them (:class:`~faceretarget.character.Material`): a ``MASK``
    material's pixels under its cutoff are not drawn (what is behind a hair card's transparent texels shows),
    ``BLEND`` materials are mixed over the rest by their alpha (in linear light; not counted as what is at a
    pixel), single-sided materials show their front faces only.

    Parameters
    ----------
    meshes : sequence of SceneMesh
    camera : Camera
    vertices : sequence of (V, 3) arrays or None, optional
        Vertices to draw instead of each mesh's rest pose (a posed or animated frame).
    only : sequence of int, optional
        Draw only these meshes (the others are not drawn and do not hide anything).
    background : 3 floats, sRGB 0..1
    ambient : float
    light : 3 floats
        Direction toward the key light in view space (x right, y up, z toward the viewer).
    textures : bool
        Sample base-colour textures (else base colours only).
    both_sides : sequence of int
        Meshes drawn double-sided whatever their materials say (a face mesh wound inside out, looked for).
    """
    W, H = camera.size
    sel = list(range(len(meshes))) if only is None else [int(i) for i in only]
    pts, tris, owner, local_tri = [], [], [], []
    off = 0
    for i in sel:
        m = meshes[i]
        v = m.mesh.vertices if vertices is None or vertices[i] is None else np.asarray(vertices[i], np.float64)
        t = m.mesh.triangles()
        pts.append(v)
        tris.append(t + off)
        owner.append(np.full(len(t), i))
        local_tri.append(np.arange(len(t)))
        off += len(v)
    P = np.concatenate(pts) if pts else np.zeros((0, 3))
    T = np.concatenate(tris) if tris else np.zeros((0, 3), np.int64)
    own = np.concatenate(owner) if owner else np.zeros(0, np.int64)
    loc = np.concatenate(local_tri) if local_tri else np.zeros(0, np.int64)
    p = camera.project(P)
    mode, cutoff, sides, group = _triangle_materials(meshes, own, loc)
    if len(both_sides):
        sides = sides | np.isin(own, np.asarray(both_sides, np.int64))
    # keep triangles with a corner in front of the image plane's box (cheap culling of the body), and of a
    # single-sided material only those facing the camera
    inside = ((p[:, 0] > -W) & (p[:, 0] < 2 * W) & (p[:, 1] > -H) & (p[:, 1] < 2 * H))
    shown = (inside[T].any(axis=1) & (sides | front_facing(p, T))) if len(T) else np.zeros(0, bool)
    keep = np.flatnonzero(shown & (mode < 2))

    def rgba(gt: np.ndarray, B: np.ndarray) -> np.ndarray:
        out = np.empty((len(gt), 4))
        owners = own[gt]
        for i in np.unique(owners):
            rows = np.flatnonzero(owners == i)
            out[rows] = _surface_color(meshes[i], loc[gt[rows]], B[rows], textures)
        return out

    def masked(tt, L0, L1, L2):
        gt = keep[tt]
        ok = np.ones(len(gt), bool)
        m = np.flatnonzero(mode[gt] == 1)
        if m.size:
            ok[m] = rgba(gt[m], np.stack([L0[m], L1[m], L2[m]], axis=1))[:, 3] >= cutoff[gt[m]]
        return ok

    zbuf = np.full(H * W, -np.inf)
    tri_id, bary = _rasterize(p, T[keep], W, H, keep=masked if (mode[keep] == 1).any() else None, zbuf=zbuf)
    hit = np.flatnonzero(tri_id >= 0)
    gt = keep[tri_id[hit]]                                  # global triangle of each hit pixel
    B = bary[hit]
    bg = _srgb_to_linear(np.clip(np.asarray(background, np.float64).reshape(3), 0, 1))
    out = np.empty((H * W, 3))
    out[:] = bg
    L = np.asarray(light, np.float64)
    L = L / np.linalg.norm(L)
    normals = _vertex_normals(P, T) @ camera.rotation.T if len(T) else np.zeros((0, 3))

    def lit(g: np.ndarray, b: np.ndarray) -> np.ndarray:
        n = np.einsum("pk,pkd->pd", b, normals[T[g]])
        n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
        n *= np.where(n[:, 2:3] < 0, -1.0, 1.0)
        return ambient + (1.0 - ambient) * np.clip(n @ L, 0.0, None)

    if hit.size:
        out[hit] = rgba(gt, B)[:, :3] * lit(gt, B)[:, None]
    blend = np.flatnonzero(shown & (mode == 2))
    if blend.size:
        def shade(tt, b):
            c = rgba(tt, b)
            return c[:, :3] * lit(tt, b)[:, None], c[:, 3:4]

        _blend_layers(out, zbuf, p, T, blend, group[blend], shade, W, H)
    img = np.round(_linear_to_srgb(out).reshape(H, W, 3) * 255.0).astype(np.uint8)
    mesh_id = np.full(H * W, -1, np.int64)
    tri_out = np.full(H * W, -1, np.int64)
    mesh_id[hit] = own[gt]
    tri_out[hit] = loc[gt]
    full_b = np.zeros((H * W, 3))
    full_b[hit] = B
    return SceneRender(img, mesh_id.reshape(H, W), tri_out.reshape(H, W), full_b.reshape(H, W, 3), camera)


def _triangle_materials(meshes: Sequence[SceneMesh], own: np.ndarray, loc: np.ndarray
                        ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Per triangle (mesh ``own``, its triangle ``loc``): alpha mode (0 opaque, 1 mask, 2 blend), cutoff,
    double-sided, and a group id per (mesh, material)."""
    n = len(own)
    mode, cutoff, sides, group = np.zeros(n, np.int64), np.full(n, 0.5), np.ones(n, bool), np.zeros(n, np.int64)
    for i in np.unique(own):
        rows = np.flatnonzero(own == i)
        m = meshes[i]
        mats = m.materials or []
        tm = m.triangle_material[loc[rows]] if m.triangle_material is not None and mats else np.zeros(rows.size, int)
        for k in np.unique(tm):
            r = rows[tm == k]
            mat = mats[int(k)] if mats else None
            group[r] = int(i) * 65536 + int(k)
            if mat is None:
                continue
            mode[r] = ALPHA_MODES.index(mat.alpha_mode) if mat.alpha_mode in ALPHA_MODES else 0
            cutoff[r] = float(mat.alpha_cutoff)
            sides[r] = bool(mat.double_sided)
    return mode, cutoff, sides, group


def _surface_color(m: SceneMesh, tri: np.ndarray, B: np.ndarray, textures: bool) -> np.ndarray:
    """Linear RGBA of pixels on triangles ``tri`` of ``m`` at barycentrics ``B``: the material's factor times its
    texture (bilinear) times the vertex colours."""
    mats = m.materials or []
    tm = m.triangle_material
    out = np.empty((len(tri), 4))
    mat_of = tm[tri] if tm is not None and len(mats) else np.zeros(len(tri), np.int64)
    tuv = m.mesh.triangle_uv_indices() if m.mesh.uvs is not None else None
    for k in np.unique(mat_of):
        rows = np.flatnonzero(mat_of == k)
        mat = mats[int(k)] if len(mats) else None
        color = np.array([0.8, 0.8, 0.8, 1.0]) if mat is None else np.r_[np.asarray(mat.color, np.float64)[:4],
                                                                           np.ones(4)][:4]
        img = mat.image if (mat is not None and textures and tuv is not None) else None
        if img is None:
            out[rows] = color
            continue
        uv = np.einsum("pk,pkd->pd", B[rows], m.mesh.uvs[tuv[tri[rows]]])
        out[rows] = _sample(img, uv) * color
    if m.vertex_colors is not None:
        out *= np.einsum("pk,pkd->pd", B, m.vertex_colors[m.mesh.triangles()[tri]])
    return out


#: sRGB byte -> linear light.
_LINEAR = _srgb_to_linear(np.arange(256) / 255.0)


def _sample(img: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Bilinear, repeating texture look-up of ``uv`` (n, 2) (glTF: v down) in linear RGBA (alpha 1 for an RGB
    image)."""
    h, w = img.shape[:2]
    rgba = img.ndim == 3 and img.shape[2] == 4

    def at(yy, xx):                          # gather the bytes first, then only those become linear light
        texel = img[np.mod(yy, h), np.mod(xx, w)]
        if img.dtype != np.uint8:
            c = np.asarray(texel, np.float64)
            return c if rgba else np.concatenate([c[:, :3], np.ones((len(c), 1))], axis=1)
        a = texel[:, 3:4] / 255.0 if rgba else np.ones((len(texel), 1))
        return np.concatenate([_LINEAR[texel[:, :3]], a], axis=1)

    return bilinear(uv, h, w, at)


def pick(render: SceneRender, meshes: Sequence[SceneMesh], points: np.ndarray, mesh: int, *,
         radius: int = 6) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The surface point of mesh ``mesh`` under each image point.

    Parameters
    ----------
    render : SceneRender
        A render in which ``mesh`` was drawn (alone, so nothing hides it).
    points : (P, 2) float
        Pixel coordinates (x right, y down; ``(0, 0)`` the centre of the top-left pixel).
    mesh : int
    radius : int
        A point over no pixel of the mesh (past its silhouette) takes the nearest pixel of it within
        this many pixels.

    Returns
    -------
    triangles : (P, 3) int
        The vertex indices of the triangle under each point (-1 rows where none within ``radius``).
    bary : (P, 3) float
        Exact barycentric coordinates of the point in that triangle's projection (clipped inside it).
    distance : (P,) float
        Pixels from the point to the pixel used (0 when directly over the mesh).
    """
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    H, W = render.mesh.shape
    faces = meshes[mesh].mesh.triangles()
    proj = render.camera.project(meshes[mesh].mesh.vertices)
    on = render.mesh == mesh
    tri_out = np.full((len(pts), 3), -1, np.int64)
    bary_out = np.zeros((len(pts), 3))
    dist = np.full(len(pts), np.inf)
    ys, xs = np.nonzero(on)
    for i, (x, y) in enumerate(pts):
        ix, iy = int(round(x)), int(round(y))
        if 0 <= ix < W and 0 <= iy < H and on[iy, ix]:
            px, py, d = ix, iy, 0.0
        else:
            if not len(xs):
                continue
            dd = (xs - x) ** 2 + (ys - y) ** 2
            j = int(np.argmin(dd))
            d = float(np.sqrt(dd[j]))
            if d > radius:
                continue
            px, py = int(xs[j]), int(ys[j])
        t = int(render.triangle[py, px])
        tv = faces[t]
        q = proj[tv, :2]
        bx = barycentric_2d(q, np.array([x, y]) if d == 0.0 else np.array([px, py], np.float64))
        tri_out[i], bary_out[i], dist[i] = tv, bx, d
    return tri_out, bary_out, dist


def barycentric_2d(q: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Barycentric coordinates of 2-D point ``p`` in triangle ``q`` (3, 2), clipped into it."""
    a, b, c = q
    v0, v1, v2 = b - a, c - a, p - a
    d = v0[0] * v1[1] - v1[0] * v0[1]
    if abs(d) < 1e-12:
        return np.array([1.0, 0.0, 0.0])
    l1 = (v2[0] * v1[1] - v1[0] * v2[1]) / d
    l2 = (v0[0] * v2[1] - v2[0] * v0[1]) / d
    lam = np.clip(np.array([1.0 - l1 - l2, l1, l2]), 0.0, None)
    return lam / lam.sum()
