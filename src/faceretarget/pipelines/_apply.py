"""A take file onto a character's own shapes: what the Blender extension's *Apply a take* runs.

Three routes, each the library's own job (nothing solved differently here):

``clone`` (a weight take: Live Link Face CSV, ``.npz`` weights)
    Pyun's cloning exactly as ``faceretarget clone --source-rig SRC --target-rig CHARACTER --keys arkit``:
    key-models paired by their ARKit names on the source rig the take drives (default the embedded demo
    character ``ada``, all 52 ARKit shapes) and on the character's ARKit shapes
    (:func:`~faceretarget.characters.drive_rig` with ``"arkit"``), :func:`clone_take`, the result's
    ARKit curves (:func:`arkit_curves`) on the character's own shapes (:func:`character_weights`).
``retarget`` (a point or vertex take: C3D markers, ``.npz`` points or vertices)
    Chuang's keyshape retargeting as ``faceretarget retarget --source-keys KEYS --target-keys CHARACTER``:
    the source keyshapes (a keyshape folder, or an ARKit-style rig folder paired by ARKit names) onto the
    character's ARKit shapes, :func:`retarget_take`, :func:`arkit_curves`, :func:`character_weights`.
``landmarks`` (a take of the 68 face points, or a weight take played on the source rig's 68 landmarks)
    The ``animate`` solve (:func:`~faceretarget.pipelines.animate` given a tracked take): the character's
    own shapes, whatever their names, fitted to the 68 points by
    :class:`~faceretarget.retarget.LandmarkSolver`, a weight take's ARKit curves as its prior.  Works on
    every character whose landmarks are known, ARKit-named or not.

``auto`` takes ``clone`` for a weight take when the character has ARKit shapes (at least 10), else
``landmarks``; ``landmarks`` for a take of 68 face points; ``retarget`` for other point and vertex takes
(which then need source keys).
"""

from __future__ import annotations

import os
import re
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..character import Character
from ..errors import InvalidDataError, MissingShapeError
from ..headpose import HeadPose
from ..names import is_arkit, normalize_name
from ..performance import Performance
from ..rig import Rig

__all__ = ["apply_take", "AppliedTake", "TAKE_ROUTES", "landmark_points"]

#: The routes of :func:`apply_take`.
TAKE_ROUTES = ("auto", "clone", "retarget", "landmarks")
_MIN_ARKIT = 10
_LABEL = re.compile(r"^(?:lm|landmark|p|pt)?[_\-]?(\d{1,2})$", re.IGNORECASE)


def _quiet(*_a) -> None:
    return None


@dataclass(eq=False)
class AppliedTake:
    """What :func:`apply_take` made.

    Attributes
    ----------
    weights : (T, C) float
        One column per channel of the character (``drive.channels``; 0 for channels at rest).
    times : (T,) float
    head : HeadPose or None
        The take's head motion (head frame), when it has one.
    audio, audio_rate
        The take's sound, when it has one.
    route : str
        The route taken.
    drive : DriveRig
        The shapes that were driven.
    """

    weights: np.ndarray
    times: np.ndarray
    head: HeadPose | None
    audio: np.ndarray | None
    audio_rate: float | None
    route: str
    drive: object


def landmark_points(take: Performance) -> np.ndarray | None:
    """``(T, 68, 3)`` points of a take of the 68 face landmarks in their order (labels ``lm0`` ..
    ``lm67``, ``0`` .. ``67``, or 68 unlabelled points), else None."""
    if take.points is None or take.points.shape[1] != 68:
        return None
    labels = list(take.labels or [])
    if not labels:
        return take.points
    idx = []
    for lab in labels:
        m = _LABEL.match(str(lab).strip())
        if m is None:
            return None
        idx.append(int(m.group(1)))
    if sorted(idx) != list(range(68)):
        return None
    return take.points[:, np.argsort(idx)]


def _source_rig(source_rig) -> Rig:
    if isinstance(source_rig, Rig):
        return source_rig
    if source_rig is None:
        from ..datasets import make_demo_character

        return make_demo_character("ada")
    from ..io import read_rig

    return read_rig(source_rig)


def _arkit_count(drive_channels) -> int:
    return sum(is_arkit(normalize_name(c.name)) for c in drive_channels)


