"""Stitch chosen database segments into one trajectory (Chuang 2004, Sec. 4.2.4).

For input segments ``i`` occupying output frames ``[a_i, b_i)``, and database segments with motion
frames ``[f0_i, f1_i]`` (inclusive, so consecutive database segments share their boundary frame):

1. **Time warp.**  Each database stretch ``f0_i..f1_i`` (usually the segment's own frames; see
   ``max_warp`` of :class:`HeadMotionDatabase`) is resampled (linear interpolation) to ``n_i + 1``
   points ``r_i``, with ``n_i = b_i - a_i``: frames ``a_i..b_i - 1`` take
   ``r_i[:n_i]`` and ``r_i[n_i]`` is where the segment would continue, the anchor of the next one.
   With ``head``, the first ``head_i`` output frames play the database at its own speed and only
   the rest is resampled onto ``f1_i``.
2. **Chain.**  Each segment is offset so it starts where the previous one would have continued
   (``offset_i = placed_{i-1}[n_{i-1}] - r_i[0]``): positions are continuous and the step across
   the join is the previous segment's own last step.  The velocity mismatch at the join,
   ``dv = v_prev_end - v_next_start`` (per frame), is absorbed by adding ``dv * k * exp(-k / tau)``
   to the new segment's ``k``-th frame: its first step then moves like the previous segment's
   last, and the correction fades within a few ``tau`` (``tau_velocity`` seconds).  With
   ``transition="before"`` the mirror-image correction is added to the frames before the join
   instead (their last step then moves like the new segment's first), ``"split"`` does half each.
3. **No drift.**  Chaining accumulates offsets.  The output is cut into sub-sequences (at phrase
   starts and at least every ``max_subsequence`` seconds); at each sub-sequence boundary the chained
   pose's distance from the database's own (unchained) pose there is measured, and a smooth
   monotone cubic (PCHIP) through those distances (0 at the first frame) is subtracted.  So each
   sub-sequence is warped to end exactly on real database poses, which spread around the database's
   mean pose, and the trajectory cannot wander off however long the input is.
4. **Smooth joins** (optional, ``smooth`` seconds, off by default): a Gaussian blended in around
   each join only.

Frames before the first segment (silence before speech starts) hold the first segment's first pose.
"""

from __future__ import annotations

import numpy as np
from scipy.interpolate import PchipInterpolator
from scipy.ndimage import gaussian_filter1d

__all__ = ["blend_segments"]


def _resample(motion: np.ndarray, f0: np.ndarray, f1: np.ndarray, n: np.ndarray,
              head: np.ndarray | None = None, step: float = 1.0) -> list[np.ndarray]:
    """For each segment the (n_i + 1, D) linear resampling of ``motion[f0_i..f1_i]``.

    With ``head``, the first ``head_i`` output frames play the database at its own speed (``step``
    database frames per output frame) and only the rest is warped to end on ``f1_i``.
    """
    counts = n + 1
    seg = np.repeat(np.arange(n.size), counts)
    k = (np.arange(counts.sum()) - np.repeat(np.cumsum(counts) - counts, counts)).astype(np.float64)
    if head is None:
        u = f0[seg] + (f1[seg] - f0[seg]) * k / n[seg]
    else:
        h = np.asarray(head, np.float64)[seg]
        uh = f0[seg] + step * h  # database frame reached at the end of the head
        tail = np.where(n[seg] > h, (k - h) / np.maximum(n[seg] - h, 1e-9), 0.0)
        u = np.where(k <= h, f0[seg] + step * k, uh + (f1[seg] - uh) * tail)
    i0 = np.clip(np.floor(u).astype(int), 0, len(motion) - 1)
    i1 = np.minimum(i0 + 1, len(motion) - 1)
    w = (u - i0)[:, None]
    r = motion[i0] * (1.0 - w) + motion[i1] * w
    return np.split(r, np.cumsum(counts)[:-1])


def blend_segments(motion: np.ndarray, f0: np.ndarray, f1: np.ndarray, a: np.ndarray, n_out: int, *,
                   fps: float, knots: np.ndarray | None = None, tau_velocity: float = 0.1,
                   smooth: float = 0.0, head: np.ndarray | None = None, step: float = 1.0,
                   transition: str = "after") -> tuple[np.ndarray, np.ndarray]:
    """Chain, warp and smooth database segments into one trajectory (module docstring).

    Parameters
    ----------
    motion : (F, D) float
        Database motion (all takes, concatenated), one row per database frame.
    f0, f1 : (N,) float
        First and last database frame (fractional allowed) of the motion played for each input
        segment, ``f1 > f0``.
    a : (N,) int
        First output frame of each input segment, strictly increasing, ``a[0] >= 0``; segment
        ``i`` ends where ``i + 1`` starts, the last at ``n_out``.
    n_out : int
        Output frames.
    fps : float
        Output frame rate (for ``tau_velocity``, ``smooth``).
    knots : (B,) int, optional
        Output frames where sub-sequences start (drift correction, step 3).
    tau_velocity : float
        Fade time of the velocity correction at joins, seconds.
    smooth : float
        Gaussian sigma around joins, seconds (0 = off).
    head : (N,) float, optional
        Output frames at the start of each segment played at the database's own speed (not
        warped); only the rest of the segment is warped to end on ``f1`` (module docstring).
    step : float
        Database frames per output frame (database fps / output fps), for ``head``.
    transition : {"after", "before", "split"}
        Where the velocity mismatch at a join is absorbed: in the new segment's first frames
        (``"after"``), in the frames before the join (``"before"``: the previous segment's
        voiceless end, so the stroke after the onset is untouched), or half each.

    Returns
    -------
    trajectory : (n_out, D) float
    joins : (N - 1,) int
        Output frames where a new segment starts.
    """
    motion = np.asarray(motion, np.float64)
    f0 = np.asarray(f0, np.float64)
    f1 = np.asarray(f1, np.float64)
    a = np.asarray(a, int)
    N = a.size
    D = motion.shape[1]
    b = np.r_[a[1:], n_out]
    n = b - a
    if N == 0:
        return np.zeros((n_out, D)), np.zeros(0, int)
    if transition not in ("after", "before", "split"):
        raise ValueError(f"transition must be 'after', 'before' or 'split', got {transition!r}")
    share_after = {"after": 1.0, "before": 0.0, "split": 0.5}[transition]
    r = _resample(motion, f0, f1, n, head, step)
    tau = max(tau_velocity * fps, 1e-6)
    chain, raw = _chain(r, a, b, n, n_out, tau, share_after)
    out = _remove_drift(chain, raw, knots, n_out)
    # 4. smooth around joins
    joins = a[1:]
    out = _smooth_joins(out, joins, smooth * fps, n_out)
    return out, joins


