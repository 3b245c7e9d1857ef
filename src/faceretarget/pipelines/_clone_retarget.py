"""Clone or retarget one take onto a character, and write the result: the ``clone`` and ``retarget``
commands as library functions.

Memory is bounded by the take's weights, not its meshes: a weight take is played on its source rig
only at the feature points the fitted model looks at, ``chunk_frames`` frames at a time, so a
``(T, V, 3)`` array of the source never exists; the target's ``(T, V, 3)`` exists only when the
output asks for vertices (``.npz``, OBJ frames), and even then it is written chunk by chunk.
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..cloning import CloneResult, ExpressionCloner
from ..errors import InvalidDataError, OutputError, TopologyError
from ..files import check_output_path
from ..formats import BAKED_FORMATS, BLEND, BVH, CLAMPED_IN_BLENDER, CSV, GLB
from ..headpose import HeadPose
from ..io import WRITERS, holds_head, read_head_motion, write_animation
from ..names import ARKIT_NAMES, normalize_name, split_parent
from ..performance import Performance
from ..retarget import BlendshapeRetargeter, RetargetResult, check_consistency
from ..rig import Rig
from ..targets import Target
from ._keys import check_face_keys, check_face_take

__all__ = ["CHUNK_FRAMES", "source_geometry", "clone_take", "retarget_take", "write_result", "Transfer",
           "result_head", "arkit_curves", "HEAD_CHOICES", "face_and_head_formats", "check_result_path",
           "MAX_TEMPORAL", "target_weights", "keep_arkit_range", "blender_timeline_note"]

#: The ``head`` choices of :func:`write_result` besides a head-motion file, a take or a pose.
HEAD_CHOICES = ("auto", "off")
#: Registered writers that hold a head but no face: not an output of a clone or retarget.
_HEAD_ONLY = (BVH,)
#: Largest ``temporal`` of :func:`retarget_take` (relative to the keys' mean squared norm): every real
#: take tried converges up to it; from about 3e3 the smoothed solve stops converging (docs/retargeting.md).
MAX_TEMPORAL = 1000.0


def face_and_head_formats() -> list[str]:
    """The output extensions that hold a face and head motion together (for messages)."""
    return [k for k, f in WRITERS.items() if f.head and k not in _HEAD_ONLY]

#: Frames evaluated at once when a weight take is played on its rig (bounds memory on long takes).
CHUNK_FRAMES = 4096


def _quiet(*_a) -> None:
    return None


def source_geometry(take: Performance, source_rig: Rig | None, vertices: np.ndarray | None = None, *,
                    model_vertices: int | None = None, chunk_frames: int = CHUNK_FRAMES,
                    log: Callable[..., None] = _quiet) -> np.ndarray | Performance:
    """What a fitted cloner or retargeter reads of ``take``.

    Point and vertex takes are returned as they are (a :class:`Performance`, so markers keep their
    labels and head motion is removed by the model).  A weight take is played on ``source_rig``
    at ``vertices`` only (the model's feature points), ``chunk_frames`` frames at a time:
    ``(T, P, 3)``.

    Parameters
    ----------
    take : Performance
    source_rig : Rig or None
        The rig a weight take drives.
    vertices : (P,) int, optional
        The vertices to evaluate (default all).
    model_vertices : int, optional
        Vertex count of the model's source keys: a rig of another topology is refused.
    """
    if take.kind != "weights":
        return take
    if source_rig is None:
        raise InvalidDataError(f"{take.source}: a weight take needs the source rig it drives (--source-rig DIR)")
    if model_vertices is not None and source_rig.n_vertices != model_vertices:
        raise TopologyError(f"{take.source}: the source rig {source_rig.name} has {source_rig.n_vertices} vertices "
                            f"but the source key-models have {model_vertices}")
    log(f"playing {take.n_frames} frames of weights on {source_rig.name}")
    W = source_rig.map_weights(take.names, take.weights, source=take.source)
    P = source_rig.n_vertices if vertices is None else len(vertices)
    out = np.empty((take.n_frames, P, 3))
    for a in range(0, take.n_frames, chunk_frames):
        out[a:a + chunk_frames] = source_rig.evaluate(W[a:a + chunk_frames], vertices)
    return out


def _apply(model: ExpressionCloner | BlendshapeRetargeter, take: Performance, source_rig: Rig | None,
           log: Callable[..., None]) -> CloneResult | RetargetResult:
    """``model.transform`` of what it reads of ``take`` (:func:`source_geometry`), with the take's head
    motion and audio carried to the result."""
    geo = source_geometry(take, source_rig, model.feature_idx_, model_vertices=len(model.source_neutral_), log=log)
    if isinstance(geo, Performance):
        return model.transform(check_face_take(geo, drop=False))     # a face: its stray markers missing, named
    res = model.transform(geo, take.times)
    res.carry(take)                  # head, audio, timecode and curves of the input take
    return res


@dataclass(eq=False)
class Transfer:
    """A take cloned or retargeted: the fitted model, its result, the seconds it took, and the target
    keys as given (``keys``: before a retargeter splits them by region; their
    :attr:`~faceretarget.rig.Rig.basis` turns key weights into ARKit curves, :func:`arkit_curves`);
    ``target``: the :class:`~faceretarget.targets.Target` the keys were given as (``keys`` is then its
    :attr:`~faceretarget.targets.Target.solve_keys`), None for a plain Rig."""

    model: ExpressionCloner | BlendshapeRetargeter
    result: CloneResult | RetargetResult
    seconds: float
    keys: Rig | None = None
    target: Target | None = None

    @property
    def target_keys(self) -> Rig:
        return self.model.target_keys_


def _target_of(target_keys: Rig | Target, source_keys: Rig,
               log: Callable[..., None]) -> tuple[Target | None, Rig, Rig]:
    """``(target, its solve keys, source keys)``: a Target's keys checked against the source keyshapes,
    or a Rig as it is.  Source keys that are an ARKit-style rig's own shapes (``--source-keys`` a rig
    folder) are cut to the shapes the target poses (a drawing of 15 ARKit keys driven by a 52-shape
    rig), with a log line; any other unmatched source keyshape is an error (a missing or misspelt key)."""
    if isinstance(target_keys, Target):
        if target_keys.kind != "mesh":
            posed = set(target_keys.names)
            keep = [n for n in source_keys.names if normalize_name(n) in posed]
            arkit = sum(_is_arkit(n) for n in source_keys.names) >= 0.8 * len(source_keys.names)
            if arkit and keep and len(keep) < len(source_keys.names):
                log(f"solving with the {len(keep)} of {len(source_keys.names)} shapes of {source_keys.name} that "
                    f"{target_keys.name} poses")
                source_keys = source_keys.subset(keep)
        target_keys.check_keys(source_keys.names, source_keys.name)
        log(target_keys.describe())
        return target_keys, target_keys.solve_keys, source_keys
    return None, target_keys, source_keys


def clone_take(take: Performance, source_keys: Rig, target_keys: Rig | Target, *, source_rig: Rig | None = None,
               method: str = "temporal", features="landmarks", weight_range="auto",
               log: Callable[..., None] = _quiet) -> Transfer:
    """Clone a take onto the target key-models (Pyun et al. 2003; :class:`~faceretarget.cloning.ExpressionCloner`).

    Parameters
    ----------
    take : Performance
        Points or vertices of the source face, or weights on ``source_rig``.
    source_keys : Rig
    target_keys : Rig or Target
        Key-model pairs (by name); a :class:`~faceretarget.targets.Target` (control table, skeleton,
        drawing) is solved in its :attr:`~faceretarget.targets.Target.solve_keys` and written by
        :func:`write_result` in its own parameters.
    source_rig : Rig, optional
        The rig a weight take drives (default ``source_keys`` when they share its topology).
    weight_range : "auto", (lo, hi) or None
        Range of the weights (:class:`~faceretarget.cloning.ExpressionCloner`).
    """
    t0 = time.perf_counter()
    check_face_keys(source_keys)
    if source_rig is None and take.kind == "weights":
        source_rig = source_keys                    # the take drives every shape, whatever the target poses
    target, target_keys, source_keys = _target_of(target_keys, source_keys, log)
    cloner = ExpressionCloner(method, features=features, weight_range=weight_range).fit(source_keys, target_keys)
    log(_range_line(cloner.weight_range_))
    rig = source_rig if source_rig is not None else (source_keys if take.kind == "weights" else None)
    res = _apply(cloner, take, rig, log)
    if res.noise_sigma > 0:
        log(f"estimated capture noise {res.noise_sigma * source_keys.mm_per_unit:.3f} mm: denoised over time")
    dt = time.perf_counter() - t0
    log(f"cloned {take.n_frames} frames with '{method}' in {dt:.2f} s; frames outside the key-models "
        f"(>35% unexplained): {(res.outside > 0.35).mean():.1%}")
    return Transfer(cloner, res, dt, target_keys, target)


def _range_line(r) -> str:
    return "weights unconstrained" if r is None else f"weights kept in [{r[0]:g}, {r[1]:g}]"


def retarget_take(take: Performance, source_keys: Rig, target_keys: Rig | Target, *, source_labels: Sequence[str] = (),
                  source_rig: Rig | None = None, check: bool = False, log: Callable[..., None] = _quiet,
                  temporal: float | None = None, **params) -> Transfer:
    """Retarget a take through keyshape pairs (Chuang Ch. 3; :class:`~faceretarget.retarget.BlendshapeRetargeter`).

    Parameters
    ----------
    take : Performance
        Markers, landmarks or vertices of the source face, or weights on ``source_rig``.
    source_keys : Rig
    target_keys : Rig or Target
        Keyshape pairs (by name); a :class:`~faceretarget.targets.Target` as in :func:`clone_take`.
    source_labels : sequence of str
        Marker labels of the source keyshapes (to match a marker take by label).
    check : bool
        Log the consistency report of the target keyshapes (:func:`~faceretarget.retarget.check_consistency`).
    temporal : float, optional
        Temporal smoothness of the ``"nnls"`` solve in units of the source keyshapes' mean squared
        norm at the feature points (``smooth = temporal * key_scale_**2``), so a value means the same
        for a rig in metres and one in centimetres: 0 none, about 1 visibly smoother curves, 100 and
        more nearly constant weights; in ``[0, MAX_TEMPORAL]`` (1000).  Instead of ``smooth``.
    **params
        :class:`~faceretarget.retarget.BlendshapeRetargeter` parameters.

    Raises
    ------
    InvalidDataError
        ``temporal`` outside ``[0, MAX_TEMPORAL]``, given with ``smooth``, or with a solver other
        than ``"nnls"``.
    """
    t0 = time.perf_counter()
    if temporal is not None:
        temporal = float(temporal)
        if not (np.isfinite(temporal) and 0.0 <= temporal <= MAX_TEMPORAL):
            raise InvalidDataError(f"temporal smoothness must be in [0, {MAX_TEMPORAL:g}] (units of the keys' mean "
                                   f"squared norm), got {temporal:g}")
        if params.get("smooth"):
            raise InvalidDataError("give temporal (relative) or smooth (absolute), not both")
        if temporal > 0 and params.get("solver", "signed") != "nnls":
            raise InvalidDataError("temporal smoothness inside the solve applies to the 'nnls' solver only "
                                   "(--solver nnls); smooth the curves of 'signed' with a filter (--smooth)")
    check_face_keys(source_keys)
    if source_rig is None and take.kind == "weights" and isinstance(target_keys, Target) and target_keys.kind != "mesh":
        source_rig = source_keys                    # the take drives every shape, whatever the target poses
    target, target_keys, source_keys = _target_of(target_keys, source_keys, log)
    if check:
        log(check_consistency(source_keys, target_keys).table())
    rt = BlendshapeRetargeter(**params).fit(source_keys, target_keys, source_labels=list(source_labels))
    if temporal:
        rt.set_params(smooth=temporal * rt.key_scale_ ** 2)
    log(_range_line(rt.weight_range_))
    res = _apply(rt, take, source_rig, log)
    if res.alignment is not None:
        log(res.alignment.report(take.unit))
    if res.noise_sigma > 0:
        log(f"estimated capture noise {res.noise_sigma * source_keys.mm_per_unit:.3f} mm: denoised over time")
    if rt.filter_level:
        log(f"weight filter level {rt.filter_level}: removed {100 * res.extremes_removed:.1f} % of the extremes")
    dt = time.perf_counter() - t0
    log(f"retargeted {take.n_frames} frames with '{rt.solver}' in {dt:.2f} s")
    return Transfer(rt, res, dt, target_keys, target)


def _is_arkit(name: str) -> bool:
    n = normalize_name(name)
    return n in ARKIT_NAMES or split_parent(n) in ARKIT_NAMES


def arkit_curves(transfer: Transfer, *, path: str | os.PathLike = "result",
                 log: Callable[..., None] = _quiet) -> tuple[np.ndarray, list[str]]:
    """The result's weights as ARKit curves, what a Live Link Face CSV holds.

    A retarget's region weights are first folded back per key
    (:meth:`~faceretarget.retarget.BlendshapeRetargeter.key_weights`).  Target keys named after ARKit
    shapes give their weights as they are; target keys defined by ARKit weight vectors (a key-model
    set, :attr:`~faceretarget.rig.Rig.basis`: ``rom-K``, ``combined84``, composed or selected keys)
    give ``W @ U``, exact because key ``i`` of the target is the target rig at ``U[i]``.

    Parameters
    ----------
    transfer : Transfer
    path : path-like
        The output, for messages.

    Returns
    -------
    W : (T, M) float
    names : list of str
        ARKit names (normalised; split halves such as ``browInnerUpLeft`` may occur).

    Raises
    ------
    OutputError
        Target keys that are neither ARKit shapes nor defined by ARKit weights (naming the key set
        and a key, and the formats that can hold them).
    """
    res, model = transfer.result, transfer.model
    W, names = res.weights, list(res.names)
    keys = transfer.keys if transfer.keys is not None else model.target_keys_
    if isinstance(model, BlendshapeRetargeter):
        W, names = model.key_weights(W), list(model.names_)
    if all(_is_arkit(n) for n in names):
        W = keep_arkit_range(W, names, rig=keys, what=str(path), log=log)
        return W, [normalize_name(n) for n in names]
    if keys.basis is not None and all(_is_arkit(n) for n in keys.basis_names) and all(n in keys for n in names):
        log(f"converted {len(names)} key weights of '{keys.name}' to {len(keys.basis_names)} ARKit curves "
            "(weights @ the keys' ARKit weight vectors)")
        idx = [keys.index(n) for n in names]
        W = _solve_in_unit_range(W, keys.basis[idx].T, keys.deltas[idx].reshape(len(idx), -1).T, str(path),
                                 "ARKit curves", list(keys.basis_names), "blend of the keys", log)
        return np.clip(keys.to_basis(W, names), 0.0, 1.0), list(keys.basis_names)
    bad = next(n for n in names if not _is_arkit(n))
    raise OutputError(f"{path}: a Live Link Face CSV holds ARKit curves, but the target keys '{keys.name}' "
                      f"('{bad}', ...) are neither ARKit shapes nor defined by ARKit weight vectors; write "
                      ".glb, .npz or .blend instead")


def _solve_in_unit_range(W: np.ndarray, A: np.ndarray, shapes: np.ndarray | None, what: str, values: str,
                         value_names: Sequence[str], blend: str, log: Callable[..., None]) -> np.ndarray:
    """``W`` ``(T, K)`` with every frame whose values ``W @ A.T`` leave [0, 1] solved again: the nearest
    weights in the metric of ``shapes`` ``(P, K)`` (identity when None) whose values are inside
    (:func:`~faceretarget.numerics.solve_inequality`), with one log line when any frame was."""
    from ..numerics import range_metric, solve_inequality

    V = W @ A.T
    bad = (V < -1e-9) | (V > 1.0 + 1e-9)            # beyond rounding (a clip writes those)
    if not bad.any():
        return W
    j = int(np.argmax(bad.sum(axis=0)))
    L = range_metric(shapes) if shapes is not None else np.eye(W.shape[1])
    out = solve_inequality(L, W, A, 0.0, 1.0)
    frames = int((out != W).any(axis=1).sum())
    log(f"{what}: {values} kept in [0, 1], ARKit's range: {int(bad.sum())} values ({bad.mean():.1%}) were outside "
        f"as solved ({V.min():.3f} .. {V.max():.3f}; most often '{value_names[j]}'), so {frames} of {len(W)} frames were "
        f"solved again as the nearest {blend} inside it{' in the rig' + chr(39) + 's geometry' if shapes is not None else ''}")
    return out


def keep_arkit_range(weights: np.ndarray, names: Sequence[str], *, rig: Rig | None = None, what: str = "weights",
                     log: Callable[..., None] = _quiet) -> np.ndarray:
    """ARKit-named weights ``(T, K)`` kept in [0, 1], ARKit's range, as every ARKit consumer plays them.

    Frames with a weight outside are solved again: the nearest in-range weights in the geometry of
    ``rig``'s shapes of those names (when given; else each weight clipped), with one log line saying
    how many values were outside.  Weights of names that are not ARKit shapes are left as they are.

    Returns
    -------
    (T, K) float
        A copy (or ``weights`` itself when nothing was outside).
    """
    W = np.asarray(weights, dtype=np.float64)
    arkit = np.array([_is_arkit(n) for n in names])
    if not arkit.any():
        return W
    A = np.eye(len(names))[arkit]
    shapes = None
    if rig is not None:                     # each name's shape on the rig (zero for a name it has no shape of)
        drive = rig.map_weights(list(names), np.eye(len(names)), warn=False)
        shapes = (drive @ rig.deltas.reshape(rig.n_shapes, -1)).T
    out = _solve_in_unit_range(W, A, shapes, what, "ARKit weights", [n for n, a in zip(names, arkit, strict=True) if a],
                               "weights", log).copy()
    out[:, arkit] = np.clip(out[:, arkit], 0.0, 1.0)          # rounding (1e-12) of the solve, or of the input
    return out


def _own_target(transfer: Transfer) -> Target | None:
    """The transfer's target when it writes itself (controls, skeleton, drawing), None for meshes."""
    t = transfer.target
    return t if t is not None and t.kind != "mesh" else None


