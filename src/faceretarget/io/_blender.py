"""Blender output: a ``.blend`` scene built with Blender's own Python module (``bpy``), and ``.fbx``
exported from that scene with Blender's FBX exporter (``make blender``, or ``pip install requests zstandard &&
pip install --no-deps 'bpy>=4.5,<4.6'``; docs/blender.md), and :func:`import_bpy`, ``import bpy`` without the
noise bpy 4.5 prints beside NumPy 2.

What :func:`write_blend` builds (a fresh scene: factory settings, empty)
------------------------------------------------------------------------
* Object ``face``: the rig's neutral as a Blender mesh in metres, polygons kept as they are
  (quads and n-gons from ``face_counts`` / ``face_indices``), the rig's vertex order unchanged,
  UVs (when the rig has them) in a ``UVMap`` layer, smooth shading.  Axes: our frame is glTF's
  (+Y up, +Z forward), Blender's is +Z up, converted exactly as Blender's glTF importer does,
  ``(x, y, z) -> (x, -z, y)``, so a ``.glb`` and a ``.blend`` of one take evaluate to the same
  vertices in Blender.
* Shape keys: ``Basis`` plus one key per rig shape named as in the rig, holding absolute positions
  (neutral + delta).  Each key's ``slider_min`` / ``slider_max`` cover that key's weights (at least
  [0, 1], widened outwards to a multiple of 0.01): Blender clamps an animated value to its slider,
  so a weight outside the slider would play clamped.  Blender's sliders stop at +-10; a weight
  beyond that is an :class:`~faceretarget.errors.InvalidDataError`.
* One action ``take``: every key's ``value`` keyed at every frame, ``LINEAR`` interpolation, at
  scene frame ``1 + (t - t0) * fps`` exactly (fractional for uneven times).  The scene's frame rate
  is the take's (:func:`blender_timebase`: an integer ``fps`` and ``fps_base``, 30 / 1.001 for
  29.97), ``frame_start`` 1, ``frame_end`` the last key's frame rounded up.
* With ``head``: an armature object ``head_rig`` with one bone ``head`` whose head (its pivot) is at
  ``head_pivot`` and whose tail points up; the face is skinned to it (vertex group ``head`` with
  weight 1 on every vertex and an Armature modifier; the object is a child of the armature), so the
  whole face turns about the pivot.  The bone's ``rotation_quaternion`` and (when the pose has a
  translation, metres) ``location`` are keyed at every frame in the same action (its own slot).
  The bone's rest frame is our frame (x left, y up, z forward), so the keyed quaternion is the
  :class:`~faceretarget.headpose.HeadPose` quaternion itself.  A frame without a pose holds the
  previous one (identity before the first).
* With ``audio``: the samples as a 16-bit WAV, a sound strip in the sequencer at frame 1 (the audio
  starts at ``times[0]``), packed into the ``.blend`` (self-contained), playback synced to audio.

:func:`write_fbx` builds the same scene and exports it with Blender's FBX exporter (the animation
baked at every scene frame, no curve simplification; shape keys as blend shapes, the head as a
skinned bone).  Every call starts from Blender's factory settings and leaves them behind, so any
``bpy`` state of the process is replaced.  The file is saved to a temporary name beside ``path`` and
moved into place when complete.
"""

from __future__ import annotations

import contextlib
import importlib.util
import math
import os
import re
import shutil
import sys
import tempfile
import warnings
from pathlib import Path

import numpy as np

from ..errors import DataWarning, FaceRetargetWarning, InvalidDataError, OutputError
from ..files import atomic_path, check_output_path
from ..formats import BLEND, FBX
from ..headpose import HeadPose
from ..optional import optional_import
from ..rig import Rig
from ..timebase import check_times, infer_fps
from ._audio import checked_audio, write_wav
from ._gltf import _checked_weights

__all__ = ["write_blend", "write_fbx", "blender_timebase", "import_bpy", "BLENDER_AXES", "SLIDER_LIMIT",
           "BLENDER_USER_ENV"]

