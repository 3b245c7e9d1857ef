"""Preview rendering with no system dependencies: see :mod:`faceretarget.render.preview`."""

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

__all__ = [
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
