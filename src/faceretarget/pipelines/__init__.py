"""The jobs a user runs, as library functions (the command line is a thin shell over these).

Four parts, by what each is: the offline jobs, a take or a video in and files out, in this package's own
modules; :mod:`.live`, a camera or video solved frame by frame into a web page; :mod:`.batch`, a jobs file
of takes x characters on Dask; and :mod:`.worker`, the process the Blender extension runs its long jobs in.
The three subpackages import the offline jobs they run from here (never the other way round), and every
public name of theirs is exported here too.

================================ ================================================================
:mod:`._animate`                 :func:`animate`: a video onto a character in one call (Ch. 5): capture,
                                 emotion, solve, head, write, preview
:mod:`._clone_retarget`          :func:`clone_take`, :func:`retarget_take`, :func:`write_result`:
                                 a take onto a character, memory bounded by its weights; the head
                                 written with it (:func:`result_head`), ARKit curves for a Live
                                 Link Face CSV (:func:`arkit_curves`)
:mod:`._apply`                   :func:`apply_take`: a take file onto a character's own shapes by the clone,
                                 retarget or landmark route (the Blender extension's *Apply a take*)
:mod:`._keys`                    :func:`select_keys` (keyshapes for an artist), :func:`compose_keys`
                                 (emotion x viseme key-models)
:mod:`._capture`                 :func:`capture_take`, :func:`fit_appearance`, :func:`encode_appearance`
:mod:`._style`                   :func:`fit_style`, :func:`fit_speaker_style`, :func:`read_style_take`:
                                 emotion models from takes (one actor, or several speakers)
:mod:`._restyle_video`           :class:`AppearanceStyleModel`, :func:`fit_appearance_style`,
                                 :func:`restyle_video`: the emotion of a face in video changed through
                                 the appearance model and rendered back into the frames (Fig. 2.6)
:mod:`._head`                    :func:`build_head_database`: a head-motion database from file pairs
:mod:`._preview`                 :func:`write_animation_preview`: the video beside the animated
                                 character, with its audio (OpenGL through EGL, or NumPy)
:mod:`._sheet`                   :func:`shape_sheet`: a contact sheet of a character's shapes
:mod:`._demo`                    :func:`run_demo`: the main job end to end on embedded characters
:mod:`._progress`                the progress indicators of long steps (shared by the jobs and batch)
:mod:`.live`                     :func:`run_live`, :class:`LiveSession`: a camera or video frame by
                                 frame onto a character in a local three.js page (``live``);
                                 :class:`LiveServer`: the page's HTTP server and WebSocket (stdlib)
:mod:`.batch`                    :func:`run_batch`: a jobs file (:func:`read_jobs`) of takes x characters on
                                 Dask, each model fitted once, resumable from its manifest (``batch``)
:mod:`.worker`                   :func:`serve_jobs`: the worker process a host UI (the Blender extension)
                                 runs the long jobs in, JSON lines in and out; :func:`cached_capture`
================================ ================================================================
"""

from ..errors import moved_names
from ._animate import (
    GAZE_DEG,
    HEAD_SOURCES,
    VIDEO_EXTENSIONS,
    AnimateOptions,
    AnimateResult,
    animate,
    drives_by_landmarks,
    face_frame,
    face_take,
    face_takes,
    frame_solver,
    gaze_rotations,
    parse_emotion,
    tracked_take,
    video_solver,
)
from ._apply import TAKE_ROUTES, AppliedTake, apply_take, landmark_points
from ._capture import (
    APPEARANCE_BYTES,
    appearance_memory,
    capture_take,
    encode_appearance,
    fit_appearance,
    tracked_videos,
)
from ._clone_retarget import (
    CHUNK_FRAMES,
    HEAD_CHOICES,
    MAX_TEMPORAL,
    Transfer,
    arkit_curves,
    blender_timeline_note,
    check_result_path,
    clone_take,
    face_and_head_formats,
    keep_arkit_range,
    result_head,
    retarget_take,
    source_geometry,
    target_weights,
    write_result,
)
from ._demo import run_demo
from ._head import build_head_database
from ._keys import (
    SELECTION_ALIASES,
    KeyGeometry,
    KeySelection,
    check_face_keys,
    check_face_take,
    compose_keys,
    key_geometry,
    select_keys,
)
from ._preview import TakeSampler, write_animation_preview
from ._restyle_video import (
    AppearanceStyleModel,
    RestyledVideo,
    align_vector_takes,
    composited_frames,
    fit_appearance_style,
    restyle_video,
    speaker_edited_landmarks,
    write_face_video,
)
from ._sheet import shape_sheet
from ._style import fit_speaker_style, fit_style, read_style_take
from .batch import (
    CONNECT_TIMEOUT,
    JOB_OPTIONS,
    OPERATIONS,
    BatchSpec,
    BatchSummary,
    ClusterError,
    Job,
    JobOutcome,
    local_cluster,
    read_jobs,
    read_manifest,
    run_batch,
)
from .live import LIVE_LIMITS, LiveFrame, LiveServer, LiveSession, LiveStats, character_glb, run_live
from .worker import JOB_KINDS, WorkerChannel, cached_capture, capture_cache_path, serve_jobs

__all__ = [
    "gaze_rotations",
    "GAZE_DEG",
    "shape_sheet",
    "animate", "AnimateOptions", "AnimateResult", "video_solver", "frame_solver", "tracked_take", "face_take", "face_frame", "face_takes", "VIDEO_EXTENSIONS", "parse_emotion", "HEAD_SOURCES", "drives_by_landmarks",
    "clone_take", "retarget_take", "write_result", "source_geometry", "Transfer", "CHUNK_FRAMES",
    "result_head", "arkit_curves", "face_and_head_formats", "HEAD_CHOICES", "check_result_path", "MAX_TEMPORAL",
    "target_weights", "keep_arkit_range", "blender_timeline_note",
    "select_keys", "compose_keys", "key_geometry", "KeySelection", "KeyGeometry", "SELECTION_ALIASES",
    "check_face_take", "check_face_keys",
    "write_animation_preview", "TakeSampler",
    "run_live", "LiveSession", "LiveStats", "LiveFrame", "LiveServer", "character_glb", "LIVE_LIMITS",
    "capture_take", "tracked_videos", "fit_appearance", "encode_appearance", "appearance_memory", "APPEARANCE_BYTES", "fit_style", "fit_speaker_style", "read_style_take", "build_head_database", "run_demo",
    "AppearanceStyleModel", "RestyledVideo", "fit_appearance_style", "restyle_video", "write_face_video",
    "composited_frames", "align_vector_takes", "speaker_edited_landmarks",
    "apply_take", "AppliedTake", "TAKE_ROUTES", "landmark_points",
    "serve_jobs", "JOB_KINDS", "WorkerChannel", "cached_capture", "capture_cache_path",
    "run_batch", "CONNECT_TIMEOUT", "read_jobs", "read_manifest", "local_cluster", "BatchSpec", "BatchSummary", "Job", "JobOutcome", "ClusterError",
    "OPERATIONS", "JOB_OPTIONS",
]

#: Names that moved to :mod:`faceretarget.characters` (issue 33); they still work here for one release.
_MOVED = ("CharacterReport", "DriveRig", "apply_landmark_record", "character_weights", "drive_rig",
          "inspect_character", "landmark_cache_path", "landmark_record", "load_character", "look_rig", "mesh_sha256",
          "read_landmark_file")


__getattr__ = moved_names(__name__, _MOVED, "faceretarget.characters")
