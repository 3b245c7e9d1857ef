"""One extension registry for every take reader and animation writer.

:func:`read_performance` and :func:`write_animation` look the path's extension up in
:data:`READERS` / :data:`WRITERS` (``"folder"`` for a folder or a path without extension), as
trimesh's exchange modules do; a new format is one function and one :func:`register_reader` /
:func:`register_writer` call (``docs/architecture.md``, "How to add a file format").

==================== ========================================== ==========================================
path                 :func:`read_performance`                   :func:`write_animation`
==================== ========================================== ==========================================
``*.csv``            Live Link Face weights (+ head)            Live Link Face weights and/or head angles
``*.c3d``            optical markers                            --
``*.npz``            vertices, weights + names, or SMPL-X       vertices (from rig + weights, chunk by
                     ``poses`` (head motion)                    chunk)
``*.glb``            weight animation (morph targets)           rig + weight animation (+ ``head``
                                                                node), or a ``head`` node alone
``*.bvh``            head motion (Neck > Neck1 > Head)          head motion (one ``Head`` joint)
``*.obj``            one frame                                  --
``*.usd[a|c]``       --                                         rig + weight animation (UsdSkel blend
                                                                shapes, or ``bake`` points) (+ ``Head``)
``*.blend``          --                                         rig + shape-key action (+ ``head`` bone,
                                                                packed audio), written by Blender (bpy)
``*.fbx``            --                                         the same scene through Blender's FBX
                                                                exporter (blend shapes + ``head`` bone)
folder / no suffix   OBJ sequence                               OBJ sequence (``frame_00000.obj``...)
==================== ========================================== ==========================================
"""

from __future__ import annotations

import os
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import InputFileError, InvalidDataError, OutputError
from ..files import check_output_path
from ..formats import BLEND, BVH, C3D, CSV, FBX, GLB, NPZ, OBJ, USD, USDA, USDC
from ..headpose import HeadPose
from ..mesh import Mesh
from ..performance import Performance
from ..rig import Rig, RigFrames

__all__ = ["read_performance", "write_animation", "write_head_motion", "register_reader", "register_writer",
           "READERS", "WRITERS", "READ_FORMATS", "WRITE_FORMATS", "HEAD_FORMATS", "Animation", "holds_head"]

#: Formats that hold head motion on its own (:func:`write_head_motion`).
HEAD_FORMATS = (BVH, GLB, CSV)


@dataclass(frozen=True)
class Format:
    """A registered reader or writer: the function, what it reads or writes (for messages), and for a
    writer whether it writes :attr:`Animation.head` (:func:`holds_head`)."""

    function: Callable
    what: str
    head: bool = False


READERS: dict[str, Format] = {}
WRITERS: dict[str, Format] = {}


def register_reader(ext: str, function: Callable[..., Performance], what: str) -> None:
    """Make :func:`read_performance` read ``ext`` (``".abc"``, or ``"folder"``) with
    ``function(path, fps=None) -> Performance``."""
    READERS[ext.lower()] = Format(function, what)


def register_writer(ext: str, function: Callable[[Path, Animation], Path], what: str, *,
                    head: bool = False) -> None:
    """Make :func:`write_animation` write ``ext`` with ``function(path, animation) -> path``.

    ``head=True`` declares that the writer puts :attr:`Animation.head` into the file beside the face
    (``clone/retarget --head`` then hands it the head motion; :func:`holds_head`).
    """
    WRITERS[ext.lower()] = Format(function, what, head)


def holds_head(path: str | os.PathLike) -> bool:
    """Whether the writer :func:`write_animation` chooses for ``path`` writes head motion with the face.

    Raises
    ------
    OutputError
        An extension no writer is registered for.
    """
    path = Path(path)
    fmt = WRITERS.get(_ext(path))
    if fmt is None:
        raise OutputError(f"{path}: unknown output format '{_ext(path)}'; use {_listing(WRITERS)}")
    return fmt.head


def _ext(path: Path) -> str:
    return "folder" if path.is_dir() or path.suffix == "" else path.suffix.lower()


