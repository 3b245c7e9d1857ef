"""From a video to an animated character in one call: the ``animate`` command (Chuang 2004, Ch. 5).

The thesis's Ch. 5 system as one pipeline::

    video --capture--> 478 landmarks, ARKit scores, head pose (neutral-calibrated, One Euro filtered)
          --68 points, head motion removed--> [emotion: restyled by the style model, per emotion]
          --solve on the character's own shapes (LandmarkSolver, or keyshape pairs)-->  weights
          --[emotions blended by alpha(t), Eq. 5.1]--> [--speech: re-timed to new speech by DTW]
          --head: tracked, synthesized from the speech (Ch. 4), or off-->  one file (+ preview video)

A character with ARKit-named shapes and its 68 landmarks is driven by
:class:`~faceretarget.retarget.LandmarkSolver`: its own shapes fitted to the tracked points, with
the tracker's calibrated scores as a prior where the points do not see a shape.  Any other character
is driven through keyshape pairs (``source_keys``: point sets of the 68 landmarks in the actor's
normalised face frame, as :func:`face_take` gives them; ``target_keys``: the artist's shapes).

Emotion (Eq. 5.1): for every emotion ``e`` with a non-zero ``alpha_e(t)`` the take's 68 points are
restyled into ``e`` by a :class:`~faceretarget.style.StyleModel` trained on face takes of the same
kind (:func:`face_take` of videos), each restyled take is solved on the character, and the weight
takes are blended, ``w(t) = (1 - sum_e alpha_e(t)) w(t) + sum_e alpha_e(t) w_e(t)``; the
character's shapes are linear in its weights, so this is the blend of the retargeted faces.  The
content (what is said) is kept by the style model, so the lip sync is kept.
"""

from __future__ import annotations

import dataclasses
import os
import time
import warnings
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..capture import Capture, face_points, mouth_opening
from ..errors import InvalidDataError, StyleRangeWarning
from ..formats import CSV, GLB
from ..formats import VIDEO_EXTENSIONS as _VIDEO_EXTENSIONS
from ..headpose import HeadPose
from ..names import is_arkit
from ..performance import Performance
from ..retarget import STABLE68 as _STABLE
from ..retarget import LandmarkSolver, neutral_face, similarity_fit
from ..rig import Rig
from ..style import SpeakerStyleModel
from ..timebase import infer_fps
from ._progress import working

__all__ = ["FACE_EYE_MM", "GAZE_DEG", "gaze_rotations", "animate", "AnimateOptions", "AnimateResult", "tracked_take", "face_take",
           "face_frame", "face_takes", "VIDEO_EXTENSIONS", "parse_emotion", "HEAD_SOURCES", "drives_by_landmarks"]

#: Where ``animate``'s head motion comes from.
HEAD_SOURCES = ("video", "speech", "off")
_LABELS = [f"lm{i}" for i in range(68)]
#: The distance between the outer eye corners a face take is scaled to (a typical adult's, in mm):
#: monocular video has no scale of its own.
FACE_EYE_MM = 90.0
#: Least ARKit-named shapes for a character to be driven by its own shapes from landmarks.
_MIN_ARKIT = 10


def _quiet(*_a) -> None:
    return None


@dataclass(eq=False)
class AnimateResult:
    """What :func:`animate` made.

    Attributes
    ----------
    weights : (T, K) float
        In ``names`` order (the character's shapes, or its target keys).
    names : list of str
    times : (T,) float
        Seconds (the video's frame times, or the new speech's with ``speech``).
    head : HeadPose or None
        The character's head motion (metres, rotation about the head's rest pose).
    audio, audio_rate
        The soundtrack (the video's or the new speech).
    take : Performance
        The tracked take (68 points in pixels and the tracker's scores, :func:`tracked_take`).
    capture : Capture or None
        The post-processed capture of the video (None when a take was given).
    tracked_mouth, character_mouth : (T,) float
        Mouth opening (inner lips over the eye-corner distance) of the tracked face and of the
        character's own lip vertices, per output frame (before ``speech`` re-timing: the video's frames).
    timings : dict
        Seconds per stage (``capture``, ``solve``, ``emotion``, ``head``, ``write``, ``preview``).
    outputs : list of Path
    """

    weights: np.ndarray
    names: list[str]
    times: np.ndarray
    head: HeadPose | None
    audio: np.ndarray | None
    audio_rate: float | None
    take: Performance
    capture: Capture | None
    tracked_mouth: np.ndarray
    character_mouth: np.ndarray
    timings: dict = field(default_factory=dict)
    outputs: list = field(default_factory=list)
    alpha: np.ndarray | None = None
    emotions: list = field(default_factory=list)
    drive: object = None
    gaze: dict = field(default_factory=dict)

    @property
    def mouth_corr(self) -> float:
        """Correlation over the take of the tracked and the character's mouth opening."""
        a, b = self.tracked_mouth, self.character_mouth
        if a.std() == 0 or b.std() == 0:
            return float("nan")
        return float(np.corrcoef(a, b)[0, 1])

    def summary(self) -> str:
        """One line: frames, faces found, time per stage."""
        cap = self.capture
        tm = " ".join(f"{k} {v:.2f}s" for k, v in self.timings.items())
        found = ("" if cap is None else f" ({cap.detected.mean():.0%} with a face found, "
                 f"{int(cap.interpolated.sum())} filled)")
        return (f"{len(self.times)} frames{found} -> {len(self.names)} shapes; mouth correlation "
                f"{self.mouth_corr:.3f}; {tm}; total {sum(self.timings.values()):.2f}s")


