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
from ..io import write_animation
from ..names import ARKIT_NAMES, normalize_name
from ..performance import Performance
from ..retarget import BlendshapeRetargeter, RetargetResult, check_consistency
from ..rig import Rig

__all__ = ["CHUNK_FRAMES", "source_geometry", "clone_take", "retarget_take", "write_result", "Transfer"]

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
        return model.transform(geo)
    res = model.transform(geo, take.times)
    res.head, res.audio, res.audio_rate, res.source = take.head, take.audio, take.audio_rate, take.source
    return res


@dataclass(eq=False)
class Transfer:
    """A take cloned or retargeted: the fitted model, its result, and the seconds it took."""

    model: ExpressionCloner | BlendshapeRetargeter
    result: CloneResult | RetargetResult
    seconds: float

    @property
    def target_keys(self) -> Rig:
        return self.model.target_keys_


def clone_take(take: Performance, source_keys: Rig, target_keys: Rig, *, source_rig: Rig | None = None,
               method: str = "temporal", features="landmarks", log: Callable[..., None] = _quiet) -> Transfer:
    """Clone a take onto the target key-models (Pyun et al. 2003; :class:`~faceretarget.cloning.ExpressionCloner`).

    Parameters
    ----------
    take : Performance
        Points or vertices of the source face, or weights on ``source_rig``.
    source_keys, target_keys : Rig
        Key-model pairs (by name).
    source_rig : Rig, optional
        The rig a weight take drives (default ``source_keys`` when they share its topology).
    """
    t0 = time.perf_counter()
    cloner = ExpressionCloner(method, features=features).fit(source_keys, target_keys)
    rig = source_rig if source_rig is not None else (source_keys if take.kind == "weights" else None)
    res = _apply(cloner, take, rig, log)
    if res.noise_sigma > 0:
        log(f"estimated capture noise {res.noise_sigma * source_keys.mm_per_unit:.3f} mm: denoised over time")
    dt = time.perf_counter() - t0
    log(f"cloned {take.n_frames} frames with '{method}' in {dt:.2f} s; frames outside the key-models "
        f"(>35% unexplained): {(res.outside > 0.35).mean():.1%}")
    return Transfer(cloner, res, dt)


def retarget_take(take: Performance, source_keys: Rig, target_keys: Rig, *, source_labels: Sequence[str] = (),
                  source_rig: Rig | None = None, check: bool = False, log: Callable[..., None] = _quiet,
                  **params) -> Transfer:
    """Retarget a take through keyshape pairs (Chuang Ch. 3; :class:`~faceretarget.retarget.BlendshapeRetargeter`).

    Parameters
    ----------
    take : Performance
        Markers, landmarks or vertices of the source face, or weights on ``source_rig``.
    source_keys, target_keys : Rig
        Keyshape pairs (by name).
    source_labels : sequence of str
        Marker labels of the source keyshapes (to match a marker take by label).
    check : bool
        Log the consistency report of the target keyshapes (:func:`~faceretarget.retarget.check_consistency`).
    **params
        :class:`~faceretarget.retarget.BlendshapeRetargeter` parameters.
    """
    t0 = time.perf_counter()
    if check:
        log(check_consistency(source_keys, target_keys).table())
    rt = BlendshapeRetargeter(**params).fit(source_keys, target_keys, source_labels=list(source_labels))
    res = _apply(rt, take, source_rig, log)
    if res.alignment is not None:
        log(res.alignment.report(take.unit))
    if res.noise_sigma > 0:
        log(f"estimated capture noise {res.noise_sigma * source_keys.mm_per_unit:.3f} mm: denoised over time")
    if rt.filter_level:
        log(f"weight filter level {rt.filter_level}: removed {100 * res.extremes_removed:.1f} % of the extremes")
    dt = time.perf_counter() - t0
    log(f"retargeted {take.n_frames} frames with '{rt.solver}' in {dt:.2f} s")
    return Transfer(rt, res, dt)


def write_result(path: str | os.PathLike, transfer: Transfer, *, head: bool = False,
                 log: Callable[..., None] = _quiet) -> Path:
    """Write a cloned or retargeted take in the format ``path`` asks for.

    ``.glb`` holds the target keys as morph targets and the weights as their animation; ``.csv``
    the weights in Live Link Face's layout (the target keys must be ARKit-named; a retarget's region
    weights are folded back per key; the take's head angles are carried); ``.npz`` / a folder the
    target meshes, evaluated and written chunk by chunk.  With ``head=True`` a ``.glb`` also holds
    the take's head motion as a ``head`` node above the face.
    """
    path = Path(path)
    res, model = transfer.result, transfer.model
    W, names = res.weights, list(res.names)
    if path.suffix.lower() == ".csv":
        if isinstance(model, BlendshapeRetargeter):
            W, names = model.key_weights(W), list(model.names_)
        arkit = [normalize_name(n) for n in names]
        if not all(n in ARKIT_NAMES for n in arkit):
            raise OutputError(f"{path}: a Live Link Face CSV needs ARKit-named target keys ({names[0]} is not "
                              "one); write .glb or .npz instead")
        out = write_animation(path, weights=W, names=arkit, times=res.times, head=res.head)
    else:
        out = write_animation(path, rig=transfer.target_keys, weights=W, names=names, times=res.times,
                              head=res.head if head and path.suffix.lower() == ".glb" else None)
    log(f"wrote {path} ({len(res.times)} frames, {len(names)} target {'keyshapes' if isinstance(model, BlendshapeRetargeter) else 'key-models'})")
    return out