def _listing(table: dict[str, Format]) -> str:
    return ", ".join(f"{k} ({f.what})" for k, f in table.items())


def read_performance(path: str | os.PathLike, fps: float | None = None) -> Performance:
    """Read a take, choosing the reader from the path's extension (:data:`READERS`).

    Parameters
    ----------
    path : path-like
        A file or a folder of OBJ frames (module docstring).
    fps : float, optional
        Frame rate for formats without times (OBJ sequences without ``times.txt``, ``.npz``
        without ``times``, a single ``.obj``).

    Raises
    ------
    InputFileError
        Missing path or an unsupported extension (named), or any reader's error.
    """
    path = Path(path)
    if not path.exists():
        raise InputFileError(f"{path}: not found")
    ext = _ext(path)
    fmt = READERS.get(ext)
    if fmt is None:
        raise InputFileError(f"{path}: unknown take format '{ext}'; supported: {_listing(READERS)}")
    return _plausible(fmt.function(path, fps=fps))


#: Largest blendshape weight a take may hold (ARKit curves are in [0, 1]; exaggerated rigs and
#: example-based key weights stay within a few units).  A larger value is a corrupt or mis-scaled
#: file, not a performance: it would drive vertices kilometres away.
MAX_TAKE_WEIGHT = 10.0


def _plausible(perf: Performance) -> Performance:
    """The take, unless its weights leave [-MAX_TAKE_WEIGHT, MAX_TAKE_WEIGHT] (an error naming the
    frame, its time and the curve)."""
    if perf.weights is not None and perf.weights.size:
        bad = np.abs(perf.weights) > MAX_TAKE_WEIGHT
        if bad.any():
            f, k = (int(x[0]) for x in np.nonzero(bad))
            raise InvalidDataError(
                f"{perf.source}: frame {f} (t={perf.times[f]:.3f} s) weight '{perf.names[k]}' is "
                f"{perf.weights[f, k]:g}, outside the plausible range +-{MAX_TAKE_WEIGHT:g} of blendshape weights "
                f"({int(bad.sum())} value(s) in {int(bad.any(axis=1).sum())} frame(s))")
    return perf


@dataclass(eq=False)
class Animation:
    """What :func:`write_animation` hands a writer (any of it may be missing; the writer says what
    it needs)."""

    times: np.ndarray
    rig: Rig | None = None
    weights: np.ndarray | None = None
    names: list[str] | None = None
    vertices: np.ndarray | None = None
    mesh: Mesh | None = None
    head: HeadPose | None = None
    timecode: float | None = None
    timecode_rate: float | None = None
    curves: np.ndarray | None = None
    curve_names: list[str] | None = None
    bake: bool = False
    audio: np.ndarray | None = None
    audio_rate: float | None = None