def _chain(r: list[np.ndarray], a: np.ndarray, b: np.ndarray, n: np.ndarray, n_out: int, tau: float,
           share_after: float) -> tuple[np.ndarray, np.ndarray]:
    """Chain the resampled segments (step 2 of the module docstring).

    Parameters
    ----------
    r : list of N (n_i + 1, D) float
        Resampled database motion of each segment (:func:`_resample`).
    a, b, n : (N,) int
        First output frame, end output frame and length of each input segment.
    n_out : int
        Output frames.
    tau : float
        Fade time of the velocity correction, output frames.
    share_after : float
        Share of the velocity mismatch absorbed after the join (the rest before it).

    Returns
    -------
    chain : (n_out, D) float
        The segments offset to continue one another, velocity-corrected at joins.
    raw : (n_out, D) float
        The segments as resampled, unchained (the database's own poses).
    """
    D = r[0].shape[1]
    chain = np.zeros((n_out, D))
    raw = np.zeros((n_out, D))
    reach = int(np.ceil(6 * tau))  # k exp(-k / tau) < 0.015 tau beyond 6 tau
    prev_next = None  # where the previous segment would continue
    prev_v = None  # its last step
    for i in range(a.size):
        ri = r[i]
        if prev_next is None:
            placed = ri.copy()
        else:
            placed = ri + (prev_next - ri[0])
            if n[i] >= 1 and ri.shape[0] >= 2:
                dv = prev_v - (ri[1] - ri[0])
                if share_after > 0:  # the new segment's first frames move like the previous last step
                    k = np.arange(ri.shape[0], dtype=np.float64)[:, None]
                    placed = placed + share_after * dv * k * np.exp(-k / tau)
                if share_after < 1:  # the previous frames already move like the new first step
                    m = np.arange(1, min(reach, a[i] - a[0]) + 1, dtype=np.float64)[:, None]
                    chain[a[i] - m[:, 0].astype(int)] += (1.0 - share_after) * dv * m * np.exp(-m / tau)
        chain[a[i]:b[i]] = placed[: n[i]]
        raw[a[i]:b[i]] = ri[: n[i]]
        prev_next = placed[n[i]]
        prev_v = placed[n[i]] - placed[n[i] - 1]
    if a[0] > 0:
        chain[: a[0]] = chain[a[0]]
        raw[: a[0]] = raw[a[0]]
    return chain, raw


def _remove_drift(chain: np.ndarray, raw: np.ndarray, knots: np.ndarray | None, n_out: int) -> np.ndarray:
    """(n_out, D) ``chain`` minus the PCHIP through its drift from ``raw`` (both (n_out, D)) at the
    sub-sequence starts ``knots`` (B,) and the last frame (step 3 of the module docstring)."""
    # 3. drift: warp each sub-sequence to end on database poses
    k = np.unique(np.r_[0, [] if knots is None else np.asarray(knots, int), n_out - 1]).astype(int)
    k = k[(k >= 0) & (k < n_out)]
    err = chain[k] - raw[k]
    err[0] = 0.0
    if k.size >= 2:
        corr = PchipInterpolator(k, err, axis=0)(np.arange(n_out))
        out = chain - corr
    else:
        out = chain
    return out


def _smooth_joins(out: np.ndarray, joins: np.ndarray, sig: float, n_out: int) -> np.ndarray:
    """(n_out, D) trajectory ``out`` with a Gaussian of ``sig`` output frames blended in around the
    (N - 1,) ``joins`` (step 4 of the module docstring); unchanged when ``sig`` is 0, there are no
    joins or ``n_out <= 3``."""
    if sig > 0 and joins.size and n_out > 3:
        sm = gaussian_filter1d(out, sig, axis=0, mode="nearest")
        t = np.arange(n_out) + 0.5  # a join sits between frames joins - 1 and joins
        j = np.clip(np.searchsorted(joins, t), 1, joins.size) - 1
        d = np.minimum(np.abs(t - joins[j]), np.abs(t - joins[np.minimum(j + 1, joins.size - 1)]))
        w = np.exp(-0.5 * (d / (2.0 * sig)) ** 2)[:, None]
        out = out * (1.0 - w) + sm * w
    return out
