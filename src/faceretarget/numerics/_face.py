"""Is this take a face?  Sizes, label vocabularies, presence and distance from the face centre.

A human face is about 150-300 mm across (the shared facial takes span 185-188 mm, c3d.org's
Facial-Sing with its head and neck markers 243 mm) and its markers have recognisable names (brow, eye, nose,
mouth, jaw...); a full-body capture spans 900-1,800 mm and its labels name the pelvis, knees and
ankles.  Keyshape selection, rigid head-motion removal and the solves all assume a face: fed a walking
take they return keyshapes of legs with a reconstruction error in the thousands of percent, and exit 0.

:func:`face_markers` looks at a marker take before any of that:

* a marker present in fewer than :data:`MIN_PRESENCE` of the frames, or whose median distance from the
  face centre (each frame's median marker) is more than :data:`FAR_RATIO` times the typical marker's,
  is a stray (an unlabelled reflection, a marker on the table) and is left out, named;
* what remains must span at most :data:`FACE_MAX_MM` (the median over frames of the largest distance
  between two markers), and its labels must not be a body's rather than a face's, else
  :class:`~faceretarget.errors.NotAFaceError` says what was found and what a face is.

The constants are properties of faces and bodies, not of any one file: the limit is twice the largest
face span seen and half the smallest full-body span.  :func:`face_mesh` checks meshes the same way by
the span of the part that moves (the face of a full-body character that only moves its face passes),
with a limit of :data:`MESH_FACE_MAX_MM`, since stylised faces are larger than human ones.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field

import numpy as np

from ..errors import InvalidDataError, NotAFaceError, excerpt
from ..names import marker_region
from ..units import mm_per_unit, normalize_unit

__all__ = ["FaceMarkers", "face_markers", "face_mesh", "FACE_MAX_MM", "MESH_FACE_MAX_MM", "MIN_PRESENCE",
           "FAR_RATIO"]

#: Largest span of a marker take taken for a face, mm.
FACE_MAX_MM = 500.0
#: Largest span of the moving part of a mesh taken for a face, mm (stylised characters have large heads).
MESH_FACE_MAX_MM = 1000.0
#: Markers present in fewer than this share of the frames are left out.
MIN_PRESENCE = 0.5
#: Markers whose median distance from the face centre exceeds this many times the median marker's are left out.
FAR_RATIO = 4.0
#: Frames measured (evenly spaced) for the span.
_SPAN_FRAMES = 200


@dataclass
class FaceMarkers:
    """What :func:`face_markers` found.

    Attributes
    ----------
    keep : (P,) bool
        The markers to use.
    dropped : dict of str to str
        Label -> why it is left out.
    span_mm : float
        Median over frames of the largest distance between two kept markers (NaN for 2-D points or an
        unknown scale).
    labels : dict of str to list of str
        Kept labels recognised as ``"face"`` or ``"body"`` places (:func:`~faceretarget.names.marker_region`).
    """

    keep: np.ndarray
    dropped: dict[str, str] = field(default_factory=dict)
    span_mm: float = float("nan")
    labels: dict[str, list[str]] = field(default_factory=dict)

    def message(self, source: str) -> str | None:
        """One line naming the markers left out and why, or None."""
        if not self.dropped:
            return None
        items = list(self.dropped.items())
        shown = "; ".join(f"{excerpt(k, bare=True)} ({v})" for k, v in items[:8])
        more = f"; and {len(items) - 8} more" if len(items) > 8 else ""
        return (f"{source}: {len(items)} marker(s) left out of selection and solve: {shown}{more}")


def _span(X: np.ndarray) -> float:
    """Median over (up to :data:`_SPAN_FRAMES`) frames of the largest distance between two present points."""
    T = len(X)
    idx = np.unique(np.linspace(0, T - 1, min(T, _SPAN_FRAMES)).round().astype(int)) if T else []
    spans = []
    for t in idx:
        q = X[t][np.isfinite(X[t]).all(axis=1)]
        if len(q) > 1:
            d = q[:, None, :] - q[None, :, :]
            spans.append(float(np.sqrt((d**2).sum(axis=2)).max()))
    return float(np.median(spans)) if spans else float("nan")


def face_markers(points: np.ndarray, labels: list[str] | None, unit: str | None, *, source: str = "take"
                 ) -> FaceMarkers:
    """Check that a marker take is a face and find its stray markers (module docstring).

    Parameters
    ----------
    points : (T, P, 3) or (T, P, 2) float
        Markers, NaN where missing.  2-D points (pixels) get the presence and distance checks only.
    labels : list of str, optional
    unit : str, optional
        The points' length unit; None is taken as millimetres (C3D's default); a unit that is not a
        length (``"px"``: tracked landmarks) leaves the span unchecked.
    source : str
        For messages.

    Returns
    -------
    FaceMarkers

    Raises
    ------
    NotAFaceError
        The take spans more than :data:`FACE_MAX_MM`, or its labels name body places and no face place.
    """
    X = np.asarray(points, dtype=np.float64)
    T, P = X.shape[:2]
    labels = list(labels) if labels else [f"marker {i}" for i in range(P)]
    present = np.isfinite(X).all(axis=2) if T else np.zeros((0, P), bool)
    share = present.mean(axis=0) if T else np.zeros(P)
    keep = share >= MIN_PRESENCE
    dropped: dict[str, str] = {}
    if keep.sum() < 3:                                  # too few well-seen markers to judge: keep what is seen
        keep = share > 0
    else:
        for i in np.flatnonzero(~keep):
            dropped[labels[i]] = f"present in {share[i]:.0%} of frames" if share[i] > 0 else "never present"
    if keep.sum() >= 3 and T:
        with np.errstate(invalid="ignore"), warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)             # frames without a marker: All-NaN
            centre = np.nanmedian(np.where(keep[None, :, None], X, np.nan), axis=1)       # (T, D)
            dist = np.linalg.norm(X - centre[:, None], axis=2)                           # (T, P)
            r = np.nanmedian(np.where(present, dist, np.nan), axis=0)
            typical = float(np.nanmedian(r[keep]))
        far = keep & (r > FAR_RATIO * typical) if typical > 0 else np.zeros(P, bool)
        if keep.sum() - far.sum() >= 3:
            for i in np.flatnonzero(far):
                dropped[labels[i]] = f"{r[i] / typical:.1f} times as far from the face centre as the typical marker"
            keep &= ~far
    kept = [labels[i] for i in np.flatnonzero(keep)]
    regions = {"face": [s for s in kept if marker_region(s) == "face"],
               "body": [s for s in kept if marker_region(s) == "body"]}
    out = FaceMarkers(keep, dropped, float("nan"), regions)
    mm = _mm(unit)
    if X.shape[2] == 3 and mm is not None:
        out.span_mm = _span(X[:, keep]) * mm
    bodyish = len(regions["body"]) >= max(3, 0.5 * len(kept)) and not regions["face"]
    if out.span_mm > FACE_MAX_MM or bodyish:
        found = (f"its {len(kept)} markers span {out.span_mm:,.0f} mm" if np.isfinite(out.span_mm)
                 else f"its {len(kept)} markers")
        if regions["body"]:
            found += f", labels name body places ({', '.join(excerpt(s, bare=True) for s in regions['body'][:6])}" \
                     f"{' ...' if len(regions['body']) > 6 else ''})"
        raise NotAFaceError(f"{source}: not a face: {found}; a face is 150-300 mm across (at most "
                            f"{FACE_MAX_MM:.0f} mm is taken for one) with markers on brows, eyes, nose, mouth "
                            "and jaw (a full-body capture? give the facial markers only)")
    return out


def _mm(unit: str | None) -> float | None:
    """Millimetres per ``unit`` (None: C3D's default, mm); None for a unit that is not a length."""
    if unit is None:
        return 1.0
    try:
        return mm_per_unit(normalize_unit(unit))
    except (InvalidDataError, ValueError, TypeError):
        return None


def face_mesh(vertices: np.ndarray, unit: str | None, *, source: str = "mesh", moving: np.ndarray | None = None
              ) -> float:
    """Check that a mesh take (or a set of key shapes) is a face by the span of its moving part.

    Parameters
    ----------
    vertices : (T, V, 3) float
        Frames of a mesh (or a neutral and its key shapes).
    unit : str, optional
        Their length unit (None, or not a length: no check, the scale is unknown).
    moving : (V,) float, optional
        How far each vertex moves (default: its range over the frames).

    Returns
    -------
    float
        The moving part's span, mm (NaN without a unit or motion).

    Raises
    ------
    NotAFaceError
        It spans more than :data:`MESH_FACE_MAX_MM`.
    """
    X = np.asarray(vertices, dtype=np.float64)
    mm = None if unit is None else _mm(unit)
    if mm is None or X.ndim != 3 or len(X) == 0:
        return float("nan")
    with np.errstate(invalid="ignore"):
        m = np.linalg.norm(np.nanmax(X, axis=0) - np.nanmin(X, axis=0), axis=1) if moving is None else np.asarray(moving)
    if not np.isfinite(m).any() or np.nanmax(m) <= 0:
        return float("nan")
    part = X[0][m > 0.1 * np.nanmax(m)]
    part = part[np.isfinite(part).all(axis=1)]
    span = float(np.ptp(part, axis=0).max()) * mm if len(part) else np.nan
    if span > MESH_FACE_MAX_MM:
        raise NotAFaceError(f"{source}: not a face: the part of the mesh that moves spans {span:,.0f} mm; a face is "
                            f"150-300 mm across (at most {MESH_FACE_MAX_MM:.0f} mm is taken for a stylised one; "
                            "a full-body animation?)")
    return span