def write_animation(path: str | os.PathLike, *, rig: Rig | None = None,
                    weights: np.ndarray | None = None, names: list[str] | None = None,
                    vertices: np.ndarray | None = None, mesh: Mesh | None = None,
                    times: np.ndarray, head: HeadPose | None = None, timecode: float | None = None,
                    timecode_rate: float | None = None, curves: np.ndarray | None = None,
                    curve_names: list[str] | None = None, bake: bool = False,
                    audio: np.ndarray | None = None, audio_rate: float | None = None) -> Path:
    """Write an animation in the format the output path asks for (:data:`WRITERS`).

    Parameters
    ----------
    path : path-like
        ``.glb`` (``rig`` and ``weights``, and/or ``head``), ``.npz`` (``vertices``, or ``rig`` +
        ``weights`` evaluated chunk by chunk), ``.csv`` (``weights`` and/or ``head``; Live Link
        Face layout), ``.bvh`` (``head``), ``.usd`` / ``.usda`` / ``.usdc`` (``rig`` + ``weights``,
        and ``head``; ``docs/usd.md``), or a path without extension / an existing folder (OBJ
        sequence; ``vertices`` + ``mesh``, or ``rig`` + ``weights``).
    rig : Rig, optional
    weights : (T, K) float, optional
        In the rig's shape order, or named by ``names``.
    names : list of str, optional
        Column names of ``weights`` (any spelling); default the rig's names.
    vertices : (T, V, 3) float, optional
    mesh : Mesh, optional
        Topology for ``vertices`` (default the rig's neutral).
    times : (T,) float
        Frame times in seconds, strictly increasing.
    head : HeadPose, optional
        Head motion (:mod:`faceretarget.headpose`); written by the formats registered with
        ``head=True`` (:func:`holds_head`), ignored by the others.
    timecode, timecode_rate : float, optional
        The take's clock (:class:`~faceretarget.performance.Performance`: seconds since midnight at
        ``times == 0``, timecode frames per second); the Live Link Face CSV writes it.
    curves : (T, C) float, optional
        Extra per-frame curves named by ``curve_names`` (Live Link Face eye angles).
    curve_names : list of str, optional
    bake : bool
        USD only: write the evaluated vertices as time-sampled points instead of blend shapes
        (other writers ignore it).
    audio : (n,) or (n, channels) float, optional
        The take's sound, starting at ``times[0]`` (``.blend`` packs it; other writers ignore it).
    audio_rate : float, optional
        Sampling rate of ``audio`` in Hz.

    Raises
    ------
    OutputError
        Unknown extension, missing data the format needs, or a path that cannot be written (missing
        or read-only folder); nothing partial is left.
    """
    path = Path(path)
    ext = _ext(path)
    fmt = WRITERS.get(ext)
    if fmt is None:
        raise OutputError(f"{path}: unknown output format '{ext}'; use {_listing(WRITERS)}")
    check_output_path(path)  # fail before any work when the folder is missing or read-only
    anim = Animation(np.asarray(times, dtype=np.float64).reshape(-1), rig, weights, names, vertices, mesh, head,
                     timecode, timecode_rate, curves, None if curve_names is None else list(curve_names),
                     bake=bool(bake), audio=audio, audio_rate=audio_rate)
    _check_sane(path, anim)
    return fmt.function(path, anim)


def _first_bad(a: np.ndarray) -> tuple[int, ...]:
    return tuple(int(x[0]) for x in np.nonzero(~np.isfinite(a)))


def _check_sane(path: Path, a: Animation) -> None:
    """No writer gets non-finite numbers or a rig it cannot draw (errors naming frame and channel)."""
    if a.times.size == 0 or not np.isfinite(a.times).all():
        raise InvalidDataError(f"{path}: times must be finite and at least one, got {a.times.size} "
                               f"with {int((~np.isfinite(a.times)).sum())} non-finite")
    checks = [("weights", a.weights), ("vertices", a.vertices), ("curves", a.curves), ("audio", a.audio)]
    for what, arr in checks:
        if arr is None:
            continue
        arr = np.asarray(arr, dtype=np.float64)
        if not np.isfinite(arr).all():
            at = _first_bad(arr)
            col = ""
            if what == "weights" and arr.ndim == 2:
                names = a.names or (a.rig.names if a.rig is not None else None)
                col = f" ('{names[at[1]]}')" if names is not None and at[1] < len(names) else ""
            raise InvalidDataError(f"{path}: {what} hold a non-finite value at frame {at[0]}{col}: "
                                   f"{arr[at]}; nothing written")
    if a.rig is not None:                       # (a Rig's own values are checked finite when it is made)
        if a.rig.neutral.n_vertices == 0:
            raise InvalidDataError(f"{path}: the rig {a.rig.name} has no vertices; nothing written")


# ------------------------------------------------------------------------------------ the formats
def _weights_for(rig: Rig, weights, names, what: str) -> np.ndarray:
    w = np.asarray(weights, dtype=np.float64)
    if w.ndim == 1:
        w = w[None]
    if names is not None:
        return rig.map_weights(list(names), w, source=what)
    if w.shape[-1] != rig.n_shapes:
        raise InvalidDataError(f"{what}: weights have {w.shape[-1]} columns but rig '{rig.name}' has "
                               f"{rig.n_shapes} shapes; pass names=")
    return w


