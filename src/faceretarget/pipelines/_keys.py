"""Key-models and keyshapes for an artist: the ``keys select`` and ``keys compose`` commands as
library functions (Chuang Ch. 3 selection and export; Pyun Sec. 2 composition)."""

from __future__ import annotations

import time
import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from ..cloning import EMOTIONS, VISEMES, build_key_models, weight_vector
from ..errors import DataWarning, InvalidDataError
from ..mesh import Mesh
from ..metrics import figure_line
from ..names import ARKIT_NAMES, normalize_name
from ..numerics import (
    SELECTION_METHODS,
    AlignResult,
    RigidAligner,
    face_markers,
    face_mesh,
    reconstruction_error,
    select_keyshapes,
)
from ..performance import Performance
from ..rig import Rig, resolve_features

__all__ = ["KeyGeometry", "KeySelection", "key_geometry", "select_keys", "compose_keys", "SELECTION_ALIASES",
           "check_face_take", "check_face_keys"]

#: Short names the command line accepts for the selection methods.
SELECTION_ALIASES = {"kmeans": "kmeans2", "pca": "pca-extrema", "greedy": "nnls-greedy", "qr": "pivoted-qr"}


def _quiet(*_a) -> None:
    return None


@dataclass(eq=False)
class KeyGeometry:
    """A take's frames as 3-D points for keyshape work (:func:`key_geometry`).

    Attributes
    ----------
    points : (T, P, 3) float
        Head-stabilised markers, landmarks (2-D ones with z = 0), a mesh sequence, or a weight take
        played on its rig; NaN where a marker is missing.
    labels : list of str
    neutral : (P, 3) float or None
        The rest pose when the take knows it (the rig's neutral for a weight take).
    mesh : Mesh or None
        Topology of mesh frames.
    alignment : AlignResult or None
        The head-motion removal of a marker take.
    """

    points: np.ndarray
    labels: list[str]
    neutral: np.ndarray | None = None
    mesh: Mesh | None = None
    alignment: AlignResult | None = None


def check_face_take(take: Performance, *, drop: bool = True) -> Performance:
    """``take`` checked to be a face (:func:`~faceretarget.numerics.face_markers`,
    :func:`~faceretarget.numerics.face_mesh`): a marker take without its stray and mostly-missing
    markers (``drop``: removed; else missing in every frame, so label matching still finds them), named
    on one warning line.

    Raises
    ------
    NotAFaceError
        A take that spans more than a face, or whose labels name a body.
    """
    if take.kind == "vertices":
        face_mesh(take.vertices, take.unit, source=take.source)
        return take
    if take.kind != "points":
        return take
    chk = face_markers(take.points, take.labels, take.unit, source=take.source)
    msg = chk.message(take.source)
    if msg is None:
        return take
    warnings.warn(msg, DataWarning, stacklevel=3)
    if drop:
        keep = np.flatnonzero(chk.keep)
        return take.with_points(take.points[:, keep], [take.labels[i] for i in keep] if take.labels else None)
    pts = take.points.copy()
    pts[:, ~chk.keep] = np.nan
    return take.with_points(pts)


def check_face_keys(keys: Rig) -> None:
    """Raise :class:`~faceretarget.errors.NotAFaceError` when source keys are not a face: point-set keys
    (markers) by their span, mesh keys by the span of the part their shapes move."""
    frames = np.concatenate([keys.neutral.vertices[None], keys.neutral.vertices + keys.deltas])
    if keys.neutral.n_faces == 0:
        flat = not np.any(frames[..., 2])                  # keys of 2-D tracks (z = 0): pixels, no scale to judge
        face_markers(frames[..., :2] if flat else frames, None, keys.unit, source=keys.name)
    else:
        face_mesh(frames, keys.unit, source=keys.name, moving=np.abs(keys.deltas).max(axis=(0, 2)) if keys.n_shapes
                  else None)


#: Frames of a weight take played on its rig at once (a progress bar step).
_PLAY_CHUNK = 256


