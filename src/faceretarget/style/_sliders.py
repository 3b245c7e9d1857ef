"""Expression sliders (Chuang 2004, Ch. 5, Eq. 5.1): per-emotion keyshape sets blended over time.

Instead of one set of target keyshapes, the artist models one set per emotion: the same ``N``
keyshapes (same mouth shapes, same source correspondence) made happy, angry, sad...  The source
take is retargeted once, to non-negative keyshape weights ``w(t)`` (Chuang Eq. 3.1/3.2, solved for
the whole take by :func:`faceretarget.numerics.solve_nnls`); the weights are played on every
emotion's target set, and the results are blended with barycentric weights ``alpha_e(t)``
(non-negative, summing to 1), given as constants or curves over time::

    y(t) = sum_e alpha_e(t) [ T_e0 + sum_i w_i(t) (T_ei - T_e0) ]                       (Eq. 5.1)

``T_e0`` is emotion ``e``'s rest shape (the neutral face with that emotion).  The target sets may be
meshes ``(N + 1, V, 3)``, feature points, or rig weight vectors ``(N + 1, K)``: any trailing shape,
row 0 the rest.  :class:`AlphaCurves` builds ``alpha(t)`` from keys.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

from ..base import Model
from ..errors import InvalidDataError
from ..numerics import smoothstep, solve_nnls

__all__ = ["ExpressionSliders", "AlphaCurves", "alpha_curves"]




class AlphaCurves:
    """Barycentric emotion weights over time from constants or keyed curves.

    Parameters
    ----------
    emotions : sequence of str
        The columns, in order.
    keys : mapping of str to float or sequence of (time, value)
        Per emotion a constant, or keys ``[(t0, v0), (t1, v1), ...]`` (seconds, any order); between
        keys the value is interpolated (``interp``), before the first and after the last it holds.
        Emotions not given are 0.
    interp : {"linear", "smooth"}
        Linear, or smoothstep (ease in and out) between keys.

    Examples
    --------
    >>> a = AlphaCurves(["neutral", "angry"], {"neutral": 1.0, "angry": [(0.0, 0.0), (1.0, 3.0)]})
    >>> a([0.0, 1.0]).round(3)
    array([[1.  , 0.  ],
           [0.25, 0.75]])
    """

    def __init__(self, emotions: Sequence[str], keys: Mapping[str, float | Sequence], interp: str = "linear"):
        self.emotions = [str(e) for e in emotions]
        if interp not in ("linear", "smooth"):
            raise InvalidDataError(f"alpha curve interpolation must be 'linear' or 'smooth', got '{interp}'")
        self.interp = interp
        unknown = [k for k in keys if k not in self.emotions]
        if unknown:
            raise InvalidDataError(f"alpha keys for unknown emotion(s) {', '.join(unknown)}; "
                                   f"have {', '.join(self.emotions)}")
        self.keys: dict[str, tuple[np.ndarray, np.ndarray]] = {}
        for e, spec in keys.items():
            if np.isscalar(spec):
                t, v = np.array([0.0]), np.array([float(spec)])
            else:
                arr = np.asarray(spec, np.float64)
                if arr.ndim != 2 or arr.shape[1] != 2 or len(arr) == 0:
                    raise InvalidDataError(f"alpha keys of '{e}' must be a number or (time, value) pairs")
                arr = arr[np.argsort(arr[:, 0], kind="stable")]
                t, v = arr[:, 0], arr[:, 1]
            if not (np.isfinite(t).all() and np.isfinite(v).all()):
                raise InvalidDataError(f"alpha keys of '{e}' are not finite")
            if (v < 0).any():
                raise InvalidDataError(f"alpha keys of '{e}' must be >= 0 (barycentric weights)")
            self.keys[e] = (t, v)

    def raw(self, times) -> np.ndarray:
        """Un-normalised values ``(T, E)`` at ``times``."""
        t = np.asarray(times, np.float64).reshape(-1)
        out = np.zeros((len(t), len(self.emotions)))
        for j, e in enumerate(self.emotions):
            if e not in self.keys:
                continue
            kt, kv = self.keys[e]
            if len(kt) == 1:
                out[:, j] = kv[0]
                continue
            if self.interp == "linear":
                out[:, j] = np.interp(t, kt, kv)
            else:
                k = np.clip(np.searchsorted(kt, t, side="right") - 1, 0, len(kt) - 2)
                f = smoothstep((t - kt[k]) / np.maximum(kt[k + 1] - kt[k], 1e-300))
                out[:, j] = (1 - f) * kv[k] + f * kv[k + 1]
        return out

    def __call__(self, times) -> np.ndarray:
        """Barycentric weights ``(T, E)``: :meth:`raw` divided by its sum at every time."""
        r = self.raw(times)
        tot = r.sum(1)
        if (tot <= 0).any():
            t = float(np.asarray(times, np.float64).reshape(-1)[int(np.flatnonzero(tot <= 0)[0])])
            raise InvalidDataError(f"alpha curves are all 0 at t={t:.3f} s; give some emotion a weight there")
        return r / tot[:, None]


def alpha_curves(times, emotions: Sequence[str], keys: Mapping[str, float | Sequence],
                 interp: str = "linear") -> np.ndarray:
    """``AlphaCurves(emotions, keys, interp)(times)``: barycentric weights ``(T, E)``."""
    return AlphaCurves(emotions, keys, interp)(times)


class ExpressionSliders(Model):
    """Retarget onto several emotions' keyshape sets and blend them with ``alpha(t)`` (Eq. 5.1).

    Parameters
    ----------
    upper : float or (N,) float, optional
        Upper bound of the keyshape weights (``solve_nnls``'s ``upper``).
    l2 : float
        Ridge weight of the weight solve.
    smooth : float
        Temporal smoothness weight of the weight solve (consecutive frames of one take).

    Attributes
    ----------
    emotions_ : list of str
    source_neutral_ : (D,) float
    source_keys_ : (D, N) float
        Source keyshape displacements, one column per keyshape.
    target_rest_ : (E, Dt) float
    target_disp_ : (E, N, Dt) float
    target_shape_ : tuple
        Trailing shape of one target frame.
    """

    def __init__(self, upper=None, l2: float = 0.0, smooth: float = 0.0):
        self.upper = upper
        self.l2 = l2
        self.smooth = smooth

    def fit(self, source_keys, targets: Mapping[str, np.ndarray]) -> ExpressionSliders:
        """Store the keyshape sets; returns self.

        Parameters
        ----------
        source_keys : (N + 1, ...) float
            Row 0 the source neutral, rows 1..N the source keyshapes (feature points, weights...).
        targets : mapping of emotion to (N + 1, ...) float
            Per emotion its target set: row 0 the rest shape with that emotion, rows 1..N the
            keyshapes in the same order as ``source_keys``; all of one trailing shape.
        """
        S = np.asarray(source_keys, np.float64)
        if S.ndim < 2 or len(S) < 2:
            raise InvalidDataError(f"source keys must be (N + 1, ...) with N >= 1, got {S.shape}")
        if not targets:
            raise InvalidDataError("give at least one emotion's target keyshape set")
        n = len(S)
        Sf = S.reshape(n, -1)
        shape = None
        rest, disp = [], []
        for e, T in targets.items():
            T = np.asarray(T, np.float64)
            if len(T) != n:
                raise InvalidDataError(f"emotion '{e}': {len(T)} target keyshapes (with the rest) for {n} source ones")
            if shape is None:
                shape = T.shape[1:]
            elif T.shape[1:] != shape:
                raise InvalidDataError(f"emotion '{e}': target keyshapes are {T.shape[1:]}, others {shape}")
            if not np.isfinite(T).all():
                raise InvalidDataError(f"emotion '{e}': target keyshapes are not finite")
            Tf = T.reshape(n, -1)
            rest.append(Tf[0])
            disp.append(Tf[1:] - Tf[0])
        if not np.isfinite(Sf).all():
            raise InvalidDataError("source keyshapes are not finite")
        self.emotions_ = [str(e) for e in targets]
        self.source_neutral_ = Sf[0]
        self.source_keys_ = (Sf[1:] - Sf[0]).T
        self.source_shape_ = tuple(S.shape[1:])
        self.target_rest_ = np.stack(rest)
        self.target_disp_ = np.stack(disp)
        self.target_shape_ = tuple(shape)
        return self

    def weights(self, frames) -> np.ndarray:
        """Non-negative keyshape weights ``(T, N)`` of source frames ``(T, ...)`` (Eq. 3.1/3.2)."""
        self._check_fitted()
        F = np.asarray(frames, np.float64)
        F = F.reshape(len(F), -1)
        if F.shape[1] != self.source_neutral_.size:
            raise InvalidDataError(f"source frames have {F.shape[1]} values but the keyshapes {self.source_neutral_.size}")
        return solve_nnls(self.source_keys_, F - self.source_neutral_, upper=self.upper, l2=self.l2,
                          smooth=self.smooth)

    def play(self, W: np.ndarray, emotion: str) -> np.ndarray:
        """Weights ``W`` ``(T, N)`` played on one emotion's target set: ``(T, ...)``."""
        self._check_fitted()
        if emotion not in self.emotions_:
            raise InvalidDataError(f"unknown emotion '{emotion}'; have {', '.join(self.emotions_)}")
        e = self.emotions_.index(emotion)
        out = self.target_rest_[e] + np.asarray(W, np.float64) @ self.target_disp_[e]
        return out.reshape((len(out),) + self.target_shape_)

    def retarget(self, frames, emotion: str) -> np.ndarray:
        """Source frames retargeted onto one emotion's set: ``(T, ...)``."""
        return self.play(self.weights(frames), emotion)

    def blend(self, W: np.ndarray, alpha, times=None) -> np.ndarray:
        """Eq. 5.1 for given keyshape weights ``W`` ``(T, N)``.

        Parameters
        ----------
        W : (T, N) float
        alpha : (E,) or (T, E) float, mapping of emotion to constant / keys, or AlphaCurves
            Barycentric emotion weights (a vector or per-frame rows; normalised to sum 1), or
            curves evaluated at ``times``.
        times : (T,) float, optional
            Frame times, needed for curves.

        Returns
        -------
        (T, ...) float
        """
        self._check_fitted()
        W = np.asarray(W, np.float64)
        T = len(W)
        if isinstance(alpha, (AlphaCurves, Mapping)):
            curves = alpha if isinstance(alpha, AlphaCurves) else AlphaCurves(self.emotions_, alpha)
            if times is None:
                raise InvalidDataError("alpha curves need the frame times")
            extra = [e for e in curves.emotions if e not in self.emotions_]
            if extra:
                raise InvalidDataError(f"alpha curves name emotion(s) without a target set: {', '.join(extra)}")
            ac = curves(times)
            if len(ac) != T:
                raise InvalidDataError(f"{len(ac)} frame times for {T} frames")
            a = np.zeros((T, len(self.emotions_)))
            for j, e in enumerate(curves.emotions):
                a[:, self.emotions_.index(e)] = ac[:, j]
        else:
            a = np.asarray(alpha, np.float64)
            if a.ndim == 1:
                a = np.broadcast_to(a, (T, len(a)))
            if a.shape != (T, len(self.emotions_)):
                raise InvalidDataError(f"alpha must be ({len(self.emotions_)},) or ({T}, {len(self.emotions_)}), "
                                       f"got {a.shape}")
            if (a < 0).any() or not np.isfinite(a).all():
                raise InvalidDataError("alpha weights must be finite and >= 0")
            tot = a.sum(1, keepdims=True)
            if (tot <= 0).any():
                raise InvalidDataError(f"alpha weights sum to 0 at frame {int(np.flatnonzero(tot[:, 0] <= 0)[0])}")
            a = a / tot
        # sum_e a_e (rest_e + W disp_e) = a @ rest + sum_e a_e (W @ disp_e)
        out = a @ self.target_rest_
        for e in range(len(self.emotions_)):
            if np.any(a[:, e] != 0):
                out += a[:, e:e + 1] * (W @ self.target_disp_[e])
        return out.reshape((T,) + self.target_shape_)

    def transform(self, frames, alpha, times=None) -> np.ndarray:
        """Retarget source frames and blend the emotions (Eq. 5.1): ``(T, ...)``."""
        return self.blend(self.weights(frames), alpha, times)