def _frames(path: Path, a: Animation) -> tuple[np.ndarray | RigFrames, Mesh | None]:
    """Vertex frames: given, or the rig driven by the weights (evaluated a chunk at a time)."""
    if a.vertices is not None:
        return np.asarray(a.vertices, dtype=np.float64), a.mesh if a.mesh is not None else (
            a.rig.neutral if a.rig is not None else None)
    if a.rig is None or a.weights is None:
        raise OutputError(f"{path}: writing {path.suffix or 'an OBJ sequence'} needs vertices, or a rig and weights")
    return RigFrames(a.rig, _weights_for(a.rig, a.weights, a.names, str(path))), a.mesh or a.rig.neutral


def _write_glb(path: Path, a: Animation) -> Path:
    from ._gltf import write_glb, write_glb_head

    if a.rig is None and a.weights is None and a.head is not None:
        return write_glb_head(path, a.times, a.head)
    if a.rig is None or a.weights is None:
        raise OutputError(f"{path}: a .glb needs a rig and weights (morph targets + animation), or a head pose")
    return write_glb(path, a.rig, a.weights, a.times, names=a.names, head=a.head)


def _write_usd(path: Path, a: Animation) -> Path:
    from ._usd import write_usd

    if a.rig is None or a.weights is None:
        raise OutputError(f"{path}: a USD file needs a rig and weights (blend shapes + animation)")
    return write_usd(path, a.rig, a.weights, a.times, names=a.names, head=a.head, bake=a.bake, audio=a.audio,
                     audio_rate=a.audio_rate)


def _write_blend(path: Path, a: Animation) -> Path:
    from ._blender import write_blend

    if a.rig is None or a.weights is None:
        raise OutputError(f"{path}: a .blend needs a rig and weights (shape keys + action)")
    return write_blend(path, a.rig, a.weights, a.times, names=a.names, head=a.head, audio=a.audio,
                       audio_rate=a.audio_rate)


def _write_fbx(path: Path, a: Animation) -> Path:
    from ._blender import write_fbx

    if a.rig is None or a.weights is None:
        raise OutputError(f"{path}: an .fbx needs a rig and weights (blend shapes + animation)")
    return write_fbx(path, a.rig, a.weights, a.times, names=a.names, head=a.head)


def _write_csv(path: Path, a: Animation) -> Path:
    from ._livelinkface import write_livelinkface

    if a.weights is None and a.head is None:
        raise OutputError(f"{path}: a Live Link Face .csv needs weights or a head pose")
    extra = dict(timecode=a.timecode, timecode_rate=a.timecode_rate, curves=a.curves,
                 curve_names=list(a.curve_names or []), source=str(path))
    if a.weights is None:
        return write_livelinkface(path, Performance(a.times, _fps(a.times), head=a.head, **extra))
    cols = list(a.names) if a.names is not None else (a.rig.names if a.rig is not None else None)
    if cols is None:
        raise OutputError(f"{path}: pass names (or a rig) to name the weight columns")
    perf = Performance.from_weights(a.weights, cols, times=a.times, head=a.head, **extra)
    return write_livelinkface(path, perf)


def _write_bvh(path: Path, a: Animation) -> Path:
    from ._bvh import make_head_bvh, write_bvh

    if a.head is None:
        raise OutputError(f"{path}: a .bvh holds head motion; this animation has none")
    return write_bvh(path, make_head_bvh(a.head, _fps(a.times)))


def _write_npz(path: Path, a: Animation) -> Path:
    from ._npz import write_npz

    v, m = _frames(path, a)
    unit = {"unit": a.rig.unit} if a.rig is not None else {}
    return write_npz(path, v, a.times, m, **unit)


def _write_folder(path: Path, a: Animation) -> Path:
    from ._obj import write_obj_sequence

    v, m = _frames(path, a)
    if m is None:
        raise OutputError(f"{path}: an OBJ sequence needs a mesh (or a rig) for its faces")
    return write_obj_sequence(path, m, v, a.times)