def key_geometry(take: Performance, source_rig: Rig | None = None, *, align: bool = True,
                 rigid_subset: Sequence[str | int] | None = None, progress: bool = False,
                 log: Callable[..., None] = _quiet) -> KeyGeometry:
    """The frames of ``take`` as points for selection and export (:class:`KeyGeometry`); a marker or mesh take
    is checked to be a face first and loses its stray markers (:func:`check_face_take`); ``progress``: a
    progress bar while a weight take is played on its rig (4,000 frames of a 9,409-vertex rig: seconds)."""
    take = check_face_take(take)
    if take.kind == "weights":
        from tqdm.auto import tqdm

        if source_rig is None:
            raise InvalidDataError(f"{take.source}: a weight take needs the rig it drives (--source-rig DIR)")
        log(f"playing {take.n_frames} frames of weights on {source_rig.name}")
        W = source_rig.map_weights(take.names, take.weights, source=take.source)
        V = np.empty((take.n_frames, source_rig.n_vertices, 3))
        with tqdm(total=take.n_frames, desc=f"playing on {source_rig.name}", unit="frame", disable=not progress,
                  leave=False) as bar:
            for a in range(0, take.n_frames, _PLAY_CHUNK):
                V[a:a + _PLAY_CHUNK] = source_rig.evaluate(W[a:a + _PLAY_CHUNK])
                bar.update(len(W[a:a + _PLAY_CHUNK]))
        return KeyGeometry(V, [], source_rig.neutral.vertices, source_rig.neutral)
    if take.kind == "vertices":
        return KeyGeometry(take.vertices, [], None, take.mesh)
    if take.kind != "points":
        raise InvalidDataError(f"{take.source}: a take of head motion only has no face to choose keyshapes from")
    pts = take.points
    if pts.shape[2] == 2:                       # 2-D landmark tracks: keyshapes in the image plane (z = 0)
        log(f"{take.source}: 2-D points; keyshapes are exported with z = 0 and no head-motion removal")
        pts = np.concatenate([pts, np.zeros(pts.shape[:2] + (1,))], axis=2)
        return KeyGeometry(pts, list(take.labels))
    al = None
    if align and pts.shape[1] >= 4:
        al = RigidAligner(subset=None if rigid_subset is None else list(rigid_subset)).fit_transform(take)
        log(al.report(take.unit))
        pts = al.take.points
    return KeyGeometry(pts, list(take.labels), None, None, al)


@dataclass(eq=False)
class KeySelection:
    """Keyshape frames chosen from a take (:func:`select_keys`).

    Attributes
    ----------
    frames : list of int
        Chosen frames, ascending.
    geometry : KeyGeometry
        The frames they index (head-stabilised).
    neutral : (P, 3) float
        The source's rest pose.
    error : float
        RMS error of the non-negative reconstruction of every complete frame from the keys, as a
        share of the take's RMS motion (0.45 = 45 %).
    method : str
    neutral_frame : int or None
        The frame taken as the rest pose (None when the rig's neutral was).
    basis : (k, M) float or None
        For a weight take: the chosen frames' weights (what each keyshape is, for
        ``write_keyshapes(..., basis=)`` and :attr:`Rig.basis <faceretarget.rig.Rig.basis>`).
    basis_names : list of str or None
        The ``M`` weight names (normalised ARKit names).
    rms_error : float
        The same error in the geometry's unit (``unit``): ``error`` times the RMS motion.
    unit : str or None
        The unit of the take's points (a weight take: its rig's).
    """

    frames: list[int]
    geometry: KeyGeometry
    neutral: np.ndarray
    error: float
    method: str
    neutral_frame: int | None = None
    basis: np.ndarray | None = None
    basis_names: list[str] | None = None
    rms_error: float = float("nan")
    unit: str | None = None


