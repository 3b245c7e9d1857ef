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
                 light: Sequence[float] = DEFAULT_LIGHT, ambient: float = 0.22, specular: float = 0.12) -> None:
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
        self.camera = camera if camera is not None else _fit_with_head_room(
            mesh.vertices, self.pivot, size, view, margin, head_room)
        self.size = self.camera.size
        self.color = _check_color(color, mesh)
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
                               background=self.background, **self._shading)
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
        self.ctx = ctx = _create_context()
        try:
            self._build(r)
        except Exception:
            ctx.release()
            raise

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
        # one colour is decoded to linear once; per-vertex sRGB colours are interpolated and decoded per
        # pixel, as render_mesh does (one pow() per pixel more)
        per_vertex = r.color.ndim == 2
        base = "to_linear(v_color)" if per_vertex else "v_color"
        prog = ctx.program(vertex_shader=_VERTEX_SHADER, fragment_shader=_FRAGMENT_SHADER.replace("BASE", base))
        self.prog = prog
        self.vbo_pos = ctx.buffer(reserve=V * 12, dynamic=True)
        self.vbo_normal = ctx.buffer(reserve=V * 12, dynamic=True)
        col = np.broadcast_to(r.color if per_vertex else _srgb_to_linear(r.color), (V, 3)).astype(np.float32)
        self.vbo_color = ctx.buffer(np.ascontiguousarray(col).tobytes())
        self.ibo = ctx.buffer(tris.astype(np.int32).tobytes())
        self.vao = ctx.vertex_array(prog, [(self.vbo_pos, "3f", "in_pos"), (self.vbo_normal, "3f", "in_normal"),
                                           (self.vbo_color, "3f", "in_color")],
                                    index_buffer=self.ibo, index_element_size=4)
        self.fbo = ctx.simple_framebuffer((W, H), components=4)
        # depth: the neutral's radius about the camera centre, with room for large head motion
        radius = float(np.linalg.norm(r.mesh.vertices - cam.center, axis=1).max()) or 1.0
        prog["ndc"].value = (2.0 * cam.scale / W, -2.0 * cam.scale / H)
        prog["zscale"].value = 1.0 / (16.0 * radius)
        L = np.asarray(r._shading["light"], np.float64).reshape(3)
        L = L / max(np.linalg.norm(L), 1e-12)
        half = L + np.array([0.0, 0.0, 1.0])
        half /= np.linalg.norm(half)
        for name, value in (("light", tuple(L)), ("fill", tuple(_FILL)), ("halfway", tuple(half)),
                            ("ambient", r._shading["ambient"]), ("specular", r._shading["specular"])):
            if prog.get(name, None) is not None:  # a compiler may drop a uniform it does not need
                prog[name].value = value
        self.clear = r.background
        self.out = np.empty((H, W, 3), np.uint8)
        self.depth_test = moderngl.DEPTH_TEST

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
        self.vbo_pos.write(p.tobytes())
        self.vbo_normal.write(np.ascontiguousarray(n, np.float32).tobytes())
        M = self.cam_R @ R
        offset = self.cam_R @ (self.pivot + t - self.cam_center)
        # GLSL matrices are column-major: hand it M's columns
        self.prog["M"].write(np.ascontiguousarray(M.T, np.float32).tobytes())
        self.prog["offset"].value = tuple(float(x) for x in offset)
        ctx = self.ctx
        self.fbo.use()
        ctx.enable(self.depth_test)
        self.fbo.clear(*self.clear, 1.0, depth=1.0)
        self.vao.render()
        self.fbo.read_into(self.out, components=3, alignment=1)
        return self.out.copy()

    def release(self) -> None:
        for obj in (self.vao, self.fbo, self.ibo, self.vbo_color, self.vbo_normal, self.vbo_pos, self.prog):
            obj.release()
        self.ctx.release()