def _fps(times: np.ndarray) -> float:
    from ..timebase import infer_fps

    return infer_fps(times, default=30.0)


def _read_csv(path: Path, fps=None) -> Performance:
    from ._livelinkface import read_livelinkface

    return read_livelinkface(path)


def _read_c3d(path: Path, fps=None) -> Performance:
    from ._c3d import read_c3d

    return read_c3d(path)


def _read_npz(path: Path, fps=None) -> Performance:
    from ._npz import read_npz_performance

    return read_npz_performance(path, fps=fps)


def _read_glb(path: Path, fps=None) -> Performance:
    from ._gltf import read_glb_weights

    names, times, weights = read_glb_weights(path)
    return Performance.from_weights(weights, names, times=times, source=str(path))


def _read_bvh(path: Path, fps=None) -> Performance:
    from ._head import read_bvh_head

    return read_bvh_head(path)


def _read_obj(path: Path, fps=None) -> Performance:
    from ._obj import read_obj

    mesh = read_obj(path)
    return Performance.from_vertices(mesh.vertices[None], mesh, times=[0.0], fps=fps or 30.0, source=str(path))


def _read_folder(path: Path, fps=None) -> Performance:
    from ._obj import read_obj_sequence

    return read_obj_sequence(path, fps=fps)


for _ext_, _fn, _what in ((CSV, _read_csv, "Live Link Face"), (C3D, _read_c3d, "markers"),
                          (NPZ, _read_npz, "vertices, weights or SMPL-X poses"),
                          (GLB, _read_glb, "morph-target weights"), (BVH, _read_bvh, "head motion"),
                          (OBJ, _read_obj, "one mesh"), ("folder", _read_folder, "OBJ frames")):
    register_reader(_ext_, _fn, _what)
for _ext_, _fn, _what, _head in ((GLB, _write_glb, "glTF morph targets + head node", True),
                                 (NPZ, _write_npz, "vertices", False),
                                 (CSV, _write_csv, "Live Link Face", True),
                                 (BVH, _write_bvh, "head motion", True),
                                 ("folder", _write_folder, "OBJ frames", False)):
    register_writer(_ext_, _fn, _what, head=_head)

for _ext_ in (USD, USDA, USDC):
    register_writer(_ext_, _write_usd, "USD blend shapes or baked points + head xform", head=True)
register_writer(BLEND, _write_blend, "Blender scene: shape keys + head bone + audio", head=True)
register_writer(FBX, _write_fbx, "FBX blend shapes + head bone (Blender's exporter)", head=True)

#: Extensions :func:`read_performance` / :func:`write_animation` know (``"folder"`` for OBJ frames).
READ_FORMATS = tuple(READERS)
WRITE_FORMATS = tuple(WRITERS)


def write_head_motion(path: str | os.PathLike, perf: Performance, protect: tuple = ()) -> Path:
    """Write ``perf.head`` (and, to a ``.csv``, its weights) by file extension (module docstring).

    Parameters
    ----------
    path : path-like
        ``.bvh``, ``.glb`` or ``.csv``.
    perf : Performance
        A take with a head pose.
    protect : tuple of path-like
        Inputs the output must not overwrite.
    """
    path = Path(path)
    ext = path.suffix.lower()
    if ext not in HEAD_FORMATS:
        raise OutputError(f"{path}: unknown head-motion output format '{ext}' (use {', '.join(HEAD_FORMATS)})")
    for p in protect:
        if p is not None and Path(p).exists() and path.exists() and os.path.samefile(p, path):
            raise OutputError(f"{path}: refusing to overwrite an input file")
    if perf.head is None:
        raise InvalidDataError(f"{perf.source}: no head motion to write")
    weights = perf.weights if ext == CSV else None
    return write_animation(path, times=perf.times, head=perf.head, weights=weights,
                           names=perf.names if weights is not None else None)