def select_keys(take: Performance, k: int, method: str = "pivoted-qr", *, source_rig: Rig | None = None,
                features="landmarks", neutral_frame: int | None = None, align: bool = True,
                rigid_subset: Sequence[str | int] | None = None, progress: bool = False,
                log: Callable[..., None] = _quiet) -> KeySelection:
    """Choose ``k`` keyshape frames of a take for an artist to model (Chuang Sec. 3.2).

    Parameters
    ----------
    take : Performance
        Markers (head motion removed first), landmarks, a mesh sequence, or weights on ``source_rig``.
    k : int
    method : str
        One of :data:`~faceretarget.numerics.SELECTION_METHODS` (or an alias of :data:`SELECTION_ALIASES`).
    source_rig : Rig, optional
        The rig a weight take drives.
    features : ``"landmarks"``, ``"all"`` or vertex indices
        With a rig: the vertices selection looks at.
    neutral_frame : int, optional
        The rest frame of a marker or mesh take (default the first complete frame).
    progress : bool
        A progress bar while a weight take is played on its rig.
    """
    t0 = time.perf_counter()
    method = SELECTION_ALIASES.get(method, method)
    if method not in SELECTION_METHODS:
        raise InvalidDataError(f"unknown selection method '{method}', use one of {', '.join(SELECTION_METHODS)} "
                               "(kmeans = kmeans2)")
    if k < 1:
        raise InvalidDataError(f"k must be at least 1, got {k}")
    geo = key_geometry(take, source_rig, align=align, rigid_subset=rigid_subset, progress=progress, log=log)
    pts = geo.points
    T = len(pts)
    complete = np.isfinite(pts).all(axis=(1, 2))
    if not complete.any():
        raise InvalidDataError(f"{take.source}: no frame has every marker; fill gaps first")
    neutral, nf = geo.neutral, None
    if neutral is None:
        nf = int(np.flatnonzero(complete)[0]) if neutral_frame is None else int(neutral_frame)
        if not 0 <= nf < T:
            raise InvalidDataError(f"neutral frame {nf} is outside the take's frames 0..{T - 1}")
        if not complete[nf]:
            raise InvalidDataError(f"{take.source}: neutral frame {nf} has missing markers; choose another")
        neutral = pts[nf]
        log(f"source neutral: frame {nf}")
    feats = np.arange(pts.shape[1])
    if source_rig is not None and not (isinstance(features, str) and features == "all"):
        feats = resolve_features(features, source_rig.n_vertices, source_rig.landmarks, who=source_rig.name)
    cand = np.flatnonzero(complete)
    if k > len(cand):
        raise InvalidDataError(f"k = {k} is more than the {len(cand)} complete frames of {take.source}")
    X = (pts[cand][:, feats] - neutral[feats]).reshape(len(cand), -1)
    frames = cand[np.asarray(select_keyshapes(X, k, method), dtype=int)]
    rms = reconstruction_error(X, np.searchsorted(cand, frames))         # in the points' unit
    motion = float(np.sqrt(np.mean(X**2)))                                # the take's RMS motion
    err = rms / motion if motion > 0 else 0.0
    unit = source_rig.unit if take.kind == "weights" and source_rig is not None else take.unit
    log(f"selected {len(frames)} keyshapes with {method} in {time.perf_counter() - t0:.2f} s")
    log(figure_line("key_reconstruction", 100 * err, f"choose more keyshapes (--k, now {len(frames)}), or select "
                    "them from a take with every expression the performance uses") + f" ({_length(rms, unit)} RMS)")
    chosen = sorted(frames.tolist())
    basis = basis_names = None
    if take.kind == "weights":
        basis, basis_names = take.weights[chosen], [normalize_name(n) for n in take.names]
    return KeySelection(chosen, geo, neutral, float(err), method, nf, basis, basis_names, float(rms), unit)


def _length(value: float, unit: str | None) -> str:
    """``value`` in ``unit`` as millimetres when the unit is known (``"0.83 mm"``), else with its unit."""
    from ..units import mm_per_unit

    try:
        return f"{value * mm_per_unit(unit):.3g} mm"
    except (InvalidDataError, KeyError, TypeError, ValueError):    # no length unit (px, none): as it is
        return f"{value:.3g} {unit or 'units'}"


def compose_keys(rig: Rig, *, log: Callable[..., None] = _quiet) -> Rig:
    """The 83 composed emotion x viseme key-models (and the pure emotions) of an ARKit-style rig,
    as a rig whose shapes are ``emotion_viseme`` (Pyun Sec. 2; the pure neutral is the rig's own).

    The rig's :attr:`~faceretarget.rig.Rig.basis` gives each key-model as the ARKit weights it is
    composed from: emotion + viseme (the pure visemes and emotions exactly; a composed key-model's
    geometry differs from that sum where the composition keeps the viseme whole, and the log says
    by how much), so a take cloned onto them can be written as Live Link Face curves.
    """
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        labels, verts = build_key_models(rig)
    for c in caught:
        log(f"warning: {c.message}")
    keep = [i for i, lab in enumerate(labels) if lab != "neutral"]
    safe = [labels[i].replace("+", "_") for i in keep]
    names = list(ARKIT_NAMES)
    E = np.stack([weight_vector(EMOTIONS[e], names) for e in EMOTIONS])
    V = np.stack([weight_vector(VISEMES[v], names) for v in VISEMES])
    U = np.concatenate([(E[:, None] + V[None]).reshape(-1, len(names)), E])[keep]   # build_key_models' order
    D = verts[keep] - rig.neutral.vertices
    S = rig.evaluate(rig.map_weights(names, U, warn=False)) - rig.neutral.vertices
    off = float(np.linalg.norm(D - S) / max(np.linalg.norm(D), 1e-300))
    log(f"key_weights: each key-model as its emotion + viseme ARKit weights; the composition moves the "
        f"key-models {100 * off:.1f} % of their motion away from that plain sum (a Live Link Face CSV plays the sum)")
    return Rig(rig.neutral, safe, D, rig.unit, rig.landmarks, None, f"{rig.name}:composed", U, names)