#: Our axes (glTF's: +Y up, +Z forward) to Blender's (+Z up, -Y forward): ``v_blender = BLENDER_AXES @ v``,
#: the conversion of Blender's glTF importer.
BLENDER_AXES = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])
#: Blender's hard limit on a shape key's slider range.
SLIDER_LIMIT = 10.0

_PURPOSE = "writing Blender files (.blend, .fbx)"

#: What bpy 4.5 prints when it is first imported beside NumPy 2, although everything faceretarget uses works:
#: its audio binding (``aud``, compiled against NumPy 1.x) cannot load NumPy's C API, NumPy explains that
#: with a traceback, and Blender says it cannot start audio (docs/blender.md).  Only output made of these lines
#: is dropped; anything else bpy prints is passed on.
_BPY_NOISE = [re.compile(p) for p in (
    r"^\s*$",
    r"^A module that was compiled using NumPy 1\.x cannot be run in$",
    r"^NumPy [\w.]+ as it may crash\. To support both 1\.x and 2\.x$",
    r"^versions of NumPy, modules must be compiled with NumPy 2\.0\.$",
    r"^Some module may need to rebuild instead e\.g\. with 'pybind11>=2\.12'\.$",
    r"^If you are a user of the module, the easiest solution will be to$",
    r"^downgrade to 'numpy<2' or try to upgrade the affected module\.$",
    r"^We expect that some modules will need time to support NumPy 2\.$",
    r"^Traceback \(most recent call last\):",
    r"^  File \".*\", line \d+, in ",
    r"^    \S",
    r"^ImportError: (numpy\.core\.multiarray failed to import)?$",
    r"^AttributeError: _ARRAY_API not found$",
    r"^Unable to initialise audio$",
)]


def _only_bpy_noise(text: str) -> bool:
    """Whether ``text`` holds nothing but bpy 4.5's NumPy-1.x audio message (:data:`_BPY_NOISE`)."""
    if "compiled using NumPy 1.x" not in text and "Unable to initialise audio" not in text:
        return not text.strip()
    return all(any(p.match(line) for p in _BPY_NOISE) for line in text.splitlines())


#: Blender's environment variables naming the user's own folders (preferences, scripts, add-ons, extensions and
#: their wheels, data files), and the system-wide script and extension folders a studio may set.
BLENDER_USER_ENV = ("BLENDER_USER_RESOURCES", "BLENDER_USER_CONFIG", "BLENDER_USER_SCRIPTS",
                    "BLENDER_USER_EXTENSIONS", "BLENDER_USER_DATAFILES")
BLENDER_SYSTEM_ENV = ("BLENDER_SYSTEM_SCRIPTS", "BLENDER_SYSTEM_EXTENSIONS")


def _isolated_blender_env() -> dict[str, str | None]:
    """Point Blender's user folders at a private, empty one in the cache folder and hide the system-wide
    script and extension folders; the variables' previous values."""
    from ..files import cache_dir

    root = cache_dir("blender-user")
    root.mkdir(parents=True, exist_ok=True)
    old = {k: os.environ.get(k) for k in BLENDER_USER_ENV + BLENDER_SYSTEM_ENV}
    for k in BLENDER_USER_ENV:
        os.environ[k] = str(root / k.rsplit("_", 1)[1].lower())
    for k in BLENDER_SYSTEM_ENV:
        os.environ.pop(k, None)
    return old


def _restore_env(values: dict[str, str | None]) -> None:
    for k, v in values.items():
        if v is None:
            os.environ.pop(k, None)
        else:
            os.environ[k] = v


def _foreign_paths(added: list[str]) -> list[str]:
    """The ``sys.path`` entries bpy added that are not its own: a user's or system's extension wheels
    (``extensions/.local/lib/pythonX.Y/site-packages``) or script folders outside the bpy package."""
    spec = importlib.util.find_spec("bpy")
    here = str(Path(spec.origin).parent) if spec is not None and spec.origin else None
    return [p for p in added if here is None or not os.path.abspath(p).startswith(here)]