def video_solver() -> LandmarkSolver:
    """The solver :func:`animate` uses for a whole take: the tracker's scores as a strong prior (``prior=10``; the
    shapes the tracker does not score keep the weak ``0.1``, else they would be held at rest; the eye shapes'
    twice as strong) with per-take gains fitted to the landmarks' motion for the shapes away from the mouth,
    within 0.5-2 (at least 1 for the eye shapes; the mouth shapes' stay 1) (:class:`~faceretarget.retarget.LandmarkSolver`'s module
    docstring).  ``prior`` and ``eye_prior`` chosen on P11's range-of-motion take (``alex_rom_3``), measured on
    the three others (``bench/fidelity.py``); leaving the mouth out of the gains was chosen after seeing those
    three (docs/results.md says so)."""
    return LandmarkSolver(prior=10.0, gains=True, unscored_prior=0.1, eye_prior=2.0, mouth_gains=False,
                          gain_min=0.5, gain_max=2.0, eye_floor=True)


def frame_solver() -> LandmarkSolver:
    """The solver of the live modes, one frame at a time: :func:`video_solver`'s priors (the tracker's scores
    strong, ``prior=10``; unscored shapes weak, ``0.1``; the eye shapes' twice as strong) without its per-take
    gains, which are fitted over a whole take.  On P11's 24 cached runs (``bench/fidelity.py``'s renders, solved
    offline with each solver) it is within 0.00-0.08x of :func:`video_solver` (brows 0.98x / 0.90x of the peer's
    error, the rest equal); the default :class:`~faceretarget.retarget.LandmarkSolver` the live modes used
    before (the scores a weak prior, ``0.1``) lost to the peer everywhere: mouth 1.26x / 1.55x, blink F1 0.16 /
    0.37 (peer 0.77)."""
    return LandmarkSolver(prior=10.0, unscored_prior=0.1, eye_prior=2.0, mouth_gains=False, eye_floor=True)


def drives_by_landmarks(character: Rig) -> bool:
    """Whether ``character`` is driven by its own shapes: its 68 landmarks and either ARKit-named shapes
    (a rig folder) or shapes chosen from a character file (:func:`~faceretarget.characters.drive_rig`,
    any names)."""
    return (character.landmarks is not None and len(character.landmarks) == 68 and character.n_shapes > 0
            and (character.keep_names or sum(is_arkit(n) for n in character.names) >= _MIN_ARKIT))


# --------------------------------------------------------------------------------------- face takes
def tracked_take(capture: Capture) -> Performance:
    """A capture's valid frames as a take of the 68 face points and the tracker's scores.

    Returns
    -------
    Performance
        Points ``(T, 68, 3)`` in pixels (+Y up, +Z toward the camera; :func:`~faceretarget.capture.face_points`)
        labelled ``lm0`` .. ``lm67``, the tracker's calibrated ARKit scores as weights, the head pose
        and the audio.
    """
    perf = capture.to_performance("weights")
    return perf.replace(points=face_points(capture.landmarks[capture.valid]), labels=_LABELS, unit="px")


def _tracked(take) -> Performance:
    """A tracked take (68 points and scores) of a Capture or a Performance of 68 points."""
    if isinstance(take, Capture):
        return tracked_take(take)
    if not isinstance(take, Performance) or take.points is None or take.points.shape[1:] != (68, 3):
        raise InvalidDataError(f"{getattr(take, 'source', take)}: expected a capture or a take of the 68 face "
                               "points (x, y, z)")
    return take


def face_take(take: Capture | Performance, *, neutral: np.ndarray | None = None) -> Performance:
    """A take's 68 face points with the head's motion removed, in a normalised face frame.

    The points of every frame (a :class:`~faceretarget.capture.Capture`'s through
    :func:`tracked_take`) are fitted by a similarity onto the actor's neutral face
    (:func:`~faceretarget.retarget.neutral_face`) on the stable points, and the neutral is scaled to
    a nominal :data:`FACE_EYE_MM` between the outer eye corners and centred on the stable points:
    takes of one actor share this frame, whatever the camera distance.

    Returns
    -------
    Performance
        Points ``(T, 68, 3)`` labelled ``lm0`` .. ``lm67`` in nominal millimetres, with the take's head
        pose and audio (no weights).
    """
    tr = _tracked(take)
    P = tr.points
    s, R, c = face_frame(tr, neutral=neutral)
    aligned = np.einsum("tpi,tij->tpj", P - c[:, None], R) / s[:, None, None]
    return Performance(tr.times, tr.fps, points=aligned, labels=_LABELS, unit="mm",
                       head=tr.head, audio=tr.audio, audio_rate=tr.audio_rate, source=tr.source)


