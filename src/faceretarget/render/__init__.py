"""Preview rendering: the NumPy rasteriser (no system dependencies) and :class:`MeshRenderer`, the fast
OpenGL (EGL) path for preview videos that falls back to it; both draw a :class:`Surface` (materials,
textures, alpha modes, sides) as a glTF viewer does."""

from ._gl import GL_PACKAGES, MeshRenderer, gl_available
from ._preview import (
    DEFAULT_BACKGROUND,
    DEFAULT_COLOR,
    DEFAULT_LIGHT,
    Camera,
    fit_camera,
    render_frames,
    render_grid,
    render_mesh,
    render_shapes,
    save_png,
    view_rotation,
)
from ._scene import SceneRender, barycentric_2d, look_at, pick, render_scene
from ._surface import ALPHA_MODES, Surface, scene_surface

__all__ = [
    "render_scene",
    "SceneRender",
    "look_at",
    "pick",
    "barycentric_2d",
    "MeshRenderer",
    "Surface",
    "scene_surface",
    "ALPHA_MODES",
    "gl_available",
    "GL_PACKAGES",
    "Camera",
    "fit_camera",
    "view_rotation",
    "render_mesh",
    "render_frames",
    "render_shapes",
    "render_grid",
    "save_png",
    "DEFAULT_LIGHT",
    "DEFAULT_COLOR",
    "DEFAULT_BACKGROUND",
]