def target_weights(transfer: Transfer) -> np.ndarray:
    """The result's weights per key of :attr:`Transfer.target` ``(T, K)``, in its key order (a
    retarget's region weights folded back per key first,
    :meth:`~faceretarget.retarget.BlendshapeRetargeter.key_weights`)."""
    if transfer.target is None:
        raise InvalidDataError("the transfer has no Target (its keys were a Rig)")
    W, names = transfer.result.weights, list(transfer.result.names)
    if isinstance(transfer.model, BlendshapeRetargeter):
        W, names = transfer.model.key_weights(W), list(transfer.model.names_)
    return W[:, transfer.target.key_order(names)]


def _resample_head(motion: Performance, times: np.ndarray, timecode: float | None, what: str) -> HeadPose:
    """``motion.head`` at ``times``: by timecode when both have one, else from their first frames."""
    if motion.head is None:
        raise InvalidDataError(f"{what}: holds no head motion")
    if motion.n_frames == len(times) and np.allclose(motion.times - motion.times[0], times - times[0], atol=1e-9) \
            and (timecode is None or motion.timecode is None
                 or abs(motion.timecode + motion.times[0] - timecode - times[0]) < 1e-6):
        return motion.head
    if timecode is not None and motion.timecode is not None:
        query = (timecode + times) - motion.timecode
        how = "by timecode"
    else:
        query = times - times[0] + motion.times[0]
        how = "from their first frames"
    ok = motion.times[motion.head.valid]
    if ok.size < 2 or query[0] < ok[0] - 1e-6 or query[-1] > ok[-1] + 1e-6:
        span = f"{ok[0]:.3f}-{ok[-1]:.3f} s" if ok.size else "no frame with a pose"
        raise InvalidDataError(f"{what}: the head motion covers {span}, the take ({len(times)} frames, "
                               f"{times[-1] - times[0]:.3f} s, aligned {how}) needs {query[0]:.3f}-{query[-1]:.3f} s; "
                               "give a head-motion file that covers the whole take")
    return motion.head.resample(motion.times, query)