def face_frame(take: Capture | Performance, *, neutral: np.ndarray | None = None
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Each frame's similarity onto the normalised face frame of :func:`face_take`.

    Returns
    -------
    s : (T,) float
    R : (T, 3, 3) float
    c : (T, 3) float
        The tracked 68 points are ``P[t] ~ s[t] face[t] @ R[t].T + c[t]`` (pixels, +Y up), with
        ``face`` the points of :func:`face_take` (nominal millimetres): a change ``d`` of the face take
        is ``s[t] d @ R[t].T`` in the tracked points.
    """
    tr = _tracked(take)
    P = tr.points
    n0 = neutral_face(P, tr.weights) if neutral is None else np.asarray(neutral, dtype=np.float64)
    n0 = FACE_EYE_MM * (n0 - n0[_STABLE].mean(axis=0)) / np.linalg.norm(n0[36] - n0[45])
    return similarity_fit(n0[_STABLE], P[:, _STABLE])


#: Video file extensions ``style fit`` captures into face takes.
VIDEO_EXTENSIONS = _VIDEO_EXTENSIONS


def face_takes(videos: Mapping[str, str | os.PathLike], *, reference: str | None = None, scores: bool = False,
               log: Callable[..., None] = _quiet, **capture) -> dict[str, Performance]:
    """Face takes (:func:`face_take`) of one actor's videos in several styles, for a style model.

    Every take shares the actor's neutral face, taken from the ``reference`` style's video
    (default ``"neutral"`` when given, else the first): a take's own quietest frames would hold its
    emotion (an angry resting face) and remove it.  ``scores``: each take also carries the tracker's
    ARKit scores as its weights, uncalibrated (what a :class:`~faceretarget.style.SpeakerStyleModel`
    reads; it measures them from each speaker's neutral take).
    """
    from ._capture import capture_take

    if not videos:
        raise InvalidDataError("face_takes: no video given")
    ref = reference or ("neutral" if "neutral" in videos else next(iter(videos)))
    if ref not in videos:
        raise InvalidDataError(f"face_takes: reference style '{ref}' has no video")
    # scores: raw, so an emotional take keeps its offset (a take's own percentile would remove it)
    caps = {k: capture_take(v, neutral_percentile=None if scores else 5.0, log=log, **capture)
            for k, v in videos.items()}
    rc = tracked_take(caps[ref])
    n0 = neutral_face(rc.points, rc.weights)
    out = {k: face_take(c, neutral=n0) for k, c in caps.items()}   # (similarity fits: any frame of n0)
    if scores:
        for k, c in caps.items():
            tr = tracked_take(c)
            out[k] = out[k].replace(weights=tr.weights, names=list(tr.names))
    return out


# --------------------------------------------------------------------------------------- emotion
def parse_emotion(spec: str | os.PathLike | Mapping | None, *, styles=None) -> dict:
    """Emotion keys for :class:`~faceretarget.style.AlphaCurves`: ``"angry:0.6"``,
    ``"angry:0.6,happy:0.2"``, a mapping, or a curve file of ``TIME EMOTION AMOUNT`` lines (``#``
    comments; amounts in [0, 1]; between keys linear).

    Returns
    -------
    dict
        ``{emotion: constant or [(time, amount), ...]}``.
    """
    if spec is None:
        return {}
    if isinstance(spec, Mapping):
        keys = dict(spec)
    elif isinstance(spec, str) and ":" in spec and not Path(spec).is_file():
        keys = {}
        for part in spec.split(","):
            name, _, amt = part.strip().partition(":")
            try:
                keys[name.strip()] = float(amt)
            except ValueError:
                raise InvalidDataError(f"--emotion {spec!r}: expected EMOTION:AMOUNT[,EMOTION:AMOUNT], "
                                       f"e.g. angry:0.6") from None
    else:
        path = Path(spec)
        if not path.is_file():
            raise InvalidDataError(f"--emotion {spec}: neither EMOTION:AMOUNT nor a curve file")
        keys = {}
        for i, line in enumerate(path.read_text().splitlines(), 1):
            line = line.split("#", 1)[0].strip()
            if not line:
                continue
            parts = line.split()
            try:
                t, name, amt = float(parts[0]), parts[1], float(parts[2])
                if len(parts) != 3:
                    raise ValueError
            except (ValueError, IndexError):
                raise InvalidDataError(f"{path}, line {i}: expected TIME EMOTION AMOUNT, got {line!r}") from None
            if not np.isfinite(t):
                raise InvalidDataError(f"{path}, line {i}: time {t} is not finite")
            keys.setdefault(name, []).append((t, amt))
        if not keys:
            raise InvalidDataError(f"{path}: no TIME EMOTION AMOUNT line")
    for name, val in keys.items():
        vals = [val] if np.isscalar(val) else [a for _, a in val]
        for a in vals:
            if not (np.isfinite(a) and 0.0 <= a <= 1.0):
                raise InvalidDataError(f"emotion '{name}': amount {a} is outside [0, 1]")
        if styles is not None and name not in styles:
            raise InvalidDataError(f"emotion '{name}' is not in the style model (it has {', '.join(styles)})")
    return keys


def _alpha(keys: dict, times: np.ndarray) -> tuple[list[str], np.ndarray]:
    """``(emotions, alpha (T, E))``: each emotion's share over time, the rest the input's own."""
    from ..style import AlphaCurves

    emotions = sorted(keys)
    a = AlphaCurves(["input"] + emotions, {"input": 0.0, **keys}).raw(times)[:, 1:]
    total = a.sum(axis=1, keepdims=True)
    return emotions, np.where(total > 1.0, a / np.maximum(total, 1e-300), a)


# --------------------------------------------------------------------------------------- head
def _about_rest(head: HeadPose, amplitude: float, source: str) -> HeadPose:
    """``head`` about its rest (mean rotation, median position), scaled by ``amplitude``: the motion the
    character's head makes about its own rest pose."""
    from scipy.spatial.transform import Rotation

    rot = head.rotation
    rel = rot.mean().inv() * rot
    tr = None
    if head.translation is not None:
        tr = (head.translation - np.nanmedian(head.translation, axis=0)) * amplitude
    return HeadPose.from_rotation(Rotation.from_rotvec(rel.as_rotvec() * amplitude), tr, source=source)


def _video_head(take: Performance, amplitude: float) -> HeadPose | None:
    """The take's head pose about its rest (mean rotation, median position), scaled by ``amplitude``."""
    if take.head is None:
        return None
    return _about_rest(take.head, amplitude, f"{take.source} (tracked head)")


#: Seconds of tracked head pose a take needs before ``head_range="auto"`` takes its range (a range read
#: off a few frames says little about how far the actor turns the head).
MIN_RANGE_SECONDS = 2.0


def _speech_range(take: Performance, head_range, log) -> np.ndarray | None:
    """Degrees (3,) the synthesized head turns (``motion_range``), or None for the database speaker's own
    range: ``head_range`` given in degrees, or with ``"auto"`` the take's tracked head (the actor's range)."""
    from ..headmotion import rotation_range

    if isinstance(head_range, str):
        if head_range == "database":
            log("head from speech: it turns as far as the database's speakers turn theirs (--head-range database)")
            return None
        if take.head is not None:
            rot = take.head.to_euler("YXZ")
            n = int(np.isfinite(rot).all(axis=1).sum())
            if n / max(take.fps, 1e-9) >= MIN_RANGE_SECONDS:
                r = rotation_range(_video_head(take, 1.0))          # as the character would turn with it
                log(f"head from speech: it turns as far as the actor's tracked head, yaw / pitch / roll "
                    f"{r[0]:.1f} / {r[1]:.1f} / {r[2]:.1f} deg (5-95 % range of {n} frames; --head-range "
                    "database for the database speakers' own, or give degrees)")
                return r
            why = f"only {n / max(take.fps, 1e-9):.1f} s of tracked head pose"
        else:
            why = "the take has no head pose"
        log(f"head from speech: it turns as far as the database's speakers turn theirs ({why}; give "
            "--head-range degrees for the speaker's own)")
        return None
    r = np.broadcast_to(np.asarray(head_range, np.float64), (3,)).copy()
    log(f"head from speech: it turns yaw / pitch / roll {r[0]:g} / {r[1]:g} / {r[2]:g} deg (5-95 % range, given)")
    return r


def _speech_head(db_path, audio, rate, times, amplitude: float, log, motion_range=None) -> HeadPose:
    from ..headmotion import HeadMotionDatabase

    if audio is None:
        raise InvalidDataError("head motion from speech needs audio: the video has none (give --speech WAV)")
    db = HeadMotionDatabase.load(db_path)
    res = db.transform(np.asarray(audio, dtype=np.float64).reshape(len(audio), -1).mean(axis=1), rate,
                       amplitude=amplitude, seed=0, fps=infer_fps(times, default=30.0), source="speech",
                       motion_range=motion_range)
    take = res.take
    log(f"head motion synthesized from the speech: {res.info.segmentation.n_segments} segment(s), about the "
        "character's rest pose")
    # the database's motion is about its speakers' mean pose (a BVH neck may hold the head turned); the
    # character's head moves about its own rest, as with the tracked head
    head = take.head.resample(take.times, np.clip(times - times[0], take.times[0], take.times[-1]))
    head = _about_rest(head, 1.0, "speech (synthesized head)")
    if motion_range is not None:
        head = _turned_as_far(head, np.asarray(motion_range, np.float64) * amplitude)
    return head


def _turned_as_far(head: HeadPose, degrees: np.ndarray) -> HeadPose:
    """``head`` (about its rest) with each Euler angle scaled so its 5-95 % range is ``degrees`` (3,).

    The database scales its motion about its speakers' mean pose (turned 8-12 degrees down for the shared
    takes); seen about the character's rest, yaw then leaks into roll and the ranges come out up to 16 %
    off (the roll of a sway asked 3.9 degrees read 3.3): scaled again here, they are what was asked."""
    from ..headmotion import EULER, rotation_range

    got = rotation_range(head)
    scale = np.where(got > 1e-9, np.asarray(degrees) / np.maximum(got, 1e-9), 0.0)
    e = head.to_euler(EULER) * scale
    return HeadPose.from_euler(EULER, e, head.translation, source=head.source)


#: The eye rotations (degrees) the tracker's ARKit gaze scores stand for at 1: looking out or in, up, down.
GAZE_DEG = {"out": 30.0, "in": 30.0, "up": 25.0, "down": 30.0}


def gaze_rotations(names: list[str], scores: np.ndarray) -> dict:
    """Each eye's rotation relative to the head (head frame) from the tracker's ``eyeLook*`` scores.

    ``out``/``in`` turn an eye about the head's up axis (the left eye's "out" toward the character's left,
    +X), ``up``/``down`` about its left-right axis, by :data:`GAZE_DEG` times the score.

    Returns
    -------
    dict
        ``{"leftEye": Rotation, "rightEye": Rotation}`` of ``T`` keys; ``{}`` when the scores have no gaze.
    """
    from scipy.spatial.transform import Rotation

    from ..names import normalize_name

    col = {normalize_name(n): i for i, n in enumerate(names)}
    S = np.nan_to_num(np.asarray(scores, dtype=np.float64), nan=0.0)
    if not any(f"eyeLook{d}Left" in col for d in ("In", "Out", "Up", "Down")):
        return {}
    out = {}
    for side, sign in (("Left", 1.0), ("Right", -1.0)):
        def s(name):
            return S[:, col[name]] if name in col else np.zeros(len(S))
        yaw = sign * (GAZE_DEG["out"] * s(f"eyeLookOut{side}") - GAZE_DEG["in"] * s(f"eyeLookIn{side}"))
        pitch = GAZE_DEG["up"] * s(f"eyeLookUp{side}") - GAZE_DEG["down"] * s(f"eyeLookDown{side}")
        out[f"{side.lower()}Eye"] = Rotation.from_euler("YX", np.stack([yaw, -pitch], axis=1), degrees=True)
    return out


# --------------------------------------------------------------------------------------- animate
@dataclass
class AnimateOptions:
    """Every option of :func:`animate`, with its default: one object the CLI, the Blender extension's worker,
    batch jobs and live sessions fill and pass (``animate(video, character, options)``), or keyword arguments
    of the same names (``animate(video, character, out="a.glb")``).

    Attributes
    ----------
    out : path-like, optional
        For a character file, the same format as its input writes the animation back into a copy of
        that file (:func:`~faceretarget.io.write_character_animation`: every node, mesh, material,
        texture and existing animation kept); otherwise ``.glb``, ``.usd``/``.usda``/``.usdc``,
        ``.blend``, ``.fbx``, ``.csv`` (Live Link Face) or any format
        :func:`~faceretarget.io.write_animation` writes.
    preview : path-like, optional
        ``.mp4``: the video and the character side by side, with the audio.
    preview_video : path-like, optional
        The video shown beside the character (default ``video`` when it is a file; needed for a
        preview of a capture or take).
    head : {"video", "speech", "off"}
        Tracked head pose, head motion synthesized from the speech (needs ``head_db``), or none.
    head_db : path-like, optional
        The head-motion database (``faceretarget headmotion build``) for ``head="speech"``.
    head_amplitude : float
        Scale of the head's rotation angles and translation (0..10).
    head_range : "auto", "database", float or 3 floats
        For ``head="speech"``: how far the synthesized head turns (degrees, 5-95 % range of yaw, pitch,
        roll; one number for all three).  ``"auto"``: as far as the take's tracked head turns when it has
        at least ``MIN_RANGE_SECONDS`` of pose (the actor's own range: nothing in the speech tells it,
        ``docs/headmotion.md``), else as far as the database's speakers; ``"database"``: always the latter.
    emotion : str, path or mapping, optional
        ``"angry:0.6"``, or a curve file (:func:`parse_emotion`); needs ``style``.
    style : StyleModel, SpeakerStyleModel or path-like, optional
        A style model trained on face takes (:func:`face_take`) of the emotions named: of one actor,
        or of several speakers (:class:`~faceretarget.style.SpeakerStyleModel`, which carries to an
        actor it has never seen; the actor's rest face is the take's mean, so give a neutral take).
    speech : path-like, optional
        New speech of the same text: the animation is re-timed to it by DTW of the audio and
        carries it as its soundtrack (and it drives ``head="speech"``).
    source_keys : Rig, optional
    target_keys : Rig or Target, optional
        Keyshape pairs for a character not driven by its own shapes; a
        :class:`~faceretarget.targets.Target` (control table, skeleton, drawings) is written in its
        own parameters and formats (no preview).
    solver : LandmarkSolver, optional
        Unfitted, with its parameters (default :func:`video_solver`: the tracker's scores a strong prior,
        with per-take gains fitted to the landmarks).
    max_frames : int, optional
        Track at most this many frames of the video.
    landmarker : path-like, optional
        A MediaPipe Face Landmarker model file (default the packaged one).
    preview_size : int
        Pixels of the character's half of the preview.
    preview_backend : str
        ``"auto"``, ``"gl"`` or ``"numpy"`` (:func:`~faceretarget.render.preview_renderer`).
    preview_colors : (V, 3) float, optional
        For a rig given as the character: the sRGB colour (0..1) of each of its vertices in the preview
        (the demo's faces: :func:`~faceretarget.datasets.demo_vertex_colors`); default clay.  A character
        file's preview shows its own materials and textures.
    bake : bool
        USD output: mesh points per frame instead of blend-shape weights.
    progress : bool
        Progress bars on stderr.
    shapes : str
        For a character file: which of its shapes drive (``auto``, ``arkit``, ``visemes``, ``all`` or
        names; :func:`~faceretarget.character.choose_shapes`).
    landmarks : path-like, optional
        For a character file: its 68 landmarks (overrides the search and the cache).
    mesh : str, optional
        For a character file with several heads: the face mesh to drive.
    neck_share : float
        For a character file with a neck joint: the share of the head's rotation the neck takes (0..1).
    """

    out: str | os.PathLike | None = None
    preview: str | os.PathLike | None = None
    preview_video: str | os.PathLike | None = None
    head: str = "video"
    head_db: str | os.PathLike | None = None
    head_amplitude: float = 1.0
    head_range: object = "auto"
    emotion: object = None
    style: object = None
    speech: str | os.PathLike | None = None
    source_keys: Rig | None = None
    target_keys: object = None
    solver: LandmarkSolver | None = None
    max_frames: int | None = None
    landmarker: str | os.PathLike | None = None
    preview_size: int = 512
    preview_backend: str = "auto"
    preview_colors: np.ndarray | None = None
    bake: bool = False
    progress: bool = False
    shapes: str = "auto"
    landmarks: str | os.PathLike | None = None
    mesh: str | None = None
    neck_share: float = 0.0

    def check(self) -> AnimateOptions:
        """Refuse out-of-range values before any work (an :class:`~faceretarget.errors.InvalidDataError`)."""
        if self.head not in HEAD_SOURCES:
            raise InvalidDataError(f"head must be one of {', '.join(HEAD_SOURCES)}, got {self.head!r}")
        if not (np.isfinite(self.head_amplitude) and 0.0 <= self.head_amplitude <= 10.0):
            raise InvalidDataError(f"head amplitude must be in [0, 10], got {self.head_amplitude}")
        if isinstance(self.head_range, str):
            if self.head_range not in ("auto", "database"):
                raise InvalidDataError(f"head range must be 'auto', 'database' or degrees, got {self.head_range!r}")
        else:
            try:
                r = np.broadcast_to(np.asarray(self.head_range, np.float64), (3,))
            except (TypeError, ValueError) as e:
                raise InvalidDataError(f"head range must be 'auto', 'database', one number or three (yaw, pitch, "
                                       f"roll degrees), got {self.head_range!r}") from e
            if not (np.isfinite(r).all() and ((r >= 0) & (r <= 360)).all()):
                raise InvalidDataError(f"head range must be in [0, 360] degrees, got {r.tolist()}")
        if self.head == "speech" and self.head_db is None:
            raise InvalidDataError("head motion from speech needs a head-motion database (--head-db DB.npz, "
                                   "made by 'faceretarget headmotion build')")
        if not (np.isfinite(self.neck_share) and 0.0 <= self.neck_share <= 1.0):
            raise InvalidDataError(f"neck share must be in [0, 1], got {self.neck_share}")
        return self


@dataclass(eq=False)
class _Solved:
    """The face solved onto the character: weights, their names, what plays them, a target that writes itself
    (controls, skeleton, drawings), and the solve itself for restyled points."""

    weights: np.ndarray
    names: list[str]
    play: Rig
    own: object
    solve: Callable[[np.ndarray], np.ndarray]
    face: Performance


class _Clock:
    """``with clock("stage"):`` adds the stage's seconds to ``timings``."""

    def __init__(self, timings: dict):
        self.timings, self._stage = timings, None

    def __call__(self, stage: str) -> _Clock:
        self._stage = stage
        return self

    def __enter__(self):
        self._t0 = time.perf_counter()

    def __exit__(self, *exc):
        if exc[0] is None:
            self.timings[self._stage] = time.perf_counter() - self._t0


def animate(video: str | os.PathLike | Capture, character, options: AnimateOptions | None = None, *,
            log: Callable[..., None] = _quiet, **kwargs) -> AnimateResult:
    """Animate ``character`` from a video of an actor (Chuang Ch. 5's system): capture -> solve -> emotion ->
    head -> write -> preview, optionally writing the animation (face and head, with the soundtrack where the
    format holds one) and a preview.

    Parameters
    ----------
    video : path-like, Capture or Performance
        Any video FFmpeg reads, a capture already made (:func:`capture_take`), or a tracked take of
        the 68 face points, with the tracker's scores as weights when it has them (:func:`tracked_take`).
    character : path-like, Character or Rig
        A character file (any format of :data:`faceretarget.formats.CHARACTER_FORMATS`) or a
        :class:`~faceretarget.character.Character` read from one: its own shapes, whatever their names,
        drive its face from the landmarks (found on a render and cached; ``landmarks``, ``mesh``,
        ``shapes``).  Or a :class:`~faceretarget.rig.Rig` (a folder of OBJ files): ARKit-named shapes and
        68 landmarks, or any rig with ``source_keys`` / ``target_keys``.
    options : AnimateOptions, optional
        Every other option (its attributes document them); keyword arguments of the same names override it.
    """
    o = dataclasses.replace(options or AnimateOptions(), **kwargs).check()
    timings: dict[str, float] = {}
    clock = _Clock(timings)
    speech_audio = None
    if o.speech is not None:                      # new speech: a silent file is refused before any work
        from ..io import read_audio

        speech_audio = read_audio(o.speech, speech=True)
    character, drive = _drive(character, o, clock, log)
    by_landmarks = _check_drivable(character, o)
    style_model, keys = _emotion_keys(o)
    with clock("capture"):
        cap, take = _capture(video, o, log)
    with clock("solve"):
        s = _solve(character, take, o, by_landmarks, log)
    if o.preview is not None and s.own is not None:
        raise InvalidDataError(f"{o.preview}: a preview plays a mesh character; a {s.own.kind} target writes its "
                               "own pictures (out: .png / .mp4 for drawings)")
    how = "its own shapes from the landmarks" if by_landmarks else "keyshape pairs"
    log(f"solved {len(s.weights)} frames on {character.name} ({how}) in {timings['solve']:.2f} s")
    alpha, emotions, W = None, [], s.weights
    if keys:
        with clock("emotion"):
            W, alpha, emotions = _emotion(s, take, style_model, keys, log)
    character_mouth = (mouth_opening(s.play.evaluate(W, s.play.landmarks)) if s.play.landmarks is not None
                       and len(s.play.landmarks) == 68 else np.full(len(W), np.nan))
    with clock("head"):
        W, times, pose, audio, rate = _head(W, take, o, speech_audio, log)
    res = AnimateResult(weights=W, names=s.names, times=times, head=pose, audio=audio, audio_rate=rate, take=take,
                        capture=cap, tracked_mouth=mouth_opening(take.points), character_mouth=character_mouth,
                        timings=timings, alpha=alpha, emotions=emotions, drive=drive)
    if o.out is not None:
        with clock("write"):
            _write_out(res, s, drive, take, o, speech_audio is not None, log)
    if o.preview is not None:
        with clock("preview"):
            _write_preview(res, video, s, drive, o, log)
    log(res.summary())
    return res


def _drive(character, o: AnimateOptions, clock: _Clock, log):
    """The rig the solve works on, and the character file's drive rig (None for a rig given as such)."""
    if isinstance(character, Rig):
        return character, None
    from ..characters import drive_rig, load_character

    with clock("character"):
        loaded = load_character(character, landmarks=o.landmarks, mesh=o.mesh, log=log)
        drive = drive_rig(loaded, o.shapes)
    log(f"{loaded.name}: {drive.summary}")
    return drive.rig, drive


def _check_drivable(character: Rig, o: AnimateOptions) -> bool:
    """Whether the character is driven by its own shapes from landmarks; else it needs keyshape pairs."""
    by_landmarks = drives_by_landmarks(character)
    if not by_landmarks and (o.source_keys is None or o.target_keys is None):
        raise InvalidDataError(
            f"{character.name}: the character has {sum(is_arkit(n) for n in character.names)} ARKit-named shapes "
            f"and {0 if character.landmarks is None else len(character.landmarks)} landmarks; to be driven by its "
            f"own shapes it needs >= {_MIN_ARKIT} and the 68 (landmarks68.txt). Otherwise give keyshape pairs "
            "(--source-keys DIR --target-keys DIR)")
    return by_landmarks


def _emotion_keys(o: AnimateOptions):
    style_model = _load_style(o.style)
    keys = parse_emotion(o.emotion, styles=None if style_model is None else style_model.styles_)
    if keys and style_model is None:
        raise InvalidDataError("--emotion needs a style model (--style MODEL.npz, from 'faceretarget style fit' "
                               "on face takes of the emotions)")
    return style_model, keys


def _capture(video, o: AnimateOptions, log) -> tuple[Capture | None, Performance]:
    """The capture of a video file (None when a capture or take is given) and its tracked take."""
    if isinstance(video, Capture | Performance):
        return (video if isinstance(video, Capture) else None), _tracked(video)
    from ._capture import capture_take

    cap = capture_take(video, landmarker=o.landmarker, max_frames=o.max_frames, neutral_percentile=5.0,
                       progress=o.progress, log=log)
    return cap, tracked_take(cap)


def _solve(character: Rig, take: Performance, o: AnimateOptions, by_landmarks: bool, log) -> _Solved:
    """The take solved onto the character: its own shapes from the landmarks (the tracker's scores a prior),
    or keyshape pairs."""
    ftake = face_take(take)
    if not by_landmarks:
        from ._clone_retarget import retarget_take

        def solve_pairs(points: np.ndarray) -> np.ndarray:
            return retarget_take(ftake.with_points(points), o.source_keys, o.target_keys,
                                 solver="nnls").result.weights

        tr = retarget_take(ftake, o.source_keys, o.target_keys, solver="nnls", log=log)
        own = tr.target if tr.target is not None and tr.target.kind != "mesh" else None
        return _Solved(tr.result.weights, list(tr.result.names), tr.target_keys, own, solve_pairs, ftake)
    from ..characters import ScorePrior, held_shapes

    # the scores' drive of the character's shapes: by name, or through the ARKit template's landmark motion
    sp = None if take.weights is None else ScorePrior(character, list(take.names), log=log)
    prior = None if sp is None else sp(take.weights, smooth=lambda X: _smooth_take(X, take.times))
    sol = (o.solver or video_solver()).fit(character, neutral_face(ftake.points))   # the face take's rest face
    # the shapes the scores hold, whatever they scored in this take (the live modes hold the same)
    scored = None if sp is None else held_shapes(character, list(take.names), sp.rows)

    def solve(points: np.ndarray) -> np.ndarray:
        return sol.transform(points, prior, take.times, scored=scored).weights

    with working(f"solving {len(ftake.times)} frames on {character.name}", o.progress):
        W = solve(ftake.points)
    return _Solved(W, list(character.names), character, None, solve, ftake)


def _smooth_take(X: np.ndarray, times: np.ndarray) -> np.ndarray:
    """``X`` (T, K) through the capture's One Euro filter both ways (no lag), each run of consecutive frames on its
    own (a take leaves out the frames without a face: a step over 1.5 frame intervals ends a run)."""
    from ..capture import DEFAULT_SMOOTH, one_euro

    t = np.asarray(times, np.float64)
    out = np.array(X, np.float64)
    dt = np.diff(t)
    cut = np.flatnonzero(dt > 1.5 * np.median(dt)) + 1 if len(dt) else np.zeros(0, int)
    for a, b in zip(np.r_[0, cut], np.r_[cut, len(t)], strict=True):
        if b - a > 1:
            out[a:b] = one_euro(out[a:b], t[a:b], DEFAULT_SMOOTH, both_ways=True)
    return out


def _emotion(s: _Solved, take: Performance, style_model, keys, log):
    """Eq. 5.1: the solve blended, per emotion, with the solve of the restyled take by the emotion's alpha(t)."""
    emotions, alpha = _alpha(keys, take.times - take.times[0])
    src = "neutral" if "neutral" in style_model.styles_ else None
    blend = (1.0 - alpha.sum(axis=1, keepdims=True)) * s.weights
    speakers = isinstance(style_model, SpeakerStyleModel)
    ftake = s.face
    if speakers and take.weights is not None:                       # its score spaces read the scores
        ftake = ftake.replace(weights=take.weights, names=list(take.names))
    for j, e in enumerate(emotions):
        if not alpha[:, j].any():
            continue
        if speakers:                                                # the actor's rest: the take itself
            r = style_model.transform(ftake, e, 1.0)
        else:
            r = style_model.transform(ftake, e, 1.0, source=src if src != e else None, warn=False)
        blend += alpha[:, j:j + 1] * s.solve(r.take.points)
        log(f"emotion '{e}': up to {alpha[:, j].max():.2f} of the face")
        if r.range.outside:                  # the same warning as 'restyle' gives (one line, by the CLI)
            warnings.warn(f"emotion '{e}': the restyled take leaves the range of the style model's training "
                          f"data by {r.range.score:.2f} of its width ({r.range.frames_outside:.0%} of frames "
                          f"beyond {r.range.margin:g}); the face may be implausible (reduce the amount)",
                          StyleRangeWarning, stacklevel=3)
    return blend, alpha, emotions


def _head(W: np.ndarray, take: Performance, o: AnimateOptions, speech_audio, log):
    """Head motion on the take's frames, then new speech: everything re-timed to it by DTW of the audio."""
    times, audio, rate = take.times, take.audio, take.audio_rate
    pose = _video_head(take, o.head_amplitude) if o.head == "video" else None
    if speech_audio is not None:
        W, times, src_t = _retime(W, times, take, speech_audio, log)
        audio, rate = speech_audio
        if pose is not None:
            pose = pose.resample(take.times, src_t)
    if o.head == "speech":
        pose = _speech_head(o.head_db, audio, rate, times, o.head_amplitude, log,
                            _speech_range(take, o.head_range, log))
    return W, times, pose, audio, rate


def _write_out(res: AnimateResult, s: _Solved, drive, take: Performance, o: AnimateOptions, new_speech: bool,
               log) -> None:
    """``out``: a target that writes itself, a copy of the character's own file, or any animation format."""
    log(f"writing {o.out}")
    if s.own is not None:                       # controls, skeleton, drawings: the target writes itself
        res.outputs.append(s.own.write(o.out, res.weights[:, s.own.key_order(res.names)], res.times, log=log,
                                       progress=o.progress))
        log(f"wrote {o.out} ({len(res.times)} frames of the {s.own.kind} target)")
    elif drive is not None and _writes_back(drive.character, o.out):
        from ..io import write_character_animation

        res.gaze = _eye_joints(drive, take) if not new_speech else {}
        res.outputs.append(write_character_animation(
            o.out, drive.character, drive.channels, drive.full_weights(res.weights), res.times, head=res.head,
            audio=res.audio, audio_rate=res.audio_rate, neck_share=o.neck_share, gaze=res.gaze, log=log))
    else:
        res.outputs.append(_write(o.out, s.play, res, o.bake, log))


def _write_preview(res: AnimateResult, video, s: _Solved, drive, o: AnimateOptions, log) -> None:
    """``preview``: the video beside the character as it looks (textures, every mesh about the face)."""
    shown = o.preview_video if o.preview_video is not None else (
        video if isinstance(video, str | os.PathLike) else None)
    if shown is None:
        raise InvalidDataError(f"{o.preview}: a preview of a capture or take needs the video to show beside "
                               "the character (preview_video)")
    if drive is not None:
        from ..characters import character_look

        look = character_look(drive)
        res.outputs.append(_preview(o.preview, shown, look.rig, res, o.preview_size, o.preview_backend, o.progress,
                                    log, surface=look.surface, pivot=look.pivot, fit_to=look.frame,
                                    turns=look.eye_turns(res.gaze)))
    else:
        colors = {} if o.preview_colors is None else {"colors": o.preview_colors}
        res.outputs.append(_preview(o.preview, shown, s.play, res, o.preview_size, o.preview_backend, o.progress,
                                    log, **colors))


def _eye_joints(drive, take: Performance) -> dict:
    """Gaze on the character's eye joints, when it has them and no gaze shapes drive (``eyeLook*``)."""
    ch = drive.character
    if take.weights is None or not (ch.joint("leftEye") or ch.joint("rightEye")):
        return {}
    driven = {n for n in drive.rig.normalized_names}
    if any(n.startswith("eyeLook") for n in driven):
        return {}
    return gaze_rotations(take.names, take.weights)


def _writes_back(character, out) -> bool:
    """Whether ``out`` writes the animation back into (a copy of) the character's own file."""
    from ..io import writes_back

    return writes_back(character, out)


def _load_style(style):
    """A :class:`~faceretarget.style.StyleModel` (one actor) or :class:`~faceretarget.style.SpeakerStyleModel`
    (several speakers), given or read from its file."""
    if style is None:
        return None
    from ..base import Model
    from ..style import SpeakerStyleModel, StyleModel

    if isinstance(style, StyleModel | SpeakerStyleModel):
        return style
    m = Model.load(style)
    if not isinstance(m, StyleModel | SpeakerStyleModel):
        from ..errors import InputFileError

        raise InputFileError(f"{style}: holds a {type(m).__name__}, not a style model ('style fit' writes one)")
    return m


def _retime(W, times, take: Performance, speech_audio, log):
    """The weights re-timed onto new speech (DTW of the audio), at the video's frame rate."""
    from ..style import align_audio, resample

    if take.audio is None:
        raise InvalidDataError(f"{take.source}: re-timing to new speech needs the video's own audio, it has none")
    x, rate = speech_audio
    mono = np.asarray(x, dtype=np.float64).reshape(len(x), -1).mean(axis=1)
    vmono = np.asarray(take.audio, dtype=np.float64).reshape(len(take.audio), -1).mean(axis=1)
    al = align_audio(mono, rate, vmono, take.audio_rate)
    fps = take.fps
    new_t = np.arange(0.0, len(mono) / rate, 1.0 / fps)
    src_t = np.clip(al(new_t) + times[0], times[0], times[-1])     # the audio starts at the first frame
    Wn = np.clip(resample(W, times, src_t), W.min(), W.max())
    log(f"re-timed to the new speech: {len(mono) / rate:.2f} s (video {times[-1] - times[0] + 1 / fps:.2f} s), "
        f"{len(new_t)} frames by DTW of the audio")
    return Wn, new_t, src_t


def _write(out, rig: Rig, res: AnimateResult, bake: bool, log) -> Path:
    from ..files import check_output_path
    from ..io import holds_head, write_animation

    path = check_output_path(Path(out))
    pose = res.head if holds_head(path) else None
    if res.head is not None and pose is None:
        log(f"{path.suffix} does not hold head motion: the head is left out")
    if path.suffix.lower() == CSV:
        from ._clone_retarget import _is_arkit

        if not all(_is_arkit(n) for n in res.names):
            from ..errors import OutputError

            raise OutputError(f"{path}: a Live Link Face CSV holds ARKit curves; {rig.name}'s shapes are not "
                              "all ARKit-named (write .glb, .usd, .blend or .fbx)")
    write_animation(path, rig=rig, weights=res.weights, names=res.names, times=res.times, head=pose,
                    audio=res.audio, audio_rate=res.audio_rate, bake=bake)
    log(f"wrote {path} ({len(res.times)} frames, {len(res.names)} shapes"
        + (", head" if pose is not None else "") + ")")
    if path.suffix.lower() == GLB:
        from ._clone_retarget import blender_timeline_note

        note = blender_timeline_note(path, res.times)
        if note:
            log(note)
    return path


def _preview(out, video, rig: Rig, res: AnimateResult, size: int, backend: str, progress: bool, log,
             **look) -> Path:
    from ._preview import write_animation_preview

    info = write_animation_preview(out, video, rig, res.weights, res.times, res.head, size=size, backend=backend,
                                   progress=progress, log=log, **look)
    log(f"wrote {out} (preview, {info.get('frames')} frames, {info.get('fps', 0):.1f} frames/s, {info.get('backend')})")
    return Path(out)