def import_bpy(purpose: str = _PURPOSE):
    """Blender's Python module, imported as ``import bpy``, isolated from the user's Blender set-up and
    without the noise bpy 4.5 makes beside NumPy 2.

    Isolated: on its import bpy reads the user's Blender configuration (``~/.config/blender/4.5`` on Linux),
    and puts the wheels of every installed extension (``extensions/.local/lib/python3.11/site-packages``)
    *before* this environment's site-packages on ``sys.path``; a user who installed an extension (ours
    bundles Pillow, SciPy and OpenCV built for Blender's NumPy 1.26) would then import those instead of
    their own (``from PIL import ImageDraw`` failed).  So Blender's user folders
    (:data:`BLENDER_USER_ENV`) are pointed at a private, empty folder in the cache
    (:func:`faceretarget.files.cache_dir` ``/ "blender-user"``) before the import and stay so for the
    process (Blender reads them again when it resets to factory settings); the system-wide script and
    extension folders are hidden; any ``sys.path`` entry bpy still added outside its own package is
    removed, and the modules imported from there are forgotten.  Nothing faceretarget does with bpy
    uses the user's preferences or add-ons: every scene starts from factory settings.  Blender takes the
    user's script folder (whose ``addons`` it appends to ``sys.path`` at every factory reset) from
    ``$XDG_CONFIG_HOME`` once, at import: that variable names the private folder during the import only.

    Quiet: bpy 4.5 declares ``numpy<2`` because its audio binding (``aud``) is compiled against NumPy 1.x;
    installed beside NumPy 2 (``make blender``), its first import prints NumPy's "A module that was
    compiled using NumPy 1.x cannot be run in NumPy 2" traceback and "Unable to initialise audio",
    although scenes, shape keys, actions, importers, exporters and packed sound strips all work
    (``tests/test_blender.py``).  This function captures what the import prints on the process's
    standard output and error, drops it when it is exactly that message, and passes anything else
    on to standard error.

    Later calls return the module already imported (inside Blender, Blender's own).  ``purpose`` is what
    needs it, for the message when it is not installed.

    Raises
    ------
    MissingDependencyError
        bpy is not installed (the message says how to install it).
    """
    if "bpy" in sys.modules and sys.modules["bpy"] is not None:
        return sys.modules["bpy"]
    from ..optional import install_line

    before = list(sys.path)
    old_env = _isolated_blender_env()
    # Blender takes the user's script folder (whose addons/ it appends to sys.path at every factory reset)
    # from the XDG configuration folder once, at import, whatever BLENDER_USER_SCRIPTS says: the private
    # folder during the import only (the process's other libraries keep the user's)
    xdg = os.environ.get("XDG_CONFIG_HOME")
    os.environ["XDG_CONFIG_HOME"] = os.environ["BLENDER_USER_CONFIG"]
    try:
        with _captured_output() as cap:
            bpy = optional_import("bpy", purpose, install_line("bpy"))
    except BaseException:
        _restore_env(old_env)                     # no bpy: the environment as it was
        raise
    finally:
        _restore_env({"XDG_CONFIG_HOME": xdg})
    text = cap()
    if not _only_bpy_noise(text):
        sys.stderr.write(text)
    foreign = _foreign_paths([p for p in sys.path if p not in before])
    if foreign:
        sys.path[:] = [p for p in sys.path if p not in foreign]
        roots = tuple(os.path.abspath(p) + os.sep for p in foreign)
        for name, mod in list(sys.modules.items()):
            f = getattr(mod, "__file__", None)
            if f and os.path.abspath(f).startswith(roots):
                del sys.modules[name]
    return bpy


