"""Length units: the one table of units a rig, take or head pose may carry.

Everything that has a length says its unit with one of these names (aliases such as
``"centimetre"`` or ``"meters"`` are normalised by :func:`normalize_unit`).  Head poses are always
in metres (:class:`~faceretarget.headpose.HeadPose`); rigs and point takes keep the unit they came
in, and :func:`scale` converts.
"""

from __future__ import annotations

import numpy as np

from .errors import InvalidDataError

__all__ = ["UNIT_TO_MM", "normalize_unit", "mm_per_unit", "scale", "guess_unit"]

#: Millimetres per unit for the units a rig may carry.
UNIT_TO_MM: dict[str, float] = {"mm": 1.0, "cm": 10.0, "m": 1000.0, "in": 25.4}

_ALIASES = {"millimeter": "mm", "millimetre": "mm", "millimeters": "mm", "millimetres": "mm",
            "centimeter": "cm", "centimetre": "cm", "centimeters": "cm", "centimetres": "cm",
            "meter": "m", "metre": "m", "meters": "m", "metres": "m", "inch": "in", "inches": "in"}


def normalize_unit(unit: str, *, what: str = "unit") -> str:
    """``"mm"``, ``"cm"``, ``"m"`` or ``"in"`` for any spelling of them (case-insensitive).

    >>> normalize_unit("Centimetres")
    'cm'
    """
    u = str(unit).strip().lower()
    u = _ALIASES.get(u, u)
    if u not in UNIT_TO_MM:
        raise InvalidDataError(f"{what}: unknown unit {unit!r}, use one of {', '.join(UNIT_TO_MM)}")
    return u


def mm_per_unit(unit) -> float:
    """Millimetres per ``unit``: a unit name (any spelling :func:`normalize_unit` takes), a positive
    number (already millimetres per unit), or an object that carries a ``unit`` (a Rig)."""
    if hasattr(unit, "unit") and not isinstance(unit, str):
        unit = unit.unit
    if isinstance(unit, str):
        return UNIT_TO_MM[normalize_unit(unit)]
    u = float(unit)
    if not (np.isfinite(u) and u > 0):
        raise InvalidDataError(f"millimetres per unit must be positive, got {unit}")
    return u


def scale(src: str, dst: str) -> float:
    """Factor that converts lengths in ``src`` to ``dst``.

    >>> scale("cm", "m")
    0.01
    """
    return mm_per_unit(src) / mm_per_unit(dst)


def guess_unit(vertices: np.ndarray) -> str:
    """Guess a face mesh's unit from its size: a human face is about 15-40 cm across.

    A bounding-box diagonal under 2 is taken as metres, under 150 as centimetres, else millimetres.
    Pass the unit explicitly when the guess is wrong (a toy character, a whole body).
    """
    v = np.asarray(getattr(vertices, "vertices", vertices), dtype=np.float64)
    with np.errstate(over="ignore", invalid="ignore"):  # an absurd 1e308 coordinate: just "mm"
        d = float(np.linalg.norm(v.max(0) - v.min(0)))
    if d < 2.0:
        return "m"
    if d < 150.0:
        return "cm"
    return "mm"