def result_head(transfer: Transfer, head="auto") -> tuple[HeadPose | None, bool]:
    """The head motion to write with a result, and whether it was asked for explicitly.

    Parameters
    ----------
    transfer : Transfer
    head : ``"auto"``, ``"off"``, path-like, Performance or HeadPose
        ``"auto"`` (or True): the take's own head pose when it has one (Live Link Face head
        columns, video capture, the markers' rigid motion); ``"off"`` (or None / False): none; a
        head-motion file (:func:`~faceretarget.io.read_head_motion`: ``.bvh``, SMPL-X ``.npz``,
        ``.c3d``, ``.glb``, ``.csv``) or a take with a head: resampled to the result's times
        (slerp), aligned by timecode when both have one and otherwise from their first frames; it
        must cover the whole take (no ends are held or extrapolated); a HeadPose: one pose per frame.

    Returns
    -------
    HeadPose or None
        One pose per frame of the result.
    bool
        True for a file, take or pose (``"auto"`` and ``"off"`` are not explicit).

    Raises
    ------
    InvalidDataError
        A head-motion file or take that does not cover the take (naming it), a pose of the wrong
        length; :class:`~faceretarget.errors.InputFileError` for an unreadable file.
    """
    res = transfer.result
    if head is True or (isinstance(head, str) and head == "auto"):
        return res.head, False
    if head is None or head is False or (isinstance(head, str) and head == "off"):
        return None, False
    times = np.asarray(res.times, dtype=np.float64)
    if isinstance(head, HeadPose):
        if head.n_frames != len(times):
            raise InvalidDataError(f"{head.source}: {head.n_frames} head poses for a take of {len(times)} frames")
        return head, True
    if isinstance(head, Performance):
        return _resample_head(head, times, res.timecode, head.source), True
    if isinstance(head, str | os.PathLike):
        return _resample_head(read_head_motion(head), times, res.timecode, str(head)), True
    raise InvalidDataError(f"head must be 'auto', 'off', a head-motion file, a take or a HeadPose, got {head!r}")