def blender_timebase(times: np.ndarray, start: float = 1.0) -> tuple[int, float, np.ndarray]:
    """Blender's frame rate for a take and the scene frame of each of its frames.

    Parameters
    ----------
    times : (T,) float
        Frame times in seconds, strictly increasing.
    start : float
        Scene frame of ``times[0]`` (1 in a ``.blend``; 0 for FBX, whose time 0 it is).

    Returns
    -------
    fps : int
        Blender's integer ``scene.render.fps``: the take's nominal rate (``infer_fps``; 30 for a
        single frame) rounded.
    fps_base : float
        ``scene.render.fps_base`` such that ``fps / fps_base`` is the take's rate (1.001 for 29.97;
        1.0 when the rate is within 1e-6 of an integer), as float32 like Blender stores it.
    frames : (T,) float
        Scene frame of each frame, ``start + (t - t0) * rate`` with the take's rate ``fps /
        fps_base`` (fractional for uneven times; integers for a regular take).

    >>> fps, base, frames = blender_timebase(np.arange(4) * 1001 / 30000)   # NTSC 29.97
    >>> fps, round(base, 6), frames.round(4).tolist()
    (30, 1.001, [1.0, 2.0, 3.0, 4.0])
    """
    t = np.asarray(times, dtype=np.float64).reshape(-1)
    rate = infer_fps(t, default=30.0)
    fps = max(1, int(round(rate)))
    base = float(np.float32(fps / rate))
    if abs(base - 1.0) < 1e-6:
        base, rate = 1.0, float(fps)
    # the take's own rate (not float32's fps_base): a regular take keys integer frames
    frames = start + (t - t[0]) * rate if t.size else t.copy()
    return fps, base, frames


