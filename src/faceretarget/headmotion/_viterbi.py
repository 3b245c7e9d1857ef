"""Minimum-cost path through a trellis (Viterbi), with an optional penalty for reusing labels.

Step ``i`` of the trellis has ``K_i`` states; a path picks one state per step.  Its cost is::

    sum_i unary[i][path[i]] + sum_i pairwise[i][path[i], path[i + 1]]

which dynamic programming minimises exactly.  Optionally each state carries a ``label`` (here: the
database segment it stands for) and a transition into a state whose label already occurs among the
last ``window`` states of the best path reaching the previous state costs ``history_penalty`` more.
That term depends on more than two neighbouring steps, so with it the search is the usual greedy
extension of Viterbi (the penalty is evaluated on each state's surviving best path), not an exact
minimum; with ``history_penalty=0`` the result is exact.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ..errors import InvalidDataError

__all__ = ["viterbi", "path_cost"]


def viterbi(unary: Sequence[np.ndarray], pairwise: Sequence[np.ndarray], *,
            labels: Sequence[np.ndarray] | None = None, history_penalty: float = 0.0,
            window: int = 8) -> tuple[np.ndarray, float]:
    """Minimum-cost path.

    Parameters
    ----------
    unary : sequence of N arrays (K_i,)
        Cost of each state of each step.
    pairwise : sequence of N-1 arrays (K_i, K_{i+1})
        Cost of each transition from step ``i`` to step ``i + 1``.
    labels : sequence of N int arrays (K_i,), optional
        A label per state, for ``history_penalty``.
    history_penalty : float
        Added when a state's label occurs in the last ``window`` states of the best path into
        the previous state (module docstring).
    window : int
        How many previous steps the history looks at.

    Returns
    -------
    path : (N,) int
        The chosen state index of each step.
    cost : float
        Its total cost (including history penalties).

    Examples
    --------
    >>> u = [np.array([0.0, 1.0]), np.array([1.0, 0.0])]
    >>> p = [np.array([[5.0, 5.0], [0.0, 0.0]])]
    >>> path, cost = viterbi(u, p)
    >>> path.tolist(), cost
    ([1, 1], 1.0)
    """
    N = len(unary)
    if N == 0:
        return np.zeros(0, int), 0.0
    if len(pairwise) != N - 1:
        raise InvalidDataError(f"viterbi: {len(pairwise)} pairwise tables for {N} steps (need {N - 1})")
    use_hist = labels is not None and history_penalty != 0.0 and window > 0
    acc, back = _forward(unary, pairwise, labels if use_hist else None, history_penalty, window)
    return _backtrack(acc, back)


def _forward(unary: Sequence[np.ndarray], pairwise: Sequence[np.ndarray], labels: Sequence[np.ndarray] | None,
             history_penalty: float, window: int) -> tuple[np.ndarray, list[np.ndarray]]:
    """Forward pass of :func:`viterbi` over N >= 1 steps (``labels`` None: no history penalty).

    Returns
    -------
    acc : (K_{N-1},) float
        Cost of the best path into each state of the last step.
    back : list of N - 1 arrays (K_i,) int
        For steps 1..N-1, the best predecessor of each state.
    """
    use_hist = labels is not None
    acc = np.asarray(unary[0], np.float64).copy()
    back: list[np.ndarray] = []
    hist = None
    if use_hist:
        lab0 = np.asarray(labels[0])
        hist = np.full((acc.size, window), -1, dtype=np.int64)
        hist[:, -1] = lab0
    for i in range(1, len(unary)):
        P = np.asarray(pairwise[i - 1], np.float64)
        u = np.asarray(unary[i], np.float64)
        if P.shape != (acc.size, u.size):
            raise InvalidDataError(f"viterbi: pairwise table {i - 1} is {P.shape}, "
                                   f"expected {(acc.size, u.size)}")
        tot = acc[:, None] + P
        if use_hist:
            lab = np.asarray(labels[i])
            seen = (hist[:, :, None] == lab[None, None, :]).any(axis=1)  # (K_prev, K_i)
            tot = tot + history_penalty * seen
        b = np.argmin(tot, axis=0)
        acc = tot[b, np.arange(u.size)] + u
        back.append(b)
        if use_hist:
            hist = np.concatenate([hist[b, 1:], lab[:, None]], axis=1)
    return acc, back


def _backtrack(acc: np.ndarray, back: list[np.ndarray]) -> tuple[np.ndarray, float]:
    """(N,) path ending in the cheapest state of ``acc`` (K_{N-1},) following the N - 1 predecessor
    arrays ``back``, and its cost."""
    N = len(back) + 1
    path = np.zeros(N, dtype=int)
    path[-1] = int(np.argmin(acc))
    cost = float(acc[path[-1]])
    for i in range(N - 1, 0, -1):
        path[i - 1] = int(back[i - 1][path[i]])
    return path, cost


def path_cost(unary: Sequence[np.ndarray], pairwise: Sequence[np.ndarray], path: Sequence[int]) -> float:
    """Cost of a given path (without history penalties), for checking :func:`viterbi`."""
    c = sum(float(unary[i][k]) for i, k in enumerate(path))
    c += sum(float(pairwise[i][path[i], path[i + 1]]) for i in range(len(path) - 1))
    return c
