"""Check an artist's target keyshapes against the mapping the others imply (Chuang leaves it as future work).

Retargeting assumes the target keyshapes relate to each other as the source keyshapes do: if
source key ``j`` is (nearly) a blend of other source keys, its target counterpart should be (nearly)
the same blend of their target counterparts.  For every key ``j``::

    c_j = argmin_{c >= 0} || sum_{i != j} c_i (S_i - S_0) - (S_j - S_0) ||       (source side)
    source_residual_j = || S-blend - S_j || / || S_j - S_0 ||
    target_error_j    = || P_j - (B_j - B_0) || / max(|| B_j - B_0 ||, || P_j ||),  P_j = sum_{i != j} c_ij (B_i - B_0)

A key the source explains well (small ``source_residual``) whose target counterpart is far from
its prediction (large ``target_error``) disagrees with the rest of the artist's mapping: a swapped
file, a keyshape modelled from the wrong frame, a sculpt at the wrong strength.  A key the source
cannot explain (it is the only one of its kind) cannot be checked and is reported as such.

Flag rule (documented defaults): among keys with ``source_residual <= checkable = 0.5``, flag
``target_error > max(ratio * source_residual, min_error, outlier * median target_error)`` with
``ratio = 3``, ``min_error = 0.35`` and ``outlier = 3``.  The median term stops two characters of
different design (whose keys relate a little differently everywhere) from being flagged wholesale:
a flag means a key disagrees much more than the others do.
For a perfectly consistent artist (both sides the same linear blends of one set of sliders) the
target error stays within a small multiple of the source residual, so nothing is flagged.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import InvalidDataError, MissingShapeError
from ..numerics import solve_nnls
from ..rig import Rig, resolve_features

__all__ = ["ConsistencyReport", "check_consistency"]


@dataclass
class ConsistencyReport:
    """Per-key results of :func:`check_consistency`.

    Attributes
    ----------
    names : list of str
    source_residual : (N,) float
        How badly the other source keys explain each source key (0 = exactly).
    target_error : (N,) float
        How far each target key is from the blend the source implies.
    checkable : (N,) bool
        Keys the source explains well enough to check.
    flagged : (N,) bool
    explained_by : list of list of (str, float)
        The largest coefficients of each key's source blend.
    """

    names: list[str]
    source_residual: np.ndarray
    target_error: np.ndarray
    checkable: np.ndarray
    flagged: np.ndarray
    explained_by: list[list[tuple[str, float]]]

    @property
    def flagged_names(self) -> list[str]:
        return [n for n, f in zip(self.names, self.flagged, strict=True) if f]

    def table(self) -> str:
        """A readable report, worst keys first."""
        order = np.argsort(-(self.target_error - self.source_residual))
        w = max(8, *(len(n) for n in self.names))
        lines = [f"{'keyshape':<{w}}  source_residual  target_error  verdict        predicted from",
                 "-" * (w + 72)]
        for i in order:
            verdict = "DISAGREES" if self.flagged[i] else ("ok" if self.checkable[i] else "unique (unchecked)")
            parts = ", ".join(f"{n} {c:.2f}" for n, c in self.explained_by[i][:3])
            lines.append(f"{self.names[i]:<{w}}  {100 * self.source_residual[i]:14.1f}%  "
                         f"{100 * self.target_error[i]:11.1f}%  {verdict:<14} {parts}")
        n = int(self.flagged.sum())
        lines.append(f"{n} of {len(self.names)} target keyshapes disagree with the mapping implied by the others"
                     + (f": {', '.join(self.flagged_names)}" if n else ""))
        return "\n".join(lines)


def check_consistency(source_keys: Rig, target_keys: Rig, *, features="auto", ratio: float = 3.0,
                      min_error: float = 0.35, checkable: float = 0.5, outlier: float = 3.0) -> ConsistencyReport:
    """Flag target keyshapes that disagree with the mapping implied by the others (see the module).

    Parameters
    ----------
    source_keys, target_keys : Rig
        Paired by name (every source key needs a target key).
    features : ``"auto"``, ``"landmarks"``, ``"all"`` or (P,) int
        Source points compared (``"auto"``: the landmarks when the source has them).
    ratio, min_error, checkable, outlier : float
        The flag rule.
    """
    names = list(source_keys.names)
    if len(names) < 3:
        raise InvalidDataError(f"{source_keys.name}: a consistency check needs at least 3 keyshapes")
    missing = [n for n in names if n not in target_keys]
    if missing:
        raise MissingShapeError(f"{target_keys.name}: no target keyshape for {', '.join(missing[:8])}")
    spec = features
    if isinstance(spec, str) and spec == "auto":
        spec = "landmarks" if source_keys.landmarks is not None and len(source_keys.landmarks) else "all"
    idx = resolve_features(spec, source_keys.n_vertices, source_keys.landmarks, who=source_keys.name)
    S = source_keys.deltas[:, idx].reshape(len(names), -1)                   # (N, D)
    T = np.stack([target_keys.deltas[target_keys.index(n)].reshape(-1) for n in names])
    N = len(names)
    sn = np.linalg.norm(S, axis=1)
    tn = np.linalg.norm(T, axis=1)
    res = np.zeros(N)
    terr = np.zeros(N)
    expl = []
    for j in range(N):
        others = np.flatnonzero(np.arange(N) != j)
        c = solve_nnls(S[others].T, S[j])
        res[j] = np.linalg.norm(c @ S[others] - S[j]) / max(sn[j], 1e-300)
        pred = c @ T[others]
        # symmetric in the key and its prediction, so a key sculpted too strong and its twins that
        # are predicted from it score alike
        terr[j] = np.linalg.norm(pred - T[j]) / max(tn[j], np.linalg.norm(pred), 1e-300)
        top = np.argsort(-c)[:4]
        expl.append([(names[others[i]], float(c[i])) for i in top if c[i] > 1e-6])
    ok = res <= checkable
    typical = float(np.median(terr[ok])) if ok.any() else 0.0
    flagged = ok & (terr > np.maximum(np.maximum(ratio * res, min_error), outlier * typical))
    return ConsistencyReport(names, res, terr, ok, flagged, expl)