# ------------------------------------------------------------------------------------------ checks
def _slider_ranges(path: Path, rig: Rig, w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per key ``(slider_min, slider_max)``: covering the key's weights and [0, 1], or an error."""
    over = np.abs(w) > SLIDER_LIMIT
    if over.any():
        f, k = (int(x[0]) for x in np.nonzero(over))
        raise InvalidDataError(
            f"{path}: frame {f} weight '{rig.names[k]}' is {w[f, k]:.6g}, beyond Blender's shape-key slider "
            f"limit of +-{SLIDER_LIMIT:g} (Blender would play it clamped); rescale the key or bound the solve")
    wmin, wmax = np.minimum(0.0, w.min(axis=0)), np.maximum(1.0, w.max(axis=0))
    # a round slider (0.01) that still covers the weights (float32 rounding is monotonic)
    lo = np.maximum(-SLIDER_LIMIT, np.minimum(np.floor(wmin * 100.0 + 1e-6) / 100.0, wmin))
    hi = np.minimum(SLIDER_LIMIT, np.maximum(np.ceil(wmax * 100.0 - 1e-6) / 100.0, wmax))
    return lo, hi


def _filled_head(path: Path, head: HeadPose, T: int) -> tuple[np.ndarray, np.ndarray | None]:
    """Quaternions (T, 4) x, y, z, w and translation (T, 3) or None, gaps held (identity / zero at start)."""
    if not isinstance(head, HeadPose):
        raise InvalidDataError(f"{path}: head must be a HeadPose, got {type(head).__name__}")
    if head.n_frames != T:
        raise InvalidDataError(f"{path}: the head pose has {head.n_frames} frames for {T} times")
    ok = head.valid
    if head.translation is not None:
        ok = ok & np.isfinite(head.translation).all(axis=1)
    # index of the last valid frame at or before each frame (-1: none yet)
    last = np.maximum.accumulate(np.where(ok, np.arange(T), -1))
    q = np.tile([0.0, 0.0, 0.0, 1.0], (T, 1))
    q[last >= 0] = head.quaternions[last[last >= 0]]
    tr = None
    if head.translation is not None:
        tr = np.zeros((T, 3))
        tr[last >= 0] = head.translation[last[last >= 0]]
    return q, tr


# ------------------------------------------------------------------------------------------ writers
def write_blend(path: str | os.PathLike, rig: Rig, weights: np.ndarray, times: np.ndarray,
                names: list[str] | None = None, *, head: HeadPose | None = None,
                audio: np.ndarray | None = None, audio_rate: float | None = None,
                head_pivot: tuple[float, float, float] | np.ndarray = (0.0, 0.0, 0.0)) -> Path:
    """Write a ``.blend`` holding the rig with shape keys animated by ``weights`` (module docstring).

    Parameters
    ----------
    path : path-like
        Output ``.blend``.
    rig : Rig
        Neutral mesh and key shapes (any unit; written in metres).
    weights : (T, K) float
        Weights per frame, in the rig's shape order or named by ``names``; within Blender's
        slider limit of +-10.
    times : (T,) float
        Frame times in seconds, strictly increasing; frame ``t`` is keyed at scene frame
        ``1 + (t - times[0]) * fps`` (:func:`blender_timebase`).
    names : list of str, optional
        Names of the columns of ``weights`` (:meth:`Rig.map_weights`).
    head : HeadPose, optional
        Head motion per frame (rotation, and translation in metres): an armature bone ``head``
        the face is skinned to.  Frames without a pose hold the previous one.
    audio : (n,) or (n, channels) float, optional
        Samples in [-1, 1] starting at ``times[0]``; packed into the file as a sound strip.
    audio_rate : float, optional
        Sampling rate of ``audio`` in Hz (an integer rate).
    head_pivot : 3 floats
        Rotation centre of the head (the bone's head) in the rig's frame, metres.

    Returns
    -------
    Path
        ``path``.

    Raises
    ------
    InvalidDataError
        Wrong weight shape, non-finite weights, a weight beyond +-10 (names the shape and frame),
        times that do not increase, a head pose of the wrong length, or bad audio.
    MissingDependencyError
        ``bpy`` is not installed (the message says how: ``make blender``).
    OutputError
        The file cannot be written (nothing partial is left).
    """
    return _write(path, BLEND, rig, weights, times, names, head, audio, audio_rate, head_pivot)


def write_fbx(path: str | os.PathLike, rig: Rig, weights: np.ndarray, times: np.ndarray,
              names: list[str] | None = None, *, head: HeadPose | None = None,
              audio: np.ndarray | None = None, audio_rate: float | None = None,
              head_pivot: tuple[float, float, float] | np.ndarray = (0.0, 0.0, 0.0)) -> Path:
    """Write an ``.fbx`` through Blender's FBX exporter from the scene :func:`write_blend` builds.

    Same parameters, returns and errors as :func:`write_blend`.  The exporter bakes the animation
    at every integer scene frame at the take's rate with no curve simplification (uneven times are
    resampled there, as the ``.blend`` plays them): shape-key values as blend-shape channels
    (``DeformPercent``), the head as a skinned bone.  The take starts at FBX time 0 (the scene is
    built from frame 0; Blender's FBX importer puts time 0 at frame 1).  Units: Blender's exporter
    writes centimetres (``UnitScaleFactor`` 1, coordinates x 100); Blender's importer (and other FBX
    readers) scale them back, so the face keeps its size in metres.  FBX has no packed audio:
    ``audio`` is checked and otherwise ignored.
    """
    return _write(path, FBX, rig, weights, times, names, head, audio, audio_rate, head_pivot)


def _write(path, kind: str, rig: Rig, weights, times, names, head, audio, audio_rate, head_pivot) -> Path:
    path = check_output_path(path)
    w, t = _checked_weights(path, rig, weights, times, names)
    t = check_times(t, source=str(path))
    lo, hi = _slider_ranges(path, rig, w)
    head_keys = None if head is None else _filled_head(path, head, t.size)
    sound = checked_audio(path, audio, audio_rate)
    pivot = np.asarray(head_pivot, dtype=np.float64).reshape(-1)
    if pivot.shape != (3,) or not np.isfinite(pivot).all():
        raise InvalidDataError(f"{path}: head_pivot must be 3 finite numbers (metres), got {head_pivot!r}")

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        with _blender_output():
            _write_scene(path, kind, rig, w, t, lo, hi, head_keys, pivot, sound)
    for m in caught:  # ours again, now that stderr is the caller's (Blender's own are dropped)
        if issubclass(m.category, FaceRetargetWarning):
            warnings.warn(m.message, m.category, stacklevel=3)
    return path


def _write_scene(path: Path, kind: str, rig: Rig, w, t, lo, hi, head_keys, pivot, sound) -> None:
    bpy = import_bpy()
    scratch = Path(tempfile.mkdtemp(prefix=f".{path.name}.", suffix=".part", dir=path.parent))
    try:
        bpy.ops.wm.read_factory_settings(use_empty=True)
        # FBX time = scene frame / fps and Blender's FBX importer puts FBX time 0 at frame 1: the
        # FBX scene starts at frame 0 so the take starts at time 0 (and at frame 1 when re-imported)
        _build_scene(bpy, path, rig, w, t, lo, hi, head_keys, pivot,
                     None if sound is None or kind != BLEND else (sound, scratch),
                     start=1.0 if kind == BLEND else 0.0)
        out = scratch / path.name
        if kind == BLEND:
            res = bpy.ops.wm.save_as_mainfile(filepath=str(out), check_existing=False, compress=True,
                                              relative_remap=False)
        else:
            res = bpy.ops.export_scene.fbx(
                filepath=str(out), check_existing=False, use_selection=False,
                object_types={"MESH", "ARMATURE"}, use_mesh_modifiers=False, global_scale=1.0,
                apply_unit_scale=True, apply_scale_options="FBX_SCALE_NONE", axis_forward="-Z", axis_up="Y",
                add_leaf_bones=False, primary_bone_axis="Y", secondary_bone_axis="X",
                bake_anim=True, bake_anim_use_all_bones=True, bake_anim_use_nla_strips=False,
                bake_anim_use_all_actions=False, bake_anim_force_startend_keying=True, bake_anim_step=1.0,
                bake_anim_simplify_factor=0.0, use_armature_deform_only=False, mesh_smooth_type="FACE",
                path_mode="AUTO")
        if "FINISHED" not in res or not out.is_file():
            raise OutputError(f"{path}: Blender did not write the file ({', '.join(sorted(res))})")
        with atomic_path(path) as tmp:
            os.replace(out, tmp)
    except RuntimeError as e:  # an operator's error report
        raise OutputError(f"{path}: Blender could not write the file ({e})") from e
    finally:
        shutil.rmtree(scratch, ignore_errors=True)
        with contextlib.suppress(Exception):  # cleanup must not hide the real error
            bpy.ops.wm.read_factory_settings(use_empty=True)  # release the scene; the next call starts clean


@contextlib.contextmanager
def _captured_output():
    """Inside the block, what the process prints on file descriptors 1 and 2 (C code included) goes to a
    temporary file; the context value is a function returning it as text (after the block)."""
    import ctypes

    try:
        libc = ctypes.CDLL(None)
    except (OSError, TypeError):  # no C library handle (Windows): Python's buffers only
        libc = None
    sys.stdout.flush()
    sys.stderr.flush()
    saved = [os.dup(1), os.dup(2)]
    text = [""]
    with tempfile.TemporaryFile(mode="w+b") as cap:
        os.dup2(cap.fileno(), 1)
        os.dup2(cap.fileno(), 2)
        try:
            yield lambda: text[0]
        finally:
            sys.stdout.flush()
            sys.stderr.flush()
            if libc is not None:
                libc.fflush(None)  # C stdio buffers, before the descriptors go back
            os.dup2(saved[0], 1)
            os.dup2(saved[1], 2)
            for fd in saved:
                os.close(fd)
            cap.seek(0)
            text[0] = cap.read().decode("utf-8", "replace")


@contextlib.contextmanager
def _blender_output():
    """Keep what Blender prints (on file descriptors 1 and 2) out of the caller's output.

    Blender's C code and its add-ons print progress ("Info: Saved as ...", "FBX export starting").
    All of it is captured; it is passed on to stderr only when the call fails.
    """
    cap = None
    ok = False
    try:
        with _captured_output() as cap:
            yield
        ok = True
    finally:
        if not ok and cap is not None:        # the exception goes on; what Blender printed explains it
            sys.stderr.write(cap())


# ------------------------------------------------------------------------------------------ the scene
def _build_scene(bpy, path: Path, rig: Rig, w: np.ndarray, t: np.ndarray, lo: np.ndarray, hi: np.ndarray,
                 head_keys, pivot: np.ndarray, sound, start: float = 1.0) -> None:
    scene = bpy.context.scene
    fps, base, frames = blender_timebase(t, start)
    scene.render.fps = fps
    scene.render.fps_base = base
    scene.frame_start = int(start)
    scene.frame_end = max(int(start), int(math.ceil(frames[-1] - 1e-6)))
    scene.frame_current = int(start)
    scene.unit_settings.system = "METRIC"
    scene.unit_settings.scale_length = 1.0

    obj = _face_object(bpy, path, rig)
    scene.collection.objects.link(obj)
    key, key_names = _shape_keys(obj, rig, lo, hi)

    action = bpy.data.actions.new("take")
    strip = action.layers.new("Layer").strips.new(type="KEYFRAME")
    linear = bpy.types.Keyframe.bl_rna.properties["interpolation"].enum_items["LINEAR"].value
    co = np.empty((t.size, 2), np.float32)
    co[:, 0] = frames

    slot = action.slots.new(id_type="KEY", name=obj.name)
    key.animation_data_create()
    key.animation_data.action = action
    key.animation_data.action_slot = slot
    bag = strip.channelbag(slot, ensure=True)
    for k, name in enumerate(key_names):
        co[:, 1] = w[:, k]
        _fcurve(bag, f'key_blocks["{bpy.utils.escape_identifier(name)}"].value', 0, co, linear)

    if head_keys is not None:
        _head_rig(bpy, scene, obj, action, strip, head_keys, pivot, frames, linear, rig)
    if sound is not None:
        _sound_strip(bpy, scene, path, *sound)


def _face_object(bpy, path: Path, rig: Rig):
    mesh = rig.neutral
    scale = rig.mm_per_unit / 1000.0
    me = bpy.data.meshes.new(rig.name or "face")
    V, F = mesh.n_vertices, mesh.n_faces
    me.vertices.add(V)
    me.vertices.foreach_set("co", (mesh.vertices * scale @ BLENDER_AXES.T).astype(np.float32).ravel())
    if F:
        me.loops.add(int(mesh.face_indices.size))
        me.loops.foreach_set("vertex_index", mesh.face_indices.astype(np.int32))
        me.polygons.add(F)
        me.polygons.foreach_set("loop_start", mesh.face_offsets.astype(np.int32))
        me.polygons.foreach_set("loop_total", mesh.face_counts.astype(np.int32))
        if mesh.uvs is not None and mesh.face_uv_indices is not None:
            uv = me.uv_layers.new(name="UVMap")
            uv.data.foreach_set("uv", mesh.uvs[mesh.face_uv_indices].astype(np.float32).ravel())
    me.update(calc_edges=True)
    if me.validate(verbose=False, clean_customdata=False):
        warnings.warn(f"{path}: Blender corrected invalid geometry of '{mesh.name}' (degenerate or duplicate "
                      "faces removed; vertices unchanged)", DataWarning, stacklevel=2)
    if len(me.vertices) != V:
        raise InvalidDataError(f"{path}: Blender changed the vertex count of '{mesh.name}' ({V} -> "
                               f"{len(me.vertices)})")
    if F:
        me.shade_smooth()
    return bpy.data.objects.new("face", me)


def _shape_keys(obj, rig: Rig, lo: np.ndarray, hi: np.ndarray):
    """Basis + one absolute key per shape; returns the Key and each shape's key name as Blender has
    it (Blender shortens names to 63 bytes and renames clashes, e.g. a shape called "Basis")."""
    scale = rig.mm_per_unit / 1000.0
    names = []
    base = rig.neutral.vertices * scale @ BLENDER_AXES.T
    obj.shape_key_add(name="Basis", from_mix=False)
    for k, name in enumerate(rig.names):
        kb = obj.shape_key_add(name=name, from_mix=False)
        kb.data.foreach_set("co", (base + rig.deltas[k] * scale @ BLENDER_AXES.T).astype(np.float32).ravel())
        kb.slider_min = float(lo[k])  # lo <= 0 < 1 <= hi: either order stays valid
        kb.slider_max = float(hi[k])
        kb.value = 0.0
        names.append(kb.name)
    key = obj.data.shape_keys
    key.name = "Key"
    key.use_relative = True
    return key, names


def _fcurve(bag, data_path: str, index: int, co: np.ndarray, linear: int, group=None):
    fc = bag.fcurves.new(data_path, index=index)
    if group is not None:
        fc.group = group
    fc.keyframe_points.add(len(co))
    fc.keyframe_points.foreach_set("co", co.ravel())
    fc.keyframe_points.foreach_set("interpolation", np.full(len(co), linear, np.int32))
    fc.update()
    return fc


def _head_rig(bpy, scene, obj, action, strip, head_keys, pivot: np.ndarray, frames: np.ndarray, linear: int,
              rig: Rig) -> None:
    q, tr = head_keys
    arm = bpy.data.armatures.new("head_rig")
    arm_obj = bpy.data.objects.new("head_rig", arm)
    scene.collection.objects.link(arm_obj)
    bpy.context.view_layer.objects.active = arm_obj
    bpy.ops.object.mode_set(mode="EDIT")
    eb = arm.edit_bones.new("head")
    p = BLENDER_AXES @ pivot
    height = float(np.ptp(rig.neutral.vertices[:, 1])) * rig.mm_per_unit / 1000.0 if rig.n_vertices else 0.0
    eb.head = p
    eb.tail = p + np.array([0.0, 0.0, max(0.5 * height, 0.01)])  # pointing up (our +Y)
    eb.roll = 0.0
    bpy.ops.object.mode_set(mode="OBJECT")
    B = np.array(arm.bones["head"].matrix_local.to_3x3())  # bone rest frame in Blender's axes
    M = B.T @ BLENDER_AXES  # our axes -> the bone's rest frame (identity: the bone's frame is ours)

    # skin the face to the bone (weight 1 everywhere), child of the armature
    vg = obj.vertex_groups.new(name="head")
    vg.add(range(rig.n_vertices), 1.0, "REPLACE")
    mod = obj.modifiers.new("Armature", "ARMATURE")
    mod.object = arm_obj
    obj.parent = arm_obj

    pb = arm_obj.pose.bones["head"]
    pb.rotation_mode = "QUATERNION"
    from scipy.spatial.transform import Rotation

    R = M @ Rotation.from_quat(q).as_matrix() @ M.T
    ql = Rotation.from_matrix(R).as_quat()  # x, y, z, w in the bone's frame
    ql = ql * np.where(ql[:, 3:] < 0, -1.0, 1.0)
    flip = np.cumprod(np.where(np.r_[1.0, np.sign((ql[1:] * ql[:-1]).sum(axis=1))] < 0, -1.0, 1.0))
    ql = ql * flip[:, None]
    wxyz = ql[:, [3, 0, 1, 2]]

    slot = action.slots.new(id_type="OBJECT", name=arm_obj.name)
    arm_obj.animation_data_create()
    arm_obj.animation_data.action = action
    arm_obj.animation_data.action_slot = slot
    bag = strip.channelbag(slot, ensure=True)
    group = bag.groups.new("head")
    co = np.empty((len(frames), 2), np.float32)
    co[:, 0] = frames
    for i in range(4):
        co[:, 1] = wxyz[:, i]
        _fcurve(bag, 'pose.bones["head"].rotation_quaternion', i, co, linear, group)
    if tr is not None:
        loc = tr @ M.T
        for i in range(3):
            co[:, 1] = loc[:, i]
            _fcurve(bag, 'pose.bones["head"].location', i, co, linear, group)


def _sound_strip(bpy, scene, path: Path, audio_and_rate, scratch: Path | None, name: str = "audio",
                 wav: str | os.PathLike | None = None) -> None:
    wav = write_wav(scratch / f"{path.stem}.wav", *audio_and_rate) if wav is None else Path(wav)
    editor = scene.sequence_editor_create()
    strips = editor.strips if hasattr(editor, "strips") else editor.sequences
    strip = strips.new_sound(name, str(wav), 1, 1)
    strip.sound.pack()
    strip.sound.name = f"{path.stem}.wav"
    strip.sound.filepath = f"//{path.stem}.wav"  # where Blender's "unpack" would put it
    scene.sync_mode = "AUDIO_SYNC"
