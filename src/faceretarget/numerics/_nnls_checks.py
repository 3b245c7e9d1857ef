"""Input checks of :func:`~._nnls_solve.solve_nnls` and of the weight filter: shapes, finite values,
bounds, weights of the terms."""

from __future__ import annotations

import numpy as np

from ..errors import InvalidDataError


def _as_float(name: str, value) -> float:
    v = float(value)
    if not np.isfinite(v) or v < 0:
        raise InvalidDataError(f"{name} must be a finite number >= 0, got {value}")
    return v


def _check_inputs(K, F, upper, mask):
    K = np.asarray(K, dtype=np.float64)
    if K.ndim != 2 or K.shape[0] == 0 or K.shape[1] == 0:
        raise InvalidDataError(f"keyshape matrix K must be (D, N) with D, N > 0, got shape {K.shape}")
    K = np.ascontiguousarray(K)                                 # (frames x features) @ K runs faster
    D, N = K.shape
    bad = None if np.isfinite(K).all() else ~np.isfinite(K).all(axis=0)
    if bad is not None:
        raise InvalidDataError(f"keyshape matrix K has NaN or infinite values in key column(s) "
                               f"{', '.join(map(str, np.flatnonzero(bad)[:10]))}")
    F = np.asarray(F, dtype=np.float64)
    single = F.ndim == 1
    if single:
        F = F[None, :]
    if F.ndim != 2 or F.shape[1] != D:
        raise InvalidDataError(f"frames F must be (T, {D}) to match K ({D} rows, {N} keys), "
                               f"got shape {F.shape if not single else F.shape[1:]}")
    T = len(F)
    rows = None
    if mask is not None:
        m = np.asarray(mask)
        if single and m.ndim == 1:
            m = m[None, :]
        if m.ndim != 2 or m.shape[0] != T or m.shape[1] == 0 or D % m.shape[1]:
            raise InvalidDataError(f"mask must be (T, D) = ({T}, {D}) or per marker (T, P) with D a multiple "
                                   f"of P, got shape {np.shape(mask)}")
        rows = np.repeat(m.astype(bool), D // m.shape[1], axis=1)
    if rows is not None:
        _check_finite(F, rows)
    else:
        # without a mask F is checked through F K ((T, N) values instead of (T, D),
        # :func:`~._nnls_solve._solve_frames`): a NaN or inf reaches every key that moves its feature; the
        # features no key moves are checked here
        idle = ~K.any(axis=1)
        if idle.any():
            _check_finite(F[:, idle], None)
    ub = None
    if upper is not None:
        ub = np.broadcast_to(np.asarray(upper, dtype=np.float64), (N,)).copy() if np.ndim(upper) == 0 \
            else np.asarray(upper, dtype=np.float64)
        if ub.shape != (N,):
            raise InvalidDataError(f"upper must be a scalar or have one bound per key ({N}), "
                                   f"got shape {ub.shape}")
        if np.isnan(ub).any() or (ub <= 0).any():
            raise InvalidDataError("upper bounds must be > 0 (inf for none); drop a key to switch it off")
        if np.isinf(ub).all():
            ub = None
    return K, F, single, rows, ub


def _check_finite(F: np.ndarray, rows: np.ndarray | None) -> None:
    """Raise naming the first frame of ``F`` (T, D) with a NaN or infinite value where ``rows`` (T, D) is
    true (everywhere when None)."""
    bad = ~np.isfinite(F) if rows is None else (~np.isfinite(F) & rows)
    if bad.any():
        frames = np.flatnonzero(bad.any(axis=1))
        raise InvalidDataError(f"frame {frames[0]} has NaN or infinite feature values"
                               + (f" ({len(frames)} frames in all)" if len(frames) > 1 else "")
                               + (" where the mask says they are present" if rows is not None else "")
                               + "; mark missing markers with mask=")


def _check_options(l2, l1, smooth, tol, backend) -> tuple[float, float, float, float]:
    """Validated weights of the terms ``l2``, ``l1``, ``smooth`` and tolerance ``tol`` of
    :func:`~._nnls_solve.solve_nnls`.

    Raises
    ------
    faceretarget.errors.InvalidDataError
        A negative or non-finite weight, a non-positive tolerance or an unknown backend.
    """
    l2, l1, smooth = _as_float("l2", l2), _as_float("l1", l1), _as_float("smooth", smooth)
    tol = float(tol)
    if backend not in ("auto", "numpy", "numba"):
        raise InvalidDataError(f"unknown backend '{backend}', use auto, numpy or numba")
    if not tol > 0:
        raise InvalidDataError(f"tol must be > 0, got {tol}")
    return l2, l1, smooth, tol