def check_result_path(path: str | os.PathLike, *, keys: Rig | None = None, bake: bool = False,
                      target: Target | None = None) -> Path:
    """Raise before any work when :func:`write_result` could not write ``path``; returns it as a Path.

    Parameters
    ----------
    path : path-like
        The output: a registered extension that holds a face, or a folder (OBJ sequence).
    keys : Rig, optional
        The target keys: a ``.csv`` needs ARKit-named keys or keys defined by ARKit weights
        (:func:`arkit_curves`).
    bake : bool
        ``write_result(bake=True)``: USD output only.
    target : Target, optional
        A target that writes itself (controls, skeleton, drawing): its formats
        (:meth:`~faceretarget.targets.Target.check_output`) instead of the animation writers'.

    Raises
    ------
    OutputError
        An unknown extension, a head-only format, ``bake`` for a format without a baked variant,
        target keys a Live Link Face CSV cannot hold, or a folder that is missing or read-only.
    """
    path = Path(path)
    if target is not None and target.kind != "mesh":
        if bake:
            raise OutputError(f"{path}: baking applies to USD output of mesh targets")
        return target.check_output(path)
    holds_head(path)                                # unknown extension -> OutputError
    if bake and path.suffix.lower() not in BAKED_FORMATS:
        raise OutputError(f"{path}: baking applies to USD output ({', '.join(sorted(BAKED_FORMATS))}); an OBJ "
                          "sequence or .npz already holds the meshes")
    if path.suffix.lower() in _HEAD_ONLY:
        raise OutputError(f"{path}: a {path.suffix} holds head motion only, not the face; write "
                          f"{', '.join(face_and_head_formats())} (or 'headmotion' tools for head motion alone)")
    if keys is not None and path.suffix.lower() == CSV and not all(_is_arkit(n) for n in keys.names) and not (
            keys.basis is not None and all(_is_arkit(n) for n in keys.basis_names)):
        bad = next(n for n in keys.names if not _is_arkit(n))
        raise OutputError(f"{path}: a Live Link Face CSV holds ARKit curves, but the target keys '{keys.name}' "
                          f"('{bad}', ...) are neither ARKit shapes nor defined by ARKit weight vectors; write "
                          ".glb, .npz or .blend instead")
    return check_output_path(path)