def apply_take(take: str | os.PathLike | Performance, character: Character, *, route: str = "auto",
               source_rig: Rig | str | os.PathLike | None = None, source_keys: str | os.PathLike | None = None,
               shapes: str = "auto", log: Callable[..., None] = _quiet) -> AppliedTake:
    """Put a take on the character's own shapes by the clone, retarget or landmark route (module docstring).

    Parameters
    ----------
    take : path-like or Performance
        A Live Link Face CSV, C3D, ``.npz`` or any take :func:`~faceretarget.io.read_performance` reads.
    character : Character
        Read (and, for the landmark route, its landmarks found: :func:`load_character`).
    route : {"auto", "clone", "retarget", "landmarks"}
    source_rig : Rig or path-like, optional
        The rig a weight take drives (clone and landmark routes); default the demo character ``ada``.
    source_keys : path-like, optional
        The retarget route's source keyshapes: a keyshape folder or an ARKit-style rig folder.
    shapes : str
        The landmark route's shapes (:func:`~faceretarget.character.choose_shapes`).

    Raises
    ------
    InvalidDataError
        A route that does not fit the take (named), or no source keys for a retarget.
    MissingShapeError
        The clone or retarget route on a character without ARKit shapes.
    """
    from ..characters import drive_rig
    from ..io import read_performance

    if route not in TAKE_ROUTES:
        raise InvalidDataError(f"route must be one of {', '.join(TAKE_ROUTES)}, got {route!r}")
    perf = take if isinstance(take, Performance) else read_performance(take)
    where = str(perf.source or take)
    points68 = landmark_points(perf) if perf.kind == "points" else None
    if route == "auto":
        if perf.kind == "weights":
            arkit = drive_rig(character, "arkit", need_landmarks=False) if _has_arkit(character) else None
            route = "clone" if arkit is not None else "landmarks"
        elif points68 is not None:
            route = "landmarks"
        else:
            route = "retarget"
    log(f"{Path(where).name}: {perf.n_frames} frames ({perf.kind}) by the {route} route")
    if route == "landmarks":
        return _by_landmarks(perf, points68, character, source_rig, shapes, where, log)
    if route == "clone":
        if perf.kind != "weights":
            raise InvalidDataError(f"{where}: the clone route takes a weight take (Live Link Face CSV, .npz weights); "
                                   f"this one holds {perf.kind}: use the retarget or landmarks route")
        return _by_clone(perf, character, source_rig, log)
    if perf.kind == "weights":
        raise InvalidDataError(f"{where}: the retarget route takes points or vertices; a weight take goes by the "
                               "clone or landmarks route")
    if source_keys is None:
        what = f"its {perf.points.shape[1]} points are" if perf.points is not None else "its vertices are"
        raise InvalidDataError(f"{where}: {what} not the 68 face landmarks: the retarget route needs source keys (a keyshape folder from "
                               "'faceretarget keys select', or an ARKit-style rig folder)")
    return _by_retarget(perf, character, source_keys, log)


def _has_arkit(character: Character) -> bool:
    from ..character import channels

    return _arkit_count(channels(character)) >= _MIN_ARKIT


def _arkit_drive(character: Character):
    from ..characters import drive_rig

    if not _has_arkit(character):
        raise MissingShapeError(f"{character.name}: fewer than {_MIN_ARKIT} ARKit-named shapes, so the ARKit curves "
                                "of a clone or retarget have nothing to drive; use the landmarks route")
    return drive_rig(character, "arkit", need_landmarks=False)


def _result(transfer, drive, perf: Performance, route: str, log) -> AppliedTake:
    from ..characters import character_weights
    from ._clone_retarget import arkit_curves

    W, names = arkit_curves(transfer, log=log)
    full = character_weights(drive, W, names)
    head = perf.head if perf.head is not None and perf.head.n_frames == len(full) else None
    return AppliedTake(full, np.asarray(perf.times, dtype=np.float64), head, perf.audio, perf.audio_rate, route,
                       drive)


def _by_clone(perf: Performance, character: Character, source_rig, log) -> AppliedTake:
    from ..cloning import keymodel_pair
    from ._clone_retarget import clone_take

    drive = _arkit_drive(character)
    src = _source_rig(source_rig)
    sk, tk, _ = keymodel_pair(src, drive.rig, "arkit")
    log(f"key-models: arkit, {sk.n_shapes} pairs on {src.name} and {character.name}")
    tr = clone_take(perf, sk, tk, source_rig=src, log=log)
    return _result(tr, drive, perf, "clone", log)


def _by_retarget(perf: Performance, character: Character, source_keys, log) -> AppliedTake:
    from ..cloning import keymodel_pair
    from ..io import is_keyshape_folder, read_keys
    from ._clone_retarget import retarget_take

    drive = _arkit_drive(character)
    sk, labels = read_keys(source_keys)
    tk = drive.rig
    if not is_keyshape_folder(source_keys):
        sk, tk, _ = keymodel_pair(sk, tk, "arkit")
    log(f"keyshapes: {sk.n_shapes} source from {source_keys}, {tk.n_shapes} on {character.name}")
    tr = retarget_take(perf, sk, tk, source_labels=labels, log=log)
    return _result(tr, drive, perf, "retarget", log)


def _by_landmarks(perf: Performance, points68, character: Character, source_rig, shapes: str, where: str,
                  log) -> AppliedTake:
    from ._animate import animate

    if perf.kind == "weights":
        src = _source_rig(source_rig)
        if src.landmarks is None or len(src.landmarks) != 68:
            raise InvalidDataError(f"{src.name}: the source rig needs its 68 landmarks to play a weight take as points")
        W = src.map_weights(perf.names, perf.weights, source=where, warn=False)
        points68 = src.evaluate(W, src.landmarks)
        tracked = perf.replace(points=points68, labels=[f"lm{i}" for i in range(68)], unit=src.unit)
        log(f"played on {src.name}'s 68 landmarks; its ARKit curves are the solve's prior")
    elif points68 is not None:
        tracked = Performance(perf.times, perf.fps, points=points68, labels=[f"lm{i}" for i in range(68)],
                              unit=perf.unit, head=perf.head, audio=perf.audio, audio_rate=perf.audio_rate,
                              source=perf.source)
    else:
        raise InvalidDataError(f"{where}: the landmarks route takes the 68 face points (labels lm0 .. lm67) or a weight "
                               f"take; this take holds {perf.kind}"
                               + (f" ({perf.points.shape[1]} points)" if perf.points is not None else ""))
    res = animate(tracked, character, shapes=shapes, head="video" if perf.head is not None else "off", log=log)
    return AppliedTake(res.drive.full_weights(res.weights), res.times, res.head, res.audio, res.audio_rate,
                       "landmarks", res.drive)
