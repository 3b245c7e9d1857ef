"""Standard key-model sets for two ARKit-style rigs (EVALUATION.md P1, and the ``clone --keys`` CLI).

A key-model set is a list of ARKit weight vectors ``u_i``; the source key-model ``i`` is the source
rig at ``u_i`` and the target key-model ``i`` the target rig at ``u_i`` (a perfectly consistent
artist).  The neutral is always the rigs' own neutral and is not listed.

``arkit``       each ARKit shape the source rig has, alone at weight 1 (the keys span every take)
``emotions6``   the five non-neutral emotions of :data:`~faceretarget.cloning.tables.EMOTIONS`
``visemes13``   the 13 visemes of :data:`~faceretarget.cloning.tables.VISEMES`
``combined84``  6 emotions x 13 visemes (weights added, clipped to [0, 1]) + the 6 pure emotions;
                the pure neutral is the rest face, so 83 key-models besides it
``rom-K``       K frames of a range-of-motion take chosen by a keyshape selection method
                on the source rig's feature points (default pivoted QR: the set that serves a solve
                inside a weight range best, P1 worst case 9.3 % vs 12.0 % for PCA extrema, 13.2 % for
                NNLS greedy and k-means at [-1, 2])
"""

from __future__ import annotations

import re

import numpy as np

from ..errors import InvalidDataError
from ..names import ARKIT_NAMES
from ..numerics import select_keyshapes
from ..performance import Performance
from ..rig import Rig
from ._tables import combined_weight_vectors, emotion_vectors, viseme_vectors

__all__ = ["KEYSETS", "keyset_weights", "keymodel_rig", "keymodel_pair"]

KEYSETS = ("arkit", "emotions6", "visemes13", "combined84", "rom-K")


def keyset_weights(spec: str, source: Rig, *, rom: Performance | None = None, features=None,
                   selection: str = "pivoted-qr") -> tuple[list[str], np.ndarray, list[str]]:
    """Weight vectors of a standard key-model set.

    Parameters
    ----------
    spec : str
        ``arkit``, ``emotions6``, ``visemes13``, ``combined84`` or ``rom-K`` (``rom-20``).
    source : Rig
        The source rig (decides which ARKit shapes exist, and drives the ROM take for ``rom-K``).
    rom : Performance, optional
        A weight take (range of motion) for ``rom-K``.
    features : (P,) int, optional
        Source feature points used to choose ROM frames (default: the rig's landmarks, else all).

    Returns
    -------
    labels : list of str
    U : (N, K) float
        One weight vector per key-model over ``names``.
    names : list of str
        The weight columns (ARKit names).
    """
    names = list(ARKIT_NAMES)
    if spec == "arkit":
        present = source.map_weights(names, np.eye(len(names)), warn=False)
        keep = [i for i in range(len(names)) if np.abs(present[i]).sum() > 0]
        return [names[i] for i in keep], np.eye(len(names))[keep], names
    if spec == "emotions6":
        labels, U = emotion_vectors(names)
    elif spec == "visemes13":
        labels, U = viseme_vectors(names)
    elif spec == "combined84":
        labels, U = combined_weight_vectors(names)
    else:
        m = re.fullmatch(r"rom-(\d+)", spec)
        if not m:
            raise InvalidDataError(f"unknown key-model set '{spec}', use one of {', '.join(KEYSETS)}")
        k = int(m.group(1))
        if rom is None or rom.weights is None:
            raise InvalidDataError(f"key-model set '{spec}' needs a range-of-motion weight take (--keys-from)")
        W = source.map_weights(rom.names, rom.weights, warn=False)
        idx = features if features is not None else source.landmarks
        D = source.deltas if idx is None else source.deltas[:, idx]          # only the feature points
        X = W @ D.reshape(source.n_shapes, -1)                               # (T, 3P) displacements
        frames = select_keyshapes(X, k, selection)
        Urom = np.zeros((len(frames), len(names)))
        col = {n: j for j, n in enumerate(rom.names)}
        from ..names import normalize_name

        for j, n in enumerate(names):
            for rn, c in col.items():
                if normalize_name(rn) == n:
                    Urom[:, j] = rom.weights[frames, c]
        labels = [f"frame{int(f):05d}" for f in frames]
        return labels, Urom, names
    keep = [i for i, lab in enumerate(labels) if np.abs(U[i]).sum() > 0]     # drop the rest face
    return [labels[i] for i in keep], U[keep], names


def keymodel_rig(rig: Rig, labels: list[str], U: np.ndarray, names: list[str], name: str | None = None) -> Rig:
    """The key-models of ``rig`` at weight vectors ``U`` as a Rig (neutral + one shape per label).

    Parameters
    ----------
    rig : Rig
    labels : list of str
        ``N`` key-model names.
    U : (N, M) float
        One weight vector per key-model over ``names``.
    names : list of str
        ``M`` shape names (ARKit).

    Returns
    -------
    Rig
        ``N`` shapes, ``rig.evaluate(U) - neutral``; :attr:`~faceretarget.rig.Rig.basis` ``U`` over
        ``names`` (so key weights ``W`` convert back to ``W @ U``).
    """
    W = rig.map_weights(names, U, warn=False)
    D = rig.evaluate(W) - rig.neutral.vertices
    return Rig(rig.neutral, list(labels), D, rig.unit, rig.landmarks, None, name or f"{rig.name}:keys",
               np.asarray(U, dtype=np.float64), list(names))


def keymodel_pair(source: Rig, target: Rig, spec: str, **kw) -> tuple[Rig, Rig, np.ndarray]:
    """Source and target key-model Rigs for a standard set, and the weight vectors ``U`` ``(N, 52)``
    (each Rig's :attr:`~faceretarget.rig.Rig.basis`, over the ARKit names)."""
    labels, U, names = keyset_weights(spec, source, **kw)
    return keymodel_rig(source, labels, U, names), keymodel_rig(target, labels, U, names), U