def write_result(path: str | os.PathLike, transfer: Transfer, *, head="auto", bake: bool = False,
                 character=None, neck_share: float = 0.0, progress: bool = False,
                 log: Callable[..., None] = _quiet) -> Path:
    """Write a cloned or retargeted take in the format ``path`` asks for.

    ``.glb`` holds the target keys as morph targets and the weights as their animation, with the
    head motion as a ``head`` node above the face; ``.csv`` the 52 ARKit curves in Live Link Face's
    layout (:func:`arkit_curves`: ARKit-named target keys as they are, key-model sets defined by
    ARKit weights converted, anything else an :class:`~faceretarget.errors.OutputError`), with the
    input take's timecode, eye angles and the head angles; ``.npz`` / a folder the target meshes,
    evaluated and written chunk by chunk.  Every other registered format gets the head motion when
    its writer holds one (:func:`~faceretarget.io.holds_head`).

    Parameters
    ----------
    path : path-like
    transfer : Transfer
    head : ``"auto"``, ``"off"``, path-like, Performance or HeadPose
        Which head motion goes into the file (:func:`result_head`).  A format that cannot hold
        head motion refuses an explicit one (file, take, pose) and logs that the take's own is
        left out with ``"auto"``.
    bake : bool
        USD only: time-sampled mesh points instead of blend shapes and weights.
    character : DriveRig, optional
        The target as a character file (:func:`~faceretarget.characters.drive_rig`): an output in its own
        format gets the animation written back into a copy of that file, the ARKit curves of the result
        (:func:`arkit_curves`) on the character's shapes and the head motion on its head joint.
    neck_share : float
        With ``character``: the share of the head rotation its neck joint takes.
    progress : bool
        A progress bar for outputs that take seconds to draw (a drawing's ``.mp4``).

    Raises
    ------
    OutputError
        Unknown format, an explicit head for a format without one, a ``.csv`` of keys without an
        ARKit definition; nothing is written.
    """
    own = _own_target(transfer)
    if character is not None:
        from ..io import writes_back

        if writes_back(character.character, path):
            return _write_back(Path(path), transfer, character, head, neck_share, log)
    path = check_result_path(path, bake=bake, target=own)
    res, model = transfer.result, transfer.model
    has_head = own.holds_head(path) if own is not None else holds_head(path)
    pose, explicit = result_head(transfer, head)
    if pose is not None and not explicit and not pose.moves():
        log(f"the take's head pose never moves (its head columns are all zero): {path.name} gets no head motion")
        pose = None
    if pose is not None and not has_head:
        if explicit:
            ok = ", ".join(face_and_head_formats())
            raise OutputError(f"{path}: this format cannot hold head motion; write the head from "
                              f"{getattr(pose, 'source', 'the head')} into one that can ({ok})")
        log(f"{path.suffix or 'an OBJ sequence'} holds no head motion: the take's head motion is not written")
        pose = None
    clock = dict(timecode=res.timecode, timecode_rate=res.timecode_rate,
                 curves=res.curves, curve_names=list(res.curve_names) if res.curves is not None else None)
    if own is not None:
        extra = dict(clock, audio=res.audio, audio_rate=res.audio_rate) if own.kind == "controls" else {}
        out = own.write(path, target_weights(transfer), res.times, head=pose, log=log, progress=progress, **extra)
        log(f"wrote {path} ({len(res.times)} frames of the {own.kind} target, {own.n_keys} keys"
            f"{', head motion' if pose is not None else ''})")
        return out
    if path.suffix.lower() == CSV:
        W, names = arkit_curves(transfer, path=path, log=log)
        out = write_animation(path, weights=W, names=names, times=res.times, head=pose, **clock)
    else:
        W, names = res.weights, list(res.names)
        out = write_animation(path, rig=transfer.target_keys, weights=W, names=names, times=res.times, head=pose,
                              audio=res.audio, audio_rate=res.audio_rate, bake=bake, **clock)
    what = "keyshapes" if isinstance(model, BlendshapeRetargeter) else "key-models"
    log(f"wrote {path} ({len(res.times)} frames, {res.weights.shape[1]} target {what}"
        f"{', head motion' if pose is not None else ''})")
    note = None if bake else _slider_note(path, res.weights)
    if note:
        log(note)
    if path.suffix.lower() == GLB:
        note = blender_timeline_note(path, res.times)
        if note:
            log(note)
    return out


