"""A fast shaded mesh renderer for preview videos: OpenGL through headless EGL, or the NumPy rasteriser.

:class:`MeshRenderer` is made once per video and renders frame after frame with one fixed camera.
The fast path draws with `moderngl <https://moderngl.readthedocs.io>`_ in a standalone EGL context
(no window, no display server: a GPU driver or Mesa's llvmpipe software rasteriser) and reads the
pixels back; the fallback is :func:`~faceretarget.render.render_mesh`.  Both give the same picture:
an orthographic camera fitted once to the neutral, Lambert shading of smooth vertex normals with the
same key and fill lights and highlight, both sides of every triangle lit, sRGB output (mean
difference well under one grey level, silhouettes equal but for edge pixels:
``tests/test_gl_preview.py``).

Head motion is a rigid transform of the whole mesh about a pivot (the neutral's centroid): a rotation
in the :class:`~faceretarget.headpose.HeadPose` frame (+Y up, +Z forward out of the face, +X the
character's left) and a translation in metres, converted to the mesh's unit with ``mm_per_unit``.

Examples
--------
>>> from faceretarget import Mesh
>>> quad = Mesh.from_triangles([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], [[0, 1, 2], [0, 2, 3]])
>>> with MeshRenderer(quad, (32, 32), backend="numpy", head_room=0.0, margin=0.0) as r:
...     img = r.render(quad.vertices)
>>> img.shape, img.dtype, r.backend
((32, 32, 3), dtype('uint8'), 'numpy')
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ..errors import InvalidDataError, MissingDependencyError
from ..mesh import Mesh
from ..optional import optional_import
from ._preview import (
    DEFAULT_BACKGROUND,
    DEFAULT_COLOR,
    DEFAULT_LIGHT,
    Camera,
    _srgb_to_linear,
    fit_camera,
    render_mesh,
)
from ._surface import Surface

__all__ = ["MeshRenderer", "gl_available", "GL_PACKAGES"]

#: Debian packages that give headless OpenGL through EGL (Mesa's llvmpipe when there is no GPU).
GL_PACKAGES = "libegl1 libgl1-mesa-dri libegl-mesa0"
_BACKENDS = ("auto", "gl", "numpy")
# the fill light of render_mesh's _shade (its highlight exponent, 40, is written out in the shader)
_FILL = np.array([0.6, -0.1, 0.8]) / np.linalg.norm([0.6, -0.1, 0.8])

_VERTEX_SHADER = """
#version 330
uniform mat3 M;        // head rotation then world-to-view rotation
uniform vec3 offset;   // view-space position of the pivot
uniform vec2 ndc;      // view units -> normalised device coordinates (y negated: rows top-down)
uniform float zscale;  // view depth -> device depth (nearer is smaller)
in vec3 in_pos;        // vertex minus pivot, mesh units
in vec3 in_normal;     // area-weighted vertex normal (not normalised)
in vec3 in_color;      // one colour: linear RGB (decoded once on upload); per vertex: sRGB
out vec3 v_normal;
out vec3 v_color;
void main() {
    vec3 p = M * in_pos + offset;
    gl_Position = vec4(p.x * ndc.x, p.y * ndc.y, -p.z * zscale, 1.0);
    float len = length(in_normal);
    v_normal = len > 0.0 ? M * (in_normal / len) : vec3(0.0);
    v_color = in_color;
}
"""

_FRAGMENT_SHADER = """
#version 330
uniform vec3 light;
uniform vec3 fill;
uniform vec3 halfway;
uniform float ambient;
uniform float specular;
in vec3 v_normal;
in vec3 v_color;
out vec4 f_color;
vec3 to_linear(vec3 c) {
    return mix(c / 12.92, pow((c + 0.055) / 1.055, vec3(2.4)), greaterThan(c, vec3(0.04045)));
}
vec3 to_srgb(vec3 c) {
    c = clamp(c, 0.0, 1.0);
    return mix(12.92 * c, 1.055 * pow(c, vec3(1.0 / 2.4)) - 0.055, greaterThan(c, vec3(0.0031308)));
}
void main() {
    float len = length(v_normal);
    vec3 n = len > 1e-12 ? v_normal / len : vec3(0.0);
    if (n.z < 0.0) n = -n;  // two-sided: a face seen from behind is lit as if it faced the viewer
    float diff = max(dot(n, light), 0.0) * 0.85 + max(dot(n, fill), 0.0) * 0.18;
    // h^40 by squaring (h^32 h^8): a general pow() per pixel costs llvmpipe about a tenth of the frame
    float h = max(dot(n, halfway), 0.0);
    float h2 = h * h;
    float h8 = (h2 * h2) * (h2 * h2);
    float h32 = (h8 * h8) * (h8 * h8);
    float spec = specular * h32 * h8;
    f_color = vec4(to_srgb(BASE * (ambient + diff) + spec), 1.0);
}
"""


# The surface path (a Surface: materials, textures, alpha modes, sides; render/_surface.py): the same
# camera, normals and lights, the base colour per pixel from the material's factor, its sRGB texture
# (decoded by the texture format, before filtering) and the vertex colour (linear).
_SURFACE_VERTEX_SHADER = """
#version 330
uniform mat3 M;
uniform vec3 offset;
uniform vec2 ndc;
uniform float zscale;
in vec3 in_pos;
in vec3 in_normal;
in vec2 in_uv;
in vec4 in_rgba;       // linear RGBA vertex colour
out vec3 v_normal;
out vec2 v_uv;
out vec4 v_rgba;
void main() {
    vec3 p = M * in_pos + offset;
    gl_Position = vec4(p.x * ndc.x, p.y * ndc.y, -p.z * zscale, 1.0);
    float len = length(in_normal);
    v_normal = len > 0.0 ? M * (in_normal / len) : vec3(0.0);
    v_uv = in_uv;
    v_rgba = in_rgba;
}
"""

_SURFACE_FRAGMENT_SHADER = """
#version 330
uniform vec3 light;
uniform vec3 fill;
uniform vec3 halfway;
uniform float ambient;
uniform float specular;
uniform sampler2D tex;
uniform vec4 factor;   // the material's base colour, linear RGBA
uniform int use_tex;
uniform int mode;      // 0 opaque, 1 mask, 2 blend
uniform float cutoff;
in vec3 v_normal;
in vec2 v_uv;
in vec4 v_rgba;
out vec4 f_color;
vec3 to_srgb(vec3 c) {
    c = clamp(c, 0.0, 1.0);
    return mix(12.92 * c, 1.055 * pow(c, vec3(1.0 / 2.4)) - 0.055, greaterThan(c, vec3(0.0031308)));
}
void main() {
    vec4 base = factor * v_rgba;
    if (use_tex == 1) base *= texture(tex, v_uv);
    DISCARD
    float len = length(v_normal);
    vec3 n = len > 1e-12 ? v_normal / len : vec3(0.0);
    if (n.z < 0.0) n = -n;
    float diff = max(dot(n, light), 0.0) * 0.85 + max(dot(n, fill), 0.0) * 0.18;
    float h = max(dot(n, halfway), 0.0);
    float h2 = h * h;
    float h8 = (h2 * h2) * (h2 * h2);
    float h32 = (h8 * h8) * (h8 * h8);
    float spec = specular * h32 * h8;
    f_color = vec4(to_srgb(base.rgb * (ambient + diff) + spec), mode == 2 ? base.a : 1.0);
}
"""
_GL_SRGB8_ALPHA8 = 0x8C43


def gl_available() -> tuple[bool, str]:
    """Whether the OpenGL path can run here, and if not why (with what to install).

    Creates and releases one EGL context (a fraction of a second).

    Returns
    -------
    ok : bool
    detail : str
        The ``GL_RENDERER`` string, or the reason the fast path cannot be used.
    """
    try:
        ctx = _create_context()
    except MissingDependencyError as e:
        return False, str(e)
    try:
        return True, str(ctx.info.get("GL_RENDERER", "unknown"))
    finally:
        ctx.release()


def _create_context():
    """A standalone OpenGL >= 3.3 context through EGL, or :class:`MissingDependencyError` saying why."""
    moderngl = optional_import("moderngl", "the fast preview renderer")
    try:
        return moderngl.create_standalone_context(backend="egl", require=330)
    except Exception as e:  # moderngl/glcontext raise bare Exceptions for a missing libEGL or driver
        msg = " ".join(str(e).split()) or type(e).__name__
        raise MissingDependencyError(
            f"the fast preview renderer found no OpenGL 3.3 through EGL ({msg}): "
            f"apt-get install {GL_PACKAGES}") from e


class MeshRenderer:
    """Render one mesh's frames (same faces, moving vertices, head motion) to ``(H, W, 3)`` uint8 images.

    Parameters
    ----------
    mesh : Mesh
        The neutral: its faces are drawn, its vertices fix the camera and the head-motion pivot.
    size : (width, height)
        Image size in pixels (the camera's size when ``camera`` is given).
    backend : ``"auto"``, ``"gl"`` or ``"numpy"``
        ``"auto"`` uses OpenGL when it can and otherwise the NumPy rasteriser (:attr:`reason` says
        why); ``"gl"`` raises :class:`~faceretarget.errors.MissingDependencyError` instead.
    color : 3 floats or (V, 3) array
        Surface colour, sRGB 0..1, one for the mesh or one per vertex.
    background : 3 floats
        Background colour, sRGB 0..1.
    camera : Camera, optional
        Use this camera instead of fitting one.
    view : str, float or (3, 3) array
        The view the camera is fitted for (:func:`~faceretarget.render.view_rotation`).
    margin : float
        Free fraction of the image on each side of the fitted framing.
    head_room : float
        Degrees of head yaw and pitch (either way) the fitted framing leaves room for: the camera is
        fitted to the neutral turned by this much about the pivot as well as to the neutral itself.
    mm_per_unit : float
        Millimetres per mesh unit (``Rig.mm_per_unit``: 10 for cm, 1000 for m); head translations
        arrive in metres.
    pivot : (3,) float, optional
        Centre of head rotations, mesh units (default: the mean of the neutral's vertices).
    light : 3 floats
        Direction toward the key light in view space (x right, y up, z toward the viewer).
    ambient, specular : float
        As in :func:`~faceretarget.render.render_mesh`.
    surface : Surface, optional
        Materials, textures and vertex colours of the mesh's triangles
        (:class:`~faceretarget.render.Surface`): drawn as a glTF viewer draws them (textures per pixel,
        alpha masks, blended materials after the opaque ones and back to front, back faces culled where a
        material is single-sided); ``color`` is then not used.
    fit_to : (N, 3) float, optional
        Points the camera is fitted to instead of the mesh's vertices (a face with more of the head around
        it than the picture shows, so that the edge where the mesh was cut stays out of the picture).

    Attributes
    ----------
    backend : str
        ``"gl (EGL, <GL_RENDERER>)"`` or ``"numpy"``.
    reason : str
        Why the OpenGL path is not used (empty when it is).
    camera : Camera
    pivot : (3,) float

    Examples
    --------
    ``with MeshRenderer(rig.neutral, (512, 512), mm_per_unit=rig.mm_per_unit) as r:`` then
    ``r.render(rig.evaluate(w), R, t)`` per frame (``R`` (3, 3), ``t`` (3,) metres, both optional).
    """

    def __init__(self, mesh: Mesh, size: tuple[int, int] = (512, 512), *, backend: str = "auto",
                 color: Sequence[float] | np.ndarray = DEFAULT_COLOR,
                 background: Sequence[float] = DEFAULT_BACKGROUND, camera: Camera | None = None,
                 view: str | float | np.ndarray = "front", margin: float = 0.05, head_room: float = 20.0,
                 mm_per_unit: float = 1000.0, pivot: np.ndarray | None = None,
                 light: Sequence[float] = DEFAULT_LIGHT, ambient: float = 0.22, specular: float = 0.12,
                 surface: Surface | None = None, fit_to: np.ndarray | None = None) -> None:
        if not isinstance(mesh, Mesh):
            raise InvalidDataError(f"MeshRenderer needs a Mesh, got {type(mesh).__name__}")
        if backend not in _BACKENDS:
            raise InvalidDataError(f"unknown render backend '{backend}', use one of {list(_BACKENDS)}")
        if not (np.isfinite(mm_per_unit) and mm_per_unit > 0):
            raise InvalidDataError(f"{mesh.name}: mm_per_unit must be positive, got {mm_per_unit}")
        self.mesh = mesh
        self.triangles = mesh.triangles()
        if not len(self.triangles):
            raise InvalidDataError(f"{mesh.name}: the mesh has no faces to render")
        self.pivot = (mesh.vertices.mean(axis=0) if pivot is None
                      else np.asarray(pivot, np.float64).reshape(3))
        self.units_per_metre = 1000.0 / float(mm_per_unit)
        framed = mesh.vertices if fit_to is None else np.asarray(fit_to, np.float64).reshape(-1, 3)
        self.camera = camera if camera is not None else _fit_with_head_room(
            framed, self.pivot, size, view, margin, head_room)
        self.size = self.camera.size
        self.color = _check_color(color, mesh)
        if surface is not None:
            surface.check(len(self.triangles), mesh.n_vertices, mesh.name)
        self.surface = surface
        self.background = tuple(float(c) for c in np.clip(np.asarray(background, np.float64).reshape(3), 0, 1))
        self._shading = {"light": light, "ambient": float(ambient), "specular": float(specular)}
        self.backend = "numpy"
        self.reason = ""
        self._gl: _GLState | None = None
        if backend == "numpy":
            self.reason = "backend='numpy' was asked for"
            return
        try:
            self._gl = _GLState(self)
        except MissingDependencyError as e:
            if backend == "gl":
                raise
            self.reason = str(e)
            return
        self.backend = f"gl (EGL, {self._gl.renderer})"

    # ------------------------------------------------------------------ context manager
    def __enter__(self) -> MeshRenderer:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        """Release the OpenGL context and its buffers (the NumPy path holds none); idempotent."""
        if self._gl is not None:
            self._gl.release()
            self._gl = None

    # ------------------------------------------------------------------ rendering
    def transform(self, vertices: np.ndarray, head_rotation: np.ndarray | None = None,
                  head_translation: np.ndarray | None = None) -> np.ndarray:
        """The vertices moved by the head: ``R (v - pivot) + pivot + t`` (``(V, 3)`` mesh units;
        ``t`` given in metres)."""
        v, R, t = self._check(vertices, head_rotation, head_translation)
        return (v - self.pivot) @ R.T + self.pivot + t

    def render(self, vertices: np.ndarray, head_rotation: np.ndarray | None = None,
               head_translation: np.ndarray | None = None) -> np.ndarray:
        """One frame.

        Parameters
        ----------
        vertices : (V, 3) float
            The face's vertices in mesh units (the mesh's vertex order), before head motion.
        head_rotation : (3, 3) float, optional
            Head rotation (:class:`~faceretarget.headpose.HeadPose` frame) about :attr:`pivot`.
        head_translation : (3,) float, optional
            Head translation in metres, in the same frame.

        Returns
        -------
        (H, W, 3) uint8
        """
        v, R, t = self._check(vertices, head_rotation, head_translation)
        if self._gl is None:
            moved = (v - self.pivot) @ R.T + self.pivot + t
            return render_mesh(moved, self.triangles, camera=self.camera, color=self.color,
                               background=self.background, surface=self.surface, **self._shading)
        return self._gl.render(v, R, t)

    def _check(self, vertices, head_rotation, head_translation) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        v = np.asarray(vertices, np.float64)
        nv = self.mesh.n_vertices
        if v.shape != (nv, 3):
            raise InvalidDataError(f"{self.mesh.name}: vertices have shape {v.shape}, the mesh has ({nv}, 3)")
        R = np.eye(3) if head_rotation is None else np.asarray(head_rotation, np.float64)
        if R.shape != (3, 3) or not np.isfinite(R).all():
            raise InvalidDataError(f"{self.mesh.name}: head rotation must be a finite (3, 3) matrix, got "
                                   f"shape {R.shape}")
        t = np.zeros(3) if head_translation is None else np.asarray(head_translation, np.float64)
        if t.shape != (3,) or not np.isfinite(t).all():
            raise InvalidDataError(f"{self.mesh.name}: head translation must be 3 finite metres, got shape "
                                   f"{t.shape}")
        return v, R, t * self.units_per_metre

    def __repr__(self) -> str:
        W, H = self.size
        return f"MeshRenderer({self.mesh.name}, {W}x{H}, {self.backend})"


def _fit_with_head_room(vertices: np.ndarray, pivot: np.ndarray, size, view, margin: float,
                        head_room: float) -> Camera:
    """A camera framing ``vertices`` (V, 3) and their copies turned by +-``head_room`` degrees of yaw
    and pitch about ``pivot``."""
    from scipy.spatial.transform import Rotation

    stack = [vertices]
    a = float(head_room)
    if a > 0:
        for axis in ("y", "x"):
            for s in (-a, a):
                R = Rotation.from_euler(axis, s, degrees=True).as_matrix()
                stack.append((vertices - pivot) @ R.T + pivot)
    return fit_camera(np.stack(stack), size, view, margin)


def _check_color(color, mesh: Mesh) -> np.ndarray:
    c = np.asarray(color, np.float64)
    if c.shape == (3,) or c.shape == (mesh.n_vertices, 3):
        return np.clip(c, 0.0, 1.0)
    raise InvalidDataError(f"{mesh.name}: colour must be 3 floats or ({mesh.n_vertices}, 3), got {c.shape}")


class _GLState:
    """The OpenGL objects of one :class:`MeshRenderer`: context, program, buffers, framebuffer."""

    def __init__(self, r: MeshRenderer) -> None:
        self.ctx = _create_context()
        self._objects: list = []
        try:
            self._build(r)
        except Exception:
            self.release()
            raise

    def _keep(self, obj):
        self._objects.append(obj)
        return obj

    def _build(self, r: MeshRenderer) -> None:
        import moderngl

        ctx = self.ctx
        self.renderer = str(ctx.info.get("GL_RENDERER", "unknown"))
        cam = r.camera
        W, H = cam.size
        self.size = (W, H)
        self.pivot = r.pivot
        self.cam_R = cam.rotation
        self.cam_center = cam.center
        tris = r.triangles
        V = r.mesh.n_vertices
        self.tris = tris
        # sparse vertex-face incidence (V x F): vertex normals = incidence @ face normals
        from scipy.sparse import csr_matrix

        rows = tris.reshape(-1)
        cols = np.repeat(np.arange(len(tris)), 3)
        self.incidence = csr_matrix((np.ones(rows.size, np.float32), (rows, cols)), shape=(V, len(tris)))
        self.surface = r.surface
        if r.surface is None:
            self._build_plain(r, V)
        else:
            self._build_surface(r, V)
        self.fbo = self._keep(ctx.simple_framebuffer((W, H), components=4))
        # depth: the neutral's radius about the camera centre, with room for large head motion
        radius = float(np.linalg.norm(r.mesh.vertices - cam.center, axis=1).max()) or 1.0
        L = np.asarray(r._shading["light"], np.float64).reshape(3)
        L = L / max(np.linalg.norm(L), 1e-12)
        half = L + np.array([0.0, 0.0, 1.0])
        half /= np.linalg.norm(half)
        for prog in self.programs:
            prog["ndc"].value = (2.0 * cam.scale / W, -2.0 * cam.scale / H)
            prog["zscale"].value = 1.0 / (16.0 * radius)
            for name, value in (("light", tuple(L)), ("fill", tuple(_FILL)), ("halfway", tuple(half)),
                                ("ambient", r._shading["ambient"]), ("specular", r._shading["specular"])):
                if prog.get(name, None) is not None:  # a compiler may drop a uniform it does not need
                    prog[name].value = value
        self.clear = r.background
        self.out = np.empty((H, W, 3), np.uint8)
        self.depth_test = moderngl.DEPTH_TEST

    def _build_plain(self, r: MeshRenderer, V: int) -> None:
        """One colour or per-vertex colours, every triangle drawn and lit from both sides."""
        ctx = self.ctx
        # one colour is decoded to linear once; per-vertex sRGB colours are interpolated and decoded per
        # pixel, as render_mesh does (one pow() per pixel more)
        per_vertex = r.color.ndim == 2
        base = "to_linear(v_color)" if per_vertex else "v_color"
        prog = self.prog = self._keep(ctx.program(vertex_shader=_VERTEX_SHADER,
                                                  fragment_shader=_FRAGMENT_SHADER.replace("BASE", base)))
        self.programs = [prog]
        self.src = None
        self.vbo_pos = self._keep(ctx.buffer(reserve=V * 12, dynamic=True))
        self.vbo_normal = self._keep(ctx.buffer(reserve=V * 12, dynamic=True))
        col = np.broadcast_to(r.color if per_vertex else _srgb_to_linear(r.color), (V, 3)).astype(np.float32)
        vbo_color = self._keep(ctx.buffer(np.ascontiguousarray(col).tobytes()))
        ibo = self._keep(ctx.buffer(self.tris.astype(np.int32).tobytes()))
        self.vao = self._keep(ctx.vertex_array(prog, [(self.vbo_pos, "3f", "in_pos"),
                                                      (self.vbo_normal, "3f", "in_normal"),
                                                      (vbo_color, "3f", "in_color")],
                                               index_buffer=ibo, index_element_size=4))

    def _build_surface(self, r: MeshRenderer, V: int) -> None:
        """A :class:`Surface`: a vertex per (vertex, texture coordinate) pair, triangles grouped by material
        (the opaque and masked ones in one index buffer, the blended ones in one rewritten each frame,
        back to front), a texture per image with the surface's own mip levels."""
        import moderngl

        ctx = self.ctx
        sf = r.surface
        tris = self.tris
        # a shader that may discard a pixel is depth-tested after it runs (llvmpipe shades every covered
        # pixel): only the masked materials use that one
        prog = self.prog = self._keep(ctx.program(vertex_shader=_SURFACE_VERTEX_SHADER,
                                                  fragment_shader=_SURFACE_FRAGMENT_SHADER.replace("DISCARD", "")))
        prog_mask = self._keep(ctx.program(
            vertex_shader=_SURFACE_VERTEX_SHADER,
            fragment_shader=_SURFACE_FRAGMENT_SHADER.replace("DISCARD", "if (base.a < cutoff) discard;")))
        self.programs = [prog, prog_mask]
        # materials that draw alike (texture, factor, alpha, sides) are one group: one draw call
        tm = _draw_groups(sf)[sf.triangle_material]
        # one drawn vertex per (group, vertex, texture coordinate), a group's vertices side by side:
        # llvmpipe shades every vertex in the index range of a draw call
        uvc = sf.uvs.reshape(-1, 2) if sf.uvs is not None else np.zeros((tris.size, 2))
        corner = np.concatenate([np.repeat(tm, 3)[:, None].astype(np.float64),
                                 tris.reshape(-1, 1).astype(np.float64), uvc], axis=1)
        key, inverse = np.unique(corner, axis=0, return_inverse=True)
        self.src = key[:, 1].astype(np.int64)
        uv = key[:, 2:]
        rtris = inverse.reshape(-1, 3)
        R = len(self.src)
        rgba = sf.vertex_colors[self.src] if sf.vertex_colors is not None else np.ones((R, 4))
        self.vbo_pos = self._keep(ctx.buffer(reserve=R * 12, dynamic=True))
        self.vbo_normal = self._keep(ctx.buffer(reserve=R * 12, dynamic=True))
        vbo_uv = self._keep(ctx.buffer(uv.astype(np.float32).tobytes()))
        vbo_rgba = self._keep(ctx.buffer(rgba.astype(np.float32).tobytes()))
        content = [(self.vbo_pos, "3f", "in_pos"), (self.vbo_normal, "3f", "in_normal"), (vbo_uv, "2f", "in_uv"),
                   (vbo_rgba, "4f", "in_rgba")]
        modes = sf.modes()
        mats = [int(k) for k in np.unique(tm)]
        # the groups nearest first (mean depth of their triangles at rest): a pixel covered by a nearer group (hair
        # over the scalp) fails the depth test before it is shaded; within a group the file's order, whose
        # neighbouring triangles share vertices
        z = (r.mesh.vertices - r.camera.center) @ r.camera.rotation[2]
        depth = {k: -float(z[tris[tm == k]].mean()) for k in mats}
        solid = sorted((k for k in mats if modes[k] < 2), key=lambda k: (modes[k], depth[k]))
        self.groups, order, start = [], [], 0
        for k in solid:
            t = np.flatnonzero(tm == k)
            self.groups.append((k, start, t.size))
            order.append(t)
            start += t.size
        order = np.concatenate(order) if order else np.zeros(0, np.int64)
        ibo = self._keep(ctx.buffer(np.ascontiguousarray(rtris[order], np.int32).tobytes() or b"\0" * 12))
        self.vao = self._keep(ctx.vertex_array(prog, content, index_buffer=ibo, index_element_size=4))
        self.vao_mask = self._keep(ctx.vertex_array(prog_mask, content, index_buffer=ibo, index_element_size=4))
        self.blend = [(k, np.flatnonzero(tm == k)) for k in mats if modes[k] == 2]
        self.rtris = rtris
        if self.blend:
            n = sum(t.size for _, t in self.blend)
            self.ibo_blend = self._keep(ctx.buffer(reserve=n * 12, dynamic=True))
            self.vao_blend = self._keep(ctx.vertex_array(prog, content, index_buffer=self.ibo_blend,
                                                         index_element_size=4))
        self.textures: dict[int, object] = {}
        self.factor = sf.factors()
        self.single = ~sf.double_sided()
        self.modes = modes
        for k in mats:
            tex = sf.texture(k)
            if tex is None or id(tex) in self.textures:
                continue
            lv = tex.levels
            gt = self._keep(ctx.texture((lv[0].shape[1], lv[0].shape[0]), 4, lv[0].tobytes(),
                                        internal_format=_GL_SRGB8_ALPHA8))
            gt.build_mipmaps()
            for j in range(1, len(lv)):
                gt.write(lv[j].tobytes(), level=j)
            gt.filter = (moderngl.LINEAR_MIPMAP_NEAREST, moderngl.LINEAR)
            gt.repeat_x = gt.repeat_y = True
            self.textures[id(tex)] = gt
        self.tex_of = {k: (self.textures[id(sf.texture(k))] if sf.texture(k) is not None else None) for k in mats}
        for pr in self.programs:
            pr["tex"].value = 0

    def render(self, v: np.ndarray, R: np.ndarray, t: np.ndarray) -> np.ndarray:
        """``v`` (V, 3) mesh units, ``R`` (3, 3) head rotation, ``t`` (3,) translation in mesh units."""
        p = (v - self.pivot).astype(np.float32)
        tr = self.tris
        a = p[tr[:, 0]]
        e1 = p[tr[:, 1]] - a
        e2 = p[tr[:, 2]] - a
        fn = np.empty_like(e1)  # cross product written out: faster than np.cross for (F, 3)
        fn[:, 0] = e1[:, 1] * e2[:, 2] - e1[:, 2] * e2[:, 1]
        fn[:, 1] = e1[:, 2] * e2[:, 0] - e1[:, 0] * e2[:, 2]
        fn[:, 2] = e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]
        n = self.incidence @ fn
        if self.src is None:
            self.vbo_pos.write(p.tobytes())
            self.vbo_normal.write(np.ascontiguousarray(n, np.float32).tobytes())
        else:
            self.vbo_pos.write(np.ascontiguousarray(p[self.src]).tobytes())
            self.vbo_normal.write(np.ascontiguousarray(n[self.src], np.float32).tobytes())
        M = self.cam_R @ R
        offset = self.cam_R @ (self.pivot + t - self.cam_center)
        # GLSL matrices are column-major: hand it M's columns
        for prog in self.programs:
            prog["M"].write(np.ascontiguousarray(M.T, np.float32).tobytes())
            prog["offset"].value = tuple(float(x) for x in offset)
        ctx = self.ctx
        self.fbo.use()
        ctx.enable(self.depth_test)
        self.fbo.clear(*self.clear, 1.0, depth=1.0)
        if self.src is None:
            self.vao.render()
        else:
            self._draw_surface(p, M, offset)
        self.fbo.read_into(self.out, components=3, alignment=1)
        return self.out.copy()

    def _material(self, k: int) -> None:
        import moderngl

        prog, ctx = self.programs[int(self.modes[k] == 1)], self.ctx
        prog["factor"].value = tuple(float(x) for x in self.factor[k])
        if prog.get("mode", None) is not None:
            prog["mode"].value = int(self.modes[k])
        if prog.get("cutoff", None) is not None:
            prog["cutoff"].value = float(self.surface.materials[k].alpha_cutoff)
        tex = self.tex_of[k]
        prog["use_tex"].value = int(tex is not None)
        if tex is not None:
            tex.use(0)
        if self.single[k]:
            ctx.enable(moderngl.CULL_FACE)
            ctx.front_face = "cw"         # counter-clockwise as seen, clockwise once the rows are flipped
            ctx.cull_face = "back"
        else:
            ctx.disable(moderngl.CULL_FACE)

    def _draw_surface(self, p: np.ndarray, M: np.ndarray, offset: np.ndarray) -> None:
        import moderngl

        ctx = self.ctx
        for k, first, count in self.groups:
            self._material(k)
            vao = self.vao_mask if self.modes[k] == 1 else self.vao
            vao.render(moderngl.TRIANGLES, vertices=3 * count, first=3 * first)
        if self.blend:
            z = p @ M[2].astype(np.float32) + np.float32(offset[2])   # view depth, larger is nearer
            tr = self.tris
            groups = sorted(self.blend, key=lambda g: float(z[tr[g[1]]].mean()))
            order, spans, start = [], [], 0
            for k, t in groups:
                o = t[np.argsort(z[tr[t]].sum(axis=1), kind="stable")]          # farthest first
                order.append(o)
                spans.append((k, start, o.size))
                start += o.size
            self.ibo_blend.write(np.ascontiguousarray(self.rtris[np.concatenate(order)], np.int32).tobytes())
            ctx.enable(moderngl.BLEND)
            ctx.blend_func = moderngl.SRC_ALPHA, moderngl.ONE_MINUS_SRC_ALPHA
            self.fbo.depth_mask = False
            for k, first, count in spans:
                self._material(k)
                self.vao_blend.render(moderngl.TRIANGLES, vertices=3 * count, first=3 * first)
            self.fbo.depth_mask = True
            ctx.disable(moderngl.BLEND)
        ctx.disable(moderngl.CULL_FACE)

    def release(self) -> None:
        for obj in reversed(self._objects):
            obj.release()
        self._objects = []
        self.ctx.release()


def _draw_groups(sf: Surface) -> np.ndarray:
    """(M,) for each material of ``sf`` the index of the first material that draws like it (same texture,
    factor, alpha mode and cutoff, sides)."""
    seen: dict = {}
    out = np.empty(len(sf.materials), np.int64)
    fac = sf.factors()
    for k, m in enumerate(sf.materials):
        key = (id(m.image) if sf.texture(k) is not None else None, tuple(np.round(fac[k], 9)), m.alpha_mode,
               float(m.alpha_cutoff), bool(m.double_sided))
        out[k] = seen.setdefault(key, k)
    return out
