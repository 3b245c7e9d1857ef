"""Ground truth of protocol P1 (paired rigs, see ``EVALUATION.md``) and its capture noise.

:func:`rig_animation` drives a rig with named ARKit weights (``Rig.map_weights`` gives a whole
weight to both halves of a split shape and 0 to shapes the weights lack), and :class:`ArkitPairing`
does so for a source and a target rig at once; :func:`add_capture_noise` adds P1's Gaussian noise.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import InvalidDataError
from ..rig import Rig
from ..units import mm_per_unit

__all__ = ["add_capture_noise", "rig_animation", "keymodels_from_weights", "ArkitPairing"]




def add_capture_noise(points, sigma_mm: float, unit, seed: int = 0) -> np.ndarray:
    """``points`` plus Gaussian noise of ``sigma_mm`` millimetres per coordinate (deterministic).

    ``unit`` is the points' unit (name, millimetres per unit, or a Rig); the same ``seed`` and shape
    give the same noise.  P1 uses 0.5 mm on the source feature points.
    """
    p = np.asarray(points, dtype=np.float64)
    if not (np.isfinite(sigma_mm) and sigma_mm >= 0):
        raise InvalidDataError(f"noise sigma must be a non-negative number of mm, got {sigma_mm}")
    if sigma_mm == 0:
        return p.copy()
    rng = np.random.default_rng(seed)
    return p + rng.normal(0.0, sigma_mm / mm_per_unit(unit), size=p.shape)


# ---------------------------------------------------------------------------------------- ground truth
def rig_animation(rig: Rig, names, weights, *, warn: bool = False) -> np.ndarray:
    """Drive ``rig`` with named weights (any spelling, e.g. Live Link Face PascalCase): ``(T, V, 3)``.

    ``Rig.map_weights`` does the P1 name map: a whole ARKit weight (``browInnerUp``) drives both
    halves of a split shape, the rig's extra shapes get 0, and channels the rig lacks (``tongueOut``
    on a rig without it) are dropped, silently unless ``warn``.
    """
    w = np.asarray(weights, dtype=np.float64)
    if w.ndim == 1:
        w = w[None]
    if w.ndim != 2 or w.shape[1] != len(names):
        raise InvalidDataError(f"weights must be (T, {len(names)}) for {len(names)} names, got {w.shape}")
    return rig.evaluate(rig.map_weights(list(names), w, source="weights", warn=warn))


def keymodels_from_weights(rig: Rig, names, U) -> np.ndarray:
    """Key-models ``(N, V, 3)``: the rig at each weight vector ``u_i`` (rows of ``U``, named ``names``)."""
    return rig_animation(rig, names, U)


@dataclass
class ArkitPairing:
    """Two rigs with ARKit semantics driven by the same weights (P1 ground truth).

    ``source`` and ``target`` are :class:`Rig` objects whose names are ARKit camelCase after
    normalisation; :meth:`animations` gives ``A(t)`` and ``B(t)``, :meth:`keymodels` the source and
    target key-models of weight vectors ``u_i`` (a perfectly consistent artist).
    """

    source: Rig
    target: Rig

    def animations(self, names, weights) -> tuple[np.ndarray, np.ndarray]:
        """``(A, B)``: source and target animation ``(T, Vs, 3)``, ``(T, Vt, 3)``."""
        return rig_animation(self.source, names, weights), rig_animation(self.target, names, weights)

    def keymodels(self, names, U) -> tuple[np.ndarray, np.ndarray]:
        """Source and target key-models ``(N, Vs, 3)``, ``(N, Vt, 3)`` for weight vectors ``U``."""
        return keymodels_from_weights(self.source, names, U), keymodels_from_weights(self.target, names, U)

    def swapped(self) -> ArkitPairing:
        """The same pair with source and target exchanged."""
        return ArkitPairing(self.target, self.source)