def _write_back(path: Path, transfer: Transfer, drive, head, neck_share: float, log) -> Path:
    """The result written back into a copy of the target character's own file."""
    from ..characters import character_weights
    from ..io import write_character_animation

    res = transfer.result
    W, names = arkit_curves(transfer, path=path, log=log)
    full = character_weights(drive, W, names)
    pose, _ = result_head(transfer, head)
    out = write_character_animation(path, drive.character, drive.channels, full, res.times, head=pose,
                                    audio=res.audio, audio_rate=res.audio_rate, neck_share=neck_share, log=log)
    log(f"wrote {path} ({len(res.times)} frames of {len(names)} ARKit curves on {drive.character.name}'s own shapes)")
    return out


#: What Blender's glTF importer leaves the scene at: 24 frames/s, frames 1 to 250 (10.4 s).
_BLENDER_DEFAULT_FPS, _BLENDER_DEFAULT_END = 24.0, 250


def blender_timeline_note(path: str | os.PathLike, times: np.ndarray) -> str | None:
    """One line when a ``.glb`` take would not play whole in Blender's default scene (24 frames/s, frames
    1-250): Blender keeps the keys at their times but plays only the scene's range."""
    times = np.asarray(times, dtype=np.float64)
    if times.size < 2:
        return None
    span = float(times[-1] - times[0])
    shown = (_BLENDER_DEFAULT_END - 1) / _BLENDER_DEFAULT_FPS
    if span <= shown + 1e-9:
        return None
    return (f"note: Blender opens {Path(path).name} in its default scene (24 fps, frames 1-250), which plays the "
            f"first {shown:.1f} s of this {span:.1f} s take: set the scene's end frame to "
            f"{int(np.ceil(span * _BLENDER_DEFAULT_FPS)) + 1} there, or write {Path(path).with_suffix(BLEND).name} "
            "(the take's own rate and frame range)")


def _slider_note(path: Path, W: np.ndarray) -> str | None:
    """One line when a file's weights leave [0, 1] and Blender's importer of that format would clamp them."""
    who = CLAMPED_IN_BLENDER.get(path.suffix.lower())
    if who is None or W.size == 0 or (W.min() >= 0.0 and W.max() <= 1.0):
        return None
    share = float(((W < 0) | (W > 1)).mean())
    return (f"note: weights run {W.min():.2f} .. {W.max():.2f} ({share:.0%} outside [0, 1]): {who} clamps them "
            f"to its sliders; for Blender write {path.with_suffix(BLEND).name} (sliders sized to the weights), "
            f"or keep [0, 1] with --weight-range 0 1")
