"""faceretarget for Blender: animate the selected character from a video, a take or live, in the open scene.

A thin shell over the faceretarget library (bundled as wheels): the panel (View3D > Sidebar >
faceretarget), operators that start jobs, and the jobs' main-thread steps; every solve runs in the
library, in a worker process.  docs/blender-extension.md describes it.
"""

from __future__ import annotations

import bpy

from . import jobs, operators, panels, props

_CLASSES = props.CLASSES + operators.CLASSES + panels.CLASSES


def register() -> None:
    for cls in _CLASSES:
        bpy.utils.register_class(cls)
    props.attach()
    jobs.start_import()


def unregister() -> None:
    jobs.shutdown()
    props.detach()
    for cls in reversed(_CLASSES):
        bpy.utils.unregister_class(cls)
